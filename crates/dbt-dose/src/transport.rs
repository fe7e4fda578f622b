//! Photon transport: analytic flights in the world and homogeneous boxes,
//! Woodcock (delta) tracking in the voxel grid, interactions sampled from the
//! material's partial coefficients. Photons are split into a fixed number of
//! batches, each with its own ChaCha8 stream, so results are reproducible for
//! a seed whatever the number of threads, and the batch means give the
//! statistical uncertainty (batch method).

use crate::material::{Material, Mu};
use crate::physics::{rotate, sample_compton, sample_rayleigh};
use crate::scene::{ray_box, Region, Scene};
use crate::spectrum::Spectrum;
use crate::DoseError;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;
use std::f64::consts::PI;

/// Step past a boundary, mm, so that a photon on a face is unambiguously on
/// one side of it (a grazing photon cannot bounce between two regions).
const NUDGE_MM: f64 = 1e-7;

/// Photons below this energy deposit locally (the tables start at 1 keV).
pub const CUTOFF_KEV: f64 = 1.0;

/// An isotropic point source collimated to a rectangle (the detector).
#[derive(Debug, Clone)]
pub struct PointSource {
    /// Focal spot, mm.
    pub position: [f64; 3],
    /// Centre of the field rectangle, mm.
    pub field_centre: [f64; 3],
    /// Unit vectors spanning the rectangle (orthogonal).
    pub field_axes: [[f64; 3]; 2],
    /// Half-sizes along the two axes, mm.
    pub field_half: [f64; 2],
    /// Energies.
    pub spectrum: Spectrum,
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

impl PointSource {
    /// A field rectangle `[x0, x1] x [y0, y1]` in the plane `z = z`.
    pub fn rect_z(
        position: [f64; 3],
        x: [f64; 2],
        y: [f64; 2],
        z: f64,
        spectrum: Spectrum,
    ) -> Self {
        Self {
            position,
            field_centre: [(x[0] + x[1]) / 2.0, (y[0] + y[1]) / 2.0, z],
            field_axes: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            field_half: [(x[1] - x[0]).abs() / 2.0, (y[1] - y[0]).abs() / 2.0],
            spectrum,
        }
    }

    fn normal(&self) -> [f64; 3] {
        let [u, v] = self.field_axes;
        [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ]
    }

    /// Distance from the source to the field plane, and the source's foot in
    /// the rectangle's coordinates.
    fn foot(&self) -> (f64, [f64; 2]) {
        let rel = sub(self.position, self.field_centre);
        let h = dot(rel, self.normal()).abs();
        (
            h,
            [dot(rel, self.field_axes[0]), dot(rel, self.field_axes[1])],
        )
    }

    /// Maximum of the hit density `(h / r)^3` over the rectangle.
    fn max_density(&self) -> f64 {
        let (h, f) = self.foot();
        let nx = f[0].clamp(-self.field_half[0], self.field_half[0]) - f[0];
        let ny = f[1].clamp(-self.field_half[1], self.field_half[1]) - f[1];
        (h / (nx * nx + ny * ny + h * h).sqrt()).powi(3)
    }

    /// Solid angle of the field seen from the source, sr.
    pub fn solid_angle(&self) -> f64 {
        let (h, f) = self.foot();
        let xs = [-self.field_half[0] - f[0], self.field_half[0] - f[0]];
        let ys = [-self.field_half[1] - f[1], self.field_half[1] - f[1]];
        let g = |x: f64, y: f64| (x * y / (h * (h * h + x * x + y * y).sqrt())).atan();
        g(xs[1], ys[1]) - g(xs[0], ys[1]) - g(xs[1], ys[0]) + g(xs[0], ys[0])
    }

