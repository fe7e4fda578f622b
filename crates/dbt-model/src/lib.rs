//! A trained model's folder as the firmware reads it (adapter: file I/O):
//! * [`signoff`]: one digest over every file the firmware reads, written when
//!   the model is released and checked at every load;
//! * [`calibration`]: the glandularity calibration file that `dbt-eval
//!   calibrate` writes;
//! * [`intervals`]: the report-interval file that `dbt-eval intervals`
//!   writes (the validation residuals behind each figure's 95 % interval);
//! * [`load_signed`]: the firmware's load: sign-off verified, the network's
//!   checksums verified (by `dbt_dbtor`), and the calibration for the
//!   configured precision required where the model was signed off calibrated,
//!   and its report intervals for the configured inputs where it has them.

pub mod calibration;
pub mod intervals;
pub mod signoff;

pub use calibration::{
    load_calibration, load_calibrations, manifest_sha256, pick_beam_calibrations, pick_calibration,
    CalibrationError, CalibrationFile, Calibrations, InputCorrections, CALIBRATION_FILE,
    CALIBRATION_FORMAT, KEPT_FROM_FIELD,
};
pub use intervals::{
    current_calibration, load_intervals, CalibrationUsed, IntervalsEntry, IntervalsError,
    IntervalsFile, IntervalsSource, INTERVALS_FILE, INTERVALS_FORMAT,
};
pub use signoff::{sign_off, verify, Signoff, SIGNOFF_FILE, SIGNOFF_FORMAT};

use dbt_dbtor::{Dbtor, Engine, Precision};
use dbt_tissue::{ClassifyOptions, GlandularityCalibration};
use std::path::{Path, PathBuf};
use thiserror::Error;

/// A model folder that cannot be used; each names the folder or file and why.
#[derive(Debug, Error)]
pub enum ModelError {
    /// A file cannot be read.
    #[error("{path}: {cause}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        cause: std::io::Error,
    },
    /// The folder does not match its sign-off or the configured digest.
    #[error("model folder {dir}: {reason}")]
    Integrity {
        /// The folder.
        dir: PathBuf,
        /// What does not match.
        reason: String,
    },
    /// The network cannot be loaded.
    #[error("model {dir}: {cause}")]
    Network {
        /// The folder.
        dir: PathBuf,
        /// Why.
        cause: dbt_dbtor::DbtorError,
    },
    /// The calibration file is unusable.
    #[error(transparent)]
    Calibration(#[from] CalibrationError),
    /// The report-interval file is unusable.
    #[error(transparent)]
    Intervals(#[from] IntervalsError),
    /// The network was trained on other counts than the configured
    /// corrections give it.
    #[error("model {dir}: trained on {trained}, but fed {fed}: it would read them wrongly; {fix}")]
    Input {
        /// The folder.
        dir: PathBuf,
        /// What its manifest says it was trained on.
        trained: &'static str,
        /// What the configuration gives it.
        fed: String,
        /// What to configure instead.
        fix: &'static str,
    },
}

impl ModelError {
    pub(crate) fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.to_path_buf(),
            cause: source,
        }
    }
}

/// Refuse a network fed other counts than it was trained on: one trained on
/// a detector's uncorrected clinical counts
/// ([`dbt_dbtor::TrainingInput::UncorrectedClinical`], its manifest's
/// dataset provenance) read only such counts (`input.uncorrected_clinical`),
/// and every other network never reads them.
pub fn check_training_input(
    dir: &Path,
    model: &Dbtor,
    input: InputCorrections,
) -> Result<(), ModelError> {
    use dbt_dbtor::TrainingInput;
    let refuse = |trained, fix| {
        Err(ModelError::Input {
            dir: dir.to_path_buf(),
            trained,
            fed: format!("counts with corrections: {}", input.describe()),
            fix,
        })
    };
    match (model.manifest().training_input(), input.uncorrected_clinical) {
        (TrainingInput::UncorrectedClinical, false) => refuse(
            "a detector's uncorrected clinical counts (its manifest's dataset provenance: corrections \"none: the detector's counts\")",
            "configure a model trained on mono-energetic or corrected counts",
        ),
        (TrainingInput::MonoScale, true) => refuse(
            "counts on the mono-energetic scale (simulated, or clinical counts corrected)",
            "correct the counts (scatter removal and linearisation) or configure a model trained on uncorrected clinical counts",
        ),
        _ => Ok(()),
    }
}

