//! A recorded acquisition on disk (`dbtor-acquisition/1`): what the gantry
//! delivers for one breast, as files. `host-sim acquire` writes it; the
//! firmware's offline processing reads it (the daemon of issue #8 receives
//! the same content over Modbus and the frame stream).
//!
//! ```text
//! DIR/acquisition.json   header: geometry, thickness, flux, technique, patient, study
//! DIR/counts.f32         [slices, views, elements] detected counts, little-endian f32
//! ```
//! Slices are coronal, chest wall first, `slice_spacing_mm` apart.

use crate::{io_err, StoreError};
use dbt_geometry::Geometry;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Format tag.
pub const ACQ_FORMAT: &str = "dbtor-acquisition/1";

/// Patient attributes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Patient {
    /// `Family^Given`.
    pub name: String,
    /// Patient ID.
    pub id: String,
    /// `YYYYMMDD` or empty.
    pub birth_date: String,
    /// `F`, `M`, `O` or empty.
    pub sex: String,
}

/// Study attributes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Study {
    /// Study Instance UID.
    pub study_uid: String,
    /// `YYYYMMDD`.
    pub date: String,
    /// `HHMMSS`.
    pub time: String,
    /// Accession number.
    pub accession: String,
    /// Study ID.
    pub study_id: String,
    /// Series Instance UID of the projections.
    pub series_uid: String,
    /// SOP Instance UIDs of the projections (one per view).
    pub instance_uids: Vec<String>,
}

/// The acquisition header.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AcquisitionHeader {
    /// [`ACQ_FORMAT`].
    pub format: String,
    /// Geometry of every slice.
    pub geometry: Geometry,
    /// Compressed thickness from the paddle, mm.
    pub thickness_mm: f64,
    /// Photons per ray without the breast (flat field), `b`.
    pub flux: f64,
    /// Number of coronal slices.
    pub slices: usize,
    /// Distance between coronal slices, mm.
    pub slice_spacing_mm: f64,
    /// Tube voltage, kV.
    pub kvp: f64,
    /// Tube loading of the whole sweep, mAs.
    pub mas_total: f64,
    /// Incident air kerma at the reference point per mAs, mGy/mAs.
    pub tube_output_mgy_per_mas: f64,
    /// `L` or `R`.
    pub laterality: String,
    /// Patient.
    pub patient: Patient,
    /// Study.
    pub study: Study,
    /// Ground truth of a simulated acquisition (for evaluation only; the
    /// processing never reads it).
    #[serde(default)]
    pub truth: Option<serde_json::Value>,
}

/// A loaded acquisition.
#[derive(Debug, Clone, PartialEq)]
pub struct Acquisition {
    /// Header.
    pub header: AcquisitionHeader,
    /// Counts, `[slices][views * elements]`.
    pub counts: Vec<Vec<f32>>,
}

fn bad(path: &Path, reason: impl Into<String>) -> StoreError {
    StoreError::Format {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

/// Write an acquisition to `dir` (created).
pub fn write_acquisition(dir: &Path, acq: &Acquisition) -> Result<(), StoreError> {
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    let n = acq.header.geometry.n_rays();
    let mut bytes = Vec::with_capacity(acq.counts.len() * n * 4);
    for (i, s) in acq.counts.iter().enumerate() {
        if s.len() != n {
            return Err(bad(
                dir,
                format!("slice {i} has {} counts, geometry needs {n}", s.len()),
            ));
        }
        bytes.extend(s.iter().flat_map(|v| v.to_le_bytes()));
    }
    let c = dir.join("counts.f32");
    std::fs::write(&c, bytes).map_err(io_err(&c))?;
    let h = dir.join("acquisition.json");
    let text = serde_json::to_string_pretty(&acq.header).map_err(|e| bad(&h, e.to_string()))?;
    std::fs::write(&h, text).map_err(io_err(&h))
}

/// Read and check an acquisition.
pub fn read_acquisition(dir: &Path) -> Result<Acquisition, StoreError> {
    let h = dir.join("acquisition.json");
    let text = std::fs::read_to_string(&h).map_err(io_err(&h))?;
    let header: AcquisitionHeader =
        serde_json::from_str(&text).map_err(|e| bad(&h, e.to_string()))?;
    if header.format != ACQ_FORMAT {
        return Err(bad(
            &h,
            format!("format `{}`, expected `{ACQ_FORMAT}`", header.format),
        ));
    }
    header
        .geometry
        .validate()
        .map_err(|e| bad(&h, e.to_string()))?;
    for (field, v) in [
        ("thickness_mm", header.thickness_mm),
        ("flux", header.flux),
        ("slice_spacing_mm", header.slice_spacing_mm),
        ("kvp", header.kvp),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(bad(&h, format!("`{field}` = {v} must be positive")));
        }
    }
    if header.laterality != "L" && header.laterality != "R" {
        return Err(bad(
            &h,
            format!("`laterality` = `{}` must be L or R", header.laterality),
        ));
    }
    let c = dir.join("counts.f32");
    let bytes = std::fs::read(&c).map_err(io_err(&c))?;
    let n = header.geometry.n_rays();
    if bytes.len() != header.slices * n * 4 {
        return Err(bad(
            &c,
            format!(
                "{} bytes, {} slices of {n} rays need {}",
                bytes.len(),
                header.slices,
                header.slices * n * 4
            ),
        ));
    }
    let counts: Vec<Vec<f32>> = bytes
        .chunks_exact(n * 4)
        .map(|s| {
            s.chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect()
        })
        .collect();
    if let Some((i, _)) = counts
        .iter()
        .enumerate()
        .find(|(_, s)| s.iter().any(|v| !v.is_finite() || *v < 0.0))
    {
        return Err(bad(
            &c,
            format!("slice {i} holds a negative or non-finite count"),
        ));
    }
    Ok(Acquisition { header, counts })
}
