//! `dbt-dose scatter-fit` keeps its Monte Carlo views when asked, reads
//! them back instead of running again, and refuses a file made with other
//! options, naming them. Few photons: this tests the command, not the
//! model (the shipped table's figures are eval/README.md's).

use std::process::Command;

fn fit(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_dbt-dose"))
        .args(["scatter-fit", "--angle", "0", "--glandularity", "0.3"])
        .args(["--photons-per-mm", "20000", "--open-photons", "400000"])
        .args(args)
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap()
}

#[test]
fn views_are_kept_read_back_and_checked() {
    let dir = tempfile::tempdir().unwrap();
    let views = dir.path().join("views.json");
    let v = views.to_str().unwrap();
    let out = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    let a = fit(&[
        "--thickness",
        "30,40",
        "--views-file",
        v,
        "--out",
        &out("a.json"),
    ]);
    assert!(a.status.success(), "{}", String::from_utf8_lossy(&a.stderr));
    let err = String::from_utf8_lossy(&a.stderr);
    assert!(
        err.contains("Monte Carlo: 30 mm") && err.contains("kept in"),
        "{err}"
    );
    let b = fit(&[
        "--thickness",
        "30,40",
        "--views-file",
        v,
        "--out",
        &out("b.json"),
    ]);
    let err = String::from_utf8_lossy(&b.stderr);
    assert!(b.status.success(), "{err}");
    assert!(
        err.contains("2 Monte Carlo views read") && !err.contains("Monte Carlo: 30 mm"),
        "{err}"
    );
    // The same kernels from the kept views (JSON's decimals: to 1e-12).
    let table = |n: &str| dbt_scatter_table(&std::fs::read_to_string(dir.path().join(n)).unwrap());
    let (ta, tb) = (table("a.json"), table("b.json"));
    assert_eq!(ta.len(), tb.len());
    for (x, y) in ta.iter().zip(&tb) {
        assert!((x - y).abs() <= 1e-12 * x.abs().max(1.0), "{x} vs {y}");
    }
    let c = fit(&[
        "--thickness",
        "30,50",
        "--views-file",
        v,
        "--out",
        &out("c.json"),
    ]);
    let err = String::from_utf8_lossy(&c.stderr);
    assert!(
        !c.status.success() && err.contains("made with") && err.contains("50.0"),
        "{err}"
    );
}

/// Every number of a table's kernels, in order.
fn dbt_scatter_table(text: &str) -> Vec<f64> {
    let v: serde_json::Value = serde_json::from_str(text).unwrap();
    let mut out = Vec::new();
    for k in v["kernels"].as_array().unwrap() {
        for key in ["thickness_mm", "wide_weight", "shift_mm"] {
            out.push(k[key].as_f64().unwrap());
        }
        for key in ["sigma_mm", "p_knots", "amplitude"] {
            out.extend(
                k[key]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|x| x.as_f64().unwrap()),
            );
        }
    }
    out
}
