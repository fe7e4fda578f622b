//! Every report passes dciodvfy (dicom3tools: no line starting "Error") and
//! dsrdump (dcmtk: exit 0, no error), and a deliberately broken report is
//! caught by the same check. Needs the Debian packages dicom3tools and dcmtk
//! (`.ci/run` installs them); a missing validator fails the test.

use dbt_dicom::*;
use dicom_dictionary_std::tags;
use std::path::Path;
use std::process::Command;

fn header() -> Header {
    Header {
        patient_name: "Doe^Jane".into(),
        patient_id: "P-0001".into(),
        patient_birth_date: "19700101".into(),
        patient_sex: "F".into(),
        study_uid: "1.2.826.0.1.3680043.10.543.77.1".into(),
        study_date: "20261122".into(),
        study_time: "101500".into(),
        study_id: "S1".into(),
        accession_number: "A123".into(),
        referring_physician: "".into(),
        laterality: Laterality::Left,
        source_series_uid: "1.2.826.0.1.3680043.10.543.77.2".into(),
        source_instance_uids: (1..=25)
            .map(|i| format!("1.2.826.0.1.3680043.10.543.77.3.{i}"))
            .collect(),
    }
}

fn equipment() -> Equipment {
    Equipment {
        manufacturer: "DBToR Medical".into(),
        model: "DBToR gantry PC".into(),
        serial: "SN-0001".into(),
        software_version: "0.1.0".into(),
        device_uid: "1.2.826.0.1.3680043.10.543.77.9".into(),
    }
}

pub fn dose_input() -> DoseInput {
    DoseInput {
        header: header(),
        equipment: equipment(),
        events: (0..25)
            .map(|i| {
                let a = -24.0 + 2.0 * i as f64;
                DoseEvent {
                    angle_start_deg: a - 1.0,
                    angle_end_deg: a + 1.0,
                    kvp: 28.0,
                    exposure_uas: 2000.0,
                    agd_mgy: 0.0571234567891234,
                    entrance_kerma_mgy: 0.21,
                    datetime: format!("202611221015{:02}", i),
                }
            })
            .collect(),
        compression_mm: 44.0,
        hvl_mm_al: 0.53,
        filter_rh_mm: 0.0587,
        accumulated_agd_mgy: 1.428,
        relative_uncertainty: 0.0072,
        model_agd_mgy: 1.84,
        content_date: "20261122".into(),
        content_time: "102000".into(),
    }
}

pub fn density_input() -> DensityInput {
    DensityInput {
        header: header(),
        equipment: equipment(),
        glandularity: 0.2345,
        fibroglandular_cm3: 120.5,
        breast_cm3: 610.0,
        reconstructor: "DBToR int8".into(),
        model_version: "dbtor-fp32 sha256:0123abcd".into(),
        content_date: "20261122".into(),
        content_time: "102000".into(),
    }
}

/// Run both validators; returns the problems found (empty: valid).
fn validate(path: &Path) -> Vec<String> {
    let mut problems = Vec::new();
    let out = Command::new("dciodvfy")
        .arg(path)
        .output()
        .expect("dciodvfy not found: apt-get install dicom3tools");
    let text =
        String::from_utf8_lossy(&out.stderr).to_string() + &String::from_utf8_lossy(&out.stdout);
    problems.extend(
        text.lines()
            .filter(|l| l.starts_with("Error"))
            .map(|l| format!("dciodvfy: {l}")),
    );
    let out = Command::new("dsrdump")
        .arg(path)
        .output()
        .expect("dsrdump not found: apt-get install dcmtk");
    let err = String::from_utf8_lossy(&out.stderr);
    if !out.status.success() {
        problems.push(format!("dsrdump exit {:?}: {err}", out.status.code()));
    }
    problems.extend(
        err.lines()
            .filter(|l| l.contains("E:") || l.to_lowercase().contains("error"))
            .map(|l| format!("dsrdump: {l}")),
    );
    problems
}

