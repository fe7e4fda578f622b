//! A DICOM file's element lengths checked against its size before it is
//! parsed: a decoder that trusts a corrupted 32-bit length allocates up to
//! 4 GiB for it. Walks the Part 10 file (preamble, file meta group in
//! explicit VR little endian, then the dataset in the transfer syntax the
//! meta group names: explicit or implicit VR little endian), including
//! sequences and items of defined and undefined length, and refuses the
//! first element whose value would run past the end of its container.

use crate::DicomError;

/// Value representations with a 2-byte reserved field and a 4-byte length in
/// explicit VR (PS3.5 7.1.2).
const LONG_VRS: [&[u8; 2]; 12] = [
    b"OB", b"OD", b"OF", b"OL", b"OV", b"OW", b"SQ", b"SV", b"UC", b"UN", b"UR", b"UT",
];
/// Every value representation of PS3.5 table 6.2-1; an explicit-VR element
/// with any other two bytes is not DICOM.
const VRS: [&[u8; 2]; 34] = [
    b"AE", b"AS", b"AT", b"CS", b"DA", b"DS", b"DT", b"FD", b"FL", b"IS", b"LO", b"LT", b"OB",
    b"OD", b"OF", b"OL", b"OV", b"OW", b"PN", b"SH", b"SL", b"SQ", b"SS", b"ST", b"SV", b"TM",
    b"UC", b"UI", b"UL", b"UN", b"UR", b"US", b"UT", b"UV",
];
const UNDEFINED: u32 = 0xFFFF_FFFF;
const ITEM: (u16, u16) = (0xFFFE, 0xE000);
const ITEM_END: (u16, u16) = (0xFFFE, 0xE00D);
const SEQ_END: (u16, u16) = (0xFFFE, 0xE0DD);
/// Nesting beyond this is refused (our reports nest 6 deep).
const MAX_DEPTH: usize = 64;

struct Walker<'a> {
    b: &'a [u8],
    explicit: bool,
}

fn fail(at: usize, reason: impl Into<String>) -> DicomError {
    DicomError::Encoding(format!("byte {at}: {}", reason.into()))
}

