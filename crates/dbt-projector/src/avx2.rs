//! AVX2 kernels (issue #30). The weights come from exactly the scalar
//! reference's operations (`table::segment`, `table::fast_weights`: multiply
//! then add, no fused multiply-add), so they apply the same matrix.
//!
//! * Forward: 8 neighbouring rays of one view per vector, walking down the
//!   rows, the two pixels of each ray gathered. In a view whose rays are all
//!   fast, 16-ray blocks as two halves: in the block's fast rows (the
//!   AVX-512 kernel's, verified when the table was built) one unmasked
//!   64-bit gather fetches both pixels of four rays, and each ray's two
//!   pixels are summed apart and added at the end (the AVX-512 kernel's
//!   order of summation); in its other rows, and in other views' 8-ray blocks of fast
//!   rays, masked gathers summed as the scalar code does. Blocks with a slow
//!   ray, and the tail of a view, go through the scalar code.
//! * Adjoint: per task (a band of rows), view by view and row by row, as the
//!   AVX-512 kernel (`avx512.rs`): a ray pass computes every ray's first
//!   pixel and its two weighted contributions into the shared scratch
//!   (`table::RowRays`; in a view of fast rays only the row's rays, clearing
//!   just what the last row left outside them). The pixels then take their
//!   sums by runs instead of the AVX-512 kernel's candidate lookups (AVX2 has
//!   no two-register permute): in a view whose first pixels are
//!   non-decreasing along the detector the rays of one first pixel are
//!   consecutive, so each ray's running sum over its run, the run's last ray
//!   packed with its vector's other run ends into consecutive lanes (one
//!   permutation from a table of 256) and stored at its pixel, gives every
//!   pixel of the verified range (`InvMap::fit_lo .. fit_hi`) its first and
//!   carried second contributions with one vector load each. The sums are
//!   the AVX-512 kernel's in the same order (`run_sums`), so both give the
//!   same image to the bit; pixels outside the range take the scalar
//!   two-sided candidates, as there.

use crate::table::{
    fast_weights, left_edge_c1, pixel_scalar, segment, slot_c1_scalar, InvMap, RayTable, RowRays,
    NO_PIXEL, PAD,
};
use std::arch::x86_64::*;

const L: usize = 8;

/// The adjoint's branches, counted in test builds only (the test
/// `packed_and_general_run_sums_agree_and_every_path_is_taken` asserts each
/// was taken): ray pass of a packed row, the checked ray pass in a view with
/// slow rays; run sums of a packed row (short runs, longer), of another row
/// (short, longer); in packed rows, vectors with no pixel skipped, one, more;
/// in other rows, vectors stored packed, lane by lane.
#[derive(Clone, Copy)]
#[cfg_attr(not(test), allow(dead_code))]
enum Path {
    RayPassPacked,
    RayPassSlowView,
    PackedShort,
    PackedLong,
    GeneralShort,
    GeneralLong,
    NoGap,
    OneGap,
    Gaps,
    GeneralPacked,
    GeneralLanes,
}

#[cfg(test)]
static PATHS: [std::sync::atomic::AtomicUsize; 11] =
    [const { std::sync::atomic::AtomicUsize::new(0) }; 11];

#[inline(always)]
fn took(path: Path) {
    #[cfg(test)]
    PATHS[path as usize].fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    #[cfg(not(test))]
    let _ = path;
}

/// # Safety
/// Requires AVX2. `r0 .. r0 + out.len()` must be rays of one view.
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn forward_rays(t: &RayTable, img: &[f32], r0: usize, out: &mut [f32]) {
    let n = out.len();
    let v = r0 / t.n_det;
    let mut done = 0;
    if t.view_simd[v] && (r0 - v * t.n_det).is_multiple_of(16) {
        // Whole 16-ray blocks of a SIMD view (every ray fast), with the
        // AVX-512 kernel's fast rows.
        while done + 16 <= n {
            let rb = r0 + done;
            // SAFETY: AVX2 per the contract; rays rb .. rb + 16 exist (one
            // view's, `done + 16 <= n`) and start a block of 16.
            let v = unsafe { forward_block16(t, img, rb) };
            out[done..done + 16].copy_from_slice(&v);
            done += 16;
        }
    }
    while done + L <= n {
        let rb = r0 + done;
        if t.fast[rb..rb + L].iter().all(|f| *f) {
            // SAFETY: AVX2 per the contract; rays rb .. rb + 8 exist (one
            // view's, `done + 8 <= n`).
            let v = unsafe { forward_block(t, img, rb) };
            out[done..done + L].copy_from_slice(&v);
        } else {
            for (k, o) in out[done..done + L].iter_mut().enumerate() {
                *o = t.forward_ray_scalar(rb + k, img);
            }
        }
        done += L;
    }
    for (o, r) in out[done..].iter_mut().zip(r0 + done..) {
        *o = t.forward_ray_scalar(r, img);
    }
}

/// The per-ray parameters of 8 rays from `rb`, in registers.
#[derive(Clone, Copy)]
struct Rays8 {
    x_top: __m256,
    sx: __m256,
    len: __m256,
    inv: __m256,
    row_lo: __m256i,
    row_hi: __m256i,
}

