//! The acquisition daemon's loop: receive from the gantry, spool
//! (`crate::spool`), settle (`dbt_intake::settle`), process, deliver, and
//! keep a status file for the diagnostics CLI.
//!
//! At start every `incoming/` entry of the spool is processed first.
//! Processing an entry is idempotent: the report file names come from the
//! entry id and the DICOM UIDs from a seed fixed by the id, so an entry
//! processed again after a crash (between delivery and the move to `done/`)
//! rewrites the same two reports: every acquisition is reported exactly
//! once.

use crate::assembly::load_model;
use crate::config::{Config, FrameTransport, ModbusTransport, Reconstructor};
use crate::link::{data_fault, receive, receive_from, to_acquisition, LinkError, LinkOptions};
use crate::modbus::{read_registers, ModbusLink};
use crate::spool::{entry_id, write_durable, Spool};
use crate::status_page::{StateReader, StatusServer, PICTURE_FILE};
use dbt_dicom::{Equipment, UidSource};
use dbt_intake::{GantryNote, RegisterReading, RegisterValues, Source};
use dbt_pipeline::{process, reports, PipelineOptions};
use dbt_status::{AcquisitionRecord, FaultRecord, Status};
use dbt_store::acquisition::read_acquisition;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Errors that stop the daemon (everything else is a fault record).
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    /// The spool or status folder is unusable.
    #[error("{path}: {cause}")]
    Io {
        /// Where.
        path: PathBuf,
        /// Why.
        cause: std::io::Error,
    },
    /// A resource the daemon needs is missing or unusable.
    #[error("{what}: {reason}")]
    Resource {
        /// The resource (a configuration key and its value).
        what: String,
        /// Why it cannot be used.
        reason: String,
    },
    /// Bad configuration.
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
    /// The processing could not be assembled from the configuration (the
    /// model folder's sign-off, network or calibration among it).
    #[error(transparent)]
    Assembly(#[from] crate::assembly::AssemblyError),
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> DaemonError + '_ {
    move |source| DaemonError::Io {
        path: path.to_path_buf(),
        cause: source,
    }
}

fn now_unix() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0)
}

/// Check everything the daemon will need without starting it (`dbtor-daemon
/// --check-config`): the model folder against its sign-off and the
/// configured digest, the model and its calibration load, the spool, output
/// and status folders are writable, and the serial devices exist. Returns
/// one line per check passed; the first failure is the error.
pub fn preflight(cfg: &Config, config_path: &Path) -> Result<Vec<String>, DaemonError> {
    let mut done = Vec::new();
    let geom = cfg.gantry_geometry(config_path)?;
    done.push(format!("geometry: {}", geom.describe()));
    if let Some(s) = cfg.gantry_system(config_path)? {
        done.push(format!(
            "cone-beam system: {} ({} views, {} x {} elements of {} mm, {} detector), rebinned to the geometry above",
            s.name,
            s.n_views(),
            s.detector.columns,
            s.detector.rows,
            s.detector.pitch_mm,
            match s.detector_motion {
                dbt_geometry::DetectorMotion::Rotating => "rotating",
                dbt_geometry::DetectorMotion::Stationary => "stationary",
                dbt_geometry::DetectorMotion::Tilting => "tilting",
            }
        ));
    }
    if cfg.recon.reconstructor == Reconstructor::Dbtor {
        let signed = load_model(cfg, &PipelineOptions::default().classify)?;
        if let Some(m) = crate::assembly::noise_match(cfg, signed.model.manifest())? {
            done.push(format!(
                "noise matching: to the model's training level, {} photons per element",
                m.target_photons
            ));
        }
        done.push(format!(
            "model: {} ({}), {} files match the sign-off {}, calibration {}",
            signed.model.manifest().name,
            signed.model.precision_label(),
            signed.signoff.files.len(),
            signed.signoff.digest,
            if signed.calibration.is_some() {
                "loaded"
            } else {
                "none (reported uncalibrated)"
            }
        ));
    }
    for (key, d) in [
        ("paths.spool", cfg.paths.spool.clone()),
        ("paths.output", cfg.paths.output.clone()),
        (
            "paths.status",
            cfg.paths
                .status
                .parent()
                .map(Path::to_path_buf)
                .unwrap_or_default(),
        ),
    ] {
        let fail = |e: std::io::Error| DaemonError::Resource {
            what: format!("{key} = {}", d.display()),
            reason: format!("not a writable folder: {e}"),
        };
        std::fs::create_dir_all(&d).map_err(fail)?;
        let probe = d.join(format!(".dbtor-preflight-{}", std::process::id()));
        std::fs::write(&probe, b"probe").map_err(fail)?;
        let _ = std::fs::remove_file(&probe);
        done.push(format!("{key}: {} writable", d.display()));
    }
    let mut devices = Vec::new();
    if cfg.frames.transport == FrameTransport::Serial {
        devices.push(("frames.port", cfg.frames.port.clone().unwrap_or_default()));
    }
    if cfg.modbus.transport == ModbusTransport::Rtu {
        devices.push(("modbus.port", cfg.modbus.port.clone().unwrap_or_default()));
    }
    for (key, dev) in devices {
        if !Path::new(&dev).exists() {
            return Err(DaemonError::Resource {
                what: format!("{key} = {dev}"),
                reason: "no such device".into(),
            });
        }
        done.push(format!("{key}: {dev} present"));
    }
    Ok(done)
}

