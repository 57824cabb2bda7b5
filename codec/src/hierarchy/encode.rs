//! The closed-loop coarse-to-fine encoder (paper §5, "coarse to fine compression").

use std::collections::{BTreeSet, HashMap};

use rayon::prelude::*;

use super::analysis::{LevelField, analysis_fields};
use super::blocks::{Block, BlockJournal, BlockOutput, BlockPlan};
use super::field::{ReconField, TempStorage};
use super::mask::encode_mask;
use super::object_error::{ErrorInput, surface_error};
use super::record_bytes::KeptRecords;
use super::refine::{Refined, gather};
use super::resolution::{Resolution, variable_sets};
use super::roots::{encode_roots, root_grid};
use super::{CodecParams, Encoded, Record};
use crate::CodecError;
use crate::entropy::{Band, BandKind, CoderKind, encode_bands};
use crate::geometry::{DiamondId, Domain, Layout};
use crate::lifting::{
    Alpha, MAX_ABS_HEIGHT, clamp_prediction, predict_cells, predict_inner_vertices,
};
use crate::quant::{HeightGrid, Quantizer};

/// Encoder settings besides the tolerance.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EncodeOptions {
    /// Diamond grid side `N` (`2^k + 1`).
    pub n: usize,
    /// Lifting weight of inner vertices.
    pub alpha: Alpha,
    /// Entropy coder.
    pub coder: CoderKind,
    /// Level pairs above the smallest hierarchy that covers the data with one root.
    pub extra_level_pairs: u32,
}

impl Default for EncodeOptions {
    fn default() -> Self {
        Self {
            n: 65,
            alpha: Alpha::One,
            coder: CoderKind::AdaptiveTokens,
            extra_level_pairs: 0,
        }
    }
}

/// The filtered height the encoder aims for at a lattice point of a level, `None` where it is
/// "don't care" (outside the data or at nodata).
struct Targets<'a> {
    grid: &'a HeightGrid,
    fields: Option<Vec<LevelField>>,
    /// Variable-resolution classes: points without a sample may still be drawn.
    resolution: Option<&'a Resolution>,
    /// `grid` (and `resolution`) hold only the points at multiples of `2^shift`, compacted
    /// ([`HeightGrid::strided`]): the levels above a block plan's cut read no others.
    shift: u32,
}

impl Targets<'_> {
    /// Whether the nodata mask calls `(x, y)` (inside the data rectangle) valid: a sample, or a
    /// point between a coarser input's samples.
    #[inline]
    fn drawn(&self, x: i64, y: i64) -> bool {
        let (x, y) = self.compact(x, y);
        match self.resolution {
            Some(r) => r.drawn(self.grid.width, x, y),
            None => self.grid.get(x, y).is_some(),
        }
    }

    /// `(x, y)` in `grid`'s points.
    #[inline]
    fn compact(&self, x: i64, y: i64) -> (i64, i64) {
        let mask = (1i64 << self.shift) - 1;
        debug_assert!(
            x & mask == 0 && y & mask == 0,
            "({x}, {y}) is not on the targets' lattice of spacing 2^{}",
            self.shift
        );
        (x >> self.shift, y >> self.shift)
    }

    /// What the nodata mask says of `(x, y)`: `None` (don't care) outside the data rectangle.
    #[inline]
    fn mask(&self, params: &CodecParams, x: i64, y: i64) -> Option<bool> {
        params
            .domain
            .data()
            .contains(x, y)
            .then(|| self.drawn(x, y))
    }

    /// Drops the resident pages of a mapped input ([`HeightGrid::release_all`]).
    fn release_all(&self) {
        self.grid.release_all();
        if let Some(r) = self.resolution {
            r.class.release(0..r.class.len());
        }
    }

    #[inline]
    fn at(&self, level: u8, x: i64, y: i64) -> Option<i32> {
        match &self.fields {
            // A valid sample lies in the data rectangle, inside the domain: no reflection, and
            // the input's own value is not needed.
            Some(f) => self
                .grid
                .is_valid(x, y)
                .then(|| f[level as usize].get_in_domain(x, y)),
            None => {
                let (x, y) = self.compact(x, y);
                self.grid.get(x, y)
            }
        }
    }
}

/// The encoder of a lattice of integer heights: [`Encoder::new`], the settings that differ
/// from the defaults, then [`Encoder::encode`].
///
/// ```ignore
/// let encoded = Encoder::new(&grid, plan.quantizer, &opts)
///     .storage(&storage)
///     .in_blocks(&block_plan, &journal)
///     .progress(&tick)
///     .encode()?;
/// ```
///
/// The output depends only on the grid, the quantizer, the options and the resolution; where
/// temporaries live and whether the levels are encoded whole or block by block do not change a
/// byte.
#[derive(Clone, Copy)]
pub struct Encoder<'a> {
    grid: &'a HeightGrid,
    quantizer: Quantizer,
    opts: &'a EncodeOptions,
    resolution: Option<&'a Resolution>,
    storage: &'a TempStorage,
    blocks: Option<(&'a BlockPlan, &'a dyn BlockJournal)>,
    progress: &'a (dyn Fn(usize, usize) + Sync),
}

impl<'a> Encoder<'a> {
    /// Encodes `grid` with residual quantizer `quantizer` and `opts`: by default the whole
    /// domain at once, temporaries in memory, no progress reports.
    pub fn new(grid: &'a HeightGrid, quantizer: Quantizer, opts: &'a EncodeOptions) -> Self {
        Encoder {
            grid,
            quantizer,
            opts,
            resolution: None,
            storage: &TempStorage::Memory,
            blocks: None,
            progress: &|_, _| {},
        }
    }

    /// Variable-resolution data ([`super::resolution`]), when `resolution` is given: `grid`
    /// holds the winning sample of every lattice point that has one, `resolution` says at which
    /// stride each sample was taken and which points between coarse samples are drawn. The
    /// hierarchy is refined only as deep as the data at each place. α = 1 only.
    pub fn resolution(mut self, resolution: Option<&'a Resolution>) -> Self {
        self.resolution = resolution;
        self
    }

    /// Keeps the encoder's large temporaries in `storage` (memory by default).
    pub fn storage(mut self, storage: &'a TempStorage) -> Self {
        self.storage = storage;
        self
    }

    /// Encodes the levels from `plan`'s cut down one block at a time ([`super::blocks`]),
    /// asking `journal` for blocks an earlier run finished and handing it each one this run
    /// finishes. α = 1 only.
    pub fn in_blocks(mut self, plan: &'a BlockPlan, journal: &'a dyn BlockJournal) -> Self {
        self.blocks = Some((plan, journal));
        self
    }

    /// Calls `progress(done, total)` after each diamond (from worker threads). The units are
    /// input samples covered: every level covers the data once and costs about the same, while
    /// a coarse diamond costs as much as thousands of fine ones, so covered area gives a usable
    /// ETA where a diamond count would not.
    pub fn progress(mut self, progress: &'a (dyn Fn(usize, usize) + Sync)) -> Self {
        self.progress = progress;
        self
    }

