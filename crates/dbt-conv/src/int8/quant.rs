//! Quantisation: scale and zero point, the bytes activations are stored
//! as, and the chunked quantization and residual updates (portable and
//! AVX-512).

use super::*;

/// Scale and zero point of an int8 tensor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QuantParams {
    /// Positive, finite.
    pub scale: f32,
    /// The int8 value of real 0.
    pub zero_point: i8,
}

impl QuantParams {
    /// ONNX QuantizeLinear to int8.
    #[inline]
    pub fn quantize(self, x: f32) -> i8 {
        ((x / self.scale).round_ties_even() + self.zero_point as f32).clamp(-128.0, 127.0) as i8
    }

    /// ONNX DequantizeLinear.
    #[inline]
    pub fn dequantize(self, q: i8) -> f32 {
        (q as i32 - self.zero_point as i32) as f32 * self.scale
    }

    /// `DQ(Q(x))`.
    #[inline]
    pub fn fake(self, x: f32) -> f32 {
        self.dequantize(self.quantize(x))
    }

    /// [`QuantParams::quantize`] multiplying by `inv = 1 / scale` instead
    /// of dividing (as tract's and onnxruntime's kernels do; a division per
    /// value cost the block a quarter of its time): a value within an ulp of
    /// a rounding tie may round the other way than the ONNX definition.
    #[inline(always)]
    pub fn quantize_rcp(self, x: f32, inv: f32) -> i8 {
        ((x * inv).round_ties_even() + self.zero_point as f32).clamp(-128.0, 127.0) as i8
    }

    /// `DQ(Q(x))` with [`QuantParams::quantize_rcp`].
    #[inline(always)]
    pub fn fake_rcp(self, x: f32, inv: f32) -> f32 {
        self.dequantize(self.quantize_rcp(x, inv))
    }

    pub(super) fn check(self, name: &str) -> Result<(), ConvError> {
        if self.scale.is_finite() && self.scale > 0.0 {
            Ok(())
        } else {
            Err(ConvError::Weights(format!(
                "{name}: scale {} is not a positive number",
                self.scale
            )))
        }
    }
}

#[inline]
pub(super) fn to_byte(q: i8) -> u8 {
    (q as i16 + 128) as u8
}

pub(super) fn pad_byte(q: QuantParams) -> u8 {
    to_byte(q.zero_point)
}

/// Pixels per chunk of the input quantization and the residual update (a
/// stack buffer: nothing is allocated in a run).
pub(super) const CHUNK: usize = 64;

/// `dst[x] = byte(Q_c(DQ(Q_q(src[x])) * k))`, without `DQ(Q_q(.))` where
/// `q` is `None` (`* k` is exact for `k = 1`).
pub(super) fn quantize_chunk(
    kernel: Kernel,
    src: &[f32],
    q: Option<QuantParams>,
    k: f32,
    qc: QuantParams,
    dst: &mut [u8],
) {
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if matches!(kernel, Kernel::Avx512 | Kernel::Amx) {
        // SAFETY: AVX-512F was detected when the block was made.
        done = unsafe { quantize_chunk_avx512(src, q, k, qc, dst) };
    }
    let _ = kernel;
    for (d, v) in dst[done..src.len()].iter_mut().zip(&src[done..]) {
        let v = q.map_or(*v, |q| q.fake(*v));
        *d = to_byte(qc.quantize(v * k));
    }
}

/// The residual on one state row of `channel`: `row[x]` updated with
/// channel `channel` of `out`'s pixel `x` (`out`: that output row's pixels,
/// `stride` channels apart), in [`CHUNK`]-pixel pieces ([`residual_chunk`]).
pub(super) fn residual_row(
    kernel: Kernel,
    row: &mut [f32],
    out: &[f32],
    (stride, channel): (usize, usize),
    qs: Option<QuantParams>,
    qr: Option<QuantParams>,
) {
    let mut add = [0.0f32; CHUNK];
    for (c, part) in row.chunks_mut(CHUNK).enumerate() {
        for (e, a) in add[..part.len()].iter_mut().enumerate() {
            *a = out[(c * CHUNK + e) * stride + channel];
        }
        residual_chunk(kernel, part, &add, qs, qr);
    }
}

