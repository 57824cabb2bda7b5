//! Work neighbouring quantized-mesh tiles share, done once a tile instead of once for every
//! block that needs it: a tile's block holds the 3 × 3 tiles around it, so without sharing
//! each tile's grid is placed and sampled nine times, and each repository sample placed on the
//! level's grid nine times. Held here: each tile's grid positions ([`Placement::locate`]) and
//! per-face boxes, its grid heights, and the repository's samples placed on a level's grid, by
//! chunk; and the cut's decision for each vertex ([`VertexStates`]: whether it is in the
//! network), which every block holding the vertex would otherwise make again. Each value is a
//! pure function of a global grid position or a sample (the same bits whichever block asks),
//! so tiles are byte-identical with or without it. Each kind is held within a memory bound, the
//! oldest first out ([`Bounded`]).

use std::sync::Arc;
use std::sync::atomic::AtomicU8;

use super::{GRID, SPAN, grid_lat_lon};
use crate::bounded::Bounded;
use crate::place::Placement;
use crate::schemes::TileId;

/// Samples along a chunk's side.
pub const CHUNK: i64 = 32;
/// Bytes of tile grid positions held (about 130 KiB a tile).
pub const POSITIONS_BYTES: usize = 32 << 20;
/// Bytes of tile grid heights held (about 66 KiB a tile).
pub const HEIGHTS_BYTES: usize = 16 << 20;
/// Bytes of placed sample chunks held (32 KiB a chunk).
pub const CHUNKS_BYTES: usize = 32 << 20;
/// Bytes of vertex decisions held (4 KiB a grid tile).
pub const STATES_BYTES: usize = 8 << 20;

/// The cut's decisions for the `GRID × GRID` vertices of one grid tile whose south-west corner
/// is the tile's own (row by row from the south): 0 not decided yet, 1 not in the network, 2
/// in it. Blocks decide a vertex from the same heights, samples and planes in the same global
/// grid coordinates, so the first decision made holds for every block; two blocks deciding
/// one vertex at once write the same value.
pub type VertexStates = Vec<AtomicU8>;
/// A grid tile not wrapped around the Earth (x may be −1 or `2 << z`): a vertex's decision is
/// held under the coordinates its block computed it in, not its wrapped twin's.
type UnwrappedTile = (u8, i64, i64);

/// A face's box of lattice positions: `x0, y0, x1, y1`.
pub type FaceBox = (u8, (f64, f64, f64, f64));
/// A lattice position: face, x, y.
pub type Position = Option<(u8, f64, f64)>;
/// A sample placed on a level's grid: global grid x, y and its height (`None`: no data).
pub type Placed = Option<(f64, f64, f64)>;
/// A tile of a level's grid: level, x (wrapped around the Earth), y (one row beyond each pole
/// allowed).
type GridTile = (u8, i64, i64);

/// A tile's `(GRID + 1)²` grid points' lattice positions, row by row from the south, and per
/// face the box of those on it.
#[derive(Debug)]
pub struct GridPositions {
    /// The positions.
    pub points: Vec<Position>,
    /// Per face, the box of the points on it.
    pub boxes: Vec<FaceBox>,
}

/// The shared work of one tiler's mesh tiles.
#[derive(Debug)]
pub struct Shared {
    positions: Bounded<GridTile, GridPositions>,
    heights: Bounded<GridTile, Vec<(f64, bool)>>,
    chunks: Bounded<(u8, u8, i64, i64), Vec<Placed>>,
    states: Bounded<UnwrappedTile, VertexStates>,
}

impl Default for Shared {
    fn default() -> Self {
        Shared {
            positions: Bounded::new(POSITIONS_BYTES),
            heights: Bounded::new(HEIGHTS_BYTES),
            chunks: Bounded::new(CHUNKS_BYTES),
            states: Bounded::new(STATES_BYTES),
        }
    }
}

/// The nine grid tiles of `t`'s block, from the south-west, row by row.
fn block_tiles(t: TileId) -> [GridTile; 9] {
    let across = 2i64 << t.z;
    std::array::from_fn(|k| {
        let (dx, dy) = ((k % 3) as i64 - 1, (k / 3) as i64 - 1);
        (
            t.z,
            (i64::from(t.x) + dx).rem_euclid(across),
            i64::from(t.y) + dy,
        )
    })
}

/// Block index of point `(i, j)` of the block's grid tile `k` ([`block_tiles`]).
fn block_index_of(k: usize, i: usize, j: usize) -> usize {
    let g = GRID as usize;
    (k / 3 * g + j) * SPAN + k % 3 * g + i
}

/// Per face, the box of `points`.
pub fn face_boxes(points: &[Position]) -> Vec<FaceBox> {
    let mut boxes: Vec<FaceBox> = Vec::new();
    for &(face, x, y) in points.iter().flatten() {
        match boxes.iter_mut().find(|b| b.0 == face) {
            Some((_, r)) => *r = (r.0.min(x), r.1.min(y), r.2.max(x), r.3.max(y)),
            None => boxes.push((face, (x, y, x, y))),
        }
    }
    boxes
}

fn grid_positions(place: &Placement, (z, tx, ty): GridTile) -> GridPositions {
    let n = GRID + 1;
    let mut points = Vec::with_capacity((n * n) as usize);
    for j in 0..n {
        for i in 0..n {
            let (lat, lon) = grid_lat_lon(z, tx * GRID + i, ty * GRID + j);
            points.push(place.locate(lat, lon));
        }
    }
    let boxes = face_boxes(&points);
    GridPositions { points, boxes }
}

