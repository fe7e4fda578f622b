//! The report-interval file of a model folder (adapter: file I/O):
//! `dbt-eval intervals` fits it from `dbt-eval accuracy` outputs on the
//! validation split, the daemon and `dbtor-process` read it when they load
//! the model. The table and the intervals are `dbt_intervals` (pure).
//!
//! Bound to the model (its manifest's SHA-256) and, table by table, to the
//! calibration the reported glandularity went through (its key and entry,
//! as the firmware picked it, kept in the table): a model recalibrated for
//! the loaded precision and inputs whose table was not refit is refused,
//! naming the table; an entry added for another beam or input, or a stale
//! table of another precision or input, leaves the loaded one as it is.

use crate::calibration::{
    check_binding, manifest_sha256, CalibrationFile, InputCorrections, CALIBRATION_FILE,
};
use dbt_intervals::IntervalTable;
use dbt_tissue::GlandularityCalibration;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use thiserror::Error;

/// The interval file in a model folder.
pub const INTERVALS_FILE: &str = "report-intervals.json";

/// Format tag of [`INTERVALS_FILE`].
pub const INTERVALS_FORMAT: &str = "dbtor-report-intervals/2";

/// An interval file is unreadable, inconsistent or stale.
#[derive(Debug, Error)]
#[error("report intervals {path}: {reason}")]
pub struct IntervalsError {
    /// The file.
    pub path: PathBuf,
    /// Why.
    pub reason: String,
}

/// How one table was fit: the command and the validation cases it read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IntervalsSource {
    /// The command that wrote it.
    pub command: String,
    /// The `dbt-eval accuracy` outputs it read (their phantoms line: the
    /// split, population and indices).
    pub inputs: Vec<String>,
    /// Validation breasts in all.
    pub cases: usize,
}

/// The calibration entry a table's reported glandularity went through.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationUsed {
    /// Its key in the calibration file (the table's own, or the plain
    /// precision's where the firmware fell back to it:
    /// [`crate::pick_calibration`]).
    pub key: String,
    /// The entry as the file stores it.
    pub entry: GlandularityCalibration,
}

/// One reconstructor's and input's table, with where it came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IntervalsEntry {
    /// The residual table.
    pub table: IntervalTable,
    /// The calibration the residuals' reported glandularity went through,
    /// as the firmware picked it when the table was fit (`None`: none).
    pub calibration: Option<CalibrationUsed>,
    /// How it was fit.
    pub source: IntervalsSource,
}

/// A model's report intervals ([`INTERVALS_FILE`]), keyed like its
/// calibrations (precision label and input corrections,
/// [`InputCorrections::key`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IntervalsFile {
    /// [`INTERVALS_FORMAT`].
    pub format: String,
    /// The model's name.
    pub model: String,
    /// SHA-256 of the model's manifest.json.
    pub manifest_sha256: String,
    /// The tables by key.
    pub tables: BTreeMap<String, IntervalsEntry>,
}

/// The calibration the firmware applies to `model`'s glandularity at its
/// precision for inputs corrected as `input` ([`crate::pick_calibration`]
/// on its folder's file, read and checked as the firmware reads it), as a
/// table records it; `None` without a file or an entry.
pub fn current_calibration(
    model: &dbt_dbtor::Dbtor,
    input: InputCorrections,
) -> Result<Option<CalibrationUsed>, crate::CalibrationError> {
    let p = model.root().join(CALIBRATION_FILE);
    if !p.is_file() {
        return Ok(None);
    }
    let f = CalibrationFile::read(&p, model)?;
    Ok(
        crate::pick_calibration(&f, &model.precision_label(), input).and_then(|(_, key)| {
            f.calibrations
                .get(&key)
                .map(|&entry| CalibrationUsed { key, entry })
        }),
    )
}

impl IntervalsFile {
    /// Read and check `path` against `model`: the format, the model's
    /// manifest, every table valid. Each table's calibration is checked
    /// where it is used ([`IntervalsFile::pick`]): a stale table of another
    /// precision or input does not stop this one's.
    pub fn read(path: &Path, model: &dbt_dbtor::Dbtor) -> Result<Self, IntervalsError> {
        let fail = |reason: String| IntervalsError {
            path: path.to_path_buf(),
            reason,
        };
        let text = std::fs::read_to_string(path).map_err(|e| fail(e.to_string()))?;
        let f: Self = serde_json::from_str(&text).map_err(|e| fail(e.to_string()))?;
        check_binding(
            &f.format,
            INTERVALS_FORMAT,
            &f.manifest_sha256,
            model,
            "dbt-eval intervals",
        )
        .map_err(fail)?;
        for (key, e) in &f.tables {
            e.table
                .validate()
                .map_err(|e| fail(format!("table {key:?}: {e}")))?;
        }
        Ok(f)
    }

    /// The file at `path` to add `model`'s tables to: as read where it is
    /// `model`'s (its other tables kept as they are: each is checked where
    /// it is used), else an empty one bound to it.
    pub fn open_or_new(
        path: &Path,
        model: &dbt_dbtor::Dbtor,
    ) -> Result<Self, dbt_dbtor::DbtorError> {
        match Self::read(path, model) {
            Ok(f) => Ok(f),
            Err(e) => {
                if path.is_file() {
                    tracing::warn!(%e, "report intervals started afresh");
                }
                Ok(Self {
                    format: INTERVALS_FORMAT.into(),
                    model: model.manifest().name.clone(),
                    manifest_sha256: manifest_sha256(model)?,
                    tables: BTreeMap::new(),
                })
            }
        }
    }

    /// The table of `model` (read from `path`) at its precision for inputs
    /// corrected as `input`: the exact key only (residuals of other inputs
    /// do not describe these); refused where the calibration the firmware
    /// now applies to them is not the one the table's residuals went
    /// through (a model recalibrated for these inputs, its intervals not
    /// refit).
    pub fn pick(
        &self,
        path: &Path,
        model: &dbt_dbtor::Dbtor,
        input: InputCorrections,
    ) -> Result<Option<&IntervalTable>, IntervalsError> {
        let key = input.key(&model.precision_label());
        let Some(e) = self.tables.get(&key) else {
            return Ok(None);
        };
        let fail = |reason: String| IntervalsError {
            path: path.to_path_buf(),
            reason,
        };
        let now = current_calibration(model, input).map_err(|e| fail(e.to_string()))?;
        if now != e.calibration {
            return Err(fail(format!(
                "table {key:?} was fit on glandularities calibrated with {:?}, but the firmware now applies {now:?} from {CALIBRATION_FILE}; refit with `dbt-eval intervals`",
                e.calibration
            )));
        }
        Ok(Some(&e.table))
    }
}

/// The table of `model` (its folder's [`INTERVALS_FILE`], read as
/// [`IntervalsFile::read`] checks it) for inputs corrected as `input`, as
/// the evaluation loads it: `None` where there is no file or no table for
/// them.
pub fn load_intervals(
    model: &dbt_dbtor::Dbtor,
    input: InputCorrections,
) -> Result<Option<IntervalTable>, IntervalsError> {
    let path = model.root().join(INTERVALS_FILE);
    if !path.is_file() {
        return Ok(None);
    }
    let f = IntervalsFile::read(&path, model)?;
    Ok(f.pick(&path, model, input)?.cloned())
}
