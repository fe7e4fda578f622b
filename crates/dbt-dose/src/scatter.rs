//! Scatter at the detector (issue #27): the photons of a DBT view that reach
//! the detector after interacting, from the same engine, scene and views as
//! the dose ([`crate::patient`]), scored by [`DetectorScore`].
//!
//! The experiment is that of the scatter literature: a homogeneous breast
//! of thickness `T` and glandularity `G` (a half-cylinder at the chest wall,
//! 2 mm of skin on its faces and its round edge: TG-195 case 3's shape),
//! between the paddle and the support, the detector rotating with the
//! source 18 mm below the support, no grid; the scatter-to-primary ratio
//! `SPR = S / P` in a region of interest where the ray through the breast's
//! centre meets the detector ("the centre of the irradiation region",
//! Carton et al. 2009). Our engine's statistical uncertainty comes from its
//! batches (`RunResult::per_photon`).

use crate::material::Material;
use crate::patient::{scene, view_source, Breast, Model, SUPPORT_MM, SUPPORT_Z_MM};
use crate::spectrum::Spectrum;
use crate::transport::{run_scored, DetectorScore, Tallies};
use crate::DoseError;
use dbt_materials::Tissue;
use serde::Serialize;

/// Skin of the homogeneous breast, mm (TG-195 case 3).
pub const SKIN_MM: f64 = 2.0;

/// The detector of the patient scene's views: `csi_um` of CsI (0: an
/// ideal detector scoring the energy fluence), `pixel_mm` pixels, photons
/// recorded where they leave the support's underside (the virtual detector
/// of [`DetectorScore::gate_z_mm`]: the rotating detector rises into the
/// breast at the outer views).
pub fn paper_detector(csi_um: f64, pixel_mm: f64) -> Result<DetectorScore, DoseError> {
    let absorber = if csi_um > 0.0 {
        let csi = Material::medium(&dbt_materials::CSI, crate::tables::elements()?)?;
        Some((csi, csi_um / 1000.0))
    } else {
        None
    };
    Ok(DetectorScore {
        pixel_mm,
        absorber,
        gate_z_mm: Some(SUPPORT_Z_MM - SUPPORT_MM),
    })
}

/// Labels (`dbt_materials`: 1 adipose, 2 skin, 3 fibroglandular) of a
/// homogeneous half-cylinder breast of `thickness_mm`, radius `radius_mm`
/// from the chest wall, `voxel_mm` voxels, in [`Breast`]'s layout; the
/// interior's glandular and adipose voxels are interleaved in the share
/// that gives `glandularity` by mass (the [`Model::Homogeneous`] scene
/// mixes them into one material).
pub fn half_cylinder(
    thickness_mm: f64,
    radius_mm: f64,
    glandularity: f64,
    voxel_mm: f64,
) -> Result<([usize; 3], Vec<u8>), DoseError> {
    for (what, v) in [
        ("thickness", thickness_mm),
        ("radius", radius_mm),
        ("voxel", voxel_mm),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(DoseError::Scene(format!(
                "half-cylinder {what} {v} mm must be a positive number"
            )));
        }
    }
    if !(0.0..=1.0).contains(&glandularity) {
        return Err(DoseError::Scene(format!(
            "glandularity {glandularity} is not a fraction"
        )));
    }
    let nv = (thickness_mm / voxel_mm).round().max(1.0) as usize;
    let nd = (radius_mm / voxel_mm).round().max(1.0) as usize;
    let nl = 2 * nd;
    // Glandular voxel share f for a mass share G.
    let (rg, ra) = (
        Tissue::Fibroglandular.density_g_cm3(),
        Tissue::Adipose.density_g_cm3(),
    );
    let f = glandularity * ra / (glandularity * ra + (1.0 - glandularity) * rg);
    let skin = SKIN_MM / voxel_mm;
    let mut labels = vec![0u8; nl * nv * nd];
    let mut gland_acc = 0.0;
    for d in 0..nd {
        for v in 0..nv {
            for l in 0..nl {
                let y = (l as f64 + 0.5) * voxel_mm - radius_mm;
                let x = (d as f64 + 0.5) * voxel_mm;
                let r = (x * x + y * y).sqrt();
                if r > radius_mm {
                    continue;
                }
                let from_face = (v as f64 + 0.5).min(nv as f64 - v as f64 - 0.5);
                labels[(d * nv + v) * nl + l] =
                    if from_face < skin || (radius_mm - r) / voxel_mm < skin {
                        2
                    } else {
                        // Error diffusion: exactly the share f, spread evenly.
                        gland_acc += f;
                        if gland_acc >= 1.0 {
                            gland_acc -= 1.0;
                            3
                        } else {
                            1
                        }
                    };
            }
        }
    }
    Ok(([nl, nv, nd], labels))
}

