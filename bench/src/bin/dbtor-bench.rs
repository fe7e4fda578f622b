//! DBToR slice benchmark (issue #5): one run measures, on the same ONNX block
//! files of a shipped model, tract fp32 and int8, onnxruntime fp32 and int8
//! (the PyPI peer, `bench/peers/ort_blocks.py`, blocks only), and the fast
//! path fp32 and int8, at the paper's full geometry and at the model's own,
//! with per-block and per-slice medians, GFLOP/s, ratios, the distance to
//! this CPU's measured peak (the physical floor: register-only FMA and VNNI
//! loops, and AMX-INT8's `tdpbusd` for the AMX rows where the CPU has it)
//! and the slice buffers. The rows' slices are timed in interleaved rounds.
//!
//! ```text
//! cargo run --release -p dbt-bench --bin dbtor-bench -- [--model DIR] [--reps N]
//!     [--geometry paper|model|both] [--out FILE.json] [--no-peers] [--no-tract]
//!     [--mixed BLOCKS]   (adds "fast mixed": int8 with BLOCKS in fp32)
//! ```
//! The blocks are fully convolutional: at the paper geometry the trained
//! model's blocks run unchanged on the 1000 x 300 image and 25 x 1280
//! sinogram. onnxruntime runs the blocks alone; its slice time adds the
//! projector time measured for the fast fp32 variant in the same run (the
//! same projector would serve it), which is stated in the table.

use anyhow::{bail, Context, Result};
use clap::Parser;
use dbt_bench::median;
use dbt_dbtor::{Dbtor, Engine, Kernel, Precision, Role, SliceProfile};
use dbt_geometry::Geometry;
use dbt_projector::Projector;
use serde_json::{json, Map, Value};
use std::path::PathBuf;
use std::process::Command;
use std::time::Instant;

/// DBToR slice benchmark: tract, onnxruntime and the fast path, fp32 and
/// int8, on one model's block files.
#[derive(Parser)]
#[command(name = "dbtor-bench")]
struct Args {
    /// The model folder.
    #[arg(long, default_value = "models/dbtor-x4")]
    model: PathBuf,
    /// Repetitions per measurement (the median is reported).
    #[arg(long, default_value_t = 5, value_parser = dbt_bench::at_least_one)]
    reps: usize,
    /// At the paper's full geometry, the model's own, or both.
    #[arg(long, value_enum, default_value_t = Where::Both)]
    geometry: Where,
    /// JSON output.
    #[arg(long, default_value = "bench/results/dbtor.json")]
    out: PathBuf,
    /// Without the onnxruntime peer.
    #[arg(long = "no-peers", action = clap::ArgAction::SetFalse)]
    peers: bool,
    /// Without tract.
    #[arg(long = "no-tract", action = clap::ArgAction::SetFalse)]
    tract: bool,
    /// Also the fast engine forced down to each slower kernel this CPU runs
    /// (AVX2, portable), as `DBTOR_KERNEL` would.
    #[arg(long)]
    all_kernels: bool,
    /// Only these forced kernel levels (e.g. `avx2,avx-vnni`, or `amx`
    /// where the CPU has it) besides the best, instead of every one
    /// (`--all-kernels`).
    #[arg(long, value_delimiter = ',', value_parser = parse_kernel)]
    kernels: Vec<Kernel>,
    /// Also each int8 row that convolves by Winograd (AVX2, AVX-VNNI) with
    /// its direct convolution instead (`DBTOR_WINOGRAD=off`): the same bits.
    #[arg(long)]
    direct: bool,
    /// Also each fp32 row of the AVX-512 and AVX2 kernels convolving by
    /// Winograd (`DBTOR_FP32_WINOGRAD=on`, opt-in: other rounding).
    #[arg(long)]
    fp32_winograd: bool,
    /// Also each int8 row with its blocks run layer by layer over
    /// whole-image buffers instead of in fused bands of rows: the same bits.
    #[arg(long)]
    layered: bool,
    /// Adds "fast mixed": int8 with these blocks in fp32 (e.g.
    /// `primal08,primal09`).
    #[arg(long, value_parser = parse_blocks)]
    mixed: Option<Blocks>,
}

