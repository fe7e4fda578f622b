//! What every command line of the workspace shares, defined once:
//! - [`GeometryArgs`]: `--geometry NAME|FILE --binning N`, with one default
//!   binning for every binary ([`DEFAULT_BINNING`], the shipped
//!   configuration's);
//! - [`ModelArgs`]: `--model DIR --precision fp32|int8 --engine fast|tract`;
//! - [`Progress`]: a progress bar on stderr that is drawn only when stderr is
//!   a terminal and the command does not print JSON, and that keeps log
//!   lines readable ([`Progress::line`] prints above the bar).
//!
//! An edge crate (clap, indicatif): binaries only. Their log subscribers
//! write through [`log_writer`], above the bar.

use std::fmt::Display;
use std::io::IsTerminal;
use std::path::PathBuf;

/// The binning every command defaults to: the shipped gantry configuration's
/// (`firmware/config/dbtor.toml`, `frames.binning`), which the shipped model
/// is trained for.
pub const DEFAULT_BINNING: usize = 4;

/// The gantry geometry of a command.
#[derive(Debug, Clone, clap::Args)]
pub struct GeometryArgs {
    /// Geometry: `paper`, `paper-tall` (80 mm image: breasts up to 75 mm),
    /// `paper-104` (104 mm) or a TOML file (as `dbtor-diag geometry` prints).
    #[arg(long, default_value = "paper")]
    pub geometry: String,
    /// Detector and image binning of that geometry (1, 2 or 4; 1 is the
    /// paper's 0.2 mm pixels).
    #[arg(long, default_value_t = DEFAULT_BINNING)]
    pub binning: usize,
}

impl GeometryArgs {
    /// The geometry (a built-in name or a TOML file), binned.
    pub fn load(&self) -> Result<dbt_geometry::Geometry, dbt_store::StoreError> {
        dbt_store::load_geometry(&self.geometry, self.binning)
    }

    /// The cone-beam system `spec` (a built-in name or a TOML file), binned
    /// as the geometry; `None` without one.
    pub fn load_system(
        &self,
        spec: Option<&str>,
    ) -> Result<Option<dbt_geometry::ConeSystem>, dbt_store::StoreError> {
        spec.map(|s| dbt_store::load_system(s, self.binning))
            .transpose()
    }
}

/// A DBToR model to run, and how.
#[derive(Debug, Clone, clap::Args)]
pub struct ModelArgs {
    /// DBToR model folder (`models/NAME`); without it, MLTR reconstructs.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Precision of the model's blocks.
    #[arg(long, default_value = "fp32", requires = "model")]
    pub precision: dbt_dbtor::Precision,
    /// Executor of the blocks: `fast` (the fused kernels) or `tract` (the
    /// reference).
    #[arg(long, default_value = "fast", requires = "model")]
    pub engine: dbt_dbtor::Engine,
}

/// The corrections of a clinical (polychromatic, scattered) acquisition
/// before the reconstruction, as the daemon's `recon.scatter` and
/// `recon.beam_hardening` configure them.
#[derive(Debug, Clone, clap::Args)]
#[command(group(clap::ArgGroup::new("linearised").args(["csi_um", "a_se_um"])))]
pub struct CorrectionArgs {
    /// Linearise the beam hardening of an energy-integrating CsI flat
    /// panel this many um thick (the daemon's `recon.beam_hardening =
    /// "csi"`, `converter_um`); without it or `--a-se-um` the counts are
    /// taken as mono-energetic.
    #[arg(long)]
    pub csi_um: Option<f64>,
    /// Linearise the beam hardening of an a-Se (direct-conversion) flat
    /// panel this many um thick (the daemon's `recon.beam_hardening =
    /// "a-se"`, `converter_um`: Hologic, Siemens, Fujifilm).
    #[arg(long)]
    pub a_se_um: Option<f64>,
    /// Remove the scatter with the shipped kernel model before the
    /// linearisation (the daemon's `recon.scatter = "kernel"`).
    #[arg(long)]
    pub descatter: bool,
    /// Match the linearised counts' noise to the DBToR model's training
    /// level (the daemon's `recon.noise_match = "training-level"`); with
    /// `--csi-um` or `--a-se-um` and a model.
    #[arg(long, requires = "linearised")]
    pub noise_match: bool,
}