/// The daemon.
pub struct Daemon {
    cfg: Config,
    config_path: PathBuf,
    /// The site's gantry (geometry, cone-beam system, tube output).
    gantry: dbt_intake::Gantry,
    /// Where every received acquisition is kept.
    spool: Spool,
    opts: PipelineOptions,
    stop: Arc<AtomicBool>,
    status: Status,
    /// Since when the gantry's frame server refuses connections.
    unreachable_since: Option<Instant>,
    /// When that was last recorded as a fault.
    unreachable_logged: Option<Instant>,
    /// When the outbox was last flushed while waiting.
    last_flush: Option<Instant>,
    /// The status page's server, if it serves (stops with the daemon).
    _status_page: Option<StatusServer>,
    /// The DICOM input's thread, if on, and the faults it reports.
    dicom: Option<crate::dicom_input::DicomInput>,
    /// Spool entries processed (or tried) in this run.
    attempted: std::collections::HashSet<String>,
    /// Set by the DICOM input on every change (an object, a spooled sweep,
    /// an association): the loop then publishes the status and takes new
    /// entries, also while it waits for the frame link.
    wake: Arc<AtomicBool>,
}

/// Why an acquisition did not reach the spool: a fault of `kind` (`link`:
/// not received, not opened or rejected; `spool`: not written), with its
/// message and the acquisition's id where it had one.
#[derive(Debug)]
struct ReceiveFault {
    kind: &'static str,
    message: String,
    acquisition: Option<String>,
}

impl ReceiveFault {
    fn link(message: String) -> Self {
        Self {
            kind: "link",
            message,
            acquisition: None,
        }
    }
}

