//! What the stages need of the counts' layout, as one trait with an
//! implementation per layout ([`dbt_intake::layout`]): the stack of rows,
//! views and elements, each ray's slope through a slab, and each ray's
//! chord through the compressed breast's box. The scatter removal, the
//! beam-hardening linearisation, the noise matching and the counts check
//! are written once over [`RayLayout`]; which layout an acquisition holds
//! was decided at intake and is never asked again.

use crate::acquisition::AcquisitionHeader;
use dbt_forward::clinical::StackLayout;
use dbt_geometry::{chord_in_rect, Geometry};
use dbt_intake::{ConeHeader, SliceHeader};

/// One value per ray: shared by every row (the slice-wise fan, each slice
/// its own copy of the same fan) or per row (a cone-beam detector, whose
/// rows cross the breast at other angles).
#[derive(Debug, Clone, PartialEq)]
pub enum PerRay {
    /// `[view * element]`, every row alike.
    Shared(Vec<f64>),
    /// `[row][view * element]`.
    PerRow(Vec<Vec<f64>>),
}

impl PerRay {
    /// The values of row `r` (`[view * element]`; empty beyond the rows).
    pub fn row(&self, r: usize) -> &[f64] {
        match self {
            PerRay::Shared(v) => v,
            PerRay::PerRow(v) => v.get(r).map_or(&[], Vec::as_slice),
        }
    }

    /// Every value mapped by `f`.
    pub fn map(self, f: impl Fn(f64) -> f64) -> Self {
        match self {
            PerRay::Shared(v) => PerRay::Shared(v.into_iter().map(f).collect()),
            PerRay::PerRow(v) => PerRay::PerRow(
                v.into_iter()
                    .map(|r| r.into_iter().map(&f).collect())
                    .collect(),
            ),
        }
    }

    /// The smallest and largest value.
    pub fn range(&self) -> (f64, f64) {
        let fold = |(a, b): (f64, f64), &s: &f64| (a.min(s), b.max(s));
        let init = (f64::INFINITY, f64::NEG_INFINITY);
        match self {
            PerRay::Shared(v) => v.iter().fold(init, fold),
            PerRay::PerRow(v) => v.iter().flatten().fold(init, fold),
        }
    }
}

/// A header that knows its counts' layout (reading the header's fields
/// through it).
pub trait RayLayout: std::ops::Deref<Target = AcquisitionHeader> + Clone + Sync {
    /// The header's validation ([`crate::validate_header`]) in this
    /// layout.
    fn validate(&self) -> Result<(), crate::HeaderError>;

    /// The stack the counts form: rows, views, elements, pitches and the
    /// views' angles.
    fn stack(&self) -> StackLayout;

    /// The cone-beam system whose frames the counts are (`None` for
    /// slice sinograms).
    fn cone_system(&self) -> Option<&dbt_geometry::ConeSystem>;

    /// `sec a` of every ray (its path through a slab over the slab's
    /// thickness).
    fn ray_secants(&self) -> PerRay;

    /// Every ray's chord through the box of the compressed breast (the
    /// image's width, the header's thickness on the support), mm.
    fn box_chords(&self) -> PerRay;

    /// The counts' shape as `(rows, views * elements)`, checked against
    /// `counts` (`what` names them in the message).
    fn check_shape(&self, counts: &[Vec<f32>], what: &str) -> Result<StackLayout, String> {
        let l = self.stack();
        if counts.len() != l.rows || counts.iter().any(|r| r.len() != l.views * l.cols) {
            return Err(format!(
                "{} rows of {what} for a stack of {} rows x {} views x {} elements",
                counts.len(),
                l.rows,
                l.views,
                l.cols
            ));
        }
        Ok(l)
    }
}

fn secant(d: [f64; 3]) -> f64 {
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() / d[2].abs()
}

impl RayLayout for SliceHeader {
    fn validate(&self) -> Result<(), crate::HeaderError> {
        SliceHeader::validate(self)
    }

    fn stack(&self) -> StackLayout {
        StackLayout::fan(&self.geometry, self.slices, self.slice_spacing_mm)
    }

    fn cone_system(&self) -> Option<&dbt_geometry::ConeSystem> {
        // Slice sinograms come from no cone-beam system (`into_layout`
        // takes the system into the cone-beam layout).
        None
    }

