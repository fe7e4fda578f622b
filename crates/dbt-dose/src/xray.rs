//! X-ray spectra of the gantry: TASMICS tungsten-anode spectra (Hernandez and
//! Boone 2014; table copied from `shared/data/tasmics`, 1 keV bins) filtered by
//! rhodium, aluminium or silver ([`AnodeFilter`]).
//!
//! - **W/Rh** (the paper's): the rhodium thickness solved per tube voltage so
//!   that the first half-value layer in aluminium matches the paper's
//!   measured HVL (Table 3); the kV chosen by compressed thickness as in that
//!   table.
//! - **W/Al** (the tomosynthesis beam of the most common clinical DBT
//!   system): [`W_AL_FILTER_MM`] of aluminium, the kV by thickness from the
//!   cited automatic-exposure table [`W_AL_AEC`].
//! - **W/Ag** (the tomosynthesis beam of the IMS Giotto Class, a 2D beam of
//!   the Hologic Selenia Dimensions): the silver thickness solved so that
//!   the first HVL matches the one a Giotto Class reports for its W/Ag DBT
//!   beam ([`W_AG_HVL`], as W/Rh matches the paper's measured HVLs); the
//!   kV by thickness HVL-matched to the paper's Table 3 ([`W_AG_AEC`]).

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
/// Density of silver, g/cm^3 (CRC Handbook, 10.49 at 20 C).
pub const AG_DENSITY: f64 = 10.49;

/// The paper's Table 3: thickness range (mm), tube voltage (kV), HVL (mm Al).
pub const PAPER_TABLE3: [((f64, f64), u32, f64); 5] = [
    ((30.0, 40.0), 27, 0.519),
    ((40.0, 50.0), 28, 0.530),
    ((50.0, 60.0), 29, 0.538),
    ((60.0, 70.0), 30, 0.547),
    ((70.0, 80.0), 31, 0.557),
];

/// Aluminium filter of the W/Al beam, mm: the 0.7 mm of the tomosynthesis
/// beam of the Hologic Selenia Dimensions (W/Al 0.7 mm Al; e.g. the
/// spectra VICTRE ships for it, `DIDSR/VICTRE_MCGPU`, and OpenVCT's Hologic
/// system constants).
pub const W_AL_FILTER_MM: f64 = 0.7;

/// The simulated automatic exposure of the W/Al beam, as (compressed
/// thickness, kV) at the middle of each of the paper's Table 3 rows: the
/// kV whose W/Al first HVL is nearest that row's measured W/Rh HVL (an
/// HVL-matched beam, the quantity the dosimetry protocols index beams by).
/// **Our choice, not a vendor's table**: no per-thickness AEC table of a
/// W/Al DBT system could be retrieved (Feng & Sechopoulos 2012, AAPM
/// TG-223, NHSBSP 1401 searched; issue #27); the firmware uses the kV the
/// gantry sends, this table only chooses what the simulator exposes.
/// `w_al_and_w_ag_aec_are_hvl_matched` recomputes it.
pub const W_AL_AEC: [(f64, u32); 5] = [(35.0, 31), (45.0, 32), (55.0, 32), (65.0, 33), (75.0, 33)];

/// The W/Ag beam's measured first HVL, `(kV, mm Al)`: what an IMS Giotto
/// Class reports for its W/Ag tomosynthesis sweeps in a radiation dose SR
/// (themorlan/openREM@d4b1ede3
/// `openrem/remapp/tests/test_files/MG-RDSR-Giotto-DBT.dcm`: 11 views a
/// sweep, X-Ray Filter Material silver, 0.05 mm nominal; 28 kV at 44 and
/// 47 mm with HVL 0.560 mm, 27 kV at 41 mm with 0.542 mm). The silver of
/// the beam is solved at the first pair and kept at every kV, as W/Rh keeps
/// its row's rhodium: 59 um, the nominal 50 um plus what the tube's window
/// and the paddle add (the same excess as W/Rh's 58 um solved for the
/// paper's HVLs against Siemens's nominal 50 um). The second pair checks
/// it (`w_ag_matches_the_measured_hvls`).
pub const W_AG_HVL: [(u32, f64); 2] = [(28, 0.560), (27, 0.542)];

