//! The daemon's state: the status file's content, one record per reported
//! acquisition (its spool entry's `result.json`), and the snapshot the status
//! page and `dbtor-diag status` both show.

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The status file's format tag.
pub const STATUS_FORMAT: &str = "dbtor-status/1";

/// One reported fault.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FaultRecord {
    /// Unix time, s.
    pub at_unix: u64,
    /// Spool entry, if one exists.
    pub acquisition: Option<String>,
    /// `link`, `modbus`, `thickness`, `input`, `implausible`, `data`,
    /// `processing`, `delivery`, `spool`, `status_page`.
    pub kind: String,
    /// What happened.
    pub message: String,
}

/// What the daemon reported for one acquisition: written as the spool
/// entry's `result.json` when it moves to `done/`, kept in the status file's
/// `recent` list. The numbers are those of its two SRs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AcquisitionRecord {
    /// The spool entry id.
    pub acquisition: String,
    /// The patient id of the header (never shown on the status page).
    #[serde(default)]
    pub patient_id: String,
    /// Reconstructor used.
    pub reconstructor: String,
    /// Compressed breast thickness of the acquisition header, mm (absent in
    /// records written before it was recorded).
    #[serde(default)]
    pub thickness_mm: Option<f64>,
    /// Glandularity from the labels.
    pub glandularity_labels: f64,
    /// Glandularity from the partial volumes.
    pub glandularity_partial_volume: f64,
    /// The reported glandularity (the density SR's Percent Fibroglandular
    /// Tissue / 100).
    pub glandularity_reported: f64,
    /// Whether the reported glandularity is calibrated.
    pub calibrated: bool,
    /// The density SR's volumetric fibroglandular fraction (0..1).
    #[serde(default)]
    pub volumetric_fraction: Option<f64>,
    /// The density SR's BI-RADS-style composition category, `a`..`d`.
    #[serde(default)]
    pub composition: Option<String>,
    /// Patient-specific MGD of the sweep (the dose SR's accumulated AGD), mGy.
    pub mgd_mgy: f64,
    /// Model-breast MGD of the sweep, mGy.
    pub model_mgd_mgy: f64,
    /// Processing time, s.
    pub seconds: f64,
    /// When the reports were written, unix s.
    pub finished_unix: u64,
    /// The report files.
    pub reports: Vec<String>,
    /// Reports kept in the outbox for a later send, with why.
    #[serde(default)]
    pub pacs_waiting: Vec<String>,
    /// Quality flags the reports carry.
    #[serde(default)]
    pub flags: Vec<String>,
    /// The reported density against the physics density of the same
    /// projections (issue #48 point 3); `None` in records written before
    /// the check existed.
    #[serde(default)]
    pub density_check: Option<dbt_dicom::DensityCheckReport>,
    /// The reported glandularity's 95 % interval, or why none (issue #48
    /// point 4; the density SR's); `None` in records written before.
    #[serde(default)]
    pub glandularity_interval: Option<dbt_dicom::FigureInterval>,
    /// The MGD's (the dose SR's).
    #[serde(default)]
    pub mgd_interval: Option<dbt_dicom::FigureInterval>,
}

/// The warning kind of a density the physics did not confirm.
pub const DENSITY_CHECK_WARNING: &str = "density_check";

/// The status file's content.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Status {
    /// Format tag ([`STATUS_FORMAT`]).
    pub format: String,
    /// Daemon version.
    pub version: String,
    /// Process id.
    pub pid: u32,
    /// Start time, unix s.
    pub started_unix: u64,
    /// Last update, unix s.
    pub updated_unix: u64,
    /// `starting`, `recovering`, `waiting`, `receiving`, `processing`,
    /// `processed`, `stopping`, `stopped`.
    pub state: String,
    /// Entry being worked on.
    pub current: Option<String>,
    /// Reconstructor in use.
    pub reconstructor: String,
    /// Acquisitions reported since start.
    pub processed: u64,
    /// Entries recovered from the spool at start.
    pub recovered: u64,
    /// Spool entries waiting.
    pub incoming: usize,
    /// The last acquisitions' results (most recent last, up to
    /// [`Status::MAX_RECENT`]).
    pub recent: Vec<AcquisitionRecord>,
    /// The last faults (most recent last, up to [`Status::MAX_FAULTS`]).
    pub faults: Vec<FaultRecord>,
    /// Faults since start, by kind.
    pub fault_counts: BTreeMap<String, u64>,
    /// Warnings since start, by kind: reports delivered whose figures a
    /// reader must not take as they stand ([`DENSITY_CHECK_WARNING`]: a
    /// density the physics did not confirm). Not faults: the device works.
    #[serde(default)]
    pub warning_counts: BTreeMap<String, u64>,
    /// The status page's address, when it serves one.
    #[serde(default)]
    pub status_page: Option<String>,
    /// The DICOM input, when it listens.
    #[serde(default)]
    pub dicom_input: Option<DicomInputStatus>,
    /// The daemon's peak resident memory since start, MiB (where the
    /// operating system says; issue #30).
    #[serde(default)]
    pub peak_rss_mib: Option<f64>,
    /// How the reconstruction's kernels were chosen at start: one line per
    /// precision measured (each configuration's median time on the model's
    /// own block, the chosen one marked; issue #52), or why none was.
    #[serde(default)]
    pub kernels: Vec<String>,
}

