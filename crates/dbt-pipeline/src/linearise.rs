//! Beam-hardening linearisation (issue #27): a polychromatic,
//! energy-integrating detector's log signal turned into the line integral
//! the reconstruction was trained on, that of the paper's 20 keV
//! attenuation (`dbt_materials::Tissue::mu_per_mm`).
//!
//! # The correction
//! For the acquisition's technique (the spectrum of the kV received for
//! its thickness: [`dbt_dose::xray::technique_spectrum`], the one the
//! simulator and the dose use) and the site's detector
//! ([`dbt_forward::clinical::Detector`]), the polychromatic log signal
//! `P(L) = -ln(S(L) / S(0))` of `L` mm of a reference tissue is computed
//! from the material tables on a grid of `L`, and each measured count
//! `c` is replaced by `b exp(-mu_ref L(P))`, `P = ln(b / c)`: the count of a
//! 20 keV beam through the same amount of reference tissue. The reference
//! is half adipose, half fibroglandular tissue by volume (a breast of about
//! 50 % glandularity by volume); `mu_ref` the mean of the two paper values.
//!
//! # Its error
//! Exact for the reference tissue. A ray through another mixture is
//! corrected as if it were the reference: its hardening differs in the
//! second order (fat and dense tissue harden the beam alike; their
//! coefficients' energy dependence differs by a few per cent), which the
//! tests bound; a ray's skin is corrected as reference tissue too.
//! The coefficients at 20 keV of the tables (xraylib) and the paper's
//! (Boone and Chavez) differ by under 2 %: the correction maps onto the
//! paper's scale, the one the network and the classifier know.
//!
//! # On the known path ([`PathModel::Known`])
//! The compressed thickness `T` is known (the paddle), and so is each
//! ray's path through the slab between support and paddle, `L = T sec a`
//! with `a` its angle to the vertical (the fan geometry's ray, or the
//! cone-beam system's source and detector element for its frames). With
//! the skin's share of it assumed (`2 s sec a`, `s` the skin thickness
//! [`NOMINAL_SKIN_MM`]), one polychromatic measurement leaves one unknown,
//! the dense share `f` of the interior: the ray's log signal is mapped
//! along the curve of `(1 - f)` fat and `f` dense tissue over that path,
//! `f` from 0 to 1, to its 20 keV line integral. Exact for any fat/dense
//! mixture where the ray crosses the whole thickness (the assumed skin's
//! error aside). A ray that reads less than all fat over the whole path
//! crosses less breast (the rounded edges, the nipple's region): it is
//! mapped as fat and skin in the same proportion over a shorter path,
//! continuous with the full path's all-fat end; one that reads more than
//! all dense (noise) as dense tissue over a longer path. The curves are
//! computed on a grid of `sec a` ([`SEC_STEP`]) and interpolated between.

use crate::layout::RayLayout;
use dbt_dose::xray::AnodeFilter;
use dbt_forward::clinical::{ClinicalPhysics, Detector};
use dbt_materials::{Converter, ConverterError, ConverterMaterial, Tissue};
use rayon::prelude::*;
use thiserror::Error;

/// Why the linearisation cannot be made.
#[derive(Debug, Error, PartialEq)]
pub enum LineariseError {
    /// A converter layer's thickness outside
    /// [`dbt_materials::CONVERTER_UM`] (or not a number).
    #[error(transparent)]
    Converter(#[from] ConverterError),
    /// The correction is for another converter than the acquisition's
    /// cone-beam system has (its file's, else 200 um of CsI).
    #[error(
        "the beam-hardening linearisation is for a detector of {configured} but the \
         acquisition's system {system} has {has}: linearise for its converter \
         (recon.beam_hardening and converter_um; dbtor-process --csi-um / --a-se-um)"
    )]
    OtherConverter {
        /// The converter the correction was computed for.
        configured: Converter,
        /// The system's name.
        system: String,
        /// The system's converter.
        has: Converter,
    },
    /// A skin thickness outside [`SKIN_MM`] (or not a number).
    #[error("{0} mm: the known-path linearisation takes a skin {lo}-{hi} mm thick", lo = SKIN_MM.start(), hi = SKIN_MM.end())]
    SkinThickness(f64),
    /// The technique's spectrum or the detector model failed.
    #[error("beam-hardening linearisation for {thickness_mm} mm: {reason}")]
    Model {
        /// The acquisition's thickness.
        thickness_mm: f64,
        /// What failed.
        reason: String,
    },
}

