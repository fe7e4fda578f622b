//! A Storage SCP (issue #31, the DICOM input's network side): accepts
//! associations for the configured storage SOP classes and Verification,
//! answers C-ECHO, and hands every C-STORE's object to the caller as a DICOM
//! Part 10 file; the caller's verdict becomes the C-STORE response: Success
//! (0000H) only after the caller kept the object durably, else a failure
//! status with an Error Comment naming the reason (so the modality keeps
//! the object and may send it again: nothing it sent is lost).

use dicom_core::{dicom_value, DataElement, VR};
use dicom_dictionary_std::tags;
use dicom_object::{FileMetaTableBuilder, InMemDicomObject};
use dicom_transfer_syntax_registry::entries::{
    EXPLICIT_VR_LITTLE_ENDIAN, IMPLICIT_VR_LITTLE_ENDIAN,
};
use dicom_ul::association::server::ServerAssociationOptions;
use dicom_ul::pdu::{PDataValue, PDataValueType, Pdu};
use std::net::TcpStream;
use std::time::Duration;

/// C-STORE failure: cannot understand (the object is not usable input).
pub const STATUS_CANNOT_UNDERSTAND: u16 = 0xC000;
/// C-STORE failure: out of resources (the object could not be kept).
pub const STATUS_OUT_OF_RESOURCES: u16 = 0xA700;

/// What the caller says of one received object.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verdict {
    /// Kept durably: Success.
    Stored,
    /// Refused: the failure status and the Error Comment (at most 64
    /// characters are sent).
    Refused(u16, String),
}

/// One association's account: objects received and their verdicts, the
/// calling AE title, and why it ended if not by release.
#[derive(Debug, Clone, Default)]
pub struct AssociationReport {
    /// The modality's AE title.
    pub calling_ae_title: String,
    /// C-STORE requests answered, with the SOP instance UID and verdict.
    pub stores: Vec<(String, Verdict)>,
    /// C-ECHO requests answered.
    pub echoes: usize,
    /// An abort or a transport error, if the association did not end by
    /// release.
    pub error: Option<String>,
    /// Presentation contexts refused at negotiation: the abstract syntax
    /// and why (a class not served, or none of the transfer syntaxes
    /// proposed is one the SCP decodes).
    pub refused_contexts: Vec<String>,
}

/// What a C-STORE brought: the object as a Part 10 file, or the data set as
/// received when it could not be read.
pub type Received = Result<Vec<u8>, Unreadable>;

/// A C-STORE data set that could not be made a Part 10 file (truncated,
/// an element beyond its end): handed over as received, so the caller
/// keeps it with the reason.
#[derive(Debug, Clone)]
pub struct Unreadable {
    /// Why.
    pub reason: String,
    /// The presentation context's transfer syntax.
    pub transfer_syntax: String,
    /// The data set's bytes as received.
    pub data_set: Vec<u8>,
}

