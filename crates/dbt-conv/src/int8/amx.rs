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
//! AMX-INT8 (`DBTOR_REQUIRE_ISA=amx_int8` makes them compulsory). On every
//! CPU, the kernel's own code (addresses, tile configuration, operand
//! layouts, epilogue) runs on an emulation of the six AMX instructions it
//! uses, as Intel's reference defines them, with every byte accessed checked
//! against its buffers (`tests::Emulated`), and gives the portable kernel's
//! sums: what is left unproven is the hardware, not the kernel's use of it.

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

// The 64-byte layout `ldtilecfg` reads (Intel's reference: palette at byte
// 0, start_row at 1, bytes 2-15 reserved, colsb of tiles 0-15 as u16 from
// byte 16, rows of tiles 0-15 as u8 from byte 48).
const _: () = {
    assert!(std::mem::size_of::<TileConfig>() == 64);
    assert!(std::mem::offset_of!(TileConfig, palette) == 0);
    assert!(std::mem::offset_of!(TileConfig, start_row) == 1);
    assert!(std::mem::offset_of!(TileConfig, colsb) == 16);
    assert!(std::mem::offset_of!(TileConfig, rows) == 48);
};

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
        // SAFETY: AMX-TILE/INT8 available and granted (the caller's
        // contract), AVX-512 VNNI with them (`available`).
        unsafe {
            row_in(
                &mut Hardware,
                Kernel::Avx512,
                p,
                inp,
                r,
                rs,
                cs,
                w,
                dst,
                sums,
            )
        }
    })
}

/// The tile operations of [`row_in`]: sums in `tmm0..tmm3`, the pixels `A`
/// in `tmm4`, the weights `B` in `tmm5`. [`Hardware`] runs the AMX
/// instructions; the tests' emulation (`tests::Emulated`) follows their
/// definitions in Intel's Architecture Instruction Set Extensions
/// Programming Reference (chapter 3, "Intel AMX Instruction Set
/// Reference") and checks every byte accessed against the buffers.
trait TileOps {
    /// `ldtilecfg`.
    unsafe fn configure(&mut self, cfg: &TileConfig);
    /// `tilezero tmm{q}`, `q < 4`.
    unsafe fn zero(&mut self, q: usize);
    /// `tileloadd tmm4 / tmm5, [base + stride * row]`.
    unsafe fn load(&mut self, tmm: usize, base: *const u8, stride: usize);
    /// `tdpbusd tmm{q}, tmm4, tmm5`: sums `q` += pixels (u8) x weights (s8).
    unsafe fn dot(&mut self, q: usize);
    /// `tilestored [c + stride * row], tmm{q}`.
    unsafe fn store(&mut self, q: usize, c: *mut i32, stride: usize);
    /// `tilerelease`.
    unsafe fn release(&mut self);
}

/// The AMX instructions themselves.
struct Hardware;

