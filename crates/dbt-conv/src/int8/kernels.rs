//! The integer convolution: padded buffers, tiles (portable and VNNI
//! `vpdpbusd`) and the epilogues that dequantize, apply PReLU and
//! requantize.

use super::*;

/// Set the one-pixel border of a padded `(h + 2) x (w + 2) x c` buffer.
pub(super) fn fill_border(buf: &mut [u8], h: usize, w: usize, c: usize, v: u8) {
    let rl = (w + 2) * c;
    buf[..rl].fill(v);
    buf[(h + 1) * rl..(h + 2) * rl].fill(v);
    for r in 1..=h {
        buf[r * rl..r * rl + c].fill(v);
        buf[(r + 1) * rl - c..(r + 1) * rl].fill(v);
    }
}

/// Where a convolution's rows go: `dst(a, x, g0, tile)` receives the
/// `a`-th row's tile of pixels from `x`, channels from `g0`.
pub(super) type RowSink<'a> = dyn FnMut(usize, usize, usize, &[i32]) + 'a;

pub(super) enum Out<'a> {
    /// Padded channels-last bytes for the next layer, quantized as it reads them.
    Bytes(&'a mut [u8], QuantParams),
    /// Dense `h x w x ocp` dequantized output of the last layer.
    Floats(&'a mut [f32]),
}

/// One output row `r` of the direct convolution of `inp` (padded rows of
/// `w + 2` pixels `cs` bytes apart, rows `r..r + 3` read): `dst(0, x, g0,
/// tile)` for each tile, in [`for_each_tile`]'s order or, on AMX, 16-pixel
/// blocks of every group first. `win`: the AVX2 kernel's scratch
/// ([`avx2_window_len`]).
#[allow(clippy::too_many_arguments)]
pub(super) fn conv_row(
    kernel: Kernel,
    p: &PackedI8,
    inp: &[u8],
    cs: usize,
    w: usize,
    r: usize,
    win: &mut [i16],
    dst: &mut RowSink<'_>,
) {
    let rs = (w + 2) * cs;
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Amx && super::amx::eligible(p) {
        super::amx::row(p, inp, r, rs, cs, w, dst);
        return;
    }
    let mut tile = [0i32; NP_NARROW * GROUP];
    for_each_tile(p.ocp, w, |g0, gw, x, np| {
        run_tile(
            kernel,
            gw,
            np,
            inp,
            r * rs + x * cs,
            rs,
            cs,
            p,
            g0,
            &mut tile,
            win,
        );
        dst(0, x, g0, &tile[..np * gw]);
    });
}

pub(super) fn conv(
    kernel: Kernel,
    p: &PackedI8,
    inp: &[u8],
    cs: usize,
    h: usize,
    w: usize,
    out: Out<'_>,
) {
    let rs = (w + 2) * cs;
    debug_assert!(inp.len() >= (h + 2) * rs);
    let ocp = p.ocp;
    let win_len = if kernel == Kernel::Avx2 {
        avx2_window_len(p.cin4)
    } else {
        0
    };
    // Winograd: the AVX2 and AVX-VNNI kernels, where the layer was packed
    // for it.
    let wino = match kernel {
        Kernel::Avx2 | Kernel::AvxVnni => p.wino.as_deref(),
        Kernel::Portable | Kernel::Avx512 | Kernel::Amx => None,
    };
    // Rows per parallel chunk: Winograd's tile height, else one.
    let per = if wino.is_some() {
        super::winograd::M
    } else {
        1
    };
    // Output rows r0..r0 + n; `dst(a, ...)` gets row r0 + a's tiles.
    thread_local! {
        static WIN: std::cell::RefCell<Vec<i16>> = const { std::cell::RefCell::new(Vec::new()) };
    }
    let rows_with = |r0: usize, n: usize, win: &mut [i16], dst: &mut RowSink<'_>| {
        #[cfg(target_arch = "x86_64")]
        if let Some(u) = wino.filter(|_| n == per) {
            super::winograd::row_triple(kernel, p, u, inp, r0, rs, cs, w, win, dst);
            return;
        }
        for a in 0..n {
            conv_row(kernel, p, inp, cs, w, r0 + a, win, &mut |_, x, g0, t| {
                dst(a, x, g0, t)
            });
        }
    };
    let rows = |r0: usize, n: usize, dst: &mut RowSink<'_>| {
        crate::with_scratch(&WIN, win_len, |win| rows_with(r0, n, win, dst))
    };
    match out {
        Out::Bytes(o, qa) => {
            let rl = (w + 2) * ocp;
            o[rl..(h + 1) * rl]
                .par_chunks_mut(per * rl)
                .enumerate()
                .for_each(|(k, orows)| {
                    rows(k * per, orows.len() / rl, &mut |a, x, g0, tile| {
                        let orow = &mut orows[a * rl + ocp..(a + 1) * rl];
                        epilogue_bytes(kernel, p, qa, x, g0, tile, orow)
                    })
                });
        }
        Out::Floats(o) => {
            let rl = w * ocp;
            o[..h * rl]
                .par_chunks_mut(per * rl)
                .enumerate()
                .for_each(|(k, orows)| {
                    rows(k * per, orows.len() / rl, &mut |a, x, g0, tile| {
                        let orow = &mut orows[a * rl..(a + 1) * rl];
                        epilogue_floats(kernel, p, x, g0, tile, orow)
                    })
                });
        }
    }
}

