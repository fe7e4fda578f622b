//! A physics-based volumetric breast density from the projections
//! (issue #48 point 2): no learning, of the kind Volpara reports (Highnam
//! et al., IWDM 2010; van Engeland et al. 2006, IEEE TMI 25:273), so that
//! every acquisition carries a second density made from the same counts by
//! another road than the network's.
//!
//! # The model, per ray of one projection
//! The counts are the primary's, on the 20 keV scale the network reads (the
//! pipeline removes the scatter and linearises the beam hardening first;
//! a mono-energetic acquisition is already that). A ray's line integral
//! `A = ln(b / c)` is that of skin, fat and dense tissue along its path `L`
//! through the breast:
//!
//! `A = mu_s S + mu_f (L_i - h) + mu_d h`,  `L_i = L - S`,
//!
//! with `S = 2 s sec a` the skin crossed at the paddle and the support (`s`
//! the nominal skin thickness, [`Options::skin_mm`]; `a` the ray's angle to
//! the vertical), `L_i` the interior path and `h` its dense share. The
//! coefficients are the paper's at 20 keV ([`dbt_materials::Tissue::mu_per_mm`]:
//! the tables the simulator, the linearisation and the classifier share).
//! Where the path is known, `h = (A - mu_s S - mu_f L_i) / (mu_d - mu_f)`,
//! clipped to `[0, L_i]`. Volumes add the rays' wedges: a ray of view `v`
//! and element `k` holds, per mm of depth, `w_k L` mm^2 of breast (`w_k` its
//! wedge's area inside the slab divided by its path there); so FGV
//! `= dy sum w h`, interior volume `= dy sum w L_i`, and the glandularity
//! by mass `1.04 FGV / (1.04 FGV + 0.93 (V_i - FGV))` (Hammerstein's
//! densities, as the truth's eq. 4: skin excluded).
//!
//! # The path: a thickness plane that calibrates itself on fat
//! In the contact region (farther than `T/2 + 5 mm` from the skin line, where
//! the breast fills the gap between paddle and support) the path is
//! `T(x, y) sec a`, `T` a plane. Fat is the least attenuating breast tissue, so
//! a ray's all-fat path `t_f` (the longest path its signal allows, as
//! vertical thickness) bounds the breast's thickness there from above: the
//! fattest rays of each 10 mm tile (their 2 % quantile, of the signal
//! smoothed over `+-2 mm` so that noise does not pull the quantile down)
//! give the plane, fitted to the tiles' lower envelope (tiles more than
//! 1 mm above the plane are dropped and the plane refitted: tiles without
//! fat do not lift it). The fitted plane only ever *thins* the breast, and
//! by at most [`Options::thinner_max_mm`] below the readout (our choice:
//! compression-thickness indicators are specified to a few mm, and a paddle's
//! tilt over a breast is of that order, Kallenberg and Karssemeijer 2012,
//! PMB 57:703; a larger disagreement is flagged, not followed). A breast
//! without fat gives tiles whose fattest rays read thicker than the readout:
//! the readout stands, and the breast is not fitted away (issue #48's
//! failure mode of relative methods). A readout that is too thin is not
//! corrected but shows as contact rays denser than dense tissue
//! ([`ViewDensity::over_dense_share`], flagged above 5 %).
//!
//! The plane is fitted twice ([`Options::contact_refit`]): after the rim's
//! edge model (below) is fitted, again from the tiles beyond each sector's
//! fitted rim width (and 5 mm), and the rim then refitted to it. A breast
//! that tapers over a rim wider than half its thickness otherwise pulls the
//! plane down with its thinner rim's fattest rays (decided on the
//! validation splits, eval/physics-density.md).
//!
//! # The rim: an edge profile fitted per sector
//! Nearer the skin line the breast leaves the paddle. Its vertical chord at
//! distance `d` from the skin line (the projection's silhouette, in mm at the
//! breast's mid-height, the chest wall not counted as a skin line) is
//! modelled as `T p(d)`, `p(d) = [1 - ((a - d) / a)^r]^(1/r)` for `d < a`, 1
//! beyond (the hyperellipse of NifTK's fat-edge fit; Snoeren and
//! Karssemeijer 2004, IEEE TMI 23:799, for the periphery's model), with `(a,
//! r)` fitted in each of [`Options::sectors`] angular sectors (around the
//! chest wall's midpoint) to the lower envelope (5 % quantile per 1 mm of
//! `d`) of the rays' all-fat thickness relative to the plane: the fattest rays
//! at each distance give the shape. A ray's path is the model's, and never
//! longer than its all-fat path. The rim's share of the breast volume is
//! reported: the estimate rests on the edge model there. One profile for
//! every sector ([`RimShape::Shared`], [`RimShape::Thinnest`]) was tried
//! against this and not shipped (eval/physics-density.md, "The rim's
//! shape").
//!
//! # What it does not do (yet)
//! The silhouettes of the other projections (a visual hull) do not
//! constrain the rim; a dense rim reads the model's fat envelope (its dense
//! share underestimated); the skin is the nominal thickness (a skin 0.5 mm
//! thicker on each face reads about 1.2 mm more dense path); scatter left in
//! the counts reads as less attenuation (fat). Each view gives its own
//! estimate: the central view's is the figure, the others' spread its
//! consistency.

use dbt_geometry::Geometry;
use dbt_materials::Tissue;
use rayon::prelude::*;
use serde::Serialize;
use thiserror::Error;

/// Why no physics density can be made.
#[derive(Debug, Error, PartialEq)]
pub enum PhysicsDensityError {
    /// The counts do not have the geometry's shape.
    #[error("counts: slice {slice} holds {got} values, the geometry's {views} views x {elements} elements make {want}")]
    Shape {
        /// The first slice of the wrong length.
        slice: usize,
        /// Its length.
        got: usize,
        /// The geometry's views.
        views: usize,
        /// The geometry's elements.
        elements: usize,
        /// views x elements.
        want: usize,
    },
    /// A count that is not a finite number.
    #[error("count {value} at slice {slice}, ray {ray}: not a finite number")]
    Count {
        /// The slice.
        slice: usize,
        /// The ray (view-major).
        ray: usize,
        /// The value.
        value: f32,
    },
    /// A setting or header value out of range.
    #[error("{field} = {value}: {reason}")]
    Invalid {
        /// The field.
        field: &'static str,
        /// Its value.
        value: f64,
        /// Why it is refused.
        reason: &'static str,
    },
    /// No ray of the view attenuated above its noise.
    #[error("view {view}: no ray crosses the breast (none attenuated above its noise)")]
    NoBreast {
        /// The view.
        view: usize,
    },
}

