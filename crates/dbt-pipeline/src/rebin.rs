//! Cone-beam projections as the slice-wise fan-beam sinograms DBToR reads
//! (issue #28).
//!
//! # The approximation
//! A real gantry's rays diverge in depth: a ray that reaches the detector
//! at depth `y_det` crosses the breast at depths from `y_det` (at the
//! support) to about `y_det (z_s - z_top) / (z_s - z_det)` (at its top). The
//! slice-wise reconstruction needs, for each coronal slice at depth `y_c`,
//! a fan-beam sinogram in the central fan's geometry. For each view `v`,
//! fan element `k` and slice `c`, the rebinned ray is the cone-beam ray
//! whose projection onto the `x-z` plane is the fan ray `(v, k)` and which
//! crosses depth `y_c` at the reference height `z_ref` (mid-breast); its
//! count is that of the detector element it reaches (the nearest element:
//! the count of one element, so the Poisson statistics DBToR was trained on
//! are kept), corrected for the ray's obliquity: a ray tilted out of the
//! `x-z` plane runs `s = |ray| / |its x-z projection|` times longer through
//! everything, so its line integral is divided by `s`
//! (`count' = flux (count / flux)^(1 / s)`, for counts a breast can give,
//! `0 < count <= flux`; any other value passes unchanged, so that the counts
//! check names it: a dead, saturated or hot element stays what it read).
//!
//! # Its error
//! For a breast uniform in depth the rebinned sinogram is the fan-beam one
//! exactly (rotating detector; a stationary detector adds the nearest-element
//! position error, at most half an element). Otherwise the rebinned ray
//! crosses depths `y_c +- dy` with
//! `dy = |y_c - y_s| (T / 2) / (z_s - z_ref)` (about 13 mm at 150 mm from the
//! chest wall for a 60 mm breast at the paper's geometry, 0 at the chest
//! wall; `depth_blur_mm`, measured by the tests). Where in depth it crosses
//! is a linear function of the height: the reconstructed stack is the breast
//! sheared in depth, which [`resample_depth`] undoes, leaving the part due
//! to the source's height changing with the view (about 0.5 mm at 150 mm).

use crate::acquisition::AcquisitionHeader;
use dbt_geometry::{ConeSystem, DetectorMotion, Geometry};
use dbt_intake::{ConeFrames, SliceHeader, SliceSinograms};
use rayon::prelude::*;
use thiserror::Error;

/// Why projections cannot be rebinned.
#[derive(Debug, Error, PartialEq)]
pub enum RebinError {
    /// The fan geometry is not the system's central fan.
    #[error("the fan geometry disagrees with cone-beam system {system}: {what}")]
    Geometry {
        /// The system's name.
        system: String,
        /// What differs.
        what: String,
    },
    /// Frames of the wrong size.
    #[error("cone-beam frames: {0}")]
    Shape(String),
}

/// The fan geometry a system's projections are rebinned to: the source
/// arc's radius and the detector at the distance it has at 0 degrees,
/// rotating, with the same views; elements and image as given.
pub fn check_fan(sys: &ConeSystem, fan: &Geometry) -> Result<(), RebinError> {
    let bad = |what: String| RebinError::Geometry {
        system: sys.name.clone(),
        what,
    };
    if (fan.source_to_center_mm - sys.arc_radius_mm).abs() > 1e-6 {
        return Err(bad(format!(
            "source to centre {} mm, the system's arc radius is {} mm",
            fan.source_to_center_mm, sys.arc_radius_mm
        )));
    }
    let d = sys.arc_radius_mm + sys.axis_height_mm;
    if (fan.source_to_detector_mm - d).abs() > 1e-6 {
        return Err(bad(format!(
            "source to detector {} mm, the system's is {d} mm",
            fan.source_to_detector_mm
        )));
    }
    if fan.n_views() != sys.n_views()
        || (0..fan.n_views()).any(|v| (fan.angle_deg(v) - sys.angle_deg(v)).abs() > 1e-9)
    {
        return Err(bad("the views' angles differ".into()));
    }
    if sys.detector_motion == DetectorMotion::Rotating
        && (fan.n_det() != sys.detector.columns
            || (fan.detector.pitch_mm - sys.detector.pitch_mm).abs() > 1e-9)
    {
        return Err(bad(format!(
            "a rotating detector's columns are the fan's elements: {} x {} mm, the fan has {} x {} mm",
            sys.detector.columns, sys.detector.pitch_mm, fan.n_det(), fan.detector.pitch_mm
        )));
    }
    Ok(())
}

