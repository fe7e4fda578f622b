//! The two reports. Codes are DICOM (DCM), SNOMED CT (SCT), UCUM, and our
//! private scheme `99DBTOR` where DICOM has no concept (model-breast dose,
//! statistical uncertainty, volumes), as PS3.16 allows for local codes.

use crate::content::{Code, Item, Rel};
use crate::DicomError;
use dicom_core::value::DataSetSequence;
use dicom_core::{DataElement, VR};
use dicom_dictionary_std::{tags, uids};
use dicom_object::{FileMetaTableBuilder, InMemDicomObject};

/// X-Ray Radiation Dose SR Storage.
pub const DOSE_SR_CLASS: &str = "1.2.840.10008.5.1.4.1.1.88.67";
/// Comprehensive SR Storage.
pub const COMPREHENSIVE_SR_CLASS: &str = "1.2.840.10008.5.1.4.1.1.88.33";
/// Breast Projection X-Ray Image Storage - For Processing: the class of the
/// source projections the reports reference as evidence (raw counts, one
/// per view; Breast Tomosynthesis Image Storage, 1.2.840.10008.5.1.4.1.1.13.1.3,
/// is a reconstructed volume, which we never receive).
pub const BREAST_PROJECTION_FOR_PROCESSING_CLASS: &str = "1.2.840.10008.5.1.4.1.1.13.1.5";
/// Digital Mammography X-Ray Image Storage - For Processing (one view per
/// object; `crate::dm` writes them, `crate::input` reads them).
pub const DM_FOR_PROCESSING_CLASS: &str = "1.2.840.10008.5.1.4.1.1.1.2.1";
/// Our private coding scheme.
pub const PRIVATE_SCHEME: &str = "99DBTOR";

/// Which breast.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Laterality {
    /// Left.
    Left,
    /// Right.
    Right,
}

impl Laterality {
    /// The DICOM code string of the side (Image / Frame Laterality): `L` or
    /// `R`.
    pub fn letter(self) -> &'static str {
        match self {
            Laterality::Left => "L",
            Laterality::Right => "R",
        }
    }

    /// CID 244 "Laterality": the image's side (the density report, the
    /// irradiation event's target region).
    fn code(self) -> Code {
        match self {
            Laterality::Left => Code::new("7771000", "SCT", "Left"),
            Laterality::Right => Code::new("24028007", "SCT", "Right"),
        }
    }

    /// CID 6022 "Side" (which includes CID 6023, BI-RADS side): the value set
    /// TID 10005 names for the laterality of the Accumulated Average
    /// Glandular Dose.
    fn breast(self) -> Code {
        match self {
            Laterality::Left => Code::new("80248007", "SCT", "Left breast"),
            Laterality::Right => Code::new("73056007", "SCT", "Right breast"),
        }
    }
}

/// The dose SR's Reference Point Definition: where the Entrance Exposure
/// at RP (incident air kerma) is (`dbt_dose::patient`'s normalisation).
pub const REFERENCE_POINT: &str = "Incident air kerma free in air (no backscatter) on the upper surface of the compressed breast, 60 mm from the chest wall, for the 0 degree view";

/// The intent of the reported procedure (TID 10001 row 3 "Has Intent",
/// CID 3629 "Procedure Intent").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProcedureIntent {
    /// Diagnostic Intent (261004008, SCT).
    Diagnostic,
    /// Screening Intent (360156006, SCT).
    Screening,
}

impl ProcedureIntent {
    fn code(self) -> Code {
        match self {
            ProcedureIntent::Diagnostic => Code::new("261004008", "SCT", "Diagnostic Intent"),
            ProcedureIntent::Screening => Code::new("360156006", "SCT", "Screening Intent"),
        }
    }
}

/// Patient, study and source attributes, from the acquisition header.
#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    /// Patient's name (PN, `Family^Given`).
    pub patient_name: String,
    /// Patient ID.
    pub patient_id: String,
    /// Birth date `YYYYMMDD` or empty.
    pub patient_birth_date: String,
    /// `F`, `M`, `O` or empty.
    pub patient_sex: String,
    /// Study Instance UID of the acquisition.
    pub study_uid: String,
    /// Study date `YYYYMMDD`.
    pub study_date: String,
    /// Study time `HHMMSS`.
    pub study_time: String,
    /// Study ID (may be empty).
    pub study_id: String,
    /// Accession number (may be empty).
    pub accession_number: String,
    /// Referring physician (may be empty).
    pub referring_physician: String,
    /// Breast.
    pub laterality: Laterality,
    /// Series Instance UID of the projections.
    pub source_series_uid: String,
    /// SOP Instance UIDs of the projections.
    pub source_instance_uids: Vec<String>,
    /// Their SOP class (Breast Projection X-Ray For Processing, or Digital
    /// Mammography X-Ray For Processing when the views came one by one).
    pub source_class: String,
}

/// The reporting device.
#[derive(Debug, Clone, PartialEq)]
pub struct Equipment {
    /// Manufacturer.
    pub manufacturer: String,
    /// Model name.
    pub model: String,
    /// Device serial number.
    pub serial: String,
    /// Software version.
    pub software_version: String,
    /// Device Observer UID.
    pub device_uid: String,
}

/// New UIDs under a configurable root: `<root>.<seed>.<counter>`. The seed
/// comes from the adapter (e.g. the time in microseconds), so the domain code
/// stays deterministic.
#[derive(Debug, Clone)]
pub struct UidSource {
    root: String,
    seed: u64,
    counter: u64,
}

fn valid_uid(u: &str) -> bool {
    !u.is_empty()
        && u.len() <= 64
        && u.split('.').all(|c| {
            !c.is_empty()
                && c.chars().all(|ch| ch.is_ascii_digit())
                && (c == "0" || !c.starts_with('0'))
        })
}

impl UidSource {
    /// A source under `root` (digits and dots, at most 40 characters).
    pub fn new(root: &str, seed: u64) -> Result<Self, DicomError> {
        if !valid_uid(root) || root.len() > 40 {
            return Err(DicomError::Field {
                field: "uid_root",
                reason: format!("`{root}` is not a UID root of at most 40 characters"),
            });
        }
        Ok(Self {
            root: root.into(),
            seed,
            counter: 0,
        })
    }

    /// The next UID.
    pub fn next_uid(&mut self) -> String {
        self.counter += 1;
        format!("{}.{}.{}", self.root, self.seed, self.counter)
    }
}

