//! End-to-end accuracy on held-out phantoms (issue #7): simulated acquisition
//! -> firmware processing -> glandularity and MGD, against the phantom truth
//! (its own labels through the same dose engine), with Bland-Altman
//! statistics, for whichever reconstructor the pipeline options select (DBToR
//! with a model, else MLTR).

use dbt_dose::patient::{mgd_to_uncertainty_on, Breast, Model};
use dbt_dose::xray::AnodeFilter;
use dbt_forward::NoiseLevel;
use dbt_geometry::Geometry;
use dbt_materials::Tissue;
use dbt_phantom::{LabelVolume, Population, PopulationKind};
use dbt_pipeline::{process, PipelineOptions};
use dbt_tissue::PartialVolumeMass;
use host_sim::Technique;
use serde::Serialize;

/// One case.
#[derive(Debug, Clone, Serialize)]
pub struct Case {
    /// Where the phantom came from.
    pub phantom: String,
    /// Compressed thickness, mm.
    pub thickness_mm: f64,
    /// True glandularity by mass.
    pub g_true: f64,
    /// Estimated glandularity from labels.
    pub g_labels: f64,
    /// Estimated glandularity from partial volumes.
    pub g_partial_volume: f64,
    /// The glandularity the firmware reports (partial volume, calibrated
    /// where the model has a calibration).
    pub g_reported: f64,
    /// The physics-based density's glandularity by mass (no learning;
    /// `dbt_physics_density`), NaN where the firmware could not make one.
    pub g_physics: f64,
    /// The physics density's whole estimate (thickness plane, rim sectors,
    /// every view), or why none.
    pub physics_density: Result<dbt_physics_density::PhysicsDensity, String>,
    /// The reported glandularity cross-checked against the physics density
    /// (`dbt_pipeline::density_check`).
    pub density_check: dbt_pipeline::density_check::DensityCheck,
    /// How well the reconstruction explains its projections
    /// (`dbt_pipeline::data_fit`); none in a physics-only report.
    pub data_fit: Option<dbt_pipeline::data_fit::DataFit>,
    /// True MGD (phantom labels through the engine), mGy.
    pub mgd_true: f64,
    /// MGD of the classified reconstruction, mGy.
    pub mgd_est: f64,
    /// Relative standard error of `mgd_true`'s Monte Carlo.
    pub mgd_true_rel_uncertainty: f64,
    /// Relative standard error of `mgd_est`'s Monte Carlo.
    pub mgd_est_rel_uncertainty: f64,
    /// Model-breast MGD (reconstruction's outline and glandularity), mGy.
    pub mgd_model: f64,
    /// The reports' 95 % intervals (or why none), as the firmware gives
    /// them.
    pub intervals: dbt_pipeline::ReportIntervals,
    /// Processing seconds.
    pub seconds: f64,
    /// What the firmware's plausibility checks measured (a case they
    /// refuse fails the run, naming the reason).
    pub plausibility: dbt_pipeline::Plausibility,
    /// Glandular fraction by depth from the chest wall (bands of
    /// [`DEPTH_BAND_MM`]), truth against the classified reconstruction.
    pub by_depth: Vec<DepthBand>,
    /// Fibroglandular volume by height above the breast support (bands of
    /// [`HEIGHT_BAND_MM`]), truth against the classified reconstruction:
    /// where the gland lies along the beam sets the patient MGD (the dose
    /// falls from the entrance surface at the top to the support).
    pub by_height: Vec<HeightBand>,
    /// The same volumes in single voxel layers at the two compressed
    /// surfaces: where the blurred skin and the limited angle put false
    /// gland (eval/README.md, "Where a fatty breast's dose reads high").
    pub by_surface: SurfaceLayers,
}

/// Layers of the reconstruction's voxel at each compressed surface in
/// [`Case::by_surface`] (8 mm at 0.8 mm voxels).
pub const SURFACE_LAYERS: usize = 10;

/// The fibroglandular and tissue volumes of single voxel layers (the
/// reconstruction's voxel) at the breast support and under the paddle (the
/// compressed thickness), truth against the classified reconstruction.
#[derive(Debug, Clone, Default, Serialize)]
pub struct SurfaceLayers {
    /// Layers above the support, the lowest first.
    pub support: Vec<HeightBand>,
    /// Layers under the paddle, the highest first.
    pub paddle: Vec<HeightBand>,
}

/// One band of height: `(from_mm, to_mm, truth, reconstruction)`, each
/// `(fibroglandular, adipose + fibroglandular)` cm^3 ([`gland_by_height`]
/// through [`banded`]).
pub type VolumeBand = (f64, f64, (f64, f64), (f64, f64));

