//! The training-dataset exporter: random phantoms from a population, all
//! their tissue-holding coronal slices, simulated at every noise level,
//! streamed to a `dbt-store` dataset with phantom-level splits.
//!
//! * `train` and `validation`: phantoms `0, 1, 2, ...` of the population drawn
//!   with the training seed; every tenth phantom (index % 10 == 9) goes to
//!   validation. Phantoms are added until the slice budget is reached.
//! * `test`: the fixed evaluation test set (population seed
//!   [`Population::TEST_SEED`], phantoms `0..test_phantoms`), the same phantoms
//!   the evaluation command uses. The training seed may not equal it.

use crate::{
    mix_seed, simulate_acquisition_with, simulate_slices, tissue_slices, Physics, SimError,
    SimSlice, Technique,
};
use dbt_forward::{log_transform, NoiseLevel};
use dbt_geometry::Geometry;
use dbt_phantom::{AnySpec, Population, PopulationKind};
use dbt_projector::Projector;
use dbt_store::dataset::{
    le_f32, ArrayEntry, Dataset, DatasetWriter, Manifest, NoiseEntry, PhantomEntry, Record,
    SliceEntry,
};
use rayon::prelude::*;
use std::path::Path;

/// Exporter options.
#[derive(Debug, Clone)]
pub struct ExportOptions {
    /// Geometry of the slices and sinograms.
    pub geometry: Geometry,
    /// Train + validation slices wanted (whole phantoms, so slightly more).
    pub slices: usize,
    /// Phantoms of the fixed test set to include as the `test` split.
    pub test_phantoms: usize,
    /// Population seed of the training phantoms.
    pub seed: u64,
    /// Noise levels, one sinogram array each.
    pub levels: Vec<NoiseLevel>,
    /// Phantoms generated at once (memory: each holds its slices).
    pub batch: usize,
    /// The phantom population (training, validation and test phantoms).
    pub population: PopulationKind,
    /// The acquisitions' physics. [`Physics::Mono`]: each level's counts
    /// as simulated (the paper's). [`Physics::Clinical`]: what the firmware
    /// feeds the network on such a gantry (issue #27): the whole
    /// acquisition simulated with that physics at the one level's dose (the
    /// Table 3 kV of its thickness), its counts corrected as the firmware
    /// corrects them (the scatter removed if the physics has scatter, the
    /// beam hardening linearised; `dbt_pipeline::correct_counts`); exactly
    /// one noise level.
    pub physics: Physics,
    /// With a clinical physics: the counts as the detector gives them, no
    /// correction (scatter and beam hardening in the sinograms): the data of
    /// the other design issue #27 compares, a network trained on uncorrected
    /// clinical acquisitions. Refused with the mono physics.
    pub uncorrected: bool,
}

