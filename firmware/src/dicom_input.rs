//! The daemon's DICOM input (issue #31): a thread serving the Storage SCP
//! (`dbt_pacs::scp`) on `[dicom_input] address`. Every Breast Projection
//! X-Ray For Processing object received is read
//! (`dbt_dicom::projections::read_projection_object`), made an acquisition
//! on the configured system (`dbt_pipeline::dicom_input`) and spooled
//! durably (`daemon::spool_entry`) before the C-STORE is answered Success;
//! the daemon's loop then processes it like a frame-link acquisition. An
//! object that cannot be used is answered with a failure status naming why,
//! kept in `faulted/<id>/` (the object and `fault.json`), and reported as an
//! `input` fault in the status. One multi-frame object is one acquisition.

use crate::daemon::{entry_id, spool_entry, write_durable};
use dbt_pacs::scp::{
    serve_association, Verdict, STATUS_CANNOT_UNDERSTAND, STATUS_OUT_OF_RESOURCES,
};
use dbt_pipeline::dicom_input::{acquisition_from_projections, System};
use dbt_status::FaultRecord;
use std::net::{SocketAddr, TcpListener};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// The storage classes the input accepts.
pub const ACCEPTED: [&str; 1] = [dbt_dicom::projections::BPXR_FOR_PROCESSING_CLASS];

/// The running input: its thread and the faults it reports.
pub struct DicomInput {
    faults: Receiver<FaultRecord>,
    /// Ends with the daemon's stop flag (not joined: an association in
    /// progress would hold the daemon's stop).
    _thread: std::thread::JoinHandle<()>,
    addr: SocketAddr,
}

fn now_unix() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0)
}

impl DicomInput {
    /// Listen on `addr` as `ae_title`, spooling into `spool`, until `stop`.
    pub fn start(
        addr: SocketAddr,
        ae_title: &str,
        spool: PathBuf,
        system: System,
        stop: Arc<AtomicBool>,
    ) -> std::io::Result<Self> {
        let listener = TcpListener::bind(addr)?;
        listener.set_nonblocking(true)?;
        let addr = listener.local_addr()?;
        let (tx, faults) = channel();
        let ae = ae_title.to_string();
        let thread = std::thread::Builder::new()
            .name("dicom-input".into())
            .spawn(move || serve(listener, &ae, &spool, &system, &stop, &tx))?;
        Ok(Self {
            faults,
            _thread: thread,
            addr,
        })
    }

    /// The address it listens on.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The faults reported since the last call.
    pub fn drain(&self) -> Vec<FaultRecord> {
        self.faults.try_iter().collect()
    }
}

/// The SOP instances already spooled from DICOM, with a digest of their
/// counts: a second copy with the same counts is answered Success without a
/// second acquisition (a modality resending after a lost response); one
/// with other counts is refused.
#[derive(Debug, Default)]
pub struct Seen(std::collections::HashMap<String, u64>);

impl Seen {
    /// The DICOM entries in `incoming/` and `done/` (their `gantry.json`).
    pub fn load(spool: &Path) -> Self {
        let mut seen = Self::default();
        for sub in ["incoming", "done"] {
            let Ok(rd) = std::fs::read_dir(spool.join(sub)) else {
                continue;
            };
            for e in rd.flatten() {
                let v: serde_json::Value = std::fs::read(e.path().join("gantry.json"))
                    .ok()
                    .and_then(|b| serde_json::from_slice(&b).ok())
                    .unwrap_or_default();
                if let (Some(sop), Some(d)) =
                    (v["sop_instance"].as_str(), v["counts_digest"].as_u64())
                {
                    seen.0.insert(sop.to_string(), d);
                }
            }
        }
        seen
    }
}

