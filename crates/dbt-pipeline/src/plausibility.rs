//! Physical plausibility: data that are well formed but cannot come from an
//! x-ray passing through a compressed breast are refused before a report is
//! written, with a reason that names the check, its measured value and its
//! limit. A few defective detector readings are corrected (interpolated
//! along the detector row) and the result carries a flag that says so.
//!
//! # The counts, against the flat field and the thickness
//! For each ray `(slice, view, element)` with flat field `b` (photons without
//! the breast) and chord `L` through the compression box (the slab between
//! the support and the paddle, `thickness_mm` high, within the image's
//! width; `dbt_geometry::chord_in_rect`), Beer-Lambert bounds the expected
//! count: `b exp(-mu_max L) <= E[c] <= b`, with `mu_max` the most attenuating
//! breast tissue of the material table (skin, 0.0854/mm at 20 keV). A count
//! is then
//! - **dead**: exactly zero (or not a finite non-negative number), where
//!   zero lies below the dark bound (so at least 36 photons were expected: a
//!   Poisson zero has probability below `exp(-36)`);
//! - **dark**: non-zero, below `lambda_min - Z sqrt(lambda_min)` with
//!   `lambda_min = b exp(-mu_max L)` and `Z` = [`NOISE_Z`]: more attenuation
//!   than the thickness allows (the Gaussian tail beyond 6 sd is 1e-9 per ray;
//!   an acquisition has at most a few million rays);
//! - **hot**: above `b + Z sqrt(b) + 1`: more photons than the unattenuated
//!   beam, beyond its Poisson noise;
//! - **saturated**: at the 16-bit detector's maximum, 65535, where the flat
//!   field lies below that maximum by more than its noise (otherwise the
//!   record is not of a 16-bit detector and the other checks apply);
//! - **stuck**: one detector element (slice, element) that reads the same
//!   non-zero value in every view, other than the flat field (a frozen
//!   readout: the rays of different views cross different tissue, and
//!   Poisson counts of 25 views never coincide).
//!
//! Up to [`DEFECT_FRACTION_MAX`] of the counts may be defective: they are
//! replaced by linear interpolation between the nearest good elements of the
//! same detector row and view, and [`CountsCheck::corrected`] says how many.
//! More is refused, naming the largest category. The limit is ours: flat-panel
//! specifications tolerate defective-pixel fractions of this order (corrected
//! by the defect map), and 0.1 % of rays each wrong by the full attenuation
//! range moves a reconstruction far less than its Poisson noise.
//!
//! # The reconstruction
//! After reconstruction, the breast (voxels not classified as air) must
//! - have a mean attenuation within the range of its tissues, between
//!   adipose and skin at 20 keV, widened by [`RECON_MU_MARGIN`] for partial
//!   volumes at the outline and reconstruction blur;
//! - have a volume that fits its compression box: at most
//!   [`VOLUME_FILL_MAX`] and at least [`VOLUME_FILL_MIN`] of the volume
//!   `thickness x footprint`, the footprint measured on the view nearest 0
//!   degrees (rays with a line integral above the noise), per slice.

use crate::acquisition::AcquisitionHeader;
pub use crate::layout::{box_chords, chord_in_box, cone_box_chords};
use crate::layout::{PerRay, RayLayout};
use dbt_materials::Tissue;
use serde::Serialize;
use thiserror::Error;

/// Standard deviations of Poisson noise a count may stray from its bound.
pub const NOISE_Z: f64 = 6.0;
/// Fraction of defective counts that is corrected and flagged; above it the
/// acquisition is refused.
pub const DEFECT_FRACTION_MAX: f64 = 1e-3;
/// The 16-bit detector's maximum count (GANTRY_INTERFACE.md: u16 counts).
pub const DETECTOR_MAX_COUNT: f32 = 65535.0;
/// Relative widening of the breast's mean-attenuation range.
pub const RECON_MU_MARGIN: f64 = 0.15;
/// Largest breast volume over `thickness x footprint`.
pub const VOLUME_FILL_MAX: f64 = 1.15;
/// Smallest breast volume over `thickness x footprint`.
pub const VOLUME_FILL_MIN: f64 = 0.35;

