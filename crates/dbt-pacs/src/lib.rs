//! Getting reports out: DICOM C-ECHO and C-STORE (dicom-ul) to a configurable
//! PACS, retries with back-off, and a persistent outbox so that nothing is
//! lost while the PACS is down. Every report is also written to the output
//! folder.
//!
//! Delivery protocol ([`Outbox::deliver`]): the Part 10 bytes are written to
//! the output folder and to the outbox (each atomically: a temporary file,
//! then a rename), then the outbox is flushed; a report leaves the outbox only
//! after the PACS answered its C-STORE with status Success (0000H) or a
//! warning (Bxxx, stored with coercion). A report the PACS refuses with a
//! failure status stays in the outbox too, so a service engineer can see it.

pub mod scp;

use dicom_core::{dicom_value, DataElement, VR};
use dicom_dictionary_std::tags;
use dicom_object::InMemDicomObject;
use dicom_transfer_syntax_registry::entries::{
    EXPLICIT_VR_LITTLE_ENDIAN, IMPLICIT_VR_LITTLE_ENDIAN,
};
use dicom_ul::association::client::ClientAssociationOptions;
use dicom_ul::pdu::{PDataValue, PDataValueType, Pdu};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;
use thiserror::Error;

/// Verification SOP Class.
pub const VERIFICATION: &str = "1.2.840.10008.1.1";

/// Errors of the network and outbox adapter; each names the peer or file.
#[derive(Debug, Error)]
pub enum PacsError {
    /// Bad configuration.
    #[error("PACS configuration: {0}")]
    Config(String),
    /// Association or transport failure (the PACS may be down).
    #[error("PACS {peer}: {reason}")]
    Network {
        /// `AET@host:port`.
        peer: String,
        /// What went wrong.
        reason: String,
    },
    /// The PACS answered with a failure status.
    #[error("PACS {peer} refused {what}: status {status:04X}H")]
    Refused {
        /// `AET@host:port`.
        peer: String,
        /// The operation and instance.
        what: String,
        /// DIMSE status.
        status: u16,
    },
    /// A file could not be read or written.
    #[error("{path}: {reason}")]
    File {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
}

/// Where reports go.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PacsConfig {
    /// Called AE title.
    pub ae_title: String,
    /// Host name or address.
    pub host: String,
    /// Port.
    pub port: u16,
    /// Our (calling) AE title.
    #[serde(default = "default_calling")]
    pub calling_ae_title: String,
    /// Attempts per flush before giving up until the next flush.
    #[serde(default = "default_attempts")]
    pub attempts: u32,
    /// First back-off delay, ms (doubled after each failed attempt).
    #[serde(default = "default_backoff")]
    pub backoff_ms: u64,
    /// Network timeout, ms.
    #[serde(default = "default_timeout")]
    pub timeout_ms: u64,
}

fn default_calling() -> String {
    "DBTOR".into()
}
fn default_attempts() -> u32 {
    3
}
fn default_backoff() -> u64 {
    500
}
fn default_timeout() -> u64 {
    10_000
}

impl PacsConfig {
    /// A configuration with default retries.
    pub fn new(ae_title: &str, host: &str, port: u16) -> Self {
        Self {
            ae_title: ae_title.into(),
            host: host.into(),
            port,
            calling_ae_title: default_calling(),
            attempts: default_attempts(),
            backoff_ms: default_backoff(),
            timeout_ms: default_timeout(),
        }
    }

    /// Parse `AET@host:port`.
    pub fn parse(s: &str) -> Result<Self, PacsError> {
        let bad = || PacsError::Config(format!("`{s}` is not AET@host:port"));
        let (aet, rest) = s.split_once('@').ok_or_else(bad)?;
        let (host, port) = rest.rsplit_once(':').ok_or_else(bad)?;
        let port: u16 = port.parse().map_err(|_| bad())?;
        let cfg = Self::new(aet, host, port);
        cfg.validate()?;
        Ok(cfg)
    }

    /// AE titles: 1-16 characters, no backslash or control characters.
    pub fn validate(&self) -> Result<(), PacsError> {
        for (name, t) in [
            ("ae_title", &self.ae_title),
            ("calling_ae_title", &self.calling_ae_title),
        ] {
            if t.trim().is_empty() || t.len() > 16 || t.chars().any(|c| c == '\\' || c.is_control())
            {
                return Err(PacsError::Config(format!(
                    "{name} `{t}` must be 1-16 characters"
                )));
            }
        }
        if self.port == 0 || self.host.is_empty() {
            return Err(PacsError::Config("host and port are required".into()));
        }
        Ok(())
    }

