//! The daemon's DICOM input (issue #31): a thread accepting associations on
//! `[dicom_input] address`, each served on its own thread (at most
//! `max_associations` at once) by the Storage SCP (`dbt_pacs::scp`).
//!
//! What it takes (`dbt_dicom::input::read_input_object`):
//! * a Breast Projection X-Ray For Processing object: the whole sweep, made
//!   an acquisition on the configured system (`dbt_pipeline::dicom_input`)
//!   and spooled durably (`spool::spool_entry`) before the C-STORE is
//!   answered Success;
//! * one object per view (Digital Mammography X-Ray For Processing, or a
//!   configured private class): each checked against the system and the
//!   sweep's first view, kept durably in `views/<sweep>/<view>.dcm` before
//!   Success, grouped by study, laterality and view; the sweep is spooled
//!   when every configured view is in, and faulted as incomplete (moved to
//!   `faulted/`) when no view of it came for the quiet time.
//!
//! An object that cannot be used is answered with a failure status naming
//! why, kept in `faulted/<id>/` (the object, or the data set as received,
//! and `fault.json`), and reported as an `input` fault. A copy of an object
//! already kept (same SOP instance, or the same view with the same counts)
//! is answered Success without a second acquisition; a copy with other
//! counts is refused. A restart reloads what was kept: the sweeps waiting
//! for views (their quiet time starts again) and the objects already spooled.

use crate::spool::{entry_id, spool_entry, write_durable};
use dbt_dicom::input::{for_presentation_classes, read_input_object, Layout, Mapping};
use dbt_dicom::projections::ReceivedProjections;
use dbt_intake::{GantryNote, Source};
use dbt_pacs::scp::{
    serve_association, Unreadable, Verdict, STATUS_CANNOT_UNDERSTAND, STATUS_OUT_OF_RESOURCES,
};
use dbt_pipeline::dicom_input::{
    acquisition_from_projections, assemble, check_object, check_same_sweep, group_key, view_index,
};
use dbt_status::{DicomInputStatus, FaultRecord, WaitingSweep};
use std::collections::{BTreeMap, HashMap};
use std::net::{SocketAddr, TcpListener};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// The input's settings.
#[derive(Debug, Clone)]
pub struct InputSettings {
    /// Our AE title.
    pub ae_title: String,
    /// The spool folder.
    pub spool: PathBuf,
    /// The configured system.
    pub system: dbt_intake::Gantry,
    /// How long a sweep waits for a view.
    pub quiet_time: Duration,
    /// Associations served at once.
    pub max_associations: usize,
    /// Private classes.
    pub private: Vec<Mapping>,
}

/// The running input.
pub struct DicomInput {
    shared: Arc<Shared>,
    /// Ends with the daemon's stop flag (not joined: an association in
    /// progress would hold the daemon's stop).
    _thread: std::thread::JoinHandle<()>,
    addr: SocketAddr,
    listening: String,
}

/// What the threads share with the daemon.
struct Shared {
    state: Mutex<State>,
    faults: Mutex<Vec<FaultRecord>>,
    counters: Mutex<DicomInputStatus>,
    open: AtomicU64,
    /// Set on every change the daemon should see (a spooled sweep, a view,
    /// an association); the daemon's loop takes it.
    wake: Arc<AtomicBool>,
}

/// Objects already kept and sweeps waiting for views.
struct State {
    settings: InputSettings,
    /// SOP instance -> digest of its counts, for every object kept.
    seen: HashMap<String, u64>,
    /// Sweeps waiting for views, by `group_key`.
    groups: BTreeMap<String, Group>,
}

/// A sweep sent one object per view, not complete yet.
struct Group {
    dir: PathBuf,
    /// The first view's attributes (counts dropped): what every other view
    /// must agree with.
    first: ReceivedProjections,
    /// View index -> (SOP instance, counts digest).
    views: BTreeMap<usize, (String, u64)>,
    last: Instant,
    last_unix: u64,
}

fn now_unix() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0)
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A thread that panicked holding the lock leaves consistent data here
    // (every change is complete before the next statement).
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// The SOP classes accepted on an association: the For Processing ones, the
/// private ones configured, and the For Presentation ones (to refuse each
/// object with its reason rather than the whole context).
pub fn accepted_classes(private: &[Mapping]) -> Vec<String> {
    let mut v: Vec<String> = vec![
        dbt_dicom::projections::BPXR_FOR_PROCESSING_CLASS.into(),
        dbt_dicom::dm::DM_FOR_PROCESSING_CLASS.into(),
    ];
    v.extend(private.iter().map(|m| m.sop_class.clone()));
    v.extend(for_presentation_classes().map(String::from));
    v
}

