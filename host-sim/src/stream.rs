//! The simulated gantry's projection stream (GANTRY_INTERFACE.md, section 2)
//! over TCP, with fault injection. One connection, one acquisition: every
//! frame is sent, then naks are answered by retransmission until the
//! receiver acknowledges the end frame or closes the connection.

use dbt_gantry::frame::{encode, AcquisitionHeader, Decoder, Frame, Projection};
use dbt_pipeline::acquisition::Acquisition;
use std::io::{Read, Write};
use std::net::TcpListener;
use std::time::Duration;

/// Faults to inject (each on the first transmission only).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// Flip a payload bit of frame `seq` (the CRC fails).
    Corrupt(u32),
    /// Do not send frame `seq`.
    Drop(u32),
    /// Send frame `seq` twice.
    Duplicate(u32),
    /// Swap frames `a` and `b`.
    Reorder(u32, u32),
    /// Pull the cable: close the connection before frame `seq`.
    Cut(u32),
    /// Detector saturation: 32 counts of projection frame `seq` at 65535
    /// (a data fault with a valid CRC).
    Saturate(u32),
    /// A flat field of projection frame `seq` that is NaN (valid CRC).
    NanFlat(u32),
    /// A dead detector: every count of every projection frame from `seq`
    /// on is zero (valid CRC).
    Zeros(u32),
    /// The header announces this many projections (more than the geometry
    /// has: an oversized announcement).
    Announce(u32),
    /// A gantry that stops reading acknowledgements after frame `seq`: it
    /// keeps resending the header without ever reading.
    Freeze(u32),
    /// The header's tube loading set to this many mAs (`mas:0`: no exposure).
    Mas(u32),
    /// The header's anode/filter set to register 6's code (`anode:2`: W/Al;
    /// `anode:0`: not stated, the field being optional).
    Anode(u32),
    /// The header's tube voltage set to this many kV (`kvp:0`: none).
    Kvp(u32),
}

impl Fault {
    /// Parse `corrupt:3`, `drop:5`, `dup:2`, `reorder:1,2`.
    pub fn parse(s: &str) -> Result<Fault, String> {
        let (k, v) = s
            .split_once(':')
            .ok_or_else(|| format!("fault `{s}`: expected kind:seq"))?;
        let n = |t: &str| {
            t.trim()
                .parse::<u32>()
                .map_err(|_| format!("fault `{s}`: `{t}` is not a sequence number"))
        };
        match k {
            "corrupt" => Ok(Fault::Corrupt(n(v)?)),
            "drop" => Ok(Fault::Drop(n(v)?)),
            "dup" => Ok(Fault::Duplicate(n(v)?)),
            "cut" => Ok(Fault::Cut(n(v)?)),
            "saturate" => Ok(Fault::Saturate(n(v)?)),
            "nanflat" => Ok(Fault::NanFlat(n(v)?)),
            "zeros" => Ok(Fault::Zeros(n(v)?)),
            "announce" => Ok(Fault::Announce(n(v)?)),
            "freeze" => Ok(Fault::Freeze(n(v)?)),
            "mas" => Ok(Fault::Mas(n(v)?)),
            "anode" => Ok(Fault::Anode(n(v)?)),
            "kvp" => Ok(Fault::Kvp(n(v)?)),
            "reorder" => {
                let (a, b) = v
                    .split_once(',')
                    .ok_or_else(|| format!("fault `{s}`: reorder:a,b"))?;
                Ok(Fault::Reorder(n(a)?, n(b)?))
            }
            _ => Err(format!(
                "fault `{s}`: kind must be corrupt, drop, dup, reorder, cut, saturate, nanflat, zeros, announce, freeze, mas, anode or kvp"
            )),
        }
    }
}