/// The settings; [`Options::default`] is the product's.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Options {
    /// Nominal skin thickness, mm (the known-path linearisation's).
    pub skin_mm: f64,
    /// Most the fitted plane may thin the breast below the readout, mm.
    pub thinner_max_mm: f64,
    /// Quantile of a tile's all-fat thickness taken as its fat, (0, 1).
    pub fat_quantile: f64,
    /// Tile side for the thickness plane, mm.
    pub tile_mm: f64,
    /// Angular sectors of the rim fit (around the chest wall's midpoint).
    pub sectors: usize,
    /// Widest rim the fit considers, mm.
    pub rim_max_mm: f64,
    /// Quantile of the rim's signal at each distance taken as its fat
    /// profile, (0, 1): the rim is taken to be mostly fat.
    pub rim_quantile: f64,
    /// Half-width of the box the signal is smoothed over, mm.
    pub smooth_mm: f64,
    /// A ray is inside the breast when its line integral exceeds this many
    /// standard deviations of its noise (`z / sqrt(c)`).
    pub noise_z: f64,
    /// Refit the thickness plane where the fitted edge model says the
    /// breast is in contact, then the edge model again (a second pass).
    pub contact_refit: bool,
    /// Which edge profile each sector's rays take (per sector as shipped;
    /// the others an evaluation option).
    pub rim_shape: RimShape,
}

/// Which edge profile each sector's rays take.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Default)]
pub enum RimShape {
    /// Each sector its own fit.
    #[default]
    PerSector,
    /// Every sector the fit to all sectors' envelope at once.
    Shared,
    /// Every sector the fitted sector profile of least area (the fattest
    /// sector's shape).
    Thinnest,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            skin_mm: 1.5,
            thinner_max_mm: 5.0,
            fat_quantile: 0.02,
            tile_mm: 10.0,
            sectors: 6,
            rim_max_mm: 60.0,
            rim_quantile: 0.25,
            smooth_mm: 2.0,
            noise_z: 6.0,
            contact_refit: true,
            rim_shape: RimShape::PerSector,
        }
    }
}

/// One acquisition's slice-wise projections (the pipeline's corrected,
/// rebinned counts).
#[derive(Debug, Clone, Copy)]
pub struct Input<'a> {
    /// The slice-wise fan geometry.
    pub geometry: &'a Geometry,
    /// Slice spacing (depth), mm.
    pub slice_spacing_mm: f64,
    /// The compression thickness readout, mm.
    pub thickness_mm: f64,
    /// Flat-field counts per ray.
    pub flux: f64,
    /// Counts `[slice][view * elements]`, slice 0 at the chest wall.
    pub counts: &'a [Vec<f32>],
}

/// The thickness plane of one view.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ThicknessFit {
    /// The readout, mm.
    pub readout_mm: f64,
    /// The plane at the contact region's centroid, as used (bounded), mm.
    pub centre_mm: f64,
    /// Thinnest and thickest the plane is over the contact region, as used, mm.
    pub range_mm: [f64; 2],
    /// The fitted plane's slopes across (x) and along (depth) the breast,
    /// mm per cm, before bounding.
    pub slope_mm_per_cm: [f64; 2],
    /// Tiles that held the fat (after the lower-envelope refits).
    pub tiles: usize,
    /// Whether the plane asked for more thinning than allowed somewhere.
    pub at_bound: bool,
}

/// The edge model of one sector.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RimSector {
    /// The sector's angles, degrees from the nipple direction (negative:
    /// toward the first detector element).
    pub from_deg: f64,
    /// See `from_deg`.
    pub to_deg: f64,
    /// The rim's width `a`, mm.
    pub width_mm: f64,
    /// The profile's exponent `r` (2: an ellipse).
    pub exponent: f64,
    /// Rays of the sector within the fitted distances.
    pub rays: usize,
    /// RMS of the envelope about the profile, relative to the thickness.
    pub misfit: f64,
    /// Whether the sector had too few distances to fit (the all-sector fit used).
    pub fallback: bool,
}

/// The estimate from one view.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ViewDensity {
    /// The view.
    pub view: usize,
    /// Its angle, degrees.
    pub angle_deg: f64,
    /// Fibroglandular volume, cm^3.
    pub fgv_cm3: f64,
    /// Breast volume (skin included), cm^3.
    pub bv_cm3: f64,
    /// Interior volume (skin excluded), cm^3.
    pub interior_cm3: f64,
    /// Volumetric density of the interior, FGV / interior volume.
    pub vbd: f64,
    /// Glandularity by mass (the truth's eq. 4).
    pub glandularity: f64,
    /// The rim's share of the breast volume.
    pub rim_share: f64,
    /// Glandularity by mass of the contact region alone (where the path is
    /// the thickness plane's: no edge model).
    pub contact_glandularity: f64,
    /// Share of the contact region denser than dense tissue over its path.
    pub over_dense_share: f64,
    /// Whether the breast reaches the detector's ends.
    pub truncated: bool,
    /// The thickness plane.
    pub thickness: ThicknessFit,
    /// The rim's sectors.
    pub rim: Vec<RimSector>,
    /// Which rays the contact region holds (where the path is the thickness
    /// plane's), for comparing another estimate over the same tissue.
    #[serde(skip)]
    pub contact: ContactMap,
    /// The breast's outline as this view's paths give it, ray by ray: the
    /// model breast of a report without a reconstruction (issue #51 point
    /// 3).
    #[serde(skip)]
    pub outline: Outline,
}

/// The breast's outline from one view's paths: for each ray (slice,
/// element), the vertical extent of its path through the breast (skin
/// included; 0 outside the breast) and the height of that extent's middle
/// above the support. In contact the extent is the thickness plane's from
/// the support up; in the rim it is the edge model's chord, about the
/// plane's mid-height (the hyperellipse is symmetric).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Outline {
    /// Each element's ray's x at the breast's mid-height, mm.
    pub x_mid_mm: Vec<f64>,
    /// Slice spacing (depth), mm.
    pub slice_mm: f64,
    /// `[slice * elements + element]`: the path's vertical extent, mm.
    pub chord_mm: Vec<f32>,
    /// `[slice * elements + element]`: the extent's middle above the
    /// support, mm.
    pub mid_mm: Vec<f32>,
    /// `[slice * elements + element]`: the dense share of the ray's
    /// interior path (its dense path over its path less the skin, clipped
    /// to `[0, 1]`; noisy ray by ray, unbiased only in the sum).
    pub dense_share: Vec<f32>,
}