/// Conv output -> (Q/DQ) -> PReLU -> Q (`qa`, the next layer's input) ->
/// byte, at `out[(x + px) * ocp + g0 + j]`.
pub(super) fn epilogue_bytes(
    kernel: Kernel,
    p: &PackedI8,
    qa: QuantParams,
    x: usize,
    g0: usize,
    tile: &[i32],
    out: &mut [u8],
) {
    match (kernel, p.q_out.is_some()) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: AVX-512F was detected when the block was made.
        (Kernel::Avx512 | Kernel::Amx, true) => unsafe {
            epilogue_bytes_avx512::<true>(p, qa, x, g0, tile, out)
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (Kernel::Avx512 | Kernel::Amx, false) => unsafe {
            epilogue_bytes_avx512::<false>(p, qa, x, g0, tile, out)
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: AVX2 was detected when the block was made.
        (Kernel::Avx2 | Kernel::AvxVnni, true) => unsafe {
            epilogue_bytes_avx2::<true>(p, qa, x, g0, tile, out)
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (Kernel::Avx2 | Kernel::AvxVnni, false) => unsafe {
            epilogue_bytes_avx2::<false>(p, qa, x, g0, tile, out)
        },
        _ => epilogue_bytes_impl(p, qa, x, g0, tile, out),
    }
}

/// The AVX-512 epilogues' common start, 16 channels: the sums less the
/// zero-point correction, times the scale, plus the bias (multiply then
/// add, no fusion); with `QO` the output's Q/DQ by `(1 / scale, zero
/// point, scale)` of `q_out`. The portable epilogue's operations.
///
/// # Safety
/// AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn dequantized_avx512<const QO: bool>(
    acc: std::arch::x86_64::__m512i,
    corr: std::arch::x86_64::__m512i,
    scale: std::arch::x86_64::__m512,
    bias: std::arch::x86_64::__m512,
    (io, zo, so): (
        std::arch::x86_64::__m512,
        std::arch::x86_64::__m512,
        std::arch::x86_64::__m512,
    ),
) -> std::arch::x86_64::__m512 {
    use std::arch::x86_64::*;
    let v = _mm512_cvtepi32_ps(_mm512_sub_epi32(acc, corr));
    let v = _mm512_add_ps(_mm512_mul_ps(v, scale), bias);
    if !QO {
        return v;
    }
    let q = _mm512_roundscale_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(
        _mm512_mul_ps(v, io),
    );
    let q = _mm512_min_ps(
        _mm512_max_ps(_mm512_add_ps(q, zo), _mm512_set1_ps(-128.0)),
        _mm512_set1_ps(127.0),
    );
    _mm512_mul_ps(_mm512_sub_ps(q, zo), so)
}

/// The same arithmetic, 16 channels at a time, operation for operation
/// (multiply then add, no fusion; multiplication by the scale's reciprocal),
/// so that it gives the portable epilogue's bits. `QO`: the convolution's
/// output is quantized (`p.q_out` is `Some`).
///
/// # Safety
/// AVX-512F and BW; `tile` and `out` hold the tile's pixels for the channel
/// group `g0`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw")]
pub(super) unsafe fn epilogue_bytes_avx512<const QO: bool>(
    p: &PackedI8,
    qa: QuantParams,
    x: usize,
    g0: usize,
    tile: &[i32],
    out: &mut [u8],
) {
    // SAFETY: AVX-512F/BW per the contract; the assert below bounds every
    // tile pixel's group in `tile` and `out`, and the per-channel vectors
    // (`corr`, `scale`, `bias`) hold all `ocp` channels, 16-lane groups from
    // `g0`.
    unsafe {
        use std::arch::x86_64::*;
        let gw = group_width(p.ocp, g0);
        // (unused without QO)
        let qo = p.q_out.unwrap_or(qa);
        let (so, zo) = (
            _mm512_set1_ps(qo.scale),
            _mm512_set1_ps(qo.zero_point as f32),
        );
        let (io, ia) = (
            _mm512_set1_ps(1.0 / qo.scale),
            _mm512_set1_ps(1.0 / qa.scale),
        );
        let zero = _mm512_setzero_ps();
        let zb = _mm512_set1_epi32(qa.zero_point as i32 + 128);
        let big = _mm512_set1_ps(1.0e9);
        assert!(tile.len().is_multiple_of(gw) && (x + tile.len() / gw) * p.ocp <= out.len());
        // 16 channels at a time, their constants held over the tile's
        // pixels (the same operations per value as pixel by pixel)
        for jv in (0..gw).step_by(L) {
            let c = g0 + jv;
            let corr = _mm512_loadu_si512(p.corr.as_ptr().add(c) as *const __m512i);
            let scale = _mm512_loadu_ps(p.scale.as_ptr().add(c));
            let bias = _mm512_loadu_ps(p.bias.as_ptr().add(c));
            let slope = _mm512_loadu_ps(p.slope.as_ptr().add(c));
            for (px, t) in tile.chunks_exact(gw).enumerate() {
                let o = out.as_mut_ptr().add((x + px) * p.ocp + c);
                let acc = _mm512_loadu_si512(t.as_ptr().add(jv) as *const __m512i);
                let v = dequantized_avx512::<QO>(acc, corr, scale, bias, (io, zo, so));
                // PReLU
                let neg = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(v, zero);
                let v = _mm512_mask_mul_ps(v, neg, v, slope);
                // Q of the activation, stored as q + 128: rounded to
                // nearest even by the conversion (MXCSR's default, as
                // `roundscale` rounds), the zero point and 128 added as
                // integers, clamped to 0..=255 by `max` and the unsigned
                // saturating narrowing: the float clamp's bytes for every
                // finite value (`big` keeps the conversion in range)
                let q = _mm512_min_ps(_mm512_mul_ps(v, ia), big);
                let b = _mm512_add_epi32(_mm512_cvtps_epi32(q), zb);
                let b = _mm512_max_epi32(b, _mm512_setzero_si512());
                _mm_storeu_si128(o as *mut __m128i, _mm512_cvtusepi32_epi8(b));
            }
        }
    }
}

/// [`epilogue_bytes_avx512`] on 8 lanes: the same operations in the same
/// order, so the portable epilogue's bits.
///
/// # Safety
/// AVX2; `tile` and `out` hold the tile's pixels for the channel group `g0`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub(super) unsafe fn epilogue_bytes_avx2<const QO: bool>(
    p: &PackedI8,
    qa: QuantParams,
    x: usize,
    g0: usize,
    tile: &[i32],
    out: &mut [u8],
) {
    // SAFETY: AVX2 per the contract; the assert below bounds every tile
    // pixel's group in `tile` and `out`, and the per-channel vectors (`corr`,
    // `scale`, `bias`, `slope`) hold all `ocp` channels, 8-lane steps from
    // `g0` inside the group (a multiple of 16 wide).
    unsafe {
        use std::arch::x86_64::*;
        const NEAREST: i32 = _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC;
        let gw = group_width(p.ocp, g0);
        // (unused without QO)
        let qo = p.q_out.unwrap_or(qa);
        let (so, zo) = (
            _mm256_set1_ps(qo.scale),
            _mm256_set1_ps(qo.zero_point as f32),
        );
        let za = _mm256_set1_ps(qa.zero_point as f32);
        let (io, ia) = (
            _mm256_set1_ps(1.0 / qo.scale),
            _mm256_set1_ps(1.0 / qa.scale),
        );
        let (lo, hi, zero) = (
            _mm256_set1_ps(-128.0),
            _mm256_set1_ps(127.0),
            _mm256_setzero_ps(),
        );
        let off = _mm256_set1_epi32(128);
        assert!(tile.len().is_multiple_of(gw) && (x + tile.len() / gw) * p.ocp <= out.len());
        for (px, t) in tile.chunks_exact(gw).enumerate() {
            let o = out[(x + px) * p.ocp + g0..].as_mut_ptr();
            for jv in (0..gw).step_by(8) {
                let c = g0 + jv;
                let acc = dbt_isa::ymm::loadu_si256(t.as_ptr().add(jv) as *const __m256i);
                let corr = dbt_isa::ymm::loadu_si256(p.corr.as_ptr().add(c) as *const __m256i);
                let v = _mm256_cvtepi32_ps(_mm256_sub_epi32(acc, corr));
                let v = _mm256_mul_ps(v, dbt_isa::ymm::loadu_ps(p.scale.as_ptr().add(c)));
                let mut v = _mm256_add_ps(v, dbt_isa::ymm::loadu_ps(p.bias.as_ptr().add(c)));
                if QO {
                    // Q/DQ of the convolution's output
                    let q = _mm256_round_ps::<NEAREST>(_mm256_mul_ps(v, io));
                    let q = _mm256_min_ps(_mm256_max_ps(_mm256_add_ps(q, zo), lo), hi);
                    v = _mm256_mul_ps(_mm256_sub_ps(q, zo), so);
                }
                // PReLU
                let neg = _mm256_cmp_ps::<_CMP_LT_OQ>(v, zero);
                let scaled = _mm256_mul_ps(v, dbt_isa::ymm::loadu_ps(p.slope.as_ptr().add(c)));
                let v = _mm256_blendv_ps(v, scaled, neg);
                // Q of the activation, stored as q + 128
                let q = _mm256_round_ps::<NEAREST>(_mm256_mul_ps(v, ia));
                let q = _mm256_min_ps(_mm256_max_ps(_mm256_add_ps(q, za), lo), hi);
                let b = _mm256_add_epi32(_mm256_cvtps_epi32(q), off);
                let w16 =
                    _mm_packus_epi32(_mm256_castsi256_si128(b), _mm256_extracti128_si256::<1>(b));
                _mm_storel_epi64(o.add(jv) as *mut __m128i, _mm_packus_epi16(w16, w16));
            }
        }
    }
}

