//! The header validation and the physical plausibility checks, each limit
//! tried just inside and just outside, on an acquisition whose counts follow
//! Beer-Lambert through a breast-like block (analytic chords, Poisson noise).

use dbt_geometry::{chord_in_rect, Geometry};
use dbt_materials::Tissue;
use dbt_pipeline::acquisition::{
    limits, validate_header, Acquisition, AcquisitionHeader, Patient, Study, ACQ_FORMAT,
};
use dbt_pipeline::plausibility::{
    check_volume, footprint_mm, Implausible, DEFECT_FRACTION_MAX, DETECTOR_MAX_COUNT,
    VOLUME_FILL_MAX,
};

const FLUX: f64 = 16_000.0; // N8

/// The counts check of a recorded header's counts, in the layout the
/// header states (the tests write headers as a file holds them).
fn check_counts(
    h: &AcquisitionHeader,
    counts: &[Vec<f32>],
) -> Result<dbt_pipeline::plausibility::Defects, Implausible> {
    check_counts_with(h, counts, false)
}

/// [`check_counts`], with scatter in the counts or not.
fn check_counts_with(
    h: &AcquisitionHeader,
    counts: &[Vec<f32>],
    scatter: bool,
) -> Result<dbt_pipeline::plausibility::Defects, Implausible> {
    use dbt_pipeline::plausibility::check_counts_with as check;
    match h.system.clone() {
        None => check(&slices(h), counts, scatter),
        Some(sys) => check(
            &dbt_pipeline::ConeHeader::new(h.clone(), sys),
            counts,
            scatter,
        ),
    }
}

/// The slice-wise header of a fan-beam acquisition.
fn slices(h: &AcquisitionHeader) -> dbt_pipeline::SliceHeader {
    dbt_pipeline::SliceHeader::try_from(h.clone()).expect("a slice-wise acquisition")
}

fn geometry() -> Geometry {
    Geometry::builtin("paper-tall").unwrap().binned(4).unwrap()
}

fn header(slices: usize, thickness: f64) -> AcquisitionHeader {
    let g = geometry();
    AcquisitionHeader {
        slice_spacing_mm: g.image.pixel_mm,
        thickness_mm: thickness,
        flux: FLUX,
        patient: Patient {
            name: "Doe^Jane".into(),
            id: "P-0001".into(),
            birth_date: "19700101".into(),
            sex: "F".into(),
        },
        study: Study {
            study_uid: "1.2.826.0.1.3680043.10.543.7".into(),
            date: "20261124".into(),
            time: "101500".into(),
            accession: "A1".into(),
            study_id: "1".into(),
            series_uid: "1.2.826.0.1.3680043.10.543.7.1".into(),
            instance_uids: vec![],
            source_class: None,
        },
        ..dbt_pipeline::acquisition::example_header(g, slices, None)
    }
}

/// Counts through a block of fibroglandular tissue `width` mm wide and
/// `height` mm high on the support (the breast in its box), Poisson at N8.
fn acquisition(slices: usize, thickness: f64, width: f64, height: f64, seed: u64) -> Acquisition {
    let h = header(slices, thickness);
    let g = &h.geometry;
    let z0 = g.support_z_mm();
    let mu = Tissue::Fibroglandular.mu_per_mm() as f64;
    let mut expected = Vec::with_capacity(g.n_rays());
    for v in 0..g.n_views() {
        for k in 0..g.n_det() {
            let (s, p) = g.ray_endpoints_mm(v, k);
            let l = chord_in_rect(s, p, -width / 2.0, width / 2.0, z0, z0 + height);
            expected.push((FLUX * (-mu * l).exp()) as f32);
        }
    }
    let counts = (0..slices)
        .map(|i| dbt_forward::poisson_counts(&expected, seed + i as u64))
        .collect();
    Acquisition { header: h, counts }
}

#[test]
fn a_clean_acquisition_passes_without_corrections() {
    let a = acquisition(4, 50.0, 120.0, 50.0, 1);
    validate_header(&a.header).unwrap();
    let d = check_counts(&a.header, &a.counts).unwrap();
    assert!(d.is_empty(), "{:?}", d.check);
    assert_eq!(d.check.rays, 4 * a.header.geometry.n_rays());
    assert_eq!(d.check.flag(), None);
    // The densest breast the box can hold (skin-like attenuation, filling
    // the box) still passes: the dark bound is the thickness's.
    let mut h = a.header.clone();
    h.slices = 2;
    let g = &h.geometry;
    let z0 = g.support_z_mm();
    let mu = Tissue::Skin.mu_per_mm() as f64;
    let c: Vec<f32> = (0..g.n_views())
        .flat_map(|v| (0..g.n_det()).map(move |k| (v, k)))
        .map(|(v, k)| {
            let (s, p) = g.ray_endpoints_mm(v, k);
            let w = g.width_mm() / 2.0;
            (FLUX * (-mu * chord_in_rect(s, p, -w, w, z0, z0 + 50.0)).exp()) as f32
        })
        .collect();
    let c = dbt_forward::poisson_counts(&c, 9);
    assert!(check_counts(&h, &[c.clone(), c]).unwrap().is_empty());
}

