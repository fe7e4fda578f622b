//! The daemon's configuration (TOML), validated at start: every error names
//! the key and says what is wrong. `firmware/config/dbtor.toml` is the
//! installed example.

use dbt_geometry::Geometry;
use serde::Deserialize;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;
use thiserror::Error;

/// A configuration error.
#[derive(Debug, Error)]
pub enum ConfigError {
    /// The file cannot be read.
    #[error("{path}: {cause}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        cause: std::io::Error,
    },
    /// TOML syntax, an unknown key, or a wrong type.
    #[error("{path}: {reason}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message (it names the key and line).
        reason: String,
    },
    /// A value that cannot work.
    #[error("{path}: `{key}`: {reason}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// The key.
        key: &'static str,
        /// Why.
        reason: String,
    },
}

/// How the projection frames arrive.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum FrameTransport {
    /// Connect to the gantry's frame server (`frames.address`).
    Tcp,
    /// A serial line (`frames.port`, `frames.baud`).
    Serial,
    /// No frame link: a site without our gantry integration, whose
    /// projections come over the DICOM input only (which must be on).
    Off,
}

/// How the gantry controller's registers are read.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum ModbusTransport {
    /// Modbus TCP (`modbus.address`).
    Tcp,
    /// Modbus RTU on a serial line (`modbus.port`, 8N1).
    Rtu,
    /// No register reads: no thickness cross-check.
    Off,
}

/// The reconstructor.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Reconstructor {
    /// DBToR with the signed-off model (`recon.model`).
    Dbtor,
    /// MLTR, the fallback (`recon.mltr_iterations`).
    Mltr,
    /// No reconstruction, for a gantry without a trained model (issue #51
    /// point 3): the physics-based density and the model breast's MGD on
    /// the gantry's geometry, each report naming the method.
    Physics,
}

/// Where the projection frames come from.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FramesConfig {
    /// `tcp` (connect to the gantry's frame server) or `serial`.
    pub transport: FrameTransport,
    /// `host:port` for tcp.
    #[serde(default)]
    pub address: Option<String>,
    /// Device path for serial.
    #[serde(default)]
    pub port: Option<String>,
    /// Baud rate for serial.
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// An acquisition fails when nothing arrives for this long, s.
    #[serde(default = "default_idle")]
    pub idle_timeout_s: f64,
    /// The gantry's geometry: `paper` (the paper's, 60 mm image),
    /// `paper-tall` (80 mm image, breasts up to 75 mm), `paper-104` (104 mm
    /// image, breasts up to 100 mm) or a geometry TOML
    /// (relative to the configuration file's folder). A DBToR model must
    /// have been trained for it (checked when the configuration is loaded).
    #[serde(default = "default_geometry")]
    pub geometry: String,
    /// Binning of that geometry (detector elements and image pixels).
    #[serde(default = "default_binning")]
    pub binning: usize,
    /// The gantry's cone-beam system (GANTRY_INTERFACE.md section 2):
    /// `paper-cone`, `siemens-victre` or a system TOML (relative to the
    /// configuration file's folder), binned by `binning`; its projections
    /// are rebinned to slice-wise sinograms in `geometry`, which must be its
    /// rebinning fan (checked when the configuration is loaded). Absent:
    /// the slice-wise fan-beam stream. A stream from another system is
    /// refused, naming both.
    #[serde(default)]
    pub system: Option<String>,
}

fn default_geometry() -> String {
    "paper".into()
}

fn default_baud() -> u32 {
    921_600
}
fn default_idle() -> f64 {
    30.0
}
fn default_binning() -> usize {
    4
}

/// The gantry controller's registers.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ModbusConfig {
    /// `tcp`, `rtu` (serial line) or `off` (no thickness cross-check).
    pub transport: ModbusTransport,
    /// `host:port` (tcp).
    #[serde(default)]
    pub address: Option<String>,
    /// Serial line (rtu).
    #[serde(default)]
    pub port: Option<String>,
    /// Baud rate (rtu, 8N1).
    #[serde(default = "default_modbus_baud")]
    pub baud: u32,
    /// Unit id.
    #[serde(default = "default_unit")]
    pub unit: u8,
    /// Address of register 0 of the map.
    #[serde(default)]
    pub base: u16,
    /// Timeout per call, ms.
    #[serde(default = "default_timeout_ms")]
    pub timeout_ms: u64,
    /// Attempts per read.
    #[serde(default = "default_attempts")]
    pub attempts: u32,
    /// Largest accepted difference between the register thickness and the
    /// acquisition header's, mm.
    #[serde(default = "default_tol")]
    pub thickness_tolerance_mm: f64,
}

fn default_modbus_baud() -> u32 {
    19_200
}
fn default_unit() -> u8 {
    1
}
fn default_timeout_ms() -> u64 {
    1000
}
fn default_attempts() -> u32 {
    3
}
fn default_tol() -> f64 {
    1.0
}

/// Reconstruction.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ReconConfig {
    /// `dbtor` or `mltr` (the fallback).
    pub reconstructor: Reconstructor,
    /// Model folder (for dbtor).
    #[serde(default)]
    pub model: Option<PathBuf>,
    /// The model folder's signed-off digest (`sha256:<hex>`, its
    /// `signoff.json`; `dbtor-diag model DIR` prints it). Required for dbtor:
    /// the daemon refuses to start on a folder whose files differ.
    #[serde(default)]
    pub model_digest: Option<String>,
    /// `int8` (the default) or `fp32`.
    #[serde(default = "default_precision")]
    pub precision: dbt_dbtor::Precision,
    /// `fast` (the fused kernels of dbt-conv, the default) or `tract` (the
    /// reference executor, any ONNX graph).
    #[serde(default = "default_engine")]
    pub engine: dbt_dbtor::Engine,
    /// With `precision = "int8"`: blocks run in fp32 (per-block mixed
    /// precision, e.g. `["primal07", "primal08", "primal09"]`).
    #[serde(default)]
    pub fp32_blocks: Vec<String>,
    /// MLTR iterations (for mltr).
    #[serde(default = "default_iterations")]
    pub mltr_iterations: usize,
    /// Target relative uncertainty of the Monte Carlo MGD.
    #[serde(default = "default_unc")]
    pub dose_uncertainty: f64,
    /// The detector's physics (issue #27): `off` (counts taken as
    /// mono-energetic: the paper's simulated photon-counting detector),
    /// `csi` (an energy-integrating CsI flat panel) or `a-se` (an a-Se
    /// direct-conversion panel: Hologic, Siemens, Fujifilm): the beam
    /// hardening linearised before the reconstruction for that converter
    /// (`dbt_pipeline::linearise`). With a cone-beam system whose file
    /// states its converter, another is refused naming both.
    #[serde(default)]
    pub beam_hardening: BeamHardeningMode,
    /// The converter layer's thickness, um (with `beam_hardening` `csi` or
    /// `a-se`; `csi_um` is read as this key too).
    #[serde(default = "default_converter_um", alias = "csi_um")]
    pub converter_um: f64,
    /// Noise matching (issue #27, `dbt_pipeline::noise_match`): `off`, or
    /// `training-level` (the corrected counts brought to the noise of the
    /// DBToR model's training level; with `beam_hardening = "csi"`,
    /// `scatter = "kernel"` and `reconstructor = "dbtor"`).
    #[serde(default)]
    pub noise_match: NoiseMatchMode,
    /// Scatter (issue #27): `off` (counts taken as primary: the paper's
    /// simulated detector, or a gantry with a grid) or `kernel` (removed
    /// before the linearisation with the shipped kernel model fitted to
    /// our Monte Carlo engine, `dbt_pipeline::descatter`; fitted for the
    /// paper geometry without a grid, W/Rh, 200 um CsI).
    #[serde(default)]
    pub scatter: ScatterMode,
    /// Reconstruct every `slice_step`-th coronal slice (and the last), the
    /// slices between interpolated in depth (issue #29 point 5; 1 to 8; 1,
    /// the default: every slice). The reports' Algorithm Version says so.
    #[serde(default = "default_slice_step")]
    pub slice_step: usize,
    /// An acquisition whose beam the model has no glandularity calibration
    /// for: `physics` (the default) reports it physics-only, each report
    /// naming the method (issue #51 point 3); `refuse` makes it a fault
    /// naming the beam.
    #[serde(default)]
    pub uncalibrated_beam: UncalibratedBeamMode,
}

/// `recon.uncalibrated_beam` (`dbtor-process --uncalibrated-beam`).
#[derive(Debug, Clone, Copy, Default, Deserialize, PartialEq, Eq, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum UncalibratedBeamMode {
    /// Reported physics-only (`dbt_pipeline::UncalibratedBeam::PhysicsOnly`).
    #[default]
    Physics,
    /// Refused, naming the beam.
    Refuse,
}

impl UncalibratedBeamMode {
    /// The pipeline's option.
    pub fn pipeline(self) -> dbt_pipeline::UncalibratedBeam {
        match self {
            Self::Physics => dbt_pipeline::UncalibratedBeam::PhysicsOnly,
            Self::Refuse => dbt_pipeline::UncalibratedBeam::Refuse,
        }
    }
}