impl Shared {
    /// The lattice position of every point of `t`'s block, row by row from the south (as
    /// [`super::block_positions`]), and per face the box of those on it.
    pub fn block_positions(&self, place: &Placement, t: TileId) -> (Vec<Position>, Vec<FaceBox>) {
        let n = (GRID + 1) as usize;
        let bytes = n * n * size_of::<Position>();
        let mut out = vec![None; SPAN * SPAN];
        let mut boxes: Vec<FaceBox> = Vec::new();
        for (k, tile) in block_tiles(t).into_iter().enumerate() {
            let grid = self
                .positions
                .get_or_make(tile, bytes, || grid_positions(place, tile));
            for j in 0..n {
                for i in 0..n {
                    out[block_index_of(k, i, j)] = grid.points[j * n + i];
                }
            }
            for &(face, r) in &grid.boxes {
                match boxes.iter_mut().find(|b| b.0 == face) {
                    Some((_, b)) => *b = (b.0.min(r.0), b.1.min(r.1), b.2.max(r.2), b.3.max(r.3)),
                    None => boxes.push((face, r)),
                }
            }
        }
        (out, boxes)
    }

    /// Per face, the box of every point of the blocks of the level-`z` tiles `xs × ys` (the
    /// grid tiles one beyond them on each side, made once and held as [`Self::block_positions`]
    /// makes them).
    pub fn group_boxes(
        &self,
        place: &Placement,
        z: u8,
        xs: (i64, i64),
        ys: (i64, i64),
    ) -> Vec<FaceBox> {
        let n = (GRID + 1) as usize;
        let bytes = n * n * size_of::<Position>();
        let across = 2i64 << z;
        let mut boxes: Vec<FaceBox> = Vec::new();
        for ty in ys.0 - 1..=ys.1 + 1 {
            for tx in xs.0 - 1..=xs.1 + 1 {
                let tile = (z, tx.rem_euclid(across), ty);
                let grid = self
                    .positions
                    .get_or_make(tile, bytes, || grid_positions(place, tile));
                for &(face, r) in &grid.boxes {
                    match boxes.iter_mut().find(|b| b.0 == face) {
                        Some((_, b)) => {
                            *b = (b.0.min(r.0), b.1.min(r.1), b.2.max(r.2), b.3.max(r.3))
                        }
                        None => boxes.push((face, r)),
                    }
                }
            }
        }
        boxes
    }

    /// The height of every point of `t`'s block: `height(gx, gy, position)` of each grid point
    /// (global grid coordinates), made once a grid tile. `positions` are the block's.
    pub fn block_heights(
        &self,
        t: TileId,
        positions: &[Position],
        height: impl Fn(i64, i64, Position) -> (f64, bool),
    ) -> Vec<(f64, bool)> {
        let n = (GRID + 1) as usize;
        let bytes = n * n * size_of::<(f64, bool)>();
        let mut out = vec![(0.0, false); SPAN * SPAN];
        let (bx, by) = super::block_origin(t);
        for (k, tile) in block_tiles(t).into_iter().enumerate() {
            let (gx0, gy0) = (bx + (k % 3) as i64 * GRID, by + (k / 3) as i64 * GRID);
            let grid = self.heights.get_or_make(tile, bytes, || {
                let mut h = Vec::with_capacity(n * n);
                for j in 0..n {
                    for i in 0..n {
                        let p = positions[block_index_of(k, i, j)];
                        h.push(height(gx0 + i as i64, gy0 + j as i64, p));
                    }
                }
                h
            });
            for j in 0..n {
                for i in 0..n {
                    out[block_index_of(k, i, j)] = grid[j * n + i];
                }
            }
        }
        out
    }

    /// The placed samples of chunk `(cx, cy)` of `face` for level-`z` tiles, row by row, made
    /// by `place(sx, sy)` for each sample (in steps of the level sampled) where not held.
    pub fn chunk(
        &self,
        (z, face, cx, cy): (u8, u8, i64, i64),
        place: impl Fn(i64, i64) -> Placed,
    ) -> std::sync::Arc<Vec<Placed>> {
        let bytes = (CHUNK * CHUNK) as usize * size_of::<Placed>();
        self.chunks.get_or_make((z, face, cx, cy), bytes, || {
            let mut out = Vec::with_capacity((CHUNK * CHUNK) as usize);
            for sy in cy * CHUNK..(cy + 1) * CHUNK {
                for sx in cx * CHUNK..(cx + 1) * CHUNK {
                    out.push(place(sx, sy));
                }
            }
            out
        })
    }

    /// The vertex decisions of `t`'s block: of its nine grid tiles ([`block_tiles`], not
    /// wrapped), from the south-west, row by row. Block point `(i, j)` with `i, j < 3 × GRID`
    /// is vertex `(j % GRID) * GRID + i % GRID` of tile `j / GRID * 3 + i / GRID`.
    pub fn block_states(&self, t: TileId) -> [Arc<VertexStates>; 9] {
        let n = (GRID * GRID) as usize;
        std::array::from_fn(|k| {
            let (dx, dy) = ((k % 3) as i64 - 1, (k / 3) as i64 - 1);
            let tile = (t.z, i64::from(t.x) + dx, i64::from(t.y) + dy);
            self.states
                .get_or_make(tile, n, || (0..n).map(|_| AtomicU8::new(0)).collect())
        })
    }

    /// Drops everything held.
    pub fn clear(&self) {
        self.positions.clear();
        self.heights.clear();
        self.chunks.clear();
        self.states.clear();
    }
}
