//! Materials as mixtures of elements by mass fraction: linear interaction
//! coefficients on the energy grid and the samplers' tables.
//!
//! For a mixture, mass coefficients add by mass fraction; the Rayleigh form
//! factor enters as `F^2_mix(x) = sum_i (w_i / A_i) F_i(x)^2` and the
//! incoherent scattering function as `S_mix(x) = sum_i (w_i / A_i) S_i(x)`
//! (independent-atom approximation, as in PENELOPE and Geant4's Livermore
//! models).

use crate::tables::{Element, E_MIN, E_STEP, N_E};
use crate::DoseError;
use dbt_materials::ElementFraction;

/// Planck constant times speed of light, keV * Angstrom.
pub const HC_KEV_A: f64 = 12.398_419_84;
/// Electron rest energy, keV.
pub const MC2_KEV: f64 = 510.998_95;

/// Linear coefficients at one energy, 1/mm.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Mu {
    /// Photoelectric absorption.
    pub photo: f64,
    /// Rayleigh scattering.
    pub rayleigh: f64,
    /// Compton scattering.
    pub compton: f64,
}

impl Mu {
    /// Total attenuation.
    pub fn total(&self) -> f64 {
        self.photo + self.rayleigh + self.compton
    }
}

/// A material ready for transport.
#[derive(Debug, Clone)]
pub struct Material {
    /// Name, for reports.
    pub name: String,
    /// Mass density, g/cm^3.
    pub density: f64,
    mu: Vec<Mu>,
    mu_en: Vec<f64>,
    /// u = x^2 grid of the Rayleigh sampler and the cumulative integral of
    /// F^2_mix over u.
    ray_u: Vec<f64>,
    ray_cum: Vec<f64>,
    /// x grid and S_mix(x) / S_mix(infinity).
    sf_x: Vec<f64>,
    sf_ratio: Vec<f64>,
}

fn grid_pos(e_kev: f64) -> (usize, f64) {
    let t = ((e_kev - E_MIN) / E_STEP).clamp(0.0, (N_E - 1) as f64 - 1e-9);
    let i = t as usize;
    (i, t - i as f64)
}

impl Material {
    /// Build a mixture; fractions are normalised, elements must be tabulated.
    pub fn new(
        name: &str,
        density: f64,
        composition: &[ElementFraction],
        elements: &[Element],
    ) -> Result<Self, DoseError> {
        if !(density.is_finite() && density > 0.0) {
            return Err(DoseError::Material(format!("{name}: density {density}")));
        }
        let wsum: f64 = composition.iter().map(|e| e.fraction).sum();
        if wsum.is_nan() || wsum <= 0.0 {
            return Err(DoseError::Material(format!("{name}: empty composition")));
        }
        let parts: Vec<(&Element, f64)> = composition
            .iter()
            .map(|c| {
                elements
                    .iter()
                    .find(|e| e.z == c.z)
                    .map(|e| (e, c.fraction / wsum))
                    .ok_or_else(|| {
                        DoseError::Material(format!("{name}: element Z = {} not tabulated", c.z))
                    })
            })
            .collect::<Result<_, _>>()?;
        // cm^2/g * g/cm^3 = 1/cm; /10 -> 1/mm.
        let k = density / 10.0;
        let mu = (0..N_E)
            .map(|i| Mu {
                photo: k * parts.iter().map(|(e, w)| w * e.photo[i]).sum::<f64>(),
                rayleigh: k * parts.iter().map(|(e, w)| w * e.rayleigh[i]).sum::<f64>(),
                compton: k * parts.iter().map(|(e, w)| w * e.compton[i]).sum::<f64>(),
            })
            .collect();
        let mu_en = (0..N_E)
            .map(|i| {
                k * parts
                    .iter()
                    .map(|(e, w)| w * e.energy_absorption[i])
                    .sum::<f64>()
            })
            .collect();
        let x = parts[0].0.x.clone();
        let f2: Vec<f64> = (0..x.len())
            .map(|j| parts.iter().map(|(e, w)| w / e.a * e.ff[j] * e.ff[j]).sum())
            .collect();
        let ray_u: Vec<f64> = x.iter().map(|v| v * v).collect();
        let mut ray_cum = vec![0.0; x.len()];
        for j in 1..x.len() {
            ray_cum[j] = ray_cum[j - 1] + 0.5 * (f2[j] + f2[j - 1]) * (ray_u[j] - ray_u[j - 1]);
        }
        let s_inf: f64 = parts.iter().map(|(e, w)| w / e.a * e.z as f64).sum();
        let sf_ratio = (0..x.len())
            .map(|j| (parts.iter().map(|(e, w)| w / e.a * e.sf[j]).sum::<f64>() / s_inf).min(1.0))
            .collect();
        Ok(Self {
            name: name.to_string(),
            density,
            mu,
            mu_en,
            ray_u,
            ray_cum,
            sf_x: x,
            sf_ratio,
        })
    }