/// A kernel level by its name (`DBTOR_KERNEL`'s names).
fn parse_kernel(s: &str) -> Result<Kernel, String> {
    Kernel::parse(s).ok_or_else(|| {
        format!(
            "unknown kernel {s:?}: expected one of {}",
            Kernel::ALL.map(|k| k.name()).join(", ")
        )
    })
}

/// Where the slices are timed.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Where {
    /// The paper's full geometry.
    Paper,
    /// The model's own geometry.
    Model,
    /// Both.
    Both,
}

/// A list of block names.
#[derive(Clone)]
struct Blocks(Vec<String>);

fn parse_blocks(s: &str) -> Result<Blocks, String> {
    Ok(Blocks(dbt_dbtor::parse_block_list(s)))
}

/// Peak rates of this CPU on 2 threads: fp32 FMA (GFLOP/s), int8 VNNI and
/// AMX-INT8 (GOP/s; NaN where the AMX kernel does not run), from
/// register-only loops (no memory traffic).
fn measured_peaks() -> (f64, f64, f64) {
    let (fma, vnni) = measured_vector_peaks();
    // (a warm-up run, which also says whether the AMX kernel runs here)
    let amx = if dbt_conv::amx_peak_ops(100_000).is_some() {
        let per_thread: Vec<f64> = std::thread::scope(|s| {
            let h: Vec<_> = (0..2)
                .map(|_| s.spawn(|| dbt_conv::amx_peak_ops(2_000_000).unwrap_or(f64::NAN)))
                .collect();
            h.into_iter()
                .map(|h| h.join().unwrap_or(f64::NAN))
                .collect()
        });
        per_thread.iter().sum::<f64>() / 1e9
    } else {
        f64::NAN
    };
    (fma, vnni, amx)
}

/// [`measured_peaks`]' FMA and VNNI loops.
fn measured_vector_peaks() -> (f64, f64) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512vnni")
            && std::arch::is_x86_feature_detected!("avx512f")
        {
            let iters = 20_000_000u64;
            let run = |int8: bool| {
                let t = Instant::now();
                std::thread::scope(|s| {
                    for _ in 0..2 {
                        s.spawn(move || {
                            // SAFETY: features detected above.
                            unsafe {
                                if int8 {
                                    peak::vnni(iters);
                                } else {
                                    peak::fma(iters);
                                }
                            }
                        });
                    }
                });
                let secs = t.elapsed().as_secs_f64();
                // 24 vectors per iteration; 16 lanes x 2 flops (fp32) or
                // 16 lanes x 4 products x 2 ops (int8), 2 threads.
                let per = if int8 { 24.0 * 128.0 } else { 24.0 * 32.0 };
                2.0 * iters as f64 * per / secs / 1e9
            };
            let _ = run(false);
            return (run(false), run(true));
        }
    }
    (f64::NAN, f64::NAN)
}

#[cfg(target_arch = "x86_64")]
mod peak {
    use std::arch::x86_64::*;

    #[target_feature(enable = "avx512f")]
    pub unsafe fn fma(iters: u64) {
        let a = _mm512_set1_ps(0.999_999);
        let b = _mm512_set1_ps(1e-7);
        let mut acc = [_mm512_set1_ps(1.0); 24];
        for _ in 0..iters {
            for v in acc.iter_mut() {
                *v = _mm512_fmadd_ps(*v, a, b);
            }
        }
        let mut s = _mm512_setzero_ps();
        for v in acc {
            s = _mm512_add_ps(s, v);
        }
        std::hint::black_box(_mm512_reduce_add_ps(s));
    }

    #[target_feature(enable = "avx512f,avx512vnni")]
    pub unsafe fn vnni(iters: u64) {
        let a = _mm512_set1_epi8(3);
        let b = _mm512_set1_epi8(-2);
        let mut acc = [_mm512_setzero_si512(); 24];
        for _ in 0..iters {
            for v in acc.iter_mut() {
                *v = _mm512_dpbusd_epi32(*v, a, b);
            }
        }
        let mut s = _mm512_setzero_si512();
        for v in acc {
            s = _mm512_add_epi32(s, v);
        }
        std::hint::black_box(_mm512_reduce_add_epi32(s));
    }
}

/// One row to run: engine, precision, the blocks kept in fp32, the kernel
/// level forced (`None`: chosen by measurement), and how the row differs
/// from the precision's default.
type Combo<'a> = (Engine, Precision, &'a [String], Option<Kernel>, Variation);

