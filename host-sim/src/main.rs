//! `host-sim`: the hardware stand-in: phantoms, recorded acquisitions,
//! training data, and the gantry's servers (projection stream, Modbus
//! registers) with fault injection. `main` hands each subcommand to its
//! `run_<name>` function.

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use dbt_cli::{GeometryArgs, Progress};
use dbt_forward::NoiseLevel;
use dbt_phantom::{Population, PopulationKind};
use host_sim::dataset::{export_observed, ExportOptions, ExportStage};
use std::path::PathBuf;
use std::time::Instant;

#[derive(Parser)]
#[command(
    name = "host-sim",
    about = "Simulated breasts, acquisitions and training data"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Generate one phantom and write it as raw labels plus a TOML sidecar.
    Phantom(PhantomArgs),
    /// Simulate the acquisition of one breast and write it as files
    /// (`dbtor-acquisition/1`: acquisition.json + counts.f32).
    Acquire(AcquireArgs),
    /// Serve a recorded acquisition as the gantry's projection stream on TCP
    /// (one connection), with optional fault injection. Exit 0 when the
    /// receiver acknowledged the end frame (delivered), 3 when it did not
    /// (the acquisition stays with the gantry).
    Stream(StreamArgs),
    /// Serve the gantry controller's Modbus registers on TCP until killed.
    Modbus(ModbusArgs),
    /// Export a training dataset (see DATASET.md).
    Dataset(DatasetArgs),
    /// Write a recorded acquisition as a Breast Projection X-Ray Image - For
    /// Processing object (one frame per view), check it with dciodvfy, and
    /// send it by C-STORE, as a modality sends to a density or dose server.
    DicomSend(DicomSendArgs),
    /// Add the FBP of one noise level's sinograms to every split of a dataset
    /// (`fbp-<level>`, the U-Net baseline's input; DATASET.md).
    Fbp(FbpArgs),
}

/// The options of `host-sim phantom`.
#[derive(Args)]
struct PhantomArgs {
    /// Output sidecar path (`NAME.toml`; the raw goes beside it).
    #[arg(long)]
    out: PathBuf,
    /// Population seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Index of the phantom in the population.
    #[arg(long, default_value_t = 0)]
    index: u64,
    #[command(flatten)]
    geometry: GeometryArgs,
    /// Phantom population: `procedural` (the breasts every model up to
    /// dbtor-x4t3 was trained on) or `anatomical` (issue #26) or `mixed` (both: index % 3 == 2 procedural).
    #[arg(long, default_value = "procedural")]
    population: PopulationKind,
}

/// The options of `host-sim acquire`.
#[derive(Args)]
struct AcquireArgs {
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
    /// Phantom of the fixed test set (never trained on).
    #[arg(long, default_value_t = 0)]
    index: u64,
    /// An external phantom instead (a sidecar TOML: `phantoms/victre-pc1.toml`,
    /// or one `host-sim phantom` wrote), resampled to the geometry's pixel:
    /// it goes through the product's own path (stream, daemon,
    /// dbtor-process) like any acquisition. Evaluation only.
    #[arg(long, conflicts_with_all = ["index", "population"])]
    phantom: Option<PathBuf>,
    #[command(flatten)]
    geometry: GeometryArgs,
    /// Noise level (`noise-free`, `N4`, `N8`, `N12`).
    #[arg(long, default_value = "N8")]
    noise: String,
    /// Phantom population: `procedural` (the breasts every model up to
    /// dbtor-x4t3 was trained on) or `anatomical` (issue #26) or `mixed` (both: index % 3 == 2 procedural).
    #[arg(long, default_value = "procedural")]
    population: PopulationKind,
    /// Acquire on a cone-beam system (issue #28): `paper-cone` (the paper's
    /// rotating detector), `siemens-victre` (stationary detector) or a system
    /// TOML; binned like the geometry. Without it, every coronal slice is
    /// its own fan beam (the paper's simplification).
    #[arg(long)]
    system: Option<String>,
    /// The physics (issue #27): `mono` (the paper's: one energy, photon
    /// counting), `clinical` (the Table 3 spectrum for the thickness, an
    /// energy-integrating detector: 200 um of CsI, or the converter the
    /// `--system` states, a-Se for Hologic and Siemens; quantum and electronic noise at the
    /// noise level's photons per element, and each view's scatter without a
    /// grid: dbt-scatter's kernels fitted to the Monte Carlo engine) or
    /// `clinical-primary` (the same without scatter).
    #[arg(long, default_value = "mono")]
    physics: String,
    /// The beam: `W/Rh` (the paper's Table 3 kV for the thickness) or
    /// `W/Al` (`dbt_dose::xray::W_AL_AEC`); the acquisition's header, the
    /// stream's and the DICOM objects carry it.
    #[arg(long, default_value = "W/Rh")]
    anode_filter: String,
}

