//! A DBT acquisition as one Breast Projection X-Ray Image - For Processing
//! object (multi-frame, one frame per view), as a modality sends it to a
//! density or dose server (issue #31): what `host-sim dicom-send` writes and
//! what the DICOM input of the daemon is tested with.
//!
//! Frames hold the raw detector counts (16 bits, unsigned, linear in the
//! exposure); the geometry is in the per-frame X-Ray Geometry and Positioner
//! functional groups, the technique in the shared X-Ray Exposure Control
//! Sensing Regions / Acquisition Dose / Generation / Filtration ones.

use crate::reports::{Equipment, Header, Report};
use crate::{DicomError, UidSource};
use dicom_core::value::PrimitiveValue;
use dicom_core::{DataElement, VR};
use dicom_dictionary_std::tags;
use dicom_object::InMemDicomObject;

/// Breast Projection X-Ray Image Storage - For Processing.
pub const BPXR_FOR_PROCESSING_CLASS: &str = crate::reports::BREAST_PROJECTION_FOR_PROCESSING_CLASS;

/// What the object says about one acquisition.
#[derive(Debug, Clone)]
pub struct ProjectionSet<'a> {
    /// Patient, study (and the series/instance UIDs are made here).
    pub header: &'a Header,
    /// The acquiring device.
    pub equipment: &'a Equipment,
    /// Detector rows and columns of each frame.
    pub rows: usize,
    /// See `rows`.
    pub columns: usize,
    /// Imager pixel spacing: between rows, between columns, mm.
    pub pixel_spacing_mm: [f64; 2],
    /// The view angles, degrees (primary positioner angle), one per frame.
    pub angles_deg: &'a [f64],
    /// Source to detector and source to isocentre distances, mm.
    pub source_to_detector_mm: f64,
    /// See `source_to_detector_mm`.
    pub source_to_isocenter_mm: f64,
    /// Compressed breast thickness, mm.
    pub thickness_mm: f64,
    /// Compression force, N.
    pub compression_force_n: f64,
    /// Distance from the breast support (its upper surface) down to the
    /// detector's input surface, mm.
    pub support_to_detector_mm: f64,
    /// Exposure time of each view, ms.
    pub exposure_ms_per_view: f64,
    /// Time between the starts of consecutive views, ms.
    pub view_interval_ms: f64,
    /// The modality's own estimate of the average glandular dose of the
    /// sweep, mGy (Organ Dose is in dGy).
    pub modality_agd_mgy: f64,
    /// Incident air kerma of the sweep at the entrance surface, mGy.
    pub entrance_dose_mgy: f64,
    /// Tube voltage, kV.
    pub kvp: f64,
    /// Tube loading of each view, uAs.
    pub exposure_uas_per_view: f64,
    /// Anode target material.
    pub anode_material: crate::AnodeMaterial,
    /// Filter material.
    pub filter_material: crate::FilterMaterial,
    /// Filter thickness, mm.
    pub filter_mm: f64,
    /// Counts, frame by frame, row-major (`frames x rows x columns`).
    pub counts: &'a [u16],
    /// Content date and time (`YYYYMMDD`, `HHMMSS`).
    pub content_date: &'a str,
    /// See `content_date`.
    pub content_time: &'a str,
}

pub(crate) fn bad(field: &'static str, reason: String) -> DicomError {
    DicomError::Field { field, reason }
}

pub(crate) fn ds(v: f64) -> String {
    crate::format_ds(v)
}

fn item(elems: Vec<DataElement<InMemDicomObject>>) -> InMemDicomObject {
    InMemDicomObject::from_element_iter(elems)
}

pub(crate) fn sq(items: Vec<InMemDicomObject>) -> dicom_core::value::Value<InMemDicomObject> {
    dicom_core::value::DataSetSequence::from(items).into()
}

pub(crate) fn code(v: &str, s: &str, m: &str) -> InMemDicomObject {
    item(vec![
        DataElement::new(tags::CODE_VALUE, VR::SH, v),
        DataElement::new(tags::CODING_SCHEME_DESIGNATOR, VR::SH, s),
        DataElement::new(tags::CODE_MEANING, VR::LO, m),
    ])
}

