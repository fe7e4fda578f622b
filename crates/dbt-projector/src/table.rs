//! Per-ray parameters and the scalar reference kernels.
//!
//! Column coordinate `X` is in pixel units with `X = 0` at the left image edge;
//! rows are indexed from the top. Ray `r = v * n_det + k` enters row `i` at
//! `X_t = x_top[r] + i * sx[r]` and leaves it at `X_b = X_t + sx[r]`; its length
//! inside any one row is `len[r]` mm.

use dbt_geometry::Geometry;
use rayon::prelude::*;

/// Rays with `|sx|` below this cross at most two pixels per row (with margin for
/// rounding) and use the two-pixel kernels.
pub(crate) const FAST_LIMIT: f32 = 0.999;

/// Scratch padding (entries) on both sides of the per-row ray arrays of the
/// pixel-driven adjoint.
pub(crate) const PAD: usize = 64;

/// A `j` that never matches a pixel: marks rays that contribute nothing.
pub(crate) const NO_PIXEL: i32 = i32::MIN / 2;

/// The inverse map of one (view, row): the fractional index of the ray through
/// the left edge of pixel `j` at the row's mid-height (where the candidates
/// come out tightest: a ray's first pixel lies within half its per-row travel
/// of that point) is the Moebius function
/// `(a j + b) / (c j + d)`. It is evaluated exactly at the first pixel `jb` of
/// each block of 16 and continued linearly with its derivative there (the
/// same operations in the scalar and SIMD code); candidate rays are
/// `floor(that) - off .. + count`, with `off` and `count` verified at
/// construction against the exact contributions. Two candidate sets share the
/// map: `(off, count)` covers every ray contributing to pixel `j` (first or
/// second pixel of the ray; the scalar fallback), `(off1, count1)` only the
/// rays whose first pixel is `j` (the SIMD pass, which adds their second
/// contributions to pixel `j + 1`).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct InvMap {
    pub a: f32,
    pub b: f32,
    pub c: f32,
    pub d: f32,
    /// `a d - b c`, the numerator of the derivative.
    pub e: f32,
    pub off: i32,
    pub count: u32,
    /// Rays `ray_lo .. ray_hi` (within the view) are the only ones valid in
    /// this row.
    pub ray_lo: u32,
    pub ray_hi: u32,
    /// Candidates of the rays whose first pixel is `j`.
    pub off1: i32,
    pub count1: u32,
    /// Blocks of 16 pixels `fit_lo .. fit_hi` (block `b` = pixels `16 b ..
    /// min(16 b + 16, nx)`) where the SIMD pixel pass applies without checks: the
    /// view's pixel index is monotone along the detector, and the block's
    /// `(off1, count1)` candidate starts are finite, non-decreasing, and all
    /// in one 32-entry window of the padded ray scratch.
    pub fit_lo: u32,
    pub fit_hi: u32,
    /// The row's rays inside the image are consecutive and fast, their first
    /// pixels lie in `-1 .. nx`, and each is its predecessor's or one or two
    /// pixels on: the AVX2 pixel pass then stores the runs' sums where the
    /// last vector's stopped, one pixel on after a pixel without rays.
    pub packed: bool,
}

impl InvMap {
    /// Value and slope of the map at block start `jb` (a multiple of 16), with
    /// one division (the SIMD code repeats these operations exactly).
    #[inline(always)]
    pub fn block(&self, jb: usize) -> (f32, f32) {
        let x = jb as f32;
        let q = 1.0 / (self.c * x + self.d);
        ((self.a * x + self.b) * q, (self.e * q) * q)
    }

    /// First candidate ray of pixel `j` (see the type's documentation).
    #[inline(always)]
    pub fn start(&self, j: usize) -> i32 {
        self.start_off(j, self.off)
    }

    /// First one-sided candidate of pixel `j` (`off1`).
    #[inline(always)]
    pub fn start1(&self, j: usize) -> i32 {
        self.start_off(j, self.off1)
    }

    #[inline(always)]
    fn start_off(&self, j: usize, off: i32) -> i32 {
        let (rb, sb) = self.block(j & !15);
        let r = rb + ((j & 15) as f32) * sb;
        // Saturating conversion; the result is covered by the `count`
        // verification (`RayTable::build_inverse_maps`).
        (r.floor().clamp(-1.0e9, 1.0e9) as i32).saturating_sub(off)
    }

