//! Scatter removal (issue #27): the scatter an energy-integrating detector
//! records without a grid, estimated by the kernel model fitted to our
//! Monte Carlo engine ([`dbt_scatter::ScatterTable`], the one the
//! simulator adds scatter with) and removed from each view's counts before
//! the beam-hardening linearisation and everything else.
//!
//! # The correction
//! For each view, the counts as fractions of the flat field (the open
//! field's primary: GANTRY_INTERFACE.md) form the detector image
//! `m = T + s(T)` (rows: coronal slices, or a cone-beam
//! detector's rows; columns: detector elements). On blocks of about 4 mm
//! ([`dbt_forward::clinical::SCATTER_BLOCK_MM`]: scatter varies over
//! centimetres) the primary `T` is solved for by
//! [`dbt_scatter::ScatterTable::remove`]; the blocks' scatter, interpolated
//! back to every element, is subtracted from each count (at least
//! [`MIN_PRIMARY`] of it kept). A difference rather than a scaling by the
//! scatter fraction: the scatter is smooth in counts, its fraction is not
//! (it jumps at the breast's edge, inside one block). Counts no exposure
//! can give (`c <= 0`, `c >` [`MAX_SIGNAL`] `b`) pass as read, for the
//! counts check to name them.

use crate::layout::RayLayout;
use dbt_dose::xray::AnodeFilter;
use dbt_scatter::{block_mean, upsample, ScatterTable};
use thiserror::Error;

/// Why the scatter cannot be removed.
#[derive(Debug, Error, PartialEq)]
pub enum DescatterError {
    /// The model failed on this acquisition.
    #[error("scatter removal: {0}")]
    Model(String),
}

/// Fixed-point steps of [`ScatterTable::remove`] (a 90 mm breast's
/// scatter-to-primary ratio of 1.5 converges to 1e-4 in about 15).
pub const ITERATIONS: usize = 20;

/// The least share of a count kept as primary (a 90 mm breast's scatter
/// is about 1.5 times its primary: 40 % of the count is primary; noise can
/// put a dark element's count under the estimated scatter).
pub const MIN_PRIMARY: f64 = 0.05;

/// The largest signal, as a multiple of the flat field, a count with
/// scatter can hold: the open field's own scatter (paddle, support) is
/// about 0.1 of it, a breast's beside it a little more; 1.5 bounds both.
/// Counts above pass as read (the counts check names them).
pub const MAX_SIGNAL: f64 = 1.5;

/// The site's scatter removal: the shipped kernel tables, one per beam
/// (`dbt_scatter::ScatterTable::shipped_for`), the acquisition's chosen by
/// its anode/filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScatterRemoval {
    /// The table of each beam, at its `AnodeFilter::index`.
    tables: [&'static ScatterTable; AnodeFilter::ALL.len()],
}

impl ScatterRemoval {
    /// The shipped tables' removal: every beam's table, each parsed and
    /// checked once.
    pub fn shipped() -> Result<Self, DescatterError> {
        let mut tables = Vec::with_capacity(AnodeFilter::ALL.len());
        for af in AnodeFilter::ALL {
            tables.push(
                ScatterTable::shipped_for(af.name())
                    .map_err(|e| DescatterError::Model(e.to_string()))?,
            );
        }
        let tables = tables
            .try_into()
            .map_err(|_| DescatterError::Model("one table per beam".into()))?;
        Ok(Self { tables })
    }

    /// The kernels of a beam.
    pub fn table(&self, af: AnodeFilter) -> &'static ScatterTable {
        self.tables[af.index()]
    }

    /// Remove the scatter from an acquisition's counts in place
    /// (`counts[row][view * cols + element]`, flat field `h.flux`; the
    /// header already validated). Returns the mean scatter-to-primary
    /// ratio removed under the breast (elements whose corrected counts
    /// are below 95 % of the flat field).
    pub fn apply<H: RayLayout>(
        &self,
        h: &H,
        counts: &mut [Vec<f32>],
    ) -> Result<f64, DescatterError> {
        let fail = |w: String| DescatterError::Model(w);
        let l = h.check_shape(counts, "counts").map_err(fail)?;
        let table = self.table(h.anode_filter);
        let (lo, hi) = table.range_mm();
        if !(lo..=hi).contains(&h.thickness_mm) {
            tracing::warn!(
                thickness_mm = h.thickness_mm,
                "the scatter model is fitted for {lo}-{hi} mm: the nearest thickness's kernels are used"
            );
        }
        let fine = l.grid();
        let (fr, fc) = l.block();
        // The flat field is the open field's primary (GANTRY_INTERFACE.md):
        // the model's unit.
        let b = h.flux;
        let (mut s_sum, mut p_sum) = (0.0, 0.0);
        for v in 0..l.views {
            let _span = tracing::trace_span!("descatter_view", v).entered();
            let mut m = vec![0.0; fine.len()];
            for (r, row) in counts.iter().enumerate() {
                for c in 0..l.cols {
                    m[r * l.cols + c] =
                        (f64::from(row[v * l.cols + c]) / b).clamp(1e-6, MAX_SIGNAL);
                }
            }
            let (mc, coarse) = block_mean(&m, &fine, fr, fc);
            let (_, s) = table
                .remove(&mc, &coarse, h.thickness_mm, l.tan_angles[v], ITERATIONS)
                .map_err(|e| fail(e.to_string()))?;
            // The scatter is smooth in counts (not as a fraction of them:
            // at the breast's edge a block holds air and tissue), so it is
            // interpolated and subtracted, each count keeping at least
            // MIN_PRIMARY of itself (noise in a dark element).
            let s = upsample(&s, &coarse, &fine);
            for (r, row) in counts.iter_mut().enumerate() {
                for c in 0..l.cols {
                    let x = &mut row[v * l.cols + c];
                    let val = f64::from(*x);
                    if val > 0.0 && val <= MAX_SIGNAL * b {
                        let sc = b * s[r * l.cols + c];
                        let p = (val - sc).max(MIN_PRIMARY * val);
                        *x = p as f32;
                        if p < 0.95 * b {
                            s_sum += val - p;
                            p_sum += p;
                        }
                    }
                }
            }
        }
        Ok(if p_sum > 0.0 { s_sum / p_sum } else { 0.0 })
    }
}