/// The checks of a projection set before any object is written: a frame
/// per angle, counts of the announced size, physical values in range.
pub(crate) fn check(p: &ProjectionSet<'_>) -> Result<(), DicomError> {
    let frames = p.angles_deg.len();
    if frames == 0 {
        return Err(bad("angles_deg", "no view".into()));
    }
    let want = frames * p.rows * p.columns;
    if p.rows == 0 || p.columns == 0 || p.rows > 8192 || p.columns > 8192 {
        return Err(bad(
            "rows",
            format!("{} x {} is not a detector size", p.rows, p.columns),
        ));
    }
    if p.counts.len() != want {
        return Err(bad(
            "counts",
            format!(
                "{} values for {frames} frames of {} x {} ({want})",
                p.counts.len(),
                p.rows,
                p.columns
            ),
        ));
    }
    for (field, v, lo, hi) in [
        ("thickness_mm", p.thickness_mm, 1.0, 200.0),
        ("kvp", p.kvp, 10.0, 60.0),
        ("exposure_uas_per_view", p.exposure_uas_per_view, 1.0, 1e6),
        (
            "source_to_detector_mm",
            p.source_to_detector_mm,
            100.0,
            2000.0,
        ),
        (
            "source_to_isocenter_mm",
            p.source_to_isocenter_mm,
            100.0,
            2000.0,
        ),
        ("pixel_spacing_mm[0]", p.pixel_spacing_mm[0], 0.01, 10.0),
        ("pixel_spacing_mm[1]", p.pixel_spacing_mm[1], 0.01, 10.0),
        ("filter_mm", p.filter_mm, 0.0, 1.0),
        ("compression_force_n", p.compression_force_n, 0.0, 500.0),
        (
            "support_to_detector_mm",
            p.support_to_detector_mm,
            0.0,
            100.0,
        ),
        (
            "exposure_ms_per_view",
            p.exposure_ms_per_view,
            0.1,
            10_000.0,
        ),
        (
            "view_interval_ms",
            p.view_interval_ms,
            p.exposure_ms_per_view,
            60_000.0,
        ),
        ("modality_agd_mgy", p.modality_agd_mgy, 0.0, 1000.0),
        ("entrance_dose_mgy", p.entrance_dose_mgy, 0.0, 1000.0),
    ] {
        if !(v.is_finite() && (lo..=hi).contains(&v)) {
            return Err(bad(field, format!("{v} is outside [{lo}, {hi}]")));
        }
    }
    Ok(())
}