    fn peer(&self) -> String {
        format!("{}@{}:{}", self.ae_title, self.host, self.port)
    }
}

fn net(cfg: &PacsConfig, e: impl std::fmt::Display) -> PacsError {
    PacsError::Network {
        peer: cfg.peer(),
        reason: e.to_string(),
    }
}

/// One DIMSE request/response on a fresh association; returns the status.
fn exchange(
    cfg: &PacsConfig,
    abstract_syntax: &str,
    command: InMemDicomObject,
    dataset: Option<&InMemDicomObject>,
) -> Result<u16, PacsError> {
    cfg.validate()?;
    let t = Duration::from_millis(cfg.timeout_ms);
    let addr = format!("{}:{}", cfg.host, cfg.port);
    let mut assoc = ClientAssociationOptions::new()
        .calling_ae_title(cfg.calling_ae_title.as_str())
        .called_ae_title(cfg.ae_title.as_str())
        .with_presentation_context(
            abstract_syntax,
            vec![
                EXPLICIT_VR_LITTLE_ENDIAN.uid(),
                IMPLICIT_VR_LITTLE_ENDIAN.uid(),
            ],
        )
        .connection_timeout(t)
        .read_timeout(t)
        .write_timeout(t)
        .establish(addr.as_str())
        .map_err(|e| net(cfg, format!("association: {e}")))?;
    let pc = assoc
        .presentation_contexts()
        .iter()
        .find(|p| p.reason == dicom_ul::pdu::PresentationContextResultReason::Acceptance)
        .cloned()
        .ok_or_else(|| {
            net(
                cfg,
                format!("no presentation context accepted for {abstract_syntax}"),
            )
        })?;
    let mut cmd = Vec::new();
    command
        .write_dataset_with_ts(&mut cmd, &IMPLICIT_VR_LITTLE_ENDIAN.erased())
        .map_err(|e| net(cfg, e))?;
    assoc
        .send(&Pdu::PData {
            data: vec![PDataValue {
                presentation_context_id: pc.id,
                value_type: PDataValueType::Command,
                is_last: true,
                data: cmd,
            }],
        })
        .map_err(|e| net(cfg, format!("sending command: {e}")))?;
    if let Some(ds) = dataset {
        let ts = if pc.transfer_syntax.trim_end_matches('\0') == IMPLICIT_VR_LITTLE_ENDIAN.uid() {
            IMPLICIT_VR_LITTLE_ENDIAN.erased()
        } else {
            EXPLICIT_VR_LITTLE_ENDIAN.erased()
        };
        let mut data = Vec::new();
        ds.write_dataset_with_ts(&mut data, &ts)
            .map_err(|e| net(cfg, e))?;
        let mut w = assoc.send_pdata(pc.id);
        w.write_all(&data)
            .map_err(|e| net(cfg, format!("sending data set: {e}")))?;
        w.finish()
            .map_err(|e| net(cfg, format!("sending data set: {e}")))?;
    }
    let status = match assoc
        .receive()
        .map_err(|e| net(cfg, format!("awaiting response: {e}")))?
    {
        Pdu::PData { data } => {
            let v = data.first().ok_or_else(|| net(cfg, "empty response"))?;
            let rsp = InMemDicomObject::read_dataset_with_ts(
                &v.data[..],
                &IMPLICIT_VR_LITTLE_ENDIAN.erased(),
            )
            .map_err(|e| net(cfg, format!("response: {e}")))?;
            rsp.element(tags::STATUS)
                .ok()
                .and_then(|e| e.to_int::<u16>().ok())
                .ok_or_else(|| net(cfg, "response without status"))?
        }
        other => return Err(net(cfg, format!("unexpected PDU {other:?}"))),
    };
    let _ = assoc.release();
    Ok(status)
}

