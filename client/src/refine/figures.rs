//! A frame's figures: what it did and how long each step took ([`FrameStats`]), the caches' use,
//! its largest screen error and whether the cut has converged.

use super::{Candidate, Refiner, View};
use crate::access::AccessStats;
use crate::access::DataSource;
use crate::spawn::Spawner;
use cbdam_codec::geometry::DiamondId;
use std::collections::BinaryHeap;
use web_time::Instant;

/// What one frame did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameStats {
    /// Frame number, from 1.
    pub frame: u64,
    /// Wall time of the frame on the calling thread, ms: pump, heaps, dispatching, waiting for
    /// decodes while budget remains, coarsening.
    pub refine_ms: f64,
    /// Worker time spent decoding the refinements that came back this frame, ms.
    pub decode_ms: f64,
    /// Of `decode_ms`, the workers' CPU time where the platform measures it (Unix; 0
    /// elsewhere): without the time they waited for a core.
    pub decode_cpu_ms: f64,
    /// Diamonds decoded that came back this frame (refinements served from the cache do not
    /// count).
    pub decoded: usize,
    /// Largest screen-space error, pixels, of a drawn diamond in the frustum that could still
    /// be refined (stored, or synthetic with detail synthesis on; neither it nor a parent it
    /// needs given up on); 0 if none. Without detail synthesis, the finest level's own error
    /// (the data's resolution) does not count: nothing can reduce it.
    pub max_screen_error_px: f64,
    /// `max_screen_error_px` is within the target.
    pub met_target: bool,
    /// Met the target and nothing is left to coarsen: the cut is the one this view converges to.
    pub converged: bool,
    /// Refined diamonds in the cut.
    pub refined: usize,
    /// Half-patches drawn.
    pub drawn_halves: usize,
    /// Triangles drawn.
    pub triangles: u64,
    /// Refinements this frame.
    pub refinements: usize,
    /// Of `decoded`, the diamonds decoded ahead of the cut (speculatively, between frames).
    pub decoded_ahead: usize,
    /// Of `refinements`, those that took a diamond decoded ahead (one decoded ahead of a view
    /// that then moved away from it counts as a plain refinement from the decoded cache).
    pub refined_ahead: usize,
    /// Coarsenings this frame.
    pub coarsenings: usize,
    /// The budget ran out with work left.
    pub budget_exhausted: bool,
    /// A refinement waited because the cut was at `cut_bytes` and nothing coarser could give
    /// way.
    pub memory_limited: bool,
    /// Bytes of the cut's decoded diamonds after the frame.
    pub cut_bytes: usize,
    /// Records the view's cut lacks, wanted this frame (queued or in flight).
    pub cut_wants: usize,
    /// Records wanted this frame only as prefetches (see [`RefineConfig::prefetch`]).
    pub prefetch_wants: usize,
    /// The data source's counters after the frame.
    pub access: AccessStats,
    /// Records rejected so far (failed fetches and failed decodes).
    pub failures: u64,
    /// Where `refine_ms` went, step by step.
    pub steps: FrameSteps,
}

/// Where a frame's wall time went, ms: the steps of [`Refiner::frame`] in order; they add up to
/// [`FrameStats::refine_ms`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameSteps {
    /// Before the refinement loop: the source's arrivals, a moving view's collection, the
    /// refinement heap.
    pub before_ms: f64,
    /// The refinement loop: dispatching, waiting for and applying decodes.
    pub loop_ms: f64,
    /// A collection after the loop (a still view's, or one going on in time the loop left).
    pub collect_ms: f64,
    /// Choosing the records to request for what the budget did not reach.
    pub want_ms: f64,
    /// The frame's largest error, prefetching, posting the requests.
    pub after_ms: f64,
    /// Planning the decoding ahead of the cut, last (cut at the end of the budget), and
    /// remembering the overrun.
    pub ahead_ms: f64,
}

impl FrameSteps {
    /// The steps' times from the instants that end them: the frame's start, then the end of
    /// each step in the order of the fields.
    pub(super) fn between(t: [Instant; 7]) -> Self {
        let ms = |i: usize| (t[i + 1] - t[i]).as_secs_f64() * 1e3;
        FrameSteps {
            before_ms: ms(0),
            loop_ms: ms(1),
            collect_ms: ms(2),
            want_ms: ms(3),
            after_ms: ms(4),
            ahead_ms: ms(5),
        }
    }
}

