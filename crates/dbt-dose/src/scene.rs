//! The geometry of a simulation: one voxel grid (Woodcock-tracked) and
//! homogeneous boxes around it, in a world of one material (air).
//! Coordinates in mm.

use crate::material::Material;
use crate::DoseError;

/// An axis-aligned voxel grid. Index `(k * ny + j) * nx + i`.
#[derive(Debug, Clone)]
pub struct VoxelGrid {
    /// Minimum corner, mm.
    pub origin: [f64; 3],
    /// Voxel side, mm.
    pub voxel_mm: f64,
    /// Voxel counts `[nx, ny, nz]`.
    pub dims: [usize; 3],
    /// Material index per voxel.
    pub material: Vec<u8>,
    /// Tally index per voxel (0: not tallied; `k` adds to tally `k - 1`).
    pub tally: Vec<u8>,
}

impl VoxelGrid {
    /// Maximum corner, mm.
    pub fn max(&self) -> [f64; 3] {
        [0, 1, 2].map(|a| self.origin[a] + self.dims[a] as f64 * self.voxel_mm)
    }

    /// Index of the voxel holding `p` (clamped to the grid).
    #[inline]
    pub fn index(&self, p: [f64; 3]) -> usize {
        let inv = 1.0 / self.voxel_mm;
        let c = |a: usize| {
            let v = ((p[a] - self.origin[a]) * inv) as isize;
            v.clamp(0, self.dims[a] as isize - 1) as usize
        };
        (c(2) * self.dims[1] + c(1)) * self.dims[0] + c(0)
    }

    /// Centre of voxel `(i, j, k)`, mm.
    pub fn centre(&self, i: usize, j: usize, k: usize) -> [f64; 3] {
        let h = self.voxel_mm;
        [
            self.origin[0] + (i as f64 + 0.5) * h,
            self.origin[1] + (j as f64 + 0.5) * h,
            self.origin[2] + (k as f64 + 0.5) * h,
        ]
    }
}

/// A homogeneous axis-aligned box.
#[derive(Debug, Clone)]
pub struct HomogeneousBox {
    /// Minimum corner, mm.
    pub min: [f64; 3],
    /// Maximum corner, mm.
    pub max: [f64; 3],
    /// Material index.
    pub material: u8,
}

/// Everything the transport needs.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Materials, indexed by the `u8` material codes.
    pub materials: Vec<Material>,
    /// The voxel grid.
    pub grid: VoxelGrid,
    /// Homogeneous boxes (must not overlap the grid or each other).
    pub boxes: Vec<HomogeneousBox>,
    /// Material of everything else.
    pub world_material: u8,
    /// The world's corners; photons leaving it escape.
    pub world_min: [f64; 3],
    /// See `world_min`.
    pub world_max: [f64; 3],
    /// Number of tallies used by the grid.
    pub n_tallies: usize,
    /// Distinct materials and the largest tally of the grid, computed once
    /// (the grid must not change after the first use).
    /// Leave it `Default::default()`.
    pub summary: std::sync::OnceLock<(Vec<u8>, u8)>,
}

fn overlap(a0: [f64; 3], a1: [f64; 3], b0: [f64; 3], b1: [f64; 3]) -> bool {
    (0..3).all(|k| a0[k] < b1[k] - 1e-9 && b0[k] < a1[k] - 1e-9)
}

impl Scene {
    /// Distinct grid materials and the largest grid tally (cached: the grid
    /// must not change after the first call).
    pub fn grid_summary(&self) -> &(Vec<u8>, u8) {
        self.summary.get_or_init(|| {
            let mut seen = [false; 256];
            let mut mats = Vec::new();
            for &m in &self.grid.material {
                if !seen[m as usize] {
                    seen[m as usize] = true;
                    mats.push(m);
                }
            }
            (mats, self.grid.tally.iter().copied().max().unwrap_or(0))
        })
    }

    /// Check the scene's consistency.
    pub fn validate(&self) -> Result<(), DoseError> {
        let g = &self.grid;
        let n: usize = g.dims.iter().product();
        if n == 0
            || g.material.len() != n
            || g.tally.len() != n
            || g.voxel_mm.is_nan()
            || g.voxel_mm <= 0.0
        {
            return Err(DoseError::Scene("voxel grid size mismatch or empty".into()));
        }
        let nm = self.materials.len();
        let (mats, max_tally) = self.grid_summary();
        if let Some(bad) = mats.iter().find(|&&m| m as usize >= nm) {
            return Err(DoseError::Scene(format!(
                "voxel material {bad} but {nm} materials"
            )));
        }
        if *max_tally as usize > self.n_tallies {
            return Err(DoseError::Scene(format!(
                "voxel tally {max_tally} but {} tallies",
                self.n_tallies
            )));
        }
        if self.world_material as usize >= nm {
            return Err(DoseError::Scene("world material out of range".into()));
        }
        for (i, b) in self.boxes.iter().enumerate() {
            if b.material as usize >= nm {
                return Err(DoseError::Scene(format!(
                    "box {i}: material {}",
                    b.material
                )));
            }
            if overlap(b.min, b.max, g.origin, g.max()) {
                return Err(DoseError::Scene(format!("box {i} overlaps the voxel grid")));
            }
            for (j, c) in self.boxes.iter().enumerate().skip(i + 1) {
                if overlap(b.min, b.max, c.min, c.max) {
                    return Err(DoseError::Scene(format!("boxes {i} and {j} overlap")));
                }
            }
        }
        Ok(())
    }

    /// The region holding point `p`.
    pub fn region_of(&self, p: [f64; 3]) -> Region {
        let inside = |a: [f64; 3], b: [f64; 3]| (0..3).all(|k| p[k] >= a[k] && p[k] < b[k]);
        if inside(self.grid.origin, self.grid.max()) {
            return Region::Grid;
        }
        for (i, b) in self.boxes.iter().enumerate() {
            if inside(b.min, b.max) {
                return Region::Box(i);
            }
        }
        Region::World
    }
}

/// Where a photon is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Region {
    /// In the world material, outside every box.
    World,
    /// In the voxel grid.
    Grid,
    /// In homogeneous box `i`.
    Box(usize),
}

/// Slab test: `(t_near, t_far)` of the ray `p + t d` through a box.
#[inline]
pub fn ray_box(p: [f64; 3], d: [f64; 3], min: [f64; 3], max: [f64; 3]) -> (f64, f64) {
    let mut tn = f64::NEG_INFINITY;
    let mut tf = f64::INFINITY;
    for k in 0..3 {
        if d[k].abs() < 1e-300 {
            if p[k] < min[k] || p[k] > max[k] {
                return (f64::INFINITY, f64::NEG_INFINITY);
            }
        } else {
            let inv = 1.0 / d[k];
            let (a, b) = ((min[k] - p[k]) * inv, (max[k] - p[k]) * inv);
            tn = tn.max(a.min(b));
            tf = tf.min(a.max(b));
        }
    }
    (tn, tf)
}