    /// Whether block `b` qualifies for the unchecked SIMD pixel pass (see
    /// `fit_lo`), computed with the SIMD kernel's arithmetic: lane `l` is
    /// `floor(rb + l * sb)`, converted by truncation, minus `off1`.
    fn block_fits(&self, b: usize, n_det: usize) -> bool {
        let (rb, sb) = self.block(16 * b);
        let mut starts = [0i64; 16];
        for (l, st) in starts.iter_mut().enumerate() {
            let r = (rb + (l as f32) * sb).floor();
            if !r.is_finite() || r.abs() >= 1.0e9 {
                return false;
            }
            *st = r as i64 - self.off1 as i64;
        }
        let (first, last) = (starts[0], starts[15]);
        starts.windows(2).all(|w| w[1] >= w[0])
            && first == rb.floor() as i64 - self.off1 as i64
            && first >= -(PAD as i64)
            && first + 32 <= (n_det + PAD) as i64
            && last + self.count1 as i64 - 1 - first <= 31
    }
}

/// Per-task scratch of the pixel-driven adjoint: each ray's pixel index and its
/// two weighted contributions for the current (view, row), padded with
/// non-contributing entries on both sides; and the row's inverse map evaluated
/// at every 16-pixel block (value, slope). Shared by the AVX-512 and AVX2
/// adjoints (each thread keeps its own).
pub(crate) struct RowRays {
    pub j: Vec<i32>,
    pub c0: Vec<f32>,
    pub c1: Vec<f32>,
    pub rb: Vec<f32>,
    pub sb: Vec<f32>,
    /// `floor(rb)` as an integer (the first candidate before `off1`).
    pub r0: Vec<i32>,
    /// Scratch index of each block's first candidate, `PAD + r0 - off1`
    /// (separate from `r0` so that `r0` is broadcast straight from memory).
    pub e: Vec<i32>,
    /// The AVX2 pixel pass's run sums by pixel (`avx2.rs`): entry `j + 1`
    /// holds the first (`a0`) and second (`a1`) contributions of the rays
    /// whose first pixel is `j`, summed in ray order; zero elsewhere.
    pub a0: Vec<f32>,
    pub a1: Vec<f32>,
    /// Partial run sums of the AVX2 pixel pass, for rows whose runs of
    /// rays with one first pixel may be longer than two.
    pub t0: Vec<f32>,
    pub t1: Vec<f32>,
    /// Rays `live.0 .. live.1` of `j`, `c0`, `c1` may hold a ray's values;
    /// every other entry is `NO_PIXEL` and zeros (kept by the AVX2 ray pass,
    /// which clears only what the last row left; the AVX-512 one rewrites
    /// every entry).
    pub live: (usize, usize),
}

impl RowRays {
    pub const fn new() -> Self {
        RowRays {
            j: Vec::new(),
            c0: Vec::new(),
            c1: Vec::new(),
            rb: Vec::new(),
            sb: Vec::new(),
            r0: Vec::new(),
            e: Vec::new(),
            a0: Vec::new(),
            a1: Vec::new(),
            t0: Vec::new(),
            t1: Vec::new(),
            live: (0, 0),
        }
    }

    pub fn reset(&mut self, n: usize, nb: usize) {
        self.j.clear();
        self.j.resize(n, NO_PIXEL);
        self.c0.clear();
        self.c0.resize(n, 0.0);
        self.c1.clear();
        self.c1.resize(n, 0.0);
        self.rb.resize(nb, 0.0);
        self.sb.resize(nb, 0.0);
        self.r0.resize(nb, 0);
        self.e.resize(nb, 0);
        // Pixels `-1 ..= 16 nb` (`16 nb >= nx`) and one 8-lane store past them.
        self.a0.resize(16 * nb + 16, 0.0);
        self.a1.resize(16 * nb + 16, 0.0);
        self.t0.resize(n, 0.0);
        self.t1.resize(n, 0.0);
        self.live = (0, 0);
    }
}

