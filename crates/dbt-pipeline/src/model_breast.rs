//! The model breast of a report made without a reconstruction (issue #51
//! point 3: a gantry for which no DBToR model is trained): the patient's
//! outline as the physics density's central view gives it
//! ([`dbt_physics_density::Outline`]: each ray's path through the breast,
//! the thickness plane in contact, the fitted edge profile in the rim), a
//! skin shell of the nominal thickness, and an interior of the physics
//! density's glandularity, its glandular tissue placed as [`Placement`]
//! says (the product's: in each column's middle by its ray's dense share).
//!
//! # Choices
//! - The outline, not Dance's semi-cylinder: the same conversion-factor
//!   physics (a homogeneous interior under a skin layer, Dance 1990, Phys
//!   Med Biol 35:1211; Dance et al. 2000, 45:3225), on the breast's own
//!   footprint and thickness, so that a breast larger or smaller than the
//!   standard one is dosed as it is.
//! - The skin: [`crate::linearise::NOMINAL_SKIN_MM`] (1.5 mm, the physics
//!   density's; Dance et al. 2000 and Huang et al. 2011, Phys Med Biol
//!   56:7441, 1.45 mm) on every face but the chest wall's.
//! - Each voxel takes the nearest ray of the central view at the breast's
//!   mid-height: the central view is within a few degrees of vertical on
//!   every built-in gantry, so a ray's vertical extent is the breast's
//!   there to within the ray's tilt across the breast's thickness.

use crate::error::PipelineError;
use dbt_materials::Tissue;
use dbt_physics_density::Outline;

/// Where the model breast's glandular tissue lies.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Placement {
    /// Mixed through the interior (the conventional model breast: the dose
    /// engine's [`dbt_dose::patient::Model::Homogeneous`]).
    Homogeneous,
    /// Each voxel column takes its ray's dense share of the interior
    /// ([`Outline::dense_share`], scaled so that the whole breast has the
    /// glandularity asked for), as glandular voxels in the column's middle
    /// (the fat under the skin of the upper and lower faces): the breast's
    /// own map of dense tissue across and in depth, placed centrally in
    /// height as breast CT finds it on average (Huang et al. 2011, Phys Med
    /// Biol 56:7441; Hernandez et al. 2015, Med Phys 42:5759, who report
    /// the homogeneous model breast overestimating the MGD by about 30 %
    /// against such distributions). Dosed as it is
    /// ([`dbt_dose::patient::Model::PatientSpecific`]). The product's
    /// choice, made on the validation split (eval/vendor-gantries.md: the
    /// worst 95 % limit of the MGD's error over the vendors' gantries and
    /// both populations 30 % against the homogeneous breast's 59 %).
    #[default]
    CentralColumns,
}

impl Placement {
    /// The dose engine's model of this breast.
    pub fn dose_model(self) -> dbt_dose::patient::Model {
        match self {
            Placement::Homogeneous => dbt_dose::patient::Model::Homogeneous,
            Placement::CentralColumns => dbt_dose::patient::Model::PatientSpecific,
        }
    }
}

/// A labelled model breast `[lateral, vertical, depth]` (lateral fastest,
/// vertical 0 on the support, depth 0 at the chest wall), as
/// [`dbt_dose::patient::Breast`] reads it.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelBreast {
    /// Voxel counts `[lateral, vertical, depth]`.
    pub dims: [usize; 3],
    /// Voxel side, mm.
    pub voxel_mm: f64,
    /// `dbt_materials` labels (0 air, 1 adipose, 2 skin, 3 fibroglandular).
    pub labels: Vec<u8>,
}

impl ModelBreast {
    /// The breast as the dose engine reads it.
    pub fn breast(&self) -> dbt_dose::patient::Breast<'_> {
        dbt_dose::patient::Breast {
            dims: self.dims,
            voxel_mm: self.voxel_mm,
            labels: &self.labels,
        }
    }
}