/// Counts that hold their scatter (issue #27's other design): beside the
/// breast up to `1 + SCATTER_AIR_MAX` times the flat field passes, beyond
/// is hot; the 16-bit maximum stays a saturation whatever the scatter bound
/// (a flat field of 40,000 puts twice it above 65,535).
#[test]
fn counts_with_scatter_have_their_own_hot_bound_and_still_saturate() {
    use dbt_pipeline::plausibility::SCATTER_AIR_MAX;
    let a = acquisition(2, 50.0, 120.0, 50.0, 4);
    let scaled = |f: f32| -> Vec<Vec<f32>> {
        a.counts
            .iter()
            .map(|s| s.iter().map(|c| c * f).collect())
            .collect()
    };
    let lifted = scaled(1.5);
    assert_eq!(
        refused_kind(check_counts(&a.header, &lifted)),
        "above the flat field"
    );
    assert!(check_counts_with(&a.header, &lifted, true)
        .unwrap()
        .is_empty());
    let beyond = scaled((1.0 + SCATTER_AIR_MAX as f32) * 1.1);
    assert_eq!(
        refused_kind(check_counts_with(&a.header, &beyond, true)),
        "above the flat field"
    );
    let mut h = a.header.clone();
    h.flux = 40_000.0;
    let n = a.counts[0].len();
    assert_eq!(
        refused_kind(check_counts_with(
            &h,
            &[vec![DETECTOR_MAX_COUNT; n], vec![DETECTOR_MAX_COUNT; n]],
            true
        )),
        "saturated"
    );
}

fn refused_kind(r: Result<dbt_pipeline::plausibility::Defects, Implausible>) -> String {
    match r {
        Err(Implausible::Counts { kind, .. }) => kind.to_string(),
        other => panic!("expected a refusal, got {other:?}"),
    }
}

#[test]
fn impossible_counts_are_refused_with_their_reason() {
    let a = acquisition(2, 50.0, 120.0, 50.0, 2);
    let n = a.counts[0].len();
    // All zero (a dead detector or no exposure).
    assert_eq!(
        refused_kind(check_counts(&a.header, &[vec![0.0; n], vec![0.0; n]])),
        "zero (dead)"
    );
    // Saturated at the 16-bit maximum.
    assert_eq!(
        refused_kind(check_counts(
            &a.header,
            &[vec![DETECTOR_MAX_COUNT; n], vec![DETECTOR_MAX_COUNT; n]]
        )),
        "saturated"
    );
    // Far above the flat field (56 % of the counts at twice the flux).
    let mut hot = a.counts.clone();
    for s in &mut hot {
        for (i, c) in s.iter_mut().enumerate() {
            if i % 25 < 14 {
                *c = 2.0 * FLUX as f32;
            }
        }
    }
    let e = check_counts(&a.header, &hot).unwrap_err().to_string();
    assert!(
        e.contains("above the flat field") && e.contains("56.0"),
        "{e}"
    );
    // Darker than a 50 mm breast can be: the counts of a 150 mm block.
    let thick = acquisition(2, 150.0, 200.0, 150.0, 3);
    let e = refused_kind(check_counts(&a.header, &thick.counts));
    assert!(
        e == "darker than the thickness allows" || e == "zero (dead)",
        "{e}"
    );
    // A stuck readout: every element of every slice the same in all views.
    let nd = a.header.geometry.n_det();
    let stuck: Vec<Vec<f32>> = a
        .counts
        .iter()
        .map(|s| (0..s.len()).map(|i| s[i % nd]).collect())
        .collect();
    // (The central view's counts everywhere: every element is one value
    // across views; air elements equal to the flat field are not stuck but
    // noisy counts are never exactly the flux.)
    assert_eq!(refused_kind(check_counts(&a.header, &stuck)), "stuck");
}

#[test]
fn a_few_defects_are_corrected_and_flagged_more_are_refused() {
    let a = acquisition(8, 50.0, 120.0, 50.0, 4);
    let total = a.counts.len() * a.counts[0].len();
    let limit = (DEFECT_FRACTION_MAX * total as f64).floor() as usize;
    // Dead pixels spread over the breast's rays, just inside the limit.
    let mut c = a.counts.clone();
    let nd = a.header.geometry.n_det();
    let mut placed = 0;
    'outer: for s in c.iter_mut() {
        for v in 0..a.header.geometry.n_views() {
            for k in (nd / 2 - 40..nd / 2 + 40).step_by(7) {
                if placed == limit {
                    break 'outer;
                }
                s[v * nd + k] = 0.0;
                placed += 1;
            }
        }
    }
    assert_eq!(placed, limit);
    let d = check_counts(&a.header, &c).unwrap();
    assert_eq!(d.check.dead, limit);
    let fixed = d.correct(&mut c).unwrap();
    assert_eq!(fixed.corrected, limit);
    assert!(fixed
        .flag()
        .unwrap()
        .contains(&format!("{limit} defective detector counts")));
    // Each corrected count lies between its neighbours' (interpolation).
    for (orig, s) in a.counts.iter().zip(&c) {
        for (i, (&o, &n)) in orig.iter().zip(s).enumerate() {
            if o != n {
                let (l, r) = (s[i - 1], s[i + 1]);
                assert!(
                    n >= l.min(r) - 1e-3 && n <= l.max(r) + 1e-3,
                    "{n} not within {l}..{r}"
                );
            }
        }
    }
    assert!(check_counts(&a.header, &c).unwrap().is_empty());
    // One more dead count than the limit is refused.
    let mut c2 = a.counts.clone();
    let mut placed = 0;
    'outer2: for s in c2.iter_mut() {
        for i in (0..s.len()).step_by(3) {
            let lam_ok = s[i] > 200.0;
            if lam_ok {
                s[i] = 0.0;
                placed += 1;
                if placed == limit + 1 {
                    break 'outer2;
                }
            }
        }
    }
    assert_eq!(refused_kind(check_counts(&a.header, &c2)), "zero (dead)");
}

