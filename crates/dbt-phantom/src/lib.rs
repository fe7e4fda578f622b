//! Compressed-breast label volumes: the procedural generator ([`generate`]),
//! external label volumes with a sidecar ([`external`]), and the extraction of
//! coronal slices on the image grid of a [`Geometry`].
//!
//! # Volume layout
//! A [`LabelVolume`] holds one `u8` label per voxel (codes of
//! [`dbt_materials::Tissue`]) on an isotropic grid with three named axes:
//! * `lateral` (left-right, along the chest wall; the image columns),
//! * `vertical` (the compression axis; index 0 rests on the breast support),
//! * `depth` (from the chest wall, index 0, toward the nipple).
//!
//! `lateral` varies fastest, then `vertical`, then `depth`, so each coronal
//! slice (fixed depth) is one contiguous block, bottom row first.
//!
//! This crate does no I/O: external volumes are decoded from bytes that an
//! adapter has read.

pub mod anatomical;
pub mod external;
pub mod generate;
mod noise;

use dbt_geometry::Geometry;
use dbt_materials::{count_labels, glandularity, Tissue, UnknownLabel, MU_BY_LABEL};
use serde::{Deserialize, Serialize};
use thiserror::Error;

pub use anatomical::{generate_anatomical, AnatomicalPopulation, AnatomicalSpec, GlandHeight};
pub use external::{ExternalSidecar, VolumeAxis};
pub use generate::{generate, PhantomSpec, Population};

/// Which phantom population a dataset or an evaluation draws from.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PopulationKind {
    /// The procedural breasts of [`generate`] ([`Population`]): the
    /// population every model up to dbtor-x4t3 was trained and tested on.
    #[default]
    Procedural,
    /// The anatomical breasts of [`anatomical`] ([`AnatomicalPopulation`]).
    Anatomical,
    /// Both, for training on a mixture: phantom `index` is procedural when
    /// `index % 3 == 2`, else anatomical (the same phantom as the anatomical
    /// population's `index`).
    Mixed,
    /// The anatomical breasts with their gland spread through the whole
    /// height and a thin subcutaneous fat layer
    /// ([`AnatomicalPopulation::draw_spread`], issue #48): phantom `index`
    /// is the anatomical population's `index` but for where its gland lies
    /// in height.
    AnatomicalSpread,
}

impl PopulationKind {
    /// Every population, in the order of [`PopulationKind::NAMES`].
    pub const ALL: [PopulationKind; 4] = [
        PopulationKind::Procedural,
        PopulationKind::Anatomical,
        PopulationKind::Mixed,
        PopulationKind::AnatomicalSpread,
    ];
    /// Names as on command lines and in manifests.
    pub const NAMES: [&'static str; 4] = ["procedural", "anatomical", "mixed", "anatomical-spread"];

    /// The name as on command lines and in manifests.
    pub fn name(self) -> &'static str {
        match self {
            PopulationKind::Procedural => "procedural",
            PopulationKind::Anatomical => "anatomical",
            PopulationKind::Mixed => "mixed",
            PopulationKind::AnatomicalSpread => "anatomical-spread",
        }
    }

    /// Parse a name of [`PopulationKind::NAMES`].
    pub fn parse(name: &str) -> Result<Self, PhantomError> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| {
                PhantomError::Sidecar(format!(
                    "unknown phantom population {name:?} (known: {})",
                    Self::NAMES.join(", ")
                ))
            })
    }

    /// Draw phantom `index` of this population (seeded with `seed`) fitted
    /// to the image of `geom`.
    pub fn draw(self, geom: &Geometry, seed: u64, index: u64) -> AnySpec {
        match self {
            PopulationKind::Procedural => {
                AnySpec::Procedural(Population::for_geometry(geom).draw(seed, index))
            }
            PopulationKind::Anatomical => {
                AnySpec::Anatomical(AnatomicalPopulation::for_geometry(geom).draw(seed, index))
            }
            PopulationKind::Mixed if index % 3 == 2 => {
                PopulationKind::Procedural.draw(geom, seed, index)
            }
            PopulationKind::Mixed => PopulationKind::Anatomical.draw(geom, seed, index),
            PopulationKind::AnatomicalSpread => AnySpec::Anatomical(
                AnatomicalPopulation::for_geometry(geom).draw_spread(seed, index),
            ),
        }
    }
}

