//! Processing of one acquisition, from counts to report contents: the
//! header's validation and the counts' plausibility first, then per coronal
//! slice reconstruction (DBToR with a trained model, or MLTR, the paper's
//! baseline, as the fallback chosen by configuration), stacking into a volume, tissue classification, density,
//! Monte Carlo MGD (patient-specific and model breast), and the two DICOM
//! reports, with the reconstructed breast's plausibility checked before any
//! figure is returned. Pure: the adapters read the acquisition and deliver
//! the reports.

use crate::acquisition::{validate_header, Acquisition, AcquisitionHeader};
use crate::layout::RayLayout;
use crate::plausibility::{
    check_counts_with, check_volume, footprint_mm, CountsCheck, VolumeCheck,
};
use dbt_dicom::{
    density_report, dose_report, DensityInput, DoseEvent, DoseInput, Equipment, FigureInterval,
    Header, Laterality, ProcedureIntent, Report, ReportMethod, UidSource,
};
use dbt_dose::patient::{mgd_to_uncertainty_on, Breast, DoseGeometry, MgdResult, Model};
use dbt_dose::xray::AnodeFilter;
use dbt_forward::log_transform;
use dbt_intake::{ConeFrames, ConeHeader, Layout, Projections, SliceHeader, SliceSinograms};
use dbt_projector::Projector;
use dbt_recon::{mltr, MltrOptions};
use dbt_tissue::{
    classify, density, Classification, ClassifyOptions, Density, GlandularityCalibration,
};
use rayon::prelude::*;
use serde::Serialize;

pub use crate::error::PipelineError;

/// Options of the processing.
#[derive(Debug, Clone, Serialize)]
pub struct PipelineOptions {
    /// The DBToR model; `None` selects MLTR.
    #[serde(skip)]
    pub dbtor: Option<std::sync::Arc<dbt_dbtor::Dbtor>>,
    /// MLTR iterations (the paper: 100), when MLTR is the reconstructor.
    pub mltr_iterations: usize,
    /// Target relative statistical uncertainty of the MGD.
    pub dose_uncertainty: f64,
    /// Monte Carlo seed.
    pub seed: u64,
    /// Tissue classification (default: the skin a `dbt_tissue::SKIN_MAX_MM`
    /// shell).
    pub classify: ClassifyOptions,
    /// Calibration of the reported (partial-volume) glandularity, fit for
    /// this reconstructor on validation phantoms
    /// (`dbt_model::load_calibrations` reads it from the model folder).
    pub calibration: Option<GlandularityCalibration>,
    /// The calibrations of acquisitions with another beam than the paper's
    /// W/Rh, which `calibration` is for (issue #27: the linearisation of a
    /// W/Al beam leaves another contrast, eval/README.md "W/Al"); a beam
    /// without one is never reported with the W/Rh calibration while
    /// `calibration` is set: refused or physics-only
    /// ([`PipelineOptions::uncalibrated_beam`]).
    #[serde(skip)]
    pub beam_calibrations: Vec<(AnodeFilter, GlandularityCalibration)>,
    /// Beam-hardening linearisation of a polychromatic detector's counts
    /// before anything reads them (issue #27); `None`: the counts are
    /// taken as mono-energetic.
    #[serde(skip)]
    pub linearise: Option<crate::linearise::BeamHardening>,
    /// Scatter removal before the linearisation (issue #27); `None`: the
    /// counts are taken as primary.
    #[serde(skip)]
    pub descatter: Option<crate::descatter::ScatterRemoval>,
    /// Noise matching after the linearisation (issue #27,
    /// [`crate::noise_match`]); `None`: the corrected counts as they are.
    #[serde(skip)]
    pub noise_match: Option<crate::noise_match::NoiseMatch>,
    /// Reconstruct every `slice_step`-th coronal slice (and the last one),
    /// the slices between interpolated linearly in depth (issue #29 point
    /// 5: density and dose may not need every detector row); 1: every
    /// slice. The volume keeps every slice's depth, so the dose grid stays
    /// isotropic.
    pub slice_step: usize,
    /// The reconstructor reads counts with their scatter and beam hardening
    /// left in (a network trained on uncorrected clinical acquisitions:
    /// issue #27's other design, `dbt-eval --uncorrected`): the counts check
    /// then expects elements beside the breast above the flat field
    /// ([`crate::plausibility::check_counts_with`]). Refused together with
    /// either correction.
    pub scatter_in_input: bool,
    /// The limits of the cross-check against the physics density
    /// ([`crate::density_check::LIMITS`] unless a test sets others).
    pub density_limits: crate::density_check::CheckLimits,
    /// The validation residuals of this reconstructor and input (the model
    /// folder's `report-intervals.json`, `dbt_model::load_signed`), from
    /// which the reported figures get their 95 % intervals (issue #48
    /// point 4); `None`: the reports say no interval is given and why.
    /// W/Rh acquisitions only: they were made on W/Rh validation breasts.
    #[serde(skip)]
    pub intervals: Option<std::sync::Arc<dbt_intervals::IntervalTable>>,
    /// How the figures are made (issue #51 point 3): a reconstruction (the
    /// default; DBToR where `dbtor` is set, else MLTR), or, on a gantry for
    /// which no model is trained, the physics density alone and the model
    /// breast's dose ([`process_layout`]'s physics-only branch).
    pub method: ReportMethod,
    /// Where a physics-only report's model breast holds its glandular
    /// tissue ([`crate::model_breast::Placement`]).
    pub physics_breast: crate::model_breast::Placement,
    /// Which edge profile the physics density's rim takes
    /// ([`dbt_physics_density::RimShape`]; per sector as shipped, the
    /// others an evaluation option: eval/physics-density.md).
    pub physics_rim: dbt_physics_density::RimShape,
    /// What becomes of an acquisition whose beam the model has no
    /// glandularity calibration for ([`PipelineOptions::for_beam`]).
    pub uncalibrated_beam: UncalibratedBeam,
}

/// What the processing does with an acquisition whose beam the calibrated
/// model has no glandularity calibration for (issue #51 point 3: a useful
/// report on every gantry, never a refusal for want of a model).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub enum UncalibratedBeam {
    /// Refused, naming the beam ([`PipelineError::NoBeamCalibration`]):
    /// the evaluation's choice, so that no figure made another way enters
    /// a table of the model's.
    #[default]
    Refuse,
    /// Reported physics-only ([`ReportMethod::PhysicsOnly`]: the
    /// physics-based density, the model breast's MGD, each report naming
    /// the method; no network, calibration, noise matching or interval):
    /// the firmware's default (`recon.uncalibrated_beam`).
    PhysicsOnly,
}

impl Default for PipelineOptions {
    fn default() -> Self {
        Self {
            dbtor: None,
            mltr_iterations: 100,
            dose_uncertainty: 0.01,
            seed: 1,
            classify: ClassifyOptions::default(),
            calibration: None,
            beam_calibrations: Vec::new(),
            linearise: None,
            descatter: None,
            noise_match: None,
            slice_step: 1,
            scatter_in_input: false,
            density_limits: crate::density_check::LIMITS,
            intervals: None,
            method: ReportMethod::Reconstruction,
            physics_breast: crate::model_breast::Placement::CentralColumns,
            physics_rim: dbt_physics_density::RimShape::PerSector,
            uncalibrated_beam: UncalibratedBeam::Refuse,
        }
    }
}

/// A model's calibrations for other beams as its calibration file names
/// them (`dbt_model::pick_beam_calibrations`), by beam; a name that is no
/// beam the dose model knows is left out, logged.
pub fn beam_calibrations(
    named: &[(String, GlandularityCalibration)],
) -> Vec<(AnodeFilter, GlandularityCalibration)> {
    named
        .iter()
        .filter_map(|(name, c)| match AnodeFilter::parse(name) {
            Ok(b) => Some((b, *c)),
            Err(e) => {
                tracing::warn!(beam = %name, "calibration for an unknown beam left out: {e}");
                None
            }
        })
        .collect()
}

/// What a model folder gives the processing besides its network: the
/// glandularity calibration of the loaded precision and inputs, the other
/// beams' (by the names the calibration file gives them), and the
/// validation residuals behind the reports' intervals
/// (`dbt_model::load_settings` reads them).
#[derive(Debug, Clone, Default)]
pub struct ModelSettings {
    /// The calibration for W/Rh, `None` for a model without one.
    pub calibration: Option<GlandularityCalibration>,
    /// The other beams' calibrations, by beam name.
    pub beam_calibrations: Vec<(String, GlandularityCalibration)>,
    /// The report intervals' residuals, `None` where the model has none.
    pub intervals: Option<dbt_intervals::IntervalTable>,
}

