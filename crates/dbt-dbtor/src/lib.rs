//! The DBToR runtime: a trained model folder (`models/<name>/`, written by
//! `training/dbtor/export.py`) is loaded, every file's SHA-256 is checked
//! against the manifest, the 2 x N blocks are loaded with tract-onnx, and the
//! unrolled primal-dual loop of the paper's Algorithm 1 runs with the Rust
//! projector.
//!
//! Conventions (written down in `training/dbtor/model.py` and in each model's
//! manifest): 5 state channels in both spaces, initialised to zero; the dual
//! block `i` sees `[h, P(f[1]), g_n, P(m)]`, the primal block `[f, P*(h[0]), m]`;
//! every block file computes `state + net(cat(state, aux))`; the network's
//! operator is `P / ||P||`; `g_n = (g - g_mean) / g_std`; the output is
//! `f[0] * x_scale` in 1/mm.

mod fast;
mod fixtures;
mod manifest;

/// The fast engine's kernels (re-exported for the benchmarks and diagnostics).
pub use dbt_conv::Kernel;
pub use fixtures::{check_fixtures, FixtureCheck, FP32_TOL_NETWORK_UNITS};

pub use manifest::{
    sha256_file, verify_checksums, BlockEntry, Fixture, ModelManifest, Normalisation, Role,
    TrainingInput, FORMAT, UNCORRECTED_CLINICAL_COUNTS,
};

use dbt_conv::{Fp32Block, Fp32Workspace, Int8Block, Int8Workspace};
use dbt_geometry::Geometry;
use dbt_projector::Projector;
use std::path::{Path, PathBuf};
use tract_onnx::prelude::*;

/// Errors of the runtime.
#[derive(Debug, thiserror::Error)]
pub enum DbtorError {
    /// A file could not be read.
    #[error("{path}: {cause}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        cause: std::io::Error,
    },
    /// The manifest is malformed or inconsistent.
    #[error("{path}: {reason}")]
    Manifest {
        /// The manifest.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A model file's checksum differs from the manifest.
    #[error("{path}: SHA-256 is {found}, the manifest says {expected}: the file was modified or corrupted; refusing to load the model")]
    Checksum {
        /// The file.
        path: PathBuf,
        /// From the manifest.
        expected: String,
        /// Computed.
        found: String,
    },
    /// tract could not load or run a block.
    #[error("{path}: {reason}")]
    Block {
        /// The block file.
        path: PathBuf,
        /// tract's message.
        reason: String,
    },
    /// The input does not fit the model.
    #[error("input: {0}")]
    Input(String),
}

/// Which version of the blocks to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// The exported fp32 graphs.
    Fp32,
    /// The static int8 (QDQ) graphs.
    Int8,
}

impl std::str::FromStr for Precision {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "fp32" => Ok(Self::Fp32),
            "int8" => Ok(Self::Int8),
            other => Err(format!("unknown precision {other:?} (fp32 or int8)")),
        }
    }
}

impl std::fmt::Display for Precision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Fp32 => "fp32",
            Self::Int8 => "int8",
        })
    }
}

/// Where the time of one slice went ([`Dbtor::profile_slice`]).
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct SliceProfile {
    /// Per block, in execution order (dual 0, primal 0, ...), ms.
    pub block_ms: Vec<f64>,
    /// All projections and backprojections of the slice, ms.
    pub projector_ms: f64,
    /// The whole slice, ms.
    pub total_ms: f64,
}

/// Which executor runs the blocks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Engine {
    /// tract-onnx: any graph; the reference executor.
    Tract,
    /// `dbt-conv`: the fused kernels (AVX-512 FMA / VNNI where the CPU has
    /// them, portable otherwise) on the weights read out of the same files.
    Fast,
}

impl std::str::FromStr for Engine {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "tract" => Ok(Self::Tract),
            "fast" => Ok(Self::Fast),
            other => Err(format!("unknown engine {other:?} (fast or tract)")),
        }
    }
}

impl std::fmt::Display for Engine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Tract => "tract",
            Self::Fast => "fast",
        })
    }
}

type Plan = std::sync::Arc<TypedSimplePlan>;

enum Blocks {
    /// tract plans with the file each was loaded from (for error messages).
    Tract(Vec<(Plan, PathBuf)>),
    /// `dbt-conv` blocks, each in its own precision.
    Fast(Vec<(FastBlock, PathBuf)>),
}

/// One block on the fast engine. (Twenty per model, made once: the size
/// difference of the variants does not matter.)
#[allow(clippy::large_enum_variant)]
enum FastBlock {
    Fp32(Fp32Block),
    Int8(Int8Block),
}

impl FastBlock {
    fn as_fp32(&self) -> Option<&Fp32Block> {
        match self {
            Self::Fp32(k) => Some(k),
            Self::Int8(_) => None,
        }
    }

    fn as_int8(&self) -> Option<&Int8Block> {
        match self {
            Self::Int8(k) => Some(k),
            Self::Fp32(_) => None,
        }
    }
}

/// The fast engine's scratch: per precision, one workspace for the dual
/// blocks and one for the primal blocks (`[dual, primal]`), where blocks of
/// that precision and role exist. (One per buffer set, which is boxed.)
#[allow(clippy::large_enum_variant)]
enum Workspaces {
    None,
    Fast {
        fp32: [Option<Fp32Workspace>; 2],
        int8: [Option<Int8Workspace>; 2],
    },
}

/// Every buffer one slice needs, made on the first slice and reused: after
/// it, the fast engine allocates nothing per slice.
struct Buffers {
    gn: Vec<f32>,
    mask: Vec<f32>,
    pm: Vec<f32>,
    h: Vec<f32>,
    f: Vec<f32>,
    aux_d: Vec<f32>,
    aux_p: Vec<f32>,
    ws: Workspaces,
}

impl Buffers {
    fn bytes(&self) -> usize {
        let floats = [
            &self.gn,
            &self.mask,
            &self.pm,
            &self.h,
            &self.f,
            &self.aux_d,
            &self.aux_p,
        ]
        .iter()
        .map(|v| v.len())
        .sum::<usize>();
        4 * floats
            + match &self.ws {
                Workspaces::None => 0,
                Workspaces::Fast { fp32, int8 } => {
                    fp32.iter().flatten().map(|w| w.bytes()).sum::<usize>()
                        + int8.iter().flatten().map(|w| w.bytes()).sum::<usize>()
                }
            }
    }
}

