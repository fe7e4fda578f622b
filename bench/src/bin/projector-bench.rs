//! Projector benchmark: median forward and adjoint times of our projector (SIMD
//! and scalar kernels) next to ASTRA's CPU `line_fanflat` projector and a scipy
//! CSR matvec, measured in the same run, with ratios; also the adjointness error
//! and the agreement of the line integrals with ASTRA's line model.
//!
//! ```text
//! cargo run --release -p dbt-bench --bin projector-bench -- [--geometry FILE.toml]
//!     [--binning N] [--reps N] [--warmup N] [--out FILE.json] [--no-peers]
//! ```
//! Prints a table and writes one JSON object (default `bench/results/projector.json`).

use anyhow::{bail, Context, Result};
use clap::Parser;
use dbt_bench::{f32_bytes, median_ms, spread_ms};
use dbt_geometry::Geometry;
use dbt_projector::{dot, Kernel, Projector};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{json, Value};
use std::path::PathBuf;
use std::time::Instant;

/// Projector benchmark: our forward and adjoint (SIMD and scalar) beside
/// ASTRA's CPU projector and a scipy CSR matvec, measured in the same run.
#[derive(Parser)]
#[command(name = "projector-bench")]
struct Args {
    /// A geometry TOML (default: the paper's).
    #[arg(long)]
    geometry: Option<PathBuf>,
    /// Binning of that geometry.
    #[arg(long, default_value_t = 1)]
    binning: usize,
    /// Timed repetitions (the median is reported).
    #[arg(long, default_value_t = 50, value_parser = dbt_bench::at_least_one)]
    reps: usize,
    /// Untimed repetitions first.
    #[arg(long, default_value_t = 5)]
    warmup: usize,
    /// JSON output.
    #[arg(long, default_value = "bench/results/projector.json")]
    out: PathBuf,
    /// Without the ASTRA and scipy peers.
    #[arg(long = "no-peers", action = clap::ArgAction::SetFalse)]
    peers: bool,
}

