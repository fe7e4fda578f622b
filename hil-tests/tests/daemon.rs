//! The daemon (`dbtor-daemon`) as a separate process beside host-sim's frame
//! server and Modbus server, over loopback TCP: an acquisition is spooled,
//! processed and reported; SIGKILL in the middle of processing and a restart
//! report it exactly once; SIGTERM stops it cleanly; a thickness disagreement
//! between the Modbus register and the acquisition header is a fault, not a
//! report; a bad configuration is refused naming the key.

use hil_tests::{free_port, pty_pair, wait_exit, workspace_bin};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Test phantom 1 acquired, with its compressed thickness.
fn acquire(dir: &Path) -> (PathBuf, f64) {
    acquire_on(dir, "paper")
}

fn acquire_on(dir: &Path, geometry: &str) -> (PathBuf, f64) {
    let acq = hil_tests::acquire_on(dir, 1, geometry);
    let t = thickness_of(&acq);
    (acq, t)
}

/// A recorded acquisition's compressed thickness.
fn thickness_of(acq: &Path) -> f64 {
    let h: serde_json::Value =
        serde_json::from_slice(&std::fs::read(acq.join("acquisition.json")).unwrap()).unwrap();
    h["thickness_mm"].as_f64().unwrap()
}

struct Gantry {
    modbus: Child,
    stream: Child,
    frames: String,
    registers: String,
}

impl Drop for Gantry {
    fn drop(&mut self) {
        let _ = self.modbus.kill();
        let _ = self.stream.kill();
        let _ = self.modbus.wait();
        let _ = self.stream.wait();
    }
}

fn gantry(acq: &Path, thickness_mm: f64) -> Gantry {
    gantry_with(acq, thickness_mm, &[])
}

/// As [`gantry`], the stream with host-sim `--fault`s.
fn gantry_with(acq: &Path, thickness_mm: f64, faults: &[&str]) -> Gantry {
    gantry_full(acq, thickness_mm, faults, &[])
}

/// As [`gantry_with`], the Modbus server with extra options.
fn gantry_full(acq: &Path, thickness_mm: f64, faults: &[&str], modbus_args: &[&str]) -> Gantry {
    let (fp, mp) = (free_port(), free_port());
    let frames = format!("127.0.0.1:{fp}");
    let registers = format!("127.0.0.1:{mp}");
    let modbus = Command::new(workspace_bin("host-sim"))
        .args([
            "modbus",
            "--listen",
            &registers,
            "--thickness-mm",
            &format!("{thickness_mm:.1}"),
        ])
        .args(modbus_args)
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let stream = Command::new(workspace_bin("host-sim"))
        .args(["stream", "--acq"])
        .arg(acq)
        .args(["--listen", &frames])
        .args(faults.iter().flat_map(|f| ["--fault", f]))
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    Gantry {
        modbus,
        stream,
        frames,
        registers,
    }
}

/// The repository's copy of the model the shipped configuration names
/// (`firmware/config/dbtor.toml`, `recon.model = ".../<name>"` ->
/// `models/<name>`): switching the shipped model is one edit of that file.
/// Returns the folder, its signed-off digest (`recon.model_digest`), the
/// gantry geometry the configuration pairs it with (`frames.geometry`) and
/// the gantry's cone-beam system (`frames.system`, if any).
fn shipped_model() -> (PathBuf, String, String, Option<String>) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let text = std::fs::read_to_string(root.join("firmware/config/dbtor.toml")).unwrap();
    let shipped: toml::Value = toml::from_str(&text).unwrap();
    let installed = shipped["recon"]["model"].as_str().unwrap();
    let name = Path::new(installed).file_name().unwrap();
    let model = root.join("models").join(name);
    assert!(model.join("manifest.json").is_file(), "{}", model.display());
    let digest = shipped["recon"]["model_digest"]
        .as_str()
        .unwrap()
        .to_string();
    let geometry = shipped["frames"]["geometry"].as_str().unwrap().to_string();
    let system = shipped["frames"]
        .get("system")
        .and_then(|s| s.as_str())
        .map(String::from);
    (model, digest, geometry, system)
}

/// A daemon configuration in `dir` from its frames, Modbus and recon
/// sections; the paths and report sections are common to every test.
fn write_config(dir: &Path, frames: &str, modbus: &str, recon: &str) -> PathBuf {
    let text = format!(
        r#"
[frames]
{frames}
idle_timeout_s = 20
binning = 4

[modbus]
{modbus}

[recon]
{recon}
dose_uncertainty = 0.2

[paths]
spool = "spool"
output = "output"
status = "run/status.json"

[status_page]
address = "127.0.0.1:0"

[report]
uid_root = "1.2.826.0.1.3680043.10.543.1"
tube_output_mgy_per_mas = 0.11
tube_output_w_al_mgy_per_mas = 0.11
"#
    );
    let p = dir.join("dbtor.toml");
    std::fs::write(&p, text).unwrap();
    p
}

fn config(dir: &Path, g: &Gantry, iterations: usize) -> PathBuf {
    write_config(
        dir,
        &format!("transport = \"tcp\"\naddress = \"{}\"", g.frames),
        &format!(
            "transport = \"tcp\"\naddress = \"{}\"\ntimeout_ms = 500\nattempts = 3\nthickness_tolerance_mm = 1.0",
            g.registers
        ),
        &format!("reconstructor = \"mltr\"\nmltr_iterations = {iterations}"),
    )
}

/// Test phantom 1 acquired on the shipped model's geometry and system
/// with the `host-sim acquire` arguments `extra`.
fn acquire_shipped(
    dir: &Path,
    shipped: &(PathBuf, String, String, Option<String>),
    extra: &[&str],
) -> PathBuf {
    hil_tests::acquire_args(dir, "acq", 1, &shipped.2, shipped.3.as_deref(), extra)
}

