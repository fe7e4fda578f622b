//! The acquisition: what the gantry delivers for one breast (geometry,
//! thickness, flat field, technique, identity, and the detected counts of
//! every coronal slice), and the validation of its header that runs before
//! any work. The frame link, the recorded-acquisition files (`dbt-store`) and
//! the DICOM input all build this type and pass the same
//! [`validate_header`].
//!
//! Counts are `[slices][views * elements]`; slices are coronal, chest wall
//! first, `slice_spacing_mm` apart.

use dbt_geometry::Geometry;
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Format tag of a recorded acquisition's header.
pub const ACQ_FORMAT: &str = "dbtor-acquisition/1";

/// Patient attributes.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Patient {
    /// `Family^Given`.
    pub name: String,
    /// Patient ID.
    pub id: String,
    /// `YYYYMMDD` or empty.
    pub birth_date: String,
    /// `F`, `M`, `O` or empty.
    pub sex: String,
}

/// Study attributes.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Study {
    /// Study Instance UID.
    pub study_uid: String,
    /// `YYYYMMDD`.
    pub date: String,
    /// `HHMMSS`.
    pub time: String,
    /// Accession number.
    pub accession: String,
    /// Study ID.
    pub study_id: String,
    /// Series Instance UID of the projections.
    pub series_uid: String,
    /// SOP Instance UIDs of the projections (one per view).
    pub instance_uids: Vec<String>,
    /// Their SOP class, when they came over DICOM (absent: the frame link's
    /// projections, referenced as Breast Projection X-Ray For Processing).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source_class: Option<String>,
}

/// The acquisition header.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AcquisitionHeader {
    /// [`ACQ_FORMAT`].
    pub format: String,
    /// Geometry of every slice.
    pub geometry: Geometry,
    /// Compressed thickness from the paddle, mm.
    pub thickness_mm: f64,
    /// Photons per ray without the breast (flat field), `b`.
    pub flux: f64,
    /// Number of coronal slices.
    pub slices: usize,
    /// Distance between coronal slices, mm.
    pub slice_spacing_mm: f64,
    /// Tube voltage, kV.
    pub kvp: f64,
    /// Anode and filter of the exposure (`W/Rh`, `W/Al`; absent in a file
    /// written before issue #27's W/Al: `W/Rh`, the only beam then). The
    /// dose, the beam-hardening correction and the scatter removal use this
    /// beam's spectra (`dbt_dose::xray::technique_spectrum`).
    #[serde(default)]
    pub anode_filter: dbt_dose::xray::AnodeFilter,
    /// Tube loading of the whole sweep, mAs.
    pub mas_total: f64,
    /// Incident air kerma at the reference point per mAs, mGy/mAs.
    pub tube_output_mgy_per_mas: f64,
    /// `L` or `R`.
    pub laterality: String,
    /// Compression force, N, where the acquisition gave it (a DICOM input
    /// object's Compression Force, the gantry's Modbus register).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub compression_force_n: Option<f64>,
    /// Exposure time of each view, ms, where the acquisition gave it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure_ms_per_view: Option<f64>,
    /// The cone-beam system the counts come from (issue #28): then the
    /// counts are its detector's frames, `[detector row][view * column]`
    /// (`slices` = detector rows), rebinned to coronal slices
    /// `slice_spacing_mm` apart in `geometry` (`rebin::slice_sinograms`
    /// in the pipeline). Absent: the counts are already coronal
    /// fan-beam sinograms.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub system: Option<dbt_geometry::ConeSystem>,
    /// Patient.
    pub patient: Patient,
    /// Study.
    pub study: Study,
    /// Ground truth of a simulated acquisition (for evaluation only; the
    /// processing never reads it).
    #[serde(default)]
    pub truth: Option<serde_json::Value>,
}

impl AcquisitionHeader {
    /// Counts per entry of `counts`: a coronal slice's sinogram (views x
    /// elements), or for a cone-beam acquisition a detector row across the
    /// views (views x columns).
    pub fn rays_per_slice(&self) -> usize {
        match &self.system {
            Some(s) => s.n_views() * s.detector.columns,
            None => self.geometry.n_rays(),
        }
    }
}

/// A loaded acquisition.
#[derive(Debug, Clone, PartialEq)]
pub struct Acquisition {
    /// Header.
    pub header: AcquisitionHeader,
    /// Counts, `[slices][views * elements]`.
    pub counts: Vec<Vec<f32>>,
}

