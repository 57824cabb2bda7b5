//! Which vertices and triangles a quantized-mesh tile carries: a right-triangulated irregular
//! network (RTIN) over the tile's 64-cell grid, refined by longest-edge bisection (the diamond
//! hierarchy of C-BDAM's cut, as in Martini) until every triangle is within a threshold of the
//! repository's surface, checked exactly at generation.
//!
//! **The error of a triangle** is the largest |surface − the triangle's plane| over every grid
//! point and every sample of the repository level the tile draws from ([`Surface::levels`]
//! index `coarsen`) that lies in it, counting only points holding data. Inside a lattice cell
//! the surface is bilinear, so over a cell lying within one triangle its largest deviation from
//! the plane is at the cell's corners: the error is exact there.
//!
//! **Shared edges.** The network is one network over the whole level: a vertex is active when
//! its diamond's two triangles (or a descendant's) are over the threshold. A vertex's
//! descendants reach at most 63 cells from it, so a tile decides each of its vertices from the
//! 3 × 3 tiles around it (the *block*), and two neighbours decide the vertices of their shared
//! edge from the same heights at the same global grid positions: the same vertices on both
//! sides, by construction. For the same reason a vertex's decision is the same in every block
//! reaching it; where blocks share their work ([`shared::Shared`]) the first block to decide a
//! vertex keeps its decision for the others.

use std::sync::Arc;
use std::sync::atomic::Ordering;

use crate::place::Placement;
use crate::schemes::TileId;
use crate::surface::Surface;

/// Cells along a tile's side.
pub const GRID: i64 = 64;
/// Grid points along a block's side (3 tiles).
pub const SPAN: usize = 3 * GRID as usize + 1;

/// The triangulation of one tile.
#[derive(Debug)]
pub struct Cut {
    /// Triangles, counter-clockwise seen from above, as tile grid positions `(i, j)` (0…64,
    /// from the west and the south).
    pub triangles: Vec<[(u32, u32); 3]>,
    /// Largest triangle error over the triangles whose three vertices hold data, metres.
    pub error: f64,
    /// Triangles over the threshold: the grid's finest, which cannot be split.
    pub over: usize,
}

/// Latitude and longitude of global grid point `(gx, gy)` of level `z` (longitude wrapped
/// into −180…180, latitude clamped at the poles): the same bits for every tile asking.
pub fn grid_lat_lon(z: u8, gx: i64, gy: i64) -> (f64, f64) {
    let cell = 180.0 / (f64::from(1u32 << z) * GRID as f64);
    let turn = GRID << (z + 1);
    let lon = -180.0 + gx.rem_euclid(turn) as f64 * cell;
    ((-90.0 + gy as f64 * cell).clamp(-90.0, 90.0), lon)
}

/// Global grid coordinates of block point 0 of tile `t` (one tile south-west of it).
pub fn block_origin(t: TileId) -> (i64, i64) {
    ((i64::from(t.x) - 1) * GRID, (i64::from(t.y) - 1) * GRID)
}

/// The lattice position of every point of `t`'s block, row by row from the south.
pub fn block_positions(place: &Placement, t: TileId) -> Vec<Option<(u8, f64, f64)>> {
    let (gx0, gy0) = block_origin(t);
    let mut out = Vec::with_capacity(SPAN * SPAN);
    for j in 0..SPAN as i64 {
        for i in 0..SPAN as i64 {
            let (lat, lon) = grid_lat_lon(t.z, gx0 + i, gy0 + j);
            out.push(place.locate(lat, lon));
        }
    }
    out
}

/// Block index of the tile's grid point `(i, j)`.
pub fn block_index(i: u32, j: u32) -> usize {
    (j as usize + GRID as usize) * SPAN + i as usize + GRID as usize
}

