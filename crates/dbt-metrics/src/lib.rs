//! The paper's image metrics, with scikit-image's conventions so that our
//! numbers can be checked against `skimage.metrics` on the same images:
//! * [`mse`]: the paper's "L2 loss", the mean squared error over all pixels;
//! * [`psnr`]: `10 log10(R^2 / MSE)` with `R` the data range;
//! * [`ssim`]: Wang et al. 2004 with skimage's defaults: 7x7 uniform window,
//!   sample covariance (`N / (N - 1)`), `K1 = 0.01`, `K2 = 0.03`, averaged over
//!   the pixels whose window lies inside the image.
//!
//! The evaluation uses attenuation in 1/cm and `R = max - min` of the ground
//! truth, which reproduces the scale of the paper's tables (see
//! `eval/README.md`). Sums are in `f64`.

use thiserror::Error;

/// Metric input errors.
#[derive(Debug, Error, PartialEq)]
pub enum MetricError {
    /// The two images differ in size or do not match the stated shape.
    #[error("images must both have {expected} pixels ({rows} x {cols}); got {a} and {b}")]
    Shape {
        /// Rows of the stated shape.
        rows: usize,
        /// Columns of the stated shape.
        cols: usize,
        /// Expected pixel count.
        expected: usize,
        /// Length of the first image.
        a: usize,
        /// Length of the second image.
        b: usize,
    },
    /// The image is smaller than the SSIM window.
    #[error("SSIM needs at least 7 x 7 pixels, got {0} x {1}")]
    TooSmall(usize, usize),
    /// A non-positive or non-finite data range.
    #[error("data range {0} must be positive and finite")]
    Range(f64),
}

/// Shape of a row-major image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shape {
    /// Rows.
    pub rows: usize,
    /// Columns.
    pub cols: usize,
}

fn check(shape: Shape, a: &[f32], b: &[f32]) -> Result<(), MetricError> {
    let expected = shape.rows * shape.cols;
    if a.len() != expected || b.len() != expected {
        return Err(MetricError::Shape {
            rows: shape.rows,
            cols: shape.cols,
            expected,
            a: a.len(),
            b: b.len(),
        });
    }
    Ok(())
}

/// Mean squared error (the paper's L2 loss).
pub fn mse(truth: &[f32], test: &[f32]) -> f64 {
    let n = truth.len().max(1) as f64;
    truth
        .iter()
        .zip(test)
        .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
        .sum::<f64>()
        / n
}

/// `max - min` of an image.
pub fn data_range(img: &[f32]) -> f64 {
    let (lo, hi) = img.iter().fold((f64::MAX, f64::MIN), |(l, h), &v| {
        (l.min(v as f64), h.max(v as f64))
    });
    hi - lo
}

/// Peak signal-to-noise ratio in dB; infinite for identical images.
pub fn psnr(truth: &[f32], test: &[f32], range: f64) -> Result<f64, MetricError> {
    if !(range.is_finite() && range > 0.0) {
        return Err(MetricError::Range(range));
    }
    Ok(10.0 * (range * range / mse(truth, test)).log10())
}

const WIN: usize = 7;

