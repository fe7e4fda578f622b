//! A cone-beam acquisition (issue #28) of a test phantom through the
//! firmware's processing: a clean one raises no flag (the frames' checks do
//! not mistake a real breast's counts for defects); a stuck detector
//! element is found in the frames, corrected and flagged; a dead detector
//! is refused naming it.

use dbt_forward::NoiseLevel;
use dbt_geometry::{ConeSystem, Geometry};
use dbt_phantom::{Population, PopulationKind};
use dbt_pipeline::{process, PipelineError, PipelineOptions};

fn acquisition() -> dbt_pipeline::acquisition::Acquisition {
    let g = Geometry::builtin("paper-tall").unwrap().binned(4).unwrap();
    let sys = ConeSystem::builtin("paper-cone")
        .unwrap()
        .binned(4)
        .unwrap();
    let vol = PopulationKind::Procedural
        .draw(&g, Population::TEST_SEED, 2)
        .generate()
        .unwrap();
    let a = host_sim::simulate_cone_acquisition(
        &vol,
        &g,
        &sys,
        NoiseLevel::Poisson(8),
        5,
        host_sim::Technique::default(),
        28.0,
        "CONE",
        "1.2.826.0.1.3680043.10.543.3",
    )
    .unwrap();
    dbt_pipeline::acquisition::Acquisition {
        header: a.header,
        counts: a.counts,
    }
}

fn opts() -> PipelineOptions {
    PipelineOptions {
        mltr_iterations: 20,
        dose_uncertainty: 0.3,
        ..Default::default()
    }
}

#[test]
fn cone_beam_frames_are_checked_before_the_rebinning() {
    let acq = acquisition();
    let sys = acq.header.system.clone().unwrap();
    let (cols, views) = (sys.detector.columns, sys.n_views());
    let clean = process(&acq, &opts()).unwrap();
    assert!(clean.flags.is_empty(), "{:?}", clean.flags);
    assert_eq!(
        clean.plausibility.counts.rays,
        sys.detector.rows * views * cols
    );
    // One element under the breast stuck at one value in every view.
    let mut stuck = acq.clone();
    let (r, c) = (60, cols / 2);
    for v in 0..views {
        stuck.counts[r][v * cols + c] = 4321.0;
    }
    let res = process(&stuck, &opts()).unwrap();
    let chk = &res.plausibility.counts;
    assert!(chk.stuck >= views && chk.corrected >= views, "{chk:?}");
    assert!(
        res.flags.iter().any(|f| f.contains("stuck")),
        "{:?}",
        res.flags
    );
    // A dead detector: every frame zero.
    let mut dead = acq;
    dead.counts.iter_mut().for_each(|r| r.fill(0.0));
    match process(&dead, &opts()) {
        Err(e @ PipelineError::Implausible(_)) => {
            assert!(e.to_string().contains("zero (dead)"), "{e}")
        }
        other => panic!(
            "a dead detector was not refused: {:?}",
            other.map(|r| r.glandularity)
        ),
    }
}

/// Continuous motion (issue #51 point 1): a system whose source travels
/// `source_blur_deg` during each exposure is simulated at three positions
/// across that arc, the midpoints of its thirds (mean angle the view's);
/// its noise-free counts are the flat field times the mean of the three
/// positions' transmissions, which differ from the step-and-shoot ones at
/// the breast's edges and nowhere by more than the three positions' own
/// spread.
#[test]
fn continuous_motion_is_the_mean_over_the_exposure_arc() {
    let g = Geometry::builtin("paper-tall").unwrap().binned(4).unwrap();
    let still = ConeSystem::builtin("paper-cone")
        .unwrap()
        .binned(4)
        .unwrap();
    let moving = ConeSystem {
        source_blur_deg: 1.5,
        ..still.clone()
    };
    let positions = host_sim::exposure_positions(&moving).unwrap();
    assert_eq!(
        host_sim::exposure_positions(&still).unwrap(),
        std::slice::from_ref(&still)
    );
    assert_eq!(positions.len(), 3);
    for v in [0, 12, 24] {
        let mean: f64 = positions.iter().map(|p| p.angle_deg(v)).sum::<f64>() / 3.0;
        assert!((mean - still.angle_deg(v)).abs() < 1e-12);
        assert!((positions[2].angle_deg(v) - positions[0].angle_deg(v) - 1.0).abs() < 1e-12);
    }
    let vol = PopulationKind::Procedural
        .draw(&g, Population::TEST_SEED, 2)
        .generate()
        .unwrap();
    let sim = |s: &ConeSystem| {
        host_sim::simulate_cone_acquisition(
            &vol,
            &g,
            s,
            NoiseLevel::NoiseFree,
            5,
            host_sim::Technique::default(),
            28.0,
            "CONE",
            "1.2.826.0.1.3680043.10.543.3",
        )
        .unwrap()
    };
    let blurred = sim(&moving);
    let each: Vec<_> = positions.iter().map(sim).collect();
    let b = blurred.header.flux;
    let (mut differ, mut n) = (0usize, 0usize);
    for (r, row) in blurred.counts.iter().enumerate() {
        for (i, &c) in row.iter().enumerate() {
            let ts: Vec<f64> = each.iter().map(|a| f64::from(a.counts[r][i]) / b).collect();
            let want = ts.iter().sum::<f64>() / 3.0;
            let got = f64::from(c) / b;
            assert!(
                (got - want).abs() < 1e-5,
                "row {r} ray {i}: {got} vs {want}"
            );
            let lo = ts.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = ts.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            assert!(got >= lo - 1e-5 && got <= hi + 1e-5);
            n += 1;
            if (f64::from(c) - f64::from(each[1].counts[r][i])).abs() > 1e-3 * b {
                differ += 1;
            }
        }
    }
    assert!(differ > 0 && differ < n / 2, "{differ} of {n} rays differ");
}