impl std::fmt::Display for PopulationKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for PopulationKind {
    type Err = PhantomError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::parse(s)
    }
}

/// A phantom of either population.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum AnySpec {
    /// A procedural phantom.
    Procedural(PhantomSpec),
    /// An anatomical phantom.
    Anatomical(AnatomicalSpec),
}

impl AnySpec {
    /// Generate its label volume.
    pub fn generate(&self) -> Result<LabelVolume, PhantomError> {
        match self {
            AnySpec::Procedural(s) => generate(s),
            AnySpec::Anatomical(s) => generate_anatomical(s),
        }
    }

    /// The requested glandularity by mass.
    pub fn glandularity(&self) -> f64 {
        match self {
            AnySpec::Procedural(s) => s.glandularity,
            AnySpec::Anatomical(s) => s.glandularity,
        }
    }
}

/// Errors of this crate; each names what was wrong.
#[derive(Debug, Error)]
pub enum PhantomError {
    /// A generator parameter is out of its allowed range.
    #[error("phantom parameter `{field}` = {value}: {reason}")]
    Parameter {
        /// Parameter name as in [`PhantomSpec`].
        field: &'static str,
        /// The offending value.
        value: f64,
        /// The allowed range or rule.
        reason: String,
    },
    /// The sidecar of an external phantom is malformed or inconsistent.
    #[error("phantom sidecar: {0}")]
    Sidecar(String),
    /// The raw data does not match the sidecar.
    #[error("phantom raw data: {0}")]
    Raw(String),
    /// A label code not in the tissue table (or not mapped by a sidecar).
    #[error("{0}")]
    Label(#[from] UnknownLabel),
    /// A label in an external volume that its sidecar does not map.
    #[error("external label {label} (first at file voxel {voxel:?}) is not mapped in the sidecar's [labels] table")]
    Unmapped {
        /// The label code in the file.
        label: u8,
        /// File indices (fastest axis first) of its first occurrence.
        voxel: [usize; 3],
    },
    /// The phantom does not fit the image of the geometry.
    #[error("phantom does not fit the geometry: {0}")]
    DoesNotFit(String),
    /// A slice index beyond the volume.
    #[error("coronal slice {index} out of range (volume has {count})")]
    SliceOutOfRange {
        /// Requested index.
        index: usize,
        /// Number of coronal slices.
        count: usize,
    },
}

/// An isotropic label volume (see the crate docs for the layout).
///
/// A volume drawn on a finer grid than its voxels (the anatomical phantoms)
/// also carries its **partial volumes**: per voxel, how many of its `sub^3`
/// fine samples hold each tissue ([`PartialVolumes`]). Then the attenuation
/// of a voxel is the fine samples' mean ([`coronal_slice`]), the ground-truth
/// glandularity is counted on the fine samples ([`LabelVolume::glandularity`]),
/// and the label of a voxel is the tissue of its centre's fine sample
/// (for the dose engine and the classification truth, which work on labels).
#[derive(Debug, Clone, PartialEq)]
pub struct LabelVolume {
    /// Voxel counts `[lateral, vertical, depth]`.
    dims: [usize; 3],
    voxel_mm: f64,
    data: Vec<u8>,
    pv: Option<PartialVolumes>,
}

/// Per-voxel tissue counts of a volume drawn `sub` times finer per axis.
#[derive(Debug, Clone, PartialEq)]
pub struct PartialVolumes {
    sub: u8,
    counts: Vec<[u8; 5]>,
}

impl PartialVolumes {
    /// Fine samples per voxel along each axis.
    pub fn sub(&self) -> u8 {
        self.sub
    }

