//! AMX-INT8 (Intel Sapphire Rapids and later): the int8 convolution as tile
//! matrix products, `tdpbusd` (unsigned bytes x signed bytes into i32).
//!
//! For 16 output pixels of a row and each tap of the 3 x 3 kernel, the input
//! tile `A` is 16 rows (the pixels, `cs` bytes apart in the padded
//! channels-last buffer) of `cin4` bytes (their channels), and each weight
//! tile `B` is the tap's packed weights (`PackedI8::w`, `[tap][cin4 / 4][ocp][4]`:
//! `cin4 / 4` rows of 16 output channels x 4 bytes, exactly AMX's layout of
//! the right-hand operand, `ocp * 4` bytes apart). Thin inputs (`3 * cin4 <=
//! 64`, the blocks' first convolutions) whose pixels are `cin4` bytes apart
//! take a kernel row's three taps in one product: a tile row of `3 * cin4`
//! bytes from a pixel holds it and its two right neighbours, against
//! `PackedI8::w_rows` (three products instead of nine). The four sum tiles
//! are shared by [`blocking`]: two 16-pixel blocks by two 16-channel blocks
//! for 32 or 64 channels, with two `A` and two `B` tiles (AMX does not rename
//! tiles: alternating lets a load proceed while a product reads the other).
//! The products accumulate the direct kernel's sums exactly. Up to 64 input
//! bytes and four 16-channel blocks (`ocp <= 64`); other layers, and the
//! rows of fewer than 16 pixels, run the AVX-512 VNNI tile; a longer row's
//! last `w % 16` pixels are made by the block of its last 16 pixels, which
//! overlaps the block before.
//!
//! Linux gives a process AMX's tile data only on request
//! (`arch_prctl(ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA)`); [`available`]
//! asks once. Each worker thread loads the tile configuration before its
//! products and releases the tiles after.
//!
//! The kernel is a candidate of the measured choice (`crate::select`) where
//! the CPU has AMX-INT8 and the OS grants the tiles; `DBTOR_KERNEL=amx`
//! forces it. An [`super::Int8Block`] on it first checks a convolution
//! against the portable kernel ([`self_check`]) and refuses AMX (naming the
//! difference) if they differ. Its hardware test runs where the CPU has
//! AMX-INT8 (`DBTOR_REQUIRE_ISA=amx_int8` makes it compulsory; it ran on an
//! Intel Xeon with AMX). On every CPU, the kernel's own code (addresses,
//! tile configuration, operand layouts, epilogue) runs on an emulation of
//! the six AMX instructions it uses, as Intel's reference defines them,
//! with every byte accessed checked against its buffers (`tests::Emulated`),
//! and gives the portable kernel's sums.

use super::*;

/// Pixels per tile (the rows of `A` and `C`).
const MT: usize = 16;

/// The first of the two pixel tiles `A` (tmm4, tmm5) and of the two weight
/// tiles `B` (tmm6, tmm7); the sums `C` are tmm0-tmm3.
const A0: usize = 4;
const B0: usize = 6;

/// Most 16-pixel blocks one pass holds.
const PB_MAX: usize = 4;

/// How the four sum tiles are shared for a layer of `nq` 16-channel
/// blocks: (16-pixel blocks, channel blocks) per pass. Each tap's pixel
/// tile is loaded once per pass and used for every channel block, each
/// weight tile (while two fit) for every pixel block; AMX does not rename
/// tiles, so alternating between two A and two B tiles lets a load proceed
/// while the previous product still reads the other. One block of 64
/// channels takes two passes of 2 x 2: four tile loads per four products,
/// where one pass of 1 x 4 takes five.
fn blocking(nq: usize) -> (usize, usize) {
    match nq {
        1 => (4, 1),
        2 | 4 => (2, 2),
        _ => (1, nq),
    }
}

