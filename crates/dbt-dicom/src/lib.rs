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
//! somewhere is the adapters' job. Reading back is [`read_values`], after
//! [`bounds::check_lengths`] has checked every element length against the
//! file's size.

pub mod bounds;
mod content;
pub mod dm;
pub mod input;
pub mod projections;
pub mod reports;
pub mod templates;

pub use content::{format_ds, AnodeMaterial, Code, FilterMaterial, Item, Rel, ANODE_TUNGSTEN};
pub use reports::{
    composition_category, composition_code, density_report, dose_report, read_values,
    DensityCheckReport, DensityInput, DoseEvent, DoseInput, Equipment, FigureInterval, Header,
    Laterality, ProcedureIntent, Report, ReportMethod, UidSource,
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

/// DICOM date `YYYYMMDD` and time `HHMMSS` (UTC) of a unix time, by the
/// civil-from-days algorithm (proleptic Gregorian; H. Hinnant,
/// "chrono-Compatible Low-Level Date Algorithms").
pub fn dicom_datetime_utc(unix_secs: u64) -> (String, String) {
    let days = (unix_secs / 86_400) as i64;
    let rem = unix_secs % 86_400;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let y = yoe + era * 400;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = if m <= 2 { y + 1 } else { y };
    (
        format!("{y:04}{m:02}{d:02}"),
        format!("{:02}{:02}{:02}", rem / 3600, (rem / 60) % 60, rem % 60),
    )
}

#[cfg(test)]
mod datetime_tests {
    use super::dicom_datetime_utc;

    #[test]
    fn known_instants() {
        let s = |a: &str, b: &str| (a.to_string(), b.to_string());
        assert_eq!(dicom_datetime_utc(0), s("19700101", "000000"));
        // `date -u -d @1700000000`: Tue Nov 14 22:13:20 UTC 2023.
        assert_eq!(dicom_datetime_utc(1_700_000_000), s("20231114", "221320"));
        // 2024-02-29 (a leap day) 12:00:00 UTC.
        assert_eq!(dicom_datetime_utc(1_709_208_000), s("20240229", "120000"));
    }
}
