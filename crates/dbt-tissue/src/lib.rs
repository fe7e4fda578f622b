//! From reconstructed attenuation to tissue labels and breast density (paper
//! section 3.5, "Discretization"):
//! 1. **Breast mask**: voxels above half the adipose attenuation are breast;
//!    everything else is air. (The paper does not say how air is separated;
//!    half of the lowest tissue attenuation is the midpoint between air and
//!    fat.)
//! 2. **Skin** by seeded region growing (Adams and Bischof 1994): the seeds are
//!    the breast voxels on its outer edge (6-neighbour of air or of the volume
//!    border, except the chest-wall face); the region grows through breast
//!    voxels whose value is at least the mean seed value
//!    ([`ClassifyOptions::paper`]). In a reconstruction the thin skin is
//!    blurred below its true attenuation, the seed mean falls under the
//!    fibroglandular value, and the unbounded growth runs from the skin into
//!    every glandular structure touching it: on our validation phantoms it
//!    took 38 % of the fibroglandular voxels. Beyond the paper, the growth is
//!    bounded to [`ClassifyOptions::skin_max_mm`] below the outer edge, and
//!    the default rule ([`SkinRule::Shell`]) takes the whole shell of the
//!    anatomical skin thickness ([`SKIN_MAX_MM`]), whatever its values: the
//!    blurred skin's inner layer, a mix of skin and fat, is otherwise read
//!    as fibroglandular right under the entrance surface, where it weighs
//!    most in the dose. Measured with `dbt-eval classification` (see
//!    eval/README.md). A model whose skin blurs deeper may add a
//!    subcutaneous fat band under the shell
//!    ([`ClassifyOptions::fat_band_mm`]): adipose whatever its values, and
//!    left out of the fit below.
//! 3. **Adipose vs fibroglandular** by fuzzy c-means (Bezdek 1981) with two
//!    classes and fuzziness 2.0 on the skin-free breast; a voxel takes the
//!    class of its larger membership.
//! 4. **Glandularity** by mass from the labels (paper eq. 4), and beyond the
//!    paper a partial-volume estimate reading each non-skin breast voxel's
//!    fibroglandular fraction from its attenuation between the adipose and
//!    fibroglandular values. The firmware reports the partial-volume
//!    estimate (the smaller spread on the validation phantoms); the labels
//!    feed the dose engine.
//!
//! Volumes use the layout of `dbt_phantom::LabelVolume`: `[lateral, vertical,
//! depth]`, lateral fastest, vertical index 0 on the support, depth index 0 at
//! the chest wall.

use dbt_materials::{glandularity, Tissue};
use rayon::prelude::*;
use serde::Serialize;
use thiserror::Error;

/// Errors of the classification.
#[derive(Debug, Error, PartialEq)]
pub enum TissueError {
    /// The volume's size does not match its dimensions.
    #[error("volume has {got} values, dimensions {dims:?} need {want}")]
    Size {
        /// Values given.
        got: usize,
        /// Values needed.
        want: usize,
        /// The dimensions.
        dims: [usize; 3],
    },
    /// The voxel side is not a positive number.
    #[error("voxel side {0} mm is not a positive number")]
    Voxel(f64),
    /// A calibration cannot be fit.
    #[error("glandularity calibration: {0}")]
    Calibration(String),
    /// Options that cannot classify.
    #[error("classification options: {0}")]
    Options(String),
    /// No breast voxel found.
    #[error("no breast tissue in the volume (no value above {0} /mm)")]
    Empty(f32),
}

/// Options of the classification.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
pub struct ClassifyOptions {
    /// Fuzziness exponent of fuzzy c-means (the paper: 2.0).
    pub fuzziness: f64,
    /// Iteration cap of fuzzy c-means.
    pub max_iter: usize,
    /// Convergence: largest change of a class centre, 1/mm.
    pub tol: f64,
    /// Deepest skin voxel, mm below the outer edge (the seeds are at depth
    /// one voxel); `None` grows without bound, as the paper describes.
    pub skin_max_mm: Option<f64>,
    /// How voxels join the skin within the depth bound.
    pub skin_rule: SkinRule,
    /// A subcutaneous fat band: breast voxels deeper than the skin's bound
    /// but within this many mm beneath it are adipose, whatever their value
    /// (`None`, the default: no band). For a network whose reconstruction
    /// blurs the skin into the layer under it, which fuzzy c-means then
    /// reads as gland right under the entrance surface, where it weighs most
    /// in the dose (training/runs/dbtor-x4w/BAR.md, "Where the patient MGD
    /// goes wrong"); unlike a deeper skin shell it adds no skin, whose
    /// attenuation would shield the gland beneath it in the Monte Carlo.
    /// Anatomically the layer under the skin is the subcutaneous
    /// (premammary) fat. Needs a skin bound; a rule of a model, chosen on
    /// its validation breasts (`dbt-eval classification --skin
    /// shell:1.6+fat:MM`). Absent from the JSON when `None` (calibration
    /// files written before it read the same).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fat_band_mm: Option<f64>,
}

/// How the skin region is grown.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize)]
pub enum SkinRule {
    /// The paper's seeded region growing: through voxels at or above the
    /// mean seed value.
    Grow,
    /// Every breast voxel within the depth bound is skin, whatever its
    /// value (a shell of the bound's thickness); without a bound, as
    /// [`SkinRule::Grow`].
    Shell,
}

/// The default skin thickness, mm: the breast skin is 1.45 +- 0.30 mm
/// thick (Huang et al. 2008, Med. Phys. 35(4), dedicated breast CT of 100
/// women; our phantoms draw it in 1.2-1.8 mm), rounded to whole voxels of
/// our 0.8 mm grid: two layers. With [`SkinRule::Shell`], the default, the
/// skin is that shell. Chosen on the validation phantoms with `dbt-eval
/// classification` (eval/README.md), where the paper's unbounded growth
/// read 38 % of the fibroglandular voxels as skin.
pub const SKIN_MAX_MM: f64 = 1.6;

impl Default for ClassifyOptions {
    fn default() -> Self {
        Self {
            fuzziness: 2.0,
            max_iter: 200,
            tol: 1e-7,
            skin_max_mm: Some(SKIN_MAX_MM),
            skin_rule: SkinRule::Shell,
            fat_band_mm: None,
        }
    }
}

impl ClassifyOptions {
    /// The paper's classification: skin grown without a depth bound.
    pub fn paper() -> Self {
        Self {
            skin_max_mm: None,
            skin_rule: SkinRule::Grow,
            ..Self::default()
        }
    }

    /// The depth bound in voxel layers (the seeds are layer 1) for voxels of
    /// side `voxel_mm`: `max(1, round(skin_max_mm / voxel_mm))`.
    pub fn skin_max_layers(&self, voxel_mm: f64) -> usize {
        match self.skin_max_mm {
            Some(mm) => ((mm / voxel_mm).round() as usize).max(1),
            None => usize::MAX,
        }
    }

    /// The fat band's depth in voxel layers below the skin's bound:
    /// `round(fat_band_mm / voxel_mm)` (0 without a band or a skin bound).
    pub fn fat_band_layers(&self, voxel_mm: f64) -> usize {
        match (self.skin_max_mm, self.fat_band_mm) {
            (Some(_), Some(mm)) if mm > 0.0 => (mm / voxel_mm).round() as usize,
            _ => 0,
        }
    }
}

/// The classification result.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Classification {
    /// Labels (dbt-materials codes: 0 air, 1 adipose, 2 skin, 3 fibroglandular).
    #[serde(skip)]
    pub labels: Vec<u8>,
    /// Fuzzy c-means class centres (adipose, fibroglandular), 1/mm.
    pub centres: [f64; 2],
    /// Mean value of the skin seeds, 1/mm.
    pub seed_mean: f64,
    /// Fuzzy c-means iterations used.
    pub iterations: usize,
}