impl DicomInput {
    /// Listen on `addr`, until `stop`; `wake` is set on every change.
    pub fn start(
        addr: SocketAddr,
        settings: InputSettings,
        stop: Arc<AtomicBool>,
        wake: Arc<AtomicBool>,
    ) -> std::io::Result<Self> {
        let listener = TcpListener::bind(addr)?;
        listener.set_nonblocking(true)?;
        let addr = listener.local_addr()?;
        let listening = format!("{}@{addr}", settings.ae_title);
        let state = State::load(settings)?;
        let counters = DicomInputStatus {
            listening: listening.clone(),
            quiet_time_s: state.settings.quiet_time.as_secs_f64(),
            ..Default::default()
        };
        let shared = Arc::new(Shared {
            state: Mutex::new(state),
            faults: Mutex::new(Vec::new()),
            counters: Mutex::new(counters),
            open: AtomicU64::new(0),
            wake,
        });
        // Sweeps a crash left complete but not spooled.
        shared.complete_ready();
        let s = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("dicom-input".into())
            .spawn(move || accept_loop(listener, s, stop))?;
        Ok(Self {
            shared,
            _thread: thread,
            addr,
            listening,
        })
    }

    /// The address it listens on.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// `AET@host:port`.
    pub fn listening(&self) -> &str {
        &self.listening
    }

    /// The faults reported since the last call.
    pub fn drain(&self) -> Vec<FaultRecord> {
        std::mem::take(&mut *lock(&self.shared.faults))
    }

    /// The input's state for the status file.
    pub fn status(&self) -> DicomInputStatus {
        let mut st = lock(&self.shared.counters).clone();
        st.associations_open = self.shared.open.load(Ordering::SeqCst);
        let state = lock(&self.shared.state);
        let expected = state.settings.system.n_views();
        st.waiting = state
            .groups
            .values()
            .map(|g| WaitingSweep {
                laterality: g.first.header.laterality.letter().into(),
                view: g.first.view.clone(),
                views_received: g.views.len(),
                views_expected: expected,
                last_view_unix: g.last_unix,
            })
            .collect();
        st
    }
}

fn accept_loop(listener: TcpListener, shared: Arc<Shared>, stop: Arc<AtomicBool>) {
    let max = lock(&shared.state).settings.max_associations as u64;
    while !stop.load(Ordering::SeqCst) {
        shared.expire();
        // At the limit, further connections wait in the listen backlog.
        if shared.open.load(Ordering::SeqCst) >= max {
            std::thread::sleep(Duration::from_millis(50));
            continue;
        }
        let stream = match listener.accept() {
            Ok((s, _)) => s,
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(100));
                continue;
            }
            Err(e) => {
                tracing::warn!(%e, "DICOM input: accepting a connection");
                std::thread::sleep(Duration::from_millis(100));
                continue;
            }
        };
        let _ = stream.set_nonblocking(false);
        shared.open.fetch_add(1, Ordering::SeqCst);
        let s = Arc::clone(&shared);
        let spawned = std::thread::Builder::new()
            .name("dicom-association".into())
            .spawn(move || {
                s.association(stream);
                s.open.fetch_sub(1, Ordering::SeqCst);
                s.wake.store(true, Ordering::SeqCst);
            });
        if let Err(e) = spawned {
            shared.open.fetch_sub(1, Ordering::SeqCst);
            tracing::error!(%e, "DICOM input: cannot start an association's thread");
        }
    }
}

