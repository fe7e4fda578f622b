//! SR content items (PS3.3 C.17.3) as a small tree, turned into datasets.

use dicom_core::value::DataSetSequence;
use dicom_core::{DataElement, VR};
use dicom_dictionary_std::tags;
use dicom_object::InMemDicomObject;

/// A coded concept (code value, coding scheme designator, code meaning).
#[derive(Debug, Clone, PartialEq)]
pub struct Code {
    /// Code value.
    pub value: String,
    /// Coding scheme designator (DCM, SCT, UCUM, 99DBTOR, ...).
    pub scheme: String,
    /// Code meaning.
    pub meaning: String,
}

impl Code {
    /// A code.
    pub fn new(value: &str, scheme: &str, meaning: &str) -> Self {
        Self {
            value: value.into(),
            scheme: scheme.into(),
            meaning: meaning.into(),
        }
    }

    /// A UCUM unit.
    pub fn ucum(unit: &str, meaning: &str) -> Self {
        Self::new(unit, "UCUM", meaning)
    }

    pub(crate) fn dataset(&self) -> InMemDicomObject {
        InMemDicomObject::from_element_iter([
            DataElement::new(tags::CODE_VALUE, VR::SH, self.value.as_str()),
            DataElement::new(tags::CODING_SCHEME_DESIGNATOR, VR::SH, self.scheme.as_str()),
            DataElement::new(tags::CODE_MEANING, VR::LO, self.meaning.as_str()),
        ])
    }
}

/// Relationship of a child to its parent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rel {
    /// CONTAINS
    Contains,
    /// HAS CONCEPT MOD
    HasConceptMod,
    /// HAS OBS CONTEXT
    HasObsContext,
    /// HAS PROPERTIES
    HasProperties,
}

impl Rel {
    fn cs(self) -> &'static str {
        match self {
            Rel::Contains => "CONTAINS",
            Rel::HasConceptMod => "HAS CONCEPT MOD",
            Rel::HasObsContext => "HAS OBS CONTEXT",
            Rel::HasProperties => "HAS PROPERTIES",
        }
    }
}

/// A content item and its children.
#[derive(Debug, Clone, PartialEq)]
pub enum Item {
    /// CONTAINER with a concept name and children.
    Container(Code, Vec<(Rel, Item)>),
    /// CODE: concept name = coded value.
    Code(Code, Code, Vec<(Rel, Item)>),
    /// NUM: concept name = value in units.
    Num(Code, f64, Code, Vec<(Rel, Item)>),
    /// TEXT.
    Text(Code, String),
    /// UIDREF.
    UidRef(Code, String),
    /// DATETIME (DT string).
    DateTime(Code, String),
}

/// A DS value within 16 characters (PS3.5 6.2; dicom-rs does not enforce it):
/// the most significant digits that fit, plain decimal when possible.
pub fn format_ds(v: f64) -> String {
    if !v.is_finite() {
        return "0".into();
    }
    for p in (0..=15usize).rev() {
        let mut s = format!("{v:.p$}");
        if s.contains('.') {
            s = s.trim_end_matches('0').trim_end_matches('.').to_string();
        }
        if s.len() <= 16 {
            if v == 0.0 || s.parse::<f64>().is_ok_and(|x| x != 0.0) {
                return s;
            }
            break;
        }
    }
    (0..=10usize)
        .rev()
        .map(|p| format!("{v:.p$E}"))
        .find(|s| s.len() <= 16)
        .unwrap_or_else(|| "0".into())
}

fn seq(items: Vec<InMemDicomObject>) -> DataSetSequence<InMemDicomObject> {
    DataSetSequence::from(items)
}

impl Item {
    fn concept(&self) -> &Code {
        match self {
            Item::Container(c, _)
            | Item::Code(c, _, _)
            | Item::Num(c, _, _, _)
            | Item::Text(c, _)
            | Item::UidRef(c, _)
            | Item::DateTime(c, _) => c,
        }
    }

    fn children(&self) -> &[(Rel, Item)] {
        match self {
            Item::Container(_, ch) | Item::Code(_, _, ch) | Item::Num(_, _, _, ch) => ch,
            _ => &[],
        }
    }