/// The attributes a projection object of either class states alike:
/// patient, study, equipment, technique and the fixed values of a raw
/// For Processing mammography image.
pub(crate) fn common_elements(p: &ProjectionSet<'_>) -> Vec<DataElement<InMemDicomObject>> {
    let h = p.header;
    let s = |t, vr, v: &str| DataElement::new(t, vr, v.to_string());
    vec![
        s(tags::SPECIFIC_CHARACTER_SET, VR::CS, "ISO_IR 192"),
        s(tags::STUDY_DATE, VR::DA, &h.study_date),
        s(tags::STUDY_TIME, VR::TM, &h.study_time),
        s(tags::CONTENT_DATE, VR::DA, p.content_date),
        s(tags::CONTENT_TIME, VR::TM, p.content_time),
        s(tags::ACCESSION_NUMBER, VR::SH, &h.accession_number),
        s(tags::MODALITY, VR::CS, "MG"),
        s(tags::MANUFACTURER, VR::LO, &p.equipment.manufacturer),
        s(tags::INSTITUTION_NAME, VR::LO, ""),
        s(
            tags::REFERRING_PHYSICIAN_NAME,
            VR::PN,
            &h.referring_physician,
        ),
        s(tags::MANUFACTURER_MODEL_NAME, VR::LO, &p.equipment.model),
        s(tags::PATIENT_NAME, VR::PN, &h.patient_name),
        s(tags::PATIENT_ID, VR::LO, &h.patient_id),
        s(tags::PATIENT_BIRTH_DATE, VR::DA, &h.patient_birth_date),
        s(tags::PATIENT_SEX, VR::CS, &h.patient_sex),
        s(tags::DEVICE_SERIAL_NUMBER, VR::LO, &p.equipment.serial),
        s(
            tags::SOFTWARE_VERSIONS,
            VR::LO,
            &p.equipment.software_version,
        ),
        s(tags::BODY_PART_THICKNESS, VR::DS, &ds(p.thickness_mm)),
        s(tags::KVP, VR::DS, &ds(p.kvp)),
        s(tags::STUDY_INSTANCE_UID, VR::UI, &h.study_uid),
        s(tags::STUDY_ID, VR::SH, &h.study_id),
        s(tags::FOCAL_SPOTS, VR::DS, "0.3"),
        s(tags::ANODE_TARGET_MATERIAL, VR::CS, p.anode_material.term()),
        s(tags::COMPRESSION_FORCE, VR::DS, &ds(p.compression_force_n)),
        s(tags::PADDLE_DESCRIPTION, VR::LO, "flat compression paddle"),
        s(tags::BREAST_IMPLANT_PRESENT, VR::CS, "NO"),
        s(tags::POSITIONER_TYPE, VR::CS, "MAMMOGRAPHIC"),
        s(tags::QUALITY_CONTROL_IMAGE, VR::CS, "NO"),
        s(tags::BURNED_IN_ANNOTATION, VR::CS, "NO"),
        s(tags::LOSSY_IMAGE_COMPRESSION, VR::CS, "00"),
        s(tags::PRESENTATION_INTENT_TYPE, VR::CS, "FOR PROCESSING"),
        s(tags::PHOTOMETRIC_INTERPRETATION, VR::CS, "MONOCHROME2"),
        s(tags::DETECTOR_TYPE, VR::CS, "DIRECT"),
        s(tags::PRESENTATION_LUT_SHAPE, VR::CS, "IDENTITY"),
        s(tags::POSITION_REFERENCE_INDICATOR, VR::LO, ""),
        s(tags::SERIES_NUMBER, VR::IS, "1"),
    ]
}

/// The beam's filter: Filter Material and its thickness (minimum =
/// maximum), at the DM object's top level and in the multi-frame object's
/// X-Ray Filter Macro alike.
pub(crate) fn filter_elements(p: &ProjectionSet<'_>) -> [DataElement<InMemDicomObject>; 3] {
    [
        DataElement::new(tags::FILTER_MATERIAL, VR::CS, p.filter_material.term()),
        DataElement::new(tags::FILTER_THICKNESS_MINIMUM, VR::DS, ds(p.filter_mm)),
        DataElement::new(tags::FILTER_THICKNESS_MAXIMUM, VR::DS, ds(p.filter_mm)),
    ]
}

/// One view's share of the modality's dose estimates: Organ Dose (dGy) and
/// Entrance Dose (mGy), the sweep's divided equally over its views.
pub(crate) fn view_dose_elements(p: &ProjectionSet<'_>) -> [DataElement<InMemDicomObject>; 2] {
    let frames = p.angles_deg.len().max(1) as f64;
    [
        DataElement::new(
            tags::ORGAN_DOSE,
            VR::DS,
            ds(p.modality_agd_mgy / 100.0 / frames),
        ),
        DataElement::new(
            tags::ENTRANCE_DOSE_INM_GY,
            VR::DS,
            ds(p.entrance_dose_mgy / frames),
        ),
    ]
}

/// Source to detector and to the breast's upper surface, and the
/// magnification at the breast support: the X-Ray geometry both classes
/// state.
pub(crate) fn distance_elements(p: &ProjectionSet<'_>) -> Vec<DataElement<InMemDicomObject>> {
    let s = |t, v: f64| DataElement::new(t, VR::DS, ds(v));
    vec![
        s(tags::DISTANCE_SOURCE_TO_DETECTOR, p.source_to_detector_mm),
        s(
            tags::DISTANCE_SOURCE_TO_PATIENT,
            p.source_to_detector_mm - p.thickness_mm,
        ),
        s(
            tags::ESTIMATED_RADIOGRAPHIC_MAGNIFICATION_FACTOR,
            p.source_to_detector_mm / (p.source_to_detector_mm - p.thickness_mm.max(1.0)),
        ),
    ]
}