/// The grid a block of `role` runs on: the sinogram (views x elements) for
/// the dual blocks, the image (rows x columns) for the primal ones.
fn grid(g: &Geometry, role: Role) -> (usize, usize) {
    match role {
        Role::Dual => (g.n_views(), g.n_det()),
        Role::Primal => (g.image.rows, g.image.columns),
    }
}

/// A comma-separated list of block names (`primal08, primal09`) as the
/// command lines and configuration give it: trimmed, empty entries dropped.
/// The names are checked against the model when it is loaded.
pub fn parse_block_list(list: &str) -> Vec<String> {
    list.split(',')
        .map(|b| b.trim().to_string())
        .filter(|b| !b.is_empty())
        .collect()
}

/// A block's name: role and two-digit iteration (`dual00`, `primal09`), as
/// the exporter and `dbtor.int8_sensitivity` name them.
pub fn block_name(b: &BlockEntry) -> String {
    let role = match b.role {
        Role::Dual => "dual",
        Role::Primal => "primal",
    };
    format!("{role}{:02}", b.index)
}

/// The first fast block of `role` that `pick` accepts (all blocks of a role
/// share widths).
fn first_of_role<'a, T>(
    v: &'a [(FastBlock, PathBuf)],
    entries: &[BlockEntry],
    role: Role,
    pick: fn(&'a FastBlock) -> Option<&'a T>,
) -> Option<&'a T> {
    v.iter()
        .zip(entries)
        .filter(|(_, e)| e.role == role)
        .find_map(|(b, _)| pick(&b.0))
}

/// A loaded, verified model ready to reconstruct slices.
pub struct Dbtor {
    manifest: ModelManifest,
    root: PathBuf,
    precision: Precision,
    /// Blocks run in fp32 although `precision` is int8 (mixed precision).
    fp32_blocks: Vec<String>,
    engine: Engine,
    projector: Projector,
    /// In execution order: dual 0, primal 0, dual 1, ...
    blocks: Blocks,
    /// Per-slice buffers kept between slices: one set per slice in flight
    /// (slices reconstructed concurrently each take their own).
    buffers: std::sync::Mutex<Vec<Buffers>>,
    /// Primal blocks run only from this many rows above the breast (fast
    /// engine); `None`: on the whole image.
    crop_margin: Option<usize>,
    /// The physical constraints applied to the network's output.
    constraints: Constraints,
    /// What the kernels' measurement found, one line per precision measured
    /// (empty where a kernel was forced or on the tract engine).
    kernel_measurements: Vec<String>,
}

/// The environment variable that forces the fast engine to the fastest
/// kernel up to a level (`portable`, `avx2`, `avx-vnni`, `avx512`, `amx`),
/// its convolutions and its fused projector (`portable` is the projector's
/// scalar kernel): to test and benchmark every path on a CPU that has a
/// faster one. Unset: the kernels are chosen by measurement on the model's
/// own blocks ([`KernelChoice::Measure`]), AMX among them where the CPU
/// has it.
pub const KERNEL_ENV: &str = "DBTOR_KERNEL";

/// The fastest kernel the fast engine may use: [`KERNEL_ENV`] if set (an
/// unknown name is an error naming it and the choices), else any.
pub fn kernel_limit() -> Result<Kernel, DbtorError> {
    match std::env::var(KERNEL_ENV) {
        Err(_) => Ok(Kernel::Avx512),
        Ok(v) => Kernel::parse(v.trim()).ok_or_else(|| {
            DbtorError::Input(format!(
                "{KERNEL_ENV}={v:?}: expected one of {}",
                Kernel::ALL.map(|k| k.name()).join(", ")
            ))
        }),
    }
}

/// How the fast engine picks its kernels: by measurement on the model's own
/// blocks (the default, issue #52), or the fastest the CPU runs up to a
/// level ([`KERNEL_ENV`], the benchmarks' forced rows).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KernelChoice {
    /// Every configuration the CPU runs checked against the portable kernel
    /// and timed on the model's first block of each precision; the fastest
    /// that agrees runs (`dbt_conv::select`).
    Measure,
    /// The fastest the CPU runs up to this level, by instruction-set rank.
    UpTo(Kernel),
}

impl KernelChoice {
    /// The level the fused projector may use.
    pub fn projector_limit(self) -> dbt_projector::Kernel {
        match self {
            KernelChoice::Measure => dbt_projector::Kernel::Avx512,
            KernelChoice::UpTo(k) => projector_limit(k),
        }
    }
}

/// [`KernelChoice::UpTo`] the level [`KERNEL_ENV`] names where it is set (an
/// unknown name is an error naming it and the choices), else
/// [`KernelChoice::Measure`].
pub fn kernel_choice() -> Result<KernelChoice, DbtorError> {
    match std::env::var(KERNEL_ENV) {
        Err(_) => Ok(KernelChoice::Measure),
        Ok(_) => kernel_limit().map(KernelChoice::UpTo),
    }
}

/// The measured choices of this process, by precision and block shape (the
/// CPU does not change while it runs; a model loaded again is not measured
/// again): the configuration and the measurement's one-line description.
type Measured<C> = std::sync::Mutex<std::collections::HashMap<String, (C, String)>>;
static MEASURED_INT8: std::sync::OnceLock<Measured<dbt_conv::select::Int8Config>> =
    std::sync::OnceLock::new();
static MEASURED_FP32: std::sync::OnceLock<Measured<dbt_conv::select::Fp32Config>> =
    std::sync::OnceLock::new();

/// Rows of the grid a block is measured on (the model's width, so that the
/// kernels' row tiling is the real one; a band of rows, so that the
/// portable reference costs a fraction of a second). The measured block is
/// the first primal one, which holds most of a slice's work: on the first
/// (dual, 16 x 320) block the fp32 AVX2 kernel measured faster than the
/// AVX-512 one, which is 1.5 times as fast over a whole slice
/// (`dbtor-bench`, docs/benchmarks.md).
const MEASURE_ROWS: usize = 32;

/// A measurement of `what` cached under `key` in `cache`: `measure` runs
/// once per process and key; its choice, with a line naming every
/// candidate's time, is logged and returned.
fn cached<C: Clone + PartialEq + std::fmt::Debug>(
    cache: &'static std::sync::OnceLock<Measured<C>>,
    key: String,
    what: &str,
    measure: impl FnOnce() -> Result<dbt_conv::select::Selection<C>, dbt_conv::ConvError>,
) -> Result<(C, String), DbtorError> {
    let cache = cache.get_or_init(Default::default);
    if let Some(hit) = cache.lock().ok().and_then(|m| m.get(&key).cloned()) {
        return Ok(hit);
    }
    let sel =
        measure().map_err(|e| DbtorError::Input(format!("measuring the {what} kernels: {e}")))?;
    let got = (
        sel.chosen.clone(),
        format!("{what} on {key}: {}", sel.describe()),
    );
    tracing::info!(chosen = ?sel.chosen, timings = %got.1, "{what} kernel chosen by measurement");
    if let Ok(mut m) = cache.lock() {
        m.insert(key, got.clone());
    }
    Ok(got)
}

