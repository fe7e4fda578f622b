//! Procedural compressed-breast phantoms in the spirit of Lau et al. 2012 and
//! Bakic et al. 2011 (the paper's virtual phantoms).
//!
//! 1. **Shape.** In the detector plane the outline is a superellipse of
//!    half-width `W/2` at the chest wall and length `L` (chest wall to nipple).
//!    Each coronal cross-section is a rounded rectangle: full thickness `T`
//!    between the paddles with semicircular lateral edges; near the nipple the
//!    cross-section also rounds off vertically (radius `T/2`), as a compressed
//!    breast loses contact with the paddles at its front.
//! 2. **Skin.** The same shape shrunk by the skin thickness (about 1.5 mm)
//!    bounds the interior; the shell in between is skin. The chest-wall face
//!    (depth 0) has no skin.
//! 3. **Compartments and Cooper's ligaments.** Seeds on a jittered grid define
//!    adipose compartments (a Voronoi partition, flattened vertically by the
//!    compression). Voxels close to the boundary between two compartments,
//!    where the distances to the nearest and second-nearest seed nearly agree,
//!    become ligament, with the sheet thickness chosen so that ligaments take a
//!    set fraction of the interior.
//! 4. **Fibroglandular tissue.** A score per interior voxel adds a central
//!    envelope (glandular tissue concentrated behind the nipple, centrally), a
//!    power-law (1/f^beta) texture (Reiser and Nishikawa 2010, beta = 3) and a
//!    per-compartment offset (whole compartments tend to be dense or fatty). The
//!    highest-scoring voxels become fibroglandular: exactly as many as the
//!    requested glandularity by mass needs, ligaments counted as glandular.
//!
//! Everything is drawn from one seed; the same spec gives the same bytes.

use crate::noise::power_law;
use crate::{LabelVolume, PhantomError};
use dbt_geometry::Geometry;
use dbt_materials::Tissue;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Everything that defines one phantom.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhantomSpec {
    /// Compressed thickness `T`, mm.
    pub thickness_mm: f64,
    /// Chest wall to nipple distance `L`, mm.
    pub chest_to_nipple_mm: f64,
    /// Lateral width at the chest wall `W`, mm.
    pub width_mm: f64,
    /// Skin thickness, mm.
    pub skin_mm: f64,
    /// Requested glandularity by mass (0..1), ligaments counted as glandular.
    pub glandularity: f64,
    /// Isotropic voxel side, mm.
    pub voxel_mm: f64,
    /// Mean spacing of adipose compartments, mm.
    pub compartment_mm: f64,
    /// Largest fraction of the interior taken by Cooper's ligaments.
    pub ligament_fraction: f64,
    /// Power-law exponent of the fibroglandular texture.
    pub beta: f64,
    /// Random seed.
    pub seed: u64,
}

/// `value` within `[lo, hi]`, or an error naming `field`.
pub(crate) fn check(field: &'static str, value: f64, lo: f64, hi: f64) -> Result<(), PhantomError> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(())
    } else {
        Err(PhantomError::Parameter {
            field,
            value,
            reason: format!("must lie in [{lo}, {hi}]"),
        })
    }
}

impl PhantomSpec {
    /// A typical breast with the given seed and voxel: 50 mm thick, 110 mm chest
    /// wall to nipple, 150 mm wide, 1.5 mm skin, 20 % glandular.
    pub fn typical(voxel_mm: f64, seed: u64) -> Self {
        Self {
            thickness_mm: 50.0,
            chest_to_nipple_mm: 110.0,
            width_mm: 150.0,
            skin_mm: 1.5,
            glandularity: 0.20,
            voxel_mm,
            compartment_mm: 14.0,
            ligament_fraction: 0.03,
            beta: 3.0,
            seed,
        }
    }