#[derive(Debug, Clone)]
pub(crate) struct RayTable {
    pub nx: usize,
    pub nz: usize,
    pub n_det: usize,
    pub n_views: usize,
    pub x_top: Vec<f32>,
    pub sx: Vec<f32>,
    pub len: Vec<f32>,
    pub inv: Vec<f32>,
    /// First and one-past-last row the ray touches inside the image.
    pub row_lo: Vec<u32>,
    pub row_hi: Vec<u32>,
    pub fast: Vec<bool>,
    /// Every ray of the view is fast and its pixel index is non-decreasing along
    /// the detector at every row: the SIMD forward kernel applies.
    pub view_simd: Vec<bool>,
    /// Whether the view has any slow ray (handled by scalar scatter in the adjoint).
    pub view_has_slow: Vec<bool>,
    /// Inverse maps, `n_views * nz`, view-major.
    pub inv_map: Vec<InvMap>,
    /// Per block of 16 rays (`v * n_det.div_ceil(16) + k / 16`, SIMD views
    /// only): the rows `[lo, hi)` in which all 16 rays are inside the image and
    /// their pixels lie in one unmasked 32-pixel window of the row (the SIMD
    /// forward kernel's fast rows). Empty where that never holds.
    pub fwd_rows: Vec<(u32, u32)>,
}

/// The first maximal run `[lo, hi)` of `0..n` on which `ok` holds (`(0, 0)`
/// if it holds nowhere): the ranges the SIMD kernels may use unchecked.
fn first_run(n: usize, ok: impl Fn(usize) -> bool) -> (u32, u32) {
    match (0..n).find(|&i| ok(i)) {
        None => (0, 0),
        Some(lo) => {
            let hi = (lo..n).find(|&i| !ok(i)).unwrap_or(n);
            (lo as u32, hi as u32)
        }
    }
}

/// The smallest `(off, count)` such that the candidates `start(j) - off ..
/// + count` (with `off = 0` in `m`) cover the rays `need.0[j] ..= need.1[j]`
/// of every pixel; `None` if no pixel needs any ray.
fn candidate_window(m: &InvMap, need: &(Vec<i64>, Vec<i64>)) -> Option<(i32, u32)> {
    let est = |j: usize| m.start_off(j, 0) as i64;
    let mut off = i64::MIN;
    for (j, &lo) in need.0.iter().enumerate() {
        if lo != i64::MAX {
            off = off.max(est(j) - lo);
        }
    }
    if off == i64::MIN {
        return None;
    }
    let mut count = 0i64;
    for (j, &hi) in need.1.iter().enumerate() {
        if hi != i64::MIN {
            count = count.max(hi - (est(j) - off) + 1);
        }
    }
    Some((
        off.clamp(i32::MIN as i64 / 4, i32::MAX as i64 / 4) as i32,
        count.clamp(0, 1 << 20) as u32,
    ))
}

/// The second contributions (to pixel 0) of the rays whose first pixel is `-1`,
/// from the ray scratch `(j, c1)` (indexed `PAD + k`, `NO_PIXEL` for rays
/// outside the row). In a view whose pixel index is non-decreasing along the
/// detector these are the first valid rays of the row, so the scan stops at
/// the first ray inside the image.
#[inline]
pub(crate) fn left_edge_c1(map: &InvMap, j: &[i32], c1: &[f32]) -> f32 {
    let mut acc = 0.0f32;
    for k in map.ray_lo as usize..map.ray_hi as usize {
        match j[PAD + k] {
            -1 => acc += c1[PAD + k],
            jk if jk >= 0 => break,
            _ => {}
        }
    }
    acc
}

/// Scratch indices of the candidates `start .. start + count` that are rays.
#[inline(always)]
fn candidates(start: i32, count: u32, n_det: usize) -> impl Iterator<Item = usize> {
    let start = start as i64;
    (start..start + count as i64)
        .filter(move |&r| r >= 0 && r < n_det as i64)
        .map(|r| PAD + r as usize)
}

/// Pixel `j` from the two-sided candidates: first contributions of the rays
/// whose first pixel it is, second contributions of those one pixel left.
#[inline(always)]
pub(crate) fn pixel_scalar(map: &InvMap, s: &RowRays, n_det: usize, j: usize) -> f32 {
    let mut acc = 0.0f32;
    for e in candidates(map.start(j), map.count, n_det) {
        if s.j[e] == j as i32 {
            acc += s.c0[e];
        }
        if s.j[e].wrapping_add(1) == j as i32 {
            acc += s.c1[e];
        }
    }
    acc
}

