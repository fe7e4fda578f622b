//! File adapters at the edge of the domain crates:
//! * [`load_external_phantom`]: a raw label volume (optionally gzip) and its
//!   TOML sidecar, decoded by `dbt_phantom::ExternalSidecar`;
//! * [`dataset`]: the memory-mappable training dataset (see `DATASET.md`).

pub mod acquisition;
pub mod dataset;
pub mod operator;

use dbt_geometry::{ConeSystem, Geometry, BUILTIN_GEOMETRIES};
use dbt_phantom::{ExternalSidecar, LabelVolume, PhantomError};
use std::io::Read;
use std::path::{Path, PathBuf};
use thiserror::Error;

/// Errors of the file adapters; each names the file.
#[derive(Debug, Error)]
pub enum StoreError {
    /// Reading or writing a file failed.
    #[error("{path}: {cause}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        cause: std::io::Error,
    },
    /// The content is not what the format says.
    #[error("{path}: {reason}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A phantom decoding error.
    #[error("{path}: {cause}")]
    Phantom {
        /// The sidecar.
        path: PathBuf,
        /// The decoding error.
        cause: PhantomError,
    },
}

pub(crate) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> StoreError + '_ {
    move |source| StoreError::Io {
        path: path.to_path_buf(),
        cause: source,
    }
}

/// Read a whole file, gunzipping it when its name ends in `.gz`.
pub fn read_maybe_gz(path: &Path) -> Result<Vec<u8>, StoreError> {
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    if path.extension().is_some_and(|e| e == "gz") {
        let mut out = Vec::new();
        flate2::read::GzDecoder::new(&bytes[..])
            .read_to_end(&mut out)
            .map_err(|e| StoreError::Format {
                path: path.to_path_buf(),
                reason: format!("not a valid gzip stream: {e}"),
            })?;
        Ok(out)
    } else {
        Ok(bytes)
    }
}

/// The text of a built-in named `spec`, or of the file `spec`; a missing
/// file that is no built-in name is refused naming the built-ins (`what`:
/// "geometry", "cone-beam system").
fn builtin_or_file(
    spec: &str,
    builtins: &[(&str, &str)],
    what: &str,
) -> Result<String, StoreError> {
    if let Some((_, text)) = builtins.iter().find(|(n, _)| *n == spec) {
        return Ok(text.to_string());
    }
    let path = Path::new(spec);
    std::fs::read_to_string(path).map_err(|source| {
        if source.kind() == std::io::ErrorKind::NotFound {
            let names: Vec<&str> = builtins.iter().map(|(n, _)| *n).collect();
            StoreError::Format {
                path: path.to_path_buf(),
                reason: format!(
                    "no such {what} file, and not a built-in {what} ({})",
                    names.join(", ")
                ),
            }
        } else {
            StoreError::Io {
                path: path.to_path_buf(),
                cause: source,
            }
        }
    })
}

/// A geometry named on a command line or in a configuration file: a
/// built-in name (`paper`, `paper-tall`, `paper-104`: [`dbt_geometry::BUILTIN_GEOMETRIES`])
/// or the path of a geometry TOML; then binned by `binning`.
pub fn load_geometry(spec: &str, binning: usize) -> Result<Geometry, StoreError> {
    let format = |reason: String| StoreError::Format {
        path: PathBuf::from(spec),
        reason,
    };
    let text = builtin_or_file(spec, &BUILTIN_GEOMETRIES, "geometry")?;
    let g = Geometry::from_toml_str(&text).map_err(|e| format(e.to_string()))?;
    g.binned(binning)
        .map_err(|e| format(format!("binning {binning}: {e}")))
}

/// A cone-beam system named on a command line or in a configuration file:
/// a built-in name (`paper-cone`, `siemens-victre`:
/// [`dbt_geometry::cone::BUILTIN_SYSTEMS`]) or the path of a system TOML;
/// then binned by `binning` (elements `binning` times larger).
pub fn load_system(spec: &str, binning: usize) -> Result<ConeSystem, StoreError> {
    let format = |reason: String| StoreError::Format {
        path: PathBuf::from(spec),
        reason,
    };
    let text = builtin_or_file(
        spec,
        &dbt_geometry::cone::BUILTIN_SYSTEMS,
        "cone-beam system",
    )?;
    let s = ConeSystem::from_toml_str(&text).map_err(|e| format(e.to_string()))?;
    s.binned(binning)
        .map_err(|e| format(format!("binning {binning}: {e}")))
}

