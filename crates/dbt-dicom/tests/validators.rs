//! Every report passes dciodvfy (dicom3tools: no line starting "Error") and
//! dsrdump (dcmtk: exit 0, no error), and a deliberately broken report is
//! caught by the same check. Needs the Debian packages dicom3tools and dcmtk
//! (`scripts/install-test-deps.sh` installs them); a missing validator fails the test.

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
        source_class: dbt_dicom::projections::BPXR_FOR_PROCESSING_CLASS.into(),
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

/// [`dose_input`] of a W/Ag sweep: silver (CID 10006, SCT 41967008), its
/// solved thickness and the Giotto's HVL at 28 kV.
fn w_ag_dose_input() -> DoseInput {
    DoseInput {
        anode_material: dbt_dicom::AnodeMaterial::Tungsten,
        filter_material: dbt_dicom::FilterMaterial::Silver,
        filter_mm: 0.059,
        hvl_mm_al: 0.56,
        ..dose_input()
    }
}

/// [`dose_input`] of a Mo/Mo sweep (GE's molybdenum anode and filter):
/// both CID 10016's and CID 10006's molybdenum (SCT 71128006), the solved
/// filter and EUREF's typical HVL at 28 kV.
fn mo_mo_dose_input() -> DoseInput {
    DoseInput {
        anode_material: dbt_dicom::AnodeMaterial::Molybdenum,
        filter_material: dbt_dicom::FilterMaterial::Molybdenum,
        filter_mm: 0.0484,
        hvl_mm_al: 0.36,
        ..dose_input()
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
                    exposure_ms: Some(60.0),
                    agd_mgy: 0.0571234567891234,
                    entrance_kerma_mgy: 0.21,
                    datetime: format!("202611221015{:02}", i),
                }
            })
            .collect(),
        compression_mm: 44.0,
        compression_force_n: Some(110.0),
        hvl_mm_al: 0.53,
        anode_material: dbt_dicom::AnodeMaterial::Tungsten,
        filter_material: dbt_dicom::FilterMaterial::Rhodium,
        filter_mm: 0.0587,
        accumulated_agd_mgy: 1.428,
        relative_uncertainty: 0.0072,
        model_agd_mgy: 1.84,
        model_agd_at_physics_mgy: None,
        agd_interval: dbt_dicom::FigureInterval {
            limits: Some([1.27, 1.61]),
            basis: "95 % prediction interval from 27 validation breasts (thickness 45-60 mm, \
                    reported glandularity below 30 %): estimate over truth +0.4 % on average"
                .into(),
        },
        content_date: "20261122".into(),
        content_time: "102000".into(),
        intent: ProcedureIntent::Diagnostic,
        source_distances_mm: [650.0, 700.0],
        algorithm_version: "model test (manifest sha256:0123abcd), fp32 on the fast engine".into(),
        method: dbt_dicom::ReportMethod::Reconstruction,
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
        check: dbt_dicom::DensityCheckReport {
            physics_glandularity: Some(0.25),
            confirmed: true,
            reasons: vec![],
        },
        method: dbt_dicom::ReportMethod::Reconstruction,
        glandularity_interval: dbt_dicom::FigureInterval {
            limits: Some([0.201, 0.289]),
            basis: "95 % prediction interval from 27 validation breasts (thickness 45-60 mm, \
                    reported glandularity below 30 %): reported minus true glandularity -2.1 pp \
                    on average, s.d. 2.0 pp"
                .into(),
        },
        content_date: "20261122".into(),
        content_time: "102000".into(),
    }
}

/// A density the physics density did not confirm.
pub fn unconfirmed_density_input() -> DensityInput {
    DensityInput {
        check: dbt_dicom::DensityCheckReport {
            physics_glandularity: Some(0.41),
            confirmed: false,
            reasons: vec![
                "the reported glandularity and the physics density disagree by -17.5 pp (limit 14)"
                    .into(),
            ],
        },
        glandularity_interval: unconfirmed_interval(),
        ..density_input()
    }
}

/// Its dose report: the model breast at the physics density beside.
pub fn unconfirmed_dose_input() -> DoseInput {
    DoseInput {
        model_agd_at_physics_mgy: Some(1.71),
        agd_interval: unconfirmed_interval(),
        ..dose_input()
    }
}

/// A physics-only density report (issue #51 point 3: no model for the
/// gantry), its estimate's own checks not passed.
pub fn physics_only_density_input() -> DensityInput {
    DensityInput {
        glandularity: 0.41,
        fibroglandular_cm3: 80.0,
        reconstructor: "none: physics-based density (no DBToR model trained and calibrated for this gantry and beam; model breast central columns)".into(),
        check: dbt_dicom::DensityCheckReport {
            physics_glandularity: Some(0.41),
            confirmed: false,
            reasons: vec!["physics density: the views disagree by 6.4 pp".into()],
        },
        glandularity_interval: physics_only_interval(),
        method: dbt_dicom::ReportMethod::PhysicsOnly,
        ..density_input()
    }
}

/// Its dose report: the model breast's AGD on the gantry's geometry.
pub fn physics_only_dose_input() -> DoseInput {
    DoseInput {
        model_agd_mgy: 1.44,
        accumulated_agd_mgy: 1.44,
        agd_interval: physics_only_interval(),
        method: dbt_dicom::ReportMethod::PhysicsOnly,
        ..dose_input()
    }
}

/// What a physics-only report says of its intervals.
pub fn physics_only_interval() -> dbt_dicom::FigureInterval {
    dbt_dicom::FigureInterval {
        limits: None,
        basis: "a physics-only report (no DBToR model trained and calibrated for this gantry and beam): no validation residuals"
            .into(),
    }
}