/// Longest reference path of the table, mm (beyond it: extrapolated
/// linearly from the last step, where no breast reaches).
const L_MAX_MM: f64 = 300.0;
/// Table step, mm.
const L_STEP_MM: f64 = 0.5;

/// The skin thicknesses the known-path linearisation accepts, mm.
pub const SKIN_MM: std::ops::RangeInclusive<f64> = 0.0..=4.0;

/// The skin thickness the known-path linearisation assumes, mm: the
/// procedural population's mid-range (1.2-1.8 mm,
/// `dbt_phantom::generate`); breast CT measured 1.44 +- 0.25 mm (Shi et al.
/// 2013, Med Phys 40:031913, the anatomical generator's figure).
pub const NOMINAL_SKIN_MM: f64 = 1.5;

/// Step of the grid of `sec a` on which the known-path curves are computed
/// (0.1 mm of path at 50 mm).
pub const SEC_STEP: f64 = 0.002;

/// What the linearisation knows of each ray's path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PathModel {
    /// Nothing: every ray is taken as the half-fat, half-dense reference
    /// tissue, of whatever length its signal gives.
    Reference,
    /// The ray's path through the compressed slab, with skin `skin_mm`
    /// thick on both faces (the module's "On the known path").
    Known {
        /// The skin thickness assumed, mm.
        skin_mm: f64,
    },
}

/// The site's beam-hardening correction: its detector, and what it knows
/// of each ray's path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BeamHardening {
    /// The detector the correction is computed for.
    pub detector: Detector,
    /// One reference tissue, or the known path.
    pub path: PathModel,
}

/// The linearisation table of one technique.
#[derive(Debug, Clone, PartialEq)]
pub struct Linearisation {
    /// Polychromatic log signal at `L = k L_STEP_MM`, increasing.
    poly: Vec<f64>,
    /// The reference's 20 keV attenuation, 1/mm.
    mu_ref: f64,
}

impl BeamHardening {
    /// The correction for a CsI flat panel `csi_um` thick (the detector's
    /// other properties at their defaults); a thickness outside
    /// [`dbt_materials::CONVERTER_UM`] is refused, naming it.
    pub fn csi(csi_um: f64) -> Result<Self, LineariseError> {
        Self::for_converter(Converter {
            material: ConverterMaterial::CsI,
            thickness_um: csi_um,
        })
    }

    /// The correction for a flat panel with `converter` (CsI or a-Se; the
    /// detector's other properties at their defaults); a thickness outside
    /// [`dbt_materials::CONVERTER_UM`] is refused, naming it.
    pub fn for_converter(converter: Converter) -> Result<Self, LineariseError> {
        converter.validate()?;
        Ok(Self {
            detector: Detector::with(converter),
            path: PathModel::Reference,
        })
    }

    /// The same detector's correction on the known path, skin `skin_mm`
    /// thick (outside [`SKIN_MM`] refused, naming it).
    pub fn on_known_path(self, skin_mm: f64) -> Result<Self, LineariseError> {
        if !(skin_mm.is_finite() && SKIN_MM.contains(&skin_mm)) {
            return Err(LineariseError::SkinThickness(skin_mm));
        }
        Ok(Self {
            path: PathModel::Known { skin_mm },
            ..self
        })
    }

    /// The detector model for the beam `af` at `kvp` (a breast
    /// `thickness_mm` thick chooses the spectrum's options), signal 1
    /// without the breast.
    fn physics(
        &self,
        af: AnodeFilter,
        kvp: f64,
        thickness_mm: f64,
    ) -> Result<ClinicalPhysics, LineariseError> {
        let fail = |reason: String| LineariseError::Model {
            thickness_mm,
            reason,
        };
        let tube = dbt_dose::xray::technique_spectrum(af, kvp, thickness_mm)
            .map_err(|e| fail(e.to_string()))?;
        let spectrum = tube.spectrum.ok_or_else(|| fail("no spectrum".into()))?;
        // The photon number scales the signal only: 1 photon, flat = 1.
        ClinicalPhysics::new(&spectrum, 1.0, &self.detector, 1.0).map_err(|e| fail(e.to_string()))
    }