#[test]
fn reports_pass_dciodvfy_and_dsrdump_and_broken_ones_do_not() {
    let dir = tempfile::tempdir().unwrap();
    let mut uids = UidSource::new("1.2.826.0.1.3680043.10.543", 42).unwrap();
    let dose = dose_report(&dose_input(), &mut uids).unwrap();
    let dens = density_report(&density_input(), &mut uids).unwrap();
    for (name, r) in [("dose.dcm", &dose), ("density.dcm", &dens)] {
        if let Ok(d) = std::env::var("DBT_DICOM_KEEP") {
            std::fs::write(Path::new(&d).join(name), r.to_bytes().unwrap()).unwrap();
        }
        let p = dir.path().join(name);
        std::fs::write(&p, r.to_bytes().unwrap()).unwrap();
        let problems = validate(&p);
        assert!(problems.is_empty(), "{name}:\n{}", problems.join("\n"));
    }
    // Broken on purpose: no Patient ID (type 1... 2 in Patient module; and no
    // Value Type at the root, which both validators require).
    let mut broken = dose_report(&dose_input(), &mut uids).unwrap();
    broken.dataset_mut().remove_element(tags::VALUE_TYPE);
    broken.dataset_mut().remove_element(tags::SOP_CLASS_UID);
    let p = dir.path().join("broken.dcm");
    std::fs::write(&p, broken.to_bytes().unwrap()).unwrap();
    assert!(
        !validate(&p).is_empty(),
        "the broken report passed the check"
    );
}

#[test]
fn values_read_back() {
    let mut uids = UidSource::new("1.2.826.0.1.3680043.10.543", 7).unwrap();
    let r = dose_report(&dose_input(), &mut uids).unwrap();
    let (class, values) = read_values(&r.to_bytes().unwrap()).unwrap();
    assert_eq!(class, "1.2.840.10008.5.1.4.1.1.88.67");
    let get = |k: &str| {
        values
            .iter()
            .filter(|(n, _)| n == k)
            .map(|(_, v)| v.clone())
            .collect::<Vec<_>>()
    };
    assert_eq!(
        get("Accumulated Average Glandular Dose"),
        vec!["1.428 mGy".to_string()]
    );
    assert_eq!(get("Average Glandular Dose").len(), 25);
    // DS values within 16 characters.
    assert!(get("Average Glandular Dose")
        .iter()
        .all(|v| v.split(' ').next().unwrap().len() <= 16));
    assert_eq!(
        get("Model-breast Accumulated Average Glandular Dose"),
        vec!["1.84 mGy".to_string()]
    );
    assert_eq!(get("Laterality")[0], "Left");
    let r = density_report(&density_input(), &mut uids).unwrap();
    let (class, values) = read_values(&r.to_bytes().unwrap()).unwrap();
    assert_eq!(class, "1.2.840.10008.5.1.4.1.1.88.33");
    let get = |k: &str| {
        values
            .iter()
            .find(|(n, _)| n == k)
            .map(|(_, v)| v.clone())
            .unwrap()
    };
    assert_eq!(get("Percent Fibroglandular Tissue"), "23.45 Percent");
    // 120.5 / 610 = 19.8 % by volume: extremely dense with our thresholds.
    assert_eq!(get("Breast composition"), "Extremely dense");
    assert_eq!(get("Algorithm Version"), "dbtor-fp32 sha256:0123abcd");
}

#[test]
fn bad_inputs_are_named() {
    let mut uids = UidSource::new("1.2.826.0.1.3680043.10.543", 1).unwrap();
    let mut d = dose_input();
    d.header.study_uid = "1.2.03".into();
    let e = dose_report(&d, &mut uids).err().unwrap().to_string();
    assert!(e.contains("header.study_uid"), "{e}");
    let mut d = dose_input();
    d.header.accession_number = "SIM8177500879482156470".into();
    let e = dose_report(&d, &mut uids).err().unwrap().to_string();
    assert!(e.contains("header.accession_number"), "{e}");
    let mut d = dose_input();
    d.events[3].datetime = String::new();
    assert!(dose_report(&d, &mut uids)
        .err()
        .unwrap()
        .to_string()
        .contains("events.datetime"));
    let mut d = dose_input();
    d.events.clear();
    assert!(dose_report(&d, &mut uids)
        .err()
        .unwrap()
        .to_string()
        .contains("events"));
    let mut d = density_input();
    d.fibroglandular_cm3 = 1e4;
    assert!(density_report(&d, &mut uids)
        .err()
        .unwrap()
        .to_string()
        .contains("fibroglandular_cm3"));
    assert!(UidSource::new("1.2.abc", 1).is_err());
    assert_eq!(composition_category(0.03).0, 'a');
    assert_eq!(composition_category(0.06).0, 'b');
    assert_eq!(composition_category(0.10).0, 'c');
    assert_eq!(composition_category(0.30).0, 'd');
}
