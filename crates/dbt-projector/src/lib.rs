//! Exact, matrix-free fan-beam projector pair for DBT coronal slices.
//!
//! `P` maps an image `f` (attenuation in mm^-1, row-major `rows x columns`, row 0
//! at the top) to line integrals `(P f)_i = sum_j l_ij f_j`, where `l_ij` is the
//! exact length (mm) of the intersection of ray `i` with pixel `j`: the model of
//! ASTRA's `line_fanflat` projector and of the paper's forward model
//! `y_i = b_i exp(-sum_j l_ij x_j)`. `P*` is its exact transpose.
//!
//! # Discretisation
//! In DBT every ray is steep: it crosses each image row once and, in the row, at
//! most two pixels whenever its horizontal travel per row is below one pixel
//! (`|dx/dz| < 1`; at the paper geometry the steepest ray has `|dx/dz| = 0.69`).
//! So the exact intersection lengths are computed row by row: a ray entering row
//! `i` at column coordinate `X_t` and leaving at `X_b` spends the fraction
//! `(ceil(lo) - lo) / |X_b - X_t|` of its row length in the first pixel and the
//! rest in the next. This has the regular memory access of Joseph's method (one
//! row at a time, two neighbouring pixels) while keeping the line model's exact
//! intersection lengths, so the line integrals of a piecewise-constant image are
//! exact (no interpolation blur) and agree with ASTRA's line model. Rays with
//! `|dx/dz| >= 1` fall back to a general per-row pixel span (same exact lengths).
//!
//! Every path (scalar reference, SIMD forward, SIMD adjoint, CSR export) derives
//! the weights from the same per-ray `f32` parameters with the same operations,
//! so `P*` is the transpose of `P` up to the order of summation.

// Kernel crate (issue #25): every unsafe operation in its own `unsafe` block
// with a `SAFETY:` comment, every unsafe function with its `# Safety` contract.
#![deny(unsafe_op_in_unsafe_fn)]
#![deny(clippy::undocumented_unsafe_blocks, clippy::missing_safety_doc)]
#![deny(missing_docs)]
// The kernels index several parallel per-ray arrays with one index; zipping
// five iterators would hide the arithmetic.
#![allow(clippy::needless_range_loop)]

use dbt_geometry::Geometry;
use rayon::prelude::*;
use thiserror::Error;

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;
mod csr;
mod table;

pub use csr::CsrMatrix;
use table::RayTable;

/// Errors from the projector.
#[derive(Debug, Error, PartialEq)]
pub enum ProjectorError {
    /// An input or output buffer has the wrong length.
    #[error("{what} has {got} elements, expected {expected}")]
    Shape {
        /// Which buffer.
        what: &'static str,
        /// Its length.
        got: usize,
        /// The length the geometry requires.
        expected: usize,
    },
}

fn check_len(what: &'static str, got: usize, expected: usize) -> Result<(), ProjectorError> {
    if got == expected {
        Ok(())
    } else {
        Err(ProjectorError::Shape {
            what,
            got,
            expected,
        })
    }
}

/// Which kernels [`Projector::forward`] and [`Projector::adjoint`] use,
/// slowest first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Kernel {
    /// Portable scalar code (the reference the others are tested against).
    Scalar,
    /// AVX2 forward (gathers) and adjoint (the AVX-512 scheme in 8-lane
    /// halves) (x86-64 with AVX2 detected at run time).
    Avx2,
    /// AVX-512F kernels (x86-64 with the feature detected at run time).
    Avx512,
}

/// The projector pair for one geometry. Construction precomputes per-ray tables
/// (a few MB at the paper geometry); projections are then allocation-free apart
/// from per-task scratch.
#[derive(Debug, Clone)]
pub struct Projector {
    geom: Geometry,
    table: RayTable,
    kernel: Kernel,
}

impl Kernel {
    /// Name for tables and logs.
    pub fn name(self) -> &'static str {
        match self {
            Kernel::Scalar => "scalar",
            Kernel::Avx2 => "avx2",
            Kernel::Avx512 => "avx512",
        }
    }
}

impl Projector {
    /// Build the projector for a (validated) geometry, choosing the fastest
    /// kernel this CPU supports.
    pub fn new(geom: &Geometry) -> Self {
        let table = RayTable::new(geom);
        Projector {
            geom: geom.clone(),
            table,
            kernel: best_kernel(),
        }
    }

    /// The same projector restricted to a given kernel (for tests and
    /// benchmarks). Falls back to [`Kernel::Scalar`] where the CPU lacks the
    /// requested feature.
    pub fn with_kernel(mut self, kernel: Kernel) -> Self {
        self.kernel = match kernel {
            Kernel::Avx512 if best_kernel() == Kernel::Avx512 => Kernel::Avx512,
            Kernel::Avx2 if has_avx2() => Kernel::Avx2,
            _ => Kernel::Scalar,
        };
        self
    }

    /// The same projector on the fastest kernel this CPU runs that is at
    /// most `limit` (the firmware's forced lower path, `DBTOR_KERNEL`).
    pub fn up_to(mut self, limit: Kernel) -> Self {
        self.kernel = best_kernel_up_to(limit);
        self
    }

    /// The kernel in use.
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    /// The geometry.
    pub fn geometry(&self) -> &Geometry {
        &self.geom
    }

    /// Number of image pixels (domain size).
    pub fn domain_len(&self) -> usize {
        self.geom.n_pixels()
    }

    /// Number of sinogram samples (range size), view-major.
    pub fn range_len(&self) -> usize {
        self.geom.n_rays()
    }

