//! What the daemon's DICOM input reads from a received object (issue #31):
//! a Breast Projection X-Ray For Processing object (one multi-frame object
//! per sweep), a Digital Mammography X-Ray For Processing object (one per
//! view), or a vendor's private projection object described by a
//! [`Mapping`] (which standard attribute is kept in which tag). Every
//! refusal names the attribute and what is wrong with it.

use crate::reports::{Header, Laterality};
use crate::reports::{
    BREAST_PROJECTION_FOR_PROCESSING_CLASS as BPXR_FOR_PROCESSING_CLASS, DM_FOR_PROCESSING_CLASS,
};
use dicom_core::header::HasLength as _;
pub use dicom_core::Tag;
use dicom_core::VR;
use dicom_dictionary_std::tags;
use dicom_object::InMemDicomObject;
use std::collections::BTreeMap;

/// How an object holds the projections of a sweep.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// One object, one frame per view (as Breast Projection X-Ray).
    MultiFrame,
    /// One object per view (as Digital Mammography X-Ray).
    PerView,
}

impl Layout {
    /// `multi-frame` or `per-view`.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "multi-frame" => Some(Self::MultiFrame),
            "per-view" => Some(Self::PerView),
            _ => None,
        }
    }
}

/// A vendor's private projection class: its SOP class UID, its layout, and
/// where it keeps each attribute the input reads (standard keyword -> tag;
/// a keyword not mapped is read where the standard puts it). Nothing is
/// built in: a site configures what its modality sends.
#[derive(Debug, Clone, PartialEq)]
pub struct Mapping {
    /// A name for the logs and faults.
    pub name: String,
    /// The private SOP class UID.
    pub sop_class: String,
    /// One object per sweep or per view.
    pub layout: Layout,
    /// Keyword -> tag (top-level element; for the per-frame angle of a
    /// multi-frame object, one value per frame).
    pub tags: BTreeMap<String, Tag>,
    /// Private creator elements that must hold these values (so a mapped
    /// private tag is the vendor's, not another block's).
    pub creators: BTreeMap<Tag, String>,
}

/// The attributes a [`Mapping`] may relocate.
pub const MAPPABLE: [&str; 15] = [
    "BodyPartThickness",
    "CompressionForce",
    "KVP",
    "ExposureInmAs",
    "ExposureInuAs",
    "ExposureTime",
    "XRaySourceIsocenterPrimaryAngle",
    "PositionerPrimaryAngle",
    "DistanceSourceToDetector",
    "DistanceSourceToIsocenter",
    "ImagerPixelSpacing",
    "ImageLaterality",
    "ViewPosition",
    "AnodeTargetMaterial",
    "FilterMaterial",
];

/// `(gggg,eeee)` or `gggg,eeee` (hexadecimal) as a tag.
pub fn parse_tag(s: &str) -> Option<Tag> {
    let t = s.trim().trim_start_matches('(').trim_end_matches(')');
    let (g, e) = t.split_once(',')?;
    let (g, e) = (g.trim(), e.trim());
    if g.len() != 4 || e.len() != 4 {
        return None;
    }
    Some(Tag(
        u16::from_str_radix(g, 16).ok()?,
        u16::from_str_radix(e, 16).ok()?,
    ))
}

impl Mapping {
    /// A mapping, refused naming the keyword not in [`MAPPABLE`], or a
    /// class that is a standard one.
    pub fn new(
        name: &str,
        sop_class: &str,
        layout: Layout,
        tags: BTreeMap<String, Tag>,
        creators: BTreeMap<Tag, String>,
    ) -> Result<Self, InputError> {
        if let Some(k) = tags.keys().find(|k| !MAPPABLE.contains(&k.as_str())) {
            return Err(attr(
                "mapping",
                format!("{k:?} is not an attribute the input reads (one of {MAPPABLE:?})"),
            ));
        }
        if [BPXR_FOR_PROCESSING_CLASS, DM_FOR_PROCESSING_CLASS].contains(&sop_class)
            || !sop_class
                .split('.')
                .all(|c| !c.is_empty() && c.bytes().all(|b| b.is_ascii_digit()))
        {
            return Err(attr(
                "mapping",
                format!("{sop_class:?} is not a private SOP class UID"),
            ));
        }
        Ok(Self {
            name: name.into(),
            sop_class: sop_class.into(),
            layout,
            tags,
            creators,
        })
    }
}

