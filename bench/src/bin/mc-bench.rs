//! Monte Carlo speed: AAPM TG-195 case 3 at 16.8 keV, 0 degrees, our engine
//! (all cores) against the vectorised numpy peer (`peers/mc_numpy.py`, same
//! physics and tables), measured in the same run. Prints a table; writes
//! `bench/results/mc.json`.
//!
//! `cargo run --release -p dbt-bench --bin mc-bench -- [--photons 1e7]
//!  [--reps 5] [--peer-photons 1e6] [--no-peer]`

use anyhow::{Context, Result};
use clap::Parser;
use dbt_bench::median_ms;
use dbt_dose::{run, tg195, Spectrum};
use std::process::Command;

/// Monte Carlo speed: TG-195 case 3 at 16.8 keV, our engine against the
/// numpy peer, measured in the same run.
#[derive(Parser)]
#[command(name = "mc-bench")]
struct Args {
    /// Photons per run of our engine (e.g. 1e7).
    #[arg(long, default_value = "1e7", value_parser = photons)]
    photons: u64,
    /// Runs of our engine (the median is reported).
    #[arg(long, default_value_t = 5, value_parser = dbt_bench::at_least_one)]
    reps: usize,
    /// Photons of the numpy peer's run.
    #[arg(long, default_value = "1e6", value_parser = photons)]
    peer_photons: u64,
    /// Without the numpy peer.
    #[arg(long = "no-peer", action = clap::ArgAction::SetFalse)]
    peer: bool,
}

/// A positive photon count, also written as `1e7`.
fn photons(s: &str) -> Result<u64, String> {
    match s.parse::<f64>() {
        Ok(v) if (1.0..=1e12).contains(&v) && v.fract() == 0.0 => Ok(v as u64),
        _ => Err(format!("{s:?}: a whole number of photons from 1 to 1e12")),
    }
}

fn main() -> Result<()> {
    let Args {
        photons,
        reps,
        peer_photons,
        peer: with_peer,
    } = Args::parse();
    let scene = tg195::scene(0.5)?;
    let src = tg195::source(0.0, Spectrum::mono(16.8)?);
    let mut totals = Vec::new();
    let mut seed = 0;
    let ms = median_ms(1, reps, || {
        seed += 1;
        if let Ok(r) = run(&scene, &src, photons, 40, seed) {
            totals.push(
                r.per_photon(|t| t.deposited_kev[tg195::BREAST_M as usize] * 1e3)
                    .0,
            );
        }
    });
    let threads = rayon::current_num_threads();
    let ours_pps_core = photons as f64 / (ms / 1e3) / threads as f64;
    let mean_total = totals.iter().sum::<f64>() / totals.len().max(1) as f64;
    let mut peer = serde_json::Value::Null;
    if with_peer {
        let script = concat!(env!("CARGO_MANIFEST_DIR"), "/peers/mc_numpy.py");
        let out = Command::new("python3")
            .arg(script)
            .arg(peer_photons.to_string())
            .output()
            .context("running python3 (numpy peer)")?;
        if out.status.success() {
            peer = serde_json::from_slice(&out.stdout)?;
        } else {
            eprintln!(
                "numpy peer failed: {}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
    }
    println!("TG-195 case 3, 16.8 keV, 0 deg; {threads} threads; median of {reps}\n");
    println!("| engine | photons | seconds | photons/s/core | total eV/photon |");
    println!("|---|---|---|---|---|");
    println!(
        "| dbt-dose (Rust, Woodcock) | {photons:.0e} | {:.2} | {:.3e} | {:.1} |",
        ms / 1e3,
        ours_pps_core,
        mean_total
    );
    let mut json = serde_json::json!({
        "case": "TG-195 case 3, 16.8 keV, 0 deg",
        "threads": threads,
        "photons": photons,
        "median_seconds": ms / 1e3,
        "photons_per_second_per_core": ours_pps_core,
        "mean_total_ev_per_photon": mean_total,
        "reference_total_ev_per_photon": tg195::REF_TOTAL_EV,
    });
    if let (Some(s), Some(n), Some(t)) = (
        peer["seconds"].as_f64(),
        peer["photons"].as_f64(),
        peer["total_ev_per_photon"].as_f64(),
    ) {
        let pps = n / s;
        println!("| numpy peer (1 process) | {n:.0e} | {s:.2} | {pps:.3e} | {t:.1} |");
        println!(
            "\nper core: {:.0}x the numpy peer; 1e7 photons would take the peer {:.0} s",
            ours_pps_core / pps,
            1e7 / pps
        );
        json["numpy_photons_per_second"] = serde_json::json!(pps);
        json["numpy_total_ev_per_photon"] = serde_json::json!(t);
        json["speedup_per_core"] = serde_json::json!(ours_pps_core / pps);
    }
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/results/mc.json");
    std::fs::create_dir_all(concat!(env!("CARGO_MANIFEST_DIR"), "/results"))?;
    std::fs::write(path, serde_json::to_string_pretty(&json)?)?;
    println!("JSON: bench/results/mc.json");
    Ok(())
}