/// The second contributions of the rays whose first pixel is `j` (one-sided
/// candidates, `InvMap::start1`), for the pixel pass's carry into pixel `j + 1`.
#[inline(always)]
pub(crate) fn slot_c1_scalar(map: &InvMap, s: &RowRays, n_det: usize, j: usize) -> f32 {
    candidates(map.start1(j), map.count1, n_det)
        .filter(|&e| s.j[e] == j as i32)
        .map(|e| s.c1[e])
        .sum()
}

/// Row segment `(lo, hi)` of a ray in row `i`, in column units.
#[inline(always)]
pub(crate) fn segment(x_top: f32, sx: f32, i: usize) -> (f32, f32) {
    let xt = x_top + (i as f32) * sx;
    let xb = xt + sx;
    (xt.min(xb), xt.max(xb))
}

/// Two-pixel weights of a fast ray: pixel `j` gets `w0`, pixel `j + 1` gets `w1`.
#[inline(always)]
pub(crate) fn fast_weights(lo: f32, len: f32, inv: f32) -> (i32, f32, f32) {
    let jf = lo.floor();
    let w0 = len * (((jf + 1.0) - lo) * inv).min(1.0);
    (jf as i32, w0, len - w0)
}

/// Exact intersection lengths of a slow ray with the pixels of one row.
#[inline]
pub(crate) fn slow_weights(
    lo: f32,
    hi: f32,
    len: f32,
    inv: f32,
    nx: usize,
    mut f: impl FnMut(usize, f32),
) {
    let j0 = (lo.floor() as i64).max(0);
    let j1 = (hi.floor() as i64).min(nx as i64 - 1);
    for j in j0..=j1 {
        let jf = j as f32;
        let w = len * ((hi.min(jf + 1.0) - lo.max(jf)) * inv);
        if w > 0.0 {
            f(j as usize, w);
        }
    }
}

#[inline(always)]
fn row_valid(lo: f32, hi: f32, nx: usize) -> bool {
    hi > 0.0 && lo < nx as f32
}

impl RayTable {
    pub fn new(g: &Geometry) -> Self {
        let (nx, nz, n_det, n_views) = (g.nx(), g.nz(), g.n_det(), g.n_views());
        let n = n_det * n_views;
        let p = g.image.pixel_mm;
        let x_min = -g.width_mm() / 2.0;
        let z_top = g.top_z_mm();
        let mut t = RayTable {
            nx,
            nz,
            n_det,
            n_views,
            x_top: vec![0.0; n],
            sx: vec![0.0; n],
            len: vec![0.0; n],
            inv: vec![0.0; n],
            row_lo: vec![0; n],
            row_hi: vec![0; n],
            fast: vec![true; n],
            view_simd: vec![true; n_views],
            view_has_slow: vec![false; n_views],
            inv_map: vec![InvMap::default(); n_views * nz],
            fwd_rows: Vec::new(),
        };
        for v in 0..n_views {
            for k in 0..n_det {
                let r = v * n_det + k;
                let ((sxm, szm), (pxm, pzm)) = g.ray_endpoints_mm(v, k);
                // Validation guarantees pzm < szm (the ray goes down).
                let dxdz = (pxm - sxm) / (pzm - szm);
                let x_at_top = sxm + (z_top - szm) * dxdz;
                let slope = -dxdz; // change of X per row going down (pixel units)
                t.x_top[r] = ((x_at_top - x_min) / p) as f32;
                t.sx[r] = slope as f32;
                t.len[r] = (p * (1.0 + dxdz * dxdz).sqrt()) as f32;
                let a = t.sx[r].abs();
                t.inv[r] = if a > 0.0 { 1.0 / a } else { f32::MAX };
                t.fast[r] = a < FAST_LIMIT;
            }
        }
        // Row ranges: the valid rows of a ray form an interval because the
        // row segment moves monotonically with the row index.
        let ranges: Vec<(u32, u32)> = (0..n)
            .into_par_iter()
            .map(|r| {
                let valid = |i: usize| {
                    let (lo, hi) = segment(t.x_top[r], t.sx[r], i);
                    row_valid(lo, hi, nx)
                };
                match (0..nz).find(|&i| valid(i)) {
                    None => (0, 0),
                    Some(first) => {
                        let last = (first..nz).rev().find(|&i| valid(i)).unwrap_or(first);
                        (first as u32, last as u32 + 1)
                    }
                }
            })
            .collect();
        for (r, (lo, hi)) in ranges.into_iter().enumerate() {
            t.row_lo[r] = lo;
            t.row_hi[r] = hi;
        }
        for v in 0..n_views {
            let rays = v * n_det..(v + 1) * n_det;
            t.view_has_slow[v] = rays.clone().any(|r| !t.fast[r]);
            t.view_simd[v] = !t.view_has_slow[v] && t.pixel_index_monotone(v);
        }
        t.build_inverse_maps(g);
        t.fwd_rows = t.forward_fast_rows();
        t
    }

