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
