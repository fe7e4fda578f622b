//! DICOM Structured Reports of the product, built with dicom-rs:
//! * [`dose_report`]: X-Ray Radiation Dose SR (TID 10001 with one TID 10003
//!   irradiation event per projection and TID 10005 accumulated mammography
//!   dose), the patient-specific Monte Carlo MGD as DICOM's "Average Glandular
//!   Dose", with the method, its uncertainty and the model-breast estimate;
//! * [`density_report`]: a Comprehensive SR with the glandularity as Percent
//!   Fibroglandular Tissue, the volumes, the BI-RADS-style composition
//!   category, the reconstructor version and the source references.
//!
//! Encoding only: [`Report::to_bytes`] gives the Part 10 file; writing it
//! somewhere is the adapters' job. Reading back is [`read_values`].

mod content;
pub mod reports;

pub use content::{format_ds, Code, Item, Rel};
pub use reports::{
    composition_category, density_report, dose_report, read_values, DensityInput, DoseEvent,
    DoseInput, Equipment, Header, Laterality, Report, UidSource,
};

use thiserror::Error;

/// Errors of report building and reading; each names what was wrong.
#[derive(Debug, Error)]
pub enum DicomError {
    /// An input value cannot be encoded (names the field).
    #[error("report field `{field}`: {reason}")]
    Field {
        /// The input field.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// dicom-rs failed to encode or decode.
    #[error("DICOM encoding: {0}")]
    Encoding(String),
}