impl Rays8 {
    /// # Safety
    /// AVX2; rays `rb .. rb + 8` exist in the table.
    #[inline(always)]
    unsafe fn load(t: &RayTable, rb: usize) -> Self {
        assert!(rb + L <= t.x_top.len() && rb + L <= t.row_hi.len());
        // SAFETY: AVX2 per the contract; the loads read rays rb .. rb + 8 of
        // the table's arrays (asserted above).
        unsafe {
            Rays8 {
                x_top: dbt_isa::ymm::loadu_ps(t.x_top.as_ptr().add(rb)),
                sx: dbt_isa::ymm::loadu_ps(t.sx.as_ptr().add(rb)),
                len: dbt_isa::ymm::loadu_ps(t.len.as_ptr().add(rb)),
                inv: dbt_isa::ymm::loadu_ps(t.inv.as_ptr().add(rb)),
                row_lo: dbt_isa::ymm::loadu_si256(t.row_lo.as_ptr().add(rb) as *const __m256i),
                row_hi: dbt_isa::ymm::loadu_si256(t.row_hi.as_ptr().add(rb) as *const __m256i),
            }
        }
    }
}

/// One row `i` of 8 fast rays, any of them possibly outside the row or the
/// image: validity masks and masked gathers; adds `w0 x_j` then `w1
/// x_(j+1)` to `acc` as the scalar code does (masked lanes add `w * 0`).
///
/// # Safety
/// AVX2; `i < nz`; `img` holds the image (`nz * nx <= i32::MAX`).
#[inline(always)]
unsafe fn forward_row_masked(
    t: &RayTable,
    img: &[f32],
    r: &Rays8,
    i: usize,
    acc: __m256,
) -> __m256 {
    // SAFETY: AVX2 per the contract; the gathers read only lanes whose pixel
    // is inside row `i` of the image (`0 <= j < nx`).
    unsafe {
        let nx = t.nx;
        let zero = _mm256_setzero_ps();
        let nx_v = _mm256_set1_epi32(nx as i32);
        let minus1 = _mm256_set1_epi32(-1);
        let fi = _mm256_set1_ps(i as f32);
        let iv = _mm256_set1_epi32(i as i32);
        let (jf, w0, w1) = weights8(r.x_top, r.sx, r.len, r.inv, fi);
        let j = _mm256_cvttps_epi32(jf);
        let j1 = _mm256_sub_epi32(j, minus1);
        // Lane is in its ray's rows: row_lo <= i < row_hi.
        let in_rows = _mm256_andnot_si256(
            _mm256_cmpgt_epi32(r.row_lo, iv),
            _mm256_cmpgt_epi32(r.row_hi, iv),
        );
        let inside = |k: __m256i| {
            _mm256_and_si256(_mm256_cmpgt_epi32(k, minus1), _mm256_cmpgt_epi32(nx_v, k))
        };
        let m0 = _mm256_and_si256(in_rows, inside(j));
        let m1 = _mm256_and_si256(in_rows, inside(j1));
        let base = _mm256_set1_epi32((i * nx) as i32);
        let g0 = _mm256_mask_i32gather_ps::<4>(
            zero,
            img.as_ptr(),
            _mm256_add_epi32(base, j),
            _mm256_castsi256_ps(m0),
        );
        let g1 = _mm256_mask_i32gather_ps::<4>(
            zero,
            img.as_ptr(),
            _mm256_add_epi32(base, j1),
            _mm256_castsi256_ps(m1),
        );
        let w0m = _mm256_and_ps(w0, _mm256_castsi256_ps(m0));
        let w1m = _mm256_and_ps(w1, _mm256_castsi256_ps(m1));
        let acc = _mm256_add_ps(acc, _mm256_mul_ps(w0m, g0));
        _mm256_add_ps(acc, _mm256_mul_ps(w1m, g1))
    }
}

/// # Safety
/// AVX2; rays `rb .. rb + 8` exist in the table and are fast rays.
#[target_feature(enable = "avx2")]
unsafe fn forward_block(t: &RayTable, img: &[f32], rb: usize) -> [f32; L] {
    // SAFETY: AVX2 per the contract; `Rays8::load` reads rays rb .. rb + 8;
    // every row passed to `forward_row_masked` is below `nz`.
    unsafe {
        assert!(img.len() >= t.nz * t.nx && t.nz * t.nx <= i32::MAX as usize);
        let r = Rays8::load(t, rb);
        let i_start = t.row_lo[rb..rb + L].iter().copied().min().unwrap_or(0) as usize;
        let i_end = t.row_hi[rb..rb + L].iter().copied().max().unwrap_or(0) as usize;
        assert!(i_end <= t.nz);
        let mut acc = _mm256_setzero_ps();
        for i in i_start..i_end {
            acc = forward_row_masked(t, img, &r, i, acc);
        }
        let mut a = [0.0f32; L];
        dbt_isa::ymm::storeu_ps(a.as_mut_ptr(), acc);
        a
    }
}