/// [`check_fan`], and the fan image resting on the system's support (the
/// breast lies there in both): what a site's configuration of a system and a
/// reconstruction geometry must satisfy.
pub fn check_site(sys: &ConeSystem, fan: &Geometry) -> Result<(), RebinError> {
    check_fan(sys, fan)?;
    let bottom = sys.axis_height_mm + fan.support_z_mm();
    if (bottom - sys.support_height_mm).abs() > 1e-6 {
        return Err(RebinError::Geometry {
            system: sys.name.clone(),
            what: format!(
                "the fan image's bottom row is {bottom} mm above the detector, the support {} mm",
                sys.support_height_mm
            ),
        });
    }
    Ok(())
}

/// The depth range (half width, mm) a rebinned slice at depth `y_c` averages
/// over, for a breast `thickness_mm` thick read at mid-breast (`z_ref`).
pub fn depth_blur_mm(sys: &ConeSystem, y_c: f64, thickness_mm: f64) -> f64 {
    let z_s = sys.axis_height_mm + sys.arc_radius_mm;
    let z_ref = sys.support_height_mm + thickness_mm / 2.0;
    (y_c - sys.source_depth_mm).abs() * (thickness_mm / 2.0) / (z_s - z_ref)
}

/// The mean source height over the views, mm above the detector.
fn mean_source_height(sys: &ConeSystem) -> f64 {
    let n = sys.n_views();
    (0..n).map(|v| sys.source(v)[2]).sum::<f64>() / n.max(1) as f64
}

/// The slice-wise reconstruction of rebinned sinograms as a regular volume
/// (issue #28: "resample the stack"). Every rebinned ray of slice `c` runs,
/// seen along the chest wall, from the source (depth `y_s`, height `z_s`)
/// through depth `y_c` at height `z_ref`: at height `z` it is at depth
/// `y_s + (y_c - y_s) k(z)`, `k(z) = (z_s - z) / (z_s - z_ref)`. In the
/// coordinates `(x, y', z)` with `y = y_s + (y' - y_s) k(z)` every such ray
/// lies in a plane `y' = y_c`, and, with the obliquity correction, its line
/// integral is the fan-beam one through that plane: the stack DBToR
/// reconstructs is the breast in those coordinates, sheared in depth by the
/// height, not blurred. This undoes the shear: the value at depth `y`,
/// height `z` is the stack's at `y' = y_s + (y - y_s) / k(z)`, linear between
/// slices (air beyond the last). Left over: the source's height changes
/// with the view (`z_s` here is the views' mean): at the paper's 24 degrees
/// it is 644 mm instead of 700, which moves `k` by 0.3 % at the top of a 60
/// mm breast, 0.5 mm at 150 mm from the chest wall (the shear undone was
/// 13 mm there).
///
/// `mu` has dims `[columns, rows, slices]` (row 0 on the support at
/// `support_mm`, rows `pixel_mm` high, slices `pixel_mm` apart from the
/// chest wall); `thickness_mm` sets `z_ref` as [`slice_sinograms`] does.
/// Returns the volume and its dims: as many slices as the deepest row needs.
pub fn resample_depth(
    sys: &ConeSystem,
    thickness_mm: f64,
    pixel_mm: f64,
    mu: &[f32],
    dims: [usize; 3],
) -> (Vec<f32>, [usize; 3]) {
    let [nx, nz, nd] = dims;
    let z_s = mean_source_height(sys);
    let y_s = sys.source_depth_mm;
    let z_ref = sys.support_height_mm + thickness_mm / 2.0;
    let k = |v: usize| {
        let z = sys.support_height_mm + (v as f64 + 0.5) * pixel_mm;
        (z_s - z) / (z_s - z_ref)
    };
    // The deepest reconstructed slice's far face, at the row stretched most.
    let k_max = (0..nz).map(k).fold(1.0f64, f64::max);
    let depth = y_s + (nd as f64 * pixel_mm - y_s) * k_max;
    let out_d = ((depth / pixel_mm).ceil() as usize).max(nd);
    let mut out = vec![0.0f32; nx * nz * out_d];
    for v in 0..nz {
        let kv = k(v);
        for d in 0..out_d {
            let y = (d as f64 + 0.5) * pixel_mm;
            // The stack's fractional slice index at (y, z).
            let c = (y_s + (y - y_s) / kv) / pixel_mm - 0.5;
            if c > nd as f64 - 0.5 {
                continue; // beyond the last slice: air
            }
            let c = c.max(0.0);
            let (c0, w) = (c.floor() as usize, c - c.floor());
            let c1 = (c0 + 1).min(nd - 1);
            let dst = (d * nz + v) * nx;
            let (a, b) = ((c0 * nz + v) * nx, (c1 * nz + v) * nx);
            for x in 0..nx {
                out[dst + x] = ((1.0 - w) * f64::from(mu[a + x]) + w * f64::from(mu[b + x])) as f32;
            }
        }
    }
    (out, [nx, nz, out_d])
}

