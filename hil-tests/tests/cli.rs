//! Every binary of the workspace is a conventional command line (clap):
//! `--help` prints its usage and exits 0, and a misspelt option is refused
//! with exit status 2, naming it. The binaries are listed from `cargo
//! metadata`, so a new one is tested without being named here.

use std::path::PathBuf;
use std::process::Command;

/// (package, binary) of every workspace binary.
fn binaries() -> Vec<(String, String)> {
    let out = Command::new(env!("CARGO"))
        .args(["metadata", "--format-version", "1", "--no-deps", "--locked"])
        .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
        .output()
        .expect("cargo metadata");
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let mut bins = Vec::new();
    for p in v["packages"].as_array().unwrap() {
        for t in p["targets"].as_array().unwrap() {
            if t["kind"].as_array().unwrap().iter().any(|k| k == "bin") {
                bins.push((
                    p["name"].as_str().unwrap().to_string(),
                    t["name"].as_str().unwrap().to_string(),
                ));
            }
        }
    }
    bins.sort();
    bins
}

/// Every binary: the prebuilt folder (`hil_tests::BIN_DIR_ENV`, set by
/// `scripts/test-all.sh`), else their release build, made here (`cargo
/// test` does not build other packages' binaries): the build the other
/// process tests run, so that no other copy of the workspace is built for
/// this test.
fn built() -> PathBuf {
    if let Some(d) = hil_tests::prebuilt_bin_dir() {
        return d;
    }
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/..");
    let st = Command::new(env!("CARGO"))
        .args([
            "build",
            "-q",
            "--release",
            "--locked",
            "--workspace",
            "--bins",
        ])
        .current_dir(root)
        .status()
        .expect("cargo build");
    assert!(st.success(), "building the binaries");
    hil_tests::release_dir()
}

#[test]
fn every_binary_has_help_and_refuses_a_misspelt_option() {
    let bins = binaries();
    assert!(bins.len() >= 10, "{bins:?}");
    let dir = built();
    for (pkg, bin) in &bins {
        let exe = dir.join(bin);
        assert!(exe.is_file(), "{pkg}/{bin}: no binary {}", exe.display());
        let help = Command::new(&exe).arg("--help").output().unwrap();
        let text = String::from_utf8_lossy(&help.stdout);
        assert!(
            help.status.success() && text.contains("Usage:"),
            "{pkg}/{bin} --help: {text}"
        );
        let bad = Command::new(&exe).arg("--no-such-option").output().unwrap();
        let err = String::from_utf8_lossy(&bad.stderr);
        assert_eq!(bad.status.code(), Some(2), "{pkg}/{bin}: {err}");
        assert!(err.contains("--no-such-option"), "{pkg}/{bin}: {err}");
    }
}
