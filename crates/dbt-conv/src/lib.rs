//! The fast path of a DBToR block (issue #5): the hot operator of the network,
//! a 3x3 convolution with zero 'same' padding followed by its bias and a
//! per-channel PReLU, and the block's residual update
//! `state <- state + L3(PReLU(L2(PReLU(L1(cat(state, aux))))))`.
//!
//! tract-onnx stays the model loader and the reference executor; this crate
//! is pure computation on weights handed to it (no I/O, no ONNX).
//!
//! Layout and blocking (fp32):
//! * activations are channels-last with a one-pixel zero border,
//!   `(h + 2) x (w + 2) x c`, so that the nine taps of every output pixel
//!   are plain offsets and there is no boundary test in the inner loop; the
//!   borders are zeroed once when the workspace is made and never written;
//! * weights are packed `[tap][in][out padded to 16]`, so the weights of one
//!   input channel and tap for all output channels are consecutive vectors;
//! * the micro-kernel keeps a tile of 6 output pixels x 64 output channels
//!   (24 AVX-512 accumulators) in registers: per (tap, input channel) it loads
//!   4 weight vectors and broadcasts 6 input values, 24 fused multiply-adds;
//! * output rows are shared among the threads with rayon.
//!
//! On AVX2 CPUs (issue #30) the same tiles are computed in register-sized
//! passes: 16 vector registers of 8 lanes hold 16 output channels x 5
//! pixels (fp32, FMA; int8: the tile's input bytes widened to i16 once and
//! `vpmaddwd` on pairs of input channels, exact where `vpmaddubsw` would
//! saturate; int8 on AVX-VNNI: `vpdpbusd` on the bytes as the AVX-512
//! kernel), written where the AVX-512 kernels write, so packing, epilogues
//! and the block loop are shared.
//!
//! The portable kernel computes the same tiles with plain arrays (the
//! compiler vectorises what it can); it runs where neither is present and is
//! the reference the SIMD kernels are tested against, all being tested
//! against a direct transcription of the convolution's definition (int8:
//! the AVX2 and VNNI kernels bit-identical to the portable one).
//! [`Kernel`] orders the kernels; a caller may force a slower one
//! (`dbt_dbtor::KERNEL_ENV`).

// Kernel crate (issue #25): every unsafe operation in its own `unsafe` block
// with a `SAFETY:` comment, every unsafe function with its `# Safety` contract.
#![deny(unsafe_op_in_unsafe_fn)]
#![deny(clippy::undocumented_unsafe_blocks, clippy::missing_safety_doc)]
/// Lanes of an AVX-512 vector of f32 or i32.
pub(crate) const L: usize = 16;
/// Output channels per register group: 4 vectors.
pub(crate) const GROUP: usize = 4 * L;
/// Pixels per tile when a group of 64 channels is in registers
/// (5 x 4 = 20 accumulators; 5 divides the widths of the paper's grids,
/// 1000, 1280 and their binned 250, 320, 500, 640).
pub(crate) const NP_WIDE: usize = 5;
/// Pixels per tile when one vector of channels is in registers.
pub(crate) const NP_NARROW: usize = 10;

/// Per-thread scratch: `f` gets the first `n` values of a buffer the thread
/// keeps in `key` (grown when a call needs more, reused after), so that the
/// kernels allocate nothing per call once warm (the fast engine's
/// no-allocation rule, `crates/dbt-dbtor/tests/no_alloc.rs`). Each use site
/// has its own key, so nested calls never share a buffer.
pub(crate) fn with_scratch<T: Copy + Default + 'static, R>(
    key: &'static std::thread::LocalKey<std::cell::RefCell<Vec<T>>>,
    n: usize,
    f: impl FnOnce(&mut [T]) -> R,
) -> R {
    key.with(|c| {
        let mut v = c.borrow_mut();
        if v.len() < n {
            v.resize(n, T::default());
        }
        f(&mut v[..n])
    })
}

/// Width of the channel group starting at `g0` of `ocp` (padded) channels:
/// 64 while that many remain, else one vector.
pub(crate) fn group_width(ocp: usize, g0: usize) -> usize {
    if ocp - g0 >= GROUP {
        GROUP
    } else {
        L
    }
}

/// The tiles of one output row of width `w`, in order: for each channel
/// group `(g0, gw)`, runs of `np` pixels from `x`. Both precisions walk a row
/// this way.
pub(crate) fn for_each_tile(ocp: usize, w: usize, mut f: impl FnMut(usize, usize, usize, usize)) {
    let mut g0 = 0;
    while g0 < ocp {
        let gw = group_width(ocp, g0);
        let per = if gw == GROUP { NP_WIDE } else { NP_NARROW };
        let mut x = 0;
        while x < w {
            let np = per.min(w - x);
            f(g0, gw, x, np);
            x += np;
        }
        g0 += gw;
    }
}

