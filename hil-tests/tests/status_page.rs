//! The daemon's status page in a real headless browser (Debian's
//! `chromium`; `scripts/install-test-deps.sh` installs it): the daemon (`dbtor-daemon`, the
//! shipped model and geometry, int8) receives three acquisitions of
//! different breasts from host-sim's frame server and one cut stream; then
//! chromium loads the page, runs its script and renders it:
//! - the page loads and every figure decodes (its script counts them);
//! - each acquisition's numbers on the page equal its SRs' (read by dcmtk's
//!   `dsrdump`) at the page's precision, and its BI-RADS category is the
//!   density SR's;
//! - `/status.json` and `dbtor-diag status --json` show the same state;
//! - no patient identifier is on the page or in its JSON;
//! - SIGTERM stops the page with the daemon.
//!
//! The screenshot goes to `$DBTOR_STATUS_SCREENSHOT` when set
//! (`scripts/status-page-screenshot.sh` makes docs/figures/status-page.png
//! that way), else into the test's folder.

use hil_tests::{free_port, wait_exit, workspace_bin};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const PHANTOMS: [u32; 3] = [1, 4, 7];

/// The shipped model and its digest and geometry (`firmware/config/dbtor.toml`).
fn shipped() -> (PathBuf, String, String) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let text = std::fs::read_to_string(root.join("firmware/config/dbtor.toml")).unwrap();
    let c: toml::Value = toml::from_str(&text).unwrap();
    let name = Path::new(c["recon"]["model"].as_str().unwrap())
        .file_name()
        .unwrap()
        .to_owned();
    (
        root.join("models").join(name),
        c["recon"]["model_digest"].as_str().unwrap().into(),
        c["frames"]["geometry"].as_str().unwrap().into(),
    )
}

fn wait_for(dir: &Path, what: &str, f: impl Fn(&serde_json::Value) -> bool) -> serde_json::Value {
    hil_tests::wait_for_status(dir, what, Duration::from_secs(300), f)
}

/// host-sim serving one acquisition on `addr` (one connection, then exit).
fn stream(acq: &Path, addr: &str, faults: &[&str]) -> Child {
    Command::new(workspace_bin("host-sim"))
        .args(["stream", "--acq"])
        .arg(acq)
        .args(["--listen", addr])
        .args(faults.iter().flat_map(|f| ["--fault", f]))
        .stderr(Stdio::null())
        .stdout(Stdio::null())
        .spawn()
        .unwrap()
}

/// The value of the SR content item named `name` in dsrdump's output:
/// `NUM:(,,"name")="value"` or `CODE:(,,"name")=(code,scheme,"meaning")`.
fn sr_value(dump: &str, name: &str) -> String {
    let key = format!("(,,\"{name}\")=");
    let i = dump
        .find(&key)
        .unwrap_or_else(|| panic!("{name} not in the SR:\n{dump}"));
    let rest = &dump[i + key.len()..];
    if let Some(r) = rest.strip_prefix('"') {
        r[..r.find('"').unwrap()].to_string()
    } else {
        // A code: its meaning.
        let r = &rest[..rest.find(')').unwrap()];
        r.rsplit('"').nth(1).unwrap().to_string()
    }
}