/// Noise matching was asked for a model that cannot be matched.
#[derive(Debug, thiserror::Error)]
#[error("{asked}: {cause}")]
pub struct NoiseMatchRefused {
    /// What asked for it (a configuration key, a command-line option).
    pub asked: String,
    /// Why the model cannot be matched.
    pub cause: crate::noise_match::NoiseMatchError,
}

/// The noise matching to `model`'s training level where `asked` names what
/// asked for it (a configuration key, a command-line option), refused
/// naming it when the model names no photon level; `None` when not asked.
pub fn matched_noise(
    asked: Option<&str>,
    model: &dbt_dbtor::ModelManifest,
) -> Result<Option<crate::noise_match::NoiseMatch>, NoiseMatchRefused> {
    asked
        .map(|asked| {
            crate::noise_match::NoiseMatch::for_model(model).map_err(|cause| NoiseMatchRefused {
                asked: asked.to_string(),
                cause,
            })
        })
        .transpose()
}

impl PipelineOptions {
    /// These options with the network `model` and its folder's `settings`
    /// (calibrations, report intervals), and, where `noise_match` names
    /// what asked for it (a configuration key, a command-line option), the
    /// counts' noise matched to the model's training level (a model that
    /// names no photon level is refused, naming what asked). The one place
    /// a model becomes processing options: the daemon, replay,
    /// `dbtor-process` (through `firmware::assembly`), `dbt-eval accuracy`
    /// and the pipeline benchmark use it.
    pub fn with_model(
        mut self,
        model: std::sync::Arc<dbt_dbtor::Dbtor>,
        settings: ModelSettings,
        noise_match: Option<&str>,
    ) -> Result<Self, NoiseMatchRefused> {
        self.noise_match = matched_noise(noise_match, model.manifest())?;
        self.calibration = settings.calibration;
        self.beam_calibrations = beam_calibrations(&settings.beam_calibrations);
        self.intervals = settings.intervals.map(std::sync::Arc::new);
        self.dbtor = Some(model);
        Ok(self)
    }

    /// The options for an acquisition with the beam `beam`: `calibration`
    /// replaced by the beam's own for another beam than W/Rh where there is
    /// one; when there is none and the options are calibrated (for W/Rh),
    /// refused naming the beam, or the physics-only options
    /// ([`UncalibratedBeam`]). A beam that reads the W/Rh calibration
    /// does so through an entry of its own in the model's signed
    /// calibration file, written where the model passed the bar
    /// (`dbt-eval beam-bar --write`): never by default, for every model.
    pub fn for_beam(
        &self,
        beam: AnodeFilter,
    ) -> Result<std::borrow::Cow<'_, PipelineOptions>, PipelineError> {
        use std::borrow::Cow;
        if beam == AnodeFilter::WRh {
            return Ok(Cow::Borrowed(self));
        }
        match self.beam_calibrations.iter().find(|(b, _)| *b == beam) {
            Some((_, c)) => Ok(Cow::Owned(PipelineOptions {
                calibration: Some(*c),
                ..self.clone()
            })),
            None if self.calibration.is_some() => match self.uncalibrated_beam {
                UncalibratedBeam::Refuse => Err(PipelineError::NoBeamCalibration(beam)),
                UncalibratedBeam::PhysicsOnly => {
                    tracing::warn!(
                        beam = beam.name(),
                        "the model has no glandularity calibration for this beam: reported physics-only"
                    );
                    Ok(Cow::Owned(PipelineOptions {
                        method: ReportMethod::PhysicsOnly,
                        dbtor: None,
                        calibration: None,
                        beam_calibrations: Vec::new(),
                        noise_match: None,
                        intervals: None,
                        ..self.clone()
                    }))
                }
            },
            None => Ok(Cow::Borrowed(self)),
        }
    }
}

/// Everything the processing found.
#[derive(Debug, Clone, Serialize)]
pub struct ProcessResult {
    /// Reconstructor used.
    pub reconstructor: String,
    /// What exactly produced the result ([`algorithm_version`]): the
    /// reports' Algorithm Version.
    pub algorithm_version: String,
    /// Volume dimensions `[lateral, vertical, depth]`.
    pub dims: [usize; 3],
    /// Voxel side, mm.
    pub voxel_mm: f64,
    /// Reconstructed attenuation, 1/mm.
    #[serde(skip)]
    pub mu: Vec<f32>,
    /// Classification summary (labels skipped in JSON).
    pub classification: Classification,
    /// Density estimates.
    pub density: Density,
    /// The physics-based density of the same counts (issue #48 point 2:
    /// `dbt_physics_density`, no learning), or why none could be made.
    pub physics_density: Result<dbt_physics_density::PhysicsDensity, String>,
    /// How well the reconstruction explains its projections
    /// ([`crate::data_fit`]); `None` without a reconstruction.
    pub data_fit: Option<crate::data_fit::DataFit>,
    /// How the figures were made.
    pub method: ReportMethod,
    /// The reported glandularity cross-checked against the physics density
    /// (issue #48 point 3): unconfirmed, the density report asserts no
    /// composition category.
    pub density_check: crate::density_check::DensityCheck,
    /// The reported glandularity: the partial-volume estimate, calibrated
    /// when [`PipelineOptions::calibration`] is set.
    pub glandularity: f64,
    /// Whether `glandularity` is calibrated.
    pub calibrated: bool,
    /// The gantry the dose was simulated on (the acquisition's cone-beam
    /// system, or the paper's).
    pub dose_geometry: DoseGeometry,
    /// Patient-specific Monte Carlo MGD (the model breast's, the same as
    /// `dose_model`, in a physics-only report).
    pub dose_patient: MgdResult,
    /// Model-breast MGD.
    pub dose_model: MgdResult,
    /// Incident air kerma at the reference point of the sweep, mGy.
    pub kerma_mgy: f64,
    /// Patient-specific MGD of the sweep, mGy.
    pub mgd_mgy: f64,
    /// Model-breast MGD of the sweep, mGy.
    pub model_mgd_mgy: f64,
    /// The 95 % intervals of the reported glandularity and MGD, or why
    /// none is given ([`report_intervals`]).
    pub intervals: ReportIntervals,
    /// Where the physics did not confirm the density: the model breast's
    /// MGD of the sweep at the physics density's glandularity, mGy (the
    /// dose report gives it beside the patient's).
    pub model_mgd_at_physics_mgy: Option<f64>,
    /// The tube spectrum the dose used (paper Table 3 for the thickness).
    pub tube: dbt_dose::xray::TubeSpectrum,
    /// The plausibility checks' measurements.
    pub plausibility: Plausibility,
    /// Quality flags the report carries (empty when nothing was corrected).
    pub flags: Vec<String>,
    /// Wall-clock seconds of each stage (for the service engineer and the
    /// pipeline benchmark; not reported).
    pub stage_seconds: StageSeconds,
}

/// Wall-clock seconds of each stage of [`process_with_progress`], in order.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct StageSeconds {
    /// Coronal slices reconstructed (of a cone-beam acquisition's rebinned
    /// slices; with a slice step, only those reconstructed), for the time
    /// per slice.
    pub slices: usize,
    /// Scatter removal, linearisation, a cone-beam acquisition's frames
    /// checked and rebinned to slice-wise sinograms.
    pub corrections: f64,
    /// Every slice reconstructed and stacked (a cone-beam stack resampled
    /// in depth).
    pub reconstruction: f64,
    /// Tissue classification, the volume's plausibility, the density and
    /// the physics density ([`physics_density`]).
    pub classification: f64,
    /// The patient-specific Monte Carlo dose.
    pub dose_patient: f64,
    /// The model breast's Monte Carlo dose.
    pub dose_model: f64,
}

impl StageSeconds {
    /// The sum of the stages.
    pub fn total(&self) -> f64 {
        self.corrections
            + self.reconstruction
            + self.classification
            + self.dose_patient
            + self.dose_model
    }
}

/// What the plausibility checks measured on an acquisition that passed them.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Plausibility {
    /// The counts against the flat field and the thickness.
    pub counts: CountsCheck,
    /// The reconstructed breast against its tissues and its box.
    pub volume: VolumeCheck,
}

/// Reconstruct, classify, and compute density and dose.
pub fn process(acq: &Acquisition, opts: &PipelineOptions) -> Result<ProcessResult, PipelineError> {
    process_with_progress(acq, opts, &mut |_| {})
}

