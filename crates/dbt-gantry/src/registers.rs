//! The gantry controller's Modbus holding registers (interface version 1).
//! The firmware is the Modbus client; addresses are 0-based holding-register
//! offsets from a configurable base address.
//!
//! | addr | register | unit / encoding |
//! |---|---|---|
//! | 0 | interface version | 1 |
//! | 1 | acquisition state | 0 idle, 1 compressing, 2 ready, 3 exposing, 4 complete, 5 fault |
//! | 2 | compressed thickness | 0.1 mm |
//! | 3 | compression force | 0.1 N |
//! | 4 | tube voltage | 0.1 kV |
//! | 5 | tube current-time product per projection | 0.01 mAs |
//! | 6 | anode/filter | 1 W/Rh, 2 W/Al, 3 W/Ag, 4 Mo/Mo, 5 Mo/Rh, 6 Rh/Rh, 7 Rh/Ag |
//! | 7 | number of projections | count |
//! | 8 | first angle | 0.1 degree, two's complement |
//! | 9 | last angle | 0.1 degree, two's complement |
//! | 10 | current projection index | 0-based |
//! | 11 | laterality (low byte: 1 L, 2 R) and view (high byte: 1 CC, 2 MLO, 3 ML, 4 LM) | |
//! | 12 | fault code | 0 none, else vendor code |

use serde::Serialize;
use thiserror::Error;

/// Number of registers of version 1.
pub const COUNT: usize = 13;
/// Interface version.
pub const INTERFACE_VERSION: u16 = 1;

/// A register that does not decode; names the register and the value.
#[derive(Debug, Clone, Error, PartialEq)]
#[error("register {address} ({name}) = {value}: {reason}")]
pub struct RegisterError {
    /// Offset.
    pub address: usize,
    /// Register name.
    pub name: &'static str,
    /// Raw value.
    pub value: u16,
    /// What is wrong.
    pub reason: String,
}

/// Acquisition state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum State {
    /// No acquisition.
    Idle,
    /// Compressing the breast.
    Compressing,
    /// Ready to expose.
    Ready,
    /// Sweep in progress.
    Exposing,
    /// Sweep done.
    Complete,
    /// The gantry reports a fault (see the fault code).
    Fault,
}

/// Decoded register values.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Registers {
    /// Interface version.
    pub version: u16,
    /// State.
    pub state: State,
    /// Thickness, mm.
    pub thickness_mm: f64,
    /// Force, N.
    pub force_n: f64,
    /// kV.
    pub kvp: f64,
    /// mAs per projection.
    pub mas_per_projection: f64,
    /// Anode/filter, e.g. `W/Rh`.
    pub anode_filter: &'static str,
    /// Projections.
    pub projections: u16,
    /// First and last angle, degrees.
    pub angles_deg: [f64; 2],
    /// Current projection.
    pub current: u16,
    /// `L` or `R`.
    pub laterality: char,
    /// `CC`, `MLO`, `ML` or `LM`.
    pub view: &'static str,
    /// Fault code (0: none).
    pub fault: u16,
}

const NAMES: [&str; COUNT] = [
    "interface version",
    "acquisition state",
    "compressed thickness",
    "compression force",
    "tube voltage",
    "mAs per projection",
    "anode/filter",
    "number of projections",
    "first angle",
    "last angle",
    "current projection",
    "laterality/view",
    "fault code",
];
/// The anode/filter combinations of register 6, by code (1 = `W/Rh`).
pub const ANODES: [&str; 7] = ["W/Rh", "W/Al", "W/Ag", "Mo/Mo", "Mo/Rh", "Rh/Rh", "Rh/Ag"];
const VIEWS: [&str; 4] = ["CC", "MLO", "ML", "LM"];

fn err(address: usize, value: u16, reason: impl Into<String>) -> RegisterError {
    RegisterError {
        address,
        name: NAMES[address],
        value,
        reason: reason.into(),
    }
}

