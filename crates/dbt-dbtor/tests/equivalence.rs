//! The Rust runtime (tract-onnx blocks + the Rust projector) against the
//! PyTorch reference stored with the shipped model (`models/dbtor-x4/fixtures`,
//! written by `training/dbtor/export.py`), and the refusal of tampered or
//! incomplete model folders.

use dbt_dbtor::{check_fixtures, Dbtor, DbtorError, ModelManifest, Precision};
use std::path::{Path, PathBuf};

fn model_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/dbtor-x4")
}

fn check(p: Precision) {
    let dir = model_dir();
    let m = Dbtor::load(&dir, p).unwrap();
    let checks = check_fixtures(&m, &dir).unwrap();
    assert!(!checks.is_empty(), "the model has no fixtures");
    for c in &checks {
        eprintln!(
            "{} {}: {} -> {}",
            c.name,
            c.precision,
            c.rule,
            if c.pass { "pass" } else { "FAIL" }
        );
        assert!(c.pass, "{c:?}");
    }
}

/// fp32: tract + Rust projector against PyTorch (tolerance in `fixtures.rs`).
#[test]
fn fp32_matches_pytorch() {
    check(Precision::Fp32);
}

/// int8: tract against onnxruntime on the same QDQ files.
#[test]
fn int8_matches_onnxruntime() {
    check(Precision::Int8);
}

fn copy_model(to: &Path) {
    let from = model_dir();
    let m = ModelManifest::load(&from).unwrap();
    std::fs::copy(from.join("manifest.json"), to.join("manifest.json")).unwrap();
    for rel in m.sha256.keys() {
        let dst = to.join(rel);
        std::fs::create_dir_all(dst.parent().unwrap()).unwrap();
        std::fs::copy(from.join(rel), dst).unwrap();
    }
}

#[test]
fn tampered_block_is_refused() {
    let t = tempfile::tempdir().unwrap();
    copy_model(t.path());
    let victim = t.path().join("int8/primal03.onnx");
    let mut bytes = std::fs::read(&victim).unwrap();
    let k = bytes.len() / 2;
    bytes[k] ^= 0x01;
    std::fs::write(&victim, bytes).unwrap();
    for p in [Precision::Fp32, Precision::Int8] {
        match Dbtor::load(t.path(), p) {
            Err(DbtorError::Checksum { path, .. }) => assert!(path.ends_with("int8/primal03.onnx")),
            other => panic!("expected a checksum error, got {other:?}"),
        }
    }
}

#[test]
fn missing_block_is_refused() {
    let t = tempfile::tempdir().unwrap();
    copy_model(t.path());
    std::fs::remove_file(t.path().join("fp32/dual07.onnx")).unwrap();
    let e = Dbtor::load(t.path(), Precision::Fp32).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("fp32/dual07.onnx") && msg.contains("missing"),
        "{msg}"
    );
}

#[test]
fn edited_manifest_is_refused() {
    let t = tempfile::tempdir().unwrap();
    copy_model(t.path());
    let p = t.path().join("manifest.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    v["blocks"].as_array_mut().unwrap().swap(0, 2);
    std::fs::write(&p, serde_json::to_string(&v).unwrap()).unwrap();
    let msg = Dbtor::load(t.path(), Precision::Fp32)
        .unwrap_err()
        .to_string();
    assert!(msg.contains("blocks[0]"), "{msg}");
    std::fs::write(&p, "{ not json").unwrap();
    let msg = Dbtor::load(t.path(), Precision::Fp32)
        .unwrap_err()
        .to_string();
    assert!(msg.contains("manifest.json"), "{msg}");
}

#[test]
fn bad_input_is_refused() {
    let m = Dbtor::load(&model_dir(), Precision::Fp32).unwrap();
    let n = m.geometry().n_rays();
    assert!(m.reconstruct(&vec![0.0; n - 1], 50.0).is_err());
    let mut g = vec![0.0; n];
    g[17] = f32::NAN;
    let msg = m.reconstruct(&g, 50.0).unwrap_err().to_string();
    assert!(msg.contains("sample 17"), "{msg}");
    assert!(m.reconstruct(&vec![0.0; n], 0.0).is_err());
}
