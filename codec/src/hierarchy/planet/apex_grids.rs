//! What a planet's apex hands to its blocks, spilled ([`super::spill`]) so that the memory of a
//! planet build does not grow with its apex (over the land, the apex grows with the land): the
//! grids of its diamonds, which the blocks read to measure the apex diamonds' object errors on
//! their own tiles ([`ApexGrids`]), and the refinements of a level's recorded diamonds, which
//! the next level (and, for the level above the cut, the blocks) gather their grids from
//! ([`ApexRefinements`]).

use std::collections::HashMap;
use std::fmt;

use super::spill::{Spill, Spilled};
use crate::CodecError;
use crate::geometry::DiamondId;
use crate::hierarchy::refine::Refined;

/// What the grids' temporary file holds, for its errors.
const WHAT: &str = "the planet apex's grids";

/// Bytes of grids kept in memory before they go to a temporary file.
pub const IN_MEMORY_BYTES: usize = 16 << 20;

/// Bytes of one level's refinements kept in memory before they go to a temporary file.
pub const REFINEMENTS_IN_MEMORY_BYTES: usize = 4 << 20;

/// Bytes of a level's refinements read back at once where they lie end to end in the spill
/// ([`ApexRefinements::load`]): one read instead of one per refinement.
pub const READ_BYTES: u64 = 1 << 20;

/// Apex grids being written ([`GridSpill::put`]), from any thread.
pub(super) struct GridSpill {
    spill: Spill,
    values: usize,
}

impl GridSpill {
    /// A spill of grids of `values` heights each.
    pub(super) fn new(values: usize) -> Self {
        Self {
            spill: Spill::new(WHAT, IN_MEMORY_BYTES),
            values,
        }
    }

    /// Appends `grid`: where it went.
    pub(super) fn put(&self, grid: &[i32]) -> Result<u64, CodecError> {
        debug_assert_eq!(grid.len(), self.values);
        let bytes: Vec<u8> = grid.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.spill.put(&bytes)
    }

    /// The grids written, by diamond (`index`: where [`GridSpill::put`] put each).
    pub(super) fn finish(self, index: HashMap<DiamondId, u64>) -> Result<ApexGrids, CodecError> {
        Ok(ApexGrids {
            bytes: self.spill.finish()?,
            index,
            values: self.values,
        })
    }
}

/// Every stored apex diamond's grid, spilled ([`GridSpill`]).
#[derive(Clone)]
pub struct ApexGrids {
    bytes: Spilled,
    index: HashMap<DiamondId, u64>,
    values: usize,
}

/// Little-endian `i32`s.
fn ints(bytes: &[u8]) -> Vec<i32> {
    bytes
        .chunks_exact(4)
        .map(|b| i32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect()
}

impl ApexGrids {
    /// The grids `grids` (each of `values` heights), spilled.
    pub fn from_grids(
        values: usize,
        grids: impl IntoIterator<Item = (DiamondId, Vec<i32>)>,
    ) -> Result<Self, CodecError> {
        let spill = GridSpill::new(values);
        let mut index = HashMap::new();
        for (id, grid) in grids {
            if grid.len() != values {
                return Err(CodecError::invalid(format!(
                    "apex diamond {id}: a grid of {} heights, not {values}",
                    grid.len()
                )));
            }
            index.insert(id, spill.put(&grid)?);
        }
        spill.finish(index)
    }

    /// The diamonds whose grids are held, in no particular order.
    pub fn ids(&self) -> impl Iterator<Item = DiamondId> + '_ {
        self.index.keys().copied()
    }

    /// How many grids are held.
    pub fn len(&self) -> usize {
        self.index.len()
    }

    /// Whether none is.
    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }

    /// Diamond `id`'s grid, read back; `None` if it is not an apex diamond.
    pub fn get(&self, id: DiamondId) -> Result<Option<Vec<i32>>, CodecError> {
        let Some(&at) = self.index.get(&id) else {
            return Ok(None);
        };
        let mut bytes = vec![0u8; self.values * 4];
        self.bytes.read(at, &mut bytes)?;
        Ok(Some(ints(&bytes)))
    }
}

impl fmt::Debug for ApexGrids {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "ApexGrids({} grids of {} heights)",
            self.len(),
            self.values
        )
    }
}

