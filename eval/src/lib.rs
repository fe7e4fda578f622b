//! Evaluation of reconstructions against the phantom truth, as in the paper's
//! Tables 1-2: L2 (MSE), SSIM and PSNR, mean +- sd over the slices of a fixed
//! test set of phantoms (population seed `Population::TEST_SEED`), noise-free
//! and at N = 4, 8, 12.
//!
//! Conventions (chosen to match the scale of the paper's numbers; see
//! `eval/README.md`): images in 1/cm, metrics over the whole image, data range
//! of the ground truth for PSNR and SSIM; FBP is limited to the thickness
//! support like MLTR.

pub mod accuracy;
pub mod classification;
pub mod ladder;
pub mod picture;
pub mod unet;
pub mod victre;

use dbt_forward::NoiseLevel;
use dbt_geometry::Geometry;
use dbt_metrics::{mean_sd, score, ImageScores, Shape};
use dbt_phantom::PopulationKind;
#[cfg(test)]
use dbt_phantom::{generate, Population};
use dbt_projector::Projector;
use dbt_recon::{mltr, Fbp, MltrOptions};
use host_sim::{simulate_slices, tissue_slices, SimSlice};
use rayon::prelude::*;
use serde::Serialize;

pub use accuracy::Split;

/// Options of the baseline evaluation.
#[derive(Debug, Clone, Serialize)]
pub struct BaselineOptions {
    /// Geometry (phantoms are generated at its pixel size).
    pub geometry: Geometry,
    /// Which phantoms (the test set unless choosing settings).
    pub split: Split,
    /// The population the split's phantoms are drawn from.
    pub population: PopulationKind,
    /// Phantoms `0..phantoms` of the split.
    pub phantoms: usize,
    /// Coronal slices per phantom, evenly spaced over its tissue slices.
    pub slices_per_phantom: usize,
    /// MLTR iterations (the paper: 100).
    pub iterations: usize,
    /// Noise levels.
    pub levels: Vec<NoiseLevel>,
}

/// mean +- sd of one metric.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Stat {
    /// Mean.
    pub mean: f64,
    /// Sample standard deviation.
    pub sd: f64,
}

/// One row of the table.
#[derive(Debug, Clone, Serialize)]
pub struct Row {
    /// `MLTR` or `FBP`.
    pub method: String,
    /// `noise-free`, `N4`, ...
    pub noise: String,
    /// L2 loss (MSE, 1/cm squared).
    pub l2: Stat,
    /// SSIM.
    pub ssim: Stat,
    /// PSNR, dB.
    pub psnr: Stat,
    /// Number of slices.
    pub n: usize,
    /// Where the SSIM is lost: its local map split by the truth under each
    /// window (`dbt_metrics::ssim_regions`).
    pub ssim_regions: RegionRow,
}

/// The SSIM of one row by region: mean +- sd over the slices that have
/// windows of the region, and the region's mean share of the windows.
#[derive(Debug, Clone, Serialize)]
pub struct RegionRow {
    /// Windows wholly inside the breast.
    pub inside: RegionStat,
    /// Windows across the breast's outline.
    pub outline: RegionStat,
    /// Windows wholly in air.
    pub air: RegionStat,
}

/// One region of [`RegionRow`].
#[derive(Debug, Clone, Copy, Serialize)]
pub struct RegionStat {
    /// Mean local SSIM over the region's windows, mean +- sd over slices.
    pub ssim: Stat,
    /// Mean share of the image's windows that fall in the region.
    pub share: f64,
    /// Slices with at least one window of the region.
    pub n: usize,
}

/// One region of the slices' [`ImageScores::ssim_regions`], picked by `region`.
fn region_stat(
    scores: &[ImageScores],
    region: fn(&dbt_metrics::SsimRegions) -> dbt_metrics::RegionSsim,
) -> RegionStat {
    let regions: Vec<_> = scores.iter().map(|s| region(&s.ssim_regions)).collect();
    let with: Vec<f64> = regions
        .iter()
        .filter(|r| r.share > 0.0)
        .map(|r| r.mean)
        .collect();
    let (mean, sd) = mean_sd(&with);
    let share = regions.iter().map(|r| r.share).sum::<f64>() / regions.len().max(1) as f64;
    RegionStat {
        ssim: Stat { mean, sd },
        share,
        n: with.len(),
    }
}

