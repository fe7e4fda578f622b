//! fp32 blocks: packing, the workspace, the tile kernels and the block loop.

mod winograd;

use crate::{
    check_run, for_each_tile, BlockWeights, Conv3x3, ConvError, Kernel, GROUP, L, NP_NARROW,
};
use rayon::prelude::*;

/// One convolution, packed `[tap][in][out padded to 16]`.
#[derive(Clone, Debug)]
pub(crate) struct Packed {
    pub cin: usize,
    pub ocp: usize,
    pub w: Vec<f32>,
    pub bias: Vec<f32>,
    pub slope: Option<Vec<f32>>,
    /// The Winograd weights (`winograd`), where asked for and
    /// eligible.
    pub wino: Option<Vec<f32>>,
}

pub(crate) fn pack(l: &Conv3x3, winograd: bool) -> Packed {
    let ocp = l.out_ch.div_ceil(L) * L;
    let mut w = vec![0.0f32; 9 * l.in_ch * ocp];
    for o in 0..l.out_ch {
        for i in 0..l.in_ch {
            for t in 0..9 {
                w[(t * l.in_ch + i) * ocp + o] = l.weight[(o * l.in_ch + i) * 9 + t];
            }
        }
    }
    let mut bias = vec![0.0f32; ocp];
    bias[..l.out_ch].copy_from_slice(&l.bias);
    let slope = l.prelu.as_ref().map(|p| {
        let mut s = vec![1.0f32; ocp];
        s[..l.out_ch].copy_from_slice(p);
        s
    });
    let wino = (winograd && winograd::eligible(l.in_ch))
        .then(|| winograd::transform_weights(&w, l.in_ch, ocp));
    Packed {
        cin: l.in_ch,
        ocp,
        w,
        bias,
        slope,
        wino,
    }
}

/// A DBToR block ready for the fp32 fast path.
#[derive(Clone, Debug)]
pub struct Fp32Block {
    state_ch: usize,
    aux_ch: usize,
    layers: [Packed; 3],
    kernel: Kernel,
    flops_per_pixel: f64,
}

/// Buffers of one block run on an `h x w` grid, made once and reused: no
/// allocation happens in [`Fp32Block::run`].
#[derive(Clone, Debug)]
pub struct Fp32Workspace {
    h: usize,
    w: usize,
    widths: [usize; 4],
    x0: Vec<f32>,
    a1: Vec<f32>,
    a2: Vec<f32>,
    out: Vec<f32>,
}

impl Fp32Workspace {
    /// Buffers for `block` on an `h x w` grid.
    pub fn new(block: &Fp32Block, h: usize, w: usize) -> Self {
        let [l1, l2, l3] = &block.layers;
        let padded = (h + 2) * (w + 2);
        Self {
            h,
            w,
            widths: [l1.cin, l1.ocp, l2.ocp, l3.ocp],
            x0: vec![0.0; padded * l1.cin],
            a1: vec![0.0; padded * l1.ocp],
            a2: vec![0.0; padded * l2.ocp],
            out: vec![0.0; h * w * l3.ocp],
        }
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        4 * (self.x0.len() + self.a1.len() + self.a2.len() + self.out.len())
    }
}

impl Fp32Block {
    /// Pack checked weights for `kernel` (the AVX-VNNI level runs the AVX2
    /// kernel: [`Kernel::for_fp32`]).
    pub fn new(b: &BlockWeights, kernel: Kernel) -> Result<Self, ConvError> {
        Self::with_winograd(b, kernel, false)
    }

    /// As [`Fp32Block::new`]; `winograd: true` convolves by Winograd's
    /// F(3x3, 3x3) on the AVX-512 and AVX2 kernels (not the direct
    /// kernels' bits: `winograd`; opt-in).
    pub fn with_winograd(
        b: &BlockWeights,
        kernel: Kernel,
        winograd: bool,
    ) -> Result<Self, ConvError> {
        b.check()?;
        let kernel = kernel.for_fp32();
        if kernel > Kernel::best_fp32() {
            return Err(ConvError::Shape(format!(
                "the {} fp32 kernel was asked for on a CPU that lacks it (best here: {})",
                kernel.name(),
                Kernel::best_fp32().name()
            )));
        }
        Ok(Self {
            state_ch: b.state_ch,
            aux_ch: b.aux_ch,
            layers: {
                let wg = winograd && matches!(kernel, Kernel::Avx2 | Kernel::Avx512);
                b.layers.each_ref().map(|l| pack(l, wg))
            },
            kernel,
            flops_per_pixel: b.flops(1, 1),
        })
    }

