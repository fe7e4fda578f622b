//! The daemon's DICOM input with one object per view (issue #31): Digital
//! Mammography X-Ray For Processing objects, grouped into a sweep by study,
//! laterality and view; every kind of bad object refused with its reason
//! while the daemon keeps serving; a sweep that stays incomplete faulted
//! after the quiet time; a SIGKILL in the middle of an association loses no
//! object answered Success; the per-view sweep is reported like the same
//! sweep sent as one multi-frame object.

use dicom_core::{DataElement, VR};
use dicom_dictionary_std::tags;
use dicom_transfer_syntax_registry::entries::EXPLICIT_VR_LITTLE_ENDIAN;
use dicom_ul::association::client::ClientAssociationOptions;
use dicom_ul::pdu::{PDataValue, PDataValueType, Pdu};
use hil_tests::{daemon_status, free_port, wait_for_status, workspace_bin};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::Duration;

const LIMIT: Duration = Duration::from_secs(240);

/// A minimal Storage SCU for what dcmtk will not send: a data set as bytes
/// (explicit VR little endian), one association for many objects, a pause
/// between them. Each store returns the response's status.
struct Scu {
    assoc: dicom_ul::association::client::ClientAssociation<std::net::TcpStream>,
    message: u16,
}

impl Scu {
    fn connect(port: u16, classes: &[&str]) -> Scu {
        Self::connect_with(port, classes, EXPLICIT_VR_LITTLE_ENDIAN.uid()).expect("association")
    }

    /// Proposing `classes` in transfer syntax `ts` only.
    fn connect_with(port: u16, classes: &[&str], ts: &str) -> Result<Scu, String> {
        let mut o = ClientAssociationOptions::new()
            .calling_ae_title("RAWSCU")
            .called_ae_title("DBTOR")
            .read_timeout(Duration::from_secs(30));
        for c in classes {
            o = o.with_presentation_context(*c, vec![ts]);
        }
        let assoc = o
            .establish(format!("127.0.0.1:{port}").as_str())
            .map_err(|e| format!("{e:?}"))?;
        Ok(Scu { assoc, message: 0 })
    }

    fn store(&mut self, class: &str, instance: &str, data_set: &[u8]) -> u16 {
        self.message += 1;
        let pc = self
            .assoc
            .presentation_contexts()
            .iter()
            .find(|p| {
                p.abstract_syntax.trim_end_matches('\0') == class
                    && p.reason == dicom_ul::pdu::PresentationContextResultReason::Acceptance
            })
            .expect("an accepted context for the class")
            .id;
        let cmd = dicom_object::InMemDicomObject::command_from_element_iter([
            DataElement::new(tags::AFFECTED_SOP_CLASS_UID, VR::UI, class),
            DataElement::new(
                tags::COMMAND_FIELD,
                VR::US,
                dicom_core::PrimitiveValue::from(0x0001u16),
            ),
            DataElement::new(
                tags::MESSAGE_ID,
                VR::US,
                dicom_core::PrimitiveValue::from(self.message),
            ),
            DataElement::new(
                tags::PRIORITY,
                VR::US,
                dicom_core::PrimitiveValue::from(0u16),
            ),
            DataElement::new(
                tags::COMMAND_DATA_SET_TYPE,
                VR::US,
                dicom_core::PrimitiveValue::from(0u16),
            ),
            DataElement::new(tags::AFFECTED_SOP_INSTANCE_UID, VR::UI, instance),
        ]);
        let mut bytes = Vec::new();
        cmd.write_dataset_with_ts(
            &mut bytes,
            &dicom_transfer_syntax_registry::entries::IMPLICIT_VR_LITTLE_ENDIAN.erased(),
        )
        .unwrap();
        self.assoc
            .send(&Pdu::PData {
                data: vec![PDataValue {
                    presentation_context_id: pc,
                    value_type: PDataValueType::Command,
                    is_last: true,
                    data: bytes,
                }],
            })
            .unwrap();
        {
            let mut w = self.assoc.send_pdata(pc);
            w.write_all(data_set).unwrap();
            w.finish().unwrap();
        }
        match self.assoc.receive().unwrap() {
            Pdu::PData { data } => {
                let rsp = dicom_object::InMemDicomObject::read_dataset_with_ts(
                    &data[0].data[..],
                    &dicom_transfer_syntax_registry::entries::IMPLICIT_VR_LITTLE_ENDIAN.erased(),
                )
                .unwrap();
                rsp.element(tags::STATUS).unwrap().to_int::<u16>().unwrap()
            }
            other => panic!("unexpected {other:?}"),
        }
    }