/// Where [`process_with_progress`] is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Stage {
    /// Slice `done` of `total` reconstructed.
    Slice {
        /// Slices reconstructed so far.
        done: usize,
        /// Slices in the acquisition.
        total: usize,
    },
    /// Tissue classification and density.
    Classification,
    /// The Monte Carlo dose runs.
    Dose,
}

/// The reconstructed volume of an acquisition, before classification.
#[derive(Debug, Clone)]
pub struct Volume {
    /// Reconstructor used.
    pub reconstructor: String,
    /// Dimensions `[lateral, vertical, depth]` (vertical: the image rows
    /// within the compressed thickness, 0 on the support).
    pub dims: [usize; 3],
    /// Voxel side, mm.
    pub voxel_mm: f64,
    /// Attenuation, 1/mm, lateral fastest.
    pub mu: Vec<f32>,
    /// The counts' plausibility check (defects corrected before the
    /// reconstruction).
    pub counts_check: CountsCheck,
    /// The breast's footprint per slice, mm
    /// ([`crate::plausibility::footprint_mm`]).
    pub footprint_mm: Vec<f64>,
}

/// The reconstructor of `opts` in words, as results, status and tables name
/// it: `DBToR NAME (PRECISION, ENGINE[, raw][, calibrated])` (raw: a DBToR
/// model without its support, or any model without its non-negativity) or
/// `MLTR N iterations`.
pub fn reconstructor_name(opts: &PipelineOptions) -> String {
    if opts.method == ReportMethod::PhysicsOnly {
        return format!(
            "none: physics-based density (no DBToR model trained and calibrated for this gantry and beam; model breast {})",
            match opts.physics_breast {
                crate::model_breast::Placement::Homogeneous => "homogeneous",
                crate::model_breast::Placement::CentralColumns => "central columns",
            }
        );
    }
    let name = match &opts.dbtor {
        Some(m) => format!(
            "DBToR {} ({}, {}{}{})",
            m.manifest().name,
            m.precision_label(),
            m.engine(),
            if (m.manifest().uses_mask() && !m.support()) || !m.constraints().nonnegative {
                ", raw"
            } else {
                ""
            },
            if opts.calibration.is_some() {
                ", calibrated"
            } else {
                ""
            }
        ),
        None => format!("MLTR {} iterations", opts.mltr_iterations),
    };
    if opts.slice_step > 1 {
        format!("{name}, every {} slice", ordinal(opts.slice_step))
    } else {
        name
    }
}

/// `2nd`, `3rd`, `4th`, ... (for the slice step in words).
fn ordinal(n: usize) -> String {
    let suffix = match (n % 10, n % 100) {
        (1, r) if r != 11 => "st",
        (2, r) if r != 12 => "nd",
        (3, r) if r != 13 => "rd",
        _ => "th",
    };
    format!("{n}{suffix}")
}

/// The slices of `n` that [`reconstruct_volume`] reconstructs with
/// `step`: 0, step, 2 step, ... and the last one.
pub fn reconstructed_slices(n: usize, step: usize) -> Vec<usize> {
    let mut v: Vec<usize> = (0..n).step_by(step.max(1)).collect();
    if n > 0 && v.last() != Some(&(n - 1)) {
        v.push(n - 1);
    }
    v
}

/// The corrections made to the counts before everything else, as the
/// Algorithm Version states them (`None`: the counts as received): the
/// scatter removal, the beam-hardening linearisation with the detector it
/// was computed for, the noise matching.
fn corrections_clause(opts: &PipelineOptions) -> Option<String> {
    let mut parts = Vec::new();
    if opts.descatter.is_some() {
        parts.push("scatter removed (the shipped kernel model)".to_string());
    }
    if let Some(bh) = &opts.linearise {
        parts.push(format!(
            "beam hardening linearised for {}",
            bh.detector.converter
        ));
    }
    if opts.noise_match.is_some() {
        parts.push("noise matched to the model's training level".to_string());
    }
    (!parts.is_empty()).then(|| format!("counts corrected: {}", parts.join(", ")))
}

/// What exactly produced a result, for the reports' Algorithm Version: the
/// model's name and the SHA-256 of its manifest (which pins every ONNX
/// file by its own SHA-256), the precision and engine, the glandularity
/// calibration in use, and this software's version; for MLTR, its
/// iterations.
pub fn algorithm_version(opts: &PipelineOptions) -> String {
    let software = match corrections_clause(opts) {
        Some(c) => format!("{c}; dbt-pipeline {}", env!("CARGO_PKG_VERSION")),
        None => concat!("dbt-pipeline ", env!("CARGO_PKG_VERSION")).to_string(),
    };
    if opts.method == ReportMethod::PhysicsOnly {
        return format!(
            "physics-based density (the central view), model-breast Monte Carlo dose on the gantry's geometry (glandular tissue {}); no learned model; {software}",
            match opts.physics_breast {
                crate::model_breast::Placement::Homogeneous => "mixed homogeneously",
                crate::model_breast::Placement::CentralColumns =>
                    "in each column's middle, by its ray's dense share",
            }
        );
    }
    let software = if opts.slice_step > 1 {
        format!(
            "every {} coronal slice reconstructed, those between interpolated in depth; {software}",
            ordinal(opts.slice_step)
        )
    } else {
        software
    };
    let calibration = match &opts.calibration {
        Some(c) if c.per_mm != 0.0 => format!(
            "glandularity calibrated G = {:.5} + {:.5} x partial-volume estimate {:+.6} x (thickness - {} mm)",
            c.offset,
            c.slope,
            c.per_mm,
            dbt_tissue::CALIBRATION_THICKNESS_REF_MM
        ),
        Some(c) => format!(
            "glandularity calibrated G = {:.5} + {:.5} x partial-volume estimate",
            c.offset, c.slope
        ),
        None => "glandularity uncalibrated (partial-volume estimate)".into(),
    };
    match &opts.dbtor {
        Some(m) => format!(
            "model {} (manifest sha256:{}), {} on the {} engine, {calibration}; {software}",
            m.manifest().name,
            if m.manifest().file_sha256.is_empty() {
                "unknown"
            } else {
                &m.manifest().file_sha256
            },
            m.precision_label(),
            m.engine(),
        ),
        // Uncalibrated MLTR says no more than it did (the calibration is a
        // learned model's); a calibrated one states it.
        None if opts.calibration.is_some() => format!(
            "MLTR, {} iterations (no learned model), {calibration}; {software}",
            opts.mltr_iterations
        ),
        None => format!(
            "MLTR, {} iterations (no learned model); {software}",
            opts.mltr_iterations
        ),
    }
}

/// A polychromatic detector's counts as `opts` asks: the scatter removed,
/// then the beam hardening linearised (every check and the reconstruction
/// read mono-energetic primary counts); `acq` itself where `opts` asks for
/// neither. The header is validated first (the corrections use its flux,
/// thickness and technique).
pub fn correct_counts<'a, H: RayLayout>(
    acq: &'a Projections<H>,
    opts: &PipelineOptions,
) -> Result<std::borrow::Cow<'a, Projections<H>>, PipelineError> {
    acq.header.validate()?;
    if opts.descatter.is_none() && opts.linearise.is_none() {
        refuse_inconsistent_corrections(opts)?;
        return Ok(std::borrow::Cow::Borrowed(acq));
    }
    let mut a = acq.clone();
    correct_in_place(&mut a, opts)?;
    Ok(std::borrow::Cow::Owned(a))
}

/// Corrections `opts` cannot apply together: counts read with their
/// scatter and corrected, or noise matched without the linearisation.
fn refuse_inconsistent_corrections(opts: &PipelineOptions) -> Result<(), PipelineError> {
    if opts.scatter_in_input && (opts.descatter.is_some() || opts.linearise.is_some()) {
        return Err(PipelineError::Input(
            "counts read with their scatter left in (scatter_in_input) cannot also be corrected: \
             a network reads either the corrected counts or the detector's"
                .into(),
        ));
    }
    if opts.noise_match.is_some() && opts.linearise.is_none() {
        return Err(PipelineError::Input(
            "noise matching works on linearised counts: configure the beam-hardening linearisation too"
                .into(),
        ));
    }
    Ok(())
}