/// The object, checked: a frame per angle, counts of the announced size,
/// physical values in range. UIDs (series, instance, frame of reference)
/// from `uids`.
pub fn projection_object(
    p: &ProjectionSet<'_>,
    uids: &mut UidSource,
) -> Result<Report, DicomError> {
    check(p)?;
    let frames = p.angles_deg.len();
    let h = p.header;
    let sop_instance = uids.next_uid();
    let series = uids.next_uid();
    let frame_of_reference = uids.next_uid();
    let lat = h.laterality.letter();
    let s = |t, vr, v: &str| DataElement::new(t, vr, v.to_string());
    let mut o = InMemDicomObject::new_empty();
    for e in common_elements(p) {
        o.put(e);
    }
    for e in [
        s(tags::SOP_CLASS_UID, VR::UI, BPXR_FOR_PROCESSING_CLASS),
        s(tags::SOP_INSTANCE_UID, VR::UI, &sop_instance),
        s(
            tags::IMAGE_TYPE,
            VR::CS,
            "ORIGINAL\\PRIMARY\\TOMOSYNTHESIS\\NONE",
        ),
        s(
            tags::ACQUISITION_DATE_TIME,
            VR::DT,
            &format!("{}{}", h.study_date, h.study_time),
        ),
        s(tags::SERIES_INSTANCE_UID, VR::UI, &series),
        s(tags::INSTANCE_NUMBER, VR::IS, "1"),
        s(tags::FRAME_OF_REFERENCE_UID, VR::UI, &frame_of_reference),
        s(tags::CONTENT_QUALIFICATION, VR::CS, "PRODUCT"),
        s(tags::NUMBER_OF_FRAMES, VR::IS, &frames.to_string()),
    ] {
        o.put(e);
    }
    o.put(DataElement::new(
        tags::ROWS,
        VR::US,
        PrimitiveValue::from(p.rows as u16),
    ));
    o.put(DataElement::new(
        tags::COLUMNS,
        VR::US,
        PrimitiveValue::from(p.columns as u16),
    ));
    for t in [tags::BITS_ALLOCATED, tags::BITS_STORED] {
        o.put(DataElement::new(t, VR::US, PrimitiveValue::from(16u16)));
    }
    o.put(DataElement::new(
        tags::HIGH_BIT,
        VR::US,
        PrimitiveValue::from(15u16),
    ));
    o.put(DataElement::new(
        tags::SAMPLES_PER_PIXEL,
        VR::US,
        PrimitiveValue::from(1u16),
    ));
    o.put(DataElement::new(
        tags::PIXEL_REPRESENTATION,
        VR::US,
        PrimitiveValue::from(0u16),
    ));
    let total_mas = p.exposure_uas_per_view * frames as f64 / 1000.0;
    let total_ms = p.exposure_ms_per_view * frames as f64;
    let ma = p.exposure_uas_per_view / p.exposure_ms_per_view;
    for e in [
        s(tags::POSITIONER_MOTION, VR::CS, "DYNAMIC"),
        s(tags::EXPOSURE_CONTROL_MODE, VR::CS, "MANUAL"),
        s(
            tags::EXPOSURE_CONTROL_MODE_DESCRIPTION,
            VR::LT,
            "technique by compressed thickness (Sechopoulos et al. Table 3)",
        ),
        s(tags::ORGAN_DOSE, VR::DS, &ds(p.modality_agd_mgy / 100.0)),
        s(tags::ENTRANCE_DOSE_INM_GY, VR::DS, &ds(p.entrance_dose_mgy)),
        s(tags::TYPE_OF_DETECTOR_MOTION, VR::CS, "NONE"),
    ] {
        o.put(e);
    }
    o.put(DataElement::new(
        tags::ACQUISITION_DURATION,
        VR::FD,
        PrimitiveValue::from(
            p.view_interval_ms * (frames - 1) as f64 / 1000.0 + p.exposure_ms_per_view / 1000.0,
        ),
    ));
    for (t, v) in [
        (tags::X_RAY_TUBE_CURRENT_INM_A, ma),
        (tags::EXPOSURE_TIME_INMS, total_ms),
        (tags::EXPOSURE_INM_AS, total_mas),
    ] {
        o.put(DataElement::new(t, VR::FD, PrimitiveValue::from(v)));
    }
    o.put(DataElement::new(
        tags::ACQUISITION_CONTEXT_SEQUENCE,
        VR::SQ,
        sq(vec![]),
    ));
    o.put(DataElement::new(
        tags::PATIENT_ORIENTATION_CODE_SEQUENCE,
        VR::SQ,
        sq(vec![code("10904000", "SCT", "erect")]),
    ));
    o.put(DataElement::new(
        tags::VIEW_CODE_SEQUENCE,
        VR::SQ,
        sq(vec![{
            let mut v = code("399162004", "SCT", "cranio-caudal");
            v.put(DataElement::new(
                tags::VIEW_MODIFIER_CODE_SEQUENCE,
                VR::SQ,
                sq(vec![]),
            ));
            v
        }]),
    ));
    // Functional groups: shared (pixel measures, technique), per frame
    // (frame content, positioner angle).
    let fl = |t, v: f64| DataElement::new(t, VR::FL, PrimitiveValue::from(v as f32));
    let fd = |t, v: f64| DataElement::new(t, VR::FD, PrimitiveValue::from(v));
    let seq = |t, items: Vec<InMemDicomObject>| DataElement::new(t, VR::SQ, sq(items));
    let (fov_w, fov_h) = (
        p.columns as f64 * p.pixel_spacing_mm[1],
        p.rows as f64 * p.pixel_spacing_mm[0],
    );
    let spacing = format!(
        "{}\\{}",
        ds(p.pixel_spacing_mm[0]),
        ds(p.pixel_spacing_mm[1])
    );
    let shared = item(vec![
        seq(
            tags::X_RAY_GEOMETRY_SEQUENCE,
            vec![item(
                std::iter::once(fl(
                    tags::DISTANCE_SOURCE_TO_ISOCENTER,
                    p.source_to_isocenter_mm,
                ))
                .chain(distance_elements(p))
                .collect(),
            )],
        ),
        seq(
            tags::FRAME_ANATOMY_SEQUENCE,
            vec![item(vec![
                seq(
                    tags::ANATOMIC_REGION_SEQUENCE,
                    vec![code("76752008", "SCT", "Breast")],
                ),
                s(tags::FRAME_LATERALITY, VR::CS, lat),
            ])],
        ),
        seq(
            tags::PIXEL_VALUE_TRANSFORMATION_SEQUENCE,
            vec![item(vec![
                s(tags::RESCALE_INTERCEPT, VR::DS, "0"),
                s(tags::RESCALE_SLOPE, VR::DS, "1"),
                s(tags::RESCALE_TYPE, VR::LO, "US"),
            ])],
        ),
        seq(
            tags::FRAME_VOILUT_SEQUENCE,
            vec![item(vec![
                s(tags::WINDOW_CENTER, VR::DS, "32768"),
                s(tags::WINDOW_WIDTH, VR::DS, "65536"),
            ])],
        ),
        seq(
            tags::FIELD_OF_VIEW_SEQUENCE,
            vec![item(vec![
                s(tags::FIELD_OF_VIEW_SHAPE, VR::CS, "RECTANGLE"),
                s(tags::FIELD_OF_VIEW_ROTATION, VR::DS, "0"),
                s(tags::FIELD_OF_VIEW_HORIZONTAL_FLIP, VR::CS, "NO"),
                DataElement::new(
                    tags::FIELD_OF_VIEW_DIMENSIONS_IN_FLOAT,
                    VR::FL,
                    PrimitiveValue::F32([fov_w as f32, fov_h as f32].into_iter().collect()),
                ),
            ])],
        ),
        seq(
            tags::FRAME_PIXEL_DATA_PROPERTIES_SEQUENCE,
            vec![item(vec![
                s(
                    tags::FRAME_TYPE,
                    VR::CS,
                    "ORIGINAL\\PRIMARY\\TOMOSYNTHESIS\\NONE",
                ),
                s(tags::IMAGER_PIXEL_SPACING, VR::DS, &spacing),
                s(tags::GEOMETRICAL_PROPERTIES, VR::CS, "UNIFORM"),
                s(tags::IMAGE_PROCESSING_APPLIED, VR::CS, "NONE"),
                s(tags::PIXEL_INTENSITY_RELATIONSHIP, VR::CS, "LIN"),
                DataElement::new(
                    tags::PIXEL_INTENSITY_RELATIONSHIP_SIGN,
                    VR::SS,
                    PrimitiveValue::from(1i16),
                ),
            ])],
        ),
        // X-Ray Filter Macro: the beam's filter.
        seq(
            tags::X_RAY_FILTER_SEQUENCE,
            vec![item(
                [s(tags::FILTER_TYPE, VR::CS, "FLAT")]
                    .into_iter()
                    .chain(filter_elements(p))
                    .collect(),
            )],
        ),
        seq(
            tags::COLLIMATOR_SHAPE_SEQUENCE,
            vec![item(vec![
                s(tags::COLLIMATOR_SHAPE, VR::CS, "RECTANGULAR"),
                s(tags::COLLIMATOR_LEFT_VERTICAL_EDGE, VR::IS, "0"),
                s(
                    tags::COLLIMATOR_RIGHT_VERTICAL_EDGE,
                    VR::IS,
                    &p.columns.to_string(),
                ),
                s(tags::COLLIMATOR_UPPER_HORIZONTAL_EDGE, VR::IS, "0"),
                s(
                    tags::COLLIMATOR_LOWER_HORIZONTAL_EDGE,
                    VR::IS,
                    &p.rows.to_string(),
                ),
            ])],
        ),
        seq(
            tags::X_RAY_ACQUISITION_DOSE_SEQUENCE,
            vec![item(
                [
                    fd(tags::EXPOSURE_TIME_INMS, p.exposure_ms_per_view),
                    fd(tags::EXPOSURE_INM_AS, p.exposure_uas_per_view / 1000.0),
                ]
                .into_iter()
                .chain(view_dose_elements(p))
                .collect(),
            )],
        ),
    ]);
    o.put(DataElement::new(
        tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE,
        VR::SQ,
        sq(vec![shared]),
    ));
    let start = format!("{}{}", h.study_date, h.study_time);
    let detector_z = -(p.source_to_detector_mm - p.source_to_isocenter_mm);
    let support_z = detector_z + p.support_to_detector_mm;
    let per_frame: Vec<InMemDicomObject> = p
        .angles_deg
        .iter()
        .enumerate()
        .map(|(k, a)| {
            // Frame k starts k view intervals after the first (whole ms).
            let at = frame_datetime(&start, (p.view_interval_ms * k as f64).round() as u64);
            item(vec![
                seq(
                    tags::FRAME_CONTENT_SEQUENCE,
                    vec![item(vec![
                        s(tags::FRAME_REFERENCE_DATE_TIME, VR::DT, &at),
                        s(tags::FRAME_ACQUISITION_DATE_TIME, VR::DT, &at),
                        fd(tags::FRAME_ACQUISITION_DURATION, p.exposure_ms_per_view),
                    ])],
                ),
                seq(
                    tags::IRRADIATION_EVENT_IDENTIFICATION_SEQUENCE,
                    vec![item(vec![s(
                        tags::IRRADIATION_EVENT_UID,
                        VR::UI,
                        &uids.next_uid(),
                    )])],
                ),
                // The source turns about the isocentre; breast support and
                // detector stay (angles 0). Isocentre coordinates, mm: z
                // toward the source at 0 degrees, x along the detector rows.
                seq(
                    tags::ISOCENTER_REFERENCE_SYSTEM_SEQUENCE,
                    vec![item(vec![
                        fd(tags::X_RAY_SOURCE_ISOCENTER_PRIMARY_ANGLE, *a),
                        fd(tags::X_RAY_SOURCE_ISOCENTER_SECONDARY_ANGLE, 0.0),
                        fd(tags::BREAST_SUPPORT_ISOCENTER_PRIMARY_ANGLE, 0.0),
                        fd(tags::BREAST_SUPPORT_ISOCENTER_SECONDARY_ANGLE, 0.0),
                        fd(tags::BREAST_SUPPORT_X_POSITION_TO_ISOCENTER, 0.0),
                        fd(tags::BREAST_SUPPORT_Y_POSITION_TO_ISOCENTER, 0.0),
                        fd(tags::BREAST_SUPPORT_Z_POSITION_TO_ISOCENTER, support_z),
                        fd(tags::DETECTOR_ISOCENTER_PRIMARY_ANGLE, 0.0),
                        fd(tags::DETECTOR_ISOCENTER_SECONDARY_ANGLE, 0.0),
                        fd(tags::DETECTOR_X_POSITION_TO_ISOCENTER, 0.0),
                        fd(tags::DETECTOR_Y_POSITION_TO_ISOCENTER, 0.0),
                        fd(tags::DETECTOR_Z_POSITION_TO_ISOCENTER, detector_z),
                        DataElement::new(
                            tags::DETECTOR_ACTIVE_AREA_TLHC_POSITION,
                            VR::FD,
                            PrimitiveValue::F64(
                                [-fov_w / 2.0, 0.0, detector_z].into_iter().collect(),
                            ),
                        ),
                        DataElement::new(
                            tags::DETECTOR_ACTIVE_AREA_ORIENTATION,
                            VR::FD,
                            PrimitiveValue::F64(
                                [1.0, 0.0, 0.0, 0.0, 1.0, 0.0].into_iter().collect(),
                            ),
                        ),
                    ])],
                ),
            ])
        })
        .collect();
    o.put(DataElement::new(
        tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE,
        VR::SQ,
        sq(per_frame),
    ));
    o.put(DataElement::new(
        tags::PIXEL_DATA,
        VR::OW,
        PrimitiveValue::U16(p.counts.iter().copied().collect()),
    ));
    Ok(Report::from_parts(
        BPXR_FOR_PROCESSING_CLASS,
        sop_instance,
        o,
    ))
}

