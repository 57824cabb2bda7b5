//! The refiner's state in three parts: the cut and what is kept up to date with it
//! ([`CutState`]), what is held in RAM against the memory budgets ([`Residency`]), and the
//! refiner's side of the data source ([`Requests`]). Each part's methods touch only that part
//! (and the [`Domain`], for the relations); the refiner's loop coordinates them.

use std::sync::Arc;

use cbdam_codec::geometry::{Cut, DiamondId, Domain, Half, IdMap, IdSet};

use super::cache::LruCache;
use super::drawn::DrawnList;
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
    /// The drawn half-patches in [`Cut::drawn_halves`]' order; updated on every refinement and
    /// coarsening, so a frame's cost follows what changed.
    pub(super) drawn: DrawnList,
    /// Refinement candidates (the diamonds with a drawn half) with their metric, kept as the
    /// cut changes rather than found by a pass over the cut each frame.
    pub(super) candidates: IdMap<Option<Info>>,
    /// Coarsening candidates: refined diamonds with no refined child, with their metric.
    pub(super) leaves: IdMap<Option<Info>>,
}

impl CutState {
    /// The drawn-list keys of the halves of unrefined, non-root `id` in its refined parents:
    /// `(parent, slot of id among the parent's children)`, one per parent (at most two: no
    /// allocation on the paths of refining and coarsening).
    fn parent_slots(&self, domain: &Domain, id: DiamondId) -> [Option<(DiamondId, usize)>; 2] {
        domain.parents(id).map(|p| {
            let p = p.filter(|&p| self.cut.is_refined(p))?;
            let slot = domain
                .children(p)
                .iter()
                .position(|c| *c == Some(id))
                .expect("child of its parent");
            Some((p, slot))
        })
    }

    /// The index of root `id` in the layout's roots.
    fn root_index(domain: &Domain, id: DiamondId) -> usize {
        domain
            .roots()
            .position(|r| r == id)
            .expect("level 0 diamonds are roots")
    }

    /// Draws the halves of `id`, just coarsened (or a root): both halves of a root, else its
    /// half in each refined parent.
    pub(super) fn show_halves(&mut self, domain: &Domain, id: DiamondId) {
        if id.level == 0 {
            let index = Self::root_index(domain, id);
            for (i, &h) in Half::BOTH.iter().enumerate() {
                let patch = self.roots[&id][h as usize].clone();
                self.drawn.show_root(index, i, patch);
            }
            return;
        }
        for (p, slot) in self.parent_slots(domain, id).into_iter().flatten() {
            self.drawn.show_child(p, slot, &self.nodes[&p]);
        }
    }

    /// Stops drawing the halves of `id`, about to be refined (its parents are refined).
    pub(super) fn hide_halves(&mut self, domain: &Domain, id: DiamondId) {
        if id.level == 0 {
            let index = Self::root_index(domain, id);
            for i in 0..Half::BOTH.len() {
                self.drawn.hide_root(index, i);
            }
            return;
        }
        for (p, slot) in self.parent_slots(domain, id).into_iter().flatten() {
            self.drawn.hide_child(p, slot);
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
        let drawn: Vec<(DiamondId, Half)> = self.drawn.iter().map(|p| (p.id, p.half)).collect();
        assert_eq!(drawn.len(), self.drawn.len(), "drawn count out of step");
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

/// What the refiner holds in RAM besides the cut's structure: compressed records, decoded
/// diamonds kept after coarsening, and the cut's decoded bytes against
/// [`RefineConfig::cut_bytes`].
pub(super) struct Residency {
    pub(super) records: LruCache<DiamondId, Arc<[u8]>>,
    pub(super) decoded: LruCache<DiamondId, Arc<Node>>,
    /// Sum of the cut's nodes' bytes.
    pub(super) cut_bytes: usize,
    /// Nodes evicted from `decoded` this frame, dropped off the frame thread at its end
    /// (`Refiner::release_evicted`).
    pub(super) evicted: Vec<Arc<Node>>,
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
        self.keep_decoded(id, node);
    }

    /// Keeps a decoded node in the decoded cache; what that evicts waits in `evicted`.
    pub(super) fn keep_decoded(&mut self, id: DiamondId, node: Arc<Node>) {
        let bytes = node.bytes();
        self.decoded
            .insert_evicting(id, node, bytes, &mut self.evicted);
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
