//! X-ray spectra of the gantry: TASMICS tungsten-anode spectra (Hernandez and
//! Boone 2014; table copied from `shared/data/tasmics`, 1 keV bins) filtered by
//! rhodium, with the rhodium thickness solved per tube voltage so that the
//! first half-value layer in aluminium matches the paper's measured HVL
//! (Table 3). The spectrum is chosen by compressed thickness as in that table.

use crate::material::Material;
use crate::spectrum::Spectrum;
use crate::tables::elements;
use crate::DoseError;
use dbt_materials::{ElementFraction, AIR};

const TASMICS_CSV: &str = include_str!("../data/tasmics_w_unfiltered.csv");

/// Density of rhodium, g/cm^3.
pub const RH_DENSITY: f64 = 12.41;
/// Density of aluminium, g/cm^3 (type 1100).
pub const AL_DENSITY: f64 = 2.699;

/// The paper's Table 3: thickness range (mm), tube voltage (kV), HVL (mm Al).
pub const PAPER_TABLE3: [((f64, f64), u32, f64); 5] = [
    ((30.0, 40.0), 27, 0.519),
    ((40.0, 50.0), 28, 0.530),
    ((50.0, 60.0), 29, 0.538),
    ((60.0, 70.0), 30, 0.547),
    ((70.0, 80.0), 31, 0.557),
];

/// Unfiltered TASMICS fluence per 1 keV bin at `kv` (energies 1..kV keV).
pub fn tasmics(kv: u32) -> Result<(Vec<f64>, Vec<f64>), DoseError> {
    let mut lines = TASMICS_CSV.lines().filter(|l| !l.starts_with('#'));
    let header = lines.next().unwrap_or("");
    let col = header
        .split(',')
        .position(|h| h.trim() == format!("kV{kv}"))
        .ok_or_else(|| DoseError::Spectrum(format!("TASMICS has no {kv} kV column (20..150)")))?;
    let (mut e, mut w) = (Vec::new(), Vec::new());
    for l in lines {
        let c: Vec<&str> = l.split(',').collect();
        let (Some(es), Some(ws)) = (c.first(), c.get(col)) else {
            continue;
        };
        let (Ok(ev), Ok(wv)) = (es.trim().parse::<f64>(), ws.trim().parse::<f64>()) else {
            return Err(DoseError::Spectrum(format!("TASMICS row `{l}`")));
        };
        if wv > 0.0 {
            e.push(ev);
            w.push(wv);
        }
    }
    Ok((e, w))
}

fn element_material(z: u8, density: f64) -> Result<Material, DoseError> {
    Material::new(
        &format!("Z{z}"),
        density,
        &[ElementFraction { z, fraction: 1.0 }],
        elements()?,
    )
}

/// Attenuating filters and the air-kerma weighting.
pub struct Filters {
    rh: Material,
    al: Material,
    air: Material,
}

impl Filters {
    /// Build from the compiled-in tables.
    pub fn new() -> Result<Self, DoseError> {
        Ok(Self {
            rh: element_material(45, RH_DENSITY)?,
            al: element_material(13, AL_DENSITY)?,
            air: Material::new("air", AIR.density, AIR.elements, elements()?)?,
        })
    }

    /// Apply `rh_mm` of rhodium to a fluence spectrum.
    pub fn filter_rh(&self, e: &[f64], w: &[f64], rh_mm: f64) -> Vec<f64> {
        e.iter()
            .zip(w)
            .map(|(&e, &w)| w * (-self.rh.mu(e).total() * rh_mm).exp())
            .collect()
    }

    /// Air kerma (relative) behind `al_mm` of aluminium: `sum phi E mu_en(air)`.
    pub fn kerma(&self, e: &[f64], w: &[f64], al_mm: f64) -> f64 {
        e.iter()
            .zip(w)
            .map(|(&e, &w)| {
                w * e * self.air.mu_en(e) / self.air.density
                    * (-self.al.mu(e).total() * al_mm).exp()
            })
            .sum()
    }

