//! The glandularity calibration file of a model folder (adapter: file I/O):
//! `dbt-eval calibrate` writes it, the daemon and `dbtor-process` read it
//! when they load the model. The calibration itself is
//! `dbt_tissue::GlandularityCalibration` (pure); the pipeline applies it.

use dbt_tissue::{ClassifyOptions, GlandularityCalibration};
use serde::Serialize;
use thiserror::Error;

/// A calibration file is unreadable or belongs to another model.
#[derive(Debug, Error)]
#[error("glandularity calibration {path}: {reason}")]
pub struct CalibrationError {
    /// The file.
    pub path: std::path::PathBuf,
    /// Why.
    pub reason: String,
}

/// The calibration file in a model folder.
pub const CALIBRATION_FILE: &str = "glandularity-calibration.json";

/// Format tag of [`CALIBRATION_FILE`].
pub const CALIBRATION_FORMAT: &str = "dbtor-glandularity-calibration/1";

/// A model's glandularity calibrations ([`CALIBRATION_FILE`]): one per
/// precision label, for the partial-volume estimate under one
/// classification, bound to the model by the SHA-256 of its manifest.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct CalibrationFile {
    /// [`CALIBRATION_FORMAT`].
    pub format: String,
    /// The model's name.
    pub model: String,
    /// SHA-256 of the model's manifest.json.
    pub manifest_sha256: String,
    /// The classification the calibrations were fit with.
    pub classification: ClassifyOptions,
    /// Per precision label (`fp32`, `int8`, `int8 (fp32: ...)`).
    pub calibrations: std::collections::BTreeMap<String, GlandularityCalibration>,
    /// How each was fit (command, phantoms, residuals), per precision label.
    #[serde(default)]
    pub fits: std::collections::BTreeMap<String, serde_json::Value>,
}

impl CalibrationFile {
    /// Read and check `path`: the format, and that it was fit for `model`
    /// (its manifest's SHA-256).
    pub fn read(
        path: &std::path::Path,
        model: &dbt_dbtor::Dbtor,
    ) -> Result<Self, CalibrationError> {
        let fail = |reason: String| CalibrationError {
            path: path.to_path_buf(),
            reason,
        };
        let text = std::fs::read_to_string(path).map_err(|e| fail(e.to_string()))?;
        let f: Self = serde_json::from_str(&text).map_err(|e| fail(e.to_string()))?;
        check_binding(
            &f.format,
            CALIBRATION_FORMAT,
            &f.manifest_sha256,
            model,
            "dbt-eval calibrate",
        )
        .map_err(fail)?;
        Ok(f)
    }
}

/// What every file bound to a model checks on reading: its format tag is
/// `expected`, and it was made for `model` (the SHA-256 of its manifest);
/// `refit` names the command that writes it again.
pub(crate) fn check_binding(
    format: &str,
    expected: &str,
    manifest_sha: &str,
    model: &dbt_dbtor::Dbtor,
    refit: &str,
) -> Result<(), String> {
    if format != expected {
        return Err(format!("format {format:?}, expected {expected:?}"));
    }
    let sha = manifest_sha256(model).map_err(|e| e.to_string())?;
    if manifest_sha != sha {
        return Err(format!(
            "fit for another model (manifest SHA-256 {manifest_sha}), not {} ({sha}); refit with `{refit}`",
            model.manifest().name
        ));
    }
    Ok(())
}

impl CalibrationFile {
    /// The file at `path` to add `model`'s calibrations to: as read where
    /// it was fit for `model` with `classification` (its other entries
    /// kept), else an empty one bound to `model` (a missing, unreadable,
    /// other model's or other classification's file is started afresh).
    pub fn open_or_new(
        path: &std::path::Path,
        model: &dbt_dbtor::Dbtor,
        classification: ClassifyOptions,
    ) -> Result<Self, dbt_dbtor::DbtorError> {
        match Self::read(path, model) {
            Ok(f) if f.classification == classification => Ok(f),
            _ => Ok(Self {
                format: CALIBRATION_FORMAT.into(),
                model: model.manifest().name.clone(),
                manifest_sha256: manifest_sha256(model)?,
                classification,
                calibrations: Default::default(),
                fits: Default::default(),
            }),
        }
    }
}

