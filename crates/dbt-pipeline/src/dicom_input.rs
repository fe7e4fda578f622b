//! Received For Processing projections as an acquisition (issue #31, the
//! DICOM input): a Breast Projection X-Ray object (the whole sweep), or the
//! views of one sweep sent one object each ([`assemble`] after grouping by
//! [`group_key`] and placing each by [`view_index`]). The objects give the
//! technique, thickness and identity; the configured system gives the
//! geometry, flat field and tube output, which the objects must agree with.
//! Everything the pipeline reads is then checked again by
//! [`validate_header`].

use crate::acquisition::{
    validate_header, Acquisition, AcquisitionHeader, HeaderError, Patient, Study, ACQ_FORMAT,
};
use dbt_dicom::input::Layout;
use dbt_dicom::projections::{ProjectionSet, ReceivedProjections};
use dbt_dose::xray::AnodeFilter;

/// The configured gantry the objects must come from.
pub use dbt_intake::Gantry;

/// Angles and distances of an object may differ from the configuration's by
/// this much (rounding in DS/FD encodings; a real mismatch is degrees and
/// centimetres).
const ANGLE_TOL_DEG: f64 = 0.01;
/// See [`ANGLE_TOL_DEG`], mm.
const DISTANCE_TOL_MM: f64 = 0.5;
/// Relative tolerance of the pixel spacing.
const SPACING_TOL: f64 = 1e-3;
/// The views of one sweep may disagree on the thickness by this much, mm
/// (DS rounding; a paddle that moved between views is a new acquisition).
const THICKNESS_TOL_MM: f64 = 0.5;

/// The beam of an object from its Anode Target Material (0018,1191) and
/// Filter Material (0018,7050): one of the beams the dose model has spectra
/// for (`dbt_dose::xray::AnodeFilter`: a tungsten anode with rhodium,
/// aluminium or silver; molybdenum with molybdenum or rhodium; rhodium with
/// rhodium); another anode, filter or pairing is refused naming the
/// attribute and its value, never reported with another beam's dose. An
/// object without an anode is taken on a tungsten one. Where the object
/// does not state its filter (optional in the DM IOD), the site's
/// `unstated` beam ([`Gantry::unstated_beam`]; `None` refuses it, naming
/// Filter Material), if its anode is the object's.
pub fn beam(
    p: &ReceivedProjections,
    unstated: Option<AnodeFilter>,
) -> Result<AnodeFilter, HeaderError> {
    use dbt_dicom::{AnodeMaterial, ANODE_TUNGSTEN};
    let stated = p.anode.as_deref().unwrap_or(ANODE_TUNGSTEN);
    let anode = AnodeMaterial::ALL
        .into_iter()
        .find(|a| a.term() == stated.trim())
        .ok_or_else(|| {
            refuse(
                "AnodeTargetMaterial",
                stated,
                format!(
                    "the dose model's spectra are for a {} anode",
                    AnodeMaterial::ALL.map(|a| a.term()).join(", ")
                ),
            )
        })?;
    let on_anode: Vec<AnodeFilter> = AnodeFilter::ALL
        .into_iter()
        .filter(|a| anode_material(*a) == anode)
        .collect();
    let Some(f) = p.filter.as_deref() else {
        let Some(u) = unstated else {
            return Err(refuse(
                "FilterMaterial",
                "(absent)",
                "the object does not state its filter, and this site takes no beam for granted \
                 ([report] unstated_beam = \"refuse\")",
            ));
        };
        if !on_anode.contains(&u) {
            return Err(refuse(
                "FilterMaterial",
                "(absent)",
                format!(
                    "the object does not state its filter, and the site's unstated beam ({u}) \
                     is not on its {} anode",
                    anode.term()
                ),
            ));
        }
        return Ok(u);
    };
    // A filter of several layers (`\`-separated) is one beam's only if
    // every layer is that beam's filter.
    on_anode
        .iter()
        .copied()
        .find(|a| {
            let term = filter_material(*a).term();
            f.split('\\').all(|m| m.trim() == term)
        })
        .ok_or_else(|| {
            refuse(
                "FilterMaterial",
                f,
                format!(
                    "the dose model's spectra on a {} anode are for one filter of {}",
                    anode.term(),
                    on_anode
                        .iter()
                        .map(|a| filter_material(*a).term())
                        .collect::<Vec<_>>()
                        .join(" or ")
                ),
            )
        })
}