/// [`row`] with its scratch of `16 * ocp` sums, its tile operations and the
/// kernel of the row's last `w % 16` pixels (callers: [`row`], which checks
/// the bounds the tile loads rely on; the tests' emulation).
///
/// # Safety
/// `tiles`' operations and `rest` may run on this CPU (for [`Hardware`]:
/// AMX-TILE/INT8 available and granted).
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
unsafe fn row_in<T: TileOps>(
    tiles: &mut T,
    rest: Kernel,
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
    // SAFETY: the tile operations may run (the contract); the configuration
    // is a valid palette-1 one (tiles of at most 16 rows and 64 bytes);
    // every tile load reads 16 pixels x cin4 bytes, `cs` bytes apart, of
    // padded rows r..r + 3 and columns x..x + 18 <= w + 2 (inside `inp`,
    // asserted by `row`), or cin4 / 4 rows of 64 bytes of one tap's weights
    // for 16 channels from 16 q (inside `p.w`); every store writes 16 rows
    // of 64 bytes inside `sums`.
    unsafe {
        tiles.configure(&cfg);
        let mut x = 0;
        while x + MT <= w {
            for q in 0..nq {
                tiles.zero(q);
            }
            for t in 0..9 {
                let a = inp
                    .as_ptr()
                    .add(r * rs + x * cs + (t / 3) * rs + (t % 3) * cs);
                tiles.load(4, a, cs);
                for q in 0..nq {
                    let b = p.w.as_ptr().add((t * g4 * ocp + q * L) * 4);
                    tiles.load(5, b as *const u8, ocp * 4);
                    tiles.dot(q);
                }
            }
            let mut g0 = 0;
            while g0 < ocp {
                let gw = group_width(ocp, g0);
                for q in g0 / L..(g0 + gw) / L {
                    let c = sums.as_mut_ptr().add(MT * g0 + (q * L - g0));
                    tiles.store(q, c, gw * 4);
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
        tiles.release();
        // The row's last pixels: the AVX-512 VNNI tile (`rest`).
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
                    rest,
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

#[cfg(target_arch = "x86_64")]
impl TileOps for Hardware {
    unsafe fn configure(&mut self, cfg: &TileConfig) {
        // SAFETY: AMX-TILE (the contract of `row_in`); a 64-byte palette-1
        // configuration.
        unsafe {
            std::arch::asm!("ldtilecfg [{}]", in(reg) cfg as *const TileConfig, options(nostack, readonly))
        }
    }

    unsafe fn zero(&mut self, q: usize) {
        // SAFETY: AMX-TILE configured, `q < 4`.
        unsafe {
            match q {
                0 => std::arch::asm!("tilezero tmm0", options(nostack, nomem)),
                1 => std::arch::asm!("tilezero tmm1", options(nostack, nomem)),
                2 => std::arch::asm!("tilezero tmm2", options(nostack, nomem)),
                3 => std::arch::asm!("tilezero tmm3", options(nostack, nomem)),
                _ => unreachable!("tile {q}: the sums are tmm0-tmm3"),
            }
        }
    }

    unsafe fn load(&mut self, tmm: usize, base: *const u8, stride: usize) {
        // SAFETY: AMX-TILE configured; the rows inside their buffer (the
        // caller's).
        unsafe {
            match tmm {
                4 => {
                    std::arch::asm!("tileloadd tmm4, [{a} + {s} * 1]", a = in(reg) base, s = in(reg) stride,
                                     options(nostack, readonly))
                }
                5 => {
                    std::arch::asm!("tileloadd tmm5, [{a} + {s} * 1]", a = in(reg) base, s = in(reg) stride,
                                     options(nostack, readonly))
                }
                _ => unreachable!("tile {tmm}: the operands are tmm4 and tmm5"),
            }
        }
    }

    unsafe fn dot(&mut self, q: usize) {
        // SAFETY: AMX-INT8 configured, `q < 4`.
        unsafe {
            match q {
                0 => std::arch::asm!("tdpbusd tmm0, tmm4, tmm5", options(nostack, nomem)),
                1 => std::arch::asm!("tdpbusd tmm1, tmm4, tmm5", options(nostack, nomem)),
                2 => std::arch::asm!("tdpbusd tmm2, tmm4, tmm5", options(nostack, nomem)),
                3 => std::arch::asm!("tdpbusd tmm3, tmm4, tmm5", options(nostack, nomem)),
                _ => unreachable!("tile {q}: the sums are tmm0-tmm3"),
            }
        }
    }

    unsafe fn store(&mut self, q: usize, c: *mut i32, stride: usize) {
        // SAFETY: AMX-TILE configured, `q < 4`, `c` valid for 16 rows of 64
        // bytes `stride` bytes apart (the caller's).
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
                3 => {
                    std::arch::asm!("tilestored [{c} + {s} * 1], tmm3", c = in(reg) c, s = in(reg) stride, options(nostack))
                }
                _ => unreachable!("tile {q}: the sums are tmm0-tmm3"),
            }
        }
    }

    unsafe fn release(&mut self) {
        // SAFETY: AMX-TILE.
        unsafe { std::arch::asm!("tilerelease", options(nostack)) }
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
            let mut next = xorshift(0x9E37_79B9_7F4A_7C15);
            let p = random_conv(cin, out_ch, &mut next);
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

/// A xorshift64 generator (the self-check's and the tests' random bytes).
fn xorshift(mut state: u64) -> impl FnMut() -> u64 {
    move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    }
}

/// A convolution of random weights, unit scales and no epilogue, packed for
/// the direct kernels (the self-check's and the tests' layer).
fn random_conv(cin: usize, out_ch: usize, next: &mut impl FnMut() -> u64) -> PackedI8 {
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
    pack(
        &l,
        QuantParams {
            scale: 1.0,
            zero_point: 0,
        },
        false,
    )
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

    /// The AMX instructions `row_in` uses, as Intel's reference defines
    /// them (Architecture Instruction Set Extensions Programming Reference,
    /// chapter 3: `LDTILECFG`, `TILEZERO`, `TILELOADD`, `TDPBUSD`,
    /// `TILESTORED`, `TILERELEASE`), on tiles of 16 rows of 64 bytes. Each
    /// instruction's operand shapes are checked as the CPU checks them
    /// (`#UD` there, a panic here), and every byte a load or store touches
    /// must lie inside one of the buffers given (read-only or writable).
    struct Emulated {
        /// (rows, bytes per row) of tiles 0-7, from the configuration.
        shape: [(usize, usize); 8],
        configured: bool,
        tiles: [[u8; 16 * 64]; 8],
        /// Byte ranges `(start, end, writable)` the kernel may touch.
        buffers: Vec<(usize, usize, bool)>,
        /// `tdpbusd` executed.
        dots: usize,
    }

    impl Emulated {
        fn new(buffers: Vec<(usize, usize, bool)>) -> Self {
            Emulated {
                shape: [(0, 0); 8],
                configured: false,
                tiles: [[0; 16 * 64]; 8],
                buffers,
                dots: 0,
            }
        }

        fn check(&self, at: usize, n: usize, write: bool) {
            assert!(
                self.buffers
                    .iter()
                    .any(|&(s, e, wr)| at >= s && at + n <= e && (wr || !write)),
                "the kernel {} {n} bytes at {at:#x}, outside its buffers",
                if write { "stores" } else { "loads" }
            );
        }

        fn dword(&self, t: usize, row: usize, k: usize) -> [u8; 4] {
            let o = row * 64 + 4 * k;
            self.tiles[t][o..o + 4].try_into().unwrap()
        }
    }

    impl TileOps for Emulated {
        unsafe fn configure(&mut self, cfg: &TileConfig) {
            // The 64 bytes as the CPU reads them, not the struct's fields.
            // SAFETY: `TileConfig` is 64 plain bytes (asserted at compile time).
            let b: [u8; 64] = unsafe { std::mem::transmute_copy(cfg) };
            assert_eq!(b[0], 1, "palette");
            assert_eq!(b[1], 0, "start_row");
            assert!(b[2..16].iter().all(|&x| x == 0), "reserved bytes");
            for t in 0..16 {
                let colsb = u16::from_le_bytes([b[16 + 2 * t], b[17 + 2 * t]]) as usize;
                let rows = b[48 + t] as usize;
                if t >= 8 {
                    // Palette 1 has 8 tiles; the CPU faults on others.
                    assert_eq!((rows, colsb), (0, 0), "tile {t}");
                    continue;
                }
                assert!(rows <= 16 && colsb <= 64, "tile {t}: {rows} x {colsb}");
                assert_eq!(rows == 0, colsb == 0, "tile {t}: {rows} x {colsb}");
                self.shape[t] = (rows, colsb);
            }
            // LDTILECFG zeroes every tile.
            self.tiles = [[0; 16 * 64]; 8];
            self.configured = true;
        }

        unsafe fn zero(&mut self, q: usize) {
            assert!(self.configured && q < 4);
            self.tiles[q] = [0; 16 * 64];
        }

        unsafe fn load(&mut self, tmm: usize, base: *const u8, stride: usize) {
            assert!(self.configured && (tmm == 4 || tmm == 5));
            let (rows, colsb) = self.shape[tmm];
            assert!(rows > 0, "tile {tmm} not configured");
            self.tiles[tmm] = [0; 16 * 64];
            for r in 0..rows {
                let at = base as usize + r * stride;
                self.check(at, colsb, false);
                // SAFETY: inside one of the buffers (checked).
                let row = unsafe { std::slice::from_raw_parts(at as *const u8, colsb) };
                self.tiles[tmm][r * 64..r * 64 + colsb].copy_from_slice(row);
            }
        }

        unsafe fn dot(&mut self, q: usize) {
            assert!(self.configured && q < 4);
            let ((cr, cc), (ar, ac), (br, bc)) = (self.shape[q], self.shape[4], self.shape[5]);
            // TDPBUSD's #UD conditions on the shapes.
            assert!(cc % 4 == 0 && ac % 4 == 0, "column bytes {cc}, {ac}");
            assert_eq!(cr, ar, "rows of C and A");
            assert_eq!(ac / 4, br, "A's dwords per row and B's rows");
            assert_eq!(cc, bc, "bytes per row of C and B");
            for m in 0..cr {
                for n in 0..cc / 4 {
                    let mut acc = i32::from_le_bytes(self.dword(q, m, n));
                    for k in 0..ac / 4 {
                        let (a, b) = (self.dword(4, m, k), self.dword(5, k, n));
                        for i in 0..4 {
                            acc = acc.wrapping_add(i32::from(a[i]) * i32::from(b[i] as i8));
                        }
                    }
                    self.tiles[q][m * 64 + 4 * n..m * 64 + 4 * n + 4]
                        .copy_from_slice(&acc.to_le_bytes());
                }
            }
            self.dots += 1;
        }

        unsafe fn store(&mut self, q: usize, c: *mut i32, stride: usize) {
            assert!(self.configured && q < 4);
            let (rows, colsb) = self.shape[q];
            for r in 0..rows {
                let at = c as usize + r * stride;
                self.check(at, colsb, true);
                // SAFETY: inside a writable buffer (checked).
                let row = unsafe { std::slice::from_raw_parts_mut(at as *mut u8, colsb) };
                row.copy_from_slice(&self.tiles[q][r * 64..r * 64 + colsb]);
            }
        }

        unsafe fn release(&mut self) {
            assert!(self.configured, "tilerelease without a configuration");
            self.configured = false;
        }
    }

    fn span<T>(v: &[T]) -> (usize, usize) {
        let s = v.as_ptr() as usize;
        (s, s + std::mem::size_of_val(v))
    }

    /// On any CPU: the AMX kernel's addressing, tile configuration, operand
    /// layouts and epilogue, run on an emulation of the AMX instructions
    /// (`Emulated`, every access inside the buffers), give the portable
    /// kernel's sums on every eligible shape tried: 3 to 64 input channels,
    /// some not a multiple of 4 (3, 5, 30), 16 to 64 outputs (one to four C
    /// tiles, epilogue groups of 64 and 16), a channel stride wider than the
    /// channels, widths below, at and past the 16-pixel tile (the rest on the
    /// portable tile, which gives the AVX-512 VNNI tile's bits). This checks
    /// the kernel's use of the instructions, not the instructions on a CPU
    /// (`amx_int8_matches_portable`, where AMX is present).
    #[test]
    fn the_amx_kernel_on_emulated_tiles_matches_portable() {
        let mut next = xorshift(0x2545_F491_4F6C_DD1D);
        let mut dots = 0;
        for (cin, out_ch) in [(5, 16), (8, 32), (30, 48), (48, 48), (64, 64), (3, 64)] {
            let p = random_conv(cin, out_ch, &mut next);
            assert!(eligible(&p), "{cin} -> {out_ch}");
            for w in [5, 16, 37, 48] {
                let cs = p.cin4 + 4;
                let rs = (w + 2) * cs;
                let inp: Vec<u8> = (0..3 * rs).map(|_| next() as u8).collect();
                let want = sums(Kernel::Portable, &p, &inp, rs, cs, w);
                let mut got = vec![0i32; w * p.ocp];
                let mut scratch = vec![0i32; MT * p.ocp];
                let (a, b, c) = (span(&inp), span(&p.w), span(&scratch));
                let mut tiles =
                    Emulated::new(vec![(a.0, a.1, false), (b.0, b.1, false), (c.0, c.1, true)]);
                let ocp = p.ocp;
                let mut put = |_: usize, x: usize, g0: usize, tile: &[i32]| {
                    let gw = group_width(ocp, g0);
                    for (px, t) in tile.chunks_exact(gw).enumerate() {
                        let o = (x + px) * ocp + g0;
                        got[o..o + gw].copy_from_slice(t);
                    }
                };
                // SAFETY: the emulation runs anywhere; the rest on the
                // portable tile.
                unsafe {
                    row_in(
                        &mut tiles,
                        Kernel::Portable,
                        &p,
                        &inp,
                        0,
                        rs,
                        cs,
                        w,
                        &mut put,
                        &mut scratch,
                    );
                }
                assert!(!tiles.configured, "tiles not released");
                assert_eq!(tiles.dots, (w / MT) * 9 * (p.ocp / L), "tdpbusd count");
                dots += tiles.dots;
                let first = want.iter().zip(&got).position(|(a, b)| a != b);
                assert_eq!(first, None, "{cin} -> {out_ch} channels, width {w}");
            }
        }
        assert!(dots > 0);
    }

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