/// What an unconfirmed density's reports say of their intervals.
pub fn unconfirmed_interval() -> dbt_dicom::FigureInterval {
    dbt_dicom::FigureInterval {
        limits: None,
        basis: "the density is not confirmed by the physics-based density, so the validation \
                residuals are not known to describe this breast"
            .into(),
    }
}

/// The density SR asserts a composition category only where the physics
/// confirms the density; otherwise it says so, with both figures and the
/// reason, and the dose SR gives the model breast at the physics density.
/// An unconfirmed density without a reason is refused.
#[test]
fn an_unconfirmed_density_report_has_no_category_and_says_why() {
    let mut uids = UidSource::new("1.2.826.0.1.3680043.10.543", 43).unwrap();
    let values = |r: dbt_dicom::Report| read_values(&r.to_bytes().unwrap()).unwrap().1;
    let get =
        |v: &[(String, String)], k: &str| v.iter().find(|(n, _)| n == k).map(|(_, s)| s.clone());
    let ok = values(density_report(&density_input(), &mut uids).unwrap());
    assert_eq!(
        get(&ok, "Breast composition").as_deref(),
        Some("Extremely dense")
    );
    assert_eq!(
        get(&ok, "Percent Fibroglandular Tissue, physics-based").as_deref(),
        Some("25 Percent")
    );
    assert_eq!(
        get(&ok, "Density cross-check").as_deref(),
        Some("Confirmed by the physics-based density")
    );
    let bad = values(density_report(&unconfirmed_density_input(), &mut uids).unwrap());
    assert_eq!(get(&bad, "Breast composition"), None);
    assert_eq!(
        get(&bad, "Density cross-check").as_deref(),
        Some("Not confirmed by the physics-based density")
    );
    let why = get(&bad, "Why the density is not confirmed").unwrap();
    assert!(
        why.contains(&format!(
            "Reported (DBToR) {:.1} %, physics-based 41.0 %",
            23.45
        )) && why.contains("-17.5 pp"),
        "{why}"
    );
    let dose = values(dose_report(&unconfirmed_dose_input(), &mut uids).unwrap());
    assert_eq!(
        get(&dose, "Model-breast AGD at the physics-based density").as_deref(),
        Some("1.71 mGy")
    );
    assert_eq!(
        get(
            &values(dose_report(&dose_input(), &mut uids).unwrap()),
            "Model-breast AGD at the physics-based density"
        ),
        None
    );
    let mut silent = unconfirmed_density_input();
    silent.check.reasons.clear();
    let e = density_report(&silent, &mut uids)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("check.reasons"), "{e}");
    let mut impossible = density_input();
    impossible.check.physics_glandularity = Some(1.3);
    let e = density_report(&impossible, &mut uids)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("check.physics_glandularity"), "{e}");
}

/// A physics-only report (issue #51 point 3) names its method in both
/// SRs, gives the physics-based figure, no composition category, and why;
/// its dose comment says the AGD is the model breast's on the gantry.
#[test]
fn a_physics_only_report_names_its_method_and_gives_no_category() {
    let mut uids = UidSource::new("1.2.826.0.1.3680043.10.543", 45).unwrap();
    let values = |r: dbt_dicom::Report| read_values(&r.to_bytes().unwrap()).unwrap().1;
    let get =
        |v: &[(String, String)], k: &str| v.iter().find(|(n, _)| n == k).map(|(_, s)| s.clone());
    let d = values(density_report(&physics_only_density_input(), &mut uids).unwrap());
    assert_eq!(get(&d, "Breast composition"), None, "{d:?}");
    assert!(get(&d, "Density cross-check")
        .unwrap()
        .contains("Physics-based density alone"));
    let why = get(&d, "Why no composition category is given").unwrap();
    assert!(
        why.contains("No DBToR model") && why.contains("views disagree"),
        "{why}"
    );
    assert!(get(&d, "Algorithm Name")
        .unwrap()
        .contains("physics-based density"));
    let m = values(dose_report(&physics_only_dose_input(), &mut uids).unwrap());
    let comment = get(&m, "Comment").unwrap();
    assert!(
        comment.contains("No DBToR model is trained and calibrated for this gantry and beam")
            && comment.contains("not patient-specific"),
        "{comment}"
    );
    // The same inputs as a reconstruction's report keep its category.
    let d = values(
        density_report(
            &DensityInput {
                check: dbt_dicom::DensityCheckReport {
                    confirmed: true,
                    reasons: vec![],
                    physics_glandularity: Some(0.41),
                },
                method: dbt_dicom::ReportMethod::Reconstruction,
                ..physics_only_density_input()
            },
            &mut uids,
        )
        .unwrap(),
    );
    assert!(get(&d, "Breast composition").is_some(), "{d:?}");
}

