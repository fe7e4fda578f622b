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
