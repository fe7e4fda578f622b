//! The daemon's spool (under `paths.spool`): every acquisition received is
//! kept here durably before it is processed, and stays here afterwards.
//! ```text
//! tmp/<id>/        being written (removed at start: never complete)
//! incoming/<id>/   received and durable (acquisition.json, counts.f32, gantry.json); not yet reported
//! done/<id>/       reported (result.json added)
//! faulted/<id>/    not reportable (fault.json says why); kept for the service engineer
//! ```
//! An acquisition is written to `tmp/`, every file and the folder are
//! fsynced, and only then renamed into `incoming/` (and that folder fsynced),
//! so a crash or power loss leaves either nothing or a complete acquisition.
//! Both inputs (the frame link, the DICOM input's threads) write entries
//! here; the daemon's loop (`crate::daemon`) processes and moves them.

use dbt_intake::GantryNote;
use dbt_pipeline::acquisition::Acquisition;
use dbt_store::acquisition::write_acquisition;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::{SystemTime, UNIX_EPOCH};

/// The spool's folders.
pub const FOLDERS: [&str; 4] = ["tmp", "incoming", "done", "faulted"];

/// A spool at its root folder.
#[derive(Debug, Clone)]
pub struct Spool {
    root: PathBuf,
}

impl Spool {
    /// The spool under `root`, its folders made and `tmp/` emptied (an
    /// entry there was never complete: the gantry still holds it). Errors
    /// name the folder.
    pub fn open(root: &Path) -> Result<Self, (PathBuf, std::io::Error)> {
        for sub in FOLDERS {
            let d = root.join(sub);
            std::fs::create_dir_all(&d).map_err(|e| (d.clone(), e))?;
        }
        let tmp = root.join("tmp");
        for e in std::fs::read_dir(&tmp)
            .map_err(|e| (tmp.clone(), e))?
            .flatten()
        {
            tracing::warn!(entry = %e.path().display(), "removing an incomplete spool entry");
            let _ = std::fs::remove_dir_all(e.path());
        }
        Ok(Spool {
            root: root.to_path_buf(),
        })
    }

    /// Entry `id`'s folder in `incoming/`.
    pub fn incoming_entry(&self, id: &str) -> PathBuf {
        self.root.join("incoming").join(id)
    }

    /// The ids waiting in `incoming/`, oldest first.
    pub fn incoming(&self) -> std::io::Result<Vec<String>> {
        let mut v: Vec<String> = std::fs::read_dir(self.root.join("incoming"))?
            .flatten()
            .filter(|e| e.path().is_dir())
            .filter_map(|e| e.file_name().to_str().map(String::from))
            .collect();
        v.sort();
        Ok(v)
    }

    /// Write `acq` and its gantry note durably as entry `id` ([`spool_entry`]).
    pub fn write(&self, id: &str, acq: &Acquisition, note: &GantryNote) -> std::io::Result<()> {
        spool_entry(&self.root, id, acq, note)
    }

    /// The gantry note of entry `id` in `incoming/`, or why it cannot be read.
    pub fn note(&self, id: &str) -> Result<GantryNote, String> {
        let p = self.incoming_entry(id).join("gantry.json");
        std::fs::read(&p)
            .map_err(|e| format!("{}: {e}", p.display()))
            .and_then(|b| serde_json::from_slice(&b).map_err(|e| format!("{}: {e}", p.display())))
    }

    /// Entry `id` from `incoming/` to `to/` (`done`, `faulted`), with
    /// `note` written durably into it as `note_name` first.
    pub fn move_entry(
        &self,
        id: &str,
        to: &str,
        note_name: &str,
        note: &impl serde::Serialize,
    ) -> std::io::Result<()> {
        let src = self.incoming_entry(id);
        let bytes = serde_json::to_vec_pretty(note).map_err(std::io::Error::other)?;
        write_durable(&src.join(note_name), &bytes)?;
        let dst = self.root.join(to).join(id);
        let _ = std::fs::remove_dir_all(&dst);
        std::fs::rename(&src, &dst)?;
        fsync_dir(&self.root.join(to))
    }
}

/// fsync a folder (its entries' names made durable).
pub fn fsync_dir(dir: &Path) -> std::io::Result<()> {
    std::fs::File::open(dir)?.sync_all()
}

/// Write `bytes` to `path` durably: temp file, fsync, rename, fsync folder.
pub fn write_durable(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = path.with_extension("tmp");
    {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
    }
    std::fs::rename(&tmp, path)?;
    if let Some(d) = path.parent() {
        fsync_dir(d)?;
    }
    Ok(())
}

/// Write `acq` durably as spool entry `id`: into `tmp/`, every file and the
/// folder fsynced, then renamed into `incoming/` (and that folder fsynced),
/// so a crash leaves either nothing or a complete entry. Used by both
/// inputs (the frame link, the DICOM input's thread).
pub fn spool_entry(
    spool: &Path,
    id: &str,
    acq: &Acquisition,
    gantry: &GantryNote,
) -> std::io::Result<()> {
    let tmp = spool.join("tmp").join(id);
    let dst = spool.join("incoming").join(id);
    let _ = std::fs::remove_dir_all(&tmp);
    write_acquisition(&tmp, acq).map_err(std::io::Error::other)?;
    write_durable(
        &tmp.join("gantry.json"),
        &serde_json::to_vec_pretty(gantry).map_err(std::io::Error::other)?,
    )?;
    for f in ["acquisition.json", "counts.f32"] {
        std::fs::File::open(tmp.join(f))?.sync_all()?;
    }
    fsync_dir(&tmp)?;
    std::fs::rename(&tmp, &dst)?;
    fsync_dir(&spool.join("incoming"))?;
    fsync_dir(&spool.join("tmp"))
}

/// A spool entry id: the time in ms (one later than the last id's when
/// two come in the same ms: the frame link and the DICOM input's
/// associations make ids concurrently), then the patient id made safe for a
/// file name (ASCII letters and digits, the rest `_`, at most 32).
pub fn entry_id(patient_id: &str) -> String {
    use std::sync::atomic::AtomicU64;
    static LAST_MS: AtomicU64 = AtomicU64::new(0);
    let now = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0);
    let prev = LAST_MS
        .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |last| {
            Some(now.max(last + 1))
        })
        .unwrap_or(0);
    let ms = now.max(prev + 1);
    let safe: String = patient_id
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .take(32)
        .collect();
    format!("{ms:013}-{safe}")
}
