//! A recorded acquisition on disk (`dbtor-acquisition/1`): what the gantry
//! delivers for one breast, as files. `host-sim acquire` writes it; the
//! firmware's offline processing and the daemon's spool read it. The type and
//! its header validation are the domain's (`dbt_pipeline::acquisition`); this
//! is the file adapter.
//!
//! ```text
//! DIR/acquisition.json   header: geometry, thickness, flux, technique, patient, study
//! DIR/counts.f32         [slices, views, elements] detected counts, little-endian f32
//! ```
//! Slices are coronal, chest wall first, `slice_spacing_mm` apart.

use crate::{io_err, StoreError};
use dbt_pipeline::acquisition::{counts_bytes, validate_header, Acquisition, AcquisitionHeader};
use std::io::Read;
use std::path::Path;

fn bad(path: &Path, reason: impl Into<String>) -> StoreError {
    StoreError::Format {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

/// Write an acquisition to `dir` (created).
pub fn write_acquisition(dir: &Path, acq: &Acquisition) -> Result<(), StoreError> {
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    let n = acq.header.rays_per_slice();
    let mut bytes = Vec::with_capacity(acq.counts.len() * n * 4);
    for (i, s) in acq.counts.iter().enumerate() {
        if s.len() != n {
            return Err(bad(
                dir,
                format!("slice {i} has {} counts, the header needs {n}", s.len()),
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
    validate_header(&header).map_err(|e| bad(&h, e.to_string()))?;
    let want = counts_bytes(&header).map_err(|e| bad(&h, e.to_string()))?;
    let c = dir.join("counts.f32");
    let len = std::fs::metadata(&c).map_err(io_err(&c))?.len();
    if len != want as u64 {
        return Err(bad(
            &c,
            format!(
                "{len} bytes, {} slices of {} rays need {want}",
                header.slices,
                header.rays_per_slice()
            ),
        ));
    }
    let mut bytes = Vec::with_capacity(want);
    std::fs::File::open(&c)
        .and_then(|f| f.take(want as u64).read_to_end(&mut bytes))
        .map_err(io_err(&c))?;
    decode_counts(header, &bytes).map_err(|reason| bad(&c, reason))
}

/// An acquisition from its header's JSON and its counts' bytes, checked as
/// [`read_acquisition`] checks the files (the fuzz target's entry).
pub fn decode_acquisition(header_json: &[u8], counts: &[u8]) -> Result<Acquisition, String> {
    let header: AcquisitionHeader =
        serde_json::from_slice(header_json).map_err(|e| e.to_string())?;
    validate_header(&header).map_err(|e| e.to_string())?;
    let want = counts_bytes(&header).map_err(|e| e.to_string())?;
    if counts.len() != want {
        return Err(format!(
            "{} bytes, {} slices of {} rays need {want}",
            counts.len(),
            header.slices,
            header.rays_per_slice()
        ));
    }
    decode_counts(header, counts)
}

fn decode_counts(header: AcquisitionHeader, bytes: &[u8]) -> Result<Acquisition, String> {
    let n = header.rays_per_slice();
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
        return Err(format!("slice {i} holds a negative or non-finite count"));
    }
    Ok(Acquisition { header, counts })
}
