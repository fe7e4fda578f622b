//! The status page's adapter: reads the daemon's state from its files (the
//! status file and the spool's `done/` records, the same files
//! `dbtor-diag status` reads, through the same [`StateReader`]) and serves
//! the page of `dbt-status` over HTTP.
//!
//! Read-only by construction: GET and HEAD of six kinds of path, nothing
//! else (405 for other methods, 404 for other paths); no patient identifier
//! (the served snapshot is de-identified: the page has no authentication);
//! no configuration or secret. The address is loopback unless the
//! configuration says otherwise (`status_page.allow_non_loopback`).
//!
//! | path | content |
//! |---|---|
//! | `/` | the page (HTML) |
//! | `/status.json` | the de-identified snapshot with the health verdict |
//! | `/page.js` | the page's script |
//! | `/figures/mgd-thickness.svg` | MGD against thickness, patient and model breast |
//! | `/figures/glandularity.svg` | the glandularity histogram |
//! | `/acquisitions/<id>/picture.svg` | one acquisition's quick-look picture |

use dbt_status::{public_id, valid_entry_id, AcquisitionRecord, Snapshot, Status};
use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// The quick-look picture's file in a spool entry.
pub const PICTURE_FILE: &str = "picture.svg";

/// Why the state cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum StateError {
    /// The status file cannot be read.
    #[error("reading the status file {path} (is the daemon running?): {cause}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        cause: std::io::Error,
    },
    /// The status file is not one.
    #[error("{path} is not a status file: {reason}")]
    Format {
        /// The file.
        path: PathBuf,
        /// The parser's message.
        reason: String,
    },
}

/// Reads the daemon's state from its status file and, when given the spool,
/// the history of reported acquisitions (`done/*/result.json`; records of
/// entries already read are kept: an entry in `done/` does not change).
pub struct StateReader {
    status_file: PathBuf,
    spool: Option<PathBuf>,
    cache: HashMap<String, AcquisitionRecord>,
}

impl StateReader {
    /// A reader of `status_file`, with the history of `spool` if given.
    pub fn new(status_file: PathBuf, spool: Option<PathBuf>) -> Self {
        Self {
            status_file,
            spool,
            cache: HashMap::new(),
        }
    }

    /// The spool, if the history is read.
    pub fn spool(&self) -> Option<&Path> {
        self.spool.as_deref()
    }

    /// The status file alone.
    pub fn status(&self) -> Result<Status, StateError> {
        let path = &self.status_file;
        let bytes = std::fs::read(path).map_err(|cause| StateError::Io {
            path: path.clone(),
            cause,
        })?;
        serde_json::from_slice(&bytes).map_err(|e| StateError::Format {
            path: path.clone(),
            reason: e.to_string(),
        })
    }

    /// The status and the spool's history, oldest first.
    pub fn read(&mut self) -> Result<Snapshot, StateError> {
        let status = self.status()?;
        let mut s = Snapshot {
            status,
            history: vec![],
            unreadable: vec![],
        };
        let Some(spool) = self.spool.clone() else {
            return Ok(s);
        };
        let done = spool.join("done");
        let ids: Vec<String> = match std::fs::read_dir(&done) {
            Ok(rd) => rd
                .flatten()
                .filter(|e| e.path().is_dir())
                .filter_map(|e| e.file_name().to_str().map(String::from))
                .collect(),
            Err(e) => {
                s.unreadable.push(dbt_status::state::Unreadable {
                    acquisition: done.display().to_string(),
                    reason: e.to_string(),
                });
                vec![]
            }
        };
        self.cache.retain(|id, _| ids.contains(id));
        for id in ids {
            if let Some(r) = self.cache.get(&id) {
                s.history.push(r.clone());
                continue;
            }
            let file = done.join(&id).join("result.json");
            let rec = std::fs::read(&file)
                .map_err(|e| e.to_string())
                .and_then(|b| {
                    serde_json::from_slice::<AcquisitionRecord>(&b).map_err(|e| e.to_string())
                });
            match rec {
                Ok(r) => {
                    self.cache.insert(id, r.clone());
                    s.history.push(r);
                }
                Err(reason) => s.unreadable.push(dbt_status::state::Unreadable {
                    acquisition: id,
                    reason: format!("result.json: {reason}"),
                }),
            }
        }
        s.sort_history();
        Ok(s)
    }
}