/// A block of 16 rays of a SIMD view as two halves of 8: the rows outside
/// the block's fast rows with [`forward_row_masked`], the fast rows (every
/// ray inside the image and its two pixels in the row, verified when the
/// table was built, `RayTable::forward_fast_rows`) with unmasked 64-bit
/// gathers of each ray's pixel pair and, per ray, one sum for each of its
/// two pixels (the AVX-512 kernel's order of summation).
///
/// # Safety
/// AVX2; rays `rb .. rb + 16` exist in the table, are one view's and start
/// one of its 16-ray blocks.
#[target_feature(enable = "avx2")]
unsafe fn forward_block16(t: &RayTable, img: &[f32], rb: usize) -> [f32; 16] {
    // SAFETY: AVX2 per the contract; `Rays8::load` reads rays rb .. rb + 16;
    // the masked rows are below `nz`; in the fast rows every gathered index
    // `i nx + j` and `i nx + j + 1` is a pixel of row `i` (verified at
    // construction: `0 <= j` and `j + 1 < nx` for each of the 16 rays).
    unsafe {
        let nx = t.nx;
        assert!(img.len() >= t.nz * nx && t.nz * nx <= i32::MAX as usize);
        let halves = [Rays8::load(t, rb), Rays8::load(t, rb + L)];
        let i_start = t.row_lo[rb..rb + 16].iter().copied().min().unwrap_or(0) as usize;
        let i_end =
            (t.row_hi[rb..rb + 16].iter().copied().max().unwrap_or(0) as usize).max(i_start);
        assert!(i_end <= t.nz);
        let v = rb / t.n_det;
        let (fa, fb) = t.fwd_rows[v * t.blocks_per_view() + (rb - v * t.n_det) / 16];
        let (fa, fb) = if fa < fb {
            (fa as usize, fb as usize)
        } else {
            (i_end, i_end)
        };
        assert!(fb <= t.nz);
        let mut res = [0f32; 16];
        for (h, r) in halves.iter().enumerate() {
            let mut acc = _mm256_setzero_ps();
            for i in (i_start..fa.min(i_end)).chain(fb.max(i_start)..i_end) {
                acc = forward_row_masked(t, img, r, i, acc);
            }
            // Each ray's two pixels are neighbours: one 64-bit gather
            // fetches both, four rays per gather, in the lane order that
            // `unpacklo/hi(w0, w1)` gives the weights (rays 0, 1, 4, 5 and
            // 2, 3, 6, 7); a horizontal add then sums each ray's pair.
            let order = _mm256_setr_epi32(0, 1, 4, 5, 2, 3, 6, 7);
            let one = _mm256_set1_ps(1.0);
            let mut fi = _mm256_set1_ps(fa as f32);
            let (mut acc0, mut acc1) = (_mm256_setzero_ps(), _mm256_setzero_ps());
            let pairs = img.as_ptr() as *const f64;
            for i in fa..fb {
                let (jf, w0, w1) = weights8(r.x_top, r.sx, r.len, r.inv, fi);
                let idx =
                    _mm256_add_epi32(_mm256_set1_epi32((i * nx) as i32), _mm256_cvttps_epi32(jf));
                let idx = _mm256_permutevar8x32_epi32(idx, order);
                let pa = _mm256_i32gather_pd::<4>(pairs, _mm256_castsi256_si128(idx));
                let pb = _mm256_i32gather_pd::<4>(pairs, _mm256_extracti128_si256::<1>(idx));
                let ya = _mm256_mul_ps(_mm256_castpd_ps(pa), _mm256_unpacklo_ps(w0, w1));
                let yb = _mm256_mul_ps(_mm256_castpd_ps(pb), _mm256_unpackhi_ps(w0, w1));
                // Lanes (w0 x_j, w1 x_(j+1)) per ray, added in pairs by the
                // accumulators' final horizontal add.
                acc0 = _mm256_add_ps(acc0, ya);
                acc1 = _mm256_add_ps(acc1, yb);
                fi = _mm256_add_ps(fi, one);
            }
            acc = _mm256_add_ps(acc, _mm256_hadd_ps(acc0, acc1));
            dbt_isa::ymm::storeu_ps(res.as_mut_ptr().add(h * L), acc);
        }
        res
    }
}

/// `table::segment` and `table::fast_weights` for 8 rays at row `fi`, with
/// the same operations: `(floor(lo), w0, w1)`.
///
/// # Safety
/// The caller runs with AVX2 enabled.
#[inline(always)]
unsafe fn weights8(
    x_top: __m256,
    sx: __m256,
    len: __m256,
    inv: __m256,
    fi: __m256,
) -> (__m256, __m256, __m256) {
    // SAFETY: AVX2 per the contract; registers only.
    unsafe {
        let one = _mm256_set1_ps(1.0);
        let xt = _mm256_add_ps(x_top, _mm256_mul_ps(fi, sx));
        let xb = _mm256_add_ps(xt, sx);
        let lo = _mm256_min_ps(xt, xb);
        let jf = _mm256_floor_ps(lo);
        let frac = _mm256_mul_ps(_mm256_sub_ps(_mm256_add_ps(jf, one), lo), inv);
        let w0 = _mm256_mul_ps(len, _mm256_min_ps(frac, one));
        (jf, w0, _mm256_sub_ps(len, w0))
    }
}

/// # Safety
/// Requires AVX2. `out` holds whole rows starting at row `i0`.
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn adjoint_rows(t: &RayTable, sino: &[f32], i0: usize, out: &mut [f32]) {
    crate::table::adjoint_band(t, sino, i0, out, |v, i, ys, map, s, row_out| {
        // SAFETY: AVX2 per this function's contract; `adjoint_band` passes
        // a view and row of the table, the view's values, scratch sized for
        // the table and one image row.
        unsafe {
            ray_pass(t, v, i, ys, s);
            pixel_pass(t, map, s, row_out);
        }
    });
}