/// [`correct_counts`] of counts the caller owns, in place (the header
/// already validated).
fn correct_in_place<H: RayLayout>(
    a: &mut Projections<H>,
    opts: &PipelineOptions,
) -> Result<(), PipelineError> {
    refuse_inconsistent_corrections(opts)?;
    // A linearisation for another detector than the system's, refused
    // before any correction is made.
    if let Some(bh) = &opts.linearise {
        bh.check_converter(&a.header)
            .map_err(|e| PipelineError::Input(e.to_string()))?;
    }
    // The detector's counts, as read: the noise matching's other input.
    let raw = opts.noise_match.map(|_| a.counts.clone());
    if let Some(sr) = &opts.descatter {
        let spr = sr
            .apply(&a.header, &mut a.counts)
            .map_err(|e| PipelineError::Input(e.to_string()))?;
        tracing::debug!(spr, "scatter removed");
    }
    // The primary the scatter removal left: the noise matching's input.
    let primary = opts.noise_match.map(|_| a.counts.clone());
    if let Some(bh) = &opts.linearise {
        let n = bh
            .apply(&a.header, &mut a.counts)
            .map_err(|e| PipelineError::Input(e.to_string()))?;
        tracing::debug!(counts = n, "beam hardening linearised");
        if let (Some(nm), Some(raw), Some(primary)) = (&opts.noise_match, &raw, &primary) {
            let r = nm
                .apply(&a.header, bh, raw, primary, &mut a.counts)
                .map_err(|e| PipelineError::Input(e.to_string()))?;
            tracing::debug!(
                variance_per_signal = r.variance_per_signal,
                air_pairs = r.air_pairs,
                matched = r.matched,
                mean_ratio = r.mean_ratio,
                "noise matched"
            );
        }
    }
    Ok(())
}

/// Reconstruct every coronal slice of `acq` with the reconstructor of
/// `opts` (its counts as received: [`correct_counts`] first for a
/// polychromatic detector's) and stack the rows within the compressed thickness into a volume,
/// calling `progress` after each slice.
pub fn reconstruct_volume(
    acq: &SliceSinograms,
    opts: &PipelineOptions,
    progress: &mut dyn FnMut(Stage),
) -> Result<Volume, PipelineError> {
    let h = &acq.header;
    h.validate()?;
    preflight(h, opts)?;
    // The counts last: every cheaper refusal above comes first.
    let (counts, counts_check) = checked_counts(h, &acq.counts, opts.scatter_in_input)?;
    reconstruct_checked(h, &counts, counts_check, opts, progress)
}

/// The counts of `h` checked ([`check_counts_with`]) and their defects
/// corrected (borrowed where there were none).
fn checked_counts<'a, H: RayLayout>(
    h: &H,
    counts: &'a [Vec<f32>],
    scatter_in_counts: bool,
) -> Result<crate::plausibility::Corrected<'a>, PipelineError> {
    let (counts, check) = check_counts_with(h, counts, scatter_in_counts)?.applied(counts)?;
    if let std::borrow::Cow::Owned(_) = counts {
        tracing::warn!(
            corrected = check.corrected,
            rows = h.stack().rows,
            "defective detector counts corrected"
        );
    }
    Ok((counts, check))
}

/// The refusals of an acquisition's header and `opts` that need no count:
/// the slice spacing against the pixel, the thickness against the image,
/// the slice step, the model's geometry.
fn preflight(h: &AcquisitionHeader, opts: &PipelineOptions) -> Result<(), PipelineError> {
    let g = &h.geometry;
    if (h.slice_spacing_mm - g.image.pixel_mm).abs() > 1e-6 {
        return Err(PipelineError::Input(format!(
            "slice spacing {} mm differs from the pixel {} mm (the dose grid must be isotropic)",
            h.slice_spacing_mm, g.image.pixel_mm
        )));
    }
    // A breast taller than the image would be cut off at the top (its
    // rows outside the grid), silently biasing the density: refuse it.
    if h.thickness_mm > g.height_mm() {
        return Err(PipelineError::Input(format!(
            "compressed thickness {:.1} mm exceeds the image height {:.1} mm of the geometry ({}): \
             reconstruct it on a taller image (the paper-tall geometry, 80 mm) with a model trained for it",
            h.thickness_mm,
            g.height_mm(),
            g.describe()
        )));
    }
    if g.rows_within_thickness(h.thickness_mm) == 0 {
        return Err(PipelineError::Input(format!(
            "thickness {} mm holds no image row",
            h.thickness_mm
        )));
    }
    if opts.slice_step == 0 {
        return Err(PipelineError::Input(
            "slice step 0: the step between reconstructed slices is at least 1 (1: every slice)"
                .into(),
        ));
    }
    if let Some(m) = &opts.dbtor {
        if m.geometry() != g {
            return Err(PipelineError::Input(format!(
                "the acquisition's geometry ({}) is not the model's ({}); use a model trained for it or MLTR",
                g.describe(),
                m.geometry().describe()
            )));
        }
    }
    Ok(())
}

/// [`reconstruct_volume`] of sinograms already checked ([`preflight`],
/// the counts' check `counts_check`, their defects corrected in `counts`).
fn reconstruct_checked(
    h: &SliceHeader,
    counts: &[Vec<f32>],
    counts_check: CountsCheck,
    opts: &PipelineOptions,
    progress: &mut dyn FnMut(Stage),
) -> Result<Volume, PipelineError> {
    let g = &h.geometry;
    let (rows, cols) = (g.image.rows, g.image.columns);
    let nv = g.rows_within_thickness(h.thickness_mm);
    let mopts = MltrOptions {
        iterations: opts.mltr_iterations,
        track_likelihood: false,
    };
    let proj = Projector::new(g);
    let mask = dbt_phantom::thickness_mask(g, h.thickness_mm);
    let nd = counts.len();
    let mut mu = vec![0f32; cols * nv * nd];
    let reconstructor = reconstructor_name(opts);
    let span = tracing::Span::current();
    let slice = |d: usize, counts: &[f32]| -> Result<Vec<f32>, PipelineError> {
        let _s = tracing::debug_span!(parent: &span, "slice", d).entered();
        match &opts.dbtor {
            Some(m) => m
                .reconstruct(&log_transform(counts, h.flux), h.thickness_mm)
                .map_err(|source| PipelineError::Dbtor {
                    slice: d,
                    cause: source,
                }),
            None => mltr(&proj, counts, h.flux, &mask, &mopts)
                .map(|r| r.0)
                .map_err(|source| PipelineError::Recon {
                    slice: d,
                    cause: source,
                }),
        }
    };
    // As many slices in flight as the pool has threads, each on its own
    // worker (the loops inside a slice still share the idle workers): one
    // slice's serial parts (normalisation, the waits at the end of each
    // block) no longer idle the other core. A slice's result does not
    // depend on it (the kernels split rows, never sums); the slices are
    // stacked, reported and their errors returned in order.
    let in_flight = rayon::current_num_threads().max(1);
    let wanted = reconstructed_slices(nd, opts.slice_step);
    let (total, slab) = (wanted.len(), nv * cols);
    let mut done = 0;
    for chunk in wanted.chunks(in_flight) {
        let imgs: Vec<Result<Vec<f32>, PipelineError>> =
            chunk.par_iter().map(|&d| slice(d, &counts[d])).collect();
        for (&d, img) in chunk.iter().zip(imgs) {
            let img = img?;
            // Image row r (0 at the top) -> vertical index rows - 1 - r.
            for v in 0..nv {
                let r = rows - 1 - v;
                let dst = (d * nv + v) * cols;
                mu[dst..dst + cols].copy_from_slice(&img[r * cols..(r + 1) * cols]);
            }
            done += 1;
            progress(Stage::Slice { done, total });
        }
    }
    // With a slice step, the slices between two reconstructed ones,
    // linearly in depth.
    for w in wanted.windows(2) {
        let (a, b) = (w[0], w[1]);
        let (lo, rest) = mu.split_at_mut((a + 1) * slab);
        let (mid, hi) = rest.split_at_mut((b - a - 1) * slab);
        let (first, last) = (&lo[a * slab..], &hi[..slab]);
        for (k, dst) in mid.chunks_exact_mut(slab).enumerate() {
            let t = (k + 1) as f32 / (b - a) as f32;
            for ((o, x), y) in dst.iter_mut().zip(first).zip(last) {
                *o = (1.0 - t) * x + t * y;
            }
        }
    }
    Ok(Volume {
        reconstructor,
        dims: [cols, nv, nd],
        voxel_mm: g.image.pixel_mm,
        mu,
        footprint_mm: footprint_mm(h, counts),
        counts_check,
    })
}