/// The options of `host-sim stream`.
#[derive(Args)]
struct StreamArgs {
    /// Recorded acquisition folder (from `acquire`).
    #[arg(long)]
    acq: PathBuf,
    /// Address to listen on, e.g. 127.0.0.1:7001.
    #[arg(long, conflicts_with = "serial")]
    listen: Option<String>,
    /// Serial line instead of TCP, e.g. /dev/ttyUSB0 or a pty.
    #[arg(long)]
    serial: Option<String>,
    /// Baud rate of the serial line.
    #[arg(long, default_value_t = 921_600)]
    baud: u32,
    /// Faults: corrupt:SEQ, drop:SEQ, dup:SEQ, reorder:A,B, cut:SEQ, saturate:SEQ, nanflat:SEQ,
    /// zeros:SEQ, announce:N, freeze:SEQ, mas:N, anode:CODE (register 6's code), kvp:N (repeatable).
    #[arg(long)]
    fault: Vec<String>,
}

/// The options of `host-sim modbus`.
#[derive(Args)]
struct ModbusArgs {
    /// Modbus TCP: address to listen on, e.g. 127.0.0.1:1502.
    #[arg(long)]
    listen: Option<String>,
    /// Modbus RTU instead: the serial line, e.g. /dev/ttyS1 or a pty.
    #[arg(long)]
    serial: Option<String>,
    /// Baud rate of the serial line (8N1).
    #[arg(long, default_value_t = 19200)]
    baud: u32,
    /// Compressed thickness, mm.
    #[arg(long, default_value_t = 45.3)]
    thickness_mm: f64,
    /// Acquisition state (idle, compressing, ready, exposing, complete, fault).
    #[arg(long, default_value = "exposing")]
    state: String,
    /// Address of register 0.
    #[arg(long, default_value_t = 0)]
    base: u16,
    /// Fault: `exception` or `silent`.
    #[arg(long)]
    fault: Option<String>,
    /// Fault: after the first read the thickness becomes this (mm), as if
    /// the compression changed during the sweep.
    #[arg(long)]
    thickness_then_mm: Option<f64>,
    /// Anode/filter register: W/Rh, W/Al, W/Ag, Mo/Mo, Mo/Rh, Rh/Rh or Rh/Ag.
    #[arg(long, default_value = "W/Rh")]
    anode_filter: String,
}

/// The options of `host-sim dataset`.
#[derive(Args)]
struct DatasetArgs {
    /// Output folder (must not hold a dataset yet).
    #[arg(long)]
    out: PathBuf,
    /// Train + validation slices wanted.
    #[arg(long, default_value_t = 10_000)]
    slices: usize,
    /// Phantoms of the fixed test set to include.
    #[arg(long, default_value_t = 5)]
    test_phantoms: usize,
    /// Population seed of the training phantoms.
    #[arg(long, default_value_t = 2024)]
    seed: u64,
    /// Noise levels, comma separated (`noise-free,N4,N8,N12`).
    #[arg(long, default_value = "noise-free,N4,N8,N12")]
    levels: String,
    #[command(flatten)]
    geometry: GeometryArgs,
    /// Phantoms generated at once.
    #[arg(long, default_value_t = 4)]
    batch: usize,
    /// Phantom population: `procedural` (the breasts every model up to
    /// dbtor-x4t3 was trained on) or `anatomical` (issue #26) or `mixed` (both: index % 3 == 2 procedural).
    #[arg(long, default_value = "procedural")]
    population: PopulationKind,
    /// The acquisitions' physics: `mono` (the paper's, every level), or
    /// `clinical` / `clinical-primary` (issue #27: one level; the counts
    /// the firmware reconstructs after its scatter removal and
    /// linearisation, DATASET.md).
    #[arg(long, default_value = "mono")]
    physics: String,
    /// With `clinical`: the detector's counts, uncorrected (scatter and
    /// beam hardening left in): the data of a network trained on what the
    /// gantry sends (issue #27's other design).
    #[arg(long)]
    uncorrected: bool,
}

