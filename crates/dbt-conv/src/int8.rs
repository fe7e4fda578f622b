//! int8 blocks: the static QDQ graph that `training/dbtor/export.py` writes
//! (onnxruntime `quantize_static`, QDQ format, int8 activations with a zero
//! point, int8 weights per output channel with zero point 0, int32 biases)
//! run in integers.
//!
//! The graph's float semantics, which this module reproduces, every
//! quantization but those of the convolutions' inputs optional
//! (`Option` in [`Int8BlockWeights`] and [`Int8Conv`]):
//! ```text
//! s' = DQ(Q(state)), a' = DQ(Q(aux))           (or state, aux)
//! x1 = DQ(Q(cat(s', a') * k))                  (k: per-channel prescale, or 1)
//! x2 = DQ(Q(PReLU(DQ(Q(conv1(x1))))))           (or PReLU(conv1(x1)))
//! x3 = DQ(Q(PReLU(DQ(Q(conv2(x2))))))
//! c3 = DQ(Q(conv3(x3)))                         (or conv3(x3))
//! out = DQ(Q(s' + c3))        (residual quantized: onnxruntime's graph)
//! out = state + c3            (float residual)
//! ```
//! export.py writes three forms: onnxruntime's plain graph (everything
//! quantized), the float residual, and its default "conv-inputs", where
//! only x1, x2 and x3 are quantized (the convolutions still multiply int8
//! by int8 into i32; what they give is dequantized and stays float through
//! the PReLU and the residual sum), with the prescale k spreading every
//! concatenated channel over the int8 range. The losses against fp32 of
//! the three forms on dbtor-x4t are in models/README.md.
//! `Q(x) = clamp(round_half_even(x / scale) + zp, -128, 127)` and
//! `DQ(q) = (q - zp) * scale`. A convolution of quantized input `x = (q - zx) sx`
//! and weights `w = qw sw[o]` is `sx sw[o] sum (q - zx) qw + b[o]`: the sum is
//! exact in i32, computed with AVX-512 VNNI `vpdpbusd` (unsigned x signed
//! bytes, 4 products per lane). Activations are stored as `u = q + 128`
//! (unsigned), so `sum (q - zx) qw = sum u qw - (128 + zx) sum qw`, the last
//! term a per-channel constant; the zero border holds `u = 128 + zx`, which
//! contributes nothing, exactly as the float graph's zero padding.
//!
//! The requantizations after each convolution multiply by the reciprocal of
//! the scale instead of dividing ([`QuantParams::quantize_rcp`]), as other
//! int8 runtimes do: rarely, a value within an ulp of a rounding tie rounds
//! the other way than the definition; the tests bound the effect.