/// SHA-256 of a loaded model's manifest.json.
pub fn manifest_sha256(model: &dbt_dbtor::Dbtor) -> Result<String, dbt_dbtor::DbtorError> {
    dbt_dbtor::sha256_file(&model.root().join("manifest.json"))
}

/// What the counts went through before the network: the input a
/// calibration was fit on, part of its key in [`CalibrationFile`]. The
/// network's partial-volume estimate carries a bias that depends on it (the
/// scatter removal's residual on clinical acquisitions, eval/README.md), so a
/// firmware that corrects its counts reads the calibration fit on counts
/// corrected the same way where the file has one.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct InputCorrections {
    /// The scatter was removed (`dbt_pipeline::descatter`).
    pub scatter_removed: bool,
    /// The beam hardening was linearised (`dbt_pipeline::linearise`).
    pub linearised: bool,
    /// ... on each ray's known path (`dbt_pipeline::linearise::PathModel::Known`)
    /// rather than as one reference tissue; with `linearised` only.
    pub known_path: bool,
    /// ... and the noise matched to the training level's
    /// (`dbt_pipeline::noise_match`); with `linearised` only.
    pub noise_matched: bool,
    /// ... for an a-Se detector (`dbt_materials::ConverterMaterial::ASe`)
    /// rather than CsI: its linearised counts read 1.6-3.4 % otherwise
    /// than CsI's would (`dbt_pipeline::linearise`), so a calibration fit
    /// on CsI's is not theirs; with `linearised` only.
    pub a_se_detector: bool,
    /// Neither, on purpose: a polychromatic detector's counts with their
    /// scatter, read by a network trained on such acquisitions (issue
    /// #27's other design; `dbt_pipeline::PipelineOptions::scatter_in_input`).
    pub uncorrected_clinical: bool,
}

impl InputCorrections {
    /// The corrections `opts` apply to the counts, with the noise matched
    /// where `noise_matched` (asked for before a model sets it in `opts`).
    pub fn of(opts: &dbt_pipeline::PipelineOptions, noise_matched: bool) -> Self {
        Self {
            scatter_removed: opts.descatter.is_some(),
            linearised: opts.linearise.is_some(),
            known_path: opts
                .linearise
                .is_some_and(|l| l.path != dbt_pipeline::linearise::PathModel::Reference),
            noise_matched,
            a_se_detector: opts.linearise.is_some_and(|l| {
                l.detector.converter.material == dbt_materials::ConverterMaterial::ASe
            }),
            uncorrected_clinical: opts.scatter_in_input,
        }
    }

    /// The corrections in words (`none`, `scatter removed`, `linearised`,
    /// `scatter removed + linearised`, each linearisation also `... on the
    /// known path`, each linearisation also `... + noise matched`, or
    /// `uncorrected clinical counts`,
    /// which takes precedence: whose callers refuse it together with a
    /// correction).
    pub fn describe(&self) -> String {
        let mut out = self.describe_corrections().to_string();
        if self.linearised && !self.uncorrected_clinical {
            if self.a_se_detector {
                out.push_str(" for a-Se");
            }
            if self.noise_matched {
                out.push_str(" + noise matched");
            }
        }
        out
    }

    fn describe_corrections(&self) -> &'static str {
        if self.uncorrected_clinical {
            return "uncorrected clinical counts";
        }
        match (self.scatter_removed, self.linearised, self.known_path) {
            (false, false, _) => "none",
            (true, false, _) => "scatter removed",
            (false, true, false) => "linearised",
            (true, true, false) => "scatter removed + linearised",
            (false, true, true) => "linearised on the known path",
            (true, true, true) => "scatter removed + linearised on the known path",
        }
    }

    /// The key of a calibration for `precision_label` fit on inputs so
    /// corrected: the label alone for plain (mono-energetic, uncorrected)
    /// inputs (the files written before issue #27 keep their meaning), else
    /// `label | corrections` (`int8 | uncorrected clinical counts` for the
    /// detector's clinical counts read as they are).
    pub fn key(&self, precision_label: &str) -> String {
        if *self == Self::default() {
            precision_label.to_string()
        } else {
            format!("{precision_label} | {}", self.describe())
        }
    }

    /// The key of a calibration for acquisitions with the beam `beam`
    /// (an anode/filter name, e.g. `W/Al`) other than the paper's W/Rh,
    /// whose calibration is [`key`](Self::key)'s: `key | beam W/Al`.
    pub fn beam_key(&self, precision_label: &str, beam: &str) -> String {
        format!("{} | beam {beam}", self.key(precision_label))
    }
}

