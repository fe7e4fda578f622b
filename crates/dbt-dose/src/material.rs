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
    /// Fraction of the energy deposited here that counts as deposited in
    /// glandular tissue, on the energy grid (0 by default; 1 for glandular
    /// tissue; `G mu_en,g / mu_en,mix` for a homogeneous mixture).
    gland_w: Vec<f64>,
}

/// Mean fraction of the photon energy given to the electron in free-electron
/// Klein-Nishina scattering at `e_kev` (Simpson over cos theta).
pub fn kn_transfer_fraction(e_kev: f64) -> f64 {
    let k = e_kev / MC2_KEV;
    let n = 400;
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..=n {
        let c = -1.0 + 2.0 * i as f64 / n as f64;
        let eps = 1.0 / (1.0 + k * (1.0 - c));
        let dcs = eps * eps * (eps + 1.0 / eps - (1.0 - c * c));
        let w = if i == 0 || i == n {
            1.0
        } else if i % 2 == 1 {
            4.0
        } else {
            2.0
        };
        num += w * dcs * (1.0 - eps);
        den += w * dcs;
    }
    num / den
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
        let mu: Vec<Mu> = (0..N_E)
            .map(|i| Mu {
                photo: k * parts.iter().map(|(e, w)| w * e.photo[i]).sum::<f64>(),
                rayleigh: k * parts.iter().map(|(e, w)| w * e.rayleigh[i]).sum::<f64>(),
                compton: k * parts.iter().map(|(e, w)| w * e.compton[i]).sum::<f64>(),
            })
            .collect();
        // Energy absorbed locally per unit path, consistent with the engine's
        // deposition model: photoelectric absorption deposits E, Compton the
        // electron's mean share of E (free-electron Klein-Nishina), Rayleigh
        // nothing. Below 50 keV in low-Z media this is mu_en (fluorescence and
        // bremsstrahlung losses are negligible): water at 20 keV gives 0.550
        // cm^2/g, NIST 0.5503.
        let mu_en = mu
            .iter()
            .enumerate()
            .map(|(i, m)| m.photo + m.compton * kn_transfer_fraction(E_MIN + i as f64 * E_STEP))
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
            gland_w: vec![0.0; N_E],
        })
    }

    /// A tissue of the model (composition and density from dbt-materials).
    pub fn tissue(t: dbt_materials::Tissue, elements: &[Element]) -> Result<Self, DoseError> {
        Self::new(t.name(), t.density_g_cm3(), t.composition(), elements)
    }

    /// A non-tissue medium (air, PMMA, PET, water).
    pub fn medium(c: &dbt_materials::Composition, elements: &[Element]) -> Result<Self, DoseError> {
        Self::new(c.name, c.density, c.elements, elements)
    }

    /// Count all energy deposited in this material as glandular.
    pub fn glandular(mut self) -> Self {
        self.gland_w = vec![1.0; N_E];
        self
    }

    /// For a homogeneous mixture with glandular mass fraction `g`: the share
    /// of deposited energy absorbed by its glandular component,
    /// `g (mu_en/rho)_glandular / (mu_en/rho)_mixture` (Boone 1999).
    pub fn glandular_share(mut self, g: f64, glandular: &Material) -> Self {
        self.gland_w = (0..N_E)
            .map(|i| {
                let mix = self.mu_en[i] / self.density;
                let gl = glandular.mu_en[i] / glandular.density;
                if mix > 0.0 {
                    (g * gl / mix).clamp(0.0, 1.0)
                } else {
                    0.0
                }
            })
            .collect();
        self
    }

    /// Glandular share of energy deposited at `e_kev` (see `glandular`).
    #[inline]
    pub fn glandular_weight(&self, e_kev: f64) -> f64 {
        let (i, t) = grid_pos(e_kev);
        self.gland_w[i] + t * (self.gland_w[i + 1] - self.gland_w[i])
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
}
