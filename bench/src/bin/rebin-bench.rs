//! What a cone-beam acquisition (issue #28) adds to the firmware's time per
//! coronal slice: the frames' counts check (`check_counts` on the detector
//! rows), the rebinning (`dbt_pipeline::rebin::rebin`) and the resampling
//! of the reconstructed stack (`resample_depth`), per slice, against the
//! DBToR slice they feed (the shipped model, measured in the same run, same
//! machine); goal at most 10 % (#28). Beside them, what a CsI detector's
//! beam-hardening linearisation of the same frames adds
//! (`dbt_pipeline::linearise`, #27: the table of the technique and the
//! map of every count) and its scatter removal (`dbt_pipeline::descatter`:
//! the kernel model's fixed point on 4 mm blocks and the subtraction);
//! goal at most 10 % for both (#27). Prints a table; writes
//! `bench/results/rebin.json`.
//!
//! `cargo run --release -p dbt-bench --bin rebin-bench -- [--model models/dbtor-x4t3]
//!  [--precision int8] [--reps 5]`
//!
//! The rebinning's cost does not depend on the counts' values, so the
//! frames are random counts of the right size (no cone-beam projection is
//! needed to time it).

use anyhow::{Context, Result};
use clap::Parser;
use dbt_bench::{at_least_one, median, median_ms};
use dbt_dbtor::{Dbtor, Engine, Precision};
use rand::{Rng, SeedableRng};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

/// Cone-beam rebinning per slice against a DBToR slice.
#[derive(Parser)]
#[command(name = "rebin-bench")]
struct Args {
    /// The DBToR model whose geometry and slice time set the scale.
    #[arg(long, default_value = "models/dbtor-x4t3qa")]
    model: PathBuf,
    /// Its precision (`fp32` or `int8`; the firmware ships int8 where the
    /// CPU has VNNI).
    #[arg(long, default_value = "int8")]
    precision: String,
    /// The cone-beam system (binned to the model's pixel).
    #[arg(long, default_value = "paper-cone")]
    system: String,
    /// Runs of each (the median is reported).
    #[arg(long, default_value_t = 5, value_parser = at_least_one)]
    reps: usize,
}