/// The fit record's field that names the W/Rh entry a beam's entry is a
/// copy of (`dbt-eval beam-bar --write`).
pub const KEPT_FROM_FIELD: &str = "w_rh_calibration_kept";

impl CalibrationFile {
    /// Put `cal` under `key` with its fit record `fit`. A refit entry
    /// invalidates the beams' entries copied from it (their bar was run
    /// against the old figures: [`KEPT_FROM_FIELD`]): those are removed,
    /// and their keys returned, so that their acquisitions are reported
    /// physics-only or refused until the bar is run again, never read with
    /// a copy of figures the model no longer has.
    pub fn insert_fit(
        &mut self,
        key: &str,
        cal: GlandularityCalibration,
        fit: serde_json::Value,
    ) -> Vec<String> {
        let changed = self.calibrations.get(key) != Some(&cal);
        self.calibrations.insert(key.to_string(), cal);
        self.fits.insert(key.to_string(), fit);
        if !changed {
            return Vec::new();
        }
        let stale: Vec<String> = self
            .fits
            .iter()
            .filter(|(k, f)| k.as_str() != key && f[KEPT_FROM_FIELD].as_str() == Some(key))
            .map(|(k, _)| k.clone())
            .collect();
        for k in &stale {
            self.calibrations.remove(k);
            self.fits.remove(k);
        }
        stale
    }

    /// The entry under `key` as the firmware applies it: with the
    /// thicknesses its thickness term was fit on (stated, else its fit's
    /// cases'); `None` without one.
    pub fn applied(&self, key: &str) -> Option<GlandularityCalibration> {
        self.calibrations
            .get(key)
            .map(|c| with_fitted_range(self, key, *c))
    }
}

/// `c` of the entry `key` of `f`, with the thicknesses its thickness term
/// was fit on: the ones it states, else those of its fit's cases (the
/// files written before the range was stored beside the calibration).
fn with_fitted_range(
    f: &CalibrationFile,
    key: &str,
    mut c: GlandularityCalibration,
) -> GlandularityCalibration {
    if c.per_mm != 0.0 && c.thickness_range_mm.is_none() {
        let t: Vec<f64> = f.fits.get(key).map_or_else(Vec::new, |fit| {
            fit["cases"].as_array().map_or_else(Vec::new, |cs| {
                cs.iter()
                    .filter_map(|x| x["thickness_mm"].as_f64())
                    .collect()
            })
        });
        if !t.is_empty() {
            let lo = t.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = t.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            c.thickness_range_mm = Some([lo, hi]);
        }
    }
    c
}

/// The entries of `f` for `precision_label` and `input` fit on another
/// beam than W/Rh ([`InputCorrections::beam_key`]), as (beam name,
/// calibration), by beam name.
pub fn pick_beam_calibrations(
    f: &CalibrationFile,
    precision_label: &str,
    input: InputCorrections,
) -> Vec<(String, GlandularityCalibration)> {
    let prefix = input.beam_key(precision_label, "");
    f.calibrations
        .iter()
        .filter_map(|(k, c)| {
            let beam = k.strip_prefix(&prefix)?;
            (!beam.is_empty() && !beam.contains(" | "))
                .then(|| (beam.to_string(), with_fitted_range(f, k, *c)))
        })
        .collect()
}

