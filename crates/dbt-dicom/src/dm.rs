//! A DBT acquisition as one Digital Mammography X-Ray Image - For Processing
//! object per projection (issue #31), the way systems that do not send the
//! multi-frame Breast Projection object deliver their projections to a
//! density or dose server. Each object is one view: the raw counts of the
//! detector (16 bits, linear), its Positioner Primary Angle, and the
//! technique of that view; the views of one sweep share the study, the
//! series, Image Laterality and View Position, and are told apart by their
//! angle (and Instance Number).
//!
//! The modules are the DM IOD's (PS3.3 A.26.2): DX Series, DX Anatomy
//! Imaged, DX Image, DX Detector, DX Positioning, X-Ray Acquisition Dose,
//! X-Ray Generation, X-Ray Filtration, Mammography Image, Acquisition
//! Context. The IOD has no isocentre distance: the reader takes the
//! configured one (see `docs/conformance.md`).

use crate::projections::{
    bad, check, code, common_elements, distance_elements, ds, filter_elements, frame_datetime, sq,
    view_dose_elements, ProjectionSet,
};
use crate::reports::{Laterality, Report};
use crate::{DicomError, UidSource};
use dicom_core::value::PrimitiveValue;
use dicom_core::{DataElement, VR};
use dicom_dictionary_std::tags;
use dicom_object::InMemDicomObject;

/// Digital Mammography X-Ray Image Storage - For Processing.
pub use crate::reports::DM_FOR_PROCESSING_CLASS;

/// One object per view of `p` (same series, Instance Number = view + 1),
/// checked as `projection_object` checks the multi-frame one.
pub fn view_objects(
    p: &ProjectionSet<'_>,
    uids: &mut UidSource,
) -> Result<Vec<Report>, DicomError> {
    check(p)?;
    let frames = p.angles_deg.len();
    if p.rows > u16::MAX as usize || p.columns > u16::MAX as usize {
        return Err(bad("rows", format!("{} x {}", p.rows, p.columns)));
    }
    let h = p.header;
    let series = uids.next_uid();
    let frame_of_reference = uids.next_uid();
    let lat = h.laterality.letter();
    let orientation = match h.laterality {
        // Patient Orientation (PS3.3 C.7.6.1.1.1): along a row the columns
        // run across the breast, down a column the rows (coronal slices)
        // run from the chest wall to the nipple (A).
        Laterality::Left => "R\\A",
        Laterality::Right => "L\\A",
    };
    let start = format!("{}{}", h.study_date, h.study_time);
    let plane = p.rows * p.columns;
    let s = |t, vr, v: &str| DataElement::new(t, vr, v.to_string());
    let us = |t, v: u16| DataElement::new(t, VR::US, PrimitiveValue::from(v));
    let seq = |t, items: Vec<InMemDicomObject>| DataElement::new(t, VR::SQ, sq(items));
    let spacing = format!(
        "{}\\{}",
        ds(p.pixel_spacing_mm[0]),
        ds(p.pixel_spacing_mm[1])
    );
    let mut out = Vec::with_capacity(frames);
    for (k, angle) in p.angles_deg.iter().enumerate() {
        let sop_instance = uids.next_uid();
        let at = frame_datetime(&start, (p.view_interval_ms * k as f64).round() as u64);
        let (date, time) = (at.get(..8).unwrap_or(""), at.get(8..).unwrap_or(""));
        let mut o = InMemDicomObject::new_empty();
        for e in common_elements(p).into_iter().chain(distance_elements(p)) {
            o.put(e);
        }
        for e in [
            s(tags::SOP_CLASS_UID, VR::UI, DM_FOR_PROCESSING_CLASS),
            s(tags::SOP_INSTANCE_UID, VR::UI, &sop_instance),
            s(tags::IMAGE_TYPE, VR::CS, "ORIGINAL\\PRIMARY\\"),
            s(tags::ACQUISITION_DATE, VR::DA, date),
            s(tags::ACQUISITION_TIME, VR::TM, time),
            s(tags::ACQUISITION_DATE_TIME, VR::DT, &at),
            s(tags::BODY_PART_EXAMINED, VR::CS, "BREAST"),
            s(
                tags::EXPOSURE_TIME,
                VR::IS,
                &format!("{}", p.exposure_ms_per_view.round().max(1.0) as i64),
            ),
            s(
                tags::EXPOSURE_INU_AS,
                VR::IS,
                &format!("{}", p.exposure_uas_per_view.round() as i64),
            ),
            s(tags::IMAGER_PIXEL_SPACING, VR::DS, &spacing),
            s(tags::POSITIONER_PRIMARY_ANGLE, VR::DS, &ds(*angle)),
            s(tags::POSITIONER_SECONDARY_ANGLE, VR::DS, "0"),
            s(tags::SERIES_INSTANCE_UID, VR::UI, &series),
            s(tags::INSTANCE_NUMBER, VR::IS, &(k + 1).to_string()),
            s(tags::PATIENT_ORIENTATION, VR::CS, orientation),
            s(tags::FRAME_OF_REFERENCE_UID, VR::UI, &frame_of_reference),
            s(tags::IMAGE_LATERALITY, VR::CS, lat),
            s(tags::RESCALE_INTERCEPT, VR::DS, "0"),
            s(tags::RESCALE_SLOPE, VR::DS, "1"),
            s(tags::RESCALE_TYPE, VR::LO, "US"),
            s(tags::PIXEL_INTENSITY_RELATIONSHIP, VR::CS, "LIN"),
            s(tags::ORGAN_EXPOSED, VR::CS, "BREAST"),
            s(tags::PARTIAL_VIEW, VR::CS, "NO"),
        ]
        .into_iter()
        .chain(filter_elements(p))
        .chain(view_dose_elements(p))
        {
            o.put(e);
        }
        o.put(DataElement::new(
            tags::PIXEL_INTENSITY_RELATIONSHIP_SIGN,
            VR::SS,
            PrimitiveValue::from(1i16),
        ));
        for e in [
            us(tags::SAMPLES_PER_PIXEL, 1),
            us(tags::ROWS, p.rows as u16),
            us(tags::COLUMNS, p.columns as u16),
            us(tags::BITS_ALLOCATED, 16),
            us(tags::BITS_STORED, 16),
            us(tags::HIGH_BIT, 15),
            us(tags::PIXEL_REPRESENTATION, 0),
        ] {
            o.put(e);
        }
        for e in [
            seq(
                tags::ANATOMIC_REGION_SEQUENCE,
                vec![code("76752008", "SCT", "Breast")],
            ),
            seq(
                tags::VIEW_CODE_SEQUENCE,
                vec![{
                    let mut v = code("399162004", "SCT", "cranio-caudal");
                    v.put(DataElement::new(
                        tags::VIEW_MODIFIER_CODE_SEQUENCE,
                        VR::SQ,
                        sq(vec![]),
                    ));
                    v
                }],
            ),
            seq(tags::ACQUISITION_CONTEXT_SEQUENCE, vec![]),
        ] {
            o.put(e);
        }
        let counts = &p.counts[k * plane..(k + 1) * plane];
        o.put(DataElement::new(
            tags::PIXEL_DATA,
            VR::OW,
            PrimitiveValue::U16(counts.iter().copied().collect()),
        ));
        out.push(Report::from_parts(DM_FOR_PROCESSING_CLASS, sop_instance, o));
    }
    Ok(out)
}
