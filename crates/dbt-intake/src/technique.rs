//! The site's technique as the dose needs it: each beam's tube output
//! (the incident air kerma per mAs at the reference point), as the
//! physicist's QC measured it.

use dbt_dose::xray::AnodeFilter;
use serde::{Deserialize, Serialize};

/// The site configuration's key of a beam's tube output (`[report]`):
/// one per beam, W/Rh's the unqualified one.
pub fn tube_output_key(beam: AnodeFilter) -> &'static str {
    match beam {
        AnodeFilter::WRh => "report.tube_output_mgy_per_mas",
        AnodeFilter::WAl => "report.tube_output_w_al_mgy_per_mas",
        AnodeFilter::WAg => "report.tube_output_w_ag_mgy_per_mas",
        AnodeFilter::MoMo => "report.tube_output_mo_mo_mgy_per_mas",
        AnodeFilter::MoRh => "report.tube_output_mo_rh_mgy_per_mas",
        AnodeFilter::RhRh => "report.tube_output_rh_rh_mgy_per_mas",
    }
}

/// A beam's tube output at the reference point, mGy/mAs: one figure for
/// every kV (`tube_output_mgy_per_mas = 0.11`), or the QC's measurements by
/// kV (`tube_output_mgy_per_mas = { kv = [25, 30, 35], mgy_per_mas = [0.06,
/// 0.09, 0.12] }`): the output of a tungsten tube rises steeply with the
/// kV (roughly as its square), so one figure misstates the incident air
/// kerma, and with it the MGD, by tens of per cent a few kV away from where
/// it was measured; a physicist who measured it at several kV enters them.
/// Between two measured kV the output is taken as a power of the kV (linear
/// in log-log); outside the measured range the exposure is refused (a
/// technique fault), never extrapolated.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(
    untagged,
    expecting = "a tube output: a number (mGy/mAs) or a table { kv = [...], mgy_per_mas = [...] }"
)]
pub enum TubeOutput {
    /// One figure at every kV.
    Single(f64),
    /// Measured at ascending kV.
    ByKv(KvTable),
}

/// The QC's tube outputs by kV.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct KvTable {
    /// kV of each measurement, ascending (at least two).
    pub kv: Vec<f64>,
    /// Output at each, mGy/mAs.
    pub mgy_per_mas: Vec<f64>,
}

impl TubeOutput {
    /// The output at `kvp`; outside a table's measured range, why not.
    pub fn at(&self, kvp: f64) -> Result<f64, String> {
        match self {
            TubeOutput::Single(v) => Ok(*v),
            TubeOutput::ByKv(KvTable { kv, mgy_per_mas }) => {
                let (Some(&lo), Some(&hi)) = (kv.first(), kv.last()) else {
                    return Err("an empty tube output table".into());
                };
                if !(kvp >= lo && kvp <= hi) {
                    return Err(format!(
                        "{kvp} kV is outside the tube output's measured {lo}-{hi} kV"
                    ));
                }
                let k = kv.partition_point(|&x| x < kvp).clamp(1, kv.len() - 1);
                let (k0, k1) = (kv[k - 1], kv[k]);
                let (o0, o1) = (mgy_per_mas[k - 1], mgy_per_mas[k]);
                if kvp == k0 {
                    return Ok(o0);
                }
                if kvp == k1 {
                    return Ok(o1);
                }
                let t = (kvp / k0).ln() / (k1 / k0).ln();
                Ok(o0 * (o1 / o0).powf(t))
            }
        }
    }

    /// The first figure (the one output, or the table's lowest kV's): a
    /// placeholder where no kV is known yet; the processing replaces it
    /// with [`Self::at`] the exposure's kV.
    pub fn nominal(&self) -> f64 {
        match self {
            TubeOutput::Single(v) => *v,
            TubeOutput::ByKv(t) => t.mgy_per_mas.first().copied().unwrap_or(0.0),
        }
    }

    /// Every figure in `(0, max]`; a table's kV ascending, within the
    /// header's kV limits, as many outputs as kV, at least two.
    pub fn check(&self, max: f64) -> Result<(), String> {
        let out_ok = |v: f64| v > 0.0 && v <= max;
        match self {
            TubeOutput::Single(v) if out_ok(*v) => Ok(()),
            TubeOutput::Single(v) => Err(format!("{v}: must be in (0, {max}] mGy/mAs")),
            TubeOutput::ByKv(KvTable { kv, mgy_per_mas }) => {
                use crate::acquisition::limits::{KVP_MAX, KVP_MIN};
                let kv_range = KVP_MIN..=KVP_MAX;
                if kv.len() < 2 || kv.len() != mgy_per_mas.len() {
                    return Err(format!(
                        "a table needs at least two kV and one output per kV ({} kV, {} outputs)",
                        kv.len(),
                        mgy_per_mas.len()
                    ));
                }
                if let Some(k) = kv.iter().find(|k| !kv_range.contains(*k)) {
                    return Err(format!(
                        "kv {k}: outside {}-{} kV",
                        kv_range.start(),
                        kv_range.end()
                    ));
                }
                if let Some(w) = kv.windows(2).find(|w| w[1] <= w[0]) {
                    return Err(format!("kv {} then {}: must ascend", w[0], w[1]));
                }
                if let Some(v) = mgy_per_mas.iter().find(|v| !out_ok(**v)) {
                    return Err(format!("mgy_per_mas {v}: must be in (0, {max}] mGy/mAs"));
                }
                Ok(())
            }
        }
    }
}
