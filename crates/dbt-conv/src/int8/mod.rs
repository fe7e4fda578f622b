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
//!
//! Split by layer: [`quant`] (quantisation), [`reference`] (the float
//! graph), [`pack`] (weights for the kernel), [`kernels`] (the integer
//! convolution), [`winograd`] (the same convolution in fewer products, on
//! AVX2 and AVX-VNNI); this file runs a block with them.

use crate::{check_run, for_each_tile, group_width, ConvError, Kernel, GROUP, L, NP_NARROW};
use rayon::prelude::*;

mod amx;
mod fused;
mod kernels;
mod pack;
mod quant;
mod reference;
pub(crate) mod winograd;

/// Whether the AMX int8 kernel runs here ([`Kernel::amx_available`]).
pub(crate) fn amx_available() -> bool {
    amx::available()
}

/// This thread's AMX-INT8 peak (int8 operations per second, two per
/// multiply-add) from `iterations` of four register-only `tdpbusd` (16 x 16
/// sums over 64 bytes each, no tile loads): the floor the benchmarks
/// compare the AMX kernel with. `None` where the AMX kernel does not run.
pub fn amx_peak_ops(iterations: usize) -> Option<f64> {
    #[cfg(target_arch = "x86_64")]
    {
        amx::available().then(|| amx::peak_ops(iterations))
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = iterations;
        None
    }
}

use kernels::*;
use pack::*;
pub use quant::QuantParams;
use quant::*;
pub use reference::{reference_int8_block, Int8BlockWeights, Int8Conv};

/// From how many bytes of layer-by-layer buffers
/// ([`Int8Block::layered_bytes`]) a block runs fused over bands of rows
/// ([`Int8Block::runs_fused`]). Measured on the Intel Xeon with AMX
/// (`dbtor-bench --layered`, docs/benchmarks.md, "Fused rows"): below it,
/// at 1.6 to 6.5 MB (the model's blocks, the paper's dual blocks), layer by
/// layer was the faster by 4 to 14 % (a band recomputes rows at its edges;
/// the buffers stay in cache); at the paper's primal blocks (58 MB) fused
/// took a median 0.89 of the layer-by-layer time with AMX over seven runs.
pub const FUSED_FROM_BYTES: usize = 16 << 20;

/// How an [`Int8Block`] chooses between the fused and the layer-by-layer
/// run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Fusion {
    /// Fused from [`FUSED_FROM_BYTES`] on.
    BySize,
    /// Layer by layer always.
    Never,
    /// Fused at every size (the tests).
    #[cfg(test)]
    Always,
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
    /// Whether the three convolutions and the residual run in one pass
    /// over bands of rows ([`fused`]) or layer by layer over the
    /// workspace's buffers (the same bits).
    fusion: Fusion,
}

/// Buffers of one int8 block run on an `h x w` grid, made once and reused.
/// For a block that runs fused on that grid ([`Int8Block::runs_fused`]),
/// only the quantized input: the layer-by-layer buffers stay empty, and
/// every block run on such a workspace runs fused (the same bits).
#[derive(Clone, Debug)]
pub struct Int8Workspace {
    h: usize,
    w: usize,
    /// Whether runs on it are fused (its layer-by-layer buffers empty).
    fused: bool,
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
        let fused = block.runs_fused(h, w);
        let n = |len: usize| if fused { 0 } else { len };
        Self {
            h,
            w,
            fused,
            widths: [l1.cin4, l1.ocp, l2.ocp, l3.ocp],
            x0: vec![0; padded * l1.cin4],
            a1: vec![0; n(padded * l1.ocp)],
            a2: vec![0; n(padded * l2.ocp)],
            out: vec![0.0; n(h * w * l3.ocp)],
        }
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.x0.len() + self.a1.len() + self.a2.len() + 4 * self.out.len()
    }
}

impl Int8Block {
    /// Pack checked weights for `kernel` (on AVX2 and AVX-VNNI, the
    /// convolutions by Winograd's F(3x3, 3x3), bit for bit the direct ones:
    /// [`Int8Block::with_winograd`]).
    pub fn new(b: &Int8BlockWeights, kernel: Kernel) -> Result<Self, ConvError> {
        Self::with_winograd(b, kernel, true)
    }