/// Instantiate the tile kernel `$f::<NB, NP>` for a run-time `np` in 1..=10.
macro_rules! dispatch_np {
    ($f:ident, $nb:literal, $np:expr, $($arg:expr),*) => {
        match $np {
            1 => $f::<$nb, 1>($($arg),*),
            2 => $f::<$nb, 2>($($arg),*),
            3 => $f::<$nb, 3>($($arg),*),
            4 => $f::<$nb, 4>($($arg),*),
            5 => $f::<$nb, 5>($($arg),*),
            6 => $f::<$nb, 6>($($arg),*),
            7 => $f::<$nb, 7>($($arg),*),
            8 => $f::<$nb, 8>($($arg),*),
            9 => $f::<$nb, 9>($($arg),*),
            _ => $f::<$nb, 10>($($arg),*),
        }
    };
}

/// The checks every block run makes before touching its workspace: the
/// first row inside the grid, the workspace made for this block's widths,
/// state and aux of the grid's size. Returns the rows to compute.
pub(crate) fn check_run(
    (hf, w): (usize, usize),
    r0: usize,
    widths_match: bool,
    (state_len, aux_len): (usize, usize),
    (state_ch, aux_ch): (usize, usize),
) -> Result<usize, ConvError> {
    let n = hf * w;
    if r0 >= hf {
        return Err(ConvError::Shape(format!(
            "first row {r0} is not inside the {hf} rows"
        )));
    }
    if !widths_match {
        return Err(ConvError::Shape(
            "the workspace was made for a block of other widths".into(),
        ));
    }
    if state_len != state_ch * n || aux_len != aux_ch * n {
        return Err(ConvError::Shape(format!(
            "state has {state_len} values and aux {aux_len}, the block needs {} and {} ({hf} x {w})",
            state_ch * n,
            aux_ch * n
        )));
    }
    Ok(hf - r0)
}

mod fp32;
mod int8;
pub mod select;

pub use fp32::{Fp32Block, Fp32Workspace};
pub use int8::{
    amx_peak_ops, reference_int8_block, Int8Block, Int8BlockWeights, Int8Conv, Int8Workspace,
    QuantParams, FUSED_FROM_BYTES,
};

/// Errors: weights or shapes that do not make a DBToR block.
#[derive(Debug, thiserror::Error)]
pub enum ConvError {
    /// The weights do not fit together.
    #[error("block weights: {0}")]
    Weights(String),
    /// An input or workspace does not match the block or the image.
    #[error("shape: {0}")]
    Shape(String),
}

/// One 3x3 convolution (stride 1, zero padding 1), its bias and an optional
/// per-output-channel PReLU slope, in ONNX / PyTorch order.
#[derive(Clone, Debug, PartialEq)]
pub struct Conv3x3 {
    /// Input channels.
    pub in_ch: usize,
    /// Output channels.
    pub out_ch: usize,
    /// `[out][in][3][3]`.
    pub weight: Vec<f32>,
    /// `[out]`.
    pub bias: Vec<f32>,
    /// `[out]` slopes of the PReLU that follows, if any.
    pub prelu: Option<Vec<f32>>,
}

impl Conv3x3 {
    fn check(&self, name: &str) -> Result<(), ConvError> {
        let bad = |r: String| Err(ConvError::Weights(format!("{name}: {r}")));
        if self.in_ch == 0 || self.out_ch == 0 {
            return bad(format!("{} -> {} channels", self.in_ch, self.out_ch));
        }
        if self.weight.len() != self.out_ch * self.in_ch * 9 {
            return bad(format!(
                "weight has {} values, expected {} x {} x 3 x 3",
                self.weight.len(),
                self.out_ch,
                self.in_ch
            ));
        }
        if self.bias.len() != self.out_ch {
            return bad(format!(
                "bias has {} values, expected {}",
                self.bias.len(),
                self.out_ch
            ));
        }
        if let Some(p) = &self.prelu {
            if p.len() != self.out_ch {
                return bad(format!(
                    "PReLU has {} slopes, expected {}",
                    p.len(),
                    self.out_ch
                ));
            }
        }
        let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
        if !finite(&self.weight) || !finite(&self.bias) || !self.prelu.as_deref().is_none_or(finite)
        {
            return bad("a weight, bias or slope is not finite".into());
        }
        Ok(())
    }
}

/// The three convolutions of a DBToR block and its channel counts.
#[derive(Clone, Debug, PartialEq)]
pub struct BlockWeights {
    /// State channels (5 in the paper): the residual's width.
    pub state_ch: usize,
    /// Auxiliary input channels concatenated after the state.
    pub aux_ch: usize,
    /// `state + aux -> hidden` (PReLU), `hidden -> hidden` (PReLU),
    /// `hidden -> state` (no activation).
    pub layers: [Conv3x3; 3],
}