/// The options of `host-sim dicom-send`.
#[derive(Args)]
struct DicomSendArgs {
    /// Recorded acquisition folder (from `acquire`).
    #[arg(long)]
    acq: PathBuf,
    /// Also write the object here (DICOM Part 10).
    #[arg(long, required_unless_present = "to")]
    out: Option<PathBuf>,
    /// Send it to this Storage SCP, AET@host:port.
    #[arg(long)]
    to: Option<String>,
    /// Our calling AE title.
    #[arg(long, default_value = "HOSTSIM")]
    calling_ae: String,
    /// Compression force of the simulated gantry, N (its Modbus register's).
    #[arg(long, default_value_t = 110.0)]
    compression_force_n: f64,
    /// Exposure time of each view, ms, and the time between views' starts:
    /// the simulated gantry's sweep (25 views in about 3.7 s).
    #[arg(long, default_value_t = 60.0)]
    exposure_ms: f64,
    /// See `exposure_ms`.
    #[arg(long, default_value_t = 150.0)]
    view_interval_ms: f64,
    /// The simulated modality's own dose estimate, mGy (Organ Dose).
    /// Default: the incident air kerma times 0.25, a typical DBT
    /// conversion for a 50 mm breast of 50 % glandularity; the product
    /// computes its own MGD and never reads this.
    #[arg(long)]
    organ_dose_mgy: Option<f64>,
    /// Skip the dciodvfy check (it is required otherwise).
    #[arg(long)]
    no_check: bool,
    /// One Digital Mammography X-Ray For Processing object per view (as
    /// systems without the multi-frame Breast Projection object send them);
    /// `--out` is then a folder (`view-01.dcm`, ...).
    #[arg(long)]
    per_view: bool,
}

/// The options of `host-sim fbp`.
#[derive(Args)]
struct FbpArgs {
    /// The dataset folder.
    #[arg(long)]
    data: PathBuf,
    /// Noise level whose sinograms are reconstructed.
    #[arg(long, default_value = "N8")]
    level: String,
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(dbt_cli::log_writer)
        .init();
    match Cli::parse().cmd {
        Cmd::Phantom(a) => run_phantom(a),
        Cmd::Acquire(a) => run_acquire(a),
        Cmd::Stream(a) => run_stream(a),
        Cmd::Modbus(a) => run_modbus(a),
        Cmd::Dataset(a) => run_dataset(a),
        Cmd::Fbp(a) => run_fbp(a),
        Cmd::DicomSend(a) => run_dicom_send(a),
    }
}

/// `host-sim phantom`.
fn run_phantom(args: PhantomArgs) -> Result<()> {
    let PhantomArgs {
        out,
        seed,
        index,
        geometry,
        population,
    } = args;
    let g = geometry.load()?;
    let vol = population.draw(&g, seed, index).generate()?;
    dbt_store::save_phantom(&vol, &out)?;
    println!(
        "{}: {:?} voxels of {} mm, thickness {:.1} mm, glandularity {:.3}",
        out.display(),
        vol.dims(),
        vol.voxel_mm(),
        vol.thickness_mm(),
        vol.glandularity().unwrap_or(0.0)
    );
    Ok(())
}

