//! Choosing the kernel by measurement, not by instruction-set rank (issue
//! #52): every configuration this CPU runs is checked against the portable
//! kernel on the same block and input, and timed; the fastest that agrees
//! runs. A kernel that disagrees is never chosen, however fast.
//!
//! [`select`] is the rule, for any kind of candidate; [`measure_int8`] and
//! [`measure_fp32`] apply it to a block's int8 and fp32 configurations
//! (kernel, and whether it convolves by Winograd).

use crate::{BlockWeights, ConvError, Fp32Block, Int8Block, Int8BlockWeights, Kernel};
use std::time::Instant;

/// One candidate's measurement.
#[derive(Debug, Clone, PartialEq)]
pub struct Timing<C> {
    /// The candidate.
    pub candidate: C,
    /// Its name in tables and logs.
    pub label: String,
    /// Whether its output agreed with the reference.
    pub agrees: bool,
    /// Its largest difference from the reference, relative to the
    /// reference's largest magnitude (infinite where it failed to run).
    pub deviation: f64,
    /// Median time of one run, ms.
    pub median_ms: f64,
}

/// The candidates measured and the one chosen.
#[derive(Debug, Clone, PartialEq)]
pub struct Selection<C> {
    /// The fastest candidate that agreed.
    pub chosen: C,
    /// Every candidate, in the order measured.
    pub timings: Vec<Timing<C>>,
    /// Where the candidates were compared with the bits of this one (the
    /// instruction-set rank's choice, [`select_keeping_bits`]) rather than
    /// with the portable kernel's output: its label.
    pub bits_of: Option<String>,
}

impl<C: PartialEq> Selection<C> {
    /// One line for logs, the status file and the self-test: each
    /// candidate's median time, the chosen one marked, a disagreeing one
    /// named as refused, or, where the candidates had to give the rank
    /// choice's bits, as giving other bits.
    pub fn describe(&self) -> String {
        self.timings
            .iter()
            .map(|t| {
                let what = if t.candidate == self.chosen {
                    " (chosen)".to_string()
                } else if t.agrees {
                    String::new()
                } else if let Some(b) = &self.bits_of {
                    format!(" (other bits than {b}'s: not eligible)")
                } else {
                    " (disagrees with the reference: refused)".to_string()
                };
                format!("{} {:.2} ms{what}", t.label, t.median_ms)
            })
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// The largest difference between `a` and `b` relative to `b`'s largest
/// magnitude (infinite when the lengths differ or a value is not a number).
fn deviation(a: &[f32], b: &[f32]) -> f64 {
    if a.len() != b.len() {
        return f64::INFINITY;
    }
    let scale = b
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs() as f64))
        .max(1e-30);
    let mut d = 0.0f64;
    for (x, y) in a.iter().zip(b) {
        let e = (x - y).abs() as f64;
        if e.is_nan() {
            return f64::INFINITY;
        }
        d = d.max(e);
    }
    d / scale
}

/// A preferred candidate is kept unless another that agrees is faster by
/// more than this share of its time: timings on a busy machine wobble by a
/// few per cent, and a choice that flips between runs would change the
/// float kernels' last bits from one start to the next.
pub const KEEP_PREFERRED_WITHIN: f64 = 0.05;

/// Run every candidate `reps` times after one warm-up run (in rounds, each
/// candidate once a round), compare its
/// output with `reference` (agreeing when its [`Timing::deviation`] is at
/// most `tolerance`: 0 asks for the same bits) and choose the fastest that
/// agrees, or `preferred` (the instruction-set rank's choice) where it
/// agrees and is within [`KEEP_PREFERRED_WITHIN`] of the fastest. `run`
/// returns a candidate's output for the measurement's input; a candidate
/// whose run fails disagrees. Refused when none agrees.
pub fn select<C: Clone + PartialEq>(
    candidates: &[(C, String)],
    reference: &[f32],
    tolerance: f64,
    reps: usize,
    preferred: Option<&C>,
    mut run: impl FnMut(&C) -> Result<Vec<f32>, ConvError>,
) -> Result<Selection<C>, ConvError> {
    select_measured(candidates, reference, tolerance, reps, preferred, |c| {
        let t0 = Instant::now();
        let out = run(c);
        (out, t0.elapsed().as_secs_f64() * 1e3)
    })
}

