//! Template-level checks of the dose SR against PS3.16, on the encoded
//! report read back as a content tree.
//!
//! dciodvfy checks the IOD (the attributes) and dsrdump the SR encoding;
//! neither checks the templates: which content items a template requires,
//! by which relationship, from which value set. [`check_dose_report`] does,
//! for the rows our dose SR uses or must use: TID 10001 (Projection X-Ray
//! Radiation Dose), TID 1002 (observer context), TID 10002 and TID 10005
//! (accumulated mammography dose), TID 10003, 10003B and 10003C (each
//! irradiation event). Each violation names the template and row.
//!
//! Value sets are those of the current edition (PS3.16 2024; the codes as
//! pydicom 3.0's tables of that edition list them, and
//! `/work/runs/rdsr-research.md` of issue #31 for the rows and conditions).
//! The CIDs are extensible where the standard says so; we hold our own
//! reports to the listed codes.

use crate::DicomError;
use dicom_dictionary_std::tags;
use dicom_object::InMemDicomObject;

/// A coded concept: value, scheme, meaning.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Coded {
    /// Code value.
    pub value: String,
    /// Coding scheme designator.
    pub scheme: String,
    /// Code meaning.
    pub meaning: String,
}

/// One content item and its children.
#[derive(Debug, Clone, PartialEq)]
pub struct Node {
    /// Relationship to the parent (`CONTAINS`, `HAS CONCEPT MOD`, ...;
    /// empty for the root).
    pub relationship: String,
    /// `CONTAINER`, `CODE`, `NUM`, `TEXT`, `UIDREF`, `DATETIME`, ...
    pub value_type: String,
    /// The concept name.
    pub concept: Option<Coded>,
    /// A CODE item's value.
    pub code: Option<Coded>,
    /// A NUM item's numeric value (as encoded).
    pub number: Option<String>,
    /// Children in document order.
    pub children: Vec<Node>,
}

impl Node {
    /// Whether the concept name is `value` in `scheme`.
    pub fn is(&self, value: &str, scheme: &str) -> bool {
        self.concept
            .as_ref()
            .is_some_and(|c| c.value == value && c.scheme == scheme)
    }

    /// The children named `value` in `scheme`.
    pub fn named<'a>(&'a self, value: &'a str, scheme: &'a str) -> impl Iterator<Item = &'a Node> {
        self.children.iter().filter(move |c| c.is(value, scheme))
    }

    /// A short path element for messages: `CODE (113705, DCM, "Scope of Accumulation")`.
    pub fn describe(&self) -> String {
        match &self.concept {
            Some(c) => format!(
                "{} ({}, {}, \"{}\")",
                self.value_type, c.value, c.scheme, c.meaning
            ),
            None => self.value_type.clone(),
        }
    }
}

fn text(o: &InMemDicomObject, t: dicom_core::Tag) -> Option<String> {
    o.element(t)
        .ok()
        .and_then(|e| e.to_str().ok())
        .map(|s| s.trim_end_matches(['\0', ' ']).trim().to_string())
}

fn coded(o: &InMemDicomObject, t: dicom_core::Tag) -> Option<Coded> {
    let item = o.element(t).ok()?.items()?.first()?;
    Some(Coded {
        value: text(item, tags::CODE_VALUE).unwrap_or_default(),
        scheme: text(item, tags::CODING_SCHEME_DESIGNATOR).unwrap_or_default(),
        meaning: text(item, tags::CODE_MEANING).unwrap_or_default(),
    })
}

fn node(o: &InMemDicomObject) -> Node {
    let children = o
        .element(tags::CONTENT_SEQUENCE)
        .ok()
        .and_then(|e| e.items())
        .map(|items| items.iter().map(node).collect())
        .unwrap_or_default();
    Node {
        relationship: text(o, tags::RELATIONSHIP_TYPE).unwrap_or_default(),
        value_type: text(o, tags::VALUE_TYPE).unwrap_or_default(),
        concept: coded(o, tags::CONCEPT_NAME_CODE_SEQUENCE),
        code: coded(o, tags::CONCEPT_CODE_SEQUENCE),
        number: o
            .element(tags::MEASURED_VALUE_SEQUENCE)
            .ok()
            .and_then(|e| e.items())
            .and_then(|i| i.first())
            .and_then(|m| text(m, tags::NUMERIC_VALUE)),
        children,
    }
}