/// The frames of an acquisition: header (seq 0), one projection per view
/// (seq 1 + view: rows = coronal slices, or a cone-beam system's detector
/// rows, which the header then names; columns = detector elements; counts
/// saturated at 65535), end (seq 1 + views).
pub fn frames_of(acq: &Acquisition) -> Result<Vec<Frame>, String> {
    let h = &acq.header;
    let g = &h.geometry;
    let (nv, nd) = match &h.system {
        Some(s) => (s.n_views(), s.detector.columns),
        None => (g.n_views(), g.n_det()),
    };
    let angle = |v: usize| match &h.system {
        Some(s) => s.angle_deg(v),
        None => g.angle_deg(v),
    };
    let rows = acq.counts.len();
    if rows > u16::MAX as usize || nd > u16::MAX as usize || nv > u16::MAX as usize {
        return Err("too many rows, columns or views for the frame format".into());
    }
    if let Some(bad) = acq.counts.iter().position(|r| r.len() != nv * nd) {
        return Err(format!(
            "row {bad} has {} counts, {nv} views of {nd} elements need {}",
            acq.counts[bad].len(),
            nv * nd
        ));
    }
    let mut frames = vec![Frame::Header(AcquisitionHeader {
        patient_id: h.patient.id.clone(),
        patient_name: h.patient.name.clone(),
        study_uid: h.study.study_uid.clone(),
        accession: h.study.accession.clone(),
        study_date: h.study.date.clone(),
        study_time: h.study.time.clone(),
        thickness_mm: h.thickness_mm,
        kvp: h.kvp,
        mas_total: h.mas_total,
        projections: nv as u16,
        rows: rows as u16,
        columns: nd as u16,
        laterality: h.laterality.clone(),
        system: h.system.as_ref().map(|s| s.name.clone()),
        // The acquisition's beam.
        anode_filter: Some(h.anode_filter.name().into()),
    })];
    for v in 0..nv {
        let mut counts = Vec::with_capacity(rows * nd);
        for slice in &acq.counts {
            counts.extend(
                slice[v * nd..(v + 1) * nd]
                    .iter()
                    .map(|&c| c.round().clamp(0.0, 65535.0) as u16),
            );
        }
        frames.push(Frame::Projection(Projection {
            view: v as u16,
            angle_deg: angle(v) as f32,
            rows: rows as u16,
            columns: nd as u16,
            counts,
            flat: vec![h.flux as f32; rows * nd],
        }));
    }
    frames.push(Frame::End {
        projections: nv as u16,
    });
    Ok(frames)
}

/// How a stream ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Served {
    /// Frames sent again on request.
    pub resent: usize,
    /// Whether the receiver acknowledged the end frame: the only receipt
    /// (GANTRY_INTERFACE.md); without it the acquisition stays with the
    /// gantry for a resend.
    pub delivered: bool,
}

/// Serve one connection on `listener`: stream `frames` with `faults`, then
/// answer naks until the end frame is acknowledged or the peer closes.
pub fn serve_one(
    listener: &TcpListener,
    frames: &[Frame],
    faults: &[Fault],
) -> std::io::Result<Served> {
    let (mut s, _) = listener.accept()?;
    s.set_read_timeout(Some(Duration::from_millis(200)))?;
    let cut = faults.iter().any(|f| matches!(f, Fault::Cut(_)));
    let r = serve_stream(&mut s, frames, faults, Duration::from_secs(30));
    if cut {
        let _ = s.shutdown(std::net::Shutdown::Both);
    }
    r
}

