//! Exact cone-beam projector pair for 3-D breast volumes (issue #28).
//!
//! `A` maps an attenuation volume `mu` (1/mm) to the line integrals of every
//! ray of a [`ConeSystem`] (from the source to each detector element's
//! centre, at every view): `(A mu)_i = sum_j l_ij mu_j`, where `l_ij` is the
//! exact length (mm) of ray `i` inside voxel `j` (the line model of the 2-D
//! projector, `dbt-projector`, in three dimensions). The lengths come from
//! a 3-D digital differential analyser (Amanatides & Woo 1987, "A fast voxel
//! traversal algorithm for ray tracing", Eurographics; the incremental form
//! of Siddon 1985, Med Phys 12:252) in `f64`, so the line integrals of a
//! piecewise-constant volume are exact to rounding. `A*` visits the same
//! voxels with the same lengths: it is the exact transpose.
//!
//! Volume layout: the phantoms' (`dbt_phantom::LabelVolume`): index
//! `(depth * vertical_count + vertical) * lateral_count + lateral`, vertical 0
//! on the breast support, depth 0 at the chest wall, the lateral centre on
//! `x = 0`. Projection layout: `[view][detector row][detector column]`
//! (rows from the chest wall: the frames of the gantry interface).

#![deny(missing_docs)]

use dbt_geometry::cone::Point3;
use dbt_geometry::ConeSystem;
use rayon::prelude::*;
use thiserror::Error;

/// Errors of the cone-beam projector.
#[derive(Debug, Error, PartialEq)]
pub enum ConeError {
    /// A buffer of the wrong length.
    #[error("{what} has {got} values, expected {expected}")]
    Shape {
        /// Which buffer.
        what: &'static str,
        /// Its length.
        got: usize,
        /// The length the system and grid require.
        expected: usize,
    },
    /// An impossible grid.
    #[error("volume grid `{field}`: {reason}")]
    Grid {
        /// The field.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
}

/// The voxel grid of a breast volume placed on the system: isotropic
/// voxels, resting on the support, centred across, from the chest wall.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VolumeGrid {
    /// Voxels across (x).
    pub lateral: usize,
    /// Voxels up from the support (z).
    pub vertical: usize,
    /// Voxels from the chest wall (y).
    pub depth: usize,
    /// Voxel side, mm.
    pub voxel_mm: f64,
}

impl VolumeGrid {
    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.lateral * self.vertical * self.depth
    }

    /// Whether the grid has no voxel.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The storage index of voxel (`lateral`, `vertical`, `depth`).
    pub fn index(&self, l: usize, v: usize, d: usize) -> usize {
        (d * self.vertical + v) * self.lateral + l
    }
}

/// The projector of one system and one grid.
#[derive(Debug, Clone)]
pub struct ConeProjector {
    system: ConeSystem,
    grid: VolumeGrid,
    /// The grid's lower corner and upper corner, mm (x, y, z).
    lo: Point3,
    hi: Point3,
}

impl ConeProjector {
    /// A projector for `grid` on `system`; the grid must fit between the
    /// support and the source.
    pub fn new(system: &ConeSystem, grid: VolumeGrid) -> Result<Self, ConeError> {
        let bad = |field: &'static str, reason: String| ConeError::Grid { field, reason };
        if !(grid.voxel_mm.is_finite() && grid.voxel_mm > 0.0) {
            return Err(bad(
                "voxel_mm",
                format!("{} is not positive", grid.voxel_mm),
            ));
        }
        if grid.is_empty() || grid.len() > 1 << 31 {
            return Err(bad("lateral", format!("{} voxels", grid.len())));
        }
        let h = grid.voxel_mm;
        let lo = [
            -(grid.lateral as f64) * h / 2.0,
            0.0,
            system.support_height_mm,
        ];
        let hi = [
            lo[0] + grid.lateral as f64 * h,
            grid.depth as f64 * h,
            lo[2] + grid.vertical as f64 * h,
        ];
        let lowest_source = (0..system.n_views())
            .map(|v| system.source(v)[2])
            .fold(f64::INFINITY, f64::min);
        if hi[2] >= lowest_source {
            return Err(bad(
                "vertical",
                format!(
                    "the volume reaches {:.1} mm, above the source ({lowest_source:.1} mm)",
                    hi[2]
                ),
            ));
        }
        Ok(Self {
            system: system.clone(),
            grid,
            lo,
            hi,
        })
    }

    /// The system.
    pub fn system(&self) -> &ConeSystem {
        &self.system
    }

    /// The grid.
    pub fn grid(&self) -> VolumeGrid {
        self.grid
    }

    /// Values of a projection set (views x rows x columns).
    pub fn range_len(&self) -> usize {
        self.system.n_views() * self.system.n_elements()
    }

    /// The ray of view `v` to element (`row`, `column`): source and
    /// element centre.
    pub fn ray(&self, v: usize, row: usize, column: usize) -> (Point3, Point3) {
        (self.system.source(v), self.system.element(v, row, column))
    }

