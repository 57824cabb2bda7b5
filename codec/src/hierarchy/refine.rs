//! The two per-diamond steps shared by encoder, decoder and renderer: gathering a diamond's grid
//! from its parents, and refining it with a record.

use super::CodecParams;
use super::gather_runs::{half_map, half_runs};
use super::mask::decode_mask;
use super::reconstruct::{reconstruct_cells, reconstruct_vertices};
use crate::CodecError;
use crate::entropy::{
    BandKind, BandMut, DecodeLimits, DecodeScratch, ParentGrid, decode_bands_on_grid_with,
};
use crate::geometry::{Diagonal, DiamondId, Domain, Half, IndexMap};
use crate::lifting::Alpha;
use crate::quant::Quantizer;

/// The level-`l+1` values a refinement produces on a level-`l` diamond's square: the values of
/// its `N²` vertices (changed only at inner vertices and only when α = ½) and of its `(N−1)²`
/// cell centres. On the square's `(2N−1)²` half-step grid, vertex `(i, j)` sits at `(2i, 2j)`
/// and cell centre `(i, j)` at `(2i+1, 2j+1)`; the other half-step points (edge midpoints) are
/// finer than level `l+1` and not stored. A child's grid steps are the half-step grid's
/// diagonals, so gathering one reads vertices and cells alternately, each at a fixed stride.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Refined {
    n: usize,
    /// The vertices (`N²`, row-major), then the cells (`(N−1)²`, row-major).
    values: Vec<i32>,
    /// Validity of the `(2N−1)²` half-step points from the record's nodata mask, trusted only
    /// at vertices and cell centres inside the data rectangle; `None` when all of those are
    /// valid.
    valid: Option<Vec<bool>>,
}

impl Refined {
    /// From vertex values (`N²`, row-major) and cell values (`(N−1)²`, row-major).
    pub fn from_parts(n: usize, vertices: &[i32], cells: &[i32]) -> Self {
        assert!(vertices.len() == n * n && cells.len() == (n - 1) * (n - 1));
        let mut values = Vec::with_capacity(vertices.len() + cells.len());
        values.extend_from_slice(vertices);
        values.extend_from_slice(cells);
        Self {
            n,
            values,
            valid: None,
        }
    }

    /// Attaches the validity of the `(2N−1)²` half-step points (`None`: all valid).
    pub fn with_validity(mut self, valid: Option<Vec<bool>>) -> Self {
        let side = 2 * self.n - 1;
        assert!(valid.as_ref().is_none_or(|v| v.len() == side * side));
        self.valid = valid;
        self
    }

    /// The half-step validity, `None` when every point this refinement produced had data.
    pub fn validity(&self) -> Option<&[bool]> {
        self.valid.as_deref()
    }

    /// The `N²` refined vertex values, row-major (with α = 1 the grid the diamond was refined
    /// from).
    pub(crate) fn vertices(&self) -> &[i32] {
        &self.values[..self.n * self.n]
    }

    /// The buffer of the values, for reuse.
    pub(crate) fn into_values(self) -> Vec<i32> {
        self.values
    }

    /// The values: the `N²` vertices, then the `(N−1)²` cells, row-major.
    pub(crate) fn values(&self) -> &[i32] {
        &self.values
    }

    /// From [`Refined::values`] of a grid of side `n`; `None` for another count.
    pub(crate) fn from_values(n: usize, values: Vec<i32>) -> Option<Self> {
        (n >= 2 && values.len() == n * n + (n - 1) * (n - 1)).then_some(Self {
            n,
            values,
            valid: None,
        })
    }

    /// Grid side `N` of the diamond.
    pub fn n(&self) -> usize {
        self.n
    }

    /// The refined value of vertex `(i, j)`.
    pub fn vertex(&self, i: usize, j: usize) -> i32 {
        assert!(i < self.n && j < self.n);
        self.values[j * self.n + i]
    }

    /// The value of cell centre `(i, j)`.
    pub fn cell(&self, i: usize, j: usize) -> i32 {
        let m = self.n - 1;
        assert!(i < m && j < m);
        self.values[self.n * self.n + j * m + i]
    }

    /// The `count` values at half-step points `(a, b), (a + 2, b), …` (vertices where both are
    /// even, cell centres where both are odd): one contiguous run.
    fn row_run(&self, a: i64, b: i64, count: usize) -> &[i32] {
        let n = self.n;
        let (vertices, cells) = self.values.split_at(n * n);
        let start = if b % 2 == 0 {
            &vertices[b as usize / 2 * n + a as usize / 2..]
        } else {
            &cells[(b as usize - 1) / 2 * (n - 1) + (a as usize - 1) / 2..]
        };
        &start[..count]
    }