    /// Tissue counts (label order) of every voxel, storage order.
    pub fn counts(&self) -> &[[u8; 5]] {
        &self.counts
    }
}

impl LabelVolume {
    /// Wrap labels; checks the length and that every label is a known tissue.
    pub fn new(dims: [usize; 3], voxel_mm: f64, data: Vec<u8>) -> Result<Self, PhantomError> {
        if !(voxel_mm.is_finite() && voxel_mm > 0.0) {
            return Err(PhantomError::Parameter {
                field: "voxel_mm",
                value: voxel_mm,
                reason: "must be positive".into(),
            });
        }
        let n = dims.iter().product::<usize>();
        if n == 0 || n != data.len() {
            return Err(PhantomError::Raw(format!(
                "dimensions {dims:?} need {n} voxels, got {}",
                data.len()
            )));
        }
        count_labels(&data)?;
        Ok(Self {
            dims,
            voxel_mm,
            data,
            pv: None,
        })
    }

    /// Attach partial volumes: `counts[i]` holds how many of voxel `i`'s
    /// `sub^3` fine samples are of each tissue (label order); each must sum to
    /// `sub^3` (at most 6 per axis, so that a count fits a byte).
    pub fn with_partial_volumes(
        mut self,
        sub: u8,
        counts: Vec<[u8; 5]>,
    ) -> Result<Self, PhantomError> {
        if !(1..=6).contains(&sub) {
            return Err(PhantomError::Parameter {
                field: "sub",
                value: sub as f64,
                reason: "fine samples per axis must lie in [1, 6]".into(),
            });
        }
        if counts.len() != self.data.len() {
            return Err(PhantomError::Raw(format!(
                "partial volumes for {} voxels, the volume has {}",
                counts.len(),
                self.data.len()
            )));
        }
        let n = (sub as u32).pow(3);
        if let Some(i) = counts
            .iter()
            .position(|c| c.iter().map(|&k| k as u32).sum::<u32>() != n)
        {
            return Err(PhantomError::Raw(format!(
                "voxel {i}: tissue counts {:?} do not sum to {n}",
                counts[i]
            )));
        }
        self.pv = Some(PartialVolumes { sub, counts });
        Ok(self)
    }

    /// The partial volumes, if the volume was drawn on a finer grid.
    pub fn partial_volumes(&self) -> Option<&PartialVolumes> {
        self.pv.as_ref()
    }

    /// Voxel counts `[lateral, vertical, depth]`.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Voxel side, mm.
    pub fn voxel_mm(&self) -> f64 {
        self.voxel_mm
    }

    /// All labels in storage order.
    pub fn labels(&self) -> &[u8] {
        &self.data
    }

    /// Number of coronal slices (the depth extent).
    pub fn n_coronal(&self) -> usize {
        self.dims[2]
    }

    /// Labels of coronal slice `d`, bottom row first, `[vertical][lateral]`.
    pub fn coronal(&self, d: usize) -> Result<&[u8], PhantomError> {
        if d >= self.dims[2] {
            return Err(PhantomError::SliceOutOfRange {
                index: d,
                count: self.dims[2],
            });
        }
        let n = self.dims[0] * self.dims[1];
        Ok(&self.data[d * n..(d + 1) * n])
    }

    /// Label at `(lateral, vertical, depth)`.
    pub fn at(&self, l: usize, v: usize, d: usize) -> u8 {
        self.data[(d * self.dims[1] + v) * self.dims[0] + l]
    }

    /// Attenuation at 20 keV (1/mm) of voxel `(lateral, vertical, depth)`:
    /// the mean of its fine samples' where the volume has partial volumes,
    /// else its label's.
    pub fn mu_at(&self, l: usize, v: usize, d: usize) -> f32 {
        let i = (d * self.dims[1] + v) * self.dims[0] + l;
        match &self.pv {
            Some(pv) => {
                pv.counts[i]
                    .iter()
                    .zip(MU_BY_LABEL)
                    .map(|(&k, m)| k as f32 * m)
                    .sum::<f32>()
                    / (pv.sub as f32).powi(3)
            }
            None => MU_BY_LABEL
                .get(self.data[i] as usize)
                .copied()
                .unwrap_or(0.0),
        }
    }

    /// Voxel counts per tissue, in label order.
    pub fn counts(&self) -> [u64; 5] {
        // Labels were validated on construction.
        count_labels(&self.data).unwrap_or([0; 5])
    }