    /// Blocks of 16 rays per view (the last one may be partial).
    pub fn blocks_per_view(&self) -> usize {
        self.n_det.div_ceil(16)
    }

    /// The fast rows of every block (see [`RayTable::fwd_rows`]), found by
    /// evaluating, row by row, exactly the pixel indices the SIMD kernel
    /// computes; the kernel relies on them without further checks.
    fn forward_fast_rows(&self) -> Vec<(u32, u32)> {
        let bpv = self.blocks_per_view();
        (0..self.n_views * bpv)
            .into_par_iter()
            .map(|b| {
                let (v, k0) = (b / bpv, (b % bpv) * 16);
                if !self.view_simd[v] || k0 + 16 > self.n_det {
                    return (0, 0);
                }
                let r0 = v * self.n_det + k0;
                let fast = |i: usize| {
                    let mut js = [0i64; 16];
                    for (k, jk) in js.iter_mut().enumerate() {
                        let r = r0 + k;
                        if !self.touches_row(r, i) {
                            return false;
                        }
                        *jk = segment(self.x_top[r], self.sx[r], i).0.floor() as i64;
                    }
                    let (first, last) = (js[0], js[15]);
                    first >= 0
                        && first + 32 <= self.nx as i64
                        && last + 1 - first <= 31
                        && js.windows(2).all(|w| w[1] >= w[0])
                };
                first_run(self.nz, fast)
            })
            .collect()
    }

    /// Whether ray `r` crosses the image in row `i`.
    #[inline(always)]
    pub fn touches_row(&self, r: usize, i: usize) -> bool {
        (i as u32) >= self.row_lo[r] && (i as u32) < self.row_hi[r]
    }

    /// Pixel index of a fast ray at row `i`, clamped to `[-1, nx - 1]` as the
    /// SIMD forward kernel computes it.
    fn clamped_j(&self, r: usize, i: usize) -> i32 {
        let (lo, _) = segment(self.x_top[r], self.sx[r], i);
        (lo.floor().clamp(-1.0, self.nx as f32 - 1.0)) as i32
    }

    fn pixel_index_monotone(&self, v: usize) -> bool {
        let base = v * self.n_det;
        (0..self.nz).into_par_iter().all(|i| {
            (1..self.n_det).all(|k| self.clamped_j(base + k, i) >= self.clamped_j(base + k - 1, i))
        })
    }

    /// Which fast rays contribute to which pixel in row `i` of view `v`:
    /// `(ray index within view, j, w0, w1)` for every valid fast ray.
    pub(crate) fn fast_contributions(
        &self,
        v: usize,
        i: usize,
        mut f: impl FnMut(usize, i32, f32, f32),
    ) {
        for k in 0..self.n_det {
            let r = v * self.n_det + k;
            if !self.fast[r] || !self.touches_row(r, i) {
                continue;
            }
            let (lo, _) = segment(self.x_top[r], self.sx[r], i);
            let (j, w0, w1) = fast_weights(lo, self.len[r], self.inv[r]);
            f(k, j, w0, w1);
        }
    }