#[test]
fn header_limits_just_inside_and_just_outside() {
    let ok = header(186, 50.0);
    validate_header(&ok).unwrap();
    type Edit = fn(&mut AcquisitionHeader);
    let cases: Vec<(&str, Edit, Edit)> = vec![
        (
            "thickness_mm",
            |h| h.thickness_mm = limits::THICKNESS_MIN_MM,
            |h| h.thickness_mm = limits::THICKNESS_MIN_MM - 0.01,
        ),
        (
            "thickness_mm",
            |h| h.thickness_mm = limits::THICKNESS_MAX_MM,
            |h| h.thickness_mm = f64::NAN,
        ),
        (
            "kvp",
            |h| h.kvp = limits::KVP_MIN,
            |h| h.kvp = limits::KVP_MIN - 0.1,
        ),
        ("kvp", |h| h.kvp = limits::KVP_MAX, |h| h.kvp = 1000.0),
        ("mas_total", |h| h.mas_total = 1e-3, |h| h.mas_total = 0.0),
        (
            "mas_total",
            |h| h.mas_total = limits::MAS_MAX,
            |h| h.mas_total = -5.0,
        ),
        (
            "tube_output_mgy_per_mas",
            |h| h.tube_output_mgy_per_mas = 1.0,
            |h| h.tube_output_mgy_per_mas = 0.0,
        ),
        ("flux", |h| h.flux = limits::FLUX_MIN, |h| h.flux = 1e-30),
        (
            "flux",
            |h| h.flux = limits::FLUX_MAX,
            |h| h.flux = f64::INFINITY,
        ),
        (
            "slices",
            |h| h.slices = 375,
            |h| h.slices = (1usize << 56) + 3,
        ),
        ("slices", |h| h.slices = 1, |h| h.slices = 0),
        (
            "study.study_uid",
            |h| h.study.study_uid = "1.2.0.3".into(),
            |h| h.study.study_uid = "1.2.03".into(),
        ),
        (
            "study.study_uid",
            |h| h.study.study_uid = "1.".repeat(31) + "12",
            |h| h.study.study_uid = "1.2.x".into(),
        ),
        (
            "study.series_uid",
            |h| h.study.series_uid = "2.25.1".into(),
            |h| h.study.series_uid = "".into(),
        ),
        (
            "study.date",
            |h| h.study.date = "20240229".into(),
            |h| h.study.date = "20260229".into(),
        ),
        (
            "study.date",
            |h| h.study.date = "20261231".into(),
            |h| h.study.date = "20261301".into(),
        ),
        (
            "study.time",
            |h| h.study.time = "235960.123456".into(),
            |h| h.study.time = "240000".into(),
        ),
        (
            "patient.id",
            |h| h.patient.id = "../x".into(),
            |h| h.patient.id = " ".into(),
        ),
        (
            "patient.id",
            |h| h.patient.id = "x".repeat(64),
            |h| h.patient.id = "a\\b".into(),
        ),
        (
            "patient.name",
            |h| h.patient.name = "".into(),
            |h| h.patient.name = "Doe\nJane".into(),
        ),
        (
            "patient.birth_date",
            |h| h.patient.birth_date = "".into(),
            |h| h.patient.birth_date = "1970-01-01".into(),
        ),
        (
            "patient.sex",
            |h| h.patient.sex = "O".into(),
            |h| h.patient.sex = "X".into(),
        ),
        (
            "laterality",
            |h| h.laterality = "R".into(),
            |h| h.laterality = "B".into(),
        ),
        (
            "study.accession",
            |h| h.study.accession = "x".repeat(16),
            |h| h.study.accession = "x".repeat(17),
        ),
        (
            "format",
            |h| h.format = ACQ_FORMAT.into(),
            |h| h.format = "dbtor-acquisition/0".into(),
        ),
    ];
    for (field, inside, outside) in cases {
        let mut h = ok.clone();
        inside(&mut h);
        validate_header(&h).unwrap_or_else(|e| panic!("{field} just inside refused: {e}"));
        let mut h = ok.clone();
        outside(&mut h);
        let e = validate_header(&h).expect_err(field);
        assert_eq!(e.field, field, "{e}");
        assert!(e.to_string().contains(field), "{e}");
    }
}