    /// Direction uniform in solid angle within the field: a point of the
    /// rectangle with density proportional to `h / r^3`, by rejection.
    #[inline]
    fn emit<R: Rng>(&self, rng: &mut R, h: f64, max_density: f64) -> [f64; 3] {
        let s = self.position;
        let [u, v] = self.field_axes;
        loop {
            let a = (2.0 * rng.random::<f64>() - 1.0) * self.field_half[0];
            let b = (2.0 * rng.random::<f64>() - 1.0) * self.field_half[1];
            let c = self.field_centre;
            let d = [
                c[0] + a * u[0] + b * v[0] - s[0],
                c[1] + a * u[1] + b * v[1] - s[1],
                c[2] + a * u[2] + b * v[2] - s[2],
            ];
            let r = dot(d, d).sqrt();
            if rng.random::<f64>() * max_density <= (h / r).powi(3) {
                return [d[0] / r, d[1] / r, d[2] / r];
            }
        }
    }
}

/// Scoring of the photons that reach the source's field rectangle, the
/// detector (issue #27: primary and scattered signal). A photon crossing
/// the rectangle from the source's side ends there (nothing lies behind
/// the detector in our scenes, so the breast's dose is unchanged); its
/// signal is `E (1 - exp(-mu(E) t / cos a))` for an absorber layer of
/// thickness `t` met at incidence `a` (the energy of the photons the layer
/// stops, which an energy-integrating detector records; K-fluorescence
/// escape neglected as in `dbt_forward::clinical`), or `E` without
/// one (the energy fluence: an ideal detector).
#[derive(Debug, Clone)]
pub struct DetectorScore {
    /// Pixel side, mm.
    pub pixel_mm: f64,
    /// The absorber and its thickness, mm; `None`: every photon's energy.
    pub absorber: Option<(Material, f64)>,
    /// A virtual detector: photons are recorded where they cross the
    /// horizontal plane `z = gate` downward (in the world material: the
    /// underside of the breast support), at the point where their line
    /// meets the detector plane, ahead or behind. For a geometry whose
    /// detector rises into the breast (the paper's detector rotating with
    /// the source: 24 degrees lifts a 256 mm detector's edge 52 mm, through
    /// the support), the signal a detector under the support would see,
    /// mapped onto the rotating detector's pixels along each photon's line,
    /// as the projector maps each ray (air between the support and the
    /// detector neglected). `None`: the detector plane itself.
    pub gate_z_mm: Option<f64>,
}

impl DetectorScore {
    /// Pixels `[n0, n1]` along the source's field axes 0 and 1; pixel
    /// `(i, j)` is at index `j * n0 + i`, `i` counting from the rectangle's
    /// `-field_half[0]` edge (likewise `j`).
    pub fn dims(&self, source: &PointSource) -> [usize; 2] {
        source
            .field_half
            .map(|h| ((2.0 * h / self.pixel_mm).round() as usize).max(1))
    }

    /// The signal of a photon of `e` keV arriving at incidence cosine `cos_a`.
    pub fn response(&self, e: f64, cos_a: f64) -> f64 {
        match &self.absorber {
            None => e,
            Some((m, t)) => e * (1.0 - (-m.mu(e).total() * t / cos_a.max(1e-6)).exp()),
        }
    }
}

/// A [`DetectorScore`] placed on a source's field rectangle.
struct Scorer<'a> {
    score: &'a DetectorScore,
    centre: [f64; 3],
    axes: [[f64; 3]; 2],
    normal: [f64; 3],
    half: [f64; 2],
    dims: [usize; 2],
    /// Sign of the source's side of the plane along `normal`.
    side: f64,
}

impl<'a> Scorer<'a> {
    fn new(score: &'a DetectorScore, source: &PointSource) -> Result<Self, DoseError> {
        if !(score.pixel_mm.is_finite() && score.pixel_mm > 0.0) {
            return Err(DoseError::Scene(format!(
                "detector pixel {} mm must be a positive number",
                score.pixel_mm
            )));
        }
        if let Some((_, t)) = &score.absorber {
            if !(t.is_finite() && *t > 0.0) {
                return Err(DoseError::Scene(format!(
                    "detector absorber {t} mm must be a positive number"
                )));
            }
        }
        let normal = source.normal();
        let side = dot(sub(source.position, source.field_centre), normal).signum();
        Ok(Self {
            score,
            centre: source.field_centre,
            axes: source.field_axes,
            normal,
            half: source.field_half,
            dims: score.dims(source),
            side,
        })
    }

