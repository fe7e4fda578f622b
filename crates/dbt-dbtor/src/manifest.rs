//! `models/<name>/manifest.json` (format `dbtor-model/1`).

use crate::DbtorError;
use dbt_geometry::Geometry;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

/// Format tag.
pub const FORMAT: &str = "dbtor-model/1";

/// Primal (image space) or dual (sinogram space).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Sinogram-space block.
    Dual,
    /// Image-space block.
    Primal,
}

/// One block, in execution order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BlockEntry {
    /// Dual or primal.
    pub role: Role,
    /// Its iteration.
    pub index: usize,
    /// Channels of its `aux` input.
    pub aux_channels: usize,
    /// fp32 ONNX file, relative to the model folder.
    pub fp32: String,
    /// int8 QDQ ONNX file.
    pub int8: String,
}

/// Normalisation constants from the training set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Normalisation {
    /// Mean of the training sinograms.
    pub g_mean: f64,
    /// Their standard deviation.
    pub g_std: f64,
    /// Image unit of the network, 1/mm.
    pub x_scale_per_mm: f64,
    /// `||P||` of the model's geometry.
    pub operator_norm: f64,
}

/// Which state channels are read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Channels {
    /// Primal channel returned as the image.
    pub output: usize,
    /// Primal channel projected for the dual block.
    pub projected: usize,
    /// Dual channel back-projected for the primal block.
    pub backprojected: usize,
}

/// A stored test case for the equivalence test.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Fixture {
    /// Case name.
    pub name: String,
    /// Compressed thickness, mm.
    pub thickness_mm: f64,
    /// Files: `sinogram`, `truth`, `torch_fp32`, `ort_int8` (raw little-endian f32).
    pub files: BTreeMap<String, String>,
}

/// The manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelManifest {
    /// [`FORMAT`].
    pub format: String,
    /// Model name.
    pub name: String,
    /// `dbtor` (the learned primal-dual with the thickness mask) or `lpd`
    /// (the same network without the mask, the paper's LPD baseline).
    pub kind: String,
    /// Geometry of the input sinogram and output image.
    pub geometry: Geometry,
    /// State channels (5).
    pub state_channels: usize,
    /// Channel conventions.
    pub channels: Channels,
    /// Normalisation.
    pub normalisation: Normalisation,
    /// Blocks in execution order.
    pub blocks: Vec<BlockEntry>,
    /// Equivalence fixtures.
    #[serde(default)]
    pub fixtures: Vec<Fixture>,
    /// SHA-256 (hex) of every file of the model, by relative path.
    pub sha256: BTreeMap<String, String>,
    /// How the model was made.
    #[serde(default)]
    pub provenance: serde_json::Value,
    /// Validation metrics recorded at export.
    #[serde(default)]
    pub validation: serde_json::Value,
    /// SHA-256 (hex) of the manifest file itself, as read by
    /// [`ModelManifest::load`] (empty for a manifest parsed from text): what
    /// the reports name the model by.
    #[serde(skip)]
    pub file_sha256: String,
}

