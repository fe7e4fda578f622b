//! `dbtor-receive`: receive one acquisition from the gantry's projection
//! stream over TCP and spool it as a recorded acquisition (atomically: a
//! temporary folder, then a rename). Exit 0 when received; 1 on a link or
//! acquisition fault (named on stderr; nothing is spooled); 2 on bad usage.
//!
//! `dbtor-receive (--connect HOST:PORT | --serial PATH [--baud 921600]) --out DIR
//!  [--geometry paper|paper-tall|FILE.toml] [--binning N] [--timeout-s 30]
//!  [--tube-output 0.11]`: the geometry is the gantry's (as the daemon's
//! `[frames] geometry` and `binning`).

use anyhow::{bail, Context, Result};
use dbtor_firmware::link::{receive, receive_from, to_acquisition};
use std::net::TcpStream;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

fn run() -> Result<bool> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (mut connect, mut out, mut binning, mut timeout, mut output) =
        (None, None, 4usize, 30u64, 0.11f64);
    let (mut serial, mut baud) = (None::<String>, 921_600u32);
    let mut geometry = String::from("paper");
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut val = |n: &str| {
            it.next()
                .cloned()
                .with_context(|| format!("{n} needs a value"))
        };
        match a.as_str() {
            "--connect" => connect = Some(val("--connect")?),
            "--serial" => serial = Some(val("--serial")?),
            "--baud" => baud = val("--baud")?.parse().context("--baud")?,
            "--out" => out = Some(PathBuf::from(val("--out")?)),
            "--geometry" => geometry = val("--geometry")?,
            "--binning" => binning = val("--binning")?.parse().context("--binning")?,
            "--timeout-s" => timeout = val("--timeout-s")?.parse().context("--timeout-s")?,
            "--tube-output" => output = val("--tube-output")?.parse().context("--tube-output")?,
            other => bail!("unknown argument `{other}`"),
        }
    }
    let out = out.context("--out DIR is required")?;
    let geom = dbt_store::load_geometry(&geometry, binning)?;
    let result = match (connect, serial) {
        (Some(addr), None) => {
            // The gantry may not be listening yet: retry the connection briefly.
            let t0 = Instant::now();
            let mut stream = loop {
                match TcpStream::connect(&addr) {
                    Ok(s) => break s,
                    Err(e) if t0.elapsed() < Duration::from_secs(timeout) => {
                        tracing::debug!(%e, "gantry not reachable yet");
                        std::thread::sleep(Duration::from_millis(50));
                    }
                    Err(e) => bail!("connecting to {addr}: {e}"),
                }
            };
            receive(&mut stream, Duration::from_secs(timeout))
        }
        (None, Some(path)) => {
            let mut port = serialport::new(&path, baud)
                .timeout(Duration::from_millis(200))
                .open()
                .with_context(|| format!("opening serial line {path}"))?;
            receive_from(&mut port, Duration::from_secs(timeout))
        }
        _ => bail!("give --connect HOST:PORT or --serial PATH"),
    };
    let (received, stats) = match result {
        Ok(r) => r,
        Err(e) => {
            eprintln!("dbtor-receive: FAULT: {e}");
            return Ok(false);
        }
    };
    let acq = match to_acquisition(&received, &geom, output) {
        Ok(a) => a,
        Err(e) => {
            eprintln!("dbtor-receive: FAULT: {e}");
            return Ok(false);
        }
    };
    let tmp = out.with_extension("part");
    let _ = std::fs::remove_dir_all(&tmp);
    dbt_store::acquisition::write_acquisition(&tmp, &acq)?;
    if out.exists() {
        bail!(
            "{} already exists: not overwriting a spooled acquisition",
            out.display()
        );
    }
    std::fs::rename(&tmp, &out)
        .with_context(|| format!("renaming {} to {}", tmp.display(), out.display()))?;
    println!(
        "{}",
        serde_json::json!({
            "spooled": out.display().to_string(),
            "patient_id": acq.header.patient.id,
            "slices": acq.header.slices,
            "frames": stats.frames,
            "crc_errors": stats.crc_errors,
            "naks": stats.naks,
            "garbage_bytes": stats.garbage_bytes,
            "saturated_pixels": received.saturated,
        })
    );
    Ok(true)
}

fn main() -> ExitCode {
    match run() {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            eprintln!("dbtor-receive: error: {e:#}");
            ExitCode::from(2)
        }
    }
}
