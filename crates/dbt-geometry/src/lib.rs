//! The one definition of the DBT acquisition geometry, used by the simulator, the
//! trainer (through the exported operator) and the firmware alike.
//!
//! # Coordinate system
//! Each coronal slice is a 2-D fan-beam problem. Coordinates are in millimetres,
//! with the origin at the rotation centre, which is the centre of the image:
//! `x` runs along the image columns (left to right), `z` runs up, towards the
//! source at 0 degrees. Image row 0 is the top row (nearest the source), row
//! `rows - 1` the bottom row on which the breast rests.
//!
//! At view angle `theta` the source sits at `R (sin theta, cos theta)` with `R` the
//! source-to-centre distance; the detector rotates with it: its centre lies on the
//! central ray at distance `D` (source-to-detector) from the source, and detector
//! element `k` sits at lateral position
//! `u_k = (k - (n - 1) / 2) * pitch` along `(cos theta, -sin theta)`.
//! A ray is the full line through the source and an element centre (as in ASTRA's
//! `fanflat` geometries); the line integral is taken over the image.
//!
//! Geometries are validated on construction; every error names the offending
//! field as it is spelled in the TOML file.

use serde::{Deserialize, Serialize};
use thiserror::Error;

pub mod cone;
pub use cone::{ConeSystem, DetectorMotion};

/// The geometry of the paper, as shipped in `geometry/paper.toml`.
pub const PAPER_TOML: &str = include_str!("../geometry/paper.toml");

/// The paper's geometry with an 80 mm image (400 rows), for breasts
/// compressed to 58-78 mm, as shipped in `geometry/paper-tall.toml`.
pub const PAPER_TALL_TOML: &str = include_str!("../geometry/paper-tall.toml");

/// The paper's geometry with a 104 mm image (520 rows), for breasts
/// compressed up to 100 mm (a screening population's thickness range), as
/// shipped in `geometry/paper-104.toml`.
pub const PAPER_104_TOML: &str = include_str!("../geometry/paper-104.toml");

/// The built-in geometries by name, for configuration files and command
/// lines (`Geometry::builtin`).
pub const BUILTIN_GEOMETRIES: [(&str, &str); 3] = [
    ("paper", PAPER_TOML),
    ("paper-tall", PAPER_TALL_TOML),
    ("paper-104", PAPER_104_TOML),
];

/// Errors from parsing or validating a geometry.
#[derive(Debug, Error, PartialEq)]
pub enum GeometryError {
    /// The TOML text could not be parsed or has missing/unknown fields.
    #[error("geometry TOML is malformed: {0}")]
    Parse(String),
    /// A field has an impossible value.
    #[error("invalid geometry field `{field}`: {reason}")]
    Invalid {
        /// The field as spelled in the TOML file, e.g. `detector.pitch_mm`.
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
}

fn invalid(field: &'static str, reason: impl Into<String>) -> GeometryError {
    GeometryError::Invalid {
        field,
        reason: reason.into(),
    }
}

/// Angular sampling: `count` views equally spaced over `[first_deg, last_deg]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Views {
    /// Number of projections (at least 2).
    pub count: usize,
    /// Angle of the first view, degrees.
    pub first_deg: f64,
    /// Angle of the last view, degrees.
    pub last_deg: f64,
}

/// A flat detector of equally spaced elements, centred on the central ray.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Detector {
    /// Number of detector elements.
    pub elements: usize,
    /// Element pitch in mm.
    pub pitch_mm: f64,
}