/// Mean structural similarity (skimage defaults, see the crate docs).
pub fn ssim(shape: Shape, a: &[f32], b: &[f32], range: f64) -> Result<f64, MetricError> {
    check(shape, a, b)?;
    if !(range.is_finite() && range > 0.0) {
        return Err(MetricError::Range(range));
    }
    let Shape { rows, cols } = shape;
    if rows < WIN || cols < WIN {
        return Err(MetricError::TooSmall(rows, cols));
    }
    // Summed-area tables of a, b, a^2, b^2, ab.
    let w = cols + 1;
    let mut sat = vec![[0f64; 5]; (rows + 1) * w];
    for r in 0..rows {
        let mut run = [0f64; 5];
        for c in 0..cols {
            let (x, y) = (a[r * cols + c] as f64, b[r * cols + c] as f64);
            let v = [x, y, x * x, y * y, x * y];
            for k in 0..5 {
                run[k] += v[k];
                sat[(r + 1) * w + c + 1][k] = sat[r * w + c + 1][k] + run[k];
            }
        }
    }
    let np = (WIN * WIN) as f64;
    let cov_norm = np / (np - 1.0);
    let c1 = (0.01 * range).powi(2);
    let c2 = (0.03 * range).powi(2);
    let half = WIN / 2;
    let mut total = 0f64;
    let mut count = 0usize;
    for r in half..rows - half {
        for c in half..cols - half {
            let (r0, r1, c0, c1i) = (r - half, r + half + 1, c - half, c + half + 1);
            let mut m = [0f64; 5];
            for (k, mk) in m.iter_mut().enumerate() {
                *mk = (sat[r1 * w + c1i][k] - sat[r0 * w + c1i][k] - sat[r1 * w + c0][k]
                    + sat[r0 * w + c0][k])
                    / np;
            }
            let (ux, uy) = (m[0], m[1]);
            let vx = cov_norm * (m[2] - ux * ux);
            let vy = cov_norm * (m[3] - uy * uy);
            let vxy = cov_norm * (m[4] - ux * uy);
            let s = ((2.0 * ux * uy + c1) * (2.0 * vxy + c2))
                / ((ux * ux + uy * uy + c1) * (vx + vy + c2));
            total += s;
            count += 1;
        }
    }
    Ok(total / count as f64)
}

/// L2 (MSE), SSIM and PSNR of one image against its ground truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageScores {
    /// Mean squared error.
    pub l2: f64,
    /// Mean SSIM.
    pub ssim: f64,
    /// PSNR, dB.
    pub psnr: f64,
}

/// All three metrics, with the data range of the ground truth.
pub fn score(shape: Shape, truth: &[f32], test: &[f32]) -> Result<ImageScores, MetricError> {
    check(shape, truth, test)?;
    let range = data_range(truth);
    Ok(ImageScores {
        l2: mse(truth, test),
        ssim: ssim(shape, truth, test, range)?,
        psnr: psnr(truth, test, range)?,
    })
}

/// Mean and sample standard deviation.
pub fn mean_sd(values: &[f64]) -> (f64, f64) {
    let n = values.len();
    if n == 0 {
        return (f64::NAN, f64::NAN);
    }
    let m = values.iter().sum::<f64>() / n as f64;
    if n == 1 {
        return (m, 0.0);
    }
    let v = values.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1) as f64;
    (m, v.sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_images() {
        let s = Shape { rows: 9, cols: 11 };
        let a: Vec<f32> = (0..99).map(|i| (i % 7) as f32).collect();
        assert_eq!(ssim(s, &a, &a, 6.0).unwrap(), 1.0);
        assert_eq!(mse(&a, &a), 0.0);
        assert!(psnr(&a, &a, 6.0).unwrap().is_infinite());
    }

    #[test]
    fn known_values() {
        // Constant offset 0.1 on a range of 1: MSE 0.01, PSNR 20 dB.
        let a = vec![0.5f32; 64];
        let b = vec![0.6f32; 64];
        assert!((mse(&a, &b) - 0.01).abs() < 1e-7);
        assert!((psnr(&a, &b, 1.0).unwrap() - 20.0).abs() < 1e-5);
        // Constant images: SSIM reduces to the luminance term.
        let s = ssim(Shape { rows: 8, cols: 8 }, &a, &b, 1.0).unwrap();
        let c1 = 1e-4;
        let want = (2.0 * 0.5 * 0.6 + c1) / (0.25 + 0.36 + c1);
        assert!((s - want).abs() < 1e-6, "{s} vs {want}");
    }

    #[test]
    fn errors() {
        let s = Shape { rows: 8, cols: 8 };
        assert!(matches!(
            ssim(s, &[0.0; 64], &[0.0; 63], 1.0),
            Err(MetricError::Shape { .. })
        ));
        assert_eq!(
            ssim(Shape { rows: 6, cols: 8 }, &[0.0; 48], &[0.0; 48], 1.0),
            Err(MetricError::TooSmall(6, 8))
        );
        assert_eq!(psnr(&[0.0], &[1.0], 0.0), Err(MetricError::Range(0.0)));
        assert_eq!(mean_sd(&[1.0, 3.0]), (2.0, 2f64.sqrt()));
    }
}