/// # Safety
/// AVX2; `v` is a view and `i` a row of the table; `ys` holds the view's
/// `n_det` values; `s` is sized for the table (`PAD` entries on both sides of
/// `n_det`).
#[target_feature(enable = "avx2")]
#[inline(never)]
unsafe fn ray_pass(t: &RayTable, v: usize, i: usize, ys: &[f32], s: &mut RowRays) {
    let n_det = t.n_det;
    assert!(ys.len() >= n_det && s.j.len() >= n_det + 2 * PAD);
    assert!(s.c0.len() >= n_det + 2 * PAD && s.c1.len() >= n_det + 2 * PAD);
    let base = v * n_det;
    assert!(base + n_det <= t.x_top.len() && base + n_det <= t.row_hi.len());
    assert!(base + n_det <= t.sx.len() && base + n_det <= t.len.len());
    assert!(base + n_det <= t.inv.len() && base + n_det <= t.row_lo.len());
    let map = &t.inv_map[v * t.nz + i];
    let (k_lo, k_hi) = (map.ray_lo as usize, map.ray_hi as usize);
    assert!(k_lo <= k_hi && k_hi <= n_det);
    if !map.packed {
        if t.view_has_slow[v] {
            took(Path::RayPassSlowView);
        }
        // SAFETY: AVX2 and the buffers' lengths per the contract (asserted).
        unsafe { ray_pass_checked(t, v, i, ys, s) };
        s.live = (0, n_det);
        return;
    }
    // A `packed` row: every ray of the view is fast, and the rays inside the
    // row are exactly `k_lo .. k_hi` (verified at construction): clear what
    // the last row left outside them, then compute them.
    let (live_lo, live_hi) = s.live;
    let left = live_lo..k_lo.clamp(live_lo, live_hi);
    let right = k_hi.clamp(live_lo, live_hi)..live_hi;
    for r in [left, right] {
        let r = PAD + r.start..PAD + r.end;
        s.j[r.clone()].fill(NO_PIXEL);
        s.c0[r.clone()].fill(0.0);
        s.c1[r].fill(0.0);
    }
    s.live = (k_lo, k_hi);
    took(Path::RayPassPacked);
    // SAFETY: AVX2 per the contract; the vectors cover rays `k .. k + 8 <=
    // k_hi <= n_det` of the view (table loads at `base + k`, `ys` at `k`, the
    // scratch stores at `PAD + k`), all inside the asserted lengths.
    unsafe {
        let fi = _mm256_set1_ps(i as f32);
        let (jp, c0p, c1p) = (s.j.as_mut_ptr(), s.c0.as_mut_ptr(), s.c1.as_mut_ptr());
        let mut k = k_lo;
        while k + L <= k_hi {
            let (j, c0, c1) = contributions8(t, base + k, ys.as_ptr().add(k), fi);
            dbt_isa::ymm::storeu_si256(jp.add(PAD + k) as *mut __m256i, j);
            dbt_isa::ymm::storeu_ps(c0p.add(PAD + k), c0);
            dbt_isa::ymm::storeu_ps(c1p.add(PAD + k), c1);
            k += L;
        }
        for k in k..k_hi {
            (s.j[PAD + k], s.c0[PAD + k], s.c1[PAD + k]) = contributions(t, base + k, i, ys[k]);
        }
    }
}

/// Rays `r .. r + 8` at row `fi`: first pixels and the two contributions of
/// the values at `y` (`weights8`, the scalar reference's operations).
///
/// # Safety
/// AVX2; rays `r .. r + 8` in the table, 8 values at `y`.
#[inline(always)]
unsafe fn contributions8(
    t: &RayTable,
    r: usize,
    y: *const f32,
    fi: __m256,
) -> (__m256i, __m256, __m256) {
    // SAFETY: per the contract.
    unsafe {
        let (jf, w0, w1) = weights8(
            dbt_isa::ymm::loadu_ps(t.x_top.as_ptr().add(r)),
            dbt_isa::ymm::loadu_ps(t.sx.as_ptr().add(r)),
            dbt_isa::ymm::loadu_ps(t.len.as_ptr().add(r)),
            dbt_isa::ymm::loadu_ps(t.inv.as_ptr().add(r)),
            fi,
        );
        let y = dbt_isa::ymm::loadu_ps(y);
        (
            _mm256_cvttps_epi32(jf),
            _mm256_mul_ps(w0, y),
            _mm256_mul_ps(w1, y),
        )
    }
}

/// One fast ray `r` at row `i`: `contributions8` in scalar code.
#[inline(always)]
fn contributions(t: &RayTable, r: usize, i: usize, y: f32) -> (i32, f32, f32) {
    let (lo, _) = segment(t.x_top[r], t.sx[r], i);
    let (j, w0, w1) = fast_weights(lo, t.len[r], t.inv[r]);
    (j, w0 * y, w1 * y)
}

/// The ray pass in rows not `packed` (views with slow rays, rows no ray
/// touches, ...): every ray of the view written, those outside the row or
/// slow as `NO_PIXEL` and zeros.
///
/// # Safety
/// As `ray_pass`, the lengths asserted there.
#[target_feature(enable = "avx2")]
unsafe fn ray_pass_checked(t: &RayTable, v: usize, i: usize, ys: &[f32], s: &mut RowRays) {
    // SAFETY: AVX2 per the contract; the 8-ray blocks start at `k` with `k + 8
    // <= n_det`, so the per-ray loads, the `ys` loads and the scratch stores at
    // `PAD + k` stay inside their buffers.
    unsafe {
        let n_det = t.n_det;
        let base = v * n_det;
        let ii = _mm256_set1_epi32(i as i32);
        let fi = _mm256_set1_ps(i as f32);
        let nop = _mm256_set1_epi32(NO_PIXEL);
        let has_slow = t.view_has_slow[v];
        let (jp, c0p, c1p) = (s.j.as_mut_ptr(), s.c0.as_mut_ptr(), s.c1.as_mut_ptr());
        let mut k = 0;
        while k + L <= n_det {
            let r = base + k;
            let (j, c0, c1) = contributions8(t, r, ys.as_ptr().add(k), fi);
            // Rays inside the row (row_lo <= i < row_hi) and fast.
            let row_lo = dbt_isa::ymm::loadu_si256(t.row_lo.as_ptr().add(r) as *const __m256i);
            let row_hi = dbt_isa::ymm::loadu_si256(t.row_hi.as_ptr().add(r) as *const __m256i);
            let mut valid = _mm256_andnot_si256(
                _mm256_cmpgt_epi32(row_lo, ii),
                _mm256_cmpgt_epi32(row_hi, ii),
            );
            if has_slow {
                let mut fast = [0i32; L];
                for (l, f) in fast.iter_mut().enumerate() {
                    *f = if t.fast[r + l] { -1 } else { 0 };
                }
                valid = _mm256_and_si256(
                    valid,
                    dbt_isa::ymm::loadu_si256(fast.as_ptr() as *const __m256i),
                );
            }
            let vf = _mm256_castsi256_ps(valid);
            dbt_isa::ymm::storeu_si256(
                jp.add(PAD + k) as *mut __m256i,
                _mm256_blendv_epi8(nop, j, valid),
            );
            dbt_isa::ymm::storeu_ps(c0p.add(PAD + k), _mm256_and_ps(c0, vf));
            dbt_isa::ymm::storeu_ps(c1p.add(PAD + k), _mm256_and_ps(c1, vf));
            k += L;
        }
        for k in k..n_det {
            let r = base + k;
            if t.touches_row(r, i) && t.fast[r] {
                (s.j[PAD + k], s.c0[PAD + k], s.c1[PAD + k]) = contributions(t, r, i, ys[k]);
            } else {
                s.j[PAD + k] = NO_PIXEL;
                s.c0[PAD + k] = 0.0;
                s.c1[PAD + k] = 0.0;
            }
        }
    }
}