/// Serve one association on `stream` as `ae_title`, accepting `classes`
/// (and Verification) in explicit or implicit VR little endian; `on_store`
/// gets `(sop class, sop instance, Part 10 bytes)`, or the data set as
/// received and why it is not readable.
pub fn serve_association(
    stream: TcpStream,
    ae_title: &str,
    classes: &[&str],
    timeout: Duration,
    on_store: &mut dyn FnMut(&str, &str, Received) -> Verdict,
) -> AssociationReport {
    let mut report = AssociationReport::default();
    let mut opts = ServerAssociationOptions::new()
        .accept_called_ae_title()
        .ae_title(ae_title)
        .with_abstract_syntax(crate::VERIFICATION)
        .with_transfer_syntax(EXPLICIT_VR_LITTLE_ENDIAN.uid())
        .with_transfer_syntax(IMPLICIT_VR_LITTLE_ENDIAN.uid())
        .read_timeout(timeout)
        .write_timeout(timeout);
    for c in classes {
        opts = opts.with_abstract_syntax(*c);
    }
    let mut assoc = match opts.establish(stream) {
        Ok(a) => a,
        Err(e) => {
            report.error = Some(format!("association refused: {e}"));
            return report;
        }
    };
    report.calling_ae_title = {
        use dicom_ul::association::Association;
        assoc.peer_ae_title().to_string()
    };
    let pcs = assoc.presentation_contexts().to_vec();
    use dicom_ul::pdu::PresentationContextResultReason as Why;
    report.refused_contexts = pcs
        .iter()
        .filter(|p| p.reason != Why::Acceptance)
        .map(|p| {
            let why = match p.reason {
                Why::AbstractSyntaxNotSupported => "SOP class not served".to_string(),
                Why::TransferSyntaxesNotSupported => format!(
                    "none of the proposed transfer syntaxes is accepted (only {} and {})",
                    EXPLICIT_VR_LITTLE_ENDIAN.uid(),
                    IMPLICIT_VR_LITTLE_ENDIAN.uid()
                ),
                _ => format!("{:?}", p.reason),
            };
            format!("{}: {why}", p.abstract_syntax.trim_end_matches('\0'))
        })
        .collect();
    let mut command: Vec<u8> = Vec::new();
    let mut data: Vec<u8> = Vec::new();
    let mut pending: Option<(u8, InMemDicomObject)> = None;
    loop {
        let pdu = match assoc.receive() {
            Ok(p) => p,
            Err(e) => {
                report.error = Some(format!("receiving: {e}"));
                return report;
            }
        };
        match pdu {
            Pdu::PData { data: values } => {
                for v in values {
                    match v.value_type {
                        PDataValueType::Command => {
                            command.extend_from_slice(&v.data);
                            if !v.is_last {
                                continue;
                            }
                            let cmd = match InMemDicomObject::read_dataset_with_ts(
                                &command[..],
                                &IMPLICIT_VR_LITTLE_ENDIAN.erased(),
                            ) {
                                Ok(c) => c,
                                Err(e) => {
                                    report.error = Some(format!("bad command set: {e}"));
                                    let _ = assoc.abort();
                                    return report;
                                }
                            };
                            command.clear();
                            let field = cmd
                                .element(tags::COMMAND_FIELD)
                                .ok()
                                .and_then(|e| e.to_int::<u16>().ok())
                                .unwrap_or(0);
                            if field == 0x0030 {
                                // C-ECHO-RQ
                                let rsp = response(&cmd, 0x8030, 0, None);
                                if send(&mut assoc, v.presentation_context_id, &rsp).is_err() {
                                    report.error = Some("sending C-ECHO-RSP".into());
                                    return report;
                                }
                                report.echoes += 1;
                            } else {
                                pending = Some((v.presentation_context_id, cmd));
                            }
                        }
                        PDataValueType::Data => {
                            data.extend_from_slice(&v.data);
                            if !v.is_last {
                                continue;
                            }
                            let Some((pc_id, cmd)) = pending.take() else {
                                report.error = Some("a data set without a command".into());
                                let _ = assoc.abort();
                                return report;
                            };
                            let text = |t| {
                                cmd.element(t)
                                    .ok()
                                    .and_then(|e| e.to_str().ok())
                                    .map(|s| s.trim_end_matches('\0').trim().to_string())
                                    .unwrap_or_default()
                            };
                            let (class, instance) = (
                                text(tags::AFFECTED_SOP_CLASS_UID),
                                text(tags::AFFECTED_SOP_INSTANCE_UID),
                            );
                            let ts = pcs
                                .iter()
                                .find(|p| p.id == pc_id)
                                .map(|p| p.transfer_syntax.trim_end_matches('\0').to_string())
                                .unwrap_or_default();
                            let body = std::mem::take(&mut data);
                            let received =
                                part10(&class, &instance, &ts, &body).map_err(|reason| {
                                    Unreadable {
                                        reason,
                                        transfer_syntax: ts.clone(),
                                        data_set: body,
                                    }
                                });
                            let verdict = on_store(&class, &instance, received);
                            let (status, comment) = match &verdict {
                                Verdict::Stored => (0, None),
                                Verdict::Refused(s, c) => (*s, Some(c.as_str())),
                            };
                            let rsp = response(&cmd, 0x8001, status, comment);
                            report.stores.push((instance, verdict));
                            if send(&mut assoc, pc_id, &rsp).is_err() {
                                report.error = Some("sending C-STORE-RSP".into());
                                return report;
                            }
                        }
                    }
                }
            }
            Pdu::ReleaseRQ => {
                let _ = assoc.send(&Pdu::ReleaseRP);
                return report;
            }
            Pdu::AbortRQ { source } => {
                report.error = Some(format!("aborted by the peer: {source:?}"));
                return report;
            }
            other => {
                report.error = Some(format!("unexpected PDU {other:?}"));
                let _ = assoc.abort();
                return report;
            }
        }
    }
}