    /// As [`Int8Block::new`]; `winograd: false` keeps the AVX2 and AVX-VNNI
    /// kernels' direct convolution everywhere (to test and benchmark it;
    /// the other kernels ignore the flag).
    pub fn with_winograd(
        b: &Int8BlockWeights,
        kernel: Kernel,
        winograd: bool,
    ) -> Result<Self, ConvError> {
        b.check()?;
        if kernel != Kernel::best_int8_up_to(kernel) {
            return Err(ConvError::Shape(format!(
                "the {} int8 kernel was asked for on a CPU that lacks it (best here: {})",
                kernel.name(),
                Kernel::best_int8().name()
            )));
        }
        #[cfg(target_arch = "x86_64")]
        if kernel == Kernel::Amx {
            amx::self_check().map_err(ConvError::Shape)?;
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
            layers: {
                let wg = winograd && matches!(kernel, Kernel::Avx2 | Kernel::AvxVnni);
                [pack(l1, b.q_cat, wg), pack(l2, q2, wg), pack(l3, q3, wg)]
            },
            kernel,
            ops_per_pixel: b.ops(1, 1),
            fusion: Fusion::BySize,
        })
    }

    /// The kernel in use.
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    /// Run layer by layer over the workspace's buffers at every size, on a
    /// workspace made after this (the same bits; for benchmarks).
    pub fn set_layer_by_layer(&mut self) {
        self.fusion = Fusion::Never;
    }

    /// The bytes a layer-by-layer run on `h x w` writes and reads back: the
    /// two padded activations and the float output.
    pub fn layered_bytes(&self, h: usize, w: usize) -> usize {
        let [l1, l2, l3] = &self.layers;
        (h + 2) * (w + 2) * (l1.ocp + l2.ocp) + h * w * l3.ocp * 4
    }

    /// Whether a run on `h x w` rows makes the three convolutions and the
    /// residual in one pass over bands of rows: where no layer convolves by
    /// Winograd and the layer-by-layer run's buffers
    /// ([`Int8Block::layered_bytes`]) reach [`FUSED_FROM_BYTES`]; else
    /// layer by layer.
    pub fn runs_fused(&self, h: usize, w: usize) -> bool {
        let direct = self.layers.iter().all(|l| l.wino.is_none());
        match self.fusion {
            Fusion::Never => false,
            Fusion::BySize => direct && self.layered_bytes(h, w) >= FUSED_FROM_BYTES,
            #[cfg(test)]
            Fusion::Always => direct,
        }
    }

    /// How many of the block's three convolutions run by Winograd.
    pub fn winograd_layers(&self) -> usize {
        self.layers.iter().filter(|l| l.wino.is_some()).count()
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
        // Fused where the workspace was made for it (`Int8Workspace::new`).
        if ws.fused {
            fused::run(
                self.kernel,
                &self.layers,
                &ws.x0,
                h,
                w,
                fused::Residual {
                    state,
                    state_ch: sc,
                    hf,
                    r0,
                    qs,
                    qr: self.q_result,
                },
            );
            return Ok(());
        }
        fill_border(&mut ws.a1, h, w, l1.ocp, pad_byte(l2.q_in));
        fill_border(&mut ws.a2, h, w, l2.ocp, pad_byte(l3.q_in));
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
        let (out, o3, qr) = (&ws.out, l3.ocp, self.q_result);
        state.par_chunks_mut(w).enumerate().for_each(|(k, row)| {
            let (ch, r) = (k / hf, k % hf);
            if r < r0 {
                return;
            }
            let r = r - r0;
            residual_row(kernel, row, &out[r * w * o3..], (o3, ch), qs, qr);
        });
        Ok(())
    }
}

