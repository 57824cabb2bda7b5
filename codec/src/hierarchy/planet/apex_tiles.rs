//! The tiles an apex level reads, kept for the next level that reads the same points: levels
//! `2m` and `2m + 1` both read level `2m + 2`'s vertices, so the even level's tiles are spilled
//! ([`super::spill`]) as it resamples them and the odd level reads them back instead of
//! resampling them again. Only one stride's tiles are kept at a time, on disk past a few MiB.

use std::collections::{BTreeSet, HashMap};
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

use super::PlanetTile;
use super::spill::{Spill, Spilled};
use super::tile_source::PlanetTiles;
use crate::CodecError;
use crate::quant::HeightGrid;

/// What the temporary file holds, for its errors.
const WHAT: &str = "the planet apex's tiles";

/// Bytes of tiles kept in memory before they go to a temporary file.
const IN_MEMORY_BYTES: usize = 4 << 20;

/// Where each kept tile is: `(face, index)` → offset and length.
type Index = HashMap<(u8, usize), (u64, usize)>;

/// Tiles being kept ([`KeptTiles::put`]), from any thread.
pub(super) struct KeptTiles {
    spill: Spill,
    index: Mutex<Index>,
}

impl KeptTiles {
    pub(super) fn new() -> Self {
        Self {
            spill: Spill::new(WHAT, IN_MEMORY_BYTES),
            index: Mutex::new(HashMap::new()),
        }
    }

    /// Keeps tile `index` of `face`.
    fn put(&self, face: u8, index: usize, t: &PlanetTile) -> Result<(), CodecError> {
        let bytes = tile_bytes(t);
        let at = self.spill.put(&bytes)?;
        let mut held = self.index.lock().expect("the kept tiles");
        held.entry((face, index)).or_insert((at, bytes.len()));
        Ok(())
    }

    /// The tiles kept, to be read back.
    pub(super) fn finish(self) -> Result<ReadTiles, CodecError> {
        Ok(ReadTiles {
            bytes: self.spill.finish()?,
            index: self.index.into_inner().expect("the kept tiles"),
        })
    }
}

/// Tiles a [`KeptTiles`] kept, read back by `(face, index)`.
pub(super) struct ReadTiles {
    bytes: Spilled,
    index: Index,
}

/// Bytes read back at once for [`ReadTiles::get_many`]: kept tiles lying within this span of
/// the spill (with gaps of at most [`GAP_BYTES`] between them) are read in one read.
const READ_BYTES: u64 = 1 << 20;

/// The largest gap between two kept tiles read in one read ([`ReadTiles::get_many`]).
const GAP_BYTES: u64 = 16 << 10;

impl ReadTiles {
    fn get(&self, face: u8, index: usize) -> Result<Option<Arc<PlanetTile>>, CodecError> {
        let Some(&(at, len)) = self.index.get(&(face, index)) else {
            return Ok(None);
        };
        let mut bytes = vec![0u8; len];
        self.bytes.read(at, &mut bytes)?;
        Ok(Some(Arc::new(tile_read_back(face, index, &bytes)?)))
    }

    /// Those of `wanted` kept here, by `(face, index)`: tiles lying near each other in the
    /// spill are read together (at most [`READ_BYTES`] a read, gaps of at most
    /// [`GAP_BYTES`]), not one read a tile — an odd apex level reads back tens of thousands of
    /// tiles of a few dozen bytes.
    pub(super) fn get_many(
        &self,
        wanted: impl IntoIterator<Item = (u8, usize)>,
    ) -> Result<HashMap<(u8, usize), Arc<PlanetTile>>, CodecError> {
        let mut spans: Vec<(u64, usize, (u8, usize))> = wanted
            .into_iter()
            .filter_map(|key| self.index.get(&key).map(|&(at, len)| (at, len, key)))
            .collect();
        spans.sort_unstable();
        spans.dedup();
        let mut out = HashMap::with_capacity(spans.len());
        let mut buf = Vec::new();
        let mut rest = &spans[..];
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
            self.bytes.read(start, &mut buf)?;
            for &(at, len, (face, index)) in &rest[..count] {
                let from = (at - start) as usize;
                let tile = tile_read_back(face, index, &buf[from..from + len])?;
                out.insert((face, index), Arc::new(tile));
            }
            rest = &rest[count..];
        }
        Ok(out)
    }
}

/// Tile `index` of `face` from the bytes [`tile_bytes`] wrote; damaged bytes are an error
/// naming it.
fn tile_read_back(face: u8, index: usize, bytes: &[u8]) -> Result<PlanetTile, CodecError> {
    let damaged = || CodecError::invalid(format!("{WHAT}: face {face} tile {index} damaged"));
    tile_of_bytes(bytes).ok_or_else(damaged)?
}

/// An apex level's source of tiles: those the previous level of the same stride kept (`read`),
/// else `tiles`' (kept in `keep` for the next level).
pub(super) struct ApexTiles<'a> {
    pub(super) tiles: &'a dyn PlanetTiles,
    pub(super) read: Option<&'a ReadTiles>,
    pub(super) keep: Option<&'a KeptTiles>,
}