/// The limits of a plausible header. Each is physics, the product's
/// hardware, or DICOM; the reason is written beside it and a test checks the
/// values just inside and just outside.
pub mod limits {
    /// Thinnest compressed breast, mm. Screening CC thickness is 59 +- 16 mm
    /// (Yaffe et al. 2009, Med Phys 36:5437; 2,831 women), the thinnest
    /// reported in such series about 15-20 mm; 10 mm is below any breast a
    /// paddle holds, so smaller is a sensor fault.
    pub const THICKNESS_MIN_MM: f64 = 10.0;
    /// Thickest compressed breast, mm: above the compression stroke of
    /// mammography gantries (the same series reach 110-120 mm). The image
    /// height of the geometry bounds it further (the pipeline refuses a
    /// breast taller than its image).
    pub const THICKNESS_MAX_MM: f64 = 150.0;
    /// Tube voltage range of mammography generators, kV (IEC 60601-2-45
    /// systems operate at 20-49 kV; DBT techniques use 25-49 kV).
    pub const KVP_MIN: f64 = 20.0;
    /// See [`KVP_MIN`].
    pub const KVP_MAX: f64 = 49.0;
    /// Largest tube loading of one DBT sweep, mAs. Clinical sweeps use
    /// 30-300 mAs (Feng & Sechopoulos 2012, Radiology 263:35: 0.66-3.52 mGy
    /// per view); 1000 mAs would deliver tens of mGy. Zero or a negative value
    /// means no exposure, and no dose can be reported from it.
    pub const MAS_MAX: f64 = 1000.0;
    /// Largest tube output at the reference point, mGy/mAs: a W/Rh tube at
    /// 49 kV delivers about 0.2 mGy/mAs at 65 cm; 1 is far beyond any tube.
    pub const TUBE_OUTPUT_MAX_MGY_PER_MAS: f64 = 1.0;
    /// Fewest flat-field photons per ray. Below this the transmitted count
    /// behind the thinnest breast already has a relative noise above 10 %
    /// (1/sqrt(100)), so no line integral is measurable; the paper's lowest
    /// level N4 has 4,000.
    pub const FLUX_MIN: f64 = 100.0;
    /// Most flat-field photons per ray a record may claim: the noise-free
    /// evaluation level is 1e6; 1e9 is beyond any detector element's
    /// capacity by orders of magnitude.
    pub const FLUX_MAX: f64 = 1e9;
    /// Longest chest-wall-to-nipple extent, mm: the largest DBT detectors
    /// are 24 x 30 cm, so the slices of one breast cannot span more than
    /// 300 mm.
    pub const DEPTH_MAX_MM: f64 = 300.0;
    /// Largest counts array of one acquisition, bytes (f32): 300 mm of
    /// 0.1 mm slices of the paper's 25 x 1280 rays is 384 MB; 1 GiB bounds
    /// any geometry the product ships and keeps `slices * rays * 4` far from
    /// overflow.
    pub const COUNTS_BYTES_MAX: usize = 1 << 30;
}

/// A header field that is not plausible: which field, its value, and why.
#[derive(Debug, Clone, PartialEq, Error)]
#[error("acquisition header `{field}` = {value}: {reason}")]
pub struct HeaderError {
    /// The field, as the header names it (`study.date`).
    pub field: &'static str,
    /// Its value, as received.
    pub value: String,
    /// Why it is refused.
    pub reason: String,
}

fn refuse(
    field: &'static str,
    value: impl std::fmt::Display,
    reason: impl Into<String>,
) -> HeaderError {
    HeaderError {
        field,
        value: value.to_string(),
        reason: reason.into(),
    }
}

fn in_range(
    field: &'static str,
    v: f64,
    lo: f64,
    hi: f64,
    unit: &str,
    why: &str,
) -> Result<(), HeaderError> {
    if !(v.is_finite() && v >= lo && v <= hi) {
        return Err(refuse(
            field,
            v,
            format!("outside the plausible range [{lo}, {hi}] {unit} ({why})"),
        ));
    }
    Ok(())
}

/// A DICOM UID (PS3.5 9.1): at most 64 characters, dot-separated
/// components of digits, none empty and none with a leading zero.
pub fn check_uid(field: &'static str, uid: &str) -> Result<(), HeaderError> {
    let why = |r: &str| {
        Err(refuse(
            field,
            format!("`{uid}`"),
            format!("not a DICOM UID: {r}"),
        ))
    };
    if uid.is_empty() {
        return why("empty");
    }
    if uid.len() > 64 {
        return why("longer than 64 characters");
    }
    for c in uid.split('.') {
        if c.is_empty() {
            return why("an empty component");
        }
        if !c.bytes().all(|b| b.is_ascii_digit()) {
            return why("a component that is not all digits");
        }
        if c.len() > 1 && c.starts_with('0') {
            return why("a component with a leading zero");
        }
    }
    Ok(())
}

