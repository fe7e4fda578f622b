//! The error ladder (issue #48 point 1): where between the acquisition and
//! the report a phantom's glandularity and dose go wrong. One phantom is
//! acquired once noise-free and once at a noise level, and the firmware's
//! stages are replaced by the truth one at a time:
//!
//! 1. `truth`: the phantom's own labels and attenuation on the
//!    reconstruction grid (what the grid can hold at all);
//! 2. `truth-mu`: the truth's attenuation (its partial volumes) through the
//!    firmware's skin rule, classifier, partial-volume estimate and
//!    calibration (the classification and calibration alone);
//! 3. `recon-mu+truth-outline`: the noise-free reconstruction's attenuation
//!    classified inside the truth's breast outline and skin (the
//!    reconstruction's attenuation alone);
//! 4. `truth-mu+recon-outline`: the truth's attenuation inside the
//!    reconstruction's outline and skin (the outline alone);
//! 5. `recon`: the noise-free reconstruction through the firmware;
//! 6. `recon@N`: the noisy acquisition through the firmware;
//! 7. `mltr`: MLTR on the noise-free acquisition (another reconstructor's
//!    view of the same data).
//!
//! Each rung gives the glandularity by labels, by partial volume and as
//! reported (calibrated), the patient MGD against the truth's labels through
//! the same Monte Carlo, the voxel confusion (air, adipose, skin,
//! fibroglandular) against the truth on the grid, and the partial-volume
//! glandularity by distance from the truth's skin surface and by depth from
//! the chest wall, beside the truth's in the same voxels.

use crate::accuracy::{agreement, Agreement};
use crate::classification::{confusion, mgd_per_kerma, truth_and_mu_on_grid};
use dbt_dose::xray::AnodeFilter;
use dbt_forward::NoiseLevel;
use dbt_geometry::Geometry;
use dbt_materials::Tissue;
use dbt_phantom::LabelVolume;
use dbt_pipeline::{reconstruct_volume, PipelineOptions};
use dbt_tissue::{
    classify, column_glandularity, density, fcm2, split_point, ClassifyOptions,
    GlandularityCalibration, PartialVolumeMass,
};
use host_sim::{simulate_acquisition_with, Technique};
use serde::Serialize;

/// Bands of distance from the truth's outer surface, mm (a voxel's distance
/// is its centre's: `(layer - 0.5) x voxel`, layer 1 the outermost).
/// The first band is the default skin shell ([`dbt_tissue::SKIN_MAX_MM`]).
pub const SKIN_DISTANCE_EDGES_MM: [f64; 5] = [0.0, 1.6, 4.0, 8.0, 16.0];

/// Width of the bands of distance from the chest wall, mm.
pub const CHEST_WALL_BAND_MM: f64 = 10.0;

/// Width of the bands of height above the breast support (the x-rays'
/// direction: depth in the tomosynthesis sense), mm.
pub const HEIGHT_BAND_MM: f64 = 5.0;

/// One band's partial-volume glandularity, truth against estimate.
#[derive(Debug, Clone, Serialize)]
pub struct BandStats {
    /// The band in words.
    pub band: String,
    /// Non-skin breast volume there by the truth's labels, cm^3.
    pub truth_cm3: f64,
    /// The truth's partial-volume glandularity by mass there.
    pub truth_g: Option<f64>,
    /// Non-skin breast volume there by the rung's labels, cm^3.
    pub est_cm3: f64,
    /// The rung's partial-volume glandularity by mass there (its labels,
    /// its attenuation).
    pub est_g: Option<f64>,
}