/// Add `fbp-<level>` to every split of the dataset in `dir`: the FBP
/// (`dbt_recon::Fbp`, Hann-windowed ramp, zero outside the thickness mask) of
/// each slice's `sino-<level>`, in 1/mm on the image grid: the input of the
/// U-Net baseline, the same FBP the evaluation computes. Returns the number of
/// slices per split.
pub fn add_fbp(dir: &Path, level: &str) -> Result<Vec<(String, usize)>, SimError> {
    let mut ds = Dataset::open(dir)?;
    let geom = ds.manifest().geometry.clone();
    let fbp = dbt_recon::Fbp::new(&geom);
    let (rows, cols) = (geom.image.rows, geom.image.columns);
    let splits: Vec<String> = ds
        .manifest()
        .splits
        .iter()
        .map(|s| s.name.clone())
        .collect();
    let name = format!("fbp-{level}");
    let file = format!("{name}.f32");
    let mut done = Vec::new();
    for split in splits {
        let _span = tracing::info_span!("fbp", split = %split).entered();
        let sino = ds.array(&split, &format!("sino-{level}"))?;
        let masks = ds.array(&split, "masks")?;
        let n = sino.len();
        let path = dir.join(&split).join(&file);
        let io = |source| dbt_store::StoreError::Io {
            path: path.clone(),
            cause: source,
        };
        let mut out = std::io::BufWriter::new(std::fs::File::create(&path).map_err(io)?);
        const CHUNK: usize = 256;
        for c0 in (0..n).step_by(CHUNK) {
            let imgs: Vec<Vec<f32>> = (c0..(c0 + CHUNK).min(n))
                .into_par_iter()
                .map(|i| {
                    let missing =
                        |what: &str| SimError::Options(format!("{split}: {what} has no slice {i}"));
                    let g = sino.f32s(i).ok_or_else(|| missing("the sinogram array"))?;
                    let m: Vec<f32> = masks
                        .bytes(i)
                        .ok_or_else(|| missing("the mask array"))?
                        .iter()
                        .map(|&b| b as f32)
                        .collect();
                    Ok(fbp.reconstruct(&g, Some(&m))?)
                })
                .collect::<Result<_, SimError>>()?;
            for img in imgs {
                std::io::Write::write_all(&mut out, &le_f32(&img)).map_err(io)?;
            }
        }
        std::io::Write::flush(&mut out).map_err(io)?;
        drop(out);
        ds.register_array(
            &split,
            ArrayEntry {
                name: name.clone(),
                file: file.clone(),
                dtype: "<f4".into(),
                shape: vec![n, rows, cols],
            },
        )?;
        done.push((split, n));
    }
    Ok(done)
}

fn phantom_records(
    spec: &AnySpec,
    geom: &Geometry,
    proj: &Projector,
    levels: &[NoiseLevel],
    physics: Physics,
    uncorrected: bool,
    noise_seed: u64,
) -> Result<(PhantomEntry, Vec<SimSlice>), SimError> {
    let vol = spec.generate()?;
    let depths = tissue_slices(&vol, 1);
    // The clinical counts come from the whole acquisition below: the
    // slices then need only their images, labels and masks.
    let slice_levels = match physics {
        Physics::Mono => levels,
        Physics::Clinical { .. } => &[],
    };
    let mut slices = simulate_slices(&vol, geom, proj, &depths, slice_levels, noise_seed)?;
    if let Physics::Clinical { detector, scatter } = physics {
        let level = match levels {
            [l] => *l,
            _ => {
                return Err(SimError::Options(format!(
                    "the clinical physics exports one noise level (its dose), not {}",
                    levels.len()
                )))
            }
        };
        let kvp = f64::from(dbt_dose::xray::paper_technique(vol.thickness_mm()).0);
        let acq = simulate_acquisition_with(
            &vol,
            geom,
            level,
            physics,
            noise_seed,
            Technique::default(),
            kvp,
            "DATASET",
            "1.2.826.0.1.3680043.10.543.3",
        )?;
        let acq = acq
            .into_sinograms()
            .map_err(|e| SimError::Options(e.to_string()))?;
        let corrected = if uncorrected {
            std::borrow::Cow::Borrowed(&acq)
        } else {
            let opts = dbt_pipeline::PipelineOptions {
                descatter: if scatter {
                    Some(
                        dbt_pipeline::descatter::ScatterRemoval::shipped()
                            .map_err(|e| SimError::Options(e.to_string()))?,
                    )
                } else {
                    None
                },
                linearise: Some(dbt_pipeline::linearise::BeamHardening {
                    detector,
                    path: dbt_pipeline::linearise::PathModel::Reference,
                }),
                ..Default::default()
            };
            dbt_pipeline::correct_counts(&acq, &opts)
                .map_err(|e| SimError::Options(format!("correcting the clinical counts: {e}")))?
        };
        for s in &mut slices {
            let counts = corrected.counts.get(s.depth).ok_or_else(|| {
                SimError::Options(format!(
                    "the clinical acquisition has {} slices, no slice {}",
                    corrected.counts.len(),
                    s.depth
                ))
            })?;
            s.counts = vec![counts.clone()];
            s.flux = vec![corrected.header.flux];
        }
    }
    let entry = PhantomEntry {
        index: 0,
        glandularity: vol.glandularity().unwrap_or(0.0),
        thickness_mm: vol.thickness_mm(),
        spec: serde_json::to_value(spec).unwrap_or_default(),
        first_slice: 0,
        slices: 0,
    };
    Ok((entry, slices))
}