/// Stream `frames` over any byte stream (TCP, a serial line), then answer
/// naks until the end frame is acknowledged, the peer closes, or nothing
/// arrives for `idle_timeout`.
pub fn serve_stream<S: Read + Write>(
    s: &mut S,
    frames: &[Frame],
    faults: &[Fault],
    idle_timeout: Duration,
) -> std::io::Result<Served> {
    let undelivered = |resent| Served {
        resent,
        delivered: false,
    };
    // Data faults: the frames themselves are wrong (valid CRC), resends too.
    let mut owned: Vec<Frame> = frames.to_vec();
    for f in faults {
        match *f {
            Fault::Saturate(q) => {
                if let Some(Frame::Projection(p)) = owned.get_mut(q as usize) {
                    let n = p.counts.len();
                    for c in p.counts.iter_mut().skip(n / 2).take(32) {
                        *c = u16::MAX;
                    }
                }
            }
            Fault::NanFlat(q) => {
                if let Some(Frame::Projection(p)) = owned.get_mut(q as usize) {
                    if let Some(v) = p.flat.get_mut(0) {
                        *v = f32::NAN;
                    }
                }
            }
            Fault::Zeros(q) => {
                for f in owned.iter_mut().skip(q as usize) {
                    if let Frame::Projection(p) = f {
                        p.counts.iter_mut().for_each(|c| *c = 0);
                    }
                }
            }
            Fault::Announce(n) => {
                if let Some(Frame::Header(h)) = owned.get_mut(0) {
                    h.projections = n.min(u16::MAX as u32) as u16;
                }
            }
            Fault::Mas(n) => {
                if let Some(Frame::Header(h)) = owned.get_mut(0) {
                    h.mas_total = n as f64;
                }
            }
            Fault::Kvp(n) => {
                if let Some(Frame::Header(h)) = owned.get_mut(0) {
                    h.kvp = n as f64;
                }
            }
            Fault::Anode(code) => {
                if let Some(Frame::Header(h)) = owned.get_mut(0) {
                    let a = dbt_gantry::registers::ANODES.get((code as usize).wrapping_sub(1));
                    h.anode_filter = (code != 0)
                        .then(|| a.map_or_else(|| format!("code {code}"), |a| a.to_string()));
                }
            }
            _ => {}
        }
    }
    let frames = &owned[..];
    let mut order: Vec<u32> = (0..frames.len() as u32).collect();
    for f in faults {
        match *f {
            Fault::Drop(q) => order.retain(|&x| x != q),
            Fault::Duplicate(q) => {
                if let Some(i) = order.iter().position(|&x| x == q) {
                    order.insert(i, q);
                }
            }
            Fault::Reorder(a, b) => {
                if let (Some(i), Some(j)) = (
                    order.iter().position(|&x| x == a),
                    order.iter().position(|&x| x == b),
                ) {
                    order.swap(i, j);
                }
            }
            Fault::Corrupt(_)
            | Fault::Saturate(_)
            | Fault::NanFlat(_)
            | Fault::Zeros(_)
            | Fault::Announce(_)
            | Fault::Freeze(_)
            | Fault::Mas(_)
            | Fault::Anode(_)
            | Fault::Kvp(_) => {}
            Fault::Cut(q) => {
                if let Some(i) = order.iter().position(|&x| x == q) {
                    order.truncate(i);
                }
            }
        }
    }
    let cut = faults.iter().any(|f| matches!(f, Fault::Cut(_)));
    let mut corrupted: Vec<u32> = Vec::new();
    for q in order {
        let Some(frame) = frames.get(q as usize) else {
            continue;
        };
        let mut bytes = encode(frame, q);
        if !corrupted.contains(&q) && faults.contains(&Fault::Corrupt(q)) && bytes.len() > 20 {
            bytes[16] ^= 0x01;
            corrupted.push(q);
        }
        match s.write_all(&bytes) {
            Ok(()) => {}
            // The receiver closed (it refused the acquisition, or went
            // away): not delivered, the gantry keeps it.
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::BrokenPipe | std::io::ErrorKind::ConnectionReset
                ) =>
            {
                return Ok(undelivered(0))
            }
            Err(e) => return Err(e),
        }
        if faults.contains(&Fault::Freeze(q)) {
            // Never read again: resend the header (each one acknowledged)
            // until the receiver gives up and closes, or `idle_timeout`.
            let header = encode(&frames[0], 0);
            let t0 = std::time::Instant::now();
            while t0.elapsed() < idle_timeout {
                if s.write_all(&header).is_err() {
                    return Ok(undelivered(0));
                }
            }
            return Ok(undelivered(0));
        }
    }
    s.flush()?;
    if cut {
        return Ok(undelivered(0));
    }
    let end_seq = frames.len() as u32 - 1;
    let mut dec = Decoder::new();
    let mut buf = vec![0u8; 4096];
    let mut resent = 0;
    let mut last = std::time::Instant::now();
    loop {
        let n = match s.read(&mut buf) {
            Ok(0) => return Ok(undelivered(resent)),
            Ok(n) => n,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::ConnectionReset
                        | std::io::ErrorKind::BrokenPipe
                        | std::io::ErrorKind::UnexpectedEof
                ) =>
            {
                return Ok(undelivered(resent))
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock
                ) =>
            {
                if last.elapsed() > idle_timeout {
                    return Ok(undelivered(resent));
                }
                continue;
            }
            Err(e) => return Err(e),
        };
        last = std::time::Instant::now();
        dec.push(&buf[..n]);
        while let Some(r) = dec.next_frame() {
            match r {
                Ok((_, Frame::Nak { seq })) => {
                    if let Some(f) = frames.get(seq as usize) {
                        // A peer that is gone (it may have everything and
                        // closed while duplicate naks were in flight) ends
                        // the session; it is not the gantry's fault.
                        if s.write_all(&encode(f, seq))
                            .and_then(|_| s.flush())
                            .is_err()
                        {
                            return Ok(undelivered(resent));
                        }
                        resent += 1;
                    }
                }
                Ok((_, Frame::Ack { seq })) if seq == end_seq => {
                    return Ok(Served {
                        resent,
                        delivered: true,
                    })
                }
                _ => {}
            }
        }
    }
}