/// What the input reads from one object: a whole sweep (multi-frame), or
/// one view (then `angles_deg` has one angle and `counts` one frame).
#[derive(Debug, Clone, PartialEq)]
pub struct ReceivedProjections {
    /// The object's SOP class.
    pub sop_class: String,
    /// One object per sweep or per view.
    pub layout: Layout,
    /// Patient, study and laterality (the object's own series and instance
    /// as the source series and the one source instance).
    pub header: Header,
    /// SOP instance UID of the object.
    pub sop_instance: String,
    /// The view (View Position, else the View Code's meaning; may be empty).
    pub view: String,
    /// Instance Number, if any.
    pub instance_number: Option<i64>,
    /// Detector rows and columns.
    pub rows: usize,
    /// See `rows`.
    pub columns: usize,
    /// Imager pixel spacing (rows, columns), mm.
    pub pixel_spacing_mm: [f64; 2],
    /// Source angle of each frame, degrees.
    pub angles_deg: Vec<f64>,
    /// Source to detector, mm.
    pub source_to_detector_mm: f64,
    /// Source to isocentre, mm (absent from DM objects).
    pub source_to_isocenter_mm: Option<f64>,
    /// Body Part Thickness, mm.
    pub thickness_mm: f64,
    /// Compression Force, N.
    pub compression_force_n: Option<f64>,
    /// KVP.
    pub kvp: f64,
    /// Exposure of the object (the sweep, or the view), mAs.
    pub exposure_mas: f64,
    /// Exposure time of each view, ms.
    pub exposure_ms_per_view: Option<f64>,
    /// Anode Target Material, as sent.
    pub anode: Option<String>,
    /// Filter Material, as sent.
    pub filter: Option<String>,
    /// Counts, frame-major (`frames x rows x columns`).
    pub counts: Vec<u16>,
}

/// Why an object is not usable input.
#[derive(Debug, thiserror::Error)]
pub enum InputError {
    /// Not a DICOM object, truncated, or a length beyond the file.
    #[error("not a readable DICOM object: {0}")]
    Unreadable(String),
    /// Another SOP class than those accepted.
    #[error("SOP class {0} is not one the input reads (Breast Projection X-Ray Image - For Processing {BPXR_FOR_PROCESSING_CLASS}, Digital Mammography X-Ray Image - For Processing {DM_FOR_PROCESSING_CLASS}, or a configured private class)")]
    Class(String),
    /// A required attribute is missing or malformed.
    #[error("{attribute}: {reason}")]
    Attribute {
        /// The attribute's keyword.
        attribute: &'static str,
        /// What is wrong.
        reason: String,
    },
}

pub(crate) fn attr(attribute: &'static str, reason: impl Into<String>) -> InputError {
    InputError::Attribute {
        attribute,
        reason: reason.into(),
    }
}

/// The For Presentation classes of the same images: named in the refusal,
/// since a site that sends everything will send these too.
const FOR_PRESENTATION: [(&str, &str); 3] = [
    (
        "1.2.840.10008.5.1.4.1.1.13.1.4",
        "Breast Projection X-Ray Image - For Presentation",
    ),
    (
        "1.2.840.10008.5.1.4.1.1.1.2",
        "Digital Mammography X-Ray Image - For Presentation",
    ),
    (
        "1.2.840.10008.5.1.4.1.1.13.1.3",
        "Breast Tomosynthesis Image (a reconstructed volume)",
    ),
];