/// How a report's figures were made (issue #51 point 3), named in both
/// reports.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ReportMethod {
    /// A DBToR reconstruction, tissue-classified: the glandularity read
    /// from it (cross-checked against the physics-based density), the AGD
    /// patient-specific on it.
    #[default]
    Reconstruction,
    /// No DBToR model is trained and calibrated for the gantry and beam
    /// (`recon.reconstructor = "physics"`, or `recon.uncalibrated_beam`):
    /// the physics-based density
    /// of the projections is the glandularity (its own consistency checks
    /// stated; no composition category: nothing cross-checks it), and the
    /// AGD is the model breast's (the
    /// breast's outline and thickness from its projections, an interior at
    /// that glandularity under the nominal skin) on the gantry's own
    /// geometry.
    PhysicsOnly,
}

impl ReportMethod {
    /// The method in a few words, for reports, logs and the status page.
    pub fn describe(self) -> &'static str {
        match self {
            ReportMethod::Reconstruction => "DBToR reconstruction",
            ReportMethod::PhysicsOnly => "physics-based density (no DBToR model trained and calibrated for this gantry and beam)",
        }
    }
}

/// One irradiation event (one projection).
#[derive(Debug, Clone, PartialEq)]
pub struct DoseEvent {
    /// Start of the arc of this projection, degrees.
    pub angle_start_deg: f64,
    /// End of the arc, degrees.
    pub angle_end_deg: f64,
    /// Tube voltage, kV.
    pub kvp: f64,
    /// Exposure, uAs.
    pub exposure_uas: f64,
    /// Exposure time, ms, when the acquisition gave it.
    pub exposure_ms: Option<f64>,
    /// Patient-specific Monte Carlo AGD of this projection, mGy.
    pub agd_mgy: f64,
    /// Incident air kerma at the reference point, mGy.
    pub entrance_kerma_mgy: f64,
    /// `YYYYMMDDHHMMSS` of the exposure.
    pub datetime: String,
}

/// Everything the dose report says.
#[derive(Debug, Clone, PartialEq)]
pub struct DoseInput {
    /// Patient and study.
    pub header: Header,
    /// The reporting device.
    pub equipment: Equipment,
    /// One per projection.
    pub events: Vec<DoseEvent>,
    /// Compressed breast thickness, mm.
    pub compression_mm: f64,
    /// Compression force, N, when the acquisition gave it.
    pub compression_force_n: Option<f64>,
    /// First HVL, mm Al.
    pub hvl_mm_al: f64,
    /// Anode target material.
    pub anode_material: crate::AnodeMaterial,
    /// Filter material.
    pub filter_material: crate::FilterMaterial,
    /// Filter thickness, mm.
    pub filter_mm: f64,
    /// Accumulated patient-specific AGD, mGy.
    pub accumulated_agd_mgy: f64,
    /// Relative statistical uncertainty of the accumulated AGD (1 s.d.).
    pub relative_uncertainty: f64,
    /// The model-breast (homogeneous) estimate, mGy.
    pub model_agd_mgy: f64,
    /// Where the density was not confirmed by the physics density: the
    /// model-breast estimate at the physics density's glandularity, mGy
    /// (issue #48 point 3; `None` when confirmed or without a physics
    /// density).
    pub model_agd_at_physics_mgy: Option<f64>,
    /// The accumulated AGD's 95 % interval, or why none is given.
    pub agd_interval: FigureInterval,
    /// Content date and time `YYYYMMDD`, `HHMMSS`.
    pub content_date: String,
    /// See `content_date`.
    pub content_time: String,
    /// The procedure's intent (TID 10001 "Has Intent").
    pub intent: ProcedureIntent,
    /// Source to isocentre (the rotation centre) and source to detector
    /// distances of the acquisition geometry, mm (TID 10003C rows 11a, 11c).
    pub source_distances_mm: [f64; 2],
    /// What exactly computed the dose (model, manifest SHA-256, precision,
    /// engine, calibration, software): in the report's Comment.
    pub algorithm_version: String,
    /// How the figures were made.
    pub method: ReportMethod,
}

/// Everything the density report says.
#[derive(Debug, Clone, PartialEq)]
pub struct DensityInput {
    /// Patient and study.
    pub header: Header,
    /// The reporting device.
    pub equipment: Equipment,
    /// Glandularity by mass, 0..1 (paper eq. 4).
    pub glandularity: f64,
    /// Fibroglandular volume, cm^3.
    pub fibroglandular_cm3: f64,
    /// Breast volume (skin included), cm^3.
    pub breast_cm3: f64,
    /// Reconstructor name (e.g. `DBToR int8`).
    pub reconstructor: String,
    /// Model version (manifest checksum or tag).
    pub model_version: String,
    /// The cross-check against the physics density of the same counts.
    pub check: DensityCheckReport,
    /// The glandularity's 95 % interval, or why none is given.
    pub glandularity_interval: FigureInterval,
    /// How the figures were made.
    pub method: ReportMethod,
    /// Content date and time.
    pub content_date: String,
    /// See `content_date`.
    pub content_time: String,
}

/// What the density report says of the cross-check against the physics
/// density (issue #48 point 3); the status file records the same.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DensityCheckReport {
    /// The physics-based glandularity by mass, 0..1, when one was made.
    pub physics_glandularity: Option<f64>,
    /// Whether the physics confirms the reported density: only then does
    /// the report assert a composition category.
    pub confirmed: bool,
    /// Why it does not (empty when confirmed).
    #[serde(default)]
    pub reasons: Vec<String>,
}

/// A 95 % interval of a reported figure (issue #48 point 4), or why none
/// is given; the status file records the same.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FigureInterval {
    /// Lower and upper limit (glandularity by mass 0..1; AGD mGy), when
    /// given.
    pub limits: Option<[f64; 2]>,
    /// What the interval rests on, or why none is given.
    pub basis: String,
}

impl FigureInterval {
    /// Checked as a report takes it: limits finite, ordered and within
    /// `lo..=hi`; a basis always (an interval says what it rests on, its
    /// absence why).
    fn check(&self, field: &'static str, lo: f64, hi: f64) -> Result<(), DicomError> {
        if let Some([a, b]) = self.limits {
            check(field, a, lo, hi)?;
            check(field, b, a, hi)?;
        }
        if self.basis.trim().is_empty() {
            return Err(DicomError::Field {
                field,
                reason: "an interval needs its basis, its absence the reason".into(),
            });
        }
        Ok(())
    }