/// SHA-256 of a file, hex.
pub fn sha256_file(path: &Path) -> Result<String, DbtorError> {
    let io = |source| DbtorError::Io {
        path: path.to_path_buf(),
        cause: source,
    };
    let mut f = std::fs::File::open(path).map_err(io)?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = f.read(&mut buf).map_err(io)?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(h.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

/// What a training dataset's counts went through before the network, as
/// `host-sim dataset` writes it (`provenance.corrections`) and a model's
/// manifest carries it (`provenance.dataset_provenance.corrections`): the
/// value for the detector's clinical counts left uncorrected (issue #27's
/// other design).
pub const UNCORRECTED_CLINICAL_COUNTS: &str = "none: the detector's counts";

/// The counts a network was trained to read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrainingInput {
    /// On the paper's mono-energetic scale: simulated mono-energetic
    /// counts, or clinical counts corrected as the firmware corrects them
    /// (and every model whose manifest states no dataset corrections,
    /// written before issue #27).
    MonoScale,
    /// A polychromatic detector's counts with their scatter and beam
    /// hardening ([`UNCORRECTED_CLINICAL_COUNTS`]).
    UncorrectedClinical,
}

impl ModelManifest {
    /// The counts the network was trained on, from its dataset's
    /// provenance.
    pub fn training_input(&self) -> TrainingInput {
        let corrections = self.provenance["dataset_provenance"]["corrections"].as_str();
        if corrections == Some(UNCORRECTED_CLINICAL_COUNTS) {
            TrainingInput::UncorrectedClinical
        } else {
            TrainingInput::MonoScale
        }
    }

    /// Whether the blocks see the thickness mask (`dbtor`) or not (`lpd`).
    pub fn uses_mask(&self) -> bool {
        self.kind == "dbtor"
    }

    /// `aux` channels of the dual and primal blocks for the kind: dual
    /// `[P(f[1]), g, P(m)]`, primal `[P*(h[0]), m]`; LPD drops the mask terms.
    pub fn aux_channels(&self) -> Option<(usize, usize)> {
        match self.kind.as_str() {
            "dbtor" => Some((3, 2)),
            "lpd" => Some((2, 1)),
            _ => None,
        }
    }

    /// Read and check `dir/manifest.json` (format, block order, channel counts).
    pub fn load(dir: &Path) -> Result<Self, DbtorError> {
        let path = dir.join("manifest.json");
        let text = std::fs::read_to_string(&path).map_err(|source| DbtorError::Io {
            path: path.clone(),
            cause: source,
        })?;
        let mut m = Self::parse(&text, &path)?;
        m.file_sha256 = Sha256::digest(text.as_bytes())
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        Ok(m)
    }

    /// Parse and check a manifest's text (`path` names it in errors).
    pub fn parse(text: &str, path: &Path) -> Result<Self, DbtorError> {
        let path = path.to_path_buf();
        let bad = |reason: String| DbtorError::Manifest {
            path: path.clone(),
            reason,
        };
        let m: ModelManifest = serde_json::from_str(text).map_err(|e| bad(e.to_string()))?;
        if m.format != FORMAT {
            return Err(bad(format!(
                "format is {:?}, expected {FORMAT:?}",
                m.format
            )));
        }
        m.geometry
            .validate()
            .map_err(|e| bad(format!("geometry: {e}")))?;
        let c = m.state_channels;
        if c == 0
            || m.channels.output >= c
            || m.channels.projected >= c
            || m.channels.backprojected >= c
        {
            return Err(bad(format!(
                "channels {:?} do not fit {c} state channels",
                m.channels
            )));
        }
        let (aux_dual, aux_primal) = m.aux_channels().ok_or_else(|| {
            bad(format!(
                "kind is {:?}, expected \"dbtor\" or \"lpd\"",
                m.kind
            ))
        })?;
        if m.blocks.is_empty() || !m.blocks.len().is_multiple_of(2) {
            return Err(bad(format!(
                "{} blocks: expected dual/primal pairs",
                m.blocks.len()
            )));
        }
        for (k, b) in m.blocks.iter().enumerate() {
            let (role, aux) = if k % 2 == 0 {
                (Role::Dual, aux_dual)
            } else {
                (Role::Primal, aux_primal)
            };
            if b.role != role || b.index != k / 2 || b.aux_channels != aux {
                return Err(bad(format!(
                    "blocks[{k}] is {:?} {} with {} aux channels; expected {role:?} {} with {aux}",
                    b.role,
                    b.index,
                    b.aux_channels,
                    k / 2
                )));
            }
            for f in [&b.fp32, &b.int8] {
                if !m.sha256.contains_key(f) {
                    return Err(bad(format!("blocks[{k}]: {f} has no SHA-256 entry")));
                }
            }
        }
        let nm = &m.normalisation;
        for (name, v) in [
            ("g_std", nm.g_std),
            ("x_scale_per_mm", nm.x_scale_per_mm),
            ("operator_norm", nm.operator_norm),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(format!("normalisation.{name} = {v} must be positive")));
            }
        }
        if !nm.g_mean.is_finite() {
            return Err(bad("normalisation.g_mean is not finite".into()));
        }
        Ok(m)
    }

    /// Check every file named in `sha256` exists and matches.
    pub fn verify_files(&self, dir: &Path) -> Result<(), DbtorError> {
        verify_checksums(dir, &self.sha256)
    }
}

/// Check that every file listed (path relative to `dir` -> SHA-256 hex) exists
/// and has that checksum (also used by the evaluation's U-Net folders).
pub fn verify_checksums(dir: &Path, sha256: &BTreeMap<String, String>) -> Result<(), DbtorError> {
    for (rel, expected) in sha256 {
        let path = dir.join(rel);
        if !path.is_file() {
            return Err(DbtorError::Manifest {
                path: dir.join("manifest.json"),
                reason: format!("{rel} is listed but missing from {}", dir.display()),
            });
        }
        let found = sha256_file(&path)?;
        if &found != expected {
            return Err(DbtorError::Checksum {
                path,
                expected: expected.clone(),
                found,
            });
        }
    }
    Ok(())
}
