//! Noise matching (issue #27): the corrected clinical counts brought to the
//! noise of the counts the network was trained on.
//!
//! # Why
//! At an N8-equivalent dose the counts of an energy-integrating detector,
//! once the scatter is removed and the beam hardening linearised, carry
//! 1.5-2.75 times the variance that an N8 photon count has at the same
//! line integral, most under thick breasts (the scatter's photons, the
//! linearisation's stretch of the hardened log signal, the energy
//! weighting: eval/README.md, "The clinical counts' noise"). A network
//! trained at N8 reads noisier input than it learned, and its reading
//! shifts with the noise.
//!
//! # The correction
//! For every ray, with `l = ln(b / q)` its linearised line integral:
//! 1. its variance `V = a c / p^2 (dl/dP)^2`: `c` the detector's count,
//!    `p` the primary left by the scatter removal, `P = ln(b / p)` the
//!    polychromatic log signal and `dl/dP` the linearisation's slope
//!    there ([`crate::linearise::Linearisation::slope`]); `a` the
//!    detector's variance per unit of signal, measured on the acquisition
//!    itself: the open field beside the breast, as half the mean square
//!    difference of neighbouring elements there over their mean (a smooth
//!    scatter cancels in the difference);
//! 2. the variance an N8 photon count has at that line integral,
//!    `W = e^l / n`, `n` the training level's photons per element
//!    ([`NoiseMatch::target_photons`]);
//! 3. where `V > W`, `l` is averaged with the same ray (view, element) of
//!    the neighbouring detector rows (the coronal slices of a slice-wise
//!    acquisition, a cone-beam detector's rows: both along the depth),
//!    `(1 - 2w) l + w (l_up + l_down)`, `w` the weight that brings `V` to
//!    `W` for independent neighbours of like variance (at most 1/3: a
//!    third of the variance; a row with one neighbour, `(1 - w) l + w l_n`,
//!    at most a half);
//! 4. the log's excess bias is taken off: `(V - W) / 2` (the log of a
//!    noisy count reads high by half its relative variance; the training
//!    counts' own, `W / 2`, stays).
//!
//! Linear in the line integrals: the partial volume is kept on average. The
//! price is depth resolution where the counts were noisier than N8.

use crate::layout::RayLayout;
use crate::linearise::{BeamHardening, PathModel};
use rayon::prelude::*;
use thiserror::Error;

/// Why the noise cannot be matched.
#[derive(Debug, Error, PartialEq)]
pub enum NoiseMatchError {
    /// The training level's photons are not a positive number.
    #[error("noise matching to {0} photons per element: must be a positive number")]
    TargetPhotons(f64),
    /// Too little open field to measure the detector's noise.
    #[error("noise matching: {pairs} pairs of neighbouring elements in the open field beside the breast, at least {MIN_AIR_PAIRS} are needed to measure the detector's noise")]
    OpenField {
        /// The pairs found.
        pairs: usize,
    },
    /// The counts are not the header's stack, or a correction is missing.
    #[error("noise matching: {0}")]
    Input(String),
}

/// Fewest pairs of open-field elements the detector's noise is measured
/// on (its relative standard error about `sqrt(2 / pairs)`: 1.4 % at
/// 10,000).
pub const MIN_AIR_PAIRS: usize = 10_000;

/// An element is open field where the scatter removal left at least this
/// share of the flat field (the breast's edge attenuates more).
pub const AIR_PRIMARY: f64 = 0.97;

/// The heaviest neighbour weight with two neighbours (a third of the
/// variance) and with one (a half).
const W_MAX: [f64; 2] = [0.5, 1.0 / 3.0];

/// The site's noise matching: the photons per element of the level the
/// network was trained at.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseMatch {
    /// Photons per detector element without the breast of the training
    /// level (N8: 16,000, `dbt_forward::NoiseLevel::flux`).
    pub target_photons: f64,
}

/// What the matching did, for the logs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseMatchReport {
    /// The detector's variance per unit of signal measured on the open
    /// field (1 for a photon-counting detector in photons).
    pub variance_per_signal: f64,
    /// Open-field pairs it was measured on.
    pub air_pairs: usize,
    /// Rays averaged with their neighbours.
    pub matched: usize,
    /// Their mean variance ratio `V / W` before.
    pub mean_ratio: f64,
}