    /// `lo-hi` in the report's unit (`scale` times the limits, `decimals`
    /// places), or `None`.
    pub fn describe(&self, scale: f64, decimals: usize) -> Option<String> {
        self.limits
            .map(|[a, b]| format!("{:.*}-{:.*}", decimals, scale * a, decimals, scale * b))
    }
}

/// A built report: the dataset and its identity.
pub struct Report {
    /// SOP Class UID.
    pub sop_class: &'static str,
    /// SOP Instance UID.
    pub sop_instance: String,
    obj: InMemDicomObject,
}

impl Report {
    /// The DICOM Part 10 file (explicit VR little endian).
    pub fn to_bytes(&self) -> Result<Vec<u8>, DicomError> {
        let file = self
            .obj
            .clone()
            .with_meta(
                FileMetaTableBuilder::new()
                    .transfer_syntax(uids::EXPLICIT_VR_LITTLE_ENDIAN)
                    .implementation_class_uid("1.2.826.0.1.3680043.10.543.1")
                    .implementation_version_name("DBTOR_0_1"),
            )
            .map_err(|e| DicomError::Encoding(e.to_string()))?;
        let mut out = Vec::new();
        file.write_all(&mut out)
            .map_err(|e| DicomError::Encoding(e.to_string()))?;
        Ok(out)
    }

    /// A report of `obj`, an object of `sop_class` built elsewhere in the crate.
    pub(crate) fn from_parts(
        sop_class: &'static str,
        sop_instance: String,
        obj: InMemDicomObject,
    ) -> Self {
        Self {
            sop_class,
            sop_instance,
            obj,
        }
    }

    /// The dataset (for tests that break it on purpose).
    pub fn dataset_mut(&mut self) -> &mut InMemDicomObject {
        &mut self.obj
    }
}

/// `HAS CONCEPT MOD (Laterality) = Left | Right`.
fn laterality_mod(l: Laterality) -> (Rel, Item) {
    (
        Rel::HasConceptMod,
        Item::Code(
            Code::new("272741003", "SCT", "Laterality"),
            l.code(),
            vec![],
        ),
    )
}

/// `HAS CONCEPT MOD (Acquisition Plane) = Single Plane`.
fn single_plane() -> (Rel, Item) {
    (
        Rel::HasConceptMod,
        Item::Code(
            dcm("113764", "Acquisition Plane"),
            dcm("113622", "Single Plane"),
            vec![],
        ),
    )
}

fn dcm(v: &str, m: &str) -> Code {
    Code::new(v, "DCM", m)
}

fn private(v: &str, m: &str) -> Code {
    Code::new(v, PRIVATE_SCHEME, m)
}

/// A figure's 95 % interval as content items: its limits (`scale` times
/// the interval's, in `unit`) where given, and always the basis or the
/// reason there is none.
fn interval_items(
    iv: &FigureInterval,
    lo: (&str, &str),
    hi: (&str, &str),
    basis: (&str, &str),
    scale: f64,
    unit: Code,
) -> Vec<(Rel, Item)> {
    let mut items = Vec::new();
    if let Some([a, b]) = iv.limits {
        for ((v, m), x) in [(lo, a), (hi, b)] {
            items.push((
                Rel::Contains,
                Item::Num(private(v, m), scale * x, unit.clone(), vec![]),
            ));
        }
    }
    items.push((
        Rel::Contains,
        Item::Text(
            private(basis.0, basis.1),
            if iv.limits.is_some() {
                iv.basis.clone()
            } else {
                format!("No 95 % interval is given: {}", iv.basis)
            },
        ),
    ));
    items
}

fn check(field: &'static str, v: f64, lo: f64, hi: f64) -> Result<(), DicomError> {
    if v.is_finite() && (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(DicomError::Field {
            field,
            reason: format!("{v} outside [{lo}, {hi}]"),
        })
    }
}

fn check_uid(field: &'static str, u: &str) -> Result<(), DicomError> {
    if valid_uid(u) {
        Ok(())
    } else {
        Err(DicomError::Field {
            field,
            reason: format!("`{u}` is not a valid UID"),
        })
    }
}

fn observer_context(eq: &Equipment) -> Vec<(Rel, Item)> {
    vec![
        (
            Rel::HasObsContext,
            Item::Code(
                dcm("121005", "Observer Type"),
                dcm("121007", "Device"),
                vec![],
            ),
        ),
        (
            Rel::HasObsContext,
            Item::UidRef(dcm("121012", "Device Observer UID"), eq.device_uid.clone()),
        ),
        (
            Rel::HasObsContext,
            Item::Text(dcm("121013", "Device Observer Name"), eq.model.clone()),
        ),
        (
            Rel::HasObsContext,
            Item::Text(
                dcm("121014", "Device Observer Manufacturer"),
                eq.manufacturer.clone(),
            ),
        ),
        (
            Rel::HasObsContext,
            Item::Text(
                dcm("121015", "Device Observer Model Name"),
                eq.model.clone(),
            ),
        ),
        (
            Rel::HasObsContext,
            Item::Text(
                dcm("121016", "Device Observer Serial Number"),
                eq.serial.clone(),
            ),
        ),
    ]
}

fn sq(items: Vec<InMemDicomObject>) -> DataSetSequence<InMemDicomObject> {
    DataSetSequence::from(items)
}

/// What distinguishes the documents in the shared header.
struct DocKind<'a> {
    class: &'static str,
    series_number: &'a str,
    content_date: &'a str,
    content_time: &'a str,
    template: &'a str,
}

