//! The exact error of a network triangle: its plane against every grid point and every sample
//! of the repository level inside it ([`Network::triangle_error`]), and gathering those
//! samples over the block ([`Network::gather_samples`]).

use std::sync::Arc;

use super::shared::{CHUNK, Placed};
use super::{Block, GRID, Network, P, SPAN};
use crate::surface::Surface;

impl Network<'_> {
    /// Every sample of the level the tile draws from whose position falls in the block, in
    /// global grid coordinates, sorted by block cell.
    pub(super) fn gather_samples(&mut self) {
        let b = self.block;
        let cells = (SPAN - 1) * (SPAN - 1);
        let Some(surface) = b.surface else {
            self.cell_start = vec![0; cells + 1];
            return;
        };
        let level = b.coarsen.min(surface.levels().len() - 1);
        let step = (1i64 << level) as f64;
        let turn = (GRID << (b.tile.z + 1)) as f64;
        let mut found: Vec<(usize, (f64, f64, f64))> = Vec::new();
        // Only the data's samples (a plane's block may reach around the Earth).
        let (ex0, ey0, ex1, ey1) = surface.extent();
        for &(face, (x0, y0, x1, y1)) in b.boxes {
            let (x0, x1) = (x0.max(ex0 as f64), x1.min(ex1 as f64));
            let (y0, y1) = (y0.max(ey0 as f64), y1.min(ey1 as f64));
            if x0 > x1 || y0 > y1 {
                continue;
            }
            let (x0, x1) = ((x0 / step).floor() - 1.0, (x1 / step).ceil() + 1.0);
            let (y0, y1) = ((y0 / step).floor() - 1.0, (y1 / step).ceil() + 1.0);
            let mut samples = Samples::new(b, face, surface, step);
            for sy in y0 as i64..=y1 as i64 {
                for sx in x0 as i64..=x1 as i64 {
                    let Some((gx, gy, h)) = samples.at(sx, sy) else {
                        continue;
                    };
                    let ly = gy - self.origin.1 as f64;
                    for k in -2..=2 {
                        let gx = gx + f64::from(k) * turn;
                        let lx = gx - self.origin.0 as f64;
                        if let Some(c) = block_cell(lx, ly) {
                            found.push((c, (gx, gy, h)));
                        }
                    }
                }
            }
        }
        self.cell_start = cell_starts(&found, cells);
        self.samples = sorted_by_cell(found, &self.cell_start);
    }

    /// Largest |height − plane of `tri`| over the block's grid points and samples in `tri`
    /// holding data; returns as soon as it passes `stop`.
    pub(super) fn triangle_error(&self, tri: [P; 3], stop: f64) -> f64 {
        let [a, b, c] = tri.map(|p| (p.0 as f64, p.1 as f64, self.height(p).0));
        let plane = Plane::through(a, b, c);
        let gx = [tri[0].0, tri[1].0, tri[2].0];
        let gy = [tri[0].1, tri[1].1, tri[2].1];
        let (x0, x1) = (*gx.iter().min().unwrap(), *gx.iter().max().unwrap());
        let (y0, y1) = (*gy.iter().min().unwrap(), *gy.iter().max().unwrap());
        let area = Area {
            plane,
            spans: Spans::of(tri),
            columns: (x0, x1),
            rows: (y0, y1),
        };
        let worst = self.grid_error(&area, stop);
        if worst > stop {
            return worst;
        }
        self.samples_error(&area, stop, worst)
    }

    /// [`Self::triangle_error`] over the grid points, row by row.
    fn grid_error(&self, area: &Area, stop: f64) -> f64 {
        let ((x0, x1), (y0, y1), plane) = (area.columns, area.rows, &area.plane);
        let mut worst = 0.0f64;
        for y in y0..=y1 {
            match &area.spans {
                // The row's span holds exactly the grid points `holds` admits: off it, a grid
                // point is at least a column from the triangle.
                Some(spans) => {
                    let (xa, xb) = spans.between(y, y);
                    for x in xa..=xb {
                        let (h, data) = self.height((x, y));
                        if data {
                            worst = worst.max((h - plane.at(x as f64, y as f64)).abs());
                        }
                    }
                }
                None => {
                    for x in x0..=x1 {
                        let (h, data) = self.height((x, y));
                        if data && plane.holds(x as f64, y as f64) {
                            worst = worst.max((h - plane.at(x as f64, y as f64)).abs());
                        }
                    }
                }
            }
            if worst > stop {
                return worst;
            }
        }
        worst
    }

    /// [`Self::triangle_error`] over the samples, cell row by cell row, from `worst`.
    fn samples_error(&self, area: &Area, stop: f64, mut worst: f64) -> f64 {
        let ((x0, x1), (y0, y1), plane) = (area.columns, area.rows, &area.plane);
        for y in y0..y1 {
            // The cells over the band's span and the one west of it (a sample within `holds`'
            // tolerance west of the span lies there; one east of the span's last column, in
            // that column's cell). Cells wholly in the triangle need no `holds`.
            let ((xa, xb), (inner_a, inner_b)) = match &area.spans {
                Some(spans) => (spans.between(y, y + 1), spans.within(y)),
                None => ((x0, x1), (1, 0)),
            };
            for x in (xa - 1).max(x0)..=xb.min(x1 - 1) {
                let Some(cell) = self.cell_of((x, y)) else {
                    continue;
                };
                let inside = inner_a <= x && x < inner_b;
                let (s, e) = (self.cell_start[cell], self.cell_start[cell + 1]);
                for &(sx, sy, h) in &self.samples[s as usize..e as usize] {
                    if inside || plane.holds(sx, sy) {
                        worst = worst.max((h - plane.at(sx, sy)).abs());
                    }
                }
            }
            if worst > stop {
                return worst;
            }
        }
        worst
    }

    /// Block cell whose south-west corner is global grid point `p`.
    fn cell_of(&self, p: P) -> Option<usize> {
        let (i, j) = (p.0 - self.origin.0, p.1 - self.origin.1);
        let n = SPAN as i64 - 1;
        ((0..n).contains(&i) && (0..n).contains(&j)).then(|| (j * n + i) as usize)
    }
}

