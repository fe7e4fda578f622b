//! AMX-INT8 (Intel Sapphire Rapids and later): the int8 convolution as tile
//! matrix products, `tdpbusd` (unsigned bytes x signed bytes into i32).
//!
//! For 16 output pixels of a row and each tap of the 3 x 3 kernel, the input
//! tile `A` is 16 rows (the pixels, `cs` bytes apart in the padded
//! channels-last buffer) of `cin4` bytes (their channels), and each weight
//! tile `B` is the tap's packed weights (`PackedI8::w`, `[tap][cin4 / 4][ocp][4]`:
//! `cin4 / 4` rows of 16 output channels x 4 bytes, exactly AMX's layout of
//! the right-hand operand, `ocp * 4` bytes apart); nine `tdpbusd` per
//! 16-channel block accumulate the sums of the direct kernel, exactly. Up to
//! four 16-channel blocks (`ocp <= 64`) and `cin4 <= 64`; other layers, and
//! the last `w % 16` pixels of a row, run the AVX-512 VNNI tile.
//!
//! Linux gives a process AMX's tile data only on request
//! (`arch_prctl(ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA)`); [`available`]
//! asks once. Each worker thread loads the tile configuration before its
//! products and releases the tiles after.
//!
//! **Not run on AMX hardware yet** (no session's CPU has had it): the
//! kernel is reached only when asked for (`DBTOR_KERNEL=amx`), never by the
//! default dispatch, and an [`super::Int8Block`] on it first checks a
//! convolution against the portable kernel ([`self_check`]) and refuses AMX
//! (naming the difference) if they differ. Its tests run where the CPU has
//! AMX-INT8 (`DBTOR_REQUIRE_ISA=amx_int8` makes them compulsory).

use super::*;

/// Pixels per tile (the rows of `A` and `C`).
const MT: usize = 16;

/// Whether a layer runs on the AMX tiles (else its direct AVX-512 tile).
pub(super) fn eligible(p: &PackedI8) -> bool {
    p.cin4 <= 64 && p.ocp <= 4 * L
}

/// This CPU has AMX-TILE and AMX-INT8 (CPUID leaf 7, EDX bits 24 and 25) and
/// AVX-512 VNNI (for the rows' last pixels), and the OS granted this process
/// the tile data (asked once).
pub(super) fn available() -> bool {
    static GRANTED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *GRANTED.get_or_init(|| {
        cpu_has_amx_int8() && Kernel::best_int8() == Kernel::Avx512 && request_tiles()
    })
}

/// CPUID: AMX-TILE and AMX-INT8.
fn cpu_has_amx_int8() -> bool {
    dbt_isa::detected("amx_tile") == Some(true) && dbt_isa::detected("amx_int8") == Some(true)
}

/// `arch_prctl(ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA)`: whether Linux lets
/// this process use the tile data.
fn request_tiles() -> bool {
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    {
        const SYS_ARCH_PRCTL: i64 = 158;
        const ARCH_REQ_XCOMP_PERM: i64 = 0x1023;
        const XFEATURE_XTILEDATA: i64 = 18;
        let ret: i64;
        // SAFETY: the arch_prctl system call with a request that only
        // changes this process's permitted extended state; the kernel
        // clobbers rcx and r11.
        unsafe {
            std::arch::asm!(
                "syscall",
                inlateout("rax") SYS_ARCH_PRCTL => ret,
                in("rdi") ARCH_REQ_XCOMP_PERM,
                in("rsi") XFEATURE_XTILEDATA,
                lateout("rcx") _,
                lateout("r11") _,
                options(nostack),
            );
        }
        ret == 0
    }
    #[cfg(not(all(target_arch = "x86_64", target_os = "linux")))]
    {
        false
    }
}

/// The 64-byte tile configuration (palette 1): tiles 0-3 the sums `C`
/// (16 rows of 16 i32), tile 4 the pixels `A` (16 rows of `cin4` bytes),
/// tile 5 the weights `B` (`cin4 / 4` rows of 64 bytes).
#[repr(C, align(64))]
struct TileConfig {
    palette: u8,
    start_row: u8,
    reserved: [u8; 14],
    colsb: [u16; 16],
    rows: [u8; 16],
}