/// The header modules shared by both reports.
fn base(
    kind: DocKind<'_>,
    h: &Header,
    eq: &Equipment,
    uids: &mut UidSource,
    root: &Item,
) -> Result<Report, DicomError> {
    check_uid("header.study_uid", &h.study_uid)?;
    check_uid("header.source_series_uid", &h.source_series_uid)?;
    check_uid("header.source_class", &h.source_class)?;
    for u in &h.source_instance_uids {
        check_uid("header.source_instance_uids", u)?;
    }
    for (field, v, max) in [
        ("header.accession_number", &h.accession_number, 16),
        ("header.study_id", &h.study_id, 16),
        ("header.patient_id", &h.patient_id, 64),
        ("header.patient_name", &h.patient_name, 64),
        ("equipment.manufacturer", &eq.manufacturer, 64),
        ("equipment.model", &eq.model, 64),
        ("equipment.serial", &eq.serial, 64),
        ("equipment.software_version", &eq.software_version, 64),
    ] {
        if v.chars().count() > max || v.contains('\\') {
            return Err(DicomError::Field {
                field,
                reason: format!("`{v}` is longer than {max} characters or holds a backslash"),
            });
        }
    }
    if h.patient_id.trim().is_empty() {
        return Err(DicomError::Field {
            field: "header.patient_id",
            reason: "empty".into(),
        });
    }
    let sop_instance = uids.next_uid();
    let series = uids.next_uid();
    let mut o = root.dataset(None);
    let s = |t, vr, v: &str| DataElement::new(t, vr, v.to_string());
    for e in [
        s(tags::SPECIFIC_CHARACTER_SET, VR::CS, "ISO_IR 192"),
        s(tags::SOP_CLASS_UID, VR::UI, kind.class),
        s(tags::SOP_INSTANCE_UID, VR::UI, &sop_instance),
        s(tags::STUDY_DATE, VR::DA, &h.study_date),
        s(tags::STUDY_TIME, VR::TM, &h.study_time),
        s(tags::CONTENT_DATE, VR::DA, kind.content_date),
        s(tags::CONTENT_TIME, VR::TM, kind.content_time),
        s(tags::ACCESSION_NUMBER, VR::SH, &h.accession_number),
        s(tags::MODALITY, VR::CS, "SR"),
        s(tags::MANUFACTURER, VR::LO, &eq.manufacturer),
        s(
            tags::REFERRING_PHYSICIAN_NAME,
            VR::PN,
            &h.referring_physician,
        ),
        s(tags::MANUFACTURER_MODEL_NAME, VR::LO, &eq.model),
        s(tags::PATIENT_NAME, VR::PN, &h.patient_name),
        s(tags::PATIENT_ID, VR::LO, &h.patient_id),
        s(tags::PATIENT_BIRTH_DATE, VR::DA, &h.patient_birth_date),
        s(tags::PATIENT_SEX, VR::CS, &h.patient_sex),
        s(tags::DEVICE_SERIAL_NUMBER, VR::LO, &eq.serial),
        s(tags::SOFTWARE_VERSIONS, VR::LO, &eq.software_version),
        s(tags::STUDY_INSTANCE_UID, VR::UI, &h.study_uid),
        s(tags::SERIES_INSTANCE_UID, VR::UI, &series),
        s(tags::STUDY_ID, VR::SH, &h.study_id),
        s(tags::SERIES_NUMBER, VR::IS, kind.series_number),
        s(tags::INSTANCE_NUMBER, VR::IS, "1"),
        s(tags::COMPLETION_FLAG, VR::CS, "COMPLETE"),
        s(tags::VERIFICATION_FLAG, VR::CS, "UNVERIFIED"),
    ] {
        o.put(e);
    }
    o.put(DataElement::new(
        tags::REFERENCED_PERFORMED_PROCEDURE_STEP_SEQUENCE,
        VR::SQ,
        sq(vec![]),
    ));
    o.put(DataElement::new(
        tags::PERFORMED_PROCEDURE_CODE_SEQUENCE,
        VR::SQ,
        sq(vec![]),
    ));
    // SOP Common: our private coding scheme, declared.
    o.put(DataElement::new(
        tags::CODING_SCHEME_IDENTIFICATION_SEQUENCE,
        VR::SQ,
        sq(vec![InMemDicomObject::from_element_iter([
            DataElement::new(tags::CODING_SCHEME_DESIGNATOR, VR::SH, PRIVATE_SCHEME),
            DataElement::new(tags::CODING_SCHEME_NAME, VR::ST, "DBToR private codes"),
            DataElement::new(
                tags::CODING_SCHEME_RESPONSIBLE_ORGANIZATION,
                VR::ST,
                "DBToR (docs/conformance.md)",
            ),
        ])]),
    ));
    o.put(DataElement::new(
        tags::CONTENT_TEMPLATE_SEQUENCE,
        VR::SQ,
        sq(vec![InMemDicomObject::from_element_iter([
            DataElement::new(tags::MAPPING_RESOURCE, VR::CS, "DCMR"),
            DataElement::new(tags::TEMPLATE_IDENTIFIER, VR::CS, kind.template),
        ])]),
    ));
    // Evidence: the projections this report was made from.
    let sops: Vec<InMemDicomObject> = h
        .source_instance_uids
        .iter()
        .map(|u| {
            InMemDicomObject::from_element_iter([
                DataElement::new(
                    tags::REFERENCED_SOP_CLASS_UID,
                    VR::UI,
                    h.source_class.as_str(),
                ),
                DataElement::new(tags::REFERENCED_SOP_INSTANCE_UID, VR::UI, u.as_str()),
            ])
        })
        .collect();
    if !sops.is_empty() {
        let series_item = InMemDicomObject::from_element_iter([
            DataElement::new(tags::REFERENCED_SOP_SEQUENCE, VR::SQ, sq(sops)),
            DataElement::new(
                tags::SERIES_INSTANCE_UID,
                VR::UI,
                h.source_series_uid.as_str(),
            ),
        ]);
        let study_item = InMemDicomObject::from_element_iter([
            DataElement::new(
                tags::REFERENCED_SERIES_SEQUENCE,
                VR::SQ,
                sq(vec![series_item]),
            ),
            DataElement::new(tags::STUDY_INSTANCE_UID, VR::UI, h.study_uid.as_str()),
        ]);
        o.put(DataElement::new(
            tags::CURRENT_REQUESTED_PROCEDURE_EVIDENCE_SEQUENCE,
            VR::SQ,
            sq(vec![study_item]),
        ));
    }
    Ok(Report {
        sop_class: kind.class,
        sop_instance,
        obj: o,
    })
}

fn mgy() -> Code {
    Code::ucum("mGy", "mGy")
}