impl NoiseMatch {
    /// The matching to `target_photons` per element (refused unless a
    /// positive number).
    pub fn to_photons(target_photons: f64) -> Result<Self, NoiseMatchError> {
        if target_photons.is_finite() && target_photons > 0.0 {
            Ok(Self { target_photons })
        } else {
            Err(NoiseMatchError::TargetPhotons(target_photons))
        }
    }

    /// The matching to the noise level `model` was trained at (its
    /// manifest's `provenance.options.level`, e.g. `N8`); a manifest that
    /// names none, or a noise-free one, or a model trained on clinical
    /// acquisitions (whose noise is not a photon count's), is refused
    /// naming it.
    pub fn for_model(model: &dbt_dbtor::ModelManifest) -> Result<Self, NoiseMatchError> {
        // A network trained on clinical counts learned their noise, not a
        // photon count's: there is no N8 count to match it to.
        if let Some(physics) = model.provenance["dataset_provenance"]["physics"].as_str() {
            if physics != "mono" {
                return Err(NoiseMatchError::Input(format!(
                    "model {} was trained on {physics} acquisitions (its manifest's dataset provenance): its training noise is not a photon count's",
                    model.name
                )));
            }
        }
        let level = model.provenance["options"]["level"]
            .as_str()
            .ok_or_else(|| {
                NoiseMatchError::Input(format!(
                "model {} names no training noise level (its manifest's provenance.options.level)",
                model.name
            ))
            })?;
        match dbt_forward::NoiseLevel::parse(level) {
            Ok(n @ dbt_forward::NoiseLevel::Poisson(_)) => Self::to_photons(n.flux()),
            _ => Err(NoiseMatchError::Input(format!(
                "model {}: training noise level {level:?} is not a photon level such as N8",
                model.name
            ))),
        }
    }