fn write_phantom(
    w: &mut DatasetWriter,
    split: &str,
    mut entry: PhantomEntry,
    index: u64,
    slices: &[SimSlice],
) -> Result<(), SimError> {
    entry.index = index;
    let masks: Vec<Vec<u8>> = slices
        .iter()
        .map(|s| s.mask.iter().map(|&m| m as u8).collect())
        .collect();
    let sinos: Vec<Vec<Vec<f32>>> = slices
        .par_iter()
        .map(|s| {
            s.counts
                .iter()
                .zip(&s.flux)
                .map(|(c, &b)| log_transform(c, b))
                .collect()
        })
        .collect();
    let records: Vec<Record<'_>> = slices
        .iter()
        .zip(&masks)
        .zip(&sinos)
        .map(|((s, m), g)| Record {
            entry: SliceEntry {
                phantom: 0,
                depth: s.depth,
                thickness_mm: s.thickness_mm,
            },
            image: &s.mu,
            labels: &s.labels,
            mask: m,
            sinograms: g.iter().map(|v| v.as_slice()).collect(),
        })
        .collect();
    w.push_phantom(split, entry, &records)?;
    Ok(())
}

/// Export a dataset to `dir`; returns its manifest.
pub fn export(dir: &Path, opts: &ExportOptions) -> Result<Manifest, SimError> {
    export_observed(dir, opts, &mut |_| {})
}

/// Where an export stands (for a progress display).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExportStage {
    /// Train and validation slices written so far, of those wanted.
    Slices {
        /// Written.
        done: usize,
        /// Wanted (whole phantoms: the last may overshoot).
        wanted: usize,
    },
    /// Test phantoms written so far.
    TestPhantoms {
        /// Written.
        done: usize,
        /// Wanted.
        wanted: usize,
    },
    /// The projector's CSR operator for the trainer.
    Operator,
}

