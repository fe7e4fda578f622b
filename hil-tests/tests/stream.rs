//! host-sim and the firmware as separate processes over loopback TCP: the
//! gantry's projection stream with injected faults. A clean stream and every
//! repairable fault (corrupt CRC, dropped, duplicated, reordered frames)
//! yield exactly the acquisition that was sent; a pulled cable yields a named
//! fault and nothing spooled.

use hil_tests::{acquire, free_port, pty_pair, workspace_bin};
use std::path::Path;
use std::process::Command;

fn transfer(acq: &Path, out: &Path, faults: &[&str]) -> (bool, String) {
    transfer_within(acq, out, faults, 20)
}

fn transfer_within(acq: &Path, out: &Path, faults: &[&str], timeout_s: u32) -> (bool, String) {
    let port = free_port();
    let addr = format!("127.0.0.1:{port}");
    let mut sim = Command::new(workspace_bin("host-sim"));
    sim.args(["stream", "--acq"])
        .arg(acq)
        .args(["--listen", &addr]);
    for f in faults {
        sim.args(["--fault", f]);
    }
    let mut sim = sim.spawn().unwrap();
    let rx = Command::new(workspace_bin("dbtor-receive"))
        .args(["--connect", &addr, "--out"])
        .arg(out)
        .args(["--timeout-s", &timeout_s.to_string()])
        .output()
        .unwrap();
    let _ = sim.kill();
    let _ = sim.wait();
    (
        rx.status.success(),
        String::from_utf8_lossy(&rx.stderr).to_string() + &String::from_utf8_lossy(&rx.stdout),
    )
}

#[test]
fn faults_are_repaired_or_reported() {
    let dir = tempfile::tempdir().unwrap();
    let acq = acquire(dir.path(), 3);
    let sent = std::fs::read(acq.join("counts.f32")).unwrap();
    let cases: [&[&str]; 6] = [
        &[],
        &["corrupt:3"],
        &["drop:5"],
        &["dup:2"],
        &["reorder:7,9"],
        &["corrupt:1", "drop:4", "dup:6", "reorder:10,12", "corrupt:0"],
    ];
    for (i, faults) in cases.iter().enumerate() {
        let out = dir.path().join(format!("rx{i}"));
        let (ok, log) = transfer(&acq, &out, faults);
        assert!(ok, "{faults:?}: {log}");
        let got = std::fs::read(out.join("counts.f32")).unwrap();
        assert!(
            got == sent,
            "{faults:?}: received counts differ from those sent"
        );
    }
    // Cable pulled mid-acquisition: a named fault, nothing spooled.
    let out = dir.path().join("cut");
    let (ok, log) = transfer(&acq, &out, &["cut:8"]);
    assert!(!ok);
    assert!(
        log.contains("FAULT") && log.contains("before the acquisition was complete"),
        "{log}"
    );
    assert!(!out.exists());
}

