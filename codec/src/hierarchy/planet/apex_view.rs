//! What the apex reads of the lattice ([`ApexView`]): every tile thinned to each stride an
//! apex level reads, written once as the tiles are painted and read back by the apex's runs.
//!
//! Apex level `l` reads the points `2^(K − ⌈(l + 1)/2⌉)` apart (the next level's vertices,
//! [`super::apex`]), so the finest level above the cut `c` reads every `2^(K − ⌈c/2⌉)`-th point
//! and the coarser levels a subset of those. A tile's points at a stride are the same whether
//! painted at that stride or thinned from the tile at its own ([`super::PlanetTiles::tile`]),
//! so each tile is thinned to every stride the apex reads as soon as it is painted (the
//! outline paints every tile once, in order: [`ApexViewWriter::put`]), and the apex paints
//! nothing: its levels, which each read tiles all over the planet, no longer ask the inputs
//! for their samples level after level. Each stride's tiles go to their own spill
//! ([`super::spill`]: past a few MiB, an unlinked temporary file), so that a run's tiles, near
//! each other, are read back in a few reads.

use std::collections::{BTreeSet, HashMap};
use std::fmt;
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

use super::grid::tiles_across;
use super::spill::{Spill, Spilled};
use super::tile_source::PlanetTiles;
use super::{PlanetGrid, PlanetTile};
use crate::CodecError;
use crate::geometry::Domain;
use crate::quant::HeightGrid;

/// What the temporary files hold, for their errors.
const WHAT: &str = "the planet apex's view of the tiles";

/// Bytes of the view kept in memory (over all strides) before it goes to temporary files.
pub const IN_MEMORY_BYTES: usize = 4 << 20;

/// Bytes read back at once ([`ApexView::tiles`]): tiles of one stride lying within this span
/// of its spill (with gaps of at most [`GAP_BYTES`] between them) are read in one read.
const READ_BYTES: u64 = 1 << 20;

/// The largest gap between two tiles read in one read ([`ApexView::tiles`]).
const GAP_BYTES: u64 = 16 << 10;

/// Bytes of a tile's record before its points: stride, rectangle, whether it has classes.
const HEADER_BYTES: usize = 4 + 32 + 1;

/// No tile kept (in [`ApexViewWriter`]'s per-tile strides).
const NOT_KEPT: u8 = u8::MAX;

/// Set in a tile's kept stride when it carries resolution classes.
const HAS_CLASS: u8 = 0x80;

/// Strides (`log2`) a view can hold: 0 to 31 ([`PlanetTile::new`]).
const STRIDES: usize = 32;

/// Where each tile's record of one stride went: an offset per tile (`u64::MAX`: none).
struct StrideSpill {
    spill: Spill,
    at: Vec<u64>,
}

/// The lattice as the apex reads it, being written ([`ApexViewWriter::put`]) from any thread.
pub struct ApexViewWriter {
    /// `log2` of the finest stride the apex reads (at most the tile side's).
    finest: u32,
    tile_log2: u32,
    /// Tiles across a face, and their rectangles (row-major, the same on every face).
    across: usize,
    rects: Vec<(i64, i64, i64, i64)>,
    /// Per tile (`face · tiles per face + index`): the stride of its finest record, with
    /// [`HAS_CLASS`]; [`NOT_KEPT`] until put.
    kept: Vec<AtomicU8>,
    strides: Vec<Mutex<Option<StrideSpill>>>,
    /// Bytes of each stride's records kept in memory before they go to a temporary file.
    in_memory: usize,
}

impl ApexViewWriter {
    /// An empty view of the planet `domain` in tiles of `2^tile_log2` steps for an apex cut at
    /// `cut` (the levels above it).
    pub fn new(domain: &Domain, tile_log2: u32, cut: u8) -> Self {
        let k = domain.layout().k();
        let finest = k.saturating_sub(u32::from(cut).div_ceil(2)).min(tile_log2);
        let side = domain.cube().map_or(0, |c| c.side());
        let rects = PlanetGrid::tile_rects(domain, tile_log2);
        let tiles = usize::from(domain.faces()) * rects.len();
        Self {
            finest,
            tile_log2,
            across: tiles_across(side, tile_log2),
            kept: (0..tiles).map(|_| AtomicU8::new(NOT_KEPT)).collect(),
            rects,
            strides: (0..STRIDES).map(|_| Mutex::new(None)).collect(),
            in_memory: IN_MEMORY_BYTES / 8,
        }
    }

