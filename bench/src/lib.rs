//! Shared helpers of the benchmark binaries.

use std::time::Instant;

/// Run `f` `warmup` times untimed, then `reps` times, returning the median
/// wall time in milliseconds.
pub fn median_ms(warmup: usize, reps: usize, f: impl FnMut()) -> f64 {
    spread_ms(warmup, reps, f).median
}

/// The median of repeated timings with their 10th and 90th percentiles: on
/// a shared virtual machine the repetitions of one run can fall into slower
/// phases (another tenant on the host), which the median alone hides.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spread {
    /// 10th percentile (nearest rank), ms.
    pub p10: f64,
    /// Median, ms.
    pub median: f64,
    /// 90th percentile (nearest rank), ms.
    pub p90: f64,
}

impl Spread {
    /// Of the timings `v` (ms); NaN everywhere when empty.
    pub fn of(mut v: Vec<f64>) -> Self {
        v.sort_by(|a, b| a.total_cmp(b));
        Spread {
            p10: percentile(&v, 0.1),
            p90: percentile(&v, 0.9),
            median: median(v),
        }
    }
}

/// Run `f` `warmup` times untimed, then `reps` times: the timings' [`Spread`].
pub fn spread_ms(warmup: usize, reps: usize, mut f: impl FnMut()) -> Spread {
    for _ in 0..warmup {
        f();
    }
    let times: Vec<f64> = (0..reps.max(1))
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    Spread::of(times)
}

/// The nearest-rank `q`-quantile (`q` in 0..=1) of ascending `sorted`; NaN
/// when empty.
pub fn percentile(sorted: &[f64], q: f64) -> f64 {
    let n = sorted.len();
    if n == 0 {
        return f64::NAN;
    }
    let rank = (q.clamp(0.0, 1.0) * n as f64).ceil() as usize;
    sorted[rank.clamp(1, n) - 1]
}

/// The median (mean of the middle two for an even count; NaN when empty).
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Write a slice of f32 as raw little-endian bytes.
pub fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// A count of at least one, for the benchmarks' `--reps` (clap value parser).
pub fn at_least_one(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(n) => Ok(n),
        Err(e) => Err(format!("{s:?}: {e}")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Nearest rank: of 1..=10 the 10th percentile is 1 and the 90th 9; one
    /// value is every percentile; the median of an even count is the mean of
    /// the middle two.
    #[test]
    fn spread_by_nearest_rank() {
        let v: Vec<f64> = (1..=10).rev().map(f64::from).collect();
        assert_eq!(
            Spread::of(v),
            Spread {
                p10: 1.0,
                median: 5.5,
                p90: 9.0
            }
        );
        assert_eq!(
            Spread::of(vec![3.0]),
            Spread {
                p10: 3.0,
                median: 3.0,
                p90: 3.0
            }
        );
        assert!(Spread::of(Vec::new()).p90.is_nan());
        assert_eq!(percentile(&[1.0, 2.0, 3.0], 0.0), 1.0);
        assert_eq!(percentile(&[1.0, 2.0, 3.0], 1.0), 3.0);
    }
}