/// A DICOM date `YYYYMMDD` (DA) that exists in the calendar.
pub fn check_date(field: &'static str, d: &str) -> Result<(), HeaderError> {
    let bad = |r: &str| {
        Err(refuse(
            field,
            format!("`{d}`"),
            format!("not a date YYYYMMDD: {r}"),
        ))
    };
    if d.len() != 8 || !d.bytes().all(|b| b.is_ascii_digit()) {
        return bad("not eight digits");
    }
    let n = |a: usize, b: usize| d[a..b].parse::<u32>().unwrap_or(0);
    let (y, m, day) = (n(0, 4), n(4, 6), n(6, 8));
    if !(1900..=9999).contains(&y) {
        return bad("year before 1900");
    }
    let leap = (y % 4 == 0 && y % 100 != 0) || y % 400 == 0;
    let days = match m {
        1 | 3 | 5 | 7 | 8 | 10 | 12 => 31,
        4 | 6 | 9 | 11 => 30,
        2 if leap => 29,
        2 => 28,
        _ => return bad("no such month"),
    };
    if day == 0 || day > days {
        return bad("no such day in that month");
    }
    Ok(())
}

/// A DICOM time `HHMMSS` with an optional fraction `.FFFFFF` (TM).
pub fn check_time(field: &'static str, t: &str) -> Result<(), HeaderError> {
    let bad = |r: &str| {
        Err(refuse(
            field,
            format!("`{t}`"),
            format!("not a time HHMMSS[.FFFFFF]: {r}"),
        ))
    };
    let (whole, frac) = t.split_once('.').unwrap_or((t, ""));
    if whole.len() != 6 || !whole.bytes().all(|b| b.is_ascii_digit()) {
        return bad("not six digits");
    }
    if frac.len() > 6 || !frac.bytes().all(|b| b.is_ascii_digit()) {
        return bad("the fraction is not up to six digits");
    }
    let n = |a: usize| whole[a..a + 2].parse::<u32>().unwrap_or(99);
    if n(0) > 23 || n(2) > 59 || n(4) > 60 {
        return bad("hour, minute or second out of range");
    }
    Ok(())
}

/// A DICOM string of at most `max` characters, without the value delimiter
/// `\` or control characters (LO, SH, PN).
pub fn check_text(
    field: &'static str,
    v: &str,
    max: usize,
    required: bool,
) -> Result<(), HeaderError> {
    if required && v.trim().is_empty() {
        return Err(refuse(field, format!("`{v}`"), "empty, and it is required"));
    }
    if v.chars().count() > max {
        return Err(refuse(
            field,
            format!("`{v}`"),
            format!("longer than {max} characters"),
        ));
    }
    if v.contains('\\') || v.chars().any(|c| c.is_control()) {
        return Err(refuse(
            field,
            format!("{v:?}"),
            "holds a backslash or a control character (not allowed in a DICOM string)",
        ));
    }
    Ok(())
}

