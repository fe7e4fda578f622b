//! Projection-stream frames.
//!
//! ```text
//! offset  size  field
//! 0       4     start marker "DBTF"
//! 4       1     protocol version (1)
//! 5       1     frame type (1 header, 2 projection, 3 end, 4 ack, 5 nak)
//! 6       4     sequence number, u32 little-endian
//! 10      4     payload length n, u32 little-endian (at most MAX_PAYLOAD)
//! 14      n     payload
//! 14+n    4     CRC-32 (IEEE 802.3) of bytes 4 .. 14+n, little-endian
//! ```

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Start marker.
pub const MARKER: [u8; 4] = *b"DBTF";
/// Protocol version of this implementation.
pub const VERSION: u8 = 1;
/// Largest accepted payload (a 4096 x 4096 projection with its flat field
/// fits): larger lengths are corruption, not data.
pub const MAX_PAYLOAD: usize = 4096 * 4096 * 6 + 64;
const HEAD: usize = 14;

/// Frame decoding errors; each says what was wrong.
#[derive(Debug, Clone, Error, PartialEq)]
pub enum FrameError {
    /// The CRC does not match: the frame must be retransmitted.
    #[error("frame {seq}: CRC mismatch (got {got:08x}, computed {want:08x})")]
    Crc {
        /// Sequence number as read (may itself be corrupt).
        seq: u32,
        /// CRC in the frame.
        got: u32,
        /// CRC computed.
        want: u32,
    },
    /// Unsupported protocol version.
    #[error("frame {seq}: protocol version {version}, this firmware speaks {VERSION}")]
    Version {
        /// Sequence number.
        seq: u32,
        /// Version in the frame.
        version: u8,
    },
    /// Unknown frame type.
    #[error("frame {seq}: unknown frame type {kind}")]
    Type {
        /// Sequence number.
        seq: u32,
        /// Type byte.
        kind: u8,
    },
    /// Declared length beyond the decoder's limit (at most [`MAX_PAYLOAD`]).
    #[error("frame {seq}: payload length {len} exceeds the {max} bytes accepted")]
    Length {
        /// Sequence number.
        seq: u32,
        /// Declared length.
        len: usize,
        /// The decoder's limit.
        max: usize,
    },
    /// The payload does not parse for its type.
    #[error("frame {seq}: bad {kind} payload: {reason}")]
    Payload {
        /// Sequence number.
        seq: u32,
        /// Frame type name.
        kind: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// Bytes that are not a frame were skipped.
    #[error("skipped {0} bytes of garbage before a frame marker")]
    Garbage(usize),
}

/// Acquisition header: study identifiers and technique (JSON payload).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AcquisitionHeader {
    /// Patient ID (1-64 characters).
    pub patient_id: String,
    /// Patient name (`Family^Given`).
    pub patient_name: String,
    /// Study Instance UID.
    pub study_uid: String,
    /// Accession number (at most 16 characters).
    pub accession: String,
    /// Acquisition date `YYYYMMDD`.
    pub study_date: String,
    /// Acquisition time `HHMMSS`.
    pub study_time: String,
    /// Compressed thickness reported by the gantry, mm.
    pub thickness_mm: f64,
    /// Tube voltage, kV.
    pub kvp: f64,
    /// Tube loading of the sweep, mAs.
    pub mas_total: f64,
    /// Number of projections to follow.
    pub projections: u16,
    /// Detector rows and columns of each projection.
    pub rows: u16,
    /// See `rows`.
    pub columns: u16,
    /// `L` or `R`.
    pub laterality: String,
    /// The acquisition system the projections come from (GANTRY_INTERFACE.md
    /// section 2): a cone-beam system's name (`paper-cone`, or the `name` of
    /// the site's system TOML): rows are the detector's rows from the chest
    /// wall. Absent: the slice-wise fan-beam stream, each row one coronal
    /// slice (the simulated gantry of the DBToR paper). The receiver refuses
    /// a stream from another system than the one it is configured for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub system: Option<String>,
    /// The exposure's anode/filter as register 6 names them (`W/Rh`,
    /// `W/Al`, `W/Ag`, `Mo/Mo`, `Mo/Rh`, `Rh/Rh`, `Rh/Ag`); absent: not stated (the Modbus
    /// register then says it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub anode_filter: Option<String>,
}

