//! Export of the projector as a CSR sparse matrix (for training in PyTorch and as
//! an independent check of the matrix-free kernels).

use crate::table::RayTable;
use rayon::prelude::*;

/// A CSR matrix with `f32` values: row `i` holds the entries
/// `indices[indptr[i]..indptr[i + 1]]` / `values[...]`.
#[derive(Debug, Clone, PartialEq)]
pub struct CsrMatrix {
    /// Number of rows (sinogram samples).
    pub n_rows: usize,
    /// Number of columns (pixels).
    pub n_cols: usize,
    /// Row pointers, `n_rows + 1` entries.
    pub indptr: Vec<u64>,
    /// Column indices.
    pub indices: Vec<u32>,
    /// Values: intersection lengths in mm.
    pub values: Vec<f32>,
}

pub(crate) fn build(t: &RayTable, n_rows: usize, n_cols: usize) -> CsrMatrix {
    let rows: Vec<(Vec<u32>, Vec<f32>)> = (0..n_rows)
        .into_par_iter()
        .map(|r| {
            let mut idx = Vec::new();
            let mut val = Vec::new();
            t.ray_weights(r, |j, w| {
                idx.push(j as u32);
                val.push(w);
            });
            (idx, val)
        })
        .collect();
    let nnz: usize = rows.iter().map(|(i, _)| i.len()).sum();
    let mut m = CsrMatrix {
        n_rows,
        n_cols,
        indptr: Vec::with_capacity(n_rows + 1),
        indices: Vec::with_capacity(nnz),
        values: Vec::with_capacity(nnz),
    };
    m.indptr.push(0);
    for (idx, val) in rows {
        m.indices.extend_from_slice(&idx);
        m.values.extend_from_slice(&val);
        m.indptr.push(m.indices.len() as u64);
    }
    m
}

impl CsrMatrix {
    /// Number of stored entries.
    pub fn nnz(&self) -> usize {
        self.values.len()
    }

    /// `y = A x`.
    pub fn matvec(&self, x: &[f32], y: &mut [f32]) {
        y.par_iter_mut().enumerate().for_each(|(r, out)| {
            let (a, b) = (self.indptr[r] as usize, self.indptr[r + 1] as usize);
            let mut acc = 0.0f32;
            for e in a..b {
                acc += self.values[e] * x[self.indices[e] as usize];
            }
            *out = acc;
        });
    }

    /// `x = A^T y` (serial; for tests).
    pub fn matvec_transpose(&self, y: &[f32], x: &mut [f32]) {
        x.fill(0.0);
        for (r, &yr) in y.iter().enumerate() {
            let (a, b) = (self.indptr[r] as usize, self.indptr[r + 1] as usize);
            for e in a..b {
                x[self.indices[e] as usize] += self.values[e] * yr;
            }
        }
    }

    /// Serialise in a simple little-endian binary layout readable with numpy:
    /// a 64-byte header (magic `DBTCSR01`, n_rows, n_cols, nnz as u64, rest zero)
    /// followed by `indptr` (u64), `indices` (u32) and `values` (f32).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(64 + self.indptr.len() * 8 + self.nnz() * 8);
        out.extend_from_slice(b"DBTCSR01");
        for v in [self.n_rows as u64, self.n_cols as u64, self.nnz() as u64] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.resize(64, 0);
        for v in &self.indptr {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for v in &self.indices {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for v in &self.values {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out
    }
}