impl Outline {
    /// The element whose ray passes nearest `x_mm` at the breast's
    /// mid-height; `None` beyond the detector ([`nearest_element`]).
    pub fn element_at(&self, x_mm: f64) -> Option<usize> {
        nearest_element(&self.x_mid_mm, x_mm)
    }
}

/// The contact region of one view, ray by ray.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ContactMap {
    /// Each element's ray's x at the breast's mid-height, mm (the
    /// geometry's frame).
    pub x_mid_mm: Vec<f64>,
    /// Slice spacing (depth), mm: slice `s` spans `[s dy, (s + 1) dy)`
    /// from the chest wall.
    pub slice_mm: f64,
    /// `[slice * elements + element]`: in the contact region.
    pub mask: Vec<bool>,
}

impl ContactMap {
    /// Whether the ray of the view through `(x_mm, depth_mm)` at the
    /// breast's mid-height (the nearest element's) is in the contact region;
    /// false outside the slices and beyond the detector.
    pub fn contains(&self, x_mm: f64, depth_mm: f64) -> bool {
        self.element_at(x_mm)
            .is_some_and(|k| self.holds(k, depth_mm))
    }

    /// The element whose ray passes nearest `x_mm` at the breast's
    /// mid-height; `None` beyond the detector ([`nearest_element`]).
    pub fn element_at(&self, x_mm: f64) -> Option<usize> {
        nearest_element(&self.x_mid_mm, x_mm)
    }

    /// Whether element `k`'s ray in the slice holding `depth_mm` is in the
    /// contact region; false outside the slices and the elements.
    pub fn holds(&self, k: usize, depth_mm: f64) -> bool {
        let nd = self.x_mid_mm.len();
        if k >= nd || self.slice_mm <= 0.0 || depth_mm.is_nan() || depth_mm < 0.0 {
            return false;
        }
        let s = (depth_mm / self.slice_mm) as usize;
        self.mask.get(s * nd + k).copied().unwrap_or(false)
    }
}

/// The element whose ray passes nearest `x_mm`, of rays crossing the
/// breast's mid-height at `x_mid_mm` (monotonic in the element, either
/// way); `None` for no rays, a NaN, or beyond the detector (half a pitch
/// past its ends). One rule for the contact map and the outline.
pub fn nearest_element(x_mid_mm: &[f64], x_mm: f64) -> Option<usize> {
    let nd = x_mid_mm.len();
    if nd == 0 {
        return None;
    }
    let (first, last) = (x_mid_mm[0], x_mid_mm[nd - 1]);
    let (lo, hi) = (first.min(last), first.max(last));
    let pitch = (hi - lo) / (nd - 1).max(1) as f64;
    if x_mm.is_nan() || x_mm < lo - pitch / 2.0 || x_mm > hi + pitch / 2.0 {
        return None;
    }
    // The rays' x is monotonic in the element.
    let k = match x_mid_mm.binary_search_by(|x| {
        if first <= last {
            x.total_cmp(&x_mm)
        } else {
            x_mm.total_cmp(x)
        }
    }) {
        Ok(k) => k,
        Err(0) => 0,
        Err(k) if k >= nd => nd - 1,
        Err(k) => {
            if (x_mid_mm[k] - x_mm).abs() < (x_mid_mm[k - 1] - x_mm).abs() {
                k
            } else {
                k - 1
            }
        }
    };
    Some(k)
}

/// The physics density of an acquisition.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PhysicsDensity {
    /// The central view's estimate: the figure.
    pub central: ViewDensity,
    /// Every view's `(angle_deg, glandularity)`.
    pub views: Vec<(f64, f64)>,
    /// Largest minus smallest of the views' glandularities, percentage points.
    pub spread_pp: f64,
    /// What a reader should know (the thickness plane at its bound, contact
    /// denser than dense tissue, a truncated breast, a rim-dominated estimate,
    /// disagreeing views).
    pub flags: Vec<String>,
}

/// Above this share of contact rays denser than dense tissue, flagged.
pub const OVER_DENSE_FLAG: f64 = 0.05;
/// Above this rim share of the breast volume, flagged.
pub const RIM_SHARE_FLAG: f64 = 0.6;
/// Above this spread between views, pp, flagged.
pub const SPREAD_FLAG_PP: f64 = 5.0;

/// The physics density of every view of `inp`; the central view's is the figure.
pub fn estimate(inp: &Input, opts: &Options) -> Result<PhysicsDensity, PhysicsDensityError> {
    check(inp, opts)?;
    let g = inp.geometry;
    let central = (0..g.n_views())
        .min_by(|&a, &b| g.angle_deg(a).abs().total_cmp(&g.angle_deg(b).abs()))
        .unwrap_or(0);
    // The views are independent: one per worker (each view's arithmetic is
    // its own, so the figures do not depend on the pool).
    let mut all = (0..g.n_views())
        .into_par_iter()
        .map(|v| view_estimate(inp, opts, v))
        .collect::<Result<Vec<_>, _>>()?;
    let views: Vec<(f64, f64)> = all.iter().map(|e| (e.angle_deg, e.glandularity)).collect();
    let central = all.swap_remove(central);
    let lo = views.iter().map(|v| v.1).fold(f64::INFINITY, f64::min);
    let hi = views.iter().map(|v| v.1).fold(f64::NEG_INFINITY, f64::max);
    let spread_pp = 100.0 * (hi - lo);
    let mut flags = Vec::new();
    let t = &central.thickness;
    if t.at_bound {
        flags.push(format!(
            "physics density: the fattest tissue asks for a breast more than {:.0} mm thinner than the {:.1} mm readout (the plane held at the bound)",
            opts.thinner_max_mm, t.readout_mm
        ));
    }
    if central.over_dense_share > OVER_DENSE_FLAG {
        flags.push(format!(
            "physics density: {:.0} % of the contact region is denser than dense tissue over the {:.1} mm readout (a readout too thin?)",
            100.0 * central.over_dense_share,
            t.readout_mm
        ));
    }
    if central.truncated {
        flags.push(
            "physics density: the breast reaches the detector's ends (volumes truncated)".into(),
        );
    }
    if central.rim_share > RIM_SHARE_FLAG {
        flags.push(format!(
            "physics density: the rim holds {:.0} % of the breast volume (the figure rests on the edge model)",
            100.0 * central.rim_share
        ));
    }
    if spread_pp > SPREAD_FLAG_PP {
        flags.push(format!(
            "physics density: the views disagree by {spread_pp:.1} pp"
        ));
    }
    Ok(PhysicsDensity {
        central,
        views,
        spread_pp,
        flags,
    })
}

