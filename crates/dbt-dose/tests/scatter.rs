//! The detector scoring of the Monte Carlo engine (issue #27): primary by
//! Beer-Lambert, the CsI layer's energy weighting, energy conservation,
//! and the scatter-to-primary ratio against a published measurement.
//! Statistical tolerances are 4-5 standard errors (deterministic for a
//! seed: a failure means a real change, not bad luck).

use dbt_dose::scatter::{paper_detector, slab_spr};
use dbt_dose::tables::elements;
use dbt_dose::{run_scored, DetectorScore, Material, PointSource, Scene, Spectrum, VoxelGrid};
use dbt_materials::{AIR, CSI, WATER};

/// 40 x 40 x 20 mm of water on z in [0, 20], a near-vacuum world.
fn water_slab() -> Scene {
    let els = elements().unwrap();
    let dims = [40, 40, 20];
    let n: usize = dims.iter().product();
    Scene {
        materials: vec![
            Material::new("vacuum", 1e-30, AIR.elements, els).unwrap(),
            Material::medium(&WATER, els).unwrap(),
        ],
        grid: VoxelGrid {
            origin: [-20.0, -20.0, 0.0],
            voxel_mm: 1.0,
            dims,
            material: vec![1; n],
            tally: vec![0; n],
        },
        boxes: vec![],
        world_material: 0,
        world_min: [-500.0; 3],
        world_max: [500.0; 3],
        n_tallies: 0,
        summary: Default::default(),
    }
}

/// A 2 x 2 mm field on a detector 10 mm under the slab, the source 400 mm
/// above it: every primary photon meets the detector at normal incidence
/// to within 1e-5.
fn narrow_beam(e: f64) -> PointSource {
    PointSource::rect_z(
        [0.0, 0.0, 400.0],
        [-1.0, 1.0],
        [-1.0, 1.0],
        -10.0,
        Spectrum::mono(e).unwrap(),
    )
}

/// Primary photons reach the detector by Beer-Lambert through the slab;
/// an ideal detector records their energy, a 200 um CsI layer
/// `E (1 - exp(-mu t))`; energy stays conserved with the detector ending
/// the photons it records; the scattered signal is recorded apart.
#[test]
fn the_detector_records_primary_by_beer_lambert_and_energy_is_conserved() {
    let scene = water_slab();
    let e = 20.0;
    let mu = Material::medium(&WATER, elements().unwrap())
        .unwrap()
        .mu(e)
        .total();
    let n = 400_000u64;
    let ideal = DetectorScore {
        pixel_mm: 0.5,
        absorber: None,
        gate_z_mm: None,
    };
    let r = run_scored(&scene, &narrow_beam(e), n, 8, 5, &ideal).unwrap();
    let t = &r.total;
    let primary: f64 = t.detector_primary.iter().sum();
    // Every uncollided photon ends on the detector with its whole energy.
    assert!(
        (primary - e * t.uncollided_escaped as f64).abs() < 1e-9 * primary,
        "{primary} vs {}",
        e * t.uncollided_escaped as f64
    );
    let frac = t.uncollided_escaped as f64 / n as f64;
    let want = (-mu * 20.0).exp();
    let se = (want * (1.0 - want) / n as f64).sqrt();
    assert!((frac - want).abs() < 4.5 * se, "{frac} vs {want} (se {se})");
    let out: f64 = t.deposited_kev.iter().sum::<f64>() + t.escaped_kev;
    assert!((out - t.emitted_kev).abs() < 1e-9 * t.emitted_kev);
    let scatter: f64 = t.detector_scatter.iter().sum();
    assert!(scatter > 0.0 && scatter + primary <= t.escaped_kev * (1.0 + 1e-12));

    let csi = Material::medium(&CSI, elements().unwrap()).unwrap();
    let eta = 1.0 - (-csi.mu(e).total() * 0.2).exp();
    let with_csi = DetectorScore {
        pixel_mm: 0.5,
        absorber: Some((csi, 0.2)),
        gate_z_mm: None,
    };
    let r = run_scored(&scene, &narrow_beam(e), n, 8, 5, &with_csi).unwrap();
    let p: f64 = r.total.detector_primary.iter().sum();
    let want = e * eta * r.total.uncollided_escaped as f64;
    assert!((p / want - 1.0).abs() < 1e-5, "{p} vs {want}");
    // The same photons as the ideal run (same seed): only the weighting differs.
    assert_eq!(r.total.uncollided_escaped, t.uncollided_escaped);

    let e = DetectorScore {
        pixel_mm: 0.0,
        absorber: None,
        gate_z_mm: None,
    };
    let err = run_scored(&scene, &narrow_beam(20.0), 10, 1, 1, &e).unwrap_err();
    assert!(err.to_string().contains("pixel 0 mm"), "{err}");
}

/// The scatter-to-primary ratio without a grid behind a CsI flat panel at
/// the centre of the field: Carton et al. 2009 (Med Phys 36:920,
/// PMC2736748) measured 0.35 for 20 mm of breast-equivalent phantom and
/// 1.34 for 80 mm (Rh/Cu at 35-49 kV; SPR falls about 9 % over that range,
/// so a 27-31 kV W/Rh beam reads slightly higher; their field, air gap and
/// phantoms are not ours, nor is their glare, measured apart at 0.10 of
/// the primary). Tolerance 15 % of the published value for those
/// differences; the engine's own standard error is under 5 % (a 30 mm
/// region: 80 mm of tissue lets through 0.6 % of the primary).
#[test]
fn spr_of_20_and_80_mm_breasts_matches_carton_2009() {
    let score = paper_detector(200.0, 2.0).unwrap();
    for (t, published, photons) in [(20.0, 0.35, 6_000_000u64), (80.0, 1.34, 60_000_000)] {
        let spec = dbt_dose::xray::paper_spectrum(t).unwrap().spectrum.unwrap();
        let r = slab_spr(t, 100.0, 0.5, &spec, 0.0, &score, 30.0, photons, 11).unwrap();
        assert!(
            r.spr.se < 0.05 * r.spr.value,
            "{t} mm: SPR {} +- {}",
            r.spr.value,
            r.spr.se
        );
        assert!(
            (r.spr.value / published - 1.0).abs() < 0.15,
            "{t} mm: SPR {} +- {}, Carton et al. {published}",
            r.spr.value,
            r.spr.se
        );
    }
}
