//! The refinement loop: the heap of candidates by screen error, refined from the top on the
//! workers until the target is met or the deadline passes; decoded results applied to the cut.

use super::job::Source;
use super::node::Node;
use super::{Candidate, DecodeJob, Done, FrameStats, LEAST_LOOKS, Need, Refiner, SMOOTHING, View};
use crate::access::DataSource;
use crate::spawn::Spawner;
use cbdam_codec::geometry::{DiamondId, IdMap};
use std::collections::BinaryHeap;
use std::sync::Arc;
use web_time::Instant;

impl<S: DataSource, X: Spawner> Refiner<S, X> {
    /// Frame step: the refinement heap, the candidates that violate the target in `view`, most
    /// urgent on top.
    pub(super) fn refinement_heap(&self, view: &View) -> BinaryHeap<Candidate> {
        // Collected, then made a heap in one pass (the order is total: ties go by id).
        let violations: Vec<Candidate> = self
            .cut_state
            .candidates
            .iter()
            .filter_map(|(&id, &info)| {
                self.violation_of(id, info, view)
                    .map(|err| Candidate { err, id })
            })
            .collect();
        BinaryHeap::from(violations)
    }

    /// Checks that a kept heap holds every candidate that violates the target in `view` but
    /// those being decoded (debug builds, so every test frame of a still view checks it).
    #[cfg(debug_assertions)]
    pub(super) fn check_kept_heap(&self, view: &View, kept: &BinaryHeap<Candidate>) {
        let held: cbdam_codec::geometry::IdSet = kept.iter().map(|c| c.id).collect();
        for c in self.refinement_heap(view).into_vec() {
            assert!(
                held.contains(&c.id) || self.decoding.contains(&c.id),
                "the kept refinement heap lacks {} ({} px)",
                c.id,
                c.err
            );
        }
    }

    /// Frame step: applies the results of decodes dispatched in earlier frames, then dispatches
    /// the most urgent ready refinements and applies what comes back until nothing more can
    /// start or `deadline` passes. What could not be refined (missing records, blocked on an
    /// ancestor) is left in `heap`; missing records go into `wanted`.
    pub(super) fn refine_until(
        &mut self,
        deadline: Option<Instant>,
        view: &View,
        heap: &mut BinaryHeap<Candidate>,
        wanted: &mut IdMap<f64>,
        stats: &mut FrameStats,
    ) {
        // Results of decodes dispatched in earlier frames first.
        while let Ok(done) = self.done_rx.try_recv() {
            self.apply(done, view, heap, stats);
        }
        let max_in_flight = 2 * self.spawner.parallelism().max(1);
        let mut waiting: Vec<Candidate> = Vec::new();
        let mut coarsening = None;
        let past = |d: Option<Instant>| d.is_some_and(|d| Instant::now() >= d);
        // Candidates looked at this frame before one could start: a frame whose deadline has
        // passed before its loop began (a loaded machine, a tiny budget) still starts one
        // refinement when one of its first few candidates can, so that every frame advances.
        let mut looked = 0;
        let mut started = false;
        loop {
            // Dispatch the most urgent ready refinements to the workers. Refinements decoded
            // ahead (the decoded cache) are applied here at once, so the deadline is checked
            // here too.
            while self.decoding.len() - self.ahead.speculative.len() < max_in_flight {
                if past(deadline) && (started || looked >= LEAST_LOOKS) {
                    stats.budget_exhausted = true;
                    break;
                }
                let Some(c) = heap.pop() else { break };
                looked += 1;
                if self.cut_state.cut.is_refined(c.id) {
                    continue;
                }
                let step = self.start_refining(c, view, heap, wanted, &mut coarsening, stats);
                started |= step.started;
                let (blocked, dispatched_self) = (step.blocked, step.dispatched_self);
                if blocked {
                    self.heap_whole = false;
                } else if !dispatched_self && !self.cut_state.cut.is_refined(c.id) {
                    waiting.push(c);
                }
            }
            let regular = self.decoding.len() - self.ahead.speculative.len();
            if stats.budget_exhausted || (regular == 0 && waiting.is_empty()) {
                // Nothing in flight that this frame waits for and nothing more could be
                // started: locally optimal for the data at hand (speculative decodes still
                // running are applied when they come back).
                break;
            }
            let done = self.next_done(deadline);
            let Some(done) = done else {
                stats.budget_exhausted = true;
                break;
            };
            self.apply(done, view, heap, stats);
            while let Ok(done) = self.done_rx.try_recv() {
                self.apply(done, view, heap, stats);
            }
            // Candidates that waited for an ancestor may be ready now.
            heap.extend(waiting.drain(..));
        }
        heap.extend(waiting);
    }

