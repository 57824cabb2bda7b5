//! The grid-aware token coder ([`CoderKind::AdaptiveGrid`](crate::entropy::CoderKind::AdaptiveGrid)):
//! [`super::tokens`]' record format, binarisation and coding order, with one more thing in
//! each cell's context that the decoder knows before it decodes the record: the **spread of
//! the cell's four corners** on the diamond's grid, `(|TL − BR| + |TR − BL|) / step` (both
//! diagonals' height differences, in quantizer steps). Where the grid is steep or rough the
//! prediction misses by more; the coded neighbours say so only after the fact, the corners
//! before.
//!
//! A quarter of the spread is added to the neighbourhood sum `s = 2|L| + 2|T| + |TL| + |TR|`
//! that picks the token coder's class and raw shift: no more models than the token coder, so
//! records of 4 096 values learn as fast as there. (Separate models per octave of the spread,
//! the context whose static entropy is lowest, learnt too slowly: `docs/RESULTS.md`.) Bands
//! other than cells (inner vertices, roots), and cells coded without their grid, add nothing:
//! their bytes are the token coder's.

use super::Scratch;
use super::tokens::{Activity, Flat, RecordEncoder, decode_record};
use super::{NCLASS, all_zero_checked};
use crate::CodecError;
use crate::entropy::{Band, BandKind, BandMut, DecodeLimits, ParentGrid};

#[cfg(test)]
#[path = "grid_tests.rs"]
pub(super) mod tests;

/// The spread is added to the neighbourhood sum divided by this (measured: 1, 2, 4 and 8, and
/// separate model sets per octave of the spread, `docs/RESULTS.md`).
const SPREAD_DIVISOR: u64 = 4;
/// What the spread may add to the sum: beyond it every class is the last one anyway.
const MAX_ADD: u64 = 4096;

/// What the corners of cell `(i, j)` of an `n × n` grid add to its neighbourhood sum: the
/// spread `(|TL − BR| + |TR − BL|) / step` divided by [`SPREAD_DIVISOR`], at most [`MAX_ADD`].
#[inline]
fn corner_term(g: &[i32], n: usize, i: usize, j: usize, step: i64) -> u16 {
    let at = |i: usize, j: usize| i64::from(g[j * n + i]);
    let (tl, tr, bl, br) = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
    let spread = ((tl - br).abs() + (tr - bl).abs()) / step;
    (spread as u64 / SPREAD_DIVISOR).min(MAX_ADD) as u16
}

/// Per cell of a diamond: what its corners add to its neighbourhood sum. Kept between records
/// (in [`crate::entropy::DecodeScratch`]) so that decoding does not allocate.
#[derive(Debug, Default)]
pub(crate) struct CellActivity {
    adds: Vec<u16>,
}

impl CellActivity {
    /// Fills the terms of the `(n − 1)²` cells of `grid`.
    pub(super) fn fill(&mut self, grid: &ParentGrid<'_>) {
        let (n, step) = (grid.n, i64::from(grid.step.max(1)));
        let m = n.saturating_sub(1);
        self.adds.clear();
        for j in 0..m {
            self.adds
                .extend((0..m).map(|i| corner_term(grid.values, n, i, j, step)));
        }
    }

    pub(super) fn activity(&self) -> Corners<'_> {
        Corners(&self.adds)
    }
}

/// [`Activity`] from the cells' corner terms: the neighbourhood sum plus the cell's term, so
/// that the class and the raw shift both see the grid.
#[derive(Clone, Copy)]
pub(super) struct Corners<'a>(&'a [u16]);

impl Activity for Corners<'_> {
    #[inline(always)]
    fn context(self, index: usize, sum: u32) -> (u32, usize) {
        (sum + u32::from(self.0[index]), 0)
    }
}

/// Whether a band of `kind`, `width × height`, holds the cells whose corners `g` holds.
pub(super) fn is_cells_of(kind: BandKind, width: usize, height: usize, g: &ParentGrid<'_>) -> bool {
    kind == BandKind::Cells && width + 1 == g.n && height + 1 == g.n
}

/// Encodes `bands` as one record appended to `out`, the cell bands' contexts from `grid`.
pub(crate) fn encode_bands(bands: &[Band<'_>], grid: Option<ParentGrid<'_>>, out: &mut Vec<u8>) {
    if all_zero_checked(bands) {
        return;
    }
    let mut cells = CellActivity::default();
    let mut record = RecordEncoder::<NCLASS>::new();
    for b in bands {
        match grid.as_ref() {
            Some(g) if is_cells_of(b.kind, b.width, b.height, g) => {
                cells.fill(g);
                record.band(b, cells.activity());
            }
            _ => record.band(b, Flat),
        }
    }
    record.finish(out);
}

/// Decodes one record written by [`encode_bands`] with the same `grid` into `bands`.
pub(crate) fn decode_bands(
    bytes: &[u8],
    bands: &mut [BandMut<'_>],
    grid: Option<ParentGrid<'_>>,
    limits: DecodeLimits,
    s: &mut Scratch,
    cells: &mut CellActivity,
) -> Result<(), CodecError> {
    decode_record::<NCLASS>(bytes, bands, s, |_, record, b| match grid.as_ref() {
        Some(g) if is_cells_of(b.kind, b.width, b.height, g) => {
            cells.fill(g);
            record.band(b, limits, cells.activity())
        }
        _ => record.band(b, limits, Flat),
    })
}