/// The same stream over a serial line: a pseudo-terminal pair made by socat
/// (Debian; `scripts/install-test-deps.sh` installs it), host-sim on one end, the firmware on the
/// other, with repairable faults.
#[test]
fn serial_line_over_a_pty_pair() {
    let dir = tempfile::tempdir().unwrap();
    let acq = acquire(dir.path(), 4);
    let pty = pty_pair(dir.path(), "tty");
    let (a, b) = (&pty.a, &pty.b);
    let mut sim = Command::new(workspace_bin("host-sim"))
        .args(["stream", "--acq"])
        .arg(&acq)
        .arg("--serial")
        .arg(a)
        .args([
            "--fault",
            "corrupt:0",
            "--fault",
            "corrupt:6",
            "--fault",
            "drop:3",
            "--fault",
            "reorder:8,11",
        ])
        .spawn()
        .unwrap();
    let out = dir.path().join("rx");
    let rx = Command::new(workspace_bin("dbtor-receive"))
        .arg("--serial")
        .arg(b)
        .arg("--out")
        .arg(&out)
        .args(["--timeout-s", "20"])
        .output()
        .unwrap();
    // The receiver's output is what counts; do not wait on the gantry.
    let _ = sim.kill();
    let _ = sim.wait();
    drop(pty);
    assert!(
        rx.status.success(),
        "{}",
        String::from_utf8_lossy(&rx.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&rx.stdout).unwrap();
    assert_eq!(report["crc_errors"], 2, "{report}");
    assert_eq!(
        std::fs::read(acq.join("counts.f32")).unwrap(),
        std::fs::read(out.join("counts.f32")).unwrap(),
        "received counts differ from those sent"
    );
}

/// A gantry that misbehaves cannot freeze or exhaust the receiver: an
/// announcement beyond the configured geometry is refused at the header, a
/// header without exposure (0 mAs, or 0 kV) or of a molybdenum exposure (no spectra
/// of the dose model) likewise, a gantry that stops reading our
/// acknowledgements is a named fault after the write timeout, not a hang.
/// Nothing is spooled in any case.
#[test]
fn a_misbehaving_gantry_is_refused_or_timed_out() {
    let dir = tempfile::tempdir().unwrap();
    let acq = acquire(dir.path(), 3);
    for (faults, timeout, words) in [
        (
            &["announce:4096"][..],
            20,
            "announces 4096 projections, the receiver is configured for 25",
        ),
        (&["mas:0"][..], 20, "`mas_total` = 0"),
        // No tube voltage: refused at the header, naming it.
        (&["kvp:0"][..], 20, "kvp 0"),
        // A stated anode/filter the dose model has no spectra for.
        (&["anode:7"][..], 20, "anode/filter Rh/Ag"),
        // Acknowledgements of a flood of repeated headers that nobody reads:
        // whichever comes first, the write timeout or the acquisition not
        // advancing, ends it.
        (&["freeze:1"][..], 3, "s (write timed out)|has not advanced"),
    ] {
        let out = dir
            .path()
            .join(format!("rx-{}", faults[0].replace(':', "-")));
        let t0 = std::time::Instant::now();
        let (ok, log) = transfer_within(&acq, &out, faults, timeout);
        assert!(!ok, "{faults:?}: {log}");
        assert!(
            log.contains("FAULT") && words.split('|').any(|w| log.contains(w)),
            "{faults:?}: {log}"
        );
        assert!(!out.exists(), "{faults:?}: nothing may be spooled");
        // Bounded by the configured timeouts (the old receiver froze for
        // 50 s with --timeout-s 3); a generous bound, not a speed goal.
        assert!(
            t0.elapsed() < std::time::Duration::from_secs(40),
            "{faults:?}"
        );
    }
}

/// A peer that sends only garbage: one byte every 100 ms never lets the
/// acquisition advance, so it fails after the idle timeout (the old receiver
/// reset its timer on every byte and never timed out); garbage and then a
/// closed connection is a fault from the first byte ("no acquisition
/// header"), not "nothing arrived".
#[test]
fn garbage_trickles_and_headerless_streams_are_faults() {
    use std::io::Write;
    for trickle in [true, false] {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap().to_string();
        let server = std::thread::spawn(move || {
            let (mut s, _) = listener.accept().unwrap();
            if trickle {
                for _ in 0..200 {
                    if s.write_all(b"x").is_err() {
                        return;
                    }
                    std::thread::sleep(std::time::Duration::from_millis(100));
                }
            } else {
                let _ = s.write_all(&[0x55u8; 100]);
            }
        });
        let dir = tempfile::tempdir().unwrap();
        let rx = Command::new(workspace_bin("dbtor-receive"))
            .args(["--connect", &addr, "--out"])
            .arg(dir.path().join("rx"))
            .args(["--timeout-s", "2"])
            .output()
            .unwrap();
        let log = String::from_utf8_lossy(&rx.stderr).to_string();
        assert_eq!(rx.status.code(), Some(1), "{log}");
        let words = if trickle {
            "has not advanced for"
        } else {
            "100 bytes arrived but no acquisition header"
        };
        assert!(log.contains(words), "{log}");
        let _ = server.join();
    }
}