    /// Encodes.
    ///
    /// Errors if the grid has no valid sample, if the reconstruction would leave the integer
    /// range (a tolerance far too fine for the heights; [`crate::quant::QuantPlan`] normally
    /// refuses those first), or if variable resolution or blocks are asked for with α = ½.
    pub fn encode(self) -> Result<Encoded, CodecError> {
        let one = self.opts.alpha == Alpha::One;
        if self.blocks.is_some() && !one {
            return Err(CodecError::invalid(
                "encoding in blocks needs α = 1 (α = ½ changes vertices, so a block's diamonds \
                 would depend on more than their ancestors' points)",
            ));
        }
        if self.resolution.is_some() && !one {
            return Err(CodecError::invalid(
                "variable-resolution data needs α = 1 (the lifting of α = ½ would constrain the \
                 points between coarse samples)",
            ));
        }
        if let Some(r) = self.resolution {
            r.check(self.grid)?;
        }
        let keeping = match (self.blocks, self.opts.alpha) {
            (Some((plan, journal)), _) => Keeping::Blocks(self.storage, plan, journal),
            (None, Alpha::One) => Keeping::Field(self.storage),
            (None, Alpha::Half) => Keeping::PerDiamond,
        };
        encode_impl(
            self.grid,
            self.resolution,
            self.quantizer,
            self.opts,
            keeping,
            self.progress,
        )
    }
}

/// How the encoder keeps the reconstruction between levels.
#[derive(Clone, Copy)]
enum Keeping<'a> {
    /// Every refined diamond of the previous level as a `(2N−1)²` half-step grid: needed for
    /// α = ½, whose refinements change vertices.
    PerDiamond,
    /// One reconstruction field over the domain ([`ReconField`]); α = 1 only.
    Field(&'a TempStorage),
    /// An apex field and one per block ([`BlockPlan`]), finished blocks kept in a journal;
    /// α = 1 only.
    Blocks(&'a TempStorage, &'a BlockPlan, &'a dyn BlockJournal),
}

fn encode_impl(
    grid: &HeightGrid,
    resolution: Option<&Resolution>,
    quantizer: Quantizer,
    opts: &EncodeOptions,
    strategy: Keeping<'_>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Encoded, CodecError> {
    let setup = Setup::new(grid, resolution, quantizer, opts)?;
    let layout = *setup.params.domain.layout();
    // Work per diamond is about the data it covers: its bounding box clipped to the data.
    let area = |id: &DiamondId| {
        let (x0, y0, x1, y1) = layout.bounds(*id);
        let span =
            |a: i64, b: i64, len: usize| (b.min(len as i64 - 1) - a.max(0) + 1).max(1) as usize;
        span(x0, x1, grid.width) * span(y0, y1, grid.height)
    };
    let total: usize = setup.stored.iter().flatten().map(area).sum();
    let done = std::sync::atomic::AtomicUsize::new(0);
    let tick = |id: &DiamondId| {
        let a = area(id);
        progress(
            done.fetch_add(a, std::sync::atomic::Ordering::Relaxed) + a,
            total,
        );
    };
    let levels = setup.levels(&tick);
    let (records, own_error) = match strategy {
        Keeping::PerDiamond => levels.per_diamond()?,
        Keeping::Field(storage) => {
            assert!(
                opts.alpha == Alpha::One,
                "the reconstruction field needs α = 1"
            );
            levels.field(storage)?
        }
        Keeping::Blocks(storage, plan, journal) => {
            assert!(opts.alpha == Alpha::One, "blocks need α = 1");
            levels.blocks(storage, plan, journal)?
        }
    };
    Ok(setup.finish(records, &own_error))
}

/// What every part of an encode needs besides the reconstruction: the header fields, the
/// targets, the stored diamonds and the coded roots.
struct Setup<'a> {
    /// The input, for the object-space errors (its bounds scanned once: a whole-grid pass).
    error_input: ErrorInput<'a>,
    params: CodecParams,
    targets: Targets<'a>,
    stored: Vec<Vec<DiamondId>>,
    recorded: Option<Vec<BTreeSet<DiamondId>>>,
    root_field: Vec<i32>,
    roots: Vec<u8>,
}

impl<'a> Setup<'a> {
    fn new(
        grid: &'a HeightGrid,
        resolution: Option<&'a Resolution>,
        quantizer: Quantizer,
        opts: &EncodeOptions,
    ) -> Result<Self, CodecError> {
        let (params, targets) = Self::params(
            grid,
            resolution,
            quantizer,
            opts,
            grid.range().is_some(),
            match resolution {
                Some(r) => r.has_holes(),
                None => grid.has_invalid(),
            },
        )?;
        // Single resolution: every stored diamond above the finest level has a record.
        let (stored, recorded) = match resolution {
            Some(r) => {
                let sets = variable_sets(&params.domain, grid.width, r);
                (sets.stored, Some(sets.recorded))
            }
            None => (stored_sets(&params.domain, grid), None),
        };
        let (root_field, roots) = encode_roots(
            &params,
            |_, x, y| targets.at(0, x, y),
            |_, x, y| targets.drawn(x, y),
        )?;
        Ok(Setup {
            error_input: ErrorInput::new(grid),
            params,
            targets,
            stored,
            recorded,
            root_field,
            roots,
        })
    }

    /// The header fields and the targets; `any_valid` and `nodata_mask` measured by the caller.
    fn params(
        grid: &'a HeightGrid,
        resolution: Option<&'a Resolution>,
        quantizer: Quantizer,
        opts: &EncodeOptions,
        any_valid: bool,
        nodata_mask: bool,
    ) -> Result<(CodecParams, Targets<'a>), CodecError> {
        if !any_valid {
            return Err(CodecError::invalid("the input has no valid sample"));
        }
        let domain = Domain::covering(opts.n, grid.width, grid.height, opts.extra_level_pairs)?;
        let layout = *domain.layout();
        let params = CodecParams {
            domain,
            alpha: opts.alpha,
            coder: opts.coder,
            quantizer,
            root_quantizer: super::root_quantizer(quantizer),
            nodata_mask,
            kind: super::RepoKind::Elevation,
        };
        let targets = Targets {
            grid,
            fields: (opts.alpha == Alpha::Half).then(|| analysis_fields(&layout, grid)),
            resolution,
            shift: 0,
        };
        Ok((params, targets))
    }

    /// [`Setup::new`] from what an earlier one measured of the grid ([`GridSummary`]): reads
    /// nothing of the grid, so `grid` need hold only the samples the caller will encode.
    fn from_summary(
        grid: &'a HeightGrid,
        resolution: Option<&'a Resolution>,
        quantizer: Quantizer,
        opts: &EncodeOptions,
        summary: GridSummary,
    ) -> Result<Self, CodecError> {
        let (params, targets) =
            Self::params(grid, resolution, quantizer, opts, true, summary.nodata_mask)?;
        let layout = params.domain.layout();
        let rf = params.domain.root_field();
        let levels = usize::from(layout.finest_level()) + 1;
        if summary.stored.len() != levels
            || summary.recorded.as_ref().is_some_and(|r| r.len() != levels)
            || summary.recorded.is_some() != resolution.is_some()
            || summary.root_field.len() != rf.width * rf.height
        {
            return Err(CodecError::invalid(
                "the grid summary does not match the grid and options",
            ));
        }
        Ok(Setup {
            error_input: ErrorInput::with_bounds(grid, summary.max_abs, summary.all_valid),
            params,
            targets,
            stored: summary.stored,
            recorded: summary
                .recorded
                .map(|r| r.into_iter().map(|l| l.into_iter().collect()).collect()),
            root_field: summary.root_field,
            roots: summary.roots,
        })
    }

    /// What this setup measured of the grid.
    fn summary(&self) -> GridSummary {
        let (max_abs, all_valid) = self.error_input.bounds();
        GridSummary {
            max_abs,
            all_valid,
            nodata_mask: self.params.nodata_mask,
            stored: self.stored.clone(),
            recorded: self
                .recorded
                .as_ref()
                .map(|r| r.iter().map(|l| l.iter().copied().collect()).collect()),
            root_field: self.root_field.clone(),
            roots: self.roots.clone(),
        }
    }

