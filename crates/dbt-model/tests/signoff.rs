//! The sign-off of a model folder against the tampering the firmware must
//! refuse: a changed calibration, a removed calibration, an added one, an
//! edited manifest, an edited sign-off, and a digest other than the
//! configured one; and the signed load's calibration rules.

use dbt_dbtor::{Engine, Precision};
use dbt_model::{
    load_signed, sign_off, verify, InputCorrections, ModelError, CALIBRATION_FILE, SIGNOFF_FILE,
};
use dbt_tissue::ClassifyOptions;
use std::path::{Path, PathBuf};

/// A copy of a committed model folder.
fn copy_model(name: &str) -> (tempfile::TempDir, PathBuf) {
    fn copy(src: &Path, dst: &Path) {
        std::fs::create_dir_all(dst).unwrap();
        for e in std::fs::read_dir(src).unwrap() {
            let e = e.unwrap();
            if e.path().is_dir() {
                copy(&e.path(), &dst.join(e.file_name()));
            } else if e.file_name() != SIGNOFF_FILE {
                std::fs::copy(e.path(), dst.join(e.file_name())).unwrap();
            }
        }
    }
    let src = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../models")
        .join(name);
    let tmp = tempfile::tempdir().unwrap();
    let dst = tmp.path().join(name);
    copy(&src, &dst);
    (tmp, dst)
}

fn integrity(e: ModelError) -> String {
    match e {
        ModelError::Integrity { reason, .. } => reason,
        other => panic!("expected an integrity error, got {other}"),
    }
}

