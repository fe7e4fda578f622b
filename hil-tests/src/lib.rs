//! Helpers shared by the hardware-in-the-loop tests in `tests/`.

/// A loopback TCP port that was free a moment ago, and that no other call in
/// this test process has handed out: the tests of one binary run in
/// parallel, and a port the kernel gives twice (once released, a bound port
/// is free again) would let one test's daemon connect to another test's
/// gantry and take its acquisition (a hang seen in CI: the other daemon
/// waited for a stream that had gone elsewhere).
pub fn free_port() -> u16 {
    static GIVEN: std::sync::Mutex<Vec<u16>> = std::sync::Mutex::new(Vec::new());
    let mut given = GIVEN.lock().unwrap_or_else(|e| e.into_inner());
    for _ in 0..1000 {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map(|a| a.port())
            .expect("a loopback port");
        if !given.contains(&port) {
            given.push(port);
            return port;
        }
    }
    panic!("no loopback port that this process has not handed out already");
}

/// Wait for `child` to exit, at most `limit`: past it the child is killed
/// and the test fails naming `what`, so that a process that never exits is a
/// failure in minutes, not a CI run that never ends.
pub fn wait_exit(
    child: &mut std::process::Child,
    limit: std::time::Duration,
    what: &str,
) -> std::process::ExitStatus {
    let t0 = std::time::Instant::now();
    loop {
        match child.try_wait() {
            Ok(Some(st)) => return st,
            Ok(None) => {}
            Err(e) => panic!("{what}: waiting for process {}: {e}", child.id()),
        }
        if t0.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{what}: still running after {limit:?}; killed");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// The environment variable naming a folder of prebuilt workspace binaries:
/// `scripts/test-all.sh` builds them all once before `cargo test` (`cargo
/// build --profile test --workspace --bins`: the tests' own profile,
/// optimised with debug assertions on, sharing every crate with cargo
/// test's build) and sets it, so that no test builds (issue #52 point 7:
/// CI's time). Unset, each test builds the release binary it runs.
pub const BIN_DIR_ENV: &str = "DBTOR_BIN_DIR";

/// The folder of prebuilt binaries [`BIN_DIR_ENV`] names, if set (an empty
/// value counts as unset). Panics, naming it, when it is not a folder.
pub fn prebuilt_bin_dir() -> Option<std::path::PathBuf> {
    let d = std::env::var_os(BIN_DIR_ENV).filter(|v| !v.is_empty())?;
    let d = std::path::PathBuf::from(d);
    assert!(
        d.is_dir(),
        "{BIN_DIR_ENV}={} is not a folder (it names the prebuilt workspace binaries)",
        d.display()
    );
    Some(d)
}

/// The release folder beside this test executable's
/// (`target/debug/deps/x-HASH` -> `target/release`).
pub fn release_dir() -> std::path::PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    exe.parent()
        .and_then(|d| d.parent())
        .and_then(|d| d.parent())
        .expect("target folder")
        .join("release")
}

/// A workspace binary (`host-sim`, or one of the firmware's), optimised:
/// from [`BIN_DIR_ENV`]'s folder when set (`scripts/test-all.sh` built
/// every binary there just before the tests), else its release build,
/// (re)built first: `cargo test` does not rebuild other packages'
/// binaries, and a stale one would test old code. Optimised, because the
/// processes run real reconstructions and Monte Carlo (the unoptimised
/// build is 20x slower). The build is a no-op when fresh (cargo does not
/// hold the build lock while tests run).
pub fn workspace_bin(name: &str) -> std::path::PathBuf {
    if let Some(d) = prebuilt_bin_dir() {
        let exe = d.join(name);
        assert!(
            exe.is_file(),
            "{BIN_DIR_ENV}={}: no `{name}` there (cargo build --profile test --workspace --bins makes it)",
            d.display()
        );
        return exe;
    }
    let pkg = if name == "host-sim" {
        "host-sim"
    } else {
        "dbtor-firmware"
    };
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut c = std::process::Command::new(cargo);
    c.args(["build", "-q", "--release", "-p", pkg, "--bin", name]);
    let ok = c.status().map(|s| s.success()).unwrap_or(false);
    assert!(ok, "building {name}");
    release_dir().join(name)
}

/// `host-sim acquire` of test phantom `index` (N = 8, binned x4) into `dir/acq`.
pub fn acquire(dir: &std::path::Path, index: u32) -> std::path::PathBuf {
    acquire_on(dir, index, "paper")
}

/// As [`acquire`], on another geometry (`host-sim acquire --geometry`):
/// `paper-tall` is the shipped configuration's.
pub fn acquire_on(dir: &std::path::Path, index: u32, geometry: &str) -> std::path::PathBuf {
    acquire_with(dir, "acq", index, geometry, None)
}

/// As [`acquire_on`], into `dir/name`, on the cone-beam `system` when given
/// (`host-sim acquire --system`: 2-D detector frames, the header naming the
/// system).
pub fn acquire_with(
    dir: &std::path::Path,
    name: &str,
    index: u32,
    geometry: &str,
    system: Option<&str>,
) -> std::path::PathBuf {
    acquire_args(dir, name, index, geometry, system, &[])
}

/// As [`acquire_with`], with more `host-sim acquire` arguments (e.g.
/// `--physics clinical`).
pub fn acquire_args(
    dir: &std::path::Path,
    name: &str,
    index: u32,
    geometry: &str,
    system: Option<&str>,
    extra: &[&str],
) -> std::path::PathBuf {
    let acq = dir.join(name);
    let st = std::process::Command::new(workspace_bin("host-sim"))
        .args([
            "acquire",
            "--index",
            &index.to_string(),
            "--geometry",
            geometry,
            "--binning",
            "4",
            "--noise",
            "N8",
        ])
        .args(system.iter().flat_map(|s| ["--system", s]))
        .args(extra)
        .arg("--out")
        .arg(&acq)
        .output()
        .expect("running host-sim acquire");
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    acq
}

/// A pseudo-terminal pair made by socat (Debian; `scripts/install-test-deps.sh` installs it):
/// `a` for the gantry's end, `b` for the firmware's. Killed on drop.
pub struct PtyPair {
    socat: std::process::Child,
    /// The gantry's end.
    pub a: std::path::PathBuf,
    /// The firmware's end.
    pub b: std::path::PathBuf,
}

impl Drop for PtyPair {
    fn drop(&mut self) {
        let _ = self.socat.kill();
        let _ = self.socat.wait();
    }
}

/// A new pty pair with links `dir/NAME-gantry` and `dir/NAME-pc`.
pub fn pty_pair(dir: &std::path::Path, name: &str) -> PtyPair {
    let (a, b) = (
        dir.join(format!("{name}-gantry")),
        dir.join(format!("{name}-pc")),
    );
    let socat = std::process::Command::new("socat")
        .arg(format!("pty,raw,echo=0,link={}", a.display()))
        .arg(format!("pty,raw,echo=0,link={}", b.display()))
        .spawn()
        .expect("socat not found: apt-get install socat");
    let t = std::time::Instant::now();
    while !(a.exists() && b.exists()) {
        assert!(t.elapsed().as_secs() < 10, "socat made no pty pair");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    PtyPair { socat, a, b }
}

/// Wait until something listens on loopback `port` (at most 30 s).
pub fn wait_for_port(port: u16, what: &str) {
    let t = std::time::Instant::now();
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(
            t.elapsed().as_secs() < 30,
            "{what} did not start listening on port {port}"
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Orthanc (Debian package `orthanc`) on loopback ports with its own
/// configuration and storage under a folder; killed on drop.
pub struct Orthanc {
    child: Child,
}

impl Orthanc {
    /// Start it and wait for its REST API (at most 30 s).
    pub fn start(dir: &Path, dicom: u16, http: u16) -> Orthanc {
        let cfg = dir.join("orthanc.json");
        let db = dir.join("db");
        std::fs::create_dir_all(&db).unwrap();
        let conf = serde_json::json!({
            "Name": "DBTOR-HIL",
            "StorageDirectory": db,
            "IndexDirectory": db,
            "DicomAet": "ORTHANC",
            "DicomPort": dicom,
            "HttpPort": http,
            "RemoteAccessAllowed": false,
            "AuthenticationEnabled": false,
            "DicomCheckCalledAet": true,
            "Plugins": [],
        });
        std::fs::write(&cfg, conf.to_string()).unwrap();
        let bin = ["/usr/sbin/Orthanc", "/usr/bin/Orthanc"]
            .into_iter()
            .map(PathBuf::from)
            .find(|p| p.exists())
            .expect("Orthanc not found: apt-get install orthanc");
        let log = std::fs::File::create(dir.join("orthanc.log")).unwrap();
        let child = Command::new(bin)
            .arg(&cfg)
            .stdout(Stdio::from(log.try_clone().unwrap()))
            .stderr(Stdio::from(log))
            .spawn()
            .unwrap();
        let o = Orthanc { child };
        let t = Instant::now();
        while http_get(http, "/system").is_none() {
            assert!(
                t.elapsed() < Duration::from_secs(30),
                "Orthanc did not start; see {}",
                dir.join("orthanc.log").display()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        o
    }

    /// Stop it (kill and reap).
    pub fn stop(mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Orthanc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Minimal HTTP/1.0 GET on loopback: the body, or None when not reachable or
/// not 200.
pub fn http_get(port: u16, path: &str) -> Option<Vec<u8>> {
    let mut s = TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(10))).ok()?;
    write!(s, "GET {path} HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n").ok()?;
    let mut buf = Vec::new();
    s.read_to_end(&mut buf).ok()?;
    let split = buf.windows(4).position(|w| w == b"\r\n\r\n")?;
    let head = String::from_utf8_lossy(&buf[..split]).to_string();
    if !head.starts_with("HTTP/1.1 200") && !head.starts_with("HTTP/1.0 200") {
        return None;
    }
    Some(buf[split + 4..].to_vec())
}

/// The status file of a daemon run in `dir` (its configuration's
/// `paths.status = "run/status.json"`), or null while there is none.
pub fn daemon_status(dir: &std::path::Path) -> serde_json::Value {
    std::fs::read(dir.join("run/status.json"))
        .ok()
        .and_then(|b| serde_json::from_slice(&b).ok())
        .unwrap_or(serde_json::Value::Null)
}

/// Poll [`daemon_status`] until `f` holds (the status it held for), failing
/// after `limit` with `what` and the last status.
pub fn wait_for_status(
    dir: &std::path::Path,
    what: &str,
    limit: Duration,
    f: impl Fn(&serde_json::Value) -> bool,
) -> serde_json::Value {
    let t0 = std::time::Instant::now();
    loop {
        let s = daemon_status(dir);
        if f(&s) {
            return s;
        }
        assert!(
            t0.elapsed() < limit,
            "timed out waiting for {what}; status: {s}"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// dcmtk's `storescu` sending `file` to `called`@127.0.0.1:`port` as
/// `calling`, with `-R`: only the presentation contexts the file needs (the
/// For Processing projection class is not in storescu's default list).
pub fn storescu(called: &str, calling: &str, port: u16, file: &Path) -> std::process::Output {
    Command::new("storescu")
        .args([
            "-R",
            "-aec",
            called,
            "-aet",
            calling,
            "127.0.0.1",
            &port.to_string(),
        ])
        .arg(file)
        .output()
        .expect("storescu (dcmtk; scripts/install-test-deps.sh installs it)")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Ports handed out in one process never repeat, from any thread (the
    /// kernel's own choice does repeat once a port is released).
    #[test]
    fn free_ports_are_never_handed_out_twice() {
        let threads: Vec<_> = (0..4)
            .map(|_| std::thread::spawn(|| (0..100).map(|_| free_port()).collect::<Vec<u16>>()))
            .collect();
        let mut all: Vec<u16> = threads
            .into_iter()
            .flat_map(|t| t.join().expect("thread"))
            .collect();
        assert!(all.iter().all(|&p| p != 0));
        let n = all.len();
        all.sort_unstable();
        all.dedup();
        assert_eq!(all.len(), n, "a port was handed out twice");
    }

    /// A process past its limit is killed and the failure names it.
    #[test]
    fn a_process_past_its_limit_is_killed_and_named() {
        let mut c = std::process::Command::new("sleep")
            .arg("30")
            .spawn()
            .expect("sleep");
        let pid = c.id();
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            wait_exit(&mut c, std::time::Duration::from_millis(200), "the sleeper")
        }));
        let msg = r.expect_err("must fail");
        let msg = msg.downcast_ref::<String>().cloned().unwrap_or_default();
        assert!(
            msg.contains("the sleeper") && msg.contains("killed"),
            "{msg}"
        );
        assert!(
            c.try_wait().expect("reaped").is_some(),
            "pid {pid} still runs"
        );
        let mut quick = std::process::Command::new("true").spawn().expect("true");
        assert!(wait_exit(&mut quick, std::time::Duration::from_secs(10), "true").success());
    }
}
