//! `dbt-eval`: evaluation tables and pictures.

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use dbt_cli::Progress;
use dbt_dbtor::{Dbtor, Precision};
use dbt_eval::picture::{auto_window, compose, Panel};
use dbt_eval::{region_table, table, test_set, BaselineOptions, Learned};
use dbt_forward::NoiseLevel;
use dbt_geometry::Geometry;
use dbt_phantom::PopulationKind;
use dbt_projector::Projector;
use dbt_recon::{mltr, Fbp, MltrOptions};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Parser)]
#[command(
    name = "dbt-eval",
    about = "Reconstruction evaluation on the fixed test set"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

/// Which phantoms an evaluation draws.
#[derive(Args)]
struct SplitArgs {
    /// `test` (the fixed held-out set: report on it) or `validation` (the
    /// dataset's validation phantoms: tune on them).
    #[arg(long, default_value = "test")]
    split: String,
    /// The training population's seed, for `--split validation` (default:
    /// the model manifest's dataset `train_seed`).
    #[arg(long)]
    train_seed: Option<u64>,
    /// Phantom population: `procedural` (every figure up to dbtor-x4t3) or
    /// `anatomical` (issue #26).
    #[arg(long, default_value = "procedural")]
    population: PopulationKind,
}

impl SplitArgs {
    fn resolve(&self, model: Option<&Dbtor>) -> Result<dbt_eval::accuracy::Split> {
        let from_model = model
            .and_then(|m| m.manifest().provenance["dataset_provenance"]["train_seed"].as_u64());
        let seed = match (self.train_seed, self.split.as_str()) {
            (Some(s), _) => s,
            (None, "validation") => from_model.context(
                "--split validation needs --train-seed (or a model whose manifest records the dataset's train_seed)",
            )?,
            (None, _) => 0,
        };
        dbt_eval::accuracy::Split::parse(&self.split, seed)
    }
}

/// How the learned models run (baselines and accuracy alike).
#[derive(Args)]
struct Runtime {
    /// Executor of the model's blocks: fast (the fused kernels) or tract
    /// (the reference).
    #[arg(long, default_value = "fast")]
    engine: String,
    /// Crop the primal blocks to the breast's rows plus this margin
    /// (fast engine; default: the whole image).
    #[arg(long)]
    crop_margin: Option<usize>,
    /// DBToR/LPD's raw output: without the support (the network's output
    /// also in the rows outside the compressed thickness, which the
    /// firmware sets to air: `Dbtor::with_support`) and without the
    /// non-negativity (`Dbtor::with_nonnegativity`); rows labelled "raw".
    #[arg(long, alias = "no-support")]
    raw: bool,
    /// The blocks the `mixed` precision runs in fp32 (the rest int8), comma
    /// separated block names (`primal07,primal08,primal09`).
    #[arg(long, default_value = "primal07,primal08,primal09")]
    mixed_fp32_blocks: String,
}

impl Default for Runtime {
    fn default() -> Self {
        Self {
            engine: "fast".into(),
            crop_margin: None,
            raw: false,
            mixed_fp32_blocks: "primal07,primal08,primal09".into(),
        }
    }
}

#[derive(Subcommand)]
enum Cmd {
    /// MLTR and FBP table (paper Tables 1-2), printed and written as JSON.
    Baselines(BaselinesArgs),
    /// Mean glandular dose of a phantom: patient-specific and model breast
    /// (Monte Carlo, paper Table 3 spectrum), as JSON.
    Mgd(MgdArgs),
    /// End-to-end accuracy of glandularity and MGD on held-out phantoms
    /// (simulated acquisition -> firmware processing), Bland-Altman
    /// statistics, JSON and PNG plots.
    Accuracy(AccuracyArgs),
    /// Two `accuracy` runs of the same phantoms and reconstructor compared
    /// case by case (issue #28: cone-beam against the idealised fan-beam
    /// acquisition): the differences of the reported glandularity (pp) and
    /// MGD (%), and the second run's errors against the truth.
    Paired(PairedArgs),
    /// The classifier against the phantom truth, voxel by voxel: each
    /// phantom reconstructed once and classified with each skin-depth bound,
    /// glandularity errors and confusion matrices (no dose). Tune here on the
    /// validation split; report with `accuracy` on the test split.
    Classification(ClassificationArgs),
    /// The error ladder (issue #48): one phantom's pipeline with one stage
    /// at a time replaced by the truth (attenuation, outline and skin,
    /// noise, reconstructor), glandularity, MGD, voxel confusion and the
    /// error by distance from the skin and by depth at each rung; the
    /// split's summary per rung. Decide on the validation split.
    Ladder(LadderArgs),
    /// Fit the glandularity calibration of a model at one precision on the
    /// validation split (never the test split): the firmware's partial-volume
    /// estimate against the phantoms' truth, `G = offset + slope * estimate`,
    /// written into the model folder (glandularity-calibration.json, bound
    /// to the manifest by its SHA-256), where the firmware finds it.
    Calibrate(CalibrateArgs),
    /// Fit the reports' 95 % intervals of a model at one precision and input
    /// from `accuracy` outputs on the validation split (never the test split,
    /// never an external phantom): each band of thickness and reported
    /// glandularity's residuals (`dbt_intervals`), written into the model
    /// folder (report-intervals.json, bound to the manifest by its SHA-256
    /// and each table to the calibration entry of its key as it stands),
    /// where the firmware finds it. Sign the
    /// model off again afterwards (`dbtor-diag model DIR --sign-off`).
    Intervals(IntervalsArgs),
    /// Whether another beam reads a model's W/Rh glandularity calibration
    /// as well as W/Rh does (eval/README.md, "The W/Ag beam"): two
    /// `accuracy` runs of the same validation phantoms, one W/Rh, one the
    /// other beam, the W/Rh calibration of their precision and inputs
    /// applied to each case, the bar printed (`dbt_eval::accuracy::beam_bar`).
    /// With `--write`, where the bar holds, that calibration is written
    /// into the model's file as the other beam's (`KEY | beam W/Ag`), the
    /// bar beside it; sign the model off again afterwards.
    BeamBar(BeamBarArgs),
    /// Compress an uncompressed VICTRE breastPhantom volume (MetaImage) by
    /// the documented volume-preserving map (`dbt_eval::victre`;
    /// scripts/victre/README.md) and write it with a sidecar that
    /// `accuracy --phantom` and `host-sim acquire --phantom` read.
    /// EVALUATION ONLY.
    VictreCompress(VictreCompressArgs),
    /// PNG of breast phantoms' three orthogonal mid-planes (attenuation,
    /// partial volumes where the phantom has them), drawn phantoms beside
    /// external ones, on axes in mm at one scale.
    Anatomy(AnatomyArgs),
    /// PNG of a test slice: phantom, sinogram, MLTR, FBP.
    Picture(PictureArgs),
    /// PNG of one test phantom's truth beside its reconstructions from the
    /// slice-wise fan-beam acquisition and from cone-beam systems' (issue
    /// #28): axial, sagittal and coronal planes, one scale.
    ConeViews(ConeViewsArgs),
}

/// The options of `dbt-eval cone-views`.
#[derive(Args)]
struct ConeViewsArgs {
    /// Output PNG.
    #[arg(long, default_value = "docs/figures/cone-beam.png")]
    out: PathBuf,
    /// The test phantom (index of the test population).
    #[arg(long, default_value_t = 0)]
    index: u64,
    /// The cone-beam systems, comma separated (built-in names or TOML files).
    #[arg(long, default_value = "paper-cone,siemens-victre")]
    systems: String,
    /// The DBToR model folder.
    #[arg(long, default_value = "models/dbtor-x4t3")]
    model: PathBuf,
    /// Its precision (fp32, int8).
    #[arg(long, default_value = "int8")]
    precision: String,
    /// Noise level of the acquisitions.
    #[arg(long, default_value = "N8")]
    noise: String,
}

/// The options of `dbt-eval intervals`.
#[derive(Args)]
struct IntervalsArgs {
    /// The model folder.
    #[arg(long)]
    model: PathBuf,
    /// The precision the accuracy runs used (fp32, int8).
    #[arg(long, default_value = "int8")]
    precision: String,
    /// The `accuracy` output folders (their accuracy.json), all of the
    /// validation split, all with the same input corrections.
    #[arg(long = "from", required = true)]
    from: Vec<PathBuf>,
    /// Interior thickness band edges, mm (default: the product's,
    /// `dbt_intervals::product_bands`).
    #[arg(long, value_delimiter = ',')]
    thickness_edges: Option<Vec<f64>>,
    /// Interior reported-glandularity band edges, 0..1.
    #[arg(long, value_delimiter = ',')]
    glandularity_edges: Option<Vec<f64>>,
}

/// The options of `dbt-eval beam-bar`.
#[derive(Args)]
struct BeamBarArgs {
    /// The model folder whose W/Rh calibration is read (and, with
    /// `--write`, written).
    #[arg(long)]
    model: PathBuf,
    /// The precision the runs used (fp32, int8).
    #[arg(long, default_value = "int8")]
    precision: String,
    /// The W/Rh `accuracy` run's folder (validation split).
    #[arg(long)]
    w_rh: PathBuf,
    /// The other beam's `accuracy` run of the same phantoms, precision and
    /// input corrections.
    #[arg(long)]
    other: PathBuf,
    /// Where the bar holds, write the W/Rh calibration into the model's
    /// calibration file as the other beam's; refused where it is missed or
    /// the beam has an entry already.
    #[arg(long)]
    write: bool,
}

/// The options of `dbt-eval victre-compress`.
#[derive(Args)]
struct VictreCompressArgs {
    /// The generator's MetaImage header (p_SEED.mhd; its data file beside
    /// it, raw or gzip-compressed).
    #[arg(long)]
    mhd: PathBuf,
    /// Compressed thickness, mm.
    #[arg(
        long,
        conflicts_with = "thickness_ratio",
        required_unless_present = "thickness_ratio"
    )]
    thickness_mm: Option<f64>,
    /// Compressed thickness as a fraction of the breast's height, rounded to
    /// a whole output voxel (VICTRE's pipeline: about 0.49 dense to 0.55
    /// fatty, scripts/victre/README.md).
    #[arg(long)]
    thickness_ratio: Option<f64>,
    /// Output voxel side, mm.
    #[arg(long, default_value_t = 0.5)]
    voxel_mm: f64,
    /// Contact fraction: columns at least this fraction of the tallest's
    /// length are flattened against the paddle (1: the affine map).
    #[arg(long, default_value_t = 0.5)]
    contact: f64,
    /// The sidecar to write (the raw volume beside it, same stem).
    #[arg(long)]
    out: PathBuf,
}

/// The options of `dbt-eval paired`.
#[derive(Args)]
struct PairedArgs {
    /// The reference run's accuracy.json (e.g. the fan-beam one).
    reference: PathBuf,
    /// The compared run's accuracy.json (e.g. the cone-beam one).
    compared: PathBuf,
    /// Write the table and the cases here as JSON.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also print this case's (the reference run's index) fibroglandular
    /// volume by height above the support in both runs, beside the truth's.
    #[arg(long)]
    case: Option<usize>,
}

/// The options of `dbt-eval baselines`.
#[derive(Args)]
struct BaselinesArgs {
    /// Binning of the paper geometry (1 = the paper's; with --model, the
    /// model's geometry is used and this must agree if given).
    #[arg(long)]
    binning: Option<usize>,
    /// A trained DBToR model folder (models/NAME) to evaluate beside the baselines.
    #[arg(long)]
    model: Option<PathBuf>,
    /// Precisions of the model to run (comma separated: fp32, int8,
    /// mixed: int8 but `--mixed-fp32-blocks` in fp32).
    #[arg(long, default_value = "fp32,int8")]
    precisions: String,
    /// A trained LPD model folder (the paper's baseline: DBToR without the
    /// mask), run in fp32 beside the model; same geometry.
    #[arg(long)]
    lpd: Option<PathBuf>,
    /// A trained U-Net model folder (the paper's baseline: a U-Net on the
    /// FBP, `training/dbtor/export_unet.py`); same geometry, except that
    /// one whose manifest says `any_rows` runs on the model's image
    /// height.
    #[arg(long)]
    unet: Option<PathBuf>,
    #[command(flatten)]
    runtime: Runtime,
    /// Phantoms: the first N of the split.
    #[arg(long, default_value_t = 5)]
    phantoms: usize,
    #[command(flatten)]
    split: SplitArgs,
    /// Slices per phantom.
    #[arg(long, default_value_t = 4)]
    slices: usize,
    /// MLTR iterations.
    #[arg(long, default_value_t = 100)]
    iterations: usize,
    /// Noise levels.
    #[arg(long, default_value = "noise-free,N4,N8,N12")]
    levels: String,
    /// JSON output.
    #[arg(long, default_value = "eval/results/baselines.json")]
    json: PathBuf,
}