/// The most attenuating breast tissue, 1/mm (skin, at 20 keV).
pub fn mu_max_per_mm() -> f64 {
    Tissue::ALL
        .iter()
        .map(|t| t.mu_per_mm() as f64)
        .fold(0.0, f64::max)
}

/// Why an acquisition cannot be reported.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum Implausible {
    /// Too many defective counts of one kind.
    #[error("{fraction_pct:.3} % of the {rays} counts are {kind} ({detail}); {total_pct:.3} % are defective in all, at most {limit_pct} % can be corrected")]
    Counts {
        /// The most frequent defect: `zero (dead)`, `darker than the
        /// thickness allows`, `above the flat field`, `saturated`, `stuck`.
        kind: &'static str,
        /// How they were judged.
        detail: String,
        /// That kind's percentage of all counts.
        fraction_pct: f64,
        /// Every defective count's percentage of all counts.
        total_pct: f64,
        /// Counts checked.
        rays: usize,
        /// [`DEFECT_FRACTION_MAX`] in percent.
        limit_pct: f64,
    },
    /// The counts are not `slices x rays`.
    #[error("the counts hold {got} slices of {len} values; the header says {slices} slices of {rays} rays")]
    Shape {
        /// Slices present.
        got: usize,
        /// Length of the first wrong slice.
        len: usize,
        /// Slices announced.
        slices: usize,
        /// Rays per slice.
        rays: usize,
    },
    /// A defective count has no good neighbour in its detector row.
    #[error("slice {slice}, view {view}: every element of the detector row is defective")]
    DeadRow {
        /// Slice.
        slice: usize,
        /// View.
        view: usize,
    },
    /// The reconstructed breast's attenuation is outside its tissues' range.
    #[error("the reconstructed breast's mean attenuation {mean:.4}/mm is outside [{lo:.4}, {hi:.4}]/mm (adipose to skin at 20 keV, +-{margin_pct} %)")]
    Attenuation {
        /// Mean over the breast.
        mean: f64,
        /// Lower limit.
        lo: f64,
        /// Upper limit.
        hi: f64,
        /// [`RECON_MU_MARGIN`] in percent.
        margin_pct: f64,
    },
    /// The reconstructed breast does not fit its compression box.
    #[error("the reconstructed breast ({breast_cm3:.1} cm3) fills {fill:.2} of thickness x footprint ({box_cm3:.1} cm3); plausible is [{lo}, {hi}]")]
    Volume {
        /// Breast volume.
        breast_cm3: f64,
        /// Thickness x footprint.
        box_cm3: f64,
        /// Their ratio.
        fill: f64,
        /// [`VOLUME_FILL_MIN`].
        lo: f64,
        /// [`VOLUME_FILL_MAX`].
        hi: f64,
    },
}

/// What the counts check found (all zero on a clean acquisition).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct CountsCheck {
    /// Counts checked.
    pub rays: usize,
    /// Zero counts where photons were certain.
    pub dead: usize,
    /// Counts darker than the thickness allows (zeros included in `dead`).
    pub dark: usize,
    /// Counts above the flat field beyond its noise.
    pub hot: usize,
    /// Counts at the detector's maximum.
    pub saturated: usize,
    /// Counts of stuck elements.
    pub stuck: usize,
    /// Defective counts replaced by interpolation.
    pub corrected: usize,
}

impl CountsCheck {
    /// The quality flag a report carries, `None` when nothing was corrected.
    pub fn flag(&self) -> Option<String> {
        (self.corrected > 0).then(|| {
            format!(
                "{} defective detector counts of {} corrected by interpolation (dead {}, dark {}, hot {}, saturated {}, stuck {})",
                self.corrected, self.rays, self.dead, self.dark, self.hot, self.saturated, self.stuck
            )
        })
    }
}

/// The count above which a ray holds more photons than the unattenuated
/// beam, beyond its Poisson noise.
fn hot_bound(flux: f64) -> f64 {
    flux + NOISE_Z * flux.sqrt() + 1.0
}

/// The per-ray count below which a ray is darker than the thickness
/// allows: one bound per ray of a slice (the slice-wise stream), or per
/// ray of each detector row (a cone-beam system's frames, whose rows cross
/// the breast at other angles).
pub(crate) fn dark_bounds<H: RayLayout>(h: &H) -> PerRay {
    let mu = mu_max_per_mm();
    let flux = h.flux;
    h.box_chords().map(|l| {
        let lam = flux * (-mu * l).exp();
        lam - NOISE_Z * lam.sqrt()
    })
}