#[inline(always)]
pub(super) fn epilogue_bytes_impl(
    p: &PackedI8,
    qa: QuantParams,
    x: usize,
    g0: usize,
    tile: &[i32],
    out: &mut [u8],
) {
    let gw = group_width(p.ocp, g0);
    let qo = p.q_out.map(|q| (q, 1.0 / q.scale));
    let ia = 1.0 / qa.scale;
    let (corr, scale) = (&p.corr[g0..g0 + gw], &p.scale[g0..g0 + gw]);
    let (bias, slope) = (&p.bias[g0..g0 + gw], &p.slope[g0..g0 + gw]);
    for (px, t) in tile.chunks_exact(gw).enumerate() {
        let o = &mut out[(x + px) * p.ocp + g0..(x + px) * p.ocp + g0 + gw];
        for j in 0..gw {
            let v = (t[j] - corr[j]) as f32 * scale[j] + bias[j];
            let v = qo.map_or(v, |(q, io)| q.fake_rcp(v, io));
            let v = if v < 0.0 { v * slope[j] } else { v };
            o[j] = to_byte(qa.quantize_rcp(v, ia));
        }
    }
}

/// Conv output -> (Q/DQ), at `out[(x + px) * ocp + g0 + j]`.
pub(super) fn epilogue_floats(
    kernel: Kernel,
    p: &PackedI8,
    x: usize,
    g0: usize,
    tile: &[i32],
    out: &mut [f32],
) {
    match kernel {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: AVX-512F was detected when the block was made.
        Kernel::Avx512 | Kernel::Amx => unsafe { epilogue_floats_avx512(p, x, g0, tile, out) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: AVX2 was detected when the block was made.
        Kernel::Avx2 | Kernel::AvxVnni => unsafe { epilogue_floats_avx2(p, x, g0, tile, out) },
        _ => epilogue_floats_impl(p, x, g0, tile, out),
    }
}

/// # Safety
/// AVX2 (the body is safe code, compiled with it enabled).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub(super) unsafe fn epilogue_floats_avx2(
    p: &PackedI8,
    x: usize,
    g0: usize,
    tile: &[i32],
    out: &mut [f32],
) {
    epilogue_floats_impl(p, x, g0, tile, out)
}

