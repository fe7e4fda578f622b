//! The fp32 convolution by Winograd's F(3x3, 3x3), the int8 kernels'
//! transforms (`int8/winograd.rs`: Toom-Cook points 0, 1, -1, 2, infinity)
//! in floats: each 3 x 3 block of outputs from its 5 x 5 input patch with
//! 25 fused multiply-adds per input and output channel instead of 81.
//!
//! The weights are transformed once in f64 (`U = G g G^T`, `G = G' / 6`)
//! and rounded to f32; the input and output transforms (`B^T d B`,
//! `A^T M A`, integer coefficients up to 4) run in f32, factorised as in the
//! int8 code. Unlike the int8 one it does not give the direct kernel's bits:
//! the sums run in another order and through the transforms, which scale
//! the inputs' rounding by up to `6 x 6` on the way in; tested against the
//! f64 definition with a bound. **Opt-in** (`Fp32Block::with_winograd`,
//! `DBTOR_FP32_WINOGRAD=on`): the firmware's fp32 default keeps the direct
//! kernels until an accuracy run on the validation split says otherwise.
//! On the AVX-512 and AVX2 kernels; the portable one stays direct.

use super::{run_tile, Packed};
use crate::int8::winograd::{GP, M, N, POS};
use crate::{group_width, Kernel, GROUP, L, NP_NARROW};

/// Where [`row_triple`]'s rows go: `dst(a, x, np, sums)`.
pub(crate) type RowSums<'a> = dyn FnMut(usize, usize, usize, &[f32]) + 'a;

/// Tiles of 3 x 3 output pixels per chunk.
const WT: usize = 20;

/// Whether a convolution of `cin` input channels runs by Winograd (the input
/// transform's 8-channel steps).
pub(crate) fn eligible(cin: usize) -> bool {
    cin >= 8 && cin.is_multiple_of(8)
}

/// `U = G g G^T` from `w` (`[tap][cin][ocp]`) into `[pos][cin][ocp]`, in f64
/// and rounded once.
pub(crate) fn transform_weights(w: &[f32], cin: usize, ocp: usize) -> Vec<f32> {
    assert_eq!(w.len(), 9 * cin * ocp);
    let mut u = vec![0.0f32; POS * cin * ocp];
    for c in 0..cin {
        for o in 0..ocp {
            let g = |ky: usize, kx: usize| f64::from(w[((3 * ky + kx) * cin + c) * ocp + o]);
            for (i, gi) in GP.iter().enumerate() {
                for (j, gj) in GP.iter().enumerate() {
                    let mut v = 0.0f64;
                    for (ky, a) in gi.iter().enumerate() {
                        for (kx, b) in gj.iter().enumerate() {
                            v += f64::from(a * b) * g(ky, kx);
                        }
                    }
                    u[((N * i + j) * cin + c) * ocp + o] = (v / 36.0) as f32;
                }
            }
        }
    }
    u
}

/// Three output rows `r..r + 3` (input padded, row stride `rs`, pixel stride
/// `cs`; `w` pixels): triples of pixels by Winograd, the last `w % 3` by the
/// kernel's direct tile; `dst(a, x, np, tile)` receives row `r + a`'s
/// sums (no bias) of `np` pixels from `x`, all `ocp` channels per pixel.
///
/// Callers: the AVX-512 and AVX2 fp32 kernels (detected when the block was
/// made); `u` is `p.wino`.
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
pub(crate) fn row_triple(
    kernel: Kernel,
    p: &Packed,
    u: &[f32],
    inp: &[f32],
    r: usize,
    rs: usize,
    cs: usize,
    w: usize,
    dst: &mut RowSums<'_>,
) {
    let (cin, ocp) = (p.cin, p.ocp);
    assert!(matches!(kernel, Kernel::Avx2 | Kernel::Avx512));
    assert!(eligible(cin) && cin <= cs && ocp.is_multiple_of(L));
    assert!(u.len() == POS * cin * ocp && rs == (w + 2) * cs && inp.len() >= (r + N) * rs);
    thread_local! {
        static BUF: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
    }
    let (vn, mn, tn) = (POS * WT * cin, POS * WT * ocp, M * WT * ocp);
    crate::with_scratch(&BUF, vn + mn + M * tn, |b| {
        let (v, b) = b.split_at_mut(vn);
        let (m, t) = b.split_at_mut(mn);
        let (t0, t12) = t.split_at_mut(tn);
        let (t1, t2) = t12.split_at_mut(tn);
        triple_in(kernel, p, u, inp, r, rs, cs, w, dst, v, m, [t0, t1, t2]);
    });
}