    fn levels<'b>(&'b self, tick: &'b (dyn Fn(&DiamondId) + Sync)) -> Levels<'b> {
        Levels {
            params: &self.params,
            error_input: self.error_input,
            targets: &self.targets,
            stored: &self.stored,
            recorded: self.recorded.as_deref(),
            root_field: &self.root_field,
            tick,
        }
    }

    /// The encoded hierarchy from every stored diamond's record and own error.
    fn finish(self, records: Vec<Record>, own_error: &HashMap<DiamondId, u32>) -> Encoded {
        let (records, leaf_error) =
            saturate_errors(&self.params.domain, &self.stored, records, own_error);
        Encoded {
            params: self.params,
            roots: self.roots,
            records,
            leaf_error,
        }
    }
}

/// What an encode's setup measures of the whole grid (scans of every sample), kept so that a
/// sharded encode's other steps need not read the whole grid again
/// ([`ShardedEncode::summary`], [`ShardedEncode::with_summary`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GridSummary {
    /// The largest `|height|` of a valid sample.
    pub max_abs: i64,
    /// Whether every sample is valid.
    pub all_valid: bool,
    /// Whether the repository carries a nodata mask.
    pub nodata_mask: bool,
    /// The stored diamonds of every level, in id order.
    pub stored: Vec<Vec<DiamondId>>,
    /// Variable resolution only: which stored diamonds get a record, per level, in id order.
    pub recorded: Option<Vec<Vec<DiamondId>>>,
    /// The root field's reconstructed values.
    pub root_field: Vec<i32>,
    /// The coded root field.
    pub roots: Vec<u8>,
}

/// An α = 1 encode split as [`Encoder::in_blocks`] splits it, into parts that run apart (in other
/// processes, on other machines) and are put together without encoding again: the apex (the
/// levels above the plan's cut, over the whole domain), each block of the finer levels, seeded
/// from the apex's field, and [`ShardedEncode::finish`], which saturates the object errors over
/// all of them. The result is the same as [`Encoder::in_blocks`]'s, bit for bit.
///
/// The apex only refines: the object errors of its levels (a scan of every sample per level,
/// about half its work) are measured by the blocks, each over its own square, and the finish
/// takes each diamond's largest. So the apex is quick, and that work is shared out.
pub struct ShardedEncode<'a> {
    setup: Setup<'a>,
    plan: BlockPlan,
    blocks: Vec<Block>,
}

/// The apex's reconstruction at the cut, as the blocks of a [`ShardedEncode`] read it.
pub struct ApexField(ReconField);

/// What the apex of a [`ShardedEncode`] produced: the records of the levels above the cut (as a
/// [`BlockOutput`], own errors 0: the blocks measure them), and the values of its field, which
/// every block starts from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ApexOutput {
    /// Records (object errors not yet saturated) of the apex levels, and their diamonds with
    /// own error 0 (the blocks' measures replace it).
    pub output: BlockOutput,
    /// The apex field's values, row-major over the lattice of spacing
    /// `2^`[`BlockPlan::apex_shift`].
    pub field: Vec<i32>,
}

impl<'a> ShardedEncode<'a> {
    /// The encode of `grid` (variable resolution with `resolution`) in `plan`'s blocks.
    pub fn new(
        grid: &'a HeightGrid,
        resolution: Option<&'a Resolution>,
        quantizer: Quantizer,
        opts: &EncodeOptions,
        plan: BlockPlan,
    ) -> Result<Self, CodecError> {
        Self::check_alpha(opts)?;
        if let Some(r) = resolution {
            r.check(grid)?;
        }
        Ok(Self::of(
            Setup::new(grid, resolution, quantizer, opts)?,
            plan,
        ))
    }

    fn check_alpha(opts: &EncodeOptions) -> Result<(), CodecError> {
        if opts.alpha != Alpha::One {
            return Err(CodecError::invalid(
                "a sharded encode needs α = 1 (α = ½ changes vertices, so a block's diamonds \
                 would depend on more than their ancestors' points)",
            ));
        }
        Ok(())
    }

    fn of(setup: Setup<'a>, plan: BlockPlan) -> Self {
        let blocks = plan.blocks(setup.params.layout());
        ShardedEncode {
            setup,
            plan,
            blocks,
        }
    }

    /// [`ShardedEncode::new`] from the [`GridSummary`] of an earlier one over the same grid
    /// ([`ShardedEncode::summary`]): nothing of the grid is read until a block (or the apex) is
    /// encoded, and a block reads only its field's rectangle
    /// ([`ShardedEncode::block_field_rect`]), so `grid` need hold only those samples (and
    /// [`ShardedEncode::finish`] needs none). The output is the same.
    pub fn with_summary(
        grid: &'a HeightGrid,
        resolution: Option<&'a Resolution>,
        quantizer: Quantizer,
        opts: &EncodeOptions,
        plan: BlockPlan,
        summary: GridSummary,
    ) -> Result<Self, CodecError> {
        Self::check_alpha(opts)?;
        if resolution.is_some_and(|r| r.class.len() != grid.valid.len()) {
            return Err(CodecError::invalid(
                "resolution classes do not match the grid's size",
            ));
        }
        let setup = Setup::from_summary(grid, resolution, quantizer, opts, summary)?;
        Ok(Self::of(setup, plan))
    }

    /// What the setup measured of the whole grid, for [`ShardedEncode::with_summary`].
    pub fn summary(&self) -> GridSummary {
        self.setup.summary()
    }

    /// The lattice rectangle `(x0, y0, x1, y1)` (inclusive, possibly beyond the grid) whose
    /// samples block `index` reads.
    pub fn block_field_rect(&self, index: usize) -> Option<(i64, i64, i64, i64)> {
        self.blocks.get(index).map(|b| b.field_rect)
    }

    /// How many blocks the plan makes.
    pub fn block_count(&self) -> usize {
        self.blocks.len()
    }

    /// Encodes the levels above the cut (their refinements; not their errors).
    pub fn apex(&self, storage: &TempStorage) -> Result<ApexOutput, CodecError> {
        let levels = self.setup.levels(&|_| {});
        let (apex, (records, own_errors)) = levels.apex(storage, &self.plan, false)?;
        Ok(ApexOutput {
            output: BlockOutput {
                records,
                own_errors: own_errors.into_iter().collect(),
            },
            field: apex.to_vec(),
        })
    }

    /// The apex's field from its values ([`ApexOutput::field`]), for [`ShardedEncode::block`]:
    /// made once for all the blocks of a shard.
    pub fn apex_field(
        &self,
        values: &[i32],
        storage: &TempStorage,
    ) -> Result<ApexField, CodecError> {
        let apex = self.plan.apex_field(self.setup.params.layout(), storage)?;
        apex.fill_from(values)?;
        Ok(ApexField(apex))
    }

    /// Encodes block `index` from the apex's field ([`ShardedEncode::apex_field`]). Its own
    /// errors include, besides its diamonds', those of the apex's diamonds over the block's
    /// square.
    pub fn block(
        &self,
        apex: &ApexField,
        index: usize,
        storage: &TempStorage,
    ) -> Result<BlockOutput, CodecError> {
        let Some(block) = self.blocks.get(index) else {
            return Err(CodecError::invalid(format!(
                "block {index} does not exist: the plan has {} blocks",
                self.blocks.len()
            )));
        };
        self.setup
            .levels(&|_| {})
            .block_and_apex_errors(&apex.0, &self.plan, block, storage)
    }