/// [`SurfaceLayers`] from per-layer bands of height `layers` (one per
/// voxel row of the compressed thickness, the lowest first; `(from_mm,
/// to_mm, truth, reconstruction)`, each `(gland, tissue)` cm^3): at most
/// [`SURFACE_LAYERS`] at each end (fewer in a breast thinner than twice
/// that, the two ends never sharing a layer).
pub fn surface_layers(layers: &[VolumeBand]) -> SurfaceLayers {
    let n = SURFACE_LAYERS.min(layers.len() / 2);
    SurfaceLayers {
        support: layers[..n].iter().copied().map(HeightBand::from).collect(),
        paddle: layers[layers.len() - n..]
            .iter()
            .rev()
            .copied()
            .map(HeightBand::from)
            .collect(),
    }
}

impl From<VolumeBand> for HeightBand {
    fn from((from_mm, to_mm, t, r): VolumeBand) -> Self {
        Self {
            from_mm,
            to_mm,
            gland_true_cm3: t.0,
            gland_recon_cm3: r.0,
            tissue_true_cm3: t.1,
            tissue_recon_cm3: r.1,
        }
    }
}

/// Width of the depth bands of [`Case::by_depth`], mm.
pub const DEPTH_BAND_MM: f64 = 20.0;

/// Width of the height bands of [`Case::by_height`], mm.
pub const HEIGHT_BAND_MM: f64 = 10.0;

/// One band of height above the breast support: the fibroglandular volume
/// (Cooper's ligaments included, skin excluded) and the volume of the
/// adipose and fibroglandular voxels, in the truth's labels and in the
/// classified reconstruction's, cm^3.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct HeightBand {
    /// Band start, mm above the support.
    pub from_mm: f64,
    /// Band end, mm.
    pub to_mm: f64,
    /// True fibroglandular volume, cm^3.
    pub gland_true_cm3: f64,
    /// Reconstructed fibroglandular volume, cm^3.
    pub gland_recon_cm3: f64,
    /// True adipose + fibroglandular volume, cm^3.
    pub tissue_true_cm3: f64,
    /// Reconstructed adipose + fibroglandular volume, cm^3.
    pub tissue_recon_cm3: f64,
}

/// The fibroglandular and the adipose + fibroglandular volumes (cm^3) of
/// `labels` (dims `[lateral, vertical, depth]`, vertical index 0 on the
/// support, cubic voxels of `voxel_mm`) in bands of `band_mm` of height,
/// `bands` of them (a voxel in the band of its centre; voxels above the
/// last band ignored).
pub fn gland_by_height(
    labels: &[u8],
    dims: [usize; 3],
    voxel_mm: f64,
    band_mm: f64,
    bands: usize,
) -> Vec<(f64, f64)> {
    let [nx, ny, _] = dims;
    let cm3 = voxel_mm.powi(3) / 1000.0;
    let mut counts = vec![(0usize, 0usize); bands];
    if nx == 0 || ny == 0 {
        return vec![(0.0, 0.0); bands];
    }
    for (row, line) in labels.chunks_exact(nx).enumerate() {
        let v = row % ny;
        let b = (((v as f64 + 0.5) * voxel_mm) / band_mm) as usize;
        let Some(c) = counts.get_mut(b) else { continue };
        for &l in line.iter().filter(|&&l| PartialVolumeMass::counts(l)) {
            c.1 += 1;
            c.0 += usize::from(is_gland(l));
        }
    }
    counts
        .into_iter()
        .map(|(g, t)| (g as f64 * cm3, t as f64 * cm3))
        .collect()
}

/// One band of depth from the chest wall: the fibroglandular share of the
/// breast's adipose and fibroglandular voxels (skin excluded; Cooper's
/// ligaments count as fibroglandular, as in the phantom's glandularity),
/// in the truth's labels and in the classified reconstruction's.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct DepthBand {
    /// Band start, mm from the chest wall.
    pub from_mm: f64,
    /// Band end, mm.
    pub to_mm: f64,
    /// True fibroglandular volume fraction (`None`: no breast there).
    pub g_true: Option<f64>,
    /// Reconstructed fibroglandular volume fraction.
    pub g_recon: Option<f64>,
}

/// Whether a voxel of label `label` is fibroglandular for glandularity and
/// dose (ligaments included: [`Tissue::is_glandular`]).
fn is_gland(label: u8) -> bool {
    Tissue::from_label(label).is_ok_and(Tissue::is_glandular)
}

