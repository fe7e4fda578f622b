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
//! * Adjoint: the AVX-512 kernel's pixel-driven scheme (`avx512.rs`) on
//!   8-lane vectors: per task (a band of rows), view by view and row by
//!   row, a ray pass computes every ray's first pixel and its two weighted
//!   contributions into the shared scratch (`table::RowRays`); a pixel pass
//!   then takes each verified 16-pixel block of the inverse map
//!   (`InvMap::fit_lo .. fit_hi`) as two halves of 8 pixels, gathers each
//!   pixel's candidate rays from the block's 32-entry window (AVX2 has no
//!   two-register permute), adds the first contributions of the rays whose
//!   first pixel it is and carries their second ones one pixel right. The
//!   candidates, the window and the order of every sum are the AVX-512
//!   kernel's, so both give the same image.

use crate::table::{
    fast_weights, left_edge_c1, pixel_scalar, segment, slot_c1_scalar, InvMap, RayTable, RowRays,
    NO_PIXEL, PAD,
};
use std::arch::x86_64::*;

const L: usize = 8;

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
unsafe fn ray_pass(t: &RayTable, v: usize, i: usize, ys: &[f32], s: &mut RowRays) {
    // SAFETY: AVX2 per the contract; the 8-ray blocks start at `k` with `k + 8
    // <= n_det`, so the per-ray loads, the `ys` loads and the scratch stores at
    // `PAD + k` stay inside their buffers.
    unsafe {
        let n_det = t.n_det;
        assert!(ys.len() >= n_det && s.j.len() >= n_det + 2 * PAD);
        assert!(s.c0.len() >= n_det + 2 * PAD && s.c1.len() >= n_det + 2 * PAD);
        let base = v * n_det;
        assert!(base + n_det <= t.x_top.len() && base + n_det <= t.row_hi.len());
        let ii = _mm256_set1_epi32(i as i32);
        let fi = _mm256_set1_ps(i as f32);
        let nop = _mm256_set1_epi32(NO_PIXEL);
        let zero = _mm256_setzero_ps();
        let map = &t.inv_map[v * t.nz + i];
        let (k_lo, k_hi) = (map.ray_lo as usize, map.ray_hi as usize);
        let has_slow = t.view_has_slow[v];
        let (jp, c0p, c1p) = (s.j.as_mut_ptr(), s.c0.as_mut_ptr(), s.c1.as_mut_ptr());
        let mut k = 0;
        while k + L <= n_det {
            let r = base + k;
            if k + L <= k_lo || k >= k_hi {
                // No ray of this block touches the row: mark it empty (the
                // scratch is reused across rows).
                dbt_isa::ymm::storeu_si256(jp.add(PAD + k) as *mut __m256i, nop);
                dbt_isa::ymm::storeu_ps(c0p.add(PAD + k), zero);
                dbt_isa::ymm::storeu_ps(c1p.add(PAD + k), zero);
                k += L;
                continue;
            }
            let (jf, w0, w1) = weights8(
                dbt_isa::ymm::loadu_ps(t.x_top.as_ptr().add(r)),
                dbt_isa::ymm::loadu_ps(t.sx.as_ptr().add(r)),
                dbt_isa::ymm::loadu_ps(t.len.as_ptr().add(r)),
                dbt_isa::ymm::loadu_ps(t.inv.as_ptr().add(r)),
                fi,
            );
            let y = dbt_isa::ymm::loadu_ps(ys.as_ptr().add(k));
            let (j, c0, c1) = (
                _mm256_cvttps_epi32(jf),
                _mm256_mul_ps(w0, y),
                _mm256_mul_ps(w1, y),
            );
            if !has_slow && k >= k_lo && k + L <= k_hi {
                // Every ray of the block is inside the row and fast.
                dbt_isa::ymm::storeu_si256(jp.add(PAD + k) as *mut __m256i, j);
                dbt_isa::ymm::storeu_ps(c0p.add(PAD + k), c0);
                dbt_isa::ymm::storeu_ps(c1p.add(PAD + k), c1);
            } else {
                // An edge block, or a view with slow rays (scattered by the
                // caller): row_lo <= i < row_hi and fast.
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
            }
            k += L;
        }
        for k in k..n_det {
            let r = base + k;
            if t.touches_row(r, i) && t.fast[r] {
                let (lo, _) = segment(t.x_top[r], t.sx[r], i);
                let (j, w0, w1) = fast_weights(lo, t.len[r], t.inv[r]);
                s.j[PAD + k] = j;
                s.c0[PAD + k] = w0 * ys[k];
                s.c1[PAD + k] = w1 * ys[k];
            } else {
                s.j[PAD + k] = NO_PIXEL;
                s.c0[PAD + k] = 0.0;
                s.c1[PAD + k] = 0.0;
            }
        }
    }
}

