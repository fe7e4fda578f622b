//! MLTR (Nuyts, De Man, Dupont, Defrise, Suetens, Mortelmans 1998, "Iterative
//! reconstruction for helical CT: a simulation study", and the transmission ML
//! algorithm it uses). One iteration, with `yhat_i = b exp(-[P mu]_i)` and
//! `P` restricted to the support `S`:
//!
//! ```text
//! mu_j <- max(0, mu_j + [P*(yhat - y)]_j / [P*(yhat * P 1_S)]_j),   j in S
//! ```
//!
//! i.e. a Newton-like step on a separable surrogate of the Poisson
//! log-likelihood `L = sum_i y_i ln yhat_i - yhat_i`. Pixels outside the support
//! (rows above the compressed thickness) stay 0, as in the paper. No
//! regularisation. Starts from zero.

use crate::{check_len, ReconError};
use dbt_projector::Projector;
use rayon::prelude::*;

/// Options of an MLTR run.
#[derive(Debug, Clone, PartialEq)]
pub struct MltrOptions {
    /// Number of iterations (the paper: 100).
    pub iterations: usize,
    /// Record the Poisson log-likelihood after every iteration (costs one
    /// extra forward projection per iteration).
    pub track_likelihood: bool,
}

impl Default for MltrOptions {
    fn default() -> Self {
        Self {
            iterations: 100,
            track_likelihood: false,
        }
    }
}

/// What an MLTR run did.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MltrReport {
    /// Poisson log-likelihood (up to a constant) of the start image and after
    /// each iteration, when tracked.
    pub log_likelihood: Vec<f64>,
}

fn log_likelihood(y: &[f32], p: &[f32], flux: f64) -> f64 {
    y.par_iter()
        .zip(p.par_iter())
        .map(|(&y, &p)| -(y as f64) * p as f64 - flux * (-(p as f64)).exp())
        .sum()
}

/// Reconstruct attenuation (1/mm, image layout) from counts `y` (view-major)
/// with flux `b` per ray. `support[j]` is non-zero where the image may be
/// non-zero (the thickness mask).
pub fn mltr(
    projector: &Projector,
    counts: &[f32],
    flux: f64,
    support: &[f32],
    options: &MltrOptions,
) -> Result<(Vec<f32>, MltrReport), ReconError> {
    let (n, m) = (projector.domain_len(), projector.range_len());
    check_len("counts", counts.len(), m)?;
    check_len("support", support.len(), n)?;
    if !(flux.is_finite() && flux > 0.0) {
        return Err(ReconError::Data(format!("flux {flux} must be positive")));
    }
    if let Some(i) = counts.iter().position(|c| !c.is_finite() || *c < 0.0) {
        return Err(ReconError::Data(format!("count {} at ray {i}", counts[i])));
    }
    let in_s: Vec<bool> = support.iter().map(|&s| s != 0.0).collect();
    let ones: Vec<f32> = in_s.iter().map(|&s| s as u8 as f32).collect();
    let mut ell = vec![0f32; m];
    projector.forward(&ones, &mut ell)?;

    let mut mu = vec![0f32; n];
    let mut p = vec![0f32; m];
    let mut r1 = vec![0f32; m];
    let mut r2 = vec![0f32; m];
    let mut num = vec![0f32; n];
    let mut den = vec![0f32; n];
    let mut report = MltrReport::default();
    if options.track_likelihood {
        report.log_likelihood.push(log_likelihood(counts, &p, flux));
    }
    for it in 0..options.iterations {
        let _span = tracing::trace_span!("mltr_iteration", it).entered();
        projector.forward(&mu, &mut p)?;
        r1.par_iter_mut()
            .zip(r2.par_iter_mut())
            .zip(p.par_iter().zip(counts.par_iter().zip(ell.par_iter())))
            .for_each(|((a, b), (&pi, (&y, &l)))| {
                let yhat = (flux * (-(pi as f64)).exp()) as f32;
                *a = yhat - y;
                *b = yhat * l;
            });
        projector.adjoint(&r1, &mut num)?;
        projector.adjoint(&r2, &mut den)?;
        mu.par_iter_mut()
            .zip(num.par_iter().zip(den.par_iter()))
            .zip(in_s.par_iter())
            .for_each(|((x, (&a, &d)), &s)| {
                if s && d > 0.0 {
                    *x = (*x + a / d).max(0.0);
                }
            });
        if options.track_likelihood {
            projector.forward(&mu, &mut p)?;
            report.log_likelihood.push(log_likelihood(counts, &p, flux));
        }
    }
    Ok((mu, report))
}

