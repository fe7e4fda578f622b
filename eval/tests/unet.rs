//! The U-Net baseline's Rust runtime (tract) against the PyTorch reference
//! stored with the shipped model (`models/unet-x4/fixtures`, written by
//! `training/dbtor/export_unet.py`), and refusals.

use dbt_dbtor::DbtorError;
use dbt_eval::unet::Unet;
use std::path::{Path, PathBuf};

fn model_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/unet-x4")
}

fn read_f32(p: &Path) -> Vec<f32> {
    std::fs::read(p)
        .unwrap()
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// tract against PyTorch on the fixtures: max abs difference below 1e-4 in
/// network units (the same rule as the DBToR blocks; both run the same f32
/// convolutions in another order, ~1e-6 per layer over 23 layers).
#[test]
fn tract_matches_pytorch() {
    let dir = model_dir();
    let u = Unet::load(&dir).unwrap();
    let xs = u.manifest().normalisation.x_scale_per_mm as f32;
    assert!(!u.manifest().fixtures.is_empty());
    for fx in &u.manifest().fixtures {
        let fbp = read_f32(&dir.join(&fx.files["fbp"]));
        let want = read_f32(&dir.join(&fx.files["torch_fp32"]));
        let got = u.network_output(&fbp).unwrap();
        // reconstruct: the same with the negative values zeroed.
        let clamped: Vec<f32> = got.iter().map(|v| v.max(0.0)).collect();
        assert_eq!(u.reconstruct(&fbp).unwrap(), clamped);
        let d = got
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b).abs() / xs)
            .fold(0.0f32, f32::max);
        eprintln!("{}: max |tract - PyTorch| = {d:.2e} network units", fx.name);
        assert!(d < 1e-4, "{}: {d}", fx.name);
    }
}

/// The shipped model folder (files and fixtures) copied to a temporary one.
fn copy_of_model() -> tempfile::TempDir {
    let from = model_dir();
    let t = tempfile::tempdir().unwrap();
    for e in std::fs::read_dir(&from).unwrap() {
        let e = e.unwrap();
        if e.file_type().unwrap().is_file() {
            std::fs::copy(e.path(), t.path().join(e.file_name())).unwrap();
        }
    }
    std::fs::create_dir(t.path().join("fixtures")).unwrap();
    for e in std::fs::read_dir(from.join("fixtures")).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), t.path().join("fixtures").join(e.file_name())).unwrap();
    }
    t
}

#[test]
fn tampered_or_wrong_input_is_refused() {
    let t = copy_of_model();
    let u = Unet::load(t.path()).unwrap();
    let n = u.geometry().n_pixels();
    assert!(u.reconstruct(&vec![0.0; n - 1]).is_err());
    let mut x = vec![0.0; n];
    x[5] = f32::INFINITY;
    assert!(u
        .reconstruct(&x)
        .unwrap_err()
        .to_string()
        .contains("pixel 5"));
    let victim = t.path().join("unet.onnx");
    let mut bytes = std::fs::read(&victim).unwrap();
    let k = bytes.len() / 3;
    bytes[k] ^= 0x10;
    std::fs::write(&victim, bytes).unwrap();
    match Unet::load(t.path()) {
        Err(DbtorError::Checksum { path, .. }) => assert!(path.ends_with("unet.onnx")),
        other => panic!("expected a checksum error, got {other:?}"),
    }
}

/// The shipped U-Net takes images of any height (its manifest says
/// `any_rows`): at its own height `load_with_rows` is `load`, bit for bit;
/// at the 104 mm image's 130 rows it runs and returns that image; without
/// `any_rows` another height is refused, naming both.
#[test]
fn other_image_heights_only_where_the_manifest_allows() {
    let dir = model_dir();
    let u = Unet::load(&dir).unwrap();
    assert!(u.manifest().any_rows);
    let rows = u.geometry().image.rows;
    let fx = &u.manifest().fixtures[0];
    let fbp = read_f32(&dir.join(&fx.files["fbp"]));
    let same = Unet::load_with_rows(&dir, Some(rows)).unwrap();
    assert_eq!(
        same.network_output(&fbp).unwrap(),
        u.network_output(&fbp).unwrap()
    );

    let tall = Unet::load_with_rows(&dir, Some(130)).unwrap();
    assert_eq!(tall.geometry().image.rows, 130);
    let cols = tall.geometry().image.columns;
    // The fixture's image on the bottom rows (the breast lies on the
    // support), air above.
    let mut x = vec![0.0; (130 - rows) * cols];
    x.extend_from_slice(&fbp);
    let out = tall.reconstruct(&x).unwrap();
    assert_eq!(out.len(), 130 * cols);
    assert!(out.iter().all(|v| v.is_finite() && *v >= 0.0));
    assert!(
        tall.reconstruct(&fbp).is_err(),
        "a 75-row image to the 130-row network"
    );

    let t = copy_of_model();
    let mpath = t.path().join("manifest.json");
    let text = std::fs::read_to_string(&mpath).unwrap();
    std::fs::write(
        &mpath,
        text.replace("\"any_rows\": true", "\"any_rows\": false"),
    )
    .unwrap();
    let e = Unet::load_with_rows(t.path(), Some(130))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("130") && e.contains(&rows.to_string()) && e.contains("any_rows"),
        "{e}"
    );
}
