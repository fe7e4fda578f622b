//! Simulated breasts and acquisitions for the host simulator, the dataset
//! exporter and the evaluation: one phantom through the shared geometry,
//! materials, projector and noise model to per-slice records.

pub mod dataset;
pub mod modbus;
pub mod stream;

use dbt_pipeline::acquisition::{
    Acquisition as AcqFile, AcquisitionHeader, Patient, Study, ACQ_FORMAT,
};

use dbt_forward::{simulate_from_line_integrals, NoiseLevel};
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

/// The physics an acquisition is simulated with (issue #27).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Physics {
    /// The paper's: one energy (20 keV), a photon-counting detector, Poisson
    /// noise at the noise level's photons per element.
    #[default]
    Mono,
    /// A polychromatic beam (the spectrum of the acquisition's kV,
    /// `dbt_dose::xray::technique_spectrum`: the one the dose uses), an energy-integrating
    /// detector (200 um of CsI, or the converter a cone-beam system's file states:
    /// [`Physics::on_system`]), quantum and electronic noise
    /// (`dbt_forward::clinical`): the noise level's photons reach each
    /// element without the breast (an N8-equivalent dose at N8), and its
    /// flat field reads that many ADU; with `scatter`, each view's scatter
    /// from the shipped kernel model (`dbt_scatter`, fitted to our Monte
    /// Carlo engine) added before the noise.
    Clinical {
        /// The detector.
        detector: dbt_forward::clinical::Detector,
        /// Whether the scatter reaches the detector (no grid).
        scatter: bool,
    },
}

impl Physics {
    /// Parse `mono`, `clinical` (the default detector, with scatter) or
    /// `clinical-primary` (without scatter: session 19's figures).
    pub fn parse(s: &str) -> Result<Self, SimError> {
        match s {
            "mono" => Ok(Physics::Mono),
            "clinical" => Ok(Physics::Clinical {
                detector: Default::default(),
                scatter: true,
            }),
            "clinical-primary" => Ok(Physics::Clinical {
                detector: Default::default(),
                scatter: false,
            }),
            other => Err(SimError::Options(format!(
                "physics {other:?}: expected mono, clinical or clinical-primary"
            ))),
        }
    }

    /// The clinical model's detector (`None` for the mono model).
    pub fn detector(&self) -> Option<dbt_forward::clinical::Detector> {
        match self {
            Physics::Mono => None,
            Physics::Clinical { detector, .. } => Some(*detector),
        }
    }

    /// The same physics on `system`'s detector: the clinical model's
    /// converter becomes the system's (`ConeSystem::converter`: its file's
    /// `[detector.converter]`, a-Se for Hologic and Siemens, else 200 um of
    /// CsI), the one the firmware's linearisation checks against; and its
    /// line spread, where the file states one (`line_spread_um`: GE's CsI,
    /// Hologic's tomosynthesis mode; `dbt_forward::spread`).
    pub fn on_system(self, system: &dbt_geometry::ConeSystem) -> Self {
        match self {
            Physics::Clinical { detector, scatter } => Physics::Clinical {
                detector: dbt_forward::clinical::Detector {
                    converter: system.converter(),
                    line_spread_mm: system.line_spread_mm(),
                    ..detector
                },
                scatter,
            },
            Physics::Mono => Physics::Mono,
        }
    }

    /// Its name.
    pub fn name(&self) -> &'static str {
        match self {
            Physics::Mono => "mono",
            Physics::Clinical { scatter: true, .. } => "clinical",
            Physics::Clinical { scatter: false, .. } => "clinical-primary",
        }
    }

    /// The clinical model of an exposure with `technique`'s beam at `kvp`
    /// of a breast `thickness_mm` thick at `noise` (the spectrum:
    /// `dbt_dose::xray::technique_spectrum`, as the dose's).
    fn clinical(
        detector: &dbt_forward::clinical::Detector,
        technique: Technique,
        kvp: f64,
        thickness_mm: f64,
        noise: NoiseLevel,
    ) -> Result<dbt_forward::clinical::ClinicalPhysics, SimError> {
        let tube = dbt_dose::xray::technique_spectrum(technique.anode_filter, kvp, thickness_mm)
            .map_err(|e| SimError::Options(e.to_string()))?;
        let spectrum = tube
            .spectrum
            .ok_or_else(|| SimError::Options("no spectrum".into()))?;
        let n = noise.flux();
        dbt_forward::clinical::ClinicalPhysics::new(&spectrum, n, detector, n)
            .map_err(|e| SimError::Options(e.to_string()))
    }
}

