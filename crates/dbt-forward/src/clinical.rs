//! The clinical physics model of an acquisition (issue #27), beside the
//! paper's mono-energetic one: a polychromatic beam hardening through the
//! breast's tissues, recorded by an energy-integrating flat panel (a CsI
//! scintillator or an a-Se photoconductor), with quantum and electronic
//! noise; with [`ClinicalPhysics::simulate_scattered`] each view's scatter
//! (the kernel model of `dbt_scatter`, fitted to our Monte Carlo engine)
//! added to the expected primary before the noise; where the detector
//! spreads its signal (a scintillator's light: [`crate::spread`]), each
//! view's quanta are spread after their draw and before the electronic
//! noise ([`ClinicalPhysics::simulate_stack`]).
//!
//! # The model
//! For a ray crossing `L_a`, `L_g`, `L_s` mm of adipose, fibroglandular
//! (Cooper's ligaments included: same composition) and skin tissue, the
//! detector's expected signal is
//!
//! `S = g sum_E N_E m1(E) exp(-(mu_a(E) L_a + mu_g(E) L_g + mu_s(E) L_s))`
//!
//! with `N_E` the photons of energy `E` reaching the element without the
//! breast (the tube spectrum of the technique, [`dbt_dose::xray`], scaled
//! to `photons_per_element`), `m1(E)` the mean energy the converter keeps
//! per incident photon ([`dbt_dose::detector`]: `eta(E) E` with
//! `eta = 1 - exp(-mu_conv(E) t)` the fraction absorbed, less the K
//! fluorescence that escapes the layer: up to 15 % of the signal just above
//! selenium's K edge at 12.66 keV, nothing for CsI below iodine's at 33.17
//! keV), and `g` the gain that makes the unattenuated signal `flat_adu`,
//! the flat field the firmware receives. The attenuation coefficients are
//! the dose engine's (xraylib 4.3.0 cross sections, Hammerstein
//! compositions: [`dbt_dose::material`]), one table for simulation, dose
//! and correction.
//!
//! Noise: each energy's detected photons are Poisson, so the signal's
//! variance is `g^2 sum_E N_E m2(E) exp(-...)` with `m2` the mean squared
//! energy kept per incident photon (compound Poisson, drawn as a normal of
//! that variance: every element holds thousands of photons; the spread of
//! deposited energies the K escape makes is in it, the part of the Swank
//! factor this model has: the conversion stage's own fluctuation, CsI's
//! light or a-Se's charge per keV, is not modelled); electronic noise adds
//! a normal of standard deviation `electronic_photons` photons of the
//! spectrum's mean detected energy (our choice, 4: a CsI flat panel's read
//! noise is about 2 x-ray photons' signal per 0.1 mm pixel, and a binned
//! element sums several pixels' noise; a negligible term at mammographic
//! signals; the same 4 for a-Se, our choice: VICTRE models 5200 electrons
//! per 85 um pixel, about 13 photons of 20 keV at its 50 eV per
//! electron-hole pair, still small beside the thousands of photons an
//! element holds).

use crate::AcquisitionError;
use dbt_dose::detector::ConverterModel;
use dbt_dose::material::Material;
use dbt_dose::spectrum::Spectrum;
use dbt_materials::{Converter, Tissue};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;

/// The materials a ray's path lengths are given for, in order.
pub const MATERIALS: [Tissue; 3] = [Tissue::Adipose, Tissue::Fibroglandular, Tissue::Skin];

/// The detector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detector {
    /// Its converter: material and thickness.
    pub converter: Converter,
    /// Electronic noise, in photons of the mean detected energy per element.
    pub electronic_photons: f64,
    /// The converter's line spread, mm: the scale of its exponential line
    /// spread function ([`crate::spread`]); 0: none.
    pub line_spread_mm: f64,
}

impl Default for Detector {
    /// 200 um of CsI ([`Converter::default`]), 4 photons of electronic
    /// noise, no spread.
    fn default() -> Self {
        Self::with(Converter::default())
    }
}

impl Detector {
    /// `converter` with the default electronic noise (4 photons) and no
    /// spread.
    pub fn with(converter: Converter) -> Self {
        Self {
            converter,
            electronic_photons: 4.0,
            line_spread_mm: 0.0,
        }
    }
}