/// [`epilogue_floats_impl`] 16 channels at a time, their constants held
/// over the tile's pixels: the same operations per value (multiply then
/// add, no fusion; the output's Q/DQ with the scale's reciprocal), so the
/// portable epilogue's bits.
///
/// # Safety
/// AVX-512F and BW; `tile` and `out` hold the tile's pixels for the channel
/// group `g0`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw")]
pub(super) unsafe fn epilogue_floats_avx512(
    p: &PackedI8,
    x: usize,
    g0: usize,
    tile: &[i32],
    out: &mut [f32],
) {
    match p.q_out {
        // SAFETY: the contract.
        Some(q) => unsafe { epilogue_floats_avx512_q::<true>(p, q, x, g0, tile, out) },
        // SAFETY: as above (the parameters unused).
        None => unsafe {
            epilogue_floats_avx512_q::<false>(
                p,
                QuantParams {
                    scale: 1.0,
                    zero_point: 0,
                },
                x,
                g0,
                tile,
                out,
            )
        },
    }
}

/// [`epilogue_floats_avx512`] with the output's Q/DQ by `qo` (`QO`) or
/// without.
///
/// # Safety
/// As [`epilogue_floats_avx512`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw")]
unsafe fn epilogue_floats_avx512_q<const QO: bool>(
    p: &PackedI8,
    qo: QuantParams,
    x: usize,
    g0: usize,
    tile: &[i32],
    out: &mut [f32],
) {
    // SAFETY: AVX-512F/BW per the contract; the assert bounds every tile
    // pixel's group in `tile` and `out`, and the per-channel vectors hold
    // all `ocp` channels, 16-lane groups from `g0`.
    unsafe {
        use std::arch::x86_64::*;
        let gw = group_width(p.ocp, g0);
        let (so, zo, io) = (
            _mm512_set1_ps(qo.scale),
            _mm512_set1_ps(qo.zero_point as f32),
            _mm512_set1_ps(1.0 / qo.scale),
        );
        assert!(tile.len().is_multiple_of(gw) && (x + tile.len() / gw) * p.ocp <= out.len());
        for jv in (0..gw).step_by(L) {
            let c = g0 + jv;
            let corr = _mm512_loadu_si512(p.corr.as_ptr().add(c) as *const __m512i);
            let scale = _mm512_loadu_ps(p.scale.as_ptr().add(c));
            let bias = _mm512_loadu_ps(p.bias.as_ptr().add(c));
            for (px, t) in tile.chunks_exact(gw).enumerate() {
                let acc = _mm512_loadu_si512(t.as_ptr().add(jv) as *const __m512i);
                let v = dequantized_avx512::<QO>(acc, corr, scale, bias, (io, zo, so));
                _mm512_storeu_ps(out.as_mut_ptr().add((x + px) * p.ocp + c), v);
            }
        }
    }
}

#[inline(always)]
pub(super) fn epilogue_floats_impl(
    p: &PackedI8,
    x: usize,
    g0: usize,
    tile: &[i32],
    out: &mut [f32],
) {
    let gw = group_width(p.ocp, g0);
    let qo = p.q_out.map(|q| (q, 1.0 / q.scale));
    let (corr, scale, bias) = (
        &p.corr[g0..g0 + gw],
        &p.scale[g0..g0 + gw],
        &p.bias[g0..g0 + gw],
    );
    for (px, t) in tile.chunks_exact(gw).enumerate() {
        let o = &mut out[(x + px) * p.ocp + g0..(x + px) * p.ocp + g0 + gw];
        for j in 0..gw {
            let v = (t[j] - corr[j]) as f32 * scale[j] + bias[j];
            o[j] = qo.map_or(v, |(q, io)| q.fake_rcp(v, io));
        }
    }
}