/// `start` (`YYYYMMDDHHMMSS`) plus `ms` milliseconds, as a DT with
/// milliseconds (the frames of one sweep are less than a day apart; a
/// start that does not parse is kept as it is, with the offset in the
/// fraction).
pub(crate) fn frame_datetime(start: &str, ms: u64) -> String {
    let secs: Option<u64> = (start.len() == 14)
        .then(|| {
            let n = |r: std::ops::Range<usize>| start.get(r).and_then(|v| v.parse::<u64>().ok());
            Some(n(8..10)? * 3600 + n(10..12)? * 60 + n(12..14)?)
        })
        .flatten();
    match secs {
        Some(s0) if s0 + ms / 1000 < 86_400 => {
            let t = s0 + ms / 1000;
            format!(
                "{}{:02}{:02}{:02}.{:03}",
                &start[..8],
                t / 3600,
                t / 60 % 60,
                t % 60,
                ms % 1000
            )
        }
        _ => format!("{start}.{:03}", ms % 1000),
    }
}

pub use crate::input::{InputError, ReceivedProjections};

/// Read a For Processing projection object (Breast Projection X-Ray, or one
/// view as Digital Mammography X-Ray): [`crate::input::read_input_object`]
/// without private classes.
pub fn read_projection_object(bytes: &[u8]) -> Result<ReceivedProjections, InputError> {
    crate::input::read_input_object(bytes, &[])
}
