//! Which instruction-set extensions this CPU has, for the kernels' tests:
//! a kernel test runs where the CPU has what the kernel needs and is
//! skipped (with a line on stderr) where it does not, unless the
//! environment variable `DBTOR_REQUIRE_ISA` (a comma-separated list, e.g.
//! `avx512f,avx512bw,avx512vnni`, set by `.ci/run` from `/proc/cpuinfo`)
//! names a missing one: then the test fails, so a machine that should test
//! a kernel cannot skip it silently. Used by the kernel crates' tests
//! (`dbt-conv`, `dbt-projector`).

/// Whether this CPU has the extension `name` (`avx2`, `fma`, `avx512f`,
/// `avx512bw`, `avx512vnni`, `avxvnni`, also spelt `avx512_vnni` and
/// `avx_vnni` as in `/proc/cpuinfo`, and `amx_tile`, `amx_int8` (read from
/// CPUID: `std`'s AMX detection is not stable yet; whether the OS grants
/// the tiles is the kernel's question): the kernels' needs); `None` for a
/// name this crate does not know.
pub fn detected(name: &str) -> Option<bool> {
    #[cfg(target_arch = "x86_64")]
    {
        Some(match name {
            "avx2" => std::arch::is_x86_feature_detected!("avx2"),
            "fma" => std::arch::is_x86_feature_detected!("fma"),
            "avx512f" => std::arch::is_x86_feature_detected!("avx512f"),
            "avx512bw" => std::arch::is_x86_feature_detected!("avx512bw"),
            "avx512vnni" | "avx512_vnni" => std::arch::is_x86_feature_detected!("avx512vnni"),
            "avxvnni" | "avx_vnni" => std::arch::is_x86_feature_detected!("avxvnni"),
            "amx_tile" => cpuid7_edx() & (1 << 24) != 0,
            "amx_int8" => cpuid7_edx() & (1 << 25) != 0,
            _ => return None,
        })
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = name;
        Some(false)
    }
}

/// CPUID leaf 7 (subleaf 0) EDX, where the AMX bits are (`std`'s detection
/// of AMX is not stable yet); 0 where the CPU has no leaf 7.
#[cfg(target_arch = "x86_64")]
fn cpuid7_edx() -> u32 {
    // CPUID exists on every x86-64 CPU; leaf 7 is read only where the
    // highest standard leaf reaches it.
    use std::arch::x86_64::__cpuid_count;
    if __cpuid_count(0, 0).eax >= 7 {
        __cpuid_count(7, 0).edx
    } else {
        0
    }
}

/// The extensions [`detected`] knows, in its spelling.
pub const KNOWN: [&str; 8] = [
    "avx2",
    "fma",
    "avx512f",
    "avx512bw",
    "avx512vnni",
    "avxvnni",
    "amx_tile",
    "amx_int8",
];

/// The extensions of [`KNOWN`] this CPU has.
pub fn present() -> Vec<&'static str> {
    KNOWN
        .into_iter()
        .filter(|n| detected(n) == Some(true))
        .collect()
}

/// Whether a kernel test that needs `needs` runs here: `true` if the CPU
/// has every one; `false` (the test is skipped, said on stderr) if not.
///
/// # Panics
/// Where `DBTOR_REQUIRE_ISA` names one of `needs` that the CPU lacks, or
/// names an extension this crate does not know.
pub fn kernel_test_runs(test: &str, needs: &[&str]) -> bool {
    let required = std::env::var("DBTOR_REQUIRE_ISA").unwrap_or_default();
    match decide(test, needs, &required, detected) {
        Ok(true) => true,
        Ok(false) => {
            eprintln!("{test}: skipped, this CPU lacks one of {needs:?}");
            false
        }
        Err(e) => panic!("{e}"),
    }
}

/// [`kernel_test_runs`]'s rule, given the variable's value and the
/// detection: run, skip, or the reason the test must fail.
fn decide(
    test: &str,
    needs: &[&str],
    required: &str,
    has: impl Fn(&str) -> Option<bool>,
) -> Result<bool, String> {
    let required: Vec<&str> = required
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .collect();
    if let Some(r) = required.iter().find(|r| has(r).is_none()) {
        return Err(format!(
            "DBTOR_REQUIRE_ISA names {r:?}, which this crate does not know"
        ));
    }
    let missing: Vec<&str> = needs
        .iter()
        .copied()
        .filter(|n| has(n) != Some(true))
        .collect();
    let demanded: Vec<&str> = missing
        .iter()
        .copied()
        .filter(|m| required.contains(m))
        .collect();
    if !demanded.is_empty() {
        return Err(format!(
            "{test}: DBTOR_REQUIRE_ISA requires {demanded:?}, which this CPU lacks: the kernel cannot be tested here"
        ));
    }
    Ok(missing.is_empty())
}

#[cfg(test)]
mod tests {
    use super::decide;

    /// A CPU with AVX2 and FMA but no AVX-512 (AMD Zen 3).
    fn zen3(name: &str) -> Option<bool> {
        match name {
            "avx2" | "fma" => Some(true),
            "avx512f" | "avx512bw" | "avx512vnni" => Some(false),
            _ => None,
        }
    }