    /// Fine-sample counts per tissue (label order): the partial volumes
    /// summed, or [`LabelVolume::counts`] for a volume without them.
    pub fn fine_counts(&self) -> [u64; 5] {
        match &self.pv {
            Some(pv) => pv.counts.iter().fold([0u64; 5], |mut acc, c| {
                for (a, &k) in acc.iter_mut().zip(c) {
                    *a += k as u64;
                }
                acc
            }),
            None => self.counts(),
        }
    }

    /// Ground-truth glandularity by mass of the whole volume (ligaments counted
    /// as fibroglandular, skin excluded), or `None` without breast tissue.
    /// With partial volumes, counted on the fine samples.
    pub fn glandularity(&self) -> Option<f64> {
        let c = self.fine_counts();
        glandularity(c[3] + c[4], c[1])
    }

    /// Compressed thickness: the vertical extent of the tissue, mm.
    pub fn thickness_mm(&self) -> f64 {
        match self.tissue_bounds() {
            Some(b) => (b[1][1] - b[1][0]) as f64 * self.voxel_mm,
            None => 0.0,
        }
    }

    /// Half-open index bounds `[[lo, hi]; 3]` of the non-air voxels, per axis.
    pub fn tissue_bounds(&self) -> Option<[[usize; 2]; 3]> {
        let [nx, nz, ny] = self.dims;
        let mut b = [[usize::MAX, 0]; 3];
        // A voxel holds tissue if its label does or, with partial volumes,
        // any of its fine samples does.
        let air = Tissue::Air.label() as usize;
        let holds = |i: usize| {
            self.data[i] != 0
                || self
                    .pv
                    .as_ref()
                    .is_some_and(|pv| pv.counts[i][air] as u32 != (pv.sub as u32).pow(3))
        };
        for d in 0..ny {
            for v in 0..nz {
                let base = (d * nz + v) * nx;
                let first = (0..nx).position(|l| holds(base + l));
                if let Some(f) = first {
                    let last = (0..nx).rposition(|l| holds(base + l)).unwrap_or(f);
                    b[0] = [b[0][0].min(f), b[0][1].max(last + 1)];
                    b[1] = [b[1][0].min(v), b[1][1].max(v + 1)];
                    b[2] = [b[2][0].min(d), b[2][1].max(d + 1)];
                }
            }
        }
        (b[0][0] != usize::MAX).then_some(b)
    }

    /// The volume cropped to the bounding box of its tissue, so that the breast
    /// rests on vertical index 0 and starts at the chest wall (depth 0).
    pub fn cropped_to_tissue(&self) -> Result<Self, PhantomError> {
        let b = self
            .tissue_bounds()
            .ok_or_else(|| PhantomError::Raw("the volume contains no tissue".into()))?;
        let dims = [b[0][1] - b[0][0], b[1][1] - b[1][0], b[2][1] - b[2][0]];
        let mut data = Vec::with_capacity(dims.iter().product());
        let mut pv = self.pv.as_ref().map(|p| PartialVolumes {
            sub: p.sub,
            counts: Vec::with_capacity(dims.iter().product()),
        });
        for d in b[2][0]..b[2][1] {
            for v in b[1][0]..b[1][1] {
                let base = (d * self.dims[1] + v) * self.dims[0];
                let r = base + b[0][0]..base + b[0][1];
                data.extend_from_slice(&self.data[r.clone()]);
                if let (Some(out), Some(src)) = (pv.as_mut(), self.pv.as_ref()) {
                    out.counts.extend_from_slice(&src.counts[r]);
                }
            }
        }
        Ok(Self {
            dims,
            voxel_mm: self.voxel_mm,
            data,
            pv,
        })
    }

