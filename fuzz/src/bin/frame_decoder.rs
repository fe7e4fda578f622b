//! Arbitrary bytes through the frame decoder (resynchronisation, CRC,
//! payload parsing, the memory budget) and every decoded frame through the
//! budgeted acquisition assembler: nothing may panic; a decoded frame must
//! re-encode to bytes that decode to the same frame.

use dbt_gantry::assemble::{Assembler, Budget};
use dbt_gantry::frame::{encode, Decoder};

fn main() {
    afl::fuzz!(|data: &[u8]| {
        let budget = Budget {
            projections: 25,
            columns: 8,
            max_rows: 16,
        };
        let mut dec = Decoder::with_max_payload(budget.projection_payload().max(1024));
        let mut asm = Assembler::with_budget(budget);
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
}
