//! A DBT sweep from each vendor's gantry through the running daemon's DICOM
//! input (issue #51 points 3 and 4, the standard layout): test phantom 1
//! acquired on Hologic's, GE's and Siemens's built-in system, sent by
//! `host-sim dicom-send --per-view` as one Digital Mammography X-Ray For
//! Processing object per view (each with its Positioner Primary Angle, as
//! systems without the multi-frame Breast Projection object send them), to
//! a DICOM-only daemon configured with that system and no model
//! (`reconstructor = "physics"`): every sweep is grouped, placed by angle on
//! the system, reported by the physics density within 4 pp of the truth,
//! and both SRs are written, the dose SR with an irradiation event for each
//! of the system's views (15, 9 and 25; that the dose is simulated on the
//! system's own geometry: host-sim/tests/vendor_gantries.rs). The vendors'
//! private layouts (GE's angle tags, Hologic's container) are not here.

use hil_tests::{free_port, wait_for_status, workspace_bin};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

/// Kills the daemon however the test ends.
struct Daemon(std::process::Child);

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn report_on(system: &str, views: usize, dir: &Path) {
    let acq = hil_tests::acquire_with(dir, "acq", 1, "paper-tall", Some(system));
    let h: serde_json::Value =
        serde_json::from_slice(&std::fs::read(acq.join("acquisition.json")).unwrap()).unwrap();
    let truth = h["truth"]["glandularity"].as_f64().unwrap();
    let dport = free_port();
    let cfg = dir.join("dbtor.toml");
    std::fs::write(
        &cfg,
        format!(
            r#"
[frames]
transport = "off"
geometry = "paper-tall"
binning = 4
system = "{system}"

[modbus]
transport = "off"

[recon]
reconstructor = "physics"
dose_uncertainty = 0.05

[paths]
spool = "spool"
output = "output"
status = "run/status.json"

[report]
uid_root = "1.2.826.0.1.3680043.10.543.1"
tube_output_mgy_per_mas = {tube}

[status_page]
address = "off"

[dicom_input]
address = "127.0.0.1:{dport}"
ae_title = "DBTOR"
flat_field_counts = {flux}
"#,
            tube = h["tube_output_mgy_per_mas"],
            flux = h["flux"],
        ),
    )
    .unwrap();
    let daemon = Daemon(
        Command::new(workspace_bin("dbtor-daemon"))
            .arg("--config")
            .arg(&cfg)
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let limit = Duration::from_secs(240);
    wait_for_status(dir, "the daemon", limit, |s| s["state"] == "waiting");
    let out = Command::new(workspace_bin("host-sim"))
        .args(["dicom-send", "--per-view", "--acq"])
        .arg(&acq)
        .args(["--to", &format!("DBTOR@127.0.0.1:{dport}")])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{system}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let s = wait_for_status(dir, "the report", limit, |s| {
        s["processed"] == 1 || !s["faults"].as_array().is_none_or(|f| f.is_empty())
    });
    drop(daemon);
    assert_eq!(s["processed"], 1, "{system}: {s}");
    assert!(s["faults"].as_array().unwrap().is_empty(), "{system}: {s}");
    let g = s["recent"][0]["glandularity_reported"].as_f64().unwrap();
    assert!(
        (g - truth).abs() < 0.04,
        "{system}: reported {g}, truth {truth}"
    );
    let done = dir.join("spool/done");
    let entry = std::fs::read_dir(&done)
        .unwrap()
        .flatten()
        .next()
        .unwrap()
        .path();
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(entry.join("result.json")).unwrap()).unwrap();
    assert!(
        r["reconstructor"]
            .as_str()
            .unwrap()
            .contains("physics-based density"),
        "{system}: {r}"
    );
    let reports: Vec<std::path::PathBuf> = std::fs::read_dir(dir.join("output"))
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.to_string_lossy().ends_with(".dcm"))
        .collect();
    assert_eq!(reports.len(), 2, "{system}");
    // One irradiation event (its Irradiation Event UID, code 113769) per
    // view of the system's sweep.
    let dose = reports
        .iter()
        .find(|p| p.to_string_lossy().ends_with("dose-sr.dcm"))
        .unwrap();
    let bytes = std::fs::read(dose).unwrap();
    let events = bytes.windows(6).filter(|w| w == b"113769").count();
    assert_eq!(events, views, "{system}");
}

#[test]
fn each_vendors_per_view_sweep_is_reported_through_the_dicom_input() {
    for (system, views) in [
        ("hologic-dimensions", 15),
        ("ge-essential", 9),
        ("siemens-inspiration", 25),
    ] {
        let dir = tempfile::tempdir().unwrap();
        report_on(system, views, dir.path());
    }
}
