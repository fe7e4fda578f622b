//! Isotropic power-law ("1/f^beta") Gaussian noise on a 3-D grid by spectral
//! synthesis (Reiser and Nishikawa 2010 use beta ~ 3 for breast texture):
//! complex white noise, filtered by `|k|^(-beta/2)`, inverse FFT, real part,
//! scaled to zero mean and unit variance. The field is periodic over the grid,
//! which is padded to FFT-friendly sizes beyond the breast.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;
use rustfft::{num_complex::Complex, FftPlanner};

/// A real noise field, `x` fastest, then `y`, then `z`.
pub(crate) struct NoiseField {
    pub dims: [usize; 3],
    pub data: Vec<f32>,
}

fn good_size(n: usize) -> usize {
    let mut m = n.max(1);
    loop {
        let mut r = m;
        for p in [2, 3, 5] {
            while r.is_multiple_of(p) {
                r /= p;
            }
        }
        if r == 1 {
            return m;
        }
        m += 1;
    }
}

/// Inverse FFT along one axis of a `dims` complex array stored x fastest.
fn ifft_axis(buf: &mut [Complex<f32>], dims: [usize; 3], axis: usize) {
    let n = dims[axis];
    let fft = FftPlanner::<f32>::new().plan_fft_inverse(n);
    match axis {
        0 => buf.par_chunks_mut(n).for_each(|line| fft.process(line)),
        1 => buf.par_chunks_mut(dims[0] * dims[1]).for_each(|plane| {
            let mut line = vec![Complex::default(); n];
            for x in 0..dims[0] {
                for (y, v) in line.iter_mut().enumerate() {
                    *v = plane[y * dims[0] + x];
                }
                fft.process(&mut line);
                for (y, v) in line.iter().enumerate() {
                    plane[y * dims[0] + x] = *v;
                }
            }
        }),
        _ => {
            // Gather z-lines for one y row at a time (x contiguous inside).
            let plane = dims[0] * dims[1];
            let rows: Vec<Vec<Complex<f32>>> = (0..dims[1])
                .into_par_iter()
                .map(|y| {
                    let mut block = vec![Complex::default(); dims[0] * n];
                    for z in 0..n {
                        let s = z * plane + y * dims[0];
                        block[z * dims[0]..(z + 1) * dims[0]].copy_from_slice(&buf[s..s + dims[0]]);
                    }
                    let mut line = vec![Complex::default(); n];
                    for x in 0..dims[0] {
                        for z in 0..n {
                            line[z] = block[z * dims[0] + x];
                        }
                        fft.process(&mut line);
                        for z in 0..n {
                            block[z * dims[0] + x] = line[z];
                        }
                    }
                    block
                })
                .collect();
            for (y, block) in rows.iter().enumerate() {
                for z in 0..n {
                    let s = z * plane + y * dims[0];
                    buf[s..s + dims[0]].copy_from_slice(&block[z * dims[0]..(z + 1) * dims[0]]);
                }
            }
        }
    }
}