#[test]
fn the_reconstructed_breast_must_fit_its_tissues_and_its_box() {
    // A 120 x 50 mm block of fibroglandular tissue, reconstructed exactly.
    let a = acquisition(3, 50.0, 120.0, 50.0, 5);
    let g = &a.header.geometry;
    let fp = footprint_mm(&a.header, &a.counts);
    for w in &fp {
        // The footprint at the isocentre: the block's width, to within the
        // magnification between the isocentre and the block's faces.
        assert!((w - 120.0).abs() < 12.0, "footprint {w} mm");
    }
    let (cols, nv, nd) = (g.image.columns, g.rows_within_thickness(50.0), 3);
    let px = g.image.pixel_mm;
    let mut mu = vec![0f32; cols * nv * nd];
    let mut labels = vec![0u8; cols * nv * nd];
    for d in 0..nd {
        for v in 0..nv {
            for c in 0..cols {
                let x = -g.width_mm() / 2.0 + (c as f64 + 0.5) * px;
                if x.abs() < 60.0 {
                    let i = (d * nv + v) * cols + c;
                    mu[i] = Tissue::Fibroglandular.mu_per_mm();
                    labels[i] = 3;
                }
            }
        }
    }
    let ok = check_volume(&a.header, &fp, &mu, &labels, px).unwrap();
    assert!((ok.fill - 1.0).abs() < 0.12, "{ok:?}");
    // Attenuation beyond any tissue (a reconstruction of garbage).
    let hot: Vec<f32> = mu.iter().map(|m| m * 2.0).collect();
    assert!(matches!(
        check_volume(&a.header, &fp, &hot, &labels, px),
        Err(Implausible::Attenuation { .. })
    ));
    // A breast wider than its footprint (the box overfilled).
    let small: Vec<f64> = fp.iter().map(|w| w / (VOLUME_FILL_MAX + 0.05)).collect();
    assert!(matches!(
        check_volume(&a.header, &small, &mu, &labels, px),
        Err(Implausible::Volume { .. })
    ));
    // No breast at all.
    assert!(check_volume(&a.header, &fp, &mu, &vec![0u8; labels.len()], px).is_err());
}

/// `acq` as the simulated modality writes it (its views at `angles`): one
/// Breast Projection X-Ray For Processing object and one Digital
/// Mammography For Processing object per view, each read back (the
/// per-view ones with their SOP instance UIDs).
fn written_and_read(
    acq: &Acquisition,
    angles: &[f64],
) -> (
    dbt_dicom::projections::ReceivedProjections,
    Vec<(String, dbt_dicom::projections::ReceivedProjections)>,
) {
    use dbt_dicom::projections::{projection_object, read_projection_object};
    let counts = dbt_pipeline::dicom_input::frames_of(acq).unwrap();
    let header = dbt_pipeline::dicom_header(acq);
    let equipment = dbt_dicom::Equipment {
        manufacturer: "test".into(),
        model: "test gantry".into(),
        serial: "1".into(),
        software_version: "0".into(),
        device_uid: "1.2.826.0.1.3680043.10.543.9".into(),
    };
    let set = dbt_pipeline::dicom_input::projection_set(
        acq,
        &header,
        &equipment,
        angles,
        &counts,
        dbt_pipeline::dicom_input::Sweep {
            compression_force_n: 110.0,
            exposure_ms_per_view: 60.0,
            view_interval_ms: 150.0,
            modality_agd_mgy: 1.5,
            filter_mm: 0.05,
            content_date: "20261124",
            content_time: "101500",
        },
    );
    let mut uids = dbt_dicom::UidSource::new("1.2.826.0.1.3680043.10.543", 3).unwrap();
    let bytes = projection_object(&set, &mut uids)
        .unwrap()
        .to_bytes()
        .unwrap();
    let views = dbt_dicom::dm::view_objects(&set, &mut uids)
        .unwrap()
        .iter()
        .map(|o| {
            (
                o.sop_instance.clone(),
                read_projection_object(&o.to_bytes().unwrap()).unwrap(),
            )
        })
        .collect();
    (read_projection_object(&bytes).unwrap(), views)
}