impl ApexTiles<'_> {
    /// The tiles `wanted`, each thinned to `min_stride` ([`PlanetTiles::tile`]): those the
    /// previous level kept read back together ([`ReadTiles::get_many`]), the others resampled.
    pub(super) fn tiles(
        &self,
        wanted: &BTreeSet<(u8, usize)>,
        min_stride: u32,
    ) -> Result<HashMap<(u8, usize), Arc<PlanetTile>>, CodecError> {
        let mut held = match self.read {
            Some(read) => read.get_many(wanted.iter().copied())?,
            None => HashMap::new(),
        };
        let missing: Vec<(u8, usize)> = wanted
            .iter()
            .filter(|key| !held.contains_key(key))
            .copied()
            .collect();
        let more = missing
            .into_par_iter()
            .map(|(f, i)| Ok(((f, i), self.tile(f, i, min_stride)?)))
            .collect::<Result<Vec<_>, CodecError>>()?;
        held.extend(more);
        Ok(held)
    }
}

impl PlanetTiles for ApexTiles<'_> {
    fn tile(&self, face: u8, index: usize, min_stride: u32) -> Result<Arc<PlanetTile>, CodecError> {
        if let Some(t) = self.read.map(|r| r.get(face, index)).transpose()?.flatten() {
            return Ok(t);
        }
        let t = self.tiles.tile(face, index, min_stride)?;
        if let Some(keep) = self.keep {
            keep.put(face, index, &t)?;
        }
        Ok(t)
    }
}

/// A tile's bytes: stride, rectangle, whether it has classes, then its heights, validity and
/// classes.
fn tile_bytes(t: &PlanetTile) -> Vec<u8> {
    let points = t.grid.values.len();
    let mut out = Vec::with_capacity(4 + 32 + 1 + points * 6);
    out.extend_from_slice(&t.stride.to_le_bytes());
    for v in [t.rect.0, t.rect.1, t.rect.2, t.rect.3] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.push(u8::from(t.class.is_some()));
    out.extend(t.grid.values.iter().flat_map(|v| v.to_le_bytes()));
    out.extend(t.grid.valid.iter().map(|&b| u8::from(b)));
    if let Some(class) = &t.class {
        out.extend_from_slice(class);
    }
    out
}

/// The tile [`tile_bytes`] wrote; `None` if the bytes are not one.
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
    let has_class = *b.get(36)? != 0;
    let (w, h) = (
        usize::try_from((rect.2 - rect.0) >> stride).ok()? + 1,
        usize::try_from((rect.3 - rect.1) >> stride).ok()? + 1,
    );
    let points = w.checked_mul(h)?;
    let rest = b.get(37..)?;
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
mod tests {
    use super::*;

    /// A tile kept reads back as the same tile (heights, validity, classes, stride and
    /// rectangle), with and without classes; damaged bytes are refused, not a panic.
    #[test]
    fn kept_tiles_read_back_as_kept() {
        use crate::hierarchy::resolution::HOLE;
        let grid = |w: usize, h: usize| HeightGrid {
            width: w,
            height: h,
            values: (0..w * h)
                .map(|v| v as i32 * 7 - 100)
                .collect::<Vec<_>>()
                .into(),
            valid: (0..w * h).map(|v| v % 3 != 0).collect::<Vec<_>>().into(),
        };
        let class: Vec<u8> = (0..25).map(|v| if v % 3 != 0 { 2 } else { HOLE }).collect();
        let a = PlanetTile::new(2, (8, 16, 24, 32), grid(5, 5), Some(class)).unwrap();
        let b = PlanetTile::new(0, (0, 0, 3, 1), grid(4, 2), None).unwrap();
        let kept = KeptTiles::new();
        kept.put(1, 7, &a).unwrap();
        kept.put(4, 0, &b).unwrap();
        let read = kept.finish().unwrap();
        for (face, index, t) in [(1, 7, &a), (4, 0, &b)] {
            let back = read.get(face, index).unwrap().unwrap();
            assert_eq!(
                (back.stride, back.rect, &back.grid, &back.class),
                (t.stride, t.rect, &t.grid, &t.class)
            );
        }
        assert!(read.get(1, 8).unwrap().is_none());
        let many = read.get_many([(4, 0), (1, 8), (1, 7), (4, 0)]).unwrap();
        assert_eq!(many.len(), 2);
        for (face, index, t) in [(1, 7, &a), (4, 0, &b)] {
            let back = &many[&(face, index)];
            assert_eq!(
                (back.stride, back.rect, &back.grid, &back.class),
                (t.stride, t.rect, &t.grid, &t.class)
            );
        }
        let bytes = tile_bytes(&a);
        for cut in [0, 3, 20, 37, bytes.len() - 1] {
            assert!(tile_of_bytes(&bytes[..cut]).is_none(), "cut at {cut}");
        }
    }
}
