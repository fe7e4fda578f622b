//! The Storage SCP of the DICOM input (issue #31, network side), with real
//! peers: dcmtk's `echoscu` and `storescu`, and `host-sim dicom-send`. A
//! usable For Processing object is handed over and answered Success; an
//! object of an accepted class that is not usable (here an SR, accepted for
//! the test) is answered with failure
//! C000 and an Error Comment naming why; a wrong called AE title is
//! refused at association.

use dbt_pacs::scp::{serve_association, AssociationReport, Verdict, STATUS_CANNOT_UNDERSTAND};
use hil_tests::{free_port, workspace_bin};
use std::net::TcpListener;
use std::process::Command;
use std::sync::mpsc;
use std::time::Duration;

/// An SCP on a free port serving `n` associations, then returning their
/// reports; objects that read as projections are kept in the channel.
fn scp(
    n: usize,
) -> (
    u16,
    std::thread::JoinHandle<Vec<AssociationReport>>,
    mpsc::Receiver<Vec<u8>>,
) {
    let port = free_port();
    let listener = TcpListener::bind(("127.0.0.1", port)).unwrap();
    let (tx, rx) = mpsc::channel();
    let h = std::thread::spawn(move || {
        let mut reports = Vec::new();
        for stream in listener.incoming().take(n) {
            let tx = tx.clone();
            let r = serve_association(
                stream.unwrap(),
                "DBTOR",
                &[
                    dbt_dicom::projections::BPXR_FOR_PROCESSING_CLASS,
                    "1.2.840.10008.5.1.4.1.1.88.33",
                ],
                Duration::from_secs(20),
                &mut |_, _, received| {
                    let bytes = match received {
                        Ok(b) => b,
                        Err(u) => return Verdict::Refused(STATUS_CANNOT_UNDERSTAND, u.reason),
                    };
                    match dbt_dicom::projections::read_projection_object(&bytes) {
                        Ok(_) => {
                            tx.send(bytes).unwrap();
                            Verdict::Stored
                        }
                        Err(e) => Verdict::Refused(STATUS_CANNOT_UNDERSTAND, e.to_string()),
                    }
                },
            );
            reports.push(r);
        }
        reports
    });
    (port, h, rx)
}

#[test]
fn echo_store_and_refusal_with_dcmtk_and_host_sim() {
    let dir = tempfile::tempdir().unwrap();
    let acq = hil_tests::acquire(dir.path(), 4);
    let file = dir.path().join("p.dcm");
    let sr = dir.path().join("sr.dcm");
    let (port, server, rx) = scp(5);
    let p = port.to_string();
    // 1. C-ECHO.
    let st = Command::new("echoscu")
        .args(["-aec", "DBTOR", "-aet", "MODALITY", "127.0.0.1", &p])
        .output()
        .expect("echoscu (dcmtk)");
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    // 2. host-sim dicom-send, our SCU.
    let out = Command::new(workspace_bin("host-sim"))
        .args(["dicom-send", "--acq"])
        .arg(&acq)
        .arg("--out")
        .arg(&file)
        .args(["--to", &format!("DBTOR@127.0.0.1:{port}")])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // 3. storescu with the same file.
    let st = hil_tests::storescu("DBTOR", "MODALITY", port, &file);
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    // 4. An SR is not projections: refused with C000 and the reason.
    let mut uids = dbt_dicom::UidSource::new("1.2.826.0.1.3680043.10.543", 5).unwrap();
    let d = dbt_dicom::density_report(
        &dbt_dicom::DensityInput {
            header: dbt_dicom::Header {
                patient_name: "Doe^Jane".into(),
                patient_id: "P1".into(),
                patient_birth_date: "".into(),
                patient_sex: "F".into(),
                study_uid: "1.2.826.0.1.3680043.10.543.88".into(),
                study_date: "20261124".into(),
                study_time: "101500".into(),
                study_id: "1".into(),
                accession_number: "".into(),
                referring_physician: "".into(),
                laterality: dbt_dicom::Laterality::Left,
                source_series_uid: "1.2.826.0.1.3680043.10.543.88.1".into(),
                source_instance_uids: vec![],
                source_class: dbt_dicom::projections::BPXR_FOR_PROCESSING_CLASS.into(),
            },
            equipment: dbt_dicom::Equipment {
                manufacturer: "x".into(),
                model: "x".into(),
                serial: "x".into(),
                software_version: "0".into(),
                device_uid: "1.2.826.0.1.3680043.10.543.88.9".into(),
            },
            glandularity: 0.2,
            fibroglandular_cm3: 100.0,
            breast_cm3: 600.0,
            reconstructor: "x".into(),
            model_version: "x".into(),
            check: dbt_dicom::DensityCheckReport {
                physics_glandularity: Some(0.25),
                confirmed: true,
                reasons: vec![],
            },
            method: dbt_dicom::ReportMethod::Reconstruction,
            glandularity_interval: dbt_dicom::FigureInterval {
                limits: None,
                basis: "no validation residuals for MLTR".into(),
            },
            content_date: "20261124".into(),
            content_time: "101500".into(),
        },
        &mut uids,
    )
    .unwrap();
    std::fs::write(&sr, d.to_bytes().unwrap()).unwrap();
    let st = hil_tests::storescu("DBTOR", "MODALITY", port, &sr);
    // storescu exits non-zero on a failure status (its status text is
    // below; the SCP's account is checked at the end).
    assert!(!st.status.success(), "storescu reported success for an SR");
    // 5. A wrong called AE title is refused at association.
    let st = Command::new("echoscu")
        .args(["-aec", "SOMEONE", "-aet", "MODALITY", "127.0.0.1", &p])
        .output()
        .unwrap();
    assert!(!st.status.success(), "a wrong called AE title was accepted");

    let reports = server.join().unwrap();
    assert_eq!(reports[0].echoes, 1);
    assert_eq!(reports[0].calling_ae_title, "MODALITY");
    assert_eq!(reports[1].stores.len(), 1);
    assert_eq!(reports[1].stores[0].1, Verdict::Stored, "{:?}", reports[1]);
    assert_eq!(reports[2].stores[0].1, Verdict::Stored, "{:?}", reports[2]);
    match &reports[3].stores[0].1 {
        Verdict::Refused(s, why) => {
            assert_eq!(*s, STATUS_CANNOT_UNDERSTAND);
            assert!(why.contains("is not one the input reads"), "{why}");
        }
        v => panic!("the SR was {v:?}"),
    }
    assert!(
        reports[4]
            .error
            .as_deref()
            .is_some_and(|e| e.contains("refused")),
        "{:?}",
        reports[4]
    );
    let kept: Vec<Vec<u8>> = rx.try_iter().collect();
    assert_eq!(kept.len(), 2);
    let a = dbt_dicom::projections::read_projection_object(&kept[0]).unwrap();
    let written =
        dbt_dicom::projections::read_projection_object(&std::fs::read(&file).unwrap()).unwrap();
    assert_eq!(a.counts, written.counts, "the counts arrive intact");
    assert_eq!(a.angles_deg, written.angles_deg);
}
