//! A block's three convolutions and its residual in one pass over bands of
//! rows, the activations between them held in a few rows per thread.
//!
//! Layer by layer, a block at the paper's geometry (1000 x 300 pixels of 64
//! channels) writes and reads back two 19 MB activation buffers and a 19 MB
//! float output: far beyond a core's L2, so the convolutions wait on memory
//! (on the Intel Xeon with AMX a primal block took about three times its
//! products' time; docs/benchmarks.md, "Fused rows"). Here each band of
//! output rows is made row by row: a row of the second activation as soon
//! as the three rows of the first it reads exist, an output row as soon as
//! its three second-activation rows exist, the residual on it at once. The
//! activations live in [`Window`]s of a few rows per thread; a band
//! recomputes the two first-activation and one second-activation rows above
//! and below it that its neighbour also makes.
//!
//! Every value is computed by the same tile kernel and epilogue as layer by
//! layer, from the same bytes, so the block's output is the same bits
//! (`fused_bands_give_the_layer_by_layer_bits`).

use super::kernels::{conv_row, epilogue_bytes, epilogue_floats};
use super::quant::{pad_byte, residual_row};
use super::{Kernel, PackedI8, QuantParams};
use rayon::prelude::*;

/// The padded rows `first..first + len` of one activation, `rl` bytes each,
/// in a buffer of `cap` rows: appending to a full window drops the rows no
/// longer read and moves the others to the front.
struct Window<'a> {
    buf: &'a mut [u8],
    rl: usize,
    /// Bytes per pixel, and the byte of real zero that pads.
    cs: usize,
    pad: u8,
    cap: usize,
    first: usize,
    len: usize,
}

impl<'a> Window<'a> {
    fn new(buf: &'a mut [u8], rl: usize, (cs, pad): (usize, u8), first: usize) -> Self {
        let cap = buf.len() / rl;
        assert!(
            cap >= 3 && rl >= 2 * cs,
            "a window holds at least three rows"
        );
        Window {
            buf,
            rl,
            cs,
            pad,
            cap,
            first,
            len: 0,
        }
    }

    /// Padded row `first + len` appended as a border row (all pad); the
    /// rows from `keep` on are still needed ([`Window::push`]).
    fn push_border(&mut self, keep: usize) {
        let pad = self.pad;
        self.push(keep).fill(pad);
    }

    /// Padded row `first + len` appended, its two border pixels padded:
    /// the row's pixels `1..=w`, for the caller to write.
    fn push_row(&mut self, keep: usize) -> &mut [u8] {
        let (cs, pad) = (self.cs, self.pad);
        let slot = self.push(keep);
        let n = slot.len();
        slot[..cs].fill(pad);
        slot[n - cs..].fill(pad);
        &mut slot[cs..n - cs]
    }

    /// The slot of padded row `first + len`, appended; a full window first
    /// drops its rows above `keep` (the first row still needed) and moves
    /// the others to the front.
    fn push(&mut self, keep: usize) -> &mut [u8] {
        if self.len == self.cap {
            assert!(
                keep > self.first && keep <= self.first + self.len,
                "a full window of rows {}..{} must drop some before row {keep}",
                self.first,
                self.first + self.len
            );
            let drop = keep - self.first;
            self.buf.copy_within(drop * self.rl..self.len * self.rl, 0);
            self.first = keep;
            self.len -= drop;
        }
        let s = self.len * self.rl;
        self.len += 1;
        &mut self.buf[s..s + self.rl]
    }

    /// The buffer and the local index of padded row `pr`, which the window
    /// holds with the two rows below it (a convolution's three input rows).
    fn rows(&self, pr: usize) -> (&[u8], usize) {
        assert!(
            pr >= self.first && pr + 3 <= self.first + self.len,
            "rows {pr}..{} are not in the window's {}..{}",
            pr + 3,
            self.first,
            self.first + self.len
        );
        (&self.buf[..self.len * self.rl], pr - self.first)
    }
}