    /// The table for an exposure with the beam `af` at `kvp` of a breast
    /// `thickness_mm` thick (its spectrum:
    /// [`dbt_dose::xray::technique_spectrum`]).
    pub fn table(
        &self,
        af: AnodeFilter,
        kvp: f64,
        thickness_mm: f64,
    ) -> Result<Linearisation, LineariseError> {
        let model = self.physics(af, kvp, thickness_mm)?;
        let n = (L_MAX_MM / L_STEP_MM) as usize + 1;
        let poly = (0..n)
            .map(|k| {
                let l = k as f64 * L_STEP_MM;
                -model.expected([l / 2.0, l / 2.0, 0.0]).0.ln()
            })
            .collect();
        Ok(Linearisation {
            poly,
            mu_ref: f64::from(Tissue::Adipose.mu_per_mm() + Tissue::Fibroglandular.mu_per_mm())
                / 2.0,
        })
    }

    /// Refuse counts from a cone-beam system whose converter (its file's,
    /// else 200 um of CsI: [`dbt_geometry::ConeSystem::converter`]) is not
    /// this correction's, naming both: the CsI correction of an a-Se
    /// panel's signal reads 80 mm of tissue 1.6-3.4 % short, several
    /// points of glandularity, with nothing else to show it.
    pub fn check_converter<H: RayLayout>(&self, h: &H) -> Result<(), LineariseError> {
        match h.cone_system() {
            Some(sys) if sys.converter() != self.detector.converter => {
                Err(LineariseError::OtherConverter {
                    configured: self.detector.converter,
                    system: sys.name.clone(),
                    has: sys.converter(),
                })
            }
            _ => Ok(()),
        }
    }

    /// Linearise an acquisition's counts in place (`counts[row][view *
    /// cols + element]`: coronal slices' sinograms, or a cone-beam
    /// detector's frames; flat field `h.flux`; the header already
    /// validated): counts a breast can give (`0 < c <= b`) are mapped; any
    /// other value passes as read, for the counts check to name it.
    /// Returns how many were mapped.
    pub fn apply<H: RayLayout>(
        &self,
        h: &H,
        counts: &mut [Vec<f32>],
    ) -> Result<usize, LineariseError> {
        self.check_converter(h)?;
        if let PathModel::Known { skin_mm } = self.path {
            return self.apply_on_known_path(h, counts, skin_mm);
        }
        let t = self.table(h.anode_filter, h.kvp, h.thickness_mm)?;
        let b = h.flux;
        let mut n = 0;
        for c in counts.iter_mut().flat_map(|s| s.iter_mut()) {
            let v = f64::from(*c);
            if v > 0.0 && v <= b {
                *c = (b * (-t.mono((b / v).ln())).exp()) as f32;
                n += 1;
            }
        }
        Ok(n)
    }