/// `row[x] = Q_r/DQ(Q_s/DQ(row[x]) + add[x])`, or `row[x] + add[x]` without
/// `qr` (the float residual).
pub(super) fn residual_chunk(
    kernel: Kernel,
    row: &mut [f32],
    add: &[f32],
    qs: Option<QuantParams>,
    qr: Option<QuantParams>,
) {
    // (check(): a quantized residual has a quantized state)
    let (Some(qr), Some(qs)) = (qr, qs) else {
        for (v, a) in row.iter_mut().zip(add) {
            *v += a;
        }
        return;
    };
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if matches!(kernel, Kernel::Avx512 | Kernel::Amx) {
        // SAFETY: AVX-512F was detected when the block was made.
        done = unsafe { residual_chunk_avx512(row, add, qs, qr) };
    }
    let _ = kernel;
    for (v, a) in row[done..].iter_mut().zip(&add[done..]) {
        *v = qr.fake(qs.fake(*v) + a);
    }
}

/// `round_half_even(v / s) + z` clamped to the int8 range, as floats.
///
/// # Safety
/// The caller runs with AVX-512F enabled.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(super) unsafe fn q16(
    v: std::arch::x86_64::__m512,
    q: QuantParams,
) -> std::arch::x86_64::__m512 {
    // SAFETY: AVX-512F per the contract; registers only.
    unsafe {
        use std::arch::x86_64::*;
        let r = _mm512_roundscale_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(
            _mm512_div_ps(v, _mm512_set1_ps(q.scale)),
        );
        let r = _mm512_add_ps(r, _mm512_set1_ps(q.zero_point as f32));
        _mm512_min_ps(
            _mm512_max_ps(r, _mm512_set1_ps(-128.0)),
            _mm512_set1_ps(127.0),
        )
    }
}

/// `DQ(Q(v))`, 16 lanes.
///
/// # Safety
/// The caller runs with AVX-512F enabled.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(super) unsafe fn fake16(
    v: std::arch::x86_64::__m512,
    q: QuantParams,
) -> std::arch::x86_64::__m512 {
    // SAFETY: AVX-512F per the contract; registers only.
    unsafe {
        use std::arch::x86_64::*;
        _mm512_mul_ps(
            _mm512_sub_ps(q16(v, q), _mm512_set1_ps(q.zero_point as f32)),
            _mm512_set1_ps(q.scale),
        )
    }
}

/// # Safety
/// AVX-512F and BW.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw")]
pub(super) unsafe fn quantize_chunk_avx512(
    src: &[f32],
    q: Option<QuantParams>,
    k: f32,
    qc: QuantParams,
    dst: &mut [u8],
) -> usize {
    // SAFETY: AVX-512F/BW per the contract; whole 16-lane chunks only, inside
    // `src` and `dst`.
    unsafe {
        use std::arch::x86_64::*;
        let n = src.len().min(dst.len()) / L * L;
        let kv = _mm512_set1_ps(k);
        for x in (0..n).step_by(L) {
            let v = _mm512_loadu_ps(src.as_ptr().add(x));
            let v = match q {
                Some(q) => fake16(v, q),
                None => v,
            };
            let v = _mm512_mul_ps(v, kv);
            let b = _mm512_add_epi32(_mm512_cvtps_epi32(q16(v, qc)), _mm512_set1_epi32(128));
            _mm_storeu_si128(
                dst.as_mut_ptr().add(x) as *mut __m128i,
                _mm512_cvtepi32_epi8(b),
            );
        }
        n
    }
}

/// # Safety
/// AVX-512F and BW.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw")]
pub(super) unsafe fn residual_chunk_avx512(
    row: &mut [f32],
    add: &[f32],
    qs: QuantParams,
    qr: QuantParams,
) -> usize {
    // SAFETY: AVX-512F/BW per the contract; whole 16-lane chunks only, inside
    // `row` and `add`.
    unsafe {
        use std::arch::x86_64::*;
        let n = row.len().min(add.len()) / L * L;
        for x in (0..n).step_by(L) {
            let s = fake16(_mm512_loadu_ps(row.as_ptr().add(x)), qs);
            let v = _mm512_add_ps(s, _mm512_loadu_ps(add.as_ptr().add(x)));
            _mm512_storeu_ps(row.as_mut_ptr().add(x), fake16(v, qr));
        }
        n
    }
}
