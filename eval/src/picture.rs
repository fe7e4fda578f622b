//! A side-by-side picture of one slice: the phantom, its sinogram, and the
//! MLTR and FBP reconstructions, stacked as grey panels (the slices are wide).

/// A grey panel, row-major.
pub struct Panel {
    /// Pixels, row-major.
    pub data: Vec<f32>,
    /// Rows.
    pub rows: usize,
    /// Columns.
    pub cols: usize,
    /// Display window (black, white).
    pub window: (f32, f32),
    /// Vertical stretch (sinograms have few views).
    pub stretch: usize,
}

/// Window covering an image's range.
pub fn auto_window(v: &[f32]) -> (f32, f32) {
    let lo = v.iter().copied().fold(f32::MAX, f32::min);
    let hi = v.iter().copied().fold(f32::MIN, f32::max);
    if hi > lo {
        (lo, hi)
    } else {
        (lo, lo + 1.0)
    }
}

/// Stack panels vertically with a 4-pixel gap; returns 8-bit grey pixels,
/// width and height.
pub fn compose(panels: &[Panel]) -> (Vec<u8>, usize, usize) {
    const GAP: usize = 4;
    let width = panels.iter().map(|p| p.cols).max().unwrap_or(1);
    let height: usize = panels.iter().map(|p| p.rows * p.stretch.max(1) + GAP).sum();
    let mut out = vec![255u8; width * height];
    let mut y0 = 0;
    for p in panels {
        let (lo, hi) = p.window;
        let s = p.stretch.max(1);
        for r in 0..p.rows * s {
            for c in 0..p.cols {
                let v = (p.data[(r / s) * p.cols + c] - lo) / (hi - lo);
                out[(y0 + r) * width + c] = (v.clamp(0.0, 1.0) * 255.0).round() as u8;
            }
        }
        y0 += p.rows * s + GAP;
    }
    (out, width, height)
}