/// The data set received in transfer syntax `ts` as a Part 10 file.
fn part10(class: &str, instance: &str, ts: &str, body: &[u8]) -> Result<Vec<u8>, String> {
    let syntax = if ts == IMPLICIT_VR_LITTLE_ENDIAN.uid() {
        IMPLICIT_VR_LITTLE_ENDIAN.erased()
    } else if ts == EXPLICIT_VR_LITTLE_ENDIAN.uid() {
        EXPLICIT_VR_LITTLE_ENDIAN.erased()
    } else {
        return Err(format!("transfer syntax {ts} not accepted"));
    };
    let obj = InMemDicomObject::read_dataset_with_ts(body, &syntax)
        .map_err(|e| format!("data set unreadable: {e}"))?;
    let file = obj
        .with_meta(
            FileMetaTableBuilder::new()
                .transfer_syntax(EXPLICIT_VR_LITTLE_ENDIAN.uid())
                .media_storage_sop_class_uid(class)
                .media_storage_sop_instance_uid(instance)
                .implementation_class_uid("1.2.826.0.1.3680043.10.543.1")
                .implementation_version_name("DBTOR_0_1"),
        )
        .map_err(|e| format!("file meta: {e}"))?;
    let mut out = Vec::new();
    file.write_all(&mut out)
        .map_err(|e| format!("encoding: {e}"))?;
    Ok(out)
}

/// A response command set to `rq`.
fn response(
    rq: &InMemDicomObject,
    field: u16,
    status: u16,
    comment: Option<&str>,
) -> InMemDicomObject {
    let copy = |t| rq.element(t).ok().cloned();
    let mut r = InMemDicomObject::new_empty();
    if let Some(e) = copy(tags::AFFECTED_SOP_CLASS_UID) {
        r.put(e);
    }
    if let Some(e) = copy(tags::AFFECTED_SOP_INSTANCE_UID) {
        r.put(e);
    }
    let id = rq
        .element(tags::MESSAGE_ID)
        .ok()
        .and_then(|e| e.to_int::<u16>().ok())
        .unwrap_or(0);
    r.put(DataElement::new(
        tags::COMMAND_FIELD,
        VR::US,
        dicom_value!(U16, [field]),
    ));
    r.put(DataElement::new(
        tags::MESSAGE_ID_BEING_RESPONDED_TO,
        VR::US,
        dicom_value!(U16, [id]),
    ));
    r.put(DataElement::new(
        tags::COMMAND_DATA_SET_TYPE,
        VR::US,
        dicom_value!(U16, [0x0101]),
    ));
    r.put(DataElement::new(
        tags::STATUS,
        VR::US,
        dicom_value!(U16, [status]),
    ));
    if let Some(c) = comment {
        let c: String = c.chars().filter(|c| *c != '\\').take(64).collect();
        r.put(DataElement::new(tags::ERROR_COMMENT, VR::LO, c));
    }
    r
}

fn send(
    assoc: &mut dicom_ul::association::server::ServerAssociation<TcpStream>,
    pc: u8,
    cmd: &InMemDicomObject,
) -> Result<(), String> {
    let mut bytes = Vec::new();
    cmd.write_dataset_with_ts(&mut bytes, &IMPLICIT_VR_LITTLE_ENDIAN.erased())
        .map_err(|e| e.to_string())?;
    assoc
        .send(&Pdu::PData {
            data: vec![PDataValue {
                presentation_context_id: pc,
                value_type: PDataValueType::Command,
                is_last: true,
                data: bytes,
            }],
        })
        .map_err(|e| e.to_string())
}
