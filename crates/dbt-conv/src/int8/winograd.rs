//! The AVX2 int8 convolution by Winograd's minimal filtering F(3x3, 3x3)
//! (Lavin & Gray 2016, "Fast algorithms for convolutional neural networks",
//! CVPR, arXiv:1509.09308; the Toom-Cook points 0, 1, -1, 2 and infinity):
//! each 3 x 3 block of output pixels from its 5 x 5 input patch with 25
//! multiplications per input channel instead of 81.
//!
//! `Y = A^T [(G g G^T) . (B^T d B)] A` with
//! ```text
//! B^T = | 2 -1 -2  1  0 |   6 G = |  3  0  0 |   A^T = | 1  1  1  1  0 |
//!       | 0 -2 -1  1  0 |         | -3 -3 -3 |         | 0  1 -1  2  0 |
//!       | 0  2 -3  1  0 |         | -1  1 -1 |         | 0  1  1  4  1 |
//!       | 0 -1  0  1  0 |         |  1  2  4 |
//!       | 0  2 -1 -2  1 |         |  0  0  6 |
//! ```
//! (`scripts/winograd-f33.py` derives them with exact fractions and checks
//! the identity), computed here in integers, exactly: the weights are
//! transformed with `G' = 6 G` (integer entries), so the sum is `36 Y`, and
//! `Y` is that shifted right by 2 (exact: a multiple of 4) times the inverse
//! of 9 modulo 2^32 (exact: a multiple of 9). Ranges: the activation bytes
//! `u` (0..=255) transform to `|B^T d B| <= 6 * 6 * 255 = 9180` (the largest
//! absolute row sum of `B^T` is 6), the weights (-128..=127) to
//! `|G' g G'^T| <= 9 * 9 * 128 = 10368`: both i16, so the products are the
//! direct AVX2 kernel's `vpmaddwd`, exact (a pair's sum at most
//! `2 * 9180 * 10368 < 2^31`); the i32 sums may wrap on the way (wrapping
//! additions are exact modulo 2^32) as long as `36 Y` itself fits, which
//! `cin4 <= 192` ensures (`36 * 9 * 192 * 255 * 128 < 2^31`). The
//! convolution is therefore bit for bit the direct one (tested), at
//! 25 / 9 = 2.8 multiply-adds per output pixel and input channel instead of
//! 9, plus the two transforms. Rows and columns left over (the grid's height
//! or width not a multiple of 3) run the direct AVX2 tile.

use super::*;

/// Tiles of 3 x 3 output pixels per chunk: 5, so 15 pixels of a row and
/// 10 accumulators per pass.
pub(super) const WT: usize = 5;

/// Output pixels per tile side.
pub(super) const M: usize = 3;

/// Input pixels per patch side, and transform positions.
const N: usize = 5;
const POS: usize = N * N;

/// `B^T`.
const BT: [[i32; N]; N] = [
    [2, -1, -2, 1, 0],
    [0, -2, -1, 1, 0],
    [0, 2, -3, 1, 0],
    [0, -1, 0, 1, 0],
    [0, 2, -1, -2, 1],
];

/// `G' = 6 G`.
const GP: [[i32; 3]; N] = [[3, 0, 0], [-3, -3, -3], [-1, 1, -1], [1, 2, 4], [0, 0, 6]];

/// `A^T`.
const AT: [[i32; N]; M] = [[1, 1, 1, 1, 0], [0, 1, -1, 2, 0], [0, 1, 1, 4, 1]];

/// The inverse of 9 modulo 2^32 (`9 * INV9 = 2 * 2^32 + 1`).
const INV9: i32 = 954_437_177;

/// Whether a convolution of `cin4` input bytes per pixel runs by Winograd
/// on AVX2 (see the module's comment).
pub(super) fn eligible(cin4: usize) -> bool {
    (4..=192).contains(&cin4) && cin4.is_multiple_of(4)
}