/// The reconstructed image (one coronal slice): square pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Image {
    /// Number of columns (along x).
    pub columns: usize,
    /// Number of rows (along z; row 0 at the top).
    pub rows: usize,
    /// Pixel side in mm.
    pub pixel_mm: f64,
    /// Height of the image's centre above the rotation centre, mm: 0 (the
    /// paper's layout, and the default) centres the image on the axis; a
    /// gantry whose breast support is not `rows x pixel_mm / 2` below its
    /// rotation axis (Hologic's pivot in the detector plane, GE's axis 18 mm
    /// above the support) rests its image on the support by this offset
    /// (issue #51). Absent from the TOML when 0, so that the paper's
    /// geometries (and their digests) are unchanged.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub centre_z_mm: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// A validated DBT coronal-slice fan-beam geometry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Geometry {
    /// Distance from the source to the rotation centre, mm.
    pub source_to_center_mm: f64,
    /// Distance from the source to the detector, mm.
    pub source_to_detector_mm: f64,
    /// Angular sampling.
    pub views: Views,
    /// Detector.
    pub detector: Detector,
    /// Image grid.
    pub image: Image,
}

/// Where a point of the image plane lands on the detector at one view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectorHit {
    /// Lateral detector coordinate, mm (0 on the central ray).
    pub u_mm: f64,
    /// Distance from the source along the central ray, mm.
    pub depth_mm: f64,
}

impl Geometry {
    /// Parse and validate a geometry from TOML text.
    pub fn from_toml_str(text: &str) -> Result<Self, GeometryError> {
        let g: Geometry = toml::from_str(text).map_err(|e| GeometryError::Parse(e.to_string()))?;
        g.validate()?;
        Ok(g)
    }

    /// Serialise to TOML (round-trips through [`Geometry::from_toml_str`]).
    pub fn to_toml_string(&self) -> String {
        // Serialising plain numbers and strings cannot fail.
        toml::to_string(self).unwrap_or_default()
    }

    /// The paper's full-resolution geometry.
    pub fn paper() -> Self {
        // The embedded file is part of this crate and covered by its tests.
        Self::from_toml_str(PAPER_TOML).expect("embedded paper geometry is valid")
    }

    /// A built-in geometry by name (`paper`, `paper-tall`, `paper-104`), or `None` for
    /// any other name.
    pub fn builtin(name: &str) -> Option<Self> {
        BUILTIN_GEOMETRIES
            .iter()
            .find(|(n, _)| *n == name)
            // The embedded files are part of this crate and covered by its tests.
            .map(|(_, text)| Self::from_toml_str(text).expect("embedded geometry is valid"))
    }

    /// A binned variant: pixels and detector elements `factor` times larger, with
    /// the same field of view. `factor` must divide the image and detector sizes.
    pub fn binned(&self, factor: usize) -> Result<Self, GeometryError> {
        if factor == 0 {
            return Err(invalid("binning", "factor must be at least 1"));
        }
        for (field, n) in [
            ("image.columns", self.image.columns),
            ("image.rows", self.image.rows),
            ("detector.elements", self.detector.elements),
        ] {
            if n % factor != 0 {
                return Err(invalid(
                    field,
                    format!("{n} is not divisible by the binning factor {factor}"),
                ));
            }
        }
        let g = Geometry {
            source_to_center_mm: self.source_to_center_mm,
            source_to_detector_mm: self.source_to_detector_mm,
            views: self.views.clone(),
            detector: Detector {
                elements: self.detector.elements / factor,
                pitch_mm: self.detector.pitch_mm * factor as f64,
            },
            image: Image {
                columns: self.image.columns / factor,
                rows: self.image.rows / factor,
                pixel_mm: self.image.pixel_mm * factor as f64,
                centre_z_mm: self.image.centre_z_mm,
            },
        };
        g.validate()?;
        Ok(g)
    }

