//! The AVX2 and AVX-VNNI int8 convolution by Winograd's minimal filtering
//! F(3x3, 3x3)
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
//! or width not a multiple of 3) run the kernel's direct tile.
//!
//! Where it runs: the AVX2 kernel (`vpmaddwd` then `vpaddd`, as its direct
//! tile) and the AVX-VNNI kernel (`vpdpwssd`, the same i16 products
//! accumulated in one instruction), all input widths (`eligible`). Not the
//! AVX-512 VNNI kernel: its direct `vpdpbusd` multiplies 64 byte pairs per
//! instruction where `vpdpwssd` multiplies 32 i16 pairs, so Winograd saves
//! only 38 % of its multiply instructions, less than the transforms cost;
//! tried (the transforms as here, a 512-bit product loop), a paper-geometry
//! slice took 300 ms against the direct kernel's 264 ms on a Zen 5
//! (`dbtor-bench --direct`, the AVX-512 rows), so it was not kept.

use super::*;

/// Tiles of 3 x 3 output pixels per chunk (each transform position's
/// weights are read once per chunk, for its register blocks of 5 tiles).
pub(super) const WT: usize = 20;

/// Output pixels per tile side.
pub(crate) const M: usize = 3;

/// Input pixels per patch side, and transform positions.
pub(crate) const N: usize = 5;
pub(crate) const POS: usize = N * N;

/// `B^T` ([`bt5`] computes it factorised; a test holds them equal).
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) const BT: [[i32; N]; N] = [
    [2, -1, -2, 1, 0],
    [0, -2, -1, 1, 0],
    [0, 2, -3, 1, 0],
    [0, -1, 0, 1, 0],
    [0, 2, -1, -2, 1],
];

/// `G' = 6 G`.
pub(crate) const GP: [[i32; 3]; N] = [[3, 0, 0], [-3, -3, -3], [-1, 1, -1], [1, 2, 4], [0, 0, 6]];

/// `A^T` ([`at5`] computes it factorised; a test holds them equal).
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) const AT: [[i32; N]; M] = [[1, 1, 1, 1, 0], [0, 1, -1, 2, 0], [0, 1, 1, 4, 1]];

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
    kernel: Kernel,
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
    assert!(matches!(kernel, Kernel::Avx2 | Kernel::AvxVnni));
    assert!(eligible(cin4) && cin4 <= cs && ocp.is_multiple_of(L));
    assert!(u.len() == POS * cin4 * ocp && (u.as_ptr() as usize).is_multiple_of(32));
    assert!(rs == (w + 2) * cs && inp.len() >= (r + N) * rs);
    thread_local! {
        static V: std::cell::RefCell<Vec<i16>> = const { std::cell::RefCell::new(Vec::new()) };
        static SUMS: std::cell::RefCell<Vec<i32>> = const { std::cell::RefCell::new(Vec::new()) };
    }
    // one 16-channel block's sums, then three rows of tiles
    let (mn, tn) = (POS * WT * L, M * WT * GROUP);
    crate::with_scratch(&V, POS * WT * cin4, |v| {
        crate::with_scratch(&SUMS, mn + M * tn, |b| {
            let (m, t) = b.split_at_mut(mn);
            let (t0, t12) = t.split_at_mut(tn);
            let (t1, t2) = t12.split_at_mut(tn);
            triple_in(
                kernel,
                p,
                u,
                inp,
                r,
                rs,
                cs,
                w,
                win,
                dst,
                v,
                m,
                [t0, t1, t2],
            )
        })
    })
}