/// One slice of the test set.
#[derive(Debug, Clone, Serialize)]
pub struct TestSlice {
    /// Test-set phantom index.
    pub phantom: u64,
    /// Coronal index.
    pub depth: usize,
}

/// The evaluation result.
#[derive(Debug, Clone, Serialize)]
pub struct BaselineReport {
    /// What was run.
    pub options: BaselineOptions,
    /// The slices used.
    pub slices: Vec<TestSlice>,
    /// Ground-truth glandularity of each test phantom.
    pub phantom_glandularity: Vec<f64>,
    /// The table.
    pub rows: Vec<Row>,
}

/// Pick `m` indices evenly spaced over `0..n`.
pub fn evenly_spaced(n: usize, m: usize) -> Vec<usize> {
    if n == 0 || m == 0 {
        return vec![];
    }
    let m = m.min(n);
    (0..m)
        .map(|k| ((k as f64 + 0.5) * n as f64 / m as f64) as usize)
        .collect()
}

/// The simulated test slices with their origin, and each phantom's glandularity.
pub type TestSet = (Vec<(TestSlice, SimSlice)>, Vec<f64>);

/// The fixed test set: phantoms and slices, simulated at every level.
pub fn test_set(
    geom: &Geometry,
    proj: &Projector,
    phantoms: usize,
    per_phantom: usize,
    levels: &[NoiseLevel],
) -> anyhow::Result<TestSet> {
    slice_set(
        geom,
        proj,
        Split::Test,
        PopulationKind::Procedural,
        phantoms,
        per_phantom,
        levels,
    )
}

/// [`test_set`] on the phantoms of any split (`Split::Validation`: choose
/// settings there, report on the test split). Noise seeds derive from the
/// split's population seed and the phantom's index.
pub fn slice_set(
    geom: &Geometry,
    proj: &Projector,
    split: Split,
    population: PopulationKind,
    phantoms: usize,
    per_phantom: usize,
    levels: &[NoiseLevel],
) -> anyhow::Result<TestSet> {
    let mut out = Vec::new();
    let mut glands = Vec::new();
    for i in 0..phantoms as u64 {
        let _span = tracing::info_span!("test_phantom", index = i).entered();
        let (seed, index) = split.draw(i);
        let vol = population.draw(geom, seed, index).generate()?;
        glands.push(vol.glandularity().unwrap_or(0.0));
        let all = tissue_slices(&vol, 1);
        let depths: Vec<usize> = evenly_spaced(all.len(), per_phantom)
            .into_iter()
            .map(|k| all[k])
            .collect();
        let noise_seed = host_sim::mix_seed(seed, &[index, 1]);
        for s in simulate_slices(&vol, geom, proj, &depths, levels, noise_seed)? {
            out.push((
                TestSlice {
                    phantom: i,
                    depth: s.depth,
                },
                s,
            ));
        }
    }
    Ok((out, glands))
}

fn to_per_cm(v: &[f32]) -> Vec<f32> {
    v.iter().map(|x| x * 10.0).collect()
}

/// A learned reconstructor of the table: a primal-dual network (DBToR, LPD)
/// on the log sinogram, or the U-Net on the FBP.
#[derive(Debug, Clone, Copy)]
pub enum Learned<'a> {
    /// DBToR or LPD (`dbt_dbtor::Dbtor`).
    PrimalDual(&'a dbt_dbtor::Dbtor),
    /// The U-Net post-processing the (masked) FBP.
    Unet(&'a crate::unet::Unet),
}

impl Learned<'_> {
    /// The geometry the model was trained for.
    pub fn geometry(&self) -> &Geometry {
        match self {
            Learned::PrimalDual(m) => m.geometry(),
            Learned::Unet(m) => m.geometry(),
        }
    }

    /// Reconstruct from the log sinogram (`line`), the thickness, and the FBP
    /// of the same slice (the U-Net's input).
    pub fn reconstruct(
        &self,
        line: &[f32],
        thickness_mm: f64,
        fbp: &[f32],
    ) -> anyhow::Result<Vec<f32>> {
        Ok(match self {
            Learned::PrimalDual(m) => m.reconstruct(line, thickness_mm)?,
            Learned::Unet(m) => m.reconstruct(fbp)?,
        })
    }
}

