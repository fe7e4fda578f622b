//! Packing a quantized convolution for the VNNI kernel: weights in
//! `[tap][cin4 / 4][ocp][4]` bytes, per-channel scales, biases and
//! zero-point corrections.

use super::*;

/// A value the packed weights are made of: any bit pattern is one.
pub(super) trait Plain: Copy + Default {}
impl Plain for i8 {}
impl Plain for i16 {}

/// One 64-byte line of packed weights, aligned to 64 bytes.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct Line([u8; 64]);

/// Packed weights on 64-byte aligned storage, so that every vector load of
/// the kernels is aligned (LLVM's generic AVX2 code splits an unaligned
/// 32-byte load into two halves and an insert).
#[derive(Clone, Debug)]
pub(super) struct Aligned<T: Plain> {
    lines: Vec<Line>,
    len: usize,
    _t: std::marker::PhantomData<T>,
}

impl<T: Plain> Aligned<T> {
    /// `v`'s values on aligned storage.
    pub(super) fn from_slice(v: &[T]) -> Self {
        let bytes = std::mem::size_of_val(v);
        let mut a = Self {
            lines: vec![Line([0; 64]); bytes.div_ceil(64)],
            len: v.len(),
            _t: std::marker::PhantomData,
        };
        let dst: &mut [T] = &mut a;
        dst.copy_from_slice(v);
        a
    }
}

impl<T: Plain> std::ops::Deref for Aligned<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        // SAFETY: `lines` holds at least `len * size_of::<T>()` initialised
        // bytes, aligned to 64 (more than `T`'s alignment), and any bit
        // pattern is a `T` (`Plain`).
        unsafe { std::slice::from_raw_parts(self.lines.as_ptr() as *const T, self.len) }
    }
}

impl<T: Plain> std::ops::DerefMut for Aligned<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        // SAFETY: as in `deref`, borrowed uniquely through `&mut self`.
        unsafe { std::slice::from_raw_parts_mut(self.lines.as_mut_ptr() as *mut T, self.len) }
    }
}

#[derive(Clone, Debug)]
pub(super) struct PackedI8 {
    pub(super) cin: usize,
    /// `cin` rounded up to 4 (bytes per pixel of the input buffer's used part).
    pub(super) cin4: usize,
    pub(super) ocp: usize,
    /// `[tap][cin4 / 4][ocp][4]`.
    pub(super) w: Aligned<i8>,
    /// `w` widened to i16 and packed by pairs of input channels,
    /// `[tap][cin4 / 2][ocp][2]`: the AVX2 kernel's operands (`vpmaddwd`
    /// sums pairs of i16 products exactly, where `vpmaddubsw` on the bytes
    /// would saturate).
    pub(super) w16: Aligned<i16>,
    /// The weights transformed for the AVX2 and AVX-VNNI kernels' Winograd
    /// convolution
    /// (`[pos][cin4 / 2][ocp][2]`, [`super::winograd`]), where it was asked
    /// for and pays ([`super::winograd::eligible`]).
    pub(super) wino: Option<Aligned<i16>>,
    /// For thin inputs (`3 * cin4 <= 64`), the weights of each kernel row
    /// with its three taps side by side, `[dy][3 * cin4 / 4][ocp][4]` (byte
    /// `dx * cin4 + c` of a row's 4-byte groups): the AMX kernel's operand
    /// where the input's pixels are `cin4` bytes apart, so that one tile
    /// row of `3 * cin4` bytes holds a pixel's three horizontal taps
    /// ([`super::amx`]; three products per 16 pixels instead of nine).
    pub(super) w_rows: Option<Aligned<i8>>,
    /// `sx * sw[o]`, 0 on padded lanes.
    pub(super) scale: Vec<f32>,
    /// `(128 + zx) * sum qw[o]`.
    pub(super) corr: Vec<i32>,
    pub(super) bias: Vec<f32>,
    pub(super) slope: Vec<f32>,
    pub(super) q_out: Option<QuantParams>,
    /// The input's quantization (the byte of real 0 is `128 + zp`).
    pub(super) q_in: QuantParams,
}

/// `l` packed; with `winograd`, also its Winograd weights where that pays.
pub(super) fn pack(l: &Int8Conv, q_in: QuantParams, winograd: bool) -> PackedI8 {
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
    // [tap][g][o][4] -> [tap][2g + e / 2][o][e % 2]
    let mut w16 = vec![0i16; w.len()];
    for (k, &v) in w.iter().enumerate() {
        let (e, o, g, t) = (
            k % 4,
            (k / 4) % ocp,
            (k / 4 / ocp) % (cin4 / 4),
            k / 4 / ocp / (cin4 / 4),
        );
        w16[((t * (cin4 / 2) + 2 * g + e / 2) * ocp + o) * 2 + e % 2] = i16::from(v);
    }
    PackedI8 {
        cin: l.in_ch,
        cin4,
        ocp,
        w: Aligned::from_slice(&w),
        wino: (winograd && super::winograd::eligible(cin4))
            .then(|| Aligned::from_slice(&super::winograd::transform_weights(&w16, cin4, ocp))),
        w16: Aligned::from_slice(&w16),
        w_rows: (3 * cin4 <= 64).then(|| Aligned::from_slice(&rows_of_taps(&w, cin4, ocp))),
        scale,
        corr,
        bias,
        slope,
        q_out: l.q_out,
        q_in,
    }
}

/// `w` (`[tap][cin4 / 4][ocp][4]`) as `[dy][3 * cin4 / 4][ocp][4]`, the
/// three taps of kernel row `dy` side by side: byte `j = dx * cin4 + c` of
/// the row's `3 * cin4` holds tap `(dy, dx)`'s weight of input channel `c`
/// ([`PackedI8::w_rows`]).
pub(super) fn rows_of_taps(w: &[i8], cin4: usize, ocp: usize) -> Vec<i8> {
    let k = 3 * cin4;
    let mut r = vec![0i8; 3 * k * ocp];
    for dy in 0..3 {
        for j in 0..k {
            let (dx, c) = (j / cin4, j % cin4);
            let t = dy * 3 + dx;
            for o in 0..ocp {
                r[((dy * (k / 4) + j / 4) * ocp + o) * 4 + j % 4] =
                    w[((t * (cin4 / 4) + c / 4) * ocp + o) * 4 + c % 4];
            }
        }
    }
    r
}