/// [`row_triple`] with its scratch: `v` (`POS * WT * cin4`), `m`
/// (`POS * WT * 16`) and three tiles of `3 * WT * GROUP` sums.
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
fn triple_in(
    kernel: Kernel,
    p: &PackedI8,
    u: &[i16],
    inp: &[u8],
    r: usize,
    rs: usize,
    cs: usize,
    w: usize,
    win: &mut [i16],
    dst: &mut RowSink<'_>,
    v: &mut [i16],
    m: &mut [i32],
    mut tiles: [&mut [i32]; M],
) {
    let (cin4, ocp) = (p.cin4, p.ocp);
    assert!(v.len() >= POS * WT * cin4 && m.len() >= POS * WT * L);
    assert!(tiles.iter().all(|t| t.len() >= M * WT * GROUP));
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
                // SAFETY: the kernel's instructions were detected when the
                // block was made (the caller's contract); `v` holds the
                // chunk's nt tiles, `uq` the transformed weights from channel
                // g0 + 16 q (aligned: `u` is, offsets are multiples of 64
                // bytes), `m` POS * WT * 16 i32; each of the tiles holds
                // 3 WT pixels of the group's gw <= GROUP.
                unsafe {
                    let (vp, mp) = (v.as_ptr(), m.as_mut_ptr());
                    gemm(kernel, nt, vp, cin4, uq, ocp, mp);
                    let t = tiles.each_mut().map(|t| t.as_mut_ptr());
                    output_avx2(mp, nt, gw, q, t);
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
        let tile = &mut *tiles[0];
        for a in 0..M {
            let mut g0 = 0;
            while g0 < ocp {
                let gw = group_width(ocp, g0);
                let base = (r + a) * rs + x * cs;
                run_tile(kernel, gw, np, inp, base, rs, cs, p, g0, tile, win);
                dst(a, x, g0, &tile[..np * gw]);
                g0 += gw;
            }
        }
    }
}

/// The factorised transforms on one vector type: `$bt(x) = B^T x` (13
/// additions; [`BT`]'s rows: `r3 = x3 - x1`, `r0 = 2 (x0 - x2) + r3`,
/// `r1 = r3 - (x1 + x2)`, `r2 = r3 + 3 (x1 - x2)`, `r4 = (x4 - x2) - 2 r3`)
/// with `$badd`/`$bsub`, and `$at(x) = A^T x` (9 additions; [`AT`]'s rows:
/// `y0 = x0 + (x1 + x2) + x3`, `y1 = (x1 - x2) + 2 x3`,
/// `y2 = (x1 + x2) + 4 x3 + x4`) with `$aadd`/`$asub`. Here on i16 and i32
/// lanes; `crate::fp32::winograd` makes the float pair.
macro_rules! factorised_transforms {
    ($bt:ident, $at:ident, $ty:ty, $badd:ident, $bsub:ident, $aadd:ident, $asub:ident) => {
        #[doc = concat!("`B^T x`, factorised (`", stringify!($badd), "`).")]
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2")]
        #[inline]
        fn $bt(x: [$ty; N]) -> [$ty; N] {
            use std::arch::x86_64::*;
            let [x0, x1, x2, x3, x4] = x;
            let r3 = $bsub(x3, x1);
            let d02 = $bsub(x0, x2);
            let r0 = $badd($badd(d02, d02), r3);
            let r1 = $bsub(r3, $badd(x1, x2));
            let u = $bsub(x1, x2);
            let r2 = $badd($badd(r3, u), $badd(u, u));
            let r4 = $bsub($bsub(x4, x2), $badd(r3, r3));
            [r0, r1, r2, r3, r4]
        }

        #[doc = concat!("`A^T x`, factorised (`", stringify!($aadd), "`).")]
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2")]
        #[inline]
        fn $at(x: [$ty; N]) -> [$ty; M] {
            use std::arch::x86_64::*;
            let [x0, x1, x2, x3, x4] = x;
            let a = $aadd(x1, x2);
            let b = $asub(x1, x2);
            let x3x2 = $aadd(x3, x3);
            let y0 = $aadd($aadd(x0, a), x3);
            let y1 = $aadd(b, x3x2);
            let y2 = $aadd($aadd(a, x4), $aadd(x3x2, x3x2));
            [y0, y1, y2]
        }
    };
}
pub(crate) use factorised_transforms;

factorised_transforms!(
    bt5,
    at5,
    std::arch::x86_64::__m256i,
    _mm256_add_epi16,
    _mm256_sub_epi16,
    _mm256_add_epi32,
    _mm256_sub_epi32
);

