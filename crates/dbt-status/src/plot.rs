//! The status page's trend figures as SVG: MGD against compressed thickness
//! (the patient-specific Monte Carlo dose beside the model breast's), and a
//! histogram of the reported glandularity. Axes carry labels with units and
//! ticks at 1-2-5 steps; an empty history draws the axes and says so.

use crate::state::AcquisitionRecord;
use std::fmt::Write;

/// Escape text for XML (SVG and HTML).
pub fn escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&#39;"),
            c => o.push(c),
        }
    }
    o
}

/// Tick positions covering `[lo, hi]` at the smallest 1-2-5 step giving at
/// most `n` intervals; the range widened to whole steps.
pub fn ticks(lo: f64, hi: f64, n: usize) -> (f64, f64, Vec<f64>) {
    let (lo, hi) = if hi > lo {
        (lo, hi)
    } else {
        (lo - 0.5, lo + 0.5)
    };
    let raw = (hi - lo) / n.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let a = (lo / step).floor() * step;
    let b = (hi / step).ceil() * step;
    let k = ((b - a) / step).round() as usize;
    let t = (0..=k).map(|i| a + i as f64 * step).collect();
    (a, b, t)
}

fn tick_label(v: f64, step: f64) -> String {
    let decimals = if step >= 1.0 {
        0
    } else {
        (-step.log10().floor()) as usize
    };
    format!("{v:.decimals$}")
}

/// A plot frame: data ranges mapped onto the SVG's plot area.
struct Frame {
    x: (f64, f64),
    y: (f64, f64),
    area: (f64, f64, f64, f64),
}

impl Frame {
    const W: f64 = 560.0;
    const H: f64 = 360.0;

    fn new(x: (f64, f64), y: (f64, f64)) -> Self {
        Self {
            x,
            y,
            area: (70.0, 56.0, Self::W - 20.0, Self::H - 56.0),
        }
    }

    fn px(&self, v: f64) -> f64 {
        let (l, _, r, _) = self.area;
        l + (v - self.x.0) / (self.x.1 - self.x.0) * (r - l)
    }

    fn py(&self, v: f64) -> f64 {
        let (_, t, _, b) = self.area;
        b - (v - self.y.0) / (self.y.1 - self.y.0) * (b - t)
    }

    /// The SVG's start: title, axes, ticks and labels.
    fn open(
        &self,
        id: &str,
        title: &str,
        x_label: &str,
        y_label: &str,
        xt: &[f64],
        yt: &[f64],
    ) -> String {
        let (l, t, r, b) = self.area;
        let mut s = String::new();
        let _ = write!(
            s,
            r#"<svg xmlns="http://www.w3.org/2000/svg" id="{id}" viewBox="0 0 {w} {h}" width="{w}" height="{h}" font-family="DejaVu Sans, sans-serif" font-size="12">"#,
            w = Self::W,
            h = Self::H
        );
        let _ = write!(
            s,
            r##"<rect width="100%" height="100%" fill="#fff"/><text class="title" x="{}" y="22" text-anchor="middle" font-size="14" font-weight="bold">{}</text>"##,
            Self::W / 2.0,
            escape(title)
        );
        let xs = xt.get(1).zip(xt.first()).map(|(a, b)| a - b).unwrap_or(1.0);
        let ys = yt.get(1).zip(yt.first()).map(|(a, b)| a - b).unwrap_or(1.0);
        for &v in xt {
            let x = self.px(v);
            let _ = write!(
                s,
                r##"<line x1="{x:.1}" y1="{t}" x2="{x:.1}" y2="{b}" stroke="#e4e4e4"/><text x="{x:.1}" y="{}" text-anchor="middle">{}</text>"##,
                b + 16.0,
                tick_label(v, xs)
            );
        }
        for &v in yt {
            let y = self.py(v);
            let _ = write!(
                s,
                r##"<line x1="{l}" y1="{y:.1}" x2="{r}" y2="{y:.1}" stroke="#e4e4e4"/><text x="{}" y="{:.1}" text-anchor="end">{}</text>"##,
                l - 6.0,
                y + 4.0,
                tick_label(v, ys)
            );
        }
        let _ = write!(
            s,
            r##"<rect x="{l}" y="{t}" width="{}" height="{}" fill="none" stroke="#333"/>"##,
            r - l,
            b - t
        );
        let _ = write!(
            s,
            r#"<text class="x-label" x="{}" y="{}" text-anchor="middle">{}</text>"#,
            (l + r) / 2.0,
            Self::H - 14.0,
            escape(x_label)
        );
        let _ = write!(
            s,
            r#"<text class="y-label" transform="translate(18 {}) rotate(-90)" text-anchor="middle">{}</text>"#,
            (t + b) / 2.0,
            escape(y_label)
        );
        s
    }

