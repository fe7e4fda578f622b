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
    Ok(ssim_map(shape, a, b, range)?.mean())
}

/// Summed-area table of `K` per-pixel quantities, `(rows + 1) x (cols + 1)`.
fn summed_area<const K: usize>(
    rows: usize,
    cols: usize,
    at: impl Fn(usize) -> [f64; K],
) -> Vec<[f64; K]> {
    let w = cols + 1;
    let mut sat = vec![[0f64; K]; (rows + 1) * w];
    for r in 0..rows {
        let mut run = [0f64; K];
        for c in 0..cols {
            let v = at(r * cols + c);
            for k in 0..K {
                run[k] += v[k];
                sat[(r + 1) * w + c + 1][k] = sat[r * w + c + 1][k] + run[k];
            }
        }
    }
    sat
}

/// Sums over the 7 x 7 window centred at `(r, c)` of a summed-area table of
/// an image `cols` wide.
fn window_sum<const K: usize>(sat: &[[f64; K]], cols: usize, r: usize, c: usize) -> [f64; K] {
    let (w, half) = (cols + 1, WIN / 2);
    let (r0, r1, c0, c1) = (r - half, r + half + 1, c - half, c + half + 1);
    let mut m = [0f64; K];
    for (k, mk) in m.iter_mut().enumerate() {
        *mk = sat[r1 * w + c1][k] - sat[r0 * w + c1][k] - sat[r1 * w + c0][k] + sat[r0 * w + c0][k];
    }
    m
}

/// The local SSIM of every pixel whose 7 x 7 window lies inside the image
/// (skimage's `full=True` map, cropped to those pixels as its mean is).
#[derive(Debug, Clone, PartialEq)]
pub struct SsimMap {
    /// Rows of the map: `rows - 6`.
    pub rows: usize,
    /// Columns of the map: `cols - 6`.
    pub cols: usize,
    /// Row-major; entry `(i, j)` is the window centred at image pixel
    /// `(i + 3, j + 3)`.
    pub values: Vec<f64>,
}

impl SsimMap {
    /// The mean SSIM ([`ssim`]).
    pub fn mean(&self) -> f64 {
        self.values.iter().sum::<f64>() / self.values.len() as f64
    }

    /// The shape of the image the map was computed on.
    pub fn image_shape(&self) -> Shape {
        Shape {
            rows: self.rows + WIN - 1,
            cols: self.cols + WIN - 1,
        }
    }
}

/// The local SSIM map (skimage defaults, see the crate docs); [`ssim`] is
/// its mean.
pub fn ssim_map(shape: Shape, a: &[f32], b: &[f32], range: f64) -> Result<SsimMap, MetricError> {
    check(shape, a, b)?;
    if !(range.is_finite() && range > 0.0) {
        return Err(MetricError::Range(range));
    }
    let Shape { rows, cols } = shape;
    if rows < WIN || cols < WIN {
        return Err(MetricError::TooSmall(rows, cols));
    }
    // Summed-area tables of a, b, a^2, b^2, ab.
    let sat = summed_area(rows, cols, |i| {
        let (x, y) = (a[i] as f64, b[i] as f64);
        [x, y, x * x, y * y, x * y]
    });
    let np = (WIN * WIN) as f64;
    let cov_norm = np / (np - 1.0);
    let c1 = (0.01 * range).powi(2);
    let c2 = (0.03 * range).powi(2);
    let half = WIN / 2;
    let mut values = Vec::with_capacity((rows - 2 * half) * (cols - 2 * half));
    for r in half..rows - half {
        for c in half..cols - half {
            let m = window_sum(&sat, cols, r, c).map(|v| v / np);
            let (ux, uy) = (m[0], m[1]);
            let vx = cov_norm * (m[2] - ux * ux);
            let vy = cov_norm * (m[3] - uy * uy);
            let vxy = cov_norm * (m[4] - ux * uy);
            values.push(
                ((2.0 * ux * uy + c1) * (2.0 * vxy + c2))
                    / ((ux * ux + uy * uy + c1) * (vx + vy + c2)),
            );
        }
    }
    Ok(SsimMap {
        rows: rows - 2 * half,
        cols: cols - 2 * half,
        values,
    })
}

/// Mean local SSIM over one kind of window, and the share of the map's
/// windows of that kind; `mean` is NaN where there are none.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegionSsim {
    /// Mean of the local SSIM over these windows.
    pub mean: f64,
    /// Their share of all windows of the map.
    pub share: f64,
}

/// Where the SSIM is lost: the map's windows split by what the ground truth
/// holds under them. `inside`: all 49 pixels are tissue (the breast's
/// interior structure); `air`: none is; `outline`: the rest, the windows
/// across the skin line. The whole-image SSIM is the share-weighted sum.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SsimRegions {
    /// Windows wholly inside the breast.
    pub inside: RegionSsim,
    /// Windows across its outline.
    pub outline: RegionSsim,
    /// Windows wholly in air.
    pub air: RegionSsim,
}