/// `V = B^T d B` of `nt` patches (5 x 5 pixels from `inp`, the next one 3
/// pixels right, so neighbours share 2 columns), 16 channels at a time
/// (then 8, then 4), into `v[(pos * WT + t) * cin4 + c]`: `B^T` down each of
/// the chunk's `3 nt + 2` columns once, then `B` along each patch's rows.
///
/// # Safety
/// AVX2; `inp` valid for rows 0..5 (stride `rs`) of pixels 0..3 nt + 2
/// (stride `cs`), `cin4` bytes each; `cin4` a multiple of 4; `v` valid for
/// `POS * WT * cin4` i16; `nt` in 1..=WT.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn input_avx2(inp: *const u8, rs: usize, cs: usize, cin4: usize, nt: usize, v: *mut i16) {
    // SAFETY: AVX2 and the ranges per the contract: each step reads and
    // writes `NC <= cin4 - c` channels from `c`.
    unsafe {
        let mut c = 0;
        while c + 16 <= cin4 {
            input_step::<16>(inp.add(c), rs, cs, nt, v.add(c), cin4);
            c += 16;
        }
        if c + 8 <= cin4 {
            input_step::<8>(inp.add(c), rs, cs, nt, v.add(c), cin4);
            c += 8;
        }
        if c < cin4 {
            input_step::<4>(inp.add(c), rs, cs, nt, v.add(c), cin4);
        }
    }
}

/// [`input_avx2`] on `NC` (16, 8 or 4) channels: bytes zero-extended into
/// the low `NC` of 16 i16 lanes (the others zero, not stored); tile `t`'s
/// position `pos` at `dst + (pos * WT + t) * cin4`.
///
/// # Safety
/// AVX2; `src` valid for `NC` bytes of rows 0..5 (stride `rs`) x pixels
/// 0..3 nt + 2 (stride `cs`); `dst` for `NC` i16 at each of those places;
/// `nt` in 1..=WT.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
#[allow(clippy::needless_range_loop)] // row i of five columns
unsafe fn input_step<const NC: usize>(
    src: *const u8,
    rs: usize,
    cs: usize,
    nt: usize,
    dst: *mut i16,
    cin4: usize,
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
        // B^T d down every column of the chunk: cols[j][i]
        let col = |j: usize| bt5([ld(0, j), ld(1, j), ld(2, j), ld(3, j), ld(4, j)]);
        // the patch's five columns, the last two kept for the next patch
        let mut p = [col(0), col(1), col(2), col(3), col(4)];
        // (B^T d) B along each patch's rows
        for t in 0..nt {
            if t > 0 {
                let j = M * t;
                p = [p[3], p[4], col(j + 2), col(j + 3), col(j + 4)];
            }
            for i in 0..N {
                let o = bt5([p[0][i], p[1][i], p[2][i], p[3][i], p[4][i]]);
                for (j, oj) in o.into_iter().enumerate() {
                    let d = dst.add(((N * i + j) * WT + t) * cin4);
                    match NC {
                        16 => dbt_isa::ymm::storeu_si256(d as *mut __m256i, oj),
                        8 => _mm_storeu_si128(d as *mut __m128i, _mm256_castsi256_si128(oj)),
                        _ => _mm_storel_epi64(d as *mut __m128i, _mm256_castsi256_si128(oj)),
                    }
                }
            }
        }
    }
}

/// [`gemm_avx2`] or [`gemm_avxvnni`], as `kernel` says.
///
/// # Safety
/// As the one called (`kernel` AVX-VNNI: its instructions; else AVX2).
#[cfg(target_arch = "x86_64")]
unsafe fn gemm(
    kernel: Kernel,
    nt: usize,
    v: *const i16,
    cin4: usize,
    u: *const i16,
    ocp: usize,
    m: *mut i32,
) {
    // SAFETY: per the contract.
    unsafe {
        if kernel == Kernel::AvxVnni {
            gemm_avxvnni(nt, v, cin4, u, ocp, m)
        } else {
            gemm_avx2(nt, v, cin4, u, ocp, m)
        }
    }
}

/// Calls `$block::<n, ...>(args)` for a run-time `n` in 1..=5.
macro_rules! by_tiles {
    ($n:expr, $block:ident, [$($c:literal),*], $($arg:expr),*) => {
        match $n {
            1 => $block::<1 $(, $c)*>($($arg),*),
            2 => $block::<2 $(, $c)*>($($arg),*),
            3 => $block::<3 $(, $c)*>($($arg),*),
            4 => $block::<4 $(, $c)*>($($arg),*),
            _ => $block::<5 $(, $c)*>($($arg),*),
        }
    };
}