/// A triangle as its error is measured over it.
struct Area {
    plane: Plane,
    /// `None` where not all its edges have whole slopes: every column of its box is visited.
    spans: Option<Spans>,
    /// Its box: least and largest column, row.
    columns: (i64, i64),
    rows: (i64, i64),
}

/// A triangle's extent along the grid rows, per edge: its rows `y0 ≤ y1`, its least and
/// largest x at `y0` (two for an edge along a row) and its slope (columns per row).
struct Spans([(i64, i64, i64, i64, i64); 3]);

impl Spans {
    /// The extent of `tri`, or `None` where an edge's slope is not whole. The network's edges
    /// run along the axes and the diagonals: slopes 0 and ±1.
    fn of(tri: [P; 3]) -> Option<Spans> {
        let edge = |p: P, q: P| {
            let (p, q) = if p.1 <= q.1 { (p, q) } else { (q, p) };
            match q.1 - p.1 {
                0 => Some((p.1, q.1, p.0.min(q.0), p.0.max(q.0), 0)),
                dy if (q.0 - p.0) % dy == 0 => Some((p.1, q.1, p.0, p.0, (q.0 - p.0) / dy)),
                _ => None,
            }
        };
        Some(Spans([
            edge(tri[0], tri[1])?,
            edge(tri[1], tri[2])?,
            edge(tri[2], tri[0])?,
        ]))
    }

    /// The least and largest column of the triangle between rows `y0 ≤ y1` (within its
    /// rows): a convex triangle's extent over a band is at the band's edges or its vertices.
    fn between(&self, y0: i64, y1: i64) -> (i64, i64) {
        let (mut lo, mut hi) = (i64::MAX, i64::MIN);
        for &(ya, yb, xlo, xhi, slope) in &self.0 {
            let (ya2, yb2) = (ya.max(y0), yb.min(y1));
            if ya2 <= yb2 {
                for y in [ya2, yb2] {
                    let dx = (y - ya) * slope;
                    lo = lo.min(xlo + dx);
                    hi = hi.max(xhi + dx);
                }
            }
        }
        (lo, hi)
    }

    /// The columns `x0 ≤ x < x1` whose cells between rows `y` and `y + 1` lie wholly in the
    /// triangle: from the larger of the two rows' least columns to the smaller of their
    /// largest (the triangle's sides are straight between its vertices' rows).
    fn within(&self, y: i64) -> (i64, i64) {
        let (a, b) = (self.between(y, y), self.between(y + 1, y + 1));
        (a.0.max(b.0), a.1.min(b.1))
    }
}

/// The cell of block position `(lx, ly)`, points on the block's far edges in its last cells.
fn block_cell(lx: f64, ly: f64) -> Option<usize> {
    let n = (SPAN - 1) as f64;
    if !(0.0..=n).contains(&lx) || !(0.0..=n).contains(&ly) {
        return None;
    }
    let (i, j) = (lx.floor().min(n - 1.0), ly.floor().min(n - 1.0));
    Some(j as usize * (SPAN - 1) + i as usize)
}