/// The physics-based density ([`dbt_physics_density::estimate`]) of
/// slice-wise sinograms whose counts are the primary's on the 20 keV scale
/// (after [`correct_counts`] and, for a cone-beam acquisition, the
/// rebinning), its defective elements corrected first; the error as text
/// where none can be made (the reconstruction's own checks name the
/// acquisition's faults).
pub fn physics_density(
    acq: &SliceSinograms,
    opts: &PipelineOptions,
) -> Result<dbt_physics_density::PhysicsDensity, String> {
    let (counts, _) = check_counts_with(&acq.header, &acq.counts, opts.scatter_in_input)
        .and_then(|d| d.applied(&acq.counts))
        .map_err(|e| e.to_string())?;
    physics_density_checked(&acq.header, &counts, opts.physics_rim)
}

/// [`physics_density`] of counts already checked and corrected.
fn physics_density_checked(
    h: &SliceHeader,
    counts: &[Vec<f32>],
    rim_shape: dbt_physics_density::RimShape,
) -> Result<dbt_physics_density::PhysicsDensity, String> {
    let input = dbt_physics_density::Input {
        geometry: &h.geometry,
        slice_spacing_mm: h.slice_spacing_mm,
        thickness_mm: h.thickness_mm,
        flux: h.flux,
        counts,
    };
    let o = dbt_physics_density::Options {
        skin_mm: crate::linearise::NOMINAL_SKIN_MM,
        noise_z: crate::plausibility::NOISE_Z,
        rim_shape,
        ..Default::default()
    };
    let _s = tracing::debug_span!("physics_density").entered();
    dbt_physics_density::estimate(&input, &o).map_err(|e| e.to_string())
}

/// How each layout reaches the reconstruction, written once per layout so
/// that no stage asks which it holds: its counts checked once (defects
/// corrected) and made slice-wise sinograms, and the reconstructed stack
/// made a regular volume.
pub trait ToSinograms: RayLayout + Sized {
    /// The (corrected) counts of `p` checked once, their defects
    /// corrected, as slice-wise sinograms, with the check.
    fn checked_sinograms(
        p: Projections<Self>,
        scatter_in_counts: bool,
    ) -> Result<(SliceSinograms, CountsCheck), PipelineError>;

    /// The stack reconstructed from [`Self::checked_sinograms`]' sinograms
    /// (`dims` lateral x vertical x depth, voxels `pixel_mm` wide) as a
    /// regular volume, its dims, and the depth of its voxels, mm.
    fn regular_volume(
        &self,
        mu: Vec<f32>,
        dims: [usize; 3],
        pixel_mm: f64,
    ) -> (Vec<f32>, [usize; 3], f64);

    /// The gantry the dose is simulated on: a cone-beam system's own
    /// (its views, arc, support, detector and its motion), the paper's for
    /// slice-wise sinograms.
    fn dose_geometry(&self) -> DoseGeometry;
}

/// The counts of `p` checked ([`checked_counts`]) and their defects
/// corrected in place; the check.
fn corrected_in_place<H: RayLayout>(
    p: &mut Projections<H>,
    scatter_in_counts: bool,
) -> Result<CountsCheck, PipelineError> {
    let (counts, check) = checked_counts(&p.header, &p.counts, scatter_in_counts)?;
    if let std::borrow::Cow::Owned(c) = counts {
        p.counts = c;
    }
    Ok(check)
}

impl ToSinograms for SliceHeader {
    fn checked_sinograms(
        mut p: SliceSinograms,
        scatter_in_counts: bool,
    ) -> Result<(SliceSinograms, CountsCheck), PipelineError> {
        let check = corrected_in_place(&mut p, scatter_in_counts)?;
        Ok((p, check))
    }

    fn regular_volume(
        &self,
        mu: Vec<f32>,
        dims: [usize; 3],
        _pixel_mm: f64,
    ) -> (Vec<f32>, [usize; 3], f64) {
        (mu, dims, self.slice_spacing_mm)
    }

    fn dose_geometry(&self) -> DoseGeometry {
        DoseGeometry::paper()
    }
}

impl ToSinograms for ConeHeader {
    /// The detector's frames are checked as read (a stuck or dead element
    /// is one element there, spread over slices and views once rebinned),
    /// their defects corrected, then rebinned.
    fn checked_sinograms(
        mut p: ConeFrames,
        scatter_in_counts: bool,
    ) -> Result<(SliceSinograms, CountsCheck), PipelineError> {
        let check = corrected_in_place(&mut p, scatter_in_counts)?;
        Ok((crate::rebin::slice_sinograms(&p)?, check))
    }

    /// A cone-beam stack is the breast sheared in depth: resampled to a
    /// regular volume.
    fn regular_volume(
        &self,
        mu: Vec<f32>,
        dims: [usize; 3],
        pixel_mm: f64,
    ) -> (Vec<f32>, [usize; 3], f64) {
        let (mu, dims) =
            crate::rebin::resample_depth(self.system(), self.thickness_mm, pixel_mm, &mu, dims);
        (mu, dims, pixel_mm)
    }

    fn dose_geometry(&self) -> DoseGeometry {
        DoseGeometry::of_system(self.system())
    }
}

/// [`process`], calling `progress` after each slice and at each later stage
/// (for the service CLI's progress display).
pub fn process_with_progress(
    acq: &Acquisition,
    opts: &PipelineOptions,
    progress: &mut dyn FnMut(Stage),
) -> Result<ProcessResult, PipelineError> {
    // The cross-check's limits and the calibration of the acquisition's
    // beam (before any work): a limit that is not a positive number would
    // confirm every density or none.
    opts.density_limits.validate()?;
    let beam_opts = opts.for_beam(acq.header.anode_filter)?;
    let opts = beam_opts.as_ref();
    validate_header(&acq.header)?;
    // The one place the layout is chosen: each is processed by the same
    // code, monomorphised.
    match acq.clone().into_layout() {
        Layout::Slices(s) => process_layout(s, opts, progress),
        Layout::Cone(c) => process_layout(c, opts, progress),
    }
}

