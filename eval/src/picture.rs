//! Pictures: one slice's phantom, sinogram and reconstructions stacked as grey
//! panels (the slices are wide), and the Bland-Altman plots of the accuracy
//! evaluation (plotters, with an embedded font).

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
    /// What the panel shows, written above it.
    pub label: String,
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

/// Height of the strip above each panel that holds its label, pixels.
const LABEL_STRIP: usize = 18;

/// Stack panels vertically, each under a strip with its label; returns
/// 8-bit grey pixels, width and height.
pub fn compose(panels: &[Panel]) -> Result<(Vec<u8>, usize, usize), PlotError> {
    use plotters::prelude::*;
    register_font()?;
    let width = panels.iter().map(|p| p.cols).max().unwrap_or(1).max(320);
    let height: usize = panels
        .iter()
        .map(|p| p.rows * p.stretch.max(1) + LABEL_STRIP)
        .sum();
    let mut rgb = vec![255u8; width * height * 3];
    {
        let root =
            BitMapBackend::with_buffer(&mut rgb, (width as u32, height as u32)).into_drawing_area();
        let mut y0 = 0;
        for p in panels {
            root.draw(&Text::new(
                p.label.clone(),
                (2, y0 as i32 + 3),
                ("sans-serif", 13).into_font(),
            ))
            .map_err(|e| PlotError(e.to_string()))?;
            y0 += LABEL_STRIP + p.rows * p.stretch.max(1);
        }
        root.present().map_err(|e| PlotError(e.to_string()))?;
    }
    let mut out: Vec<u8> = rgb
        .chunks_exact(3)
        .map(|c| c[0].min(c[1]).min(c[2]))
        .collect();
    let mut y0 = 0;
    for p in panels {
        let (lo, hi) = p.window;
        let s = p.stretch.max(1);
        y0 += LABEL_STRIP;
        for r in 0..p.rows * s {
            for c in 0..p.cols {
                let v = (p.data[(r / s) * p.cols + c] - lo) / (hi - lo);
                out[(y0 + r) * width + c] = (v.clamp(0.0, 1.0) * 255.0).round() as u8;
            }
        }
        y0 += p.rows * s;
    }
    Ok((out, width, height))
}

/// The font of the plots' text: DejaVu Sans Mono (Bitstream Vera licence,
/// `eval/assets/DejaVu-LICENSE.txt`), embedded so that nothing depends on the
/// fonts a machine happens to have.
const FONT: &[u8] = include_bytes!("../assets/DejaVuSansMono.ttf");

fn register_font() -> Result<(), PlotError> {
    static REGISTERED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font("sans-serif", plotters::style::FontStyle::Normal, FONT)
            .is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(PlotError("the embedded plot font does not load".into()))
    }
}

/// A plot could not be drawn.
#[derive(Debug, thiserror::Error)]
#[error("plot: {0}")]
pub struct PlotError(String);

/// A Bland-Altman plot like the paper's Figures 4-5: one point per case at
/// (mean of truth and estimate, difference), the zero line dotted, the bias
/// solid and the 95 % limits of agreement dashed, axes labelled and ticked.
pub struct BlandAltman<'a> {
    /// Title (reconstructor and quantity).
    pub title: String,
    /// x axis label (the mean, with its unit).
    pub x_label: &'a str,
    /// y axis label (the difference, with its unit).
    pub y_label: &'a str,
    /// Means of truth and estimate, one per case.
    pub means: &'a [f64],
    /// Differences, one per case.
    pub diffs: &'a [f64],
    /// Mean difference.
    pub bias: f64,
    /// 95 % limits of agreement.
    pub loa: [f64; 2],
}