/// How a row runs its blocks.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Variation {
    /// As the firmware loads them.
    Default,
    /// Winograd toggled from the precision's default (int8 direct, fp32 by
    /// Winograd).
    Toggled,
    /// int8 blocks layer by layer over whole-image buffers instead of in
    /// fused bands of rows.
    Layered,
}

struct Variant {
    name: String,
    slice_ms: f64,
    dual_ms: f64,
    primal_ms: f64,
    projector_ms: f64,
    ops: f64,
    load_s: f64,
    buffers_mb: Option<f64>,
    note: String,
}

/// A row's engine, loaded and warmed up, waiting for its timed slices.
struct Loaded {
    name: String,
    d: Dbtor,
    load_s: f64,
    engine: Engine,
    precision: Precision,
}

fn role_median(d: &Dbtor, profs: &[SliceProfile], role: Role) -> f64 {
    let ks: Vec<usize> = d
        .manifest()
        .blocks
        .iter()
        .enumerate()
        .filter(|(_, b)| b.role == role)
        .map(|(k, _)| k)
        .collect();
    median(
        profs
            .iter()
            .flat_map(|p| ks.iter().map(|&k| p.block_ms[k]))
            .collect(),
    )
}

/// RMS difference, 1/mm.
fn rms(a: &[f32], b: &[f32]) -> f64 {
    dbt_metrics::mse(a, b).sqrt()
}