/// [`select`]'s rule on runs that report their own time in ms (`measure`
/// returns a run's output and its duration): the wall clock in [`select`],
/// a given duration in the rule's tests, which must not depend on how busy
/// the machine is.
fn select_measured<C: Clone + PartialEq>(
    candidates: &[(C, String)],
    reference: &[f32],
    tolerance: f64,
    reps: usize,
    preferred: Option<&C>,
    mut measure: impl FnMut(&C) -> (Result<Vec<f32>, ConvError>, f64),
) -> Result<Selection<C>, ConvError> {
    // One warm-up round (its outputs are checked too), then the timed
    // rounds, each candidate once a round in turn: a machine whose speed
    // drifts during the measurement (another tenant, the clock) moves every
    // candidate alike, where timing one candidate's runs after another's
    // gave the earlier ones other conditions than the later ones. A
    // candidate that fails or gives no number is not run again.
    let n = candidates.len();
    let mut times: Vec<Vec<f64>> = vec![Vec::with_capacity(reps.max(1)); n];
    let mut devs = vec![0.0f64; n];
    for k in 0..=reps.max(1) {
        for (i, (c, _)) in candidates.iter().enumerate() {
            if !devs[i].is_finite() {
                continue;
            }
            let (out, dt) = measure(c);
            devs[i] = match out {
                Ok(o) => devs[i].max(deviation(&o, reference)),
                Err(_) => f64::INFINITY,
            };
            if k > 0 {
                times[i].push(dt);
            }
        }
    }
    let mut timings = Vec::with_capacity(n);
    for (((c, label), mut times), dev) in candidates.iter().zip(times).zip(devs) {
        times.sort_by(f64::total_cmp);
        let median_ms = times.get(times.len() / 2).copied().unwrap_or(f64::INFINITY);
        timings.push(Timing {
            candidate: c.clone(),
            label: label.clone(),
            agrees: dev <= tolerance,
            deviation: dev,
            median_ms,
        });
    }
    let fastest = timings
        .iter()
        .filter(|t| t.agrees && t.median_ms.is_finite())
        .min_by(|a, b| a.median_ms.total_cmp(&b.median_ms));
    let kept = fastest.and_then(|f| {
        timings.iter().find(|t| {
            preferred == Some(&t.candidate)
                && t.agrees
                && t.median_ms <= f.median_ms * (1.0 + KEEP_PREFERRED_WITHIN)
        })
    });
    let chosen = kept
        .or(fastest)
        .map(|t| t.candidate.clone())
        .ok_or_else(|| {
            ConvError::Shape(format!(
                "no kernel agrees with the portable one: {}",
                timings
                    .iter()
                    .map(|t| format!("{} deviation {:.3e}", t.label, t.deviation))
                    .collect::<Vec<_>>()
                    .join(", ")
            ))
        })?;
    Ok(Selection {
        chosen,
        timings,
        bits_of: None,
    })
}

/// [`select`] that never changes a result: where the `preferred`
/// candidate (the instruction-set rank's choice) agrees with the
/// `reference` (the portable kernel's output) within `tolerance`, only the
/// candidates that compute the preferred one's bits are eligible, the
/// fastest of them chosen; otherwise [`select`] against the reference. A
/// float kernel chosen by timing alone could flip between two starts of
/// the daemon on a busy machine, and a service engineer's replay would then
/// not reproduce the report to the bit; with a tolerance of 0 (the int8
/// kernels) the two rules are one.
pub fn select_keeping_bits<C: Clone + PartialEq>(
    candidates: &[(C, String)],
    reference: &[f32],
    tolerance: f64,
    reps: usize,
    preferred: Option<&C>,
    mut run: impl FnMut(&C) -> Result<Vec<f32>, ConvError>,
) -> Result<Selection<C>, ConvError> {
    if let Some(p) = preferred {
        if let Ok(out) = run(p) {
            if deviation(&out, reference) <= tolerance && tolerance > 0.0 {
                let mut sel = select(candidates, &out, 0.0, reps, Some(p), run)?;
                sel.bits_of = candidates
                    .iter()
                    .find(|(c, _)| c == p)
                    .map(|(_, l)| l.clone());
                return Ok(sel);
            }
        }
    }
    select(candidates, reference, tolerance, reps, preferred, run)
}

