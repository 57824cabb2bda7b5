//! The refiner's state in three parts: the cut and what is kept up to date with it
//! ([`CutState`]), what is held in RAM against the memory budgets ([`Residency`]), and the
//! refiner's side of the data source ([`Requests`]). Each part's methods touch only that part
//! (and the [`Domain`], for the relations); the refiner's loop coordinates them.

use std::collections::BTreeMap;
use std::sync::Arc;

use cbdam_codec::geometry::{Cut, DiamondId, Domain, Half, IdMap, IdSet};

use super::cache::LruCache;
use super::node::{Info, Node};
use crate::access::Priority;
use crate::patch::HalfPatch;

/// Recent error messages kept for [`super::Refiner::errors`].
const ERROR_LOG: usize = 64;

/// The cut and what is kept up to date with it as it changes.
pub(super) struct CutState {
    pub(super) cut: Cut,
    pub(super) nodes: IdMap<Arc<Node>>,
    pub(super) roots: IdMap<[Arc<HalfPatch>; 2]>,
    /// The drawn half-patches, keyed by [`DrawKey::packed`] so that iteration follows
    /// [`Cut::drawn_halves`]' order; updated on every refinement and coarsening, so a frame's
    /// cost follows what changed.
    pub(super) drawn: BTreeMap<u128, Arc<HalfPatch>>,
    /// Refinement candidates (the diamonds with a drawn half) with their metric, kept as the
    /// cut changes rather than found by a pass over the cut each frame.
    pub(super) candidates: IdMap<Option<Info>>,
    /// Coarsening candidates: refined diamonds with no refined child, with their metric.
    pub(super) leaves: IdMap<Option<Info>>,
}

impl CutState {
    /// The drawn-list keys of the halves of unrefined, non-root `id` in its refined parents:
    /// `(parent, slot of id among the parent's children)`.
    fn parent_slots(
        &self,
        domain: &Domain,
        id: DiamondId,
    ) -> impl Iterator<Item = (DiamondId, usize)> {
        domain
            .parents(id)
            .into_iter()
            .flatten()
            .filter(|&p| self.cut.is_refined(p))
            .map(move |p| {
                let slot = domain
                    .children(p)
                    .iter()
                    .position(|c| *c == Some(id))
                    .expect("child of its parent");
                (p, slot)
            })
    }

    /// The drawn-list keys of the halves of unrefined `id` (one per refined parent, both
    /// halves for a root), with the halves.
    fn half_keys(&self, domain: &Domain, id: DiamondId) -> Vec<(DrawKey, Arc<HalfPatch>)> {
        if id.level == 0 {
            let idx = domain
                .roots()
                .position(|r| r == id)
                .expect("level 0 diamonds are roots");
            return Half::BOTH
                .iter()
                .enumerate()
                .map(|(i, &h)| (DrawKey::Root(idx, i), self.roots[&id][h as usize].clone()))
                .collect();
        }
        self.parent_slots(domain, id)
            .map(|(p, slot)| {
                let half = self.nodes[&p].halves[slot]
                    .clone()
                    .expect("refined parents hold their children's halves");
                (DrawKey::Child(p, slot), half)
            })
            .collect()
    }

    /// Draws the halves of `id`, just coarsened (or a root).
    pub(super) fn show_halves(&mut self, domain: &Domain, id: DiamondId) {
        for (k, h) in self.half_keys(domain, id) {
            self.drawn.insert(k.packed(), h);
        }
    }

    /// Stops drawing the halves of `id`, about to be refined (its parents are refined): the
    /// keys [`CutState::half_keys`] gives, found without cloning the halves.
    pub(super) fn hide_halves(&mut self, domain: &Domain, id: DiamondId) {
        let keys: Vec<DrawKey> = if id.level == 0 {
            self.half_keys(domain, id)
                .into_iter()
                .map(|(k, _)| k)
                .collect()
        } else {
            self.parent_slots(domain, id)
                .map(|(p, slot)| DrawKey::Child(p, slot))
                .collect()
        };
        for k in keys {
            self.drawn.remove(&k.packed());
        }
    }

    /// Whether refined `id` has no refined child (a coarsening candidate).
    pub(super) fn is_leaf(&self, domain: &Domain, id: DiamondId) -> bool {
        !domain
            .children(id)
            .into_iter()
            .flatten()
            .any(|c| self.cut.is_refined(c))
    }

    /// Checks the incrementally kept sets against a recomputation from the cut (debug builds,
    /// so every test frame checks them).
    #[cfg(debug_assertions)]
    pub(super) fn check_incremental_sets(&self, domain: &Domain) {
        let mut candidates: Vec<DiamondId> = domain
            .roots()
            .filter(|r| !self.cut.is_refined(*r))
            .collect();
        for a in self.cut.refined() {
            for k in domain.children(a).into_iter().flatten() {
                if !self.cut.is_refined(k) {
                    candidates.push(k);
                }
            }
        }
        candidates.sort_unstable();
        candidates.dedup();
        let mut kept: Vec<DiamondId> = self.candidates.keys().copied().collect();
        kept.sort_unstable();
        assert_eq!(
            kept, candidates,
            "refinement candidates out of step with the cut"
        );
        let mut leaves: Vec<DiamondId> = self
            .cut
            .refined()
            .filter(|&d| self.is_leaf(domain, d))
            .collect();
        leaves.sort_unstable();
        let mut kept: Vec<DiamondId> = self.leaves.keys().copied().collect();
        kept.sort_unstable();
        assert_eq!(
            kept, leaves,
            "coarsening candidates out of step with the cut"
        );
        let drawn: Vec<(DiamondId, Half)> = self.drawn.values().map(|p| (p.id, p.half)).collect();
        assert_eq!(
            drawn,
            self.cut.drawn_halves(domain),
            "drawn list out of step"
        );
    }