use crate::{check_run, for_each_tile, group_width, ConvError, Kernel, GROUP, L, NP_NARROW};
use rayon::prelude::*;

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

    fn check(self, name: &str) -> Result<(), ConvError> {
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

/// One quantized 3x3 convolution.
#[derive(Clone, Debug, PartialEq)]
pub struct Int8Conv {
    /// Input channels.
    pub in_ch: usize,
    /// Output channels.
    pub out_ch: usize,
    /// `[out][in][3][3]` int8 weights (zero point 0).
    pub weight: Vec<i8>,
    /// `[out]` weight scales.
    pub weight_scale: Vec<f32>,
    /// `[out]` the dequantized bias.
    pub bias: Vec<f32>,
    /// `[out]` PReLU slopes (float in the graph), if a PReLU follows.
    pub prelu: Option<Vec<f32>>,
    /// The quantization of the convolution's output, if any (`None`: the
    /// dequantized sum goes on in float).
    pub q_out: Option<QuantParams>,
    /// The quantization of the PReLU's output, if a PReLU follows.
    pub q_act: Option<QuantParams>,
}

/// The quantized block: layers and the activation quantizations around them.
#[derive(Clone, Debug, PartialEq)]
pub struct Int8BlockWeights {
    /// State channels.
    pub state_ch: usize,
    /// Aux channels.
    pub aux_ch: usize,
    /// Quantization of the state input, if any.
    pub q_state: Option<QuantParams>,
    /// Quantization of the aux input, if any.
    pub q_aux: Option<QuantParams>,
    /// `[state_ch + aux_ch]` factors the concatenation is multiplied by
    /// before its quantization, if any.
    pub prescale: Option<Vec<f32>>,
    /// Quantization of the (prescaled) concatenation.
    pub q_cat: QuantParams,
    /// The three convolutions.
    pub layers: [Int8Conv; 3],
    /// Quantization of the block's output, `DQ(Q(DQ(Q(state)) + c3))`; `None`:
    /// the float residual `state + c3`.
    pub q_result: Option<QuantParams>,
}

impl Int8BlockWeights {
    /// Check that the layers chain and every scale is usable.
    pub fn check(&self) -> Result<(), ConvError> {
        let bad = |r: String| Err(ConvError::Weights(r));
        if let Some(q) = self.q_state {
            q.check("state")?;
        }
        if let Some(q) = self.q_aux {
            q.check("aux")?;
        }
        self.q_cat.check("concatenation")?;
        if let Some(k) = &self.prescale {
            if k.len() != self.state_ch + self.aux_ch {
                return bad(format!(
                    "prescale: {} factors for {} channels",
                    k.len(),
                    self.state_ch + self.aux_ch
                ));
            }
            if k.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
                return bad("prescale: a factor is not a positive number".into());
            }
        }
        if let Some(q) = self.q_result {
            q.check("output")?;
            if self.q_state.is_none() {
                return bad(
                    "the quantized residual adds the quantized state, which is not quantized"
                        .into(),
                );
            }
        }
        let mut cin = self.state_ch + self.aux_ch;
        for (k, l) in self.layers.iter().enumerate() {
            let name = format!("layer {}", k + 1);
            if l.in_ch != cin || l.in_ch == 0 || l.out_ch == 0 {
                return bad(format!("{name}: takes {} channels, is fed {cin}", l.in_ch));
            }
            if l.weight.len() != l.out_ch * l.in_ch * 9
                || l.weight_scale.len() != l.out_ch
                || l.bias.len() != l.out_ch
                || l.prelu.as_ref().is_some_and(|p| p.len() != l.out_ch)
            {
                return bad(format!(
                    "{name}: weight, scale, bias or slope lengths do not match {} -> {}",
                    l.in_ch, l.out_ch
                ));
            }
            if l.weight_scale.iter().any(|s| !(s.is_finite() && *s > 0.0))
                || l.bias.iter().any(|b| !b.is_finite())
                || l.prelu
                    .as_ref()
                    .is_some_and(|p| p.iter().any(|s| !s.is_finite()))
            {
                return bad(format!(
                    "{name}: a weight scale, bias or slope is not finite (or a scale not positive)"
                ));
            }
            if let Some(q) = l.q_out {
                q.check(&format!("{name} output"))?;
            }
            let last = k == 2;
            if last != l.prelu.is_none() || l.prelu.is_some() != l.q_act.is_some() {
                return bad(format!(
                    "{name}: expected PReLU (with its quantization) after layers 1 and 2 only"
                ));
            }
            if let Some(q) = l.q_act {
                q.check(&format!("{name} PReLU"))?;
            }
            cin = l.out_ch;
        }
        if cin != self.state_ch {
            return bad(format!(
                "layer 3 gives {cin} channels, the state has {}",
                self.state_ch
            ));
        }
        Ok(())
    }

    /// Integer multiply-adds x 2 of one block on `h x w`.
    pub fn ops(&self, h: usize, w: usize) -> f64 {
        let px = (h * w) as f64;
        self.layers
            .iter()
            .map(|l| 18.0 * (l.in_ch * l.out_ch) as f64 * px)
            .sum()
    }
}

/// The float semantics of the QDQ graph, transcribed (CHW, f64 sums over the
/// dequantized values): the reference of the integer kernels.
pub fn reference_int8_block(
    b: &Int8BlockWeights,
    state: &[f32],
    aux: &[f32],
    h: usize,
    w: usize,
) -> Result<Vec<f32>, ConvError> {
    b.check()?;
    let n = h * w;
    if state.len() != b.state_ch * n || aux.len() != b.aux_ch * n {
        return Err(ConvError::Shape("state or aux length".into()));
    }
    let fake = |q: Option<QuantParams>, v: f32| q.map_or(v, |q| q.fake(v));
    let s1: Vec<f32> = state.iter().map(|&v| fake(b.q_state, v)).collect();
    let mut x: Vec<f32> = s1
        .iter()
        .copied()
        .chain(aux.iter().map(|&v| fake(b.q_aux, v)))
        .enumerate()
        .map(|(k, v)| {
            let v = b.prescale.as_ref().map_or(v, |p| v * p[k / n]);
            b.q_cat.fake(v)
        })
        .collect();
    for l in &b.layers {
        let fl = crate::Conv3x3 {
            in_ch: l.in_ch,
            out_ch: l.out_ch,
            weight: l
                .weight
                .iter()
                .enumerate()
                .map(|(k, &q)| q as f32 * l.weight_scale[k / (l.in_ch * 9)])
                .collect(),
            bias: l.bias.clone(),
            prelu: None,
        };
        let y = crate::reference_conv(&fl, &x, h, w);
        x = y
            .iter()
            .enumerate()
            .map(|(k, &v)| {
                let v = fake(l.q_out, v);
                match (&l.prelu, l.q_act) {
                    (Some(p), Some(q)) => q.fake(if v < 0.0 { v * p[k / n] } else { v }),
                    _ => v,
                }
            })
            .collect();
    }
    Ok(match b.q_result {
        Some(q) => s1.iter().zip(&x).map(|(s, c)| q.fake(s + c)).collect(),
        None => state.iter().zip(&x).map(|(s, c)| s + c).collect(),
    })
}