/// The detector's images of one view.
#[derive(Debug, Clone, Serialize)]
pub struct DetectorImages {
    /// Pixels `[n0, n1]`: `n0` along x (chest wall to nipple), `n1` along
    /// the chest wall; pixel `(i, j)` at `j * n0 + i`.
    pub dims: [usize; 2],
    /// Pixel side, mm.
    pub pixel_mm: f64,
    /// Primary signal per emitted photon, keV.
    pub primary: Vec<f64>,
    /// Scattered signal per emitted photon, keV.
    pub scatter: Vec<f64>,
    /// The scattered signal by the place of the photon's first
    /// interaction: breast, air, paddle, support, body (they sum to
    /// `scatter`).
    #[serde(skip)]
    pub scatter_by_origin: [Vec<f64>; 5],
    /// Photons simulated.
    pub photons: u64,
    #[serde(skip)]
    batches: Vec<Tallies>,
}

/// A ratio and its standard error.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Estimate {
    /// Value.
    pub value: f64,
    /// Standard error (batch method).
    pub se: f64,
}

impl DetectorImages {
    /// `sum S / sum P` over the pixels `f` accepts (by `(i, j)`), with its
    /// standard error from the batches (delta method on each batch's ratio).
    pub fn spr_where(&self, f: impl Fn(usize, usize) -> bool) -> Estimate {
        let [n0, n1] = self.dims;
        let sums = |p: &[f64], s: &[f64]| {
            let (mut a, mut b) = (0.0, 0.0);
            for j in 0..n1 {
                for i in 0..n0 {
                    if f(i, j) {
                        a += s[j * n0 + i];
                        b += p[j * n0 + i];
                    }
                }
            }
            a / b
        };
        let value = sums(&self.primary, &self.scatter);
        let r: Vec<f64> = self
            .batches
            .iter()
            .map(|b| {
                sums(
                    &b.detector_primary,
                    &summed(&b.detector_scatter, self.primary.len()),
                )
            })
            .collect();
        let n = r.len() as f64;
        let m = r.iter().sum::<f64>() / n;
        let var = r.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
        Estimate {
            value,
            se: (var / n).sqrt(),
        }
    }

    /// Shares of the scattered signal in the pixels `f` accepts by the
    /// place of the first interaction (breast, air, paddle, support, body).
    pub fn origin_shares_where(&self, f: impl Fn(usize, usize) -> bool) -> [f64; 5] {
        let [n0, n1] = self.dims;
        let mut s = [0.0; 5];
        for (o, img) in s.iter_mut().zip(&self.scatter_by_origin) {
            for j in 0..n1 {
                for i in 0..n0 {
                    if f(i, j) {
                        *o += img[j * n0 + i];
                    }
                }
            }
        }
        let total: f64 = s.iter().sum();
        s.map(|v| v / total.max(f64::MIN_POSITIVE))
    }

    /// The pixel `(i, j)` of the point `q` (dose coordinates, mm) seen from
    /// the source of the view at `angle_deg`.
    pub fn pixel_of(&self, angle_deg: f64, q: [f64; 3]) -> Option<(usize, usize)> {
        let src = view_source(angle_deg, Spectrum::mono(20.0).ok()?);
        let s = src.position;
        let d = [q[0] - s[0], q[1] - s[1], q[2] - s[2]];
        let [u, v] = src.field_axes;
        let n = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        let c = src.field_centre;
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let t = dot([c[0] - s[0], c[1] - s[1], c[2] - s[2]], n) / dot(d, n);
        let h = [
            s[0] + t * d[0] - c[0],
            s[1] + t * d[1] - c[1],
            s[2] + t * d[2] - c[2],
        ];
        let a = dot(h, u) + src.field_half[0];
        let b = dot(h, v) + src.field_half[1];
        let (i, j) = ((a / self.pixel_mm).floor(), (b / self.pixel_mm).floor());
        (i >= 0.0 && j >= 0.0 && (i as usize) < self.dims[0] && (j as usize) < self.dims[1])
            .then_some((i as usize, j as usize))
    }
}

/// The detector images of `breast` (homogeneous or as labelled, per
/// `model`) in the view at `angle_deg`, `photons` photons of `spectrum` in
/// `batches` batches.
#[allow(clippy::too_many_arguments)]
pub fn detector_images(
    breast: &Breast<'_>,
    model: Model,
    spectrum: &Spectrum,
    angle_deg: f64,
    score: &DetectorScore,
    photons: u64,
    batches: usize,
    seed: u64,
) -> Result<DetectorImages, DoseError> {
    let sc = scene(breast, model)?;
    let src = view_source(angle_deg, spectrum.clone());
    let r = run_scored(&sc, &src, photons, batches, seed, score)?;
    let n = r.total.photons as f64;
    let per = |v: &[f64]| v.iter().map(|x| x / n).collect::<Vec<f64>>();
    let np = r.total.detector_primary.len();
    // Tally order [grid, world, paddle, support, body]: the patient scene's.
    let by_origin: [Vec<f64>; 5] =
        std::array::from_fn(|o| per(&r.total.detector_scatter[o * np..(o + 1) * np]));
    Ok(DetectorImages {
        dims: score.dims(&src),
        pixel_mm: score.pixel_mm,
        primary: per(&r.total.detector_primary),
        scatter: per(&summed(&r.total.detector_scatter, np)),
        scatter_by_origin: by_origin,
        photons: r.total.photons,
        batches: r.batches,
    })
}

