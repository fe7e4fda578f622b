//! `dbtor-daemon`: the gantry-side service. Reads its configuration (TOML,
//! validated before anything starts), recovers the spool, then receives,
//! spools, processes and delivers every acquisition until SIGTERM or SIGINT
//! (the acquisition in hand is finished first).
//!
//! `dbtor-daemon --config /etc/dbtor/dbtor.toml [--once] [--check-config]`
//!
//! Exit codes: 0 stopped cleanly (or the configuration checks passed); 1
//! with `--once`, a fault was recorded (the status file names it); 2
//! configuration or start-up error.

use anyhow::{Context, Result};
use clap::Parser;
use dbtor_firmware::cli::error_chain;
use dbtor_firmware::config::Config;
use dbtor_firmware::daemon::{preflight, Daemon};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

#[derive(Parser)]
#[command(
    name = "dbtor-daemon",
    about = "The DBToR gantry-side service: receive, spool, process, report",
    after_help = "Exit codes: 0 stopped cleanly or checks passed; 1 with --once, a fault was recorded; 2 configuration or start-up error."
)]
struct Cli {
    /// The configuration (TOML; firmware/config/dbtor.toml documents it).
    #[arg(long)]
    config: PathBuf,
    /// Stop after one acquisition (exit 1 if a fault was recorded).
    #[arg(long)]
    once: bool,
    /// Check the configuration and everything it names (the model against
    /// its sign-off, the folders, the devices), then exit.
    #[arg(long)]
    check_config: bool,
}

/// `--check-config`: every check the daemon's start needs, printed.
fn check_config(cfg: &Config, path: &Path) -> Result<bool> {
    for line in preflight(cfg, path)? {
        println!("{line}");
    }
    println!("{}: OK", path.display());
    Ok(true)
}

/// Run the service until SIGTERM or SIGINT (or one acquisition with `once`).
fn serve(cfg: Config, path: PathBuf, once: bool) -> Result<bool> {
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        signal_hook::flag::register(sig, Arc::clone(&stop))
            .context("installing the signal handler")?;
    }
    let mut d = Daemon::new(cfg, path, stop)?;
    tracing::info!("dbtor-daemon started");
    d.run(once)?;
    tracing::info!("dbtor-daemon stopped");
    // With --once, a fault (link, spool, processing, delivery) is a failure.
    Ok(!(once && d.fault_count() > 0))
}

fn run(cli: Cli) -> Result<bool> {
    let cfg = Config::load(&cli.config)?;
    if cli.check_config {
        check_config(&cfg, &cli.config)
    } else {
        serve(cfg, cli.config, cli.once)
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    match run(cli) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            eprintln!("dbtor-daemon: error: {}", error_chain(&e));
            ExitCode::from(2)
        }
    }
}