impl PartialEq for ApexGrids {
    /// The same diamonds with the same grids (every grid read back).
    fn eq(&self, other: &Self) -> bool {
        self.values == other.values
            && self.len() == other.len()
            && self
                .ids()
                .all(|id| matches!((self.get(id), other.get(id)), (Ok(a), Ok(b)) if a == b))
    }
}

/// The refinements of one apex level being written ([`RefinedSpill::put`]).
pub(super) struct RefinedSpill {
    spill: Spill,
    n: usize,
    index: HashMap<DiamondId, (u64, bool)>,
}

impl RefinedSpill {
    /// A spill of refinements of grids of side `n`.
    pub(super) fn new(n: usize) -> Self {
        Self {
            spill: Spill::new("the planet apex's refinements", REFINEMENTS_IN_MEMORY_BYTES),
            n,
            index: HashMap::new(),
        }
    }

    /// Appends diamond `id`'s refinement.
    pub(super) fn put(&mut self, id: DiamondId, refined: &Refined) -> Result<(), CodecError> {
        debug_assert_eq!(refined.n(), self.n);
        let mut bytes: Vec<u8> = refined
            .values()
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        if let Some(valid) = refined.validity() {
            bytes.extend(valid.iter().map(|&b| u8::from(b)));
        }
        let at = self.spill.put(&bytes)?;
        self.index.insert(id, (at, refined.validity().is_some()));
        Ok(())
    }

    /// The refinements written.
    pub(super) fn finish(self) -> Result<ApexRefinements, CodecError> {
        Ok(ApexRefinements {
            bytes: Some(self.spill.finish()?),
            n: self.n,
            index: self.index,
        })
    }
}

/// The refinements of one apex level's recorded diamonds, spilled ([`RefinedSpill`]): read
/// back a few at a time, by the diamonds of the next level that gather from them.
#[derive(Clone)]
pub struct ApexRefinements {
    /// `None` when nothing was written.
    bytes: Option<Spilled>,
    n: usize,
    /// Per diamond, where its refinement is and whether it carries a validity.
    index: HashMap<DiamondId, (u64, bool)>,
}

impl ApexRefinements {
    /// No refinement (above the roots), of grids of side `n`.
    pub fn none(n: usize) -> Self {
        Self {
            bytes: None,
            n,
            index: HashMap::new(),
        }
    }

    /// The refinements `refined` (each of a grid of side `n`), spilled.
    pub fn from_refined(
        n: usize,
        refined: impl IntoIterator<Item = (DiamondId, Refined)>,
    ) -> Result<Self, CodecError> {
        let mut spill = RefinedSpill::new(n);
        for (id, r) in refined {
            if r.n() != n {
                return Err(CodecError::invalid(format!(
                    "apex diamond {id}: a refinement of side {}, not {n}",
                    r.n()
                )));
            }
            spill.put(id, &r)?;
        }
        spill.finish()
    }