/// `host-sim acquire`.
fn run_acquire(args: AcquireArgs) -> Result<()> {
    let AcquireArgs {
        out,
        index,
        phantom,
        geometry,
        noise,
        population,
        system,
        physics,
        anode_filter,
    } = args;
    let physics = host_sim::Physics::parse(&physics)?;
    let anode_filter = dbt_dose::xray::AnodeFilter::parse(&anode_filter)
        .with_context(|| format!("--anode-filter {anode_filter}"))?;
    let g = geometry.load()?;
    let (vol, seed, patient, what) = match &phantom {
        None => (
            population
                .draw(&g, Population::TEST_SEED, index)
                .generate()?,
            host_sim::mix_seed(Population::TEST_SEED, &[index, 1]),
            format!("TEST{index:03}"),
            format!("test phantom {index}"),
        ),
        Some(p) => {
            let vol = dbt_store::load_external_phantom(p)
                .with_context(|| format!("--phantom {}", p.display()))?
                .resampled(g.image.pixel_mm)
                .with_context(|| format!("--phantom {}: resampling", p.display()))?;
            // The patient id and the noise seed from the sidecar's name:
            // the same file gives the same acquisition.
            let stem: String = p
                .file_stem()
                .map(|s| s.to_string_lossy().to_string())
                .unwrap_or_default()
                .chars()
                .map(|c| {
                    if c.is_ascii_alphanumeric() {
                        c.to_ascii_uppercase()
                    } else {
                        '_'
                    }
                })
                .take(12)
                .collect();
            let key = stem
                .bytes()
                .fold(0u64, |h, b| h.rotate_left(5) ^ u64::from(b));
            (
                vol,
                host_sim::mix_seed(Population::TEST_SEED, &[key, 2]),
                format!("EXT{stem}"),
                format!("external phantom {}", p.display()),
            )
        }
    };
    let noise = NoiseLevel::parse(&noise)?;
    let kvp = f64::from(anode_filter.aec_kv(vol.thickness_mm()));
    let root = "1.2.826.0.1.3680043.10.543.2";
    let sys = match &system {
        None => None,
        Some(name) => Some(
            geometry
                .load_system(Some(name))
                .with_context(|| format!("--system {name}"))?
                .context("no system")?,
        ),
    };
    // The reconstruction geometry the firmware rebins a cone-beam system's
    // frames to: the system's fan on the geometry's detector elements and
    // image (the geometry itself for `paper-cone` and the paper's).
    let fan = match &sys {
        None => g.clone(),
        Some(s) => {
            let fan = s.rebinning_fan(&g)?;
            dbt_pipeline::rebin::check_site(s, &fan).with_context(|| {
                format!(
                    "--system {} with --geometry {}",
                    system.as_deref().unwrap_or_default(),
                    geometry.geometry
                )
            })?;
            fan
        }
    };
    let acq = host_sim::simulate_on(
        &vol,
        &fan,
        sys.as_ref(),
        noise,
        physics,
        seed,
        host_sim::Technique {
            anode_filter,
            ..Default::default()
        },
        kvp,
        &patient,
        root,
    )?;
    dbt_store::acquisition::write_acquisition(&out, &acq)?;
    println!(
        "{}: {what}, {} {}, thickness {:.1} mm, glandularity {:.3}, {}, {} physics",
        out.display(),
        acq.header.slices,
        match &acq.header.system {
            Some(s) => format!("detector rows of {}", s.name),
            None => "slices".to_string(),
        },
        acq.header.thickness_mm,
        vol.glandularity().unwrap_or(0.0),
        noise.name(),
        physics.name()
    );
    Ok(())
}

