//! The processing's error: each says which step and why.

use crate::acquisition::HeaderError;
use crate::plausibility::Implausible;
use dbt_dose::xray::AnodeFilter;
use thiserror::Error;

/// Errors of the processing; each says which step and why.
#[derive(Debug, Error)]
pub enum PipelineError {
    /// The acquisition cannot be processed as given.
    #[error("acquisition: {0}")]
    Input(String),
    /// A header field is implausible (checked before any work).
    #[error(transparent)]
    Header(#[from] HeaderError),
    /// The counts or the reconstruction cannot come from a breast.
    #[error("implausible acquisition: {0}")]
    Implausible(#[from] Implausible),
    /// DBToR failed.
    #[error("DBToR reconstruction of slice {slice}: {cause}")]
    Dbtor {
        /// Coronal slice.
        slice: usize,
        /// Cause.
        cause: dbt_dbtor::DbtorError,
    },
    /// Reconstruction failed.
    #[error("reconstruction of slice {slice}: {cause}")]
    Recon {
        /// Coronal slice.
        slice: usize,
        /// Cause.
        cause: dbt_recon::ReconError,
    },
    /// Classification failed.
    #[error("classification: {0}")]
    Tissue(#[from] dbt_tissue::TissueError),
    /// Dose computation failed.
    #[error("dose: {0}")]
    Dose(#[from] dbt_dose::DoseError),
    /// Report building failed.
    #[error("report: {0}")]
    Report(#[from] dbt_dicom::DicomError),
    /// Cone-beam projections could not be rebinned.
    #[error("cone-beam rebinning: {0}")]
    Rebin(#[from] crate::rebin::RebinError),
    /// The model's glandularity calibration is not for this beam.
    #[error("anode/filter {0}: the model has no glandularity calibration for this beam (run its bar on validation acquisitions with `dbt-eval beam-bar`, or fit one with `dbt-eval calibrate --anode-filter {0}`); not reported")]
    NoBeamCalibration(AnodeFilter),
}