impl Walker<'_> {
    fn u16(&self, at: usize) -> Result<u16, DicomError> {
        self.b
            .get(at..at + 2)
            .map(|s| u16::from_le_bytes([s[0], s[1]]))
            .ok_or_else(|| fail(at, "truncated"))
    }
    fn u32(&self, at: usize) -> Result<u32, DicomError> {
        self.b
            .get(at..at + 4)
            .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
            .ok_or_else(|| fail(at, "truncated"))
    }

    /// The header of the element at `at`: its tag, its value's declared
    /// length, the header's size, and whether it is an explicit SQ.
    fn element(&self, at: usize) -> Result<((u16, u16), u32, usize, bool), DicomError> {
        let tag = (self.u16(at)?, self.u16(at + 2)?);
        if !self.explicit || tag.0 == 0xFFFE {
            return Ok((tag, self.u32(at + 4)?, 8, false));
        }
        let vr = self
            .b
            .get(at + 4..at + 6)
            .ok_or_else(|| fail(at, "truncated"))?;
        if !VRS.iter().any(|v| v[..] == *vr) {
            return Err(fail(
                at,
                format!(
                    "element ({:04X},{:04X}) has the value representation {:02X} {:02X}, not a DICOM one",
                    tag.0, tag.1, vr[0], vr[1]
                ),
            ));
        }
        Ok(if LONG_VRS.iter().any(|v| v[..] == *vr) {
            (tag, self.u32(at + 8)?, 12, vr == b"SQ")
        } else {
            (tag, self.u16(at + 6)? as u32, 8, false)
        })
    }

    /// Walk the elements in `[at, end)` (or up to a delimiter when
    /// `undefined`); returns the position after the last one.
    fn dataset(
        &self,
        mut at: usize,
        end: usize,
        undefined: bool,
        depth: usize,
    ) -> Result<usize, DicomError> {
        if depth > MAX_DEPTH {
            return Err(fail(at, format!("nested deeper than {MAX_DEPTH}")));
        }
        while at < end {
            let (tag, len, head, is_seq) = self.element(at)?;
            if undefined && tag == ITEM_END {
                return Ok(at + 8);
            }
            let value = at + head;
            if len == UNDEFINED {
                // A sequence (or UN/implicit SQ) of items up to its delimiter.
                at = self.items(value, end, depth + 1)?;
                continue;
            }
            let what = || format!("element ({:04X},{:04X})", tag.0, tag.1);
            let stop = value_end(at, value, len, end, what)?;
            if is_seq {
                self.items(value, stop, depth + 1)?;
            }
            at = stop;
        }
        if undefined {
            return Err(fail(at, "an item of undefined length has no delimiter"));
        }
        Ok(at)
    }

    /// The items of a sequence in `[at, end)`, or up to its delimiter.
    fn items(&self, mut at: usize, end: usize, depth: usize) -> Result<usize, DicomError> {
        while at < end {
            let tag = (self.u16(at)?, self.u16(at + 2)?);
            let len = self.u32(at + 4)?;
            if tag == SEQ_END {
                return Ok(at + 8);
            }
            if tag != ITEM {
                return Err(fail(
                    at,
                    format!(
                        "({:04X},{:04X}) where a sequence item belongs",
                        tag.0, tag.1
                    ),
                ));
            }
            if len == UNDEFINED {
                at = self.dataset(at + 8, end, true, depth)?;
            } else {
                let stop = value_end(at, at + 8, len, end, || "an item".to_string())?;
                self.dataset(at + 8, stop, false, depth)?;
                at = stop;
            }
        }
        Ok(at)
    }
}

/// The end of a value of `len` bytes from `value`, refused (naming `what`,
/// which starts at `at`) if it runs past `end`.
fn value_end(
    at: usize,
    value: usize,
    len: u32,
    end: usize,
    what: impl FnOnce() -> String,
) -> Result<usize, DicomError> {
    value
        .checked_add(len as usize)
        .filter(|&s| s <= end)
        .ok_or_else(|| {
            fail(
                at,
                format!(
                    "{} declares {len} bytes, only {} remain",
                    what(),
                    end.saturating_sub(value)
                ),
            )
        })
}