    /// Visit the voxels the half-line from `s` through `e` crosses inside
    /// the grid, with the length (mm) it runs in each.
    pub fn trace(&self, s: Point3, e: Point3, mut visit: impl FnMut(usize, f64)) {
        let g = &self.grid;
        let h = g.voxel_mm;
        let n = [g.lateral, g.depth, g.vertical];
        let d = [e[0] - s[0], e[1] - s[1], e[2] - s[2]];
        let length = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        if length == 0.0 {
            return;
        }
        // The parameter interval inside the box. A ray is the half-line
        // from the source through the element's centre (as the 2-D
        // projector's and ASTRA's line models: the paper's rotating
        // detector passes under the breast's edge at the largest angles).
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for a in 0..3 {
            if d[a] == 0.0 {
                if s[a] < self.lo[a] || s[a] > self.hi[a] {
                    return;
                }
                continue;
            }
            let (ta, tb) = ((self.lo[a] - s[a]) / d[a], (self.hi[a] - s[a]) / d[a]);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
        if t0 >= t1 {
            return;
        }
        // The voxel where the ray enters, and the parameters of its next
        // boundary on each axis.
        let tm = 0.5 * (t0 + t1.min(t0 + 1e-9));
        let mut idx = [0i64; 3];
        let mut next = [f64::INFINITY; 3];
        let mut delta = [f64::INFINITY; 3];
        let mut step = [0i64; 3];
        for a in 0..3 {
            // The entry point lies on a face of the box: the voxel is the
            // one the ray goes into, found just past it.
            let q = s[a] + tm * d[a];
            let i = ((q - self.lo[a]) / h).floor() as i64;
            idx[a] = i.clamp(0, n[a] as i64 - 1);
            if d[a] > 0.0 {
                step[a] = 1;
                next[a] = (self.lo[a] + (idx[a] + 1) as f64 * h - s[a]) / d[a];
                delta[a] = h / d[a];
            } else if d[a] < 0.0 {
                step[a] = -1;
                next[a] = (self.lo[a] + idx[a] as f64 * h - s[a]) / d[a];
                delta[a] = -h / d[a];
            }
        }
        let mut t = t0;
        loop {
            // The axis whose boundary comes first.
            let a = if next[0] <= next[1] && next[0] <= next[2] {
                0
            } else if next[1] <= next[2] {
                1
            } else {
                2
            };
            let t_exit = next[a].min(t1);
            if t_exit > t {
                // Axes are (x, y, z) = (lateral, depth, vertical).
                visit(
                    g.index(idx[0] as usize, idx[2] as usize, idx[1] as usize),
                    (t_exit - t) * length,
                );
                t = t_exit;
            }
            if t >= t1 {
                return;
            }
            idx[a] += step[a];
            if idx[a] < 0 || idx[a] >= n[a] as i64 {
                return;
            }
            next[a] += delta[a];
        }
    }

    /// `A mu`: the line integrals of every ray, views x rows x columns.
    pub fn forward(&self, mu: &[f32]) -> Result<Vec<f32>, ConeError> {
        if mu.len() != self.grid.len() {
            return Err(ConeError::Shape {
                what: "volume",
                got: mu.len(),
                expected: self.grid.len(),
            });
        }
        let (rows, cols) = (self.system.detector.rows, self.system.detector.columns);
        let mut out = vec![0.0f32; self.range_len()];
        out.par_chunks_mut(cols).enumerate().for_each(|(vr, line)| {
            let (v, r) = (vr / rows, vr % rows);
            let s = self.system.source(v);
            for (c, o) in line.iter_mut().enumerate() {
                let mut acc = 0.0f64;
                self.trace(s, self.system.element(v, r, c), |j, l| {
                    acc += f64::from(mu[j]) * l
                });
                *o = acc as f32;
            }
        });
        Ok(out)
    }

    /// `A* p`: every ray's value spread back over the voxels it crosses,
    /// weighted by the same lengths.
    pub fn adjoint(&self, p: &[f32]) -> Result<Vec<f32>, ConeError> {
        if p.len() != self.range_len() {
            return Err(ConeError::Shape {
                what: "projections",
                got: p.len(),
                expected: self.range_len(),
            });
        }
        let (rows, cols) = (self.system.detector.rows, self.system.detector.columns);
        let n = self.grid.len();
        let sum = p
            .par_chunks(cols)
            .enumerate()
            .fold(
                || vec![0.0f64; n],
                |mut acc, (vr, line)| {
                    let (v, r) = (vr / rows, vr % rows);
                    let s = self.system.source(v);
                    for (c, &y) in line.iter().enumerate() {
                        if y != 0.0 {
                            let y = f64::from(y);
                            self.trace(s, self.system.element(v, r, c), |j, l| acc[j] += y * l);
                        }
                    }
                    acc
                },
            )
            .reduce(
                || vec![0.0f64; n],
                |mut a, b| {
                    for (x, y) in a.iter_mut().zip(b) {
                        *x += y;
                    }
                    a
                },
            );
        Ok(sum.into_iter().map(|x| x as f32).collect())
    }
}
