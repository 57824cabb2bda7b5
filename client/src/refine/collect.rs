//! Garbage collection: coarsening refined diamonds the view no longer needs, least needed
//! first, within a share of the frame's budget, and freeing what the decoded cache evicts.

use super::node::Node;
use super::{Candidate, FrameStats, GC_MIN_COARSENINGS, GC_SHARE, Refiner, View};
use crate::access::DataSource;
use crate::spawn::Spawner;
use cbdam_codec::geometry::DiamondId;
use std::collections::BinaryHeap;
use web_time::Instant;

impl<S: DataSource, X: Spawner> Refiner<S, X> {
    /// Frame step: a moving view's collection, first in the frame, for a share of the budget.
    /// Coarsening costs microseconds a diamond, a view moving fast leaves hundreds to coarsen at
    /// once, and a collection left what the refinement loop leaves would get nothing in frames
    /// whose budget the loop spends. Coarsening before refining changes nothing the loop does:
    /// what is coarsened meets the target, what is refined does not.
    pub(super) fn collect_before(&mut self, view: &View, start: Instant, stats: &mut FrameStats) {
        let until = self.config.budget.map(|b| start + b / GC_SHARE);
        let (coarsened, finished) = self.collect_garbage(view, GC_MIN_COARSENINGS, until);
        stats.coarsenings += coarsened;
        self.collecting = !finished;
    }

    /// Frame step after the refinement loop. A still view's frame that collects
    /// (`still_collects`) does so only once its loop has refined all it could: until then its
    /// collection waits (its garbage is the moving view's, and the loop's refinements are what
    /// the view lacks). A collection stopped at its budget goes on in the time the loop left
    /// (nothing it could refine now), up to the deadline.
    pub(super) fn collect_after(
        &mut self,
        still_collects: bool,
        deadline: Option<Instant>,
        view: &View,
        stats: &mut FrameStats,
    ) {
        let deferred = still_collects && !stats.budget_exhausted;
        if still_collects && stats.budget_exhausted {
            self.collecting = true;
        }
        if let (Some(d), Some(b)) = (deadline, self.config.budget)
            && (deferred
                || (self.collecting && d.saturating_duration_since(Instant::now()) >= b / GC_SHARE))
        {
            let least = if deferred { GC_MIN_COARSENINGS } else { 0 };
            let (coarsened, finished) = self.collect_garbage(view, least, deadline);
            stats.coarsenings += coarsened;
            self.collecting = !finished;
        }
    }

    /// Coarsens every refined diamond the view does not need, finest first (a coarsening
    /// heap ordered by ascending screen error, re-fed with parents that become leaves), or
    /// those it reaches by `until` (after at least `least`). Returns how many
    /// it coarsened and whether it found none left.
    pub(super) fn collect_garbage(
        &mut self,
        view: &View,
        least: usize,
        until: Option<Instant>,
    ) -> (usize, bool) {
        // Collected, then made a heap in one pass.
        let unneeded: Vec<std::cmp::Reverse<Candidate>> = self
            .cut_state
            .leaves
            .iter()
            .filter_map(|(&id, info)| {
                let err = info.and_then(|i| view.error(&i)).unwrap_or(0.0);
                (err <= self.config.pixel_error).then_some(std::cmp::Reverse(Candidate { err, id }))
            })
            .collect();
        let mut heap = BinaryHeap::from(unneeded);
        let mut done = 0;
        while let Some(std::cmp::Reverse(c)) = heap.pop() {
            if done >= least && until.is_some_and(|u| Instant::now() >= u) {
                return (done, false);
            }
            if !self.coarsen_in_cut(c.id) {
                continue;
            }
            done += 1;
            self.release(c.id);
            for p in self.domain.parents(c.id).into_iter().flatten() {
                if self.cut_state.cut.is_refined(p)
                    && self.cut_state.is_leaf(&self.domain, p)
                    && let Some(c) = self.unneeded(p, view)
                {
                    heap.push(std::cmp::Reverse(c));
                }
            }
        }
        (done, true)
    }

