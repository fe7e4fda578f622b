//! The status page: one HTML document from a (de-identified) [`Snapshot`],
//! with no external resource. Its figures are separate SVG resources of the
//! same server (`/figures/*.svg`, `/acquisitions/<id>/picture.svg`); its one
//! script ([`PAGE_JS`], served as `/page.js`: the page's content security
//! policy allows no inline script) records on `<body>` how many figures the
//! browser decoded, which the headless-browser test reads.

use crate::plot::escape;
use crate::state::{public_id, AcquisitionRecord, Snapshot};
use std::fmt::Write;

/// Rows of the acquisitions table (newest first).
pub const TABLE_ROWS: usize = 50;

/// The page's script: counts the figures that loaded.
pub const PAGE_JS: &str = r#"// DBToR status page: record which figures the browser decoded.
window.addEventListener('load', function () {
  var figs = Array.prototype.slice.call(document.querySelectorAll('img.figure'));
  var ok = figs.filter(function (i) { return i.complete && i.naturalWidth > 0; });
  var bad = figs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); });
  document.body.setAttribute('data-figures-loaded', String(ok.length));
  document.body.setAttribute('data-figures-broken',
    bad.map(function (i) { return i.getAttribute('src'); }).join(' '));
});
"#;

/// The content security policy the server sends with the page.
pub const CONTENT_SECURITY_POLICY: &str =
    "default-src 'none'; img-src 'self' data:; script-src 'self'; style-src 'unsafe-inline'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'";

/// A unix time as `YYYY-MM-DD HH:MM:SS` UTC (the reports' calendar:
/// `dbt_dicom::dicom_datetime_utc`).
pub fn utc(unix: u64) -> String {
    let (d, t) = dbt_dicom::dicom_datetime_utc(unix);
    let (d, t) = (d.as_bytes(), t.as_bytes());
    let s = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    format!(
        "{}-{}-{} {}:{}:{}",
        s(&d[..4]),
        s(&d[4..6]),
        s(&d[6..8]),
        s(&t[..2]),
        s(&t[2..4]),
        s(&t[4..6])
    )
}

/// The BI-RADS-style composition category's name: its CID 6000 meaning
/// (`dbt_dicom::composition_code`), in lower case; `unknown` otherwise.
pub fn composition_name(letter: &str) -> String {
    let mut c = letter.chars();
    match (c.next(), c.next()) {
        (Some(l), None) => dbt_dicom::composition_code(l)
            .map(|code| code.meaning.to_lowercase())
            .unwrap_or_else(|| "unknown".into()),
        _ => "unknown".into(),
    }
}

/// The number formats of the page (the test compares them with the SRs'
/// values at these precisions): glandularity in % to 0.1, MGD in mGy to
/// 0.001, thickness in mm to 0.1.
pub fn fmt_glandularity(g: f64) -> String {
    format!("{:.1}", 100.0 * g)
}

/// See [`fmt_glandularity`].
pub fn fmt_mgd(mgy: f64) -> String {
    format!("{mgy:.3}")
}

/// A glandularity interval as the page and `dbtor-diag` show it: `lo-hi`
/// in %, or `-` (the cell's title gives the basis or the reason).
pub fn fmt_glandularity_interval(iv: Option<&dbt_dicom::FigureInterval>) -> String {
    iv.and_then(|i| i.describe(100.0, 1))
        .unwrap_or_else(|| "-".into())
}

/// An MGD interval, `lo-hi` in mGy, or `-`.
pub fn fmt_mgd_interval(iv: Option<&dbt_dicom::FigureInterval>) -> String {
    iv.and_then(|i| i.describe(1.0, 3))
        .unwrap_or_else(|| "-".into())
}

