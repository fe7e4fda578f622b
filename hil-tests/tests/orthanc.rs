//! A real PACS: Orthanc (Debian package `orthanc`) started on loopback ports.
//! Reports arrive by C-STORE and are read back through Orthanc's REST API;
//! with Orthanc stopped they wait in the outbox and arrive after it starts.
//! `scripts/install-test-deps.sh` installs Orthanc; a missing binary fails the test.

use dbt_dicom::*;
use dbt_pacs::{echo, Outbox, PacsConfig};
use hil_tests::{free_port, http_get, Orthanc};

fn instances(port: u16) -> Vec<String> {
    let body = http_get(port, "/instances").expect("GET /instances");
    serde_json::from_slice(&body).unwrap()
}

fn header() -> Header {
    Header {
        patient_name: "Doe^Jane".into(),
        patient_id: "HIL-0001".into(),
        patient_birth_date: "19700101".into(),
        patient_sex: "F".into(),
        study_uid: "1.2.826.0.1.3680043.10.543.88.1".into(),
        study_date: "20261122".into(),
        study_time: "101500".into(),
        study_id: "S1".into(),
        accession_number: "A1".into(),
        referring_physician: "".into(),
        laterality: Laterality::Right,
        source_series_uid: "1.2.826.0.1.3680043.10.543.88.2".into(),
        source_instance_uids: vec!["1.2.826.0.1.3680043.10.543.88.3".into()],
        source_class: dbt_dicom::projections::BPXR_FOR_PROCESSING_CLASS.into(),
    }
}

fn equipment() -> Equipment {
    Equipment {
        manufacturer: "DBToR Medical".into(),
        model: "DBToR gantry PC".into(),
        serial: "SN-HIL".into(),
        software_version: "0.1.0".into(),
        device_uid: "1.2.826.0.1.3680043.10.543.88.9".into(),
    }
}

fn dose(agd: f64) -> DoseInput {
    DoseInput {
        header: header(),
        equipment: equipment(),
        events: vec![DoseEvent {
            angle_start_deg: -1.0,
            angle_end_deg: 1.0,
            kvp: 29.0,
            exposure_uas: 3000.0,
            exposure_ms: Some(60.0),
            agd_mgy: agd,
            entrance_kerma_mgy: 4.2,
            datetime: "20261122101500".into(),
        }],
        compression_mm: 52.0,
        compression_force_n: Some(110.0),
        hvl_mm_al: 0.538,
        anode_material: dbt_dicom::AnodeMaterial::Tungsten,
        filter_material: dbt_dicom::FilterMaterial::Rhodium,
        filter_mm: 0.0583,
        accumulated_agd_mgy: agd,
        relative_uncertainty: 0.008,
        model_agd_mgy: agd * 1.3,
        model_agd_at_physics_mgy: None,
        agd_interval: dbt_dicom::FigureInterval {
            limits: Some([0.9 * agd, 1.1 * agd]),
            basis: "95 % prediction interval from 20 validation breasts".into(),
        },
        content_date: "20261122".into(),
        content_time: "102000".into(),
        intent: ProcedureIntent::Diagnostic,
        source_distances_mm: [650.0, 700.0],
        algorithm_version: "model test (manifest sha256:0123abcd), fp32 on the fast engine".into(),
        method: dbt_dicom::ReportMethod::Reconstruction,
    }
}

fn density() -> DensityInput {
    DensityInput {
        header: header(),
        equipment: equipment(),
        glandularity: 0.12,
        fibroglandular_cm3: 40.0,
        breast_cm3: 700.0,
        reconstructor: "DBToR fp32".into(),
        model_version: "test".into(),
        check: dbt_dicom::DensityCheckReport {
            physics_glandularity: Some(0.25),
            confirmed: true,
            reasons: vec![],
        },
        method: dbt_dicom::ReportMethod::Reconstruction,
        glandularity_interval: dbt_dicom::FigureInterval {
            limits: Some([0.08, 0.17]),
            basis: "95 % prediction interval from 20 validation breasts".into(),
        },
        content_date: "20261122".into(),
        content_time: "102000".into(),
    }
}

#[test]
fn reports_reach_orthanc_and_survive_an_outage() {
    let dir = tempfile::tempdir().unwrap();
    let (dicom, http) = (free_port(), free_port());
    let orthanc = Orthanc::start(dir.path(), dicom, http);
    let mut pacs = PacsConfig::new("ORTHANC", "127.0.0.1", dicom);
    pacs.attempts = 2;
    pacs.backoff_ms = 50;
    pacs.timeout_ms = 3000;
    echo(&pacs).expect("C-ECHO to Orthanc");
    // Orthanc checks the called AE title: a wrong one is refused at association.
    let wrong = PacsConfig::new("NOTORTHANC", "127.0.0.1", dicom);
    assert!(echo(&wrong).is_err());

    let ob = Outbox::open(&dir.path().join("output"), &dir.path().join("outbox")).unwrap();
    let mut uids = UidSource::new("1.2.826.0.1.3680043.10.543", 99).unwrap();
    let d = dose_report(&dose(1.61), &mut uids).unwrap();
    let g = density_report(&density(), &mut uids).unwrap();
    let mut sent_bytes = Vec::new();
    for (name, r) in [("dose", &d), ("density", &g)] {
        let bytes = r.to_bytes().unwrap();
        let rep = ob.deliver(name, &bytes, Some(&pacs)).unwrap();
        assert_eq!(rep.sent.len(), 1, "{name}: {:?}", rep.waiting);
        sent_bytes.push(bytes);
    }
    assert!(ob.pending().unwrap().is_empty());
    // Read back through the REST API and compare the report values.
    let ids = instances(http);
    assert_eq!(ids.len(), 2);
    let mut got: Vec<_> = ids
        .iter()
        .map(|id| read_values(&http_get(http, &format!("/instances/{id}/file")).unwrap()).unwrap())
        .collect();
    let mut want: Vec<_> = sent_bytes.iter().map(|b| read_values(b).unwrap()).collect();
    got.sort_by(|a, b| a.0.cmp(&b.0));
    want.sort_by(|a, b| a.0.cmp(&b.0));
    assert_eq!(got, want);

    // Outage: the report waits in the outbox (and is in the output folder).
    orthanc.stop();
    let late = dose_report(&dose(2.02), &mut uids).unwrap();
    let rep = ob
        .deliver("late-dose", &late.to_bytes().unwrap(), Some(&pacs))
        .unwrap();
    assert!(rep.sent.is_empty() && rep.waiting.len() == 1, "{rep:?}");
    assert_eq!(ob.pending().unwrap().len(), 1);
    assert!(dir.path().join("output/late-dose.dcm").exists());

    // Orthanc is back: the next flush delivers it.
    let orthanc = Orthanc::start(dir.path(), dicom, http);
    let rep = ob.flush(&pacs).unwrap();
    assert_eq!(rep.sent.len(), 1, "{rep:?}");
    assert!(ob.pending().unwrap().is_empty());
    assert_eq!(instances(http).len(), 3);
    orthanc.stop();
}
