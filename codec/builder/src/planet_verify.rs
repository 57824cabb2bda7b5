//! `cbdam verify` of a planet within `--memory-limit`: the comparison [`crate::planet`] makes of
//! the whole lattice, made block by block where the whole would not fit.
//!
//! The inputs are read through the cache the build uses and the lattice is painted tile by tile
//! ([`LatticeTiles`]) under the same shares of the limit as the build's ([`PlanetMemory`]):
//! once to fix each tile's stride and write the apex's view of it, then as each block asks.
//! Every level is compared with the lattice by [`PlanetBlockVerify`] (the apex over the whole
//! planet, then block by block); each input's resampling error is the build's out-of-core
//! measure ([`LatticeTiles::resampling`]); the end-to-end error is the same measure with the
//! decoded finest level in place of the lattice's heights, each block writing the finest level
//! of its tiles to a temporary file ([`DecodedTiles`]) as it decodes them.

use std::collections::HashMap;
use std::io::{Read, Seek, SeekFrom, Write};
use std::sync::{Arc, Mutex};

use crate::assign::AssignedGeoRef;
use crate::error::{BuildError, Context, Result, bail};
use crate::planet::{BYTES_PER_LATTICE_POINT, BlockWise, PlanetComparison, input_cache_budget};
use crate::planet_input::PlanetInputs;
use crate::planet_lattice::{LatticeTiles, Resampler, TileHeights};
use crate::planet_memory::PlanetMemory;
use crate::planet_resampling::InputResampling;
use crate::tiles::Tile;
use cbdam_codec::geometry::{DiamondId, Domain, Layout};
use cbdam_codec::hierarchy::planet::{
    ApexViewWriter, BlockGroups, PlanetBlockVerify, PlanetOutline, TileGroup, default_cut,
    group_rect, planet_block_groups,
};
use cbdam_codec::hierarchy::resolution::HOLE;
use cbdam_codec::hierarchy::{PlanetGrid, PlanetTile, VerifyReport};
use cbdam_codec::quant::HeightGrid;
use cbdam_codec::repository::Repository;

/// Checks a planet repository against the inputs it was built from, within `limit` bytes: the
/// whole comparison ([`crate::planet::compare_planet`]) where the lattice's tiles fit in the
/// limit at [`BYTES_PER_LATTICE_POINT`] (the faster path), else block by block (see the module
/// documentation). The same figures either way.
pub fn compare_planet_within(
    repo: &Repository,
    tiles: &[Tile],
    nodata: Option<f64>,
    assign: Option<&AssignedGeoRef>,
    limit: u64,
) -> Result<PlanetComparison> {
    let domain = repo.head().params().domain;
    if domain.cube().is_none() {
        bail!("this repository is planar: compare it with compare_dem or compare_tiles");
    }
    let inputs = PlanetInputs::read(tiles, nodata, assign, input_cache_budget(limit))?;
    let (n, k) = (domain.n(), domain.layout().k());
    let held = crate::planet_plan::estimated_held_points(&inputs, n, k)?;
    if held.saturating_mul(BYTES_PER_LATTICE_POINT) <= limit {
        return crate::planet::compare_planet_inputs(repo, &inputs);
    }
    compare_planet_in_blocks(repo, &inputs, limit)
}

