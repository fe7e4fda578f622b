//! AVX-512F kernels. They compute the weights with exactly the operations of the
//! scalar reference (`table::segment`, `table::fast_weights`: multiply then add,
//! no fused multiply-add), so they apply the same matrix; only the order of
//! summation differs.
//!
//! * Forward: 16 neighbouring rays of one view per vector, walking down the
//!   rows. In a row the 16 rays touch a run of at most ~20 neighbouring pixels,
//!   so the two pixels each ray needs are fetched with two in-register permutes
//!   from a 32-pixel window of the row (no gathers). In the block's fast rows
//!   (all rays inside, window in bounds; found at construction) the loads are
//!   unmasked and there are no per-row checks.
//! * Adjoint: pixel-driven, so that every output pixel is written once. Per
//!   task (a band of rows), view by view and row by row: a ray pass computes
//!   every ray's first pixel `j` and its two weighted contributions (to `j` and
//!   `j + 1`); a pixel pass then collects, for 16 pixels at a time, the few
//!   candidate rays whose first pixel each is (given by the row's inverse map,
//!   verified at construction to cover them), adds their first contributions
//!   and carries their second ones one pixel right with a lane shift.

use crate::table::{
    fast_weights, left_edge_c1, pixel_scalar, segment, slot_c1_scalar, InvMap, RayTable, RowRays,
    NO_PIXEL, PAD,
};
use std::arch::x86_64::*;

const L: usize = 16;

/// # Safety
/// The caller runs with AVX-512F enabled (an `avx512f` target-feature
/// function). `k` is in `0..16`.
#[inline(always)]
unsafe fn lane(v: __m512i, k: i32) -> i32 {
    // SAFETY: AVX-512F per the contract; the store writes 64 bytes into `a`, 16
    // i32.
    unsafe {
        let mut a = [0i32; L];
        _mm512_storeu_si512(a.as_mut_ptr() as *mut __m512i, v);
        a[k as usize]
    }
}

/// # Safety
/// The caller runs with AVX-512F enabled.
#[inline(always)]
unsafe fn floor_ps(x: __m512) -> __m512 {
    // SAFETY: AVX-512F per the contract; registers only.
    unsafe { _mm512_roundscale_ps::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(x) }
}

/// `table::segment` and `table::fast_weights` for 16 rays at row `fi`, with the
/// same operations: `(lo, floor(lo), w0, w1)`.
///
/// # Safety
/// The caller runs with AVX-512F enabled.
#[inline(always)]
unsafe fn weights16(
    x_top: __m512,
    sx: __m512,
    len: __m512,
    inv: __m512,
    fi: __m512,
) -> (__m512, __m512, __m512, __m512) {
    // SAFETY: AVX-512F per the contract; registers only.
    unsafe {
        let one = _mm512_set1_ps(1.0);
        let xt = _mm512_add_ps(x_top, _mm512_mul_ps(fi, sx));
        let xb = _mm512_add_ps(xt, sx);
        let lo = _mm512_min_ps(xt, xb);
        let jf = floor_ps(lo);
        let frac = _mm512_mul_ps(_mm512_sub_ps(_mm512_add_ps(jf, one), lo), inv);
        let w0 = _mm512_mul_ps(len, _mm512_min_ps(frac, one));
        (lo, jf, w0, _mm512_sub_ps(len, w0))
    }
}

/// Mask of the window elements `e in 0..16` with `0 <= start + e < n`.
#[inline(always)]
fn window_mask(start: i64, n: i64) -> u16 {
    let lo = (-start).clamp(0, 16);
    let hi = (n - start).clamp(0, 16);
    if hi <= lo {
        return 0;
    }
    let full: u32 = (1u32 << hi) - 1;
    let low: u32 = (1u32 << lo) - 1;
    (full & !low) as u16
}

/// # Safety
/// Requires AVX-512F. `r0 .. r0 + out.len()` must be rays of one view.
#[target_feature(enable = "avx512f")]
pub(crate) unsafe fn forward_rays(t: &RayTable, img: &[f32], r0: usize, out: &mut [f32]) {
    // SAFETY: AVX-512F per the contract; whole blocks only (`done + 16 <=
    // out.len()`), so `forward_block` reads rays `rb .. rb + 16` of this view,
    // inside the table.
    unsafe {
        let v = r0 / t.n_det;
        let n = out.len();
        let mut done = 0;
        if t.view_simd[v] {
            while done + L <= n {
                let rb = r0 + done;
                out[done..done + L].copy_from_slice(&forward_block(t, img, rb));
                done += L;
            }
        }
        for (o, r) in out[done..].iter_mut().zip(r0 + done..) {
            *o = t.forward_ray_scalar(r, img);
        }
    }
}