    /// Reject impossible or unphysical parameters, naming the field.
    pub fn validate(&self) -> Result<(), PhantomError> {
        check("voxel_mm", self.voxel_mm, 0.05, 5.0)?;
        check("thickness_mm", self.thickness_mm, 10.0, 120.0)?;
        check("chest_to_nipple_mm", self.chest_to_nipple_mm, 20.0, 250.0)?;
        check(
            "width_mm",
            self.width_mm,
            2.0 * self.thickness_mm.min(60.0),
            400.0,
        )?;
        check("skin_mm", self.skin_mm, 0.0, self.thickness_mm / 4.0)?;
        check("glandularity", self.glandularity, 0.01, 0.95)?;
        check("compartment_mm", self.compartment_mm, 3.0, 60.0)?;
        check("ligament_fraction", self.ligament_fraction, 0.0, 0.2)?;
        check("beta", self.beta, 0.0, 4.0)?;
        if self.thickness_mm < 8.0 * self.voxel_mm {
            return Err(PhantomError::Parameter {
                field: "voxel_mm",
                value: self.voxel_mm,
                reason: format!("too coarse for a {} mm thick breast", self.thickness_mm),
            });
        }
        Ok(())
    }

    /// Voxel counts `[lateral, vertical, depth]` of the generated volume.
    pub fn dims(&self) -> [usize; 3] {
        let h = self.voxel_mm;
        [
            (self.width_mm / h).ceil() as usize,
            (self.thickness_mm / h).round() as usize,
            (self.chest_to_nipple_mm / h).ceil() as usize,
        ]
    }
}

/// Ranges from which random phantoms are drawn.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Population {
    /// Compressed thickness range, mm.
    pub thickness_mm: [f64; 2],
    /// Chest wall to nipple range, mm.
    pub chest_to_nipple_mm: [f64; 2],
    /// Widest breast allowed, mm (the image width less a margin).
    pub max_width_mm: f64,
    /// Glandularity range by mass.
    pub glandularity: [f64; 2],
    /// Voxel side, mm.
    pub voxel_mm: f64,
}

impl Population {
    /// Population seed of the fixed evaluation test set. Training datasets
    /// must use another seed (the exporter refuses this one), so that no test
    /// phantom is ever trained on.
    pub const TEST_SEED: u64 = 0x7E57_0000_0000_0001;

    /// The population (thickness 30-75 mm, chest wall to nipple 58-180
    /// mm, glandularity 3-70 %), limited to what fits the image of `geom`: the
    /// thickness to the image height less 2 pixels, the width to the image width
    /// less 4 pixels. Voxels equal the geometry's pixels.
    pub fn for_geometry(geom: &Geometry) -> Self {
        let p = geom.image.pixel_mm;
        Self {
            thickness_mm: [30.0, 75.0f64.min(geom.height_mm() - 2.0 * p)],
            chest_to_nipple_mm: [58.0, 180.0],
            max_width_mm: geom.width_mm() - 4.0 * p,
            glandularity: [0.03, 0.70],
            voxel_mm: p,
        }
    }

    /// Draw phantom `index` of a population seeded with `seed`.
    pub fn draw(&self, seed: u64, index: u64) -> PhantomSpec {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(index);
        let u = |rng: &mut ChaCha8Rng, r: [f64; 2]| r[0] + (r[1] - r[0]) * rng.random::<f64>();
        let thickness_mm = u(&mut rng, self.thickness_mm);
        let chest_to_nipple_mm = u(&mut rng, self.chest_to_nipple_mm);
        // Width grows with the breast's length (about 90 mm for the smallest,
        // 200 mm for the largest), with 15 % spread.
        let w = (60.0 + 0.8 * chest_to_nipple_mm) * u(&mut rng, [0.85, 1.15]);
        let width_mm = w.clamp(2.0 * thickness_mm.min(60.0), self.max_width_mm);
        // Most breasts are fatty: skew toward low glandularity.
        let g = self.glandularity;
        let glandularity = g[0] + (g[1] - g[0]) * rng.random::<f64>().powi(2);
        PhantomSpec {
            thickness_mm,
            chest_to_nipple_mm,
            width_mm,
            skin_mm: u(&mut rng, [1.2, 1.8]),
            glandularity,
            voxel_mm: self.voxel_mm,
            compartment_mm: u(&mut rng, [10.0, 18.0]),
            ligament_fraction: 0.03,
            beta: 3.0,
            seed: rng.random(),
        }
    }
}

/// Superellipse exponent of the outline in the detector plane.
const OUTLINE_P: f64 = 2.5;
/// Vertical flattening of the compartments by the compression.
pub(crate) const FLATTEN: f64 = 0.6;