impl BlandAltman<'_> {
    /// Width and height of the picture, pixels.
    pub const SIZE: (u32, u32) = (800, 520);

    /// Draws the plot: RGB pixels (8 bit), width, height and the axis ranges
    /// `[x0, x1, y0, y1]` (the data and lines with a 10 % margin).
    pub fn render(&self) -> Result<(Vec<u8>, usize, usize, [f64; 4]), PlotError> {
        use plotters::prelude::*;
        register_font()?;
        let err = |e: &dyn std::fmt::Display| PlotError(e.to_string());
        let finite = |v: &f64| v.is_finite();
        let xs = self.means.iter().copied().filter(finite);
        let lo_x = xs.clone().fold(f64::MAX, f64::min);
        let hi_x = xs.fold(f64::MIN, f64::max);
        let ys = self
            .diffs
            .iter()
            .copied()
            .chain([self.loa[0], self.loa[1], self.bias, 0.0])
            .filter(finite);
        let lo_y = ys.clone().fold(f64::MAX, f64::min);
        let hi_y = ys.fold(f64::MIN, f64::max);
        if lo_x > hi_x || lo_y > hi_y {
            return Err(PlotError("no finite case to plot".into()));
        }
        let pad = |lo: f64, hi: f64| {
            let r = (hi - lo).max(1e-6 * hi.abs().max(1.0));
            (lo - 0.1 * r, hi + 0.1 * r)
        };
        let ((x0, x1), (y0, y1)) = (pad(lo_x, hi_x), pad(lo_y, hi_y));
        let (w, h) = Self::SIZE;
        let mut buf = vec![255u8; (w * h * 3) as usize];
        {
            let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
            root.fill(&WHITE).map_err(|e| err(&e))?;
            // Long titles (a calibrated reconstructor's name) get a smaller
            // font so they fit the width: about 0.55 em per character.
            let chars = self.title.chars().count().max(1) as f64;
            let size = (f64::from(w) / (0.55 * chars)).clamp(10.0, 18.0);
            let mut chart = ChartBuilder::on(&root)
                .caption(&self.title, ("sans-serif", size))
                .margin(12)
                .x_label_area_size(46)
                .y_label_area_size(64)
                .build_cartesian_2d(x0..x1, y0..y1)
                .map_err(|e| err(&e))?;
            chart
                .configure_mesh()
                .x_desc(self.x_label)
                .y_desc(self.y_label)
                .label_style(("sans-serif", 14))
                .axis_desc_style(("sans-serif", 15))
                .light_line_style(WHITE)
                .draw()
                .map_err(|e| err(&e))?;
            let grey = RGBColor(150, 150, 150);
            // Dash and gap lengths in pixels: the zero line dotted, the
            // limits dashed.
            let dashed = |y: f64, dash: i32, gap: i32, style: ShapeStyle| {
                DashedLineSeries::new([(x0, y), (x1, y)], dash, gap, style)
            };
            chart
                .draw_series(dashed(0.0, 5, 18, grey.stroke_width(1)))
                .map_err(|e| err(&e))?;
            for l in self.loa {
                chart
                    .draw_series(dashed(l, 12, 12, BLACK.stroke_width(1)))
                    .map_err(|e| err(&e))?;
            }
            chart
                .draw_series(LineSeries::new(
                    [(x0, self.bias), (x1, self.bias)],
                    BLACK.stroke_width(2),
                ))
                .map_err(|e| err(&e))?;
            // Line labels just above their line, at the right (text is anchored
            // at its top-left corner; the plot area is about 420 px high).
            let above = (y1 - y0) * 17.0 / 420.0;
            let label = |y: f64, text: String| {
                Text::new(
                    text,
                    (x1 - 0.2 * (x1 - x0), y + above),
                    ("sans-serif", 13).into_font(),
                )
            };
            chart
                .draw_series([
                    label(self.bias, format!("bias {:+.2}", self.bias)),
                    label(self.loa[0], format!("-1.96 sd {:+.2}", self.loa[0])),
                    label(self.loa[1], format!("+1.96 sd {:+.2}", self.loa[1])),
                ])
                .map_err(|e| err(&e))?;
            chart
                .draw_series(
                    self.means
                        .iter()
                        .zip(self.diffs)
                        .filter(|(m, d)| m.is_finite() && d.is_finite())
                        .map(|(&m, &d)| Circle::new((m, d), 4, RGBColor(30, 30, 30).filled())),
                )
                .map_err(|e| err(&e))?;
            root.present().map_err(|e| err(&e))?;
        }
        Ok((buf, w as usize, h as usize, [x0, x1, y0, y1]))
    }
}