    /// Where the flight from `p` along `d` is recorded: distance to the
    /// recording (the gate or the detector), pixel and incidence cosine;
    /// `None` if it is not (moving away, parallel, or outside the
    /// rectangle).
    #[inline]
    fn hit(&self, p: [f64; 3], d: [f64; 3]) -> Option<(f64, usize, f64)> {
        let h = dot(sub(p, self.centre), self.normal);
        let dn = dot(d, self.normal);
        let t = match self.score.gate_z_mm {
            Some(z) => {
                // A photon leaving a box whose underside is the gate
                // starts a nudge below it.
                if p[2] < z - 10.0 * NUDGE_MM || d[2] >= 0.0 || dn * self.side >= 0.0 {
                    return None;
                }
                ((z - p[2]) / d[2]).max(0.0)
            }
            None => {
                if h * self.side <= 0.0 || dn * self.side >= 0.0 {
                    return None;
                }
                -h / dn
            }
        };
        // The line's meeting with the detector plane (from p: -h / dn).
        let q = sub(advance(p, d, -h / dn), self.centre);
        let pix = self.score.pixel_mm;
        let index = |k: usize| {
            let a = dot(q, self.axes[k]);
            (a.abs() < self.half[k])
                .then(|| (((a + self.half[k]) / pix) as usize).min(self.dims[k] - 1))
        };
        let (i, j) = (index(0)?, index(1)?);
        Some((t, j * self.dims[0] + i, dn.abs()))
    }
}

/// Index of a region in [`Tallies::detector_scatter`].
fn origin_index(r: Region) -> usize {
    match r {
        Region::Grid => 0,
        Region::World => 1,
        Region::Box(i) => 2 + i,
    }
}

/// Energy bookkeeping of a run or a batch, keV.
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct Tallies {
    /// Photons emitted.
    pub photons: u64,
    /// Energy emitted.
    pub emitted_kev: f64,
    /// Energy deposited per material.
    pub deposited_kev: Vec<f64>,
    /// Energy deposited per grid tally.
    pub tally_kev: Vec<f64>,
    /// Energy that left the world.
    pub escaped_kev: f64,
    /// Interactions by type: photoelectric, Rayleigh, Compton.
    pub interactions: [u64; 3],
    /// Photons that left the world without any interaction (primary
    /// transmission).
    pub uncollided_escaped: u64,
    /// Energy deposited in glandular tissue (per the materials' glandular
    /// weights).
    pub glandular_kev: f64,
    /// With a [`DetectorScore`]: the signal (keV, per the score's response)
    /// of photons reaching the detector without any interaction, per pixel
    /// (see [`DetectorScore::dims`] for the layout); empty otherwise.
    pub detector_primary: Vec<f64>,
    /// As `detector_primary`, of photons that interacted at least once, by
    /// the region of their first interaction: the image of region `o` at
    /// `o * pixels`, regions in the order `[grid, world, box 0, box 1, ...]`.
    pub detector_scatter: Vec<f64>,
}

impl Tallies {
    fn new(nm: usize, nt: usize) -> Self {
        Self {
            deposited_kev: vec![0.0; nm],
            tally_kev: vec![0.0; nt],
            ..Default::default()
        }
    }

    fn with_detector(mut self, pixels: usize, origins: usize) -> Self {
        self.detector_primary = vec![0.0; pixels];
        self.detector_scatter = vec![0.0; pixels * origins];
        self
    }