    fn ray_secants(&self) -> PerRay {
        let g = &self.geometry;
        PerRay::Shared(
            (0..g.n_views())
                .flat_map(|v| {
                    (0..g.n_det()).map(move |k| {
                        let (s, p) = g.ray_endpoints_mm(v, k);
                        secant([p.0 - s.0, 0.0, p.1 - s.1])
                    })
                })
                .collect(),
        )
    }

    fn box_chords(&self) -> PerRay {
        PerRay::Shared(box_chords(&self.geometry, self.thickness_mm))
    }
}

impl RayLayout for ConeHeader {
    fn validate(&self) -> Result<(), crate::HeaderError> {
        ConeHeader::validate(self)
    }

    fn stack(&self) -> StackLayout {
        StackLayout::cone(self.system())
    }

    fn cone_system(&self) -> Option<&dbt_geometry::ConeSystem> {
        Some(self.system())
    }

    fn ray_secants(&self) -> PerRay {
        let sys = self.system();
        let (rows, views, cols) = (sys.detector.rows, sys.n_views(), sys.detector.columns);
        PerRay::PerRow(
            (0..rows)
                .map(|r| {
                    let mut out = Vec::with_capacity(views * cols);
                    for v in 0..views {
                        let s = sys.source(v);
                        for c in 0..cols {
                            let e = sys.element(v, r, c);
                            out.push(secant([e[0] - s[0], e[1] - s[1], e[2] - s[2]]));
                        }
                    }
                    out
                })
                .collect(),
        )
    }

    fn box_chords(&self) -> PerRay {
        PerRay::PerRow(cone_box_chords(
            self.system(),
            self.geometry.width_mm(),
            self.thickness_mm,
        ))
    }
}

/// The chord (mm) of each ray `(view, element)` through the compression box
/// of thickness `t` on the geometry's support, within the image's width.
pub fn box_chords(g: &Geometry, t: f64) -> Vec<f64> {
    let (hw, z0) = (g.width_mm() / 2.0, g.support_z_mm());
    let mut out = Vec::with_capacity(g.n_rays());
    for v in 0..g.n_views() {
        for k in 0..g.n_det() {
            let (s, p) = g.ray_endpoints_mm(v, k);
            out.push(chord_in_rect(s, p, -hw, hw, z0, z0 + t));
        }
    }
    out
}

/// The chord (mm) of the segment from `s` to `e` through the box
/// `[lo, hi]` (slab method; 0 when it misses).
pub fn chord_in_box(s: [f64; 3], e: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> f64 {
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for a in 0..3 {
        let d = e[a] - s[a];
        if d.abs() < 1e-12 {
            if s[a] < lo[a] || s[a] > hi[a] {
                return 0.0;
            }
            continue;
        }
        let (u, w) = ((lo[a] - s[a]) / d, (hi[a] - s[a]) / d);
        t0 = t0.max(u.min(w));
        t1 = t1.min(u.max(w));
    }
    let len = (0..3).map(|a| (e[a] - s[a]).powi(2)).sum::<f64>().sqrt();
    (t1 - t0).max(0.0) * len
}

/// The chord (mm) of each cone-beam ray `[row][view * column + column]`
/// of `sys` (the half-line from the source through the element) through
/// the compression box: thickness `t` on the support, the
/// fan image's width `width_mm` across, the detector's depth.
pub fn cone_box_chords(sys: &dbt_geometry::ConeSystem, width_mm: f64, t: f64) -> Vec<Vec<f64>> {
    let d = &sys.detector;
    let lo = [-width_mm / 2.0, 0.0, sys.support_height_mm];
    let hi = [
        width_mm / 2.0,
        d.rows as f64 * d.pitch_mm,
        sys.support_height_mm + t,
    ];
    (0..d.rows)
        .map(|r| {
            (0..sys.n_views())
                .flat_map(|v| {
                    let src = sys.source(v);
                    (0..d.columns).map(move |c| {
                        // The half-line from the source through the element
                        // (as the projector takes it: a rotating detector's
                        // edge rises into the box at the widest angles).
                        let e = sys.element(v, r, c);
                        let far = [0, 1, 2].map(|a| src[a] + 10.0 * (e[a] - src[a]));
                        chord_in_box(src, far, lo, hi)
                    })
                })
                .collect()
        })
        .collect()
}