/// How the gantry interface names the slice-wise fan-beam stream (no
/// `system` in the header), in messages.
pub const FAN_STREAM: &str = "the slice-wise fan-beam stream (no system)";

/// The stream's system in words: its name, or [`FAN_STREAM`].
pub fn system_name(system: Option<&str>) -> String {
    match system {
        Some(s) => format!("cone-beam system `{s}`"),
        None => FAN_STREAM.to_string(),
    }
}

impl AcquisitionHeader {
    /// Validate identifiers and technique.
    pub fn validate(&self) -> Result<(), String> {
        if self.patient_id.trim().is_empty() || self.patient_id.len() > 64 {
            return Err(format!(
                "patient_id `{}` must have 1-64 characters",
                self.patient_id
            ));
        }
        let uid_ok = !self.study_uid.is_empty()
            && self.study_uid.len() <= 64
            && self.study_uid.split('.').all(|c| {
                !c.is_empty()
                    && c.bytes().all(|b| b.is_ascii_digit())
                    && (c == "0" || !c.starts_with('0'))
            });
        if !uid_ok {
            return Err(format!("study_uid `{}` is not a valid UID", self.study_uid));
        }
        let digits = |s: &str, n: usize| s.len() == n && s.bytes().all(|b| b.is_ascii_digit());
        if !digits(&self.study_date, 8) {
            return Err(format!("study_date `{}` must be YYYYMMDD", self.study_date));
        }
        if !digits(&self.study_time, 6) {
            return Err(format!("study_time `{}` must be HHMMSS", self.study_time));
        }
        if self.accession.len() > 16 {
            return Err(format!(
                "accession `{}` is longer than 16 characters",
                self.accession
            ));
        }
        if !(self.thickness_mm.is_finite() && (10.0..=150.0).contains(&self.thickness_mm)) {
            return Err(format!(
                "thickness_mm {} outside 10..150",
                self.thickness_mm
            ));
        }
        if !(self.kvp.is_finite() && (15.0..=50.0).contains(&self.kvp)) {
            return Err(format!("kvp {} outside 15..50", self.kvp));
        }
        if self.projections == 0 || self.rows == 0 || self.columns == 0 {
            return Err("projections, rows and columns must be positive".into());
        }
        if self.laterality != "L" && self.laterality != "R" {
            return Err(format!("laterality `{}` must be L or R", self.laterality));
        }
        if let Some(a) = &self.anode_filter {
            if !crate::registers::ANODES.contains(&a.as_str()) {
                return Err(format!(
                    "anode_filter `{a}` is not one of {}",
                    crate::registers::ANODES.join(", ")
                ));
            }
        }
        if let Some(s) = &self.system {
            if s.is_empty() || s.len() > 64 || s.chars().any(char::is_control) {
                return Err(format!(
                    "system {s:?} must have 1-64 characters, none a control character"
                ));
            }
        }
        Ok(())
    }
}

/// One projection: raw counts and the unattenuated reference (flat field).
#[derive(Debug, Clone, PartialEq)]
pub struct Projection {
    /// View index (0-based).
    pub view: u16,
    /// Source angle, degrees.
    pub angle_deg: f32,
    /// Detector rows.
    pub rows: u16,
    /// Detector columns.
    pub columns: u16,
    /// Raw counts, row-major.
    pub counts: Vec<u16>,
    /// Flat field `b_i`, row-major.
    pub flat: Vec<f32>,
}

