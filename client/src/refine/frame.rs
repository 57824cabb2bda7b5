//! One frame of the refinement loop, step by step: start, refine within the deadline, collect,
//! want and prefetch, decode ahead; and settling a still view.

use super::{
    AHEAD_RESERVE, Candidate, FrameStats, FrameSteps, KeptHeap, PREFETCH_RESERVE, Refiner, View,
};
use crate::access::DataSource;
use crate::camera::Camera;
use crate::spawn::Spawner;
use cbdam_codec::geometry::IdMap;
use std::collections::BinaryHeap;
use web_time::Instant;

impl<S: DataSource, X: Spawner> Refiner<S, X> {
    /// Runs one frame for `camera`: refine within the budget, request what is missing,
    /// prefetch, cancel what is no longer needed, and every few frames coarsen.
    pub fn frame(&mut self, camera: &Camera) -> FrameStats {
        let start = Instant::now();
        let collects = self.start_frame(start);
        let deadline = self.refinement_deadline(start);
        self.source.pump();
        self.take_arrived();

        let view = View::new(*camera, 0.0, &self.world);
        let mut stats = FrameStats {
            frame: self.frame,
            ..FrameStats::default()
        };
        // A moving view collects first, a still view after its loop (see `collect_before`).
        let still = self.config.budget.is_some() && self.last_camera == Some(*camera);
        if collects && !still {
            self.collect_before(&view, start, &mut stats);
        }
        let mut heap = self.frame_heap(camera, &view, still);
        self.heap_whole = true;
        let mut wanted: IdMap<f64> = IdMap::default();
        let loop_start = Instant::now();
        self.refine_until(deadline, &view, &mut heap, &mut wanted, &mut stats);
        let loop_end = Instant::now();
        self.collect_after(collects && still, deadline, &view, &mut stats);
        self.smooth_refinement_rate(&stats);
        let collect_end = Instant::now();

        // What the budget did not reach still gets requested, then prefetch (neither can want
        // anything from a source that always has everything at hand).
        let may_want = !self.source.always_available();
        let leftovers = self.leftovers(&mut heap);
        if may_want {
            self.want_leftovers(&leftovers, &mut wanted);
        }
        let want_end = Instant::now();
        let worst_violating = if self.heap_whole {
            self.worst_violating(&view, &heap)
        } else {
            None
        };
        self.keep_heap(camera, heap);
        stats.cut_wants = wanted.len();
        let prefetching = may_want && self.config.prefetch.allows(wanted.len());
        let (worst, ahead) =
            self.worst_and_prefetch(camera, &view, start, prefetching, worst_violating);
        self.last_camera = Some(*camera);
        self.add_prefetches(ahead, &mut wanted, &mut stats);
        self.post_requests(wanted);
        let after_end = Instant::now();
        // The workers keep decoding what the view still needs until the next frame. Last in
        // the frame, so that what it may take is known: the rest of the budget (its plan is
        // cut there, but each free worker gets a job; see AHEAD_RESERVE).
        if self.decodes_ahead() {
            let budget_end = self.config.budget.map(|b| start + b - b / AHEAD_RESERVE);
            self.speculate(&view, leftovers, budget_end);
        }
        self.remember_overrun(deadline, &stats);
        self.release_evicted();
        let end = Instant::now();
        stats.refine_ms = (end - start).as_secs_f64() * 1e3;
        stats.steps = FrameSteps::between([
            start,
            loop_start,
            loop_end,
            collect_end,
            want_end,
            after_end,
            end,
        ]);
        #[cfg(debug_assertions)]
        self.cut_state.check_incremental_sets(&self.domain);
        self.figures(&view, worst, &mut stats);
        stats
    }

    /// Frame step: the refinement heap of this frame. A still view's is the last frame's
    /// leftovers when nothing left it since but what was refined: the same screen errors, and
    /// the pass over every candidate skipped.
    fn frame_heap(&mut self, camera: &Camera, view: &View, still: bool) -> BinaryHeap<Candidate> {
        match self.kept_heap.take() {
            Some(kept)
                if still
                    && kept.camera == *camera
                    && kept.pixel_error == self.config.pixel_error =>
            {
                #[cfg(debug_assertions)]
                self.check_kept_heap(view, &kept.heap);
                kept.heap
            }
            _ => self.refinement_heap(view),
        }
    }

    /// Frame step: what the loop left in the heap, for wants and decoding ahead. A whole heap
    /// is still needed after this (the frame's largest error, the next frame's heap): copied;
    /// otherwise taken.
    fn leftovers(&self, heap: &mut BinaryHeap<Candidate>) -> Vec<Candidate> {
        if self.heap_whole {
            heap.iter().copied().collect()
        } else {
            std::mem::take(heap).into_vec()
        }
    }

    /// Frame step: keeps a whole heap for the next frame, which reuses it if the view stays
    /// still (see [`KeptHeap`]).
    fn keep_heap(&mut self, camera: &Camera, heap: BinaryHeap<Candidate>) {
        self.kept_heap = (self.config.budget.is_some() && self.heap_whole).then_some(KeptHeap {
            camera: *camera,
            pixel_error: self.config.pixel_error,
            heap,
        });
    }

    /// Frame step: the frame's largest screen error and what to prefetch. One pass over the
    /// final cut's candidates serves prefetching and the figures; without prefetching the
    /// figures need only the largest error (from a whole heap when there is one): no list is
    /// made.
    fn worst_and_prefetch(
        &mut self,
        camera: &Camera,
        view: &View,
        start: Instant,
        prefetching: bool,
        worst_violating: Option<f64>,
    ) -> (f64, IdMap<f64>) {
        if prefetching {
            let candidates = self.candidate_list();
            let errors: Vec<Option<f64>> = candidates
                .iter()
                .map(|&(_, info)| info.and_then(|i| view.error(&i)))
                .collect();
            let until = self.config.budget.map(|b| start + b - b / PREFETCH_RESERVE);
            let ahead = self.prefetch(camera, &candidates, &errors, until);
            let worst =
                self.worst_error(candidates.iter().zip(&errors).map(|(&(id, _), &e)| (id, e)));
            (worst, ahead)
        } else if let Some(worst) = worst_violating {
            #[cfg(debug_assertions)]
            assert_eq!(
                worst,
                self.worst_of_candidates(view),
                "largest error from the heap"
            );
            (worst, IdMap::default())
        } else {
            (self.worst_of_candidates(view), IdMap::default())
        }
    }

    /// Runs frames for one still `camera` until the cut has converged, or for `max_frames`
    /// frames at most, and returns the last frame's stats. With an unlimited budget and a local
    /// source the first frame usually converges: a single image's cut, picked exactly as a
    /// flight's frames pick theirs.
    pub fn settle(&mut self, camera: &Camera, max_frames: u32) -> FrameStats {
        let mut stats = self.frame(camera);
        for _ in 1..max_frames {
            if stats.converged {
                break;
            }
            stats = self.frame(camera);
        }
        stats
    }
}