    fn add(&mut self, o: &Tallies) {
        self.photons += o.photons;
        self.emitted_kev += o.emitted_kev;
        self.escaped_kev += o.escaped_kev;
        for (a, b) in self.deposited_kev.iter_mut().zip(&o.deposited_kev) {
            *a += b;
        }
        for (a, b) in self.tally_kev.iter_mut().zip(&o.tally_kev) {
            *a += b;
        }
        for k in 0..3 {
            self.interactions[k] += o.interactions[k];
        }
        self.uncollided_escaped += o.uncollided_escaped;
        self.glandular_kev += o.glandular_kev;
        for (a, b) in [
            (&mut self.detector_primary, &o.detector_primary),
            (&mut self.detector_scatter, &o.detector_scatter),
        ] {
            for (x, y) in a.iter_mut().zip(b) {
                *x += y;
            }
        }
    }
}

/// A run: the totals and the per-batch tallies.
#[derive(Debug, Clone, Serialize)]
pub struct RunResult {
    /// Sum over batches.
    pub total: Tallies,
    /// Each batch.
    pub batches: Vec<Tallies>,
}

impl RunResult {
    /// Mean per emitted photon of `f(batch) / photons(batch)` and its standard
    /// error from the spread of the batch means.
    pub fn per_photon(&self, f: impl Fn(&Tallies) -> f64) -> (f64, f64) {
        let mean = f(&self.total) / self.total.photons.max(1) as f64;
        let n = self.batches.len();
        if n < 2 {
            return (mean, f64::NAN);
        }
        let v: Vec<f64> = self
            .batches
            .iter()
            .map(|b| f(b) / b.photons.max(1) as f64)
            .collect();
        let m = v.iter().sum::<f64>() / n as f64;
        let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1) as f64;
        (mean, (var / n as f64).sqrt())
    }
}

struct Cache {
    e: f64,
    mu: Vec<Mu>,
    total: Vec<f64>,
    grid_max: f64,
}

impl Cache {
    fn update(&mut self, scene: &Scene, grid_mats: &[u8], e: f64) {
        if e == self.e {
            return;
        }
        self.e = e;
        for (i, m) in scene.materials.iter().enumerate() {
            self.mu[i] = m.mu(e);
            self.total[i] = self.mu[i].total();
        }
        self.grid_max = grid_mats
            .iter()
            .map(|&m| self.total[m as usize])
            .fold(0.0, f64::max);
    }
}

#[inline]
fn exp_sample<R: Rng>(rng: &mut R, mu: f64) -> f64 {
    if mu <= 0.0 {
        return f64::INFINITY;
    }
    -(1.0 - rng.random::<f64>()).ln() / mu
}

#[inline]
fn advance(p: [f64; 3], d: [f64; 3], s: f64) -> [f64; 3] {
    [p[0] + s * d[0], p[1] + s * d[1], p[2] + s * d[2]]
}

/// Outcome of an interaction.
enum After {
    Absorbed,
    Scattered,
}

#[allow(clippy::too_many_arguments)]
#[inline]
fn interact<R: Rng>(
    scene: &Scene,
    cache: &Cache,
    mat: usize,
    tally: u8,
    e: &mut f64,
    d: &mut [f64; 3],
    rng: &mut R,
    t: &mut Tallies,
) -> After {
    let mu = cache.mu[mat];
    let r = rng.random::<f64>() * cache.total[mat];
    let gw = scene.materials[mat].glandular_weight(*e);
    let deposit = |kev: f64, t: &mut Tallies| {
        t.deposited_kev[mat] += kev;
        t.glandular_kev += kev * gw;
        if tally > 0 {
            t.tally_kev[tally as usize - 1] += kev;
        }
    };
    if r < mu.photo {
        t.interactions[0] += 1;
        deposit(*e, t);
        return After::Absorbed;
    }
    let m = &scene.materials[mat];
    let (cos_t, e_out) = if r < mu.photo + mu.rayleigh {
        t.interactions[1] += 1;
        (sample_rayleigh(m, *e, rng), *e)
    } else {
        t.interactions[2] += 1;
        sample_compton(m, *e, rng)
    };
    deposit(*e - e_out, t);
    *e = e_out;
    *d = rotate(*d, cos_t, 2.0 * PI * rng.random::<f64>());
    if *e < CUTOFF_KEV {
        deposit(*e, t);
        return After::Absorbed;
    }
    After::Scattered
}