/// A frame.
#[derive(Debug, Clone, PartialEq)]
pub enum Frame {
    /// Type 1.
    Header(AcquisitionHeader),
    /// Type 2.
    Projection(Projection),
    /// Type 3: the number of projections sent.
    End {
        /// Projections sent.
        projections: u16,
    },
    /// Type 4: frame received intact.
    Ack {
        /// Acknowledged sequence number.
        seq: u32,
    },
    /// Type 5: please retransmit.
    Nak {
        /// Sequence number to retransmit.
        seq: u32,
    },
}

impl Frame {
    fn kind(&self) -> u8 {
        match self {
            Frame::Header(_) => 1,
            Frame::Projection(_) => 2,
            Frame::End { .. } => 3,
            Frame::Ack { .. } => 4,
            Frame::Nak { .. } => 5,
        }
    }

    fn payload(&self) -> Vec<u8> {
        match self {
            Frame::Header(h) => serde_json::to_vec(h).unwrap_or_default(),
            Frame::Projection(p) => {
                let mut v = Vec::with_capacity(10 + p.counts.len() * 6);
                v.extend(p.view.to_le_bytes());
                v.extend(p.angle_deg.to_le_bytes());
                v.extend(p.rows.to_le_bytes());
                v.extend(p.columns.to_le_bytes());
                for c in &p.counts {
                    v.extend(c.to_le_bytes());
                }
                for f in &p.flat {
                    v.extend(f.to_le_bytes());
                }
                v
            }
            Frame::End { projections } => projections.to_le_bytes().to_vec(),
            Frame::Ack { seq } | Frame::Nak { seq } => seq.to_le_bytes().to_vec(),
        }
    }
}

/// Encode a frame with sequence number `seq`.
pub fn encode(frame: &Frame, seq: u32) -> Vec<u8> {
    let payload = frame.payload();
    let mut out = Vec::with_capacity(HEAD + payload.len() + 4);
    out.extend(MARKER);
    out.push(VERSION);
    out.push(frame.kind());
    out.extend(seq.to_le_bytes());
    out.extend((payload.len() as u32).to_le_bytes());
    out.extend(&payload);
    let crc = crc32fast::hash(&out[4..]);
    out.extend(crc.to_le_bytes());
    out
}

fn u16_at(b: &[u8], i: usize) -> u16 {
    u16::from_le_bytes([b[i], b[i + 1]])
}

fn decode_payload(kind: u8, seq: u32, p: &[u8]) -> Result<Frame, FrameError> {
    let bad = |kind: &'static str, reason: String| FrameError::Payload { seq, kind, reason };
    match kind {
        1 => {
            let h: AcquisitionHeader =
                serde_json::from_slice(p).map_err(|e| bad("header", e.to_string()))?;
            h.validate().map_err(|r| bad("header", r))?;
            Ok(Frame::Header(h))
        }
        2 => {
            if p.len() < 10 {
                return Err(bad(
                    "projection",
                    format!("{} bytes, at least 10 needed", p.len()),
                ));
            }
            let view = u16_at(p, 0);
            let angle_deg = f32::from_le_bytes([p[2], p[3], p[4], p[5]]);
            let (rows, columns) = (u16_at(p, 6), u16_at(p, 8));
            let n = rows as usize * columns as usize;
            if p.len() != 10 + 6 * n {
                return Err(bad(
                    "projection",
                    format!(
                        "{} bytes for {rows} x {columns} pixels, expected {}",
                        p.len(),
                        10 + 6 * n
                    ),
                ));
            }
            if !angle_deg.is_finite() {
                return Err(bad("projection", "angle is not finite".into()));
            }
            let counts = (0..n).map(|i| u16_at(p, 10 + 2 * i)).collect();
            let flat: Vec<f32> = (0..n)
                .map(|i| {
                    let o = 10 + 2 * n + 4 * i;
                    f32::from_le_bytes([p[o], p[o + 1], p[o + 2], p[o + 3]])
                })
                .collect();
            if let Some(i) = flat.iter().position(|f| !f.is_finite() || *f <= 0.0) {
                return Err(bad(
                    "projection",
                    format!("flat field {} at pixel {i}", flat[i]),
                ));
            }
            Ok(Frame::Projection(Projection {
                view,
                angle_deg,
                rows,
                columns,
                counts,
                flat,
            }))
        }
        3..=5 => {
            let want = if kind == 3 { 2 } else { 4 };
            if p.len() != want {
                return Err(bad(
                    "control",
                    format!("{} bytes, expected {want}", p.len()),
                ));
            }
            Ok(match kind {
                3 => Frame::End {
                    projections: u16_at(p, 0),
                },
                4 => Frame::Ack {
                    seq: u32::from_le_bytes([p[0], p[1], p[2], p[3]]),
                },
                _ => Frame::Nak {
                    seq: u32::from_le_bytes([p[0], p[1], p[2], p[3]]),
                },
            })
        }
        k => Err(FrameError::Type { seq, kind: k }),
    }
}