    /// [`ApexViewWriter::new`] keeping at most `in_memory` bytes of each stride's records in
    /// memory.
    #[cfg(test)]
    fn with_in_memory(domain: &Domain, tile_log2: u32, cut: u8, in_memory: usize) -> Self {
        Self {
            in_memory,
            ..Self::new(domain, tile_log2, cut)
        }
    }

    /// The stride (`log2`) every tile should be put at or finer: the finest the apex reads.
    pub fn finest_stride(&self) -> u32 {
        self.finest
    }

    /// Keeps tile `index` of `face` (at its own stride, or any at least as fine as
    /// [`ApexViewWriter::finest_stride`]): its points on each stride the apex may read.
    pub fn put(&self, face: u8, index: usize, t: &PlanetTile) -> Result<(), CodecError> {
        let slot = usize::from(face) * self.rects.len() + index;
        let (Some(kept), Some(&rect)) = (self.kept.get(slot), self.rects.get(index)) else {
            return Err(CodecError::invalid(format!(
                "{WHAT}: face {face} has no tile {index}"
            )));
        };
        if t.rect != rect {
            return Err(CodecError::invalid(format!(
                "{WHAT}: face {face} tile {index} covers {:?}, not {rect:?}",
                t.rect
            )));
        }
        let base = t.stride.max(self.finest);
        if base >= STRIDES as u32 {
            return Err(CodecError::invalid(format!(
                "{WHAT}: face {face} tile {index} at stride 2^{}",
                t.stride
            )));
        }
        let mut bytes = Vec::new();
        for stride in base..=base.max(self.tile_log2) {
            thinned_bytes(t, stride, &mut bytes);
            let mut held = self.strides[stride as usize].lock().expect("a view");
            let s = held.get_or_insert_with(|| StrideSpill {
                spill: Spill::new(WHAT, self.in_memory),
                at: vec![u64::MAX; self.kept.len()],
            });
            s.at[slot] = s.spill.put(&bytes)?;
        }
        let class = if t.class.is_some() { HAS_CLASS } else { 0 };
        kept.store(base as u8 | class, Ordering::Relaxed);
        Ok(())
    }

    /// Puts every tile of the planet `tiles` hands out, asked for at the finest stride the apex
    /// reads (on the current rayon pool): for a source whose tiles were not put as they were
    /// painted.
    pub fn put_all(&self, tiles: &dyn PlanetTiles, faces: u8) -> Result<(), CodecError> {
        let per_face = self.rects.len();
        (0..usize::from(faces) * per_face)
            .into_par_iter()
            .try_for_each(|i| {
                let (face, index) = ((i / per_face) as u8, i % per_face);
                self.put(face, index, &*tiles.tile(face, index, self.finest)?)
            })
    }

    /// The view written, to be read back.
    pub fn finish(self) -> Result<ApexView, CodecError> {
        let strides = self
            .strides
            .into_iter()
            .map(|s| {
                let s = s.into_inner().expect("a view");
                s.map(|s| Ok::<_, CodecError>((s.spill.finish()?, s.at)))
                    .transpose()
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(ApexView {
            finest: self.finest,
            tile_log2: self.tile_log2,
            across: self.across,
            rects: self.rects,
            kept: self.kept.into_iter().map(AtomicU8::into_inner).collect(),
            strides,
        })
    }
}

/// The lattice as the apex reads it ([`ApexViewWriter`] wrote it): tiles read back thinned to
/// a stride.
pub struct ApexView {
    finest: u32,
    tile_log2: u32,
    across: usize,
    rects: Vec<(i64, i64, i64, i64)>,
    kept: Vec<u8>,
    strides: Vec<Option<(Spilled, Vec<u64>)>>,
}

impl fmt::Debug for ApexView {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("ApexView")
            .field("finest", &self.finest)
            .field("tile_log2", &self.tile_log2)
            .field("tiles", &self.kept.len())
            .finish_non_exhaustive()
    }
}

impl ApexView {
    /// Tiles across a face.
    pub fn tiles_across(&self) -> usize {
        self.across
    }

