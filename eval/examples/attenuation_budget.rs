//! Where a reconstruction puts the phantom's attenuation, and what that does
//! to the partial-volume glandularity: the diagnostic behind eval/README.md's
//! explanation of the VICTRE gap.
//!
//! ```sh
//! cargo run --release -p dbt-eval --example attenuation_budget -- MODEL victre [N8]
//! cargo run --release -p dbt-eval --example attenuation_budget -- MODEL 2 [N8]   # test phantoms 0..2
//! ```
//!
//! Each phantom is acquired (noise-free unless `N8`) and reconstructed by
//! MLTR (100 iterations) and by DBToR fp32 (`MODEL`) with the firmware's
//! reconstruction step. For each, against the truth on the same grid:
//! - the total attenuation (data consistency: 1 for a reconstruction that
//!   fits the data and puts nothing outside the image);
//! - the partial-volume glandularity with the **truth's** labels (the
//!   reconstruction's error alone) and with its own (the firmware's);
//! - the mean attenuation under each true tissue;
//! - by coronal slice, grouped by how much of the box "compressed thickness
//!   x the breast's lateral extent" the breast fills: the attenuation error of
//!   the non-skin breast tissue and the attenuation found in the air inside
//!   the box, both relative to that tissue's true attenuation.

use anyhow::{ensure, Context, Result};
use dbt_dbtor::{Dbtor, Precision};
use dbt_eval::accuracy::{split_phantoms, Split};
use dbt_eval::classification::{confusion, truth_on_grid};
use dbt_forward::NoiseLevel;
use dbt_phantom::{labels_to_mu, PopulationKind};
use dbt_pipeline::{reconstruct_volume, PipelineOptions};
use dbt_tissue::{classify, density, ClassifyOptions};
use host_sim::{simulate_acquisition, Technique};
use std::path::Path;
use std::sync::Arc;

const FILL_BINS: [&str; 4] = ["fill < 0.7", "0.7 - 0.8", "0.8 - 0.9", ">= 0.9"];

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    ensure!(
        args.len() >= 2,
        "usage: attenuation_budget MODEL (victre | N_TEST_PHANTOMS) [N8]"
    );
    let model = Arc::new(Dbtor::load(Path::new(&args[0]), Precision::Fp32)?);
    let g = model.geometry().clone();
    let noise = match args.get(2).map(String::as_str) {
        None => NoiseLevel::NoiseFree,
        Some(n) => NoiseLevel::parse(n)?,
    };
    let phantoms = if args[1] == "victre" {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../phantoms/victre-pc1.toml");
        let v = dbt_store::load_external_phantom(&p)?.resampled(g.image.pixel_mm)?;
        vec![("VICTRE pc_1".to_string(), v)]
    } else {
        let n: usize = args[1].parse().context("the number of test phantoms")?;
        split_phantoms(&g, Split::Test, PopulationKind::Procedural, n)
            .collect::<Result<Vec<_>>>()?
    };
    let vox = g.image.pixel_mm;
    for (name, vol) in phantoms {
        let acq = simulate_acquisition(
            &vol,
            &g,
            noise,
            1,
            Technique::default(),
            28.0,
            "BUDGET",
            "1.2.826.0.1.3680043.10.543.3",
        )?
        .into_sinograms()?;
        let dims = [
            g.image.columns,
            g.rows_within_thickness(vol.thickness_mm()),
            vol.n_coronal(),
        ];
        let truth = truth_on_grid(&vol, &g, dims)?;
        let mu_t = labels_to_mu(&truth);
        let breast = truth.iter().filter(|&&l| l != 0).count() as f64;
        let skin = truth.iter().filter(|&&l| l == 2).count() as f64;
        println!(
            "{name}: T {:.1} mm, G {:.4}, {}; skin {:.1} % of the breast voxels",
            vol.thickness_mm(),
            vol.glandularity().unwrap_or(0.0),
            noise.name(),
            100.0 * skin / breast
        );
        print_outline(&truth, dims, vox);
        for (rname, dbtor) in [("MLTR", None), ("DBToR fp32", Some(model.clone()))] {
            let opts = PipelineOptions {
                dbtor,
                mltr_iterations: 100,
                dose_uncertainty: 0.2,
                seed: 1,
                classify: ClassifyOptions::default(),
                slice_step: 1,
                ..Default::default()
            };
            let v = reconstruct_volume(&acq, &opts, &mut |_| {})?;
            ensure!(v.dims == dims, "volume {:?} against {:?}", v.dims, dims);
            report(rname, &v.mu, &mu_t, &truth, dims, vox)?;
        }
    }
    Ok(())
}