/// Outline half-width and thickness of a cross-section at depth `y`.
fn section(y: f64, half_w: f64, len: f64, t: f64) -> (f64, f64) {
    if y >= len || half_w <= 0.0 || t <= 0.0 {
        return (0.0, 0.0);
    }
    let a = half_w * (1.0 - (y / len).powf(OUTLINE_P)).powf(1.0 / OUTLINE_P);
    let front = len - t / 2.0;
    let th = if y <= front {
        t
    } else {
        2.0 * ((t / 2.0).powi(2) - (y - front).powi(2)).max(0.0).sqrt()
    };
    (a, th)
}

/// Signed distance to a rounded rectangle of half-width `a`, half-height `b`,
/// corner radius `min(a, b)`.
fn rounded_rect_sd(x: f64, z: f64, a: f64, b: f64) -> f64 {
    let r = a.min(b);
    let qx = x.abs() - (a - r);
    let qz = z.abs() - (b - r);
    let outside = qx.max(0.0).hypot(qz.max(0.0));
    outside + qx.max(qz).min(0.0) - r
}

/// Compartment seeds: a jittered grid in scaled coordinates (lateral from
/// the breast's left edge, vertical / [`FLATTEN`], depth), one normal
/// "density bias" per compartment.
pub(crate) struct Seeds {
    cells: [usize; 3],
    cell_mm: f64,
    pos: Vec<[f64; 3]>,
    pub(crate) bias: Vec<f32>,
}

impl Seeds {
    /// Seeds spaced `c` mm over a breast `[width, thickness, length]` mm.
    pub(crate) fn new(extent_mm: [f64; 3], c: f64, rng: &mut ChaCha8Rng) -> Self {
        // Scaled coordinates: z / FLATTEN, so compartments are isotropic there.
        let ext = [extent_mm[0], extent_mm[1] / FLATTEN, extent_mm[2]];
        let cells = ext.map(|e| (e / c).ceil() as usize + 3);
        let n = cells.iter().product();
        let mut pos = Vec::with_capacity(n);
        let mut bias = Vec::with_capacity(n);
        for k in 0..cells[2] {
            for j in 0..cells[1] {
                for i in 0..cells[0] {
                    let jit = |rng: &mut ChaCha8Rng| 0.5 + 0.8 * (rng.random::<f64>() - 0.5);
                    pos.push([
                        (i as f64 - 1.0 + jit(rng)) * c,
                        (j as f64 - 1.0 + jit(rng)) * c,
                        (k as f64 - 1.0 + jit(rng)) * c,
                    ]);
                    bias.push(StandardNormal.sample(rng));
                }
            }
        }
        Self {
            cells,
            cell_mm: c,
            pos,
            bias,
        }
    }

    /// The seeds that can be nearest or second nearest anywhere within `r`
    /// of `p` (scaled coordinates): those no farther from `p` than its second
    /// nearest plus `2 r` (a seed's distance changes by at most `r` over the
    /// ball, so does the second-nearest distance). Also the gap at `p`.
    /// (The generators use [`SeedRow::candidates`], the same bit for bit.)
    #[cfg(test)]
    pub(crate) fn candidates(&self, p: [f64; 3], r: f64) -> Candidates {
        candidates_of(&self.neighbours(p), r)
    }

    /// Gap `d2 - d1` at `p` among the candidates only.
    pub(crate) fn gap_among(&self, c: &Candidates, p: [f64; 3]) -> f32 {
        let (d1, d2) = smallest_two(c.ids[..c.n].iter().map(|&id| {
            let s = self.pos[id as usize];
            (s[0] - p[0]).powi(2) + (s[1] - p[1]).powi(2) + (s[2] - p[2]).powi(2)
        }));
        (d2.sqrt() - d1.sqrt()) as f32
    }

    /// The cell (with a one-cell margin) holding coordinate `v` on an axis
    /// of `n` cells.
    fn cell(&self, v: f64, n: usize) -> isize {
        cell_index(v, self.cell_mm, n)
    }