/// An int8 configuration: the kernel, and whether its convolutions run by
/// Winograd (AVX2 and AVX-VNNI have it; bit for bit the direct ones).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Int8Config {
    /// The kernel.
    pub kernel: Kernel,
    /// Winograd's F(3x3, 3x3) where the kernel has it.
    pub winograd: bool,
}

impl Int8Config {
    /// `avx2 winograd`, `avx512 direct`, ...
    pub fn label(&self) -> String {
        let conv = if self.winograd { "winograd" } else { "direct" };
        format!("{} {conv}", self.kernel.name())
    }

    /// Every int8 configuration this CPU runs, the portable kernel first;
    /// AMX where the CPU has it and the OS grants its tiles.
    pub fn candidates() -> Vec<Int8Config> {
        let mut v = vec![Int8Config {
            kernel: Kernel::Portable,
            winograd: false,
        }];
        for k in [Kernel::Avx2, Kernel::AvxVnni, Kernel::Avx512, Kernel::Amx] {
            let runs = if k == Kernel::Amx {
                Kernel::amx_available()
            } else {
                Kernel::best_int8_up_to(k) == k
            };
            if !runs {
                continue;
            }
            v.push(Int8Config {
                kernel: k,
                winograd: false,
            });
            if matches!(k, Kernel::Avx2 | Kernel::AvxVnni) {
                v.push(Int8Config {
                    kernel: k,
                    winograd: true,
                });
            }
        }
        v
    }
}

/// An fp32 configuration (Winograd changes the sums' rounding, so it is a
/// candidate only where asked for).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fp32Config {
    /// The kernel.
    pub kernel: Kernel,
    /// Winograd's F(3x3, 3x3).
    pub winograd: bool,
}

impl Fp32Config {
    /// `avx512`, `avx2 winograd`, ...
    pub fn label(&self) -> String {
        if self.winograd {
            format!("{} winograd", self.kernel.name())
        } else {
            self.kernel.name().to_string()
        }
    }

    /// Every fp32 configuration this CPU runs, the portable kernel first;
    /// with `winograd`, each SIMD kernel's Winograd convolution too.
    pub fn candidates(winograd: bool) -> Vec<Fp32Config> {
        let mut v = vec![Fp32Config {
            kernel: Kernel::Portable,
            winograd: false,
        }];
        for k in [Kernel::Avx2, Kernel::Avx512] {
            if Kernel::best_fp32_up_to(k) != k {
                continue;
            }
            v.push(Fp32Config {
                kernel: k,
                winograd: false,
            });
            if winograd {
                v.push(Fp32Config {
                    kernel: k,
                    winograd: true,
                });
            }
        }
        v
    }
}

/// Deterministic inputs in [-1, 1) (xorshift: the same on every machine),
/// for the measurements here and the projector's.
pub fn inputs(n: usize, mut state: u64) -> Vec<f32> {
    (0..n)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            ((state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        })
        .collect()
}

/// How many times each candidate is timed.
pub const REPS: usize = 3;

/// `candidates` measured on one block with `state_ch` + `aux_ch` input
/// channels over an `h x w` grid: `run` gives a configuration's new state
/// for the deterministic inputs ([`inputs`]); `reference`'s output is the
/// one every candidate is compared with, within `tolerance`.
fn measure_block<C: Copy + PartialEq>(
    (state_ch, aux_ch, h, w): (usize, usize, usize, usize),
    candidates: &[C],
    label: impl Fn(&C) -> String,
    reference: C,
    tolerance: f64,
    preferred: Option<&C>,
    run: impl Fn(&C, &mut [f32], &[f32]) -> Result<(), ConvError>,
) -> Result<Selection<C>, ConvError> {
    let state = inputs(state_ch * h * w, 0x9E37_79B9_7F4A_7C15);
    let aux = inputs(aux_ch * h * w, 0xD1B5_4A32_D192_ED03);
    let run = |c: &C| -> Result<Vec<f32>, ConvError> {
        let mut s = state.clone();
        run(c, &mut s, &aux)?;
        Ok(s)
    };
    let reference = run(&reference)?;
    let labelled: Vec<_> = candidates.iter().map(|c| (*c, label(c))).collect();
    select_keeping_bits(&labelled, &reference, tolerance, REPS, preferred, run)
}