/// Labels with their dims and cubic voxel size, mm.
type Labelled<'a> = (&'a [u8], [usize; 3], f64);

/// A band statistic: `(labels, dims, voxel_mm, band_mm, bands)` to one
/// value per band.
type BandStat<T> = fn(&[u8], [usize; 3], f64, f64, usize) -> Vec<T>;

/// One band statistic `f(labels, dims, voxel_mm, band_mm, bands)` of the
/// truth and of the reconstruction, band by band: `(from_mm, to_mm, truth,
/// reconstruction)`.
fn banded<T>(
    truth: Labelled,
    recon: Labelled,
    band_mm: f64,
    bands: usize,
    f: BandStat<T>,
) -> Vec<(f64, f64, T, T)> {
    let t = f(truth.0, truth.1, truth.2, band_mm, bands);
    let r = f(recon.0, recon.1, recon.2, band_mm, bands);
    t.into_iter()
        .zip(r)
        .enumerate()
        .map(|(k, (t, r))| (k as f64 * band_mm, (k + 1) as f64 * band_mm, t, r))
        .collect()
}

/// The fibroglandular volume fraction of `labels` (dims `[lateral,
/// vertical, depth]`, voxels `voxel_mm` deep) in bands of `band_mm` from the
/// chest wall (depth index 0), `bands` of them.
pub fn gland_by_depth(
    labels: &[u8],
    dims: [usize; 3],
    voxel_mm: f64,
    band_mm: f64,
    bands: usize,
) -> Vec<Option<f64>> {
    let plane = dims[0] * dims[1];
    let mut counts = vec![(0usize, 0usize); bands];
    for d in 0..dims[2] {
        let b = (((d as f64 + 0.5) * voxel_mm) / band_mm) as usize;
        let Some(c) = counts.get_mut(b) else { break };
        let slice = labels.get(d * plane..(d + 1) * plane).unwrap_or(&[]);
        for &l in slice.iter().filter(|&&l| PartialVolumeMass::counts(l)) {
            c.1 += 1;
            c.0 += usize::from(is_gland(l));
        }
    }
    counts
        .into_iter()
        .map(|(g, t)| (t > 0).then(|| g as f64 / t as f64))
        .collect()
}

/// Bland-Altman summary of differences.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Agreement {
    /// Mean difference.
    pub bias: f64,
    /// Sample standard deviation of the differences.
    pub sd: f64,
    /// 95 % limits of agreement, `bias -+ 1.96 sd`.
    pub loa: [f64; 2],
    /// Largest absolute difference.
    pub max_abs: f64,
    /// Two-sided p-value of the paired t-test for zero bias.
    pub p_value: f64,
    /// Cases.
    pub n: usize,
}

/// Bland-Altman statistics of `diffs`.
pub fn agreement(diffs: &[f64]) -> Agreement {
    let n = diffs.len();
    let (bias, sd) = dbt_metrics::mean_sd(diffs);
    let p_value = if n > 1 && sd > 0.0 {
        dbt_intervals::t_two_sided_p(bias / (sd / (n as f64).sqrt()), (n - 1) as f64)
    } else {
        f64::NAN
    };
    Agreement {
        bias,
        sd,
        loa: [bias - 1.96 * sd, bias + 1.96 * sd],
        max_abs: diffs.iter().fold(0.0, |m, d| m.max(d.abs())),
        p_value,
        n,
    }
}

/// The bar another beam passes to read the W/Rh glandularity calibration
/// instead of its own (eval/README.md, "The W/Ag beam"; written before any
/// acquisition of W/Al, the first beam it was put to, was evaluated): on
/// the same validation phantoms, the other beam's reported-glandularity
/// bias within this many pp of W/Rh's ...
pub const BEAM_BAR_BIAS_PP: f64 = 0.5;
/// ... its standard deviation at most this many pp over W/Rh's ...
pub const BEAM_BAR_SD_PP: f64 = 0.1;
/// ... and none of its errors beyond this many pp (the paper's bar).
pub const BEAM_BAR_MAX_PP: f64 = 3.0;

/// [`beam_bar`]'s verdict.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct BeamBar {
    /// W/Rh's errors with its own calibration, pp.
    pub w_rh: Agreement,
    /// The other beam's errors with W/Rh's calibration, pp.
    pub other: Agreement,
    /// `|bias(other) - bias(W/Rh)|`, pp.
    pub bias_difference_pp: f64,
    /// `sd(other) - sd(W/Rh)`, pp.
    pub sd_difference_pp: f64,
    /// Whether the other beam keeps W/Rh's calibration.
    pub kept: bool,
}

