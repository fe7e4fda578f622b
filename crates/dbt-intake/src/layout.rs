//! The two layouts an acquisition's counts arrive in, as two types: the
//! slice-wise fan-beam sinograms the reconstruction reads
//! ([`SliceSinograms`]), and a cone-beam detector's frames
//! ([`ConeFrames`]), which the pipeline's rebinning turns into the former
//! (the only bridge between them). Which one an [`Acquisition`] holds is
//! decided here, once ([`Acquisition::into_layout`]); every stage after
//! takes one of the two types (or is generic over both) and never asks.
//!
//! The header of each is an [`AcquisitionHeader`] behind a type that keeps
//! its invariant: a [`SliceHeader`] has no cone-beam system, a
//! [`ConeHeader`] holds its system apart from the header (whose `system` is
//! then empty, so no stage can read the layout from it).

use crate::acquisition::{validate_header, Acquisition, AcquisitionHeader, HeaderError};
use dbt_geometry::ConeSystem;
use thiserror::Error;

/// The header of slice-wise fan-beam sinograms: `counts[slice][view *
/// element]`, coronal slices `slice_spacing_mm` apart on `geometry`.
#[derive(Debug, Clone, PartialEq)]
pub struct SliceHeader(AcquisitionHeader);

/// The header of a cone-beam detector's frames: `counts[detector
/// row][view * column]` of [`ConeHeader::system`].
#[derive(Debug, Clone, PartialEq)]
pub struct ConeHeader {
    header: AcquisitionHeader,
    system: ConeSystem,
}

/// An acquisition's counts under a header that says their layout.
#[derive(Debug, Clone, PartialEq)]
pub struct Projections<H> {
    /// The header ([`SliceHeader`] or [`ConeHeader`]).
    pub header: H,
    /// The counts, one row per slice or detector row.
    pub counts: Vec<Vec<f32>>,
}

/// Coronal fan-beam sinograms, slice by slice: what the reconstruction
/// reads.
pub type SliceSinograms = Projections<SliceHeader>;
/// A cone-beam detector's frames, row by row.
pub type ConeFrames = Projections<ConeHeader>;

/// An acquisition in the layout its header states.
#[derive(Debug, Clone, PartialEq)]
pub enum Layout {
    /// Slice-wise fan-beam sinograms.
    Slices(SliceSinograms),
    /// A cone-beam system's frames.
    Cone(ConeFrames),
}

/// An acquisition of the other layout where one was required.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error("the acquisition holds a cone-beam system's frames ({system}), not slice-wise sinograms: rebin them first")]
pub struct NotSlices {
    /// The system's name.
    pub system: String,
}

impl std::ops::Deref for SliceHeader {
    type Target = AcquisitionHeader;
    fn deref(&self) -> &AcquisitionHeader {
        &self.0
    }
}

impl std::ops::Deref for ConeHeader {
    type Target = AcquisitionHeader;
    fn deref(&self) -> &AcquisitionHeader {
        &self.header
    }
}

impl TryFrom<AcquisitionHeader> for SliceHeader {
    type Error = NotSlices;
    fn try_from(h: AcquisitionHeader) -> Result<Self, NotSlices> {
        match &h.system {
            Some(s) => Err(NotSlices {
                system: s.name.clone(),
            }),
            None => Ok(Self(h)),
        }
    }
}

impl SliceHeader {
    /// [`crate::validate_header`] of this header.
    pub fn validate(&self) -> Result<(), HeaderError> {
        validate_header(&self.0)
    }

    /// The header as written to a file or sent on.
    pub fn into_inner(self) -> AcquisitionHeader {
        self.0
    }
}

impl ConeHeader {
    /// [`crate::validate_header`] of this header with its system (the
    /// system's own validation, its rows' pitch and its frames' size).
    pub fn validate(&self) -> Result<(), HeaderError> {
        validate_header(&self.clone().into_inner())
    }

    /// The header (its `system` empty: the layout is [`Self::system`]) and
    /// the system.
    pub fn new(mut header: AcquisitionHeader, system: ConeSystem) -> Self {
        header.system = None;
        Self { header, system }
    }

    /// The cone-beam system the frames come from.
    pub fn system(&self) -> &ConeSystem {
        &self.system
    }

    /// The header as written to a file or sent on (the system in it).
    pub fn into_inner(self) -> AcquisitionHeader {
        let mut h = self.header;
        h.system = Some(self.system);
        h
    }
}

impl Acquisition {
    /// The acquisition in the layout its header states: the one place that
    /// asks.
    pub fn into_layout(self) -> Layout {
        let Acquisition { mut header, counts } = self;
        match header.system.take() {
            Some(system) => Layout::Cone(Projections {
                header: ConeHeader { header, system },
                counts,
            }),
            None => Layout::Slices(Projections {
                header: SliceHeader(header),
                counts,
            }),
        }
    }

    /// The acquisition's slice-wise sinograms, or which system's frames it
    /// holds instead.
    pub fn into_sinograms(self) -> Result<SliceSinograms, NotSlices> {
        match self.into_layout() {
            Layout::Slices(s) => Ok(s),
            Layout::Cone(c) => Err(NotSlices {
                system: c.header.system.name,
            }),
        }
    }
}

impl From<SliceSinograms> for Acquisition {
    fn from(p: SliceSinograms) -> Self {
        Acquisition {
            header: p.header.into_inner(),
            counts: p.counts,
        }
    }
}

impl From<ConeFrames> for Acquisition {
    fn from(p: ConeFrames) -> Self {
        Acquisition {
            header: p.header.into_inner(),
            counts: p.counts,
        }
    }
}

impl From<Layout> for Acquisition {
    fn from(l: Layout) -> Self {
        match l {
            Layout::Slices(s) => s.into(),
            Layout::Cone(c) => c.into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::acquisition::example_header;

    fn cone() -> ConeSystem {
        ConeSystem::builtin("paper-cone").expect("a built-in system")
    }

    /// The layout is read once and the round trip back to the file's
    /// acquisition is exact, for both layouts; no typed header shows a
    /// system.
    #[test]
    fn into_layout_round_trips_and_hides_the_system() {
        let g = dbt_geometry::Geometry::paper();
        let fan = Acquisition {
            header: example_header(g.clone(), 2, None),
            counts: vec![vec![1.0; 3]; 2],
        };
        let Layout::Slices(s) = fan.clone().into_layout() else {
            panic!("a fan acquisition read as cone-beam frames")
        };
        assert!(s.header.system.is_none());
        assert_eq!(Acquisition::from(s), fan);

        let sys = cone();
        let frames = Acquisition {
            header: example_header(g, 2, Some(sys.clone())),
            counts: vec![vec![1.0; 3]; 2],
        };
        let Layout::Cone(c) = frames.clone().into_layout() else {
            panic!("cone-beam frames read as sinograms")
        };
        let h: &AcquisitionHeader = &c.header;
        assert!(
            h.system.is_none(),
            "the system is the type's, not the header's"
        );
        assert_eq!(c.header.system(), &sys);
        let e = frames.clone().into_sinograms().unwrap_err();
        assert!(e.to_string().contains(&sys.name), "{e}");
        assert_eq!(Acquisition::from(c), frames);
    }

    /// A header that names a system is no slice header.
    #[test]
    fn a_slice_header_has_no_system() {
        assert!(
            SliceHeader::try_from(example_header(dbt_geometry::Geometry::paper(), 1, None))
                .is_ok_and(|h| h.system.is_none())
        );
        assert!(SliceHeader::try_from(example_header(
            dbt_geometry::Geometry::paper(),
            1,
            Some(cone())
        ))
        .is_err());
    }
}
