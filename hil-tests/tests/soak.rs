//! The soak: acquisitions back to back through `dbtor-daemon`, with faults
//! injected at random (seeded): repairable link faults, a pulled cable (the
//! gantry resends), the PACS down and back, a Modbus server that stops
//! answering, a SIGKILL mid-processing and a restart, and now and then a
//! physically impossible acquisition (a dead detector). Every acquisition
//! must end exactly one way: reported once (its two SRs in Orthanc, no
//! duplicate) or, for the impossible ones and the Modbus timeouts, refused
//! with the fault in the status and the entry kept in `spool/faulted`. The
//! daemon's RSS and open file descriptors are sampled after each acquisition
//! and must stay flat after warm-up; the curves are printed.
//!
//! The first seven acquisitions inject each kind once (none first), the rest
//! at random. CI runs 10 acquisitions (this test); the full soak is
//! `DBTOR_SOAK_ACQUISITIONS=100 cargo test -p hil-tests --test hil soak:: -- --nocapture`
//! (hil-tests/README.md has its result).

use hil_tests::{acquire, free_port, http_get, workspace_bin, Orthanc};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

#[derive(Debug, Clone, Copy, PartialEq)]
enum Fault {
    None,
    /// Corrupt, drop, duplicate, reorder: repaired by retransmission.
    Link,
    /// The cable pulled mid-acquisition; the gantry sends it again.
    Cut,
    /// The PACS is down while the acquisition is reported, up afterwards.
    PacsDown,
    /// The Modbus server stops answering: a thickness fault, refused.
    ModbusSilent,
    /// SIGKILL while processing, then a restart: reported exactly once.
    Kill,
    /// A dead detector (all counts zero): refused as implausible.
    Impossible,
}

impl Fault {
    fn refused(self) -> bool {
        matches!(self, Fault::ModbusSilent | Fault::Impossible)
    }
}

/// xorshift64: a seeded, dependency-free choice of faults.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    fn fault(&mut self) -> Fault {
        match self.next() % 20 {
            0..=7 => Fault::None,
            8..=10 => Fault::Link,
            11 | 12 => Fault::Cut,
            13 | 14 => Fault::PacsDown,
            15 | 16 => Fault::ModbusSilent,
            17 => Fault::Kill,
            _ => Fault::Impossible,
        }
    }
}

fn modbus(addr: &str, thickness: f64, silent: bool) -> Proc {
    let mut c = Command::new(workspace_bin("host-sim"));
    c.args([
        "modbus",
        "--listen",
        addr,
        "--thickness-mm",
        &format!("{thickness:.1}"),
    ]);
    if silent {
        c.args(["--fault", "silent"]);
    }
    let child = Proc(
        c.stderr(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let port: u16 = addr.rsplit(':').next().unwrap().parse().unwrap();
    hil_tests::wait_for_port(port, "host-sim modbus");
    child
}

fn stream(acq: &Path, addr: &str, faults: &[&str]) -> Proc {
    let mut c = Command::new(workspace_bin("host-sim"));
    c.args(["stream", "--acq"])
        .arg(acq)
        .args(["--listen", addr]);
    for f in faults {
        c.args(["--fault", f]);
    }
    // Not probed: it serves one connection, the daemon's (which retries
    // until it listens).
    Proc(
        c.stderr(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .unwrap(),
    )
}

/// A child process killed and reaped on drop (a failing assertion must not
/// leave daemons or servers running).
struct Proc(Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn daemon(cfg: &Path) -> Proc {
    Proc(
        Command::new(workspace_bin("dbtor-daemon"))
            .arg("--config")
            .arg(cfg)
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    )
}

fn status(dir: &Path) -> serde_json::Value {
    hil_tests::daemon_status(dir)
}

fn count(dir: &Path) -> usize {
    std::fs::read_dir(dir).map(|d| d.count()).unwrap_or(0)
}

/// RSS (kB) and open file descriptors of a process.
fn usage(pid: u32) -> (u64, usize) {
    let rss = std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1).and_then(|v| v.parse().ok()))
        })
        .unwrap_or(0);
    let fds = count(Path::new(&format!("/proc/{pid}/fd")));
    (rss, fds)
}