/// Both figures carry their 95 % interval and what it rests on; a report
/// without one says why; an interval out of order, out of range or without
/// its basis is refused naming the field. (Both SRs with and without
/// intervals go through dciodvfy, dsrdump and PixelMed in the tests above:
/// `density_input`/`dose_input` have them, the unconfirmed ones not.)
#[test]
fn reports_carry_each_figures_95_percent_interval() {
    let mut uids = UidSource::new("1.2.826.0.1.3680043.10.543", 44).unwrap();
    let values = |r: dbt_dicom::Report| read_values(&r.to_bytes().unwrap()).unwrap().1;
    let get =
        |v: &[(String, String)], k: &str| v.iter().find(|(n, _)| n == k).map(|(_, s)| s.clone());
    let d = values(density_report(&density_input(), &mut uids).unwrap());
    assert_eq!(
        get(
            &d,
            "Percent Fibroglandular Tissue, 95 % interval, lower limit"
        )
        .as_deref(),
        Some("20.1 Percent")
    );
    assert_eq!(
        get(
            &d,
            "Percent Fibroglandular Tissue, 95 % interval, upper limit"
        )
        .as_deref(),
        Some("28.9 Percent")
    );
    let basis = get(&d, "Percent Fibroglandular Tissue, 95 % interval, basis").unwrap();
    assert!(
        basis.starts_with("95 % prediction interval from 27 validation breasts"),
        "{basis}"
    );
    let m = values(dose_report(&dose_input(), &mut uids).unwrap());
    assert_eq!(
        get(&m, "Accumulated AGD, 95 % interval, lower limit").as_deref(),
        Some("1.27 mGy")
    );
    assert_eq!(
        get(&m, "Accumulated AGD, 95 % interval, upper limit").as_deref(),
        Some("1.61 mGy")
    );
    // None given: no limits, the reason.
    let d = values(density_report(&unconfirmed_density_input(), &mut uids).unwrap());
    assert_eq!(
        get(
            &d,
            "Percent Fibroglandular Tissue, 95 % interval, lower limit"
        ),
        None
    );
    let why = get(&d, "Percent Fibroglandular Tissue, 95 % interval, basis").unwrap();
    assert!(
        why.starts_with("No 95 % interval is given: the density is not confirmed"),
        "{why}"
    );
    let m = values(dose_report(&unconfirmed_dose_input(), &mut uids).unwrap());
    assert_eq!(get(&m, "Accumulated AGD, 95 % interval, upper limit"), None);
    assert!(get(&m, "Accumulated AGD, 95 % interval, basis")
        .unwrap()
        .starts_with("No 95 % interval is given"));
    // Refused: limits reversed, a glandularity beyond 1, no basis.
    for (iv, field) in [
        (Some([0.3, 0.2]), "glandularity_interval"),
        (Some([0.2, 1.3]), "glandularity_interval"),
        (None, "glandularity_interval"),
    ] {
        let mut bad = density_input();
        bad.glandularity_interval = dbt_dicom::FigureInterval {
            limits: iv,
            basis: if iv.is_some() { "x".into() } else { " ".into() },
        };
        let e = density_report(&bad, &mut uids).err().unwrap().to_string();
        assert!(e.contains(field), "{e}");
    }
    let mut bad = dose_input();
    bad.agd_interval.limits = Some([f64::NAN, 1.0]);
    let e = dose_report(&bad, &mut uids).err().unwrap().to_string();
    assert!(e.contains("agd_interval"), "{e}");
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
    // The reports of a density the physics did not confirm (issue #48
    // point 3): no category, the reason, the model breast at the physics
    // density.
    let dose_unconfirmed = dose_report(&unconfirmed_dose_input(), &mut uids).unwrap();
    let dens_unconfirmed = density_report(&unconfirmed_density_input(), &mut uids).unwrap();
    // A physics-only pair (issue #51 point 3).
    let dose_physics = dose_report(&physics_only_dose_input(), &mut uids).unwrap();
    let dens_physics = density_report(&physics_only_density_input(), &mut uids).unwrap();
    // A W/Ag sweep (issue #51 point 2): the silver filter's code.
    let dose_w_ag = dose_report(&w_ag_dose_input(), &mut uids).unwrap();
    // A Mo/Mo sweep: molybdenum's code as anode and as filter.
    let dose_mo_mo = dose_report(&mo_mo_dose_input(), &mut uids).unwrap();
    for (name, r) in [
        ("dose.dcm", &dose),
        ("density.dcm", &dens),
        ("dose-unconfirmed.dcm", &dose_unconfirmed),
        ("density-unconfirmed.dcm", &dens_unconfirmed),
        ("dose-physics.dcm", &dose_physics),
        ("density-physics.dcm", &dens_physics),
        ("dose-w-ag.dcm", &dose_w_ag),
        ("dose-mo-mo.dcm", &dose_mo_mo),
    ] {
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
    // The accumulated dose's side from CID 6022, the events' anatomy from CID 244.
    assert_eq!(get("Laterality")[0], "Left breast");
    assert_eq!(get("Laterality")[1], "Left");
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

/// The dose SR meets its templates (TID 10001, 1002, 10002, 10005, 10003,
/// 10003B, 10003C) by our template-level check, and the check catches each
/// defect an independent SR validator found in earlier reports: the
/// Procedure reported without Has Intent, the Scope of Accumulation related
/// by CONTAINS, no Source of Dose Information, a CID 244 laterality where
/// TID 10005 wants CID 6022; and an event without its Number of Pulses.
#[test]
fn dose_report_meets_its_templates_and_each_known_defect_is_caught() {
    use dbt_dicom::templates::{check_dose_report, read_tree, Coded, Node};
    let mut uids = UidSource::new("1.2.826.0.1.3680043.10.543", 42).unwrap();
    let bytes = dose_report(&dose_input(), &mut uids)
        .unwrap()
        .to_bytes()
        .unwrap();
    let good = read_tree(&bytes).unwrap();
    let v = check_dose_report(&good);
    assert!(v.is_empty(), "{}", v.join("\n"));
    assert_eq!(
        good.named("113706", "DCM").count(),
        25,
        "one event per view"
    );

    let find = |n: &mut Node, v: &str| -> usize {
        n.children.iter().position(|c| c.is(v, "DCM")).unwrap()
    };
    type Break<'a> = Box<dyn Fn(&mut Node) + 'a>;
    let defects: Vec<(&str, Break)> = vec![
        (
            "TID 10001 row 3",
            Box::new(|n: &mut Node| {
                let i = find(n, "121058");
                n.children[i].children.clear();
            }),
        ),
        (
            "TID 10001 row 6",
            Box::new(|n: &mut Node| {
                let i = find(n, "113705");
                n.children[i].relationship = "CONTAINS".into();
            }),
        ),
        (
            "TID 10001 row 18",
            Box::new(|n: &mut Node| {
                let i = find(n, "113854");
                n.children.remove(i);
            }),
        ),
        (
            "TID 10005 row 2",
            Box::new(|n: &mut Node| {
                let i = find(n, "113702");
                let acc = &mut n.children[i];
                let j = acc
                    .children
                    .iter()
                    .position(|c| c.is("111637", "DCM"))
                    .unwrap();
                acc.children[j].children[0].code = Some(Coded {
                    value: "7771000".into(),
                    scheme: "SCT".into(),
                    meaning: "Left".into(),
                });
            }),
        ),
        (
            "TID 10003B row 7",
            Box::new(|n: &mut Node| {
                let i = find(n, "113706");
                n.children[i].children.retain(|c| !c.is("113768", "DCM"));
            }),
        ),
    ];
    for (row, break_it) in defects {
        let mut t = good.clone();
        break_it(&mut t);
        let v = check_dose_report(&t);
        assert!(
            v.iter().any(|m| m.starts_with(row)),
            "{row} not caught: {v:?}"
        );
    }
}

/// PixelMed's DicomSRValidator (Debian libpixelmed-java; `scripts/install-test-deps.sh` installs
/// it), an SR validator independent of ours, finds no template error in the
/// dose SR, except where its value sets predate the current edition: its
/// CID 10006 and 10016 (2022 build) know the metals only by the retired
/// "X or X compound" codes, where PS3.16 2024 lists the elements (Rhodium
/// 59801003, Silver 41967008, Tungsten 26194003, as pydicom 3.0's tables of
/// that edition do).
#[test]
fn dose_report_passes_pixelmed_sr_validation() {
    let jar = Path::new("/usr/share/java/pixelmed.jar");
    assert!(
        jar.is_file(),
        "PixelMed not found: apt-get install libpixelmed-java (scripts/install-test-deps.sh installs it)"
    );
    // The full 25-event sweep once; the unconfirmed and physics-only
    // reports differ from it above the events (their intervals, the model
    // breast at the physics density, the method), so they are validated on
    // a 3-event sweep: PixelMed's templates are slow on a 25-event report
    // on a 2-core CI machine, even with Saxon (issue #52 point 7).
    let three_events = |mut d: DoseInput| {
        d.events.truncate(3);
        d
    };
    for input in [
        dose_input(),
        three_events(unconfirmed_dose_input()),
        three_events(physics_only_dose_input()),
        three_events(w_ag_dose_input()),
        three_events(mo_mo_dose_input()),
    ] {
        pixelmed_validates_dose(jar, &input);
    }
}

/// PixelMed's validator finds no error in either density SR (confirmed,
/// and without a category); its warnings are our items outside any
/// template (the report claims none: its content is ours).
#[test]
fn density_reports_pass_pixelmed_sr_validation() {
    let jar = Path::new("/usr/share/java/pixelmed.jar");
    assert!(
        jar.is_file(),
        "PixelMed not found: apt-get install libpixelmed-java (scripts/install-test-deps.sh installs it)"
    );
    let dir = tempfile::tempdir().unwrap();
    let mut uids = UidSource::new("1.2.826.0.1.3680043.10.543", 44).unwrap();
    for (i, input) in [
        density_input(),
        unconfirmed_density_input(),
        physics_only_density_input(),
    ]
    .iter()
    .enumerate()
    {
        let p = dir.path().join(format!("density-{i}.dcm"));
        std::fs::write(
            &p,
            density_report(input, &mut uids)
                .unwrap()
                .to_bytes()
                .unwrap(),
        )
        .unwrap();
        let text = pixelmed(jar, &p);
        assert!(
            text.contains("Found ComprehensiveSR IOD") && text.contains("IOD validation complete"),
            "validator did not run: {text}"
        );
        let errors: Vec<&str> = text.lines().filter(|l| l.starts_with("Error")).collect();
        assert!(errors.is_empty(), "{}", errors.join("\n"));
    }
}

/// Saxon-HE (Debian libsaxonhe-java; `scripts/install-test-deps.sh` installs it): the XSLT
/// processor PixelMed's own validation scripts name instead of the JDK's
/// Xalan, and faster on the dose SRs (issue #52 point 7). Its output here
/// was Xalan's, line for line, on every report the tests validate.
const SAXON_JAR: &str = "/usr/share/java/Saxon-HE.jar";

/// PixelMed's DicomSRValidator's output (stdout and stderr) on `file`.
fn pixelmed(jar: &Path, file: &Path) -> String {
    let saxon = Path::new(SAXON_JAR);
    assert!(
        saxon.is_file(),
        "Saxon-HE not found at {SAXON_JAR}: apt-get install libsaxonhe-java (scripts/install-test-deps.sh installs it)"
    );
    let mut classpath = jar.as_os_str().to_owned();
    classpath.push(":");
    classpath.push(saxon);
    let out = Command::new("java")
        .args([
            // A short run: the JVM's first-tier compiler only and its serial
            // collector cut its CPU time about threefold (9.5 -> 3.5 s a
            // report on the Intel Xeon; docs/benchmarks.md, "CI time"), the
            // validator's output unchanged byte for byte.
            "-XX:TieredStopAtLevel=1",
            "-XX:+UseSerialGC",
            // PixelMed's compiled templates exceed the JDK's default XPath limits.
            "-Djdk.xml.xpathExprOpLimit=0",
            "-Djdk.xml.xpathExprGrpLimit=0",
            "-Djdk.xml.xpathTotalOpLimit=0",
            "-Djavax.xml.transform.TransformerFactory=net.sf.saxon.TransformerFactoryImpl",
            "-cp",
        ])
        .arg(classpath)
        .arg("com.pixelmed.validate.DicomSRValidator")
        .arg(file)
        .output()
        .expect("java (default-jre-headless)");
    String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr)
}

fn pixelmed_validates_dose(jar: &Path, input: &DoseInput) {
    let dir = tempfile::tempdir().unwrap();
    let mut uids = UidSource::new("1.2.826.0.1.3680043.10.543", 42).unwrap();
    let p = dir.path().join("dose.dcm");
    std::fs::write(
        &p,
        dose_report(input, &mut uids).unwrap().to_bytes().unwrap(),
    )
    .unwrap();
    let text = pixelmed(jar, &p);
    assert!(
        text.contains("Found Root Template TID_10001"),
        "validator did not run: {text}"
    );
    let errors: Vec<&str> = text
        .lines()
        .filter(|l| l.starts_with("Error"))
        .filter(|l| {
            !(l.contains("(59801003,SCT,\"Rhodium\") not found in context group 10006")
                || l.contains("(41967008,SCT,\"Silver\") not found in context group 10006")
                || l.contains("(26194003,SCT,\"Tungsten\") not found in context group 10016")
                || l.contains("(71128006,SCT,\"Molybdenum\") not found in context group 100"))
        })
        .collect();
    assert!(errors.is_empty(), "{}", errors.join("\n"));
    // Its warnings are our two private NUMs in the (extensible) TID 10002,
    // and Compression Force: row 10a of TID 10003C since CP-1770 (PS3.16
    // 2019b, with Compression Pressure and Contact Area; OpenREM reads it
    // there, its issue #914), which PixelMed's templates predate.
    let warnings: Vec<&str> = text.lines().filter(|l| l.starts_with("Warning")).collect();
    assert!(
        warnings.iter().all(|w| w.contains("99DBTOR")
            || w.contains("NUM (111647,DCM,\"Compression Force\"): Content Item not in template")),
        "{}",
        warnings.join("\n")
    );
}

/// A projection set of `rows x columns` frames at the paper's 25 angles.
fn projection_set<'a>(
    h: &'a Header,
    eq: &'a Equipment,
    angles: &'a [f64],
    counts: &'a [u16],
    rows: usize,
    columns: usize,
) -> dbt_dicom::projections::ProjectionSet<'a> {
    dbt_dicom::projections::ProjectionSet {
        header: h,
        equipment: eq,
        rows,
        columns,
        pixel_spacing_mm: [0.8, 0.8],
        angles_deg: angles,
        source_to_detector_mm: 700.0,
        source_to_isocenter_mm: 650.0,
        thickness_mm: 45.0,
        compression_force_n: 110.0,
        support_to_detector_mm: 5.0,
        exposure_ms_per_view: 60.0,
        view_interval_ms: 150.0,
        modality_agd_mgy: 1.6,
        entrance_dose_mgy: 6.6,
        kvp: 29.0,
        exposure_uas_per_view: 2400.0,
        anode_material: dbt_dicom::AnodeMaterial::Tungsten,
        filter_material: dbt_dicom::FilterMaterial::Rhodium,
        filter_mm: 0.058,
        counts,
        content_date: "20261122",
        content_time: "101500",
    }
}

