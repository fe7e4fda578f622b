//! Receiving one acquisition from the frame stream: the header first, one
//! projection per view (in any order, duplicates dropped), then the end
//! frame. The sender numbers frames `0` (header), `1 + view` (projections),
//! `1 + projections` (end), so a missing view is requested by a nak of its
//! sequence number.

use crate::frame::{AcquisitionHeader, Frame, Projection};
use thiserror::Error;

/// What the receiver must do after a frame.
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    /// Acknowledge this sequence number.
    Ack(u32),
    /// Ask for these sequence numbers again.
    Nak(Vec<u32>),
}

/// Faults that end an acquisition (reported, never silently accepted).
#[derive(Debug, Clone, Error, PartialEq)]
pub enum AssemblyError {
    /// Too many frames before any header.
    #[error("frame {0}: too many frames without an acquisition header")]
    NoHeader(u32),
    /// A second, different header in the same acquisition.
    #[error("a second acquisition header (frame {0}) in the same acquisition")]
    SecondHeader(u32),
    /// A projection that does not fit the header.
    #[error("projection {view}: {reason}")]
    BadProjection {
        /// View index.
        view: u16,
        /// What is wrong.
        reason: String,
    },
    /// The same view arrived twice with different content.
    #[error("view {0} arrived twice with different content")]
    Conflict(u16),
    /// The header announces more than the receiver is configured for.
    #[error("the header announces {announced} {what}, the receiver is configured for {allowed} (its memory budget comes from the configured geometry, not from the sender)")]
    Budget {
        /// `projections`, `columns` or `rows`.
        what: &'static str,
        /// What the header says.
        announced: u16,
        /// What the configuration allows.
        allowed: u16,
    },
    /// The end frame disagrees with the header.
    #[error("end frame says {sent} projections, the header {expected}")]
    Count {
        /// Projections the sender says it sent.
        sent: u16,
        /// Projections the header announced.
        expected: u16,
    },
}

/// A complete acquisition.
#[derive(Debug, Clone, PartialEq)]
pub struct Received {
    /// The header.
    pub header: AcquisitionHeader,
    /// Projections by view index.
    pub projections: Vec<Projection>,
    /// Pixels at the 16-bit ceiling (65535), over all projections.
    pub saturated: usize,
}

/// The assembler's state. Projections and the end frame that arrive before
/// the header (whose first transmission may have been corrupt) wait for it,
/// up to [`MAX_EARLY`] frames.
#[derive(Debug, Default)]
pub struct Assembler {
    header: Option<AcquisitionHeader>,
    views: Vec<Option<Projection>>,
    end_seen: bool,
    early: Vec<(u32, Frame)>,
    budget: Option<Budget>,
}

/// What a receiver is configured for (from its geometry, never from what
/// the sender announces): a header announcing more is refused before any
/// projection is kept, and projections that arrive before the header are
/// kept only within it, so one acquisition holds at most
/// [`Budget::bytes`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Budget {
    /// Projections (views) of the configured geometry.
    pub projections: u16,
    /// Detector columns (elements) of the configured geometry.
    pub columns: u16,
    /// The most detector rows (coronal slices) a projection may have.
    pub max_rows: u16,
}

impl Budget {
    /// The largest projection payload, bytes (`10 + 6 rows columns`).
    pub fn projection_payload(&self) -> usize {
        10 + 6 * self.max_rows as usize * self.columns as usize
    }

    /// The most projection bytes one acquisition may hold.
    pub fn bytes(&self) -> usize {
        self.projections as usize * self.projection_payload()
    }

    fn check(
        &self,
        what: &'static str,
        announced: u16,
        allowed: u16,
        exact: bool,
    ) -> Result<(), AssemblyError> {
        if (exact && announced != allowed) || announced > allowed || announced == 0 {
            return Err(AssemblyError::Budget {
                what,
                announced,
                allowed,
            });
        }
        Ok(())
    }

    /// A header within the budget: the configured projections and columns,
    /// at most `max_rows` rows.
    pub fn check_header(&self, h: &AcquisitionHeader) -> Result<(), AssemblyError> {
        self.check("projections", h.projections, self.projections, true)?;
        self.check("columns", h.columns, self.columns, true)?;
        self.check("rows", h.rows, self.max_rows, false)
    }
}

/// Frames kept while the header is missing; beyond that the acquisition is a
/// fault (a gantry that never sends a header must not fill the memory).
pub const MAX_EARLY: usize = 4096;

impl Assembler {
    /// A new, empty assembler without a budget (any header the codec
    /// accepts; for tools and tests).
    pub fn new() -> Self {
        Self::default()
    }