/// One plane of a volume as an attenuation image, row 0 at the top.
pub struct Plane {
    /// Panel title.
    pub title: String,
    /// Attenuation (1/mm), row-major.
    pub data: Vec<f32>,
    /// Rows.
    pub rows: usize,
    /// Columns.
    pub cols: usize,
    /// Pixel side, mm.
    pub pixel_mm: f64,
    /// x axis label.
    pub x_label: &'static str,
    /// y axis label.
    pub y_label: &'static str,
    /// Whether row 0 is the largest y (heights) or the smallest (depth
    /// from the chest wall, drawn downward).
    pub y_up: bool,
}

/// The three orthogonal planes of a breast volume through its tissue: the
/// axial plane at mid-height of the chest-wall face, the sagittal plane at
/// mid-width, the coronal plane at a third of the chest-wall-to-nipple
/// distance. Attenuation from the partial volumes where the volume has
/// them ([`dbt_phantom::LabelVolume::mu_at`]).
pub fn mid_planes(vol: &dbt_phantom::LabelVolume) -> Option<[Plane; 3]> {
    let b = vol.tissue_bounds()?;
    Some(planes_at(b, vol.voxel_mm(), |l, v, d| vol.mu_at(l, v, d)))
}

/// The planes of [`mid_planes`] of `truth`, taken from a reconstruction of
/// it: attenuation `mu` of dims `[columns, rows within the thickness,
/// slices]` (vertical index 0 on the support, `dbt_pipeline::ProcessResult`),
/// whose column `c` holds the truth's lateral index `c + nx / 2 - columns / 2`
/// (`dbt_phantom::coronal_slice`); 0 outside it.
pub fn recon_planes(
    truth: &dbt_phantom::LabelVolume,
    mu: &[f32],
    dims: [usize; 3],
) -> Option<[Plane; 3]> {
    let b = truth.tissue_bounds()?;
    let shift = truth.dims()[0] as isize / 2 - dims[0] as isize / 2;
    Some(planes_at(b, truth.voxel_mm(), |l, v, d| {
        let c = l as isize - shift;
        if c < 0 || c as usize >= dims[0] || v >= dims[1] || d >= dims[2] {
            return 0.0;
        }
        mu.get((d * dims[1] + v) * dims[0] + c as usize)
            .copied()
            .unwrap_or(0.0)
    }))
}

/// The axial, sagittal and coronal planes of [`mid_planes`] within the
/// bounds `b` (`[lateral, vertical, depth]` index ranges), voxels `h` mm,
/// attenuation from `at(lateral, vertical, depth)`.
fn planes_at(b: [[usize; 2]; 3], h: f64, at: impl Fn(usize, usize, usize) -> f32) -> [Plane; 3] {
    let ([l0, l1], [v0, v1], [d0, d1]) = (b[0], b[1], b[2]);
    let (lm, vm, dm) = ((l0 + l1) / 2, (v0 + v1) / 2, d0 + (d1 - d0) / 3);
    let axial = Plane {
        title: format!("axial, {:.0} mm above the support", (vm - v0) as f64 * h),
        data: (d0..d1)
            .flat_map(|d| (l0..l1).map(move |l| (l, d)))
            .map(|(l, d)| at(l, vm, d))
            .collect(),
        rows: d1 - d0,
        cols: l1 - l0,
        pixel_mm: h,
        x_label: "lateral (mm)",
        y_label: "depth from the chest wall (mm)",
        y_up: false,
    };
    let sagittal = Plane {
        title: "sagittal, mid-width".into(),
        data: (v0..v1)
            .rev()
            .flat_map(|v| (d0..d1).map(move |d| (v, d)))
            .map(|(v, d)| at(lm, v, d))
            .collect(),
        rows: v1 - v0,
        cols: d1 - d0,
        pixel_mm: h,
        x_label: "depth from the chest wall (mm)",
        y_label: "height (mm)",
        y_up: true,
    };
    let coronal = Plane {
        title: format!(
            "coronal, {:.0} mm from the chest wall",
            (dm - d0) as f64 * h
        ),
        data: (v0..v1)
            .rev()
            .flat_map(|v| (l0..l1).map(move |l| (l, v)))
            .map(|(l, v)| at(l, v, dm))
            .collect(),
        rows: v1 - v0,
        cols: l1 - l0,
        pixel_mm: h,
        x_label: "lateral (mm)",
        y_label: "height (mm)",
        y_up: true,
    };
    [axial, sagittal, coronal]
}

