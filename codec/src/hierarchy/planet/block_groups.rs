//! Which lattice tiles each block of a block-wise planet encode takes ([`BlockGroups`]): blocks
//! follow the data, not the cube.
//!
//! A block is a rectangle of tiles on one face. Each face is cut in quarters (halves where a
//! side is one tile) until a part's estimated memory — the points its tiles hold at their own
//! strides, and the grids of the stored diamonds below the cut whose centres it owns — fits a
//! budget, or the part is one tile. Where only coarse data reaches (an ETOPO ocean under a fine
//! inset's lattice: few points a tile, no diamond below the cut) a whole face or a large part
//! of it is one block; where fine data is, a block is a few tiles or one. Which tiles go
//! together changes no byte of the output: a diamond is refined from its parents and its own
//! points wherever it is computed, and its error is the largest over the tiles under it.

use std::collections::HashMap;

use crate::CodecError;
use crate::geometry::{DiamondId, Domain};

use super::grid::{tile_of, tiles_across};

/// Bytes a block is estimated to hold per point its tiles hold: the tile's height, validity
/// and class, the lattice cache's winner, and the neighbours' strips it reads.
const BYTES_PER_TILE_POINT: u64 = 8;

/// Bytes a block is estimated to hold per grid point of each stored diamond it owns: the
/// diamond's gathered grid and refinement, and its children's next level.
const BYTES_PER_DIAMOND_POINT: u64 = 16;

/// A rectangle of tiles of one face: columns `first.0..=last.0`, rows `first.1..=last.1` of the
/// face's tile grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileGroup {
    /// The face.
    pub face: u8,
    /// Tile column and row of the first tile.
    pub first: (usize, usize),
    /// Tile column and row of the last tile (inclusive).
    pub last: (usize, usize),
}

impl TileGroup {
    /// Whether tile `index` of a face `across` tiles wide (row-major) is in the group.
    pub fn holds(&self, index: usize, across: usize) -> bool {
        let (bx, by) = (index % across, index / across);
        (self.first.0..=self.last.0).contains(&bx) && (self.first.1..=self.last.1).contains(&by)
    }

    /// The row-major indices of its tiles on a face `across` tiles wide.
    pub fn tiles(&self, across: usize) -> impl Iterator<Item = usize> + '_ {
        (self.first.1..=self.last.1)
            .flat_map(move |by| (self.first.0..=self.last.0).map(move |bx| by * across + bx))
    }

    /// The lattice columns and rows (inclusive) whose points its tiles own: a tile owns its
    /// first row and column, its last only on the face's far side (as [`tile_of`] assigns).
    pub fn owned_span(&self, side: i64, tile_log2: u32) -> ((i64, i64), (i64, i64)) {
        let across = tiles_across(side, tile_log2);
        let span = |a: usize, b: usize| {
            let lo = (a as i64) << tile_log2;
            let hi = if b + 1 == across {
                side
            } else {
                ((b as i64 + 1) << tile_log2) - 1
            };
            (lo, hi)
        };
        (
            span(self.first.0, self.last.0),
            span(self.first.1, self.last.1),
        )
    }
}

/// The blocks of a block-wise planet encode, in block order (face by face).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BlockGroups {
    groups: Vec<TileGroup>,
}

impl BlockGroups {
    /// One block per tile, row-major, face by face.
    pub fn one_per_tile(domain: &Domain, tile_log2: u32) -> Self {
        let side = domain.cube().map_or(0, |c| c.side());
        let across = tiles_across(side, tile_log2);
        let groups = (0..domain.faces())
            .flat_map(|face| {
                (0..across * across).map(move |i| TileGroup {
                    face,
                    first: (i % across, i / across),
                    last: (i % across, i / across),
                })
            })
            .collect();
        Self { groups }
    }

    /// Tiles grouped so that each block's estimated memory fits `block_bytes`, and at most
    /// the `at_least`-th part of the whole planet's (so that shards have blocks to share), or
    /// it is one tile (see the module notes): `strides` per face, per tile, the `log2` of the
    /// stride it holds its points at; `stored` per level, the planet's stored diamonds, of
    /// which those from level `cut` down are counted where their centres lie.
    pub fn within(
        domain: &Domain,
        tile_log2: u32,
        strides: &[Vec<u32>],
        stored: &[Vec<DiamondId>],
        cut: u8,
        (block_bytes, at_least): (u64, usize),
    ) -> Result<Self, CodecError> {
        let side = domain.cube().map_or(0, |c| c.side());
        let across = tiles_across(side, tile_log2);
        let faces = usize::from(domain.faces());
        if strides.len() != faces || strides.iter().any(|f| f.len() != across * across) {
            return Err(CodecError::invalid(format!(
                "tile strides for {} faces of {} tiles, not {faces} of {}",
                strides.len(),
                strides.first().map_or(0, Vec::len),
                across * across
            )));
        }
        let n = domain.n() as u64;
        let mut bytes: Vec<Vec<u64>> = strides
            .iter()
            .map(|face| {
                let tile = |i: usize, s: u32| {
                    let extent = |b: usize| {
                        let lo = (b as i64) << tile_log2;
                        ((((b as i64 + 1) << tile_log2).min(side) - lo) >> s) as u64 + 1
                    };
                    extent(i % across) * extent(i / across) * BYTES_PER_TILE_POINT
                };
                face.iter().enumerate().map(|(i, &s)| tile(i, s)).collect()
            })
            .collect();
        for id in stored.iter().skip(usize::from(cut)).flatten() {
            let i = tile_of(side, tile_log2, i64::from(id.x), i64::from(id.y));
            bytes[usize::from(id.face)][i] += n * n * BYTES_PER_DIAMOND_POINT;
        }
        let total: u64 = bytes.iter().flatten().sum();
        let budget = block_bytes.min(total.div_ceil(at_least.max(1) as u64));
        let mut groups = Vec::new();
        for (face, bytes) in bytes.iter().enumerate() {
            let face = u8::try_from(face).expect("6 faces");
            let whole = TileGroup {
                face,
                first: (0, 0),
                last: (across - 1, across - 1),
            };
            split(whole, across, bytes, budget, &mut groups);
        }
        Ok(Self { groups })
    }