impl TileConfig {
    fn new(cin4: usize) -> Self {
        let mut c = Self {
            palette: 1,
            start_row: 0,
            reserved: [0; 14],
            colsb: [0; 16],
            rows: [0; 16],
        };
        for t in 0..4 {
            c.colsb[t] = 64;
            c.rows[t] = MT as u8;
        }
        c.colsb[4] = cin4 as u16;
        c.rows[4] = MT as u8;
        c.colsb[5] = 64;
        c.rows[5] = (cin4 / 4) as u8;
        c
    }
}

/// One output row `r` on AMX: `dst(0, x, g0, tile)` as the direct kernel's
/// (`tile[p * gw + j]`).
///
/// Callers: the AMX kernel only ([`available`] was true when the block was
/// made); `p` [`eligible`].
#[cfg(target_arch = "x86_64")]
pub(super) fn row(
    p: &PackedI8,
    inp: &[u8],
    r: usize,
    rs: usize,
    cs: usize,
    w: usize,
    dst: &mut RowSink<'_>,
) {
    let (cin4, ocp) = (p.cin4, p.ocp);
    assert!(eligible(p) && cin4.is_multiple_of(4) && cin4 <= cs && ocp.is_multiple_of(L));
    assert!(rs == (w + 2) * cs && inp.len() >= (r + 3) * rs && p.w.len() == 9 * cin4 * ocp);
    thread_local! {
        static SUMS: std::cell::RefCell<Vec<i32>> = const { std::cell::RefCell::new(Vec::new()) };
    }
    // 16 pixels x ocp sums, group by group in the epilogue's layout
    crate::with_scratch(&SUMS, MT * ocp, |sums| {
        row_in(p, inp, r, rs, cs, w, dst, sums)
    })
}

/// [`row`] with its scratch of `16 * ocp` sums (callers: [`row`], which
/// checks the bounds the tile loads rely on).
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
fn row_in(
    p: &PackedI8,
    inp: &[u8],
    r: usize,
    rs: usize,
    cs: usize,
    w: usize,
    dst: &mut RowSink<'_>,
    sums: &mut [i32],
) {
    let (cin4, ocp) = (p.cin4, p.ocp);
    assert!(sums.len() >= MT * ocp);
    let cfg = TileConfig::new(cin4);
    let (g4, nq) = (cin4 / 4, ocp / L);
    // SAFETY: AMX-TILE/INT8 available and granted (the caller's contract);
    // the configuration is a valid palette-1 one (tiles of at most 16 rows
    // and 64 bytes); every tile load reads 16 pixels x cin4 bytes, `cs` bytes
    // apart, of padded rows r..r + 3 and columns x..x + 18 <= w + 2 (inside
    // `inp`, asserted), or cin4 / 4 rows of 64 bytes of one tap's weights for
    // 16 channels from 16 q (inside `p.w`); every store writes 16 rows of 64
    // bytes inside `sums`.
    unsafe {
        std::arch::asm!("ldtilecfg [{}]", in(reg) &cfg as *const TileConfig, options(nostack, readonly));
        let mut x = 0;
        while x + MT <= w {
            for q in 0..nq {
                tilezero(q);
            }
            for t in 0..9 {
                let a = inp
                    .as_ptr()
                    .add(r * rs + x * cs + (t / 3) * rs + (t % 3) * cs);
                std::arch::asm!("tileloadd tmm4, [{a} + {s} * 1]", a = in(reg) a, s = in(reg) cs,
                                options(nostack, readonly));
                for q in 0..nq {
                    let b = p.w.as_ptr().add((t * g4 * ocp + q * L) * 4);
                    std::arch::asm!("tileloadd tmm5, [{b} + {s} * 1]", b = in(reg) b, s = in(reg) ocp * 4,
                                    options(nostack, readonly));
                    dot(q);
                }
            }
            let mut g0 = 0;
            while g0 < ocp {
                let gw = group_width(ocp, g0);
                for q in g0 / L..(g0 + gw) / L {
                    let c = sums.as_mut_ptr().add(MT * g0 + (q * L - g0));
                    store(q, c, gw * 4);
                }
                g0 += gw;
            }
            let mut g0 = 0;
            while g0 < ocp {
                let gw = group_width(ocp, g0);
                dst(0, x, g0, &sums[MT * g0..MT * (g0 + gw)]);
                g0 += gw;
            }
            x += MT;
        }
        std::arch::asm!("tilerelease", options(nostack));
        // The row's last pixels: the AVX-512 VNNI tile.
        let mut tile = [0i32; NP_NARROW * GROUP];
        let mut g0 = 0;
        while g0 < ocp {
            let gw = group_width(ocp, g0);
            let mut xx = x;
            while xx < w {
                let np = (w - xx).min(if gw == GROUP {
                    crate::NP_WIDE
                } else {
                    NP_NARROW
                });
                run_tile(
                    Kernel::Avx512,
                    gw,
                    np,
                    inp,
                    r * rs + xx * cs,
                    rs,
                    cs,
                    p,
                    g0,
                    &mut tile,
                    &mut [],
                );
                dst(0, xx, g0, &tile[..np * gw]);
                xx += np;
            }
            g0 += gw;
        }
    }
}

