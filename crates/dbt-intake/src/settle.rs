//! Settling an acquisition: what the gantry delivered (the acquisition as
//! received and spooled) and what the link saw at the time (the gantry
//! note: the Modbus registers at the start and the end of the sweep, the
//! beam the stream's header stated, a data fault) turned, under the site's
//! policy, into the acquisition the pipeline reports, or a refusal that
//! names why. Pure: the daemon reads the note from the spool and passes the
//! site's configuration; the same function settles every entry, so a
//! replay of the settled header computes what was reported.
//!
//! The rules, in order:
//! 1. a data fault seen at receipt (saturated pixels) refuses the entry;
//! 2. frames with the gantry's registers read (Modbus on): the thickness
//!    register at the start against the end (the breast moved) and against
//!    the header, each within the site's tolerance; the beam is register 6's
//!    (one the dose model has no spectra for is refused, and so is a stream
//!    header stating another beam);
//! 3. frames without registers whose header states no beam: the site's
//!    unstated beam, or refused where the site takes none for granted
//!    (a DICOM object's beam was settled by the DICOM input from its own
//!    attributes);
//! 4. the beam's tube output at the exposure's kV (the site's QC),
//!    refused where the site has none for the beam or the kV is outside
//!    its table;
//! 5. the compression force from the registers where the input gave none.

use crate::acquisition::Acquisition;
use crate::technique::TubeOutput;
use dbt_dose::xray::AnodeFilter;
use dbt_gantry::stats::LinkStats;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Where an acquisition came in.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Source {
    /// The framed projection stream (TCP or serial line).
    #[default]
    Frames,
    /// The DICOM input (a Storage SCP).
    Dicom,
}

/// The gantry's registers as read at one moment of a sweep.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RegisterValues {
    /// Compressed thickness, mm.
    pub thickness_mm: f64,
    /// Tube voltage, kV.
    pub kvp: f64,
    /// mAs per projection.
    pub mas_per_projection: f64,
    /// Number of projections.
    pub projections: u16,
    /// Anode/filter as register 6 names it (`W/Rh`, `W/Al`, `W/Ag`, ...).
    pub anode_filter: String,
    /// `L` or `R`.
    pub laterality: String,
    /// `CC`, `MLO`, `ML` or `LM`.
    pub view: String,
    /// The gantry's fault code (0: none).
    pub fault: u16,
    /// Compression force, N.
    pub force_n: f64,
}

impl From<&dbt_gantry::registers::Registers> for RegisterValues {
    fn from(r: &dbt_gantry::registers::Registers) -> Self {
        RegisterValues {
            thickness_mm: r.thickness_mm,
            kvp: r.kvp,
            mas_per_projection: r.mas_per_projection,
            projections: r.projections,
            anode_filter: r.anode_filter.to_string(),
            laterality: r.laterality.to_string(),
            view: r.view.to_string(),
            fault: r.fault,
            force_n: r.force_n,
        }
    }
}

/// One reading of the registers: their values, or why they could not be
/// read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum RegisterReading {
    /// Not read (timeout, exception, no endpoint).
    Failed {
        /// Why.
        error: String,
    },
    /// Read.
    Read(RegisterValues),
}

impl RegisterReading {
    /// The values, if read.
    pub fn values(&self) -> Option<&RegisterValues> {
        match self {
            RegisterReading::Read(v) => Some(v),
            RegisterReading::Failed { .. } => None,
        }
    }
}

/// What the link saw of one acquisition, kept beside it in the spool
/// (`gantry.json`) and read when it is settled.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct GantryNote {
    /// How it came in.
    #[serde(default)]
    pub source: Source,
    /// Frames: the reception's counters.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub link: Option<LinkStats>,
    /// Frames: pixels at the detector's saturation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub saturated_pixels: Option<u64>,
    /// The registers at the start of the sweep (absent: Modbus off).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modbus: Option<RegisterReading>,
    /// The registers after the sweep.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modbus_end: Option<RegisterReading>,
    /// The beam the stream's header stated (optional there).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub header_anode_filter: Option<String>,
    /// Why the data are unfit for a report, as seen at receipt.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub data_fault: Option<String>,
    /// DICOM: the objects' SOP class.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sop_class: Option<String>,
    /// DICOM: each object's SOP Instance UID and the digest of its counts
    /// (a resent object is recognised and not reported twice).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub objects: BTreeMap<String, u64>,
}