/// One rung of the ladder.
#[derive(Debug, Clone, Serialize)]
pub struct Rung {
    /// Which stages are the truth's (see the module documentation).
    pub name: String,
    /// Glandularity by mass from the labels.
    pub g_labels: f64,
    /// Glandularity by mass from partial volumes.
    pub g_partial_volume: f64,
    /// The reported (calibrated partial-volume) glandularity.
    pub g_reported: f64,
    /// Glandularity by mass from partial volumes without the clamp of each
    /// voxel's fraction to 0..1 (the rung's non-skin breast voxels' mean
    /// attenuation): the partial-volume estimate less what the clamp takes
    /// where attenuation has moved between voxels of the breast.
    pub g_unclamped: f64,
    /// Glandularity by mass from each column's attenuation along the beam
    /// (`dbt_tissue::column_glandularity`, uncalibrated).
    pub g_column: f64,
    /// Patient MGD of the rung's labels over the truth's, minus one, %.
    pub mgd_error_percent: Option<f64>,
    /// Voxel counts `[true][estimated]` over [`crate::classification::CLASSES`].
    pub confusion: [[u64; 4]; 4],
    /// By distance from the truth's skin surface.
    pub by_skin_distance: Vec<BandStats>,
    /// By height above the support (depth along the beam).
    pub by_height: Vec<BandStats>,
    /// By distance from the chest wall.
    pub by_chest_wall: Vec<BandStats>,
    /// How far the rung's attenuation fits the acquisition it came from
    /// ([`data_residual`]; `None` for the rungs made of the truth's
    /// attenuation against the noisy acquisition, which have none).
    pub data_residual: Option<f64>,
}

/// One phantom's ladder.
#[derive(Debug, Clone, Serialize)]
pub struct LadderCase {
    /// Where the phantom came from.
    pub phantom: String,
    /// Compressed thickness, mm.
    pub thickness_mm: f64,
    /// True glandularity by mass (the phantom's fine samples).
    pub g_true: f64,
    /// The truth's breast volume over the box "compressed thickness x each
    /// coronal slice's lateral extent" (how far the breast fills the
    /// reconstruction's support).
    pub fill: f64,
    /// The rungs, in the module documentation's order.
    pub rungs: Vec<Rung>,
}

/// What the ladder runs.
#[derive(Debug, Clone)]
pub struct LadderSetup {
    /// The firmware's reconstruction (DBToR with its calibration and
    /// classification options; MLTR when it has no model).
    pub opts: PipelineOptions,
    /// Noise level of the noisy rung.
    pub noise: NoiseLevel,
    /// MLTR iterations of the `mltr` rung; `None` leaves it out.
    pub mltr_iterations: Option<usize>,
    /// Target relative uncertainty of each Monte Carlo MGD; `None`: no dose.
    pub dose_uncertainty: Option<f64>,
    /// Acquisition and Monte Carlo seed.
    pub seed: u64,
}

/// Distance layers from the outer surface of the breast `labels != 0`
/// (dims `[lateral, vertical, depth]`): 1 for a breast voxel with an air
/// neighbour or on the volume's border (except the chest-wall face, depth
/// index 0), counted through the breast by 6-neighbour steps; 0 for air.
pub fn surface_layers(labels: &[u8], dims: [usize; 3]) -> Vec<u32> {
    let [nx, ny, nz] = dims;
    let mut layer = vec![u32::MAX; labels.len()];
    let mut queue = std::collections::VecDeque::new();
    let neighbours = |i: usize| {
        let (x, y, z) = (i % nx, (i / nx) % ny, i / (nx * ny));
        let at = |x: usize, y: usize, z: usize| (z * ny + y) * nx + x;
        // (neighbour, leaves the volume through an outer face)
        [
            x.checked_sub(1).map(|x| at(x, y, z)).ok_or(true),
            (x + 1 < nx).then(|| at(x + 1, y, z)).ok_or(true),
            y.checked_sub(1).map(|y| at(x, y, z)).ok_or(true),
            (y + 1 < ny).then(|| at(x, y + 1, z)).ok_or(true),
            z.checked_sub(1).map(|z| at(x, y, z)).ok_or(false),
            (z + 1 < nz).then(|| at(x, y, z + 1)).ok_or(true),
        ]
    };
    for (i, &l) in labels.iter().enumerate() {
        if l == 0 {
            layer[i] = 0;
        } else if neighbours(i).iter().any(|n| match n {
            Ok(j) => labels[*j] == 0,
            Err(outer) => *outer,
        }) {
            layer[i] = 1;
            queue.push_back(i);
        }
    }
    while let Some(i) = queue.pop_front() {
        for j in neighbours(i).into_iter().flatten() {
            if layer[j] == u32::MAX {
                layer[j] = layer[i] + 1;
                queue.push_back(j);
            }
        }
    }
    layer
}

