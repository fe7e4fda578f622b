//! The pipeline assembled from a site's configuration, in one place: the
//! daemon processes every acquisition with these options, and `dbtor-diag
//! replay --config` replays a spool entry with the same ones, so that a
//! service engineer's replay computes what the daemon reported (the daemon
//! writes the settled header back into the entry for the same reason).

use crate::config::{Config, ConfigError, Reconstructor};
use dbt_pipeline::PipelineOptions;
use std::path::Path;
use std::sync::Arc;

/// Why the processing could not be assembled from the configuration.
#[derive(Debug, thiserror::Error)]
pub enum AssemblyError {
    /// The model folder fails its sign-off, its network does not load, or
    /// its calibration is unusable.
    #[error(transparent)]
    Model(#[from] dbt_model::ModelError),
    /// A resource the processing needs is missing or unusable.
    #[error("{what}: {reason}")]
    Resource {
        /// The resource (a configuration key and its value).
        what: String,
        /// Why it cannot be used.
        reason: String,
    },
    /// Bad configuration.
    #[error(transparent)]
    Config(#[from] ConfigError),
}

/// The processing options of the site configured by `cfg` (read from
/// `config_path`, against which its relative paths resolve): the
/// reconstructor, the signed model with its calibrations and noise
/// matching, the counts' corrections, the slice step, the Monte Carlo's
/// uncertainty. Everything the daemon's reports depend on beyond the
/// acquisition itself.
pub fn pipeline_options(
    cfg: &Config,
    config_path: &Path,
) -> Result<PipelineOptions, AssemblyError> {
    let mut opts = PipelineOptions {
        mltr_iterations: cfg.recon.mltr_iterations,
        dose_uncertainty: cfg.recon.dose_uncertainty,
        linearise: cfg.linearise(),
        descatter: cfg.descatter(config_path)?,
        slice_step: cfg.recon.slice_step,
        uncalibrated_beam: cfg.recon.uncalibrated_beam.pipeline(),
        ..PipelineOptions::default()
    };
    match cfg.recon.reconstructor {
        Reconstructor::Dbtor => {
            let signed = load_model(cfg, &opts.classify)?;
            opts = with_model(opts, signed, noise_match_key(cfg))?;
        }
        Reconstructor::Physics => opts.method = dbt_dicom::ReportMethod::PhysicsOnly,
        Reconstructor::Mltr => {}
    }
    Ok(opts)
}

/// `opts` with a signed model in it: the network, its glandularity
/// calibrations (the loaded precision's and each beam's) and report
/// intervals, and, where `noise_match` names what asked for it (a
/// configuration key, a command-line option), the counts' noise matched to
/// its training level (a model that names no photon level is refused,
/// naming what asked): [`PipelineOptions::with_model`], the one place a
/// model becomes processing options, here for the daemon and replay
/// (through [`pipeline_options`]) and `dbtor-process`.
pub fn with_model(
    opts: PipelineOptions,
    signed: dbt_model::SignedModel,
    noise_match: Option<&str>,
) -> Result<PipelineOptions, AssemblyError> {
    let (model, settings) = signed.into_parts();
    opts.with_model(Arc::new(model), settings, noise_match)
        .map_err(refused)
}

/// The configured DBToR model, loaded the firmware's way: the sign-off and
/// the configured digest first, then the ONNX checksums, and the
/// calibration for the configured precision (`Config::load` checked the
/// manifest's geometry and validated precision and engine).
pub(crate) fn load_model(
    cfg: &Config,
    classify: &dbt_tissue::ClassifyOptions,
) -> Result<dbt_model::SignedModel, AssemblyError> {
    let dir = cfg.recon.model.clone().unwrap_or_default();
    let (precision, engine) = (cfg.recon.precision, cfg.recon.engine);
    Ok(dbt_model::load_signed(
        &dir,
        precision,
        &cfg.recon.fp32_blocks,
        engine,
        classify,
        cfg.input_corrections(),
        cfg.recon.model_digest.as_deref(),
    )?)
}

/// The configured noise matching (`recon.noise_match`) to `model`'s
/// training level: `None` when off; a model that names no photon level is
/// refused naming the key.
pub fn noise_match(
    cfg: &Config,
    model: &dbt_dbtor::ModelManifest,
) -> Result<Option<dbt_pipeline::noise_match::NoiseMatch>, AssemblyError> {
    dbt_pipeline::matched_noise(noise_match_key(cfg), model).map_err(refused)
}

/// A refused noise matching as the assembly's error, naming what asked.
fn refused(e: dbt_pipeline::NoiseMatchRefused) -> AssemblyError {
    AssemblyError::Resource {
        what: e.asked,
        reason: e.cause.to_string(),
    }
}

/// The configuration's key and value that ask for noise matching, or
/// `None` when it is off.
fn noise_match_key(cfg: &Config) -> Option<&'static str> {
    (cfg.recon.noise_match == crate::config::NoiseMatchMode::TrainingLevel)
        .then_some("recon.noise_match = \"training-level\"")
}
