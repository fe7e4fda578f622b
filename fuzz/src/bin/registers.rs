//! Arbitrary register words through the register decoder: nothing may
//! panic; whatever decodes must encode back to the same words.

use dbt_gantry::registers::{decode, encode, COUNT};

fn main() {
    afl::fuzz!(|data: &[u8]| {
        let words: Vec<u16> = data
            .chunks_exact(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .collect();
        if let Ok(r) = decode(&words) {
            let back = encode(&r);
            assert_eq!(&back[..], &words[..COUNT], "decode/encode round trip");
        }
    });
}