/// Labels inside a given outline: air (0) and skin (2) where `outline` has
/// them, the rest of its breast split into adipose and fibroglandular by the
/// firmware's fuzzy c-means on `mu` (the voxel takes the nearer centre).
pub fn classify_within(mu: &[f32], outline: &[u8], opts: &ClassifyOptions) -> Vec<u8> {
    let inside = |l: u8| l != Tissue::Air.label() && l != Tissue::Skin.label();
    let vals: Vec<f64> = mu
        .iter()
        .zip(outline)
        .filter(|(_, &l)| inside(l))
        .map(|(&m, _)| m as f64)
        .collect();
    let (centres, _) = fcm2(&vals, opts);
    let mid = split_point(centres);
    mu.iter()
        .zip(outline)
        .map(|(&m, &l)| {
            if !inside(l) {
                l
            } else if m as f64 >= mid {
                Tissue::Fibroglandular.label()
            } else {
                Tissue::Adipose.label()
            }
        })
        .collect()
}

/// The partial-volume sums of the non-skin breast voxels among `idx` (the
/// firmware's estimate: `dbt_tissue::density`).
fn pv_sums(mu: &[f32], labels: &[u8], idx: impl Iterator<Item = usize>) -> PartialVolumeMass {
    let mut pv = PartialVolumeMass::default();
    for i in idx {
        if PartialVolumeMass::counts(labels[i]) {
            pv.add(mu[i] as f64, 1);
        }
    }
    pv
}

/// The relative data residual of a volume against the acquisition it was
/// reconstructed from: `||P f - g|| / ||g||` over every view and element of
/// every slice, `P` the acquisition's projector, `f` each slice's image
/// (the volume's rows within the thickness, air above), `g` the log of the
/// counts: the firmware's [`dbt_pipeline::data_fit`] over every slice. A
/// reconstruction that fits its data reads the noise's share; a network far
/// from what it was trained on may not fit (a data-consistency check needs
/// no truth).
pub fn data_residual(
    acq: &dbt_pipeline::SliceSinograms,
    mu: &[f32],
    dims: [usize; 3],
) -> anyhow::Result<f64> {
    let slices: Vec<usize> = (0..acq.counts.len()).collect();
    Ok(dbt_pipeline::data_fit::data_fit(&acq.header, &acq.counts, mu, dims, &slices)?.residual)
}

/// Glandularity by mass of the non-skin breast voxels' mean attenuation
/// (fractions not clamped per voxel; the mean's clamped to 0..1).
pub fn unclamped_glandularity(mu: &[f32], labels: &[u8]) -> f64 {
    let (mut sum, mut n) = (0.0f64, 0usize);
    for (&m, &l) in mu.iter().zip(labels) {
        if PartialVolumeMass::counts(l) {
            sum += m as f64;
            n += 1;
        }
    }
    let mut pv = PartialVolumeMass::default();
    pv.add(sum / n.max(1) as f64, 1);
    pv.glandularity().unwrap_or(0.0)
}

/// The bands' statistics: `band_of(i)` gives voxel `i`'s band (or `None`).
#[allow(clippy::too_many_arguments)]
fn bands(
    names: &[String],
    band_of: &dyn Fn(usize) -> Option<usize>,
    truth: (&[f32], &[u8]),
    est: (&[f32], &[u8]),
    voxel_mm: f64,
) -> Vec<BandStats> {
    let n = truth.1.len();
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); names.len()];
    for i in 0..n {
        if let Some(b) = band_of(i) {
            members[b].push(i);
        }
    }
    let cm3 = voxel_mm.powi(3) / 1000.0;
    names
        .iter()
        .zip(&members)
        .map(|(name, idx)| {
            let t = pv_sums(truth.0, truth.1, idx.iter().copied());
            let e = pv_sums(est.0, est.1, idx.iter().copied());
            BandStats {
                band: name.clone(),
                truth_cm3: t.voxels as f64 * cm3,
                truth_g: t.glandularity(),
                est_cm3: e.voxels as f64 * cm3,
                est_g: e.glandularity(),
            }
        })
        .collect()
}