fn check(dims: [usize; 3], n: usize) -> Result<(), TissueError> {
    let want = dims.iter().product();
    if n != want || want == 0 {
        return Err(TissueError::Size { got: n, want, dims });
    }
    Ok(())
}

/// The 6-neighbours of voxel `i` (lateral, vertical, depth), with a flag per
/// direction telling whether it leaves the volume.
fn neighbours(i: usize, dims: [usize; 3]) -> [(Option<usize>, bool); 6] {
    let [nx, ny, nz] = dims;
    let (x, y, z) = (i % nx, (i / nx) % ny, i / (nx * ny));
    let at = |x: usize, y: usize, z: usize| (z * ny + y) * nx + x;
    [
        (x.checked_sub(1).map(|x| at(x, y, z)), false),
        ((x + 1 < nx).then(|| at(x + 1, y, z)), false),
        (y.checked_sub(1).map(|y| at(x, y, z)), false),
        ((y + 1 < ny).then(|| at(x, y + 1, z)), false),
        // Depth 0 is the chest wall: leaving there is not an outer edge.
        (z.checked_sub(1).map(|z| at(x, y, z)), true),
        ((z + 1 < nz).then(|| at(x, y, z + 1)), false),
    ]
}

/// Classify a reconstructed attenuation volume (1/mm) of cubic voxels of
/// side `voxel_mm`.
pub fn classify(
    mu: &[f32],
    dims: [usize; 3],
    voxel_mm: f64,
    opts: &ClassifyOptions,
) -> Result<Classification, TissueError> {
    check(dims, mu.len())?;
    if !(voxel_mm.is_finite() && voxel_mm > 0.0) {
        return Err(TissueError::Voxel(voxel_mm));
    }
    if let Some(b) = opts.fat_band_mm {
        if !(b.is_finite() && b >= 0.0) || opts.skin_max_mm.is_none() {
            return Err(TissueError::Options(format!(
                "a fat band of {b} mm (needs a finite depth >= 0 and a skin bound; skin bound {:?})",
                opts.skin_max_mm
            )));
        }
    }
    let _span = tracing::debug_span!("classify", ?dims).entered();
    let air_cut = 0.5 * Tissue::Adipose.mu_per_mm();
    // The per-voxel passes run on rayon's pool, each collected in voxel
    // order: the same classification whatever the number of threads (at
    // the paper's 0.2 mm a breast is ~10^8 voxels).
    let breast: Vec<bool> = mu.par_iter().map(|&v| v > air_cut).collect();
    if !breast.par_iter().any(|&b| b) {
        return Err(TissueError::Empty(air_cut));
    }
    // Seeds: breast voxels with an air neighbour or on the volume border
    // (except the chest-wall face).
    let seeds: Vec<usize> = (0..mu.len())
        .into_par_iter()
        .filter(|&i| {
            breast[i]
                && neighbours(i, dims).iter().any(|&(n, chest)| match n {
                    Some(j) => !breast[j],
                    None => !chest,
                })
        })
        .collect();
    let seed_mean = seeds.iter().map(|&i| mu[i] as f64).sum::<f64>() / seeds.len().max(1) as f64;
    // Depth below the outer edge in voxel layers (seeds: 1), by breadth-first
    // search through the breast, where the skin's depth is bounded.
    let max_layers = opts.skin_max_layers(voxel_mm);
    let band_layers = opts.fat_band_layers(voxel_mm);
    let mut fat_band = Vec::new();
    let depth_ok: Vec<bool> = if max_layers == usize::MAX {
        vec![true; mu.len()]
    } else {
        // u16 depths (a quarter of u32's memory): the search stops at
        // `max_layers` (and the fat band's), far below u16::MAX for any
        // skin bound in voxels.
        let cap = max_layers.min(u16::MAX as usize - 1) as u16;
        let search = (max_layers + band_layers).min(u16::MAX as usize - 1) as u16;
        let mut depth = vec![u16::MAX; mu.len()];
        let mut queue = std::collections::VecDeque::with_capacity(seeds.len());
        for &i in &seeds {
            depth[i] = 1;
            queue.push_back(i);
        }
        while let Some(i) = queue.pop_front() {
            if depth[i] >= search {
                continue;
            }
            for (n, _) in neighbours(i, dims) {
                if let Some(j) = n {
                    if breast[j] && depth[j] == u16::MAX {
                        depth[j] = depth[i] + 1;
                        queue.push_back(j);
                    }
                }
            }
        }
        if band_layers > 0 {
            fat_band = depth.par_iter().map(|&d| d > cap && d <= search).collect();
        }
        depth.par_iter().map(|&d| d <= cap).collect()
    };
    // Region growing from the seeds through breast voxels >= seed mean.
    let mut skin = vec![false; mu.len()];
    // The shell rule grows through every voxel within the bound. "At or
    // above the mean" allows the mean's rounding (1e-9 relative): the f64
    // mean of equal values can come out one ulp above each of them.
    let floor = match opts.skin_rule {
        SkinRule::Shell if max_layers != usize::MAX => f64::NEG_INFINITY,
        _ => seed_mean - 1e-9 * seed_mean.abs(),
    };
    let mut stack: Vec<usize> = seeds
        .iter()
        .copied()
        .filter(|&i| mu[i] as f64 >= floor)
        .collect();
    for &i in &stack {
        skin[i] = true;
    }
    while let Some(i) = stack.pop() {
        for (n, _) in neighbours(i, dims) {
            if let Some(j) = n {
                if breast[j] && depth_ok[j] && !skin[j] && mu[j] as f64 >= floor {
                    skin[j] = true;
                    stack.push(j);
                }
            }
        }
    }
    // Fuzzy c-means (2 classes) on the skin-free breast (f32 values, as
    // reconstructed: half the memory of f64 copies, the same sums).
    // Counted per chunk, then each chunk's values written to its own part
    // of the vector: in voxel order, in parallel, without a second copy.
    const PART: usize = 1 << 16;
    // The fat band's values are the blurred skin's, not evidence of either
    // class: left out of the fit as the skin is (empty without a band).
    let in_band = |i: usize| fat_band.get(i).copied().unwrap_or(false);
    let keep = |i: usize| breast[i] && !skin[i] && !in_band(i);
    let counts: Vec<usize> = (0..mu.len().div_ceil(PART))
        .into_par_iter()
        .map(|c| {
            (c * PART..((c + 1) * PART).min(mu.len()))
                .filter(|&i| keep(i))
                .count()
        })
        .collect();
    let mut vals = vec![0.0f32; counts.iter().sum()];
    let mut parts = Vec::with_capacity(counts.len());
    let mut rest = &mut vals[..];
    for &c in &counts {
        let (part, tail) = rest.split_at_mut(c);
        parts.push(part);
        rest = tail;
    }
    parts.into_par_iter().enumerate().for_each(|(c, part)| {
        let from = (c * PART..((c + 1) * PART).min(mu.len())).filter(|&i| keep(i));
        for (o, i) in part.iter_mut().zip(from) {
            *o = mu[i];
        }
    });
    let (centres, iterations) = fcm2_of(&vals, opts);
    let mid = split_point(centres);
    let labels = (0..mu.len())
        .into_par_iter()
        .map(|i| {
            if !breast[i] {
                Tissue::Air.label()
            } else if skin[i] {
                Tissue::Skin.label()
            } else if in_band(i) {
                Tissue::Adipose.label()
            } else if (mu[i] as f64) >= mid {
                // With two classes and one feature, the larger membership
                // switches exactly at the midpoint of the centres.
                Tissue::Fibroglandular.label()
            } else {
                Tissue::Adipose.label()
            }
        })
        .collect();
    Ok(Classification {
        labels,
        centres,
        seed_mean,
        iterations,
    })
}