/// The clinical physics of one technique: spectrum, photons, detector.
#[derive(Debug, Clone)]
pub struct ClinicalPhysics {
    /// Photons per element at each energy, detected (`N_E eta(E)`).
    detected: Vec<f64>,
    /// Energy kept per element at each energy, keV (`N_E m1(E)`).
    m1: Vec<f64>,
    /// Squared energy kept per element at each energy, keV^2 (`N_E m2(E)`).
    m2: Vec<f64>,
    /// Attenuation of each of [`MATERIALS`] at each energy, 1/mm.
    mu: Vec<[f64; 3]>,
    gain: f64,
    electronic_sd: f64,
    flat_adu: f64,
    /// The detector's line spread, mm (0: none).
    line_spread_mm: f64,
}

fn bad(what: impl Into<String>) -> AcquisitionError {
    AcquisitionError::Physics(what.into())
}

impl ClinicalPhysics {
    /// The physics of `spectrum` (photon weights) with `photons_per_element`
    /// photons reaching each element without the breast, recorded by
    /// `detector` and scaled so that the flat field reads `flat_adu`.
    pub fn new(
        spectrum: &Spectrum,
        photons_per_element: f64,
        detector: &Detector,
        flat_adu: f64,
    ) -> Result<Self, AcquisitionError> {
        for (what, v) in [
            ("photons per element", photons_per_element),
            ("flat field (ADU)", flat_adu),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(format!("{what} {v} must be a positive number")));
            }
        }
        if !(detector.electronic_photons.is_finite() && detector.electronic_photons >= 0.0) {
            return Err(bad(format!(
                "electronic noise {} photons must be a non-negative number",
                detector.electronic_photons
            )));
        }
        if !(detector.line_spread_mm.is_finite() && detector.line_spread_mm >= 0.0) {
            return Err(bad(format!(
                "line spread {} mm must be a non-negative number",
                detector.line_spread_mm
            )));
        }
        let conv = ConverterModel::new(detector.converter).map_err(|e| bad(e.to_string()))?;
        let tables = dbt_dose::tables::elements().map_err(|e| bad(e.to_string()))?;
        let tissues: Vec<Material> = MATERIALS
            .iter()
            .map(|&t| Material::tissue(t, tables))
            .collect::<Result<_, _>>()
            .map_err(|e| bad(e.to_string()))?;
        let energies = &spectrum.energies;
        let (mut detected, mut m1, mut m2) = (Vec::new(), Vec::new(), Vec::new());
        for (&e, &w) in energies.iter().zip(&spectrum.weights) {
            let r = conv.response(e).map_err(|e| bad(e.to_string()))?;
            let n = photons_per_element * w;
            detected.push(n * r.absorbed);
            m1.push(n * r.mean_kev);
            m2.push(n * r.mean_sq_kev2);
        }
        let mu = energies
            .iter()
            .map(|&e| [0, 1, 2].map(|m| tissues[m].mu(e).total()))
            .collect();
        let raw_flat: f64 = m1.iter().sum();
        let n_det: f64 = detected.iter().sum();
        if !(raw_flat > 0.0 && n_det > 0.0) {
            return Err(bad(format!(
                "{} absorbs no photon of this spectrum ({} energies, {}-{} keV)",
                detector.converter,
                spectrum.energies.len(),
                spectrum.energies.first().copied().unwrap_or(0.0),
                spectrum.energies.last().copied().unwrap_or(0.0)
            )));
        }
        let gain = flat_adu / raw_flat;
        // Electronic noise: photons of the mean detected energy.
        let electronic_sd = gain * detector.electronic_photons * raw_flat / n_det;
        Ok(Self {
            detected,
            m1,
            m2,
            mu,
            gain,
            electronic_sd,
            flat_adu,
            line_spread_mm: detector.line_spread_mm,
        })
    }

    /// The unattenuated signal, ADU (the flat field).
    pub fn flat_adu(&self) -> f64 {
        self.flat_adu
    }

    /// The detector's absorption efficiency for the spectrum (detected over
    /// incident photons).
    pub fn detected_photons(&self) -> f64 {
        self.detected.iter().sum()
    }

    /// Expected signal (ADU) and its variance (ADU^2) behind `paths` mm of
    /// adipose, fibroglandular and skin tissue.
    pub fn expected(&self, paths: [f64; 3]) -> (f64, f64) {
        let (mut s, mut v) = (0.0, 0.0);
        for ((&a, &b), mu) in self.m1.iter().zip(&self.m2).zip(&self.mu) {
            let t = (-(mu[0] * paths[0] + mu[1] * paths[1] + mu[2] * paths[2])).exp();
            s += a * t;
            v += b * t;
        }
        (
            self.gain * s,
            self.gain * self.gain * v + self.electronic_sd * self.electronic_sd,
        )
    }

    /// Noisy signals of rays with per-material path lengths
    /// (`paths[m][ray]`, mm, in the order of [`MATERIALS`]), reproducible
    /// from `seed` (blocks of 4096 rays draw from their own streams);
    /// `noise: false` gives the expected signals. A detector with a line
    /// spread needs the rays' layout on the detector: [`Self::simulate_stack`].
    pub fn simulate(
        &self,
        paths: &[Vec<f32>; 3],
        noise: bool,
        seed: u64,
    ) -> Result<Vec<f32>, AcquisitionError> {
        if self.line_spread_mm > 0.0 {
            return Err(bad(format!(
                "the detector's line spread ({} mm) needs the rays' layout on the detector (simulate_stack)",
                self.line_spread_mm
            )));
        }
        let (mean, var) = self.expected_all(paths)?;
        Ok(draw(&mean, &var, noise, seed))
    }

    /// Expected signals (ADU) and variances of rays (`paths` as in
    /// [`Self::simulate`]).
    pub fn expected_all(
        &self,
        paths: &[Vec<f32>; 3],
    ) -> Result<(Vec<f64>, Vec<f64>), AcquisitionError> {
        let n = paths[0].len();
        if paths.iter().any(|p| p.len() != n) {
            return Err(bad(format!(
                "path lengths of {}, {} and {} rays",
                paths[0].len(),
                paths[1].len(),
                paths[2].len()
            )));
        }
        Ok((0..n)
            .into_par_iter()
            .map(|i| self.expected([0, 1, 2].map(|m| f64::from(paths[m][i]))))
            .unzip())
    }

    /// Variance per ADU of a signal made of this spectrum's photons (the
    /// open field's `<E^2> / <E>` in ADU): the scatter's noise (its
    /// softer spectrum neglected).
    pub fn variance_per_adu(&self) -> f64 {
        let s: f64 = self.m1.iter().sum();
        let v: f64 = self.m2.iter().sum();
        self.gain * v / s
    }

    /// [`Self::simulate`] with the scatter of the shipped kernel model
    /// ([`dbt_scatter::ScatterTable`], fitted to our Monte Carlo engine)
    /// added to each view's expected primary before the noise: the rays
    /// form a stack of `layout.rows` detector rows (a coronal slice's rays
    /// or a cone-beam detector row) of `layout.views` views of
    /// `layout.cols` elements ([`StackLayout`]). The scatter is computed
    /// on blocks of about 4 mm (it varies
    /// over centimetres) and interpolated back to every element. Returns
    /// the signals and the expected scatter (ADU) of every ray.
    pub fn simulate_scattered(
        &self,
        paths: &[Vec<f32>; 3],
        layout: &StackLayout,
        table: &dbt_scatter::ScatterTable,
        thickness_mm: f64,
        noise: bool,
        seed: u64,
    ) -> Result<(Vec<f32>, Vec<f32>), AcquisitionError> {
        self.simulate_stack(paths, layout, Some((table, thickness_mm)), noise, seed)
    }

    /// The signals of a stack of detector images (`layout`): with
    /// `scatter` (a table and the breast's thickness) as
    /// [`Self::simulate_scattered`], else the primary alone (then the
    /// returned scatter is zeros); the detector's line spread, if it has
    /// one, spreads each view's quanta after their draw and before the
    /// electronic noise ([`crate::spread`]). Without a spread the signals
    /// are [`Self::simulate`]'s (with the scatter added), draw for draw.
    pub fn simulate_stack(
        &self,
        paths: &[Vec<f32>; 3],
        layout: &StackLayout,
        scatter: Option<(&dbt_scatter::ScatterTable, f64)>,
        noise: bool,
        seed: u64,
    ) -> Result<(Vec<f32>, Vec<f32>), AcquisitionError> {
        let (mut mean, mut var) = self.expected_all(paths)?;
        layout.check(mean.len())?;
        let scatter = match scatter {
            Some((table, thickness_mm)) => {
                let scatter = layout.scatter(&mean, self.flat_adu, table, thickness_mm)?;
                let vpa = self.variance_per_adu();
                for ((m, v), s) in mean.iter_mut().zip(&mut var).zip(&scatter) {
                    *m += s;
                    *v += vpa * s;
                }
                scatter
            }
            None => vec![0.0; mean.len()],
        };
        let signals = if self.line_spread_mm > 0.0 {
            self.draw_spread(mean, &var, layout, noise, seed)?
        } else {
            draw(&mean, &var, noise, seed)
        };
        Ok((signals, scatter.iter().map(|&x| x as f32).collect()))
    }

    /// [`draw`] through the line spread: the quanta (the variance less the
    /// electronic part) drawn, spread view by view, white noise making up
    /// each element's quantum variance to that of photons absorbed anywhere
    /// in their element ([`crate::spread::element_variance`]), then the
    /// electronic noise added (each its own streams of `seed`).
    fn draw_spread(
        &self,
        mut mean: Vec<f64>,
        var: &[f64],
        layout: &StackLayout,
        noise: bool,
        seed: u64,
    ) -> Result<Vec<f32>, AcquisitionError> {
        let e_var = self.electronic_sd * self.electronic_sd;
        let quanta = |i: usize| (var[i] - e_var).max(0.0);
        if noise {
            normal_draws(&mut mean, seed, 0, |i| quanta(i).sqrt());
        }
        crate::spread::spread_stack(
            &mut mean,
            [layout.rows, layout.views, layout.cols],
            [layout.row_mm, layout.col_mm],
            self.line_spread_mm,
        )?;
        if noise {
            let (kr, tr) = crate::spread::element_variance(self.line_spread_mm, layout.row_mm)?;
            let (kc, tc) = crate::spread::element_variance(self.line_spread_mm, layout.col_mm)?;
            let missing = (tr * tc - kr * kc).max(0.0);
            normal_draws(&mut mean, seed, MAKE_UP_STREAMS, |i| {
                (quanta(i) * missing).sqrt()
            });
            let sd = self.electronic_sd;
            normal_draws(&mut mean, seed, ELECTRONIC_STREAMS, |_| sd);
        }
        Ok(mean.iter().map(|&s| s.max(0.0) as f32).collect())
    }
}