/// `host-sim stream`.
fn run_stream(args: StreamArgs) -> Result<()> {
    let StreamArgs {
        acq,
        listen,
        serial,
        baud,
        fault,
    } = args;
    let faults = fault
        .iter()
        .map(|f| host_sim::stream::Fault::parse(f))
        .collect::<Result<Vec<_>, _>>()
        .map_err(anyhow::Error::msg)?;
    let a = dbt_store::acquisition::read_acquisition(&acq)?;
    let frames = host_sim::stream::frames_of(&a).map_err(anyhow::Error::msg)?;
    let served = match (listen, serial) {
        (Some(listen), None) => {
            let l = std::net::TcpListener::bind(&listen)
                .with_context(|| format!("listening on {listen}"))?;
            eprintln!("host-sim: streaming {} frames on {listen}", frames.len());
            host_sim::stream::serve_one(&l, &frames, &faults)?
        }
        (None, Some(path)) => {
            let mut port = serialport::new(&path, baud)
                .timeout(std::time::Duration::from_millis(200))
                .open()
                .with_context(|| format!("opening serial line {path}"))?;
            eprintln!(
                "host-sim: streaming {} frames on {path} at {baud} Bd",
                frames.len()
            );
            host_sim::stream::serve_stream(
                &mut port,
                &frames,
                &faults,
                std::time::Duration::from_secs(30),
            )?
        }
        _ => bail!("give --listen HOST:PORT or --serial PATH"),
    };
    let resent = served.resent;
    if !served.delivered {
        // The gantry keeps what the receiver did not acknowledge.
        println!(
            "streamed {} frames, {resent} retransmitted; NOT delivered: the receiver did not acknowledge the end frame, the acquisition stays with the gantry",
            frames.len()
        );
        std::process::exit(3);
    }
    println!(
        "streamed {} frames, {resent} retransmitted; delivered",
        frames.len()
    );
    Ok(())
}

/// `host-sim modbus`.
fn run_modbus(args: ModbusArgs) -> Result<()> {
    let ModbusArgs {
        listen,
        serial,
        baud,
        thickness_mm,
        state,
        base,
        fault,
        thickness_then_mm,
        anode_filter,
    } = args;
    use dbt_gantry::registers::{encode, Registers, State, ANODES};
    let anode_filter = ANODES
        .iter()
        .copied()
        .find(|a| *a == anode_filter)
        .with_context(|| {
            format!(
                "--anode-filter `{anode_filter}`: one of {}",
                ANODES.join(", ")
            )
        })?;
    use host_sim::modbus::{serve, GantryService, ModbusFault};
    let state = match state.as_str() {
        "idle" => State::Idle,
        "compressing" => State::Compressing,
        "ready" => State::Ready,
        "exposing" => State::Exposing,
        "complete" => State::Complete,
        "fault" => State::Fault,
        other => bail!("--state `{other}`: idle, compressing, ready, exposing, complete or fault"),
    };
    let fault = match fault.as_deref() {
        None => None,
        Some("exception") => Some(ModbusFault::Exception),
        Some("silent") => Some(ModbusFault::Silent),
        Some(other) => bail!("--fault `{other}`: exception or silent"),
    };
    // The beam's automatic exposure (the paper's Table 3 for an anode/filter
    // the dose model has no spectra for: the register is what is tested).
    let kvp = f64::from(
        dbt_dose::xray::AnodeFilter::parse(anode_filter)
            .map_or(dbt_dose::xray::paper_technique(thickness_mm).0, |b| {
                b.aec_kv(thickness_mm)
            }),
    );
    let regs = Registers {
        version: 1,
        state,
        thickness_mm,
        force_n: 110.0,
        kvp,
        mas_per_projection: 2.4,
        anode_filter,
        projections: 25,
        angles_deg: [-24.0, 24.0],
        current: 12,
        laterality: 'L',
        view: "CC",
        fault: 0,
    };
    let service = GantryService {
        registers: std::sync::Arc::new(std::sync::Mutex::new(encode(&regs))),
        base,
        fault,
        thickness_then: thickness_then_mm.map(|t| (t * 10.0).round().clamp(0.0, 65535.0) as u16),
    };
    let rt = tokio::runtime::Runtime::new()?;
    match (listen, serial) {
        (Some(listen), None) => {
            let addr: std::net::SocketAddr = listen
                .parse()
                .with_context(|| format!("--listen {listen}"))?;
            eprintln!("host-sim: Modbus TCP on {addr}");
            rt.block_on(serve(addr, service))?;
        }
        (None, Some(path)) => {
            eprintln!("host-sim: Modbus RTU on {path} at {baud} baud, 8N1");
            rt.block_on(host_sim::modbus::serve_rtu(&path, baud, service))
                .with_context(|| format!("Modbus RTU on {path}"))?;
        }
        _ => bail!("give --listen HOST:PORT (Modbus TCP) or --serial PATH (Modbus RTU)"),
    }
    Ok(())
}

