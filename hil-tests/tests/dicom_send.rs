//! A simulated acquisition as a modality sends it (issue #31 item 2):
//! `host-sim dicom-send` writes it as a Breast Projection X-Ray Image - For
//! Processing object, checks it with dciodvfy and sends it by C-STORE to
//! Orthanc; dcmtk's `storescu` sends the same file too. Orthanc stores both
//! with the For Processing SOP class, one frame per view, the counts intact.
//! (The daemon's DICOM input that will receive them is issue #31 item 1.)

use hil_tests::{free_port, http_get, workspace_bin, Orthanc};
use std::process::Command;

fn instances(port: u16) -> Vec<String> {
    let body = http_get(port, "/instances").expect("GET /instances");
    serde_json::from_slice(&body).unwrap()
}

#[test]
fn dicom_send_and_storescu_deliver_a_valid_projection_object() {
    let dir = tempfile::tempdir().unwrap();
    let acq = hil_tests::acquire(dir.path(), 3);
    let (dicom, http) = (free_port(), free_port());
    let orthanc = Orthanc::start(dir.path(), dicom, http);
    let file = dir.path().join("projections.dcm");
    let out = Command::new(workspace_bin("host-sim"))
        .args(["dicom-send", "--acq"])
        .arg(&acq)
        .arg("--out")
        .arg(&file)
        .args(["--to", &format!("ORTHANC@127.0.0.1:{dicom}")])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("dciodvfy: no error") && text.contains("sent to"),
        "{text}"
    );
    let ids = instances(http);
    assert_eq!(ids.len(), 1, "{ids:?}");
    let tags: serde_json::Value = serde_json::from_slice(
        &http_get(http, &format!("/instances/{}/simplified-tags", ids[0])).unwrap(),
    )
    .unwrap();
    assert_eq!(
        tags["SOPClassUID"], "1.2.840.10008.5.1.4.1.1.13.1.5",
        "{tags}"
    );
    assert_eq!(tags["NumberOfFrames"], "25", "{tags}");
    assert_eq!(tags["PresentationIntentType"], "FOR PROCESSING", "{tags}");
    // The stored file is the one written: same bytes of pixel data.
    let stored = http_get(http, &format!("/instances/{}/file", ids[0])).unwrap();
    let written = std::fs::read(&file).unwrap();
    let tail = |b: &[u8]| b[b.len() - 4096..].to_vec();
    assert_eq!(
        tail(&stored),
        tail(&written),
        "pixel data changed on the way"
    );

    // dcmtk's storescu sends the same file (a new instance: Orthanc keeps
    // one copy of an SOP instance, so the count stays 1).
    let st = hil_tests::storescu("ORTHANC", "STORESCU", dicom, &file);
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    assert_eq!(instances(http).len(), 1);
    orthanc.stop();
}