/// The attenuation that splits adipose from fibroglandular voxels for the
/// fuzzy c-means `centres` (low, high): with two classes and one feature
/// the larger membership switches at their midpoint. Two classes need two
/// populations: when the centres meet (a skin-free breast of one value), the
/// midpoint of the two tissues' nominal attenuations instead.
pub fn split_point(centres: [f64; 2]) -> f64 {
    if centres[1] - centres[0] < 1e-6 {
        0.5 * (Tissue::Adipose.mu_per_mm() as f64 + Tissue::Fibroglandular.mu_per_mm() as f64)
    } else {
        0.5 * (centres[0] + centres[1])
    }
}

/// `total_cmp` of f32 and f64, as one function pointer type.
trait TotalOrder: Copy + Send + Sync {
    fn total_cmp_ref(a: &Self, b: &Self) -> std::cmp::Ordering;

    /// [`quantiles`] of `vals` (a type may find them faster).
    fn quantiles(vals: &[Self], fs: [f64; 2]) -> [Self; 2] {
        quantiles(vals, fs, Self::total_cmp_ref)
    }
}

impl TotalOrder for f32 {
    fn total_cmp_ref(a: &Self, b: &Self) -> std::cmp::Ordering {
        a.total_cmp(b)
    }

    /// The same two values by a parallel histogram of the values' leading
    /// 16 bits in `total_cmp` order (one pass over them on the pool), then
    /// a selection among the values of the bin that holds each rank only.
    fn quantiles(vals: &[Self], fs: [f64; 2]) -> [Self; 2] {
        // total_cmp order as unsigned order: negative values' bits inverted,
        // positive ones' sign bit set.
        let key = |x: f32| {
            let b = x.to_bits();
            if b >> 31 == 1 {
                !b
            } else {
                b | 1 << 31
            }
        };
        const BINS: usize = 1 << 16;
        // One histogram per worker's run of chunks (not one per chunk:
        // a histogram is as large as a chunk), then merged.
        let hist = vals
            .par_chunks(1 << 16)
            .fold(
                || vec![0usize; BINS],
                |mut h, c| {
                    for &x in c {
                        h[(key(x) >> 16) as usize] += 1;
                    }
                    h
                },
            )
            .reduce(
                || vec![0usize; BINS],
                |mut a, b| {
                    for (x, y) in a.iter_mut().zip(&b) {
                        *x += y;
                    }
                    a
                },
            );
        let n = vals.len();
        fs.map(|f| {
            let k = ((n - 1) as f64 * f) as usize;
            // The bin holding rank k, and the ranks below it.
            let (mut below, mut bin) = (0usize, 0usize);
            while below + hist[bin] <= k {
                below += hist[bin];
                bin += 1;
            }
            let mut inside: Vec<f32> = vals
                .par_iter()
                .copied()
                .filter(|&x| (key(x) >> 16) as usize == bin)
                .collect();
            *inside.select_nth_unstable_by(k - below, f32::total_cmp).1
        })
    }
}

impl TotalOrder for f64 {
    fn total_cmp_ref(a: &Self, b: &Self) -> std::cmp::Ordering {
        a.total_cmp(b)
    }
}

/// Values whose c-means terms are computed together before they are summed.
const FCM_BLOCK: usize = 64;

/// Values per chunk of [`fcm2`]'s sums.
const FCM_CHUNK: usize = 1 << 14;

/// Fuzzy c-means with two classes on scalar values; returns the centres
/// (low, high) and the iterations used. Starts from the 25th and 75th
/// percentiles.
pub fn fcm2(vals: &[f64], opts: &ClassifyOptions) -> ([f64; 2], usize) {
    fcm2_of(vals, opts)
}

/// The values `sorted[(n - 1) * f]` of a sorted copy of `vals` for the
/// fractions `fs` (ascending), by selection (linear time) instead of a
/// sort: the same values, since the k-th smallest in `total_cmp` order is
/// one value whatever finds it.
fn quantiles<T: Copy + Send + Sync>(
    vals: &[T],
    fs: [f64; 2],
    cmp: fn(&T, &T) -> std::cmp::Ordering,
) -> [T; 2] {
    let mut work = vals.to_vec();
    let n = work.len();
    let k0 = ((n - 1) as f64 * fs[0]) as usize;
    let k1 = ((n - 1) as f64 * fs[1]) as usize;
    let (_, &mut a, upper) = work.select_nth_unstable_by(k0, cmp);
    // k1 >= k0: the k1-th smallest is the (k1 - k0 - 1)-th of the part
    // above the k0-th (or the k0-th itself).
    let b = if k1 == k0 {
        a
    } else {
        *upper.select_nth_unstable_by(k1 - k0 - 1, cmp).1
    };
    [a, b]
}

/// [`fcm2`] on values of either precision (each read as f64).
fn fcm2_of<T: TotalOrder + Into<f64>>(vals: &[T], opts: &ClassifyOptions) -> ([f64; 2], usize) {
    if vals.is_empty() {
        let a = Tissue::Adipose.mu_per_mm() as f64;
        let g = Tissue::Fibroglandular.mu_per_mm() as f64;
        return ([a, g], 0);
    }
    let [lo, hi] = T::quantiles(vals, [0.25, 0.75]);
    let mut c: [f64; 2] = [lo.into(), hi.into()];
    if c[1] - c[0] < 1e-9 {
        c[1] = c[0] + 1e-6;
    }
    let m = opts.fuzziness;
    for it in 1..=opts.max_iter {
        // The sums in fixed chunks, added in chunk order: the same centres
        // whatever the number of threads.
        let partial: Vec<[f64; 4]> = vals
            .par_chunks(FCM_CHUNK)
            .map(|chunk| fcm_chunk_sums(chunk, c, m))
            .collect();
        let (mut num, mut den) = ([0.0f64; 2], [0.0f64; 2]);
        for s in &partial {
            num[0] += s[0];
            den[0] += s[1];
            num[1] += s[2];
            den[1] += s[3];
        }
        let nc = [num[0] / den[0], num[1] / den[1]];
        let shift = (nc[0] - c[0]).abs().max((nc[1] - c[1]).abs());
        c = nc;
        if shift < opts.tol {
            return (c, it);
        }
    }
    (c, opts.max_iter)
}

/// One chunk's c-means sums `[sum w0 x, sum w0, sum w1 x, sum w1]` for the
/// centres `c` and fuzziness `m`, added in value order.
fn fcm_chunk_sums<T: Copy + Into<f64>>(chunk: &[T], c: [f64; 2], m: f64) -> [f64; 4] {
    let p = 2.0 / (m - 1.0);
    // x^e, by a product where e is 2 (the default fuzziness 2 gives p = 2
    // and m = 2; p is 2 exactly when m is 2).
    let pow = |x: f64, e: f64| if e == 2.0 { x * x } else { x.powf(e) };
    let mut s = [0.0f64; 4];
    // Each block's per-value terms first, elementwise (the compiler
    // vectorises them, divisions included), then the sums in value order:
    // the same operations on the same values as one value at a time, so
    // the same bits.
    let mut xs = [0.0f64; FCM_BLOCK];
    let mut ws = [[0.0f64; 2]; FCM_BLOCK];
    for block in chunk.chunks(FCM_BLOCK) {
        let terms = xs.iter_mut().zip(ws.iter_mut()).zip(block);
        // u_k = 1 / sum_j (d_k / d_j)^(2/(m-1)), w_k = u_k^m
        if m == 2.0 {
            // p = 2: products (libm's pow took most of the classification's
            // time)
            for ((xo, wo), &x) in terms {
                let x: f64 = x.into();
                let d0 = (x - c[0]).abs().max(1e-12);
                let d1 = (x - c[1]).abs().max(1e-12);
                let r = d0 / d1;
                let u0 = 1.0 / (1.0 + r * r);
                let u1 = 1.0 - u0;
                *xo = x;
                *wo = [u0 * u0, u1 * u1];
            }
        } else {
            for ((xo, wo), &x) in terms {
                let x: f64 = x.into();
                let d0 = (x - c[0]).abs().max(1e-12);
                let d1 = (x - c[1]).abs().max(1e-12);
                let u0 = 1.0 / (1.0 + pow(d0 / d1, p));
                let u1 = 1.0 - u0;
                *xo = x;
                *wo = [pow(u0, m), pow(u1, m)];
            }
        }
        for (&x, &[w0, w1]) in xs.iter().zip(&ws).take(block.len()) {
            s[0] += w0 * x;
            s[1] += w0;
            s[2] += w1 * x;
            s[3] += w1;
        }
    }
    s
}

