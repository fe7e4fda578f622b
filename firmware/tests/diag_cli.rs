//! dbtor-diag's command line: a service engineer's typo is refused (exit 2,
//! naming the option) instead of being ignored and a default used.

use std::process::Command;

fn diag(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_dbtor-diag"))
        .args(args)
        .output()
        .expect("dbtor-diag runs");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn a_mistyped_option_is_refused_and_named() {
    let (code, _, err) = diag(&["model", "models/dbtor-x4", "--precison", "int8"]);
    assert_eq!(code, 2);
    assert!(err.contains("--precison"), "{err}");
    let (code, _, err) = diag(&["model", "models/dbtor-x4", "--precision", "fp16"]);
    assert_eq!(code, 2);
    assert!(err.contains("fp16"), "{err}");
}

#[test]
fn options_that_need_another_are_refused_without_it() {
    // --precision only means something with --model (MLTR otherwise).
    let (code, _, err) = diag(&["replay", "/nonexistent", "--precision", "int8"]);
    assert_eq!(code, 2);
    assert!(err.contains("--model"), "{err}");
    // Modbus needs exactly one of HOST:PORT and --rtu.
    let (code, _, _) = diag(&["modbus"]);
    assert_eq!(code, 2);
    let (code, _, err) = diag(&["modbus", "127.0.0.1:502", "--rtu", "/dev/ttyS0"]);
    assert_eq!(code, 2);
    assert!(err.contains("--rtu"), "{err}");
}

#[test]
fn geometry_prints_the_binned_geometry_and_bad_input_exits_2() {
    let (code, out, _) = diag(&["geometry", "--binning", "4"]);
    assert_eq!(code, 0);
    assert!(out.contains("[views]"), "{out}");
    let (code, _, err) = diag(&["geometry", "--binning", "four"]);
    assert_eq!(code, 2);
    assert!(err.contains("four"), "{err}");
    // A missing file is an input error (2), named.
    let (code, _, err) = diag(&["report", "/nonexistent/x.dcm"]);
    assert_eq!(code, 2);
    assert!(err.contains("/nonexistent/x.dcm"), "{err}");
}

/// `dbtor-diag report` on a report whose one element length was corrupted
/// (0xFFFFFFF0): refused naming the element, without allocating what the
/// length claims (the read-back is bounded by the file's size).
#[test]
fn a_corrupted_dicom_length_is_refused_not_allocated() {
    use dbt_dicom::*;
    let header = Header {
        patient_name: "Doe^Jane".into(),
        patient_id: "P-0001".into(),
        patient_birth_date: "".into(),
        patient_sex: "F".into(),
        study_uid: "1.2.826.0.1.3680043.10.543.77.1".into(),
        study_date: "20261122".into(),
        study_time: "101500".into(),
        study_id: "S1".into(),
        accession_number: "A1".into(),
        referring_physician: "".into(),
        laterality: Laterality::Left,
        source_series_uid: "1.2.826.0.1.3680043.10.543.77.2".into(),
        source_instance_uids: vec![],
        source_class: dbt_dicom::projections::BPXR_FOR_PROCESSING_CLASS.into(),
    };
    let equipment = Equipment {
        manufacturer: "DBToR".into(),
        model: "DBToR gantry PC".into(),
        serial: "SN-1".into(),
        software_version: "0.1.0".into(),
        device_uid: "1.2.826.0.1.3680043.10.543.77.9".into(),
    };
    let r = density_report(
        &DensityInput {
            header,
            equipment,
            glandularity: 0.2,
            fibroglandular_cm3: 100.0,
            breast_cm3: 500.0,
            reconstructor: "MLTR 100 iterations".into(),
            model_version: "none".into(),
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
            content_time: "120000".into(),
        },
        &mut UidSource::new("1.2.3", 1).unwrap(),
    )
    .unwrap();
    let bytes = r.to_bytes().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.dcm");
    std::fs::write(&good, &bytes).unwrap();
    let (code, out, err) = diag(&["report", good.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("Percent"), "{out}");
    // The Content Sequence (0040,A730), an SQ with a 32-bit length.
    let at = bytes
        .windows(6)
        .position(|w| w == [0x40, 0x00, 0x30, 0xA7, b'S', b'Q'])
        .unwrap();
    let mut bad = bytes.clone();
    bad[at + 8..at + 12].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
    let badp = dir.path().join("bad.dcm");
    std::fs::write(&badp, &bad).unwrap();
    let (code, _, err) = diag(&["report", badp.to_str().unwrap()]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("(0040,A730) declares 4294967280 bytes"),
        "{err}"
    );
}

/// Every firmware binary answers `--help` (exit 0, its usage) and refuses an
/// unknown option (exit 2, naming it); they used to parse their arguments by
/// hand and took `--help` for an unknown option.
#[test]
fn every_binary_has_help_and_refuses_unknown_options() {
    for exe in [
        env!("CARGO_BIN_EXE_dbtor-diag"),
        env!("CARGO_BIN_EXE_dbtor-daemon"),
        env!("CARGO_BIN_EXE_dbtor-process"),
        env!("CARGO_BIN_EXE_dbtor-receive"),
    ] {
        let out = Command::new(exe).arg("--help").output().unwrap();
        let text = String::from_utf8_lossy(&out.stdout);
        assert_eq!(out.status.code(), Some(0), "{exe}: {text}");
        assert!(text.contains("Usage:"), "{exe}: {text}");
        let out = Command::new(exe).arg("--frobnicate").output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{exe}: {err}");
        assert!(err.contains("--frobnicate"), "{exe}: {err}");
    }
}