    /// `out[k]` = `f` of the value at half-step point `(a + k·da, b + k·db)`, `da` and `db` ±1
    /// (a diagonal, through vertices and cell centres alternately): what a caller that converts
    /// the values (e.g. into an output raster's samples) reads in one pass, without a copy of
    /// the diagonal in between.
    pub(crate) fn map_diagonal<T>(
        &self,
        a: i64,
        b: i64,
        da: i64,
        db: i64,
        out: &mut [T],
        f: impl Fn(i32) -> T,
    ) {
        assert!(
            da.abs() == 1 && db.abs() == 1 && a % 2 == b % 2,
            "a diagonal through vertices and cell centres"
        );
        // Vertices and cells alternate along a diagonal; every second step each moves by one
        // step of its own grid.
        let n = self.n as i64;
        let (vertices, cells) = self.values.split_at(self.n * self.n);
        let vertex = |a: i64, b: i64| b / 2 * n + a / 2;
        let cell = |a: i64, b: i64| (b - 1) / 2 * (n - 1) + (a - 1) / 2;
        let (vertex_stride, cell_stride) = (db * n + da, db * (n - 1) + da);
        let (a1, b1) = (a + da, b + db);
        // The first stream starts at (a, b), the second at the next point (an index only when
        // the diagonal has one).
        let ((first, k0, d0), (second, k1, d1)) = if a % 2 == 0 {
            (
                (vertices, vertex(a, b), vertex_stride),
                (cells, cell(a1, b1), cell_stride),
            )
        } else {
            (
                (cells, cell(a, b), cell_stride),
                (vertices, vertex(a1, b1), vertex_stride),
            )
        };
        let (even, odd) = (out.len().div_ceil(2), out.len() / 2);
        map_strided(strided(first, k0, d0, even), out.iter_mut().step_by(2), &f);
        map_strided(
            strided(second, k1, d1, odd),
            out.iter_mut().skip(1).step_by(2),
            &f,
        );
    }

    /// [`crate::cache::prefetch`] of [`Refined::row_run`].
    pub(super) fn prefetch_row(&self, a: i64, b: i64, count: usize) {
        crate::cache::prefetch(self.row_run(a, b, count));
    }

    /// The value at half-step point `(a, b)`, a vertex (both even) or a cell centre (both odd).
    fn at_half_step(&self, a: i64, b: i64) -> i32 {
        assert_eq!(a % 2, b % 2, "({a}, {b}) is an edge midpoint");
        if a % 2 == 0 {
            self.vertex((a / 2) as usize, (b / 2) as usize)
        } else {
            self.cell((a / 2) as usize, (b / 2) as usize)
        }
    }
}

/// Gathers the `N × N` grid of a non-root diamond from its parents' refinements.
///
/// `parents[h]` is the refinement of the parent on half `h` ([`Domain::parents`] order); it may
/// be `None` only where that parent does not exist (a diamond on the domain's edge), and then
/// the missing half is the mirror image of the present one across the split diagonal — the
/// symmetric extension the paper uses for incomplete diamonds. On a cube-sphere each half is
/// read in its parent's face frame ([`Domain::grid_in_parent_frame`]), so a half lying across a
/// cube edge comes from the neighbouring face's parent.
///
/// # Panics
/// If both parents are missing, or if the two parents disagree on the split diagonal (the
/// parents' sides are never changed by a refinement, so a disagreement is a bug, not bad data).
pub fn gather(domain: &Domain, id: DiamondId, parents: [Option<&Refined>; 2], out: &mut [i32]) {
    gather_values(domain, id, parents, true, out);
}

/// The validity of `id`'s `N × N` grid, gathered from its parents' refinements like
/// [`gather`] gathers heights: `None` when no parent has a mask (all valid). Trusted only at
/// points inside the data rectangle. Unlike heights, the parents may differ on the diagonal
/// outside the data rectangle (don't care), so that is not checked.
pub fn gather_validity(
    domain: &Domain,
    id: DiamondId,
    parents: [Option<&Refined>; 2],
) -> Option<Vec<bool>> {
    let layout = domain.layout();
    if parents.iter().flatten().all(|p| p.valid.is_none()) {
        return None;
    }
    let n = layout.n();
    let side = 2 * n - 1;
    let all = vec![true; side * side];
    let sources = parents.map(|p| {
        p.map(|p| HalfStepGrid {
            side,
            values: p.valid.as_deref().unwrap_or(&all),
        })
    });
    let mut out = vec![true; n * n];
    gather_values(domain, id, sources, false, &mut out);
    Some(out)
}