/// Density estimates of a classified volume.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Density {
    /// Glandularity by mass from the labels (paper eq. 4).
    pub glandularity_labels: f64,
    /// Glandularity by mass from partial volumes.
    pub glandularity_partial_volume: f64,
    /// Fibroglandular volume from the labels, cm^3.
    pub fibroglandular_cm3: f64,
    /// Fibroglandular volume from partial volumes, cm^3.
    pub fibroglandular_partial_volume_cm3: f64,
    /// Breast volume (skin included), cm^3.
    pub breast_cm3: f64,
}

/// Both density estimates. `mu` is the reconstruction the labels came from;
/// the partial-volume fraction of a non-skin breast voxel is
/// `clamp((mu - mu_a) / (mu_g - mu_a), 0, 1)` with the materials' 20 keV
/// values.
pub fn density(mu: &[f32], labels: &[u8], voxel_mm: f64) -> Density {
    let mut c = [0u64; 5];
    for &l in labels {
        c[(l as usize).min(4)] += 1;
    }
    let ng = c[3] + c[4];
    let mut pv = PartialVolumeMass::default();
    for (&v, &l) in mu.iter().zip(labels) {
        if PartialVolumeMass::counts(l) {
            pv.add(v as f64, 1);
        }
    }
    let vox_cm3 = voxel_mm.powi(3) / 1000.0;
    Density {
        glandularity_labels: glandularity(ng, c[1]).unwrap_or(0.0),
        glandularity_partial_volume: pv.glandularity().unwrap_or(0.0),
        fibroglandular_cm3: ng as f64 * vox_cm3,
        fibroglandular_partial_volume_cm3: pv.glandular_voxels * vox_cm3,
        breast_cm3: (c[1] + c[2] + c[3] + c[4]) as f64 * vox_cm3,
    }
}

/// The partial-volume estimate's sums: each non-skin breast voxel's
/// fibroglandular fraction `clamp((mu - mu_a) / (mu_g - mu_a), 0, 1)` from
/// its attenuation (the materials' 20 keV values), summed by mass and by
/// volume. [`density`], [`column_glandularity`] and the evaluation's
/// estimates by region add to one.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PartialVolumeMass {
    /// Fibroglandular mass, voxel volumes x g/cm^3.
    pub glandular: f64,
    /// Adipose mass, voxel volumes x g/cm^3.
    pub adipose: f64,
    /// Fibroglandular volume, voxels (the fractions' sum).
    pub glandular_voxels: f64,
    /// Voxels added.
    pub voxels: usize,
}

impl PartialVolumeMass {
    /// Whether a voxel of label `label` is in the estimate: adipose,
    /// fibroglandular and ligament (skin and air are not).
    pub fn counts(label: u8) -> bool {
        matches!(label, 1 | 3 | 4)
    }

    /// The fibroglandular fraction of attenuation `mu` (1/mm), clamped to
    /// 0..1.
    pub fn fraction(mu: f64) -> f64 {
        let (ma, mg) = (
            Tissue::Adipose.mu_per_mm() as f64,
            Tissue::Fibroglandular.mu_per_mm() as f64,
        );
        ((mu - ma) / (mg - ma)).clamp(0.0, 1.0)
    }

    /// Add `n` voxels whose (mean) attenuation is `mu`.
    pub fn add(&mut self, mu: f64, n: usize) {
        let f = Self::fraction(mu);
        let w = n as f64;
        self.glandular += w * f * Tissue::Fibroglandular.density_g_cm3();
        self.adipose += w * (1.0 - f) * Tissue::Adipose.density_g_cm3();
        self.glandular_voxels += w * f;
        self.voxels += n;
    }

    /// Glandularity by mass, or `None` without mass.
    pub fn glandularity(&self) -> Option<f64> {
        (self.glandular + self.adipose > 0.0)
            .then(|| self.glandular / (self.glandular + self.adipose))
    }
}

/// Glandularity by mass from each column's attenuation along the beam
/// (issue #48): a tomosynthesis reconstruction is exact across the x-rays
/// and blurred along them (the limited angle leaves the frequencies along
/// the beam unmeasured), so tissue it misplaces in height stays in its
/// column (lateral, depth), whose sum the central view measures. For every
/// column holding non-skin breast voxels (labels adipose, fibroglandular,
/// ligament) the whole column's attenuation (every row of the volume,
/// whatever its label: what leaked into the air above or below the breast
/// counts), less the skin voxels' nominal attenuation, is spread over those
/// voxels: their mean attenuation gives the column's fibroglandular
/// fraction `f = (m - mu_a) / (mu_g - mu_a)`, clamped to 0..1 per column
/// (not per voxel: a voxel that reads above the fibroglandular value keeps
/// its excess for its column's fatter voxels). The breast's height in each
/// column is the labels'. `dims = [lateral, vertical, depth]`.
pub fn column_glandularity(mu: &[f32], labels: &[u8], dims: [usize; 3]) -> Option<f64> {
    let [nx, ny, nz] = dims;
    if mu.len() != nx * ny * nz || labels.len() != mu.len() {
        return None;
    }
    let ms = Tissue::Skin.mu_per_mm() as f64;
    let skin = Tissue::Skin.label();
    let mut pv = PartialVolumeMass::default();
    for z in 0..nz {
        for x in 0..nx {
            let (mut sum, mut n) = (0.0f64, 0usize);
            for y in 0..ny {
                let i = (z * ny + y) * nx + x;
                let l = labels[i];
                if l == skin {
                    sum -= ms;
                } else if PartialVolumeMass::counts(l) {
                    n += 1;
                }
                sum += mu[i] as f64;
            }
            if n > 0 {
                pv.add(sum / n as f64, n);
            }
        }
    }
    pv.glandularity()
}

/// The compressed thickness a calibration's thickness term is centred on,
/// mm.
pub const CALIBRATION_THICKNESS_REF_MM: f64 = 50.0;

/// A linear calibration of a glandularity estimate, `G = offset + slope *
/// estimate + per_mm * (T - 50 mm)` (clamped to 0..1; `T` the compressed
/// thickness; `per_mm` 0 unless fit with [`Self::fit_with_thickness`]), fit by
/// least squares on phantoms whose truth
/// is known: the validation phantoms of the reconstructor it corrects, never
/// the test set. It removes a systematic, density-dependent error of the
/// reconstruction (blur reads fatty breasts slightly dense) and, with the
/// thickness term, a size-dependent one (small, thin breasts read dense:
/// eval/README.md, "The clinical counts' noise"); it cannot remove noise.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
pub struct GlandularityCalibration {
    /// Intercept (glandularity fraction).
    pub offset: f64,
    /// Slope.
    pub slope: f64,
    /// Per mm of compressed thickness above [`CALIBRATION_THICKNESS_REF_MM`]
    /// (glandularity fraction; absent, 0, in the files written before it).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub per_mm: f64,
    /// The compressed thicknesses the thickness term was fit on, mm: it is
    /// applied within them widened by [`CALIBRATION_THICKNESS_MARGIN_MM`]
    /// and held at that edge beyond (never extrapolated far). `None`: no
    /// limit (a calibration without the term).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub thickness_range_mm: Option<[f64; 2]>,
}

