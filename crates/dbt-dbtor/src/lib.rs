//! The DBToR runtime: a trained model folder (`models/<name>/`, written by
//! `training/dbtor/export.py`) is loaded, every file's SHA-256 is checked
//! against the manifest, the 2 x N blocks are loaded with tract-onnx, and the
//! unrolled primal-dual loop of the paper's Algorithm 1 runs with the Rust
//! projector.
//!
//! Conventions (written down in `training/dbtor/model.py` and in each model's
//! manifest): 5 state channels in both spaces, initialised to zero; the dual
//! block `i` sees `[h, P(f[1]), g_n, P(m)]`, the primal block `[f, P*(h[0]), m]`;
//! every block file computes `state + net(cat(state, aux))`; the network's
//! operator is `P / ||P||`; `g_n = (g - g_mean) / g_std`; the output is
//! `f[0] * x_scale` in 1/mm.

mod fixtures;
mod manifest;

pub use fixtures::{check_fixtures, FixtureCheck, FP32_TOL_NETWORK_UNITS};

pub use manifest::{sha256_file, BlockEntry, Fixture, ModelManifest, Normalisation, Role, FORMAT};

use dbt_geometry::Geometry;
use dbt_projector::Projector;
use std::path::{Path, PathBuf};
use tract_onnx::prelude::*;

/// Errors of the runtime.
#[derive(Debug, thiserror::Error)]
pub enum DbtorError {
    /// A file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The manifest is malformed or inconsistent.
    #[error("{path}: {reason}")]
    Manifest {
        /// The manifest.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A model file's checksum differs from the manifest.
    #[error("{path}: SHA-256 is {found}, the manifest says {expected}: the file was modified or corrupted; refusing to load the model")]
    Checksum {
        /// The file.
        path: PathBuf,
        /// From the manifest.
        expected: String,
        /// Computed.
        found: String,
    },
    /// tract could not load or run a block.
    #[error("{path}: {reason}")]
    Block {
        /// The block file.
        path: PathBuf,
        /// tract's message.
        reason: String,
    },
    /// The input does not fit the model.
    #[error("input: {0}")]
    Input(String),
}

/// Which version of the blocks to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// The exported fp32 graphs.
    Fp32,
    /// The static int8 (QDQ) graphs.
    Int8,
}

impl std::str::FromStr for Precision {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "fp32" => Ok(Self::Fp32),
            "int8" => Ok(Self::Int8),
            other => Err(format!("unknown precision {other:?} (fp32 or int8)")),
        }
    }
}

impl std::fmt::Display for Precision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Fp32 => "fp32",
            Self::Int8 => "int8",
        })
    }
}

type Plan = std::sync::Arc<TypedSimplePlan>;

/// A loaded, verified model ready to reconstruct slices.
pub struct Dbtor {
    manifest: ModelManifest,
    root: PathBuf,
    precision: Precision,
    projector: Projector,
    /// In execution order: dual 0, primal 0, dual 1, ..., with the file each
    /// was loaded from (for error messages).
    plans: Vec<(Plan, PathBuf)>,
}

impl std::fmt::Debug for Dbtor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Dbtor")
            .field("model", &self.manifest.name)
            .field("root", &self.root)
            .field("precision", &self.precision)
            .field("blocks", &self.plans.len())
            .finish()
    }
}

impl Dbtor {
    /// Load the model in `dir` (manifest.json and the files it names), verify
    /// every checksum, and prepare the blocks of `precision` for the model's
    /// geometry.
    pub fn load(dir: &Path, precision: Precision) -> Result<Self, DbtorError> {
        let manifest = ModelManifest::load(dir)?;
        manifest.verify_files(dir)?;
        let g = &manifest.geometry;
        let (rows, cols) = (g.image.rows, g.image.columns);
        let (views, det) = (g.n_views(), g.n_det());
        let c = manifest.state_channels;
        let mut plans = Vec::with_capacity(manifest.blocks.len());
        for b in &manifest.blocks {
            let rel = match precision {
                Precision::Fp32 => &b.fp32,
                Precision::Int8 => &b.int8,
            };
            let path = dir.join(rel);
            let (h, w) = match b.role {
                Role::Dual => (views, det),
                Role::Primal => (rows, cols),
            };
            let fail = |e: TractError| DbtorError::Block {
                path: path.clone(),
                reason: format!("{e:#}"),
            };
            let plan = tract_onnx::onnx()
                .model_for_path(&path)
                .map_err(fail)?
                .with_input_fact(0, f32::fact([1, c, h, w]).into())
                .map_err(fail)?
                .with_input_fact(1, f32::fact([1, b.aux_channels, h, w]).into())
                .map_err(fail)?
                .into_optimized()
                .map_err(fail)?
                .into_runnable()
                .map_err(fail)?;
            plans.push((plan, path));
        }
        tracing::info!(model = %manifest.name, %precision, blocks = plans.len(), "DBToR model loaded");
        Ok(Self {
            projector: Projector::new(g),
            manifest,
            root: dir.to_path_buf(),
            precision,
            plans,
        })
    }

    /// The manifest.
    pub fn manifest(&self) -> &ModelManifest {
        &self.manifest
    }

    /// The model's geometry (the grid of its input sinogram and output image).
    pub fn geometry(&self) -> &Geometry {
        &self.manifest.geometry
    }

