//! The U-Net baseline of the paper (post-processing of FBP reconstructions),
//! for the evaluation only (it is not part of the gantry's runtime,
//! `dbt-dbtor`, which the firmware links): a model folder written by `training/dbtor/export_unet.py`
//! (`manifest.json`, format `dbtor-unet/1`, and one ONNX file), checksums
//! verified, run with tract-onnx. The network takes the FBP in units of the
//! manifest's `x_scale_per_mm` and returns the image in the same unit.

use dbt_dbtor::{verify_checksums, DbtorError};
use dbt_geometry::Geometry;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use tract_onnx::prelude::*;

/// Format tag of a U-Net model folder.
pub const UNET_FORMAT: &str = "dbtor-unet/1";

/// Normalisation of the U-Net's input and output.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UnetNormalisation {
    /// Image unit of the network, 1/mm.
    pub x_scale_per_mm: f64,
}

/// A stored test case: `fbp`, `truth`, `torch_fp32` (raw little-endian f32).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UnetFixture {
    /// Case name.
    pub name: String,
    /// Files by role, relative to the model folder.
    pub files: BTreeMap<String, String>,
}

/// `manifest.json` of a U-Net model folder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UnetManifest {
    /// [`UNET_FORMAT`].
    pub format: String,
    /// Model name.
    pub name: String,
    /// `unet`.
    pub kind: String,
    /// Geometry (the image grid of the input FBP and the output).
    pub geometry: Geometry,
    /// The ONNX file, relative to the folder.
    pub file: String,
    /// Normalisation.
    pub normalisation: UnetNormalisation,
    /// Equivalence fixtures.
    #[serde(default)]
    pub fixtures: Vec<UnetFixture>,
    /// SHA-256 (hex) of every file, by relative path.
    pub sha256: BTreeMap<String, String>,
    /// How the model was made.
    #[serde(default)]
    pub provenance: serde_json::Value,
    /// Validation recorded at export.
    #[serde(default)]
    pub validation: serde_json::Value,
    /// Whether the network takes images of any height (the image's other
    /// dimensions and the scan as in `geometry`): the network is fully
    /// convolutional, and its graph reads the height from its input
    /// (`training/dbtor/unet_any_rows.py`). [`Unet::load_with_rows`] refuses
    /// other heights without it.
    #[serde(default)]
    pub any_rows: bool,
}

/// A loaded U-Net.
pub struct Unet {
    manifest: UnetManifest,
    /// The manifest's geometry with the image height it was loaded for.
    geometry: Geometry,
    plan: std::sync::Arc<TypedSimplePlan>,
    path: PathBuf,
    nonnegative: bool,
}

impl std::fmt::Debug for Unet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Unet")
            .field("model", &self.manifest.name)
            .field("file", &self.path)
            .finish()
    }
}

impl Unet {
    /// Load `dir/manifest.json`, check it, verify every checksum and prepare
    /// the network for the model's image size.
    pub fn load(dir: &Path) -> Result<Self, DbtorError> {
        Self::load_with_rows(dir, None)
    }

