//! The DICOM report read-back (`dbtor-diag report`) on arbitrary bytes:
//! nothing may panic, and no element length is trusted beyond the input's
//! size (the bounds check runs before dicom-rs parses).

fn main() {
    afl::fuzz!(|data: &[u8]| {
        let _ = dbt_dicom::read_values(data);
    });
}