/// How the counts' scatter is handled.
#[derive(Debug, Clone, Copy, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum ScatterMode {
    /// Counts taken as primary.
    #[default]
    Off,
    /// Removed with the shipped kernel model.
    Kernel,
}

/// Whether the corrected counts' noise is matched to the network's.
#[derive(Debug, Clone, Copy, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum NoiseMatchMode {
    /// The corrected counts as they are.
    #[default]
    Off,
    /// Matched to the DBToR model's training noise level.
    TrainingLevel,
}

/// How the counts' beam hardening is handled.
#[derive(Debug, Clone, Copy, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum BeamHardeningMode {
    /// Counts taken as mono-energetic.
    #[default]
    Off,
    /// Linearised for a CsI energy-integrating detector.
    Csi,
    /// Linearised for an a-Se direct-conversion detector.
    #[serde(rename = "a-se")]
    ASe,
}

impl BeamHardeningMode {
    /// The converter material linearised for (`None`: off).
    pub fn material(self) -> Option<dbt_materials::ConverterMaterial> {
        match self {
            BeamHardeningMode::Off => None,
            BeamHardeningMode::Csi => Some(dbt_materials::ConverterMaterial::CsI),
            BeamHardeningMode::ASe => Some(dbt_materials::ConverterMaterial::ASe),
        }
    }
}

fn default_converter_um() -> f64 {
    200.0
}

/// int8 since dbtor-x4t3qa (its GPTQ-rounded int8 as accurate as fp32 on
/// the validation split: models/README.md).
fn default_precision() -> dbt_dbtor::Precision {
    dbt_dbtor::Precision::Int8
}
fn default_engine() -> dbt_dbtor::Engine {
    dbt_dbtor::Engine::Fast
}
fn default_iterations() -> usize {
    100
}
fn default_unc() -> f64 {
    0.01
}

fn default_slice_step() -> usize {
    1
}

/// The slice steps the firmware takes (`recon.slice_step`, `dbtor-process
/// --slice-step`): every slice to every 8th.
pub const SLICE_STEPS: std::ops::RangeInclusive<usize> = 1..=8;

/// Folders.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PathsConfig {
    /// Received acquisitions, kept until their reports are delivered.
    pub spool: PathBuf,
    /// Reports.
    pub output: PathBuf,
    /// The status file the diagnostics CLI reads.
    pub status: PathBuf,
}

/// Report identity and destination.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ReportConfig {
    /// UID root of this installation.
    pub uid_root: String,
    /// `AET@host:port` of the PACS, if any.
    #[serde(default)]
    pub pacs: Option<String>,
    /// Device serial number in the reports.
    #[serde(default = "default_serial")]
    pub device_serial: String,
    /// Tube output at the reference point, mGy/mAs (from the QC), of the
    /// W/Rh beam: one figure, or the QC's figures by kV ([`TubeOutput`]).
    pub tube_output_mgy_per_mas: TubeOutput,
    /// The same for the W/Al beam (its own QC figure: the filters pass
    /// different shares of the tube's output); absent, W/Al exposures are
    /// refused rather than dosed with the W/Rh output.
    #[serde(default)]
    pub tube_output_w_al_mgy_per_mas: Option<TubeOutput>,
    /// The same for the W/Ag beam; absent, W/Ag exposures are refused.
    #[serde(default)]
    pub tube_output_w_ag_mgy_per_mas: Option<TubeOutput>,
    /// The Mo/Mo beam's tube output, mGy/mAs at 1 m, as
    /// [`Self::tube_output_w_al_mgy_per_mas`]. Absent: refused.
    #[serde(default)]
    pub tube_output_mo_mo_mgy_per_mas: Option<TubeOutput>,
    /// The Mo/Rh beam's tube output, as above. Absent: refused.
    #[serde(default)]
    pub tube_output_mo_rh_mgy_per_mas: Option<TubeOutput>,
    /// The Rh/Rh beam's tube output, as above. Absent: refused.
    #[serde(default)]
    pub tube_output_rh_rh_mgy_per_mas: Option<TubeOutput>,
    /// The beam of an acquisition whose input does not state it (a DICOM
    /// object without Filter Material; a stream header without
    /// `anode_filter` where no Modbus register 6 is read): `"W/Rh"` (the
    /// default, the paper's), `"W/Al"`, `"W/Ag"`, or `"refuse"` for a site whose
    /// gantry uses more than one beam: such an acquisition is then a
    /// `technique` fault, never dosed with a beam taken for granted.
    #[serde(default = "default_unstated_beam")]
    pub unstated_beam: String,
}

fn default_unstated_beam() -> String {
    "W/Rh".into()
}

pub use dbt_intake::technique::{KvTable, TubeOutput};

impl ReportConfig {
    /// [`Self::unstated_beam`]: the beam, or `None` for `"refuse"`. Checked
    /// by [`Config::validate`]; an unknown value reads as `None` (refuse).
    pub fn unstated_beam(&self) -> Option<dbt_dose::xray::AnodeFilter> {
        dbt_dose::xray::AnodeFilter::parse(&self.unstated_beam).ok()
    }

    /// The tube output of `beam`, if configured.
    pub fn tube_output(&self, beam: dbt_dose::xray::AnodeFilter) -> Option<&TubeOutput> {
        match beam {
            dbt_dose::xray::AnodeFilter::WRh => Some(&self.tube_output_mgy_per_mas),
            dbt_dose::xray::AnodeFilter::WAl => self.tube_output_w_al_mgy_per_mas.as_ref(),
            dbt_dose::xray::AnodeFilter::WAg => self.tube_output_w_ag_mgy_per_mas.as_ref(),
            dbt_dose::xray::AnodeFilter::MoMo => self.tube_output_mo_mo_mgy_per_mas.as_ref(),
            dbt_dose::xray::AnodeFilter::MoRh => self.tube_output_mo_rh_mgy_per_mas.as_ref(),
            dbt_dose::xray::AnodeFilter::RhRh => self.tube_output_rh_rh_mgy_per_mas.as_ref(),
        }
    }

    /// The configuration key of `beam`'s tube output.
    pub fn tube_output_key(beam: dbt_dose::xray::AnodeFilter) -> &'static str {
        dbt_intake::technique::tube_output_key(beam)
    }
}

fn default_serial() -> String {
    "UNSET".into()
}

/// The status page (`firmware/src/status_page.rs`).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StatusPageConfig {
    /// `host:port` to serve the read-only page on, or `"off"`. Default
    /// [`StatusPageConfig::DEFAULT_ADDRESS`] (loopback).
    #[serde(default = "default_status_address")]
    pub address: String,
    /// Serve on an address other than loopback. The page has no
    /// authentication (it shows no patient identifier and has no write
    /// action), so this is a decision for the site's network, taken in the
    /// configuration.
    #[serde(default)]
    pub allow_non_loopback: bool,
}

impl StatusPageConfig {
    /// The default address: loopback, port 8090.
    pub const DEFAULT_ADDRESS: &'static str = "127.0.0.1:8090";
}

impl Default for StatusPageConfig {
    fn default() -> Self {
        Self {
            address: Self::DEFAULT_ADDRESS.into(),
            allow_non_loopback: false,
        }
    }
}

fn default_status_address() -> String {
    StatusPageConfig::DEFAULT_ADDRESS.into()
}

/// The DICOM input: a Storage SCP for the modality's For Processing
/// projections (issue #31), beside the frame link.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DicomInputConfig {
    /// `host:port` to listen on, or `"off"` (the default).
    #[serde(default = "default_off")]
    pub address: String,
    /// Our AE title (the called AE title the modality must use).
    #[serde(default = "default_ae")]
    pub ae_title: String,
    /// The detector's unattenuated counts per element at the technique
    /// (the flat field the For Processing counts are relative to; from the
    /// system's calibration). Required when the input is on.
    #[serde(default)]
    pub flat_field_counts: Option<f64>,
    /// A sweep sent one object per view is complete when every configured
    /// view is in; when no view of it arrived for this long, s, it is
    /// faulted as incomplete (default 120: a modality sends its views within
    /// seconds of the sweep, and a resend after a network fault within a
    /// minute or two).
    #[serde(default = "default_quiet_time")]
    pub quiet_time_s: f64,
    /// Associations served at once (default 4); more wait for a free one.
    #[serde(default = "default_max_associations")]
    pub max_associations: usize,
    /// Vendor private projection classes, each with its mapping file
    /// (none built in).
    #[serde(default)]
    pub private_class: Vec<PrivateClassConfig>,
}

/// A vendor's private projection class and the file that says where it
/// keeps what the input reads.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PrivateClassConfig {
    /// Its SOP class UID.
    pub sop_class: String,
    /// The mapping file (TOML: `name`, `layout` = "multi-frame" or
    /// "per-view", `[tags]` keyword = "gggg,eeee", `[creators]`
    /// "gggg,00xx" = private creator); relative to the configuration.
    pub mapping: PathBuf,
}

/// A mapping file's content.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct MappingFile {
    name: String,
    layout: String,
    #[serde(default)]
    tags: std::collections::BTreeMap<String, String>,
    #[serde(default)]
    creators: std::collections::BTreeMap<String, String>,
}

impl Default for DicomInputConfig {
    fn default() -> Self {
        Self {
            address: default_off(),
            ae_title: default_ae(),
            flat_field_counts: None,
            quiet_time_s: default_quiet_time(),
            max_associations: default_max_associations(),
            private_class: vec![],
        }
    }
}

