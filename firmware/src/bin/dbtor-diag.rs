//! Service diagnostics for the DBToR gantry PC.
//!
//! ```text
//! dbtor-diag selftest [--geometry paper|paper-tall|FILE.toml] [--binning N] [--json]
//! dbtor-diag geometry [--geometry paper|paper-tall|FILE.toml] [--binning N]
//! dbtor-diag report FILE.dcm [--json]     # the values of a dose or density SR
//! dbtor-diag echo AET@host:port            # DICOM C-ECHO to the PACS
//! dbtor-diag modbus (HOST:PORT | --rtu PATH [--baud 19200]) [--unit N] [--base N] [--json]   # read and decode the gantry registers
//! dbtor-diag model DIR [--precision fp32|int8] [--json]   # checksums + stored fixtures of a DBToR model
//! dbtor-diag status (--config FILE | --status FILE) [--json]  # the daemon's state, results and faults
//! dbtor-diag config FILE                   # validate a daemon configuration and print it
//! dbtor-diag replay ENTRY [--model DIR [--precision P]] [--iterations N] [--dose-uncertainty U] [--json]
//!                                          # reprocess a spooled acquisition offline (nothing is sent)
//! dbtor-diag bench [--model DIR] [--reps N] [--json]   # projector and DBToR slice timings on this PC
//! ```
//! Exit codes: 0 all checks passed, 1 a check failed, 2 bad usage or input.

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use dbt_cli::GeometryArgs;
use dbt_dbtor::{Engine, Precision};
use dbt_geometry::Geometry;
use dbtor_firmware::selftest;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "dbtor-diag",
    about = "Service diagnostics for the DBToR gantry PC",
    after_help = "Exit codes: 0 all checks passed, 1 a check failed, 2 bad usage or input."
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Projector self-test: adjointness, analytic line integrals, norm bound.
    Selftest(SelftestArgs),
    /// Print the geometry as TOML.
    Geometry(PrintGeometryArgs),
    /// The values of a dose or density structured report.
    Report(ReportArgs),
    /// DICOM C-ECHO to the PACS.
    Echo(EchoArgs),
    /// Read and decode the gantry registers (Modbus TCP, or RTU with --rtu).
    Modbus(ModbusArgs),
    /// Verify a DBToR model folder: its sign-off (one digest over the
    /// manifest, the calibration and every ONNX file), the network's
    /// checksums and its stored fixtures.
    Model(ModelArgs),
    /// The daemon's state, results and faults.
    Status(StatusArgs),
    /// Validate a daemon configuration and print it.
    Config(ConfigArgs),
    /// Reprocess a spooled acquisition offline (nothing is sent).
    Replay(ReplayArgs),
    /// Projector and DBToR slice timings on this PC.
    Bench(BenchArgs),
}

/// The options of `dbtor-diag selftest`.
#[derive(Args)]
struct SelftestArgs {
    #[command(flatten)]
    geometry: GeometryArgs,
    /// Also measure the fast engine's kernels on this model folder's own
    /// blocks (each configuration the CPU runs checked against the portable
    /// kernel and timed; the fastest that agrees is the one the daemon
    /// runs) and print what was measured and chosen.
    #[arg(long)]
    model: Option<PathBuf>,
    /// The precision measured with `--model`.
    #[arg(long, default_value = "int8")]
    precision: Precision,
    #[arg(long)]
    json: bool,
}

/// The options of `dbtor-diag geometry`.
#[derive(Args)]
struct PrintGeometryArgs {
    #[command(flatten)]
    geometry: GeometryArgs,
}

/// The options of `dbtor-diag report`.
#[derive(Args)]
struct ReportArgs {
    file: PathBuf,
    #[arg(long)]
    json: bool,
}

/// The options of `dbtor-diag echo`.
#[derive(Args)]
struct EchoArgs {
    /// AET@host:port
    peer: String,
}

/// The options of `dbtor-diag modbus`.
#[derive(Args)]
struct ModbusArgs {
    /// HOST:PORT of a Modbus TCP gantry.
    #[arg(required_unless_present = "rtu", conflicts_with = "rtu")]
    address: Option<String>,
    /// Serial line of a Modbus RTU gantry.
    #[arg(long)]
    rtu: Option<String>,
    #[arg(long, default_value_t = 19_200)]
    baud: u32,
    #[arg(long, default_value_t = 1)]
    unit: u8,
    /// Register base address.
    #[arg(long, default_value_t = 0)]
    base: u16,
    #[arg(long)]
    json: bool,
}

