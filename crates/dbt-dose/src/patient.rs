//! Patient-specific mean glandular dose (paper section 3.6, eq. 5) on a
//! classified breast, and the conventional model-breast estimate with the same
//! engine.
//!
//! # Set-up (paper Figure 6, our choices where it is silent)
//! Dose coordinates: `z = 0` the detector plane, `x` from the chest wall
//! (x = 0) toward the nipple, `y` along the chest wall. The source is 700 mm
//! above the detector, the rotation axis (parallel to x, through y = 0) 50 mm
//! above it, so that the breast support, 30 mm below the rotation centre as in
//! the 2-D geometry (image height 60 mm, breast on the bottom row), lies at
//! z = 20 mm. The source sits above the chest wall (x = 0) and, for a view at
//! angle `theta`, rotates about that axis; the field is collimated to the
//! detector, which rotates with it (paper: "the detector rotating with the
//! x-ray source"): 256 mm along y (1280 x 0.2 mm) by 240 mm along x, starting
//! at the chest wall. Around the breast voxels: a 3 mm PET compression paddle
//! on the breast, a 2 mm PMMA support plate under it (the paper does not name
//! its material), a water box for the body behind the chest wall (TG-195
//! size), air elsewhere.
//!
//! # Quantities
//! `MGD = E_g / M_g` (eq. 5): energy deposited in glandular tissue over the
//! glandular mass, with Cooper's ligaments counted as glandular (as for G).
//! Normalisation: the incident air kerma at the reference point (60 mm from
//! the chest wall, on the breast's upper surface, y = 0) for the 0-degree
//! view, free in air (air attenuation included, no backscatter), times the
//! number of views (equal tube loading per view). Both per emitted photon, so
//! `MGD / K` is the dimensionless conversion factor (DgN-like).

use crate::material::Material;
use crate::scene::{HomogeneousBox, Scene, VoxelGrid};
use crate::spectrum::Spectrum;
use crate::tables::elements;
use crate::transport::{run, PointSource, Tallies};
use crate::DoseError;
use dbt_materials::{Tissue, AIR, PET, PMMA, WATER};
use serde::Serialize;

/// Source to detector, mm.
pub const SOURCE_TO_DETECTOR_MM: f64 = 700.0;
/// Source to rotation axis, mm.
pub const SOURCE_TO_AXIS_MM: f64 = 650.0;
/// Top of the breast support above the detector, mm.
pub const SUPPORT_Z_MM: f64 = 20.0;
/// Paddle (PET) thickness, mm.
pub const PADDLE_MM: f64 = 3.0;
/// Support plate (PMMA) thickness, mm.
pub const SUPPORT_MM: f64 = 2.0;
/// Detector extent along the chest wall (y) and toward the nipple (x), mm.
pub const DETECTOR_MM: [f64; 2] = [256.0, 240.0];
/// Reference point of the incident air kerma: distance from the chest wall.
pub const KERMA_REF_X_MM: f64 = 60.0;

/// 1 eV/g in mGy.
const EV_PER_G_TO_MGY: f64 = 1.602_176_634e-19 / 1e-3 * 1e3;

/// A classified breast: labels of `dbt_materials` (0 air, 1 adipose, 2 skin,
/// 3 fibroglandular, 4 ligament), axes `[lateral, vertical, depth]` with
/// lateral fastest (the layout of `dbt_phantom::LabelVolume`), vertical index 0
/// on the support, depth index 0 at the chest wall.
pub struct Breast<'a> {
    /// Voxel counts `[lateral, vertical, depth]`.
    pub dims: [usize; 3],
    /// Voxel side, mm.
    pub voxel_mm: f64,
    /// Labels.
    pub labels: &'a [u8],
}

/// Which breast model to simulate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Model {
    /// The voxels as classified.
    PatientSpecific,
    /// Same outline and skin, interior a homogeneous mixture of the same
    /// glandularity by mass (the conventional model breast).
    Homogeneous,
}

