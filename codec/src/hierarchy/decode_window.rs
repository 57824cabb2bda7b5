//! Decoding one level over a rectangle of a planar hierarchy, in parallel: what a reader of a
//! window (`cbdam.open(...).read(window=...)` in Python) needs, decoding only the records that
//! reach the window.
//!
//! Which diamonds matter. A grid point of a diamond of level `l` lies within `radius(l)` of its
//! centre, and a parent's centre within the parent's radius of its child's. So every diamond of
//! the target level `L` with a grid point in the window is centred within `radius(L)` of it, and
//! its ancestors at level `l` within `reach(l) = radius(L) + Σ_{m=l}^{L−1} radius(m)`
//! ([`LevelWindow::reach`]). Decoding, level by level, only the stored diamonds within the reach
//! of their level decodes each of them exactly as the whole walk
//! ([`super::walk_all_with_validity`]) does, and visits at level `L`, in the whole walk's order,
//! every diamond the whole walk visits there that has a grid point in the window — so per
//! sample of the window the last visit, the value and validity a reader keeps, is the whole
//! walk's. The refinements of one level are independent of each other and run on rayon's pool.

use std::collections::HashMap;

use rayon::prelude::*;

use super::CodecParams;
use super::decode::{Decoder, leaves_of};
use super::refine::{RefineScratch, Refined};
use crate::CodecError;
use crate::geometry::{DiamondId, DomainKind};

/// One level's samples over an inclusive lattice rectangle `(x0, y0, x1, y1)` of a planar
/// domain (lattice x = column, y = row of the data, row 0 north).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelWindow {
    /// The level to decode (any level; only even ones are axis-aligned grids).
    pub level: u8,
    /// The rectangle, inclusive, in lattice units.
    pub rect: (i64, i64, i64, i64),
}

/// Diamonds decoded in one parallel step of the target level before they are visited in order:
/// bounds the grids held at once.
const VISIT_CHUNK: usize = 4096;

impl LevelWindow {
    /// How far (L∞, lattice units) from the rectangle the diamonds of `level` that the read
    /// needs can be centred (see the module documentation).
    pub fn reach(&self, params: &CodecParams, level: u8) -> i64 {
        let layout = params.layout();
        let ancestors: i64 = (level..self.level).map(|l| layout.radius(l)).sum();
        ancestors + layout.radius(self.level)
    }

    fn within(&self, id: DiamondId, reach: i64) -> bool {
        let (x0, y0, x1, y1) = self.rect;
        let (x, y) = (i64::from(id.x), i64::from(id.y));
        x >= x0 - reach && x <= x1 + reach && y >= y0 - reach && y <= y1 + reach
    }

    /// The stored diamonds (of `stored`, the index's ids) whose records the read decodes: those
    /// above the target level within their level's reach, in id order. What a remote reader
    /// fetches before [`decode_window`].
    pub fn records_needed(&self, params: &CodecParams, stored: &[DiamondId]) -> Vec<DiamondId> {
        let mut ids: Vec<DiamondId> = stored
            .iter()
            .copied()
            .filter(|&id| id.level < self.level && self.within(id, self.reach(params, id.level)))
            .collect();
        ids.sort_unstable();
        ids
    }

    /// Refuses what this reader cannot decode: a cube-sphere, or a level past the finest.
    fn check(&self, params: &CodecParams) -> Result<(), CodecError> {
        if params.domain.kind() != DomainKind::Planar {
            return Err(CodecError::unsupported(
                "a window read decodes planar repositories; this one is a planet (cube-sphere)",
            ));
        }
        let finest = params.layout().finest_level();
        if self.level > finest {
            return Err(CodecError::invalid(format!(
                "level {}: the finest level of this repository is {finest}",
                self.level
            )));
        }
        Ok(())
    }
}

