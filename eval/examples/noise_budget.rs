//! What the noise does to the corrected counts the network reads: the
//! diagnostic behind eval/README.md's "The clinical counts' noise".
//!
//! ```sh
//! cargo run --release -p dbt-eval --example noise_budget -- 8          # validation phantoms 0..8
//! cargo run --release -p dbt-eval --example noise_budget -- 8 W/Al
//! cargo run --release -p dbt-eval --example noise_budget -- 8 W/Rh match   # noise matched to N8
//! ```
//!
//! Each validation phantom (the calibration's: procedural, training seed
//! 2024, `paper-tall` binned x4) is acquired four times with the same seed:
//! mono-energetic and clinical (the beam's automatic exposure, scatter
//! without a grid), each at N8 and noise-free; the clinical counts are
//! corrected as the firmware corrects them (scatter removed, beam hardening
//! linearised). For every ray under the breast, `l = ln(b / c)` of the N8
//! counts is compared with the noise-free one of the same ray, grouped by
//! the noise-free `l`: the mean difference (the log's bias) and its
//! variance, and the variance a mono-energetic photon count at that `l`
//! would have (`exp(l) / b`).

use anyhow::{ensure, Context, Result};
use dbt_dose::xray::AnodeFilter;
use dbt_eval::accuracy::{split_phantoms, Split};
use dbt_forward::NoiseLevel;
use dbt_phantom::PopulationKind;
use dbt_pipeline::{correct_counts, PipelineOptions};
use host_sim::{simulate_on, Physics, Technique};

const BINS: [f64; 7] = [0.5, 1.5, 2.5, 3.0, 3.5, 4.0, 5.0];

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    ensure!(
        !args.is_empty(),
        "usage: noise_budget N_VALIDATION_PHANTOMS [W/Rh|W/Al]"
    );
    let n: usize = args[0].parse().context("the number of phantoms")?;
    let beam = AnodeFilter::parse(args.get(1).map_or("W/Rh", String::as_str))?;
    let g = dbt_geometry::Geometry::builtin("paper-tall")
        .context("paper-tall")?
        .binned(4)?;
    let matched = args.get(2).map(String::as_str) == Some("match");
    let opts = PipelineOptions {
        descatter: Some(dbt_pipeline::descatter::ScatterRemoval::shipped()?),
        linearise: Some(dbt_pipeline::linearise::BeamHardening::csi(200.0)?),
        noise_match: if matched {
            Some(dbt_pipeline::noise_match::NoiseMatch::to_photons(
                NoiseLevel::Poisson(8).flux(),
            )?)
        } else {
            None
        },
        ..Default::default()
    };
    let tech = Technique {
        anode_filter: beam,
        ..Default::default()
    };
    let root = "1.2.826.0.1.3680043.10.543.3";
    // Per bin of the noise-free l: [rays, sum d, sum d^2, sum exp(l)/b].
    let mut acc = [[[0f64; 4]; BINS.len()]; 2];
    println!(
        "{beam}, validation phantoms 0..{n}, N8 against noise-free, rays under the breast{}",
        if matched {
            "; clinical noise matched to N8"
        } else {
            ""
        }
    );
    for (k, p) in split_phantoms(
        &g,
        Split::Validation { seed: 2024 },
        PopulationKind::Procedural,
        n,
    )
    .enumerate()
    {
        let (name, vol) = p?;
        let kvp = f64::from(beam.aec_kv(vol.thickness_mm()));
        let seed = k as u64 + 1;
        for (i, physics) in [Physics::Mono, Physics::parse("clinical")?]
            .into_iter()
            .enumerate()
        {
            let acq = |noise| -> Result<_> {
                let a = simulate_on(&vol, &g, None, noise, physics, seed, tech, kvp, "NB", root)?
                    .into_sinograms()?;
                Ok(if i == 1 {
                    correct_counts(&a, &opts)?.into_owned()
                } else {
                    a
                })
            };
            let noisy = acq(NoiseLevel::Poisson(8))?;
            // The noise-free reference is never matched (no noise to
            // measure on its open field).
            let clean = {
                let a = simulate_on(
                    &vol,
                    &g,
                    None,
                    NoiseLevel::NoiseFree,
                    physics,
                    seed,
                    tech,
                    kvp,
                    "NB",
                    root,
                )?
                .into_sinograms()?;
                if i == 1 {
                    let o = PipelineOptions {
                        noise_match: None,
                        ..opts.clone()
                    };
                    correct_counts(&a, &o)?.into_owned()
                } else {
                    a
                }
            };
            let (bn, bc) = (noisy.header.flux, clean.header.flux);
            for (rn, rc) in noisy.counts.iter().zip(&clean.counts) {
                for (&cn, &cc) in rn.iter().zip(rc) {
                    let lc = (bc / f64::from(cc)).ln();
                    if !(cn > 0.0 && cc > 0.0 && lc > BINS[0]) {
                        continue;
                    }
                    let d = (bn / f64::from(cn)).ln() - lc;
                    let j = BINS.iter().rposition(|&b| lc >= b).unwrap_or(0);
                    let a = &mut acc[i][j];
                    a[0] += 1.0;
                    a[1] += d;
                    a[2] += d * d;
                    a[3] += lc.exp() / bn;
                }
            }
        }
        println!("  {name}: T {:.1} mm", vol.thickness_mm());
    }
    println!("| noise-free l | rays (mono / clinical) | log bias, mono / clinical | variance, mono / clinical | Poisson variance at l (1/counts) | clinical / mono variance |");
    println!("|---|---|---|---|---|---|");
    for j in 0..BINS.len() {
        let [m, c] = [acc[0][j], acc[1][j]];
        if m[0] < 100.0 || c[0] < 100.0 {
            continue;
        }
        let stat = |a: [f64; 4]| {
            let mean = a[1] / a[0];
            (mean, a[2] / a[0] - mean * mean, a[3] / a[0])
        };
        let ((bm, vm, pm), (bcl, vc, _)) = (stat(m), stat(c));
        let hi = BINS.get(j + 1).map_or("".to_string(), |h| format!("{h}"));
        println!(
            "| {}-{hi} | {} / {} | {bm:+.5} / {bcl:+.5} | {vm:.5} / {vc:.5} | {pm:.5} | {:.2} |",
            BINS[j],
            m[0],
            c[0],
            vc / vm
        );
    }
    Ok(())
}