/// Whether another beam keeps the W/Rh calibration: `w_rh_pp` and
/// `other_pp` are the reported-glandularity errors (pp) of the same
/// phantoms, both read with W/Rh's calibration ([`BEAM_BAR_BIAS_PP`],
/// [`BEAM_BAR_SD_PP`], [`BEAM_BAR_MAX_PP`]). A bar on fewer than two
/// cases a side, or on unequal counts, is missed.
pub fn beam_bar(w_rh_pp: &[f64], other_pp: &[f64]) -> BeamBar {
    let (w_rh, other) = (agreement(w_rh_pp), agreement(other_pp));
    let bias_difference_pp = (other.bias - w_rh.bias).abs();
    let sd_difference_pp = other.sd - w_rh.sd;
    let kept = w_rh_pp.len() == other_pp.len()
        && w_rh_pp.len() >= 2
        && bias_difference_pp <= BEAM_BAR_BIAS_PP
        && sd_difference_pp <= BEAM_BAR_SD_PP
        && other.max_abs <= BEAM_BAR_MAX_PP;
    BeamBar {
        w_rh,
        other,
        bias_difference_pp,
        sd_difference_pp,
        kept,
    }
}

/// One phantom through acquisition, processing and dose.
pub fn run_case(
    name: String,
    vol: &LabelVolume,
    geom: &Geometry,
    noise: NoiseLevel,
    opts: &PipelineOptions,
    seed: u64,
) -> anyhow::Result<Case> {
    run_cases(name, vol, geom, noise, std::slice::from_ref(opts), seed)?
        .pop()
        .ok_or_else(|| anyhow::anyhow!("no reconstructor"))
}

/// One phantom acquired once and processed by each of `opts` (one case per
/// reconstructor, in order); the truth's MGD (its own labels through the
/// same dose engine, same spectrum and kerma) is computed once.
pub fn run_cases(
    name: String,
    vol: &LabelVolume,
    geom: &Geometry,
    noise: NoiseLevel,
    opts: &[PipelineOptions],
    seed: u64,
) -> anyhow::Result<Vec<Case>> {
    run_cases_on(
        name,
        vol,
        geom,
        None,
        host_sim::Physics::Mono,
        AnodeFilter::WRh,
        noise,
        opts,
        seed,
    )
}