    /// Nearest-neighbour resampling to another isotropic voxel size (labels are
    /// categorical, so they are sampled, never averaged). Voxel centres of the
    /// new grid are sampled in the old grid; the physical extent is kept up to
    /// one new voxel.
    pub fn resampled(&self, voxel_mm: f64) -> Result<Self, PhantomError> {
        if !(voxel_mm.is_finite() && voxel_mm > 0.0) {
            return Err(PhantomError::Parameter {
                field: "voxel_mm",
                value: voxel_mm,
                reason: "must be positive".into(),
            });
        }
        if (voxel_mm - self.voxel_mm).abs() < 1e-9 {
            return Ok(self.clone());
        }
        if self.pv.is_some() {
            return Err(PhantomError::Parameter {
                field: "voxel_mm",
                value: voxel_mm,
                reason: format!(
                    "a volume with partial volumes is drawn at its voxel ({} mm); draw it again at the new voxel instead of resampling",
                    self.voxel_mm
                ),
            });
        }
        let r = self.voxel_mm / voxel_mm;
        let nd = self.dims.map(|n| ((n as f64 * r).round() as usize).max(1));
        let map = |i: usize, axis: usize| -> usize {
            let c = ((i as f64 + 0.5) / r).floor() as usize;
            c.min(self.dims[axis] - 1)
        };
        let mut data = Vec::with_capacity(nd.iter().product());
        for d in 0..nd[2] {
            let sd = map(d, 2);
            for v in 0..nd[1] {
                let sv = map(v, 1);
                for l in 0..nd[0] {
                    data.push(self.at(map(l, 0), sv, sd));
                }
            }
        }
        Ok(Self {
            dims: nd,
            voxel_mm,
            data,
            pv: None,
        })
    }
}

/// One coronal slice placed on the image grid of a geometry.
#[derive(Debug, Clone, PartialEq)]
pub struct Slice {
    /// Labels, image layout: row 0 at the top, `rows x columns`.
    pub labels: Vec<u8>,
    /// Compressed breast thickness of the phantom, mm (what the gantry reports).
    pub thickness_mm: f64,
    /// Attenuation from the partial volumes (the mean of the fine samples'),
    /// image layout, for a volume that has them.
    pub partial_mu: Option<Vec<f32>>,
    /// Each label's share of the fine samples (air, adipose, skin,
    /// fibroglandular, ligament), image layout, for a volume that has
    /// partial volumes.
    pub partial_shares: Option<Vec<[f32; 5]>>,
}

impl Slice {
    /// Attenuation image at 20 keV (1/mm), image layout: the partial volumes'
    /// where the volume has them, else the labels'.
    pub fn mu(&self) -> Vec<f32> {
        match &self.partial_mu {
            Some(mu) => mu.clone(),
            None => labels_to_mu(&self.labels),
        }
    }

    /// The share of each pixel that is adipose, fibroglandular (Cooper's
    /// ligaments included: the same composition) and skin tissue, image
    /// layout (the partial volumes' where the volume has them, else 0 or 1
    /// from the labels): what a polychromatic acquisition projects per
    /// material.
    pub fn material_shares(&self) -> [Vec<f32>; 3] {
        let n = self.labels.len();
        let mut out = [vec![0f32; n], vec![0f32; n], vec![0f32; n]];
        for i in 0..n {
            let f = match &self.partial_shares {
                Some(p) => p[i],
                None => {
                    let mut f = [0f32; 5];
                    if let Some(x) = f.get_mut(self.labels[i] as usize) {
                        *x = 1.0;
                    }
                    f
                }
            };
            out[0][i] = f[Tissue::Adipose.label() as usize];
            out[1][i] =
                f[Tissue::Fibroglandular.label() as usize] + f[Tissue::Ligament.label() as usize];
            out[2][i] = f[Tissue::Skin.label() as usize];
        }
        out
    }