fn default_quiet_time() -> f64 {
    120.0
}

fn default_max_associations() -> usize {
    4
}

/// The DICOM input as configured and checked.
#[derive(Debug, Clone)]
pub struct DicomInputSettings {
    /// Where it listens.
    pub address: SocketAddr,
    /// Our AE title.
    pub ae_title: String,
    /// The flat field, counts.
    pub flat_field_counts: f64,
    /// See [`DicomInputConfig::quiet_time_s`].
    pub quiet_time: std::time::Duration,
    /// See [`DicomInputConfig::max_associations`].
    pub max_associations: usize,
    /// The private classes' mappings.
    pub private: Vec<dbt_dicom::input::Mapping>,
}

fn default_off() -> String {
    "off".into()
}

fn default_ae() -> String {
    "DBTOR".into()
}

/// The whole file.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Frames.
    pub frames: FramesConfig,
    /// Modbus.
    pub modbus: ModbusConfig,
    /// Reconstruction and dose.
    pub recon: ReconConfig,
    /// Folders.
    pub paths: PathsConfig,
    /// Reports.
    pub report: ReportConfig,
    /// The status page (default: served on loopback).
    #[serde(default)]
    pub status_page: StatusPageConfig,
    /// The DICOM input (default: off).
    #[serde(default)]
    pub dicom_input: DicomInputConfig,
}

/// The dotted key (`recon.engine`) of the value at byte `at` of a TOML
/// configuration: the key on its line, under the last `[table]` above.
fn key_at(text: &str, at: usize) -> Option<String> {
    let before = text.get(..at)?;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let line = text[line_start..].lines().next()?;
    let key = line.split_once('=')?.0.trim();
    if key.is_empty() || key.starts_with('#') || key.starts_with('[') {
        return None;
    }
    let table = before[..line_start]
        .lines()
        .rev()
        .map(str::trim)
        .find(|l| l.starts_with('[') && l.ends_with(']'))
        .map(|l| l.trim_matches(|c| c == '[' || c == ']').trim());
    Some(match table {
        Some(t) => format!("{t}.{key}"),
        None => key.to_string(),
    })
}

impl Config {
    /// The site's rules for settling an acquisition ([`dbt_intake::settle`]):
    /// the thickness cross-check where the registers are read, the unstated
    /// beam, each configured beam's tube output.
    pub fn site_policy(&self) -> dbt_intake::SitePolicy {
        use dbt_dose::xray::AnodeFilter;
        dbt_intake::SitePolicy {
            thickness_tolerance_mm: (self.modbus.transport != ModbusTransport::Off)
                .then_some(self.modbus.thickness_tolerance_mm),
            unstated_beam: self.report.unstated_beam(),
            tube_outputs: AnodeFilter::ALL
                .into_iter()
                .filter_map(|b| self.report.tube_output(b).map(|t| (b, t.clone())))
                .collect(),
        }
    }