/// Counts with their defects corrected (borrowed where there were none),
/// and the check that says what was corrected: [`Defects::applied`].
pub type Corrected<'a> = (std::borrow::Cow<'a, [Vec<f32>]>, CountsCheck);

/// The defective counts that [`check_counts`] found, to be corrected.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Defects {
    /// What was found.
    pub check: CountsCheck,
    /// Per slice with a defect: which of its rays are defective.
    masks: Vec<(usize, Vec<bool>)>,
    /// Detector elements per view.
    elements: usize,
}

impl Defects {
    /// Whether no count is defective.
    pub fn is_empty(&self) -> bool {
        self.masks.is_empty()
    }

    /// `counts` with these defects corrected ([`Defects::correct`] on a
    /// copy), or `counts` themselves where there are none; and the check.
    pub fn applied<'a>(&self, counts: &'a [Vec<f32>]) -> Result<Corrected<'a>, Implausible> {
        if self.is_empty() {
            return Ok((std::borrow::Cow::Borrowed(counts), self.check.clone()));
        }
        let mut c = counts.to_vec();
        let chk = self.correct(&mut c)?;
        Ok((std::borrow::Cow::Owned(c), chk))
    }

    /// Replace every defective count by linear interpolation between the
    /// nearest good elements of its detector row (same slice and view);
    /// returns the check with `corrected` set.
    pub fn correct(&self, counts: &mut [Vec<f32>]) -> Result<CountsCheck, Implausible> {
        let nd = self.elements;
        let mut chk = self.check.clone();
        for (si, mask) in &self.masks {
            let Some(s) = counts.get_mut(*si) else {
                continue;
            };
            for (v, (row, m)) in s.chunks_mut(nd).zip(mask.chunks(nd)).enumerate() {
                if !m.iter().any(|&x| x) {
                    continue;
                }
                if m.iter().all(|&x| x) {
                    return Err(Implausible::DeadRow {
                        slice: *si,
                        view: v,
                    });
                }
                for k in 0..nd {
                    if !m[k] {
                        continue;
                    }
                    let left = (0..k).rev().find(|&j| !m[j]);
                    let right = (k + 1..nd).find(|&j| !m[j]);
                    row[k] = match (left, right) {
                        (Some(l), Some(r)) => {
                            let w = (k - l) as f32 / (r - l) as f32;
                            row[l] * (1.0 - w) + row[r] * w
                        }
                        (Some(l), None) => row[l],
                        (None, Some(r)) => row[r],
                        (None, None) => row[k],
                    };
                    chk.corrected += 1;
                }
            }
        }
        Ok(chk)
    }
}

/// Check every count against the flat field and the thickness: up to
/// [`DEFECT_FRACTION_MAX`] defective counts are returned for
/// [`Defects::correct`], more are refused. The header must have passed
/// [`crate::acquisition::validate_header`]. A cone-beam acquisition's
/// counts are its detector's frames (rows of views of columns): checked as
/// read, before the rebinning spreads a defect over slices and views.
pub fn check_counts<H: RayLayout>(h: &H, counts: &[Vec<f32>]) -> Result<Defects, Implausible> {
    check_counts_with(h, counts, false)
}

/// The most scatter an element outside the breast can receive, as a
/// fraction of the flat field: a count with the scatter left in
/// ([`check_counts_with`]) is taken as too bright only above
/// `(1 + SCATTER_AIR_MAX) x` the flat field. Our Monte Carlo engine's
/// scatter beside a 90 mm breast, the thickest the population holds, is
/// well under that (the shipped kernel model's largest air-side scatter,
/// `dbt-dose scatter-check`, is a few tenths of the flat field); doubling
/// the flat field is what no breast can give.
pub const SCATTER_AIR_MAX: f64 = 1.0;