/// The weights transformed, `U = G' g G'^T` per output and input channel,
/// from `w16` (`[tap][cin4 / 2][ocp][2]`) into `[pos][cin4 / 2][ocp][2]`,
/// `pos = 5 i + j` (`i` along the kernel's rows).
pub(super) fn transform_weights(w16: &[i16], cin4: usize, ocp: usize) -> Vec<i16> {
    let k2 = cin4 / 2;
    assert_eq!(w16.len(), 9 * k2 * ocp * 2);
    let mut u = vec![0i16; POS * k2 * ocp * 2];
    for k in 0..k2 {
        for o in 0..ocp {
            for e in 0..2 {
                let g = |ky: usize, kx: usize| {
                    i32::from(w16[(((3 * ky + kx) * k2 + k) * ocp + o) * 2 + e])
                };
                for (i, gi) in GP.iter().enumerate() {
                    for (j, gj) in GP.iter().enumerate() {
                        let mut v = 0;
                        for (ky, a) in gi.iter().enumerate() {
                            for (kx, b) in gj.iter().enumerate() {
                                v += a * g(ky, kx) * b;
                            }
                        }
                        // |v| <= 9 * 9 * 128 (module comment)
                        u[(((N * i + j) * k2 + k) * ocp + o) * 2 + e] = v as i16;
                    }
                }
            }
        }
    }
    u
}

/// Three output rows `r..r + 3` of the convolution (`inp` padded, row
/// stride `rs`, pixel stride `cs`; `w` pixels), the triples of pixels by
/// Winograd on AVX2 and the last `w % 3` columns by the direct AVX2 tile;
/// `dst(a, x, g0, tile)` receives row `r + a`'s tiles in the direct kernel's
/// layout (`tile[p * gw + j]`, pixels from `x`, channels from `g0`).
///
/// Callers: the AVX2 kernel only (AVX2 detected, which `Int8Block::new`
/// checks); `u` is `p.wino`.
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
pub(super) fn row_triple(
    p: &PackedI8,
    u: &[i16],
    inp: &[u8],
    r: usize,
    rs: usize,
    cs: usize,
    w: usize,
    win: &mut [i16],
    dst: &mut RowSink<'_>,
) {
    let (cin4, ocp) = (p.cin4, p.ocp);
    assert!(eligible(cin4) && cin4 <= cs && ocp.is_multiple_of(L));
    assert!(u.len() == POS * cin4 * ocp && (u.as_ptr() as usize).is_multiple_of(32));
    assert!(rs == (w + 2) * cs && inp.len() >= (r + N) * rs);
    let mut v = vec![0i16; POS * WT * cin4];
    let mut m = vec![0i32; POS * WT * L];
    let mut tiles: [Vec<i32>; M] = std::array::from_fn(|_| vec![0; M * WT * GROUP]);
    let mut x = 0;
    while x + M <= w {
        let nt = ((w - x) / M).min(WT);
        // SAFETY: AVX2 (the caller's contract); the chunk's patches are
        // padded rows r..r + 5 and columns x..x + 3 nt + 2 <= w + 2, inside
        // `inp` (asserted), `cin4 <= cs` bytes each; `v` holds POS * WT * cin4.
        unsafe {
            input_avx2(
                inp.as_ptr().add(r * rs + x * cs),
                rs,
                cs,
                cin4,
                nt,
                v.as_mut_ptr(),
            )
        };
        let mut g0 = 0;
        while g0 < ocp {
            let gw = group_width(ocp, g0);
            for q in 0..gw / L {
                let uq = u[(g0 + q * L) * 2..].as_ptr();
                // SAFETY: AVX2; `v` holds the chunk's nt tiles, `uq` the
                // transformed weights from channel g0 + 16 q (aligned: `u` is,
                // offsets are multiples of 32 bytes), `m` POS * WT * 16 i32;
                // each of the tiles holds 3 WT pixels of the group's gw <= GROUP.
                unsafe {
                    let (vp, mp) = (v.as_ptr(), m.as_mut_ptr());
                    match nt {
                        1 => gemm_avx2::<1>(vp, cin4, uq, ocp, mp),
                        2 => gemm_avx2::<2>(vp, cin4, uq, ocp, mp),
                        3 => gemm_avx2::<3>(vp, cin4, uq, ocp, mp),
                        4 => gemm_avx2::<4>(vp, cin4, uq, ocp, mp),
                        _ => gemm_avx2::<5>(vp, cin4, uq, ocp, mp),
                    }
                    let t = tiles.each_mut().map(|t| t.as_mut_ptr());
                    output_avx2(m.as_ptr(), nt, gw, q, t);
                }
            }
            for (a, t) in tiles.iter().enumerate() {
                dst(a, x, g0, &t[..M * nt * gw]);
            }
            g0 += gw;
        }
        x += M * nt;
    }
    if x < w {
        let np = w - x;
        let tile = &mut tiles[0];
        for a in 0..M {
            let mut g0 = 0;
            while g0 < ocp {
                let gw = group_width(ocp, g0);
                let base = (r + a) * rs + x * cs;
                run_tile(Kernel::Avx2, gw, np, inp, base, rs, cs, p, g0, tile, win);
                dst(a, x, g0, &tile[..np * gw]);
                g0 += gw;
            }
        }
    }
}