/// A streaming decoder: feed it bytes as they arrive, take frames (or errors)
/// out. After a bad frame it resynchronises on the next start marker.
///
/// Linear in the bytes received, whatever they are: consumed bytes are
/// skipped by an offset (the buffer is compacted once half of it is
/// consumed), the marker search resumes where it stopped, and a candidate
/// frame's CRC comes from prefix CRCs in O(log n) ([`crate::crc`]). Payloads
/// longer than the decoder's limit ([`Decoder::with_max_payload`]; by
/// default [`MAX_PAYLOAD`]) are refused from their header, never buffered.
#[derive(Debug)]
pub struct Decoder {
    buf: Vec<u8>,
    /// `prefix[i]`: CRC-32 of every byte received before `buf[i]` (one more
    /// entry than `buf`).
    prefix: Vec<u32>,
    /// Consumed bytes at the front of `buf`.
    pos: usize,
    /// Bytes from `pos` known to hold no marker start.
    scanned: usize,
    max_payload: usize,
    work: u64,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::with_max_payload(MAX_PAYLOAD)
    }
}

impl Decoder {
    /// A new decoder accepting payloads up to [`MAX_PAYLOAD`].
    pub fn new() -> Self {
        Self::default()
    }

    /// A new decoder accepting payloads up to `max_payload` bytes (the
    /// receiver's memory budget; at most [`MAX_PAYLOAD`]).
    pub fn with_max_payload(max_payload: usize) -> Self {
        Self {
            buf: Vec::new(),
            prefix: vec![0],
            pos: 0,
            scanned: 0,
            max_payload: max_payload.min(MAX_PAYLOAD),
            work: 0,
        }
    }

    /// Byte-steps spent so far (bytes hashed on arrival, bytes searched for
    /// a marker, 64 per CRC check): the measure by which the tests hold the
    /// decoder to linear time, whatever the input.
    pub fn work(&self) -> u64 {
        self.work
    }

    /// The largest payload this decoder accepts.
    pub fn max_payload(&self) -> usize {
        self.max_payload
    }

