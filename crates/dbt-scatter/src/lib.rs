//! Scatter at the detector of a DBT view by kernel superposition (issue
//! #27): the fast model of the photons that reach the detector after
//! interacting in the breast, the paddle or the support, fitted to our
//! Monte Carlo engine (`dbt_dose::scatter`, fitted by `dbt-dose
//! scatter-fit`), used by the simulator to add scatter to a clinical
//! acquisition and by the firmware to remove it before DBToR.
//!
//! # The model
//! On the detector of one view, with the signals as fractions of the open
//! field's primary (the view without a breast, paddle and support in
//! place), the primary transmission `T(u)` and its log `p(u) = -ln T(u)`,
//! the scatter is
//!
//! `s(u) = sum_u' T(u') A(p(u')) k(u - u' - c tan(theta) e)`
//!
//! each pixel's primary spreading a share `A(p)` of itself as scatter with
//! the kernel `k = (1 - w) G(sigma_1) + w G(sigma_2)` (two normalised 2-D
//! Gaussians: a narrow one for the forward-peaked Rayleigh and single
//! Compton scatter, a wide one for the rest), shifted by `c tan(theta)`
//! along the chest wall (`e`: the direction the source moves) for the
//! view angle `theta` (the scatter kernel turns asymmetric with the
//! projection angle, Sechopoulos et al. 2007, Med Phys 34:564). `A` is
//! piecewise linear in `p` (the kernel "driven by the local projection
//! value"); `sigma_1`, `sigma_2`, `w`, `c` and the knots of `A` are fitted
//! per compressed thickness ([`fit`]) and interpolated between thicknesses.
//! It is the kernel-superposition family of the DBT literature (Díaz et
//! al.; Sun & Star-Lack's adaptive kernels for cone-beam CT); its use of
//! the projection value for the amplitude is ours.
//!
//! # Units and layout
//! Images are row-major on a [`Grid`]: rows from the chest wall toward the
//! nipple, columns along the chest wall; pitches in mm on the detector.
//! Signals are fractions of the open field (dimensionless).

use serde::{Deserialize, Serialize};
use thiserror::Error;

pub mod fit;

/// Errors of the scatter model; each names the bad value.
#[derive(Debug, Clone, Error, PartialEq)]
pub enum ScatterError {
    /// An image or a grid is malformed.
    #[error("scatter image: {0}")]
    Image(String),
    /// A kernel table is malformed.
    #[error("scatter table: {0}")]
    Table(String),
}

/// A detector image's pixels and pitches.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Grid {
    /// Rows (from the chest wall).
    pub rows: usize,
    /// Columns (along the chest wall).
    pub cols: usize,
    /// Row pitch, mm.
    pub row_mm: f64,
    /// Column pitch, mm.
    pub col_mm: f64,
}

impl Grid {
    /// Pixels.
    pub fn len(&self) -> usize {
        self.rows * self.cols
    }

    /// Whether it has no pixel.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Check the grid and that `img` has its size.
    pub fn check(&self, img: &[f64], what: &str) -> Result<(), ScatterError> {
        if self.is_empty()
            || !(self.row_mm.is_finite() && self.row_mm > 0.0)
            || !(self.col_mm.is_finite() && self.col_mm > 0.0)
        {
            return Err(ScatterError::Image(format!(
                "grid {} x {} pixels of {} x {} mm is empty or has a bad pitch",
                self.rows, self.cols, self.row_mm, self.col_mm
            )));
        }
        if img.len() != self.len() {
            return Err(ScatterError::Image(format!(
                "{what} has {} pixels, the grid {} x {} = {}",
                img.len(),
                self.rows,
                self.cols,
                self.len()
            )));
        }
        if let Some((i, v)) = img.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(ScatterError::Image(format!(
                "{what} pixel {i} (row {}, column {}) is {v}",
                i / self.cols,
                i % self.cols
            )));
        }
        Ok(())
    }
}