/// The int8 configurations of `candidates` measured on `weights` (the
/// model's own block) over an `h x w` grid: each against the portable
/// kernel's output bit for bit, timed ([`REPS`] runs), the fastest that
/// agrees chosen (the instruction-set rank's within
/// [`KEEP_PREFERRED_WITHIN`]).
pub fn measure_int8(
    weights: &Int8BlockWeights,
    h: usize,
    w: usize,
    candidates: &[Int8Config],
) -> Result<Selection<Int8Config>, ConvError> {
    let best = Kernel::best_int8();
    let preferred = candidates
        .iter()
        .find(|c| c.kernel == best && (c.winograd || !c.kernel.has_int8_winograd()));
    measure_block(
        (weights.state_ch, weights.aux_ch, h, w),
        candidates,
        Int8Config::label,
        Int8Config {
            kernel: Kernel::Portable,
            winograd: false,
        },
        0.0,
        preferred,
        |c, state, aux| {
            let b = Int8Block::with_winograd(weights, c.kernel, c.winograd)?;
            b.run(&mut crate::Int8Workspace::new(&b, h, w), state, aux)
        },
    )
}

/// The fp32 configurations of `candidates` measured on `weights` over an
/// `h x w` grid ([`select_keeping_bits`]): the instruction-set rank's
/// choice held to the portable kernel's output within 1e-4 of its largest
/// magnitude (the kernels sum in other orders, and Winograd rounds
/// differently), then the fastest configuration that computes its bits
/// (the rank's within [`KEEP_PREFERRED_WITHIN`]).
pub fn measure_fp32(
    weights: &BlockWeights,
    h: usize,
    w: usize,
    candidates: &[Fp32Config],
) -> Result<Selection<Fp32Config>, ConvError> {
    let preferred = candidates
        .iter()
        .find(|c| c.kernel == Kernel::best_fp32() && !c.winograd);
    measure_block(
        (weights.state_ch, weights.aux_ch, h, w),
        candidates,
        Fp32Config::label,
        Fp32Config {
            kernel: Kernel::Portable,
            winograd: false,
        },
        1e-4,
        preferred,
        |c, state, aux| {
            let b = Fp32Block::with_winograd(weights, c.kernel, c.winograd)?;
            b.run(&mut crate::Fp32Workspace::new(&b, h, w), state, aux)
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rule: the fastest candidate that agrees; a faster one that
    /// disagrees (a deliberately broken kernel) or fails is never chosen
    /// and is named as refused. The runs report given durations
    /// (`select_measured`), so the rule's outcome cannot depend on how busy
    /// the machine is; the wall clock's path is the next test's.
    #[test]
    fn a_kernel_that_disagrees_is_never_chosen() {
        let reference = vec![1.0f32, -2.0, 3.0];
        let c = |n: &str| (n.to_string(), n.to_string());
        let cands = [
            c("portable"),
            c("slow"),
            c("fast"),
            c("broken"),
            c("failing"),
        ];
        let off_by_a_bit = || vec![1.0, -2.0, f32::from_bits(3.0f32.to_bits() + 1)];
        let sel = select_measured(&cands, &reference, 0.0, 3, None, |name| {
            match name.as_str() {
                "portable" => (Ok(reference.clone()), 12.0),
                "slow" => (Ok(reference.clone()), 8.0),
                "fast" => (Ok(reference.clone()), 3.0),
                // Fastest of all, and wrong in one value's last bit.
                "broken" => (Ok(off_by_a_bit()), 0.5),
                _ => (Err(ConvError::Shape("no such kernel here".into())), 0.1),
            }
        })
        .unwrap();
        assert_eq!(sel.chosen, "fast");
        let broken = sel
            .timings
            .iter()
            .find(|t| t.candidate == "broken")
            .unwrap();
        assert!(!broken.agrees && broken.deviation > 0.0);
        let failing = sel
            .timings
            .iter()
            .find(|t| t.candidate == "failing")
            .unwrap();
        assert!(!failing.agrees && failing.deviation.is_infinite());
        let d = sel.describe();
        assert!(d.contains("fast") && d.contains("(chosen)"), "{d}");
        assert!(d.contains("broken") && d.contains("refused"), "{d}");
        // A tolerance admits the broken one (fp32's rule), and then it wins.
        let lax = select_measured(&cands[..4], &reference, 1e-6, 1, None, |name| {
            if name == "broken" {
                (Ok(off_by_a_bit()), 0.5)
            } else {
                (Ok(reference.clone()), 2.0)
            }
        })
        .unwrap();
        assert_eq!(lax.chosen, "broken");
        // None agrees: refused, naming each.
        let e = select_measured(&cands[3..4], &reference, 0.0, 1, None, |_| {
            (Ok(vec![0.0; 3]), 1.0)
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("broken deviation"), "{e}");
        // The median of the timed runs decides, the warm-up run not at all:
        // one slow outlier among three does not move a candidate.
        let mut calls = std::collections::HashMap::<String, usize>::new();
        let outlier = select_measured(
            &[c("steady"), c("jumpy")],
            &reference,
            0.0,
            3,
            None,
            |name| {
                let k = calls.entry(name.clone()).or_default();
                *k += 1;
                let ms = match (name.as_str(), *k) {
                    ("steady", _) => 10.0,
                    // warm-up 100 ms, then 5, 50, 5: median 5
                    ("jumpy", 1) => 100.0,
                    ("jumpy", 3) => 50.0,
                    _ => 5.0,
                };
                (Ok(reference.clone()), ms)
            },
        )
        .unwrap();
        assert_eq!(outlier.chosen, "jumpy", "{}", outlier.describe());
        // A preferred candidate within 5 % of the fastest is kept; one far
        // slower, or one that disagrees, is not.
        let timed = |name: &String| {
            let ms = match name.as_str() {
                "portable" => 20.0,
                "slow" => 12.0,
                "fast2" => 10.4,
                _ => 10.0,
            };
            if name == "broken" {
                (Ok(vec![0.0; 3]), ms)
            } else {
                (Ok(reference.clone()), ms)
            }
        };
        let near = [c("fast"), c("fast2")];
        let kept =
            select_measured(&near, &reference, 0.0, 3, Some(&"fast2".to_string()), timed).unwrap();
        assert_eq!(kept.chosen, "fast2", "{}", kept.describe());
        let far = [c("slow"), c("fast")];
        let sel =
            select_measured(&far, &reference, 0.0, 3, Some(&"slow".to_string()), timed).unwrap();
        assert_eq!(sel.chosen, "fast", "{}", sel.describe());
        let bad = [c("broken"), c("slow")];
        let sel =
            select_measured(&bad, &reference, 0.0, 1, Some(&"broken".to_string()), timed).unwrap();
        assert_eq!(sel.chosen, "slow");
    }

    /// A machine that slows down during the measurement does not favour
    /// the candidate measured first: the rounds interleave the candidates.
    /// "faster" is 10 % faster than "first"; every run takes 10 % longer
    /// than the run before it. Timed one candidate after the other, "first"
    /// (medians 12 against 14.4 ms) would be chosen.
    #[test]
    fn a_drifting_machine_does_not_favour_the_first_measured() {
        let reference = vec![1.0f32];
        let c = |n: &str| (n.to_string(), n.to_string());
        let mut run = 0usize;
        let sel = select_measured(
            &[c("first"), c("faster")],
            &reference,
            0.0,
            3,
            None,
            |name| {
                let base = if name == "faster" { 9.0 } else { 10.0 };
                let ms = base * (1.0 + 0.1 * run as f64);
                run += 1;
                (Ok(reference.clone()), ms)
            },
        )
        .unwrap();
        assert_eq!(sel.chosen, "faster", "{}", sel.describe());
        assert_eq!(run, 8, "a warm-up and three timed rounds of two");
    }

    /// `select` times the runs by the wall clock: of two that agree, one
    /// sleeping 1 ms and one 40 ms, the first is chosen (a margin that a
    /// loaded 2-core machine's late wake-ups, a few ms, do not close).
    #[test]
    fn select_times_by_the_wall_clock() {
        let reference = vec![1.0f32];
        let c = |n: &str| (n.to_string(), n.to_string());
        let sel = select(&[c("slow"), c("fast")], &reference, 0.0, 3, None, |name| {
            let ms = if name == "fast" { 1 } else { 40 };
            std::thread::sleep(std::time::Duration::from_millis(ms));
            Ok(reference.clone())
        })
        .unwrap();
        assert_eq!(sel.chosen, "fast", "{}", sel.describe());
        let slow = sel.timings.iter().find(|t| t.candidate == "slow").unwrap();
        assert!(slow.median_ms >= 40.0, "{}", sel.describe());
    }

    /// On this CPU every int8 configuration agrees with the portable kernel
    /// bit for bit and one of them is chosen; the portable kernel is never
    /// chosen where a SIMD kernel runs.
    #[test]
    fn every_int8_configuration_here_agrees_and_one_is_chosen() {
        let wts = crate::int8::tests::random_int8(5, 4, 32, 7);
        let cands = Int8Config::candidates();
        let sel = measure_int8(&wts, 12, 40, &cands).unwrap();
        assert_eq!(sel.timings.len(), cands.len());
        assert!(sel.timings.iter().all(|t| t.agrees), "{}", sel.describe());
        if cands.len() > 1 {
            assert_ne!(sel.chosen.kernel, Kernel::Portable, "{}", sel.describe());
        }
    }

    /// The fp32 choice never changes a figure: the rank's choice is held to
    /// the portable kernel within 1e-4, and whatever is chosen computes its
    /// bits (Winograd candidates included, which round otherwise).
    #[test]
    fn the_fp32_choice_gives_the_rank_choices_bits() {
        let f = crate::testutil::random_block(5, 4, 32, 9);
        let fc = Fp32Config::candidates(true);
        let sel = measure_fp32(&f, 12, 40, &fc).unwrap();
        let rank = Fp32Config {
            kernel: Kernel::best_fp32(),
            winograd: false,
        };
        let out = |c: &Fp32Config| {
            let (h, w) = (12, 40);
            let mut s = inputs(f.state_ch * h * w, 1);
            let aux = inputs(f.aux_ch * h * w, 2);
            let b = Fp32Block::with_winograd(&f, c.kernel, c.winograd).unwrap();
            b.run(&mut crate::Fp32Workspace::new(&b, h, w), &mut s, &aux)
                .unwrap();
            s
        };
        assert_eq!(out(&sel.chosen), out(&rank), "{}", sel.describe());
        assert!(
            sel.timings.iter().any(|t| t.candidate == rank && t.agrees),
            "{}",
            sel.describe()
        );
        let portable = Fp32Config {
            kernel: Kernel::Portable,
            winograd: false,
        };
        if rank != portable {
            assert!(deviation(&out(&rank), &out(&portable)) <= 1e-4);
        }
        // A configuration with other bits is refused, however fast, and
        // named as giving other bits than the rank choice's (not as
        // disagreeing with the portable kernel, within whose tolerance it
        // may be).
        let d = sel.describe();
        for t in &sel.timings {
            assert_eq!(t.agrees, out(&t.candidate) == out(&rank), "{}", t.label);
            if !t.agrees {
                let named = format!("{} ", t.label);
                let at = d.find(&named).expect("every candidate named");
                assert!(
                    d[at..]
                        .split(", ")
                        .next()
                        .unwrap()
                        .contains("other bits than"),
                    "{d}"
                );
            }
        }
    }
}
