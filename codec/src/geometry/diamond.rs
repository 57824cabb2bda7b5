//! Diamond identifiers.

use std::fmt;
use std::str::FromStr;

use crate::CodecError;

/// A diamond: its level and the lattice coordinates of its centre.
///
/// Ordering is by level first, so sorting a set of ids gives a coarse-to-fine order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct DiamondId {
    /// Level: 0 for roots, `2K` for the finest (the input grid).
    pub level: u8,
    /// Centre, lattice column (west to east).
    pub x: u32,
    /// Centre, lattice row (north to south, like the input rows).
    pub y: u32,
}

impl DiamondId {
    /// A diamond id; whether it exists depends on the [`crate::geometry::Layout`].
    pub const fn new(level: u8, x: u32, y: u32) -> Self {
        Self { level, x, y }
    }

    /// Whether the level is even (axis-aligned square) or odd (rotated 45°).
    pub const fn is_even(&self) -> bool {
        self.level.is_multiple_of(2)
    }
}

/// Text form used in URLs and logs: `level-x-y`, e.g. `3-512-256`.
impl fmt::Display for DiamondId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}-{}-{}", self.level, self.x, self.y)
    }
}

impl FromStr for DiamondId {
    type Err = CodecError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = || CodecError::invalid(format!("malformed diamond id {s:?} (want level-x-y)"));
        let mut it = s.split('-');
        let (Some(l), Some(x), Some(y), None) = (it.next(), it.next(), it.next(), it.next()) else {
            return Err(bad());
        };
        // `parse` accepts a leading '+'; ids have one canonical spelling, so insist on digits.
        let digits = |t: &str| !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit());
        if !(digits(l) && digits(x) && digits(y)) {
            return Err(bad());
        }
        Ok(Self {
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
        ] {
            assert!(
                bad.parse::<DiamondId>().is_err(),
                "{bad:?} should not parse"
            );
        }
    }
}