/// A configuration for the gantry `g` running the shipped model
/// (`shipped_model()`) in int8 on its geometry and system, the beam
/// hardening linearised and the scatter removal `scatter` (`kernel` or
/// `off`); with the removal, the noise matched to the model's training
/// level (the clinical setup eval/README.md measures).
fn clinical_config(
    dir: &Path,
    g: &Gantry,
    shipped: &(PathBuf, String, String, Option<String>),
    scatter: &str,
) -> PathBuf {
    let (model, digest, geometry, system) = shipped;
    write_config(
        dir,
        &format!(
            "transport = \"tcp\"\naddress = \"{}\"\ngeometry = \"{geometry}\"\n{}",
            g.frames,
            system
                .as_ref()
                .map(|s| format!("system = {s:?}"))
                .unwrap_or_default()
        ),
        &format!(
            "transport = \"tcp\"\naddress = \"{}\"\ntimeout_ms = 500\nattempts = 3\nthickness_tolerance_mm = 1.0",
            g.registers
        ),
        &format!(
            "reconstructor = \"dbtor\"\nmodel = {:?}\nmodel_digest = {digest:?}\nprecision = \"int8\"\nbeam_hardening = \"csi\"\nscatter = \"{scatter}\"\nnoise_match = \"{}\"",
            model.display().to_string(),
            if scatter == "kernel" { "training-level" } else { "off" }
        ),
    )
}