#[derive(Clone, Debug)]
struct PackedI8 {
    cin: usize,
    /// `cin` rounded up to 4 (bytes per pixel of the input buffer's used part).
    cin4: usize,
    ocp: usize,
    /// `[tap][cin4 / 4][ocp][4]`.
    w: Vec<i8>,
    /// `sx * sw[o]`, 0 on padded lanes.
    scale: Vec<f32>,
    /// `(128 + zx) * sum qw[o]`.
    corr: Vec<i32>,
    bias: Vec<f32>,
    slope: Vec<f32>,
    q_out: Option<QuantParams>,
    /// The input's quantization (the byte of real 0 is `128 + zp`).
    q_in: QuantParams,
}

fn pack(l: &Int8Conv, q_in: QuantParams) -> PackedI8 {
    let ocp = l.out_ch.div_ceil(L) * L;
    let cin4 = l.in_ch.div_ceil(4) * 4;
    let mut w = vec![0i8; 9 * cin4 * ocp];
    let mut scale = vec![0.0f32; ocp];
    let mut corr = vec![0i32; ocp];
    let mut bias = vec![0.0f32; ocp];
    let mut slope = vec![1.0f32; ocp];
    for o in 0..l.out_ch {
        let mut sum = 0i32;
        for i in 0..l.in_ch {
            for t in 0..9 {
                let q = l.weight[(o * l.in_ch + i) * 9 + t];
                w[((t * (cin4 / 4) + i / 4) * ocp + o) * 4 + i % 4] = q;
                sum += q as i32;
            }
        }
        scale[o] = q_in.scale * l.weight_scale[o];
        corr[o] = (128 + q_in.zero_point as i32) * sum;
        bias[o] = l.bias[o];
        if let Some(p) = &l.prelu {
            slope[o] = p[o];
        }
    }
    PackedI8 {
        cin: l.in_ch,
        cin4,
        ocp,
        w,
        scale,
        corr,
        bias,
        slope,
        q_out: l.q_out,
        q_in,
    }
}

/// A quantized DBToR block ready for the int8 fast path.
#[derive(Clone, Debug)]
pub struct Int8Block {
    state_ch: usize,
    aux_ch: usize,
    q_state: Option<QuantParams>,
    q_aux: Option<QuantParams>,
    /// One factor per concatenated channel (1 without a prescale: exact).
    prescale: Vec<f32>,
    q_cat: QuantParams,
    q_result: Option<QuantParams>,
    layers: [PackedI8; 3],
    kernel: Kernel,
    ops_per_pixel: f64,
}

/// Buffers of one int8 block run on an `h x w` grid, made once and reused.
#[derive(Clone, Debug)]
pub struct Int8Workspace {
    h: usize,
    w: usize,
    widths: [usize; 4],
    x0: Vec<u8>,
    a1: Vec<u8>,
    a2: Vec<u8>,
    out: Vec<f32>,
}

impl Int8Workspace {
    /// Buffers for `block` on an `h x w` grid.
    pub fn new(block: &Int8Block, h: usize, w: usize) -> Self {
        let [l1, l2, l3] = &block.layers;
        let padded = (h + 2) * (w + 2);
        Self {
            h,
            w,
            widths: [l1.cin4, l1.ocp, l2.ocp, l3.ocp],
            x0: vec![0; padded * l1.cin4],
            a1: vec![0; padded * l1.ocp],
            a2: vec![0; padded * l2.ocp],
            out: vec![0.0; h * w * l3.ocp],
        }
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.x0.len() + self.a1.len() + self.a2.len() + 4 * self.out.len()
    }
}

impl Int8Block {
    /// Pack checked weights for `kernel`.
    pub fn new(b: &Int8BlockWeights, kernel: Kernel) -> Result<Self, ConvError> {
        b.check()?;
        if kernel == Kernel::Avx512 && Kernel::best_int8() != Kernel::Avx512 {
            return Err(ConvError::Shape(
                "the AVX-512 VNNI kernel was asked for on a CPU without it".into(),
            ));
        }
        let [l1, l2, l3] = &b.layers;
        // check(): layers 1 and 2 end in a quantized PReLU
        let (Some(q2), Some(q3)) = (l1.q_act, l2.q_act) else {
            return Err(ConvError::Weights(
                "layers 1 and 2 must end in a quantized PReLU".into(),
            ));
        };
        Ok(Self {
            state_ch: b.state_ch,
            aux_ch: b.aux_ch,
            q_state: b.q_state,
            q_aux: b.q_aux,
            prescale: b
                .prescale
                .clone()
                .unwrap_or_else(|| vec![1.0; b.state_ch + b.aux_ch]),
            q_cat: b.q_cat,
            q_result: b.q_result,
            layers: [pack(l1, b.q_cat), pack(l2, q2), pack(l3, q3)],
            kernel,
            ops_per_pixel: b.ops(1, 1),
        })
    }

