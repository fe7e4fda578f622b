//! Per-element photon interaction data, generated once from xraylib 4.3.0 by
//! `data/gen_tables.py` and compiled in (nothing is read at run time).

use crate::DoseError;

const ELEMENTS_CSV: &str = include_str!("../data/elements.csv");
const XS_CSV: &str = include_str!("../data/xs.csv");
const FF_CSV: &str = include_str!("../data/ff.csv");

/// First energy of the cross-section grid, keV.
pub const E_MIN: f64 = 1.0;
/// Spacing of the cross-section grid, keV.
pub const E_STEP: f64 = 0.1;
/// Number of grid energies (1.0 ..= 60.0 keV).
pub const N_E: usize = 591;

/// One element's tables.
#[derive(Debug, Clone)]
pub struct Element {
    /// Atomic number.
    pub z: u8,
    /// Atomic weight, g/mol.
    pub a: f64,
    /// Mass coefficients on the energy grid, cm^2/g: photoelectric, Rayleigh,
    /// Compton (with S).
    pub photo: Vec<f64>,
    /// Rayleigh (coherent), with the form factor.
    pub rayleigh: Vec<f64>,
    /// Compton (incoherent), with the incoherent scattering function.
    pub compton: Vec<f64>,
    /// Momentum transfer grid `x = sin(theta/2)/lambda`, 1/Angstrom.
    pub x: Vec<f64>,
    /// Atomic form factor F(x, Z).
    pub ff: Vec<f64>,
    /// Incoherent scattering function S(x, Z).
    pub sf: Vec<f64>,
}

fn rows(text: &'static str) -> impl Iterator<Item = Vec<&'static str>> {
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with('Z') && !l.trim().is_empty())
        .map(|l| l.split(',').collect())
}

fn num(s: &str, what: &str) -> Result<f64, DoseError> {
    s.trim()
        .parse()
        .map_err(|_| DoseError::Table(format!("{what}: `{s}` is not a number")))
}

/// All elements of the compiled-in tables, parsed once per process.
pub fn elements() -> Result<&'static [Element], DoseError> {
    static TABLES: std::sync::OnceLock<Result<Vec<Element>, String>> = std::sync::OnceLock::new();
    TABLES
        .get_or_init(|| parse_elements().map_err(|e| e.to_string()))
        .as_deref()
        .map_err(|e| DoseError::Table(e.clone()))
}

fn parse_elements() -> Result<Vec<Element>, DoseError> {
    let mut out = Vec::new();
    for r in rows(ELEMENTS_CSV) {
        let z = num(r[0], "elements.csv Z")? as u8;
        out.push(Element {
            z,
            a: num(r.get(2).copied().unwrap_or(""), "elements.csv A")?,
            photo: vec![],
            rayleigh: vec![],
            compton: vec![],
            x: vec![],
            ff: vec![],
            sf: vec![],
        });
    }
    let find = |out: &mut Vec<Element>, z: u8| out.iter().position(|e| e.z == z);
    for r in rows(XS_CSV) {
        if r.len() != 5 {
            return Err(DoseError::Table(format!("xs.csv row {r:?}")));
        }
        let z = num(r[0], "xs.csv Z")? as u8;
        let i = find(&mut out, z).ok_or_else(|| DoseError::Table(format!("xs.csv: Z {z}")))?;
        let e = &mut out[i];
        e.photo.push(num(r[2], "photo")?);
        e.rayleigh.push(num(r[3], "rayleigh")?);
        e.compton.push(num(r[4], "compton")?);
    }
    for r in rows(FF_CSV) {
        if r.len() != 4 {
            return Err(DoseError::Table(format!("ff.csv row {r:?}")));
        }
        let z = num(r[0], "ff.csv Z")? as u8;
        let i = find(&mut out, z).ok_or_else(|| DoseError::Table(format!("ff.csv: Z {z}")))?;
        let e = &mut out[i];
        e.x.push(num(r[1], "x")?);
        e.ff.push(num(r[2], "F")?);
        e.sf.push(num(r[3], "S")?);
    }
    for e in &out {
        if e.photo.len() != N_E || e.x.len() < 2 {
            return Err(DoseError::Table(format!("element {} incomplete", e.z)));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tables_load_and_match_known_values() {
        let els = elements().unwrap();
        let o = els.iter().find(|e| e.z == 8).unwrap();
        // xraylib 4.3.0, O at 16.8 keV: photo 1.0729, Rayleigh 0.12698, Compton 0.14910 cm^2/g.
        let i = ((16.8 - E_MIN) / E_STEP).round() as usize;
        assert!((o.photo[i] - 1.0729).abs() < 1e-3);
        assert!((o.rayleigh[i] - 0.12698).abs() < 1e-4);
        assert!((o.compton[i] - 0.14910).abs() < 1e-4);
        assert_eq!(o.a, 16.0);
        // F(0) = Z, S(large x) -> Z.
        assert!((o.ff[0] - 8.0).abs() < 1e-6);
        assert!((o.sf.last().unwrap() - 8.0).abs() < 0.01);
    }
}