/// [`row_triple`] with its scratch: `v` (`POS * WT * cin`), `m`
/// (`POS * WT * ocp`) and three tiles of `3 * WT * ocp` sums (the first
/// also the left-over columns' row).
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
fn triple_in(
    kernel: Kernel,
    p: &Packed,
    u: &[f32],
    inp: &[f32],
    r: usize,
    rs: usize,
    cs: usize,
    w: usize,
    dst: &mut RowSums<'_>,
    v: &mut [f32],
    m: &mut [f32],
    mut tiles: [&mut [f32]; M],
) {
    let (cin, ocp) = (p.cin, p.ocp);
    assert!(v.len() >= POS * WT * cin && m.len() >= POS * WT * ocp);
    assert!(tiles.iter().all(|t| t.len() >= M * WT * ocp));
    let mut x = 0;
    while x + M <= w {
        let nt = ((w - x) / M).min(WT);
        // SAFETY: AVX2 (both kernels' CPUs have it); the chunk's patches are
        // padded rows r..r + 5 and columns x..x + 3 nt + 2 <= w + 2 inside
        // `inp` (asserted), `cin <= cs` values each; `v` holds POS * WT * cin.
        unsafe {
            input(
                inp.as_ptr().add(r * rs + x * cs),
                rs,
                cs,
                cin,
                nt,
                v.as_mut_ptr(),
            )
        };
        // SAFETY: the kernel's instructions (detected); `v` as filled, `u`
        // the transformed weights, `m` POS * WT * ocp values.
        unsafe {
            if kernel == Kernel::Avx512 {
                gemm_avx512(nt, v.as_ptr(), cin, u.as_ptr(), ocp, m.as_mut_ptr());
            } else {
                gemm_avx2(nt, v.as_ptr(), cin, u.as_ptr(), ocp, m.as_mut_ptr());
            }
        }
        let t = tiles.each_mut().map(|t| t.as_mut_ptr());
        // SAFETY: AVX2; `m` filled for nt tiles, each tile buffer 3 WT x ocp.
        unsafe { output(m.as_ptr(), nt, ocp, t) };
        for (a, t) in tiles.iter().enumerate() {
            dst(a, x, M * nt, &t[..M * nt * ocp]);
        }
        x += M * nt;
    }
    if x < w {
        let np = w - x;
        let mut tile = [0.0f32; NP_NARROW * GROUP];
        // np <= 2 pixels: inside the first tile buffer
        let row = &mut *tiles[0];
        for a in 0..M {
            let mut g0 = 0;
            while g0 < ocp {
                let gw = group_width(ocp, g0);
                let base = (r + a) * rs + x * cs;
                run_tile(kernel, gw, np, inp, base, rs, cs, p, g0, &mut tile);
                for px in 0..np {
                    row[px * ocp + g0..px * ocp + g0 + gw]
                        .copy_from_slice(&tile[px * gw..(px + 1) * gw]);
                }
                g0 += gw;
            }
            dst(a, x, np, &row[..np * ocp]);
        }
    }
}

crate::int8::winograd::factorised_transforms!(
    bt5,
    at5,
    std::arch::x86_64::__m256,
    _mm256_add_ps,
    _mm256_sub_ps,
    _mm256_add_ps,
    _mm256_sub_ps
);