/// `host-sim dataset`.
fn run_dataset(args: DatasetArgs) -> Result<()> {
    let DatasetArgs {
        out,
        slices,
        test_phantoms,
        seed,
        levels,
        geometry,
        batch,
        population,
        physics,
        uncorrected,
    } = args;
    let physics = host_sim::Physics::parse(&physics)?;
    let levels = levels
        .split(',')
        .map(NoiseLevel::parse)
        .collect::<Result<Vec<_>, _>>()?;
    if slices == 0 {
        bail!("--slices must be positive");
    }
    let opts = ExportOptions {
        geometry: geometry.load()?,
        slices,
        test_phantoms,
        seed,
        levels,
        batch,
        population,
        physics,
        uncorrected,
    };
    let t = Instant::now();
    let bar = Progress::new(slices as u64, "dataset", "slices", false);
    let m = export_observed(&out, &opts, &mut |stage| match stage {
        ExportStage::Slices { done, wanted } => {
            // Whole phantoms: the last one may overshoot what was wanted.
            bar.set_length(done.max(wanted) as u64);
            bar.set_position(done as u64)
        }
        ExportStage::TestPhantoms { done, wanted } => {
            bar.message(format!("test phantoms {done}/{wanted}"))
        }
        ExportStage::Operator => bar.message("the projector's operator"),
    })?;
    bar.finish();
    let secs = t.elapsed().as_secs_f64();
    let n: Vec<String> = m
        .splits
        .iter()
        .map(|s| {
            format!(
                "{} {} slices / {} phantoms",
                s.name,
                s.slices.len(),
                s.phantoms.len()
            )
        })
        .collect();
    let total: usize = m.splits.iter().map(|s| s.slices.len()).sum();
    println!(
        "{}: {} ({} slices in {:.1} s, {:.1} slices/s)",
        out.display(),
        n.join(", "),
        total,
        secs,
        total as f64 / secs
    );
    Ok(())
}

/// `host-sim fbp`.
fn run_fbp(args: FbpArgs) -> Result<()> {
    let FbpArgs { data, level } = args;
    let t = Instant::now();
    for (split, n) in host_sim::dataset::add_fbp(&data, &level)? {
        println!("{split}: fbp-{level} of {n} slices");
    }
    println!("{:.0} s", t.elapsed().as_secs_f64());
    Ok(())
}

/// `host-sim dicom-send`.
/// `file` passes dciodvfy with no Error line (dicom3tools).
fn dciodvfy_clean(file: &std::path::Path) -> Result<()> {
    let o = std::process::Command::new("dciodvfy")
        .arg(file)
        .output()
        .context("running dciodvfy (apt-get install dicom3tools; --no-check skips it)")?;
    let text = String::from_utf8_lossy(&o.stderr).to_string() + &String::from_utf8_lossy(&o.stdout);
    let errors: Vec<&str> = text.lines().filter(|l| l.starts_with("Error")).collect();
    if !errors.is_empty() {
        bail!(
            "dciodvfy finds {} errors in {}:\n{}",
            errors.len(),
            file.display(),
            errors.join("\n")
        );
    }
    Ok(())
}