/// A grid of planes: one row per volume (its name in each panel's title),
/// one column per plane, the panels of a column on axes in mm at one scale
/// (1:1 aspect), grey from the
/// attenuation window `window` (1/mm). RGB pixels, width, height.
pub fn render_planes(
    rows: &[(String, [Plane; 3])],
    window: (f32, f32),
) -> Result<(Vec<u8>, usize, usize), PlotError> {
    use plotters::prelude::*;
    register_font()?;
    let err = |e: &dyn std::fmt::Display| PlotError(e.to_string());
    const PANEL: (u32, u32) = (560, 330);
    const AXES: (u32, u32) = (64, 46);
    let (w, h) = (3 * PANEL.0, PANEL.1 * rows.len().max(1) as u32);
    // One scale per column (the same plane of every volume): the largest
    // mm per plot pixel any of its panels needs.
    let plot = (
        (PANEL.0 - AXES.0 - 20) as f64,
        (PANEL.1 - AXES.1 - 40) as f64,
    );
    let scales: Vec<f64> = (0..3)
        .map(|c| {
            rows.iter()
                .map(|(_, p)| {
                    let p = &p[c];
                    (p.cols as f64 * p.pixel_mm / plot.0).max(p.rows as f64 * p.pixel_mm / plot.1)
                })
                .fold(0.0f64, f64::max)
                .max(1e-6)
        })
        .collect();
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let areas = root.split_evenly((rows.len().max(1), 3));
        for (r, (name, planes)) in rows.iter().enumerate() {
            for (c, p) in planes.iter().enumerate() {
                let area = &areas[r * 3 + c];
                let (xw, yw) = (plot.0 * scales[c], plot.1 * scales[c]);
                let ext_y = p.rows as f64 * p.pixel_mm;
                let y_range = if p.y_up { 0.0..yw } else { yw..0.0 };
                let mut chart = ChartBuilder::on(area)
                    .caption(format!("{name}: {}", p.title), ("sans-serif", 14))
                    .margin(8)
                    .x_label_area_size(AXES.1)
                    .y_label_area_size(AXES.0)
                    .build_cartesian_2d(0.0..xw, y_range)
                    .map_err(|e| err(&e))?;
                chart
                    .configure_mesh()
                    .disable_mesh()
                    .x_desc(p.x_label)
                    .y_desc(p.y_label)
                    .label_style(("sans-serif", 12))
                    .axis_desc_style(("sans-serif", 13))
                    .draw()
                    .map_err(|e| err(&e))?;
                let (lo, hi) = window;
                chart
                    .draw_series((0..p.rows).flat_map(|i| {
                        (0..p.cols).map(move |j| {
                            let v = ((p.data[i * p.cols + j] - lo) / (hi - lo)).clamp(0.0, 1.0);
                            let g = (v * 255.0).round() as u8;
                            // Row 0 is the top of the picture.
                            let (y_top, y_bot) = if p.y_up {
                                (
                                    ext_y - i as f64 * p.pixel_mm,
                                    ext_y - (i + 1) as f64 * p.pixel_mm,
                                )
                            } else {
                                (i as f64 * p.pixel_mm, (i + 1) as f64 * p.pixel_mm)
                            };
                            let x = j as f64 * p.pixel_mm;
                            Rectangle::new(
                                [(x, y_top), (x + p.pixel_mm, y_bot)],
                                RGBColor(g, g, g).filled(),
                            )
                        })
                    }))
                    .map_err(|e| err(&e))?;
            }
        }
        root.present().map_err(|e| err(&e))?;
    }
    Ok((buf, w as usize, h as usize))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plot<'a>(means: &'a [f64], diffs: &'a [f64]) -> BlandAltman<'a> {
        BlandAltman {
            title: "test".into(),
            x_label: "mean (%)",
            y_label: "difference (pp)",
            means,
            diffs,
            bias: 1.0,
            loa: [-2.0, 4.0],
        }
    }

    fn dark(px: &[u8], w: usize, x: std::ops::Range<usize>, y: std::ops::Range<usize>) -> usize {
        y.flat_map(|r| x.clone().map(move |c| (r, c)))
            .filter(|&(r, c)| px[3 * (r * w + c)] < 128)
            .count()
    }

    #[test]
    fn the_plot_has_its_points_lines_and_axis_text() {
        let (means, diffs) = ([10.0, 20.0, 30.0], [0.0, 1.0, 2.0]);
        let (px, w, h, r) = plot(&means, &diffs).render().unwrap();
        assert_eq!((w, h), (800, 520));
        assert_eq!(px.len(), w * h * 3);
        // Ranges: the data and the lines (-2..4, 10..30) with 10 % margins.
        assert!(
            (r[0] - 8.0).abs() < 1e-9 && (r[1] - 32.0).abs() < 1e-9,
            "{r:?}"
        );
        assert!(
            (r[2] + 2.6).abs() < 1e-9 && (r[3] - 4.6).abs() < 1e-9,
            "{r:?}"
        );
        // Text left of the plot (the y label and tick labels) and below it.
        assert!(dark(&px, w, 0..60, 100..400) > 100, "no y axis text");
        assert!(dark(&px, w, 200..600, h - 40..h) > 100, "no x axis text");
        // The bias line is solid across the plot area: a dark row of pixels.
        let row_dark = (0..h).any(|y| dark(&px, w, 150..750, y..y + 1) > 550);
        assert!(row_dark, "no solid bias line");
    }

    #[test]
    fn a_plot_without_a_finite_case_is_an_error() {
        let e = plot(&[f64::NAN], &[f64::NAN]);
        // The lines are finite, but there is no x range.
        assert!(e.render().is_err());
    }

    /// The mid-planes of a partial-volume phantom: the three planes through
    /// its tissue, attenuation between the tissues' (partial volumes), and
    /// a picture with one row per volume.
    #[test]
    fn mid_planes_of_a_partial_volume_phantom() {
        let spec = dbt_phantom::AnatomicalSpec {
            thickness_mm: 30.0,
            chest_to_nipple_mm: 50.0,
            width_mm: 80.0,
            edge_mm: 10.0,
            sub: 2,
            ..dbt_phantom::AnatomicalSpec::typical(1.0, 3)
        };
        let vol = dbt_phantom::generate_anatomical(&spec).unwrap();
        let planes = mid_planes(&vol).unwrap();
        let b = vol.tissue_bounds().unwrap();
        assert_eq!(
            (planes[0].rows, planes[0].cols),
            (b[2][1] - b[2][0], b[0][1] - b[0][0])
        );
        assert_eq!(
            (planes[1].rows, planes[1].cols),
            (b[1][1] - b[1][0], b[2][1] - b[2][0])
        );
        assert_eq!(
            (planes[2].rows, planes[2].cols),
            (b[1][1] - b[1][0], b[0][1] - b[0][0])
        );
        let pure = dbt_materials::MU_BY_LABEL;
        let mixed = planes[2]
            .data
            .iter()
            .filter(|v| pure.iter().all(|p| (*v - p).abs() > 1e-6))
            .count();
        assert!(mixed > 0);
        let (px, w, h) = render_planes(&[("a".into(), planes)], (0.04, 0.09)).unwrap();
        assert_eq!((w, h), (1680, 330));
        assert_eq!(px.len(), w * h * 3);
        assert!(px.iter().any(|&p| p < 100), "nothing dark drawn");
    }
}