/// The site's rules for settling an acquisition (its configuration).
#[derive(Debug, Clone, PartialEq)]
pub struct SitePolicy {
    /// Where the gantry's registers are read (Modbus on): the largest
    /// difference between the thickness register and the header, and
    /// between the register at the start and at the end, mm. `None`:
    /// Modbus off.
    pub thickness_tolerance_mm: Option<f64>,
    /// The beam of an acquisition whose input states none; `None`: refused.
    pub unstated_beam: Option<AnodeFilter>,
    /// Each beam's tube output, where configured.
    pub tube_outputs: Vec<(AnodeFilter, TubeOutput)>,
}

/// Why an acquisition is not reported: the status file's fault kind and
/// the message.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{kind}: {message}")]
pub struct Refusal {
    /// What kind of fault.
    pub kind: RefusalKind,
    /// What was wrong, naming the values.
    pub message: String,
}

/// The kinds of [`Refusal`] (the status file's fault kinds).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RefusalKind {
    /// The data are unfit for a report (saturation).
    Data,
    /// The thickness registers disagree with each other or the header, or
    /// were not read.
    Thickness,
    /// The beam or its tube output.
    Technique,
}

impl RefusalKind {
    /// The status file's name of the kind.
    pub fn name(self) -> &'static str {
        match self {
            RefusalKind::Data => "data",
            RefusalKind::Thickness => "thickness",
            RefusalKind::Technique => "technique",
        }
    }
}

impl std::fmt::Display for RefusalKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

fn refuse(kind: RefusalKind, message: String) -> Refusal {
    Refusal { kind, message }
}

