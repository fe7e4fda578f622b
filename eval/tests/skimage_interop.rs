//! Our L2 / PSNR / SSIM against scikit-image on the same images (agreement
//! 1e-4: SSIM absolute, MSE and PSNR relative). Needs python3 with the
//! packages of `eval/peers/requirements.txt` (`scripts/install-test-deps.sh` installs them); a
//! missing peer fails the test with the install command.

use dbt_forward::NoiseLevel;
use dbt_geometry::Geometry;
use dbt_metrics::{data_range, mse, psnr, score, ssim, RegionSsim, Shape};
use dbt_projector::Projector;
use dbt_recon::{mltr, Fbp, MltrOptions};
use std::path::Path;
use std::process::Command;

fn write_f32(path: &Path, v: &[f32]) {
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    std::fs::write(path, bytes).unwrap();
}

fn peer(dir: &Path, a: &[f32], b: &[f32], shape: Shape) -> serde_json::Value {
    let (pa, pb) = (dir.join("a.f32"), dir.join("b.f32"));
    write_f32(&pa, a);
    write_f32(&pb, b);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("peers/metrics_peer.py");
    let out = Command::new("python3")
        .arg(&script)
        .arg(&pa)
        .arg(&pb)
        .arg(shape.rows.to_string())
        .arg(shape.cols.to_string())
        .output()
        .expect("python3 not found: install it and `pip install -r eval/peers/requirements.txt`");
    assert!(
        out.status.success(),
        "scikit-image peer failed (pip install -r eval/peers/requirements.txt):\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

fn compare(dir: &Path, name: &str, a: &[f32], b: &[f32], shape: Shape) {
    let p = peer(dir, a, b, shape);
    let r = data_range(a);
    let (m, ps, ss) = (
        mse(a, b),
        psnr(a, b, r).unwrap(),
        ssim(shape, a, b, r).unwrap(),
    );
    let (pm, pp, pss) = (
        p["mse"].as_f64().unwrap(),
        p["psnr"].as_f64().unwrap(),
        p["ssim"].as_f64().unwrap(),
    );
    eprintln!("{name}: mse {m:.6e}/{pm:.6e} psnr {ps:.6}/{pp:.6} ssim {ss:.6}/{pss:.6}");
    assert!(
        (m - pm).abs() <= 1e-4 * pm,
        "{name}: MSE {m} vs skimage {pm}"
    );
    assert!(
        (ps - pp).abs() <= 1e-4 * pp.abs(),
        "{name}: PSNR {ps} vs skimage {pp}"
    );
    assert!(
        (ss - pss).abs() <= 1e-4,
        "{name}: SSIM {ss} vs skimage {pss}"
    );
    // The SSIM by region against skimage's full map split the same way
    // (shares are window counts over the total, equal to rounding; means to
    // the SSIM's 1e-4).
    let regions = score(shape, a, b).unwrap().ssim_regions;
    for (key, ours) in [
        ("inside", regions.inside),
        ("outline", regions.outline),
        ("air", regions.air),
    ] {
        let RegionSsim { mean, share } = ours;
        let theirs = &p["ssim_regions"][key];
        eprintln!(
            "{name} {key}: ssim {mean:.6}/{} share {share:.6}/{}",
            theirs["mean"], theirs["share"]
        );
        let their_share = theirs["share"].as_f64().unwrap();
        assert!(
            (share - their_share).abs() < 1e-12,
            "{name} {key}: share {share} vs skimage {their_share}"
        );
        match theirs["mean"].as_f64() {
            Some(m) => assert!(
                (mean - m).abs() <= 1e-4,
                "{name} {key}: SSIM {mean} vs skimage {m}"
            ),
            None => assert!(mean.is_nan(), "{name} {key}: skimage has no such window"),
        }
    }
}

#[test]
fn metrics_match_scikit_image() {
    let dir = tempfile::tempdir().unwrap();
    // A real evaluation pair: a test-set slice against its MLTR and FBP
    // reconstructions at N = 8, in 1/cm as the evaluation uses.
    let g = Geometry::paper().binned(4).unwrap();
    let proj = Projector::new(&g);
    let (set, _) = dbt_eval::test_set(&g, &proj, 1, 1, &[NoiseLevel::Poisson(8)]).unwrap();
    let s = &set[0].1;
    let shape = Shape {
        rows: g.image.rows,
        cols: g.image.columns,
    };
    let per_cm = |v: &[f32]| v.iter().map(|x| x * 10.0).collect::<Vec<f32>>();
    let truth = per_cm(&s.mu);
    let opts = MltrOptions {
        iterations: 20,
        track_likelihood: false,
    };
    let (rec, _) = mltr(&proj, &s.counts[0], s.flux[0], &s.mask, &opts).unwrap();
    compare(dir.path(), "MLTR", &truth, &per_cm(&rec), shape);
    let line = dbt_forward::log_transform(&s.counts[0], s.flux[0]);
    let f = Fbp::new(&g).reconstruct(&line, Some(&s.mask)).unwrap();
    compare(dir.path(), "FBP", &truth, &per_cm(&f), shape);
    // An odd-sized random pair.
    let shape = Shape { rows: 31, cols: 47 };
    let mut x = 12345u64;
    let mut rnd = || {
        x = x
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (x >> 40) as f32 / (1u64 << 24) as f32
    };
    let a: Vec<f32> = (0..31 * 47).map(|_| rnd()).collect();
    let b: Vec<f32> = a.iter().map(|v| v * 0.8 + 0.3 * rnd()).collect();
    compare(dir.path(), "random", &a, &b, shape);
}