    /// `sino = P img`. `img` is row-major `rows x columns`; `sino` is view-major
    /// `views x elements`.
    pub fn forward(&self, img: &[f32], sino: &mut [f32]) -> Result<(), ProjectorError> {
        check_len("image", img.len(), self.domain_len())?;
        check_len("sinogram", sino.len(), self.range_len())?;
        let n_det = self.geom.n_det();
        const CHUNK: usize = 128;
        sino.par_chunks_mut(n_det)
            .enumerate()
            .for_each(|(v, view_out)| {
                view_out
                    .par_chunks_mut(CHUNK)
                    .enumerate()
                    .for_each(|(c, out)| {
                        let r0 = v * n_det + c * CHUNK;
                        self.forward_rays(img, r0, out);
                    });
            });
        Ok(())
    }

    /// `img = P* sino` (overwrites `img`).
    pub fn adjoint(&self, sino: &[f32], img: &mut [f32]) -> Result<(), ProjectorError> {
        check_len("sinogram", sino.len(), self.range_len())?;
        check_len("image", img.len(), self.domain_len())?;
        let nx = self.geom.nx();
        // Bands of rows: each task owns its rows, so no two tasks write the same
        // pixel and the result does not depend on scheduling.
        let band = self.adjoint_band_rows();
        img.par_chunks_mut(nx * band)
            .enumerate()
            .for_each(|(b, out)| {
                let i0 = b * band;
                self.adjoint_rows(sino, i0, out);
            });
        Ok(())
    }

    fn adjoint_band_rows(&self) -> usize {
        let nz = self.geom.nz();
        // Two bands per thread: some load balance, while larger bands reuse
        // each view's ray table over more rows. One to eight bands per thread
        // were compared with `projector-bench` (change the factor below): two
        // was as fast as one and faster than four or eight.
        let tasks = 2 * rayon::current_num_threads().max(1);
        nz.div_ceil(tasks).max(2)
    }

    /// Forward projection of rays `r0 .. r0 + out.len()` (all in one view).
    fn forward_rays(&self, img: &[f32], r0: usize, out: &mut [f32]) {
        match self.kernel {
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => {
                // SAFETY: `Kernel::Avx512` is only selected after run-time
                // detection of AVX-512F.
                unsafe { avx512::forward_rays(&self.table, img, r0, out) }
            }
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => {
                // SAFETY: `Kernel::Avx2` is only selected after run-time
                // detection of AVX2.
                unsafe { avx2::forward_rays(&self.table, img, r0, out) }
            }
            _ => {
                for (o, r) in out.iter_mut().zip(r0..) {
                    *o = self.table.forward_ray_scalar(r, img);
                }
            }
        }
    }

    /// Adjoint restricted to rows `i0 .. i0 + out.len() / nx`.
    fn adjoint_rows(&self, sino: &[f32], i0: usize, out: &mut [f32]) {
        match self.kernel {
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => {
                // SAFETY: see `forward_rays`.
                unsafe { avx512::adjoint_rows(&self.table, sino, i0, out) }
            }
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => {
                // SAFETY: see `forward_rays`.
                unsafe { avx2::adjoint_rows(&self.table, sino, i0, out) }
            }
            _ => self.table.adjoint_rows_scalar(sino, i0, out),
        }
    }

    /// The operator as a CSR sparse matrix (rows = sinogram samples, columns =
    /// pixels), with exactly the weights of the matrix-free path.
    pub fn to_csr(&self) -> CsrMatrix {
        csr::build(&self.table, self.range_len(), self.domain_len())
    }

    /// Largest singular value `||P||_2` by power iteration on `P* P`, starting
    /// from a constant image, stopping when the estimate changes by less than
    /// `rel_tol` or after `max_iter` iterations. Returns `(norm, iterations)`.
    pub fn operator_norm(&self, max_iter: usize, rel_tol: f64) -> (f64, usize) {
        let mut x = vec![1.0f32; self.domain_len()];
        let mut y = vec![0.0f32; self.range_len()];
        let mut prev = 0.0f64;
        let mut sigma = 0.0f64;
        for it in 1..=max_iter.max(1) {
            let nx = norm2(&x);
            if nx == 0.0 {
                return (0.0, it);
            }
            let inv = (1.0 / nx) as f32;
            x.iter_mut().for_each(|v| *v *= inv);
            // Shapes are correct by construction.
            let _ = self.forward(&x, &mut y);
            let _ = self.adjoint(&y, &mut x);
            // ||P*P x|| with ||x|| = 1 converges to sigma^2.
            sigma = norm2(&x).sqrt();
            if it > 1 && ((sigma - prev).abs() <= rel_tol * sigma) {
                return (sigma, it);
            }
            prev = sigma;
        }
        (sigma, max_iter)
    }
}

/// Euclidean norm in f64.
pub fn norm2(v: &[f32]) -> f64 {
    v.iter()
        .map(|&a| (a as f64) * (a as f64))
        .sum::<f64>()
        .sqrt()
}

/// Inner product in f64.
pub fn dot(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(&x, &y)| x as f64 * y as f64).sum()
}

/// The fastest kernel available on this CPU.
pub fn best_kernel() -> Kernel {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            return Kernel::Avx512;
        }
    }
    if has_avx2() {
        return Kernel::Avx2;
    }
    Kernel::Scalar
}

/// The fastest kernel this CPU runs that is at most `limit` (what
/// [`Projector::up_to`] selects).
pub fn best_kernel_up_to(limit: Kernel) -> Kernel {
    best_kernel().min(limit)
}

fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}