fn projection_counts(frames: usize, rows: usize, cols: usize) -> Vec<u16> {
    (0..frames * rows * cols)
        .map(|i| (1000 + (i * 7919) % 15000) as u16)
        .collect()
}

/// A simulated acquisition as a Breast Projection X-Ray Image - For
/// Processing object passes dciodvfy with no Error line.
#[test]
fn projection_object_passes_dciodvfy() {
    use dbt_dicom::projections::{projection_object, ProjectionSet};
    let (h, eq) = (header(), equipment());
    let angles: Vec<f64> = (0..25).map(|i| -24.0 + 2.0 * i as f64).collect();
    let counts = projection_counts(25, 12, 40);
    let p = projection_set(&h, &eq, &angles, &counts, 12, 40);
    let mut uids = UidSource::new("1.2.826.0.1.3680043.10.543", 7).unwrap();
    let r = projection_object(&p, &mut uids).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bpxr.dcm");
    std::fs::write(&path, r.to_bytes().unwrap()).unwrap();
    if let Ok(d) = std::env::var("DBT_DICOM_KEEP") {
        std::fs::write(Path::new(&d).join("bpxr.dcm"), r.to_bytes().unwrap()).unwrap();
    }
    let out = Command::new("dciodvfy").arg(&path).output().unwrap();
    let text =
        String::from_utf8_lossy(&out.stderr).to_string() + &String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("BreastProjectionXRayImage"), "{text}");
    // No error, and nothing outside the IOD (a standard, not a standard
    // extended, object); dciodvfy's remaining warnings are three defined
    // terms it does not list (Frame Type TOMOSYNTHESIS, Positioner Motion
    // DYNAMIC, Type of Detector Motion NONE).
    let bad: Vec<&str> = text
        .lines()
        .filter(|l| l.starts_with("Error") || l.contains("not present in standard DICOM IOD"))
        .collect();
    assert!(bad.is_empty(), "{}", bad.join("\n"));
    // What it says reads back: the frames, their size and the counts.
    let obj = dicom_object::from_reader(&r.to_bytes().unwrap()[..]).unwrap();
    let num = |t| obj.element(t).unwrap().to_int::<u32>().unwrap();
    assert_eq!(num(tags::NUMBER_OF_FRAMES), 25);
    assert_eq!((num(tags::ROWS), num(tags::COLUMNS)), (12, 40));
    let px = obj
        .element(tags::PIXEL_DATA)
        .unwrap()
        .to_multi_int::<u16>()
        .unwrap();
    assert_eq!(px, counts);

    // Refused, naming the value: counts of another size, an absurd thickness.
    let short = &counts[..counts.len() - 1];
    let e = projection_object(
        &ProjectionSet {
            counts: short,
            ..p.clone()
        },
        &mut uids,
    )
    .err()
    .unwrap()
    .to_string();
    assert!(e.contains("counts") && e.contains("11999"), "{e}");
    let e = projection_object(
        &ProjectionSet {
            thickness_mm: 0.0,
            ..p.clone()
        },
        &mut uids,
    )
    .err()
    .unwrap()
    .to_string();
    assert!(e.contains("thickness_mm"), "{e}");
}