    /// The seeds of the 27 cells around `p` with their squared distances,
    /// depth outermost, lateral innermost.
    fn neighbours(&self, p: [f64; 3]) -> [(f64, u32); 27] {
        let (ci, cj, ck) = (
            self.cell(p[0], self.cells[0]),
            self.cell(p[1], self.cells[1]),
            self.cell(p[2], self.cells[2]),
        );
        let mut all = [(0f64, 0u32); 27];
        let mut n = 0;
        for k in ck - 1..=ck + 1 {
            for j in cj - 1..=cj + 1 {
                for i in ci - 1..=ci + 1 {
                    let id = (k as usize * self.cells[1] + j as usize) * self.cells[0] + i as usize;
                    let s = self.pos[id];
                    all[n] = (
                        (s[0] - p[0]).powi(2) + (s[1] - p[1]).powi(2) + (s[2] - p[2]).powi(2),
                        id as u32,
                    );
                    n += 1;
                }
            }
        }
        all
    }

    /// Nearest seed and the gap `d2 - d1` to the second nearest, searching the
    /// 27 neighbouring cells (seeds are jittered within their cells, so this is
    /// exact for the jitter used).
    pub(crate) fn nearest(&self, p: [f64; 3]) -> (usize, f32) {
        nearest_of(&self.neighbours(p))
    }

    /// The seeds around the line of points `(x, p1, p2)` (any `x`), with
    /// the parts of their squared distances that do not depend on `x`:
    /// [`SeedRow::nearest`] and [`SeedRow::candidates`] are
    /// [`Seeds::nearest`] and [`Seeds::candidates`] at `(x, p1, p2)`, bit
    /// for bit (the same terms added in the same order), for a fraction of
    /// the work when many points share the line.
    pub(crate) fn row(&self, p1: f64, p2: f64) -> SeedRow {
        let (cj, ck) = (self.cell(p1, self.cells[1]), self.cell(p2, self.cells[2]));
        let nx = self.cells[0];
        let mut cols = vec![[(0f64, 0f64, 0f64, 0u32); 9]; nx];
        for (i, col) in cols.iter_mut().enumerate() {
            let mut m = 0;
            for k in ck - 1..=ck + 1 {
                for j in cj - 1..=cj + 1 {
                    let id = (k as usize * self.cells[1] + j as usize) * nx + i;
                    let s = self.pos[id];
                    col[m] = (s[0], (s[1] - p1).powi(2), (s[2] - p2).powi(2), id as u32);
                    m += 1;
                }
            }
        }
        SeedRow {
            cell_mm: self.cell_mm,
            cols,
        }
    }
}

/// The cell (with a one-cell margin) of coordinate `v` on an axis of `n`
/// cells of `cell_mm`: [`Seeds`]' and [`SeedRow`]'s one rule.
fn cell_index(v: f64, cell_mm: f64, n: usize) -> isize {
    ((v / cell_mm).floor() as isize + 1).clamp(1, n as isize - 2)
}

/// The smallest and second smallest of `ds` (`f64::MAX` where there are
/// fewer), ties kept in order.
fn smallest_two(ds: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut d1, mut d2) = (f64::MAX, f64::MAX);
    for d in ds {
        if d < d1 {
            d2 = d1;
            d1 = d;
        } else if d < d2 {
            d2 = d;
        }
    }
    (d1, d2)
}

/// [`Seeds::nearest`]'s choice among the neighbours, in their order.
/// (Written without branches: `d2` becomes `min(d2, max(d1, d))`, which is
/// what the branches of [`smallest_two`] give, ties included.)
fn nearest_of(all: &[(f64, u32)]) -> (usize, f32) {
    let (mut d1, mut d2, mut best) = (f64::MAX, f64::MAX, 0u32);
    for &(d, id) in all {
        d2 = d2.min(d1.max(d));
        best = if d < d1 { id } else { best };
        d1 = d1.min(d);
    }
    (best as usize, (d2.sqrt() - d1.sqrt()) as f32)
}

/// [`Seeds::candidates`] among the neighbours.
fn candidates_of(all: &[(f64, u32)], r: f64) -> Candidates {
    let (d1, d2) = smallest_two(all.iter().map(|&(d, _)| d));
    let (d1, d2) = (d1.sqrt(), d2.sqrt());
    let limit = (d2 + 2.0 * r).powi(2);
    let mut c = Candidates {
        ids: [0; 27],
        n: 0,
        gap: (d2 - d1) as f32,
    };
    for &(d, id) in all {
        if d <= limit {
            c.ids[c.n] = id;
            c.n += 1;
        }
    }
    c
}

