//! The daemon with both inputs (issue #31): the same simulated acquisition,
//! cone-beam on the shipped system (`paper-cone`, issue #28: the detector's
//! 2-D frames), arrives once over the frame link (host-sim stream) and once over DICOM
//! (host-sim dicom-send, a For Processing object, C-STORE), then once more
//! from dcmtk's storescu; all are reported with the same glandularity (MGD
//! within the Monte Carlo uncertainty) and their SRs reach Orthanc. An object from another
//! gantry (other detector) is refused with a named reason, kept in
//! `faulted/`, recorded as an `input` fault, and the daemon keeps serving.

use hil_tests::{free_port, http_get, wait_exit, wait_for_status, workspace_bin, Orthanc};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

fn results(dir: &Path) -> Vec<serde_json::Value> {
    let done = dir.join("spool/done");
    let mut ids: Vec<_> = std::fs::read_dir(&done)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .collect();
    ids.sort();
    ids.iter()
        .map(|p| serde_json::from_slice(&std::fs::read(p.join("result.json")).unwrap()).unwrap())
        .collect()
}

/// `host-sim dicom-send` of `acq` to the daemon's input on `port`.
fn dicom_send(acq: &Path, port: u16) -> std::process::Output {
    Command::new(workspace_bin("host-sim"))
        .args(["dicom-send", "--acq"])
        .arg(acq)
        .args(["--to", &format!("DBTOR@127.0.0.1:{port}")])
        .output()
        .unwrap()
}