impl BlockWeights {
    /// Check that the three layers chain and fit the state and aux widths.
    pub fn check(&self) -> Result<(), ConvError> {
        let [l1, l2, l3] = &self.layers;
        l1.check("layer 1")?;
        l2.check("layer 2")?;
        l3.check("layer 3")?;
        let bad = |r: String| Err(ConvError::Weights(r));
        if l1.in_ch != self.state_ch + self.aux_ch {
            return bad(format!(
                "layer 1 takes {} channels, the block feeds state {} + aux {}",
                l1.in_ch, self.state_ch, self.aux_ch
            ));
        }
        if l2.in_ch != l1.out_ch || l3.in_ch != l2.out_ch {
            return bad(format!(
                "layers do not chain: {}->{}, {}->{}, {}->{}",
                l1.in_ch, l1.out_ch, l2.in_ch, l2.out_ch, l3.in_ch, l3.out_ch
            ));
        }
        if l3.out_ch != self.state_ch {
            return bad(format!(
                "layer 3 gives {} channels, the state has {}",
                l3.out_ch, self.state_ch
            ));
        }
        if l1.prelu.is_none() || l2.prelu.is_none() || l3.prelu.is_some() {
            return bad("expected PReLU after layers 1 and 2 and none after layer 3".into());
        }
        Ok(())
    }

    /// Floating-point operations of one block on an `h x w` grid (2 per
    /// multiply-add, bias and activation not counted).
    pub fn flops(&self, h: usize, w: usize) -> f64 {
        let px = (h * w) as f64;
        self.layers
            .iter()
            .map(|l| 2.0 * 9.0 * (l.in_ch * l.out_ch) as f64 * px)
            .sum()
    }
}

/// Which kernel runs the tiles, slowest first (the order is the dispatch's:
/// a kernel may be forced down to any lower one).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Kernel {
    /// Plain Rust arrays, any CPU.
    Portable,
    /// AVX2 + FMA (fp32) or AVX2 `vpmaddwd` on bytes widened to i16 (int8).
    Avx2,
    /// int8 only: AVX-VNNI, the VEX-encoded 256-bit `vpdpbusd` of CPUs with
    /// AVX2 and AVX-VNNI (Intel Alder Lake and later client cores have it
    /// without AVX-512). fp32 runs its AVX2 kernel at this level
    /// ([`Kernel::for_fp32`]).
    AvxVnni,
    /// AVX-512F fused multiply-add (fp32) or AVX-512 VNNI `vpdpbusd` (int8).
    Avx512,
    /// int8 only: AMX-INT8 tile products (`tdpbusd`), on CPUs with AMX and
    /// AVX-512 VNNI (Intel Sapphire Rapids and later). Never ranked first by
    /// [`Kernel::best_int8`]: chosen where [`select`] measures it fastest
    /// and correct, or forced (`DBTOR_KERNEL=amx`; not yet run on AMX
    /// hardware, see `int8/amx.rs`); fp32 runs AVX-512 at this level.
    Amx,
}

impl Kernel {
    /// Every kernel, slowest first.
    pub const ALL: [Kernel; 5] = [
        Kernel::Portable,
        Kernel::Avx2,
        Kernel::AvxVnni,
        Kernel::Avx512,
        Kernel::Amx,
    ];

    /// The fp32 kernel of this level: AVX-VNNI and AMX have no fp32 kernel
    /// of their own, so their levels run fp32 on AVX2 and AVX-512.
    pub fn for_fp32(self) -> Self {
        match self {
            Self::AvxVnni => Self::Avx2,
            Self::Amx => Self::Avx512,
            k => k,
        }
    }

    /// Whether this CPU (and OS) runs the AMX int8 kernel: AMX-TILE,
    /// AMX-INT8 and AVX-512 VNNI, and the tile data granted to the process.
    pub fn amx_available() -> bool {
        crate::int8::amx_available()
    }