/// The kernels of one compressed thickness.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Kernels {
    /// Compressed thickness, mm.
    pub thickness_mm: f64,
    /// Standard deviations of the narrow and the wide Gaussian, mm.
    pub sigma_mm: [f64; 2],
    /// Weight `w` of the wide Gaussian.
    pub wide_weight: f64,
    /// Shift `c` of the kernel along the chest wall per unit `tan(theta)`, mm.
    pub shift_mm: f64,
    /// Knots of `A` in `p` (increasing); `A` is constant beyond the ends.
    pub p_knots: Vec<f64>,
    /// `A` at the knots.
    pub amplitude: Vec<f64>,
}

impl Kernels {
    fn check(&self) -> Result<(), ScatterError> {
        let t = self.thickness_mm;
        let bad = |w: String| Err(ScatterError::Table(format!("thickness {t} mm: {w}")));
        if !(t.is_finite() && t > 0.0) {
            return bad("the thickness must be positive".into());
        }
        if self.sigma_mm.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return bad(format!("sigmas {:?} mm must be positive", self.sigma_mm));
        }
        if !(0.0..=1.0).contains(&self.wide_weight) {
            return bad(format!(
                "wide weight {} is not a fraction",
                self.wide_weight
            ));
        }
        if !self.shift_mm.is_finite() {
            return bad(format!("shift {} mm", self.shift_mm));
        }
        if self.p_knots.is_empty() || self.p_knots.len() != self.amplitude.len() {
            return bad(format!(
                "{} knots and {} amplitudes",
                self.p_knots.len(),
                self.amplitude.len()
            ));
        }
        if self
            .p_knots
            .windows(2)
            .any(|w| w[1] <= w[0] || w[1].is_nan())
        {
            return bad(format!("knots {:?} do not increase", self.p_knots));
        }
        if let Some(a) = self
            .amplitude
            .iter()
            .find(|a| !(a.is_finite() && **a >= 0.0))
        {
            return bad(format!("amplitude {a} must be non-negative"));
        }
        Ok(())
    }

    /// `A(p)`: piecewise linear between the knots, constant beyond them.
    pub fn amplitude_at(&self, p: f64) -> f64 {
        let k = &self.p_knots;
        let a = &self.amplitude;
        if p <= k[0] {
            return a[0];
        }
        match k.iter().position(|&x| x > p) {
            None => a[a.len() - 1],
            Some(i) => {
                let f = (p - k[i - 1]) / (k[i] - k[i - 1]);
                a[i - 1] + f * (a[i] - a[i - 1])
            }
        }
    }

    /// The kernel applied to a source image `q` (each pixel's scatter
    /// before spreading), shifted for `tan_angle`.
    pub fn spread(&self, q: &[f64], grid: &Grid, tan_angle: f64) -> Vec<f64> {
        let w = self.wide_weight;
        let a = gaussian_blur(q, grid, self.sigma_mm[0]);
        let b = gaussian_blur(q, grid, self.sigma_mm[1]);
        let s: Vec<f64> = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (1.0 - w) * x + w * y)
            .collect();
        shift_cols(&s, grid, self.shift_mm * tan_angle)
    }

    /// The scatter of a primary transmission image `t` (fractions of the
    /// open field) at the view angle whose tangent is `tan_angle`.
    pub fn scatter(&self, t: &[f64], grid: &Grid, tan_angle: f64) -> Vec<f64> {
        let q: Vec<f64> = t
            .iter()
            .map(|&x| {
                let x = x.clamp(1e-9, 1.0);
                x * self.amplitude_at(-x.ln())
            })
            .collect();
        self.spread(&q, grid, tan_angle)
    }
}

/// The kernels of every fitted thickness for one spectrum family,
/// geometry and detector, with where they came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScatterTable {
    /// The spectra (e.g. the paper's Table 3 W/Rh by thickness).
    pub spectrum: String,
    /// The geometry (source, detector, air gap, paddle, support).
    pub geometry: String,
    /// The detector.
    pub detector: String,
    /// The command that made it, the engine's photons and seeds.
    pub provenance: String,
    /// One entry per fitted thickness, by increasing thickness.
    pub kernels: Vec<Kernels>,
}