/// Check every element length of a DICOM Part 10 file against its size.
pub fn check_lengths(bytes: &[u8]) -> Result<(), DicomError> {
    // After "DICM": at 132 with the 128-byte preamble, at 4 without.
    let m = if bytes.get(128..132) == Some(b"DICM") {
        132
    } else if bytes.get(0..4) == Some(b"DICM") {
        4
    } else {
        return Err(DicomError::Encoding(
            "not a DICOM Part 10 file (no DICM prefix at byte 128 or 0)".into(),
        ));
    };
    let meta = Walker {
        b: bytes,
        explicit: true,
    };
    // The meta group: (0002,0000) UL gives its length.
    let group_len = {
        if meta.u16(m)? != 0x0002 || meta.u16(m + 2)? != 0x0000 {
            return Err(fail(
                m,
                "the file meta group does not start with its group length",
            ));
        }
        meta.u32(m + 8)? as usize
    };
    let start = m + 12;
    let meta_end = start
        .checked_add(group_len)
        .filter(|&e| e <= bytes.len())
        .ok_or_else(|| {
            fail(
                m + 8,
                format!("file meta group length {group_len} exceeds the file"),
            )
        })?;
    meta.dataset(start, meta_end, false, 0)?;
    // Transfer syntax (0002,0010).
    let mut ts = String::new();
    let mut at = start;
    while at < meta_end {
        let (tag, len, head, _) = meta.element(at)?;
        let stop = value_end(at, at + head, len, meta_end, || {
            "a file meta element".into()
        })?;
        if tag == (0x0002, 0x0010) {
            ts = String::from_utf8_lossy(&bytes[at + head..stop])
                .trim_end_matches(['\0', ' '])
                .to_string();
        }
        at = stop;
    }
    let explicit = match ts.as_str() {
        "1.2.840.10008.1.2" => false,
        "1.2.840.10008.1.2.1" | "" => true,
        other => {
            return Err(DicomError::Encoding(format!(
            "transfer syntax {other} is not read here (explicit or implicit VR little endian only)"
        )))
        }
    };
    Walker { b: bytes, explicit }.dataset(meta_end, bytes.len(), false, 0)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A minimal explicit-VR file: meta group with its transfer syntax, then
    /// a short string element and a sequence of one item.
    fn file(preamble: bool) -> Vec<u8> {
        let el = |out: &mut Vec<u8>, g: u16, e: u16, vr: &[u8; 2], v: &[u8]| {
            out.extend(g.to_le_bytes());
            out.extend(e.to_le_bytes());
            out.extend(vr);
            if LONG_VRS.contains(&vr) {
                out.extend([0, 0]);
                out.extend((v.len() as u32).to_le_bytes());
            } else {
                out.extend((v.len() as u16).to_le_bytes());
            }
            out.extend(v);
        };
        let mut meta = Vec::new();
        el(&mut meta, 0x0002, 0x0010, b"UI", b"1.2.840.10008.1.2.1\0");
        let mut b = if preamble { vec![0u8; 128] } else { vec![] };
        b.extend(b"DICM");
        el(
            &mut b,
            0x0002,
            0x0000,
            b"UL",
            &(meta.len() as u32).to_le_bytes(),
        );
        b.extend(meta);
        el(&mut b, 0x0010, 0x0020, b"LO", b"P1");
        let mut item = Vec::new();
        el(&mut item, 0x0008, 0x0100, b"SH", b"T-04000");
        let mut seq = Vec::new();
        seq.extend(0xFFFEu16.to_le_bytes());
        seq.extend(0xE000u16.to_le_bytes());
        seq.extend((item.len() as u32).to_le_bytes());
        seq.extend(item);
        el(&mut b, 0x0040, 0xA043, b"SQ", &seq);
        b
    }

    #[test]
    fn well_formed_files_pass() {
        check_lengths(&file(true)).unwrap();
        check_lengths(&file(false)).unwrap();
    }

    #[test]
    fn a_corrupted_length_is_refused_without_allocating_it() {
        let good = file(true);
        // The SQ's 32-bit length (4 bytes after its tag, VR and reserved).
        let sq = good
            .windows(4)
            .rposition(|w| w == [0x40, 0x00, 0x43, 0xA0])
            .unwrap();
        let mut bad = good.clone();
        bad[sq + 8..sq + 12].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
        let e = check_lengths(&bad).unwrap_err().to_string();
        assert!(e.contains("(0040,A043) declares 4294967280 bytes"), "{e}");
        // Truncation and a short-string length beyond the end.
        assert!(check_lengths(&good[..good.len() - 3]).is_err());
        let lo = good
            .windows(4)
            .position(|w| w == [0x10, 0x00, 0x20, 0x00])
            .unwrap();
        let mut bad = good.clone();
        bad[lo + 6..lo + 8].copy_from_slice(&0xFFFFu16.to_le_bytes());
        assert!(check_lengths(&bad).is_err());
        assert!(check_lengths(b"not dicom").is_err());
        // A value representation that is not DICOM's (fuzzing found such
        // files costing dicom-rs seconds of CPU).
        let mut bad = good.clone();
        bad[lo + 4..lo + 6].copy_from_slice(&[0x01, 0x01]);
        let e = check_lengths(&bad).unwrap_err().to_string();
        assert!(
            e.contains("(0010,0020) has the value representation 01 01"),
            "{e}"
        );
    }
}