/// Rebinned projections.
#[derive(Debug, Clone, PartialEq)]
pub struct Rebinned {
    /// Counts `[slice][view * element + element]` in the fan geometry.
    pub counts: Vec<Vec<f32>>,
    /// Per slice, the rays through the image box that reached beyond the
    /// detector's edge (given the edge element's count).
    pub off_detector: Vec<usize>,
}

/// The rebinned sinograms of coronal slices `0..slices` (`slice_mm` apart,
/// centres at `(c + 1/2) slice_mm` from the chest wall) from cone-beam frames
/// `frames[row][view * columns + column]` of `sys`, read at height `z_ref_mm`
/// above the detector; counts `[slice][view * elements + element]` in the
/// geometry `fan` (checked by [`check_fan`]). `flux` is the unattenuated
/// count (for the obliquity correction).
pub fn rebin(
    sys: &ConeSystem,
    fan: &Geometry,
    frames: &[Vec<f32>],
    flux: f64,
    slices: usize,
    slice_mm: f64,
    z_ref_mm: f64,
) -> Result<Rebinned, RebinError> {
    check_fan(sys, fan)?;
    let (rows, cols, views) = (sys.detector.rows, sys.detector.columns, sys.n_views());
    if frames.len() != rows || frames.iter().any(|f| f.len() != views * cols) {
        return Err(RebinError::Shape(format!(
            "{} rows of {:?} values for a {rows} x {cols} detector and {views} views",
            frames.len(),
            frames.first().map(Vec::len)
        )));
    }
    let (det, pitch) = (fan.n_det(), sys.detector.pitch_mm);
    let image_half_mm = fan.image.columns as f64 * fan.image.pixel_mm / 2.0;
    let image_top = sys.support_height_mm + fan.image.rows as f64 * fan.image.pixel_mm;
    // Each fan ray's source and direction, once (`[view * det + element]`).
    struct Ray {
        s: [f64; 3],
        dx: f64,
        dz: f64,
        t_ref: f64,
        crosses: bool,
    }
    let rays: Vec<Ray> = (0..views)
        .flat_map(|v| {
            let s = sys.source(v);
            (0..det).map(move |k| {
                // The fan element's centre (the virtual rotating detector).
                let u = (k as f64 - (det as f64 - 1.0) / 2.0) * fan.detector.pitch_mm;
                let p = sys.rotating_point(v, u, 0.0);
                let (dx, dz) = (p[0] - s[0], p[2] - s[2]);
                let t_ref = (z_ref_mm - s[2]) / dz;
                // Does this fan ray cross the image? (Else it sees air.)
                let x_at = |z: f64| s[0] + (z - s[2]) / dz * dx;
                let crosses = x_at(sys.support_height_mm).abs() < image_half_mm
                    || x_at(image_top).abs() < image_half_mm;
                Ray {
                    s,
                    dx,
                    dz,
                    t_ref,
                    crosses,
                }
            })
        })
        .collect();
    let mut out = vec![vec![0.0f32; views * det]; slices];
    let mut off_detector = vec![0usize; slices];
    // The slices on rayon's pool: each is written by one worker, with the
    // arithmetic of one slice at a time.
    out.par_iter_mut()
        .zip(off_detector.par_iter_mut())
        .enumerate()
        .try_for_each(|(c, (slice, off))| -> Result<(), RebinError> {
            let y_c = (c as f64 + 0.5) * slice_mm;
            for v in 0..views {
                for k in 0..det {
                    let Ray {
                        s,
                        dx,
                        dz,
                        t_ref,
                        crosses,
                    } = rays[v * det + k];
                    let dy = (y_c - s[1]) / t_ref;
                    // Where the ray meets the detector: the rotating one at
                    // the fan element (parameter 1), the stationary one at
                    // z = 0.
                    let (t_det, col) = match sys.detector_motion {
                        DetectorMotion::Rotating => (1.0, k as f64),
                        DetectorMotion::Stationary => {
                            let td = -s[2] / dz;
                            (td, (s[0] + td * dx) / pitch + (cols as f64 - 1.0) / 2.0)
                        }
                        // The detector turned by phi about the axis (0, h):
                        // its points (u cos phi - h sin phi, h - u sin phi
                        // - h cos phi) form the line x sin phi + z cos phi
                        // = h (cos phi - 1), which gives the ray's
                        // parameter; the column from u = x cos phi
                        // - (z - h) sin phi.
                        DetectorMotion::Tilting => {
                            let phi = sys.detector_angle_deg(v).to_radians();
                            let (sn, cs) = phi.sin_cos();
                            let h = sys.axis_height_mm;
                            let td = (h * cs - h - s[0] * sn - s[2] * cs) / (dx * sn + dz * cs);
                            let (x, z) = (s[0] + td * dx, s[2] + td * dz);
                            let u = x * cs - (z - h) * sn;
                            (td, u / pitch + (cols as f64 - 1.0) / 2.0)
                        }
                    };
                    let row = (s[1] + t_det * dy) / pitch - 0.5;
                    let (ri, ci) = (row.round(), col.round());
                    let idx = slice.get_mut(v * det + k).ok_or_else(|| {
                        RebinError::Shape("fan geometry larger than its sinogram".into())
                    })?;
                    let outside = ri < 0.0 || ri >= rows as f64 || ci < 0.0 || ci >= cols as f64;
                    if outside {
                        if !crosses {
                            // Air beside the image.
                            *idx = flux as f32;
                            continue;
                        }
                        // Through the image box but beyond the detector's
                        // edge (its corners at the widest angles): the edge
                        // element's count, and counted for the caller to
                        // judge.
                        *off += 1;
                    }
                    let (ri, ci) = (
                        ri.clamp(0.0, rows as f64 - 1.0),
                        ci.clamp(0.0, cols as f64 - 1.0),
                    );
                    let count = f64::from(frames[ri as usize][v * cols + ci as usize]);
                    // The obliquity of the ray that reached this element (its
                    // depth at the detector, not the ideal one's).
                    let dy = ((ri + 0.5) * pitch - s[1]) / t_det;
                    let obliquity =
                        (dx * dx + dy * dy + dz * dz).sqrt() / (dx * dx + dz * dz).sqrt();
                    // Only a count a breast can give (0 < c <= b) is
                    // corrected; any other (zero, negative, not a number,
                    // above the flat field, a saturated 65535) passes as
                    // read, for the counts check to name it.
                    *idx = if count > 0.0 && count <= flux {
                        (flux * (count / flux).powf(1.0 / obliquity)) as f32
                    } else {
                        count as f32
                    };
                }
            }
            Ok(())
        })?;
    Ok(Rebinned {
        counts: out,
        off_detector,
    })
}