/// A product loop and its block: `$gemm` sums, per transform position, the
/// element-wise products over the input channels for 16 output channels x
/// `nt` tiles, 5 tiles at a time (`$block`: 10 accumulators, as the direct
/// AVX2 pass; each position's weights read once per 5 tiles while in
/// cache): per pair of input channels one 32-bit broadcast per tile and,
/// per 8 channels, `$acc(acc, pair, weights)` against the pair-packed
/// transformed weights; stored at `m[(pos * WT + t) * 16 + k]`.
macro_rules! product_loop {
    ($gemm:ident, $block:ident, $features:literal, $acc:expr, $what:literal) => {
        #[doc = concat!("The Winograd products with ", $what, ".")]
        ///
        /// # Safety
        #[doc = concat!("`", $features, "`; `v` as [`input_avx2`] fills it for `nt` (1..=WT)")]
        /// tiles; `u` valid for the transformed weights (`[pos][cin4 / 2][ocp][2]`)
        /// from the block's first channel and aligned to 32 bytes (`ocp` a
        /// multiple of 16); `m` valid for `POS * WT * 16` i32.
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        unsafe fn $gemm(
            nt: usize,
            v: *const i16,
            cin4: usize,
            u: *const i16,
            ocp: usize,
            m: *mut i32,
        ) {
            // SAFETY: the features and the ranges per the contract, block
            // by block.
            unsafe {
                for pos in 0..POS {
                    let w = u.add(pos * (cin4 / 2) * ocp * 2);
                    for t0 in (0..nt).step_by(5) {
                        let vb = v.add((pos * WT + t0) * cin4);
                        let mb = m.add((pos * WT + t0) * L);
                        by_tiles!(nt - t0, $block, [], vb, cin4, w, ocp, mb);
                    }
                }
            }
        }

        /// `NT` tiles at one position: `v` and `m` at the first tile, `w` at
        /// the position's weights.
        ///
        /// # Safety
        /// As the product loop's, for those tiles.
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        #[inline]
        unsafe fn $block<const NT: usize>(
            v: *const i16,
            cin4: usize,
            w: *const i16,
            ocp: usize,
            m: *mut i32,
        ) {
            // SAFETY: the features and the ranges per the contract.
            unsafe {
                use std::arch::x86_64::*;
                let mut a0 = [_mm256_setzero_si256(); NT];
                let mut a1 = [_mm256_setzero_si256(); NT];
                for k in 0..cin4 / 2 {
                    let wr = w.add(k * ocp * 2);
                    let w0 = _mm256_load_si256(wr as *const __m256i);
                    let w1 = _mm256_load_si256(wr.add(16) as *const __m256i);
                    for t in 0..NT {
                        let pair = (v.add(t * cin4 + 2 * k) as *const i32).read_unaligned();
                        let b = _mm256_set1_epi32(pair);
                        a0[t] = $acc(a0[t], b, w0);
                        a1[t] = $acc(a1[t], b, w1);
                    }
                }
                for t in 0..NT {
                    dbt_isa::ymm::storeu_si256(m.add(t * L) as *mut __m256i, a0[t]);
                    dbt_isa::ymm::storeu_si256(m.add(t * L + 8) as *mut __m256i, a1[t]);
                }
            }
        }
    };
}

product_loop!(
    gemm_avx2,
    block_avx2,
    "avx2",
    |a, b, w| _mm256_add_epi32(a, _mm256_madd_epi16(b, w)),
    "AVX2's `vpmaddwd` (exact sums of two i16 products) and `vpaddd`"
);
product_loop!(
    gemm_avxvnni,
    block_avxvnni,
    "avx2,avxvnni",
    |a, b, w| _mm256_dpwssd_avx_epi32(a, b, w),
    "AVX-VNNI's `vpdpwssd` (the same products and the accumulation in one instruction)"
);