    /// After `id` was coarsened: its node moves to the decoded cache.
    pub(super) fn release(&mut self, id: DiamondId) {
        if let Some(node) = self.cut_state.nodes.remove(&id) {
            self.residency.retire(id, node);
        }
    }

    /// Makes room in the cut budget for one more node before `keep` is refined (or dispatched
    /// for decoding) to fix a screen error of `err`: coarsens refined leaves, smallest screen
    /// error first, while theirs is below `err`. Parents of `keep` and of diamonds being
    /// decoded stay. `pool` is this frame's coarsening heap, built on first need. False if the
    /// budget cannot be met that way.
    pub(super) fn make_room(
        &mut self,
        err: f64,
        keep: DiamondId,
        view: &View,
        pool: &mut Option<BinaryHeap<std::cmp::Reverse<Candidate>>>,
        stats: &mut FrameStats,
    ) -> bool {
        let Some(limit) = self.config.cut_bytes else {
            return true;
        };
        // Worst case: every node with all four child halves and nodata masks.
        let node = Node::worst_bytes(self.domain.n(), self.drape.is_some());
        let fits = |me: &Self| {
            let regular = me.decoding.len() - me.ahead.speculative.len();
            me.residency.cut_bytes + (regular + 1) * node <= limit
        };
        if fits(self) {
            return true;
        }
        if pool.is_none() {
            let heap = self
                .cut_state
                .leaves
                .iter()
                .map(|(&id, info)| {
                    std::cmp::Reverse(Candidate {
                        err: info.and_then(|i| view.error(&i)).unwrap_or(0.0),
                        id,
                    })
                })
                .collect();
            *pool = Some(heap);
        }
        let heap = pool.as_mut().expect("built above");
        let mut kept = Vec::new();
        let ok = loop {
            if fits(self) {
                break true;
            }
            let Some(std::cmp::Reverse(c)) = heap.pop() else {
                break false;
            };
            // Entries go stale as the frame refines and coarsens.
            if !self.cut_state.cut.is_refined(c.id) || !self.cut_state.is_leaf(&self.domain, c.id) {
                continue;
            }
            if c.err >= err {
                heap.push(std::cmp::Reverse(c));
                break false;
            }
            let is_parent = |d: DiamondId| self.domain.parents(d).contains(&Some(c.id));
            if is_parent(keep) || self.decoding.iter().any(|&d| is_parent(d)) {
                kept.push(std::cmp::Reverse(c));
                continue;
            }
            if !self.coarsen_in_cut(c.id) {
                continue;
            }
            stats.coarsenings += 1;
            self.heap_whole = false;
            self.release(c.id);
            for p in self.domain.parents(c.id).into_iter().flatten() {
                if self.cut_state.cut.is_refined(p) && self.cut_state.is_leaf(&self.domain, p) {
                    let err = self.drawn_error(p, view);
                    heap.push(std::cmp::Reverse(Candidate { err, id: p }));
                }
            }
        };
        heap.extend(kept);
        ok
    }

    /// `Some` (with its error, for ordering) if a refined diamond is not needed by the view.
    pub(super) fn unneeded(&mut self, id: DiamondId, view: &View) -> Option<Candidate> {
        let err = self.info(id).and_then(|i| view.error(&i)).unwrap_or(0.0);
        (err <= self.config.pixel_error).then_some(Candidate { err, id })
    }

    /// The screen error a refined diamond would show if coarsened: its own, 0 outside the
    /// frustum.
    pub(super) fn drawn_error(&mut self, id: DiamondId, view: &View) -> f64 {
        self.info(id).and_then(|i| view.error(&i)).unwrap_or(0.0)
    }

    /// Frame step: hands the nodes the decoded cache evicted this frame to a worker to drop.
    /// Dropping a node frees its five buffers (~100 KB at N = 65), allocated by the worker that
    /// decoded it: on the frame thread that was a fifth of garbage collection's time in a paced
    /// `low_pass` flight (each coarsening moves a node into the full cache, which evicts one).
    /// A spawner without threads drops them here.
    pub(super) fn release_evicted(&mut self) {
        if !self.residency.evicted.is_empty() {
            let evicted = std::mem::take(&mut self.residency.evicted);
            self.spawner.spawn(move || drop(evicted));
        }
    }
}