impl Daemon {
    /// Prepare: folders, model (checksums verified), status file.
    pub fn new(
        cfg: Config,
        config_path: PathBuf,
        stop: Arc<AtomicBool>,
    ) -> Result<Self, DaemonError> {
        let gantry = cfg.gantry(&config_path)?;
        let opts = crate::assembly::pipeline_options(&cfg, &config_path)?;
        let reconstructor = dbt_pipeline::reconstructor_name(&opts);
        let spool = Spool::open(&cfg.paths.spool)
            .map_err(|(path, cause)| DaemonError::Io { path, cause })?;
        std::fs::create_dir_all(&cfg.paths.output).map_err(io(&cfg.paths.output))?;
        if let Some(d) = cfg.paths.status.parent() {
            std::fs::create_dir_all(d).map_err(io(d))?;
        }
        let mut status = Status::starting(
            env!("CARGO_PKG_VERSION"),
            std::process::id(),
            now_unix(),
            reconstructor,
        );
        // How the kernels were chosen (issue #52): measured at the model's
        // load, or forced.
        status.kernels = match &opts.dbtor {
            Some(m) if !m.kernel_measurements().is_empty() => m.kernel_measurements().to_vec(),
            Some(m) => vec![match m.kernel() {
                Some(k) => format!("{k} (forced by {}, not measured)", dbt_dbtor::KERNEL_ENV),
                None => "the tract engine (no fast kernels to choose)".into(),
            }],
            None => vec![],
        };
        // The status page: a bind failure is a fault, not a reason to stop
        // reporting.
        let mut page_fault = None;
        let status_page = match cfg.status_page_address(&config_path)? {
            None => None,
            Some(addr) => {
                let reader =
                    StateReader::new(cfg.paths.status.clone(), Some(cfg.paths.spool.clone()));
                match StatusServer::start(addr, reader, Arc::clone(&stop)) {
                    Ok(srv) => {
                        tracing::info!(address = %srv.addr(), "status page served");
                        status.status_page = Some(format!("http://{}/", srv.addr()));
                        Some(srv)
                    }
                    Err(e) => {
                        page_fault = Some(format!(
                            "status_page.address {addr}: cannot serve the status page: {e}"
                        ));
                        None
                    }
                }
            }
        };
        let mut d = Self {
            cfg,
            config_path,
            gantry,
            spool,
            opts,
            stop,
            status,
            unreachable_since: None,
            unreachable_logged: None,
            last_flush: None,
            _status_page: status_page,
            dicom: None,
            attempted: Default::default(),
            wake: Arc::new(AtomicBool::new(false)),
        };
        if let Some(di) = d.cfg.dicom_input(&d.config_path)? {
            let settings = crate::dicom_input::InputSettings {
                ae_title: di.ae_title.clone(),
                spool: d.cfg.paths.spool.clone(),
                system: dbt_intake::Gantry {
                    flux: Some(di.flat_field_counts),
                    ..d.gantry.clone()
                },
                quiet_time: di.quiet_time,
                max_associations: di.max_associations,
                private: di.private.clone(),
            };
            let input = crate::dicom_input::DicomInput::start(
                di.address,
                settings,
                Arc::clone(&d.stop),
                Arc::clone(&d.wake),
            )
            .map_err(|e| DaemonError::Resource {
                what: format!("dicom_input.address = {}", di.address),
                reason: e.to_string(),
            })?;
            tracing::info!(address = %input.addr(), "DICOM input listening");
            d.status.dicom_input = Some(input.status());
            d.dicom = Some(input);
        }
        d.publish("starting", None);
        if let Some(msg) = page_fault {
            d.fault(None, "status_page", msg);
        }
        Ok(d)
    }

    fn publish(&mut self, state: &str, current: Option<&str>) {
        if let Some(input) = &self.dicom {
            for f in input.drain() {
                tracing::error!(acquisition = f.acquisition, kind = %f.kind, message = %f.message, "fault");
                self.status.push_fault(f);
            }
            self.status.dicom_input = Some(input.status());
        }
        self.status.state = state.into();
        self.status.current = current.map(String::from);
        self.status.updated_unix = now_unix();
        self.status.peak_rss_mib = dbt_cli::peak_rss_mib();
        self.status.incoming = self.incoming().map(|v| v.len()).unwrap_or(0);
        let path = self.cfg.paths.status.clone();
        match serde_json::to_vec_pretty(&self.status) {
            Ok(bytes) => {
                if let Err(e) = write_durable(&path, &bytes) {
                    tracing::error!(path = %path.display(), %e, "cannot write the status file");
                }
            }
            Err(e) => tracing::error!(%e, "cannot encode the status"),
        }
    }

    fn fault(&mut self, acquisition: Option<&str>, kind: &str, message: String) {
        tracing::error!(acquisition, kind, %message, "fault");
        self.status.push_fault(FaultRecord {
            at_unix: now_unix(),
            acquisition: acquisition.map(String::from),
            kind: kind.into(),
            message,
        });
        let state = self.status.state.clone();
        let current = self.status.current.clone();
        self.publish(&state, current.as_deref());
    }

    /// While the daemon waits for the frame link: if the DICOM input changed
    /// something, show it (publish the status); whether it spooled entries
    /// to process.
    fn dicom_spooled(&mut self) -> bool {
        if !self.wake.swap(false, Ordering::SeqCst) {
            return false;
        }
        let state = self.status.state.clone();
        self.publish(&state, None);
        !self.new_entries().is_empty()
    }

    /// `incoming/` entries not yet tried in this run.
    fn new_entries(&self) -> Vec<String> {
        self.incoming()
            .unwrap_or_default()
            .into_iter()
            .filter(|id| !self.attempted.contains(id))
            .collect()
    }

    fn incoming(&self) -> std::io::Result<Vec<String>> {
        self.spool.incoming()
    }

