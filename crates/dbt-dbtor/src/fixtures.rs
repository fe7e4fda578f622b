//! Equivalence of this runtime with the exporter's references, on the fixtures
//! stored in the model folder (the firmware's self-test and the CI's
//! equivalence test both call this).
//!
//! Tolerances:
//! - fp32 against PyTorch: max abs difference below 1e-4 in the network's image
//!   unit (`x_scale`, about 0.04 /mm, so a few 1e-6 /mm). Both compute the same
//!   graph and differ only in summation order (CSR vs matrix-free projector,
//!   MKL vs tract convolutions): about 1e-6 relative per step over 20 blocks.
//! - int8 against onnxruntime on the same QDQ files (tract's and the fast
//!   path's integer kernels alike). The runtimes may
//!   round a requantised activation one step apart (and such a step then
//!   travels through the later blocks), so they are not compared to each
//!   other directly but by their distance to the fp32 network they
//!   approximate: RMS(tract int8 - PyTorch fp32) at most 1.5 x
//!   RMS(ort int8 - PyTorch fp32), and tract's RMS error to the phantom within
//!   5 % of onnxruntime's. The int8-vs-fp32 loss itself is measured by the
//!   evaluation table (`dbt-eval baselines --model`).

use crate::{Dbtor, DbtorError, Precision};
use serde::Serialize;
use std::path::Path;

/// fp32 tolerance, network image units.
pub const FP32_TOL_NETWORK_UNITS: f64 = 1e-4;

/// The result for one fixture.
#[derive(Debug, Clone, Serialize)]
pub struct FixtureCheck {
    /// Fixture name.
    pub name: String,
    /// Precision run.
    pub precision: Precision,
    /// Executor.
    pub engine: crate::Engine,
    /// Max abs difference to the reference of that precision, 1/mm.
    pub max_abs_per_mm: f64,
    /// RMS difference to that reference, 1/mm.
    pub rms_per_mm: f64,
    /// RMS difference to the phantom, 1/mm.
    pub rms_to_truth_per_mm: f64,
    /// Within tolerance.
    pub pass: bool,
    /// The rule applied, with its numbers.
    pub rule: String,
}

fn read_f32(path: &Path, n: usize) -> Result<Vec<f32>, DbtorError> {
    let b = std::fs::read(path).map_err(|source| DbtorError::Io {
        path: path.to_path_buf(),
        cause: source,
    })?;
    if b.len() != 4 * n {
        return Err(DbtorError::Manifest {
            path: path.to_path_buf(),
            reason: format!("{} bytes, expected {} ({n} f32)", b.len(), 4 * n),
        });
    }
    Ok(b.chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect())
}

fn max_abs(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs() as f64)
        .fold(0.0, f64::max)
}

fn rms(a: &[f32], b: &[f32]) -> f64 {
    (a.iter()
        .zip(b)
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        / a.len().max(1) as f64)
        .sqrt()
}

/// Reconstruct every fixture of `model` (loaded from `dir`) and compare.
pub fn check_fixtures(model: &Dbtor, dir: &Path) -> Result<Vec<FixtureCheck>, DbtorError> {
    let g = model.geometry();
    let (n_sino, n_img) = (g.n_rays(), g.n_pixels());
    let xs = model.manifest().normalisation.x_scale_per_mm;
    let mut out = Vec::new();
    for fx in &model.manifest().fixtures {
        let file = |k: &str| {
            fx.files
                .get(k)
                .map(|f| dir.join(f))
                .ok_or_else(|| DbtorError::Manifest {
                    path: dir.join("manifest.json"),
                    reason: format!("fixture {} has no {k} file", fx.name),
                })
        };
        let sino = read_f32(&file("sinogram")?, n_sino)?;
        let truth = read_f32(&file("truth")?, n_img)?;
        let fp32 = read_f32(&file("torch_fp32")?, n_img)?;
        let x = model.network_output(&sino, fx.thickness_mm)?;
        let check = match model.precision() {
            Precision::Fp32 => {
                let d = max_abs(&x, &fp32);
                FixtureCheck {
                    name: fx.name.clone(),
                    precision: Precision::Fp32,
                    engine: model.engine(),
                    max_abs_per_mm: d,
                    rms_per_mm: rms(&x, &fp32),
                    rms_to_truth_per_mm: rms(&x, &truth),
                    pass: d / xs < FP32_TOL_NETWORK_UNITS,
                    rule: format!(
                        "max |{} - PyTorch| = {:.2e} network units < {FP32_TOL_NETWORK_UNITS:.0e}",
                        model.engine(),
                        d / xs
                    ),
                }
            }
            Precision::Int8 => {
                let ort = read_f32(&file("ort_int8")?, n_img)?;
                let (d_tract, d_ort) = (rms(&x, &fp32), rms(&ort, &fp32));
                let (e_tract, e_ort) = (rms(&x, &truth), rms(&ort, &truth));
                FixtureCheck {
                    name: fx.name.clone(),
                    precision: Precision::Int8,
                    engine: model.engine(),
                    max_abs_per_mm: max_abs(&x, &ort),
                    rms_per_mm: rms(&x, &ort),
                    rms_to_truth_per_mm: e_tract,
                    pass: d_tract <= 1.5 * d_ort && e_tract <= 1.05 * e_ort,
                    rule: format!(
                        "RMS to fp32: {} int8 {d_tract:.2e} vs ort int8 {d_ort:.2e} /mm (limit 1.5x); error to phantom {e_tract:.3e} vs ort's {e_ort:.3e} /mm (limit 1.05x)",
                        model.engine()
                    ),
                }
            }
        };
        out.push(check);
    }
    Ok(out)
}