/// The DICOM input's state (issue #31): where it listens, its associations
/// and objects, and the sweeps sent one view at a time that wait for their
/// other views.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DicomInputStatus {
    /// `AET@host:port`.
    pub listening: String,
    /// Associations open now.
    pub associations_open: u64,
    /// Associations since start.
    pub associations_total: u64,
    /// The last association's calling AE title and start, unix s.
    pub last_association: Option<(String, u64)>,
    /// Objects kept (whole sweeps or views).
    pub objects_stored: u64,
    /// Copies of objects already kept (answered Success, nothing new).
    pub objects_duplicate: u64,
    /// Objects refused (kept in `faulted/`).
    pub objects_refused: u64,
    /// Presentation contexts refused at negotiation (a class or transfer
    /// syntax the input does not take).
    pub contexts_refused: u64,
    /// Sweeps waiting for views.
    pub waiting: Vec<WaitingSweep>,
    /// How long a sweep waits for its last view before it is faulted, s.
    pub quiet_time_s: f64,
}

/// A sweep whose views come one object each, not yet complete. No patient
/// or study identifier: the status page shows it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WaitingSweep {
    /// `L` or `R`.
    pub laterality: String,
    /// The view (e.g. `cranio-caudal`).
    pub view: String,
    /// Views received.
    pub views_received: usize,
    /// Views a sweep of the configured gantry has.
    pub views_expected: usize,
    /// When its last view arrived, unix s.
    pub last_view_unix: u64,
}

impl Status {
    /// Faults kept in [`Status::faults`].
    pub const MAX_FAULTS: usize = 50;
    /// Acquisitions kept in [`Status::recent`].
    pub const MAX_RECENT: usize = 10;

    /// A daemon's status at its start.
    pub fn starting(version: &str, pid: u32, now_unix: u64, reconstructor: String) -> Self {
        Self {
            format: STATUS_FORMAT.into(),
            version: version.into(),
            pid,
            started_unix: now_unix,
            updated_unix: now_unix,
            peak_rss_mib: None,
            state: "starting".into(),
            current: None,
            reconstructor,
            processed: 0,
            recovered: 0,
            incoming: 0,
            recent: vec![],
            faults: vec![],
            fault_counts: BTreeMap::new(),
            warning_counts: BTreeMap::new(),
            status_page: None,
            dicom_input: None,
            kernels: vec![],
        }
    }

    /// Record a fault (keeping the last [`Status::MAX_FAULTS`]).
    pub fn push_fault(&mut self, f: FaultRecord) {
        *self.fault_counts.entry(f.kind.clone()).or_default() += 1;
        self.faults.push(f);
        if self.faults.len() > Self::MAX_FAULTS {
            self.faults.remove(0);
        }
    }

    /// Record a reported acquisition (keeping the last [`Status::MAX_RECENT`]).
    pub fn push_reported(&mut self, r: AcquisitionRecord) {
        self.processed += 1;
        if r.density_check.as_ref().is_some_and(|c| !c.confirmed) {
            *self
                .warning_counts
                .entry(DENSITY_CHECK_WARNING.into())
                .or_default() += 1;
        }
        self.recent.push(r);
        if self.recent.len() > Self::MAX_RECENT {
            self.recent.remove(0);
        }
    }

    /// Faults recorded since start.
    pub fn fault_total(&self) -> u64 {
        self.fault_counts.values().sum()
    }

    /// Healthy: no fault newer than the last reported acquisition.
    pub fn healthy(&self) -> bool {
        let last_ok = self.recent.last().map(|r| r.finished_unix);
        match (self.faults.last().map(|f| f.at_unix), last_ok) {
            (None, _) => true,
            (Some(f), Some(ok)) => ok > f,
            (Some(_), None) => false,
        }
    }
}