    /// Append received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        if self.pos > 0 && self.pos * 2 >= self.buf.len() {
            self.buf.drain(..self.pos);
            self.prefix.drain(..self.pos);
            self.pos = 0;
        }
        self.work += bytes.len() as u64;
        let c = *self.prefix.last().unwrap_or(&0);
        crate::crc::prefixes(c, bytes, &mut self.prefix);
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes waiting for the rest of a frame.
    pub fn pending(&self) -> usize {
        self.buf.len() - self.pos
    }

    /// The declared payload length of the frame being received, once its
    /// marker and header are in (and within the limit); `None` between
    /// frames.
    pub fn frame_in_progress(&self) -> Option<usize> {
        let b = &self.buf[self.pos..];
        if b.len() < HEAD || b[..4] != MARKER {
            return None;
        }
        let len = u32::from_le_bytes([b[10], b[11], b[12], b[13]]) as usize;
        (len <= self.max_payload).then_some(len)
    }

    fn consume(&mut self, n: usize) {
        self.pos += n;
        self.scanned = self.scanned.saturating_sub(n);
    }

    /// The next complete frame as `(sequence, frame)`, an error about the
    /// bytes skipped or rejected, or `None` until more bytes arrive.
    pub fn next_frame(&mut self) -> Option<Result<(u32, Frame), FrameError>> {
        // Find the marker, resuming the search where it stopped.
        let avail = &self.buf[self.pos..];
        let from = self.scanned.min(avail.len());
        let start = avail[from..]
            .windows(4)
            .position(|w| w == MARKER)
            .map(|i| i + from);
        // `start`, when found, is at or after `from`.
        self.work += (start.unwrap_or(avail.len()) - from + 1) as u64;
        match start {
            None => {
                // Keep the last 3 bytes: they may begin a marker.
                let keep = avail.len().min(3);
                let drop = avail.len() - keep;
                self.scanned = avail.len().saturating_sub(3).max(self.scanned);
                if drop > 0 {
                    self.consume(drop);
                    return Some(Err(FrameError::Garbage(drop)));
                }
                return None;
            }
            Some(s) if s > 0 => {
                self.scanned = s;
                self.consume(s);
                return Some(Err(FrameError::Garbage(s)));
            }
            _ => self.scanned = 0,
        }
        let b = &self.buf[self.pos..];
        if b.len() < HEAD {
            return None;
        }
        let version = b[4];
        let kind = b[5];
        let seq = u32::from_le_bytes([b[6], b[7], b[8], b[9]]);
        let len = u32::from_le_bytes([b[10], b[11], b[12], b[13]]) as usize;
        if len > self.max_payload {
            // Corrupt length, or more than the budget: skip this marker and
            // resynchronise.
            self.consume(4);
            return Some(Err(FrameError::Length {
                seq,
                len,
                max: self.max_payload,
            }));
        }
        if b.len() < HEAD + len + 4 {
            return None;
        }
        let end = HEAD + len;
        let got = u32::from_le_bytes([b[end], b[end + 1], b[end + 2], b[end + 3]]);
        let (a, z) = (self.pos + 4, self.pos + end);
        let want = crate::crc::range(self.prefix[a], self.prefix[z], (z - a) as u64);
        self.work += 64;
        if got != want {
            // Do not trust the length: resynchronise after this marker.
            self.consume(4);
            return Some(Err(FrameError::Crc { seq, got, want }));
        }
        let payload = &self.buf[self.pos + HEAD..self.pos + end];
        let r = if version != VERSION {
            Err(FrameError::Version { seq, version })
        } else {
            decode_payload(kind, seq, payload).map(|f| (seq, f))
        };
        self.consume(end + 4);
        Some(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(super) fn header() -> AcquisitionHeader {
        AcquisitionHeader {
            patient_id: "P1".into(),
            patient_name: "Doe^Jane".into(),
            study_uid: "1.2.826.0.1.3680043.10.543.5".into(),
            accession: "A1".into(),
            study_date: "20261122".into(),
            study_time: "101500".into(),
            thickness_mm: 45.0,
            kvp: 28.0,
            mas_total: 60.0,
            projections: 25,
            rows: 3,
            columns: 4,
            laterality: "L".into(),
            system: None,
            anode_filter: None,
        }
    }

    fn projection(view: u16) -> Projection {
        Projection {
            view,
            angle_deg: -24.0 + 2.0 * view as f32,
            rows: 3,
            columns: 4,
            counts: (0..12).map(|i| 1000 + i).collect(),
            flat: vec![16000.0; 12],
        }
    }

    fn all(d: &mut Decoder) -> Vec<Result<(u32, Frame), FrameError>> {
        std::iter::from_fn(|| d.next_frame()).collect()
    }

    #[test]
    fn round_trip_byte_by_byte() {
        let frames = vec![
            Frame::Header(header()),
            Frame::Projection(projection(0)),
            Frame::Projection(projection(1)),
            Frame::End { projections: 2 },
            Frame::Ack { seq: 3 },
            Frame::Nak { seq: 9 },
        ];
        let bytes: Vec<u8> = frames
            .iter()
            .enumerate()
            .flat_map(|(i, f)| encode(f, i as u32))
            .collect();
        let mut d = Decoder::new();
        let mut got = Vec::new();
        for b in bytes {
            d.push(&[b]);
            while let Some(r) = d.next_frame() {
                got.push(r.unwrap());
            }
        }
        let want: Vec<(u32, Frame)> = frames
            .into_iter()
            .enumerate()
            .map(|(i, f)| (i as u32, f))
            .collect();
        assert_eq!(got, want);
        assert_eq!(d.pending(), 0);
    }

    /// The system travels in the header; a header without one (a version-1
    /// gantry of the slice-wise stream) still reads, and one is named.
    #[test]
    fn the_header_carries_the_system() {
        let mut h = header();
        let plain = encode(&Frame::Header(h.clone()), 0);
        assert!(!String::from_utf8_lossy(&plain).contains("system"));
        h.system = Some("paper-cone".into());
        let mut d = Decoder::new();
        d.push(&encode(&Frame::Header(h.clone()), 0));
        assert_eq!(
            d.next_frame().unwrap().unwrap(),
            (0, Frame::Header(h.clone()))
        );
        assert_eq!(h.validate(), Ok(()));
        for bad in ["", "a\nb", &"x".repeat(65)] {
            h.system = Some(bad.into());
            let e = h.validate().unwrap_err();
            assert!(e.contains("system"), "{e}");
        }
        assert_eq!(
            system_name(Some("paper-cone")),
            "cone-beam system `paper-cone`"
        );
        assert_eq!(system_name(None), FAN_STREAM);
        // The anode/filter, when stated, is one of register 6's.
        let mut h = header();
        h.anode_filter = Some("W/Al".into());
        assert_eq!(h.validate(), Ok(()));
        h.anode_filter = Some("W/Xx".into());
        let e = h.validate().unwrap_err();
        assert!(
            e.contains("anode_filter `W/Xx`") && e.contains("W/Rh"),
            "{e}"
        );
    }

    #[test]
    fn corruption_is_detected_and_the_stream_resynchronises() {
        let mut bytes = encode(&Frame::Projection(projection(0)), 7);
        bytes[30] ^= 0x40; // flip a payload bit
        let good = encode(&Frame::Projection(projection(1)), 8);
        let mut stream = b"noise".to_vec();
        stream.extend(&bytes);
        stream.extend(&good);
        let mut d = Decoder::new();
        d.push(&stream);
        let out = all(&mut d);
        assert!(matches!(out[0], Err(FrameError::Garbage(5))));
        assert!(matches!(out[1], Err(FrameError::Crc { seq: 7, .. })));
        // Whatever the resync skipped, the good frame comes out intact.
        let last = out.iter().rev().find_map(|r| r.as_ref().ok()).unwrap();
        assert_eq!(last, &(8, Frame::Projection(projection(1))));
    }

    #[test]
    fn bad_payloads_and_lengths_are_named() {
        let mut h = header();
        h.study_uid = "1.02.3".into();
        let mut d = Decoder::new();
        d.push(&encode(&Frame::Header(h), 1));
        let e = d.next_frame().unwrap().unwrap_err().to_string();
        assert!(e.contains("study_uid"), "{e}");
        // A declared length beyond the limit is rejected without buffering it.
        let mut f = encode(&Frame::End { projections: 1 }, 2);
        f[10..14].copy_from_slice(&(u32::MAX).to_le_bytes());
        d.push(&f);
        assert!(matches!(
            d.next_frame(),
            Some(Err(FrameError::Length { .. }))
        ));
        // A projection with the wrong size.
        let mut p = projection(0);
        p.counts.pop();
        let mut d = Decoder::new();
        d.push(&encode(&Frame::Projection(p), 3));
        let e = d.next_frame().unwrap().unwrap_err().to_string();
        assert!(e.contains("projection"), "{e}");
        // Zero flat field.
        let mut p = projection(0);
        p.flat[5] = 0.0;
        d.push(&encode(&Frame::Projection(p), 4));
        assert!(d
            .next_frame()
            .unwrap()
            .unwrap_err()
            .to_string()
            .contains("flat field"));
    }

    #[test]
    fn random_garbage_never_panics() {
        // A deterministic fuzz-like sweep: random bytes, random truncations
        // and bit flips of valid frames (cargo fuzz needs a nightly toolchain,
        // which this project's machines do not have).
        let mut s = 0x1234_5678_9abc_def0u64;
        let mut r = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let valid = encode(&Frame::Projection(projection(2)), 5);
        for _ in 0..3000 {
            let mut d = Decoder::new();
            let mut bytes = if r() % 2 == 0 {
                (0..(r() % 200)).map(|_| r() as u8).collect::<Vec<_>>()
            } else {
                let mut v = valid.clone();
                let flips = r() % 4;
                for _ in 0..flips {
                    let i = (r() as usize) % v.len();
                    v[i] ^= 1 << (r() % 8);
                }
                v.truncate((r() as usize) % (v.len() + 1));
                v
            };
            if r() % 3 == 0 {
                bytes.splice(0..0, MARKER);
            }
            d.push(&bytes);
            for _ in 0..1000 {
                if d.next_frame().is_none() {
                    break;
                }
            }
        }
    }
}

#[cfg(test)]
mod linear {
    use super::*;

    /// Crafted input that made the old decoder quadratic: 2 MB of start
    /// markers, each with a header announcing the largest payload (every one
    /// a false start whose "frame" is hashed, then skipped by 4 bytes), and a
    /// real frame at the end. The decoder must spend a bounded number of
    /// byte-steps per byte received, and still find the real frame.
    #[test]
    fn resynchronisation_is_linear_in_the_bytes_received() {
        let max = 64 * 1024;
        let mut fake = Vec::new();
        fake.extend(MARKER);
        fake.push(VERSION);
        fake.push(2);
        fake.extend(7u32.to_le_bytes());
        fake.extend((max as u32).to_le_bytes());
        let mut stream = Vec::new();
        while stream.len() < 2 << 20 {
            stream.extend(&fake);
        }
        let good = encode(&Frame::End { projections: 25 }, 26);
        stream.extend(&good);
        // Pad so the last false frames can complete and fail their CRC.
        stream.extend(vec![0u8; max + 64]);
        let mut d = Decoder::with_max_payload(max);
        let mut found = None;
        let (mut crc, mut steps) = (0usize, 0usize);
        for chunk in stream.chunks(4096) {
            d.push(chunk);
            while let Some(r) = d.next_frame() {
                steps += 1;
                match r {
                    Ok(f) => found = Some(f),
                    Err(FrameError::Crc { .. }) => crc += 1,
                    Err(_) => {}
                }
            }
        }
        assert_eq!(found, Some((26, Frame::End { projections: 25 })));
        assert!(crc > 100_000, "{crc} false starts checked");
        let per_byte = d.work() as f64 / stream.len() as f64;
        assert!(
            per_byte < 16.0,
            "{per_byte:.1} byte-steps per byte ({steps} results)"
        );
        assert!(d.pending() < max + 64 + 4);
    }

    #[test]
    fn payloads_beyond_the_budget_are_refused_from_their_header() {
        let mut d = Decoder::with_max_payload(100);
        let big = encode(&Frame::Header(super::tests::header()), 0);
        d.push(&big[..HEAD]);
        match d.next_frame() {
            Some(Err(FrameError::Length { len, max: 100, .. })) => assert!(len > 100),
            other => panic!("{other:?}"),
        }
    }
}
