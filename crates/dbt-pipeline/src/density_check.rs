//! The reported density cross-checked against the physics density of the
//! same counts (issue #48 point 3): never a confident composition category
//! that the physics contradicts, never a silent disagreement.
//!
//! Two comparisons, both glandularity by mass in percentage points:
//! * **whole breast**: the reported glandularity (the network's partial
//!   volume, calibrated) against the physics density's central view
//!   ([`dbt_physics_density::PhysicsDensity::central`]);
//! * **contact region**: the network's partial-volume glandularity over the
//!   voxel columns whose central-view ray the physics density reads on the
//!   thickness plane alone (no edge model: [`ContactMap`]), calibrated as
//!   the report is, against the physics density's own figure there. This is
//!   the sharp one: both read the same tissue from the same counts, so the
//!   physics' largest error (the rim's edge model) is out of it.
//!
//! The density is *confirmed* when a physics density exists, both
//! disagreements are within their limits and the breast lies in the
//! validated domain (it fills its box as a validation breast did)
//! ([`CheckLimits::default`]: set on the validation splits,
//! eval/density-check.md). Otherwise the density report asserts no BI-RADS
//! category, says why, and gives both figures.

use crate::process::PipelineError;
use dbt_geometry::Geometry;
use dbt_physics_density::{ContactMap, PhysicsDensity};
use dbt_tissue::{GlandularityCalibration, PartialVolumeMass};
use serde::Serialize;

/// The largest disagreements a confirmed density may show, pp, and the
/// validated domain it must lie in.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CheckLimits {
    /// Reported minus physics, whole breast.
    pub whole_pp: f64,
    /// Network minus physics over the physics' contact region.
    pub contact_pp: f64,
    /// The smallest fill of its box (reconstructed breast volume over
    /// thickness x footprint, [`crate::plausibility::VolumeCheck::fill`]) a
    /// confirmed breast may have: below it much of the compressed slab is
    /// air, which neither estimate was validated on (both read such a
    /// breast's periphery as fat, and so agree on a wrong figure).
    pub min_fill: f64,
}

/// The product's limits, set on the validation splits (procedural and
/// anatomical, mono-energetic and clinical physics, 10 breasts each, the
/// firmware's model): 1.2 times the largest |disagreement| seen there
/// (11.4 pp whole breast, 7.1 pp over the contact region), rounded up to a
/// whole percentage point (eval/density-check.md gives the figures and the
/// command); the smallest fill, 0.95 times the smallest of the 160
/// validation breasts of the report intervals (0.762), rounded down to two
/// places (eval/density-check.md, "The validated domain").
pub const LIMITS: CheckLimits = CheckLimits {
    whole_pp: 14.0,
    contact_pp: 9.0,
    min_fill: 0.72,
};

impl Default for CheckLimits {
    fn default() -> Self {
        LIMITS
    }
}

impl CheckLimits {
    /// Refused unless both disagreement limits are positive and finite and
    /// the smallest fill a fraction.
    pub fn validate(&self) -> Result<(), PipelineError> {
        if !(self.min_fill.is_finite() && (0.0..1.0).contains(&self.min_fill)) {
            return Err(PipelineError::Input(format!(
                "density check limit min_fill = {}: must be a fraction 0..1",
                self.min_fill
            )));
        }
        for (name, v) in [("whole_pp", self.whole_pp), ("contact_pp", self.contact_pp)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(PipelineError::Input(format!(
                    "density check limit {name} = {v}: must be a positive number of percentage points"
                )));
            }
        }
        Ok(())
    }
}

/// The cross-check of one acquisition.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DensityCheck {
    /// The reported glandularity by mass, 0..1.
    pub reported: f64,
    /// The physics density's glandularity (central view), 0..1, when one
    /// could be made.
    pub physics: Option<f64>,
    /// `reported - physics`, pp.
    pub difference_pp: Option<f64>,
    /// The network's glandularity over the physics' contact region
    /// (calibrated as reported), 0..1.
    pub contact_network: Option<f64>,
    /// The physics density's glandularity there, 0..1.
    pub contact_physics: Option<f64>,
    /// `contact_network - contact_physics`, pp.
    pub contact_difference_pp: Option<f64>,
    /// The limits applied.
    pub limits: CheckLimits,
    /// Whether the physics confirms the reported density.
    pub confirmed: bool,
    /// Why it does not (empty when confirmed).
    pub reasons: Vec<String>,
}

