//! CRC-32 (IEEE 802.3, reflected polynomial 0xEDB88320) of any byte range
//! of a stream in O(log n), from prefix CRCs.
//!
//! The frame decoder keeps `P[i] = crc32(stream[0..i])` for every byte it
//! holds. CRC-32 is affine, so for `A || B` (zlib's `crc32_combine`):
//! `crc(A || B) = (x^(8 |B|) mod p) * crc(A) xor crc(B)` in GF(2)[x] mod the
//! polynomial, hence `crc(stream[a..b]) = P[b] xor (x^(8 (b - a)) * P[a])`.
//! A candidate frame's CRC then costs a few dozen carry-less products,
//! whatever its declared length, and resynchronising over any byte sequence
//! stays linear in the bytes received (the quadratic case was re-hashing up
//! to a full frame for every false start marker).

/// The reflected CRC-32 polynomial.
const POLY: u32 = 0xEDB8_8320;

const fn byte_table() -> [u32; 256] {
    let mut t = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 { (c >> 1) ^ POLY } else { c >> 1 };
            k += 1;
        }
        t[i] = c;
        i += 1;
    }
    t
}

static TABLE: [u32; 256] = byte_table();

/// `a * b mod p` in the reflected representation (zlib's `multmodp`).
const fn multmodp(a: u32, mut b: u32) -> u32 {
    let mut m: u32 = 1 << 31;
    let mut p = 0u32;
    loop {
        if a & m != 0 {
            p ^= b;
            if a & (m - 1) == 0 {
                break;
            }
        }
        m >>= 1;
        b = if b & 1 != 0 { (b >> 1) ^ POLY } else { b >> 1 };
    }
    p
}

/// `x^(2^k) mod p` for k = 0..32 (zlib's `x2n_table`).
const fn x2n_table() -> [u32; 32] {
    let mut t = [0u32; 32];
    let mut p: u32 = 1 << 30; // x^1
    t[0] = p;
    let mut n = 1;
    while n < 32 {
        p = multmodp(p, p);
        t[n] = p;
        n += 1;
    }
    t
}

static X2N: [u32; 32] = x2n_table();

/// `x^(8 n) mod p`.
fn x8n(mut n: u64) -> u32 {
    let mut p: u32 = 1 << 31; // x^0
    let mut k = 3; // 2^3 = 8 bits per byte
    while n != 0 {
        if n & 1 != 0 {
            p = multmodp(X2N[k & 31], p);
        }
        n >>= 1;
        k += 1;
    }
    p
}

/// The CRC-32 of `prefix || bytes` from the CRC-32 of `prefix`.
pub fn extend(crc: u32, bytes: &[u8]) -> u32 {
    let mut c = !crc;
    for &b in bytes {
        c = TABLE[((c ^ b as u32) & 0xff) as usize] ^ (c >> 8);
    }
    !c
}

/// Append the CRC-32 of `prefix || bytes[..=i]` for every `i` to `out`,
/// from `crc`, the CRC-32 of `prefix`.
pub fn prefixes(crc: u32, bytes: &[u8], out: &mut Vec<u32>) {
    out.reserve(bytes.len());
    let mut c = !crc;
    for &b in bytes {
        c = TABLE[((c ^ b as u32) & 0xff) as usize] ^ (c >> 8);
        out.push(!c);
    }
}

/// The CRC-32 of `stream[a..b]` from the prefix CRCs `pa = crc(stream[0..a])`
/// and `pb = crc(stream[0..b])`.
pub fn range(pa: u32, pb: u32, len: u64) -> u32 {
    pb ^ multmodp(x8n(len), pa)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn extend_is_crc32() {
        assert_eq!(extend(0, b"123456789"), 0xCBF4_3926); // the check value
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let v: Vec<u8> = (0..5000).map(|_| r.random()).collect();
        assert_eq!(extend(0, &v), crc32fast::hash(&v));
        assert_eq!(
            extend(extend(0, &v[..1234]), &v[1234..]),
            crc32fast::hash(&v)
        );
    }

    #[test]
    fn any_range_from_prefixes() {
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let v: Vec<u8> = (0..20_000).map(|_| r.random()).collect();
        let mut pre = vec![0u32];
        prefixes(0, &v[..777], &mut pre);
        prefixes(pre[777], &v[777..], &mut pre);
        assert_eq!(pre.len(), v.len() + 1);
        for _ in 0..300 {
            let a = r.random_range(0..v.len());
            let b = r.random_range(a..=v.len());
            assert_eq!(
                range(pre[a], pre[b], (b - a) as u64),
                crc32fast::hash(&v[a..b]),
                "range {a}..{b}"
            );
        }
    }
}