/// [`compare_planet_within`] block by block, whatever the planet's size.
pub fn compare_planet_in_blocks(
    repo: &Repository,
    inputs: &PlanetInputs,
    limit: u64,
) -> Result<PlanetComparison> {
    let head = repo.head();
    let params = *head.params();
    let plan = *head.plan();
    let (n, k) = (params.domain.n(), params.domain.layout().k());
    let memory = PlanetMemory::new(inputs, (n, k), rayon::current_num_threads(), limit)?;
    inputs.set_cache_budget(memory.input_cache_budget());
    let resampler = Resampler::new(inputs, n, k, &plan)?;
    let cut = default_cut(resampler.domain(), resampler.tile_log2());
    let view = ApexViewWriter::new(resampler.domain(), resampler.tile_log2(), cut);
    let (lattice, outline, _, _) =
        LatticeTiles::outline(resampler, memory.lattice_cache_budget(), Some(&view))?;
    let view = view.finish().map_err(BuildError::from)?;
    let records = head
        .entries()
        .iter()
        .map(|e| Ok((e.id, repo.record(e.id)?)))
        .collect::<Result<Vec<_>>>()?;
    repo.release_pages();
    let (walk, mut levels) = PlanetBlockVerify::new(
        params,
        head.root_bytes(),
        records,
        (&outline, &view),
        cut,
        memory.block_bytes(),
    )
    .context("decoding the planet's apex")?;
    drop(view);
    let groups = planet_block_groups(
        &outline,
        walk.cut(),
        lattice.strides(),
        (
            lattice.share_out(walk.diamond_bytes(), memory.block_bytes()),
            1,
        ),
    )
    .map_err(BuildError::from)?;
    // Insets measured as soon as their tiles are decoded, their decoded tiles let go after.
    let (decoded, ready, insets) = DecodedTiles::for_blocks(&lattice, &outline, &groups)?;
    let mut measured = vec![None; inputs.inputs.len()];
    for (index, measured_now) in ready.iter().enumerate() {
        let group = groups.get(index).expect("a block of the planet");
        let mut finest = decoded.block(group);
        let mut write = |id: DiamondId, p: &[i32], v: Option<&[bool]>| finest.put(id, p, v);
        walk.verify_block(group, &lattice, &mut levels, Some(&mut write))
            .with_context(|| format!("decoding block {index} (face {})", group.face))?;
        decoded.save(index, finest)?;
        for &i in measured_now {
            measured[i] = Some(both_errors(&lattice, &decoded, i)?);
            decoded.measured(insets[i].as_deref().unwrap_or_default());
        }
    }
    drop(walk);
    let report = VerifyReport {
        levels,
        bound: params.quantizer.k() as u32,
    };
    let (resampling, end_to_end) = the_other_inputs(&lattice, &decoded, measured)?;
    let on_disk = decoded.on_disk();
    Ok(PlanetComparison {
        report,
        resampling,
        end_to_end,
        max_error: plan.max_error(),
        blocks: Some(BlockWise {
            blocks: groups.len(),
            decoded_written: on_disk.2,
            decoded_peak: on_disk.0,
            decoded_at_end: on_disk.1,
        }),
    })
}

/// The errors of the inputs not measured during the blocks (global ones, a band of rows at a
/// time), once the blocks are let go.
fn the_other_inputs(
    lattice: &LatticeTiles<'_>,
    decoded: &Arc<DecodedTiles>,
    measured: Vec<Option<(InputResampling, InputResampling)>>,
) -> Result<(Vec<InputResampling>, Vec<InputResampling>)> {
    measured
        .into_iter()
        .enumerate()
        .map(|(i, m)| m.map_or_else(|| both_errors(lattice, decoded, i), Ok))
        .collect::<Result<Vec<_>>>()
        .map(|both| both.into_iter().unzip())
}

/// `log2` of the finest stride at which the inputs measured in bands (those `insets` gives no
/// tiles for, [`LatticeTiles::inset_tiles`]) read any tile: a tile held at a finer stride is
/// read by them at this one. `None` when there are none.
fn banded_stride(lattice: &LatticeTiles<'_>, insets: &[Option<Vec<(u8, usize)>>]) -> Option<u32> {
    (0..insets.len())
        .filter(|&i| insets[i].is_none())
        .map(|i| lattice.view_stride_of(i))
        .min()
}

/// Input `input`'s resampling error (the lattice against its samples) and end-to-end error
/// (the `decoded` finest level against them).
fn both_errors(
    lattice: &LatticeTiles<'_>,
    decoded: &Arc<DecodedTiles>,
    input: usize,
) -> Result<(InputResampling, InputResampling)> {
    lattice.set_heights(None);
    let resampling = lattice.resampling(input)?;
    let heights: Arc<dyn TileHeights + '_> = decoded.clone();
    lattice.set_heights(Some(heights));
    let end_to_end = lattice.resampling(input);
    lattice.set_heights(None);
    Ok((resampling, end_to_end?))
}