#[cfg(test)]
pub(crate) mod tests {
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
    pub(crate) fn random_int8(sc: usize, ac: usize, hidden: usize, seed: u64) -> Int8BlockWeights {
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
        if dbt_isa::kernel_test_runs("int8 avx2", &["avx2"]) {
            assert!(Kernel::best_int8() >= Kernel::Avx2);
            // Exact integer products and sums: bit-identical too.
            assert_eq!(run(&b, Kernel::Avx2, &state, &aux, h, w), got);
        }
        if dbt_isa::kernel_test_runs("int8 avx-vnni", &["avx2", "avxvnni"]) {
            assert!(Kernel::best_int8() >= Kernel::AvxVnni);
            assert_eq!(run(&b, Kernel::AvxVnni, &state, &aux, h, w), got);
        }
    }

    /// Every pixel count of a tile (1..=10 and a tail), both group widths,
    /// input channels that fill 16-byte steps or not (7 and 20 concatenated
    /// channels: 8 and 20 bytes per pixel, the AVX2 window's 16-, 8- and
    /// 4-byte steps), on the AVX2 and AVX-VNNI kernels, against the portable
    /// one.
    #[test]
    fn avx2_and_avx_vnni_int8_match_portable_on_every_tile_shape() {
        let kernels: Vec<Kernel> = [
            (Kernel::Avx2, "int8 avx2", &["avx2"][..]),
            (Kernel::AvxVnni, "int8 avx-vnni", &["avx2", "avxvnni"][..]),
        ]
        .into_iter()
        .filter(|(_, name, needs)| dbt_isa::kernel_test_runs(name, needs))
        .map(|(k, _, _)| k)
        .collect();
        for k in kernels {
            for w in 1..=12 {
                for (sc, ac) in [(5, 2), (5, 15)] {
                    for hidden in [64, 16, 32] {
                        let b = in_form(random_int8(sc, ac, hidden, 11 + w as u64), Form::Plain, 1);
                        let state = random_vec(sc * 2 * w, 1);
                        let aux = random_vec(ac * 2 * w, 2);
                        assert_eq!(
                            run(&b, k, &state, &aux, 2, w),
                            run(&b, Kernel::Portable, &state, &aux, 2, w),
                            "{k:?}: {sc} + {ac} -> {hidden} channels, width {w}"
                        );
                    }
                }
            }
        }
    }

    /// The AVX2 and AVX-VNNI kernels' blocks by Winograd give the direct
    /// blocks' bits, on
    /// every grid height 1-7 (whole 3-row groups and 1 or 2 rows left over)
    /// and widths with 0, 1 or 2 columns left over, one and several chunks
    /// of tiles, in all three graph forms; the portable and AVX-512 kernels
    /// do not pack for it.
    #[test]
    fn winograd_blocks_give_the_direct_blocks_bits() {
        let run_with = |b: &Int8BlockWeights, k, wg: bool, state: &[f32], aux: &[f32], h, w| {
            let blk = Int8Block::with_winograd(b, k, wg).unwrap();
            assert_eq!(blk.winograd_layers(), if wg { 3 } else { 0 });
            let mut ws = Int8Workspace::new(&blk, h, w);
            let mut s = state.to_vec();
            blk.run(&mut ws, &mut s, aux).unwrap();
            s
        };
        for k in winograd::tests::winograd_kernels() {
            for (f, form) in FORMS.into_iter().enumerate() {
                for h in 1..=7 {
                    for (w, hidden) in [(1, 16), (5, 32), (16, 80), (17, 32), (31, 16), (65, 32)] {
                        let seed = (h * 100 + w + f) as u64;
                        let b = in_form(random_int8(5, 3, hidden, seed), form, seed);
                        let state = random_vec(5 * h * w, seed);
                        let aux = random_vec(3 * h * w, seed + 1);
                        assert_eq!(
                            run_with(&b, k, true, &state, &aux, h, w),
                            run_with(&b, k, false, &state, &aux, h, w),
                            "{k:?}, {form:?}: {h} x {w}, {hidden} channels"
                        );
                    }
                }
            }
        }
        let b = random_int8(5, 3, 32, 1);
        for k in [Kernel::Portable, Kernel::best_int8()] {
            if !matches!(k, Kernel::Avx2 | Kernel::AvxVnni) {
                assert_eq!(Int8Block::new(&b, k).unwrap().winograd_layers(), 0);
            }
        }
    }

