//! A real gantry's geometry (issue #28): the source on an arc, x-rays
//! diverging in depth as well as across, a 2-D detector that rotates with the
//! source or stays still.
//!
//! # Coordinate system
//! Millimetres. `x` across the chest wall (0 on the central plane of the
//! sweep), `y` the depth from the detector's chest-wall edge towards the
//! nipple, `z` up from the detector's input plane at 0 degrees. The source
//! turns about the axis `{x = 0, z = axis_height_mm}` (parallel to `y`): at
//! view angle `theta` it sits at
//! `(R sin theta, source_depth_mm, axis_height_mm + R cos theta)`.
//! Detector element (row `j`, column `k`) at 0 degrees lies at
//! `((k - (columns - 1) / 2) pitch, (j + 1/2) pitch, 0)`: rows run from the
//! chest wall, columns across. A `stationary` detector keeps that position
//! at every view; a `rotating` one turns with the source about the same
//! axis, so that in every plane `y = const` the source, the axis and the
//! detector's centre line stay aligned (the paper's fan-beam geometry is
//! the plane `y = source_depth_mm` of the rotating system); a `tilting` one
//! turns about the same axis by `detector_tilt_factor` times the source's
//! angle (Hologic's, about 0.28: 4.2 degrees over a 15 degree sweep). All
//! three are the one rule `detector angle = k x source angle`, k 0, 1 or
//! the factor ([`ConeSystem::detector_angle_deg`]).
//!
//! A breast volume rests on the support (`z = support_height_mm`), is
//! centred across (`x = 0`) and starts at the chest wall (`y = 0`).

use crate::{invalid, GeometryError, Views};
use serde::{Deserialize, Serialize};

/// `paper-cone`: the paper's gantry as a cone-beam system.
pub const PAPER_CONE_TOML: &str = include_str!("../geometry/paper-cone.toml");
/// `siemens-victre`: a stationary-detector, wide-angle system.
pub const SIEMENS_VICTRE_TOML: &str = include_str!("../geometry/siemens-victre.toml");

/// `hologic-dimensions`: Hologic Selenia Dimensions, a tilting detector,
/// the pivot in its plane (every value cited in `geometry/SOURCES-vendors.md`).
pub const HOLOGIC_DIMENSIONS_TOML: &str = include_str!("../geometry/hologic-dimensions.toml");
/// `ge-essential`: GE Senographe Essential, 9 views, stationary CsI detector.
pub const GE_ESSENTIAL_TOML: &str = include_str!("../geometry/ge-essential.toml");
/// `siemens-inspiration`: Siemens Mammomat Inspiration as NifTK measured it.
pub const SIEMENS_INSPIRATION_TOML: &str = include_str!("../geometry/siemens-inspiration.toml");

/// The built-in cone-beam systems by name.
pub const BUILTIN_SYSTEMS: [(&str, &str); 5] = [
    ("paper-cone", PAPER_CONE_TOML),
    ("siemens-victre", SIEMENS_VICTRE_TOML),
    ("hologic-dimensions", HOLOGIC_DIMENSIONS_TOML),
    ("ge-essential", GE_ESSENTIAL_TOML),
    ("siemens-inspiration", SIEMENS_INSPIRATION_TOML),
];

/// Whether the detector turns with the source.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DetectorMotion {
    /// Turns with the source about the rotation axis.
    Rotating,
    /// Stays in the plane `z = 0`.
    Stationary,
    /// Turns about the rotation axis by `detector_tilt_factor` times the
    /// source's angle.
    Tilting,
}

