//! A frame's figures: its largest screen error and whether the cut has converged.

use super::*;

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