    fn release(self) {
        let _ = self.assoc.release();
    }
}

/// A Part 10 file's class, instance and data set (explicit VR LE).
fn data_set(file: &Path) -> (String, String, Vec<u8>) {
    let o = dicom_object::open_file(file).unwrap();
    let class = o
        .meta()
        .media_storage_sop_class_uid()
        .trim_end_matches('\0')
        .to_string();
    let instance = o
        .meta()
        .media_storage_sop_instance_uid()
        .trim_end_matches('\0')
        .to_string();
    let mut bytes = Vec::new();
    o.write_dataset_with_ts(&mut bytes, &EXPLICIT_VR_LITTLE_ENDIAN.erased())
        .unwrap();
    (class, instance, bytes)
}

/// The daemon's configuration at a site without the frame link: the DICOM
/// input only (quiet time `quiet` s).
fn config(dir: &Path, dport: u16, flux: f64, tube: f64, quiet: f64, extra: &str) -> PathBuf {
    let cfg = dir.join("dbtor.toml");
    std::fs::write(
        &cfg,
        format!(
            r#"
[frames]
transport = "off"
binning = 4

[modbus]
transport = "off"

[recon]
reconstructor = "mltr"
mltr_iterations = 20
dose_uncertainty = 0.05

[paths]
spool = "spool"
output = "output"
status = "run/status.json"

[report]
uid_root = "1.2.826.0.1.3680043.10.543.1"
tube_output_mgy_per_mas = {tube}

[status_page]
address = "off"

[dicom_input]
address = "127.0.0.1:{dport}"
ae_title = "DBTOR"
flat_field_counts = {flux}
quiet_time_s = {quiet}
{extra}
"#,
        ),
    )
    .unwrap();
    cfg
}

/// The daemon process, killed when dropped (a failing test leaves none).
struct Daemon(Child);

impl Daemon {
    fn id(&self) -> u32 {
        self.0.id()
    }