impl DensityCheck {
    /// What the density report and the status file say of it.
    pub fn report(&self) -> dbt_dicom::DensityCheckReport {
        dbt_dicom::DensityCheckReport {
            physics_glandularity: self.physics,
            confirmed: self.confirmed,
            reasons: self.reasons.clone(),
        }
    }

    /// One line for logs, the status page and the service CLI.
    pub fn summary(&self) -> String {
        let pc = |v: Option<f64>| v.map_or("none".to_string(), |g| format!("{:.1} %", 100.0 * g));
        let pp = |v: Option<f64>| v.map_or("n/a".to_string(), |d| format!("{d:+.1} pp"));
        format!(
            "{}: reported {:.1} %, physics {} ({}); contact region network {}, physics {} ({})",
            if self.confirmed {
                "confirmed"
            } else {
                "NOT CONFIRMED"
            },
            100.0 * self.reported,
            pc(self.physics),
            pp(self.difference_pp),
            pc(self.contact_network),
            pc(self.contact_physics),
            pp(self.contact_difference_pp),
        )
    }
}

/// The network's partial-volume glandularity by mass over the voxel columns
/// whose central-view ray `map` holds in the contact region (a column at
/// lateral `x` and depth `y` is the ray nearest `x` at the breast's
/// mid-height in the slice holding `y`; the ray's tilt, at most the
/// detector's half fan, moves it by `T/2 tan a` at the faces, within the
/// contact region's 5 mm margin from the rim). Skin and air voxels are out
/// (as in [`dbt_tissue::density`]). `dims = [lateral, vertical, depth]`,
/// lateral as the geometry's image columns; `depth_step_mm` the volume's
/// depth voxel (the slice spacing of a slice-wise volume). `None` without a
/// breast voxel there.
pub fn contact_glandularity(
    mu: &[f32],
    labels: &[u8],
    dims: [usize; 3],
    geometry: &Geometry,
    depth_step_mm: f64,
    map: &ContactMap,
) -> Option<f64> {
    let [nx, ny, nz] = dims;
    if mu.len() != nx * ny * nz || labels.len() != mu.len() {
        return None;
    }
    // Each column's element, once (it does not change with depth).
    let elements: Vec<Option<usize>> = (0..nx)
        .map(|c| map.element_at(geometry.pixel_center_mm(0, c).0))
        .collect();
    let mut pv = PartialVolumeMass::default();
    for z in 0..nz {
        let y_mm = (z as f64 + 0.5) * depth_step_mm;
        for (x, k) in elements.iter().enumerate() {
            if !k.is_some_and(|k| map.holds(k, y_mm)) {
                continue;
            }
            for r in 0..ny {
                let i = (z * ny + r) * nx + x;
                if PartialVolumeMass::counts(labels[i]) {
                    pv.add(mu[i] as f64, 1);
                }
            }
        }
    }
    pv.glandularity()
}

/// The cross-check of a reported glandularity against the physics density.
/// `contact_network_pv` is [`contact_glandularity`] of the reconstruction
/// over the physics' contact region (uncalibrated); `calibration` and
/// `thickness_mm` map it as the reported figure was mapped; `fill` is the
/// reconstructed breast's fill of its box
/// ([`crate::plausibility::VolumeCheck::fill`]), below `limits.min_fill`
/// (or not a number) outside the validated domain.
pub fn cross_check(
    reported: f64,
    contact_network_pv: Option<f64>,
    calibration: Option<&GlandularityCalibration>,
    thickness_mm: f64,
    physics: &Result<PhysicsDensity, String>,
    fill: f64,
    limits: CheckLimits,
) -> DensityCheck {
    let mut reasons = Vec::new();
    let contact_network = contact_network_pv.map(|g| match calibration {
        Some(c) => c.apply(g, thickness_mm),
        None => g,
    });
    let (physics_g, contact_physics) = match physics {
        Ok(p) => (
            Some(p.central.glandularity),
            Some(p.central.contact_glandularity),
        ),
        Err(e) => {
            reasons.push(format!("no physics density to check against: {e}"));
            (None, None)
        }
    };
    let finite = |v: Option<f64>| v.filter(|x| x.is_finite());
    let (physics_g, contact_physics) = (finite(physics_g), finite(contact_physics));
    let difference_pp = physics_g.map(|p| 100.0 * (reported - p));
    let contact_difference_pp = match (contact_network, contact_physics) {
        (Some(n), Some(p)) => Some(100.0 * (n - p)),
        _ => None,
    };
    if physics.is_ok() && physics_g.is_none() {
        reasons.push("the physics density is not a number".into());
    }
    if let Some(d) = difference_pp {
        if d.abs() > limits.whole_pp {
            reasons.push(format!(
                "the reported glandularity and the physics density disagree by {d:+.1} pp (limit {:.0})",
                limits.whole_pp
            ));
        }
    }
    match contact_difference_pp {
        Some(d) if d.abs() > limits.contact_pp => reasons.push(format!(
            "over the contact region the network and the physics disagree by {d:+.1} pp (limit {:.0})",
            limits.contact_pp
        )),
        Some(_) => {}
        None if physics_g.is_some() => reasons.push(
            "no contact region common to the reconstruction and the physics density".into(),
        ),
        None => {}
    }
    if !reported.is_finite() {
        reasons.push("the reported glandularity is not a number".into());
    }
    if fill.is_nan() || fill < limits.min_fill {
        reasons.push(format!(
            "the breast fills {:.1} % of its compressed box, less than any validated breast \
             (limit {:.0} %): the estimates are not known to hold where so much of the box is air",
            100.0 * fill,
            100.0 * limits.min_fill
        ));
    }
    DensityCheck {
        reported,
        physics: physics_g,
        difference_pp,
        contact_network,
        contact_physics,
        contact_difference_pp,
        limits,
        confirmed: reasons.is_empty(),
        reasons,
    }
}