/// What the network is cut from.
pub struct Block<'a> {
    /// The tile.
    pub tile: TileId,
    /// Where the repository lies.
    pub place: &'a Placement,
    /// The surface (`None`: no point of the block on the data).
    pub surface: Option<&'a Surface>,
    /// [`block_positions`].
    pub positions: &'a [Option<(u8, f64, f64)>],
    /// Per face, the box of the block points on it ([`shared::face_boxes`] of `positions`).
    pub boxes: &'a [shared::FaceBox],
    /// The block points' heights as drawn (0 m without data) and whether they hold data.
    pub heights: &'a [(f64, bool)],
    /// The level index the tile draws from.
    pub coarsen: usize,
    /// The largest triangle error allowed, metres.
    pub threshold: f64,
    /// Whether the heights are raised by EGM96's undulation (as `heights` are): the samples
    /// are raised too.
    pub to_ellipsoid: bool,
    /// Where placed samples and vertex decisions are shared between blocks (only for a whole
    /// surface: a window's chunks could reach past it); `None`: made for this block alone.
    pub shared: Option<&'a shared::Shared>,
}

/// The network's state over one block.
struct Network<'a> {
    block: &'a Block<'a>,
    origin: (i64, i64),
    /// Samples `(gx, gy, h)` in global grid coordinates, by block cell.
    samples: Vec<(f64, f64, f64)>,
    cell_start: Vec<u32>,
    /// Per block point: 0 not decided, 1 inactive, 2 active.
    state: Vec<u8>,
    /// The decisions shared with other blocks ([`shared::Shared::block_states`]).
    decided: Option<[Arc<shared::VertexStates>; 9]>,
}

/// Cuts tile `block.tile`.
pub fn cut(block: &Block<'_>) -> Cut {
    let mut net = Network {
        block,
        origin: block_origin(block.tile),
        samples: Vec::new(),
        cell_start: Vec::new(),
        state: vec![0; SPAN * SPAN],
        decided: block.shared.map(|s| s.block_states(block.tile)),
    };
    net.gather_samples();
    let (x0, y0) = (net.origin.0 + GRID, net.origin.1 + GRID);
    let (c0, c1, c2, c3) = square_corners(x0 + GRID / 2, y0 + GRID / 2, GRID / 2);
    let mut leaves = Vec::new();
    net.emit([c0, c2, c1], &mut leaves);
    net.emit([c0, c2, c3], &mut leaves);
    let (mut error, mut over) = (0.0f64, 0);
    let mut triangles = Vec::with_capacity(leaves.len());
    for tri in leaves {
        if tri.iter().all(|&p| net.height(p).1) {
            let e = net.triangle_error(tri, f64::INFINITY);
            error = error.max(e);
            over += usize::from(e > block.threshold);
        }
        let local = tri.map(|(gx, gy)| ((gx - x0) as u32, (gy - y0) as u32));
        let [a, b, c] = local.map(|(i, j)| (f64::from(i), f64::from(j)));
        let cross = (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0);
        triangles.push(if cross > 0.0 {
            local
        } else {
            [local[0], local[2], local[1]]
        });
    }
    Cut {
        triangles,
        error,
        over,
    }
}

/// Trailing zeros, capped at 7 (0 counts as a multiple of everything).
fn tz(v: i64) -> u32 {
    if v == 0 { 7 } else { v.trailing_zeros().min(7) }
}

/// The corners of the square of half-side `h` centred on `(cx, cy)`: the first and third on
/// its diagonal (the one through the corner lying on multiples of `4h`), the others off it.
type P = (i64, i64);
fn square_corners(cx: i64, cy: i64, h: i64) -> (P, P, P, P) {
    let corners = [
        (cx - h, cy - h),
        (cx + h, cy - h),
        (cx + h, cy + h),
        (cx - h, cy + h),
    ];
    let on = |p: P| p.0.rem_euclid(4 * h) == 0 && p.1.rem_euclid(4 * h) == 0;
    let k = (0..4).find(|&k| on(corners[k])).unwrap_or(0);
    (
        corners[k],
        corners[(k + 1) % 4],
        corners[(k + 2) % 4],
        corners[(k + 3) % 4],
    )
}