    fn build_inverse_maps(&mut self, g: &Geometry) {
        let (nx, nz, n_det) = (self.nx, self.nz, self.n_det);
        let p = g.image.pixel_mm;
        let x_min = -g.width_mm() / 2.0;
        let z_top = g.top_z_mm();
        let d = g.source_to_detector_mm;
        let pitch = g.detector.pitch_mm;
        let h = (n_det as f64 - 1.0) / 2.0;
        let maps: Vec<InvMap> = (0..self.n_views * nz)
            .into_par_iter()
            .map(|vi| {
                let (v, i) = (vi / nz, vi % nz);
                let th = g.angle_rad(v);
                let (s, c) = th.sin_cos();
                let (sxm, szm) = g.source_mm(v);
                let z = z_top - (i as f64 + 0.5) * p;
                // lateral(X) = c p X + l0, depth(X) = -s p X + d0
                let l0 = (x_min - sxm) * c - (z - szm) * s;
                let d0 = -((x_min - sxm) * s + (z - szm) * c);
                // r = (D/pitch * lateral + h * depth) / depth
                let (ma, mb, mc, md) = (
                    d / pitch * c * p - h * s * p,
                    d / pitch * l0 + h * d0,
                    -s * p,
                    d0,
                );
                let mut m = InvMap {
                    a: ma as f32,
                    b: mb as f32,
                    c: mc as f32,
                    d: md as f32,
                    e: (ma * md - mb * mc) as f32,
                    off: 0,
                    count: 0,
                    ray_lo: 0,
                    ray_hi: 0,
                    off1: 0,
                    count1: 0,
                    fit_lo: 0,
                    fit_hi: 0,
                    packed: false,
                };
                let touches = |k: usize| self.touches_row(v * n_det + k, i);
                if let (Some(first), Some(last)) =
                    ((0..n_det).position(touches), (0..n_det).rposition(touches))
                {
                    m.ray_lo = first as u32;
                    m.ray_hi = last as u32 + 1;
                }
                // Which rays each pixel needs, from the exact contributions:
                // all contributing rays, and those whose first pixel it is.
                let mut need = (vec![i64::MAX; nx], vec![i64::MIN; nx]);
                let mut need1 = (vec![i64::MAX; nx], vec![i64::MIN; nx]);
                // (previous ray and its first pixel, `packed` so far)
                let mut packed = (None::<(usize, i32)>, self.view_simd[v]);
                let add = |need: &mut (Vec<i64>, Vec<i64>), j: i64, k: usize| {
                    if (0..nx as i64).contains(&j) {
                        let u = j as usize;
                        need.0[u] = need.0[u].min(k as i64);
                        need.1[u] = need.1[u].max(k as i64);
                    }
                };
                self.fast_contributions(v, i, |k, j, w0, w1| {
                    let jl = j as i64;
                    if w0 != 0.0 {
                        add(&mut need, jl, k);
                    }
                    if w1 != 0.0 {
                        add(&mut need, jl + 1, k);
                    }
                    add(&mut need1, jl, k);
                    packed.1 &= (-1..nx as i32).contains(&j)
                        && packed
                            .0
                            .is_none_or(|(kp, jp)| k == kp + 1 && (jp..=jp + 2).contains(&j));
                    packed.0 = Some((k, j));
                });
                let Some((off, count)) = candidate_window(&m, &need) else {
                    return m; // no contributions in this row: count 0
                };
                m.off = off;
                m.count = count;
                if let Some((off1, count1)) = candidate_window(&m, &need1) {
                    m.off1 = off1;
                    m.count1 = count1;
                    // Including a last partial block (masked in the kernel).
                    let fits = |b: usize| self.view_simd[v] && m.block_fits(b, n_det);
                    (m.fit_lo, m.fit_hi) = first_run(nx.div_ceil(16), fits);
                }
                // Every ray inside the row is fast in a SIMD view, so the
                // ones visited are those between `ray_lo` and `ray_hi`.
                m.packed = packed.1 && packed.0.is_some();
                m
            })
            .collect();
        self.inv_map = maps;
    }

