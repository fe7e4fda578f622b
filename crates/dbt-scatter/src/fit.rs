//! Fitting the kernels of one thickness to Monte Carlo detector images.
//!
//! For given kernel shapes (`sigma_1`, `sigma_2`, `w`, `c`) the model is
//! linear in the amplitudes at the knots (`A` is a sum of hat functions),
//! so each candidate shape is scored by a non-negative least-squares fit of
//! the amplitudes, and the shape with the least weighted error wins (a grid
//! search over the candidates given).
//!
//! The error weights: under the breast (`T < 0.95`) the relative error of
//! the scatter, `(s_model - s_mc) / s_mc`, which is what the
//! scatter-to-primary ratio's accuracy asks; outside it the error of the
//! total signal, `(s_model - s_mc) / (T + s_mc)`, which is what the log
//! projection DBToR reads there sees.

use crate::{Grid, Kernels, ScatterError};

/// One Monte Carlo view: its primary transmission and scatter, fractions
/// of the open field.
#[derive(Debug, Clone)]
pub struct Sample {
    /// Pixels.
    pub grid: Grid,
    /// Primary transmission.
    pub transmission: Vec<f64>,
    /// Scatter.
    pub scatter: Vec<f64>,
    /// `tan(theta)` of the view.
    pub tan_angle: f64,
}

/// Candidate kernel shapes.
#[derive(Debug, Clone)]
pub struct Candidates {
    /// Narrow Gaussian's sigma, mm.
    pub sigma_narrow: Vec<f64>,
    /// Wide Gaussian's sigma, mm.
    pub sigma_wide: Vec<f64>,
    /// Wide Gaussian's weight.
    pub wide_weight: Vec<f64>,
    /// Shift per unit tan(theta), mm.
    pub shift: Vec<f64>,
}

/// A fit's result: the kernels and their RMS weighted error (relative
/// under the breast, of the total signal outside it: the module's
/// weights), Monte Carlo noise included.
#[derive(Debug, Clone)]
pub struct Fitted {
    /// The kernels.
    pub kernels: Kernels,
    /// RMS weighted error.
    pub rms: f64,
}

fn hat(p: f64, knots: &[f64], b: usize) -> f64 {
    let n = knots.len();
    let x = p.clamp(knots[0], knots[n - 1]);
    let left = if b > 0 {
        knots[b - 1]
    } else {
        f64::NEG_INFINITY
    };
    let right = if b + 1 < n {
        knots[b + 1]
    } else {
        f64::INFINITY
    };
    let k = knots[b];
    if x == k {
        1.0
    } else if x < k && x > left {
        (x - left) / (k - left)
    } else if x > k && x < right {
        (right - x) / (right - k)
    } else {
        0.0
    }
}

fn weights(s: &Sample) -> Vec<f64> {
    s.transmission
        .iter()
        .zip(&s.scatter)
        .map(|(&t, &m)| {
            let d = if t < 0.95 { m } else { t + m };
            if d > 0.0 {
                1.0 / (d * d)
            } else {
                0.0
            }
        })
        .collect()
}

/// Solve the normal equations `a x = b` (symmetric, small) by Gaussian
/// elimination with partial pivoting; `None` if singular.
fn solve(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for i in 0..n {
        let piv = (i..n).max_by(|&x, &y| a[x][i].abs().total_cmp(&a[y][i].abs()))?;
        if a[piv][i].abs() < 1e-300 {
            return None;
        }
        a.swap(i, piv);
        b.swap(i, piv);
        let (top, rest) = a.split_at_mut(i + 1);
        let pivot = &top[i];
        for (k, row) in rest.iter_mut().enumerate() {
            let f = row[i] / pivot[i];
            for (x, p) in row[i..].iter_mut().zip(&pivot[i..]) {
                *x -= f * p;
            }
            b[i + 1 + k] -= f * b[i];
        }
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        let s: f64 = (i + 1..n).map(|c| a[i][c] * x[c]).sum();
        x[i] = (b[i] - s) / a[i][i];
    }
    Some(x)
}