/// The DICOM input's conversion (issue #31): an acquisition written as a
/// Breast Projection X-Ray For Processing object and read back is the same
/// acquisition on the same configured system (counts exactly: integers);
/// an object from another gantry is refused naming the attribute.
#[test]
fn a_projection_object_reads_back_as_the_same_acquisition() {
    use dbt_pipeline::dicom_input::{acquisition_from_projections, Gantry};
    let acq = acquisition(6, 45.0, 120.0, 45.0, 5);
    let h = &acq.header;
    let g = &h.geometry;
    let angles: Vec<f64> = (0..g.n_views()).map(|v| g.angle_deg(v)).collect();
    let (received, objects) = written_and_read(&acq, &angles);
    let system = Gantry {
        geometry: g.clone(),
        cone: None,
        flux: Some(h.flux),
        tube_output_mgy_per_mas: h.tube_output_mgy_per_mas,
        unstated_beam: Some(dbt_dose::xray::AnodeFilter::WRh),
    };
    let back = acquisition_from_projections(&received, &system).unwrap();
    let rounded: Vec<Vec<f32>> = acq
        .counts
        .iter()
        .map(|s| s.iter().map(|c| (*c as u16) as f32).collect())
        .collect();
    assert_eq!(back.counts, rounded);
    let mut want = h.clone();
    want.study.series_uid = received.header.source_series_uid.clone();
    want.study.instance_uids = received.header.source_instance_uids.clone();
    want.study.source_class = Some(dbt_dicom::projections::BPXR_FOR_PROCESSING_CLASS.into());
    // What the object carried beyond the frame link's header.
    want.compression_force_n = Some(110.0);
    want.exposure_ms_per_view = Some(60.0);
    assert!((back.header.mas_total - want.mas_total).abs() < 1e-9);
    want.mas_total = back.header.mas_total;
    assert_eq!(back.header, want);

    let other = Gantry {
        geometry: g.clone().binned(2).unwrap(),
        ..system.clone()
    };
    let e = acquisition_from_projections(&received, &other)
        .unwrap_err()
        .to_string();
    assert!(e.contains("Columns") && e.contains("elements"), "{e}");

    // The same sweep as one Digital Mammography For Processing object per
    // view, received in any order: assembled, the same acquisition (but
    // the evidence: the views' own class and instances).
    use dbt_pipeline::dicom_input::{assemble, group_key, view_index};
    let mut views: Vec<_> = objects.iter().map(|(_, o)| o.clone()).collect();
    views.reverse();
    views.swap(3, 11);
    let keys: std::collections::BTreeSet<String> = views.iter().map(group_key).collect();
    assert_eq!(keys.len(), 1, "{keys:?}");
    assert_eq!(view_index(&views[0], &system).unwrap(), g.n_views() - 1);
    let swept = assemble(&views, &system).unwrap();
    let from_views = acquisition_from_projections(&swept, &system).unwrap();
    assert_eq!(from_views.counts, back.counts);
    let mut want_views = back.header.clone();
    want_views.study.series_uid = views[0].header.source_series_uid.clone();
    want_views.study.instance_uids = objects.iter().map(|(uid, _)| uid.clone()).collect();
    want_views.study.source_class = Some(dbt_dicom::dm::DM_FOR_PROCESSING_CLASS.into());
    // The per-view exposures are whole uAs: their sum within 0.5 uAs each.
    assert!(
        (from_views.header.mas_total - back.header.mas_total).abs() < 0.5e-3 * views.len() as f64
    );
    want_views.mas_total = from_views.header.mas_total;
    assert_eq!(from_views.header, want_views);

    // A view missing, a view twice, a view of another thickness: named.
    let named = |v: &[dbt_dicom::projections::ReceivedProjections], want: &str| {
        let e = assemble(v, &system).unwrap_err().to_string();
        assert!(e.contains(want), "{want}: {e}");
    };
    named(&views[1..], "missing the views at");
    let mut twice = views.clone();
    twice[5] = twice[6].clone();
    named(&twice, "is there twice");
    let mut thicker = views.clone();
    thicker[9].thickness_mm += 5.0;
    named(&thicker, "BodyPartThickness");
    let mut other_angle = views.clone();
    other_angle[2].angles_deg[0] += 0.7;
    named(&other_angle, "no configured view is at this angle");
    let mut mixed_beam = views.clone();
    mixed_beam[4].filter = Some("ALUMINUM".into());
    named(&mixed_beam, "FilterMaterial");
    mixed_beam[4].filter = None;
    named(&mixed_beam, "FilterMaterial");

    // The beam travels in both forms: a W/Al sweep reads back as W/Al, a
    // W/Ag one as W/Ag (the
    // multi-frame object's X-Ray Filter Macro, each view's Filter
    // Material); another filter or anode is refused naming the attribute
    // and its value (issue #27).
    for (beam, anode, term) in [
        (dbt_dose::xray::AnodeFilter::WAl, "TUNGSTEN", "ALUMINUM"),
        (dbt_dose::xray::AnodeFilter::WAg, "TUNGSTEN", "SILVER"),
        (
            dbt_dose::xray::AnodeFilter::MoMo,
            "MOLYBDENUM",
            "MOLYBDENUM",
        ),
        (dbt_dose::xray::AnodeFilter::MoRh, "MOLYBDENUM", "RHODIUM"),
        (dbt_dose::xray::AnodeFilter::RhRh, "RHODIUM", "RHODIUM"),
    ] {
        let mut a = acq.clone();
        a.header.anode_filter = beam;
        let (received, objects) = written_and_read(&a, &angles);
        assert_eq!(received.filter.as_deref(), Some(term));
        assert_eq!(received.anode.as_deref(), Some(anode));
        let back = acquisition_from_projections(&received, &system).unwrap();
        assert_eq!(back.header.anode_filter, beam);
        let views: Vec<_> = objects.iter().map(|(_, o)| o.clone()).collect();
        let swept = assemble(&views, &system).unwrap();
        assert_eq!(swept.filter.as_deref(), Some(term));
        let from_views = acquisition_from_projections(&swept, &system).unwrap();
        assert_eq!(from_views.header.anode_filter, beam);
    }
    for (anode, filter, field, value) in [
        (None, Some("COPPER"), "FilterMaterial", "COPPER"),
        (
            None,
            Some("ALUMINUM\\RHODIUM"),
            "FilterMaterial",
            "ALUMINUM\\RHODIUM",
        ),
        (
            Some("COPPER"),
            Some("RHODIUM"),
            "AnodeTargetMaterial",
            "COPPER",
        ),
        // GE Pristina's Rh/Ag, and pairings no gantry makes: refused
        // naming the filter and the anode's beams.
        (Some("RHODIUM"), Some("SILVER"), "FilterMaterial", "SILVER"),
        (
            Some("MOLYBDENUM"),
            Some("ALUMINUM"),
            "FilterMaterial",
            "MOLYBDENUM anode",
        ),
        (
            Some("TUNGSTEN"),
            Some("MOLYBDENUM"),
            "FilterMaterial",
            "RHODIUM or ALUMINUM or SILVER",
        ),
    ] {
        let mut r = received.clone();
        r.anode = anode.map(String::from).or(r.anode);
        r.filter = filter.map(String::from);
        let e = acquisition_from_projections(&r, &system)
            .unwrap_err()
            .to_string();
        assert!(e.contains(field) && e.contains(value), "{e}");
    }
    // Each beam's filter on a tungsten anode, a filter of several layers of
    // one material too.
    use dbt_dose::xray::AnodeFilter;
    for (filter, want) in [
        ("RHODIUM", AnodeFilter::WRh),
        ("ALUMINUM", AnodeFilter::WAl),
        ("ALUMINUM\\ALUMINUM", AnodeFilter::WAl),
    ] {
        let mut r = received.clone();
        (r.anode, r.filter) = (Some("TUNGSTEN".into()), Some(filter.into()));
        let got = acquisition_from_projections(&r, &system).unwrap();
        assert_eq!(got.header.anode_filter, want, "{filter}");
    }
    // No filter stated (optional in the DM IOD): the site's unstated beam,
    // whichever it is, or refused naming the attribute where the site takes
    // none for granted; an anode without a filter likewise.
    for anode in [None, Some("TUNGSTEN")] {
        let mut r = received.clone();
        (r.anode, r.filter) = (anode.map(String::from), None);
        let plain = acquisition_from_projections(&r, &system).unwrap();
        assert_eq!(plain.header.anode_filter, AnodeFilter::WRh);
        let w_al_site = Gantry {
            unstated_beam: Some(AnodeFilter::WAl),
            ..system.clone()
        };
        let got = acquisition_from_projections(&r, &w_al_site).unwrap();
        assert_eq!(got.header.anode_filter, AnodeFilter::WAl);
        let strict = Gantry {
            unstated_beam: None,
            ..system.clone()
        };
        let e = acquisition_from_projections(&r, &strict)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("FilterMaterial") && e.contains("unstated_beam"),
            "{e}"
        );
        let e = dbt_pipeline::dicom_input::check_object(&r, &strict)
            .unwrap_err()
            .to_string();
        assert!(e.contains("FilterMaterial"), "{e}");
    }
    // A molybdenum or rhodium anode without a filter: the site's unstated
    // beam only if it is on that anode, else refused naming both.
    for (anode, site, ok) in [
        ("MOLYBDENUM", AnodeFilter::WRh, false),
        ("MOLYBDENUM", AnodeFilter::MoRh, true),
        ("RHODIUM", AnodeFilter::MoRh, false),
        ("RHODIUM", AnodeFilter::RhRh, true),
    ] {
        let mut r = received.clone();
        (r.anode, r.filter) = (Some(anode.into()), None);
        let site_gantry = Gantry {
            unstated_beam: Some(site),
            ..system.clone()
        };
        match acquisition_from_projections(&r, &site_gantry) {
            Ok(got) => {
                assert!(ok, "{anode} with {site}");
                assert_eq!(got.header.anode_filter, site);
            }
            Err(e) => {
                let e = e.to_string();
                assert!(!ok, "{anode} with {site}: {e}");
                assert!(
                    e.contains("FilterMaterial") && e.contains(site.name()) && e.contains(anode),
                    "{e}"
                );
            }
        }
    }
}