/// The For Presentation classes the input accepts on an association only to
/// refuse each object with a reason (see [`read_input_object`]).
pub fn for_presentation_classes() -> impl Iterator<Item = &'static str> {
    FOR_PRESENTATION.iter().map(|(c, _)| *c)
}

/// An element's value as text: its string form, or for an element read as
/// UN (a private tag in implicit VR), its bytes as ASCII.
fn element_text(e: &dicom_object::mem::InMemElement) -> Option<String> {
    let s = if e.vr() == VR::UN {
        e.to_bytes()
            .ok()
            .map(|b| String::from_utf8_lossy(&b).into_owned())
    } else {
        e.to_str().ok().map(|s| s.into_owned())
    }?;
    Some(s.trim_end_matches(['\0', ' ']).trim().to_string())
}

/// An element's numbers (DS/IS text, FL/FD/US/SS binary, or UN text).
fn element_numbers(e: &dicom_object::mem::InMemElement) -> Result<Vec<f64>, String> {
    if e.vr() == VR::UN {
        let t = element_text(e).ok_or("unreadable")?;
        return t
            .split('\\')
            .map(|v| v.trim().parse::<f64>().map_err(|_| format!("{v:?}")))
            .collect();
    }
    e.to_multi_float64().map_err(|e| e.to_string())
}

/// Reads values where the standard or the mapping puts them.
struct Source<'a> {
    o: &'a InMemDicomObject,
    map: Option<&'a Mapping>,
}

impl Source<'_> {
    fn tag(&self, keyword: &str, standard: Tag) -> Tag {
        self.map
            .and_then(|m| m.tags.get(keyword).copied())
            .unwrap_or(standard)
    }

    fn mapped(&self, keyword: &str) -> bool {
        self.map.is_some_and(|m| m.tags.contains_key(keyword))
    }

    fn text(&self, keyword: &'static str, t: Tag) -> Result<String, InputError> {
        let e = self
            .o
            .element(self.tag(keyword, t))
            .map_err(|_| attr(keyword, "missing"))?;
        element_text(e).ok_or_else(|| attr(keyword, "not text"))
    }

    fn opt_text(&self, keyword: &'static str, t: Tag) -> Option<String> {
        self.text(keyword, t).ok().filter(|s| !s.is_empty())
    }

    fn numbers(&self, keyword: &'static str, t: Tag) -> Result<Vec<f64>, InputError> {
        let e = self
            .o
            .element(self.tag(keyword, t))
            .map_err(|_| attr(keyword, "missing"))?;
        let v = element_numbers(e).map_err(|r| attr(keyword, r))?;
        if v.is_empty() {
            return Err(attr(keyword, "empty"));
        }
        if let Some(x) = v.iter().find(|x| !x.is_finite()) {
            return Err(attr(keyword, format!("{x} is not finite")));
        }
        Ok(v)
    }

    fn num(&self, keyword: &'static str, t: Tag) -> Result<f64, InputError> {
        Ok(self.numbers(keyword, t)?[0])
    }

    fn opt_num(&self, keyword: &'static str, t: Tag) -> Result<Option<f64>, InputError> {
        match self.o.element(self.tag(keyword, t)) {
            Err(_) => Ok(None),
            Ok(e) if e.is_empty() => Ok(None),
            Ok(_) => self.num(keyword, t).map(Some),
        }
    }
}

fn items(
    o: &InMemDicomObject,
    t: Tag,
    name: &'static str,
) -> Result<Vec<InMemDicomObject>, InputError> {
    Ok(o.element(t)
        .map_err(|_| attr(name, "missing"))?
        .items()
        .ok_or_else(|| attr(name, "not a sequence"))?
        .to_vec())
}

fn first(o: &InMemDicomObject, t: Tag, name: &'static str) -> Result<InMemDicomObject, InputError> {
    items(o, t, name)?
        .into_iter()
        .next()
        .ok_or_else(|| attr(name, "empty"))
}