/// The shipped table (paper geometry, Table 3 W/Rh spectra, 200 um CsI):
/// `data/w-rh-paper.json`, made by `dbt-dose scatter-fit`.
pub const SHIPPED_JSON: &str = include_str!("../data/w-rh-paper.json");
/// The shipped table of the W/Al beam (paper geometry, the W/Al automatic
/// exposure, 200 um CsI): `data/w-al-paper.json`, made by `dbt-dose
/// scatter-fit --anode-filter W/Al`.
pub const SHIPPED_W_AL_JSON: &str = include_str!("../data/w-al-paper.json");
/// The shipped table of the W/Ag beam (paper geometry, the W/Ag automatic
/// exposure, 200 um CsI): `data/w-ag-paper.json`, made by `dbt-dose
/// scatter-fit --anode-filter W/Ag`.
pub const SHIPPED_W_AG_JSON: &str = include_str!("../data/w-ag-paper.json");
/// The shipped tables of the molybdenum- and rhodium-anode beams (paper
/// geometry, each beam's simulated automatic exposure, 200 um CsI):
/// `data/mo-mo-paper.json`, `data/mo-rh-paper.json`, `data/rh-rh-paper.json`,
/// made by `dbt-dose scatter-fit --anode-filter Mo/Mo` (`Mo/Rh`, `Rh/Rh`).
pub const SHIPPED_MO_MO_JSON: &str = include_str!("../data/mo-mo-paper.json");
/// See [`SHIPPED_MO_MO_JSON`].
pub const SHIPPED_MO_RH_JSON: &str = include_str!("../data/mo-rh-paper.json");
/// See [`SHIPPED_MO_MO_JSON`].
pub const SHIPPED_RH_RH_JSON: &str = include_str!("../data/rh-rh-paper.json");

/// Each beam's shipped table, by the name the gantry's anode/filter
/// register gives the beam.
pub const SHIPPED_TABLES: [(&str, &str); 6] = [
    ("W/Rh", SHIPPED_JSON),
    ("W/Al", SHIPPED_W_AL_JSON),
    ("W/Ag", SHIPPED_W_AG_JSON),
    ("Mo/Mo", SHIPPED_MO_MO_JSON),
    ("Mo/Rh", SHIPPED_MO_RH_JSON),
    ("Rh/Rh", SHIPPED_RH_RH_JSON),
];

impl ScatterTable {
    /// Parse and check a table.
    pub fn from_json(text: &str) -> Result<Self, ScatterError> {
        let t: ScatterTable =
            serde_json::from_str(text).map_err(|e| ScatterError::Table(e.to_string()))?;
        t.check()?;
        Ok(t)
    }