/// Pixel pass (see the module's documentation): in a row with a verified
/// fit range, the run sums of `run_sums` added to the fit range's pixels in
/// vectors of 8, other pixels with the scalar two-sided candidates.
///
/// # Safety
/// AVX2; `s` was filled by `ray_pass` for this row; `row_out` is one image
/// row.
#[target_feature(enable = "avx2")]
unsafe fn pixel_pass(t: &RayTable, map: &InvMap, s: &mut RowRays, row_out: &mut [f32]) {
    // SAFETY: AVX2 per the contract; the loads of `a0` (from `p + 1`) and
    // `a1` (from `p`) and the stores to `row_out` (at `p`) cover 8 pixels
    // from `p < nx`, the row's last ones masked to its end; `a0` and `a1`
    // hold `16 nb + 16 >= nx + 16` entries.
    unsafe {
        let (nx, n_det) = (t.nx, t.n_det);
        assert_eq!(row_out.len(), nx);
        let (fit_lo, fit_hi) = (map.fit_lo as usize, map.fit_hi as usize);
        for j in 0..(fit_lo * 16).min(nx) {
            row_out[j] += pixel_scalar(map, s, n_det, j);
        }
        if fit_lo < fit_hi {
            run_sums(t, map, s);
            let jb = fit_lo * 16;
            let je = (fit_hi * 16).min(nx);
            assert!(je + L < s.a0.len() && je + L <= s.a1.len());
            // The second contributions carried into the fit range's first
            // pixel, as the AVX-512 kernel takes them.
            s.a1[jb] = if jb == 0 {
                left_edge_c1(map, &s.j, &s.c1)
            } else {
                slot_c1_scalar(map, s, n_det, jb - 1)
            };
            let lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
            let (a0p, a1p) = (s.a0.as_ptr(), s.a1.as_ptr());
            let mut p = jb;
            while p < je {
                let o = row_out.as_mut_ptr().add(p);
                // The pixel's own rays' first contributions, then the second
                // ones of the pixel before (the AVX-512 kernel's order).
                let sum = _mm256_add_ps(
                    dbt_isa::ymm::loadu_ps(a0p.add(p + 1)),
                    dbt_isa::ymm::loadu_ps(a1p.add(p)),
                );
                if p + L <= je {
                    dbt_isa::ymm::storeu_ps(o, _mm256_add_ps(dbt_isa::ymm::loadu_ps(o), sum));
                } else {
                    // The range's last, partial vector: pixels past it are
                    // neither read nor written.
                    let m = _mm256_cmpgt_epi32(_mm256_set1_epi32((je - p) as i32), lanes);
                    _mm256_maskstore_ps(o, m, _mm256_add_ps(_mm256_maskload_ps(o, m), sum));
                }
                p += L;
            }
        }
        for (j, o) in row_out.iter_mut().enumerate().skip(fit_hi.max(fit_lo) * 16) {
            // Past the fit range (empty when the range reaches the row's end).
            *o += pixel_scalar(map, s, n_det, j);
        }
    }
}

/// For mask `m` of 8 lanes, the positions of its set bits in ascending order
/// (then zeros): the permutation that packs a vector's run ends together.
const PACK: [[u8; 8]; 256] = {
    let mut t = [[0u8; 8]; 256];
    let mut m = 0;
    while m < 256 {
        let (mut l, mut n) = (0, 0);
        while l < 8 {
            if m & (1 << l) != 0 {
                t[m][n] = l as u8;
                n += 1;
            }
            l += 1;
        }
        m += 1;
    }
    t
};