/// As [`export`], calling `on` after each phantom written and before the
/// operator.
pub fn export_observed(
    dir: &Path,
    opts: &ExportOptions,
    on: &mut dyn FnMut(ExportStage),
) -> Result<Manifest, SimError> {
    if opts.seed == Population::TEST_SEED {
        return Err(SimError::Options(
            "the training seed equals the evaluation test-set seed; choose another".into(),
        ));
    }
    if opts.levels.is_empty() {
        return Err(SimError::Options(
            "at least one noise level is needed".into(),
        ));
    }
    if opts.physics != Physics::Mono && opts.levels.len() != 1 {
        return Err(SimError::Options(format!(
            "the {} physics exports one noise level (its dose), not {}",
            opts.physics.name(),
            opts.levels.len()
        )));
    }
    if opts.uncorrected && opts.physics == Physics::Mono {
        return Err(SimError::Options(
            "uncorrected counts are a clinical physics' (the mono physics has nothing to correct)"
                .into(),
        ));
    }
    let geom = &opts.geometry;
    let proj = Projector::new(geom);
    let kind = opts.population;
    let levels: Vec<NoiseEntry> = opts
        .levels
        .iter()
        .map(|l| NoiseEntry {
            name: l.name(),
            flux: l.flux(),
        })
        .collect();
    let encoding = serde_json::json!({
        "images": "linear attenuation at 20 keV in 1/mm (paper values / 10)",
        "labels": {"0": "air", "1": "adipose", "2": "skin", "3": "fibroglandular", "4": "ligament"},
        "masks": "1 on every image row whose centre lies within the compressed thickness above the support (bottom row), across the full width; 0 above",
        "sinograms": match opts.physics {
            Physics::Mono => "g = ln(b / max(y, 0.5)) of the simulated counts y, view-major [views, elements]".to_string(),
            Physics::Clinical { scatter, .. } if opts.uncorrected => format!(
                "g = ln(b / max(y, 0.5)) of the clinical acquisition's counts y as the detector gives them, uncorrected ({}, polychromatic: no linearisation); b the header's flux; view-major [views, elements]",
                if scatter { "the scatter in them" } else { "no scatter simulated" }
            ),
            Physics::Clinical { scatter, .. } => format!(
                "g = ln(b / max(y, 0.5)) of the counts y the firmware reconstructs: the clinical acquisition's counts {}, then linearised to 20 keV (dbt_pipeline::correct_counts); b the header's flux; view-major [views, elements]",
                if scatter { "with the scatter removed (the shipped kernel model)" } else { "(no scatter simulated)" }
            ),
        },
        "image_layout": "row 0 at the top (nearest the source at 0 degrees), breast on the bottom row",
    });
    let provenance = serde_json::json!({
        "generator": "host-sim dataset",
        "population": match kind {
            PopulationKind::Procedural => serde_json::to_value(Population::for_geometry(geom)),
            PopulationKind::Anatomical => {
                serde_json::to_value(dbt_phantom::AnatomicalPopulation::for_geometry(geom))
            }
            PopulationKind::AnatomicalSpread => Ok(serde_json::json!({
                "anatomical": dbt_phantom::AnatomicalPopulation::for_geometry(geom),
                "rule": "AnatomicalPopulation::draw_spread: the anatomical draw, the gland spread through the height",
            })),
            PopulationKind::Mixed => Ok(serde_json::json!({
                "procedural": Population::for_geometry(geom),
                "anatomical": dbt_phantom::AnatomicalPopulation::for_geometry(geom),
                "rule": "population index % 3 == 2: procedural, else anatomical",
            })),
        }
        .unwrap_or_default(),
        "population_kind": kind.name(),
        "physics": opts.physics.name(),
        "corrections": if opts.physics == Physics::Mono {
            "none (mono-energetic, no scatter)"
        } else if opts.uncorrected {
            // What a model trained on it is then fed: checked at load
            // (`dbt_model::check_training_input`).
            dbt_dbtor::UNCORRECTED_CLINICAL_COUNTS
        } else if matches!(opts.physics, Physics::Clinical { scatter: true, .. }) {
            "the firmware's: scatter removed, beam hardening linearised"
        } else {
            "the firmware's: beam hardening linearised (no scatter simulated)"
        },
        "train_seed": opts.seed,
        "test_seed": Population::TEST_SEED,
        "validation_rule": "population index % 10 == 9",
        "version": env!("CARGO_PKG_VERSION"),
    });
    let mut w = DatasetWriter::create(
        dir,
        geom.clone(),
        levels,
        encoding,
        provenance,
        &["train", "validation", "test"],
    )?;
    let batch = opts.batch.max(1);
    let mut produced = 0usize;
    let mut next = 0u64;
    while produced < opts.slices {
        let idx: Vec<u64> = (next..next + batch as u64).collect();
        next += batch as u64;
        let done: Vec<_> = idx
            .par_iter()
            .map(|&i| {
                let spec = kind.draw(geom, opts.seed, i);
                phantom_records(
                    &spec,
                    geom,
                    &proj,
                    &opts.levels,
                    opts.physics,
                    opts.uncorrected,
                    mix_seed(opts.seed, &[i, 1]),
                )
            })
            .collect::<Result<_, _>>()?;
        for (i, (entry, slices)) in idx.into_iter().zip(done) {
            if produced >= opts.slices {
                break;
            }
            produced += slices.len();
            let split = if i % 10 == 9 { "validation" } else { "train" };
            tracing::info!(
                phantom = i,
                split,
                slices = slices.len(),
                produced,
                "phantom exported"
            );
            write_phantom(&mut w, split, entry, i, &slices)?;
            on(ExportStage::Slices {
                done: produced,
                wanted: opts.slices,
            });
        }
    }
    for i in 0..opts.test_phantoms as u64 {
        let spec = kind.draw(geom, Population::TEST_SEED, i);
        let (entry, slices) = phantom_records(
            &spec,
            geom,
            &proj,
            &opts.levels,
            opts.physics,
            opts.uncorrected,
            mix_seed(Population::TEST_SEED, &[i, 1]),
        )?;
        write_phantom(&mut w, "test", entry, i, &slices)?;
        on(ExportStage::TestPhantoms {
            done: i as usize + 1,
            wanted: opts.test_phantoms,
        });
    }
    let manifest = w.finish()?;
    on(ExportStage::Operator);
    // The operator the trainer uses: the same projector, as CSR.
    let (norm, _) = proj.operator_norm(200, 1e-6);
    dbt_store::operator::write_operator(&dir.join("operator"), geom, &proj.to_csr(), norm)?;
    Ok(manifest)
}