    /// The encoded hierarchy from the apex's output and every block's, in any order. A
    /// diamond's own error is the largest any part gives it.
    pub fn finish(
        self,
        parts: impl IntoIterator<Item = BlockOutput>,
    ) -> Result<Encoded, CodecError> {
        // A merge of a mapped lattice's shards spills their records, as `cbdam build` does.
        let mut records = KeptRecords::new(self.setup.targets.grid.windows())?;
        let mut own_error: HashMap<DiamondId, u32> = HashMap::new();
        for part in parts {
            records.extend(part.records)?;
            for (id, e) in part.own_errors {
                let max = own_error.entry(id).or_insert(e);
                *max = (*max).max(e);
            }
        }
        // Every stored diamond's own error is needed to saturate its ancestors'.
        if let Some(id) = self
            .setup
            .stored
            .iter()
            .flatten()
            .find(|id| !own_error.contains_key(id))
        {
            return Err(CodecError::invalid(format!(
                "diamond {id} is in none of the parts given: a block is missing"
            )));
        }
        Ok(self.setup.finish(records.finish()?, &own_error))
    }
}

/// Sets each record's object error to the largest own error of its diamond and every stored
/// descendant (fine to coarse: a diamond's error bounds every descendant's, so the error a
/// renderer sees never increases when it refines), and sorts the records by id. Returns them
/// with the finest level's largest own error.
pub(super) fn saturate_errors(
    domain: &Domain,
    stored: &[Vec<DiamondId>],
    mut records: Vec<Record>,
    own_error: &HashMap<DiamondId, u32>,
) -> (Vec<Record>, u32) {
    let finest = domain.finest_level();
    let mut saturated: HashMap<DiamondId, u32> = HashMap::new();
    for level in (0..=finest).rev() {
        for &id in &stored[level as usize] {
            let children = domain.children(id).into_iter().flatten();
            let e = children
                .filter_map(|c| saturated.get(&c))
                .fold(own_error[&id], |a, &b| a.max(b));
            saturated.insert(id, e);
        }
    }
    for r in &mut records {
        r.object_error = saturated[&r.id];
    }
    let leaf_error = stored[finest as usize]
        .iter()
        .map(|id| own_error[id])
        .max()
        .unwrap_or(0);
    records.sort_by_key(|r| r.id);
    (records, leaf_error)
}

/// Records (object errors not yet saturated) and each stored diamond's own object error.
type LevelOutput = (Vec<Record>, HashMap<DiamondId, u32>);

/// What the coarse-to-fine pass over the levels works on.
struct Levels<'a> {
    params: &'a CodecParams,
    /// The input, for the object-space errors.
    error_input: ErrorInput<'a>,
    targets: &'a Targets<'a>,
    stored: &'a [Vec<DiamondId>],
    /// Which stored diamonds get a record, per level; `None`: all above the finest level.
    recorded: Option<&'a [BTreeSet<DiamondId>]>,
    root_field: &'a [i32],
    tick: &'a (dyn Fn(&DiamondId) + Sync),
}