/// How the rays of an acquisition form each view's detector image: `rows`
/// detector rows (from the chest wall) of `views` views of `cols` elements
/// (along the chest wall), ray `(r, v, c)` at `(r * views + v) * cols + c`.
#[derive(Debug, Clone, PartialEq)]
pub struct StackLayout {
    /// Detector rows.
    pub rows: usize,
    /// Views.
    pub views: usize,
    /// Elements per row.
    pub cols: usize,
    /// Row pitch on the detector, mm.
    pub row_mm: f64,
    /// Element pitch, mm.
    pub col_mm: f64,
    /// `tan(theta)` of each view's angle.
    pub tan_angles: Vec<f64>,
}

/// Block side of the scatter's computation, mm.
pub const SCATTER_BLOCK_MM: f64 = 4.0;

impl StackLayout {
    /// The slice-wise fan-beam stack: `slices` coronal slices `spacing_mm`
    /// apart are the detector's rows (each its own fan: no magnification
    /// along them), the geometry's views and elements.
    pub fn fan(geom: &dbt_geometry::Geometry, slices: usize, spacing_mm: f64) -> Self {
        Self {
            rows: slices,
            views: geom.n_views(),
            cols: geom.n_det(),
            row_mm: spacing_mm,
            col_mm: geom.detector.pitch_mm,
            tan_angles: (0..geom.n_views())
                .map(|v| geom.angle_rad(v).tan())
                .collect(),
        }
    }

