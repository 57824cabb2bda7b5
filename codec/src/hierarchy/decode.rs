//! Decoding diamond by diamond: the walks over a whole hierarchy and the finest level
//! reconstructed from them (the exact L∞ verifier built on them is [`super::verify`]).

use std::collections::HashMap;

use rayon::prelude::*;

use super::decode_pool::{GridPool, with_thread_scratch};
use super::gather_runs::prefetch_gather;
use super::refine::{
    ChildHalf, RefineScratch, Refined, gather, gather_validity, refine, refine_owned,
};
use super::roots::{decode_roots, root_grid};
use super::{CodecParams, Encoded};
use crate::CodecError;
use crate::geometry::{DiamondId, Half};
use crate::lifting::Alpha;

/// A decoder: the root field plus the per-diamond steps. The renderer drives it diamond by
/// diamond; [`super::verify`] drives it over the whole hierarchy.
#[derive(Clone, Debug)]
pub struct Decoder {
    params: CodecParams,
    roots: Vec<i32>,
    /// The root field's validity, `None` when the repository has no nodata mask.
    root_valid: Option<Vec<bool>>,
}

impl Decoder {
    /// Decodes the root field.
    pub fn new(params: CodecParams, root_bytes: &[u8]) -> Result<Self, CodecError> {
        if params.kind != super::RepoKind::Elevation {
            return Err(CodecError::unsupported(
                "this is a colour repository: its three channels need the colour decoder",
            ));
        }
        let (roots, root_valid) = decode_roots(&params, root_bytes)?;
        Ok(Self {
            params,
            roots,
            root_valid,
        })
    }

    /// The header fields.
    pub fn params(&self) -> &CodecParams {
        &self.params
    }

    /// The `N × N` grid of `id`: from the root field at level 0, otherwise gathered from the
    /// refinements of its existing parents ([`gather`]).
    pub fn grid_of(&self, id: DiamondId, parents: [Option<&Refined>; 2]) -> Vec<i32> {
        self.grid_into(id, parents, Vec::new())
    }

    /// [`Decoder::grid_of`] in the buffer `p` (emptied and grown as needed): with room for the
    /// cells too, which a refinement with α = 1 appends ([`refine_owned`]).
    pub(super) fn grid_into(
        &self,
        id: DiamondId,
        parents: [Option<&Refined>; 2],
        mut p: Vec<i32>,
    ) -> Vec<i32> {
        let n = self.params.layout().n();
        p.clear();
        p.reserve(grid_capacity(n));
        p.resize(n * n, 0i32);
        if id.level == 0 {
            root_grid(&self.params.domain, &self.roots, id, &mut p);
        } else {
            gather(&self.params.domain, id, parents, &mut p);
        }
        p
    }

    /// The validity of `id`'s `N × N` grid (`true` = the input had data there), `None` when all
    /// points are valid. Only points inside the data rectangle are meaningful.
    pub fn validity_of(&self, id: DiamondId, parents: [Option<&Refined>; 2]) -> Option<Vec<bool>> {
        if id.level > 0 {
            return gather_validity(&self.params.domain, id, parents);
        }
        let field = self.root_valid.as_ref()?;
        let n = self.params.layout().n();
        let mut v = vec![true; n * n];
        root_grid(&self.params.domain, field, id, &mut v);
        Some(v)
    }

    /// Refines diamond `id` with grid `p` by its record (with the quantizer of `id`'s level).
    pub fn refine(
        &self,
        id: DiamondId,
        p: &[i32],
        record: &[u8],
        scratch: &mut RefineScratch,
    ) -> Result<Refined, CodecError> {
        refine(
            &self.params,
            self.params.quantizer_at(id.level),
            p,
            record,
            scratch,
        )
    }
}

/// Values a diamond's buffer holds: its `N²` vertices, then a refinement's `(N − 1)²` cells.
fn grid_capacity(n: usize) -> usize {
    n * n + (n - 1) * (n - 1)
}

/// The worst error found on one level.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelReport {
    /// The level.
    pub level: u8,
    /// Diamonds whose grids were checked.
    pub diamonds: usize,
    /// Valid vertices checked (shared vertices counted once per diamond).
    pub vertices: u64,
    /// Largest |reconstructed − filtered| seen, units.
    pub max_error: u32,
    /// The bound this level's errors must respect, units: `k`, or with per-level quantizers
    /// the level's own ([`CodecParams::level_bound`]).
    pub bound: u32,
}