fn run_dicom_send(args: DicomSendArgs) -> Result<()> {
    let DicomSendArgs {
        acq,
        out,
        to,
        calling_ae,
        compression_force_n,
        exposure_ms,
        view_interval_ms,
        organ_dose_mgy,
        no_check,
        per_view,
    } = args;
    let a = dbt_store::acquisition::read_acquisition(&acq)?;
    let h = &a.header;
    let g = &h.geometry;
    // A cone-beam acquisition's frames are its system's detector's.
    let (views, det) = match &h.system {
        Some(s) => (s.n_views(), s.detector.columns),
        None => (g.n_views(), g.n_det()),
    };
    let counts = dbt_pipeline::dicom_input::frames_of(&a)?;
    let angles: Vec<f64> = (0..views)
        .map(|v| match &h.system {
            Some(s) => s.angle_deg(v),
            None => g.angle_deg(v),
        })
        .collect();
    let kerma = h.mas_total * h.tube_output_mgy_per_mas;
    let header = dbt_pipeline::dicom_header(&a);
    let equipment = dbt_dicom::Equipment {
        manufacturer: "DBToR host-sim".into(),
        model: "simulated DBT gantry".into(),
        serial: "SIM-GANTRY".into(),
        software_version: env!("CARGO_PKG_VERSION").into(),
        device_uid: "1.2.826.0.1.3680043.10.543.2.9".into(),
    };
    let ms = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0);
    let (date, time) = dbt_dicom::dicom_datetime_utc(ms / 1000);
    let set = dbt_pipeline::dicom_input::projection_set(
        &a,
        &header,
        &equipment,
        &angles,
        &counts,
        dbt_pipeline::dicom_input::Sweep {
            compression_force_n,
            exposure_ms_per_view: exposure_ms,
            view_interval_ms,
            modality_agd_mgy: organ_dose_mgy.unwrap_or(0.25 * kerma),
            filter_mm: dbt_dose::xray::technique_spectrum(h.anode_filter, h.kvp, h.thickness_mm)?
                .filter_mm,
            content_date: &date,
            content_time: &time,
        },
    );
    // UIDs unique per send: the milliseconds and the process id.
    let mut uids = dbt_dicom::UidSource::new(
        &format!("1.2.826.0.1.3680043.10.543.2.{}", std::process::id()),
        ms,
    )?;
    let objects = if per_view {
        dbt_dicom::dm::view_objects(&set, &mut uids)?
    } else {
        vec![dbt_dicom::projections::projection_object(&set, &mut uids)?]
    };
    let dir = match (&out, per_view) {
        (Some(p), true) => {
            std::fs::create_dir_all(p).with_context(|| format!("creating {}", p.display()))?;
            Some(p.clone())
        }
        _ => None,
    };
    // The objects written to the temporary folder (no --out) are removed
    // however this returns: a refused store or a failed check too.
    struct Temporary(Vec<PathBuf>);
    impl Drop for Temporary {
        fn drop(&mut self) {
            for f in &self.0 {
                let _ = std::fs::remove_file(f);
            }
        }
    }
    let mut temporary = Temporary(Vec::new());
    let mut written = Vec::new();
    for (k, obj) in objects.iter().enumerate() {
        let bytes = obj.to_bytes()?;
        let file = match (&dir, &out) {
            (Some(d), _) => d.join(format!("view-{:02}.dcm", k + 1)),
            (None, Some(p)) => p.clone(),
            (None, None) => std::env::temp_dir().join(format!("host-sim-{}.dcm", obj.sop_instance)),
        };
        if out.is_none() {
            temporary.0.push(file.clone());
        }
        std::fs::write(&file, &bytes).with_context(|| format!("writing {}", file.display()))?;
        if !no_check {
            dciodvfy_clean(&file)?;
        }
        written.push((file, bytes, obj.sop_instance.clone()));
    }
    let what = if per_view {
        format!(
            "{} view objects (Digital Mammography X-Ray For Processing) of {} x {det}",
            objects.len(),
            h.slices
        )
    } else {
        format!("{views} frames of {} x {det}", h.slices)
    };
    println!(
        "{}: {what}, SOP instance {}{}",
        dir.as_ref().unwrap_or(&written[0].0).display(),
        written
            .iter()
            .map(|w| w.2.as_str())
            .collect::<Vec<_>>()
            .join(" "),
        if no_check { "" } else { ", dciodvfy: no error" }
    );
    if let Some(to) = to {
        let mut cfg = dbt_pacs::PacsConfig::parse(&to)?;
        cfg.calling_ae_title = calling_ae;
        for (_, bytes, _) in &written {
            dbt_pacs::store_with_retry(&cfg, bytes)?;
        }
        println!("sent to {to}");
    }
    Ok(())
}