/// Build the X-Ray Radiation Dose SR (TID 10001/10003/10005).
pub fn dose_report(input: &DoseInput, uids: &mut UidSource) -> Result<Report, DicomError> {
    check("compression_mm", input.compression_mm, 1.0, 200.0)?;
    if let Some(f) = input.compression_force_n {
        check("compression_force_n", f, 0.0, 500.0)?;
    }
    check("hvl_mm_al", input.hvl_mm_al, 0.05, 10.0)?;
    check(
        "accumulated_agd_mgy",
        input.accumulated_agd_mgy,
        0.0,
        1000.0,
    )?;
    check("model_agd_mgy", input.model_agd_mgy, 0.0, 1000.0)?;
    if let Some(m) = input.model_agd_at_physics_mgy {
        check("model_agd_at_physics_mgy", m, 0.0, 1000.0)?;
    }
    check(
        "source_distances_mm[0]",
        input.source_distances_mm[0],
        100.0,
        2000.0,
    )?;
    check(
        "source_distances_mm[1]",
        input.source_distances_mm[1],
        input.source_distances_mm[0],
        2000.0,
    )?;
    check("relative_uncertainty", input.relative_uncertainty, 0.0, 1.0)?;
    input.agd_interval.check("agd_interval", 0.0, 1000.0)?;
    if input.events.is_empty() {
        return Err(DicomError::Field {
            field: "events",
            reason: "at least one irradiation event is needed".into(),
        });
    }
    let h = &input.header;
    let breast = || Code::new("76752008", "SCT", "Breast");
    // TID 10001 rows 2-3: the procedure and its intent.
    let mut children = vec![(
        Rel::HasConceptMod,
        Item::Code(
            dcm("121058", "Procedure reported"),
            Code::new("71651007", "SCT", "Mammography"),
            vec![(
                Rel::HasConceptMod,
                Item::Code(
                    Code::new("363703001", "SCT", "Has Intent"),
                    input.intent.code(),
                    vec![],
                ),
            )],
        ),
    )];
    children.extend(observer_context(&input.equipment));
    // Row 6: the scope is observation context, not content.
    children.push((
        Rel::HasObsContext,
        Item::Code(
            dcm("113705", "Scope of Accumulation"),
            dcm("113014", "Study"),
            vec![(
                Rel::HasProperties,
                Item::UidRef(dcm("110180", "Study Instance UID"), h.study_uid.clone()),
            )],
        ),
    ));
    let at_physics = input.model_agd_at_physics_mgy.map_or(String::new(), |m| {
        format!(
            " The breast density was not confirmed by the physics-based density of the same \
             projections (see the density report): the model-breast estimate at the \
             physics-based glandularity is {} mGy.",
            crate::format_ds(m)
        )
    });
    let method = match input.method {
        ReportMethod::Reconstruction => format!(
            "Average glandular dose computed patient-specifically by Monte Carlo photon transport \
             (photoelectric, Rayleigh, Compton; validated against AAPM TG-195 case 3) on the \
             tissue-classified DBToR reconstruction of this breast; relative statistical \
             uncertainty {:.2} % (1 s.d., batch method). Model-breast (homogeneous, same \
             thickness and glandularity) estimate with the same engine: {} mGy.{at_physics} \
             Computed by: {}.",
            100.0 * input.relative_uncertainty,
            crate::format_ds(input.model_agd_mgy),
            input.algorithm_version
        ),
        ReportMethod::PhysicsOnly => format!(
            "No DBToR model is trained and calibrated for this gantry and beam: average glandular dose of the model breast \
             by Monte Carlo photon transport (photoelectric, Rayleigh, Compton; validated against \
             AAPM TG-195 case 3) on this gantry's geometry: the breast's outline and thickness from \
             its projections, its interior at the physics-based glandularity (see the density \
             report) under a 1.5 mm skin, the glandular tissue placed as stated below; not \
             patient-specific. Relative statistical \
             uncertainty {:.2} % (1 s.d., batch method). Computed by: {}.",
            100.0 * input.relative_uncertainty,
            input.algorithm_version
        ),
    };
    children.push((
        Rel::Contains,
        Item::Container(
            dcm("113702", "Accumulated X-Ray Dose Data"),
            vec![
                single_plane(),
                (
                    Rel::Contains,
                    Item::Num(
                        dcm("111637", "Accumulated Average Glandular Dose"),
                        input.accumulated_agd_mgy,
                        mgy(),
                        vec![(
                            Rel::HasConceptMod,
                            Item::Code(
                                Code::new("272741003", "SCT", "Laterality"),
                                h.laterality.breast(),
                                vec![],
                            ),
                        )],
                    ),
                ),
                (
                    Rel::Contains,
                    Item::Num(
                        private(
                            "AGDMODEL",
                            "Model-breast Accumulated Average Glandular Dose",
                        ),
                        input.model_agd_mgy,
                        mgy(),
                        vec![],
                    ),
                ),
                (
                    Rel::Contains,
                    Item::Num(
                        private("AGDUNC", "Relative statistical uncertainty of AGD"),
                        100.0 * input.relative_uncertainty,
                        Code::ucum("%", "Percent"),
                        vec![],
                    ),
                ),
            ]
            .into_iter()
            .chain(interval_items(
                &input.agd_interval,
                ("AGDLO95", "Accumulated AGD, 95 % interval, lower limit"),
                ("AGDHI95", "Accumulated AGD, 95 % interval, upper limit"),
                ("AGDINT95", "Accumulated AGD, 95 % interval, basis"),
                1.0,
                mgy(),
            ))
            .collect(),
        ),
    ));
    // Beside the patient's dose where the physics did not confirm the
    // density: the model breast at the physics density's glandularity
    // (issue #48 point 3), after the model breast at the reported one.
    if let Some(m) = input.model_agd_at_physics_mgy {
        if let Some((_, Item::Container(_, items))) = children.last_mut() {
            let at = items
                .iter()
                .position(|(_, it)| matches!(it, Item::Num(c, ..) if c.value == "AGDMODEL"))
                .map_or(items.len(), |i| i + 1);
            items.insert(
                at,
                (
                    Rel::Contains,
                    Item::Num(
                        private(
                            "AGDMODELPHYS",
                            "Model-breast AGD at the physics-based density",
                        ),
                        m,
                        mgy(),
                        vec![],
                    ),
                ),
            );
        }
    }
    for (i, ev) in input.events.iter().enumerate() {
        check("events.agd_mgy", ev.agd_mgy, 0.0, 1000.0)?;
        check("events.kvp", ev.kvp, 10.0, 60.0)?;
        let dt_ok = ev.datetime.len() >= 8
            && ev.datetime.len() <= 26
            && ev.datetime[..8].bytes().all(|b| b.is_ascii_digit());
        if !dt_ok {
            return Err(DicomError::Field {
                field: "events.datetime",
                reason: format!("`{}` is not a DICOM DT (YYYYMMDD[HHMMSS])", ev.datetime),
            });
        }
        if let Some(t) = ev.exposure_ms {
            check("events.exposure_ms", t, 0.0, 60_000.0)?;
        }
        let eu = uids.next_uid();
        let mut items = vec![
            single_plane(),
            (
                Rel::Contains,
                Item::UidRef(dcm("113769", "Irradiation Event UID"), eu),
            ),
            (
                Rel::Contains,
                Item::DateTime(dcm("111526", "DateTime Started"), ev.datetime.clone()),
            ),
            (
                Rel::Contains,
                Item::Code(
                    dcm("113721", "Irradiation Event Type"),
                    dcm("113613", "Rotational Acquisition"),
                    vec![],
                ),
            ),
            (
                Rel::Contains,
                Item::Text(
                    dcm("125203", "Acquisition Protocol"),
                    format!("DBT projection {} of {}", i + 1, input.events.len()),
                ),
            ),
            // TID 10003 rows 9-10: the anatomy and its laterality (CID 244);
            // row 17: the target region (no laterality of its own there).
            (
                Rel::Contains,
                Item::Code(
                    Code::new("91723000", "SCT", "Anatomical structure"),
                    breast(),
                    vec![laterality_mod(h.laterality)],
                ),
            ),
            (
                Rel::Contains,
                Item::Code(dcm("123014", "Target Region"), breast(), vec![]),
            ),
            (
                Rel::Contains,
                Item::Num(
                    dcm("111633", "Compression Thickness"),
                    input.compression_mm,
                    Code::ucum("mm", "mm"),
                    vec![],
                ),
            ),
            (
                Rel::Contains,
                Item::Num(
                    dcm("111631", "Average Glandular Dose"),
                    ev.agd_mgy,
                    mgy(),
                    vec![],
                ),
            ),
            (
                Rel::Contains,
                Item::Num(
                    dcm("111636", "Entrance Exposure at RP"),
                    ev.entrance_kerma_mgy,
                    mgy(),
                    vec![],
                ),
            ),
            // TID 10003 row 22 (required with row 21): where the kerma is.
            (
                Rel::Contains,
                Item::Text(
                    dcm("113780", "Reference Point Definition"),
                    REFERENCE_POINT.into(),
                ),
            ),
            (
                Rel::Contains,
                Item::Num(
                    dcm("112011", "Positioner Primary Angle"),
                    ev.angle_start_deg,
                    Code::ucum("deg", "degree"),
                    vec![],
                ),
            ),
            (
                Rel::Contains,
                Item::Num(
                    dcm("113739", "Positioner Primary End Angle"),
                    ev.angle_end_deg,
                    Code::ucum("deg", "degree"),
                    vec![],
                ),
            ),
            (
                Rel::Contains,
                Item::Num(dcm("113733", "KVP"), ev.kvp, Code::ucum("kV", "kV"), vec![]),
            ),
            (
                Rel::Contains,
                Item::Num(
                    dcm("113736", "Exposure"),
                    ev.exposure_uas,
                    Code::ucum("uA.s", "uAs"),
                    vec![],
                ),
            ),
            // TID 10003B row 7 (required without Fluoro Mode): one exposure
            // per projection.
            (
                Rel::Contains,
                Item::Num(
                    dcm("113768", "Number of Pulses"),
                    1.0,
                    Code::ucum("1", "no units"),
                    vec![],
                ),
            ),
            (
                Rel::Contains,
                Item::Num(
                    dcm("111634", "Half Value Layer"),
                    input.hvl_mm_al,
                    Code::ucum("mm", "mm"),
                    vec![],
                ),
            ),
            (
                Rel::Contains,
                Item::Code(
                    dcm("111632", "Anode Target Material"),
                    // CID 10016.
                    input.anode_material.code(),
                    vec![],
                ),
            ),
            (
                Rel::Contains,
                Item::Container(
                    dcm("113771", "X-Ray Filters"),
                    vec![
                        (
                            Rel::Contains,
                            Item::Code(
                                dcm("113772", "X-Ray Filter Type"),
                                dcm("113653", "Flat filter"),
                                vec![],
                            ),
                        ),
                        (
                            Rel::Contains,
                            Item::Code(
                                dcm("113757", "X-Ray Filter Material"),
                                // CID 10006.
                                input.filter_material.code(),
                                vec![],
                            ),
                        ),
                        (
                            Rel::Contains,
                            Item::Num(
                                dcm("113758", "X-Ray Filter Thickness Minimum"),
                                input.filter_mm,
                                Code::ucum("mm", "mm"),
                                vec![],
                            ),
                        ),
                        (
                            Rel::Contains,
                            Item::Num(
                                dcm("113773", "X-Ray Filter Thickness Maximum"),
                                input.filter_mm,
                                Code::ucum("mm", "mm"),
                                vec![],
                            ),
                        ),
                    ],
                ),
            ),
        ];
        // What the acquisition gave beyond the technique: the compression
        // force (TID 10003 row 25a, after the thickness) and the exposure
        // time (TID 10003B, after the exposure); absent rows are omitted,
        // not written as zero.
        let after = |items: &[(Rel, Item)], code: &str| {
            items
                .iter()
                .position(|(_, it)| matches!(it, Item::Num(c, ..) if c.value == code))
                .map_or(items.len(), |i| i + 1)
        };
        if let Some(f) = input.compression_force_n {
            let at = after(&items, "111633");
            items.insert(
                at,
                (
                    Rel::Contains,
                    Item::Num(
                        dcm("111647", "Compression Force"),
                        f,
                        Code::ucum("N", "N"),
                        vec![],
                    ),
                ),
            );
        }
        if let Some(t) = ev.exposure_ms {
            let at = after(&items, "113736");
            items.insert(
                at,
                (
                    Rel::Contains,
                    Item::Num(
                        dcm("113824", "Exposure Time"),
                        t,
                        Code::ucum("ms", "ms"),
                        vec![],
                    ),
                ),
            );
        }
        children.push((
            Rel::Contains,
            Item::Container(dcm("113706", "Irradiation Event X-Ray Data"), items),
        ));
    }
    // Row 15: how the dose was computed, and by what exactly.
    children.push((Rel::Contains, Item::Text(dcm("121106", "Comment"), method)));
    // Row 18 (CID 10020): the dose is calculated by this system (Monte
    // Carlo on the reconstructed breast, from the acquisition's technique),
    // not measured, entered by hand, copied or derived from other reports.
    // With this source TID 10001 requires the irradiation events (TID 10003;
    // it would not with "Computed From Image Attributes", 113867).
    children.push((
        Rel::Contains,
        Item::Code(
            dcm("113854", "Source of Dose Information"),
            dcm("113940", "System Calculated"),
            vec![],
        ),
    ));
    let root = Item::Container(dcm("113701", "X-Ray Radiation Dose Report"), children);
    let kind = DocKind {
        class: DOSE_SR_CLASS,
        series_number: "9001",
        content_date: &input.content_date,
        content_time: &input.content_time,
        template: "10001",
    };
    let mut r = base(kind, h, &input.equipment, uids, &root)?;
    r.obj.put(DataElement::new(
        tags::SERIES_DESCRIPTION,
        VR::LO,
        "DBToR radiation dose report",
    ));
    Ok(r)
}