/// The options of `dbt-eval mgd`.
#[derive(Args)]
struct MgdArgs {
    /// External phantom sidecar (default: a test-set phantom).
    #[arg(long)]
    phantom: Option<PathBuf>,
    /// Test-set phantom index (when no --phantom).
    #[arg(long, default_value_t = 0)]
    index: u64,
    /// Dose voxel side, mm (phantoms are generated or resampled to it).
    #[arg(long, default_value_t = 0.8)]
    voxel: f64,
    /// `dbt` (25 views, -24..24 deg) or `mammo` (0 deg).
    #[arg(long, default_value = "dbt")]
    views: String,
    /// Target relative statistical uncertainty of each MGD.
    #[arg(long, default_value_t = 0.01)]
    target: f64,
    /// Spectrum file (energy keV, weight) instead of the paper's Table 3 choice.
    #[arg(long)]
    spectrum: Option<PathBuf>,
    /// Tube output: incident air kerma at the reference point per mAs
    /// (mGy/mAs, measured on the system), to report MGD in mGy.
    #[arg(long)]
    kerma_mgy_per_mas: Option<f64>,
    /// Tube loading of the whole acquisition, mAs (with --kerma-mgy-per-mas).
    #[arg(long)]
    mas: Option<f64>,
    /// Seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

/// The acquisitions' physics and the firmware's corrections of their
/// counts (`accuracy`, `calibrate`).
#[derive(Args)]
struct PhysicsArgs {
    /// The acquisition's physics (issue #27): `mono` (the paper's: one
    /// energy, photon counting), `clinical` (polychromatic, CsI
    /// energy-integrating detector, quantum and electronic noise, scatter
    /// without a grid) or `clinical-primary` (the same without scatter).
    #[arg(long, default_value = "mono")]
    physics: String,
    /// Linearise the beam hardening before the reconstruction
    /// (`dbt_pipeline::linearise`, the clinical physics' CsI detector).
    #[arg(long)]
    linearise: bool,
    /// Linearise on each ray's known path through the compressed breast
    /// (`dbt_pipeline::linearise::PathModel::Known`, skin
    /// `NOMINAL_SKIN_MM`) rather than as one reference tissue; with
    /// `--linearise`.
    #[arg(long, requires = "linearise")]
    known_path: bool,
    /// Match the corrected counts' noise to this training level's (the
    /// network's: its manifest's `level`, e.g. `N8`;
    /// `dbt_pipeline::noise_match`); with `--linearise`.
    #[arg(long, requires = "linearise")]
    noise_match: Option<String>,
    /// Remove the scatter before the linearisation
    /// (`dbt_pipeline::descatter`, the shipped kernel model).
    #[arg(long)]
    descatter: bool,
    /// The clinical counts as the detector gives them, scatter and beam
    /// hardening left in, for a network trained on such acquisitions
    /// (`host-sim dataset --uncorrected`; issue #27's other design):
    /// neither correction (refused with either), and the counts check
    /// expects the scatter beside the breast above the flat field.
    #[arg(long)]
    uncorrected: bool,
    /// The beam: `W/Rh` (the paper's Table 3 kV for each thickness), or
    /// another of `dbt_dose::xray::AnodeFilter::ALL` at its automatic
    /// exposure (`AnodeFilter::aec_kv`); the acquisition's header carries
    /// it to the corrections and the dose.
    #[arg(long, default_value = "W/Rh")]
    anode_filter: String,
}

/// [`PhysicsArgs`] resolved.
struct Physics {
    /// The simulated physics.
    physics: host_sim::Physics,
    /// The beam-hardening linearisation, if asked for.
    linearise: Option<dbt_pipeline::linearise::BeamHardening>,
    /// The scatter removal, if asked for.
    descatter: Option<dbt_pipeline::descatter::ScatterRemoval>,
    /// The noise matching, if asked for.
    noise_match: Option<dbt_pipeline::noise_match::NoiseMatch>,
    /// The counts go to the network uncorrected, their scatter in them.
    scatter_in_input: bool,
    /// The corrections, as the calibration's key names them.
    input: dbt_model::InputCorrections,
    /// The beam.
    beam: dbt_dose::xray::AnodeFilter,
}

impl PhysicsArgs {
    fn resolve(&self) -> Result<Physics> {
        anyhow::ensure!(
            !(self.uncorrected && (self.linearise || self.descatter)),
            "--uncorrected feeds the detector's counts as they are: not with --linearise or --descatter"
        );
        anyhow::ensure!(
            !self.uncorrected || self.physics == "clinical",
            "--uncorrected is for --physics clinical (its counts hold scatter and beam hardening), not {:?}",
            self.physics
        );
        Ok(Physics {
            physics: host_sim::Physics::parse(&self.physics)?,
            linearise: if self.linearise {
                let bh = dbt_pipeline::linearise::BeamHardening {
                    detector: Default::default(),
                    path: dbt_pipeline::linearise::PathModel::Reference,
                };
                Some(if self.known_path {
                    bh.on_known_path(dbt_pipeline::linearise::NOMINAL_SKIN_MM)?
                } else {
                    bh
                })
            } else {
                None
            },
            noise_match: match &self.noise_match {
                Some(level) => {
                    let n = dbt_forward::NoiseLevel::parse(level)
                        .with_context(|| format!("--noise-match {level}"))?;
                    anyhow::ensure!(
                        n != dbt_forward::NoiseLevel::NoiseFree,
                        "--noise-match {level}: a network's training level has noise"
                    );
                    Some(dbt_pipeline::noise_match::NoiseMatch::to_photons(n.flux())?)
                }
                None => None,
            },
            descatter: if self.descatter {
                Some(dbt_pipeline::descatter::ScatterRemoval::shipped()?)
            } else {
                None
            },
            input: dbt_model::InputCorrections {
                scatter_removed: self.descatter,
                linearised: self.linearise,
                known_path: self.known_path,
                noise_matched: self.noise_match.is_some(),
                // Set from the system's converter below, with the
                // linearisation's detector.
                a_se_detector: false,
                uncorrected_clinical: self.uncorrected,
            },
            scatter_in_input: self.uncorrected,
            beam: dbt_dose::xray::AnodeFilter::parse(&self.anode_filter)
                .with_context(|| format!("--anode-filter {}", self.anode_filter))?,
        })
    }
}

/// `--noise-match LEVEL` against the level the model was trained at (the
/// firmware always matches to the manifest's, so a calibration fit at
/// another would be read under the same key for other counts): refused
/// where they differ, or where the model cannot be matched at all.
fn check_noise_level(
    nm: Option<dbt_pipeline::noise_match::NoiseMatch>,
    manifest: &dbt_dbtor::ModelManifest,
) -> Result<()> {
    if let Some(nm) = nm {
        let own = dbt_pipeline::noise_match::NoiseMatch::for_model(manifest)?;
        anyhow::ensure!(
            own.target_photons == nm.target_photons,
            "--noise-match asks for {} photons per element, but model {} was trained at {} (its manifest's level): the firmware matches to the model's",
            nm.target_photons,
            manifest.name,
            own.target_photons
        );
    }
    Ok(())
}

/// The options of `dbt-eval accuracy`.
#[derive(Args)]
struct AccuracyArgs {
    /// Phantoms: the first N of the split.
    #[arg(long, default_value_t = 30)]
    phantoms: usize,
    #[command(flatten)]
    split: SplitArgs,
    /// Evaluate this external phantom (sidecar) instead.
    #[arg(long)]
    phantom: Option<PathBuf>,
    /// Binning of the paper geometry (voxels = pixels; default 4). With
    /// a model, its geometry is used, and this must agree if given.
    #[arg(long)]
    binning: Option<usize>,
    /// Noise level.
    #[arg(long, default_value = "N8")]
    noise: String,
    /// MLTR iterations.
    #[arg(long, default_value_t = 100)]
    iterations: usize,
    /// Target MGD uncertainty per Monte Carlo run.
    #[arg(long, default_value_t = 0.01)]
    dose_uncertainty: f64,
    /// Output folder (accuracy.json, bland-altman-*.png).
    #[arg(long, default_value = "eval/results/accuracy")]
    out: PathBuf,
    /// The DBToR model (needed for the fp32 and int8 reconstructors).
    #[arg(long)]
    model: Option<PathBuf>,
    #[command(flatten)]
    physics: PhysicsArgs,
    /// Acquire on this cone-beam system (issue #28: `paper-cone`,
    /// `siemens-victre` or a system TOML), binned as the geometry is
    /// (its pixel over 0.2 mm); the firmware rebins to slices. Default: every
    /// coronal slice its own fan beam.
    #[arg(long)]
    system: Option<String>,
    /// The skin rule of the classification (as `classification
    /// --skin`); default: the firmware's.
    #[arg(long)]
    skin: Option<String>,
    /// Report the glandularity uncalibrated even where the model folder
    /// has a calibration (`dbt-eval calibrate`).
    #[arg(long)]
    no_calibration: bool,
    /// The physics density's rim (an evaluation option; eval/physics-density.md):
    /// `per-sector` (as shipped: each sector its own edge profile),
    /// `shared` (every sector the fit to all sectors' envelope) or
    /// `thinnest` (every sector the fattest sector's profile).
    #[arg(long, default_value = "per-sector", value_parser = ["per-sector", "shared", "thinnest"])]
    rim_shape: String,
    /// Reconstructors to compare on the same acquisitions (comma
    /// separated: mltr, fp32, int8, mixed, physics (no reconstruction: the
    /// physics-only report of a gantry without a model, its model breast
    /// as shipped; physics-homogeneous, physics-columns: with either
    /// placement of its glandular tissue); default: fp32 with --model, else
    /// mltr).
    #[arg(long)]
    reconstructors: Option<String>,
    /// Slice steps to run each reconstructor with (comma separated; 2:
    /// every 2nd coronal slice reconstructed, those between interpolated,
    /// the firmware's `recon.slice_step`), on the same acquisitions.
    #[arg(long, default_value = "1")]
    slice_steps: String,
    #[command(flatten)]
    runtime: Runtime,
}

/// The options of `dbt-eval classification`.
#[derive(Args)]
struct ClassificationArgs {
    /// Phantoms: the first N of the split.
    #[arg(long, default_value_t = 20)]
    phantoms: usize,
    #[command(flatten)]
    split: SplitArgs,
    /// Classify this external phantom (sidecar) instead.
    #[arg(long)]
    phantom: Option<PathBuf>,
    /// Binning of the paper geometry, without a model.
    #[arg(long, default_value_t = dbt_cli::DEFAULT_BINNING)]
    binning: usize,
    /// Noise level.
    #[arg(long, default_value = "N8")]
    noise: String,
    /// The DBToR model; without it, MLTR reconstructs.
    #[arg(long)]
    model: Option<PathBuf>,
    /// Model precision (fp32, int8).
    #[arg(long, default_value = "fp32")]
    precision: String,
    /// MLTR iterations (without a model).
    #[arg(long, default_value_t = 100)]
    iterations: usize,
    /// Skin variants to compare, comma separated: `none` (the paper's
    /// unbounded growth), a depth bound in mm (`2.4`: growth through
    /// voxels >= the seed mean, at most that deep), or `shell:MM` (every
    /// voxel within the bound); a bounded rule may add a subcutaneous fat
    /// band, `+fat:MM` (`shell:1.6+fat:0.8`:
    /// `dbt_tissue::ClassifyOptions::fat_band_mm`).
    #[arg(long, default_value = "none,1.6,2.4,3.2,shell:1.6,shell:2.4")]
    skin: String,
    /// Also the patient-specific MGD of each variant against the
    /// phantom's labels, to this relative Monte Carlo uncertainty.
    #[arg(long)]
    dose_uncertainty: Option<f64>,
    /// JSON output.
    #[arg(long, default_value = "eval/results/classification.json")]
    json: PathBuf,
    #[command(flatten)]
    runtime: Runtime,
}

/// The options of `dbt-eval ladder`.
#[derive(Args)]
struct LadderArgs {
    /// Phantoms: the first N of the split.
    #[arg(long, default_value_t = 10)]
    phantoms: usize,
    #[command(flatten)]
    split: SplitArgs,
    /// This external phantom (sidecar) instead.
    #[arg(long)]
    phantom: Option<PathBuf>,
    /// The DBToR model (its calibration is the firmware's).
    #[arg(long)]
    model: PathBuf,
    /// Model precision (fp32, int8).
    #[arg(long, default_value = "int8")]
    precision: String,
    /// Noise level of the noisy rung.
    #[arg(long, default_value = "N8")]
    noise: String,
    /// MLTR iterations of the MLTR rung (0 leaves it out).
    #[arg(long, default_value_t = 100)]
    mltr_iterations: usize,
    /// Relative Monte Carlo uncertainty of each rung's MGD (0: no dose).
    #[arg(long, default_value_t = 0.02)]
    dose_uncertainty: f64,
    /// Band tables (skin distance, depth) printed per phantom.
    #[arg(long)]
    bands: bool,
    /// JSON output.
    #[arg(long, default_value = "eval/results/ladder.json")]
    json: PathBuf,
    #[command(flatten)]
    runtime: Runtime,
}

/// The options of `dbt-eval calibrate`.
#[derive(Args)]
struct CalibrateArgs {
    /// The DBToR model folder.
    #[arg(long)]
    model: PathBuf,
    /// Precision the calibration is for (fp32, int8, mixed).
    #[arg(long, default_value = "fp32")]
    precision: String,
    /// Validation phantoms.
    #[arg(long, default_value_t = 16)]
    phantoms: usize,
    /// The training population's seed (default: the model manifest's).
    #[arg(long)]
    train_seed: Option<u64>,
    /// Population of the validation phantoms (`procedural`,
    /// `anatomical`).
    #[arg(long, default_value = "procedural")]
    population: PopulationKind,
    /// Noise level.
    #[arg(long, default_value = "N8")]
    noise: String,
    /// The acquisitions' physics and corrections: `clinical` with both
    /// corrections fits the calibration the firmware reads when it corrects
    /// its counts the same way (`dbt_model::InputCorrections`).
    #[command(flatten)]
    physics: PhysicsArgs,
    /// Write here instead of the model folder.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Fit nothing: carry this precision's calibrations (every input's) from
    /// another model folder whose blocks of this precision are the same files
    /// (their SHA-256 in both manifests), with the same geometry and
    /// normalisation: a re-quantised folder keeps its fp32 fits.
    #[arg(long)]
    carry_from: Option<PathBuf>,
    /// Fit a thickness term too: `G = a + b PV + c (T - 50 mm)`, `T` the
    /// compressed thickness (`dbt_tissue::GlandularityCalibration::fit_with_thickness`).
    #[arg(long)]
    thickness_term: bool,
    /// The skin rule to fit under (as `classification --skin`; default:
    /// the firmware's). The file records it; a file of another rule is
    /// started afresh.
    #[arg(long)]
    skin: Option<String>,
    #[command(flatten)]
    runtime: Runtime,
}

/// The options of `dbt-eval anatomy`.
#[derive(Args)]
struct AnatomyArgs {
    /// Output PNG.
    #[arg(long, default_value = "docs/figures/anatomy.png")]
    out: PathBuf,
    /// Population of the drawn phantoms.
    #[arg(long, default_value = "anatomical")]
    population: PopulationKind,
    /// Population seed (default: the training datasets' 2024; never the
    /// test seed's phantoms in a picture chosen by eye).
    #[arg(long, default_value_t = 2024)]
    seed: u64,
    /// Indices of the drawn phantoms, comma separated.
    #[arg(long, default_value = "0,1")]
    index: String,
    /// External phantoms (sidecar TOML), comma separated.
    #[arg(long, default_value = "phantoms/victre-pc1.toml")]
    external: String,
    /// Voxel of the pictures, mm (the drawn phantoms are generated at
    /// it, the external ones resampled to it).
    #[arg(long, default_value_t = 0.4)]
    voxel_mm: f64,
}

/// The options of `dbt-eval picture`.
#[derive(Args)]
struct PictureArgs {
    /// Output PNG.
    #[arg(long, default_value = "eval/results/slice.png")]
    out: PathBuf,
    /// Binning of the paper geometry.
    #[arg(long, default_value_t = 1)]
    binning: usize,
    /// Test-set phantom.
    #[arg(long, default_value_t = 0)]
    phantom: usize,
    /// Noise level.
    #[arg(long, default_value = "N8")]
    noise: String,
    /// A trained DBToR model: adds its reconstruction (fp32) and the
    /// difference to the phantom (the paper's Figures 7-9); the geometry
    /// is the model's.
    #[arg(long)]
    model: Option<PathBuf>,
}

/// A skin variant of `dbt-eval classification`: `none`, `MM` or
/// `shell:MM`, a bounded one with `+fat:MM` after it.
fn parse_skin_variant(v: &str) -> Result<dbt_tissue::ClassifyOptions> {
    use dbt_tissue::{ClassifyOptions, SkinRule};
    // A finite positive number of mm, or None.
    let positive_mm = |mm: &str| mm.parse::<f64>().ok().filter(|x| x.is_finite() && *x > 0.0);
    let (skin, fat_band_mm) = match v.split_once("+fat:") {
        Some((skin, mm)) => (
            skin,
            Some(positive_mm(mm).with_context(|| {
                format!("--skin: {v:?}: the fat band {mm:?} is not a positive number of mm")
            })?),
        ),
        None => (v, None),
    };
    if fat_band_mm.is_some() && skin == "none" {
        bail!("--skin: {v:?}: a fat band needs a skin bound (`MM` or `shell:MM` before `+fat:`)");
    }
    let (rule, mm) = match skin.strip_prefix("shell:") {
        Some(mm) => (SkinRule::Shell, mm),
        None => (SkinRule::Grow, skin),
    };
    let bound = match mm {
        "none" if rule == SkinRule::Grow => None,
        mm => Some(positive_mm(mm).with_context(|| {
            format!("--skin: {skin:?} is not `none`, a positive number of mm, or `shell:MM`")
        })?),
    };
    Ok(ClassifyOptions {
        skin_max_mm: bound,
        skin_rule: rule,
        fat_band_mm,
        ..ClassifyOptions::default()
    })
}

/// The table name of a skin variant.
fn skin_variant_name(o: &dbt_tissue::ClassifyOptions) -> String {
    let skin = match (o.skin_rule, o.skin_max_mm) {
        (_, None) => "grow, unbounded (paper)".into(),
        (dbt_tissue::SkinRule::Grow, Some(mm)) => format!("grow, <= {mm} mm"),
        (dbt_tissue::SkinRule::Shell, Some(mm)) => format!("shell {mm} mm"),
    };
    match o.fat_band_mm {
        Some(mm) if o.skin_max_mm.is_some() => format!("{skin} + fat band {mm} mm"),
        _ => skin,
    }
}

/// Write `value` as pretty JSON (and a newline) to `path`, making its folder.
fn write_json(path: &std::path::Path, value: &impl serde::Serialize) -> Result<()> {
    if let Some(d) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(d).with_context(|| format!("creating {}", d.display()))?;
    }
    std::fs::write(path, serde_json::to_string_pretty(value)? + "\n")
        .with_context(|| format!("writing {}", path.display()))
}

