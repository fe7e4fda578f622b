//! `dbtor-daemon`: the gantry-side service. Reads its configuration (TOML,
//! validated before anything starts), recovers the spool, then receives,
//! spools, processes and delivers every acquisition until SIGTERM or SIGINT
//! (the acquisition in hand is finished first).
//!
//! `dbtor-daemon --config /etc/dbtor/dbtor.toml [--once] [--check-config]`
//!
//! Exit codes: 0 stopped cleanly, 2 configuration or start-up error.

use anyhow::{bail, Context, Result};
use dbtor_firmware::config::Config;
use dbtor_firmware::daemon::Daemon;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

fn run() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (mut config, mut once, mut check) = (None, false, false);
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--config" => config = Some(PathBuf::from(it.next().context("--config needs a file")?)),
            "--once" => once = true,
            "--check-config" => check = true,
            other => bail!("unknown argument `{other}` (usage: dbtor-daemon --config FILE [--once] [--check-config])"),
        }
    }
    let path = config.context("--config FILE is required")?;
    let cfg = Config::load(&path)?;
    if check {
        println!("{}: OK", path.display());
        return Ok(());
    }
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        signal_hook::flag::register(sig, Arc::clone(&stop))
            .context("installing the signal handler")?;
    }
    let mut d = Daemon::new(cfg, path, stop)?;
    tracing::info!("dbtor-daemon started");
    d.run(once)?;
    tracing::info!("dbtor-daemon stopped");
    Ok(())
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("dbtor-daemon: error: {e:#}");
            ExitCode::from(2)
        }
    }
}