#[allow(clippy::too_many_arguments)]
fn track<R: Rng>(
    scene: &Scene,
    grid_mats: &[u8],
    cache: &mut Cache,
    mut p: [f64; 3],
    mut d: [f64; 3],
    mut e: f64,
    rng: &mut R,
    t: &mut Tallies,
    scorer: Option<&Scorer<'_>>,
) {
    let g = &scene.grid;
    let (gmin, gmax) = (g.origin, g.max());
    let mut region = scene.region_of(p);
    let before = t.interactions.iter().sum::<u64>();
    // Region of the first interaction (for the scatter's origin).
    let mut first: Option<usize> = None;
    loop {
        cache.update(scene, grid_mats, e);
        match region {
            Region::World => {
                // Nearest entry into the grid or a box along the ray.
                let mut best = (f64::INFINITY, Region::World);
                let (tn, tf) = ray_box(p, d, gmin, gmax);
                if tn <= tf && tf > 1e-9 {
                    best = (tn.max(0.0), Region::Grid);
                }
                for (i, b) in scene.boxes.iter().enumerate() {
                    let (tn, tf) = ray_box(p, d, b.min, b.max);
                    if tn <= tf && tf > 1e-9 && tn.max(0.0) < best.0 {
                        best = (tn.max(0.0), Region::Box(i));
                    }
                }
                let (_, t_exit) = ray_box(p, d, scene.world_min, scene.world_max);
                let wm = scene.world_material as usize;
                let s = exp_sample(rng, cache.total[wm]);
                if let Some((t_hit, pix, cos_a)) = scorer.and_then(|sc| sc.hit(p, d)) {
                    if t_hit < s.min(best.0).min(t_exit) {
                        // The photon ends on the detector.
                        let signal = scorer.map_or(0.0, |sc| sc.score.response(e, cos_a));
                        t.escaped_kev += e;
                        match first {
                            None => {
                                t.uncollided_escaped += 1;
                                t.detector_primary[pix] += signal;
                            }
                            Some(o) => {
                                let n = t.detector_primary.len();
                                t.detector_scatter[o * n + pix] += signal;
                            }
                        }
                        return;
                    }
                }
                if s < best.0.min(t_exit) {
                    p = advance(p, d, s);
                    first.get_or_insert(origin_index(Region::World));
                    if let After::Absorbed = interact(scene, cache, wm, 0, &mut e, &mut d, rng, t) {
                        return;
                    }
                } else if best.0 <= t_exit && best.1 != Region::World {
                    p = advance(p, d, best.0 + NUDGE_MM);
                    region = best.1;
                } else {
                    t.escaped_kev += e;
                    if t.interactions.iter().sum::<u64>() == before {
                        t.uncollided_escaped += 1;
                    }
                    return;
                }
            }
            Region::Box(i) => {
                let b = &scene.boxes[i];
                let (_, t_exit) = ray_box(p, d, b.min, b.max);
                let m = b.material as usize;
                let s = exp_sample(rng, cache.total[m]);
                if s < t_exit {
                    p = advance(p, d, s);
                    first.get_or_insert(origin_index(Region::Box(i)));
                    if let After::Absorbed = interact(scene, cache, m, 0, &mut e, &mut d, rng, t) {
                        return;
                    }
                } else {
                    p = advance(p, d, t_exit.max(0.0) + NUDGE_MM);
                    region = Region::World;
                }
            }
            Region::Grid => {
                let (_, t_exit) = ray_box(p, d, gmin, gmax);
                let t_exit = t_exit.max(0.0);
                let mu_max = cache.grid_max;
                let mut travelled = 0.0;
                loop {
                    let s = exp_sample(rng, mu_max);
                    if travelled + s >= t_exit {
                        p = advance(p, d, t_exit + NUDGE_MM);
                        region = Region::World;
                        break;
                    }
                    travelled += s;
                    let q = advance(p, d, travelled);
                    let idx = g.index(q);
                    let m = g.material[idx] as usize;
                    if rng.random::<f64>() * mu_max < cache.total[m] {
                        p = q;
                        first.get_or_insert(origin_index(Region::Grid));
                        match interact(scene, cache, m, g.tally[idx], &mut e, &mut d, rng, t) {
                            After::Absorbed => return,
                            After::Scattered => break,
                        }
                    }
                }
            }
        }
    }
}

