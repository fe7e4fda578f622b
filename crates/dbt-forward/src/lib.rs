//! Simulated acquisitions of one coronal slice with the paper's forward model
//! (eq. 2): `y_i = b_i exp(-sum_j l_ij mu_j)`, a perfect photon-counting
//! detector, and Poisson noise with `b_i = 1000 * sqrt(2)^N` (N = 4, 8, 12), or
//! no noise.
//!
//! The log transform that turns counts back into line integrals lives here
//! too, so the dataset exporter (hence the trainer) and the firmware share it:
//! `g_i = ln(b / max(y_i, 0.5))`. The floor of half a count keeps a ray that
//! counted zero photons finite (it happens at N = 4 behind the thickest
//! tissue); it is the usual half-count correction.
//!
//! [`clinical`]: the clinical physics model (issue #27): a polychromatic
//! beam through the tissues' own attenuation, an energy-integrating CsI
//! detector, quantum and electronic noise.

pub mod clinical;
pub mod spread;

use dbt_projector::{Projector, ProjectorError};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Poisson};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Errors of the acquisition simulation.
#[derive(Debug, Error)]
pub enum AcquisitionError {
    /// The projector rejected the image (wrong size).
    #[error(transparent)]
    Projector(#[from] ProjectorError),
    /// A noise level outside what the model supports.
    #[error("noise level N = {0} is not supported (0..=30)")]
    BadNoiseLevel(u32),
    /// Counts and flux disagree in size or value.
    #[error("counts: {0}")]
    BadCounts(String),
    /// The clinical physics model cannot be built or used as asked.
    #[error("clinical physics: {0}")]
    Physics(String),
}

/// Photon flux of a noise-free acquisition. The noise-free log transform is
/// exact for any flux; this one only keeps counts in a realistic range.
pub const NOISE_FREE_FLUX: f64 = 1.0e6;

/// The noise of an acquisition.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NoiseLevel {
    /// Expected counts, no noise.
    NoiseFree,
    /// Poisson counts with `b = 1000 * sqrt(2)^N` photons per ray.
    Poisson(u32),
}

impl NoiseLevel {
    /// The paper's levels: noise-free, N = 4, 8, 12.
    pub const PAPER: [NoiseLevel; 4] = [
        NoiseLevel::NoiseFree,
        NoiseLevel::Poisson(4),
        NoiseLevel::Poisson(8),
        NoiseLevel::Poisson(12),
    ];

    /// Photons emitted toward each detector element, `b_i`.
    pub fn flux(self) -> f64 {
        match self {
            NoiseLevel::NoiseFree => NOISE_FREE_FLUX,
            // sqrt(2)^N = 2^(N/2), exact for even N.
            NoiseLevel::Poisson(n) => 1000.0 * 2f64.powf(n as f64 / 2.0),
        }
    }

    /// A short name: `noise-free` or `N4`.
    pub fn name(self) -> String {
        match self {
            NoiseLevel::NoiseFree => "noise-free".into(),
            NoiseLevel::Poisson(n) => format!("N{n}"),
        }
    }

    /// Parse a name as written by [`NoiseLevel::name`] (also `none`, `4`).
    pub fn parse(s: &str) -> Result<NoiseLevel, AcquisitionError> {
        let t = s.trim();
        if t == "noise-free" || t == "none" {
            return Ok(NoiseLevel::NoiseFree);
        }
        let n: u32 = t.trim_start_matches('N').parse().map_err(|_| {
            AcquisitionError::BadCounts(format!("noise level `{s}` is not noise-free or N<number>"))
        })?;
        if n > 30 {
            return Err(AcquisitionError::BadNoiseLevel(n));
        }
        Ok(NoiseLevel::Poisson(n))
    }
}

/// Expected counts `b exp(-p)` of line integrals `p`.
pub fn expected_counts(line_integrals: &[f32], flux: f64) -> Vec<f32> {
    line_integrals
        .par_iter()
        .map(|&p| (flux * (-(p as f64)).exp()) as f32)
        .collect()
}

/// One Poisson realisation of expected counts, reproducible from `seed`: each
/// block of 4096 rays draws from its own ChaCha8 stream, so the result does not
/// depend on the number of threads.
pub fn poisson_counts(expected: &[f32], seed: u64) -> Vec<f32> {
    let mut out = vec![0f32; expected.len()];
    out.par_chunks_mut(4096)
        .zip(expected.par_chunks(4096))
        .enumerate()
        .for_each(|(blk, (o, e))| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream(blk as u64);
            for (y, &lam) in o.iter_mut().zip(e) {
                *y = match Poisson::new(lam as f64) {
                    Ok(p) => p.sample(&mut rng) as f32,
                    // lambda = 0 (or not finite): no photons.
                    Err(_) => 0.0,
                };
            }
        });
    out
}

/// A simulated acquisition of one slice.
#[derive(Debug, Clone, PartialEq)]
pub struct Acquisition {
    /// Detected counts per ray, view-major (`views x elements`).
    pub counts: Vec<f32>,
    /// Photons per ray, `b`.
    pub flux: f64,
    /// The noise model used.
    pub noise: NoiseLevel,
}

