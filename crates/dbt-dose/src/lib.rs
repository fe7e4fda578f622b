//! Monte Carlo photon transport for breast dosimetry, 5-50 keV (paper section
//! 3.6; Geant4 there, our own engine here, validated against AAPM TG-195).
//!
//! * Physics ([`physics`]): photoelectric absorption deposited locally,
//!   Rayleigh scattering with atomic form factors, Compton scattering with
//!   Klein-Nishina corrected by the incoherent scattering function `S(x, Z)`;
//!   per-element data from xraylib ([`tables`], generated once by
//!   `data/gen_tables.py` and compiled in).
//! * Materials ([`material`]): mixtures by mass fraction; compositions and
//!   densities come from `dbt-materials` (defined once).
//! * Geometry and tracking ([`scene`], [`transport`]): a voxel grid tracked with
//!   Woodcock (delta) tracking, analytic homogeneous boxes around it, a world
//!   of air; reproducible batches with independent random streams.
//! * [`tg195`]: AAPM TG-195 case 3, the reference this engine must reproduce.

pub mod detector;
pub mod material;
pub mod patient;
pub mod physics;
pub mod scatter;
pub mod scene;
pub mod spectrum;
pub mod tables;
pub mod tg195;
pub mod transport;
pub mod xray;

use thiserror::Error;

pub use material::Material;
pub use scene::{HomogeneousBox, Scene, VoxelGrid};
pub use spectrum::Spectrum;
pub use transport::{
    run, run_observed, run_scored, DetectorScore, PointSource, RunResult, Tallies,
};

/// Errors of the dose engine; each says what was wrong.
#[derive(Debug, Error)]
pub enum DoseError {
    /// The compiled-in tables are inconsistent (a build problem).
    #[error("physics table: {0}")]
    Table(String),
    /// A material cannot be built.
    #[error("material: {0}")]
    Material(String),
    /// The scene is inconsistent.
    #[error("scene: {0}")]
    Scene(String),
    /// A spectrum is malformed.
    #[error("spectrum: {0}")]
    Spectrum(String),
}
