//! Cone-beam rebinning (issue #28) against physics: exact for a breast
//! uniform in depth on the rotating system; within the nearest-element
//! bound on the stationary one; and a depth step blurred over no more than
//! the stated depth range.

use dbt_cone::{ConeProjector, VolumeGrid};
use dbt_geometry::{ConeSystem, Geometry};
use dbt_pipeline::rebin::{depth_blur_mm, rebin};
use rand::{Rng, SeedableRng};

const FLUX: f64 = 1e6;

/// The paper's 200 x 60 mm image at 1.6 mm, on the axis.
const IMG: (usize, usize, f64) = (125, 37, 1.6);

fn paper() -> (ConeSystem, Geometry) {
    let sys = on_axis("paper-cone", 8);
    let fan = sys.central_fan(IMG.0, IMG.1, IMG.2).unwrap();
    (sys, fan)
}

/// The built-in system `name` binned `bin` times, its support lowered so
/// that the image's middle is on the rotation axis.
fn on_axis(name: &str, bin: usize) -> ConeSystem {
    let sys = ConeSystem::builtin(name).unwrap().binned(bin).unwrap();
    ConeSystem {
        support_height_mm: sys.axis_height_mm - IMG.1 as f64 * IMG.2 / 2.0,
        ..sys
    }
}

/// The stationary-detector system binned x4, the image on its axis, and
/// its virtual rotating detector of the paper's 1.6 mm elements.
fn victre() -> (ConeSystem, Geometry) {
    let sys = on_axis("siemens-victre", 4);
    let fan = Geometry {
        source_to_center_mm: sys.arc_radius_mm,
        source_to_detector_mm: sys.arc_radius_mm + sys.axis_height_mm,
        views: sys.views.clone(),
        detector: dbt_geometry::Detector {
            elements: 170,
            pitch_mm: 1.6,
        },
        image: dbt_geometry::Image {
            columns: IMG.0,
            rows: IMG.1,
            pixel_mm: IMG.2,
            centre_z_mm: 0.0,
        },
    };
    fan.validate().unwrap();
    (sys, fan)
}

/// A volume whose every coronal slice is `img` (row 0 at the top) where
/// `keep(depth_mm)`, air elsewhere.
fn volume(img: &[f32], depth: usize, keep: impl Fn(f64) -> bool) -> (VolumeGrid, Vec<f32>) {
    let grid = VolumeGrid {
        lateral: IMG.0,
        vertical: IMG.1,
        depth,
        voxel_mm: IMG.2,
    };
    let mut vol = vec![0.0f32; grid.len()];
    for d in 0..depth {
        if !keep((d as f64 + 0.5) * IMG.2) {
            continue;
        }
        for v in 0..IMG.1 {
            for l in 0..IMG.0 {
                vol[grid.index(l, v, d)] = img[(IMG.1 - 1 - v) * IMG.0 + l];
            }
        }
    }
    (grid, vol)
}

/// Noise-free counts of `vol`, as frames `[row][view * columns + column]`.
fn frames(sys: &ConeSystem, grid: VolumeGrid, vol: &[f32]) -> Vec<Vec<f32>> {
    let a = ConeProjector::new(sys, grid).unwrap();
    let p = a.forward(vol).unwrap();
    let (rows, cols) = (sys.detector.rows, sys.detector.columns);
    (0..rows)
        .map(|r| {
            (0..sys.n_views())
                .flat_map(|v| {
                    let at = (v * rows + r) * cols;
                    p[at..at + cols]
                        .iter()
                        .map(|x| (FLUX * (-f64::from(*x)).exp()) as f32)
                        .collect::<Vec<_>>()
                })
                .collect()
        })
        .collect()
}

fn fan_sinogram(fan: &Geometry, img: &[f32]) -> Vec<f32> {
    let mut sino = vec![0.0f32; fan.n_rays()];
    dbt_projector::Projector::new(fan)
        .forward(img, &mut sino)
        .unwrap();
    sino
}