    /// While waiting for the gantry, send the reports that wait in the
    /// outbox (the PACS was down) every 10 s, so they do not wait for the
    /// next acquisition.
    fn flush_outbox(&mut self) {
        if self
            .last_flush
            .is_some_and(|t| t.elapsed() < Duration::from_secs(10))
        {
            return;
        }
        self.last_flush = Some(Instant::now());
        let (outbox, pacs) = match self.outbox() {
            Ok((o, Some(p))) => (o, p),
            Ok((_, None)) => return,
            Err(e) => {
                tracing::warn!(%e, "outbox unreadable");
                return;
            }
        };
        if outbox.pending().map(|v| v.is_empty()).unwrap_or(true) {
            return;
        }
        match outbox.flush(&pacs) {
            Ok(r) if !r.sent.is_empty() => {
                tracing::info!(
                    sent = r.sent.len(),
                    waiting = r.waiting.len(),
                    "outbox flushed"
                )
            }
            Ok(_) => {}
            Err(e) => tracing::debug!(%e, "outbox not flushed"),
        }
    }

    /// The output folder's outbox and the configured PACS, if any.
    fn outbox(&self) -> Result<(dbt_pacs::Outbox, Option<dbt_pacs::PacsConfig>), String> {
        let outbox = dbt_pacs::Outbox::open(
            &self.cfg.paths.output,
            &self.cfg.paths.output.join("outbox"),
        )
        .map_err(|e| e.to_string())?;
        let pacs = match &self.cfg.report.pacs {
            Some(p) => Some(dbt_pacs::PacsConfig::parse(p).map_err(|e| e.to_string())?),
            None => None,
        };
        Ok((outbox, pacs))
    }

    /// Faults recorded since start.
    pub fn fault_count(&self) -> u64 {
        self.status.fault_total()
    }

    /// Run until SIGTERM (the stop flag): recover the spool, then receive and
    /// process acquisitions. With `once`, return after one acquisition.
    pub fn run(&mut self, once: bool) -> Result<(), DaemonError> {
        let _span = tracing::info_span!("daemon", config = %self.config_path.display()).entered();
        self.publish("recovering", None);
        let pending = self.incoming().map_err(io(&self.cfg.paths.spool))?;
        if !pending.is_empty() {
            tracing::info!(entries = pending.len(), "recovering spooled acquisitions");
        }
        for id in pending {
            if self.stop.load(Ordering::SeqCst) {
                break;
            }
            self.attempted.insert(id.clone());
            self.process_entry(&id);
            self.status.recovered += 1;
        }
        while !self.stop.load(Ordering::SeqCst) {
            // Entries the DICOM input spooled meanwhile (each tried once per
            // run: one whose delivery failed stays for the next start).
            self.wake.store(false, Ordering::SeqCst);
            let new = self.new_entries();
            if !new.is_empty() {
                for id in new {
                    if self.stop.load(Ordering::SeqCst) {
                        break;
                    }
                    self.attempted.insert(id.clone());
                    self.process_entry(&id);
                }
                if once {
                    break;
                }
                continue;
            }
            self.publish("waiting", None);
            match self.receive_one() {
                Ok(Some(id)) => {
                    self.process_entry(&id);
                    if once {
                        break;
                    }
                }
                Ok(None) => {}
                Err(f) => {
                    self.fault(f.acquisition.as_deref(), f.kind, f.message);
                    if once {
                        break;
                    }
                }
            }
        }
        self.publish("stopped", None);
        Ok(())
    }

