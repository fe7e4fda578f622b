//! The gantry an acquisition comes from, as the site configured it: one
//! description for every input (the frame link and the DICOM input check
//! what they receive against it, and map it into an [`crate::Acquisition`]).

use dbt_dose::xray::AnodeFilter;
use dbt_geometry::{ConeSystem, Geometry};

/// The configured gantry.
#[derive(Debug, Clone, PartialEq)]
pub struct Gantry {
    /// The (fan-beam) reconstruction geometry, the model's (`frames.geometry`,
    /// `binning`).
    pub geometry: Geometry,
    /// The gantry's cone-beam system (`frames.system`): its detector's frames
    /// (rows from the chest wall) are rebinned by the processing. `None`:
    /// each frame row is one coronal slice of `geometry`'s fan beam.
    pub cone: Option<ConeSystem>,
    /// Photons per detector element without the breast, for an input whose
    /// objects do not state it (the DICOM input's For Processing counts:
    /// `[dicom_input] flat_field_counts`, from the system's calibration);
    /// `None` where the input states its own (the frame link's header).
    pub flux: Option<f64>,
    /// Incident air kerma at the reference point per mAs, mGy/mAs: the
    /// site's nominal figure (the processing settles the exposure's own,
    /// [`crate::settle`]).
    pub tube_output_mgy_per_mas: f64,
    /// The beam of an input that does not state its filter: the site's one
    /// beam (`[report] unstated_beam`), or `None` for a site with several:
    /// such an input is refused, naming what is missing, never dosed with a
    /// beam taken for granted.
    pub unstated_beam: Option<AnodeFilter>,
}

impl Gantry {
    /// The slice-wise fan-beam gantry of `geometry`, W/Rh where unstated.
    pub fn fan(geometry: &Geometry, tube_output_mgy_per_mas: f64) -> Self {
        Gantry {
            geometry: geometry.clone(),
            cone: None,
            flux: None,
            tube_output_mgy_per_mas,
            unstated_beam: Some(AnodeFilter::WRh),
        }
    }

    /// Views of the sweep.
    pub fn n_views(&self) -> usize {
        match &self.cone {
            Some(c) => c.n_views(),
            None => self.geometry.n_views(),
        }
    }

    /// Angle of view `v`, degrees.
    pub fn angle_deg(&self, v: usize) -> f64 {
        match &self.cone {
            Some(c) => c.angle_deg(v),
            None => self.geometry.angle_deg(v),
        }
    }

    /// Detector columns and their pitch, mm.
    pub fn columns(&self) -> (usize, f64) {
        match &self.cone {
            Some(c) => (c.detector.columns, c.detector.pitch_mm),
            None => (self.geometry.n_det(), self.geometry.detector.pitch_mm),
        }
    }

    /// Source to detector (at 0 degrees for a cone-beam system: a
    /// stationary detector's distance along the central ray changes with
    /// the view) and source to rotation axis, mm.
    pub fn distances(&self) -> (f64, f64) {
        match &self.cone {
            Some(c) => (c.arc_radius_mm + c.axis_height_mm, c.arc_radius_mm),
            None => (
                self.geometry.source_to_detector_mm,
                self.geometry.source_to_center_mm,
            ),
        }
    }
}