/// The run sums of one row (`RowRays::a0`, `a1`): in a view whose first
/// pixels are non-decreasing along the detector (every view with a fit
/// range), the rays whose first pixel is `j` are consecutive, at most
/// `count1` of them (the verified candidate count). Each ray's running sum
/// over its run so far, `s_k = (s_{k-1} if j_{k-1} = j_k else +0) + c_k`, is
/// the AVX-512 pixel pass's sum, the same additions in the same order (it
/// adds a pixel's matching candidates in ray order to `+0`, leaving the
/// others out); a run's last ray holds the pixel's sum, and a pixel no ray
/// starts in keeps `+0`, as there. The last rays of
/// the runs in each 8-ray vector are packed into consecutive lanes and stored
/// at their first pixel's entry, zeros in the lanes after them (at pixels
/// whose runs come later in ray order, or that have no ray).
///
/// # Safety
/// AVX2; `s` was filled by `ray_pass` for this row and the row's view has a
/// fit range (`map.fit_lo < map.fit_hi`: non-decreasing first pixels).
#[target_feature(enable = "avx2")]
unsafe fn run_sums(t: &RayTable, map: &InvMap, s: &mut RowRays) {
    // SAFETY: AVX2 per the contract. The ray vectors start at scratch index
    // `e = PAD + k` with `ray_lo <= k < ray_hi <= n_det`, and read `e - 1 ..
    // e + 9 <= n_det + PAD + 9 <= n_det + 2 PAD` (the scratch's length,
    // asserted).
    unsafe {
        let (nx, n) = (t.nx, t.n_det + 2 * PAD);
        assert!(s.j.len() >= n && s.c0.len() >= n && s.c1.len() >= n);
        assert!(s.t0.len() >= n && s.t1.len() >= n);
        assert!(s.a0.len() >= nx + 16 && s.a1.len() >= nx + 16);
        let (k_lo, k_hi) = (map.ray_lo as usize, map.ray_hi as usize);
        assert!(k_hi <= t.n_det);
        if k_lo >= k_hi {
            // No ray in the row (a verified range implies some).
            s.a0.fill(0.0);
            s.a1.fill(0.0);
            return;
        }
        // Runs longer than two: the running sums up to the run's
        // `count1 - 1`-th ray, one more each pass; a pass goes down the
        // detector so that it reads the previous pass's sums below it.
        let long = map.count1 > 2;
        if long {
            // Up to the last vector's end (its lanes past `k_hi` are no
            // run ends; copied so that they hold those rays' zeros).
            let span = PAD + k_lo - 1..PAD + k_lo + (k_hi - k_lo).div_ceil(L) * L + 1;
            s.t0[span.clone()].copy_from_slice(&s.c0[span.clone()]);
            s.t1[span.clone()].copy_from_slice(&s.c1[span]);
            let (jp, c0p, c1p) = (s.j.as_ptr(), s.c0.as_ptr(), s.c1.as_ptr());
            let (t0p, t1p) = (s.t0.as_mut_ptr(), s.t1.as_mut_ptr());
            for _ in 2..map.count1 {
                let mut k = k_lo + (k_hi - k_lo).div_ceil(L) * L;
                while k > k_lo {
                    k -= L;
                    let e = PAD + k;
                    let same = _mm256_castsi256_ps(_mm256_cmpeq_epi32(
                        dbt_isa::ymm::loadu_si256(jp.add(e - 1) as *const __m256i),
                        dbt_isa::ymm::loadu_si256(jp.add(e) as *const __m256i),
                    ));
                    let v0 = _mm256_add_ps(
                        _mm256_and_ps(dbt_isa::ymm::loadu_ps(t0p.add(e - 1)), same),
                        dbt_isa::ymm::loadu_ps(c0p.add(e)),
                    );
                    let v1 = _mm256_add_ps(
                        _mm256_and_ps(dbt_isa::ymm::loadu_ps(t1p.add(e - 1)), same),
                        dbt_isa::ymm::loadu_ps(c1p.add(e)),
                    );
                    dbt_isa::ymm::storeu_ps(t0p.add(e), v0);
                    dbt_isa::ymm::storeu_ps(t1p.add(e), v1);
                }
            }
        }
        let rays = Rays {
            j: s.j.as_ptr(),
            c0: s.c0.as_ptr(),
            c1: s.c1.as_ptr(),
            t0: s.t0.as_ptr(),
            t1: s.t1.as_ptr(),
        };
        let (e_lo, e_hi) = (PAD + k_lo, PAD + k_hi);
        let (a0, a1) = (&mut s.a0[..nx + 16], &mut s.a1[..nx + 16]);
        took(match (map.packed, long) {
            (true, false) => Path::PackedShort,
            (true, true) => Path::PackedLong,
            (false, false) => Path::GeneralShort,
            (false, true) => Path::GeneralLong,
        });
        if map.packed {
            // Entries `at0 .. at` are written; the pixel pass reads the fit
            // range's, `fit_lo * 16 ..= min(fit_hi * 16, nx)`.
            let at0 = (*rays.j.add(e_lo) + 1) as usize;
            let at = if long {
                packed_runs::<true>(&rays, e_lo, e_hi, at0, a0, a1)
            } else {
                packed_runs::<false>(&rays, e_lo, e_hi, at0, a0, a1)
            };
            let (jb, je) = (map.fit_lo as usize * 16, (map.fit_hi as usize * 16).min(nx));
            let clamp = |a: usize| a.clamp(jb, je + 1);
            for a in [a0, a1] {
                a[jb..clamp(at0)].fill(0.0);
                a[clamp(at)..je + 1].fill(0.0);
            }
        } else {
            a0.fill(0.0);
            a1.fill(0.0);
            if long {
                general_runs::<true>(&rays, e_lo, e_hi, a0, a1)
            } else {
                general_runs::<false>(&rays, e_lo, e_hi, a0, a1)
            }
        }
    }
}

/// A row's ray scratch: first pixels, contributions, and the partial run
/// sums of the passes for runs longer than two rays (`RowRays::t0`, `t1`).
struct Rays {
    j: *const i32,
    c0: *const f32,
    c1: *const f32,
    t0: *const f32,
    t1: *const f32,
}