#[cfg(test)]
mod tests {
    use super::*;
    use dbt_forward::{simulate, NoiseLevel};
    use dbt_geometry::Geometry;

    fn small_case() -> (Geometry, Vec<f32>, Vec<f32>) {
        let mut g = Geometry::paper().binned(4).unwrap();
        g.image.columns = 120;
        g.image.rows = 40;
        g.detector.elements = 200;
        g.validate().unwrap();
        let cols = g.image.columns;
        let mut mu = vec![0f32; g.n_pixels()];
        let mut support = vec![0f32; g.n_pixels()];
        for r in 10..40 {
            support[r * cols..(r + 1) * cols].fill(1.0);
            for c in 20..100 {
                let dense = (40..60).contains(&c) && (18..28).contains(&r);
                mu[r * cols + c] = if r == 10 || r == 39 || c == 20 || c == 99 {
                    0.0854
                } else if dense {
                    0.0798
                } else {
                    0.0512
                };
            }
        }
        (g, mu, support)
    }

    #[test]
    fn likelihood_increases_monotonically() {
        let (g, mu, support) = small_case();
        let proj = Projector::new(&g);
        for noise in [
            NoiseLevel::NoiseFree,
            NoiseLevel::Poisson(4),
            NoiseLevel::Poisson(8),
        ] {
            let acq = simulate(&proj, &mu, noise, 42).unwrap();
            let opts = MltrOptions {
                iterations: 30,
                track_likelihood: true,
            };
            let (rec, rep) = mltr(&proj, &acq.counts, acq.flux, &support, &opts).unwrap();
            let ll = &rep.log_likelihood;
            assert_eq!(ll.len(), 31);
            for k in 1..ll.len() {
                // Allow only float rounding of the sum (relative 1e-9).
                assert!(
                    ll[k] >= ll[k - 1] - 1e-9 * ll[k - 1].abs(),
                    "{noise:?}: likelihood fell at iteration {k}: {} -> {}",
                    ll[k - 1],
                    ll[k]
                );
            }
            assert!(ll[30] > ll[0]);
            // Nothing outside the support, nothing negative.
            for (x, s) in rec.iter().zip(&support) {
                assert!(*x >= 0.0);
                if *s == 0.0 {
                    assert_eq!(*x, 0.0);
                }
            }
        }
    }

    #[test]
    fn noise_free_converges_toward_truth() {
        let (g, mu, support) = small_case();
        let proj = Projector::new(&g);
        let acq = simulate(&proj, &mu, NoiseLevel::NoiseFree, 0).unwrap();
        let err = |iters| {
            let opts = MltrOptions {
                iterations: iters,
                track_likelihood: false,
            };
            let (rec, _) = mltr(&proj, &acq.counts, acq.flux, &support, &opts).unwrap();
            let e: f64 = rec
                .iter()
                .zip(&mu)
                .map(|(a, b)| ((a - b) as f64).powi(2))
                .sum();
            let t: f64 = mu.iter().map(|&b| (b as f64).powi(2)).sum();
            (e / t).sqrt()
        };
        let (e5, e50) = (err(5), err(50));
        assert!(e50 < e5, "{e5} -> {e50}");
        // Limited angle: the mean attenuation in the support is right even if
        // the vertical distribution is not.
        assert!(e50 < 0.35, "relative error {e50}");
    }

    #[test]
    fn bad_inputs_rejected() {
        let (g, _, support) = small_case();
        let proj = Projector::new(&g);
        let y = vec![1.0f32; g.n_rays()];
        let o = MltrOptions::default();
        assert!(matches!(
            mltr(&proj, &y[1..], 10.0, &support, &o),
            Err(ReconError::Size { what: "counts", .. })
        ));
        assert!(mltr(&proj, &y, 0.0, &support, &o).is_err());
        let mut bad = y.clone();
        bad[3] = f32::NAN;
        let e = mltr(&proj, &bad, 10.0, &support, &o)
            .unwrap_err()
            .to_string();
        assert!(e.contains("ray 3"), "{e}");
    }
}