/// FNV-1a over the counts.
pub fn counts_digest(counts: &[u16]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for c in counts {
        for b in c.to_le_bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    h
}

fn serve(
    listener: TcpListener,
    ae: &str,
    spool: &Path,
    system: &System,
    stop: &AtomicBool,
    faults: &Sender<FaultRecord>,
) {
    let mut seen = Seen::load(spool);
    while !stop.load(Ordering::SeqCst) {
        let stream = match listener.accept() {
            Ok((s, _)) => s,
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(100));
                continue;
            }
            Err(e) => {
                tracing::warn!(%e, "DICOM input: accepting a connection");
                std::thread::sleep(Duration::from_millis(100));
                continue;
            }
        };
        let _ = stream.set_nonblocking(false);
        let _span = tracing::info_span!("dicom_association").entered();
        let report = serve_association(
            stream,
            ae,
            &ACCEPTED,
            Duration::from_secs(30),
            &mut |class, instance, bytes| {
                receive(spool, system, &mut seen, faults, class, instance, bytes)
            },
        );
        if let Some(e) = &report.error {
            tracing::warn!(calling = %report.calling_ae_title, error = %e, "DICOM association ended");
        }
    }
}

/// One object: spooled (Success), a duplicate (Success, nothing new), or
/// kept in `faulted/` (failure).
pub fn receive(
    spool: &Path,
    system: &System,
    seen: &mut Seen,
    faults: &Sender<FaultRecord>,
    class: &str,
    instance: &str,
    bytes: Vec<u8>,
) -> Verdict {
    let read = dbt_dicom::projections::read_projection_object(&bytes)
        .map_err(|e| e.to_string())
        .and_then(|p| {
            let digest = counts_digest(&p.counts);
            match seen.0.get(instance) {
                Some(d) if *d == digest => return Ok(None),
                Some(_) => {
                    return Err(format!(
                        "a second copy of SOP instance {instance} with other counts than the one received"
                    ))
                }
                None => {}
            }
            acquisition_from_projections(&p, system)
                .map(|a| Some((p, a, digest)))
                .map_err(|e| e.to_string())
        });
    match read {
        Ok(None) => {
            tracing::info!(%instance, "a copy of an object already received: nothing new");
            Verdict::Stored
        }
        Ok(Some((p, acq, digest))) => {
            let id = entry_id(&acq.header.patient.id);
            let note = serde_json::json!({
                "source": "dicom",
                "sop_class": class,
                "sop_instance": instance,
                "counts_digest": digest,
                "compression_force_n": p.compression_force_n,
            });
            match spool_entry(spool, &id, &acq, &note) {
                Ok(()) => {
                    tracing::info!(acquisition = %id, %instance, "spooled from DICOM");
                    seen.0.insert(instance.to_string(), digest);
                    Verdict::Stored
                }
                Err(e) => {
                    let msg = format!("cannot spool SOP instance {instance}: {e}");
                    let _ = faults.send(FaultRecord {
                        at_unix: now_unix(),
                        acquisition: Some(id),
                        kind: "spool".into(),
                        message: msg.clone(),
                    });
                    Verdict::Refused(STATUS_OUT_OF_RESOURCES, msg)
                }
            }
        }
        Err(reason) => {
            let id = entry_id("dicom");
            let dir = spool.join("faulted").join(&id);
            let kept = std::fs::create_dir_all(&dir)
                .and_then(|_| write_durable(&dir.join("object.dcm"), &bytes))
                .and_then(|_| {
                    write_durable(
                        &dir.join("fault.json"),
                        &serde_json::to_vec_pretty(&serde_json::json!({
                            "kind": "input",
                            "message": reason,
                            "sop_class": class,
                            "sop_instance": instance,
                        }))
                        .unwrap_or_default(),
                    )
                });
            if let Err(e) = kept {
                tracing::error!(%e, "DICOM input: cannot keep a refused object");
            }
            let msg = format!("DICOM object {instance} refused: {reason}");
            let _ = faults.send(FaultRecord {
                at_unix: now_unix(),
                acquisition: Some(id),
                kind: "input".into(),
                message: msg,
            });
            Verdict::Refused(STATUS_CANNOT_UNDERSTAND, reason)
        }
    }
}