/// The decoded finest level of the tiles, on disk while some input still needs it: each
/// tile's heights (4 bytes a point) then validity (1 byte). A tile is written at its own stride
/// in its block's temporary file while an inset whose samples it holds is still to be measured
/// (the file goes when none of its tiles is needed), and at the stride the global inputs read
/// it at ([`banded_stride`]) in a file kept to the end: so the disk holds the
/// blocks around the insets being measured and a coarse planet, not the whole finest level.
struct DecodedTiles {
    /// Per face, per tile: the stride's `log2`.
    strides: Vec<Vec<u32>>,
    rects: Vec<(i64, i64, i64, i64)>,
    /// `log2` of the stride the global inputs read every tile at, if there are any.
    banded: Option<u32>,
    store: Mutex<Store>,
    tile_log2: u32,
    side: i64,
    layout: Layout,
}

/// Where [`DecodedTiles`] keeps its tiles.
struct Store {
    /// Tiles at the global inputs' stride (or their own where coarser), kept to the end.
    kept: TempFile,
    /// Per block written: its file of tiles at their own stride, and how many are still needed.
    blocks: HashMap<usize, (TempFile, usize)>,
    /// Per tile written: where it is.
    at: HashMap<(u8, usize), Stored>,
    /// Per tile: the insets still to be measured whose samples it holds.
    pending: HashMap<(u8, usize), usize>,
    /// Bytes in the files now, at most, and written in all.
    on_disk: u64,
    peak: u64,
    written: u64,
}

/// An anonymous temporary file appended to, and its length.
struct TempFile(std::fs::File, u64);

/// Where a decoded tile is: at its own stride in a block's file (block, offset) while an inset
/// still needs it, and at a coarser or equal stride in the kept file (stride's `log2`, offset).
#[derive(Default)]
struct Stored {
    own: Option<(usize, u64)>,
    kept: Option<(u32, u64)>,
}

/// A decoded tile: its stride's `log2`, heights and validity.
type Decoded = (u32, Vec<i32>, Vec<bool>);

/// A tile being decoded: its rectangle, stride's `log2`, heights and validity.
type Decoding = ((i64, i64, i64, i64), u32, Vec<i32>, Vec<bool>);

/// One block's tiles being decoded: per tile, its rectangle, stride, heights and validity.
struct BlockTiles {
    face: u8,
    tiles: HashMap<usize, Decoding>,
    across: usize,
    tile_log2: u32,
    rect: (i64, i64, i64, i64),
    layout: Layout,
}

impl TempFile {
    fn new() -> Result<Self> {
        let file = tempfile::tempfile().context("creating the decoded planet's temporary file")?;
        Ok(Self(file, 0))
    }

    /// Appends `values` then `valid`; where they start.
    fn append(&mut self, values: &[i32], valid: &[bool]) -> Result<u64> {
        let mut bytes = Vec::with_capacity(values.len() * 5);
        bytes.extend(values.iter().flat_map(|v| v.to_le_bytes()));
        bytes.extend(valid.iter().map(|&v| u8::from(v)));
        let start = self.1;
        self.0
            .write_all(&bytes)
            .context("writing the decoded planet's temporary file")?;
        self.1 += bytes.len() as u64;
        Ok(start)
    }

    /// The `points` heights and validity written at `start`.
    fn read(&mut self, start: u64, points: usize) -> Result<(Vec<i32>, Vec<bool>)> {
        let mut bytes = vec![0u8; points * 5];
        self.0.seek(SeekFrom::Start(start))?;
        self.0.read_exact(&mut bytes)?;
        self.0.seek(SeekFrom::Start(self.1))?;
        let (v, b) = bytes.split_at(points * 4);
        let values = v
            .chunks_exact(4)
            .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        Ok((values, b.iter().map(|&b| b != 0).collect()))
    }
}