/// The content tree of an encoded SR (bounded by the file's size, as
/// [`crate::read_values`]).
pub fn read_tree(bytes: &[u8]) -> Result<Node, DicomError> {
    crate::bounds::check_lengths(bytes)?;
    let obj = dicom_object::from_reader(bytes).map_err(|e| DicomError::Encoding(e.to_string()))?;
    Ok(node(&obj))
}

/// CID 3629 "Procedure Intent" (the codes a DBT report can mean).
const CID_3629: &[&str] = &["261004008", "360156006", "113680"];
/// CID 10000 "Scope of Accumulation": Study, Series, Performed Procedure Step.
const CID_10000: &[&str] = &["113014", "113015", "113016"];
/// CID 6022 "Side": left, right, both breasts.
const CID_6022: &[&str] = &["80248007", "73056007", "63762007"];
/// CID 244 "Laterality".
const CID_244: &[&str] = &["7771000", "24028007", "51440002", "66459002"];
/// CID 10003 "Equipment Plane Identification": Single Plane, Plane A, Plane B.
const CID_10003: &[&str] = &["113622", "113620", "113621"];
/// CID 10002 "Irradiation Event Type": stationary, stepping, rotational
/// acquisition, fluoroscopy.
const CID_10002: &[&str] = &["113611", "113612", "113613", "P5-06000", "44491008"];
/// CID 10016 "Anode Target Material": molybdenum, tungsten, rhodium.
const CID_10016: &[&str] = &["71128006", "26194003", "59801003"];
/// CID 10006 "X-Ray Filter Material".
const CID_10006: &[&str] = &[
    "12503006",
    "59801003",
    "41967008",
    "71128006",
    "66925006",
    "12597001",
    "767776000",
    "767775001",
    "45215009",
    "88488004",
];
/// CID 10020 "Source of Projection X-Ray Dose Information".
const CID_10020: &[&str] = &[
    "113856", "113857", "113858", "15869005", "113866", "113867", "113868", "113940",
];

struct Checker {
    out: Vec<String>,
}

impl Checker {
    fn fail(&mut self, at: &str, msg: String) {
        self.out.push(format!("{at}: {msg}"));
    }

    /// The children of `parent` named (`value`, `scheme`), checked for
    /// count (`min..=max`), relationship and value type.
    #[allow(clippy::too_many_arguments)]
    fn rows<'a>(
        &mut self,
        at: &str,
        parent: &'a Node,
        value: &'a str,
        scheme: &'a str,
        rel: &str,
        vt: &str,
        min: usize,
        max: usize,
    ) -> Vec<&'a Node> {
        let found: Vec<&Node> = parent.named(value, scheme).collect();
        if found.len() < min || found.len() > max {
            let want = if max == usize::MAX {
                format!("at least {min}")
            } else if min == max {
                format!("{min}")
            } else {
                format!("{min} to {max}")
            };
            self.fail(
                at,
                format!(
                    "({value}, {scheme}) under {}: {} found, {want} required",
                    parent.describe(),
                    found.len()
                ),
            );
        }
        for f in &found {
            if f.relationship != rel {
                self.fail(
                    at,
                    format!(
                        "{} must be related by {rel}, found {}",
                        f.describe(),
                        f.relationship
                    ),
                );
            }
            if f.value_type != vt {
                self.fail(
                    at,
                    format!("{} must be a {vt}, found {}", f.describe(), f.value_type),
                );
            }
        }
        found
    }

    fn in_set(&mut self, at: &str, n: &Node, cid: &str, set: &[&str]) {
        match &n.code {
            Some(c) if set.contains(&c.value.as_str()) => {}
            Some(c) => self.fail(
                at,
                format!(
                    "{} = ({}, {}, \"{}\") is not in CID {cid}",
                    n.describe(),
                    c.value,
                    c.scheme,
                    c.meaning
                ),
            ),
            None => self.fail(at, format!("{} has no code value", n.describe())),
        }
    }
}