/// What `projection_object` writes, `read_projection_object` reads back;
/// and each kind of unusable input is refused naming what is wrong: another
/// class (an SR), For Presentation, no thickness, pixel data of another
/// size, a truncated file.
#[test]
fn projection_object_reads_back_and_bad_input_is_named() {
    use dbt_dicom::projections::{projection_object, read_projection_object};
    let (h, eq) = (header(), equipment());
    let angles: Vec<f64> = (0..25).map(|i| -24.0 + 2.0 * i as f64).collect();
    let counts = projection_counts(25, 6, 20);
    let p = projection_set(&h, &eq, &angles, &counts, 6, 20);
    let mut uids = UidSource::new("1.2.826.0.1.3680043.10.543", 9).unwrap();
    let r = projection_object(&p, &mut uids).unwrap();
    let bytes = r.to_bytes().unwrap();
    let got = read_projection_object(&bytes).unwrap();
    assert_eq!(got.counts, counts);
    assert_eq!((got.rows, got.columns), (6, 20));
    assert_eq!(got.angles_deg, angles);
    assert_eq!(got.pixel_spacing_mm, [0.8, 0.8]);
    assert_eq!(
        (got.source_to_detector_mm, got.source_to_isocenter_mm),
        (700.0, Some(650.0))
    );
    assert_eq!((got.thickness_mm, got.kvp), (45.0, 29.0));
    assert!((got.exposure_mas - 60.0).abs() < 1e-9);
    assert_eq!(got.compression_force_n, Some(110.0));
    assert_eq!(got.header.patient_id, h.patient_id);
    assert_eq!(got.header.laterality, Laterality::Left);
    assert_eq!(
        got.header.source_instance_uids,
        vec![r.sop_instance.clone()]
    );

    let named = |bytes: &[u8], want: &str| {
        let e = read_projection_object(bytes).err().map(|e| e.to_string());
        assert!(
            e.as_deref().is_some_and(|e| e.contains(want)),
            "{want}: {e:?}"
        );
    };
    let sr = dose_report(&dose_input(), &mut uids)
        .unwrap()
        .to_bytes()
        .unwrap();
    let edited = |f: &dyn Fn(&mut dbt_dicom::Report)| {
        let mut u = UidSource::new("1.2.826.0.1.3680043.10.543", 10).unwrap();
        let mut r = projection_object(&p, &mut u).unwrap();
        f(&mut r);
        r.to_bytes().unwrap()
    };
    named(&sr, "is not one the input reads");
    // The X-Ray Filter Macro per frame instead of shared: read per frame,
    // and the frames must agree.
    let per_frame_filters = |materials: &dyn Fn(usize) -> &'static str| {
        edited(&|r| {
            use dicom_core::value::DataSetSequence;
            use dicom_core::{DataElement, VR};
            use dicom_object::InMemDicomObject;
            let ds = r.dataset_mut();
            let items_of = |ds: &mut InMemDicomObject, t| -> Vec<InMemDicomObject> {
                ds.take_element(t).unwrap().items().unwrap().to_vec()
            };
            let mut shared = items_of(ds, tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE);
            let filter = shared[0].take_element(tags::X_RAY_FILTER_SEQUENCE).unwrap();
            let mut frames = items_of(ds, tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE);
            for (k, f) in frames.iter_mut().enumerate() {
                let mut item = filter.items().unwrap()[0].clone();
                item.put(DataElement::new(
                    tags::FILTER_MATERIAL,
                    VR::CS,
                    materials(k),
                ));
                f.put(DataElement::new(
                    tags::X_RAY_FILTER_SEQUENCE,
                    VR::SQ,
                    DataSetSequence::from(vec![item]),
                ));
            }
            for (t, v) in [
                (tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE, shared),
                (tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE, frames),
            ] {
                ds.put(DataElement::new(t, VR::SQ, DataSetSequence::from(v)));
            }
        })
    };
    let got = read_projection_object(&per_frame_filters(&|_| "ALUMINUM")).unwrap();
    assert_eq!(got.filter.as_deref(), Some("ALUMINUM"));
    named(
        &per_frame_filters(&|k| if k == 3 { "RHODIUM" } else { "ALUMINUM" }),
        "FilterMaterial: frame 4",
    );
    named(
        &edited(&|r| {
            r.dataset_mut().put(dicom_core::DataElement::new(
                tags::PRESENTATION_INTENT_TYPE,
                dicom_core::VR::CS,
                "FOR PRESENTATION",
            ));
        }),
        "not FOR PROCESSING",
    );
    named(
        &edited(&|r| {
            r.dataset_mut().remove_element(tags::BODY_PART_THICKNESS);
        }),
        "BodyPartThickness: missing",
    );
    named(
        &edited(&|r| {
            r.dataset_mut().put(dicom_core::DataElement::new(
                tags::ROWS,
                dicom_core::VR::US,
                dicom_core::PrimitiveValue::from(7u16),
            ));
        }),
        "PixelData: 3000 values for 25 frames of 7 x 20",
    );
    named(&bytes[..bytes.len() / 2], "not a readable DICOM object");
}