/// Where [`gather_values`] reads a parent's values on its half-step grid.
trait HalfStepSource<T>: Copy {
    /// The value at half-step point `(a, b)`.
    fn at(&self, a: i64, b: i64) -> T;
    /// The `k`-th place of `out` (for each `k < count`) gets the value at `(a + 2k, b)`: a run
    /// of one row of the half-step grid, all vertices or all cell centres, read in memory
    /// order.
    fn read_row<'o>(&self, a: i64, b: i64, count: usize, out: impl Iterator<Item = &'o mut T>)
    where
        T: 'o;
}

/// Values on every point of a `side × side` half-step grid, row-major.
#[derive(Clone, Copy)]
struct HalfStepGrid<'a, T> {
    side: usize,
    values: &'a [T],
}

impl<T: Copy> HalfStepSource<T> for HalfStepGrid<'_, T> {
    fn at(&self, a: i64, b: i64) -> T {
        self.values[b as usize * self.side + a as usize]
    }

    fn read_row<'o>(&self, a: i64, b: i64, count: usize, out: impl Iterator<Item = &'o mut T>)
    where
        T: 'o,
    {
        let start = b as usize * self.side + a as usize;
        let run = &self.values[start..start + 2 * count.max(1) - 1];
        out.zip(run.iter().step_by(2)).for_each(|(o, &v)| *o = v);
    }
}

impl HalfStepSource<i32> for &Refined {
    fn at(&self, a: i64, b: i64) -> i32 {
        self.at_half_step(a, b)
    }

    fn read_row<'o>(&self, a: i64, b: i64, count: usize, out: impl Iterator<Item = &'o mut i32>) {
        assert_eq!(a % 2, b % 2, "a row of vertices or of cell centres");
        // Vertices sit at even (a, b), cell centres at odd: either way a row's run is contiguous.
        out.zip(self.row_run(a, b, count))
            .for_each(|(o, &v)| *o = v);
    }
}

/// The `count` indices `start, start + stride, …` of `values` as one slice (checked once) and
/// the step through it: `(slice, step, backwards)`. Empty when `count` is 0.
fn strided(values: &[i32], start: i64, stride: i64, count: usize) -> (&[i32], usize, bool) {
    let (span, step, backwards) = strided_span(values.len(), start, stride, count);
    (&values[span], step, backwards)
}

/// The index range that holds the `count` indices `start, start + stride, …` (of a slice of
/// `len`, checked), the step through it and whether it is walked from its end. Empty when
/// `count` is 0.
fn strided_span(
    len: usize,
    start: i64,
    stride: i64,
    count: usize,
) -> (std::ops::Range<usize>, usize, bool) {
    if count == 0 {
        return (0..0, 1, false);
    }
    let step = stride.unsigned_abs() as usize;
    let span = step * (count - 1);
    let start = start as usize;
    let (first, last, backwards) = if stride >= 0 {
        (start, start + span, false)
    } else {
        (start.wrapping_sub(span), start, true)
    };
    assert!(
        first <= last && last < len,
        "a strided run of {count} from {start} by {stride} outside {len} values"
    );
    (first..last + 1, step.max(1), backwards)
}

/// Copies every `step`-th value of a [`strided`] slice (from its end when `backwards`) into
/// `out`: no bounds check per value.
fn map_strided<'a, T: 'a>(
    (values, step, backwards): (&[i32], usize, bool),
    out: impl Iterator<Item = &'a mut T>,
    f: &impl Fn(i32) -> T,
) {
    if backwards {
        out.zip(values.iter().rev().step_by(step))
            .for_each(|(o, &v)| *o = f(v));
    } else {
        out.zip(values.iter().step_by(step))
            .for_each(|(o, &v)| *o = f(v));
    }
}