/// `sum_j c[j] x[j]` for small constant integer `c` (0, +-1..+-4), by
/// additions and shifts (the constants are known where this is inlined, so
/// the matches fold away).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn lin16(c: &[i32; N], x: &[std::arch::x86_64::__m256i; N]) -> std::arch::x86_64::__m256i {
    use std::arch::x86_64::*;
    let mut acc = _mm256_setzero_si256();
    for (&k, &v) in c.iter().zip(x) {
        let t = match k.abs() {
            0 => continue,
            1 => v,
            2 => _mm256_add_epi16(v, v),
            3 => _mm256_add_epi16(_mm256_add_epi16(v, v), v),
            _ => _mm256_slli_epi16::<2>(v),
        };
        acc = if k > 0 {
            _mm256_add_epi16(acc, t)
        } else {
            _mm256_sub_epi16(acc, t)
        };
    }
    acc
}

/// [`lin16`] on i32 lanes.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn lin32(c: &[i32; N], x: &[std::arch::x86_64::__m256i; N]) -> std::arch::x86_64::__m256i {
    use std::arch::x86_64::*;
    let mut acc = _mm256_setzero_si256();
    for (&k, &v) in c.iter().zip(x) {
        let t = match k.abs() {
            0 => continue,
            1 => v,
            2 => _mm256_add_epi32(v, v),
            3 => _mm256_add_epi32(_mm256_add_epi32(v, v), v),
            _ => _mm256_slli_epi32::<2>(v),
        };
        acc = if k > 0 {
            _mm256_add_epi32(acc, t)
        } else {
            _mm256_sub_epi32(acc, t)
        };
    }
    acc
}

/// `V = B^T d B` of `nt` patches (5 x 5 pixels from `inp`, the next one 3
/// pixels right), 16 channels at a time (then 8, then 4), into
/// `v[(pos * WT + t) * cin4 + c]`.
///
/// # Safety
/// AVX2; `inp` valid for rows 0..5 (stride `rs`) of pixels 0..3 nt + 2
/// (stride `cs`), `cin4` bytes each; `cin4` a multiple of 4; `v` valid for
/// `POS * WT * cin4` i16; `nt <= WT`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn input_avx2(inp: *const u8, rs: usize, cs: usize, cin4: usize, nt: usize, v: *mut i16) {
    // SAFETY: AVX2 and the ranges per the contract: each step reads and
    // writes `n <= cin4 - c` channels from `c`.
    unsafe {
        for t in 0..nt {
            let (src, dst) = (inp.add(M * t * cs), v.add(t * cin4));
            let mut c = 0;
            while c + 16 <= cin4 {
                input_step::<16>(src.add(c), rs, cs, dst.add(c), WT * cin4);
                c += 16;
            }
            if c + 8 <= cin4 {
                input_step::<8>(src.add(c), rs, cs, dst.add(c), WT * cin4);
                c += 8;
            }
            if c < cin4 {
                input_step::<4>(src.add(c), rs, cs, dst.add(c), WT * cin4);
            }
        }
    }
}