/// `Y = (A^T M A) / 36` of `nt` tiles' 16 channels (block `q` of a group
/// `gw` wide): row `a` of each tile to `out[a]`, pixel `3 t + b` at
/// `[(3 t + b) * gw + 16 q + k]`.
///
/// # Safety
/// AVX2; `m` as [`gemm_avx2`] fills it for `nt` tiles; each `out[a]` valid
/// for `3 * nt * gw` i32; `16 (q + 1) <= gw`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn output_avx2(m: *const i32, nt: usize, gw: usize, q: usize, out: [*mut i32; M]) {
    // SAFETY: AVX2 and the ranges per the contract.
    unsafe {
        use std::arch::x86_64::*;
        let inv9 = _mm256_set1_epi32(INV9);
        for t in 0..nt {
            for h in 0..2 {
                let ld = |pos: usize| {
                    dbt_isa::ymm::loadu_si256(m.add((pos * WT + t) * L + 8 * h) as *const __m256i)
                };
                // A^T M down each column: s[j][a]
                let s: [[__m256i; M]; N] = [0, 1, 2, 3, 4].map(|j| {
                    at5([
                        ld(j),
                        ld(N + j),
                        ld(2 * N + j),
                        ld(3 * N + j),
                        ld(4 * N + j),
                    ])
                });
                // (A^T M) A along each row, then / 4 (a shift) / 9 (the inverse)
                for a in 0..M {
                    let y = at5([s[0][a], s[1][a], s[2][a], s[3][a], s[4][a]]);
                    for (b, yb) in y.into_iter().enumerate() {
                        let yb = _mm256_mullo_epi32(_mm256_srai_epi32::<2>(yb), inv9);
                        let at = out[a].add((M * t + b) * gw + q * L + 8 * h);
                        dbt_isa::ymm::storeu_si256(at as *mut __m256i, yb);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The integer sums of three output rows by Winograd (AVX2, AVX-VNNI) against the portable
    /// direct tile, bit for bit, at the ends of the ranges the module's
    /// comment bounds (weights -128 and 127, activation bytes 0 and 255,
    /// mixed with random ones), for 3 to 64 input channels (cin4 4 to 64, so
    /// the input transform's 16-, 8- and 4-channel steps; pixel strides equal
    /// to cin4 or wider), output channels in one
    /// 16-lane group, a 64-lane group and both (80), and widths with 0, 1
    /// or 2 columns left over, shorter than a register block of tiles and
    /// longer than two chunks.
    #[test]
    fn winograd_sums_are_the_direct_sums_at_the_ends_of_the_ranges() {
        for kernel in winograd_kernels() {
            sums_match(kernel);
        }
    }

    /// The Winograd kernels this CPU runs (each product loop), skipped
    /// with a printed reason where it lacks them.
    pub(in crate::int8) fn winograd_kernels() -> Vec<Kernel> {
        [
            (Kernel::Avx2, "int8 avx2 winograd", &["avx2"][..]),
            (
                Kernel::AvxVnni,
                "int8 avx-vnni winograd",
                &["avx2", "avxvnni"][..],
            ),
        ]
        .into_iter()
        .filter(|(_, name, needs)| dbt_isa::kernel_test_runs(name, needs))
        .map(|(k, _, _)| k)
        .collect()
    }

    fn sums_match(kernel: Kernel) {
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
            (32, 32, 0, 3 * WT * 2 + 4),
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
                kernel,
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
            assert_eq!(
                got, want,
                "{kernel:?}: {cin} -> {out_ch} channels, width {w}"
            );
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

    /// The factorised transforms are the matrices: each unit vector (in
    /// every lane, and a lane pattern) goes to the matrix's column.
    #[test]
    fn factorised_transforms_are_the_matrices() {
        if !dbt_isa::kernel_test_runs("int8 avx2 winograd", &["avx2"]) {
            return;
        }
        use std::arch::x86_64::*;
        let lanes16 = |v: __m256i| -> [i16; 16] {
            // SAFETY: a 32-byte value reinterpreted as 16 i16.
            unsafe { std::mem::transmute(v) }
        };
        let lanes32 = |v: __m256i| -> [i32; 8] {
            // SAFETY: a 32-byte value reinterpreted as 8 i32.
            unsafe { std::mem::transmute(v) }
        };
        for k in 0..N {
            for scale in [1i32, -3, 1000] {
                // SAFETY: AVX2 (checked above).
                let (b, a) = unsafe {
                    let x16: [__m256i; N] = std::array::from_fn(|j| {
                        _mm256_set1_epi16(if j == k { scale as i16 } else { 0 })
                    });
                    let x32: [__m256i; N] =
                        std::array::from_fn(|j| _mm256_set1_epi32(if j == k { scale } else { 0 }));
                    (bt5(x16), at5(x32))
                };
                for (i, row) in BT.iter().enumerate() {
                    assert!(lanes16(b[i])
                        .iter()
                        .all(|&v| i32::from(v) == row[k] * scale));
                }
                for (i, row) in AT.iter().enumerate() {
                    assert!(lanes32(a[i]).iter().all(|&v| v == row[k] * scale));
                }
            }
        }
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
