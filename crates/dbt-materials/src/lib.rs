//! The tissues of the DBToR model, defined once and used by the phantom generator,
//! the acquisition simulator, the trainer (through the dataset) and the firmware.
//!
//! * Label codes (`u8`) are ours: `0` air, `1` adipose, `2` skin, `3`
//!   fibroglandular, `4` Cooper's ligament. They are stored in phantoms and
//!   datasets; [`Tissue::from_label`] rejects any other code.
//! * Linear attenuation at 20 keV is the paper's (section "Materials", computed
//!   there with Boone and Chavez 1996): adipose 0.512 /cm, fibroglandular and
//!   Cooper's ligaments 0.798 /cm, skin 0.854 /cm. We store it per **mm**
//!   because every length in the geometry and projector is in mm.
//! * Mass densities and elemental compositions are Hammerstein et al. 1979, as
//!   quoted in AAPM TG-195 case 3 (`shared/reference/tg195-case3.md`). Cooper's
//!   ligaments take the composition and density of fibroglandular tissue, as in
//!   the paper.

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// A label code that names no tissue.
#[derive(Debug, Error, PartialEq, Eq)]
#[error("unknown tissue label {0} (known: 0 air, 1 adipose, 2 skin, 3 fibroglandular, 4 ligament)")]
pub struct UnknownLabel(pub u8);

/// One tissue class of the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, PartialOrd, Ord)]
#[serde(rename_all = "lowercase")]
pub enum Tissue {
    /// Air around the breast (attenuation neglected, as in the paper).
    Air,
    /// Adipose (fat) tissue.
    Adipose,
    /// The skin layer.
    Skin,
    /// Fibroglandular (dense) tissue.
    Fibroglandular,
    /// Cooper's ligaments (fibroglandular composition).
    Ligament,
}

/// An element's mass fraction in a composition.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ElementFraction {
    /// Atomic number.
    pub z: u8,
    /// Mass fraction (0..1).
    pub fraction: f64,
}

const fn ef(z: u8, percent: f64) -> ElementFraction {
    ElementFraction {
        z,
        fraction: percent / 100.0,
    }
}

/// Hammerstein 1979 adipose tissue (TG-195 case 3).
const ADIPOSE: [ElementFraction; 8] = [
    ef(1, 11.2),
    ef(6, 61.9),
    ef(7, 1.7),
    ef(8, 25.1),
    ef(15, 0.025),
    ef(16, 0.025),
    ef(19, 0.025),
    ef(20, 0.025),
];
/// Hammerstein 1979 glandular tissue (TG-195 case 3).
const GLANDULAR: [ElementFraction; 8] = [
    ef(1, 10.2),
    ef(6, 18.4),
    ef(7, 3.2),
    ef(8, 67.7),
    ef(15, 0.125),
    ef(16, 0.125),
    ef(19, 0.125),
    ef(20, 0.125),
];
/// Hammerstein 1979 skin (TG-195 case 3).
const SKIN: [ElementFraction; 8] = [
    ef(1, 9.8),
    ef(6, 17.8),
    ef(7, 5.0),
    ef(8, 66.7),
    ef(15, 0.175),
    ef(16, 0.175),
    ef(19, 0.175),
    ef(20, 0.175),
];
/// Dry air (TG-195 case 3).
const AIR_ELEMENTS: [ElementFraction; 4] = [
    ef(6, 0.0124),
    ef(7, 75.5268),
    ef(8, 23.1781),
    ef(18, 1.2827),
];

/// A non-tissue medium of the dose simulation (plates, body, air).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Composition {
    /// Name for reports.
    pub name: &'static str,
    /// Mass density, g/cm^3.
    pub density: f64,
    /// Elements by mass fraction.
    pub elements: &'static [ElementFraction],
}

/// Dry air (TG-195 case 3).
pub const AIR: Composition = Composition {
    name: "air",
    density: 0.001205,
    elements: &AIR_ELEMENTS,
};
/// PMMA compression plates (TG-195 case 3).
pub const PMMA: Composition = Composition {
    name: "PMMA",
    density: 1.19,
    elements: &[ef(1, 8.0541), ef(6, 59.9846), ef(8, 31.9613)],
};
/// PET (polyethylene terephthalate, C10H8O4), the paper's compression paddle.
pub const PET: Composition = Composition {
    name: "PET",
    density: 1.38,
    elements: &[ef(1, 4.1959), ef(6, 62.5017), ef(8, 33.3025)],
};
/// Caesium iodide, the scintillator of the detector (density 4.51 g/cm^3;
/// by mass Cs 132.905 / 259.81, I 126.904 / 259.81).
pub const CSI: Composition = Composition {
    name: "CsI",
    density: 4.51,
    elements: &[ef(55, 51.155), ef(53, 48.845)],
};
/// Amorphous selenium, the photoconductor of direct-conversion detectors
/// (Hologic, Siemens, Fujifilm, IMS). Density 4.3 g/cm^3: vitreous
/// selenium's 4.28 (CRC Handbook of Chemistry and Physics) rounded as the
/// a-Se detector literature gives it (Kasap et al., Phys. Status Solidi B
/// 246 (2009) 1794). Our choice between sources; the VICTRE MC-GPU input
/// (`DIDSR/VICTRE_MCGPU`, "MFP(Se,19.0keV)" = 40.27 um) implies PENELOPE's
/// 4.5 for selenium, with which 200 um absorbs 0.3 % more at 20 keV and 2 %
/// more at 30 keV (xraylib 4.3.0 `CS_Total`).
pub const A_SE: Composition = Composition {
    name: "a-Se",
    density: 4.3,
    elements: &[ef(34, 100.0)],
};

