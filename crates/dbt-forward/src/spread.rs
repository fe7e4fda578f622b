//! The detector's spatial spread (issue #51 point 1): the light of an x-ray
//! absorbed in a scintillator (CsI) spreads over neighbouring elements
//! before it is read, which blurs the image and the quantum noise alike.
//!
//! # The model
//! The converter's line spread function is an exponential,
//! `LSF(x) = exp(-|x| / s) / (2 s)`, whose transfer function is the
//! Lorentzian `1 / (1 + (2 pi f s)^2)`; an element of pitch `a` integrates
//! it over its aperture, so the presampling MTF is
//!
//! `MTF(f) = sinc(pi f a) / (1 + (2 pi f s)^2)`.
//!
//! The simulator samples each element's line integrals at its centre and
//! spreads them with the element kernel below, so what its detector does to
//! a sinusoid is the kernel's response `H(f) = sum_n h[n] cos(2 pi f n a)`
//! ([`element_response`]; the aperture is in the kernel), and that is what
//! a scale is fitted to. For GE's Senographe Essential (CsI(Tl) on a-Si,
//! 100 um elements) the least-squares `s` of `H` to the MTF Ghetti et al.
//! measured on its detector (Med. Phys. 35:456, 2008: 0.85, 0.59 and 0.24
//! at 1, 2 and 4 lp/mm) is 56.8 um, which gives 0.860, 0.587 and 0.238;
//! the system's file states it (`[detector] line_spread_um`,
//! `ge-essential.toml`) and a test here checks it against the measured
//! values. Direct-conversion (a-Se) panels spread less: Hologic's Selenia
//! Dimensions in its tomosynthesis mode (2 x 2 binned to 140 um) has an
//! MTF of 0.39 at its Nyquist frequency (Olgar et al., RoFo 185:1188,
//! 2013), which `H` gives with `s` = 47.4 um (`hologic-dimensions.toml`;
//! one measured value, so the spread's shape is the model's, and the whole
//! loss below the aperture's is put in a spread of the quanta, which no
//! measured noise spectrum was found to check). No MTF of Siemens's 85 um panel was found
//! (Hoheisel et al. 2004, IEEE NSS, measured the older 70 um Novation:
//! "well above 40 %" at its Nyquist frequency): its files state no spread,
//! nor does the paper's gantry (its ideal detector).
//!
//! On the simulator's elements (ray-driven: one line integral per element,
//! the image taken as constant over each), a photon absorbed uniformly
//! within element `0` leaves in element `n` the fraction
//!
//! `h[n] = (1/a) (G((n+1) a) - 2 G(n a) + G((n-1) a))`
//!
//! with `G` the second integral of the LSF (`G(x) = (s/2) exp(x/s)` for
//! `x < 0`, `x + (s/2) exp(-x/s)` above): [`element_kernel`], applied along
//! the rows and along the columns of each view's image (a separable spread:
//! the fitted response along both axes; a scintillator's 2-D spread is
//! round, which differs only off the axes). The exponential is one
//! parameter: a CsI layer's sharper core and longer tail are not in it. Binned elements take the
//! binned pitch (the light spreads within the binned element as within
//! its pixels).
//!
//! Where it acts: on each element's quanta after their Poisson draw and
//! before the readout's electronic noise, which does not spread (the
//! cascaded model of an indirect panel: Cunningham, Handbook of Medical
//! Imaging vol. 1, 2000, ch. 2), so the image and its quantum noise share
//! the MTF and the electronic noise stays white. Spreading each element's
//! drawn quanta by the kernel gives them the variance `sum h^2` per axis,
//! below that of photons absorbed anywhere in their element,
//! `(1/a) sum_n int phi_n(u)^2 du` (`phi_n(u)` the share of a photon at `u`
//! landing in element `n`; Jensen's inequality): [`element_variance`]
//! gives both, and the simulator adds the difference as white noise after
//! the spread, so that each element's quantum variance is the physical one
//! (its spectrum's shape at the highest frequencies is not). At the detector's borders
//! the image is continued by its mirror image: a flat field stays flat, as
//! a panel's gain calibration makes it.
//! Not modelled: the spread's energy
//! dependence (the MTF was measured at 28 kV Mo/Mo with 2 mm Al, beams of
//! the same range as ours) and the longer, oblique paths of the views'
//! rays through the layer.

