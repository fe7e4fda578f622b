//! `dbtor-process`: process one recorded acquisition (offline mode of the
//! firmware): reconstruct, classify, density, Monte Carlo MGD, and deliver the
//! DICOM reports to the output folder (and the PACS, if given). Prints a JSON
//! summary. The daemon of issue #8 runs the same pipeline on acquisitions
//! received from the gantry.
//!
//! `dbtor-process ACQ_DIR --out DIR [--pacs AET@host:port] [--uid-root ROOT]
//!   [--model models/dbtor-x4 [--precision fp32|int8 [--fp32-blocks primal08,primal09]]] [--iterations N]
//!   [--dose-uncertainty 0.01]`
//!
//! With `--model`, slices are reconstructed by DBToR (the model's checksums are
//! verified first); without it by MLTR (`--iterations`, default 100).

use anyhow::{bail, Context, Result};
use dbt_dicom::{Equipment, UidSource};
use dbtor_firmware::pipeline::{process, reports, PipelineOptions};
use std::path::PathBuf;

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut acq_dir = None;
    let mut out = None;
    let mut pacs = None;
    let mut uid_root = "1.2.826.0.1.3680043.10.543.1".to_string();
    let mut opts = PipelineOptions::default();
    let mut model = None;
    let mut precision = dbt_dbtor::Precision::Fp32;
    let mut engine = dbt_dbtor::Engine::Fast;
    let mut fp32_blocks: Vec<String> = Vec::new();
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut val = |name: &str| {
            it.next()
                .cloned()
                .with_context(|| format!("{name} needs a value"))
        };
        match a.as_str() {
            "--out" => out = Some(PathBuf::from(val("--out")?)),
            "--pacs" => pacs = Some(dbt_pacs::PacsConfig::parse(&val("--pacs")?)?),
            "--uid-root" => uid_root = val("--uid-root")?,
            "--model" => model = Some(PathBuf::from(val("--model")?)),
            "--precision" => {
                precision = val("--precision")?
                    .parse()
                    .map_err(anyhow::Error::msg)
                    .context("--precision")?
            }
            "--fp32-blocks" => fp32_blocks = dbt_dbtor::parse_block_list(&val("--fp32-blocks")?),
            "--engine" => {
                engine = val("--engine")?
                    .parse()
                    .map_err(anyhow::Error::msg)
                    .context("--engine")?
            }
            "--iterations" => {
                opts.mltr_iterations = val("--iterations")?.parse().context("--iterations")?
            }
            "--dose-uncertainty" => {
                opts.dose_uncertainty = val("--dose-uncertainty")?
                    .parse()
                    .context("--dose-uncertainty")?
            }
            s if s.starts_with("--") => bail!("unknown option `{s}`"),
            s => acq_dir = Some(PathBuf::from(s)),
        }
    }
    let acq_dir =
        acq_dir.context("usage: dbtor-process ACQ_DIR --out DIR [--pacs AET@host:port]")?;
    let out = out.context("--out DIR is required")?;
    if let Some(dir) = &model {
        if !fp32_blocks.is_empty() && precision != dbt_dbtor::Precision::Int8 {
            bail!("--fp32-blocks needs --precision int8");
        }
        let m = dbt_dbtor::Dbtor::load_mixed(dir, precision, &fp32_blocks, engine)
            .with_context(|| format!("loading the DBToR model {}", dir.display()))?;
        opts.calibration = dbtor_firmware::calibration::load_calibration(&m, &opts.classify)?;
        opts.dbtor = Some(std::sync::Arc::new(m));
    }
    let acq = dbt_store::acquisition::read_acquisition(&acq_dir)?;
    let t = std::time::Instant::now();
    let res = process(&acq, &opts)?;
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
    let (date, time) = ("20261122".to_string(), "120000".to_string());
    let (dose, dens) = reports(&acq, &res, &equipment, &mut uids, &date, &time)?;
    let outbox = dbt_pacs::Outbox::open(&out, &out.join("outbox"))?;
    let mut delivery = Vec::new();
    for (name, r) in [("dose-sr", &dose), ("density-sr", &dens)] {
        let rep = outbox.deliver(
            &format!("{}-{name}", acq.header.patient.id),
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
        "result": res,
        "truth": acq.header.truth,
        "output": out.display().to_string(),
        "delivery": delivery,
    });
    println!("{}", serde_json::to_string_pretty(&summary)?);
    Ok(())
}