/// `InvMap::block` at blocks `0, 16, 32, ...` (8 blocks per vector, the same
/// IEEE operations, so the same values).
///
/// # Safety
/// AVX2; the scratch vectors' lengths are multiples of 16 (`RowRays::reset`
/// with `nb` a multiple of 16).
#[target_feature(enable = "avx2")]
unsafe fn block_values(map: &InvMap, s: &mut RowRays) {
    // SAFETY: AVX2 per the contract; `q` steps by 8 below the shortest
    // vector's length, a multiple of 16, so every store is inside.
    unsafe {
        let (rb, sb, r0, eb) = (&mut s.rb, &mut s.sb, &mut s.r0, &mut s.e);
        let e_off = _mm256_set1_epi32(PAD as i32 - map.off1);
        let lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        let (a, b) = (_mm256_set1_ps(map.a), _mm256_set1_ps(map.b));
        let (c, d, e) = (
            _mm256_set1_ps(map.c),
            _mm256_set1_ps(map.d),
            _mm256_set1_ps(map.e),
        );
        let one = _mm256_set1_ps(1.0);
        for q in (0..rb.len().min(sb.len()).min(r0.len()).min(eb.len())).step_by(L) {
            let blocks = _mm256_add_epi32(_mm256_set1_epi32(q as i32), lanes);
            let x = _mm256_cvtepi32_ps(_mm256_slli_epi32::<4>(blocks));
            let inv = _mm256_div_ps(one, _mm256_add_ps(_mm256_mul_ps(c, x), d));
            let val = _mm256_mul_ps(_mm256_add_ps(_mm256_mul_ps(a, x), b), inv);
            let slope = _mm256_mul_ps(_mm256_mul_ps(e, inv), inv);
            dbt_isa::ymm::storeu_ps(rb.as_mut_ptr().add(q), val);
            dbt_isa::ymm::storeu_ps(sb.as_mut_ptr().add(q), slope);
            let first = _mm256_cvttps_epi32(_mm256_floor_ps(val));
            dbt_isa::ymm::storeu_si256(r0.as_mut_ptr().add(q) as *mut __m256i, first);
            dbt_isa::ymm::storeu_si256(
                eb.as_mut_ptr().add(q) as *mut __m256i,
                _mm256_add_epi32(first, e_off),
            );
        }
    }
}