    fn empty_note(&self, s: &mut String) {
        let (l, t, r, b) = self.area;
        let _ = write!(
            s,
            r##"<text class="empty" x="{}" y="{}" text-anchor="middle" fill="#777">no reported acquisitions in the spool yet</text>"##,
            (l + r) / 2.0,
            (t + b) / 2.0
        );
    }
}

/// MGD (mGy) against compressed thickness (mm) for every record with a
/// thickness: the patient-specific MGD (filled circles) beside the model
/// breast's (open squares), one pair per acquisition. `data-points` on the
/// root counts the acquisitions drawn.
pub fn mgd_vs_thickness(history: &[AcquisitionRecord]) -> String {
    let pts: Vec<(f64, f64, f64)> = history
        .iter()
        .filter_map(|r| r.thickness_mm.map(|t| (t, r.mgd_mgy, r.model_mgd_mgy)))
        .filter(|(t, a, b)| t.is_finite() && a.is_finite() && b.is_finite())
        .collect();
    let (x0, x1) = pts
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let (x0, x1) = if pts.is_empty() {
        (20.0, 90.0)
    } else {
        (x0 - 2.0, x1 + 2.0)
    };
    let y1 = pts.iter().fold(0.0f64, |m, p| m.max(p.1).max(p.2));
    let y1 = if pts.is_empty() { 3.0 } else { y1 * 1.1 };
    let (xa, xb, xt) = ticks(x0, x1, 7);
    let (ya, yb, yt) = ticks(0.0, y1, 6);
    let f = Frame::new((xa, xb), (ya, yb));
    let mut s = f.open(
        "mgd-thickness",
        "Mean glandular dose against compressed thickness",
        "compressed breast thickness (mm)",
        "MGD of the sweep (mGy)",
        &xt,
        &yt,
    );
    s = s.replacen("<svg ", &format!(r#"<svg data-points="{}" "#, pts.len()), 1);
    if pts.is_empty() {
        f.empty_note(&mut s);
    }
    for &(t, patient, model) in &pts {
        let (x, yp, ym) = (f.px(t), f.py(patient), f.py(model));
        let _ = write!(
            s,
            r##"<line x1="{x:.1}" y1="{yp:.1}" x2="{x:.1}" y2="{ym:.1}" stroke="#bbb"/><rect class="model" x="{:.1}" y="{:.1}" width="8" height="8" fill="none" stroke="#d9730d" stroke-width="1.5"><title>model breast: {model:.3} mGy at {t:.1} mm</title></rect><circle class="patient" cx="{x:.1}" cy="{yp:.1}" r="4.5" fill="#1f5fa8"><title>patient-specific: {patient:.3} mGy at {t:.1} mm</title></circle>"##,
            x - 4.0,
            ym - 4.0
        );
    }
    // The legend above the plot area, clear of the points.
    let (l, t, _, _) = f.area;
    let _ = write!(
        s,
        r##"<g class="legend" transform="translate({l} {})"><circle cx="6" cy="-4" r="4.5" fill="#1f5fa8"/><text x="16" y="0">patient-specific (Monte Carlo)</text><rect x="222" y="-8" width="8" height="8" fill="none" stroke="#d9730d" stroke-width="1.5"/><text x="236" y="0">model breast (same technique)</text></g></svg>"##,
        t - 10.0
    );
    s
}

/// Histogram of the reported glandularity (%), 5-point bins from 0 to the
/// largest value's bin (at least 50 %). `data-points` counts the
/// acquisitions drawn.
pub fn glandularity_histogram(history: &[AcquisitionRecord]) -> String {
    const BIN: f64 = 5.0;
    let g: Vec<f64> = history
        .iter()
        .map(|r| 100.0 * r.glandularity_reported)
        .filter(|g| g.is_finite())
        .collect();
    let top = g.iter().fold(50.0f64, |m, v| m.max(*v)).min(100.0);
    let bins = ((top / BIN).ceil() as usize).max(1);
    let mut counts = vec![0usize; bins];
    for v in &g {
        let i = ((v / BIN).floor().max(0.0) as usize).min(bins - 1);
        counts[i] += 1;
    }
    let most = counts.iter().copied().max().unwrap_or(0).max(1) as f64;
    let (ya, yb, yt) = ticks(0.0, most, most.min(6.0) as usize);
    let xb = bins as f64 * BIN;
    let (_, _, xt) = ticks(0.0, xb, 10);
    let f = Frame::new((0.0, xb), (ya, yb));
    let mut s = f.open(
        "glandularity-histogram",
        "Reported glandularity",
        "glandularity by mass (%)",
        "acquisitions",
        &xt,
        &yt,
    );
    s = s.replacen("<svg ", &format!(r#"<svg data-points="{}" "#, g.len()), 1);
    if g.is_empty() {
        f.empty_note(&mut s);
    }
    for (i, &c) in counts.iter().enumerate().filter(|(_, c)| **c > 0) {
        let (xl, xr) = (f.px(i as f64 * BIN), f.px((i + 1) as f64 * BIN));
        let (yt, yb) = (f.py(c as f64), f.py(0.0));
        let _ = write!(
            s,
            r##"<rect class="bar" data-count="{c}" x="{:.1}" y="{yt:.1}" width="{:.1}" height="{:.1}" fill="#4f8a5b" stroke="#fff"><title>{c} acquisition(s) with {}-{} %</title></rect>"##,
            xl,
            xr - xl,
            yb - yt,
            i as f64 * BIN,
            (i + 1) as f64 * BIN
        );
    }
    s.push_str("</svg>");
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::state::tests::record;

    #[test]
    fn ticks_cover_the_range_at_round_steps() {
        let (a, b, t) = ticks(23.0, 77.0, 7);
        assert!(a <= 23.0 && b >= 77.0);
        assert_eq!(t.first().copied(), Some(a));
        assert_eq!(t.last().copied(), Some(b));
        let step = t[1] - t[0];
        assert_eq!(step, 10.0);
        // 1.37 / 6 = 0.23 per interval: the next 1-2-5 step is 0.5.
        let (_, _, t) = ticks(0.0, 1.37, 6);
        assert!((t[1] - t[0] - 0.5).abs() < 1e-12, "{t:?}");
        assert!(t.len() - 1 <= 6);
        // A degenerate range still has ticks.
        let (a, b, t) = ticks(5.0, 5.0, 4);
        assert!(a < 5.0 && b > 5.0 && t.len() >= 2);
    }

    #[test]
    fn dose_plot_draws_one_pair_per_acquisition_with_labelled_axes() {
        let h = vec![
            record("1", 40.0, 0.3, 1.1, 1),
            record("2", 60.0, 0.1, 1.6, 2),
            AcquisitionRecord {
                thickness_mm: None,
                ..record("3", 0.0, 0.2, 1.0, 3)
            },
        ];
        let s = mgd_vs_thickness(&h);
        assert!(s.contains(r#"data-points="2""#));
        assert_eq!(s.matches(r#"class="patient""#).count(), 2);
        assert_eq!(s.matches(r#"class="model""#).count(), 2);
        assert!(s.contains("compressed breast thickness (mm)"));
        assert!(s.contains("MGD of the sweep (mGy)"));
        assert!(s.ends_with("</svg>"));
        // The larger thickness is drawn to the right, the larger dose higher.
        let cx: Vec<f64> = s
            .match_indices(r#"class="patient" cx=""#)
            .map(|(i, m)| {
                let rest = &s[i + m.len()..];
                rest[..rest.find('"').unwrap()].parse().unwrap()
            })
            .collect();
        assert!(cx[1] > cx[0]);
    }

    #[test]
    fn histogram_counts_every_acquisition_once() {
        let h: Vec<_> = [0.02, 0.07, 0.08, 0.31, 0.99, 0.5]
            .iter()
            .enumerate()
            .map(|(i, g)| record(&i.to_string(), 50.0, *g, 1.0, i as u64))
            .collect();
        let s = glandularity_histogram(&h);
        let total: usize = s
            .match_indices(r#"data-count=""#)
            .map(|(i, m)| {
                let rest = &s[i + m.len()..];
                rest[..rest.find('"').unwrap()].parse::<usize>().unwrap()
            })
            .sum();
        assert_eq!(total, 6);
        assert!(s.contains(r#"data-count="2""#), "two in the 5-10 % bin");
        assert!(s.contains("glandularity by mass (%)"));
    }

    #[test]
    fn empty_history_says_so() {
        for s in [mgd_vs_thickness(&[]), glandularity_histogram(&[])] {
            assert!(s.contains("no reported acquisitions"));
            assert!(s.contains(r#"data-points="0""#));
        }
    }

    #[test]
    fn text_is_escaped() {
        assert_eq!(
            escape(r#"<a href="x">&'"#),
            "&lt;a href=&quot;x&quot;&gt;&amp;&#39;"
        );
    }
}
