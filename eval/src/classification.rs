//! The classifier against the phantom truth, voxel by voxel (issue #7): each
//! phantom is acquired once and reconstructed once with the firmware's
//! reconstruction step; the volume is then classified with each of several
//! [`ClassifyOptions`] and compared with the phantom's own labels on the
//! same grid: the glandularity of both estimators and the confusion matrix
//! (true label x estimated label). No dose is computed, so classifier
//! variants can be compared on many phantoms quickly; `accuracy` runs the
//! whole chain.
//!
//! Tune on the validation split (`Split::Validation`), report on the test
//! split.

use crate::accuracy::{agreement, Agreement};
use dbt_dose::patient::{dbt_views, mgd_to_uncertainty, Breast, Model};
use dbt_forward::NoiseLevel;
use dbt_geometry::Geometry;
use dbt_phantom::{coronal_slice, LabelVolume};
use dbt_pipeline::{correct_counts, reconstruct_volume, PipelineOptions, Volume};
use dbt_tissue::{classify, density, ClassifyOptions};
use host_sim::{simulate_acquisition_with, Technique};
use serde::Serialize;

/// The tissue classes of the confusion matrix, in label order.
pub const CLASSES: [&str; 4] = ["air", "adipose", "skin", "fibroglandular"];

/// The truth labels of `vol` on the grid of a reconstructed volume of
/// `dims = [columns, rows within the thickness, coronal slices]`, placed as
/// the acquisition places them (`dbt_phantom::coronal_slice`).
pub fn truth_on_grid(
    vol: &LabelVolume,
    geom: &Geometry,
    dims: [usize; 3],
) -> anyhow::Result<Vec<u8>> {
    Ok(truth_and_mu_on_grid(vol, geom, dims)?.0)
}

/// [`truth_on_grid`] and the truth's attenuation on the same grid (1/mm):
/// the partial volumes' mean attenuation where the phantom has them, else
/// its labels' (`dbt_phantom::Slice::mu`), exactly what the acquisition
/// projects.
pub fn truth_and_mu_on_grid(
    vol: &LabelVolume,
    geom: &Geometry,
    dims: [usize; 3],
) -> anyhow::Result<(Vec<u8>, Vec<f32>)> {
    let [cols, nv, nd] = dims;
    anyhow::ensure!(
        cols == geom.image.columns && nv <= geom.image.rows && nd == vol.n_coronal(),
        "volume dimensions {dims:?} do not match the geometry ({} x {}) and the phantom's {} coronal slices",
        geom.image.columns,
        geom.image.rows,
        vol.n_coronal()
    );
    let rows = geom.image.rows;
    let mut out = vec![0u8; cols * nv * nd];
    let mut mu = vec![0f32; cols * nv * nd];
    for d in 0..nd {
        let s = coronal_slice(vol, d, geom)?;
        let m = s.mu();
        for v in 0..nv {
            let r = rows - 1 - v;
            let dst = (d * nv + v) * cols;
            out[dst..dst + cols].copy_from_slice(&s.labels[r * cols..(r + 1) * cols]);
            mu[dst..dst + cols].copy_from_slice(&m[r * cols..(r + 1) * cols]);
        }
    }
    Ok((out, mu))
}

/// Voxel counts `[true class][estimated class]` over [`CLASSES`] (labels
/// above 3 count as fibroglandular).
pub fn confusion(truth: &[u8], est: &[u8]) -> [[u64; 4]; 4] {
    let mut m = [[0u64; 4]; 4];
    for (&t, &e) in truth.iter().zip(est) {
        m[(t as usize).min(3)][(e as usize).min(3)] += 1;
    }
    m
}

/// One phantom under one classifier variant.
#[derive(Debug, Clone, Serialize)]
pub struct ClassCase {
    /// Where the phantom came from.
    pub phantom: String,
    /// Compressed thickness, mm.
    pub thickness_mm: f64,
    /// True glandularity by mass.
    pub g_true: f64,
    /// Glandularity from the labels.
    pub g_labels: f64,
    /// Glandularity from partial volumes.
    pub g_partial_volume: f64,
    /// Voxel counts `[true][estimated]` over [`CLASSES`].
    pub confusion: [[u64; 4]; 4],
    /// Patient-specific MGD of the classified volume over that of the
    /// phantom's own labels (same spectrum, views and kerma), minus one, in
    /// percent; `None` without dose.
    pub mgd_error_percent: Option<f64>,
}

/// A classifier variant's summary over the cases.
#[derive(Debug, Clone, Serialize)]
pub struct VariantSummary {
    /// The variant's options.
    pub options: ClassifyOptions,
    /// Glandularity error from the labels, percentage points.
    pub glandularity_labels_pp: Agreement,
    /// Glandularity error from partial volumes, percentage points.
    pub glandularity_partial_volume_pp: Agreement,
    /// Patient-specific MGD error, percent (cases with dose only).
    pub mgd_percent: Option<Agreement>,
    /// Confusion summed over the cases, each true class's row as fractions.
    pub confusion_fractions: [[f64; 4]; 4],
    /// The cases.
    pub cases: Vec<ClassCase>,
}