#[cfg(test)]
mod tests {
    use super::*;
    use dbt_store::dataset::Dataset;

    fn tiny_geometry() -> Geometry {
        Geometry::paper().binned(4).unwrap()
    }

    /// `fbp-<level>` holds, slice by slice, exactly `Fbp::reconstruct` of the
    /// stored sinogram with the stored mask; an unknown level is refused.
    #[test]
    fn fbp_array_is_the_fbp_of_each_stored_sinogram() {
        let opts = ExportOptions {
            geometry: tiny_geometry(),
            slices: 60,
            test_phantoms: 0,
            seed: 5,
            levels: vec![NoiseLevel::Poisson(8)],
            batch: 1,
            population: PopulationKind::Procedural,
            physics: Physics::Mono,
            uncorrected: false,
        };
        let d = tempfile::tempdir().unwrap();
        export(d.path(), &opts).unwrap();
        let done = add_fbp(d.path(), "N8").unwrap();
        assert!(done.iter().any(|(s, n)| s == "train" && *n > 0), "{done:?}");
        let ds = Dataset::open(d.path()).unwrap();
        let (sino, masks, fbp) = (
            ds.array("train", "sino-N8").unwrap(),
            ds.array("train", "masks").unwrap(),
            ds.array("train", "fbp-N8").unwrap(),
        );
        assert_eq!(fbp.len(), sino.len());
        let f = dbt_recon::Fbp::new(&opts.geometry);
        for i in [0, sino.len() - 1] {
            let m: Vec<f32> = masks.bytes(i).unwrap().iter().map(|&b| b as f32).collect();
            let want = f.reconstruct(&sino.f32s(i).unwrap(), Some(&m)).unwrap();
            assert_eq!(fbp.f32s(i).unwrap(), want, "slice {i}");
            assert!(want.iter().any(|&v| v != 0.0));
        }
        assert!(add_fbp(d.path(), "N4").is_err());
    }