    /// Match the linearised counts `lin` in place, from the detector's
    /// counts `raw` and the scatter removal's primary `primary` of the same
    /// acquisition (all `[row][view * cols + element]`; the header
    /// validated), linearised by `bh` (one reference tissue: the known path
    /// is refused).
    pub fn apply<H: RayLayout>(
        &self,
        h: &H,
        bh: &BeamHardening,
        raw: &[Vec<f32>],
        primary: &[Vec<f32>],
        lin: &mut [Vec<f32>],
    ) -> Result<NoiseMatchReport, NoiseMatchError> {
        let bad = |s: String| NoiseMatchError::Input(s);
        if bh.path != PathModel::Reference {
            return Err(bad(
                "implemented for the one-reference linearisation only".into()
            ));
        }
        let stack = h.check_shape(raw, "detector counts").map_err(bad)?;
        h.check_shape(primary, "primary counts").map_err(bad)?;
        h.check_shape(lin, "linearised counts").map_err(bad)?;
        let (rows, views, cols) = (stack.rows, stack.views, stack.cols);
        let per_row = views * cols;
        let table = bh
            .table(h.anode_filter, h.kvp, h.thickness_mm)
            .map_err(|e| bad(e.to_string()))?;
        let b = h.flux;
        // The detector's variance per unit of signal, on the open field.
        let (mut sq, mut sum, mut pairs) = (0.0, 0.0, 0usize);
        let open = |p: f64| p >= AIR_PRIMARY * b && p <= b / AIR_PRIMARY;
        for (rr, rp) in raw.iter().zip(primary) {
            for v in 0..views {
                let o = v * cols;
                for k in o..o + cols - 1 {
                    let (c0, c1) = (f64::from(rr[k]), f64::from(rr[k + 1]));
                    let (p0, p1) = (f64::from(rp[k]), f64::from(rp[k + 1]));
                    if open(p0) && open(p1) && c0.is_finite() && c1.is_finite() {
                        sq += (c0 - c1) * (c0 - c1);
                        sum += c0 + c1;
                        pairs += 1;
                    }
                }
            }
        }
        if pairs < MIN_AIR_PAIRS {
            return Err(NoiseMatchError::OpenField { pairs });
        }
        // E[(c0 - c1)^2] = 2 a mean: a = sq / pairs / 2 / (sum / 2 / pairs).
        let a = sq / sum;
        // Each ray's line integral (NaN where the counts are none a breast
        // gives, or darker than the thickness allows: a defect, left as read
        // for the counts check, and kept out of its neighbours' means) and
        // its own V and W.
        let dark = crate::plausibility::dark_bounds(h);
        let l: Vec<Vec<f64>> = lin
            .par_iter()
            .enumerate()
            .map(|(r, row)| {
                let bound = dark.row(r);
                row.iter()
                    .enumerate()
                    .map(|(i, &q)| {
                        if bound.get(i).is_some_and(|&d| f64::from(q) < d) {
                            f64::NAN
                        } else {
                            ln_ratio(b, q)
                        }
                    })
                    .collect()
            })
            .collect();
        let vw: Vec<Vec<(f64, f64)>> = (0..rows)
            .into_par_iter()
            .map(|r| {
                (0..per_row)
                    .map(|i| {
                        let (c, p, li) = (f64::from(raw[r][i]), f64::from(primary[r][i]), l[r][i]);
                        if !(li.is_finite() && c > 0.0 && p > 0.0 && p <= b) {
                            return (f64::NAN, f64::NAN);
                        }
                        let s = table.slope((b / p).ln());
                        (a * c / (p * p) * s * s, li.exp() / self.target_photons)
                    })
                    .collect()
            })
            .collect();
        // Each ray's ratio V / W and W, as the mean of its 3 x 3
        // neighbourhood's (rows x elements of its view) but itself: a
        // weight taken from the ray's own noisy reading would pull its high
        // readings down more than its low ones up.
        let rw: Vec<Vec<(f64, f64)>> = (0..rows)
            .into_par_iter()
            .map(|r| {
                (0..per_row)
                    .map(|i| {
                        let (v, k) = (i / cols, i % cols);
                        let (mut sr, mut sw, mut n) = (0.0, 0.0, 0.0);
                        let r0 = r.saturating_sub(1);
                        for (rr, row) in vw.iter().enumerate().skip(r0).take(r + 2 - r0) {
                            for kk in k.saturating_sub(1)..(k + 2).min(cols) {
                                let (vj, wj) = row[v * cols + kk];
                                if (rr, kk) != (r, k) && vj.is_finite() && wj > 0.0 {
                                    sr += vj / wj;
                                    sw += wj;
                                    n += 1.0;
                                }
                            }
                        }
                        if n > 0.0 && l[r][i].is_finite() {
                            (sr / n, sw / n)
                        } else {
                            (f64::NAN, f64::NAN)
                        }
                    })
                    .collect()
            })
            .collect();
        // Row by row on rayon's pool (each ray reads the unmatched line
        // integrals only: the same result whatever the pool's size).
        let per_row_counts: Vec<(usize, f64)> = lin
            .par_iter_mut()
            .enumerate()
            .map(|(r, out_row)| {
                let (mut matched, mut ratio_sum) = (0usize, 0.0);
                for i in 0..per_row {
                    let (li, (ri, target)) = (l[r][i], rw[r][i]);
                    // NaN compares false: left as read.
                    if ri.partial_cmp(&1.0) != Some(std::cmp::Ordering::Greater) {
                        continue;
                    }
                    let (mut sum_n, mut m) = (0.0, 0usize);
                    for n in [r.checked_sub(1), (r + 1 < rows).then_some(r + 1)]
                        .into_iter()
                        .flatten()
                    {
                        if l[n][i].is_finite() {
                            sum_n += l[n][i];
                            m += 1;
                        }
                    }
                    if m == 0 {
                        continue;
                    }
                    let w = weight(ri, m);
                    let mean_n = sum_n / m as f64;
                    let smoothed = (1.0 - m as f64 * w) * li + m as f64 * w * mean_n;
                    // The excess log bias: (V - W) / 2, W = e^l / n (of the
                    // neighbourhood's mean l, as the ratio).
                    let out = smoothed - (ri - 1.0) * target / 2.0;
                    out_row[i] = (b * (-out).exp()) as f32;
                    matched += 1;
                    ratio_sum += ri;
                }
                (matched, ratio_sum)
            })
            .collect();
        let matched: usize = per_row_counts.iter().map(|c| c.0).sum();
        let ratio_sum: f64 = per_row_counts.iter().map(|c| c.1).sum();
        Ok(NoiseMatchReport {
            variance_per_signal: a,
            air_pairs: pairs,
            matched,
            mean_ratio: if matched > 0 {
                ratio_sum / matched as f64
            } else {
                1.0
            },
        })
    }
}

/// `ln(b / q)` of a count a breast can give (`0 < q <= b`), else NaN.
fn ln_ratio(b: f64, q: f32) -> f64 {
    let q = f64::from(q);
    if q > 0.0 && q <= b {
        (b / q).ln()
    } else {
        f64::NAN
    }
}