/// A flat 2-D detector of square elements.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Detector2d {
    /// Elements across the chest wall.
    pub columns: usize,
    /// Elements from the chest wall towards the nipple.
    pub rows: usize,
    /// Element pitch, mm.
    pub pitch_mm: f64,
    /// Its x-ray converter (`[detector.converter]`: `material` "CsI" or
    /// "a-Se", `thickness_um`), where the system's file states it; absent:
    /// [`dbt_materials::Converter::default`] (200 um of CsI).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub converter: Option<dbt_materials::Converter>,
    /// The converter's line spread, um (`line_spread_um`): the scale `s` of
    /// an exponential line spread function `exp(-|x| / s) / (2 s)` across
    /// the detector's plane (a scintillator's light spread: the model and
    /// the fit to a measured MTF are `dbt_forward::spread`'s), where the
    /// system's file states it; absent: none (each element records only
    /// what reaches it, the paper's ideal detector).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub line_spread_um: Option<f64>,
}

/// A validated cone-beam DBT system.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConeSystem {
    /// Its name (what the gantry interface states).
    pub name: String,
    /// Source to rotation axis, mm.
    pub arc_radius_mm: f64,
    /// Rotation axis above the detector's input plane (at 0 degrees), mm.
    pub axis_height_mm: f64,
    /// Breast support above the detector's input plane, mm.
    pub support_height_mm: f64,
    /// The source's depth `y`, mm (0: above the chest-wall edge).
    pub source_depth_mm: f64,
    /// Rotating, stationary or tilting detector.
    pub detector_motion: DetectorMotion,
    /// A tilting detector's angle over the source's (0 < k < 1); given for
    /// a tilting detector only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub detector_tilt_factor: Option<f64>,
    /// Views: `count` of them from `first_deg` to `last_deg`, evenly spaced
    /// unless `view_angles_deg` gives each.
    pub views: Views,
    /// Each view's source angle, degrees, increasing, where the system's
    /// views are not evenly spaced (measured angles; the first and last
    /// must be `views.first_deg` and `views.last_deg`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view_angles_deg: Option<Vec<f64>>,
    /// The arc the source travels during one view's exposure, degrees
    /// (continuous motion: the focal spot is smeared over it); 0 for
    /// step-and-shoot.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub source_blur_deg: f64,
    /// Detector.
    pub detector: Detector2d,
}

/// A point, mm.
pub type Point3 = [f64; 3];

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

impl ConeSystem {
    /// Parse and validate from TOML text.
    pub fn from_toml_str(text: &str) -> Result<Self, GeometryError> {
        let s: Self = toml::from_str(text).map_err(|e| GeometryError::Parse(e.to_string()))?;
        s.validate()?;
        Ok(s)
    }

    /// A built-in system by name ([`BUILTIN_SYSTEMS`]).
    pub fn builtin(name: &str) -> Option<Self> {
        BUILTIN_SYSTEMS
            .iter()
            .find(|(n, _)| *n == name)
            // The embedded files are part of this crate and covered by its tests.
            .map(|(_, t)| Self::from_toml_str(t).expect("embedded system is valid"))
    }

    /// The detector's converter: the one the system states, else 200 um of
    /// CsI ([`dbt_materials::Converter::default`]).
    pub fn converter(&self) -> dbt_materials::Converter {
        self.detector.converter.unwrap_or_default()
    }

    /// The converter's line spread scale, mm (0: none; see
    /// [`Detector2d::line_spread_um`]).
    pub fn line_spread_mm(&self) -> f64 {
        self.detector.line_spread_um.unwrap_or(0.0) / 1000.0
    }

    /// Elements `factor` times larger on each side (same detector area).
    pub fn binned(&self, factor: usize) -> Result<Self, GeometryError> {
        if factor == 0 {
            return Err(invalid("binning", "factor must be at least 1"));
        }
        let d = &self.detector;
        let s = Self {
            detector: Detector2d {
                columns: d.columns / factor,
                rows: d.rows / factor,
                pitch_mm: d.pitch_mm * factor as f64,
                converter: d.converter,
                line_spread_um: d.line_spread_um,
            },
            ..self.clone()
        };
        s.validate()?;
        Ok(s)
    }