/// `V = B^T d B` of `nt` patches, 8 channels at a time, into
/// `v[(pos * WT + t) * cin + c]` (each column's `B^T` once per chunk).
///
/// # Safety
/// AVX2; `inp` valid for rows 0..5 (stride `rs`) of pixels 0..3 nt + 2
/// (stride `cs`), `cin` values each; `cin` a multiple of 8; `v` valid for
/// `POS * WT * cin`; `nt` in 1..=WT.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::needless_range_loop)] // row i of five columns
unsafe fn input(inp: *const f32, rs: usize, cs: usize, cin: usize, nt: usize, v: *mut f32) {
    // SAFETY: AVX2 and the ranges per the contract.
    unsafe {
        use dbt_isa::ymm::{loadu_ps, storeu_ps};
        use std::arch::x86_64::*;
        for c in (0..cin).step_by(8) {
            let src = inp.add(c);
            let mut cols = [[_mm256_setzero_ps(); N]; M * WT + 2];
            for (j, col) in cols.iter_mut().enumerate().take(M * nt + 2) {
                let at = src.add(j * cs);
                *col = bt5([
                    loadu_ps(at),
                    loadu_ps(at.add(rs)),
                    loadu_ps(at.add(2 * rs)),
                    loadu_ps(at.add(3 * rs)),
                    loadu_ps(at.add(4 * rs)),
                ]);
            }
            for t in 0..nt {
                let p = &cols[M * t..M * t + N];
                for i in 0..N {
                    let o = bt5([p[0][i], p[1][i], p[2][i], p[3][i], p[4][i]]);
                    for (j, oj) in o.into_iter().enumerate() {
                        storeu_ps(v.add(((N * i + j) * WT + t) * cin + c), oj);
                    }
                }
            }
        }
    }
}

/// The element-wise products summed over the input channels, per position,
/// 16 output channels x up to 5 tiles at a time (10 accumulators of 8
/// lanes), into `m[(pos * WT + t) * ocp + o]`.
///
/// # Safety
/// AVX2 and FMA; `v` filled for `nt` (1..=WT) tiles; `u` the transformed
/// weights (`POS * cin * ocp`); `m` valid for `POS * WT * ocp`; `ocp` a
/// multiple of 16.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn gemm_avx2(nt: usize, v: *const f32, cin: usize, u: *const f32, ocp: usize, m: *mut f32) {
    // SAFETY: AVX2, FMA and the ranges per the contract.
    unsafe {
        for pos in 0..POS {
            for q in (0..ocp).step_by(L) {
                let w = u.add(pos * cin * ocp + q);
                for t0 in (0..nt).step_by(5) {
                    let (vb, mb) = (
                        v.add((pos * WT + t0) * cin),
                        m.add((pos * WT + t0) * ocp + q),
                    );
                    match nt - t0 {
                        1 => block_avx2::<1>(vb, cin, w, ocp, mb),
                        2 => block_avx2::<2>(vb, cin, w, ocp, mb),
                        3 => block_avx2::<3>(vb, cin, w, ocp, mb),
                        4 => block_avx2::<4>(vb, cin, w, ocp, mb),
                        _ => block_avx2::<5>(vb, cin, w, ocp, mb),
                    }
                }
            }
        }
    }
}

/// `NT` tiles x 16 channels of [`gemm_avx2`] at one position.
///
/// # Safety
/// As [`gemm_avx2`], for those tiles and channels.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn block_avx2<const NT: usize>(
    v: *const f32,
    cin: usize,
    w: *const f32,
    ocp: usize,
    m: *mut f32,
) {
    // SAFETY: AVX2, FMA and the ranges per the contract.
    unsafe {
        use dbt_isa::ymm::{loadu_ps, storeu_ps};
        use std::arch::x86_64::*;
        let mut a0 = [_mm256_setzero_ps(); NT];
        let mut a1 = [_mm256_setzero_ps(); NT];
        for c in 0..cin {
            let wr = w.add(c * ocp);
            let (w0, w1) = (loadu_ps(wr), loadu_ps(wr.add(8)));
            for t in 0..NT {
                let b = _mm256_broadcast_ss(&*v.add(t * cin + c));
                a0[t] = _mm256_fmadd_ps(b, w0, a0[t]);
                a1[t] = _mm256_fmadd_ps(b, w1, a1[t]);
            }
        }
        for t in 0..NT {
            storeu_ps(m.add(t * ocp), a0[t]);
            storeu_ps(m.add(t * ocp + 8), a1[t]);
        }
    }
}