    /// A new assembler that refuses what exceeds `budget`.
    pub fn with_budget(budget: Budget) -> Self {
        Self {
            budget: Some(budget),
            ..Self::default()
        }
    }

    /// Whether the header has arrived.
    pub fn has_header(&self) -> bool {
        self.header.is_some()
    }

    /// The header, once it has arrived.
    pub fn header(&self) -> Option<&AcquisitionHeader> {
        self.header.as_ref()
    }

    /// How far the acquisition has come: the header, each view in, the end
    /// frame (retransmissions, duplicates and control frames do not count).
    pub fn progress(&self) -> usize {
        self.header.is_some() as usize
            + self.views.iter().filter(|v| v.is_some()).count()
            + self.end_seen as usize
            + self.early.len()
    }

    /// Views still missing (after the header).
    pub fn missing(&self) -> Vec<u16> {
        self.views
            .iter()
            .enumerate()
            .filter(|(_, p)| p.is_none())
            .map(|(i, _)| i as u16)
            .collect()
    }

    /// Take one intact frame. Returns the reply and, once every view is in and
    /// the end frame was seen, the acquisition.
    pub fn accept(
        &mut self,
        seq: u32,
        frame: Frame,
    ) -> Result<(Reply, Option<Received>), AssemblyError> {
        match frame {
            Frame::Header(h) => {
                match &self.header {
                    None => {
                        if let Some(b) = &self.budget {
                            b.check_header(&h)?;
                        }
                        self.views = vec![None; h.projections as usize];
                        self.header = Some(h);
                        // Replay what arrived early, acknowledging nothing
                        // twice (those frames were acknowledged on arrival).
                        let mut done = None;
                        let mut naks = Vec::new();
                        for (s, f) in std::mem::take(&mut self.early) {
                            let (r, d) = self.accept(s, f)?;
                            if let Reply::Nak(v) = r {
                                naks = v;
                            }
                            done = done.or(d);
                        }
                        if !naks.is_empty() && done.is_none() {
                            // The end frame came early and views are missing:
                            // ask for them now.
                            return Ok((Reply::Nak(naks), None));
                        }
                        return Ok((Reply::Ack(seq), done));
                    }
                    Some(old) if *old == h => {} // retransmitted
                    Some(_) => return Err(AssemblyError::SecondHeader(seq)),
                }
                Ok((Reply::Ack(seq), None))
            }
            Frame::Projection(p) => {
                let Some(h) = self.header.as_ref() else {
                    return self.hold(seq, Frame::Projection(p));
                };
                let bad = |reason: String| AssemblyError::BadProjection {
                    view: p.view,
                    reason,
                };
                if p.view >= h.projections {
                    return Err(bad(format!(
                        "view index beyond the {} announced",
                        h.projections
                    )));
                }
                if p.rows != h.rows || p.columns != h.columns {
                    return Err(bad(format!(
                        "{} x {} pixels, the header announced {} x {}",
                        p.rows, p.columns, h.rows, h.columns
                    )));
                }
                let slot = &mut self.views[p.view as usize];
                match slot {
                    Some(old) if *old != p => return Err(AssemblyError::Conflict(p.view)),
                    Some(_) => {}
                    None => *slot = Some(p),
                }
                Ok((Reply::Ack(seq), self.complete()))
            }
            Frame::End { projections } => {
                let Some(h) = self.header.as_ref() else {
                    // Ask for the header (sequence 0) again.
                    self.hold(seq, Frame::End { projections })?;
                    return Ok((Reply::Nak(vec![0]), None));
                };
                if projections != h.projections {
                    return Err(AssemblyError::Count {
                        sent: projections,
                        expected: h.projections,
                    });
                }
                self.end_seen = true;
                let missing = self.missing();
                if missing.is_empty() {
                    Ok((Reply::Ack(seq), self.complete()))
                } else {
                    Ok((
                        Reply::Nak(missing.iter().map(|&v| 1 + v as u32).collect()),
                        None,
                    ))
                }
            }
            Frame::Ack { .. } | Frame::Nak { .. } => Ok((Reply::Ack(seq), None)),
        }
    }

    fn hold(&mut self, seq: u32, f: Frame) -> Result<(Reply, Option<Received>), AssemblyError> {
        let limit = self
            .budget
            .map_or(MAX_EARLY, |b| (b.projections as usize + 1).min(MAX_EARLY));
        if self.early.len() >= limit {
            return Err(AssemblyError::NoHeader(seq));
        }
        if let (Some(b), Frame::Projection(p)) = (&self.budget, &f) {
            b.check("columns", p.columns, b.columns, true)?;
            b.check("rows", p.rows, b.max_rows, false)?;
        }
        self.early.push((seq, f));
        Ok((Reply::Ack(seq), None))
    }