/// The DICOM anode material of a beam.
pub fn anode_material(af: AnodeFilter) -> dbt_dicom::AnodeMaterial {
    match af.anode() {
        dbt_dose::xray::Anode::W => dbt_dicom::AnodeMaterial::Tungsten,
        dbt_dose::xray::Anode::Mo => dbt_dicom::AnodeMaterial::Molybdenum,
        dbt_dose::xray::Anode::Rh => dbt_dicom::AnodeMaterial::Rhodium,
    }
}

/// The DICOM filter material of a beam.
pub fn filter_material(af: AnodeFilter) -> dbt_dicom::FilterMaterial {
    match af.filter_metal() {
        dbt_dose::xray::FilterMetal::Rh => dbt_dicom::FilterMaterial::Rhodium,
        dbt_dose::xray::FilterMetal::Al => dbt_dicom::FilterMaterial::Aluminum,
        dbt_dose::xray::FilterMetal::Ag => dbt_dicom::FilterMaterial::Silver,
        dbt_dose::xray::FilterMetal::Mo => dbt_dicom::FilterMaterial::Molybdenum,
    }
}

fn refuse(field: &'static str, value: impl ToString, reason: impl Into<String>) -> HeaderError {
    HeaderError {
        field,
        value: value.to_string(),
        reason: reason.into(),
    }
}

/// The checks of one object against the configured system that do not
/// depend on how many views it holds: detector columns and pitch, source
/// distances, anode and filter.
pub fn check_object(p: &ReceivedProjections, system: &Gantry) -> Result<(), HeaderError> {
    let (det, pitch) = system.columns();
    if p.columns != det {
        return Err(refuse(
            "Columns",
            p.columns,
            format!("the configured detector has {det} elements"),
        ));
    }
    if (p.pixel_spacing_mm[1] / pitch - 1.0).abs() > SPACING_TOL {
        return Err(refuse(
            "ImagerPixelSpacing",
            p.pixel_spacing_mm[1],
            format!("the configured element pitch is {pitch} mm"),
        ));
    }
    if let Some(c) = &system.cone {
        // A cone-beam detector's rows are its own: their number and pitch
        // are the system's.
        if p.rows != c.detector.rows {
            return Err(refuse(
                "Rows",
                p.rows,
                format!(
                    "the configured system {} has {} detector rows",
                    c.name, c.detector.rows
                ),
            ));
        }
        if (p.pixel_spacing_mm[0] / c.detector.pitch_mm - 1.0).abs() > SPACING_TOL {
            return Err(refuse(
                "ImagerPixelSpacing",
                p.pixel_spacing_mm[0],
                format!(
                    "the configured system {}'s row pitch is {} mm",
                    c.name, c.detector.pitch_mm
                ),
            ));
        }
    }
    let (sdd, sid) = system.distances();
    for (field, got, want) in [
        (
            "DistanceSourceToDetector",
            Some(p.source_to_detector_mm),
            sdd,
        ),
        ("DistanceSourceToIsocenter", p.source_to_isocenter_mm, sid),
    ] {
        // An object without the isocentre distance (the DM IOD has none)
        // is taken on the configured one.
        let Some(got) = got else { continue };
        if (got - want).abs() > DISTANCE_TOL_MM {
            return Err(refuse(
                field,
                got,
                format!("the configured gantry's is {want} mm"),
            ));
        }
    }
    // Another anode or filter than the dose model's would be reported
    // with the wrong dose.
    beam(p, system.unstated_beam)?;
    Ok(())
}