/// BI-RADS-style composition category (CID 6000) from the volumetric
/// fibroglandular fraction. Thresholds (volume %): below 4.5 almost entirely
/// fatty, below 7.5 scattered fibroglandular densities, below 15.5
/// heterogeneously dense, else extremely dense: the published mapping of
/// volumetric density grades to BI-RADS 5th edition categories (Volpara
/// density grades). Our choice, to be tuned by the evaluation (issue #7).
pub fn composition_category(volume_fraction: f64) -> (char, Code) {
    let p = 100.0 * volume_fraction;
    let letter = if p < 4.5 {
        'a'
    } else if p < 7.5 {
        'b'
    } else if p < 15.5 {
        'c'
    } else {
        'd'
    };
    (
        letter,
        composition_code(letter).unwrap_or_else(|| Code::new("", "SCT", "")),
    )
}

/// The CID 6000 code of BI-RADS composition category `a`..`d`.
pub fn composition_code(letter: char) -> Option<Code> {
    let (v, m) = match letter {
        'a' => ("129715009", "Almost entirely fatty"),
        'b' => ("129716005", "Scattered fibroglandular densities"),
        'c' => ("129717001", "Heterogeneously dense"),
        'd' => ("129718006", "Extremely dense"),
        _ => return None,
    };
    Some(Code::new(v, "SCT", m))
}