/// [`input_avx2`] on `NC` (16, 8 or 4) channels of one patch: bytes
/// zero-extended into the low `NC` of 16 i16 lanes (the others zero, not
/// stored), `V` of position `pos` at `dst + pos * ps`.
///
/// # Safety
/// AVX2; `src` valid for `NC` bytes of rows 0..5 (stride `rs`) x pixels 0..5
/// (stride `cs`); `dst` for `NC` i16 at `pos * ps`, `pos < 25`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
#[allow(clippy::needless_range_loop)] // e[i][j] filled column by column
unsafe fn input_step<const NC: usize>(
    src: *const u8,
    rs: usize,
    cs: usize,
    dst: *mut i16,
    ps: usize,
) {
    // SAFETY: AVX2 and the ranges per the contract (loads and stores of
    // exactly NC bytes / i16).
    unsafe {
        use std::arch::x86_64::*;
        let ld = |i: usize, j: usize| {
            let a = src.add(i * rs + j * cs);
            _mm256_cvtepu8_epi16(match NC {
                16 => _mm_loadu_si128(a as *const __m128i),
                8 => _mm_loadl_epi64(a as *const __m128i),
                _ => _mm_cvtsi32_si128((a as *const i32).read_unaligned()),
            })
        };
        // B^T d, column by column: e[i][j]
        let mut e = [[_mm256_setzero_si256(); N]; N];
        for j in 0..N {
            let d = [ld(0, j), ld(1, j), ld(2, j), ld(3, j), ld(4, j)];
            for (i, b) in BT.iter().enumerate() {
                e[i][j] = lin16(b, &d);
            }
        }
        // (B^T d) B, row by row
        for (i, ei) in e.iter().enumerate() {
            for (j, b) in BT.iter().enumerate() {
                let o = lin16(b, ei);
                let d = dst.add((N * i + j) * ps);
                match NC {
                    16 => _mm256_storeu_si256(d as *mut __m256i, o),
                    8 => _mm_storeu_si128(d as *mut __m128i, _mm256_castsi256_si128(o)),
                    _ => _mm_storel_epi64(d as *mut __m128i, _mm256_castsi256_si128(o)),
                }
            }
        }
    }
}

/// The element-wise products summed over the input channels, per transform
/// position, for 16 output channels x `NT` tiles (10 accumulators, as the
/// direct AVX2 pass): per pair of input channels one 32-bit broadcast per
/// tile and two `vpmaddwd` against the pair-packed transformed weights;
/// stored at `m[(pos * WT + t) * 16 + k]`.
///
/// # Safety
/// AVX2; `v` as [`input_avx2`] fills it for `NT` tiles; `u` valid for the
/// transformed weights (`[pos][cin4 / 2][ocp][2]`) from the pass's first
/// channel and aligned to 32 bytes (`ocp` a multiple of 16); `m` valid for
/// `POS * WT * 16` i32.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn gemm_avx2<const NT: usize>(
    v: *const i16,
    cin4: usize,
    u: *const i16,
    ocp: usize,
    m: *mut i32,
) {
    // SAFETY: AVX2 and the ranges per the contract.
    unsafe {
        use std::arch::x86_64::*;
        let k2 = cin4 / 2;
        for pos in 0..POS {
            let ib = v.add(pos * WT * cin4);
            let wb = u.add(pos * k2 * ocp * 2);
            let mut a0 = [_mm256_setzero_si256(); NT];
            let mut a1 = [_mm256_setzero_si256(); NT];
            for k in 0..k2 {
                let wr = wb.add(k * ocp * 2);
                let w0 = _mm256_load_si256(wr as *const __m256i);
                let w1 = _mm256_load_si256(wr.add(16) as *const __m256i);
                for t in 0..NT {
                    let pair = (ib.add(t * cin4 + 2 * k) as *const i32).read_unaligned();
                    let b = _mm256_set1_epi32(pair);
                    a0[t] = _mm256_add_epi32(a0[t], _mm256_madd_epi16(b, w0));
                    a1[t] = _mm256_add_epi32(a1[t], _mm256_madd_epi16(b, w1));
                }
            }
            for t in 0..NT {
                let o = m.add((pos * WT + t) * L);
                _mm256_storeu_si256(o as *mut __m256i, a0[t]);
                _mm256_storeu_si256(o.add(8) as *mut __m256i, a1[t]);
            }
        }
    }
}