fn measured_int8(
    w: &dbt_conv::Int8BlockWeights,
    grid: (usize, usize),
    winograd: bool,
) -> Result<(dbt_conv::select::Int8Config, String), DbtorError> {
    use dbt_conv::select::{measure_int8, Int8Config};
    let (h, wd) = (grid.0.min(MEASURE_ROWS), grid.1);
    let key = format!("{h}x{wd}, {}+{} channels", w.state_ch, w.aux_ch);
    cached(&MEASURED_INT8, key, "int8", || {
        let cands: Vec<Int8Config> = Int8Config::candidates()
            .into_iter()
            .filter(|c| winograd || !c.winograd)
            .collect();
        measure_int8(w, h, wd, &cands)
    })
}

fn measured_fp32(
    w: &dbt_conv::BlockWeights,
    grid: (usize, usize),
    winograd: bool,
) -> Result<(dbt_conv::select::Fp32Config, String), DbtorError> {
    use dbt_conv::select::{measure_fp32, Fp32Config};
    let (h, wd) = (grid.0.min(MEASURE_ROWS), grid.1);
    let key = format!("{h}x{wd}, {}+{} channels", w.state_ch, w.aux_ch);
    cached(&MEASURED_FP32, key, "fp32", || {
        measure_fp32(w, h, wd, &Fp32Config::candidates(winograd))
    })
}

static MEASURED_PROJECTOR: std::sync::OnceLock<Measured<dbt_projector::Kernel>> =
    std::sync::OnceLock::new();

/// The fused projector's kernel chosen as the blocks' are: each kernel the
/// CPU runs applied forward and adjoint to the same pseudo-random image and
/// sinogram of `g`, checked against the scalar kernel (within 1e-5 of the
/// largest value: the kernels sum in other orders) and timed; the fastest
/// that agrees. Cached per geometry.
fn measured_projector(g: &Geometry) -> Result<(Projector, String), DbtorError> {
    use dbt_projector::Kernel as P;
    let base = Projector::new(g);
    let (k, what) = cached(&MEASURED_PROJECTOR, g.describe(), "projector", || {
        let x = dbt_conv::select::inputs(base.domain_len(), 0x9E37_79B9_7F4A_7C15);
        let y = dbt_conv::select::inputs(base.range_len(), 0xD1B5_4A32_D192_ED03);
        let run = |k: &P| -> Result<Vec<f32>, dbt_conv::ConvError> {
            let p = base.clone().up_to(*k);
            let mut out = vec![0.0f32; p.range_len() + p.domain_len()];
            let (sino, img) = out.split_at_mut(p.range_len());
            p.forward(&x, sino)
                .and_then(|_| p.adjoint(&y, img))
                .map_err(|e| dbt_conv::ConvError::Shape(e.to_string()))?;
            Ok(out)
        };
        let reference = run(&P::Scalar)?;
        let cands: Vec<(P, String)> = [P::Scalar, P::Avx2, P::Avx512]
            .into_iter()
            .filter(|k| dbt_projector::best_kernel_up_to(*k) == *k)
            .map(|k| (k, format!("{k:?}").to_lowercase()))
            .collect();
        let preferred = dbt_projector::best_kernel_up_to(P::Avx512);
        dbt_conv::select::select_keeping_bits(
            &cands,
            &reference,
            1e-5,
            dbt_conv::select::REPS,
            Some(&preferred),
            run,
        )
    })?;
    Ok((base.up_to(k), what))
}

/// The environment variable that turns the AVX2 and AVX-VNNI int8 kernels' Winograd
/// convolution off (`off` or `0`; `on`, `1` or unset: on): its direct
/// convolution gives the same bits more slowly, so this is for tests,
/// benchmarks and service comparisons only.
pub const WINOGRAD_ENV: &str = "DBTOR_WINOGRAD";

/// The environment variable that turns the fp32 kernels' Winograd
/// convolution on (`on` or `1`; `off`, `0` or unset: off). Unlike int8's it
/// changes the fp32 sums' rounding (`dbt_conv`'s `fp32::winograd`), so it is
/// opt-in until an accuracy run chooses it.
pub const FP32_WINOGRAD_ENV: &str = "DBTOR_FP32_WINOGRAD";

/// Whether the fp32 kernels convolve by Winograd: [`FP32_WINOGRAD_ENV`]
/// (another value is an error naming it and the choices).
pub fn fp32_winograd_wanted() -> Result<bool, DbtorError> {
    std::env::var(FP32_WINOGRAD_ENV).map_or(Ok(false), |v| parse_switch(FP32_WINOGRAD_ENV, &v))
}

/// Whether the AVX2 and AVX-VNNI int8 kernels may convolve by Winograd: [`WINOGRAD_ENV`]
/// (another value is an error naming it and the choices).
pub fn winograd_allowed() -> Result<bool, DbtorError> {
    std::env::var(WINOGRAD_ENV).map_or(Ok(true), |v| parse_switch(WINOGRAD_ENV, &v))
}

/// An on/off environment value (`name` for the error).
fn parse_switch(name: &str, v: &str) -> Result<bool, DbtorError> {
    match v.trim() {
        "on" | "1" => Ok(true),
        "off" | "0" => Ok(false),
        _ => Err(DbtorError::Input(format!(
            "{name}={v:?}: expected on, off, 1 or 0"
        ))),
    }
}

/// A fast-path block's error, naming its file.
fn fast_path_err(path: &Path) -> impl Fn(dbt_conv::ConvError) -> DbtorError + '_ {
    move |e| DbtorError::Block {
        path: path.to_path_buf(),
        reason: format!("fast path: {e}"),
    }
}

/// The fused projector's kernel level under the fast engine's `limit`
/// (`portable` is the projector's scalar kernel).
pub fn projector_limit(limit: Kernel) -> dbt_projector::Kernel {
    match limit {
        Kernel::Portable => dbt_projector::Kernel::Scalar,
        Kernel::Avx2 | Kernel::AvxVnni => dbt_projector::Kernel::Avx2,
        Kernel::Avx512 | Kernel::Amx => dbt_projector::Kernel::Avx512,
    }
}