    /// Wait for the gantry, receive one acquisition, spool it. `Ok(None)`:
    /// nothing arrived (or stop); `Err`: the fault that kept it from the
    /// spool, for the caller to record (nothing was spooled).
    fn receive_one(&mut self) -> Result<Option<String>, ReceiveFault> {
        let link = LinkOptions {
            stop: Some(Arc::clone(&self.stop)),
            // Before the first byte, the DICOM input's work goes first.
            yield_to: self.dicom.as_ref().map(|_| Arc::clone(&self.wake)),
            ..LinkOptions::new(self.cfg.idle_timeout()).for_site(&self.gantry)
        };
        if self.cfg.frames.transport == FrameTransport::Off {
            // DICOM input only: wait for it (or SIGTERM), sending what waits
            // in the outbox meanwhile.
            while !self.stop.load(Ordering::SeqCst) {
                if self.dicom_spooled() {
                    break;
                }
                self.flush_outbox();
                std::thread::sleep(Duration::from_millis(100));
            }
            return Ok(None);
        }
        let received = if self.cfg.frames.transport == FrameTransport::Tcp {
            let addr = self.cfg.frames.address.clone().unwrap_or_default();
            let mut stream = loop {
                if self.stop.load(Ordering::SeqCst) {
                    return Ok(None);
                }
                match std::net::TcpStream::connect(&addr) {
                    Ok(s) => {
                        self.unreachable_since = None;
                        break s;
                    }
                    Err(e) => {
                        if self.dicom_spooled() {
                            return Ok(None);
                        }
                        self.flush_outbox();
                        // Quiet while the gantry is off; a fault once the
                        // link has been down for the idle timeout, then a
                        // warning every 10 minutes.
                        let since = *self.unreachable_since.get_or_insert_with(Instant::now);
                        let down = since.elapsed();
                        if down > self.cfg.idle_timeout()
                            && self
                                .unreachable_logged
                                .is_none_or(|t| t.elapsed() > Duration::from_secs(600))
                        {
                            self.unreachable_logged = Some(Instant::now());
                            self.fault(
                                None,
                                "link",
                                format!(
                                    "gantry frame server {addr} unreachable for {:.0} s: {e}",
                                    down.as_secs_f64()
                                ),
                            );
                        } else {
                            tracing::debug!(%addr, %e, "gantry frame server not reachable");
                        }
                        std::thread::sleep(Duration::from_millis(200));
                    }
                }
            };
            let gantry = self.read_gantry();
            self.publish("receiving", None);
            (receive(&mut stream, &link), gantry)
        } else {
            let port = self.cfg.frames.port.clone().unwrap_or_default();
            let opened = serialport::new(&port, self.cfg.frames.baud)
                .timeout(Duration::from_millis(200))
                .open();
            let mut s = match opened {
                Ok(s) => s,
                Err(e) => {
                    std::thread::sleep(Duration::from_secs(1));
                    return Err(ReceiveFault::link(format!(
                        "opening serial line {port}: {e}"
                    )));
                }
            };
            let gantry = self.read_gantry();
            self.publish("receiving", None);
            (receive_from(&mut s, &link), gantry)
        };
        let ((rx, stats), gantry) = match received {
            (Ok(r), g) => (r, g),
            // Nothing at all arrived (the gantry connected and left), or stop.
            (Err(LinkError::NoHeader { bytes: 0, .. }), _) | (Err(LinkError::Stopped), _) => {
                return Ok(None)
            }
            (Err(e), _) => {
                return Err(ReceiveFault::link(format!("acquisition not received: {e} (nothing spooled; the gantry keeps it for a resend)")));
            }
        };
        let acq = to_acquisition(&rx, &self.gantry)
            .map_err(|e| ReceiveFault::link(format!("acquisition rejected: {e}")))?;
        let id = entry_id(&acq.header.patient.id);
        // The beam is settled from the note at processing
        // (`dbt_intake::settle`), and the settled header written back.
        let note = GantryNote {
            source: Source::Frames,
            link: Some(stats),
            saturated_pixels: Some(rx.saturated as u64),
            modbus: gantry,
            modbus_end: self.read_gantry(),
            header_anode_filter: rx.header.anode_filter.clone(),
            data_fault: data_fault(&rx),
            ..Default::default()
        };
        match self.spool.write(&id, &acq, &note) {
            Ok(()) => {
                tracing::info!(acquisition = %id, slices = acq.header.slices, "spooled");
                Ok(Some(id))
            }
            Err(e) => Err(ReceiveFault {
                message: format!("cannot spool: {e}"),
                kind: "spool",
                acquisition: Some(id),
            }),
        }
    }