/// Signals of rays with per-material path lengths under `physics`'s
/// clinical model (noise-free at `NoiseFree`), the rays forming the stack
/// `layout` of detector images; with scatter, of a breast `thickness_mm`
/// thick exposed with the beam `af` (its shipped scatter table).
fn clinical_signals(
    model: &dbt_forward::clinical::ClinicalPhysics,
    paths: &[Vec<f32>; 3],
    layout: &dbt_forward::clinical::StackLayout,
    scatter: Option<(f64, dbt_dose::xray::AnodeFilter)>,
    noise: NoiseLevel,
    seed: u64,
) -> Result<Vec<f32>, SimError> {
    let err = |e: dbt_forward::AcquisitionError| SimError::Options(e.to_string());
    let noisy = noise != NoiseLevel::NoiseFree;
    let table = scatter
        .map(|(thickness, af)| {
            dbt_scatter::ScatterTable::shipped_for(af.name())
                .map(|t| (t, thickness))
                .map_err(|e| SimError::Options(e.to_string()))
        })
        .transpose()?;
    Ok(model
        .simulate_stack(paths, layout, table, noisy, seed)
        .map_err(err)?
        .0)
}

/// The positions of one exposure of each view: the system itself for a
/// step-and-shoot gantry, else the source (with a detector that moves with
/// it) at three points across the arc `source_blur_deg` it travels during
/// the exposure, the midpoints of its thirds.
pub fn exposure_positions(
    system: &dbt_geometry::ConeSystem,
) -> Result<Vec<dbt_geometry::ConeSystem>, SimError> {
    let b = system.source_blur_deg;
    if b == 0.0 {
        return Ok(vec![system.clone()]);
    }
    [-b / 3.0, 0.0, b / 3.0]
        .iter()
        .map(|&off| {
            let mut s = system.clone();
            s.source_blur_deg = 0.0;
            s.views.first_deg += off;
            s.views.last_deg += off;
            s.view_angles_deg = Some(
                (0..system.n_views())
                    .map(|v| system.angle_deg(v) + off)
                    .collect(),
            );
            s.validate().map_err(|e| SimError::Cone(e.to_string()))?;
            Ok(s)
        })
        .collect()
}

/// The line integral of the mean transmission of each ray over several
/// positions' line integrals: `-ln(mean exp(-p))`.
fn mean_transmission_path(ps: &[Vec<f32>]) -> Vec<f32> {
    if ps.len() == 1 {
        return ps[0].clone();
    }
    let n = ps.len() as f64;
    (0..ps[0].len())
        .map(|i| {
            let t: f64 = ps.iter().map(|p| (-f64::from(p[i])).exp()).sum::<f64>() / n;
            (-t.ln()) as f32
        })
        .collect()
}

/// The mean of several positions' paths, ray by ray.
fn mean_path(ps: &[Vec<f32>]) -> Vec<f32> {
    let n = ps.len() as f32;
    (0..ps[0].len())
        .map(|i| ps.iter().map(|p| p[i]).sum::<f32>() / n)
        .collect()
}

/// Technique of a simulated acquisition (plausible values, not a measured
/// tube): the beam, a sweep of `mas_total` and a tube output at the
/// reference point (the kV is the beam's automatic exposure for the
/// thickness, `AnodeFilter::aec_kv`, passed beside it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Technique {
    /// Anode and filter (the default: the paper's W/Rh).
    pub anode_filter: dbt_dose::xray::AnodeFilter,
    /// Tube loading of the sweep, mAs.
    pub mas_total: f64,
    /// Incident air kerma at the reference point per mAs, mGy/mAs.
    pub tube_output_mgy_per_mas: f64,
}

