//! Self-tests a service engineer can run on the gantry PC.

use dbt_geometry::{chord_in_rect, Geometry};
use dbt_projector::{dot, norm2, Projector};

/// The outcome of one check.
#[derive(Debug, Clone)]
pub struct Check {
    /// Short name.
    pub name: String,
    /// Measured value.
    pub value: f64,
    /// Pass threshold (the value must be below it).
    pub limit: f64,
    /// Human-readable detail.
    pub detail: String,
}

impl Check {
    /// Whether the check passed.
    pub fn passed(&self) -> bool {
        self.value.is_finite() && self.value < self.limit
    }
}

/// Deterministic pseudo-random numbers in [0, 1) (xorshift), so the self-test
/// needs no RNG dependency and gives the same numbers on every machine.
fn pseudo_random(n: usize, mut state: u64) -> Vec<f32> {
    (0..n)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        })
        .collect()
}

/// Projector self-test at `g`: adjointness on pseudo-random data, and the line
/// integrals of a 60 mm adipose slab against the closed form.
pub fn projector(g: &Geometry) -> Vec<Check> {
    let p = Projector::new(g);
    let x = pseudo_random(p.domain_len(), 0x9E37_79B9_7F4A_7C15);
    let y = pseudo_random(p.range_len(), 0xD1B5_4A32_D192_ED03);
    let mut px = vec![0.0; p.range_len()];
    let mut pty = vec![0.0; p.domain_len()];
    // Shapes come from the same geometry, so these cannot fail.
    let _ = p.forward(&x, &mut px);
    let _ = p.adjoint(&y, &mut pty);
    let (lhs, rhs) = (dot(&px, &y), dot(&x, &pty));
    let adj = (lhs - rhs).abs() / lhs.abs();
    let mut checks = vec![Check {
        name: "projector adjointness".into(),
        value: adj,
        limit: 1e-5,
        detail: format!(
            "<Px,y> = {lhs:.6e}, <x,P*y> = {rhs:.6e} ({:?} kernel)",
            p.kernel()
        ),
    }];

    // Slab: every row, |x| < 80 mm, mu = 0.0512 / mm (adipose at 20 keV).
    let mu = 0.0512f64;
    let half = 80.0f64.min(g.width_mm() / 2.0);
    let mut slab = vec![0.0f32; p.domain_len()];
    for i in 0..g.nz() {
        for j in 0..g.nx() {
            if g.pixel_center_mm(i, j).0.abs() < half {
                slab[i * g.nx() + j] = mu as f32;
            }
        }
    }
    let _ = p.forward(&slab, &mut px);
    let (lo, hi) = (g.support_z_mm(), g.top_z_mm());
    let mut worst = 0.0f64;
    for v in 0..g.n_views() {
        for k in 0..g.n_det() {
            let (s, e) = g.ray_endpoints_mm(v, k);
            let exact = mu * chord_in_rect(s, e, -half, half, lo, hi);
            let got = px[v * g.n_det() + k] as f64;
            worst = worst.max((got - exact).abs() / exact.max(mu * g.height_mm()));
        }
    }
    checks.push(Check {
        name: "slab line integrals".into(),
        value: worst,
        limit: 1e-3,
        detail: format!(
            "{:.0} mm slab, worst relative error over {} rays",
            g.height_mm(),
            g.n_rays()
        ),
    });
    // The power-iteration norm must bound the gain on any image (checked on the
    // pseudo-random one): excess = ||P x|| / (||P|| ||x||) - 1 must be <= 0.
    let (sigma, iters) = p.operator_norm(200, 1e-6);
    let _ = p.forward(&x, &mut px);
    let excess = norm2(&px) / (sigma * norm2(&x)) - 1.0;
    checks.push(Check {
        name: "operator norm bound".into(),
        value: excess.max(0.0),
        limit: 1e-5,
        detail: format!(
            "||P||_2 = {sigma:.4} mm after {iters} power iterations; ||Px||/||x|| = {:.4}",
            norm2(&px) / norm2(&x)
        ),
    });
    checks
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projector_selftest_passes_on_a_binned_geometry() {
        let g = Geometry::paper().binned(4).unwrap();
        let checks = projector(&g);
        assert_eq!(checks.len(), 3);
        for c in &checks {
            assert!(c.passed(), "{c:?}");
        }
    }

    #[test]
    fn a_failing_value_fails() {
        let c = Check {
            name: "x".into(),
            value: f64::NAN,
            limit: 1.0,
            detail: String::new(),
        };
        assert!(!c.passed());
        let c = Check {
            name: "x".into(),
            value: 2.0,
            limit: 1.0,
            detail: String::new(),
        };
        assert!(!c.passed());
    }
}