/// [`gemm_avx2`] on AVX-512: 32 output channels (2 registers of 16) x up to 5
/// tiles at a time, or 16 x 5 where only 16 remain.
///
/// # Safety
/// AVX-512F; otherwise as [`gemm_avx2`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn gemm_avx512(
    nt: usize,
    v: *const f32,
    cin: usize,
    u: *const f32,
    ocp: usize,
    m: *mut f32,
) {
    // SAFETY: AVX-512F and the ranges per the contract.
    unsafe {
        for pos in 0..POS {
            let mut q = 0;
            while q < ocp {
                let two = ocp - q >= 2 * L;
                let w = u.add(pos * cin * ocp + q);
                for t0 in (0..nt).step_by(5) {
                    let (vb, mb) = (
                        v.add((pos * WT + t0) * cin),
                        m.add((pos * WT + t0) * ocp + q),
                    );
                    macro_rules! go {
                        ($nq:literal) => {
                            match nt - t0 {
                                1 => block_avx512::<1, $nq>(vb, cin, w, ocp, mb),
                                2 => block_avx512::<2, $nq>(vb, cin, w, ocp, mb),
                                3 => block_avx512::<3, $nq>(vb, cin, w, ocp, mb),
                                4 => block_avx512::<4, $nq>(vb, cin, w, ocp, mb),
                                _ => block_avx512::<5, $nq>(vb, cin, w, ocp, mb),
                            }
                        };
                    }
                    if two {
                        go!(2)
                    } else {
                        go!(1)
                    }
                }
                q += if two { 2 * L } else { L };
            }
        }
    }
}

/// `NT` tiles x `NQ` blocks of 16 channels of [`gemm_avx512`] at one
/// position.
///
/// # Safety
/// As [`gemm_avx512`], for those tiles and channels.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn block_avx512<const NT: usize, const NQ: usize>(
    v: *const f32,
    cin: usize,
    w: *const f32,
    ocp: usize,
    m: *mut f32,
) {
    // SAFETY: AVX-512F and the ranges per the contract.
    unsafe {
        use std::arch::x86_64::*;
        let mut acc = [[_mm512_setzero_ps(); NQ]; NT];
        for c in 0..cin {
            let wr = w.add(c * ocp);
            let mut wv = [_mm512_setzero_ps(); NQ];
            for (q, wq) in wv.iter_mut().enumerate() {
                *wq = _mm512_loadu_ps(wr.add(q * L));
            }
            for (t, a) in acc.iter_mut().enumerate() {
                let b = _mm512_set1_ps(*v.add(t * cin + c));
                for (aq, wq) in a.iter_mut().zip(&wv) {
                    *aq = _mm512_fmadd_ps(b, *wq, *aq);
                }
            }
        }
        for (t, a) in acc.iter().enumerate() {
            for (q, aq) in a.iter().enumerate() {
                _mm512_storeu_ps(m.add(t * ocp + q * L), *aq);
            }
        }
    }
}

