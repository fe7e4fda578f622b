//! `dbtor-process`: process one recorded acquisition (offline mode of the
//! firmware): reconstruct, classify, density, Monte Carlo MGD, and deliver the
//! DICOM reports to the output folder (and the PACS, if given). Prints a JSON
//! summary. The daemon of issue #8 runs the same pipeline on acquisitions
//! received from the gantry.
//!
//! `dbtor-process ACQ_DIR --out DIR [--pacs AET@host:port] [--uid-root ROOT]
//!   [--model models/dbtor-x4t3 [--model-digest sha256:...] [--precision fp32|int8 [--fp32-blocks primal08,primal09]]] [--iterations N]
//!   [--dose-uncertainty 0.01]`
//!
//! With `--model`, slices are reconstructed by DBToR; the model folder is
//! checked against its sign-off first (and against `--model-digest
//! sha256:...`, the configuration's `recon.model_digest`, when given), then
//! the network's checksums. Without it, by MLTR (`--iterations`, default
//! 100). With `--physics-only` (a gantry without a trained model), nothing
//! is reconstructed: the physics-based density is reported and the model
//! breast's MGD, each report naming the method. The reports' content date
//! and time are the clock's (UTC).

use anyhow::{Context, Result};
use clap::Parser;
use dbt_dicom::{Equipment, UidSource};
use dbt_pipeline::{reports, PipelineOptions};
use dbtor_firmware::cli::error_chain;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "dbtor-process",
    about = "Process one recorded acquisition into the dose and density DICOM reports",
    after_help = "Exit codes: 0 reported; 2 bad usage, refused input (named) or a processing error."
)]
struct Cli {
    /// The recorded acquisition (acquisition.json + counts.f32).
    acquisition: PathBuf,
    /// Output folder of the reports (and its outbox).
    #[arg(long)]
    out: PathBuf,
    /// Also send the reports to this PACS, AET@host:port.
    #[arg(long)]
    pacs: Option<String>,
    #[arg(long, default_value = "1.2.826.0.1.3680043.10.543.1")]
    uid_root: String,
    #[command(flatten)]
    model: dbt_cli::ModelArgs,
    /// The model folder's configured digest (`recon.model_digest`).
    #[arg(long, requires = "model")]
    model_digest: Option<String>,
    /// With int8: blocks kept in fp32, e.g. `primal08,primal09`.
    #[arg(long, requires = "model")]
    fp32_blocks: Option<String>,
    /// MLTR iterations.
    #[arg(long, default_value_t = 100)]
    iterations: usize,
    /// Relative statistical uncertainty the Monte Carlo dose runs to.
    #[arg(long, default_value_t = 0.01)]
    dose_uncertainty: f64,
    #[command(flatten)]
    corrections: dbt_cli::CorrectionArgs,
    /// Reconstruct every Nth coronal slice (and the last), those between
    /// interpolated in depth (the daemon's `recon.slice_step`; 1 to 8).
    #[arg(long, default_value_t = 1, value_parser = slice_step)]
    slice_step: usize,
    /// No reconstruction (a gantry without a trained model, issue #51): the
    /// physics-based density is the glandularity and the MGD the model
    /// breast's on the gantry's geometry (the daemon's `reconstructor =
    /// "physics"`).
    #[arg(long, conflicts_with_all = ["model", "iterations", "slice_step"])]
    physics_only: bool,
    /// An acquisition whose beam the model has no glandularity calibration
    /// for: `physics` reports it physics-only, `refuse` refuses it naming
    /// the beam (the daemon's `recon.uncalibrated_beam`).
    #[arg(long, value_enum, default_value = "physics")]
    uncalibrated_beam: dbtor_firmware::config::UncalibratedBeamMode,
}