fn process_layout<H: ToSinograms>(
    mut acq: Projections<H>,
    opts: &PipelineOptions,
    progress: &mut dyn FnMut(Stage),
) -> Result<ProcessResult, PipelineError> {
    let mut clock = std::time::Instant::now();
    let mut lap = move || {
        let now = std::time::Instant::now();
        let s = now.duration_since(clock).as_secs_f64();
        clock = now;
        s
    };
    let mut stage_seconds = StageSeconds::default();
    // The header was validated by the caller; the counts are this
    // acquisition's own copy, corrected where they lie.
    correct_in_place(&mut acq, opts)?;
    preflight(&acq.header, opts)?;
    let layout = acq.header.clone();
    // The counts last: every cheaper refusal above comes first.
    let (acq, counts_check) = H::checked_sinograms(acq, opts.scatter_in_input)?;
    let h = &acq.header;
    let g = &h.geometry;
    let _span =
        tracing::info_span!("acquisition", patient = %h.patient.id, slices = h.slices).entered();
    stage_seconds.corrections = lap();
    if opts.method == ReportMethod::PhysicsOnly {
        return physics_only(&layout, &acq, counts_check, opts, stage_seconds, progress);
    }
    stage_seconds.slices = reconstructed_slices(acq.counts.len(), opts.slice_step).len();
    let Volume {
        reconstructor,
        dims,
        mu,
        counts_check,
        footprint_mm,
        ..
    } = reconstruct_checked(h, &acq.counts, counts_check, opts, progress)?;
    // How well the reconstructed slices explain their projections (before
    // a cone-beam stack is resampled: the slices are the rebinned ones).
    let data_fit = {
        let _s = tracing::debug_span!("data_fit").entered();
        crate::data_fit::data_fit(
            h,
            &acq.counts,
            &mu,
            dims,
            &reconstructed_slices(acq.counts.len(), opts.slice_step),
        )?
    };
    // The volume lateral x vertical x depth, and its depth voxel (a
    // cone-beam stack is resampled to the pixel, a slice-wise one keeps the
    // slices).
    let (mu, dims, depth_step) = layout.regular_volume(mu, dims, g.image.pixel_mm);
    stage_seconds.reconstruction = lap();
    progress(Stage::Classification);
    let classification = classify(&mu, dims, g.image.pixel_mm, &opts.classify)?;
    let volume_check = check_volume(
        h,
        &footprint_mm,
        &mu,
        &classification.labels,
        g.image.pixel_mm,
    )?;
    let dens = density(&mu, &classification.labels, g.image.pixel_mm);
    // The second density, of the same corrected counts: after every
    // refusal of the reconstruction and the volume, so that an acquisition
    // refused costs none of it.
    let physics_density = physics_density_checked(h, &acq.counts, opts.physics_rim);
    let glandularity = opts
        .calibration
        .map_or(dens.glandularity_partial_volume, |c| {
            c.apply(dens.glandularity_partial_volume, h.thickness_mm)
        });
    let density_check = {
        let _s = tracing::debug_span!("density_check").entered();
        let contact = physics_density.as_ref().ok().and_then(|p| {
            crate::density_check::contact_glandularity(
                &mu,
                &classification.labels,
                dims,
                g,
                depth_step,
                &p.central.contact,
            )
        });
        crate::density_check::cross_check(
            glandularity,
            contact,
            opts.calibration.as_ref(),
            h.thickness_mm,
            &physics_density,
            volume_check.fill,
            opts.density_limits,
        )
        .with_data_fit(data_fit)
    };
    if density_check.confirmed {
        tracing::info!(check = %density_check.summary(), "density confirmed by the physics");
    } else {
        tracing::warn!(check = %density_check.summary(), reasons = ?density_check.reasons, "density not confirmed by the physics");
    }
    stage_seconds.classification = lap();
    progress(Stage::Dose);
    let (tube, spectrum) = exposure_spectrum(h)?;
    let breast = Breast {
        dims,
        voxel_mm: g.image.pixel_mm,
        labels: &classification.labels,
    };
    let gantry = layout.dose_geometry();
    let max = 100_000_000;
    let dose_patient = mgd_to_uncertainty_on(
        &gantry,
        &breast,
        Model::PatientSpecific,
        &spectrum,
        opts.dose_uncertainty,
        200_000,
        max,
        opts.seed,
    )?;
    stage_seconds.dose_patient = lap();
    // The model breast (the outline and skin of `b`, the interior mixed to
    // its labels' glandularity).
    let model_breast = |b: &Breast, seed: u64| {
        mgd_to_uncertainty_on(
            &gantry,
            b,
            Model::Homogeneous,
            &spectrum,
            opts.dose_uncertainty,
            200_000,
            max,
            seed,
        )
    };
    let dose_model = model_breast(&breast, opts.seed + 1)?;
    // Not confirmed: the model breast at the physics density too, so that
    // the dose report shows what the physics' figure would mean for the
    // dose.
    let model_at_physics = match (density_check.confirmed, density_check.physics) {
        (false, Some(g)) => {
            let relabelled =
                crate::density_check::labels_at_glandularity(&classification.labels, g);
            let b = Breast {
                labels: &relabelled,
                ..breast
            };
            Some(model_breast(&b, opts.seed + 2)?)
        }
        _ => None,
    };
    stage_seconds.dose_model = lap();
    tracing::info!(
        corrections_s = stage_seconds.corrections,
        reconstruction_s = stage_seconds.reconstruction,
        classification_s = stage_seconds.classification,
        dose_patient_s = stage_seconds.dose_patient,
        dose_model_s = stage_seconds.dose_model,
        "acquisition processed"
    );
    let kerma_mgy = h.mas_total * h.tube_output_mgy_per_mas;
    let mgd_mgy = dose_patient.mgd_per_kerma * kerma_mgy;
    let intervals = report_intervals(
        opts.intervals.as_deref(),
        h.anode_filter,
        h.thickness_mm,
        glandularity,
        &density_check,
        mgd_mgy,
        dose_patient.mgd_rel_uncertainty,
    );
    Ok(ProcessResult {
        reconstructor,
        algorithm_version: algorithm_version(opts),
        dims,
        voxel_mm: g.image.pixel_mm,
        mu,
        glandularity,
        calibrated: opts.calibration.is_some(),
        density: dens,
        physics_density,
        data_fit: Some(data_fit),
        method: ReportMethod::Reconstruction,
        density_check,
        mgd_mgy,
        model_mgd_mgy: dose_model.mgd_per_kerma * kerma_mgy,
        intervals,
        model_mgd_at_physics_mgy: model_at_physics.map(|m| m.mgd_per_kerma * kerma_mgy),
        kerma_mgy,
        classification,
        dose_geometry: gantry,
        dose_patient,
        dose_model,
        tube,
        flags: counts_check.flag().into_iter().collect(),
        plausibility: Plausibility {
            counts: counts_check,
            volume: volume_check,
        },
        stage_seconds,
    })
}

/// The least glandularity a physics-only report's model breast is dosed at
/// (its MGD's limit for a breast read without glandular tissue: the dose
/// per glandular mass of a vanishing share).
pub const PHYSICS_ONLY_MIN_GLANDULARITY: f64 = 0.001;

/// The exposure's spectrum from the technique received, for both reports
/// (the one place the technique becomes a spectrum:
/// [`dbt_dose::xray::technique_spectrum`]): the tube's description and its
/// photons.
fn exposure_spectrum(
    h: &AcquisitionHeader,
) -> Result<(dbt_dose::xray::TubeSpectrum, dbt_dose::spectrum::Spectrum), PipelineError> {
    let tube = dbt_dose::xray::technique_spectrum(h.anode_filter, h.kvp, h.thickness_mm)?;
    let spectrum = tube.spectrum.clone().ok_or_else(|| {
        PipelineError::Input(format!(
            "the technique {} at {} kV for {} mm gave no photon spectrum to dose with",
            h.anode_filter, h.kvp, h.thickness_mm
        ))
    })?;
    Ok((tube, spectrum))
}

/// The report of a gantry for which no model is trained (issue #51 point
/// 3): the physics density of the checked counts is the glandularity; the
/// model breast ([`crate::model_breast`]: the central view's outline, the
/// nominal skin, an interior at that glandularity placed as
/// [`PipelineOptions::physics_breast`] says) is dosed on
/// the gantry's own geometry and its MGD is the one reported; no interval
/// (none is validated for this method). Refused, naming why, where no
/// physics density can be made: nothing else would stand behind a figure.
fn physics_only<H: ToSinograms>(
    layout: &H,
    acq: &SliceSinograms,
    counts_check: CountsCheck,
    opts: &PipelineOptions,
    mut stage_seconds: StageSeconds,
    progress: &mut dyn FnMut(Stage),
) -> Result<ProcessResult, PipelineError> {
    let h = &acq.header;
    let g = &h.geometry;
    let t0 = std::time::Instant::now();
    progress(Stage::Classification);
    let physics = physics_density_checked(h, &acq.counts, opts.physics_rim).map_err(|e| {
        PipelineError::Input(format!(
            "no report: the physics-based density, the only method without a calibrated model for this gantry and beam, could not be made: {e}"
        ))
    })?;
    let gl = physics.central.glandularity;
    let density_check = crate::density_check::physics_only(&physics, opts.density_limits);
    if density_check.confirmed {
        tracing::info!(
            glandularity = gl,
            "physics-only report: the estimate passed its checks"
        );
    } else {
        tracing::warn!(reasons = ?density_check.reasons, "physics-only report: the estimate did not pass its checks");
    }
    // A breast read with no glandular tissue has no glandular dose to
    // average: its MGD is the limit as the glandularity goes to 0, dosed
    // at the floor and said so.
    let mut flags = counts_check.flag().into_iter().collect::<Vec<_>>();
    let dosed_at = if gl.is_finite() && gl >= PHYSICS_ONLY_MIN_GLANDULARITY {
        gl.min(1.0)
    } else {
        flags.push(format!(
            "the physics density reads {:.2} % glandular: the model breast is dosed at {:.1} % (the MGD's limit for a breast without glandular tissue)",
            100.0 * gl,
            100.0 * PHYSICS_ONLY_MIN_GLANDULARITY
        ));
        PHYSICS_ONLY_MIN_GLANDULARITY
    };
    let model = crate::model_breast::from_outline(
        &physics.central.outline,
        g.width_mm(),
        g.image.pixel_mm,
        crate::linearise::NOMINAL_SKIN_MM,
        dosed_at,
        opts.physics_breast,
    )?;
    // The model breast's attenuation at the 20 keV scale, for the status
    // page's pictures and the density's volumes.
    let mu: Vec<f32> = model
        .labels
        .iter()
        .map(|&l| dbt_materials::Tissue::from_label(l).map_or(0.0, |t| t.mu_per_mm()))
        .collect();
    let dens = density(&mu, &model.labels, model.voxel_mm);
    let classification = Classification {
        labels: model.labels.clone(),
        centres: [
            f64::from(dbt_materials::Tissue::Adipose.mu_per_mm()),
            f64::from(dbt_materials::Tissue::Fibroglandular.mu_per_mm()),
        ],
        seed_mean: f64::from(dbt_materials::Tissue::Skin.mu_per_mm()),
        iterations: 0,
    };
    stage_seconds.classification = t0.elapsed().as_secs_f64();
    progress(Stage::Dose);
    let t1 = std::time::Instant::now();
    let (tube, spectrum) = exposure_spectrum(h)?;
    let gantry = layout.dose_geometry();
    let dose = mgd_to_uncertainty_on(
        &gantry,
        &model.breast(),
        opts.physics_breast.dose_model(),
        &spectrum,
        opts.dose_uncertainty,
        200_000,
        100_000_000,
        opts.seed + 1,
    )?;
    stage_seconds.dose_model = t1.elapsed().as_secs_f64();
    let kerma_mgy = h.mas_total * h.tube_output_mgy_per_mas;
    let mgd_mgy = dose.mgd_per_kerma * kerma_mgy;
    let none = |what: &str| {
        FigureInterval {
        limits: None,
        basis: format!(
            "a physics-only report (no DBToR model trained and calibrated for this gantry and beam): its {what} has no validation residuals to rest an interval on"
        ),
    }
    };
    tracing::info!(
        glandularity = gl,
        mgd_mgy,
        gantry = %gantry.name,
        "acquisition reported by the physics density alone"
    );
    Ok(ProcessResult {
        reconstructor: reconstructor_name(opts),
        algorithm_version: algorithm_version(opts),
        dims: model.dims,
        voxel_mm: model.voxel_mm,
        mu,
        glandularity: gl,
        calibrated: false,
        density: dens,
        physics_density: Ok(physics),
        data_fit: None,
        method: ReportMethod::PhysicsOnly,
        density_check,
        mgd_mgy,
        model_mgd_mgy: mgd_mgy,
        intervals: ReportIntervals {
            glandularity: none("glandularity"),
            mgd: none("MGD"),
        },
        model_mgd_at_physics_mgy: None,
        kerma_mgy,
        classification,
        dose_geometry: gantry,
        dose_patient: dose.clone(),
        dose_model: dose,
        tube,
        flags,
        plausibility: Plausibility {
            counts: counts_check,
            volume: VolumeCheck::default(),
        },
        stage_seconds,
    })
}