    /// Scalar forward projection of one ray (the reference).
    pub fn forward_ray_scalar(&self, r: usize, img: &[f32]) -> f32 {
        let nx = self.nx;
        let (x0, sx, len, inv) = (self.x_top[r], self.sx[r], self.len[r], self.inv[r]);
        let mut acc = 0.0f32;
        for i in self.row_lo[r] as usize..self.row_hi[r] as usize {
            let (lo, hi) = segment(x0, sx, i);
            let row = &img[i * nx..(i + 1) * nx];
            if self.fast[r] {
                let (j, w0, w1) = fast_weights(lo, len, inv);
                if j >= 0 {
                    acc += w0 * row[j as usize];
                }
                if j + 1 < nx as i32 {
                    acc += w1 * row[(j + 1) as usize];
                }
            } else {
                slow_weights(lo, hi, len, inv, nx, |j, w| acc += w * row[j]);
            }
        }
        acc
    }

    /// Scalar adjoint (ray-driven scatter) for rows `i0 .. i0 + out.len() / nx`.
    pub fn adjoint_rows_scalar(&self, sino: &[f32], i0: usize, out: &mut [f32]) {
        let nx = self.nx;
        let i1 = i0 + out.len() / nx;
        out.fill(0.0);
        for r in 0..self.n_det * self.n_views {
            let y = sino[r];
            let ra = (self.row_lo[r] as usize).max(i0);
            let rb = (self.row_hi[r] as usize).min(i1);
            for i in ra..rb {
                self.scatter_ray_row(r, i, y, &mut out[(i - i0) * nx..(i - i0 + 1) * nx]);
            }
        }
    }

    /// Add ray `r`'s contribution `y * l_rj` to the pixels of one row.
    #[inline]
    pub fn scatter_ray_row(&self, r: usize, i: usize, y: f32, row: &mut [f32]) {
        let nx = self.nx;
        let (lo, hi) = segment(self.x_top[r], self.sx[r], i);
        if self.fast[r] {
            let (j, w0, w1) = fast_weights(lo, self.len[r], self.inv[r]);
            if j >= 0 {
                row[j as usize] += w0 * y;
            }
            if j + 1 < nx as i32 {
                row[(j + 1) as usize] += w1 * y;
            }
        } else {
            slow_weights(lo, hi, self.len[r], self.inv[r], nx, |j, w| row[j] += w * y);
        }
    }

    /// The weights of ray `r` as `(pixel, weight)` in the order the forward
    /// kernel visits them (used by the CSR export).
    pub fn ray_weights(&self, r: usize, mut f: impl FnMut(usize, f32)) {
        let nx = self.nx;
        for i in self.row_lo[r] as usize..self.row_hi[r] as usize {
            let (lo, hi) = segment(self.x_top[r], self.sx[r], i);
            if self.fast[r] {
                let (j, w0, w1) = fast_weights(lo, self.len[r], self.inv[r]);
                if j >= 0 && w0 != 0.0 {
                    f(i * nx + j as usize, w0);
                }
                if j + 1 < nx as i32 && w1 != 0.0 {
                    f(i * nx + (j + 1) as usize, w1);
                }
            } else {
                slow_weights(lo, hi, self.len[r], self.inv[r], nx, |j, w| {
                    f(i * nx + j, w)
                });
            }
        }
    }
}

/// The pixel-driven adjoints' walk over a band of rows (`avx512.rs`,
/// `avx2.rs`): view-major over the task's rows, so that one view's ray
/// parameters stay in L1 while its rows are visited (faster than row-major in
/// `projector-bench`; each pixel still sums the views in order). For each
/// (view, row) with fast rays `row(v, i, view values, inverse map, scratch,
/// image row)` adds them; the slow rays are scattered here. The scratch is
/// per thread and reset, not reallocated, on every call: after the first
/// call on a thread the adjoint allocates nothing (the DBToR slice loop's
/// no-allocation rule). `out` holds whole rows from row `i0`.
pub(crate) fn adjoint_band(
    t: &RayTable,
    sino: &[f32],
    i0: usize,
    out: &mut [f32],
    row: impl Fn(usize, usize, &[f32], &InvMap, &mut RowRays, &mut [f32]),
) {
    thread_local! {
        static SCRATCH: std::cell::RefCell<RowRays> =
            const { std::cell::RefCell::new(RowRays::new()) };
    }
    let (nx, n_det) = (t.nx, t.n_det);
    SCRATCH.with(|cell| {
        let mut s = cell.borrow_mut();
        s.reset(n_det + 2 * PAD, nx.div_ceil(16).next_multiple_of(16));
        out.fill(0.0);
        for v in 0..t.n_views {
            let ys = &sino[v * n_det..(v + 1) * n_det];
            for (di, row_out) in out.chunks_exact_mut(nx).enumerate() {
                let i = i0 + di;
                let map = t.inv_map[v * t.nz + i];
                if map.count > 0 {
                    row(v, i, ys, &map, &mut s, row_out);
                }
                if t.view_has_slow[v] {
                    for k in 0..n_det {
                        let r = v * n_det + k;
                        if !t.fast[r] && t.touches_row(r, i) {
                            t.scatter_ray_row(r, i, ys[k], row_out);
                        }
                    }
                }
            }
        }
    });
}