    #[test]
    fn runs_skips_or_fails_as_the_variable_says() {
        assert_eq!(decide("t", &["avx2", "fma"], "", zen3), Ok(true));
        assert_eq!(decide("t", &["avx512f"], "", zen3), Ok(false));
        assert_eq!(decide("t", &["avx512f"], "avx2,fma", zen3), Ok(false));
        let e = decide("t", &["avx512f", "avx512bw"], "avx2, avx512bw", zen3).unwrap_err();
        assert!(e.contains("avx512bw") && !e.contains("avx512f\""), "{e}");
        let e = decide("t", &["avx2"], "avx-512", zen3).unwrap_err();
        assert!(e.contains("avx-512"), "{e}");
    }
}

/// 32-byte unaligned loads and stores that stay one instruction each.
///
/// Code compiled for a generic x86-64 with AVX2 enabled per function
/// (`#[target_feature]`, as every runtime-dispatched kernel here is) keeps
/// LLVM's generic tuning, which splits an unaligned 32-byte load into a
/// 16-byte load and an insert, and a store into a 16-byte store and an
/// extract (seen in the AVX2 kernels' disassembly: 50 inserts and 18
/// extracts in the Winograd output transform alone). Every AVX2 CPU made
/// since Haswell and Zen 1 loads and stores 32 unaligned bytes in one
/// instruction at full speed, so these helpers say it in inline assembly,
/// which the compiler does not rewrite.
#[cfg(target_arch = "x86_64")]
pub mod ymm {
    use std::arch::asm;
    use std::arch::x86_64::{__m256, __m256i};

    /// `vmovdqu`: 32 bytes from `p`.
    ///
    /// # Safety
    /// AVX; `p` valid for reading 32 bytes.
    #[target_feature(enable = "avx")]
    #[inline]
    pub unsafe fn loadu_si256(p: *const __m256i) -> __m256i {
        let r;
        // SAFETY: AVX and `p` valid per the contract; a plain load.
        unsafe {
            asm!("vmovdqu {r}, ymmword ptr [{p}]", r = out(ymm_reg) r, p = in(reg) p,
                 options(pure, readonly, nostack, preserves_flags));
        }
        r
    }

    /// `vmovdqu`: 32 bytes to `p`.
    ///
    /// # Safety
    /// AVX; `p` valid for writing 32 bytes.
    #[target_feature(enable = "avx")]
    #[inline]
    pub unsafe fn storeu_si256(p: *mut __m256i, v: __m256i) {
        // SAFETY: AVX and `p` valid per the contract; a plain store.
        unsafe {
            asm!("vmovdqu ymmword ptr [{p}], {v}", p = in(reg) p, v = in(ymm_reg) v,
                 options(nostack, preserves_flags));
        }
    }

    /// `vmovups`: 8 floats from `p`.
    ///
    /// # Safety
    /// AVX; `p` valid for reading 8 floats.
    #[target_feature(enable = "avx")]
    #[inline]
    pub unsafe fn loadu_ps(p: *const f32) -> __m256 {
        let r;
        // SAFETY: AVX and `p` valid per the contract; a plain load.
        unsafe {
            asm!("vmovups {r}, ymmword ptr [{p}]", r = out(ymm_reg) r, p = in(reg) p,
                 options(pure, readonly, nostack, preserves_flags));
        }
        r
    }

    /// `vmovups`: 8 floats to `p`.
    ///
    /// # Safety
    /// AVX; `p` valid for writing 8 floats.
    #[target_feature(enable = "avx")]
    #[inline]
    pub unsafe fn storeu_ps(p: *mut f32, v: __m256) {
        // SAFETY: AVX and `p` valid per the contract; a plain store.
        unsafe {
            asm!("vmovups ymmword ptr [{p}], {v}", p = in(reg) p, v = in(ymm_reg) v,
                 options(nostack, preserves_flags));
        }
    }

    #[cfg(test)]
    mod tests {
        use super::*;

        #[test]
        fn unaligned_loads_and_stores_move_the_bytes() {
            if !std::arch::is_x86_feature_detected!("avx") {
                eprintln!("skipped: no AVX");
                return;
            }
            let src: Vec<u8> = (0..100u8).collect();
            let mut dst = vec![0u8; 100];
            let f: Vec<f32> = (0..20).map(|k| k as f32 * 0.5).collect();
            let mut g = vec![0.0f32; 20];
            for off in [0, 1, 3, 17, 31] {
                // SAFETY: AVX detected above; 32 bytes (8 floats) from each
                // offset are inside the vectors.
                unsafe {
                    let v = loadu_si256(src.as_ptr().add(off) as *const __m256i);
                    storeu_si256(dst.as_mut_ptr().add(off + 5) as *mut __m256i, v);
                    let w = loadu_ps(f.as_ptr().add(off % 12));
                    storeu_ps(g.as_mut_ptr().add(off % 12), w);
                }
                assert_eq!(dst[off + 5..off + 37], src[off..off + 32]);
                assert_eq!(g[off % 12..off % 12 + 8], f[off % 12..off % 12 + 8]);
            }
        }
    }
}