/// `tilezero tmm{q}`.
///
/// # Safety
/// AMX-TILE configured, `q < 4`.
#[cfg(target_arch = "x86_64")]
unsafe fn tilezero(q: usize) {
    // SAFETY: per the contract.
    unsafe {
        match q {
            0 => std::arch::asm!("tilezero tmm0", options(nostack, nomem)),
            1 => std::arch::asm!("tilezero tmm1", options(nostack, nomem)),
            2 => std::arch::asm!("tilezero tmm2", options(nostack, nomem)),
            _ => std::arch::asm!("tilezero tmm3", options(nostack, nomem)),
        }
    }
}

/// `tdpbusd tmm{q}, tmm4, tmm5`: sums `q` += pixels (u8) x weights (s8).
///
/// # Safety
/// AMX-INT8 configured, `q < 4`.
#[cfg(target_arch = "x86_64")]
unsafe fn dot(q: usize) {
    // SAFETY: per the contract.
    unsafe {
        match q {
            0 => std::arch::asm!("tdpbusd tmm0, tmm4, tmm5", options(nostack, nomem)),
            1 => std::arch::asm!("tdpbusd tmm1, tmm4, tmm5", options(nostack, nomem)),
            2 => std::arch::asm!("tdpbusd tmm2, tmm4, tmm5", options(nostack, nomem)),
            _ => std::arch::asm!("tdpbusd tmm3, tmm4, tmm5", options(nostack, nomem)),
        }
    }
}

/// `tilestored [c + stride * row], tmm{q}`.
///
/// # Safety
/// AMX-TILE configured, `q < 4`, `c` valid for 16 rows of 64 bytes
/// `stride` bytes apart.
#[cfg(target_arch = "x86_64")]
unsafe fn store(q: usize, c: *mut i32, stride: usize) {
    // SAFETY: per the contract.
    unsafe {
        match q {
            0 => {
                std::arch::asm!("tilestored [{c} + {s} * 1], tmm0", c = in(reg) c, s = in(reg) stride, options(nostack))
            }
            1 => {
                std::arch::asm!("tilestored [{c} + {s} * 1], tmm1", c = in(reg) c, s = in(reg) stride, options(nostack))
            }
            2 => {
                std::arch::asm!("tilestored [{c} + {s} * 1], tmm2", c = in(reg) c, s = in(reg) stride, options(nostack))
            }
            _ => {
                std::arch::asm!("tilestored [{c} + {s} * 1], tmm3", c = in(reg) c, s = in(reg) stride, options(nostack))
            }
        }
    }
}

