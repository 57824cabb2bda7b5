//! Decoding block by block: the decode counterpart of [`super::blocks`], so that a hierarchy
//! larger than memory is decoded — and verified — in a bounded amount of it.
//!
//! The whole-hierarchy walk ([`super::walk_all_with_validity`]) keeps the refinements of a whole
//! level to gather the next one from: 16 bytes and more per lattice point at the fine levels. This
//! walk decodes the levels above a [`BlockPlan`]'s cut over the whole domain (the *apex*) and
//! keeps only the last apex level's refinements; then each block decodes, level by level, the
//! stored diamonds whose centre lies within [`BlockWalk::reach`] of its owned rectangle, from the
//! apex's refinements at the cut and from its own below.
//!
//! Why a block sees what the whole walk sees. A parent's centre is within the parent's radius of
//! its child's, so the stored parents of a diamond within `reach(l)` of the owned rectangle are
//! within `reach(l − 1)` of it, and the block decodes them: every diamond it decodes or visits,
//! it decodes exactly as the whole walk does. A grid point of a diamond of level `l` lies within
//! `radius(l)` of its centre, and `radius(l) ≤ reach(l)` (the finest radius is added to every
//! reach for the finest level's leaves), so every diamond the whole walk visits that has a grid
//! point in the owned rectangle is visited by the block too, in the same order (coarse to fine,
//! by id within a level). So per lattice point of the owned rectangle, the last visit — the value
//! and validity a reconstruction keeps — is the whole walk's.

use std::collections::HashMap;

use super::blocks::{Block, BlockPlan};
use super::decode::{Decoder, LevelRecords, Visit, leaves_of, records_by_level, walk_level};
use super::decode_pool::GridPool;
use super::refine::{RefineScratch, Refined};
use super::{CodecParams, Encoded};
use crate::CodecError;
use crate::geometry::{DiamondId, DomainKind, Layout};
use crate::lifting::Alpha;

/// A planar α = 1 hierarchy decoded block by block (see the module documentation): built with
/// the apex decoded; [`BlockWalk::walk_block`] then decodes any block, from any thread.
pub struct BlockWalk<'a> {
    decoder: Decoder,
    plan: BlockPlan,
    blocks: Vec<Block>,
    levels: Vec<LevelRecords<'a>>,
    /// Refinements of the stored diamonds of the level above the cut.
    apex: HashMap<DiamondId, Refined>,
}