/// [`gather`] over any per-point values of the parents' half-step grids.
fn gather_values<T: Copy + PartialEq + std::fmt::Debug, G: HalfStepSource<T>>(
    domain: &Domain,
    id: DiamondId,
    parents: [Option<G>; 2],
    check_diagonal: bool,
    out: &mut [T],
) {
    let layout = domain.layout();
    let n = layout.n();
    assert_eq!(out.len(), n * n);
    assert!(
        parents.iter().any(Option::is_some),
        "{id} has no parent to gather from"
    );
    let diag = layout.diagonal(id);
    let ids = domain.parents(id);
    let mut maps = [None, None];
    for (h, half) in Half::BOTH.into_iter().enumerate() {
        let Some(parent) = parents[h] else { continue };
        let pid = ids[h].expect("a refinement was passed for a parent that does not exist");
        // In the parent's face frame: on a cube-sphere a half may lie across a face edge.
        let m = half_map(domain, id, half, pid).expect("child grid maps into its parent");
        if check_diagonal && maps.iter().any(Option::is_some) {
            // The diagonal of `id` was written from the first parent: the second must agree.
            for j in 0..n {
                let d = match diag {
                    Diagonal::Main => j,
                    Diagonal::Anti => n - 1 - j,
                };
                let (a, b) = m.apply(d as i64, j as i64);
                let v = parent.at(a, b);
                assert_eq!(
                    out[j * n + d],
                    v,
                    "parents of {id} disagree on its diagonal"
                );
            }
        }
        copy_half(&m, diag, half, n, parent, out);
        maps[h] = Some((parent, m));
    }
    // A half whose parent is missing is the mirror image of the other half across the split
    // diagonal (the symmetric extension of incomplete diamonds): read from the present parent
    // through the mirror, not transposed inside `out` (a column walk).
    for (h, half) in Half::BOTH.into_iter().enumerate() {
        if maps[h].is_some() {
            continue;
        }
        let (parent, m) = maps[1 - h].expect("one parent is present");
        copy_half(&mirrored(&m, diag, n), diag, half, n, parent, out);
    }
}

/// `m` composed with the reflection across the split diagonal `diag` of an `n × n` grid: where
/// the mirror image of child index `(i, j)` lands in the parent.
fn mirrored(m: &IndexMap, diag: Diagonal, n: usize) -> IndexMap {
    match diag {
        // (i, j) ↦ (j, i)
        Diagonal::Main => IndexMap {
            a0: m.a0,
            ai: m.aj,
            aj: m.ai,
            b0: m.b0,
            bi: m.bj,
            bj: m.bi,
        },
        // (i, j) ↦ (n − 1 − j, n − 1 − i)
        Diagonal::Anti => {
            let k = (n - 1) as i64;
            IndexMap {
                a0: m.a0 + (m.ai + m.aj) * k,
                ai: -m.aj,
                aj: -m.ai,
                b0: m.b0 + (m.bi + m.bj) * k,
                bi: -m.bj,
                bj: -m.bi,
            }
        }
    }
}

/// Copies the points of `half` (split diagonal included) of a child's `n × n` grid from a
/// parent's half-step grid through `m`, reading the parent in memory order ([`half_runs`]).
fn copy_half<T: Copy, G: HalfStepSource<T>>(
    m: &IndexMap,
    diag: Diagonal,
    half: Half,
    n: usize,
    parent: G,
    out: &mut [T],
) {
    half_runs(m, diag, half, n, |run| {
        // The run's places in `out`, sliced once: no bounds check per value.
        let (places, step, backwards) = strided_span(out.len(), run.start, run.out_step, run.count);
        let places = &mut out[places];
        if backwards {
            parent.read_row(
                run.a,
                run.b,
                run.count,
                places.iter_mut().rev().step_by(step),
            );
        } else {
            parent.read_row(run.a, run.b, run.count, places.iter_mut().step_by(step));
        }
    });
}

/// One half of a child's `N × N` grid (split diagonal included) as a parent's refinement holds
/// it: what [`gather`] copies from that parent, read on demand instead, so that a caller can put
/// the child's points straight where it wants them (e.g. an output raster) without gathering the
/// child's grid first. Child point `(i, j)` of the half is the parent's half-step value at
/// `map.apply(i, j)`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ChildHalf<'a> {
    /// The child.
    pub(crate) child: DiamondId,
    parent: &'a Refined,
    map: IndexMap,
    diag: Diagonal,
    half: Half,
}

impl<'a> ChildHalf<'a> {
    /// The half of `child` on parent `parent_id`'s side (`half`), whose refinement is `parent`.
    pub(crate) fn new(
        domain: &Domain,
        child: DiamondId,
        half: Half,
        parent_id: DiamondId,
        parent: &'a Refined,
    ) -> Self {
        let layout = domain.layout();
        let map =
            half_map(domain, child, half, parent_id).expect("child grid maps into its parent");
        Self {
            child,
            parent,
            map,
            diag: layout.diagonal(child),
            half,
        }
    }