    /// The registers now (`None` when Modbus is off; why not, when
    /// unreadable).
    fn read_gantry(&mut self) -> Option<RegisterReading> {
        if self.cfg.modbus.transport == ModbusTransport::Off {
            return None;
        }
        let endpoint = match self.cfg.modbus_endpoint(&self.config_path) {
            Ok(a) => a,
            Err(e) => {
                return Some(RegisterReading::Failed {
                    error: e.to_string(),
                })
            }
        };
        let link = ModbusLink {
            unit: self.cfg.modbus.unit,
            base: self.cfg.modbus.base,
            timeout: Duration::from_millis(self.cfg.modbus.timeout_ms),
            attempts: self.cfg.modbus.attempts,
            ..ModbusLink::with_endpoint(endpoint)
        };
        Some(match read_registers(&link) {
            Ok(r) => RegisterReading::Read(RegisterValues::from(&r)),
            Err(e) => RegisterReading::Failed {
                error: e.to_string(),
            },
        })
    }

    fn move_entry(&mut self, id: &str, to: &str, note_name: &str, note: &impl serde::Serialize) {
        if let Err(e) = self.spool.move_entry(id, to, note_name, note) {
            self.fault(Some(id), "spool", format!("cannot move to {to}/: {e}"));
        }
    }

    /// Record a fault for entry `id` and keep it in `faulted/` with the reason.
    fn reject(&mut self, id: &str, kind: &str, msg: String) {
        self.fault(Some(id), kind, msg.clone());
        let note = serde_json::json!({"kind": kind, "message": msg});
        self.move_entry(id, "faulted", "fault.json", &note);
    }