    fn complete(&self) -> Option<Received> {
        if !self.end_seen || self.views.iter().any(|v| v.is_none()) {
            return None;
        }
        let projections: Vec<Projection> = self.views.iter().flatten().cloned().collect();
        let saturated = projections
            .iter()
            .map(|p| p.counts.iter().filter(|&&c| c == u16::MAX).count())
            .sum();
        Some(Received {
            header: self.header.clone()?,
            projections,
            saturated,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(n: u16) -> AcquisitionHeader {
        AcquisitionHeader {
            patient_id: "P".into(),
            patient_name: "X^Y".into(),
            study_uid: "1.2.3".into(),
            accession: "A".into(),
            study_date: "20261122".into(),
            study_time: "101500".into(),
            thickness_mm: 40.0,
            kvp: 28.0,
            mas_total: 50.0,
            projections: n,
            rows: 2,
            columns: 2,
            laterality: "R".into(),
            system: None,
            anode_filter: None,
        }
    }

    fn proj(v: u16) -> Projection {
        Projection {
            view: v,
            angle_deg: v as f32,
            rows: 2,
            columns: 2,
            counts: vec![v, 1, 2, u16::MAX],
            flat: vec![100.0; 4],
        }
    }

    #[test]
    fn out_of_order_duplicates_and_missing_views() {
        let mut a = Assembler::new();
        assert_eq!(
            a.accept(0, Frame::Header(header(3))).unwrap().0,
            Reply::Ack(0)
        );
        a.accept(3, Frame::Projection(proj(2))).unwrap();
        a.accept(1, Frame::Projection(proj(0))).unwrap();
        a.accept(1, Frame::Projection(proj(0))).unwrap(); // duplicate
                                                          // End with view 1 missing: nak its sequence number.
        let (r, done) = a.accept(4, Frame::End { projections: 3 }).unwrap();
        assert_eq!(r, Reply::Nak(vec![2]));
        assert!(done.is_none());
        let (_, done) = a.accept(2, Frame::Projection(proj(1))).unwrap();
        let got = done.unwrap();
        assert_eq!(
            got.projections.iter().map(|p| p.view).collect::<Vec<_>>(),
            vec![0, 1, 2]
        );
        assert_eq!(got.saturated, 3);
    }

    #[test]
    fn frames_before_a_late_header_wait_for_it() {
        let mut a = Assembler::new();
        a.accept(1, Frame::Projection(proj(0))).unwrap();
        // End before the header: ask for the header.
        let (r, _) = a.accept(3, Frame::End { projections: 2 }).unwrap();
        assert_eq!(r, Reply::Nak(vec![0]));
        // The header arrives; view 1 is still missing: ask for it.
        let (r, d) = a.accept(0, Frame::Header(header(2))).unwrap();
        assert_eq!(r, Reply::Nak(vec![2]));
        assert!(d.is_none());
        let (_, d) = a.accept(2, Frame::Projection(proj(1))).unwrap();
        assert_eq!(d.unwrap().projections.len(), 2);
        // A gantry that never sends a header is a fault, not a memory leak.
        let mut a = Assembler::new();
        for i in 0..MAX_EARLY as u32 {
            a.accept(i + 1, Frame::End { projections: 1 }).unwrap();
        }
        assert!(matches!(
            a.accept(1, Frame::End { projections: 1 }),
            Err(AssemblyError::NoHeader(_))
        ));
    }

    #[test]
    fn faults_are_reported() {
        let mut a = Assembler::new();
        a.accept(0, Frame::Header(header(2))).unwrap();
        let mut h = header(2);
        h.thickness_mm = 55.0;
        assert_eq!(
            a.accept(5, Frame::Header(h)).unwrap_err(),
            AssemblyError::SecondHeader(5)
        );
        a.accept(1, Frame::Projection(proj(0))).unwrap();
        let mut p = proj(0);
        p.counts[0] = 9;
        assert_eq!(
            a.accept(1, Frame::Projection(p)).unwrap_err(),
            AssemblyError::Conflict(0)
        );
        let mut p = proj(1);
        p.rows = 3;
        assert!(a
            .accept(2, Frame::Projection(p))
            .unwrap_err()
            .to_string()
            .contains("3 x 2"));
        assert!(matches!(
            a.accept(9, Frame::End { projections: 5 }),
            Err(AssemblyError::Count { .. })
        ));
    }
}