/// Decodes `window.level` over `window.rect` and hands `visit` every diamond of that level the
/// whole walk ([`super::walk_all_with_validity`]) visits with a grid point in the rectangle, in
/// the same order, with its grid and validity: the stored diamonds and the leaves below stored
/// parents. `stored`: every stored diamond (the index's ids); `record`: the bytes of one of them
/// (asked only for [`LevelWindow::records_needed`], from rayon's threads), checked by the
/// caller. A stored diamond with a parent that is not is corrupt, as in the whole walk.
pub fn decode_window<'a>(
    params: CodecParams,
    roots: &[u8],
    stored: &[DiamondId],
    record: impl Fn(DiamondId) -> Result<&'a [u8], CodecError> + Sync,
    window: LevelWindow,
    mut visit: impl FnMut(DiamondId, &[i32], Option<&[bool]>),
) -> Result<(), CodecError> {
    window.check(&params)?;
    let decoder = Decoder::new(params, roots)?;
    let finest = params.layout().finest_level();
    let mut by_level: Vec<Vec<DiamondId>> = vec![Vec::new(); usize::from(finest) + 1];
    for &id in stored {
        if id.level >= finest || !params.domain.contains(id) {
            return Err(CodecError::corrupt(format!(
                "record for impossible diamond {id}"
            )));
        }
        if id.level <= window.level && window.within(id, window.reach(&params, id.level)) {
            by_level[usize::from(id.level)].push(id);
        }
    }
    for level in &mut by_level {
        level.sort_unstable();
    }
    let mut prev: HashMap<DiamondId, Refined> = HashMap::new();
    for level in 0..=window.level {
        let stored_here = &by_level[usize::from(level)];
        let ids = if finest == 0 {
            // A single level: the roots are the leaves, and there are no records.
            params.domain.roots().collect()
        } else if level == 0 {
            stored_here.clone()
        } else {
            let reach = window.reach(&params, level);
            let mut ids = leaves_of(&params, prev.keys().copied(), &prev, |c| {
                window.within(c, reach)
            });
            ids.extend_from_slice(stored_here);
            ids.sort_unstable();
            ids.dedup();
            ids
        };
        if level == window.level {
            return visit_level(&decoder, &ids, &prev, &mut visit);
        }
        check_parents(&decoder, stored_here, &prev)?;
        prev = refine_level(&decoder, stored_here, &prev, &record)?;
    }
    Ok(())
}

/// A stored diamond whose existing parents are not all stored is corrupt.
fn check_parents(
    decoder: &Decoder,
    ids: &[DiamondId],
    prev: &HashMap<DiamondId, Refined>,
) -> Result<(), CodecError> {
    let domain = &decoder.params().domain;
    for &id in ids.iter().filter(|id| id.level > 0) {
        if domain
            .parents(id)
            .into_iter()
            .flatten()
            .any(|p| !prev.contains_key(&p))
        {
            return Err(CodecError::corrupt(format!(
                "{id} is stored but a parent is not"
            )));
        }
    }
    Ok(())
}

/// The refinements of the stored diamonds `ids` of one level, in parallel.
fn refine_level<'a>(
    decoder: &Decoder,
    ids: &[DiamondId],
    prev: &HashMap<DiamondId, Refined>,
    record: &(impl Fn(DiamondId) -> Result<&'a [u8], CodecError> + Sync),
) -> Result<HashMap<DiamondId, Refined>, CodecError> {
    let domain = &decoder.params().domain;
    ids.par_iter()
        .map_init(RefineScratch::default, |scratch, &id| {
            let parents = domain.parents(id).map(|p| p.and_then(|p| prev.get(&p)));
            let p = decoder.grid_of(id, parents);
            Ok((id, decoder.refine(&p, record(id)?, scratch)?))
        })
        .collect()
}

/// Gathers the grids of the target level's `ids` in parallel, a chunk at a time, and visits
/// them in order.
fn visit_level(
    decoder: &Decoder,
    ids: &[DiamondId],
    prev: &HashMap<DiamondId, Refined>,
    visit: &mut impl FnMut(DiamondId, &[i32], Option<&[bool]>),
) -> Result<(), CodecError> {
    let domain = &decoder.params().domain;
    for chunk in ids.chunks(VISIT_CHUNK) {
        let grids: Vec<(Vec<i32>, Option<Vec<bool>>)> = chunk
            .par_iter()
            .map(|&id| {
                let parents = domain.parents(id).map(|p| p.and_then(|p| prev.get(&p)));
                (
                    decoder.grid_of(id, parents),
                    decoder.validity_of(id, parents),
                )
            })
            .collect();
        for (&id, (grid, valid)) in chunk.iter().zip(&grids) {
            visit(id, grid, valid.as_deref());
        }
    }
    Ok(())
}