/// [`check_counts`], for counts that still hold their scatter when
/// `scatter_in_counts` (the input of a network trained on uncorrected
/// clinical acquisitions, issue #27's other design): the elements beside
/// the breast then read above the flat field by its scatter, and only
/// counts above `(1 + SCATTER_AIR_MAX) x` the flat field are hot. That
/// bound holds for every element, so a hot element under the breast is
/// caught only above it too: the price of reading counts with scatter.
/// Saturation is judged on the flat field alone, as without scatter.
pub fn check_counts_with<H: RayLayout>(
    h: &H,
    counts: &[Vec<f32>],
    scatter_in_counts: bool,
) -> Result<Defects, Implausible> {
    let stack = h.stack();
    let (nv, nd) = (stack.views, stack.cols);
    let nr = nv * nd;
    if counts.len() != h.slices {
        return Err(Implausible::Shape {
            got: counts.len(),
            len: counts.first().map_or(0, |s| s.len()),
            slices: h.slices,
            rays: nr,
        });
    }
    if let Some(s) = counts.iter().find(|s| s.len() != nr) {
        return Err(Implausible::Shape {
            got: counts.len(),
            len: s.len(),
            slices: h.slices,
            rays: nr,
        });
    }
    let dark_below = dark_bounds(h);
    let b = h.flux;
    let hot = if scatter_in_counts {
        hot_bound(b * (1.0 + SCATTER_AIR_MAX))
    } else {
        hot_bound(b)
    };
    // A record of a 16-bit detector: its flat field lies below the maximum
    // (the flat field's own bound, whatever scatter the counts may hold).
    let saturable = (DETECTOR_MAX_COUNT as f64) > hot_bound(b);
    let mut chk = CountsCheck {
        rays: nr * counts.len(),
        ..Default::default()
    };
    let mut bad = vec![false; nr];
    let mut defects: Vec<(usize, Vec<bool>)> = Vec::new();
    for (si, s) in counts.iter().enumerate() {
        let mut any = false;
        for (r, (&c, &dark)) in s.iter().zip(dark_below.row(si)).enumerate() {
            let c64 = c as f64;
            let d = if !c64.is_finite() || c64 < 0.0 {
                chk.dead += 1;
                true
            } else if saturable && c >= DETECTOR_MAX_COUNT {
                chk.saturated += 1;
                true
            } else if c64 > hot {
                chk.hot += 1;
                true
            } else if c64 < dark {
                if c == 0.0 {
                    chk.dead += 1;
                } else {
                    chk.dark += 1;
                }
                true
            } else {
                false
            };
            bad[r] = d;
            any |= d;
        }
        // Stuck elements: the same non-zero value in every view, not the flat field.
        if nv > 1 {
            for k in 0..nd {
                let c0 = s[k];
                if c0 != 0.0
                    && (c0 as f64 - b).abs() > 1e-6 * b
                    && (1..nv).all(|v| s[v * nd + k] == c0)
                {
                    for v in 0..nv {
                        if !bad[v * nd + k] {
                            bad[v * nd + k] = true;
                            chk.stuck += 1;
                        }
                    }
                    any = true;
                }
            }
        }
        if any {
            defects.push((si, bad.clone()));
        }
    }
    let total = chk.dead + chk.dark + chk.hot + chk.saturated + chk.stuck;
    let limit = (DEFECT_FRACTION_MAX * chk.rays as f64).floor() as usize;
    if total > limit {
        let (kind, n, detail) = [
            (
                "zero (dead)",
                chk.dead,
                format!("no photon where the thickness lets {NOISE_Z} sd more through"),
            ),
            (
                "darker than the thickness allows",
                chk.dark,
                format!(
                    "below flat field x exp(-{:.4}/mm x chord) by more than {NOISE_Z} sd, for {} mm",
                    mu_max_per_mm(),
                    h.thickness_mm
                ),
            ),
            (
                "above the flat field",
                chk.hot,
                if scatter_in_counts {
                    format!(
                        "above {hot:.0}: the flat field {b} plus the most scatter beside a breast ({SCATTER_AIR_MAX} x it), + {NOISE_Z} sd"
                    )
                } else {
                    format!("above {b} + {NOISE_Z} sd")
                },
            ),
            ("saturated", chk.saturated, format!("at the detector's maximum {DETECTOR_MAX_COUNT}")),
            ("stuck", chk.stuck, "one value in every view".into()),
        ]
        .into_iter()
        .max_by_key(|(_, n, _)| *n)
        .unwrap_or(("defective", total, String::new()));
        let pct = |k: usize| 100.0 * k as f64 / chk.rays.max(1) as f64;
        return Err(Implausible::Counts {
            kind,
            detail,
            fraction_pct: pct(n),
            total_pct: pct(total),
            rays: chk.rays,
            limit_pct: DEFECT_FRACTION_MAX * 100.0,
        });
    }
    Ok(Defects {
        check: chk,
        masks: defects,
        elements: nd,
    })
}