/// The breast's extent in every tenth of its coronal slices (depth from the
/// chest wall), against the compressed thickness.
fn print_outline(truth: &[u8], dims: [usize; 3], vox: f64) {
    let [cols, nv, nd] = dims;
    for d in (0..nd).step_by(nd.div_ceil(10).max(1)) {
        let s = &truth[d * nv * cols..(d + 1) * nv * cols];
        let rows: Vec<usize> = (0..nv)
            .filter(|&v| s[v * cols..(v + 1) * cols].iter().any(|&l| l != 0))
            .collect();
        let c: Vec<usize> = (0..cols)
            .filter(|&x| (0..nv).any(|v| s[v * cols + x] != 0))
            .collect();
        if let (Some(r0), Some(r1), Some(c0), Some(c1)) =
            (rows.first(), rows.last(), c.first(), c.last())
        {
            println!(
                "    depth {:5.1} mm: breast {:5.1} mm wide, {:4.1} mm tall (rows {r0}..={r1} of {nv} under the paddle)",
                d as f64 * vox,
                (c1 - c0 + 1) as f64 * vox,
                (r1 - r0 + 1) as f64 * vox
            );
        }
    }
}

fn report(
    name: &str,
    mu: &[f32],
    mu_t: &[f32],
    truth: &[u8],
    dims: [usize; 3],
    vox: f64,
) -> Result<()> {
    let sum = |v: &[f32]| v.iter().map(|&x| x as f64).sum::<f64>();
    let with_truth = density(mu, truth, vox);
    let c = classify(mu, dims, vox, &ClassifyOptions::default())?;
    let own = density(mu, &c.labels, vox);
    println!(
        "  {name}: total attenuation / truth's {:.4}; PV glandularity with the truth's labels {:.4}, with its own {:.4} (label estimate {:.4})",
        sum(mu) / sum(mu_t),
        with_truth.glandularity_partial_volume,
        own.glandularity_partial_volume,
        own.glandularity_labels
    );
    let mut by = [(0f64, 0f64, 0u64); 5];
    for ((&r, &t), &l) in mu.iter().zip(mu_t).zip(truth) {
        let k = (l as usize).min(4);
        by[k].0 += r as f64;
        by[k].1 += t as f64;
        by[k].2 += 1;
    }
    for (k, tname) in ["air", "adipose", "skin", "fibroglandular", "ligament"]
        .iter()
        .enumerate()
    {
        let (r, t, n) = by[k];
        if n > 0 {
            println!(
                "    under true {tname:14}: mean mu {:.5} /mm (truth {:.5}), {n} voxels",
                r / n as f64,
                t / n as f64
            );
        }
    }
    // (error in non-skin tissue, its true attenuation, attenuation in air, tissue voxels)
    let mut bins = [(0f64, 0f64, 0f64, 0u64); 4];
    let [cols, nv, nd] = dims;
    for d in 0..nd {
        let s = d * nv * cols..(d + 1) * nv * cols;
        let (mut lo, mut hi, mut n) = (cols, 0, 0usize);
        for (i, &l) in truth[s.clone()].iter().enumerate() {
            if l != 0 {
                lo = lo.min(i % cols);
                hi = hi.max(i % cols);
                n += 1;
            }
        }
        if n == 0 {
            continue;
        }
        let fill = n as f64 / ((hi - lo + 1) * nv) as f64;
        let b = &mut bins[match fill {
            f if f < 0.7 => 0,
            f if f < 0.8 => 1,
            f if f < 0.9 => 2,
            _ => 3,
        }];
        for i in s {
            match truth[i] {
                0 => b.2 += mu[i] as f64,
                2 => {}
                _ => {
                    b.0 += (mu[i] - mu_t[i]) as f64;
                    b.1 += mu_t[i] as f64;
                    b.3 += 1;
                }
            }
        }
    }
    for (k, bname) in FILL_BINS.iter().enumerate() {
        let (e, t, a, n) = bins[k];
        if n > 0 {
            println!(
                "    slices {bname:10}: {n:8} tissue voxels, tissue attenuation {:+6.2} %, in the air of the box {:5.2} %",
                100.0 * e / t,
                100.0 * a / t
            );
        }
    }
    println!(
        "    confusion (rows true air, adipose, skin, fibroglandular): {:?}",
        confusion(truth, &c.labels)
    );
    Ok(())
}