/// Load an external phantom from its sidecar (the raw file is resolved
/// relative to the sidecar's folder).
pub fn load_external_phantom(sidecar: &Path) -> Result<LabelVolume, StoreError> {
    let text = std::fs::read_to_string(sidecar).map_err(io_err(sidecar))?;
    let phantom_err = |source| StoreError::Phantom {
        path: sidecar.to_path_buf(),
        cause: source,
    };
    let sc = ExternalSidecar::from_toml_str(&text).map_err(phantom_err)?;
    let raw_path = sidecar.parent().unwrap_or(Path::new(".")).join(&sc.raw);
    let raw = read_maybe_gz(&raw_path)?;
    sc.decode(&raw).map_err(|source| StoreError::Phantom {
        path: raw_path.clone(),
        cause: source,
    })
}

/// Write a label volume as raw bytes plus a sidecar that
/// [`load_external_phantom`] reads back (our own label codes, our axis order).
pub fn save_phantom(vol: &LabelVolume, sidecar: &Path) -> Result<(), StoreError> {
    let stem = sidecar
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "phantom".into());
    let raw_name = format!("{stem}.raw");
    let raw_path = sidecar.parent().unwrap_or(Path::new(".")).join(&raw_name);
    std::fs::write(&raw_path, vol.labels()).map_err(io_err(&raw_path))?;
    let [nx, nz, ny] = vol.dims();
    let mut text = format!(
        "# Label volume written by dbt-store (labels are dbt-materials codes).\n\
         raw = \"{raw_name}\"\ndims = [{nx}, {nz}, {ny}]\n\
         axes = [\"lateral\", \"vertical\", \"depth\"]\nvoxel_mm = {}\n[labels]\n",
        vol.voxel_mm()
    );
    for t in dbt_materials::Tissue::ALL {
        text.push_str(&format!("{} = \"{}\"\n", t.label(), t.name()));
    }
    std::fs::write(sidecar, text).map_err(io_err(sidecar))
}

#[cfg(test)]
mod tests {
    use super::*;
    use dbt_phantom::{generate, PhantomSpec};
    use std::io::Write;

    #[test]
    fn generated_phantom_round_trips_through_files_and_gzip() {
        let dir = tempfile::tempdir().unwrap();
        let spec = PhantomSpec {
            thickness_mm: 30.0,
            chest_to_nipple_mm: 40.0,
            width_mm: 70.0,
            ..PhantomSpec::typical(1.0, 3)
        };
        let vol = generate(&spec).unwrap();
        let sc = dir.path().join("p.toml");
        save_phantom(&vol, &sc).unwrap();
        assert_eq!(
            load_external_phantom(&sc).unwrap(),
            vol.cropped_to_tissue().unwrap()
        );
        // gzip the raw and point the sidecar at it.
        let raw = std::fs::read(dir.path().join("p.raw")).unwrap();
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        gz.write_all(&raw).unwrap();
        std::fs::write(dir.path().join("p.raw.gz"), gz.finish().unwrap()).unwrap();
        let text = std::fs::read_to_string(&sc)
            .unwrap()
            .replace("p.raw\"", "p.raw.gz\"");
        std::fs::write(&sc, text).unwrap();
        assert_eq!(
            load_external_phantom(&sc).unwrap(),
            vol.cropped_to_tissue().unwrap()
        );
    }