    /// Fills the drawn list of the initial cut (roots only).
    pub(super) fn rebuild_drawn(&mut self, domain: &Domain) {
        self.drawn.clear();
        let roots: Vec<DiamondId> = domain.roots().collect();
        for r in roots {
            self.show_halves(domain, r);
        }
    }
}

/// Where a drawn half sits in [`Cut::drawn_halves`]' order: unrefined roots first (by their
/// index in [`Layout::roots`], then the half's index in [`Half::BOTH`]), then the halves of
/// refined diamonds' children, by parent (the cut's coarse-to-fine order), then child slot.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub(super) enum DrawKey {
    Root(usize, usize),
    Child(DiamondId, usize),
}

impl DrawKey {
    /// The key as one integer in the same order: the drawn list's map compares integers, not
    /// enums of ids (its searches were a quarter of applying a refinement on the frame thread,
    /// in perf of a paced `low_pass` settling).
    /// Roots below `2^127`, children above; a child's id in [`DiamondId`]'s field order
    /// (level, face, x, y: 80 bits), then the slot (below 4).
    pub(super) fn packed(self) -> u128 {
        match self {
            DrawKey::Root(index, half) => (index as u128) << 2 | half as u128,
            DrawKey::Child(id, slot) => {
                1 << 127
                    | u128::from(id.level) << 74
                    | u128::from(id.face) << 66
                    | u128::from(id.x) << 34
                    | u128::from(id.y) << 2
                    | slot as u128
            }
        }
    }
}

/// What the refiner holds in RAM besides the cut's structure: compressed records, decoded
/// diamonds kept after coarsening, and the cut's decoded bytes against
/// [`RefineConfig::cut_bytes`].
pub(super) struct Residency {
    pub(super) records: LruCache<DiamondId, Arc<[u8]>>,
    pub(super) decoded: LruCache<DiamondId, Arc<Node>>,
    /// Sum of the cut's nodes' bytes.
    pub(super) cut_bytes: usize,
}

impl Residency {
    /// Keeps a record that has arrived.
    pub(super) fn keep_record(&mut self, id: DiamondId, bytes: Arc<[u8]>) {
        let size = bytes.len() + 64;
        self.records.insert(id, bytes, size);
    }

    /// Takes in the node of a diamond just coarsened: out of the cut's bytes, into the decoded
    /// cache.
    pub(super) fn retire(&mut self, id: DiamondId, node: Arc<Node>) {
        let bytes = node.bytes();
        self.cut_bytes -= bytes;
        self.decoded.insert(id, node, bytes);
    }
}

/// The refiner's side of the data source: what is requested, and what failed.
#[derive(Default)]
pub(super) struct Requests {
    pub(super) requested: IdMap<Priority>,
    pub(super) failures: IdMap<u32>,
    pub(super) failure_count: u64,
    pub(super) broken: IdSet,
    pub(super) errors: Vec<String>,
    /// Per record requested while `track_classes`: whether its last request was a prefetch only.
    pub(super) last_class: IdMap<bool>,
    /// Whether `last_class` is kept (benchmarks).
    pub(super) track_classes: bool,
}

impl Requests {
    /// Counts a failure of `id`, gives up on it after `max_failures`, and keeps the message
    /// (the last [`ERROR_LOG`]).
    pub(super) fn log_failure(&mut self, id: DiamondId, message: String, max_failures: u32) {
        self.failure_count += 1;
        let n = self.failures.entry(id).or_default();
        *n += 1;
        let gave_up = *n >= max_failures;
        if gave_up {
            self.broken.insert(id);
        }
        if self.errors.len() >= ERROR_LOG {
            self.errors.remove(0);
        }
        self.errors.push(if gave_up {
            format!("{message} (giving up on {id})")
        } else {
            message
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The packed keys sort as the keys do (the drawn list's order is the cut's), over every
    /// pair of keys made of a few values of each field, the extremes among them, so that pairs
    /// tie on the leading fields and each later one decides somewhere.
    #[test]
    fn packed_draw_keys_keep_the_order() {
        let bytes = [0, 1, 2, u8::MAX];
        let coords = [0, 1, 2, u32::MAX - 1, u32::MAX];
        let mut keys: Vec<DrawKey> = (0..3)
            .flat_map(|i| (0..2).map(move |h| DrawKey::Root(i, h)))
            .collect();
        for level in bytes {
            for face in bytes {
                for x in coords {
                    for y in coords {
                        for slot in 0..4 {
                            let id = DiamondId::on_face(face, level, x, y);
                            keys.push(DrawKey::Child(id, slot));
                        }
                    }
                }
            }
        }
        for a in &keys {
            for b in &keys {
                assert_eq!(a.packed().cmp(&b.packed()), a.cmp(b), "{a:?} against {b:?}");
            }
        }
    }
}