/// A slice step the firmware takes (`dbtor_firmware::config::SLICE_STEPS`).
fn slice_step(s: &str) -> Result<usize, String> {
    let steps = dbtor_firmware::config::SLICE_STEPS;
    match s.parse::<usize>() {
        Ok(n) if steps.contains(&n) => Ok(n),
        _ => Err(format!(
            "{s:?}: a whole number of slices from {} to {}",
            steps.start(),
            steps.end()
        )),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()),
        )
        .with_writer(dbt_cli::log_writer)
        .init();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("dbtor-process: error: {}", error_chain(&e));
            ExitCode::from(2)
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    let pacs = cli
        .pacs
        .as_deref()
        .map(dbt_pacs::PacsConfig::parse)
        .transpose()?;
    let (acq_dir, out, uid_root) = (cli.acquisition, cli.out, cli.uid_root);
    let mut opts = PipelineOptions {
        mltr_iterations: cli.iterations,
        dose_uncertainty: cli.dose_uncertainty,
        linearise: cli
            .corrections
            .linearise()
            .context("--csi-um / --a-se-um")?,
        descatter: cli.corrections.descatter()?,
        slice_step: cli.slice_step,
        method: if cli.physics_only {
            dbt_dicom::ReportMethod::PhysicsOnly
        } else {
            dbt_dicom::ReportMethod::Reconstruction
        },
        uncalibrated_beam: cli.uncalibrated_beam.pipeline(),
        ..PipelineOptions::default()
    };
    let dbt_cli::ModelArgs {
        model,
        precision,
        engine,
    } = cli.model;
    anyhow::ensure!(
        !cli.corrections.noise_match || model.is_some(),
        "--noise-match matches the counts to a DBToR model's training noise: give --model"
    );
    if let Some(dir) = &model {
        let fp32_blocks = cli
            .fp32_blocks
            .as_deref()
            .map(dbt_dbtor::parse_block_list)
            .unwrap_or_default();
        if !fp32_blocks.is_empty() && precision != dbt_dbtor::Precision::Int8 {
            anyhow::bail!("--fp32-blocks needs --precision int8");
        }
        let signed = dbt_model::load_signed(
            dir,
            precision,
            &fp32_blocks,
            engine,
            &opts.classify,
            dbt_model::InputCorrections::of(&opts, cli.corrections.noise_match),
            cli.model_digest.as_deref(),
        )
        .with_context(|| format!("loading the DBToR model {}", dir.display()))?;
        opts = dbtor_firmware::assembly::with_model(
            opts,
            signed,
            cli.corrections.noise_match.then_some("--noise-match"),
        )?;
    }
    let acq = dbt_store::acquisition::read_acquisition(&acq_dir)?;
    let t = std::time::Instant::now();
    let res = dbt_cli::process_with_bar(&acq, &opts, false)?;
    let secs = t.elapsed().as_secs_f64();
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_micros() as u64)
        .unwrap_or(0);
    let mut uids = UidSource::new(&uid_root, now)?;
    let equipment = Equipment {
        manufacturer: "DBToR".into(),
        model: "DBToR gantry PC".into(),
        serial: "SIM-0001".into(),
        software_version: env!("CARGO_PKG_VERSION").into(),
        device_uid: format!("{uid_root}.9.1"),
    };
    // Both densities and the verdict, for the reader of the terminal (the
    // JSON below has them too).
    eprintln!("dbtor-process: density {}", res.density_check.summary());
    for r in &res.density_check.reasons {
        eprintln!("dbtor-process:   not confirmed: {r}");
    }
    eprintln!(
        "dbtor-process: {}",
        dbt_status::page::interval_summary(
            res.glandularity,
            &res.intervals.glandularity,
            res.mgd_mgy,
            &res.intervals.mgd
        )
    );
    let (date, time) = dbt_dicom::dicom_datetime_utc(now / 1_000_000);
    let (dose, dens) = reports(&acq, &res, &equipment, &mut uids, &date, &time)?;
    let outbox = dbt_pacs::Outbox::open(&out, &out.join("outbox"))?;
    let mut delivery = Vec::new();
    for (name, r) in [("dose-sr", &dose), ("density-sr", &dens)] {
        let rep = outbox.deliver(
            &format!("{}-{name}", file_stem(&acq.header.patient.id)),
            &r.to_bytes()?,
            pacs.as_ref(),
        )?;
        delivery.push(serde_json::json!({
            "report": name,
            "sop_instance_uid": r.sop_instance,
            "sent": rep.sent.len(),
            "waiting": rep.waiting.iter().map(|(p, e)| format!("{}: {e}", p.display())).collect::<Vec<_>>(),
        }));
    }
    let summary = serde_json::json!({
        "acquisition": acq_dir.display().to_string(),
        "seconds": secs,
        "peak_rss_mib": dbt_cli::peak_rss_mib(),
        "result": res,
        "truth": acq.header.truth,
        "output": out.display().to_string(),
        "delivery": delivery,
    });
    println!("{}", serde_json::to_string_pretty(&summary)?);
    Ok(())
}

/// A file-name stem from a patient ID: a DICOM LO may hold `/`, `.` and
/// spaces, which must not reach a path; everything but ASCII letters, digits,
/// `-` and `_` becomes `_`.
fn file_stem(id: &str) -> String {
    id.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .take(64)
        .collect()
}