/// A triangle's plane over the grid, and whether a point lies in the triangle.
struct Plane {
    origin: (f64, f64, f64),
    slope: (f64, f64),
    /// Per edge: its inward normal and a point on it.
    edges: [(f64, f64, f64, f64); 3],
}

impl Plane {
    fn through(a: (f64, f64, f64), b: (f64, f64, f64), c: (f64, f64, f64)) -> Plane {
        let (ux, uy, uh) = (b.0 - a.0, b.1 - a.1, b.2 - a.2);
        let (vx, vy, vh) = (c.0 - a.0, c.1 - a.1, c.2 - a.2);
        let det = ux * vy - uy * vx;
        let slope = ((uh * vy - vh * uy) / det, (ux * vh - vx * uh) / det);
        let sign = det.signum();
        let edge = |p: (f64, f64, f64), q: (f64, f64, f64)| {
            (-(q.1 - p.1) * sign, (q.0 - p.0) * sign, p.0, p.1)
        };
        Plane {
            origin: a,
            slope,
            edges: [edge(a, b), edge(b, c), edge(c, a)],
        }
    }

    fn at(&self, x: f64, y: f64) -> f64 {
        self.origin.2 + (x - self.origin.0) * self.slope.0 + (y - self.origin.1) * self.slope.1
    }

    /// Whether `(x, y)` lies in the triangle or on its edges (within a millionth of a cell).
    fn holds(&self, x: f64, y: f64) -> bool {
        self.edges
            .iter()
            .all(|e| e.0 * (x - e.2) + e.1 * (y - e.3) >= -1e-6 * (e.0.abs() + e.1.abs()))
    }
}

/// A chunk of placed samples, row by row.
type Chunk = Arc<Vec<Placed>>;

/// Where a block's samples come from: placed one by one, or from the shared chunks (a whole
/// surface only: a window's chunk could reach past the window), the last chunk kept at hand.
struct Samples<'a> {
    block: &'a Block<'a>,
    face: u8,
    surface: &'a Surface,
    step: f64,
    /// The chunk last read, and its index.
    chunk: Option<(P, Chunk)>,
}

impl<'a> Samples<'a> {
    fn new(block: &'a Block<'a>, face: u8, surface: &'a Surface, step: f64) -> Self {
        Samples {
            block,
            face,
            surface,
            step,
            chunk: None,
        }
    }

    /// Sample `(sx, sy)` (in steps of the level sampled) placed on the block's level grid.
    fn at(&mut self, sx: i64, sy: i64) -> Placed {
        let Some(shared) = self.block.shared else {
            return place_sample(self.block, self.surface, self.face, (sx, sy), self.step);
        };
        let key = (sx.div_euclid(CHUNK), sy.div_euclid(CHUNK));
        if self.chunk.as_ref().is_none_or(|c| c.0 != key) {
            let (b, s, face, step) = (self.block, self.surface, self.face, self.step);
            let chunk = shared.chunk((b.tile.z, face, key.0, key.1), |x, y| {
                place_sample(b, s, face, (x, y), step)
            });
            self.chunk = Some((key, chunk));
        }
        let (_, chunk) = self.chunk.as_ref().expect("set above");
        let (i, j) = (sx.rem_euclid(CHUNK), sy.rem_euclid(CHUNK));
        chunk[(j * CHUNK + i) as usize]
    }
}

/// Sample `(sx, sy)` of `face` (in steps of `step`) placed on the level grid of `b`'s tile:
/// global grid x and y, and its height (raised onto the ellipsoid where the block's are).
fn place_sample(b: &Block<'_>, surface: &Surface, face: u8, (sx, sy): P, step: f64) -> Placed {
    let (x, y) = (sx as f64 * step, sy as f64 * step);
    let (h, _) = surface.height(face, x, y, b.coarsen)?;
    let ll = b.place.lat_lon(face, x, y);
    let h = match b.to_ellipsoid {
        true => h + crate::geoid::undulation(ll.lat, ll.lon),
        false => h,
    };
    let cell = 180.0 / (f64::from(1u32 << b.tile.z) * GRID as f64);
    Some(((ll.lon + 180.0) / cell, (ll.lat + 90.0) / cell, h))
}