/// The seeds around a line of constant height and depth ([`Seeds::row`]).
pub(crate) struct SeedRow {
    cell_mm: f64,
    /// Per lateral cell, its nine neighbours in height and depth (depth
    /// outer): lateral position, squared height and depth differences, id.
    cols: Vec<[(f64, f64, f64, u32); 9]>,
}

impl SeedRow {
    /// The 27 neighbours of `(x, p1, p2)` in [`Seeds::neighbours`]'s order
    /// and with its distances.
    fn neighbours(&self, x: f64) -> [(f64, u32); 27] {
        let ci = self.cell_of(x);
        let mut all = [(0f64, 0u32); 27];
        for m in 0..9 {
            for (o, i) in (ci - 1..=ci + 1).enumerate() {
                let (sx, b, c, id) = self.cols[i][m];
                all[m * 3 + o] = ((sx - x).powi(2) + b + c, id);
            }
        }
        all
    }

    /// [`Seeds::nearest`] at `(x, p1, p2)` (the generators take many at
    /// once, [`SeedRow::nearest_each`]).
    #[cfg(test)]
    pub(crate) fn nearest(&self, x: f64) -> (usize, f32) {
        nearest_of(&self.neighbours(x))
    }

    /// The lateral cell of `x` (with the one-cell margin).
    fn cell_of(&self, x: f64) -> usize {
        cell_index(x, self.cell_mm, self.cols.len()) as usize
    }

    /// [`SeedRow::nearest`] at each of `xs` (ascending), into `out`. The
    /// points in one lateral cell share their 27 neighbours; of those, a
    /// seed whose squared distance is, everywhere between the run's first
    /// and last point, larger than the second smallest of the neighbours'
    /// largest squared distances there can be neither nearest nor second
    /// nearest at any of them, and is left out. The others are tried in
    /// the same order with the same arithmetic, so the result is the same
    /// bit for bit.
    pub(crate) fn nearest_each(&self, xs: &[f64], out: &mut Vec<(usize, f32)>) {
        out.clear();
        let mut k = 0;
        while k < xs.len() {
            let ci = self.cell_of(xs[k]);
            let mut e = k + 1;
            while e < xs.len() && self.cell_of(xs[e]) == ci {
                e += 1;
            }
            let (xa, xb) = (xs[k], xs[e - 1]);
            let mut all = [(0f64, 0f64, 0f64, 0u32); 27];
            let mut lo = [0f64; 27];
            let (mut u1, mut u2) = (f64::MAX, f64::MAX);
            for m in 0..9 {
                for (o, i) in (ci - 1..=ci + 1).enumerate() {
                    let q = self.cols[i][m];
                    let (da, db) = ((q.0 - xa).powi(2), (q.0 - xb).powi(2));
                    let near = if (xa..=xb).contains(&q.0) {
                        0.0
                    } else {
                        da.min(db)
                    };
                    let up = da.max(db) + q.1 + q.2;
                    u2 = u2.min(u1.max(up));
                    u1 = u1.min(up);
                    all[m * 3 + o] = q;
                    lo[m * 3 + o] = near + q.1 + q.2;
                }
            }
            // A margin far above the rounding of these few operations.
            let limit = u2 * (1.0 + 1e-9) + 1e-9;
            let mut kept = [(0f64, 0f64, 0f64, 0u32); 27];
            let mut n = 0;
            for (q, &l) in all.iter().zip(&lo) {
                if l <= limit {
                    kept[n] = *q;
                    n += 1;
                }
            }
            let mut d = [(0f64, 0u32); 27];
            for &x in &xs[k..e] {
                for (t, &(sx, b, c, id)) in d.iter_mut().zip(&kept[..n]) {
                    *t = ((sx - x).powi(2) + b + c, id);
                }
                out.push(nearest_of(&d[..n]));
            }
            k = e;
        }
    }

    /// [`Seeds::candidates`] at `(x, p1, p2)`.
    pub(crate) fn candidates(&self, x: f64, r: f64) -> Candidates {
        candidates_of(&self.neighbours(x), r)
    }
}