/// The start of the epilogue group holding channel `c` (groups of
/// [`group_width`] from 0).
fn group_start(ocp: usize, c: usize) -> usize {
    let mut g0 = 0;
    while g0 + group_width(ocp, g0) <= c {
        g0 += group_width(ocp, g0);
    }
    g0
}

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
/// (16 rows of 16 i32), tiles 4 and 5 the pixels `A` (16 rows of `cin4`
/// bytes), tiles 6 and 7 the weights `B` (`cin4 / 4` rows of 64 bytes).
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
    /// Products over `k` bytes: `A` is 16 rows of `k` bytes, `B` `k / 4`
    /// rows of 64.
    fn new(k: usize) -> Self {
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
        for t in 4..6 {
            c.colsb[t] = k as u16;
            c.rows[t] = MT as u8;
        }
        for t in 6..8 {
            c.colsb[t] = 64;
            c.rows[t] = (k / 4) as u8;
        }
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
    // up to 4 x 16 pixels x ocp sums, block by block, group by group in
    // the epilogue's layout
    crate::with_scratch(&SUMS, MT * PB_MAX * ocp, |sums| {
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
/// in `tmm4` and `tmm5`, the weights `B` in `tmm6` and `tmm7`. [`Hardware`] runs the AMX
/// instructions; the tests' emulation (`tests::Emulated`) follows their
/// definitions in Intel's Architecture Instruction Set Extensions
/// Programming Reference (chapter 3, "Intel AMX Instruction Set
/// Reference") and checks every byte accessed against the buffers.
trait TileOps {
    /// `ldtilecfg`.
    unsafe fn configure(&mut self, cfg: &TileConfig);
    /// `tilezero tmm{q}`, `q < 4`.
    unsafe fn zero(&mut self, q: usize);
    /// `tileloadd tmm{t}, [base + stride * row]`, `4 <= t < 8`.
    unsafe fn load(&mut self, tmm: usize, base: *const u8, stride: usize);
    /// `tdpbusd tmm{q}, tmm{a}, tmm{b}`: sums `q` (< 4) += pixels `a` (4 or
    /// 5, u8) x weights `b` (6 or 7, s8).
    unsafe fn dot(&mut self, q: usize, a: usize, b: usize);
    /// `tilestored [c + stride * row], tmm{q}`.
    unsafe fn store(&mut self, q: usize, c: *mut i32, stride: usize);
    /// `tilerelease`.
    unsafe fn release(&mut self);
}

/// The AMX instructions themselves.
struct Hardware;

/// [`row`] with its scratch of `16 * ocp` sums, its tile operations and the
/// kernel of a row of fewer than 16 pixels (callers: [`row`], which checks
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
    let nq = ocp / L;
    let (pb, qb) = blocking(nq);
    assert!(sums.len() >= MT * pb * ocp);
    // The products: nine taps of `cin4` bytes, or, where the pixels are
    // `cin4` bytes apart and the row's three taps fit a tile row, three
    // kernel rows of `3 * cin4` bytes (a tile row starting at a pixel holds
    // it and its two right neighbours). `(k, taps, weights)`: bytes per
    // product, the products per output and their weights.
    let (k, ntaps, wts): (usize, usize, &[i8]) = match p.w_rows.as_deref() {
        Some(wr) if cs == cin4 => (3 * cin4, 3, wr),
        _ => (cin4, 9, &p.w),
    };
    let tap_offset = |t: usize| {
        if ntaps == 3 {
            t * rs
        } else {
            (t / 3) * rs + (t % 3) * cs
        }
    };
    let cfg = TileConfig::new(k);
    // SAFETY: the tile operations may run (the contract); the configuration
    // is a valid palette-1 one (tiles of at most 16 rows and 64 bytes);
    // every pixel tile load reads 16 rows of `k` bytes, `cs` bytes apart,
    // from padded rows r..r + 3 and columns x..x + 16 * np + 2 <= w + 2
    // (nine taps: each row `cin4 <= cs` bytes of one pixel; three: `3 *
    // cs` bytes, the pixel and its two right neighbours), inside `inp`
    // (asserted by `row`); every weight tile load `k / 4` rows of 64 bytes
    // of one product's weights for 16 channels from 16 q (inside `wts`,
    // `ntaps * k * ocp` bytes); every store writes 16 rows of 64 bytes
    // inside the first `16 * np * ocp` sums.
    unsafe {
        tiles.configure(&cfg);
        let mut x = 0;
        while x < w && w >= MT {
            // A row's last `w % 16` pixels: the block of its last 16, whose
            // first pixels were made already (the same sums again, written
            // over themselves).
            if x + MT > w {
                x = w - MT;
            }
            // `np` blocks of 16 pixels from x (fewer at the row's end)
            let np = ((w - x) / MT).min(pb);
            let mut q0 = 0;
            while q0 < nq {
                let nqp = qb.min(nq - q0);
                // the pass with its tile numbers as constants (no jumps
                // between the tile instructions)
                let pass = Pass {
                    inp,
                    wts,
                    base: r * rs + x * cs,
                    cs,
                    k,
                    ocp,
                    q0,
                };
                match (np, nqp) {
                    (1, 1) => pass.products::<T, 1, 1>(tiles, ntaps, &tap_offset),
                    (2, 1) => pass.products::<T, 2, 1>(tiles, ntaps, &tap_offset),
                    (3, 1) => pass.products::<T, 3, 1>(tiles, ntaps, &tap_offset),
                    (4, 1) => pass.products::<T, 4, 1>(tiles, ntaps, &tap_offset),
                    (1, 2) => pass.products::<T, 1, 2>(tiles, ntaps, &tap_offset),
                    (2, 2) => pass.products::<T, 2, 2>(tiles, ntaps, &tap_offset),
                    (1, 3) => pass.products::<T, 1, 3>(tiles, ntaps, &tap_offset),
                    (1, 4) => pass.products::<T, 1, 4>(tiles, ntaps, &tap_offset),
                    _ => unreachable!("{np} x {nqp} blocks: more than the four sum tiles"),
                }
                // sums of pixel block i, channel block q: the epilogue's
                // layout of block i (`MT * ocp` sums, group by group)
                for i in 0..np {
                    for j in 0..nqp {
                        let q = q0 + j;
                        let g0 = group_start(ocp, q * L);
                        let gw = group_width(ocp, g0);
                        let c = sums.as_mut_ptr().add(i * MT * ocp + MT * g0 + (q * L - g0));
                        tiles.store(i * nqp + j, c, gw * 4);
                    }
                }
                q0 += nqp;
            }
            for i in 0..np {
                let block = &sums[i * MT * ocp..(i + 1) * MT * ocp];
                let mut g0 = 0;
                while g0 < ocp {
                    let gw = group_width(ocp, g0);
                    dst(0, x + i * MT, g0, &block[MT * g0..MT * (g0 + gw)]);
                    g0 += gw;
                }
            }
            x += np * MT;
        }
        tiles.release();
        // A row of fewer than 16 pixels: the AVX-512 VNNI tile (`rest`).
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

/// One pass of [`row_in`]: the sums of `NP` 16-pixel blocks from the
/// pixel at `base` by `NQ` 16-channel blocks from `q0`, over every tap.
struct Pass<'a> {
    inp: &'a [u8],
    wts: &'a [i8],
    base: usize,
    cs: usize,
    /// Bytes per product.
    k: usize,
    ocp: usize,
    q0: usize,
}

impl Pass<'_> {
    /// Zero the `NP * NQ` sum tiles and accumulate every tap's products
    /// into them (sum tile `i * NQ + j`: pixel block `i`, channel block
    /// `q0 + j`).
    ///
    /// # Safety
    /// [`row_in`]'s: the tile operations may run and are configured for
    /// `k`-byte products; the pass's pixels and weights are inside `inp`
    /// and `wts`.
    #[inline(always)]
    unsafe fn products<T: TileOps, const NP: usize, const NQ: usize>(
        &self,
        tiles: &mut T,
        ntaps: usize,
        tap_offset: &impl Fn(usize) -> usize,
    ) {
        let (k, ocp, cs) = (self.k, self.ocp, self.cs);
        // SAFETY: the contract.
        unsafe {
            for q in 0..NP * NQ {
                tiles.zero(q);
            }
            for t in 0..ntaps {
                let tap = self.base + tap_offset(t);
                for i in 0..NP {
                    let a = A0 + i % 2;
                    tiles.load(a, self.inp.as_ptr().add(tap + i * MT * cs), cs);
                    for j in 0..NQ {
                        let b = B0 + j % 2;
                        // the weights stay in B while they fit (two
                        // blocks), else each is loaded for its product
                        if i == 0 || NQ > 2 {
                            let wq = self
                                .wts
                                .as_ptr()
                                .add((t * (k / 4) * ocp + (self.q0 + j) * L) * 4);
                            tiles.load(b, wq as *const u8, ocp * 4);
                        }
                        tiles.dot(i * NQ + j, a, b);
                    }
                }
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
impl TileOps for Hardware {
    #[inline(always)]
    unsafe fn configure(&mut self, cfg: &TileConfig) {
        // SAFETY: AMX-TILE (the contract of `row_in`); a 64-byte palette-1
        // configuration.
        unsafe {
            std::arch::asm!("ldtilecfg [{}]", in(reg) cfg as *const TileConfig, options(nostack, readonly))
        }
    }

    #[inline(always)]
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

    #[inline(always)]
    unsafe fn load(&mut self, tmm: usize, base: *const u8, stride: usize) {
        macro_rules! load {
            ($t:literal) => {
                std::arch::asm!(concat!("tileloadd tmm", $t, ", [{a} + {s} * 1]"), a = in(reg) base,
                                s = in(reg) stride, options(nostack, readonly))
            };
        }
        // SAFETY: AMX-TILE configured; the rows inside their buffer (the
        // caller's).
        unsafe {
            match tmm {
                4 => load!(4),
                5 => load!(5),
                6 => load!(6),
                7 => load!(7),
                _ => unreachable!("tile {tmm}: the operands are tmm4-tmm7"),
            }
        }
    }

    #[inline(always)]
    unsafe fn dot(&mut self, q: usize, a: usize, b: usize) {
        macro_rules! dot {
            ($q:literal, $a:literal, $b:literal) => {
                std::arch::asm!(
                    concat!("tdpbusd tmm", $q, ", tmm", $a, ", tmm", $b),
                    options(nostack, nomem)
                )
            };
        }
        macro_rules! dots {
            ($q:literal) => {
                match (a, b) {
                    (4, 6) => dot!($q, 4, 6),
                    (4, 7) => dot!($q, 4, 7),
                    (5, 6) => dot!($q, 5, 6),
                    (5, 7) => dot!($q, 5, 7),
                    _ => unreachable!("tiles {a}, {b}: A is tmm4 or tmm5, B tmm6 or tmm7"),
                }
            };
        }
        // SAFETY: AMX-INT8 configured, `q < 4`, A and B operand tiles.
        unsafe {
            match q {
                0 => dots!(0),
                1 => dots!(1),
                2 => dots!(2),
                3 => dots!(3),
                _ => unreachable!("tile {q}: the sums are tmm0-tmm3"),
            }
        }
    }

    #[inline(always)]
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

    #[inline(always)]
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

/// [`super::amx_peak_ops`] (callers: [`available`] was true): four
/// independent sums, each `tdpbusd` 16 x 16 x 64 multiply-adds, from tiles
/// loaded once.
#[cfg(target_arch = "x86_64")]
pub(super) fn peak_ops(iterations: usize) -> f64 {
    let cfg = TileConfig::new(64);
    let ones = [1u8; 64 * MT];
    let mut hw = Hardware;
    let t = std::time::Instant::now();
    // SAFETY: AMX available and granted (the caller's); the operand tiles
    // are loaded from `ones` (16 rows of 64 bytes each).
    unsafe {
        hw.configure(&cfg);
        for tmm in A0..B0 + 2 {
            hw.load(tmm, ones.as_ptr(), 64);
        }
        for _ in 0..iterations {
            hw.dot(0, 4, 6);
            hw.dot(1, 4, 7);
            hw.dot(2, 5, 6);
            hw.dot(3, 5, 7);
        }
        hw.release();
    }
    let s = t.elapsed().as_secs_f64().max(1e-9);
    iterations as f64 * 4.0 * (MT * 16 * 64) as f64 * 2.0 / s
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
/// AMX: [`row`]; not AVX2, whose scratch this does not give).
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
    assert_eq!(rs, (w + 2) * cs);
    super::kernels::conv_row(kernel, p, inp, cs, w, 0, &mut [], &mut |_, x, g0, t| {
        put(x, g0, t)
    });
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
            assert!(self.configured && (4..8).contains(&tmm));
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

        unsafe fn dot(&mut self, q: usize, a: usize, b: usize) {
            assert!(self.configured && q < 4 && (4..8).contains(&a) && (4..8).contains(&b));
            assert!(
                q != a && q != b && a != b,
                "tdpbusd tmm{q}, tmm{a}, tmm{b}: #UD"
            );
            let ((cr, cc), (ar, ac), (br, bc)) = (self.shape[q], self.shape[a], self.shape[b]);
            // TDPBUSD's #UD conditions on the shapes.
            assert!(cc % 4 == 0 && ac % 4 == 0, "column bytes {cc}, {ac}");
            assert_eq!(cr, ar, "rows of C and A");
            assert_eq!(ac / 4, br, "A's dwords per row and B's rows");
            assert_eq!(cc, bc, "bytes per row of C and B");
            for m in 0..cr {
                for n in 0..cc / 4 {
                    let mut acc = i32::from_le_bytes(self.dword(q, m, n));
                    for k in 0..ac / 4 {
                        let (x, y) = (self.dword(a, m, k), self.dword(b, k, n));
                        for i in 0..4 {
                            acc = acc.wrapping_add(i32::from(x[i]) * i32::from(y[i] as i8));
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
    /// channels, widths below, at and past the 16-pixel tile and past every
    /// blocking's pass of up to four (the rest on the portable tile, which
    /// gives the AVX-512 VNNI tile's bits). This checks
    /// the kernel's use of the instructions, not the instructions on a CPU
    /// (`amx_int8_matches_portable`, where AMX is present).
    #[test]
    fn the_amx_kernel_on_emulated_tiles_matches_portable() {
        let mut next = xorshift(0x2545_F491_4F6C_DD1D);
        let (mut dots, mut row_products) = (0, 0);
        for (cin, out_ch) in [
            (5, 16),
            (8, 32),
            (30, 48),
            (48, 48),
            (64, 64),
            (3, 64),
            (7, 64),
        ] {
            let p = random_conv(cin, out_ch, &mut next);
            assert!(eligible(&p), "{cin} -> {out_ch}");
            let ws = [5, 15, 16, 17, 37, 48, 80, 101];
            for (w, cs) in ws.iter().flat_map(|&w| [(w, p.cin4), (w, p.cin4 + 4)]) {
                let rs = (w + 2) * cs;
                let inp: Vec<u8> = (0..3 * rs).map(|_| next() as u8).collect();
                let want = sums(Kernel::Portable, &p, &inp, rs, cs, w);
                let mut got = vec![0i32; w * p.ocp];
                let mut scratch = vec![0i32; MT * PB_MAX * p.ocp];
                let (a, b, c) = (span(&inp), span(&p.w), span(&scratch));
                let mut buffers = vec![(a.0, a.1, false), (b.0, b.1, false), (c.0, c.1, true)];
                if let Some(wr) = p.w_rows.as_deref() {
                    let d = span(wr);
                    buffers.push((d.0, d.1, false));
                }
                let mut tiles = Emulated::new(buffers);
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
                let taps = if p.w_rows.is_some() && cs == p.cin4 {
                    3
                } else {
                    9
                };
                // a block per 16 pixels, the last 16 a block of their own
                // where the width leaves a remainder (none below 16)
                let blocks = if w < MT { 0 } else { w.div_ceil(MT) };
                assert_eq!(tiles.dots, blocks * taps * (p.ocp / L), "tdpbusd count");
                dots += tiles.dots;
                if taps == 3 {
                    row_products += tiles.dots;
                }
                let first = want.iter().zip(&got).position(|(a, b)| a != b);
                assert_eq!(
                    first, None,
                    "{cin} -> {out_ch} channels, width {w}, stride {cs}"
                );
            }
        }
        assert!(dots > 0 && row_products > 0);
    }

    /// Where the CPU has AMX-INT8: the OS grants the tiles, the self-check
    /// passes, and blocks on AMX give the portable kernel's bits (every
    /// convolution eligible: 8 to 64 input bytes, 16 to 64 outputs; widths
    /// below, at and past a 16-pixel tile and past a pass of several).
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
        for (w, hidden) in [(5, 32), (16, 32), (37, 16), (40, 32), (101, 64), (83, 16)] {
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