/// Run MLTR, FBP and the given learned models (name, model) on the test set
/// and tabulate. Each model's geometry must be the evaluation geometry.
pub fn evaluate_baselines(
    opts: &BaselineOptions,
    models: &[(String, Learned)],
) -> anyhow::Result<BaselineReport> {
    evaluate_baselines_observed(opts, models, &mut |_, _| {})
}

/// As [`evaluate_baselines`], calling `on_slice(done, total)` after each
/// test slice (every noise level and method).
pub fn evaluate_baselines_observed(
    opts: &BaselineOptions,
    models: &[(String, Learned)],
    on_slice: &mut dyn FnMut(usize, usize),
) -> anyhow::Result<BaselineReport> {
    let g = &opts.geometry;
    for (name, m) in models {
        anyhow::ensure!(
            m.geometry() == g,
            "{name}: the model's geometry ({}) is not the evaluation geometry ({})",
            m.geometry().describe(),
            g.describe()
        );
    }
    let mut methods: Vec<String> = vec!["MLTR".into(), "FBP".into()];
    methods.extend(models.iter().map(|(n, _)| n.clone()));
    let proj = Projector::new(g);
    let fbp = Fbp::new(g);
    let shape = Shape {
        rows: g.image.rows,
        cols: g.image.columns,
    };
    let (set, glands) = slice_set(
        g,
        &proj,
        opts.split,
        opts.population,
        opts.phantoms,
        opts.slices_per_phantom,
        &opts.levels,
    )?;
    let mltr_opts = MltrOptions {
        iterations: opts.iterations,
        track_likelihood: false,
    };
    // scores[level][method] = per-slice scores
    let mut scores = vec![vec![Vec::<ImageScores>::new(); methods.len()]; opts.levels.len()];
    for (done, (ts, s)) in set.iter().enumerate() {
        let _span = tracing::info_span!("slice", phantom = ts.phantom, depth = ts.depth).entered();
        let truth = to_per_cm(&s.mu);
        let per_level: Vec<anyhow::Result<Vec<ImageScores>>> = (0..opts.levels.len())
            .into_par_iter()
            .map(|k| {
                let (m, _) = mltr(&proj, &s.counts[k], s.flux[k], &s.mask, &mltr_opts)?;
                let line = dbt_forward::log_transform(&s.counts[k], s.flux[k]);
                let f = fbp.reconstruct(&line, Some(&s.mask))?;
                let mut out = vec![
                    score(shape, &truth, &to_per_cm(&m))?,
                    score(shape, &truth, &to_per_cm(&f))?,
                ];
                for (_, model) in models {
                    let x = model.reconstruct(&line, s.thickness_mm, &f)?;
                    out.push(score(shape, &truth, &to_per_cm(&x))?);
                }
                Ok(out)
            })
            .collect();
        for (k, r) in per_level.into_iter().enumerate() {
            for (mi, sc) in r?.into_iter().enumerate() {
                scores[k][mi].push(sc);
            }
        }
        on_slice(done + 1, set.len());
    }
    let mut rows = Vec::new();
    for (mi, method) in methods.iter().enumerate() {
        for (k, lvl) in opts.levels.iter().enumerate() {
            let sc = &scores[k][mi];
            let stat = |f: fn(&ImageScores) -> f64| {
                let v: Vec<f64> = sc.iter().map(f).collect();
                let (mean, sd) = mean_sd(&v);
                Stat { mean, sd }
            };
            rows.push(Row {
                method: method.to_string(),
                noise: lvl.name(),
                l2: stat(|s| s.l2),
                ssim: stat(|s| s.ssim),
                psnr: stat(|s| s.psnr),
                n: sc.len(),
                ssim_regions: RegionRow {
                    inside: region_stat(sc, |r| r.inside),
                    outline: region_stat(sc, |r| r.outline),
                    air: region_stat(sc, |r| r.air),
                },
            });
        }
    }
    Ok(BaselineReport {
        options: opts.clone(),
        slices: set.into_iter().map(|(t, _)| t).collect(),
        phantom_glandularity: glands,
        rows,
    })
}

