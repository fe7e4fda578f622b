//! Interaction sampling: Rayleigh with atomic form factors, Compton with
//! Klein-Nishina corrected by the incoherent scattering function, and the
//! direction update. Photoelectric absorption deposits the photon's energy
//! locally (no fluorescence: below 50 keV in breast tissue its yield and range
//! are negligible, as TG-195 notes).

use crate::material::{Material, HC_KEV_A, MC2_KEV};
use rand::Rng;

/// Sample the Rayleigh polar angle cosine at `e_kev`: `x^2` from the `F^2`
/// distribution up to `x_max^2`, then accept with `(1 + cos^2) / 2`.
pub fn sample_rayleigh<R: Rng>(m: &Material, e_kev: f64, rng: &mut R) -> f64 {
    let x_max = e_kev / HC_KEV_A;
    let u_max = x_max * x_max;
    let g_max = m.rayleigh_cum(u_max);
    loop {
        let u = m.rayleigh_inv(rng.random::<f64>() * g_max).min(u_max);
        let cos_t = 1.0 - 2.0 * u / u_max;
        if rng.random::<f64>() * 2.0 <= 1.0 + cos_t * cos_t {
            return cos_t;
        }
    }
}

/// Sample Compton scattering at `e_kev`: returns `(cos_theta, e_out_kev)`.
/// Klein-Nishina by the method of Geant4's `G4KleinNishinaCompton` (Butcher
/// and Messel), then rejection with `S(x, Z) / Z`, `x = sin(theta/2) E / hc`.
pub fn sample_compton<R: Rng>(m: &Material, e_kev: f64, rng: &mut R) -> (f64, f64) {
    let k = e_kev / MC2_KEV;
    let eps0 = 1.0 / (1.0 + 2.0 * k);
    let eps0sq = eps0 * eps0;
    let alpha1 = -eps0.ln();
    let alpha2 = alpha1 + 0.5 * (1.0 - eps0sq);
    loop {
        let (eps, epssq) = if alpha1 > alpha2 * rng.random::<f64>() {
            let e = (-alpha1 * rng.random::<f64>()).exp();
            (e, e * e)
        } else {
            let sq = eps0sq + (1.0 - eps0sq) * rng.random::<f64>();
            (sq.sqrt(), sq)
        };
        let onecost = (1.0 - eps) / (eps * k);
        let sint2 = onecost * (2.0 - onecost);
        let greject = 1.0 - eps * sint2 / (1.0 + epssq);
        if greject < rng.random::<f64>() {
            continue;
        }
        let cos_t = 1.0 - onecost;
        let x = (e_kev / HC_KEV_A) * (onecost / 2.0).max(0.0).sqrt();
        if rng.random::<f64>() <= m.sf_ratio(x) {
            return (cos_t, eps * e_kev);
        }
    }
}

/// Klein-Nishina differential cross section shape at `cos_theta` times
/// `S(x)/Z` (for tests of the sampler).
pub fn compton_dcs_shape(m: &Material, e_kev: f64, cos_theta: f64) -> f64 {
    let k = e_kev / MC2_KEV;
    let p = 1.0 / (1.0 + k * (1.0 - cos_theta));
    let kn = p * p * (p + 1.0 / p - (1.0 - cos_theta * cos_theta));
    let x = (e_kev / HC_KEV_A) * ((1.0 - cos_theta) / 2.0).max(0.0).sqrt();
    kn * m.sf_ratio(x)
}

/// Rotate unit direction `d` by polar angle `acos(cos_t)` and azimuth `phi`.
pub fn rotate(d: [f64; 3], cos_t: f64, phi: f64) -> [f64; 3] {
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let (sp, cp) = phi.sin_cos();
    let [u, v, w] = d;
    let r = (1.0 - w * w).max(0.0).sqrt();
    let out = if r < 1e-10 {
        let s = if w >= 0.0 { 1.0 } else { -1.0 };
        [sin_t * cp, sin_t * sp, s * cos_t]
    } else {
        [
            u * cos_t + sin_t * (u * w * cp - v * sp) / r,
            v * cos_t + sin_t * (v * w * cp + u * sp) / r,
            w * cos_t - r * sin_t * cp,
        ]
    };
    let n = (out[0] * out[0] + out[1] * out[1] + out[2] * out[2]).sqrt();
    [out[0] / n, out[1] / n, out[2] / n]
}