fn daemon(cfg: &Path, extra: &[&str]) -> Child {
    Command::new(workspace_bin("dbtor-daemon"))
        .arg("--config")
        .arg(cfg)
        .args(extra)
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

/// `dbtor-daemon --once` on `cfg`, its exit status; a daemon still running
/// after 5 minutes (one acquisition takes seconds) fails the test.
fn once(cfg: &Path) -> std::process::ExitStatus {
    wait_exit(
        &mut daemon(cfg, &["--once"]),
        Duration::from_secs(300),
        &format!("dbtor-daemon --once --config {}", cfg.display()),
    )
}

fn status(dir: &Path) -> serde_json::Value {
    hil_tests::daemon_status(dir)
}

fn wait_for(
    dir: &Path,
    what: &str,
    limit: Duration,
    f: impl Fn(&serde_json::Value) -> bool,
) -> serde_json::Value {
    hil_tests::wait_for_status(dir, what, limit, f)
}

fn entries(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|r| {
            r.flatten()
                .filter_map(|e| e.file_name().to_str().map(String::from))
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

fn sigterm(child: &mut Child) -> std::process::ExitStatus {
    let ok = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(ok.success());
    let t0 = Instant::now();
    loop {
        if let Some(st) = child.try_wait().unwrap() {
            return st;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "no exit after SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn sigkill_mid_processing_then_restart_reports_exactly_once() {
    let dir = tempfile::tempdir().unwrap();
    let (acq, thickness) = acquire(dir.path());
    let g = gantry(&acq, thickness);
    let cfg = config(dir.path(), &g, 20);
    let mut d = daemon(&cfg, &[]);
    let s = wait_for(dir.path(), "processing", Duration::from_secs(120), |s| {
        s["state"] == "processing"
    });
    let id = s["current"].as_str().unwrap().to_string();
    d.kill().unwrap(); // SIGKILL
    wait_exit(&mut d, Duration::from_secs(60), "the killed daemon");
    assert_eq!(
        entries(&dir.path().join("spool/incoming")),
        vec![id.clone()],
        "the acquisition must survive in the spool"
    );
    assert!(entries(&dir.path().join("spool/done")).is_empty());

    // Restart: the spooled acquisition is processed first.
    let mut d = daemon(&cfg, &[]);
    let s = wait_for(dir.path(), "recovery", Duration::from_secs(180), |s| {
        s["processed"] == 1 && s["state"] == "waiting"
    });
    assert_eq!(s["recovered"], 1, "{s}");
    let st = sigterm(&mut d);
    assert!(st.success(), "{st:?}");
    assert_eq!(status(dir.path())["state"], "stopped");

    assert!(entries(&dir.path().join("spool/incoming")).is_empty());
    assert_eq!(entries(&dir.path().join("spool/done")), vec![id.clone()]);
    let reports: Vec<String> = entries(&dir.path().join("output"))
        .into_iter()
        .filter(|n| n.ends_with(".dcm"))
        .collect();
    assert_eq!(
        reports,
        vec![format!("{id}-density-sr.dcm"), format!("{id}-dose-sr.dcm")]
    );
    let result: serde_json::Value = serde_json::from_slice(
        &std::fs::read(dir.path().join("spool/done").join(&id).join("result.json")).unwrap(),
    )
    .unwrap();
    assert!(result["mgd_mgy"].as_f64().unwrap() > 0.0, "{result}");
    // The reports read back.
    for r in &reports {
        let out = Command::new(workspace_bin("dbtor-diag"))
            .arg("report")
            .arg(dir.path().join("output").join(r))
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    // The diagnostics CLI reads the status file.
    let out = Command::new(workspace_bin("dbtor-diag"))
        .args(["status", "--json", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["status"]["processed"], 1, "{v}");
    // The service engineer's offline replay of the spooled acquisition
    // with the site's configuration reproduces the report.
    replay_reproduces_the_report(&cfg, &dir.path().join("spool/done").join(&id));
}

/// `dbtor-diag replay --config CFG ENTRY` (issue #50): the daemon's own
/// processing assembled from the site's configuration
/// (`dbtor_firmware::assembly`) replays a `done/` entry to the reported
/// glandularity and MGD (the same seed: to the bit; the MGD allowed three
/// of its Monte Carlo standard errors should the sums' order ever differ).
fn replay_reproduces_the_report(cfg: &Path, entry: &Path) {
    let out = Command::new(workspace_bin("dbtor-diag"))
        .args(["replay", "--json", "--config"])
        .arg(cfg)
        .arg(entry)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let stored = &v["stored_result"];
    let f = |x: &serde_json::Value| x.as_f64().unwrap_or(f64::NAN);
    for key in [
        "glandularity_reported",
        "glandularity_labels",
        "glandularity_partial_volume",
    ] {
        assert!((f(&v[key]) - f(&stored[key])).abs() < 1e-9, "{key}: {v}");
    }
    let (mgd, u) = (f(&v["mgd_mgy"]), f(&v["mgd_relative_uncertainty"]));
    assert!(
        (mgd / f(&stored["mgd_mgy"]) - 1.0).abs() <= 3.0 * u,
        "MGD: {v}"
    );
    assert_eq!(v["reconstructor"], stored["reconstructor"], "{v}");
    // Without the configuration the replay says it is not the report's.
    assert!(
        v["processing"]
            .as_str()
            .unwrap()
            .starts_with("the daemon's"),
        "{v}"
    );
}

#[test]
fn thickness_disagreement_is_a_fault_not_a_report() {
    let dir = tempfile::tempdir().unwrap();
    let (acq, thickness) = acquire(dir.path());
    let g = gantry(&acq, thickness + 5.0);
    let cfg = config(dir.path(), &g, 2);
    let st = once(&cfg);
    assert_eq!(st.code(), Some(1), "--once after a fault exits 1");
    let s = status(dir.path());
    let faults = s["faults"].as_array().unwrap();
    assert!(
        faults
            .iter()
            .any(|f| f["kind"] == "thickness"
                && f["message"].as_str().unwrap().contains("disagreement")),
        "{s}"
    );
    assert_eq!(entries(&dir.path().join("spool/faulted")).len(), 1);
    assert!(entries(&dir.path().join("output"))
        .iter()
        .all(|n| !n.ends_with(".dcm")));
    // diag exits 1 when the last acquisition faulted.
    let out = Command::new(workspace_bin("dbtor-diag"))
        .args(["status", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    assert_eq!(
        out.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("thickness"));
}

/// An exposure with another anode/filter than the dose model's (W/Rh,
/// W/Al) is a `technique` fault naming it, kept in faulted/, never a report
/// (issue #27); so is a register that names another beam than the
/// stream's header, and, at a site that takes no beam for granted
/// (`[report] unstated_beam = "refuse"`), a stream whose header states none
/// without a register to say it; and an exposure whose kV the site's tube
/// output table does not cover.
#[test]
fn another_anode_filter_is_a_fault_not_a_report() {
    let dir = tempfile::tempdir().unwrap();
    let (acq, thickness) = acquire(dir.path());
    let g = gantry_full(&acq, thickness, &[], &["--anode-filter", "Rh/Ag"]);
    let cfg = config(dir.path(), &g, 2);
    let st = once(&cfg);
    assert_eq!(st.code(), Some(1), "--once after a fault exits 1");
    let s = status(dir.path());
    let f = &s["faults"][0];
    assert_eq!(f["kind"], "technique", "{s}");
    let m = f["message"].as_str().unwrap();
    assert!(
        m.contains("Rh/Ag") && m.contains("W/Rh, W/Al, W/Ag, Mo/Mo, Mo/Rh, Rh/Rh"),
        "{m}"
    );
    drop(g);
    // The stream's header says W/Rh (the acquisition's beam), the register
    // W/Al: which beam was used is not known, nothing is reported.
    let run = dir.path().join("disagree");
    std::fs::create_dir_all(&run).unwrap();
    let g = gantry_full(&acq, thickness, &[], &["--anode-filter", "W/Al"]);
    let cfg = config(&run, &g, 2);
    let st = once(&cfg);
    assert_eq!(st.code(), Some(1), "--once after a fault exits 1");
    let s = status(&run);
    let m = s["faults"][0]["message"].as_str().unwrap();
    assert!(
        m.contains("disagreement") && m.contains("W/Al") && m.contains("W/Rh"),
        "{m}"
    );
    assert_eq!(entries(&run.join("spool/faulted")).len(), 1);
    assert_eq!(entries(&dir.path().join("spool/faulted")).len(), 1);
    assert!(entries(&dir.path().join("output"))
        .iter()
        .all(|n| !n.ends_with(".dcm")));
    // No register and a header that states no beam: a site that takes no
    // beam for granted refuses it (kept in faulted/); one that names its
    // beam (the default, W/Rh) reports it.
    for (unstated, code) in [("refuse", 1), ("W/Rh", 0)] {
        let run = dir.path().join(unstated.replace('/', "-"));
        std::fs::create_dir_all(&run).unwrap();
        let g = gantry_with(&acq, thickness, &["anode:0"]);
        let cfg = write_config(
            &run,
            &format!("transport = \"tcp\"\naddress = \"{}\"", g.frames),
            "transport = \"off\"",
            "reconstructor = \"mltr\"\nmltr_iterations = 20",
        );
        let text = std::fs::read_to_string(&cfg).unwrap().replace(
            "tube_output_w_al_mgy_per_mas = 0.11",
            &format!("tube_output_w_al_mgy_per_mas = 0.11\nunstated_beam = {unstated:?}"),
        );
        std::fs::write(&cfg, text).unwrap();
        let st = once(&cfg);
        let s = status(&run);
        assert_eq!(st.code(), Some(code), "unstated_beam {unstated}: {s}");
        if code == 1 {
            let f = &s["faults"][0];
            assert_eq!(f["kind"], "technique", "{s}");
            let m = f["message"].as_str().unwrap();
            assert!(m.contains("unstated_beam") && m.contains("refuse"), "{m}");
            assert_eq!(entries(&run.join("spool/faulted")).len(), 1);
        } else {
            assert_eq!(s["processed"], 1, "{s}");
        }
    }
    // A tube output measured by kV that does not reach the exposure's kV
    // (the QC's table of another technique range): not extrapolated, a
    // technique fault naming the range.
    let run = dir.path().join("kv-table");
    std::fs::create_dir_all(&run).unwrap();
    let g = gantry(&acq, thickness);
    let cfg = config(&run, &g, 20);
    let text = std::fs::read_to_string(&cfg).unwrap().replace(
        "tube_output_mgy_per_mas = 0.11\n",
        "tube_output_mgy_per_mas = { kv = [20, 21], mgy_per_mas = [0.05, 0.055] }\n",
    );
    std::fs::write(&cfg, text).unwrap();
    assert_eq!(once(&cfg).code(), Some(1));
    let s = status(&run);
    let f = &s["faults"][0];
    assert_eq!(f["kind"], "technique", "{s}");
    let m = f["message"].as_str().unwrap();
    assert!(m.contains("tube output") && m.contains("20-21 kV"), "{m}");
    assert_eq!(entries(&run.join("spool/faulted")).len(), 1);
    // A table that does: the dose is the output at the exposure's kV (twice
    // the flat 0.11 here, while the table's first figure, the placeholder
    // of the spooled header, is 0.05), and the spooled header keeps it, so
    // a replay of the entry computes the same dose.
    let header: serde_json::Value =
        serde_json::from_slice(&std::fs::read(acq.join("acquisition.json")).unwrap()).unwrap();
    let kv = header["kvp"].as_f64().unwrap();
    let mut mgd = Vec::new();
    for (name, output) in [
        ("flat", "0.11".to_string()),
        (
            "kv-table-in",
            format!("{{ kv = [20, {kv}, 49], mgy_per_mas = [0.05, 0.22, 0.3] }}"),
        ),
    ] {
        let run = dir.path().join(name);
        std::fs::create_dir_all(&run).unwrap();
        let g = gantry(&acq, thickness);
        let cfg = config(&run, &g, 20);
        let text = std::fs::read_to_string(&cfg).unwrap().replace(
            "tube_output_mgy_per_mas = 0.11\n",
            &format!("tube_output_mgy_per_mas = {output}\n"),
        );
        std::fs::write(&cfg, text).unwrap();
        assert_eq!(once(&cfg).code(), Some(0), "{name}: {}", status(&run));
        mgd.push(status(&run)["recent"][0]["mgd_mgy"].as_f64().unwrap());
        let done = entries(&run.join("spool/done"));
        let spooled: serde_json::Value = serde_json::from_slice(
            &std::fs::read(
                run.join("spool/done")
                    .join(&done[0])
                    .join("acquisition.json"),
            )
            .unwrap(),
        )
        .unwrap();
        let want = if name == "flat" { 0.11 } else { 0.22 };
        assert_eq!(
            spooled["tube_output_mgy_per_mas"].as_f64(),
            Some(want),
            "{name}"
        );
    }
    assert!(
        (mgd[1] / mgd[0] - 2.0).abs() < 1e-6,
        "MGD {} with the table against {} flat",
        mgd[1],
        mgd[0]
    );
}

/// Start the daemon on `cfg`, expect exit 2 (refused at start), return its
/// stderr.
fn refused(cfg: &Path) -> String {
    let out = Command::new(workspace_bin("dbtor-daemon"))
        .arg("--config")
        .arg(cfg)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn bad_configuration_is_refused_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let g = Gantry {
        modbus: Command::new("true").spawn().unwrap(),
        stream: Command::new("true").spawn().unwrap(),
        frames: "127.0.0.1:1".into(),
        registers: "not-an-address".into(),
    };
    let err = refused(&config(dir.path(), &g, 2));
    assert!(err.contains("modbus.address"), "{err}");
    assert!(
        !dir.path().join("spool").exists(),
        "nothing may start on a bad configuration"
    );
    // A model trained for another geometry than the gantry's: refused at
    // start, naming the key and both geometries.
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/dbtor-x4");
    let cfg = write_config(
        dir.path(),
        "transport = \"tcp\"\naddress = \"127.0.0.1:1\"\ngeometry = \"paper-tall\"",
        "transport = \"off\"",
        &format!(
            "reconstructor = \"dbtor\"\nmodel = {:?}",
            model.display().to_string()
        ),
    );
    let err = refused(&cfg);
    assert!(
        err.contains("recon.model") && err.contains("250x75") && err.contains("250x100"),
        "{err}"
    );
    assert!(!dir.path().join("spool").exists());
}

/// The same daemon with the gantry on serial lines only: frames on one socat
/// pty pair, Modbus RTU on another. A clean acquisition is reported.
#[test]
fn clean_acquisition_over_serial_lines() {
    let dir = tempfile::tempdir().unwrap();
    // The shipped model on the fast engine, its geometry and the gantry's
    // cone-beam system: the gantry PC's configuration (2-D detector frames
    // over the serial line, rebinned by the firmware).
    let (model, digest, geometry, system) = shipped_model();
    let acq = hil_tests::acquire_with(dir.path(), "acq", 1, &geometry, system.as_deref());
    let thickness = thickness_of(&acq);
    let frames = pty_pair(dir.path(), "frames");
    let regs = pty_pair(dir.path(), "modbus");
    let (frames_gantry, frames_pc) = (&frames.a, &frames.b);
    let (modbus_gantry, modbus_pc) = (&regs.a, &regs.b);
    let modbus = Command::new(workspace_bin("host-sim"))
        .args(["modbus", "--serial"])
        .arg(modbus_gantry)
        .args(["--thickness-mm", &format!("{thickness:.1}")])
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let cfg = write_config(
        dir.path(),
        &format!(
            "transport = \"serial\"\nport = \"{}\"\ngeometry = \"{geometry}\"\n{}",
            frames_pc.display(),
            system
                .as_ref()
                .map(|s| format!("system = {s:?}"))
                .unwrap_or_default()
        ),
        &format!(
            "transport = \"rtu\"\nport = \"{}\"\nbaud = 19200\ntimeout_ms = 1000",
            modbus_pc.display()
        ),
        &format!(
            "reconstructor = \"dbtor\"\nmodel = {:?}\nmodel_digest = {digest:?}\nprecision = \"int8\"\nengine = \"fast\"",
            model.display().to_string()
        ),
    );
    let mut d = daemon(&cfg, &["--once"]);
    // The daemon opens its ends first; then the gantry streams.
    std::thread::sleep(Duration::from_millis(500));
    let stream = Command::new(workspace_bin("host-sim"))
        .args(["stream", "--acq"])
        .arg(&acq)
        .arg("--serial")
        .arg(frames_gantry)
        .args(["--fault", "corrupt:2", "--fault", "drop:5"])
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    let st = loop {
        if let Some(st) = d.try_wait().unwrap() {
            break st;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(180),
            "daemon did not finish; status {}",
            status(dir.path())
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    for mut c in [stream, modbus] {
        let _ = c.kill();
        let _ = c.wait();
    }
    drop((frames, regs));
    assert!(st.success(), "{st:?}");
    let s = status(dir.path());
    assert_eq!(s["processed"], 1, "{s}");
    assert!(s["faults"].as_array().unwrap().is_empty(), "{s}");
    // The shipped model carries an int8 glandularity calibration too.
    let rec = s["recent"][0]["reconstructor"].as_str().unwrap_or_default();
    assert!(
        rec.starts_with("DBToR") && rec.ends_with("(int8, fast, calibrated)"),
        "{s}"
    );
    assert_eq!(s["recent"][0]["calibrated"], true, "{s}");
    let reports = entries(&dir.path().join("output"))
        .into_iter()
        .filter(|n| n.ends_with(".dcm"))
        .count();
    assert_eq!(reports, 2);
    let done = entries(&dir.path().join("spool/done"));
    let gantry: serde_json::Value = serde_json::from_slice(
        &std::fs::read(
            dir.path()
                .join("spool/done")
                .join(&done[0])
                .join("gantry.json"),
        )
        .unwrap(),
    )
    .unwrap();
    assert!(
        (gantry["modbus"]["thickness_mm"].as_f64().unwrap() - thickness).abs() < 0.06,
        "{gantry}"
    );
    assert!(
        gantry["link"]["crc_errors"].as_u64().unwrap() >= 1,
        "{gantry}"
    );
    // A cone-beam entry replays to its report.
    replay_reproduces_the_report(&cfg, &dir.path().join("spool/done").join(&done[0]));
}

/// The clinical physics end to end (issue #27): the gantry's cone-beam
/// frames of a polychromatic exposure through a CsI detector with scatter
/// (`host-sim acquire --physics clinical`), the daemon configured for that
/// detector (`[recon] scatter = "kernel"`, `beam_hardening = "csi"`) with
/// the shipped model in int8: reported, within 3 pp of the phantom's
/// glandularity. The same daemon without the scatter removal refuses the
/// same frames (the air beside the breast reads above the flat field):
/// a fault, not a report.
#[test]
fn clinical_physics_is_reported_after_both_corrections() {
    let dir = tempfile::tempdir().unwrap();
    let shipped = shipped_model();
    let acq = acquire_shipped(dir.path(), &shipped, &["--physics", "clinical"]);
    let thickness = thickness_of(&acq);
    let truth = {
        let h: serde_json::Value =
            serde_json::from_slice(&std::fs::read(acq.join("acquisition.json")).unwrap()).unwrap();
        assert_eq!(h["truth"]["physics"], "clinical");
        h["truth"]["glandularity"].as_f64().unwrap()
    };
    for scatter in ["kernel", "off"] {
        let run = dir.path().join(scatter);
        std::fs::create_dir_all(&run).unwrap();
        let g = gantry(&acq, thickness);
        let cfg = clinical_config(&run, &g, &shipped, scatter);
        let st = once(&cfg);
        let s = status(&run);
        if scatter == "kernel" {
            assert!(st.success(), "{st:?} {s}");
            assert_eq!(s["processed"], 1, "{s}");
            assert!(s["faults"].as_array().unwrap().is_empty(), "{s}");
            let g = s["recent"][0]["glandularity_reported"].as_f64().unwrap();
            assert!((g - truth).abs() < 0.03, "reported {g}, truth {truth}");
            // The kernels were chosen by measurement on the model's own
            // blocks, and the status says which and how fast (issue #52).
            assert!(
                s["kernels"].as_array().is_some_and(|k| k
                    .iter()
                    .any(|l| l.as_str().is_some_and(|l| l.contains("(chosen)")))),
                "{s}"
            );
            // The daemon states its peak memory (issue #30).
            let rss = s["peak_rss_mib"].as_f64().unwrap();
            assert!(rss > 10.0, "{s}");
            eprintln!("daemon peak resident memory {rss:.0} MiB");
            // A clinical entry (both corrections, noise matching) replays
            // to its report.
            let done = entries(&run.join("spool/done"));
            replay_reproduces_the_report(&cfg, &run.join("spool/done").join(&done[0]));
        } else {
            assert_eq!(st.code(), Some(1), "--once after a fault exits 1: {s}");
            let m = s["faults"][0]["message"].as_str().unwrap();
            assert!(m.contains("above the flat field"), "{m}");
            assert_eq!(entries(&run.join("spool/faulted")).len(), 1);
        }
    }
}

/// A vendor's gantry without a trained model (issue #51 point 3): test
/// phantom 1 acquired on Hologic's gantry (tilting detector, the pivot in
/// its plane, 15 views over +-7.5 degrees; clinical physics on its a-Se
/// detector), streamed and registered like any other; the daemon
/// configured with that system, `beam_hardening = "a-se"` and
/// `reconstructor = "physics"` reports it without a reconstruction: the
/// physics density within 4 pp of the truth, no fault, both SRs naming the
/// method and read back by `dbtor-diag report`, the dose SR with an
/// irradiation event per view of Hologic's 15; the entry replays to its
/// report.
#[test]
fn a_vendor_gantry_without_a_model_is_reported_by_the_physics() {
    let dir = tempfile::tempdir().unwrap();
    let shipped = shipped_model();
    let system = "hologic-dimensions";
    let acq = hil_tests::acquire_args(
        dir.path(),
        "acq",
        1,
        &shipped.2,
        Some(system),
        &["--physics", "clinical"],
    );
    let thickness = thickness_of(&acq);
    let truth = {
        let h: serde_json::Value =
            serde_json::from_slice(&std::fs::read(acq.join("acquisition.json")).unwrap()).unwrap();
        h["truth"]["glandularity"].as_f64().unwrap()
    };
    let g = gantry(&acq, thickness);
    let cfg = write_config(
        dir.path(),
        &format!(
            "transport = \"tcp\"\naddress = \"{}\"\ngeometry = {:?}\nsystem = {system:?}",
            g.frames, shipped.2
        ),
        &format!(
            "transport = \"tcp\"\naddress = \"{}\"\ntimeout_ms = 500\nattempts = 3\nthickness_tolerance_mm = 1.0",
            g.registers
        ),
        "reconstructor = \"physics\"\nbeam_hardening = \"a-se\"\nscatter = \"kernel\"",
    );
    let st = once(&cfg);
    let s = status(dir.path());
    assert!(st.success(), "{st:?} {s}");
    assert_eq!(s["processed"], 1, "{s}");
    assert!(s["faults"].as_array().unwrap().is_empty(), "{s}");
    let reported = s["recent"][0]["glandularity_reported"].as_f64().unwrap();
    assert!(
        (reported - truth).abs() < 0.04,
        "reported {reported}, truth {truth}"
    );
    // Both reports name the method and read back.
    let reports: Vec<PathBuf> = std::fs::read_dir(dir.path().join("output"))
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "dcm"))
        .collect();
    assert_eq!(reports.len(), 2, "{reports:?}");
    for r in &reports {
        let bytes = std::fs::read(r).unwrap();
        assert!(
            String::from_utf8_lossy(&bytes)
                .contains("No DBToR model is trained and calibrated for this gantry and beam"),
            "{}",
            r.display()
        );
        let out = Command::new(workspace_bin("dbtor-diag"))
            .arg("report")
            .arg(r)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        if r.to_string_lossy().ends_with("dose-sr.dcm") {
            let events = bytes.windows(6).filter(|w| w == b"113769").count();
            assert_eq!(events, 15, "one irradiation event per view");
        }
    }
    let done = entries(&dir.path().join("spool/done"));
    replay_reproduces_the_report(&cfg, &dir.path().join("spool/done").join(&done[0]));
}

/// A W/Al exposure end to end (issue #27): the clinical physics of a
/// tungsten beam through 0.7 mm aluminium at its automatic exposure's kV
/// (`host-sim acquire --anode-filter W/Al`), the stream's header and the
/// gantry's register 6 both W/Al; the daemon removes the scatter with the
/// W/Al kernels, linearises with the W/Al spectrum and computes the dose
/// with it: reported within 3 pp, and the dose SR names the aluminium
/// filter (CID 10006), not rhodium. Without a W/Al tube output in the
/// configuration the same exposure is a `technique` fault, not a report
/// dosed with the W/Rh output.
#[test]
fn a_w_al_exposure_is_reported_with_its_own_beam() {
    let dir = tempfile::tempdir().unwrap();
    let shipped = shipped_model();
    let acq = acquire_shipped(
        dir.path(),
        &shipped,
        &["--physics", "clinical", "--anode-filter", "W/Al"],
    );
    let thickness = thickness_of(&acq);
    let h: serde_json::Value =
        serde_json::from_slice(&std::fs::read(acq.join("acquisition.json")).unwrap()).unwrap();
    assert_eq!(h["anode_filter"], "W/Al", "{h}");
    let truth = h["truth"]["glandularity"].as_f64().unwrap();
    let no_output = dir.path().join("no-w-al-output");
    std::fs::create_dir_all(&no_output).unwrap();
    let g = gantry_full(&acq, thickness, &[], &["--anode-filter", "W/Al"]);
    let cfg = clinical_config(&no_output, &g, &shipped, "kernel");
    let text = std::fs::read_to_string(&cfg).unwrap();
    std::fs::write(
        &cfg,
        text.replace("tube_output_w_al_mgy_per_mas = 0.11\n", ""),
    )
    .unwrap();
    let st = once(&cfg);
    assert_eq!(st.code(), Some(1), "--once after a fault exits 1");
    let s = status(&no_output);
    let m = s["faults"][0]["message"].as_str().unwrap();
    assert!(m.contains("W/Al") && m.contains("tube output"), "{m}");
    drop(g);
    let g = gantry_full(&acq, thickness, &[], &["--anode-filter", "W/Al"]);
    let cfg = clinical_config(dir.path(), &g, &shipped, "kernel");
    let st = once(&cfg);
    let s = status(dir.path());
    assert!(st.success(), "{st:?} {s}");
    assert_eq!(s["processed"], 1, "{s}");
    let gl = s["recent"][0]["glandularity_reported"].as_f64().unwrap();
    assert!((gl - truth).abs() < 0.03, "reported {gl}, truth {truth}");
    let dose = entries(&dir.path().join("output"))
        .into_iter()
        .find(|n| n.ends_with("-dose-sr.dcm"))
        .expect("a dose SR");
    let bytes = std::fs::read(dir.path().join("output").join(dose)).unwrap();
    let has = |t: &str| bytes.windows(t.len()).any(|w| w == t.as_bytes());
    // A stream header that does not state the beam (optional there): the
    // register's is taken and spooled with the acquisition, so a replay of
    // the entry keeps it.
    let unstated = dir.path().join("unstated");
    std::fs::create_dir_all(&unstated).unwrap();
    let g2 = gantry_full(&acq, thickness, &["anode:0"], &["--anode-filter", "W/Al"]);
    let cfg2 = clinical_config(&unstated, &g2, &shipped, "kernel");
    let st2 = once(&cfg2);
    let s2 = status(&unstated);
    assert!(st2.success(), "{st2:?} {s2}");
    assert_eq!(
        s2["recent"][0]["glandularity_reported"].as_f64(),
        Some(gl),
        "the same W/Al processing: {s2}"
    );
    let done = unstated.join("spool/done");
    let entry = entries(&done).into_iter().next().expect("a done entry");
    let spooled: serde_json::Value =
        serde_json::from_slice(&std::fs::read(done.join(entry).join("acquisition.json")).unwrap())
            .unwrap();
    assert_eq!(spooled["anode_filter"], "W/Al", "{spooled}");
    assert!(
        has("12503006") && has("Aluminum"),
        "the SR names the aluminium filter"
    );
    assert!(!has("Rhodium"), "and no rhodium");
}

/// Data faults with valid CRCs: detector saturation in one projection is a
/// `data` fault (the acquisition is kept in `spool/faulted`, no report); a NaN
/// flat field is refused at reception with the view and element named.
#[test]
fn saturated_counts_and_nan_flat_field_are_faults_not_reports() {
    for (fault, kind, words) in [
        ("saturate:4", "data", "saturated at 65535 in views [3]"),
        ("nanflat:2", "link", "flat field NaN"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let (acq, thickness) = acquire(dir.path());
        let g = gantry_with(&acq, thickness, &[fault]);
        let cfg = config(dir.path(), &g, 2);
        // With --once, a fault is a failure (exit 1), and the status names it.
        let st = once(&cfg);
        assert_eq!(st.code(), Some(1), "{fault}");
        let s = status(dir.path());
        let f = &s["faults"].as_array().unwrap()[0];
        assert_eq!(f["kind"], kind, "{fault}: {s}");
        assert!(
            f["message"].as_str().unwrap().contains(words),
            "{fault}: {s}"
        );
        assert_eq!(s["processed"], 0);
        assert!(
            entries(&dir.path().join("output"))
                .iter()
                .all(|n| !n.ends_with(".dcm")),
            "{fault}"
        );
        let kept = entries(&dir.path().join("spool/faulted")).len();
        assert_eq!(kept, usize::from(kind == "data"), "{fault}");
    }
}

/// Absurd or changing thickness readings (0 mm, 200 mm, a compression that
/// changes during the sweep) and an unreadable register (exception response,
/// silence: the client times out) are `thickness` faults, never reports.
#[test]
fn absurd_or_changing_thickness_is_a_fault() {
    for (extra, words) in [
        (vec!["--thickness-mm", "0"], "disagreement"),
        (vec!["--thickness-mm", "200"], "disagreement"),
        (
            vec!["--thickness-then-mm", "30"],
            "changed during the sweep",
        ),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let (acq, thickness) = acquire(dir.path());
        let (fp, mp) = (free_port(), free_port());
        let t = format!("{thickness:.1}");
        let mut args = vec!["modbus", "--listen"];
        let listen = format!("127.0.0.1:{mp}");
        args.push(&listen);
        if extra[0] != "--thickness-mm" {
            args.extend(["--thickness-mm", &t]);
        }
        args.extend(extra.iter().copied());
        let g = Gantry {
            modbus: Command::new(workspace_bin("host-sim"))
                .args(&args)
                .stderr(Stdio::null())
                .spawn()
                .unwrap(),
            stream: Command::new(workspace_bin("host-sim"))
                .args(["stream", "--acq"])
                .arg(&acq)
                .args(["--listen", &format!("127.0.0.1:{fp}")])
                .stderr(Stdio::null())
                .spawn()
                .unwrap(),
            frames: format!("127.0.0.1:{fp}"),
            registers: listen.clone(),
        };
        let cfg = config(dir.path(), &g, 2);
        assert_eq!(once(&cfg).code(), Some(1));
        let s = status(dir.path());
        let f = &s["faults"].as_array().unwrap()[0];
        assert_eq!(f["kind"], "thickness", "{extra:?}: {s}");
        assert!(
            f["message"].as_str().unwrap().contains(words),
            "{extra:?}: {s}"
        );
        assert_eq!(s["processed"], 0);
        assert_eq!(entries(&dir.path().join("spool/faulted")).len(), 1);
    }
}

/// Physically impossible data from a well-behaved link: an all-zero stream
/// (a dead detector) is refused before any report, naming the check; the
/// acquisition is kept in faulted/ for the service engineer (nothing received
/// is lost) and `--once` exits 1.
#[test]
fn an_all_zero_stream_is_refused_not_reported() {
    let dir = tempfile::tempdir().unwrap();
    let (acq, thickness) = acquire(dir.path());
    let g = gantry_with(&acq, thickness, &["zeros:1"]);
    let cfg = config(dir.path(), &g, 2);
    let st = once(&cfg);
    assert_eq!(st.code(), Some(1));
    let s = status(dir.path());
    let f = &s["faults"].as_array().unwrap()[0];
    assert_eq!(f["kind"], "implausible", "{s}");
    assert!(
        f["message"].as_str().unwrap().contains("are zero (dead)"),
        "{s}"
    );
    assert_eq!(s["fault_counts"]["implausible"], 1, "{s}");
    assert_eq!(s["processed"], 0);
    assert!(entries(&dir.path().join("output"))
        .iter()
        .all(|n| !n.ends_with(".dcm")));
    assert_eq!(entries(&dir.path().join("spool/faulted")).len(), 1);
}

/// `--check-config` checks what the daemon will need, not only the syntax:
/// a model folder that fails its sign-off, a spool that cannot be written,
/// a serial device that does not exist; each refused naming it (exit 2).
#[test]
fn check_config_checks_the_model_the_spool_and_the_devices() {
    let check = |cfg: &Path| {
        let out = Command::new(workspace_bin("dbtor-daemon"))
            .arg("--config")
            .arg(cfg)
            .arg("--check-config")
            .output()
            .unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stdout).to_string()
                + &String::from_utf8_lossy(&out.stderr),
        )
    };
    let dir = tempfile::tempdir().unwrap();
    // A copy of the shipped model: first as signed off, then tampered.
    let (model, digest, geometry, _) = shipped_model();
    let copy = dir.path().join("model");
    let cp = Command::new("cp")
        .arg("-r")
        .arg(&model)
        .arg(&copy)
        .status()
        .unwrap();
    assert!(cp.success());
    let recon = format!(
        "reconstructor = \"dbtor\"\nmodel = {:?}\nmodel_digest = {digest:?}",
        copy.display().to_string()
    );
    let frames =
        format!("transport = \"tcp\"\naddress = \"127.0.0.1:5000\"\ngeometry = \"{geometry}\"");
    let cfg = write_config(dir.path(), &frames, "transport = \"off\"", &recon);
    let (code, out) = check(&cfg);
    assert_eq!(code, Some(0), "{out}");
    assert!(
        out.contains("match the sign-off") && out.contains("writable"),
        "{out}"
    );
    // The calibration's slope changed.
    let cal = copy.join("glandularity-calibration.json");
    let text = std::fs::read_to_string(&cal).unwrap();
    std::fs::write(&cal, text.replacen("\"slope\": 1.", "\"slope\": 2.", 1)).unwrap();
    let (code, out) = check(&cfg);
    assert_eq!(code, Some(2), "{out}");
    assert!(
        out.contains("glandularity-calibration.json has SHA-256"),
        "{out}"
    );
    std::fs::write(&cal, text).unwrap();
    // A spool that is a file, not a folder.
    let _ = std::fs::remove_dir_all(dir.path().join("spool"));
    std::fs::write(dir.path().join("spool"), b"not a folder").unwrap();
    let (code, out) = check(&cfg);
    assert_eq!(code, Some(2), "{out}");
    assert!(
        out.contains("paths.spool") && out.contains("not a writable folder"),
        "{out}"
    );
    std::fs::remove_file(dir.path().join("spool")).unwrap();
    // A serial frame line that does not exist.
    let cfg = write_config(
        dir.path(),
        &format!(
            "transport = \"serial\"\nport = \"/dev/ttyDBTOR-NONE\"\ngeometry = \"{geometry}\""
        ),
        "transport = \"off\"",
        &recon,
    );
    let (code, out) = check(&cfg);
    assert_eq!(code, Some(2), "{out}");
    assert!(
        out.contains("frames.port = /dev/ttyDBTOR-NONE: no such device"),
        "{out}"
    );
}

/// A gantry frame server that stays unreachable is a `link` fault in the
/// status once the idle timeout has passed (it used to be retried forever,
/// logged at trace level only), and SIGTERM still stops the daemon.
#[test]
fn an_unreachable_gantry_is_a_fault_in_the_status() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port(); // nothing listens there
    let cfg = write_config(
        dir.path(),
        &format!("transport = \"tcp\"\naddress = \"127.0.0.1:{port}\""),
        "transport = \"off\"",
        "reconstructor = \"mltr\"\nmltr_iterations = 20",
    );
    let text = std::fs::read_to_string(&cfg)
        .unwrap()
        .replace("idle_timeout_s = 20", "idle_timeout_s = 1");
    std::fs::write(&cfg, text).unwrap();
    let mut d = daemon(&cfg, &[]);
    let t0 = Instant::now();
    let s = loop {
        let s = status(dir.path());
        if s["fault_counts"]["link"].as_u64().unwrap_or(0) > 0 {
            break s;
        }
        assert!(t0.elapsed() < Duration::from_secs(30), "no link fault: {s}");
        std::thread::sleep(Duration::from_millis(100));
    };
    let f = &s["faults"].as_array().unwrap()[0];
    assert!(
        f["message"]
            .as_str()
            .unwrap()
            .contains(&format!("127.0.0.1:{port} unreachable")),
        "{s}"
    );
    assert!(sigterm(&mut d).success());
}

/// A gantry streaming from another system than the configured one (issue
/// #28): refused at the stream's header, naming both systems; nothing is
/// spooled or reported, the gantry is never told the acquisition arrived
/// (host-sim exits 3: it keeps it), and the daemon goes on: the configured
/// system's cone-beam stream that follows is received, rebinned and
/// reported.
#[test]
fn a_stream_from_another_system_is_refused_and_the_next_one_reported() {
    let dir = tempfile::tempdir().unwrap();
    let fan = hil_tests::acquire_with(dir.path(), "fan", 1, "paper-tall", None);
    let cone = hil_tests::acquire_with(dir.path(), "cone", 1, "paper-tall", Some("paper-cone"));
    let thickness = thickness_of(&cone);
    let g = gantry(&fan, thickness);
    let cfg = write_config(
        dir.path(),
        &format!(
            "transport = \"tcp\"\naddress = \"{}\"\ngeometry = \"paper-tall\"\nsystem = \"paper-cone\"",
            g.frames
        ),
        &format!(
            "transport = \"tcp\"\naddress = \"{}\"\ntimeout_ms = 500\nattempts = 3\nthickness_tolerance_mm = 1.0",
            g.registers
        ),
        "reconstructor = \"mltr\"\nmltr_iterations = 3",
    );
    let mut d = Daemon(daemon(&cfg, &[]));
    let s = wait_for(dir.path(), "the refusal", Duration::from_secs(60), |s| {
        s["faults"].as_array().is_some_and(|f| !f.is_empty())
    });
    let f = &s["faults"][0];
    let m = f["message"].as_str().unwrap();
    assert_eq!(f["kind"], "link", "{s}");
    assert!(
        m.contains("slice-wise fan-beam stream")
            && m.contains("configured for cone-beam system `paper-cone`"),
        "{m}"
    );
    // The gantry was not told it arrived: it keeps the acquisition.
    let mut g = g;
    let t0 = Instant::now();
    let st = loop {
        if let Some(st) = g.stream.try_wait().unwrap() {
            break st;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "host-sim still streaming"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    assert_eq!(st.code(), Some(3), "host-sim: not delivered");
    for sub in ["incoming", "done", "faulted"] {
        assert!(
            entries(&dir.path().join("spool").join(sub)).is_empty(),
            "{sub}"
        );
    }
    // The configured system's stream, on the same address: reported.
    let frames_port = g.frames.clone();
    g.stream = Command::new(workspace_bin("host-sim"))
        .args(["stream", "--acq"])
        .arg(&cone)
        .args(["--listen", &frames_port])
        .stderr(Stdio::null())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    let s = wait_for(
        dir.path(),
        "the cone-beam report",
        Duration::from_secs(240),
        |s| s["processed"] == 1,
    );
    // One fault: the refused stream. (A loaded machine may take longer
    // than the idle timeout to start the second stream; the daemon then
    // also records the frame server as unreachable, which is not what this
    // test is about.)
    let faults: Vec<_> = s["faults"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| !f["message"].as_str().unwrap_or("").contains("unreachable"))
        .collect();
    assert_eq!(faults.len(), 1, "{s}");
    assert!(
        faults[0]["message"]
            .as_str()
            .unwrap()
            .contains("configured for cone-beam system"),
        "{s}"
    );
    let st = wait_exit(&mut g.stream, Duration::from_secs(60), "host-sim stream");
    assert_eq!(st.code(), Some(0), "host-sim: delivered");
    sigterm(&mut d.0);
    let done = entries(&dir.path().join("spool/done"));
    assert_eq!(done.len(), 1);
    let acq: serde_json::Value = serde_json::from_slice(
        &std::fs::read(
            dir.path()
                .join("spool/done")
                .join(&done[0])
                .join("acquisition.json"),
        )
        .unwrap(),
    )
    .unwrap();
    assert_eq!(
        acq["system"]["name"], "paper-cone",
        "the spool keeps the frames as sent"
    );
    assert_eq!(
        entries(&dir.path().join("output"))
            .iter()
            .filter(|n| n.ends_with(".dcm"))
            .count(),
        2
    );
}

/// A daemon killed when the test ends, whatever happens.
struct Daemon(Child);

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}