/// Patient-specific MGD per unit kerma of a label volume for the DBT sweep
/// and the automatic exposure of `beam` for `thickness_mm`, to relative
/// uncertainty `target`.
#[allow(clippy::too_many_arguments)]
pub fn mgd_per_kerma(
    beam: dbt_dose::xray::AnodeFilter,
    labels: &[u8],
    dims: [usize; 3],
    voxel_mm: f64,
    thickness_mm: f64,
    target: f64,
    seed: u64,
) -> anyhow::Result<f64> {
    let tube = dbt_dose::xray::aec_spectrum(beam, thickness_mm)?;
    let spectrum = tube
        .spectrum
        .ok_or_else(|| anyhow::anyhow!("no spectrum for {thickness_mm} mm"))?;
    let breast = Breast {
        dims,
        voxel_mm,
        labels,
    };
    Ok(mgd_to_uncertainty(
        &breast,
        Model::PatientSpecific,
        &spectrum,
        &dbt_views(),
        target,
        200_000,
        100_000_000,
        seed,
    )?
    .mgd_per_kerma)
}

/// Acquire `vol` (noise `noise`, physics `physics`, beam `beam`, seed
/// `seed`), reconstruct it with `opts`' reconstructor, and classify the volume with each of `variants`; with
/// `dose` (a target relative uncertainty), also the patient-specific MGD of
/// each classified volume against the phantom's own labels.
#[allow(clippy::too_many_arguments)]
pub fn run_phantom(
    name: &str,
    vol: &LabelVolume,
    geom: &Geometry,
    noise: NoiseLevel,
    physics: host_sim::Physics,
    beam: dbt_dose::xray::AnodeFilter,
    opts: &PipelineOptions,
    variants: &[ClassifyOptions],
    dose: Option<f64>,
    seed: u64,
) -> anyhow::Result<Vec<ClassCase>> {
    let _span = tracing::info_span!("classification case", %name).entered();
    let acq = simulate_acquisition_with(
        vol,
        geom,
        noise,
        physics,
        seed,
        Technique {
            anode_filter: beam,
            ..Default::default()
        },
        f64::from(beam.aec_kv(vol.thickness_mm())),
        "EVAL",
        "1.2.826.0.1.3680043.10.543.3",
    )?;
    let acq = acq.into_sinograms()?;
    let acq = correct_counts(&acq, opts)?;
    let Volume {
        dims, voxel_mm, mu, ..
    } = reconstruct_volume(&acq, opts, &mut |_| {})?;
    let truth = truth_on_grid(vol, geom, dims)?;
    let t = vol.thickness_mm();
    let truth_mgd = dose
        .map(|u| {
            mgd_per_kerma(
                beam,
                vol.labels(),
                vol.dims(),
                vol.voxel_mm(),
                t,
                u,
                seed + 7,
            )
        })
        .transpose()?;
    variants
        .iter()
        .map(|o| {
            let c = classify(&mu, dims, voxel_mm, o)?;
            let d = density(&mu, &c.labels, voxel_mm);
            let mgd_error_percent = match (dose, truth_mgd) {
                (Some(u), Some(m)) => Some(
                    100.0 * (mgd_per_kerma(beam, &c.labels, dims, voxel_mm, t, u, seed)? / m - 1.0),
                ),
                _ => None,
            };
            Ok(ClassCase {
                phantom: name.to_string(),
                thickness_mm: vol.thickness_mm(),
                g_true: vol.glandularity().unwrap_or(0.0),
                g_labels: d.glandularity_labels,
                g_partial_volume: d.glandularity_partial_volume,
                confusion: confusion(&truth, &c.labels),
                mgd_error_percent,
            })
        })
        .collect()
}