/// The table as Markdown.
pub fn table(report: &BaselineReport) -> String {
    let mut s = String::from(
        "| Model | noise | L2 loss | SSIM | PSNR (dB) | slices |\n|---|---|---|---|---|---|\n",
    );
    for r in &report.rows {
        s.push_str(&format!(
            "| {} | {} | {:.4} ± {:.1e} | {:.3} ± {:.1e} | {:.2} ± {:.1e} | {} |\n",
            r.method,
            r.noise,
            r.l2.mean,
            r.l2.sd,
            r.ssim.mean,
            r.ssim.sd,
            r.psnr.mean,
            r.psnr.sd,
            r.n
        ));
    }
    s
}

/// The SSIM by region as Markdown: for each row, the local SSIM of the
/// windows wholly inside the breast, across its outline and wholly in air
/// (mean +- sd over slices) with each region's share of the windows.
pub fn region_table(report: &BaselineReport) -> String {
    let mut s = String::from(
        "| Model | noise | SSIM | inside the breast | outline | air |\n|---|---|---|---|---|---|\n",
    );
    let cell = |r: &RegionStat| {
        format!(
            "{:.3} ± {:.1e} ({:.0} %)",
            r.ssim.mean,
            r.ssim.sd,
            100.0 * r.share
        )
    };
    for r in &report.rows {
        let g = &r.ssim_regions;
        s.push_str(&format!(
            "| {} | {} | {:.3} | {} | {} | {} |\n",
            r.method,
            r.noise,
            r.ssim.mean,
            cell(&g.inside),
            cell(&g.outline),
            cell(&g.air)
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spacing() {
        assert_eq!(evenly_spaced(10, 2), vec![2, 7]);
        assert_eq!(evenly_spaced(3, 5), vec![0, 1, 2]);
        assert!(evenly_spaced(0, 3).is_empty());
    }

    /// The validation split draws other phantoms than the test split, and
    /// the test split through `slice_set` is `test_set`.
    #[test]
    fn slice_sets_of_the_two_splits() {
        let g = Geometry::paper().binned(10).unwrap();
        let proj = Projector::new(&g);
        let lv = [NoiseLevel::Poisson(8)];
        let (test, gt) = test_set(&g, &proj, 2, 1, &lv).unwrap();
        let (same, gs) = slice_set(
            &g,
            &proj,
            Split::Test,
            PopulationKind::Procedural,
            2,
            1,
            &lv,
        )
        .unwrap();
        assert_eq!(gt, gs);
        assert_eq!(test[1].1.counts, same[1].1.counts);
        let (_, gv) = slice_set(
            &g,
            &proj,
            Split::Validation { seed: 2024 },
            PopulationKind::Procedural,
            2,
            1,
            &lv,
        )
        .unwrap();
        assert_ne!(gt, gv);
        let pop = Population::for_geometry(&g);
        let want = generate(&pop.draw(2024, 19))
            .unwrap()
            .glandularity()
            .unwrap();
        assert_eq!(gv[1], want);
    }

    #[test]
    fn tiny_evaluation_runs_and_mltr_beats_fbp() {
        let opts = BaselineOptions {
            geometry: Geometry::paper().binned(4).unwrap(),
            split: Split::Test,
            population: PopulationKind::Procedural,
            phantoms: 1,
            slices_per_phantom: 2,
            iterations: 20,
            levels: vec![NoiseLevel::NoiseFree, NoiseLevel::Poisson(8)],
        };
        let r = evaluate_baselines(&opts, &[]).unwrap();
        assert_eq!(r.rows.len(), 4);
        assert_eq!(r.slices.len(), 2);
        for row in &r.rows {
            assert_eq!(row.n, 2);
            assert!(row.l2.mean.is_finite() && row.ssim.mean <= 1.0);
        }
        // MLTR is quantitative, limited-angle FBP is not: MLTR's L2 is lower.
        assert!(r.rows[0].l2.mean < r.rows[2].l2.mean);
        assert!(table(&r).contains("| MLTR | noise-free |"));
        // The regions' shares cover every window; every slice has windows
        // across the outline and in air.
        for row in &r.rows {
            let g = &row.ssim_regions;
            let share = g.inside.share + g.outline.share + g.air.share;
            assert!((share - 1.0).abs() < 1e-12, "shares sum to {share}");
            assert!(g.outline.n == 2 && g.air.n == 2);
        }
        assert!(region_table(&r).contains("| MLTR | noise-free |"));
    }
}