    #[test]
    fn bad_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let sc = dir.path().join("s.toml");
        // Missing sidecar.
        let e = load_external_phantom(&sc).unwrap_err().to_string();
        assert!(e.contains("s.toml"), "{e}");
        // Sidecar fine, raw missing.
        std::fs::write(
            &sc,
            "raw = \"r.raw\"\ndims = [2, 2, 2]\naxes = [\"lateral\", \"vertical\", \"depth\"]\nvoxel_mm = 1.0\n[labels]\n0 = \"air\"\n1 = \"adipose\"\n",
        )
        .unwrap();
        let e = load_external_phantom(&sc).unwrap_err().to_string();
        assert!(e.contains("r.raw"), "{e}");
        // Raw too short.
        std::fs::write(dir.path().join("r.raw"), [1u8; 7]).unwrap();
        let e = load_external_phantom(&sc).unwrap_err().to_string();
        assert!(e.contains("7 bytes") && e.contains("need 8"), "{e}");
        // Unmapped label.
        std::fs::write(dir.path().join("r.raw"), [1, 1, 1, 1, 1, 29, 1, 1]).unwrap();
        let e = load_external_phantom(&sc).unwrap_err().to_string();
        assert!(e.contains("label 29") && e.contains("[1, 0, 1]"), "{e}");
        // Corrupt gzip.
        std::fs::write(dir.path().join("r.raw.gz"), b"not gzip").unwrap();
        std::fs::write(
            &sc,
            std::fs::read_to_string(&sc)
                .unwrap()
                .replace("r.raw\"", "r.raw.gz\""),
        )
        .unwrap();
        let e = load_external_phantom(&sc).unwrap_err().to_string();
        assert!(e.contains("gzip"), "{e}");
    }

    #[test]
    fn geometry_by_name_or_file() {
        let tall = load_geometry("paper-tall", 4).unwrap();
        assert_eq!((tall.image.rows, tall.n_det()), (100, 320));
        assert_eq!(load_geometry("paper", 1).unwrap(), Geometry::paper());
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("g.toml");
        std::fs::write(&f, Geometry::paper().binned(2).unwrap().to_toml_string()).unwrap();
        let s = f.to_str().unwrap();
        assert_eq!(
            load_geometry(s, 1).unwrap(),
            Geometry::paper().binned(2).unwrap()
        );
        // A binning that does not divide the file's sizes names it.
        let e = load_geometry(s, 7).unwrap_err().to_string();
        assert!(e.contains("binning 7") && e.contains("g.toml"), "{e}");
        // Neither a file nor a built-in name: both are said.
        let e = load_geometry("paper_tall", 4).unwrap_err().to_string();
        assert!(
            e.contains("paper_tall") && e.contains("paper, paper-tall"),
            "{e}"
        );
        // A file that is not a geometry.
        std::fs::write(&f, "rows = 3").unwrap();
        let e = load_geometry(s, 1).unwrap_err().to_string();
        assert!(e.contains("g.toml"), "{e}");
    }

    #[test]
    fn system_by_name_or_file() {
        let p = load_system("paper-cone", 4).unwrap();
        assert_eq!((p.detector.rows, p.detector.columns), (250, 320));
        assert!((p.detector.pitch_mm - 0.8).abs() < 1e-12);
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("s.toml");
        std::fs::write(&f, dbt_geometry::cone::SIEMENS_VICTRE_TOML).unwrap();
        let s = f.to_str().unwrap();
        assert_eq!(
            load_system(s, 1).unwrap(),
            ConeSystem::builtin("siemens-victre").unwrap()
        );
        let e = load_system(s, 0).unwrap_err().to_string();
        assert!(e.contains("binning 0") && e.contains("s.toml"), "{e}");
        let e = load_system("paper_cone", 4).unwrap_err().to_string();
        assert!(
            e.contains("paper_cone") && e.contains("paper-cone, siemens-victre"),
            "{e}"
        );
        // A fan geometry is not a system.
        std::fs::write(&f, dbt_geometry::PAPER_TOML).unwrap();
        let e = load_system(s, 1).unwrap_err().to_string();
        assert!(e.contains("s.toml"), "{e}");
    }

    #[test]
    fn victre_phantom_when_present() {
        // The shipped sidecar must parse; the volume itself is loaded only when
        // the shared folder sits beside the repository (it is not in the repo).
        let sc = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../phantoms/victre-pc1.toml");
        let text = std::fs::read_to_string(&sc).unwrap();
        ExternalSidecar::from_toml_str(&text).unwrap();
        let parsed = ExternalSidecar::from_toml_str(&text).unwrap();
        let raw = sc.parent().unwrap().join(&parsed.raw);
        if !raw.exists() {
            eprintln!("skipping the VICTRE volume: {} not present", raw.display());
            return;
        }
        let vol = load_external_phantom(&sc).unwrap();
        // Paddle voxels are air and cropped away: the breast is about 50 mm.
        let t = vol.thickness_mm();
        assert!((45.0..55.0).contains(&t), "thickness {t}");
        let g = vol.glandularity().unwrap();
        // Label 29 alone gives 0.49 by mass (shared README); ducts, TDLUs,
        // vessels and ligaments add a little.
        assert!((0.49..0.53).contains(&g), "glandularity {g}");
    }
}