/// Every violation of TID 10001 (and the templates it includes) that the
/// dose SR `root` shows, each naming its template and row; empty when it
/// conforms. Rows checked: everything mandatory or conditionally required
/// for a mammography/DBT report, and the value sets of every coded row it
/// carries.
pub fn check_dose_report(root: &Node) -> Vec<String> {
    let mut c = Checker { out: vec![] };
    if !root.is("113701", "DCM") || root.value_type != "CONTAINER" {
        c.fail(
            "TID 10001 row 1",
            format!(
                "the root must be CONTAINER (113701, DCM), found {}",
                root.describe()
            ),
        );
        return c.out;
    }
    // Rows 2-3: Procedure reported and its intent.
    for p in c.rows(
        "TID 10001 row 2",
        root,
        "121058",
        "DCM",
        "HAS CONCEPT MOD",
        "CODE",
        1,
        1,
    ) {
        for i in c.rows(
            "TID 10001 row 3",
            p,
            "363703001",
            "SCT",
            "HAS CONCEPT MOD",
            "CODE",
            1,
            1,
        ) {
            c.in_set("TID 10001 row 3", i, "3629", CID_3629);
        }
    }
    // Row 5 = TID 1002: a device observer.
    for t in c.rows(
        "TID 1002 row 1",
        root,
        "121005",
        "DCM",
        "HAS OBS CONTEXT",
        "CODE",
        1,
        1,
    ) {
        if t.code.as_ref().is_some_and(|v| v.value == "121007") {
            c.rows(
                "TID 1004 row 1",
                root,
                "121012",
                "DCM",
                "HAS OBS CONTEXT",
                "UIDREF",
                1,
                1,
            );
        }
    }
    // Rows 6-7: the scope of accumulation, as observation context.
    for s in c.rows(
        "TID 10001 row 6",
        root,
        "113705",
        "DCM",
        "HAS OBS CONTEXT",
        "CODE",
        1,
        1,
    ) {
        c.in_set("TID 10001 row 6", s, "10000", CID_10000);
        let uids = s
            .children
            .iter()
            .filter(|k| k.value_type == "UIDREF" && k.relationship == "HAS PROPERTIES")
            .count();
        if uids != 1 {
            c.fail(
                "TID 10001 row 7",
                format!("the scope needs 1 HAS PROPERTIES UIDREF, found {uids}"),
            );
        }
    }
    // Rows 11-13 = TID 10002 (and 10005 for mammography).
    for a in c.rows(
        "TID 10002 row 1",
        root,
        "113702",
        "DCM",
        "CONTAINS",
        "CONTAINER",
        1,
        2,
    ) {
        for p in c.rows(
            "TID 10002 row 2",
            a,
            "113764",
            "DCM",
            "HAS CONCEPT MOD",
            "CODE",
            1,
            1,
        ) {
            c.in_set("TID 10002 row 2", p, "10003", CID_10003);
        }
        for agd in c.rows(
            "TID 10005 row 1",
            a,
            "111637",
            "DCM",
            "CONTAINS",
            "NUM",
            1,
            2,
        ) {
            for l in c.rows(
                "TID 10005 row 2",
                agd,
                "272741003",
                "SCT",
                "HAS CONCEPT MOD",
                "CODE",
                1,
                1,
            ) {
                c.in_set("TID 10005 row 2", l, "6022", CID_6022);
            }
        }
    }
    // Row 18: the source of the dose information (its value decides
    // whether the events are required).
    let sources = c.rows(
        "TID 10001 row 18",
        root,
        "113854",
        "DCM",
        "CONTAINS",
        "CODE",
        1,
        usize::MAX,
    );
    let mut events_required = false;
    for s in &sources {
        c.in_set("TID 10001 row 18", s, "10020", CID_10020);
        let v = s.code.as_ref().map(|v| v.value.as_str()).unwrap_or("");
        events_required |= !matches!(v, "113858" | "113866" | "113867");
    }
    // Row 14 = TID 10003, required unless the dose came from MPPS or image
    // attributes.
    let events = c.rows(
        "TID 10001 row 14",
        root,
        "113706",
        "DCM",
        "CONTAINS",
        "CONTAINER",
        usize::from(events_required),
        usize::MAX,
    );
    for e in events {
        check_event(&mut c, e);
    }
    c.out
}

