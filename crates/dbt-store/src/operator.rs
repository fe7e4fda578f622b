//! The projector exported as a CSR matrix for the trainer (PyTorch), so that
//! training and the firmware use the same operator `P`.
//!
//! ```text
//! DIR/operator.json      format, geometry, shape, nnz, operator norm
//! DIR/indptr.u64         [n_rows + 1]   <u8
//! DIR/indices.u32        [nnz]          <u4
//! DIR/values.f32         [nnz]          <f4   intersection lengths, mm
//! ```
//! Rows are sinogram samples (view-major), columns image pixels (row-major),
//! exactly as `dbt_projector::Projector::forward`.

use crate::{io_err, StoreError};
use dbt_geometry::Geometry;
use dbt_projector::CsrMatrix;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::Path;

/// Format tag.
pub const FORMAT: &str = "dbtor-operator/1";

/// `operator.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OperatorManifest {
    /// [`FORMAT`].
    pub format: String,
    /// Geometry the matrix belongs to.
    pub geometry: Geometry,
    /// Sinogram samples.
    pub n_rows: usize,
    /// Image pixels.
    pub n_cols: usize,
    /// Stored entries.
    pub nnz: usize,
    /// Largest singular value, by power iteration.
    pub norm: f64,
}

fn write_le<T: Copy>(
    path: &Path,
    data: &[T],
    to_bytes: impl Fn(T) -> Vec<u8>,
) -> Result<(), StoreError> {
    let f = std::fs::File::create(path).map_err(io_err(path))?;
    let mut w = std::io::BufWriter::new(f);
    for &v in data {
        w.write_all(&to_bytes(v)).map_err(io_err(path))?;
    }
    w.flush().map_err(io_err(path))
}

/// Write `csr` (of `geometry`, with operator norm `norm`) into `dir` (created
/// if missing).
pub fn write_operator(
    dir: &Path,
    geometry: &Geometry,
    csr: &CsrMatrix,
    norm: f64,
) -> Result<OperatorManifest, StoreError> {
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    write_le(&dir.join("indptr.u64"), &csr.indptr, |v| {
        v.to_le_bytes().to_vec()
    })?;
    write_le(&dir.join("indices.u32"), &csr.indices, |v| {
        v.to_le_bytes().to_vec()
    })?;
    write_le(&dir.join("values.f32"), &csr.values, |v| {
        v.to_le_bytes().to_vec()
    })?;
    let m = OperatorManifest {
        format: FORMAT.into(),
        geometry: geometry.clone(),
        n_rows: csr.n_rows,
        n_cols: csr.n_cols,
        nnz: csr.nnz(),
        norm,
    };
    let path = dir.join("operator.json");
    let text = serde_json::to_string_pretty(&m).map_err(|e| StoreError::Format {
        path: path.clone(),
        reason: e.to_string(),
    })?;
    std::fs::write(&path, text).map_err(io_err(&path))?;
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use dbt_projector::Projector;

    #[test]
    fn files_hold_the_matrix() {
        let g = Geometry::paper().binned(4).unwrap();
        let p = Projector::new(&g);
        let csr = p.to_csr();
        let dir = tempfile::tempdir().unwrap();
        let m = write_operator(dir.path(), &g, &csr, 1.0).unwrap();
        assert_eq!(m.nnz, csr.nnz());
        let bytes = std::fs::read(dir.path().join("values.f32")).unwrap();
        assert_eq!(bytes.len(), 4 * csr.nnz());
        let v: Vec<f32> = bytes
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        assert_eq!(v, csr.values);
        let ip = std::fs::read(dir.path().join("indptr.u64")).unwrap();
        assert_eq!(ip.len(), 8 * (csr.n_rows + 1));
        let back: OperatorManifest = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join("operator.json")).unwrap(),
        )
        .unwrap();
        assert_eq!(back, m);
    }
}