/// Where a sweep's dose is simulated: the gantry's focal spot at each view,
/// the detector the field is collimated to (turned by the detector's angle
/// at that view), and the breast support, in the dose coordinates of this
/// module (`z = 0` the detector plane at 0 degrees, `x` from the chest wall,
/// `y` along it). One geometry per gantry (issue #51): the paper's
/// ([`DoseGeometry::paper`], this module's constants), or a cone-beam
/// system's own ([`DoseGeometry::of_system`]: Hologic's 15 views over +-7.5
/// degrees from 700 mm with a tilting detector, GE's 9 over +-12.5 degrees
/// over a stationary one, ...).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DoseGeometry {
    /// The gantry's name (`paper`, or the cone-beam system's).
    pub name: String,
    /// The source's distance from the rotation axis, mm.
    pub arc_radius_mm: f64,
    /// The rotation axis's height above the detector, mm.
    pub axis_height_mm: f64,
    /// The focal spot's distance from the chest wall (dose `x`), mm.
    pub source_depth_mm: f64,
    /// The breast support's upper face above the detector, mm.
    pub support_z_mm: f64,
    /// The detector (and field) along the chest wall (`y`) and toward the
    /// nipple (`x`), mm.
    pub detector_mm: [f64; 2],
    /// Each view's source angle and detector angle, degrees.
    pub views: Vec<[f64; 2]>,
}

impl DoseGeometry {
    /// The paper's gantry with its 25 views ([`dbt_views`]): source 650 mm
    /// from the axis, 700 mm from the rotating detector, the support 20 mm
    /// above it.
    pub fn paper() -> Self {
        Self::paper_views(&dbt_views())
    }

    /// The paper's gantry with the views `views_deg` (a mammogram: `[0]`).
    pub fn paper_views(views_deg: &[f64]) -> Self {
        DoseGeometry {
            name: "paper".into(),
            arc_radius_mm: SOURCE_TO_AXIS_MM,
            axis_height_mm: SOURCE_TO_DETECTOR_MM - SOURCE_TO_AXIS_MM,
            source_depth_mm: 0.0,
            support_z_mm: SUPPORT_Z_MM,
            detector_mm: DETECTOR_MM,
            views: views_deg.iter().map(|&a| [a, a]).collect(),
        }
    }

    /// A cone-beam system's gantry: its views (measured angles where it
    /// gives them), arc, axis, support and detector; the detector turned by
    /// `k x` the source's angle as the system says (0 stationary, 1
    /// rotating, Hologic's tilt factor). The source's arc during an
    /// exposure (`source_blur_deg`) is not simulated: the dose of an arc of
    /// a few tenths of a degree is that of its middle.
    pub fn of_system(sys: &dbt_geometry::ConeSystem) -> Self {
        let p = sys.detector.pitch_mm;
        DoseGeometry {
            name: sys.name.clone(),
            arc_radius_mm: sys.arc_radius_mm,
            axis_height_mm: sys.axis_height_mm,
            source_depth_mm: sys.source_depth_mm,
            support_z_mm: sys.support_height_mm,
            detector_mm: [
                sys.detector.columns as f64 * p,
                sys.detector.rows as f64 * p,
            ],
            views: (0..sys.n_views())
                .map(|v| [sys.angle_deg(v), sys.detector_angle_deg(v)])
                .collect(),
        }
    }

    /// The views' source angles, degrees.
    pub fn angles_deg(&self) -> Vec<f64> {
        self.views.iter().map(|v| v[0]).collect()
    }

    /// The source with the source at `angle_deg` and the detector turned
    /// by `detector_deg` (both about the axis through (., 0,
    /// `axis_height_mm`) parallel to x), the field collimated to the
    /// detector.
    pub fn source(&self, angle_deg: f64, detector_deg: f64, spectrum: Spectrum) -> PointSource {
        let (r, h) = (self.arc_radius_mm, self.axis_height_mm);
        let (s, c) = angle_deg.to_radians().sin_cos();
        let (sd, cd) = detector_deg.to_radians().sin_cos();
        PointSource {
            position: [self.source_depth_mm, r * s, h + r * c],
            field_centre: [self.detector_mm[1] / 2.0, -h * sd, h - h * cd],
            field_axes: [[1.0, 0.0, 0.0], [0.0, cd, -sd]],
            field_half: [self.detector_mm[1] / 2.0, self.detector_mm[0] / 2.0],
            spectrum,
        }
    }

    /// View `v`'s source ([`DoseGeometry::source`]); `None` past the views.
    pub fn view_source(&self, v: usize, spectrum: Spectrum) -> Option<PointSource> {
        self.views.get(v).map(|&[a, d]| self.source(a, d, spectrum))
    }
}