/// Bands of `width_mm` over `n` voxels of `voxel_mm` (a voxel in the band
/// of its centre): their names and the band of each index.
fn even_bands(
    n: usize,
    voxel_mm: f64,
    width_mm: f64,
) -> (Vec<String>, impl Fn(usize) -> Option<usize>) {
    let count = ((n as f64 * voxel_mm) / width_mm).ceil() as usize;
    let names = (0..count)
        .map(|k| format!("{}-{} mm", k as f64 * width_mm, (k + 1) as f64 * width_mm))
        .collect();
    let band = move |i: usize| {
        Some((((i as f64 + 0.5) * voxel_mm) / width_mm) as usize).filter(|&b| b < count)
    };
    (names, band)
}

/// The band names of [`SKIN_DISTANCE_EDGES_MM`], the air outside first.
pub fn skin_band_names() -> Vec<String> {
    let e = SKIN_DISTANCE_EDGES_MM;
    let mut v = vec!["outside the breast".to_string()];
    for k in 0..e.len() {
        v.push(match e.get(k + 1) {
            Some(hi) => format!("{}-{} mm", e[k], hi),
            None => format!(">= {} mm", e[k]),
        });
    }
    v
}

/// Everything a rung is compared with.
struct Truth<'a> {
    labels: &'a [u8],
    mu: &'a [f32],
    layers: &'a [u32],
    dims: [usize; 3],
    voxel_mm: f64,
    thickness_mm: f64,
    /// (beam, MGD per kerma of the phantom's own labels) with dose.
    dose: Option<(AnodeFilter, f64)>,
}

impl Truth<'_> {
    #[allow(clippy::too_many_arguments)]
    fn rung(
        &self,
        name: &str,
        mu: &[f32],
        labels: &[u8],
        calibration: Option<GlandularityCalibration>,
        dose: Option<f64>,
        seed: u64,
        data_residual: Option<f64>,
    ) -> anyhow::Result<Rung> {
        let d = density(mu, labels, self.voxel_mm);
        let mgd_error_percent = match (self.dose, dose) {
            (Some((beam, truth)), Some(u)) => Some(
                100.0
                    * (mgd_per_kerma(
                        beam,
                        labels,
                        self.dims,
                        self.voxel_mm,
                        self.thickness_mm,
                        u,
                        seed,
                    )? / truth
                        - 1.0),
            ),
            _ => None,
        };
        let vox = self.voxel_mm;
        let skin_names = skin_band_names();
        let edges = SKIN_DISTANCE_EDGES_MM;
        let skin_band = |i: usize| -> Option<usize> {
            let l = self.layers[i];
            if l == 0 {
                return Some(0);
            }
            let dist = (l as f64 - 0.5) * vox;
            Some(1 + edges.iter().rposition(|&e| dist >= e).unwrap_or(0))
        };
        let [nx, ny, nz] = self.dims;
        let (chest_names, chest_band) = even_bands(nz, vox, CHEST_WALL_BAND_MM);
        let (height_names, height_band) = even_bands(ny, vox, HEIGHT_BAND_MM);
        let chest = |i: usize| chest_band(i / (nx * ny));
        let height = |i: usize| height_band((i / nx) % ny);
        Ok(Rung {
            name: name.to_string(),
            g_labels: d.glandularity_labels,
            g_partial_volume: d.glandularity_partial_volume,
            g_reported: calibration.map_or(d.glandularity_partial_volume, |c| {
                c.apply(d.glandularity_partial_volume, self.thickness_mm)
            }),
            g_unclamped: unclamped_glandularity(mu, labels),
            g_column: column_glandularity(mu, labels, self.dims).unwrap_or(0.0),
            mgd_error_percent,
            confusion: confusion(self.labels, labels),
            by_skin_distance: bands(
                &skin_names,
                &skin_band,
                (self.mu, self.labels),
                (mu, labels),
                vox,
            ),
            by_height: bands(
                &height_names,
                &height,
                (self.mu, self.labels),
                (mu, labels),
                vox,
            ),
            by_chest_wall: bands(
                &chest_names,
                &chest,
                (self.mu, self.labels),
                (mu, labels),
                vox,
            ),
            data_residual,
        })
    }
}

