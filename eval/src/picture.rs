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

/// A Bland-Altman plot as 8-bit grey pixels (`width x height`): one dark
/// square per case at (mean of truth and estimate, difference), the zero line
/// dotted, the bias solid and the 95 % limits dashed. Axes span the data with
/// a 10 % margin; the caller states the ranges in the accompanying JSON.
pub fn bland_altman(
    means: &[f64],
    diffs: &[f64],
    bias: f64,
    loa: [f64; 2],
) -> (Vec<u8>, usize, usize, [f64; 4]) {
    let (w, h) = (640usize, 400usize);
    let mut px = vec![255u8; w * h];
    let lo_x = means.iter().copied().fold(f64::MAX, f64::min);
    let hi_x = means.iter().copied().fold(f64::MIN, f64::max);
    let ys = diffs.iter().copied().chain([loa[0], loa[1], 0.0]);
    let lo_y = ys.clone().fold(f64::MAX, f64::min);
    let hi_y = ys.fold(f64::MIN, f64::max);
    let pad = |lo: f64, hi: f64| {
        let r = (hi - lo).max(1e-9);
        (lo - 0.1 * r, hi + 0.1 * r)
    };
    let ((x0, x1), (y0, y1)) = (pad(lo_x, hi_x), pad(lo_y, hi_y));
    let to_px = |x: f64, y: f64| {
        let c = ((x - x0) / (x1 - x0) * (w - 1) as f64).round() as isize;
        let r = ((y1 - y) / (y1 - y0) * (h - 1) as f64).round() as isize;
        (c, r)
    };
    let mut hline = |y: f64, on: &dyn Fn(usize) -> bool, v: u8| {
        let (_, r) = to_px(x0, y);
        if (0..h as isize).contains(&r) {
            for c in 0..w {
                if on(c) {
                    px[r as usize * w + c] = v;
                }
            }
        }
    };
    hline(0.0, &|c| c % 6 < 2, 150);
    hline(bias, &|_| true, 0);
    hline(loa[0], &|c| c % 12 < 7, 60);
    hline(loa[1], &|c| c % 12 < 7, 60);
    for (&m, &d) in means.iter().zip(diffs) {
        let (c, r) = to_px(m, d);
        for dr in -3..=3 {
            for dc in -3..=3 {
                let (rr, cc) = (r + dr, c + dc);
                if (0..h as isize).contains(&rr) && (0..w as isize).contains(&cc) {
                    px[rr as usize * w + cc as usize] = 30;
                }
            }
        }
    }
    // Frame.
    for c in 0..w {
        px[c] = 0;
        px[(h - 1) * w + c] = 0;
    }
    for r in 0..h {
        px[r * w] = 0;
        px[r * w + w - 1] = 0;
    }
    (px, w, h, [x0, x1, y0, y1])
}