/// The record of a refined diamond with reconstructed grid `p` (object error not yet
/// saturated).
pub(super) fn record_of(id: DiamondId, p: &[i32], bytes: Vec<u8>) -> Record {
    let (min, max) = p
        .iter()
        .fold((i32::MAX, i32::MIN), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    Record {
        id,
        bytes: bytes.into(),
        object_error: 0,
        min,
        max,
    }
}

impl Levels<'_> {
    /// The record of a refined diamond with reconstructed grid `p`.
    fn record(id: DiamondId, p: &[i32], bytes: Vec<u8>) -> Record {
        record_of(id, p, bytes)
    }

    /// The levels with the previous level's refinements kept per diamond (any α).
    fn per_diamond(&self) -> Result<LevelOutput, CodecError> {
        let layout = self.params.layout();
        let (finest, n) = (layout.finest_level(), layout.n());
        let mut records: Vec<Record> = Vec::new();
        let mut own_error: HashMap<DiamondId, u32> = HashMap::new();
        let mut prev: HashMap<DiamondId, Refined> = HashMap::new();
        for level in 0..=finest {
            let grids_of = |id: DiamondId| -> Vec<i32> {
                let mut p = vec![0i32; n * n];
                if level == 0 {
                    root_grid(&self.params.domain, self.root_field, id, &mut p);
                } else {
                    let parents = (self.params.domain)
                        .parents(id)
                        .map(|pid| pid.map(|pid| &prev[&pid]));
                    gather(&self.params.domain, id, parents, &mut p);
                }
                p
            };
            if level == finest {
                for (id, e) in self.stored[level as usize]
                    .par_iter()
                    .map(|&id| {
                        let e = surface_error(layout, id, &grids_of(id), &self.error_input);
                        (self.tick)(&id);
                        (id, e)
                    })
                    .collect::<Vec<_>>()
                {
                    own_error.insert(id, e);
                }
                break;
            }
            let results = self.stored[level as usize]
                .par_iter()
                .map(|&id| {
                    let p = grids_of(id);
                    let err = surface_error(layout, id, &p, &self.error_input);
                    let r = refine_encode(
                        self.params,
                        id,
                        &p,
                        |x, y| self.targets.at(level + 1, x, y),
                        |x, y| self.targets.mask(self.params, x, y),
                    )?;
                    let vertices = r.vertices.as_deref().unwrap_or(&p);
                    let refined = Refined::from_parts(n, vertices, &r.cells);
                    (self.tick)(&id);
                    Ok((id, refined, Self::record(id, &p, r.bytes), err))
                })
                .collect::<Result<Vec<_>, CodecError>>()?;
            prev.clear();
            for (id, refined, record, err) in results {
                own_error.insert(id, err);
                prev.insert(id, refined);
                records.push(record);
            }
        }
        Ok((records, own_error))
    }

    /// The levels with one reconstruction field (α = 1): each refinement writes its new points
    /// into the field, and the next level gathers from it.
    fn field(&self, storage: &TempStorage) -> Result<LevelOutput, CodecError> {
        let layout = self.params.layout();
        let (ex, ey) = layout.face_extent();
        let field = ReconField::new(ex as usize + 1, ey as usize + 1, storage)?;
        self.seed_roots(&field);
        let mut records: Vec<Record> = Vec::new();
        let mut own_error: HashMap<DiamondId, u32> = HashMap::new();
        for level in 0..=layout.finest_level() {
            let ids = &self.stored[level as usize];
            for (id, record, err) in self.encode_level(&field, level, ids, &|_| true, true)? {
                own_error.insert(id, err);
                records.extend(record);
            }
        }
        Ok((records, own_error))
    }

    /// The levels with a reconstruction field per block ([`BlockPlan`], α = 1): an apex field
    /// holds only the points of the levels above the plan's cut, and each block of the finer
    /// levels is encoded in a field of its own that holds the block and the reach of its
    /// diamonds' ancestors ([`BlockPlan::reach`]). Diamonds of that margin are encoded again
    /// by every block that needs them, but recorded only by the block that owns their centre,
    /// so the output is the same as [`Levels::field`]'s.
    fn blocks(
        &self,
        storage: &TempStorage,
        plan: &BlockPlan,
        journal: &dyn BlockJournal,
    ) -> Result<LevelOutput, CodecError> {
        let layout = self.params.layout();
        let finest = layout.finest_level();
        let cut = plan.cut_level.min(finest);
        if self.targets.grid.windows() {
            // The setup's scans are over: the apex and the blocks read copies of parts of the
            // mapped input, not the mapping.
            self.targets.release_all();
        }
        // The apex's own errors are measured by the blocks, each over its square, as in a
        // sharded encode: a whole-grid scan per apex level would read a mapped input whole.
        let (apex, (apex_records, mut own_error)) = self.apex(storage, plan, false)?;
        // A mapped lattice's records go to a temporary file as their blocks finish: the
        // repository would otherwise be held in memory beside the fields ([`KeptRecords`]).
        let mut records = KeptRecords::new(self.targets.grid.windows())?;
        records.extend(apex_records)?;
        for (index, block) in plan.blocks(layout).into_iter().enumerate() {
            let out = match journal.load(index)? {
                Some(out) => {
                    for level in cut..=finest {
                        block
                            .select(&self.stored[level as usize], 0)
                            .iter()
                            .for_each(self.tick);
                    }
                    out
                }
                None => {
                    let out = self.block_and_apex_errors(&apex, plan, &block, storage)?;
                    journal.save(index, &out)?;
                    out
                }
            };
            // An apex diamond's own error is the largest over the blocks' squares.
            for (id, e) in out.own_errors {
                let max = own_error.entry(id).or_insert(e);
                *max = (*max).max(e);
            }
            records.extend(out.records)?;
        }
        Ok((records.finish()?, own_error))
    }

    /// The levels above `plan`'s cut, in the apex field ([`Levels::blocks`]): the field, the
    /// records and the own errors (0 unless `measure_errors`: a sharded encode measures them
    /// in its blocks, [`Levels::apex_errors`]).
    fn apex(
        &self,
        storage: &TempStorage,
        plan: &BlockPlan,
        measure_errors: bool,
    ) -> Result<(ReconField, LevelOutput), CodecError> {
        let layout = self.params.layout();
        let grid = self.targets.grid;
        if grid.windows() && !measure_errors && self.targets.shift == 0 {
            // Its points, copied from the mapped files: read in place, each scattered point
            // would map a whole folio of the page cache (up to 2 MiB, measured on Linux 6.18).
            let shift = plan.apex_shift(layout);
            debug_assert!(self.targets.fields.is_none(), "blocks need α = 1");
            let points = grid.strided(shift)?;
            let classes = self
                .targets
                .resolution
                .map(|r| r.strided(grid.width, shift))
                .transpose()?;
            let targets = Targets {
                grid: &points,
                fields: None,
                resolution: classes.as_ref(),
                shift,
            };
            return Levels {
                targets: &targets,
                ..*self
            }
            .apex(storage, plan, false);
        }
        let cut = plan.cut_level.min(layout.finest_level());
        let mut records: Vec<Record> = Vec::new();
        let mut own_error: HashMap<DiamondId, u32> = HashMap::new();
        let apex = plan.apex_field(layout, storage)?;
        self.seed_roots(&apex);
        for level in 0..cut {
            let ids = &self.stored[level as usize];
            for (id, record, err) in
                self.encode_level(&apex, level, ids, &|_| true, measure_errors)?
            {
                own_error.insert(id, err);
                records.extend(record);
            }
        }
        Ok((apex, (records, own_error)))
    }

    /// One block of the fine levels ([`Levels::block`]) and the errors of the apex's diamonds
    /// over its square ([`Levels::apex_errors`]). An input in mapped files is read through a
    /// window of the block's field ([`HeightGrid::window`]): the block's reads, at random under
    /// every diamond, then touch memory instead of faulting in the file's pages.
    fn block_and_apex_errors(
        &self,
        apex: &ReconField,
        plan: &BlockPlan,
        block: &Block,
        storage: &TempStorage,
    ) -> Result<BlockOutput, CodecError> {
        let both = |levels: &Levels| -> Result<BlockOutput, CodecError> {
            let mut out = levels.block(apex, plan, block, storage)?;
            out.own_errors.extend(levels.apex_errors(apex, plan, block));
            Ok(out)
        };
        let grid = self.targets.grid;
        if !grid.windows() {
            return both(self);
        }
        debug_assert!(self.targets.fields.is_none(), "blocks need α = 1");
        let window = grid.window(block.field_rect)?;
        let classes = self
            .targets
            .resolution
            .map(|r| r.window(grid.width, block.field_rect))
            .transpose()?;
        let targets = Targets {
            grid: &window,
            fields: None,
            resolution: classes.as_ref(),
            shift: 0,
        };
        let (max_abs, all_valid) = self.error_input.bounds();
        both(&Levels {
            error_input: ErrorInput::with_bounds(&window, max_abs, all_valid),
            targets: &targets,
            ..*self
        })
    }

    /// One block of the fine levels ([`Levels::blocks`]): its diamonds' records and errors.
    fn block(
        &self,
        apex: &ReconField,
        plan: &BlockPlan,
        block: &Block,
        storage: &TempStorage,
    ) -> Result<BlockOutput, CodecError> {
        let layout = self.params.layout();
        let cut = plan.cut_level.min(layout.finest_level());
        let field = block.field(storage)?;
        // The block's lattice points of the coarse levels, from the apex.
        for (x, y) in block.apex_points() {
            field.set(x, y, apex.get(x, y));
        }
        let mut out = BlockOutput::default();
        for level in cut..=layout.finest_level() {
            let reach = plan.reach(layout, level);
            let ids = block.select(&self.stored[level as usize], reach);
            let owned = |id: DiamondId| block.owns(id);
            for (id, record, err) in self.encode_level(&field, level, &ids, &owned, true)? {
                if owned(id) {
                    out.own_errors.push((id, err));
                    out.records.extend(record);
                }
            }
        }
        Ok(out)
    }

    /// The object errors of the levels above `plan`'s cut (the apex's diamonds, reconstructed
    /// in `apex`) over the samples of `block`'s owned rectangle: for each stored apex diamond
    /// that reaches the rectangle. The blocks' rectangles tile the domain, so the largest of a
    /// diamond's errors over all blocks is its own error ([`ShardedEncode::finish`] takes it).
    fn apex_errors(
        &self,
        apex: &ReconField,
        plan: &BlockPlan,
        block: &Block,
    ) -> Vec<(DiamondId, u32)> {
        let layout = self.params.layout();
        let n = layout.n();
        let cut = plan.cut_level.min(layout.finest_level());
        let (x0, y0, x1, y1) = block.owned;
        let input = self.error_input.clipped(block.owned);
        let reaches = |id: &DiamondId| {
            let (a0, b0, a1, b1) = layout.bounds(*id);
            a0 <= x1 && a1 >= x0 && b0 <= y1 && b1 >= y0
        };
        let ids: Vec<DiamondId> = self.stored[..cut as usize]
            .iter()
            .flatten()
            .copied()
            .filter(reaches)
            .collect();
        ids.par_iter()
            .map(|&id| {
                let mut p = vec![0i32; n * n];
                if id.level == 0 {
                    root_grid(&self.params.domain, self.root_field, id, &mut p);
                } else {
                    apex.gather(&self.params.domain, id, &mut p);
                }
                (id, surface_error(layout, id, &p, &input))
            })
            .collect()
    }

    /// Writes level 0's vertices (the root field, at spacing `2^K`) into `field`.
    fn seed_roots(&self, field: &ReconField) {
        let rf = self.params.domain.root_field();
        let (rw, rh, s) = (rf.width, rf.height, rf.spacing);
        for (k, &v) in self.root_field.iter().enumerate() {
            field.set((k % rw) as i64 * s, (k / rw) as i64 * s, v);
        }
        debug_assert_eq!(self.root_field.len(), rw * rh);
    }

    /// Encodes the diamonds `ids` of `level` against `field`, writing their new points into it:
    /// for each, its record (refined diamonds above the finest level) and own object error (0
    /// unless `measure_errors`). Progress counts the diamonds `counted` says.
    fn encode_level(
        &self,
        field: &ReconField,
        level: u8,
        ids: &[DiamondId],
        counted: &(dyn Fn(DiamondId) -> bool + Sync),
        measure_errors: bool,
    ) -> Result<Vec<(DiamondId, Option<Record>, u32)>, CodecError> {
        let layout = self.params.layout();
        let (finest, n) = (layout.finest_level(), layout.n());
        let grid_of = |id: DiamondId| -> Vec<i32> {
            let mut p = vec![0i32; n * n];
            if level == 0 {
                root_grid(&self.params.domain, self.root_field, id, &mut p);
            } else {
                field.gather(&self.params.domain, id, &mut p);
            }
            p
        };
        ids.par_iter()
            .map(|&id| {
                let p = grid_of(id);
                let err = if measure_errors {
                    surface_error(layout, id, &p, &self.error_input)
                } else {
                    0
                };
                let refines = level < finest
                    && self
                        .recorded
                        .is_none_or(|r| r[level as usize].contains(&id));
                let record = if refines {
                    let r = refine_encode(
                        self.params,
                        id,
                        &p,
                        |x, y| self.targets.at(level + 1, x, y),
                        |x, y| self.targets.mask(self.params, x, y),
                    )?;
                    write_cells(field, layout, id, &r.cells);
                    Some(Self::record(id, &p, r.bytes))
                } else {
                    None
                };
                if counted(id) {
                    (self.tick)(&id);
                }
                Ok((id, record, err))
            })
            .collect()
    }
}