fn line_integrals(counts: &[f32]) -> Vec<f64> {
    counts
        .iter()
        .map(|c| -(f64::from(*c) / FLUX).ln())
        .collect()
}

/// Rotating detector, a breast uniform in depth: every rebinned slice's
/// sinogram is the fan-beam sinogram of the slice (to 5e-5 of the largest
/// line integral: f32 counts and the 2-D projector's f32 per-ray
/// parameters, about 3e-5 relative on a ray of 40 pixels).
#[test]
fn depth_uniform_breast_rebins_to_the_fan_sinogram() {
    let (sys, fan) = paper();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let img: Vec<f32> = (0..IMG.0 * IMG.1)
        .map(|_| rng.random_range(0.0..0.08))
        .collect();
    let (grid, vol) = volume(&img, 100, |_| true);
    let f = frames(&sys, grid, &vol);
    let z_ref = sys.support_height_mm + 30.0;
    let slices = 60;
    let out = rebin(&sys, &fan, &f, FLUX, slices, IMG.2, z_ref)
        .unwrap()
        .counts;
    let want = fan_sinogram(&fan, &img);
    let largest = want.iter().fold(0.0f32, |a, b| a.max(*b)) as f64;
    for (c, s) in out.iter().enumerate() {
        let got = line_integrals(s);
        let (wi, worst) = got
            .iter()
            .zip(&want)
            .map(|(g, w)| (g - f64::from(*w)).abs())
            .enumerate()
            .fold((0, 0.0), |a, (i, e)| if e > a.1 { (i, e) } else { a });
        let at = (wi / fan.n_det(), wi % fan.n_det());
        assert!(
            worst < 5e-5 * largest,
            "slice {c}: {worst:e} of {largest} at (view, element) {at:?}"
        );
    }
}

/// Stationary and tilting detectors, a breast uniform in depth: the
/// rebinned sinograms differ from the fan-beam ones only by the
/// nearest-element position error (half a physical element, 0.17 mm here,
/// magnified at most 1.22 at the widest views: less than one fan element),
/// so every rebinned value lies within the fan sinogram's values at its
/// neighbouring elements. The tilting detector is the same system's turned
/// by 0.28 x the source angle (Hologic's factor): where its rays meet it is
/// found here from two of its elements' positions, not from the
/// rebinning's formula.
#[test]
fn fixed_and_tilting_detectors_rebin_within_the_nearest_element_bound() {
    let (fixed, fan) = victre();
    let tilting = ConeSystem {
        detector_motion: dbt_geometry::DetectorMotion::Tilting,
        detector_tilt_factor: Some(0.28),
        ..fixed.clone()
    };
    tilting.validate().unwrap();
    for sys in [fixed, tilting] {
        within_the_nearest_element_bound(&sys, &fan);
    }
}

/// Where the line from `s` through `p` (in the x-z plane) meets the
/// detector at view `v`, mm from the detector's centre line along it: the
/// detector's line through two of its elements.
fn on_detector(sys: &ConeSystem, v: usize, s: [f64; 3], p: [f64; 3]) -> f64 {
    let c = sys.detector.columns;
    let (a, b) = (sys.element(v, 0, 0), sys.element(v, 0, c - 1));
    let (ex, ez) = (b[0] - a[0], b[2] - a[2]);
    let (dx, dz) = (p[0] - s[0], p[2] - s[2]);
    // s + t d = a + w e, solved for w (Cramer's rule).
    let det = dx * (-ez) - dz * (-ex);
    let w = ((a[0] - s[0]) * (-ez) - (a[2] - s[2]) * (-ex)) / det;
    let len = (ex * ex + ez * ez).sqrt();
    (w - 0.5) * len
}