    /// Starts what refining candidate `c` needs, in [`Self::plan`] order: each diamond of the
    /// plan whose parents are refined is applied from the decoded cache or dispatched to a
    /// worker (after making room under the cut's memory limit). A missing record goes into
    /// `wanted` (with the candidate's error) and blocks `c`; so does one that can never be
    /// decoded, or a memory limit that leaves no room.
    fn start_refining(
        &mut self,
        c: Candidate,
        view: &View,
        heap: &mut BinaryHeap<Candidate>,
        wanted: &mut IdMap<f64>,
        coarsening: &mut Option<BinaryHeap<std::cmp::Reverse<Candidate>>>,
        stats: &mut FrameStats,
    ) -> Started {
        let mut step = Started::default();
        for d in self.plan(c.id) {
            if self.decoding.contains(&d) {
                continue;
            }
            let parents_done = self
                .domain
                .parents(d)
                .into_iter()
                .flatten()
                .all(|p| self.cut_state.cut.is_refined(p));
            match self.need(d) {
                Need::Impossible => {
                    step.blocked = true;
                    break;
                }
                Need::Missing => {
                    let w = wanted.entry(d).or_insert(c.err);
                    *w = w.max(c.err);
                    step.blocked = true;
                }
                Need::Ready(_)
                    if parents_done && !self.make_room(c.err, d, view, coarsening, stats) =>
                {
                    stats.memory_limited = true;
                    step.blocked = true;
                    break;
                }
                Need::Ready(Source::Cached(node)) if parents_done => {
                    // Decoded before (ahead of the cut, or coarsened since): refining is free.
                    let done = Done {
                        id: d,
                        result: Some(Ok(node)),
                        secs: None,
                        cpu_secs: None,
                        speculative: false,
                        last: false,
                    };
                    self.apply(done, view, heap, stats);
                    step.dispatched_self |= d == c.id;
                    step.started = true;
                }
                Need::Ready(s) if parents_done => {
                    self.dispatch(d, s);
                    step.dispatched_self |= d == c.id;
                    step.started = true;
                }
                Need::Ready(_) => {}
            }
        }
        step
    }

    /// The next finished decode: waits for it until `deadline` (forever without one); `None`
    /// when the deadline passed first.
    #[cfg(not(target_arch = "wasm32"))]
    pub(super) fn next_done(&self, deadline: Option<Instant>) -> Option<Done> {
        match deadline {
            None => self.done_rx.recv().ok(),
            Some(d) => {
                let now = Instant::now();
                if now >= d {
                    None
                } else {
                    self.done_rx.recv_timeout(d - now).ok()
                }
            }
        }
    }

    /// The next finished decode, if one has arrived and `deadline` has not passed: a browser's
    /// page must never block (and `recv_timeout` would read `std`'s clock, which wasm32 lacks).
    /// With the [`Inline`](crate::spawn::Inline) spawner every decode has finished when it is
    /// dispatched, so this loses nothing; with asynchronous workers the frame ends and the
    /// results are applied next frame.
    #[cfg(target_arch = "wasm32")]
    pub(super) fn next_done(&self, deadline: Option<Instant>) -> Option<Done> {
        if deadline.is_some_and(|d| Instant::now() >= d) {
            return None;
        }
        self.done_rx.try_recv().ok()
    }

