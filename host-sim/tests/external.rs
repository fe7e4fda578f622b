//! An external phantom through the product's own path (issue #48 point 5):
//! `host-sim acquire --phantom SIDECAR` acquires a phantom from its sidecar
//! (here one `host-sim phantom` wrote, so that the truth is known), with its
//! truth in the header; the same sidecar gives the same acquisition; a
//! sidecar that cannot be read is refused naming it.

use std::process::Command;

fn host_sim() -> Command {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
}

fn header(acq: &std::path::Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(acq.join("acquisition.json")).unwrap()).unwrap()
}

#[test]
fn an_external_phantom_is_acquired_from_its_sidecar() {
    let dir = tempfile::tempdir().unwrap();
    let sidecar = dir.path().join("breast.toml");
    let geometry = ["--geometry", "paper", "--binning", "10"];
    let made = host_sim()
        .args(["phantom", "--index", "3", "--out"])
        .arg(&sidecar)
        .args(geometry)
        .output()
        .unwrap();
    assert!(made.status.success());
    // "...: [dims] voxels of V mm, thickness T mm, glandularity G"
    let printed = String::from_utf8_lossy(&made.stdout).to_string();
    let number_after = |key: &str| -> f64 {
        let rest = printed.split(key).nth(1).expect(key);
        rest.trim_start()
            .split(|c: char| !(c.is_ascii_digit() || c == '.'))
            .next()
            .unwrap()
            .parse()
            .unwrap()
    };
    let (g_true, t_true) = (number_after("glandularity"), number_after("thickness"));
    let acquire = |out: &str, extra: &[&str]| {
        let o = host_sim()
            .args(["acquire", "--phantom"])
            .arg(&sidecar)
            .arg("--out")
            .arg(dir.path().join(out))
            .args(geometry)
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        header(&dir.path().join(out))
    };
    let a = acquire("a", &[]);
    let b = acquire("b", &[]);
    // The phantom's own truth (its sidecar holds its labels at the
    // geometry's pixel: no resampling), as `host-sim phantom` printed it.
    let g = a["truth"]["glandularity"].as_f64().unwrap();
    assert!((g - g_true).abs() < 5e-4, "{g} against {g_true}");
    assert!(
        (a["thickness_mm"].as_f64().unwrap() - t_true).abs() < 0.05,
        "{a}"
    );
    assert_eq!(a["patient"]["id"], "EXTBREAST", "{a}");
    // The same sidecar, the same counts.
    let counts = |n: &str| std::fs::read(dir.path().join(n).join("counts.f32")).unwrap();
    assert_eq!(counts("a"), counts("b"));
    assert_eq!(a, b);
    // A sidecar that is not there is refused naming it; --phantom with
    // --index is refused as contradictory.
    let o = host_sim()
        .args(["acquire", "--phantom", "/nonexistent/p.toml", "--out"])
        .arg(dir.path().join("c"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("/nonexistent/p.toml"));
    let o = host_sim()
        .args(["acquire", "--phantom"])
        .arg(&sidecar)
        .args(["--index", "2", "--out"])
        .arg(dir.path().join("d"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
}