fn main() -> Result<()> {
    let args = Args::parse();
    let base = match &args.geometry {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            Geometry::from_toml_str(&text).with_context(|| format!("geometry {}", p.display()))?
        }
        None => Geometry::paper(),
    };
    let g = base.binned(args.binning)?;
    let threads = rayon::current_num_threads();
    println!("cpu: {}", dbt_cli::cpu_summary());
    println!("geometry: {}", g.describe());
    println!(
        "threads: {threads}, repetitions: {} (after {} warm-up)",
        args.reps, args.warmup
    );

    let t = Instant::now();
    let proj = Projector::new(&g);
    let build_ms = t.elapsed().as_secs_f64() * 1e3;
    let fast = proj.clone();
    let scalar = proj.clone().with_kernel(Kernel::Scalar);
    // The AVX2 path, forced where a faster one is the default (issue #30).
    let avx2 = proj.clone().with_kernel(Kernel::Avx2);

    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    // Attenuation-like values (per mm) so that line integrals are realistic.
    let img: Vec<f32> = (0..proj.domain_len())
        .map(|_| 0.05 + 0.03 * rng.random::<f32>())
        .collect();
    let sino_in: Vec<f32> = (0..proj.range_len()).map(|_| rng.random::<f32>()).collect();
    let mut sino = vec![0.0f32; proj.range_len()];
    let mut back = vec![0.0f32; proj.domain_len()];

    let fwd = spread_ms(args.warmup, args.reps, || {
        let _ = fast.forward(&img, &mut sino);
    });
    let adj = spread_ms(args.warmup, args.reps, || {
        let _ = fast.adjoint(&sino_in, &mut back);
    });
    let (fwd_ms, adj_ms) = (fwd.median, adj.median);
    let (afwd_ms, aadj_ms) = if avx2.kernel() == Kernel::Avx2 && fast.kernel() != Kernel::Avx2 {
        (
            median_ms(args.warmup, args.reps, || {
                let _ = avx2.forward(&img, &mut sino);
            }),
            median_ms(args.warmup, args.reps, || {
                let _ = avx2.adjoint(&sino_in, &mut back);
            }),
        )
    } else {
        (f64::NAN, f64::NAN)
    };
    let sreps = (args.reps / 5).max(3);
    let sfwd_ms = median_ms(1, sreps, || {
        let _ = scalar.forward(&img, &mut sino);
    });
    let sadj_ms = median_ms(1, sreps, || {
        let _ = scalar.adjoint(&sino_in, &mut back);
    });
    fast.forward(&img, &mut sino)?;
    fast.adjoint(&sino_in, &mut back)?;
    let lhs = dot(&sino, &sino_in);
    let rhs = dot(&img, &back);
    let adjoint_rel_error = (lhs - rhs).abs() / lhs.abs();

    let t = Instant::now();
    let csr = proj.to_csr();
    let csr_build_ms = t.elapsed().as_secs_f64() * 1e3;

    let peers = if args.peers {
        run_peers(
            &g,
            &img,
            &sino,
            &sino_in,
            &back,
            &csr.to_bytes(),
            args.reps,
            args.warmup,
        )
    } else {
        json!({"skipped": true})
    };
    let num = |k: &str| peers.get(k).and_then(Value::as_f64);

    println!();
    println!(
        "{:<34} {:>10} {:>10}",
        "implementation", "forward", "adjoint"
    );
    println!(
        "{:<34} {:>8.2}ms {:>8.2}ms",
        format!("ours, {:?}, {threads} threads", fast.kernel()),
        fwd_ms,
        adj_ms
    );
    println!(
        "{:<34} {:>10} {:>10}",
        "  (its p10-p90 over the repetitions)",
        format!("{:.2}-{:.2}", fwd.p10, fwd.p90),
        format!("{:.2}-{:.2}", adj.p10, adj.p90)
    );
    if afwd_ms.is_finite() {
        println!(
            "{:<34} {:>8.2}ms {:>8.2}ms",
            format!("ours, Avx2 (forced), {threads} threads"),
            afwd_ms,
            aadj_ms
        );
    }
    println!(
        "{:<34} {:>8.2}ms {:>8.2}ms",
        format!("ours, scalar, {threads} threads"),
        sfwd_ms,
        sadj_ms
    );
    let row = |name: &str, f: Option<f64>, a: Option<f64>| {
        let s = |v: Option<f64>| v.map_or("n/a".to_string(), |x| format!("{x:.2}ms"));
        println!("{:<34} {:>10} {:>10}", name, s(f), s(a));
    };
    row(
        "ASTRA line_fanflat (CPU, 1 thread)",
        num("astra_forward_ms"),
        num("astra_adjoint_ms"),
    );
    row(
        "scipy CSR matvec (1 thread)",
        num("csr_forward_ms"),
        num("csr_adjoint_ms"),
    );
    println!();
    let ratio = |peer: Option<f64>, ours: f64| peer.map(|p| p / ours);
    let show = |v: Option<f64>| v.map_or("n/a".into(), |x| format!("{x:.1}x"));
    println!(
        "speed-up vs ASTRA: forward {}, adjoint {}",
        show(ratio(num("astra_forward_ms"), fwd_ms)),
        show(ratio(num("astra_adjoint_ms"), adj_ms))
    );
    println!(
        "speed-up vs CSR:   forward {}, adjoint {}",
        show(ratio(num("csr_forward_ms"), fwd_ms)),
        show(ratio(num("csr_adjoint_ms"), adj_ms))
    );
    println!("adjoint test |<Px,y> - <x,P*y>| / |<Px,y>| = {adjoint_rel_error:.2e}");
    if let Some(e) = num("astra_vs_ours_forward_rel_l2") {
        println!(
            "line integrals vs ASTRA line model: relative L2 {e:.2e} (worst view {:.2e}); adjoint {:.2e}",
            num("astra_vs_ours_forward_worst_view_rel_l2").unwrap_or(f64::NAN),
            num("astra_vs_ours_adjoint_rel_l2").unwrap_or(f64::NAN)
        );
    }
    for k in ["astra_error", "csr_error"] {
        if let Some(e) = peers.get(k) {
            println!("peer unavailable ({k}): {e}");
        }
    }
    println!(
        "projector construction {build_ms:.1} ms, CSR export {csr_build_ms:.1} ms ({} non-zeros)",
        csr.nnz()
    );

    let result = json!({
        "geometry": g.describe(),
        "geometry_toml": g.to_toml_string(),
        "threads": threads,
        "kernel": format!("{:?}", fast.kernel()),
        "reps": args.reps,
        "forward_ms": fwd_ms,
        "adjoint_ms": adj_ms,
        "forward_p10_p90_ms": [fwd.p10, fwd.p90],
        "adjoint_p10_p90_ms": [adj.p10, adj.p90],
        "avx2_forced_forward_ms": if afwd_ms.is_finite() { json!(afwd_ms) } else { Value::Null },
        "avx2_forced_adjoint_ms": if aadj_ms.is_finite() { json!(aadj_ms) } else { Value::Null },
        "cpu": dbt_cli::cpu_summary(),
        "scalar_forward_ms": sfwd_ms,
        "scalar_adjoint_ms": sadj_ms,
        "astra_forward_ms": num("astra_forward_ms"),
        "astra_adjoint_ms": num("astra_adjoint_ms"),
        "csr_forward_ms": num("csr_forward_ms"),
        "csr_adjoint_ms": num("csr_adjoint_ms"),
        "speedup_vs_astra_forward": ratio(num("astra_forward_ms"), fwd_ms),
        "speedup_vs_astra_adjoint": ratio(num("astra_adjoint_ms"), adj_ms),
        "speedup_vs_csr_forward": ratio(num("csr_forward_ms"), fwd_ms),
        "adjoint_rel_error": adjoint_rel_error,
        "astra_vs_ours_forward_rel_l2": num("astra_vs_ours_forward_rel_l2"),
        "astra_vs_ours_forward_worst_view_rel_l2": num("astra_vs_ours_forward_worst_view_rel_l2"),
        "astra_vs_ours_adjoint_rel_l2": num("astra_vs_ours_adjoint_rel_l2"),
        "construction_ms": build_ms,
        "csr_export_ms": csr_build_ms,
        "csr_nnz": csr.nnz(),
        "peers": peers,
    });
    if let Some(dir) = args.out.parent() {
        if !dir.as_os_str().is_empty() {
            std::fs::create_dir_all(dir)?;
        }
    }
    std::fs::write(&args.out, serde_json::to_string_pretty(&result)?)?;
    println!("wrote {}", args.out.display());
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn run_peers(
    g: &Geometry,
    img: &[f32],
    fwd: &[f32],
    sino_in: &[f32],
    adj: &[f32],
    csr: &[u8],
    reps: usize,
    warmup: usize,
) -> Value {
    let dir = std::env::temp_dir().join(format!("dbt-projector-bench-{}", std::process::id()));
    let run = || -> Result<Value> {
        std::fs::create_dir_all(&dir)?;
        let files = [
            ("image", f32_bytes(img)),
            ("ours_forward", f32_bytes(fwd)),
            ("sinogram", f32_bytes(sino_in)),
            ("ours_adjoint", f32_bytes(adj)),
            ("csr", csr.to_vec()),
        ];
        let mut job = json!({"geometry": g, "reps": reps, "warmup": warmup});
        for (name, bytes) in files {
            let p = dir.join(format!("{name}.bin"));
            std::fs::write(&p, bytes)?;
            job[name] = json!(p);
        }
        let job_path = dir.join("job.json");
        std::fs::write(&job_path, job.to_string())?;
        let script = concat!(env!("CARGO_MANIFEST_DIR"), "/peers/projector_peers.py");
        let python = std::env::var("PYTHON").unwrap_or_else(|_| "python3".into());
        let out = std::process::Command::new(&python)
            .arg(script)
            .arg(&job_path)
            .env("OMP_NUM_THREADS", "1")
            .output()
            .with_context(|| format!("running {python} {script}"))?;
        if !out.status.success() {
            bail!(
                "peer script failed: {}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        Ok(serde_json::from_slice(&out.stdout)?)
    };
    let v =
        run().unwrap_or_else(|e| json!({"astra_error": e.to_string(), "csr_error": e.to_string()}));
    let _ = std::fs::remove_dir_all(&dir);
    v
}