fn laterality(v: Option<String>, name: &'static str) -> Result<Laterality, InputError> {
    [Laterality::Left, Laterality::Right]
        .into_iter()
        .find(|l| v.as_deref() == Some(l.letter()))
        .ok_or_else(|| attr(name, format!("{v:?}, expected L or R")))
}

/// Read a received object: a Breast Projection X-Ray or Digital Mammography
/// X-Ray For Processing object, or one of the `private` classes. Refused,
/// naming the attribute, when it is another class (For Presentation
/// named as such), lacks the thickness, technique or geometry, or its
/// pixel data disagree with its rows, columns and frames.
pub fn read_input_object(
    bytes: &[u8],
    private: &[Mapping],
) -> Result<ReceivedProjections, InputError> {
    crate::bounds::check_lengths(bytes).map_err(|e| InputError::Unreadable(e.to_string()))?;
    let o = dicom_object::from_reader(bytes).map_err(|e| InputError::Unreadable(e.to_string()))?;
    let plain = Source { o: &o, map: None };
    let class = plain.text("SOPClassUID", tags::SOP_CLASS_UID)?;
    if let Some((_, name)) = FOR_PRESENTATION.iter().find(|(c, _)| *c == class) {
        return Err(attr(
            "SOPClassUID",
            format!("{class} is {name}: processed for display, its counts are no longer the detector's; send the For Processing images"),
        ));
    }
    let map = private.iter().find(|m| m.sop_class == class);
    let layout = match (class.as_str(), map) {
        (BPXR_FOR_PROCESSING_CLASS, _) => Layout::MultiFrame,
        (DM_FOR_PROCESSING_CLASS, _) => Layout::PerView,
        (_, Some(m)) => m.layout,
        _ => return Err(InputError::Class(class)),
    };
    if let Some(m) = map {
        for (t, want) in &m.creators {
            let got = o.element(*t).ok().and_then(element_text);
            if got.as_deref() != Some(want.as_str()) {
                return Err(attr(
                    "PrivateCreator",
                    format!(
                        "({:04X},{:04X}) is {got:?}, the mapping {:?} expects {want:?}",
                        t.0, t.1, m.name
                    ),
                ));
            }
        }
    }
    let src = Source { o: &o, map };
    // A private object may omit the intent; a standard one may not.
    let intent = if map.is_some() {
        plain.opt_text("PresentationIntentType", tags::PRESENTATION_INTENT_TYPE)
    } else {
        Some(plain.text("PresentationIntentType", tags::PRESENTATION_INTENT_TYPE)?)
    };
    if let Some(intent) = intent.filter(|i| i != "FOR PROCESSING") {
        return Err(attr(
            "PresentationIntentType",
            format!("{intent:?}, not FOR PROCESSING"),
        ));
    }
    let rows = plain.num("Rows", tags::ROWS)? as usize;
    let columns = plain.num("Columns", tags::COLUMNS)? as usize;
    let frames = match plain.opt_num("NumberOfFrames", tags::NUMBER_OF_FRAMES)? {
        Some(f) => f as usize,
        None if layout == Layout::PerView => 1,
        None => return Err(attr("NumberOfFrames", "missing")),
    };
    if layout == Layout::PerView && frames != 1 {
        return Err(attr(
            "NumberOfFrames",
            format!("{frames}: an object per view has one frame"),
        ));
    }
    for (name, t, want) in [
        ("BitsAllocated", tags::BITS_ALLOCATED, 16.0),
        ("PixelRepresentation", tags::PIXEL_REPRESENTATION, 0.0),
        ("SamplesPerPixel", tags::SAMPLES_PER_PIXEL, 1.0),
    ] {
        let v = plain.num(name, t)?;
        if v != want {
            return Err(attr(name, format!("{v}, expected {want}")));
        }
    }
    let counts = o
        .element(tags::PIXEL_DATA)
        .map_err(|_| attr("PixelData", "missing"))?
        .to_multi_int::<u16>()
        .map_err(|e| attr("PixelData", e.to_string()))?;
    let want = frames * rows * columns;
    if counts.len() != want || want == 0 {
        return Err(attr(
            "PixelData",
            format!(
                "{} values for {frames} frames of {rows} x {columns} ({want})",
                counts.len()
            ),
        ));
    }
    let study_uid = plain.text("StudyInstanceUID", tags::STUDY_INSTANCE_UID)?;
    let sop_instance = plain.text("SOPInstanceUID", tags::SOP_INSTANCE_UID)?;
    let view = src
        .opt_text("ViewPosition", tags::VIEW_POSITION)
        .or_else(|| {
            first(&o, tags::VIEW_CODE_SEQUENCE, "ViewCodeSequence")
                .ok()
                .and_then(|c| {
                    Source { o: &c, map: None }.opt_text("CodeMeaning", tags::CODE_MEANING)
                })
        })
        .unwrap_or_default();
    let geometry = if layout == Layout::PerView {
        per_view_geometry(&src)?
    } else {
        multi_frame_geometry(&o, &src, frames)?
    };
    let exposure_mas = match src.opt_num("ExposureInmAs", tags::EXPOSURE_INM_AS)? {
        Some(v) => v,
        None => src.num("ExposureInuAs", tags::EXPOSURE_INU_AS)? / 1000.0,
    };
    let exposure_time = src.opt_num("ExposureTime", tags::EXPOSURE_TIME)?;
    let exposure_ms_per_view = match layout {
        Layout::PerView => exposure_time,
        // Exposure Time (in ms) of a multi-frame object is the sweep's.
        Layout::MultiFrame => match exposure_time {
            Some(t) => Some(t),
            None => plain.opt_num("ExposureTimeInms", tags::EXPOSURE_TIME_INMS)?,
        }
        .map(|t| t / frames as f64),
    };
    Ok(ReceivedProjections {
        sop_class: class.clone(),
        layout,
        header: Header {
            patient_name: plain
                .opt_text("PatientName", tags::PATIENT_NAME)
                .unwrap_or_default(),
            patient_id: plain.text("PatientID", tags::PATIENT_ID)?,
            patient_birth_date: plain
                .opt_text("PatientBirthDate", tags::PATIENT_BIRTH_DATE)
                .unwrap_or_default(),
            patient_sex: plain
                .opt_text("PatientSex", tags::PATIENT_SEX)
                .unwrap_or_default(),
            study_uid,
            study_date: plain
                .opt_text("StudyDate", tags::STUDY_DATE)
                .unwrap_or_default(),
            study_time: plain
                .opt_text("StudyTime", tags::STUDY_TIME)
                .unwrap_or_default(),
            study_id: plain
                .opt_text("StudyID", tags::STUDY_ID)
                .unwrap_or_default(),
            accession_number: plain
                .opt_text("AccessionNumber", tags::ACCESSION_NUMBER)
                .unwrap_or_default(),
            referring_physician: plain
                .opt_text("ReferringPhysicianName", tags::REFERRING_PHYSICIAN_NAME)
                .unwrap_or_default(),
            laterality: geometry.laterality,
            source_series_uid: plain.text("SeriesInstanceUID", tags::SERIES_INSTANCE_UID)?,
            source_instance_uids: vec![sop_instance.clone()],
            source_class: class.clone(),
        },
        sop_instance,
        view,
        instance_number: plain
            .opt_num("InstanceNumber", tags::INSTANCE_NUMBER)
            .ok()
            .flatten()
            .map(|v| v as i64),
        rows,
        columns,
        pixel_spacing_mm: geometry.spacing,
        angles_deg: geometry.angles,
        source_to_detector_mm: geometry.sdd,
        source_to_isocenter_mm: geometry.sid,
        thickness_mm: src.num("BodyPartThickness", tags::BODY_PART_THICKNESS)?,
        compression_force_n: src.opt_num("CompressionForce", tags::COMPRESSION_FORCE)?,
        kvp: src.num("KVP", tags::KVP)?,
        exposure_mas,
        exposure_ms_per_view,
        anode: src.opt_text("AnodeTargetMaterial", tags::ANODE_TARGET_MATERIAL),
        // Top level (the DM IOD), else the X-Ray Filter Macro of a
        // multi-frame object's functional groups.
        filter: match src.opt_text("FilterMaterial", tags::FILTER_MATERIAL) {
            Some(f) => Some(f),
            None => frame_filter(&o)?,
        },
        counts,
    })
}

