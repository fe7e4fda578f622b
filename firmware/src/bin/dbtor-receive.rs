//! `dbtor-receive`: receive one acquisition from the gantry's projection
//! stream over TCP or a serial line and spool it as a recorded acquisition
//! (atomically: a temporary folder, then a rename). Exit 0 when received; 1
//! on a link or acquisition fault (named on stderr; nothing is spooled); 2
//! on bad usage.
//!
//! `dbtor-receive (--connect HOST:PORT | --serial PATH [--baud 921600]) --out DIR
//!  [--geometry paper|paper-tall|FILE.toml] [--binning N]
//!  [--system paper-cone|FILE.toml] [--timeout-s 30] [--tube-output 0.11]`:
//! the geometry and system are the gantry's (as the daemon's `[frames]
//! geometry`, `binning` and `system`); they also set the receiver's memory
//! budget. A stream from another system is refused naming both.

use anyhow::{bail, Context, Result};
use clap::Parser;
use dbtor_firmware::cli::error_chain;
use dbtor_firmware::link::{receive, receive_from, to_acquisition, Gantry, LinkOptions};
use std::net::TcpStream;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(
    name = "dbtor-receive",
    about = "Receive one acquisition from the gantry's projection stream and spool it",
    after_help = "Exit codes: 0 received and spooled; 1 link or acquisition fault (nothing spooled); 2 bad usage."
)]
struct Cli {
    /// The gantry's frame server, HOST:PORT.
    #[arg(long, required_unless_present = "serial", conflicts_with = "serial")]
    connect: Option<String>,
    /// The serial line of the frame stream.
    #[arg(long)]
    serial: Option<String>,
    #[arg(long, default_value_t = 921_600)]
    baud: u32,
    /// The spool folder to create.
    #[arg(long)]
    out: PathBuf,
    /// The gantry's geometry (as the daemon's `[frames] geometry` and `binning`).
    #[command(flatten)]
    geometry: dbt_cli::GeometryArgs,
    /// The gantry's cone-beam system (`paper-cone`, `siemens-victre` or a
    /// system TOML, binned as the geometry), as the daemon's `[frames]
    /// system`; without it, the slice-wise fan-beam stream.
    #[arg(long)]
    system: Option<String>,
    /// Idle and write timeout, s.
    #[arg(long, default_value_t = 30)]
    timeout_s: u64,
    /// Tube output at the reference point, mGy/mAs (the site's calibration).
    #[arg(long, default_value_t = 0.11)]
    tube_output: f64,
}

/// Connect to the gantry, which may not be listening yet: retry briefly.
fn connect(addr: &str, timeout: Duration) -> Result<TcpStream> {
    let t0 = Instant::now();
    loop {
        match TcpStream::connect(addr) {
            Ok(s) => return Ok(s),
            Err(e) if t0.elapsed() < timeout => {
                tracing::debug!(%e, "gantry not reachable yet");
                std::thread::sleep(Duration::from_millis(50));
            }
            Err(e) => bail!("connecting to {addr}: {e}"),
        }
    }
}

fn run(cli: Cli) -> Result<bool> {
    let geom = cli.geometry.load()?;
    let system = cli.geometry.load_system(cli.system.as_deref())?;
    // A cone-beam system's frames are rebinned to its fan on the geometry
    // (as the daemon's configuration and host-sim make it).
    let geom = match &system {
        Some(s) => s.rebinning_fan(&geom)?,
        None => geom,
    };
    if let Some(s) = &system {
        dbt_pipeline::rebin::check_site(s, &geom).with_context(|| {
            format!(
                "--system {} with --geometry {}",
                s.name, cli.geometry.geometry
            )
        })?;
    }
    let site = Gantry {
        cone: system,
        ..Gantry::fan(&geom, cli.tube_output)
    };
    let timeout = Duration::from_secs(cli.timeout_s);
    let link = LinkOptions::new(timeout).for_site(&site);
    let result = match (&cli.connect, &cli.serial) {
        (Some(addr), None) => receive(&mut connect(addr, timeout)?, &link),
        (None, Some(path)) => {
            let mut port = serialport::new(path, cli.baud)
                .timeout(Duration::from_millis(200))
                .open()
                .with_context(|| format!("opening serial line {path}"))?;
            receive_from(&mut port, &link)
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
    let acq = match to_acquisition(&received, &site) {
        Ok(a) => a,
        Err(e) => {
            eprintln!("dbtor-receive: FAULT: {e}");
            return Ok(false);
        }
    };
    let out = &cli.out;
    let tmp = out.with_extension("part");
    let _ = std::fs::remove_dir_all(&tmp);
    dbt_store::acquisition::write_acquisition(&tmp, &acq)?;
    if out.exists() {
        bail!(
            "{} already exists: not overwriting a spooled acquisition",
            out.display()
        );
    }
    std::fs::rename(&tmp, out)
        .with_context(|| format!("renaming {} to {}", tmp.display(), out.display()))?;
    println!(
        "{}",
        serde_json::json!({
            "spooled": out.display().to_string(),
            "patient_id": acq.header.patient.id,
            // Coronal slices, or a cone-beam system's detector rows.
            "slices": acq.header.slices,
            "system": acq.header.system.as_ref().map(|s| s.name.clone()),
            "link": stats,
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
    let cli = Cli::parse();
    match run(cli) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            eprintln!("dbtor-receive: error: {}", error_chain(&e));
            ExitCode::from(2)
        }
    }
}
