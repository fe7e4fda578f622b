//! The pure processing of one acquisition, shared by the firmware (daemon,
//! `dbtor-process`, `dbtor-diag`) and the evaluation (`dbt-eval`): no file,
//! socket or serial line here; the adapters read the acquisition and deliver
//! the reports.
//!
//! * [`acquisition`]: the [`Acquisition`] type and [`validate_header`], the
//!   one header validation of every input (frame link, files, DICOM), from
//!   the intake crate ([`dbt_intake`], where an acquisition is settled);
//! * [`layout`]: what the stages need of the counts' layout, one trait
//!   implemented by the intake's two layouts (slice-wise sinograms,
//!   cone-beam frames);
//! * [`plausibility`]: the counts against the flat field and the thickness,
//!   and the reconstructed breast against its tissues and its box;
//! * [`data_fit`]: how well the reconstruction explains its projections;
//! * [`density_check`]: the reported density against the physics density
//!   of the same counts;
//! * [`process`]: reconstruction, classification, density, dose, reports;
//! * [`model_breast`]: the model breast of a report without a
//!   reconstruction, from the physics density's outline;
//! * [`rebin`]: cone-beam projections as slice-wise fan-beam sinograms;
//! * [`descatter`], [`linearise`], [`noise_match`]: a polychromatic
//!   detector's counts corrected to what the network was trained on.

pub use dbt_intake::acquisition;
pub use dbt_intake::{ConeFrames, ConeHeader, Layout, NotSlices, SliceHeader, SliceSinograms};
pub mod data_fit;
pub mod density_check;
pub mod descatter;
pub mod dicom_input;
pub mod error;
pub mod layout;
pub mod linearise;
pub mod model_breast;
pub mod noise_match;
pub mod plausibility;
pub mod process;
pub mod rebin;

pub use acquisition::{
    validate_header, Acquisition, AcquisitionHeader, HeaderError, Patient, Study, ACQ_FORMAT,
};
pub use dbt_dicom::{FigureInterval, ReportMethod};
pub use plausibility::{CountsCheck, Implausible, VolumeCheck};
pub use process::*;