/// The acquisition settled by the note and the site's policy (the module's
/// rules), or the refusal.
pub fn settle(
    mut acq: Acquisition,
    note: &GantryNote,
    policy: &SitePolicy,
) -> Result<Acquisition, Refusal> {
    if let Some(msg) = &note.data_fault {
        return Err(refuse(RefusalKind::Data, msg.clone()));
    }
    let start = note.modbus.as_ref().and_then(RegisterReading::values);
    let h = &mut acq.header;
    match (policy.thickness_tolerance_mm, note.source) {
        (Some(tol), Source::Frames) => {
            let reg = start.map(|r| r.thickness_mm);
            let end = note
                .modbus_end
                .as_ref()
                .and_then(RegisterReading::values)
                .map(|r| r.thickness_mm);
            let header = h.thickness_mm;
            let msg = match (reg, end) {
                (Some(r), Some(e)) if (e - r).abs() > tol => Some(format!(
                    "thickness changed during the sweep: Modbus register {r:.1} mm at the start, {e:.1} mm at the end (tolerance {tol} mm)"
                )),
                (None, _) => Some(format!(
                    "no Modbus thickness at exposure time ({}); header says {header} mm",
                    match &note.modbus {
                        Some(RegisterReading::Failed { error }) => error.as_str(),
                        _ => "not read",
                    }
                )),
                (Some(r), _) if (r - header).abs() > tol => Some(format!(
                    "thickness disagreement: Modbus register {r:.1} mm, acquisition header {header:.1} mm (tolerance {tol} mm)"
                )),
                _ => None,
            };
            if let Some(msg) = msg {
                return Err(refuse(RefusalKind::Thickness, msg));
            }
            // The dose model has spectra for tungsten filtered by rhodium
            // or aluminium: another beam would be dosed wrong (issue #27).
            // The register names the beam; a header stating another is a
            // disagreement, not reported.
            let af = start.map_or("missing", |r| r.anode_filter.as_str());
            let Ok(beam) = AnodeFilter::parse(af) else {
                return Err(refuse(
                    RefusalKind::Technique,
                    format!(
                        "anode/filter {af} (Modbus register 6): the dose model's spectra are {} only; not reported",
                        AnodeFilter::supported()
                    ),
                ));
            };
            if let Some(stated) = note
                .header_anode_filter
                .as_deref()
                .filter(|s| *s != beam.name())
            {
                return Err(refuse(
                    RefusalKind::Technique,
                    format!(
                        "anode/filter disagreement: Modbus register 6 {beam}, acquisition header {stated}; not reported"
                    ),
                ));
            }
            h.anode_filter = beam;
        }
        (_, Source::Frames) if note.header_anode_filter.is_none() => {
            // Frames whose header states no beam: the registers' where they
            // were read at receipt (a site that turned Modbus off since),
            // else the site's unstated beam, or refused.
            let register = start.and_then(|r| AnodeFilter::parse(&r.anode_filter).ok());
            match register.or(policy.unstated_beam) {
                Some(b) => h.anode_filter = b,
                None => {
                    return Err(refuse(
                        RefusalKind::Technique,
                        "anode/filter: neither the acquisition header nor a Modbus register states the beam, and this site takes none for granted ([report] unstated_beam = \"refuse\"); not reported".into(),
                    ))
                }
            }
        }
        _ => {}
    }
    // The dose's incident kerma is the beam's own tube output (QC), at the
    // exposure's kV where the QC measured it by kV.
    let beam = h.anode_filter;
    let output = policy
        .tube_outputs
        .iter()
        .find(|(b, _)| *b == beam)
        .map(|(_, t)| t)
        .ok_or_else(|| {
            format!(
                "anode/filter {beam}: no tube output configured for this beam ({}); its dose cannot be computed; not reported",
                crate::technique::tube_output_key(beam)
            )
        })
        .and_then(|t| {
            t.at(h.kvp).map_err(|e| {
                format!("tube output of {beam}: {e}; its dose cannot be computed; not reported")
            })
        })
        .map_err(|m| refuse(RefusalKind::Technique, m))?;
    h.tube_output_mgy_per_mas = output;
    // The force the gantry reported at exposure time goes into the dose SR
    // (a DICOM object carries its own).
    if h.compression_force_n.is_none() {
        h.compression_force_n = start
            .map(|r| r.force_n)
            .filter(|f| f.is_finite() && *f > 0.0 && *f <= 500.0);
    }
    Ok(acq)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::acquisition::example_header;
    use crate::technique::KvTable;

    fn acquisition() -> Acquisition {
        let mut header = example_header(dbt_geometry::Geometry::paper(), 1, None);
        header.thickness_mm = 50.0;
        header.kvp = 30.0;
        header.tube_output_mgy_per_mas = 0.0;
        Acquisition {
            header,
            counts: vec![],
        }
    }

    fn registers(thickness_mm: f64, anode_filter: &str) -> RegisterReading {
        RegisterReading::Read(RegisterValues {
            thickness_mm,
            kvp: 30.0,
            mas_per_projection: 2.0,
            projections: 25,
            anode_filter: anode_filter.into(),
            laterality: "L".into(),
            view: "CC".into(),
            fault: 0,
            force_n: 120.0,
        })
    }

    fn policy() -> SitePolicy {
        SitePolicy {
            thickness_tolerance_mm: Some(2.0),
            unstated_beam: Some(AnodeFilter::WRh),
            tube_outputs: vec![
                (AnodeFilter::WRh, TubeOutput::Single(0.11)),
                (
                    AnodeFilter::WAl,
                    TubeOutput::ByKv(KvTable {
                        kv: vec![25.0, 35.0],
                        mgy_per_mas: vec![0.06, 0.12],
                    }),
                ),
            ],
        }
    }

    fn note(start: Option<RegisterReading>, end: Option<RegisterReading>) -> GantryNote {
        GantryNote {
            modbus: start,
            modbus_end: end,
            ..Default::default()
        }
    }

    fn refused(r: Result<Acquisition, Refusal>) -> Refusal {
        r.expect_err("refused")
    }

    /// The registers agree: settled with register 6's beam, the tube
    /// output at the kV and the register's force.
    #[test]
    fn agreeing_registers_settle_the_beam_output_and_force() {
        let n = note(Some(registers(50.5, "W/Al")), Some(registers(50.4, "W/Al")));
        let a = settle(acquisition(), &n, &policy()).unwrap();
        assert_eq!(a.header.anode_filter, AnodeFilter::WAl);
        // Between 25 and 35 kV as a power of the kV: 0.06 (30/25)^(ln 2 / ln 1.4).
        let want = 0.06 * (30.0f64 / 25.0).powf(2f64.ln() / 1.4f64.ln());
        assert!((a.header.tube_output_mgy_per_mas - want).abs() < 1e-12);
        assert_eq!(a.header.compression_force_n, Some(120.0));
    }

    /// Each thickness rule refuses alone, naming the values.
    #[test]
    fn the_thickness_rules_refuse_by_name() {
        let p = policy();
        let r = refused(settle(
            acquisition(),
            &note(Some(registers(50.0, "W/Rh")), Some(registers(53.0, "W/Rh"))),
            &p,
        ));
        assert_eq!(r.kind, RefusalKind::Thickness);
        assert!(
            r.message.contains("changed during the sweep")
                && r.message.contains("53.0 mm at the end"),
            "{r}"
        );
        let r = refused(settle(
            acquisition(),
            &note(Some(registers(47.0, "W/Rh")), Some(registers(47.0, "W/Rh"))),
            &p,
        ));
        assert!(
            r.message
                .contains("Modbus register 47.0 mm, acquisition header 50.0 mm"),
            "{r}"
        );
        let r = refused(settle(
            acquisition(),
            &note(
                Some(RegisterReading::Failed {
                    error: "timeout after 3 attempts".into(),
                }),
                None,
            ),
            &p,
        ));
        assert!(
            r.message
                .contains("no Modbus thickness at exposure time (timeout after 3 attempts)"),
            "{r}"
        );
        let r = refused(settle(acquisition(), &note(None, None), &p));
        assert!(r.message.contains("(not read)"), "{r}");
        assert_eq!(r.kind.name(), "thickness");
    }

    /// A beam the dose has no spectra for, or a header stating another
    /// beam than the register: refused; a beam without a tube output or a
    /// kV outside its table: refused.
    #[test]
    fn the_beam_rules_refuse_by_name() {
        let p = policy();
        let r = refused(settle(
            acquisition(),
            &note(
                Some(registers(50.0, "Rh/Ag")),
                Some(registers(50.0, "Rh/Ag")),
            ),
            &p,
        ));
        assert_eq!(r.kind, RefusalKind::Technique);
        assert!(
            r.message.contains("anode/filter Rh/Ag (Modbus register 6)"),
            "{r}"
        );
        let mut n = note(Some(registers(50.0, "W/Rh")), Some(registers(50.0, "W/Rh")));
        n.header_anode_filter = Some("W/Al".into());
        let r = refused(settle(acquisition(), &n, &p));
        assert!(
            r.message
                .contains("Modbus register 6 W/Rh, acquisition header W/Al"),
            "{r}"
        );
        let only_rh = SitePolicy {
            tube_outputs: vec![(AnodeFilter::WRh, TubeOutput::Single(0.11))],
            ..policy()
        };
        let r = refused(settle(
            acquisition(),
            &note(Some(registers(50.0, "W/Al")), Some(registers(50.0, "W/Al"))),
            &only_rh,
        ));
        assert!(r.message.contains("no tube output configured"), "{r}");
        let mut hot = acquisition();
        hot.header.kvp = 38.0;
        let r = refused(settle(
            hot,
            &note(Some(registers(50.0, "W/Al")), Some(registers(50.0, "W/Al"))),
            &p,
        ));
        assert!(
            r.message
                .contains("38 kV is outside the tube output's measured 25-35 kV"),
            "{r}"
        );
    }

    /// Without registers, a header stating no beam takes the site's
    /// unstated beam, or is refused where the site takes none; a header
    /// stating one keeps it; a DICOM entry is not held to the registers.
    #[test]
    fn the_unstated_beam_and_the_dicom_input() {
        let off = SitePolicy {
            thickness_tolerance_mm: None,
            unstated_beam: Some(AnodeFilter::WAl),
            ..policy()
        };
        let mut a = acquisition();
        a.header.kvp = 28.0;
        let s = settle(a.clone(), &GantryNote::default(), &off).unwrap();
        assert_eq!(s.header.anode_filter, AnodeFilter::WAl);
        assert_eq!(s.header.compression_force_n, None);
        let refuse_all = SitePolicy {
            unstated_beam: None,
            ..off.clone()
        };
        let r = refused(settle(a.clone(), &GantryNote::default(), &refuse_all));
        assert!(r.message.contains("unstated_beam = \"refuse\""), "{r}");
        let stated = GantryNote {
            header_anode_filter: Some("W/Rh".into()),
            ..Default::default()
        };
        let s = settle(a.clone(), &stated, &refuse_all).unwrap();
        assert_eq!(s.header.anode_filter, AnodeFilter::WRh);
        // DICOM, Modbus on: no register needed, the object's beam kept.
        let dicom = GantryNote {
            source: Source::Dicom,
            ..Default::default()
        };
        let s = settle(a, &dicom, &policy()).unwrap();
        assert_eq!(s.header.anode_filter, AnodeFilter::WRh);
        assert_eq!(s.header.tube_output_mgy_per_mas, 0.11);
    }

    /// A data fault refuses before anything else.
    #[test]
    fn a_data_fault_refuses_first() {
        let n = GantryNote {
            data_fault: Some("12 pixels saturated at 65535 in views [3]".into()),
            ..Default::default()
        };
        let r = refused(settle(acquisition(), &n, &policy()));
        assert_eq!(r.kind, RefusalKind::Data);
        assert!(r.message.contains("12 pixels saturated"));
    }

    /// The notes the daemon and the DICOM input wrote before the note was
    /// typed read as the same note.
    #[test]
    fn earlier_untyped_notes_read_back() {
        let frames = r#"{"link": {"bytes": 10, "frames": 2, "crc_errors": 0, "length_errors": 0, "naks": 0, "garbage_bytes": 0, "suppressed_logs": 0},
            "saturated_pixels": 0, "modbus": {"thickness_mm": 50.0, "kvp": 30.0, "mas_per_projection": 2.0, "projections": 25,
            "anode_filter": "W/Rh", "laterality": "L", "view": "CC", "fault": 0, "force_n": 100.0},
            "modbus_end": {"error": "timeout"}, "header_anode_filter": null, "data_fault": null}"#;
        let n: GantryNote = serde_json::from_str(frames).unwrap();
        assert_eq!(n.source, Source::Frames);
        assert_eq!(
            n.modbus
                .as_ref()
                .and_then(|r| r.values())
                .map(|v| v.thickness_mm),
            Some(50.0)
        );
        assert!(matches!(n.modbus_end, Some(RegisterReading::Failed { .. })));
        assert_eq!(n.link.as_ref().map(|l| l.frames), Some(2));
        let off = r#"{"link": {}, "saturated_pixels": 0, "modbus": null, "modbus_end": null, "header_anode_filter": "W/Al", "data_fault": null}"#;
        let n: GantryNote = serde_json::from_str(off).unwrap();
        assert!(n.modbus.is_none() && n.header_anode_filter.as_deref() == Some("W/Al"));
        let dicom = r#"{"source": "dicom", "sop_class": "1.2.840.10008.5.1.4.1.1.13.1.4", "objects": {"1.2.3": 42}}"#;
        let n: GantryNote = serde_json::from_str(dicom).unwrap();
        assert_eq!(n.source, Source::Dicom);
        assert_eq!(n.objects.get("1.2.3"), Some(&42));
        let back: GantryNote = serde_json::from_str(&serde_json::to_string(&n).unwrap()).unwrap();
        assert_eq!(back, n);
    }
}