fn within_the_nearest_element_bound(sys: &ConeSystem, fan: &Geometry) {
    let sys = sys.clone();
    // A smooth breast: a Gaussian blob across, 40 mm wide.
    let img: Vec<f32> = (0..IMG.0 * IMG.1)
        .map(|i| {
            let x = ((i % IMG.0) as f64 - IMG.0 as f64 / 2.0) * IMG.2;
            (0.05 * (-(x / 40.0).powi(2)).exp()) as f32
        })
        .collect();
    let (grid, vol) = volume(&img, 80, |_| true);
    let f = frames(&sys, grid, &vol);
    let rebinned = rebin(&sys, fan, &f, FLUX, 40, IMG.2, sys.support_height_mm + 30.0).unwrap();
    let out = rebinned.counts;
    // The fan rays that meet the detector plane beyond its edge (through
    // the image box's top corners at the widest angles) get the edge
    // element's count: counted by rebin, not held to the bound.
    let beyond = |v: usize, k: usize| {
        let s = sys.source(v);
        let u = (k as f64 - (fan.n_det() as f64 - 1.0) / 2.0) * fan.detector.pitch_mm;
        let p = sys.rotating_point(v, u, 0.0);
        on_detector(&sys, v, s, p).abs()
            > sys.detector.columns as f64 * sys.detector.pitch_mm / 2.0 - sys.detector.pitch_mm
    };
    let skipped = (0..fan.n_views())
        .flat_map(|v| (0..fan.n_det()).map(move |k| (v, k)))
        .filter(|&(v, k)| beyond(v, k))
        .count();
    assert!(rebinned.off_detector.iter().all(|&n| n <= skipped));
    let want = fan_sinogram(fan, &img);
    let det = fan.n_det();
    for (c, s) in out.iter().enumerate() {
        let got = line_integrals(s);
        for v in 0..fan.n_views() {
            for k in 1..det - 1 {
                if beyond(v, k) {
                    continue;
                }
                let i = v * det + k;
                // The nearest element is less than a fan element away: the
                // rebinned value lies within the fan's values at the
                // neighbouring elements, give or take the 2-D projector's
                // f32 rounding (5e-5 relative, as on the rotating system)
                // and 1e-4 for the counts' f32.
                let near = [want[i - 1], want[i], want[i + 1]].map(f64::from);
                let margin = 1e-4 + 5e-5 * near[1];
                let (lo, hi) = (
                    near.iter().copied().fold(f64::INFINITY, f64::min) - margin,
                    near.iter().copied().fold(f64::NEG_INFINITY, f64::max) + margin,
                );
                assert!(
                    (lo..=hi).contains(&got[i]),
                    "{:?}: slice {c} view {v} element {k}: {} outside [{lo}, {hi}]",
                    sys.detector_motion,
                    got[i]
                );
            }
        }
    }
}

/// A breast that ends at 80 mm from the chest wall (uniform before, air
/// after): slices farther than the stated depth blur from the step are
/// exact (all tissue, or none); the ones within it are partial. The blur
/// is real (some slice is partial) and no wider than stated.
#[test]
fn a_depth_step_is_blurred_no_more_than_stated() {
    let (sys, fan) = paper();
    let img = vec![0.02f32; IMG.0 * IMG.1];
    let step = 80.0;
    let (grid, vol) = volume(&img, 100, |y| y < step);
    let f = frames(&sys, grid, &vol);
    let thickness = IMG.1 as f64 * IMG.2;
    let z_ref = sys.support_height_mm + thickness / 2.0;
    let slices = 90;
    let out = rebin(&sys, &fan, &f, FLUX, slices, IMG.2, z_ref)
        .unwrap()
        .counts;
    let full = fan_sinogram(&fan, &img);
    let centre = |v: usize| v * fan.n_det() + fan.n_det() / 2;
    let mut partial = 0;
    for (c, s) in out.iter().enumerate() {
        let y = (c as f64 + 0.5) * IMG.2;
        let blur = depth_blur_mm(&sys, y, thickness) + IMG.2;
        let got = line_integrals(s);
        for v in 0..fan.n_views() {
            let frac = got[centre(v)] / f64::from(full[centre(v)]);
            if y < step - blur {
                assert!(
                    (frac - 1.0).abs() < 1e-4,
                    "slice {c} ({y} mm) view {v}: {frac}"
                );
            } else if y > step + blur {
                assert!(frac.abs() < 1e-4, "slice {c} ({y} mm) view {v}: {frac}");
            } else if frac > 0.01 && frac < 0.99 {
                partial += 1;
            }
        }
    }
    assert!(partial > 0, "no slice saw the step blurred");
}