/// The x-ray converter of an energy-integrating flat panel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
pub enum ConverterMaterial {
    /// Caesium iodide scintillator on amorphous silicon (indirect
    /// conversion: GE).
    #[default]
    #[serde(rename = "CsI", alias = "csi", alias = "CSI")]
    CsI,
    /// Amorphous selenium photoconductor (direct conversion: Hologic,
    /// Siemens, Fujifilm).
    #[serde(rename = "a-Se", alias = "a-se", alias = "A-SE", alias = "a-SE")]
    ASe,
}

impl ConverterMaterial {
    /// Both, in declaration order.
    pub const ALL: [ConverterMaterial; 2] = [ConverterMaterial::CsI, ConverterMaterial::ASe];

    /// `CsI` or `a-Se`.
    pub fn name(self) -> &'static str {
        match self {
            ConverterMaterial::CsI => "CsI",
            ConverterMaterial::ASe => "a-Se",
        }
    }

    /// Its composition.
    pub fn composition(self) -> &'static Composition {
        match self {
            ConverterMaterial::CsI => &CSI,
            ConverterMaterial::ASe => &A_SE,
        }
    }

    /// Parse `CsI` or `a-Se` (case-insensitive); anything else is refused,
    /// naming it.
    pub fn parse(s: &str) -> Result<Self, ConverterError> {
        Self::ALL
            .into_iter()
            .find(|m| m.name().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| ConverterError::Material(s.to_string()))
    }
}

impl std::fmt::Display for ConverterMaterial {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A converter layer's thicknesses the product accepts, um: the
/// mammography and DBT flat panels' class (CsI 150-250 um, a-Se 200-250
/// um) with room either side; beyond it a figure is a typo.
pub const CONVERTER_UM: std::ops::RangeInclusive<f64> = 50.0..=1000.0;

/// A detector's converter: its material and thickness.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Converter {
    /// The material.
    pub material: ConverterMaterial,
    /// Its thickness, um.
    pub thickness_um: f64,
}

impl Default for Converter {
    /// 200 um of CsI (the thickness class of DBT flat panels, 150-250 um;
    /// our choice within it): the paper's gantry as we simulate it.
    fn default() -> Self {
        Self {
            material: ConverterMaterial::CsI,
            thickness_um: 200.0,
        }
    }
}

impl Converter {
    /// A converter of `material`, `thickness_um` thick; a thickness outside
    /// [`CONVERTER_UM`] (or not a number) is refused, naming it.
    pub fn new(material: ConverterMaterial, thickness_um: f64) -> Result<Self, ConverterError> {
        let c = Self {
            material,
            thickness_um,
        };
        c.validate()?;
        Ok(c)
    }

    /// Check the thickness against [`CONVERTER_UM`].
    pub fn validate(&self) -> Result<(), ConverterError> {
        if self.thickness_um.is_finite() && CONVERTER_UM.contains(&self.thickness_um) {
            Ok(())
        } else {
            Err(ConverterError::Thickness {
                material: self.material,
                um: self.thickness_um,
            })
        }
    }
}

impl std::fmt::Display for Converter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} um {}", self.thickness_um, self.material)
    }
}

/// A converter that cannot be.
#[derive(Debug, Error, PartialEq)]
pub enum ConverterError {
    /// A material other than CsI and a-Se.
    #[error("detector converter `{0}`: expected CsI or a-Se")]
    Material(String),
    /// A thickness outside [`CONVERTER_UM`].
    #[error("{um} um of {material}: a converter layer is {lo}-{hi} um thick", lo = CONVERTER_UM.start(), hi = CONVERTER_UM.end())]
    Thickness {
        /// The material.
        material: ConverterMaterial,
        /// The thickness given.
        um: f64,
    },
}

/// Water (the body in the dose simulation).
pub const WATER: Composition = Composition {
    name: "water",
    density: 1.0,
    elements: &[ef(1, 11.1894), ef(8, 88.8106)],
};