/// A simulated acquisition as Digital Mammography X-Ray For Processing
/// objects, one per view: every one passes dciodvfy with no Error line and
/// nothing outside the IOD, and holds its view's counts and angle.
#[test]
fn view_objects_pass_dciodvfy() {
    use dbt_dicom::dm::{view_objects, DM_FOR_PROCESSING_CLASS};
    let (h, eq) = (header(), equipment());
    let angles: Vec<f64> = (0..25).map(|i| -24.0 + 2.0 * i as f64).collect();
    let counts = projection_counts(25, 12, 40);
    let p = projection_set(&h, &eq, &angles, &counts, 12, 40);
    let mut uids = UidSource::new("1.2.826.0.1.3680043.10.543", 8).unwrap();
    let objects = view_objects(&p, &mut uids).unwrap();
    assert_eq!(objects.len(), 25);
    let dir = tempfile::tempdir().unwrap();
    for (k, r) in objects.iter().enumerate() {
        assert_eq!(r.sop_class, DM_FOR_PROCESSING_CLASS);
        let bytes = r.to_bytes().unwrap();
        let obj = dicom_object::from_reader(&bytes[..]).unwrap();
        let px = obj
            .element(tags::PIXEL_DATA)
            .unwrap()
            .to_multi_int::<u16>()
            .unwrap();
        assert_eq!(px, counts[k * 480..(k + 1) * 480]);
        let angle = obj
            .element(tags::POSITIONER_PRIMARY_ANGLE)
            .unwrap()
            .to_float64()
            .unwrap();
        assert_eq!(angle, angles[k]);
        if ![0, 12, 24].contains(&k) {
            continue;
        }
        let path = dir.path().join(format!("dm{k}.dcm"));
        std::fs::write(&path, &bytes).unwrap();
        if let Ok(d) = std::env::var("DBT_DICOM_KEEP") {
            std::fs::write(Path::new(&d).join(format!("dm{k}.dcm")), &bytes).unwrap();
        }
        let out = Command::new("dciodvfy").arg(&path).output().unwrap();
        let text = String::from_utf8_lossy(&out.stderr).to_string()
            + &String::from_utf8_lossy(&out.stdout);
        assert!(text.contains("MammographyImageForProcessing"), "{text}");
        assert!(!text.contains("Warning"), "{text}");
        let bad: Vec<&str> = text
            .lines()
            .filter(|l| l.starts_with("Error") || l.contains("not present in standard DICOM IOD"))
            .collect();
        assert!(bad.is_empty(), "view {k}:\n{}", bad.join("\n"));
    }
}