/// Rows of the two activations each window holds: about 1 MiB per thread
/// for both (a core's L2 is 1-2 MiB on the CPUs this runs on), from 5 to
/// 32. [`run`] makes `rows - 4` output rows a step: the first activation's
/// window then holds the rows of the second that step reads and the one
/// before (its rows `re + 2 - (r - 1)` at most, four more than the step).
fn window_rows(rl1: usize, rl2: usize) -> usize {
    #[cfg(test)]
    {
        let n = TEST_WINDOW_ROWS.load(std::sync::atomic::Ordering::Relaxed);
        if n > 0 {
            return n;
        }
    }
    ((1 << 20) / (rl1 + rl2)).clamp(5, 32)
}

/// The tests' window rows where not 0 (any number from 5 gives the same
/// bits, so tests running beside the one that sets it are not affected).
#[cfg(test)]
pub(super) static TEST_WINDOW_ROWS: std::sync::atomic::AtomicUsize =
    std::sync::atomic::AtomicUsize::new(0);

/// How many bands `h` rows are cut into: one per thread (each band runs on
/// one thread), two per thread where each still has 64 rows (so that a
/// slower thread's band can be taken by another: a band recomputes two
/// rows of the second convolution, 3 % of its work at 64 rows), never more
/// than the rows.
fn bands(h: usize, threads: usize) -> usize {
    let t = threads.max(1);
    let n = if h / (2 * t) >= 64 { 2 * t } else { t };
    n.min(h).max(1)
}

/// The state and the residual's quantizations: where [`run`] adds each
/// output row to.
pub(super) struct Residual<'a> {
    /// The state, channel-major over `hf` rows of `w`.
    pub(super) state: &'a mut [f32],
    pub(super) state_ch: usize,
    pub(super) hf: usize,
    /// The first row run (rows above it are left alone).
    pub(super) r0: usize,
    pub(super) qs: Option<QuantParams>,
    pub(super) qr: Option<QuantParams>,
}

/// A pointer to the state that bands writing disjoint rows share.
#[derive(Clone, Copy)]
struct StatePtr(*mut f32);
// SAFETY: only dereferenced in `run`, where each band writes the state rows
// of its own output rows (disjoint between bands) and nothing else reads
// or writes the state during the pass.
unsafe impl Send for StatePtr {}
// SAFETY: as for Send: the bands' rows are disjoint.
unsafe impl Sync for StatePtr {}

impl StatePtr {
    /// The `w` values from offset `at`.
    ///
    /// # Safety
    /// Inside the state, and no other reference to them alive.
    #[allow(clippy::mut_from_ref)]
    unsafe fn row(&self, at: usize, w: usize) -> &mut [f32] {
        // SAFETY: the caller's.
        unsafe { std::slice::from_raw_parts_mut(self.0.add(at), w) }
    }
}

