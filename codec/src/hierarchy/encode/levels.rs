//! The coarse-to-fine pass over the levels: each stored diamond refined and coded against the
//! reconstruction the decoder will have, the previous level kept per diamond, in one field, or
//! in an apex field and one per block.

use std::collections::{BTreeSet, HashMap};
use std::ops::Range;

use rayon::prelude::*;

use crate::CodecError;
use crate::geometry::{DiamondId, Domain, Layout};
use crate::hierarchy::blocks::{Block, BlockJournal, BlockOutput, BlockPlan};
use crate::hierarchy::field::{ReconField, TempStorage};
use crate::hierarchy::object_error::{ErrorInput, surface_error};
use crate::hierarchy::record_bytes::KeptRecords;
use crate::hierarchy::refine::{Refined, gather};
use crate::hierarchy::roots::root_grid;
use crate::hierarchy::{CodecParams, Record};

use super::refinement::refine_encode;
use super::targets::Targets;

/// Records (object errors not yet saturated) and each stored diamond's own object error.
pub(super) type LevelOutput = (Vec<Record>, HashMap<DiamondId, u32>);

/// What the coarse-to-fine pass over the levels works on.
pub(super) struct Levels<'a> {
    pub(super) params: &'a CodecParams,
    /// The input, for the object-space errors.
    pub(super) error_input: ErrorInput<'a>,
    pub(super) targets: &'a Targets<'a>,
    pub(super) stored: &'a [Vec<DiamondId>],
    /// Which stored diamonds get a record, per level; `None`: all above the finest level.
    pub(super) recorded: Option<&'a [BTreeSet<DiamondId>]>,
    pub(super) root_field: &'a [i32],
    pub(super) tick: &'a (dyn Fn(&DiamondId) + Sync),
}

/// The grid of `id` before its refinement: from the root field at level 0, else gathered from
/// its parents' refinements (`prev`, the level above's).
///
/// # Panics
/// If a parent of `id` is not in `prev` (every stored diamond's parents are recorded).
pub(in crate::hierarchy) fn grid_from_parents(
    domain: &Domain,
    root_field: &[i32],
    id: DiamondId,
    prev: &HashMap<DiamondId, Refined>,
) -> Vec<i32> {
    let n = domain.n();
    let mut p = vec![0i32; n * n];
    if id.level == 0 {
        root_grid(domain, root_field, id, &mut p);
    } else {
        let parents = domain.parents(id).map(|pid| pid.map(|pid| &prev[&pid]));
        gather(domain, id, parents, &mut p);
    }
    p
}

/// What [`per_diamond_levels`] made: the records in `stored` order, what `visit` said of each
/// stored diamond, and the refinements of the last level passed (for the levels after it).
pub(in crate::hierarchy) struct LevelPass<T> {
    pub(in crate::hierarchy) records: Vec<Record>,
    pub(in crate::hierarchy) visited: Vec<(DiamondId, T)>,
    pub(in crate::hierarchy) last: HashMap<DiamondId, Refined>,
}

/// The coarse-to-fine pass over `levels` that planes and planets share, the previous level's
/// refinements kept per diamond: each stored diamond's grid gathered from the level above's
/// refinements (from the root field at level 0) and handed to `visit`, the diamonds of a level
/// in parallel. `visit` gives the diamond's refinement and record (`None`: a leaf, which the
/// next level does not gather from) and what the caller keeps of it (an object error, the
/// grid). Records are kept in `stored` order, which fixes the repository's bytes.
pub(in crate::hierarchy) fn per_diamond_levels<T: Send>(
    domain: &Domain,
    root_field: &[i32],
    stored: &[Vec<DiamondId>],
    levels: Range<u8>,
    visit: impl Fn(DiamondId, Vec<i32>) -> Result<(Option<(Refined, Record)>, T), CodecError> + Sync,
) -> Result<LevelPass<T>, CodecError> {
    let mut pass = LevelPass {
        records: Vec::new(),
        visited: Vec::new(),
        last: HashMap::new(),
    };
    for level in levels {
        let prev = &pass.last;
        let results = stored[level as usize]
            .par_iter()
            .map(|&id| {
                let (refined, kept) = visit(id, grid_from_parents(domain, root_field, id, prev))?;
                Ok((id, refined, kept))
            })
            .collect::<Result<Vec<_>, CodecError>>()?;
        pass.last.clear();
        for (id, refined, kept) in results {
            pass.visited.push((id, kept));
            if let Some((refined, record)) = refined {
                pass.last.insert(id, refined);
                pass.records.push(record);
            }
        }
    }
    Ok(pass)
}

/// The record of a refined diamond with reconstructed grid `p` (object error not yet
/// saturated).
pub(in crate::hierarchy) fn record_of(id: DiamondId, p: &[i32], bytes: Vec<u8>) -> Record {
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
    pub(super) fn record(id: DiamondId, p: &[i32], bytes: Vec<u8>) -> Record {
        record_of(id, p, bytes)
    }

    /// The levels with the previous level's refinements kept per diamond (any α).
    pub(super) fn per_diamond(&self) -> Result<LevelOutput, CodecError> {
        let layout = self.params.layout();
        let (finest, n) = (layout.finest_level(), layout.n());
        let pass = per_diamond_levels(
            &self.params.domain,
            self.root_field,
            self.stored,
            0..finest + 1,
            |id, p| {
                let err = surface_error(layout, id, &p, &self.error_input);
                // The finest level is only measured: its diamonds are the leaves.
                let refined = if id.level == finest {
                    None
                } else {
                    let r = refine_encode(
                        self.params,
                        id,
                        &p,
                        |x, y| self.targets.at(id.level + 1, x, y),
                        |x, y| self.targets.mask(self.params, x, y),
                    )?;
                    let vertices = r.vertices.as_deref().unwrap_or(&p);
                    let refined = Refined::from_parts(n, vertices, &r.cells);
                    Some((refined, Self::record(id, &p, r.bytes)))
                };
                (self.tick)(&id);
                Ok((refined, err))
            },
        )?;
        Ok((pass.records, pass.visited.into_iter().collect()))
    }

    /// The levels with one reconstruction field (α = 1): each refinement writes its new points
    /// into the field, and the next level gathers from it.
    pub(super) fn field(&self, storage: &TempStorage) -> Result<LevelOutput, CodecError> {
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
    pub(super) fn blocks(
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
    pub(super) fn apex(
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
    pub(super) fn block_and_apex_errors(
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
    pub(super) fn block(
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
    pub(super) fn apex_errors(
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
    pub(super) fn seed_roots(&self, field: &ReconField) {
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
    pub(super) fn encode_level(
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