/// Unit-variance power-law noise covering at least `min_dims` points of
/// spacing `spacing_mm`, reproducible from `seed`.
pub(crate) fn power_law(min_dims: [usize; 3], spacing_mm: f64, beta: f64, seed: u64) -> NoiseField {
    let dims = min_dims.map(|n| good_size(n + 8));
    let n: usize = dims.iter().product();
    // White noise per z-plane from its own stream: reproducible and parallel.
    let plane = dims[0] * dims[1];
    let mut buf = vec![Complex::<f32>::default(); n];
    buf.par_chunks_mut(plane).enumerate().for_each(|(z, p)| {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(z as u64);
        for v in p.iter_mut() {
            let re: f32 = StandardNormal.sample(&mut rng);
            let im: f32 = StandardNormal.sample(&mut rng);
            *v = Complex::new(re, im);
        }
    });
    // Spectral filter |k|^(-beta/2), no DC; k in cycles/mm.
    let freq = |i: usize, m: usize| -> f64 {
        let s = if i <= m / 2 {
            i as f64
        } else {
            i as f64 - m as f64
        };
        s / (m as f64 * spacing_mm)
    };
    buf.par_chunks_mut(plane).enumerate().for_each(|(z, p)| {
        let kz = freq(z, dims[2]);
        for y in 0..dims[1] {
            let ky = freq(y, dims[1]);
            for x in 0..dims[0] {
                let kx = freq(x, dims[0]);
                let k2 = kx * kx + ky * ky + kz * kz;
                let a = if k2 > 0.0 { k2.powf(-beta / 4.0) } else { 0.0 };
                p[y * dims[0] + x] *= a as f32;
            }
        }
    });
    for axis in 0..3 {
        ifft_axis(&mut buf, dims, axis);
    }
    let mut data: Vec<f32> = buf.par_iter().map(|c| c.re).collect();
    let mean = data.iter().map(|&v| v as f64).sum::<f64>() / n as f64;
    let var = data.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / n as f64;
    let inv = if var > 0.0 { 1.0 / var.sqrt() } else { 0.0 };
    data.par_iter_mut()
        .for_each(|v| *v = ((*v as f64 - mean) * inv) as f32);
    NoiseField { dims, data }
}

impl NoiseField {
    /// Trilinear interpolation at grid coordinates (in units of the spacing).
    pub fn sample(&self, x: f64, y: f64, z: f64) -> f32 {
        let [nx, ny, nz] = self.dims;
        let clampi = |v: f64, n: usize| -> (usize, f32) {
            let v = v.clamp(0.0, (n - 1) as f64 - 1e-9);
            let i = v.floor() as usize;
            (i, (v - i as f64) as f32)
        };
        let (ix, fx) = clampi(x, nx);
        let (iy, fy) = clampi(y, ny);
        let (iz, fz) = clampi(z, nz);
        let at = |x: usize, y: usize, z: usize| self.data[(z * ny + y) * nx + x];
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let c00 = lerp(at(ix, iy, iz), at(ix + 1, iy, iz), fx);
        let c10 = lerp(at(ix, iy + 1, iz), at(ix + 1, iy + 1, iz), fx);
        let c01 = lerp(at(ix, iy, iz + 1), at(ix + 1, iy, iz + 1), fx);
        let c11 = lerp(at(ix, iy + 1, iz + 1), at(ix + 1, iy + 1, iz + 1), fx);
        lerp(lerp(c00, c10, fy), lerp(c01, c11, fy), fz)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unit_variance_and_reproducible() {
        let a = power_law([20, 12, 10], 1.0, 3.0, 7);
        let b = power_law([20, 12, 10], 1.0, 3.0, 7);
        assert_eq!(a.data, b.data);
        let n = a.data.len() as f64;
        let m = a.data.iter().map(|&v| v as f64).sum::<f64>() / n;
        let v = a.data.iter().map(|&x| (x as f64 - m).powi(2)).sum::<f64>() / n;
        assert!(m.abs() < 1e-5 && (v - 1.0).abs() < 1e-4);
        let c = power_law([20, 12, 10], 1.0, 3.0, 8);
        assert_ne!(a.data, c.data);
    }

    #[test]
    fn spectrum_follows_power_law() {
        // Neighbour correlation grows with beta (smoother fields).
        let corr = |beta: f64| {
            let f = power_law([40, 40, 40], 1.0, beta, 3);
            let [nx, _, _] = f.dims;
            let mut s = 0.0f64;
            for i in 0..f.data.len() - 1 {
                if (i + 1) % nx != 0 {
                    s += (f.data[i] * f.data[i + 1]) as f64;
                }
            }
            s / f.data.len() as f64
        };
        let (c0, c2, c3) = (corr(0.0), corr(2.0), corr(3.0));
        assert!(c0.abs() < 0.05, "white noise correlated: {c0}");
        assert!(c2 > 0.3 && c3 > c2 + 0.2, "beta 2: {c2}, beta 3: {c3}");
    }
}