    /// SIGTERM, and wait.
    fn stop(mut self) {
        let _ = Command::new("kill")
            .args(["-TERM", &self.0.id().to_string()])
            .status();
        hil_tests::wait_exit(
            &mut self.0,
            std::time::Duration::from_secs(60),
            "the daemon after SIGTERM",
        );
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn start_daemon(cfg: &Path, log: &Path) -> Daemon {
    Daemon(
        Command::new(workspace_bin("dbtor-daemon"))
            .arg("--config")
            .arg(cfg)
            .stdout(std::process::Stdio::null())
            .stderr(std::fs::File::create(log).unwrap())
            .spawn()
            .unwrap(),
    )
}

/// `acq` written as view objects into `out` (no send).
fn views_of(acq: &Path, out: &Path) -> Vec<PathBuf> {
    let o = Command::new(workspace_bin("host-sim"))
        .args(["dicom-send", "--per-view", "--acq"])
        .arg(acq)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("dciodvfy: no error"));
    (1..=25)
        .map(|k| out.join(format!("view-{k:02}.dcm")))
        .collect()
}

fn storescu(port: u16, files: &[PathBuf]) -> std::process::Output {
    Command::new("storescu")
        .args(["-R", "-aec", "DBTOR", "-aet", "MODALITY", "127.0.0.1"])
        .arg(port.to_string())
        .args(files)
        .output()
        .expect("storescu (dcmtk)")
}

fn dcmodify(file: &Path, args: &[&str]) {
    let o = Command::new("dcmodify")
        .args(["-nb", "-nrc"])
        .args(args)
        .arg(file)
        .output()
        .expect("dcmodify (dcmtk)");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

fn faulted(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir.join("spool/faulted"))
        .map(|r| r.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    v.sort();
    v
}

fn header(acq: &Path) -> (f64, f64) {
    let h: serde_json::Value =
        serde_json::from_slice(&std::fs::read(acq.join("acquisition.json")).unwrap()).unwrap();
    (
        h["flux"].as_f64().unwrap(),
        h["tube_output_mgy_per_mas"].as_f64().unwrap(),
    )
}

/// How long a sweep waits for its views in the first test, s: longer than
/// the bad objects take to send (a few seconds), short enough to wait for.
const QUIET_S: f64 = 15.0;

/// The private class of the test's vendor (under our UID root).
const PRIVATE: &str = "1.2.826.0.1.3680043.10.543.77.1";

#[test]
fn views_make_one_sweep_and_bad_objects_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let acq = hil_tests::acquire(d, 2);
    let (flux, tube) = header(&acq);
    let views = views_of(&acq, &d.join("views-a"));
    // The same breast acquired again at another dose (other noise: other
    // pixels, same size).
    let acq_b = d.join("acq-b");
    let o = Command::new(workspace_bin("host-sim"))
        .args([
            "acquire",
            "--index",
            "2",
            "--binning",
            "4",
            "--noise",
            "N4",
            "--out",
        ])
        .arg(&acq_b)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let views_b = views_of(&acq_b, &d.join("views-b"));

    // The bad objects, made before any is sent.
    let bad = d.join("bad");
    std::fs::create_dir_all(&bad).unwrap();
    let copy = |name: &str, from: &Path| {
        let p = bad.join(name);
        std::fs::copy(from, &p).unwrap();
        p
    };
    // For Presentation.
    let presentation = copy("presentation.dcm", &views[3]);
    dcmodify(
        &presentation,
        &[
            "-m",
            "(0008,0016)=1.2.840.10008.5.1.4.1.1.1.2",
            "-m",
            "(0008,0068)=FOR PRESENTATION",
        ],
    );
    // No thickness.
    let no_thickness = copy("thickness.dcm", &views[3]);
    dcmodify(&no_thickness, &["-e", "(0018,11a0)"]);
    // A pixel count that disagrees with the rows.
    let rows = copy("rows.dcm", &views[3]);
    dcmodify(&rows, &["-m", "(0028,0010)=7"]);
    // A second copy of view 4 with other pixels: the other acquisition's
    // view 4 made part of this sweep (study, series, patient).
    let other_pixels = copy("other-pixels.dcm", &views_b[3]);
    let a4 = dicom_object::open_file(&views[3]).unwrap();
    let text_of = |t| {
        a4.element(t)
            .unwrap()
            .to_str()
            .unwrap()
            .trim_end_matches('\0')
            .to_string()
    };
    for (tag, t) in [
        ("(0020,000d)", tags::STUDY_INSTANCE_UID),
        ("(0020,000e)", tags::SERIES_INSTANCE_UID),
        ("(0010,0020)", tags::PATIENT_ID),
    ] {
        dcmodify(&other_pixels, &["-m", &format!("{tag}={}", text_of(t))]);
    }
    let truncated = data_set(&views_b[5]);

    let dport = free_port();
    // A vendor's private class: its views keep the thickness in a private
    // tag of their own creator.
    std::fs::write(
        d.join("acme.toml"),
        "name = \"ACME DBT\"\nlayout = \"per-view\"\n[tags]\nBodyPartThickness = \"0019,1012\"\n[creators]\n\"0019,0010\" = \"ACME DBT\"\n",
    )
    .unwrap();
    let cfg = config(
        d,
        dport,
        flux,
        tube,
        QUIET_S,
        &format!(
            "[[dicom_input.private_class]]\nsop_class = \"{PRIVATE}\"\nmapping = \"acme.toml\""
        ),
    );
    let daemon = start_daemon(&cfg, &d.join("daemon.log"));
    wait_for_status(d, "the daemon", LIMIT, |s| s["state"] == "waiting");

    // 1. 24 of the 25 views, by storescu in one association: kept, the
    // sweep waits (the status and dbtor-diag show it).
    let o = storescu(dport, &views[..24]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = wait_for_status(d, "24 views waiting", LIMIT, |s| {
        s["dicom_input"]["waiting"][0]["views_received"] == 24
            && s["dicom_input"]["associations_total"] == 1
            && s["dicom_input"]["associations_open"] == 0
    });
    assert_eq!(s["dicom_input"]["waiting"][0]["views_expected"], 25, "{s}");
    assert_eq!(s["dicom_input"]["objects_stored"], 24, "{s}");
    assert_eq!(s["dicom_input"]["last_association"][0], "MODALITY", "{s}");
    let diag = Command::new(workspace_bin("dbtor-diag"))
        .args(["status", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&diag.stdout);
    assert!(
        text.contains("24 of 25 views") && text.contains("listening as DBTOR@"),
        "{text}"
    );

    // 2. The bad objects while the sweep waits: each refused naming why,
    // kept in faulted/ (what was received), an input fault each.
    let mut expected_faults = 0;
    let mut refused = |file: Option<&Path>, want: &str| {
        if let Some(f) = file {
            let o = storescu(dport, &[f.to_path_buf()]);
            assert!(
                !o.status.success() || String::from_utf8_lossy(&o.stderr).contains("Status: Error"),
                "{want}: accepted\n{}",
                String::from_utf8_lossy(&o.stderr)
            );
        }
        expected_faults += 1;
        let s = wait_for_status(d, want, LIMIT, |s| {
            s["fault_counts"]["input"].as_u64() == Some(expected_faults)
        });
        let f = s["faults"].as_array().unwrap().last().unwrap().clone();
        assert!(f["message"].as_str().unwrap().contains(want), "{want}: {f}");
    };
    refused(Some(&presentation), "For Presentation");
    refused(Some(&no_thickness), "BodyPartThickness: missing");
    refused(Some(&rows), "PixelData");
    refused(Some(&other_pixels), "a second copy of view 4");
    // A transfer syntax the input does not decode (JPEG-LS lossless, as a
    // modality compressing its projections proposes it; dcmtk's storescu
    // would fall back to an uncompressed one): the presentation context is
    // refused at negotiation, so nothing is received and nothing kept; the
    // fault names the class and why.
    let e = Scu::connect_with(
        dport,
        &[dbt_dicom::dm::DM_FOR_PROCESSING_CLASS],
        "1.2.840.10008.1.2.4.80",
    )
    .err()
    .expect("a JPEG-LS context accepted");
    assert!(e.contains("NoAcceptedPresentationContexts"), "{e}");
    refused(None, "none of the proposed transfer syntaxes is accepted");
    // A truncated data set (a peer that lost its end).
    let (class, instance, bytes) = &truncated;
    let mut scu = Scu::connect(dport, &[class]);
    let status = scu.store(class, instance, &bytes[..bytes.len() - 5000]);
    scu.release();
    assert_eq!(status, 0xC000);
    refused(None, "data set unreadable");
    let kept = faulted(d);
    assert_eq!(kept.len(), 5, "{kept:?}");
    for k in &kept {
        let f: serde_json::Value =
            serde_json::from_slice(&std::fs::read(k.join("fault.json")).unwrap()).unwrap();
        assert!(!f["message"].as_str().unwrap().is_empty());
        assert!(k.join("object.dcm").is_file() || k.join("data-set.bin").is_file());
    }
    let s = daemon_status(d);
    assert_eq!(s["dicom_input"]["waiting"][0]["views_received"], 24, "{s}");
    assert_eq!(s["dicom_input"]["objects_refused"], 5, "{s}");

    // 3. Still serving: the 25th view completes the sweep; it is reported.
    let o = storescu(dport, &views[24..]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = wait_for_status(d, "the per-view report", LIMIT, |s| s["processed"] == 1);
    assert!(
        s["dicom_input"]["waiting"].as_array().unwrap().is_empty(),
        "{s}"
    );
    // The same views again: Success, nothing new.
    let o = storescu(dport, &views[..3]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    wait_for_status(d, "the duplicates counted", LIMIT, |s| {
        s["dicom_input"]["objects_duplicate"] == 3
    });

    // 4. A sweep that stays incomplete: faulted after the quiet time,
    // naming the missing views, its views kept.
    let o = storescu(dport, &views_b[..5]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    expected_faults += 1;
    let s = wait_for_status(d, "the incomplete sweep's fault", LIMIT, |s| {
        s["fault_counts"]["input"].as_u64() == Some(expected_faults)
    });
    let f = s["faults"].as_array().unwrap().last().unwrap().clone();
    let m = f["message"].as_str().unwrap();
    assert!(
        m.contains("incomplete sweep: 5 of 25 views") && m.contains("missing the views at"),
        "{m}"
    );
    let dcm_files = |k: &Path| {
        std::fs::read_dir(k)
            .unwrap()
            .flatten()
            .filter(|e| e.path().extension().is_some_and(|x| x == "dcm"))
            .count()
    };
    let sweep = faulted(d)
        .into_iter()
        .find(|k| dcm_files(k) == 5)
        .expect("the incomplete sweep's five views in faulted/");
    assert!(sweep.join("fault.json").is_file());

    // 5. The same sweep as one multi-frame object: the same glandularity,
    // the MGD within the Monte Carlo uncertainty.
    let o = Command::new(workspace_bin("host-sim"))
        .args(["dicom-send", "--acq"])
        .arg(&acq)
        .args(["--to", &format!("DBTOR@127.0.0.1:{dport}")])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    wait_for_status(d, "the multi-frame report", LIMIT, |s| s["processed"] == 2);
    let r: Vec<serde_json::Value> = {
        let mut ids: Vec<_> = std::fs::read_dir(d.join("spool/done"))
            .unwrap()
            .flatten()
            .map(|e| e.path())
            .collect();
        ids.sort();
        ids.iter()
            .map(|p| {
                serde_json::from_slice(&std::fs::read(p.join("result.json")).unwrap()).unwrap()
            })
            .collect()
    };
    assert_eq!(
        r[0]["glandularity_reported"], r[1]["glandularity_reported"],
        "{r:?}"
    );
    let (a, b) = (
        r[0]["mgd_mgy"].as_f64().unwrap(),
        r[1]["mgd_mgy"].as_f64().unwrap(),
    );
    assert!((a - b).abs() <= 3.0 * 0.05 * 2f64.sqrt() * a, "{a} vs {b}");
    // The per-view sweep's dose SR names its evidence as DM For Processing
    // and carries the objects' compression force and exposure time.
    let dose = std::fs::read_dir(d.join("output"))
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.to_string_lossy().ends_with("-dose-sr.dcm"))
        .min()
        .unwrap();
    let dump = Command::new("dsrdump").arg(&dose).output().unwrap();
    let dump = String::from_utf8_lossy(&dump.stdout);
    assert!(
        dump.contains("\"Compression Force\")=\"110\" (N,UCUM")
            && dump.contains("\"Exposure Time\")=\"60\" (ms,UCUM"),
        "{dump}"
    );
    let dump = Command::new("dcmdump").arg(&dose).output().unwrap();
    let dump = String::from_utf8_lossy(&dump.stdout);
    assert!(
        dump.lines().any(|l| l.contains("ReferencedSOPClassUID")
            && l.contains("=DigitalMammographyXRayImageStorageForProcessing")),
        "{dump}"
    );

    // 6. The same views as the vendor's private class (new instances, the
    // thickness moved to the vendor's tag, written as UN as an Implicit VR
    // sender's private tags arrive): read through the configured mapping,
    // reported alike.
    let thickness = text_of(tags::BODY_PART_THICKNESS);
    let private_dir = d.join("private");
    std::fs::create_dir_all(&private_dir).unwrap();
    let private: Vec<PathBuf> = views
        .iter()
        .enumerate()
        .map(|(k, v)| {
            let mut o = dicom_object::open_file(v).unwrap();
            let instance = format!("{}.{}", text_of(tags::SERIES_INSTANCE_UID), 900 + k);
            o.put(DataElement::new(tags::SOP_CLASS_UID, VR::UI, PRIVATE));
            o.put(DataElement::new(
                tags::SOP_INSTANCE_UID,
                VR::UI,
                instance.as_str(),
            ));
            o.remove_element(tags::BODY_PART_THICKNESS);
            o.remove_element(tags::PRESENTATION_INTENT_TYPE);
            o.put(DataElement::new(
                dicom_core::Tag(0x0019, 0x0010),
                VR::LO,
                "ACME DBT",
            ));
            let mut t = thickness.clone().into_bytes();
            if t.len() % 2 == 1 {
                t.push(b' ');
            }
            o.put(DataElement::new(
                dicom_core::Tag(0x0019, 0x1012),
                VR::UN,
                dicom_core::PrimitiveValue::U8(t.into()),
            ));
            o.meta_mut().media_storage_sop_class_uid = PRIVATE.to_string();
            o.meta_mut().media_storage_sop_instance_uid = instance;
            let p = private_dir.join(format!("view-{:02}.dcm", k + 1));
            o.write_to_file(&p).unwrap();
            p
        })
        .collect();
    // (dcmtk's storescu sends no class it does not know.)
    let mut scu = Scu::connect(dport, &[PRIVATE]);
    for f in &private {
        let (class, instance, bytes) = data_set(f);
        let status = scu.store(&class, &instance, &bytes);
        assert_eq!(status, 0, "{}: {}", f.display(), daemon_status(d)["faults"]);
    }
    scu.release();
    wait_for_status(d, "the private class's report", LIMIT, |s| {
        s["processed"] == 3
    });
    let done: Vec<PathBuf> = {
        let mut v: Vec<_> = std::fs::read_dir(d.join("spool/done"))
            .unwrap()
            .flatten()
            .map(|e| e.path())
            .collect();
        v.sort();
        v
    };
    let r2: serde_json::Value =
        serde_json::from_slice(&std::fs::read(done[2].join("result.json")).unwrap()).unwrap();
    assert_eq!(r2["glandularity_reported"], r[0]["glandularity_reported"]);
    let g: serde_json::Value =
        serde_json::from_slice(&std::fs::read(done[2].join("gantry.json")).unwrap()).unwrap();
    assert_eq!(g["sop_class"], PRIVATE, "{g}");
    daemon.stop();
}

/// SIGKILL while an association is sending the views: every view answered
/// Success is in the spool after the restart, the sweep waits for the rest,
/// and the modality's resend of all 25 (duplicates answered Success)
/// completes it.
#[test]
fn sigkill_mid_association_loses_no_view_answered_success() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let acq = hil_tests::acquire(d, 2);
    let (flux, tube) = header(&acq);
    let dport = free_port();
    let cfg = config(d, dport, flux, tube, 120.0, "");
    let daemon = start_daemon(&cfg, &d.join("daemon-1.log"));
    wait_for_status(d, "the daemon", LIMIT, |s| s["state"] == "waiting");
    let views = views_of(&acq, &d.join("views"));
    let objects: Vec<_> = views.iter().map(|v| data_set(v)).collect();
    let mut scu = Scu::connect(dport, &[&objects[0].0]);
    let mut answered = Vec::new();
    for (class, instance, bytes) in &objects[..8] {
        assert_eq!(scu.store(class, instance, bytes), 0, "{instance}");
        answered.push(instance.clone());
    }
    // Killed in the middle of the association.
    assert!(Command::new("kill")
        .args(["-KILL", &daemon.id().to_string()])
        .status()
        .unwrap()
        .success());
    drop(daemon);
    drop(scu);
    // Every view answered Success is on disk.
    let kept: Vec<PathBuf> = std::fs::read_dir(d.join("spool/views"))
        .unwrap()
        .flatten()
        .flat_map(|g| {
            std::fs::read_dir(g.path())
                .unwrap()
                .flatten()
                .map(|e| e.path())
        })
        .filter(|p| p.extension().is_some_and(|x| x == "dcm"))
        .collect();
    assert_eq!(kept.len(), answered.len(), "{kept:?}");
    // Restarted: the sweep waits with its 8 views.
    let daemon = start_daemon(&cfg, &d.join("daemon-2.log"));
    let s = wait_for_status(d, "the reloaded sweep", LIMIT, |s| {
        s["state"] == "waiting" && s["dicom_input"]["waiting"][0]["views_received"] == 8
    });
    assert_eq!(s["processed"], 0, "{s}");
    // The modality sends all 25 again: 8 duplicates, 17 new, one sweep.
    let o = storescu(dport, &views);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = wait_for_status(d, "the sweep's report", LIMIT, |s| s["processed"] == 1);
    assert_eq!(s["dicom_input"]["objects_duplicate"], 8, "{s}");
    assert_eq!(s["dicom_input"]["objects_stored"], 17, "{s}");
    assert!(faulted(d).is_empty());
    assert_eq!(
        daemon_status(d)["fault_counts"]["input"],
        serde_json::Value::Null
    );
    daemon.stop();
}