    /// A cone-beam system's frames: its detector's rows, views and columns.
    pub fn cone(system: &dbt_geometry::ConeSystem) -> Self {
        Self {
            rows: system.detector.rows,
            views: system.n_views(),
            cols: system.detector.columns,
            row_mm: system.detector.pitch_mm,
            col_mm: system.detector.pitch_mm,
            tan_angles: (0..system.n_views())
                .map(|v| system.angle_deg(v).to_radians().tan())
                .collect(),
        }
    }

    /// One view's detector image: the rows by the elements.
    pub fn grid(&self) -> dbt_scatter::Grid {
        dbt_scatter::Grid {
            rows: self.rows,
            cols: self.cols,
            row_mm: self.row_mm,
            col_mm: self.col_mm,
        }
    }

    /// Rows and elements per block of the scatter's computation (about
    /// [`SCATTER_BLOCK_MM`] square): the simulator's and the firmware's.
    pub fn block(&self) -> (usize, usize) {
        let n = |pitch: f64| (SCATTER_BLOCK_MM / pitch).round().max(1.0) as usize;
        (n(self.row_mm), n(self.col_mm))
    }

    fn check(&self, n: usize) -> Result<(), AcquisitionError> {
        if self.rows * self.views * self.cols != n || self.tan_angles.len() != self.views {
            return Err(bad(format!(
                "a stack of {} rows x {} views x {} elements ({} angles) for {n} rays",
                self.rows,
                self.views,
                self.cols,
                self.tan_angles.len()
            )));
        }
        Ok(())
    }