/// TID 10003 (with 10003B and 10003C) for one mammography event.
fn check_event(c: &mut Checker, e: &Node) {
    let rows = |c: &mut Checker, row: &str, v: &'static str, s: &'static str, rel, vt, min, max| {
        c.rows(&format!("TID {row}"), e, v, s, rel, vt, min, max)
            .into_iter()
            .cloned()
            .collect::<Vec<Node>>()
    };
    for p in rows(
        c,
        "10003 row 2",
        "113764",
        "DCM",
        "HAS CONCEPT MOD",
        "CODE",
        1,
        1,
    ) {
        c.in_set("TID 10003 row 2", &p, "10003", CID_10003);
    }
    rows(
        c,
        "10003 row 3",
        "113769",
        "DCM",
        "CONTAINS",
        "UIDREF",
        1,
        1,
    );
    rows(
        c,
        "10003 row 6",
        "111526",
        "DCM",
        "CONTAINS",
        "DATETIME",
        1,
        1,
    );
    let kind = rows(c, "10003 row 7", "113721", "DCM", "CONTAINS", "CODE", 1, 1);
    for k in &kind {
        c.in_set("TID 10003 row 7", k, "10002", CID_10002);
    }
    for a in rows(
        c,
        "10003 row 9",
        "91723000",
        "SCT",
        "CONTAINS",
        "CODE",
        0,
        1,
    ) {
        for l in c.rows(
            "TID 10003 row 10",
            &a,
            "272741003",
            "SCT",
            "HAS CONCEPT MOD",
            "CODE",
            0,
            1,
        ) {
            c.in_set("TID 10003 row 10", l, "244", CID_244);
        }
    }
    for t in rows(c, "10003 row 17", "123014", "DCM", "CONTAINS", "CODE", 1, 1) {
        if !t.children.is_empty() {
            c.fail(
                "TID 10003 row 17",
                format!(
                    "{} has no children in the template (laterality belongs to row 9's anatomy)",
                    t.describe()
                ),
            );
        }
    }
    // Rows 21-23: the entrance exposure needs its reference point.
    if e.named("111636", "DCM").next().is_some() && e.named("113780", "DCM").count() != 1 {
        c.fail(
            "TID 10003 rows 22-23",
            "Entrance Exposure at RP needs one Reference Point Definition (TEXT or CODE)".into(),
        );
    }
    // TID 10003B: AGD (mammography), KVP, pulses, exposure, anode, filters.
    rows(c, "10003B row 4", "111631", "DCM", "CONTAINS", "NUM", 1, 1);
    rows(
        c,
        "10003B row 11",
        "113733",
        "DCM",
        "CONTAINS",
        "NUM",
        1,
        usize::MAX,
    );
    if e.named("113732", "DCM").next().is_none() {
        rows(c, "10003B row 7", "113768", "DCM", "CONTAINS", "NUM", 1, 1);
    }
    let exposure = e.named("113736", "DCM").count() > 0
        || (e.named("113734", "DCM").count() > 0 && e.named("113824", "DCM").count() > 0);
    if !exposure {
        c.fail(
            "TID 10003B rows 12-15",
            "Exposure (113736), or X-Ray Tube Current and Exposure Time, is required".into(),
        );
    }
    for a in rows(
        c,
        "10003B row 17",
        "111632",
        "DCM",
        "CONTAINS",
        "CODE",
        0,
        1,
    ) {
        c.in_set("TID 10003B row 17", &a, "10016", CID_10016);
    }
    for f in rows(
        c,
        "10003B row 18",
        "113771",
        "DCM",
        "CONTAINS",
        "CONTAINER",
        0,
        usize::MAX,
    ) {
        for m in c.rows(
            "TID 10003B row 20",
            &f,
            "113757",
            "DCM",
            "CONTAINS",
            "CODE",
            0,
            1,
        ) {
            c.in_set("TID 10003B row 20", m, "10006", CID_10006);
        }
    }
    // TID 10003C: a rotational event has its end angle.
    if kind
        .iter()
        .any(|k| k.code.as_ref().is_some_and(|v| v.value == "113613"))
    {
        rows(c, "10003C row 2", "112011", "DCM", "CONTAINS", "NUM", 1, 1);
        rows(c, "10003C row 4", "113739", "DCM", "CONTAINS", "NUM", 1, 1);
    }
}
