//! The closed-loop coarse-to-fine encoder (paper §5, "coarse to fine compression"): its options,
//! the [`Encoder`] builder and the setup every strategy shares; the levels, the sharded encode,
//! one refinement and the stored sets are in the submodules.

use std::collections::{BTreeSet, HashMap};

use super::analysis::analysis_fields;
use super::blocks::{BlockJournal, BlockPlan};
use super::field::TempStorage;
use super::object_error::ErrorInput;
use super::resolution::{Resolution, variable_sets};
use super::roots::encode_roots;
use super::{CodecParams, Encoded, Record};
use crate::CodecError;
use crate::entropy::CoderKind;
use crate::geometry::{DiamondId, Domain};
use crate::lifting::Alpha;
use crate::quant::{HeightGrid, LevelQuantizers, Quantizer};

mod levels;
mod refinement;
mod sharded;
mod stored;
mod targets;

use levels::Levels;
pub(super) use levels::{grid_from_parents, per_diamond_levels, record_of};
pub(super) use refinement::refine_encode;
pub use sharded::{ApexField, ApexOutput, ShardedEncode};
pub(crate) use stored::stored_sets;
use targets::Targets;

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
    levels: Option<LevelQuantizers>,
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
            levels: None,
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

    /// Quantizes each level's records with its own quantizer (`None`: `quantizer` on every
    /// level). `quantizer` must be the largest of them, and there must be one per level of
    /// records of the hierarchy; an `--rms-error` build's allocation.
    pub fn per_level(mut self, levels: Option<LevelQuantizers>) -> Self {
        self.levels = levels;
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
            (self.quantizer, self.levels),
            self.opts,
            keeping,
            self.progress,
        )
    }
}

/// `levels` if they fit `params`: one per level of records, the largest `params.quantizer`
/// (which the root field was quantized from).
fn checked_levels(
    params: &CodecParams,
    levels: Option<LevelQuantizers>,
) -> Result<Option<LevelQuantizers>, CodecError> {
    let Some(l) = levels else {
        return Ok(None);
    };
    let finest = usize::from(params.layout().finest_level());
    if l.len() != finest || l.max_k() != params.quantizer.k() as u32 {
        return Err(CodecError::invalid(format!(
            "{} per-level quantizers, largest k = {}, for a hierarchy of {finest} levels of \
             records with k = {}",
            l.len(),
            l.max_k(),
            params.quantizer.k()
        )));
    }
    Ok(Some(l))
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
    (quantizer, levels): (Quantizer, Option<LevelQuantizers>),
    opts: &EncodeOptions,
    strategy: Keeping<'_>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Encoded, CodecError> {
    let setup = Setup::new(grid, resolution, quantizer, levels, opts)?;
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
        levels: Option<LevelQuantizers>,
        opts: &EncodeOptions,
    ) -> Result<Self, CodecError> {
        let (params, targets) = Self::params(
            grid,
            resolution,
            (quantizer, levels),
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
        (quantizer, levels): (Quantizer, Option<LevelQuantizers>),
        opts: &EncodeOptions,
        any_valid: bool,
        nodata_mask: bool,
    ) -> Result<(CodecParams, Targets<'a>), CodecError> {
        if !any_valid {
            return Err(CodecError::invalid("the input has no valid sample"));
        }
        let domain = Domain::covering(opts.n, grid.width, grid.height, opts.extra_level_pairs)?;
        let layout = *domain.layout();
        let mut params = CodecParams {
            domain,
            alpha: opts.alpha,
            coder: opts.coder,
            quantizer,
            levels: None,
            root_quantizer: super::root_quantizer(quantizer),
            nodata_mask,
            kind: super::RepoKind::Elevation,
        };
        params.levels = checked_levels(&params, levels)?;
        params.root_quantizer = super::root_quantizer_of(quantizer, params.levels);
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
        let (params, targets) = Self::params(
            grid,
            resolution,
            (quantizer, None),
            opts,
            true,
            summary.nodata_mask,
        )?;
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

#[cfg(test)]
mod tests;