/// A view object reads back with its angle, technique and view; a private
/// class is read only with its mapping (the thickness moved to a private
/// tag of a named creator), and refused naming what is wrong otherwise.
#[test]
fn view_objects_and_mapped_private_objects_read_back() {
    use dbt_dicom::dm::view_objects;
    use dbt_dicom::input::{read_input_object, Layout, Mapping};
    use dicom_core::{DataElement, Tag, VR};
    let (h, eq) = (header(), equipment());
    let angles: Vec<f64> = (0..25).map(|i| -24.0 + 2.0 * i as f64).collect();
    let counts = projection_counts(25, 6, 20);
    let p = projection_set(&h, &eq, &angles, &counts, 6, 20);
    let mut uids = UidSource::new("1.2.826.0.1.3680043.10.543", 11).unwrap();
    let objects = view_objects(&p, &mut uids).unwrap();
    let got = read_input_object(&objects[3].to_bytes().unwrap(), &[]).unwrap();
    assert_eq!(got.layout, Layout::PerView);
    assert_eq!(got.angles_deg, vec![angles[3]]);
    assert_eq!(got.counts, counts[3 * 120..4 * 120]);
    assert_eq!((got.rows, got.columns), (6, 20));
    assert_eq!(got.source_to_isocenter_mm, None);
    assert!((got.exposure_mas - 2.4).abs() < 1e-9);
    assert_eq!(got.exposure_ms_per_view, Some(60.0));
    assert_eq!(got.compression_force_n, Some(110.0));
    assert_eq!(got.anode.as_deref(), Some("TUNGSTEN"));
    assert_eq!(got.filter.as_deref(), Some("RHODIUM"));
    assert_eq!(got.view, "cranio-caudal");
    assert_eq!(got.instance_number, Some(4));
    assert_eq!(got.header.laterality, Laterality::Left);

    // For Presentation is named as such.
    let mut r = view_objects(&p, &mut uids).unwrap().remove(0);
    r.dataset_mut().put(DataElement::new(
        tags::SOP_CLASS_UID,
        VR::UI,
        "1.2.840.10008.5.1.4.1.1.1.2",
    ));
    let e = read_input_object(&r.to_bytes().unwrap(), &[])
        .unwrap_err()
        .to_string();
    assert!(e.contains("For Presentation"), "{e}");

    // A vendor's class: thickness in (0019,1012) of creator "ACME DBT".
    let private = "1.2.826.0.1.3680043.10.543.77.1";
    let mut r = view_objects(&p, &mut uids).unwrap().remove(5);
    let o = r.dataset_mut();
    o.put(DataElement::new(tags::SOP_CLASS_UID, VR::UI, private));
    o.remove_element(tags::BODY_PART_THICKNESS);
    o.remove_element(tags::PRESENTATION_INTENT_TYPE);
    o.put(DataElement::new(Tag(0x0019, 0x0010), VR::LO, "ACME DBT"));
    o.put(DataElement::new(Tag(0x0019, 0x1012), VR::DS, "45.0"));
    let bytes = r.to_bytes().unwrap();
    let e = read_input_object(&bytes, &[]).unwrap_err().to_string();
    assert!(
        e.contains(private) && e.contains("configured private class"),
        "{e}"
    );
    let mapping = |creator: &str| {
        Mapping::new(
            "ACME",
            private,
            Layout::PerView,
            [("BodyPartThickness".to_string(), Tag(0x0019, 0x1012))].into(),
            [(Tag(0x0019, 0x0010), creator.to_string())].into(),
        )
        .unwrap()
    };
    let got = read_input_object(&bytes, &[mapping("ACME DBT")]).unwrap();
    assert_eq!(got.thickness_mm, 45.0);
    assert_eq!(got.angles_deg, vec![angles[5]]);
    let e = read_input_object(&bytes, &[mapping("OTHER")])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("PrivateCreator") && e.contains("ACME DBT"),
        "{e}"
    );
    // A mapping names only attributes the input reads, for a private class.
    let e = Mapping::new(
        "x",
        private,
        Layout::PerView,
        [("PatientAge".to_string(), Tag(0x0019, 0x1001))].into(),
        Default::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("PatientAge"), "{e}");
    assert!(Mapping::new(
        "x",
        dbt_dicom::dm::DM_FOR_PROCESSING_CLASS,
        Layout::PerView,
        Default::default(),
        Default::default()
    )
    .is_err());
}

