//! The gantry's Modbus registers over loopback TCP, host-sim (server) and the
//! firmware's diagnostics (client) as separate processes; a third-party
//! client, mbpoll (Debian; `scripts/install-test-deps.sh` installs it), reads the same registers.
//! Injected faults (exception responses, silence) give named failures and
//! exit status 1, never made-up values.

use hil_tests::{free_port, pty_pair, wait_for_port, workspace_bin};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

struct Sim(Child);

impl Drop for Sim {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn start(port: u16, extra: &[&str]) -> Sim {
    let child = Command::new(workspace_bin("host-sim"))
        .args([
            "modbus",
            "--listen",
            &format!("127.0.0.1:{port}"),
            "--thickness-mm",
            "52.1",
        ])
        .args(extra)
        .spawn()
        .unwrap();
    wait_for_port(port, "host-sim modbus");
    Sim(child)
}

#[test]
fn registers_are_read_decoded_and_faults_named() {
    let port = free_port();
    let _sim = start(port, &[]);
    let out = Command::new(workspace_bin("dbtor-diag"))
        .args(["modbus", &format!("127.0.0.1:{port}"), "--json"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let r = &v["registers"];
    assert_eq!(r["thickness_mm"], 52.1);
    assert_eq!(r["kvp"], 29.0);
    assert_eq!(r["state"], "Exposing");
    assert_eq!(r["projections"], 25);
    assert_eq!(r["angles_deg"][0], -24.0);
    assert_eq!(r["laterality"], "L");

    // A third-party client reads the same register values.
    let mb = Command::new("mbpoll")
        .args([
            "-m",
            "tcp",
            "-a",
            "1",
            "-r",
            "1",
            "-c",
            "13",
            "-t",
            "4",
            "-1",
            "-p",
            &port.to_string(),
            "127.0.0.1",
        ])
        .output()
        .expect("mbpoll not found: apt-get install mbpoll");
    assert!(
        mb.status.success(),
        "{}",
        String::from_utf8_lossy(&mb.stderr)
    );
    let text = String::from_utf8_lossy(&mb.stdout);
    let values: Vec<u16> = text
        .lines()
        .filter(|l| l.starts_with('['))
        .filter_map(|l| l.split_whitespace().nth(1).and_then(|x| x.parse().ok()))
        .collect();
    assert_eq!(values.len(), 13, "{text}");
    assert_eq!(values[2], 521, "thickness register (0.1 mm)");
    assert_eq!(values[8], (-240i16) as u16, "first angle register");

    // Faults.
    for (fault, want) in [
        ("exception", "exception response"),
        ("silent", "no answer within"),
    ] {
        let port = free_port();
        let _sim = start(port, &["--fault", fault]);
        let out = Command::new(workspace_bin("dbtor-diag"))
            .args(["modbus", &format!("127.0.0.1:{port}")])
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout);
        assert_eq!(out.status.code(), Some(1), "{fault}: {text}");
        assert!(text.contains(want), "{fault}: {text}");
    }
}

/// The firmware's client against a third-party server: pymodbus
/// (`hil-tests/peers/pymodbus_gantry.py`, the register map encoded
/// independently in Python; `scripts/install-test-deps.sh` installs pymodbus).
#[test]
fn firmware_client_reads_a_pymodbus_server() {
    let port = free_port();
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("peers/pymodbus_gantry.py");
    let server = Command::new("python3")
        .arg(&script)
        .args([&port.to_string(), "47.3"])
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("python3 (with pymodbus: pip install -r hil-tests/peers/requirements.txt)");
    let _server = Sim(server);
    wait_for_port(port, "the pymodbus server (is pymodbus installed?)");
    let out = Command::new(workspace_bin("dbtor-diag"))
        .args(["modbus", &format!("127.0.0.1:{port}"), "--json"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let r = &v["registers"];
    assert_eq!(r["thickness_mm"], 47.3);
    assert_eq!(r["force_n"], 123.4);
    assert_eq!(r["kvp"], 29.0);
    assert_eq!(r["mas_per_projection"], 2.15);
    assert_eq!(r["anode_filter"], "W/Rh");
    assert_eq!(r["angles_deg"], serde_json::json!([-24.0, 24.0]));
    assert_eq!(r["laterality"], "L");
    assert_eq!(r["view"], "MLO");
    assert_eq!(r["state"], "Exposing");
}

/// Read over RTU, retrying while the server opens its end of the line.
fn diag_rtu(tty: &std::path::Path) -> std::process::Output {
    let t = Instant::now();
    loop {
        let out = Command::new(workspace_bin("dbtor-diag"))
            .arg("modbus")
            .arg("--rtu")
            .arg(tty)
            .arg("--json")
            .output()
            .unwrap();
        if out.status.success() || t.elapsed() > Duration::from_secs(20) {
            return out;
        }
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// Modbus RTU on a pty pair: host-sim's RTU server read by the firmware's
/// client and by mbpoll (`-m rtu`), and a pymodbus RTU server read by the
/// firmware's client.
#[test]
fn rtu_over_a_pty_pair() {
    let dir = tempfile::tempdir().unwrap();
    {
        let pty = pty_pair(dir.path(), "modbus");
        let _sim = Sim(Command::new(workspace_bin("host-sim"))
            .args(["modbus", "--serial"])
            .arg(&pty.a)
            .args(["--thickness-mm", "61.7"])
            .spawn()
            .unwrap());
        let out = diag_rtu(&pty.b);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stdout)
        );
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(v["registers"]["thickness_mm"], 61.7);
        assert_eq!(v["registers"]["state"], "Exposing");
        let mb = Command::new("mbpoll")
            .args([
                "-m", "rtu", "-b", "19200", "-P", "none", "-a", "1", "-r", "1", "-c", "13", "-1",
            ])
            .arg(&pty.b)
            .output()
            .expect("mbpoll not found: apt-get install mbpoll");
        let text = String::from_utf8_lossy(&mb.stdout);
        assert!(mb.status.success(), "{text}");
        assert!(text.contains("[3]: \t617"), "{text}");
    }
    {
        let dir2 = tempfile::tempdir().unwrap();
        let pty = pty_pair(dir2.path(), "modbus");
        let script =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("peers/pymodbus_gantry.py");
        let _server = Sim(Command::new("python3")
            .arg(&script)
            .arg(&pty.a)
            .arg("47.3")
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap());
        let out = diag_rtu(&pty.b);
        assert!(
            out.status.success(),
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(v["registers"]["thickness_mm"], 47.3);
        assert_eq!(v["registers"]["view"], "MLO");
    }
}