/// Why a spool entry's record could not be read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Unreadable {
    /// The spool entry.
    pub acquisition: String,
    /// Why.
    pub reason: String,
}

/// What the status page and `dbtor-diag status` show: the status file and
/// the spool's history of reported acquisitions (oldest first).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Snapshot {
    /// The daemon's status file.
    pub status: Status,
    /// Every reported acquisition still in the spool's `done/`, oldest first.
    pub history: Vec<AcquisitionRecord>,
    /// `done/` entries whose record could not be read.
    pub unreadable: Vec<Unreadable>,
}

impl Snapshot {
    /// The snapshot with every patient identifier removed: what the
    /// unauthenticated status page serves. Patient ids go, and every spool
    /// entry id (`<ms>-<patient id>`) becomes its [`public_id`], in the
    /// records, the report names, the outbox notes and the faults.
    pub fn deidentified(&self) -> Snapshot {
        let mut s = self.clone();
        let mut ids: Vec<String> = Vec::new();
        for r in s.status.recent.iter_mut().chain(s.history.iter_mut()) {
            r.patient_id.clear();
            ids.push(r.acquisition.clone());
        }
        ids.extend(s.status.current.iter().cloned());
        ids.extend(s.status.faults.iter().filter_map(|f| f.acquisition.clone()));
        ids.extend(s.unreadable.iter().map(|u| u.acquisition.clone()));
        // Longest first: an id that is a prefix of another is replaced last.
        ids.sort_by_key(|i| std::cmp::Reverse(i.len()));
        ids.dedup();
        let scrub = |text: &mut String| {
            for id in &ids {
                if text.contains(id.as_str()) {
                    *text = text.replace(id.as_str(), public_id(id));
                }
            }
        };
        for r in s.status.recent.iter_mut().chain(s.history.iter_mut()) {
            scrub(&mut r.acquisition);
            r.reports.iter_mut().for_each(scrub);
            r.pacs_waiting.iter_mut().for_each(scrub);
        }
        if let Some(c) = s.status.current.as_mut() {
            scrub(c);
        }
        for f in &mut s.status.faults {
            if let Some(a) = f.acquisition.as_mut() {
                scrub(a);
            }
            scrub(&mut f.message);
        }
        for u in &mut s.unreadable {
            scrub(&mut u.acquisition);
            scrub(&mut u.reason);
        }
        s
    }

    /// The history's records sorted oldest first (by finish time, then id).
    pub fn sort_history(&mut self) {
        self.history.sort_by(|a, b| {
            (a.finished_unix, &a.acquisition).cmp(&(b.finished_unix, &b.acquisition))
        });
    }
}

/// The part of a spool entry id (`<unix ms>-<patient id>`) that names it
/// without the patient: its time stamp, unique to the entry.
pub fn public_id(id: &str) -> &str {
    id.split('-').next().unwrap_or(id)
}