impl Tissue {
    /// Every tissue, in label order.
    pub const ALL: [Tissue; 5] = [
        Tissue::Air,
        Tissue::Adipose,
        Tissue::Skin,
        Tissue::Fibroglandular,
        Tissue::Ligament,
    ];

    /// The label code stored in phantoms and datasets.
    pub const fn label(self) -> u8 {
        match self {
            Tissue::Air => 0,
            Tissue::Adipose => 1,
            Tissue::Skin => 2,
            Tissue::Fibroglandular => 3,
            Tissue::Ligament => 4,
        }
    }

    /// The tissue of a label code.
    pub fn from_label(label: u8) -> Result<Tissue, UnknownLabel> {
        Tissue::ALL
            .get(label as usize)
            .copied()
            .ok_or(UnknownLabel(label))
    }

    /// Lower-case name, as used in sidecars, manifests and reports.
    pub const fn name(self) -> &'static str {
        match self {
            Tissue::Air => "air",
            Tissue::Adipose => "adipose",
            Tissue::Skin => "skin",
            Tissue::Fibroglandular => "fibroglandular",
            Tissue::Ligament => "ligament",
        }
    }

    /// Parse a name as written by [`Tissue::name`].
    pub fn from_name(name: &str) -> Option<Tissue> {
        Tissue::ALL.into_iter().find(|t| t.name() == name)
    }

    /// Linear attenuation coefficient at 20 keV in 1/mm (paper values /10).
    pub const fn mu_per_mm(self) -> f32 {
        match self {
            Tissue::Air => 0.0,
            Tissue::Adipose => 0.0512,
            Tissue::Skin => 0.0854,
            Tissue::Fibroglandular | Tissue::Ligament => 0.0798,
        }
    }

    /// Mass density in g/cm^3 (Hammerstein 1979; ligament = fibroglandular).
    pub const fn density_g_cm3(self) -> f64 {
        match self {
            Tissue::Air => 0.001205,
            Tissue::Adipose => 0.93,
            Tissue::Skin => 1.09,
            Tissue::Fibroglandular | Tissue::Ligament => 1.04,
        }
    }

    /// Elemental composition by mass (Hammerstein 1979; ligament = fibroglandular).
    pub fn composition(self) -> &'static [ElementFraction] {
        match self {
            Tissue::Air => &AIR_ELEMENTS,
            Tissue::Adipose => &ADIPOSE,
            Tissue::Skin => &SKIN,
            Tissue::Fibroglandular | Tissue::Ligament => &GLANDULAR,
        }
    }

    /// Whether the tissue counts as fibroglandular for glandularity and dose
    /// (the paper counts Cooper's ligaments as fibroglandular).
    pub const fn is_glandular(self) -> bool {
        matches!(self, Tissue::Fibroglandular | Tissue::Ligament)
    }
}

/// Composition of a homogeneous glandular/adipose mixture with glandular
/// mass fraction `g` (mass fractions mixed), and its density
/// `1 / (g / rho_g + (1 - g) / rho_a)` (volumes add).
pub fn glandular_adipose_mix(g: f64) -> (Vec<ElementFraction>, f64) {
    let comp = GLANDULAR
        .iter()
        .zip(ADIPOSE.iter())
        .map(|(eg, ea)| ElementFraction {
            z: eg.z,
            fraction: g * eg.fraction + (1.0 - g) * ea.fraction,
        })
        .collect();
    let rho = 1.0
        / (g / Tissue::Fibroglandular.density_g_cm3()
            + (1.0 - g) / Tissue::Adipose.density_g_cm3());
    (comp, rho)
}

/// Attenuation lookup table indexed by label code (codes above 4 are not
/// present; callers validate labels first).
pub const MU_BY_LABEL: [f32; 5] = [
    Tissue::Air.mu_per_mm(),
    Tissue::Adipose.mu_per_mm(),
    Tissue::Skin.mu_per_mm(),
    Tissue::Fibroglandular.mu_per_mm(),
    Tissue::Ligament.mu_per_mm(),
];

/// Glandularity by mass, `G = N_g rho_g / (N_g rho_g + N_a rho_a)` (paper eq. for
/// G), from voxel counts of fibroglandular (ligaments included) and adipose
/// tissue. Skin and air do not enter. Returns `None` when there is no breast
/// tissue at all.
pub fn glandularity(n_glandular: u64, n_adipose: u64) -> Option<f64> {
    let g = n_glandular as f64 * Tissue::Fibroglandular.density_g_cm3();
    let a = n_adipose as f64 * Tissue::Adipose.density_g_cm3();
    if g + a > 0.0 {
        Some(g / (g + a))
    } else {
        None
    }
}