    /// The expected scatter (ADU) of every ray for the expected primary
    /// `signal` (ADU) and the open field `flat` (ADU).
    pub fn scatter(
        &self,
        signal: &[f64],
        flat: f64,
        table: &dbt_scatter::ScatterTable,
        thickness_mm: f64,
    ) -> Result<Vec<f64>, AcquisitionError> {
        self.check(signal.len())?;
        let fine = self.grid();
        let (fr, fc) = self.block();
        let per_view: Vec<Vec<f64>> = (0..self.views)
            .into_par_iter()
            .map(|v| {
                let mut t = vec![0.0; fine.len()];
                for r in 0..self.rows {
                    let from = (r * self.views + v) * self.cols;
                    for c in 0..self.cols {
                        t[r * self.cols + c] = signal[from + c] / flat;
                    }
                }
                let (tc, coarse) = dbt_scatter::block_mean(&t, &fine, fr, fc);
                let s = table
                    .scatter(&tc, &coarse, thickness_mm, self.tan_angles[v])
                    .map_err(|e| bad(e.to_string()))?;
                Ok(dbt_scatter::upsample(&s, &coarse, &fine))
            })
            .collect::<Result<_, AcquisitionError>>()?;
        let mut out = vec![0.0; signal.len()];
        for (v, s) in per_view.iter().enumerate() {
            for r in 0..self.rows {
                let to = (r * self.views + v) * self.cols;
                for c in 0..self.cols {
                    out[to + c] = flat * s[r * self.cols + c];
                }
            }
        }
        Ok(out)
    }
}

/// The electronic noise's streams of a spread detector start here (the
/// quanta's are the blocks' numbers, as [`draw`]'s).
const ELECTRONIC_STREAMS: u64 = 1 << 40;

/// The streams of the white noise that makes up a spread detector's quantum
/// variance.
const MAKE_UP_STREAMS: u64 = 2 << 40;

/// Adds to each value a normal draw of standard deviation `sd(i)`, blocks
/// of 4096 from their own streams `first_stream + block` of `seed`.
fn normal_draws(
    values: &mut [f64],
    seed: u64,
    first_stream: u64,
    sd: impl Fn(usize) -> f64 + Sync,
) {
    values
        .par_chunks_mut(4096)
        .enumerate()
        .for_each(|(blk, o)| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream(first_stream + blk as u64);
            for (k, y) in o.iter_mut().enumerate() {
                let z: f64 = rand_distr::StandardNormal.sample(&mut rng);
                *y += sd(blk * 4096 + k) * z;
            }
        });
}