    /// Check every constraint, naming the first offending field.
    pub fn validate(&self) -> Result<(), GeometryError> {
        let positive = |field: &'static str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(invalid(
                    field,
                    format!("must be a finite positive number, got {v}"),
                ))
            }
        };
        positive("arc_radius_mm", self.arc_radius_mm)?;
        if let Some(c) = &self.detector.converter {
            c.validate()
                .map_err(|e| invalid("detector.converter", e.to_string()))?;
        }
        // The axis may lie in the detector's plane (Hologic's pivot), not
        // below it.
        if !(self.axis_height_mm.is_finite() && self.axis_height_mm >= 0.0) {
            return Err(invalid(
                "axis_height_mm",
                format!(
                    "must be a finite number, 0 or above (0: the axis in the detector's plane), got {}",
                    self.axis_height_mm
                ),
            ));
        }
        match (self.detector_motion, self.detector_tilt_factor) {
            (DetectorMotion::Tilting, Some(k)) if k.is_finite() && k > 0.0 && k < 1.0 => {}
            (DetectorMotion::Tilting, k) => {
                return Err(invalid(
                    "detector_tilt_factor",
                    format!(
                        "a tilting detector needs a factor between 0 and 1 (exclusive; 0 is stationary, 1 rotating), got {k:?}"
                    ),
                ))
            }
            (_, Some(k)) => {
                return Err(invalid(
                    "detector_tilt_factor",
                    format!("{k} given for a detector that is not tilting"),
                ))
            }
            (_, None) => {}
        }
        if !(self.source_blur_deg.is_finite()
            && self.source_blur_deg >= 0.0
            && self.source_blur_deg < 5.0)
        {
            return Err(invalid(
                "source_blur_deg",
                format!(
                    "must be 0 (step-and-shoot) or the arc of one exposure, below 5 degrees, got {}",
                    self.source_blur_deg
                ),
            ));
        }
        positive("detector.pitch_mm", self.detector.pitch_mm)?;
        if let Some(s) = self.detector.line_spread_um {
            // Up to a millimetre: a scintillator's light spreads over tens of
            // um (a CsI panel's scale is about 60: ge-essential.toml).
            if !(s.is_finite() && (0.0..=1000.0).contains(&s)) {
                return Err(invalid(
                    "detector.line_spread_um",
                    format!("must be a number of um from 0 to 1000, got {s}"),
                ));
            }
        }
        if !(self.support_height_mm.is_finite()
            && self.support_height_mm >= 0.0
            && self.support_height_mm < self.axis_height_mm + self.arc_radius_mm / 2.0)
        {
            return Err(invalid(
                "support_height_mm",
                format!(
                    "must lie between the detector and well below the source, got {}",
                    self.support_height_mm
                ),
            ));
        }
        if !self.source_depth_mm.is_finite() {
            return Err(invalid("source_depth_mm", "must be finite"));
        }
        if self.views.count < 2 {
            return Err(invalid("views.count", "at least 2 views are needed"));
        }
        for (field, a) in [
            ("views.first_deg", self.views.first_deg),
            ("views.last_deg", self.views.last_deg),
        ] {
            if !a.is_finite() || a.abs() >= 60.0 {
                return Err(invalid(
                    field,
                    format!("must be within (-60, 60) degrees, got {a}"),
                ));
            }
        }
        if self.views.last_deg <= self.views.first_deg {
            return Err(invalid("views.last_deg", "must exceed views.first_deg"));
        }
        if let Some(a) = &self.view_angles_deg {
            if a.len() != self.views.count {
                return Err(invalid(
                    "view_angles_deg",
                    format!("{} angles for {} views", a.len(), self.views.count),
                ));
            }
            if a.iter().any(|x| !x.is_finite()) || a.windows(2).any(|w| w[1] <= w[0]) {
                return Err(invalid(
                    "view_angles_deg",
                    "must be finite and increasing, one per view",
                ));
            }
            let ends = (a[0] - self.views.first_deg).abs() < 1e-9
                && (a[a.len() - 1] - self.views.last_deg).abs() < 1e-9;
            if !ends {
                return Err(invalid(
                    "view_angles_deg",
                    format!(
                        "first and last ({}, {}) must be views.first_deg and views.last_deg ({}, {})",
                        a[0],
                        a[a.len() - 1],
                        self.views.first_deg,
                        self.views.last_deg
                    ),
                ));
            }
        }
        for (field, n) in [
            ("detector.columns", self.detector.columns),
            ("detector.rows", self.detector.rows),
        ] {
            if n == 0 || n > 1 << 16 {
                return Err(invalid(field, format!("{n} elements")));
            }
        }
        // The source stays above the support at every view.
        for v in 0..self.views.count {
            let s = self.source(v);
            if s[2] <= self.support_height_mm + 50.0 {
                return Err(invalid(
                    "arc_radius_mm",
                    format!(
                        "the source at view {v} is {:.1} mm high, not above the breast",
                        s[2]
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Number of views.
    pub fn n_views(&self) -> usize {
        self.views.count
    }

    /// View angle, degrees: the measured one where the system gives each
    /// view's, else evenly spaced.
    pub fn angle_deg(&self, v: usize) -> f64 {
        if let Some(a) = self.view_angles_deg.as_ref().and_then(|a| a.get(v)) {
            return *a;
        }
        let w = &self.views;
        w.first_deg + (w.last_deg - w.first_deg) * v as f64 / (w.count - 1) as f64
    }

    /// Whether the views are evenly spaced (no measured angles).
    pub fn evenly_spaced(&self) -> bool {
        self.view_angles_deg.is_none()
    }

    /// The detector's angle at view `v`, degrees: `k x` the source's, `k` 0
    /// (stationary), 1 (rotating) or the tilt factor.
    pub fn detector_angle_deg(&self, v: usize) -> f64 {
        let k = match self.detector_motion {
            DetectorMotion::Stationary => 0.0,
            DetectorMotion::Rotating => 1.0,
            DetectorMotion::Tilting => self.detector_tilt_factor.unwrap_or(0.0),
        };
        k * self.angle_deg(v)
    }

    /// Detector elements of one view (rows x columns).
    pub fn n_elements(&self) -> usize {
        self.detector.rows * self.detector.columns
    }

    /// The source at view `v`.
    pub fn source(&self, v: usize) -> Point3 {
        let t = self.angle_deg(v).to_radians();
        [
            self.arc_radius_mm * t.sin(),
            self.source_depth_mm,
            self.axis_height_mm + self.arc_radius_mm * t.cos(),
        ]
    }

    /// The centre of detector element (`row`, `column`) at view `v`.
    pub fn element(&self, v: usize, row: usize, column: usize) -> Point3 {
        let p = self.detector.pitch_mm;
        let x = (column as f64 - (self.detector.columns as f64 - 1.0) / 2.0) * p;
        let y = (row as f64 + 0.5) * p;
        match self.detector_motion {
            DetectorMotion::Stationary => [x, y, 0.0],
            DetectorMotion::Rotating => self.rotating_point(v, x, y),
            DetectorMotion::Tilting => self.turned_point(self.detector_angle_deg(v), x, y),
        }
    }

    /// The point at `(x_mm, y_mm)` of the detector's plane (`z = 0` at 0
    /// degrees) turned by `deg` about the rotation axis: (x, 0) turned
    /// about the axis (0, h) in the x-z plane as the source is ((0, R)
    /// relative to the axis goes to (R sin t, R cos t)), so (dx, dz) goes to
    /// (dx cos t + dz sin t, -dx sin t + dz cos t).
    pub fn turned_point(&self, deg: f64, x_mm: f64, y_mm: f64) -> Point3 {
        let t = deg.to_radians();
        let h = self.axis_height_mm;
        let (dx, dz) = (x_mm, -h);
        [
            dx * t.cos() + dz * t.sin(),
            y_mm,
            h - dx * t.sin() + dz * t.cos(),
        ]
    }

    /// The point at `(x_mm, y_mm)` of a detector that turns with the source
    /// (in the plane `z = 0` at 0 degrees), at view `v`: the rotating
    /// detector's elements, and the fan geometry's elements that the
    /// rebinning reads a stationary detector for.
    pub fn rotating_point(&self, v: usize, x_mm: f64, y_mm: f64) -> Point3 {
        self.turned_point(self.angle_deg(v), x_mm, y_mm)
    }

    /// The fan geometry this system's projections are rebinned to for a
    /// reconstruction on `template`'s detector elements and image: the
    /// source arc's radius, the detector at the distance it has at 0
    /// degrees (turning with the source: a virtual detector for a stationary
    /// one), the system's views, and the template's image resting on the
    /// system's support (raised by `image.centre_z_mm` where the support is
    /// not half the image below the axis: Hologic's pivot, GE's axis). It is
    /// `template` itself when the template was made for this system
    /// (`paper-cone` and the paper's geometries).
    pub fn rebinning_fan(
        &self,
        template: &crate::Geometry,
    ) -> Result<crate::Geometry, GeometryError> {
        if !self.evenly_spaced() {
            return Err(invalid(
                "view_angles_deg",
                "a fan geometry's views are evenly spaced: this system's measured angles have no rebinning fan",
            ));
        }
        // The image rests on the support: its centre `rows x pixel / 2`
        // above it, measured from the axis (0 for the paper's layout).
        let rows_mm = template.image.rows as f64 * template.image.pixel_mm;
        let mut image = template.image.clone();
        image.centre_z_mm = self.support_height_mm + rows_mm / 2.0 - self.axis_height_mm;
        let mut g = crate::Geometry {
            source_to_center_mm: self.arc_radius_mm,
            source_to_detector_mm: self.arc_radius_mm + self.axis_height_mm,
            views: self.views.clone(),
            image,
            ..template.clone()
        };
        // A detector that does not turn with the source is read through a
        // virtual one that does: as many of the template's elements as
        // cover the image at every view (the same parity, so that the
        // central ray keeps its place on an element's centre or edge). A
        // rotating detector's elements are its own columns.
        if self.detector_motion != DetectorMotion::Rotating {
            let pitch = g.detector.pitch_mm;
            let reach = (0..g.n_views())
                .flat_map(|v| {
                    g.image_corners_mm()
                        .map(|(x, z)| g.project_point(v, x, z).u_mm)
                })
                .fold(0.0f64, |m, u| m.max(u.abs()));
            let need = (2.0 * reach / pitch).ceil() as usize;
            let mut n = g.detector.elements.max(need);
            if n % 2 != g.detector.elements % 2 {
                n += 1;
            }
            g.detector.elements = n;
        }
        g.validate()?;
        Ok(g)
    }

    /// The 2-D fan-beam geometry of the plane `y = source_depth_mm` of a
    /// rotating system, with an image of `columns x rows` pixels of
    /// `pixel_mm` centred across and resting on the support.
    pub fn central_fan(
        &self,
        columns: usize,
        rows: usize,
        pixel_mm: f64,
    ) -> Result<crate::Geometry, GeometryError> {
        if self.detector_motion != DetectorMotion::Rotating {
            return Err(invalid(
                "detector_motion",
                "a stationary detector has no rotating fan-beam equivalent",
            ));
        }
        let g = crate::Geometry {
            source_to_center_mm: self.arc_radius_mm,
            source_to_detector_mm: self.arc_radius_mm + self.axis_height_mm,
            views: self.views.clone(),
            detector: crate::Detector {
                elements: self.detector.columns,
                pitch_mm: self.detector.pitch_mm,
            },
            image: crate::Image {
                columns,
                rows,
                pixel_mm,
                centre_z_mm: self.support_height_mm + rows as f64 * pixel_mm / 2.0
                    - self.axis_height_mm,
            },
        };
        g.validate()?;
        Ok(g)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_systems_load_and_match_their_sources() {
        let p = ConeSystem::builtin("paper-cone").unwrap();
        // The paper: source 650 mm from the axis, 700 mm from the detector.
        let s = p.source(12);
        assert!((s[2] - 700.0).abs() < 1e-9 && s[0].abs() < 1e-9);
        assert!((p.element(12, 0, 640)[2]).abs() < 1e-9);
        let g = ConeSystem::builtin("siemens-victre").unwrap();
        assert_eq!(g.detector_motion, DetectorMotion::Stationary);
        // VICTRE: source 650 mm above the detector at 0 degrees, views
        // 2.0833 degrees apart.
        assert!((g.source(12)[2] - 650.0).abs() < 1e-9);
        assert!((g.angle_deg(1) - g.angle_deg(0) - 50.0 / 24.0).abs() < 1e-12);
        assert!(ConeSystem::builtin("nonesuch").is_none());
    }

    /// Each built-in system's converter is what its file cites: a-Se for
    /// Hologic and Siemens (direct conversion), CsI for GE; the paper's
    /// (stated nowhere) 200 um of CsI; binning keeps it; a converter that
    /// cannot be is refused naming the field and the value.
    #[test]
    fn each_system_states_its_converter() {
        use dbt_materials::ConverterMaterial::{ASe, CsI};
        for (name, material) in [
            ("paper-cone", CsI),
            ("siemens-victre", ASe),
            ("hologic-dimensions", ASe),
            ("ge-essential", CsI),
            ("siemens-inspiration", ASe),
        ] {
            let s = ConeSystem::builtin(name).unwrap();
            assert_eq!(s.converter().material, material, "{name}");
            assert_eq!(s.converter().thickness_um, 200.0, "{name}");
            assert_eq!(s.binned(4).unwrap().converter(), s.converter(), "{name}");
        }
        assert!(ConeSystem::builtin("paper-cone")
            .unwrap()
            .detector
            .converter
            .is_none());
        let t = SIEMENS_VICTRE_TOML.replace("thickness_um = 200.0", "thickness_um = 0.2");
        let e = ConeSystem::from_toml_str(&t).unwrap_err().to_string();
        assert!(
            e.contains("detector.converter") && e.contains("0.2 um"),
            "{e}"
        );
        // The firmware's spelling reads too.
        let t = SIEMENS_VICTRE_TOML.replace("\"a-Se\"", "\"a-se\"");
        assert_eq!(
            ConeSystem::from_toml_str(&t).unwrap().converter().material,
            ASe
        );
        let t = SIEMENS_VICTRE_TOML.replace("\"a-Se\"", "\"GOS\"");
        let e = ConeSystem::from_toml_str(&t).unwrap_err().to_string();
        assert!(e.contains("GOS"), "{e}");
    }

    /// The panel's spread (`[detector] line_spread_um`): read in um, kept
    /// by binning, absent where the file states none; a negative, huge or
    /// non-numeric one is refused naming the key and the value.
    #[test]
    fn a_detector_states_its_line_spread() {
        let ge = ConeSystem::builtin("ge-essential").unwrap();
        assert_eq!(ge.detector.line_spread_um, Some(56.8));
        assert!((ge.line_spread_mm() - 0.0568).abs() < 1e-15);
        assert_eq!(ge.binned(4).unwrap().line_spread_mm(), ge.line_spread_mm());
        assert_eq!(
            ConeSystem::builtin("paper-cone").unwrap().line_spread_mm(),
            0.0
        );
        for bad in ["-1.0", "1500.0", "nan"] {
            let t = GE_ESSENTIAL_TOML
                .replace("line_spread_um = 56.8", &format!("line_spread_um = {bad}"));
            let e = ConeSystem::from_toml_str(&t).unwrap_err().to_string();
            assert!(e.contains("detector.line_spread_um"), "{bad}: {e}");
        }
    }

    /// A rotating detector stays at the same distance from the source and
    /// perpendicular to the central ray; a stationary one stays put.
    #[test]
    fn detectors_move_as_declared() {
        let p = ConeSystem::builtin("paper-cone")
            .unwrap()
            .binned(8)
            .unwrap();
        let dist = |a: Point3, b: Point3| {
            ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
        };
        let c = (p.detector.columns - 1) as f64 / 2.0;
        for v in [0, 7, 24] {
            // Between the two central columns: the central ray's foot.
            let (a, b) = (
                p.element(v, 0, c.floor() as usize),
                p.element(v, 0, c.ceil() as usize),
            );
            let foot = [(a[0] + b[0]) / 2.0, p.source_depth_mm, (a[2] + b[2]) / 2.0];
            let d = dist(p.source(v), [foot[0], p.source_depth_mm, foot[2]]);
            assert!((d - 700.0).abs() < 1e-6, "view {v}: {d}");
        }
        let g = ConeSystem::builtin("siemens-victre")
            .unwrap()
            .binned(16)
            .unwrap();
        assert_eq!(g.element(0, 3, 5), g.element(24, 3, 5));
    }

    #[test]
    fn bad_systems_are_refused_by_field() {
        let bad = |from: &str, to: &str, field: &str| {
            let t = PAPER_CONE_TOML.replace(from, to);
            let e = ConeSystem::from_toml_str(&t).unwrap_err().to_string();
            assert!(e.contains(field), "{to}: {e}");
        };
        bad(
            "arc_radius_mm = 650.0",
            "arc_radius_mm = -1.0",
            "arc_radius_mm",
        );
        bad(
            "detector_motion = \"rotating\"",
            "detector_motion = \"wobbling\"",
            "wobbling",
        );
        bad("last_deg = 24.0", "last_deg = -30.0", "views.last_deg");
        bad("columns = 1280", "columns = 0", "detector.columns");
        bad(
            "axis_height_mm = 50.0",
            "axis_height_mm = -1.0",
            "axis_height_mm",
        );
        let tilting = "detector_motion = \"tilting\"";
        bad(
            "detector_motion = \"rotating\"",
            tilting,
            "detector_tilt_factor",
        );
        for k in ["0.0", "1.0", "-0.3", "nan"] {
            bad(
                "detector_motion = \"rotating\"",
                &format!("{tilting}\ndetector_tilt_factor = {k}"),
                "detector_tilt_factor",
            );
        }
        bad(
            "detector_motion = \"rotating\"",
            "detector_motion = \"stationary\"\ndetector_tilt_factor = 0.3",
            "not tilting",
        );
        for blur in ["-0.1", "5.0"] {
            bad(
                "detector_motion = \"rotating\"",
                &format!("detector_motion = \"rotating\"\nsource_blur_deg = {blur}"),
                "source_blur_deg",
            );
        }
        let angles = |list: &str| {
            PAPER_CONE_TOML.replace(
                "detector_motion = \"rotating\"",
                &format!("detector_motion = \"rotating\"\nview_angles_deg = [{list}]"),
            )
        };
        let even: Vec<String> = (0..25)
            .map(|v| format!("{}", -24.0 + 2.0 * v as f64))
            .collect();
        let mut uneven = even.clone();
        uneven[1] = "-23.5".into();
        let p = ConeSystem::from_toml_str(&angles(&uneven.join(","))).unwrap();
        assert_eq!(p.angle_deg(1), -23.5);
        assert!(!p.evenly_spaced());
        assert!(p.rebinning_fan(&crate::Geometry::paper()).is_err());
        for (list, why) in [
            (even[..24].join(","), "24 angles for 25 views"),
            (
                {
                    let mut l = even.clone();
                    l.swap(3, 4);
                    l.join(",")
                },
                "increasing",
            ),
            (
                {
                    let mut l = even.clone();
                    l[24] = "23.0".into();
                    l.join(",")
                },
                "must be views.first_deg and views.last_deg",
            ),
        ] {
            let e = ConeSystem::from_toml_str(&angles(&list))
                .unwrap_err()
                .to_string();
            assert!(e.contains("view_angles_deg") && e.contains(why), "{e}");
        }
    }

    /// The vendors' systems carry the figures of their sources
    /// (`geometry/SOURCES-vendors.md`): source-to-detector distance at 0
    /// degrees, views, pitch; the tilting detector turns by 0.28 x the
    /// source's angle about the pivot in its plane, rigidly (every element
    /// keeps its distance from the axis), and a factor of 1 would be the
    /// rotating detector, 0 the stationary one.
    #[test]
    fn vendor_systems_match_their_sources() {
        for (name, sid, views, pitch) in [
            ("hologic-dimensions", 700.0, 15, 0.14),
            ("ge-essential", 660.0, 9, 0.1),
            ("siemens-inspiration", 655.5, 25, 0.085),
        ] {
            let s = ConeSystem::builtin(name).unwrap();
            assert_eq!(s.name, name);
            let mid = s.n_views() / 2;
            assert!((s.source(mid)[2] - sid).abs() < 1e-9, "{name}");
            assert_eq!(s.n_views(), views, "{name}");
            assert_eq!(s.detector.pitch_mm, pitch, "{name}");
        }
        let h = ConeSystem::builtin("hologic-dimensions").unwrap();
        assert_eq!(h.detector_motion, DetectorMotion::Tilting);
        let last = h.n_views() - 1;
        assert!((h.detector_angle_deg(last) - 0.28 * 7.5).abs() < 1e-12);
        assert!((h.detector_angle_deg(0) + 0.28 * 7.5).abs() < 1e-12);
        let (c, r) = (h.detector.columns - 1, h.detector.rows - 1);
        for v in [0, 7, last] {
            let (a, b) = (h.element(v, 0, 0), h.element(v, 0, c));
            // The detector's row turned by the detector's angle: its
            // direction (cos phi, -sin phi) in x-z.
            let phi = h.detector_angle_deg(v).to_radians();
            let len = ((b[0] - a[0]).powi(2) + (b[2] - a[2]).powi(2)).sqrt();
            assert!(((b[0] - a[0]) / len - phi.cos()).abs() < 1e-12, "view {v}");
            assert!(((b[2] - a[2]) / len + phi.sin()).abs() < 1e-12, "view {v}");
            // Rigid about the axis at z = 0: distances in x-z kept.
            for (row, col) in [(0, 0), (r, c), (r / 2, c / 3)] {
                let e = h.element(v, row, col);
                let e0 = h.element(mid_view(&h), row, col);
                let d = |p: Point3| (p[0] * p[0] + p[2] * p[2]).sqrt();
                assert!((d(e) - d(e0)).abs() < 1e-9, "view {v} ({row}, {col})");
                assert_eq!(e[1], e0[1]);
            }
        }
        // k = 1 and k = 0 as the rule: the turned point at the source's
        // angle is the rotating element, at 0 the stationary one.
        let p = ConeSystem::builtin("paper-cone").unwrap();
        for v in [0, 12, 24] {
            assert_eq!(
                p.turned_point(p.angle_deg(v), 1.4, 2.2),
                p.rotating_point(v, 1.4, 2.2)
            );
            let g = ConeSystem::builtin("siemens-victre").unwrap();
            let e = g.element(v, 4, 9);
            let t = g.turned_point(0.0, e[0], e[1]);
            assert!((t[0] - e[0]).abs() < 1e-12 && t[2].abs() < 1e-12);
        }
    }

    fn mid_view(s: &ConeSystem) -> usize {
        s.n_views() / 2
    }

    /// The paper's geometries are `paper-cone`'s rebinning fan; the
    /// stationary system's has its own source radius, distance and views.
    #[test]
    fn rebinning_fans() {
        let tall = crate::Geometry::builtin("paper-tall").unwrap();
        let p = ConeSystem::builtin("paper-cone").unwrap();
        assert_eq!(p.rebinning_fan(&tall).unwrap(), tall);
        let v = ConeSystem::builtin("siemens-victre").unwrap();
        let f = v.rebinning_fan(&tall).unwrap();
        assert_eq!(
            (f.source_to_center_mm, f.source_to_detector_mm),
            (600.0, 650.0)
        );
        assert_eq!(f.views, v.views);
        assert_eq!(
            (f.detector.clone(), f.image.clone()),
            (tall.detector.clone(), tall.image.clone())
        );
    }
}