/// The images of [`crate::Tallies::detector_scatter`] summed over the
/// regions of origin.
fn summed(by_origin: &[f64], pixels: usize) -> Vec<f64> {
    let mut s = vec![0.0; pixels];
    for img in by_origin.chunks_exact(pixels) {
        for (a, b) in s.iter_mut().zip(img) {
            *a += b;
        }
    }
    s
}

/// The SPR of a homogeneous half-cylinder breast in a region of
/// `roi_mm` x `roi_mm` where the ray through the breast's centre (half its
/// radius from the chest wall, mid-thickness) meets the detector.
#[derive(Debug, Clone, Serialize)]
pub struct SlabSpr {
    /// Compressed thickness, mm.
    pub thickness_mm: f64,
    /// View angle, degrees.
    pub angle_deg: f64,
    /// Scatter-to-primary ratio in the region.
    pub spr: Estimate,
    /// Share of the scatter from the paddle (first interaction there).
    pub paddle_share: f64,
    /// Photons simulated.
    pub photons: u64,
}

/// [`SlabSpr`] for one configuration.
#[allow(clippy::too_many_arguments)]
pub fn slab_spr(
    thickness_mm: f64,
    radius_mm: f64,
    glandularity: f64,
    spectrum: &Spectrum,
    angle_deg: f64,
    score: &DetectorScore,
    roi_mm: f64,
    photons: u64,
    seed: u64,
) -> Result<SlabSpr, DoseError> {
    let voxel = 1.0;
    let (dims, labels) = half_cylinder(thickness_mm, radius_mm, glandularity, voxel)?;
    let b = Breast {
        dims,
        voxel_mm: voxel,
        labels: &labels,
    };
    let im = detector_images(
        &b,
        Model::Homogeneous,
        spectrum,
        angle_deg,
        score,
        photons,
        20,
        seed,
    )?;
    let centre = [radius_mm / 2.0, 0.0, SUPPORT_Z_MM + thickness_mm / 2.0];
    let (ci, cj) = im.pixel_of(angle_deg, centre).ok_or_else(|| {
        DoseError::Scene(format!(
            "the breast's centre is not seen on the detector at {angle_deg} degrees"
        ))
    })?;
    let half = (roi_mm / 2.0 / im.pixel_mm).max(0.5);
    let roi = |i: usize, j: usize| {
        (i as f64 - ci as f64).abs() < half && (j as f64 - cj as f64).abs() < half
    };
    let spr = im.spr_where(roi);
    Ok(SlabSpr {
        thickness_mm,
        angle_deg,
        spr,
        paddle_share: im.origin_shares_where(roi)[2],
        photons: im.photons,
    })
}

/// A view's primary and scatter as fractions of the open field (the same
/// view without the breast: paddle and support in place), on the layout
/// of `dbt_scatter::Grid`: rows from the chest wall, columns along it.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct OpenFieldFractions {
    /// Rows (along x, from the chest wall) and columns (along the chest wall).
    pub rows_cols: [usize; 2],
    /// Pixel side, mm.
    pub pixel_mm: f64,
    /// Primary transmission `P / P0`.
    pub transmission: Vec<f64>,
    /// Scatter `S / P0`.
    pub scatter: Vec<f64>,
    /// Photons of the breast's run and of the open field's.
    pub photons: [u64; 2],
}

/// The open field of `breast`'s views: the same scene without the breast
/// (paddle and support in place), for [`OpenFieldFractions::new`].
#[allow(clippy::too_many_arguments)]
pub fn open_field(
    breast: &Breast<'_>,
    spectrum: &Spectrum,
    angle_deg: f64,
    score: &DetectorScore,
    photons: u64,
    seed: u64,
) -> Result<DetectorImages, DoseError> {
    let empty = vec![0u8; breast.labels.len()];
    let open = Breast {
        labels: &empty,
        ..*breast
    };
    detector_images(
        &open,
        Model::Homogeneous,
        spectrum,
        angle_deg,
        score,
        photons,
        20,
        seed,
    )
}

impl OpenFieldFractions {
    /// A view's images `with` the breast as fractions of its `open` field
    /// ([`open_field`], same spectrum, angle and detector); pixels where
    /// the open field recorded nothing are 0.
    pub fn new(with: &DetectorImages, open: &DetectorImages) -> Result<Self, DoseError> {
        if with.dims != open.dims {
            return Err(DoseError::Scene(format!(
                "the open field has {:?} pixels, the view {:?}",
                open.dims, with.dims
            )));
        }
        let [n0, n1] = with.dims;
        let mut t = vec![0.0; n0 * n1];
        let mut s = vec![0.0; n0 * n1];
        for j in 0..n1 {
            for i in 0..n0 {
                let p0 = open.primary[j * n0 + i];
                if p0 > 0.0 {
                    t[i * n1 + j] = with.primary[j * n0 + i] / p0;
                    s[i * n1 + j] = with.scatter[j * n0 + i] / p0;
                }
            }
        }
        Ok(Self {
            rows_cols: [n0, n1],
            pixel_mm: with.pixel_mm,
            transmission: t,
            scatter: s,
            photons: [with.photons, open.photons],
        })
    }
}