/// The share of the box "thickness rows x each coronal slice's lateral
/// extent" that the breast `labels != 0` fills.
pub fn box_fill(labels: &[u8], dims: [usize; 3]) -> f64 {
    let [nx, ny, nz] = dims;
    let (mut tissue, mut boxed) = (0usize, 0usize);
    for z in 0..nz {
        let s = &labels[z * nx * ny..(z + 1) * nx * ny];
        let (mut lo, mut hi, mut n) = (nx, 0, 0);
        for (i, &l) in s.iter().enumerate() {
            if l != 0 {
                lo = lo.min(i % nx);
                hi = hi.max(i % nx);
                n += 1;
            }
        }
        if n > 0 {
            tissue += n;
            boxed += (hi - lo + 1) * ny;
        }
    }
    if boxed == 0 {
        0.0
    } else {
        tissue as f64 / boxed as f64
    }
}

/// Run the ladder on one phantom (mono-energetic acquisition with the W/Rh
/// beam at its automatic kV, slice-wise on `geom`, the model's geometry).
pub fn run_ladder(
    name: &str,
    vol: &LabelVolume,
    geom: &Geometry,
    setup: &LadderSetup,
) -> anyhow::Result<LadderCase> {
    let _span = tracing::info_span!("ladder", %name).entered();
    let beam = AnodeFilter::WRh;
    let kvp = f64::from(beam.aec_kv(vol.thickness_mm()));
    let acquire = |noise: NoiseLevel| {
        simulate_acquisition_with(
            vol,
            geom,
            noise,
            host_sim::Physics::Mono,
            setup.seed,
            Technique {
                anode_filter: beam,
                ..Default::default()
            },
            kvp,
            "LADDER",
            "1.2.826.0.1.3680043.10.543.3",
        )
        .map_err(anyhow::Error::from)
        .and_then(|a| Ok(a.into_sinograms()?))
    };
    let clean = acquire(NoiseLevel::NoiseFree)?;
    let noisy = acquire(setup.noise)?;
    let opts = &setup.opts;
    let vox = geom.image.pixel_mm;
    let t_mm = vol.thickness_mm();
    let recon = reconstruct_volume(&clean, opts, &mut |_| {})?;
    let dims = recon.dims;
    let (t_labels, t_mu) = truth_and_mu_on_grid(vol, geom, dims)?;
    let layers = surface_layers(&t_labels, dims);
    let dose = match setup.dose_uncertainty {
        Some(u) => Some((
            beam,
            mgd_per_kerma(
                beam,
                vol.labels(),
                vol.dims(),
                vol.voxel_mm(),
                t_mm,
                u,
                setup.seed + 7,
            )?,
        )),
        None => None,
    };
    let truth = Truth {
        labels: &t_labels,
        mu: &t_mu,
        layers: &layers,
        dims,
        voxel_mm: vox,
        thickness_mm: t_mm,
        dose,
    };
    let cal = opts.calibration;
    let u = setup.dose_uncertainty;
    let seed = setup.seed;
    let mut rungs = Vec::new();
    // The truth's own attenuation against the noise-free acquisition: the
    // residual of a perfect reconstruction (the projector's and the
    // partial volumes' consistency).
    let r_truth = Some(data_residual(&clean, &t_mu, dims)?);
    rungs.push(truth.rung("truth", &t_mu, &t_labels, cal, u, seed, r_truth)?);
    let tc = classify(&t_mu, dims, vox, &opts.classify)?;
    rungs.push(truth.rung("truth-mu", &t_mu, &tc.labels, cal, u, seed, r_truth)?);
    let rc = classify(&recon.mu, dims, vox, &opts.classify)?;
    let r_clean = Some(data_residual(&clean, &recon.mu, dims)?);
    let within = classify_within(&recon.mu, &t_labels, &opts.classify);
    rungs.push(truth.rung(
        "recon-mu+truth-outline",
        &recon.mu,
        &within,
        cal,
        u,
        seed,
        r_clean,
    )?);
    let within = classify_within(&t_mu, &rc.labels, &opts.classify);
    rungs.push(truth.rung(
        "truth-mu+recon-outline",
        &t_mu,
        &within,
        cal,
        u,
        seed,
        r_truth,
    )?);
    rungs.push(truth.rung("recon", &recon.mu, &rc.labels, cal, u, seed, r_clean)?);
    let rn = reconstruct_volume(&noisy, opts, &mut |_| {})?;
    anyhow::ensure!(
        rn.dims == dims,
        "noisy volume {:?} against {dims:?}",
        rn.dims
    );
    let c = classify(&rn.mu, dims, vox, &opts.classify)?;
    let tag = format!("recon@{}", setup.noise.name());
    let r_noisy = Some(data_residual(&noisy, &rn.mu, dims)?);
    rungs.push(truth.rung(&tag, &rn.mu, &c.labels, cal, u, seed, r_noisy)?);
    if let Some(it) = setup.mltr_iterations {
        let mo = PipelineOptions {
            dbtor: None,
            mltr_iterations: it,
            calibration: None,
            ..opts.clone()
        };
        let m = reconstruct_volume(&clean, &mo, &mut |_| {})?;
        anyhow::ensure!(m.dims == dims, "MLTR volume {:?} against {dims:?}", m.dims);
        let c = classify(&m.mu, dims, vox, &opts.classify)?;
        let r = Some(data_residual(&clean, &m.mu, dims)?);
        rungs.push(truth.rung(&format!("mltr-{it}"), &m.mu, &c.labels, None, u, seed, r)?);
    }
    Ok(LadderCase {
        phantom: name.to_string(),
        thickness_mm: t_mm,
        g_true: vol.glandularity().unwrap_or(0.0),
        fill: box_fill(&t_labels, dims),
        rungs,
    })
}

