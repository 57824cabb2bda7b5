//! An α = 1 encode in parts that run apart — the apex and each block of the finer levels — and
//! are put together without encoding again ([`ShardedEncode`]).

use std::collections::HashMap;

use crate::CodecError;
use crate::geometry::DiamondId;
use crate::hierarchy::Encoded;
use crate::hierarchy::blocks::{Block, BlockOutput, BlockPlan};
use crate::hierarchy::field::{ReconField, TempStorage};
use crate::hierarchy::record_bytes::KeptRecords;
use crate::hierarchy::resolution::Resolution;
use crate::lifting::Alpha;
use crate::quant::{HeightGrid, Quantizer};

use super::{EncodeOptions, GridSummary, Setup};

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
    pub(super) setup: Setup<'a>,
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
            Setup::new(grid, resolution, quantizer, None, opts)?,
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