    /// The fastest kernel this CPU runs for fp32.
    pub fn best_fp32() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                return Self::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                return Self::Avx2;
            }
        }
        Self::Portable
    }

    /// The fastest fp32 kernel this CPU runs, at most `limit`.
    pub fn best_fp32_up_to(limit: Kernel) -> Self {
        Self::best_fp32().min(limit.for_fp32())
    }

    /// The fastest int8 kernel this CPU runs, at most `limit` (AMX only when
    /// `limit` names it and the CPU has it).
    pub fn best_int8_up_to(limit: Kernel) -> Self {
        if limit == Self::Amx && Self::amx_available() {
            Self::Amx
        } else {
            Self::best_int8().min(limit)
        }
    }

    /// A kernel by its [`Kernel::name`].
    pub fn parse(name: &str) -> Option<Kernel> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }

    /// The fastest kernel this CPU runs for int8.
    pub fn best_int8() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("avx512bw")
                && std::arch::is_x86_feature_detected!("avx512vnni")
            {
                return Self::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                if std::arch::is_x86_feature_detected!("avxvnni") {
                    return Self::AvxVnni;
                }
                return Self::Avx2;
            }
        }
        Self::Portable
    }

    /// Whether this kernel's int8 convolution can run by Winograd (AVX2
    /// and AVX-VNNI; bit for bit the direct one).
    pub fn has_int8_winograd(self) -> bool {
        matches!(self, Self::Avx2 | Self::AvxVnni)
    }

    /// Name for tables and logs.
    pub fn name(self) -> &'static str {
        match self {
            Self::Portable => "portable",
            Self::Avx2 => "avx2",
            Self::AvxVnni => "avx-vnni",
            Self::Avx512 => "avx512",
            Self::Amx => "amx",
        }
    }
}

/// A direct transcription of the definitions (CHW, zero padding): the
/// reference both kernels are tested against. `state` is `state_ch x h x w`,
/// `aux` is `aux_ch x h x w`; returns the new state.
pub fn reference_block(
    b: &BlockWeights,
    state: &[f32],
    aux: &[f32],
    h: usize,
    w: usize,
) -> Result<Vec<f32>, ConvError> {
    b.check()?;
    let n = h * w;
    if state.len() != b.state_ch * n || aux.len() != b.aux_ch * n {
        return Err(ConvError::Shape(format!(
            "state {} / aux {} values for {} + {} channels of {h} x {w}",
            state.len(),
            aux.len(),
            b.state_ch,
            b.aux_ch
        )));
    }
    let mut x: Vec<f32> = state.iter().chain(aux).copied().collect();
    for l in &b.layers {
        x = reference_conv(l, &x, h, w);
    }
    Ok(state.iter().zip(&x).map(|(s, d)| s + d).collect())
}

/// One convolution layer by its definition, accumulating in f64.
pub fn reference_conv(l: &Conv3x3, x: &[f32], h: usize, w: usize) -> Vec<f32> {
    let mut y = vec![0.0f32; l.out_ch * h * w];
    for o in 0..l.out_ch {
        for r in 0..h {
            for c in 0..w {
                let mut acc = l.bias[o] as f64;
                for i in 0..l.in_ch {
                    for ky in 0..3 {
                        for kx in 0..3 {
                            let (rr, cc) =
                                (r as isize + ky as isize - 1, c as isize + kx as isize - 1);
                            if rr < 0 || cc < 0 || rr >= h as isize || cc >= w as isize {
                                continue;
                            }
                            let v = x[(i * h + rr as usize) * w + cc as usize] as f64;
                            acc += v * l.weight[((o * l.in_ch + i) * 3 + ky) * 3 + kx] as f64;
                        }
                    }
                }
                let mut v = acc as f32;
                if let Some(p) = &l.prelu {
                    if v < 0.0 {
                        v *= p[o];
                    }
                }
                y[(o * h + r) * w + c] = v;
            }
        }
    }
    y
}

#[cfg(test)]
pub(crate) mod testutil {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Random block weights with He-like scales, so that activations stay O(1).
    pub fn random_block(state_ch: usize, aux_ch: usize, hidden: usize, seed: u64) -> BlockWeights {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut layer = |i: usize, o: usize, prelu: bool| {
            let s = (2.0 / (9.0 * i as f32)).sqrt();
            Conv3x3 {
                in_ch: i,
                out_ch: o,
                weight: (0..o * i * 9).map(|_| rng.random_range(-s..s)).collect(),
                bias: (0..o).map(|_| rng.random_range(-0.1..0.1)).collect(),
                prelu: prelu.then(|| (0..o).map(|_| rng.random_range(0.0..0.5)).collect()),
            }
        };
        BlockWeights {
            state_ch,
            aux_ch,
            layers: [
                layer(state_ch + aux_ch, hidden, true),
                layer(hidden, hidden, true),
                layer(hidden, state_ch, false),
            ],
        }
    }

    pub fn random_vec(n: usize, seed: u64) -> Vec<f32> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n).map(|_| rng.random_range(-1.0..1.0)).collect()
    }

    /// The largest difference between `a` and `b`, relative to `b`'s
    /// largest magnitude.
    pub fn max_rel(a: &[f32], b: &[f32]) -> f64 {
        let scale = b
            .iter()
            .fold(0.0f64, |m, v| m.max(v.abs() as f64))
            .max(1e-30);
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs() as f64)
            .fold(0.0, f64::max)
            / scale
    }
}