impl DecodedTiles {
    /// Nothing decoded yet, for the tiles of `2^tile_log2` steps of `domain` held at `strides`
    /// (per face, per tile), read by the global inputs at `banded` ([`banded_stride`])
    /// and by the insets in `inset_tiles` (each tile once per inset whose samples it holds).
    fn new(
        strides: &[Vec<u32>],
        domain: &Domain,
        tile_log2: u32,
        banded: Option<u32>,
        inset_tiles: impl Iterator<Item = (u8, usize)>,
    ) -> Result<Self> {
        let mut pending = HashMap::new();
        for tile in inset_tiles {
            *pending.entry(tile).or_insert(0) += 1;
        }
        Ok(Self {
            strides: strides.to_vec(),
            rects: PlanetGrid::tile_rects(domain, tile_log2),
            banded,
            store: Mutex::new(Store {
                kept: TempFile::new()?,
                blocks: HashMap::new(),
                at: HashMap::new(),
                pending,
                on_disk: 0,
                peak: 0,
                written: 0,
            }),
            tile_log2,
            side: domain.cube().expect("a cube-sphere").side(),
            layout: *domain.layout(),
        })
    }

    /// Nothing decoded yet, for the tiles of `lattice` in `groups`; with, per block, the insets
    /// measured once it is done (after the last block holding its tiles), and per input the
    /// tiles it is measured on where it is an inset ([`LatticeTiles::inset_tiles`]).
    #[allow(clippy::type_complexity)]
    fn for_blocks(
        lattice: &LatticeTiles<'_>,
        outline: &PlanetOutline,
        groups: &BlockGroups,
    ) -> Result<(Arc<Self>, Vec<Vec<usize>>, Vec<Option<Vec<(u8, usize)>>>)> {
        let across = PlanetGrid::tile_rects(outline.domain(), outline.tile_log2())
            .len()
            .isqrt();
        let block_of: HashMap<(u8, usize), usize> = (0..groups.len())
            .filter_map(|b| groups.get(b).map(|g| (b, g)))
            .flat_map(|(b, g)| g.tiles(across).map(move |i| ((g.face, i), b)))
            .collect();
        let insets: Vec<_> = (0..lattice.input_count())
            .map(|i| lattice.inset_tiles(i))
            .collect();
        // Each inset after the last block holding its tiles (as the build's
        // `measured_after_blocks`, from the footprints just found).
        let mut ready = vec![Vec::new(); groups.len()];
        for (i, tiles) in insets.iter().enumerate() {
            let last = tiles.as_ref().and_then(|tiles| {
                let blocks = tiles.iter().map(|t| block_of.get(t).copied());
                blocks.collect::<Option<Vec<_>>>()?.into_iter().max()
            });
            if let Some(b) = last {
                ready[b].push(i);
            }
        }
        let decoded = Self::new(
            lattice.strides(),
            outline.domain(),
            outline.tile_log2(),
            banded_stride(lattice, &insets),
            insets.iter().flatten().flatten().copied(),
        )?;
        Ok((Arc::new(decoded), ready, insets))
    }

    /// The tiles of `group`, every point invalid (0) until a diamond writes it.
    fn block(&self, group: &TileGroup) -> BlockTiles {
        let across = self.rects.len().isqrt();
        let tiles = group
            .tiles(across)
            .map(|i| {
                let rect = self.rects[i];
                let s = self.strides[usize::from(group.face)][i];
                let (w, h) = tile_size(rect, s);
                (i, (rect, s, vec![0; w * h], vec![false; w * h]))
            })
            .collect();
        BlockTiles {
            face: group.face,
            tiles,
            across,
            tile_log2: self.tile_log2,
            rect: group_rect(group, self.side, self.tile_log2),
            layout: self.layout,
        }
    }