impl LevelReport {
    /// One empty report per level `0..=finest` of `params`'s hierarchy.
    pub fn empty(params: &CodecParams) -> Vec<LevelReport> {
        (0..=params.layout().finest_level())
            .map(|level| LevelReport {
                level,
                diamonds: 0,
                vertices: 0,
                max_error: 0,
                bound: params.level_bound(level),
            })
            .collect()
    }
}

/// What [`super::verify`] found.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct VerifyReport {
    /// One entry per level, coarse to fine.
    pub levels: Vec<LevelReport>,
    /// The bound every error must respect, units (`k`; with per-level quantizers the largest,
    /// each level's own in [`LevelReport::bound`]).
    pub bound: u32,
}

impl VerifyReport {
    /// Largest error over all levels, units.
    pub fn max_error(&self) -> u32 {
        self.levels.iter().map(|l| l.max_error).max().unwrap_or(0)
    }
    /// Whether every level is within its bound (and so within `bound`).
    pub fn within_bound(&self) -> bool {
        self.max_error() <= self.bound
            && self
                .levels
                .iter()
                .all(|l| l.max_error <= l.bound.min(self.bound))
    }
}

/// Decodes the whole hierarchy coarse to fine and hands every diamond's reconstructed grid to
/// `visit`: the stored diamonds of each level, then the finest diamonds all of whose existing
/// parents are stored. Single-threaded and in level order, like a renderer that refines all.
pub fn walk(encoded: &Encoded, mut visit: impl FnMut(DiamondId, &[i32])) -> Result<(), CodecError> {
    walk_with_validity(encoded, |id, p, _| visit(id, p))
}

/// [`walk`], also handing `visit` the validity of each grid ([`Decoder::validity_of`]; `None`:
/// all valid).
pub fn walk_with_validity(
    encoded: &Encoded,
    visit: impl FnMut(DiamondId, &[i32], Option<&[bool]>),
) -> Result<(), CodecError> {
    walk_impl(encoded, false, visit)
}

/// [`walk_with_validity`], visiting at every level (not only the finest) also the diamonds
/// without a record whose parents all have one: the leaves of a variable-resolution hierarchy
/// ([`super::resolution`]), where coarse data ends the refinement above the finest level.
pub fn walk_all_with_validity(
    encoded: &Encoded,
    visit: impl FnMut(DiamondId, &[i32], Option<&[bool]>),
) -> Result<(), CodecError> {
    walk_impl(encoded, true, visit)
}

fn walk_impl(
    encoded: &Encoded,
    all_levels: bool,
    mut visit: impl FnMut(DiamondId, &[i32], Option<&[bool]>),
) -> Result<(), CodecError> {
    walk_batches_impl(encoded, all_levels, |batch| {
        for v in batch {
            visit(v.id, v.grid, v.valid);
        }
    })
}

/// One diamond as a walk visits it: its id, reconstructed grid and the grid's validity
/// (`None`: all valid).
#[derive(Clone, Copy, Debug)]
pub struct Visit<'a> {
    /// The diamond.
    pub id: DiamondId,
    /// Its `N × N` reconstructed grid, row-major.
    pub grid: &'a [i32],
    /// The grid's validity ([`Decoder::validity_of`]), `None` when all valid.
    pub valid: Option<&'a [bool]>,
}