/// The model breast of `outline` on voxels `voxel_mm` wide across a field
/// `width_mm` wide (centred on `x = 0`), its skin `skin_mm` thick, its
/// interior at glandularity `g` by mass (as near as whole voxels allow),
/// the glandular tissue placed as `placement` says.
pub fn from_outline(
    outline: &Outline,
    width_mm: f64,
    voxel_mm: f64,
    skin_mm: f64,
    g: f64,
    placement: Placement,
) -> Result<ModelBreast, PipelineError> {
    let bad = |what: String| PipelineError::Input(format!("model breast: {what}"));
    for (name, v) in [
        ("voxel", voxel_mm),
        ("width", width_mm),
        ("skin", skin_mm),
        ("slice spacing", outline.slice_mm),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(bad(format!("{name} {v} mm is not a positive length")));
        }
    }
    if !(0.0..=1.0).contains(&g) {
        return Err(bad(format!("glandularity {g} outside 0..1")));
    }
    let nd = outline.x_mid_mm.len();
    if nd == 0
        || !outline.chord_mm.len().is_multiple_of(nd)
        || outline.mid_mm.len() != outline.chord_mm.len()
        || outline.dense_share.len() != outline.chord_mm.len()
    {
        return Err(bad(format!(
            "an outline of {} chords, {} middles and {} dense shares for {nd} elements",
            outline.chord_mm.len(),
            outline.mid_mm.len(),
            outline.dense_share.len()
        )));
    }
    let ns = outline.chord_mm.len() / nd;
    let top = (0..ns * nd)
        .filter(|&i| outline.chord_mm[i] > 0.0)
        .map(|i| f64::from(outline.mid_mm[i]) + f64::from(outline.chord_mm[i]) / 2.0)
        .fold(0.0f64, f64::max);
    if top <= 0.0 {
        return Err(bad("the outline holds no breast".into()));
    }
    let nx = (width_mm / voxel_mm).round().max(1.0) as usize;
    let nz = (top / voxel_mm).ceil() as usize;
    let ny = ((ns as f64 * outline.slice_mm) / voxel_mm).ceil() as usize;
    let x_of = |c: f64| -width_mm / 2.0 + (c + 0.5) * voxel_mm;
    // The breast's extent (bottom, top) at lateral position x, depth y.
    let extent = |x: f64, y: f64| -> Option<(f64, f64)> {
        if y < 0.0 {
            return None;
        }
        let k = outline.element_at(x)?;
        let s = (y / outline.slice_mm) as usize;
        if s >= ns {
            return None;
        }
        let (c, m) = (
            f64::from(outline.chord_mm[s * nd + k]),
            f64::from(outline.mid_mm[s * nd + k]),
        );
        (c > 0.0).then(|| ((m - c / 2.0).max(0.0), m + c / 2.0))
    };
    let inside = |x: f64, z: f64, y: f64| extent(x, y).is_some_and(|(lo, hi)| z >= lo && z <= hi);
    let mut labels = vec![0u8; nx * nz * ny];
    for d in 0..ny {
        let y = (d as f64 + 0.5) * voxel_mm;
        for c in 0..nx {
            let x = x_of(c as f64);
            let Some((lo, hi)) = extent(x, y) else {
                continue;
            };
            for v in 0..nz {
                let z = (v as f64 + 0.5) * voxel_mm;
                if z < lo || z > hi {
                    continue;
                }
                // Skin where the surface is within the skin's thickness:
                // above, below, across or toward the nipple (the chest
                // wall is no surface).
                let skin = z - lo < skin_mm
                    || hi - z < skin_mm
                    || !inside(x - skin_mm, z, y)
                    || !inside(x + skin_mm, z, y)
                    || !inside(x, z, y + skin_mm);
                labels[(d * nz + v) * nx + c] = if skin {
                    Tissue::Skin.label()
                } else {
                    Tissue::Adipose.label()
                };
            }
        }
    }
    if !labels.contains(&Tissue::Adipose.label()) {
        return Err(bad(
            "the outline is all skin (thinner than two skins everywhere)".into(),
        ));
    }
    let labels = match placement {
        Placement::Homogeneous => crate::density_check::labels_at_glandularity(&labels, g),
        Placement::CentralColumns => {
            let share = |c: usize, d: usize| -> f64 {
                let x = x_of(c as f64);
                let y = (d as f64 + 0.5) * voxel_mm;
                let (Some(k), s) = (outline.element_at(x), (y / outline.slice_mm) as usize) else {
                    return 0.0;
                };
                outline
                    .dense_share
                    .get(s * nd + k)
                    .map_or(0.0, |&f| f64::from(f))
            };
            central_columns(labels, [nx, nz, ny], g, share)
        }
    };
    Ok(ModelBreast {
        dims: [nx, nz, ny],
        voxel_mm,
        labels,
    })
}