/// FNV-1a (64 bits) over `bytes`.
fn fnv1a(bytes: impl IntoIterator<Item = u8>) -> u64 {
    bytes.into_iter().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// FNV-1a over the counts (little-endian bytes).
pub fn counts_digest(counts: &[u16]) -> u64 {
    fnv1a(counts.iter().flat_map(|c| c.to_le_bytes()))
}

/// The folder of a waiting sweep: a digest of its key.
fn group_dir(spool: &Path, key: &str) -> PathBuf {
    spool
        .join("views")
        .join(format!("{:016x}", fnv1a(key.bytes())))
}

/// What became of one object.
enum Outcome {
    /// A new sweep spooled, or a view kept.
    Stored,
    /// A copy of what was kept.
    Duplicate,
    /// Refused: the failure status and the reason (the object is kept in
    /// `faulted/`).
    Refused(u16, String),
}

impl State {
    /// The objects already spooled (`incoming/`, `done/`: their
    /// `gantry.json`) and the sweeps waiting in `views/`.
    fn load(settings: InputSettings) -> std::io::Result<Self> {
        let spool = settings.spool.clone();
        let mut seen = HashMap::new();
        for sub in ["incoming", "done"] {
            let Ok(rd) = std::fs::read_dir(spool.join(sub)) else {
                continue;
            };
            for e in rd.flatten() {
                let v: serde_json::Value = std::fs::read(e.path().join("gantry.json"))
                    .ok()
                    .and_then(|b| serde_json::from_slice(&b).ok())
                    .unwrap_or_default();
                if let Some(objects) = v["objects"].as_object() {
                    for (sop, d) in objects {
                        if let Some(d) = d.as_u64() {
                            seen.insert(sop.clone(), d);
                        }
                    }
                }
                // Entries spooled by the previous version (one object each).
                if let (Some(sop), Some(d)) =
                    (v["sop_instance"].as_str(), v["counts_digest"].as_u64())
                {
                    seen.insert(sop.to_string(), d);
                }
            }
        }
        let views = spool.join("views");
        std::fs::create_dir_all(&views)?;
        let mut state = Self {
            settings,
            seen,
            groups: BTreeMap::new(),
        };
        for e in std::fs::read_dir(&views)?.flatten() {
            state.reload_group(&e.path());
        }
        Ok(state)
    }

    /// A waiting sweep's folder after a restart: its views read again; a
    /// folder whose views were all spooled already (a crash between the
    /// spool and the removal) is removed.
    fn reload_group(&mut self, dir: &Path) {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .map(|rd| rd.flatten().map(|e| e.path()).collect())
            .unwrap_or_default();
        files.retain(|p| p.extension().is_some_and(|x| x == "dcm"));
        files.sort();
        let mut group: Option<(String, Group)> = None;
        let mut all_spooled = true;
        for f in &files {
            let parsed = std::fs::read(f)
                .map_err(|e| e.to_string())
                .and_then(|b| {
                    read_input_object(&b, &self.settings.private).map_err(|e| e.to_string())
                })
                .and_then(|p| {
                    view_index(&p, &self.settings.system)
                        .map(|k| (k, p))
                        .map_err(|e| e.to_string())
                });
            let (k, mut p) = match parsed {
                Ok(v) => v,
                Err(e) => {
                    tracing::error!(file = %f.display(), %e, "a kept view no longer reads");
                    continue;
                }
            };
            let digest = counts_digest(&p.counts);
            all_spooled &= self.seen.get(&p.sop_instance) == Some(&digest);
            self.seen.insert(p.sop_instance.clone(), digest);
            let sop = p.sop_instance.clone();
            p.counts = Vec::new();
            let g = group.get_or_insert_with(|| {
                (
                    group_key(&p),
                    Group {
                        dir: dir.to_path_buf(),
                        first: p,
                        views: BTreeMap::new(),
                        last: Instant::now(),
                        last_unix: now_unix(),
                    },
                )
            });
            g.1.views.insert(k, (sop, digest));
        }
        match group {
            Some(_) if all_spooled => {
                let _ = std::fs::remove_dir_all(dir);
            }
            Some((key, g)) => {
                tracing::info!(views = g.views.len(), "a sweep waiting for views, reloaded");
                self.groups.insert(key, g);
            }
            None => {
                let _ = std::fs::remove_dir_all(dir);
            }
        }
    }

    /// One object received.
    fn receive(
        &mut self,
        class: &str,
        instance: &str,
        received: Result<Vec<u8>, Unreadable>,
        faults: &mut Vec<FaultRecord>,
    ) -> Outcome {
        let bytes = match received {
            Ok(b) => b,
            Err(u) => {
                let reason = format!("{} (transfer syntax {})", u.reason, u.transfer_syntax);
                self.keep_refused(
                    class,
                    instance,
                    &u.data_set,
                    "data-set.bin",
                    &reason,
                    faults,
                );
                return Outcome::Refused(STATUS_CANNOT_UNDERSTAND, reason);
            }
        };
        match self.take(class, instance, &bytes, faults) {
            Ok(o) => o,
            Err((status, reason)) => {
                self.keep_refused(class, instance, &bytes, "object.dcm", &reason, faults);
                Outcome::Refused(status, reason)
            }
        }
    }

    fn take(
        &mut self,
        class: &str,
        instance: &str,
        bytes: &[u8],
        faults: &mut Vec<FaultRecord>,
    ) -> Result<Outcome, (u16, String)> {
        let refuse = |e: String| (STATUS_CANNOT_UNDERSTAND, e);
        let p =
            read_input_object(bytes, &self.settings.private).map_err(|e| refuse(e.to_string()))?;
        let digest = counts_digest(&p.counts);
        match self.seen.get(instance) {
            Some(d) if *d == digest => return Ok(Outcome::Duplicate),
            Some(_) => {
                return Err(refuse(format!(
                "a second copy of SOP instance {instance} with other pixels than the one received"
            )))
            }
            None => {}
        }
        let system = &self.settings.system;
        if p.layout == Layout::MultiFrame {
            let acq =
                acquisition_from_projections(&p, system).map_err(|e| refuse(e.to_string()))?;
            let id = entry_id(&acq.header.patient.id);
            let note = GantryNote {
                source: Source::Dicom,
                sop_class: Some(class.to_string()),
                objects: [(instance.to_string(), digest)].into(),
                ..Default::default()
            };
            self.spool(&id, &acq, &note, faults)?;
            tracing::info!(acquisition = %id, %instance, "spooled from DICOM");
            self.seen.insert(instance.to_string(), digest);
            return Ok(Outcome::Stored);
        }
        // One view of a sweep.
        check_object(&p, system).map_err(|e| refuse(e.to_string()))?;
        let k = view_index(&p, system).map_err(|e| refuse(e.to_string()))?;
        let key = group_key(&p);
        if let Some(g) = self.groups.get(&key) {
            check_same_sweep(&g.first, &p).map_err(|e| refuse(e.to_string()))?;
            if let Some((sop, d)) = g.views.get(&k) {
                if *d == digest {
                    return Ok(Outcome::Duplicate);
                }
                return Err(refuse(format!(
                    "a second copy of view {} ({} deg) with other pixels than SOP instance {sop}",
                    k + 1,
                    system.angle_deg(k)
                )));
            }
        }
        let dir = group_dir(&self.settings.spool, &key);
        std::fs::create_dir_all(&dir)
            .and_then(|_| write_durable(&dir.join(format!("{k:03}.dcm")), bytes))
            .and_then(|_| {
                std::fs::File::open(self.settings.spool.join("views")).and_then(|d| d.sync_all())
            })
            .map_err(|e| {
                (
                    STATUS_OUT_OF_RESOURCES,
                    format!("cannot keep view {}: {e}", k + 1),
                )
            })?;
        self.seen.insert(instance.to_string(), digest);
        let mut first = p;
        first.counts = Vec::new();
        let g = self.groups.entry(key.clone()).or_insert_with(|| Group {
            dir,
            first,
            views: BTreeMap::new(),
            last: Instant::now(),
            last_unix: now_unix(),
        });
        g.views.insert(k, (instance.to_string(), digest));
        g.last = Instant::now();
        g.last_unix = now_unix();
        tracing::info!(
            view = k + 1,
            views = g.views.len(),
            of = system.n_views(),
            %instance,
            "view kept"
        );
        if g.views.len() == system.n_views() {
            self.complete(&key, faults);
        }
        Ok(Outcome::Stored)
    }

    fn spool(
        &self,
        id: &str,
        acq: &dbt_pipeline::Acquisition,
        note: &GantryNote,
        faults: &mut Vec<FaultRecord>,
    ) -> Result<(), (u16, String)> {
        spool_entry(&self.settings.spool, id, acq, note).map_err(|e| {
            let msg = format!("cannot spool acquisition {id}: {e}");
            faults.push(FaultRecord {
                at_unix: now_unix(),
                acquisition: Some(id.to_string()),
                kind: "spool".into(),
                message: msg.clone(),
            });
            (STATUS_OUT_OF_RESOURCES, msg)
        })
    }

    /// Every view of sweep `key` is in: assembled and spooled, its folder
    /// removed; if the sweep is refused as a whole, its folder goes to
    /// `faulted/` with the reason.
    fn complete(&mut self, key: &str, faults: &mut Vec<FaultRecord>) {
        let Some(g) = self.groups.get(key) else {
            return;
        };
        let dir = g.dir.clone();
        let objects: BTreeMap<String, u64> =
            g.views.values().map(|(sop, d)| (sop.clone(), *d)).collect();
        let class = g.first.sop_class.clone();
        let built = g
            .views
            .keys()
            .map(|k| {
                std::fs::read(dir.join(format!("{k:03}.dcm")))
                    .map_err(|e| format!("view {}: {e}", k + 1))
                    .and_then(|b| {
                        read_input_object(&b, &self.settings.private).map_err(|e| e.to_string())
                    })
            })
            .collect::<Result<Vec<_>, String>>()
            .and_then(|views| assemble(&views, &self.settings.system).map_err(|e| e.to_string()))
            .and_then(|sweep| {
                acquisition_from_projections(&sweep, &self.settings.system)
                    .map_err(|e| e.to_string())
            });
        match built {
            Ok(acq) => {
                let id = entry_id(&acq.header.patient.id);
                let note = GantryNote {
                    source: Source::Dicom,
                    sop_class: Some(class.to_string()),
                    objects: objects.clone(),
                    ..Default::default()
                };
                if self.spool(&id, &acq, &note, faults).is_err() {
                    // Kept in views/: tried again at the next start.
                    return;
                }
                tracing::info!(acquisition = %id, views = objects.len(), "sweep spooled from DICOM views");
                if let Err(e) = std::fs::remove_dir_all(&dir) {
                    tracing::warn!(%e, dir = %dir.display(), "cannot remove a spooled sweep's views");
                }
                self.groups.remove(key);
            }
            Err(reason) => {
                self.fault_group(key, &format!("sweep refused: {reason}"), faults);
            }
        }
    }

    /// Sweep `key` moved to `faulted/<id>/` with `reason`.
    fn fault_group(&mut self, key: &str, reason: &str, faults: &mut Vec<FaultRecord>) {
        let Some(g) = self.groups.remove(key) else {
            return;
        };
        let id = entry_id(&g.first.header.patient_id);
        let dst = self.settings.spool.join("faulted").join(&id);
        let moved = std::fs::create_dir_all(self.settings.spool.join("faulted"))
            .and_then(|_| std::fs::rename(&g.dir, &dst))
            .and_then(|_| {
                write_durable(
                    &dst.join("fault.json"),
                    &serde_json::to_vec_pretty(&serde_json::json!({
                        "kind": "input",
                        "message": reason,
                        "sop_class": g.first.sop_class,
                        "views": g.views.values().map(|(s, _)| s).collect::<Vec<_>>(),
                    }))
                    .unwrap_or_default(),
                )
            });
        if let Err(e) = moved {
            tracing::error!(%e, "cannot move a refused sweep to faulted/");
        }
        // Its views may be sent again (the modality's resend of the sweep).
        for (sop, _) in g.views.values() {
            self.seen.remove(sop);
        }
        faults.push(FaultRecord {
            at_unix: now_unix(),
            acquisition: Some(id),
            kind: "input".into(),
            message: reason.to_string(),
        });
    }

    /// Sweeps whose last view came longer ago than the quiet time.
    fn expire(&mut self, faults: &mut Vec<FaultRecord>) -> bool {
        let quiet = self.settings.quiet_time;
        let geometry = self.settings.system.clone();
        let stale: Vec<String> = self
            .groups
            .iter()
            .filter(|(_, g)| g.last.elapsed() > quiet)
            .map(|(k, _)| k.clone())
            .collect();
        for key in &stale {
            let Some(g) = self.groups.get(key) else {
                continue;
            };
            let missing: Vec<String> = (0..geometry.n_views())
                .filter(|k| !g.views.contains_key(k))
                .map(|k| format!("{}", geometry.angle_deg(k)))
                .collect();
            let reason = format!(
                "incomplete sweep: {} of {} views after a quiet time of {} s; missing the views at {} deg",
                g.views.len(),
                geometry.n_views(),
                quiet.as_secs_f64(),
                missing.join(", ")
            );
            self.fault_group(key, &reason, faults);
        }
        !stale.is_empty()
    }

    /// An object refused: kept in `faulted/<id>/` with the reason.
    fn keep_refused(
        &self,
        class: &str,
        instance: &str,
        bytes: &[u8],
        name: &str,
        reason: &str,
        faults: &mut Vec<FaultRecord>,
    ) {
        let id = entry_id("dicom");
        let dir = self.settings.spool.join("faulted").join(&id);
        let kept = std::fs::create_dir_all(&dir)
            .and_then(|_| write_durable(&dir.join(name), bytes))
            .and_then(|_| {
                write_durable(
                    &dir.join("fault.json"),
                    &serde_json::to_vec_pretty(&serde_json::json!({
                        "kind": "input",
                        "message": reason,
                        "sop_class": class,
                        "sop_instance": instance,
                    }))
                    .unwrap_or_default(),
                )
            });
        if let Err(e) = kept {
            tracing::error!(%e, "DICOM input: cannot keep a refused object");
        }
        tracing::warn!(%instance, %reason, "DICOM object refused");
        faults.push(FaultRecord {
            at_unix: now_unix(),
            acquisition: Some(id),
            kind: "input".into(),
            message: format!("DICOM object {instance} refused: {reason}"),
        });
    }
}

impl Shared {
    fn with_state<R>(&self, f: impl FnOnce(&mut State, &mut Vec<FaultRecord>) -> R) -> R {
        let mut faults = Vec::new();
        let r = f(&mut lock(&self.state), &mut faults);
        if !faults.is_empty() {
            lock(&self.faults).extend(faults);
            self.wake.store(true, Ordering::SeqCst);
        }
        r
    }

    fn expire(&self) {
        if self.with_state(|s, f| s.expire(f)) {
            self.wake.store(true, Ordering::SeqCst);
        }
    }

    fn complete_ready(&self) {
        self.with_state(|s, f| {
            let n = s.settings.system.n_views();
            let ready: Vec<String> = s
                .groups
                .iter()
                .filter(|(_, g)| g.views.len() == n)
                .map(|(k, _)| k.clone())
                .collect();
            for k in ready {
                s.complete(&k, f);
            }
        });
    }

    /// Serve one association.
    fn association(&self, stream: std::net::TcpStream) {
        let _span = tracing::info_span!("dicom_association").entered();
        let started = now_unix();
        let (ae, classes) = {
            let s = lock(&self.state);
            (
                s.settings.ae_title.clone(),
                accepted_classes(&s.settings.private),
            )
        };
        let classes: Vec<&str> = classes.iter().map(String::as_str).collect();
        let report = serve_association(
            stream,
            &ae,
            &classes,
            Duration::from_secs(30),
            &mut |class, instance, received| {
                let outcome = self.with_state(|s, f| s.receive(class, instance, received, f));
                let mut c = lock(&self.counters);
                let verdict = match outcome {
                    Outcome::Stored => {
                        c.objects_stored += 1;
                        Verdict::Stored
                    }
                    Outcome::Duplicate => {
                        tracing::info!(%instance, "a copy of an object already kept: nothing new");
                        c.objects_duplicate += 1;
                        Verdict::Stored
                    }
                    Outcome::Refused(status, reason) => {
                        c.objects_refused += 1;
                        Verdict::Refused(status, reason)
                    }
                };
                self.wake.store(true, Ordering::SeqCst);
                verdict
            },
        );
        {
            let mut c = lock(&self.counters);
            c.associations_total += 1;
            c.last_association = Some((report.calling_ae_title.clone(), started));
            c.contexts_refused += report.refused_contexts.len() as u64;
        }
        // A class we do not serve is routine (modalities propose all they
        // may send); a served class in a transfer syntax we cannot decode
        // is a site configuration fault.
        let undecodable: Vec<&String> = report
            .refused_contexts
            .iter()
            .filter(|r| r.contains("transfer syntax"))
            .collect();
        for r in &report.refused_contexts {
            tracing::info!(calling = %report.calling_ae_title, context = %r, "presentation context refused");
        }
        if !undecodable.is_empty() {
            let msg = format!(
                "association from {}: presentation contexts refused, nothing received through them: {}",
                report.calling_ae_title,
                undecodable
                    .iter()
                    .map(|s| s.as_str())
                    .collect::<Vec<_>>()
                    .join("; ")
            );
            lock(&self.faults).push(FaultRecord {
                at_unix: now_unix(),
                acquisition: None,
                kind: "input".into(),
                message: msg,
            });
        }
        if let Some(e) = &report.error {
            tracing::warn!(calling = %report.calling_ae_title, error = %e, "DICOM association ended");
        }
    }
}