    /// The shipped table (W/Rh's), parsed once.
    pub fn shipped() -> Result<&'static ScatterTable, ScatterError> {
        Self::shipped_for("W/Rh")
    }

    /// The shipped table of a beam named as the gantry's anode/filter
    /// register names it (one of [`SHIPPED_TABLES`]), parsed once; another
    /// name is refused, naming it and the beams that have one.
    pub fn shipped_for(anode_filter: &str) -> Result<&'static ScatterTable, ScatterError> {
        type Parsed = std::sync::OnceLock<Result<ScatterTable, ScatterError>>;
        static PARSED: [Parsed; SHIPPED_TABLES.len()] =
            [const { Parsed::new() }; SHIPPED_TABLES.len()];
        let i = SHIPPED_TABLES
            .iter()
            .position(|(name, _)| *name == anode_filter)
            .ok_or_else(|| {
                let have: Vec<&str> = SHIPPED_TABLES.iter().map(|(n, _)| *n).collect();
                ScatterError::Table(format!(
                    "no scatter table for the anode/filter `{anode_filter}` ({})",
                    have.join(", ")
                ))
            })?;
        PARSED[i]
            .get_or_init(|| Self::from_json(SHIPPED_TABLES[i].1))
            .as_ref()
            .map_err(Clone::clone)
    }

    /// Check every entry and their order.
    pub fn check(&self) -> Result<(), ScatterError> {
        if self.kernels.is_empty() {
            return Err(ScatterError::Table("no thickness".into()));
        }
        for k in &self.kernels {
            k.check()?;
        }
        if self
            .kernels
            .windows(2)
            .any(|w| w[1].thickness_mm <= w[0].thickness_mm || w[1].thickness_mm.is_nan())
        {
            return Err(ScatterError::Table("thicknesses do not increase".into()));
        }
        Ok(())
    }

    /// The fitted thicknesses' range, mm.
    pub fn range_mm(&self) -> (f64, f64) {
        (
            self.kernels[0].thickness_mm,
            self.kernels[self.kernels.len() - 1].thickness_mm,
        )
    }

    /// The two entries bracketing `thickness_mm` and the weight of the
    /// second (clamped to the fitted range).
    fn bracket(&self, thickness_mm: f64) -> (&Kernels, &Kernels, f64) {
        let k = &self.kernels;
        let i = k
            .iter()
            .position(|e| e.thickness_mm >= thickness_mm)
            .unwrap_or(k.len() - 1);
        if i == 0 || k[i].thickness_mm <= thickness_mm {
            return (&k[i], &k[i], 0.0);
        }
        let (a, b) = (&k[i - 1], &k[i]);
        (
            a,
            b,
            (thickness_mm - a.thickness_mm) / (b.thickness_mm - a.thickness_mm),
        )
    }

    /// The scatter of a primary transmission image `t` of a breast
    /// `thickness_mm` thick at the view angle whose tangent is
    /// `tan_angle`: the two bracketing thicknesses' estimates interpolated
    /// linearly (the nearest fitted one outside the range).
    pub fn scatter(
        &self,
        t: &[f64],
        grid: &Grid,
        thickness_mm: f64,
        tan_angle: f64,
    ) -> Result<Vec<f64>, ScatterError> {
        grid.check(t, "primary transmission")?;
        if !(thickness_mm.is_finite() && thickness_mm > 0.0) {
            return Err(ScatterError::Image(format!(
                "compressed thickness {thickness_mm} mm"
            )));
        }
        let (a, b, f) = self.bracket(thickness_mm);
        let sa = a.scatter(t, grid, tan_angle);
        if f == 0.0 {
            return Ok(sa);
        }
        let sb = b.scatter(t, grid, tan_angle);
        Ok(sa
            .iter()
            .zip(&sb)
            .map(|(x, y)| (1.0 - f) * x + f * y)
            .collect())
    }

    /// Remove the scatter from a measured image `m` (primary plus scatter,
    /// fractions of the open field): the primary `T` with
    /// `T + s(T) = m`, by the multiplicative fixed point
    /// `T <- T m / (T + s(T))` from `T = m / 2` (it stays positive and, the
    /// model's scatter growing with the primary, converges where the
    /// additive one diverges for scatter-to-primary ratios above 1).
    /// Returns the primary and the scatter after `iterations` steps.
    pub fn remove(
        &self,
        m: &[f64],
        grid: &Grid,
        thickness_mm: f64,
        tan_angle: f64,
        iterations: usize,
    ) -> Result<(Vec<f64>, Vec<f64>), ScatterError> {
        grid.check(m, "measured image")?;
        let m: Vec<f64> = m.iter().map(|&x| x.max(1e-9)).collect();
        let mut t: Vec<f64> = m.iter().map(|&x| (x / 2.0).min(1.0)).collect();
        let mut s = self.scatter(&t, grid, thickness_mm, tan_angle)?;
        for _ in 0..iterations {
            for ((ti, &mi), &si) in t.iter_mut().zip(&m).zip(&s) {
                *ti = (*ti * mi / (*ti + si)).min(1.0);
            }
            s = self.scatter(&t, grid, thickness_mm, tan_angle)?;
        }
        Ok((t, s))
    }
}