fn dsrdump(file: &Path) -> String {
    let out = Command::new("dsrdump")
        .arg("-Ec")
        .arg(file)
        .output()
        .expect("dsrdump (dcmtk) must be installed: scripts/install-test-deps.sh installs it");
    assert!(out.status.success(), "{}", file.display());
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The text of the cell `class` in the table row of acquisition `id`.
fn cell(dom: &str, id: &str, class: &str) -> String {
    let row_at = dom
        .find(&format!("<tr data-acquisition=\"{id}\">"))
        .unwrap_or_else(|| panic!("no row for {id}"));
    let row = &dom[row_at..row_at + dom[row_at..].find("</tr>").unwrap()];
    let key = format!("class=\"{class}\"");
    let at = row
        .find(&key)
        .unwrap_or_else(|| panic!("no {class} cell in {row}"));
    let r = &row[at..];
    let r = &r[r.find('>').unwrap() + 1..];
    r[..r.find('<').unwrap()].to_string()
}

fn chromium(args: &[&str], url: &str) -> std::process::Output {
    let out = Command::new("chromium")
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-dev-shm-usage",
            "--no-first-run",
            "--hide-scrollbars",
        ])
        .args(args)
        .arg(url)
        .output()
        .expect(
            "chromium must be installed: scripts/install-test-deps.sh installs Debian's chromium",
        );
    assert!(
        out.status.success(),
        "chromium {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

#[test]
fn status_page_in_headless_chromium_shows_what_the_srs_say() {
    let dir = tempfile::tempdir().unwrap();
    let (model, digest, geometry) = shipped();
    let frames = format!("127.0.0.1:{}", free_port());
    let cfg = dir.path().join("dbtor.toml");
    std::fs::write(
        &cfg,
        format!(
            r#"
[frames]
transport = "tcp"
address = "{frames}"
idle_timeout_s = 20
geometry = "{geometry}"
binning = 4

[modbus]
transport = "off"

[recon]
reconstructor = "dbtor"
model = {model:?}
model_digest = "{digest}"
precision = "int8"
dose_uncertainty = 0.1

[paths]
spool = "spool"
output = "output"
status = "run/status.json"

[report]
uid_root = "1.2.826.0.1.3680043.10.543.1"
tube_output_mgy_per_mas = 0.11

[status_page]
address = "127.0.0.1:0"
"#,
            model = model.display().to_string()
        ),
    )
    .unwrap();
    let acqs: Vec<PathBuf> = PHANTOMS
        .iter()
        .map(|&i| {
            let d = dir.path().join(format!("phantom{i}"));
            std::fs::create_dir_all(&d).unwrap();
            hil_tests::acquire_on(&d, i, &geometry)
        })
        .collect();
    let mut daemon = Command::new(workspace_bin("dbtor-daemon"))
        .arg("--config")
        .arg(&cfg)
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let s = wait_for(dir.path(), "the status page", |s| {
        s["status_page"].is_string()
    });
    let url = s["status_page"].as_str().unwrap().to_string();
    let port: u16 = url
        .trim_end_matches('/')
        .rsplit(':')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    // A cut stream first (a link fault on the page), then three breasts.
    let mut cut = stream(&acqs[0], &frames, &["cut:3"]);
    wait_for(dir.path(), "the link fault", |s| {
        s["fault_counts"]["link"].as_u64() >= Some(1)
    });
    wait_exit(&mut cut, Duration::from_secs(60), "the cut host-sim stream");
    for (k, acq) in acqs.iter().enumerate() {
        let mut g = stream(acq, &frames, &[]);
        wait_for(dir.path(), "a report", |s| {
            s["processed"].as_u64() == Some(k as u64 + 1) && s["state"] == "waiting"
        });
        wait_exit(&mut g, Duration::from_secs(60), "host-sim stream");
    }

    // The page in chromium: loaded, script run, figures decoded.
    let dom =
        String::from_utf8(chromium(&["--virtual-time-budget=10000", "--dump-dom"], &url).stdout)
            .unwrap();
    let attr = |name: &str| {
        let k = format!("{name}=\"");
        let i = dom.find(&k).unwrap_or_else(|| panic!("no {name} in {dom}"));
        dom[i + k.len()..][..dom[i + k.len()..].find('"').unwrap()].to_string()
    };
    assert_eq!(attr("data-figures-expected"), "3");
    assert_eq!(
        attr("data-figures-loaded"),
        "3",
        "broken: {}",
        attr("data-figures-broken")
    );
    assert_eq!(attr("data-healthy"), "true", "reports after the fault");
    assert!(dom.contains("<td>link</td>"), "the link fault is listed");

    // Every acquisition's numbers are its SRs'.
    let done: Vec<String> = {
        let mut v: Vec<String> = std::fs::read_dir(dir.path().join("spool/done"))
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    };
    assert_eq!(done.len(), PHANTOMS.len());
    for id in &done {
        let public = id.split('-').next().unwrap();
        let out = dir.path().join("output");
        let dose = dsrdump(&out.join(format!("{id}-dose-sr.dcm")));
        let dens = dsrdump(&out.join(format!("{id}-density-sr.dcm")));
        let num = |dump: &str, name: &str| sr_value(dump, name).parse::<f64>().unwrap();
        assert_eq!(
            cell(&dom, public, "num glandularity"),
            format!("{:.1}", num(&dens, "Percent Fibroglandular Tissue")),
            "{id}"
        );
        assert_eq!(
            cell(&dom, public, "num mgd"),
            format!("{:.3}", num(&dose, "Accumulated Average Glandular Dose")),
            "{id}"
        );
        assert_eq!(
            cell(&dom, public, "num model-mgd"),
            format!(
                "{:.3}",
                num(&dose, "Model-breast Accumulated Average Glandular Dose")
            ),
            "{id}"
        );
        assert_eq!(
            cell(&dom, public, "num thickness"),
            format!("{:.1}", num(&dose, "Compression Thickness")),
            "{id}"
        );
        let shown = cell(&dom, public, "composition");
        if dens.contains("\"Breast composition\")") {
            let meaning = sr_value(&dens, "Breast composition").to_lowercase();
            assert!(
                shown.ends_with(&format!("({meaning})")),
                "{shown} vs {meaning}"
            );
        } else {
            // A density the physics did not confirm: no category in the SR
            // nor on the page, which says why.
            assert!(
                dens.contains("Not confirmed by the physics-based density"),
                "{id}: neither a category nor the cross-check's verdict:\n{dens}"
            );
            assert!(shown.contains("not confirmed by the physics"), "{shown}");
        }
        // The patient id (in the entry id) is nowhere on the page.
        let patient = &id[public.len() + 1..];
        assert!(!dom.contains(patient), "{patient} on the page");
    }

    // The figures themselves: one point pair per acquisition, one count
    // per acquisition in the histogram, and the latest picture's panels.
    let get = |path: &str| {
        String::from_utf8(hil_tests::http_get(port, path).unwrap_or_else(|| panic!("{path}")))
            .unwrap()
    };
    let n = PHANTOMS.len();
    assert!(get("/figures/mgd-thickness.svg").contains(&format!("data-points=\"{n}\"")));
    assert!(get("/figures/glandularity.svg").contains(&format!("data-points=\"{n}\"")));
    let latest = done.last().unwrap().split('-').next().unwrap();
    let pic = get(&format!("/acquisitions/{latest}/picture.svg"));
    assert_eq!(pic.matches("<g class=\"panel\">").count(), 4);

    // The page's JSON and dbtor-diag read the same state.
    let page: serde_json::Value = serde_json::from_str(&get("/status.json")).unwrap();
    let out = Command::new(workspace_bin("dbtor-diag"))
        .args(["status", "--json", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    let diag: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(page["healthy"], diag["healthy"]);
    for k in [
        "processed",
        "fault_counts",
        "reconstructor",
        "pid",
        "started_unix",
    ] {
        assert_eq!(page["status"][k], diag["status"][k], "{k}");
    }
    let (ph, dh) = (
        page["history"].as_array().unwrap(),
        diag["history"].as_array().unwrap(),
    );
    assert_eq!(ph.len(), n);
    assert_eq!(dh.len(), n);
    for (p, d) in ph.iter().zip(dh) {
        let did = d["acquisition"].as_str().unwrap();
        assert_eq!(p["acquisition"], did.split('-').next().unwrap());
        for k in [
            "glandularity_reported",
            "mgd_mgy",
            "model_mgd_mgy",
            "thickness_mm",
            "composition",
            "finished_unix",
        ] {
            assert_eq!(p[k], d[k], "{k}");
        }
        assert_eq!(p["patient_id"], "", "no patient id in the page's JSON");
        assert_ne!(d["patient_id"], "", "dbtor-diag (local) shows it");
    }

    // The screenshot.
    let shot = std::env::var_os("DBTOR_STATUS_SCREENSHOT")
        .map(PathBuf::from)
        .unwrap_or_else(|| dir.path().join("status-page.png"));
    chromium(
        &[
            "--virtual-time-budget=10000",
            "--window-size=1280,1900",
            &format!("--screenshot={}", shot.display()),
        ],
        &url,
    );
    let png = std::fs::read(&shot).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    let (w, h) = (
        u32::from_be_bytes(png[16..20].try_into().unwrap()),
        u32::from_be_bytes(png[20..24].try_into().unwrap()),
    );
    assert_eq!((w, h), (1280, 1900));
    assert!(png.len() > 50_000, "a rendered page, not a blank one");

    // SIGTERM: the daemon stops, and so does its page.
    assert!(Command::new("kill")
        .args(["-TERM", &daemon.id().to_string()])
        .status()
        .unwrap()
        .success());
    let t0 = Instant::now();
    while daemon.try_wait().unwrap().is_none() {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "no exit after SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(std::net::TcpStream::connect(("127.0.0.1", port)).is_err());
}