/// `Y = A^T M A` of `nt` tiles, 8 channels at a time: row `a` of each tile
/// to `out[a]`, pixel `3 t + b` at `[(3 t + b) * ocp + o]`.
///
/// # Safety
/// AVX2; `m` filled for `nt` tiles; each `out[a]` valid for `3 nt ocp`;
/// `ocp` a multiple of 8.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn output(m: *const f32, nt: usize, ocp: usize, out: [*mut f32; M]) {
    // SAFETY: AVX2 and the ranges per the contract.
    unsafe {
        use dbt_isa::ymm::{loadu_ps, storeu_ps};
        use std::arch::x86_64::*;
        for t in 0..nt {
            for o in (0..ocp).step_by(8) {
                let ld = |pos: usize| loadu_ps(m.add((pos * WT + t) * ocp + o));
                let mut s = [[_mm256_setzero_ps(); M]; N];
                for (j, sj) in s.iter_mut().enumerate() {
                    *sj = at5([
                        ld(j),
                        ld(N + j),
                        ld(2 * N + j),
                        ld(3 * N + j),
                        ld(4 * N + j),
                    ]);
                }
                for (a, dst) in out.iter().enumerate() {
                    let y = at5([s[0][a], s[1][a], s[2][a], s[3][a], s[4][a]]);
                    for (b, yb) in y.into_iter().enumerate() {
                        storeu_ps(dst.add((M * t + b) * ocp + o), yb);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::int8::winograd::{AT, BT};
    use crate::testutil::{max_rel, random_block, random_vec};
    use crate::{reference_block, Fp32Block, Fp32Workspace};

    /// The factorised float transforms are the matrices (unit vectors).
    #[test]
    fn factorised_float_transforms_are_the_matrices() {
        if !dbt_isa::kernel_test_runs("fp32 winograd", &["avx2"]) {
            return;
        }
        use std::arch::x86_64::*;
        for k in 0..N {
            // SAFETY: AVX2 detected above.
            let (b, a) = unsafe {
                let x: [__m256; N] =
                    std::array::from_fn(|j| _mm256_set1_ps(if j == k { 1.5 } else { 0.0 }));
                (bt5(x), at5(x))
            };
            for (i, row) in BT.iter().enumerate() {
                // SAFETY: a 32-byte value read as 8 floats.
                let l: [f32; 8] = unsafe { std::mem::transmute(b[i]) };
                assert!(l.iter().all(|&v| v == row[k] as f32 * 1.5));
            }
            for (i, row) in AT.iter().enumerate() {
                // SAFETY: as above.
                let l: [f32; 8] = unsafe { std::mem::transmute(a[i]) };
                assert!(l.iter().all(|&v| v == row[k] as f32 * 1.5));
            }
        }
    }

    /// Blocks convolving by Winograd against the f64 definition, on the
    /// AVX-512 and AVX2 kernels: every height 1-7 (whole 3-row groups and
    /// rows left over), widths with 0, 1 or 2 columns left over, one and
    /// several chunks; 8- and 16-channel inputs (the first layer's 8 = 5 + 3
    /// concatenated; a 7-channel input stays direct). The bound: the direct
    /// kernels' 1e-5 (f32 sums of up to 576 products against f64) times 4,
    /// for the transforms' scaling of the rounding (at most 36 on a term,
    /// far less on the sums: measured below 2e-6 here).
    #[test]
    fn winograd_blocks_match_the_definition() {
        let kernels: Vec<Kernel> = [
            (Kernel::Avx2, "fp32 avx2 winograd", &["avx2", "fma"][..]),
            (Kernel::Avx512, "fp32 avx512 winograd", &["avx512f"][..]),
        ]
        .into_iter()
        .filter(|(_, name, needs)| dbt_isa::kernel_test_runs(name, needs))
        .map(|(k, _, _)| k)
        .collect();
        for k in kernels {
            let mut worst = 0.0f64;
            for h in 1..=7 {
                for (sc, ac, hidden, w) in [
                    (5, 3, 32, 1),
                    (5, 3, 16, 7),
                    (5, 3, 32, 17),
                    (5, 2, 48, 65),
                    (5, 3, 64, 9),
                ] {
                    let b = random_block(sc, ac, hidden, (h * 31 + w) as u64);
                    let state = random_vec(sc * h * w, 1);
                    let aux = random_vec(ac * h * w, 2);
                    let want = reference_block(&b, &state, &aux, h, w).unwrap();
                    let fb = Fp32Block::with_winograd(&b, k, true).unwrap();
                    let eligible_layers = usize::from(eligible(sc + ac)) + 2;
                    assert_eq!(fb.winograd_layers(), eligible_layers);
                    let mut ws = Fp32Workspace::new(&fb, h, w);
                    let mut got = state.clone();
                    fb.run(&mut ws, &mut got, &aux).unwrap();
                    let e = max_rel(&got, &want);
                    worst = worst.max(e);
                    assert!(
                        e < 4e-5,
                        "{k:?} {sc}+{ac}->{hidden} {h}x{w}: max rel error {e:e}"
                    );
                }
            }
            eprintln!("{k:?}: Winograd fp32 worst relative error {worst:.1e}");
        }
    }
}
