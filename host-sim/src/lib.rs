//! Simulated breasts and acquisitions for the host simulator, the dataset
//! exporter and the evaluation: one phantom through the shared geometry,
//! materials, projector and noise model to per-slice records.

pub mod dataset;
pub mod modbus;
pub mod stream;

use dbt_pipeline::acquisition::{
    Acquisition as AcqFile, AcquisitionHeader, Patient, Study, ACQ_FORMAT,
};

use dbt_acquisition::{simulate_from_line_integrals, NoiseLevel};
use dbt_geometry::Geometry;
use dbt_phantom::{coronal_slice, LabelVolume, PhantomError};
use dbt_projector::{Projector, ProjectorError};
use rayon::prelude::*;
use thiserror::Error;

/// Errors of the simulation.
#[derive(Debug, Error)]
pub enum SimError {
    /// Phantom generation or slicing failed.
    #[error(transparent)]
    Phantom(#[from] PhantomError),
    /// The projector rejected an image.
    #[error(transparent)]
    Projector(#[from] ProjectorError),
    /// A file adapter failed.
    #[error(transparent)]
    Store(#[from] dbt_store::StoreError),
    /// A reconstruction for a derived array failed.
    #[error(transparent)]
    Recon(#[from] dbt_recon::ReconError),
    /// Options that cannot work.
    #[error("{0}")]
    Options(String),
    /// The cone-beam projector refused the volume or the system.
    #[error("cone-beam projection: {0}")]
    Cone(String),
}

/// One simulated coronal slice.
#[derive(Debug, Clone, PartialEq)]
pub struct SimSlice {
    /// Coronal index (depth from the chest wall, voxels).
    pub depth: usize,
    /// Labels, image layout.
    pub labels: Vec<u8>,
    /// Attenuation at 20 keV, 1/mm, image layout.
    pub mu: Vec<f32>,
    /// Thickness mask, 0/1, image layout.
    pub mask: Vec<f32>,
    /// Compressed thickness, mm.
    pub thickness_mm: f64,
    /// Counts per noise level (view-major), in the order asked.
    pub counts: Vec<Vec<f32>>,
    /// Flux per noise level.
    pub flux: Vec<f64>,
}

/// A reproducible seed for (base, a, b, c): SplitMix64 over the tuple.
pub fn mix_seed(base: u64, parts: &[u64]) -> u64 {
    let mut x = base;
    for &p in parts {
        x ^= p.wrapping_add(0x9E37_79B9_7F4A_7C15);
        x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = x;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        x = z ^ (z >> 31);
    }
    x
}

/// The coronal indices holding tissue, every `step`-th one.
pub fn tissue_slices(vol: &LabelVolume, step: usize) -> Vec<usize> {
    (0..vol.n_coronal())
        .filter(|&d| vol.coronal(d).is_ok_and(|s| s.iter().any(|&l| l != 0)))
        .step_by(step.max(1))
        .collect()
}

/// Simulate the acquisitions of the given coronal slices of `vol` at each
/// noise level. Noise seeds derive from `(seed, depth, level)` only, so the
/// result does not depend on which other slices are simulated or on threads.
pub fn simulate_slices(
    vol: &LabelVolume,
    geom: &Geometry,
    projector: &Projector,
    depths: &[usize],
    levels: &[NoiseLevel],
    seed: u64,
) -> Result<Vec<SimSlice>, SimError> {
    depths
        .par_iter()
        .map(|&d| {
            let _span = tracing::debug_span!("simulate_slice", depth = d).entered();
            let s = coronal_slice(vol, d, geom)?;
            let mu = s.mu();
            let mut p = vec![0f32; projector.range_len()];
            projector.forward(&mu, &mut p)?;
            let (mut counts, mut flux) = (Vec::new(), Vec::new());
            for (k, &lvl) in levels.iter().enumerate() {
                let a =
                    simulate_from_line_integrals(&p, lvl, mix_seed(seed, &[d as u64, k as u64]));
                counts.push(a.counts);
                flux.push(a.flux);
            }
            Ok(SimSlice {
                depth: d,
                mask: s.thickness_mask(geom),
                labels: s.labels,
                mu,
                thickness_mm: s.thickness_mm,
                counts,
                flux,
            })
        })
        .collect()
}

/// Technique of a simulated acquisition (plausible values, not a measured
/// tube): the kV of the paper's Table 3 for the thickness, a sweep of
/// `mas_total` and a tube output at the reference point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Technique {
    /// Tube loading of the sweep, mAs.
    pub mas_total: f64,
    /// Incident air kerma at the reference point per mAs, mGy/mAs.
    pub tube_output_mgy_per_mas: f64,
}

impl Default for Technique {
    fn default() -> Self {
        Self {
            mas_total: 60.0,
            tube_output_mgy_per_mas: 0.11,
        }
    }
}

/// Simulate the whole acquisition of a phantom: every coronal slice at one
/// noise level, with a synthetic patient and study (UIDs under `uid_root`).
#[allow(clippy::too_many_arguments)]
pub fn simulate_acquisition(
    vol: &LabelVolume,
    geom: &Geometry,
    noise: NoiseLevel,
    seed: u64,
    technique: Technique,
    kvp: f64,
    patient_id: &str,
    uid_root: &str,
) -> Result<AcqFile, SimError> {
    let _span = tracing::info_span!("acquisition", patient_id).entered();
    let proj = Projector::new(geom);
    let depths: Vec<usize> = (0..vol.n_coronal()).collect();
    let slices = simulate_slices(vol, geom, &proj, &depths, &[noise], seed)?;
    let mut file =
        simulate_acquisition_header(vol, geom, noise, seed, technique, kvp, patient_id, uid_root);
    file.header.slices = slices.len();
    file.counts = slices
        .into_iter()
        .map(|s| s.counts.into_iter().next().unwrap_or_default())
        .collect();
    Ok(file)
}

/// The header of a simulated acquisition (patient, study, technique,
/// truth), with no counts yet.
#[allow(clippy::too_many_arguments)]
fn simulate_acquisition_header(
    vol: &LabelVolume,
    geom: &Geometry,
    noise: NoiseLevel,
    seed: u64,
    technique: Technique,
    kvp: f64,
    patient_id: &str,
    uid_root: &str,
) -> AcqFile {
    let thickness = vol.thickness_mm();
    let uid = |k: u64| format!("{uid_root}.{seed}.{k}");
    let header = AcquisitionHeader {
        format: ACQ_FORMAT.into(),
        geometry: geom.clone(),
        thickness_mm: thickness,
        flux: noise.flux(),
        slices: 0,
        slice_spacing_mm: vol.voxel_mm(),
        kvp,
        mas_total: technique.mas_total,
        tube_output_mgy_per_mas: technique.tube_output_mgy_per_mas,
        laterality: "L".into(),
        compression_force_n: None,
        exposure_ms_per_view: None,
        system: None,
        patient: Patient {
            name: format!("Phantom^{patient_id}"),
            id: patient_id.into(),
            birth_date: "".into(),
            sex: "F".into(),
        },
        study: Study {
            study_uid: uid(1),
            date: "20261122".into(),
            time: "120000".into(),
            accession: format!("SIM{:013}", seed % 10_000_000_000_000),
            study_id: "1".into(),
            series_uid: uid(2),
            instance_uids: (0..geom.n_views() as u64).map(|v| uid(100 + v)).collect(),
            source_class: None,
        },
        truth: Some(serde_json::json!({
            "glandularity": vol.glandularity(),
            "thickness_mm": thickness,
            "noise": noise.name(),
            "voxel_mm": vol.voxel_mm(),
            "dims": vol.dims(),
        })),
    };
    AcqFile {
        header,
        counts: vec![],
    }
}

/// Simulate a phantom's acquisition on a cone-beam system (issue #28): the
/// whole 3-D attenuation volume (the coronal slices as placed on `geom`'s
/// image grid, resting on the support) projected by the exact cone-beam
/// projector (`dbt_cone`), with Poisson noise at `noise`'s flux per detector
/// element. The header is `simulate_acquisition`'s, with `system` set and
/// the counts the detector's frames (`[row][view * column]`); `geom` is the
/// fan geometry the firmware reconstructs in (its image must rest on the
/// system's support).
#[allow(clippy::too_many_arguments)]
pub fn simulate_cone_acquisition(
    vol: &LabelVolume,
    geom: &Geometry,
    system: &dbt_geometry::ConeSystem,
    noise: NoiseLevel,
    seed: u64,
    technique: Technique,
    kvp: f64,
    patient_id: &str,
    uid_root: &str,
) -> Result<AcqFile, SimError> {
    let _span =
        tracing::info_span!("cone_acquisition", patient_id, system = %system.name).entered();
    let (cols, rows) = (geom.image.columns, geom.image.rows);
    let grid = dbt_cone::VolumeGrid {
        lateral: cols,
        vertical: rows,
        depth: vol.n_coronal(),
        voxel_mm: geom.image.pixel_mm,
    };
    let mut mu = vec![0.0f32; grid.len()];
    for d in 0..vol.n_coronal() {
        let s = coronal_slice(vol, d, geom)?.mu();
        for v in 0..rows {
            for l in 0..cols {
                mu[grid.index(l, v, d)] = s[(rows - 1 - v) * cols + l];
            }
        }
    }
    let proj =
        dbt_cone::ConeProjector::new(system, grid).map_err(|e| SimError::Cone(e.to_string()))?;
    let p = proj
        .forward(&mu)
        .map_err(|e| SimError::Cone(e.to_string()))?;
    let (drows, dcols, views) = (
        system.detector.rows,
        system.detector.columns,
        system.n_views(),
    );
    // Frames: detector row r across the views.
    let mut frames_li = vec![0.0f32; p.len()];
    for v in 0..views {
        for r in 0..drows {
            let from = (v * drows + r) * dcols;
            let to = r * views * dcols + v * dcols;
            frames_li[to..to + dcols].copy_from_slice(&p[from..from + dcols]);
        }
    }
    let a = simulate_from_line_integrals(&frames_li, noise, mix_seed(seed, &[u64::MAX]));
    let mut file =
        simulate_acquisition_header(vol, geom, noise, seed, technique, kvp, patient_id, uid_root);
    file.header.system = Some(system.clone());
    file.header.slices = drows;
    file.header.flux = a.flux;
    file.counts = a
        .counts
        .chunks(views * dcols)
        .map(<[f32]>::to_vec)
        .collect();
    Ok(file)
}