/// The block's three convolutions from the quantized input `x0` (padded
/// channels-last, `h + 2` rows of `w + 2` pixels of `l1.cin4` bytes, its
/// borders filled) and the residual into `res`'s rows `r0..r0 + h`.
pub(super) fn run(
    kernel: Kernel,
    [l1, l2, l3]: &[PackedI8; 3],
    x0: &[u8],
    h: usize,
    w: usize,
    res: Residual<'_>,
) {
    let (c1, c2, c3) = (l1.ocp, l2.ocp, l3.ocp);
    let (rl1, rl2, rl3) = ((w + 2) * c1, (w + 2) * c2, w * c3);
    let cap = window_rows(rl1, rl2);
    let (pad1, pad2) = (pad_byte(l2.q_in), pad_byte(l3.q_in));
    let nb = bands(h, rayon::current_num_threads());
    let Residual {
        state,
        state_ch,
        hf,
        r0,
        qs,
        qr,
    } = res;
    assert!(state.len() >= state_ch * hf * w && r0 + h <= hf && state_ch <= c3);
    assert!(x0.len() >= (h + 2) * (w + 2) * l1.cin4);
    let sp = StatePtr(state.as_mut_ptr());
    thread_local! {
        static A1: std::cell::RefCell<Vec<u8>> = const { std::cell::RefCell::new(Vec::new()) };
        static A2: std::cell::RefCell<Vec<u8>> = const { std::cell::RefCell::new(Vec::new()) };
        static OUT: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
        static WIN: std::cell::RefCell<Vec<i16>> = const { std::cell::RefCell::new(Vec::new()) };
    }
    let win_len = if kernel == Kernel::Avx2 {
        super::kernels::avx2_window_len(l1.cin4.max(l2.cin4).max(l3.cin4))
    } else {
        0
    };
    (0..nb).into_par_iter().for_each(|k| {
        let (b0, b1) = (k * h / nb, (k + 1) * h / nb);
        crate::with_scratch(&A1, cap * rl1, |a1| {
            crate::with_scratch(&A2, cap * rl2, |a2| {
                crate::with_scratch(&OUT, rl3, |orow| {
                    crate::with_scratch(&WIN, win_len, |win| {
                        let mut w1 = Window::new(a1, rl1, (c1, pad1), b0.saturating_sub(1));
                        let mut w2 = Window::new(a2, rl2, (c2, pad2), b0);
                        let (mut next1, mut next2) = (w1.first, b0);
                        let step = cap - 4;
                        let mut r = b0;
                        while r < b1 {
                            // output rows r..re, each layer's rows for them
                            // in turn (its weights stay in L1 over the run)
                            let re = (r + step).min(b1);
                            // the second activation's last padded row they
                            // read, and the first activation's that it reads
                            let t2 = re + 1;
                            let t1 = t2.min(h) + 1;
                            let keep1 = next2.saturating_sub(1);
                            while next1 <= t1 {
                                let q = next1;
                                if q == 0 || q == h + 1 {
                                    w1.push_border(keep1);
                                } else {
                                    let o = w1.push_row(keep1);
                                    conv_row(
                                        kernel,
                                        l1,
                                        x0,
                                        l1.cin4,
                                        w,
                                        q - 1,
                                        win,
                                        &mut |_, x, g0, t| {
                                            epilogue_bytes(kernel, l1, l2.q_in, x, g0, t, o)
                                        },
                                    );
                                }
                                next1 += 1;
                            }
                            while next2 <= t2 {
                                let pr = next2;
                                if pr == 0 || pr == h + 1 {
                                    w2.push_border(r);
                                } else {
                                    let (src, lr) = w1.rows(pr - 1);
                                    let o = w2.push_row(r);
                                    conv_row(
                                        kernel,
                                        l2,
                                        src,
                                        c1,
                                        w,
                                        lr,
                                        win,
                                        &mut |_, x, g0, t| {
                                            epilogue_bytes(kernel, l2, l3.q_in, x, g0, t, o)
                                        },
                                    );
                                }
                                next2 += 1;
                            }
                            for rr in r..re {
                                let (src, lr) = w2.rows(rr);
                                conv_row(kernel, l3, src, c2, w, lr, win, &mut |_, x, g0, t| {
                                    epilogue_floats(kernel, l3, x, g0, t, orow)
                                });
                                // the residual on the row's state, channel by
                                // channel, as the layer-by-layer pass adds it
                                for ch in 0..state_ch {
                                    // SAFETY: row r0 + rr of channel ch is
                                    // inside the state (asserted above); only
                                    // this band has output row rr, and nothing
                                    // else touches the state during the pass
                                    // (`StatePtr`).
                                    let row = unsafe { sp.row((ch * hf + r0 + rr) * w, w) };
                                    residual_row(kernel, row, orow, (c3, ch), qs, qr);
                                }
                            }
                            r = re;
                        }
                    })
                })
            })
        })
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_window_keeps_the_rows_still_read() {
        let mut buf = vec![0u8; 4 * 2];
        let mut w = Window::new(&mut buf, 2, (1, 0), 5);
        for v in 5..12u8 {
            w.push((v as usize).saturating_sub(2).max(5)).fill(v);
            if w.len >= 3 {
                let (b, lr) = w.rows(v as usize - 2);
                assert_eq!(&b[lr * 2..lr * 2 + 6], &[v - 2, v - 2, v - 1, v - 1, v, v]);
            }
        }
    }

    #[test]
    fn bands_fill_the_threads_and_keep_16_rows_beyond() {
        for h in 1..200 {
            for t in 1..9 {
                let nb = bands(h, t);
                assert!(
                    (1..=h).contains(&nb) && nb <= 2 * t,
                    "h {h}, {t} threads: {nb}"
                );
                assert!(nb >= t.min(h), "h {h}, {t} threads: {nb} bands");
                assert!(nb <= t || h / nb >= 16, "h {h}, {t} threads: {nb} bands");
            }
        }
    }
}
