//! The product's acquisition as it enters, pure (no file, socket or serial
//! line): every input (the frame link, the DICOM input, a recorded
//! acquisition) builds one [`Acquisition`] and passes the one
//! [`validate_header`]; the daemon then [`settle`]s it, with what the link
//! saw ([`GantryNote`]) and the site's rules ([`SitePolicy`]), into the
//! acquisition the pipeline reports, or a [`Refusal`] that names why.
//!
//! * [`acquisition`]: the acquisition type, its header and the limits of a
//!   plausible header;
//! * [`layout`]: the two layouts of the counts as two types (slice-wise
//!   sinograms, cone-beam frames), decided once;
//! * [`gantry`]: the configured gantry every input checks against;
//! * [`technique`]: a beam's tube output as the site's QC measured it;
//! * [`settle`]: the note, the policy and the rules.

pub mod acquisition;
pub mod gantry;
pub mod layout;
pub mod settle;
pub mod technique;

pub use acquisition::{
    validate_header, Acquisition, AcquisitionHeader, HeaderError, Patient, Study, ACQ_FORMAT,
};
pub use gantry::Gantry;
pub use layout::{
    ConeFrames, ConeHeader, Layout, NotSlices, Projections, SliceHeader, SliceSinograms,
};
pub use settle::{
    settle, GantryNote, Refusal, RefusalKind, RegisterReading, RegisterValues, SitePolicy, Source,
};
pub use technique::{KvTable, TubeOutput};