fn parse_levels(s: &str) -> Result<Vec<NoiseLevel>> {
    Ok(s.split(',')
        .map(NoiseLevel::parse)
        .collect::<Result<_, _>>()?)
}

/// `dbt-eval cone-views`.
fn run_cone_views(args: ConeViewsArgs) -> Result<()> {
    let ConeViewsArgs {
        out,
        index,
        systems,
        model,
        precision,
        noise,
    } = args;
    let noise = NoiseLevel::parse(&noise)?;
    let rt = Runtime::default();
    let load = |g: Option<&Geometry>| -> Result<Dbtor> {
        load_models_on(Some(&model), &precision, &rt, g)?
            .pop()
            .map(|(_, m)| m)
            .context("no model loaded")
    };
    let m = load(None)?;
    let g = m.geometry().clone();
    let vol = PopulationKind::Procedural
        .draw(&g, dbt_phantom::Population::TEST_SEED, index)
        .generate()?;
    let truth = dbt_eval::picture::mid_planes(&vol).context("the phantom holds no tissue")?;
    let mut rows = vec![(
        format!(
            "test phantom {index} (T {:.0} mm, G {:.0} %)",
            vol.thickness_mm(),
            100.0 * vol.glandularity().unwrap_or(0.0)
        ),
        truth,
    )];
    // Each model (the fan's, and each system's rebinning fan's) as the
    // firmware assembles it.
    let opts = |m: Dbtor| -> Result<dbt_pipeline::PipelineOptions> {
        let settings = dbt_model::load_settings(
            &m,
            &dbt_tissue::ClassifyOptions::default(),
            dbt_model::InputCorrections::default(),
        )?;
        Ok(dbt_pipeline::PipelineOptions::default().with_model(
            std::sync::Arc::new(m),
            settings,
            None,
        )?)
    };
    let tech = host_sim::Technique::default();
    let root = "1.2.826.0.1.3680043.10.543.3";
    let seed = 1000 + index;
    let mut runs: Vec<(String, dbt_pipeline::acquisition::Acquisition, Dbtor)> = Vec::new();
    let kvp = f64::from(dbt_dose::xray::paper_technique(vol.thickness_mm()).0);
    let fan = host_sim::simulate_acquisition(&vol, &g, noise, seed, tech, kvp, "EVAL", root)?;
    runs.push(("slice-wise fan beam".into(), fan, m));
    for name in systems.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let s = dbt_store::load_system(name, 1)?;
        let factor = (g.detector.pitch_mm / s.detector.pitch_mm).round().max(1.0) as usize;
        let s = s.binned(factor)?;
        let g_acq = s.rebinning_fan(&g)?;
        let a = host_sim::simulate_cone_acquisition(
            &vol, &g_acq, &s, noise, seed, tech, kvp, "EVAL", root,
        )?;
        let model = load((g_acq != g).then_some(&g_acq))?;
        runs.push((format!("cone beam, {}", s.name), a, model));
    }
    for (name, acq, m) in runs {
        let res = dbt_pipeline::process(&acq, &opts(m)?)?;
        println!(
            "{name}: G reported {:.3} (truth {:.3}), MGD {:.3} mGy",
            res.glandularity,
            vol.glandularity().unwrap_or(0.0),
            res.mgd_mgy
        );
        let planes = dbt_eval::picture::recon_planes(&vol, &res.mu, res.dims)
            .context("the phantom holds no tissue")?;
        rows.push((
            format!("{name} (G {:.0} %)", 100.0 * res.glandularity),
            planes,
        ));
    }
    let window = (
        dbt_materials::Tissue::Adipose.mu_per_mm() * 0.9,
        dbt_materials::Tissue::Fibroglandular.mu_per_mm() * 1.05,
    );
    let (px, w, h) = dbt_eval::picture::render_planes(&rows, window)?;
    write_png_rgb(&out, &px, w, h)?;
    println!("wrote {}", out.display());
    Ok(())
}

/// `dbt-eval anatomy`: the mid-planes of drawn and external phantoms.
fn anatomy_cmd(
    out: &PathBuf,
    population: PopulationKind,
    seed: u64,
    index: &str,
    external: &str,
    voxel_mm: f64,
) -> Result<()> {
    anyhow::ensure!(
        seed != dbt_phantom::Population::TEST_SEED,
        "pictures are drawn from the training population, not the test seed"
    );
    // A geometry whose pixel is the picture's voxel: the paper's, 104 mm
    // high, at the pixel asked for.
    let mut g = Geometry::builtin("paper-104").context("built-in geometry")?;
    g.image.pixel_mm = voxel_mm;
    g.image.columns = (200.0 / voxel_mm).round() as usize;
    g.image.rows = (104.0 / voxel_mm).round() as usize;
    let mut rows = Vec::new();
    for tok in index.split(',').map(str::trim).filter(|t| !t.is_empty()) {
        let i: u64 = tok.parse().with_context(|| format!("--index {tok:?}"))?;
        let spec = population.draw(&g, seed, i);
        let vol = spec.generate()?;
        let name = format!(
            "{population} #{i} (T {:.0} mm, G {:.0} %)",
            vol.thickness_mm(),
            100.0 * vol.glandularity().unwrap_or(0.0)
        );
        let planes = dbt_eval::picture::mid_planes(&vol).context("the phantom holds no tissue")?;
        rows.push((name, planes));
    }
    for p in external.split(',').map(str::trim).filter(|t| !t.is_empty()) {
        let vol = dbt_store::load_external_phantom(std::path::Path::new(p))?.resampled(voxel_mm)?;
        let stem = std::path::Path::new(p)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| p.to_string());
        let name = format!(
            "{stem} (T {:.0} mm, G {:.0} %)",
            vol.thickness_mm(),
            100.0 * vol.glandularity().unwrap_or(0.0)
        );
        let planes = dbt_eval::picture::mid_planes(&vol).context("the phantom holds no tissue")?;
        rows.push((name, planes));
    }
    let window = (
        dbt_materials::Tissue::Adipose.mu_per_mm() * 0.9,
        dbt_materials::Tissue::Fibroglandular.mu_per_mm() * 1.05,
    );
    let (px, w, h) = dbt_eval::picture::render_planes(&rows, window)?;
    write_png_rgb(out, &px, w, h)?;
    println!("wrote {} ({} phantoms)", out.display(), rows.len());
    Ok(())
}

fn write_png(path: &PathBuf, pixels: &[u8], w: usize, h: usize) -> Result<()> {
    write_png_as(path, pixels, w, h, png::ColorType::Grayscale)
}

fn write_png_rgb(path: &PathBuf, pixels: &[u8], w: usize, h: usize) -> Result<()> {
    write_png_as(path, pixels, w, h, png::ColorType::Rgb)
}

fn write_png_as(
    path: &PathBuf,
    pixels: &[u8],
    w: usize,
    h: usize,
    color: png::ColorType,
) -> Result<()> {
    if let Some(d) = path.parent() {
        std::fs::create_dir_all(d).with_context(|| format!("creating {}", d.display()))?;
    }
    // A picture whose every RGB pixel is grey is written as grey (a third
    // of the bytes: the figures live in the repository).
    let grey;
    let (pixels, color) =
        if color == png::ColorType::Rgb && pixels.chunks(3).all(|p| p[0] == p[1] && p[1] == p[2]) {
            grey = pixels.chunks(3).map(|p| p[0]).collect::<Vec<u8>>();
            (&grey[..], png::ColorType::Grayscale)
        } else {
            (pixels, color)
        };
    let f = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(f), w as u32, h as u32);
    enc.set_color(color);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Best);
    enc.write_header()?.write_image_data(pixels)?;
    Ok(())
}

/// Load a model folder at each precision asked for, named by its kind and
/// precision: `DBToR fp32`, `LPD fp32`, ...
fn load_models(
    dir: Option<&std::path::Path>,
    precisions: &str,
    rt: &Runtime,
) -> Result<Vec<(String, Dbtor)>> {
    load_models_on(dir, precisions, rt, None)
}

/// [`load_models`], the (fully convolutional) blocks run with the operator
/// of `geometry` when given (same sinogram and image grids as the model's):
/// a model on a system it was not trained for, for evaluation only.
fn load_models_on(
    dir: Option<&std::path::Path>,
    precisions: &str,
    rt: &Runtime,
    geometry: Option<&Geometry>,
) -> Result<Vec<(String, Dbtor)>> {
    let Some(dir) = dir else { return Ok(vec![]) };
    let engine: dbt_dbtor::Engine = rt.engine.parse().map_err(anyhow::Error::msg)?;
    let mut out = Vec::new();
    for token in precisions.split(',').filter(|p| !p.is_empty()) {
        let (p, fp32_blocks): (Precision, Vec<String>) = match token {
            "mixed" => (
                Precision::Int8,
                dbt_dbtor::parse_block_list(&rt.mixed_fp32_blocks),
            ),
            p => (p.parse().map_err(anyhow::Error::msg)?, Vec::new()),
        };
        let m = match geometry {
            None => Dbtor::load_mixed(dir, p, &fp32_blocks, engine),
            Some(g) => Dbtor::load_for_geometry(dir, p, &fp32_blocks, engine, g),
        }
        .with_context(|| format!("loading {} ({token}, {engine})", dir.display()))?
        .with_crop(rt.crop_margin)?;
        // The model's default constraints (support: DBToR on, LPD off;
        // non-negativity on), or none.
        let (m, raw) = if rt.raw {
            (m.with_support(false).with_nonnegativity(false), " raw")
        } else {
            (m, "")
        };
        let kind = match m.manifest().kind.as_str() {
            "lpd" => "LPD",
            _ => "DBToR",
        };
        out.push((format!("{kind} {}{raw}", m.precision_label()), m));
    }
    Ok(out)
}

/// The phantoms an evaluation runs on: the external phantom `phantom`
/// (resampled to the geometry's pixel) if given, else the first `n` of
/// `split`.
fn phantom_inputs(
    phantom: Option<&std::path::Path>,
    g: &Geometry,
    split: dbt_eval::accuracy::Split,
    population: PopulationKind,
    n: usize,
) -> Vec<Result<(String, dbt_phantom::LabelVolume)>> {
    match phantom {
        Some(p) => vec![dbt_store::load_external_phantom(p)
            .map_err(anyhow::Error::from)
            .and_then(|v| Ok(v.resampled(g.image.pixel_mm)?))
            .map(|v| (p.display().to_string(), v))],
        None => dbt_eval::accuracy::split_phantoms(g, split, population, n).collect(),
    }
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()),
        )
        .with_writer(dbt_cli::log_writer)
        .init();
    match Cli::parse().cmd {
        Cmd::Baselines(args) => run_baselines(args),
        Cmd::Mgd(args) => run_mgd(args),
        Cmd::Accuracy(args) => run_accuracy(args),
        Cmd::Paired(args) => run_paired(args),
        Cmd::Classification(args) => run_classification(args),
        Cmd::Ladder(args) => run_ladder(args),
        Cmd::Calibrate(args) => run_calibrate(args),
        Cmd::Intervals(args) => run_intervals(args),
        Cmd::BeamBar(args) => run_beam_bar(args),
        Cmd::VictreCompress(args) => run_victre_compress(args),
        Cmd::Anatomy(args) => run_anatomy(args),
        Cmd::Picture(args) => run_picture(args),
        Cmd::ConeViews(args) => run_cone_views(args),
    }
}

/// `dbt-eval baselines`.
fn run_baselines(args: BaselinesArgs) -> Result<()> {
    let BaselinesArgs {
        binning,
        model,
        precisions,
        lpd,
        unet,
        runtime,
        phantoms,
        split,
        slices,
        iterations,
        levels,
        json,
    } = args;
    let mut loaded = load_models(model.as_deref(), &precisions, &runtime)?;
    loaded.extend(load_models(lpd.as_deref(), "fp32", &runtime)?);
    // The U-Net is fully convolutional: with a DBToR model, it runs on
    // that model's image height if its manifest allows (any_rows).
    let rows = loaded.first().map(|(_, m)| m.geometry().image.rows);
    let unet = unet
        .map(|d| {
            dbt_eval::unet::Unet::load_with_rows(&d, rows)
                .map(|u| u.with_nonnegativity(!runtime.raw))
                .with_context(|| format!("loading the U-Net {}", d.display()))
        })
        .transpose()?;
    let mut refs: Vec<(String, Learned)> = loaded
        .iter()
        .map(|(n, m)| (n.clone(), Learned::PrimalDual(m)))
        .collect();
    if let Some(u) = &unet {
        let name = if runtime.raw { "U-Net raw" } else { "U-Net" };
        refs.push((name.into(), Learned::Unet(u)));
    }
    // The learned models' own geometry (evaluate_baselines checks they
    // all agree); --binning must give the same.
    let geometry = match (refs.first(), binning) {
        (Some((_, m)), None) => m.geometry().clone(),
        (Some((name, m)), Some(b)) => {
            let g = Geometry::paper().binned(b)?;
            anyhow::ensure!(
                &g == m.geometry(),
                "--binning {b} gives {}, but {name} was trained for {}",
                g.describe(),
                m.geometry().describe()
            );
            g
        }
        (None, b) => Geometry::paper().binned(b.unwrap_or(1))?,
    };
    let population = split.population;
    let split = split.resolve(loaded.first().map(|(_, m)| m))?;
    let opts = BaselineOptions {
        geometry,
        split,
        population,
        phantoms,
        slices_per_phantom: slices,
        iterations,
        levels: parse_levels(&levels)?,
    };
    let t = Instant::now();
    let bar = Progress::new((phantoms * slices) as u64, "baselines", "slices", false);
    let report = dbt_eval::evaluate_baselines_observed(&opts, &refs, &mut |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })?;
    bar.finish();
    println!(
        "Baselines on the {} split ({} phantoms, {} slices, {}; MLTR {} iterations; {:.0} s)\n",
        split.describe(),
        phantoms,
        report.slices.len(),
        opts.geometry.describe(),
        iterations,
        t.elapsed().as_secs_f64()
    );
    print!("{}", table(&report));
    println!(
        "\nSSIM by region (windows wholly inside the breast, across its outline, wholly in air; \
         share of the windows in brackets)\n"
    );
    print!("{}", region_table(&report));
    write_json(&json, &report)?;
    println!("\nJSON: {}", json.display());
    Ok(())
}

