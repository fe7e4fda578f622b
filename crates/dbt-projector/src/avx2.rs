//! AVX2 forward kernel (issue #30): 8 neighbouring rays of one view per
//! vector, walking down the rows, the two pixels of each ray fetched with
//! masked gathers. The weights come from exactly the scalar reference's
//! operations (`table::segment`, `table::fast_weights`: multiply then add,
//! no fused multiply-add), so it applies the same matrix; only the order of
//! the sums over rays differs from nothing (each lane is one ray, summed
//! row by row as the scalar code does). Blocks with a slow ray, and the
//! tail of a view, go through the scalar code. The adjoint stays scalar on
//! AVX2-only CPUs.

use crate::table::RayTable;
use std::arch::x86_64::*;

const L: usize = 8;

/// # Safety
/// Requires AVX2. `r0 .. r0 + out.len()` must be rays of one view.
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn forward_rays(t: &RayTable, img: &[f32], r0: usize, out: &mut [f32]) {
    let n = out.len();
    let mut done = 0;
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

/// # Safety
/// AVX2; rays `rb .. rb + 8` exist in the table and are fast rays. Every
/// gathered index is masked to `0 <= j < nx` in a row `i < nz` of the image.
#[target_feature(enable = "avx2")]
unsafe fn forward_block(t: &RayTable, img: &[f32], rb: usize) -> [f32; L] {
    // SAFETY: AVX2 per the contract; the loads read rays rb .. rb + 8 of the
    // table's arrays; the gathers read only lanes whose pixel is inside row
    // `i` of the image (`i < row_hi <= nz`, `0 <= j < nx`), as asserted.
    unsafe {
        let nx = t.nx;
        assert!(img.len() >= t.nz * nx && t.nz * nx <= i32::MAX as usize);
        assert!(rb + L <= t.x_top.len() && rb + L <= t.row_hi.len());
        let x_top = _mm256_loadu_ps(t.x_top.as_ptr().add(rb));
        let sx = _mm256_loadu_ps(t.sx.as_ptr().add(rb));
        let len = _mm256_loadu_ps(t.len.as_ptr().add(rb));
        let inv = _mm256_loadu_ps(t.inv.as_ptr().add(rb));
        let row_lo = _mm256_loadu_si256(t.row_lo.as_ptr().add(rb) as *const __m256i);
        let row_hi = _mm256_loadu_si256(t.row_hi.as_ptr().add(rb) as *const __m256i);
        let i_start = t.row_lo[rb..rb + L].iter().copied().min().unwrap_or(0) as usize;
        let i_end = t.row_hi[rb..rb + L].iter().copied().max().unwrap_or(0) as usize;
        assert!(i_end <= t.nz);
        let one = _mm256_set1_ps(1.0);
        let zero = _mm256_setzero_ps();
        let nx_v = _mm256_set1_epi32(nx as i32);
        let minus1 = _mm256_set1_epi32(-1);
        let mut acc = _mm256_setzero_ps();
        for i in i_start..i_end {
            let fi = _mm256_set1_ps(i as f32);
            let iv = _mm256_set1_epi32(i as i32);
            // table::segment, table::fast_weights
            let xt = _mm256_add_ps(x_top, _mm256_mul_ps(fi, sx));
            let xb = _mm256_add_ps(xt, sx);
            let lo = _mm256_min_ps(xt, xb);
            let jf = _mm256_floor_ps(lo);
            let frac = _mm256_mul_ps(_mm256_sub_ps(_mm256_add_ps(jf, one), lo), inv);
            let w0 = _mm256_mul_ps(len, _mm256_min_ps(frac, one));
            let w1 = _mm256_sub_ps(len, w0);
            let j = _mm256_cvttps_epi32(jf);
            let j1 = _mm256_sub_epi32(j, minus1);
            // Lane is in its ray's rows: row_lo <= i < row_hi.
            let in_rows = _mm256_andnot_si256(
                _mm256_cmpgt_epi32(row_lo, iv),
                _mm256_cmpgt_epi32(row_hi, iv),
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
            // The scalar code adds w0 * x_j, then w1 * x_(j+1); masked
            // lanes add w * 0.
            let w0m = _mm256_and_ps(w0, _mm256_castsi256_ps(m0));
            let w1m = _mm256_and_ps(w1, _mm256_castsi256_ps(m1));
            acc = _mm256_add_ps(acc, _mm256_mul_ps(w0m, g0));
            acc = _mm256_add_ps(acc, _mm256_mul_ps(w1m, g1));
        }
        let mut a = [0.0f32; L];
        _mm256_storeu_ps(a.as_mut_ptr(), acc);
        a
    }
}