use crate::AcquisitionError;
use rayon::prelude::*;

/// The kernel's ends are cut where an element receives less than this
/// fraction (then renormalised to 1).
const TAIL: f64 = 1e-7;

fn bad(what: String) -> AcquisitionError {
    AcquisitionError::Physics(what)
}

/// The integral of the exponential LSF of scale `s > 0`: the share of a
/// point's light falling left of `x`.
fn cdf(x: f64, s: f64) -> f64 {
    if x < 0.0 {
        0.5 * (x / s).exp()
    } else {
        1.0 - 0.5 * (-x / s).exp()
    }
}

/// The second integral of the exponential LSF of scale `s` (`s = 0`: the
/// ramp `max(x, 0)`).
fn g(x: f64, s: f64) -> f64 {
    if s == 0.0 {
        return x.max(0.0);
    }
    if x < 0.0 {
        0.5 * s * (x / s).exp()
    } else {
        x + 0.5 * s * (-x / s).exp()
    }
}

/// The fractions `h[-N..=N]` of an element's absorbed light that elements
/// `-N..=N` of pitch `pitch_mm` record, for an exponential line spread of
/// scale `scale_mm` (the module's formula); sums to 1, symmetric, `[1]`
/// without a spread.
pub fn element_kernel(scale_mm: f64, pitch_mm: f64) -> Result<Vec<f64>, AcquisitionError> {
    if !(scale_mm.is_finite() && scale_mm >= 0.0) {
        return Err(bad(format!(
            "line spread {scale_mm} mm must be a non-negative number"
        )));
    }
    if !(pitch_mm.is_finite() && pitch_mm > 0.0) {
        return Err(bad(format!(
            "element pitch {pitch_mm} mm must be a positive number"
        )));
    }
    let h = |n: i64| {
        let x = n as f64 * pitch_mm;
        (g(x + pitch_mm, scale_mm) - 2.0 * g(x, scale_mm) + g(x - pitch_mm, scale_mm)) / pitch_mm
    };
    // h(n) falls as exp(-n a / s) beyond n = 1.
    let mut half = 0i64;
    while h(half + 1) > TAIL && half < 4096 {
        half += 1;
    }
    // Symmetric by construction (the closed form is, up to rounding).
    let k: Vec<f64> = (-half..=half).map(|n| h(n.abs())).collect();
    let sum: f64 = k.iter().sum();
    Ok(k.into_iter().map(|v| v / sum).collect())
}

/// The element kernel's response to a sinusoid of `f_per_mm` sampled at
/// the element centres, `sum_n h[n] cos(2 pi f n a)`: the simulated
/// detector's MTF.
pub fn element_response(
    scale_mm: f64,
    pitch_mm: f64,
    f_per_mm: f64,
) -> Result<f64, AcquisitionError> {
    let k = element_kernel(scale_mm, pitch_mm)?;
    let half = (k.len() / 2) as f64;
    Ok(k.iter()
        .enumerate()
        .map(|(n, h)| {
            h * (2.0 * std::f64::consts::PI * f_per_mm * (n as f64 - half) * pitch_mm).cos()
        })
        .sum())
}

/// Per axis, the variance (relative to the unspread element's) of spread
/// quanta: `(sum h^2, (1/a) sum_n int phi_n(u)^2 du)`, the kernel's and
/// that of photons absorbed anywhere in their element (midpoint rule, 400
/// points per element).
pub fn element_variance(scale_mm: f64, pitch_mm: f64) -> Result<(f64, f64), AcquisitionError> {
    let k = element_kernel(scale_mm, pitch_mm)?;
    let code: f64 = k.iter().map(|h| h * h).sum();
    if scale_mm == 0.0 {
        return Ok((code, 1.0));
    }
    let a = pitch_mm;
    let m = 400;
    let reach = (k.len() / 2) as i64 + 2;
    let mut truth = 0.0;
    for n in -reach..=reach {
        for i in 0..m {
            let u = -a / 2.0 + (i as f64 + 0.5) * a / m as f64;
            let phi =
                cdf((n as f64 + 0.5) * a - u, scale_mm) - cdf((n as f64 - 0.5) * a - u, scale_mm);
            truth += phi * phi / m as f64;
        }
    }
    Ok((code, truth.min(1.0)))
}

