//! The firmware's end of the projection stream (GANTRY_INTERFACE.md section
//! 2): receive frames, acknowledge intact ones, nak corrupt and missing ones,
//! assemble the acquisition, and turn it into the processing's input. The
//! transport here is TCP (the bench and test transport of the interface); the
//! serial line carries the same bytes.

use dbt_gantry::assemble::{Assembler, Received, Reply};
use dbt_gantry::frame::{encode, Decoder, Frame, FrameError};
use dbt_geometry::Geometry;
use dbt_store::acquisition::{Acquisition, AcquisitionHeader, Patient, Study, ACQ_FORMAT};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::Duration;
use thiserror::Error;

/// Link faults: each is reported, none is silently accepted.
#[derive(Debug, Error)]
pub enum LinkError {
    /// Transport failure (cable pulled, peer gone, timeout).
    #[error("link: {0}")]
    Io(#[from] std::io::Error),
    /// A frame that cannot be repaired by retransmission.
    #[error("frame: {0}")]
    Frame(#[from] FrameError),
    /// The acquisition does not assemble.
    #[error("acquisition: {0}")]
    Assembly(#[from] dbt_gantry::assemble::AssemblyError),
    /// The stream ended before the acquisition was complete.
    #[error("the stream ended before the acquisition was complete (views {0:?} missing; all views are listed if the header never arrived)")]
    Incomplete(Vec<u16>),
    /// The data cannot be used (e.g. a flat field that is not a positive number).
    #[error("data: {0}")]
    Data(String),
    /// The acquisition does not fit the configured geometry.
    #[error("acquisition does not fit the configured geometry: {0}")]
    Geometry(String),
}

/// What a reception did (for the logs and the status file).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LinkStats {
    /// Intact frames.
    pub frames: usize,
    /// Frames rejected by their CRC.
    pub crc_errors: usize,
    /// Sequence numbers asked again.
    pub naks: usize,
    /// Bytes skipped while resynchronising.
    pub garbage_bytes: usize,
}

/// Send a control frame; a peer that is gone means an incomplete acquisition.
fn send<S: Write>(stream: &mut S, f: &Frame, asm: &Assembler) -> Result<(), LinkError> {
    match stream.write_all(&encode(f, 0)) {
        Ok(()) => Ok(()),
        Err(e)
            if matches!(
                e.kind(),
                std::io::ErrorKind::BrokenPipe | std::io::ErrorKind::ConnectionReset
            ) =>
        {
            Err(LinkError::Incomplete(asm.missing()))
        }
        Err(e) => Err(e.into()),
    }
}

/// Receive one acquisition over `stream`.
pub fn receive(
    stream: &mut TcpStream,
    timeout: Duration,
) -> Result<(Received, LinkStats), LinkError> {
    // Short reads let the overall deadline apply to any transport.
    stream.set_read_timeout(Some(Duration::from_millis(200)))?;
    receive_from(stream, timeout)
}

/// Receive one acquisition over any byte stream (TCP, a serial line). Reads
/// may time out (serial ports do): the acquisition fails only when nothing
/// arrives for `idle_timeout`.
pub fn receive_from<S: Read + Write>(
    stream: &mut S,
    idle_timeout: Duration,
) -> Result<(Received, LinkStats), LinkError> {
    let mut last_data = std::time::Instant::now();
    let mut dec = Decoder::new();
    let mut asm = Assembler::new();
    let mut stats = LinkStats::default();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = match stream.read(&mut buf) {
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => 0,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock
                ) =>
            {
                if last_data.elapsed() > idle_timeout {
                    return Err(LinkError::Incomplete(asm.missing()));
                }
                continue;
            }
            Err(e) => return Err(e.into()),
        };
        last_data = std::time::Instant::now();
        if n == 0 {
            // Peer gone (cable pulled, gantry restarted) before completion.
            return Err(LinkError::Incomplete(asm.missing()));
        }
        dec.push(&buf[..n]);
        while let Some(r) = dec.next_frame() {
            match r {
                Ok((seq, frame)) => {
                    stats.frames += 1;
                    let (reply, done) = asm.accept(seq, frame)?;
                    match reply {
                        Reply::Ack(s) => send(stream, &Frame::Ack { seq: s }, &asm)?,
                        Reply::Nak(list) => {
                            for s in list {
                                stats.naks += 1;
                                send(stream, &Frame::Nak { seq: s }, &asm)?;
                            }
                        }
                    }
                    if let Some(acq) = done {
                        // Tell the gantry the whole acquisition is in: the
                        // acknowledgement of the end frame's sequence number.
                        let end = 1 + acq.header.projections as u32;
                        let _ = stream.write_all(&encode(&Frame::Ack { seq: end }, 0));
                        let _ = stream.flush();
                        tracing::info!(?stats, "acquisition received");
                        return Ok((acq, stats));
                    }
                }
                Err(FrameError::Crc { seq, .. }) => {
                    stats.crc_errors += 1;
                    stats.naks += 1;
                    tracing::warn!(seq, "CRC error: asking for retransmission");
                    send(stream, &Frame::Nak { seq }, &asm)?;
                }
                Err(FrameError::Garbage(n)) => stats.garbage_bytes += n,
                Err(FrameError::Length { .. }) => {}
                Err(e) => return Err(e.into()),
            }
        }
    }
}