/// The neighbour weight `w` that divides a ray's variance by `ratio` with
/// `m` independent neighbours of like variance (1 or 2): the variance
/// factor is `(1 - m w)^2 + m w^2`; at most [`W_MAX`] (its minimum).
pub fn weight(ratio: f64, m: usize) -> f64 {
    let (mf, wmax) = if m >= 2 {
        (2.0, W_MAX[1])
    } else {
        (1.0, W_MAX[0])
    };
    if ratio.partial_cmp(&1.0) != Some(std::cmp::Ordering::Greater) {
        return 0.0;
    }
    // (m^2 + m) w^2 - 2 m w + (1 - 1 / ratio) = 0, the smaller root.
    let (qa, qb, qc) = (mf * mf + mf, -2.0 * mf, 1.0 - 1.0 / ratio);
    let disc = qb * qb - 4.0 * qa * qc;
    if disc <= 0.0 {
        return wmax;
    }
    ((-qb - disc.sqrt()) / (2.0 * qa)).min(wmax)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::acquisition::AcquisitionHeader;
    use rand::{Rng, SeedableRng};

    /// A slice-wise acquisition header of `slices` rows on the paper
    /// geometry binned x4 (25 views of 320 elements).
    fn header(slices: usize) -> dbt_intake::SliceHeader {
        let paper = dbt_geometry::Geometry::builtin("paper").unwrap();
        dbt_intake::SliceHeader::try_from(AcquisitionHeader {
            thickness_mm: 50.0,
            slice_spacing_mm: 0.8,
            kvp: 29.0,
            ..crate::acquisition::example_header(paper.binned(4).unwrap(), slices, None)
        })
        .unwrap()
    }

    /// The detector's counts of a uniform breast (elements 80..240 of every
    /// view) beside the open field: primary `p0` under the breast plus as
    /// much scatter (SPR 1), the flat field beside it; each count drawn
    /// with the variance `a c` (Gaussian; `a` the detector's variance per
    /// unit of signal). Returns the counts and the primary (the counts less
    /// the known scatter).
    fn counts(h: &AcquisitionHeader, p0: f64, a: f64, seed: u64) -> [Vec<Vec<f32>>; 2] {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let (views, cols) = (h.geometry.n_views(), h.geometry.n_det());
        let mut normal = move || {
            // Box-Muller: two uniforms, one standard normal.
            let (u, v): (f64, f64) = (rng.random_range(1e-12..1.0), rng.random());
            (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        };
        let (mut raw, mut primary) = (Vec::new(), Vec::new());
        for _ in 0..h.slices {
            let (mut r, mut p) = (Vec::new(), Vec::new());
            for i in 0..views * cols {
                let scatter = if (80..240).contains(&(i % cols)) {
                    p0
                } else {
                    0.0
                };
                let c = if scatter > 0.0 { p0 + scatter } else { h.flux };
                let x = c + (a * c).sqrt() * normal();
                r.push(x as f32);
                p.push((x - scatter) as f32);
            }
            raw.push(r);
            primary.push(p);
        }
        [raw, primary]
    }

    /// The detector's noise is measured on the open field; a uniform
    /// breast's rays, noisier than an N8 count at their line integral (the
    /// scatter's photons), come out with the N8 count's variance (within 10
    /// %) and their mean line integral less the log's excess bias; the open
    /// field, no noisier than N8, is left as it was.
    #[test]
    fn a_noisier_breast_is_brought_to_the_target_variance() {
        let h = header(40);
        let bh = BeamHardening::csi(200.0).unwrap();
        let (p0, a) = (800.0, 1.1);
        let [raw, primary] = counts(&h, p0, a, 7);
        let mut lin = primary.clone();
        bh.apply(&h, &mut lin).unwrap();
        let before = lin.clone();
        let nm = NoiseMatch::to_photons(h.flux).unwrap();
        let r = nm.apply(&h, &bh, &raw, &primary, &mut lin).unwrap();
        assert!((r.variance_per_signal / a - 1.0).abs() < 0.03, "{r:?}");
        // What the breast's rays should read: V = a c / p^2 (dl/dP)^2
        // against W = e^l / n.
        let table = bh.table(h.anode_filter, h.kvp, h.thickness_mm).unwrap();
        let p_poly = (h.flux / p0).ln();
        let l0 = table.mono(p_poly);
        let v0 = a * 2.0 * p0 / (p0 * p0) * table.slope(p_poly).powi(2);
        let w = l0.exp() / h.flux;
        let ratio = v0 / w;
        assert!(ratio > 1.3 && ratio < 3.0, "{ratio}");
        assert!(
            (r.mean_ratio / ratio - 1.0).abs() < 0.05,
            "{r:?} against {ratio}"
        );
        let cols = h.geometry.n_det();
        let stats = |c: &[Vec<f32>], breast: bool| {
            let l: Vec<f64> = c[1..c.len() - 1]
                .iter()
                .flat_map(|row| {
                    row.iter()
                        .enumerate()
                        .filter(move |(i, _)| {
                            let k = i % cols;
                            if breast {
                                (80..240).contains(&k)
                            } else {
                                !(79..241).contains(&k)
                            }
                        })
                        .map(|(_, &q)| (h.flux / f64::from(q)).ln())
                })
                .collect();
            let m = l.iter().sum::<f64>() / l.len() as f64;
            (
                m,
                l.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / l.len() as f64,
            )
        };
        let ((m_before, v_before), (m_after, v_after)) = (stats(&before, true), stats(&lin, true));
        assert!((v_before / v0 - 1.0).abs() < 0.1, "{v_before} {v0}");
        assert!(
            (v_after / w - 1.0).abs() < 0.1,
            "{v_after} against the target {w}"
        );
        let bias = (v0 - w) / 2.0;
        assert!(
            (m_before - m_after - bias).abs() < 0.15 * bias,
            "{m_before} {m_after} {bias}"
        );
        // Every matched ray is the breast's; the open field is left.
        // (within one element of the breast's edge a ray's neighbourhood
        // holds both: the open field's beside it may be averaged with the
        // open field of the neighbouring rows, the breast's edge left)
        let breast = h.slices * h.geometry.n_views() * 160;
        let edges = h.slices * h.geometry.n_views() * 2;
        assert!(r.matched.abs_diff(breast) <= edges, "{r:?}");
        let ((_, v_air_before), (_, v_air_after)) = (stats(&before, false), stats(&lin, false));
        assert_eq!(v_air_before, v_air_after);
    }

    /// Without enough open field the detector's noise cannot be measured:
    /// refused, naming the pairs; so is the known-path linearisation and a
    /// stack that is not the header's; a target that is not a positive
    /// number is refused naming it.
    #[test]
    fn what_cannot_be_matched_is_refused() {
        let h = header(2);
        let bh = BeamHardening::csi(200.0).unwrap();
        let [raw, _] = counts(&h, 800.0, 1.0, 1);
        let mut lin = raw.clone();
        let nm = NoiseMatch::to_photons(16_000.0).unwrap();
        let e = nm.apply(&h, &bh, &raw, &raw, &mut lin).unwrap_err();
        assert!(matches!(e, NoiseMatchError::OpenField { .. }), "{e}");
        assert!(e.to_string().contains("at least 10000"), "{e}");
        let kp = bh.on_known_path(1.5).unwrap();
        let e = nm.apply(&h, &kp, &raw, &raw, &mut lin).unwrap_err();
        assert!(e.to_string().contains("one-reference"), "{e}");
        let e = nm.apply(&h, &bh, &raw[..1], &raw, &mut lin).unwrap_err();
        assert!(e.to_string().contains("1 rows of detector counts"), "{e}");
        for bad in [0.0, -5.0, f64::NAN] {
            assert!(matches!(
                NoiseMatch::to_photons(bad),
                Err(NoiseMatchError::TargetPhotons(_))
            ));
        }
        assert_eq!(lin, raw);
    }

    /// The weight gives the variance factor asked for, with one neighbour
    /// and with two, and stops at the factor's minimum.
    #[test]
    fn the_weight_divides_the_variance_as_asked() {
        for m in [1usize, 2] {
            let mf = m as f64;
            for ratio in [1.0001, 1.3, 1.53, 2.0, 2.6] {
                let w = weight(ratio, m);
                let factor = (1.0 - mf * w).powi(2) + mf * w * w;
                if ratio <= 1.0 / (if m == 2 { 1.0 / 3.0 } else { 0.5 }) {
                    assert!(
                        (factor - 1.0 / ratio).abs() < 1e-12,
                        "m {m} ratio {ratio}: {factor}"
                    );
                }
            }
            let wmax = if m == 2 { 1.0 / 3.0 } else { 0.5 };
            assert!((weight(10.0, m) - wmax).abs() < 1e-12);
            assert_eq!(weight(0.8, m), 0.0);
            assert_eq!(weight(f64::NAN, m), 0.0);
        }
    }
}