/// One rung summarised over the cases.
#[derive(Debug, Clone, Serialize)]
pub struct RungSummary {
    /// The rung.
    pub name: String,
    /// Reported glandularity error, pp.
    pub reported_pp: Agreement,
    /// Partial-volume glandularity error, pp.
    pub partial_volume_pp: Agreement,
    /// Label glandularity error, pp.
    pub labels_pp: Agreement,
    /// Unclamped partial-volume glandularity error, pp.
    pub unclamped_pp: Agreement,
    /// Column glandularity error, pp.
    pub column_pp: Agreement,
    /// Patient MGD error, %.
    pub mgd_percent: Option<Agreement>,
    /// The data residual's mean and sd over the cases.
    pub data_residual: Option<[f64; 2]>,
    /// The confusion summed over the cases, voxel counts.
    pub confusion: [[u64; 4]; 4],
    /// The same, each true class's row as fractions.
    pub confusion_fractions: [[f64; 4]; 4],
}

/// Summarise the cases rung by rung (every case has the same rungs).
pub fn summarise(cases: &[LadderCase]) -> Vec<RungSummary> {
    let Some(first) = cases.first() else {
        return Vec::new();
    };
    (0..first.rungs.len())
        .map(|k| {
            let pp = |f: fn(&Rung) -> f64| {
                agreement(
                    &cases
                        .iter()
                        .map(|c| 100.0 * (f(&c.rungs[k]) - c.g_true))
                        .collect::<Vec<_>>(),
                )
            };
            let mgd: Option<Vec<f64>> =
                cases.iter().map(|c| c.rungs[k].mgd_error_percent).collect();
            let mut total = [[0u64; 4]; 4];
            for c in cases {
                for (t, row) in c.rungs[k].confusion.iter().enumerate() {
                    for (e, n) in row.iter().enumerate() {
                        total[t][e] += n;
                    }
                }
            }
            RungSummary {
                name: first.rungs[k].name.clone(),
                reported_pp: pp(|r| r.g_reported),
                partial_volume_pp: pp(|r| r.g_partial_volume),
                labels_pp: pp(|r| r.g_labels),
                unclamped_pp: pp(|r| r.g_unclamped),
                column_pp: pp(|r| r.g_column),
                mgd_percent: mgd.filter(|m| !m.is_empty()).map(|m| agreement(&m)),
                data_residual: cases
                    .iter()
                    .map(|c| c.rungs[k].data_residual)
                    .collect::<Option<Vec<f64>>>()
                    .map(|v| {
                        let (m, sd) = dbt_metrics::mean_sd(&v);
                        [m, sd]
                    }),
                confusion: total,
                confusion_fractions: total.map(|row| {
                    let n: u64 = row.iter().sum();
                    row.map(|v| if n > 0 { v as f64 / n as f64 } else { 0.0 })
                }),
            }
        })
        .collect()
}