/// Non-negative least squares on the normal equations by an active set:
/// amplitudes that come out negative are fixed at zero, most negative
/// first, and the rest refitted.
fn nnls(ata: &[Vec<f64>], atb: &[f64]) -> Vec<f64> {
    let n = atb.len();
    // A small ridge keeps knots without data (zero rows) solvable.
    let ridge = 1e-10 * (0..n).map(|i| ata[i][i]).sum::<f64>().max(1e-300);
    let mut free: Vec<bool> = vec![true; n];
    loop {
        let idx: Vec<usize> = (0..n).filter(|&i| free[i]).collect();
        let a: Vec<Vec<f64>> = idx
            .iter()
            .map(|&i| {
                idx.iter()
                    .map(|&j| ata[i][j] + if i == j { ridge } else { 0.0 })
                    .collect()
            })
            .collect();
        let b: Vec<f64> = idx.iter().map(|&i| atb[i]).collect();
        let x = solve(a, b).unwrap_or_else(|| vec![0.0; idx.len()]);
        let worst = x
            .iter()
            .enumerate()
            .filter(|(_, v)| **v < 0.0)
            .min_by(|a, b| a.1.total_cmp(b.1));
        match worst {
            Some((k, _)) => free[idx[k]] = false,
            None => {
                let mut out = vec![0.0; n];
                for (k, &i) in idx.iter().enumerate() {
                    out[i] = x[k];
                }
                return out;
            }
        }
    }
}

/// The knots of `A` for `samples`: `p = 0` (outside the breast: the
/// paddle's and support's own scatter), then `n_knots - 1` evenly from the
/// 2nd to the 98th percentile of `p` under the breast (`T < 0.95`): where
/// the data are, not where noise reaches.
pub(crate) fn knots(
    thickness_mm: f64,
    samples: &[Sample],
    n_knots: usize,
) -> Result<Vec<f64>, ScatterError> {
    let mut under: Vec<f64> = samples
        .iter()
        .flat_map(|s| s.transmission.iter())
        .filter(|&&t| t > 0.0 && t < 0.95)
        .map(|&t| -t.ln())
        .collect();
    if under.len() < 10 {
        return Err(ScatterError::Table(format!(
            "fit of {thickness_mm} mm: {} pixels under the breast",
            under.len()
        )));
    }
    under.sort_by(f64::total_cmp);
    let q = |f: f64| under[((under.len() - 1) as f64 * f) as usize];
    let (lo, hi) = (q(0.02), q(0.98).max(q(0.02) + 0.05));
    Ok(std::iter::once(0.0)
        .chain((0..n_knots - 1).map(|i| lo + (hi - lo) * i as f64 / (n_knots - 2).max(1) as f64))
        .collect())
}