impl<'a> BlockWalk<'a> {
    /// Decodes the apex — the levels above `plan`'s cut, over the whole domain — handing `visit`
    /// every diamond it visits there as the whole walk does ([`super::walk_all_with_validity`]:
    /// the stored diamonds, and from level 1 on the leaves), in the same order.
    ///
    /// Refuses a cube-sphere, α = ½ (whose refinements change the vertices they start from) and
    /// a plan whose cut is not above the finest level.
    pub fn new(
        params: CodecParams,
        roots: &[u8],
        records: impl IntoIterator<Item = (DiamondId, &'a [u8])>,
        plan: BlockPlan,
        mut visit: impl FnMut(DiamondId, &[i32], Option<&[bool]>),
    ) -> Result<Self, CodecError> {
        if params.domain.kind() != DomainKind::Planar || params.alpha != Alpha::One {
            return Err(CodecError::unsupported(
                "only a planar hierarchy with α = 1 decodes block by block",
            ));
        }
        let layout = params.layout();
        if plan.cut_level >= layout.finest_level() {
            return Err(CodecError::invalid(format!(
                "a block plan cut at level {} leaves no level to the blocks of a hierarchy of {} \
                 levels",
                plan.cut_level,
                layout.finest_level() + 1
            )));
        }
        let decoder = Decoder::new(params, roots)?;
        let levels = records_by_level(&params, records)?;
        let mut prev = HashMap::new();
        let mut scratch = RefineScratch::default();
        let pool = GridPool::default();
        for level in 0..plan.cut_level {
            let stored = &levels[level as usize];
            let ids = if level == 0 {
                stored.ids.clone()
            } else {
                let mut ids = leaves_of(
                    &params,
                    levels[level as usize - 1].ids.iter().copied(),
                    &prev,
                    |_| true,
                );
                ids.extend_from_slice(&stored.ids);
                ids.sort_unstable();
                ids.dedup();
                ids
            };
            let next = walk_level(
                &decoder,
                &ids,
                stored,
                &prev,
                &mut scratch,
                &pool,
                &mut |batch: &[Visit<'_>]| {
                    for v in batch {
                        visit(v.id, v.grid, v.valid);
                    }
                },
            )?;
            pool.give_refinements(std::mem::replace(&mut prev, next).into_values());
        }
        Ok(Self {
            decoder,
            blocks: plan.blocks(layout),
            plan,
            levels,
            apex: prev,
        })
    }

    /// The plan's blocks, row by row ([`BlockPlan::blocks`]).
    pub fn blocks(&self) -> &[Block] {
        &self.blocks
    }

    /// The header fields.
    pub fn params(&self) -> &CodecParams {
        self.decoder.params()
    }

    /// The plan.
    pub fn plan(&self) -> &BlockPlan {
        &self.plan
    }

    /// How far (L∞, lattice units) from its owned rectangle a block decodes the diamonds of
    /// `level`: the reach of the encoder's blocks ([`BlockPlan::reach`]) and the finest radius.
    pub fn reach(layout: &Layout, plan: &BlockPlan, level: u8) -> i64 {
        plan.reach(layout, level) + layout.radius(layout.finest_level())
    }

    /// Decodes block `index` from the cut to the finest level, handing `visit` each diamond it
    /// visits with whether the block owns it ([`Block::owns`]): all of them are decoded exactly
    /// as by the whole walk, and every diamond that has a grid point in the owned rectangle is
    /// among them, in the whole walk's order (see the module documentation).
    pub fn walk_block(
        &self,
        index: usize,
        mut visit: impl FnMut(DiamondId, bool, &[i32], Option<&[bool]>),
    ) -> Result<(), CodecError> {
        let params = *self.decoder.params();
        let layout = params.layout();
        let block = &self.blocks[index];
        let reach = |level: u8| Self::reach(layout, &self.plan, level);
        let mut own: HashMap<DiamondId, Refined> = HashMap::new();
        let mut scratch = RefineScratch::default();
        let pool = GridPool::default();
        for level in self.plan.cut_level..=layout.finest_level() {
            let stored = &self.levels[level as usize];
            let mut ids = block.select(&stored.ids, reach(level));
            let prev = if level == self.plan.cut_level {
                &self.apex
            } else {
                &own
            };
            if level > 0 {
                let parents = block.select(&self.levels[level as usize - 1].ids, reach(level - 1));
                ids.extend(leaves_of(&params, parents, prev, |c| {
                    block.within(c, reach(level))
                }));
                ids.sort_unstable();
                ids.dedup();
            }
            let next = walk_level(
                &self.decoder,
                &ids,
                stored,
                prev,
                &mut scratch,
                &pool,
                &mut |batch: &[Visit<'_>]| {
                    for v in batch {
                        visit(v.id, block.owns(v.id), v.grid, v.valid);
                    }
                },
            )?;
            pool.give_refinements(std::mem::replace(&mut own, next).into_values());
        }
        Ok(())
    }
}

/// The block walk of an [`Encoded`] hierarchy: [`BlockWalk::new`] over its records.
pub fn block_walk<'a>(
    encoded: &'a Encoded,
    plan: BlockPlan,
    visit: impl FnMut(DiamondId, &[i32], Option<&[bool]>),
) -> Result<BlockWalk<'a>, CodecError> {
    BlockWalk::new(
        encoded.params,
        &encoded.roots,
        encoded.records.iter().map(|r| (r.id, &r.bytes[..])),
        plan,
        visit,
    )
}