/// C-ECHO: is the PACS there and talking DICOM?
pub fn echo(cfg: &PacsConfig) -> Result<(), PacsError> {
    let cmd = InMemDicomObject::command_from_element_iter([
        DataElement::new(tags::AFFECTED_SOP_CLASS_UID, VR::UI, VERIFICATION),
        DataElement::new(tags::COMMAND_FIELD, VR::US, dicom_value!(U16, [0x0030])),
        DataElement::new(tags::MESSAGE_ID, VR::US, dicom_value!(U16, [1])),
        DataElement::new(
            tags::COMMAND_DATA_SET_TYPE,
            VR::US,
            dicom_value!(U16, [0x0101]),
        ),
    ]);
    match exchange(cfg, VERIFICATION, cmd, None)? {
        0 => Ok(()),
        s => Err(PacsError::Refused {
            peer: cfg.peer(),
            what: "C-ECHO".into(),
            status: s,
        }),
    }
}

/// C-STORE one Part 10 file's data set.
pub fn store(cfg: &PacsConfig, part10: &[u8]) -> Result<(), PacsError> {
    let file = dicom_object::from_reader(part10)
        .map_err(|e| PacsError::Config(format!("not a DICOM file: {e}")))?;
    let class = file
        .meta()
        .media_storage_sop_class_uid()
        .trim_end_matches('\0')
        .to_string();
    let instance = file
        .meta()
        .media_storage_sop_instance_uid()
        .trim_end_matches('\0')
        .to_string();
    let cmd = InMemDicomObject::command_from_element_iter([
        DataElement::new(tags::AFFECTED_SOP_CLASS_UID, VR::UI, class.as_str()),
        DataElement::new(tags::COMMAND_FIELD, VR::US, dicom_value!(U16, [0x0001])),
        DataElement::new(tags::MESSAGE_ID, VR::US, dicom_value!(U16, [1])),
        DataElement::new(tags::PRIORITY, VR::US, dicom_value!(U16, [0x0000])),
        DataElement::new(
            tags::COMMAND_DATA_SET_TYPE,
            VR::US,
            dicom_value!(U16, [0x0000]),
        ),
        DataElement::new(tags::AFFECTED_SOP_INSTANCE_UID, VR::UI, instance.as_str()),
    ]);
    let status = exchange(cfg, &class, cmd, Some(&file))?;
    if status == 0 || status & 0xF000 == 0xB000 {
        Ok(())
    } else {
        Err(PacsError::Refused {
            peer: cfg.peer(),
            what: format!("C-STORE of {instance}"),
            status,
        })
    }
}

/// `store` with `attempts` tries and doubling back-off between them; a
/// refusal by the PACS is not retried.
pub fn store_with_retry(cfg: &PacsConfig, part10: &[u8]) -> Result<(), PacsError> {
    let mut delay = cfg.backoff_ms;
    let mut last = None;
    for attempt in 1..=cfg.attempts.max(1) {
        match store(cfg, part10) {
            Ok(()) => return Ok(()),
            Err(e @ PacsError::Refused { .. }) | Err(e @ PacsError::Config(_)) => return Err(e),
            Err(e) => {
                tracing::warn!(attempt, error = %e, "C-STORE failed");
                last = Some(e);
                if attempt < cfg.attempts {
                    std::thread::sleep(Duration::from_millis(delay));
                    delay = delay.saturating_mul(2);
                }
            }
        }
    }
    Err(last.unwrap_or_else(|| net(cfg, "no attempt made")))
}

/// The output folder and the outbox.
#[derive(Debug, Clone)]
pub struct Outbox {
    /// Every report is written here and stays.
    pub output_dir: PathBuf,
    /// Reports waiting for the PACS.
    pub outbox_dir: PathBuf,
}

fn file_err(path: &Path, e: impl std::fmt::Display) -> PacsError {
    PacsError::File {
        path: path.to_path_buf(),
        reason: e.to_string(),
    }
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), PacsError> {
    let tmp = path.with_extension("part");
    {
        let mut f = std::fs::File::create(&tmp).map_err(|e| file_err(&tmp, e))?;
        f.write_all(bytes).map_err(|e| file_err(&tmp, e))?;
        f.sync_all().map_err(|e| file_err(&tmp, e))?;
    }
    std::fs::rename(&tmp, path).map_err(|e| file_err(path, e))
}

/// What a flush did.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct FlushReport {
    /// Files sent and removed from the outbox.
    pub sent: Vec<PathBuf>,
    /// Files left in the outbox, with the reason.
    pub waiting: Vec<(PathBuf, String)>,
}