/// What [`Dbtor::reconstruct`] enforces on the network's output: priors the
/// acquisition guarantees, which the network only approximates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Constraints {
    /// Zero (air) in the rows outside the compression slab
    /// ([`Dbtor::with_support`]).
    pub support: bool,
    /// No negative attenuation ([`Dbtor::with_nonnegativity`]).
    pub nonnegative: bool,
}

/// Set the negative values of an image to zero: the non-negativity of
/// DBToR's runtime and of the U-Net baseline. Not `max(0)`, which would turn
/// a NaN into 0 and hide it.
pub fn zero_negatives(img: &mut [f32]) {
    img.iter_mut().filter(|v| **v < 0.0).for_each(|v| *v = 0.0);
}

impl Constraints {
    /// The network's output as is: what the fixtures store.
    pub const NONE: Self = Self {
        support: false,
        nonnegative: false,
    };
}

impl std::fmt::Debug for Dbtor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Dbtor")
            .field("model", &self.manifest.name)
            .field("root", &self.root)
            .field("precision", &self.precision)
            .field("fp32_blocks", &self.fp32_blocks)
            .field("engine", &self.engine)
            .field("blocks", &self.manifest.blocks.len())
            .finish()
    }
}

impl Dbtor {
    /// [`Dbtor::load_with`] the tract engine (the reference).
    pub fn load(dir: &Path, precision: Precision) -> Result<Self, DbtorError> {
        Self::load_with(dir, precision, Engine::Tract)
    }

    /// Load the model in `dir` (manifest.json and the files it names), verify
    /// every checksum, and prepare the blocks of `precision` for the model's
    /// geometry on `engine`.
    pub fn load_with(dir: &Path, precision: Precision, engine: Engine) -> Result<Self, DbtorError> {
        Self::load_mixed(dir, precision, &[], engine)
    }

    /// [`Dbtor::load_with`] int8 or fp32, but the blocks named in
    /// `fp32_blocks` (`dual03`, `primal09`, ...: role and two-digit index)
    /// run in fp32: per-block mixed precision, to keep the blocks that lose
    /// the most when quantised (`python -m dbtor.int8_sensitivity`) in float.
    /// An unknown name is an error naming it and the model's blocks.
    pub fn load_mixed(
        dir: &Path,
        precision: Precision,
        fp32_blocks: &[String],
        engine: Engine,
    ) -> Result<Self, DbtorError> {
        let manifest = ModelManifest::load(dir)?;
        manifest.verify_files(dir)?;
        let g = manifest.geometry.clone();
        Self::load_on(
            dir,
            manifest,
            precision,
            fp32_blocks,
            engine,
            &g,
            kernel_choice()?,
        )
    }

    /// As [`Dbtor::load_mixed`], but run the (fully convolutional) blocks on
    /// another geometry: for benchmarks at the paper's full size with a model
    /// trained binned. The normalisation stays the model's.
    pub fn load_for_geometry(
        dir: &Path,
        precision: Precision,
        fp32_blocks: &[String],
        engine: Engine,
        geometry: &Geometry,
    ) -> Result<Self, DbtorError> {
        let manifest = ModelManifest::load(dir)?;
        manifest.verify_files(dir)?;
        let mut m = manifest;
        m.geometry = geometry.clone();
        Self::load_on(
            dir,
            m,
            precision,
            fp32_blocks,
            engine,
            geometry,
            kernel_choice()?,
        )
    }

    /// As [`Dbtor::load_for_geometry`], the fast engine's kernels at most
    /// `limit` (the benchmarks force each path in turn this way).
    pub fn load_for_geometry_up_to(
        dir: &Path,
        precision: Precision,
        fp32_blocks: &[String],
        engine: Engine,
        geometry: &Geometry,
        limit: Kernel,
    ) -> Result<Self, DbtorError> {
        let manifest = ModelManifest::load(dir)?;
        manifest.verify_files(dir)?;
        let mut m = manifest;
        m.geometry = geometry.clone();
        let g = geometry.clone();
        Self::load_on(
            dir,
            m,
            precision,
            fp32_blocks,
            engine,
            &g,
            KernelChoice::UpTo(limit),
        )
    }