/// The AMX kernel against the portable one on one random convolution (48
/// input channels, 48 outputs in three 16-channel groups, 37 pixels: two
/// AMX tiles and the AVX-512 remainder), checked once per process; an error
/// names the first difference. [`super::Int8Block`] refuses AMX on an error.
#[cfg(target_arch = "x86_64")]
pub(super) fn self_check() -> Result<(), String> {
    static CHECK: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    CHECK
        .get_or_init(|| {
            let (cin, out_ch, w, cs) = (48, 48, 37, 52);
            let mut state = 0x9E37_79B9_7F4A_7C15u64;
            let mut next = move || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                state
            };
            let weight = (0..out_ch * cin * 9).map(|_| next() as i8).collect();
            let l = Int8Conv {
                in_ch: cin,
                out_ch,
                weight,
                weight_scale: vec![1.0; out_ch],
                bias: vec![0.0; out_ch],
                prelu: None,
                q_out: None,
                q_act: None,
            };
            let p = pack(&l, QuantParams { scale: 1.0, zero_point: 0 }, false);
            let rs = (w + 2) * cs;
            let inp: Vec<u8> = (0..3 * rs).map(|_| next() as u8).collect();
            let (want, got) = (sums(Kernel::Portable, &p, &inp, rs, cs, w), sums(Kernel::Amx, &p, &inp, rs, cs, w));
            match want.iter().zip(&got).position(|(a, b)| a != b) {
                None => Ok(()),
                Some(k) => Err(format!(
                    "the AMX kernel's self-check failed: {} of {} sums differ from the portable kernel's \
                     (first: pixel {}, channel {}: {} against {}); AMX refused",
                    want.iter().zip(&got).filter(|(a, b)| a != b).count(),
                    want.len(),
                    k / p.ocp,
                    k % p.ocp,
                    got[k],
                    want[k]
                )),
            }
        })
        .clone()
}

/// One row's integer sums, `[x][ocp]`, by `kernel` (portable: its tiles;
/// AMX: [`row`]).
#[cfg(target_arch = "x86_64")]
fn sums(kernel: Kernel, p: &PackedI8, inp: &[u8], rs: usize, cs: usize, w: usize) -> Vec<i32> {
    let mut out = vec![0i32; w * p.ocp];
    let mut put = |x: usize, g0: usize, tile: &[i32]| {
        let gw = group_width(p.ocp, g0);
        for (px, t) in tile.chunks_exact(gw).enumerate() {
            let o = (x + px) * p.ocp + g0;
            out[o..o + gw].copy_from_slice(t);
        }
    };
    if kernel == Kernel::Amx {
        row(p, inp, 0, rs, cs, w, &mut |_, x, g0, t| put(x, g0, t));
    } else {
        let mut tile = [0i32; NP_NARROW * GROUP];
        for_each_tile(p.ocp, w, |g0, gw, x, np| {
            run_tile(
                kernel,
                gw,
                np,
                inp,
                x * cs,
                rs,
                cs,
                p,
                g0,
                &mut tile,
                &mut [],
            );
            put(x, g0, &tile[..np * gw]);
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Where the CPU has AMX-INT8: the OS grants the tiles, the self-check
    /// passes, and blocks on AMX give the portable kernel's bits (every
    /// convolution eligible: 8 and 32 input bytes, 16 and 32 outputs; widths
    /// below, at and past a 16-pixel tile).
    #[test]
    fn amx_int8_matches_portable() {
        if !dbt_isa::kernel_test_runs("int8 amx", &["amx_tile", "amx_int8", "avx512vnni"]) {
            return;
        }
        assert!(
            available(),
            "the CPU has AMX-INT8 but the OS did not grant the tile data"
        );
        self_check().unwrap();
        for (w, hidden) in [(5, 32), (16, 32), (37, 16), (40, 32)] {
            let b = crate::int8::tests::random_int8(5, 3, hidden, w as u64);
            let state = crate::testutil::random_vec(5 * 3 * w, 1);
            let aux = crate::testutil::random_vec(3 * 3 * w, 2);
            let run = |k| {
                let blk = Int8Block::new(&b, k).unwrap();
                let mut ws = Int8Workspace::new(&blk, 3, w);
                let mut s = state.clone();
                blk.run(&mut ws, &mut s, &aux).unwrap();
                s
            };
            assert_eq!(
                run(Kernel::Amx),
                run(Kernel::Portable),
                "width {w}, {hidden} channels"
            );
        }
    }
}