    /// Check every constraint; the error names the first offending field.
    pub fn validate(&self) -> Result<(), GeometryError> {
        fn positive(field: &'static str, v: f64) -> Result<(), GeometryError> {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(invalid(
                    field,
                    format!("must be a finite positive number, got {v}"),
                ))
            }
        }
        positive("source_to_center_mm", self.source_to_center_mm)?;
        positive("source_to_detector_mm", self.source_to_detector_mm)?;
        positive("detector.pitch_mm", self.detector.pitch_mm)?;
        positive("image.pixel_mm", self.image.pixel_mm)?;
        if !self.image.centre_z_mm.is_finite() {
            return Err(invalid(
                "image.centre_z_mm",
                format!("must be a finite number, got {}", self.image.centre_z_mm),
            ));
        }
        // The detector may pass through the rotation centre (Hologic's
        // pivot lies in the detector's plane), never nearer the source.
        if self.source_to_detector_mm < self.source_to_center_mm {
            return Err(invalid(
                "source_to_detector_mm",
                format!(
                    "must be at least source_to_center_mm ({} mm), got {} mm",
                    self.source_to_center_mm, self.source_to_detector_mm
                ),
            ));
        }
        if self.views.count < 2 {
            return Err(invalid(
                "views.count",
                format!("at least 2 views are needed, got {}", self.views.count),
            ));
        }
        for (field, a) in [
            ("views.first_deg", self.views.first_deg),
            ("views.last_deg", self.views.last_deg),
        ] {
            if !a.is_finite() || a.abs() >= 80.0 {
                return Err(invalid(
                    field,
                    format!("angle must be finite and within (-80, 80) degrees, got {a}"),
                ));
            }
        }
        if self.views.last_deg <= self.views.first_deg {
            return Err(invalid(
                "views.last_deg",
                format!(
                    "must be greater than views.first_deg ({}), got {}",
                    self.views.first_deg, self.views.last_deg
                ),
            ));
        }
        for (field, n) in [
            ("detector.elements", self.detector.elements),
            ("image.columns", self.image.columns),
            ("image.rows", self.image.rows),
        ] {
            if n == 0 {
                return Err(invalid(field, "must be at least 1"));
            }
            if n > 1 << 20 {
                return Err(invalid(field, format!("{n} is implausibly large")));
            }
        }
        // The source must see the whole image in front of it, and the detector
        // must catch the shadow of the whole image, at every view.
        let half_w = self.detector_width_mm() / 2.0;
        for v in 0..self.views.count {
            for (x, z) in self.image_corners_mm() {
                if self.project_point(v, x, z).depth_mm <= 1e-6 * self.source_to_center_mm {
                    return Err(invalid(
                        "source_to_center_mm",
                        format!(
                            "the source is not outside the image at view {v} ({:.3} deg): image corner ({x}, {z}) mm is not in front of it",
                            self.angle_deg(v)
                        ),
                    ));
                }
            }
        }
        for v in 0..self.views.count {
            for (x, z) in self.image_corners_mm() {
                let hit = self.project_point(v, x, z);
                if hit.u_mm.abs() > half_w * (1.0 + 1e-12) {
                    return Err(invalid(
                        "detector.elements",
                        format!(
                            "the detector ({} x {} mm = {:.3} mm) does not cover the image at view {v} ({:.3} deg): corner ({x}, {z}) mm projects to u = {:.3} mm",
                            self.detector.elements,
                            self.detector.pitch_mm,
                            2.0 * half_w,
                            self.angle_deg(v),
                            hit.u_mm
                        ),
                    ));
                }
            }
            // Every ray must cross the image rows downwards (not run along them).
            for k in [0, self.detector.elements - 1] {
                let (s, p) = self.ray_endpoints_mm(v, k);
                let dz = p.1 - s.1;
                let dx = p.0 - s.0;
                if dz >= 0.0 || dx.abs() > 20.0 * dz.abs() {
                    return Err(invalid(
                        "views",
                        format!(
                            "ray of element {k} at view {v} ({:.3} deg) does not cross the image rows downwards",
                            self.angle_deg(v)
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// Number of views.
    pub fn n_views(&self) -> usize {
        self.views.count
    }
    /// Number of detector elements.
    pub fn n_det(&self) -> usize {
        self.detector.elements
    }
    /// Number of image columns.
    pub fn nx(&self) -> usize {
        self.image.columns
    }
    /// Number of image rows.
    pub fn nz(&self) -> usize {
        self.image.rows
    }
    /// Number of image pixels.
    pub fn n_pixels(&self) -> usize {
        self.nx() * self.nz()
    }
    /// Number of sinogram samples (views x detector elements).
    pub fn n_rays(&self) -> usize {
        self.n_views() * self.n_det()
    }
    /// Image width in mm.
    pub fn width_mm(&self) -> f64 {
        self.image.columns as f64 * self.image.pixel_mm
    }
    /// Image height in mm.
    pub fn height_mm(&self) -> f64 {
        self.image.rows as f64 * self.image.pixel_mm
    }
    /// Detector width in mm.
    pub fn detector_width_mm(&self) -> f64 {
        self.detector.elements as f64 * self.detector.pitch_mm
    }

    /// Angle of view `v` in degrees.
    pub fn angle_deg(&self, v: usize) -> f64 {
        let n = self.views.count as f64;
        let step = (self.views.last_deg - self.views.first_deg) / (n - 1.0);
        self.views.first_deg + step * v as f64
    }
    /// Angle of view `v` in radians.
    pub fn angle_rad(&self, v: usize) -> f64 {
        self.angle_deg(v).to_radians()
    }

    /// Lateral position of detector element `k` (its centre), mm.
    pub fn element_u_mm(&self, k: usize) -> f64 {
        (k as f64 - (self.detector.elements as f64 - 1.0) / 2.0) * self.detector.pitch_mm
    }

    /// Source position `(x, z)` in mm at view `v`.
    pub fn source_mm(&self, v: usize) -> (f64, f64) {
        let t = self.angle_rad(v);
        let r = self.source_to_center_mm;
        (r * t.sin(), r * t.cos())
    }

    /// The point `(x, z)` in mm at lateral detector coordinate `u_mm` (0 on
    /// the central ray) at view `v`: element centres, their edges, any
    /// position along the detector.
    pub fn detector_point_mm(&self, v: usize, u_mm: f64) -> (f64, f64) {
        let (s, c) = self.angle_rad(v).sin_cos();
        let off = self.source_to_center_mm - self.source_to_detector_mm;
        (off * s + u_mm * c, off * c - u_mm * s)
    }

    /// Source and detector-element centre `(x, z)` in mm defining ray `(v, k)`.
    pub fn ray_endpoints_mm(&self, v: usize, k: usize) -> ((f64, f64), (f64, f64)) {
        (
            self.source_mm(v),
            self.detector_point_mm(v, self.element_u_mm(k)),
        )
    }

    /// Project an image-plane point onto the detector at view `v`.
    pub fn project_point(&self, v: usize, x: f64, z: f64) -> DetectorHit {
        let t = self.angle_rad(v);
        let (s, c) = t.sin_cos();
        let (sx, sz) = self.source_mm(v);
        let (px, pz) = (x - sx, z - sz);
        let depth = -(px * s + pz * c);
        let lateral = px * c - pz * s;
        DetectorHit {
            u_mm: lateral * self.source_to_detector_mm / depth,
            depth_mm: depth,
        }
    }

    /// The four image corners `(x, z)` in mm.
    pub fn image_corners_mm(&self) -> [(f64, f64); 4] {
        let (hw, lo, hi) = (self.width_mm() / 2.0, self.support_z_mm(), self.top_z_mm());
        [(-hw, lo), (-hw, hi), (hw, lo), (hw, hi)]
    }

    /// Centre `(x, z)` in mm of pixel `(row, col)`.
    pub fn pixel_center_mm(&self, row: usize, col: usize) -> (f64, f64) {
        let p = self.image.pixel_mm;
        (
            -self.width_mm() / 2.0 + (col as f64 + 0.5) * p,
            self.top_z_mm() - (row as f64 + 0.5) * p,
        )
    }

    /// z coordinate (mm) of the breast support: the bottom edge of the image.
    pub fn support_z_mm(&self) -> f64 {
        self.image.centre_z_mm - self.height_mm() / 2.0
    }

    /// z coordinate (mm) of the image's top edge (row 0's upper side).
    pub fn top_z_mm(&self) -> f64 {
        self.image.centre_z_mm + self.height_mm() / 2.0
    }

    /// Number of image rows, counted from the bottom, whose pixel centres lie
    /// inside a compressed breast of the given thickness resting on the support.
    pub fn rows_within_thickness(&self, thickness_mm: f64) -> usize {
        let r = (thickness_mm / self.image.pixel_mm + 0.5).floor();
        if r.is_nan() || r <= 0.0 {
            0
        } else {
            (r as usize).min(self.image.rows)
        }
    }

    /// A short human-readable description, e.g. for benchmark tables.
    pub fn describe(&self) -> String {
        let raised = if self.image.centre_z_mm != 0.0 {
            format!(
                ", the image centred {} mm above the axis (source {} / {} mm)",
                self.image.centre_z_mm, self.source_to_center_mm, self.source_to_detector_mm
            )
        } else {
            String::new()
        };
        format!(
            "{}x{} px of {} mm, {} views over [{}, {}] deg, {} elements of {} mm{raised}",
            self.image.columns,
            self.image.rows,
            self.image.pixel_mm,
            self.views.count,
            self.views.first_deg,
            self.views.last_deg,
            self.detector.elements,
            self.detector.pitch_mm
        )
    }
}

/// Length (mm) of the part of the line through `s` and `p` inside the
/// axis-aligned rectangle `[x0, x1] x [z0, z1]` (slab method): the closed-form
/// line integral of a uniform rectangle per unit attenuation.
pub fn chord_in_rect(s: (f64, f64), p: (f64, f64), x0: f64, x1: f64, z0: f64, z1: f64) -> f64 {
    let d = (p.0 - s.0, p.1 - s.1);
    let n = (d.0 * d.0 + d.1 * d.1).sqrt();
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    for (o, dd, lo, hi) in [(s.0, d.0, x0, x1), (s.1, d.1, z0, z1)] {
        if dd.abs() < 1e-300 {
            if o < lo || o > hi {
                return 0.0;
            }
        } else {
            let (a, b) = ((lo - o) / dd, (hi - o) / dd);
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
    }
    (t1 - t0).max(0.0) * n
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The 104 mm variant (issue #26's screening thicknesses up to 100 mm)
    /// is the paper's geometry with 520 rows: valid (the detector still
    /// catches the whole image's shadow at every view), binnable, the same
    /// rays.
    #[test]
    fn the_104_mm_variant_is_the_paper_geometry_520_rows_high() {
        let t = Geometry::builtin("paper-104").unwrap();
        let p = Geometry::paper();
        assert_eq!(t.image.rows, 520);
        assert!((t.height_mm() - 104.0).abs() < 1e-9);
        let mut same = t.clone();
        same.image.rows = p.image.rows;
        assert_eq!(same, p);
        let b = t.binned(4).unwrap();
        assert_eq!((b.image.rows, b.image.columns, b.n_det()), (130, 250, 320));
        // Row centres at (k + 0.5) 0.8 mm <= 100 mm: k = 0..=124.
        assert_eq!(b.rows_within_thickness(100.0), 125);
    }

    /// The taller variant (issue #7's 58-75 mm breasts) is the paper's
    /// geometry with an 80 mm image: valid, binnable, the same rays.
    #[test]
    fn the_tall_variant_is_the_paper_geometry_80_mm_high() {
        let t = Geometry::builtin("paper-tall").unwrap();
        let p = Geometry::paper();
        assert_eq!(Geometry::builtin("paper"), Some(p.clone()));
        assert_eq!(Geometry::builtin("paper-tal"), None);
        assert_eq!(t.image.rows, 400);
        assert!((t.height_mm() - 80.0).abs() < 1e-9);
        let mut same = t.clone();
        same.image.rows = p.image.rows;
        assert_eq!(same, p);
        let b = t.binned(4).unwrap();
        assert_eq!((b.image.rows, b.image.columns, b.n_det()), (100, 250, 320));
        // Row centres at (k + 0.5) 0.8 mm <= 75 mm: k = 0..=93.
        assert_eq!(b.rows_within_thickness(75.0), 94);
    }

    fn field_of(e: GeometryError) -> &'static str {
        match e {
            GeometryError::Invalid { field, .. } => field,
            GeometryError::Parse(m) => panic!("expected a validation error, got parse error {m}"),
        }
    }

    fn with(f: impl FnOnce(&mut Geometry)) -> Result<Geometry, GeometryError> {
        let mut g = Geometry::paper();
        f(&mut g);
        g.validate().map(|_| g)
    }

    #[test]
    fn paper_geometry_matches_the_paper() {
        let g = Geometry::paper();
        assert_eq!(g.n_views(), 25);
        assert_eq!(g.n_det(), 1280);
        assert_eq!((g.nx(), g.nz()), (1000, 300));
        assert!((g.angle_deg(0) + 24.0).abs() < 1e-12);
        assert!((g.angle_deg(12)).abs() < 1e-12);
        assert!((g.angle_deg(24) - 24.0).abs() < 1e-12);
        // 2-degree steps.
        assert!((g.angle_deg(1) - g.angle_deg(0) - 2.0).abs() < 1e-12);
        // Central ray at 0 deg hits the detector 50 mm below the centre.
        let (s, p) = g.ray_endpoints_mm(12, 639);
        assert!((s.1 - 650.0).abs() < 1e-9);
        assert!((p.1 + 50.0).abs() < 1e-9);
        assert!(
            (p.0 + 0.1).abs() < 1e-9,
            "element 639 centre is half a pitch left"
        );
        // The breast support is the bottom of the 60 mm image.
        assert!((g.support_z_mm() + 30.0).abs() < 1e-12);
    }

    #[test]
    fn toml_round_trip() {
        let g = Geometry::paper();
        let back = Geometry::from_toml_str(&g.to_toml_string()).unwrap();
        assert_eq!(g, back);
    }

    #[test]
    fn binned_variants_are_derived() {
        let g = Geometry::paper();
        let b4 = g.binned(4).unwrap();
        assert_eq!((b4.nx(), b4.nz(), b4.n_det()), (250, 75, 320));
        assert!((b4.image.pixel_mm - 0.8).abs() < 1e-12);
        assert!((b4.detector.pitch_mm - 0.8).abs() < 1e-12);
        assert_eq!(b4.width_mm(), g.width_mm());
        let b2 = g.binned(2).unwrap();
        assert_eq!((b2.nx(), b2.nz(), b2.n_det()), (500, 150, 640));
        assert_eq!(field_of(g.binned(0).unwrap_err()), "binning");
        assert_eq!(field_of(g.binned(3).unwrap_err()), "image.columns");
    }

    #[test]
    fn impossible_geometries_name_the_field() {
        type Mutation = Box<dyn FnOnce(&mut Geometry)>;
        let cases: Vec<(&str, Mutation)> = vec![
            ("detector.pitch_mm", Box::new(|g| g.detector.pitch_mm = 0.0)),
            (
                "detector.pitch_mm",
                Box::new(|g| g.detector.pitch_mm = f64::NAN),
            ),
            ("image.pixel_mm", Box::new(|g| g.image.pixel_mm = -0.2)),
            (
                "source_to_center_mm",
                Box::new(|g| g.source_to_center_mm = 0.0),
            ),
            (
                "source_to_detector_mm",
                Box::new(|g| g.source_to_detector_mm = 600.0),
            ),
            ("views.count", Box::new(|g| g.views.count = 1)),
            ("views.last_deg", Box::new(|g| g.views.last_deg = -30.0)),
            ("views.first_deg", Box::new(|g| g.views.first_deg = -95.0)),
            ("image.columns", Box::new(|g| g.image.columns = 0)),
            ("image.rows", Box::new(|g| g.image.rows = 0)),
            ("detector.elements", Box::new(|g| g.detector.elements = 0)),
            // 1000 elements of 0.2 mm (200 mm) cannot catch a 200 mm wide image
            // magnified by the fan.
            (
                "detector.elements",
                Box::new(|g| g.detector.elements = 1000),
            ),
            // Source inside the image.
            (
                "source_to_center_mm",
                Box::new(|g| {
                    g.source_to_center_mm = 20.0;
                    g.source_to_detector_mm = 700.0;
                }),
            ),
        ];
        for (field, f) in cases {
            let err = with(f).unwrap_err();
            assert_eq!(field_of(err), field);
        }
    }

    #[test]
    fn malformed_toml_is_a_parse_error() {
        assert!(matches!(
            Geometry::from_toml_str("source_to_center_mm = 650.0"),
            Err(GeometryError::Parse(_))
        ));
        let unknown = PAPER_TOML.replace("pitch_mm = 0.2", "pitch_mm = 0.2\ncolour = 3");
        let e = Geometry::from_toml_str(&unknown).unwrap_err();
        assert!(e.to_string().contains("colour"), "{e}");
        let bad = PAPER_TOML.replace("count = 25", "count = 1");
        assert_eq!(
            field_of(Geometry::from_toml_str(&bad).unwrap_err()),
            "views.count"
        );
    }

    /// A raised image rests where asked (rays are whole lines: an image may
    /// reach through the detector's plane, as paper-104's does by 2 mm); a
    /// centre that is not a number is refused naming the field.
    #[test]
    fn a_raised_image_moves_with_its_centre() {
        let mut g = Geometry::paper();
        g.image.centre_z_mm = 20.0;
        g.validate().unwrap();
        assert!(g
            .describe()
            .ends_with("the image centred 20 mm above the axis (source 650 / 700 mm)"));
        assert!(!Geometry::paper().describe().contains("above the axis"));
        assert!((g.support_z_mm() + 10.0).abs() < 1e-12);
        assert!((g.top_z_mm() - 50.0).abs() < 1e-12);
        assert!((g.pixel_center_mm(299, 0).1 - (-10.0 + 0.1)).abs() < 1e-9);
        g.image.centre_z_mm = f64::NAN;
        assert!(g
            .validate()
            .unwrap_err()
            .to_string()
            .contains("image.centre_z_mm"));
    }

    #[test]
    fn projection_of_the_centre_is_the_central_ray() {
        let g = Geometry::paper();
        for v in 0..g.n_views() {
            let hit = g.project_point(v, 0.0, 0.0);
            assert!(hit.u_mm.abs() < 1e-9);
            assert!((hit.depth_mm - 650.0).abs() < 1e-9);
        }
    }

    #[test]
    fn chord_in_rect_closed_forms() {
        // Vertical line through a 60 mm tall box.
        assert!(
            (chord_in_rect((0.0, 100.0), (0.0, -100.0), -80.0, 80.0, -30.0, 30.0) - 60.0).abs()
                < 1e-12
        );
        // 45-degree diagonal through a unit square from corner to corner.
        let c = chord_in_rect((-1.0, -1.0), (2.0, 2.0), 0.0, 1.0, 0.0, 1.0);
        assert!((c - 2f64.sqrt()).abs() < 1e-12);
        // A line that misses, and one parallel to an edge outside it.
        assert_eq!(
            chord_in_rect((5.0, 0.0), (6.0, 1.0), 0.0, 1.0, 0.0, 1.0),
            0.0
        );
        assert_eq!(
            chord_in_rect((2.0, -5.0), (2.0, 5.0), 0.0, 1.0, 0.0, 1.0),
            0.0
        );
    }

    #[test]
    fn thickness_rows() {
        let g = Geometry::paper();
        assert_eq!(g.rows_within_thickness(50.0), 250);
        assert_eq!(g.rows_within_thickness(0.0), 0);
        assert_eq!(g.rows_within_thickness(1000.0), 300);
        assert_eq!(g.rows_within_thickness(f64::NAN), 0);
    }
}