/// Fit the kernels of `thickness_mm` to `samples` over the candidate
/// shapes, with `n_knots` knots of `A` (at least 3): `p = 0`, then evenly
/// over the samples' `p` under the breast.
pub fn fit(
    thickness_mm: f64,
    samples: &[Sample],
    candidates: &Candidates,
    n_knots: usize,
) -> Result<Fitted, ScatterError> {
    if samples.is_empty() || n_knots < 3 {
        return Err(ScatterError::Table(format!(
            "fit of {thickness_mm} mm: {} samples and {n_knots} knots",
            samples.len()
        )));
    }
    for s in samples {
        s.grid.check(&s.transmission, "Monte Carlo primary")?;
        s.grid.check(&s.scatter, "Monte Carlo scatter")?;
    }
    let knots = knots(thickness_mm, samples, n_knots)?;
    let w: Vec<Vec<f64>> = samples.iter().map(weights).collect();
    let weighted = w.iter().flatten().filter(|&&x| x > 0.0).count();
    // Each knot's hat times T, per sample, blurred once per sigma: the
    // candidate shapes only mix and shift these.
    let sources: Vec<Vec<Vec<f64>>> = samples
        .iter()
        .map(|s| {
            (0..n_knots)
                .map(|b| {
                    s.transmission
                        .iter()
                        .map(|&t| {
                            let t = t.clamp(1e-9, 1.0);
                            t * hat(-t.ln(), &knots, b)
                        })
                        .collect()
                })
                .collect()
        })
        .collect();
    let blurred = |sigma: f64| -> Vec<Vec<Vec<f64>>> {
        samples
            .iter()
            .zip(&sources)
            .map(|(s, q)| {
                q.iter()
                    .map(|qb| crate::gaussian_blur(qb, &s.grid, sigma))
                    .collect()
            })
            .collect()
    };
    let narrow: Vec<_> = candidates
        .sigma_narrow
        .iter()
        .map(|&s| blurred(s))
        .collect();
    let wide: Vec<_> = candidates.sigma_wide.iter().map(|&s| blurred(s)).collect();
    let mut best: Option<Fitted> = None;
    for (i1, &s1) in candidates.sigma_narrow.iter().enumerate() {
        for (i2, &s2) in candidates.sigma_wide.iter().enumerate() {
            if s2 <= s1 {
                continue;
            }
            for &ww in &candidates.wide_weight {
                for &c in &candidates.shift {
                    let mut ata = vec![vec![0.0; n_knots]; n_knots];
                    let mut atb = vec![0.0; n_knots];
                    let mut bases: Vec<Vec<Vec<f64>>> = Vec::with_capacity(samples.len());
                    for (k, (s, ws)) in samples.iter().zip(&w).enumerate() {
                        let basis: Vec<Vec<f64>> = (0..n_knots)
                            .map(|b| {
                                let mix: Vec<f64> = narrow[i1][k][b]
                                    .iter()
                                    .zip(&wide[i2][k][b])
                                    .map(|(x, y)| (1.0 - ww) * x + ww * y)
                                    .collect();
                                crate::shift_cols(&mix, &s.grid, c * s.tan_angle)
                            })
                            .collect();
                        for i in 0..n_knots {
                            for j in i..n_knots {
                                let v: f64 = basis[i]
                                    .iter()
                                    .zip(&basis[j])
                                    .zip(ws)
                                    .map(|((a, b), w)| a * b * w)
                                    .sum();
                                ata[i][j] += v;
                                if i != j {
                                    ata[j][i] += v;
                                }
                            }
                            atb[i] += basis[i]
                                .iter()
                                .zip(&s.scatter)
                                .zip(ws)
                                .map(|((a, m), w)| a * m * w)
                                .sum::<f64>();
                        }
                        bases.push(basis);
                    }
                    let amp = nnls(&ata, &atb);
                    let mut err = 0.0;
                    for ((s, ws), basis) in samples.iter().zip(&w).zip(&bases) {
                        for (k, (&m, &wk)) in s.scatter.iter().zip(ws).enumerate() {
                            let model: f64 = (0..n_knots).map(|b| amp[b] * basis[b][k]).sum();
                            err += wk * (model - m).powi(2);
                        }
                    }
                    let rms = (err / weighted.max(1) as f64).sqrt();
                    if best.as_ref().is_none_or(|b| rms < b.rms) {
                        best = Some(Fitted {
                            kernels: Kernels {
                                thickness_mm,
                                sigma_mm: [s1, s2],
                                wide_weight: ww,
                                shift_mm: c,
                                p_knots: knots.clone(),
                                amplitude: amp,
                            },
                            rms,
                        });
                    }
                }
            }
        }
    }
    best.ok_or_else(|| {
        ScatterError::Table(format!(
            "fit of {thickness_mm} mm: no candidate shape (the wide sigma must exceed the narrow)"
        ))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fit recovers the kernels that made the data.
    #[test]
    fn the_fit_recovers_a_known_model() {
        let g = Grid {
            rows: 40,
            cols: 44,
            row_mm: 4.0,
            col_mm: 4.0,
        };
        let samples: Vec<Sample> = [0.0, 0.4]
            .iter()
            .map(|&tan| {
                // A half-disc breast with p rising to 3 at its centre.
                let t: Vec<f64> = (0..g.len())
                    .map(|i| {
                        let (r, c) = ((i / 44) as f64, (i % 44) as f64 - 22.0);
                        let d = (r * r + c * c).sqrt() / 25.0;
                        if d < 1.0 {
                            (-3.0 * (1.0 - d * d).sqrt()).exp()
                        } else {
                            1.0
                        }
                    })
                    .collect();
                Sample {
                    grid: g,
                    transmission: t,
                    scatter: vec![],
                    tan_angle: tan,
                }
            })
            .collect();
        let truth = Kernels {
            thickness_mm: 50.0,
            sigma_mm: [6.0, 24.0],
            wide_weight: 0.5,
            shift_mm: 8.0,
            p_knots: knots(50.0, &samples, 4).unwrap(),
            amplitude: vec![0.05, 0.3, 0.7, 1.1],
        };
        let samples: Vec<Sample> = samples
            .into_iter()
            .map(|s| Sample {
                scatter: truth.scatter(&s.transmission, &g, s.tan_angle),
                ..s
            })
            .collect();
        let c = Candidates {
            sigma_narrow: vec![4.0, 6.0, 8.0],
            sigma_wide: vec![16.0, 24.0, 32.0],
            wide_weight: vec![0.3, 0.5, 0.7],
            shift: vec![0.0, 8.0, -8.0],
        };
        let f = fit(50.0, &samples, &c, 4).unwrap();
        assert_eq!(f.kernels.sigma_mm, [6.0, 24.0]);
        assert_eq!(f.kernels.wide_weight, 0.5);
        assert_eq!(f.kernels.shift_mm, 8.0);
        assert!(f.rms < 1e-6, "{}", f.rms);
        for (a, b) in f.kernels.amplitude.iter().zip(&truth.amplitude) {
            assert!((a - b).abs() < 1e-4, "{a} vs {b}");
        }
    }
}
