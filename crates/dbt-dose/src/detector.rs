//! The energy response of an energy-integrating flat panel's converter
//! (a CsI scintillator or an a-Se photoconductor): per incident photon of
//! energy `E` at normal incidence, the chance it is absorbed and the first
//! two moments of the energy it leaves in the layer, which is what the
//! signal (charge or light) is proportional to.
//!
//! # The model
//! A layer `t` thick of linear attenuation `mu(E)` absorbs
//! `eta = 1 - exp(-mu t)` of the photons, each where it first interacts,
//! depth `z` distributed as `mu exp(-mu z)` (a scattering interaction counts
//! as an absorption, as the clinical model always took it: in Se and CsI
//! at mammographic energies photoelectric absorption is 90-97 % of `mu`).
//! A photoelectric absorption above an element's K edge leaves a K vacancy
//! with probability `1 - 1/J` (`J` the edge's jump ratio), which emits a
//! line of group `i` (Ka, Kb) with probability `omega_i` (yield times
//! radiative rate); the line is emitted isotropically and leaves the layer,
//! unabsorbed, through either face with probability
//!
//! `P_esc(z) = (E2(mu_i z) + E2(mu_i (t - z))) / 2`
//!
//! (`E2` the exponential integral of order 2: half the directions point to
//! each face, a direction of cosine `u` to the face crosses `z / u`), with
//! `mu_i` the layer's attenuation at the line's energy. An escape deposits
//! `E - E_i`; everything else deposits `E` (photo- and Auger electrons are
//! absorbed locally; the fluorescence that is reabsorbed stays in the
//! layer). So, per incident photon, the escape probability is
//!
//! `p_i = (mu_pe,K(E) / mu(E)) omega_i int_0^t mu exp(-mu z) P_esc(z) dz`
//!
//! and the deposited energy's moments are `m1 = eta E - sum_i p_i E_i`,
//! `m2 = (eta - sum_i p_i) E^2 + sum_i p_i (E - E_i)^2`. This is the
//! escape-only part of the K-fluorescence model of Zhao et al. 2003 (Med.
//! Phys. 30:254, a-Se for mammography: "the K edge of a-Se is 12.66 keV and
//! within the energy range of a mammographic spectrum") and of VICTRE's
//! MC-GPU detector (K-edge, fluorescence energy and yield as its input);
//! the reabsorbed fluorescence's lateral spread (a blur: 15 % of the MTF at
//! an 85 um element's Nyquist frequency, Zhao et al.) is not modelled here:
//! the detector's spatial spread, where a system's file states one, is
//! the simulator's (`dbt_forward::spread`: an exponential line spread
//! fitted to a measured MTF, which includes whatever spreads the signal). For CsI the model changes nothing below iodine's K
//! edge (33.17 keV): every tube voltage of our automatic exposures (27-33
//! kV); an exposure at 34 kV or more (the intake takes 20-49) loses
//! iodine's and caesium's lines too. Normal incidence: an oblique ray's
//! longer path through the layer (up to 10 % at 25 degrees) is neglected.
//!
//! Data: the converter's attenuation from the compiled-in xraylib tables
//! ([`crate::tables`]), the K shells from `data/kshell.csv` (xraylib 4.3.0:
//! edge, jump ratio, fluorescence yield and radiative rates). Checked
//! against VICTRE's MC-GPU detector input: its selenium mean free path at
//! 19 keV is ours within 1 % at its density; its mean free path of the
//! fluorescence (0.00593 cm at 11.223 keV) is 16 % shorter than xraylib's
//! at the same density, which we do not follow (the tables are one source
//! for every material); with it the escape would be smaller.

use crate::material::Material;
use crate::tables::{self, Element, E_MIN, E_STEP, N_E};
use crate::DoseError;
use dbt_materials::Converter;

/// The converter's response to one incident photon of one energy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Response {
    /// Chance the photon interacts in the layer (`eta`).
    pub absorbed: f64,
    /// Chance a fluorescence photon escapes, per incident photon.
    pub escape: f64,
    /// Mean energy deposited per incident photon, keV.
    pub mean_kev: f64,
    /// Mean squared energy deposited per incident photon, keV^2.
    pub mean_sq_kev2: f64,
}

/// One element's K-fluorescence escape route in the converter.
struct Route {
    /// The element's photoelectric attenuation in the layer on the
    /// tables' grid, 1/mm.
    photo: Vec<f64>,
    shell: &'static tables::KShell,
}

/// A converter ready to answer [`ConverterModel::response`].
pub struct ConverterModel {
    converter: Converter,
    material: Material,
    routes: Vec<Route>,
}

/// Points of the depth integral (midpoints in the absorbed fraction).
const DEPTH_POINTS: usize = 400;

impl ConverterModel {
    /// The model of `converter` (its thickness checked).
    pub fn new(converter: Converter) -> Result<Self, DoseError> {
        converter
            .validate()
            .map_err(|e| DoseError::Material(e.to_string()))?;
        let elements = tables::elements()?;
        let comp = converter.material.composition();
        let material = Material::medium(comp, elements)?;
        let mut routes = Vec::new();
        for f in comp.elements {
            let Some(shell) = tables::kshell(f.z)? else {
                continue;
            };
            let el: &Element = elements
                .iter()
                .find(|e| e.z == f.z)
                .ok_or_else(|| DoseError::Table(format!("no element Z {}", f.z)))?;
            // cm^2/g x g/cm^3 = 1/cm; per mm: / 10.
            let photo = el
                .photo
                .iter()
                .map(|p| p * f.fraction * comp.density / 10.0)
                .collect();
            routes.push(Route { photo, shell });
        }
        Ok(Self {
            converter,
            material,
            routes,
        })
    }