/// Index `i` of a line of `n` continued by its mirror image (half-sample
/// symmetric: `-1 -> 0`, `n -> n - 1`).
fn mirror(mut i: i64, n: i64) -> usize {
    loop {
        if i < 0 {
            i = -1 - i;
        } else if i >= n {
            i = 2 * n - 1 - i;
        } else {
            return i as usize;
        }
    }
}

/// One line `src` (stride-free) convolved with the odd kernel `k`, mirrored
/// at its ends, into `dst`.
fn convolve_line(src: &[f64], k: &[f64], dst: &mut [f64]) {
    let n = src.len() as i64;
    let half = (k.len() / 2) as i64;
    for (i, d) in dst.iter_mut().enumerate() {
        let i = i as i64;
        let mut acc = 0.0;
        for (t, &w) in k.iter().enumerate() {
            acc += w * src[mirror(i + t as i64 - half, n)];
        }
        *d = acc;
    }
}

/// Spread every view's image of the stack `values` of `[rows, views,
/// cols]` (ray `(r, v, c)` at `(r * views + v) * cols + c`, as
/// `clinical::StackLayout` orders them) by the line spread of scale
/// `scale_mm`, along the rows and the elements, `[row_mm, col_mm]` apart.
pub fn spread_stack(
    values: &mut [f64],
    [rows, views, cols]: [usize; 3],
    [row_mm, col_mm]: [f64; 2],
    scale_mm: f64,
) -> Result<(), AcquisitionError> {
    if rows * views * cols != values.len() {
        return Err(bad(format!(
            "a stack of {rows} rows x {views} views x {cols} elements for {} values",
            values.len()
        )));
    }
    let kc = element_kernel(scale_mm, col_mm)?;
    let kr = element_kernel(scale_mm, row_mm)?;
    if kc.len() == 1 && kr.len() == 1 {
        return Ok(());
    }
    let spread: Vec<Vec<f64>> = (0..views)
        .into_par_iter()
        .map(|v| {
            // Along the elements, row by row.
            let mut img = vec![0.0; rows * cols];
            for r in 0..rows {
                let from = (r * views + v) * cols;
                convolve_line(
                    &values[from..from + cols],
                    &kc,
                    &mut img[r * cols..][..cols],
                );
            }
            // Along the rows, column by column.
            let (mut line, mut out) = (vec![0.0; rows], vec![0.0; rows]);
            for c in 0..cols {
                for r in 0..rows {
                    line[r] = img[r * cols + c];
                }
                convolve_line(&line, &kr, &mut out);
                for r in 0..rows {
                    img[r * cols + c] = out[r];
                }
            }
            img
        })
        .collect();
    for (v, img) in spread.iter().enumerate() {
        for r in 0..rows {
            let to = (r * views + v) * cols;
            values[to..to + cols].copy_from_slice(&img[r * cols..][..cols]);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The closed form is the integral it stands for: the light of a
    /// photon absorbed uniformly in element 0 falling into element `n`,
    /// `(1/a) int_{-a/2}^{a/2} int_{element n} LSF(x - u) dx du`, by a fine
    /// midpoint rule (relative error of the rule well under 1e-5 at these
    /// step counts).
    #[test]
    fn the_kernel_is_the_light_that_reaches_each_element() {
        for (s, a) in [(0.0604, 0.1), (0.0604, 0.4), (0.02, 0.085), (0.3, 0.1)] {
            let k = element_kernel(s, a).unwrap();
            let half = (k.len() / 2) as i64;
            let lsf = |x: f64| (-x.abs() / s).exp() / (2.0 * s);
            let m = 400;
            for n in 0..=half.min(4) {
                let mut acc = 0.0;
                for i in 0..m {
                    let u = -a / 2.0 + (i as f64 + 0.5) * a / m as f64;
                    for j in 0..m {
                        let x = (n as f64 - 0.5) * a + (j as f64 + 0.5) * a / m as f64;
                        acc += lsf(x - u);
                    }
                }
                let want = acc * (a / m as f64) * (a / m as f64) / a;
                let got = k[(half + n) as usize];
                assert!(
                    (got - want).abs() < 2e-4 * want.max(1e-3),
                    "s {s} a {a} n {n}: {got} against {want}"
                );
                assert_eq!(got, k[(half - n) as usize], "symmetric");
            }
            assert!((k.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        }
        assert_eq!(element_kernel(0.0, 0.1).unwrap(), vec![1.0]);
        for (s, a) in [(-0.1, 0.1), (f64::NAN, 0.1), (0.06, 0.0)] {
            assert!(element_kernel(s, a).is_err(), "{s} {a}");
        }
    }

    /// GE Senographe Essential: with the shipped scale (ge-essential.toml)
    /// the simulated detector's response (`element_response`, at its 0.1 mm
    /// elements) is the presampling MTF Ghetti et al. 2008 measured on the
    /// Essential's detector within 0.012 at each frequency, and the scale is
    /// the least-squares one to those three values (a scan in steps of
    /// 0.05 um); Hologic's gives Olgar et al.'s 0.39 at Nyquist.
    #[test]
    fn the_csi_spread_matches_the_measured_mtf() {
        let system = dbt_geometry::ConeSystem::builtin("ge-essential").unwrap();
        let s = system.line_spread_mm();
        let a = system.detector.pitch_mm;
        let measured = [(1.0, 0.85), (2.0, 0.59), (4.0, 0.24)];
        for (f, m) in measured {
            let got = element_response(s, a, f).unwrap();
            assert!((got - m).abs() < 0.012, "{f} lp/mm: {got:.3} against {m}");
        }
        let sse = |s: f64| {
            measured
                .iter()
                .map(|&(f, m)| (element_response(s, a, f).unwrap() - m).powi(2))
                .sum::<f64>()
        };
        let best = (400..3000)
            .map(|i| i as f64 * 5e-5)
            .min_by(|x, y| sse(*x).total_cmp(&sse(*y)))
            .unwrap();
        assert!((best - s).abs() < 0.15e-3, "fit {best} mm, shipped {s} mm");
        // The binned system keeps the converter's spread.
        assert_eq!(system.binned(4).unwrap().line_spread_mm(), s);
        // Hologic's tomosynthesis mode: 0.39 at the Nyquist frequency of its
        // binned 140 um elements (Olgar et al. 2013).
        let h = dbt_geometry::ConeSystem::builtin("hologic-dimensions").unwrap();
        let a = h.detector.pitch_mm;
        let got = element_response(h.line_spread_mm(), a, 0.5 / a).unwrap();
        assert!((got - 0.39).abs() < 0.002, "Hologic at Nyquist: {got:.4}");
        // Siemens's and the paper's state none.
        for name in ["paper-cone", "siemens-victre", "siemens-inspiration"] {
            let sys = dbt_geometry::ConeSystem::builtin(name).unwrap();
            assert_eq!(sys.line_spread_mm(), 0.0, "{name}");
        }
    }

    /// The spread quanta's variance: the kernel's `sum h^2` and that of
    /// photons absorbed anywhere in their element, per axis; the second is
    /// never below the first (Jensen's inequality), both at most 1, both 1
    /// without a spread; the physical one against a direct Monte Carlo of
    /// photons at uniform positions in element 0 (the mean square of the
    /// share landing in each element, 200,000 photons: within 1 %).
    /// Printed with `--nocapture` for the built-in panels.
    #[test]
    fn spread_quanta_have_the_variance_of_photons_anywhere_in_their_element() {
        for (name, system, binning) in [
            ("GE", "ge-essential", 1usize),
            ("GE binned x8", "ge-essential", 8),
            ("Hologic", "hologic-dimensions", 1),
            ("Hologic binned x6", "hologic-dimensions", 6),
        ] {
            let sys = dbt_geometry::ConeSystem::builtin(system).unwrap();
            let (s, a) = (sys.line_spread_mm(), sys.detector.pitch_mm * binning as f64);
            let (code, truth) = element_variance(s, a).unwrap();
            eprintln!(
                "{name}: 2-D quantum variance of spread quanta {:.3} of the unspread by the kernel, {:.3} for photons anywhere in their element",
                code * code,
                truth * truth
            );
            assert!(code < truth && truth < 1.0, "{name}: {code} {truth}");
            // Monte Carlo: photon at u, its light at u + x, x from the LSF.
            use rand::{Rng, SeedableRng};
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
            let n = 200_000;
            let mut shares = std::collections::BTreeMap::<i64, f64>::new();
            for _ in 0..n {
                let u: f64 = rng.random_range(-a / 2.0..a / 2.0);
                for m in -6i64..=6 {
                    let phi = cdf((m as f64 + 0.5) * a - u, s) - cdf((m as f64 - 0.5) * a - u, s);
                    *shares.entry(m).or_default() += phi * phi / n as f64;
                }
            }
            let mc: f64 = shares.values().sum();
            assert!((mc / truth - 1.0).abs() < 0.01, "{name}: {mc} {truth}");
        }
        assert_eq!(element_variance(0.0, 0.1).unwrap(), (1.0, 1.0));
    }

    /// A flat field stays flat (the mirrored borders); a point's light is
    /// all kept in its view and spread as the kernel's outer product;
    /// white noise loses the variance the kernel's squares say
    /// (`(sum h^2)^2` in two dimensions), within its sampling error.
    #[test]
    fn a_stack_spreads_view_by_view_and_conserves_light() {
        let (rows, views, cols) = (40, 3, 50);
        let l = [rows, views, cols];
        let s = 0.0604;
        let mut flat = vec![7.5; rows * views * cols];
        spread_stack(&mut flat, l, [0.1, 0.1], s).unwrap();
        assert!(flat.iter().all(|&v| (v - 7.5).abs() < 1e-12));

        let mut point = vec![0.0; rows * views * cols];
        let (r0, v0, c0) = (20, 1, 25);
        point[(r0 * views + v0) * cols + c0] = 1.0;
        spread_stack(&mut point, l, [0.1, 0.1], s).unwrap();
        let k = element_kernel(s, 0.1).unwrap();
        let half = k.len() / 2;
        let mut total = 0.0;
        for r in 0..rows {
            for v in 0..views {
                for c in 0..cols {
                    let got = point[(r * views + v) * cols + c];
                    total += got;
                    let (dr, dc) = (r as i64 - r0 as i64, c as i64 - c0 as i64);
                    let want = if v == v0
                        && dr.unsigned_abs() as usize <= half
                        && dc.unsigned_abs() as usize <= half
                    {
                        k[(dr + half as i64) as usize] * k[(dc + half as i64) as usize]
                    } else {
                        0.0
                    };
                    assert!((got - want).abs() < 1e-15, "({r}, {v}, {c}): {got} {want}");
                }
            }
        }
        assert!((total - 1.0).abs() < 1e-12);

        // White noise of unit variance (a fixed generator: reproducible).
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let (rows, cols) = (200, 200);
        let l = [rows, 1, cols];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut noise: Vec<f64> = (0..rows * cols)
            .map(|_| StandardNormal.sample(&mut rng))
            .collect();
        spread_stack(&mut noise, l, [0.1, 0.1], s).unwrap();
        let sq: f64 = k.iter().map(|h| h * h).sum();
        let want = sq * sq;
        // The interior only (the mirrored borders correlate differently).
        let (mut n, mut m2) = (0.0, 0.0);
        for r in 5..rows - 5 {
            for c in 5..cols - 5 {
                m2 += noise[r * cols + c].powi(2);
                n += 1.0;
            }
        }
        let var = m2 / n;
        // 36,100 correlated samples: the estimate's relative error is a few
        // per cent at most.
        assert!(
            (var / want - 1.0).abs() < 0.05,
            "variance {var}, expected {want}"
        );
        assert!(want < 0.7, "the spread removes noise: {want}");
        assert!(spread_stack(&mut noise, [3, 1, 3], [0.1, 0.1], s).is_err());
    }
}