/// The 95 % intervals of the two reported figures (issue #48 point 4), as
/// the reports, the status file and `dbtor-diag` give them.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReportIntervals {
    /// The true glandularity by mass's, 0..1.
    pub glandularity: FigureInterval,
    /// The true patient MGD's, mGy.
    pub mgd: FigureInterval,
}

/// The intervals of a breast `thickness_mm` thick reported at glandularity
/// `glandularity` and MGD `mgd_mgy` (its Monte Carlo's relative standard
/// error `mc_rel`), from the validation residuals `table`: none (each with
/// the reason) without residuals for this reconstructor and input, for
/// another beam than the W/Rh they were measured on, or where the physics
/// density did not confirm the density (the residuals describe breasts the
/// network reads as it read the validation's; one the physics contradicts
/// is not known to be such a breast).
pub fn report_intervals(
    table: Option<&dbt_intervals::IntervalTable>,
    beam: AnodeFilter,
    thickness_mm: f64,
    glandularity: f64,
    check: &crate::density_check::DensityCheck,
    mgd_mgy: f64,
    mc_rel: f64,
) -> ReportIntervals {
    let none = |why: String| ReportIntervals {
        glandularity: FigureInterval {
            limits: None,
            basis: why.clone(),
        },
        mgd: FigureInterval {
            limits: None,
            basis: why,
        },
    };
    let Some(table) = table else {
        return none(
            "the reconstructor has no validation residuals for these inputs (its model folder's \
             report-intervals.json)"
                .into(),
        );
    };
    if beam != AnodeFilter::WRh {
        return none(format!(
            "the validation residuals are of W/Rh acquisitions, this one is {}",
            beam.name()
        ));
    }
    if !check.confirmed {
        return none(
            "the density is not confirmed by the physics-based density, so the validation \
             residuals are not known to describe this breast"
                .into(),
        );
    }
    let figure = |r: Result<dbt_intervals::Interval, dbt_intervals::IntervalError>| match r {
        Ok(i) => FigureInterval {
            limits: Some([i.lo, i.hi]),
            basis: i.basis,
        },
        Err(e) => FigureInterval {
            limits: None,
            basis: format!("the interval could not be made: {e}"),
        },
    };
    ReportIntervals {
        glandularity: figure(table.glandularity(thickness_mm, glandularity)),
        mgd: figure(table.mgd(thickness_mm, glandularity, mgd_mgy, mc_rel)),
    }
}

/// The DICOM identity of an acquisition (patient, study, laterality, its
/// projections' series and instances), as its reports and its DICOM
/// projection object carry it.
pub fn dicom_header(acq: &Acquisition) -> Header {
    let h = &acq.header;
    Header {
        patient_name: h.patient.name.clone(),
        patient_id: h.patient.id.clone(),
        patient_birth_date: h.patient.birth_date.clone(),
        patient_sex: h.patient.sex.clone(),
        study_uid: h.study.study_uid.clone(),
        study_date: h.study.date.clone(),
        study_time: h.study.time.clone(),
        study_id: h.study.study_id.clone(),
        accession_number: h.study.accession.clone(),
        referring_physician: String::new(),
        laterality: if h.laterality == "R" {
            Laterality::Right
        } else {
            Laterality::Left
        },
        source_series_uid: h.study.series_uid.clone(),
        source_instance_uids: h.study.instance_uids.clone(),
        source_class: h
            .study
            .source_class
            .clone()
            .unwrap_or_else(|| dbt_dicom::projections::BPXR_FOR_PROCESSING_CLASS.into()),
    }
}

/// The dose and density reports of a processed acquisition.
pub fn reports(
    acq: &Acquisition,
    res: &ProcessResult,
    equipment: &Equipment,
    uids: &mut UidSource,
    content_date: &str,
    content_time: &str,
) -> Result<(Report, Report), PipelineError> {
    let h = &acq.header;
    let g = &h.geometry;
    let header = dicom_header(acq);
    let nv = g.n_views();
    let step = if nv > 1 {
        g.angle_deg(1) - g.angle_deg(0)
    } else {
        0.0
    };
    let tube = &res.tube;
    let events = (0..nv)
        .map(|v| {
            let a = g.angle_deg(v);
            let frac = res
                .dose_patient
                .view_fractions
                .get(v)
                .copied()
                .unwrap_or(1.0 / nv as f64);
            DoseEvent {
                angle_start_deg: a - step / 2.0,
                angle_end_deg: a + step / 2.0,
                kvp: h.kvp,
                exposure_uas: h.mas_total * 1000.0 / nv as f64,
                exposure_ms: h.exposure_ms_per_view,
                agd_mgy: res.mgd_mgy * frac,
                entrance_kerma_mgy: res.kerma_mgy / nv as f64,
                datetime: format!("{}{}", h.study.date, h.study.time),
            }
        })
        .collect();
    let dose = dose_report(
        &DoseInput {
            header: header.clone(),
            equipment: equipment.clone(),
            events,
            compression_mm: h.thickness_mm,
            compression_force_n: h.compression_force_n,
            hvl_mm_al: tube.hvl_mm_al,
            anode_material: crate::dicom_input::anode_material(h.anode_filter),
            filter_material: crate::dicom_input::filter_material(h.anode_filter),
            filter_mm: tube.filter_mm,
            accumulated_agd_mgy: res.mgd_mgy,
            relative_uncertainty: res.dose_patient.mgd_rel_uncertainty,
            model_agd_mgy: res.model_mgd_mgy,
            model_agd_at_physics_mgy: res.model_mgd_at_physics_mgy,
            agd_interval: res.intervals.mgd.clone(),
            content_date: content_date.into(),
            content_time: content_time.into(),
            // Nothing in the acquisition says screening or diagnostic: the
            // DBT sweep is reported as a diagnostic imaging procedure.
            intent: ProcedureIntent::Diagnostic,
            source_distances_mm: [g.source_to_center_mm, g.source_to_detector_mm],
            algorithm_version: res.algorithm_version.clone(),
            method: res.method,
        },
        uids,
    )?;
    let dens = density_report(
        &DensityInput {
            header,
            equipment: equipment.clone(),
            // The partial-volume estimate (the evaluation's choice,
            // eval/README.md), calibrated where the model has a calibration.
            glandularity: res.glandularity,
            fibroglandular_cm3: res.density.fibroglandular_partial_volume_cm3,
            breast_cm3: res.density.breast_cm3.max(1.0),
            reconstructor: res.reconstructor.clone(),
            model_version: res.algorithm_version.clone(),
            check: res.density_check.report(),
            glandularity_interval: res.intervals.glandularity.clone(),
            method: res.method,
            content_date: content_date.into(),
            content_time: content_time.into(),
        },
        uids,
    )?;
    Ok((dose, dens))
}