impl CorrectionArgs {
    /// The beam-hardening linearisation asked for (a converter thickness
    /// outside `dbt_materials::CONVERTER_UM` refused, naming it).
    pub fn linearise(
        &self,
    ) -> Result<
        Option<dbt_pipeline::linearise::BeamHardening>,
        dbt_pipeline::linearise::LineariseError,
    > {
        use dbt_materials::{Converter, ConverterMaterial};
        let converter = match (self.csi_um, self.a_se_um) {
            (Some(um), _) => Converter {
                material: ConverterMaterial::CsI,
                thickness_um: um,
            },
            (None, Some(um)) => Converter {
                material: ConverterMaterial::ASe,
                thickness_um: um,
            },
            (None, None) => return Ok(None),
        };
        dbt_pipeline::linearise::BeamHardening::for_converter(converter).map(Some)
    }

    /// The scatter removal asked for.
    pub fn descatter(
        &self,
    ) -> Result<
        Option<dbt_pipeline::descatter::ScatterRemoval>,
        dbt_pipeline::descatter::DescatterError,
    > {
        self.descatter
            .then(dbt_pipeline::descatter::ScatterRemoval::shipped)
            .transpose()
    }
}

/// The bar on the terminal now, if any: log lines are written above it.
static ACTIVE: std::sync::Mutex<Option<indicatif::ProgressBar>> = std::sync::Mutex::new(None);

/// Standard error, written above the progress bar on the terminal (if any):
/// the writer of the binaries' log subscribers (`tracing_subscriber::fmt()
/// .with_writer(dbt_cli::log_writer)`), so that log lines and a bar do not
/// overwrite each other.
pub struct LogWriter;

/// A [`LogWriter`] (a `MakeWriter` for tracing-subscriber).
pub fn log_writer() -> LogWriter {
    LogWriter
}

impl std::io::Write for LogWriter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let bar = ACTIVE.lock().ok().and_then(|g| g.clone());
        match bar {
            Some(b) if !b.is_finished() => {
                b.suspend(|| std::io::stderr().write_all(buf))?;
                Ok(buf.len())
            }
            _ => std::io::stderr().write(buf),
        }
    }

    fn flush(&mut self) -> std::io::Result<()> {
        std::io::stderr().flush()
    }
}

/// This machine as every benchmark and diagnostic prints it: the CPU model
/// (`/proc/cpuinfo`), the instruction sets the kernels use that it has, and
/// the logical CPUs.
pub fn cpu_summary() -> String {
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, m)| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let isa = dbt_isa::present();
    format!(
        "{model}; {} logical CPUs; {}",
        std::thread::available_parallelism().map_or(1, |n| n.get()),
        if isa.is_empty() {
            format!("none of {}", dbt_isa::KNOWN.join("/"))
        } else {
            isa.join(" ")
        }
    )
}

/// The process's peak resident memory so far, MiB (Linux: `VmHWM` of
/// `/proc/self/status`); `None` where the kernel does not say.
pub fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    parse_vm_hwm(&status)
}

/// `VmHWM:   123456 kB` as MiB.
fn parse_vm_hwm(status: &str) -> Option<f64> {
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line
        .trim_start_matches("VmHWM:")
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kb / 1024.0)
}

/// Whether a progress bar may be drawn: stderr is a terminal and the command
/// does not print JSON.
pub fn bars_wanted(json: bool) -> bool {
    !json && std::io::stderr().is_terminal()
}

/// A progress bar over `len` steps, or an invisible one (see
/// [`bars_wanted`]); log lines go through [`Progress::line`] either way.
pub struct Progress {
    bar: indicatif::ProgressBar,
    visible: bool,
}

impl Progress {
    /// A bar named `what` over `len` `unit`s, drawn when [`bars_wanted`]`(json)`.
    pub fn new(len: u64, what: &str, unit: &str, json: bool) -> Self {
        Self::with_visibility(len, what, unit, bars_wanted(json))
    }

    /// As [`Progress::new`], visibility given.
    pub fn with_visibility(len: u64, what: &str, unit: &str, visible: bool) -> Self {
        let bar = if visible {
            let b = indicatif::ProgressBar::new(len);
            let template = format!(
                "{what} [{{bar:30.cyan/blue}}] {{pos}}/{{len}} {unit} {{elapsed_precise}} (eta {{eta}}) {{msg}}"
            );
            if let Ok(style) = indicatif::ProgressStyle::with_template(&template) {
                b.set_style(style.progress_chars("=> "));
            }
            if let Ok(mut g) = ACTIVE.lock() {
                *g = Some(b.clone());
            }
            b
        } else {
            indicatif::ProgressBar::hidden()
        };
        Self { bar, visible }
    }

