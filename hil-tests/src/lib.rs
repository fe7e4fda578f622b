//! Helpers shared by the hardware-in-the-loop tests in `tests/`.

/// A loopback TCP port that was free a moment ago.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .unwrap_or(0)
}

/// A workspace binary (`host-sim`, or one of the firmware's), (re)built first:
/// `cargo test` does not rebuild other packages' binaries, and a stale one
/// would test old code. A no-op when fresh (cargo does not hold the build
/// lock while tests run).
pub fn workspace_bin(name: &str) -> std::path::PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    let dir = exe
        .parent()
        .and_then(|d| d.parent())
        .expect("target profile folder")
        .to_path_buf();
    let pkg = if name == "host-sim" {
        "host-sim"
    } else {
        "dbtor-firmware"
    };
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut c = std::process::Command::new(cargo);
    c.args(["build", "-q", "-p", pkg, "--bin", name]);
    if dir.ends_with("release") {
        c.arg("--release");
    }
    let ok = c.status().map(|s| s.success()).unwrap_or(false);
    assert!(ok, "building {name}");
    dir.join(name)
}