    /// The kernel in use.
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    /// How many of the block's three convolutions run by Winograd.
    pub fn winograd_layers(&self) -> usize {
        self.layers.iter().filter(|l| l.wino.is_some()).count()
    }

    /// Floating-point operations of one run on `h x w`.
    pub fn flops(&self, h: usize, w: usize) -> f64 {
        self.flops_per_pixel * (h * w) as f64
    }

    /// `state <- state + block(cat(state, aux))`, both channel-major
    /// (`c x h x w`), on the workspace's grid.
    pub fn run(
        &self,
        ws: &mut Fp32Workspace,
        state: &mut [f32],
        aux: &[f32],
    ) -> Result<(), ConvError> {
        self.run_rows(ws, state, aux, 0)
    }

    /// As [`Fp32Block::run`], on the rows `r0..h` of the grid only, as if
    /// they were the whole image (zero padding above row `r0`); the rows
    /// above are left as they are. For cropping the primal work to the
    /// rows where the breast can be.
    pub fn run_rows(
        &self,
        ws: &mut Fp32Workspace,
        state: &mut [f32],
        aux: &[f32],
        r0: usize,
    ) -> Result<(), ConvError> {
        let (hf, w) = (ws.h, ws.w);
        let [l1, l2, l3] = &self.layers;
        let h = check_run(
            (hf, w),
            r0,
            ws.widths == [l1.cin, l1.ocp, l2.ocp, l3.ocp],
            (state.len(), aux.len()),
            (self.state_ch, self.aux_ch),
        )?;
        let (sc, c0) = (self.state_ch, l1.cin);
        // cat(state, aux) into the padded channels-last input.
        // (Rows are sliced out, not skipped: rayon's `skip` spawns a heap job.)
        let rl = (w + 2) * c0;
        // The row below the last one computed is the bottom zero border (an
        // interior row of the buffers when rows are cropped).
        for (buf, c) in [(&mut ws.x0, c0), (&mut ws.a1, l1.ocp), (&mut ws.a2, l2.ocp)] {
            buf[(h + 1) * (w + 2) * c..(h + 2) * (w + 2) * c].fill(0.0);
        }
        ws.x0[rl..(h + 1) * rl]
            .par_chunks_mut(rl)
            .enumerate()
            .for_each(|(r, row)| {
                let r = r + r0;
                for ch in 0..c0 {
                    let src = if ch < sc {
                        &state[(ch * hf + r) * w..(ch * hf + r + 1) * w]
                    } else {
                        let a = ch - sc;
                        &aux[(a * hf + r) * w..(a * hf + r + 1) * w]
                    };
                    for (x, v) in src.iter().enumerate() {
                        row[(x + 1) * c0 + ch] = *v;
                    }
                }
            });
        conv(self.kernel, l1, &ws.x0, c0, h, w, &mut ws.a1, true);
        conv(self.kernel, l2, &ws.a1, l1.ocp, h, w, &mut ws.a2, true);
        conv(self.kernel, l3, &ws.a2, l2.ocp, h, w, &mut ws.out, false);
        let (out, o3) = (&ws.out, l3.ocp);
        state.par_chunks_mut(w).enumerate().for_each(|(k, row)| {
            let (ch, r) = (k / hf, k % hf);
            if r < r0 {
                return;
            }
            let r = r - r0;
            for (x, v) in row.iter_mut().enumerate() {
                *v += out[(r * w + x) * o3 + ch];
            }
        });
        Ok(())
    }
}