/// The seeds near a point ([`Seeds::candidates`]).
pub(crate) struct Candidates {
    ids: [u32; 27],
    n: usize,
    /// The gap `d2 - d1` at the point.
    pub(crate) gap: f32,
}

const OUTSIDE: u8 = 0;
const SKIN: u8 = 1;
const INTERIOR: u8 = 2;

/// Generate the label volume of `spec`.
pub fn generate(spec: &PhantomSpec) -> Result<LabelVolume, PhantomError> {
    spec.validate()?;
    let _span = tracing::info_span!("phantom", seed = spec.seed).entered();
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let dims = spec.dims();
    let [nx, nz, ny] = dims;
    let h = spec.voxel_mm;
    let (half_w, len, t, s) = (
        spec.width_mm / 2.0,
        spec.chest_to_nipple_mm,
        spec.thickness_mm,
        spec.skin_mm,
    );
    let seeds = Seeds::new(
        [spec.width_mm, spec.thickness_mm, spec.chest_to_nipple_mm],
        spec.compartment_mm,
        &mut rng,
    );
    // Texture on a grid no finer than 0.4 mm (the 1/f^3 spectrum has little
    // power beyond), interpolated to the voxels.
    let nh = h.max(0.4);
    let ndims = [
        (spec.width_mm / nh).ceil() as usize + 2,
        (spec.thickness_mm / nh).ceil() as usize + 2,
        (spec.chest_to_nipple_mm / nh).ceil() as usize + 2,
    ];
    let texture = power_law(ndims, nh, spec.beta, rng.random());
    // The centre of the glandular envelope varies per breast.
    let centre = [
        0.1 * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut rng),
        0.25 + 0.2 * rng.random::<f64>(),
        0.15 * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut rng),
    ];

    // Pass 1: shape class, ligament gap and glandular score of every voxel.
    let plane = nx * nz;
    let mut class = vec![OUTSIDE; nx * nz * ny];
    let mut gap = vec![0f32; nx * nz * ny];
    let mut score = vec![0f32; nx * nz * ny];
    class
        .par_chunks_mut(plane)
        .zip(gap.par_chunks_mut(plane))
        .zip(score.par_chunks_mut(plane))
        .enumerate()
        .for_each(|(d, ((cls, gp), sc))| {
            let y = (d as f64 + 0.5) * h;
            let (a, th) = section(y, half_w, len, t);
            let (ai, thi) = section(y, half_w - s, len - s, t - 2.0 * s);
            if a <= 0.0 {
                return;
            }
            for v in 0..nz {
                let z = (v as f64 + 0.5) * h;
                let zc = z - t / 2.0;
                for l in 0..nx {
                    let x = (l as f64 + 0.5) * h - nx as f64 * h / 2.0;
                    if rounded_rect_sd(x, zc, a, th / 2.0) > 0.0 {
                        continue;
                    }
                    let i = v * nx + l;
                    if ai <= 0.0 || rounded_rect_sd(x, zc, ai, thi / 2.0) > 0.0 {
                        cls[i] = SKIN;
                        continue;
                    }
                    cls[i] = INTERIOR;
                    let (seed, g) = seeds.nearest([x + half_w, z / FLATTEN, y]);
                    gp[i] = g;
                    let ex = (x / a - centre[0]) / 0.55;
                    let ey = (y / len - centre[1]) / 0.5;
                    let ez = (zc / (t / 2.0) - centre[2]) / 0.7;
                    let env = -(ex * ex + ey * ey + ez * ez) as f32;
                    let tex = texture.sample((x + half_w) / nh, z / nh, y / nh);
                    sc[i] = env + 0.6 * tex + 0.4 * seeds.bias[seed];
                }
            }
        });

    // Ligaments: the thinnest-gap voxels, at most `ligament_fraction` of the
    // interior and at most 40 % of the glandular voxels the target needs.
    let interior: Vec<usize> = (0..class.len()).filter(|&i| class[i] == INTERIOR).collect();
    let n_int = interior.len();
    if n_int == 0 {
        return Err(PhantomError::Parameter {
            field: "skin_mm",
            value: s,
            reason: "the breast has no interior under the skin".into(),
        });
    }
    let (rg, ra) = (
        Tissue::Fibroglandular.density_g_cm3(),
        Tissue::Adipose.density_g_cm3(),
    );
    let g = spec.glandularity;
    let g_vol = g * ra / (g * ra + (1.0 - g) * rg);
    let n_gland = (g_vol * n_int as f64).round() as usize;
    let n_lig = ((spec.ligament_fraction * n_int as f64) as usize).min(n_gland * 2 / 5);
    let mut is_lig = vec![false; class.len()];
    if n_lig > 0 {
        let mut gaps: Vec<(f32, usize)> = interior.iter().map(|&i| (gap[i], i)).collect();
        gaps.select_nth_unstable_by(n_lig - 1, |a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        for &(_, i) in &gaps[..n_lig] {
            is_lig[i] = true;
        }
    }
    drop(gap);
    // Fibroglandular: the highest scores among the non-ligament interior.
    let n_fg = n_gland - n_lig;
    let mut is_fg = vec![false; class.len()];
    if n_fg > 0 {
        let mut scores: Vec<(f32, usize)> = interior
            .iter()
            .filter(|&&i| !is_lig[i])
            .map(|&i| (score[i], i))
            .collect();
        scores.select_nth_unstable_by(n_fg - 1, |a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        for &(_, i) in &scores[..n_fg] {
            is_fg[i] = true;
        }
    }
    let labels: Vec<u8> = (0..class.len())
        .into_par_iter()
        .map(|i| match class[i] {
            OUTSIDE => Tissue::Air.label(),
            SKIN => Tissue::Skin.label(),
            _ if is_lig[i] => Tissue::Ligament.label(),
            _ if is_fg[i] => Tissue::Fibroglandular.label(),
            _ => Tissue::Adipose.label(),
        })
        .collect();
    tracing::debug!(n_int, n_lig, n_fg, "phantom generated");
    LabelVolume::new(dims, h, labels)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small(seed: u64, g: f64) -> PhantomSpec {
        PhantomSpec {
            thickness_mm: 40.0,
            chest_to_nipple_mm: 60.0,
            width_mm: 90.0,
            glandularity: g,
            ..PhantomSpec::typical(1.0, seed)
        }
    }

    #[test]
    fn same_seed_same_bytes_other_seed_differs() {
        let a = generate(&small(11, 0.2)).unwrap();
        let b = generate(&small(11, 0.2)).unwrap();
        assert_eq!(a.labels(), b.labels());
        let c = generate(&small(12, 0.2)).unwrap();
        assert_ne!(a.labels(), c.labels());
    }

    #[test]
    fn requested_glandularity_within_one_point() {
        for (seed, g) in [(1, 0.03), (2, 0.15), (3, 0.4), (4, 0.7)] {
            let v = generate(&small(seed, g)).unwrap();
            let got = v.glandularity().unwrap();
            assert!((got - g).abs() < 0.01, "asked {g}, got {got}");
            let c = v.counts();
            assert!(c[4] > 0, "no ligaments at g = {g}");
            assert!(c[2] > 0 && c[1] > 0);
        }
    }

    #[test]
    fn shape_skin_and_support() {
        let spec = small(5, 0.2);
        let v = generate(&spec).unwrap();
        let [nx, nz, ny] = v.dims();
        assert_eq!([nx, nz, ny], [90, 40, 60]);
        // Rests on the support and spans the thickness at the chest wall.
        assert!((v.thickness_mm() - 40.0).abs() < 1e-9);
        // The bottom and top rows at the centre of the chest-wall slice are skin
        // (1.5 mm at 1 mm voxels: exactly the outermost voxel row and the next
        // one whose centre is within 1.5 mm).
        let col = nx / 2;
        assert_eq!(v.at(col, 0, 0), Tissue::Skin.label());
        assert_eq!(v.at(col, nz - 1, 0), Tissue::Skin.label());
        assert_ne!(v.at(col, 2, 0), Tissue::Skin.label());
        assert_ne!(v.at(col, 2, 0), Tissue::Air.label());
        // The corners of the chest-wall slice are air (rounded edges).
        assert_eq!(v.at(0, 0, 0), Tissue::Air.label());
        assert_eq!(v.at(nx - 1, nz - 1, 0), Tissue::Air.label());
        // Cross-sections shrink toward the nipple.
        let area = |d: usize| v.coronal(d).unwrap().iter().filter(|&&l| l != 0).count();
        assert!(area(0) > area(ny / 2) && area(ny / 2) > area(ny - 2));
    }

    #[test]
    fn bad_specs_name_the_field() {
        let mut s = small(1, 0.2);
        s.glandularity = 0.99;
        let e = generate(&s).unwrap_err().to_string();
        assert!(e.contains("glandularity"), "{e}");
        let mut s = small(1, 0.2);
        s.thickness_mm = f64::NAN;
        assert!(generate(&s)
            .unwrap_err()
            .to_string()
            .contains("thickness_mm"));
        let mut s = small(1, 0.2);
        s.voxel_mm = 6.0;
        assert!(generate(&s).unwrap_err().to_string().contains("voxel_mm"));
    }

    #[test]
    fn population_fits_geometry() {
        let g = Geometry::paper().binned(4).unwrap();
        let pop = Population::for_geometry(&g);
        for i in 0..50 {
            let s = pop.draw(9, i);
            s.validate().unwrap();
            assert!(s.thickness_mm <= g.height_mm() && s.width_mm <= g.width_mm());
            assert!((0.03..=0.70).contains(&s.glandularity));
        }
        assert_eq!(pop.draw(9, 3), pop.draw(9, 3));
        assert_ne!(pop.draw(9, 3), pop.draw(9, 4));
    }

    /// A row of seeds gives the same nearest seed, gap and candidates as
    /// the seeds themselves, bit for bit, anywhere along its line (also
    /// beyond the seeds' box, where the cells clamp).
    #[test]
    fn seed_rows_agree_with_seeds_bit_for_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let seeds = Seeds::new([120.0, 50.0, 90.0], 7.0, &mut rng);
        for _ in 0..200 {
            let (p1, p2) = (
                -5.0 + 100.0 * rng.random::<f64>(),
                -5.0 + 100.0 * rng.random::<f64>(),
            );
            let row = seeds.row(p1, p2);
            for _ in 0..50 {
                let x = -10.0 + 140.0 * rng.random::<f64>();
                let (a, b) = (seeds.nearest([x, p1, p2]), row.nearest(x));
                assert_eq!((a.0, a.1.to_bits()), (b.0, b.1.to_bits()));
                let (c, d) = (seeds.candidates([x, p1, p2], 0.7), row.candidates(x, 0.7));
                assert_eq!(c.gap.to_bits(), d.gap.to_bits());
                assert_eq!(c.ids[..c.n], d.ids[..d.n]);
            }
            // Runs of points 0.8 mm apart (as the lattice), and sparse ones.
            let x0 = -10.0 + 20.0 * rng.random::<f64>();
            let step = if rng.random::<bool>() {
                0.8
            } else {
                9.0 * rng.random::<f64>() + 0.01
            };
            let xs: Vec<f64> = (0..150).map(|i| x0 + i as f64 * step).collect();
            let mut each = Vec::new();
            row.nearest_each(&xs, &mut each);
            for (&x, &(id, gap)) in xs.iter().zip(&each) {
                let (a, g) = seeds.nearest([x, p1, p2]);
                assert_eq!((a, g.to_bits()), (id, gap.to_bits()), "x {x}");
            }
        }
    }

    /// The procedural population stays byte-identical to the one every
    /// earlier figure was made on: FNV-1a of the labels, recorded after
    /// checking that commit 6d69eb3's generator (before the anatomical
    /// generator shared the compartment seeds) gives the same bytes.
    #[test]
    fn procedural_phantoms_are_unchanged() {
        let fnv = |v: &LabelVolume| {
            v.labels().iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
                (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
            })
        };
        let g = Geometry::builtin("paper-tall").unwrap().binned(4).unwrap();
        let pop = Population::for_geometry(&g);
        let v = generate(&pop.draw(Population::TEST_SEED, 7)).unwrap();
        assert_eq!(v.dims(), [173, 54, 102]);
        assert_eq!(fnv(&v), 0x6054_0f48_4eb7_0983);
        let v = generate(&pop.draw(2024, 3)).unwrap();
        assert_eq!(fnv(&v), 0xf618_befa_739c_d60f);
    }
}