fn bench_geometry(a: &Args, label: &str, g: &Geometry, peaks: (f64, f64, f64)) -> Result<Value> {
    let (rows, cols, views, det) = (g.image.rows, g.image.columns, g.n_views(), g.n_det());
    println!("\n== {label}: image {cols} x {rows}, sinogram {views} x {det} ==");
    // A realistic input: the line integrals of a 50 mm breast of soft tissue
    // (0.05 /mm) with a denser inner region.
    let thickness = 50.0_f64.min(0.8 * rows as f64 * g.image.pixel_mm);
    let mut img = dbt_phantom::thickness_mask(g, thickness);
    for (k, v) in img.iter_mut().enumerate() {
        let (r, c) = (k / cols, k % cols);
        *v *= if (r * 7 + c * 3) % 11 < 4 {
            0.065
        } else {
            0.048
        };
    }
    let mut sino = vec![0.0f32; g.n_rays()];
    Projector::new(g).forward(&img, &mut sino)?;

    let roles: Vec<Role> = dbt_dbtor::ModelManifest::load(&a.model)?
        .blocks
        .iter()
        .map(|b| b.role)
        .collect();
    let mut variants: Vec<Variant> = Vec::new();
    let mut outputs: Vec<(String, Vec<f32>)> = Vec::new();
    let mut loaded: Vec<Loaded> = Vec::new();
    let mut flops = None;
    let mut fast_projector_ms = f64::NAN;
    // The fast engine with each kernel level this CPU runs, fastest first
    // (the levels below the best forced with the same limit DBTOR_KERNEL
    // sets), each precision once per kernel it actually runs (fp32 has no
    // AVX-VNNI kernel: that level runs its AVX2 one).
    // `DBTOR_KERNEL` limits every row as it limits the firmware (issue
    // #52: it did not reach the benchmark, so a row run under
    // `DBTOR_KERNEL=avx2` could be AVX-512's); `amx` asks for the AMX row.
    let env_limit = dbt_dbtor::kernel_limit()?;
    let best = Kernel::best_fp32().max(Kernel::best_int8()).min(env_limit);
    if std::env::var_os(dbt_dbtor::KERNEL_ENV).is_some() {
        println!(
            "{}={}: every fast row runs at most the {} kernels",
            dbt_dbtor::KERNEL_ENV,
            env_limit.name(),
            best.name()
        );
    }
    let forced: Vec<Kernel> = Kernel::ALL
        .into_iter()
        .rev()
        .filter(|k| {
            // AMX only where it runs and asked for (never the default dispatch)
            let runs = *k <= best || (*k == Kernel::Amx && Kernel::amx_available());
            let asked = a.all_kernels
                || a.kernels.contains(k)
                || (*k == Kernel::Amx && env_limit == Kernel::Amx);
            runs && (*k == best || asked)
        })
        .collect();
    // (engine, precision, blocks in fp32, kernel limit, Winograd toggled from
    // the precision's default: int8 direct, fp32 by Winograd)
    // (limit `None`: the kernels chosen by measurement at load, as the
    // firmware chooses them when `DBTOR_KERNEL` is unset: issue #52's
    // "default choice" row, beside the forced ones of the same run)
    let mut combos: Vec<Combo> = Vec::new();
    if std::env::var_os(dbt_dbtor::KERNEL_ENV).is_none() {
        for p in [Precision::Fp32, Precision::Int8] {
            combos.push((Engine::Fast, p, &[][..], None, Variation::Default));
        }
    }
    let mut seen: Vec<(Precision, Kernel)> = Vec::new();
    for k in &forced {
        for (precision, runs) in [
            (Precision::Fp32, Kernel::best_fp32_up_to(*k)),
            (Precision::Int8, Kernel::best_int8_up_to(*k)),
        ] {
            if !seen.contains(&(precision, runs)) {
                seen.push((precision, runs));
                let row = |v| (Engine::Fast, precision, &[][..], Some(*k), v);
                combos.push(row(Variation::Default));
                if a.layered && precision == Precision::Int8 {
                    combos.push(row(Variation::Layered));
                }
                // Winograd is the AVX2 and AVX-VNNI int8 kernels' default,
                // the fp32 kernels' option
                let toggles = match precision {
                    Precision::Int8 => a.direct && matches!(runs, Kernel::Avx2 | Kernel::AvxVnni),
                    Precision::Fp32 => {
                        a.fp32_winograd && matches!(runs, Kernel::Avx2 | Kernel::Avx512)
                    }
                };
                if toggles {
                    combos.push(row(Variation::Toggled));
                }
            }
        }
    }
    if a.tract {
        for p in [Precision::Fp32, Precision::Int8] {
            combos.push((Engine::Tract, p, &[][..], Some(best), Variation::Default));
        }
    }
    if let Some(Blocks(mixed)) = a.mixed.as_ref().filter(|b| !b.0.is_empty()) {
        let at = combos.len().min(2);
        combos.insert(
            at,
            (
                Engine::Fast,
                Precision::Int8,
                &mixed[..],
                Some(best),
                Variation::Default,
            ),
        );
    }
    let mut measurements: Vec<String> = Vec::new();
    for (engine, precision, fp32_blocks, limit, variation) in combos {
        let toggled = variation == Variation::Toggled;
        let layered = variation == Variation::Layered;
        // Forced rows are named by the kernel they run (fp32 at the AVX-VNNI
        // level runs AVX2); the measured rows by what the measurement chose.
        let runs = |limit: Kernel| match precision {
            Precision::Fp32 => Kernel::best_fp32_up_to(limit),
            Precision::Int8 => Kernel::best_int8_up_to(limit),
        };
        let forced_note = match limit {
            None => " (measured choice)".to_string(),
            Some(l) if engine == Engine::Fast && l != best => format!(" [{}]", runs(l).name()),
            Some(_) => String::new(),
        };
        let runs = runs(limit.unwrap_or(best));
        let name = if toggled && precision == Precision::Fp32 {
            format!("{engine} {precision} [{} winograd]", runs.name())
        } else if toggled {
            format!("{engine} {precision} [{} direct]", runs.name())
        } else if layered {
            format!("{engine} {precision} [{}, layer by layer]", runs.name())
        } else if fp32_blocks.is_empty() {
            format!("{engine} {precision}{forced_note}")
        } else {
            format!("{engine} mixed")
        };
        let t = Instant::now();
        let d = match limit {
            None => Dbtor::load_for_geometry(&a.model, precision, fp32_blocks, engine, g),
            Some(l) => {
                Dbtor::load_for_geometry_up_to(&a.model, precision, fp32_blocks, engine, g, l)
            }
        }
        .with_context(|| format!("loading {name}"))?;
        for m in d.kernel_measurements() {
            if !measurements.contains(m) {
                measurements.push(m.clone());
            }
        }
        let d = if layered { d.int8_layer_by_layer() } else { d };
        let d = match (toggled, precision) {
            (false, _) => Ok(d),
            (true, Precision::Int8) => d.without_winograd(),
            (true, Precision::Fp32) => d.with_fp32_winograd(),
        }
        .with_context(|| format!("loading {name}"))?;
        let load_s = t.elapsed().as_secs_f64();
        if flops.is_none() {
            flops = d.block_flops().map(|v| v.iter().sum::<f64>());
        }
        let (first, _) = d.profile_slice(&sino, thickness)?; // warm-up
        if toggled && precision == Precision::Fp32 {
            // The row before is the same kernel's direct convolution.
            if let Some((dn, dout)) = outputs.last() {
                let range = dout.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                let max = first
                    .iter()
                    .zip(dout)
                    .map(|(x, y)| (x - y).abs())
                    .fold(0.0f32, f32::max);
                eprintln!(
                    "  {name}: max |difference| from {dn}'s image {:.2e} of its range",
                    max / range.max(f32::MIN_POSITIVE)
                );
            }
        } else if toggled || layered {
            // The row before is the same kernel by Winograd, or fused: the
            // same bits.
            if let Some((wn, wo)) = outputs.last() {
                let differ = wo.iter().zip(&first).filter(|(a, b)| a != b).count();
                if differ > 0 {
                    bail!(
                        "{name}: {differ} of {} values differ from {wn}'s",
                        first.len()
                    );
                }
                eprintln!("  {name}: bit for bit {wn}'s output");
            }
        }
        outputs.push((name.clone(), first));
        loaded.push(Loaded {
            name,
            d,
            load_s,
            engine,
            precision,
        });
    }
    // Every row's repetitions interleaved (one slice of each row in turn,
    // `reps` rounds): a machine whose speed drifts during the run (another
    // tenant, the clock) moves every row alike, so rows of the same run
    // compare (issue #52's "within 5 % of the fastest").
    let mut profs: Vec<Vec<SliceProfile>> = vec![Vec::with_capacity(a.reps); loaded.len()];
    for k in 0..a.reps {
        eprint!("\r  round {}/{} of {} rows   ", k + 1, a.reps, loaded.len());
        for (l, p) in loaded.iter().zip(profs.iter_mut()) {
            p.push(l.d.profile_slice(&sino, thickness)?.1);
        }
    }
    eprintln!();
    for (l, profs) in loaded.iter().zip(&profs) {
        let (name, d, load_s, engine, precision) =
            (l.name.clone(), &l.d, l.load_s, l.engine, l.precision);
        let fp32_blocks_len = d.fp32_blocks().len();
        let slice_ms = median(profs.iter().map(|p| p.total_ms).collect());
        let projector_ms = median(profs.iter().map(|p| p.projector_ms).collect());
        // The peers' slices add the projector of the best kernel (the first
        // fast fp32 variant), not of a forced slower one.
        if engine == Engine::Fast && precision == Precision::Fp32 && fast_projector_ms.is_nan() {
            fast_projector_ms = projector_ms;
        }
        variants.push(Variant {
            name: name.clone(),
            slice_ms,
            dual_ms: role_median(d, profs, Role::Dual),
            primal_ms: role_median(d, profs, Role::Primal),
            projector_ms,
            ops: flops.unwrap_or(f64::NAN),
            load_s,
            buffers_mb: (engine == Engine::Fast).then(|| d.slice_buffer_bytes() as f64 / 1e6),
            note: match (d.kernel(), fp32_blocks_len) {
                (Some(k), 0) => {
                    let (wg, all) = d.winograd_convolutions();
                    let wg = if wg > 0 {
                        format!("; Winograd F(3x3,3x3) on {wg} of {all} convolutions (fewer multiply-adds than the floor's count)")
                    } else {
                        String::new()
                    };
                    let (fu, n8) = d.int8_fused_blocks();
                    let fu = if n8 > 0 {
                        format!("; {fu} of {n8} int8 blocks fused")
                    } else {
                        String::new()
                    };
                    format!("kernel {k}, projector {}{wg}{fu}", d.projector_kernel().name())
                }
                (Some(k), n) => format!(
                    "kernels {k}, projector {}; {n} blocks fp32 (rate and floor as fp32)",
                    d.projector_kernel().name()
                ),
                (None, _) => format!("projector {}", d.projector_kernel().name()),
            },
        });
    }
    if a.peers {
        for precision in ["fp32", "int8"] {
            let out = Command::new("python3")
                .args(["bench/peers/ort_blocks.py", "--model"])
                .arg(&a.model)
                .args(["--precision", precision, "--reps", &a.reps.to_string()])
                .args(["--dual", &views.to_string(), &det.to_string()])
                .args(["--primal", &rows.to_string(), &cols.to_string()])
                .output()
                .context(
                    "running bench/peers/ort_blocks.py (pip install -r training/requirements.txt)",
                )?;
            if !out.status.success() {
                bail!(
                    "onnxruntime peer failed: {}",
                    String::from_utf8_lossy(&out.stderr)
                );
            }
            let v: Value = serde_json::from_slice(&out.stdout).context("peer output")?;
            let ms: Vec<f64> = v["block_ms"]
                .as_array()
                .context("peer block_ms")?
                .iter()
                .filter_map(|x| x.as_f64())
                .collect();
            let of_role = |role: Role| -> Vec<f64> {
                ms.iter()
                    .zip(&roles)
                    .filter(|(_, r)| **r == role)
                    .map(|(m, _)| *m)
                    .collect()
            };
            let (dual, primal) = (of_role(Role::Dual), of_role(Role::Primal));
            variants.push(Variant {
                name: format!("ort {precision}"),
                slice_ms: ms.iter().sum::<f64>() + fast_projector_ms,
                dual_ms: median(dual),
                primal_ms: median(primal),
                projector_ms: fast_projector_ms,
                ops: flops.unwrap_or(f64::NAN),
                load_s: v["load_s"].as_f64().unwrap_or(f64::NAN),
                buffers_mb: None,
                note: format!(
                    "onnxruntime {} blocks + Rust projector (best kernel)",
                    v["onnxruntime"].as_str().unwrap_or("?")
                ),
            });
        }
    }
    let ort_best = variants
        .iter()
        .filter(|v| v.name.starts_with("ort"))
        .map(|v| v.slice_ms)
        .fold(f64::INFINITY, f64::min);
    println!(
        "{:<12} {:>10} {:>9} {:>10} {:>9} {:>9} {:>8} {:>8} {:>8} {:>9}  note",
        "variant",
        "slice ms",
        "dual ms",
        "primal ms",
        "proj ms",
        "G(FL)OP/s",
        "x floor",
        "vs ort",
        "load s",
        "bufs MB"
    );
    let mut rows_json = Vec::new();
    for v in &variants {
        let int8 = v.name.contains("int8");
        // the AMX rows against the tiles' peak, other int8 rows against VNNI's
        let peak = match (int8, v.note.starts_with("kernel amx")) {
            (true, true) => peaks.2,
            (true, false) => peaks.1,
            (false, _) => peaks.0,
        };
        let rate = v.ops / ((v.slice_ms - v.projector_ms) * 1e-3) / 1e9;
        let floor_ms = v.ops / (peak * 1e9) * 1e3;
        let x_floor = v.slice_ms / floor_ms;
        let vs_ort = ort_best / v.slice_ms;
        println!(
            "{:<12} {:>10.1} {:>9.2} {:>10.2} {:>9.1} {:>9.1} {:>8.2} {:>8.2} {:>8.2} {:>9}  {}",
            v.name,
            v.slice_ms,
            v.dual_ms,
            v.primal_ms,
            v.projector_ms,
            rate,
            x_floor,
            vs_ort,
            v.load_s,
            v.buffers_mb
                .map(|b| format!("{b:.1}"))
                .unwrap_or("-".into()),
            v.note
        );
        rows_json.push(json!({
            "variant": v.name, "slice_ms": v.slice_ms, "dual_block_ms": v.dual_ms,
            "primal_block_ms": v.primal_ms, "projector_ms": v.projector_ms,
            "gops_blocks": rate, "floor_ms": floor_ms, "x_floor": x_floor,
            "speedup_vs_best_ort": vs_ort, "load_s": v.load_s,
            "slice_buffers_mb": v.buffers_mb, "note": v.note,
        }));
    }
    // The measured choice against the fastest row of its precision in this
    // run (issue #52: within 5 %).
    for m in &measurements {
        println!("  measured at load: {m}");
    }
    let mut measured_vs_fastest = Map::new();
    for p in ["fp32", "int8"] {
        let measured = format!("fast {p} (measured choice)");
        let Some(mv) = variants.iter().find(|v| v.name == measured) else {
            continue;
        };
        let fastest = variants
            .iter()
            .filter(|v| v.name.starts_with(&format!("fast {p}")))
            .min_by(|a, b| a.slice_ms.total_cmp(&b.slice_ms));
        if let Some(f) = fastest {
            let over = 100.0 * (mv.slice_ms / f.slice_ms - 1.0);
            println!(
                "  {measured}: {:.1} ms, {over:+.1} % against the fastest {p} row of this run ({}, {:.1} ms)",
                mv.slice_ms, f.name, f.slice_ms
            );
            measured_vs_fastest.insert(p.into(), json!({"measured_ms": mv.slice_ms, "fastest": f.name, "fastest_ms": f.slice_ms, "over_percent": over}));
        }
    }
    // Agreement with the reference executor on this input.
    let mut agreement = Map::new();
    if let Some((_, reference)) = outputs.iter().find(|(n, _)| n == "tract fp32") {
        let range = reference.iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
        for (n, o) in &outputs {
            let max = o
                .iter()
                .zip(reference)
                .map(|(x, y)| (x - y).abs() as f64)
                .fold(0.0, f64::max);
            agreement.insert(
                n.clone(),
                json!({"max_abs_vs_tract_fp32_rel": max / range, "rms_vs_tract_fp32_per_mm": rms(o, reference)}),
            );
            println!(
                "  {n:<12} vs tract fp32: max |diff| = {:.2e} of the image's range, RMS {:.2e} /mm",
                max / range,
                rms(o, reference)
            );
        }
    }
    let by = |n: &str| {
        variants
            .iter()
            .find(|v| v.name == n)
            .map(|v| v.slice_ms)
            .unwrap_or(f64::NAN)
    };
    Ok(json!({
        "geometry": g.describe(),
        "image": [cols, rows], "sinogram": [views, det],
        "block_flops_per_slice": flops,
        "slice_ms_fast_int8": by("fast int8"), "slice_ms_fast_fp32": by("fast fp32"),
        "slice_ms_tract_fp32": by("tract fp32"), "slice_ms_tract_int8": by("tract int8"),
        "slice_ms_ort_fp32": by("ort fp32"), "slice_ms_ort_int8": by("ort int8"),
        "slice_ms_fast_mixed": by("fast mixed"),
        "slice_ms_fast_fp32_avx2": by("fast fp32 [avx2]"),
        "slice_ms_fast_fp32_portable": by("fast fp32 [portable]"),
        "slice_ms_fast_int8_portable": by("fast int8 [portable]"),
        "variants": rows_json,
        "kernel_measurements": measurements,
        "measured_vs_fastest": measured_vs_fastest,
        "agreement": agreement,
    }))
}