/// The geometries the SIMD adjoints' unit tests run on: the binned paper
/// geometry; an odd one (rays sparser than pixels, fit ranges ending inside
/// rows); the odd one with rays far sparser than pixels (first pixels more
/// than two apart: the AVX2 pass's rows that are not `packed`), with rays
/// denser than pixels (runs of up to three rays: `count1 > 2`), and with views
/// out to 60 degrees (slow rays).
#[cfg(test)]
pub(crate) fn adjoint_test_geometries() -> Vec<(&'static str, Geometry)> {
    let odd = Geometry::from_toml_str(
        "source_to_center_mm = 400.0\nsource_to_detector_mm = 470.0\n\
         [views]\ncount = 9\nfirst_deg = -21.0\nlast_deg = 17.0\n\
         [detector]\nelements = 331\npitch_mm = 0.61\n\
         [image]\ncolumns = 203\nrows = 77\npixel_mm = 0.37\n",
    )
    .unwrap();
    let mut sparse = odd.clone();
    sparse.detector.elements = 101;
    sparse.detector.pitch_mm = 2.0;
    let mut dense = odd.clone();
    dense.detector.elements = 721;
    dense.detector.pitch_mm = 0.28;
    let mut wide = odd.clone();
    wide.views.first_deg = -60.0;
    wide.views.last_deg = 60.0;
    vec![
        ("binned x4", Geometry::paper().binned(4).unwrap()),
        ("odd", odd),
        ("sparse rays", sparse),
        ("dense rays", dense),
        ("wide", wide),
    ]
}

/// The SIMD adjoints' test of their fit ranges (`avx512.rs`, `avx2.rs`):
/// `adjoint` (whole image, from row 0) against the scalar reference on the
/// test geometries (`adjoint_test_geometries`), with each (view, row)'s verified
/// range `fit_lo .. fit_hi` cut by hand (a sub-range of a verified range is
/// itself valid), so that the scalar pixels before and after the range and
/// the carry into its first block from a scalar pixel run.
#[cfg(test)]
pub(crate) fn check_cut_fit_ranges(adjoint: impl Fn(&RayTable, &[f32], &mut [f32])) {
    use rand::{Rng, SeedableRng};
    for (_, g) in adjoint_test_geometries() {
        let base = RayTable::new(&g);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let y: Vec<f32> = (0..g.n_rays()).map(|_| rng.random::<f32>()).collect();
        let mut reference = vec![0.0; g.n_pixels()];
        base.adjoint_rows_scalar(&y, 0, &mut reference);
        for (cut_lo, cut_hi) in [(0, 0), (1, 0), (3, 2), (0, 1), (usize::MAX, 0)] {
            let mut t = base.clone();
            for m in &mut t.inv_map {
                let lo = (m.fit_lo as usize)
                    .saturating_add(cut_lo)
                    .min(m.fit_hi as usize);
                let hi = (m.fit_hi as usize).saturating_sub(cut_hi).max(lo);
                m.fit_lo = lo as u32;
                m.fit_hi = hi as u32;
            }
            let mut out = vec![0.0; g.n_pixels()];
            adjoint(&t, &y, &mut out);
            for (k, (p, q)) in out.iter().zip(&reference).enumerate() {
                assert!(
                    (p - q).abs() <= 1e-5 * q.abs().max(1.0),
                    "cut ({cut_lo}, {cut_hi}) pixel {k}: {p} vs {q}"
                );
            }
        }
    }
}