    /// The breast-thickness mask of the paper: 1 on every image row whose
    /// centre lies within the compressed thickness above the support, across the
    /// full width; 0 above. Encoded as `f32` 0/1, image layout.
    pub fn thickness_mask(&self, geom: &Geometry) -> Vec<f32> {
        thickness_mask(geom, self.thickness_mm)
    }
}

/// Attenuation (1/mm) of each label; labels must be valid tissue codes.
pub fn labels_to_mu(labels: &[u8]) -> Vec<f32> {
    labels
        .iter()
        .map(|&l| MU_BY_LABEL.get(l as usize).copied().unwrap_or(0.0))
        .collect()
}

/// The thickness mask (see [`Slice::thickness_mask`]) for a reported thickness.
pub fn thickness_mask(geom: &Geometry, thickness_mm: f64) -> Vec<f32> {
    let rows = geom.image.rows;
    let cols = geom.image.columns;
    let inside = geom.rows_within_thickness(thickness_mm);
    let mut m = vec![0.0f32; rows * cols];
    m[(rows - inside) * cols..].fill(1.0);
    m
}

/// Place coronal slice `d` of `vol` on the image grid of `geom`: the breast
/// rests on the bottom row and the volume's lateral centre sits at `x = 0`.
/// The volume's voxel must equal the geometry's pixel (resample first with
/// [`LabelVolume::resampled`]); the phantom must fit the image.
pub fn coronal_slice(vol: &LabelVolume, d: usize, geom: &Geometry) -> Result<Slice, PhantomError> {
    let src = vol.coronal(d)?;
    if (vol.voxel_mm - geom.image.pixel_mm).abs() > 1e-9 {
        return Err(PhantomError::DoesNotFit(format!(
            "voxel {} mm differs from the image pixel {} mm; resample the volume first",
            vol.voxel_mm, geom.image.pixel_mm
        )));
    }
    let [nx, nz, _] = vol.dims;
    let (rows, cols) = (geom.image.rows, geom.image.columns);
    // Vertical: only rows holding tissue must fit (air above is dropped).
    let plane = nx * nz;
    let air_pv = |i: usize| {
        vol.pv.as_ref().is_none_or(|pv| {
            pv.counts[d * plane + i][Tissue::Air.label() as usize] as u32 == (pv.sub as u32).pow(3)
        })
    };
    let top = (0..nz)
        .rev()
        .find(|&v| (v * nx..(v + 1) * nx).any(|i| src[i] != 0 || !air_pv(i)))
        .map_or(0, |v| v + 1);
    if top > rows {
        return Err(PhantomError::DoesNotFit(format!(
            "tissue is {} mm high, the image only {} mm ({} rows)",
            top as f64 * vol.voxel_mm,
            geom.height_mm(),
            rows
        )));
    }
    if nx > cols {
        // Lateral air margins may be trimmed, tissue may not.
        let b = vol.tissue_bounds().unwrap_or([[0, 0]; 3]);
        let (lo, hi) = (b[0][0], b[0][1]);
        let off = (nx - cols) / 2;
        if lo < off || hi > off + cols {
            return Err(PhantomError::DoesNotFit(format!(
                "tissue is {} mm wide, the image only {} mm",
                (hi - lo) as f64 * vol.voxel_mm,
                geom.width_mm()
            )));
        }
    }
    let mut labels = vec![0u8; rows * cols];
    let pv = vol.pv.as_ref().map(|pv| {
        let n = nx * nz;
        (&pv.counts[d * n..(d + 1) * n], (pv.sub as f32).powi(3))
    });
    let mut partial_mu = pv.map(|_| vec![0f32; rows * cols]);
    let mut partial_shares = pv.map(|_| vec![[0f32; 5]; rows * cols]);
    // Column c of the image holds lateral index c + shift.
    let shift = nx as isize / 2 - cols as isize / 2;
    for v in 0..top {
        let row = rows - 1 - v;
        for c in 0..cols {
            let l = c as isize + shift;
            if l >= 0 && (l as usize) < nx {
                labels[row * cols + c] = src[v * nx + l as usize];
                if let (Some(mu), Some((counts, n))) = (partial_mu.as_mut(), pv) {
                    let k = counts[v * nx + l as usize];
                    mu[row * cols + c] = k
                        .iter()
                        .zip(MU_BY_LABEL)
                        .map(|(&k, m)| k as f32 * m)
                        .sum::<f32>()
                        / n;
                    if let Some(sh) = partial_shares.as_mut() {
                        sh[row * cols + c] = k.map(|k| k as f32 / n);
                    }
                }
            }
        }
    }
    Ok(Slice {
        labels,
        thickness_mm: vol.thickness_mm(),
        partial_mu,
        partial_shares,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tiny() -> LabelVolume {
        // 4 lateral x 3 vertical x 2 depth
        let mut data = vec![0u8; 24];
        data[1] = 1; // (1,0,0)
        data[4 + 2] = 3; // (2,1,0)
        data[12 + 1] = 2; // (1,0,1)
        LabelVolume::new([4, 3, 2], 0.5, data).unwrap()
    }

    /// The material shares a polychromatic acquisition projects: from the
    /// labels (0 or 1) or the partial volumes; weighted by the tissues'
    /// attenuation they give the slice's attenuation image.
    #[test]
    fn material_shares_add_up_to_the_attenuation() {
        let g = Geometry::builtin("paper").unwrap().binned(4).unwrap();
        // 2 lateral x 1 vertical x 1 depth: adipose | fine mixture.
        let v = LabelVolume::new([2, 1, 1], g.image.pixel_mm, vec![1, 3]).unwrap();
        let s = coronal_slice(&v, 0, &g).unwrap();
        let [a, f, k] = s.material_shares();
        let mu = s.mu();
        for i in 0..mu.len() {
            let want = a[i] * Tissue::Adipose.mu_per_mm()
                + f[i] * Tissue::Fibroglandular.mu_per_mm()
                + k[i] * Tissue::Skin.mu_per_mm();
            assert!((want - mu[i]).abs() < 1e-7, "pixel {i}");
        }
        assert_eq!(a.iter().sum::<f32>(), 1.0);
        // 8 fine samples: 4 adipose, 1 skin, 2 fibroglandular, 1 ligament.
        let pv = v
            .clone()
            .with_partial_volumes(2, vec![[8, 0, 0, 0, 0], [0, 4, 1, 2, 1]])
            .unwrap();
        let s = coronal_slice(&pv, 0, &g).unwrap();
        let [a, f, k] = s.material_shares();
        let mu = s.mu();
        let c = mu.iter().position(|&m| m > 0.0).unwrap();
        assert_eq!((a[c], f[c], k[c]), (0.5, 0.375, 0.125));
        let want = 0.5 * Tissue::Adipose.mu_per_mm()
            + 0.375 * Tissue::Fibroglandular.mu_per_mm()
            + 0.125 * Tissue::Skin.mu_per_mm();
        assert!((mu[c] - want).abs() < 1e-7);
    }

    #[test]
    fn layout_bounds_crop() {
        let v = tiny();
        assert_eq!(v.at(2, 1, 0), 3);
        assert_eq!(v.tissue_bounds(), Some([[1, 3], [0, 2], [0, 2]]));
        let c = v.cropped_to_tissue().unwrap();
        assert_eq!(c.dims(), [2, 2, 2]);
        assert_eq!(c.at(1, 1, 0), 3);
        assert!((v.thickness_mm() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn bad_volumes_rejected() {
        assert!(matches!(
            LabelVolume::new([2, 2, 2], 1.0, vec![0; 7]),
            Err(PhantomError::Raw(_))
        ));
        assert!(matches!(
            LabelVolume::new([2, 1, 1], 1.0, vec![0, 7]),
            Err(PhantomError::Label(UnknownLabel(7)))
        ));
        assert!(LabelVolume::new([2, 1, 1], 0.0, vec![0, 0]).is_err());
    }

    /// Population names round-trip and an unknown one names the known; the
    /// mixed population is the anatomical one except every third phantom,
    /// which is the procedural one's.
    #[test]
    fn population_kinds_parse_and_mix() {
        for k in PopulationKind::ALL {
            assert_eq!(PopulationKind::parse(k.name()).unwrap(), k);
            assert_eq!(k.to_string().parse::<PopulationKind>().unwrap(), k);
        }
        let e = PopulationKind::parse("victre").unwrap_err().to_string();
        assert!(
            e.contains("victre") && e.contains("procedural, anatomical, mixed"),
            "{e}"
        );
        let g = Geometry::builtin("paper-104").unwrap().binned(4).unwrap();
        for i in 0..6 {
            let m = PopulationKind::Mixed.draw(&g, 9, i);
            let want = if i % 3 == 2 {
                PopulationKind::Procedural.draw(&g, 9, i)
            } else {
                PopulationKind::Anatomical.draw(&g, 9, i)
            };
            assert_eq!(m, want);
        }
    }

    /// Partial volumes: refused when they do not add up or do not match the
    /// volume; counted by `glandularity`; kept by cropping; a resampling
    /// that would drop them is refused.
    #[test]
    fn partial_volumes_are_checked_and_counted() {
        let v = tiny();
        let n = v.labels().len();
        let mut counts = vec![[8u8, 0, 0, 0, 0]; n];
        assert!(v
            .clone()
            .with_partial_volumes(2, counts[..n - 1].to_vec())
            .is_err());
        counts[0] = [7, 0, 0, 0, 0];
        let e = v
            .clone()
            .with_partial_volumes(2, counts.clone())
            .unwrap_err()
            .to_string();
        assert!(e.contains("voxel 0") && e.contains("8"), "{e}");
        assert!(v.clone().with_partial_volumes(7, vec![[0; 5]; n]).is_err());
        // Voxels (1,0,0) and (1,0,1) all skin, voxel (2,1,0) 3 of 8 fine
        // samples fibroglandular and 5 adipose (whatever their labels say).
        let mut counts = vec![[8u8, 0, 0, 0, 0]; n];
        counts[1] = [0, 0, 8, 0, 0];
        counts[4 + 2] = [0, 5, 0, 3, 0];
        counts[12 + 1] = [0, 0, 8, 0, 0];
        let pv = v.clone().with_partial_volumes(2, counts).unwrap();
        let want = dbt_materials::glandularity(3, 5).unwrap();
        assert!((pv.glandularity().unwrap() - want).abs() < 1e-12);
        assert_eq!(v.glandularity(), dbt_materials::glandularity(1, 1));
        let mu = pv.mu_at(2, 1, 0);
        let m = MU_BY_LABEL;
        assert!((mu - (5.0 * m[1] + 3.0 * m[3]) / 8.0).abs() < 1e-7);
        let c = pv.cropped_to_tissue().unwrap();
        assert_eq!(c.fine_counts()[1..], pv.fine_counts()[1..]);
        assert!(pv.resampled(0.25).is_err());
        assert_eq!(pv.resampled(0.5).unwrap(), pv);
    }

    #[test]
    fn resample_keeps_extent_and_labels() {
        let v = tiny();
        let r = v.resampled(0.25).unwrap();
        assert_eq!(r.dims(), [8, 6, 4]);
        assert_eq!(r.at(2, 0, 0), 1);
        assert_eq!(r.at(3, 1, 1), 1);
        assert_eq!(r.at(4, 2, 0), 3);
        let back = r.resampled(0.5).unwrap();
        assert_eq!(back, v);
    }

    #[test]
    fn slice_rests_on_bottom_row_centred() {
        let g = Geometry::paper().binned(4).unwrap();
        let vol = LabelVolume::new([4, 3, 1], g.image.pixel_mm, {
            let mut d = vec![1u8; 12];
            d[8..].fill(0); // top vertical row is air
            d
        })
        .unwrap();
        let s = coronal_slice(&vol, 0, &g).unwrap();
        let (rows, cols) = (g.image.rows, g.image.columns);
        let c0 = cols / 2 - 2;
        assert_eq!(s.labels[(rows - 1) * cols + c0], 1);
        assert_eq!(s.labels[(rows - 2) * cols + c0 + 3], 1);
        assert_eq!(s.labels[(rows - 3) * cols + c0], 0);
        assert_eq!(s.labels[(rows - 1) * cols + c0 - 1], 0);
        assert_eq!(s.labels.iter().filter(|&&l| l == 1).count(), 8);
        // Mask: 2 rows thick (1.6 mm at 0.8 mm pixels).
        let m = s.thickness_mask(&g);
        assert_eq!(m.iter().filter(|&&x| x == 1.0).count(), 2 * cols);
        assert!(matches!(
            coronal_slice(&vol, 1, &g),
            Err(PhantomError::SliceOutOfRange { .. })
        ));
        let wrong = vol.resampled(0.4).unwrap();
        assert!(matches!(
            coronal_slice(&wrong, 0, &g),
            Err(PhantomError::DoesNotFit(_))
        ));
    }
}