    /// Check, process and deliver one spooled acquisition.
    fn process_entry(&mut self, id: &str) {
        let _span = tracing::info_span!("acquisition", id).entered();
        self.publish("processing", Some(id));
        let dir = self.spool.incoming_entry(id);
        let acq = match read_acquisition(&dir) {
            Ok(a) => a,
            Err(e) => {
                let msg = format!("spooled acquisition refused: {e}");
                self.reject(id, "input", msg);
                return;
            }
        };
        let spooled = acq.header.clone();
        // What the link saw at receipt (the registers at the start and the
        // end of the sweep, the stream header's beam, a data fault).
        let note = match self.spool.note(id) {
            Ok(n) => n,
            Err(e) => {
                self.reject(
                    id,
                    "input",
                    format!("the entry's gantry note (gantry.json) is unreadable: {e}"),
                );
                return;
            }
        };
        let acq = match dbt_intake::settle(acq, &note, &self.cfg.site_policy()) {
            Ok(a) => a,
            Err(r) => {
                self.reject(id, r.kind.name(), r.message);
                return;
            }
        };
        // What was settled here (the beam, the tube output at the
        // exposure's kV, the force) goes into the spooled header, so that
        // `dbtor-diag replay` and `dbtor-process` on the entry compute what
        // the daemon reports.
        if acq.header != spooled {
            let h = dir.join("acquisition.json");
            let written = serde_json::to_vec_pretty(&acq.header)
                .map_err(std::io::Error::other)
                .and_then(|b| write_durable(&h, &b));
            if let Err(e) = written {
                tracing::warn!(path = %h.display(), error = %e, "the settled header was not written back; a replay of this entry may differ");
            }
        }
        let t0 = Instant::now();
        let res = match process(&acq, &self.opts) {
            Ok(r) => r,
            Err(e) => {
                // Physically impossible data are named apart from failures
                // of the processing itself; both keep the entry in faulted/.
                let kind = match e {
                    dbt_pipeline::PipelineError::Implausible(_)
                    | dbt_pipeline::PipelineError::Header(_) => "implausible",
                    _ => "processing",
                };
                self.reject(id, kind, e.to_string());
                return;
            }
        };
        // UIDs fixed by the entry: a re-run after a crash rewrites the same reports.
        let seed: u64 = id
            .split('-')
            .next()
            .and_then(|s| s.parse().ok())
            .unwrap_or(1);
        // The quick-look picture for the status page, kept with the entry.
        let caption = format!(
            "acquisition {}: {} mm, {}",
            dbt_status::public_id(id),
            acq.header.thickness_mm,
            res.reconstructor
        );
        match dbt_status::picture::quicklook(
            &res.mu,
            &res.classification.labels,
            res.dims,
            res.voxel_mm,
            &caption,
        ) {
            Ok(svg) => {
                if let Err(e) = write_durable(&dir.join(PICTURE_FILE), svg.as_bytes()) {
                    tracing::warn!(%e, "cannot keep the quick-look picture");
                }
            }
            Err(e) => tracing::warn!(%e, "no quick-look picture"),
        }
        let delivered = (|| -> Result<AcquisitionRecord, String> {
            let mut uids =
                UidSource::new(&self.cfg.report.uid_root, seed).map_err(|e| e.to_string())?;
            let equipment = Equipment {
                manufacturer: "DBToR".into(),
                model: "DBToR gantry PC".into(),
                serial: self.cfg.report.device_serial.clone(),
                software_version: env!("CARGO_PKG_VERSION").into(),
                device_uid: format!("{}.9.1", self.cfg.report.uid_root),
            };
            let (date, time) = dicom_now();
            let (dose, dens) = reports(&acq, &res, &equipment, &mut uids, &date, &time)
                .map_err(|e| e.to_string())?;
            let (outbox, pacs) = self.outbox()?;
            let mut waiting = Vec::new();
            for (name, r) in [("dose-sr", &dose), ("density-sr", &dens)] {
                let bytes = r.to_bytes().map_err(|e| e.to_string())?;
                let rep = outbox
                    .deliver(&format!("{id}-{name}"), &bytes, pacs.as_ref())
                    .map_err(|e| e.to_string())?;
                waiting.extend(
                    rep.waiting
                        .into_iter()
                        .map(|(p, e)| format!("{}: {e}", p.display())),
                );
            }
            // The density SR's volumetric fraction and composition category
            // (dbt_pipeline::reports builds the SR from the same values).
            let vf =
                res.density.fibroglandular_partial_volume_cm3 / res.density.breast_cm3.max(1.0);
            Ok(AcquisitionRecord {
                acquisition: id.to_string(),
                patient_id: acq.header.patient.id.clone(),
                reconstructor: res.reconstructor.clone(),
                thickness_mm: Some(acq.header.thickness_mm),
                glandularity_labels: res.density.glandularity_labels,
                glandularity_partial_volume: res.density.glandularity_partial_volume,
                glandularity_reported: res.glandularity,
                calibrated: res.calibrated,
                volumetric_fraction: Some(vf),
                // No category where the physics did not confirm the
                // density (the SR gives none either).
                composition: res
                    .density_check
                    .confirmed
                    .then(|| dbt_dicom::composition_category(vf).0.to_string()),
                mgd_mgy: res.mgd_mgy,
                model_mgd_mgy: res.model_mgd_mgy,
                seconds: t0.elapsed().as_secs_f64(),
                finished_unix: now_unix(),
                reports: vec![format!("{id}-dose-sr.dcm"), format!("{id}-density-sr.dcm")],
                pacs_waiting: waiting,
                // Defective counts corrected before the reconstruction;
                // a density the physics did not confirm.
                flags: res
                    .flags
                    .iter()
                    .cloned()
                    .chain((!res.density_check.confirmed).then(|| {
                        format!(
                            "{}: {}",
                            dbt_status::DENSITY_CHECK_WARNING,
                            res.density_check.reasons.join("; ")
                        )
                    }))
                    .collect(),
                density_check: Some(res.density_check.report()),
                glandularity_interval: Some(res.intervals.glandularity.clone()),
                mgd_interval: Some(res.intervals.mgd.clone()),
            })
        })();
        match delivered {
            Ok(summary) => {
                if let Some(w) = Some(&summary.pacs_waiting).filter(|w| !w.is_empty()) {
                    self.fault(
                        Some(id),
                        "delivery",
                        format!("reports kept in the outbox for a later send: {w:?}"),
                    );
                }
                tracing::info!(
                    acquisition = id,
                    mgd_mgy = res.mgd_mgy,
                    g = res.glandularity,
                    "reported"
                );
                match serde_json::to_value(&summary) {
                    Ok(note) => self.move_entry(id, "done", "result.json", &note),
                    Err(e) => {
                        self.fault(Some(id), "spool", format!("cannot encode the result: {e}"))
                    }
                }
                self.status.push_reported(summary);
            }
            Err(msg) => {
                // Left in incoming/: retried at the next start.
                self.fault(Some(id), "delivery", msg);
            }
        }
        self.publish("processed", Some(id));
    }
}

fn dicom_now() -> (String, String) {
    dbt_dicom::dicom_datetime_utc(now_unix())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn content_date_is_today() {
        let (d, t) = dicom_now();
        assert_eq!(d.len(), 8);
        assert_eq!(t.len(), 6);
        assert!(d.as_str() >= "20240101");
    }
}