/// The entry of `f` for `precision_label` and `input`: the one fit on inputs
/// corrected as `input` where there is one, else the plain one (fit on
/// mono-energetic inputs, which the corrections aim to reproduce; logged as
/// a warning naming both), else `None`. Uncorrected clinical counts
/// ([`InputCorrections::uncorrected_clinical`]) are nothing like
/// mono-energetic ones: they read only their own entry, never the plain
/// one (`None` and a warning naming the refit otherwise). Returns the
/// calibration and the key it was found under.
pub fn pick_calibration(
    f: &CalibrationFile,
    precision_label: &str,
    input: InputCorrections,
) -> Option<(GlandularityCalibration, String)> {
    let exact = input.key(precision_label);
    if let Some(c) = f.calibrations.get(&exact) {
        return Some((with_fitted_range(f, &exact, *c), exact));
    }
    if input.uncorrected_clinical {
        tracing::warn!(
            wanted = %exact,
            "no calibration fit on uncorrected clinical counts; reporting uncalibrated (fit one with `dbt-eval calibrate --physics clinical --uncorrected`)"
        );
        return None;
    }
    let plain = InputCorrections::default().key(precision_label);
    let c = f.calibrations.get(&plain)?;
    if input != InputCorrections::default() {
        tracing::warn!(
            wanted = %exact,
            using = %plain,
            "no calibration fit on inputs with these corrections; using the plain one, fit on mono-energetic inputs (refit with `dbt-eval calibrate --physics clinical` and the corrections)"
        );
    }
    Some((*c, plain))
}

/// A model's calibrations for one precision, classification and input
/// corrections: the paper's W/Rh beam's and those of other beams.
pub type Calibrations = (
    Option<GlandularityCalibration>,
    Vec<(String, GlandularityCalibration)>,
);

/// The calibrations of `model` at its precision for `classify` and inputs
/// corrected as `input`, read once from its folder ([`CALIBRATION_FILE`]):
/// the W/Rh one ([`pick_calibration`]) and the other beams'
/// ([`pick_beam_calibrations`]). None where there is no file or it was fit
/// with another classification, no W/Rh one where it has no entry for this
/// precision (the estimate is then reported uncalibrated, and a warning
/// logged). A file of another model is an error.
pub fn load_calibrations(
    model: &dbt_dbtor::Dbtor,
    classify: &ClassifyOptions,
    input: InputCorrections,
) -> Result<Calibrations, CalibrationError> {
    let path = model.root().join(CALIBRATION_FILE);
    if !path.is_file() {
        return Ok((None, Vec::new()));
    }
    let f = CalibrationFile::read(&path, model)?;
    let label = model.precision_label();
    if &f.classification != classify {
        tracing::warn!(path = %path.display(), "the calibration was fit with another classification; glandularity reported uncalibrated");
        return Ok((None, Vec::new()));
    }
    let base = pick_calibration(&f, &label, input).map(|(c, _)| c);
    if base.is_none() {
        tracing::warn!(path = %path.display(), precision = %label, "no calibration for this precision; glandularity reported uncalibrated");
    }
    Ok((base, pick_beam_calibrations(&f, &label, input)))
}

