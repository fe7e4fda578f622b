//! Arbitrary bytes through the frame decoder (resynchronisation, CRC,
//! payload parsing) and every decoded frame through the acquisition
//! assembler: nothing may panic; a decoded frame must re-encode to bytes that
//! decode to the same frame.
#![no_main]

use dbt_gantry::assemble::Assembler;
use dbt_gantry::frame::{encode, Decoder};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut dec = Decoder::new();
    let mut asm = Assembler::new();
    // Feed in two chunks to exercise partial frames.
    let cut = data.first().map_or(0, |&b| b as usize % (data.len() + 1));
    dec.push(&data[..cut]);
    dec.push(&data[cut..]);
    while let Some(r) = dec.next_frame() {
        if let Ok((seq, frame)) = r {
            let bytes = encode(&frame, seq);
            let mut again = Decoder::new();
            again.push(&bytes);
            match again.next_frame() {
                Some(Ok((s2, f2))) => {
                    assert!(s2 == seq && f2 == frame, "re-encoding changed the frame")
                }
                other => panic!("a decoded frame did not survive re-encoding: {other:?}"),
            }
            let _ = asm.accept(seq, frame);
        }
    }
});