/// The diamond of vertex `(gx, gy)`: its two triangles (hypotenuse first, then the apex) and
/// its children (the midpoints of the diamond's legs); `None` for a tile corner (always there).
fn diamond(gx: i64, gy: i64) -> Option<([[P; 3]; 2], Vec<P>)> {
    let (tx, ty) = (tz(gx), tz(gy));
    let k = tx.min(ty);
    if k >= GRID.trailing_zeros() {
        return None;
    }
    let h = 1i64 << k;
    if tx == ty {
        let (c0, c1, c2, c3) = square_corners(gx, gy, h);
        let children = vec![(gx - h, gy), (gx + h, gy), (gx, gy - h), (gx, gy + h)];
        return Some(([[c0, c2, c1], [c0, c2, c3]], children));
    }
    // The midpoint of an axis-aligned segment of length 2h.
    let ((e0, e1), (a0, a1)) = if tx < ty {
        (((gx - h, gy), (gx + h, gy)), ((gx, gy - h), (gx, gy + h)))
    } else {
        (((gx, gy - h), (gx, gy + h)), ((gx - h, gy), (gx + h, gy)))
    };
    let children = if k == 0 {
        Vec::new()
    } else {
        let q = h / 2;
        vec![
            (gx - q, gy - q),
            (gx + q, gy - q),
            (gx - q, gy + q),
            (gx + q, gy + q),
        ]
    };
    Some(([[e0, e1, a0], [e0, e1, a1]], children))
}

impl Network<'_> {
    /// Block index of global grid point `p`, if in the block.
    fn index(&self, p: P) -> Option<usize> {
        let (i, j) = (p.0 - self.origin.0, p.1 - self.origin.1);
        let inside = (0..SPAN as i64).contains(&i) && (0..SPAN as i64).contains(&j);
        inside.then(|| j as usize * SPAN + i as usize)
    }

    /// A block point's height and whether it holds data (outside the block: none).
    fn height(&self, p: P) -> (f64, bool) {
        self.index(p)
            .map_or((0.0, false), |k| self.block.heights[k])
    }

    /// Whether vertex `p` is in the network.
    fn active(&mut self, p: P) -> bool {
        let Some((tris, children)) = diamond(p.0, p.1) else {
            return true;
        };
        let Some(k) = self.index(p) else {
            // Beyond the block's reach: unreachable from the tile's own vertices.
            return false;
        };
        if self.state[k] == 0 {
            self.state[k] = self
                .shared_state(k)
                .map_or(0, |s| s.load(Ordering::Relaxed));
        }
        if self.state[k] != 0 {
            return self.state[k] == 2;
        }
        let threshold = self.block.threshold;
        let on = tris
            .iter()
            .any(|&t| self.triangle_error(t, threshold) > threshold)
            || children.into_iter().any(|c| self.active(c));
        self.state[k] = if on { 2 } else { 1 };
        if let Some(s) = self.shared_state(k) {
            s.store(self.state[k], Ordering::Relaxed);
        }
        on
    }

    /// The shared decision of block point `k`, where decisions are shared (points on the
    /// block's north and east edges are no vertex a block reaches).
    fn shared_state(&self, k: usize) -> Option<&std::sync::atomic::AtomicU8> {
        let (i, j) = (k % SPAN, k / SPAN);
        let g = GRID as usize;
        let tiles = self.decided.as_ref().filter(|_| i < 3 * g && j < 3 * g)?;
        Some(&tiles[j / g * 3 + i / g][j % g * g + i % g])
    }

    /// The network's triangles within triangle `[a, b, c]` (hypotenuse `a`–`b`, apex `c`).
    fn emit(&mut self, [a, b, c]: [P; 3], out: &mut Vec<[P; 3]>) {
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let splits = dx % 2 == 0 && dy % 2 == 0;
        let m = ((a.0 + b.0) / 2, (a.1 + b.1) / 2);
        if splits && self.active(m) {
            self.emit([a, c, m], out);
            self.emit([c, b, m], out);
        } else {
            out.push([a, b, c]);
        }
    }
}

mod error;
pub mod shared;