/// Build the density report (Comprehensive SR).
pub fn density_report(input: &DensityInput, uids: &mut UidSource) -> Result<Report, DicomError> {
    check("glandularity", input.glandularity, 0.0, 1.0)?;
    check("breast_cm3", input.breast_cm3, 1.0, 1e5)?;
    check(
        "fibroglandular_cm3",
        input.fibroglandular_cm3,
        0.0,
        input.breast_cm3,
    )?;
    if let Some(g) = input.check.physics_glandularity {
        check("check.physics_glandularity", g, 0.0, 1.0)?;
    }
    input
        .glandularity_interval
        .check("glandularity_interval", 0.0, 1.0)?;
    if !input.check.confirmed && input.check.reasons.is_empty() {
        return Err(DicomError::Field {
            field: "check.reasons",
            reason: "an unconfirmed density needs the reason it is not confirmed".into(),
        });
    }
    let vf = input.fibroglandular_cm3 / input.breast_cm3;
    let (_, cat) = composition_category(vf);
    let cm3 = || Code::ucum("cm3", "cubic centimeter");
    let mut children = observer_context(&input.equipment);
    children.push((
        Rel::Contains,
        Item::Num(
            dcm("111046", "Percent Fibroglandular Tissue"),
            100.0 * input.glandularity,
            Code::ucum("%", "Percent"),
            vec![laterality_mod(input.header.laterality)],
        ),
    ));
    children.extend(interval_items(
        &input.glandularity_interval,
        (
            "PFTLO95",
            "Percent Fibroglandular Tissue, 95 % interval, lower limit",
        ),
        (
            "PFTHI95",
            "Percent Fibroglandular Tissue, 95 % interval, upper limit",
        ),
        (
            "PFTINT95",
            "Percent Fibroglandular Tissue, 95 % interval, basis",
        ),
        100.0,
        Code::ucum("%", "Percent"),
    ));
    children.push((
        Rel::Contains,
        Item::Num(
            private("FGV", "Fibroglandular tissue volume"),
            input.fibroglandular_cm3,
            cm3(),
            vec![],
        ),
    ));
    children.push((
        Rel::Contains,
        Item::Num(
            private("BV", "Breast volume"),
            input.breast_cm3,
            cm3(),
            vec![],
        ),
    ));
    children.push((
        Rel::Contains,
        Item::Num(
            private("VPD", "Volumetric fibroglandular fraction"),
            100.0 * vf,
            Code::ucum("%", "Percent"),
            vec![],
        ),
    ));
    // The cross-check (issue #48 point 3): the physics-based figure in
    // every report; the composition category only where it confirms the
    // reported density, else why not, with both figures.
    let chk = &input.check;
    if let Some(g) = chk.physics_glandularity {
        children.push((
            Rel::Contains,
            Item::Num(
                private("PHYSPFT", "Percent Fibroglandular Tissue, physics-based"),
                100.0 * g,
                Code::ucum("%", "Percent"),
                vec![],
            ),
        ));
    }
    children.push((
        Rel::Contains,
        Item::Code(
            private("DCHECK", "Density cross-check"),
            match (input.method, chk.confirmed) {
                (ReportMethod::Reconstruction, true) => {
                    private("CONFIRMED", "Confirmed by the physics-based density")
                }
                (ReportMethod::Reconstruction, false) => {
                    private("UNCONFIRMED", "Not confirmed by the physics-based density")
                }
                (ReportMethod::PhysicsOnly, true) => private(
                    "PHYSONLY",
                    "Physics-based density alone, its own checks passed",
                ),
                (ReportMethod::PhysicsOnly, false) => private(
                    "PHYSONLYFLAG",
                    "Physics-based density alone, its own checks not passed",
                ),
            },
            vec![],
        ),
    ));
    if input.method == ReportMethod::PhysicsOnly {
        // No category from the physics density alone: nothing cross-checks
        // it, and on realistic breasts it is not known to place a breast in
        // its category reliably (eval/vendor-gantries.md).
        let checks = if chk.confirmed {
            String::new()
        } else {
            format!(
                " Its own checks were not passed: {}.",
                chk.reasons.join("; ")
            )
        };
        children.push((
            Rel::Contains,
            Item::Text(
                private("NOCATWHY", "Why no composition category is given"),
                format!(
                    "No DBToR model is trained and calibrated for this gantry and beam: the physics-based density alone, with no \
                     reconstruction to cross-check it, is not validated to the precision a composition \
                     category needs, and none is given.{checks}"
                ),
            ),
        ));
    } else if chk.confirmed {
        children.push((
            Rel::Contains,
            Item::Code(
                Code::new("129714008", "SCT", "Breast composition"),
                cat,
                vec![],
            ),
        ));
    } else {
        let physics = chk
            .physics_glandularity
            .map_or("none could be made".to_string(), |g| {
                format!("{:.1} %", 100.0 * g)
            });
        children.push((
            Rel::Contains,
            Item::Text(
                private("DCHECKWHY", "Why the density is not confirmed"),
                match input.method {
                    ReportMethod::Reconstruction => format!(
                        "The breast density could not be confirmed and no composition category is \
                         given. Reported (DBToR) {:.1} %, physics-based {physics}: {}.",
                        100.0 * input.glandularity,
                        chk.reasons.join("; ")
                    ),
                    ReportMethod::PhysicsOnly => format!(
                        "The physics-based density {physics} did not pass its own checks and no \
                         composition category is given: {}.",
                        chk.reasons.join("; ")
                    ),
                },
            ),
        ));
    }
    children.push((
        Rel::Contains,
        Item::Text(dcm("111001", "Algorithm Name"), input.reconstructor.clone()),
    ));
    children.push((
        Rel::Contains,
        Item::Text(
            dcm("111003", "Algorithm Version"),
            input.model_version.clone(),
        ),
    ));
    children.push((
        Rel::Contains,
        Item::Text(
            dcm("121106", "Comment"),
            match input.method {
                ReportMethod::Reconstruction => "Percent Fibroglandular Tissue is the glandularity by mass, G = Ng rho_g / (Ng rho_g + Na rho_a) \
             (Hammerstein densities), Cooper's ligaments counted as fibroglandular, skin excluded, from the \
             tissue-classified DBToR reconstruction; the composition category uses the volumetric fraction \
             (thresholds 4.5 / 7.5 / 15.5 %) and is given only where the physics-based density (each ray's \
             dense-tissue path relative to fat, from the same projections, no learning) confirms the reported one.",
                ReportMethod::PhysicsOnly => "No DBToR model is trained and calibrated for this gantry and beam: Percent Fibroglandular Tissue is the \
             physics-based glandularity by mass (each ray's dense-tissue path relative to fat, from the projections \
             of the central view, no learning; Hammerstein densities, skin excluded), not a reconstruction's; \
             its own checks (the views' agreement, the thickness readout, the breast inside the detector, the \
             edge model's share) are stated; no composition category is given.",
            }
            .into(),
        ),
    ));
    let root = Item::Container(
        private("VBDR", "Volumetric breast density report"),
        children,
    );
    let kind = DocKind {
        class: COMPREHENSIVE_SR_CLASS,
        series_number: "9002",
        content_date: &input.content_date,
        content_time: &input.content_time,
        template: "2000",
    };
    let mut r = base(kind, &input.header, &input.equipment, uids, &root)?;
    // TID 2000 is the basic diagnostic imaging report; our content is not
    // template-conformant to it, so no Content Template Sequence is claimed.
    r.obj.remove_element(tags::CONTENT_TEMPLATE_SEQUENCE);
    r.obj.put(DataElement::new(
        tags::SERIES_DESCRIPTION,
        VR::LO,
        "DBToR breast density report",
    ));
    Ok(r)
}