#[test]
fn every_change_to_a_signed_off_folder_is_refused() {
    let (_t, dir) = copy_model("dbtor-x4t3");
    assert!(integrity(verify(&dir, None).unwrap_err()).contains("not been signed off"));
    let s = sign_off(&dir).unwrap();
    assert!(s.files.contains_key(CALIBRATION_FILE));
    assert!(s.files.contains_key("manifest.json"));
    assert!(s.files.keys().any(|f| f.starts_with("int8/")));
    assert_eq!(verify(&dir, Some(&s.digest)).unwrap(), s);

    // A calibration slope changed to 1.5.
    let cal = dir.join(CALIBRATION_FILE);
    let orig = std::fs::read_to_string(&cal).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&orig).unwrap();
    v["calibrations"]["fp32"]["slope"] = serde_json::json!(1.5);
    std::fs::write(&cal, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    let e = integrity(verify(&dir, Some(&s.digest)).unwrap_err());
    assert!(e.contains(CALIBRATION_FILE) && e.contains("changed"), "{e}");
    // Removed: the model was signed off calibrated.
    std::fs::remove_file(&cal).unwrap();
    let e = integrity(verify(&dir, Some(&s.digest)).unwrap_err());
    assert!(e.contains("missing") && e.contains("uncalibrated"), "{e}");
    std::fs::write(&cal, &orig).unwrap();
    verify(&dir, Some(&s.digest)).unwrap();

    // The manifest's geometry edited.
    let man = dir.join("manifest.json");
    let m = std::fs::read_to_string(&man).unwrap();
    std::fs::write(
        &man,
        m.replacen("\"pitch_mm\": 0.8", "\"pitch_mm\": 0.9", 1),
    )
    .unwrap();
    let e = integrity(verify(&dir, None).unwrap_err());
    assert!(e.contains("manifest.json"), "{e}");
    std::fs::write(&man, &m).unwrap();

    // One flipped byte in an ONNX file.
    let onnx = dir.join("int8/primal09.onnx");
    let mut b = std::fs::read(&onnx).unwrap();
    let mid = b.len() / 2;
    b[mid] ^= 1;
    std::fs::write(&onnx, &b).unwrap();
    assert!(integrity(verify(&dir, None).unwrap_err()).contains("int8/primal09.onnx"));
    b[mid] ^= 1;
    std::fs::write(&onnx, &b).unwrap();

    // The sign-off edited to match a tampered file: its digest no longer
    // matches its listing, and a re-signed folder is not the configured one.
    let sp = dir.join(SIGNOFF_FILE);
    let text = std::fs::read_to_string(&sp).unwrap();
    let mut sv: serde_json::Value = serde_json::from_str(&text).unwrap();
    sv["files"][CALIBRATION_FILE] = serde_json::json!("0".repeat(64));
    std::fs::write(&sp, serde_json::to_string(&sv).unwrap()).unwrap();
    assert!(integrity(verify(&dir, None).unwrap_err()).contains("edited"));
    std::fs::write(&cal, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    let resigned = sign_off(&dir).unwrap();
    assert_ne!(resigned.digest, s.digest);
    let e = integrity(verify(&dir, Some(&s.digest)).unwrap_err());
    assert!(e.contains("recon.model_digest"), "{e}");
}

#[test]
fn a_calibration_added_after_the_sign_off_is_refused() {
    let (_t, dir) = copy_model("dbtor-x4t3");
    let cal = dir.join(CALIBRATION_FILE);
    let text = std::fs::read(&cal).unwrap();
    std::fs::remove_file(&cal).unwrap();
    let s = sign_off(&dir).unwrap();
    assert!(!s.files.contains_key(CALIBRATION_FILE));
    std::fs::write(&cal, text).unwrap();
    let e = integrity(verify(&dir, Some(&s.digest)).unwrap_err());
    assert!(e.contains("not signed off"), "{e}");
}

#[test]
fn the_signed_load_requires_the_calibration_of_its_precision() {
    let (_t, dir) = copy_model("dbtor-x4t3");
    let s = sign_off(&dir).unwrap();
    let classify = ClassifyOptions::default();
    let m = load_signed(
        &dir,
        Precision::Fp32,
        &[],
        Engine::Fast,
        &classify,
        InputCorrections::default(),
        Some(&s.digest),
    )
    .unwrap();
    let c = m.calibration.expect("calibrated");
    assert!((c.slope - 1.0317085005586797).abs() < 1e-12);
    // A mixed-precision label the file has no fit for is an error, not an
    // uncalibrated report.
    let e = load_signed(
        &dir,
        Precision::Int8,
        &["primal09".to_string()],
        Engine::Fast,
        &classify,
        InputCorrections::default(),
        None,
    )
    .err()
    .expect("refused")
    .to_string();
    assert!(e.contains("no calibration for precision"), "{e}");
    // Another classification than the calibration's.
    let e = load_signed(
        &dir,
        Precision::Fp32,
        &[],
        Engine::Fast,
        &ClassifyOptions::paper(),
        InputCorrections::default(),
        None,
    )
    .err()
    .expect("refused")
    .to_string();
    assert!(e.contains("another tissue classification"), "{e}");
}

/// A network is fed only the counts it was trained on: one trained on a
/// detector's uncorrected clinical counts (its manifest's dataset
/// provenance) is refused with corrected or mono-energetic counts, and a
/// network trained on the mono-energetic scale is refused with uncorrected
/// clinical counts; each refusal names what the model was trained on and
/// what it would be fed.
#[test]
fn a_network_is_fed_only_the_counts_it_was_trained_on() {
    let (_t, dir) = copy_model("dbtor-x4t3");
    std::fs::remove_file(dir.join(CALIBRATION_FILE)).unwrap();
    let classify = ClassifyOptions::default();
    let raw = InputCorrections {
        uncorrected_clinical: true,
        ..Default::default()
    };
    let corrected = InputCorrections {
        scatter_removed: true,
        linearised: true,
        ..Default::default()
    };
    let load = |input: InputCorrections| {
        let s = sign_off(&dir).unwrap();
        load_signed(
            &dir,
            Precision::Fp32,
            &[],
            Engine::Fast,
            &classify,
            input,
            Some(&s.digest),
        )
    };
    // The shipped network, trained on mono-energetic counts.
    assert!(load(InputCorrections::default()).is_ok());
    assert!(load(corrected).is_ok());
    let e = load(raw).err().expect("refused").to_string();
    assert!(
        e.contains("trained on counts on the mono-energetic scale")
            && e.contains("uncorrected clinical counts"),
        "{e}"
    );
    // The same network as if trained on uncorrected clinical counts.
    let path = dir.join("manifest.json");
    let mut m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    m["provenance"]["dataset_provenance"]["corrections"] =
        serde_json::json!(dbt_dbtor::UNCORRECTED_CLINICAL_COUNTS);
    std::fs::write(&path, serde_json::to_string_pretty(&m).unwrap()).unwrap();
    assert!(load(raw).is_ok());
    for input in [InputCorrections::default(), corrected] {
        let e = load(input).err().expect("refused");
        assert!(matches!(e, ModelError::Input { .. }), "{e}");
        let e = e.to_string();
        assert!(
            e.contains("trained on a detector's uncorrected clinical counts")
                && e.contains(&format!("corrections: {}", input.describe())),
            "{e}"
        );
    }
}
