//! How well the reconstruction explains the projections it came from
//! (issue #48 point 3, eval/ladder.md "A check that needs no truth"): the
//! reconstructed slices projected again and compared with the log counts
//! they were reconstructed from. A network far from the breasts it was
//! trained on need not fit the data it is given, and this is measurable on
//! every acquisition without the truth (on VICTRE's breasts and most of
//! our anatomical ones the shipped network's residual is twice the largest
//! of its own world's, MLTR's a fifth of it).
//!
//! Per reconstructed slice `d` (rows outside the compressed thickness are
//! air, as the reconstruction sets them), with `g` the measured line
//! integrals `ln(b / max(y, 0.5))` and `P f` the projected slice:
//!
//! * `residual = sqrt(sum (P f - g)^2 / sum g^2)` over every ray of every
//!   reconstructed slice (the ladder's figure);
//! * `noise = sqrt(sum 1 / max(y, 0.5) / sum g^2)`: the part of it that
//!   Poisson noise alone would give, `var ln y = 1 / y` (a count of the
//!   noise-matched or N8 level's statistics);
//! * `excess = sqrt(max(residual^2 - noise^2, 0))`: what the noise does not
//!   explain.
//!
//! Sums in slice order, each slice's on one worker: the figures do not
//! depend on the pool.

use crate::error::PipelineError;
use dbt_intake::SliceHeader;
use dbt_projector::Projector;
use rayon::prelude::*;
use serde::Serialize;

/// The fit of a reconstruction to its projections.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DataFit {
    /// `||P f - g|| / ||g||` over the reconstructed slices.
    pub residual: f64,
    /// The share of it Poisson noise alone gives.
    pub noise: f64,
    /// `sqrt(residual^2 - noise^2)`, 0 where the noise explains it all.
    pub excess: f64,
    /// Slices compared (the reconstructed ones).
    pub slices: usize,
}

/// [`DataFit`] of the stack `mu` (`dims = [columns, rows within the
/// thickness, slices]`, lateral fastest, vertical index 0 on the support)
/// against the checked counts `counts` of `h`, over the slices `slices`.
pub fn data_fit(
    h: &SliceHeader,
    counts: &[Vec<f32>],
    mu: &[f32],
    dims: [usize; 3],
    slices: &[usize],
) -> Result<DataFit, PipelineError> {
    let g = &h.geometry;
    let [cols, nv, nd] = dims;
    let rows = g.image.rows;
    if cols != g.image.columns || nv > rows || nd != counts.len() || mu.len() != cols * nv * nd {
        return Err(PipelineError::Input(format!(
            "data fit: a volume of {dims:?} ({} values) against an image of {cols} x {rows} and {} slices",
            mu.len(),
            counts.len()
        )));
    }
    if let Some(&d) = slices.iter().find(|&&d| d >= nd) {
        return Err(PipelineError::Input(format!("data fit: slice {d} of {nd}")));
    }
    let proj = Projector::new(g);
    let b = h.flux;
    let per_slice = slices
        .par_iter()
        .map(|&d| -> Result<[f64; 3], PipelineError> {
            let mut img = vec![0f32; rows * cols];
            for v in 0..nv {
                let r = rows - 1 - v;
                let src = (d * nv + v) * cols;
                img[r * cols..(r + 1) * cols].copy_from_slice(&mu[src..src + cols]);
            }
            let mut sino = vec![0f32; g.n_rays()];
            proj.forward(&img, &mut sino)
                .map_err(|e| PipelineError::Input(format!("data fit, slice {d}: {e}")))?;
            let (mut num, mut den, mut var) = (0.0, 0.0, 0.0);
            for (&p, &y) in sino.iter().zip(&counts[d]) {
                let y = f64::from(y).max(0.5);
                let m = (b / y).ln();
                num += (f64::from(p) - m).powi(2);
                den += m * m;
                var += 1.0 / y;
            }
            Ok([num, den, var])
        })
        .collect::<Result<Vec<_>, _>>()?;
    let [num, den, var] = per_slice
        .iter()
        .fold([0.0; 3], |a, s| [a[0] + s[0], a[1] + s[1], a[2] + s[2]]);
    let den = den.max(1e-300);
    let (residual, noise) = ((num / den).sqrt(), (var / den).sqrt());
    Ok(DataFit {
        residual,
        noise,
        excess: (residual * residual - noise * noise).max(0.0).sqrt(),
        slices: slices.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(slices: usize) -> SliceHeader {
        let g = dbt_geometry::Geometry::paper().binned(4).unwrap();
        let mut h = crate::acquisition::example_header(g.clone(), slices, None);
        h.slice_spacing_mm = g.image.pixel_mm;
        SliceHeader::try_from(h).unwrap()
    }

    /// Noise-free counts of a stack fit it exactly (residual 0 up to the
    /// counts' f32); a stack that is not the one projected does not; the
    /// noise share is `sqrt(sum 1/y / sum g^2)` of the counts.
    #[test]
    fn a_volume_fits_its_own_noise_free_projections_and_no_other() {
        let h = header(2);
        let g = &h.geometry;
        let (cols, rows) = (g.image.columns, g.image.rows);
        let nv = g.rows_within_thickness(h.thickness_mm);
        let mut mu = vec![0f32; cols * nv * 2];
        for d in 0..2 {
            for v in 0..nv {
                for c in cols / 4..3 * cols / 4 {
                    mu[(d * nv + v) * cols + c] = 0.05 + 0.01 * d as f32;
                }
            }
        }
        let proj = Projector::new(g);
        let counts: Vec<Vec<f32>> = (0..2)
            .map(|d| {
                let mut img = vec![0f32; rows * cols];
                for v in 0..nv {
                    let r = rows - 1 - v;
                    img[r * cols..(r + 1) * cols]
                        .copy_from_slice(&mu[(d * nv + v) * cols..(d * nv + v + 1) * cols]);
                }
                let mut s = vec![0f32; g.n_rays()];
                proj.forward(&img, &mut s).unwrap();
                s.iter()
                    .map(|&p| (h.flux * (-f64::from(p)).exp()) as f32)
                    .collect()
            })
            .collect();
        let fit = data_fit(&h, &counts, &mu, [cols, nv, 2], &[0, 1]).unwrap();
        assert!(fit.residual < 1e-5, "{fit:?}");
        let (var, den): (f64, f64) = counts
            .iter()
            .flatten()
            .map(|&y| {
                let m = (h.flux / f64::from(y).max(0.5)).ln();
                (1.0 / f64::from(y).max(0.5), m * m)
            })
            .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
        assert!((fit.noise - (var / den).sqrt()).abs() < 1e-12);
        assert_eq!(fit.excess, 0.0);
        // Another breast: 20 % denser everywhere.
        let other: Vec<f32> = mu.iter().map(|m| m * 1.2).collect();
        let off = data_fit(&h, &counts, &other, [cols, nv, 2], &[0, 1]).unwrap();
        assert!((off.residual - 0.2).abs() < 0.01, "{off:?}");
        assert!(off.excess > 0.19);
        // Only the slices asked for.
        let one = data_fit(&h, &counts, &other, [cols, nv, 2], &[1]).unwrap();
        assert_eq!(one.slices, 1);
        assert!(data_fit(&h, &counts, &other, [cols, nv, 2], &[2]).is_err());
        assert!(data_fit(&h, &counts, &other[1..], [cols, nv, 2], &[0]).is_err());
    }
}
