//! A received Breast Projection X-Ray For Processing object as an
//! acquisition (issue #31, the DICOM input): the object's technique,
//! thickness and identity; the configured system's geometry, flat field and
//! tube output, which the object must agree with. Everything the pipeline
//! reads is then checked again by [`validate_header`].

use crate::acquisition::{
    validate_header, Acquisition, AcquisitionHeader, HeaderError, Patient, Study, ACQ_FORMAT,
};
use dbt_dicom::projections::{ProjectionSet, ReceivedProjections};
use dbt_dicom::Laterality;
use dbt_geometry::Geometry;

/// The configured system the objects must come from.
#[derive(Debug, Clone)]
pub struct System {
    /// The gantry's geometry, as configured (`frames.geometry`, `binning`).
    pub geometry: Geometry,
    /// Photons per detector element without the breast (the flat field the
    /// For Processing counts are relative to), from the system's calibration.
    pub flux: f64,
    /// Incident air kerma at the reference point per mAs, mGy/mAs.
    pub tube_output_mgy_per_mas: f64,
}

/// Angles and distances of an object may differ from the configuration's by
/// this much (rounding in DS/FD encodings; a real mismatch is degrees and
/// centimetres).
const ANGLE_TOL_DEG: f64 = 0.01;
/// See [`ANGLE_TOL_DEG`], mm.
const DISTANCE_TOL_MM: f64 = 0.5;
/// Relative tolerance of the pixel spacing.
const SPACING_TOL: f64 = 1e-3;

fn refuse(field: &'static str, value: impl ToString, reason: impl Into<String>) -> HeaderError {
    HeaderError {
        field,
        value: value.to_string(),
        reason: reason.into(),
    }
}

/// The acquisition of `p` on `system`, refused naming the attribute where
/// the object disagrees with the configured system (views, angles,
/// distances, detector columns and pitch) or with the header's limits.
pub fn acquisition_from_projections(
    p: &ReceivedProjections,
    system: &System,
) -> Result<Acquisition, HeaderError> {
    let g = &system.geometry;
    let (views, det) = (g.n_views(), g.n_det());
    if p.angles_deg.len() != views {
        return Err(refuse(
            "NumberOfFrames",
            p.angles_deg.len(),
            format!("the configured gantry has {views} views"),
        ));
    }
    for (v, a) in p.angles_deg.iter().enumerate() {
        if (a - g.angle_deg(v)).abs() > ANGLE_TOL_DEG {
            return Err(refuse(
                "XRaySourceIsocenterPrimaryAngle",
                format!("{a} (frame {})", v + 1),
                format!("the configured view {} is at {} deg", v + 1, g.angle_deg(v)),
            ));
        }
    }
    if p.columns != det {
        return Err(refuse(
            "Columns",
            p.columns,
            format!("the configured detector has {det} elements"),
        ));
    }
    if (p.pixel_spacing_mm[1] / g.detector.pitch_mm - 1.0).abs() > SPACING_TOL {
        return Err(refuse(
            "ImagerPixelSpacing",
            p.pixel_spacing_mm[1],
            format!("the configured element pitch is {} mm", g.detector.pitch_mm),
        ));
    }
    for (field, got, want) in [
        (
            "DistanceSourceToDetector",
            p.source_to_detector_mm,
            g.source_to_detector_mm,
        ),
        (
            "DistanceSourceToIsocenter",
            p.source_to_isocenter_mm,
            g.source_to_center_mm,
        ),
    ] {
        if (got - want).abs() > DISTANCE_TOL_MM {
            return Err(refuse(
                field,
                got,
                format!("the configured gantry's is {want} mm"),
            ));
        }
    }
    // Frames are views of (rows = coronal slices) x (columns = elements).
    let (rows, frame) = (p.rows, p.rows * p.columns);
    let counts: Vec<Vec<f32>> = (0..rows)
        .map(|s| {
            (0..views)
                .flat_map(|v| {
                    let at = v * frame + s * det;
                    p.counts[at..at + det].iter().map(|&c| f32::from(c))
                })
                .collect()
        })
        .collect();
    let h = &p.header;
    let header = AcquisitionHeader {
        format: ACQ_FORMAT.into(),
        geometry: g.clone(),
        thickness_mm: p.thickness_mm,
        flux: system.flux,
        slices: rows,
        slice_spacing_mm: p.pixel_spacing_mm[0],
        kvp: p.kvp,
        mas_total: p.exposure_mas,
        tube_output_mgy_per_mas: system.tube_output_mgy_per_mas,
        laterality: match h.laterality {
            Laterality::Left => "L",
            Laterality::Right => "R",
        }
        .into(),
        patient: Patient {
            name: h.patient_name.clone(),
            id: h.patient_id.clone(),
            birth_date: h.patient_birth_date.clone(),
            sex: h.patient_sex.clone(),
        },
        study: Study {
            study_uid: h.study_uid.clone(),
            date: h.study_date.clone(),
            time: h.study_time.clone(),
            accession: h.accession_number.clone(),
            study_id: h.study_id.clone(),
            series_uid: h.source_series_uid.clone(),
            instance_uids: h.source_instance_uids.clone(),
        },
        truth: None,
    };
    validate_header(&header)?;
    Ok(Acquisition { header, counts })
}