fn main() -> Result<()> {
    let a = Args::parse();
    let model_geometry = dbt_dbtor::ModelManifest::load(&a.model)?.geometry;
    let peaks = measured_peaks();
    println!("cpu: {}", dbt_cli::cpu_summary());
    println!(
        "measured peak on 2 threads: fp32 FMA {:.1} GFLOP/s, int8 VNNI {:.1} GOP/s, int8 AMX {:.1} GOP/s",
        peaks.0, peaks.1, peaks.2
    );
    let mut out = Map::new();
    out.insert("model".into(), json!(a.model));
    out.insert("cpu".into(), json!(dbt_cli::cpu_summary()));
    out.insert("reps".into(), json!(a.reps));
    out.insert("threads".into(), json!(rayon::current_num_threads()));
    out.insert("peak_fp32_gflops".into(), json!(peaks.0));
    out.insert("peak_int8_gops".into(), json!(peaks.1));
    out.insert("peak_amx_int8_gops".into(), json!(peaks.2));
    if a.geometry != Where::Model {
        let paper = Geometry::paper();
        let v = bench_geometry(&a, "paper geometry", &paper, peaks)?;
        for k in [
            "slice_ms_fast_int8",
            "slice_ms_fast_fp32",
            "slice_ms_tract_fp32",
            "slice_ms_tract_int8",
            "slice_ms_ort_fp32",
            "slice_ms_ort_int8",
        ] {
            out.insert(k.into(), v[k].clone());
        }
        out.insert("paper".into(), v);
    }
    if a.geometry != Where::Paper {
        let v = bench_geometry(&a, "model geometry", &model_geometry, peaks)?;
        out.insert("model_geometry".into(), v);
    }
    if let Some(dir) = a.out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(&a.out, serde_json::to_string_pretty(&Value::Object(out))?)?;
    println!("\nwrote {}", a.out.display());
    Ok(())
}
