//! Photon energy spectra: monoenergetic, or tabulated (energy, weight) as read
//! from a two-column file.

use crate::DoseError;
use rand::Rng;

/// A normalised discrete spectrum.
#[derive(Debug, Clone, PartialEq)]
pub struct Spectrum {
    /// Energies, keV.
    pub energies: Vec<f64>,
    /// Probabilities (sum 1).
    pub weights: Vec<f64>,
    cdf: Vec<f64>,
}

/// Lowest and highest energies the physics tables support, keV.
pub const SPECTRUM_RANGE: (f64, f64) = (5.0, 50.0);

impl Spectrum {
    /// One energy.
    pub fn mono(e_kev: f64) -> Result<Self, DoseError> {
        Self::new(vec![e_kev], vec![1.0])
    }

    /// From energies and non-negative weights (normalised here).
    pub fn new(energies: Vec<f64>, weights: Vec<f64>) -> Result<Self, DoseError> {
        if energies.is_empty() || energies.len() != weights.len() {
            return Err(DoseError::Spectrum(
                "need as many weights as energies, at least one".into(),
            ));
        }
        for (i, (&e, &w)) in energies.iter().zip(&weights).enumerate() {
            if !(SPECTRUM_RANGE.0..=SPECTRUM_RANGE.1).contains(&e) {
                return Err(DoseError::Spectrum(format!(
                    "line {}: energy {e} keV outside {:?} keV",
                    i + 1,
                    SPECTRUM_RANGE
                )));
            }
            if !(w.is_finite() && w >= 0.0) {
                return Err(DoseError::Spectrum(format!("line {}: weight {w}", i + 1)));
            }
        }
        let s: f64 = weights.iter().sum();
        if s.is_nan() || s <= 0.0 {
            return Err(DoseError::Spectrum("all weights are zero".into()));
        }
        let weights: Vec<f64> = weights.iter().map(|w| w / s).collect();
        let mut acc = 0.0;
        let cdf = weights
            .iter()
            .map(|w| {
                acc += w;
                acc
            })
            .collect();
        Ok(Self {
            energies,
            weights,
            cdf,
        })
    }

    /// Parse two whitespace- or comma-separated columns (energy keV, weight);
    /// `#` starts a comment.
    pub fn parse(text: &str) -> Result<Self, DoseError> {
        let (mut e, mut w) = (Vec::new(), Vec::new());
        for (n, line) in text.lines().enumerate() {
            let line = line.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            let cols: Vec<&str> = line
                .split(|c: char| c == ',' || c.is_whitespace())
                .filter(|s| !s.is_empty())
                .collect();
            let bad = || {
                DoseError::Spectrum(format!(
                    "line {}: expected `energy weight`, got `{line}`",
                    n + 1
                ))
            };
            if cols.len() != 2 {
                return Err(bad());
            }
            e.push(cols[0].parse::<f64>().map_err(|_| bad())?);
            w.push(cols[1].parse::<f64>().map_err(|_| bad())?);
        }
        Self::new(e, w)
    }

    /// Mean energy, keV.
    pub fn mean(&self) -> f64 {
        self.energies
            .iter()
            .zip(&self.weights)
            .map(|(e, w)| e * w)
            .sum()
    }

    /// Draw an energy.
    #[inline]
    pub fn sample<R: Rng>(&self, rng: &mut R) -> f64 {
        if self.energies.len() == 1 {
            return self.energies[0];
        }
        let u = rng.random::<f64>();
        let i = self
            .cdf
            .partition_point(|&c| c < u)
            .min(self.energies.len() - 1);
        self.energies[i]
    }
}