/// What a modality knows of its sweep beyond the acquisition file.
#[derive(Debug, Clone, Copy)]
pub struct Sweep<'a> {
    /// Compression force, N.
    pub compression_force_n: f64,
    /// Exposure time of each view, ms.
    pub exposure_ms_per_view: f64,
    /// Time between views' starts, ms.
    pub view_interval_ms: f64,
    /// The modality's own dose estimate of the sweep, mGy.
    pub modality_agd_mgy: f64,
    /// Rhodium filter, mm.
    pub filter_rh_mm: f64,
    /// Content date and time.
    pub content_date: &'a str,
    /// See `content_date`.
    pub content_time: &'a str,
}

/// The frames of `acq` for its projection object: view by view, detector
/// rows = coronal slices, columns = elements; refused where a count does
/// not fit 16 bits.
pub fn frames_of(acq: &Acquisition) -> Result<Vec<u16>, HeaderError> {
    let g = &acq.header.geometry;
    let (views, det) = (g.n_views(), g.n_det());
    let mut out = Vec::with_capacity(views * acq.counts.len() * det);
    for v in 0..views {
        for (s, slice) in acq.counts.iter().enumerate() {
            let row = slice
                .get(v * det..(v + 1) * det)
                .ok_or_else(|| refuse("counts", s, format!("slice {s} has no view {v}")))?;
            for (e, c) in row.iter().enumerate() {
                let c = c.round();
                if !(0.0..=65535.0).contains(&c) {
                    return Err(refuse(
                        "counts",
                        c,
                        format!("view {v}, slice {s}, element {e} does not fit 16 bits"),
                    ));
                }
                out.push(c as u16);
            }
        }
    }
    Ok(out)
}

/// The projection object's content for `acq` (the inverse of
/// [`acquisition_from_projections`]), with its frames (`frames_of`) and the
/// views' angles given.
pub fn projection_set<'a>(
    acq: &'a Acquisition,
    header: &'a dbt_dicom::Header,
    equipment: &'a dbt_dicom::Equipment,
    angles_deg: &'a [f64],
    counts: &'a [u16],
    sweep: Sweep<'a>,
) -> ProjectionSet<'a> {
    let h = &acq.header;
    let g = &h.geometry;
    let views = g.n_views();
    ProjectionSet {
        header,
        equipment,
        rows: h.slices,
        columns: g.n_det(),
        pixel_spacing_mm: [h.slice_spacing_mm, g.detector.pitch_mm],
        angles_deg,
        source_to_detector_mm: g.source_to_detector_mm,
        source_to_isocenter_mm: g.source_to_center_mm,
        thickness_mm: h.thickness_mm,
        compression_force_n: sweep.compression_force_n,
        support_to_detector_mm: 0.0,
        exposure_ms_per_view: sweep.exposure_ms_per_view,
        view_interval_ms: sweep.view_interval_ms,
        modality_agd_mgy: sweep.modality_agd_mgy,
        entrance_dose_mgy: h.mas_total * h.tube_output_mgy_per_mas,
        kvp: h.kvp,
        exposure_uas_per_view: h.mas_total * 1000.0 / views as f64,
        filter_rh_mm: sweep.filter_rh_mm,
        counts,
        content_date: sweep.content_date,
        content_time: sweep.content_time,
    }
}