/// What the reconstruction check measured.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct VolumeCheck {
    /// Mean attenuation of the breast voxels, 1/mm.
    pub breast_mean_mu: f64,
    /// Breast volume (voxels not air), cm^3.
    pub breast_cm3: f64,
    /// Thickness x footprint, cm^3.
    pub box_cm3: f64,
    /// `breast_cm3 / box_cm3`.
    pub fill: f64,
}

/// The footprint of each slice on the view nearest 0 degrees: the lateral
/// extent, mm at the image's centre (the isocentre in the paper's layout;
/// a raised image's own centre, `image.centre_z_mm`), between the outermost
/// elements whose line integral exceeds its noise (`NOISE_Z /
/// sqrt(counts)`).
pub fn footprint_mm(h: &AcquisitionHeader, counts: &[Vec<f32>]) -> Vec<f64> {
    let g = &h.geometry;
    let nd = g.n_det();
    let v0 = (0..g.n_views())
        .min_by(|&a, &b| g.angle_deg(a).abs().total_cmp(&g.angle_deg(b).abs()))
        .unwrap_or(0);
    // Detector pitch at the image's centre (the isocentre unless raised).
    let pitch = g.detector.pitch_mm * (g.source_to_center_mm - g.image.centre_z_mm)
        / g.source_to_detector_mm;
    counts
        .iter()
        .map(|s| {
            let row = &s[v0 * nd..(v0 + 1) * nd];
            let inside = |&c: &f32| {
                let c = (c as f64).max(0.5);
                (h.flux / c).ln() > NOISE_Z / c.sqrt()
            };
            match (row.iter().position(inside), row.iter().rposition(inside)) {
                (Some(a), Some(b)) => (b - a + 1) as f64 * pitch,
                _ => 0.0,
            }
        })
        .collect()
}

/// Check the reconstructed breast: its mean attenuation (voxels with a
/// non-air label) and its volume against `thickness x footprint`.
/// `mu` and `labels` are the volume `[lateral, vertical, depth]` of
/// `voxel_mm` voxels; `footprint` is [`footprint_mm`] of the counts.
pub fn check_volume(
    h: &AcquisitionHeader,
    footprint: &[f64],
    mu: &[f32],
    labels: &[u8],
    voxel_mm: f64,
) -> Result<VolumeCheck, Implausible> {
    let (mut n, mut sum) = (0usize, 0f64);
    for (&m, &l) in mu.iter().zip(labels) {
        if l != 0 {
            n += 1;
            sum += m as f64;
        }
    }
    let mean = if n > 0 { sum / n as f64 } else { 0.0 };
    let breast_cm3 = n as f64 * voxel_mm.powi(3) / 1000.0;
    let box_cm3 = footprint.iter().sum::<f64>() * h.slice_spacing_mm * h.thickness_mm / 1000.0;
    let fill = if box_cm3 > 0.0 {
        breast_cm3 / box_cm3
    } else {
        f64::INFINITY
    };
    let (lo, hi) = (
        Tissue::Adipose.mu_per_mm() as f64 * (1.0 - RECON_MU_MARGIN),
        Tissue::Skin.mu_per_mm() as f64 * (1.0 + RECON_MU_MARGIN),
    );
    if !(mean >= lo && mean <= hi) {
        return Err(Implausible::Attenuation {
            mean,
            lo,
            hi,
            margin_pct: RECON_MU_MARGIN * 100.0,
        });
    }
    if !(VOLUME_FILL_MIN..=VOLUME_FILL_MAX).contains(&fill) {
        return Err(Implausible::Volume {
            breast_cm3,
            box_cm3,
            fill,
            lo: VOLUME_FILL_MIN,
            hi: VOLUME_FILL_MAX,
        });
    }
    Ok(VolumeCheck {
        breast_mean_mu: mean,
        breast_cm3,
        box_cm3,
        fill,
    })
}