/// Pixel pass (see the module's documentation): the fit range's 16-pixel
/// blocks in halves of 8 with gathered candidates, other pixels with the
/// scalar two-sided candidates.
///
/// # Safety
/// AVX2; `s` was filled by `ray_pass` for this row; `row_out` is one image
/// row.
#[target_feature(enable = "avx2")]
unsafe fn pixel_pass(t: &RayTable, map: &InvMap, s: &mut RowRays, row_out: &mut [f32]) {
    // SAFETY: AVX2 per the contract; the gathers read the 32-entry window of
    // each block in the padded scratch (`InvMap::block_fits`: every lane's
    // candidates `idx .. idx + count1` lie in `0..32` of the window, and the
    // window inside the scratch), and the stores write the fit range's
    // 8-pixel halves of `row_out`, the row's last one masked to its end.
    unsafe {
        let (nx, n_det) = (t.nx, t.n_det);
        assert_eq!(row_out.len(), nx);
        let (fit_lo, fit_hi) = (map.fit_lo as usize, map.fit_hi as usize);
        if fit_lo < fit_hi {
            block_values(map, s);
        }
        let s = &*s;
        for j in 0..(fit_lo * 16).min(nx) {
            row_out[j] += pixel_scalar(map, s, n_det, j);
        }
        if fit_lo < fit_hi {
            assert!(fit_hi <= s.rb.len() && fit_hi <= s.e.len());
            let jb = fit_lo * 16;
            let carry = if jb == 0 {
                left_edge_c1(map, &s.j, &s.c1)
            } else {
                slot_c1_scalar(map, s, n_det, jb - 1)
            };
            // Lane 7 of `prev` is the second contributions of the pixel
            // before the current half.
            let mut prev = _mm256_set1_ps(carry);
            let (jp, c0p, c1p) = (s.j.as_ptr(), s.c0.as_ptr(), s.c1.as_ptr());
            let lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
            let rot = _mm256_setr_epi32(7, 0, 1, 2, 3, 4, 5, 6);
            // The lanes' pixel offsets in the 16-pixel block, per half.
            let lane_f = [
                _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0),
                _mm256_setr_ps(8.0, 9.0, 10.0, 11.0, 12.0, 13.0, 14.0, 15.0),
            ];
            let one = _mm256_set1_epi32(1);
            for b in fit_lo..fit_hi {
                // Checked at construction (`InvMap::block_fits`).
                let rb = _mm256_set1_ps(s.rb[b]);
                let sb = _mm256_set1_ps(s.sb[b]);
                let r0 = _mm256_set1_epi32(s.r0[b]);
                let e = s.e[b] as usize;
                for h in 0..2 {
                    let p0 = b * 16 + h * L;
                    if p0 >= nx {
                        break;
                    }
                    let rf = _mm256_cvttps_epi32(_mm256_floor_ps(_mm256_add_ps(
                        rb,
                        _mm256_mul_ps(lane_f[h], sb),
                    )));
                    let mut id = _mm256_sub_epi32(rf, r0);
                    let jv = _mm256_add_epi32(_mm256_set1_epi32(p0 as i32), lanes);
                    let (mut a0, mut a1) = (_mm256_setzero_ps(), _mm256_setzero_ps());
                    // The half's candidates, window positions `first ..=
                    // last + count1 - 1`: in two registers of 8 where they
                    // span at most 16 entries (the usual case; the lookup is
                    // then two permutes and a blend), else gathered.
                    let first = _mm256_cvtsi256_si32(id) as i64;
                    let last = _mm256_extract_epi32::<7>(id) as i64;
                    let lo = e as i64 + first;
                    let narrow = first >= 0
                        && last - first + map.count1 as i64 - 1 <= 15
                        && lo + 16 <= s.j.len().min(s.c0.len()).min(s.c1.len()) as i64;
                    if narrow {
                        let lo = lo as usize;
                        let (jl, jh) = (
                            dbt_isa::ymm::loadu_si256(jp.add(lo) as *const __m256i),
                            dbt_isa::ymm::loadu_si256(jp.add(lo + L) as *const __m256i),
                        );
                        let (c0l, c0h) = (
                            dbt_isa::ymm::loadu_ps(c0p.add(lo)),
                            dbt_isa::ymm::loadu_ps(c0p.add(lo + L)),
                        );
                        let (c1l, c1h) = (
                            dbt_isa::ymm::loadu_ps(c1p.add(lo)),
                            dbt_isa::ymm::loadu_ps(c1p.add(lo + L)),
                        );
                        let mut loc = _mm256_sub_epi32(id, _mm256_set1_epi32(first as i32));
                        let seven = _mm256_set1_epi32(7);
                        for _ in 0..map.count1 {
                            let hi = _mm256_cmpgt_epi32(loc, seven);
                            let hf = _mm256_castsi256_ps(hi);
                            let jr = _mm256_blendv_epi8(
                                _mm256_permutevar8x32_epi32(jl, loc),
                                _mm256_permutevar8x32_epi32(jh, loc),
                                hi,
                            );
                            let m = _mm256_castsi256_ps(_mm256_cmpeq_epi32(jr, jv));
                            let c0 = _mm256_blendv_ps(
                                _mm256_permutevar8x32_ps(c0l, loc),
                                _mm256_permutevar8x32_ps(c0h, loc),
                                hf,
                            );
                            let c1 = _mm256_blendv_ps(
                                _mm256_permutevar8x32_ps(c1l, loc),
                                _mm256_permutevar8x32_ps(c1h, loc),
                                hf,
                            );
                            a0 = _mm256_add_ps(a0, _mm256_and_ps(c0, m));
                            a1 = _mm256_add_ps(a1, _mm256_and_ps(c1, m));
                            loc = _mm256_add_epi32(loc, one);
                        }
                    } else {
                        for _ in 0..map.count1 {
                            let jr = _mm256_i32gather_epi32::<4>(jp.add(e), id);
                            let m = _mm256_castsi256_ps(_mm256_cmpeq_epi32(jr, jv));
                            let c0 = _mm256_i32gather_ps::<4>(c0p.add(e), id);
                            let c1 = _mm256_i32gather_ps::<4>(c1p.add(e), id);
                            a0 = _mm256_add_ps(a0, _mm256_and_ps(c0, m));
                            a1 = _mm256_add_ps(a1, _mm256_and_ps(c1, m));
                            id = _mm256_add_epi32(id, one);
                        }
                    }
                    // Lane l gets a1 of pixel p0 + l - 1 (lane 7 of `prev`).
                    let carried = _mm256_blend_ps::<1>(
                        _mm256_permutevar8x32_ps(a1, rot),
                        _mm256_permutevar8x32_ps(prev, rot),
                    );
                    prev = a1;
                    let o = row_out.as_mut_ptr().add(p0);
                    let sum = _mm256_add_ps(a0, carried);
                    if p0 + L <= nx {
                        dbt_isa::ymm::storeu_ps(o, _mm256_add_ps(dbt_isa::ymm::loadu_ps(o), sum));
                    } else {
                        // The row's last, partial half: lanes past the row
                        // are neither read nor written.
                        let m = _mm256_cmpgt_epi32(_mm256_set1_epi32((nx - p0) as i32), lanes);
                        _mm256_maskstore_ps(o, m, _mm256_add_ps(_mm256_maskload_ps(o, m), sum));
                    }
                }
            }
        }
        for (j, o) in row_out.iter_mut().enumerate().skip(fit_hi.max(fit_lo) * 16) {
            // Past the fit range (empty when the range reaches the row's end).
            *o += pixel_scalar(map, s, n_det, j);
        }
    }
}

#[cfg(test)]
mod tests {
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
}