/// The result of one MGD estimate.
#[derive(Debug, Clone, Serialize)]
pub struct MgdResult {
    /// Which model.
    pub model: Model,
    /// Views simulated (angles, degrees).
    pub views_deg: Vec<f64>,
    /// Photons in total.
    pub photons: u64,
    /// Glandularity by mass of the breast (ligaments counted).
    pub glandularity: f64,
    /// Glandular mass, g.
    pub glandular_mass_g: f64,
    /// MGD per emitted photon, mGy (all views).
    pub mgd_per_photon_mgy: f64,
    /// Each view's share of the MGD (sums to 1).
    pub view_fractions: Vec<f64>,
    /// Relative standard error of the MGD (batch method).
    pub mgd_rel_uncertainty: f64,
    /// Incident air kerma at the reference point per emitted photon, mGy
    /// (0-degree view, times the number of views).
    pub kerma_per_photon_mgy: f64,
    /// MGD per unit incident air kerma (mGy/mGy).
    pub mgd_per_kerma: f64,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Material codes of the patient scene.
const AIR_M: u8 = 0;
const ADIPOSE_M: u8 = 1;
const SKIN_M: u8 = 2;
const GLAND_M: u8 = 3;
const PET_M: u8 = 4;
const PMMA_M: u8 = 5;
const WATER_M: u8 = 6;
const MIX_M: u8 = 7;

fn validate(b: &Breast<'_>) -> Result<(), DoseError> {
    let n: usize = b.dims.iter().product();
    if n == 0 || b.labels.len() != n {
        return Err(DoseError::Scene(format!(
            "breast dims {:?} need {n} labels, got {}",
            b.dims,
            b.labels.len()
        )));
    }
    if b.voxel_mm.is_nan() || b.voxel_mm <= 0.0 {
        return Err(DoseError::Scene(format!("voxel size {} mm", b.voxel_mm)));
    }
    if let Some(l) = b.labels.iter().find(|&&l| l > 4) {
        return Err(DoseError::Scene(format!("unknown tissue label {l}")));
    }
    Ok(())
}

/// Glandularity by mass and glandular voxel count of a breast.
pub fn glandularity(b: &Breast<'_>) -> (f64, u64) {
    let mut c = [0u64; 5];
    for &l in b.labels {
        c[(l as usize).min(4)] += 1;
    }
    let ng = c[3] + c[4];
    (dbt_materials::glandularity(ng, c[1]).unwrap_or(0.0), ng)
}

/// The dose scene of a breast on the paper's gantry.
pub fn scene(b: &Breast<'_>, model: Model) -> Result<Scene, DoseError> {
    scene_on(&DoseGeometry::paper(), b, model)
}

/// The dose scene of a breast resting on `geom`'s support.
pub fn scene_on(geom: &DoseGeometry, b: &Breast<'_>, model: Model) -> Result<Scene, DoseError> {
    validate(b)?;
    let (support_z, detector) = (geom.support_z_mm, geom.detector_mm);
    let els = elements()?;
    let gland = Material::tissue(Tissue::Fibroglandular, els)?;
    let (g, _) = glandularity(b);
    // Homogeneous interior: glandular and adipose mixed by mass fraction g.
    let (mix_comp, mix_density) = dbt_materials::glandular_adipose_mix(g);
    let materials = vec![
        Material::medium(&AIR, els)?,
        Material::tissue(Tissue::Adipose, els)?,
        Material::tissue(Tissue::Skin, els)?,
        gland.clone().glandular(),
        Material::medium(&PET, els)?,
        Material::medium(&PMMA, els)?,
        Material::medium(&WATER, els)?,
        Material::new("breast mixture", mix_density, &mix_comp, els)?.glandular_share(g, &gland),
    ];
    let [nl, nv, nd] = b.dims;
    let h = b.voxel_mm;
    let dims = [nd, nl, nv];
    let mut material = vec![AIR_M; nl * nv * nd];
    for d in 0..nd {
        for v in 0..nv {
            for l in 0..nl {
                let lab = b.labels[(d * nv + v) * nl + l];
                let m = match (lab, model) {
                    (0, _) => AIR_M,
                    (2, _) => SKIN_M,
                    (_, Model::Homogeneous) => MIX_M,
                    (1, _) => ADIPOSE_M,
                    _ => GLAND_M,
                };
                material[(v * nl + l) * nd + d] = m;
            }
        }
    }
    let t = nv as f64 * h;
    let half_y = detector[0] / 2.0;
    let scene = Scene {
        materials,
        grid: VoxelGrid {
            origin: [0.0, -(nl as f64) * h / 2.0, support_z],
            voxel_mm: h,
            dims,
            tally: vec![0; material.len()],
            material,
        },
        boxes: vec![
            HomogeneousBox {
                min: [0.0, -half_y, support_z + t],
                max: [detector[1], half_y, support_z + t + PADDLE_MM],
                material: PET_M,
            },
            HomogeneousBox {
                min: [0.0, -half_y, support_z - SUPPORT_MM],
                max: [detector[1], half_y, support_z],
                material: PMMA_M,
            },
            HomogeneousBox {
                min: [-170.0, -150.0, -110.0],
                max: [0.0, 150.0, 190.0],
                material: WATER_M,
            },
        ],
        world_material: AIR_M,
        world_min: [-1000.0; 3],
        world_max: [1000.0; 3],
        n_tallies: 0,
        summary: Default::default(),
    };
    if nl as f64 * h > detector[0] || nd as f64 * h > detector[1] {
        return Err(DoseError::Scene(format!(
            "breast {:.0} x {:.0} mm exceeds the detector {:?} mm",
            nl as f64 * h,
            nd as f64 * h,
            detector
        )));
    }
    scene.validate()?;
    Ok(scene)
}

/// The source of a view at `angle_deg` on the paper's gantry (rotation
/// about the axis through (., 0, 50 mm) parallel to x), collimated to the
/// rotating detector.
pub fn view_source(angle_deg: f64, spectrum: Spectrum) -> PointSource {
    DoseGeometry::paper_views(&[]).source(angle_deg, angle_deg, spectrum)
}

/// The paper's DBT views: 25 from -24 to 24 degrees every 2 degrees.
pub fn dbt_views() -> Vec<f64> {
    (0..25).map(|i| -24.0 + 2.0 * i as f64).collect()
}

/// Incident air kerma (mGy) per photon emitted into the field of `src` at
/// point `q`, free in air with air attenuation, no backscatter.
pub fn air_kerma_per_photon(src: &PointSource, q: [f64; 3]) -> Result<f64, DoseError> {
    let air = Material::new("air", AIR.density, AIR.elements, elements()?)?;
    let d = [
        q[0] - src.position[0],
        q[1] - src.position[1],
        q[2] - src.position[2],
    ];
    let r_mm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    let fluence_per_cm2 = 1.0 / (src.solid_angle() * (r_mm / 10.0).powi(2));
    let s = &src.spectrum;
    let per_kev_g: f64 = s
        .energies
        .iter()
        .zip(&s.weights)
        .map(|(&e, &w)| {
            let mu = air.mu(e).total();
            w * e * (air.mu_en(e) / air.density * 10.0) * (-mu * r_mm).exp()
        })
        .sum();
    // fluence [1/cm^2] * E [keV] * mu_en/rho [cm^2/g] = keV/g.
    Ok(fluence_per_cm2 * per_kev_g * 1e3 * EV_PER_G_TO_MGY)
}

/// Estimate the MGD of `breast` for the given views of the paper's gantry,
/// with `photons` photons in total (equal per view), in `batches` batches
/// per view.
pub fn mgd(
    breast: &Breast<'_>,
    model: Model,
    spectrum: &Spectrum,
    views_deg: &[f64],
    photons: u64,
    batches: usize,
    seed: u64,
) -> Result<MgdResult, DoseError> {
    mgd_on(
        &DoseGeometry::paper_views(views_deg),
        breast,
        model,
        spectrum,
        photons,
        batches,
        seed,
    )
}

/// [`mgd`] on the gantry `geom` (its views).
pub fn mgd_on(
    geom: &DoseGeometry,
    breast: &Breast<'_>,
    model: Model,
    spectrum: &Spectrum,
    photons: u64,
    batches: usize,
    seed: u64,
) -> Result<MgdResult, DoseError> {
    if geom.views.is_empty() {
        return Err(DoseError::Scene("no views".into()));
    }
    let sc = scene_on(geom, breast, model)?;
    mgd_in(&sc, geom, breast, model, spectrum, photons, batches, seed)
}

/// [`mgd_on`] in a scene already built for `breast` and `model` (views checked).
#[allow(clippy::too_many_arguments)]
fn mgd_in(
    sc: &Scene,
    geom: &DoseGeometry,
    breast: &Breast<'_>,
    model: Model,
    spectrum: &Spectrum,
    photons: u64,
    batches: usize,
    seed: u64,
) -> Result<MgdResult, DoseError> {
    let n_views = geom.views.len();
    let _span =
        tracing::info_span!("mgd", ?model, gantry = %geom.name, views = n_views, photons).entered();
    let t0 = std::time::Instant::now();
    let (g, n_gland) = glandularity(breast);
    let voxel_g = breast.voxel_mm.powi(3) / 1000.0;
    let interior = breast
        .labels
        .iter()
        .filter(|&&l| l == 1 || l == 3 || l == 4)
        .count() as f64;
    let m_gland = match model {
        Model::PatientSpecific => n_gland as f64 * voxel_g * Tissue::Fibroglandular.density_g_cm3(),
        Model::Homogeneous => {
            let rho = sc.materials[MIX_M as usize].density;
            g * interior * voxel_g * rho
        }
    };
    if m_gland <= 0.0 {
        return Err(DoseError::Scene(
            "the breast has no glandular tissue".into(),
        ));
    }
    let per_view = (photons / n_views as u64).max(batches as u64);
    let mut e_gland = 0.0;
    let mut per_view_e = Vec::with_capacity(n_views);
    let mut var = 0.0;
    let mut total = 0u64;
    for (k, &[a, d]) in geom.views.iter().enumerate() {
        let src = geom.source(a, d, spectrum.clone());
        let r = run(sc, &src, per_view, batches, seed.wrapping_add(k as u64))?;
        let (m, se) = r.per_photon(|t: &Tallies| t.glandular_kev);
        e_gland += m;
        per_view_e.push(m);
        var += se * se;
        total += r.total.photons;
    }
    // keV per photon per view, summed over views -> mGy per photon per view.
    let to_mgy = 1e3 * EV_PER_G_TO_MGY / m_gland;
    let mgd = e_gland * to_mgy;
    let t = breast.dims[1] as f64 * breast.voxel_mm;
    // The incident air kerma of a view at 0 degrees (the source above the
    // support, the detector flat), times the views.
    let k0 = air_kerma_per_photon(
        &geom.source(0.0, 0.0, spectrum.clone()),
        [KERMA_REF_X_MM, 0.0, geom.support_z_mm + t],
    )? * n_views as f64;
    Ok(MgdResult {
        model,
        views_deg: geom.angles_deg(),
        photons: total,
        glandularity: g,
        glandular_mass_g: m_gland,
        mgd_per_photon_mgy: mgd,
        view_fractions: per_view_e.iter().map(|e| e / e_gland).collect(),
        mgd_rel_uncertainty: var.sqrt() / e_gland,
        kerma_per_photon_mgy: k0,
        mgd_per_kerma: mgd / k0,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// [`mgd`] with as many photons as a relative statistical uncertainty of
/// `target` needs (a pilot with `pilot` photons estimates the variance; the
/// reported result is the final run alone), at most `max_photons`, on the
/// paper's gantry.
#[allow(clippy::too_many_arguments)]
pub fn mgd_to_uncertainty(
    breast: &Breast<'_>,
    model: Model,
    spectrum: &Spectrum,
    views_deg: &[f64],
    target: f64,
    pilot: u64,
    max_photons: u64,
    seed: u64,
) -> Result<MgdResult, DoseError> {
    mgd_to_uncertainty_on(
        &DoseGeometry::paper_views(views_deg),
        breast,
        model,
        spectrum,
        target,
        pilot,
        max_photons,
        seed,
    )
}

/// [`mgd_to_uncertainty`] on the gantry `geom` (its views).
#[allow(clippy::too_many_arguments)]
pub fn mgd_to_uncertainty_on(
    geom: &DoseGeometry,
    breast: &Breast<'_>,
    model: Model,
    spectrum: &Spectrum,
    target: f64,
    pilot: u64,
    max_photons: u64,
    seed: u64,
) -> Result<MgdResult, DoseError> {
    if geom.views.is_empty() {
        return Err(DoseError::Scene("no views".into()));
    }
    // One scene serves the pilot and the final run.
    let sc = scene_on(geom, breast, model)?;
    let p = mgd_in(&sc, geom, breast, model, spectrum, pilot, 20, seed ^ 0x5EED)?;
    let need = (pilot as f64 * (p.mgd_rel_uncertainty / target).powi(2) * 1.15).ceil() as u64;
    let n = need.clamp(pilot, max_photons);
    let mut r = mgd_in(&sc, geom, breast, model, spectrum, n, 20, seed)?;
    r.seconds += p.seconds;
    Ok(r)
}