/// Wait until `done/` + `faulted/` hold `n` entries and nothing is incoming.
fn wait_settled(dir: &Path, n: usize, what: &str) {
    let t = Instant::now();
    loop {
        let settled = count(&dir.join("spool/done")) + count(&dir.join("spool/faulted"));
        if settled >= n && count(&dir.join("spool/incoming")) == 0 {
            return;
        }
        assert!(
            t.elapsed() < Duration::from_secs(240),
            "{what}: {settled} of {n} settled; status {}",
            status(dir)
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Add a status file's fault counts to `seen`.
fn add_counts(st: &serde_json::Value, seen: &mut std::collections::BTreeMap<String, u64>) {
    if let Some(m) = st["fault_counts"].as_object() {
        for (k, v) in m {
            *seen.entry(k.clone()).or_default() += v.as_u64().unwrap_or(0);
        }
    }
}

fn instances(http: u16) -> Vec<String> {
    http_get(http, "/instances")
        .and_then(|b| serde_json::from_slice(&b).ok())
        .unwrap_or_default()
}

#[test]
fn acquisitions_back_to_back_with_faults() {
    let n: usize = std::env::var("DBTOR_SOAK_ACQUISITIONS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10);
    let seed: u64 = std::env::var("DBTOR_SOAK_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(24);
    let dir = tempfile::tempdir().unwrap();
    let dir = dir.path();
    let acq = acquire(dir, 1);
    let h: serde_json::Value =
        serde_json::from_slice(&std::fs::read(acq.join("acquisition.json")).unwrap()).unwrap();
    let thickness = h["thickness_mm"].as_f64().unwrap();
    let (dicom, http) = (free_port(), free_port());
    let pacs_dir = dir.join("orthanc");
    std::fs::create_dir_all(&pacs_dir).unwrap();
    let mut orthanc = Some(Orthanc::start(&pacs_dir, dicom, http));
    let (fp, mp) = (free_port(), free_port());
    let (frames, registers) = (format!("127.0.0.1:{fp}"), format!("127.0.0.1:{mp}"));
    let mut regs = modbus(&registers, thickness, false);
    let cfg = dir.join("dbtor.toml");
    std::fs::write(
        &cfg,
        format!(
            r#"
[frames]
transport = "tcp"
address = "{frames}"
idle_timeout_s = 5
binning = 4

[modbus]
transport = "tcp"
address = "{registers}"
timeout_ms = 300
attempts = 2

[recon]
reconstructor = "mltr"
mltr_iterations = 20
dose_uncertainty = 0.2

[paths]
spool = "spool"
output = "output"
status = "run/status.json"

[status_page]
address = "127.0.0.1:0"

[report]
uid_root = "1.2.826.0.1.3680043.10.543.1"
pacs = "ORTHANC@127.0.0.1:{dicom}"
tube_output_mgy_per_mas = 0.11
"#
        ),
    )
    .unwrap();
    let mut d = daemon(&cfg);
    let mut rng = Rng(seed);
    let (mut reported, mut refused, mut restarts) = (0usize, 0usize, 0usize);
    let mut curve: Vec<(usize, u32, u64, usize, Fault)> = Vec::new();
    let mut expected_faults: std::collections::BTreeMap<&str, u64> = Default::default();
    // Fault counts over every daemon process (the status restarts with it).
    let mut seen: std::collections::BTreeMap<String, u64> = Default::default();
    // Every kind once first (so the short run covers them all), then at random.
    const EACH: [Fault; 7] = [
        Fault::None,
        Fault::Link,
        Fault::Cut,
        Fault::PacsDown,
        Fault::ModbusSilent,
        Fault::Kill,
        Fault::Impossible,
    ];
    for i in 0..n {
        let fault = EACH.get(i).copied().unwrap_or_else(|| rng.fault());
        let link_fault = ["corrupt:3", "drop:5", "dup:2", "reorder:7,9"][(rng.next() % 4) as usize];
        match fault {
            Fault::PacsDown => {
                if let Some(o) = orthanc.take() {
                    o.stop();
                }
            }
            Fault::ModbusSilent => {
                drop(regs);
                regs = modbus(&registers, thickness, true);
            }
            _ => {}
        }
        let faults: Vec<&str> = match fault {
            Fault::Link => vec![link_fault],
            Fault::Impossible => vec!["zeros:1"],
            _ => vec![],
        };
        let settled_before = count(&dir.join("spool/done")) + count(&dir.join("spool/faulted"));
        if fault == Fault::Cut {
            // The cable is pulled: the daemon records a link fault, the
            // gantry keeps the acquisition and sends it again.
            let mut s = stream(&acq, &frames, &["cut:8"]);
            hil_tests::wait_exit(
                &mut s.0,
                std::time::Duration::from_secs(120),
                "the cut host-sim stream",
            );
            *expected_faults.entry("link").or_default() += 1;
        }
        let s = stream(&acq, &frames, &faults);
        if fault == Fault::Kill {
            // SIGKILL while it processes, then a restart.
            let t = Instant::now();
            while status(dir)["state"] != "processing" {
                assert!(t.elapsed() < Duration::from_secs(60), "never processing");
                std::thread::sleep(Duration::from_millis(20));
            }
            drop(d);
            add_counts(&status(dir), &mut seen);
            d = daemon(&cfg);
            restarts += 1;
        }
        wait_settled(
            dir,
            settled_before + 1,
            &format!("acquisition {i} ({fault:?})"),
        );
        drop(s);
        match fault {
            Fault::PacsDown => {
                *expected_faults.entry("delivery").or_default() += 1;
                orthanc = Some(Orthanc::start(&pacs_dir, dicom, http));
            }
            Fault::ModbusSilent => {
                *expected_faults.entry("thickness").or_default() += 1;
                drop(regs);
                regs = modbus(&registers, thickness, false);
            }
            Fault::Impossible => *expected_faults.entry("implausible").or_default() += 1,
            _ => {}
        }
        if fault.refused() {
            refused += 1;
        } else {
            reported += 1;
        }
        let (rss, fds) = usage(d.0.id());
        curve.push((i, d.0.id(), rss, fds, fault));
    }
    // Reports that waited for the PACS arrive by the daemon's outbox flush.
    let t = Instant::now();
    while instances(http).len() < 2 * reported {
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "{} of {} reports in Orthanc; outbox: {}; faulted: {:?}; status {}",
            instances(http).len(),
            2 * reported,
            count(&dir.join("output/outbox")),
            std::fs::read_dir(dir.join("spool/faulted"))
                .map(|d| d
                    .flatten()
                    .filter_map(|e| std::fs::read_to_string(e.path().join("fault.json")).ok())
                    .collect::<Vec<_>>())
                .unwrap_or_default(),
            status(dir)
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    let st = status(dir);
    add_counts(&st, &mut seen);
    println!("soak: {n} acquisitions, seed {seed}: {reported} reported, {refused} refused, {restarts} restarts");
    println!(
        "{:>4} {:>8} {:>10} {:>5}  fault",
        "acq", "pid", "RSS kB", "fds"
    );
    for (i, pid, rss, fds, f) in &curve {
        println!("{i:>4} {pid:>8} {rss:>10} {fds:>5}  {f:?}");
    }
    println!("faults in the status, over every daemon process: {seen:?}");
    drop(d);
    drop(regs);

    // 0 lost, 0 duplicated: every reported acquisition's two SRs once in
    // Orthanc (SOP Instance UIDs are fixed by the spool entry, so a report
    // sent twice would not add an instance; a re-processed entry with new
    // UIDs would), every refused one kept in faulted/.
    assert_eq!(instances(http).len(), 2 * reported, "reports in Orthanc");
    assert_eq!(count(&dir.join("spool/done")), reported);
    assert_eq!(count(&dir.join("spool/faulted")), refused);
    assert_eq!(count(&dir.join("output/outbox")), 0);
    // Every injected fault visible in the status, by kind.
    for (kind, want) in &expected_faults {
        let got = seen.get(*kind).copied().unwrap_or(0);
        assert!(
            got >= *want,
            "{kind}: {got} faults in the status, {want} injected; {seen:?}"
        );
    }
    // RSS and fds flat after warm-up (the first third, per daemon process):
    // the last sample of each process within 25 % (RSS) and 4 (fds) of its
    // largest warm sample.
    let mut by_pid: std::collections::BTreeMap<u32, Vec<(u64, usize)>> = Default::default();
    for (_, pid, rss, fds, _) in &curve {
        by_pid.entry(*pid).or_default().push((*rss, *fds));
    }
    for (pid, s) in by_pid {
        if s.len() < 6 {
            continue;
        }
        let warm = s.len() / 3;
        let (max_rss, max_fd) = s[..warm]
            .iter()
            .fold((0, 0), |a, b| (a.0.max(b.0), a.1.max(b.1)));
        for (k, (rss, fds)) in s.iter().enumerate().skip(warm) {
            assert!(
                *rss as f64 <= 1.25 * max_rss as f64,
                "pid {pid}: RSS {rss} kB at sample {k}, warm maximum {max_rss} kB"
            );
            assert!(
                *fds <= max_fd + 4,
                "pid {pid}: {fds} fds at sample {k}, warm maximum {max_fd}"
            );
        }
    }
    drop(orthanc);
}