fn main() -> Result<()> {
    let a = Args::parse();
    let precision = match a.precision.as_str() {
        "fp32" => Precision::Fp32,
        "int8" => Precision::Int8,
        p => anyhow::bail!("--precision {p:?}: fp32 or int8"),
    };
    let d = Dbtor::load_with(&a.model, precision, Engine::Fast)
        .with_context(|| format!("loading {}", a.model.display()))?;
    let sys = dbt_store::load_system(&a.system, 1)?;
    // Detector elements as near the model's as binning makes them, and the
    // fan they are rebinned to (the model's blocks on its operator).
    let factor = (d.geometry().detector.pitch_mm / sys.detector.pitch_mm)
        .round()
        .max(1.0) as usize;
    let sys = sys.binned(factor)?;
    let fan = sys.rebinning_fan(d.geometry())?;
    let d = if &fan == d.geometry() {
        d
    } else {
        Dbtor::load_for_geometry(&a.model, precision, &[], Engine::Fast, &fan)?
    };
    let (rows, cols, views) = (sys.detector.rows, sys.detector.columns, sys.n_views());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let flux = 16_000.0;
    let frames: Vec<Vec<f32>> = (0..rows)
        .map(|_| {
            (0..views * cols)
                .map(|_| rng.random_range(1_000.0..16_000.0))
                .collect()
        })
        .collect();
    // As `rebin::slice_sinograms`: every slice the detector covers at mid-breast
    // of a 60 mm breast.
    let thickness = 60.0;
    let z_ref = sys.support_height_mm + thickness / 2.0;
    let z_s = sys.axis_height_mm + sys.arc_radius_mm;
    let slices =
        (rows as f64 * sys.detector.pitch_mm * (z_s - z_ref) / z_s / fan.image.pixel_mm) as usize;
    let rebin_ms = median_ms(1, a.reps, || {
        let _ = dbt_pipeline::rebin::rebin(
            &sys,
            &fan,
            &frames,
            flux,
            slices,
            fan.image.pixel_mm,
            z_ref,
        );
    });
    let per_slice_rebin = rebin_ms / slices as f64;
    // The frames' counts check, as `process` runs it on a cone-beam header.
    let header = dbt_pipeline::ConeHeader::new(
        dbt_pipeline::acquisition::AcquisitionHeader {
            thickness_mm: thickness,
            flux,
            slice_spacing_mm: fan.image.pixel_mm,
            ..dbt_pipeline::acquisition::example_header(fan.clone(), rows, None)
        },
        sys.clone(),
    );
    let check_ms = median_ms(1, a.reps, || {
        let _ = dbt_pipeline::plausibility::check_counts(&header, &frames);
    });
    // The resampling of the reconstructed stack (the rows a 60 mm breast
    // fills).
    let nz = fan.rows_within_thickness(thickness);
    let stack: Vec<f32> = (0..fan.image.columns * nz * slices)
        .map(|_| rng.random_range(0.04..0.09))
        .collect();
    let resample_ms = median_ms(1, a.reps, || {
        let _ = dbt_pipeline::rebin::resample_depth(
            &sys,
            thickness,
            fan.image.pixel_mm,
            &stack,
            [fan.image.columns, nz, slices],
        );
    });
    // The system's own detector (a-Se for siemens-victre): another is
    // refused before any work.
    let bh = dbt_pipeline::linearise::BeamHardening::for_converter(sys.converter())?;
    let linearise_ms = median_ms(1, a.reps, || {
        let mut f = frames.clone();
        let _ = bh.apply(&header, &mut f);
    });
    // The copy the timing needs, apart.
    let copy_ms = median_ms(1, a.reps, || {
        let _ = std::hint::black_box(frames.clone());
    });
    let linearise_ms = (linearise_ms - copy_ms).max(0.0);
    // The scatter removal of the same frames (#27: the kernel model on
    // 4 mm blocks, its fixed point, the subtraction from every count).
    let removal = dbt_pipeline::descatter::ScatterRemoval::shipped()?;
    let descatter_ms = median_ms(1, a.reps, || {
        let mut f = frames.clone();
        let _ = removal.apply(&header, &mut f);
    });
    let descatter_ms = (descatter_ms - copy_ms).max(0.0);
    // The noise matching of frames with an open field (a quarter of each
    // view's columns on either side at the flat field, its noise as a
    // photon count's): what it measures the detector's noise on.
    let open: Vec<Vec<f32>> = frames
        .iter()
        .map(|row| {
            row.iter()
                .enumerate()
                .map(|(i, &c)| {
                    let k = i % cols;
                    if k < cols / 4 || k >= 3 * cols / 4 {
                        (flux + flux.sqrt() * rng.random_range(-1.7..1.7)) as f32
                    } else {
                        c
                    }
                })
                .collect()
        })
        .collect();
    let matching = dbt_pipeline::noise_match::NoiseMatch::to_photons(flux)?;
    let mut open_lin = open.clone();
    bh.apply(&header, &mut open_lin)?;
    // Once checked: a refusal would time nothing.
    matching.apply(&header, &bh, &open, &open, &mut open_lin.clone())?;
    let match_ms = median_ms(1, a.reps, || {
        let mut f = open_lin.clone();
        let _ = matching.apply(&header, &bh, &open, &open, &mut f);
    });
    let match_ms = (match_ms - copy_ms).max(0.0);
    let all_ms = check_ms + rebin_ms + resample_ms;
    let per_slice_all = all_ms / slices as f64;
    // The DBToR slice, same machine, same run.
    let sino: Vec<f32> = (0..fan.n_rays())
        .map(|_| rng.random_range(0.5..4.0))
        .collect();
    let _ = d.reconstruct(&sino, thickness)?; // warm-up
    let mut times = Vec::new();
    for _ in 0..a.reps {
        let t = Instant::now();
        let _ = d.reconstruct(&sino, thickness)?;
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let slice_ms = median(times);
    let ratio = per_slice_all / slice_ms;
    let share = |ms: f64| 100.0 * ms / slices as f64 / slice_ms;
    println!("cpu: {}", dbt_cli::cpu_summary());
    println!(
        "system {} binned x{factor}: {rows} x {cols} detector, {views} views; fan {}; {slices} slices",
        sys.name,
        fan.describe()
    );
    println!("| what | median ms | per slice ms | share of the DBToR slice |");
    println!("|---|---|---|---|");
    for (what, ms) in [
        ("counts check of the frames", check_ms),
        ("rebin", rebin_ms),
        ("resample the stack", resample_ms),
    ] {
        println!(
            "| {what}, whole acquisition ({slices} slices) | {ms:.2} | {:.3} | {:.2} % |",
            ms / slices as f64,
            share(ms)
        );
    }
    println!(
        "| **all three** | {all_ms:.2} | {per_slice_all:.3} | **{:.2} %** |",
        100.0 * ratio
    );
    println!(
        "| beam-hardening linearisation (#27), whole acquisition | {linearise_ms:.2} | {:.3} | **{:.2} %** |",
        linearise_ms / slices as f64,
        share(linearise_ms)
    );
    println!(
        "| scatter removal (#27), whole acquisition | {descatter_ms:.2} | {:.3} | **{:.2} %** |",
        descatter_ms / slices as f64,
        share(descatter_ms)
    );
    println!(
        "| both corrections (#27) | {:.2} | {:.3} | **{:.2} %** |",
        descatter_ms + linearise_ms,
        (descatter_ms + linearise_ms) / slices as f64,
        share(descatter_ms + linearise_ms)
    );
    println!(
        "| noise matching (#27), whole acquisition | {match_ms:.2} | {:.3} | **{:.2} %** |",
        match_ms / slices as f64,
        share(match_ms)
    );
    let corrections = descatter_ms + linearise_ms + match_ms;
    println!(
        "| the three corrections (#27) | {corrections:.2} | {:.3} | **{:.2} %** |",
        corrections / slices as f64,
        share(corrections)
    );
    println!(
        "| DBToR slice ({}, {} engine) | {slice_ms:.1} | {slice_ms:.1} | 100 % |",
        a.precision,
        Engine::Fast
    );
    println!(
        "goal: at most 10 % -> {}",
        if ratio <= 0.10 { "met" } else { "missed" }
    );
    let out = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/results"));
    std::fs::create_dir_all(&out)?;
    std::fs::write(
        out.join("rebin.json"),
        serde_json::to_vec_pretty(&json!({
            "cpu": dbt_cli::cpu_summary(),
            "system": sys.name,
            "binning": factor,
            "slices": slices,
            "rebin_ms_median": rebin_ms,
            "rebin_ms_per_slice": per_slice_rebin,
            "check_ms_median": check_ms,
            "resample_ms_median": resample_ms,
            "linearise_ms_median": linearise_ms,
            "descatter_ms_median": descatter_ms,
            "all_ms_per_slice": per_slice_all,
            "dbtor_slice_ms_median": slice_ms,
            "precision": a.precision,
            "share": ratio,
            "reps": a.reps,
        }))?,
    )?;
    Ok(())
}