/// The Filter Material of a multi-frame object's X-Ray Filter Macro, each
/// frame's (per frame, else shared): `None` where no frame states one; the
/// frames stating different materials, or some none, is refused.
fn frame_filter(o: &InMemDicomObject) -> Result<Option<String>, InputError> {
    let shared = first(
        o,
        tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE,
        "SharedFunctionalGroupsSequence",
    )
    .ok();
    let per_frame = items(
        o,
        tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE,
        "PerFrameFunctionalGroupsSequence",
    )
    .unwrap_or_default();
    let material = |g: &InMemDicomObject| {
        first(g, tags::X_RAY_FILTER_SEQUENCE, "XRayFilterSequence")
            .ok()
            .and_then(|f| {
                Source { o: &f, map: None }.opt_text("FilterMaterial", tags::FILTER_MATERIAL)
            })
    };
    let from_shared = shared.as_ref().and_then(material);
    if per_frame.is_empty() {
        return Ok(from_shared);
    }
    let frames: Vec<Option<String>> = per_frame
        .iter()
        .map(|g| material(g).or_else(|| from_shared.clone()))
        .collect();
    match frames.iter().position(|f| *f != frames[0]) {
        None => Ok(frames[0].clone()),
        Some(k) => Err(attr(
            "FilterMaterial",
            format!(
                "frame {} states {:?}, frame 1 {:?}: one sweep, one filter",
                k + 1,
                frames[k],
                frames[0]
            ),
        )),
    }
}