    /// The precision the blocks run in.
    pub fn precision(&self) -> Precision {
        self.precision
    }

    fn run_block(
        &self,
        k: usize,
        state: &[f32],
        aux: &[f32],
        shape: (usize, usize),
    ) -> Result<Vec<f32>, DbtorError> {
        let b = &self.manifest.blocks[k];
        let c = self.manifest.state_channels;
        let (h, w) = shape;
        let (plan, file) = &self.plans[k];
        let path = || file.clone();
        let fail = |e: TractError| DbtorError::Block {
            path: path(),
            reason: format!("{e:#}"),
        };
        let st = Tensor::from_shape(&[1, c, h, w], state).map_err(fail)?;
        let ax = Tensor::from_shape(&[1, b.aux_channels, h, w], aux).map_err(fail)?;
        let out = plan.run(tvec![st.into(), ax.into()]).map_err(fail)?;
        let view = out[0].to_plain_array_view::<f32>().map_err(fail)?;
        if view.len() != c * h * w {
            return Err(DbtorError::Block {
                path: path(),
                reason: format!("output has {} values, expected {}", view.len(), c * h * w),
            });
        }
        Ok(view.iter().copied().collect())
    }

    /// Reconstruct one coronal slice from its log-transformed sinogram `g`
    /// (`ln(b / y)`, view-major, on the model's geometry) and the compressed
    /// thickness. Returns attenuation in 1/mm, row-major on the model's image.
    pub fn reconstruct(&self, g: &[f32], thickness_mm: f64) -> Result<Vec<f32>, DbtorError> {
        let geom = &self.manifest.geometry;
        let n_img = geom.n_pixels();
        let n_sino = geom.n_rays();
        if g.len() != n_sino {
            return Err(DbtorError::Input(format!(
                "sinogram has {} samples, the model's geometry needs {} ({} views x {} elements)",
                g.len(),
                n_sino,
                geom.n_views(),
                geom.n_det()
            )));
        }
        if let Some(i) = g.iter().position(|v| !v.is_finite()) {
            return Err(DbtorError::Input(format!(
                "sinogram sample {i} is not finite ({})",
                g[i]
            )));
        }
        if !(thickness_mm.is_finite() && thickness_mm > 0.0) {
            return Err(DbtorError::Input(format!(
                "thickness {thickness_mm} mm is not a positive number"
            )));
        }
        let n = &self.manifest.normalisation;
        let c = self.manifest.state_channels;
        let ch = &self.manifest.channels;
        let inv_norm = (1.0 / n.operator_norm) as f32;
        let (g_mean, g_std) = (n.g_mean as f32, n.g_std as f32);
        let gn: Vec<f32> = g.iter().map(|&v| (v - g_mean) / g_std).collect();
        let mask = dbt_phantom::thickness_mask(geom, thickness_mm);
        let mut pm = vec![0.0f32; n_sino];
        self.project(&mask, &mut pm, inv_norm)?;

        let mut h = vec![0.0f32; c * n_sino];
        let mut f = vec![0.0f32; c * n_img];
        let mut aux_d = vec![0.0f32; 3 * n_sino];
        let mut aux_p = vec![0.0f32; 2 * n_img];
        aux_d[n_sino..2 * n_sino].copy_from_slice(&gn);
        aux_d[2 * n_sino..].copy_from_slice(&pm);
        aux_p[n_img..].copy_from_slice(&mask);
        let sino_shape = (geom.n_views(), geom.n_det());
        let img_shape = (geom.image.rows, geom.image.columns);
        for (k, b) in self.manifest.blocks.iter().enumerate() {
            let _s = tracing::trace_span!("block", role = ?b.role, index = b.index).entered();
            match b.role {
                Role::Dual => {
                    let fc = &f[ch.projected * n_img..(ch.projected + 1) * n_img];
                    let (pf, _) = aux_d.split_at_mut(n_sino);
                    self.project(fc, pf, inv_norm)?;
                    h = self.run_block(k, &h, &aux_d, sino_shape)?;
                }
                Role::Primal => {
                    let hc = &h[ch.backprojected * n_sino..(ch.backprojected + 1) * n_sino];
                    let (bh, _) = aux_p.split_at_mut(n_img);
                    self.backproject(hc, bh, inv_norm)?;
                    f = self.run_block(k, &f, &aux_p, img_shape)?;
                }
            }
        }
        let xs = n.x_scale_per_mm as f32;
        Ok(f[ch.output * n_img..(ch.output + 1) * n_img]
            .iter()
            .map(|v| v * xs)
            .collect())
    }

    fn project(&self, img: &[f32], out: &mut [f32], scale: f32) -> Result<(), DbtorError> {
        self.projector
            .forward(img, out)
            .map_err(|e| DbtorError::Input(e.to_string()))?;
        out.iter_mut().for_each(|v| *v *= scale);
        Ok(())
    }

    fn backproject(&self, sino: &[f32], out: &mut [f32], scale: f32) -> Result<(), DbtorError> {
        self.projector
            .adjoint(sino, out)
            .map_err(|e| DbtorError::Input(e.to_string()))?;
        out.iter_mut().for_each(|v| *v *= scale);
        Ok(())
    }
}