/// The W/Rh calibration of [`load_calibrations`].
pub fn load_calibration(
    model: &dbt_dbtor::Dbtor,
    classify: &ClassifyOptions,
    input: InputCorrections,
) -> Result<Option<GlandularityCalibration>, CalibrationError> {
    Ok(load_calibrations(model, classify, input)?.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A refit entry removes the beams' entries copied from it (and only
    /// those); the same figures written again keep them.
    #[test]
    fn a_refit_removes_the_beam_entries_copied_from_it() {
        let cal = |o: f64| GlandularityCalibration {
            offset: o,
            slope: 1.0,
            per_mm: 0.0,
            thickness_range_mm: None,
        };
        let mut f = CalibrationFile {
            format: CALIBRATION_FORMAT.into(),
            model: "m".into(),
            manifest_sha256: String::new(),
            classification: Default::default(),
            calibrations: Default::default(),
            fits: Default::default(),
        };
        assert!(f
            .insert_fit("int8 | c", cal(0.1), serde_json::json!({}))
            .is_empty());
        f.insert_fit("int8", cal(0.2), serde_json::json!({}));
        f.insert_fit(
            "int8 | c | beam W/Ag",
            cal(0.1),
            serde_json::json!({ (KEPT_FROM_FIELD): "int8 | c" }),
        );
        f.insert_fit("int8 | c | beam W/Al", cal(0.3), serde_json::json!({}));
        // The same figures again: nothing removed.
        assert!(f
            .insert_fit("int8 | c", cal(0.1), serde_json::json!({}))
            .is_empty());
        assert!(f
            .insert_fit("int8", cal(0.25), serde_json::json!({}))
            .is_empty());
        assert_eq!(f.calibrations.len(), 4);
        let removed = f.insert_fit("int8 | c", cal(0.11), serde_json::json!({}));
        assert_eq!(removed, ["int8 | c | beam W/Ag"]);
        assert!(!f.calibrations.contains_key("int8 | c | beam W/Ag"));
        assert!(!f.fits.contains_key("int8 | c | beam W/Ag"));
        assert!(f.calibrations.contains_key("int8 | c | beam W/Al"));
    }

    /// A calibration file read and written again keeps every float it
    /// held, bit for bit, the fits' provenance included (`dbt-eval
    /// calibrate` and `beam-bar` rewrite the file to add an entry; serde_json
    /// without `float_roundtrip` moved the last digit of about one value in
    /// ten, e.g. 0.39320223059274373 to 0.3932022305927438).
    #[test]
    fn a_rewritten_file_keeps_every_float() {
        let awkward = [
            0.39320223059274373,
            48.800000000000004,
            0.11430478668248159,
            -5.6239735091168086e-15,
            1e-7,
            0.1 + 0.2,
        ];
        let f = CalibrationFile {
            format: CALIBRATION_FORMAT.into(),
            model: "m".into(),
            manifest_sha256: "0".repeat(64),
            classification: Default::default(),
            calibrations: awkward
                .iter()
                .enumerate()
                .map(|(i, &v)| {
                    (
                        format!("int8 | {i}"),
                        GlandularityCalibration {
                            offset: v,
                            slope: 1.0 + v,
                            per_mm: v / 3.0,
                            thickness_range_mm: Some([v, 2.0 * v]),
                        },
                    )
                })
                .collect(),
            fits: [(
                "int8 | 0".to_string(),
                serde_json::json!({ "cases": awkward }),
            )]
            .into_iter()
            .collect(),
        };
        let text = serde_json::to_string_pretty(&f).unwrap();
        let back: CalibrationFile = serde_json::from_str(&text).unwrap();
        for (k, c) in &f.calibrations {
            let b = back.calibrations[k];
            assert_eq!(
                [c.offset, c.slope, c.per_mm].map(f64::to_bits),
                [b.offset, b.slope, b.per_mm].map(f64::to_bits),
                "{k}"
            );
            assert_eq!(
                c.thickness_range_mm.map(|r| r.map(f64::to_bits)),
                b.thickness_range_mm.map(|r| r.map(f64::to_bits)),
                "{k}"
            );
        }
        let cases: Vec<f64> =
            serde_json::from_value(back.fits["int8 | 0"]["cases"].clone()).unwrap();
        assert_eq!(
            cases.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            awkward.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
        assert_eq!(serde_json::to_string_pretty(&back).unwrap(), text);
    }

    /// Another beam's calibrations sit under their own keys: picked by the
    /// corrections and precision they were fit for, never as the W/Rh one;
    /// so do the known-path linearisation's.
    #[test]
    fn beam_calibrations_have_their_own_keys() {
        let corrected = InputCorrections {
            scatter_removed: true,
            linearised: true,
            ..Default::default()
        };
        let raw = InputCorrections {
            uncorrected_clinical: true,
            ..Default::default()
        };
        assert_eq!(raw.key("int8"), "int8 | uncorrected clinical counts");
        // Uncorrected clinical counts never read the plain (mono) entry.
        let mono = GlandularityCalibration {
            offset: 0.0,
            slope: 1.0,
            per_mm: 0.0,
            thickness_range_mm: None,
        };
        let mut only_plain = CalibrationFile {
            format: CALIBRATION_FORMAT.into(),
            model: "m".into(),
            manifest_sha256: String::new(),
            classification: Default::default(),
            calibrations: [("int8".to_string(), mono)].into_iter().collect(),
            fits: Default::default(),
        };
        assert!(pick_calibration(&only_plain, "int8", raw).is_none());
        assert!(pick_calibration(&only_plain, "int8", corrected).is_some());
        let own = GlandularityCalibration {
            offset: 0.1,
            slope: 1.2,
            per_mm: 0.0,
            thickness_range_mm: None,
        };
        only_plain.calibrations.insert(raw.key("int8"), own);
        assert_eq!(
            pick_calibration(&only_plain, "int8", raw).map(|(c, _)| c),
            Some(own)
        );
        assert_eq!(
            corrected.beam_key("int8", "W/Al"),
            "int8 | scatter removed + linearised | beam W/Al"
        );
        assert_eq!(
            InputCorrections::default().beam_key("fp32", "W/Al"),
            "fp32 | beam W/Al"
        );
        let cal = |o: f64| GlandularityCalibration {
            offset: o,
            slope: 1.0,
            per_mm: 0.0,
            thickness_range_mm: None,
        };
        let f = CalibrationFile {
            format: CALIBRATION_FORMAT.into(),
            model: "m".into(),
            manifest_sha256: "x".into(),
            classification: ClassifyOptions::default(),
            calibrations: [
                ("int8".to_string(), cal(0.1)),
                ("int8 | scatter removed + linearised".to_string(), cal(0.2)),
                (
                    "int8 | scatter removed + linearised | beam W/Al".to_string(),
                    cal(0.3),
                ),
                (
                    "fp32 | scatter removed + linearised | beam W/Al".to_string(),
                    cal(0.4),
                ),
                ("int8 | beam W/Al".to_string(), cal(0.5)),
            ]
            .into_iter()
            .collect(),
            fits: Default::default(),
        };
        assert_eq!(
            pick_beam_calibrations(&f, "int8", corrected),
            vec![("W/Al".to_string(), cal(0.3))]
        );
        assert_eq!(
            pick_beam_calibrations(&f, "int8", InputCorrections::default()),
            vec![("W/Al".to_string(), cal(0.5))]
        );
        assert_eq!(
            pick_calibration(&f, "int8", corrected).map(|(c, _)| c),
            Some(cal(0.2))
        );
        assert!(pick_beam_calibrations(&f, "mixed", corrected).is_empty());
        // The known path's inputs are others: they never read the one
        // reference's calibrations (only the plain one, with a warning).
        // An a-Se detector's linearised inputs are others too.
        let a_se = InputCorrections {
            a_se_detector: true,
            ..corrected
        };
        assert_eq!(
            a_se.key("int8"),
            "int8 | scatter removed + linearised for a-Se"
        );
        assert_ne!(a_se.key("int8"), corrected.key("int8"));
        let known = InputCorrections {
            known_path: true,
            ..corrected
        };
        assert_eq!(
            known.beam_key("int8", "W/Al"),
            "int8 | scatter removed + linearised on the known path | beam W/Al"
        );
        assert!(pick_beam_calibrations(&f, "int8", known).is_empty());
        // A thickness term written without its range takes its fit's
        // cases' thicknesses.
        let mut g = f.clone();
        let key = "int8 | scatter removed + linearised".to_string();
        g.calibrations.insert(
            key.clone(),
            GlandularityCalibration {
                per_mm: 0.0003,
                ..cal(0.2)
            },
        );
        g.fits.insert(
            key,
            serde_json::json!({"cases": [{"thickness_mm": 33.5}, {"thickness_mm": 71.0}, {"thickness_mm": 50.0}]}),
        );
        let (c, _) = pick_calibration(&g, "int8", corrected).unwrap();
        assert_eq!(c.thickness_range_mm, Some([33.5, 71.0]));
        assert_eq!(
            pick_calibration(&f, "int8", known),
            Some((cal(0.1), "int8".to_string()))
        );
    }
}