/// How far beyond the thicknesses it was fit on a calibration's thickness
/// term is extrapolated, mm.
pub const CALIBRATION_THICKNESS_MARGIN_MM: f64 = 5.0;

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

impl GlandularityCalibration {
    /// The calibrated glandularity of an estimate for a breast compressed
    /// to `thickness_mm`.
    pub fn apply(&self, estimate: f64, thickness_mm: f64) -> f64 {
        let t = match self.thickness_range_mm {
            Some([lo, hi]) => thickness_mm.clamp(
                lo - CALIBRATION_THICKNESS_MARGIN_MM,
                hi + CALIBRATION_THICKNESS_MARGIN_MM,
            ),
            None => thickness_mm,
        };
        (self.offset + self.slope * estimate + self.per_mm * (t - CALIBRATION_THICKNESS_REF_MM))
            .clamp(0.0, 1.0)
    }

    /// Least-squares fit of `truth = offset + slope * estimate + per_mm *
    /// (thickness - 50 mm)`; needs at least five cases whose estimates span
    /// more than 1 percentage point and whose thicknesses span more than 10
    /// mm, all finite.
    pub fn fit_with_thickness(
        estimates: &[f64],
        truths: &[f64],
        thicknesses_mm: &[f64],
    ) -> Result<Self, TissueError> {
        let n = estimates.len();
        if n != truths.len() || n != thicknesses_mm.len() || n < 5 {
            return Err(TissueError::Calibration(format!(
                "{n} estimates, {} truths and {} thicknesses: need at least 5 cases of each",
                truths.len(),
                thicknesses_mm.len()
            )));
        }
        // The estimates' checks are the two-parameter fit's.
        Self::fit(estimates, truths)?;
        if thicknesses_mm.iter().any(|v| !v.is_finite()) {
            return Err(TissueError::Calibration("a thickness is not finite".into()));
        }
        let (lo, hi) = thicknesses_mm
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &t| {
                (a.min(t), b.max(t))
            });
        if hi - lo <= 10.0 {
            return Err(TissueError::Calibration(format!(
                "the thicknesses span {:.1} mm: too narrow to fit a thickness term",
                hi - lo
            )));
        }
        // Normal equations of [1, e, t - 50], solved by Gaussian elimination
        // with partial pivoting.
        let mut m = [[0.0f64; 4]; 3];
        for ((&e, &y), &t) in estimates.iter().zip(truths).zip(thicknesses_mm) {
            let x = [1.0, e, t - CALIBRATION_THICKNESS_REF_MM];
            for i in 0..3 {
                for j in 0..3 {
                    m[i][j] += x[i] * x[j];
                }
                m[i][3] += x[i] * y;
            }
        }
        for c in 0..3 {
            let p = (c..3)
                .max_by(|&a, &b| m[a][c].abs().total_cmp(&m[b][c].abs()))
                .unwrap_or(c);
            m.swap(c, p);
            if m[c][c].abs() < 1e-12 {
                return Err(TissueError::Calibration(
                    "the estimates and the thicknesses are collinear: no thickness term can be fit"
                        .into(),
                ));
            }
            let pivot = m[c];
            for (r, row) in m.iter_mut().enumerate() {
                if r != c {
                    let f = row[c] / pivot[c];
                    for (x, p) in row.iter_mut().zip(pivot).skip(c) {
                        *x -= f * p;
                    }
                }
            }
        }
        Ok(Self {
            offset: m[0][3] / m[0][0],
            slope: m[1][3] / m[1][1],
            per_mm: m[2][3] / m[2][2],
            thickness_range_mm: Some([lo, hi]),
        })
    }

    /// Least-squares fit of `truth = offset + slope * estimate`; needs at
    /// least three pairs spanning more than 1 percentage point, all finite.
    pub fn fit(estimates: &[f64], truths: &[f64]) -> Result<Self, TissueError> {
        let n = estimates.len();
        if n != truths.len() || n < 3 {
            return Err(TissueError::Calibration(format!(
                "{n} estimates and {} truths: need at least 3 pairs",
                truths.len()
            )));
        }
        if estimates.iter().chain(truths).any(|v| !v.is_finite()) {
            return Err(TissueError::Calibration("a value is not finite".into()));
        }
        let (mx, my) = (
            estimates.iter().sum::<f64>() / n as f64,
            truths.iter().sum::<f64>() / n as f64,
        );
        let sxx: f64 = estimates.iter().map(|x| (x - mx).powi(2)).sum();
        let sxy: f64 = estimates
            .iter()
            .zip(truths)
            .map(|(x, y)| (x - mx) * (y - my))
            .sum();
        let range = estimates.iter().fold(f64::NEG_INFINITY, |a, &b| a.max(b))
            - estimates.iter().fold(f64::INFINITY, |a, &b| a.min(b));
        if range <= 0.01 {
            return Err(TissueError::Calibration(format!(
                "the estimates span {:.2} percentage points: too narrow to fit a slope",
                100.0 * range
            )));
        }
        let slope = sxy / sxx;
        Ok(Self {
            offset: my - slope * mx,
            slope,
            per_mm: 0.0,
            thickness_range_mm: None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The column estimate reads a column's composition wherever in its
    /// height the attenuation sits, in the air above it or below the skin;
    /// and it reads a uniform mixture exactly.
    #[test]
    fn the_column_estimate_ignores_where_in_height_the_attenuation_sits() {
        // One column of 6 rows: skin, 4 breast voxels (2 fat, 2 gland), air.
        let labels = [2u8, 1, 1, 3, 3, 0];
        let exact = [S, A, A, G, G, 0.0];
        let g = column_glandularity(&exact, &labels, [1, 6, 1]).unwrap();
        let want = glandularity(2, 2).unwrap();
        assert!((g - want).abs() < 1e-6, "{g} against {want}");
        // The same attenuation, the gland smeared upward into the air and
        // the skin: the voxel estimate falls, the column's does not.
        let smeared = [S + 0.01, A, A, G - 0.01, G - 0.02, 0.02];
        let moved = column_glandularity(&smeared, &labels, [1, 6, 1]).unwrap();
        assert!((moved - want).abs() < 1e-6, "{moved} against {want}");
        let voxelwise = density(&smeared, &labels, 1.0).glandularity_partial_volume;
        assert!(voxelwise < want - 0.05);
        // A uniform 30 % mixture in two columns reads 30 % by volume.
        let m = A + 0.3 * (G - A);
        let g = column_glandularity(&[m; 4], &[1; 4], [2, 2, 1]).unwrap();
        let (ra, rg) = (
            Tissue::Adipose.density_g_cm3(),
            Tissue::Fibroglandular.density_g_cm3(),
        );
        let by_mass = 0.3 * rg / (0.3 * rg + 0.7 * ra);
        assert!((g - by_mass).abs() < 1e-6);
        // No breast: no estimate; a size mismatch: none either.
        assert_eq!(column_glandularity(&[0.0; 2], &[0; 2], [1, 2, 1]), None);
        assert_eq!(column_glandularity(&[0.0; 3], &[0; 2], [1, 2, 1]), None);
    }

    const A: f32 = 0.0512;
    const G: f32 = 0.0798;
    const S: f32 = 0.0854;

    /// A box of breast inside air: 1-voxel skin shell (except the chest wall),
    /// interior split into an adipose half and a glandular half.
    /// Voxel `i`'s coordinates and its depth in layers below the outer
    /// faces of `slab(dims, margin)` (the outer layer 1; the chest wall,
    /// z = 0, is no outer face); for voxels inside the slab only (outside
    /// it the subtraction underflows).
    fn slab_depth(i: usize, [nx, ny, nz]: [usize; 3], margin: usize) -> ([usize; 3], usize) {
        let (x, y, z) = (i % nx, (i / nx) % ny, i / (nx * ny));
        let (xl, yl, zl) = (nx - margin - 1, ny - margin - 1, nz - margin - 1);
        let d = 1 + (x - margin).min(xl - x).min(y).min(yl - y).min(zl - z);
        ([x, y, z], d)
    }

    fn slab(dims: [usize; 3], margin: usize) -> (Vec<f32>, Vec<u8>) {
        let [nx, ny, nz] = dims;
        let mut mu = vec![0f32; nx * ny * nz];
        let mut truth = vec![0u8; nx * ny * nz];
        for z in 0..nz - margin {
            for y in 0..ny - margin {
                for x in margin..nx - margin {
                    let i = (z * ny + y) * nx + x;
                    let shell = x == margin
                        || x == nx - margin - 1
                        || y == 0
                        || y == ny - margin - 1
                        || z == nz - margin - 1;
                    let (v, l) = if shell {
                        (S, 2)
                    } else if x < nx / 2 {
                        (A, 1)
                    } else {
                        (G, 3)
                    };
                    mu[i] = v;
                    truth[i] = l;
                }
            }
        }
        (mu, truth)
    }

    #[test]
    fn two_tissue_slab_is_classified_exactly() {
        let dims = [20, 12, 10];
        let (mu, truth) = slab(dims, 2);
        // The paper's growth, and the default shell at a voxel of 2 mm (one
        // layer: the slab's skin).
        let c = classify(&mu, dims, 1.0, &ClassifyOptions::paper()).unwrap();
        assert_eq!(c.labels, truth);
        let shell = classify(&mu, dims, 2.0, &ClassifyOptions::default()).unwrap();
        assert_eq!(shell.labels, truth);
        assert!((c.centres[0] - A as f64).abs() < 1e-6 && (c.centres[1] - G as f64).abs() < 1e-6);
        let d = density(&mu, &c.labels, 1.0);
        let ng = truth.iter().filter(|&&l| l == 3).count() as f64;
        let na = truth.iter().filter(|&&l| l == 1).count() as f64;
        let want = ng * 1.04 / (ng * 1.04 + na * 0.93);
        assert!((d.glandularity_labels - want).abs() < 1e-12);
        assert!((d.glandularity_partial_volume - want).abs() < 1e-6);
    }

    /// A reconstruction blurs the thin skin below the fibroglandular value.
    /// Where a glandular block touches the skin, the paper's unbounded
    /// growth (through voxels >= the seed mean) runs into the whole block;
    /// the depth bound stops it at the skin's depth.
    #[test]
    fn the_skin_depth_bound_stops_the_growth_into_glandular_tissue() {
        let dims = [40, 24, 20];
        let (mut mu, truth) = slab(dims, 2);
        let [nx, ny, _] = dims;
        // Blurred skin: 0.075 /mm, under the glandular 0.0798.
        for (v, &l) in mu.iter_mut().zip(&truth) {
            if l == 2 {
                *v = 0.075;
            }
        }
        // The slab's glandular half touches the skin on four faces.
        let count = |labels: &[u8], l: u8| labels.iter().filter(|&&v| v == l).count();
        let paper = classify(&mu, dims, 0.8, &ClassifyOptions::paper()).unwrap();
        assert!(
            (0..mu.len()).all(|i| truth[i] != 3 || paper.labels[i] == 2),
            "unbounded growth takes every glandular voxel"
        );
        // What is left is one population (adipose), read as adipose.
        assert_eq!(count(&paper.labels, 3), 0);
        let grow = ClassifyOptions {
            skin_max_mm: Some(2.4),
            skin_rule: SkinRule::Grow,
            ..ClassifyOptions::default()
        };
        let bounded = classify(&mu, dims, 0.8, &grow).unwrap();
        assert_eq!(grow.skin_max_layers(0.8), 3);
        assert_eq!(ClassifyOptions::default().skin_max_layers(0.8), 2);
        // Bounded: the skin shell plus at most the two glandular layers
        // below it; every glandular voxel deeper than 3 layers stays.
        let lost = count(&truth, 3) - count(&bounded.labels, 3);
        let deep = (0..mu.len())
            .filter(|&i| truth[i] == 3 && bounded.labels[i] != 3)
            .all(|i| {
                let (x, y, z) = (i % nx, (i / nx) % ny, i / (nx * ny));
                y <= 2 || x + 3 >= nx - 2 || z + 3 >= dims[2] - 2 || y + 3 >= ny - 2
            });
        assert!(lost > 0 && deep, "lost {lost}");
        assert!(count(&bounded.labels, 3) > count(&truth, 3) / 2);
        // No bound at a voxel of 1 mm and a bound of 1 mm: the seeds alone.
        let o = ClassifyOptions {
            skin_max_mm: Some(1.0),
            ..ClassifyOptions::default()
        };
        assert_eq!(o.skin_max_layers(1.0), 1);
        assert_eq!(ClassifyOptions::paper().skin_max_layers(0.8), usize::MAX);
        assert_eq!(classify(&mu, dims, 0.0, &o), Err(TissueError::Voxel(0.0)));
    }

    /// The shell rule takes every breast voxel within the bound, whatever
    /// its value, and nothing deeper.
    #[test]
    fn the_skin_shell_is_the_bound_deep() {
        let dims = [20, 12, 10];
        let (mu, _) = slab(dims, 2);
        let o = ClassifyOptions {
            skin_max_mm: Some(1.6),
            skin_rule: SkinRule::Shell,
            ..ClassifyOptions::default()
        };
        let c = classify(&mu, dims, 0.8, &o).unwrap();
        for (i, &l) in c.labels.iter().enumerate() {
            if mu[i] == 0.0 {
                assert_eq!(l, 0);
                continue;
            }
            // Depth in layers below the outer faces (x: 2..=17, y: 0..=9,
            // z: ..=7; the chest wall z = 0 is not an outer face).
            let ([x, y, z], depth) = slab_depth(i, dims, 2);
            assert_eq!(
                l == 2,
                depth <= 2,
                "voxel {x},{y},{z} depth {depth} label {l}"
            );
        }
        // Without a bound the shell rule is the growth rule.
        let unbounded = ClassifyOptions {
            skin_max_mm: None,
            skin_rule: SkinRule::Shell,
            ..ClassifyOptions::default()
        };
        assert_eq!(
            classify(&mu, dims, 0.8, &unbounded).unwrap().labels,
            classify(&mu, dims, 0.8, &ClassifyOptions::paper())
                .unwrap()
                .labels
        );
    }

    /// The fat band: the layers under the skin's shell, as deep as the band,
    /// are adipose whatever their value and left out of the fit; the skin
    /// and everything deeper are as without the band; a band needs a skin
    /// bound and a depth >= 0.
    #[test]
    fn the_fat_band_is_adipose_under_the_skin_and_nothing_else() {
        let dims = [20, 12, 10];
        let (mu, truth) = slab(dims, 2);
        let shell = ClassifyOptions::default();
        let band = ClassifyOptions {
            fat_band_mm: Some(1.6),
            ..shell
        };
        assert_eq!(band.fat_band_layers(0.8), 2);
        assert_eq!(shell.fat_band_layers(0.8), 0);
        let plain = classify(&mu, dims, 0.8, &shell).unwrap();
        let c = classify(&mu, dims, 0.8, &band).unwrap();
        let mut in_band = 0;
        for (i, &l) in c.labels.iter().enumerate() {
            if mu[i] == 0.0 {
                assert_eq!(l, 0);
                continue;
            }
            // Layers below the outer faces, as in the shell's test.
            let ([x, y, z], depth) = slab_depth(i, dims, 2);
            match depth {
                1..=2 => assert_eq!(l, 2, "skin at {x},{y},{z}"),
                3..=4 => {
                    assert_eq!(l, 1, "band at {x},{y},{z}");
                    in_band += usize::from(truth[i] == 3);
                }
                _ => assert_eq!(
                    l == 3,
                    mu[i] as f64 >= split_point(c.centres),
                    "deeper at {x},{y},{z}"
                ),
            }
        }
        assert!(in_band > 0, "the slab puts gland in the band");
        // The deeper voxels keep their classes (the fit's centres are those
        // of the deeper voxels, one population each here).
        let deep_gland = |labels: &[u8]| {
            (0..labels.len())
                .filter(|&i| mu[i] != 0.0 && slab_depth(i, dims, 2).1 > 4 && labels[i] == 3)
                .count()
        };
        assert_eq!(deep_gland(&c.labels), deep_gland(&plain.labels));
        // A band of 0 mm is no band.
        let zero = ClassifyOptions {
            fat_band_mm: Some(0.0),
            ..shell
        };
        assert_eq!(classify(&mu, dims, 0.8, &zero).unwrap(), plain);
        for bad in [
            ClassifyOptions {
                fat_band_mm: Some(-0.8),
                ..shell
            },
            ClassifyOptions {
                fat_band_mm: Some(f64::NAN),
                ..shell
            },
            ClassifyOptions {
                fat_band_mm: Some(0.8),
                ..ClassifyOptions::paper()
            },
        ] {
            assert!(
                matches!(classify(&mu, dims, 0.8, &bad), Err(TissueError::Options(_))),
                "{bad:?}"
            );
        }
        // The JSON of a rule without a band is the one written before bands
        // existed, and reads back.
        let j = serde_json::to_string(&shell).unwrap();
        assert!(!j.contains("fat_band"), "{j}");
        assert_eq!(serde_json::from_str::<ClassifyOptions>(&j).unwrap(), shell);
        let j = serde_json::to_string(&band).unwrap();
        assert_eq!(serde_json::from_str::<ClassifyOptions>(&j).unwrap(), band);
    }

    /// The fit recovers an exact line, and refuses what cannot be fit.
    #[test]
    fn calibration_fits_a_plane_with_the_thickness() {
        let est = [0.05, 0.2, 0.4, 0.6, 0.3, 0.1];
        let t = [32.0, 70.0, 45.0, 58.0, 36.0, 64.0];
        let truth: Vec<f64> = est
            .iter()
            .zip(&t)
            .map(|(e, t)| -0.02 + 1.05 * e - 0.0004 * (t - 50.0))
            .collect();
        let c = GlandularityCalibration::fit_with_thickness(&est, &truth, &t).unwrap();
        assert!((c.offset + 0.02).abs() < 1e-12, "{c:?}");
        assert!((c.slope - 1.05).abs() < 1e-12, "{c:?}");
        assert!((c.per_mm + 0.0004).abs() < 1e-12, "{c:?}");
        assert!((c.apply(0.3, 60.0) - (-0.02 + 0.315 - 0.004)).abs() < 1e-12);
        // Fit on 32-70 mm: applied down to 27 mm and up to 75 mm, held there.
        assert_eq!(c.thickness_range_mm, Some([32.0, 70.0]));
        assert!((c.apply(0.3, 27.0) - (-0.02 + 0.315 + 0.0092)).abs() < 1e-12);
        assert_eq!(c.apply(0.3, 12.0), c.apply(0.3, 27.0));
        assert_eq!(c.apply(0.3, 150.0), c.apply(0.3, 75.0));
        // Thicknesses too alike, too few cases, a NaN: refused.
        let flat = [50.0, 52.0, 55.0, 51.0, 58.0, 53.0];
        for bad in [
            GlandularityCalibration::fit_with_thickness(&est, &truth, &flat),
            GlandularityCalibration::fit_with_thickness(&est[..4], &truth[..4], &t[..4]),
            GlandularityCalibration::fit_with_thickness(&est, &truth, &[f64::NAN; 6]),
        ] {
            assert!(matches!(bad, Err(TissueError::Calibration(_))), "{bad:?}");
        }
        // A file written before the term reads as without it.
        let old: GlandularityCalibration =
            serde_json::from_str(r#"{"offset": 0.1, "slope": 1.0}"#).unwrap();
        assert_eq!(old.per_mm, 0.0);
        assert_eq!(old.apply(0.2, 70.0), old.apply(0.2, 30.0));
        assert!(!serde_json::to_string(&old).unwrap().contains("per_mm"));
    }

    #[test]
    fn calibration_fits_a_line_and_clamps() {
        let est = [0.05, 0.2, 0.4, 0.6];
        let truth: Vec<f64> = est.iter().map(|e| -0.015 + 1.03 * e).collect();
        let c = GlandularityCalibration::fit(&est, &truth).unwrap();
        assert!((c.offset + 0.015).abs() < 1e-12 && (c.slope - 1.03).abs() < 1e-12);
        assert_eq!(c.apply(0.0, 42.0), 0.0);
        assert_eq!(c.apply(1.0, 42.0), 1.0);
        assert!((c.apply(0.5, 42.0) - (-0.015 + 0.515)).abs() < 1e-12);
        for bad in [
            GlandularityCalibration::fit(&est[..2], &truth[..2]),
            GlandularityCalibration::fit(&est, &truth[..3]),
            GlandularityCalibration::fit(&[0.3, 0.3, 0.305], &[0.3, 0.31, 0.32]),
            GlandularityCalibration::fit(&[0.1, f64::NAN, 0.5], &[0.1, 0.2, 0.5]),
        ] {
            assert!(matches!(bad, Err(TissueError::Calibration(_))), "{bad:?}");
        }
    }

    #[test]
    fn partial_volume_reads_mixtures() {
        // A blurred volume where every interior voxel is 30 % glandular by
        // volume: labels say 0 or 1, partial volumes say 0.3 by volume.
        let dims = [12, 8, 6];
        let (mut mu, _) = slab(dims, 1);
        let mix = A + 0.3 * (G - A);
        let c0 = classify(&mu, dims, 1.0, &ClassifyOptions::default()).unwrap();
        for (v, &l) in mu.iter_mut().zip(&c0.labels) {
            if l == 1 || l == 3 {
                *v = mix;
            }
        }
        let labels: Vec<u8> = c0
            .labels
            .iter()
            .map(|&l| if l == 3 { 1 } else { l })
            .collect();
        let d = density(&mu, &labels, 0.5);
        let want = 0.3 * 1.04 / (0.3 * 1.04 + 0.7 * 0.93);
        assert!(
            (d.glandularity_partial_volume - want).abs() < 1e-6,
            "{}",
            d.glandularity_partial_volume
        );
        assert_eq!(d.glandularity_labels, 0.0);
        let interior = labels.iter().filter(|&&l| l == 1).count() as f64;
        assert!(
            (d.fibroglandular_partial_volume_cm3 - 0.3 * interior * 0.125 / 1000.0).abs() < 1e-9
        );
        assert!(
            (d.breast_cm3 - labels.iter().filter(|&&l| l != 0).count() as f64 * 0.125 / 1000.0)
                .abs()
                < 1e-12
        );
    }

    #[test]
    fn fcm_separates_two_noisy_populations() {
        let mut v = Vec::new();
        let mut s = 1u64;
        let mut r = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1);
            ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        for _ in 0..3000 {
            v.push(0.0512 + 0.004 * r());
        }
        for _ in 0..1000 {
            v.push(0.0798 + 0.004 * r());
        }
        let (c, it) = fcm2(&v, &ClassifyOptions::default());
        assert!(
            (c[0] - 0.0512).abs() < 1e-3 && (c[1] - 0.0798).abs() < 1e-3,
            "{c:?}"
        );
        assert!(it > 1 && it < 200);
    }

    /// `n` attenuation-like values: every `high_every`-th about the
    /// fibroglandular value, the others about the adipose one, spread
    /// uniformly over `spread` (a linear congruential sequence from `seed`).
    fn two_populations(n: usize, seed: u64, high_every: usize, spread: f64) -> Vec<f64> {
        let mut s = seed;
        (0..n)
            .map(|i| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1);
                let u = ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5;
                let centre = if i % high_every == 0 { 0.0798 } else { 0.0512 };
                centre + spread * u
            })
            .collect()
    }

    /// `f` in a rayon pool of `threads` threads.
    fn in_pool<R: Send>(threads: usize, f: impl FnOnce() -> R + Send) -> R {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(f)
    }

    #[test]
    fn fcm_centres_do_not_depend_on_the_threads() {
        // Several chunks of sums (FCM_CHUNK values each) and a partial one.
        let v = two_populations(3 * FCM_CHUNK + 1234, 7, 3, 0.004);
        let run = |threads: usize, opts: &ClassifyOptions| in_pool(threads, || fcm2(&v, opts));
        for fuzziness in [2.0, 1.7] {
            let opts = ClassifyOptions {
                fuzziness,
                ..ClassifyOptions::default()
            };
            let one = run(1, &opts);
            assert_eq!(one, run(2, &opts), "fuzziness {fuzziness}");
            assert_eq!(one, run(5, &opts), "fuzziness {fuzziness}");
            let (c, it) = one;
            assert!(
                (c[0] - 0.0512).abs() < 1e-3 && (c[1] - 0.0798).abs() < 1e-3,
                "{c:?}"
            );
            assert!(it > 1 && it < opts.max_iter, "{it}");
        }
    }

    /// The selection gives the sorted copy's values: ties, negative zero,
    /// one and two values, both precisions; and fcm2 starts from them (f32
    /// and f64 values of the same numbers give the same centres).
    #[test]
    fn quantiles_are_the_sorted_values_and_f32_reads_as_f64() {
        let mut s = 3u64;
        let mut r = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1);
            (s >> 40) as f32 / 16.0 - 300.0
        };
        for n in [1usize, 2, 3, 4, 7, 100, 1001] {
            let mut v: Vec<f32> = (0..n).map(|_| r()).collect();
            if n > 3 {
                v[1] = v[0]; // a tie
                v[2] = -0.0;
                v[3] = 0.0;
            }
            let mut sorted = v.clone();
            sorted.sort_by(|a, b| a.total_cmp(b));
            for fs in [[0.25, 0.75], [0.0, 1.0], [0.5, 0.5], [0.1, 0.9]] {
                let k = |f: f64| sorted[((n - 1) as f64 * f) as usize];
                let want = [k(fs[0]), k(fs[1])].map(f32::to_bits);
                let got = quantiles(&v, fs, f32::total_cmp_ref);
                assert_eq!(got.map(f32::to_bits), want, "{n} {fs:?}");
                // f32's own: the histogram, then a selection in one bin
                let got = <f32 as TotalOrder>::quantiles(&v, fs);
                assert_eq!(got.map(f32::to_bits), want, "{n} {fs:?}, histogram");
            }
            // attenuation-like values: many in each bin of the histogram
            let narrow: Vec<f32> = v.iter().map(|&x| 0.05 + x * 1e-9).collect();
            let mut sorted = narrow.clone();
            sorted.sort_by(|a, b| a.total_cmp(b));
            let k = |f: f64| sorted[((n - 1) as f64 * f) as usize].to_bits();
            let got = <f32 as TotalOrder>::quantiles(&narrow, [0.25, 0.75]);
            assert_eq!(got.map(f32::to_bits), [k(0.25), k(0.75)], "{n} narrow");
            let v64: Vec<f64> = v.iter().map(|&x| x as f64).collect();
            let opts = ClassifyOptions::default();
            assert_eq!(fcm2_of(&v, &opts), fcm2(&v64, &opts), "{n} values");
        }
    }

    /// The blocked c-means sums are the one-value-at-a-time loop's to the
    /// bit (a transcription of it here): both fuzziness paths, blocks with
    /// a partial tail, centres on both sides of values.
    #[test]
    fn fcm_blocks_give_the_one_at_a_time_sums() {
        let reference = |vals: &[f64], c: [f64; 2], m: f64| -> [f64; 4] {
            let p = 2.0 / (m - 1.0);
            let pow = |x: f64, e: f64| if e == 2.0 { x * x } else { x.powf(e) };
            let mut s = [0.0f64; 4];
            for &x in vals {
                let d0 = (x - c[0]).abs().max(1e-12);
                let d1 = (x - c[1]).abs().max(1e-12);
                let u0 = 1.0 / (1.0 + pow(d0 / d1, p));
                let u1 = 1.0 - u0;
                let (w0, w1) = (pow(u0, m), pow(u1, m));
                s[0] += w0 * x;
                s[1] += w0;
                s[2] += w1 * x;
                s[3] += w1;
            }
            s
        };
        let v = two_populations(3 * FCM_BLOCK + 17, 5, 4, 0.006);
        for m in [2.0, 1.7, 2.5] {
            for c in [[0.05, 0.08], [0.0513, 0.0799], [0.06, 0.061]] {
                for n in [1, FCM_BLOCK - 1, FCM_BLOCK, FCM_BLOCK + 1, v.len()] {
                    let (want, got) = (reference(&v[..n], c, m), fcm_chunk_sums(&v[..n], c, m));
                    assert_eq!(
                        got.map(f64::to_bits),
                        want.map(f64::to_bits),
                        "m {m}, c {c:?}, {n} values"
                    );
                }
            }
        }
    }

    /// The whole classification does not depend on the pool's threads.
    #[test]
    fn classification_does_not_depend_on_the_threads() {
        let dims = [23, 17, 19];
        let (mut mu, _) = slab(dims, 3);
        let mut s = 11u64;
        for v in mu.iter_mut().filter(|v| **v > 0.0) {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1);
            *v += 0.01 * (((s >> 11) as f32 / (1u64 << 53) as f32) - 0.5);
        }
        let run = |threads: usize| {
            in_pool(threads, || {
                classify(&mu, dims, 0.5, &ClassifyOptions::default()).unwrap()
            })
        };
        let one = run(1);
        for t in [2, 3] {
            let other = run(t);
            assert_eq!(one.labels, other.labels, "{t} threads");
            assert_eq!(one.centres, other.centres, "{t} threads");
            assert_eq!(
                one.seed_mean.to_bits(),
                other.seed_mean.to_bits(),
                "{t} threads"
            );
        }
    }

    #[test]
    fn bad_volumes() {
        assert!(matches!(
            classify(&[0.0; 5], [2, 2, 2], 1.0, &ClassifyOptions::default()),
            Err(TissueError::Size { .. })
        ));
        assert!(matches!(
            classify(&[0.0; 8], [2, 2, 2], 1.0, &ClassifyOptions::default()),
            Err(TissueError::Empty(_))
        ));
    }
}