/// Writes the cell values of a refinement of `id` (the points new at the next level) into the
/// field; those outside the domain (edge diamonds' mirrored halves) are never read back.
fn write_cells(field: &ReconField, layout: &Layout, id: DiamondId, cells: &[i32]) {
    let m = layout.n() - 1;
    let g = layout.grid(id);
    for cj in 0..m {
        for ci in 0..m {
            let (x2, y2) = g.point2(2 * ci as i64 + 1, 2 * cj as i64 + 1);
            let (x, y) = (x2 / 2, y2 / 2);
            if field.contains(x, y) {
                field.set(x, y, cells[cj * m + ci]);
            }
        }
    }
}

/// What one refinement on the encoder side produces.
pub(super) struct Refinement {
    /// Reconstructed cell centres, `(N−1)²`.
    pub(super) cells: Vec<i32>,
    /// Reconstructed vertices, `N²`, when α = ½ changed them (`None`: the input grid).
    vertices: Option<Vec<i32>>,
    /// The coded record.
    pub(super) bytes: Vec<u8>,
}

/// One refinement on the encoder side (`target` and `mask` in `id`'s face frame, `mask` saying
/// `Some(valid)` where the nodata mask cares): quantized residuals against the reconstruction
/// (eqs. 5–8), the refined reconstruction, and the coded record.
pub(super) fn refine_encode(
    params: &CodecParams,
    id: DiamondId,
    p: &[i32],
    target: impl Fn(i64, i64) -> Option<i32>,
    mask: impl Fn(i64, i64) -> Option<bool>,
) -> Result<Refinement, CodecError> {
    let layout = params.layout();
    let n = layout.n();
    let m = n - 1;
    let g = layout.grid(id);
    let q = params.quantizer;
    let step = i64::from(q.step());
    let overflow = || {
        CodecError::invalid(
            "reconstructed heights overflow the integer range; use a larger tolerance",
        )
    };
    let mut cells = vec![0i32; m * m];
    predict_cells(p, n, &mut cells);
    for c in &mut cells {
        *c = clamp_prediction(i64::from(*c)) as i32;
    }
    let mut dc = vec![0i32; m * m];
    for cj in 0..m {
        for ci in 0..m {
            let (x2, y2) = g.point2(2 * ci as i64 + 1, 2 * cj as i64 + 1);
            debug_assert!(
                x2 % 2 == 0 && y2 % 2 == 0,
                "cell centres of refinable levels are lattice points"
            );
            let k = cj * m + ci;
            if let Some(t) = target(x2 / 2, y2 / 2) {
                let pred = i64::from(cells[k]);
                let idx = q.index(i64::from(t) - pred);
                let v = pred + idx * step;
                if v.abs() > i64::from(MAX_ABS_HEIGHT) {
                    return Err(overflow());
                }
                dc[k] = idx as i32;
                cells[k] = v as i32;
            }
        }
    }
    let mut vertices = None;
    let mut dv = Vec::new();
    if params.alpha == Alpha::Half {
        let vertices = vertices.insert(p.to_vec());
        let k = n - 2;
        dv = vec![0i32; k * k];
        // The decoder's batch prediction (`refine`), so both sides compute it the same way.
        let mut vpred = vec![0i32; k * k];
        predict_inner_vertices(&cells, n, &mut vpred);
        for j in 1..n - 1 {
            for i in 1..n - 1 {
                let (x, y) = g.point(i as i64, j as i64);
                // Eq. 8 with P̃: the decoder never has P, so it predicts 2P̃ − Pred_V(C̃).
                let pred = clamp_prediction(
                    2 * i64::from(p[j * n + i]) - i64::from(vpred[(j - 1) * k + (i - 1)]),
                );
                let (idx, v) = match target(x, y) {
                    Some(t) => {
                        let idx = q.index(i64::from(t) - pred);
                        (idx, pred + idx * step)
                    }
                    None => (0, pred),
                };
                if v.abs() > i64::from(MAX_ABS_HEIGHT) {
                    return Err(overflow());
                }
                dv[(j - 1) * k + (i - 1)] = idx as i32;
                vertices[j * n + i] = v as i32;
            }
        }
    }
    let mut bands = vec![Band {
        kind: BandKind::Cells,
        width: m,
        height: m,
        values: &dc,
    }];
    if params.alpha == Alpha::Half {
        bands.push(Band {
            kind: BandKind::Vertices,
            width: n - 2,
            height: n - 2,
            values: &dv,
        });
    }
    let mut bytes = Vec::new();
    if params.nodata_mask {
        // The validity of the level-`l+1` points of the square (equal-parity half-step points)
        // where `mask` cares (in the data rectangle); the rest is don't care.
        let all_valid = std::cell::Cell::new(true);
        let cared = |a: usize, b: usize| -> Option<bool> {
            if a % 2 != b % 2 {
                return None;
            }
            let (x2, y2) = g.point2(a as i64, b as i64);
            let (x, y) = (x2 / 2, y2 / 2);
            let v = mask(x, y);
            if v == Some(false) {
                all_valid.set(false);
            }
            v
        };
        encode_mask(2 * n - 1, 2 * n - 1, &cared, &mut bytes);
        let mask_len = bytes.len();
        encode_bands(params.coder, &bands, &mut bytes);
        // An empty record means "all valid, all residuals zero", as without a mask.
        if all_valid.get() && bytes.len() == mask_len {
            bytes.clear();
        }
    } else {
        encode_bands(params.coder, &bands, &mut bytes);
    }
    Ok(Refinement {
        cells,
        vertices,
        bytes,
    })
}