/// Simulate `photons` photons from `source` in `scene`, in `batches` batches.
pub fn run(
    scene: &Scene,
    source: &PointSource,
    photons: u64,
    batches: usize,
    seed: u64,
) -> Result<RunResult, DoseError> {
    run_observed(scene, source, photons, batches, seed, &|| {})
}

/// As [`run`], calling `on_batch` as each batch finishes (from the worker
/// threads, in no particular order): for a progress display. The result
/// does not depend on it.
pub fn run_observed(
    scene: &Scene,
    source: &PointSource,
    photons: u64,
    batches: usize,
    seed: u64,
    on_batch: &(dyn Fn() + Sync),
) -> Result<RunResult, DoseError> {
    run_inner(scene, source, photons, batches, seed, None, on_batch)
}

/// As [`run`], scoring the photons that reach the source's field rectangle
/// (the detector) with `score`: [`Tallies::detector_primary`] and
/// [`Tallies::detector_scatter`]. The
/// photons that reach it end there, so the detector's scene must hold
/// nothing behind the rectangle that could scatter back.
pub fn run_scored(
    scene: &Scene,
    source: &PointSource,
    photons: u64,
    batches: usize,
    seed: u64,
    score: &DetectorScore,
) -> Result<RunResult, DoseError> {
    let scorer = Scorer::new(score, source)?;
    run_inner(scene, source, photons, batches, seed, Some(&scorer), &|| {})
}

fn run_inner(
    scene: &Scene,
    source: &PointSource,
    photons: u64,
    batches: usize,
    seed: u64,
    scorer: Option<&Scorer<'_>>,
    on_batch: &(dyn Fn() + Sync),
) -> Result<RunResult, DoseError> {
    scene.validate()?;
    if photons == 0 || batches == 0 {
        return Err(DoseError::Scene(
            "photons and batches must be positive".into(),
        ));
    }
    if scene.region_of(source.position) != Region::World {
        return Err(DoseError::Scene(
            "the source lies inside the grid or a box".into(),
        ));
    }
    let grid_mats = scene.grid_summary().0.clone();
    let nm = scene.materials.len();
    let maxd = source.max_density();
    let origins = 2 + scene.boxes.len();
    let new_tallies = || {
        let t = Tallies::new(nm, scene.n_tallies);
        match scorer {
            Some(sc) => t.with_detector(sc.dims[0] * sc.dims[1], origins),
            None => t,
        }
    };
    let (h, _) = source.foot();
    let results: Vec<Tallies> = (0..batches)
        .into_par_iter()
        .map(|b| {
            let _span = tracing::trace_span!("mc_batch", b).entered();
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream(b as u64);
            let n = photons / batches as u64 + u64::from((b as u64) < photons % batches as u64);
            let mut t = new_tallies();
            let mut cache = Cache {
                e: f64::NAN,
                mu: vec![Mu::default(); nm],
                total: vec![0.0; nm],
                grid_max: 0.0,
            };
            for _ in 0..n {
                let e = source.spectrum.sample(&mut rng);
                let d = source.emit(&mut rng, h, maxd);
                t.photons += 1;
                t.emitted_kev += e;
                track(
                    scene,
                    &grid_mats,
                    &mut cache,
                    source.position,
                    d,
                    e,
                    &mut rng,
                    &mut t,
                    scorer,
                );
            }
            on_batch();
            t
        })
        .collect();
    let mut total = new_tallies();
    for r in &results {
        total.add(r);
    }
    Ok(RunResult {
        total,
        batches: results,
    })
}