/// [`ssim_map`] split by the windows' content of `tissue` (one flag per
/// pixel of the map's image, normally `truth > 0`).
pub fn ssim_regions(map: &SsimMap, tissue: &[bool]) -> Result<SsimRegions, MetricError> {
    let shape = map.image_shape();
    let expected = shape.rows * shape.cols;
    if tissue.len() != expected {
        return Err(MetricError::Shape {
            rows: shape.rows,
            cols: shape.cols,
            expected,
            a: tissue.len(),
            b: expected,
        });
    }
    let sat = summed_area(shape.rows, shape.cols, |i| [f64::from(u8::from(tissue[i]))]);
    let half = WIN / 2;
    // [sum, count] of inside, outline, air
    let mut acc = [[0f64; 2]; 3];
    for i in 0..map.rows {
        for j in 0..map.cols {
            let n = window_sum(&sat, shape.cols, i + half, j + half)[0] as usize;
            let k = match n {
                0 => 2,
                n if n == WIN * WIN => 0,
                _ => 1,
            };
            acc[k][0] += map.values[i * map.cols + j];
            acc[k][1] += 1.0;
        }
    }
    let total = map.values.len() as f64;
    let region = |k: usize| RegionSsim {
        mean: if acc[k][1] > 0.0 {
            acc[k][0] / acc[k][1]
        } else {
            f64::NAN
        },
        share: acc[k][1] / total,
    };
    Ok(SsimRegions {
        inside: region(0),
        outline: region(1),
        air: region(2),
    })
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
    /// The SSIM split by region of the ground truth (tissue = `truth > 0`).
    pub ssim_regions: SsimRegions,
}

/// All three metrics, with the data range of the ground truth, and the SSIM
/// by region ([`ssim_regions`], tissue where the truth is above zero).
pub fn score(shape: Shape, truth: &[f32], test: &[f32]) -> Result<ImageScores, MetricError> {
    check(shape, truth, test)?;
    let range = data_range(truth);
    let map = ssim_map(shape, truth, test, range)?;
    let tissue: Vec<bool> = truth.iter().map(|&v| v > 0.0).collect();
    Ok(ImageScores {
        l2: mse(truth, test),
        ssim: map.mean(),
        psnr: psnr(truth, test, range)?,
        ssim_regions: ssim_regions(&map, &tissue)?,
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

    /// A 7-row image whose left 10 columns are tissue: the 14 window centres
    /// (columns 3..=16) split into 4 wholly inside (3..=6), 6 across the
    /// edge and 4 wholly in air (13..=16); the share-weighted region means
    /// give back the mean SSIM.
    #[test]
    fn regions_split_the_windows_by_the_truth() {
        let shape = Shape { rows: 7, cols: 20 };
        let truth: Vec<f32> = (0..140)
            .map(|i| {
                if i % 20 < 10 {
                    0.5 + 0.01 * (i % 3) as f32
                } else {
                    0.0
                }
            })
            .collect();
        let test: Vec<f32> = truth
            .iter()
            .enumerate()
            .map(|(i, v)| v + 0.02 * ((i * 7) % 5) as f32)
            .collect();
        let tissue: Vec<bool> = truth.iter().map(|&v| v > 0.0).collect();
        let map = ssim_map(shape, &truth, &test, 0.52).unwrap();
        assert_eq!((map.rows, map.cols), (1, 14));
        assert_eq!(map.image_shape(), shape);
        let r = ssim_regions(&map, &tissue).unwrap();
        assert!((r.inside.share - 4.0 / 14.0).abs() < 1e-12);
        assert!((r.outline.share - 6.0 / 14.0).abs() < 1e-12);
        assert!((r.air.share - 4.0 / 14.0).abs() < 1e-12);
        let inside: f64 = map.values[..4].iter().sum::<f64>() / 4.0;
        assert!((r.inside.mean - inside).abs() < 1e-12);
        let whole = ssim(shape, &truth, &test, 0.52).unwrap();
        let weighted = r.inside.mean * r.inside.share
            + r.outline.mean * r.outline.share
            + r.air.mean * r.air.share;
        assert!((whole - weighted).abs() < 1e-12, "{whole} vs {weighted}");
        // No tissue at all: every window is air, the others are empty.
        let r = ssim_regions(&map, &[false; 140]).unwrap();
        assert_eq!(r.air.share, 1.0);
        assert!(r.inside.mean.is_nan() && r.inside.share == 0.0);
        // A tissue mask of the wrong size is refused.
        assert!(matches!(
            ssim_regions(&map, &[false; 139]),
            Err(MetricError::Shape { .. })
        ));
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