    /// The columns `lo..=hi` of child row `j` on this half.
    pub(crate) fn row_range(&self, n: usize, j: usize) -> (usize, usize) {
        half_range(self.diag, self.half, n, j)
    }

    /// `out[k]` = `f` of child point `(i + k, j)` (the points must lie on this half): the row
    /// converted as it is read, straight into where the caller wants it (one pass along the
    /// parent's diagonal, no copy of it in between).
    pub(crate) fn map_row<T>(&self, i: usize, j: usize, out: &mut [T], f: impl Fn(i32) -> T) {
        let m = &self.map;
        let (a, b) = m.apply(i as i64, j as i64);
        self.parent.map_diagonal(a, b, m.ai, m.bi, out, f);
    }
}

/// A diamond's `N × N` grid joined from its two half-grids, as [`gather`] would give it from
/// the parents those halves were gathered from: `halves[h]` is the grid gathered from parent `h`
/// alone (its own half, split diagonal included, and the mirror image of it on the other half),
/// `None` where that parent does not exist. Each row of a half is one contiguous copy, which is
/// what makes this cheaper than gathering again from the parents' half-step grids (read on
/// diagonals, cold in cache).
///
/// Where both halves exist the diagonal is taken from `halves[1]`; heights gathered from a
/// diamond's parents agree there (the parents' sides are never changed by a refinement), a
/// validity may not outside the data rectangle (don't care), as in [`gather_validity`].
///
/// # Panics
/// If both halves are missing or a half is not `N × N`.
pub fn join_halves<T: Copy + PartialEq + std::fmt::Debug>(
    diag: Diagonal,
    n: usize,
    halves: [Option<&[T]>; 2],
    out: &mut [T],
) {
    assert_eq!(out.len(), n * n);
    match halves {
        [None, None] => panic!("no half to join"),
        [Some(one), None] | [None, Some(one)] => out.copy_from_slice(one),
        [Some(_), Some(_)] => {
            for (h, half) in Half::BOTH.into_iter().enumerate() {
                let grid = halves[h].expect("both halves");
                assert_eq!(grid.len(), n * n);
                for j in 0..n {
                    let (lo, hi) = half_range(diag, half, n, j);
                    let row = j * n;
                    out[row + lo..=row + hi].copy_from_slice(&grid[row + lo..=row + hi]);
                }
            }
        }
    }
}

/// Fills each half whose parent is missing (`present[h]` false) with the mirror image of the
/// other half across the split diagonal: the symmetric extension of incomplete diamonds.
pub(crate) fn mirror_missing_halves<T: Copy>(
    diag: Diagonal,
    n: usize,
    present: [bool; 2],
    out: &mut [T],
) {
    for (h, half) in Half::BOTH.into_iter().enumerate() {
        if present[h] {
            continue;
        }
        for j in 0..n {
            let (lo, hi) = half_range(diag, half, n, j);
            for i in lo..=hi {
                let (mi, mj) = match diag {
                    Diagonal::Main => (j, i),
                    Diagonal::Anti => (n - 1 - j, n - 1 - i),
                };
                out[j * n + i] = out[mj * n + mi];
            }
        }
    }
}

/// Column range `lo..=hi` of row `j` in one half (diagonal included).
pub(crate) fn half_range(diag: Diagonal, half: Half, n: usize, j: usize) -> (usize, usize) {
    match (diag, half) {
        (Diagonal::Main, Half::Positive) => (j, n - 1),
        (Diagonal::Main, Half::Negative) => (0, j),
        (Diagonal::Anti, Half::Positive) => (n - 1 - j, n - 1),
        (Diagonal::Anti, Half::Negative) => (0, n - 1 - j),
    }
}

/// Scratch buffers for [`refine`], reused across calls to avoid allocation per diamond.
#[derive(Debug, Default)]
pub struct RefineScratch {
    dc: Vec<i32>,
    dv: Vec<i32>,
    cells: Vec<i32>,
    vertices: Vec<i32>,
    /// Inner-vertex predictions (α = ½).
    vpred: Vec<i32>,
    entropy: DecodeScratch,
}