/// The simulated automatic exposure of the W/Ag beam, as [`W_AL_AEC`]: per
/// row of the paper's Table 3, the W/Ag kV whose first HVL is nearest that
/// row's. **Our choice**: the one Giotto report read (27 kV at 41 mm, 28 kV
/// at 44-47 mm, a kV or two above this table) is no table;
/// `w_al_and_w_ag_aec_are_hvl_matched` recomputes it. The firmware uses the kV the
/// gantry sends; this table only chooses what the simulator exposes.
pub const W_AG_AEC: [(f64, u32); 5] = [(35.0, 26), (45.0, 26), (55.0, 27), (65.0, 27), (75.0, 28)];

/// The anode/filter combinations the product has spectra for, named as the
/// gantry's register 6 names them (GANTRY_INTERFACE.md): another
/// combination (Mo/Mo, Mo/Rh: no molybdenum-anode spectrum model here) is
/// refused by [`AnodeFilter::parse`], naming it, never reported with
/// another beam's dose.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize,
)]
pub enum AnodeFilter {
    /// Tungsten, rhodium (the paper's beam).
    #[default]
    #[serde(rename = "W/Rh")]
    WRh,
    /// Tungsten, aluminium.
    #[serde(rename = "W/Al")]
    WAl,
    /// Tungsten, silver.
    #[serde(rename = "W/Ag")]
    WAg,
}

impl AnodeFilter {
    /// Every supported combination.
    pub const ALL: [AnodeFilter; 3] = [AnodeFilter::WRh, AnodeFilter::WAl, AnodeFilter::WAg];

    /// Its place in [`Self::ALL`] (a table per beam indexes by it).
    pub const fn index(self) -> usize {
        match self {
            AnodeFilter::WRh => 0,
            AnodeFilter::WAl => 1,
            AnodeFilter::WAg => 2,
        }
    }

    /// The register's name, `W/Rh`, `W/Al` or `W/Ag`.
    pub fn name(self) -> &'static str {
        match self {
            AnodeFilter::WRh => "W/Rh",
            AnodeFilter::WAl => "W/Al",
            AnodeFilter::WAg => "W/Ag",
        }
    }

    /// Parse a register name; anything else is refused, naming it and the
    /// supported ones.
    pub fn parse(s: &str) -> Result<Self, DoseError> {
        Self::ALL
            .into_iter()
            .find(|a| a.name() == s.trim())
            .ok_or_else(|| {
                DoseError::Spectrum(format!(
                    "anode/filter `{s}`: the dose model has spectra for {} only",
                    Self::supported()
                ))
            })
    }

    /// `W/Rh, W/Al, W/Ag`.
    pub fn supported() -> String {
        Self::ALL.map(|a| a.name()).join(", ")
    }

    /// The automatic exposure's tube voltage for a compressed thickness:
    /// the paper's Table 3 for W/Rh ([`paper_technique`]), [`W_AL_AEC`]
    /// for W/Al and [`W_AG_AEC`] for W/Ag (the nearest tabulated
    /// thickness; beyond the table, its last row).
    pub fn aec_kv(self, thickness_mm: f64) -> u32 {
        let table = match self {
            AnodeFilter::WRh => return paper_technique(thickness_mm).0,
            AnodeFilter::WAl => &W_AL_AEC,
            AnodeFilter::WAg => &W_AG_AEC,
        };
        let t = if thickness_mm.is_finite() {
            thickness_mm
        } else {
            0.0
        };
        table
            .iter()
            .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()))
            .map_or(table[0].1, |r| r.1)
    }
}

impl std::fmt::Display for AnodeFilter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

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
    ag: Material,
    air: Material,
}

impl Filters {
    /// Build from the compiled-in tables.
    pub fn new() -> Result<Self, DoseError> {
        Ok(Self {
            rh: element_material(45, RH_DENSITY)?,
            al: element_material(13, AL_DENSITY)?,
            ag: element_material(47, AG_DENSITY)?,
            air: Material::new("air", AIR.density, AIR.elements, elements()?)?,
        })
    }

    /// Apply `rh_mm` of rhodium to a fluence spectrum.
    pub fn filter_rh(&self, e: &[f64], w: &[f64], rh_mm: f64) -> Vec<f64> {
        self.filter(AnodeFilter::WRh, e, w, rh_mm)
    }

    /// Apply `mm` of the filter of `af` to a fluence spectrum.
    pub fn filter(&self, af: AnodeFilter, e: &[f64], w: &[f64], mm: f64) -> Vec<f64> {
        let m = match af {
            AnodeFilter::WRh => &self.rh,
            AnodeFilter::WAl => &self.al,
            AnodeFilter::WAg => &self.ag,
        };
        e.iter()
            .zip(w)
            .map(|(&e, &w)| w * (-m.mu(e).total() * mm).exp())
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
        self.solve(AnodeFilter::WRh, kv, hvl_mm)
    }