#[allow(clippy::too_many_arguments)]
#[inline]
pub(super) fn run_tile(
    kernel: Kernel,
    gw: usize,
    np: usize,
    inp: &[u8],
    base: usize,
    rs: usize,
    cs: usize,
    p: &PackedI8,
    g0: usize,
    tile: &mut [i32],
    win: &mut [i16],
) {
    assert!(base + 2 * rs + (np + 1) * cs + p.cin4 <= inp.len());
    assert!(g0 + gw <= p.ocp && p.w.len() == 9 * p.cin4 * p.ocp);
    assert!(np * gw <= tile.len() && (1..=NP_NARROW).contains(&np) && p.cin4 <= cs);
    let g4 = p.cin4 / 4;
    match kernel {
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx512 | Kernel::Amx => {
            let (i, wp, t) = (
                inp[base..].as_ptr(),
                p.w[g0 * 4..].as_ptr(),
                tile.as_mut_ptr(),
            );
            // SAFETY: AVX-512 F/BW/VNNI were detected when the block was made
            // (Int8Block::new refuses otherwise); the asserts above bound
            // every address the kernel touches.
            unsafe {
                if gw == GROUP {
                    dispatch_np!(tile_vnni, 4, np, i, rs, cs, g4, wp, p.ocp, t)
                } else {
                    dispatch_np!(tile_vnni, 1, np, i, rs, cs, g4, wp, p.ocp, t)
                }
            }
        }
        #[cfg(target_arch = "x86_64")]
        Kernel::AvxVnni => {
            let (i, wp, t) = (
                inp[base..].as_ptr(),
                p.w[g0 * 4..].as_ptr(),
                tile.as_mut_ptr(),
            );
            assert!(
                (wp as usize).is_multiple_of(32),
                "packed weights not aligned"
            );
            // SAFETY: AVX2 and AVX-VNNI were detected when the block was made
            // (Int8Block::new refuses otherwise); the asserts above bound
            // every address the kernel touches and align the weights.
            unsafe { tile_avxvnni(gw / L, np, i, rs, cs, g4, wp, p.ocp, t) }
        }
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx2 => {
            assert!(p.w16.len() == p.w.len());
            let (i, wp, t) = (
                inp[base..].as_ptr(),
                p.w16[g0 * 2..].as_ptr(),
                tile.as_mut_ptr(),
            );
            assert!(
                (wp as usize).is_multiple_of(32),
                "packed weights not aligned"
            );
            // SAFETY: AVX2 was detected when the block was made
            // (Int8Block::new refuses otherwise); the asserts above bound
            // every address the kernel touches and align the weights (w16
            // holds w's values, as many, pair-packed: `[tap][cin4 / 2][ocp][2]`);
            // the window's length is checked by the kernel.
            unsafe { tile_avx2(gw / L, np, i, rs, cs, p.cin4, wp, p.ocp, t, win) }
        }
        _ => {
            if gw == GROUP {
                dispatch_np!(
                    tile_portable,
                    4,
                    np,
                    inp,
                    base,
                    rs,
                    cs,
                    g4,
                    &p.w,
                    g0,
                    p.ocp,
                    tile
                )
            } else {
                dispatch_np!(
                    tile_portable,
                    1,
                    np,
                    inp,
                    base,
                    rs,
                    cs,
                    g4,
                    &p.w,
                    g0,
                    p.ocp,
                    tile
                )
            }
        }
    }
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn tile_portable<const NB: usize, const NP: usize>(
    inp: &[u8],
    base: usize,
    rs: usize,
    cs: usize,
    g4: usize,
    w: &[i8],
    g0: usize,
    ocp: usize,
    tile: &mut [i32],
) {
    let mut acc = [[[0i32; L]; NB]; NP];
    for t in 0..9 {
        let ib = base + (t / 3) * rs + (t % 3) * cs;
        for g in 0..g4 {
            let wr = &w[((t * g4 + g) * ocp + g0) * 4..];
            for (p, a) in acc.iter_mut().enumerate() {
                let u = &inp[ib + p * cs + 4 * g..ib + p * cs + 4 * g + 4];
                for (j, aj) in a.iter_mut().enumerate() {
                    for (k, ak) in aj.iter_mut().enumerate() {
                        let wv = &wr[(j * L + k) * 4..(j * L + k) * 4 + 4];
                        *ak += (0..4).map(|e| u[e] as i32 * wv[e] as i32).sum::<i32>();
                    }
                }
            }
        }
    }
    for (p, a) in acc.iter().enumerate() {
        for (j, aj) in a.iter().enumerate() {
            tile[(p * NB + j) * L..(p * NB + j + 1) * L].copy_from_slice(aj);
        }
    }
}

/// # Safety
/// AVX-512 F, BW and VNNI; `inp` valid for every tap of the tile, `w` for
/// `9 * g4 * ocp * 4` bytes from the group's first lane, `out` for
/// `NP * NB * 16` i32.
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx512f,avx512bw,avx512vnni")]
pub(super) unsafe fn tile_vnni<const NB: usize, const NP: usize>(
    inp: *const u8,
    rs: usize,
    cs: usize,
    g4: usize,
    w: *const i8,
    ocp: usize,
    out: *mut i32,
) {
    // SAFETY: AVX-512 F/BW/VNNI and the pointer ranges per the contract (`#
    // Safety` above).
    unsafe {
        use std::arch::x86_64::*;
        let mut acc = [[_mm512_setzero_si512(); NB]; NP];
        for t in 0..9 {
            let ib = inp.add((t / 3) * rs + (t % 3) * cs);
            let wb = w.add(t * g4 * ocp * 4);
            for g in 0..g4 {
                let wr = wb.add(g * ocp * 4);
                let mut wv = [_mm512_setzero_si512(); NB];
                for (j, v) in wv.iter_mut().enumerate() {
                    *v = _mm512_loadu_si512(wr.add(j * 4 * L) as *const __m512i);
                }
                for (p, a) in acc.iter_mut().enumerate() {
                    let four = (ib.add(p * cs + 4 * g) as *const i32).read_unaligned();
                    let b = _mm512_set1_epi32(four);
                    for (j, aj) in a.iter_mut().enumerate() {
                        *aj = _mm512_dpbusd_epi32(*aj, b, wv[j]);
                    }
                }
            }
        }
        for (p, a) in acc.iter().enumerate() {
            for (j, aj) in a.iter().enumerate() {
                _mm512_storeu_si512(out.add((p * NB + j) * L) as *mut __m512i, *aj);
            }
        }
    }
}

/// Pixels of one AVX2 or AVX-VNNI pass: 16 output channels (two 8-lane
/// accumulators) x up to 5 pixels, 10 accumulators of the 16 registers.
const NP_PASS: usize = 5;

/// The i16 window an AVX2 tile reads: `3 x (np + 2)` pixels of `cin4`
/// values, the tile's input bytes zero-extended once per tile (a few
/// percent of its multiply-adds) rather than once per pass.
pub(super) fn avx2_window_len(cin4: usize) -> usize {
    3 * (NP_NARROW + 2) * cin4
}

/// AVX2: the VNNI tile computed exactly with `vpmaddwd`. The tile's input
/// window is zero-extended to i16 once ([`avx2_window_len`]); each pass
/// keeps 16 output channels x up to 5 pixels in 10 accumulators: per pair of
/// input channels it broadcasts the pair (one 32-bit load per pixel) and
/// multiplies it with two vectors of 8 channels x the pair's i16 weights
/// (`PackedI8::w16`), each `vpmaddwd` giving 8 channels' sums of two exact
/// products. Written where the VNNI kernel writes
/// (`out[(p * nb + j) * 16 + k]`).
///
/// # Safety
/// AVX2; `inp` valid for every tap of the tile (`2 * rs + (np + 1) * cs +
/// cin4` bytes), `w` for `9 * (cin4 / 2) * ocp * 2` i16 from the group's
/// first lane and aligned to 32 bytes (`ocp` a multiple of 16), `out` for `np * nb * 16` i32; `np` in 1..=10, `nb` in 1..=4,
/// `cin4` a multiple of 4 no larger than `cs`, `win` at least
/// [`avx2_window_len`]`(cin4)` long.
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx2")]
pub(super) unsafe fn tile_avx2(
    nb: usize,
    np: usize,
    inp: *const u8,
    rs: usize,
    cs: usize,
    cin4: usize,
    w: *const i16,
    ocp: usize,
    out: *mut i32,
    win: &mut [i16],
) {
    use std::arch::x86_64::*;
    let (wcs, wrs) = (cin4, (np + 2) * cin4);
    assert!(win.len() >= 3 * wrs && cin4.is_multiple_of(4));
    let wp = win.as_mut_ptr();
    for ry in 0..3 {
        for px in 0..np + 2 {
            // SAFETY: pixel (ry, px) of the tile's taps is inside `inp` per the
            // contract (`cin4 <= cs` bytes each); its i16 copy is inside `win`
            // (asserted above).
            unsafe {
                let src = inp.add(ry * rs + px * cs);
                let dst = wp.add(ry * wrs + px * wcs);
                let mut c = 0;
                while c + 16 <= cin4 {
                    let b = _mm_loadu_si128(src.add(c) as *const __m128i);
                    dbt_isa::ymm::storeu_si256(dst.add(c) as *mut __m256i, _mm256_cvtepu8_epi16(b));
                    c += 16;
                }
                while c < cin4 {
                    let four = (src.add(c) as *const i32).read_unaligned();
                    let v = _mm_cvtepu8_epi16(_mm_cvtsi32_si128(four));
                    _mm_storel_epi64(dst.add(c) as *mut __m128i, v);
                    c += 4;
                }
            }
        }
    }
    for_each_pass(np, nb, |p0, n, q| {
        // SAFETY: the pass reads pixels p0..p0 + n of the window and the
        // weights of channels 16q..16q + 16 of the group, and writes those
        // values of `out`: inside the contract's ranges.
        unsafe {
            let (i, wq, o) = (
                wp.add(p0 * wcs) as *const i16,
                w.add(q * L * 2),
                out.add(p0 * nb * L + q * L),
            );
            let k2 = cin4 / 2;
            match n {
                1 => pass_avx2::<1>(i, wrs, wcs, k2, wq, ocp, o, nb),
                2 => pass_avx2::<2>(i, wrs, wcs, k2, wq, ocp, o, nb),
                3 => pass_avx2::<3>(i, wrs, wcs, k2, wq, ocp, o, nb),
                4 => pass_avx2::<4>(i, wrs, wcs, k2, wq, ocp, o, nb),
                _ => pass_avx2::<5>(i, wrs, wcs, k2, wq, ocp, o, nb),
            }
        }
    });
}

/// The passes of an AVX2-sized tile of `np` pixels and `nb` 16-channel
/// blocks: `f(p0, n, q)` for each run of up to [`NP_PASS`] pixels from `p0`
/// and each block `q`.
#[inline(always)]
fn for_each_pass(np: usize, nb: usize, mut f: impl FnMut(usize, usize, usize)) {
    let mut p0 = 0;
    while p0 < np {
        let n = (np - p0).min(NP_PASS);
        for q in 0..nb {
            f(p0, n, q);
        }
        p0 += n;
    }
}

/// 16 output channels x `NP` pixels of [`tile_avx2`], stored at
/// `out[p * nb * 16 + k]`.
///
/// # Safety
/// AVX2; `win` valid for every tap of `NP` pixels (`k2` pairs of i16 each),
/// `w` for the group's pair-packed weights from the pass's first channel,
/// aligned to 32 bytes (`ocp` a multiple of 16),
/// `out` for `(NP - 1) * nb * 16 + 16` i32.
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx2")]
unsafe fn pass_avx2<const NP: usize>(
    win: *const i16,
    wrs: usize,
    wcs: usize,
    k2: usize,
    w: *const i16,
    ocp: usize,
    out: *mut i32,
    nb: usize,
) {
    // SAFETY: AVX2 and the pointer ranges per the contract.
    unsafe {
        use std::arch::x86_64::*;
        let mut a0 = [_mm256_setzero_si256(); NP];
        let mut a1 = [_mm256_setzero_si256(); NP];
        for t in 0..9 {
            let ib = win.add((t / 3) * wrs + (t % 3) * wcs);
            let wb = w.add(t * k2 * ocp * 2);
            for k in 0..k2 {
                let wr = wb.add(k * ocp * 2);
                // aligned: `PackedI8::w16` is, and every offset is a
                // multiple of 32 bytes
                let w0 = _mm256_load_si256(wr as *const __m256i);
                let w1 = _mm256_load_si256(wr.add(16) as *const __m256i);
                for p in 0..NP {
                    let pair = (ib.add(p * wcs + 2 * k) as *const i32).read_unaligned();
                    let b = _mm256_set1_epi32(pair);
                    a0[p] = _mm256_add_epi32(a0[p], _mm256_madd_epi16(b, w0));
                    a1[p] = _mm256_add_epi32(a1[p], _mm256_madd_epi16(b, w1));
                }
            }
        }
        for p in 0..NP {
            let o = out.add(p * nb * L);
            dbt_isa::ymm::storeu_si256(o as *mut __m256i, a0[p]);
            dbt_isa::ymm::storeu_si256(o.add(8) as *mut __m256i, a1[p]);
        }
    }
}

/// AVX-VNNI (the VEX-encoded `vpdpbusd` of CPUs with AVX2 and AVX-VNNI but
/// no AVX-512, e.g. Intel's Alder Lake and later client cores): the VNNI
/// tile on 8-lane vectors, on the same packed bytes, each pass 16 output
/// channels x up to 5 pixels (10 accumulators). Written where the VNNI
/// kernel writes.
///
/// # Safety
/// AVX2 and AVX-VNNI; `inp` valid for every tap of the tile, `w` for
/// `9 * g4 * ocp * 4` bytes from the group's first lane and aligned to 32
/// bytes (`ocp` a multiple of 16), `out` for
/// `np * nb * 16` i32; `np` in 1..=10, `nb` in 1..=4.
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx2,avxvnni")]
pub(super) unsafe fn tile_avxvnni(
    nb: usize,
    np: usize,
    inp: *const u8,
    rs: usize,
    cs: usize,
    g4: usize,
    w: *const i8,
    ocp: usize,
    out: *mut i32,
) {
    for_each_pass(np, nb, |p0, n, q| {
        // SAFETY: the pass reads pixels p0..p0 + n of the tile and the
        // weights of channels 16q..16q + 16 of the group, and writes those
        // values of `out`: inside the contract's ranges.
        unsafe {
            let (i, wq, o) = (
                inp.add(p0 * cs),
                w.add(q * L * 4),
                out.add(p0 * nb * L + q * L),
            );
            match n {
                1 => pass_avxvnni::<1>(i, rs, cs, g4, wq, ocp, o, nb),
                2 => pass_avxvnni::<2>(i, rs, cs, g4, wq, ocp, o, nb),
                3 => pass_avxvnni::<3>(i, rs, cs, g4, wq, ocp, o, nb),
                4 => pass_avxvnni::<4>(i, rs, cs, g4, wq, ocp, o, nb),
                _ => pass_avxvnni::<5>(i, rs, cs, g4, wq, ocp, o, nb),
            }
        }
    });
}

/// 16 output channels x `NP` pixels of [`tile_avxvnni`], stored at
/// `out[p * nb * 16 + k]`.
///
/// # Safety
/// AVX2 and AVX-VNNI; `inp` valid for every tap of `NP` pixels, `w` for the
/// group's weights from the pass's first channel, aligned to 32 bytes (`ocp`
/// a multiple of 16), `out` for
/// `(NP - 1) * nb * 16 + 16` i32.
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx2,avxvnni")]
unsafe fn pass_avxvnni<const NP: usize>(
    inp: *const u8,
    rs: usize,
    cs: usize,
    g4: usize,
    w: *const i8,
    ocp: usize,
    out: *mut i32,
    nb: usize,
) {
    // SAFETY: AVX2, AVX-VNNI and the pointer ranges per the contract.
    unsafe {
        use std::arch::x86_64::*;
        let mut a0 = [_mm256_setzero_si256(); NP];
        let mut a1 = [_mm256_setzero_si256(); NP];
        for t in 0..9 {
            let ib = inp.add((t / 3) * rs + (t % 3) * cs);
            let wb = w.add(t * g4 * ocp * 4);
            for g in 0..g4 {
                let wr = wb.add(g * ocp * 4);
                // aligned: `PackedI8::w` is, and every offset is a multiple
                // of 32 bytes
                let w0 = _mm256_load_si256(wr as *const __m256i);
                let w1 = _mm256_load_si256(wr.add(32) as *const __m256i);
                for p in 0..NP {
                    let four = (ib.add(p * cs + 4 * g) as *const i32).read_unaligned();
                    let b = _mm256_set1_epi32(four);
                    a0[p] = _mm256_dpbusd_avx_epi32(a0[p], b, w0);
                    a1[p] = _mm256_dpbusd_avx_epi32(a1[p], b, w1);
                }
            }
        }
        for p in 0..NP {
            let o = out.add(p * nb * L);
            dbt_isa::ymm::storeu_si256(o as *mut __m256i, a0[p]);
            dbt_isa::ymm::storeu_si256(o.add(8) as *mut __m256i, a1[p]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The AVX-512 epilogues give the portable ones' bytes and floats on
    /// sums far past any convolution's (both saturations of the byte, every
    /// rounding), with and without the output's Q/DQ, negative and
    /// positive zero points, 64- and 16-channel groups.
    #[test]
    fn avx512_epilogues_match_portable_past_every_sum() {
        if !dbt_isa::kernel_test_runs("int8 avx512 epilogue", &["avx512f", "avx512bw"]) {
            return;
        }
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let mut saturated = (false, false);
        for (out_ch, q_out, zp, scale) in [
            (64, None, -7, 0.5f32),
            (64, Some((0.7f32, 3i8)), 11, 1e-3),
            (16, None, 20, 37.0),
            (20, Some((0.01, -20)), -128, 1e-6),
        ] {
            let l = Int8Conv {
                in_ch: 8,
                out_ch,
                weight: (0..out_ch * 8 * 9).map(|_| next() as i8).collect(),
                weight_scale: (0..out_ch).map(|k| 0.5 + k as f32 * 0.1).collect(),
                bias: (0..out_ch).map(|k| k as f32 * 3.5 - 40.0).collect(),
                prelu: Some((0..out_ch).map(|k| 0.25 * k as f32 - 2.0).collect()),
                q_out: q_out.map(|(scale, zero_point)| QuantParams { scale, zero_point }),
                q_act: None,
            };
            let p = pack(
                &l,
                QuantParams {
                    scale,
                    zero_point: 5,
                },
                false,
            );
            let qa = QuantParams {
                scale: 0.37,
                zero_point: zp,
            };
            let g0 = 0;
            let gw = group_width(p.ocp, g0);
            let np = 24;
            // Sums far past any convolution's (at most 9 x 64 x 255 x 128,
            // under 2^25, in magnitude), short of the i32 overflow of
            // `sum - corr`.
            const BIG: i32 = 1 << 28;
            let tile: Vec<i32> = (0..np * gw)
                .map(|k| match k % 7 {
                    0 => BIG - (next() % 5) as i32,
                    1 => -BIG + (next() % 5) as i32,
                    2 => (next() % 600) as i32 - 300,
                    _ => (next() as i32 >> 3) >> (next() % 28),
                })
                .collect();
            let (mut want, mut got) = (vec![0u8; np * p.ocp], vec![0u8; np * p.ocp]);
            epilogue_bytes_impl(&p, qa, 0, g0, &tile, &mut want);
            // SAFETY: AVX-512F/BW present (checked above).
            unsafe {
                if p.q_out.is_some() {
                    epilogue_bytes_avx512::<true>(&p, qa, 0, g0, &tile, &mut got)
                } else {
                    epilogue_bytes_avx512::<false>(&p, qa, 0, g0, &tile, &mut got)
                }
            }
            assert_eq!(
                got, want,
                "bytes, {out_ch} channels, {q_out:?}, zero point {zp}"
            );
            saturated.0 |= want.contains(&0);
            saturated.1 |= want.contains(&255);
            let (mut want, mut got) = (vec![0f32; np * p.ocp], vec![0f32; np * p.ocp]);
            epilogue_floats_impl(&p, 0, g0, &tile, &mut want);
            // SAFETY: as above.
            unsafe { epilogue_floats_avx512(&p, 0, g0, &tile, &mut got) };
            let same = got
                .iter()
                .zip(&want)
                .all(|(a, b)| a.to_bits() == b.to_bits());
            assert!(same, "floats, {out_ch} channels, {q_out:?}");
        }
        assert_eq!(
            saturated,
            (true, true),
            "both of the byte's saturations reached"
        );
    }
}