/// The acquisition of `p` on `system`, refused naming the attribute where
/// the object disagrees with the configured system (views, angles,
/// distances, detector columns and pitch) or with the header's limits.
pub fn acquisition_from_projections(
    p: &ReceivedProjections,
    system: &Gantry,
) -> Result<Acquisition, HeaderError> {
    let g = &system.geometry;
    let (views, (det, _)) = (system.n_views(), system.columns());
    if p.angles_deg.len() != views {
        return Err(refuse(
            "NumberOfFrames",
            p.angles_deg.len(),
            format!("the configured gantry has {views} views"),
        ));
    }
    for (v, a) in p.angles_deg.iter().enumerate() {
        if (a - system.angle_deg(v)).abs() > ANGLE_TOL_DEG {
            return Err(refuse(
                "XRaySourceIsocenterPrimaryAngle",
                format!("{a} (frame {})", v + 1),
                format!(
                    "the configured view {} is at {} deg",
                    v + 1,
                    system.angle_deg(v)
                ),
            ));
        }
    }
    check_object(p, system)?;
    // Frames are views of rows (coronal slices, or a cone-beam detector's
    // rows) x columns (elements).
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
        flux: system.flux.ok_or_else(|| {
            refuse(
                "flux",
                "none",
                "the configured gantry states no flat field for For Processing objects ([dicom_input] flat_field_counts)",
            )
        })?,
        slices: rows,
        // A cone-beam system's rows are rebinned to slices one pixel apart.
        slice_spacing_mm: match &system.cone {
            Some(_) => g.image.pixel_mm,
            None => p.pixel_spacing_mm[0],
        },
        kvp: p.kvp,
        anode_filter: beam(p, system.unstated_beam)?,
        mas_total: p.exposure_mas,
        tube_output_mgy_per_mas: system.tube_output_mgy_per_mas,
        laterality: h.laterality.letter().into(),
        compression_force_n: p.compression_force_n,
        exposure_ms_per_view: p.exposure_ms_per_view,
        system: system.cone.clone(),
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
            source_class: Some(p.sop_class.clone()),
        },
        truth: None,
    };
    validate_header(&header)?;
    Ok(Acquisition { header, counts })
}

/// The group a view object belongs to: one acquisition per study,
/// laterality and view (`study|L|cranio-caudal`).
pub fn group_key(p: &ReceivedProjections) -> String {
    format!(
        "{}|{}|{}",
        p.header.study_uid,
        p.header.laterality.letter(),
        p.view
    )
}

/// The configured view a one-view object is, by its angle; refused naming
/// the angle when no configured view is within the tolerance.
pub fn view_index(p: &ReceivedProjections, system: &Gantry) -> Result<usize, HeaderError> {
    let [a] = p.angles_deg[..] else {
        return Err(refuse(
            "NumberOfFrames",
            p.angles_deg.len(),
            "a one-view object has one frame",
        ));
    };
    let n = system.n_views();
    (0..n)
        .find(|&v| (system.angle_deg(v) - a).abs() <= ANGLE_TOL_DEG)
        .ok_or_else(|| {
            refuse(
                "PositionerPrimaryAngle",
                a,
                format!(
                    "no configured view is at this angle (the gantry's {n} views run from {} to {} deg)",
                    system.angle_deg(0),
                    system.angle_deg(n.saturating_sub(1))
                ),
            )
        })
}

/// One sweep from its one-view objects (one per configured view, any
/// order): the frames in view order, the exposures summed, every source
/// instance kept. Refused, naming the attribute, where the views disagree
/// (patient, series, detector, thickness, technique) or a view is missing
/// or twice.
pub fn assemble(
    views: &[ReceivedProjections],
    system: &Gantry,
) -> Result<ReceivedProjections, HeaderError> {
    let n = system.n_views();
    let mut slots: Vec<Option<&ReceivedProjections>> = vec![None; n];
    for p in views {
        let k = view_index(p, system)?;
        if slots[k].is_some() {
            return Err(refuse(
                "PositionerPrimaryAngle",
                p.angles_deg[0],
                format!("view {} is there twice", k + 1),
            ));
        }
        slots[k] = Some(p);
    }
    let placed: Vec<&ReceivedProjections> = slots.iter().flatten().copied().collect();
    if placed.len() != n {
        let missing: Vec<String> = (0..n)
            .filter(|&k| slots[k].is_none())
            .map(|k| format!("{} deg", system.angle_deg(k)))
            .collect();
        return Err(refuse(
            "views",
            placed.len(),
            format!(
                "{n} views make a sweep; missing the views at {}",
                missing.join(", ")
            ),
        ));
    }
    let first = placed[0];
    for p in &placed[1..] {
        check_same_sweep(first, p)?;
    }
    let mut header = first.header.clone();
    header.source_instance_uids = placed.iter().map(|p| p.sop_instance.clone()).collect();
    Ok(ReceivedProjections {
        header,
        layout: Layout::PerView,
        angles_deg: placed.iter().map(|p| p.angles_deg[0]).collect(),
        exposure_mas: placed.iter().map(|p| p.exposure_mas).sum(),
        counts: placed
            .iter()
            .flat_map(|p| p.counts.iter().copied())
            .collect(),
        ..first.clone()
    })
}

