//! Progress bars where people look, and nowhere else: a command run on a
//! terminal (a pseudo-terminal made by util-linux's `script`) draws its bar
//! on stderr; the same command with stderr piped, or with `--json`, draws
//! none, and its log lines are there either way.

use hil_tests::workspace_bin;
use std::path::Path;
use std::process::Command;

/// Run `cmd` (a shell command line) on a pseudo-terminal; what the terminal
/// showed.
fn on_a_terminal(cmd: &str) -> String {
    let out = Command::new("script")
        .args(["-qec", cmd, "/dev/null"])
        .output()
        .expect("util-linux's script");
    assert!(
        out.status.success(),
        "{cmd}: {}",
        String::from_utf8_lossy(&out.stdout)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn dataset_cmd(out: &Path) -> String {
    format!(
        "{} dataset --out {} --slices 40 --test-phantoms 1 --levels N8",
        workspace_bin("host-sim").display(),
        out.display()
    )
}

#[test]
fn dataset_export_draws_a_bar_on_a_terminal_only() {
    let dir = tempfile::tempdir().unwrap();
    let tty = on_a_terminal(&dataset_cmd(&dir.path().join("a")));
    assert!(tty.contains("dataset ["), "no bar on the terminal: {tty}");
    assert!(tty.contains("slices"), "{tty}");
    assert!(tty.contains("phantom exported"), "log lines kept: {tty}");
    let out = Command::new(workspace_bin("host-sim"))
        .args(["dataset", "--out"])
        .arg(dir.path().join("b"))
        .args(["--slices", "40", "--test-phantoms", "1", "--levels", "N8"])
        .output()
        .unwrap();
    assert!(out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("dataset ["), "a bar into a pipe: {err}");
    assert!(err.contains("phantom exported"), "log lines kept: {err}");
}

#[test]
fn replay_draws_a_bar_unless_json() {
    let dir = tempfile::tempdir().unwrap();
    let acq = hil_tests::acquire(dir.path(), 2);
    let replay = |json: &str| {
        on_a_terminal(&format!(
            "{} replay {} --iterations 20 --dose-uncertainty 0.3 {json}",
            workspace_bin("dbtor-diag").display(),
            acq.display()
        ))
    };
    let tty = replay("");
    assert!(tty.contains("reconstruction ["), "no bar: {tty}");
    let json = replay("--json");
    assert!(
        !json.contains("reconstruction ["),
        "a bar with --json: {json}"
    );
    assert!(json.contains("\"glandularity_labels\""), "{json}");
}