/// [`walk_all_with_validity`], handing `visit` the diamonds a batch at a time: consecutive runs
/// of the walk's order, decoded in parallel. A caller that writes each batch in parallel (e.g.
/// into disjoint rows of a raster, each part taking the batch's diamonds in order) sees what
/// the serial walk shows it and uses every core for the visit too.
pub fn walk_all_batches(
    encoded: &Encoded,
    visit: impl FnMut(&[Visit<'_>]),
) -> Result<(), CodecError> {
    walk_batches_impl(encoded, true, visit)
}

pub(super) fn walk_batches_impl(
    encoded: &Encoded,
    all_levels: bool,
    mut visit: impl FnMut(&[Visit<'_>]),
) -> Result<(), CodecError> {
    let params = encoded.params;
    let decoder = Decoder::new(params, &encoded.roots)?;
    let finest = params.layout().finest_level();
    let levels = records_by_level(
        &params,
        encoded.records.iter().map(|r| (r.id, &r.bytes[..])),
    )?;
    let mut prev: HashMap<DiamondId, Refined> = HashMap::new();
    let mut scratch = RefineScratch::default();
    let pool = GridPool::default();
    for level in 0..=finest {
        let stored = &levels[level as usize];
        let ids = if finest == 0 {
            // A single level: the roots are the leaves, and there are no records.
            params.domain.roots().collect()
        } else if level == finest || (all_levels && level > 0) {
            let mut ids = leaves_of(&params, prev.keys().copied(), &prev, |_| true);
            ids.extend_from_slice(&stored.ids);
            ids.sort_unstable();
            ids.dedup();
            ids
        } else {
            stored.ids.clone()
        };
        let next = walk_level(
            &decoder,
            &ids,
            stored,
            &prev,
            &mut scratch,
            &pool,
            &mut visit,
        )?;
        pool.give_refinements(std::mem::replace(&mut prev, next).into_values());
    }
    Ok(())
}

/// One level's records, sorted by id, looked up by binary search.
#[derive(Default)]
pub(super) struct LevelRecords<'a> {
    pub(super) ids: Vec<DiamondId>,
    bytes: Vec<&'a [u8]>,
}

impl<'a> LevelRecords<'a> {
    /// The record of `id`, if stored on this level.
    pub(super) fn get(&self, id: DiamondId) -> Option<&'a [u8]> {
        self.ids.binary_search(&id).ok().map(|i| self.bytes[i])
    }
}

/// `records` grouped by level and sorted; a record of a diamond that cannot be stored (at the
/// finest level or beyond, or outside the domain) is corrupt.
pub(super) fn records_by_level<'a>(
    params: &CodecParams,
    records: impl IntoIterator<Item = (DiamondId, &'a [u8])>,
) -> Result<Vec<LevelRecords<'a>>, CodecError> {
    let finest = params.layout().finest_level();
    let mut by_level: Vec<Vec<(DiamondId, &'a [u8])>> = vec![Vec::new(); finest as usize + 1];
    for (id, bytes) in records {
        if id.level >= finest || !params.domain.contains(id) {
            return Err(CodecError::corrupt(format!(
                "record for impossible diamond {id}"
            )));
        }
        by_level[id.level as usize].push((id, bytes));
    }
    Ok(by_level
        .into_iter()
        .map(|mut level| {
            if !level.is_sorted_by_key(|r| r.0) {
                level.sort_by_key(|r| r.0);
            }
            let (ids, bytes) = level.into_iter().unzip();
            LevelRecords { ids, bytes }
        })
        .collect())
}

/// The children of `parents` (one level's diamonds) that `keep` accepts and whose existing
/// parents are all in `prev` (decoded and stored): the leaves a walk visits without a record of
/// their own. Sorted, without repeats.
pub(super) fn leaves_of(
    params: &CodecParams,
    parents: impl IntoIterator<Item = DiamondId>,
    prev: &HashMap<DiamondId, Refined>,
    keep: impl Fn(DiamondId) -> bool,
) -> Vec<DiamondId> {
    let domain = &params.domain;
    let mut leaves: Vec<DiamondId> = parents
        .into_iter()
        .flat_map(|p| domain.children(p))
        .flatten()
        .filter(|&c| {
            keep(c)
                && domain
                    .parents(c)
                    .into_iter()
                    .flatten()
                    .all(|p| prev.contains_key(&p))
        })
        .collect();
    leaves.sort_unstable();
    leaves.dedup();
    leaves
}

/// Visits the diamonds `ids` of one level (in that order) and refines those with a record in
/// `records`, gathering each grid from `prev`, the refinements of the level above; gives the
/// refinements of this level. A stored diamond with a parent that is not is corrupt.
///
/// The diamonds of a level depend only on the level above, so they are decoded in parallel
/// (rayon, in chunks of a few per worker to bound the memory held) and each chunk is handed to
/// `visit` as one batch in `ids` order: a visit that takes a batch's diamonds in order sees
/// exactly what a serial walk shows it, and the first error in that order is the one returned
/// (after visiting the diamonds before it).
pub(super) fn walk_level(
    decoder: &Decoder,
    ids: &[DiamondId],
    records: &LevelRecords<'_>,
    prev: &HashMap<DiamondId, Refined>,
    scratch: &mut RefineScratch,
    pool: &GridPool,
    visit: &mut impl FnMut(&[Visit<'_>]),
) -> Result<HashMap<DiamondId, Refined>, CodecError> {
    let mut next = HashMap::with_capacity(records.ids.len().min(ids.len()));
    let chunk = PARALLEL_CHUNK_PER_WORKER * rayon::current_num_threads().max(1);
    for ids in ids.chunks(chunk) {
        let decoded = decode_chunk(decoder, ids, records, prev, scratch, pool);
        visit_batch(ids, decoded, &mut next, pool, visit)?;
    }
    Ok(next)
}

/// [`decode_diamond`] of each of `ids`, in parallel when there are several workers.
fn decode_chunk(
    decoder: &Decoder,
    ids: &[DiamondId],
    records: &LevelRecords<'_>,
    prev: &HashMap<DiamondId, Refined>,
    scratch: &mut RefineScratch,
    pool: &GridPool,
) -> Vec<Result<DecodedDiamond, CodecError>> {
    // While one diamond decodes, the parents' values the next one gathers are fetched.
    let prefetch_next = |k: usize| {
        if let Some(&next) = ids.get(k + 1) {
            let domain = &decoder.params().domain;
            let parents = domain.parents(next).map(|p| p.and_then(|p| prev.get(&p)));
            prefetch_gather(domain, next, parents);
        }
    };
    if rayon::current_num_threads() <= 1 || ids.len() < 2 {
        (0..ids.len())
            .map(|k| {
                prefetch_next(k);
                decode_diamond(decoder, ids[k], records, prev, scratch, pool)
            })
            .collect()
    } else {
        (0..ids.len())
            .into_par_iter()
            .map(|k| {
                prefetch_next(k);
                with_thread_scratch(|scratch| {
                    decode_diamond(decoder, ids[k], records, prev, scratch, pool)
                })
            })
            .collect()
    }
}

/// For a caller that needs only one level's grids, `last + 1` (≥ 1): decodes the stored
/// diamonds of levels `0..=last` and, instead of gathering the grids of level `last + 1`, hands
/// `visit` each batch of level `last`'s refinements as the halves of the children a walk
/// ([`walk_all_batches`]) would visit on level `last + 1` ([`ChildHalf`]), in the walk's order
/// of the parents. Every point of those children's grids inside the domain is in one of the
/// halves, with the value the walk shows there (where a child's other parent does not exist,
/// its other half — the mirror image the walk gathers — lies outside the domain). The refinements of level `last` are read while in cache and
/// their buffers reused as soon as their batch is visited. Planar domains only.
pub(crate) fn walk_child_halves(
    encoded: &Encoded,
    last: u8,
    mut visit: impl FnMut(&[ChildHalf<'_>]),
) -> Result<(), CodecError> {
    let params = encoded.params;
    planar_only(&params)?;
    let decoder = Decoder::new(params, &encoded.roots)?;
    if last >= params.layout().finest_level() {
        return Err(CodecError::invalid(format!(
            "level {last} has no children to visit"
        )));
    }
    let levels = records_by_level(
        &params,
        encoded.records.iter().map(|r| (r.id, &r.bytes[..])),
    )?;
    let mut prev: HashMap<DiamondId, Refined> = HashMap::new();
    let mut scratch = RefineScratch::default();
    let pool = GridPool::default();
    for stored in &levels[..usize::from(last)] {
        let next = walk_level(
            &decoder,
            &stored.ids,
            stored,
            &prev,
            &mut scratch,
            &pool,
            &mut |_: &[Visit<'_>]| {},
        )?;
        pool.give_refinements(std::mem::replace(&mut prev, next).into_values());
    }
    let stored = &levels[usize::from(last)];
    let chunk = PARALLEL_CHUNK_PER_WORKER * rayon::current_num_threads().max(1);
    for ids in stored.ids.chunks(chunk) {
        let decoded = decode_chunk(&decoder, ids, stored, &prev, &mut scratch, &pool);
        let mut refined = Vec::with_capacity(decoded.len());
        for (&id, d) in ids.iter().zip(decoded) {
            match d?.body {
                DecodedBody::SharedGrid(r) => refined.push((id, r)),
                DecodedBody::Separate(grid, r) => {
                    pool.give(grid);
                    refined.push((id, r));
                }
                // Not met: every diamond walked here has a record.
                DecodedBody::Unrefined(grid) => pool.give(grid),
                DecodedBody::Corrupt(_, e) => return Err(e),
            }
        }
        let mut halves = Vec::with_capacity(4 * refined.len());
        for (id, r) in &refined {
            visited_child_halves(&params, *id, r, stored, &mut halves);
        }
        visit(&halves);
        drop(halves);
        pool.give_refinements(refined.into_iter().map(|(_, r)| r));
    }
    Ok(())
}

/// Appends to `out` the halves that refinement `refined` of `id` gives its children that a walk
/// visits: those whose existing parents are all `stored` (on `id`'s level).
fn visited_child_halves<'a>(
    params: &CodecParams,
    id: DiamondId,
    refined: &'a Refined,
    stored: &LevelRecords<'_>,
    out: &mut Vec<ChildHalf<'a>>,
) {
    let domain = &params.domain;
    for child in domain.children(id).into_iter().flatten() {
        let parents = domain.parents(child);
        if !parents.iter().flatten().all(|&p| stored.get(p).is_some()) {
            continue;
        }
        for (h, half) in Half::BOTH.into_iter().enumerate() {
            if parents[h] != Some(id) {
                continue;
            }
            out.push(ChildHalf::new(domain, child, half, id, refined));
        }
    }
}

/// Diamonds each worker decodes for one batch of [`walk_level`]'s visits.
const PARALLEL_CHUNK_PER_WORKER: usize = 16;

/// One diamond as [`walk_level`] visits it: its grid's validity, and its grid and refinement.
struct DecodedDiamond {
    valid: Option<Vec<bool>>,
    body: DecodedBody,
}

/// A diamond's grid and what its record made of it.
enum DecodedBody {
    /// No record: the gathered grid.
    Unrefined(Vec<i32>),
    /// Refined with α = 1: the refinement's vertices are the gathered grid (no second copy).
    SharedGrid(Refined),
    /// Refined with α = ½ (the vertices moved): the gathered grid and the refinement.
    Separate(Vec<i32>, Refined),
    /// A corrupt record: the gathered grid, and the error to report after the visit.
    Corrupt(Vec<i32>, CodecError),
}

/// Gathers `id`'s grid and validity from `prev` and refines it by its record, if any.
fn decode_diamond(
    decoder: &Decoder,
    id: DiamondId,
    records: &LevelRecords<'_>,
    prev: &HashMap<DiamondId, Refined>,
    scratch: &mut RefineScratch,
    pool: &GridPool,
) -> Result<DecodedDiamond, CodecError> {
    let params = decoder.params();
    let parent_ids = params.domain.parents(id);
    let parents = parent_ids.map(|p| p.and_then(|p| prev.get(&p)));
    if id.level > 0
        && parent_ids
            .iter()
            .zip(&parents)
            .any(|(id, r)| id.is_some() && r.is_none())
    {
        return Err(CodecError::corrupt(format!(
            "{id} is stored but a parent is not"
        )));
    }
    let n = params.layout().n();
    let grid = decoder.grid_into(id, parents, pool.take(grid_capacity(n)));
    let valid = decoder.validity_of(id, parents);
    let body = match records.get(id) {
        None => DecodedBody::Unrefined(grid),
        Some(bytes) if params.alpha == Alpha::Half => {
            match decoder.refine(id, &grid, bytes, scratch) {
                Ok(refined) => DecodedBody::Separate(grid, refined),
                Err(e) => DecodedBody::Corrupt(grid, e),
            }
        }
        Some(bytes) => {
            match refine_owned(params, params.quantizer_at(id.level), grid, bytes, scratch) {
                Ok(refined) => DecodedBody::SharedGrid(refined),
                Err((grid, e)) => DecodedBody::Corrupt(grid, e),
            }
        }
    };
    Ok(DecodedDiamond { valid, body })
}

/// Hands a chunk of decoded diamonds to `visit` as one batch and keeps their refinements in
/// `next`; the errors of [`decode_diamond`] in the order a serial walk meets them (a missing
/// parent before the diamond's visit, a corrupt record after it): the batch ends there.
fn visit_batch(
    ids: &[DiamondId],
    decoded: Vec<Result<DecodedDiamond, CodecError>>,
    next: &mut HashMap<DiamondId, Refined>,
    pool: &GridPool,
    visit: &mut impl FnMut(&[Visit<'_>]),
) -> Result<(), CodecError> {
    let mut kept = Vec::with_capacity(decoded.len());
    let mut missing_parent = None;
    for (&id, decoded) in ids.iter().zip(decoded) {
        match decoded {
            Err(e) => {
                missing_parent = Some(e);
                break;
            }
            Ok(d) => {
                let corrupt = matches!(d.body, DecodedBody::Corrupt(..));
                kept.push((id, d));
                if corrupt {
                    break;
                }
            }
        }
    }
    if !kept.is_empty() {
        let batch: Vec<Visit<'_>> = kept
            .iter()
            .map(|(id, d)| Visit {
                id: *id,
                grid: d.grid(),
                valid: d.valid.as_deref(),
            })
            .collect();
        visit(&batch);
    }
    for (id, DecodedDiamond { body, .. }) in kept {
        match body {
            DecodedBody::Unrefined(grid) => pool.give(grid),
            DecodedBody::SharedGrid(refined) => {
                next.insert(id, refined);
            }
            DecodedBody::Separate(grid, refined) => {
                pool.give(grid);
                next.insert(id, refined);
            }
            DecodedBody::Corrupt(_, e) => return Err(e),
        }
    }
    missing_parent.map_or(Ok(()), Err)
}

impl DecodedDiamond {
    /// The grid a walk shows: the gathered grid (for α = 1 also the refinement's vertices).
    fn grid(&self) -> &[i32] {
        match &self.body {
            DecodedBody::Unrefined(grid)
            | DecodedBody::Separate(grid, _)
            | DecodedBody::Corrupt(grid, _) => grid,
            DecodedBody::SharedGrid(refined) => refined.vertices(),
        }
    }
}

/// Decodes the finest level onto the input's grid (the domain's data rectangle, row-major):
/// within the bound of every valid sample, unconstrained elsewhere.
pub fn reconstruct_finest(encoded: &Encoded) -> Result<Vec<i32>, CodecError> {
    Ok(reconstruct_finest_with_validity(encoded)?.0)
}

/// [`reconstruct_finest`] and the repository's nodata mask on the same grid (`true` = the input
/// had data; all `true` without a mask).
pub fn reconstruct_finest_with_validity(
    encoded: &Encoded,
) -> Result<(Vec<i32>, Vec<bool>), CodecError> {
    let mut finest = FinestRaster::new(&encoded.params)?;
    walk_with_validity(encoded, |id, p, v| finest.put(id, p, v))?;
    Ok((finest.heights, finest.valid))
}

/// Two rasters of `params`' data rectangle, filled with `a` and `b`; refused for a cube-sphere or
/// one too large to hold. The size comes from a header: a crafted file may declare terabytes, so
/// ask, don't abort.
fn data_rasters<A: Clone, B: Clone>(
    params: &CodecParams,
    a: A,
    b: B,
) -> Result<(Vec<A>, Vec<B>), CodecError> {
    planar_only(params)?;
    let (w, h) = params.domain.data().size();
    let (mut first, mut second) = (Vec::new(), Vec::new());
    w.checked_mul(h)
        .filter(|&len| {
            first.try_reserve_exact(len).is_ok() && second.try_reserve_exact(len).is_ok()
        })
        .map(|len| {
            first.resize(len, a);
            second.resize(len, b);
        })
        .ok_or_else(|| {
            CodecError::limit(format!("cannot hold a {w}×{h} reconstruction in memory"))
        })?;
    Ok((first, second))
}

/// The finest level on the input's grid (the domain's data rectangle, row-major), filled from a
/// walk's visits ([`FinestRaster::put`]; the other levels' are ignored): what
/// [`reconstruct_finest_with_validity`] returns.
pub(super) struct FinestRaster {
    params: CodecParams,
    /// The heights, units; 0 where no finest diamond reaches.
    pub(super) heights: Vec<i32>,
    /// The nodata mask (`true` = the input had data; all `true` without a mask).
    pub(super) valid: Vec<bool>,
}

impl FinestRaster {
    /// An empty raster of `params`' data rectangle, refused for a cube-sphere or one too large
    /// to hold.
    pub(super) fn new(params: &CodecParams) -> Result<Self, CodecError> {
        // Points no finest diamond reaches lie in leaves without data, which are not stored.
        let (heights, valid) = data_rasters(params, 0, !params.nodata_mask)?;
        Ok(Self {
            params: *params,
            heights,
            valid,
        })
    }

    /// Writes the visit of diamond `id` (grid `p`, validity `v`) if it is of the finest level.
    pub(super) fn put(&mut self, id: DiamondId, p: &[i32], v: Option<&[bool]>) {
        let layout = self.params.layout();
        if id.level != layout.finest_level() {
            return;
        }
        let (n, data) = (layout.n(), self.params.domain.data());
        let w = data.size().0;
        let g = layout.grid(id);
        for j in 0..n {
            for i in 0..n {
                let (x, y) = g.point(i as i64, j as i64);
                if data.contains(x, y) {
                    let k = y as usize * w + x as usize;
                    self.heights[k] = p[j * n + i];
                    self.valid[k] = v.is_none_or(|v| v[j * n + i]);
                }
            }
        }
    }
}

/// Refuses a cube-sphere where one planar raster is asked for.
pub(super) fn planar_only(params: &CodecParams) -> Result<(), CodecError> {
    if params.domain.kind() == crate::geometry::DomainKind::Planar {
        Ok(())
    } else {
        Err(CodecError::invalid(
            "this hierarchy is a cube-sphere: its six faces need the planet decoder \
             (reconstruct_planet, verify_planet)",
        ))
    }
}

/// What [`reconstruct_reached`] knows of a lattice point of the data rectangle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reached {
    /// No decoded diamond has the point on its grid (inside a coarse leaf, or no data).
    No,
    /// A grid point whose nodata mask says valid.
    Valid,
    /// A grid point whose nodata mask says invalid.
    Invalid,
}

/// The reconstruction at every lattice point of the data rectangle that is a grid point of some
/// diamond of [`walk_all_with_validity`] (values of the same point agree at every level, α = 1
/// vertices never change; for α = ½ the finest visit wins), and the nodata mask there.
pub fn reconstruct_reached(encoded: &Encoded) -> Result<(Vec<i32>, Vec<Reached>), CodecError> {
    let mut reached = ReachedRaster::new(&encoded.params)?;
    walk_impl(encoded, true, |id, p, v| reached.put(id, p, v))?;
    Ok((reached.heights, reached.state))
}

/// Every level's grid points on the input's grid, filled from a walk's visits: what
/// [`reconstruct_reached`] returns.
pub(super) struct ReachedRaster {
    params: CodecParams,
    /// The heights, units; 0 where no diamond reaches.
    pub(super) heights: Vec<i32>,
    /// What the walk found at each point.
    pub(super) state: Vec<Reached>,
}

impl ReachedRaster {
    /// An empty raster of `params`' data rectangle, refused for a cube-sphere or one too large
    /// to hold.
    pub(super) fn new(params: &CodecParams) -> Result<Self, CodecError> {
        let (heights, state) = data_rasters(params, 0i32, Reached::No)?;
        Ok(Self {
            params: *params,
            heights,
            state,
        })
    }

    /// Writes the visit of diamond `id` (grid `p`, validity `v`), of any level.
    pub(super) fn put(&mut self, id: DiamondId, p: &[i32], v: Option<&[bool]>) {
        let layout = self.params.layout();
        let (n, data) = (layout.n(), self.params.domain.data());
        let w = data.size().0;
        let g = layout.grid(id);
        for j in 0..n {
            for i in 0..n {
                let (x, y) = g.point(i as i64, j as i64);
                if data.contains(x, y) {
                    let k = y as usize * w + x as usize;
                    self.heights[k] = p[j * n + i];
                    self.state[k] = if v.is_none_or(|v| v[j * n + i]) {
                        Reached::Valid
                    } else {
                        Reached::Invalid
                    };
                }
            }
        }
    }
}