/// Read back a report: `(concept meaning, value)` for every NUM, CODE, TEXT
/// and UIDREF item in document order (values as strings), plus the SOP class.
pub fn read_values(bytes: &[u8]) -> Result<(String, Vec<(String, String)>), DicomError> {
    // Bounded by the file's size: no declared length is trusted beyond it.
    crate::bounds::check_lengths(bytes)?;
    let obj = dicom_object::from_reader(bytes).map_err(|e| DicomError::Encoding(e.to_string()))?;
    let class = obj
        .element(tags::SOP_CLASS_UID)
        .ok()
        .and_then(|e| e.to_str().ok())
        .map(|s| s.trim_end_matches('\0').to_string())
        .unwrap_or_default();
    let mut out = Vec::new();
    fn meaning(o: &InMemDicomObject, t: dicom_core::Tag) -> String {
        o.element(t)
            .ok()
            .and_then(|e| e.items())
            .and_then(|i| i.first())
            .and_then(|c| c.element(tags::CODE_MEANING).ok())
            .and_then(|e| e.to_str().ok())
            .map(|s| s.to_string())
            .unwrap_or_default()
    }
    fn walk(o: &InMemDicomObject, out: &mut Vec<(String, String)>) {
        let vt = o
            .element(tags::VALUE_TYPE)
            .ok()
            .and_then(|e| e.to_str().ok())
            .map(|s| s.trim().to_string())
            .unwrap_or_default();
        let name = meaning(o, tags::CONCEPT_NAME_CODE_SEQUENCE);
        let val = match vt.as_str() {
            "NUM" => o
                .element(tags::MEASURED_VALUE_SEQUENCE)
                .ok()
                .and_then(|e| e.items())
                .and_then(|i| i.first())
                .map(|m| {
                    let v = m
                        .element(tags::NUMERIC_VALUE)
                        .ok()
                        .and_then(|e| e.to_str().ok())
                        .map(|s| s.trim().to_string())
                        .unwrap_or_default();
                    format!("{v} {}", meaning(m, tags::MEASUREMENT_UNITS_CODE_SEQUENCE))
                }),
            "CODE" => Some(meaning(o, tags::CONCEPT_CODE_SEQUENCE)),
            "TEXT" => o
                .element(tags::TEXT_VALUE)
                .ok()
                .and_then(|e| e.to_str().ok())
                .map(|s| s.to_string()),
            "UIDREF" => o
                .element(tags::UID)
                .ok()
                .and_then(|e| e.to_str().ok())
                .map(|s| s.to_string()),
            _ => None,
        };
        if let Some(v) = val {
            out.push((name, v));
        }
        if let Some(items) = o
            .element(tags::CONTENT_SEQUENCE)
            .ok()
            .and_then(|e| e.items())
        {
            for i in items {
                walk(i, out);
            }
        }
    }
    walk(&obj, &mut out);
    Ok((class, out))
}