#[cfg(test)]
mod beam_tests {
    use super::*;

    /// A calibrated W/Al acquisition reads the W/Al calibration, or is
    /// refused naming the beam; W/Rh and uncalibrated options are unchanged.
    #[test]
    fn each_beam_reads_its_own_calibration() {
        let cal = |o: f64| GlandularityCalibration {
            offset: o,
            slope: 1.0,
            per_mm: 0.0,
            thickness_range_mm: None,
        };
        let plain = PipelineOptions::default();
        assert_eq!(plain.for_beam(AnodeFilter::WAl).unwrap().calibration, None);
        let w_rh_only = PipelineOptions {
            calibration: Some(cal(0.1)),
            ..Default::default()
        };
        assert_eq!(
            w_rh_only.for_beam(AnodeFilter::WRh).unwrap().calibration,
            Some(cal(0.1))
        );
        let e = w_rh_only
            .for_beam(AnodeFilter::WAl)
            .unwrap_err()
            .to_string();
        assert!(e.contains("W/Al") && e.contains("not reported"), "{e}");
        // W/Ag too: no beam reads W/Rh's calibration without an entry of
        // its own (the model's file carries it where its bar held).
        let e = w_rh_only
            .for_beam(AnodeFilter::WAg)
            .unwrap_err()
            .to_string();
        assert!(e.contains("W/Ag") && e.contains("not reported"), "{e}");
        // Or, where the site asks for it, reported physics-only: no
        // calibration, noise matching or intervals of the model's.
        let physics = PipelineOptions {
            uncalibrated_beam: UncalibratedBeam::PhysicsOnly,
            noise_match: Some(crate::noise_match::NoiseMatch {
                target_photons: 16_000.0,
            }),
            ..w_rh_only.clone()
        };
        let o = physics.for_beam(AnodeFilter::WAg).unwrap();
        assert_eq!(o.method, ReportMethod::PhysicsOnly);
        assert_eq!(o.calibration, None);
        assert!(o.noise_match.is_none() && o.intervals.is_none() && o.dbtor.is_none());
        let o = physics.for_beam(AnodeFilter::WRh).unwrap();
        assert_eq!(o.method, ReportMethod::Reconstruction);
        assert_eq!(o.calibration, Some(cal(0.1)));
        let w_ag_own = PipelineOptions {
            beam_calibrations: beam_calibrations(&[("W/Ag".into(), cal(0.5))]),
            ..w_rh_only.clone()
        };
        assert_eq!(
            w_ag_own.for_beam(AnodeFilter::WAg).unwrap().calibration,
            Some(cal(0.5))
        );
        let both = PipelineOptions {
            beam_calibrations: beam_calibrations(&[
                ("W/Al".into(), cal(0.3)),
                ("Rh/Ag".into(), cal(0.9)),
            ]),
            ..w_rh_only
        };
        assert_eq!(both.beam_calibrations.len(), 1, "the unknown beam left out");
        assert_eq!(
            both.for_beam(AnodeFilter::WAl).unwrap().calibration,
            Some(cal(0.3))
        );
        assert_eq!(
            both.for_beam(AnodeFilter::WRh).unwrap().calibration,
            Some(cal(0.1))
        );
        // A W/Al calibration alone (no W/Rh one for these corrections):
        // W/Al reads it, W/Rh stays uncalibrated.
        let w_al_only = PipelineOptions {
            calibration: None,
            ..both
        };
        assert_eq!(
            w_al_only.for_beam(AnodeFilter::WAl).unwrap().calibration,
            Some(cal(0.3))
        );
        assert_eq!(
            w_al_only.for_beam(AnodeFilter::WRh).unwrap().calibration,
            None
        );
    }
}

#[cfg(test)]
mod interval_tests {
    use super::*;
    use crate::density_check::{cross_check, LIMITS};

    fn table() -> dbt_intervals::IntervalTable {
        // 12 breasts in each of the product's six bands: reported 2 pp
        // below the truth +- 2 pp, MGD exp(0.03) high +- 4 %.
        let bands = dbt_intervals::product_bands();
        let mut rs = Vec::new();
        for t in [35.0, 50.0, 70.0] {
            for g in [0.1, 0.4] {
                for k in 0..12 {
                    let z = (k as f64 - 5.5) / 3.6;
                    rs.push(dbt_intervals::Residual {
                        thickness_mm: t,
                        g_reported: g,
                        g_true: g + (2.0 + 2.0 * z) / 100.0,
                        mgd_est_mgy: 1.0 * (0.03 + 0.04 * z).exp(),
                        mgd_true_mgy: 1.0,
                        mgd_est_rel_uncertainty: 0.01,
                        mgd_true_rel_uncertainty: 0.01,
                    });
                }
            }
        }
        dbt_intervals::IntervalTable::fit(&rs, bands).unwrap()
    }

    /// Intervals are given for a confirmed W/Rh density with residuals,
    /// the truth's side of the reported figure (the residuals say it reads
    /// low); never without residuals, for another beam, or for a density
    /// the physics did not confirm, each saying why.
    #[test]
    fn intervals_only_where_the_residuals_describe_the_breast() {
        let t = table();
        let physics = Err("none".to_string());
        let mut check = cross_check(0.4, None, None, 50.0, &physics, 0.9, LIMITS);
        assert!(!check.confirmed);
        let unconfirmed =
            report_intervals(Some(&t), AnodeFilter::WRh, 50.0, 0.4, &check, 1.2, 0.01);
        assert!(unconfirmed.glandularity.limits.is_none() && unconfirmed.mgd.limits.is_none());
        assert!(
            unconfirmed.mgd.basis.contains("not confirmed"),
            "{}",
            unconfirmed.mgd.basis
        );
        check.confirmed = true;
        check.reasons.clear();
        let ok = report_intervals(Some(&t), AnodeFilter::WRh, 50.0, 0.4, &check, 1.2, 0.01);
        let [lo, hi] = ok.glandularity.limits.unwrap();
        assert!(
            lo < 0.42 && hi > 0.42 && lo > 0.4 - 0.1 && hi < 0.42 + 0.1,
            "{lo}-{hi}"
        );
        let [mlo, mhi] = ok.mgd.limits.unwrap();
        let centre = 1.2 / 0.03_f64.exp();
        assert!(
            mlo < centre && mhi > centre && mhi / mlo < 1.25,
            "{mlo}-{mhi}"
        );
        assert!(
            ok.glandularity.basis.contains("thickness 45-60 mm"),
            "{}",
            ok.glandularity.basis
        );
        let none = report_intervals(None, AnodeFilter::WRh, 50.0, 0.4, &check, 1.2, 0.01);
        assert!(none.glandularity.basis.contains("no validation residuals"));
        let w_al = report_intervals(Some(&t), AnodeFilter::WAl, 50.0, 0.4, &check, 1.2, 0.01);
        assert!(
            w_al.mgd.limits.is_none() && w_al.mgd.basis.contains("W/Al"),
            "{}",
            w_al.mgd.basis
        );
        // An impossible figure gets no interval, and says why.
        let nan = report_intervals(
            Some(&t),
            AnodeFilter::WRh,
            50.0,
            0.4,
            &check,
            f64::NAN,
            0.01,
        );
        assert!(
            nan.mgd.limits.is_none() && nan.mgd.basis.contains("mgd_mgy"),
            "{}",
            nan.mgd.basis
        );
        assert!(nan.glandularity.limits.is_some());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Algorithm Version names the corrections and the detector the
    /// linearisation was computed for (a physicist reading the report can
    /// tell a-Se from CsI); none where the counts were taken as received.
    #[test]
    fn the_algorithm_version_names_the_corrections() {
        let plain = PipelineOptions {
            method: ReportMethod::PhysicsOnly,
            ..Default::default()
        };
        assert!(!algorithm_version(&plain).contains("corrected"));
        let a_se =
            dbt_materials::Converter::new(dbt_materials::ConverterMaterial::ASe, 200.0).unwrap();
        let opts = PipelineOptions {
            linearise: Some(crate::linearise::BeamHardening::for_converter(a_se).unwrap()),
            ..plain
        };
        let v = algorithm_version(&opts);
        assert!(
            v.contains("counts corrected: beam hardening linearised for 200 um a-Se; dbt-pipeline"),
            "{v}"
        );
    }
}