    /// The known-path curves of an exposure with the beam `af` at `kvp`
    /// of a breast `thickness_mm` thick, skin `skin_mm`, for rays whose
    /// `sec a` lies within `[sec_lo, sec_hi]`.
    pub fn known_path_table(
        &self,
        af: AnodeFilter,
        kvp: f64,
        thickness_mm: f64,
        skin_mm: f64,
        (sec_lo, sec_hi): (f64, f64),
    ) -> Result<KnownPathTable, LineariseError> {
        let fail = |reason: String| LineariseError::Model {
            thickness_mm,
            reason,
        };
        if !(sec_lo.is_finite() && sec_hi.is_finite() && 1.0 <= sec_lo && sec_lo <= sec_hi) {
            return Err(fail(format!(
                "ray secants {sec_lo}-{sec_hi}: a ray crossing the slab has a secant of at least 1"
            )));
        }
        if !(skin_mm.is_finite() && SKIN_MM.contains(&skin_mm) && 2.0 * skin_mm < thickness_mm) {
            return Err(LineariseError::SkinThickness(skin_mm));
        }
        let model = self.physics(af, kvp, thickness_mm)?;
        let n = (((sec_hi - sec_lo) / SEC_STEP).ceil() as usize + 1).max(2);
        let step = ((sec_hi - sec_lo) / (n - 1) as f64).max(SEC_STEP / 4.0);
        let mu = [Tissue::Adipose, Tissue::Fibroglandular, Tissue::Skin]
            .map(|t| f64::from(t.mu_per_mm()));
        let curves = (0..n)
            .map(|i| {
                let sec = sec_lo + i as f64 * step;
                let skin = 2.0 * skin_mm * sec;
                let interior = thickness_mm * sec - skin;
                // (fat, dense, skin) along the curve: a shorter path of fat
                // and skin in the same proportion, the full path from all
                // fat to all dense, then more dense tissue than the path
                // holds.
                let shorter = (0..KP_SHORTER).map(|m| {
                    let x = m as f64 / KP_SHORTER as f64;
                    [interior * x, 0.0, skin * x]
                });
                let full = (0..=KP_MIXTURE).map(|j| {
                    let f = j as f64 / KP_MIXTURE as f64;
                    [interior * (1.0 - f), interior * f, skin]
                });
                let longer = (1..=KP_LONGER).map(|m| {
                    let extra = 0.5 * interior * m as f64 / KP_LONGER as f64;
                    [0.0, interior + extra, skin]
                });
                let (p, mono): (Vec<f64>, Vec<f64>) = shorter
                    .chain(full)
                    .chain(longer)
                    .map(|l| {
                        (
                            -model.expected(l).0.ln(),
                            mu[0] * l[0] + mu[1] * l[1] + mu[2] * l[2],
                        )
                    })
                    .unzip();
                // NaN compares false: not increasing either.
                let increasing = |v: &[f64]| v.windows(2).all(|w| w[0] < w[1]);
                if !(increasing(&p) && increasing(&mono)) {
                    return Err(fail(format!(
                        "the known-path curve at secant {sec:.4} is not increasing"
                    )));
                }
                Ok(Curve { p, mono })
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(KnownPathTable {
            sec_lo,
            step,
            curves,
        })
    }

    fn apply_on_known_path<H: RayLayout>(
        &self,
        h: &H,
        counts: &mut [Vec<f32>],
        skin_mm: f64,
    ) -> Result<usize, LineariseError> {
        let fail = |reason: String| LineariseError::Model {
            thickness_mm: h.thickness_mm,
            reason,
        };
        h.check_shape(counts, "counts").map_err(fail)?;
        // Each ray's sec a: the fan's rays are every slice's; the cone's
        // differ by detector row too.
        let sec = h.ray_secants();
        let t =
            self.known_path_table(h.anode_filter, h.kvp, h.thickness_mm, skin_mm, sec.range())?;
        let b = h.flux;
        let n = counts.par_iter_mut().enumerate().map(|(r, row)| {
            let sec = sec.row(r);
            let mut n = 0;
            for (c, &s) in row.iter_mut().zip(sec) {
                let v = f64::from(*c);
                if v > 0.0 && v <= b {
                    *c = (b * (-t.mono((b / v).ln(), s)).exp()) as f32;
                    n += 1;
                }
            }
            n
        });
        Ok(n.sum())
    }
}

/// Points of a known-path curve below the full path (fat and skin).
const KP_SHORTER: usize = 40;
/// Points of a known-path curve along the full path (dense share 0..=1).
const KP_MIXTURE: usize = 20;
/// Points of a known-path curve beyond all dense tissue.
const KP_LONGER: usize = 8;

/// One known-path curve: log signal and 20 keV line integral, both
/// increasing.
#[derive(Debug, Clone, PartialEq)]
struct Curve {
    p: Vec<f64>,
    mono: Vec<f64>,
}

impl Curve {
    fn mono(&self, p: f64) -> f64 {
        let k = self
            .p
            .partition_point(|&q| q < p)
            .max(1)
            .min(self.p.len() - 1);
        // Linear within the curve; its end segments extended beyond it.
        let (p0, p1) = (self.p[k - 1], self.p[k]);
        let (m0, m1) = (self.mono[k - 1], self.mono[k]);
        m0 + (p - p0) * (m1 - m0) / (p1 - p0)
    }
}

/// The known-path linearisation of one exposure: a curve per `sec a` on a
/// grid ([`BeamHardening::known_path_table`]).
#[derive(Debug, Clone, PartialEq)]
pub struct KnownPathTable {
    sec_lo: f64,
    step: f64,
    curves: Vec<Curve>,
}

impl KnownPathTable {
    /// The 20 keV line integral of a ray with log signal `p` whose path
    /// crosses the slab at `sec a` = `sec` (interpolated between the
    /// grid's curves; clamped to the grid).
    pub fn mono(&self, p: f64, sec: f64) -> f64 {
        let last = self.curves.len() - 1;
        let x = ((sec - self.sec_lo) / self.step).clamp(0.0, last as f64);
        let i = (x.floor() as usize).min(last - 1);
        let w = x - i as f64;
        (1.0 - w) * self.curves[i].mono(p) + w * self.curves[i + 1].mono(p)
    }
}

impl Linearisation {
    /// The 20 keV line integral of the reference tissue whose polychromatic
    /// log signal is `p` (linear between table points).
    pub fn mono(&self, p: f64) -> f64 {
        if p <= 0.0 {
            return p * self.slope_at(0);
        }
        let k = self.poly.partition_point(|&q| q < p);
        let l = if k >= self.poly.len() {
            // Beyond the table: the last step's slope.
            let last = self.poly.len() - 1;
            last as f64 * L_STEP_MM + (p - self.poly[last]) / self.slope_at(last - 1)
        } else {
            let (a, b) = (self.poly[k - 1], self.poly[k]);
            ((k - 1) as f64 + (p - a) / (b - a)) * L_STEP_MM
        };
        self.mu_ref * l
    }

    /// `d mono / d p` at the polychromatic log signal `p`: the slope of the
    /// table's segment `p` falls in (the first one below it, the last
    /// one's beyond it).
    pub fn slope(&self, p: f64) -> f64 {
        let last = self.poly.len() - 1;
        let k = self.poly.partition_point(|&q| q < p).clamp(1, last);
        self.mu_ref * L_STEP_MM / (self.poly[k] - self.poly[k - 1])
    }

    /// Polychromatic log signal per mm of reference tissue at table step `k`.
    fn slope_at(&self, k: usize) -> f64 {
        (self.poly[k + 1] - self.poly[k]) / L_STEP_MM
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bh() -> BeamHardening {
        BeamHardening {
            detector: Detector::default(),
            path: PathModel::Reference,
        }
    }

    /// A CsI panel's thickness within [`dbt_materials::CONVERTER_UM`]
    /// gives that detector (the rest at its defaults); one outside, or not
    /// a number, is refused naming it; an a-Se panel likewise.
    #[test]
    fn a_csi_thickness_is_checked() {
        assert_eq!(BeamHardening::csi(200.0).unwrap(), bh());
        assert_eq!(
            BeamHardening::csi(50.0)
                .unwrap()
                .detector
                .converter
                .thickness_um,
            50.0
        );
        for bad in [5.0, 1000.5, f64::NAN, f64::INFINITY] {
            let e = BeamHardening::csi(bad).unwrap_err();
            assert!(matches!(e, LineariseError::Converter(_)), "{e}");
            assert!(e.to_string().contains("50-1000 um"), "{e}");
        }
        let a_se = Converter {
            material: ConverterMaterial::ASe,
            thickness_um: 2.0,
        };
        let e = BeamHardening::for_converter(a_se).unwrap_err().to_string();
        assert!(e.starts_with("2 um of a-Se"), "{e}");
        assert!(BeamHardening::csi(5.0)
            .unwrap_err()
            .to_string()
            .starts_with("5 um"));
    }

    /// Each beam's spectrum at its automatic exposure for a 50 mm breast.
    fn beams() -> Vec<(AnodeFilter, f64, dbt_dose::Spectrum)> {
        AnodeFilter::ALL
            .into_iter()
            .map(|af| {
                let s = dbt_dose::xray::aec_spectrum(af, 50.0).unwrap();
                (af, f64::from(s.kv), s.spectrum.unwrap())
            })
            .collect()
    }

    /// Exact for the reference tissue: its polychromatic signal through any
    /// path maps to the paper's 20 keV line integral of that path, for
    /// either beam.
    #[test]
    fn the_reference_tissue_is_linearised_exactly() {
        let b = bh();
        for (af, kv, s) in beams() {
            let t = b.table(af, kv, 50.0).unwrap();
            let m = ClinicalPhysics::new(&s, 1.0, &Detector::default(), 1.0).unwrap();
            for l in [0.0, 3.3, 25.0, 50.0, 77.7, 140.0] {
                let p = -m.expected([l / 2.0, l / 2.0, 0.0]).0.ln();
                let want = l * (0.0512 + 0.0798) / 2.0;
                assert!(
                    (t.mono(p) - want).abs() < 1e-4,
                    "{af} {l} mm: {} vs {want}",
                    t.mono(p)
                );
            }
        }
        // The W/Rh table is the paper's Table 3 spectrum's.
        assert_eq!(beams()[0].1, 29.0);
    }

    /// An a-Se detector's correction is exact for its own signal (the
    /// reference tissue through any path, either beam), and the converter
    /// matters: the CsI correction applied to an a-Se panel's signal reads
    /// 80 mm of reference tissue 1-4 % short (what a site configured with
    /// the wrong converter would get; the firmware refuses a converter
    /// other than its cone-beam system's).
    #[test]
    fn an_a_se_panel_is_linearised_exactly_with_its_own_table() {
        let a_se = Converter::new(ConverterMaterial::ASe, 200.0).unwrap();
        let b = BeamHardening::for_converter(a_se).unwrap();
        for (af, kv, s) in beams() {
            let t = b.table(af, kv, 50.0).unwrap();
            let wrong = bh().table(af, kv, 50.0).unwrap();
            let m = ClinicalPhysics::new(&s, 1.0, &Detector::with(a_se), 1.0).unwrap();
            for l in [0.0, 3.3, 25.0, 50.0, 77.7, 140.0] {
                let p = -m.expected([l / 2.0, l / 2.0, 0.0]).0.ln();
                let want = l * (0.0512 + 0.0798) / 2.0;
                assert!(
                    (t.mono(p) - want).abs() < 1e-4,
                    "{af} {l} mm: {}",
                    t.mono(p)
                );
            }
            let p = -m.expected([40.0, 40.0, 0.0]).0.ln();
            let off = wrong.mono(p) / (80.0 * (0.0512 + 0.0798) / 2.0) - 1.0;
            eprintln!(
                "{af}: the CsI table on an a-Se signal, 80 mm: {:+.2} %",
                100.0 * off
            );
            assert!(off < -0.01 && off > -0.04, "{af}: {off}");
        }
    }

    /// Another tissue: all fat or all dense tissue of a 50 mm breast. W/Rh
    /// is corrected to within 1 % of its 20 keV line integral (the
    /// second-order error of one reference; uncorrected: fat +1.4 %, dense
    /// tissue -4.3 %, dense tissue hardening the beam more). The broader,
    /// harder W/Al beam (32 kV, mean 21.1 keV against 19.4) reads both far
    /// lower uncorrected (-12.8 %, -22.3 %) and keeps +3.2 % and -2.8 %
    /// after the correction: one reference cannot undo the fat-to-dense
    /// contrast lost at its higher energies (14 % of it; W/Rh 4 %), which
    /// is why the glandularity calibration is per beam (eval/README.md,
    /// "W/Al"). W/Ag (26 kV, mean 19.4 keV, silver's K edge cutting the
    /// spectrum above 25.5 keV) keeps +1.0 % and -1.1 % (uncorrected +0.5 %
    /// and -6.1 %). The molybdenum and rhodium anodes' softer beams read
    /// both tissues high uncorrected (Mo/Mo 27 kV, mean 16.8 keV: +30.5 %
    /// and +25.8 %) and keep Mo/Mo -1.5 % and +0.4 %, Mo/Rh -0.4 % and
    /// -0.3 %, Rh/Rh +0.5 % and -0.8 % after it.
    #[test]
    fn other_tissues_are_corrected_to_the_second_order() {
        for (af, kv, s) in beams() {
            let t = bh().table(af, kv, 50.0).unwrap();
            let m = ClinicalPhysics::new(&s, 1.0, &Detector::default(), 1.0).unwrap();
            for (paths, mu, uncorrected_pct) in [
                ([50.0, 0.0, 0.0], 0.0512, 1.4),
                ([0.0, 50.0, 0.0], 0.0798, -4.3),
            ] {
                let p = -m.expected(paths).0.ln();
                let want = 50.0 * mu;
                let off = 100.0 * (p / want - 1.0);
                if af == AnodeFilter::WRh {
                    // The figures eval/README.md quotes, to their last digit.
                    assert!((off - uncorrected_pct).abs() < 0.05, "{paths:?}: {off} %");
                }
                let got = t.mono(p);
                // The figures the doc above and eval/README.md ("The W/Al
                // beam") quote: `cargo test -p dbt-pipeline --lib linearise
                // -- --nocapture`.
                eprintln!(
                    "{af} {kv} kV (mean {:.1} keV) {paths:?}: uncorrected {off:+.1} %, corrected {:+.2} %",
                    s.mean(),
                    100.0 * (got / want - 1.0)
                );
                let bound = match af {
                    AnodeFilter::WRh => 0.01,
                    AnodeFilter::WAl => 0.035,
                    AnodeFilter::WAg => 0.015,
                    AnodeFilter::MoMo => 0.02,
                    AnodeFilter::MoRh | AnodeFilter::RhRh => 0.01,
                };
                assert!(
                    (got / want - 1.0).abs() < bound,
                    "{af} {paths:?}: {got} vs {want} (uncorrected {off} %)"
                );
                // Where the beam already reads a path within 1 % of its
                // line integral (W/Ag's fat, +0.5 %; Rh/Rh's dense tissue,
                // -0.6 %: both beams' means near the paper's 20 keV), the
                // one reference may move it the wrong way by as much;
                // elsewhere the correction improves it.
                if (p / want - 1.0).abs() > 0.01 {
                    assert!(
                        (got - want).abs() < (p - want).abs(),
                        "{af} {paths:?}: {got} vs {p}"
                    );
                }
            }
        }
    }

    /// On the known path, any fat/dense mixture over the whole thickness
    /// maps to its 20 keV line integral, skin included, for either beam,
    /// at any ray angle (between the grid's secants too): within 0.02 %
    /// (the curves' linear interpolation), where one reference leaves W/Al
    /// +3.2 % and -2.8 % (the test above). A shorter path of fat and skin
    /// in the assumed proportion maps exactly too, and the curve is
    /// continuous where the two meet.
    #[test]
    fn mixtures_on_the_known_path_are_linearised_exactly() {
        let kp = bh().on_known_path(NOMINAL_SKIN_MM).unwrap();
        let mu = [0.0512, 0.0798, 0.0854];
        for (af, kv, s) in beams() {
            let m = ClinicalPhysics::new(&s, 1.0, &Detector::default(), 1.0).unwrap();
            let t = kp
                .known_path_table(af, kv, 50.0, NOMINAL_SKIN_MM, (1.0, 1.13))
                .unwrap();
            for sec in [1.0, 1.0537, 1.1011, 1.13] {
                let skin = 2.0 * NOMINAL_SKIN_MM * sec;
                let interior = 50.0 * sec - skin;
                let mut worst: f64 = 0.0;
                for f in [0.0, 0.13, 0.5, 0.77, 1.0] {
                    let l = [interior * (1.0 - f), interior * f, skin];
                    let p = -m.expected(l).0.ln();
                    let want = mu[0] * l[0] + mu[1] * l[1] + mu[2] * l[2];
                    worst = worst.max((t.mono(p, sec) / want - 1.0).abs());
                }
                for x in [0.1, 0.5, 0.93] {
                    let l = [interior * x, 0.0, skin * x];
                    let p = -m.expected(l).0.ln();
                    let want = mu[0] * l[0] + mu[2] * l[2];
                    worst = worst.max((t.mono(p, sec) / want - 1.0).abs());
                }
                assert!(worst < 2e-4, "{af} sec {sec}: {worst}");
                // Continuous at the full path's all-fat end.
                let p = -m.expected([interior, 0.0, skin]).0.ln();
                let (below, above) = (t.mono(p - 1e-9, sec), t.mono(p + 1e-9, sec));
                assert!((above - below).abs() < 1e-6, "{af} sec {sec}");
            }
            eprintln!(
                "{af} {kv} kV: fat, dense and their mixtures within 0.02 % on the known path"
            );
        }
    }

    /// A skin the correction cannot assume, or a thickness it leaves no
    /// interior in, is refused naming it; so is a ray that cannot cross the
    /// slab, and counts that are not the header's stack.
    #[test]
    fn the_known_path_refuses_what_it_cannot_use() {
        for bad in [-0.1, 4.5, f64::NAN] {
            let e = bh().on_known_path(bad).unwrap_err();
            assert!(matches!(e, LineariseError::SkinThickness(_)), "{e}");
            assert!(e.to_string().contains("0-4 mm"), "{e}");
        }
        let kp = bh().on_known_path(1.5).unwrap();
        let (af, kv, _) = beams().remove(0);
        assert!(kp.known_path_table(af, kv, 2.5, 1.5, (1.0, 1.1)).is_err());
        let e = kp
            .known_path_table(af, kv, 50.0, 1.5, (0.9, 1.1))
            .unwrap_err();
        assert!(e.to_string().contains("secant"), "{e}");
        let mut c = vec![vec![8_000.0; 7]];
        let e = kp.apply(&header(), &mut c).unwrap_err();
        assert!(
            e.to_string()
                .contains("1 rows of counts for a stack of 1 rows x"),
            "{e}"
        );
        assert_eq!(c[0][0], 8_000.0);
    }

    /// Each ray is linearised on its own path: the slice-wise fan's rays
    /// (every slice alike) and a cone-beam system's frames (each detector
    /// row's rays slanted along the chest-wall-to-nipple axis too). Counts
    /// made of 40 % dense interior over each ray's whole path come back as
    /// that path's 20 keV transmission.
    #[test]
    fn each_ray_is_linearised_on_its_own_path() {
        let kp = bh().on_known_path(NOMINAL_SKIN_MM).unwrap();
        let cone = dbt_geometry::ConeSystem::builtin("paper-cone")
            .unwrap()
            .binned(8)
            .unwrap();
        let paper = dbt_geometry::Geometry::builtin("paper").unwrap();
        let fan = crate::acquisition::example_header(paper.clone(), 1, None);
        on_its_own_path(&kp, &dbt_intake::SliceHeader::try_from(fan).unwrap());
        let frames = crate::acquisition::example_header(paper, 1, None);
        on_its_own_path(&kp, &dbt_intake::ConeHeader::new(frames, cone));
    }

    fn on_its_own_path<H: RayLayout>(kp: &BeamHardening, h: &H) {
        let sec = h.ray_secants();
        let s = dbt_dose::xray::technique_spectrum(h.anode_filter, h.kvp, h.thickness_mm)
            .unwrap()
            .spectrum
            .unwrap();
        let m = ClinicalPhysics::new(&s, 1.0, &Detector::default(), 1.0).unwrap();
        let stack = h.stack();
        let (rows, per_row) = (stack.rows, stack.views * stack.cols);
        let path = |sec: f64| {
            let skin = 2.0 * NOMINAL_SKIN_MM * sec;
            let interior = h.thickness_mm * sec - skin;
            [interior * 0.6, interior * 0.4, skin]
        };
        let mut c: Vec<Vec<f32>> = (0..rows)
            .map(|r| {
                sec.row(r)
                    .iter()
                    .map(|&s| (h.flux * m.expected(path(s)).0) as f32)
                    .collect()
            })
            .collect();
        assert_eq!(kp.apply(h, &mut c).unwrap(), rows * per_row);
        let (lo, hi) = sec.range();
        assert!(lo >= 1.0 && hi > 1.05, "{lo} {hi}");
        for (r, row) in c.iter().enumerate() {
            for (i, &v) in row.iter().enumerate() {
                let l = path(sec.row(r)[i]);
                let want = 0.0512 * l[0] + 0.0798 * l[1] + 0.0854 * l[2];
                let got = (h.flux / f64::from(v)).ln();
                assert!(
                    (got / want - 1.0).abs() < 5e-4,
                    "row {r} ray {i}: {got} vs {want}"
                );
            }
        }
    }

    fn header() -> dbt_intake::SliceHeader {
        let paper = dbt_geometry::Geometry::builtin("paper").unwrap();
        dbt_intake::SliceHeader::try_from(crate::acquisition::example_header(paper, 1, None))
            .unwrap()
    }

    /// Counts a breast cannot give pass as read; the others map.
    #[test]
    fn impossible_counts_pass_unchanged() {
        let h = header();
        let mut c = vec![vec![
            0.0,
            -1.0,
            f32::NAN,
            65535.0,
            16_000.0,
            8_000.0,
            20_000.0,
        ]];
        let n = bh().apply(&h, &mut c).unwrap();
        assert_eq!(n, 2);
        assert_eq!(c[0][..2], [0.0, -1.0]);
        assert!(c[0][2].is_nan());
        assert_eq!(c[0][3], 65535.0);
        assert_eq!(c[0][4], 16_000.0);
        assert_ne!(c[0][5], 8_000.0);
        assert_eq!(c[0][6], 20_000.0);
    }
}