/// The options of `dbtor-diag model`.
#[derive(Args)]
struct ModelArgs {
    dir: PathBuf,
    /// Check one precision only (default: both).
    #[arg(long)]
    precision: Option<Precision>,
    /// The digest the site's configuration pins (`recon.model_digest`).
    #[arg(long)]
    digest: Option<String>,
    /// Sign the folder off as it is now (writes signoff.json and prints
    /// the digest for `recon.model_digest`), after its checks pass.
    #[arg(long)]
    sign_off: bool,
    #[arg(long)]
    json: bool,
}

/// The options of `dbtor-diag status`.
#[derive(Args)]
struct StatusArgs {
    /// The daemon's configuration (names the status file).
    #[arg(long, required_unless_present = "status", conflicts_with = "status")]
    config: Option<PathBuf>,
    /// The status file itself.
    #[arg(long)]
    status: Option<PathBuf>,
    #[arg(long)]
    json: bool,
}

/// The options of `dbtor-diag config`.
#[derive(Args)]
struct ConfigArgs {
    file: PathBuf,
}

/// The options of `dbtor-diag replay`.
#[derive(Args)]
struct ReplayArgs {
    /// The spool entry (`done/ID`, `faulted/ID`, `incoming/ID`) or any
    /// recorded acquisition folder.
    entry: PathBuf,
    /// The site's configuration (`dbtor.toml`): replay with exactly the
    /// daemon's processing (its signed model, calibrations, corrections,
    /// noise matching, slice step and Monte Carlo), so that the figures are
    /// the reported ones. Without it, an ad hoc processing from the options
    /// below (`--model`, or MLTR), which the reports were not made with.
    #[arg(long, conflicts_with_all = ["model", "iterations", "dose_uncertainty"])]
    config: Option<PathBuf>,
    #[command(flatten)]
    model: dbt_cli::ModelArgs,
    /// MLTR iterations (ad hoc processing only).
    #[arg(long)]
    iterations: Option<usize>,
    /// Relative statistical uncertainty the Monte Carlo dose runs to (ad hoc
    /// processing only).
    #[arg(long)]
    dose_uncertainty: Option<f64>,
    #[arg(long)]
    json: bool,
}

/// The options of `dbtor-diag bench`.
#[derive(Args)]
struct BenchArgs {
    #[arg(long)]
    model: Option<PathBuf>,
    #[arg(long, default_value_t = 5)]
    reps: usize,
    #[arg(long)]
    json: bool,
}

fn load_geometry(a: &GeometryArgs) -> Result<Geometry> {
    Ok(a.load()?)
}