/// One layer over the whole grid: `inp` is padded channels-last with channel
/// stride `cs`; the output is padded channels-last (`padded`) or dense
/// `h x w x ocp`, with bias and PReLU applied.
#[allow(clippy::too_many_arguments)]
fn conv(
    kernel: Kernel,
    p: &Packed,
    inp: &[f32],
    cs: usize,
    h: usize,
    w: usize,
    out: &mut [f32],
    padded: bool,
) {
    let ocp = p.ocp;
    let (row_len, px0, skip) = if padded {
        ((w + 2) * ocp, ocp, 1)
    } else {
        (w * ocp, 0, 0)
    };
    let rs = (w + 2) * cs;
    debug_assert!(inp.len() >= (h + 2) * rs);
    debug_assert!(p.cin <= cs);
    let wino = match kernel {
        Kernel::Avx2 | Kernel::Avx512 => p.wino.as_deref(),
        _ => None,
    };
    let per = if wino.is_some() {
        crate::int8::winograd::M
    } else {
        1
    };
    out[skip * row_len..(skip + h) * row_len]
        .par_chunks_mut(per * row_len)
        .enumerate()
        .for_each(|(k, orows)| {
            let n = orows.len() / row_len;
            #[cfg(target_arch = "x86_64")]
            if let Some(u) = wino.filter(|_| n == per) {
                let mut put = |a: usize, x: usize, np: usize, sums: &[f32]| {
                    let orow = &mut orows[a * row_len..(a + 1) * row_len];
                    epilogue(p, 0, ocp, np, sums, &mut orow[px0 + x * ocp..]);
                };
                winograd::row_triple(kernel, p, u, inp, k * per, rs, cs, w, &mut put);
                return;
            }
            let mut tile = [0.0f32; NP_NARROW * GROUP];
            for a in 0..n {
                let r = k * per + a;
                let orow = &mut orows[a * row_len..(a + 1) * row_len];
                for_each_tile(ocp, w, |g0, gw, x, np| {
                    let base = r * rs + x * cs;
                    run_tile(kernel, gw, np, inp, base, rs, cs, p, g0, &mut tile);
                    epilogue(p, g0, gw, np, &tile, &mut orow[px0 + x * ocp..]);
                });
            }
        });
}

/// Bias and PReLU on a tile of `np` pixels x `gw` channels, written at
/// `out[p * ocp + g0 + j]`.
#[inline]
pub(crate) fn epilogue(p: &Packed, g0: usize, gw: usize, np: usize, tile: &[f32], out: &mut [f32]) {
    let bias = &p.bias[g0..g0 + gw];
    for px in 0..np {
        let t = &tile[px * gw..(px + 1) * gw];
        let o = &mut out[px * p.ocp + g0..px * p.ocp + g0 + gw];
        match &p.slope {
            Some(s) => {
                let s = &s[g0..g0 + gw];
                for j in 0..gw {
                    let v = t[j] + bias[j];
                    o[j] = if v < 0.0 { v * s[j] } else { v };
                }
            }
            None => {
                for j in 0..gw {
                    o[j] = t[j] + bias[j];
                }
            }
        }
    }
}