impl Outbox {
    /// Create both folders.
    pub fn open(output_dir: &Path, outbox_dir: &Path) -> Result<Self, PacsError> {
        for d in [output_dir, outbox_dir] {
            std::fs::create_dir_all(d).map_err(|e| file_err(d, e))?;
        }
        Ok(Self {
            output_dir: output_dir.into(),
            outbox_dir: outbox_dir.into(),
        })
    }

    /// Write a report (named `name.dcm`) to the output folder and the outbox,
    /// then flush the outbox to `pacs` if one is configured.
    pub fn deliver(
        &self,
        name: &str,
        part10: &[u8],
        pacs: Option<&PacsConfig>,
    ) -> Result<FlushReport, PacsError> {
        if name.is_empty() || name.contains(['/', '\\']) || name.starts_with('.') {
            return Err(PacsError::Config(format!("report name `{name}`")));
        }
        write_atomic(&self.output_dir.join(format!("{name}.dcm")), part10)?;
        write_atomic(&self.outbox_dir.join(format!("{name}.dcm")), part10)?;
        match pacs {
            Some(p) => self.flush(p),
            None => Ok(FlushReport::default()),
        }
    }

    /// Reports waiting in the outbox, oldest name first.
    pub fn pending(&self) -> Result<Vec<PathBuf>, PacsError> {
        let mut v: Vec<PathBuf> = std::fs::read_dir(&self.outbox_dir)
            .map_err(|e| file_err(&self.outbox_dir, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "dcm"))
            .collect();
        v.sort();
        Ok(v)
    }

    /// Try to send every waiting report; stop at the first network failure
    /// (the PACS is down: the rest waits too).
    pub fn flush(&self, pacs: &PacsConfig) -> Result<FlushReport, PacsError> {
        let mut rep = FlushReport::default();
        let pending = self.pending()?;
        let mut down: Option<String> = None;
        for p in pending {
            if let Some(reason) = &down {
                rep.waiting.push((p, reason.clone()));
                continue;
            }
            let bytes = std::fs::read(&p).map_err(|e| file_err(&p, e))?;
            match store_with_retry(pacs, &bytes) {
                Ok(()) => {
                    std::fs::remove_file(&p).map_err(|e| file_err(&p, e))?;
                    tracing::info!(file = %p.display(), "report stored in PACS");
                    rep.sent.push(p);
                }
                Err(e @ PacsError::Network { .. }) => {
                    down = Some(e.to_string());
                    rep.waiting.push((p, e.to_string()));
                }
                Err(e) => rep.waiting.push((p, e.to_string())),
            }
        }
        Ok(rep)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_parsing() {
        let c = PacsConfig::parse("ORTHANC@127.0.0.1:4242").unwrap();
        assert_eq!(
            (c.ae_title.as_str(), c.host.as_str(), c.port),
            ("ORTHANC", "127.0.0.1", 4242)
        );
        assert!(PacsConfig::parse("ORTHANC127.0.0.1:4242").is_err());
        assert!(PacsConfig::parse("A@h:notaport").is_err());
        assert!(PacsConfig::parse("WAY_TOO_LONG_AE_TITLE@h:1").is_err());
    }

    #[test]
    fn pacs_down_keeps_reports_in_the_outbox() {
        let d = tempfile::tempdir().unwrap();
        let ob = Outbox::open(&d.path().join("out"), &d.path().join("outbox")).unwrap();
        // A port nobody listens on.
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let port = l.local_addr().unwrap().port();
        drop(l);
        let mut cfg = PacsConfig::new("NOBODY", "127.0.0.1", port);
        cfg.attempts = 2;
        cfg.backoff_ms = 10;
        cfg.timeout_ms = 500;
        assert!(matches!(echo(&cfg), Err(PacsError::Network { .. })));
        let bytes = b"not even DICOM, but the outbox does not care".to_vec();
        let rep = ob.deliver("r1", &bytes, Some(&cfg)).unwrap();
        assert!(rep.sent.is_empty());
        assert_eq!(rep.waiting.len(), 1);
        assert!(d.path().join("out/r1.dcm").exists());
        assert_eq!(ob.pending().unwrap().len(), 1);
        assert!(ob.deliver("../evil", &bytes, None).is_err());
    }
}
