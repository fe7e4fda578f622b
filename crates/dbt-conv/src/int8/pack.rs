//! Packing a quantized convolution for the VNNI kernel: weights in
//! `[tap][cin4 / 4][ocp][4]` bytes, per-channel scales, biases and
//! zero-point corrections.

use super::*;

#[derive(Clone, Debug)]
pub(super) struct PackedI8 {
    pub(super) cin: usize,
    /// `cin` rounded up to 4 (bytes per pixel of the input buffer's used part).
    pub(super) cin4: usize,
    pub(super) ocp: usize,
    /// `[tap][cin4 / 4][ocp][4]`.
    pub(super) w: Vec<i8>,
    /// `w` widened to i16, same order: the AVX2 kernel's operands
    /// (`vpmaddwd` sums pairs of i16 products exactly, where `vpmaddubsw`
    /// on the bytes would saturate).
    pub(super) w16: Vec<i16>,
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

pub(super) fn pack(l: &Int8Conv, q_in: QuantParams) -> PackedI8 {
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
    let w16 = w.iter().map(|&v| i16::from(v)).collect();
    PackedI8 {
        cin: l.in_ch,
        cin4,
        ocp,
        w,
        w16,
        scale,
        corr,
        bias,
        slope,
        q_out: l.q_out,
        q_in,
    }
}