    fn load_on(
        dir: &Path,
        manifest: ModelManifest,
        precision: Precision,
        fp32_blocks: &[String],
        engine: Engine,
        g: &Geometry,
        choice: KernelChoice,
    ) -> Result<Self, DbtorError> {
        let c = manifest.state_channels;
        let names: Vec<String> = manifest.blocks.iter().map(block_name).collect();
        if let Some(bad) = fp32_blocks.iter().find(|b| !names.contains(b)) {
            return Err(DbtorError::Input(format!(
                "no block {bad:?} in {} (blocks: {})",
                dir.display(),
                names.join(", ")
            )));
        }
        // Each block's precision: the model's, or fp32 where named.
        let fp32_blocks: Vec<String> = if precision == Precision::Int8 {
            fp32_blocks.to_vec()
        } else {
            Vec::new()
        };
        let files: Vec<_> = manifest
            .blocks
            .iter()
            .map(|b| {
                let p = if fp32_blocks.contains(&block_name(b)) {
                    Precision::Fp32
                } else {
                    precision
                };
                let rel = match p {
                    Precision::Fp32 => &b.fp32,
                    Precision::Int8 => &b.int8,
                };
                (b, p, dir.join(rel))
            })
            .collect();
        // The block each precision's kernels are measured on: its first
        // primal block (most of a slice's work), else its first; `None`
        // where no block runs in that precision.
        let measured_block = |p: Precision| {
            files
                .iter()
                .filter(|f| f.1 == p)
                .find(|f| f.0.role == Role::Primal)
                .or_else(|| files.iter().find(|f| f.1 == p))
        };
        let mut kernel_measurements = Vec::new();
        let blocks = match engine {
            Engine::Tract => {
                let mut plans = Vec::with_capacity(manifest.blocks.len());
                for (b, _, path) in files {
                    let (h, w) = grid(g, b.role);
                    let fail = |e: TractError| DbtorError::Block {
                        path: path.clone(),
                        reason: format!("{e:#}"),
                    };
                    let plan = tract_onnx::onnx()
                        .model_for_path(&path)
                        .map_err(fail)?
                        .with_input_fact(0, f32::fact([1, c, h, w]).into())
                        .map_err(fail)?
                        .with_input_fact(1, f32::fact([1, b.aux_channels, h, w]).into())
                        .map_err(fail)?
                        .into_optimized()
                        .map_err(fail)?
                        .into_runnable()
                        .map_err(fail)?;
                    plans.push((plan, path));
                }
                Blocks::Tract(plans)
            }
            Engine::Fast => {
                use dbt_conv::select::{Fp32Config, Int8Config};
                let winograd = winograd_allowed()?;
                let fp32_winograd = fp32_winograd_wanted()?;
                // Each precision's configuration, once, for every block that
                // runs in it: the fastest up to the forced level, or measured.
                let fp32_cfg = match (choice, measured_block(Precision::Fp32)) {
                    (_, None) => None,
                    (KernelChoice::UpTo(limit), Some(_)) => Some(Fp32Config {
                        kernel: Kernel::best_fp32_up_to(limit),
                        winograd: fp32_winograd,
                    }),
                    (KernelChoice::Measure, Some((b, _, path))) => {
                        let w = fast::fp32_block(path, c, b.aux_channels)?;
                        let (cfg, what) = measured_fp32(&w, grid(g, b.role), fp32_winograd)?;
                        kernel_measurements.push(what);
                        Some(cfg)
                    }
                };
                let int8_cfg = match (choice, measured_block(Precision::Int8)) {
                    (_, None) => None,
                    (KernelChoice::UpTo(limit), Some(_)) => Some(Int8Config {
                        kernel: Kernel::best_int8_up_to(limit),
                        winograd,
                    }),
                    (KernelChoice::Measure, Some((b, _, path))) => {
                        let w = fast::int8_block(path, c, b.aux_channels)?;
                        let (cfg, what) = measured_int8(&w, grid(g, b.role), winograd)?;
                        kernel_measurements.push(what);
                        Some(cfg)
                    }
                };
                let mut v = Vec::new();
                for (b, p, path) in &files {
                    let blk = match (p, fp32_cfg, int8_cfg) {
                        (Precision::Fp32, Some(cfg), _) => {
                            let w = fast::fp32_block(path, c, b.aux_channels)?;
                            FastBlock::Fp32(
                                Fp32Block::with_winograd(&w, cfg.kernel, cfg.winograd)
                                    .map_err(fast_path_err(path))?,
                            )
                        }
                        (Precision::Int8, _, Some(cfg)) => {
                            let w = fast::int8_block(path, c, b.aux_channels)?;
                            FastBlock::Int8(
                                Int8Block::with_winograd(&w, cfg.kernel, cfg.winograd)
                                    .map_err(fast_path_err(path))?,
                            )
                        }
                        // measured_block finds a block of every precision
                        // that runs, so each has its configuration.
                        (p, _, _) => {
                            return Err(DbtorError::Input(format!(
                                "{}: no {p} kernel configuration",
                                path.display()
                            )))
                        }
                    };
                    v.push((blk, path.clone()));
                }
                Blocks::Fast(v)
            }
        };
        // The fused projector: measured with the blocks (fast engine), else
        // the fastest up to the forced level.
        let projector = match (engine, choice) {
            (Engine::Fast, KernelChoice::Measure) => {
                let (p, what) = measured_projector(g)?;
                kernel_measurements.push(what);
                p
            }
            _ => Projector::new(g).up_to(choice.projector_limit()),
        };
        // The support is the thickness prior: DBToR's, not LPD's. No
        // attenuation is negative, whatever the network.
        let constraints = Constraints {
            support: manifest.uses_mask(),
            nonnegative: true,
        };
        let s = Self {
            // The fused projector follows the forced kernel too, so that a
            // forced path is the whole slice of a CPU that has no faster one.
            projector,
            kernel_measurements,
            manifest,
            root: dir.to_path_buf(),
            precision,
            fp32_blocks,
            engine,
            blocks,
            buffers: std::sync::Mutex::new(Vec::new()),
            crop_margin: None,
            constraints,
        };
        tracing::info!(model = %s.manifest.name, precision = %s.precision_label(), %engine, kernel = s.kernel().unwrap_or("tract"), blocks = s.manifest.blocks.len(), "DBToR model loaded");
        Ok(s)
    }

    /// Crop the primal blocks to the rows the thickness mask says can hold
    /// breast, plus `margin` rows above (fast engine only; the rows above
    /// stay zero). This changes the network's function (the blocks see a
    /// zero border where they saw empty image): its effect on accuracy is
    /// measured by `dbt-eval baselines --crop-margin N` against the same
    /// command without it (no figure of it is kept in the documents).
    pub fn with_crop(mut self, margin: Option<usize>) -> Result<Self, DbtorError> {
        if margin.is_some() && self.engine != Engine::Fast {
            return Err(DbtorError::Input(
                "cropping the primal blocks needs the fast engine".into(),
            ));
        }
        self.crop_margin = margin;
        Ok(self)
    }

    /// Whether [`Dbtor::reconstruct`] sets the image to zero (air) in the rows
    /// outside the compressed thickness (default: yes for DBToR, no for LPD,
    /// which by definition does not know the thickness). Nothing but air can
    /// be there: the breast lies between the support and the paddle. This is
    /// the support MLTR is given (`dbt_recon::mltr`'s mask, the paper's
    /// "compressed breast thickness to set the size of the reconstruction
    /// volume"); the network sees the same prior as its mask input but only
    /// approximates zero there (and its int8 version adds quantisation noise
    /// there). Off: the network's output as is, as the fixtures store it.
    pub fn with_support(mut self, on: bool) -> Self {
        self.constraints.support = on;
        self
    }

    /// Whether the support is applied.
    pub fn support(&self) -> bool {
        self.constraints.support
    }

    /// Whether [`Dbtor::reconstruct`] sets negative values to zero (default:
    /// yes, for DBToR and LPD). Attenuation is never negative; the network
    /// only approximates that, with small values of either sign in the air
    /// around the breast (int8 more than fp32). Zeroing them is the
    /// projection onto the physically possible images, so it can only bring
    /// every pixel closer to a non-negative truth. It cannot change the
    /// tissue classification: breast voxels are those above half the
    /// adipose attenuation (`dbt_tissue`), and only their values are read,
    /// so density and dose are the same with it on or off (tested in
    /// firmware/tests/pipeline.rs). Off: the network's output as is.
    pub fn with_nonnegativity(mut self, on: bool) -> Self {
        self.constraints.nonnegative = on;
        self
    }

    /// The constraints applied to the network's output.
    pub fn constraints(&self) -> Constraints {
        self.constraints
    }

    /// The crop margin, if cropping.
    pub fn crop_margin(&self) -> Option<usize> {
        self.crop_margin
    }