/// Check every header field before any work: the geometry, the technique,
/// the flat field, the sizes (with checked arithmetic), the identity and the
/// UIDs, each against [`limits`] or DICOM's value representations. The
/// counts' size against `slices` is the reader's to check.
pub fn validate_header(h: &AcquisitionHeader) -> Result<(), HeaderError> {
    use limits::*;
    if h.format != ACQ_FORMAT {
        return Err(refuse(
            "format",
            format!("`{}`", h.format),
            format!("expected `{ACQ_FORMAT}`"),
        ));
    }
    let g = &h.geometry;
    g.validate()
        .map_err(|e| refuse("geometry", g.describe(), e.to_string()))?;
    // A cone-beam system read from a file is checked as one loaded from
    // TOML is (deserialising does not validate).
    if let Some(s) = &h.system {
        s.validate()
            .map_err(|e| refuse("system", &s.name, e.to_string()))?;
    }
    in_range(
        "thickness_mm",
        h.thickness_mm,
        THICKNESS_MIN_MM,
        THICKNESS_MAX_MM,
        "mm",
        "a compressed breast",
    )?;
    in_range(
        "flux",
        h.flux,
        FLUX_MIN,
        FLUX_MAX,
        "photons per ray",
        "the flat field",
    )?;
    in_range(
        "kvp",
        h.kvp,
        KVP_MIN,
        KVP_MAX,
        "kV",
        "mammography generators",
    )?;
    if !(h.mas_total.is_finite() && h.mas_total > 0.0 && h.mas_total <= MAS_MAX) {
        return Err(refuse(
            "mas_total",
            h.mas_total,
            format!(
                "must be above 0 and at most {MAS_MAX} mAs (no exposure means no dose to report)"
            ),
        ));
    }
    if !(h.tube_output_mgy_per_mas.is_finite()
        && h.tube_output_mgy_per_mas > 0.0
        && h.tube_output_mgy_per_mas <= TUBE_OUTPUT_MAX_MGY_PER_MAS)
    {
        return Err(refuse(
            "tube_output_mgy_per_mas",
            h.tube_output_mgy_per_mas,
            format!("must be above 0 and at most {TUBE_OUTPUT_MAX_MGY_PER_MAS} mGy/mAs"),
        ));
    }
    if !(h.slice_spacing_mm.is_finite() && h.slice_spacing_mm > 0.0) {
        return Err(refuse(
            "slice_spacing_mm",
            h.slice_spacing_mm,
            "must be positive",
        ));
    }
    if h.slices == 0 {
        return Err(refuse("slices", 0, "no slice"));
    }
    // The slice-wise stream's rows are slices; a cone-beam system's are its
    // detector's rows.
    let (row_mm, rows) = match &h.system {
        Some(s) => (s.detector.pitch_mm, "detector rows"),
        None => (h.slice_spacing_mm, "slices"),
    };
    let depth = h.slices as f64 * row_mm;
    if depth > DEPTH_MAX_MM {
        return Err(refuse(
            "slices",
            h.slices,
            format!(
                "{} {rows} of {row_mm} mm span {depth:.0} mm, more than the {DEPTH_MAX_MM} mm any DBT detector covers",
                h.slices
            ),
        ));
    }
    counts_bytes(h)?;
    if h.laterality != "L" && h.laterality != "R" {
        return Err(refuse(
            "laterality",
            format!("`{}`", h.laterality),
            "must be L or R",
        ));
    }
    let p = &h.patient;
    check_text("patient.name", &p.name, 64, false)?;
    check_text("patient.id", &p.id, 64, true)?;
    if !p.birth_date.is_empty() {
        check_date("patient.birth_date", &p.birth_date)?;
    }
    if !["", "F", "M", "O"].contains(&p.sex.as_str()) {
        return Err(refuse(
            "patient.sex",
            format!("`{}`", p.sex),
            "must be F, M, O or empty",
        ));
    }
    let s = &h.study;
    check_uid("study.study_uid", &s.study_uid)?;
    check_uid("study.series_uid", &s.series_uid)?;
    for u in &s.instance_uids {
        check_uid("study.instance_uids", u)?;
    }
    check_date("study.date", &s.date)?;
    check_time("study.time", &s.time)?;
    check_text("study.accession", &s.accession, 16, false)?;
    check_text("study.study_id", &s.study_id, 16, false)?;
    Ok(())
}

/// The size in bytes of the header's counts (`slices x views x elements`
/// f32), with checked arithmetic, at most [`limits::COUNTS_BYTES_MAX`].
pub fn counts_bytes(h: &AcquisitionHeader) -> Result<usize, HeaderError> {
    let too_big = || {
        refuse(
            "slices",
            h.slices,
            format!(
                "{} slices of {} rays exceed the {} MiB an acquisition may hold",
                h.slices,
                h.rays_per_slice(),
                limits::COUNTS_BYTES_MAX >> 20
            ),
        )
    };
    let bytes = h
        .slices
        .checked_mul(h.rays_per_slice())
        .and_then(|n| n.checked_mul(4))
        .ok_or_else(too_big)?;
    if bytes > limits::COUNTS_BYTES_MAX {
        return Err(too_big());
    }
    Ok(bytes)
}

/// A valid header for tests and examples: `slices` rows on `geometry` (a
/// cone-beam `system`'s frames where given), a 45 mm breast at N8's flat
/// field (16,000), 28 kV W/Rh, 60 mAs at 0.11 mGy/mAs.
pub fn example_header(
    geometry: dbt_geometry::Geometry,
    slices: usize,
    system: Option<dbt_geometry::ConeSystem>,
) -> AcquisitionHeader {
    AcquisitionHeader {
        format: ACQ_FORMAT.into(),
        geometry,
        thickness_mm: 45.0,
        flux: 16_000.0,
        slices,
        slice_spacing_mm: 0.2,
        kvp: 28.0,
        anode_filter: Default::default(),
        mas_total: 60.0,
        tube_output_mgy_per_mas: 0.11,
        laterality: "L".into(),
        compression_force_n: None,
        exposure_ms_per_view: None,
        system,
        patient: Default::default(),
        study: Default::default(),
        truth: None,
    }
}
