//! The training dataset: plain little-endian arrays that `memmap2` (Rust) and
//! `numpy.memmap` (Python) map directly, described by `manifest.json`.
//!
//! ```text
//! DIR/manifest.json                 format, geometry, noise levels, splits
//! DIR/<split>/images.f32            [n, rows, cols]   attenuation at 20 keV, 1/mm
//! DIR/<split>/labels.u8             [n, rows, cols]   tissue codes (dbt-materials)
//! DIR/<split>/masks.u8              [n, rows, cols]   thickness mask, 0/1
//! DIR/<split>/sino-<level>.f32      [n, views, elements]  ln(b / max(y, 0.5))
//! ```
//! Arrays are C order, no header; `manifest.json` gives each file's dtype (numpy
//! notation) and shape. A split holds whole phantoms only. The writer streams
//! records to disk, so a dataset may be larger than memory.

use crate::{io_err, StoreError};
use dbt_geometry::Geometry;
use memmap2::Mmap;
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Format tag in the manifest.
pub const FORMAT: &str = "dbtor-dataset/1";

/// A noise level of the dataset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NoiseEntry {
    /// `noise-free`, `N4`, ...
    pub name: String,
    /// Photons per ray `b`.
    pub flux: f64,
}

/// One phantom of a split.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhantomEntry {
    /// Index in the population that drew it.
    pub index: u64,
    /// Ground-truth glandularity by mass of the whole phantom.
    pub glandularity: f64,
    /// Compressed thickness, mm.
    pub thickness_mm: f64,
    /// The generator parameters (free-form JSON).
    pub spec: serde_json::Value,
    /// First slice of this phantom in the split.
    pub first_slice: usize,
    /// Number of slices.
    pub slices: usize,
}

/// One slice of a split.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SliceEntry {
    /// Position of its phantom in the split's `phantoms`.
    pub phantom: usize,
    /// Coronal index (depth from the chest wall, in voxels).
    pub depth: usize,
    /// Reported compressed thickness, mm (the mask's height).
    pub thickness_mm: f64,
}

/// One array file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ArrayEntry {
    /// Array name (`images`, `sino-N8`, ...).
    pub name: String,
    /// File, relative to the split folder.
    pub file: String,
    /// numpy dtype string (`<f4`, `|u1`).
    pub dtype: String,
    /// C-order shape.
    pub shape: Vec<usize>,
}

/// A split (train, validation, test).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SplitManifest {
    /// `train`, `validation` or `test`.
    pub name: String,
    /// Phantoms, whole.
    pub phantoms: Vec<PhantomEntry>,
    /// Slices in file order.
    pub slices: Vec<SliceEntry>,
    /// The array files.
    pub arrays: Vec<ArrayEntry>,
}

/// The dataset manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// [`FORMAT`].
    pub format: String,
    /// The acquisition geometry (image and sinogram shapes follow from it).
    pub geometry: Geometry,
    /// Noise levels, one sinogram array each.
    pub noise_levels: Vec<NoiseEntry>,
    /// Documentation of the encodings (units, log transform, mask, labels).
    pub encoding: serde_json::Value,
    /// How the data were made (population, seeds, command).
    pub provenance: serde_json::Value,
    /// The splits.
    pub splits: Vec<SplitManifest>,
}

/// One slice to write.
pub struct Record<'a> {
    /// Where it comes from.
    pub entry: SliceEntry,
    /// Attenuation image, 1/mm.
    pub image: &'a [f32],
    /// Labels.
    pub labels: &'a [u8],
    /// Thickness mask, 0/1.
    pub mask: &'a [u8],
    /// One log-transformed sinogram per noise level, in manifest order.
    pub sinograms: Vec<&'a [f32]>,
}

struct SplitWriter {
    dir: PathBuf,
    manifest: SplitManifest,
    files: Vec<(PathBuf, BufWriter<File>)>,
}

/// Streams a dataset to disk.
pub struct DatasetWriter {
    root: PathBuf,
    manifest: Manifest,
    splits: Vec<SplitWriter>,
}