/// A spool entry id the status page may name in a URL: the daemon's ids are
/// ASCII letters, digits, `-`, `_` and `.` (never `..`), at most 128 bytes.
pub fn valid_entry_id(id: &str) -> bool {
    !id.is_empty()
        && id.len() <= 128
        && id != "."
        && !id.contains("..")
        && id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.'))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn record(id: &str, t: f64, g: f64, mgd: f64, at: u64) -> AcquisitionRecord {
        AcquisitionRecord {
            acquisition: id.into(),
            patient_id: "PAT-1".into(),
            reconstructor: "dbtor".into(),
            thickness_mm: Some(t),
            glandularity_labels: g,
            glandularity_partial_volume: g,
            glandularity_reported: g,
            calibrated: true,
            volumetric_fraction: Some(g * 0.9),
            composition: Some("c".into()),
            mgd_mgy: mgd,
            model_mgd_mgy: mgd * 1.1,
            seconds: 12.0,
            finished_unix: at,
            reports: vec![],
            pacs_waiting: vec![],
            flags: vec![],
            density_check: Some(dbt_dicom::DensityCheckReport {
                physics_glandularity: Some(g),
                confirmed: true,
                reasons: vec![],
            }),
            glandularity_interval: Some(dbt_dicom::FigureInterval {
                // Binary fractions: they survive the JSON round trip exactly.
                limits: Some([0.179_687_5, 0.273_437_5]),
                basis: "95 % prediction interval from 14 validation breasts".into(),
            }),
            mgd_interval: Some(dbt_dicom::FigureInterval {
                limits: Some([1.25, 1.625]),
                basis: "95 % prediction interval from 14 validation breasts".into(),
            }),
        }
    }

    /// A density the physics did not confirm is counted as a
    /// `density_check` warning, not a fault (the device stays healthy).
    #[test]
    fn an_unconfirmed_density_is_a_counted_warning() {
        let mut s = Status::starting("0", 1, 100, "dbtor".into());
        s.push_reported(record("a", 50.0, 0.2, 1.3, 120));
        assert!(s.warning_counts.is_empty());
        let mut r = record("b", 50.0, 0.6, 1.3, 130);
        r.composition = None;
        r.density_check = Some(dbt_dicom::DensityCheckReport {
            physics_glandularity: Some(0.4),
            confirmed: false,
            reasons: vec!["disagree by +20.0 pp".into()],
        });
        s.push_reported(r);
        assert_eq!(s.warning_counts[DENSITY_CHECK_WARNING], 1);
        assert!(s.healthy() && s.fault_total() == 0);
        // Written and read back.
        let back: Status = serde_json::from_str(&serde_json::to_string(&s).unwrap()).unwrap();
        assert_eq!(back, s);
    }

    #[test]
    fn health_is_no_fault_after_the_last_report() {
        let mut s = Status::starting("0", 1, 100, "dbtor".into());
        assert!(s.healthy());
        s.push_fault(FaultRecord {
            at_unix: 110,
            acquisition: None,
            kind: "link".into(),
            message: "m".into(),
        });
        assert!(!s.healthy());
        s.push_reported(record("a", 50.0, 0.2, 1.3, 120));
        assert!(s.healthy());
        assert_eq!(s.fault_total(), 1);
        assert_eq!(s.processed, 1);
    }

    #[test]
    fn lists_keep_their_last_entries() {
        let mut s = Status::starting("0", 1, 100, "dbtor".into());
        for i in 0..(Status::MAX_FAULTS + 5) {
            s.push_fault(FaultRecord {
                at_unix: i as u64,
                acquisition: None,
                kind: "link".into(),
                message: format!("{i}"),
            });
        }
        assert_eq!(s.faults.len(), Status::MAX_FAULTS);
        assert_eq!(s.faults[0].message, "5");
        assert_eq!(s.fault_counts["link"], (Status::MAX_FAULTS + 5) as u64);
        for i in 0..(Status::MAX_RECENT + 3) {
            s.push_reported(record(&format!("{i}"), 50.0, 0.2, 1.3, 200 + i as u64));
        }
        assert_eq!(s.recent.len(), Status::MAX_RECENT);
        assert_eq!(s.recent[0].acquisition, "3");
    }

    #[test]
    fn deidentified_snapshot_has_no_patient_id() {
        let id = "1732467000123-PAT_1";
        let mut st = Status::starting("0", 1, 100, "dbtor".into());
        let mut r = record(id, 50.0, 0.2, 1.3, 120);
        r.reports = vec![format!("{id}-dose-sr.dcm")];
        st.push_reported(r.clone());
        st.push_fault(FaultRecord {
            at_unix: 130,
            acquisition: Some(id.into()),
            kind: "spool".into(),
            message: format!("cannot move {id} to done/"),
        });
        let s = Snapshot {
            status: st,
            history: vec![r],
            unreadable: vec![],
        };
        let text = serde_json::to_string(&s.deidentified()).unwrap();
        assert!(!text.contains("PAT"), "{text}");
        assert!(serde_json::to_string(&s).unwrap().contains("PAT-1"));
        assert_eq!(s.deidentified().history[0].acquisition, "1732467000123");
        assert_eq!(
            s.deidentified().status.faults[0].message,
            "cannot move 1732467000123 to done/"
        );
    }

    #[test]
    fn records_of_older_daemons_still_read() {
        // A result.json written before thickness and composition were recorded.
        let old = r#"{"acquisition":"1-x","patient_id":"P","reconstructor":"mltr",
            "glandularity_labels":0.2,"glandularity_partial_volume":0.21,
            "glandularity_reported":0.21,"calibrated":false,"mgd_mgy":1.2,
            "model_mgd_mgy":1.4,"seconds":3.0,"finished_unix":5,"reports":[],
            "pacs_waiting":[],"flags":[]}"#;
        let r: AcquisitionRecord = serde_json::from_str(old).unwrap();
        assert_eq!(r.thickness_mm, None);
        assert_eq!(r.composition, None);
    }

    #[test]
    fn entry_ids_that_could_leave_the_spool_are_refused() {
        assert!(valid_entry_id("1732467000-00001-PAT_1"));
        for bad in [
            "",
            ".",
            "..",
            "../etc",
            "a/b",
            "a%2fb",
            "a b",
            &"x".repeat(129),
        ] {
            assert!(!valid_entry_id(bad), "{bad}");
        }
    }
}