    /// Writes block `index`'s tiles: at their own stride where an inset still needs them, and
    /// at the global inputs' stride.
    fn save(&self, index: usize, block: BlockTiles) -> Result<()> {
        let mut store = self.store.lock().expect("the decoded tiles");
        let store = &mut *store;
        let mut own = None;
        for (i, (rect, s, values, valid)) in block.tiles {
            let key = (block.face, i);
            let mut stored = Stored::default();
            let coarse = self.banded.map(|b| s.max(b));
            if coarse == Some(s) {
                stored.kept = Some((s, store.kept.append(&values, &valid)?));
            } else {
                if store.pending.get(&key).is_some_and(|&n| n > 0) {
                    let file = match &mut own {
                        Some(f) => f,
                        None => own.insert((TempFile::new()?, 0)),
                    };
                    stored.own = Some((index, file.0.append(&values, &valid)?));
                    file.1 += 1;
                }
                if let Some(c) = coarse {
                    let (v, b) = points_at_stride(rect, s, c, &values, &valid);
                    stored.kept = Some((c, store.kept.append(&v, &b)?));
                }
            }
            store.at.insert(key, stored);
        }
        let before = store.on_disk;
        if let Some(file) = own {
            store.blocks.insert(index, file);
        }
        store.on_disk = store.kept.1 + store.blocks.values().map(|f| f.0.1).sum::<u64>();
        store.written += store.on_disk - before;
        store.peak = store.peak.max(store.on_disk);
        Ok(())
    }

    /// An inset whose samples `tiles` hold was measured: the tiles no other inset needs are let
    /// go at their own stride, and a block's file once none of its tiles is needed.
    fn measured(&self, tiles: &[(u8, usize)]) {
        let mut store = self.store.lock().expect("the decoded tiles");
        let store = &mut *store;
        for key in tiles {
            let Some(n) = store.pending.get_mut(key) else {
                continue;
            };
            *n = n.saturating_sub(1);
            if *n > 0 {
                continue;
            }
            let Some(stored) = store.at.get_mut(key) else {
                continue;
            };
            let Some((block, _)) = stored.own.take() else {
                continue;
            };
            if let Some(file) = store.blocks.get_mut(&block) {
                file.1 -= 1;
                if file.1 == 0 {
                    let gone = store.blocks.remove(&block).map_or(0, |f| f.0.1);
                    store.on_disk -= gone;
                }
            }
        }
    }

    /// The most bytes the temporary files held at once, what they hold now, and the bytes
    /// written to them.
    fn on_disk(&self) -> (u64, u64, u64) {
        let store = self.store.lock().expect("the decoded tiles");
        (store.peak, store.on_disk, store.written)
    }

    /// Tile `index` of `face` as decoded, at a stride whose points include those of stride
    /// `2^want`: `None` where no block decoded it; an error where the points asked for were let
    /// go (an input measured after the insets it was let go for).
    fn load(&self, face: u8, index: usize, want: u32) -> Result<Option<Decoded>> {
        let mut store = self.store.lock().expect("the decoded tiles");
        let store = &mut *store;
        let Some(stored) = store.at.get(&(face, index)) else {
            return Ok(None);
        };
        let rect = self.rects[index];
        if let Some((s, start)) = stored.kept.filter(|&(s, _)| s <= want) {
            let (w, h) = tile_size(rect, s);
            let (values, valid) = store.kept.read(start, w * h)?;
            return Ok(Some((s, values, valid)));
        }
        let Some((block, start)) = stored.own else {
            bail!(
                "the decoded tile {index} of face {face} is not kept at stride 2^{want} (let go \
                 before an input reading it there was measured)"
            );
        };
        let s = self.strides[usize::from(face)][index];
        let (w, h) = tile_size(rect, s);
        let file = store
            .blocks
            .get_mut(&block)
            .expect("a needed tile's block file");
        let (values, valid) = file.0.read(start, w * h)?;
        Ok(Some((s, values, valid)))
    }
}

/// The points at stride `2^c` of a tile over `rect` held at stride `2^s` (`c >= s`).
fn points_at_stride(
    rect: (i64, i64, i64, i64),
    s: u32,
    c: u32,
    values: &[i32],
    valid: &[bool],
) -> (Vec<i32>, Vec<bool>) {
    let (w, _) = tile_size(rect, s);
    let (cw, ch) = tile_size(rect, c);
    let step = 1usize << (c - s);
    let at = |k: usize| (k / cw) * step * w + (k % cw) * step;
    (
        (0..cw * ch).map(|k| values[at(k)]).collect(),
        (0..cw * ch).map(|k| valid[at(k)]).collect(),
    )
}