/// # Safety
/// AVX-512F; rays `rb .. rb + 16` exist in the table (one view's). The fast
/// rows' 32-pixel windows were verified in bounds when the table was built
/// (`RayTable::forward_fast_rows`).
#[target_feature(enable = "avx512f")]
unsafe fn forward_block(t: &RayTable, img: &[f32], rb: usize) -> [f32; L] {
    // SAFETY: AVX-512F per the contract; the per-ray loads read rays `rb .. rb +
    // 16`, inside the table; the fast rows' image windows lie in the image
    // (verified at construction); the general rows go through
    // `forward_row_general`'s masked loads.
    unsafe {
        let nx = t.nx;
        let x_top = _mm512_loadu_ps(t.x_top.as_ptr().add(rb));
        let sx = _mm512_loadu_ps(t.sx.as_ptr().add(rb));
        let len = _mm512_loadu_ps(t.len.as_ptr().add(rb));
        let inv = _mm512_loadu_ps(t.inv.as_ptr().add(rb));
        let i_start = t.row_lo[rb..rb + L].iter().copied().min().unwrap_or(0) as usize;
        let i_end = (t.row_hi[rb..rb + L].iter().copied().max().unwrap_or(0) as usize).max(i_start);
        let v = rb / t.n_det;
        let (fa, fb) = t.fwd_rows[v * t.blocks_per_view() + (rb - v * t.n_det) / L];
        let (fa, fb) = if fa < fb {
            (fa as usize, fb as usize)
        } else {
            (i_end, i_end)
        };
        let mut acc = _mm512_setzero_ps();
        for i in (i_start..fa.min(i_end)).chain(fb.max(i_start)..i_end) {
            acc = forward_row_general(t, img, rb, (x_top, sx, len, inv), i, acc);
        }
        // Fast rows: every ray inside, pixels in one in-bounds 32-pixel window
        // (verified at construction, `RayTable::forward_fast_rows`). Two
        // accumulators keep the dependency chain at one FMA per row.
        let ione = _mm512_set1_epi32(1);
        let (mut acc0, mut acc1) = (_mm512_setzero_ps(), _mm512_setzero_ps());
        let mut fi = _mm512_set1_ps(fa as f32);
        let one = _mm512_set1_ps(1.0);
        for i in fa..fb {
            let (_, jf, w0, w1) = weights16(x_top, sx, len, inv, fi);
            let jc = _mm512_cvttps_epi32(jf);
            let base = _mm512_cvtsi512_si32(jc);
            let p = img.as_ptr().add(i * nx + base as usize);
            let win_lo = _mm512_loadu_ps(p);
            let win_hi = _mm512_loadu_ps(p.add(16));
            let idx0 = _mm512_sub_epi32(jc, _mm512_set1_epi32(base));
            let v0 = _mm512_permutex2var_ps(win_lo, idx0, win_hi);
            let v1 = _mm512_permutex2var_ps(win_lo, _mm512_add_epi32(idx0, ione), win_hi);
            acc0 = _mm512_fmadd_ps(w0, v0, acc0);
            acc1 = _mm512_fmadd_ps(w1, v1, acc1);
            fi = _mm512_add_ps(fi, one);
        }
        acc = _mm512_add_ps(acc, _mm512_add_ps(acc0, acc1));
        let mut res = [0f32; L];
        _mm512_storeu_ps(res.as_mut_ptr(), acc);
        res
    }
}