/// Summarise one variant's cases.
pub fn summarise(options: ClassifyOptions, cases: Vec<ClassCase>) -> VariantSummary {
    let pp = |f: fn(&ClassCase) -> f64| {
        agreement(
            &cases
                .iter()
                .map(|c| 100.0 * (f(c) - c.g_true))
                .collect::<Vec<_>>(),
        )
    };
    let mut total = [[0u64; 4]; 4];
    for c in &cases {
        for (t, row) in c.confusion.iter().enumerate() {
            for (e, n) in row.iter().enumerate() {
                total[t][e] += n;
            }
        }
    }
    let confusion_fractions = total.map(|row| {
        let n: u64 = row.iter().sum();
        row.map(|v| if n > 0 { v as f64 / n as f64 } else { 0.0 })
    });
    let mgd: Option<Vec<f64>> = cases.iter().map(|c| c.mgd_error_percent).collect();
    VariantSummary {
        options,
        mgd_percent: mgd.filter(|m| !m.is_empty()).map(|m| agreement(&m)),
        glandularity_labels_pp: pp(|c| c.g_labels),
        glandularity_partial_volume_pp: pp(|c| c.g_partial_volume),
        confusion_fractions,
        cases,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dbt_phantom::{generate, Population};

    /// The truth on the grid holds the phantom's every tissue voxel (the
    /// phantom fits the image), so its glandularity is the phantom's; and a
    /// perfect reconstruction (the truth's own attenuation) is classified
    /// without a single wrong voxel.
    #[test]
    fn the_truth_on_the_grid_is_the_phantom_and_classifies_exactly() {
        let g = Geometry::paper().binned(4).unwrap();
        let spec = Population::for_geometry(&g).draw(Population::TEST_SEED, 0);
        let vol = generate(&spec).unwrap();
        let nv = g.rows_within_thickness(vol.thickness_mm());
        let dims = [g.image.columns, nv, vol.n_coronal()];
        let truth = truth_on_grid(&vol, &g, dims).unwrap();
        let count = |l: u8, x: &[u8]| x.iter().filter(|&&v| v == l).count() as u64;
        let c = vol.counts();
        for l in 1..=3u8 {
            assert_eq!(count(l, &truth), c[l as usize], "label {l}");
        }
        let mu = dbt_phantom::labels_to_mu(&truth);
        // The paper's growth is exact on the truth's own attenuation (the
        // skin, 0.0854 /mm, is the brightest tissue).
        let cl = classify(&mu, dims, g.image.pixel_mm, &ClassifyOptions::paper()).unwrap();
        let m = confusion(&truth, &cl.labels);
        for (t, row) in m.iter().enumerate() {
            for (e, &n) in row.iter().enumerate() {
                if t != e {
                    assert_eq!(n, 0, "true {} read as {}", CLASSES[t], CLASSES[e]);
                }
            }
        }
        let d = density(&mu, &cl.labels, g.image.pixel_mm);
        let gt = vol.glandularity().unwrap();
        assert!((d.glandularity_labels - gt).abs() < 1e-12);
        assert!(truth_on_grid(&vol, &g, [dims[0] + 1, nv, dims[2]]).is_err());
    }

    /// One phantom through acquisition, MLTR and two variants: the
    /// confusion covers every voxel of the volume, the variants share the
    /// truth, and the MGD errors are finite.
    #[test]
    fn a_phantom_through_the_reconstruction_and_two_variants() {
        let g = Geometry::paper().binned(10).unwrap();
        let (name, vol) = crate::accuracy::test_phantoms(&g, 1)
            .next()
            .unwrap()
            .unwrap();
        let opts = PipelineOptions {
            mltr_iterations: 5,
            ..PipelineOptions::default()
        };
        let variants = [ClassifyOptions::paper(), ClassifyOptions::default()];
        let noise = NoiseLevel::parse("N8").unwrap();
        let cs = run_phantom(
            &name,
            &vol,
            &g,
            noise,
            host_sim::Physics::Mono,
            dbt_dose::xray::AnodeFilter::WRh,
            &opts,
            &variants,
            Some(0.05),
            3,
        )
        .unwrap();
        assert_eq!(cs.len(), 2);
        let nv = g.rows_within_thickness(vol.thickness_mm());
        let voxels = (g.image.columns * nv * vol.n_coronal()) as u64;
        for c in &cs {
            let total: u64 = c.confusion.iter().flatten().sum();
            assert_eq!(total, voxels);
            assert_eq!(c.g_true, cs[0].g_true);
            let truth_rows: Vec<u64> = c.confusion.iter().map(|r| r.iter().sum()).collect();
            let first: Vec<u64> = cs[0].confusion.iter().map(|r| r.iter().sum()).collect();
            assert_eq!(truth_rows, first, "the variants share the truth");
            assert!(c.mgd_error_percent.is_some_and(f64::is_finite));
        }
        let without = run_phantom(
            &name,
            &vol,
            &g,
            noise,
            host_sim::Physics::Mono,
            dbt_dose::xray::AnodeFilter::WRh,
            &opts,
            &variants[..1],
            None,
            3,
        )
        .unwrap();
        assert_eq!(without[0].g_labels, cs[0].g_labels);
        assert!(without[0].mgd_error_percent.is_none());
    }

    #[test]
    fn confusion_counts_pairs_and_summary_rows_sum_to_one() {
        let m = confusion(&[0, 1, 1, 3, 4, 2], &[0, 3, 1, 3, 2, 2]);
        assert_eq!(m[1], [0, 1, 0, 1]);
        assert_eq!(m[3], [0, 0, 1, 1]);
        assert_eq!(m[2][2], 1);
        let case = |g_labels| ClassCase {
            phantom: "x".into(),
            thickness_mm: 40.0,
            g_true: 0.2,
            g_labels,
            g_partial_volume: 0.2,
            confusion: m,
            mgd_error_percent: None,
        };
        let s = summarise(ClassifyOptions::default(), vec![case(0.25), case(0.15)]);
        assert!(s.glandularity_labels_pp.bias.abs() < 1e-12);
        assert!((s.glandularity_labels_pp.max_abs - 5.0).abs() < 1e-9);
        assert!(s.mgd_percent.is_none());
        for row in &s.confusion_fractions {
            let t: f64 = row.iter().sum();
            assert!((t - 1.0).abs() < 1e-12);
        }
    }
}