/// Separable Gaussian blur of standard deviation `sigma_mm`, zero outside
/// the image (nothing scatters from beyond the detector's edge), the
/// kernel truncated at 4 sigma and normalised over its full extent (so
/// the blur conserves the image's sum away from the edges).
pub fn gaussian_blur(img: &[f64], grid: &Grid, sigma_mm: f64) -> Vec<f64> {
    let taps = |pitch: f64| -> Vec<f64> {
        let s = sigma_mm / pitch;
        let r = (4.0 * s).ceil().max(1.0) as isize;
        let mut k: Vec<f64> = (-r..=r)
            .map(|i| {
                // Integral of the Gaussian over the pixel (not its centre value).
                let (a, b) = ((i as f64 - 0.5) / s, (i as f64 + 0.5) / s);
                erf(b / std::f64::consts::SQRT_2) - erf(a / std::f64::consts::SQRT_2)
            })
            .collect();
        let sum: f64 = k.iter().sum();
        k.iter_mut().for_each(|x| *x /= sum);
        k
    };
    let (kr, kc) = (taps(grid.row_mm), taps(grid.col_mm));
    let (nr, nc) = (grid.rows, grid.cols);
    let rc = (kc.len() / 2) as isize;
    let mut tmp = vec![0.0; nr * nc];
    for r in 0..nr {
        let row = &img[r * nc..(r + 1) * nc];
        let out = &mut tmp[r * nc..(r + 1) * nc];
        for (c, o) in out.iter_mut().enumerate() {
            let mut acc = 0.0;
            for (j, &w) in kc.iter().enumerate() {
                let cc = c as isize + j as isize - rc;
                if cc >= 0 && (cc as usize) < nc {
                    acc += w * row[cc as usize];
                }
            }
            *o = acc;
        }
    }
    let rr = (kr.len() / 2) as isize;
    let mut out = vec![0.0; nr * nc];
    for r in 0..nr {
        for (j, &w) in kr.iter().enumerate() {
            let src = r as isize + j as isize - rr;
            if src < 0 || src as usize >= nr {
                continue;
            }
            let s = &tmp[src as usize * nc..(src as usize + 1) * nc];
            for (o, &v) in out[r * nc..(r + 1) * nc].iter_mut().zip(s) {
                *o += w * v;
            }
        }
    }
    out
}

/// The image moved by `mm` along the columns (linear interpolation, zero
/// entering from the edge).
pub fn shift_cols(img: &[f64], grid: &Grid, mm: f64) -> Vec<f64> {
    if mm == 0.0 {
        return img.to_vec();
    }
    let d = mm / grid.col_mm;
    let (whole, frac) = (d.floor() as isize, d - d.floor());
    let nc = grid.cols as isize;
    let mut out = vec![0.0; img.len()];
    for r in 0..grid.rows {
        let row = &img[r * grid.cols..(r + 1) * grid.cols];
        let at = |c: isize| {
            if c >= 0 && c < nc {
                row[c as usize]
            } else {
                0.0
            }
        };
        for c in 0..nc {
            // out(c) = in(c - d)
            let src = c - whole;
            out[r * grid.cols + c as usize] = (1.0 - frac) * at(src) + frac * at(src - 1);
        }
    }
    out
}

/// Block means of `fr x fc` pixels (partial blocks at the far edges
/// averaged over what they hold).
pub fn block_mean(img: &[f64], grid: &Grid, fr: usize, fc: usize) -> (Vec<f64>, Grid) {
    let (fr, fc) = (fr.max(1), fc.max(1));
    let g = Grid {
        rows: grid.rows.div_ceil(fr),
        cols: grid.cols.div_ceil(fc),
        row_mm: grid.row_mm * fr as f64,
        col_mm: grid.col_mm * fc as f64,
    };
    let mut sum = vec![0.0; g.len()];
    let mut n = vec![0u32; g.len()];
    for r in 0..grid.rows {
        for c in 0..grid.cols {
            let k = (r / fr) * g.cols + c / fc;
            sum[k] += img[r * grid.cols + c];
            n[k] += 1;
        }
    }
    for (s, &k) in sum.iter_mut().zip(&n) {
        *s /= f64::from(k.max(1));
    }
    (sum, g)
}

/// A coarse image `img` on `coarse` (block means of `fine`'s pixels,
/// [`block_mean`]) interpolated bilinearly back to every pixel of `fine`,
/// by pixel centres (held constant beyond the outermost centres).
pub fn upsample(img: &[f64], coarse: &Grid, fine: &Grid) -> Vec<f64> {
    let fr = coarse.row_mm / fine.row_mm;
    let fc = coarse.col_mm / fine.col_mm;
    let pos = |i: usize, f: f64, n: usize| -> (usize, usize, f64) {
        let x = ((i as f64 + 0.5) / f - 0.5).clamp(0.0, (n - 1) as f64);
        let a = x.floor() as usize;
        let b = (a + 1).min(n - 1);
        (a, b, x - a as f64)
    };
    let mut out = vec![0.0; fine.len()];
    for r in 0..fine.rows {
        let (r0, r1, wr) = pos(r, fr, coarse.rows);
        for c in 0..fine.cols {
            let (c0, c1, wc) = pos(c, fc, coarse.cols);
            let v = |rr: usize, cc: usize| img[rr * coarse.cols + cc];
            out[r * fine.cols + c] = (1.0 - wr) * ((1.0 - wc) * v(r0, c0) + wc * v(r0, c1))
                + wr * ((1.0 - wc) * v(r1, c0) + wc * v(r1, c1));
        }
    }
    out
}

