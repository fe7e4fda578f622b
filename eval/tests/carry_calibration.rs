//! `dbt-eval calibrate --carry-from OLD`: a folder whose blocks of a
//! precision are OLD's files takes OLD's calibrations of that precision
//! (every input's), bound to its own manifest; a folder whose blocks differ
//! is refused, naming the block.

use std::path::{Path, PathBuf};
use std::process::Command;

fn shipped() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/dbtor-x4t3")
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dst = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &dst);
        } else {
            std::fs::copy(e.path(), dst).unwrap();
        }
    }
}

/// A copy of the shipped folder whose first block's `kind` file is the
/// second block's (same shapes, another file).
fn with_first_block_swapped(kind: &str) -> tempfile::TempDir {
    let t = tempfile::tempdir().unwrap();
    copy_dir(&shipped(), t.path());
    let path = t.path().join("manifest.json");
    let mut m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let second = m["blocks"][2][kind].clone();
    m["blocks"][0][kind] = second;
    std::fs::write(&path, serde_json::to_string_pretty(&m).unwrap()).unwrap();
    t
}

fn carry(model: &Path, precision: &str) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_dbt-eval"))
        .args(["calibrate", "--model"])
        .arg(model)
        .args(["--precision", precision, "--carry-from"])
        .arg(shipped())
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap()
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn calibrations_carry_only_between_the_same_blocks() {
    // int8 blocks differ: the fp32 calibrations carry, the int8 ones do not.
    let t = with_first_block_swapped("int8");
    let out = carry(t.path(), "fp32");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let old = json(&shipped().join("glandularity-calibration.json"));
    let new = json(&t.path().join("glandularity-calibration.json"));
    let sha = dbt_dbtor::sha256_file(&t.path().join("manifest.json")).unwrap();
    assert_eq!(new["manifest_sha256"], serde_json::Value::String(sha));
    assert_ne!(new["manifest_sha256"], old["manifest_sha256"]);
    let keys: Vec<&String> = new["calibrations"].as_object().unwrap().keys().collect();
    assert_eq!(keys, ["fp32", "fp32 | scatter removed + linearised"]);
    for k in keys {
        assert_eq!(new["calibrations"][k], old["calibrations"][k], "{k}");
        assert_eq!(
            new["fits"][k]["carried_from"]["model"], old["model"],
            "{k}: the fit does not name its source"
        );
    }
    let out = carry(t.path(), "int8");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("int8 block int8/dual01.onnx") && err.contains("is not int8/dual00.onnx"),
        "{err}"
    );
    // fp32 blocks differ: refused too.
    let t = with_first_block_swapped("fp32");
    let out = carry(t.path(), "fp32");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("fp32 block fp32/dual01.onnx"), "{err}");
    // and the folder's calibration file (the shipped one, copied) is untouched
    assert_eq!(
        json(&t.path().join("glandularity-calibration.json")),
        json(&shipped().join("glandularity-calibration.json"))
    );
}