/// Mean line integral below which a trailing rebinned slice is air (beyond
/// the nipple): a 1 mm skin-and-fat edge already gives about 0.04.
const AIR_MEAN_LINE_INTEGRAL: f64 = 0.005;

/// The slice-wise fan-beam acquisition of a cone-beam one: every coronal
/// slice the detector covers at mid-breast, `slice_spacing_mm` apart,
/// rebinned ([`rebin`]) at mid-breast height; trailing slices of air
/// (beyond the nipple) dropped. The fan geometry's image must rest on the
/// system's support (the breast sits there in both). The one bridge from
/// [`ConeFrames`] to [`SliceSinograms`].
pub fn slice_sinograms(frames: &ConeFrames) -> Result<SliceSinograms, RebinError> {
    let h = &frames.header;
    let sys = h.system();
    let fan = &h.geometry;
    check_site(sys, fan)?;
    if h.slices != sys.detector.rows || frames.counts.len() != sys.detector.rows {
        return Err(RebinError::Shape(format!(
            "header says {} rows, {} rows of counts, the detector has {}",
            h.slices,
            frames.counts.len(),
            sys.detector.rows
        )));
    }
    let z_ref = sys.support_height_mm + h.thickness_mm / 2.0;
    let z_s = sys.axis_height_mm + sys.arc_radius_mm;
    // The depth the detector covers at mid-breast (the rays converge
    // towards the source).
    let covered = sys.detector.rows as f64 * sys.detector.pitch_mm * (z_s - z_ref) / z_s;
    let n = (covered / h.slice_spacing_mm).floor() as usize;
    let out = rebin(
        sys,
        fan,
        &frames.counts,
        h.flux,
        n,
        h.slice_spacing_mm,
        z_ref,
    )?;
    let mut counts = out.counts;
    while counts.last().is_some_and(|s| {
        let mean = s
            .iter()
            .map(|&c| (h.flux / f64::from(c).max(0.5)).ln())
            .sum::<f64>()
            / s.len().max(1) as f64;
        mean < AIR_MEAN_LINE_INTEGRAL
    }) {
        counts.pop();
    }
    // The detector's far edge is met only by slices beyond the breast (air,
    // dropped above); a kept slice that needed it is worth a warning.
    let off: usize = out.off_detector.iter().take(counts.len()).sum();
    if off > 0 {
        tracing::warn!(
            rays = off,
            "rays through the image box beyond the detector's edge: edge counts used"
        );
    }
    let mut header: AcquisitionHeader = (**h).clone();
    header.slices = counts.len();
    let header = SliceHeader::try_from(header).map_err(|e| RebinError::Shape(e.to_string()))?;
    Ok(SliceSinograms { header, counts })
}