/// The error function (Abramowitz & Stegun 7.1.26, |error| < 1.5e-7).
fn erf(x: f64) -> f64 {
    let s = x.signum();
    let x = x.abs();
    let t = 1.0 / (1.0 + 0.327_591_1 * x);
    let y = 1.0
        - (((((1.061_405_429 * t - 1.453_152_027) * t) + 1.421_413_741) * t - 0.284_496_736) * t
            + 0.254_829_592)
            * t
            * (-x * x).exp();
    s * y
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(rows: usize, cols: usize, mm: f64) -> Grid {
        Grid {
            rows,
            cols,
            row_mm: mm,
            col_mm: mm,
        }
    }

    fn kernels() -> Kernels {
        Kernels {
            thickness_mm: 50.0,
            sigma_mm: [8.0, 30.0],
            wide_weight: 0.4,
            shift_mm: 10.0,
            p_knots: vec![0.0, 1.0, 3.0],
            amplitude: vec![0.1, 0.5, 1.0],
        }
    }

    /// Conservation: far from the edges the kernel spreads each pixel's
    /// scatter without creating or losing any (sum of the spread equals
    /// the sum of the sources, to the 4-sigma truncation's renormalisation:
    /// exactly, up to rounding), and a shift moves, not scales.
    #[test]
    fn the_kernel_conserves_what_it_spreads() {
        // 320 mm square: the wide kernel's 4 sigma (120 mm) stays inside.
        let g = grid(161, 161, 2.0);
        let (a, b) = (80 * 161 + 80, 70 * 161 + 72);
        let mut q = vec![0.0; g.len()];
        q[a] = 1.0;
        q[b] = 0.5;
        let k = kernels();
        let s = k.spread(&q, &g, 0.0);
        let sum: f64 = s.iter().sum();
        assert!((sum - 1.5).abs() < 1e-9, "{sum}");
        let shifted = k.spread(&q, &g, 0.3);
        assert!((shifted.iter().sum::<f64>() - 1.5).abs() < 1e-9);
        // The centroid of the point's spread moves by c tan = 3 mm along columns.
        let one: Vec<f64> = {
            let mut q = vec![0.0; g.len()];
            q[a] = 1.0;
            k.spread(&q, &g, 0.3)
        };
        let cx: f64 = one
            .iter()
            .enumerate()
            .map(|(i, v)| (i % 161) as f64 * v)
            .sum::<f64>()
            / one.iter().sum::<f64>();
        assert!(((cx - 80.0) * 2.0 - 3.0).abs() < 1e-6, "{cx}");
        // A uniform source far from the edges: the spread is the source.
        let flat = vec![1.0; g.len()];
        let b = gaussian_blur(&flat, &g, 8.0);
        assert!((b[a] - 1.0).abs() < 1e-12);
    }

    /// Under a uniform slab wider than the kernel the scatter is `T A(p)`
    /// (the scatter-to-primary ratio is the amplitude), and removing it
    /// gives the primary back.
    #[test]
    fn a_uniform_slab_has_its_amplitude_as_spr_and_removal_inverts_it() {
        let g = grid(121, 121, 2.0);
        let t0 = (-2.0f64).exp();
        let t = vec![t0; g.len()];
        let table = ScatterTable {
            spectrum: "test".into(),
            geometry: "test".into(),
            detector: "test".into(),
            provenance: "test".into(),
            kernels: vec![kernels()],
        };
        let s = table.scatter(&t, &g, 50.0, 0.0).unwrap();
        let c = 60 * 121 + 60;
        assert!((s[c] / t0 - 0.75).abs() < 1e-6, "{}", s[c] / t0);
        let m: Vec<f64> = t.iter().zip(&s).map(|(a, b)| a + b).collect();
        let (p, _) = table.remove(&m, &g, 50.0, 0.0, 30).unwrap();
        assert!((p[c] / t0 - 1.0).abs() < 1e-4, "{}", p[c] / t0);
    }

    #[test]
    fn bad_images_and_tables_are_named() {
        let g = grid(4, 5, 1.0);
        let table = ScatterTable {
            spectrum: String::new(),
            geometry: String::new(),
            detector: String::new(),
            provenance: String::new(),
            kernels: vec![kernels()],
        };
        let e = table.scatter(&[0.5; 19], &g, 50.0, 0.0).unwrap_err();
        assert!(e.to_string().contains("19 pixels"), "{e}");
        let mut img = vec![0.5; 20];
        img[7] = f64::NAN;
        let e = table.scatter(&img, &g, 50.0, 0.0).unwrap_err();
        assert!(e.to_string().contains("row 1, column 2"), "{e}");
        let mut k = kernels();
        k.p_knots = vec![0.0, 2.0, 1.0];
        let e = ScatterTable {
            kernels: vec![k],
            ..table.clone()
        }
        .check()
        .unwrap_err();
        assert!(e.to_string().contains("do not increase"), "{e}");
    }

    #[test]
    fn block_means_and_upsampling_keep_a_linear_ramp() {
        let g = grid(20, 30, 0.8);
        let img: Vec<f64> = (0..g.len())
            .map(|i| (i / 30) as f64 + 2.0 * (i % 30) as f64)
            .collect();
        let (c, cg) = block_mean(&img, &g, 5, 5);
        assert_eq!((cg.rows, cg.cols), (4, 6));
        let up = upsample(&c, &cg, &g);
        // Inside the outermost coarse centres the ramp comes back exactly.
        for r in 3..17 {
            for col in 3..27 {
                let i = r * 30 + col;
                assert!((up[i] - img[i]).abs() < 1e-9, "{r} {col}");
            }
        }
    }
}