    /// Read and validate. Relative paths are taken from the file's folder.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
            path: path.to_path_buf(),
            cause: source,
        })?;
        Self::parse(&text, path)
    }

    /// Parse and validate a configuration's text as if read from `path`
    /// (relative paths are taken from its folder).
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let mut c: Config = toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: path.to_path_buf(),
            reason: match e.span().and_then(|s| key_at(text, s.start)) {
                Some(key) => format!("`{key}`: {e}"),
                None => e.to_string(),
            },
        })?;
        let base = path.parent().unwrap_or(Path::new("."));
        let abs = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        };
        if Geometry::builtin(&c.frames.geometry).is_none() {
            let mut g = PathBuf::from(&c.frames.geometry);
            abs(&mut g);
            c.frames.geometry = g.to_string_lossy().into_owned();
        }
        if let Some(s) = c.frames.system.as_mut() {
            if dbt_geometry::ConeSystem::builtin(s).is_none() {
                let mut p = PathBuf::from(&*s);
                abs(&mut p);
                *s = p.to_string_lossy().into_owned();
            }
        }
        abs(&mut c.paths.spool);
        abs(&mut c.paths.output);
        abs(&mut c.paths.status);
        if let Some(m) = c.recon.model.as_mut() {
            abs(m);
        }
        c.validate(path)?;
        Ok(c)
    }

    /// The status page's address, `None` when `status_page.address = "off"`.
    /// Refuses an unparsable address, and one that is not loopback unless
    /// `status_page.allow_non_loopback` is set.
    pub fn status_page_address(&self, path: &Path) -> Result<Option<SocketAddr>, ConfigError> {
        let sp = &self.status_page;
        if sp.address == "off" {
            return Ok(None);
        }
        let bad = |reason: String| ConfigError::Invalid {
            path: path.to_path_buf(),
            key: "status_page.address",
            reason,
        };
        let addr: SocketAddr = sp.address.parse().map_err(|e| {
            bad(format!(
                "{:?}: {e} (an IP address and a port, e.g. {}, or \"off\")",
                sp.address,
                StatusPageConfig::DEFAULT_ADDRESS
            ))
        })?;
        if !addr.ip().is_loopback() && !sp.allow_non_loopback {
            return Err(bad(format!(
                "{:?} is not a loopback address, and the page has no authentication: \
                 set status_page.allow_non_loopback = true to serve it there",
                sp.address
            )));
        }
        Ok(Some(addr))
    }

    /// The DICOM input's settings, `None` when off; refuses an unparsable
    /// address, an AE title that is not 1-16 characters, a missing or
    /// non-positive flat field, a quiet time outside 1 s - 1 day, no
    /// association, and a private class whose mapping file is unreadable
    /// or maps what the input does not read (each named).
    pub fn dicom_input(&self, path: &Path) -> Result<Option<DicomInputSettings>, ConfigError> {
        let d = &self.dicom_input;
        if d.address == "off" {
            return Ok(None);
        }
        let bad = |key: &'static str, reason: String| ConfigError::Invalid {
            path: path.to_path_buf(),
            key,
            reason,
        };
        let addr: SocketAddr = d.address.parse().map_err(|e| {
            bad(
                "dicom_input.address",
                format!(
                    "{:?}: {e} (an IP address and a port, e.g. 0.0.0.0:11112, or \"off\")",
                    d.address
                ),
            )
        })?;
        let ae = d.ae_title.trim();
        if ae.is_empty() || ae.len() > 16 || ae.contains('\\') {
            return Err(bad(
                "dicom_input.ae_title",
                format!("{:?}: 1 to 16 characters, no backslash", d.ae_title),
            ));
        }
        let flux = d.flat_field_counts.ok_or_else(|| {
            bad(
                "dicom_input.flat_field_counts",
                "required with the DICOM input on (the system's calibrated flat field)".into(),
            )
        })?;
        if !(flux.is_finite() && flux > 0.0 && flux <= 65535.0 * 16.0) {
            return Err(bad(
                "dicom_input.flat_field_counts",
                format!("{flux} is not a positive count"),
            ));
        }
        if !(d.quiet_time_s.is_finite() && (1.0..=86_400.0).contains(&d.quiet_time_s)) {
            return Err(bad(
                "dicom_input.quiet_time_s",
                format!("{}: 1 to 86400 s", d.quiet_time_s),
            ));
        }
        if !(1..=64).contains(&d.max_associations) {
            return Err(bad(
                "dicom_input.max_associations",
                format!("{}: 1 to 64", d.max_associations),
            ));
        }
        let base = path.parent().unwrap_or(Path::new("."));
        let mut private = Vec::new();
        for (i, pc) in d.private_class.iter().enumerate() {
            let file = base.join(&pc.mapping);
            let named = |reason: String| {
                bad(
                    "dicom_input.private_class.mapping",
                    format!("[{i}] {}: {reason}", file.display()),
                )
            };
            let text = std::fs::read_to_string(&file).map_err(|e| named(e.to_string()))?;
            let m: MappingFile = toml::from_str(&text).map_err(|e| named(e.to_string()))?;
            let layout = dbt_dicom::input::Layout::parse(&m.layout).ok_or_else(|| {
                named(format!(
                    "layout {:?}: \"multi-frame\" or \"per-view\"",
                    m.layout
                ))
            })?;
            let tag = |t: &str| {
                dbt_dicom::input::parse_tag(t)
                    .ok_or_else(|| named(format!("{t:?} is not a tag (gggg,eeee)")))
            };
            let tags = m
                .tags
                .iter()
                .map(|(k, v)| Ok((k.clone(), tag(v)?)))
                .collect::<Result<_, ConfigError>>()?;
            let creators = m
                .creators
                .iter()
                .map(|(k, v)| Ok((tag(k)?, v.clone())))
                .collect::<Result<_, ConfigError>>()?;
            let mapping = dbt_dicom::input::Mapping::new(
                &m.name,
                pc.sop_class.trim(),
                layout,
                tags,
                creators,
            )
            .map_err(|e| named(e.to_string()))?;
            private.push(mapping);
        }
        Ok(Some(DicomInputSettings {
            address: addr,
            ae_title: ae.to_string(),
            flat_field_counts: flux,
            quiet_time: std::time::Duration::from_secs_f64(d.quiet_time_s),
            max_associations: d.max_associations,
            private,
        }))
    }

    fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        let bad = |key: &'static str, reason: String| ConfigError::Invalid {
            path: path.to_path_buf(),
            key,
            reason,
        };
        self.status_page_address(path)?;
        self.dicom_input(path)?;
        match self.frames.transport {
            FrameTransport::Tcp => {
                let a = self.frames.address.as_deref().ok_or_else(|| {
                    bad("frames.address", "required with transport = \"tcp\"".into())
                })?;
                let addr: SocketAddr = a.parse().map_err(|e| {
                    bad(
                        "frames.address",
                        format!("{a:?}: {e} (an IP address and a port, e.g. 192.168.10.2:5000)"),
                    )
                })?;
                if addr.port() == 0 {
                    return Err(bad("frames.address", format!("{a:?}: port 0")));
                }
            }
            FrameTransport::Off => {
                if self.dicom_input.address == "off" {
                    return Err(bad(
                        "frames.transport",
                        "\"off\" leaves no input: turn the DICOM input on ([dicom_input] address)"
                            .into(),
                    ));
                }
            }
            FrameTransport::Serial => {
                if self.frames.port.is_none() {
                    return Err(bad(
                        "frames.port",
                        "required with transport = \"serial\"".into(),
                    ));
                }
                if self.frames.baud < 1200 {
                    return Err(bad(
                        "frames.baud",
                        format!("{} is below 1200", self.frames.baud),
                    ));
                }
            }
        }
        if !(self.frames.idle_timeout_s > 0.0 && self.frames.idle_timeout_s <= 3600.0) {
            return Err(bad(
                "frames.idle_timeout_s",
                "must be in (0, 3600] s".into(),
            ));
        }
        if ![1, 2, 4].contains(&self.frames.binning) {
            return Err(bad(
                "frames.binning",
                format!("{}: expected 1, 2 or 4", self.frames.binning),
            ));
        }
        let gantry = self.gantry_geometry(path)?;
        if let Some(sys) = self.gantry_system(path)? {
            dbt_pipeline::rebin::check_site(&sys, &gantry).map_err(|e| {
                bad(
                    "frames.system",
                    format!(
                        "{e} (frames.geometry = {:?}, binning {}: the geometry must be the system's rebinning fan)",
                        self.frames.geometry, self.frames.binning
                    ),
                )
            })?;
        }
        match self.modbus.transport {
            ModbusTransport::Tcp | ModbusTransport::Rtu => {
                self.modbus_endpoint(path)?;
            }
            ModbusTransport::Off => {}
        }
        if self.modbus.timeout_ms == 0 || self.modbus.attempts == 0 {
            return Err(bad(
                "modbus.timeout_ms",
                "timeout and attempts must be positive".into(),
            ));
        }
        if !(self.modbus.thickness_tolerance_mm > 0.0 && self.modbus.thickness_tolerance_mm < 20.0)
        {
            return Err(bad(
                "modbus.thickness_tolerance_mm",
                "must be in (0, 20) mm".into(),
            ));
        }
        if let Some(material) = self.recon.beam_hardening.material() {
            let converter = dbt_materials::Converter {
                material,
                thickness_um: self.recon.converter_um,
            };
            if let Err(e) = converter.validate() {
                return Err(bad("recon.converter_um", e.to_string()));
            }
            // The system's converter: its file's, else 200 um of CsI.
            if let Some(sys) = self.gantry_system(path)? {
                if sys.converter() != converter {
                    return Err(bad(
                        "recon.beam_hardening",
                        format!(
                            "linearises for {converter}, but frames.system {} has {} \
                             (set beam_hardening and converter_um to its converter)",
                            sys.name,
                            sys.converter()
                        ),
                    ));
                }
            }
        } else if !(self.recon.converter_um.is_finite() && self.recon.converter_um > 0.0) {
            return Err(bad(
                "recon.converter_um",
                format!(
                    "{} um must be a positive number (read only with beam_hardening \"csi\" or \"a-se\")",
                    self.recon.converter_um
                ),
            ));
        }
        if self.recon.noise_match == NoiseMatchMode::TrainingLevel
            && (self.recon.beam_hardening == BeamHardeningMode::Off
                || self.recon.scatter != ScatterMode::Kernel
                || self.recon.reconstructor != Reconstructor::Dbtor)
        {
            return Err(bad(
                "recon.noise_match",
                "\"training-level\" matches corrected counts to a DBToR model's training noise, as measured with both corrections: it needs beam_hardening = \"csi\" or \"a-se\", scatter = \"kernel\" and reconstructor = \"dbtor\"".into(),
            ));
        }
        match self.recon.reconstructor {
            Reconstructor::Dbtor => {
                let m = self.recon.model.as_ref().ok_or_else(|| {
                    bad(
                        "recon.model",
                        "required with reconstructor = \"dbtor\"".into(),
                    )
                })?;
                if !m.join("manifest.json").is_file() {
                    return Err(bad(
                        "recon.model",
                        format!("{} has no manifest.json", m.display()),
                    ));
                }
                // The model must be trained for the gantry's geometry.
                let manifest = dbt_dbtor::ModelManifest::load(m)
                    .map_err(|e| bad("recon.model", e.to_string()))?;
                if manifest.geometry != gantry {
                    return Err(bad(
                        "recon.model",
                        format!(
                            "{} was trained for {}, the gantry (frames.geometry = {:?}{}, binning {}) is {}: use a model trained for this gantry, or reconstructor = \"physics\" (the physics-based density and the model breast's dose, no model)",
                            m.display(),
                            manifest.geometry.describe(),
                            self.frames.geometry,
                            self.frames
                                .system
                                .as_deref()
                                .map_or(String::new(), |s| format!(", frames.system = {s:?}")),
                            self.frames.binning,
                            gantry.describe()
                        ),
                    ));
                }
                let digest = self.recon.model_digest.as_deref().ok_or_else(|| {
                    bad(
                        "recon.model_digest",
                        format!(
                            "required with reconstructor = \"dbtor\": the signed-off digest of {} (`dbtor-diag model DIR` prints it)",
                            m.display()
                        ),
                    )
                })?;
                let hex = digest.strip_prefix("sha256:").unwrap_or("");
                if hex.len() != 64 || !hex.bytes().all(|b| b.is_ascii_hexdigit()) {
                    return Err(bad(
                        "recon.model_digest",
                        format!("{digest:?} is not sha256:<64 hex digits>"),
                    ));
                }
                if !self.recon.fp32_blocks.is_empty()
                    && self.recon.precision != dbt_dbtor::Precision::Int8
                {
                    return Err(bad(
                        "recon.fp32_blocks",
                        "only with precision = \"int8\" (the blocks that stay fp32)".into(),
                    ));
                }
            }
            Reconstructor::Mltr => {
                if self.recon.mltr_iterations == 0 {
                    return Err(bad("recon.mltr_iterations", "must be positive".into()));
                }
            }
            // Nothing is reconstructed: a model named would be silently
            // unused, so it is refused.
            Reconstructor::Physics => {
                if let Some(m) = &self.recon.model {
                    return Err(bad(
                        "recon.model",
                        format!(
                            "{} is not used with reconstructor = \"physics\" (no reconstruction): remove it, or use reconstructor = \"dbtor\"",
                            m.display()
                        ),
                    ));
                }
            }
        }
        if !(self.recon.dose_uncertainty > 0.0 && self.recon.dose_uncertainty <= 0.5) {
            return Err(bad("recon.dose_uncertainty", "must be in (0, 0.5]".into()));
        }
        if !SLICE_STEPS.contains(&self.recon.slice_step) {
            return Err(bad(
                "recon.slice_step",
                format!(
                    "{}: reconstruct every {}st to {}th coronal slice",
                    self.recon.slice_step,
                    SLICE_STEPS.start(),
                    SLICE_STEPS.end()
                ),
            ));
        }
        if let Some(p) = &self.report.pacs {
            dbt_pacs::PacsConfig::parse(p).map_err(|e| bad("report.pacs", e.to_string()))?;
        }
        dbt_dicom::UidSource::new(&self.report.uid_root, 1)
            .map_err(|e| bad("report.uid_root", e.to_string()))?;
        // The acquisition header's limit: a configuration every acquisition's
        // header would be refused for is refused at start instead.
        let max = dbt_pipeline::acquisition::limits::TUBE_OUTPUT_MAX_MGY_PER_MAS;
        for beam in dbt_dose::xray::AnodeFilter::ALL {
            if let Some(Err(e)) = self.report.tube_output(beam).map(|t| t.check(max)) {
                return Err(bad(ReportConfig::tube_output_key(beam), e));
            }
        }
        let unstated = &self.report.unstated_beam;
        if unstated != "refuse" {
            match dbt_dose::xray::AnodeFilter::parse(unstated) {
                Ok(b) if self.report.tube_output(b).is_none() => {
                    return Err(bad(
                        "report.unstated_beam",
                        format!(
                            "{unstated}: no tube output is configured for it ({})",
                            ReportConfig::tube_output_key(b)
                        ),
                    ))
                }
                Ok(_) => {}
                Err(e) => {
                    return Err(bad(
                        "report.unstated_beam",
                        format!("{unstated:?}: {e}; or \"refuse\""),
                    ))
                }
            }
        }
        Ok(())
    }

    /// The Modbus server (transport tcp or rtu).
    pub fn modbus_endpoint(&self, path: &Path) -> Result<crate::modbus::Endpoint, ConfigError> {
        let bad = |key: &'static str, reason: String| ConfigError::Invalid {
            path: path.to_path_buf(),
            key,
            reason,
        };
        if self.modbus.transport == ModbusTransport::Rtu {
            let p =
                self.modbus.port.clone().ok_or_else(|| {
                    bad("modbus.port", "required with transport = \"rtu\"".into())
                })?;
            if self.modbus.baud < 1200 {
                return Err(bad(
                    "modbus.baud",
                    format!("{} is below 1200", self.modbus.baud),
                ));
            }
            return Ok(crate::modbus::Endpoint::Rtu {
                path: p,
                baud: self.modbus.baud,
            });
        }
        let a = self
            .modbus
            .address
            .as_deref()
            .ok_or_else(|| bad("modbus.address", "required with transport = \"tcp\"".into()))?;
        let addr: SocketAddr = a.parse().map_err(|e| {
            bad(
                "modbus.address",
                format!("{a:?}: {e} (an IP address and port)"),
            )
        })?;
        Ok(crate::modbus::Endpoint::Tcp(addr))
    }

    /// The gantry's geometry (`frames.geometry`, binned by `frames.binning`).
    pub fn gantry_geometry(&self, path: &Path) -> Result<Geometry, ConfigError> {
        let g =
            dbt_store::load_geometry(&self.frames.geometry, self.frames.binning).map_err(|e| {
                ConfigError::Invalid {
                    path: path.to_path_buf(),
                    key: "frames.geometry",
                    reason: e.to_string(),
                }
            })?;
        // A cone-beam system's frames are rebinned to its fan on the
        // geometry's image and elements (the geometry itself for the
        // paper's gantry; raised onto the support, its virtual detector
        // widened, for a vendor's: `ConeSystem::rebinning_fan`).
        match self.gantry_system(path)? {
            Some(sys) => sys.rebinning_fan(&g).map_err(|e| ConfigError::Invalid {
                path: path.to_path_buf(),
                key: "frames.system",
                reason: format!(
                    "{e} (the system's fan on frames.geometry = {:?})",
                    self.frames.geometry
                ),
            }),
            None => Ok(g),
        }
    }

    /// The gantry's cone-beam system (`frames.system`, binned by
    /// `frames.binning`), if any.
    pub fn gantry_system(
        &self,
        path: &Path,
    ) -> Result<Option<dbt_geometry::ConeSystem>, ConfigError> {
        self.frames
            .system
            .as_deref()
            .map(|s| dbt_store::load_system(s, self.frames.binning))
            .transpose()
            .map_err(|e| ConfigError::Invalid {
                path: path.to_path_buf(),
                key: "frames.system",
                reason: e.to_string(),
            })
    }

    /// The site's gantry, as every input checks against it: its geometry
    /// and cone-beam system, the nominal tube output and the unstated beam
    /// (the flat field of For Processing objects is the DICOM input's:
    /// [`Self::dicom_input`]).
    pub fn gantry(&self, path: &Path) -> Result<dbt_intake::Gantry, ConfigError> {
        Ok(dbt_intake::Gantry {
            geometry: self.gantry_geometry(path)?,
            cone: self.gantry_system(path)?,
            flux: None,
            tube_output_mgy_per_mas: self.report.tube_output_mgy_per_mas.nominal(),
            unstated_beam: self.report.unstated_beam(),
        })
    }

    /// The beam-hardening correction the configuration asks for, if any.
    pub fn linearise(&self) -> Option<dbt_pipeline::linearise::BeamHardening> {
        self.recon.beam_hardening.material().map(|material| {
            dbt_pipeline::linearise::BeamHardening {
                detector: dbt_forward::clinical::Detector::with(dbt_materials::Converter {
                    material,
                    thickness_um: self.recon.converter_um,
                }),
                path: dbt_pipeline::linearise::PathModel::Reference,
            }
        })
    }

    /// What the configured corrections do to the counts before the
    /// network: the key of the glandularity calibration to load
    /// (`dbt_model::pick_calibration`).
    pub fn input_corrections(&self) -> dbt_model::InputCorrections {
        dbt_model::InputCorrections {
            scatter_removed: self.recon.scatter == ScatterMode::Kernel,
            linearised: self.recon.beam_hardening != BeamHardeningMode::Off,
            noise_matched: self.recon.noise_match == NoiseMatchMode::TrainingLevel,
            a_se_detector: self.recon.beam_hardening == BeamHardeningMode::ASe,
            ..Default::default()
        }
    }

    /// The scatter removal the configuration asks for, if any.
    pub fn descatter(
        &self,
        path: &Path,
    ) -> Result<Option<dbt_pipeline::descatter::ScatterRemoval>, ConfigError> {
        match self.recon.scatter {
            ScatterMode::Off => Ok(None),
            ScatterMode::Kernel => dbt_pipeline::descatter::ScatterRemoval::shipped()
                .map(Some)
                .map_err(|e| ConfigError::Invalid {
                    path: path.to_path_buf(),
                    key: "recon.scatter",
                    reason: e.to_string(),
                }),
        }
    }

    /// The idle timeout of the frame link.
    pub fn idle_timeout(&self) -> Duration {
        Duration::from_secs_f64(self.frames.idle_timeout_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shipped example with the model pointed at the repository's copy of
    /// the one it names (`models/<name>` for `recon.model = ".../<name>"`), so
    /// that switching the shipped model is one edit of the shipped file.
    fn example(edit: impl Fn(String) -> String) -> Result<Config, ConfigError> {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let text = std::fs::read_to_string(root.join("config/dbtor.toml")).unwrap();
        let shipped: toml::Value = toml::from_str(&text).unwrap();
        let installed = shipped["recon"]["model"].as_str().unwrap().to_string();
        let name = Path::new(&installed).file_name().unwrap();
        let model = root.join("../models").join(name);
        assert!(model.join("manifest.json").is_file(), "{}", model.display());
        let text = text.replace(
            &format!("{installed:?}"),
            &format!("{:?}", model.display().to_string()),
        );
        let t = tempfile::tempdir().unwrap();
        let p = t.path().join("dbtor.toml");
        std::fs::write(&p, edit(text)).unwrap();
        Config::load(&p)
    }

    /// `text` with the physics-only reconstructor and no model.
    fn physics(text: &str) -> String {
        without(&without(text, "model"), "precision")
            .replace("reconstructor = \"dbtor\"", "reconstructor = \"physics\"")
    }

    /// `text` without the lines that set `key`.
    fn without(text: &str, key: &str) -> String {
        text.lines()
            .filter(|l| !l.starts_with(key))
            .collect::<Vec<_>>()
            .join("\n")
    }

    #[test]
    fn engine_is_validated_and_defaults_to_fast() {
        let c = example(|t| t).unwrap();
        assert_eq!(c.recon.engine, dbt_dbtor::Engine::Fast);
        let c = example(|t| t.replace("engine = \"fast\"", "engine = \"tract\"")).unwrap();
        assert_eq!(c.recon.engine, dbt_dbtor::Engine::Tract);
        let c = example(|t| without(&t, "engine")).unwrap();
        assert_eq!(c.recon.engine, dbt_dbtor::Engine::Fast);
        let e = example(|t| t.replace("engine = \"fast\"", "engine = \"warp\""))
            .unwrap_err()
            .to_string();
        assert!(e.contains("recon.engine") && e.contains("warp"), "{e}");
    }

    /// The status page: loopback by default, `off` turns it off, and an
    /// address other than loopback is refused unless the configuration
    /// allows it explicitly.
    #[test]
    fn status_page_is_loopback_unless_allowed() {
        let path = Path::new("x.toml");
        let c = example(|t| t).unwrap();
        assert_eq!(
            c.status_page_address(path).unwrap(),
            Some("127.0.0.1:8090".parse().unwrap())
        );
        let c = example(|t| {
            let i = t.find("[status_page]").unwrap();
            t[..i].to_string()
        })
        .unwrap();
        assert_eq!(
            c.status_page,
            StatusPageConfig::default(),
            "section optional"
        );
        let c =
            example(|t| t.replace("address = \"127.0.0.1:8090\"", "address = \"off\"")).unwrap();
        assert_eq!(c.status_page_address(path).unwrap(), None);
        for public in ["0.0.0.0:8090", "192.168.10.5:8090", "[::]:8090"] {
            let e = example(|t| t.replace("127.0.0.1:8090", public))
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("`status_page.address`")
                    && e.contains(public)
                    && e.contains("allow_non_loopback"),
                "{public}: {e}"
            );
            let c = example(|t| {
                t.replace("127.0.0.1:8090", public)
                    .replace("allow_non_loopback = false", "allow_non_loopback = true")
            })
            .unwrap();
            assert!(c.status_page_address(path).unwrap().is_some());
        }
        let e = example(|t| t.replace("127.0.0.1:8090", "localhost"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("`status_page.address`") && e.contains("localhost"),
            "{e}"
        );
    }

    /// The DICOM input: off by default; on, it needs an address, an AE title
    /// of 1-16 characters and the flat field, a quiet time and an
    /// association limit in range, and readable private-class mappings of
    /// what the input reads, each refused by name.
    #[test]
    fn dicom_input_is_checked() {
        let path = Path::new("x.toml");
        let c = example(|t| t).unwrap();
        assert!(c.dicom_input(path).unwrap().is_none());
        let on = |extra: &str| {
            example(move |t| {
                let i = t.find("[dicom_input]").unwrap();
                format!("{}[dicom_input]\n{extra}\n", &t[..i])
            })
        };
        // No frame link: only with the DICOM input on.
        let e = example(|t| t.replacen("transport = \"tcp\"", "transport = \"off\"", 1))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("`frames.transport`") && e.contains("no input"),
            "{e}"
        );
        let c = example(|t| {
            let i = t.find("[dicom_input]").unwrap();
            format!(
                "{}[dicom_input]\naddress = \"127.0.0.1:11112\"\nflat_field_counts = 1.0\n",
                &t[..i]
            )
            .replacen("transport = \"tcp\"", "transport = \"off\"", 1)
        })
        .unwrap();
        assert_eq!(c.frames.transport, FrameTransport::Off);
        let c = on("address = \"127.0.0.1:11112\"\nflat_field_counts = 16000.0").unwrap();
        let d = c.dicom_input(path).unwrap().unwrap();
        assert_eq!(d.address, "127.0.0.1:11112".parse().unwrap());
        assert_eq!(d.flat_field_counts, 16000.0);
        assert_eq!(d.quiet_time.as_secs(), 120);
        assert_eq!(d.max_associations, 4);
        assert!(d.private.is_empty());
        // A private class and its mapping.
        let dir = tempfile::tempdir().unwrap();
        let mapping = dir.path().join("acme.toml");
        std::fs::write(
            &mapping,
            "name = \"ACME\"\nlayout = \"per-view\"\n[tags]\nBodyPartThickness = \"0019,1012\"\n[creators]\n\"0019,0010\" = \"ACME DBT\"\n",
        )
        .unwrap();
        let private = |file: &Path| {
            format!(
                "address = \"127.0.0.1:1\"\nflat_field_counts = 1.0\n[[dicom_input.private_class]]\nsop_class = \"1.2.826.0.1.3680043.10.543.77.1\"\nmapping = {:?}",
                file.display().to_string()
            )
        };
        let c = on(&private(&mapping)).unwrap();
        let m = &c.dicom_input(path).unwrap().unwrap().private[0];
        assert_eq!(m.layout, dbt_dicom::input::Layout::PerView);
        assert_eq!(
            m.tags["BodyPartThickness"],
            dbt_dicom::input::Tag(0x0019, 0x1012)
        );
        let bad_mapping = dir.path().join("bad.toml");
        std::fs::write(
            &bad_mapping,
            "name = \"X\"\nlayout = \"per-view\"\n[tags]\nPatientAge = \"0019,1001\"\n",
        )
        .unwrap();
        for (extra, key, says) in [
            ("address = \"127.0.0.1:11112\"".to_string(), "dicom_input.flat_field_counts", ""),
            ("address = \"nowhere\"\nflat_field_counts = 1.0".into(), "dicom_input.address", "nowhere"),
            (
                "address = \"127.0.0.1:1\"\nflat_field_counts = 1.0\nae_title = \"A_TITLE_MUCH_TOO_LONG\"".into(),
                "dicom_input.ae_title",
                "A_TITLE",
            ),
            ("address = \"127.0.0.1:1\"\nflat_field_counts = -3.0".into(), "dicom_input.flat_field_counts", "-3"),
            ("address = \"127.0.0.1:1\"\nflat_field_counts = 1.0\nquiet_time_s = 0.0".into(), "dicom_input.quiet_time_s", "0"),
            ("address = \"127.0.0.1:1\"\nflat_field_counts = 1.0\nmax_associations = 0".into(), "dicom_input.max_associations", "0"),
            (private(&dir.path().join("none.toml")), "dicom_input.private_class.mapping", "none.toml"),
            (private(&bad_mapping), "dicom_input.private_class.mapping", "PatientAge"),
        ] {
            let e = on(&extra).unwrap_err().to_string();
            assert!(e.contains(&format!("`{key}`")) && e.contains(says), "{extra}: {e}");
        }
    }

    /// Transport, reconstructor and precision are typed: a misspelt value is
    /// refused naming its key (table and key, from the parser's position)
    /// and the values it could be.
    #[test]
    fn misspelt_choices_name_the_key_and_the_choices() {
        for (from, to, key, choices) in [
            (
                "transport = \"tcp\"",
                "transport = \"tpc\"",
                "frames.transport",
                "serial",
            ),
            (
                "reconstructor = \"dbtor\"",
                "reconstructor = \"dbtr\"",
                "recon.reconstructor",
                "mltr",
            ),
            (
                "precision = \"int8\"",
                "precision = \"fp16\"",
                "recon.precision",
                "fp32",
            ),
        ] {
            let e = example(|t| t.replacen(from, to, 1))
                .unwrap_err()
                .to_string();
            let bad = to.split('"').nth(1).unwrap();
            assert!(
                e.contains(&format!("`{key}`")) && e.contains(bad) && e.contains(choices),
                "{to}: {e}"
            );
        }
        // The Modbus section's transport: its own key.
        let e = example(|t| {
            let i = t.find("[modbus]").unwrap();
            let (a, b) = t.split_at(i);
            format!(
                "{a}{}",
                b.replacen("transport = \"tcp\"", "transport = \"udp\"", 1)
            )
        })
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("`modbus.transport`") && e.contains("udp") && e.contains("rtu"),
            "{e}"
        );
        let c = example(|t| t).unwrap();
        assert_eq!(c.frames.transport, FrameTransport::Tcp);
        assert_eq!(c.recon.reconstructor, Reconstructor::Dbtor);
    }

    /// The model's signed-off digest is required with DBToR and must be a
    /// SHA-256; the frame server's address must parse, port 1-65535.
    #[test]
    fn model_digest_and_addresses_are_checked() {
        let c = example(|t| t).unwrap();
        assert!(c.recon.model_digest.unwrap().starts_with("sha256:"));
        let e = example(|t| without(&t, "model_digest"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("recon.model_digest") && e.contains("required"),
            "{e}"
        );
        let e = example(|t| {
            let d = t
                .lines()
                .find(|l| l.starts_with("model_digest"))
                .unwrap()
                .to_string();
            t.replace(&d, "model_digest = \"md5:1234\"")
        })
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("recon.model_digest") && e.contains("md5:1234"),
            "{e}"
        );
        for bad in [
            "127.0.0.1:70000",
            "::::",
            "127.0.0.1",
            "gantry:5000",
            "127.0.0.1:0",
        ] {
            let e = example(|t| t.replace("127.0.0.1:5000", bad))
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("frames.address") && e.contains(bad),
                "{bad}: {e}"
            );
        }
        let c = example(|t| t.replace("127.0.0.1:5000", "[::1]:5000")).unwrap();
        assert_eq!(c.frames.address.as_deref(), Some("[::1]:5000"));
        // The tube output every acquisition header would be refused for.
        let e = example(|t| {
            t.replace(
                "tube_output_mgy_per_mas = 0.11",
                "tube_output_mgy_per_mas = 1.5",
            )
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("report.tube_output_mgy_per_mas"), "{e}");
        assert!(example(|t| t.replace(
            "tube_output_mgy_per_mas = 0.11",
            "tube_output_mgy_per_mas = 1.0"
        ))
        .is_ok());
        // The W/Al beam's own output: optional, checked alike.
        let al = |v: &str| {
            example(|t| {
                t.replace(
                    "tube_output_w_al_mgy_per_mas = 0.11",
                    &format!("tube_output_w_al_mgy_per_mas = {v}"),
                )
            })
        };
        let c = al("0.2").unwrap();
        use dbt_dose::xray::AnodeFilter;
        let at30 = |b| c.report.tube_output(b).map(|t| t.at(30.0).unwrap());
        assert_eq!(at30(AnodeFilter::WAl), Some(0.2));
        assert_eq!(at30(AnodeFilter::WRh), Some(0.11));
        let e = al("0").unwrap_err().to_string();
        assert!(e.contains("report.tube_output_w_al_mgy_per_mas"), "{e}");
        let absent = example(|t| t.replace("tube_output_w_al_mgy_per_mas = 0.11\n", "")).unwrap();
        assert_eq!(absent.report.tube_output(AnodeFilter::WAl), None);
        // Every other beam's key is the one its messages name, and sets
        // that beam's output only.
        for beam in AnodeFilter::ALL {
            if matches!(beam, AnodeFilter::WRh | AnodeFilter::WAl) {
                continue;
            }
            let key = ReportConfig::tube_output_key(beam);
            let field = key.trim_start_matches("report.");
            assert_eq!(absent.report.tube_output(beam), None, "{beam}");
            let c = example(|t| {
                t.replace(
                    "tube_output_w_al_mgy_per_mas = 0.11\n",
                    &format!("{field} = 0.07\n"),
                )
            })
            .unwrap();
            for other in AnodeFilter::ALL {
                let got = c.report.tube_output(other).map(|t| t.at(30.0).unwrap());
                let want = match other {
                    AnodeFilter::WRh => Some(0.11),
                    o if o == beam => Some(0.07),
                    _ => None,
                };
                assert_eq!(got, want, "{key}: {other}");
            }
            let e = example(|t| {
                t.replace(
                    "tube_output_w_al_mgy_per_mas = 0.11\n",
                    &format!("{field} = -1\n"),
                )
            })
            .unwrap_err()
            .to_string();
            assert!(e.contains(key), "{e}");
        }
        // The QC's outputs by kV: a power law between measured kV, exact at
        // them, refused outside; bad tables refused naming the key.
        let table = example(|t| {
            t.replace(
                "tube_output_mgy_per_mas = 0.11\n",
                "tube_output_mgy_per_mas = { kv = [25, 30, 35], mgy_per_mas = [0.06, 0.09, 0.12] }\n",
            )
        })
        .unwrap();
        let t = table.report.tube_output(AnodeFilter::WRh).unwrap();
        assert_eq!(t.at(25.0), Ok(0.06));
        assert_eq!(t.at(35.0), Ok(0.12));
        assert!((t.at(30.0).unwrap() - 0.09).abs() < 1e-12);
        // 0.06 (27.5/25)^(ln 1.5 / ln 1.2): between the neighbours, below
        // the straight line's 0.075 (the output is convex in kV).
        let mid = t.at(27.5).unwrap();
        let want = 0.06 * (27.5f64 / 25.0).powf(1.5f64.ln() / 1.2f64.ln());
        assert!((mid - want).abs() < 1e-12 && mid < 0.075, "{mid}");
        let e = t.at(36.0).unwrap_err();
        assert!(e.contains("36") && e.contains("25-35"), "{e}");
        assert!(t.at(24.9).is_err());
        for bad in [
            "{ kv = [30], mgy_per_mas = [0.09] }",
            "{ kv = [25, 30], mgy_per_mas = [0.06] }",
            "{ kv = [30, 25], mgy_per_mas = [0.06, 0.09] }",
            "{ kv = [25, 60], mgy_per_mas = [0.06, 0.09] }",
            "{ kv = [25, 30], mgy_per_mas = [0.06, -1] }",
            "{ kv = [25, 30], mgy = [0.06, 0.09] }",
            "{ kv = [25, 30], mgy_per_mas = [0.06, 0.09], beam = \"W/Al\" }",
            "\"0.11\"",
        ] {
            let e = example(|t| {
                t.replace(
                    "tube_output_mgy_per_mas = 0.11\n",
                    &format!("tube_output_mgy_per_mas = {bad}\n"),
                )
            })
            .unwrap_err()
            .to_string();
            assert!(e.contains("report.tube_output_mgy_per_mas"), "{bad}: {e}");
        }
        // The beam of an input that states none: the site's, or refused.
        let unstated = |v: &str| {
            example(|t| {
                t.replace(
                    "unstated_beam = \"W/Rh\"",
                    &format!("unstated_beam = {v:?}"),
                )
            })
        };
        assert_eq!(c.report.unstated_beam(), Some(AnodeFilter::WRh));
        assert_eq!(
            unstated("W/Al").unwrap().report.unstated_beam(),
            Some(AnodeFilter::WAl)
        );
        assert_eq!(unstated("refuse").unwrap().report.unstated_beam(), None);
        let e = unstated("W/Ag").unwrap_err().to_string();
        assert!(
            e.contains("report.unstated_beam")
                && e.contains("W/Ag")
                && e.contains("report.tube_output_w_ag_mgy_per_mas"),
            "{e}"
        );
        let e = example(|t| {
            t.replace("tube_output_w_al_mgy_per_mas = 0.11\n", "")
                .replace("unstated_beam = \"W/Rh\"", "unstated_beam = \"W/Al\"")
        })
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("report.unstated_beam") && e.contains("tube output"),
            "{e}"
        );
    }

    /// fp32 blocks are an int8 option: listed with fp32 they are refused,
    /// naming the key; with int8 they are kept.
    #[test]
    fn fp32_blocks_need_int8() {
        let list = "fp32_blocks = [\"primal08\", \"primal09\"]";
        let e = example(|t| {
            t.replace("fp32_blocks = []", list)
                .replace("precision = \"int8\"", "precision = \"fp32\"")
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("recon.fp32_blocks") && e.contains("int8"), "{e}");
        let c = example(|t| t.replace("fp32_blocks = []", list)).unwrap();
        assert_eq!(c.recon.fp32_blocks, ["primal08", "primal09"]);
        assert!(example(|t| t).unwrap().recon.fp32_blocks.is_empty());
    }

    /// The gantry geometry: a built-in name or a file (relative to the
    /// configuration's folder); anything else is refused naming the key.
    #[test]
    fn gantry_geometry_by_name_or_file() {
        let c = example(|t| t).unwrap();
        let p = Path::new("dbtor.toml");
        assert_eq!(c.frames.geometry, "paper-tall");
        assert_eq!(c.gantry_geometry(p).unwrap().image.rows, 100);
        // With MLTR and the slice-wise stream, any geometry goes (a DBToR
        // model must match it: below; a cone-beam system too: its test).
        let mltr = |t: &str| {
            without(t, "system").replace("reconstructor = \"dbtor\"", "reconstructor = \"mltr\"")
        };
        let c = example(|t| mltr(&t).replace("geometry = \"paper-tall\"", "geometry = \"paper\""))
            .unwrap();
        assert_eq!(
            c.gantry_geometry(p).unwrap(),
            Geometry::paper().binned(4).unwrap()
        );
        // Absent: the paper's.
        let c = example(|t| without(&mltr(&t), "geometry")).unwrap();
        assert_eq!(c.frames.geometry, "paper");
        let e = example(|t| t.replace("\"paper-tall\"", "\"tall\""))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("frames.geometry") && e.contains("tall") && e.contains("paper-tall"),
            "{e}"
        );
        // The model must be trained for the configured geometry.
        let e = example(|t| without(&t, "system").replace("\"paper-tall\"", "\"paper\""))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("recon.model") && e.contains("250x100") && e.contains("250x75"),
            "{e}"
        );
        // A relative file is read from the configuration's folder.
        let c = example(|t| t.replace("\"paper-tall\"", "\"no-such.toml\""));
        let e = c.unwrap_err().to_string();
        assert!(
            e.contains("frames.geometry") && e.contains("no-such.toml"),
            "{e}"
        );
    }

    /// The beam-hardening correction: off as shipped, a CsI detector's on
    /// request; an impossible scintillator is refused naming the key.
    #[test]
    fn beam_hardening_is_configured() {
        let c = example(|t| t).unwrap();
        assert_eq!(c.linearise(), None);
        let c =
            example(|t| t.replace("beam_hardening = \"off\"", "beam_hardening = \"csi\"")).unwrap();
        assert_eq!(
            c.linearise().unwrap().detector.converter,
            dbt_materials::Converter::default()
        );
        let e = example(|t| {
            t.replace("beam_hardening = \"off\"", "beam_hardening = \"csi\"")
                .replace("converter_um = 200.0", "converter_um = 5.0")
        })
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("recon.converter_um") && e.contains("5 um"),
            "{e}"
        );
        // The key's former name still reads (no cone-beam system here: the
        // shipped one's converter is 200 um of CsI).
        let c = example(|t| {
            without(&t, "system")
                .replace("beam_hardening = \"off\"", "beam_hardening = \"a-se\"")
                .replace("converter_um = 200.0", "csi_um = 250.0")
        })
        .unwrap();
        let d = c.linearise().unwrap().detector.converter;
        assert_eq!(d.material, dbt_materials::ConverterMaterial::ASe);
        assert_eq!(d.thickness_um, 250.0);
        let e = example(|t| t.replace("beam_hardening = \"off\"", "beam_hardening = \"selenium\""))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("beam_hardening") && e.contains("selenium"),
            "{e}"
        );
    }

    /// Noise matching: off as shipped; `training-level` with both
    /// corrections and DBToR; without them, or another word, refused
    /// naming the key.
    #[test]
    fn noise_matching_is_configured() {
        let c = example(|t| t).unwrap();
        assert_eq!(c.recon.noise_match, NoiseMatchMode::Off);
        assert!(!c.input_corrections().noise_matched);
        let on = |t: String| {
            t.replace("beam_hardening = \"off\"", "beam_hardening = \"csi\"")
                .replace("scatter = \"off\"", "scatter = \"kernel\"")
                .replace("noise_match = \"off\"", "noise_match = \"training-level\"")
        };
        let c = example(on).unwrap();
        assert_eq!(c.recon.noise_match, NoiseMatchMode::TrainingLevel);
        assert!(c.input_corrections().noise_matched);
        let e = example(|t| t.replace("noise_match = \"off\"", "noise_match = \"training-level\""))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("recon.noise_match") && e.contains("beam_hardening"),
            "{e}"
        );
        // Without the scatter removal: refused too (never measured).
        let e = example(|t| on(t).replace("scatter = \"kernel\"", "scatter = \"off\""))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("recon.noise_match") && e.contains("scatter"),
            "{e}"
        );
        let e = example(|t| on(t).replace("reconstructor = \"dbtor\"", "reconstructor = \"mltr\""))
            .unwrap_err()
            .to_string();
        assert!(e.contains("recon.noise_match"), "{e}");
        let e = example(|t| t.replace("noise_match = \"off\"", "noise_match = \"n8\""))
            .unwrap_err()
            .to_string();
        assert!(e.contains("noise_match") && e.contains("n8"), "{e}");
    }

    /// The scatter removal: off as shipped, the kernel model on request;
    /// another word is refused naming the key.
    #[test]
    fn scatter_removal_is_configured() {
        let p = Path::new("dbtor.toml");
        let c = example(|t| t).unwrap();
        assert_eq!(c.descatter(p).unwrap(), None);
        let c = example(|t| t.replace("scatter = \"off\"", "scatter = \"kernel\"")).unwrap();
        let r = c.descatter(p).unwrap().unwrap();
        for af in dbt_dose::xray::AnodeFilter::ALL {
            assert_eq!(r.table(af).range_mm(), (20.0, 90.0));
        }
        let e = example(|t| t.replace("scatter = \"off\"", "scatter = \"grid\""))
            .unwrap_err()
            .to_string();
        assert!(e.contains("scatter") && e.contains("grid"), "{e}");
    }

    /// The calibration key follows the configured corrections: the shipped
    /// (uncorrected) inputs read `int8`, both corrections `int8 | scatter
    /// removed + linearised`, one alone its own key.
    #[test]
    fn the_calibration_key_follows_the_corrections() {
        let key =
            |f: &dyn Fn(String) -> String| example(f).unwrap().input_corrections().key("int8");
        assert_eq!(key(&|t| t), "int8");
        let both = |t: String| {
            t.replace("scatter = \"off\"", "scatter = \"kernel\"")
                .replace("beam_hardening = \"off\"", "beam_hardening = \"csi\"")
        };
        assert_eq!(key(&both), "int8 | scatter removed + linearised");
        assert_eq!(
            key(&|t| both(t).replace("noise_match = \"off\"", "noise_match = \"training-level\"")),
            "int8 | scatter removed + linearised + noise matched"
        );
        assert_eq!(
            key(&|t| t.replace("beam_hardening = \"off\"", "beam_hardening = \"csi\"")),
            "int8 | linearised"
        );
    }

    /// `recon.slice_step`: 1 in the shipped file and when absent, 2..8
    /// taken, 0 and 9 refused naming the key and the value.
    #[test]
    fn the_slice_step_is_checked() {
        let step = |f: &dyn Fn(String) -> String| example(f).map(|c| c.recon.slice_step);
        assert_eq!(step(&|t| t).unwrap(), 1);
        assert_eq!(step(&|t| without(&t, "slice_step")).unwrap(), 1);
        assert_eq!(
            step(&|t| t.replace("slice_step = 1 ", "slice_step = 8 ")).unwrap(),
            8
        );
        for bad in ["0", "9"] {
            let e = step(&|t| t.replace("slice_step = 1 ", &format!("slice_step = {bad} ")))
                .unwrap_err()
                .to_string();
            assert!(e.contains("recon.slice_step") && e.contains(bad), "{e}");
        }
    }

    /// `recon.uncalibrated_beam`: physics-only in the shipped file and
    /// when absent, `refuse` taken, another value refused naming it.
    #[test]
    fn an_uncalibrated_beam_is_reported_physics_only_unless_refused() {
        let mode = |f: &dyn Fn(String) -> String| example(f).map(|c| c.recon.uncalibrated_beam);
        let shipped = "uncalibrated_beam = \"physics\"";
        assert_eq!(mode(&|t| t).unwrap(), UncalibratedBeamMode::Physics);
        assert_eq!(
            mode(&|t| without(&t, "uncalibrated_beam")).unwrap(),
            UncalibratedBeamMode::Physics
        );
        let refuse = mode(&|t| t.replace(shipped, "uncalibrated_beam = \"refuse\"")).unwrap();
        assert_eq!(refuse, UncalibratedBeamMode::Refuse);
        assert_eq!(refuse.pipeline(), dbt_pipeline::UncalibratedBeam::Refuse);
        assert_eq!(
            UncalibratedBeamMode::Physics.pipeline(),
            dbt_pipeline::UncalibratedBeam::PhysicsOnly
        );
        let e = mode(&|t| t.replace(shipped, "uncalibrated_beam = \"w/rh\""))
            .unwrap_err()
            .to_string();
        assert!(e.contains("w/rh") && e.contains("uncalibrated_beam"), "{e}");
    }

    /// With a cone-beam system, the linearisation must be for its
    /// converter (its file's, else 200 um of CsI): Hologic's a-Se taken,
    /// CsI (or a-Se of another thickness) refused naming the key, the
    /// system and both converters.
    #[test]
    fn the_linearisation_is_for_the_system_s_converter() {
        let on = |name: &str, mode: &str, um: &str| {
            example(|t| {
                physics(&t)
                    .replace("\"paper-cone\"", &format!("{name:?}"))
                    .replace(
                        "beam_hardening = \"off\"",
                        &format!("beam_hardening = {mode:?}"),
                    )
                    .replace("converter_um = 200.0", &format!("converter_um = {um}"))
            })
        };
        let c = on("hologic-dimensions", "a-se", "200.0").unwrap();
        let d = c.linearise().unwrap().detector.converter;
        assert_eq!(d.material, dbt_materials::ConverterMaterial::ASe);
        for (mode, um) in [("csi", "200.0"), ("a-se", "250.0")] {
            let e = on("hologic-dimensions", mode, um).unwrap_err().to_string();
            assert!(
                e.contains("recon.beam_hardening")
                    && e.contains("hologic-dimensions")
                    && e.contains("200 um a-Se"),
                "{e}"
            );
        }
        assert!(on("ge-essential", "a-se", "200.0").is_err());
        assert!(on("ge-essential", "csi", "200.0").is_ok());
        // The paper's system states none: 200 um of CsI, as simulated.
        assert!(on("paper-cone", "csi", "200.0").is_ok());
        assert!(on("paper-cone", "csi", "150.0").is_err());
        assert!(on("paper-cone", "a-se", "200.0").is_err());
    }

    /// The cone-beam system: the shipped one, none (the slice-wise stream),
    /// a file relative to the configuration; a system whose rebinning fan
    /// is not the geometry, or an unknown one, is refused naming the key.
    #[test]
    fn gantry_system_by_name_or_file() {
        let p = Path::new("dbtor.toml");
        let c = example(|t| t).unwrap();
        let s = c.gantry_system(p).unwrap().unwrap();
        assert_eq!((s.name.as_str(), s.detector.columns), ("paper-cone", 320));
        assert_eq!(c.gantry(p).unwrap().cone, Some(s));
        let c = example(|t| without(&t, "system")).unwrap();
        assert_eq!(c.gantry_system(p).unwrap(), None);
        // The stationary system's fan has another source radius and views:
        // the model is not trained for it (and the physics-only report is
        // offered).
        let e = example(|t| t.replace("\"paper-cone\"", "\"siemens-victre\""))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("recon.model")
                && e.contains("siemens-victre")
                && e.contains("[-25, 25]")
                && e.contains("reconstructor = \"physics\""),
            "{e}"
        );
        // Without a model, every built-in system has its fan on the
        // geometry (Hologic's pivot and GE's axis included).
        for (name, _) in dbt_geometry::cone::BUILTIN_SYSTEMS {
            let c =
                example(|t| physics(&t).replace("\"paper-cone\"", &format!("{name:?}"))).unwrap();
            let (g, sys) = (
                c.gantry_geometry(p).unwrap(),
                c.gantry_system(p).unwrap().unwrap(),
            );
            dbt_pipeline::rebin::check_site(&sys, &g).unwrap();
        }
        // A model named with the physics-only reconstructor is refused.
        let e = example(|t| t.replace("reconstructor = \"dbtor\"", "reconstructor = \"physics\""))
            .unwrap_err()
            .to_string();
        assert!(e.contains("recon.model") && e.contains("not used"), "{e}");
        let e = example(|t| t.replace("\"paper-cone\"", "\"paper-cone-2\""))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("frames.system")
                && e.contains("paper-cone-2")
                && e.contains("paper-cone, siemens-victre"),
            "{e}"
        );
        // A file beside the configuration (its own name travels in the
        // stream's header).
        let t = tempfile::tempdir().unwrap();
        std::fs::write(
            t.path().join("site.toml"),
            dbt_geometry::cone::PAPER_CONE_TOML
                .replace("name = \"paper-cone\"", "name = \"site-7\""),
        )
        .unwrap();
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let text = std::fs::read_to_string(root.join("config/dbtor.toml"))
            .unwrap()
            .replace("\"paper-cone\"", "\"site.toml\"");
        let shipped: toml::Value = toml::from_str(&text).unwrap();
        let installed = shipped["recon"]["model"].as_str().unwrap().to_string();
        let model = root
            .join("../models")
            .join(Path::new(&installed).file_name().unwrap());
        let text = text.replace(
            &format!("{installed:?}"),
            &format!("{:?}", model.display().to_string()),
        );
        let cfg = t.path().join("dbtor.toml");
        std::fs::write(&cfg, text).unwrap();
        let c = Config::load(&cfg).unwrap();
        assert_eq!(c.gantry_system(&cfg).unwrap().unwrap().name, "site-7");
    }
}
