//! The whole processing of one recorded acquisition (issue #30, "the
//! pipeline around the network"): `dbt_pipeline::process` on the firmware's
//! model, its stages timed (`ProcessResult::stage_seconds`: corrections
//! and cone-beam rebinning, every slice's reconstruction, classification,
//! the two Monte Carlo doses), in a pool of one thread (the peer, same run,
//! same machine) and in pools of more, with the speed-up and the parallel
//! efficiency of each stage; the process's peak resident memory. Prints a
//! table; writes `bench/results/pipeline.json`.
//!
//! `cargo run --release -p dbt-bench --bin pipeline-bench -- --acquisition DIR
//!  [--model models/dbtor-x4t3] [--precisions fp32,int8] [--threads 1,2] [--reps 3]
//!  [--descatter --csi-um 200] [--slice-step N] [--timing-only-on-acquisition-grid]`
//!
//! DIR is a recorded acquisition (`host-sim acquire --out DIR ...`; the main
//! job's is `out/main-job/gantry-acquisition`).

use anyhow::{Context, Result};
use clap::Parser;
use dbt_bench::{at_least_one, median};
use dbt_dbtor::{Dbtor, Engine, Precision};
use dbt_pipeline::{PipelineOptions, StageSeconds};
use serde_json::json;
use std::path::PathBuf;
use std::sync::Arc;

/// The processing of one acquisition, stage by stage, in pools of threads.
#[derive(Parser)]
#[command(name = "pipeline-bench")]
struct Args {
    /// A recorded acquisition (`acquisition.json` + `counts.f32`).
    #[arg(long)]
    acquisition: PathBuf,
    /// The DBToR model folder (the shipped configuration's).
    #[arg(long, default_value = "models/dbtor-x4t3qa")]
    model: PathBuf,
    /// Precisions, comma separated (`fp32`, `int8`).
    #[arg(long, default_value = "fp32,int8")]
    precisions: String,
    /// Pool sizes, comma separated; the first is the peer of the others.
    #[arg(long, default_value = "1,2")]
    threads: String,
    /// Runs of each (the median of each stage is reported).
    #[arg(long, default_value_t = 3, value_parser = at_least_one)]
    reps: usize,
    /// The corrections of a clinical acquisition (as `dbtor-process`'s).
    #[command(flatten)]
    corrections: dbt_cli::CorrectionArgs,
    /// Reconstruct every Nth coronal slice, those between interpolated
    /// (`dbtor-process --slice-step`).
    #[arg(long, default_value_t = 1, value_parser = at_least_one)]
    slice_step: usize,
    /// Run the model's weights on the acquisition's grid when it is not the
    /// model's (e.g. a 0.2 mm acquisition with a model trained at 0.8 mm):
    /// TIMING ONLY, the network reconstructs nonsense on a pixel size it
    /// was not trained for, so the figures printed are not results. Issue
    /// #30's 0.2 mm acquisition before a full-resolution model exists.
    #[arg(long)]
    timing_only_on_acquisition_grid: bool,
}

const STAGES: [&str; 6] = [
    "corrections",
    "reconstruction",
    "classification",
    "dose, patient",
    "dose, model breast",
    "all",
];

fn stage_values(s: &StageSeconds) -> [f64; 6] {
    [
        s.corrections,
        s.reconstruction,
        s.classification,
        s.dose_patient,
        s.dose_model,
        s.total(),
    ]
}

fn list<T: std::str::FromStr>(s: &str, what: &str) -> Result<Vec<T>>
where
    T::Err: std::fmt::Display,
{
    s.split(',')
        .map(|x| {
            x.trim()
                .parse::<T>()
                .map_err(|e| anyhow::anyhow!("{what} {x:?}: {e}"))
        })
        .collect()
}