/// Where each block cell's samples start in the sorted list (and the end, last).
fn cell_starts(found: &[(usize, (f64, f64, f64))], cells: usize) -> Vec<u32> {
    let mut start = vec![0u32; cells + 1];
    for f in found {
        start[f.0 + 1] += 1;
    }
    for c in 0..cells {
        start[c + 1] += start[c];
    }
    start
}

/// The samples sorted by cell, each cell's in the order found (a counting sort).
fn sorted_by_cell(found: Vec<(usize, (f64, f64, f64))>, start: &[u32]) -> Vec<(f64, f64, f64)> {
    let mut next: Vec<u32> = start.to_vec();
    let mut out = vec![(0.0, 0.0, 0.0); found.len()];
    for (c, s) in found {
        out[next[c] as usize] = s;
        next[c] += 1;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::super::diamond;
    use super::*;

    /// Every triangle of every diamond of a tile's vertices, in every vertex order.
    fn network_triangles() -> Vec<[P; 3]> {
        let mut out = Vec::new();
        for gy in GRID..=2 * GRID {
            for gx in GRID..=2 * GRID {
                let Some((tris, _)) = diamond(gx, gy) else {
                    continue;
                };
                for [a, b, c] in tris {
                    out.extend([[a, b, c], [b, a, c], [c, a, b], [a, c, b]]);
                }
            }
        }
        out
    }

    /// Points over `tri`'s box and one cell around it: a lattice of 1/7 cell, and the points
    /// a hair (1e-7 cell) either side of its edges.
    fn points_near(tri: [P; 3]) -> Vec<(f64, f64)> {
        let (x0, x1) = (
            tri.iter().map(|p| p.0).min().unwrap(),
            tri.iter().map(|p| p.0).max().unwrap(),
        );
        let (y0, y1) = (
            tri.iter().map(|p| p.1).min().unwrap(),
            tri.iter().map(|p| p.1).max().unwrap(),
        );
        let mut out = Vec::new();
        for j in 7 * (y0 - 1)..=7 * (y1 + 1) {
            for i in 7 * (x0 - 1)..=7 * (x1 + 1) {
                out.push((i as f64 / 7.0 + 0.01, j as f64 / 7.0 + 0.02));
            }
        }
        for (p, q) in [(tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])] {
            for t in 0..=16 {
                let (x, y) = (
                    p.0 as f64 + (q.0 - p.0) as f64 * f64::from(t) / 16.0,
                    p.1 as f64 + (q.1 - p.1) as f64 * f64::from(t) / 16.0,
                );
                for d in [-1e-7, 0.0, 1e-7] {
                    out.extend([(x + d, y), (x, y + d)]);
                }
            }
        }
        out
    }

    #[test]
    fn spans_visit_every_point_holds_admits() {
        let tris = network_triangles();
        assert!(tris.len() > 10_000, "{} triangles", tris.len());
        for tri in tris {
            let plane = Plane::through(
                (tri[0].0 as f64, tri[0].1 as f64, 1.0),
                (tri[1].0 as f64, tri[1].1 as f64, -2.0),
                (tri[2].0 as f64, tri[2].1 as f64, 0.5),
            );
            let spans = Spans::of(tri).expect("a network triangle's slopes are whole");
            let (y0, y1) = (
                tri.iter().map(|p| p.1).min().unwrap(),
                tri.iter().map(|p| p.1).max().unwrap(),
            );
            // Grid points: a row's span is exactly the points `holds` admits.
            for y in y0..=y1 {
                let (xa, xb) = spans.between(y, y);
                for x in xa - 3..=xb + 3 {
                    let admitted = plane.holds(x as f64, y as f64);
                    assert_eq!(
                        admitted,
                        (xa..=xb).contains(&x),
                        "{tri:?}: grid point ({x}, {y})"
                    );
                }
            }
            // Samples: every one `holds` admits is in a cell visited; cells counted as wholly
            // inside are.
            for (x, y) in points_near(tri) {
                let row = y.floor() as i64;
                if !(y0..y1).contains(&row) {
                    continue;
                }
                let (column, (xa, xb), (ia, ib)) = (
                    x.floor() as i64,
                    spans.between(row, row + 1),
                    spans.within(row),
                );
                if plane.holds(x, y) {
                    assert!(
                        (xa - 1..=xb).contains(&column),
                        "{tri:?}: sample ({x}, {y}) not visited"
                    );
                } else {
                    assert!(
                        !(ia..ib).contains(&column),
                        "{tri:?}: sample ({x}, {y}) outside, in a cell counted inside"
                    );
                }
            }
        }
    }
}