    /// Whether the bar is drawn (on a terminal: indicatif draws nothing
    /// where stderr is not one).
    pub fn is_visible(&self) -> bool {
        self.visible
    }

    /// Advance by `n` steps.
    pub fn inc(&self, n: u64) {
        self.bar.inc(n);
    }

    /// Set the position.
    pub fn set_position(&self, pos: u64) {
        self.bar.set_position(pos);
    }

    /// Set the total.
    pub fn set_length(&self, len: u64) {
        self.bar.set_length(len);
    }

    /// The short message after the bar.
    pub fn message(&self, msg: impl Into<String>) {
        self.bar.set_message(msg.into());
    }

    /// Print a line on stderr above the bar (the bar is suspended meanwhile),
    /// or plainly when there is no bar.
    pub fn line(&self, msg: impl Display) {
        self.bar.suspend(|| eprintln!("{msg}"));
    }

    /// Remove the bar.
    pub fn finish(&self) {
        self.bar.finish_and_clear();
        if let Ok(mut g) = ACTIVE.lock() {
            if g.as_ref().is_some_and(|b| b.is_finished()) {
                *g = None;
            }
        }
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        self.finish();
    }
}

/// [`dbt_pipeline::process`] of one acquisition with a bar over its slices,
/// then its classification and dose stages (see [`Progress::new`] for when
/// it is drawn).
pub fn process_with_bar(
    acq: &dbt_pipeline::acquisition::Acquisition,
    opts: &dbt_pipeline::PipelineOptions,
    json: bool,
) -> Result<dbt_pipeline::ProcessResult, dbt_pipeline::PipelineError> {
    use dbt_pipeline::Stage;
    let bar = Progress::new(acq.header.slices as u64, "reconstruction", "slices", json);
    let r = dbt_pipeline::process_with_progress(acq, opts, &mut |st| match st {
        Stage::Slice { done, total } => {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        }
        Stage::Classification => bar.message("classification and density"),
        Stage::Dose => bar.message("Monte Carlo dose"),
    });
    bar.finish();
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn peak_memory_is_read_from_the_kernel_status() {
        let status = "Name:\tx\nVmPeak:\t  999 kB\nVmHWM:\t  204800 kB\nVmRSS:\t 1 kB\n";
        assert_eq!(parse_vm_hwm(status), Some(200.0));
        assert_eq!(parse_vm_hwm("VmRSS: 1 kB"), None);
        if cfg!(target_os = "linux") {
            assert!(peak_rss_mib().is_some_and(|m| m > 0.0));
        }
    }
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        geometry: GeometryArgs,
        #[command(flatten)]
        model: ModelArgs,
    }

    #[test]
    fn geometry_defaults_to_the_shipped_binning() {
        let c = Cli::try_parse_from(["x"]).unwrap();
        assert_eq!(c.geometry.binning, DEFAULT_BINNING);
        assert_eq!(c.geometry.geometry, "paper");
        let g = c.geometry.load().unwrap();
        assert_eq!(g, dbt_geometry::Geometry::paper().binned(4).unwrap());
        let c = Cli::try_parse_from(["x", "--geometry", "paper-tall", "--binning", "1"]).unwrap();
        assert!(c.geometry.load().is_ok());
    }

    #[test]
    fn bad_geometry_and_model_options_are_named() {
        let c = Cli::try_parse_from(["x", "--geometry", "nope.toml"]).unwrap();
        let e = c.geometry.load().unwrap_err().to_string();
        assert!(e.contains("nope.toml"), "{e}");
        let e = Cli::try_parse_from(["x", "--precision", "int8"])
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("--model"), "precision needs a model: {e}");
        let e = Cli::try_parse_from(["x", "--model", "m", "--precision", "fp16"])
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("fp16"), "{e}");
    }

    #[test]
    fn progress_is_off_with_json_and_off_a_terminal() {
        assert!(!Progress::new(10, "x", "steps", true).is_visible());
        // Tests run with stderr captured or piped: not a terminal.
        if !std::io::stderr().is_terminal() {
            assert!(!Progress::new(10, "x", "steps", false).is_visible());
        }
        let p = Progress::with_visibility(3, "x", "steps", true);
        assert!(p.is_visible());
        p.inc(1);
        p.line("a log line");
        // Log lines go through the active bar while it runs.
        assert!(ACTIVE.lock().unwrap().is_some());
        use std::io::Write;
        log_writer()
            .write_all(b"a log line through the writer\n")
            .unwrap();
        p.finish();
        assert!(ACTIVE.lock().unwrap().is_none());
        log_writer().write_all(b"and after it\n").unwrap();
    }
}