/// Impossible counts pass the rebinning as read, for the counts check to
/// name them: at the N8 flat field (16000), a view of saturated elements
/// (65535), one of dead ones (0), one not a number, one above the flat
/// field.
#[test]
fn impossible_counts_pass_unchanged() {
    let (sys, fan) = paper();
    let img = vec![0.02f32; IMG.0 * IMG.1];
    let (grid, vol) = volume(&img, 100, |_| true);
    let mut f = frames(&sys, grid, &vol);
    let cols = sys.detector.columns;
    let flux = 16_000.0;
    let bad = [65535.0f32, 0.0, f32::NAN, 20_000.0];
    for row in f.iter_mut() {
        for (v, b) in bad.iter().enumerate() {
            row[v * cols..(v + 1) * cols].fill(*b);
        }
    }
    let out = rebin(
        &sys,
        &fan,
        &f,
        flux,
        60,
        IMG.2,
        sys.support_height_mm + 30.0,
    )
    .unwrap()
    .counts;
    let det = fan.n_det();
    for s in &out {
        for (v, b) in bad.iter().enumerate() {
            for c in &s[v * det..(v + 1) * det] {
                assert!(
                    // (or the flat field: a ray beside the image, air)
                    c.to_bits() == b.to_bits() || *c == flux as f32,
                    "view {v}: {c} for {b}"
                );
            }
        }
    }
}

/// The rebinned stack is the breast sheared in depth (what
/// `resample_depth` undoes): the central view's central ray of slice `c`
/// crosses depth `y k(z)` at height `z`, `k(z) = (z_s - z) / (z_s - z_ref)`,
/// where `y` is its depth at `z_ref`: `y_c`, or rather the depth of the
/// nearest detector row's ray there. Through a step at depth 80 mm its
/// obliquity-corrected line integral is the attenuation times the heights
/// where `y k(z) < 80` (exact: the step lies on voxel faces).
#[test]
fn the_rebinned_stack_is_the_breast_sheared_in_depth() {
    let (sys, fan) = paper();
    let mu = 0.02f32;
    let img = vec![mu; IMG.0 * IMG.1];
    let step = 80.0;
    let (grid, vol) = volume(&img, 100, |y| y < step);
    let f = frames(&sys, grid, &vol);
    let thickness = IMG.1 as f64 * IMG.2;
    let (bottom, top) = (sys.support_height_mm, sys.support_height_mm + thickness);
    let z_ref = bottom + thickness / 2.0;
    let out = rebin(&sys, &fan, &f, FLUX, 90, IMG.2, z_ref)
        .unwrap()
        .counts;
    let v = fan.n_views() / 2;
    let z_s = sys.source(v)[2];
    let centre = v * fan.n_det() + fan.n_det() / 2;
    let mut sheared = 0;
    let pitch = sys.detector.pitch_mm;
    for (c, s) in out.iter().enumerate() {
        let y_c = (c as f64 + 0.5) * IMG.2;
        // The nearest detector row to the ideal ray's, and its ray's depth
        // at z_ref.
        let row = (y_c * z_s / (z_s - z_ref) / pitch - 0.5).round();
        let y = (row + 0.5) * pitch * (z_s - z_ref) / z_s;
        assert!((y - y_c).abs() <= pitch / 2.0);
        // y k(z) < step  <=>  z > z_s - step (z_s - z_ref) / y.
        let z_cut = (z_s - step * (z_s - z_ref) / y).clamp(bottom, top);
        let want = f64::from(mu) * (top - z_cut);
        let got = line_integrals(s)[centre];
        // The central element's ray passes 0.4 mm beside the axis (even
        // element count): its x-z length differs by (0.4 / 700)^2.
        assert!(
            (got - want).abs() < 1e-4,
            "slice {c} ({y_c} mm): {got} vs {want}"
        );
        if want > 1e-6 && (want - f64::from(mu) * thickness).abs() > 1e-6 {
            sheared += 1;
        }
    }
    assert!(sheared > 3, "no slice crossed the step obliquely");
}