    /// The converter modelled.
    pub fn converter(&self) -> Converter {
        self.converter
    }

    /// The layer's linear attenuation at `e_kev`, 1/mm.
    pub fn mu(&self, e_kev: f64) -> f64 {
        self.material.mu(e_kev).total()
    }

    /// The response to a photon of `e_kev` at normal incidence.
    pub fn response(&self, e_kev: f64) -> Result<Response, DoseError> {
        if !(e_kev.is_finite() && e_kev > 0.0) {
            return Err(DoseError::Spectrum(format!(
                "photon energy {e_kev} keV must be a positive number"
            )));
        }
        let t = self.converter.thickness_um / 1000.0;
        let mu = self.mu(e_kev);
        let absorbed = -(-mu * t).exp_m1();
        let mut escape = 0.0;
        let mut lost = 0.0;
        let mut lost_sq = 0.0;
        for r in &self.routes {
            let k = r.shell.k_share(e_kev);
            if k == 0.0 || mu <= 0.0 {
                continue;
            }
            let pe_share = interp(&r.photo, e_kev) / mu;
            for line in &r.shell.lines {
                let mu_f = self.mu(line.energy_kev);
                let p = pe_share * k * line.share * escape_integral(mu, mu_f, t);
                escape += p;
                lost += p * line.energy_kev;
                lost_sq += p * ((e_kev - line.energy_kev).powi(2) - e_kev * e_kev);
            }
        }
        Ok(Response {
            absorbed,
            escape,
            mean_kev: absorbed * e_kev - lost,
            mean_sq_kev2: absorbed * e_kev * e_kev + lost_sq,
        })
    }
}

/// Linear interpolation on the tables' grid (clamped at its ends).
fn interp(v: &[f64], e_kev: f64) -> f64 {
    let x = ((e_kev - E_MIN) / E_STEP).clamp(0.0, (N_E - 1) as f64);
    let i = (x.floor() as usize).min(N_E - 2);
    let f = x - i as f64;
    v[i] + f * (v[i + 1] - v[i])
}

/// `int_0^t mu exp(-mu z) P_esc(z) dz` with `P_esc(z) = (E2(mu_f z) +
/// E2(mu_f (t - z))) / 2`: in the absorbed fraction `u = 1 - exp(-mu z)`
/// (uniform where the photons interact), midpoints.
pub fn escape_integral(mu: f64, mu_f: f64, t: f64) -> f64 {
    let eta = -(-mu * t).exp_m1();
    if eta.is_nan() || eta <= 0.0 {
        return 0.0;
    }
    let du = eta / DEPTH_POINTS as f64;
    (0..DEPTH_POINTS)
        .map(|j| {
            let u = (j as f64 + 0.5) * du;
            let z = (-(-u).ln_1p() / mu).min(t);
            0.5 * (expint(2, mu_f * z) + expint(2, mu_f * (t - z)))
        })
        .sum::<f64>()
        * du
}

/// The exponential integral `E_n(x) = int_1^inf exp(-x s) / s^n ds` for
/// `n >= 1`, `x >= 0` (`E_n(0) = 1 / (n - 1)` for `n > 1`): the series for
/// `x <= 1`, the continued fraction (modified Lentz) beyond, to 1e-12
/// (Abramowitz and Stegun 5.1.11-5.1.12 and 5.1.22).
pub fn expint(n: u32, x: f64) -> f64 {
    const EULER: f64 = 0.577_215_664_901_532_9;
    const EPS: f64 = 1e-12;
    const FPMIN: f64 = 1e-300;
    let nm1 = f64::from(n.saturating_sub(1));
    if n == 0 {
        return (-x).exp() / x;
    }
    if x <= 0.0 {
        return if n > 1 { 1.0 / nm1 } else { f64::INFINITY };
    }
    if x > 1.0 {
        let mut b = x + f64::from(n);
        let mut c = 1.0 / FPMIN;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..1000 {
            let fi = f64::from(i);
            let a = -fi * (nm1 + fi);
            b += 2.0;
            d = 1.0 / (a * d + b);
            c = b + a / c;
            let del = c * d;
            h *= del;
            if (del - 1.0).abs() < EPS {
                break;
            }
        }
        h * (-x).exp()
    } else {
        let mut ans = if n > 1 { 1.0 / nm1 } else { -x.ln() - EULER };
        let mut fact = 1.0;
        for i in 1..1000u32 {
            let fi = f64::from(i);
            fact *= -x / fi;
            let del = if i != n - 1 {
                -fact / (fi - nm1)
            } else {
                let psi = -EULER + (1..=n - 1).map(|k| 1.0 / f64::from(k)).sum::<f64>();
                fact * (-x.ln() + psi)
            };
            ans += del;
            if del.abs() < ans.abs() * EPS {
                break;
            }
        }
        ans
    }
}

#[cfg(test)]
mod tests;