/// Both figures with their 95 % intervals in one line, e.g. "glandularity
/// 23.4 % (95 % interval 20.1-28.9 %), MGD 1.428 mGy (95 % interval
/// 1.270-1.610 mGy)"; a figure without one says why.
pub fn interval_summary(
    g: f64,
    g_iv: &dbt_dicom::FigureInterval,
    mgd: f64,
    mgd_iv: &dbt_dicom::FigureInterval,
) -> String {
    let one = |v: String, unit: &str, iv: &dbt_dicom::FigureInterval, shown: Option<String>| {
        match shown {
            Some(r) => format!("{v} {unit} (95 % interval {r} {unit})"),
            None => format!("{v} {unit} (no 95 % interval: {})", iv.basis),
        }
    };
    format!(
        "glandularity {}, MGD {}",
        one(fmt_glandularity(g), "%", g_iv, g_iv.describe(100.0, 1)),
        one(fmt_mgd(mgd), "mGy", mgd_iv, mgd_iv.describe(1.0, 3))
    )
}

/// The URL of an acquisition's quick-look picture.
pub fn picture_url(id: &str) -> String {
    format!("/acquisitions/{}/picture.svg", public_id(id))
}

const STYLE: &str = "body{font-family:'DejaVu Sans',sans-serif;margin:16px 24px;color:#222;max-width:1250px}\
h1{font-size:22px;margin:0 0 4px}h2{font-size:17px;margin:22px 0 8px;border-bottom:1px solid #ccc}\
table{border-collapse:collapse;font-size:13px}td,th{padding:3px 8px;border-bottom:1px solid #e4e4e4;text-align:left}\
th{background:#f2f2f2}td.num{text-align:right;font-variant-numeric:tabular-nums}\
.badge{display:inline-block;padding:2px 10px;border-radius:10px;color:#fff;font-weight:bold}\
.ok{background:#2e7d32}.bad{background:#c62828}.figs{display:flex;flex-wrap:wrap;gap:16px}\
img.figure{border:1px solid #ddd;max-width:100%;height:auto}.note{color:#666;font-size:12px}";