/// Refines a diamond: decodes its record and synthesises its level-`l+1` values from `p`, its
/// reconstructed `N × N` grid (eqs. 6 and 8); `q` is the quantizer of the diamond's level
/// ([`CodecParams::quantizer_at`]).
///
/// Never panics on bad bytes; a record whose values would leave the representable range is
/// [`CodecError::Corrupt`].
pub fn refine(
    params: &CodecParams,
    q: Quantizer,
    p: &[i32],
    record: &[u8],
    scratch: &mut RefineScratch,
) -> Result<Refined, CodecError> {
    let valid = synthesise(params, q, p, record, scratch)?;
    // With α = 1 a refinement leaves every vertex as it was: interleave `p` itself.
    let vertices = if params.alpha == Alpha::Half {
        &scratch.vertices[..]
    } else {
        p
    };
    Ok(Refined::from_parts(params.layout().n(), vertices, &scratch.cells).with_validity(valid))
}

/// [`refine`] taking the grid by value: with α = 1 the refinement's vertices are the grid
/// itself, so its cells are appended to `grid` (allocate it with room for `(N−1)²` more to
/// avoid a reallocation) instead of copying both into a new buffer. Gives back `grid`
/// unchanged with the error when the record is corrupt. The values are [`refine`]'s exactly.
pub(crate) fn refine_owned(
    params: &CodecParams,
    q: Quantizer,
    mut grid: Vec<i32>,
    record: &[u8],
    scratch: &mut RefineScratch,
) -> Result<Refined, (Vec<i32>, CodecError)> {
    if params.alpha == Alpha::Half {
        return refine(params, q, &grid, record, scratch).map_err(|e| (grid, e));
    }
    let valid = match synthesise(params, q, &grid, record, scratch) {
        Ok(valid) => valid,
        Err(e) => return Err((grid, e)),
    };
    let n = params.layout().n();
    assert_eq!(grid.len(), n * n, "a diamond's grid is N × N");
    grid.extend_from_slice(&scratch.cells);
    Ok(Refined {
        n,
        values: grid,
        valid: None,
    }
    .with_validity(valid))
}

/// The part of [`refine`] that decodes the record and computes the new values into
/// `scratch.cells` (and, with α = ½, the updated vertices into `scratch.vertices`); gives the
/// record's half-step validity (`None`: all valid).
fn synthesise(
    params: &CodecParams,
    q: Quantizer,
    p: &[i32],
    record: &[u8],
    scratch: &mut RefineScratch,
) -> Result<Option<Vec<bool>>, CodecError> {
    let n = params.layout().n();
    let valid = decode_residuals(params, q, p, record, scratch)?;
    let step = i64::from(q.step());
    let RefineScratch {
        dc,
        dv,
        cells,
        vertices,
        vpred,
        ..
    } = scratch;
    reconstruct_cells(p, n, dc, step, cells)?;
    if params.alpha == Alpha::Half {
        reconstruct_vertices(p, n, cells, dv, step, vpred, vertices)?;
    }
    Ok(valid)
}

/// The record's nodata mask (`None`: all valid) and its residual bands, decoded into
/// `scratch.dc` (cells) and, with α = ½, `scratch.dv` (inner vertices); `p` is the diamond's
/// grid, which a grid-aware coder's contexts read.
fn decode_residuals(
    params: &CodecParams,
    q: Quantizer,
    p: &[i32],
    record: &[u8],
    scratch: &mut RefineScratch,
) -> Result<Option<Vec<bool>>, CodecError> {
    let n = params.layout().n();
    let m = n - 1;
    let RefineScratch {
        dc, dv, entropy, ..
    } = scratch;
    dc.resize(m * m, 0);
    dv.resize((n - 2) * (n - 2), 0);
    let half = params.alpha == Alpha::Half;
    let (valid, record) = if params.nodata_mask && !record.is_empty() {
        let side = 2 * n - 1;
        let (mask, used) = decode_mask(side, side, record)?;
        // All valid is the common case: keep no bitmap for it.
        (mask.contains(&false).then_some(mask), &record[used..])
    } else {
        (None, record)
    };
    let mut bands = [
        BandMut {
            kind: BandKind::Cells,
            width: m,
            height: m,
            values: dc.as_mut_slice(),
        },
        BandMut {
            kind: BandKind::Vertices,
            width: n - 2,
            height: n - 2,
            values: dv.as_mut_slice(),
        },
    ];
    let grid = ParentGrid {
        values: p,
        n,
        step: q.step(),
    };
    decode_bands_on_grid_with(
        params.coder,
        record,
        &mut bands[..1 + usize::from(half)],
        Some(grid),
        DecodeLimits::default(),
        entropy,
    )?;
    Ok(valid)
}

#[cfg(test)]
#[path = "refine_tests.rs"]
mod tests;