impl Acquisition {
    /// Line integrals estimated from the counts (see the crate docs).
    pub fn line_integrals(&self) -> Vec<f32> {
        log_transform(&self.counts, self.flux)
    }
}

/// Simulate the acquisition of attenuation image `mu` (1/mm, image layout).
pub fn simulate(
    projector: &Projector,
    mu: &[f32],
    noise: NoiseLevel,
    seed: u64,
) -> Result<Acquisition, AcquisitionError> {
    let mut p = vec![0f32; projector.range_len()];
    projector.forward(mu, &mut p)?;
    Ok(simulate_from_line_integrals(&p, noise, seed))
}

/// Simulate from precomputed noise-free line integrals (one projection shared
/// by several noise levels).
pub fn simulate_from_line_integrals(p: &[f32], noise: NoiseLevel, seed: u64) -> Acquisition {
    let flux = noise.flux();
    let expected = expected_counts(p, flux);
    let counts = match noise {
        NoiseLevel::NoiseFree => expected,
        NoiseLevel::Poisson(_) => poisson_counts(&expected, seed),
    };
    Acquisition {
        counts,
        flux,
        noise,
    }
}

/// `g_i = ln(b / max(y_i, 0.5))`: line integrals from counts.
pub fn log_transform(counts: &[f32], flux: f64) -> Vec<f32> {
    counts
        .par_iter()
        .map(|&y| (flux / (y as f64).max(0.5)).ln() as f32)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use dbt_geometry::Geometry;

    #[test]
    fn paper_flux_levels() {
        assert_eq!(NoiseLevel::Poisson(4).flux(), 4000.0);
        assert!((NoiseLevel::Poisson(8).flux() - 16000.0).abs() < 1e-9);
        assert!((NoiseLevel::Poisson(12).flux() - 64000.0).abs() < 1e-6);
        assert_eq!(NoiseLevel::parse("N8").unwrap(), NoiseLevel::Poisson(8));
        assert_eq!(
            NoiseLevel::parse("noise-free").unwrap(),
            NoiseLevel::NoiseFree
        );
        assert!(NoiseLevel::parse("N99").is_err());
        assert!(NoiseLevel::parse("loud").is_err());
    }

    #[test]
    fn poisson_mean_and_variance() {
        // 200k draws at each of three rates: the sample mean is within 4
        // standard errors of lambda, the sample variance within 4 standard
        // errors of lambda (var of the sample variance ~ (2 lambda^2 + lambda)/n).
        for lam in [3.0f64, 250.0, 40000.0] {
            let n = 200_000;
            let y = poisson_counts(&vec![lam as f32; n], 17);
            let m = y.iter().map(|&v| v as f64).sum::<f64>() / n as f64;
            let v = y.iter().map(|&x| (x as f64 - m).powi(2)).sum::<f64>() / (n - 1) as f64;
            let se_m = (lam / n as f64).sqrt();
            let se_v = ((2.0 * lam * lam + lam) / n as f64).sqrt();
            assert!((m - lam).abs() < 4.0 * se_m, "lambda {lam}: mean {m}");
            assert!((v - lam).abs() < 4.0 * se_v, "lambda {lam}: variance {v}");
            assert!(y.iter().all(|&c| c >= 0.0 && c.fract() == 0.0));
        }
    }

    #[test]
    fn reproducible_and_seed_dependent() {
        let e = vec![100.0f32; 10_000];
        assert_eq!(poisson_counts(&e, 5), poisson_counts(&e, 5));
        assert_ne!(poisson_counts(&e, 5), poisson_counts(&e, 6));
    }

    #[test]
    fn noise_free_log_transform_recovers_line_integrals() {
        let g = Geometry::paper().binned(4).unwrap();
        let proj = Projector::new(&g);
        let mut mu = vec![0f32; g.n_pixels()];
        let cols = g.image.columns;
        for r in g.image.rows - 40..g.image.rows {
            mu[r * cols + 60..r * cols + 190].fill(0.0798);
        }
        let a = simulate(&proj, &mu, NoiseLevel::NoiseFree, 0).unwrap();
        let mut p = vec![0f32; g.n_rays()];
        proj.forward(&mu, &mut p).unwrap();
        let back = a.line_integrals();
        for (x, y) in p.iter().zip(&back) {
            assert!((x - y).abs() < 1e-5 * x.max(1.0), "{x} vs {y}");
        }
        // Noisy counts average to the expected counts over the detector.
        let n = simulate(&proj, &mu, NoiseLevel::Poisson(8), 3).unwrap();
        let (se, sn): (f64, f64) = (
            expected_counts(&p, 16000.0).iter().map(|&v| v as f64).sum(),
            n.counts.iter().map(|&v| v as f64).sum(),
        );
        assert!((se - sn).abs() < 4.0 * se.sqrt(), "{se} vs {sn}");
        // Zero counts stay finite.
        assert!(log_transform(&[0.0], 4000.0)[0].is_finite());
    }
}