/// A model loaded the firmware's way.
pub struct SignedModel {
    /// The network.
    pub model: Dbtor,
    /// Its glandularity calibration for the loaded precision, `None` only
    /// for a model signed off without a calibration file.
    pub calibration: Option<GlandularityCalibration>,
    /// The calibrations for other beams than W/Rh (beam name, calibration:
    /// [`pick_beam_calibrations`]); a beam without one is refused or
    /// reported physics-only by the pipeline while `calibration` is set
    /// (`dbt_pipeline::UncalibratedBeam`).
    pub beam_calibrations: Vec<(String, GlandularityCalibration)>,
    /// The validation residuals behind the reports' 95 % intervals for the
    /// loaded precision and inputs, `None` where the model has none for
    /// them (the reports then say so).
    pub intervals: Option<dbt_intervals::IntervalTable>,
    /// The verified sign-off.
    pub signoff: Signoff,
}

impl SignedModel {
    /// The network and what its folder gives the processing besides it
    /// ([`dbt_pipeline::PipelineOptions::with_model`] takes both).
    pub fn into_parts(self) -> (Dbtor, dbt_pipeline::ModelSettings) {
        (
            self.model,
            dbt_pipeline::ModelSettings {
                calibration: self.calibration,
                beam_calibrations: self.beam_calibrations,
                intervals: self.intervals,
            },
        )
    }
}

/// The settings of a model loaded without its sign-off (a candidate under
/// evaluation): its calibrations for `classify` and `input`
/// ([`load_calibrations`]: none, logged, where they were fit with another
/// classification) and its report intervals ([`load_intervals`]).
pub fn load_settings(
    model: &Dbtor,
    classify: &ClassifyOptions,
    input: InputCorrections,
) -> Result<dbt_pipeline::ModelSettings, ModelError> {
    let (calibration, beam_calibrations) = load_calibrations(model, classify, input)?;
    Ok(dbt_pipeline::ModelSettings {
        calibration,
        beam_calibrations,
        intervals: load_intervals(model, input)?,
    })
}

/// Load `dir` as the firmware does: [`verify`] against its sign-off and the
/// configured digest `pinned`, load the network (which verifies the ONNX
/// checksums of its manifest), and read the calibration for inputs corrected
/// as `input` ([`pick_calibration`]). A model signed off
/// with a calibration file must have a calibration for this precision and
/// `classify`; a model signed off without one is reported uncalibrated (and
/// logged as such).
pub fn load_signed(
    dir: &Path,
    precision: Precision,
    fp32_blocks: &[String],
    engine: Engine,
    classify: &ClassifyOptions,
    input: InputCorrections,
    pinned: Option<&str>,
) -> Result<SignedModel, ModelError> {
    let signoff = verify(dir, pinned)?;
    let model = Dbtor::load_mixed(dir, precision, fp32_blocks, engine).map_err(|source| {
        ModelError::Network {
            dir: dir.to_path_buf(),
            cause: source,
        }
    })?;
    check_training_input(dir, &model, input)?;
    let mut beam_calibrations = Vec::new();
    let calibration = if signoff.files.contains_key(CALIBRATION_FILE) {
        let path = dir.join(CALIBRATION_FILE);
        let f = CalibrationFile::read(&path, &model)?;
        let label = model.precision_label();
        if f.classification != *classify {
            return Err(CalibrationError {
                path,
                reason: "fit with another tissue classification than the configured one; refit with `dbt-eval calibrate`".into(),
            }
            .into());
        }
        beam_calibrations = pick_beam_calibrations(&f, &label, input);
        for (beam, c) in &beam_calibrations {
            tracing::info!(model = %dir.display(), %beam, offset = c.offset, slope = c.slope, "glandularity calibration for a beam");
        }
        match pick_calibration(&f, &label, input) {
            Some((c, key)) => {
                tracing::info!(model = %dir.display(), calibration = %key, offset = c.offset, slope = c.slope, "glandularity calibration");
                Some(c)
            }
            None => {
                return Err(CalibrationError {
                    path,
                    reason: format!(
                        "no calibration for precision `{label}` (it has {:?}); refit with `dbt-eval calibrate` or configure a calibrated precision",
                        f.calibrations.keys().collect::<Vec<_>>()
                    ),
                }
                .into())
            }
        }
    } else {
        tracing::warn!(model = %dir.display(), "the model was signed off without a glandularity calibration: glandularity reported uncalibrated");
        None
    };
    let intervals = if signoff.files.contains_key(INTERVALS_FILE) {
        let path = dir.join(INTERVALS_FILE);
        let f = IntervalsFile::read(&path, &model)?;
        let label = model.precision_label();
        let t = f.pick(&path, &model, input)?.cloned();
        match &t {
            Some(_) => {
                tracing::info!(model = %dir.display(), key = %input.key(&label), "report intervals")
            }
            None => {
                tracing::warn!(model = %dir.display(), key = %input.key(&label), have = ?f.tables.keys().collect::<Vec<_>>(), "no report intervals for this precision and input: the reports give none")
            }
        }
        t
    } else {
        None
    };
    Ok(SignedModel {
        model,
        calibration,
        beam_calibrations,
        intervals,
        signoff,
    })
}
