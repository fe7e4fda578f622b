//! The sign-off of a model folder: one digest over every file the firmware
//! reads from it (the manifest, the glandularity calibration where there is
//! one, and every block's fp32 and int8 ONNX file), written once by the
//! person who releases the model (`dbtor-diag model DIR --sign-off`) into
//! [`SIGNOFF_FILE`], pinned in the site's configuration
//! (`recon.model_digest`), and checked at every load and by `dbtor-diag
//! model`.
//!
//! The digest is the SHA-256 of the `sha256sum`-style listing
//! `"<file sha256>  <relative path>\n"`, sorted by path: a flipped byte in
//! any file, a file removed (a calibration deleted), a file added (a
//! calibration dropped into an uncalibrated model) or a rewritten
//! `signoff.json` each change it or fail the comparison.

use crate::ModelError;
use dbt_dbtor::{sha256_file, ModelManifest};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::path::Path;

/// The sign-off file in a model folder.
pub const SIGNOFF_FILE: &str = "signoff.json";
/// Format tag of [`SIGNOFF_FILE`].
pub const SIGNOFF_FORMAT: &str = "dbtor-model-signoff/1";

/// The content of [`SIGNOFF_FILE`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Signoff {
    /// [`SIGNOFF_FORMAT`].
    pub format: String,
    /// The model's name (its manifest's).
    pub model: String,
    /// The digest over `files` (`sha256:<hex>`).
    pub digest: String,
    /// SHA-256 of every file the firmware reads, by relative path.
    pub files: BTreeMap<String, String>,
}

/// The files of `dir` that the firmware reads: `manifest.json`, the
/// calibration and report-interval files if present, and every block's
/// ONNX files.
pub fn firmware_files(dir: &Path) -> Result<Vec<String>, ModelError> {
    let m = read_manifest(dir)?;
    let mut files = vec!["manifest.json".to_string()];
    for f in [crate::CALIBRATION_FILE, crate::INTERVALS_FILE] {
        if dir.join(f).is_file() {
            files.push(f.to_string());
        }
    }
    for b in &m.blocks {
        for f in [&b.fp32, &b.int8] {
            if f.contains("..") || Path::new(f).is_absolute() {
                return Err(ModelError::Integrity {
                    dir: dir.to_path_buf(),
                    reason: format!("block file `{f}` lies outside the model folder"),
                });
            }
            files.push(f.clone());
        }
    }
    files.sort();
    files.dedup();
    Ok(files)
}

/// The digest of a listing of file checksums.
pub fn digest_of(files: &BTreeMap<String, String>) -> String {
    let mut h = Sha256::new();
    for (path, sha) in files {
        h.update(format!("{sha}  {path}\n").as_bytes());
    }
    let d = h.finalize();
    let hex: String = d.iter().map(|b| format!("{b:02x}")).collect();
    format!("sha256:{hex}")
}

/// Hash the firmware's files of `dir` as they are now.
pub fn compute(dir: &Path) -> Result<Signoff, ModelError> {
    let mut files = BTreeMap::new();
    for f in firmware_files(dir)? {
        let sha = sha256_file(&dir.join(&f)).map_err(|e| ModelError::Integrity {
            dir: dir.to_path_buf(),
            reason: format!("{f}: {e}"),
        })?;
        files.insert(f, sha);
    }
    let model = read_manifest(dir)?.name;
    Ok(Signoff {
        format: SIGNOFF_FORMAT.into(),
        model,
        digest: digest_of(&files),
        files,
    })
}

/// The folder's manifest as JSON (its checks are `dbt_dbtor`'s, at load).
fn read_manifest(dir: &Path) -> Result<ModelManifest, ModelError> {
    let mpath = dir.join("manifest.json");
    let text = std::fs::read_to_string(&mpath).map_err(|e| ModelError::io(&mpath, e))?;
    serde_json::from_str(&text).map_err(|e| ModelError::Integrity {
        dir: dir.to_path_buf(),
        reason: format!("manifest.json: {e}"),
    })
}

/// Write [`SIGNOFF_FILE`] for the folder as it is now; returns the sign-off
/// (its digest goes into the configuration's `recon.model_digest`).
pub fn sign_off(dir: &Path) -> Result<Signoff, ModelError> {
    let s = compute(dir)?;
    let path = dir.join(SIGNOFF_FILE);
    let text = serde_json::to_string_pretty(&s).map_err(|e| ModelError::Integrity {
        dir: dir.to_path_buf(),
        reason: e.to_string(),
    })?;
    std::fs::write(&path, text + "\n").map_err(|e| ModelError::io(&path, e))?;
    Ok(s)
}

/// Check `dir` against its sign-off and, where given, the configured digest
/// `pinned`: the sign-off exists and is well formed, its digest is its
/// listing's, every listed file exists and matches, every file the firmware
/// reads is listed, and the digest equals `pinned`. Each failure names the
/// file or the two digests.
pub fn verify(dir: &Path, pinned: Option<&str>) -> Result<Signoff, ModelError> {
    let fail = |reason: String| ModelError::Integrity {
        dir: dir.to_path_buf(),
        reason,
    };
    let path = dir.join(SIGNOFF_FILE);
    let text = std::fs::read_to_string(&path).map_err(|e| {
        fail(format!(
            "{SIGNOFF_FILE}: {e}; the model has not been signed off (`dbtor-diag model DIR --sign-off`)"
        ))
    })?;
    let s: Signoff =
        serde_json::from_str(&text).map_err(|e| fail(format!("{SIGNOFF_FILE}: {e}")))?;
    if s.format != SIGNOFF_FORMAT {
        return Err(fail(format!(
            "{SIGNOFF_FILE}: format {:?}, expected {SIGNOFF_FORMAT:?}",
            s.format
        )));
    }
    if digest_of(&s.files) != s.digest {
        return Err(fail(format!(
            "{SIGNOFF_FILE}: its digest {} is not that of its file list ({}): the sign-off was edited",
            s.digest,
            digest_of(&s.files)
        )));
    }
    if let Some(p) = pinned {
        if p != s.digest {
            return Err(fail(format!(
                "the model folder's digest {} is not the configured recon.model_digest {p}",
                s.digest
            )));
        }
    }
    for (f, want) in &s.files {
        let fp = dir.join(f);
        if !fp.is_file() {
            let what = if f == crate::CALIBRATION_FILE {
                " (the model was signed off calibrated: its glandularity would be reported uncalibrated)"
            } else if f == crate::INTERVALS_FILE {
                " (the model was signed off with report intervals: its reports would give none)"
            } else {
                ""
            };
            return Err(fail(format!("{f} is missing{what}")));
        }
        let got = sha256_file(&fp).map_err(|e| fail(format!("{f}: {e}")))?;
        if &got != want {
            return Err(fail(format!(
                "{f} has SHA-256 {got}, signed off as {want}: the file was changed"
            )));
        }
    }
    for f in firmware_files(dir)? {
        if !s.files.contains_key(&f) {
            return Err(fail(format!(
                "{f} is read by the firmware but was not signed off (added after the sign-off)"
            )));
        }
    }
    Ok(s)
}