    /// The kernel in use.
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    /// Operations (2 per multiply-add) of one run on `h x w`.
    pub fn ops(&self, h: usize, w: usize) -> f64 {
        self.ops_per_pixel * (h * w) as f64
    }

    /// `state <- DQ(Q(DQ(Q(state)) + block(...)))`, or `state + block(...)`
    /// with the float residual, channel-major, on the workspace's grid.
    pub fn run(
        &self,
        ws: &mut Int8Workspace,
        state: &mut [f32],
        aux: &[f32],
    ) -> Result<(), ConvError> {
        self.run_rows(ws, state, aux, 0)
    }

    /// As [`Int8Block::run`] on the rows `r0..h` only (see
    /// [`crate::Fp32Block::run_rows`]).
    pub fn run_rows(
        &self,
        ws: &mut Int8Workspace,
        state: &mut [f32],
        aux: &[f32],
        r0: usize,
    ) -> Result<(), ConvError> {
        let (hf, w) = (ws.h, ws.w);
        let [l1, l2, l3] = &self.layers;
        let h = check_run(
            (hf, w),
            r0,
            ws.widths == [l1.cin4, l1.ocp, l2.ocp, l3.ocp],
            (state.len(), aux.len()),
            (self.state_ch, self.aux_ch),
        )?;
        // Borders (and channel padding) hold the byte of real zero of each
        // buffer's quantization, which differs from block to block.
        fill_border(&mut ws.x0, h, w, l1.cin4, pad_byte(l1.q_in));
        fill_border(&mut ws.a1, h, w, l1.ocp, pad_byte(l2.q_in));
        fill_border(&mut ws.a2, h, w, l2.ocp, pad_byte(l3.q_in));
        let (sc, c4) = (self.state_ch, l1.cin4);
        let pad0 = pad_byte(l1.q_in);
        let (qs, qa, qc, kernel) = (self.q_state, self.q_aux, self.q_cat, self.kernel);
        let prescale = &self.prescale;
        let rl = (w + 2) * c4;
        ws.x0[rl..(h + 1) * rl]
            .par_chunks_mut(rl)
            .enumerate()
            .for_each(|(r, row)| {
                let r = r + r0;
                for ch in 0..c4 {
                    if ch >= l1.cin {
                        for x in 0..w {
                            row[(x + 1) * c4 + ch] = pad0;
                        }
                        continue;
                    }
                    let (src, q) = if ch < sc {
                        (&state[(ch * hf + r) * w..(ch * hf + r + 1) * w], qs)
                    } else {
                        let a = ch - sc;
                        (&aux[(a * hf + r) * w..(a * hf + r + 1) * w], qa)
                    };
                    let mut buf = [0u8; CHUNK];
                    for (k, part) in src.chunks(CHUNK).enumerate() {
                        quantize_chunk(kernel, part, q, prescale[ch], qc, &mut buf);
                        for (e, b) in buf[..part.len()].iter().enumerate() {
                            row[(k * CHUNK + e + 1) * c4 + ch] = *b;
                        }
                    }
                }
            });
        conv(
            self.kernel,
            l1,
            &ws.x0,
            c4,
            h,
            w,
            Out::Bytes(&mut ws.a1, l2.q_in),
        );
        conv(
            self.kernel,
            l2,
            &ws.a1,
            l1.ocp,
            h,
            w,
            Out::Bytes(&mut ws.a2, l3.q_in),
        );
        conv(
            self.kernel,
            l3,
            &ws.a2,
            l2.ocp,
            h,
            w,
            Out::Floats(&mut ws.out),
        );
        let (out, o3, qr, kernel) = (&ws.out, l3.ocp, self.q_result, self.kernel);
        state.par_chunks_mut(w).enumerate().for_each(|(k, row)| {
            let (ch, r) = (k / hf, k % hf);
            if r < r0 {
                return;
            }
            let r = r - r0;
            let mut add = [0.0f32; CHUNK];
            for (c, part) in row.chunks_mut(CHUNK).enumerate() {
                for (e, a) in add[..part.len()].iter_mut().enumerate() {
                    *a = out[(r * w + c * CHUNK + e) * o3 + ch];
                }
                residual_chunk(kernel, part, &add, qs, qr);
            }
        });
        Ok(())
    }
}