    #[test]
    fn export_is_reproducible_and_splits_whole_phantoms() {
        let opts = ExportOptions {
            geometry: tiny_geometry(),
            slices: 150,
            test_phantoms: 1,
            seed: 5,
            levels: vec![NoiseLevel::NoiseFree, NoiseLevel::Poisson(8)],
            batch: 2,
            population: PopulationKind::Procedural,
            physics: Physics::Mono,
            uncorrected: false,
        };
        let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
        let ma = export(a.path(), &opts).unwrap();
        let mb = export(b.path(), &opts).unwrap();
        assert_eq!(ma, mb);
        for f in [
            "train/images.f32",
            "train/sino-N8.f32",
            "test/labels.u8",
            "test/masks.u8",
        ] {
            assert_eq!(
                std::fs::read(a.path().join(f)).unwrap(),
                std::fs::read(b.path().join(f)).unwrap(),
                "{f} differs"
            );
        }
        let ds = Dataset::open(a.path()).unwrap();
        let m = ds.manifest();
        let train = &m.splits[0];
        assert!(train.slices.len() + m.splits[1].slices.len() >= 150);
        // Slices of a phantom are contiguous and all in one split.
        for (k, p) in train.phantoms.iter().enumerate() {
            for s in &train.slices[p.first_slice..p.first_slice + p.slices] {
                assert_eq!(s.phantom, k);
            }
        }
        assert_eq!(m.splits[2].phantoms.len(), 1);
        // Noise-free sinogram = forward projection of the stored image.
        let proj = Projector::new(&opts.geometry);
        let img = ds.array("train", "images").unwrap().f32s(3).unwrap();
        let sino = ds
            .array("train", "sino-noise-free")
            .unwrap()
            .f32s(3)
            .unwrap();
        let mut p = vec![0f32; proj.range_len()];
        proj.forward(&img, &mut p).unwrap();
        for (x, y) in p.iter().zip(&sino) {
            assert!((x - y).abs() < 1e-4, "{x} vs {y}");
        }
        // The training seed may not be the test seed.
        let bad = ExportOptions {
            seed: Population::TEST_SEED,
            ..opts
        };
        assert!(export(tempfile::tempdir().unwrap().path(), &bad).is_err());
    }

    /// An anatomical dataset: its images are the partial volumes'
    /// attenuation (values between the tissues'), its noise-free sinograms
    /// their projections, its manifest names the population, and its
    /// phantoms' truth is the fine samples' glandularity.
    #[test]
    fn anatomical_export_carries_partial_volumes() {
        let opts = ExportOptions {
            geometry: Geometry::builtin("paper-104").unwrap().binned(4).unwrap(),
            slices: 60,
            test_phantoms: 0,
            seed: 7,
            levels: vec![NoiseLevel::NoiseFree],
            batch: 1,
            population: PopulationKind::Anatomical,
            physics: Physics::Mono,
            uncorrected: false,
        };
        let d = tempfile::tempdir().unwrap();
        let m = export(d.path(), &opts).unwrap();
        assert_eq!(m.provenance["population_kind"], "anatomical");
        let ds = Dataset::open(d.path()).unwrap();
        let proj = Projector::new(&opts.geometry);
        let images = ds.array("train", "images").unwrap();
        let sinos = ds.array("train", "sino-noise-free").unwrap();
        let n = ds.manifest().splits[0].slices.len();
        let mid = images.f32s(n / 2).unwrap();
        let pure: Vec<f32> = dbt_materials::MU_BY_LABEL.to_vec();
        let mixed = mid
            .iter()
            .filter(|v| pure.iter().all(|p| (*v - p).abs() > 1e-6))
            .count();
        assert!(mixed > 100, "only {mixed} partial-volume pixels");
        let mut p = vec![0f32; proj.range_len()];
        proj.forward(&mid, &mut p).unwrap();
        for (x, y) in p.iter().zip(&sinos.f32s(n / 2).unwrap()) {
            assert!((x - y).abs() < 1e-4, "{x} vs {y}");
        }
        let first = &ds.manifest().splits[0].phantoms[0];
        let spec = PopulationKind::Anatomical.draw(&opts.geometry, 7, 0);
        let vol = spec.generate().unwrap();
        assert_eq!(first.glandularity, vol.glandularity().unwrap());
    }