/// [`run_cases`], the acquisition made on cone-beam `system` when given
/// (issue #28: the firmware rebins it to slice-wise sinograms in `geom`),
/// with `physics` (issue #27) and the beam `beam`.
#[allow(clippy::too_many_arguments)]
pub fn run_cases_on(
    name: String,
    vol: &LabelVolume,
    geom: &Geometry,
    system: Option<&dbt_geometry::ConeSystem>,
    physics: host_sim::Physics,
    beam: AnodeFilter,
    noise: NoiseLevel,
    opts: &[PipelineOptions],
    seed: u64,
) -> anyhow::Result<Vec<Case>> {
    let _span = tracing::info_span!("case", %name).entered();
    let t0 = std::time::Instant::now();
    let tech = Technique {
        anode_filter: beam,
        ..Default::default()
    };
    let root = "1.2.826.0.1.3680043.10.543.3";
    // The gantry's automatic exposure: the beam's kV for the thickness (the
    // paper's Table 3 for W/Rh; the spectrum the acquisition, the
    // correction and the dose then take from the header).
    let kvp = f64::from(beam.aec_kv(vol.thickness_mm()));
    let acq = host_sim::simulate_on(
        vol, geom, system, noise, physics, seed, tech, kvp, "EVAL", root,
    )?;
    let acquired = t0.elapsed().as_secs_f64();
    let mut truth_mgd_per_kerma = None;
    let mut cases = Vec::with_capacity(opts.len());
    for o in opts {
        let t = std::time::Instant::now();
        let res = process(&acq, o)?;
        let (per_kerma, truth_rel) = match truth_mgd_per_kerma {
            Some(v) => v,
            None => {
                // The acquisition's thickness is the phantom's: the same
                // spectrum for every reconstructor.
                let spec = res
                    .tube
                    .spectrum
                    .clone()
                    .ok_or_else(|| anyhow::anyhow!("no spectrum"))?;
                let truth = Breast {
                    dims: vol.dims(),
                    voxel_mm: vol.voxel_mm(),
                    labels: vol.labels(),
                };
                // On the gantry the acquisition was made and dosed on.
                let m = mgd_to_uncertainty_on(
                    &res.dose_geometry,
                    &truth,
                    Model::PatientSpecific,
                    &spec,
                    o.dose_uncertainty,
                    200_000,
                    100_000_000,
                    seed + 7,
                )?;
                let m = (m.mgd_per_kerma, m.mgd_rel_uncertainty);
                truth_mgd_per_kerma = Some(m);
                m
            }
        };
        // Labels, dims and voxel size of the truth and of the classified
        // reconstruction, for the band statistics.
        let truth_labels = (vol.labels(), vol.dims(), vol.voxel_mm());
        let recon_labels = (&res.classification.labels[..], res.dims, res.voxel_mm);
        cases.push(Case {
            phantom: name.clone(),
            thickness_mm: vol.thickness_mm(),
            g_true: vol.glandularity().unwrap_or(0.0),
            g_labels: res.density.glandularity_labels,
            g_partial_volume: res.density.glandularity_partial_volume,
            g_reported: res.glandularity,
            g_physics: res
                .physics_density
                .as_ref()
                .map_or(f64::NAN, |p| p.central.glandularity),
            physics_density: res.physics_density.clone(),
            density_check: res.density_check.clone(),
            data_fit: res.data_fit,
            mgd_true: per_kerma * res.kerma_mgy,
            mgd_est: res.mgd_mgy,
            mgd_true_rel_uncertainty: truth_rel,
            mgd_est_rel_uncertainty: res.dose_patient.mgd_rel_uncertainty,
            mgd_model: res.model_mgd_mgy,
            intervals: res.intervals.clone(),
            seconds: acquired + t.elapsed().as_secs_f64(),
            plausibility: res.plausibility.clone(),
            by_depth: {
                let depth_mm = vol.n_coronal() as f64 * vol.voxel_mm();
                let bands = (depth_mm / DEPTH_BAND_MM).ceil() as usize;
                banded(
                    truth_labels,
                    recon_labels,
                    DEPTH_BAND_MM,
                    bands,
                    gland_by_depth,
                )
                .into_iter()
                .map(|(from_mm, to_mm, g_true, g_recon)| DepthBand {
                    from_mm,
                    to_mm,
                    g_true,
                    g_recon,
                })
                .collect()
            },
            by_height: {
                let height_mm =
                    (vol.dims()[1] as f64 * vol.voxel_mm()).max(res.dims[1] as f64 * res.voxel_mm);
                let bands = (height_mm / HEIGHT_BAND_MM).ceil() as usize;
                banded(
                    truth_labels,
                    recon_labels,
                    HEIGHT_BAND_MM,
                    bands,
                    gland_by_height,
                )
                .into_iter()
                .map(HeightBand::from)
                .collect()
            },
            by_surface: {
                // One band per voxel row of the compressed thickness.
                let rows = (vol.thickness_mm() / res.voxel_mm).round() as usize;
                surface_layers(&banded(
                    truth_labels,
                    recon_labels,
                    res.voxel_mm,
                    rows,
                    gland_by_height,
                ))
            },
        });
    }
    Ok(cases)
}

/// The fixed held-out phantoms `0..n` of the test population.
pub fn test_phantoms(
    geom: &Geometry,
    n: usize,
) -> impl Iterator<Item = anyhow::Result<(String, LabelVolume)>> + '_ {
    split_phantoms(geom, Split::Test, PopulationKind::Procedural, n)
}

/// Which phantoms an evaluation draws.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Split {
    /// The fixed test set (`Population::TEST_SEED`, indices `0..n`): report
    /// on it, never tune on it.
    Test,
    /// The dataset's validation phantoms (population `seed`, the training
    /// seed; indices `9, 19, 29, ...`, the exporter's `index % 10 == 9`
    /// rule): never trained on, used to choose estimator settings.
    Validation {
        /// The training population's seed (the dataset manifest's
        /// `train_seed`).
        seed: u64,
    },
}

impl Split {
    /// Population seed and index of the `k`-th phantom of the split.
    pub fn draw(&self, k: u64) -> (u64, u64) {
        match *self {
            Split::Test => (Population::TEST_SEED, k),
            Split::Validation { seed } => (seed, 10 * k + 9),
        }
    }

    /// Parse `test` or `validation` (with the training seed).
    pub fn parse(name: &str, train_seed: u64) -> anyhow::Result<Self> {
        match name {
            "test" => Ok(Split::Test),
            "validation" => {
                anyhow::ensure!(
                    train_seed != Population::TEST_SEED,
                    "the training seed is the test seed"
                );
                Ok(Split::Validation { seed: train_seed })
            }
            other => anyhow::bail!("unknown split {other:?} (test, validation)"),
        }
    }