/// Bytes held by the refiner's CPU caches ([`Refiner::cache_use`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CacheUse {
    /// Compressed records kept in RAM.
    pub record_bytes: usize,
    /// [`RefineConfig::record_cache_bytes`].
    pub record_budget: usize,
    /// Decoded diamonds kept after coarsening.
    pub decoded_bytes: usize,
    /// [`RefineConfig::decoded_cache_bytes`].
    pub decoded_budget: usize,
    /// Decoded diamonds evicted so far.
    pub decoded_evictions: u64,
}

impl<S: DataSource, X: Spawner> Refiner<S, X> {
    /// Frame step: the frame's figures of the cut it leaves.
    pub(super) fn figures(&mut self, view: &View, worst: f64, stats: &mut FrameStats) {
        let (max_err, coarsenable) = self.measure(view, worst);
        stats.max_screen_error_px = max_err;
        stats.met_target = max_err <= self.config.pixel_error;
        stats.converged = stats.met_target && coarsenable == 0;
        stats.refined = self.cut_state.nodes.len();
        stats.cut_bytes = self.residency.cut_bytes;
        stats.drawn_halves = self.cut_state.drawn.len();
        let n1 = (self.domain.n() - 1) as u64;
        stats.triangles = self.cut_state.drawn.len() as u64 * n1 * n1;
        stats.access = self.source.stats();
        stats.failures = self.requests.failure_count;
    }

    /// [`Refiner::worst_error`] over the cut's candidates in `view`.
    pub(super) fn worst_of_candidates(&self, view: &View) -> f64 {
        self.worst_error(
            self.cut_state
                .candidates
                .iter()
                .map(|(&id, info)| (id, info.and_then(|i| view.error(&i)))),
        )
    }

    /// With a whole heap (see `heap_whole`), the frame's largest error found without a pass
    /// over every candidate: every candidate that violates the target is in `heap` or being
    /// decoded, so when one of them could still be refined, the largest of theirs is the
    /// largest of all. `None` when none could (the largest error is then within the target,
    /// and only the pass finds it).
    pub(super) fn worst_violating(&self, view: &View, heap: &BinaryHeap<Candidate>) -> Option<f64> {
        let mut worst: Option<f64> = None;
        let mut consider = |me: &Self, id: DiamondId, err: f64| {
            if worst.is_none_or(|w| err > w)
                && me.cut_state.candidates.contains_key(&id)
                && !me.blocked(id)
            {
                worst = Some(err);
            }
        };
        for c in heap.iter() {
            consider(self, c.id, c.err);
        }
        for &id in &self.decoding {
            let info = self.cut_state.candidates.get(&id).copied().flatten();
            if let Some(err) = self.violation_of(id, info, view) {
                consider(self, id, err);
            }
        }
        worst
    }

    /// The largest of `errors` (the cut's candidates with their screen errors) that a
    /// refinement could still fix.
    pub(super) fn worst_error(
        &self,
        errors: impl Iterator<Item = (DiamondId, Option<f64>)>,
    ) -> f64 {
        let mut worst = 0f64;
        for (id, e) in errors {
            if let Some(e) = e
                && e > worst
                && !self.blocked(id)
            {
                worst = e;
            }
        }
        worst
    }

    /// `worst` (from [`Refiner::worst_error`]), and how many refined diamonds garbage
    /// collection would remove (0, uncounted, when `worst` is above the target).
    pub(super) fn measure(&mut self, view: &View, worst: f64) -> (f64, usize) {
        // Only a cut that meets the target can be converged, so only then does the count
        // matter: skip the pass over the whole cut otherwise.
        if worst > self.config.pixel_error {
            return (worst, 0);
        }
        let coarsenable = self
            .cut_state
            .leaves
            .values()
            .filter(|info| {
                info.and_then(|i| view.error(&i)).unwrap_or(0.0) <= self.config.pixel_error
            })
            .count();
        (worst, coarsenable)
    }
}