/// `dbt-eval mgd`.
fn run_mgd(args: MgdArgs) -> Result<()> {
    let MgdArgs {
        phantom,
        index,
        voxel,
        views,
        target,
        spectrum,
        kerma_mgy_per_mas,
        mas,
        seed,
    } = args;
    use dbt_dose::patient::{dbt_views, mgd_to_uncertainty, Breast, Model};
    let vol = match &phantom {
        Some(p) => dbt_store::load_external_phantom(p)?.resampled(voxel)?,
        None => {
            let g = Geometry::paper();
            let mut spec = dbt_phantom::Population::for_geometry(&g)
                .draw(dbt_phantom::Population::TEST_SEED, index);
            spec.voxel_mm = voxel;
            dbt_phantom::generate(&spec)?
        }
    };
    let views_deg = match views.as_str() {
        "dbt" => dbt_views(),
        "mammo" => vec![0.0],
        other => anyhow::bail!("--views must be dbt or mammo, got `{other}`"),
    };
    let tube = dbt_dose::xray::paper_spectrum(vol.thickness_mm())?;
    let (spectrum, spectrum_json) = match &spectrum {
        Some(p) => (
            dbt_dose::Spectrum::parse(
                &std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?,
            )
            .with_context(|| format!("spectrum {}", p.display()))?,
            serde_json::json!({ "file": p.display().to_string() }),
        ),
        None => (
            tube.spectrum.clone().context("spectrum")?,
            serde_json::to_value(&tube)?,
        ),
    };
    let b = Breast {
        dims: vol.dims(),
        voxel_mm: vol.voxel_mm(),
        labels: vol.labels(),
    };
    let max = 200_000_000;
    let bar = Progress::new(2, "Monte Carlo MGD", "runs", false);
    bar.message("patient-specific");
    let p = mgd_to_uncertainty(
        &b,
        Model::PatientSpecific,
        &spectrum,
        &views_deg,
        target,
        200_000,
        max,
        seed,
    )?;
    bar.inc(1);
    bar.message("model breast");
    let m = mgd_to_uncertainty(
        &b,
        Model::Homogeneous,
        &spectrum,
        &views_deg,
        target,
        200_000,
        max,
        seed + 1,
    )?;
    bar.finish();
    let out = serde_json::json!({
        "phantom": phantom.as_ref().map(|p| p.display().to_string()).unwrap_or(format!("test-set phantom {index}")),
        "dims": vol.dims(),
        "voxel_mm": vol.voxel_mm(),
        "thickness_mm": vol.thickness_mm(),
        "glandularity": vol.glandularity(),
        "spectrum": spectrum_json,
        "mgd_mgy": match (kerma_mgy_per_mas, mas) {
            // MGD = (MGD / K) x K, K = output x mAs spread over the views
            // (mgd_per_kerma already refers to the summed kerma).
            (Some(k), Some(q)) => serde_json::json!({
                "patient_specific": p.mgd_per_kerma * k * q,
                "model_breast": m.mgd_per_kerma * k * q,
                "kerma_mgy": k * q,
            }),
            _ => serde_json::Value::Null,
        },
        "views": views,
        "patient_specific": p,
        "model_breast": m,
        "model_over_patient": m.mgd_per_kerma / p.mgd_per_kerma,
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}

/// `dbt-eval accuracy`.
fn run_accuracy(args: AccuracyArgs) -> Result<()> {
    let AccuracyArgs {
        phantoms,
        split,
        phantom,
        binning,
        noise,
        iterations,
        dose_uncertainty,
        out,
        model,
        skin,
        no_calibration,
        rim_shape,
        reconstructors,
        slice_steps,
        runtime,
        system,
        physics,
    } = args;
    let Physics {
        physics,
        linearise,
        descatter,
        noise_match,
        scatter_in_input,
        mut input,
        beam,
    } = physics.resolve()?;
    // A system's own converter (a-Se for Hologic and Siemens) is what the
    // linearisation is computed for (below): its calibration key says so.
    if let (Some(name), true) = (&system, input.linearised) {
        input.a_se_detector = dbt_store::load_system(name, 1)
            .with_context(|| format!("--system {name}"))?
            .converter()
            .material
            == dbt_materials::ConverterMaterial::ASe;
    }
    let skin = match skin {
        Some(v) => parse_skin_variant(&v)?,
        None => dbt_tissue::ClassifyOptions::default(),
    };
    use dbt_eval::accuracy::{run_cases_on, summarise, Case, QUANTITIES};
    let noise = NoiseLevel::parse(&noise)?;
    let list =
        reconstructors.unwrap_or_else(|| if model.is_some() { "fp32" } else { "mltr" }.to_string());
    let steps: Vec<usize> = slice_steps
        .split(',')
        .map(|x| {
            x.trim()
                .parse::<usize>()
                .ok()
                .filter(|&n| n >= 1)
                .with_context(|| {
                    format!("--slice-steps {x:?}: a whole number of slices, at least 1")
                })
        })
        .collect::<Result<_>>()?;
    let mut recs: Vec<(String, String, dbt_pipeline::PipelineOptions)> = Vec::new();
    for r in list.split(',').map(str::trim).filter(|r| !r.is_empty()) {
        let dbtor = match r {
            "mltr" | "physics" | "physics-homogeneous" | "physics-columns" => None,
            "fp32" | "int8" | "mixed" => {
                anyhow::ensure!(model.is_some(), "--reconstructors {r} needs --model");
                let m = load_models(model.as_deref(), r, &runtime)?
                    .pop()
                    .map(|(_, m)| m)
                    .context("no model loaded")?;
                check_noise_level(noise_match, m.manifest())?;
                Some(std::sync::Arc::new(m))
            }
            other => {
                anyhow::bail!("unknown reconstructor {other:?} (mltr, fp32, int8, mixed, physics, physics-homogeneous, physics-columns)")
            }
        };
        let tag = match r {
            "mltr" | "physics" | "physics-homogeneous" | "physics-columns" => r.to_string(),
            other => format!("dbtor-{other}"),
        };
        // The options as the firmware assembles them
        // (`PipelineOptions::with_model`): the model's calibrations and
        // report intervals (none with --no-calibration: the intervals were
        // fit on calibrated glandularities), the noise matched to its level.
        let base = dbt_pipeline::PipelineOptions {
            mltr_iterations: iterations,
            dose_uncertainty,
            seed: 1,
            classify: skin,
            linearise,
            descatter,
            noise_match,
            scatter_in_input,
            method: if r.starts_with("physics") {
                dbt_pipeline::ReportMethod::PhysicsOnly
            } else {
                dbt_pipeline::ReportMethod::Reconstruction
            },
            physics_breast: match r {
                "physics-homogeneous" => dbt_pipeline::model_breast::Placement::Homogeneous,
                "physics-columns" => dbt_pipeline::model_breast::Placement::CentralColumns,
                _ => dbt_pipeline::PipelineOptions::default().physics_breast,
            },
            physics_rim: match rim_shape.as_str() {
                "shared" => dbt_physics_density::RimShape::Shared,
                "thinnest" => dbt_physics_density::RimShape::Thinnest,
                _ => dbt_physics_density::RimShape::PerSector,
            },
            ..Default::default()
        };
        let assembled = match &dbtor {
            Some(m) => {
                let settings = if no_calibration {
                    dbt_pipeline::ModelSettings::default()
                } else {
                    dbt_model::load_settings(m, &skin, input)?
                };
                base.with_model(m.clone(), settings, noise_match.map(|_| "--noise-match"))?
            }
            None => base,
        };
        let calibration = assembled.calibration;
        for &slice_step in &steps {
            let opts = dbt_pipeline::PipelineOptions {
                slice_step,
                ..assembled.clone()
            };
            let label = dbt_pipeline::reconstructor_name(&opts);
            // The calibration this run's beam reads (a beam the model has
            // none for is refused at the first phantom, naming it).
            let calibration = opts.for_beam(beam).map_or(calibration, |o| o.calibration);
            let label = match calibration {
                Some(c) if c.per_mm != 0.0 => format!(
                    "{label} [G = {:+.4} + {:.4} x PV {:+.6} x (T - 50 mm)]",
                    c.offset, c.slope, c.per_mm
                ),
                Some(c) => format!("{label} [G = {:+.4} + {:.4} x PV]", c.offset, c.slope),
                None => label,
            };
            let tag = if slice_step > 1 {
                format!("{tag}-step{slice_step}")
            } else {
                tag.clone()
            };
            recs.push((label, tag, opts));
        }
    }
    anyhow::ensure!(!recs.is_empty(), "no reconstructor given");
    // The model's geometry (a taller variant holds thicker breasts);
    // without one, the paper's binned.
    let g = match recs.iter().find_map(|(_, _, o)| o.dbtor.as_deref()) {
        Some(m) => {
            if let Some(b) = binning {
                let want = Geometry::paper().binned(b)?;
                anyhow::ensure!(
                    &want == m.geometry(),
                    "--binning {b} gives {}, but the model was trained for {}",
                    want.describe(),
                    m.geometry().describe()
                );
            }
            m.geometry().clone()
        }
        None => Geometry::paper().binned(binning.unwrap_or(dbt_cli::DEFAULT_BINNING))?,
    };
    let system = match &system {
        None => None,
        Some(name) => {
            let s = dbt_store::load_system(name, 1).with_context(|| format!("--system {name}"))?;
            // Detector elements as near the model's as binning makes them.
            let factor = (g.detector.pitch_mm / s.detector.pitch_mm).round().max(1.0) as usize;
            Some(s.binned(factor)?)
        }
    };
    // The linearisation is for the system's detector: the converter its
    // file states (a-Se for Hologic and Siemens), as the acquisition's.
    if let Some(s) = &system {
        for (_, _, o) in recs.iter_mut() {
            if let Some(bh) = o.linearise.as_mut() {
                bh.detector.converter = s.converter();
            }
        }
    }
    // A system whose rebinning fan is not the model's geometry (another
    // source radius or other views: `siemens-victre`): the model's blocks
    // run with that fan's operator, an evaluation the firmware does not
    // make (it refuses a model on another geometry).
    let g_acq = match &system {
        Some(s) => s.rebinning_fan(&g)?,
        None => g.clone(),
    };
    if g_acq != g {
        eprintln!(
            "the model's blocks run on {} (the rebinning fan of {}), not on {}, the geometry they were trained for",
            g_acq.describe(),
            system.as_ref().map(|s| s.name.as_str()).unwrap_or_default(),
            g.describe()
        );
        for (_, tag, o) in recs.iter_mut() {
            if o.dbtor.is_some() {
                let token = tag.trim_start_matches("dbtor-");
                let m = load_models_on(model.as_deref(), token, &runtime, Some(&g_acq))?
                    .pop()
                    .map(|(_, m)| m)
                    .context("no model loaded")?;
                o.dbtor = Some(std::sync::Arc::new(m));
            }
        }
    }
    let population = split.population;
    let split = split.resolve(recs.iter().find_map(|(_, _, o)| o.dbtor.as_deref()))?;
    let opts: Vec<_> = recs.iter().map(|(_, _, o)| o.clone()).collect();
    let inputs = phantom_inputs(phantom.as_deref(), &g, split, population, phantoms);
    let mut cases: Vec<Vec<Case>> = vec![Vec::new(); recs.len()];
    let bar = Progress::new(inputs.len() as u64, "accuracy", "phantoms", false);
    for (k, item) in inputs.into_iter().enumerate() {
        let (name, vol) = item?;
        bar.message(name.clone());
        let cs = run_cases_on(
            name,
            &vol,
            &g_acq,
            system.as_ref(),
            physics,
            beam,
            noise,
            &opts,
            1000 + k as u64,
        )?;
        bar.inc(1);
        for ((label, _, _), (c, all)) in recs.iter().zip(cs.into_iter().zip(cases.iter_mut())) {
            bar.line(format!(
                "{} [{label}]: T {:.1} mm, G true {:.3} labels {:.3} pv {:.3}; MGD true {:.3} est {:.3} model {:.3} mGy ({:.0} s)",
                c.phantom, c.thickness_mm, c.g_true, c.g_labels, c.g_partial_volume, c.mgd_true, c.mgd_est, c.mgd_model, c.seconds
            ));
            all.push(c);
        }
    }
    bar.finish();
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    println!("| reconstructor | quantity | bias | sd | 95 % limits | max abs | p (bias) | n |\n|---|---|---|---|---|---|---|---|");
    let mut results = Vec::new();
    for ((label, tag, _), cases) in recs.iter().zip(&cases) {
        let summary = summarise(cases);
        let mut plots = serde_json::Map::new();
        for (q, a) in QUANTITIES.iter().zip(summary.in_order()) {
            println!(
                "| {label} | {} | {:+.2} | {:.2} | [{:+.2}, {:+.2}] | {:.2} | {:.3} | {} |",
                q.name, a.bias, a.sd, a.loa[0], a.loa[1], a.max_abs, a.p_value, a.n
            );
            let (diffs, means): (Vec<f64>, Vec<f64>) = cases.iter().map(q.pick).unzip();
            let file = format!("bland-altman-{tag}-{}.png", q.short);
            let plot = dbt_eval::picture::BlandAltman {
                title: format!("{label}: {}", q.name),
                x_label: q.mean_axis,
                y_label: q.difference_axis,
                means: &means,
                diffs: &diffs,
                bias: a.bias,
                loa: a.loa,
            };
            let (px, w, h, ranges) = plot.render()?;
            write_png_rgb(&out.join(&file), &px, w, h)?;
            plots.insert(file, serde_json::json!({"quantity": q.name, "x_range_mean": [ranges[0], ranges[1]], "y_range_difference": [ranges[2], ranges[3]]}));
        }
        results.push(serde_json::json!({
            "reconstructor": label,
            "cases": cases,
            "summary": summary,
            "plots": plots,
        }));
    }
    let json = serde_json::json!({
        "noise": noise.name(),
        "geometry": g_acq.describe(),
        "system": system.as_ref().map(|s| s.name.clone()),
        "physics": physics.name(),
        "linearised": linearise.is_some(),
        "detector": if input.a_se_detector { "a-Se" } else { "CsI" },
        "linearised_on_known_path": linearise.is_some_and(|l| l.path != dbt_pipeline::linearise::PathModel::Reference),
        "noise_matched_to_photons": noise_match.map(|n| n.target_photons),
        "descattered": descatter.is_some(),
        "uncorrected_input": scatter_in_input,
        "anode_filter": beam.name(),
        "phantoms": match &phantom {
            Some(p) => p.display().to_string(),
            None => split.describe(),
        },
        "classification": skin,
        "skin": skin_variant_name(&skin),
        "reconstructors": results,
    });
    write_json(&out.join("accuracy.json"), &json)?;
    // What the firmware's plausibility checks measured (none refused,
    // or the run would have stopped naming the case).
    for ((label, _, opts), cases) in recs.iter().zip(&cases) {
        if opts.method == dbt_pipeline::ReportMethod::PhysicsOnly {
            // Nothing reconstructed: no volume to check, no cross-check.
            let flagged: Vec<&Case> = cases
                .iter()
                .filter(|c| !c.density_check.confirmed)
                .collect();
            println!(
                "physics-only [{label}]: {} of {} estimates flagged by their own checks",
                flagged.len(),
                cases.len()
            );
            for c in flagged {
                println!("  {}: {}", c.phantom, c.density_check.reasons.join("; "));
            }
            continue;
        }
        let range = |f: &dyn Fn(&Case) -> f64| {
            cases
                .iter()
                .map(f)
                .fold([f64::INFINITY, f64::NEG_INFINITY], |r, v| {
                    [r[0].min(v), r[1].max(v)]
                })
        };
        let fill = range(&|c| c.plausibility.volume.fill);
        let mu = range(&|c| c.plausibility.volume.breast_mean_mu);
        let corrected: usize = cases.iter().map(|c| c.plausibility.counts.corrected).sum();
        println!(
            "plausibility [{label}]: {} cases passed; breast volume / (thickness x footprint) {:.3}-{:.3} (limits {}-{}); breast mean attenuation {:.4}-{:.4} /mm; {corrected} counts corrected",
            cases.len(), fill[0], fill[1],
            dbt_pipeline::plausibility::VOLUME_FILL_MIN, dbt_pipeline::plausibility::VOLUME_FILL_MAX,
            mu[0], mu[1]
        );
    }
    // The cross-check against the physics density (issue #48 point 3):
    // how many reports would assert no category, and the disagreements the
    // limits are set from (eval/density-check.md).
    for ((label, _, opts), cases) in recs.iter().zip(&cases) {
        if opts.method == dbt_pipeline::ReportMethod::PhysicsOnly {
            continue;
        }
        let unconfirmed = cases.iter().filter(|c| !c.density_check.confirmed).count();
        let most = |f: &dyn Fn(&Case) -> Option<f64>| {
            cases
                .iter()
                .filter_map(f)
                .fold(0.0f64, |m, d| m.max(d.abs()))
        };
        let whole = most(&|c| c.density_check.difference_pp);
        let contact = most(&|c| c.density_check.contact_difference_pp);
        // The nearest any case came to its band's limits, as a share of it.
        let nearest = cases
            .iter()
            .flat_map(|c| {
                let l = &c.density_check.limits;
                [
                    c.density_check.difference_pp.map(|d| d.abs() / l.whole_pp),
                    c.density_check
                        .contact_difference_pp
                        .map(|d| d.abs() / l.contact_pp),
                ]
            })
            .flatten()
            .fold(0.0f64, f64::max);
        let l = dbt_pipeline::density_check::LIMITS;
        let bands = (0..l.bands.len())
            .map(|k| {
                let a = l.at(l.bands[k].from_reported);
                let band = if a.band[1].is_finite() {
                    format!("{:.0}-{:.0} %", 100.0 * a.band[0], 100.0 * a.band[1])
                } else {
                    format!(">= {:.0} %", 100.0 * a.band[0])
                };
                format!("{band} {:.0}/{:.0}", a.whole_pp, a.contact_pp)
            })
            .collect::<Vec<_>>()
            .join(", ");
        println!(
            "density check [{label}]: {unconfirmed} of {} not confirmed; largest |reported - physics| {whole:.1} pp, over the contact region {contact:.1} pp, the nearest to its band's limit {:.0} % of it (limits, whole/contact pp, by the reported glandularity: {bands}); smallest fill of the box {:.3} (limit {:.2}); largest excess of the data residual over its noise {:.4} (limit {:.3}), {} beyond it",
            cases.len(),
            100.0 * nearest,
            cases.iter().map(|c| c.plausibility.volume.fill).fold(f64::INFINITY, f64::min),
            l.min_fill,
            cases.iter().filter_map(|c| c.data_fit).map(|f| f.excess).fold(0.0f64, f64::max),
            l.data_fit_max,
            cases.iter().filter_map(|c| c.data_fit).filter(|f| f.excess > l.data_fit_max).count()
        );
        for c in cases.iter().filter(|c| !c.density_check.confirmed) {
            println!("  {}: {}", c.phantom, c.density_check.reasons.join("; "));
        }
    }
    // The reports' 95 % intervals against the truth (issue #48 point 4).
    for ((label, _, _), cases) in recs.iter().zip(&cases) {
        let [g, m] = [
            interval_coverage(cases.iter().map(|c| (&c.intervals.glandularity, c.g_true))),
            interval_coverage(cases.iter().map(|c| (&c.intervals.mgd, c.mgd_true))),
        ];
        println!(
            "95 % intervals [{label}]: glandularity given for {} of {}, covering the truth in {}; MGD given for {}, covering the truth in {}",
            g.0,
            cases.len(),
            g.1,
            m.0,
            m.1,
        );
        if let Some(c) = cases
            .iter()
            .find(|c| c.intervals.glandularity.limits.is_none())
        {
            println!(
                "  none for {}: {}",
                c.phantom, c.intervals.glandularity.basis
            );
        }
    }
    println!("\nJSON and Bland-Altman PNGs (x: mean of truth and estimate; y: difference; solid: bias; dashed: 95 % limits): {}", out.display());
    Ok(())
}

/// `dbt-eval intervals`.
fn run_intervals(args: IntervalsArgs) -> Result<()> {
    let IntervalsArgs {
        model,
        precision,
        from,
        thickness_edges,
        glandularity_edges,
    } = args;
    let prec: dbt_dbtor::Precision = precision.parse().map_err(anyhow::Error::msg)?;
    let m = dbt_dbtor::Dbtor::load_mixed(&model, prec, &[], dbt_dbtor::Engine::Fast)
        .with_context(|| format!("loading {}", model.display()))?;
    let label = m.precision_label();
    let name = m.manifest().name.clone();
    let mut residuals = Vec::new();
    let mut inputs = Vec::new();
    let mut input: Option<dbt_model::InputCorrections> = None;
    for dir in &from {
        let (path, j) = read_validation_run(dir, "intervals are fit on validation breasts only")?;
        let phantoms = j["phantoms"].as_str().unwrap_or("");
        anyhow::ensure!(
            j["anode_filter"].as_str() == Some("W/Rh"),
            "{}: beam {}, the intervals are W/Rh's",
            path.display(),
            j["anode_filter"]
        );
        let this = run_input_corrections(&j);
        if let Some(first) = input {
            anyhow::ensure!(
                first == this,
                "{}: inputs {:?}, but the first run's are {:?}; one table per input",
                path.display(),
                this.key(&label),
                first.key(&label)
            );
        }
        input = Some(this);
        let recs = j["reconstructors"]
            .as_array()
            .context("no reconstructors")?;
        let r = recs
            .iter()
            .find(|r| {
                r["reconstructor"].as_str().is_some_and(|s| {
                    s.contains(&name)
                        && s.contains(&format!("({precision},"))
                        && s.contains("calibrated")
                })
            })
            .with_context(|| {
                format!(
                    "{}: no calibrated {precision} run of {name}",
                    path.display()
                )
            })?;
        let cases = r["cases"].as_array().context("no cases")?;
        for c in cases {
            let f = |k: &str| {
                c[k].as_f64().with_context(|| {
                    format!(
                        "{}: a case without {k} (rerun `dbt-eval accuracy`)",
                        path.display()
                    )
                })
            };
            residuals.push(dbt_intervals::Residual {
                thickness_mm: f("thickness_mm")?,
                g_reported: f("g_reported")?,
                g_true: f("g_true")?,
                mgd_est_mgy: f("mgd_est")?,
                mgd_true_mgy: f("mgd_true")?,
                mgd_est_rel_uncertainty: f("mgd_est_rel_uncertainty")?,
                mgd_true_rel_uncertainty: f("mgd_true_rel_uncertainty")?,
            });
        }
        inputs.push(format!(
            "{} ({} cases, physics {}): {phantoms}",
            dir.display(),
            cases.len(),
            j["physics"].as_str().unwrap_or("?")
        ));
    }
    let input = input.context("no runs")?;
    let mut bands = dbt_intervals::product_bands();
    if let Some(e) = thickness_edges {
        bands.thickness_mm = e;
    }
    if let Some(e) = glandularity_edges {
        bands.glandularity = e;
    }
    let table = dbt_intervals::IntervalTable::fit(&residuals, bands)?;
    let key = input.key(&label);
    println!(
        "report intervals of {name}, {key}: {} validation breasts",
        residuals.len()
    );
    println!("| band | n | glandularity: reported - true, mean (pp) | s.d. (pp) | 95 % half-width (pp) | MGD: ln(est/true) mean (%) | s.d. (%) | of which Monte Carlo (%) |");
    println!("|---|---|---|---|---|---|---|---|");
    for st in &table.stats {
        println!(
            "| {} | {} | {:+.2} | {:.2} | {:.2} | {:+.2} | {:.2} | {:.2} |",
            table
                .bands
                .describe((st.thickness_band, st.glandularity_band)),
            st.n,
            st.g_mean_pp,
            st.g_sd_pp,
            st.glandularity_half_width_pp(),
            100.0 * st.mgd_log_mean,
            100.0 * st.mgd_log_sd,
            100.0 * st.mgd_mc_var.sqrt()
        );
    }
    let path = model.join(dbt_model::INTERVALS_FILE);
    let mut file = dbt_model::IntervalsFile::open_or_new(&path, &m)?;
    // The calibration the runs' reported glandularity went through: the
    // model's entry for these inputs as it stands (the table is refused
    // once that entry changes).
    let calibration = dbt_model::current_calibration(&m, input)?;
    file.tables.insert(
        key,
        dbt_model::IntervalsEntry {
            table,
            calibration,
            source: dbt_model::IntervalsSource {
                command: std::env::args().collect::<Vec<_>>().join(" "),
                inputs,
                cases: residuals.len(),
            },
        },
    );
    std::fs::write(&path, serde_json::to_string_pretty(&file)? + "\n")
        .with_context(|| format!("writing {}", path.display()))?;
    println!(
        "written: {} (sign the model off again: dbtor-diag model {} --sign-off)",
        path.display(),
        model.display()
    );
    Ok(())
}

/// The input corrections an `accuracy` run's accuracy.json records.
fn run_input_corrections(j: &serde_json::Value) -> dbt_model::InputCorrections {
    let flag = |k: &str| j[k].as_bool().unwrap_or(false);
    dbt_model::InputCorrections {
        scatter_removed: flag("descattered"),
        linearised: flag("linearised"),
        known_path: flag("linearised_on_known_path"),
        noise_matched: !j["noise_matched_to_photons"].is_null(),
        a_se_detector: j["detector"].as_str() == Some("a-Se"),
        uncorrected_clinical: flag("uncorrected_input"),
    }
}

/// One `accuracy` run read for `beam-bar`: its beam, input corrections,
/// phantoms' description and, per case, (phantom, T mm, G true, partial
/// volume) of `name`'s `precision` run.
struct BarRun {
    beam: dbt_dose::xray::AnodeFilter,
    input: dbt_model::InputCorrections,
    phantoms: String,
    classification: serde_json::Value,
    cases: Vec<(String, f64, f64, f64)>,
}

/// An `accuracy` run's accuracy.json (its path, its JSON), refused unless
/// its phantoms are the validation split (`why` says what is decided on
/// it): what the model's files are fit on never sees a test breast.
fn read_validation_run(dir: &Path, why: &str) -> Result<(PathBuf, serde_json::Value)> {
    let path = dir.join("accuracy.json");
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let j: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
    let phantoms = j["phantoms"].as_str().unwrap_or("");
    anyhow::ensure!(
        phantoms.starts_with("validation"),
        "{}: phantoms {phantoms:?} are not the validation split; {why}",
        path.display()
    );
    Ok((path, j))
}

fn read_bar_run(dir: &Path, name: &str, precision: &str) -> Result<BarRun> {
    let (path, j) = read_validation_run(dir, "a calibration is chosen on validation breasts only")?;
    let phantoms = j["phantoms"].as_str().unwrap_or("").to_string();
    let beam_name = j["anode_filter"].as_str().unwrap_or("");
    let beam = dbt_dose::xray::AnodeFilter::parse(beam_name)
        .map_err(|e| anyhow::anyhow!("{}: anode_filter {beam_name:?}: {e}", path.display()))?;
    let r = j["reconstructors"]
        .as_array()
        .and_then(|rs| {
            rs.iter().find(|r| {
                r["reconstructor"]
                    .as_str()
                    .is_some_and(|s| s.contains(&format!(" {name} ({precision},")))
            })
        })
        .with_context(|| format!("{}: no {precision} run of {name}", path.display()))?;
    let mut cases = Vec::new();
    for c in r["cases"].as_array().context("no cases")? {
        let f = |k: &str| {
            c[k].as_f64()
                .with_context(|| format!("{}: a case without {k}", path.display()))
        };
        let phantom = c["phantom"]
            .as_str()
            .with_context(|| format!("{}: a case without its phantom", path.display()))?;
        cases.push((
            phantom.to_string(),
            f("thickness_mm")?,
            f("g_true")?,
            f("g_partial_volume")?,
        ));
    }
    Ok(BarRun {
        beam,
        input: run_input_corrections(&j),
        phantoms,
        classification: j["classification"].clone(),
        cases,
    })
}

/// `dbt-eval beam-bar`.
fn run_beam_bar(args: BeamBarArgs) -> Result<()> {
    use dbt_dose::xray::AnodeFilter;
    use dbt_model::{CalibrationFile, CALIBRATION_FILE};
    let prec: Precision = args.precision.parse().map_err(anyhow::Error::msg)?;
    let m = Dbtor::load_mixed(&args.model, prec, &[], dbt_dbtor::Engine::Fast)
        .with_context(|| format!("loading {}", args.model.display()))?;
    let (label, name) = (m.precision_label(), m.manifest().name.clone());
    let (a, b) = (
        read_bar_run(&args.w_rh, &name, &args.precision)?,
        read_bar_run(&args.other, &name, &args.precision)?,
    );
    anyhow::ensure!(
        a.beam == AnodeFilter::WRh,
        "{}: beam {}, not W/Rh",
        args.w_rh.display(),
        a.beam.name()
    );
    anyhow::ensure!(
        b.beam != AnodeFilter::WRh,
        "{}: beam W/Rh; the other run must be another beam's",
        args.other.display()
    );
    anyhow::ensure!(
        a.input == b.input,
        "the runs' inputs differ: {} against {}",
        a.input.key(&label),
        b.input.key(&label)
    );
    anyhow::ensure!(
        a.phantoms == b.phantoms
            && a.cases.len() == b.cases.len()
            && a.cases.iter().zip(&b.cases).all(|(x, y)| x.0 == y.0),
        "the runs are not of the same phantoms ({}: {} cases of {}; {}: {} cases of {})",
        args.w_rh.display(),
        a.cases.len(),
        a.phantoms,
        args.other.display(),
        b.cases.len(),
        b.phantoms
    );
    let path = args.model.join(CALIBRATION_FILE);
    let mut file = CalibrationFile::read(&path, &m)?;
    let classification = serde_json::to_value(file.classification)?;
    for (run, dir) in [(&a, &args.w_rh), (&b, &args.other)] {
        anyhow::ensure!(
            run.classification == classification,
            "{}: classified with {}, but the calibration was fit with {classification}",
            dir.display(),
            run.classification
        );
    }
    let key = a.input.key(&label);
    // As the firmware applies it (a thickness term held within the
    // thicknesses it was fit on), and so carried: the range stated.
    let cal = file.applied(&key).with_context(|| {
        format!(
            "{}: no calibration under {key:?} (it has {:?})",
            path.display(),
            file.calibrations.keys().collect::<Vec<_>>()
        )
    })?;
    let errors = |r: &BarRun| -> Vec<f64> {
        r.cases
            .iter()
            .map(|(_, t, g, pv)| 100.0 * (cal.apply(*pv, *t) - g))
            .collect()
    };
    let bar = dbt_eval::accuracy::beam_bar(&errors(&a), &errors(&b));
    println!(
        "{name}, calibration {key:?}: G = {:+.5} + {:.5} x partial volume{}",
        cal.offset,
        cal.slope,
        if cal.per_mm != 0.0 {
            format!(" {:+.6} x (T - 50 mm)", cal.per_mm)
        } else {
            String::new()
        }
    );
    println!("| beam (W/Rh calibration) | n | bias (pp) | sd (pp) | max abs (pp) |\n|---|---|---|---|---|");
    for (beam, ag) in [(a.beam, bar.w_rh), (b.beam, bar.other)] {
        println!(
            "| {} | {} | {:+.2} | {:.2} | {:.2} |",
            beam.name(),
            ag.n,
            ag.bias,
            ag.sd,
            ag.max_abs
        );
    }
    use dbt_eval::accuracy::{BEAM_BAR_BIAS_PP, BEAM_BAR_MAX_PP, BEAM_BAR_SD_PP};
    println!(
        "bar: |bias difference| {:.2} pp (<= {BEAM_BAR_BIAS_PP}), sd difference {:+.2} pp (<= {BEAM_BAR_SD_PP}), largest error {:.2} pp (<= {BEAM_BAR_MAX_PP}): {}",
        bar.bias_difference_pp,
        bar.sd_difference_pp,
        bar.other.max_abs,
        if bar.kept {
            "kept"
        } else {
            "missed: the beam needs its own calibration"
        }
    );
    if !args.write {
        return Ok(());
    }
    let beam_key = a.input.beam_key(&label, b.beam.name());
    if !bar.kept {
        bail!(
            "not written: {} missed the bar; fit its own calibration (`dbt-eval calibrate --anode-filter {}` with the same precision and corrections)",
            b.beam.name(),
            b.beam.name()
        );
    }
    if file.calibrations.contains_key(&beam_key) {
        bail!(
            "not written: {} has an entry {beam_key:?} already; remove it first to replace it",
            path.display()
        );
    }
    file.insert_fit(
        &beam_key,
        cal,
        serde_json::json!({
            (dbt_model::KEPT_FROM_FIELD): key,
            "why": "the beam's validation acquisitions read with the W/Rh calibration passed the bar written before they were evaluated (eval/README.md, \"The W/Ag beam\")",
            "bar": {
                "limits_pp": {
                    "bias_difference": BEAM_BAR_BIAS_PP,
                    "sd_difference": BEAM_BAR_SD_PP,
                    "max_abs": BEAM_BAR_MAX_PP,
                },
                "result": bar,
            },
            "command": std::env::args().collect::<Vec<_>>().join(" "),
            "split": b.phantoms,
            "anode_filter": b.beam.name(),
            "input_corrections": b.input.describe(),
            "cases": b.cases.iter().map(|(p, t, g, pv)| serde_json::json!({
                "phantom": p, "thickness_mm": t, "g_true": g, "g_partial_volume": pv,
            })).collect::<Vec<_>>(),
        }),
    );
    write_json(&path, &file)?;
    println!(
        "wrote {beam_key:?} into {} (sign the model off again: dbtor-diag model {} --sign-off, and pin its new digest)",
        path.display(),
        args.model.display()
    );
    Ok(())
}

/// `dbt-eval victre-compress`.
fn run_victre_compress(args: VictreCompressArgs) -> Result<()> {
    let text = std::fs::read_to_string(&args.mhd)
        .with_context(|| format!("reading {}", args.mhd.display()))?;
    let field = |k: &str| {
        text.lines()
            .find_map(|l| {
                let (a, b) = l.split_once('=')?;
                (a.trim() == k).then(|| b.trim().to_string())
            })
            .with_context(|| format!("{}: no {k}", args.mhd.display()))
    };
    let nums = |k: &str| -> Result<Vec<f64>> {
        field(k)?
            .split_whitespace()
            .map(|v| v.parse::<f64>().with_context(|| format!("{k}: {v:?}")))
            .collect()
    };
    let d = nums("DimSize")?;
    let sp = nums("ElementSpacing")?;
    anyhow::ensure!(
        d.len() == 3 && sp.len() == 3,
        "{}: not a 3-D volume",
        args.mhd.display()
    );
    anyhow::ensure!(
        sp.iter().all(|v| (v - sp[0]).abs() < 1e-9),
        "{}: voxels {sp:?} are not cubic",
        args.mhd.display()
    );
    anyhow::ensure!(
        field("ElementType")? == "MET_UCHAR",
        "{}: not uint8 labels",
        args.mhd.display()
    );
    let dir = args.mhd.parent().unwrap_or(std::path::Path::new("."));
    let data = dir.join(field("ElementDataFile")?);
    let gz = std::path::PathBuf::from(format!("{}.gz", data.display()));
    let raw = dbt_store::read_maybe_gz(if data.is_file() { &data } else { &gz })?;
    let dims = [d[0] as usize, d[1] as usize, d[2] as usize];
    let thickness_mm = match (args.thickness_mm, args.thickness_ratio) {
        (Some(t), _) => t,
        (None, Some(r)) => {
            let h = dbt_eval::victre::height_mm(&raw, dims, sp[0])
                .with_context(|| format!("{}: no breast tissue", args.mhd.display()))?;
            (r * h / args.voxel_mm).round() * args.voxel_mm
        }
        (None, None) => anyhow::bail!("--thickness-mm or --thickness-ratio"),
    };
    let c =
        dbt_eval::victre::compress(&raw, dims, sp[0], thickness_mm, args.voxel_mm, args.contact)?;
    let stem = args
        .out
        .file_stem()
        .context("--out needs a file name")?
        .to_string_lossy()
        .to_string();
    let raw_name = format!("{stem}.raw");
    let out_dir = args.out.parent().unwrap_or(std::path::Path::new("."));
    std::fs::write(out_dir.join(&raw_name), &c.labels)?;
    let provenance = format!(
        "VICTRE breastPhantom {} ({:.1} mm tall, chest wall cropped by {} voxels), compressed to {} mm \
         (contact fraction {}, in-plane stretch {:.3}) by the volume-preserving map of dbt_eval::victre (`{}`)",
        args.mhd.display(),
        c.height_mm,
        c.cropped_voxels,
        thickness_mm,
        args.contact,
        c.stretch,
        std::env::args().collect::<Vec<_>>().join(" ")
    );
    std::fs::write(
        &args.out,
        dbt_eval::victre::sidecar(&c, &raw_name, &provenance),
    )?;
    let vol = dbt_store::load_external_phantom(&args.out)?;
    println!(
        "{}: {:?} voxels of {} mm, {:.1} mm thick, glandularity by mass {:.3} (from {:.1} mm tall)",
        args.out.display(),
        c.dims,
        c.voxel_mm,
        vol.thickness_mm(),
        vol.glandularity().unwrap_or(f64::NAN),
        c.height_mm
    );
    Ok(())
}

/// Of figures with their intervals and truths: how many intervals were
/// given, and how many of those hold the truth.
fn interval_coverage<'a>(
    figures: impl Iterator<Item = (&'a dbt_pipeline::FigureInterval, f64)>,
) -> (usize, usize) {
    figures.fold((0, 0), |(n, k), (iv, truth)| match iv.limits {
        Some([a, b]) => (n + 1, k + usize::from((a..=b).contains(&truth))),
        None => (n, k),
    })
}

/// `dbt-eval classification`.
fn run_classification(args: ClassificationArgs) -> Result<()> {
    let ClassificationArgs {
        phantoms,
        split,
        phantom,
        binning,
        noise,
        model,
        precision,
        iterations,
        skin,
        dose_uncertainty,
        json,
        runtime,
    } = args;
    use dbt_eval::classification::{run_phantom, summarise, CLASSES};
    let model = load_models(model.as_deref(), &precision, &runtime)?
        .pop()
        .map(|(_, m)| std::sync::Arc::new(m));
    let population = split.population;
    let split = split.resolve(model.as_deref())?;
    let g = match &model {
        Some(m) => m.geometry().clone(),
        None => Geometry::paper().binned(binning)?,
    };
    let noise = NoiseLevel::parse(&noise)?;
    let variants = skin
        .split(',')
        .map(|v| parse_skin_variant(v.trim()))
        .collect::<Result<Vec<_>>>()?;
    let opts = dbt_pipeline::PipelineOptions {
        dbtor: model,
        mltr_iterations: iterations,
        ..Default::default()
    };
    let reconstructor = dbt_pipeline::reconstructor_name(&opts);
    let t0 = Instant::now();
    let mut per_variant = vec![Vec::new(); variants.len()];
    let inputs = phantom_inputs(phantom.as_deref(), &g, split, population, phantoms);
    let phantoms = inputs.len();
    let bar = Progress::new(phantoms as u64, "classification", "phantoms", false);
    for (k, item) in inputs.into_iter().enumerate() {
        let (name, vol) = item?;
        bar.message(name.clone());
        let cs = run_phantom(
            &name,
            &vol,
            &g,
            noise,
            host_sim::Physics::Mono,
            dbt_dose::xray::AnodeFilter::WRh,
            &opts,
            &variants,
            dose_uncertainty,
            1000 + k as u64,
        )?;
        let mut line = format!(
            "{name}: T {:.1} mm, G true {:.3}",
            vol.thickness_mm(),
            cs[0].g_true
        );
        for c in &cs {
            line += &format!(" | {:.3} / {:.3}", c.g_labels, c.g_partial_volume);
            if let Some(e) = c.mgd_error_percent {
                line += &format!(" / MGD {e:+.1} %");
            }
        }
        bar.inc(1);
        bar.line(line);
        for (all, c) in per_variant.iter_mut().zip(cs) {
            all.push(c);
        }
    }
    bar.finish();
    let source = match &phantom {
        Some(p) => p.display().to_string(),
        None => format!("{phantoms} phantoms of the {} split", split.describe()),
    };
    println!(
        "Classification on {source}, {reconstructor}, {} ({:.0} s)\n",
        noise.name(),
        t0.elapsed().as_secs_f64()
    );
    println!("| skin | G labels bias / sd / max (pp) | G partial volume bias / sd / max (pp) | MGD bias / sd / max (%) | fibroglandular read as adipose / skin | adipose read as fibroglandular | skin read as fibroglandular |\n|---|---|---|---|---|---|---|");
    let mut out = Vec::new();
    for (o, cases) in variants.into_iter().zip(per_variant) {
        let s = summarise(o, cases);
        let (a, b) = (s.glandularity_labels_pp, s.glandularity_partial_volume_pp);
        let f = &s.confusion_fractions;
        let mgd = s.mgd_percent.map_or("-".to_string(), |m| {
            format!("{:+.1} / {:.1} / {:.1}", m.bias, m.sd, m.max_abs)
        });
        println!(
            "| {} | {:+.2} / {:.2} / {:.2} | {:+.2} / {:.2} / {:.2} | {mgd} | {:.3} / {:.3} | {:.3} | {:.3} |",
            skin_variant_name(&o),
            a.bias, a.sd, a.max_abs, b.bias, b.sd, b.max_abs,
            f[3][1], f[3][2], f[1][3], f[2][3]
        );
        out.push(serde_json::json!({"name": skin_variant_name(&o), "result": s}));
    }
    write_json(
        &json,
        &serde_json::json!({
            "split": source,
            "reconstructor": reconstructor,
            "noise": noise.name(),
            "geometry": g.describe(),
            "classes": CLASSES,
            "variants": out,
        }),
    )?;
    println!("\nJSON: {}", json.display());
    Ok(())
}

/// `dbt-eval ladder`.
fn run_ladder(args: LadderArgs) -> Result<()> {
    let LadderArgs {
        phantoms,
        split,
        phantom,
        model,
        precision,
        noise,
        mltr_iterations,
        dose_uncertainty,
        bands,
        json,
        runtime,
    } = args;
    use dbt_eval::ladder::{band_table, run_ladder, summarise, summary_table, LadderSetup};
    let m = load_models(Some(&model), &precision, &runtime)?
        .pop()
        .map(|(_, m)| std::sync::Arc::new(m))
        .context("no model loaded")?;
    let classify = dbt_tissue::ClassifyOptions::default();
    let settings = dbt_model::load_settings(&m, &classify, dbt_model::InputCorrections::default())?;
    let population = split.population;
    let split = split.resolve(Some(&m))?;
    let g = m.geometry().clone();
    let setup = LadderSetup {
        opts: dbt_pipeline::PipelineOptions {
            classify,
            ..Default::default()
        }
        .with_model(m, settings, None)?,
        noise: NoiseLevel::parse(&noise)?,
        mltr_iterations: (mltr_iterations > 0).then_some(mltr_iterations),
        dose_uncertainty: (dose_uncertainty > 0.0).then_some(dose_uncertainty),
        seed: 1,
    };
    let reconstructor = dbt_pipeline::reconstructor_name(&setup.opts);
    let t0 = Instant::now();
    let inputs = phantom_inputs(phantom.as_deref(), &g, split, population, phantoms);
    let bar = Progress::new(inputs.len() as u64, "ladder", "phantoms", false);
    let mut cases = Vec::new();
    for (k, item) in inputs.into_iter().enumerate() {
        let (name, vol) = item?;
        bar.message(name.clone());
        let setup = LadderSetup {
            seed: 1000 + k as u64,
            ..setup.clone()
        };
        let c = run_ladder(&name, &vol, &g, &setup)?;
        let mut line = format!(
            "{name}: T {:.1} mm, G true {:.3}, fill {:.3}; reported - truth (pp):",
            c.thickness_mm, c.g_true, c.fill
        );
        for r in &c.rungs {
            line += &format!(" {} {:+.1}", r.name, 100.0 * (r.g_reported - c.g_true));
        }
        bar.inc(1);
        bar.line(line);
        if bands {
            type Pick = fn(&dbt_eval::ladder::Rung) -> &[dbt_eval::ladder::BandStats];
            let tables: [(&str, Pick); 3] = [
                ("distance from the skin", |r| &r.by_skin_distance),
                ("height above the support", |r| &r.by_height),
                ("distance from the chest wall", |r| &r.by_chest_wall),
            ];
            for (what, pick) in tables {
                let rows: Vec<_> = c
                    .rungs
                    .iter()
                    .skip(1)
                    .map(|r| (r.name.as_str(), pick(r)))
                    .collect();
                bar.line(band_table(&format!("{name}: {what}"), &rows));
            }
        }
        cases.push(c);
    }
    bar.finish();
    let source = match &phantom {
        Some(p) => p.display().to_string(),
        None => format!(
            "{} {population} phantoms of the {} split",
            cases.len(),
            split.describe()
        ),
    };
    let summary = summarise(&cases);
    println!(
        "Ladder on {source}, {reconstructor}, noisy rung {} ({:.0} s); errors against the truth, bias +- sd\n",
        setup.noise.name(),
        t0.elapsed().as_secs_f64()
    );
    print!("{}", summary_table(&summary));
    write_json(
        &json,
        &serde_json::json!({
            "phantoms": source,
            "reconstructor": reconstructor,
            "geometry": g.describe(),
            "noise": setup.noise.name(),
            "summary": summary,
            "cases": cases,
        }),
    )?;
    println!("\nJSON: {}", json.display());
    Ok(())
}

/// `dbt-eval calibrate`.
fn run_calibrate(args: CalibrateArgs) -> Result<()> {
    let CalibrateArgs {
        model,
        precision,
        phantoms,
        train_seed,
        population,
        noise,
        physics,
        out,
        carry_from,
        thickness_term,
        skin,
        runtime,
    } = args;
    use dbt_model::{CalibrationFile, CALIBRATION_FILE};
    if let Some(from) = carry_from {
        return carry_calibration(&model, &from, &precision, out, &runtime);
    }
    let Physics {
        physics,
        linearise,
        descatter,
        noise_match,
        scatter_in_input,
        input,
        beam,
    } = physics.resolve()?;
    let m = load_models(Some(&model), &precision, &runtime)?
        .pop()
        .map(|(_, m)| std::sync::Arc::new(m))
        .context("no model loaded")?;
    check_noise_level(noise_match, m.manifest())?;
    let split = SplitArgs {
        split: "validation".into(),
        train_seed,
        population,
    }
    .resolve(Some(&m))?;
    let g = m.geometry().clone();
    let noise = NoiseLevel::parse(&noise)?;
    let classify = match skin {
        Some(v) => parse_skin_variant(&v)?,
        None => dbt_tissue::ClassifyOptions::default(),
    };
    // The model without its settings (`PipelineOptions::with_model` is the
    // product's assembly): this command fits the calibration.
    let opts = dbt_pipeline::PipelineOptions {
        dbtor: Some(m.clone()),
        classify,
        linearise,
        descatter,
        noise_match,
        scatter_in_input,
        ..Default::default()
    };
    let t0 = Instant::now();
    let mut cases = Vec::new();
    let bar = Progress::new(phantoms as u64, "calibrate", "phantoms", false);
    for (k, item) in dbt_eval::accuracy::split_phantoms(&g, split, population, phantoms).enumerate()
    {
        let (name, vol) = item?;
        bar.message(name.clone());
        let c = dbt_eval::classification::run_phantom(
            &name,
            &vol,
            &g,
            noise,
            physics,
            beam,
            &opts,
            &[classify],
            None,
            1000 + k as u64,
        )?
        .pop()
        .context("no case")?;
        bar.inc(1);
        bar.line(format!(
            "{name}: T {:.1} mm, G true {:.4}, partial volume {:.4}",
            c.thickness_mm, c.g_true, c.g_partial_volume
        ));
        cases.push(c);
    }
    bar.finish();
    let (est, truth): (Vec<f64>, Vec<f64>) =
        cases.iter().map(|c| (c.g_partial_volume, c.g_true)).unzip();
    let thick: Vec<f64> = cases.iter().map(|c| c.thickness_mm).collect();
    let fit = |idx: &[usize]| {
        let pick = |v: &[f64]| idx.iter().map(|&i| v[i]).collect::<Vec<_>>();
        if thickness_term {
            dbt_tissue::GlandularityCalibration::fit_with_thickness(
                &pick(&est),
                &pick(&truth),
                &pick(&thick),
            )
        } else {
            dbt_tissue::GlandularityCalibration::fit(&pick(&est), &pick(&truth))
        }
    };
    let all: Vec<usize> = (0..cases.len()).collect();
    let cal = fit(&all)?;
    let pp = |f: &dyn Fn(usize) -> f64| {
        dbt_eval::accuracy::agreement(
            &all.iter()
                .map(|&i| 100.0 * (f(i) - truth[i]))
                .collect::<Vec<_>>(),
        )
    };
    let (before, after) = (pp(&|i| est[i]), pp(&|i| cal.apply(est[i], thick[i])));
    // Leave-one-out: each phantom read with the calibration fit on the
    // others (what a phantom outside the fit can expect, the parameters'
    // own overfit counted).
    let loo: Vec<f64> = all
        .iter()
        .map(|&i| {
            let rest: Vec<usize> = all.iter().copied().filter(|&j| j != i).collect();
            Ok(100.0 * (fit(&rest)?.apply(est[i], thick[i]) - truth[i]))
        })
        .collect::<Result<_>>()?;
    let loo_rms = (loo.iter().map(|e| e * e).sum::<f64>() / loo.len() as f64).sqrt();
    let loo_max = loo.iter().fold(0.0f64, |a, e| a.max(e.abs()));
    // The paper's W/Rh beam under the corrections' key; another beam's
    // calibration under its own (`| beam W/Al`), read for that beam's
    // acquisitions only.
    let label = match beam {
        dbt_dose::xray::AnodeFilter::WRh => input.key(&m.precision_label()),
        b => input.beam_key(&m.precision_label(), b.name()),
    };
    println!(
        "Calibration of {} ({label}) on {phantoms} phantoms of the {} split, {}, {} physics ({:.0} s): G = {:+.5} + {:.5} x partial volume{}",
        m.manifest().name,
        split.describe(),
        noise.name(),
        physics.name(),
        t0.elapsed().as_secs_f64(),
        cal.offset,
        cal.slope,
        if thickness_term {
            format!(" {:+.6} x (T - 50 mm)", cal.per_mm)
        } else {
            String::new()
        }
    );
    println!(
        "  on these phantoms: error before bias {:+.2} sd {:.2} max {:.2} pp; after bias {:+.2} sd {:.2} max {:.2} pp; leave-one-out rms {loo_rms:.3} max {loo_max:.2} pp",
        before.bias, before.sd, before.max_abs, after.bias, after.sd, after.max_abs
    );
    let path = out.unwrap_or_else(|| model.join(CALIBRATION_FILE));
    // Keep the other precisions' entries of a file fit for this model
    // and classification; start afresh otherwise.
    let mut file = CalibrationFile::open_or_new(&path, &m, classify)?;
    let removed = file.insert_fit(
        &label,
        cal,
        serde_json::json!({
            "command": std::env::args().collect::<Vec<_>>().join(" "),
            "split": split.describe(),
            "population": population.name(),
            "phantoms": phantoms,
            "noise": noise.name(),
            "physics": physics.name(),
            "anode_filter": beam.name(),
            "input_corrections": input.describe(),
            "estimator": "partial volume",
            "error_before_pp": before,
            "error_after_pp": after,
            "thickness_term": thickness_term,
            "error_loo_pp": { "rms": loo_rms, "max_abs": loo_max, "n": loo.len() },
            "cases": cases.iter().map(|c| serde_json::json!({
                "phantom": c.phantom, "thickness_mm": c.thickness_mm,
                "g_true": c.g_true, "g_partial_volume": c.g_partial_volume,
            })).collect::<Vec<_>>(),
        }),
    );
    write_json(&path, &file)?;
    println!("wrote {}", path.display());
    for k in removed {
        println!("removed {k:?}: a copy of the entry refit here, its bar run against the old figures (run `dbt-eval beam-bar` again)");
    }
    Ok(())
}

/// `dbt-eval calibrate --carry-from OLD`: copy `precision`'s entries of
/// OLD's calibration file into `model`'s, after checking that the two
/// folders run the same network in that precision (the same geometry,
/// normalisation and block files), so that the fits OLD's commands made
/// hold for `model` as they stand.
fn carry_calibration(
    model: &Path,
    from: &Path,
    precision: &str,
    out: Option<PathBuf>,
    runtime: &Runtime,
) -> Result<()> {
    use dbt_model::{CalibrationFile, CALIBRATION_FILE};
    if precision != "fp32" && precision != "int8" {
        bail!("--carry-from carries fp32 or int8 calibrations, not {precision:?}");
    }
    let load = |dir: &Path| -> Result<dbt_dbtor::Dbtor> {
        load_models(Some(dir), precision, runtime)?
            .pop()
            .map(|(_, m)| m)
            .with_context(|| format!("no model loaded from {}", dir.display()))
    };
    let (new, old) = (load(model)?, load(from)?);
    let (nm, om) = (new.manifest(), old.manifest());
    if nm.geometry != om.geometry || nm.normalisation != om.normalisation || nm.kind != om.kind {
        bail!(
            "{} and {} differ in geometry, normalisation or kind: their {precision} calibrations are not interchangeable",
            model.display(),
            from.display()
        );
    }
    if nm.blocks.len() != om.blocks.len() {
        bail!(
            "{} has {} blocks, {} has {}",
            model.display(),
            nm.blocks.len(),
            from.display(),
            om.blocks.len()
        );
    }
    for (a, b) in nm.blocks.iter().zip(&om.blocks) {
        let (fa, fb) = if precision == "fp32" {
            (&a.fp32, &b.fp32)
        } else {
            (&a.int8, &b.int8)
        };
        let (ha, hb) = (nm.sha256.get(fa), om.sha256.get(fb));
        if ha.is_none() || ha != hb {
            let hex = |h: Option<&String>| h.map_or("none".to_string(), |h| h.clone());
            bail!(
                "{precision} block {fa} of {} is not {fb} of {} (SHA-256 {} against {}): fit the calibration instead",
                model.display(),
                from.display(),
                hex(ha),
                hex(hb)
            );
        }
    }
    let old_file = CalibrationFile::read(&from.join(CALIBRATION_FILE), &old)?;
    let path = out.unwrap_or_else(|| model.join(CALIBRATION_FILE));
    let mut file = CalibrationFile::open_or_new(&path, &new, old_file.classification)?;
    let keys: Vec<&String> = old_file
        .calibrations
        .keys()
        .filter(|k| k.as_str() == precision || k.starts_with(&format!("{precision} | ")))
        .collect();
    if keys.is_empty() {
        bail!(
            "{} has no {precision} calibration to carry",
            from.join(CALIBRATION_FILE).display()
        );
    }
    for k in keys {
        let cal = old_file.calibrations[k];
        let fit = old_file.fits.get(k);
        let mut record = serde_json::json!({
            "carried_from": {
                "model": om.name,
                "manifest_sha256": old_file.manifest_sha256,
                "why": format!("the same {precision} blocks (SHA-256 checked), geometry and normalisation"),
                "command": std::env::args().collect::<Vec<_>>().join(" "),
            },
            "fit": fit,
        });
        // A beam's copy of a W/Rh entry stays marked as one.
        if let Some(kept) = fit.and_then(|f| f.get(dbt_model::KEPT_FROM_FIELD)) {
            record[dbt_model::KEPT_FROM_FIELD] = kept.clone();
        }
        file.insert_fit(k, cal, record);
        println!(
            "carried {k}: G = {:+.5} + {:.5} x partial volume (from {})",
            cal.offset, cal.slope, om.name
        );
    }
    write_json(&path, &file)?;
    println!("wrote {}", path.display());
    Ok(())
}

/// `dbt-eval anatomy`.
fn run_anatomy(args: AnatomyArgs) -> Result<()> {
    let AnatomyArgs {
        out,
        population,
        seed,
        index,
        external,
        voxel_mm,
    } = args;
    anatomy_cmd(&out, population, seed, &index, &external, voxel_mm)?;
    Ok(())
}

/// `dbt-eval picture`.
fn run_picture(args: PictureArgs) -> Result<()> {
    let PictureArgs {
        out,
        binning,
        phantom,
        noise,
        model,
    } = args;
    let model = load_models(model.as_deref(), "fp32", &Runtime::default())?
        .pop()
        .map(|(_, m)| m);
    let g = match &model {
        Some(m) => m.geometry().clone(),
        None => Geometry::paper().binned(binning)?,
    };
    let proj = Projector::new(&g);
    let level = NoiseLevel::parse(&noise)?;
    let (set, _) = test_set(&g, &proj, phantom + 1, 1, &[level])?;
    let (_, s) = set.last().context("the test phantom has no slices")?;
    let (m, _) = mltr(
        &proj,
        &s.counts[0],
        s.flux[0],
        &s.mask,
        &MltrOptions::default(),
    )?;
    let line = dbt_forward::log_transform(&s.counts[0], s.flux[0]);
    let f = Fbp::new(&g).reconstruct(&line, Some(&s.mask))?;
    let (rows, cols) = (g.image.rows, g.image.columns);
    let mu_window = (0.0, 0.0854 * 1.05);
    let mut panels = vec![
        Panel {
            data: s.mu.clone(),
            rows,
            cols,
            window: mu_window,
            stretch: 1,
            label: format!("phantom, slice {} (0 to 0.09 /mm)", s.depth),
        },
        Panel {
            window: auto_window(&line),
            data: line,
            rows: g.n_views(),
            cols: g.n_det(),
            stretch: (rows / g.n_views()).max(1),
            label: format!(
                "sinogram, {}: views top to bottom, detector left to right",
                level.name()
            ),
        },
        Panel {
            data: m,
            rows,
            cols,
            window: mu_window,
            stretch: 1,
            label: "MLTR, 100 iterations (the phantom's window)".into(),
        },
        Panel {
            window: auto_window(&f),
            data: f,
            rows,
            cols,
            stretch: 1,
            label: "FBP (its own window)".into(),
        },
    ];
    let mut legend = String::from(
        "phantom (0..0.09 /mm), sinogram, MLTR 100 it. (same window), FBP (own window)",
    );
    if let Some(m) = &model {
        let x = m.reconstruct(
            &dbt_forward::log_transform(&s.counts[0], s.flux[0]),
            s.thickness_mm,
        )?;
        let diff: Vec<f32> = x.iter().zip(&s.mu).map(|(a, b)| a - b).collect();
        panels.push(Panel {
            data: x,
            rows,
            cols,
            window: mu_window,
            stretch: 1,
            label: "DBToR fp32 (the phantom's window)".into(),
        });
        panels.push(Panel {
            data: diff,
            rows,
            cols,
            window: (-0.02, 0.02),
            stretch: 1,
            label: "DBToR - phantom (-0.02 to 0.02 /mm)".into(),
        });
        legend.push_str(", DBToR fp32 (same window), DBToR - phantom (-0.02..0.02 /mm)");
    }
    let (px, w, h) = compose(&panels)?;
    write_png(&out, &px, w, h)?;
    println!(
        "{}: test phantom {phantom}, slice {}, {}; panels top to bottom: {legend}",
        out.display(),
        s.depth,
        level.name()
    );
    Ok(())
}

/// One phantom of `dbt-eval paired`: name, thickness, glandularity and MGD
/// differences (compared - reference), the compared run's errors.
type Row = (String, f64, f64, f64, f64, f64);

/// `dbt-eval paired`.
fn run_paired(args: PairedArgs) -> Result<()> {
    let read = |p: &Path| -> Result<serde_json::Value> {
        let text =
            std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
        serde_json::from_str(&text).with_context(|| format!("parsing {}", p.display()))
    };
    let (a, b) = (read(&args.reference)?, read(&args.compared)?);
    let cases = |v: &serde_json::Value, which: &Path| -> Result<Vec<serde_json::Value>> {
        v["reconstructors"][0]["cases"]
            .as_array()
            .cloned()
            .with_context(|| format!("{}: no cases", which.display()))
    };
    let (ca, cb) = (cases(&a, &args.reference)?, cases(&b, &args.compared)?);
    let model = |v: &serde_json::Value| {
        network_of(
            v["reconstructors"][0]["reconstructor"]
                .as_str()
                .unwrap_or_default(),
        )
    };
    anyhow::ensure!(
        model(&a) == model(&b),
        "the two runs used different reconstructors: {} and {}",
        model(&a),
        model(&b)
    );
    let num = |c: &serde_json::Value, k: &str| -> Result<f64> {
        c[k].as_f64().with_context(|| format!("case without {k}"))
    };
    let pairs = matched_cases(&ca, &cb)
        .map_err(|name| anyhow::anyhow!("phantom {name} is not in {}", args.compared.display()))?;
    let mut rows: Vec<Row> = Vec::new();
    for &(x, y) in &pairs {
        let name = x["phantom"].as_str().unwrap_or_default();
        let dg = 100.0 * (num(y, "g_reported")? - num(x, "g_reported")?);
        let dm = 100.0 * (num(y, "mgd_est")? / num(x, "mgd_est")? - 1.0);
        let eg = 100.0 * (num(y, "g_reported")? - num(y, "g_true")?);
        let em = 100.0 * (num(y, "mgd_est")? / num(y, "mgd_true")? - 1.0);
        rows.push((name.to_string(), num(y, "thickness_mm")?, dg, dm, eg, em));
    }
    anyhow::ensure!(!rows.is_empty(), "no case to compare");
    let stat = |f: &dyn Fn(&Row) -> f64| {
        let v: Vec<f64> = rows.iter().map(f).collect();
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
        let max = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        (mean, sd, max)
    };
    println!(
        "{} cases: {} against {}",
        rows.len(),
        args.compared.display(),
        args.reference.display()
    );
    println!("| quantity | mean | sd | max abs |\n|---|---|---|---|");
    let table = [
        (
            "glandularity reported, compared - reference (pp)",
            stat(&|r| r.2),
        ),
        ("MGD, compared / reference - 1 (%)", stat(&|r| r.3)),
        (
            "glandularity reported, compared - truth (pp)",
            stat(&|r| r.4),
        ),
        ("MGD, compared / truth - 1 (%)", stat(&|r| r.5)),
    ];
    for (q, (m, s, x)) in &table {
        println!("| {q} | {m:+.2} | {s:.2} | {x:.2} |");
    }
    // The error by depth from the chest wall (runs that recorded it).
    // Per band: its range (mm) and each case's (reference, compared) error.
    type Band = (f64, f64, Vec<(f64, f64)>);
    let mut bands: Vec<Band> = Vec::new();
    for &(x, y) in &pairs {
        let empty = Vec::new();
        let (bx, by) = (
            x["by_depth"].as_array().unwrap_or(&empty),
            y["by_depth"].as_array().unwrap_or(&empty),
        );
        for (k, (p, q)) in bx.iter().zip(by).enumerate() {
            let f = |v: &serde_json::Value, key: &str| v[key].as_f64();
            if let (Some(tp), Some(rp), Some(tq), Some(rq), Some(a), Some(b)) = (
                f(p, "g_true"),
                f(p, "g_recon"),
                f(q, "g_true"),
                f(q, "g_recon"),
                f(p, "from_mm"),
                f(p, "to_mm"),
            ) {
                if bands.len() <= k {
                    bands.resize(k + 1, (0.0, 0.0, Vec::new()));
                }
                bands[k].0 = a;
                bands[k].1 = b;
                bands[k].2.push((100.0 * (rp - tp), 100.0 * (rq - tq)));
            }
        }
    }
    let depth: Vec<serde_json::Value> = bands
        .iter()
        .filter(|b| !b.2.is_empty())
        .map(|(a, b, v)| {
            let n = v.len() as f64;
            let mean = |f: &dyn Fn(&(f64, f64)) -> f64| v.iter().map(f).sum::<f64>() / n;
            let max = v.iter().fold(0.0f64, |m, d| m.max((d.1 - d.0).abs()));
            serde_json::json!({"from_mm": a, "to_mm": b, "n": v.len(),
                "reference_error_pp": mean(&|d| d.0), "compared_error_pp": mean(&|d| d.1),
                "difference_pp": mean(&|d| d.1 - d.0), "max_abs_difference_pp": max})
        })
        .collect();
    if !depth.is_empty() {
        println!("\nFibroglandular volume fraction by depth from the chest wall, classified reconstruction - truth (pp):");
        println!("| depth (mm) | cases | reference | compared | compared - reference | max abs |\n|---|---|---|---|---|---|");
        for d in &depth {
            let f = |k: &str| d[k].as_f64().unwrap_or(f64::NAN);
            println!(
                "| {:.0}-{:.0} | {} | {:+.2} | {:+.2} | {:+.2} | {:.2} |",
                f("from_mm"),
                f("to_mm"),
                d["n"],
                f("reference_error_pp"),
                f("compared_error_pp"),
                f("difference_pp"),
                f("max_abs_difference_pp")
            );
        }
    }
    // The fibroglandular volume by height above the support (runs that
    // recorded it): per band, the mean over the cases of reconstruction -
    // truth, cm^3, in each run.
    let height = height_bands(&pairs);
    if !height.is_empty() {
        println!("\nFibroglandular volume by height above the support, classified reconstruction - truth (cm^3, mean over the cases):");
        println!("| height (mm) | cases | reference | compared |\n|---|---|---|---|");
        for h in &height {
            println!(
                "| {:.0}-{:.0} | {} | {:+.2} | {:+.2} |",
                h.0, h.1, h.2, h.3, h.4
            );
        }
    }
    let surface = surface_bands(&pairs);
    for (bands, at) in surface
        .iter()
        .zip(["above the support", "under the paddle"])
    {
        if !bands.is_empty() {
            println!("\nFibroglandular volume by voxel layer {at}, classified reconstruction - truth (cm^3, mean over the cases):");
            println!("| layer | cases | reference | compared |\n|---|---|---|---|");
            for (k, h) in bands.iter().enumerate() {
                println!("| {} | {} | {:+.3} | {:+.3} |", k + 1, h.2, h.3, h.4);
            }
        }
    }
    if let Some(k) = args.case {
        let &(x, y) = pairs
            .get(k)
            .with_context(|| format!("--case {k}: the reference run has {} cases", ca.len()))?;
        let name = x["phantom"].as_str().unwrap_or_default();
        let empty = Vec::new();
        let (bx, by) = (
            x["by_height"].as_array().unwrap_or(&empty),
            y["by_height"].as_array().unwrap_or(&empty),
        );
        anyhow::ensure!(
            !bx.is_empty() && bx.len() == by.len(),
            "case {k} ({name}): no fibroglandular volume by height in both runs (accuracy.json before it was recorded?)"
        );
        let f = |v: &serde_json::Value, key: &str| v[key].as_f64().unwrap_or(f64::NAN);
        println!(
            "\n{name}, {:.1} mm, {:.1} % glandular: fibroglandular volume by height above the support (cm^3)",
            f(x, "thickness_mm"),
            100.0 * f(x, "g_true")
        );
        println!("| height (mm) | truth | reference | compared |\n|---|---|---|---|");
        let mut sums = [0.0f64; 3];
        for (p, q) in bx.iter().zip(by) {
            if f(p, "tissue_true_cm3") > 0.0 || f(p, "tissue_recon_cm3") > 0.0 {
                let v = [
                    f(p, "gland_true_cm3"),
                    f(p, "gland_recon_cm3"),
                    f(q, "gland_recon_cm3"),
                ];
                for (s, v) in sums.iter_mut().zip(v) {
                    *s += v;
                }
                println!(
                    "| {:.0}-{:.0} | {:.1} | {:.1} | {:.1} |",
                    f(p, "from_mm"),
                    f(p, "to_mm"),
                    v[0],
                    v[1],
                    v[2]
                );
            }
        }
        println!("| all | {:.1} | {:.1} | {:.1} |", sums[0], sums[1], sums[2]);
        for at in ["support", "paddle"] {
            let (Some(sx), Some(sy)) = (
                x["by_surface"][at].as_array(),
                y["by_surface"][at].as_array(),
            ) else {
                continue;
            };
            println!("\n{name}: fibroglandular volume by voxel layer at the {at} (cm^3)");
            println!(
                "| layer | height (mm) | truth | reference | compared |\n|---|---|---|---|---|"
            );
            for (k, (p, q)) in sx.iter().zip(sy).enumerate() {
                println!(
                    "| {} | {:.1}-{:.1} | {:.3} | {:.3} | {:.3} |",
                    k + 1,
                    f(p, "from_mm"),
                    f(p, "to_mm"),
                    f(p, "gland_true_cm3"),
                    f(p, "gland_recon_cm3"),
                    f(q, "gland_recon_cm3")
                );
            }
        }
        for (run, c) in [("reference", x), ("compared", y)] {
            println!(
                "{run}: glandularity by labels {:+.2} pp, patient MGD {:+.1} % against the truth",
                100.0 * (f(c, "g_labels") - f(c, "g_true")),
                100.0 * (f(c, "mgd_est") / f(c, "mgd_true") - 1.0)
            );
        }
    }
    if let Some(out) = args.out {
        let json = serde_json::json!({
            "by_height": height.iter().map(|h| serde_json::json!({"from_mm": h.0, "to_mm": h.1, "n": h.2, "reference_excess_cm3": h.3, "compared_excess_cm3": h.4})).collect::<Vec<_>>(),
            "by_surface": {
                "support": surface[0].iter().enumerate().map(|(k, h)| serde_json::json!({"layer": k + 1, "n": h.2, "reference_excess_cm3": h.3, "compared_excess_cm3": h.4})).collect::<Vec<_>>(),
                "paddle": surface[1].iter().enumerate().map(|(k, h)| serde_json::json!({"layer": k + 1, "n": h.2, "reference_excess_cm3": h.3, "compared_excess_cm3": h.4})).collect::<Vec<_>>(),
            },
            "by_depth": depth,
            "reference": args.reference.display().to_string(),
            "compared": args.compared.display().to_string(),
            "table": table.iter().map(|(q, (m, s, x))| serde_json::json!({"quantity": q, "mean": m, "sd": s, "max_abs": x})).collect::<Vec<_>>(),
            "cases": rows.iter().map(|r| serde_json::json!({"phantom": r.0, "thickness_mm": r.1, "dg_pp": r.2, "dmgd_pct": r.3, "g_error_pp": r.4, "mgd_error_pct": r.5})).collect::<Vec<_>>(),
        });
        write_json(&out, &json)?;
    }
    Ok(())
}

/// The network and precision of an `accuracy` run's reconstructor name,
/// which `paired` requires the same in both runs: the calibration (the
/// bracket after the name) may differ, as with and without noise matching,
/// or be absent from one (a classification other than the calibration's).
fn network_of(reconstructor: &str) -> String {
    reconstructor
        .split(" [")
        .next()
        .unwrap_or_default()
        .replace(", calibrated)", ")")
}

/// Each reference case (in its order) with the compared run's case of the
/// same phantom; `Err` names the first phantom the compared run lacks.
fn matched_cases<'a>(
    ca: &'a [serde_json::Value],
    cb: &'a [serde_json::Value],
) -> Result<Vec<(&'a serde_json::Value, &'a serde_json::Value)>, String> {
    ca.iter()
        .map(|x| {
            let name = x["phantom"].as_str().unwrap_or_default();
            cb.iter()
                .find(|y| y["phantom"].as_str() == Some(name))
                .map(|y| (x, y))
                .ok_or_else(|| name.to_string())
        })
        .collect()
}

/// One band's mean excess over matched cases: `(from_mm, to_mm, cases,
/// reference, compared)` ([`mean_excess`]).
type Excess = (f64, f64, usize, f64, f64);

/// Per height band of matched cases (cases without `by_height` left out):
/// `(from_mm, to_mm, cases, reference, compared)`, the last two the mean
/// over the cases of the reconstruction's fibroglandular volume less the
/// truth's, cm^3.
fn height_bands(pairs: &[(&serde_json::Value, &serde_json::Value)]) -> Vec<Excess> {
    mean_excess(pairs, |c| c["by_height"].as_array())
}

/// Per voxel layer at the support and under the paddle (`by_surface`;
/// cases without it left out), as [`height_bands`]: layer `k` is the `k`-th
/// from its surface in every case (its heights, the first case's, differ
/// with the thickness under the paddle).
fn surface_bands(pairs: &[(&serde_json::Value, &serde_json::Value)]) -> [Vec<Excess>; 2] {
    [
        mean_excess(pairs, |c| c["by_surface"]["support"].as_array()),
        mean_excess(pairs, |c| c["by_surface"]["paddle"].as_array()),
    ]
}

/// The mean over matched cases, band by band of the array `bands_of` selects
/// in each case, of the reconstruction's fibroglandular volume less the
/// truth's: `(from_mm, to_mm, cases, reference, compared)`.
fn mean_excess(
    pairs: &[(&serde_json::Value, &serde_json::Value)],
    bands_of: fn(&serde_json::Value) -> Option<&Vec<serde_json::Value>>,
) -> Vec<Excess> {
    let mut bands: Vec<Excess> = Vec::new();
    for &(x, y) in pairs {
        let (Some(bx), Some(by)) = (bands_of(x), bands_of(y)) else {
            continue;
        };
        for (k, (p, q)) in bx.iter().zip(by).enumerate() {
            let f = |v: &serde_json::Value, key: &str| v[key].as_f64();
            if let (Some(a), Some(b), Some(tp), Some(rp), Some(tq), Some(rq)) = (
                f(p, "from_mm"),
                f(p, "to_mm"),
                f(p, "gland_true_cm3"),
                f(p, "gland_recon_cm3"),
                f(q, "gland_true_cm3"),
                f(q, "gland_recon_cm3"),
            ) {
                if bands.len() <= k {
                    bands.resize(k + 1, (0.0, 0.0, 0, 0.0, 0.0));
                }
                let band = &mut bands[k];
                if band.2 == 0 {
                    (band.0, band.1) = (a, b);
                }
                band.2 += 1;
                band.3 += rp - tp;
                band.4 += rq - tq;
            }
        }
    }
    bands
        .into_iter()
        .filter(|b| b.2 > 0)
        .map(|(a, b, n, r, c)| (a, b, n, r / n as f64, c / n as f64))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use dbt_tissue::{ClassifyOptions, SkinRule};

    /// The height bands average each band's excess over the matched cases;
    /// a case without bands is left out; the matching pairs each reference
    /// case with its phantom's in the other run and names one it lacks.
    #[test]
    fn height_bands_average_the_matched_cases() {
        let case = |name: &str, bands: &[(f64, f64)]| {
            serde_json::json!({"phantom": name, "by_height": bands.iter().enumerate().map(|(k, (t, r))| serde_json::json!({
                "from_mm": 10.0 * k as f64, "to_mm": 10.0 * (k + 1) as f64,
                "gland_true_cm3": t, "gland_recon_cm3": r})).collect::<Vec<_>>()})
        };
        let a = [
            case("p0", &[(1.0, 2.0), (3.0, 3.0)]),
            case("p1", &[(1.0, 4.0)]),
            case("p2", &[(1.0, 9.0)]),
            serde_json::json!({"phantom": "p3"}),
        ];
        let b = [
            case("p1", &[(1.0, 1.0)]),
            case("p0", &[(1.0, 1.0), (3.0, 5.0)]),
            serde_json::json!({"phantom": "p3"}),
        ];
        assert_eq!(matched_cases(&a, &b).unwrap_err(), "p2");
        let (a, b) = ([&a[..2], &a[3..]].concat(), b);
        let pairs = matched_cases(&a, &b).unwrap();
        assert_eq!(pairs.len(), 3);
        assert_eq!(pairs[0].1["phantom"], "p0");
        let h = height_bands(&pairs);
        assert_eq!(h, vec![(0.0, 10.0, 2, 2.0, 0.0), (10.0, 20.0, 1, 0.0, 2.0)]);
        assert!(height_bands(&[]).is_empty());
        // The surface layers, by their count from each surface whatever
        // their heights.
        let layered = |name: &str, paddle: &[(f64, f64, f64)]| {
            serde_json::json!({"phantom": name, "by_surface": {"support": [], "paddle": paddle.iter().map(|(from, t, r)| serde_json::json!({
                "from_mm": from, "to_mm": from + 0.8, "gland_true_cm3": t, "gland_recon_cm3": r})).collect::<Vec<_>>()}})
        };
        let a = [
            layered("p0", &[(40.0, 0.5, 1.5), (39.2, 1.0, 1.0)]),
            layered("p1", &[(70.4, 0.0, 0.5)]),
        ];
        let b = [
            layered("p0", &[(40.0, 0.5, 0.5), (39.2, 1.0, 2.0)]),
            layered("p1", &[(70.4, 0.0, 0.0)]),
        ];
        let pairs = matched_cases(&a, &b).unwrap();
        let [support, paddle] = surface_bands(&pairs);
        assert!(support.is_empty());
        assert_eq!(
            paddle,
            vec![(40.0, 40.8, 2, 0.75, 0.0), (39.2, 40.0, 1, 0.0, 1.0)]
        );
    }

    /// Runs of one network compare whatever their calibrations; another
    /// network or precision does not.
    #[test]
    fn paired_runs_are_one_network_whatever_the_calibration() {
        let cal = "DBToR m (int8, fast, calibrated) [G = -0.0257 + 1.0475 x PV]";
        let other = "DBToR m (int8, fast, calibrated) [G = -0.04 + 1.07 x PV]";
        let none = "DBToR m (int8, fast)";
        assert_eq!(network_of(cal), network_of(other));
        assert_eq!(network_of(cal), network_of(none));
        assert_ne!(network_of(cal), network_of("DBToR m (fp32, fast)"));
        assert_ne!(network_of(none), network_of("DBToR n (int8, fast)"));
    }

    /// Every skin variant's spelling reads as the rule it names, the fat
    /// band only under a bounded skin, and a bad one is refused naming it.
    #[test]
    fn skin_variants_parse_and_name_themselves() {
        let d = ClassifyOptions::default();
        assert_eq!(parse_skin_variant("shell:1.6").unwrap(), d);
        assert_eq!(skin_variant_name(&d), "shell 1.6 mm");
        let band = parse_skin_variant("shell:1.6+fat:0.8").unwrap();
        assert_eq!(
            band,
            ClassifyOptions {
                fat_band_mm: Some(0.8),
                ..d
            }
        );
        assert_eq!(skin_variant_name(&band), "shell 1.6 mm + fat band 0.8 mm");
        let grow = parse_skin_variant("2.4+fat:1.6").unwrap();
        assert_eq!(
            (grow.skin_rule, grow.skin_max_mm, grow.fat_band_mm),
            (SkinRule::Grow, Some(2.4), Some(1.6))
        );
        assert_eq!(parse_skin_variant("none").unwrap().skin_max_mm, None);
        for bad in [
            "none+fat:0.8",
            "shell:1.6+fat:0",
            "shell:1.6+fat:-1",
            "shell:1.6+fat:x",
            "shell:0",
            "fat:0.8",
        ] {
            let e = parse_skin_variant(bad).unwrap_err().to_string();
            assert!(e.contains(bad), "{bad}: {e}");
        }
    }
}