    /// How many blocks.
    pub fn len(&self) -> usize {
        self.groups.len()
    }

    /// Whether there is no block.
    pub fn is_empty(&self) -> bool {
        self.groups.is_empty()
    }

    /// The block of each tile `(face, index)` of a face `across` tiles wide, for blocks of
    /// fewer than 64 tiles (a larger block holds coarse tiles only, cheap to paint again).
    pub fn block_of_tiles(&self, across: usize) -> HashMap<(u8, usize), usize> {
        self.groups
            .iter()
            .enumerate()
            .filter(|(_, g)| g.tiles(across).nth(63).is_none())
            .flat_map(|(b, g)| g.tiles(across).map(move |i| ((g.face, i), b)))
            .collect()
    }

    /// Block `index`'s tiles.
    pub fn get(&self, index: usize) -> Option<&TileGroup> {
        self.groups.get(index)
    }
}

/// Appends `group` to `out` if its tiles' `bytes` fit `budget` or it is one tile, else its
/// quarters (halves along a side one tile wide), each in turn, in row-major order.
fn split(group: TileGroup, across: usize, bytes: &[u64], budget: u64, out: &mut Vec<TileGroup>) {
    let total: u64 = group.tiles(across).map(|i| bytes[i]).sum();
    let ((x0, y0), (x1, y1)) = (group.first, group.last);
    if total <= budget || (x0 == x1 && y0 == y1) {
        out.push(group);
        return;
    }
    let halves = |a: usize, b: usize| {
        let mid = a + (b - a).div_ceil(2);
        if a == b {
            vec![(a, b)]
        } else {
            vec![(a, mid - 1), (mid, b)]
        }
    };
    for (ya, yb) in halves(y0, y1) {
        for &(xa, xb) in &halves(x0, x1) {
            let part = TileGroup {
                face: group.face,
                first: (xa, ya),
                last: (xb, yb),
            };
            split(part, across, bytes, budget, out);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every tile lands in exactly one group, one tile with a heavy weight is alone, and the
    /// light rest make few groups.
    #[test]
    fn groups_cover_every_tile_once_and_follow_the_weight() {
        let domain = Domain::cube_sphere(9, 4).unwrap();
        let side = domain.cube().unwrap().side();
        let t = 3;
        let across = tiles_across(side, t);
        assert_eq!(across, 16);
        let mut strides = vec![vec![3u32; across * across]; 6];
        strides[2][5 * across + 7] = 0;
        // A coarse tile holds 2² points (32 B), the fine one 9² (648 B): under 700 B the fine
        // one is alone (any quarter holding it and three others is 744 B), the coarse ones go
        // 16 together (512 B; 64 are 2 048 B).
        let g = BlockGroups::within(&domain, t, &strides, &[], 0, (700, 1)).unwrap();
        for face in 0..6u8 {
            for i in 0..across * across {
                let holding = g
                    .groups
                    .iter()
                    .filter(|b| b.face == face && b.holds(i, across));
                assert_eq!(holding.count(), 1, "face {face} tile {i}");
            }
        }
        let fine = g
            .groups
            .iter()
            .find(|b| b.face == 2 && b.holds(5 * across + 7, across));
        assert_eq!(fine.unwrap().tiles(across).count(), 1);
        for b in g.groups.iter().filter(|b| b.face != 2) {
            assert_eq!(b.tiles(across).count(), 16, "{b:?}");
        }
        let one = BlockGroups::one_per_tile(&domain, t);
        assert_eq!(one.len(), 6 * across * across);
        // Asked for at least 200 blocks, the budget shrinks to the 200th part of the planet.
        let many = BlockGroups::within(&domain, t, &strides, &[], 0, (u64::MAX, 200)).unwrap();
        assert!(
            many.len() >= 200 && many.len() < g.len() * 200,
            "{}",
            many.len()
        );
        let e = BlockGroups::within(&domain, t, &strides[..5], &[], 0, (0, 1)).unwrap_err();
        assert!(e.to_string().contains("5 faces"), "{e}");
    }

    /// A group's owned span ends one step before the next tile, or at the face's far side.
    #[test]
    fn owned_spans_meet_without_overlap() {
        let g = TileGroup {
            face: 0,
            first: (1, 0),
            last: (2, 3),
        };
        assert_eq!(g.owned_span(64, 4), ((16, 47), (0, 64)));
        let g = TileGroup {
            face: 0,
            first: (3, 3),
            last: (3, 3),
        };
        assert_eq!(g.owned_span(64, 4), ((48, 64), (48, 64)));
    }
}