#[inline]
fn to_byte(q: i8) -> u8 {
    (q as i16 + 128) as u8
}

fn pad_byte(q: QuantParams) -> u8 {
    to_byte(q.zero_point)
}

/// Pixels per chunk of the input quantization and the residual update (a
/// stack buffer: nothing is allocated in a run).
const CHUNK: usize = 64;

/// `dst[x] = byte(Q_c(DQ(Q_q(src[x])) * k))`, without `DQ(Q_q(.))` where
/// `q` is `None` (`* k` is exact for `k = 1`).
fn quantize_chunk(
    kernel: Kernel,
    src: &[f32],
    q: Option<QuantParams>,
    k: f32,
    qc: QuantParams,
    dst: &mut [u8],
) {
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Avx512 {
        // SAFETY: AVX-512F was detected when the block was made.
        done = unsafe { quantize_chunk_avx512(src, q, k, qc, dst) };
    }
    let _ = kernel;
    for (d, v) in dst[done..src.len()].iter_mut().zip(&src[done..]) {
        let v = q.map_or(*v, |q| q.fake(*v));
        *d = to_byte(qc.quantize(v * k));
    }
}

/// `row[x] = Q_r/DQ(Q_s/DQ(row[x]) + add[x])`, or `row[x] + add[x]` without
/// `qr` (the float residual).
fn residual_chunk(
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
    if kernel == Kernel::Avx512 {
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
unsafe fn q16(v: std::arch::x86_64::__m512, q: QuantParams) -> std::arch::x86_64::__m512 {
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
unsafe fn fake16(v: std::arch::x86_64::__m512, q: QuantParams) -> std::arch::x86_64::__m512 {
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
unsafe fn quantize_chunk_avx512(
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
unsafe fn residual_chunk_avx512(
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

/// Set the one-pixel border of a padded `(h + 2) x (w + 2) x c` buffer.
fn fill_border(buf: &mut [u8], h: usize, w: usize, c: usize, v: u8) {
    let rl = (w + 2) * c;
    buf[..rl].fill(v);
    buf[(h + 1) * rl..(h + 2) * rl].fill(v);
    for r in 1..=h {
        buf[r * rl..r * rl + c].fill(v);
        buf[(r + 1) * rl - c..(r + 1) * rl].fill(v);
    }
}

enum Out<'a> {
    /// Padded channels-last bytes for the next layer, quantized as it reads them.
    Bytes(&'a mut [u8], QuantParams),
    /// Dense `h x w x ocp` dequantized output of the last layer.
    Floats(&'a mut [f32]),
}

fn conv(kernel: Kernel, p: &PackedI8, inp: &[u8], cs: usize, h: usize, w: usize, out: Out<'_>) {
    let rs = (w + 2) * cs;
    debug_assert!(inp.len() >= (h + 2) * rs);
    let ocp = p.ocp;
    let row = |r: usize, dst: &mut dyn FnMut(usize, usize, &[i32])| {
        let mut tile = [0i32; NP_NARROW * GROUP];
        for_each_tile(ocp, w, |g0, gw, x, np| {
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
            );
            dst(x, g0, &tile[..np * gw]);
        });
    };
    match out {
        Out::Bytes(o, qa) => {
            let rl = (w + 2) * ocp;
            o[rl..(h + 1) * rl]
                .par_chunks_mut(rl)
                .enumerate()
                .for_each(|(r, orow)| {
                    row(r, &mut |x, g0, tile| {
                        epilogue_bytes(kernel, p, qa, x, g0, tile, &mut orow[ocp..])
                    })
                });
        }
        Out::Floats(o) => {
            o[..h * w * ocp]
                .par_chunks_mut(w * ocp)
                .enumerate()
                .for_each(|(r, orow)| {
                    row(r, &mut |x, g0, tile| {
                        epilogue_floats(kernel, p, x, g0, tile, orow)
                    })
                });
        }
    }
}

/// Conv output -> (Q/DQ) -> PReLU -> Q (`qa`, the next layer's input) ->
/// byte, at `out[(x + px) * ocp + g0 + j]`.
fn epilogue_bytes(
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
        (Kernel::Avx512, true) => unsafe { epilogue_bytes_avx512::<true>(p, qa, x, g0, tile, out) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        (Kernel::Avx512, false) => unsafe {
            epilogue_bytes_avx512::<false>(p, qa, x, g0, tile, out)
        },
        _ => epilogue_bytes_impl(p, qa, x, g0, tile, out),
    }
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
unsafe fn epilogue_bytes_avx512<const QO: bool>(
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
        let za = _mm512_set1_ps(qa.zero_point as f32);
        let (io, ia) = (
            _mm512_set1_ps(1.0 / qo.scale),
            _mm512_set1_ps(1.0 / qa.scale),
        );
        let (lo, hi, zero) = (
            _mm512_set1_ps(-128.0),
            _mm512_set1_ps(127.0),
            _mm512_setzero_ps(),
        );
        let off = _mm512_set1_epi32(128);
        assert!(tile.len().is_multiple_of(gw) && (x + tile.len() / gw) * p.ocp <= out.len());
        for (px, t) in tile.chunks_exact(gw).enumerate() {
            let o = out[(x + px) * p.ocp + g0..].as_mut_ptr();
            for jv in (0..gw).step_by(L) {
                let c = g0 + jv;
                let acc = _mm512_loadu_si512(t.as_ptr().add(jv) as *const __m512i);
                let corr = _mm512_loadu_si512(p.corr.as_ptr().add(c) as *const __m512i);
                let v = _mm512_cvtepi32_ps(_mm512_sub_epi32(acc, corr));
                let v = _mm512_mul_ps(v, _mm512_loadu_ps(p.scale.as_ptr().add(c)));
                let mut v = _mm512_add_ps(v, _mm512_loadu_ps(p.bias.as_ptr().add(c)));
                if QO {
                    // Q/DQ of the convolution's output
                    let q = _mm512_roundscale_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(
                        _mm512_mul_ps(v, io),
                    );
                    let q = _mm512_min_ps(_mm512_max_ps(_mm512_add_ps(q, zo), lo), hi);
                    v = _mm512_mul_ps(_mm512_sub_ps(q, zo), so);
                }
                // PReLU
                let neg = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(v, zero);
                let v = _mm512_mask_mul_ps(v, neg, v, _mm512_loadu_ps(p.slope.as_ptr().add(c)));
                // Q of the activation, stored as q + 128
                let q = _mm512_roundscale_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(
                    _mm512_mul_ps(v, ia),
                );
                let q = _mm512_min_ps(_mm512_max_ps(_mm512_add_ps(q, za), lo), hi);
                let b = _mm512_add_epi32(_mm512_cvtps_epi32(q), off);
                _mm_storeu_si128(o.add(jv) as *mut __m128i, _mm512_cvtepi32_epi8(b));
            }
        }
    }
}

#[inline(always)]
fn epilogue_bytes_impl(
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
fn epilogue_floats(
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
        Kernel::Avx512 => unsafe { epilogue_floats_avx512(p, x, g0, tile, out) },
        _ => epilogue_floats_impl(p, x, g0, tile, out),
    }
}

/// # Safety
/// AVX-512F and BW (the body is safe code, compiled with them enabled).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw")]
unsafe fn epilogue_floats_avx512(p: &PackedI8, x: usize, g0: usize, tile: &[i32], out: &mut [f32]) {
    epilogue_floats_impl(p, x, g0, tile, out)
}

#[inline(always)]
fn epilogue_floats_impl(p: &PackedI8, x: usize, g0: usize, tile: &[i32], out: &mut [f32]) {
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
fn run_tile(
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
) {
    assert!(base + 2 * rs + (np + 1) * cs + p.cin4 <= inp.len());
    assert!(g0 + gw <= p.ocp && p.w.len() == 9 * p.cin4 * p.ocp);
    assert!(np * gw <= tile.len() && (1..=NP_NARROW).contains(&np) && p.cin4 <= cs);
    let g4 = p.cin4 / 4;
    match kernel {
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx512 => {
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
fn tile_portable<const NB: usize, const NP: usize>(
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
unsafe fn tile_vnni<const NB: usize, const NP: usize>(
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{random_block, random_vec};
    use rand::{Rng, SeedableRng};

    /// The three graph forms export.py writes.
    #[derive(Clone, Copy, Debug, PartialEq)]
    enum Form {
        Plain,
        FloatResidual,
        ConvInputs,
    }

    const FORMS: [Form; 3] = [Form::Plain, Form::FloatResidual, Form::ConvInputs];

    /// `b` in `form`: the float residual drops the output's quantization;
    /// conv-inputs also those of the state, aux and convolution outputs,
    /// and prescales the concatenation (factors between 0.5 and 2, so that
    /// the concatenation's scale still leaves some values saturating).
    fn in_form(mut b: Int8BlockWeights, form: Form, seed: u64) -> Int8BlockWeights {
        if form != Form::Plain {
            b.q_result = None;
        }
        if form == Form::ConvInputs {
            b.q_state = None;
            b.q_aux = None;
            for l in &mut b.layers {
                l.q_out = None;
            }
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x77);
            b.prescale = Some(
                (0..b.state_ch + b.aux_ch)
                    .map(|_| rng.random_range(0.5f32..2.0))
                    .collect(),
            );
        }
        b
    }

    /// A quantized block from random float weights: per-channel symmetric
    /// weights, activation scales that leave some values saturating, zero
    /// points away from 0 so that the zero-point algebra is exercised.
    fn random_int8(sc: usize, ac: usize, hidden: usize, seed: u64) -> Int8BlockWeights {
        let f = random_block(sc, ac, hidden, seed);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x5a);
        let mut q = |scale: f32| QuantParams {
            scale: scale * rng.random_range(0.8..1.25),
            zero_point: rng.random_range(-20..=20),
        };
        let (q_state, q_aux, q_cat, q_result) = (q(0.009), q(0.008), q(0.01), q(0.012));
        let acts = [
            (q(0.02), Some(q(0.015))),
            (q(0.03), Some(q(0.02))),
            (q(0.02), None),
        ];
        let layers = f.layers.clone().map(|l| l);
        let mut k = 0;
        let layers = layers.map(|l| {
            let (q_out, q_act) = acts[k];
            k += 1;
            let per = l.in_ch * 9;
            let weight_scale: Vec<f32> = (0..l.out_ch)
                .map(|o| {
                    l.weight[o * per..(o + 1) * per]
                        .iter()
                        .fold(0.0f32, |m, v| m.max(v.abs()))
                        / 127.0
                })
                .collect();
            Int8Conv {
                in_ch: l.in_ch,
                out_ch: l.out_ch,
                weight: l
                    .weight
                    .iter()
                    .enumerate()
                    .map(|(i, v)| (v / weight_scale[i / per]).round() as i8)
                    .collect(),
                weight_scale,
                bias: l.bias,
                prelu: l.prelu,
                q_out: Some(q_out),
                q_act,
            }
        });
        Int8BlockWeights {
            state_ch: sc,
            aux_ch: ac,
            q_state: Some(q_state),
            q_aux: Some(q_aux),
            prescale: None,
            q_cat,
            layers,
            q_result: Some(q_result),
        }
    }

    fn run(
        b: &Int8BlockWeights,
        k: Kernel,
        state: &[f32],
        aux: &[f32],
        h: usize,
        w: usize,
    ) -> Vec<f32> {
        let blk = Int8Block::new(b, k).unwrap();
        let mut ws = Int8Workspace::new(&blk, h, w);
        let mut s = state.to_vec();
        blk.run(&mut ws, &mut s, aux).unwrap();
        // Reusing the workspace gives the same answer.
        let mut again = state.to_vec();
        blk.run(&mut ws, &mut again, aux).unwrap();
        assert_eq!(s, again);
        s
    }

    fn check(sc: usize, ac: usize, hidden: usize, h: usize, w: usize, form: Form) {
        let b = in_form(random_int8(sc, ac, hidden, 11 + w as u64), form, w as u64);
        let state = random_vec(sc * h * w, 3);
        let aux = random_vec(ac * h * w, 4);
        let want = reference_int8_block(&b, &state, &aux, h, w).unwrap();
        let got = run(&b, Kernel::Portable, &state, &aux, h, w);
        // The integer sums are exact where the reference sums dequantized
        // floats: a value within float rounding of a quantization tie may
        // round the other way at one of the requantizations and move its
        // neighbours by a fraction of a quantum. So: nearly every output
        // identical, none off by more than two output quanta (the block
        // output's; with the float residual the last convolution's; with
        // conv-inputs, where the output is a float sum, the last PReLU's
        // quantum times the largest |weight| of conv3 times its 9 in_ch taps,
        // what one flipped input step can move an output by).
        let q = match (b.q_result, b.layers[2].q_out) {
            (Some(q), _) | (None, Some(q)) => q.scale,
            (None, None) => {
                let l = &b.layers[2];
                let wmax = l
                    .weight
                    .iter()
                    .enumerate()
                    .map(|(k, v)| (*v as f32 * l.weight_scale[k / (l.in_ch * 9)]).abs())
                    .fold(0.0f32, f32::max);
                b.layers[1].q_act.map_or(0.0, |q| q.scale) * wmax * 9.0
            }
        };
        // In float sums a differing output need not be a whole quantum off:
        // "differs" is more than float rounding (1e-3 of a quantum).
        let tol = if form == Form::ConvInputs {
            1e-3 * q
        } else {
            0.0
        };
        let off: Vec<f32> = got.iter().zip(&want).map(|(a, b)| (a - b).abs()).collect();
        let worst = off.iter().fold(0.0f32, |m, v| m.max(*v));
        let differing = off.iter().filter(|v| **v > tol).count();
        let moved = got
            .iter()
            .zip(&state)
            .filter(|(a, s)| (**a - **s).abs() > 2.0 * q)
            .count();
        // The block is not close to the identity: the test sees the convolutions.
        assert!(
            moved * 2 > got.len(),
            "only {moved} of {} outputs moved",
            got.len()
        );
        assert!(
            worst <= 2.0 * q * 1.0001,
            "{sc}+{ac}->{hidden} {h}x{w} {form:?}: off by {} quanta",
            worst / q
        );
        assert!(
            differing * 100 <= got.len(),
            "{differing} of {} outputs differ",
            got.len()
        );
        if dbt_isa::kernel_test_runs("int8 vnni", &["avx512f", "avx512bw", "avx512vnni"]) {
            assert_eq!(Kernel::best_int8(), Kernel::Avx512);
            // Same integers, same float epilogue: bit-identical.
            assert_eq!(run(&b, Kernel::Avx512, &state, &aux, h, w), got);
        }
    }

    #[test]
    fn integer_kernels_reproduce_the_qdq_graph() {
        for form in FORMS {
            check(5, 2, 64, 9, 13, form);
            check(5, 3, 64, 4, 25, form);
            check(5, 3, 16, 3, 7, form);
            check(2, 1, 48, 5, 11, form);
            check(5, 2, 64, 1, 1, form);
        }
    }

    #[test]
    fn float_residual_adds_the_unquantized_state() {
        // With the float residual the output minus the (unquantized) state is
        // the update c3 = DQ(Q(conv3)): a whole number of c3's quanta, to the
        // float rounding of the sum (states here are O(1), quanta O(0.02):
        // 1e-3 quanta is far above that rounding and far below a quantum).
        // The quantized residual gives other outputs: the test sees which
        // form ran.
        let (sc, ac, h, w) = (5, 2, 6, 9);
        let mut b = random_int8(sc, ac, 16, 3);
        let state = random_vec(sc * h * w, 7);
        let aux = random_vec(ac * h * w, 8);
        let quantized = run(&b, Kernel::Portable, &state, &aux, h, w);
        b.q_result = None;
        let got = run(&b, Kernel::Portable, &state, &aux, h, w);
        let q3 = b.layers[2].q_out.map_or(0.0, |q| q.scale);
        for (g, s) in got.iter().zip(&state) {
            let k = (g - s) / q3;
            assert!((k - k.round()).abs() < 1e-3, "update {k} quanta");
        }
        let moved = got.iter().zip(&quantized).filter(|(a, b)| a != b).count();
        assert!(moved * 2 > got.len(), "only {moved} outputs differ");
    }

    #[test]
    fn cropped_rows_are_the_block_on_the_sub_image() {
        let (sc, ac, h, w, r0) = (5, 2, 9, 21, 3);
        let b = random_int8(sc, ac, 16, 5);
        let state = random_vec(sc * h * w, 1);
        let aux = random_vec(ac * h * w, 2);
        let rows = |v: &[f32], c: usize| -> Vec<f32> {
            (0..c)
                .flat_map(|ch| v[(ch * h + r0) * w..(ch + 1) * h * w].to_vec())
                .collect()
        };
        let want = run(
            &b,
            Kernel::Portable,
            &rows(&state, sc),
            &rows(&aux, ac),
            h - r0,
            w,
        );
        for k in [Kernel::Portable, Kernel::best_int8()] {
            let blk = Int8Block::new(&b, k).unwrap();
            let mut ws = Int8Workspace::new(&blk, h, w);
            let mut s = state.clone();
            blk.run(&mut ws, &mut s, &aux).unwrap();
            let mut got = state.clone();
            blk.run_rows(&mut ws, &mut got, &aux, r0).unwrap();
            assert_eq!(
                &got[..r0 * w],
                &state[..r0 * w],
                "rows above the crop changed"
            );
            assert_eq!(rows(&got, sc), want);
        }
    }

    #[test]
    fn quantization_follows_onnx() {
        let q = QuantParams {
            scale: 0.5,
            zero_point: 3,
        };
        // round half to even, then the zero point, then saturation
        assert_eq!(q.quantize(0.25), 3);
        assert_eq!(q.quantize(0.75), 5);
        assert_eq!(q.quantize(-0.75), 1);
        assert_eq!(q.quantize(1e9), 127);
        assert_eq!(q.quantize(-1e9), -128);
        assert_eq!(q.dequantize(5), 1.0);
        let mut b = random_int8(5, 2, 16, 1);
        b.layers[1].q_out = Some(QuantParams {
            scale: 0.0,
            zero_point: 0,
        });
        let e = Int8Block::new(&b, Kernel::Portable).unwrap_err();
        assert!(e.to_string().contains("layer 2 output: scale 0"), "{e}");
        let mut b = random_int8(5, 2, 16, 1);
        b.layers[2].q_act = Some(b.q_cat);
        assert!(Int8Block::new(&b, Kernel::Portable).is_err());
    }
}