    /// The split in words, as printed and in the JSON.
    pub fn describe(&self) -> String {
        match self {
            Split::Test => "test (population TEST_SEED, phantoms 0..n)".into(),
            Split::Validation { seed } => {
                format!("validation (training population seed {seed}, indices 9, 19, 29, ...)")
            }
        }
    }

    /// The name of a phantom of the split, as printed and in the JSON.
    fn name(&self, k: u64) -> String {
        match self {
            Split::Test => format!("test-set phantom {k}"),
            Split::Validation { .. } => {
                format!(
                    "validation phantom {} (population index {})",
                    k,
                    self.draw(k).1
                )
            }
        }
    }
}

/// The first `n` phantoms of `split` of `population`, generated at the
/// geometry's pixel.
pub fn split_phantoms(
    geom: &Geometry,
    split: Split,
    population: PopulationKind,
    n: usize,
) -> impl Iterator<Item = anyhow::Result<(String, LabelVolume)>> + '_ {
    (0..n as u64).map(move |k| {
        let (seed, index) = split.draw(k);
        let vol = population.draw(geom, seed, index).generate()?;
        let name = match population {
            PopulationKind::Procedural => split.name(k),
            other => format!("{other} {}", split.name(k)),
        };
        Ok((name, vol))
    })
}

/// Summary rows of a set of cases.
#[derive(Debug, Clone, Serialize)]
pub struct AccuracySummary {
    /// Reported glandularity error, percentage points.
    pub glandularity_reported_pp: Agreement,
    /// Glandularity error (labels), percentage points.
    pub glandularity_labels_pp: Agreement,
    /// Glandularity error (partial volume), percentage points.
    pub glandularity_partial_volume_pp: Agreement,
    /// Physics-based density's glandularity error, percentage points.
    pub glandularity_physics_pp: Agreement,
    /// Patient-specific MGD error, percent.
    pub mgd_percent: Agreement,
    /// Model-breast MGD error, percent.
    pub model_mgd_percent: Agreement,
}

/// One compared quantity of a case: `(difference, mean of truth and
/// estimate)`, the Bland-Altman axes.
pub type Pick = fn(&Case) -> (f64, f64);

/// A compared quantity: its table name, file tag, Bland-Altman axis labels,
/// and how a case gives it.
pub struct Quantity {
    /// Name in the tables (with the difference's unit).
    pub name: &'static str,
    /// Tag in file names.
    pub short: &'static str,
    /// Bland-Altman x axis: the mean of truth and estimate, with its unit.
    pub mean_axis: &'static str,
    /// Bland-Altman y axis: the difference, with its unit.
    pub difference_axis: &'static str,
    /// `(difference, mean)` of a case.
    pub pick: Pick,
}

/// The compared quantities, in the order of [`AccuracySummary::in_order`].
pub const QUANTITIES: [Quantity; 6] = [
    Quantity {
        name: "glandularity, reported (pp)",
        short: "glandularity-reported",
        mean_axis: "mean of true and reported glandularity (%)",
        difference_axis: "reported - truth (percentage points)",
        pick: |c| {
            (
                100.0 * (c.g_reported - c.g_true),
                50.0 * (c.g_reported + c.g_true),
            )
        },
    },
    Quantity {
        name: "glandularity, labels (pp)",
        short: "glandularity",
        mean_axis: "mean of true and estimated glandularity (%)",
        difference_axis: "estimate - truth (percentage points)",
        pick: |c| {
            (
                100.0 * (c.g_labels - c.g_true),
                50.0 * (c.g_labels + c.g_true),
            )
        },
    },
    Quantity {
        name: "glandularity, partial volume (pp)",
        short: "glandularity-pv",
        mean_axis: "mean of true and estimated glandularity (%)",
        difference_axis: "estimate - truth (percentage points)",
        pick: |c| {
            (
                100.0 * (c.g_partial_volume - c.g_true),
                50.0 * (c.g_partial_volume + c.g_true),
            )
        },
    },
    Quantity {
        name: "glandularity, physics density (pp)",
        short: "glandularity-physics",
        mean_axis: "mean of true and physics glandularity (%)",
        difference_axis: "physics - truth (percentage points)",
        pick: |c| {
            (
                100.0 * (c.g_physics - c.g_true),
                50.0 * (c.g_physics + c.g_true),
            )
        },
    },
    Quantity {
        name: "MGD, patient-specific (%)",
        short: "mgd",
        mean_axis: "mean of true and estimated MGD (mGy)",
        difference_axis: "estimate / truth - 1 (%)",
        pick: |c| {
            (
                100.0 * (c.mgd_est / c.mgd_true - 1.0),
                0.5 * (c.mgd_est + c.mgd_true),
            )
        },
    },
    Quantity {
        name: "MGD, model breast (%)",
        short: "mgd-model",
        mean_axis: "mean of true and model-breast MGD (mGy)",
        difference_axis: "model breast / truth - 1 (%)",
        pick: |c| {
            (
                100.0 * (c.mgd_model / c.mgd_true - 1.0),
                0.5 * (c.mgd_model + c.mgd_true),
            )
        },
    },
];

