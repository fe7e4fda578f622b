//! The firmware's end of the projection stream (GANTRY_INTERFACE.md section
//! 2): receive frames, acknowledge intact ones, nak corrupt and missing ones,
//! assemble the acquisition, and turn it into the processing's input. The
//! transport here is TCP (the bench and test transport of the interface); the
//! serial line carries the same bytes.

use dbt_dose::xray::AnodeFilter;
use dbt_gantry::assemble::{Assembler, Budget, Received, Reply};
use dbt_gantry::frame::{
    encode, system_name, AcquisitionHeader as GantryHeader, Decoder, Frame, FrameError,
};
use dbt_pipeline::acquisition::{Acquisition, AcquisitionHeader, Patient, Study, ACQ_FORMAT};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::Duration;
use thiserror::Error;

/// Link faults: each is reported, none is silently accepted.
#[derive(Debug, Error)]
pub enum LinkError {
    /// Transport failure (cable pulled, peer gone).
    #[error("link: {0}")]
    Io(#[from] std::io::Error),
    /// A frame that cannot be repaired by retransmission.
    #[error("frame: {0}")]
    Frame(#[from] FrameError),
    /// The acquisition does not assemble.
    #[error("acquisition: {0}")]
    Assembly(#[from] dbt_gantry::assemble::AssemblyError),
    /// The stream ended or went quiet after the header, views missing.
    #[error("the stream ended before the acquisition was complete (views {0:?} missing)")]
    Incomplete(Vec<u16>),
    /// Bytes arrived but no acquisition header.
    #[error("{bytes} bytes arrived but no acquisition header ({frames} intact frames, {crc_errors} CRC errors, {garbage_bytes} bytes of garbage)")]
    NoHeader {
        /// Bytes received.
        bytes: usize,
        /// Intact frames.
        frames: usize,
        /// CRC errors.
        crc_errors: usize,
        /// Garbage bytes skipped.
        garbage_bytes: usize,
    },
    /// Bytes keep arriving, but the acquisition does not advance.
    #[error(
        "the acquisition has not advanced for {secs:.0} s although bytes keep arriving ({stats})"
    )]
    NoProgress {
        /// Seconds since the last frame that advanced the acquisition (or
        /// the first byte).
        secs: f64,
        /// What arrived meanwhile.
        stats: String,
    },
    /// The gantry stopped reading our acknowledgements.
    #[error("the gantry has not read our acknowledgements for {secs:.0} s (write timed out)")]
    Stalled {
        /// The write timeout, s.
        secs: f64,
    },
    /// The receiver was asked to stop.
    #[error("stopped (SIGTERM) during the reception")]
    Stopped,
    /// The acquisition header is implausible: refused before its projections.
    #[error("acquisition refused at its header: {0}")]
    Header(#[from] dbt_pipeline::HeaderError),
    /// The data cannot be used (e.g. a flat field that is not a positive number).
    #[error("data: {0}")]
    Data(String),
    /// The acquisition does not fit the configured geometry.
    #[error("acquisition does not fit the configured geometry: {0}")]
    Geometry(String),
    /// The stream comes from another acquisition system than the configured
    /// one: refused at its header, before any projection is kept (the
    /// gantry keeps the acquisition: its end frame is never acknowledged).
    #[error("acquisition refused at its header: the stream is from {stream}, this firmware is configured for {configured} (frames.system)")]
    System {
        /// What the header says, in words.
        stream: String,
        /// What the configuration says, in words.
        configured: String,
    },
    /// The header states an exposure the dose model has no spectra for.
    #[error("acquisition refused at its header: anode/filter {stated}: the dose model's spectra are {} only", AnodeFilter::supported())]
    Technique {
        /// The anode/filter the header states.
        stated: String,
    },
}

/// What a receiver is configured for: the site's gantry (its
/// reconstruction geometry, the cone-beam system the gantry streams from,
/// the site's tube output), the one description the DICOM input checks
/// against too.
pub use dbt_intake::Gantry;

/// Refuse a stream header from another system than the site's gantry,
/// naming both, or of an exposure the dose model has no spectra for (an
/// anode/filter other than `dbt_dose::xray::AnodeFilter::ALL`), naming it.
pub fn check_header(gantry: &Gantry, h: &GantryHeader) -> Result<(), LinkError> {
    if let Some(a) = h.anode_filter.as_deref() {
        if AnodeFilter::parse(a).is_err() {
            return Err(LinkError::Technique {
                stated: a.to_string(),
            });
        }
    }
    let want = gantry.cone.as_ref().map(|s| s.name.as_str());
    if h.system.as_deref() == want {
        return Ok(());
    }
    Err(LinkError::System {
        stream: system_name(h.system.as_deref()),
        configured: system_name(want),
    })
}

pub use dbt_gantry::stats::LinkStats;

/// How a reception is bounded.
#[derive(Debug, Clone)]
pub struct LinkOptions {
    /// The acquisition fails when no byte arrives for this long.
    pub idle_timeout: Duration,
    /// A write (ack, nak) that does not complete within this is a stalled peer.
    pub write_timeout: Duration,
    /// What the configured geometry allows; `None`: anything the codec accepts.
    pub budget: Option<Budget>,
    /// Slowest useful transfer rate, bytes/s: when the acquisition has not
    /// advanced for `idle_timeout` (plus, while a frame is in progress, its
    /// declared length at this rate), a trickle of bytes is a fault. 8 kB/s
    /// is below what the slowest supported frame line, 115200 baud, moves
    /// (11.5 kB/s).
    pub min_rate: f64,
    /// Set to stop the reception (SIGTERM).
    pub stop: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
    /// Set when other work waits (the DICOM input): while no byte has
    /// arrived, a read that finds the line idle returns
    /// [`LinkError::NoHeader`] with no byte.
    pub yield_to: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
    /// The configured geometry, system and tube output: the header is
    /// checked against the system and validated as soon as it arrives
    /// ([`Gantry::check_header`], [`dbt_pipeline::validate_header`]).
    pub site: Option<Gantry>,
}

impl LinkOptions {
    /// Options with `idle_timeout` (also the write timeout), no budget and
    /// no stop flag.
    pub fn new(idle_timeout: Duration) -> Self {
        Self {
            idle_timeout,
            write_timeout: idle_timeout,
            budget: None,
            min_rate: 8192.0,
            stop: None,
            yield_to: None,
            site: None,
        }
    }

    /// With the memory budget of `site`, and the header checked against it
    /// on arrival.
    pub fn for_site(mut self, site: &Gantry) -> Self {
        self.budget = Some(budget_for(site));
        self.site = Some(site.clone());
        self
    }
}

/// The receiver's budget for `site`: the fan-beam stream's views and
/// detector elements and at most `DEPTH_MAX_MM / pixel` detector rows
/// (coronal slices); a cone-beam system's views, columns and rows.
pub fn budget_for(site: &Gantry) -> Budget {
    let to16 = |n: usize| n.min(u16::MAX as usize) as u16;
    match &site.cone {
        Some(s) => Budget {
            projections: to16(s.n_views()),
            columns: to16(s.detector.columns),
            max_rows: to16(s.detector.rows),
        },
        None => {
            let g = &site.geometry;
            let rows = (dbt_pipeline::acquisition::limits::DEPTH_MAX_MM / g.image.pixel_mm).floor();
            Budget {
                projections: to16(g.n_views()),
                columns: to16(g.n_det()),
                max_rows: rows.clamp(1.0, u16::MAX as f64) as u16,
            }
        }
    }
}

/// At most one log line per second per kind; the rest are counted.
#[derive(Debug, Default)]
struct LogLimiter {
    last: Option<std::time::Instant>,
    suppressed: usize,
}

impl LogLimiter {
    fn allow(&mut self) -> Option<usize> {
        let now = std::time::Instant::now();
        match self.last {
            Some(t) if now.duration_since(t) < Duration::from_secs(1) => {
                self.suppressed += 1;
                None
            }
            _ => {
                self.last = Some(now);
                Some(std::mem::take(&mut self.suppressed))
            }
        }
    }
}

/// Send a control frame; a peer that is gone means an incomplete acquisition.
fn send<S: Write>(
    stream: &mut S,
    f: &Frame,
    asm: &Assembler,
    opts: &LinkOptions,
) -> Result<(), LinkError> {
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
        Err(e)
            if matches!(
                e.kind(),
                std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock
            ) =>
        {
            Err(LinkError::Stalled {
                secs: opts.write_timeout.as_secs_f64(),
            })
        }
        Err(e) => Err(e.into()),
    }
}

/// Receive one acquisition over `stream` (TCP): reads poll every 200 ms,
/// writes time out after `opts.write_timeout`.
pub fn receive(
    stream: &mut TcpStream,
    opts: &LinkOptions,
) -> Result<(Received, LinkStats), LinkError> {
    // Short reads let the overall deadline apply to any transport.
    stream.set_read_timeout(Some(Duration::from_millis(200)))?;
    stream.set_write_timeout(Some(opts.write_timeout.max(Duration::from_millis(1))))?;
    receive_from(stream, opts)
}

/// Receive one acquisition over any byte stream (TCP, a serial line). Reads
/// may time out (serial ports do). The reception fails when nothing arrives
/// for `opts.idle_timeout`, when bytes arrive but the acquisition does not
/// advance for `idle_timeout` (plus the frame in progress at `min_rate`),
/// when a write stalls, or when the stop flag is set. Memory is bounded by
/// the budget: the decoder refuses longer payloads, the assembler larger
/// headers.
pub fn receive_from<S: Read + Write>(
    stream: &mut S,
    opts: &LinkOptions,
) -> Result<(Received, LinkStats), LinkError> {
    let t0 = std::time::Instant::now();
    let mut last_data = t0;
    let mut last_frame = t0;
    let (mut dec, mut asm) = match opts.budget {
        Some(b) => (
            Decoder::with_max_payload(b.projection_payload().max(1024)),
            Assembler::with_budget(b),
        ),
        None => (Decoder::new(), Assembler::new()),
    };
    let mut stats = LinkStats::default();
    let mut crc_log = LogLimiter::default();
    let mut buf = vec![0u8; 1 << 16];
    let ended = |asm: &Assembler, stats: &LinkStats| {
        if asm.has_header() {
            LinkError::Incomplete(asm.missing())
        } else {
            LinkError::NoHeader {
                bytes: stats.bytes,
                frames: stats.frames,
                crc_errors: stats.crc_errors,
                garbage_bytes: stats.garbage_bytes,
            }
        }
    };
    loop {
        if opts
            .stop
            .as_ref()
            .is_some_and(|s| s.load(std::sync::atomic::Ordering::SeqCst))
        {
            return Err(LinkError::Stopped);
        }

        // Bytes that do not advance the acquisition (garbage, corrupt or
        // repeated frames) get `idle_timeout`; a frame in progress the time
        // its declared length takes at `min_rate` on top. Only while bytes
        // keep arriving: a line silent for `idle_timeout` is the idle case
        // below (the acquisition's own fault: no header, or what is
        // missing), whichever check a busy machine happens to reach first.
        let in_flight = dec.frame_in_progress().unwrap_or(0) as f64 / opts.min_rate.max(1.0);
        let progress_limit = opts.idle_timeout + Duration::from_secs_f64(in_flight);
        if stats.bytes > 0
            && last_frame.elapsed() > progress_limit
            && last_data.elapsed() <= opts.idle_timeout
        {
            return Err(LinkError::NoProgress {
                secs: last_frame.elapsed().as_secs_f64(),
                stats: stats.to_string(),
            });
        }
        let n = match stream.read(&mut buf) {
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => 0,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::TimedOut
                        | std::io::ErrorKind::WouldBlock
                        | std::io::ErrorKind::Interrupted
                ) =>
            {
                // Nothing has arrived and other work waits: give way (the
                // line is idle; a gantry that starts sending finds us back).
                let give_way = stats.bytes == 0
                    && opts
                        .yield_to
                        .as_ref()
                        .is_some_and(|s| s.load(std::sync::atomic::Ordering::SeqCst));
                if give_way || last_data.elapsed() > opts.idle_timeout {
                    return Err(ended(&asm, &stats));
                }
                continue;
            }
            Err(e) => return Err(e.into()),
        };
        last_data = std::time::Instant::now();
        if n == 0 {
            // Peer gone (cable pulled, gantry restarted) before completion.
            return Err(ended(&asm, &stats));
        }
        if stats.bytes == 0 {
            // The no-progress clock starts at the first byte: waiting for
            // a gantry to begin is the idle timeout's business.
            last_frame = last_data;
        }
        stats.bytes += n;
        dec.push(&buf[..n]);
        while let Some(r) = dec.next_frame() {
            match r {
                Ok((seq, frame)) => {
                    stats.frames += 1;
                    let before = asm.progress();
                    let had_header = asm.has_header();
                    let (reply, done) = asm.accept(seq, frame)?;
                    if let (false, Some(h), Some(site)) = (had_header, asm.header(), &opts.site) {
                        check_header(site, h)?;
                        // The domain's validation, before any projection is
                        // kept. The flat field comes with the projections
                        // (`to_acquisition` checks it is positive and uniform,
                        // the spool's reader validates its value); the lowest
                        // plausible one stands in for it here.
                        let flux = dbt_pipeline::acquisition::limits::FLUX_MIN;
                        dbt_pipeline::validate_header(&domain_header(h, site, flux))?;
                    }
                    if asm.progress() != before {
                        last_frame = std::time::Instant::now();
                    }
                    match reply {
                        Reply::Ack(s) => send(stream, &Frame::Ack { seq: s }, &asm, opts)?,
                        Reply::Nak(list) => {
                            for s in list {
                                stats.naks += 1;
                                send(stream, &Frame::Nak { seq: s }, &asm, opts)?;
                            }
                        }
                    }
                    if let Some(acq) = done {
                        // Tell the gantry the whole acquisition is in: the
                        // acknowledgement of the end frame's sequence number.
                        let end = 1 + acq.header.projections as u32;
                        let _ = stream.write_all(&encode(&Frame::Ack { seq: end }, 0));
                        let _ = stream.flush();
                        stats.suppressed_logs = crc_log.suppressed;
                        tracing::info!(%stats, "acquisition received");
                        return Ok((acq, stats));
                    }
                }
                Err(FrameError::Crc { seq, .. }) => {
                    stats.crc_errors += 1;
                    stats.naks += 1;
                    if let Some(suppressed) = crc_log.allow() {
                        tracing::warn!(
                            seq,
                            crc_errors = stats.crc_errors,
                            suppressed,
                            "CRC error: asking for retransmission"
                        );
                    }
                    send(stream, &Frame::Nak { seq }, &asm, opts)?;
                }
                Err(FrameError::Garbage(n)) => stats.garbage_bytes += n,
                Err(FrameError::Length { .. }) => stats.length_errors += 1,
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

/// The site's tube output is its calibration (configuration). A cone-beam
/// system's frames stay detector rows (`[row][view * column]`), the header
/// carrying the system: the processing rebins them.
pub fn to_acquisition(r: &Received, site: &Gantry) -> Result<Acquisition, LinkError> {
    let h = &r.header;
    let geom = &site.geometry;
    let bad = |m: String| LinkError::Geometry(m);
    check_header(site, h)?;
    let (views, columns, what) = match &site.cone {
        Some(s) => (
            s.n_views(),
            s.detector.columns,
            format!("system {}", s.name),
        ),
        None => (geom.n_views(), geom.n_det(), "geometry".to_string()),
    };
    let angle = |v: usize| match &site.cone {
        Some(s) => s.angle_deg(v),
        None => geom.angle_deg(v),
    };
    if h.projections as usize != views {
        return Err(bad(format!(
            "{} projections, the {what} has {views} views",
            h.projections
        )));
    }
    if h.columns as usize != columns {
        return Err(bad(format!(
            "{} columns, the {what}'s detector has {columns}",
            h.columns
        )));
    }
    if let Some(s) = &site.cone {
        if h.rows as usize != s.detector.rows {
            return Err(bad(format!(
                "{} rows, the {what}'s detector has {}",
                h.rows, s.detector.rows
            )));
        }
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
        let want = angle(p.view as usize);
        if (p.angle_deg as f64 - want).abs() > 0.05 {
            return Err(bad(format!(
                "view {} at {} deg, the {what} says {want:.2}",
                p.view, p.angle_deg
            )));
        }
    }
    let (rows, nd, nv) = (h.rows as usize, columns, views);
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
        header: domain_header(h, site, flux as f64),
        counts,
    })
}

/// The domain's acquisition header from the gantry's header frame: detector
/// rows are coronal slices one pixel apart (the slice-wise stream), or the
/// rows of the site's cone-beam system.
pub fn domain_header(h: &GantryHeader, site: &Gantry, flux: f64) -> AcquisitionHeader {
    let geom = &site.geometry;
    AcquisitionHeader {
        format: ACQ_FORMAT.into(),
        geometry: geom.clone(),
        thickness_mm: h.thickness_mm,
        flux,
        slices: h.rows as usize,
        slice_spacing_mm: geom.image.pixel_mm,
        kvp: h.kvp,
        // The header's beam (refused by `check_header` if unknown); where
        // it states none, the paper's W/Rh until the daemon reads the
        // gantry's register 6.
        anode_filter: h
            .anode_filter
            .as_deref()
            .and_then(|a| AnodeFilter::parse(a).ok())
            .unwrap_or_default(),
        mas_total: h.mas_total,
        tube_output_mgy_per_mas: site.tube_output_mgy_per_mas,
        laterality: h.laterality.clone(),
        compression_force_n: None,
        exposure_ms_per_view: None,
        system: site.cone.clone(),
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
            source_class: None,
        },
        truth: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dbt_gantry::frame::AcquisitionHeader as H;
    use dbt_geometry::{ConeSystem, Geometry};

    /// A byte stream that delivers `input` then times out, and whose writes
    /// time out (a peer that stopped reading) or succeed.
    struct Peer {
        input: std::io::Cursor<Vec<u8>>,
        writes_stall: bool,
    }

    impl Read for Peer {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            match self.input.read(buf)? {
                0 => {
                    std::thread::sleep(Duration::from_millis(20));
                    Err(std::io::ErrorKind::TimedOut.into())
                }
                n => Ok(n),
            }
        }
    }

    impl Write for Peer {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            if self.writes_stall {
                Err(std::io::ErrorKind::WouldBlock.into())
            } else {
                Ok(buf.len())
            }
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    fn header() -> H {
        H {
            patient_id: "P1".into(),
            patient_name: "Doe^Jane".into(),
            study_uid: "1.2.826.0.1.3680043.10.543.5".into(),
            accession: "A1".into(),
            study_date: "20261122".into(),
            study_time: "101500".into(),
            thickness_mm: 45.0,
            kvp: 28.0,
            mas_total: 60.0,
            projections: 25,
            rows: 186,
            columns: 320,
            laterality: "L".into(),
            system: None,
            anode_filter: None,
        }
    }

    fn run(input: Vec<u8>, writes_stall: bool, site: bool) -> LinkError {
        let mut p = Peer {
            input: std::io::Cursor::new(input),
            writes_stall,
        };
        let g = Geometry::builtin("paper").unwrap().binned(4).unwrap();
        let mut o = LinkOptions::new(Duration::from_millis(300));
        if site {
            o = o.for_site(&Gantry::fan(&g, 0.11));
        }
        receive_from(&mut p, &o).unwrap_err()
    }

    /// The DICOM input's wake flag ends a reception on an idle line (the
    /// daemon then processes what the input spooled) long before the idle
    /// timeout, and never one whose bytes are arriving.
    #[test]
    fn a_reception_yields_before_its_first_byte_only() {
        let flag = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let o = LinkOptions {
            yield_to: Some(std::sync::Arc::clone(&flag)),
            ..LinkOptions::new(Duration::from_secs(30))
        };
        let raiser = {
            let flag = std::sync::Arc::clone(&flag);
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(200));
                flag.store(true, std::sync::atomic::Ordering::SeqCst);
            })
        };
        let mut idle = Peer {
            input: std::io::Cursor::new(vec![]),
            writes_stall: false,
        };
        let t0 = std::time::Instant::now();
        let e = receive_from(&mut idle, &o).unwrap_err();
        raiser.join().unwrap();
        assert!(matches!(e, LinkError::NoHeader { bytes: 0, .. }), "{e}");
        assert!(t0.elapsed() < Duration::from_secs(5), "{:?}", t0.elapsed());
        // Flag still set: a reception under way is not interrupted (it ends
        // by its own rule: the idle timeout of this short peer).
        let o = LinkOptions {
            idle_timeout: Duration::from_millis(300),
            ..o
        };
        let e = run_with(encode(&Frame::Header(header()), 0), &o);
        assert!(matches!(e, LinkError::Incomplete(_)), "{e}");
    }

    fn run_with(input: Vec<u8>, o: &LinkOptions) -> LinkError {
        let mut p = Peer {
            input: std::io::Cursor::new(input),
            writes_stall: false,
        };
        receive_from(&mut p, o).unwrap_err()
    }

    #[test]
    fn a_peer_that_stops_reading_is_a_stalled_link() {
        let e = run(encode(&Frame::Header(header()), 0), true, true);
        assert!(matches!(e, LinkError::Stalled { .. }), "{e}");
        assert!(e.to_string().contains("write timed out"), "{e}");
    }

    #[test]
    fn a_header_is_validated_on_arrival() {
        let mut h = header();
        h.mas_total = 0.0;
        let e = run(encode(&Frame::Header(h), 0), false, true).to_string();
        assert!(
            e.contains("refused at its header") && e.contains("mas_total"),
            "{e}"
        );
        let mut h = header();
        h.rows = 4095;
        let e = run(encode(&Frame::Header(h), 0), false, true).to_string();
        assert!(
            e.contains("announces 4095 rows") && e.contains("375"),
            "{e}"
        );
        // Without a site configuration only the codec's checks apply.
        let e = run(encode(&Frame::Header(header()), 0), false, false);
        assert!(
            matches!(e, LinkError::Incomplete(ref v) if v.len() == 25),
            "{e}"
        );
    }

    /// A stream from another system than the configured one is refused at
    /// its header, naming both; the configured system's budget (its
    /// detector) applies.
    #[test]
    fn a_stream_from_another_system_is_refused_naming_both() {
        let g = Geometry::builtin("paper-tall").unwrap().binned(4).unwrap();
        let fan = Gantry::fan(&g, 0.11);
        let cone = Gantry {
            cone: Some(
                ConeSystem::builtin("paper-cone")
                    .unwrap()
                    .binned(4)
                    .unwrap(),
            ),
            ..fan.clone()
        };
        let go = |h: H, site: &Gantry| {
            run_with(
                encode(&Frame::Header(h), 0),
                &LinkOptions::new(Duration::from_millis(300)).for_site(site),
            )
        };
        let mut h = header();
        h.system = Some("paper-cone".into());
        let e = go(h.clone(), &fan).to_string();
        assert!(
            e.contains("cone-beam system `paper-cone`") && e.contains("slice-wise fan-beam"),
            "{e}"
        );
        let e = go(header(), &cone).to_string();
        assert!(
            e.contains("is from the slice-wise fan-beam")
                && e.contains("configured for cone-beam system `paper-cone`"),
            "{e}"
        );
        let mut other = h.clone();
        other.system = Some("siemens-victre".into());
        let e = go(other, &cone).to_string();
        assert!(
            e.contains("`siemens-victre`") && e.contains("`paper-cone`"),
            "{e}"
        );
        // The right system: its detector's rows and columns are the budget.
        h.rows = 250;
        let e = go(h.clone(), &cone);
        assert!(
            matches!(e, LinkError::Incomplete(ref v) if v.len() == 25),
            "{e}"
        );
        h.rows = 251;
        let e = go(h, &cone).to_string();
        assert!(e.contains("announces 251 rows") && e.contains("250"), "{e}");
        // An exposure the dose model has no spectra for, stated in the header.
        let mut h = header();
        h.anode_filter = Some("Rh/Ag".into());
        let e = go(h.clone(), &fan).to_string();
        assert!(
            e.contains("anode/filter Rh/Ag") && e.contains("W/Rh, W/Al, W/Ag, Mo/Mo, Mo/Rh, Rh/Rh"),
            "{e}"
        );
        for ok in ["W/Rh", "W/Al", "W/Ag", "Mo/Mo", "Mo/Rh", "Rh/Rh"] {
            h.anode_filter = Some(ok.into());
            assert!(matches!(go(h.clone(), &fan), LinkError::Incomplete(_)));
        }
        // The stated beam reaches the acquisition's header.
        h.anode_filter = Some("W/Al".into());
        let site = Gantry::fan(&dbt_geometry::Geometry::paper(), 0.11);
        assert_eq!(domain_header(&h, &site, 1e4).anode_filter, AnodeFilter::WAl);
        h.anode_filter = None;
        assert_eq!(domain_header(&h, &site, 1e4).anode_filter, AnodeFilter::WRh);
    }

    /// One CRC error per frame must not write one log line each: at most one
    /// a second, the rest counted.
    #[test]
    fn log_lines_are_rate_limited_and_counted() {
        let mut l = LogLimiter::default();
        assert_eq!(l.allow(), Some(0));
        for _ in 0..1000 {
            assert_eq!(l.allow(), None);
        }
        assert_eq!(l.suppressed, 1000);
        l.last = Some(std::time::Instant::now() - Duration::from_millis(1100));
        assert_eq!(
            l.allow(),
            Some(1000),
            "the next line reports what was suppressed"
        );
    }

    /// Garbage then silence is the idle case (no header), not "bytes keep
    /// arriving", however late the receiver first reads them (a loaded
    /// machine: the no-progress clock starts at the first byte, not at the
    /// start).
    #[test]
    fn headerless_bytes_are_a_fault_and_silence_is_not() {
        let e = run(vec![0x55; 100], false, true);
        assert!(matches!(e, LinkError::NoHeader { bytes: 100, .. }), "{e}");
        let e = run(vec![], false, true);
        assert!(matches!(e, LinkError::NoHeader { bytes: 0, .. }), "{e}");
        // The receiver reaches its first read only after the idle timeout
        // (a loaded machine), the garbage waiting for it, then silence.
        struct Late(Peer, bool);
        impl Read for Late {
            fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
                if !std::mem::replace(&mut self.1, true) {
                    std::thread::sleep(Duration::from_millis(400));
                }
                self.0.read(buf)
            }
        }
        impl Write for Late {
            fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
                self.0.write(buf)
            }
            fn flush(&mut self) -> std::io::Result<()> {
                self.0.flush()
            }
        }
        let mut late = Late(
            Peer {
                input: std::io::Cursor::new(vec![0x55; 100]),
                writes_stall: false,
            },
            false,
        );
        let e = receive_from(&mut late, &LinkOptions::new(Duration::from_millis(300))).unwrap_err();
        assert!(matches!(e, LinkError::NoHeader { bytes: 100, .. }), "{e}");
    }
}