/// For the 8 rays from scratch index `e`: the run ends' lane mask, the
/// running sums of first and second contributions, the first pixels and
/// their predecessors'. `LONG`: the running sums before each ray are in
/// `t0`, `t1` (else they are the predecessor's contributions).
///
/// # Safety
/// AVX2; `e - 1 .. e + 9` inside the scratch.
#[inline(always)]
unsafe fn sums<const LONG: bool>(r: &Rays, e: usize) -> (u32, __m256, __m256, __m256i, __m256i) {
    // SAFETY: per the contract.
    unsafe {
        let jm = dbt_isa::ymm::loadu_si256(r.j.add(e - 1) as *const __m256i);
        let j0 = dbt_isa::ymm::loadu_si256(r.j.add(e) as *const __m256i);
        let next = dbt_isa::ymm::loadu_si256(r.j.add(e + 1) as *const __m256i);
        // Rays inside the row whose successor has another first pixel.
        let not_end = _mm256_or_si256(
            _mm256_cmpeq_epi32(j0, next),
            _mm256_cmpeq_epi32(j0, _mm256_set1_epi32(NO_PIXEL)),
        );
        let m = !(_mm256_movemask_ps(_mm256_castsi256_ps(not_end)) as u32) & 0xff;
        let same = _mm256_castsi256_ps(_mm256_cmpeq_epi32(jm, j0));
        let (p0, p1) = if LONG { (r.t0, r.t1) } else { (r.c0, r.c1) };
        let s0 = _mm256_add_ps(
            _mm256_and_ps(dbt_isa::ymm::loadu_ps(p0.add(e - 1)), same),
            dbt_isa::ymm::loadu_ps(r.c0.add(e)),
        );
        let s1 = _mm256_add_ps(
            _mm256_and_ps(dbt_isa::ymm::loadu_ps(p1.add(e - 1)), same),
            dbt_isa::ymm::loadu_ps(r.c1.add(e)),
        );
        (m, s0, s1, j0, jm)
    }
}

/// The lanes of `m` packed into the first ones; the lanes after them are
/// any of the vector's (`pack`: zeros).
///
/// # Safety
/// AVX2.
#[inline(always)]
unsafe fn pack_any(m: u32, s0: __m256, s1: __m256) -> (__m256, __m256) {
    // SAFETY: AVX2; `PACK[m & 0xff]` is 8 bytes.
    unsafe {
        let idx = _mm256_cvtepu8_epi32(_mm_loadl_epi64(
            PACK[m as usize & 0xff].as_ptr() as *const __m128i
        ));
        (
            _mm256_permutevar8x32_ps(s0, idx),
            _mm256_permutevar8x32_ps(s1, idx),
        )
    }
}

/// The lanes of `m` packed into the first ones, zeros after them.
///
/// # Safety
/// AVX2.
#[inline(always)]
unsafe fn pack(m: u32, s0: __m256, s1: __m256) -> (__m256, __m256) {
    // SAFETY: AVX2.
    unsafe {
        let (v0, v1) = pack_any(m, s0, s1);
        let keep = _mm256_castsi256_ps(_mm256_cmpgt_epi32(
            _mm256_set1_epi32(m.count_ones() as i32),
            _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
        ));
        (_mm256_and_ps(v0, keep), _mm256_and_ps(v1, keep))
    }
}

/// `run_sums` in a `packed` row (`InvMap::packed`): the run ends are the
/// pixels from the first ray's on, one after the other but where a ray's
/// first pixel is two past its predecessor's, so each vector's are stored
/// where the last one's stop, in two parts around one such pixel without
/// rays (left at zero), lane by lane around more. Returns the entry after
/// the last run end's (`at0`: the first ray's); the entries from there to
/// the end of the last store hold any values.
///
/// # Safety
/// AVX2; the ray vectors from `e_lo` before `e_hi` inside the scratch as in
/// `run_sums`; the row `packed`.
#[target_feature(enable = "avx2")]
#[inline(never)]
unsafe fn packed_runs<const LONG: bool>(
    r: &Rays,
    e_lo: usize,
    e_hi: usize,
    at0: usize,
    a0: &mut [f32],
    a1: &mut [f32],
) -> usize {
    // SAFETY: AVX2 and the scratch per the contract; every store is at
    // `at .. at + 16` with `at` a run end's first pixel plus one, at most
    // `nx` (`packed`), checked against the entries' length before it.
    unsafe {
        let len = a0.len().min(a1.len());
        let (a0p, a1p) = (a0.as_mut_ptr(), a1.as_mut_ptr());
        let two = _mm256_set1_epi32(2);
        let mut at = at0;
        let mut e = e_lo;
        while e < e_hi {
            let (m, s0, s1, j0, jm) = sums::<LONG>(r, e);
            // Rays two pixels past their predecessor (never one outside the
            // row: `NO_PIXEL` is far from every pixel).
            let gap = _mm256_cmpeq_epi32(_mm256_sub_epi32(j0, jm), two);
            let g = _mm256_movemask_ps(_mm256_castsi256_ps(gap)) as u32;
            assert!(at + 2 * L <= len);
            if g == 0 {
                took(Path::NoGap);
                // The lanes after the run ends land where later vectors'
                // run ends, or the zeros after the loop, go.
                let (v0, v1) = pack_any(m, s0, s1);
                dbt_isa::ymm::storeu_ps(a0p.add(at), v0);
                dbt_isa::ymm::storeu_ps(a1p.add(at), v1);
                at += m.count_ones() as usize;
            } else if g & (g - 1) == 0 {
                took(Path::OneGap);
                let (lo, hi) = (m & (g - 1), m & !(g - 1));
                let (v0, v1) = pack(lo, s0, s1);
                dbt_isa::ymm::storeu_ps(a0p.add(at), v0);
                dbt_isa::ymm::storeu_ps(a1p.add(at), v1);
                at += lo.count_ones() as usize + 1;
                let (v0, v1) = pack_any(hi, s0, s1);
                dbt_isa::ymm::storeu_ps(a0p.add(at), v0);
                dbt_isa::ymm::storeu_ps(a1p.add(at), v1);
                at += hi.count_ones() as usize;
            } else {
                // The vector's run ends span at most 16 pixels (8 rays, each
                // at most two pixels on): zeros first, then lane by lane.
                took(Path::Gaps);
                let zero = _mm256_setzero_ps();
                for a in [a0p, a1p] {
                    dbt_isa::ymm::storeu_ps(a.add(at), zero);
                    dbt_isa::ymm::storeu_ps(a.add(at + L), zero);
                }
                let (mut v0, mut v1) = ([0f32; L], [0f32; L]);
                dbt_isa::ymm::storeu_ps(v0.as_mut_ptr(), s0);
                dbt_isa::ymm::storeu_ps(v1.as_mut_ptr(), s1);
                for l in 0..L {
                    if m & (1 << l) != 0 {
                        at = (*r.j.add(e + l) + 1) as usize;
                        assert!(at < len);
                        *a0p.add(at) = v0[l];
                        *a1p.add(at) = v1[l];
                        at += 1;
                    }
                }
            }
            e += L;
        }
        at
    }
}