/// The stored diamonds of every level `0..=L`, sorted: the finest diamonds that meet a valid
/// sample, and all their ancestors (a child's grid comes half from each parent, and some
/// parents do not touch the data themselves).
pub(crate) fn stored_sets(domain: &Domain, grid: &HeightGrid) -> Vec<Vec<DiamondId>> {
    let layout = domain.layout();
    let (w, h) = (grid.width, grid.height);
    let finest = layout.finest_level();
    let r = layout.radius(finest) as usize;
    let (ex, ey) = layout.face_extent();
    // Leaf (a, b) is centred at ((2a+1)r, (2b+1)r); it exists while the centre is inside the
    // domain, and is stored when its closed box [2ar, 2ar + 2r] × [2br, 2br + 2r] holds a valid
    // sample. Scanning each leaf's rows with an early exit keeps this one pass over the mask at
    // worst, with no per-sample table (a summed-area table would cost 4 bytes per sample).
    let count = |extent: i64, len: usize| {
        let in_domain = (extent as usize).div_ceil(2 * r);
        let reaching_data = len.saturating_sub(1) / (2 * r) + 1;
        in_domain.min(reaching_data)
    };
    let (nx, ny) = (count(ex, w), count(ey, h));
    let rows: Vec<Vec<bool>> = (0..ny)
        .into_par_iter()
        .map(|b| {
            let mut hit = vec![false; nx];
            for y in (2 * b * r)..=((2 * b + 2) * r).min(h - 1) {
                let row = &grid.valid[y * w..(y + 1) * w];
                grid.valid.touched(w);
                for (a, hit) in hit.iter_mut().enumerate() {
                    if !*hit {
                        let (x0, x1) = (2 * a * r, ((2 * a + 2) * r).min(w - 1));
                        *hit = row[x0..=x1].iter().any(|&v| v);
                    }
                }
            }
            hit
        })
        .collect();
    let mut leaves = Vec::new();
    for (b, row) in rows.iter().enumerate() {
        for (a, &hit) in row.iter().enumerate() {
            if hit {
                let (cx, cy) = ((2 * a + 1) * r, (2 * b + 1) * r);
                leaves.push(DiamondId::new(finest, cx as u32, cy as u32));
            }
        }
    }
    with_ancestors(domain, leaves)
}