fn invalid(field: &'static str, value: f64, reason: &'static str) -> PhysicsDensityError {
    PhysicsDensityError::Invalid {
        field,
        value,
        reason,
    }
}

fn check(inp: &Input, opts: &Options) -> Result<(), PhysicsDensityError> {
    let g = inp.geometry;
    let want = g.n_views() * g.n_det();
    for (s, row) in inp.counts.iter().enumerate() {
        if row.len() != want {
            return Err(PhysicsDensityError::Shape {
                slice: s,
                got: row.len(),
                views: g.n_views(),
                elements: g.n_det(),
                want,
            });
        }
        if let Some(r) = row.iter().position(|c| !c.is_finite()) {
            return Err(PhysicsDensityError::Count {
                slice: s,
                ray: r,
                value: row[r],
            });
        }
    }
    let pos = |field, v: f64| {
        if v.is_finite() && v > 0.0 {
            Ok(())
        } else {
            Err(invalid(field, v, "must be a positive number"))
        }
    };
    pos("thickness_mm", inp.thickness_mm)?;
    if inp.thickness_mm > g.height_mm() {
        return Err(invalid(
            "thickness_mm",
            inp.thickness_mm,
            "exceeds the geometry's image height",
        ));
    }
    pos("slice_spacing_mm", inp.slice_spacing_mm)?;
    pos("flux", inp.flux)?;
    if inp.counts.is_empty() {
        return Err(invalid("slices", 0.0, "no slice"));
    }
    pos("skin_mm", opts.skin_mm)?;
    if 2.0 * opts.skin_mm >= inp.thickness_mm {
        return Err(invalid(
            "skin_mm",
            opts.skin_mm,
            "two skins fill the compressed thickness",
        ));
    }
    pos("thinner_max_mm", opts.thinner_max_mm)?;
    pos("tile_mm", opts.tile_mm)?;
    pos("rim_max_mm", opts.rim_max_mm)?;
    pos("smooth_mm", opts.smooth_mm)?;
    pos("noise_z", opts.noise_z)?;
    let fraction = |field, v: f64| {
        if v > 0.0 && v < 1.0 {
            Ok(())
        } else {
            Err(invalid(field, v, "must lie in (0, 1)"))
        }
    };
    fraction("rim_quantile", opts.rim_quantile)?;
    fraction("fat_quantile", opts.fat_quantile)?;
    if opts.sectors == 0 {
        return Err(invalid("sectors", 0.0, "at least one sector"));
    }
    Ok(())
}

/// The paper's coefficients at 20 keV, 1/mm: fat, dense, skin.
fn mus() -> (f64, f64, f64) {
    (
        Tissue::Adipose.mu_per_mm() as f64,
        Tissue::Fibroglandular.mu_per_mm() as f64,
        Tissue::Skin.mu_per_mm() as f64,
    )
}

/// A ray's geometry at one view.
#[derive(Debug, Clone, Copy)]
struct RayGeom {
    /// Secant of its angle to the vertical.
    sec: f64,
    /// Its x at the slab's mid-height, mm.
    x_mid: f64,
    /// Its wedge's area in the slab per mm of path, mm.
    w: f64,
}

fn rays(g: &Geometry, v: usize, t: f64) -> Vec<RayGeom> {
    let src = g.source_mm(v);
    let z0 = g.support_z_mm();
    let (z1, zm) = (z0 + t, z0 + t / 2.0);
    let x_at = |d: (f64, f64), z: f64| src.0 + (z - src.1) * (d.0 - src.0) / (d.1 - src.1);
    let p = g.detector.pitch_mm;
    (0..g.n_det())
        .map(|k| {
            let u = g.element_u_mm(k);
            let d = g.detector_point_mm(v, u);
            let (dx, dz) = (d.0 - src.0, d.1 - src.1);
            let sec = (dx * dx + dz * dz).sqrt() / dz.abs();
            let (l, r) = (
                g.detector_point_mm(v, u - p / 2.0),
                g.detector_point_mm(v, u + p / 2.0),
            );
            let area =
                t * ((x_at(r, z0) - x_at(l, z0)).abs() + (x_at(r, z1) - x_at(l, z1)).abs()) / 2.0;
            RayGeom {
                sec,
                x_mid: x_at(d, zm),
                w: area / (t * sec),
            }
        })
        .collect()
}

/// The all-fat path of a ray (skin at the two faces, fat between): the
/// longest path its line integral allows.
fn fat_path(a: f64, skin_path: f64, mu_f: f64, mu_s: f64) -> f64 {
    if a <= mu_s * skin_path {
        a / mu_s
    } else {
        skin_path + (a - mu_s * skin_path) / mu_f
    }
}

/// Quantile `q` of `v` (sorted in place), linear between order statistics.
fn quantile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    let x = q * (v.len() - 1) as f64;
    let i = x.floor() as usize;
    let j = (i + 1).min(v.len() - 1);
    v[i] + (x - i as f64) * (v[j] - v[i])
}

/// Squared Euclidean distance to the nearest zero of `f` along positions
/// `pos` (Felzenszwalb and Huttenlocher's lower envelope of parabolas): `out[i]
/// = min_j (pos_i - pos_j)^2 + f_j`, over finite `f_j`.
fn edt1d(f: &[f64], pos: &[f64], out: &mut [f64]) {
    let n = f.len();
    let mut v: Vec<usize> = Vec::with_capacity(n);
    let mut z: Vec<f64> = Vec::with_capacity(n + 1);
    for q in 0..n {
        if !f[q].is_finite() {
            continue;
        }
        loop {
            match v.last() {
                None => {
                    v.push(q);
                    z.clear();
                    z.push(f64::NEG_INFINITY);
                    break;
                }
                Some(&p) => {
                    let s = ((f[q] + pos[q] * pos[q]) - (f[p] + pos[p] * pos[p]))
                        / (2.0 * (pos[q] - pos[p]));
                    if s <= *z.last().unwrap_or(&f64::NEG_INFINITY) {
                        v.pop();
                        z.pop();
                        continue;
                    }
                    v.push(q);
                    z.push(s);
                    break;
                }
            }
        }
    }
    if v.is_empty() {
        out.iter_mut().for_each(|o| *o = f64::INFINITY);
        return;
    }
    let mut k = 0;
    for i in 0..out.len() {
        while k + 1 < v.len() && z[k + 1] < pos[i] {
            k += 1;
        }
        let d = pos[i] - pos[v[k]];
        out[i] = d * d + f[v[k]];
    }
}