/// Voxel counts per tissue of a label array; errors on the first unknown code.
pub fn count_labels(labels: &[u8]) -> Result<[u64; 5], UnknownLabel> {
    let mut hist = [0u64; 256];
    for &l in labels {
        hist[l as usize] += 1;
    }
    if let Some(bad) = (5..256).find(|&i| hist[i] > 0) {
        return Err(UnknownLabel(bad as u8));
    }
    Ok([hist[0], hist[1], hist[2], hist[3], hist[4]])
}

/// Glandularity of a label array (ligaments counted as fibroglandular).
pub fn glandularity_of_labels(labels: &[u8]) -> Result<Option<f64>, UnknownLabel> {
    let c = count_labels(labels)?;
    Ok(glandularity(c[3] + c[4], c[1]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_attenuation_values_per_cm() {
        // The paper quotes /cm; we store /mm.
        assert!((Tissue::Adipose.mu_per_mm() * 10.0 - 0.512).abs() < 1e-6);
        assert!((Tissue::Fibroglandular.mu_per_mm() * 10.0 - 0.798).abs() < 1e-6);
        assert!((Tissue::Ligament.mu_per_mm() * 10.0 - 0.798).abs() < 1e-6);
        assert!((Tissue::Skin.mu_per_mm() * 10.0 - 0.854).abs() < 1e-6);
        assert_eq!(Tissue::Air.mu_per_mm(), 0.0);
    }

    #[test]
    fn labels_round_trip_and_unknown_rejected() {
        for t in Tissue::ALL {
            assert_eq!(Tissue::from_label(t.label()), Ok(t));
            assert_eq!(Tissue::from_name(t.name()), Some(t));
            assert_eq!(MU_BY_LABEL[t.label() as usize], t.mu_per_mm());
        }
        assert_eq!(Tissue::from_label(5), Err(UnknownLabel(5)));
        assert_eq!(count_labels(&[0, 1, 9]), Err(UnknownLabel(9)));
    }

    #[test]
    fn compositions_sum_to_one() {
        for t in Tissue::ALL {
            let s: f64 = t.composition().iter().map(|e| e.fraction).sum();
            assert!((s - 1.0).abs() < 1e-6, "{t:?} sums to {s}");
        }
    }

    #[test]
    fn media_compositions_sum_to_one() {
        for c in [AIR, PMMA, PET, WATER, CSI, A_SE] {
            let s: f64 = c.elements.iter().map(|e| e.fraction).sum();
            assert!((s - 1.0).abs() < 1e-5, "{} sums to {s}", c.name);
        }
    }

    /// Converters: names parse back (case-insensitive), the default is 200
    /// um of CsI, the TOML form reads, and a material or thickness that
    /// cannot be is refused naming it.
    #[test]
    fn converters_parse_and_are_checked() {
        for m in ConverterMaterial::ALL {
            assert_eq!(ConverterMaterial::parse(m.name()), Ok(m));
            assert_eq!(ConverterMaterial::parse(&m.name().to_uppercase()), Ok(m));
        }
        assert_eq!(ConverterMaterial::ASe.composition().elements[0].z, 34);
        let e = ConverterMaterial::parse("GOS").unwrap_err().to_string();
        assert!(e.contains("`GOS`") && e.contains("a-Se"), "{e}");
        assert_eq!(Converter::default().to_string(), "200 um CsI");
        assert!(Converter::new(ConverterMaterial::ASe, 250.0).is_ok());
        for bad in [0.2, 1200.0, f64::NAN] {
            let e = Converter::new(ConverterMaterial::ASe, bad)
                .unwrap_err()
                .to_string();
            assert!(e.contains(&format!("{bad} um of a-Se")), "{e}");
        }
    }

    #[test]
    fn mixture_by_mass() {
        let (c, rho) = glandular_adipose_mix(0.2);
        let s: f64 = c.iter().map(|e| e.fraction).sum();
        assert!((s - 1.0).abs() < 1e-9);
        // TG-195 quotes 0.952 g/cm3 for its 20/80 breast, rounded; volumes
        // adding gives 0.9505.
        assert!((rho - 0.9505).abs() < 1e-3);
        assert_eq!(
            glandular_adipose_mix(1.0).0[0].fraction,
            GLANDULAR[0].fraction
        );
    }

    #[test]
    fn glandularity_by_mass() {
        // Equal voxel counts: G = 1.04 / (1.04 + 0.93).
        let g = glandularity(100, 100).unwrap();
        assert!((g - 1.04 / 1.97).abs() < 1e-12);
        assert_eq!(glandularity(0, 0), None);
        // Skin and air are ignored, ligaments count as glandular.
        let g = glandularity_of_labels(&[0, 2, 2, 1, 3, 4])
            .unwrap()
            .unwrap();
        assert!((g - 2.0 * 1.04 / (2.0 * 1.04 + 0.93)).abs() < 1e-12);
    }
}