    /// The diamonds whose refinements are held, in no particular order.
    pub fn ids(&self) -> impl Iterator<Item = DiamondId> + '_ {
        self.index.keys().copied()
    }

    /// How many refinements are held.
    pub fn len(&self) -> usize {
        self.index.len()
    }

    /// Whether none is.
    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }

    /// Diamond `id`'s refinement, read back; `None` if it has none here.
    pub fn get(&self, id: DiamondId) -> Result<Option<Refined>, CodecError> {
        let (Some(&(at, has_validity)), Some(bytes)) = (self.index.get(&id), &self.bytes) else {
            return Ok(None);
        };
        let mut buf = vec![0u8; self.spilled_len(has_validity)];
        bytes.read(at, &mut buf)?;
        Ok(Some(self.refinement_of(has_validity, &buf)))
    }

    /// The refinements of those of `ids` held here, read back, by diamond: refinements written
    /// one after the other are read together, up to [`READ_BYTES`] at a time.
    pub fn load(
        &self,
        ids: impl IntoIterator<Item = DiamondId>,
    ) -> Result<HashMap<DiamondId, Refined>, CodecError> {
        let Some(bytes) = &self.bytes else {
            return Ok(HashMap::new());
        };
        let mut wanted: Vec<(u64, bool, DiamondId)> = ids
            .into_iter()
            .filter_map(|id| self.index.get(&id).map(|&(at, v)| (at, v, id)))
            .collect();
        wanted.sort_unstable();
        wanted.dedup();
        let mut out = HashMap::with_capacity(wanted.len());
        let mut buf = Vec::new();
        let mut rest = &wanted[..];
        while let Some(&(start, _, _)) = rest.first() {
            // The longest run of refinements lying end to end, within the read's bytes.
            let mut end = start;
            let mut count = 0;
            for &(at, v, _) in rest {
                let len = self.spilled_len(v) as u64;
                if at != end || (count > 0 && end + len - start > READ_BYTES) {
                    break;
                }
                end += len;
                count += 1;
            }
            buf.resize((end - start) as usize, 0);
            bytes.read(start, &mut buf)?;
            for &(at, v, id) in &rest[..count] {
                let from = (at - start) as usize;
                let piece = &buf[from..from + self.spilled_len(v)];
                out.insert(id, self.refinement_of(v, piece));
            }
            rest = &rest[count..];
        }
        Ok(out)
    }

    /// Bytes a refinement takes in the spill, with its validity or not.
    fn spilled_len(&self, has_validity: bool) -> usize {
        let n = self.n;
        let side = 2 * n - 1;
        (n * n + (n - 1) * (n - 1)) * 4 + if has_validity { side * side } else { 0 }
    }

    /// The refinement whose spilled bytes are `buf` ([`Self::spilled_len`] of them).
    fn refinement_of(&self, has_validity: bool, buf: &[u8]) -> Refined {
        let n = self.n;
        let values = n * n + (n - 1) * (n - 1);
        let refined = Refined::from_values(n, ints(&buf[..values * 4]))
            .expect("a refinement of the spill's side");
        refined.with_validity(
            has_validity.then(|| buf[values * 4..].iter().map(|&b| b != 0).collect()),
        )
    }
}

impl fmt::Debug for ApexRefinements {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "ApexRefinements({} refinements of side {})",
            self.len(),
            self.n
        )
    }
}

impl PartialEq for ApexRefinements {
    /// The same diamonds with the same refinements (every one read back).
    fn eq(&self, other: &Self) -> bool {
        self.n == other.n
            && self.len() == other.len()
            && self
                .ids()
                .all(|id| matches!((self.get(id), other.get(id)), (Ok(a), Ok(b)) if a == b))
    }
}