/// Accumulate one tile (no bias) into `tile[p * gw + j]`.
#[allow(clippy::too_many_arguments)]
#[inline]
pub(crate) fn run_tile(
    kernel: Kernel,
    gw: usize,
    np: usize,
    inp: &[f32],
    base: usize,
    rs: usize,
    cs: usize,
    p: &Packed,
    g0: usize,
    tile: &mut [f32],
) {
    // Bounds the kernels rely on: every tap of the tile is inside `inp`, the
    // packed weights cover the group, the tile holds np x gw values.
    assert!(base + 2 * rs + (np + 1) * cs + p.cin <= inp.len());
    assert!(g0 + gw <= p.ocp && p.w.len() == 9 * p.cin * p.ocp);
    assert!(np * gw <= tile.len() && (1..=NP_NARROW).contains(&np));
    match kernel {
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx512 => {
            let (i, wp, t) = (inp[base..].as_ptr(), p.w[g0..].as_ptr(), tile.as_mut_ptr());
            // SAFETY: AVX-512F was detected when the block was made
            // (Fp32Block::new refuses otherwise); the asserts above bound
            // every address the kernel reads and writes.
            unsafe {
                if gw == GROUP {
                    dispatch_np!(tile_avx512, 4, np, i, rs, cs, p.cin, wp, p.ocp, t)
                } else {
                    dispatch_np!(tile_avx512, 1, np, i, rs, cs, p.cin, wp, p.ocp, t)
                }
            }
        }
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx2 => {
            let (i, wp, t) = (inp[base..].as_ptr(), p.w[g0..].as_ptr(), tile.as_mut_ptr());
            // SAFETY: AVX2 and FMA were detected when the block was made
            // (Fp32Block::new refuses otherwise); the asserts above bound
            // every address the kernel reads and writes.
            unsafe { tile_avx2(gw / L, np, i, rs, cs, p.cin, wp, p.ocp, t) }
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
                    p.cin,
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
                    p.cin,
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
    inp: &[f32],
    base: usize,
    rs: usize,
    cs: usize,
    cin: usize,
    w: &[f32],
    g0: usize,
    ocp: usize,
    tile: &mut [f32],
) {
    let mut acc = [[[0.0f32; L]; NB]; NP];
    for t in 0..9 {
        let ib = base + (t / 3) * rs + (t % 3) * cs;
        for ic in 0..cin {
            let wr = &w[(t * cin + ic) * ocp + g0..];
            for (p, a) in acc.iter_mut().enumerate() {
                let b = inp[ib + p * cs + ic];
                for (j, aj) in a.iter_mut().enumerate() {
                    let wv = &wr[j * L..(j + 1) * L];
                    for k in 0..L {
                        aj[k] += b * wv[k];
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
/// AVX-512F; `inp` valid for every tap of the tile (`2 * rs + (NP + 1) * cs`
/// values), `w` for `9 * cin * ocp` values from the group's first lane, `out`
/// for `NP * NB * 16`.
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx512f")]
unsafe fn tile_avx512<const NB: usize, const NP: usize>(
    inp: *const f32,
    rs: usize,
    cs: usize,
    cin: usize,
    w: *const f32,
    ocp: usize,
    out: *mut f32,
) {
    // SAFETY: AVX-512F and the pointer ranges per the contract (`# Safety` above).
    unsafe {
        use std::arch::x86_64::*;
        let mut acc = [[_mm512_setzero_ps(); NB]; NP];
        for t in 0..9 {
            let ib = inp.add((t / 3) * rs + (t % 3) * cs);
            let wb = w.add(t * cin * ocp);
            for ic in 0..cin {
                let wr = wb.add(ic * ocp);
                let mut wv = [_mm512_setzero_ps(); NB];
                for (j, v) in wv.iter_mut().enumerate() {
                    *v = _mm512_loadu_ps(wr.add(j * L));
                }
                for (p, a) in acc.iter_mut().enumerate() {
                    let b = _mm512_set1_ps(*ib.add(p * cs + ic));
                    for (j, aj) in a.iter_mut().enumerate() {
                        *aj = _mm512_fmadd_ps(b, wv[j], *aj);
                    }
                }
            }
        }
        for (p, a) in acc.iter().enumerate() {
            for (j, aj) in a.iter().enumerate() {
                _mm512_storeu_ps(out.add((p * NB + j) * L), *aj);
            }
        }
    }
}

/// AVX2 + FMA: the AVX-512 tile computed in register-sized pieces. AVX2 has
/// 16 vector registers of 8 lanes, so one pass keeps 16 output channels
/// (2 registers) x up to 5 pixels (10 accumulators) plus 2 weight vectors
/// and a broadcast; the tile of `nb` x 16 channels x `np` pixels is covered
/// by `nb` x ceil(np / 5) passes, written where the AVX-512 kernel writes
/// (`out[(p * nb + j) * 16 + k]`).
///
/// # Safety
/// AVX2 and FMA; the pointer ranges of [`tile_avx512`]'s contract with
/// `NB = nb`, `NP = np` (`np` in 1..=10, `nb` in 1..=4).
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx2,fma")]
unsafe fn tile_avx2(
    nb: usize,
    np: usize,
    inp: *const f32,
    rs: usize,
    cs: usize,
    cin: usize,
    w: *const f32,
    ocp: usize,
    out: *mut f32,
) {
    let mut p0 = 0;
    while p0 < np {
        let n = (np - p0).min(5);
        for j in 0..nb {
            // SAFETY: the pass reads pixels p0..p0 + n of the tile (inside
            // its input range) and channels j * 16..(j + 1) * 16 of the
            // group (inside its weights), and writes those values of `out`.
            unsafe {
                let (i, wj, o) = (inp.add(p0 * cs), w.add(j * L), out.add((p0 * nb + j) * L));
                match n {
                    1 => pass_avx2::<1>(i, rs, cs, cin, wj, ocp, o, nb),
                    2 => pass_avx2::<2>(i, rs, cs, cin, wj, ocp, o, nb),
                    3 => pass_avx2::<3>(i, rs, cs, cin, wj, ocp, o, nb),
                    4 => pass_avx2::<4>(i, rs, cs, cin, wj, ocp, o, nb),
                    _ => pass_avx2::<5>(i, rs, cs, cin, wj, ocp, o, nb),
                }
            }
        }
        p0 += n;
    }
}

/// 16 output channels x `NP` pixels: the accumulators of one AVX2 pass,
/// stored at `out[p * nb * 16 + k]`.
///
/// # Safety
/// AVX2 and FMA; `inp` valid for every tap of `NP` pixels, `w` for
/// `9 * cin * ocp` values from the pass's first channel, `out` for
/// `(NP - 1) * nb * 16 + 16` values.
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx2,fma")]
unsafe fn pass_avx2<const NP: usize>(
    inp: *const f32,
    rs: usize,
    cs: usize,
    cin: usize,
    w: *const f32,
    ocp: usize,
    out: *mut f32,
    nb: usize,
) {
    // SAFETY: AVX2, FMA and the pointer ranges per the contract.
    unsafe {
        use std::arch::x86_64::*;
        let mut lo = [_mm256_setzero_ps(); NP];
        let mut hi = [_mm256_setzero_ps(); NP];
        for t in 0..9 {
            let ib = inp.add((t / 3) * rs + (t % 3) * cs);
            let wb = w.add(t * cin * ocp);
            for ic in 0..cin {
                let wr = wb.add(ic * ocp);
                let (w0, w1) = (
                    dbt_isa::ymm::loadu_ps(wr),
                    dbt_isa::ymm::loadu_ps(wr.add(8)),
                );
                for p in 0..NP {
                    let b = _mm256_broadcast_ss(&*ib.add(p * cs + ic));
                    lo[p] = _mm256_fmadd_ps(b, w0, lo[p]);
                    hi[p] = _mm256_fmadd_ps(b, w1, hi[p]);
                }
            }
        }
        for p in 0..NP {
            let o = out.add(p * nb * L);
            dbt_isa::ymm::storeu_ps(o, lo[p]);
            dbt_isa::ymm::storeu_ps(o.add(8), hi[p]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference_block;
    use crate::testutil::{max_rel, random_block, random_vec};

    fn check(kernel: Kernel, sc: usize, ac: usize, hidden: usize, h: usize, w: usize) {
        let b = random_block(sc, ac, hidden, 7 + h as u64);
        let state = random_vec(sc * h * w, 1);
        let aux = random_vec(ac * h * w, 2);
        let want = reference_block(&b, &state, &aux, h, w).unwrap();
        let fb = Fp32Block::new(&b, kernel).unwrap();
        let mut ws = Fp32Workspace::new(&fb, h, w);
        let mut got = state.clone();
        fb.run(&mut ws, &mut got, &aux).unwrap();
        // f32 accumulation over up to 64 x 9 = 576 products against the f64
        // reference: relative error ~ sqrt(576) * 6e-8 per layer, three layers.
        let e = max_rel(&got, &want);
        assert!(
            e < 1e-5,
            "{kernel:?} {sc}+{ac}->{hidden} {h}x{w}: max rel error {e:e}"
        );
        // A second run on the same workspace gives the same answer (the
        // padded borders stay zero).
        let mut again = state.clone();
        fb.run(&mut ws, &mut again, &aux).unwrap();
        assert_eq!(again, got);
    }

    /// The shapes both kernels are checked on: hidden widths of 4 and 1
    /// register groups and 48 (3 single vectors), widths with and without a
    /// tail of pixels, and a single pixel.
    fn check_shapes(kernel: Kernel) {
        check(kernel, 5, 2, 64, 9, 13);
        check(kernel, 5, 3, 64, 4, 25);
        check(kernel, 5, 3, 16, 3, 7);
        check(kernel, 2, 1, 48, 5, 11);
        check(kernel, 5, 2, 64, 1, 1);
    }

    #[test]
    fn portable_matches_definition() {
        check_shapes(Kernel::Portable);
    }

    #[test]
    fn avx2_matches_definition() {
        if !dbt_isa::kernel_test_runs("fp32 avx2", &["avx2", "fma"]) {
            return;
        }
        assert!(Kernel::best_fp32() >= Kernel::Avx2);
        check_shapes(Kernel::Avx2);
        // Every pixel count of a tile (1..=10) and both group widths.
        for w in 1..=12 {
            check(Kernel::Avx2, 5, 2, 64, 2, w);
            check(Kernel::Avx2, 5, 2, 16, 2, w);
        }
    }

    #[test]
    fn avx512_matches_definition() {
        if !dbt_isa::kernel_test_runs("fp32 avx512", &["avx512f"]) {
            return;
        }
        assert_eq!(Kernel::best_fp32(), Kernel::Avx512);
        check_shapes(Kernel::Avx512);
    }

    #[test]
    fn cropped_rows_are_the_block_on_the_sub_image() {
        let (sc, ac, h, w, r0) = (5, 2, 9, 13, 4);
        let b = random_block(sc, ac, 16, 3);
        let state = random_vec(sc * h * w, 1);
        let aux = random_vec(ac * h * w, 2);
        let rows = |v: &[f32], c: usize| -> Vec<f32> {
            (0..c)
                .flat_map(|ch| v[(ch * h + r0) * w..(ch + 1) * h * w].to_vec())
                .collect()
        };
        let want = reference_block(&b, &rows(&state, sc), &rows(&aux, ac), h - r0, w).unwrap();
        for k in [Kernel::Portable, Kernel::best_fp32()] {
            let fb = Fp32Block::new(&b, k).unwrap();
            let mut ws = Fp32Workspace::new(&fb, h, w);
            // A full run first leaves data in the rows the cropped run uses
            // as its bottom border.
            let mut s = state.clone();
            fb.run(&mut ws, &mut s, &aux).unwrap();
            let mut got = state.clone();
            fb.run_rows(&mut ws, &mut got, &aux, r0).unwrap();
            assert_eq!(
                &got[..r0 * w],
                &state[..r0 * w],
                "rows above the crop changed"
            );
            assert!(max_rel(&rows(&got, sc), &want) < 1e-5);
            assert!(fb.run_rows(&mut ws, &mut got, &aux, h).is_err());
        }
    }

    #[test]
    fn shapes_are_checked() {
        let b = random_block(5, 2, 16, 1);
        let fb = Fp32Block::new(&b, Kernel::Portable).unwrap();
        let mut ws = Fp32Workspace::new(&fb, 3, 4);
        let mut s = vec![0.0; 5 * 12];
        let e = fb.run(&mut ws, &mut s, &[0.0; 23]).unwrap_err();
        assert!(e.to_string().contains("aux 23"), "{e}");
        let other = Fp32Block::new(&random_block(5, 3, 16, 1), Kernel::Portable).unwrap();
        let e = other.run(&mut ws, &mut s, &[0.0; 36]).unwrap_err();
        assert!(e.to_string().contains("workspace"), "{e}");
        let mut bad = b.clone();
        bad.layers[1].bias.pop();
        let e = Fp32Block::new(&bad, Kernel::Portable).unwrap_err();
        assert!(e.to_string().contains("layer 2: bias has 15 values"), "{e}");
        let mut bad = b.clone();
        bad.layers[2].out_ch = 4;
        assert!(Fp32Block::new(&bad, Kernel::Portable).is_err());
        let mut bad = b;
        bad.layers[0].weight[3] = f32::NAN;
        let e = Fp32Block::new(&bad, Kernel::Portable).unwrap_err();
        assert!(e.to_string().contains("not finite"), "{e}");
    }
}