/// A cone-beam sweep (issue #28) written as Breast Projection X-Ray and as
/// per-view Digital Mammography objects reads back, on the configured
/// cone-beam system, as the same acquisition (the detector's frames, the
/// system in the header); on another system's configuration it is refused
/// naming the attribute.
#[test]
fn a_cone_beam_projection_object_reads_back_on_its_system() {
    use dbt_pipeline::dicom_input::{acquisition_from_projections, assemble, Gantry};
    let sys = dbt_geometry::ConeSystem::builtin("paper-cone")
        .unwrap()
        .binned(8)
        .unwrap();
    let g = Geometry::builtin("paper-tall").unwrap().binned(8).unwrap();
    dbt_pipeline::rebin::check_site(&sys, &g).unwrap();
    let (rows, cols, views) = (sys.detector.rows, sys.detector.columns, sys.n_views());
    let mut h = header(rows, 45.0);
    h.slice_spacing_mm = g.image.pixel_mm;
    h.geometry = g.clone();
    h.system = Some(sys.clone());
    validate_header(&h).unwrap();
    let counts: Vec<Vec<f32>> = (0..rows)
        .map(|r| {
            (0..views * cols)
                .map(|i| (1000 + (r * 7 + i * 13) % 15000) as f32)
                .collect()
        })
        .collect();
    let acq = Acquisition {
        header: h.clone(),
        counts,
    };
    let frames = dbt_pipeline::dicom_input::frames_of(&acq).unwrap();
    assert_eq!(frames.len(), rows * cols * views);
    let angles: Vec<f64> = (0..views).map(|v| sys.angle_deg(v)).collect();
    let (received, objects) = written_and_read(&acq, &angles);
    // The detector's frames, its square elements.
    assert_eq!((received.rows, received.columns), (rows, cols));
    assert_eq!(received.pixel_spacing_mm, [sys.detector.pitch_mm; 2]);
    let system = Gantry {
        geometry: g.clone(),
        cone: Some(sys.clone()),
        flux: Some(h.flux),
        tube_output_mgy_per_mas: h.tube_output_mgy_per_mas,
        unstated_beam: Some(dbt_dose::xray::AnodeFilter::WRh),
    };
    let back = acquisition_from_projections(&received, &system).unwrap();
    assert_eq!(back.counts, acq.counts);
    assert_eq!(back.header.system.as_ref(), Some(&sys));
    assert_eq!(back.header.slices, rows);
    assert_eq!(back.header.slice_spacing_mm, g.image.pixel_mm);
    // Per view, any order: the same frames.
    let mut per_view: Vec<_> = objects.into_iter().map(|(_, o)| o).collect();
    per_view.reverse();
    let swept = assemble(&per_view, &system).unwrap();
    assert_eq!(
        acquisition_from_projections(&swept, &system)
            .unwrap()
            .counts,
        acq.counts
    );
    // Another system's configuration: the stationary one (other angles),
    // a detector of other rows.
    let victre = dbt_geometry::ConeSystem::builtin("siemens-victre")
        .unwrap()
        .binned(8)
        .unwrap();
    let other = Gantry {
        cone: Some(victre),
        ..system.clone()
    };
    let e = acquisition_from_projections(&received, &other)
        .unwrap_err()
        .to_string();
    assert!(e.contains("XRaySourceIsocenterPrimaryAngle"), "{e}");
    let mut fewer_rows = sys.clone();
    fewer_rows.detector.rows -= 1;
    let other = Gantry {
        cone: Some(fewer_rows),
        ..system
    };
    let e = acquisition_from_projections(&received, &other)
        .unwrap_err()
        .to_string();
    assert!(e.contains("Rows") && e.contains("paper-cone"), "{e}");
}