struct Geometry {
    angles: Vec<f64>,
    sdd: f64,
    sid: Option<f64>,
    spacing: [f64; 2],
    laterality: Laterality,
}

fn spacing(v: Vec<f64>) -> Result<[f64; 2], InputError> {
    if v.len() != 2 || v.iter().any(|x| *x <= 0.0) {
        return Err(attr("ImagerPixelSpacing", format!("{v:?}")));
    }
    Ok([v[0], v[1]])
}

/// A DM (or per-view private) object: the DX Positioning and Detector
/// attributes at the top level.
fn per_view_geometry(src: &Source<'_>) -> Result<Geometry, InputError> {
    Ok(Geometry {
        angles: vec![src.num("PositionerPrimaryAngle", tags::POSITIONER_PRIMARY_ANGLE)?],
        sdd: src.num(
            "DistanceSourceToDetector",
            tags::DISTANCE_SOURCE_TO_DETECTOR,
        )?,
        sid: src.opt_num(
            "DistanceSourceToIsocenter",
            tags::DISTANCE_SOURCE_TO_ISOCENTER,
        )?,
        spacing: spacing(src.numbers("ImagerPixelSpacing", tags::IMAGER_PIXEL_SPACING)?)?,
        laterality: laterality(
            src.opt_text("ImageLaterality", tags::IMAGE_LATERALITY),
            "ImageLaterality",
        )?,
    })
}

