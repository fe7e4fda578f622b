//! `dbt-dose`: the Monte Carlo engine's commands.

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use dbt_dose::tg195;
use dbt_dose::{run_observed, Spectrum};
use std::path::PathBuf;
use std::time::Instant;

#[derive(Parser)]
#[command(name = "dbt-dose", about = "Monte Carlo breast dosimetry")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// The paper's W/Rh spectra (Table 3): rhodium solved for each HVL, as JSON.
    Spectra,
    /// AAPM TG-195 case 3: energy deposited in the breast and the 7 VOIs, as JSON.
    Tg195(Tg195Args),
}

/// The options of `dbt-dose tg195`.
#[derive(Args)]
struct Tg195Args {
    /// Spectrum file (two columns: energy keV, relative weight); default 16.8 keV.
    #[arg(long)]
    spectrum: Option<PathBuf>,
    /// Monoenergetic source, keV (ignored with --spectrum).
    #[arg(long, default_value_t = 16.8)]
    energy: f64,
    /// Source rotation about the x axis through the origin, degrees.
    #[arg(long, default_value_t = 0.0)]
    angle: f64,
    /// Photons.
    #[arg(long, default_value_t = 10_000_000)]
    photons: u64,
    /// Voxel side of the breast grid, mm.
    #[arg(long, default_value_t = 0.5)]
    voxel: f64,
    /// Batches for the uncertainty.
    #[arg(long, default_value_t = 40)]
    batches: usize,
    /// Seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

fn main() -> Result<()> {
    match Cli::parse().cmd {
        Cmd::Spectra => run_spectra(),
        Cmd::Tg195(a) => run_tg195(a),
    }
}

/// `dbt-dose spectra`.
fn run_spectra() -> Result<()> {
    let rows: Vec<_> = dbt_dose::xray::PAPER_TABLE3
        .iter()
        .map(|&((lo, hi), kv, hvl)| {
            let s = dbt_dose::xray::w_rh_spectrum(kv, hvl)?;
            Ok(serde_json::json!({
                "thickness_mm": [lo, hi],
                "kv": kv,
                "target_hvl_mm_al": hvl,
                "rh_um": s.rh_mm * 1e3,
                "hvl_mm_al": s.hvl_mm_al,
                "mean_kev": s.mean_kev,
            }))
        })
        .collect::<Result<_>>()?;
    println!("{}", serde_json::to_string_pretty(&rows)?);
    Ok(())
}

/// `dbt-dose tg195`.
fn run_tg195(args: Tg195Args) -> Result<()> {
    let Tg195Args {
        spectrum,
        energy,
        angle,
        photons,
        voxel,
        batches,
        seed,
    } = args;
    let spec = match &spectrum {
        Some(p) => Spectrum::parse(
            &std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?,
        )
        .with_context(|| format!("spectrum {}", p.display()))?,
        None => Spectrum::mono(energy)?,
    };
    let scene = tg195::scene(voxel)?;
    let src = tg195::source(angle, spec);
    let t = Instant::now();
    let bar = dbt_cli::Progress::new(batches as u64, "TG-195 case 3", "batches", false);
    let r = run_observed(&scene, &src, photons, batches, seed, &|| bar.inc(1))?;
    bar.finish();
    let secs = t.elapsed().as_secs_f64();
    let (total, total_se) = r.per_photon(|t| t.deposited_kev[tg195::BREAST_M as usize] * 1e3);
    let vois: Vec<(f64, f64)> = (0..7)
        .map(|v| r.per_photon(|t| t.tally_kev[v] * 1e3))
        .collect();
    let threads = rayon::current_num_threads();
    let out = serde_json::json!({
        "case": "AAPM TG-195 case 3",
        "source": if spectrum.is_some() { serde_json::json!({"spectrum": spectrum}) } else { serde_json::json!({"energy_kev": energy}) },
        "angle_deg": angle,
        "photons": photons,
        "seconds": secs,
        "threads": threads,
        "photons_per_second_per_core": photons as f64 / secs / threads as f64,
        "voxel_mm": voxel,
        "total_ev_per_photon": total,
        "total_standard_error": total_se,
        "voi_ev_per_photon": vois.iter().map(|v| v.0).collect::<Vec<_>>(),
        "voi_standard_error": vois.iter().map(|v| v.1).collect::<Vec<_>>(),
        "reference_16_8_kev_0_deg": {
            "total_ev_per_photon": tg195::REF_TOTAL_EV,
            "voi_ev_per_photon": tg195::REF_VOI_EV,
        },
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}