    /// The executor.
    pub fn engine(&self) -> Engine {
        self.engine
    }

    /// What the kernels' measurement found at load, one line per precision
    /// (each configuration's median time, the chosen one marked); empty
    /// where `DBTOR_KERNEL` forced the kernels or on the tract engine.
    pub fn kernel_measurements(&self) -> &[String] {
        &self.kernel_measurements
    }

    /// The fused projector's kernel (either engine; `DBTOR_KERNEL` limits it).
    pub fn projector_kernel(&self) -> dbt_projector::Kernel {
        self.projector.kernel()
    }

    /// The fast path's kernel ("avx512", "avx2" or "portable"; the first
    /// block's, which mixed precision may differ from), `None` on tract.
    pub fn kernel(&self) -> Option<&'static str> {
        match &self.blocks {
            Blocks::Tract(_) => None,
            Blocks::Fast(v) => v.first().map(|b| match &b.0 {
                FastBlock::Fp32(k) => k.kernel().name(),
                FastBlock::Int8(k) => k.kernel().name(),
            }),
        }
    }

    /// The same model with the int8 kernels' direct convolution
    /// everywhere (as [`WINOGRAD_ENV`]`=off` loads it): the int8 blocks that
    /// convolve by Winograd reloaded without it (for benchmarks).
    pub fn without_winograd(self) -> Result<Self, DbtorError> {
        self.with_blocks_rebuilt(Precision::Int8, false)
    }

    /// The same model with its int8 blocks run layer by layer over
    /// whole-image buffers instead of in fused bands of rows (the same
    /// bits; for benchmarks).
    pub fn int8_layer_by_layer(mut self) -> Self {
        if let Blocks::Fast(v) = &mut self.blocks {
            for (blk, _) in v.iter_mut() {
                if let FastBlock::Int8(k) = blk {
                    k.set_layer_by_layer();
                }
            }
        }
        // a workspace made before holds the fused pass's buffers only
        self.buffers
            .get_mut()
            .unwrap_or_else(|e| e.into_inner())
            .clear();
        self
    }

    /// Of the fast engine's int8 blocks, how many run fused over bands of
    /// rows on their grid, and how many there are.
    pub fn int8_fused_blocks(&self) -> (usize, usize) {
        match &self.blocks {
            Blocks::Tract(_) => (0, 0),
            Blocks::Fast(v) => v.iter().zip(&self.manifest.blocks).fold(
                (0, 0),
                |(n, all), ((blk, _), b)| match blk {
                    FastBlock::Int8(k) => {
                        let (h, w) = grid(&self.manifest.geometry, b.role);
                        (n + usize::from(k.runs_fused(h, w)), all + 1)
                    }
                    FastBlock::Fp32(_) => (n, all),
                },
            ),
        }
    }

    /// The same model with its fp32 blocks convolving by Winograd (as
    /// [`FP32_WINOGRAD_ENV`]`=on` loads it; for benchmarks).
    pub fn with_fp32_winograd(self) -> Result<Self, DbtorError> {
        self.with_blocks_rebuilt(Precision::Fp32, true)
    }

    /// The fast engine's blocks of `precision` read again from their files
    /// and made on the same kernel with Winograd on or off.
    fn with_blocks_rebuilt(
        mut self,
        precision: Precision,
        winograd: bool,
    ) -> Result<Self, DbtorError> {
        let c = self.manifest.state_channels;
        if let Blocks::Fast(v) = &mut self.blocks {
            for ((blk, path), b) in v.iter_mut().zip(&self.manifest.blocks) {
                match (blk, precision) {
                    (FastBlock::Int8(k), Precision::Int8) => {
                        let w = fast::int8_block(path, c, b.aux_channels)?;
                        *k = Int8Block::with_winograd(&w, k.kernel(), winograd)
                            .map_err(fast_path_err(path))?;
                    }
                    (FastBlock::Fp32(k), Precision::Fp32) => {
                        let w = fast::fp32_block(path, c, b.aux_channels)?;
                        *k = Fp32Block::with_winograd(&w, k.kernel(), winograd)
                            .map_err(fast_path_err(path))?;
                    }
                    _ => {}
                }
            }
        }
        Ok(self)
    }

    /// Convolutions run by Winograd (the AVX2 and AVX-VNNI int8 kernels',
    /// the fp32 kernels' where asked for), of all the fast engine's.
    pub fn winograd_convolutions(&self) -> (usize, usize) {
        match &self.blocks {
            Blocks::Tract(_) => (0, 0),
            Blocks::Fast(v) => v.iter().fold((0, 0), |(n, all), b| match &b.0 {
                FastBlock::Fp32(k) => (n + k.winograd_layers(), all + 3),
                FastBlock::Int8(k) => (n + k.winograd_layers(), all + 3),
            }),
        }
    }

    fn new_buffers(&self) -> Buffers {
        let g = &self.manifest.geometry;
        let (n_img, n_sino) = (g.n_pixels(), g.n_rays());
        let c = self.manifest.state_channels;
        // Checked when the manifest was loaded.
        let (aux_dual, aux_primal) = self.manifest.aux_channels().unwrap_or((3, 2));
        let ((views, det), (rows, cols)) = (grid(g, Role::Dual), grid(g, Role::Primal));
        let e = &self.manifest.blocks;
        let ws = match &self.blocks {
            Blocks::Tract(_) => Workspaces::None,
            Blocks::Fast(v) => {
                let (f, i) = (FastBlock::as_fp32, FastBlock::as_int8);
                Workspaces::Fast {
                    fp32: [
                        first_of_role(v, e, Role::Dual, f)
                            .map(|d| Fp32Workspace::new(d, views, det)),
                        first_of_role(v, e, Role::Primal, f)
                            .map(|p| Fp32Workspace::new(p, rows, cols)),
                    ],
                    int8: [
                        first_of_role(v, e, Role::Dual, i)
                            .map(|d| Int8Workspace::new(d, views, det)),
                        first_of_role(v, e, Role::Primal, i)
                            .map(|p| Int8Workspace::new(p, rows, cols)),
                    ],
                }
            }
        };
        Buffers {
            gn: vec![0.0; n_sino],
            mask: vec![0.0; n_img],
            pm: vec![0.0; n_sino],
            h: vec![0.0; c * n_sino],
            f: vec![0.0; c * n_img],
            aux_d: vec![0.0; aux_dual * n_sino],
            aux_p: vec![0.0; aux_primal * n_img],
            ws,
        }
    }

    /// Floating-point operations of each block on this geometry (2 per
    /// multiply-add), from the fast path's weights; `None` on tract.
    pub fn block_flops(&self) -> Option<Vec<f64>> {
        let g = &self.manifest.geometry;
        let roles = self.manifest.blocks.iter().map(|b| grid(g, b.role));
        match &self.blocks {
            Blocks::Tract(_) => None,
            Blocks::Fast(v) => Some(
                v.iter()
                    .zip(roles)
                    .map(|(b, (h, w))| match &b.0 {
                        FastBlock::Fp32(k) => k.flops(h, w),
                        FastBlock::Int8(k) => k.ops(h, w),
                    })
                    .collect(),
            ),
        }
    }

    /// Bytes of one set of per-slice buffers (state, aux, workspaces), one
    /// per slice in flight. A set is made if no slice has made one yet, and
    /// kept for the next slice.
    pub fn slice_buffer_bytes(&self) -> usize {
        let mut pool = self.buffers.lock().unwrap_or_else(|e| e.into_inner());
        if pool.is_empty() {
            pool.push(self.new_buffers());
        }
        pool[0].bytes()
    }

    /// The model folder it was loaded from.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The manifest.
    pub fn manifest(&self) -> &ModelManifest {
        &self.manifest
    }

    /// The model's geometry (the grid of its input sinogram and output image).
    pub fn geometry(&self) -> &Geometry {
        &self.manifest.geometry
    }

    /// The precision the blocks run in (int8 also when some run in fp32:
    /// [`Dbtor::fp32_blocks`]).
    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// The blocks run in fp32 in an int8 model (mixed precision).
    pub fn fp32_blocks(&self) -> &[String] {
        &self.fp32_blocks
    }

    /// The precision in words: `fp32`, `int8`, or `int8 (fp32: primal08,
    /// primal09)`.
    pub fn precision_label(&self) -> String {
        if self.fp32_blocks.is_empty() {
            self.precision.to_string()
        } else {
            format!("{} (fp32: {})", self.precision, self.fp32_blocks.join(", "))
        }
    }

    /// `state <- block k(state, aux)` on an `h x w` grid.
    fn run_block(
        &self,
        k: usize,
        state: &mut [f32],
        aux: &[f32],
        ws: &mut Workspaces,
        r0: usize,
    ) -> Result<(), DbtorError> {
        let b = &self.manifest.blocks[k];
        let (h, w) = grid(&self.manifest.geometry, b.role);
        let c = self.manifest.state_channels;
        let conv_fail = |path: &Path, e: dbt_conv::ConvError| DbtorError::Block {
            path: path.to_path_buf(),
            reason: format!("fast path: {e}"),
        };
        match (&self.blocks, ws, b.role) {
            (Blocks::Tract(plans), _, _) => {
                let (plan, file) = &plans[k];
                let fail = |e: TractError| DbtorError::Block {
                    path: file.clone(),
                    reason: format!("{e:#}"),
                };
                let st = Tensor::from_shape(&[1, c, h, w], state).map_err(fail)?;
                let ax = Tensor::from_shape(&[1, b.aux_channels, h, w], aux).map_err(fail)?;
                let out = plan.run(tvec![st.into(), ax.into()]).map_err(fail)?;
                let view = out[0].to_plain_array_view::<f32>().map_err(fail)?;
                if view.len() != state.len() {
                    return Err(DbtorError::Block {
                        path: file.clone(),
                        reason: format!(
                            "output has {} values, expected {}",
                            view.len(),
                            state.len()
                        ),
                    });
                }
                state.iter_mut().zip(view.iter()).for_each(|(s, v)| *s = *v);
                Ok(())
            }
            (Blocks::Fast(v), Workspaces::Fast { fp32, int8 }, role) => {
                let (at, r0) = if role == Role::Dual { (0, 0) } else { (1, r0) };
                let missing = || DbtorError::Input("internal: no workspace for the block".into());
                match &v[k].0 {
                    FastBlock::Fp32(blk) => {
                        blk.run_rows(fp32[at].as_mut().ok_or_else(missing)?, state, aux, r0)
                    }
                    FastBlock::Int8(blk) => {
                        blk.run_rows(int8[at].as_mut().ok_or_else(missing)?, state, aux, r0)
                    }
                }
                .map_err(|e| conv_fail(&v[k].1, e))
            }
            _ => Err(DbtorError::Input(
                "internal: workspaces do not match the engine".into(),
            )),
        }
    }

    /// Reconstruct one coronal slice from its log-transformed sinogram `g`
    /// (`ln(b / y)`, view-major, on the model's geometry) and the compressed
    /// thickness. Returns attenuation in 1/mm, row-major on the model's image.
    /// With the support on (the default, [`Dbtor::with_support`]) the rows
    /// outside the compressed thickness are zero; with the non-negativity
    /// (the default, [`Dbtor::with_nonnegativity`]) no value is negative.
    pub fn reconstruct(&self, g: &[f32], thickness_mm: f64) -> Result<Vec<f32>, DbtorError> {
        let mut out = vec![0.0f32; self.manifest.geometry.n_pixels()];
        self.reconstruct_into(g, thickness_mm, &mut out)?;
        Ok(out)
    }

    /// The network's output f[0] (1/mm) without the support or the
    /// non-negativity, whatever [`Dbtor::constraints`] says: what the
    /// fixtures store.
    pub fn network_output(&self, g: &[f32], thickness_mm: f64) -> Result<Vec<f32>, DbtorError> {
        let mut out = vec![0.0f32; self.manifest.geometry.n_pixels()];
        self.slice(g, thickness_mm, &mut out, None, Constraints::NONE)?;
        Ok(out)
    }

    /// [`Dbtor::reconstruct`] into `out` (the model's image size). With the
    /// fast engine nothing is allocated after the first slice: the buffers
    /// are kept between calls (a set per concurrent call, made by its first).
    pub fn reconstruct_into(
        &self,
        g: &[f32],
        thickness_mm: f64,
        out: &mut [f32],
    ) -> Result<(), DbtorError> {
        self.slice(g, thickness_mm, out, None, self.constraints)
    }

    /// Reconstruct one slice (as [`Dbtor::reconstruct`]) timing every block
    /// and the projector: for benchmarks and the service CLI.
    pub fn profile_slice(
        &self,
        g: &[f32],
        thickness_mm: f64,
    ) -> Result<(Vec<f32>, SliceProfile), DbtorError> {
        let mut out = vec![0.0f32; self.manifest.geometry.n_pixels()];
        let mut p = SliceProfile {
            block_ms: vec![0.0; self.manifest.blocks.len()],
            ..SliceProfile::default()
        };
        let t = std::time::Instant::now();
        self.slice(g, thickness_mm, &mut out, Some(&mut p), self.constraints)?;
        p.total_ms = t.elapsed().as_secs_f64() * 1e3;
        Ok((out, p))
    }

    fn slice(
        &self,
        g: &[f32],
        thickness_mm: f64,
        out: &mut [f32],
        prof: Option<&mut SliceProfile>,
        constraints: Constraints,
    ) -> Result<(), DbtorError> {
        let geom = &self.manifest.geometry;
        let n_img = geom.n_pixels();
        let n_sino = geom.n_rays();
        if g.len() != n_sino {
            return Err(DbtorError::Input(format!(
                "sinogram has {} samples, the model's geometry needs {} ({} views x {} elements)",
                g.len(),
                n_sino,
                geom.n_views(),
                geom.n_det()
            )));
        }
        if out.len() != n_img {
            return Err(DbtorError::Input(format!(
                "output has room for {} pixels, the model's image has {n_img}",
                out.len()
            )));
        }
        if let Some(i) = g.iter().position(|v| !v.is_finite()) {
            return Err(DbtorError::Input(format!(
                "sinogram sample {i} is not finite ({})",
                g[i]
            )));
        }
        if !(thickness_mm.is_finite() && thickness_mm > 0.0) {
            return Err(DbtorError::Input(format!(
                "thickness {thickness_mm} mm is not a positive number"
            )));
        }
        let taken = self.buffers.lock().unwrap_or_else(|e| e.into_inner()).pop();
        let mut bufs = match taken {
            Some(b) => b,
            None => self.new_buffers(),
        };
        // The slice runs on a worker of rayon's pool, so that the parallel
        // loops inside it queue their jobs on the workers' own deques (which
        // stop growing after the first slice) instead of pushing each one
        // through the pool's injector from outside (which allocates a block
        // every 63 jobs). One job is injected per slice.
        let span = tracing::Span::current();
        let r = rayon::scope(|_| {
            span.in_scope(|| self.run_slice(&mut bufs, g, thickness_mm, out, prof, constraints))
        });
        self.buffers
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(bufs);
        r
    }

    fn run_slice(
        &self,
        b: &mut Buffers,
        g: &[f32],
        thickness_mm: f64,
        out: &mut [f32],
        mut prof: Option<&mut SliceProfile>,
        constraints: Constraints,
    ) -> Result<(), DbtorError> {
        use std::time::Instant;
        let ms = |t: Instant| t.elapsed().as_secs_f64() * 1e3;
        let geom = &self.manifest.geometry;
        let (n_img, n_sino) = (geom.n_pixels(), geom.n_rays());
        let n = &self.manifest.normalisation;
        let ch = &self.manifest.channels;
        let inv_norm = (1.0 / n.operator_norm) as f32;
        let (g_mean, g_std) = (n.g_mean as f32, n.g_std as f32);
        let Buffers {
            gn,
            mask,
            pm,
            h,
            f,
            aux_d,
            aux_p,
            ws,
        } = b;
        for (d, v) in gn.iter_mut().zip(g) {
            *d = (v - g_mean) / g_std;
        }
        // The thickness mask (dbt_phantom::thickness_mask, in place).
        let inside = geom.rows_within_thickness(thickness_mm);
        let cols = geom.image.columns;
        let first = (geom.image.rows - inside) * cols;
        mask[..first].fill(0.0);
        mask[first..].fill(1.0);
        let r0 = self
            .crop_margin
            .map(|m| (first / cols).saturating_sub(m).min(geom.image.rows - 1))
            .unwrap_or(0);
        h.fill(0.0);
        f.fill(0.0);
        aux_d[n_sino..2 * n_sino].copy_from_slice(gn);
        if self.manifest.uses_mask() {
            self.project(mask, pm, inv_norm)?;
            aux_d[2 * n_sino..].copy_from_slice(pm);
            aux_p[n_img..].copy_from_slice(mask);
        }
        for (k, blk) in self.manifest.blocks.iter().enumerate() {
            let _s = tracing::trace_span!("block", role = ?blk.role, index = blk.index).entered();
            let t0 = Instant::now();
            match blk.role {
                Role::Dual => {
                    let fc = &f[ch.projected * n_img..(ch.projected + 1) * n_img];
                    self.project(fc, &mut aux_d[..n_sino], inv_norm)?;
                }
                Role::Primal => {
                    let hc = &h[ch.backprojected * n_sino..(ch.backprojected + 1) * n_sino];
                    self.backproject(hc, &mut aux_p[..n_img], inv_norm)?;
                }
            }
            let t1 = Instant::now();
            match blk.role {
                Role::Dual => self.run_block(k, h, aux_d, ws, 0)?,
                Role::Primal => self.run_block(k, f, aux_p, ws, r0)?,
            }
            if let Some(p) = prof.as_deref_mut() {
                p.projector_ms += ms(t0) - ms(t1);
                p.block_ms[k] = ms(t1);
            }
        }
        let xs = n.x_scale_per_mm as f32;
        for (o, v) in out
            .iter_mut()
            .zip(&f[ch.output * n_img..(ch.output + 1) * n_img])
        {
            *o = v * xs;
        }
        if constraints.support {
            out[..first].fill(0.0);
        }
        if constraints.nonnegative {
            zero_negatives(out);
        }
        Ok(())
    }

    fn project(&self, img: &[f32], out: &mut [f32], scale: f32) -> Result<(), DbtorError> {
        self.projector
            .forward(img, out)
            .map_err(|e| DbtorError::Input(e.to_string()))?;
        out.iter_mut().for_each(|v| *v *= scale);
        Ok(())
    }

    fn backproject(&self, sino: &[f32], out: &mut [f32], scale: f32) -> Result<(), DbtorError> {
        self.projector
            .adjoint(sino, out)
            .map_err(|e| DbtorError::Input(e.to_string()))?;
        out.iter_mut().for_each(|v| *v *= scale);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn winograd_switch_values_are_read_or_refused_by_name() {
        for (v, want) in [("on", true), ("1", true), (" off ", false), ("0", false)] {
            assert_eq!(parse_switch(WINOGRAD_ENV, v).unwrap(), want, "{v:?}");
        }
        let e = parse_switch(WINOGRAD_ENV, "no").unwrap_err().to_string();
        assert!(
            e.contains("DBTOR_WINOGRAD=\"no\"") && e.contains("on, off"),
            "{e}"
        );
    }
}
