//! AVX-512F kernels. They compute the weights with exactly the operations of the
//! scalar reference (`table::segment`, `table::fast_weights`: multiply then add,
//! no fused multiply-add), so they apply the same matrix; only the order of
//! summation differs.
//!
//! * Forward: 16 neighbouring rays of one view per vector, walking down the
//!   rows. In a row the 16 rays touch a run of at most ~20 neighbouring pixels,
//!   so the two pixels each ray needs are fetched with two in-register permutes
//!   from a 32-pixel window of the row (no gathers).
//! * Adjoint: pixel-driven, so that every output pixel is written once. For each
//!   (view, row) a ray pass computes every ray's pixel index and its two
//!   weighted contributions; a pixel pass then collects, for 16 pixels at a time,
//!   the contributions of the few candidate rays given by the row's inverse map
//!   (verified at construction to cover every contributing ray).

use crate::table::{fast_weights, segment, InvMap, RayTable, NO_PIXEL, PAD};
use std::arch::x86_64::*;

const L: usize = 16;

#[inline(always)]
unsafe fn lane(v: __m512i, k: i32) -> i32 {
    let mut a = [0i32; L];
    _mm512_storeu_si512(a.as_mut_ptr() as *mut __m512i, v);
    a[k as usize]
}

#[inline(always)]
unsafe fn floor_ps(x: __m512) -> __m512 {
    _mm512_roundscale_ps::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(x)
}