impl TileHeights for DecodedTiles {
    /// `tile` with the decoded heights and validity at its points (invalid where no block
    /// decoded the tile).
    fn heights(&self, face: u8, index: usize, tile: &PlanetTile) -> Result<PlanetTile> {
        let (x0, y0, _, _) = tile.rect;
        let points = tile.points();
        let (mut values, mut valid) = (vec![0; points], vec![false; points]);
        if let Some((s, dv, dvalid)) = self.load(face, index, tile.stride)? {
            let (w, _) = tile_size(self.rects[index], s);
            let step = tile.stride;
            for row in 0..tile.grid.height {
                for col in 0..tile.grid.width {
                    let (x, y) = (x0 + ((col as i64) << step), y0 + ((row as i64) << step));
                    let k = ((y - y0) >> s) as usize * w + ((x - x0) >> s) as usize;
                    values[row * tile.grid.width + col] = dv[k];
                    valid[row * tile.grid.width + col] = dvalid[k];
                }
            }
        }
        let grid = HeightGrid {
            width: tile.grid.width,
            height: tile.grid.height,
            values: values.into(),
            valid: valid.into(),
        };
        // Classes as the lattice's where they agree with the decoded validity, else the
        // nearest that does (the measure reads heights, validity and winners only).
        let class = tile.class.as_ref().map(|class| {
            class
                .iter()
                .zip(grid.valid.iter())
                .map(|(&c, &v)| match (v, c < 32) {
                    (true, true) | (false, false) => c,
                    (true, false) => 0,
                    (false, true) => HOLE,
                })
                .collect()
        });
        Ok(PlanetTile::new(tile.stride, tile.rect, grid, class)?)
    }
}

impl BlockTiles {
    /// Writes diamond `id`'s grid `p` (validity `v`, `None`: all valid) on the block's tiles'
    /// points it holds.
    fn put(&mut self, id: DiamondId, p: &[i32], v: Option<&[bool]>) {
        let n = self.layout.n();
        let g = self.layout.grid(id);
        let (rx0, ry0, rx1, ry1) = self.rect;
        let last = self.across - 1;
        for j in 0..n {
            for i in 0..n {
                let (x, y) = g.point(i as i64, j as i64);
                if x < rx0 || x > rx1 || y < ry0 || y > ry1 {
                    continue;
                }
                let k = j * n + i;
                let (value, ok) = (p[k], v.is_none_or(|v| v[k]));
                let cell = |a: i64| ((a >> self.tile_log2) as usize).min(last);
                let (bx, by) = (cell(x), cell(y));
                // The owner, and the tiles before it along each axis when the point is on
                // their side (as `PlanetGrid::set` writes).
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let (Some(tx), Some(ty)) = (bx.checked_sub(dx), by.checked_sub(dy)) else {
                        continue;
                    };
                    let Some((rect, s, values, valid)) =
                        self.tiles.get_mut(&(ty * self.across + tx))
                    else {
                        continue;
                    };
                    if let Some(at) = point_index(*rect, *s, x, y) {
                        values[at] = value;
                        valid[at] = ok;
                    }
                }
            }
        }
    }
}

/// The index of point `(x, y)` among those a tile over `rect` holds at stride `2^s`.
fn point_index((x0, y0, x1, y1): (i64, i64, i64, i64), s: u32, x: i64, y: i64) -> Option<usize> {
    let mask = (1i64 << s) - 1;
    let inside = x0 <= x && x <= x1 && y0 <= y && y <= y1;
    (inside && (x - x0) & mask == 0 && (y - y0) & mask == 0).then(|| {
        ((y - y0) >> s) as usize * (((x1 - x0) >> s) as usize + 1) + ((x - x0) >> s) as usize
    })
}

/// Points a row and rows of a tile over `rect` at stride `2^s`.
fn tile_size((x0, y0, x1, y1): (i64, i64, i64, i64), s: u32) -> (usize, usize) {
    (((x1 - x0) >> s) as usize + 1, ((y1 - y0) >> s) as usize + 1)
}