    /// Starts refining `id` (whose parents are refined) on a worker thread.
    pub(super) fn dispatch(&mut self, id: DiamondId, source: Source) {
        let given = self
            .domain
            .parents(id)
            .into_iter()
            .flatten()
            .map(|p| (p, self.cut_state.nodes[&p].clone()))
            .collect();
        self.dispatch_job(vec![(id, source)], given, false);
    }

    /// Starts one job on a worker thread: `steps` refined in order, each step's parents found
    /// among the earlier steps or in `given`.
    pub(super) fn dispatch_job(
        &mut self,
        steps: Vec<(DiamondId, Source)>,
        given: Vec<(DiamondId, Arc<Node>)>,
        speculative: bool,
    ) {
        for &(id, _) in &steps {
            self.decoding.insert(id);
            if speculative {
                self.ahead.speculative.insert(id);
            }
        }
        if speculative {
            self.ahead.jobs += 1;
        }
        self.spawner.spawn_job(DecodeJob {
            decoder: self.decoder.clone(),
            drape: self.drape.clone(),
            domain: self.domain,
            given,
            shift: self.shift,
            seed: self.config.detail.map_or(0, |d| d.seed),
            steps,
            speculative,
            tx: self.done_tx.clone(),
            from_message: false,
            keep_refined: self.spawner.sends_jobs_as_messages(),
        });
    }

    /// Puts a finished refinement into the cut, or into the cache if the cut moved on (a
    /// parent was coarsened meanwhile).
    pub(super) fn apply(
        &mut self,
        done: Done,
        view: &View,
        heap: &mut BinaryHeap<Candidate>,
        stats: &mut FrameStats,
    ) {
        let id = done.id;
        if done.speculative {
            self.ahead.speculative.remove(&id);
            if done.last {
                self.ahead.jobs -= 1;
            }
        }
        self.decoding.remove(&id);
        if let Some(secs) = done.secs {
            stats.decode_ms += secs * 1e3;
            stats.decode_cpu_ms += done.cpu_secs.unwrap_or(0.0) * 1e3;
            stats.decoded += 1;
            self.pacing.decode_s += SMOOTHING * (secs - self.pacing.decode_s);
        }
        let node = match done.result {
            Some(Ok(node)) => node,
            Some(Err(e)) => {
                self.log_failure(id, format!("decoding {id} failed: {e}"));
                return;
            }
            // Not decoded: a step before it in its job failed.
            None => {
                self.heap_whole = false;
                return;
            }
        };
        let parents_refined = self
            .domain
            .parents(id)
            .into_iter()
            .flatten()
            .all(|p| self.cut_state.cut.is_refined(p));
        // Decoded ahead: into the cache, from which the refinement loop takes it (within its
        // budget and the cut's memory limit).
        if done.speculative {
            self.ahead.arrived.insert(id);
            if done.secs.is_some() {
                stats.decoded_ahead += 1;
            }
        }
        if !done.speculative && !parents_refined {
            self.heap_whole = false;
        }
        if done.speculative || self.cut_state.cut.is_refined(id) || !parents_refined {
            self.residency.keep_decoded(id, node);
            return;
        }
        self.residency.decoded.remove(&id);
        if self.ahead.kept.remove(&id) | self.ahead.arrived.remove(&id) {
            stats.refined_ahead += 1;
        }
        self.residency.cut_bytes += node.bytes();
        if let Some(old) = self.cut_state.nodes.insert(id, node) {
            self.residency.cut_bytes -= old.bytes();
        }
        let children = self.refine_in_cut(id);
        stats.refinements += 1;
        for (k, info) in children.into_iter().flatten() {
            if let Some(err) = self.violation_of(k, info, view) {
                heap.push(Candidate { err, id: k });
            }
        }
    }
}

/// What [`Refiner::start_refining`] did for one candidate.
#[derive(Default)]
struct Started {
    /// A refinement of its plan was applied or dispatched.
    started: bool,
    /// The candidate itself was.
    dispatched_self: bool,
    /// Its plan cannot go on now (a record missing or undecodable, or no room).
    blocked: bool,
}
