//! The quick-look picture of one processed acquisition, as one SVG: the
//! reconstructed coronal slice and its tissue classification, and the axial
//! and sagittal mid-planes of the reconstruction. Images are embedded PNGs
//! (8-bit, nearest-neighbour scaled by the browser), on axes in mm at one
//! scale for every panel, each panel titled.
//!
//! Planes through the tissue's bounding box (labels other than air), as the
//! evaluation's `dbt-eval picture` draws them: the coronal slice a third of
//! the way from the chest wall to the nipple, the axial plane at mid-height,
//! the sagittal plane at mid-width.

use crate::plot::escape;
use base64::Engine;
use std::fmt::Write;

/// Why a picture could not be drawn.
#[derive(Debug, thiserror::Error)]
pub enum PictureError {
    /// The arrays do not match the dimensions.
    #[error("volume of {dims:?} needs {want} voxels; attenuation has {mu}, labels {labels}")]
    Size {
        /// `[lateral, vertical, depth]`.
        dims: [usize; 3],
        /// Voxels the dimensions need.
        want: usize,
        /// Attenuation values given.
        mu: usize,
        /// Labels given.
        labels: usize,
    },
    /// No voxel is tissue.
    #[error("no tissue in the classified volume")]
    NoTissue,
    /// The voxel size is not a positive number.
    #[error("voxel side {0} mm is not positive")]
    Voxel(f64),
    /// PNG encoding failed.
    #[error("encoding a panel: {0}")]
    Png(String),
}

/// Colours of the classification panel by dbt-materials label (0 air,
/// 1 adipose, 2 skin, 3 fibroglandular), with their legend names.
pub const CLASS_COLOURS: [([u8; 3], &str); 4] = [
    ([0, 0, 0], "air"),
    ([230, 190, 120], "adipose"),
    ([200, 90, 110], "skin"),
    ([245, 245, 245], "fibroglandular"),
];

/// One panel: pixels (grey or RGB), its size and title.
struct Panel {
    png: Vec<u8>,
    cols: usize,
    rows: usize,
    title: String,
    x_label: &'static str,
    y_label: &'static str,
}

fn encode(px: &[u8], cols: usize, rows: usize, rgb: bool) -> Result<Vec<u8>, PictureError> {
    let mut out = Vec::new();
    {
        let mut e = png::Encoder::new(&mut out, cols as u32, rows as u32);
        e.set_color(if rgb {
            png::ColorType::Rgb
        } else {
            png::ColorType::Grayscale
        });
        e.set_depth(png::BitDepth::Eight);
        let mut w = e
            .write_header()
            .map_err(|e| PictureError::Png(e.to_string()))?;
        w.write_image_data(px)
            .map_err(|e| PictureError::Png(e.to_string()))?;
    }
    Ok(out)
}

/// Grey window: the 1st and 99th percentiles of the tissue's attenuation.
fn window(mu: &[f32], labels: &[u8]) -> (f32, f32) {
    let mut v: Vec<f32> = mu
        .iter()
        .zip(labels)
        .filter(|(m, l)| **l != 0 && m.is_finite())
        .map(|(m, _)| *m)
        .collect();
    if v.is_empty() {
        return (0.0, 1.0);
    }
    v.sort_by(f32::total_cmp);
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    let (a, b) = (at(0.01), at(0.99));
    if b > a {
        (a, b)
    } else {
        (a, a + 1e-3)
    }
}

fn grey(m: f32, (a, b): (f32, f32)) -> u8 {
    if !m.is_finite() {
        return 0;
    }
    (((m - a) / (b - a)).clamp(0.0, 1.0) * 255.0).round() as u8
}