/// Bytes of a refinement of a grid of side `n` (its values and, at most, its validity): what a
/// run of refinements held at once is counted in.
pub(super) fn refinement_bytes(n: usize) -> usize {
    let side = 2 * n - 1;
    (n * n + (n - 1) * (n - 1)) * 4 + side * side
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Grids written from several threads read back as written, each by its diamond: held in
    /// memory, and spilled to a file past [`IN_MEMORY_BYTES`] (200 grids of a 64th of it).
    #[test]
    fn grids_read_back_as_written() {
        const V: usize = IN_MEMORY_BYTES / 4 / 64;
        let grid = |i: u32| {
            (0..V as i32)
                .map(|v| v * 1000 - i as i32 * 7)
                .collect::<Vec<i32>>()
        };
        let spill = GridSpill::new(V);
        let index: HashMap<DiamondId, u64> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..4u32)
                .map(|t| {
                    let spill = &spill;
                    s.spawn(move || {
                        (0..50u32)
                            .map(|i| {
                                let i = t * 50 + i;
                                (DiamondId::new(3, i, i + 1), spill.put(&grid(i)).unwrap())
                            })
                            .collect::<Vec<_>>()
                    })
                })
                .collect();
            handles
                .into_iter()
                .flat_map(|h| h.join().unwrap())
                .collect()
        });
        let grids = spill.finish(index).unwrap();
        assert!(grids.bytes.in_file(), "not spilled");
        assert_eq!(grids.len(), 200);
        for i in 0..200u32 {
            assert_eq!(
                grids.get(DiamondId::new(3, i, i + 1)).unwrap(),
                Some(grid(i))
            );
        }
        assert_eq!(grids.get(DiamondId::new(3, 0, 0)).unwrap(), None);
        let few = (0..20u32).map(|i| (DiamondId::new(3, i, i + 1), grid(i)));
        let held = ApexGrids::from_grids(V, few).unwrap();
        assert!(!held.bytes.in_file(), "spilled");
        for i in 0..20u32 {
            assert_eq!(
                held.get(DiamondId::new(3, i, i + 1)).unwrap(),
                Some(grid(i))
            );
        }
        let all = (0..200u32).map(|i| (DiamondId::new(3, i, i + 1), grid(i)));
        assert_eq!(ApexGrids::from_grids(V, all).unwrap(), grids);
        let e = ApexGrids::from_grids(V, [(DiamondId::new(3, 0, 0), vec![0; 8])]).unwrap_err();
        assert!(
            e.to_string().contains(&format!("8 heights, not {V}")),
            "{e}"
        );
    }

    /// Refinements read back as written, each by its diamond, with and without a validity:
    /// held in memory, and spilled to a file past [`REFINEMENTS_IN_MEMORY_BYTES`]; a refinement
    /// of another side is refused by name.
    #[test]
    fn refinements_read_back_as_written() {
        let n = 33;
        let refined = |i: u32| {
            let vertices: Vec<i32> = (0..n * n).map(|v| v as i32 * 3 - i as i32).collect();
            let cells: Vec<i32> = (0..(n - 1) * (n - 1))
                .map(|v| -(v as i32) + i as i32)
                .collect();
            let r = Refined::from_parts(n, &vertices, &cells);
            let side = 2 * n - 1;
            match i % 3 {
                0 => r.with_validity(Some(
                    (0..side * side)
                        .map(|k| !(k + i as usize).is_multiple_of(5))
                        .collect(),
                )),
                _ => r,
            }
        };
        let id = |i: u32| DiamondId::new(5, 2 * i + 1, 7);
        // 8.3 KB each: 600 of them are past the in-memory bytes.
        for (count, in_file) in [(20u32, false), (600, true)] {
            let all =
                ApexRefinements::from_refined(n, (0..count).map(|i| (id(i), refined(i)))).unwrap();
            assert_eq!(all.bytes.as_ref().unwrap().in_file(), in_file, "{count}");
            assert_eq!(all.len(), count as usize);
            for i in (0..count).rev() {
                assert_eq!(all.get(id(i)).unwrap(), Some(refined(i)), "{i} of {count}");
            }
            assert_eq!(all.get(DiamondId::new(5, 0, 0)).unwrap(), None);
            let some = all
                .load([id(1), id(3), id(1), DiamondId::new(5, 0, 0)])
                .unwrap();
            assert_eq!(some.len(), 2);
            assert_eq!(some[&id(3)], refined(3));
        }
        assert!(ApexRefinements::none(n).get(id(0)).unwrap().is_none());
        assert!(ApexRefinements::none(n).load([id(0)]).unwrap().is_empty());
        let e =
            ApexRefinements::from_refined(n, [(id(0), Refined::from_parts(3, &[0; 9], &[0; 4]))])
                .unwrap_err();
        assert!(e.to_string().contains("side 3, not 33"), "{e}");
    }

    /// Refinements loaded together ([`ApexRefinements::load`]: those lying end to end in the
    /// spill read at once, up to [`READ_BYTES`]) read back as each one alone: all of 600 (5 MB,
    /// with and without validity), every third, the last few in reverse order with repeats.
    #[test]
    fn refinements_loaded_together_read_back_as_written() {
        let n = 33;
        let refined = |i: u32| {
            let vertices: Vec<i32> = (0..n * n).map(|v| v as i32 * 5 + i as i32).collect();
            let r = Refined::from_parts(n, &vertices, &vec![i as i32; (n - 1) * (n - 1)]);
            let side = 2 * n - 1;
            match i % 4 {
                1 => r.with_validity(Some((0..side * side).map(|k| k % 7 != 0).collect())),
                _ => r,
            }
        };
        let id = |i: u32| DiamondId::new(7, i, 2 * i + 3);
        let all = ApexRefinements::from_refined(n, (0..600).map(|i| (id(i), refined(i)))).unwrap();
        let sets: [Vec<u32>; 3] = [
            (0..600).collect(),
            (0..600).step_by(3).collect(),
            vec![599, 598, 599, 590, 17, 598],
        ];
        for set in sets {
            let loaded = all.load(set.iter().map(|&i| id(i))).unwrap();
            let distinct: std::collections::BTreeSet<u32> = set.iter().copied().collect();
            assert_eq!(loaded.len(), distinct.len());
            for i in distinct {
                assert_eq!(loaded[&id(i)], refined(i), "{i}");
            }
        }
    }
}