impl AccuracySummary {
    /// The agreements in the order of [`QUANTITIES`].
    pub fn in_order(&self) -> [Agreement; 6] {
        [
            self.glandularity_reported_pp,
            self.glandularity_labels_pp,
            self.glandularity_partial_volume_pp,
            self.glandularity_physics_pp,
            self.mgd_percent,
            self.model_mgd_percent,
        ]
    }
}

/// Summarise cases.
pub fn summarise(cases: &[Case]) -> AccuracySummary {
    let [reported, g, gpv, physics, mgd, model] =
        QUANTITIES.map(|q| agreement(&cases.iter().map(|c| (q.pick)(c).0).collect::<Vec<_>>()));
    AccuracySummary {
        glandularity_reported_pp: reported,
        glandularity_labels_pp: g,
        glandularity_partial_volume_pp: gpv,
        glandularity_physics_pp: physics,
        mgd_percent: mgd,
        model_mgd_percent: model,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The beam bar at and beyond each of its three limits: a beam whose
    /// errors are W/Rh's shifted by the bias limit, or spread to the sd
    /// limit, keeps the calibration; a little more of either, one error
    /// beyond 3 pp, unequal counts or a single case miss it.
    #[test]
    fn beam_bar_holds_each_limit() {
        let w_rh = [-1.0, -0.5, 0.0, 0.5, 1.0];
        assert!(beam_bar(&w_rh, &w_rh).kept);
        let shifted = |d: f64| w_rh.map(|e| e + d);
        assert!(beam_bar(&w_rh, &shifted(0.49)).kept);
        let b = beam_bar(&w_rh, &shifted(0.51));
        assert!(!b.kept && (b.bias_difference_pp - 0.51).abs() < 1e-12);
        assert!(!beam_bar(&w_rh, &shifted(-0.51)).kept);
        let sd = agreement(&w_rh).sd;
        let spread = |f: f64| w_rh.map(|e| e * f);
        assert!(beam_bar(&w_rh, &spread((sd + 0.09) / sd)).kept);
        let b = beam_bar(&w_rh, &spread((sd + 0.11) / sd));
        assert!(!b.kept && (b.sd_difference_pp - 0.11).abs() < 1e-9);
        let mut far = w_rh;
        far[0] = -3.01;
        assert!(!beam_bar(&far, &far).kept, "an error beyond 3 pp");
        assert!(!beam_bar(&w_rh, &w_rh[..4]).kept, "unequal counts");
        assert!(!beam_bar(&[0.1], &[0.1]).kept, "one case");
    }

    /// Depth bands: slices fall in the band of their centre; skin and air
    /// do not count; a band without breast is `None`; slices beyond the
    /// last band are ignored.
    #[test]
    fn gland_by_depth_counts_per_band() {
        // 2 x 1 voxels per slice, 5 slices of 10 mm, bands of 20 mm.
        let labels = [3, 1, 4, 2, 0, 2, 0, 0, 3, 1];
        let g = gland_by_depth(&labels, [2, 1, 5], 10.0, 20.0, 2);
        assert_eq!(g, vec![Some(2.0 / 3.0), None]);
        let g = gland_by_depth(&labels, [2, 1, 5], 10.0, 20.0, 3);
        assert_eq!(g, vec![Some(2.0 / 3.0), None, Some(0.5)]);
        let g = gland_by_depth(&labels, [2, 1, 5], 10.0, 30.0, 2);
        assert_eq!(g, vec![Some(2.0 / 3.0), Some(0.5)]);
    }

    /// Height bands: rows fall in the band of their centre (vertical index
    /// 0 on the support, whatever the depth slice); skin and air count in
    /// neither volume; rows above the last band are ignored.
    #[test]
    fn gland_by_height_counts_per_band() {
        // 2 lateral x 3 vertical x 2 depth voxels of 10 mm (1 cm^3 each).
        #[rustfmt::skip]
        let labels = [
            3, 1, // depth 0, height 0-10 mm
            4, 2, //          10-20
            0, 3, //          20-30
            1, 1, // depth 1, 0-10
            3, 0, //          10-20
            3, 3, //          20-30
        ];
        let g = gland_by_height(&labels, [2, 3, 2], 10.0, 20.0, 2);
        assert_eq!(g, vec![(3.0, 6.0), (3.0, 3.0)]);
        let g = gland_by_height(&labels, [2, 3, 2], 10.0, 10.0, 2);
        assert_eq!(
            g,
            vec![(1.0, 4.0), (2.0, 2.0)],
            "the top row is beyond the bands"
        );
        assert_eq!(
            gland_by_height(&labels, [0, 3, 2], 10.0, 10.0, 1),
            vec![(0.0, 0.0)]
        );
    }

    /// The surface layers are the ends of the per-layer bands, the paddle's
    /// counted down from the top; a thin breast's ends share no layer.
    #[test]
    fn surface_layers_take_each_end() {
        let layers: Vec<_> = (0..25)
            .map(|k| {
                let k = k as f64;
                (k, k + 1.0, (k, 100.0), (2.0 * k, 100.0 + k))
            })
            .collect();
        let s = surface_layers(&layers);
        assert_eq!(s.support.len(), SURFACE_LAYERS);
        assert_eq!(s.paddle.len(), SURFACE_LAYERS);
        assert_eq!(s.support[0].from_mm, 0.0);
        assert_eq!(s.support[9].gland_recon_cm3, 18.0);
        assert_eq!(s.paddle[0].from_mm, 24.0, "the top layer first");
        assert_eq!(s.paddle[0].gland_true_cm3, 24.0);
        assert_eq!(s.paddle[0].tissue_recon_cm3, 124.0);
        assert_eq!(s.paddle[9].to_mm, 16.0);
        let thin = surface_layers(&layers[..7]);
        assert_eq!((thin.support.len(), thin.paddle.len()), (3, 3));
        assert_eq!(
            thin.paddle[2].from_mm, 4.0,
            "layer 3 (the middle) in neither"
        );
        assert!(surface_layers(&[]).support.is_empty());
    }

    /// Several reconstructors on one acquisition share its truth: the same
    /// phantom, thickness, true glandularity and true MGD; the estimates are
    /// their own (more MLTR iterations change them) and repeatable.
    #[test]
    fn reconstructors_share_the_acquisition_and_the_truth() {
        let g = Geometry::paper().binned(4).unwrap();
        let (name, vol) = test_phantoms(&g, 1).next().unwrap().unwrap();
        let opts = |it| PipelineOptions {
            dbtor: None,
            mltr_iterations: it,
            dose_uncertainty: 0.05,
            seed: 1,
            ..PipelineOptions::default()
        };
        let noise = NoiseLevel::parse("N8").unwrap();
        let cs = run_cases(name.clone(), &vol, &g, noise, &[opts(3), opts(12)], 5).unwrap();
        assert_eq!(cs.len(), 2);
        assert_eq!(cs[0].g_true, cs[1].g_true);
        assert_eq!(cs[0].mgd_true, cs[1].mgd_true);
        assert_eq!(cs[0].thickness_mm, vol.thickness_mm());
        assert!(cs[0].mgd_true > 0.0 && cs[0].mgd_true.is_finite());
        assert_ne!(cs[0].g_partial_volume, cs[1].g_partial_volume);
        let again = run_case(name, &vol, &g, noise, &opts(12), 5).unwrap();
        assert_eq!(again.g_labels, cs[1].g_labels);
        assert_eq!(again.mgd_est, cs[1].mgd_est);
        assert_eq!(again.mgd_true, cs[1].mgd_true);
    }

    /// The validation split draws the exporter's validation indices of the
    /// training population, never the test population.
    #[test]
    fn splits_draw_their_own_populations() {
        assert_eq!(Split::Test.draw(3), (Population::TEST_SEED, 3));
        let v = Split::parse("validation", 2024).unwrap();
        assert_eq!(v.draw(0), (2024, 9));
        assert_eq!(v.draw(2), (2024, 29));
        assert!(Split::parse("validation", Population::TEST_SEED).is_err());
        assert!(Split::parse("train", 2024).is_err());
        assert_eq!(Split::parse("test", 2024).unwrap(), Split::Test);
    }

    #[test]
    fn agreement_of_known_differences() {
        let a = agreement(&[1.0, -1.0, 2.0, -2.0]);
        assert_eq!(a.bias, 0.0);
        assert!((a.sd - (10.0f64 / 3.0).sqrt()).abs() < 1e-12);
        assert_eq!(a.max_abs, 2.0);
        assert!((a.p_value - 1.0).abs() < 1e-12);
        assert!((a.loa[1] - 1.96 * a.sd).abs() < 1e-12);
    }
}
