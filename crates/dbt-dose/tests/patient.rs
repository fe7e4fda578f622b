//! Patient MGD set-up: field geometry, kerma normalisation, and the
//! patient-specific estimate against the homogeneous model where they must
//! agree (a finely mixed breast).

use dbt_dose::patient::{air_kerma_per_photon, dbt_views, mgd, view_source, Breast, Model};
use dbt_dose::xray::paper_spectrum;
use dbt_dose::{PointSource, Spectrum};

#[test]
fn solid_angle_of_the_field() {
    // Square of half-side a centred under the source: 4 atan(a^2 / (h sqrt(h^2 + 2 a^2))).
    let (a, h) = (50.0, 300.0);
    let s = PointSource::rect_z(
        [0.0, 0.0, h],
        [-a, a],
        [-a, a],
        0.0,
        Spectrum::mono(20.0).unwrap(),
    );
    let want = 4.0 * (a * a / (h * (h * h + 2.0 * a * a).sqrt())).atan();
    assert!((s.solid_angle() - want).abs() < 1e-12 * want);
    // The rotating detector subtends the same solid angle at every view.
    let sp = Spectrum::mono(20.0).unwrap();
    let o0 = view_source(0.0, sp.clone()).solid_angle();
    let o24 = view_source(24.0, sp).solid_angle();
    assert!((o0 - o24).abs() < 1e-12);
}

#[test]
fn air_kerma_follows_inverse_square() {
    let src = view_source(0.0, Spectrum::mono(20.0).unwrap());
    let k1 = air_kerma_per_photon(&src, [60.0, 0.0, 70.0]).unwrap();
    let k2 = air_kerma_per_photon(&src, [60.0, 0.0, 20.0]).unwrap();
    let r = |z: f64| (60.0f64.powi(2) + (700.0f64 - z).powi(2)).sqrt();
    // Inverse square times the extra air between the two points.
    let air_mu_20kev = 0.778 * 0.001205 / 10.0; // (mu/rho) 0.778 cm^2/g (NIST), 1/mm
    let want = (r(70.0) / r(20.0)).powi(2) * (-(r(20.0) - r(70.0)) * air_mu_20kev).exp();
    assert!((k2 / k1 - want).abs() < 2e-3, "{} vs {want}", k2 / k1);
}

/// A 40 mm thick slab breast, 80 x 60 mm, 1 mm skin, interior a fine
/// checkerboard of glandular and adipose voxels (glandular fraction by
/// count 1/2).
fn checker_breast() -> (Vec<u8>, [usize; 3]) {
    let dims = [80, 40, 60];
    let mut l = vec![1u8; dims.iter().product()];
    for d in 0..dims[2] {
        for v in 0..dims[1] {
            for x in 0..dims[0] {
                let i = (d * dims[1] + v) * dims[0] + x;
                let edge =
                    v == 0 || v == dims[1] - 1 || x == 0 || x == dims[0] - 1 || d == dims[2] - 1;
                l[i] = if edge {
                    2
                } else if (x + v + d) % 2 == 0 {
                    3
                } else {
                    1
                };
            }
        }
    }
    (l, dims)
}

#[test]
fn finely_mixed_breast_matches_the_homogeneous_model() {
    let (labels, dims) = checker_breast();
    let b = Breast {
        dims,
        voxel_mm: 1.0,
        labels: &labels,
    };
    let spec = paper_spectrum(40.0).unwrap().spectrum.unwrap();
    let views = [0.0];
    let p = mgd(&b, Model::PatientSpecific, &spec, &views, 4_000_000, 20, 1).unwrap();
    let m = mgd(&b, Model::Homogeneous, &spec, &views, 4_000_000, 20, 1).unwrap();
    eprintln!("patient {:?}\nmodel {:?}", p, m);
    let diff = p.mgd_per_kerma / m.mgd_per_kerma - 1.0;
    let se = (p.mgd_rel_uncertainty.powi(2) + m.mgd_rel_uncertainty.powi(2)).sqrt();
    assert!(
        diff.abs() < 4.0 * se + 0.005,
        "patient vs model: {diff} (se {se})"
    );
    assert!(p.mgd_rel_uncertainty < 0.02);
    // A conversion factor of the published magnitude (Dance: g c s about
    // 0.2-0.35 mGy/mGy for 40-50 mm, ~50 % glandular, W/Rh).
    assert!(
        (0.15..0.5).contains(&m.mgd_per_kerma),
        "{}",
        m.mgd_per_kerma
    );
}

#[test]
fn dbt_views_and_bad_breasts() {
    let v = dbt_views();
    assert_eq!(v.len(), 25);
    assert_eq!(v[0], -24.0);
    assert_eq!(v[24], 24.0);
    let spec = Spectrum::mono(20.0).unwrap();
    let bad = Breast {
        dims: [2, 2, 2],
        voxel_mm: 1.0,
        labels: &[0; 7],
    };
    assert!(mgd(&bad, Model::PatientSpecific, &spec, &[0.0], 100, 2, 1).is_err());
    let unknown = Breast {
        dims: [2, 1, 1],
        voxel_mm: 1.0,
        labels: &[3, 9],
    };
    let e = mgd(&unknown, Model::PatientSpecific, &spec, &[0.0], 100, 2, 1)
        .unwrap_err()
        .to_string();
    assert!(e.contains("label 9"), "{e}");
    let fat = Breast {
        dims: [2, 1, 1],
        voxel_mm: 1.0,
        labels: &[1, 1],
    };
    assert!(mgd(&fat, Model::PatientSpecific, &spec, &[0.0], 100, 2, 1).is_err());
}

#[test]
fn energy_absorption_matches_nist_for_water() {
    // NIST (Hubbell and Seltzer) mu_en/rho of water: 15 keV 1.374, 20 keV
    // 0.5503, 30 keV 0.1557 cm^2/g. Our local-deposition mu_en agrees within
    // 2 % (the photoelectric data sets differ by about that).
    let w = dbt_dose::Material::new(
        "water",
        1.0,
        dbt_materials::WATER.elements,
        dbt_dose::tables::elements().unwrap(),
    )
    .unwrap();
    for (e, nist) in [(15.0, 1.374), (20.0, 0.5503), (30.0, 0.1557)] {
        let ours = w.mu_en(e) * 10.0; // 1/mm at 1 g/cm^3 -> cm^2/g
        assert!(
            (ours / nist - 1.0).abs() < 0.02,
            "{e} keV: {ours} vs NIST {nist}"
        );
    }
}