/// One row of a forward block where some rays may be outside the image or the
/// pixels may not fit one in-bounds window: masked loads and validity masks.
///
/// # Safety
/// The caller runs with AVX-512F enabled; rays `rb .. rb + 16` exist in the
/// table; `i` is a row of the image.
#[inline(always)]
unsafe fn forward_row_general(
    t: &RayTable,
    img: &[f32],
    rb: usize,
    (x_top, sx, len, inv): (__m512, __m512, __m512, __m512),
    i: usize,
    acc: __m512,
) -> __m512 {
    // SAFETY: AVX-512F per the contract; per-ray loads of rays `rb .. rb + 16`;
    // the image window's lanes outside the row are masked off (`window_mask`), and
    // masked-off lanes are not accessed.
    unsafe {
        let nx = t.nx;
        let row_lo = _mm512_loadu_si512(t.row_lo.as_ptr().add(rb) as *const __m512i);
        let row_hi = _mm512_loadu_si512(t.row_hi.as_ptr().add(rb) as *const __m512i);
        let jmin = _mm512_set1_ps(-1.0);
        let jmax = _mm512_set1_ps(nx as f32 - 1.0);
        let ione = _mm512_set1_epi32(1);
        let fi = _mm512_set1_ps(i as f32);
        let (lo, jf, w0, w1) = weights16(x_top, sx, len, inv, fi);
        let ii = _mm512_set1_epi32(i as i32);
        let valid = _mm512_cmpge_epi32_mask(ii, row_lo) & _mm512_cmplt_epi32_mask(ii, row_hi);
        let jc = _mm512_cvttps_epi32(_mm512_min_ps(_mm512_max_ps(jf, jmin), jmax));
        let j_first = _mm512_cvtsi512_si32(jc);
        let j_last = lane(jc, 15);
        let row = img.as_ptr().add(i * nx);
        if j_last + 1 - j_first <= 31 {
            let base = j_first as i64;
            let m_lo = window_mask(base, nx as i64);
            let m_hi = window_mask(base + 16, nx as i64);
            // Masked-off elements are not accessed (AVX-512 fault suppression),
            // so the window may start one pixel left of the row.
            let p = row.wrapping_offset(base as isize);
            let win_lo = _mm512_maskz_loadu_ps(m_lo, p);
            let win_hi = _mm512_maskz_loadu_ps(m_hi, p.wrapping_add(16));
            let idx0 = _mm512_sub_epi32(jc, _mm512_set1_epi32(j_first));
            let idx1 = _mm512_add_epi32(idx0, ione);
            let v0 = _mm512_permutex2var_ps(win_lo, idx0, win_hi);
            let v1 = _mm512_permutex2var_ps(win_lo, idx1, win_hi);
            let acc = _mm512_fmadd_ps(_mm512_maskz_mov_ps(valid, w0), v0, acc);
            _mm512_fmadd_ps(_mm512_maskz_mov_ps(valid, w1), v1, acc)
        } else {
            // Rays too far apart for one window (not met at DBT geometries).
            let mut lo_a = [0f32; L];
            _mm512_storeu_ps(lo_a.as_mut_ptr(), lo);
            let mut add = [0f32; L];
            for (k, a) in add.iter_mut().enumerate() {
                if valid & (1 << k) != 0 {
                    let (j, w0, w1) = fast_weights(lo_a[k], t.len[rb + k], t.inv[rb + k]);
                    if j >= 0 {
                        *a += w0 * img[i * nx + j as usize];
                    }
                    if j + 1 < nx as i32 {
                        *a += w1 * img[i * nx + (j + 1) as usize];
                    }
                }
            }
            _mm512_add_ps(acc, _mm512_loadu_ps(add.as_ptr()))
        }
    }
}

/// # Safety
/// Requires AVX-512F. `out` holds whole rows starting at row `i0`.
#[target_feature(enable = "avx512f")]
pub(crate) unsafe fn adjoint_rows(t: &RayTable, sino: &[f32], i0: usize, out: &mut [f32]) {
    crate::table::adjoint_band(t, sino, i0, out, |v, i, ys, map, s, row_out| {
        // SAFETY: AVX-512F per this function's contract; `adjoint_band` passes
        // a view and row of the table, the view's values, scratch sized for
        // the table and one image row.
        unsafe {
            ray_pass(t, v, i, ys, s);
            pixel_pass(t, map, s, row_out);
        }
    });
}

