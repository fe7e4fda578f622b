//! Baseline reconstructions of one coronal slice, as in the paper:
//! * [`mltr`]: Maximum Likelihood for Transmission tomography (Nuyts et al.
//!   1998), unregularised, with the support limited to the compressed
//!   thickness (the paper's 100 iterations are the caller's choice).
//! * [`Fbp`]: filtered backprojection for the limited-angle fan beam, ramp
//!   filter with a Hann window, a fast look and the U-Net's input.

pub mod fbp;
pub mod mltr;

pub use fbp::Fbp;
pub use mltr::{mltr, MltrOptions, MltrReport};

use dbt_projector::ProjectorError;
use thiserror::Error;

/// Errors of the reconstructions.
#[derive(Debug, Error)]
pub enum ReconError {
    /// A projector call failed (sizes).
    #[error(transparent)]
    Projector(#[from] ProjectorError),
    /// Input arrays of the wrong size.
    #[error("{what} has {got} values, expected {expected}")]
    Size {
        /// Which input.
        what: &'static str,
        /// Its length.
        got: usize,
        /// The expected length.
        expected: usize,
    },
    /// A non-finite or negative count, or a non-positive flux.
    #[error("invalid measurement: {0}")]
    Data(String),
}

pub(crate) fn check_len(what: &'static str, got: usize, expected: usize) -> Result<(), ReconError> {
    if got == expected {
        Ok(())
    } else {
        Err(ReconError::Size {
            what,
            got,
            expected,
        })
    }
}