impl Default for Technique {
    fn default() -> Self {
        Self {
            anode_filter: Default::default(),
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

/// [`simulate_acquisition`] under `physics`: the mono-energetic model is
/// [`simulate_acquisition`] itself; the clinical one projects each
/// coronal slice's adipose, fibroglandular and skin shares and records the
/// polychromatic signal of each ray (`Physics::Clinical`); the header's
/// flux is then the detector's flat field, its truth names the physics.
#[allow(clippy::too_many_arguments)]
pub fn simulate_acquisition_with(
    vol: &LabelVolume,
    geom: &Geometry,
    noise: NoiseLevel,
    physics: Physics,
    seed: u64,
    technique: Technique,
    kvp: f64,
    patient_id: &str,
    uid_root: &str,
) -> Result<AcqFile, SimError> {
    let Physics::Clinical { detector, scatter } = physics else {
        return simulate_acquisition(vol, geom, noise, seed, technique, kvp, patient_id, uid_root);
    };
    let _span = tracing::info_span!("acquisition", patient_id, physics = physics.name()).entered();
    let model = Physics::clinical(&detector, technique, kvp, vol.thickness_mm(), noise)?;
    let proj = Projector::new(geom);
    let paths: Vec<[Vec<f32>; 3]> = (0..vol.n_coronal())
        .into_par_iter()
        .map(|d| {
            let s = coronal_slice(vol, d, geom)?;
            let shares = s.material_shares();
            let mut paths: [Vec<f32>; 3] = Default::default();
            for (p, img) in paths.iter_mut().zip(&shares) {
                *p = vec![0f32; proj.range_len()];
                proj.forward(img, p)?;
            }
            Ok(paths)
        })
        .collect::<Result<_, SimError>>()?;
    let counts: Vec<Vec<f32>> = if scatter {
        let layout = dbt_forward::clinical::StackLayout::fan(geom, paths.len(), vol.voxel_mm());
        let all: [Vec<f32>; 3] =
            std::array::from_fn(|m| paths.iter().flat_map(|p| p[m].iter().copied()).collect());
        let signals = clinical_signals(
            &model,
            &all,
            &layout,
            Some((vol.thickness_mm(), technique.anode_filter)),
            noise,
            mix_seed(seed, &[u64::MAX - 1]),
        )?;
        signals
            .chunks(proj.range_len())
            .map(<[f32]>::to_vec)
            .collect()
    } else {
        // Each slice's rays alone: one detector row.
        let layout = dbt_forward::clinical::StackLayout::fan(geom, 1, vol.voxel_mm());
        paths
            .par_iter()
            .enumerate()
            .map(|(d, p)| {
                clinical_signals(
                    &model,
                    p,
                    &layout,
                    None,
                    noise,
                    mix_seed(seed, &[d as u64, 0]),
                )
            })
            .collect::<Result<_, SimError>>()?
    };
    let mut file =
        simulate_acquisition_header(vol, geom, noise, seed, technique, kvp, patient_id, uid_root);
    file.header.slices = counts.len();
    file.header.flux = model.flat_adu();
    if let Some(t) = file.header.truth.as_mut() {
        t["physics"] = physics.name().into();
        if let Some(d) = physics.detector() {
            t["detector"] = d.converter.to_string().into();
        }
    }
    file.counts = counts;
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
        anode_filter: technique.anode_filter,
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

/// The acquisition of `vol` under `physics`: on the cone-beam `system` when
/// given ([`simulate_cone_acquisition_with`]; `geom` its rebinning fan),
/// else every coronal slice its own fan beam of `geom`
/// ([`simulate_acquisition_with`]).
#[allow(clippy::too_many_arguments)]
pub fn simulate_on(
    vol: &LabelVolume,
    geom: &Geometry,
    system: Option<&dbt_geometry::ConeSystem>,
    noise: NoiseLevel,
    physics: Physics,
    seed: u64,
    technique: Technique,
    kvp: f64,
    patient_id: &str,
    uid_root: &str,
) -> Result<AcqFile, SimError> {
    match system {
        None => simulate_acquisition_with(
            vol, geom, noise, physics, seed, technique, kvp, patient_id, uid_root,
        ),
        Some(sys) => simulate_cone_acquisition_with(
            vol, geom, sys, noise, physics, seed, technique, kvp, patient_id, uid_root,
        ),
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
    simulate_cone_acquisition_with(
        vol,
        geom,
        system,
        noise,
        Physics::Mono,
        seed,
        technique,
        kvp,
        patient_id,
        uid_root,
    )
}

/// [`simulate_cone_acquisition`] under `physics`: the clinical physics
/// projects the adipose, fibroglandular and skin shares of the volume
/// (three cone-beam projections) and records each element's
/// polychromatic signal.
#[allow(clippy::too_many_arguments)]
pub fn simulate_cone_acquisition_with(
    vol: &LabelVolume,
    geom: &Geometry,
    system: &dbt_geometry::ConeSystem,
    noise: NoiseLevel,
    physics: Physics,
    seed: u64,
    technique: Technique,
    kvp: f64,
    patient_id: &str,
    uid_root: &str,
) -> Result<AcqFile, SimError> {
    // The system's own detector, where its file states the converter.
    let physics = physics.on_system(system);
    let _span =
        tracing::info_span!("cone_acquisition", patient_id, system = %system.name, physics = physics.name()).entered();
    let (cols, rows) = (geom.image.columns, geom.image.rows);
    let grid = dbt_cone::VolumeGrid {
        lateral: cols,
        vertical: rows,
        depth: vol.n_coronal(),
        voxel_mm: geom.image.pixel_mm,
    };
    // The volumes to project: the attenuation (mono), or each material's
    // share (clinical).
    let n_vol = match physics {
        Physics::Mono => 1,
        Physics::Clinical { .. } => 3,
    };
    let mut vols = vec![vec![0.0f32; grid.len()]; n_vol];
    for d in 0..vol.n_coronal() {
        let s = coronal_slice(vol, d, geom)?;
        let images: Vec<Vec<f32>> = match physics {
            Physics::Mono => vec![s.mu()],
            Physics::Clinical { .. } => s.material_shares().to_vec(),
        };
        for (dst, img) in vols.iter_mut().zip(&images) {
            for v in 0..rows {
                for l in 0..cols {
                    dst[grid.index(l, v, d)] = img[(rows - 1 - v) * cols + l];
                }
            }
        }
    }
    // The positions the source (and a detector that moves with it) takes
    // during each exposure: the view's own, or for continuous motion three
    // across the arc it travels.
    let positions = exposure_positions(system)?;
    let projectors = positions
        .iter()
        .map(|p| dbt_cone::ConeProjector::new(p, grid))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| SimError::Cone(e.to_string()))?;
    let (drows, dcols, views) = (
        system.detector.rows,
        system.detector.columns,
        system.n_views(),
    );
    // Frames: detector row r across the views.
    let frames_of = |p: &[f32]| {
        let mut f = vec![0.0f32; p.len()];
        for v in 0..views {
            for r in 0..drows {
                let from = (v * drows + r) * dcols;
                let to = r * views * dcols + v * dcols;
                f[to..to + dcols].copy_from_slice(&p[from..from + dcols]);
            }
        }
        f
    };
    let forward = |v: &[f32]| -> Result<Vec<Vec<f32>>, SimError> {
        projectors
            .iter()
            .map(|p| p.forward(v).map(|p| frames_of(&p)))
            .collect::<Result<_, _>>()
            .map_err(|e| SimError::Cone(e.to_string()))
    };
    let projected: Vec<Vec<f32>> = match physics {
        // One attenuation: the mean transmission over the positions, as
        // the line integral that gives it (exact).
        Physics::Mono => vec![mean_transmission_path(&forward(&vols[0])?)],
        // Each material's path averaged over the positions: the
        // polychromatic signal is not linear in the paths, an error of the
        // second order in their change across one exposure's arc.
        Physics::Clinical { .. } => vols
            .iter()
            .map(|v| forward(v).map(|ps| mean_path(&ps)))
            .collect::<Result<_, _>>()?,
    };
    let (counts, flux) = match physics {
        Physics::Mono => {
            let a = simulate_from_line_integrals(&projected[0], noise, mix_seed(seed, &[u64::MAX]));
            (a.counts, a.flux)
        }
        Physics::Clinical { detector, scatter } => {
            let model = Physics::clinical(&detector, technique, kvp, vol.thickness_mm(), noise)?;
            let paths: [Vec<f32>; 3] = [
                projected[0].clone(),
                projected[1].clone(),
                projected[2].clone(),
            ];
            let layout = dbt_forward::clinical::StackLayout::cone(system);
            let c = clinical_signals(
                &model,
                &paths,
                &layout,
                scatter.then_some((vol.thickness_mm(), technique.anode_filter)),
                noise,
                mix_seed(seed, &[u64::MAX]),
            )?;
            (c, model.flat_adu())
        }
    };
    let mut file =
        simulate_acquisition_header(vol, geom, noise, seed, technique, kvp, patient_id, uid_root);
    file.header.system = Some(system.clone());
    file.header.slices = drows;
    file.header.flux = flux;
    if let (Physics::Clinical { detector, .. }, Some(t)) = (physics, file.header.truth.as_mut()) {
        t["physics"] = physics.name().into();
        t["detector"] = detector.converter.to_string().into();
        t["line_spread_um"] = (detector.line_spread_mm * 1000.0).into();
    }
    file.counts = counts.chunks(views * dcols).map(<[f32]>::to_vec).collect();
    Ok(file)
}
