//! The daemon's state as the service engineer and the physicist see it.
//!
//! - [`state`]: the status file ([`Status`]), the record of one reported
//!   acquisition ([`AcquisitionRecord`], the spool entry's `result.json`),
//!   the health verdict, and the [`Snapshot`] that the status page and
//!   `dbtor-diag status` both show, with its de-identified form;
//! - [`plot`]: the trend figures (MGD against thickness beside the model
//!   breast's; the glandularity histogram) as SVG;
//! - [`picture`]: an acquisition's quick-look picture (coronal slice, its
//!   classification, axial and sagittal mid-planes) as SVG;
//! - [`page`]: the HTML page and its script.
//!
//! Pure: no I/O. The firmware's `status_page` adapter reads the files and
//! serves HTTP.

pub mod page;
pub mod picture;
pub mod plot;
pub mod state;

pub use state::{
    public_id, valid_entry_id, AcquisitionRecord, DicomInputStatus, FaultRecord, Snapshot, Status,
    WaitingSweep, DENSITY_CHECK_WARNING,
};