/// The status page of `s` (de-identify it first: the page shows what it is
/// given), generated at `now_unix`.
pub fn render(s: &Snapshot, now_unix: u64) -> String {
    let st = &s.status;
    let healthy = st.healthy();
    let mut h = String::new();
    let latest = s.history.last();
    let figures = 2 + usize::from(latest.is_some());
    let _ = write!(
        h,
        r#"<!doctype html><html lang="en"><head><meta charset="utf-8"><meta http-equiv="refresh" content="30"><title>DBToR status: {state}</title><style>{STYLE}</style></head><body data-figures-expected="{figures}" data-healthy="{healthy}"><h1>DBToR gantry PC</h1><p><span id="health" class="badge {cls}">{verdict}</span> <span class="note">read-only; generated {now} UTC, refreshed every 30 s; the same state as JSON: <a href="/status.json">/status.json</a></span></p>"#,
        state = escape(&st.state),
        cls = if healthy { "ok" } else { "bad" },
        verdict = if healthy {
            "healthy"
        } else {
            "fault since the last report"
        },
        now = utc(now_unix),
    );
    // State.
    let _ = write!(
        h,
        r#"<h2>Daemon</h2><table id="daemon"><tr><th>state</th><td id="state">{}{}</td></tr><tr><th>reconstructor</th><td id="reconstructor">{}</td></tr><tr><th>kernels</th><td id="kernels">{}</td></tr><tr><th>version, pid</th><td>{} (pid {})</td></tr><tr><th>started</th><td>{} UTC</td></tr><tr><th>last update</th><td>{} UTC</td></tr><tr><th>reported since start</th><td id="processed">{}</td></tr><tr><th>recovered from the spool at start</th><td>{}</td></tr><tr><th>waiting in the spool</th><td>{}</td></tr><tr><th>faults since start</th><td id="fault-total">{}</td></tr></table>"#,
        escape(&st.state),
        st.current
            .as_deref()
            .map(|c| format!(" ({})", escape(c)))
            .unwrap_or_default(),
        escape(&st.reconstructor),
        if st.kernels.is_empty() {
            "-".to_string()
        } else {
            st.kernels
                .iter()
                .map(|k| escape(k))
                .collect::<Vec<_>>()
                .join("<br>")
        },
        escape(&st.version),
        st.pid,
        utc(st.started_unix),
        utc(st.updated_unix),
        st.processed,
        st.recovered,
        st.incoming,
        st.fault_total(),
    );
    // The DICOM input.
    if let Some(d) = &st.dicom_input {
        let _ = write!(
            h,
            r#"<h2>DICOM input</h2><table id="dicom-input"><tr><th>listening as</th><td>{}</td></tr><tr><th>associations open, since start</th><td id="associations">{}, {}</td></tr><tr><th>objects kept, duplicates, refused</th><td id="dicom-objects">{}, {}, {}</td></tr><tr><th>presentation contexts refused</th><td>{}</td></tr>"#,
            escape(&d.listening),
            d.associations_open,
            d.associations_total,
            d.objects_stored,
            d.objects_duplicate,
            d.objects_refused,
            d.contexts_refused,
        );
        for w in &d.waiting {
            let _ = write!(
                h,
                r#"<tr><th>sweep waiting for views</th><td class="waiting">{} {}: {} of {} views, the last at {} UTC (faulted after {} s)</td></tr>"#,
                escape(&w.laterality),
                escape(&w.view),
                w.views_received,
                w.views_expected,
                utc(w.last_view_unix),
                d.quiet_time_s,
            );
        }
        h.push_str("</table>");
    }
    // The latest acquisition's picture.
    if let Some(r) = latest {
        let _ = write!(
            h,
            r#"<h2>Latest acquisition: {id}</h2><p>{summary}</p><img class="figure" id="latest-picture" src="{url}" alt="coronal slice, classification and mid-planes of acquisition {id}">"#,
            id = escape(&r.acquisition),
            summary = summary(r),
            url = escape(&picture_url(&r.acquisition)),
        );
    }
    // Trends.
    let _ = write!(
        h,
        r#"<h2>Trends over the spool's history ({n} reported acquisition{s})</h2><div class="figs"><img class="figure" id="mgd-thickness" src="/figures/mgd-thickness.svg" alt="MGD against compressed thickness"><img class="figure" id="glandularity-histogram" src="/figures/glandularity.svg" alt="glandularity histogram"></div>"#,
        n = s.history.len(),
        s = if s.history.len() == 1 { "" } else { "s" },
    );
    // Acquisitions.
    let _ = write!(
        h,
        r#"<h2>Acquisitions (newest first, up to {TABLE_ROWS})</h2><table id="acquisitions"><tr><th>acquisition</th><th>reported (UTC)</th><th>thickness (mm)</th><th>glandularity (%)</th><th>95 % interval (%)</th><th>composition</th><th>MGD patient (mGy)</th><th>95 % interval (mGy)</th><th>MGD model breast (mGy)</th><th>reconstructor</th><th>flags</th><th>picture</th></tr>"#
    );
    for r in s.history.iter().rev().take(TABLE_ROWS) {
        let comp = composition_cell(r);
        let _ = write!(
            h,
            r#"<tr data-acquisition="{id}"><td>{id}</td><td>{at}</td><td class="num thickness">{t}</td><td class="num glandularity">{g}</td><td class="num glandularity-interval" title="{giv_basis}">{giv}</td><td class="composition" data-category="{c}">{c} ({cn})</td><td class="num mgd">{mgd}</td><td class="num mgd-interval" title="{miv_basis}">{miv}</td><td class="num model-mgd">{model}</td><td>{rec}{cal}</td><td>{flags}</td><td><a href="{url}">picture</a></td></tr>"#,
            id = escape(&r.acquisition),
            at = utc(r.finished_unix),
            t = r
                .thickness_mm
                .map(|t| format!("{t:.1}"))
                .unwrap_or_else(|| "-".into()),
            g = fmt_glandularity(r.glandularity_reported),
            giv = fmt_glandularity_interval(r.glandularity_interval.as_ref()),
            giv_basis = escape(
                r.glandularity_interval
                    .as_ref()
                    .map_or("", |i| i.basis.as_str())
            ),
            miv = fmt_mgd_interval(r.mgd_interval.as_ref()),
            miv_basis = escape(r.mgd_interval.as_ref().map_or("", |i| i.basis.as_str())),
            c = escape(comp.0),
            cn = escape(&comp.1),
            mgd = fmt_mgd(r.mgd_mgy),
            model = fmt_mgd(r.model_mgd_mgy),
            rec = escape(&r.reconstructor),
            cal = if r.calibrated { ", calibrated" } else { "" },
            flags = escape(&r.flags.join(", ")),
            url = escape(&picture_url(&r.acquisition)),
        );
    }
    h.push_str("</table>");
    if !s.unreadable.is_empty() {
        h.push_str(
            r#"<p class="note">spool entries whose record cannot be read:</p><ul id="unreadable">"#,
        );
        for u in &s.unreadable {
            let _ = write!(
                h,
                "<li>{}: {}</li>",
                escape(&u.acquisition),
                escape(&u.reason)
            );
        }
        h.push_str("</ul>");
    }
    // Warnings: delivered reports a reader must not take as they stand.
    h.push_str(
        r#"<h2>Warnings</h2><table id="warning-counts"><tr><th>kind</th><th>since start</th></tr>"#,
    );
    let _ = write!(
        h,
        r#"<tr class="warning" data-kind="{k}"><td>{k} (density not confirmed by the physics: no composition category reported)</td><td class="num">{n}</td></tr>"#,
        k = crate::state::DENSITY_CHECK_WARNING,
        n = st
            .warning_counts
            .get(crate::state::DENSITY_CHECK_WARNING)
            .copied()
            .unwrap_or(0),
    );
    for (k, n) in st
        .warning_counts
        .iter()
        .filter(|(k, _)| k.as_str() != crate::state::DENSITY_CHECK_WARNING)
    {
        let _ = write!(
            h,
            r#"<tr class="warning" data-kind="{k}"><td>{k}</td><td class="num">{n}</td></tr>"#,
            k = escape(k)
        );
    }
    h.push_str("</table>");
    // Faults.
    h.push_str(
        r#"<h2>Faults</h2><table id="fault-counts"><tr><th>kind</th><th>since start</th></tr>"#,
    );
    for (k, n) in &st.fault_counts {
        let _ = write!(
            h,
            "<tr><td>{}</td><td class=\"num\">{n}</td></tr>",
            escape(k)
        );
    }
    h.push_str(r#"</table><p></p><table id="faults"><tr><th>at (UTC)</th><th>kind</th><th>acquisition</th><th>what happened</th></tr>"#);
    for f in st.faults.iter().rev().take(20) {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            utc(f.at_unix),
            escape(&f.kind),
            escape(f.acquisition.as_deref().unwrap_or("-")),
            escape(&f.message)
        );
    }
    h.push_str(r#"</table><script src="/page.js"></script></body></html>"#);
    h
}

/// A record's composition as the table shows it: `(letter or "-", what it
/// means)`; a density the physics did not confirm has none, and says so.
fn composition_cell(r: &AcquisitionRecord) -> (&str, String) {
    match (&r.composition, &r.density_check) {
        (Some(c), _) => (c.as_str(), composition_name(c)),
        (None, Some(chk)) if !chk.confirmed => (
            "-",
            format!(
                "{}: not confirmed by the physics, physics density {} %",
                crate::state::DENSITY_CHECK_WARNING,
                chk.physics_glandularity
                    .map_or("none".into(), |g| format!("{:.1}", 100.0 * g))
            ),
        ),
        (None, _) => ("-", composition_name("-")),
    }
}

/// One line about a record: what its two reports say.
fn summary(r: &AcquisitionRecord) -> String {
    let comp = composition_cell(r);
    let check = match &r.density_check {
        Some(c) if c.confirmed => format!(
            ", confirmed by the physics density ({} %)",
            c.physics_glandularity
                .map_or("-".into(), |g| format!("{:.1}", 100.0 * g))
        ),
        Some(c) => format!(
            ", NOT confirmed by the physics density: {}",
            escape(&c.reasons.join("; "))
        ),
        None => String::new(),
    };
    let interval = |iv: Option<&dbt_dicom::FigureInterval>, scale, decimals, unit: &str| {
        iv.map_or(String::new(), |i| match i.describe(scale, decimals) {
            Some(r) => format!(", 95 % interval {r} {unit}"),
            None => format!(", no 95 % interval: {}", escape(&i.basis)),
        })
    };
    format!(
        "glandularity {} % ({}{}), composition {} ({}){check}, MGD {} mGy patient-specific{}, {} mGy model breast, {}",
        fmt_glandularity(r.glandularity_reported),
        if r.calibrated { "calibrated" } else { "uncalibrated" },
        interval(r.glandularity_interval.as_ref(), 100.0, 1, "%"),
        escape(comp.0),
        escape(&comp.1),
        fmt_mgd(r.mgd_mgy),
        interval(r.mgd_interval.as_ref(), 1.0, 3, "mGy"),
        fmt_mgd(r.model_mgd_mgy),
        r.thickness_mm
            .map(|t| format!("{t:.1} mm compressed"))
            .unwrap_or_else(|| "thickness not recorded".into()),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::state::tests::record;
    use crate::state::{FaultRecord, Status};

    #[test]
    fn utc_matches_known_dates() {
        assert_eq!(utc(0), "1970-01-01 00:00:00");
        assert_eq!(utc(951_782_400), "2000-02-29 00:00:00");
        assert_eq!(utc(1_795_979_045), "2026-11-29 19:04:05");
    }

    #[test]
    fn page_shows_state_records_figures_and_faults_escaped() {
        let mut st = Status::starting("1.2", 7, 1_700_000_000, "dbtor".into());
        let r = record("1732467000123", 52.0, 0.234, 1.4567, 1_700_000_100);
        st.push_reported(r.clone());
        st.push_fault(FaultRecord {
            at_unix: 1_700_000_200,
            acquisition: None,
            kind: "link".into(),
            message: "<script>alert(1)</script>".into(),
        });
        let s = Snapshot {
            status: st,
            history: vec![r],
            unreadable: vec![],
        };
        let h = render(&s, 1_700_000_300);
        assert!(h.contains(r#"data-figures-expected="3""#));
        assert!(h.contains(r#"data-healthy="false""#));
        assert!(h.contains(r#"<td class="num glandularity">23.4</td>"#));
        assert!(h.contains(r#"<td class="num mgd">1.457</td>"#));
        assert!(h.contains(r#"<td class="num model-mgd">1.602</td>"#));
        // The 95 % intervals (issue #48 point 4), each with its basis.
        assert!(h.contains(
            r#"<td class="num glandularity-interval" title="95 % prediction interval from 14 validation breasts">18.0-27.3</td>"#
        ), "{h}");
        assert!(h.contains(r#"<td class="num mgd-interval" title="95 % prediction interval from 14 validation breasts">1.250-1.625</td>"#));
        assert!(h.contains("glandularity 23.4 % (calibrated, 95 % interval 18.0-27.3 %)"));
        assert!(h.contains("MGD 1.457 mGy patient-specific, 95 % interval 1.250-1.625 mGy"));
        let mut none = s.history[0].clone();
        none.mgd_interval = Some(dbt_dicom::FigureInterval {
            limits: None,
            basis: "the density is not confirmed <by the physics>".into(),
        });
        let line = summary(&none);
        assert!(
            line.contains("no 95 % interval: the density is not confirmed &lt;by the physics&gt;"),
            "{line}"
        );
        assert!(interval_summary(
            0.234,
            none.glandularity_interval.as_ref().unwrap(),
            1.4567,
            none.mgd_interval.as_ref().unwrap()
        )
        .ends_with(
            "MGD 1.457 mGy (no 95 % interval: the density is not confirmed <by the physics>)"
        ));
        assert!(h.contains("c (heterogeneously dense)"));
        assert!(h.contains("/acquisitions/1732467000123/picture.svg"));
        assert!(h.contains("/figures/mgd-thickness.svg"));
        assert!(!h.contains("<script>alert"), "fault text is escaped");
        assert!(h.contains("&lt;script&gt;alert(1)&lt;/script&gt;"));
        assert_eq!(h.matches("<script").count(), 1, "one external script");
    }

    #[test]
    fn page_without_history_expects_the_two_trend_figures() {
        let st = Status::starting("1.2", 7, 1_700_000_000, "mltr".into());
        let s = Snapshot {
            status: st,
            history: vec![],
            unreadable: vec![],
        };
        let h = render(&s, 1_700_000_001);
        assert!(h.contains(r#"data-figures-expected="2""#));
        assert!(h.contains(r#"data-healthy="true""#));
        assert!(!h.contains("latest-picture"));
    }
}