    /// The packed weights' storage is aligned for the AVX2 and AVX-VNNI
    /// kernels' aligned loads, and holds the weights' values: the pair
    /// packing is a permutation of the byte packing.
    #[test]
    fn packed_weights_are_aligned_and_a_permutation() {
        let b = random_int8(5, 2, 64, 3);
        for l in &b.layers {
            let p = pack(l, b.q_cat, true);
            assert_eq!(p.w.as_ptr() as usize % 64, 0);
            assert_eq!(p.w16.as_ptr() as usize % 64, 0);
            let mut a: Vec<i16> = p.w.iter().map(|&v| i16::from(v)).collect();
            let mut c = p.w16.to_vec();
            a.sort_unstable();
            c.sort_unstable();
            assert_eq!(a, c);
            // tap 4, input channel 3 (pair 1, second), the last output
            // channel
            let (t, i, o) = (4, 3, l.out_ch - 1);
            let want = l.weight[(o * l.in_ch + i) * 9 + t];
            assert_eq!(
                p.w[((t * (p.cin4 / 4) + i / 4) * p.ocp + o) * 4 + i % 4],
                want
            );
            assert_eq!(
                p.w16[((t * (p.cin4 / 2) + i / 2) * p.ocp + o) * 2 + i % 2],
                i16::from(want)
            );
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
    fn fused_bands_give_the_layer_by_layer_bits() {
        // Heights from one row a band to several window steps, widths
        // with and without AMX's 16-pixel remainder, both output forms, on
        // one and on four threads (one band, and four), every kernel here
        // (AVX2 and AVX-VNNI without Winograd, the fused pass's case).
        let pools = [1, 4].map(|n| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
        });
        let mut kernels = vec![Kernel::Portable];
        for k in [Kernel::Avx2, Kernel::AvxVnni, Kernel::Avx512, Kernel::Amx] {
            if (k == Kernel::Amx && Kernel::amx_available())
                || (k != Kernel::Amx && Kernel::best_int8_up_to(k) == k)
            {
                kernels.push(k);
            }
        }
        for (h, w, form) in [
            (1, 7, Form::Plain),
            (2, 16, Form::ConvInputs),
            (3, 33, Form::FloatResidual),
            (31, 18, Form::ConvInputs),
            (32, 40, Form::Plain),
            (70, 21, Form::ConvInputs),
        ] {
            let b = in_form(random_int8(5, 2, 64, 40 + h as u64), form, h as u64);
            let state = random_vec(5 * h * w, 7);
            let aux = random_vec(2 * h * w, 8);
            for &k in &kernels {
                let mut fused = Int8Block::with_winograd(&b, k, false).unwrap();
                fused.fusion = Fusion::Always;
                let mut layered = fused.clone();
                layered.set_layer_by_layer();
                let mut wl = Int8Workspace::new(&layered, h, w);
                let mut want = state.clone();
                layered.run(&mut wl, &mut want, &aux).unwrap();
                // the fused block's workspace holds the input only
                let mut ws = Int8Workspace::new(&fused, h, w);
                assert!(ws.fused && ws.a1.is_empty() && ws.bytes() < wl.bytes());
                assert!(!wl.fused);
                // the windows' sizes for their width (32 rows here), and
                // the fewest (5 rows: a step of one output row)
                for rows in [0, 5] {
                    fused::TEST_WINDOW_ROWS.store(rows, std::sync::atomic::Ordering::Relaxed);
                    for pool in &pools {
                        let mut got = state.clone();
                        pool.install(|| fused.run(&mut ws, &mut got, &aux)).unwrap();
                        let n = pool.current_num_threads();
                        assert_eq!(
                            got,
                            want,
                            "{} on {h} x {w}, {form:?}, {n} threads, window {rows}",
                            k.name()
                        );
                    }
                }
                fused::TEST_WINDOW_ROWS.store(0, std::sync::atomic::Ordering::Relaxed);
            }
        }
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