/// # Safety
/// AVX-512F; `v` is a view and `i` a row of the table; `ys` holds the view's
/// `n_det` values; `s` is sized for the table (`PAD` entries on both sides of
/// `n_det`).
#[target_feature(enable = "avx512f")]
unsafe fn ray_pass(t: &RayTable, v: usize, i: usize, ys: &[f32], s: &mut RowRays) {
    // SAFETY: AVX-512F per the contract; the 16-ray blocks start at `k` with `k +
    // 16 <= n_det`, so the per-ray loads, the `ys` loads and the scratch stores at
    // `PAD + k` stay inside their buffers.
    unsafe {
        let n_det = t.n_det;
        let base = v * n_det;
        let ii = _mm512_set1_epi32(i as i32);
        let fi = _mm512_set1_ps(i as f32);
        let nop = _mm512_set1_epi32(NO_PIXEL);
        let map = &t.inv_map[v * t.nz + i];
        let (k_lo, k_hi) = (map.ray_lo as usize, map.ray_hi as usize);
        let zero = _mm512_setzero_ps();
        let has_slow = t.view_has_slow[v];
        // Whole blocks of rays that all touch the row (and are all fast).
        let (ia, ib) = if has_slow {
            (0, 0)
        } else {
            (k_lo.next_multiple_of(L), k_hi / L * L)
        };
        let mut k = 0;
        while k + L <= n_det {
            // The whole interior blocks, unmasked (every other block below).
            if k == ia && ia < ib {
                let (jp, c0p, c1p) = (s.j.as_mut_ptr(), s.c0.as_mut_ptr(), s.c1.as_mut_ptr());
                for k in (ia..ib).step_by(L) {
                    let r = base + k;
                    let (_, jf, w0, w1) = weights16(
                        _mm512_loadu_ps(t.x_top.as_ptr().add(r)),
                        _mm512_loadu_ps(t.sx.as_ptr().add(r)),
                        _mm512_loadu_ps(t.len.as_ptr().add(r)),
                        _mm512_loadu_ps(t.inv.as_ptr().add(r)),
                        fi,
                    );
                    let y = _mm512_loadu_ps(ys.as_ptr().add(k));
                    _mm512_storeu_si512(jp.add(PAD + k) as *mut __m512i, _mm512_cvttps_epi32(jf));
                    _mm512_storeu_ps(c0p.add(PAD + k), _mm512_mul_ps(w0, y));
                    _mm512_storeu_ps(c1p.add(PAD + k), _mm512_mul_ps(w1, y));
                }
                k = ib;
                continue;
            }
            if k + L <= k_lo || k >= k_hi {
                // No ray of this block touches the row: mark it empty (the scratch
                // is reused across rows and must not keep stale entries).
                _mm512_storeu_si512(s.j.as_mut_ptr().add(PAD + k) as *mut __m512i, nop);
                _mm512_storeu_ps(s.c0.as_mut_ptr().add(PAD + k), zero);
                _mm512_storeu_ps(s.c1.as_mut_ptr().add(PAD + k), zero);
                k += L;
                continue;
            }
            let r = base + k;
            let x_top = _mm512_loadu_ps(t.x_top.as_ptr().add(r));
            let sx = _mm512_loadu_ps(t.sx.as_ptr().add(r));
            let len = _mm512_loadu_ps(t.len.as_ptr().add(r));
            let inv = _mm512_loadu_ps(t.inv.as_ptr().add(r));
            let y = _mm512_loadu_ps(ys.as_ptr().add(k));
            // An edge block (some rays outside the row) or a block of a view with
            // slow rays (scattered separately): mask both out.
            let row_lo = _mm512_loadu_si512(t.row_lo.as_ptr().add(r) as *const __m512i);
            let row_hi = _mm512_loadu_si512(t.row_hi.as_ptr().add(r) as *const __m512i);
            let mut valid =
                _mm512_cmpge_epi32_mask(ii, row_lo) & _mm512_cmplt_epi32_mask(ii, row_hi);
            if has_slow {
                for l in 0..L {
                    if !t.fast[r + l] {
                        valid &= !(1 << l);
                    }
                }
            }
            let (_, jf, w0, w1) = weights16(x_top, sx, len, inv, fi);
            let j = _mm512_mask_blend_epi32(valid, nop, _mm512_cvttps_epi32(jf));
            _mm512_storeu_si512(s.j.as_mut_ptr().add(PAD + k) as *mut __m512i, j);
            _mm512_storeu_ps(
                s.c0.as_mut_ptr().add(PAD + k),
                _mm512_maskz_mul_ps(valid, w0, y),
            );
            _mm512_storeu_ps(
                s.c1.as_mut_ptr().add(PAD + k),
                _mm512_maskz_mul_ps(valid, w1, y),
            );
            k += L;
        }
        for k in k..n_det {
            let r = base + k;
            let inside = t.touches_row(r, i);
            if inside && t.fast[r] {
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

/// 32 consecutive entries of the row's ray scratch, in registers.
struct Window {
    jl: __m512i,
    jh: __m512i,
    c0l: __m512,
    c0h: __m512,
    c1l: __m512,
    c1h: __m512,
}

/// For 16 pixels `jv`, the sums over the rays whose first pixel it is (window
/// positions `idx .. idx + n`) of their first (`.0`) and second (`.1`)
/// contributions.
///
/// # Safety
/// The caller runs with AVX-512F enabled.
#[inline(always)]
unsafe fn collect_first(w: &Window, idx: __m512i, jv: __m512i, n: u32) -> (__m512, __m512) {
    // SAFETY: AVX-512F per the contract; registers only.
    unsafe {
        let one = _mm512_set1_epi32(1);
        let mut acc = (_mm512_setzero_ps(), _mm512_setzero_ps());
        let mut id = idx;
        for _ in 0..n {
            acc = collect_one(w, id, jv, acc);
            id = _mm512_add_epi32(id, one);
        }
        acc
    }
}

/// One candidate step of [`collect_first`]: window position `id`.
///
/// # Safety
/// The caller runs with AVX-512F enabled.
#[inline(always)]
unsafe fn collect_one(
    w: &Window,
    id: __m512i,
    jv: __m512i,
    (a0, a1): (__m512, __m512),
) -> (__m512, __m512) {
    // SAFETY: AVX-512F per the contract; registers only.
    unsafe {
        let jr = _mm512_permutex2var_epi32(w.jl, id, w.jh);
        let c0 = _mm512_permutex2var_ps(w.c0l, id, w.c0h);
        let c1 = _mm512_permutex2var_ps(w.c1l, id, w.c1h);
        let m = _mm512_cmpeq_epi32_mask(jr, jv);
        (
            _mm512_mask_add_ps(a0, m, a0, c0),
            _mm512_mask_add_ps(a1, m, a1, c1),
        )
    }
}

/// `InvMap::block` at blocks `0, 16, 32, ...` (16 blocks per vector, the same
/// IEEE operations, so the same values).
///
/// # Safety
/// AVX-512F; the scratch vectors' lengths are multiples of 16 (`RowRays::reset`
/// with `nb` a multiple of 16).
#[target_feature(enable = "avx512f")]
unsafe fn block_values(map: &InvMap, s: &mut RowRays) {
    // SAFETY: AVX-512F per the contract; `q` steps by 16 below the shortest
    // vector's length, a multiple of 16, so every store is inside.
    unsafe {
        let (rb, sb, r0, eb) = (&mut s.rb, &mut s.sb, &mut s.r0, &mut s.e);
        let e_off = _mm512_set1_epi32(PAD as i32 - map.off1);
        let lanes = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        let (a, b) = (_mm512_set1_ps(map.a), _mm512_set1_ps(map.b));
        let (c, d, e) = (
            _mm512_set1_ps(map.c),
            _mm512_set1_ps(map.d),
            _mm512_set1_ps(map.e),
        );
        let one = _mm512_set1_ps(1.0);
        for q in (0..rb.len().min(sb.len()).min(r0.len()).min(eb.len())).step_by(L) {
            let blocks = _mm512_add_epi32(_mm512_set1_epi32(q as i32), lanes);
            let x = _mm512_cvtepi32_ps(_mm512_slli_epi32::<4>(blocks));
            let inv = _mm512_div_ps(one, _mm512_add_ps(_mm512_mul_ps(c, x), d));
            let val = _mm512_mul_ps(_mm512_add_ps(_mm512_mul_ps(a, x), b), inv);
            let slope = _mm512_mul_ps(_mm512_mul_ps(e, inv), inv);
            _mm512_storeu_ps(rb.as_mut_ptr().add(q), val);
            _mm512_storeu_ps(sb.as_mut_ptr().add(q), slope);
            let first = _mm512_cvttps_epi32(floor_ps(val));
            _mm512_storeu_si512(r0.as_mut_ptr().add(q) as *mut __m512i, first);
            _mm512_storeu_si512(
                eb.as_mut_ptr().add(q) as *mut __m512i,
                _mm512_add_epi32(first, e_off),
            );
        }
    }
}

/// Pixel pass: blocks in the map's fit range collect, for each pixel, the
/// rays whose first pixel it is (first contributions to the pixel, second
/// ones carried to the next pixel); other pixels use the scalar two-sided
/// candidates.
///
/// # Safety
/// AVX-512F; `s` was filled by `ray_pass` and `block_values` for this row;
/// `row_out` is one image row.
#[target_feature(enable = "avx512f")]
unsafe fn pixel_pass(t: &RayTable, map: &InvMap, s: &mut RowRays, row_out: &mut [f32]) {
    // SAFETY: AVX-512F per the contract; the candidate windows read the padded
    // scratch (`PAD` non-contributing entries on both sides; the fit range is
    // the blocks whose windows stay inside it, checked when the table was
    // built), and the stores write the fit range's 16-pixel blocks of
    // `row_out`, the row's last one masked to the row's end.
    unsafe {
        let (nx, n_det) = (t.nx, t.n_det);
        let lanes = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        let lanes_f = _mm512_cvtepi32_ps(lanes);
        let (fit_lo, fit_hi) = (map.fit_lo as usize, map.fit_hi as usize);
        if fit_lo < fit_hi {
            block_values(map, s);
        }
        let s = &*s;
        for j in 0..(fit_lo * L).min(nx) {
            row_out[j] += pixel_scalar(map, s, n_det, j);
        }
        if fit_lo < fit_hi {
            // Second contributions into the first pixel of the range.
            let jb = fit_lo * L;
            let carry = if jb == 0 {
                left_edge_c1(map, &s.j, &s.c1)
            } else {
                slot_c1_scalar(map, s, n_det, jb - 1)
            };
            let mut prev = _mm512_set1_ps(carry);
            let (jp, c0p, c1p) = (s.j.as_ptr(), s.c0.as_ptr(), s.c1.as_ptr());
            let (rbp, sbp, r0p, ep) = (s.rb.as_ptr(), s.sb.as_ptr(), s.r0.as_ptr(), s.e.as_ptr());
            let mut jv = _mm512_add_epi32(_mm512_set1_epi32(jb as i32), lanes);
            let step = _mm512_set1_epi32(L as i32);
            for b in fit_lo..fit_hi {
                // Checked at construction (`InvMap::block_fits`): finite, in
                // range, non-decreasing, one window; lane 0 is floor(rb) exactly.
                let rb = _mm512_set1_ps(*rbp.add(b));
                let sb = _mm512_set1_ps(*sbp.add(b));
                let r0 = _mm512_set1_epi32(*r0p.add(b));
                let rf =
                    _mm512_cvttps_epi32(floor_ps(_mm512_add_ps(rb, _mm512_mul_ps(lanes_f, sb))));
                let e = *ep.add(b) as usize;
                let idx = _mm512_sub_epi32(rf, r0);
                let w = Window {
                    jl: _mm512_loadu_si512(jp.add(e) as *const __m512i),
                    jh: _mm512_loadu_si512(jp.add(e + 16) as *const __m512i),
                    c0l: _mm512_loadu_ps(c0p.add(e)),
                    c0h: _mm512_loadu_ps(c0p.add(e + 16)),
                    c1l: _mm512_loadu_ps(c1p.add(e)),
                    c1h: _mm512_loadu_ps(c1p.add(e + 16)),
                };
                let (a0, a1) = collect_first(&w, idx, jv, map.count1);
                // Lane l gets a1 of pixel jb + l - 1 (lane 15 of the previous block).
                let carried = _mm512_castsi512_ps(_mm512_alignr_epi32::<15>(
                    _mm512_castps_si512(a1),
                    _mm512_castps_si512(prev),
                ));
                prev = a1;
                let o = row_out.as_mut_ptr().add(b * L);
                let sum = _mm512_add_ps(a0, carried);
                if b * L + L <= nx {
                    _mm512_storeu_ps(o, _mm512_add_ps(_mm512_loadu_ps(o), sum));
                } else {
                    // The last, partial block: lanes past the row are neither read
                    // nor written (fault suppression).
                    let m = ((1u32 << (nx - b * L)) - 1) as u16;
                    _mm512_mask_storeu_ps(o, m, _mm512_add_ps(_mm512_maskz_loadu_ps(m, o), sum));
                }
                jv = _mm512_add_epi32(jv, step);
            }
        }
        for (j, o) in row_out.iter_mut().enumerate().skip(fit_hi.max(fit_lo) * L) {
            // Past the fit range (empty when the range reaches the row's end).
            *o += pixel_scalar(map, s, n_det, j);
        }
    }
}

#[cfg(test)]
mod tests {
    /// The geometries of the projector tests have every pixel block in the
    /// SIMD pass; cutting the fit ranges by hand exercises the scalar pixels
    /// before and after them and the carry into the first SIMD block from a
    /// scalar pixel (`slot_c1_scalar`). A sub-range of a verified range is
    /// itself valid.
    #[test]
    fn cut_fit_ranges_match_the_scalar_adjoint() {
        if !dbt_isa::kernel_test_runs("projector avx512 fit ranges", &["avx512f"]) {
            return;
        }
        // SAFETY: AVX-512F detected above.
        crate::table::check_cut_fit_ranges(|t, y, out| unsafe {
            super::adjoint_rows(t, y, 0, out)
        });
    }
}