#[test]
fn both_inputs_report_the_same_acquisition_alike() {
    let dir = tempfile::tempdir().unwrap();
    let acq = hil_tests::acquire_with(dir.path(), "acq", 2, "paper-tall", Some("paper-cone"));
    let h: serde_json::Value =
        serde_json::from_slice(&std::fs::read(acq.join("acquisition.json")).unwrap()).unwrap();
    let flux = h["flux"].as_f64().unwrap();
    let (frames, dport) = (format!("127.0.0.1:{}", free_port()), free_port());
    // The reports go on to Orthanc, the site's PACS.
    let (pacs, pacs_http) = (free_port(), free_port());
    let orthanc_dir = dir.path().join("orthanc");
    std::fs::create_dir_all(&orthanc_dir).unwrap();
    let orthanc = Orthanc::start(&orthanc_dir, pacs, pacs_http);
    let cfg = dir.path().join("dbtor.toml");
    std::fs::write(
        &cfg,
        format!(
            r#"
[frames]
transport = "tcp"
address = "{frames}"
idle_timeout_s = 20
geometry = "paper-tall"
binning = 4
system = "paper-cone"

[modbus]
transport = "off"

[recon]
reconstructor = "mltr"
mltr_iterations = 20
dose_uncertainty = 0.05

[paths]
spool = "spool"
output = "output"
status = "run/status.json"

[report]
uid_root = "1.2.826.0.1.3680043.10.543.1"
pacs = "ORTHANC@127.0.0.1:{pacs}"
tube_output_mgy_per_mas = {tube}

[status_page]
address = "off"

[dicom_input]
address = "127.0.0.1:{dport}"
ae_title = "DBTOR"
flat_field_counts = {flux}
"#,
            tube = h["tube_output_mgy_per_mas"],
        ),
    )
    .unwrap();
    let mut daemon = Command::new(workspace_bin("dbtor-daemon"))
        .arg("--config")
        .arg(&cfg)
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let limit = Duration::from_secs(240);
    wait_for_status(dir.path(), "the daemon", limit, |s| s["state"] == "waiting");
    // 1. The frame link.
    let mut stream = Command::new(workspace_bin("host-sim"))
        .args(["stream", "--acq"])
        .arg(&acq)
        .args(["--listen", &frames])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    wait_for_status(dir.path(), "the frame-link report", limit, |s| {
        s["processed"] == 1
    });
    wait_exit(&mut stream, Duration::from_secs(60), "host-sim stream");
    // 2. DICOM.
    let out = dicom_send(&acq, dport);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    wait_for_status(dir.path(), "the DICOM report", limit, |s| {
        s["processed"] == 2
    });
    let r = results(dir.path());
    assert_eq!(r.len(), 2);
    assert_eq!(
        r[0]["glandularity_reported"], r[1]["glandularity_reported"],
        "same counts, same glandularity: {r:?}"
    );
    let (a, b) = (
        r[0]["mgd_mgy"].as_f64().unwrap(),
        r[1]["mgd_mgy"].as_f64().unwrap(),
    );
    // Within 3 standard deviations of the difference of two 5 % runs.
    assert!((a - b).abs() <= 3.0 * 0.05 * 2f64.sqrt() * a, "{a} vs {b}");
    let reports = std::fs::read_dir(dir.path().join("output"))
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().ends_with(".dcm"))
        .count();
    assert_eq!(reports, 4, "two SRs per acquisition");

    // 3. An object from another detector (binned x2): refused, named, kept.
    let other = dir.path().join("other");
    let st = Command::new(workspace_bin("host-sim"))
        .args([
            "acquire",
            "--index",
            "2",
            "--binning",
            "2",
            "--noise",
            "N8",
            "--out",
        ])
        .arg(&other)
        .output()
        .unwrap();
    assert!(st.status.success());
    let out = dicom_send(&other, dport);
    assert!(
        !out.status.success(),
        "the SCP accepted another detector's object"
    );
    let s = wait_for_status(dir.path(), "the input fault", limit, |s| {
        s["fault_counts"]["input"].as_u64() == Some(1)
    });
    let f = s["faults"].as_array().unwrap().last().unwrap().clone();
    assert!(f["message"].as_str().unwrap().contains("Columns"), "{f}");
    let faulted: Vec<_> = std::fs::read_dir(dir.path().join("spool/faulted"))
        .unwrap()
        .flatten()
        .collect();
    assert_eq!(faulted.len(), 1);
    assert!(faulted[0].path().join("object.dcm").is_file());

    // 4. Still serving, and dcmtk's storescu is a modality too: the first
    // acquisition written as an object (a new SOP instance) and sent by it.
    let file = dir.path().join("again.dcm");
    let out = Command::new(workspace_bin("host-sim"))
        .args(["dicom-send", "--acq"])
        .arg(&acq)
        .arg("--out")
        .arg(&file)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let st = hil_tests::storescu("DBTOR", "MODALITY", dport, &file);
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    wait_for_status(dir.path(), "a report after the fault", limit, |s| {
        s["processed"] == 3
    });
    let r = results(dir.path());
    assert_eq!(r[2]["glandularity_reported"], r[0]["glandularity_reported"]);
    // The same object again (a modality resending after a lost response):
    // Success, and no second acquisition.
    let st = hil_tests::storescu("DBTOR", "MODALITY", dport, &file);
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    std::thread::sleep(Duration::from_secs(2));
    let s = hil_tests::daemon_status(dir.path());
    assert_eq!(s["processed"], 3, "a duplicate made a new acquisition: {s}");
    assert_eq!(s["incoming"], 0, "{s}");
    // Every report reached the PACS: two SRs per acquisition.
    let t0 = std::time::Instant::now();
    let stored = loop {
        let v: Vec<String> =
            serde_json::from_slice(&http_get(pacs_http, "/instances").unwrap()).unwrap();
        if v.len() >= 6 || t0.elapsed() > Duration::from_secs(30) {
            break v;
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    assert_eq!(stored.len(), 6, "{stored:?}");
    assert!(Command::new("kill")
        .args(["-TERM", &daemon.id().to_string()])
        .status()
        .unwrap()
        .success());
    wait_exit(
        &mut daemon,
        Duration::from_secs(60),
        "the daemon after SIGTERM",
    );
    orthanc.stop();
}