fn median_ms(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

fn run() -> Result<bool> {
    run_cmd(Cli::parse().cmd)
}

fn run_cmd(cmd: Cmd) -> Result<bool> {
    match cmd {
        Cmd::Selftest(args) => run_selftest(args),
        Cmd::Config(args) => run_config(args),
        Cmd::Status(args) => run_status(args),
        Cmd::Replay(args) => run_replay(args),
        Cmd::Bench(args) => run_bench(args),
        Cmd::Model(args) => run_model(args),
        Cmd::Geometry(args) => run_geometry(args),
        Cmd::Report(args) => run_report(args),
        Cmd::Echo(args) => run_echo(args),
        Cmd::Modbus(args) => run_modbus(args),
    }
}

/// The fast engine's kernels here: fp32, int8 (and whether it convolves by
/// Winograd) and the fused projector's, and whether `DBTOR_KERNEL` forces
/// them down.
fn conv_kernels() -> Result<String> {
    use dbt_conv::Kernel;
    let limit = dbt_dbtor::kernel_limit()?;
    let int8 = Kernel::best_int8_up_to(limit);
    let winograd = match (int8, dbt_dbtor::winograd_allowed()?) {
        (Kernel::Avx2 | Kernel::AvxVnni, true) => " (Winograd F(3x3,3x3))",
        (Kernel::Avx2 | Kernel::AvxVnni, false) => " (direct convolution: DBTOR_WINOGRAD)",
        (Kernel::Avx512, _) if limit == Kernel::Amx => {
            " (AMX asked for: not on this CPU or not granted)"
        }
        _ => "",
    };
    Ok(format!(
        "fp32 {}, int8 {}{winograd}, projector {}{}",
        Kernel::best_fp32_up_to(limit).name(),
        int8.name(),
        dbt_projector::best_kernel_up_to(dbt_dbtor::projector_limit(limit)).name(),
        match std::env::var(dbt_dbtor::KERNEL_ENV) {
            Ok(v) => format!(" ({}={v})", dbt_dbtor::KERNEL_ENV),
            Err(_) => String::new(),
        }
    ))
}

/// `dbtor-diag selftest`: `Ok(false)` when a check failed.
fn run_selftest(args: SelftestArgs) -> Result<bool> {
    let SelftestArgs {
        geometry,
        model,
        precision,
        json,
    } = args;
    let g = load_geometry(&geometry)?;
    let checks = selftest::projector(&g);
    let ok = checks.iter().all(|c| c.passed());
    let cpu = dbt_cli::cpu_summary();
    let kernels = match &model {
        // The model's own blocks measured, as the daemon's load measures them.
        Some(dir) => {
            let m = dbt_dbtor::Dbtor::load_with(dir, precision, Engine::Fast)
                .with_context(|| format!("loading {}", dir.display()))?;
            match m.kernel_measurements() {
                [] => format!(
                    "{} (forced by {}, not measured)",
                    conv_kernels()?,
                    dbt_dbtor::KERNEL_ENV
                ),
                lines => format!("measured on {}: {}", dir.display(), lines.join("; ")),
            }
        }
        None => format!(
            "{} (by instruction set; --model DIR measures them)",
            conv_kernels()?
        ),
    };
    if json {
        let v: Vec<_> = checks
            .iter()
            .map(|c| serde_json::json!({"check": c.name, "value": c.value, "limit": c.limit, "passed": c.passed(), "detail": c.detail}))
            .collect();
        println!(
            "{}",
            serde_json::json!({"geometry": g.describe(), "cpu": cpu, "conv_kernels": kernels, "passed": ok, "checks": v})
        );
    } else {
        println!("cpu: {cpu}");
        println!("DBToR fast engine: {kernels}");
        println!("geometry: {}", g.describe());
        println!(
            "{:<24} {:>6} {:>11} {:>9}  detail",
            "check", "result", "value", "limit"
        );
        for c in &checks {
            let r = if c.passed() { "PASS" } else { "FAIL" };
            println!(
                "{:<24} {:>6} {:>11.3e} {:>9.1e}  {}",
                c.name, r, c.value, c.limit, c.detail
            );
        }
        println!(
            "{}",
            if ok {
                "all checks passed"
            } else {
                "SOME CHECKS FAILED"
            }
        );
    }
    Ok(ok)
}

/// `dbtor-diag config`: `Ok(false)` when a check failed.
fn run_config(args: ConfigArgs) -> Result<bool> {
    let ConfigArgs { file } = args;
    let cfg = dbtor_firmware::config::Config::load(&file)?;
    println!("{}: valid\n{cfg:#?}", file.display());
    Ok(true)
}

/// `dbtor-diag status`: the state the status page shows, read the same way
/// (`dbtor_firmware::status_page::StateReader`): the status file and, with
/// `--config`, the spool's history. `Ok(false)` when a check failed.
fn run_status(args: StatusArgs) -> Result<bool> {
    let StatusArgs {
        config,
        status,
        json,
    } = args;
    let (path, spool, page) = match (status, config) {
        (Some(s), _) => (s, None, None),
        (None, Some(c)) => {
            let cfg = dbtor_firmware::config::Config::load(&c)?;
            let page = cfg.status_page_address(&c)?;
            (cfg.paths.status, Some(cfg.paths.spool), page)
        }
        _ => bail!("status needs --config FILE or --status FILE"),
    };
    let mut reader = dbtor_firmware::status_page::StateReader::new(path.clone(), spool);
    let snap = reader.read()?;
    let st = &snap.status;
    let alive = st.pid > 0 && std::path::Path::new(&format!("/proc/{}", st.pid)).exists();
    let healthy = st.healthy();
    if json {
        let mut v = dbtor_firmware::status_page::snapshot_json(&snap);
        v["status_file"] = path.display().to_string().into();
        v["running"] = (alive && st.state != "stopped").into();
        println!("{v}");
        return Ok(healthy);
    }
    let running = if st.state == "stopped" {
        "stopped".to_string()
    } else if alive {
        format!("running (pid {})", st.pid)
    } else {
        format!("NOT RUNNING (pid {} gone; last state {})", st.pid, st.state)
    };
    println!("daemon        {running}");
    println!(
        "health        {}",
        if healthy {
            "healthy"
        } else {
            "fault since the last report"
        }
    );
    println!(
        "state         {}{}",
        st.state,
        st.current
            .as_deref()
            .map(|c| format!(" ({c})"))
            .unwrap_or_default()
    );
    println!("reconstructor {}", st.reconstructor);
    for k in &st.kernels {
        println!("kernels       {k}");
    }
    println!(
        "processed     {} (recovered from spool at start: {}; waiting in spool: {})",
        st.processed, st.recovered, st.incoming
    );
    match (&st.status_page, page) {
        (Some(url), _) => println!("status page   {url}"),
        (None, Some(a)) => println!("status page   configured on {a}, not served (see the faults)"),
        (None, None) => println!("status page   off"),
    }
    print_dicom_input(st.dicom_input.as_ref(), st.updated_unix);
    let recent = if reader.spool().is_some() {
        &snap.history
    } else {
        &st.recent
    };
    if reader.spool().is_some() {
        println!(
            "history       {} reported acquisitions in the spool{}",
            snap.history.len(),
            if snap.unreadable.is_empty() {
                String::new()
            } else {
                format!(" ({} unreadable)", snap.unreadable.len())
            }
        );
    }
    println!("recent acquisitions:");
    for a in recent.iter().rev().take(10) {
        println!(
            "  {:<40} {:>5} mm  G {:>5} %  {}  MGD {} mGy (model breast {})  {:.1} s",
            a.acquisition,
            a.thickness_mm
                .map(|t| format!("{t:.1}"))
                .unwrap_or_else(|| "-".into()),
            dbt_status::page::fmt_glandularity(a.glandularity_reported),
            a.composition.as_deref().unwrap_or("-"),
            dbt_status::page::fmt_mgd(a.mgd_mgy),
            dbt_status::page::fmt_mgd(a.model_mgd_mgy),
            a.seconds
        );
        match &a.density_check {
            Some(c) if !c.confirmed => println!(
                "    {}: density NOT confirmed by the physics (physics {} %): {}",
                dbt_status::DENSITY_CHECK_WARNING,
                c.physics_glandularity
                    .map_or("none".into(), dbt_status::page::fmt_glandularity),
                c.reasons.join("; ")
            ),
            Some(c) => println!(
                "    density confirmed by the physics ({} %)",
                c.physics_glandularity
                    .map_or("-".into(), dbt_status::page::fmt_glandularity)
            ),
            None => {}
        }
        if let (Some(g), Some(m)) = (&a.glandularity_interval, &a.mgd_interval) {
            println!(
                "    {}",
                dbt_status::page::interval_summary(a.glandularity_reported, g, a.mgd_mgy, m)
            );
        }
    }
    if !st.warning_counts.is_empty() {
        println!(
            "warnings since start: {}",
            st.warning_counts
                .iter()
                .map(|(k, n)| format!("{k} {n}"))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    for u in &snap.unreadable {
        println!("  unreadable {}: {}", u.acquisition, u.reason);
    }
    println!("faults ({}):", st.faults.len());
    for f in st.faults.iter().rev().take(10) {
        println!(
            "  [{}] {:<10} {} {}",
            dbt_status::page::utc(f.at_unix),
            f.kind,
            f.acquisition.as_deref().unwrap_or("-"),
            f.message
        );
    }
    Ok(healthy)
}

/// `dbtor-diag replay`: `Ok(false)` when a check failed.
fn run_replay(args: ReplayArgs) -> Result<bool> {
    let ReplayArgs {
        entry,
        config,
        model:
            dbt_cli::ModelArgs {
                model,
                precision,
                engine,
            },
        iterations,
        dose_uncertainty,
        json,
    } = args;
    let entry = entry.as_path();
    let acq = dbt_store::acquisition::read_acquisition(entry)?;
    let (opts, processing) = match &config {
        Some(path) => {
            let cfg = dbtor_firmware::config::Config::load(path)?;
            (
                dbtor_firmware::assembly::pipeline_options(&cfg, path)?,
                format!("the daemon's, from {}", path.display()),
            )
        }
        None => {
            let mut opts = dbt_pipeline::PipelineOptions::default();
            if let Some(n) = iterations {
                opts.mltr_iterations = n;
            }
            if let Some(u) = dose_uncertainty {
                opts.dose_uncertainty = u;
            }
            if let Some(dir) = model {
                opts.dbtor = Some(std::sync::Arc::new(dbt_dbtor::Dbtor::load_with(
                    &dir, precision, engine,
                )?));
            }
            (
                opts,
                "ad hoc (no --config: not the processing the reports were made with)".to_string(),
            )
        }
    };
    let t = std::time::Instant::now();
    eprintln!(
        "replaying {} ({} slices), processing {processing} ...",
        entry.display(),
        acq.header.slices
    );
    let r = dbt_cli::process_with_bar(&acq, &opts, json)?;
    let stored: Option<serde_json::Value> = std::fs::read(entry.join("result.json"))
        .ok()
        .and_then(|b| serde_json::from_slice(&b).ok());
    let out = serde_json::json!({
        "entry": entry.display().to_string(),
        "processing": processing,
        "reconstructor": r.reconstructor,
        "seconds": t.elapsed().as_secs_f64(),
        "glandularity_reported": r.glandularity,
        "glandularity_labels": r.density.glandularity_labels,
        "glandularity_partial_volume": r.density.glandularity_partial_volume,
        "mgd_mgy": r.mgd_mgy,
        "mgd_relative_uncertainty": r.dose_patient.mgd_rel_uncertainty,
        "model_mgd_mgy": r.model_mgd_mgy,
        "stored_result": stored,
    });
    if json {
        println!("{out}");
    } else {
        println!(
            "replay of {} ({}, {:.1} s), processing {processing}",
            entry.display(),
            r.reconstructor,
            t.elapsed().as_secs_f64()
        );
        let st = |k: &str| {
            stored
                .as_ref()
                .and_then(|v| v[k].as_f64())
                .map(|x| format!("{x:.3}"))
                .unwrap_or("-".into())
        };
        println!("{:<28} {:>10} {:>10}", "", "replay", "stored");
        for (name, value, key) in [
            (
                "glandularity (reported)",
                r.glandularity,
                "glandularity_reported",
            ),
            (
                "glandularity (labels)",
                r.density.glandularity_labels,
                "glandularity_labels",
            ),
            (
                "glandularity (partial vol.)",
                r.density.glandularity_partial_volume,
                "glandularity_partial_volume",
            ),
            ("MGD, mGy", r.mgd_mgy, "mgd_mgy"),
            ("model-breast MGD, mGy", r.model_mgd_mgy, "model_mgd_mgy"),
        ] {
            println!("{name:<28} {value:>10.3} {:>10}", st(key));
        }
    }
    Ok(true)
}

/// `dbtor-diag bench`: `Ok(false)` when a check failed.
fn run_bench(args: BenchArgs) -> Result<bool> {
    let BenchArgs { model, reps, json } = args;
    let (cpu, kernels) = (dbt_cli::cpu_summary(), conv_kernels()?);
    if !json {
        println!("cpu: {cpu}");
        println!("DBToR fast engine: {kernels}");
    }
    let g = Geometry::paper();
    let p = dbt_projector::Projector::new(&g);
    let x = vec![0.05f32; g.n_pixels()];
    let mut y = vec![0f32; g.n_rays()];
    let mut back = vec![0f32; g.n_pixels()];
    let (mut fw, mut ad) = (Vec::new(), Vec::new());
    for _ in 0..reps.max(1) {
        let t = std::time::Instant::now();
        p.forward(&x, &mut y)?;
        fw.push(t.elapsed().as_secs_f64() * 1e3);
        let t = std::time::Instant::now();
        p.adjoint(&y, &mut back)?;
        ad.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let mut rows = vec![
        (
            "projector forward, paper geometry".to_string(),
            median_ms(fw),
        ),
        (
            "projector adjoint, paper geometry".to_string(),
            median_ms(ad),
        ),
    ];
    if let Some(dir) = model {
        for (prec, engine) in [
            (Precision::Fp32, Engine::Fast),
            (Precision::Int8, Engine::Fast),
            (Precision::Fp32, Engine::Tract),
            (Precision::Int8, Engine::Tract),
        ] {
            let m = dbt_dbtor::Dbtor::load_with(&dir, prec, engine)?;
            let mg = m.geometry().clone();
            let g0 = vec![1.0f32; mg.n_rays()];
            let mut v = Vec::new();
            let bar = dbt_cli::Progress::new(
                reps.max(1) as u64,
                &format!("DBToR {prec} {engine}"),
                "slices",
                json,
            );
            for _ in 0..reps.max(1) {
                let t = std::time::Instant::now();
                m.reconstruct(&g0, 45.0)?;
                v.push(t.elapsed().as_secs_f64() * 1e3);
                bar.inc(1);
            }
            bar.finish();
            rows.push((
                format!(
                    "DBToR slice {prec} {engine}, {}x{} px",
                    mg.image.columns, mg.image.rows
                ),
                median_ms(v),
            ));
        }
    }
    if json {
        let o: serde_json::Map<String, serde_json::Value> = rows
            .iter()
            .map(|(k, v)| (k.clone(), serde_json::json!(v)))
            .collect();
        println!(
            "{}",
            serde_json::json!({"cpu": cpu, "conv_kernels": kernels, "reps": reps, "median_ms": o})
        );
    } else {
        println!("{:<44} {:>12}", "operation (median of reps)", "ms");
        for (k, v) in &rows {
            println!("{k:<44} {v:>12.2}");
        }
    }
    Ok(true)
}

/// `dbtor-diag model`: `Ok(false)` when a check failed.
fn run_model(args: ModelArgs) -> Result<bool> {
    let ModelArgs {
        dir,
        precision,
        digest,
        sign_off,
        json,
    } = args;
    let precisions = match precision {
        Some(p) => vec![p],
        None => vec![Precision::Fp32, Precision::Int8],
    };
    let dir = dir.as_path();
    let mut all = Vec::new();
    let runs = precisions
        .iter()
        .flat_map(|p| [Engine::Fast, Engine::Tract].map(|e| (*p, e)));
    for (p, e) in runs {
        let t = std::time::Instant::now();
        // Loading verifies every SHA-256 of the manifest first.
        let m = dbt_dbtor::Dbtor::load_with(dir, p, e)
            .with_context(|| format!("loading {} ({p}, {e})", dir.display()))?;
        let checks = dbt_dbtor::check_fixtures(&m, dir)?;
        if !json {
            println!(
                "{} ({p}, {e}): {} files verified, {} fixtures, {:.1} s",
                m.manifest().name,
                m.manifest().sha256.len(),
                checks.len(),
                t.elapsed().as_secs_f64()
            );
            for c in &checks {
                let r = if c.pass { "PASS" } else { "FAIL" };
                println!("  {:<8} {r}  {}", c.name, c.rule);
            }
        }
        all.extend(checks);
    }
    let mut ok = !all.is_empty() && all.iter().all(|c| c.pass);
    if sign_off && ok {
        dbt_model::sign_off(dir)?;
    }
    let signoff = match dbt_model::verify(dir, digest.as_deref()) {
        Ok(s) => {
            serde_json::json!({"passed": true, "digest": s.digest, "files": s.files.len()})
        }
        Err(e) => {
            ok = false;
            serde_json::json!({"passed": false, "error": e.to_string()})
        }
    };
    if json {
        println!(
            "{}",
            serde_json::json!({"model": dir.display().to_string(), "passed": ok, "signoff": signoff, "fixtures": all})
        );
    } else if signoff["passed"] == true {
        println!(
            "sign-off: PASS  {} files, digest {}",
            signoff["files"],
            signoff["digest"].as_str().unwrap_or_default()
        );
    } else {
        println!(
            "sign-off: FAIL  {}",
            signoff["error"].as_str().unwrap_or_default()
        );
    }
    Ok(ok)
}

/// `dbtor-diag geometry`: `Ok(false)` when a check failed.
fn run_geometry(args: PrintGeometryArgs) -> Result<bool> {
    let PrintGeometryArgs { geometry } = args;
    let g = load_geometry(&geometry)?;
    print!("{}", g.to_toml_string());
    Ok(true)
}

/// `dbtor-diag report`: `Ok(false)` when a check failed.
fn run_report(args: ReportArgs) -> Result<bool> {
    let ReportArgs { file, json } = args;
    let bytes = std::fs::read(&file).with_context(|| format!("reading {}", file.display()))?;
    let (class, values) =
        dbt_dicom::read_values(&bytes).with_context(|| format!("decoding {}", file.display()))?;
    let file = file.display().to_string();
    if json {
        let v: Vec<_> = values
            .iter()
            .map(|(k, v)| serde_json::json!({"concept": k, "value": v}))
            .collect();
        println!(
            "{}",
            serde_json::json!({"file": file, "sop_class_uid": class, "values": v})
        );
    } else {
        println!("{file}: SOP class {class}");
        for (k, v) in &values {
            println!("  {k}: {v}");
        }
    }
    Ok(true)
}

/// `dbtor-diag echo`: `Ok(false)` when a check failed.
fn run_echo(args: EchoArgs) -> Result<bool> {
    let EchoArgs { peer } = args;
    let cfg = dbt_pacs::PacsConfig::parse(&peer)?;
    let t = std::time::Instant::now();
    match dbt_pacs::echo(&cfg) {
        Ok(()) => {
            println!(
                "C-ECHO {peer}: success in {:.0} ms",
                t.elapsed().as_secs_f64() * 1e3
            );
            Ok(true)
        }
        Err(e) => {
            println!("C-ECHO {peer}: FAILED: {e}");
            Ok(false)
        }
    }
}

/// `dbtor-diag modbus`: `Ok(false)` when a check failed.
fn run_modbus(args: ModbusArgs) -> Result<bool> {
    let ModbusArgs {
        address,
        rtu,
        baud,
        unit,
        base,
        json,
    } = args;
    let endpoint = match (rtu, address) {
        (Some(path), None) => dbtor_firmware::modbus::Endpoint::Rtu { path, baud },
        (None, Some(addr)) => dbtor_firmware::modbus::Endpoint::Tcp(
            addr.parse()
                .with_context(|| format!("`{addr}` is not HOST:PORT"))?,
        ),
        _ => bail!("modbus needs HOST:PORT (TCP) or --rtu PATH [--baud N] (RTU)"),
    };
    let addr = endpoint.to_string();
    let mut link = dbtor_firmware::modbus::ModbusLink::with_endpoint(endpoint);
    link.unit = unit;
    link.base = base;
    match dbtor_firmware::modbus::read_registers(&link) {
        Ok(r) => {
            if json {
                println!("{}", serde_json::json!({"address": addr, "registers": r}));
            } else {
                println!("gantry registers at {addr} (unit {unit}, base {base}):");
                println!("  interface version   {}", r.version);
                println!("  state               {:?}", r.state);
                println!("  thickness           {:.1} mm", r.thickness_mm);
                println!("  force               {:.1} N", r.force_n);
                println!("  tube voltage        {:.1} kV", r.kvp);
                println!("  mAs per projection  {:.2}", r.mas_per_projection);
                println!("  anode/filter        {}", r.anode_filter);
                println!(
                    "  projections         {} over [{:.1}, {:.1}] deg",
                    r.projections, r.angles_deg[0], r.angles_deg[1]
                );
                println!("  current projection  {}", r.current);
                println!("  laterality / view   {} {}", r.laterality, r.view);
                println!("  fault code          {}", r.fault);
            }
            Ok(true)
        }
        Err(e) => {
            println!("Modbus {addr}: FAILED: {e}");
            Ok(false)
        }
    }
}

fn main() -> ExitCode {
    match run() {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            eprintln!(
                "dbtor-diag: error: {}",
                dbtor_firmware::cli::error_chain(&e)
            );
            ExitCode::from(2)
        }
    }
}

/// The DICOM input's lines of `dbtor-diag status`: where it listens, its
/// associations and objects, and each sweep waiting for views.
fn print_dicom_input(d: Option<&dbt_status::DicomInputStatus>, now_unix: u64) {
    let Some(d) = d else {
        println!("dicom input   off");
        return;
    };
    println!("dicom input   listening as {}", d.listening);
    println!(
        "  associations {} open, {} since start{}",
        d.associations_open,
        d.associations_total,
        d.last_association
            .as_ref()
            .map(|(ae, t)| format!(
                " (last: {ae}, {} s before this status)",
                now_unix.saturating_sub(*t)
            ))
            .unwrap_or_default()
    );
    println!(
        "  objects      {} kept, {} duplicates, {} refused; {} presentation contexts refused",
        d.objects_stored, d.objects_duplicate, d.objects_refused, d.contexts_refused
    );
    if d.waiting.is_empty() {
        println!("  waiting      no sweep waits for views");
    }
    for w in &d.waiting {
        println!(
            "  waiting      {} {}: {} of {} views, last {} s before this status (faulted after {} s)",
            w.laterality,
            w.view,
            w.views_received,
            w.views_expected,
            now_unix.saturating_sub(w.last_view_unix),
            d.quiet_time_s
        );
    }
}
