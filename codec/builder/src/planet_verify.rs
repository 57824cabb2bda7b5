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
use crate::planet::{BYTES_PER_LATTICE_POINT, PlanetComparison, input_cache_budget};
use crate::planet_input::PlanetInputs;
use crate::planet_lattice::{LatticeTiles, Resampler, TileHeights};
use crate::planet_memory::PlanetMemory;
use crate::tiles::Tile;
use cbdam_codec::geometry::{DiamondId, Domain, Layout};
use cbdam_codec::hierarchy::planet::{
    ApexViewWriter, PlanetBlockVerify, TileGroup, default_cut, group_rect, planet_block_groups,
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
    let (walk, mut levels) =
        PlanetBlockVerify::new(params, head.root_bytes(), records, &outline, cut, &view)
            .context("decoding the planet's apex")?;
    drop(view);
    let groups = planet_block_groups(
        &outline,
        walk.cut(),
        lattice.strides(),
        (memory.block_bytes(), 1),
    )
    .map_err(BuildError::from)?;
    let decoded = DecodedTiles::new(lattice.strides(), outline.domain(), outline.tile_log2())?;
    for index in 0..groups.len() {
        let group = groups.get(index).expect("a block of the planet");
        let mut finest = decoded.block(group);
        let mut write = |id: DiamondId, p: &[i32], v: Option<&[bool]>| finest.put(id, p, v);
        walk.verify_block(group, &lattice, &mut levels, Some(&mut write))
            .with_context(|| format!("decoding block {index} (face {})", group.face))?;
        decoded.save(finest)?;
    }
    drop(walk);
    let report = VerifyReport {
        levels,
        bound: params.quantizer.k() as u32,
    };
    let resampling = (0..inputs.inputs.len())
        .map(|i| lattice.resampling(i))
        .collect::<Result<Vec<_>>>()?;
    let decoded: Arc<dyn TileHeights + '_> = Arc::new(decoded);
    lattice.set_heights(Some(decoded));
    let end_to_end = (0..inputs.inputs.len())
        .map(|i| lattice.resampling(i))
        .collect::<Result<Vec<_>>>()?;
    Ok(PlanetComparison {
        report,
        resampling,
        end_to_end,
        max_error: plan.max_error(),
        blocks: Some(groups.len()),
    })
}

/// The decoded finest level of every tile, at the tile's own stride, in a temporary file:
/// heights (4 bytes a point) then validity (1 byte), tile after tile as the blocks write them.
struct DecodedTiles {
    /// Per face, per tile: the stride's `log2`.
    strides: Vec<Vec<u32>>,
    rects: Vec<(i64, i64, i64, i64)>,
    file: Mutex<(std::fs::File, u64)>,
    /// Where each tile written starts.
    at: Mutex<HashMap<(u8, usize), u64>>,
    tile_log2: u32,
    side: i64,
    layout: Layout,
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

impl DecodedTiles {
    /// Nothing decoded yet, for the tiles of `2^tile_log2` steps of `domain` held at `strides`
    /// (per face, per tile).
    fn new(strides: &[Vec<u32>], domain: &Domain, tile_log2: u32) -> Result<Self> {
        let file = tempfile::tempfile().context("creating the decoded planet's temporary file")?;
        Ok(Self {
            strides: strides.to_vec(),
            rects: PlanetGrid::tile_rects(domain, tile_log2),
            file: Mutex::new((file, 0)),
            at: Mutex::new(HashMap::new()),
            tile_log2,
            side: domain.cube().expect("a cube-sphere").side(),
            layout: *domain.layout(),
        })
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

    /// Appends `block`'s tiles to the file.
    fn save(&self, block: BlockTiles) -> Result<()> {
        let mut file = self.file.lock().expect("the decoded tiles' file");
        let mut at = self.at.lock().expect("the decoded tiles' index");
        for (i, (_, _, values, valid)) in block.tiles {
            let mut bytes = Vec::with_capacity(values.len() * 5);
            bytes.extend(values.iter().flat_map(|v| v.to_le_bytes()));
            bytes.extend(valid.iter().map(|&v| u8::from(v)));
            let start = file.1;
            file.0
                .write_all(&bytes)
                .context("writing the decoded planet's temporary file")?;
            file.1 += bytes.len() as u64;
            at.insert((block.face, i), start);
        }
        Ok(())
    }

    /// Tile `index` of `face` as decoded: heights and validity at its own stride.
    fn load(&self, face: u8, index: usize) -> Result<Option<Decoded>> {
        let Some(&start) = self
            .at
            .lock()
            .expect("the decoded tiles' index")
            .get(&(face, index))
        else {
            return Ok(None);
        };
        let s = self.strides[usize::from(face)][index];
        let (w, h) = tile_size(self.rects[index], s);
        let mut bytes = vec![0u8; w * h * 5];
        let mut file = self.file.lock().expect("the decoded tiles' file");
        file.0.seek(SeekFrom::Start(start))?;
        file.0.read_exact(&mut bytes)?;
        let end = file.1;
        file.0.seek(SeekFrom::Start(end))?;
        let (v, b) = bytes.split_at(w * h * 4);
        let values = v
            .chunks_exact(4)
            .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        Ok(Some((s, values, b.iter().map(|&b| b != 0).collect())))
    }
}

impl TileHeights for DecodedTiles {
    /// `tile` with the decoded heights and validity at its points (invalid where no block
    /// decoded the tile).
    fn heights(&self, face: u8, index: usize, tile: &PlanetTile) -> Result<PlanetTile> {
        let (x0, y0, _, _) = tile.rect;
        let points = tile.points();
        let (mut values, mut valid) = (vec![0; points], vec![false; points]);
        if let Some((s, dv, dvalid)) = self.load(face, index)? {
            let (w, _) = tile_size(tile.rect, s);
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