/// The profile `p(d) = [1 - ((a - d)/a)^r]^(1/r)` (1 beyond `a`).
fn profile(d: f64, a: f64, r: f64) -> f64 {
    if d >= a {
        1.0
    } else if d <= 0.0 {
        0.0
    } else {
        (1.0 - ((a - d) / a).powf(r)).max(0.0).powf(1.0 / r)
    }
}

const EXPONENTS: [f64; 11] = [1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0];

/// The edge model at distance `d` from the skin line, relative to the
/// thickness `t`: the breast's vertical chord `p(d; a, r)` and its
/// interior's, the outline shrunk by the skin `s` (`(1 - 2s/t) p(d - s; a -
/// s, r)`): in the contact region `1` and `1 - 2s/t`.
fn edge(d: f64, a: f64, r: f64, t: f64, s: f64) -> (f64, f64) {
    let c = profile(d, a, r);
    let inner = if a > s {
        profile(d - s, a - s, r)
    } else if d >= s {
        1.0
    } else {
        0.0
    };
    (c, (1.0 - 2.0 * s / t) * inner)
}

/// The all-fat breast's line integral per mm of thickness (vertical) at
/// distance `d`: skin over the chord less the interior, fat in the interior.
fn fat_signal(d: f64, a: f64, r: f64, t: f64, s: f64, mu_f: f64, mu_s: f64) -> f64 {
    let (c, ci) = edge(d, a, r, t, s);
    mu_s * (c - ci) + mu_f * ci
}

/// Fit `(a, r)` to the envelope `(d, A / (T sec a))` points; `(a, r, rms)`
/// (rms relative to the contact's all-fat signal).
fn fit_profile(
    env: &[(f64, f64)],
    a_max: f64,
    t: f64,
    s: f64,
    mu_f: f64,
    mu_s: f64,
) -> (f64, f64, f64) {
    let mut best = (a_max, 2.0, f64::INFINITY);
    let mut a = 0.5;
    while a <= a_max + 1e-9 {
        for &r in &EXPONENTS {
            let sse: f64 = env
                .iter()
                .map(|&(d, q)| (q - fat_signal(d, a, r, t, s, mu_f, mu_s)).powi(2))
                .sum();
            if sse < best.2 {
                best = (a, r, sse);
            }
        }
        a += 0.5;
    }
    let full = fat_signal(f64::INFINITY, 1.0, 2.0, t, s, mu_f, mu_s);
    (
        best.0,
        best.1,
        (best.2 / env.len().max(1) as f64).sqrt() / full,
    )
}

/// The estimate from view `v` alone.
pub fn estimate_view(
    inp: &Input,
    opts: &Options,
    v: usize,
) -> Result<ViewDensity, PhysicsDensityError> {
    check(inp, opts)?;
    if v >= inp.geometry.n_views() {
        return Err(invalid("view", v as f64, "beyond the geometry's views"));
    }
    view_estimate(inp, opts, v)
}