/// The processing's input from a received acquisition: detector rows are
/// coronal slices (spaced one pixel apart), columns detector elements.
/// Faults of the data that do not stop the reception but make the acquisition
/// unfit for a report: detector saturation (a count at 65535 is a lower bound,
/// its line integral unknown). `None` when the data are usable.
pub fn data_fault(r: &Received) -> Option<String> {
    if r.saturated == 0 {
        return None;
    }
    let views: Vec<u16> = r
        .projections
        .iter()
        .filter(|p| p.counts.contains(&u16::MAX))
        .map(|p| p.view)
        .collect();
    Some(format!(
        "{} pixels saturated at 65535 in views {views:?}: their line integrals are unknown",
        r.saturated
    ))
}

/// `tube_output_mgy_per_mas` is the site's calibration (configuration).
pub fn to_acquisition(
    r: &Received,
    geom: &Geometry,
    tube_output_mgy_per_mas: f64,
) -> Result<Acquisition, LinkError> {
    let h = &r.header;
    let bad = |m: String| LinkError::Geometry(m);
    if h.projections as usize != geom.n_views() {
        return Err(bad(format!(
            "{} projections, the geometry has {} views",
            h.projections,
            geom.n_views()
        )));
    }
    if h.columns as usize != geom.n_det() {
        return Err(bad(format!(
            "{} columns, the detector has {} elements",
            h.columns,
            geom.n_det()
        )));
    }
    for p in &r.projections {
        if let Some((k, f)) = p
            .flat
            .iter()
            .enumerate()
            .find(|(_, f)| !(f.is_finite() && **f > 0.0))
        {
            return Err(LinkError::Data(format!(
                "flat field of view {} at element {k} is {f}: not a positive number",
                p.view
            )));
        }
    }
    let flux = r.projections[0].flat[0];
    if r.projections
        .iter()
        .any(|p| p.flat.iter().any(|&f| (f - flux).abs() > 1e-3 * flux))
    {
        return Err(bad(
            "non-uniform flat field (per-ray flux is not supported yet)".into(),
        ));
    }
    for p in &r.projections {
        let want = geom.angle_deg(p.view as usize);
        if (p.angle_deg as f64 - want).abs() > 0.05 {
            return Err(bad(format!(
                "view {} at {} deg, the geometry says {want:.2}",
                p.view, p.angle_deg
            )));
        }
    }
    let (rows, nd, nv) = (h.rows as usize, geom.n_det(), geom.n_views());
    let counts = (0..rows)
        .map(|s| {
            let mut v = vec![0f32; nv * nd];
            for p in &r.projections {
                let o = p.view as usize * nd;
                for k in 0..nd {
                    v[o + k] = p.counts[s * nd + k] as f32;
                }
            }
            v
        })
        .collect();
    Ok(Acquisition {
        header: AcquisitionHeader {
            format: ACQ_FORMAT.into(),
            geometry: geom.clone(),
            thickness_mm: h.thickness_mm,
            flux: flux as f64,
            slices: rows,
            slice_spacing_mm: geom.image.pixel_mm,
            kvp: h.kvp,
            mas_total: h.mas_total,
            tube_output_mgy_per_mas,
            laterality: h.laterality.clone(),
            patient: Patient {
                name: h.patient_name.clone(),
                id: h.patient_id.clone(),
                birth_date: String::new(),
                sex: String::new(),
            },
            study: Study {
                study_uid: h.study_uid.clone(),
                date: h.study_date.clone(),
                time: h.study_time.clone(),
                accession: h.accession.clone(),
                study_id: String::new(),
                // Projections are not stored as DICOM here: a series UID
                // derived from the study's stands in for the evidence.
                series_uid: if h.study_uid.len() <= 62 {
                    h.study_uid.clone() + ".1"
                } else {
                    h.study_uid.clone()
                },
                instance_uids: vec![],
            },
            truth: None,
        },
        counts,
    })
}
