//! Why the classified gland of a fatty breast gathers at the compressed
//! surfaces (eval/README.md, "Where a fatty breast's dose reads high"):
//! the reconstruction's attenuation in the truth's adipose tissue, layer by
//! layer of height, against where the classifier splits fat from gland.
//! A layer whose fat reads denser on average (a bias) or more spread (noise)
//! has more of it classified gland; which of the two tells where a mend
//! belongs.
//!
//! ```sh
//! cargo run --release -p dbt-eval --example surface_attenuation -- models/dbtor-x4t3qa 12
//! cargo run --release -p dbt-eval --example surface_attenuation -- models/dbtor-x4t3qa 12 mono
//! ```
//!
//! Arguments: the model folder (int8, the firmware's precision), the
//! validation phantoms (comma separated: procedural, the manifest's training
//! seed, the model's geometry, as `dbt-eval accuracy --split validation`),
//! and `clinical` (the default: W/Rh at the automatic exposure's kV,
//! scatter removed, beam hardening linearised, noise matched to the model's
//! level, as the firmware ships) or `mono` (the mono-energetic N8
//! acquisition the network was trained on). One acquisition per phantom
//! (N8, seed 1), processed by the firmware's pipeline; the truth's labels
//! on the reconstruction's grid.
//!
//! Per voxel layer of height (the reconstruction's rows, the support's
//! first): over the truth's adipose voxels that the classification keeps
//! out of the skin, their mean attenuation and its standard deviation
//! (both relative to the whole breast's adipose mean) and the share read
//! as gland; over the truth's fibroglandular voxels, their mean. The split
//! point is the firmware's fuzzy c-means boundary (`dbt_tissue::split_point`).