    /// The N8 sinogram of the training slice at fraction `at` of the
    /// dataset in `dir`, summed over the rays through the breast (line
    /// integral above 1), over the 20 keV line integrals of its image.
    fn log_signal_over_line_integrals(dir: &Path, geometry: &Geometry, at: f64) -> f64 {
        let ds = Dataset::open(dir).unwrap();
        let (images, sinos) = (
            ds.array("train", "images").unwrap(),
            ds.array("train", "sino-N8").unwrap(),
        );
        let proj = Projector::new(geometry);
        let mut p = vec![0f32; proj.range_len()];
        let i = (ds.manifest().splits[0].slices.len() as f64 * at) as usize;
        proj.forward(&images.f32s(i).unwrap(), &mut p).unwrap();
        let g = sinos.f32s(i).unwrap();
        let (mut sum_g, mut sum_p) = (0.0f64, 0.0f64);
        for (x, y) in p.iter().zip(&g) {
            if *x > 1.0 {
                sum_p += *x as f64;
                sum_g += *y as f64;
            }
        }
        assert!(sum_p > 0.0, "slice {i}: no ray through the breast");
        sum_g / sum_p
    }

    /// A clinical-physics dataset holds what the firmware reconstructs:
    /// after the scatter removal and the linearisation its sinograms are the
    /// 20 keV line integrals of the stored images, up to the noise and the
    /// corrections' residual (the removal leaves at most a few per cent of
    /// the primary under thick breasts, under 1 % of a line integral,
    /// eval/README.md): the mean over the rays through the breast within
    /// 2 %. Two noise levels are refused (the physics sets one dose).
    #[test]
    fn clinical_export_holds_the_corrected_line_integrals() {
        let opts = ExportOptions {
            geometry: tiny_geometry(),
            slices: 30,
            test_phantoms: 0,
            seed: 5,
            levels: vec![NoiseLevel::Poisson(8)],
            batch: 1,
            population: PopulationKind::Procedural,
            physics: Physics::parse("clinical").unwrap(),
            uncorrected: false,
        };
        let d = tempfile::tempdir().unwrap();
        let m = export(d.path(), &opts).unwrap();
        assert_eq!(m.provenance["physics"], "clinical");
        for at in [0.25, 0.5] {
            let rel = log_signal_over_line_integrals(d.path(), &opts.geometry, at) - 1.0;
            assert!(
                rel.abs() < 0.02,
                "slice at {at}: corrected line integrals {rel:+.4} off"
            );
        }
        let two = ExportOptions {
            levels: vec![NoiseLevel::Poisson(8), NoiseLevel::Poisson(4)],
            ..opts
        };
        let e = export(tempfile::tempdir().unwrap().path(), &two)
            .unwrap_err()
            .to_string();
        assert!(e.contains("one noise level"), "{e}");
        // Uncorrected: the same acquisitions' counts as detected, the
        // scatter adding photons and the hardened beam losing fewer, so the
        // log signal under the breast reads well below the 20 keV line
        // integrals (the scatter alone, SPR 0.3-1 at these thicknesses,
        // takes ln(1 + SPR) = 0.26-0.69 off each ray's few units), and the
        // mono physics refuses the option.
        let raw = ExportOptions {
            uncorrected: true,
            levels: vec![NoiseLevel::Poisson(8)],
            ..two
        };
        let d = tempfile::tempdir().unwrap();
        let m = export(d.path(), &raw).unwrap();
        // The value a model's load checks its configured input against.
        assert_eq!(
            m.provenance["corrections"].as_str(),
            Some(dbt_dbtor::UNCORRECTED_CLINICAL_COUNTS),
            "{}",
            m.provenance
        );
        let ratio = log_signal_over_line_integrals(d.path(), &raw.geometry, 0.5);
        assert!(
            ratio < 0.9,
            "uncorrected log signal {ratio:.3} of the line integrals"
        );
        let mono = ExportOptions {
            physics: Physics::Mono,
            ..raw
        };
        let e = export(tempfile::tempdir().unwrap().path(), &mono)
            .unwrap_err()
            .to_string();
        assert!(e.contains("uncorrected"), "{e}");
    }
}
