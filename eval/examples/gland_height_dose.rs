//! How much the patient MGD depends on where a little gland lies in height
//! (eval/README.md, "Where a fatty breast's dose reads high"): one
//! validation phantom's own labels, and the same labels with `V` cm^3 of
//! adipose tissue made fibroglandular in one 10 mm band of height, evenly
//! spread over the band's adipose voxels; each through the dose engine
//! (patient-specific model, the paper's gantry, the W/Rh beam at the
//! automatic exposure's kV), MGD per unit incident air kerma.
//!
//! ```sh
//! cargo run --release -p dbt-eval --example gland_height_dose -- 12 2.2 0,30,60
//! ```
//!
//! Arguments: the validation phantom (procedural, training seed 2024, the
//! `paper-tall` geometry binned x4, as `dbt-eval accuracy --split
//! validation`), the volume to add (cm^3), and the bands' lower edges (mm
//! above the support).

use anyhow::{ensure, Context, Result};
use dbt_dose::patient::{mgd_to_uncertainty_on, Breast, DoseGeometry, Model};
use dbt_dose::xray::{aec_spectrum, AnodeFilter};
use dbt_eval::accuracy::{split_phantoms, Split};
use dbt_materials::Tissue;
use dbt_phantom::PopulationKind;

const BAND_MM: f64 = 10.0;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let k: usize = args
        .first()
        .map_or(Ok(12), |s| s.parse())
        .context("the phantom")?;
    let add_cm3: f64 = args
        .get(1)
        .map_or(Ok(2.2), |s| s.parse())
        .context("the volume")?;
    let bands: Vec<f64> = args
        .get(2)
        .map_or("0,30,60", String::as_str)
        .split(',')
        .map(|s| s.parse::<f64>().with_context(|| format!("band {s}")))
        .collect::<Result<_>>()?;
    ensure!(add_cm3 > 0.0, "the volume to add must be positive");
    let g = dbt_geometry::Geometry::builtin("paper-tall")
        .context("paper-tall")?
        .binned(4)?;
    let (name, vol) = split_phantoms(
        &g,
        Split::Validation { seed: 2024 },
        PopulationKind::Procedural,
        k + 1,
    )
    .nth(k)
    .context("no such phantom")??;
    let spec = aec_spectrum(AnodeFilter::WRh, vol.thickness_mm())?
        .spectrum
        .context("no spectrum")?;
    let [nx, ny, _] = vol.dims();
    let vox = vol.voxel_mm();
    let per_voxel_cm3 = vox.powi(3) / 1000.0;
    let mgd = |labels: &[u8]| -> Result<f64> {
        let b = Breast {
            dims: vol.dims(),
            voxel_mm: vox,
            labels,
        };
        let m = mgd_to_uncertainty_on(
            &DoseGeometry::paper(),
            &b,
            Model::PatientSpecific,
            &spec,
            0.01,
            200_000,
            200_000_000,
            7,
        )?;
        Ok(m.mgd_per_kerma)
    };
    let base = mgd(vol.labels())?;
    println!(
        "{name}: {:.1} mm, glandularity {:.1} %; MGD per kerma {base:.4} (own labels)",
        vol.thickness_mm(),
        100.0 * vol.glandularity().unwrap_or(0.0)
    );
    println!("| gland added, cm^3 | band (mm above the support) | MGD per kerma | change |\n|---|---|---|---|");
    for lo in bands {
        // The band's adipose voxels (vertical index from the support).
        let idx: Vec<usize> = (0..vol.labels().len())
            .filter(|&i| {
                let h = ((i / nx) % ny) as f64 * vox + 0.5 * vox;
                h >= lo && h < lo + BAND_MM && vol.labels()[i] == Tissue::Adipose.label()
            })
            .collect();
        let want = (add_cm3 / per_voxel_cm3).round() as usize;
        ensure!(
            want <= idx.len(),
            "band {lo} mm holds {} cm^3 of adipose tissue, fewer than {add_cm3}",
            idx.len() as f64 * per_voxel_cm3
        );
        let mut labels = vol.labels().to_vec();
        for j in 0..want {
            labels[idx[j * idx.len() / want]] = Tissue::Fibroglandular.label();
        }
        let m = mgd(&labels)?;
        println!(
            "| {:.2} | {lo:.0}-{:.0} | {m:.4} | {:+.1} % |",
            want as f64 * per_voxel_cm3,
            lo + BAND_MM,
            100.0 * (m / base - 1.0)
        );
    }
    Ok(())
}