    /// [`Unet::load`], the network prepared for images of `rows` rows
    /// (`None`: the manifest's); a height other than the manifest's needs a
    /// manifest that says `any_rows`.
    pub fn load_with_rows(dir: &Path, rows: Option<usize>) -> Result<Self, DbtorError> {
        let mpath = dir.join("manifest.json");
        let bad = |reason: String| DbtorError::Manifest {
            path: mpath.clone(),
            reason,
        };
        let text = std::fs::read_to_string(&mpath).map_err(|source| DbtorError::Io {
            path: mpath.clone(),
            cause: source,
        })?;
        let m: UnetManifest = serde_json::from_str(&text).map_err(|e| bad(e.to_string()))?;
        if m.format != UNET_FORMAT || m.kind != "unet" {
            return Err(bad(format!(
                "format {:?} kind {:?}, expected {UNET_FORMAT:?} kind \"unet\"",
                m.format, m.kind
            )));
        }
        m.geometry
            .validate()
            .map_err(|e| bad(format!("geometry: {e}")))?;
        let xs = m.normalisation.x_scale_per_mm;
        if !(xs.is_finite() && xs > 0.0) {
            return Err(bad(format!(
                "normalisation.x_scale_per_mm = {xs} must be positive"
            )));
        }
        if !m.sha256.contains_key(&m.file) {
            return Err(bad(format!("{} has no SHA-256 entry", m.file)));
        }
        verify_checksums(dir, &m.sha256)?;
        let path = dir.join(&m.file);
        let fail = |e: TractError| DbtorError::Block {
            path: path.clone(),
            reason: format!("{e:#}"),
        };
        let mut geometry = m.geometry.clone();
        if let Some(r) = rows.filter(|&r| r != geometry.image.rows) {
            if !m.any_rows {
                return Err(bad(format!(
                    "the network takes images of {} rows, not {r} (the manifest does not say any_rows)",
                    geometry.image.rows
                )));
            }
            geometry.image.rows = r;
            geometry
                .validate()
                .map_err(|e| bad(format!("geometry with {r} image rows: {e}")))?;
        }
        let (rows, cols) = (geometry.image.rows, geometry.image.columns);
        let plan = tract_onnx::onnx()
            .model_for_path(&path)
            .map_err(fail)?
            .with_input_fact(0, f32::fact([1, 1, rows, cols]).into())
            .map_err(fail)?
            .into_optimized()
            .map_err(fail)?
            .into_runnable()
            .map_err(fail)?;
        Ok(Unet {
            manifest: m,
            geometry,
            plan,
            path,
            nonnegative: true,
        })
    }

    /// The manifest.
    pub fn manifest(&self) -> &UnetManifest {
        &self.manifest
    }

    /// The geometry the network was loaded for (the manifest's, with the
    /// image height of [`Unet::load_with_rows`]).
    pub fn geometry(&self) -> &Geometry {
        &self.geometry
    }

    /// Whether [`Unet::reconstruct`] sets negative values to zero (default:
    /// yes), the same physical constraint as DBToR's runtime
    /// (`Dbtor::with_nonnegativity`), so that the baselines are compared on
    /// equal terms.
    pub fn with_nonnegativity(mut self, on: bool) -> Self {
        self.nonnegative = on;
        self
    }

    /// The image (1/mm) from an FBP reconstruction (1/mm) of the model's image
    /// size, as `dbt_recon::Fbp::reconstruct` gives it with the thickness mask;
    /// no value negative unless [`Unet::with_nonnegativity`] turned that off.
    pub fn reconstruct(&self, fbp: &[f32]) -> Result<Vec<f32>, DbtorError> {
        let mut out = self.network_output(fbp)?;
        if self.nonnegative {
            dbt_dbtor::zero_negatives(&mut out);
        }
        Ok(out)
    }

    /// The network's output (1/mm) as is: what the fixtures store.
    pub fn network_output(&self, fbp: &[f32]) -> Result<Vec<f32>, DbtorError> {
        let g = &self.geometry;
        let (rows, cols) = (g.image.rows, g.image.columns);
        if fbp.len() != rows * cols {
            return Err(DbtorError::Input(format!(
                "FBP image has {} pixels, the model's image has {rows} x {cols}",
                fbp.len()
            )));
        }
        if let Some(i) = fbp.iter().position(|v| !v.is_finite()) {
            return Err(DbtorError::Input(format!(
                "FBP pixel {i} is not finite ({})",
                fbp[i]
            )));
        }
        let xs = self.manifest.normalisation.x_scale_per_mm as f32;
        let fail = |e: TractError| DbtorError::Block {
            path: self.path.clone(),
            reason: format!("{e:#}"),
        };
        let x: Vec<f32> = fbp.iter().map(|v| v / xs).collect();
        let input = Tensor::from_shape(&[1, 1, rows, cols], &x).map_err(fail)?;
        let out = self.plan.run(tvec![input.into()]).map_err(fail)?;
        let view = out[0].to_plain_array_view::<f32>().map_err(fail)?;
        if view.len() != rows * cols {
            return Err(DbtorError::Block {
                path: self.path.clone(),
                reason: format!("output has {} values, expected {}", view.len(), rows * cols),
            });
        }
        Ok(view.iter().map(|v| v * xs).collect())
    }
}