/// The `<f4` encoding of the dataset's float arrays.
pub fn le_f32(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

impl DatasetWriter {
    /// Create `root` (which must not hold a dataset yet) with the given splits.
    pub fn create(
        root: &Path,
        geometry: Geometry,
        noise_levels: Vec<NoiseEntry>,
        encoding: serde_json::Value,
        provenance: serde_json::Value,
        split_names: &[&str],
    ) -> Result<Self, StoreError> {
        if root.join("manifest.json").exists() {
            return Err(StoreError::Format {
                path: root.to_path_buf(),
                reason: "already holds a dataset (manifest.json); choose an empty folder".into(),
            });
        }
        let mut splits = Vec::new();
        for name in split_names {
            let dir = root.join(name);
            std::fs::create_dir_all(&dir).map_err(io_err(&dir))?;
            let mut names = vec![
                ("images".to_string(), "images.f32".to_string()),
                ("labels".into(), "labels.u8".into()),
                ("masks".into(), "masks.u8".into()),
            ];
            for n in &noise_levels {
                names.push((format!("sino-{}", n.name), format!("sino-{}.f32", n.name)));
            }
            let mut files = Vec::new();
            let mut arrays = Vec::new();
            for (aname, file) in names {
                let path = dir.join(&file);
                let f = File::create(&path).map_err(io_err(&path))?;
                files.push((path, BufWriter::with_capacity(1 << 20, f)));
                let dtype = if file.ends_with(".u8") { "|u1" } else { "<f4" };
                arrays.push(ArrayEntry {
                    name: aname,
                    file,
                    dtype: dtype.into(),
                    shape: vec![],
                });
            }
            splits.push(SplitWriter {
                dir,
                manifest: SplitManifest {
                    name: name.to_string(),
                    phantoms: vec![],
                    slices: vec![],
                    arrays,
                },
                files,
            });
        }
        Ok(Self {
            root: root.to_path_buf(),
            manifest: Manifest {
                format: FORMAT.into(),
                geometry,
                noise_levels,
                encoding,
                provenance,
                splits: vec![],
            },
            splits,
        })
    }

    fn split_mut(&mut self, split: &str) -> Result<&mut SplitWriter, StoreError> {
        let root = self.root.clone();
        self.splits
            .iter_mut()
            .find(|s| s.manifest.name == split)
            .ok_or_else(|| StoreError::Format {
                path: root,
                reason: format!("no split named `{split}`"),
            })
    }

    /// Append one phantom and all its slices to a split.
    pub fn push_phantom(
        &mut self,
        split: &str,
        mut phantom: PhantomEntry,
        records: &[Record<'_>],
    ) -> Result<(), StoreError> {
        let g = self.manifest.geometry.clone();
        let n_levels = self.manifest.noise_levels.len();
        let sw = self.split_mut(split)?;
        phantom.first_slice = sw.manifest.slices.len();
        phantom.slices = records.len();
        let pidx = sw.manifest.phantoms.len();
        for r in records {
            let bad = |what: &str, got: usize, want: usize| StoreError::Format {
                path: sw.dir.clone(),
                reason: format!("record {what} has {got} values, geometry needs {want}"),
            };
            if r.image.len() != g.n_pixels() {
                return Err(bad("image", r.image.len(), g.n_pixels()));
            }
            if r.labels.len() != g.n_pixels() {
                return Err(bad("labels", r.labels.len(), g.n_pixels()));
            }
            if r.mask.len() != g.n_pixels() {
                return Err(bad("mask", r.mask.len(), g.n_pixels()));
            }
            if r.sinograms.len() != n_levels {
                return Err(bad("sinogram count", r.sinograms.len(), n_levels));
            }
            for s in &r.sinograms {
                if s.len() != g.n_rays() {
                    return Err(bad("sinogram", s.len(), g.n_rays()));
                }
            }
            let mut chunks: Vec<Vec<u8>> =
                vec![le_f32(r.image), r.labels.to_vec(), r.mask.to_vec()];
            chunks.extend(r.sinograms.iter().map(|s| le_f32(s)));
            for ((path, f), bytes) in sw.files.iter_mut().zip(chunks) {
                f.write_all(&bytes).map_err(io_err(path))?;
            }
            let mut e = r.entry.clone();
            e.phantom = pidx;
            sw.manifest.slices.push(e);
        }
        sw.manifest.phantoms.push(phantom);
        Ok(())
    }

    /// Flush every file and write `manifest.json`; returns the manifest.
    pub fn finish(mut self) -> Result<Manifest, StoreError> {
        let g = &self.manifest.geometry;
        for mut sw in self.splits {
            let n = sw.manifest.slices.len();
            for (a, (path, f)) in sw.manifest.arrays.iter_mut().zip(sw.files.iter_mut()) {
                f.flush().map_err(io_err(path))?;
                a.shape = if a.name.starts_with("sino-") {
                    vec![n, g.n_views(), g.n_det()]
                } else {
                    vec![n, g.image.rows, g.image.columns]
                };
            }
            self.manifest.splits.push(sw.manifest);
        }
        let path = self.root.join("manifest.json");
        let text =
            serde_json::to_string_pretty(&self.manifest).map_err(|e| StoreError::Format {
                path: path.clone(),
                reason: e.to_string(),
            })?;
        std::fs::write(&path, text).map_err(io_err(&path))?;
        Ok(self.manifest)
    }
}

/// A dataset opened for reading; arrays are memory-mapped.
pub struct Dataset {
    root: PathBuf,
    manifest: Manifest,
}

/// One memory-mapped array.
pub struct MappedArray {
    map: Mmap,
    /// Its manifest entry.
    pub entry: ArrayEntry,
    item: usize,
}

impl MappedArray {
    /// Number of items along the first axis.
    pub fn len(&self) -> usize {
        self.entry.shape.first().copied().unwrap_or(0)
    }

    /// Whether the array holds no items.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Raw bytes of item `i`.
    pub fn bytes(&self, i: usize) -> Option<&[u8]> {
        (i < self.len()).then(|| &self.map[i * self.item..(i + 1) * self.item])
    }

    /// Item `i` decoded as little-endian `f32`.
    pub fn f32s(&self, i: usize) -> Option<Vec<f32>> {
        self.bytes(i).map(|b| {
            b.chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        })
    }
}

impl Dataset {
    /// Open the dataset in `root` and check its manifest.
    pub fn open(root: &Path) -> Result<Self, StoreError> {
        let path = root.join("manifest.json");
        let text = std::fs::read_to_string(&path).map_err(io_err(&path))?;
        let manifest: Manifest = serde_json::from_str(&text).map_err(|e| StoreError::Format {
            path: path.clone(),
            reason: e.to_string(),
        })?;
        if manifest.format != FORMAT {
            return Err(StoreError::Format {
                path,
                reason: format!("format `{}`, this reader knows `{FORMAT}`", manifest.format),
            });
        }
        Ok(Self {
            root: root.to_path_buf(),
            manifest,
        })
    }

    /// The manifest.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// Map array `name` of split `split`, checking the file size.
    pub fn array(&self, split: &str, name: &str) -> Result<MappedArray, StoreError> {
        let sm = self
            .manifest
            .splits
            .iter()
            .find(|s| s.name == split)
            .ok_or_else(|| StoreError::Format {
                path: self.root.clone(),
                reason: format!("no split `{split}`"),
            })?;
        let entry = sm
            .arrays
            .iter()
            .find(|a| a.name == name)
            .cloned()
            .ok_or_else(|| StoreError::Format {
                path: self.root.join(split),
                reason: format!("no array `{name}`"),
            })?;
        let path = self.root.join(split).join(&entry.file);
        let f = File::open(&path).map_err(io_err(&path))?;
        // SAFETY: the dataset files are written once and not modified while
        // mapped; a concurrent truncation would be a misuse outside our control.
        let map = unsafe { Mmap::map(&f) }.map_err(io_err(&path))?;
        let width = if entry.dtype == "|u1" { 1 } else { 4 };
        let item = entry.shape.iter().skip(1).product::<usize>() * width;
        let want = item * entry.shape.first().copied().unwrap_or(0);
        if map.len() != want {
            return Err(StoreError::Format {
                path,
                reason: format!("{} bytes, shape {:?} needs {want}", map.len(), entry.shape),
            });
        }
        Ok(MappedArray { map, entry, item })
    }

    /// Add (or replace) an array of a split whose file has already been
    /// written into the split's folder, and rewrite `manifest.json`. The file
    /// size is checked against the entry's shape first.
    pub fn register_array(&mut self, split: &str, entry: ArrayEntry) -> Result<(), StoreError> {
        let path = self.root.join(split).join(&entry.file);
        let width = match entry.dtype.as_str() {
            "|u1" => 1,
            "<f4" => 4,
            other => {
                return Err(StoreError::Format {
                    path,
                    reason: format!("dtype `{other}`: this writer knows `<f4` and `|u1`"),
                })
            }
        };
        let want = entry.shape.iter().product::<usize>() * width;
        let got = std::fs::metadata(&path).map_err(io_err(&path))?.len() as usize;
        if got != want {
            return Err(StoreError::Format {
                path,
                reason: format!("{got} bytes, shape {:?} needs {want}", entry.shape),
            });
        }
        let root = self.root.clone();
        let sm = self
            .manifest
            .splits
            .iter_mut()
            .find(|s| s.name == split)
            .ok_or_else(|| StoreError::Format {
                path: root.clone(),
                reason: format!("no split `{split}`"),
            })?;
        sm.arrays.retain(|a| a.name != entry.name);
        sm.arrays.push(entry);
        let mpath = root.join("manifest.json");
        let text =
            serde_json::to_string_pretty(&self.manifest).map_err(|e| StoreError::Format {
                path: mpath.clone(),
                reason: e.to_string(),
            })?;
        let tmp = root.join("manifest.json.tmp");
        std::fs::write(&tmp, text).map_err(io_err(&tmp))?;
        std::fs::rename(&tmp, &mpath).map_err(io_err(&mpath))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_errors() {
        let dir = tempfile::tempdir().unwrap();
        let mut g = Geometry::paper().binned(4).unwrap();
        g.image.rows = 20;
        g.validate().unwrap();
        let levels = vec![NoiseEntry {
            name: "N8".into(),
            flux: 16000.0,
        }];
        let mut w = DatasetWriter::create(
            dir.path(),
            g.clone(),
            levels.clone(),
            serde_json::json!({}),
            serde_json::json!({}),
            &["train", "test"],
        )
        .unwrap();
        let img: Vec<f32> = (0..g.n_pixels()).map(|i| i as f32 * 0.5).collect();
        let lab = vec![3u8; g.n_pixels()];
        let sino: Vec<f32> = (0..g.n_rays()).map(|i| -(i as f32)).collect();
        let rec = |d| Record {
            entry: SliceEntry {
                phantom: 0,
                depth: d,
                thickness_mm: 12.0,
            },
            image: &img,
            labels: &lab,
            mask: &lab,
            sinograms: vec![&sino],
        };
        let ph = PhantomEntry {
            index: 7,
            glandularity: 0.2,
            thickness_mm: 12.0,
            spec: serde_json::json!({"seed": 1}),
            first_slice: 0,
            slices: 0,
        };
        w.push_phantom("train", ph.clone(), &[rec(0), rec(1)])
            .unwrap();
        w.push_phantom("test", ph.clone(), &[rec(5)]).unwrap();
        let bad = Record {
            image: &img[1..],
            ..rec(2)
        };
        assert!(w.push_phantom("train", ph.clone(), &[bad]).is_err());
        assert!(w.push_phantom("nope", ph, &[]).is_err());
        w.finish().unwrap();

        let ds = Dataset::open(dir.path()).unwrap();
        let m = ds.manifest();
        assert_eq!(m.splits[0].slices.len(), 2);
        assert_eq!(m.splits[0].phantoms[0].slices, 2);
        let images = ds.array("train", "images").unwrap();
        assert_eq!(images.len(), 2);
        assert_eq!(images.f32s(1).unwrap(), img);
        assert!(images.f32s(2).is_none());
        assert_eq!(ds.array("test", "sino-N8").unwrap().f32s(0).unwrap(), sino);
        assert_eq!(
            ds.array("test", "labels").unwrap().bytes(0).unwrap(),
            &lab[..]
        );
        assert!(ds.array("validation", "images").is_err());
        // A derived array: registered after its file is written, kept by a
        // reopened manifest; a file of the wrong size is refused.
        let mut ds = ds;
        let derived: Vec<u8> = img
            .iter()
            .chain(&img)
            .flat_map(|v| (v * 2.0).to_le_bytes())
            .collect();
        std::fs::write(dir.path().join("train").join("twice.f32"), &derived).unwrap();
        let entry = ArrayEntry {
            name: "twice".into(),
            file: "twice.f32".into(),
            dtype: "<f4".into(),
            shape: vec![2, g.image.rows, g.image.columns],
        };
        ds.register_array("train", entry.clone()).unwrap();
        let re = Dataset::open(dir.path()).unwrap();
        assert_eq!(
            re.array("train", "twice").unwrap().f32s(1).unwrap()[3],
            img[3] * 2.0
        );
        let mut short = entry;
        short.shape[0] = 3;
        let e = ds.register_array("train", short).unwrap_err().to_string();
        assert!(e.contains("twice.f32"), "{e}");
        assert!(ds
            .register_array("nope", re.array("train", "twice").unwrap().entry)
            .is_err());
        // A truncated file is reported with its path.
        let p = dir.path().join("train").join("masks.u8");
        let len = std::fs::metadata(&p).unwrap().len();
        std::fs::OpenOptions::new()
            .write(true)
            .open(&p)
            .unwrap()
            .set_len(len - 1)
            .unwrap();
        let e = ds.array("train", "masks").err().unwrap().to_string();
        assert!(e.contains("masks.u8"), "{e}");
        // Creating over an existing dataset is refused.
        assert!(DatasetWriter::create(
            dir.path(),
            g,
            levels,
            serde_json::json!({}),
            serde_json::json!({}),
            &["train"]
        )
        .is_err());
    }
}