/// `table::segment` and `table::fast_weights` for 16 rays at row `fi`, with the
/// same operations: `(lo, floor(lo), w0, w1)`.
#[inline(always)]
unsafe fn weights16(
    x_top: __m512,
    sx: __m512,
    len: __m512,
    inv: __m512,
    fi: __m512,
) -> (__m512, __m512, __m512, __m512) {
    let one = _mm512_set1_ps(1.0);
    let xt = _mm512_add_ps(x_top, _mm512_mul_ps(fi, sx));
    let xb = _mm512_add_ps(xt, sx);
    let lo = _mm512_min_ps(xt, xb);
    let jf = floor_ps(lo);
    let frac = _mm512_mul_ps(_mm512_sub_ps(_mm512_add_ps(jf, one), lo), inv);
    let w0 = _mm512_mul_ps(len, _mm512_min_ps(frac, one));
    (lo, jf, w0, _mm512_sub_ps(len, w0))
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

#[target_feature(enable = "avx512f")]
unsafe fn forward_block(t: &RayTable, img: &[f32], rb: usize) -> [f32; L] {
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

/// One row of a forward block where some rays may be outside the image or the
/// pixels may not fit one in-bounds window: masked loads and validity masks.
#[inline(always)]
unsafe fn forward_row_general(
    t: &RayTable,
    img: &[f32],
    rb: usize,
    (x_top, sx, len, inv): (__m512, __m512, __m512, __m512),
    i: usize,
    acc: __m512,
) -> __m512 {
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

/// Per-task scratch of the pixel-driven adjoint: each ray's pixel index and its
/// two weighted contributions for the current (view, row), padded with
/// non-contributing entries on both sides.
struct RowRays {
    j: Vec<i32>,
    c0: Vec<f32>,
    c1: Vec<f32>,
}

/// # Safety
/// Requires AVX-512F. `out` holds whole rows starting at row `i0`.
#[target_feature(enable = "avx512f")]
pub(crate) unsafe fn adjoint_rows(t: &RayTable, sino: &[f32], i0: usize, out: &mut [f32]) {
    let n_det = t.n_det;
    let n = n_det + 2 * PAD;
    // Per-thread scratch, reset (not reallocated) on every call: after the
    // first call on a thread the adjoint allocates nothing (the DBToR slice
    // loop's no-allocation rule).
    thread_local! {
        static SCRATCH: std::cell::RefCell<RowRays> = const {
            std::cell::RefCell::new(RowRays { j: Vec::new(), c0: Vec::new(), c1: Vec::new() })
        };
    }
    SCRATCH.with(|cell| {
        let mut s = cell.borrow_mut();
        s.j.clear();
        s.j.resize(n, NO_PIXEL);
        s.c0.clear();
        s.c0.resize(n, 0.0);
        s.c1.clear();
        s.c1.resize(n, 0.0);
        adjoint_rows_with(t, sino, i0, out, &mut s);
    });
}

#[target_feature(enable = "avx512f")]
unsafe fn adjoint_rows_with(
    t: &RayTable,
    sino: &[f32],
    i0: usize,
    out: &mut [f32],
    s: &mut RowRays,
) {
    let (nx, n_det) = (t.nx, t.n_det);
    out.fill(0.0);
    for (di, row_out) in out.chunks_exact_mut(nx).enumerate() {
        let i = i0 + di;
        for v in 0..t.n_views {
            let map = t.inv_map[v * t.nz + i];
            let ys = &sino[v * n_det..(v + 1) * n_det];
            if map.count > 0 {
                ray_pass(t, v, i, ys, s);
                pixel_pass(t, &map, s, row_out);
            }
            if t.view_has_slow[v] {
                for k in 0..n_det {
                    let r = v * n_det + k;
                    let inside = t.touches_row(r, i);
                    if !t.fast[r] && inside {
                        t.scatter_ray_row(r, i, ys[k], row_out);
                    }
                }
            }
        }
    }
}

#[target_feature(enable = "avx512f")]
unsafe fn ray_pass(t: &RayTable, v: usize, i: usize, ys: &[f32], s: &mut RowRays) {
    let n_det = t.n_det;
    let base = v * n_det;
    let ii = _mm512_set1_epi32(i as i32);
    let fi = _mm512_set1_ps(i as f32);
    let nop = _mm512_set1_epi32(NO_PIXEL);
    let map = &t.inv_map[v * t.nz + i];
    let (k_lo, k_hi) = (map.ray_lo as usize, map.ray_hi as usize);
    let zero = _mm512_setzero_ps();
    let mut k = 0;
    while k + L <= n_det {
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
        let row_lo = _mm512_loadu_si512(t.row_lo.as_ptr().add(r) as *const __m512i);
        let row_hi = _mm512_loadu_si512(t.row_hi.as_ptr().add(r) as *const __m512i);
        let interior = k >= k_lo && k + L <= k_hi && !t.view_has_slow[v];
        let mut valid = if interior {
            0xffff
        } else {
            _mm512_cmpge_epi32_mask(ii, row_lo) & _mm512_cmplt_epi32_mask(ii, row_hi)
        };
        if t.view_has_slow[v] {
            for l in 0..L {
                if !t.fast[r + l] {
                    valid &= !(1 << l);
                }
            }
        }
        let (_, jf, w0, w1) = weights16(x_top, sx, len, inv, fi);
        if interior {
            _mm512_storeu_si512(
                s.j.as_mut_ptr().add(PAD + k) as *mut __m512i,
                _mm512_cvttps_epi32(jf),
            );
            _mm512_storeu_ps(s.c0.as_mut_ptr().add(PAD + k), _mm512_mul_ps(w0, y));
            _mm512_storeu_ps(s.c1.as_mut_ptr().add(PAD + k), _mm512_mul_ps(w1, y));
        } else {
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
        }
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

#[inline(always)]
fn pixel_scalar(map: &InvMap, s: &RowRays, n_det: usize, j: usize) -> f32 {
    let start = map.start(j) as i64;
    let mut acc = 0.0f32;
    for k in 0..map.count as i64 {
        let r = start + k;
        if r < 0 || r >= n_det as i64 {
            continue;
        }
        let e = PAD + r as usize;
        if s.j[e] == j as i32 {
            acc += s.c0[e];
        }
        if s.j[e].wrapping_add(1) == j as i32 {
            acc += s.c1[e];
        }
    }
    acc
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

/// Add, for 16 pixels `jv`, the contributions of the candidate rays at window
/// positions `idx` to two independent accumulators (first and second pixel of
/// each ray), keeping the dependency chains short.
#[inline(always)]
unsafe fn collect_step(
    w: &Window,
    idx: __m512i,
    jv: __m512i,
    acc: (__m512, __m512),
) -> (__m512, __m512) {
    let jr = _mm512_permutex2var_epi32(w.jl, idx, w.jh);
    let c0 = _mm512_permutex2var_ps(w.c0l, idx, w.c0h);
    let c1 = _mm512_permutex2var_ps(w.c1l, idx, w.c1h);
    let m0 = _mm512_cmpeq_epi32_mask(jr, jv);
    let m1 = _mm512_cmpeq_epi32_mask(_mm512_add_epi32(jr, _mm512_set1_epi32(1)), jv);
    (
        _mm512_mask_add_ps(acc.0, m0, acc.0, c0),
        _mm512_mask_add_ps(acc.1, m1, acc.1, c1),
    )
}

/// Contributions of candidates `idx + k`, `k < n`, to 16 pixels.
#[inline(always)]
unsafe fn collect_n(w: &Window, idx: __m512i, jv: __m512i, n: i32) -> __m512 {
    let mut acc = (_mm512_setzero_ps(), _mm512_setzero_ps());
    for k in 0..n {
        acc = collect_step(w, _mm512_add_epi32(idx, _mm512_set1_epi32(k)), jv, acc);
    }
    _mm512_add_ps(acc.0, acc.1)
}

#[target_feature(enable = "avx512f")]
unsafe fn pixel_pass(t: &RayTable, map: &InvMap, s: &RowRays, row_out: &mut [f32]) {
    let (nx, n_det) = (t.nx, t.n_det);
    let count = map.count as i32;
    let lanes = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    let lanes_f = _mm512_cvtepi32_ps(lanes);
    let off = _mm512_set1_epi32(map.off);
    let lim = _mm512_set1_ps(1.0e9);
    let mut jb = 0;
    while jb + L <= nx {
        let jv = _mm512_add_epi32(_mm512_set1_epi32(jb as i32), lanes);
        // Same operations as InvMap::start.
        let (rb, sb) = map.block(jb);
        let r = _mm512_add_ps(
            _mm512_set1_ps(rb),
            _mm512_mul_ps(lanes_f, _mm512_set1_ps(sb)),
        );
        let r = floor_ps(r);
        let r = _mm512_max_ps(
            _mm512_min_ps(r, lim),
            _mm512_sub_ps(_mm512_setzero_ps(), lim),
        );
        let start = _mm512_sub_epi32(_mm512_cvttps_epi32(r), off);
        let first = _mm512_cvtsi512_si32(start);
        let last = lane(start, 15);
        let fits = map.monotone
            && first >= -(PAD as i32)
            && first + 32 <= (n_det + PAD) as i32
            && last + count - 1 - first <= 31;
        if fits {
            let e = (PAD as i32 + first) as usize;
            let jl = _mm512_loadu_si512(s.j.as_ptr().add(e) as *const __m512i);
            let jh = _mm512_loadu_si512(s.j.as_ptr().add(e + 16) as *const __m512i);
            let c0l = _mm512_loadu_ps(s.c0.as_ptr().add(e));
            let c0h = _mm512_loadu_ps(s.c0.as_ptr().add(e + 16));
            let c1l = _mm512_loadu_ps(s.c1.as_ptr().add(e));
            let c1h = _mm512_loadu_ps(s.c1.as_ptr().add(e + 16));
            let idx = _mm512_sub_epi32(start, _mm512_set1_epi32(first));
            let w = Window {
                jl,
                jh,
                c0l,
                c0h,
                c1l,
                c1h,
            };
            let acc = collect_n(&w, idx, jv, count);
            let o = row_out.as_mut_ptr().add(jb);
            _mm512_storeu_ps(o, _mm512_add_ps(_mm512_loadu_ps(o), acc));
        } else {
            for j in jb..jb + L {
                row_out[j] += pixel_scalar(map, s, n_det, j);
            }
        }
        jb += L;
    }
    for (j, o) in row_out.iter_mut().enumerate().skip(jb) {
        *o += pixel_scalar(map, s, n_det, j);
    }
}