/// `Y = (A^T M A) / 36` of `nt` tiles' 16 channels (block `q` of a group
/// `gw` wide): row `a` of each tile to `out[a]`, pixel `3 t + b` at
/// `[(3 t + b) * gw + 16 q + k]`.
///
/// # Safety
/// AVX2; `m` as [`gemm_avx2`] fills it for `nt` tiles; each `out[a]` valid
/// for `3 * nt * gw` i32; `16 (q + 1) <= gw`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::needless_range_loop)] // s[a][j] filled column by column
unsafe fn output_avx2(m: *const i32, nt: usize, gw: usize, q: usize, out: [*mut i32; M]) {
    // SAFETY: AVX2 and the ranges per the contract.
    unsafe {
        use std::arch::x86_64::*;
        let inv9 = _mm256_set1_epi32(INV9);
        for t in 0..nt {
            for h in 0..2 {
                let ld = |pos: usize| {
                    _mm256_loadu_si256(m.add((pos * WT + t) * L + 8 * h) as *const __m256i)
                };
                // A^T M, column by column: s[a][j]
                let mut s = [[_mm256_setzero_si256(); N]; M];
                for j in 0..N {
                    let c = [
                        ld(j),
                        ld(N + j),
                        ld(2 * N + j),
                        ld(3 * N + j),
                        ld(4 * N + j),
                    ];
                    for (a, at) in AT.iter().enumerate() {
                        s[a][j] = lin32(at, &c);
                    }
                }
                // (A^T M) A, row by row, then / 4 (a shift) / 9 (the inverse)
                for (a, sa) in s.iter().enumerate() {
                    for (b, at) in AT.iter().enumerate() {
                        let y = _mm256_mullo_epi32(_mm256_srai_epi32::<2>(lin32(at, sa)), inv9);
                        let at = out[a].add((M * t + b) * gw + q * L + 8 * h);
                        _mm256_storeu_si256(at as *mut __m256i, y);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The integer sums of two output rows by Winograd against the portable
    /// direct tile, bit for bit, at the ends of the ranges the module's
    /// comment bounds (weights -128 and 127, activation bytes 0 and 255,
    /// mixed with random ones), for 3 to 64 input channels (cin4 4 to 64, so
    /// the input transform's 16-, 8- and 4-channel steps; pixel strides equal
    /// to cin4 or wider), output channels in one
    /// 16-lane group, a 64-lane group and both (80), and widths with and
    /// without the odd last column, shorter and longer than a chunk.
    #[test]
    fn winograd_sums_are_the_direct_sums_at_the_ends_of_the_ranges() {
        if !dbt_isa::kernel_test_runs("int8 avx2 winograd", &["avx2"]) {
            return;
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(29);
        for (cin, out_ch, extra, w) in [
            (16, 16, 0, 7),
            (32, 80, 4, 12),
            (45, 5, 0, 1),
            (64, 64, 16, 3),
            (32, 32, 0, 21),
            (8, 32, 0, 10),
            (7, 16, 4, 5),
            (20, 32, 0, 6),
            (3, 16, 0, 2),
        ] {
            let weight = (0..out_ch * cin * 9)
                .map(|_| match rng.random_range(0..4) {
                    0 => -128,
                    1 => 127,
                    _ => rng.random::<i8>(),
                })
                .collect();
            let l = Int8Conv {
                in_ch: cin,
                out_ch,
                weight,
                weight_scale: vec![1.0; out_ch],
                bias: vec![0.0; out_ch],
                prelu: None,
                q_out: None,
                q_act: None,
            };
            let q_in = QuantParams {
                scale: 1.0,
                zero_point: 0,
            };
            let p = pack(&l, q_in, true);
            let u = p.wino.as_deref().expect("Winograd weights");
            let cs = p.cin4 + extra;
            let rs = (w + 2) * cs;
            let inp: Vec<u8> = (0..N * rs)
                .map(|_| match rng.random_range(0..3) {
                    0 => 0,
                    1 => 255,
                    _ => rng.random::<u8>(),
                })
                .collect();
            let mut want = vec![0i32; M * w * p.ocp];
            let mut tile = [0i32; NP_NARROW * GROUP];
            for a in 0..M {
                for_each_tile(p.ocp, w, |g0, gw, x, np| {
                    let base = a * rs + x * cs;
                    run_tile(
                        Kernel::Portable,
                        gw,
                        np,
                        &inp,
                        base,
                        rs,
                        cs,
                        &p,
                        g0,
                        &mut tile,
                        &mut [],
                    );
                    for px in 0..np {
                        let o = (a * w + x + px) * p.ocp + g0;
                        want[o..o + gw].copy_from_slice(&tile[px * gw..(px + 1) * gw]);
                    }
                });
            }
            let mut got = vec![i32::MIN; M * w * p.ocp];
            let mut win = vec![0i16; avx2_window_len(p.cin4)];
            row_triple(
                &p,
                u,
                &inp,
                0,
                rs,
                cs,
                w,
                &mut win,
                &mut |a, x, g0, tile| {
                    let gw = group_width(p.ocp, g0);
                    for (px, t) in tile.chunks_exact(gw).enumerate() {
                        let o = (a * w + x + px) * p.ocp + g0;
                        got[o..o + gw].copy_from_slice(t);
                    }
                },
            );
            assert_eq!(got, want, "{cin} -> {out_ch} channels, width {w}");
            // Sums larger than any one product: not a trivial case.
            let big = want.iter().map(|v| v.unsigned_abs()).max().unwrap_or(0);
            assert!(big > 255 * 128, "largest |sum| {big}");
        }
    }

    /// The constants are a Winograd F(3x3, 3x3): on random integer
    /// patches and kernels, `A^T [(G' g G'^T) . (B^T d B)] A` is 36 times the
    /// 3 x 3 correlation; and the row sums behind the module's range bounds.
    #[test]
    fn the_transforms_give_36_times_the_correlation() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(36);
        let mul = |a: &[Vec<i64>], b: &[Vec<i64>]| -> Vec<Vec<i64>> {
            (0..a.len())
                .map(|i| {
                    (0..b[0].len())
                        .map(|j| (0..b.len()).map(|k| a[i][k] * b[k][j]).sum())
                        .collect()
                })
                .collect()
        };
        let tr = |a: &[Vec<i64>]| -> Vec<Vec<i64>> {
            (0..a[0].len())
                .map(|j| a.iter().map(|r| r[j]).collect())
                .collect()
        };
        let m64 = |a: &[[i32; N]]| -> Vec<Vec<i64>> {
            a.iter()
                .map(|r| r.iter().map(|&v| i64::from(v)).collect())
                .collect()
        };
        let (bt, at) = (m64(&BT), m64(&AT));
        let gp: Vec<Vec<i64>> = GP
            .iter()
            .map(|r| r.iter().map(|&v| i64::from(v)).collect())
            .collect();
        for _ in 0..200 {
            let d: Vec<Vec<i64>> = (0..N)
                .map(|_| (0..N).map(|_| rng.random_range(-300..=300)).collect())
                .collect();
            let g: Vec<Vec<i64>> = (0..3)
                .map(|_| (0..3).map(|_| rng.random_range(-128..=127)).collect())
                .collect();
            let u = mul(&mul(&gp, &g), &tr(&gp));
            let v = mul(&mul(&bt, &d), &tr(&bt));
            let prod: Vec<Vec<i64>> = (0..N)
                .map(|i| (0..N).map(|j| u[i][j] * v[i][j]).collect())
                .collect();
            let y = mul(&mul(&at, &prod), &tr(&at));
            for a in 0..M {
                for b in 0..M {
                    let want: i64 = (0..3)
                        .flat_map(|ky| (0..3).map(move |kx| (ky, kx)))
                        .map(|(ky, kx)| d[a + ky][b + kx] * g[ky][kx])
                        .sum();
                    assert_eq!(y[a][b], 36 * want, "output ({a}, {b})");
                }
            }
        }
        let row_sum = |r: &[i32]| r.iter().map(|v| v.abs()).sum::<i32>();
        assert_eq!(BT.iter().map(|r| row_sum(r)).max(), Some(6));
        assert_eq!(GP.iter().map(|r| row_sum(r)).max(), Some(9));
        assert_eq!(9i32.wrapping_mul(INV9), 1);
    }

    /// The packed transformed weights are `G' g G'^T` of the pair-packed
    /// weights at their places.
    #[test]
    #[allow(clippy::needless_range_loop)]
    fn transformed_weights_sit_where_the_kernel_reads_them() {
        let (cin4, ocp) = (16, 32);
        let w16: Vec<i16> = (0..9 * cin4 * ocp)
            .map(|k| ((k * 37 % 256) as i16) - 128)
            .collect();
        let u = transform_weights(&w16, cin4, ocp);
        for (k, o, e) in [(0, 0, 0), (3, 7, 1), (7, 31, 1)] {
            let g = |t: usize| i32::from(w16[((t * (cin4 / 2) + k) * ocp + o) * 2 + e]);
            for i in 0..N {
                for j in 0..N {
                    let mut s = 0;
                    for a in 0..3 {
                        for b in 0..3 {
                            s += GP[i][a] * g(3 * a + b) * GP[j][b];
                        }
                    }
                    let got = u[(((N * i + j) * (cin4 / 2) + k) * ocp + o) * 2 + e];
                    assert_eq!(
                        i32::from(got),
                        s,
                        "pos ({i}, {j}), pair {k}, channel {o}.{e}"
                    );
                }
            }
        }
    }
}