/// `resample_depth` undoes the shear: a stack holding a step at depth
/// `Y / k(z)` in row `z` (partial volumes in the slice it falls in: the
/// rebinned reconstruction of a breast ending at depth `Y` at every
/// height) becomes the step at `Y` in every row, to a tenth of a slice
/// (linear interpolation of the edge's partial volume).
#[test]
fn resampling_undoes_the_shear() {
    use dbt_pipeline::rebin::resample_depth;
    let (sys, _) = paper();
    let px = IMG.2;
    let (nx, nz, nd) = (3, IMG.1, 80);
    let thickness = nz as f64 * px;
    let z_ref = sys.support_height_mm + thickness / 2.0;
    let z_s = (0..sys.n_views()).map(|v| sys.source(v)[2]).sum::<f64>() / sys.n_views() as f64;
    let k = |r: usize| {
        let z = sys.support_height_mm + (r as f64 + 0.5) * px;
        (z_s - z) / (z_s - z_ref)
    };
    let step = 100.0;
    let mut mu = vec![0.0f32; nx * nz * nd];
    for d in 0..nd {
        for r in 0..nz {
            let fill = ((step / k(r) - d as f64 * px) / px).clamp(0.0, 1.0);
            for x in 0..nx {
                mu[(d * nz + r) * nx + x] = fill as f32;
            }
        }
    }
    let (out, dims) = resample_depth(&sys, thickness, px, &mu, [nx, nz, nd]);
    assert_eq!(dims[..2], [nx, nz]);
    assert!(dims[2] >= nd);
    let edge = |vol: &[f32], r: usize, n: usize| {
        (0..n)
            .map(|d| f64::from(vol[(d * nz + r) * nx + 1]) * px)
            .sum::<f64>()
    };
    let spread = |vol: &[f32], n: usize| {
        let e: Vec<f64> = (0..nz).map(|r| edge(vol, r, n)).collect();
        e.iter().cloned().fold(f64::MIN, f64::max) - e.iter().cloned().fold(f64::MAX, f64::min)
    };
    // Before: the step's depth changes with the height by the shear.
    assert!(spread(&mu, nd) > 5.0, "{}", spread(&mu, nd));
    // After: at the same depth in every row.
    for r in 0..nz {
        let e = edge(&out, r, dims[2]);
        assert!((e - step).abs() <= 0.1 * px, "row {r}: step at {e} mm");
    }
}

/// The slices are rebinned on rayon's pool; the counts and the rays counted
/// beyond the detector's edge do not depend on its threads (both systems,
/// a breast varying in depth).
#[test]
fn rebinning_does_not_depend_on_the_threads() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    let img: Vec<f32> = (0..IMG.0 * IMG.1)
        .map(|_| rng.random_range(0.0..0.08))
        .collect();
    let (grid, vol) = volume(&img, 60, |d| d < 50.0);
    for (sys, fan) in [paper(), victre()] {
        let f = frames(&sys, grid, &vol);
        let z_ref = sys.support_height_mm + 30.0;
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| rebin(&sys, &fan, &f, FLUX, 40, IMG.2, z_ref))
        };
        let one = run(1);
        for t in [2, 3] {
            match (&one, run(t)) {
                (Ok(a), Ok(b)) => {
                    assert_eq!(a.counts, b.counts, "{}: {t} threads", sys.name);
                    assert_eq!(a.off_detector, b.off_detector, "{}: {t} threads", sys.name);
                }
                (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string()),
                (a, b) => panic!("{}: {a:?} against {b:?}", sys.name),
            }
        }
    }
}