/// The quick-look SVG of a reconstruction `mu` (1/mm) and its labels, both
/// `[lateral, vertical, depth]` with lateral fastest, voxels `voxel_mm` on a
/// side; `caption` goes above the panels.
pub fn quicklook(
    mu: &[f32],
    labels: &[u8],
    dims: [usize; 3],
    voxel_mm: f64,
    caption: &str,
) -> Result<String, PictureError> {
    let [nx, ny, nz] = dims;
    let want = nx * ny * nz;
    if mu.len() != want || labels.len() != want || want == 0 {
        return Err(PictureError::Size {
            dims,
            want,
            mu: mu.len(),
            labels: labels.len(),
        });
    }
    if !(voxel_mm > 0.0 && voxel_mm.is_finite()) {
        return Err(PictureError::Voxel(voxel_mm));
    }
    let at = |x: usize, y: usize, z: usize| (z * ny + y) * nx + x;
    // The tissue's bounding box, half-open.
    let (mut lo, mut hi) = ([usize::MAX; 3], [0usize; 3]);
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                if labels[at(x, y, z)] != 0 {
                    for (k, v) in [x, y, z].into_iter().enumerate() {
                        lo[k] = lo[k].min(v);
                        hi[k] = hi[k].max(v + 1);
                    }
                }
            }
        }
    }
    if lo[0] == usize::MAX {
        return Err(PictureError::NoTissue);
    }
    let ([x0, y0, z0], [x1, y1, z1]) = (lo, hi);
    let (xm, ym, zm) = ((x0 + x1) / 2, (y0 + y1) / 2, z0 + (z1 - z0) / 3);
    let win = window(mu, labels);
    let h = voxel_mm;
    // Coronal (lateral across, height up), at depth zm.
    let cor: Vec<usize> = (y0..y1)
        .rev()
        .flat_map(|y| (x0..x1).map(move |x| at(x, y, zm)))
        .collect();
    let cor_grey: Vec<u8> = cor.iter().map(|&i| grey(mu[i], win)).collect();
    let cor_class: Vec<u8> = cor
        .iter()
        .flat_map(|&i| CLASS_COLOURS[usize::from(labels[i].min(3))].0)
        .collect();
    // Axial (lateral across, depth from the chest wall down), at height ym.
    let axial: Vec<u8> = (z0..z1)
        .flat_map(|z| (x0..x1).map(move |x| at(x, ym, z)))
        .map(|i| grey(mu[i], win))
        .collect();
    // Sagittal (depth across, height up), at width xm.
    let sag: Vec<u8> = (y0..y1)
        .rev()
        .flat_map(|y| (z0..z1).map(move |z| at(xm, y, z)))
        .map(|i| grey(mu[i], win))
        .collect();
    let (w, hgt, d) = (x1 - x0, y1 - y0, z1 - z0);
    let depth_title = format!("{:.0} mm from the chest wall", (zm - z0) as f64 * h);
    let panels = [
        Panel {
            png: encode(&cor_grey, w, hgt, false)?,
            cols: w,
            rows: hgt,
            title: format!("coronal slice, {depth_title}"),
            x_label: "lateral (mm)",
            y_label: "height (mm)",
        },
        Panel {
            png: encode(&cor_class, w, hgt, true)?,
            cols: w,
            rows: hgt,
            title: "its tissue classification".into(),
            x_label: "lateral (mm)",
            y_label: "height (mm)",
        },
        Panel {
            png: encode(&axial, w, d, false)?,
            cols: w,
            rows: d,
            title: format!("axial mid-plane, {:.0} mm up", (ym - y0) as f64 * h),
            x_label: "lateral (mm)",
            y_label: "depth from the chest wall (mm)",
        },
        Panel {
            png: encode(&sag, d, hgt, false)?,
            cols: d,
            rows: hgt,
            title: "sagittal mid-plane".into(),
            x_label: "depth from the chest wall (mm)",
            y_label: "height (mm)",
        },
    ];
    Ok(layout(&panels, h, caption, win))
}