#[cfg(test)]
mod shipped_tests {
    use super::*;

    /// A breast-like image on the detector: a half disc from the chest
    /// wall, `p` rising from its edge to `p_max` at its centre.
    fn half_disc(g: &Grid, p_max: f64) -> Vec<f64> {
        (0..g.len())
            .map(|i| {
                let (r, c) = (
                    (i / g.cols) as f64,
                    (i % g.cols) as f64 - g.cols as f64 / 2.0,
                );
                let d = (r * r + c * c).sqrt() * g.row_mm / 90.0;
                if d < 1.0 {
                    (-p_max * (1.0 - d * d).sqrt().clamp(0.3, 1.0)).exp()
                } else {
                    1.0
                }
            })
            .collect()
    }

    /// The shipped table parses, covers 20-90 mm, and its removal inverts
    /// its scatter: from `T + s(T)` the primary comes back to 0.1 % under
    /// a thick breast (scatter-to-primary up to 1.5) at every angle.
    #[test]
    fn the_shipped_table_removes_what_it_adds() {
        let t = ScatterTable::shipped().unwrap();
        assert_eq!(t.range_mm(), (20.0, 90.0));
        let g = Grid {
            rows: 60,
            cols: 64,
            row_mm: 4.0,
            col_mm: 4.0,
        };
        for (thickness, p_max) in [(25.0, 1.5), (55.0, 3.0), (85.0, 4.8)] {
            let tr = half_disc(&g, p_max);
            for tan in [0.0, 0.2, -0.45] {
                let s = t.scatter(&tr, &g, thickness, tan).unwrap();
                let m: Vec<f64> = tr.iter().zip(&s).map(|(a, b)| a + b).collect();
                let (back, _) = t.remove(&m, &g, thickness, tan, 20).unwrap();
                let worst = tr
                    .iter()
                    .zip(&back)
                    .map(|(a, b)| (b / a - 1.0).abs())
                    .fold(0.0, f64::max);
                let spr = tr.iter().zip(&s).map(|(a, b)| b / a).fold(0.0, f64::max);
                assert!(
                    worst < 1e-3,
                    "{thickness} mm, tan {tan}: {worst} (SPR up to {spr})"
                );
            }
        }
    }
}