/// A recorded cone-beam header's system is validated like a loaded one:
/// an impossible one (a negative element pitch) is refused, naming it.
#[test]
fn an_impossible_cone_beam_system_is_refused_by_name() {
    let mut h = header(6, 45.0);
    let mut sys = dbt_geometry::ConeSystem::builtin("paper-cone").unwrap();
    h.system = Some(sys.clone());
    dbt_pipeline::validate_header(&h).unwrap();
    sys.detector.pitch_mm = -0.2;
    h.system = Some(sys);
    let e = dbt_pipeline::validate_header(&h).unwrap_err().to_string();
    assert!(
        e.contains("system") && e.contains("detector.pitch_mm"),
        "{e}"
    );
}

/// Cone-beam frames (issue #28) are checked as read, per detector row
/// against the chords of its own rays through the compression box: a clean
/// Poisson acquisition of the densest tissue filling the box passes without
/// a flag; a stuck element (one value in every view) and a dead one are
/// found in the frames and corrected.
#[test]
fn cone_beam_frames_are_checked_as_read() {
    use dbt_cone::{ConeProjector, VolumeGrid};
    let sys = dbt_geometry::ConeSystem::builtin("paper-cone")
        .unwrap()
        .binned(8)
        .unwrap();
    let g = Geometry::builtin("paper-tall").unwrap().binned(8).unwrap();
    let t = 45.0;
    let (width, depth_mm) = (120.0, 100.0);
    let grid = VolumeGrid {
        lateral: g.image.columns,
        vertical: g.image.rows,
        depth: (depth_mm / g.image.pixel_mm) as usize,
        voxel_mm: g.image.pixel_mm,
    };
    let mu = Tissue::Fibroglandular.mu_per_mm();
    let mut vol = vec![0.0f32; grid.len()];
    let half = g.image.columns as f64 * g.image.pixel_mm / 2.0;
    for d in 0..grid.depth {
        for v in 0..grid.vertical {
            for l in 0..grid.lateral {
                let x = (l as f64 + 0.5) * grid.voxel_mm - half;
                let z = (v as f64 + 0.5) * grid.voxel_mm;
                if x.abs() < width / 2.0 && z < t {
                    vol[grid.index(l, v, d)] = mu;
                }
            }
        }
    }
    let p = ConeProjector::new(&sys, grid)
        .unwrap()
        .forward(&vol)
        .unwrap();
    let (rows, cols, views) = (sys.detector.rows, sys.detector.columns, sys.n_views());
    let counts: Vec<Vec<f32>> = (0..rows)
        .map(|r| {
            let expected: Vec<f32> = (0..views)
                .flat_map(|v| {
                    let at = (v * rows + r) * cols;
                    p[at..at + cols]
                        .iter()
                        .map(|x| (FLUX * (-f64::from(*x)).exp()) as f32)
                        .collect::<Vec<_>>()
                })
                .collect();
            dbt_forward::poisson_counts(&expected, 77 + r as u64)
        })
        .collect();
    let mut h = header(rows, t);
    h.geometry = g.clone();
    h.slice_spacing_mm = g.image.pixel_mm;
    h.system = Some(sys.clone());
    validate_header(&h).unwrap();
    let clean = check_counts(&h, &counts).unwrap();
    assert!(clean.is_empty(), "{:?}", clean.check);
    assert_eq!(clean.check.rays, rows * views * cols);
    // A stuck element and a dead one, in the frames.
    let mut bad = counts.clone();
    let (r, c) = (40, 70);
    for v in 0..views {
        bad[r][v * cols + c] = 9000.0;
    }
    bad[20][3 * cols + 90] = 0.0;
    let d = check_counts(&h, &bad).unwrap();
    assert_eq!((d.check.stuck, d.check.dead), (views, 1), "{:?}", d.check);
    let fixed = d.correct(&mut bad).unwrap();
    assert_eq!(fixed.corrected, views + 1);
    assert!(bad[r][5 * cols + c] != 9000.0 && bad[20][3 * cols + 90] > 0.0);
    assert!(check_counts(&h, &bad).unwrap().is_empty());
    // Through the whole processing: host-sim/tests/cone.rs.
}