/// The summary as a Markdown table: per rung the errors' bias +- sd (pp;
/// MGD %) and the confusion's telling shares.
pub fn summary_table(rows: &[RungSummary]) -> String {
    let mut s = String::from(
        "| rung | G reported (pp) | G partial volume (pp) | G labels (pp) | G unclamped (pp) | G columns (pp) | MGD (%) | data residual | fibrogl. read adipose | adipose read fibrogl. | breast read air | air read breast |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let f = |a: &Agreement| format!("{:+.2} +- {:.2}", a.bias, a.sd);
    for r in rows {
        let c = &r.confusion_fractions;
        let n = &r.confusion;
        // Indices into `crate::classification::CLASSES`.
        let (air, adi, skin, fg) = (0, 1, 2, 3);
        let breast: u64 = n[adi].iter().chain(&n[skin]).chain(&n[fg]).sum();
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {:.1} % | {:.1} % | {:.1} % | {:.1} % |\n",
            r.name,
            f(&r.reported_pp),
            f(&r.partial_volume_pp),
            f(&r.labels_pp),
            f(&r.unclamped_pp),
            f(&r.column_pp),
            r.mgd_percent.as_ref().map_or("-".into(), f),
            r.data_residual
                .map_or("-".into(), |[m, sd]| format!("{:.4} +- {:.4}", m, sd)),
            100.0 * c[fg][adi],
            100.0 * c[adi][fg],
            100.0 * (n[adi][air] + n[skin][air] + n[fg][air]) as f64 / breast.max(1) as f64,
            100.0 * (1.0 - c[air][air]),
        ));
    }
    s
}