/// [`estimate_view`] of an input [`check`] passed and a view that exists.
fn view_estimate(
    inp: &Input,
    opts: &Options,
    v: usize,
) -> Result<ViewDensity, PhysicsDensityError> {
    let g = inp.geometry;
    let (mu_f, mu_d, mu_s) = mus();
    let dmu = mu_d - mu_f;
    let (ns, nd) = (inp.counts.len(), g.n_det());
    let t_read = inp.thickness_mm;
    let dy = inp.slice_spacing_mm;
    let geo = rays(g, v, t_read);
    let pitch_mid = (geo[nd - 1].x_mid - geo[0].x_mid).abs() / (nd - 1).max(1) as f64;
    // Line integrals and the silhouette.
    let mut a = vec![0f64; ns * nd];
    let mut inside = vec![false; ns * nd];
    for (s, row) in inp.counts.iter().enumerate() {
        for k in 0..nd {
            let c = (row[v * nd + k] as f64).max(0.5);
            let li = (inp.flux / c).ln().max(0.0);
            a[s * nd + k] = li;
            inside[s * nd + k] = li > opts.noise_z / c.sqrt();
        }
    }
    if !inside.iter().any(|&b| b) {
        return Err(PhysicsDensityError::NoBreast { view: v });
    }
    let truncated = (0..ns).any(|s| inside[s * nd] || inside[s * nd + nd - 1]);
    // The signal smoothed over the breast's rays (a summed-area table).
    let (hk, hs) = (
        (opts.smooth_mm / pitch_mid).round() as usize,
        (opts.smooth_mm / dy).round() as usize,
    );
    let w1 = nd + 1;
    let mut sa = vec![0f64; (ns + 1) * w1];
    let mut sm = vec![0f64; (ns + 1) * w1];
    for s in 0..ns {
        for k in 0..nd {
            let (m, x) = if inside[s * nd + k] {
                (1.0, a[s * nd + k])
            } else {
                (0.0, 0.0)
            };
            let i = (s + 1) * w1 + k + 1;
            sa[i] = x + sa[i - 1] + sa[i - w1] - sa[i - w1 - 1];
            sm[i] = m + sm[i - 1] + sm[i - w1] - sm[i - w1 - 1];
        }
    }
    let boxsum = |t: &[f64], s: usize, k: usize| {
        let (s0, s1) = (s.saturating_sub(hs), (s + hs + 1).min(ns));
        let (k0, k1) = (k.saturating_sub(hk), (k + hk + 1).min(nd));
        t[s1 * w1 + k1] - t[s0 * w1 + k1] - t[s1 * w1 + k0] + t[s0 * w1 + k0]
    };
    let smooth: Vec<f64> = (0..ns * nd)
        .map(|i| {
            if !inside[i] {
                return 0.0;
            }
            let (s, k) = (i / nd, i % nd);
            boxsum(&sa, s, k) / boxsum(&sm, s, k).max(1.0)
        })
        .collect();
    // Distance to the skin line, mm at mid-height: the rows' background
    // (the detector's ends beyond the last elements count as background),
    // then along depth (the chest wall is not a skin line; beyond the last
    // slice is background).
    let mut dx2 = vec![0f64; ns * nd];
    let x_before = geo[0].x_mid - (geo[1.min(nd - 1)].x_mid - geo[0].x_mid);
    let x_after = geo[nd - 1].x_mid + (geo[nd - 1].x_mid - geo[nd.saturating_sub(2)].x_mid);
    for s in 0..ns {
        let mut last = x_before;
        for k in 0..nd {
            if inside[s * nd + k] {
                let d = geo[k].x_mid - last;
                dx2[s * nd + k] = d * d;
            } else {
                last = geo[k].x_mid;
            }
        }
        let mut last = x_after;
        for k in (0..nd).rev() {
            if inside[s * nd + k] {
                let d = geo[k].x_mid - last;
                dx2[s * nd + k] = dx2[s * nd + k].min(d * d);
            } else {
                last = geo[k].x_mid;
            }
        }
    }
    let pos: Vec<f64> = (0..=ns).map(|s| (s as f64 + 0.5) * dy).collect();
    let mut dist = vec![0f64; ns * nd];
    let mut col = vec![0f64; ns + 1];
    let mut out = vec![0f64; ns + 1];
    for k in 0..nd {
        for s in 0..ns {
            col[s] = dx2[s * nd + k];
        }
        col[ns] = 0.0;
        edt1d(&col, &pos, &mut out);
        for s in 0..ns {
            dist[s * nd + k] = if inside[s * nd + k] {
                (out[s].sqrt() - pitch_mid.max(dy) / 2.0).max(0.0)
            } else {
                0.0
            };
        }
    }
    // Sectors by the direction to the nearest skin line (the distance's
    // descent: -90 degrees toward the first element's side, 0 toward the
    // nipple, +90 toward the last element's side).
    let nsec = opts.sectors;
    let grad = |i: usize| {
        let (s, k) = (i / nd, i % nd);
        let at = |s2: usize, k2: usize| {
            let j = s2 * nd + k2;
            if inside[j] {
                Some(dist[j])
            } else {
                None
            }
        };
        // The slope between the neighbours on either side, or between a
        // neighbour and this ray where the other is not breast (0 where
        // neither is).
        let here = (dist[i], 0.0);
        let slope = |lo: Option<(f64, f64)>, hi: Option<(f64, f64)>| {
            let ((a, pa), (b, pb)) = (lo.unwrap_or(here), hi.unwrap_or(here));
            if (pb - pa).abs() > 0.0 {
                (b - a) / (pb - pa)
            } else {
                0.0
            }
        };
        let kx = |k2: usize| geo[k2].x_mid - geo[k].x_mid;
        let left = if k > 0 {
            at(s, k - 1).map(|d| (d, kx(k - 1)))
        } else {
            None
        };
        let right = if k + 1 < nd {
            at(s, k + 1).map(|d| (d, kx(k + 1)))
        } else {
            None
        };
        let gx = slope(left, right);
        let ky = |s2: usize| pos[s2] - pos[s];
        let back = if s > 0 {
            at(s - 1, k).map(|d| (d, ky(s - 1)))
        } else {
            None
        };
        let fwd = if s + 1 < ns {
            at(s + 1, k).map(|d| (d, ky(s + 1)))
        } else {
            Some((0.0, ky(s) + dy))
        };
        let gy = slope(back, fwd);
        (gx, gy)
    };
    let sector: Vec<usize> = (0..ns * nd)
        .map(|i| {
            if !inside[i] {
                return 0;
            }
            let (gx, gy) = grad(i);
            // The skin line lies down the gradient.
            let ang = (-gx).atan2((-gy).max(0.0)).to_degrees();
            (((ang + 90.0) / 180.0 * nsec as f64).floor().max(0.0) as usize).min(nsec - 1)
        })
        .collect();
    let sector_of = |s: usize, k: usize| sector[s * nd + k];
    // The all-fat vertical thickness of each breast ray (smoothed signal).
    let skin_path = |k: usize| 2.0 * opts.skin_mm * geo[k].sec;
    let t_fat = |i: usize| {
        let k = i % nd;
        fat_path(smooth[i], skin_path(k), mu_f, mu_s) / geo[k].sec
    };
    // The thickness plane from the deep contact's fattest rays per tile.
    let x_lo = geo.iter().map(|r| r.x_mid).fold(f64::INFINITY, f64::min);
    let fit_plane = |deep: &dyn Fn(usize) -> bool| -> (Option<Plane>, Vec<(f64, f64, f64)>) {
        let mut tiles: std::collections::BTreeMap<(usize, usize), Vec<usize>> = Default::default();
        for (i, _) in inside.iter().enumerate().filter(|&(i, &b)| b && deep(i)) {
            let (s, k) = (i / nd, i % nd);
            let key = (
                ((geo[k].x_mid - x_lo) / opts.tile_mm) as usize,
                (pos[s] / opts.tile_mm) as usize,
            );
            tiles.entry(key).or_default().push(i);
        }
        let mut pts: Vec<(f64, f64, f64)> = Vec::new();
        for idx in tiles.values() {
            if idx.len() < 20 {
                continue;
            }
            let mut tf: Vec<f64> = idx.iter().map(|&i| t_fat(i)).collect();
            let q = quantile(&mut tf, opts.fat_quantile);
            let xm = idx.iter().map(|&i| geo[i % nd].x_mid).sum::<f64>() / idx.len() as f64;
            let ym = idx.iter().map(|&i| pos[i / nd]).sum::<f64>() / idx.len() as f64;
            pts.push((xm, ym, q));
        }
        (fit_plane_lower(&pts), pts)
    };
    let bound_of = |plane: Option<Plane>, x: f64, y: f64| match plane {
        Some(p) => p.at(x, y).clamp(t_read - opts.thinner_max_mm, t_read),
        None => t_read,
    };
    // The rim: each sector's envelope of all-fat thickness relative to the plane.
    let bin = pitch_mid.max(dy).max(1.0);
    let fit_max = opts.rim_max_mm.min(t_read);
    let nbins = (fit_max / bin).ceil() as usize;
    // The envelope is of the signal per mm of local thickness, capped at the
    // contact's all-fat value (denser bins say nothing about the shape).
    let full = fat_signal(f64::INFINITY, 1.0, 2.0, t_read, opts.skin_mm, mu_f, mu_s);
    // Each bin's point is the mean (distance, signal) of its rays about the
    // quantile `rim_quantile` of the signal: the fat profile at the distances
    // those rays have (the profile is steep near the skin line, where a bin's
    // centre would misplace them).
    let envelope = |bins: &mut [Vec<(f64, f64)>]| -> Vec<(f64, f64)> {
        bins.iter_mut()
            .filter(|b| b.len() >= 5)
            .map(|b| {
                b.sort_by(|x, y| x.1.total_cmp(&y.1));
                // The rays about the quantile (a tenth of the bin around it).
                let n = b.len();
                let q = (opts.rim_quantile * (n - 1) as f64).round() as usize;
                let half = (n / 20).max(1);
                let (lo, hi) = (q.saturating_sub(half), (q + half + 1).min(n));
                let m = (hi - lo) as f64;
                let (sd, sv) = b[lo..hi]
                    .iter()
                    .fold((0.0, 0.0), |acc, p| (acc.0 + p.0, acc.1 + p.1));
                (sd / m, (sv / m).min(full))
            })
            .collect()
    };
    let fit_rim = |plane: Option<Plane>| -> Vec<RimSector> {
        let mut per: Vec<Vec<Vec<(f64, f64)>>> = vec![vec![Vec::new(); nbins]; nsec];
        let mut rays_in: Vec<usize> = vec![0; nsec];
        for i in 0..ns * nd {
            if inside[i] && dist[i] < fit_max {
                let (s, k) = (i / nd, i % nd);
                let sec = sector_of(s, k);
                let b = ((dist[i] / bin) as usize).min(nbins - 1);
                per[sec][b].push((
                    dist[i],
                    smooth[i] / (bound_of(plane, geo[k].x_mid, pos[s]) * geo[k].sec),
                ));
                rays_in[sec] += 1;
            }
        }
        let mut all_bins: Vec<Vec<(f64, f64)>> = vec![Vec::new(); nbins];
        for s in &per {
            for (j, b) in s.iter().enumerate() {
                all_bins[j].extend_from_slice(b);
            }
        }
        let all_env = envelope(&mut all_bins);
        let all_fit = if all_env.len() >= 3 {
            fit_profile(&all_env, fit_max, t_read, opts.skin_mm, mu_f, mu_s)
        } else {
            (t_read / 2.0, 2.0, f64::NAN)
        };
        let mut rim = Vec::with_capacity(nsec);
        for (j, bins) in per.iter_mut().enumerate() {
            let env = envelope(bins);
            let (from, to) = (
                -90.0 + 180.0 * j as f64 / nsec as f64,
                -90.0 + 180.0 * (j + 1) as f64 / nsec as f64,
            );
            let (fit, fallback) = if env.len() >= 3 {
                (
                    fit_profile(&env, fit_max, t_read, opts.skin_mm, mu_f, mu_s),
                    false,
                )
            } else {
                (all_fit, true)
            };
            rim.push(RimSector {
                from_deg: from,
                to_deg: to,
                width_mm: fit.0,
                exponent: fit.1,
                rays: rays_in[j],
                misfit: fit.2,
                fallback,
            });
        }
        let area = |a: f64, r: f64| {
            (0..200)
                .map(|k| profile((k as f64 + 0.5) * fit_max / 200.0, a, r))
                .sum::<f64>()
        };
        // The one profile (and its misfit) every sector takes; where there is
        // none (too few distances in all sectors, or every sector a
        // fallback) each keeps its own, as per sector.
        let chosen = match opts.rim_shape {
            RimShape::PerSector => None,
            RimShape::Shared => (all_env.len() >= 3).then_some((all_fit.0, all_fit.1, all_fit.2)),
            RimShape::Thinnest => rim
                .iter()
                .filter(|r| !r.fallback)
                .map(|r| (r.width_mm, r.exponent, r.misfit))
                .min_by(|x, y| area(x.0, x.1).total_cmp(&area(y.0, y.1))),
        };
        if let Some((a, r, misfit)) = chosen {
            for sec in &mut rim {
                sec.width_mm = a;
                sec.exponent = r;
                sec.misfit = misfit;
                sec.fallback = false;
            }
        }
        rim
    };
    // First pass: the contact taken to begin half the thickness (and 5 mm)
    // from the skin line, as a round edge would.
    let (mut plane, mut pts) = fit_plane(&|i| dist[i] >= t_read / 2.0 + 5.0);
    let mut rim = fit_rim(plane);
    // Second pass: the plane refitted where the fitted edge says the breast
    // is in contact (5 mm beyond each sector's rim width): a breast that
    // tapers over a wider rim than half its thickness would otherwise pull
    // the plane down with its thinner rim's fattest rays, and read its
    // contact dense. Kept where at least three tiles remain.
    if opts.contact_refit {
        let (p2, pts2) =
            fit_plane(&|i| dist[i] >= (t_read / 2.0).max(rim[sector[i]].width_mm) + 5.0);
        if p2.is_some() {
            plane = p2;
            pts = pts2;
            rim = fit_rim(plane);
        }
    }
    let bound = |x: f64, y: f64| bound_of(plane, x, y);
    let at_bound = match plane {
        Some(p) => pts
            .iter()
            .any(|&(x, y, _)| p.at(x, y) < t_read - opts.thinner_max_mm),
        None => false,
    };
    // The volumes.
    let (mut fgv, mut bv, mut vi, mut rim_bv) = (0f64, 0f64, 0f64, 0f64);
    let (mut fgv_c, mut vi_c) = (0f64, 0f64);
    let (mut contact, mut over) = (0usize, 0usize);
    let mut contact_mask = vec![false; ns * nd];
    let (mut chord, mut mid) = (vec![0f32; ns * nd], vec![0f32; ns * nd]);
    let mut dense_share = vec![0f32; ns * nd];
    let (mut t_lo, mut t_hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for i in 0..ns * nd {
        if !inside[i] {
            continue;
        }
        let (s, k) = (i / nd, i % nd);
        let r = &geo[k];
        let t = bound(r.x_mid, pos[s]);
        let sec = &rim[sector_of(s, k)];
        let (p, pi) = edge(dist[i], sec.width_mm, sec.exponent, t, opts.skin_mm);
        // The path from the edge model (never longer than the smoothed
        // signal's all-fat path, its skin kept); the dense share from the
        // ray's own signal, unclipped, so that the noise averages out in the
        // sum (a clip at 0 would add E[max(0, noise)] to every fat ray).
        let a_i = smooth[i];
        let skin_model = (p - pi) * t * r.sec;
        let l_fat = fat_path(a_i, skin_model, mu_f, mu_s);
        // In contact, never longer than the all-fat path (a per-ray fat
        // reference, of the smoothed signal). In the rim the model's path
        // itself: the rays' residuals about the fitted profile, fat ones
        // negative as often as positive, cancel in the sum, which a cap
        // (a clip at h = 0) would not let them.
        let l = if p >= 1.0 {
            (t * p * r.sec).min(l_fat)
        } else {
            t * p * r.sec
        };
        let skin = skin_model.min(l);
        let li = l - skin;
        chord[i] = (l / r.sec) as f32;
        // In contact the path runs from the support up; in the rim about
        // the plane's mid-height.
        mid[i] = if p >= 1.0 { l / r.sec / 2.0 } else { t / 2.0 } as f32;
        let h_free = (a_i - mu_s * skin - mu_f * li) / dmu;
        // In the rim the profile is curved and the model was fitted to the
        // smoothed signal: the smoothed signal it is (the raw one reads the
        // curvature the smoothing took out as dense tissue).
        let h = if p < 1.0 {
            h_free
        } else {
            (a[i] - mu_s * skin - mu_f * li) / dmu
        };
        dense_share[i] = if li > 0.0 {
            (h / li).clamp(0.0, 1.0) as f32
        } else {
            0.0
        };
        if p >= 1.0 {
            contact += 1;
            contact_mask[i] = true;
            fgv_c += r.w * h * dy;
            vi_c += r.w * li * dy;
            if h_free > li + 1.0 {
                over += 1;
            }
            t_lo = t_lo.min(t);
            t_hi = t_hi.max(t);
        } else {
            rim_bv += r.w * l * dy;
        }
        fgv += r.w * h * dy;
        bv += r.w * l * dy;
        vi += r.w * li * dy;
    }
    if vi <= 0.0 {
        return Err(PhysicsDensityError::NoBreast { view: v });
    }
    let fgv = fgv.clamp(0.0, vi);
    let (rho_g, rho_a) = (
        Tissue::Fibroglandular.density_g_cm3(),
        Tissue::Adipose.density_g_cm3(),
    );
    let by_mass = |f: f64, v: f64| {
        let f = f.clamp(0.0, v);
        if v > 0.0 {
            rho_g * f / (rho_g * f + rho_a * (v - f))
        } else {
            f64::NAN
        }
    };
    let glandularity = by_mass(fgv, vi);
    let (cx, cy) = if pts.is_empty() {
        (0.0, pos[ns / 2])
    } else {
        (
            pts.iter().map(|p| p.0).sum::<f64>() / pts.len() as f64,
            pts.iter().map(|p| p.1).sum::<f64>() / pts.len() as f64,
        )
    };
    if !t_lo.is_finite() {
        t_lo = t_read;
        t_hi = t_read;
    }
    Ok(ViewDensity {
        view: v,
        angle_deg: g.angle_deg(v),
        fgv_cm3: fgv / 1000.0,
        bv_cm3: bv / 1000.0,
        interior_cm3: vi / 1000.0,
        vbd: fgv / vi,
        glandularity,
        rim_share: rim_bv / bv,
        contact_glandularity: by_mass(fgv_c, vi_c),
        over_dense_share: if contact > 0 {
            over as f64 / contact as f64
        } else {
            0.0
        },
        truncated,
        thickness: ThicknessFit {
            readout_mm: t_read,
            centre_mm: bound(cx, cy),
            range_mm: [t_lo, t_hi],
            slope_mm_per_cm: plane.map_or([0.0, 0.0], |p| [10.0 * p.cx, 10.0 * p.cy]),
            tiles: plane.map_or(0, |p| p.tiles),
            at_bound,
        },
        rim,
        contact: ContactMap {
            x_mid_mm: geo.iter().map(|r| r.x_mid).collect(),
            slice_mm: dy,
            mask: contact_mask,
        },
        outline: Outline {
            x_mid_mm: geo.iter().map(|r| r.x_mid).collect(),
            slice_mm: dy,
            chord_mm: chord,
            mid_mm: mid,
            dense_share,
        },
    })
}

/// A plane `t = c0 + cx (x - x0) + cy (y - y0)`.
#[derive(Debug, Clone, Copy)]
struct Plane {
    c0: f64,
    cx: f64,
    cy: f64,
    x0: f64,
    y0: f64,
    tiles: usize,
}

impl Plane {
    fn at(&self, x: f64, y: f64) -> f64 {
        self.c0 + self.cx * (x - self.x0) + self.cy * (y - self.y0)
    }
}

/// Least-squares plane through `(x, y, t)`, refitted to the lower envelope:
/// points more than 1 mm above the plane are dropped (five rounds). A slope
/// is fitted only along an axis the points span by at least 20 mm; `None`
/// with fewer than 3 points.
fn fit_plane_lower(pts: &[(f64, f64, f64)]) -> Option<Plane> {
    let mut keep: Vec<(f64, f64, f64)> = pts.to_vec();
    let mut plane = None;
    for _ in 0..5 {
        if keep.len() < 3 {
            break;
        }
        let n = keep.len() as f64;
        let x0 = keep.iter().map(|p| p.0).sum::<f64>() / n;
        let y0 = keep.iter().map(|p| p.1).sum::<f64>() / n;
        let t0 = keep.iter().map(|p| p.2).sum::<f64>() / n;
        let span = |f: &dyn Fn(&(f64, f64, f64)) -> f64| {
            let lo = keep.iter().map(f).fold(f64::INFINITY, f64::min);
            let hi = keep.iter().map(f).fold(f64::NEG_INFINITY, f64::max);
            hi - lo
        };
        let (fx, fy) = (span(&|p| p.0) >= 20.0, span(&|p| p.1) >= 20.0);
        let (mut sxx, mut syy, mut sxy, mut sxt, mut syt) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &(x, y, t) in &keep {
            let (dx, dy, dt) = (x - x0, y - y0, t - t0);
            sxx += dx * dx;
            syy += dy * dy;
            sxy += dx * dy;
            sxt += dx * dt;
            syt += dy * dt;
        }
        let (cx, cy) = match (fx, fy) {
            (true, true) => {
                let det = sxx * syy - sxy * sxy;
                if det.abs() < 1e-12 {
                    (0.0, 0.0)
                } else {
                    ((sxt * syy - syt * sxy) / det, (syt * sxx - sxt * sxy) / det)
                }
            }
            (true, false) => (sxt / sxx, 0.0),
            (false, true) => (0.0, syt / syy),
            (false, false) => (0.0, 0.0),
        };
        let p = Plane {
            c0: t0,
            cx,
            cy,
            x0,
            y0,
            tiles: keep.len(),
        };
        plane = Some(p);
        let next: Vec<_> = keep
            .iter()
            .copied()
            .filter(|&(x, y, t)| t - p.at(x, y) <= 1.0)
            .collect();
        if next.len() == keep.len() {
            break;
        }
        keep = next;
    }
    plane
}

#[cfg(test)]
mod tests;