/// The breast's labels with its interior (adipose, fibroglandular,
/// ligament) relabelled so that its glandularity by mass is `g` (as near as
/// whole voxels allow): the model breast ([`dbt_dose::patient::Model::Homogeneous`],
/// which mixes the interior to the labels' glandularity and ignores where
/// each tissue lies) at another glandularity than the reconstruction's,
/// the outline and skin unchanged.
pub fn labels_at_glandularity(labels: &[u8], g: f64) -> Vec<u8> {
    use dbt_materials::Tissue;
    let interior = |l: u8| matches!(l, 1 | 3 | 4);
    let n = labels.iter().filter(|&&l| interior(l)).count() as f64;
    let (rg, ra) = (
        Tissue::Fibroglandular.density_g_cm3(),
        Tissue::Adipose.density_g_cm3(),
    );
    let g = g.clamp(0.0, 1.0);
    // g = rg ng / (rg ng + ra (n - ng))  <=>  ng = g ra n / (rg - g (rg - ra)).
    let ng = (g * ra * n / (rg - g * (rg - ra))).round() as usize;
    let mut left = ng;
    labels
        .iter()
        .map(|&l| {
            if !interior(l) {
                l
            } else if left > 0 {
                left -= 1;
                Tissue::Fibroglandular.label()
            } else {
                Tissue::Adipose.label()
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn physics(g: f64, contact: f64) -> Result<PhysicsDensity, String> {
        // A physics density as the crate makes it, figures replaced.
        let mut p = dbt_physics_density::PhysicsDensity {
            central: dbt_physics_density::ViewDensity {
                view: 12,
                angle_deg: 0.0,
                fgv_cm3: 100.0,
                bv_cm3: 400.0,
                interior_cm3: 380.0,
                vbd: 0.26,
                glandularity: 0.0,
                rim_share: 0.3,
                contact_glandularity: 0.0,
                over_dense_share: 0.0,
                truncated: false,
                thickness: dbt_physics_density::ThicknessFit {
                    readout_mm: 50.0,
                    centre_mm: 50.0,
                    range_mm: [50.0, 50.0],
                    slope_mm_per_cm: [0.0, 0.0],
                    tiles: 10,
                    at_bound: false,
                },
                rim: vec![],
                contact: ContactMap::default(),
            },
            views: vec![],
            spread_pp: 0.0,
            flags: vec![],
        };
        p.central.glandularity = g;
        p.central.contact_glandularity = contact;
        Ok(p)
    }

    /// Within both limits: confirmed, no reason; each limit alone breaks
    /// it, naming the disagreement; no physics density: not confirmed.
    #[test]
    fn each_disagreement_alone_withholds_the_confirmation() {
        let l = CheckLimits {
            whole_pp: 10.0,
            contact_pp: 5.0,
            ..LIMITS
        };
        let ok = cross_check(0.30, Some(0.32), None, 50.0, &physics(0.25, 0.30), 0.9, l);
        assert!(ok.confirmed, "{:?}", ok.reasons);
        assert!((ok.difference_pp.unwrap() - 5.0).abs() < 1e-9);
        assert!((ok.contact_difference_pp.unwrap() - 2.0).abs() < 1e-9);
        let whole = cross_check(0.40, Some(0.32), None, 50.0, &physics(0.25, 0.30), 0.9, l);
        assert!(!whole.confirmed);
        assert!(whole.reasons[0].contains("+15.0 pp"), "{:?}", whole.reasons);
        let contact = cross_check(0.30, Some(0.38), None, 50.0, &physics(0.25, 0.30), 0.9, l);
        assert!(!contact.confirmed);
        assert!(
            contact.reasons[0].contains("contact region") && contact.reasons[0].contains("+8.0"),
            "{:?}",
            contact.reasons
        );
        let none = cross_check(
            0.30,
            Some(0.32),
            None,
            50.0,
            &Err("no breast".into()),
            0.9,
            l,
        );
        assert!(!none.confirmed && none.physics.is_none());
        assert!(none.reasons[0].contains("no breast"));
        let nan = cross_check(
            0.30,
            Some(0.32),
            None,
            50.0,
            &physics(f64::NAN, 0.3),
            0.9,
            l,
        );
        assert!(!nan.confirmed);
        assert!(!cross_check(0.30, None, None, 50.0, &physics(0.25, 0.30), 0.9, l).confirmed);
    }

    /// The network's contact figure is mapped by the report's calibration
    /// before it is compared.
    #[test]
    fn the_contact_figure_is_calibrated_as_the_report() {
        let cal = GlandularityCalibration {
            offset: -0.05,
            slope: 1.0,
            per_mm: 0.0,
            thickness_range_mm: None,
        };
        let c = cross_check(
            0.30,
            Some(0.35),
            Some(&cal),
            50.0,
            &physics(0.30, 0.30),
            0.9,
            LIMITS,
        );
        assert!((c.contact_network.unwrap() - 0.30).abs() < 1e-12);
        assert!(c.confirmed);
    }

    /// The relabelled breast has the asked glandularity by mass, its skin
    /// and air where they were.
    #[test]
    fn relabelling_gives_the_asked_glandularity() {
        let labels: Vec<u8> = (0..10_000u32)
            .map(|i| [0, 2, 1, 1, 3, 4][i as usize % 6])
            .collect();
        for g in [0.0, 0.05, 0.3, 0.77, 1.0] {
            let r = labels_at_glandularity(&labels, g);
            let got = dbt_materials::glandularity_of_labels(&r).unwrap().unwrap();
            assert!((got - g).abs() < 1e-3, "asked {g}, got {got}");
            assert!(labels
                .iter()
                .zip(&r)
                .all(|(&a, &b)| (a == 0 || a == 2) == (a == b) || matches!(a, 1 | 3 | 4)));
            assert!(labels
                .iter()
                .zip(&r)
                .filter(|(&a, _)| a == 0 || a == 2)
                .all(|(a, b)| a == b));
        }
    }

    #[test]
    fn limits_must_be_positive() {
        assert!(LIMITS.validate().is_ok());
        let e = CheckLimits {
            whole_pp: 0.0,
            contact_pp: 5.0,
            ..LIMITS
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(e.contains("whole_pp = 0"), "{e}");
        let e = CheckLimits {
            min_fill: f64::NAN,
            ..LIMITS
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(e.contains("min_fill = NaN"), "{e}");
    }

    /// A breast filling less of its box than any validated one is not
    /// confirmed, whatever the two estimates say, and says why; one at the
    /// limit is; a fill that is not a number is not.
    #[test]
    fn a_breast_outside_the_validated_fill_is_not_confirmed() {
        let agree = |fill| {
            cross_check(
                0.30,
                Some(0.30),
                None,
                50.0,
                &physics(0.30, 0.30),
                fill,
                LIMITS,
            )
        };
        assert!(agree(0.9).confirmed);
        let c = agree(LIMITS.min_fill);
        assert!(c.confirmed, "{:?}", c.reasons);
        let c = agree(0.687);
        assert!(!c.confirmed);
        assert!(
            c.reasons[0].contains("fills 68.7 % of its compressed box"),
            "{:?}",
            c.reasons
        );
        assert!(c.reasons[0].contains("limit 72 %"), "{:?}", c.reasons);
        assert!(!agree(f64::NAN).confirmed);
    }
}
