//! The block-wise encode of a planet lattice ([`encode_out_of_core`]): the outline, the apex,
//! the blocks, and each input's resampling error, with the points each step painted.

use std::collections::HashMap;

use super::{LatticeTiles, Resampler};
use crate::error::{BuildError, Result};
use crate::peak_memory::{cpu_seconds, peak_rss};
use crate::planet_input::PlanetInputs;
use crate::planet_resampling::{InputResampling, sample_footprint};
use cbdam_codec::CodecError;
use cbdam_codec::hierarchy::planet::{Apex, ApexViewWriter, PlanetBlocks, default_cut};
use cbdam_codec::hierarchy::{BlockJournal, EncodeOptions, Encoded};
use cbdam_codec::quant::QuantPlan;

/// What [`encode_out_of_core`] made.
pub struct LatticeEncode {
    /// The hierarchy.
    pub encoded: Encoded,
    /// Per input, the resampling error against its samples.
    pub resampling: Vec<InputResampling>,
    /// Distinct lattice points with data.
    pub valid: u64,
    /// Points the lattice's tiles hold.
    pub held_points: u64,
    /// Block by block: how many blocks, and how many lattice tiles they group.
    pub blocks: Option<(usize, usize)>,
    /// Block by block: lattice points painted (resampled from the inputs) by each step, in
    /// order; a point painted again counts again.
    pub painted: Vec<(&'static str, u64)>,
    /// Block by block: points the outline proved to take a fine input's valid sample and did
    /// not paint ([`Resampler::covered`]).
    pub outline_covered: u64,
    /// Block by block: the process's peak resident memory after each step, bytes
    /// ([`crate::peak_memory::peak_rss`]; empty where the system does not say).
    pub peaks: Vec<(&'static str, u64)>,
    /// Block by block: inputs read from their files by each step ([`PlanetInputs::reads`]).
    pub reads: Vec<(&'static str, u64)>,
    /// Block by block: the CPU time (user, system) of each step, seconds
    /// ([`crate::peak_memory::cpu_seconds`]; empty where the system does not say).
    pub cpu: Vec<(&'static str, (f64, f64))>,
}

/// Encodes the inputs resampled onto the `n`, `k` lattice block by block, resampling each tile
/// as it is asked for (a cache of `cache_budget` bytes of tiles; tiles grouped into blocks of
/// about `block_bytes`, [`PlanetBlocks::with_block_bytes`]), finished blocks kept in `journal`,
/// and measures each input's resampling error: the same hierarchy and figures as
/// [`crate::planet::resample`] then [`cbdam_codec::hierarchy::encode_planet`] and
/// [`crate::planet::resampling_error`] of the whole lattice. An input on at most three faces is
/// measured as soon as the blocks of all its tiles are done, while the cache still holds them
/// (a global input after the blocks, once the apex is let go, a band of rows at a time).
pub fn encode_out_of_core(
    inputs: &PlanetInputs,
    n: usize,
    k: u32,
    plan: &QuantPlan,
    enc: &EncodeOptions,
    (cache_budget, block_bytes): (u64, u64),
    journal: &dyn BlockJournal,
) -> Result<LatticeEncode> {
    let mut figures = StepFigures::new(inputs);
    let resampler = Resampler::new(inputs, n, k, plan)?;
    let cut = default_cut(resampler.domain(), resampler.tile_log2());
    // What the apex reads of each tile, kept as the outline paints it.
    let view = ApexViewWriter::new(resampler.domain(), resampler.tile_log2(), cut);
    let (tiles, outline, valid, held_points) =
        LatticeTiles::outline(resampler, cache_budget, Some(&view))?;
    let view = view.finish().map_err(BuildError::from)?;
    let mut painted = PaintedBySteps::new(tiles.resampler.painted());
    figures.after("outline");
    let mut resampling: Vec<Option<InputResampling>> = vec![None; inputs.inputs.len()];
    // Points the resampling error painted during the blocks.
    let mut early = (0, 0);
    let (encoded, counts) = {
        let apex = Apex::EncodeFrom(block_bytes, view);
        let blocks = PlanetBlocks::new(&outline, &tiles, plan.quantizer, enc, cut, apex)
            .and_then(|b| {
                let budget = tiles.share_out(b.diamond_bytes(), block_bytes);
                b.with_block_bytes(tiles.strides(), (budget, 1))
            })
            .map_err(BuildError::from)?;
        painted.step(tiles.resampler.painted(), APEX, ((0, 0), (0, 0)));
        figures.after("apex");
        let tiles_count = tiles.strides().iter().map(Vec::len).sum();
        let counts = (blocks.block_count(), tiles_count);
        let ready = tiles.measured_after_blocks(&blocks.block_of_tiles(), counts.0);
        let mut failed = None;
        let encoded = blocks.finish_with(journal, true, &mut |block| {
            let before = tiles.resampler.painted();
            for &i in &ready[block] {
                match tiles.resampling(i) {
                    Ok(r) => resampling[i] = Some(r),
                    Err(e) => {
                        let message = format!("{e:#}");
                        failed = Some(e);
                        return Err(CodecError::invalid(message));
                    }
                }
            }
            let after = tiles.resampler.painted();
            early = (early.0 + after.0 - before.0, early.1 + after.1 - before.1);
            Ok(())
        });
        if let Some(e) = failed {
            return Err(e);
        }
        (encoded.map_err(BuildError::from)?, counts)
    };
    painted.step(tiles.resampler.painted(), BLOCKS, (early, (0, 0)));
    figures.after("blocks");
    // The apex and the blocks are let go before the global inputs are measured.
    let resampling = resampling
        .into_iter()
        .enumerate()
        .map(|(i, r)| r.map_or_else(|| tiles.resampling(i), Ok))
        .collect::<Result<Vec<_>>>()?;
    painted.step(tiles.resampler.painted(), RESAMPLING, ((0, 0), early));
    figures.after("resampling error");
    Ok(LatticeEncode {
        encoded,
        resampling,
        valid,
        held_points,
        blocks: Some(counts),
        painted: painted.counts,
        outline_covered: tiles.resampler.covered(),
        peaks: figures.peaks,
        reads: figures.reads,
        cpu: figures.cpu,
    })
}

/// The process's peak resident memory, the inputs read and the CPU time (user, system) of
/// each step.
struct StepFigures<'i> {
    inputs: &'i PlanetInputs,
    peaks: Vec<(&'static str, u64)>,
    reads: Vec<(&'static str, u64)>,
    cpu: Vec<(&'static str, (f64, f64))>,
    read_before: u64,
    /// The CPU time when the last step ended.
    cpu_before: Option<(f64, f64)>,
}

impl<'i> StepFigures<'i> {
    /// Before the outline: the inputs read so far were read for the height range.
    fn new(inputs: &'i PlanetInputs) -> Self {
        let read = inputs.reads().0;
        Self {
            inputs,
            peaks: Vec::new(),
            reads: vec![("height range", read)],
            cpu: Vec::new(),
            read_before: read,
            cpu_before: cpu_seconds(),
        }
    }

    /// After `step`.
    fn after(&mut self, step: &'static str) {
        self.peaks.extend(peak_rss().map(|p| (step, p)));
        let read = self.inputs.reads().0;
        self.reads.push((step, read - self.read_before));
        self.read_before = read;
        let now = cpu_seconds();
        if let (Some(a), Some(b)) = (self.cpu_before, now) {
            self.cpu.push((step, (b.0 - a.0, b.1 - a.1)));
        }
        self.cpu_before = now;
    }
}

/// The steps' names in `--timings`: the points painted whole, and in parts of tiles.
const APEX: (&str, &str) = ("apex", "apex (parts of tiles)");
const BLOCKS: (&str, &str) = ("blocks", "blocks (strips of neighbouring tiles)");
const RESAMPLING: (&str, &str) = (
    "resampling error",
    "resampling error (parts of tiles around an input's samples)",
);

/// Points (all, of parts) a step painted for the next, and points the last painted for it.
type Moved = ((u64, u64), (u64, u64));

/// Lattice points painted by each step, whole and in parts of tiles (a part only where some).
struct PaintedBySteps {
    counts: Vec<(&'static str, u64)>,
    /// The resampler's counts (all, of parts) at the end of the last step.
    last: (u64, u64),
}

impl PaintedBySteps {
    /// After the outline, the resampler's counts `now`.
    fn new(now: (u64, u64)) -> Self {
        Self {
            counts: vec![("outline", now.0)],
            last: now,
        }
    }

    /// A step ending at the resampler's counts `now` (all, of parts), less the points `moved.0`
    /// that the next step painted meanwhile, and with `moved.1` that it painted for the last.
    fn step(&mut self, now: (u64, u64), (whole, part): (&'static str, &'static str), moved: Moved) {
        let ((less_all, less_parts), (more_all, more_parts)) = moved;
        let all = now.0 - self.last.0 - less_all + more_all;
        let parts = now.1 - self.last.1 - less_parts + more_parts;
        self.counts.push((whole, all - parts));
        if parts > 0 {
            self.counts.push((part, parts));
        }
        self.last = now;
    }
}

impl LatticeTiles<'_> {
    /// Per block of the `blocks` (`block_of`: the block of each tile in a small one), the
    /// inputs whose resampling error is measured once it is done: each input on at most three
    /// faces ([`sample_footprint`]) whose tiles all lie in those blocks, after the last of them.
    fn measured_after_blocks(
        &self,
        block_of: &HashMap<(u8, usize), usize>,
        blocks: usize,
    ) -> Vec<Vec<usize>> {
        let r = &self.resampler;
        let mut after = vec![Vec::new(); blocks];
        for (i, input) in r.inputs.inputs.iter().enumerate() {
            if sample_footprint(input, r.strides[i], r.side).is_none() {
                continue;
            }
            let last = self
                .input_tiles(i)
                .iter()
                .map(|&(f, t, _)| block_of.get(&(f, t)).copied())
                .collect::<Option<Vec<_>>>()
                .and_then(|b| b.into_iter().max());
            if let Some(b) = last.filter(|&b| b < blocks) {
                after[b].push(i);
            }
        }
        after
    }

    /// How many inputs the lattice is resampled from.
    pub(crate) fn input_count(&self) -> usize {
        self.resampler.inputs.inputs.len()
    }

    /// The tiles (face, index) input `input`'s resampling error reads where its samples lie on
    /// at most three faces ([`sample_footprint`]); `None` for an input measured a band of rows
    /// at a time over every tile it can cover.
    pub(crate) fn inset_tiles(&self, input: usize) -> Option<Vec<(u8, usize)>> {
        let r = &self.resampler;
        let footprint = sample_footprint(&r.inputs.inputs[input], r.strides[input], r.side)?;
        Some(
            self.input_tiles_in(input, Some(footprint.as_slice()))
                .into_iter()
                .map(|(f, t, _)| (f, t))
                .collect(),
        )
    }

    /// `log2` of the stride input `input` reads the tiles at, capped at the tile's side (a
    /// tile held at a finer stride is read at this one).
    pub(crate) fn view_stride_of(&self, input: usize) -> u32 {
        self.resampler.strides[input].min(self.resampler.tile_log2)
    }
}