/// Noisy draws of normals of the given means and variances (blocks of 4096
/// from their own streams of `seed`), clamped at zero; the means when
/// `noise` is false.
fn draw(mean: &[f64], var: &[f64], noise: bool, seed: u64) -> Vec<f32> {
    let mut out = vec![0f32; mean.len()];
    out.par_chunks_mut(4096).enumerate().for_each(|(blk, o)| {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(blk as u64);
        for (k, y) in o.iter_mut().enumerate() {
            let i = blk * 4096 + k;
            let (s, v) = (mean[i], var[i]);
            *y = if noise {
                match Normal::new(s, v.sqrt()) {
                    Ok(d) => d.sample(&mut rng).max(0.0) as f32,
                    Err(_) => s as f32,
                }
            } else {
                s as f32
            };
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn physics(spectrum: &Spectrum) -> ClinicalPhysics {
        ClinicalPhysics::new(spectrum, 16_000.0, &Detector::default(), 16_000.0).unwrap()
    }

    /// Beer-Lambert with a spectrum: through a slab of adipose and one of
    /// fibroglandular tissue the signal is the analytic sum over the
    /// spectrum's energies of the detected energy times the two
    /// exponentials (coefficients from NIST-traceable tables: adipose at 20
    /// keV within 2 % of the paper's 0.512 /cm, fibroglandular of 0.798 /cm).
    #[test]
    fn a_spectrum_through_two_slabs_is_the_analytic_sum() {
        let tables = dbt_dose::tables::elements().unwrap();
        let a = Material::tissue(Tissue::Adipose, tables).unwrap();
        let g = Material::tissue(Tissue::Fibroglandular, tables).unwrap();
        assert!((a.mu(20.0).total() / 0.0512 - 1.0).abs() < 0.02);
        assert!((g.mu(20.0).total() / 0.0798 - 1.0).abs() < 0.02);
        let s = dbt_dose::xray::paper_spectrum(50.0)
            .unwrap()
            .spectrum
            .unwrap();
        let p = physics(&s);
        let csi = Material::medium(&dbt_materials::CSI, tables).unwrap();
        let (la, lg) = (30.0, 20.0);
        let (mut num, mut den) = (0.0, 0.0);
        for (&e, &w) in s.energies.iter().zip(&s.weights) {
            let eta = 1.0 - (-csi.mu(e).total() * 0.2).exp();
            den += w * eta * e;
            num += w * eta * e * (-(a.mu(e).total() * la + g.mu(e).total() * lg)).exp();
        }
        let (got, _) = p.expected([la, lg, 0.0]);
        assert!((got / (16_000.0 * num / den) - 1.0).abs() < 1e-12, "{got}");
        assert!((p.expected([0.0; 3]).0 / 16_000.0 - 1.0).abs() < 1e-15);
    }

    /// An a-Se detector: the same analytic sum with each energy weighted by
    /// the energy the layer keeps ([`dbt_dose::detector`]: absorbed less
    /// the escaping K fluorescence); it differs from CsI's: behind 40 mm of
    /// fibroglandular tissue the relative signal is 3-8 % higher than with
    /// CsI (the escape takes most from the soft end, which the tissue
    /// removes first: a-Se weights the harder photons more), which a
    /// linearisation for the wrong converter would read as less tissue.
    #[test]
    fn an_a_se_detector_weights_each_energy_by_what_it_keeps() {
        let tables = dbt_dose::tables::elements().unwrap();
        let g = Material::tissue(Tissue::Fibroglandular, tables).unwrap();
        let s = dbt_dose::xray::paper_spectrum(50.0)
            .unwrap()
            .spectrum
            .unwrap();
        let a_se = Converter::new(dbt_materials::ConverterMaterial::ASe, 200.0).unwrap();
        let p = ClinicalPhysics::new(&s, 16_000.0, &Detector::with(a_se), 16_000.0).unwrap();
        let conv = ConverterModel::new(a_se).unwrap();
        let (mut num, mut den) = (0.0, 0.0);
        for (&e, &w) in s.energies.iter().zip(&s.weights) {
            let kept = conv.response(e).unwrap().mean_kev;
            den += w * kept;
            num += w * kept * (-g.mu(e).total() * 40.0).exp();
        }
        let (got, _) = p.expected([0.0, 40.0, 0.0]);
        assert!((got / (16_000.0 * num / den) - 1.0).abs() < 1e-12, "{got}");
        let csi = physics(&s).expected([0.0, 40.0, 0.0]).0;
        // 5.5 % more signal behind 40 mm with the paper's 30 kV W/Rh beam.
        assert!(
            got / csi > 1.03 && got / csi < 1.08,
            "a-Se {got}, CsI {csi}"
        );
    }

    /// One energy: the mono-energetic model, exactly (Beer-Lambert at that
    /// energy), whatever the detector; its variance is the photons'.
    #[test]
    fn a_mono_spectrum_is_beer_lambert() {
        let s = Spectrum::mono(20.0).unwrap();
        let p = ClinicalPhysics::new(
            &s,
            16_000.0,
            &Detector {
                converter: Converter::default(),
                electronic_photons: 0.0,
                line_spread_mm: 0.0,
            },
            16_000.0,
        )
        .unwrap();
        let tables = dbt_dose::tables::elements().unwrap();
        let g = Material::tissue(Tissue::Fibroglandular, tables).unwrap();
        let (got, var) = p.expected([0.0, 40.0, 0.0]);
        let t = (-g.mu(20.0).total() * 40.0).exp();
        assert!((got / (16_000.0 * t) - 1.0).abs() < 1e-12);
        // Detected photons n = N eta; signal = 16000 t in ADU of
        // 16000 / (N eta) per photon: variance (16000 / n)^2 n t.
        let n = p.detected_photons();
        assert!((var / (16_000.0f64.powi(2) / n * t) - 1.0).abs() < 1e-9);
    }

    /// The detector's efficiency: 200 um of CsI at 20 keV absorbs
    /// `1 - exp(-26.86 cm^2/g x 4.51 g/cm^3 x 0.02 cm) = 0.9113` (the mass
    /// coefficient is xraylib 4.3.0's CS_Total of Cs and I by mass,
    /// computed outside the tables this crate reads), fewer at 32 keV, more
    /// with a thicker layer, and jumps at iodine's K-edge (33.17 keV).
    #[test]
    fn csi_absorbs_as_its_attenuation_says() {
        let eff = |e: f64, um: f64| {
            let s = Spectrum::mono(e).unwrap();
            let d = Detector {
                converter: Converter::new(dbt_materials::ConverterMaterial::CsI, um).unwrap(),
                electronic_photons: 0.0,
                line_spread_mm: 0.0,
            };
            ClinicalPhysics::new(&s, 1.0, &d, 1.0)
                .unwrap()
                .detected_photons()
        };
        assert!(
            (eff(20.0, 200.0) - 0.9113).abs() < 1e-3,
            "{}",
            eff(20.0, 200.0)
        );
        assert!(eff(32.0, 200.0) < eff(20.0, 200.0));
        assert!(eff(32.0, 400.0) > eff(32.0, 200.0));
        // The K-edge of iodine: more absorbed just above than just below.
        assert!(eff(33.4, 100.0) > eff(33.0, 100.0));
    }

    /// Beam hardening: the log signal per mm falls as the path grows (the
    /// beam's mean energy rises), and the noise is seeded.
    #[test]
    fn the_beam_hardens_and_noise_is_reproducible() {
        let s = dbt_dose::xray::paper_spectrum(50.0)
            .unwrap()
            .spectrum
            .unwrap();
        let p = physics(&s);
        let per_mm = |l: f64| (p.flat_adu() / p.expected([0.0, l, 0.0]).0).ln() / l;
        assert!(per_mm(10.0) > per_mm(40.0) && per_mm(40.0) > per_mm(80.0));
        let paths = [vec![20.0f32; 5000], vec![10.0; 5000], vec![1.5; 5000]];
        let a = p.simulate(&paths, true, 7).unwrap();
        assert_eq!(a, p.simulate(&paths, true, 7).unwrap());
        assert_ne!(a, p.simulate(&paths, true, 8).unwrap());
        let (m, v) = p.expected([20.0, 10.0, 1.5]);
        let mean = a.iter().map(|&x| f64::from(x)).sum::<f64>() / a.len() as f64;
        let var = a
            .iter()
            .map(|&x| (f64::from(x) - mean).powi(2))
            .sum::<f64>()
            / (a.len() - 1) as f64;
        // 5000 draws: the mean within 4 standard errors, the variance within 10 %.
        assert!(
            (mean - m).abs() < 4.0 * (v / 5000.0).sqrt(),
            "{mean} vs {m}"
        );
        assert!((var / v - 1.0).abs() < 0.1, "{var} vs {v}");
        let e = p
            .simulate(&[vec![1.0], vec![], vec![]], false, 0)
            .unwrap_err();
        assert!(e.to_string().contains("path lengths"), "{e}");
    }

    /// A spreading detector (GE's CsI, `crate::spread`): a uniform exposure
    /// keeps its mean, and its noise is the quanta's times the spread
    /// quanta's variance (`spread::element_variance`, squared for the two
    /// axes) plus the electronic noise's, unspread (within the sampling
    /// error of 40,000 elements); an edge is spread exactly as the
    /// kernel says (noise-free); the draws are seeded; without a spread
    /// the stack's signals are `simulate`'s draw for draw; `simulate`
    /// refuses a spreading detector (it has no layout).
    #[test]
    fn a_spreading_detector_blurs_quanta_not_readout() {
        let s = dbt_dose::xray::paper_spectrum(50.0)
            .unwrap()
            .spectrum
            .unwrap();
        let spread_mm = 0.0568;
        let detector = Detector {
            // Electronic noise large enough to be seen beside the quanta.
            electronic_photons: 40.0,
            line_spread_mm: spread_mm,
            ..Detector::default()
        };
        let p = ClinicalPhysics::new(&s, 16_000.0, &detector, 16_000.0).unwrap();
        let (rows, cols) = (200, 200);
        let layout = StackLayout {
            rows,
            views: 1,
            cols,
            row_mm: 0.1,
            col_mm: 0.1,
            tan_angles: vec![0.0],
        };
        let n = rows * cols;
        let paths = [vec![20.0f32; n], vec![10.0; n], vec![1.5; n]];
        let (a, scatter) = p.simulate_stack(&paths, &layout, None, true, 7).unwrap();
        assert!(scatter.iter().all(|&x| x == 0.0));
        assert_eq!(
            a,
            p.simulate_stack(&paths, &layout, None, true, 7).unwrap().0
        );
        let (m, v) = p.expected([20.0, 10.0, 1.5]);
        let e_var = p.electronic_sd * p.electronic_sd;
        let k = crate::spread::element_kernel(spread_mm, 0.1).unwrap();
        let (_, per_axis) = crate::spread::element_variance(spread_mm, 0.1).unwrap();
        let want = (v - e_var) * per_axis * per_axis + e_var;
        // The interior (the mirrored borders correlate differently).
        let inner: Vec<f64> = (5..rows - 5)
            .flat_map(|r| (5..cols - 5).map(move |c| r * cols + c))
            .map(|i| f64::from(a[i]))
            .collect();
        let mean = inner.iter().sum::<f64>() / inner.len() as f64;
        let var = inner.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (inner.len() - 1) as f64;
        assert!((mean / m - 1.0).abs() < 1e-3, "{mean} vs {m}");
        assert!(
            (var / want - 1.0).abs() < 0.05,
            "{var} vs {want} (unspread {v})"
        );
        assert!(want < 0.75 * v, "the spread removes noise: {want} of {v}");

        // A noise-free edge: 20 mm more gland under the left half.
        let paths = [
            vec![20.0f32; n],
            (0..n)
                .map(|i| if i % cols < cols / 2 { 30.0 } else { 10.0 })
                .collect(),
            vec![1.5; n],
        ];
        let (edge, _) = p.simulate_stack(&paths, &layout, None, false, 0).unwrap();
        let (lo, hi) = (
            p.expected([20.0, 30.0, 1.5]).0,
            p.expected([20.0, 10.0, 1.5]).0,
        );
        let half = k.len() / 2;
        for c in 0..cols {
            let want: f64 = (0..k.len())
                .map(|t| {
                    let src = (c + t) as i64 - half as i64;
                    let src = src.clamp(0, cols as i64 - 1) as usize;
                    k[t] * if src < cols / 2 { lo } else { hi }
                })
                .sum();
            let got = f64::from(edge[100 * cols + c]);
            assert!(
                (got / want - 1.0).abs() < 1e-6,
                "column {c}: {got} vs {want}"
            );
        }
        assert!(f64::from(edge[100 * cols + cols / 2 - 1]) > lo * 1.01);

        let e = p.simulate(&paths, false, 0).unwrap_err().to_string();
        assert!(e.contains("line spread") && e.contains("0.0568"), "{e}");
        // No spread: the stack draws what `simulate` draws.
        let plain = physics(&s);
        let paths = [vec![20.0f32; n], vec![10.0; n], vec![1.5; n]];
        assert_eq!(
            plain
                .simulate_stack(&paths, &layout, None, true, 9)
                .unwrap()
                .0,
            plain.simulate(&paths, true, 9).unwrap()
        );
        let bad = Detector {
            line_spread_mm: -1.0,
            ..Detector::default()
        };
        let e = ClinicalPhysics::new(&s, 1.0, &bad, 1.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("line spread -1"), "{e}");
    }
}