/// A multi-frame object: the functional groups (per frame, else shared),
/// or the mapped top-level tags of a private one.
fn multi_frame_geometry(
    o: &InMemDicomObject,
    src: &Source<'_>,
    frames: usize,
) -> Result<Geometry, InputError> {
    let fg = || -> Result<(InMemDicomObject, Vec<InMemDicomObject>), InputError> {
        let shared = first(
            o,
            tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE,
            "SharedFunctionalGroupsSequence",
        )?;
        let per_frame = items(
            o,
            tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE,
            "PerFrameFunctionalGroupsSequence",
        )?;
        if per_frame.len() != frames {
            return Err(attr(
                "PerFrameFunctionalGroupsSequence",
                format!("{} items for {frames} frames", per_frame.len()),
            ));
        }
        Ok((shared, per_frame))
    };
    // A macro's item in frame k's group, else in the shared one.
    let group = |fg: &(InMemDicomObject, Vec<InMemDicomObject>), k: usize, t, name| {
        first(&fg.1[k], t, name).or_else(|_| first(&fg.0, t, name))
    };
    let num_in =
        |o: &InMemDicomObject, keyword: &'static str, t| Source { o, map: None }.num(keyword, t);
    let angles = if src.mapped("XRaySourceIsocenterPrimaryAngle") {
        let v = src.numbers(
            "XRaySourceIsocenterPrimaryAngle",
            tags::X_RAY_SOURCE_ISOCENTER_PRIMARY_ANGLE,
        )?;
        if v.len() != frames {
            return Err(attr(
                "XRaySourceIsocenterPrimaryAngle",
                format!("{} values for {frames} frames", v.len()),
            ));
        }
        v
    } else {
        let fg = fg()?;
        (0..frames)
            .map(|k| {
                let iso = group(
                    &fg,
                    k,
                    tags::ISOCENTER_REFERENCE_SYSTEM_SEQUENCE,
                    "IsocenterReferenceSystemSequence",
                )?;
                num_in(
                    &iso,
                    "XRaySourceIsocenterPrimaryAngle",
                    tags::X_RAY_SOURCE_ISOCENTER_PRIMARY_ANGLE,
                )
            })
            .collect::<Result<Vec<_>, _>>()?
    };
    // Each remaining value: the mapped tag, else its functional group.
    let geometry_item = || {
        fg().and_then(|fg| {
            group(
                &fg,
                0,
                tags::X_RAY_GEOMETRY_SEQUENCE,
                "XRayGeometrySequence",
            )
        })
    };
    let sdd = if src.mapped("DistanceSourceToDetector") {
        src.num(
            "DistanceSourceToDetector",
            tags::DISTANCE_SOURCE_TO_DETECTOR,
        )?
    } else {
        num_in(
            &geometry_item()?,
            "DistanceSourceToDetector",
            tags::DISTANCE_SOURCE_TO_DETECTOR,
        )?
    };
    let sid = if src.mapped("DistanceSourceToIsocenter") {
        src.num(
            "DistanceSourceToIsocenter",
            tags::DISTANCE_SOURCE_TO_ISOCENTER,
        )?
    } else {
        num_in(
            &geometry_item()?,
            "DistanceSourceToIsocenter",
            tags::DISTANCE_SOURCE_TO_ISOCENTER,
        )?
    };
    let spacing = spacing(if src.mapped("ImagerPixelSpacing") {
        src.numbers("ImagerPixelSpacing", tags::IMAGER_PIXEL_SPACING)?
    } else {
        let fg = fg()?;
        let props = group(
            &fg,
            0,
            tags::FRAME_PIXEL_DATA_PROPERTIES_SEQUENCE,
            "FramePixelDataPropertiesSequence",
        )?;
        Source {
            o: &props,
            map: None,
        }
        .numbers("ImagerPixelSpacing", tags::IMAGER_PIXEL_SPACING)?
    })?;
    let laterality = if src.mapped("ImageLaterality") {
        laterality(
            src.opt_text("ImageLaterality", tags::IMAGE_LATERALITY),
            "ImageLaterality",
        )?
    } else {
        let fg = fg()?;
        let anat = group(&fg, 0, tags::FRAME_ANATOMY_SEQUENCE, "FrameAnatomySequence")?;
        laterality(
            Source {
                o: &anat,
                map: None,
            }
            .opt_text("FrameLaterality", tags::FRAME_LATERALITY),
            "FrameLaterality",
        )?
    };
    Ok(Geometry {
        angles,
        sdd,
        sid: Some(sid),
        spacing,
        laterality,
    })
}