/// Decode a block of [`COUNT`] registers. Physically impossible values are
/// errors here; plausibility against the acquisition header is the daemon's.
pub fn decode(r: &[u16]) -> Result<Registers, RegisterError> {
    if r.len() < COUNT {
        return Err(RegisterError {
            address: r.len(),
            name: "block",
            value: r.len() as u16,
            reason: format!("{} registers read, {COUNT} needed", r.len()),
        });
    }
    if r[0] != INTERFACE_VERSION {
        return Err(err(
            0,
            r[0],
            format!("this firmware speaks version {INTERFACE_VERSION}"),
        ));
    }
    let state = match r[1] {
        0 => State::Idle,
        1 => State::Compressing,
        2 => State::Ready,
        3 => State::Exposing,
        4 => State::Complete,
        5 => State::Fault,
        v => return Err(err(1, v, "unknown state")),
    };
    let thickness_mm = r[2] as f64 / 10.0;
    if thickness_mm > 200.0 {
        return Err(err(2, r[2], "above 200 mm"));
    }
    let kvp = r[4] as f64 / 10.0;
    if !(kvp == 0.0 || (15.0..=50.0).contains(&kvp)) {
        return Err(err(4, r[4], "outside 15-50 kV"));
    }
    let anode_filter = match r[6] {
        1..=7 => ANODES[r[6] as usize - 1],
        v => return Err(err(6, v, "unknown anode/filter code")),
    };
    let angle = |i: usize| (r[i] as i16) as f64 / 10.0;
    let angles_deg = [angle(8), angle(9)];
    for (k, a) in angles_deg.iter().enumerate() {
        if a.abs() > 90.0 {
            return Err(err(8 + k, r[8 + k], "beyond +-90 degrees"));
        }
    }
    if r[7] > 0 && r[10] >= r[7] && state == State::Exposing {
        return Err(err(10, r[10], format!("beyond the {} projections", r[7])));
    }
    let laterality = match r[11] & 0xFF {
        1 => 'L',
        2 => 'R',
        _ => return Err(err(11, r[11], "laterality must be 1 (L) or 2 (R)")),
    };
    let view = match r[11] >> 8 {
        v @ 1..=4 => VIEWS[v as usize - 1],
        _ => return Err(err(11, r[11], "view must be 1-4 (CC, MLO, ML, LM)")),
    };
    Ok(Registers {
        version: r[0],
        state,
        thickness_mm,
        force_n: r[3] as f64 / 10.0,
        kvp,
        mas_per_projection: r[5] as f64 / 100.0,
        anode_filter,
        projections: r[7],
        angles_deg,
        current: r[10],
        laterality,
        view,
        fault: r[12],
    })
}

/// Encode registers (the simulator's side). Values are rounded to the
/// register units.
pub fn encode(v: &Registers) -> [u16; COUNT] {
    let state = match v.state {
        State::Idle => 0,
        State::Compressing => 1,
        State::Ready => 2,
        State::Exposing => 3,
        State::Complete => 4,
        State::Fault => 5,
    };
    let anode = ANODES
        .iter()
        .position(|a| *a == v.anode_filter)
        .map_or(0, |i| i as u16 + 1);
    let view = VIEWS
        .iter()
        .position(|a| *a == v.view)
        .map_or(0, |i| i as u16 + 1);
    let lat = if v.laterality == 'R' { 2 } else { 1 };
    let tenth = |x: f64| (x * 10.0).round().clamp(0.0, 65535.0) as u16;
    let angle = |x: f64| ((x * 10.0).round() as i16) as u16;
    [
        v.version,
        state,
        tenth(v.thickness_mm),
        tenth(v.force_n),
        tenth(v.kvp),
        (v.mas_per_projection * 100.0).round().clamp(0.0, 65535.0) as u16,
        anode,
        v.projections,
        angle(v.angles_deg[0]),
        angle(v.angles_deg[1]),
        v.current,
        lat | (view << 8),
        v.fault,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Registers {
        Registers {
            version: 1,
            state: State::Exposing,
            thickness_mm: 45.3,
            force_n: 110.0,
            kvp: 28.0,
            mas_per_projection: 2.4,
            anode_filter: "W/Rh",
            projections: 25,
            angles_deg: [-24.0, 24.0],
            current: 12,
            laterality: 'L',
            view: "CC",
            fault: 0,
        }
    }

    #[test]
    fn round_trip() {
        let s = sample();
        assert_eq!(decode(&encode(&s)).unwrap(), s);
        assert_eq!(encode(&s)[8], (-240i16) as u16);
    }

    #[test]
    fn bad_registers_are_named() {
        let mut r = encode(&sample());
        r[1] = 9;
        assert!(decode(&r)
            .unwrap_err()
            .to_string()
            .contains("acquisition state"));
        let mut r = encode(&sample());
        r[2] = 2001;
        assert!(decode(&r)
            .unwrap_err()
            .to_string()
            .contains("compressed thickness"));
        let mut r = encode(&sample());
        r[0] = 2;
        assert!(decode(&r)
            .unwrap_err()
            .to_string()
            .contains("interface version"));
        let mut r = encode(&sample());
        r[11] = 3;
        assert!(decode(&r).unwrap_err().to_string().contains("laterality"));
        assert!(decode(&r[..5]).is_err());
    }

    #[test]
    fn any_register_block_decodes_or_errs_without_panicking() {
        let mut s = 99u64;
        for _ in 0..20000 {
            let r: Vec<u16> = (0..COUNT)
                .map(|_| {
                    s = s
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    (s >> 48) as u16
                })
                .collect();
            let _ = decode(&r);
        }
    }
}