    /// Linear coefficients at `e_kev` (linear interpolation on the 0.1 keV grid).
    pub fn mu(&self, e_kev: f64) -> Mu {
        let (i, t) = grid_pos(e_kev);
        let (a, b) = (self.mu[i], self.mu[i + 1]);
        Mu {
            photo: a.photo + t * (b.photo - a.photo),
            rayleigh: a.rayleigh + t * (b.rayleigh - a.rayleigh),
            compton: a.compton + t * (b.compton - a.compton),
        }
    }

    /// Linear energy-absorption coefficient at `e_kev`, 1/mm.
    pub fn mu_en(&self, e_kev: f64) -> f64 {
        let (i, t) = grid_pos(e_kev);
        self.mu_en[i] + t * (self.mu_en[i + 1] - self.mu_en[i])
    }

    /// Cumulative F^2 integral up to `u = x^2`.
    pub(crate) fn rayleigh_cum(&self, u: f64) -> f64 {
        let j = self
            .ray_u
            .partition_point(|&v| v <= u)
            .clamp(1, self.ray_u.len() - 1);
        let (u0, u1) = (self.ray_u[j - 1], self.ray_u[j]);
        let t = ((u - u0) / (u1 - u0)).clamp(0.0, 1.0);
        self.ray_cum[j - 1] + t * (self.ray_cum[j] - self.ray_cum[j - 1])
    }

    /// Inverse of [`Material::rayleigh_cum`].
    pub(crate) fn rayleigh_inv(&self, g: f64) -> f64 {
        let j = self
            .ray_cum
            .partition_point(|&v| v <= g)
            .clamp(1, self.ray_cum.len() - 1);
        let (g0, g1) = (self.ray_cum[j - 1], self.ray_cum[j]);
        let t = if g1 > g0 {
            ((g - g0) / (g1 - g0)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        self.ray_u[j - 1] + t * (self.ray_u[j] - self.ray_u[j - 1])
    }

    /// `S_mix(x) / S_mix(inf)`, in [0, 1].
    pub(crate) fn sf_ratio(&self, x: f64) -> f64 {
        let j = self.sf_x.partition_point(|&v| v <= x);
        if j >= self.sf_x.len() {
            return *self.sf_ratio.last().unwrap_or(&1.0);
        }
        let j = j.max(1);
        let (x0, x1) = (self.sf_x[j - 1], self.sf_x[j]);
        let t = ((x - x0) / (x1 - x0)).clamp(0.0, 1.0);
        self.sf_ratio[j - 1] + t * (self.sf_ratio[j] - self.sf_ratio[j - 1])
    }

    /// Differential Rayleigh cross section shape `(1 + cos^2) F^2_mix(x)` at
    /// `cos_theta` (for tests of the sampler).
    pub fn rayleigh_dcs_shape(&self, e_kev: f64, cos_theta: f64) -> f64 {
        let x = (e_kev / HC_KEV_A) * ((1.0 - cos_theta) / 2.0).max(0.0).sqrt();
        let u = x * x;
        // dG/du = F^2(u) at u, by a centred difference of the cumulative.
        let h = (u * 1e-3).max(1e-8);
        let f2 = (self.rayleigh_cum(u + h) - self.rayleigh_cum((u - h).max(0.0)))
            / (u + h - (u - h).max(0.0));
        (1.0 + cos_theta * cos_theta) * f2
    }
}