/// A case's band table for one rung: per band the truth's and the rung's
/// partial-volume glandularity (%) and volume (cm^3).
pub fn band_table(title: &str, rows: &[(&str, &[BandStats])]) -> String {
    let Some((_, first)) = rows.first() else {
        return String::new();
    };
    let mut s = format!("| {title} |");
    for b in first.iter() {
        s.push_str(&format!(" {} |", b.band));
    }
    s.push_str("\n|---|");
    s.push_str(&"---|".repeat(first.len()));
    s.push('\n');
    let g = |x: Option<f64>| x.map_or("-".to_string(), |v| format!("{:.1}", 100.0 * v));
    s.push_str("| truth: G % (cm^3) |");
    for b in first.iter() {
        s.push_str(&format!(" {} ({:.1}) |", g(b.truth_g), b.truth_cm3));
    }
    s.push('\n');
    for (name, bands) in rows {
        s.push_str(&format!("| {name}: G % (cm^3) |"));
        for b in bands.iter() {
            s.push_str(&format!(" {} ({:.1}) |", g(b.est_g), b.est_cm3));
        }
        s.push('\n');
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Surface layers: a 5 x 5 x 3 block of tissue in air; the chest-wall
    /// face (depth 0) is no surface, the other faces are.
    #[test]
    fn surface_layers_count_from_the_outer_faces_only() {
        let dims = [7, 7, 3];
        let mut labels = vec![0u8; 7 * 7 * 3];
        for z in 0..3 {
            for y in 1..6 {
                for x in 1..6 {
                    labels[(z * 7 + y) * 7 + x] = 1;
                }
            }
        }
        let l = surface_layers(&labels, dims);
        let at = |x: usize, y: usize, z: usize| l[(z * 7 + y) * 7 + x];
        assert_eq!(at(0, 0, 0), 0);
        assert_eq!(at(1, 3, 1), 1);
        // Depth 2 is the last slice: its face is a surface (the nipple side).
        assert_eq!(at(3, 3, 2), 1);
        // The centre of the chest-wall slice is deep: 2 from the last
        // slice's face, 3 from the lateral faces.
        assert_eq!(at(3, 3, 0), 3);
        assert_eq!(at(3, 3, 1), 2);
    }

    /// Inside a given outline the two tissues are split at the midpoint of
    /// the c-means centres; air and skin are the outline's.
    #[test]
    fn classify_within_keeps_the_outline_and_splits_the_inside() {
        let fat = Tissue::Adipose.mu_per_mm();
        let gland = Tissue::Fibroglandular.mu_per_mm();
        let mu = [0.0, fat, gland, fat, gland, 0.2, gland];
        let outline = [0, 1, 1, 3, 3, 2, 0];
        let l = classify_within(&mu, &outline, &ClassifyOptions::default());
        assert_eq!(l, vec![0, 1, 3, 1, 3, 2, 0]);
    }

    #[test]
    fn box_fill_of_a_half_filled_box() {
        // One slice, 4 wide x 2 tall: the breast fills the bottom row.
        let labels = [1, 1, 1, 1, 0, 0, 0, 0];
        assert!((box_fill(&labels, [4, 2, 1]) - 0.5).abs() < 1e-12);
        assert_eq!(box_fill(&[0; 8], [4, 2, 1]), 0.0);
    }

    /// On a procedural phantom (no partial volumes), the `truth` rung reads
    /// the phantom's own glandularity exactly, its confusion is diagonal,
    /// and every rung is there; MLTR rungs are finite.
    #[test]
    fn the_truth_rung_reads_the_truth() {
        let g = Geometry::paper().binned(10).unwrap();
        let (name, vol) = crate::accuracy::test_phantoms(&g, 1)
            .next()
            .unwrap()
            .unwrap();
        let setup = LadderSetup {
            opts: PipelineOptions {
                mltr_iterations: 4,
                ..PipelineOptions::default()
            },
            noise: NoiseLevel::parse("N8").unwrap(),
            mltr_iterations: Some(2),
            dose_uncertainty: None,
            seed: 3,
        };
        let c = run_ladder(&name, &vol, &g, &setup).unwrap();
        let names: Vec<&str> = c.rungs.iter().map(|r| r.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "truth",
                "truth-mu",
                "recon-mu+truth-outline",
                "truth-mu+recon-outline",
                "recon",
                "recon@N8",
                "mltr-2"
            ]
        );
        let t = &c.rungs[0];
        assert!((t.g_labels - c.g_true).abs() < 1e-12);
        assert!((t.g_partial_volume - c.g_true).abs() < 1e-9);
        for (i, row) in t.confusion.iter().enumerate() {
            for (j, &n) in row.iter().enumerate() {
                if i != j {
                    assert_eq!(n, 0);
                }
            }
        }
        // The truth's bands read the truth's own glandularity.
        for b in &t.by_skin_distance {
            assert_eq!(b.truth_g, b.est_g);
            assert_eq!(b.truth_cm3, b.est_cm3);
        }
        let sv: f64 = t.by_skin_distance.iter().map(|b| b.truth_cm3).sum();
        for by in [&t.by_height, &t.by_chest_wall] {
            let v: f64 = by.iter().map(|b| b.truth_cm3).sum();
            assert!((v - sv).abs() < 1e-9 && v > 0.0);
        }
        assert!(c.fill > 0.5 && c.fill <= 1.0);
        // The truth's attenuation fits its noise-free acquisition (the
        // same projector; f32 counts); a reconstruction less well.
        let r_truth = t.data_residual.unwrap();
        assert!(r_truth < 1e-4, "truth residual {r_truth}");
        let r_recon = c.rungs[4].data_residual.unwrap();
        assert!(r_recon.is_finite() && r_recon > r_truth, "{r_recon}");
        for r in &c.rungs {
            assert!(r.g_partial_volume.is_finite() && r.g_reported.is_finite());
        }
        let s = summarise(std::slice::from_ref(&c));
        assert_eq!(s.len(), c.rungs.len());
        assert!(summary_table(&s).lines().count() == 2 + s.len());
    }
}
