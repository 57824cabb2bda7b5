//! Diamond identifiers.

use std::fmt;
use std::str::FromStr;

use crate::CodecError;

/// A diamond: its level, the face of the domain its centre lies on, and the lattice coordinates
/// of its centre on that face.
///
/// A plane is one face (face 0). A domain of several faces (the cube-sphere) owns each diamond
/// whose centre lies on an edge shared by two faces from one canonical face; which one is the
/// domain's business ([`crate::geometry::Domain`]), the id only records it.
///
/// Ordering is by level first, so sorting a set of ids gives a coarse-to-fine order; within a
/// level, by face, then by centre.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct DiamondId {
    /// Level: 0 for roots, `2K` for the finest (the input grid).
    pub level: u8,
    /// Face of the domain (0 on a plane).
    pub face: u8,
    /// Centre, lattice column of the face (west to east on a plane).
    pub x: u32,
    /// Centre, lattice row of the face (north to south on a plane, like the input rows).
    pub y: u32,
}

/// Hashes level and face as one word, so that ids of face 0 hash exactly as ids did before faces
/// existed (hash maps keyed by ids iterate in the same order; [`super::IdHasher`] takes every
/// integer width as one word).
impl std::hash::Hash for DiamondId {
    #[inline]
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        state.write_u32(u32::from(self.level) | u32::from(self.face) << 8);
        state.write_u32(self.x);
        state.write_u32(self.y);
    }
}

impl DiamondId {
    /// A diamond of face 0 (a plane's only face); whether it exists depends on the
    /// [`crate::geometry::Domain`].
    #[inline]
    pub const fn new(level: u8, x: u32, y: u32) -> Self {
        Self {
            level,
            face: 0,
            x,
            y,
        }
    }

    /// A diamond of face `face`.
    #[inline]
    pub const fn on_face(face: u8, level: u8, x: u32, y: u32) -> Self {
        Self { level, face, x, y }
    }

    /// The same diamond on a lattice `2^shift` times finer (level pairs added below the finest,
    /// as the client's synthetic detail does): the centre scaled up, level and face kept.
    pub const fn finer(self, shift: u32) -> Self {
        Self::on_face(self.face, self.level, self.x << shift, self.y << shift)
    }

    /// The inverse of [`DiamondId::finer`]: the centre scaled down by `2^shift` (low bits
    /// dropped; callers check they are zero where that matters).
    pub const fn coarser(self, shift: u32) -> Self {
        Self::on_face(self.face, self.level, self.x >> shift, self.y >> shift)
    }

    /// Whether the level is even (axis-aligned square) or odd (rotated 45°).
    pub const fn is_even(&self) -> bool {
        self.level.is_multiple_of(2)
    }
}

/// Text form used in URLs and logs: `level-x-y` on face 0, e.g. `3-512-256`, and the
/// face-qualified `fF-level-x-y` on other faces, e.g. `f4-3-512-256` (`docs/FORMAT.md`,
/// "Diamond ids"). Face 0 may also be written `f0-level-x-y`; it prints in the short form.
impl fmt::Display for DiamondId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.face != 0 {
            write!(f, "f{}-", self.face)?;
        }
        write!(f, "{}-{}-{}", self.level, self.x, self.y)
    }
}

impl FromStr for DiamondId {
    type Err = CodecError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = || {
            CodecError::invalid(format!(
                "malformed diamond id {s:?} (want level-x-y or fFACE-level-x-y)"
            ))
        };
        // `parse` accepts a leading '+'; ids have one canonical spelling, so insist on digits.
        let digits = |t: &str| !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit());
        let (face, rest) = match s.strip_prefix('f') {
            Some(qualified) => {
                let (f, rest) = qualified.split_once('-').ok_or_else(bad)?;
                if !digits(f) {
                    return Err(bad());
                }
                (f.parse::<u8>().map_err(|_| bad())?, rest)
            }
            None => (0, s),
        };
        let mut it = rest.split('-');
        let (Some(l), Some(x), Some(y), None) = (it.next(), it.next(), it.next(), it.next()) else {
            return Err(bad());
        };
        if !(digits(l) && digits(x) && digits(y)) {
            return Err(bad());
        }
        Ok(Self {
            face,
            level: l.parse().map_err(|_| bad())?,
            x: x.parse().map_err(|_| bad())?,
            y: y.parse().map_err(|_| bad())?,
        })
    }
}

/// One of the two triangular halves of a diamond, separated by its split diagonal.
///
/// `Positive` is the half where `i > j` (main diagonal) or `i + j > N − 1` (anti-diagonal) in the
/// diamond's grid coordinates; it is the half lying in the diamond's first parent.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Half {
    /// The half in the first parent.
    Positive = 0,
    /// The half in the second parent.
    Negative = 1,
}

impl Half {
    /// Both halves.
    pub const BOTH: [Half; 2] = [Half::Positive, Half::Negative];
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn face_qualified_ids_round_trip_and_face_zero_keeps_the_short_form() {
        let id = DiamondId::on_face(4, 3, 512, 256);
        assert_eq!(id.to_string(), "f4-3-512-256");
        assert_eq!("f4-3-512-256".parse::<DiamondId>().unwrap(), id);
        let plane = DiamondId::new(3, 512, 256);
        assert_eq!("f0-3-512-256".parse::<DiamondId>().unwrap(), plane);
        assert_eq!(plane.to_string(), "3-512-256");
        // Coarse to fine first, then face, then centre.
        let mut ids = [
            DiamondId::on_face(1, 2, 0, 0),
            DiamondId::on_face(0, 3, 0, 0),
            DiamondId::on_face(0, 2, 9, 9),
        ];
        ids.sort();
        assert_eq!(ids[0], DiamondId::on_face(0, 2, 9, 9));
        assert_eq!(ids[2], DiamondId::on_face(0, 3, 0, 0));
    }

    #[test]
    fn face_zero_hashes_as_the_three_fields_did() {
        // The hash of a face-0 id is the IdHasher's fold of (level, x, y), as before faces.
        use std::hash::{BuildHasher, Hasher};
        let b = super::super::IdBuildHasher::default();
        let id = DiamondId::new(5, 96, 160);
        let mut h = b.build_hasher();
        h.write_u8(5);
        h.write_u32(96);
        h.write_u32(160);
        assert_eq!(b.hash_one(id), h.finish());
        assert_ne!(
            b.hash_one(id),
            b.hash_one(DiamondId::on_face(1, 5, 96, 160))
        );
    }

    #[test]
    fn id_text_round_trips_and_rejects_junk() {
        let id = DiamondId::new(7, 4096, 12);
        assert_eq!(id.to_string(), "7-4096-12");
        assert_eq!("7-4096-12".parse::<DiamondId>().unwrap(), id);
        for bad in [
            "",
            "7-1",
            "7-1-2-3",
            "a-1-2",
            "7--2",
            "+7-1-2",
            "7-1-99999999999",
            "256-1-1",
            "f-1-2-3",
            "f1-2-3",
            "f256-1-2-3",
            "F1-1-2-3",
            "f+1-1-2-3",
            "f1--1-2-3",
        ] {
            assert!(
                bad.parse::<DiamondId>().is_err(),
                "{bad:?} should not parse"
            );
        }
    }
}