/// The snapshot as JSON, with the health verdict: what `/status.json`
/// serves (de-identified) and `dbtor-diag status --json` prints.
pub fn snapshot_json(s: &Snapshot) -> serde_json::Value {
    serde_json::json!({
        "healthy": s.status.healthy(),
        "status": s.status,
        "history": s.history,
        "unreadable": s.unreadable,
    })
}

/// One HTTP answer.
#[derive(Debug)]
pub struct Reply {
    /// HTTP status code.
    pub code: u16,
    /// Content type.
    pub content_type: &'static str,
    /// Body.
    pub body: Vec<u8>,
}

impl Reply {
    fn ok(content_type: &'static str, body: impl Into<Vec<u8>>) -> Self {
        Self {
            code: 200,
            content_type,
            body: body.into(),
        }
    }

    fn text(code: u16, body: impl Into<String>) -> Self {
        Self {
            code,
            content_type: "text/plain; charset=utf-8",
            body: body.into().into_bytes(),
        }
    }
}

fn now_unix() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0)
}

/// The answer to `method url`: the router of the page.
pub fn respond(reader: &mut StateReader, method: &str, url: &str) -> Reply {
    if method != "GET" && method != "HEAD" {
        return Reply::text(405, "read-only: GET and HEAD only\n");
    }
    let path = url.split(['?', '#']).next().unwrap_or("");
    let spool = reader.spool.clone();
    let mut snapshot = || -> Result<Snapshot, Reply> {
        reader
            .read()
            .map(|s| s.deidentified())
            .map_err(|e| Reply::text(503, format!("{e}\n")))
    };
    let result = match path {
        "/" | "/index.html" => snapshot().map(|s| {
            Reply::ok(
                "text/html; charset=utf-8",
                dbt_status::page::render(&s, now_unix()),
            )
        }),
        "/status.json" => snapshot().map(|s| {
            Reply::ok(
                "application/json",
                serde_json::to_vec_pretty(&snapshot_json(&s)).unwrap_or_default(),
            )
        }),
        "/page.js" => Ok(Reply::ok(
            "text/javascript; charset=utf-8",
            dbt_status::page::PAGE_JS,
        )),
        "/figures/mgd-thickness.svg" => snapshot().map(|s| {
            Reply::ok(
                "image/svg+xml",
                dbt_status::plot::mgd_vs_thickness(&s.history),
            )
        }),
        "/figures/glandularity.svg" => snapshot().map(|s| {
            Reply::ok(
                "image/svg+xml",
                dbt_status::plot::glandularity_histogram(&s.history),
            )
        }),
        p => match p
            .strip_prefix("/acquisitions/")
            .and_then(|r| r.strip_suffix("/picture.svg"))
        {
            Some(key) if valid_entry_id(key) && !key.contains('-') => picture(spool, key),
            _ => Err(Reply::text(404, format!("no such page: {p}\n"))),
        },
    };
    result.unwrap_or_else(|r| r)
}

/// The picture of the `done/` entry whose public id is `key`.
fn picture(spool: Option<PathBuf>, key: &str) -> Result<Reply, Reply> {
    let missing = || Reply::text(404, format!("no picture of acquisition {key}\n"));
    let done = spool.ok_or_else(missing)?.join("done");
    let entry = std::fs::read_dir(&done)
        .map_err(|_| missing())?
        .flatten()
        .filter_map(|e| e.file_name().to_str().map(String::from))
        .find(|id| valid_entry_id(id) && public_id(id) == key)
        .ok_or_else(missing)?;
    let bytes = std::fs::read(done.join(entry).join(PICTURE_FILE)).map_err(|_| missing())?;
    Ok(Reply::ok("image/svg+xml", bytes))
}