use anyhow::{ensure, Context, Result};
use dbt_dbtor::{Dbtor, Precision};
use dbt_eval::accuracy::{split_phantoms, Split};
use dbt_eval::classification::truth_on_grid;
use dbt_forward::NoiseLevel;
use dbt_materials::Tissue;
use dbt_phantom::PopulationKind;
use dbt_pipeline::noise_match::NoiseMatch;
use dbt_pipeline::{process, PipelineOptions};
use std::path::Path;
use std::sync::Arc;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    ensure!(
        args.len() >= 2,
        "usage: surface_attenuation MODEL PHANTOMS [clinical|mono]"
    );
    let model = Arc::new(Dbtor::load(Path::new(&args[0]), Precision::Int8)?);
    let wanted: Vec<usize> = args[1]
        .split(',')
        .map(|s| s.parse().with_context(|| format!("phantom {s:?}")))
        .collect::<Result<_>>()?;
    let clinical = match args.get(2).map_or("clinical", String::as_str) {
        "clinical" => true,
        "mono" => false,
        other => anyhow::bail!("{other:?}: clinical or mono"),
    };
    let g = model.geometry().clone();
    let seed = model.manifest().provenance["dataset_provenance"]["train_seed"]
        .as_u64()
        .context("the manifest names no training seed")?;
    let opts = PipelineOptions {
        dbtor: Some(model.clone()),
        dose_uncertainty: 0.2,
        seed: 1,
        descatter: clinical
            .then(dbt_pipeline::descatter::ScatterRemoval::shipped)
            .transpose()?,
        // The firmware's linearisation (`dbt-eval accuracy --linearise`).
        linearise: clinical.then_some(dbt_pipeline::linearise::BeamHardening {
            detector: Default::default(),
            path: dbt_pipeline::linearise::PathModel::Reference,
        }),
        noise_match: clinical
            .then(|| NoiseMatch::for_model(model.manifest()))
            .transpose()?,
        ..Default::default()
    };
    let physics = if clinical {
        host_sim::Physics::parse("clinical")?
    } else {
        host_sim::Physics::Mono
    };
    let beam = dbt_dose::xray::AnodeFilter::WRh;
    let last = wanted.iter().copied().max().unwrap_or(0);
    for (k, p) in split_phantoms(
        &g,
        Split::Validation { seed },
        PopulationKind::Procedural,
        last + 1,
    )
    .enumerate()
    {
        if !wanted.contains(&k) {
            continue;
        }
        let (name, vol) = p?;
        let kvp = f64::from(beam.aec_kv(vol.thickness_mm()));
        let tech = host_sim::Technique {
            anode_filter: beam,
            ..Default::default()
        };
        let acq = host_sim::simulate_on(
            &vol,
            &g,
            None,
            NoiseLevel::Poisson(8),
            physics,
            1,
            tech,
            kvp,
            "SURFACE",
            "1.2.826.0.1.3680043.10.543.3",
        )?;
        let res = process(&acq, &opts)?;
        let truth = truth_on_grid(&vol, &g, res.dims)?;
        let labels = &res.classification.labels;
        let split = dbt_tissue::split_point(res.classification.centres);
        let [nx, ny, nz] = res.dims;
        let (fat, gland) = (Tissue::Adipose.label(), Tissue::Fibroglandular.label());
        // Per layer: [fat n, sum mu, sum mu^2, read gland, gland n, sum mu].
        let mut acc = vec![[0f64; 6]; ny];
        for z in 0..nz {
            for (y, a) in acc.iter_mut().enumerate() {
                for x in 0..nx {
                    let i = (z * ny + y) * nx + x;
                    let (t, l, m) = (truth[i], labels[i], f64::from(res.mu[i]));
                    if t == fat && (l == fat || l == gland) {
                        a[0] += 1.0;
                        a[1] += m;
                        a[2] += m * m;
                        a[3] += f64::from(u8::from(l == gland));
                    } else if t == gland && (l == fat || l == gland) {
                        a[4] += 1.0;
                        a[5] += m;
                    }
                }
            }
        }
        let all_fat = acc
            .iter()
            .fold([0f64; 2], |s, a| [s[0] + a[0], s[1] + a[1]]);
        ensure!(all_fat[0] > 0.0, "{name}: no adipose voxel");
        let fat_mean = all_fat[1] / all_fat[0];
        println!(
            "\n{name}: {:.1} mm, {:.1} % glandular, {}; fuzzy c-means centres {:.5} / {:.5} 1/mm, split {:.5} ({:+.1} % of the adipose mean {:.5}); true gland's attenuation {:.5} nominal",
            vol.thickness_mm(),
            100.0 * vol.glandularity().unwrap_or(0.0),
            if clinical { "clinical, noise matched" } else { "mono-energetic" },
            res.classification.centres[0],
            res.classification.centres[1],
            split,
            100.0 * (split / fat_mean - 1.0),
            fat_mean,
            Tissue::Fibroglandular.mu_per_mm(),
        );
        println!("| layer (height, mm) | adipose voxels | adipose mean - breast's adipose mean (%) | adipose sd (% of its mean) | adipose read as gland (%) | gland voxels | gland mean - adipose mean (%) |");
        println!("|---|---|---|---|---|---|---|");
        let vox = res.voxel_mm;
        for (y, a) in acc.iter().enumerate() {
            if a[0] < 1.0 {
                continue;
            }
            let mean = a[1] / a[0];
            let sd = (a[2] / a[0] - mean * mean).max(0.0).sqrt();
            let g_mean = if a[4] > 0.0 {
                format!("{:+.1}", 100.0 * (a[5] / a[4] / fat_mean - 1.0))
            } else {
                "-".into()
            };
            println!(
                "| {} ({:.1}-{:.1}) | {} | {:+.2} | {:.1} | {:.2} | {} | {} |",
                y + 1,
                y as f64 * vox,
                (y + 1) as f64 * vox,
                a[0],
                100.0 * (mean / fat_mean - 1.0),
                100.0 * sd / mean,
                100.0 * a[3] / a[0],
                a[4],
                g_mean
            );
        }
    }
    Ok(())
}