/// Two by two panels at one scale (px per mm) chosen so the widest column
/// fits 420 px.
fn layout(panels: &[Panel; 4], voxel_mm: f64, caption: &str, win: (f32, f32)) -> String {
    const MARGIN_L: f64 = 62.0;
    const MARGIN_T: f64 = 30.0;
    const MARGIN_B: f64 = 46.0;
    const GAP: f64 = 24.0;
    const HEAD: f64 = 30.0;
    let widest = panels
        .iter()
        .map(|p| p.cols as f64 * voxel_mm)
        .fold(1.0f64, f64::max);
    let scale = (420.0 / widest).min(8.0); // px per mm
    let size = |p: &Panel| {
        (
            p.cols as f64 * voxel_mm * scale,
            p.rows as f64 * voxel_mm * scale,
        )
    };
    let col_w = |c: usize| size(&panels[c]).0.max(size(&panels[c + 2]).0);
    let row_h = |r: usize| size(&panels[2 * r]).1.max(size(&panels[2 * r + 1]).1);
    let cell_w = [col_w(0), col_w(1)];
    let cell_h = [row_h(0), row_h(1)];
    let width = 2.0 * (MARGIN_L + GAP) + cell_w[0] + cell_w[1];
    let height = HEAD + 2.0 * (MARGIN_T + MARGIN_B) + cell_h[0] + cell_h[1] + 40.0;
    let mut s = String::new();
    let _ = write!(
        s,
        r##"<svg xmlns="http://www.w3.org/2000/svg" class="quicklook" viewBox="0 0 {width:.0} {height:.0}" width="{width:.0}" height="{height:.0}" font-family="DejaVu Sans, sans-serif" font-size="12"><rect width="100%" height="100%" fill="#fff"/><text class="caption" x="12" y="20" font-size="14" font-weight="bold">{}</text>"##,
        escape(caption)
    );
    for (i, p) in panels.iter().enumerate() {
        let (r, c) = (i / 2, i % 2);
        let ox = MARGIN_L + c as f64 * (cell_w[0] + MARGIN_L + 2.0 * GAP);
        let oy = HEAD + MARGIN_T + r as f64 * (cell_h[0] + MARGIN_T + MARGIN_B);
        let (pw, ph) = size(p);
        let data = base64::engine::general_purpose::STANDARD.encode(&p.png);
        let _ = write!(
            s,
            r##"<g class="panel"><text class="panel-title" x="{ox:.1}" y="{:.1}" font-weight="bold">{}</text><image x="{ox:.1}" y="{oy:.1}" width="{pw:.1}" height="{ph:.1}" preserveAspectRatio="none" style="image-rendering:pixelated" href="data:image/png;base64,{data}"/><rect x="{ox:.1}" y="{oy:.1}" width="{pw:.1}" height="{ph:.1}" fill="none" stroke="#333"/>"##,
            oy - 8.0,
            escape(&p.title)
        );
        // Ticks every 10, 20 or 50 mm along both axes.
        let extent = (p.cols as f64 * voxel_mm, p.rows as f64 * voxel_mm);
        let step = |mm: f64| {
            if mm > 150.0 {
                50.0
            } else if mm > 60.0 {
                20.0
            } else {
                10.0
            }
        };
        let (sx, sy) = (step(extent.0), step(extent.1));
        let mut v = 0.0;
        while v <= extent.0 + 1e-9 {
            let x = ox + v * scale;
            let _ = write!(
                s,
                r##"<line x1="{x:.1}" y1="{:.1}" x2="{x:.1}" y2="{:.1}" stroke="#333"/><text x="{x:.1}" y="{:.1}" text-anchor="middle" font-size="10">{v:.0}</text>"##,
                oy + ph,
                oy + ph + 4.0,
                oy + ph + 15.0
            );
            v += sx;
        }
        // Heights count up from the panel's bottom; depths down from its top.
        let up = p.y_label == "height (mm)";
        let mut v = 0.0;
        while v <= extent.1 + 1e-9 {
            let y = if up {
                oy + ph - v * scale
            } else {
                oy + v * scale
            };
            let _ = write!(
                s,
                r##"<line x1="{:.1}" y1="{y:.1}" x2="{ox:.1}" y2="{y:.1}" stroke="#333"/><text x="{:.1}" y="{:.1}" text-anchor="end" font-size="10">{v:.0}</text>"##,
                ox - 4.0,
                ox - 6.0,
                y + 3.5
            );
            v += sy;
        }
        let _ = write!(
            s,
            r#"<text class="x-label" x="{:.1}" y="{:.1}" text-anchor="middle">{}</text><text class="y-label" transform="translate({:.1} {:.1}) rotate(-90)" text-anchor="middle">{}</text></g>"#,
            ox + pw / 2.0,
            oy + ph + 30.0,
            p.x_label,
            ox - 40.0,
            oy + ph / 2.0,
            p.y_label
        );
    }
    // Legend: the classes and the grey window.
    let ly = height - 22.0;
    let mut x = 12.0;
    for (rgb, name) in CLASS_COLOURS {
        let _ = write!(
            s,
            r##"<rect x="{x:.1}" y="{:.1}" width="12" height="12" fill="rgb({},{},{})" stroke="#333"/><text x="{:.1}" y="{ly:.1}">{name}</text>"##,
            ly - 10.0,
            rgb[0],
            rgb[1],
            rgb[2],
            x + 16.0
        );
        x += 30.0 + 7.5 * name.len() as f64;
    }
    let _ = write!(
        s,
        r#"<text x="{:.1}" y="{ly:.1}">grey: attenuation {:.4} to {:.4} /mm (black to white)</text></svg>"#,
        x + 10.0,
        win.0,
        win.1
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A half-ellipsoid breast with a glandular core in a larger volume.
    fn breast(dims: [usize; 3]) -> (Vec<f32>, Vec<u8>) {
        let [nx, ny, nz] = dims;
        let mut mu = vec![0.0f32; nx * ny * nz];
        let mut lab = vec![0u8; nx * ny * nz];
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let (u, v, w) = (
                        (x as f64 - 20.0) / 15.0,
                        (y as f64 - 2.0) / 8.0,
                        z as f64 / 12.0,
                    );
                    let r = u * u + v * v + w * w;
                    let i = (z * ny + y) * nx + x;
                    if r < 1.0 && (2..10).contains(&y) {
                        let (l, m) = if r < 0.2 { (3, 0.08) } else { (1, 0.05) };
                        lab[i] = l;
                        mu[i] = m;
                    }
                }
            }
        }
        (mu, lab)
    }

    #[test]
    fn quicklook_has_four_titled_panels_on_mm_axes() {
        let dims = [44, 12, 16];
        let (mu, lab) = breast(dims);
        let s = quicklook(&mu, &lab, dims, 0.8, "acquisition 1").unwrap();
        assert_eq!(s.matches(r#"<g class="panel">"#).count(), 4);
        assert_eq!(s.matches("data:image/png;base64,").count(), 4);
        for t in [
            "coronal slice, ",
            "its tissue classification",
            "axial mid-plane",
            "sagittal mid-plane",
            "lateral (mm)",
            "height (mm)",
            "depth from the chest wall (mm)",
            "fibroglandular",
        ] {
            assert!(s.contains(t), "{t}");
        }
        // The embedded coronal PNG decodes to the tissue box (29 x 8 voxels).
        let i = s.find("base64,").unwrap() + 7;
        let b64 = &s[i..i + s[i..].find('"').unwrap()];
        let png = base64::engine::general_purpose::STANDARD
            .decode(b64)
            .unwrap();
        let dec = png::Decoder::new(png.as_slice());
        let r = dec.read_info().unwrap();
        let info = r.info();
        assert_eq!((info.width, info.height), (29, 8));
    }

    #[test]
    fn classification_colours_follow_the_labels() {
        let dims = [44, 12, 16];
        let (mu, lab) = breast(dims);
        let s = quicklook(&mu, &lab, dims, 0.8, "x").unwrap();
        let pngs: Vec<&str> = s
            .match_indices("base64,")
            .map(|(i, _)| {
                let r = &s[i + 7..];
                &r[..r.find('"').unwrap()]
            })
            .collect();
        let png = base64::engine::general_purpose::STANDARD
            .decode(pngs[1])
            .unwrap();
        let mut r = png::Decoder::new(png.as_slice()).read_info().unwrap();
        let mut buf = vec![0; r.output_buffer_size()];
        let info = r.next_frame(&mut buf).unwrap();
        let px = &buf[..info.buffer_size()];
        let colours: std::collections::BTreeSet<[u8; 3]> =
            px.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
        assert!(colours.contains(&CLASS_COLOURS[3].0), "glandular core");
        assert!(colours.contains(&CLASS_COLOURS[1].0), "adipose");
    }

    #[test]
    fn bad_volumes_are_named() {
        let e = quicklook(&[0.0; 5], &[0; 6], [1, 2, 3], 1.0, "x").unwrap_err();
        assert!(e.to_string().contains("needs 6 voxels"), "{e}");
        let e = quicklook(&[0.0; 6], &[0; 6], [1, 2, 3], 1.0, "x").unwrap_err();
        assert!(e.to_string().contains("no tissue"), "{e}");
        let e = quicklook(&[0.0; 6], &[1; 6], [1, 2, 3], 0.0, "x").unwrap_err();
        assert!(e.to_string().contains("not positive"), "{e}");
    }
}