/// The running server: stops when the daemon's stop flag is set or when
/// dropped.
pub struct StatusServer {
    addr: SocketAddr,
    quit: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl StatusServer {
    /// Serve on `addr` (port 0: any free port) from `reader` until `stop`.
    pub fn start(
        addr: SocketAddr,
        mut reader: StateReader,
        stop: Arc<AtomicBool>,
    ) -> Result<Self, std::io::Error> {
        let server = tiny_http::Server::http(addr).map_err(std::io::Error::other)?;
        let addr = server
            .server_addr()
            .to_ip()
            .ok_or_else(|| std::io::Error::other("not an IP listener"))?;
        let quit = Arc::new(AtomicBool::new(false));
        let q = Arc::clone(&quit);
        let thread = std::thread::Builder::new()
            .name("status-page".into())
            .spawn(move || {
                while !stop.load(Ordering::SeqCst) && !q.load(Ordering::SeqCst) {
                    let req = match server.recv_timeout(Duration::from_millis(200)) {
                        Ok(Some(r)) => r,
                        Ok(None) => continue,
                        Err(e) => {
                            tracing::warn!(%e, "status page: receiving a request");
                            continue;
                        }
                    };
                    let method = req.method().as_str().to_string();
                    let reply = respond(&mut reader, &method, req.url());
                    let mut resp = tiny_http::Response::from_data(if method == "HEAD" {
                        vec![]
                    } else {
                        reply.body
                    })
                    .with_status_code(reply.code);
                    for (k, v) in [
                        ("Content-Type", reply.content_type),
                        ("Cache-Control", "no-store"),
                        ("X-Content-Type-Options", "nosniff"),
                        ("Referrer-Policy", "no-referrer"),
                        (
                            "Content-Security-Policy",
                            dbt_status::page::CONTENT_SECURITY_POLICY,
                        ),
                        ("Allow", "GET, HEAD"),
                    ] {
                        if let Ok(h) = tiny_http::Header::from_bytes(k.as_bytes(), v.as_bytes()) {
                            resp.add_header(h);
                        }
                    }
                    if let Err(e) = req.respond(resp) {
                        tracing::debug!(%e, "status page: the client went away");
                    }
                }
            })?;
        Ok(Self {
            addr,
            quit,
            thread: Some(thread),
        })
    }

    /// The address it listens on.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }
}

impl Drop for StatusServer {
    fn drop(&mut self) {
        self.quit.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(id: &str, t: f64, at: u64) -> AcquisitionRecord {
        AcquisitionRecord {
            acquisition: id.into(),
            patient_id: "SECRET_PATIENT".into(),
            reconstructor: "mltr".into(),
            thickness_mm: Some(t),
            glandularity_labels: 0.2,
            glandularity_partial_volume: 0.21,
            glandularity_reported: 0.21,
            calibrated: false,
            volumetric_fraction: Some(0.15),
            composition: Some("c".into()),
            mgd_mgy: 1.25,
            model_mgd_mgy: 1.4,
            seconds: 2.0,
            finished_unix: at,
            reports: vec![format!("{id}-dose-sr.dcm")],
            pacs_waiting: vec![],
            flags: vec![],
            density_check: Some(dbt_dicom::DensityCheckReport {
                physics_glandularity: Some(0.2),
                confirmed: true,
                reasons: vec![],
            }),
            glandularity_interval: Some(dbt_dicom::FigureInterval {
                limits: Some([0.17, 0.24]),
                basis: "95 % prediction interval from 14 validation breasts".into(),
            }),
            mgd_interval: Some(dbt_dicom::FigureInterval {
                limits: None,
                basis: "the reconstructor has no validation residuals for these inputs".into(),
            }),
        }
    }

    /// A status file and a spool with two reported entries (one with a
    /// picture) and one broken record.
    fn state(dir: &Path) -> StateReader {
        let spool = dir.join("spool");
        let mut st = Status::starting("0.1", 1, 100, "mltr".into());
        for (i, (id, t)) in [("1000-SECRET_PATIENT", 40.0), ("2000-SECRET_PATIENT", 60.0)]
            .into_iter()
            .enumerate()
        {
            let e = spool.join("done").join(id);
            std::fs::create_dir_all(&e).unwrap();
            let mut r = record(id, t, 200 + i as u64);
            if i == 1 {
                // The physics did not confirm the second one's density.
                r.composition = None;
                r.density_check = Some(dbt_dicom::DensityCheckReport {
                    physics_glandularity: Some(0.45),
                    confirmed: false,
                    reasons: vec!["disagree by -24.0 pp (limit 14)".into()],
                });
            }
            std::fs::write(e.join("result.json"), serde_json::to_vec(&r).unwrap()).unwrap();
            st.push_reported(r);
        }
        std::fs::write(
            spool.join("done/2000-SECRET_PATIENT").join(PICTURE_FILE),
            "<svg/>",
        )
        .unwrap();
        std::fs::create_dir_all(spool.join("done/3000-X")).unwrap();
        std::fs::write(spool.join("done/3000-X/result.json"), "{").unwrap();
        let status = dir.join("status.json");
        std::fs::write(&status, serde_json::to_vec(&st).unwrap()).unwrap();
        StateReader::new(status, Some(spool))
    }

    #[test]
    fn snapshot_reads_history_oldest_first_and_names_broken_records() {
        let dir = tempfile::tempdir().unwrap();
        let mut r = state(dir.path());
        let s = r.read().unwrap();
        assert_eq!(s.history.len(), 2);
        assert_eq!(s.history[0].acquisition, "1000-SECRET_PATIENT");
        assert_eq!(s.unreadable.len(), 1);
        assert_eq!(s.unreadable[0].acquisition, "3000-X");
        assert!(s.unreadable[0].reason.contains("result.json"));
        // A second read (from the cache) is the same.
        assert_eq!(r.read().unwrap(), s);
    }

    #[test]
    fn routes_serve_de_identified_content_read_only() {
        let dir = tempfile::tempdir().unwrap();
        let mut r = state(dir.path());
        for path in [
            "/",
            "/status.json",
            "/figures/mgd-thickness.svg",
            "/figures/glandularity.svg",
            "/page.js",
        ] {
            let rep = respond(&mut r, "GET", path);
            assert_eq!(rep.code, 200, "{path}");
            let body = String::from_utf8(rep.body).unwrap();
            assert!(!body.contains("SECRET"), "{path} shows a patient id");
        }
        let j: serde_json::Value =
            serde_json::from_slice(&respond(&mut r, "GET", "/status.json?x=1").body).unwrap();
        assert_eq!(j["history"][1]["acquisition"], "2000");
        assert_eq!(j["healthy"], true);
        // The density the physics did not confirm: counted as a warning,
        // shown without a category, with the reason.
        assert_eq!(j["status"]["warning_counts"]["density_check"], 1, "{j}");
        let page = String::from_utf8(respond(&mut r, "GET", "/").body).unwrap();
        assert!(
            page.contains(r#"data-kind="density_check""#)
                && page.contains(
                    "density_check: not confirmed by the physics, physics density 45.0 %"
                )
                && page.contains("NOT confirmed by the physics density: disagree by -24.0 pp"),
            "{page}"
        );
        let pic = respond(&mut r, "GET", "/acquisitions/2000/picture.svg");
        assert_eq!((pic.code, pic.body.as_slice()), (200, b"<svg/>".as_slice()));
        assert_eq!(pic.content_type, "image/svg+xml");
        for bad in [
            "/acquisitions/1000/picture.svg", // no picture
            "/acquisitions/2000-SECRET_PATIENT/picture.svg",
            "/acquisitions/../status.json/picture.svg",
            "/acquisitions/%2e%2e/picture.svg",
            "/etc/passwd",
            "/status.json/",
        ] {
            assert_eq!(respond(&mut r, "GET", bad).code, 404, "{bad}");
        }
        for m in ["POST", "PUT", "DELETE", "PATCH"] {
            assert_eq!(respond(&mut r, m, "/").code, 405, "{m}");
        }
    }

    #[test]
    fn a_missing_status_file_is_a_503_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let mut r = StateReader::new(dir.path().join("nope.json"), None);
        let rep = respond(&mut r, "GET", "/");
        assert_eq!(rep.code, 503);
        assert!(String::from_utf8(rep.body).unwrap().contains("nope.json"));
    }

    #[test]
    fn the_server_answers_over_tcp_and_stops_with_the_flag() {
        use std::io::{Read, Write};
        let dir = tempfile::tempdir().unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let srv = StatusServer::start(
            "127.0.0.1:0".parse().unwrap(),
            state(dir.path()),
            Arc::clone(&stop),
        )
        .unwrap();
        let mut c = std::net::TcpStream::connect(srv.addr()).unwrap();
        c.write_all(b"GET /status.json HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
            .unwrap();
        let mut text = String::new();
        c.read_to_string(&mut text).unwrap();
        assert!(text.starts_with("HTTP/1.1 200"), "{text}");
        assert!(text.contains("Cache-Control: no-store"), "{text}");
        assert!(text.contains("\"healthy\""), "{text}");
        stop.store(true, Ordering::SeqCst);
        drop(srv); // joins the thread: returns once the flag is seen
    }
}