    /// First HVL in mm Al (bisection to 1e-6 mm).
    pub fn hvl_mm_al(&self, e: &[f64], w: &[f64]) -> f64 {
        let k0 = self.kerma(e, w, 0.0);
        let (mut lo, mut hi) = (0.0, 20.0);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if self.kerma(e, w, mid) > 0.5 * k0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    /// Rhodium thickness (mm) giving the target HVL at `kv`.
    pub fn solve_rh(&self, kv: u32, hvl_mm: f64) -> Result<f64, DoseError> {
        let (e, w) = tasmics(kv)?;
        let f = |rh: f64| self.hvl_mm_al(&e, &self.filter_rh(&e, &w, rh));
        let (mut lo, mut hi) = (0.0, 0.5);
        if !(f(lo) <= hvl_mm && f(hi) >= hvl_mm) {
            return Err(DoseError::Spectrum(format!(
                "no rhodium thickness in 0..0.5 mm gives HVL {hvl_mm} mm Al at {kv} kV"
            )));
        }
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if f(mid) < hvl_mm {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        Ok(0.5 * (lo + hi))
    }
}

/// A W/Rh spectrum and how it was made.
#[derive(Debug, Clone, serde::Serialize)]
pub struct TubeSpectrum {
    /// Tube voltage, kV.
    pub kv: u32,
    /// Rhodium filtration, mm.
    pub rh_mm: f64,
    /// First HVL, mm Al (as solved).
    pub hvl_mm_al: f64,
    /// Mean energy, keV.
    pub mean_kev: f64,
    /// The photon spectrum (energies 5..kV keV).
    #[serde(skip)]
    pub spectrum: Option<Spectrum>,
}

/// The row of the paper's Table 3 for a compressed thickness, as
/// `(kV, HVL mm Al)`: thinner than 30 mm uses the 27 kV row, thicker than 80
/// mm the 31 kV row.
pub fn paper_technique(thickness_mm: f64) -> (u32, f64) {
    let row = PAPER_TABLE3
        .iter()
        .find(|r| thickness_mm < r.0 .1)
        .unwrap_or(&PAPER_TABLE3[4]);
    (row.1, row.2)
}

/// The paper's spectrum for a compressed thickness ([`paper_technique`]).
pub fn paper_spectrum(thickness_mm: f64) -> Result<TubeSpectrum, DoseError> {
    let (kv, hvl) = paper_technique(thickness_mm);
    w_rh_spectrum(kv, hvl)
}

/// The spectrum of an exposure at `kvp` of a breast `thickness_mm` thick:
/// the one place the technique becomes a spectrum, for the acquisition's
/// simulation, the beam-hardening correction and the dose (issue #27).
/// The paper's Table 3 row for the thickness when the gantry used its kV
/// ([`paper_spectrum`]: every figure made with the table's technique
/// stands); another kV (the gantry's automatic exposure chose it) keeps
/// the rhodium of the table's row nearest that kV (the filter does not
/// change with the kV), TASMICS at the kV rounded to the table's 1 kV
/// (0.05 keV of mean energy per 0.5 kV). Kilovolts outside TASMICS's
/// 20-150 are refused naming the value; the caller's technique limits
/// (`dbt_pipeline::acquisition::limits`) are narrower.
pub fn technique_spectrum(kvp: f64, thickness_mm: f64) -> Result<TubeSpectrum, DoseError> {
    if !kvp.is_finite() {
        return Err(DoseError::Spectrum(format!("tube voltage {kvp} kV")));
    }
    let kv = kvp.round();
    let (row_kv, _) = paper_technique(thickness_mm);
    if kv == f64::from(row_kv) {
        return paper_spectrum(thickness_mm);
    }
    if !(20.0..=150.0).contains(&kv) {
        return Err(DoseError::Spectrum(format!(
            "tube voltage {kvp} kV: TASMICS tabulates 20-150 kV"
        )));
    }
    let kv = kv as u32;
    let row = PAPER_TABLE3
        .iter()
        .min_by_key(|r| r.1.abs_diff(kv))
        .unwrap_or(&PAPER_TABLE3[0]);
    let f = Filters::new()?;
    let rh = f.solve_rh(row.1, row.2)?;
    w_rh_filtered(kv, rh)
}

/// W/Rh spectrum at `kv` with rhodium solved for `hvl_mm` of aluminium.
pub fn w_rh_spectrum(kv: u32, hvl_mm: f64) -> Result<TubeSpectrum, DoseError> {
    let f = Filters::new()?;
    let rh = f.solve_rh(kv, hvl_mm)?;
    w_rh_filtered(kv, rh)
}

/// W/Rh spectrum at `kv` through `rh` mm of rhodium.
fn w_rh_filtered(kv: u32, rh: f64) -> Result<TubeSpectrum, DoseError> {
    let f = Filters::new()?;
    let (e, w) = tasmics(kv)?;
    let wf = f.filter_rh(&e, &w, rh);
    let hvl = f.hvl_mm_al(&e, &wf);
    let (e5, w5): (Vec<f64>, Vec<f64>) = e
        .iter()
        .zip(&wf)
        .filter(|(e, _)| **e >= 5.0)
        .map(|(a, b)| (*a, *b))
        .unzip();
    let spectrum = Spectrum::new(e5, w5)?;
    Ok(TubeSpectrum {
        kv,
        rh_mm: rh,
        hvl_mm_al: hvl,
        mean_kev: spectrum.mean(),
        spectrum: Some(spectrum),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rhodium_matches_paper_hvls() {
        for (_, kv, hvl) in PAPER_TABLE3 {
            let s = w_rh_spectrum(kv, hvl).unwrap();
            assert!((s.hvl_mm_al - hvl).abs() < 1e-4, "{kv} kV: {}", s.hvl_mm_al);
            // The issue quotes about 64 um Rh for these HVLs.
            assert!(
                (0.040..0.090).contains(&s.rh_mm),
                "{kv} kV: {} mm Rh",
                s.rh_mm
            );
            assert!(
                (15.0..22.0).contains(&s.mean_kev),
                "{kv} kV: mean {}",
                s.mean_kev
            );
        }
        assert!(tasmics(19).is_err());
        assert_eq!(paper_spectrum(45.0).unwrap().kv, 28);
        assert_eq!(paper_spectrum(75.0).unwrap().kv, 31);
    }

    /// The received kV: the table's own for the thickness gives the
    /// table's spectrum; another keeps the nearest row's rhodium, so the
    /// beam hardens with the kV (a higher HVL and mean energy); nonsense is
    /// refused naming it.
    #[test]
    fn the_received_kv_sets_the_spectrum() {
        let p = paper_spectrum(55.0).unwrap();
        let same = technique_spectrum(29.2, 55.0).unwrap();
        assert_eq!((same.kv, same.rh_mm), (p.kv, p.rh_mm));
        let hot = technique_spectrum(34.0, 55.0).unwrap();
        let row31 = w_rh_spectrum(31, 0.557).unwrap();
        assert_eq!(hot.kv, 34);
        assert!((hot.rh_mm - row31.rh_mm).abs() < 1e-12);
        assert!(hot.hvl_mm_al > row31.hvl_mm_al && hot.mean_kev > row31.mean_kev);
        let cold = technique_spectrum(25.0, 55.0).unwrap();
        assert!(cold.mean_kev < p.mean_kev);
        for bad in [f64::NAN, 0.0, 200.0] {
            let e = technique_spectrum(bad, 55.0).unwrap_err();
            assert!(e.to_string().contains(&format!("{bad} kV")), "{e}");
        }
    }

    #[test]
    fn hvl_grows_with_filtration() {
        let f = Filters::new().unwrap();
        let (e, w) = tasmics(28).unwrap();
        let a = f.hvl_mm_al(&e, &f.filter_rh(&e, &w, 0.03));
        let b = f.hvl_mm_al(&e, &f.filter_rh(&e, &w, 0.06));
        assert!(b > a && a > 0.2);
    }
}