/// The stored sets of every level from the finest level's stored diamonds: each coarser level
/// holds the parents of the next finer level's, in id order.
pub(crate) fn with_ancestors(domain: &Domain, leaves: Vec<DiamondId>) -> Vec<Vec<DiamondId>> {
    let finest = domain.finest_level();
    let mut sets = vec![Vec::new(); finest as usize + 1];
    sets[finest as usize] = leaves;
    for level in (0..finest as usize).rev() {
        let parents: BTreeSet<DiamondId> = sets[level + 1]
            .iter()
            .flat_map(|&d| domain.parents(d))
            .flatten()
            .collect();
        sets[level] = parents.into_iter().collect();
    }
    sets
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quant::QuantPlan;
    use crate::samples::{Dem, SampleType};
    use proptest::prelude::*;

    /// The leaf selection by summed-area table that `stored_sets` replaced: the reference.
    fn leaves_by_table(layout: &Layout, grid: &HeightGrid) -> Vec<DiamondId> {
        let (w, h) = (grid.width, grid.height);
        let mut sat = vec![0u32; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0u32;
            for x in 0..w {
                row += u32::from(grid.valid[y * w + x]);
                sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
            }
        }
        let count = |x0: i64, y0: i64, x1: i64, y1: i64| -> u32 {
            let (x0, y0) = (x0.max(0) as usize, y0.max(0) as usize);
            let (x1, y1) = (
                (x1 + 1).min(w as i64) as usize,
                (y1 + 1).min(h as i64) as usize,
            );
            if x0 >= x1 || y0 >= y1 {
                return 0;
            }
            sat[y1 * (w + 1) + x1] + sat[y0 * (w + 1) + x0]
                - sat[y0 * (w + 1) + x1]
                - sat[y1 * (w + 1) + x0]
        };
        let finest = layout.finest_level();
        let r = layout.radius(finest);
        let (ex, ey) = layout.face_extent();
        let mut leaves = Vec::new();
        for cy in (r..ey.min(h as i64 - 1 + r + 1)).step_by(2 * r as usize) {
            for cx in (r..ex.min(w as i64 - 1 + r + 1)).step_by(2 * r as usize) {
                if count(cx - r, cy - r, cx + r, cy + r) > 0 {
                    leaves.push(DiamondId::new(finest, cx as u32, cy as u32));
                }
            }
        }
        leaves
    }

    /// Rough terrain with a few nodata holes, deterministic in `seed`.
    fn terrain(w: usize, h: usize, holes: &[u16], seed: u64) -> HeightGrid {
        let mut s = seed | 1;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let values = (0..w * h)
            .map(|k| {
                let (x, y) = ((k % w) as f64, (k / w) as f64);
                let smooth = 300.0 * (x / 9.0).sin() * (y / 13.0).cos() + 4.0 * x;
                smooth as i32 + (next() % 41) as i32 - 20
            })
            .collect();
        let mut g = HeightGrid::all_valid(w, h, values);
        for &hole in holes {
            let c = hole as usize % (w * h);
            // A small square hole, so whole leaves can lose all their data.
            for k in [c, c + 1, c + w, c + w + 1] {
                if k < w * h {
                    g.valid[k] = false;
                }
            }
        }
        g
    }

    fn both_ways(grid: &HeightGrid, q: Quantizer, opts: &EncodeOptions, storage: &TempStorage) {
        let old = encode_impl(grid, None, q, opts, Keeping::PerDiamond, &|_, _| {}).unwrap();
        let new = encode_impl(grid, None, q, opts, Keeping::Field(storage), &|_, _| {}).unwrap();
        assert!(
            old == new,
            "field and per-diamond encoders differ on {}×{} {opts:?}",
            grid.width,
            grid.height
        );
    }

    /// The whole-domain field encoder against the block encoder with `plan`.
    fn in_blocks_too(grid: &HeightGrid, q: Quantizer, opts: &EncodeOptions, plan: &BlockPlan) {
        let whole = encode_impl(
            grid,
            None,
            q,
            opts,
            Keeping::Field(&TempStorage::Memory),
            &|_, _| {},
        )
        .unwrap();
        // In memory, and the same grid in mapped files: there the apex reads a copy of its
        // points and each block a window of its field, not the mapping (on Unix; elsewhere the
        // mapping in place), and the records go to a spill file.
        let mapped = grid.copied_to(&TempStorage::File(None)).unwrap();
        assert_eq!(mapped.windows(), cfg!(unix));
        for (input, storage) in [(grid, "memory"), (&mapped, "mapped files")] {
            let blocks = Encoder::new(input, q, opts)
                .in_blocks(plan, &super::super::blocks::NoJournal)
                .encode()
                .unwrap();
            assert!(
                whole == blocks,
                "block encoder of a grid in {storage} differs on {}×{} {opts:?} {plan:?}",
                grid.width,
                grid.height
            );
        }
        // The same split run as shards would run it: each part from its own encoder (another
        // process), the apex's field passed as values, the parts put together in reverse. The
        // blocks and the merge are set up from the apex's summary of the grid, each block
        // given only the samples of its field's rectangle (the rest nodata) and the merge none:
        // what they read beyond that would change the output.
        let first = ShardedEncode::new(grid, None, q, opts, *plan).unwrap();
        let apex = first.apex(&TempStorage::Memory).unwrap();
        // The apex of a grid in mapped files, from a copy of its points: the same.
        let from_files = ShardedEncode::new(&mapped, None, q, opts, *plan).unwrap();
        let mut got = from_files.apex(&TempStorage::Memory).unwrap();
        let mut want = apex.clone();
        got.output.own_errors.sort_unstable();
        want.output.own_errors.sort_unstable();
        assert!(got == want, "the apex of a mapped grid differs");
        let summary = first.summary();
        let count = first.block_count();
        let finest = first.setup.params.layout().finest_level();
        let windowed = |rect: Option<(i64, i64, i64, i64)>| {
            let mut part = grid.clone();
            for y in 0..grid.height {
                for x in 0..grid.width {
                    let (x, y) = (x as i64, y as i64);
                    let inside = rect.is_some_and(|(x0, y0, x1, y1)| {
                        (x0..=x1).contains(&x) && (y0..=y1).contains(&y)
                    });
                    if !inside {
                        let k = y as usize * grid.width + x as usize;
                        part.values[k] = 0;
                        part.valid[k] = false;
                    }
                }
            }
            part
        };
        let mut parts: Vec<BlockOutput> = (0..count)
            .map(|i| {
                let mut part = windowed(first.block_field_rect(i));
                if i % 2 == 1 {
                    // Every other shard's grid in mapped files, read through windows.
                    part = part.copied_to(&TempStorage::File(None)).unwrap();
                }
                let shard =
                    ShardedEncode::with_summary(&part, None, q, opts, *plan, summary.clone())
                        .unwrap();
                let field = shard.apex_field(&apex.field, &TempStorage::Memory).unwrap();
                shard.block(&field, i, &TempStorage::Memory).unwrap()
            })
            .collect();
        parts.push(apex.output);
        parts.reverse();
        // The merge's grid in mapped files: it spills the records it gathers.
        let nothing = windowed(None).copied_to(&TempStorage::File(None)).unwrap();
        let merger =
            ShardedEncode::with_summary(&nothing, None, q, opts, *plan, summary.clone()).unwrap();
        if count > 0 {
            // A missing block is an error, not a repository with holes.
            let short: Vec<BlockOutput> = parts[..parts.len() - 1].to_vec();
            let cut = plan.cut_level.min(finest);
            let any_owned = parts
                .last()
                .is_some_and(|p| p.own_errors.iter().any(|(id, _)| id.level >= cut));
            if any_owned {
                let fresh = ShardedEncode::new(grid, None, q, opts, *plan).unwrap();
                assert!(
                    fresh.finish(short).is_err(),
                    "a missing block went unnoticed"
                );
            }
        }
        let sharded = merger.finish(parts).unwrap();
        assert!(
            whole == sharded,
            "sharded encode differs on {}×{} {opts:?} {plan:?}",
            grid.width,
            grid.height
        );
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

        #[test]
        fn block_encoder_is_bit_identical_to_the_whole_field_one(
            n_pow in 1u32..5,
            w in 1usize..120,
            h in 1usize..120,
            extra in 0u32..2,
            k in 0u32..4,
            holes in proptest::collection::vec(any::<u16>(), 0..30),
            seed in any::<u64>(),
            cut in 0u8..12,
            side in 1i64..200,
        ) {
            let mut grid = terrain(w, h, &holes, seed);
            if grid.range().is_none() {
                grid.valid[0] = true;
            }
            let opts = EncodeOptions {
                n: (1 << n_pow) + 1,
                extra_level_pairs: extra,
                coder: CoderKind::ALL[(seed % 3) as usize],
                ..EncodeOptions::default()
            };
            let plan = BlockPlan { cut_level: cut, block_side: side };
            in_blocks_too(&grid, Quantizer::new(k).unwrap(), &opts, &plan);
        }
        #[test]
        fn field_encoder_is_bit_identical_to_the_per_diamond_one(
            n_pow in 1u32..5,
            w in 1usize..90,
            h in 1usize..90,
            extra in 0u32..2,
            k in 0u32..4,
            holes in proptest::collection::vec(any::<u16>(), 0..30),
            seed in any::<u64>(),
            file in any::<bool>(),
        ) {
            let mut grid = terrain(w, h, &holes, seed);
            if grid.range().is_none() {
                grid.valid[0] = true;
            }
            let opts = EncodeOptions {
                n: (1 << n_pow) + 1,
                extra_level_pairs: extra,
                coder: CoderKind::ALL[(seed % 3) as usize],
                ..EncodeOptions::default()
            };
            let storage = if file { TempStorage::File(None) } else { TempStorage::Memory };
            both_ways(&grid, Quantizer::new(k).unwrap(), &opts, &storage);
        }

        #[test]
        fn leaf_scan_matches_the_summed_area_table(
            n_pow in 1u32..4,
            w in 1usize..70,
            h in 1usize..70,
            extra in 0u32..2,
            holes in proptest::collection::vec(any::<u16>(), 0..400),
        ) {
            let grid = terrain(w, h, &holes, 7);
            let domain = Domain::covering((1 << n_pow) + 1, w, h, extra).unwrap();
            let layout = *domain.layout();
            let sets = stored_sets(&domain, &grid);
            prop_assert_eq!(&sets[layout.finest_level() as usize], &leaves_by_table(&layout, &grid));
        }
    }

    /// A single-band GeoTIFF of `data/` as a [`Dem`] (samples and GDAL's nodata tag; no
    /// georeferencing, which the encoder does not read): the readers are the builder's, which
    /// this crate's own tests cannot depend on.
    fn read_tiff_fixture(path: &std::path::Path) -> Dem {
        use tiff::decoder::{Decoder, DecodingResult};
        let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
        let mut decoder = Decoder::new(file).unwrap();
        let (width, height) = decoder.dimensions().unwrap();
        let nodata = decoder
            .get_tag_ascii_string(tiff::tags::Tag::Unknown(42113))
            .ok()
            .and_then(|t| t.trim_matches(char::from(0)).trim().parse::<f64>().ok());
        let (values, sample_type): (Vec<f64>, _) = match decoder.read_image().unwrap() {
            DecodingResult::I16(v) => (v.into_iter().map(f64::from).collect(), SampleType::I16),
            DecodingResult::U16(v) => (v.into_iter().map(f64::from).collect(), SampleType::U16),
            DecodingResult::I32(v) => (v.into_iter().map(f64::from).collect(), SampleType::I32),
            DecodingResult::F32(v) => (v.into_iter().map(f64::from).collect(), SampleType::F32),
            DecodingResult::F64(v) => (v, SampleType::F64),
            _ => panic!("{}: a sample type the fixtures do not use", path.display()),
        };
        Dem {
            width: width as usize,
            height: height as usize,
            values,
            sample_type,
            nodata,
            georef: None,
        }
    }

    #[test]
    fn field_encoder_is_bit_identical_on_real_dems_with_nodata_and_odd_sizes() {
        let data = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../data");
        // (file, window x0, y0, w, h, ε): nodata, odd sizes, a data rectangle ending mid-diamond.
        let cases = [
            ("rhine_nodata.tif", 0, 0, 0, 0, 1.0),
            ("srtm3_demcompare.tif", 37, 11, 301, 257, 1.0),
            ("lidar1m_mn.tif", 5, 3, 129, 200, 0.5),
            ("jacksboro_mpl.tif", 0, 0, 0, 0, 2.0),
        ];
        for (name, x0, y0, w, h, eps) in cases {
            let mut dem = read_tiff_fixture(&data.join(name));
            if w > 0 {
                dem = dem.crop(x0, y0, w, h).unwrap();
            }
            let plan = QuantPlan::for_dem(&dem, eps, None).unwrap();
            let grid = HeightGrid::from_dem(&dem, &plan).unwrap();
            if name.starts_with("rhine") {
                assert!(grid.valid.iter().any(|v| !v), "the fixture has nodata");
            }
            for n in [17, 65] {
                let opts = EncodeOptions {
                    n,
                    ..EncodeOptions::default()
                };
                both_ways(&grid, plan.quantizer, &opts, &TempStorage::Memory);
                // Blocks of a few finest diamonds (most of the work in margins) and of many.
                for (cut_level, block_side) in [(2, 64), (5, 300), (8, 97)] {
                    let blocks = BlockPlan {
                        cut_level,
                        block_side,
                    };
                    in_blocks_too(&grid, plan.quantizer, &opts, &blocks);
                }
            }
        }
    }
}