/// A vendor's multi-frame class without functional groups: every geometry
/// value from the mapped top-level tags (the angles one value per frame);
/// a mapped angle list of another length is refused naming it.
#[test]
fn a_mapped_multi_frame_private_object_reads_without_functional_groups() {
    use dbt_dicom::input::{read_input_object, Layout, Mapping, Tag};
    use dicom_core::{DataElement, VR};
    let (h, eq) = (header(), equipment());
    let angles: Vec<f64> = (0..25).map(|i| -24.0 + 2.0 * i as f64).collect();
    let counts = projection_counts(25, 6, 20);
    let p = projection_set(&h, &eq, &angles, &counts, 6, 20);
    let mut uids = UidSource::new("1.2.826.0.1.3680043.10.543", 12).unwrap();
    let private = "1.2.826.0.1.3680043.10.543.77.2";
    let mut object = |angle_values: &[f64]| {
        let mut r = dbt_dicom::projections::projection_object(&p, &mut uids).unwrap();
        let o = r.dataset_mut();
        o.put(DataElement::new(tags::SOP_CLASS_UID, VR::UI, private));
        o.remove_element(tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE);
        o.remove_element(tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE);
        let ds = |v: &[f64]| {
            v.iter()
                .map(|x| format!("{x}"))
                .collect::<Vec<_>>()
                .join("\\")
        };
        for (t, vr, v) in [
            (Tag(0x0019, 0x1020), VR::DS, ds(angle_values)),
            (Tag(0x0019, 0x1021), VR::DS, "700".to_string()),
            (Tag(0x0019, 0x1022), VR::DS, "650".to_string()),
            (Tag(0x0019, 0x1023), VR::DS, "0.8\\0.8".to_string()),
            (Tag(0x0019, 0x1024), VR::CS, "R".to_string()),
        ] {
            o.put(DataElement::new(t, vr, v));
        }
        r.to_bytes().unwrap()
    };
    let mapping = Mapping::new(
        "vendor",
        private,
        Layout::MultiFrame,
        [
            ("XRaySourceIsocenterPrimaryAngle", 0x1020),
            ("DistanceSourceToDetector", 0x1021),
            ("DistanceSourceToIsocenter", 0x1022),
            ("ImagerPixelSpacing", 0x1023),
            ("ImageLaterality", 0x1024),
        ]
        .into_iter()
        .map(|(k, e)| (k.to_string(), Tag(0x0019, e)))
        .collect(),
        Default::default(),
    )
    .unwrap();
    let got = read_input_object(&object(&angles), std::slice::from_ref(&mapping)).unwrap();
    assert_eq!(got.layout, Layout::MultiFrame);
    assert_eq!(got.angles_deg, angles);
    assert_eq!(got.counts, counts);
    assert_eq!(
        (got.source_to_detector_mm, got.source_to_isocenter_mm),
        (700.0, Some(650.0))
    );
    assert_eq!(got.pixel_spacing_mm, [0.8, 0.8]);
    assert_eq!(got.header.laterality, Laterality::Right);
    let e = read_input_object(&object(&angles[..24]), &[mapping])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("XRaySourceIsocenterPrimaryAngle") && e.contains("24 values for 25 frames"),
        "{e}"
    );
}