fn main() -> Result<()> {
    let a = Args::parse();
    let threads: Vec<usize> = list(&a.threads, "--threads")?;
    if threads.contains(&0) {
        anyhow::bail!("--threads: every pool needs at least one thread");
    }
    let acq = dbt_store::acquisition::read_acquisition(&a.acquisition)
        .with_context(|| format!("reading {}", a.acquisition.display()))?;
    let base = PipelineOptions {
        linearise: a.corrections.linearise().context("--csi-um / --a-se-um")?,
        descatter: a.corrections.descatter()?,
        slice_step: a.slice_step,
        ..PipelineOptions::default()
    };
    let cpu = dbt_cli::cpu_summary();
    println!("cpu: {cpu}");
    println!(
        "acquisition {}: {}, thickness {:.1} mm",
        a.acquisition.display(),
        match &acq.header.system {
            Some(s) => format!(
                "cone-beam {}, {} detector rows (rebinned to slices)",
                s.name, acq.header.slices
            ),
            None => format!("fan-beam, {} slices", acq.header.slices),
        },
        acq.header.thickness_mm,
    );
    let mut rows = Vec::new();
    for p in a.precisions.split(',') {
        let precision = match p.trim() {
            "fp32" => Precision::Fp32,
            "int8" => Precision::Int8,
            p => anyhow::bail!("--precisions {p:?}: fp32 or int8"),
        };
        let m = if a.timing_only_on_acquisition_grid {
            Dbtor::load_for_geometry_up_to(
                &a.model,
                precision,
                &[],
                Engine::Fast,
                &acq.header.geometry,
                dbt_dbtor::kernel_limit()?,
            )
        } else {
            Dbtor::load_with(&a.model, precision, Engine::Fast)
        }
        .with_context(|| format!("loading {}", a.model.display()))?;
        if a.timing_only_on_acquisition_grid {
            println!(
                "TIMING ONLY: {}'s weights on the acquisition's grid ({}); the figures below are not results",
                a.model.display(),
                acq.header.geometry.describe()
            );
        }
        println!(
            "model {} {precision}: convolutions {}, projector {}",
            a.model.display(),
            m.kernel().unwrap_or("tract"),
            m.projector_kernel().name()
        );
        // The model as the daemon assembles it (its calibrations and report
        // intervals: a density the physics does not confirm costs a third
        // Monte Carlo run).
        let noise_matched = a.corrections.noise_match;
        let settings = dbt_model::load_settings(
            &m,
            &base.classify,
            dbt_model::InputCorrections::of(&base, noise_matched),
        )?;
        let base = base.clone().with_model(
            Arc::new(m),
            settings,
            noise_matched.then_some("--noise-match"),
        )?;
        let mut medians = Vec::new();
        for &t in &threads {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(t).build()?;
            let mut runs: Vec<[f64; 6]> = Vec::new();
            let mut figures = None;
            let mut slices = 0;
            // One untimed run first (buffers, page faults, the pool).
            for rep in 0..=a.reps {
                let r = pool.install(|| dbt_pipeline::process(&acq, &base))?;
                if rep > 0 {
                    runs.push(stage_values(&r.stage_seconds));
                }
                slices = r.stage_seconds.slices;
                let f = (r.glandularity, r.mgd_mgy);
                // The figures must not depend on the pool.
                if let Some(prev) = figures.replace(f) {
                    anyhow::ensure!(prev == f, "{t} threads: figures changed between runs");
                }
            }
            let med: Vec<f64> = (0..6)
                .map(|k| median(runs.iter().map(|r| r[k]).collect()))
                .collect();
            medians.push((t, med, figures, slices));
        }
        let (t0, peer, peer_figures, slices) = medians[0].clone();
        let slices = slices.max(1) as f64;
        println!(
            "| {p} | threads | {} | speed-up of all against {t0} thread(s) | efficiency |",
            STAGES.join(" s | ") + " s"
        );
        println!("|---|---|{}---|---|", "---|".repeat(STAGES.len()));
        for (t, med, figures, _) in &medians {
            anyhow::ensure!(
                *figures == peer_figures,
                "{t} threads report other figures than {t0}: {figures:?} against {peer_figures:?}"
            );
            let speedup = peer[5] / med[5];
            let efficiency = speedup * t0 as f64 / *t as f64;
            println!(
                "| {p} | {t} | {} | {speedup:.2}x | {:.0} % |",
                med.iter()
                    .map(|s| format!("{s:.3}"))
                    .collect::<Vec<_>>()
                    .join(" | "),
                100.0 * efficiency
            );
            let per_stage: serde_json::Map<String, serde_json::Value> = STAGES
                .iter()
                .zip(med)
                .map(|(k, v)| (k.to_string(), json!(v)))
                .collect();
            rows.push(json!({
                "precision": p,
                "threads": t,
                "median_s": per_stage,
                "speedup_vs_peer": speedup,
                "efficiency": efficiency,
                "glandularity": figures.map(|f| f.0),
                "mgd_mgy": figures.map(|f| f.1),
            }));
        }
        println!(
            "{p}: reconstruction per slice ({slices} slices) {:.1} ms ({t0} thread(s)) -> {}",
            1e3 * peer[1] / slices,
            medians[1..]
                .iter()
                .map(|(t, m, _, _)| format!("{:.1} ms ({t} threads)", 1e3 * m[1] / slices))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    let rss = dbt_cli::peak_rss_mib();
    println!(
        "peak resident memory of this process (every run above): {}",
        rss.map_or("not reported".into(), |m| format!("{m:.0} MiB"))
    );
    let out = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/results"));
    std::fs::create_dir_all(&out)?;
    std::fs::write(
        out.join("pipeline.json"),
        serde_json::to_vec_pretty(&json!({
            "cpu": cpu,
            "acquisition": a.acquisition.display().to_string(),
            "detector_rows_or_slices": acq.header.slices,
            "model": a.model.display().to_string(),
            "reps": a.reps,
            "rows": rows,
            "peak_rss_mib": rss,
        }))?,
    )?;
    Ok(())
}