    /// The tiles `wanted` (face, index), each with the points on multiples of `2^max(s,
    /// min(min_stride, tile side))` for its own stride `2^s`, as [`PlanetTiles::tile`] gives
    /// them: tiles near each other in the spill of their stride read together. Errors for a
    /// tile not kept or asked for finer than the view holds it.
    pub fn tiles(
        &self,
        wanted: &BTreeSet<(u8, usize)>,
        min_stride: u32,
    ) -> Result<HashMap<(u8, usize), Arc<PlanetTile>>, CodecError> {
        let mut by_stride: Vec<Vec<Span>> = vec![Vec::new(); STRIDES];
        for &(face, index) in wanted {
            let (stride, at, len) = self.place(face, index, min_stride)?;
            by_stride[stride as usize].push((at, len, (face, index)));
        }
        let mut out = HashMap::with_capacity(wanted.len());
        for (stride, mut spans) in by_stride.into_iter().enumerate() {
            if let Some((spilled, _)) = self.strides.get(stride).and_then(Option::as_ref) {
                spans.sort_unstable();
                read_spans(spilled, &spans, &mut out)?;
            }
        }
        Ok(out)
    }

    /// Stride, offset and length of tile `index` of `face`'s record read at `min_stride`.
    fn place(
        &self,
        face: u8,
        index: usize,
        min_stride: u32,
    ) -> Result<(u32, u64, usize), CodecError> {
        let slot = usize::from(face) * self.rects.len() + index;
        let kept = self.kept.get(slot).copied().unwrap_or(NOT_KEPT);
        let not_kept = || {
            CodecError::invalid(format!(
                "{WHAT}: face {face} tile {index} at stride 2^{min_stride} was not kept"
            ))
        };
        if kept == NOT_KEPT || min_stride < self.finest {
            return Err(not_kept());
        }
        let base = u32::from(kept & !HAS_CLASS);
        let stride = base.max(min_stride.min(self.tile_log2));
        let (_, at) = self.strides[stride as usize]
            .as_ref()
            .ok_or_else(not_kept)?;
        let at = at[slot];
        if at == u64::MAX {
            return Err(not_kept());
        }
        let (x0, y0, x1, y1) = self.rects[index];
        let points = (((x1 - x0) >> stride) as usize + 1) * (((y1 - y0) >> stride) as usize + 1);
        let per_point = if kept & HAS_CLASS != 0 { 6 } else { 5 };
        Ok((stride, at, HEADER_BYTES + points * per_point))
    }
}

/// A tile's record in a spill: offset, length and the tile (face, index).
type Span = (u64, usize, (u8, usize));

/// Reads the records `spans` (sorted) of `spilled` into `out`: records
/// lying near each other read together (at most [`READ_BYTES`] a read, gaps of at most
/// [`GAP_BYTES`]), not one read a tile — an apex level reads tens of thousands of tiles of a
/// few dozen bytes.
fn read_spans(
    spilled: &Spilled,
    spans: &[Span],
    out: &mut HashMap<(u8, usize), Arc<PlanetTile>>,
) -> Result<(), CodecError> {
    let mut buf = Vec::new();
    let mut rest = spans;
    while let Some(&(start, _, _)) = rest.first() {
        let mut end = start;
        let mut count = 0;
        for &(at, len, _) in rest {
            let stop = at + len as u64;
            if count > 0 && (at > end + GAP_BYTES || stop - start > READ_BYTES) {
                break;
            }
            end = end.max(stop);
            count += 1;
        }
        buf.resize((end - start) as usize, 0);
        spilled.read(start, &mut buf)?;
        for &(at, len, (face, index)) in &rest[..count] {
            let from = (at - start) as usize;
            let tile = tile_read_back(face, index, &buf[from..from + len])?;
            out.insert((face, index), Arc::new(tile));
        }
        rest = &rest[count..];
    }
    Ok(())
}

/// Tile `index` of `face` from the bytes [`thinned_bytes`] wrote; damaged bytes are an error
/// naming it.
fn tile_read_back(face: u8, index: usize, bytes: &[u8]) -> Result<PlanetTile, CodecError> {
    let damaged = || CodecError::invalid(format!("{WHAT}: face {face} tile {index} damaged"));
    tile_of_bytes(bytes).ok_or_else(damaged)?
}

/// Writes into `out` (cleared first) the record of `t`'s points on multiples of `2^stride`
/// (`stride` at least the tile's own; the same points as [`super::thinned`] keeps): stride,
/// rectangle, whether it has classes, then the points' heights, validity and classes.
fn thinned_bytes(t: &PlanetTile, stride: u32, out: &mut Vec<u8>) {
    debug_assert!(stride >= t.stride);
    let (x0, y0, x1, y1) = t.rect;
    let step = 1usize << stride;
    let (w, h) = (
        ((x1 - x0) >> stride) as usize + 1,
        ((y1 - y0) >> stride) as usize + 1,
    );
    let points = w * h;
    out.clear();
    out.reserve(HEADER_BYTES + points * 6);
    out.extend_from_slice(&stride.to_le_bytes());
    for v in [x0, y0, x1, y1] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.push(u8::from(t.class.is_some()));
    let at = |x: i64, y: i64| {
        t.index(x, y)
            .expect("a point of the tile on a coarser stride")
    };
    let rows = || (y0..=y1).step_by(step);
    let columns = || (x0..=x1).step_by(step);
    for y in rows() {
        for x in columns() {
            out.extend_from_slice(&t.grid.values[at(x, y)].to_le_bytes());
        }
    }
    for y in rows() {
        out.extend(columns().map(|x| u8::from(t.grid.valid[at(x, y)])));
    }
    if let Some(class) = &t.class {
        for y in rows() {
            out.extend(columns().map(|x| class[at(x, y)]));
        }
    }
    debug_assert_eq!(
        out.len(),
        HEADER_BYTES + points * (5 + usize::from(t.class.is_some()))
    );
}

/// The tile [`thinned_bytes`] wrote; `None` if the bytes are not one.
fn tile_of_bytes(b: &[u8]) -> Option<Result<PlanetTile, CodecError>> {
    let stride = u32::from_le_bytes(b.get(0..4)?.try_into().ok()?);
    let at = |i: usize| -> Option<i64> {
        Some(i64::from_le_bytes(
            b.get(4 + 8 * i..12 + 8 * i)?.try_into().ok()?,
        ))
    };
    let rect = (at(0)?, at(1)?, at(2)?, at(3)?);
    if stride >= 32 || rect.2 < rect.0 || rect.3 < rect.1 {
        return None;
    }
    let has_class = *b.get(HEADER_BYTES - 1)? != 0;
    let (w, h) = (
        usize::try_from((rect.2 - rect.0) >> stride).ok()? + 1,
        usize::try_from((rect.3 - rect.1) >> stride).ok()? + 1,
    );
    let points = w.checked_mul(h)?;
    let rest = b.get(HEADER_BYTES..)?;
    if rest.len() != points * if has_class { 6 } else { 5 } {
        return None;
    }
    let values: Vec<i32> = rest[..4 * points]
        .chunks_exact(4)
        .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    let valid: Vec<bool> = rest[4 * points..5 * points]
        .iter()
        .map(|&v| v != 0)
        .collect();
    let class = has_class.then(|| rest[5 * points..].to_vec());
    let grid = HeightGrid {
        width: w,
        height: h,
        values: values.into(),
        valid: valid.into(),
    };
    Some(PlanetTile::new(stride, rect, grid, class))
}

#[cfg(test)]
#[path = "apex_view_tests.rs"]
mod tests;