    /// Thickness (mm) of the filter of `af` giving the target HVL at `kv`.
    pub fn solve(&self, af: AnodeFilter, kv: u32, hvl_mm: f64) -> Result<f64, DoseError> {
        let (e, w) = tasmics(kv)?;
        let f = |mm: f64| self.hvl_mm_al(&e, &self.filter(af, &e, &w, mm));
        let (mut lo, mut hi) = (0.0, 0.5);
        if !(f(lo) <= hvl_mm && f(hi) >= hvl_mm) {
            return Err(DoseError::Spectrum(format!(
                "no {af} filter in 0..0.5 mm gives HVL {hvl_mm} mm Al at {kv} kV"
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

/// A tube spectrum and how it was made.
#[derive(Debug, Clone, serde::Serialize)]
pub struct TubeSpectrum {
    /// Tube voltage, kV.
    pub kv: u32,
    /// The anode and filter.
    pub anode_filter: AnodeFilter,
    /// Filter thickness, mm (rhodium, aluminium or silver).
    pub filter_mm: f64,
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

/// The spectrum of the automatic exposure of `af` for a breast
/// `thickness_mm` thick ([`AnodeFilter::aec_kv`]).
pub fn aec_spectrum(af: AnodeFilter, thickness_mm: f64) -> Result<TubeSpectrum, DoseError> {
    technique_spectrum(af, f64::from(af.aec_kv(thickness_mm)), thickness_mm)
}

/// The spectrum of an exposure at `kvp` with `af` of a breast
/// `thickness_mm` thick: the one place the technique becomes a spectrum,
/// for the acquisition's simulation, the beam-hardening correction and the
/// dose (issue #27). W/Al: TASMICS at the kV rounded to 1 kV through
/// [`W_AL_FILTER_MM`] of aluminium; W/Ag: the same through the silver of
/// [`w_ag_filter_mm`]. W/Rh: the paper's Table 3 row for the thickness when the gantry used its kV
/// ([`paper_spectrum`]: every figure made with the table's technique
/// stands); another kV (the gantry's automatic exposure chose it) keeps
/// the rhodium of the table's row nearest that kV (the filter does not
/// change with the kV), TASMICS at the kV rounded to the table's 1 kV
/// (0.05 keV of mean energy per 0.5 kV). Kilovolts outside TASMICS's
/// 20-150 are refused naming the value; the caller's technique limits
/// (`dbt_pipeline::acquisition::limits`) are narrower.
pub fn technique_spectrum(
    af: AnodeFilter,
    kvp: f64,
    thickness_mm: f64,
) -> Result<TubeSpectrum, DoseError> {
    if !kvp.is_finite() {
        return Err(DoseError::Spectrum(format!("tube voltage {kvp} kV")));
    }
    let kv = kvp.round();
    let (row_kv, _) = paper_technique(thickness_mm);
    if af == AnodeFilter::WRh && kv == f64::from(row_kv) {
        return paper_spectrum(thickness_mm);
    }
    if !(20.0..=150.0).contains(&kv) {
        return Err(DoseError::Spectrum(format!(
            "tube voltage {kvp} kV: TASMICS tabulates 20-150 kV"
        )));
    }
    let kv = kv as u32;
    match af {
        AnodeFilter::WAl => return filtered(af, kv, W_AL_FILTER_MM),
        AnodeFilter::WAg => return filtered(af, kv, w_ag_filter_mm()?),
        AnodeFilter::WRh => {}
    }
    let row = PAPER_TABLE3
        .iter()
        .min_by_key(|r| r.1.abs_diff(kv))
        .unwrap_or(&PAPER_TABLE3[0]);
    let f = Filters::new()?;
    let rh = f.solve_rh(row.1, row.2)?;
    filtered(AnodeFilter::WRh, kv, rh)
}

/// The silver of the W/Ag beam, mm: solved once for the first pair of
/// [`W_AG_HVL`].
pub fn w_ag_filter_mm() -> Result<f64, DoseError> {
    static MM: std::sync::OnceLock<Result<f64, String>> = std::sync::OnceLock::new();
    MM.get_or_init(|| {
        let (kv, hvl) = W_AG_HVL[0];
        Filters::new()
            .and_then(|f| f.solve(AnodeFilter::WAg, kv, hvl))
            .map_err(|e| e.to_string())
    })
    .clone()
    .map_err(DoseError::Spectrum)
}

/// W/Rh spectrum at `kv` with rhodium solved for `hvl_mm` of aluminium.
pub fn w_rh_spectrum(kv: u32, hvl_mm: f64) -> Result<TubeSpectrum, DoseError> {
    let f = Filters::new()?;
    let rh = f.solve_rh(kv, hvl_mm)?;
    filtered(AnodeFilter::WRh, kv, rh)
}

/// The tungsten spectrum at `kv` through `mm` of the filter of `af`.
fn filtered(af: AnodeFilter, kv: u32, mm: f64) -> Result<TubeSpectrum, DoseError> {
    let f = Filters::new()?;
    let (e, w) = tasmics(kv)?;
    let wf = f.filter(af, &e, &w, mm);
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
        anode_filter: af,
        filter_mm: mm,
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
                (0.040..0.090).contains(&s.filter_mm),
                "{kv} kV: {} mm Rh",
                s.filter_mm
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
        let same = technique_spectrum(AnodeFilter::WRh, 29.2, 55.0).unwrap();
        assert_eq!((same.kv, same.filter_mm), (p.kv, p.filter_mm));
        let hot = technique_spectrum(AnodeFilter::WRh, 34.0, 55.0).unwrap();
        let row31 = w_rh_spectrum(31, 0.557).unwrap();
        assert_eq!(hot.kv, 34);
        assert!((hot.filter_mm - row31.filter_mm).abs() < 1e-12);
        assert!(hot.hvl_mm_al > row31.hvl_mm_al && hot.mean_kev > row31.mean_kev);
        let cold = technique_spectrum(AnodeFilter::WRh, 25.0, 55.0).unwrap();
        assert!(cold.mean_kev < p.mean_kev);
        for bad in [f64::NAN, 0.0, 200.0] {
            let e = technique_spectrum(AnodeFilter::WRh, bad, 55.0).unwrap_err();
            assert!(e.to_string().contains(&format!("{bad} kV")), "{e}");
        }
    }

    /// [`W_AL_AEC`] and [`W_AG_AEC`] are what their documentation says: per
    /// Table 3 row, the beam's kV (20-49) whose first HVL is nearest the
    /// row's W/Rh HVL.
    #[test]
    fn w_al_and_w_ag_aec_are_hvl_matched() {
        for (af, table) in [(AnodeFilter::WAl, W_AL_AEC), (AnodeFilter::WAg, W_AG_AEC)] {
            for (row, (t, kv)) in PAPER_TABLE3.iter().zip(table) {
                assert!((t - 0.5 * (row.0 .0 + row.0 .1)).abs() < 1e-9);
                let best = (20..50)
                    .min_by(|a, b| {
                        let d = |k: u32| {
                            let s = technique_spectrum(af, f64::from(k), t).unwrap();
                            (s.hvl_mm_al - row.2).abs()
                        };
                        d(*a).total_cmp(&d(*b))
                    })
                    .unwrap();
                assert_eq!(kv, best, "{af} {t} mm");
                assert_eq!(af.aec_kv(t), kv);
            }
        }
        assert_eq!(AnodeFilter::WAl.aec_kv(10.0), W_AL_AEC[0].1);
        assert_eq!(AnodeFilter::WAl.aec_kv(120.0), W_AL_AEC[4].1);
        assert_eq!(AnodeFilter::WAl.aec_kv(f64::NAN), W_AL_AEC[0].1);
        assert_eq!(AnodeFilter::WRh.aec_kv(45.0), 28);
    }

    /// The W/Al beam against an independent spectrum model: VICTRE's
    /// 41 kV W + 0.7 mm Al spectrum (`DIDSR/VICTRE_MCGPU`, made with SPEKTR,
    /// i.e. TASMIP; its header: first HVL 0.684 mm Al, mean 24.340 keV).
    /// Two different models of the tungsten spectrum (TASMICS from Monte
    /// Carlo, TASMIP interpolated from measurements), different attenuation
    /// tables and 1 keV against finer bins: 2 % tolerance on each (ours:
    /// 0.687 mm, 24.65 keV).
    #[test]
    fn w_al_matches_an_independent_spectrum_model() {
        let s = technique_spectrum(AnodeFilter::WAl, 41.0, 50.0).unwrap();
        assert_eq!(s.anode_filter, AnodeFilter::WAl);
        assert_eq!(s.filter_mm, W_AL_FILTER_MM);
        assert!((s.hvl_mm_al / 0.684 - 1.0).abs() < 0.02, "{}", s.hvl_mm_al);
        assert!((s.mean_kev / 24.340 - 1.0).abs() < 0.02, "{}", s.mean_kev);
        // Harder with the kV, and no rhodium K edge: at the same HVL the
        // W/Al beam carries more photons above 23.2 keV than W/Rh.
        let lo = technique_spectrum(AnodeFilter::WAl, 28.0, 50.0).unwrap();
        assert!(lo.hvl_mm_al < s.hvl_mm_al && lo.mean_kev < s.mean_kev);
        // A Selenia Dimensions's own dose report states 0.453 mm at 26 kV
        // for its 0.7 mm Al sweeps (themorlan/openREM@d4b1ede3
        // `MG-RDSR-Hologic_mix.dcm`); the nominal filter alone gives less,
        // as the nominal 50 um of W/Rh and W/Ag give less than their
        // measured HVLs (eval/README.md, "The W/Ag beam"). Printed, not
        // solved for: W/Al keeps the nominal 0.7 mm.
        let h26 = technique_spectrum(AnodeFilter::WAl, 26.0, 20.0).unwrap();
        eprintln!(
            "W/Al 0.7 mm, 26 kV: HVL {:.3} mm Al (a Selenia Dimensions reports 0.453)",
            h26.hvl_mm_al
        );
        assert!(h26.hvl_mm_al < 0.453);
    }

    #[test]
    fn anode_filters_are_parsed_or_refused_by_name() {
        for (i, a) in AnodeFilter::ALL.into_iter().enumerate() {
            assert_eq!(a.index(), i, "{a}");
            assert_eq!(AnodeFilter::parse(a.name()).unwrap(), a);
            let json = serde_json::to_string(&a).unwrap();
            assert_eq!(json, format!("\"{}\"", a.name()));
        }
        for bad in ["Mo/Rh", "Mo/Mo", "Rh/Ag", "", "w/rh", "w/ag"] {
            let e = AnodeFilter::parse(bad).unwrap_err().to_string();
            assert!(
                e.contains(&format!("`{bad}`")) && e.contains("W/Rh, W/Al, W/Ag"),
                "{e}"
            );
        }
    }

    /// The W/Ag beam against the HVLs a Giotto Class reports (W_AG_HVL):
    /// the silver solved at 28 kV gives the 27 kV sweep's 0.542 mm within
    /// 1 % (the two reports were not used together: one solves, the other
    /// checks), and it is the nominal 50 um plus a filtration of the size
    /// W/Rh's solved rhodium carries over Siemens's nominal 50 um (our
    /// rhodium 58-59 um): 55-75 um.
    #[test]
    fn w_ag_matches_the_measured_hvls() {
        let ag = w_ag_filter_mm().unwrap();
        assert!((0.055..0.075).contains(&ag), "{ag} mm Ag");
        let (kv, hvl) = W_AG_HVL[0];
        let s = technique_spectrum(AnodeFilter::WAg, f64::from(kv), 45.0).unwrap();
        assert!((s.hvl_mm_al - hvl).abs() < 1e-4, "{}", s.hvl_mm_al);
        assert_eq!((s.anode_filter, s.filter_mm), (AnodeFilter::WAg, ag));
        let (kv, hvl) = W_AG_HVL[1];
        let s = technique_spectrum(AnodeFilter::WAg, f64::from(kv), 41.0).unwrap();
        // The figures eval/README.md ("The W/Ag beam") quotes: `cargo test
        // -p dbt-dose --lib w_ag -- --nocapture`.
        eprintln!(
            "W/Ag: {:.1} um Ag; {kv} kV: HVL {:.3} mm Al against {hvl} reported",
            1000.0 * ag,
            s.hvl_mm_al
        );
        assert!(
            (s.hvl_mm_al / hvl - 1.0).abs() < 0.01,
            "{} against {hvl}",
            s.hvl_mm_al
        );
        // Silver's K edge (25.5 keV) cuts the spectrum above it: at 27 kV
        // the 26 keV bin holds under a tenth of the 25 keV bin's photons
        // (through 59 um of silver: about 0.04 against 0.55 of them).
        let sp = s.spectrum.as_ref().unwrap();
        let at = |e: f64| {
            let i = sp
                .energies
                .iter()
                .position(|&x| (x - e).abs() < 0.01)
                .unwrap();
            sp.weights[i]
        };
        assert!(at(26.0) < 0.1 * at(25.0), "{} {}", at(25.0), at(26.0));
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