/// Whether `p` is a view of the same sweep as `first`: refused naming the
/// attribute where they differ (patient, series, class, detector, spacing,
/// kV, anode and filter as stated, thickness).
pub fn check_same_sweep(
    first: &ReceivedProjections,
    p: &ReceivedProjections,
) -> Result<(), HeaderError> {
    let differs = |field: &'static str, a: String, b: String| {
        (a != b).then(|| {
            refuse(
                field,
                b,
                format!(
                    "the sweep's other views have {a} (view at {} deg)",
                    p.angles_deg.first().copied().unwrap_or(f64::NAN)
                ),
            )
        })
    };
    let checks = [
        differs(
            "PatientID",
            first.header.patient_id.clone(),
            p.header.patient_id.clone(),
        ),
        differs(
            "SeriesInstanceUID",
            first.header.source_series_uid.clone(),
            p.header.source_series_uid.clone(),
        ),
        differs("SOPClassUID", first.sop_class.clone(), p.sop_class.clone()),
        differs(
            "Rows",
            format!("{} x {}", first.rows, first.columns),
            format!("{} x {}", p.rows, p.columns),
        ),
        differs(
            "ImagerPixelSpacing",
            format!("{:?}", first.pixel_spacing_mm),
            format!("{:?}", p.pixel_spacing_mm),
        ),
        differs("KVP", first.kvp.to_string(), p.kvp.to_string()),
        // The beam as each view states it (a view that omits it while
        // another states it is a mixed sweep too).
        differs(
            "AnodeTargetMaterial",
            format!("{:?}", first.anode),
            format!("{:?}", p.anode),
        ),
        differs(
            "FilterMaterial",
            format!("{:?}", first.filter),
            format!("{:?}", p.filter),
        ),
        ((first.thickness_mm - p.thickness_mm).abs() > THICKNESS_TOL_MM).then(|| {
            refuse(
                "BodyPartThickness",
                p.thickness_mm,
                format!(
                    "the sweep's other views have {} mm (tolerance {THICKNESS_TOL_MM} mm)",
                    first.thickness_mm
                ),
            )
        }),
    ];
    match checks.into_iter().flatten().next() {
        Some(e) => Err(e),
        None => Ok(()),
    }
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
    /// Filter thickness, mm (its material: the acquisition's beam).
    pub filter_mm: f64,
    /// Content date and time.
    pub content_date: &'a str,
    /// See `content_date`.
    pub content_time: &'a str,
}

/// The frames of `acq` for its projection object: view by view, detector
/// rows = coronal slices, columns = elements; refused where a count does
/// not fit 16 bits.
pub fn frames_of(acq: &Acquisition) -> Result<Vec<u16>, HeaderError> {
    let h = &acq.header;
    let (views, det) = match &h.system {
        Some(c) => (c.n_views(), c.detector.columns),
        None => (h.geometry.n_views(), h.geometry.n_det()),
    };
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
    // A cone-beam system's detector (square elements; distances at 0
    // degrees; the breast support above the detector), or the fan stream's
    // rows of slices.
    let (views, columns, spacing, sdd, sid, support) = match &h.system {
        Some(c) => (
            c.n_views(),
            c.detector.columns,
            [c.detector.pitch_mm; 2],
            c.arc_radius_mm + c.axis_height_mm,
            c.arc_radius_mm,
            c.support_height_mm,
        ),
        None => (
            g.n_views(),
            g.n_det(),
            [h.slice_spacing_mm, g.detector.pitch_mm],
            g.source_to_detector_mm,
            g.source_to_center_mm,
            0.0,
        ),
    };
    ProjectionSet {
        header,
        equipment,
        rows: h.slices,
        columns,
        pixel_spacing_mm: spacing,
        angles_deg,
        source_to_detector_mm: sdd,
        source_to_isocenter_mm: sid,
        thickness_mm: h.thickness_mm,
        compression_force_n: sweep.compression_force_n,
        support_to_detector_mm: support,
        exposure_ms_per_view: sweep.exposure_ms_per_view,
        view_interval_ms: sweep.view_interval_ms,
        modality_agd_mgy: sweep.modality_agd_mgy,
        entrance_dose_mgy: h.mas_total * h.tube_output_mgy_per_mas,
        kvp: h.kvp,
        exposure_uas_per_view: h.mas_total * 1000.0 / views as f64,
        anode_material: anode_material(h.anode_filter),
        filter_material: filter_material(h.anode_filter),
        filter_mm: sweep.filter_mm,
        counts,
        content_date: sweep.content_date,
        content_time: sweep.content_time,
    }
}