/// `run_sums` in other rows: each vector's run ends stored with one packed
/// store where their pixels are consecutive and inside `-1 .. nx`, else lane
/// by lane (pixels `-1 .. nx` only). `a0`, `a1` are zero before.
///
/// # Safety
/// As `packed_runs`, but for any row with a fit range.
#[target_feature(enable = "avx2")]
unsafe fn general_runs<const LONG: bool>(
    r: &Rays,
    e_lo: usize,
    e_hi: usize,
    a0: &mut [f32],
    a1: &mut [f32],
) {
    // SAFETY: AVX2 and the scratch per the contract; the packed stores are
    // at `j_f + 1 .. j_f + 9` with `-1 <= j_f <= j_l < nx`, inside the `nx +
    // 16` entries (asserted by the caller's slicing), the lane stores at
    // `j + 1` with `-1 <= j < nx`.
    unsafe {
        let nx = a0.len().min(a1.len()) - 16;
        let (a0p, a1p) = (a0.as_mut_ptr(), a1.as_mut_ptr());
        let mut e = e_lo;
        while e < e_hi {
            let (m, s0, s1, _, _) = sums::<LONG>(r, e);
            if m != 0 {
                let count = m.count_ones() as i32;
                let jf = *r.j.add(e + m.trailing_zeros() as usize);
                let jl = *r.j.add(e + 31 - m.leading_zeros() as usize);
                if jl - jf + 1 == count && jf >= -1 && jl < nx as i32 {
                    took(Path::GeneralPacked);
                    let (v0, v1) = pack(m, s0, s1);
                    let at = (jf + 1) as usize;
                    dbt_isa::ymm::storeu_ps(a0p.add(at), v0);
                    dbt_isa::ymm::storeu_ps(a1p.add(at), v1);
                } else {
                    took(Path::GeneralLanes);
                    let (mut v0, mut v1) = ([0f32; L], [0f32; L]);
                    dbt_isa::ymm::storeu_ps(v0.as_mut_ptr(), s0);
                    dbt_isa::ymm::storeu_ps(v1.as_mut_ptr(), s1);
                    for l in 0..L {
                        if m & (1 << l) != 0 {
                            let j = *r.j.add(e + l);
                            if (-1..nx as i32).contains(&j) {
                                *a0p.add((j + 1) as usize) = v0[l];
                                *a1p.add((j + 1) as usize) = v1[l];
                            }
                        }
                    }
                }
            }
            e += L;
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::table::{adjoint_test_geometries, RayTable};
    use rand::{Rng, SeedableRng};

    /// As the AVX-512 kernel's test of the same name: cutting the fit ranges
    /// by hand exercises the scalar pixels before and after them and the
    /// carry into the first SIMD block from a scalar pixel.
    #[test]
    fn cut_fit_ranges_match_the_scalar_adjoint() {
        if !dbt_isa::kernel_test_runs("projector avx2 fit ranges", &["avx2"]) {
            return;
        }
        // SAFETY: AVX2 detected above.
        crate::table::check_cut_fit_ranges(|t, y, out| unsafe {
            super::adjoint_rows(t, y, 0, out)
        });
    }

    /// A row's run sums are the same to the bit whether stored packed or
    /// pixel by pixel (`general_runs`, forced on every row in a second run),
    /// on every test geometry, with signed values and zeros of both signs;
    /// and the two runs took every branch of the adjoint (`Path`, counted in
    /// test builds).
    #[test]
    fn packed_and_general_run_sums_agree_and_every_path_is_taken() {
        if !dbt_isa::kernel_test_runs("projector avx2 run sums", &["avx2"]) {
            return;
        }
        for (name, g) in adjoint_test_geometries() {
            let t = RayTable::new(&g);
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
            let y: Vec<f32> = (0..g.n_rays())
                .map(|k| match k % 13 {
                    0 => 0.0,
                    7 => -0.0,
                    _ => rng.random::<f32>() - 0.5,
                })
                .collect();
            let mut general = t.clone();
            for m in &mut general.inv_map {
                m.packed = false;
            }
            let (mut a, mut b) = (vec![0.0; g.n_pixels()], vec![0.0; g.n_pixels()]);
            // SAFETY: AVX2 detected above.
            unsafe {
                super::adjoint_rows(&t, &y, 0, &mut a);
                super::adjoint_rows(&general, &y, 0, &mut b);
            }
            let first = a
                .iter()
                .zip(&b)
                .position(|(p, q)| p.to_bits() != q.to_bits());
            assert_eq!(first, None, "{name}: packed and general run sums differ");
        }
        let taken: Vec<usize> = super::PATHS
            .iter()
            .map(|n| n.load(std::sync::atomic::Ordering::Relaxed))
            .collect();
        assert!(
            taken.iter().all(|&n| n > 0),
            "branches not taken (`Path` order): {taken:?}"
        );
    }
}