/// The chord of a segment through a box: along an axis, diagonal, grazing
/// the box, and missing it.
#[test]
fn chords_in_a_box() {
    use dbt_pipeline::plausibility::chord_in_box;
    let (lo, hi) = ([0.0, 0.0, 0.0], [2.0, 3.0, 4.0]);
    assert!((chord_in_box([1.0, 1.0, -5.0], [1.0, 1.0, 10.0], lo, hi) - 4.0).abs() < 1e-12);
    let diag = chord_in_box([-1.0, -1.5, -2.0], [3.0, 4.5, 6.0], lo, hi);
    assert!(
        (diag - (4.0f64 + 9.0 + 16.0).sqrt()).abs() < 1e-12,
        "{diag}"
    );
    // Ends inside the box: only the part within.
    assert!((chord_in_box([1.0, 1.0, 1.0], [1.0, 1.0, 9.0], lo, hi) - 3.0).abs() < 1e-12);
    assert_eq!(chord_in_box([5.0, 1.0, -1.0], [5.0, 1.0, 9.0], lo, hi), 0.0);
    assert_eq!(chord_in_box([-1.0, 1.0, 5.0], [3.0, 1.0, 5.0], lo, hi), 0.0);
}

/// The scatter removal (issue #27) refuses counts of another shape than the
/// header's, naming both; counts no exposure can give (0, twice the flat
/// field) pass as read for the counts check to name; the others lose
/// scatter, never more than their count allows.
#[test]
fn scatter_removal_checks_its_input_and_keeps_impossible_counts() {
    let removal = dbt_pipeline::descatter::ScatterRemoval::shipped().unwrap();
    let a = acquisition(6, 50.0, 120.0, 50.0, 3);
    let mut short = a.counts.clone();
    short.pop();
    let e = removal
        .apply(&slices(&a.header), &mut short)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("5 rows of counts") && e.contains("6 rows"),
        "{e}"
    );
    let mut c = a.counts.clone();
    c[2][7] = 0.0;
    c[3][11] = 2.0 * FLUX as f32;
    removal.apply(&slices(&a.header), &mut c).unwrap();
    assert_eq!((c[2][7], c[3][11]), (0.0, 2.0 * FLUX as f32));
    for (r, (row, orig)) in c.iter().zip(&a.counts).enumerate() {
        for (k, (got, was)) in row.iter().zip(orig).enumerate() {
            if (r, k) != (2, 7) && (r, k) != (3, 11) && *was > 0.0 {
                assert!(*got < *was && *got >= 0.05 * *was, "{got} from {was}");
            }
        }
    }
}

/// The physics density as the pipeline makes it (`process::physics_density`:
/// the header's flux, thickness and slice spacing handed over, defects
/// corrected first): a block of fat reads no dense tissue, a block of
/// fibroglandular tissue almost all, and a dead element does not change the
/// figure (tolerance: the box's walls, seen by diverging rays, are a rim the
/// edge model reads as fat; the estimator's own tests bound it).
#[test]
fn the_physics_density_reads_fat_as_fat_and_dense_as_dense() {
    let opts = dbt_pipeline::process::PipelineOptions::default();
    let block = |mu: f64, seed: u64| {
        let mut a = acquisition(40, 50.0, 120.0, 50.0, seed);
        let g = a.header.geometry.clone();
        let z0 = g.support_z_mm();
        let expected: Vec<f32> = (0..g.n_views())
            .flat_map(|v| (0..g.n_det()).map(move |k| (v, k)))
            .map(|(v, k)| {
                let (s, p) = g.ray_endpoints_mm(v, k);
                (FLUX * (-mu * chord_in_rect(s, p, -60.0, 60.0, z0, z0 + 50.0)).exp()) as f32
            })
            .collect();
        a.counts = (0..40)
            .map(|i| dbt_forward::poisson_counts(&expected, seed + i))
            .collect();
        a
    };
    let fat = block(Tissue::Adipose.mu_per_mm() as f64, 11);
    let p = dbt_pipeline::process::physics_density(&fat.clone().into_sinograms().unwrap(), &opts)
        .expect("fat");
    assert!(
        p.central.glandularity < 0.03,
        "fat reads {}",
        p.central.glandularity
    );
    let mut dense = block(Tissue::Fibroglandular.mu_per_mm() as f64, 12);
    let p = dbt_pipeline::process::physics_density(&dense.clone().into_sinograms().unwrap(), &opts)
        .expect("dense");
    assert!(
        p.central.glandularity > 0.9,
        "dense reads {}",
        p.central.glandularity
    );
    assert_eq!(p.central.thickness.readout_mm, 50.0);
    let nd = dense.header.geometry.n_det();
    let centre = 12 * nd + nd / 2;
    dense.counts[20][centre] = 0.0;
    let q = dbt_pipeline::process::physics_density(&dense.clone().into_sinograms().unwrap(), &opts)
        .expect("dense, one dead");
    assert!((q.central.glandularity - p.central.glandularity).abs() < 1e-3);
}