    /// The dataset of this item; `rel` is `None` for the root.
    pub(crate) fn dataset(&self, rel: Option<Rel>) -> InMemDicomObject {
        let mut o = InMemDicomObject::new_empty();
        if let Some(r) = rel {
            o.put(DataElement::new(tags::RELATIONSHIP_TYPE, VR::CS, r.cs()));
        }
        let vt = match self {
            Item::Container(..) => "CONTAINER",
            Item::Code(..) => "CODE",
            Item::Num(..) => "NUM",
            Item::Text(..) => "TEXT",
            Item::UidRef(..) => "UIDREF",
            Item::DateTime(..) => "DATETIME",
        };
        o.put(DataElement::new(tags::VALUE_TYPE, VR::CS, vt));
        o.put(DataElement::new(
            tags::CONCEPT_NAME_CODE_SEQUENCE,
            VR::SQ,
            seq(vec![self.concept().dataset()]),
        ));
        match self {
            Item::Container(..) => {
                o.put(DataElement::new(
                    tags::CONTINUITY_OF_CONTENT,
                    VR::CS,
                    "SEPARATE",
                ));
            }
            Item::Code(_, v, _) => {
                o.put(DataElement::new(
                    tags::CONCEPT_CODE_SEQUENCE,
                    VR::SQ,
                    seq(vec![v.dataset()]),
                ));
            }
            Item::Num(_, v, unit, _) => {
                let mv = InMemDicomObject::from_element_iter([
                    DataElement::new(
                        tags::MEASUREMENT_UNITS_CODE_SEQUENCE,
                        VR::SQ,
                        seq(vec![unit.dataset()]),
                    ),
                    DataElement::new(tags::NUMERIC_VALUE, VR::DS, format_ds(*v).as_str()),
                ]);
                o.put(DataElement::new(
                    tags::MEASURED_VALUE_SEQUENCE,
                    VR::SQ,
                    seq(vec![mv]),
                ));
            }
            Item::Text(_, t) => {
                o.put(DataElement::new(tags::TEXT_VALUE, VR::UT, t.as_str()));
            }
            Item::UidRef(_, u) => {
                o.put(DataElement::new(tags::UID, VR::UI, u.as_str()));
            }
            Item::DateTime(_, dt) => {
                o.put(DataElement::new(tags::DATE_TIME, VR::DT, dt.as_str()));
            }
        }
        let ch = self.children();
        if !ch.is_empty() {
            let items = ch.iter().map(|(r, i)| i.dataset(Some(*r))).collect();
            o.put(DataElement::new(tags::CONTENT_SEQUENCE, VR::SQ, seq(items)));
        }
        o
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ds_fits_16_characters() {
        for v in [
            0.0,
            1.0,
            -2.5,
            0.123_456_789_012_345_68,
            123_456_789.123_456_79,
            1e-12,
            -3.3e20,
            7.25,
        ] {
            let s = format_ds(v);
            assert!(s.len() <= 16, "{v}: `{s}`");
            let back: f64 = s.parse().unwrap();
            let tol = if v == 0.0 { 0.0 } else { v.abs() * 1e-9 };
            assert!((back - v).abs() <= tol, "{v} -> {s}");
        }
        assert_eq!(format_ds(7.25), "7.25");
        assert_eq!(format_ds(2.0), "2");
    }
}

/// The tube's Anode Target Material (0018,1191) defined term for
/// tungsten (the material a projection without the attribute is taken on).
pub const ANODE_TUNGSTEN: &str = "TUNGSTEN";

/// The tube's anode material, as the objects name it: Anode Target
/// Material (0018,1191) in the projections, CID 10016 "Anode Target
/// Material" in the dose report.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AnodeMaterial {
    /// Tungsten (W/Rh, W/Al, W/Ag beams).
    Tungsten,
    /// Molybdenum (Mo/Mo, Mo/Rh beams).
    Molybdenum,
    /// Rhodium (Rh/Rh beams).
    Rhodium,
}

impl AnodeMaterial {
    /// Every anode the objects name.
    pub const ALL: [AnodeMaterial; 3] = [
        AnodeMaterial::Tungsten,
        AnodeMaterial::Molybdenum,
        AnodeMaterial::Rhodium,
    ];

    /// The Anode Target Material (0018,1191) defined term.
    pub fn term(self) -> &'static str {
        match self {
            AnodeMaterial::Tungsten => ANODE_TUNGSTEN,
            AnodeMaterial::Molybdenum => "MOLYBDENUM",
            AnodeMaterial::Rhodium => "RHODIUM",
        }
    }

    /// The CID 10016 code (SNOMED CT, as pydicom's CID 10016 dictionary
    /// gives them; the legacy SRT codes were C-164F9, C-150F9 and C-167F9).
    pub fn code(self) -> Code {
        match self {
            AnodeMaterial::Tungsten => Code::new("26194003", "SCT", "Tungsten"),
            AnodeMaterial::Molybdenum => Code::new("71128006", "SCT", "Molybdenum"),
            AnodeMaterial::Rhodium => Code::new("59801003", "SCT", "Rhodium"),
        }
    }
}

/// An x-ray filter's material, as the objects name it: Filter Material
/// (0018,7050) in the projections, CID 10006 "X-Ray Filter Materials" in
/// the dose report.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FilterMaterial {
    /// Rhodium (W/Rh beams).
    Rhodium,
    /// Aluminium (W/Al beams).
    Aluminum,
    /// Silver (W/Ag beams).
    Silver,
    /// Molybdenum (Mo/Mo beams).
    Molybdenum,
}

impl FilterMaterial {
    /// The Filter Material (0018,7050) defined term.
    pub fn term(self) -> &'static str {
        match self {
            FilterMaterial::Rhodium => "RHODIUM",
            FilterMaterial::Aluminum => "ALUMINUM",
            FilterMaterial::Silver => "SILVER",
            FilterMaterial::Molybdenum => "MOLYBDENUM",
        }
    }

    /// The CID 10006 code (SNOMED CT; the legacy SRT codes were C-167F9,
    /// C-120F9, C-137F9 and C-150F9; silver's and molybdenum's SCT codes as
    /// pydicom's CID 10006 dictionary gives them).
    pub fn code(self) -> Code {
        match self {
            FilterMaterial::Rhodium => Code::new("59801003", "SCT", "Rhodium"),
            FilterMaterial::Aluminum => Code::new("12503006", "SCT", "Aluminum"),
            FilterMaterial::Silver => Code::new("41967008", "SCT", "Silver"),
            FilterMaterial::Molybdenum => Code::new("71128006", "SCT", "Molybdenum"),
        }
    }
}
