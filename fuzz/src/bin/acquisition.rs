//! A recorded acquisition (`acquisition.json` and `counts.f32`) from
//! arbitrary bytes: the first two bytes give the header's length, the rest
//! is the counts. Nothing may panic or allocate beyond the header's checked
//! size; what is accepted has the slices its header announces.

fn main() {
    afl::fuzz!(|data: &[u8]| {
        if data.len() < 2 {
            return;
        }
        let n = (u16::from_le_bytes([data[0], data[1]]) as usize).min(data.len() - 2);
        let (header, counts) = data[2..].split_at(n);
        if let Ok(a) = dbt_store::acquisition::decode_acquisition(header, counts) {
            assert_eq!(a.counts.len(), a.header.slices);
        }
    });
}