/// `labels` (air, skin, adipose interior) with each column's interior
/// made glandular in its middle: `share(column, slice)` of it, scaled by one
/// factor so that the whole breast's glandularity by mass is `g` (as near
/// as whole voxels allow; a column is at most all glandular).
fn central_columns(
    mut labels: Vec<u8>,
    [nx, nz, ny]: [usize; 3],
    g: f64,
    share: impl Fn(usize, usize) -> f64,
) -> Vec<u8> {
    let adipose = Tissue::Adipose.label();
    let (rg, ra) = (
        Tissue::Fibroglandular.density_g_cm3(),
        Tissue::Adipose.density_g_cm3(),
    );
    // Each column's interior voxels (rows) and dense share.
    let mut cols = Vec::new();
    let mut n = 0usize;
    for d in 0..ny {
        for c in 0..nx {
            let rows: Vec<usize> = (0..nz)
                .filter(|&v| labels[(d * nz + v) * nx + c] == adipose)
                .collect();
            if !rows.is_empty() {
                n += rows.len();
                // A share that is not a number is none; every column keeps
                // a vanishing one, so that a glandularity the shared
                // columns cannot hold is spread over the others rather
                // than missed.
                let f = share(c, d);
                let f = if f.is_finite() {
                    f.clamp(0.0, 1.0)
                } else {
                    0.0
                };
                cols.push((c, d, rows, f.max(1e-9)));
            }
        }
    }
    let g = g.clamp(0.0, 1.0);
    // The glandular voxels the glandularity asks for (as
    // density_check::labels_at_glandularity), and the scale that gives
    // them: the largest s with sum min(1, s f) n_c <= want, by bisection.
    let want = g * ra * n as f64 / (rg - g * (rg - ra));
    let total = |s: f64| -> f64 {
        cols.iter()
            .map(|(_, _, r, f)| (s * f).min(1.0) * r.len() as f64)
            .sum()
    };
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    while total(hi) < want && hi < 1e12 {
        hi *= 2.0;
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if total(mid) < want {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let s = hi;
    let gland = Tissue::Fibroglandular.label();
    // Whole voxels: each column's share rounded with the remainder carried
    // to the next, so that the sum is the want.
    let mut carry = 0.0f64;
    for (c, d, rows, f) in &cols {
        let exact = (s * f).min(1.0) * rows.len() as f64 + carry;
        let k = (exact.round().max(0.0) as usize).min(rows.len());
        carry = exact - k as f64;
        let start = (rows.len() - k) / 2;
        for &v in &rows[start..start + k] {
            labels[(d * nz + v) * nx + c] = gland;
        }
    }
    labels
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A box breast: 100 mm across (elements 1 mm apart), 60 mm deep (slices
    /// 1 mm), 40 mm thick in contact, with a 10 mm half-round rim at the
    /// nipple end.
    fn box_outline() -> Outline {
        let (nd, ns) = (161, 80);
        let x_mid_mm: Vec<f64> = (0..nd).map(|k| k as f64 - 80.0).collect();
        let mut chord = vec![0f32; nd * ns];
        let mut mid = vec![0f32; nd * ns];
        // Dense in the middle third across, fat beside.
        let mut dense = vec![0f32; nd * ns];
        for s in 0..ns {
            let y = s as f64 + 0.5;
            for (k, &x) in x_mid_mm.iter().enumerate() {
                if x.abs() > 50.0 || y > 70.0 {
                    continue;
                }
                let c = if y <= 60.0 {
                    40.0
                } else {
                    // A circle of radius 20 about (60, 20): chord 2 sqrt(...).
                    2.0 * (400.0 - (y - 60.0) * (y - 60.0) * 4.0).max(0.0).sqrt()
                };
                chord[s * nd + k] = c as f32;
                mid[s * nd + k] = 20.0;
                dense[s * nd + k] = if x.abs() < 50.0 / 3.0 { 0.9 } else { 0.0 };
            }
        }
        Outline {
            x_mid_mm,
            slice_mm: 1.0,
            chord_mm: chord,
            mid_mm: mid,
            dense_share: dense,
        }
    }

    /// The model breast holds the outline's volume (to the voxel), a skin
    /// shell on every face but the chest wall's, and the glandularity asked
    /// for.
    #[test]
    fn a_box_outline_gives_the_box_with_its_skin() {
        let o = box_outline();
        let m = from_outline(&o, 200.0, 1.0, 1.5, 0.3, Placement::Homogeneous).unwrap();
        let [nx, nz, ny] = m.dims;
        assert_eq!(ny, 80, "the slices' depth");
        assert_eq!((nx, nz), (200, 40));
        let breast = m.labels.iter().filter(|&&l| l != 0).count() as f64;
        // 100 x 40 x 60 mm of contact and the rim's half-round: the chords
        // integrated over 10 mm of depth, 100 mm across.
        let rim: f64 = (0..10)
            .map(|s| {
                let y = 60.5 + s as f64;
                2.0 * (400.0 - (y - 60.0) * (y - 60.0) * 4.0).max(0.0).sqrt()
            })
            .sum::<f64>()
            * 100.0;
        let want = 100.0 * 40.0 * 60.0 + rim;
        assert!(
            (breast / want - 1.0).abs() < 0.03,
            "{breast} voxels against {want} mm^3"
        );
        // Skin at the top, the bottom and the sides, not at the chest wall.
        let at = |c: usize, v: usize, d: usize| m.labels[(d * nz + v) * nx + c];
        assert_eq!(at(100, 0, 30), Tissue::Skin.label());
        assert_eq!(at(100, 39, 30), Tissue::Skin.label());
        assert_eq!(at(50, 20, 30), Tissue::Skin.label());
        assert_ne!(at(100, 20, 0), Tissue::Skin.label());
        assert_ne!(at(100, 20, 30), Tissue::Skin.label());
        assert_eq!(at(10, 20, 30), 0, "beside the breast is air");
        let (g, _) = dbt_dose::patient::glandularity(&m.breast());
        assert!((g - 0.3).abs() < 1e-3, "glandularity {g}");
    }

    /// Central columns: the glandularity asked for, the glandular tissue
    /// only where the rays read dense (the middle third across), in the
    /// middle of each column's height.
    #[test]
    fn central_columns_follow_the_rays_and_the_middle() {
        let m = from_outline(
            &box_outline(),
            200.0,
            1.0,
            1.5,
            0.2,
            Placement::CentralColumns,
        )
        .unwrap();
        let [nx, nz, _] = m.dims;
        let (g, _) = dbt_dose::patient::glandularity(&m.breast());
        assert!((g - 0.2).abs() < 2e-3, "glandularity {g}");
        let at = |c: usize, v: usize, d: usize| m.labels[(d * nz + v) * nx + c];
        let gland = Tissue::Fibroglandular.label();
        // x = 0 (column 100) is dense in its middle, fat near the faces;
        // x = -40 mm (column 60) is fat throughout.
        assert_eq!(at(100, 20, 30), gland);
        assert_eq!(at(100, 3, 30), Tissue::Adipose.label());
        assert!((0..nz).all(|v| at(60, v, 30) != gland));
    }

    /// Shares that hold too little (none at all), or are not numbers, still
    /// give the glandularity asked for, spread over the columns.
    #[test]
    fn central_columns_meet_the_glandularity_whatever_the_shares() {
        let mut o = box_outline();
        o.dense_share.iter_mut().for_each(|f| *f = 0.0);
        let m = from_outline(&o, 200.0, 1.0, 1.5, 0.001, Placement::CentralColumns).unwrap();
        let (g, n) = dbt_dose::patient::glandularity(&m.breast());
        assert!(n > 0 && (g - 0.001).abs() < 2e-4, "{g} ({n} voxels)");
        let mut o = box_outline();
        o.dense_share.iter_mut().for_each(|f| *f = f32::NAN);
        let m = from_outline(&o, 200.0, 1.0, 1.5, 0.3, Placement::CentralColumns).unwrap();
        let (g, _) = dbt_dose::patient::glandularity(&m.breast());
        assert!((g - 0.3).abs() < 2e-3, "{g}");
    }

    #[test]
    fn an_empty_or_malformed_outline_is_refused_by_name() {
        let mut o = box_outline();
        o.chord_mm.iter_mut().for_each(|c| *c = 0.0);
        let e = from_outline(&o, 200.0, 1.0, 1.5, 0.3, Placement::Homogeneous)
            .unwrap_err()
            .to_string();
        assert!(e.contains("no breast"), "{e}");
        let mut o = box_outline();
        o.mid_mm.pop();
        let e = from_outline(&o, 200.0, 1.0, 1.5, 0.3, Placement::Homogeneous)
            .unwrap_err()
            .to_string();
        assert!(e.contains("chords"), "{e}");
        let mut o = box_outline();
        o.dense_share.pop();
        let e = from_outline(&o, 200.0, 1.0, 1.5, 0.3, Placement::CentralColumns)
            .unwrap_err()
            .to_string();
        assert!(e.contains("dense shares"), "{e}");
        let e = from_outline(&box_outline(), 200.0, 1.0, 1.5, 1.3, Placement::Homogeneous)
            .unwrap_err()
            .to_string();
        assert!(e.contains("glandularity 1.3"), "{e}");
        let e = from_outline(&box_outline(), 200.0, 0.0, 1.5, 0.3, Placement::Homogeneous)
            .unwrap_err()
            .to_string();
        assert!(e.contains("voxel 0"), "{e}");
    }
}
