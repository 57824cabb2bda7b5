//! Decoding ahead of the cut (speculation): at the end of a frame, jobs sized to last until the
//! next one decode what the view still needs, so that later frames refine without waiting.

use super::job::Source;
use super::node::Node;
use super::{
    AHEAD_LIMIT, Candidate, LEAST_LOOKS, Need, Refiner, SPECULATION_MISSES, SPECULATIVE_STEPS, View,
};
use crate::access::DataSource;
use crate::camera::Camera;
use crate::spawn::Spawner;
use cbdam_codec::geometry::{DiamondId, IdMap, IdSet};
use std::collections::BinaryHeap;
use std::sync::Arc;
use web_time::Instant;

/// What is decoded ahead of the cut.
#[derive(Debug, Default)]
pub(super) struct Ahead {
    /// The part of `decoding` decoded ahead of the cut by speculative jobs: their results go to
    /// the decoded cache, from which a later refinement takes them at no cost.
    pub(super) speculative: IdSet,
    /// Speculative jobs dispatched and not finished.
    pub(super) jobs: usize,
    /// Diamonds decoded ahead that came back and are not refined yet, and that the view of
    /// `view` needs (pruned when speculating: those that left the decoded cache, and those the
    /// view has moved away from).
    pub(super) kept: IdSet,
    /// Diamonds decoded ahead that came back since the last pruning, not looked at yet.
    pub(super) arrived: IdSet,
    /// The camera `kept` was last pruned for.
    pub(super) view: Option<Camera>,
}

impl<S: DataSource, X: Spawner> Refiner<S, X> {
    /// Frame step, after the refinement loop: hands the workers the refinements the view still
    /// needs, so that they decode until the next frame instead of idling. From the most urgent
    /// `leftovers` (refinement candidates the budget did not reach) down, most urgent first, it
    /// takes every diamond that violates the target in `view` and whose parents' data exists
    /// (refined, decoded ahead, or taken earlier in this pass: it does not need the cut),
    /// followed by its children. Each job refines its diamonds in that order; a diamond goes
    /// to the job holding its parents (skipped if they are in two), else to the least loaded.
    /// The results go to the decoded cache; the next frames' refinements take them from there
    /// without waiting. Because the metric is monotone (a child's error is at most its
    /// parents'), parents come before their children, and what a still view speculates is
    /// exactly what its converged cut refines: nothing is decoded in vain unless the view moves.
    pub(super) fn speculate(
        &mut self,
        view: &View,
        leftovers: Vec<Candidate>,
        until: Option<Instant>,
    ) {
        let Some((free, max_steps)) = self.speculation_capacity() else {
            return;
        };
        self.prune_ahead(view);
        let room = AHEAD_LIMIT.saturating_sub(self.ahead.kept.len() + self.ahead.speculative.len());
        let mut plan = Plan::new(free, max_steps, (max_steps * free).min(room), leftovers);
        while let Some(Candidate { id, .. }) = plan.frontier.pop() {
            if plan.should_stop(until) {
                break;
            }
            plan.looked += 1;
            if !plan.seen.insert(id)
                || self.cut_state.cut.is_refined(id)
                || self.decoding.contains(&id)
            {
                continue;
            }
            if !self.residency.decoded.contains(&id) && !self.take_ahead(&mut plan, id) {
                plan.missed_one();
                continue;
            }
            for k in self.domain.children(id).into_iter().flatten() {
                // A child of two parents is looked at once.
                if !plan.queued.insert(k) {
                    continue;
                }
                if let Some(err) = self.violation(k, view) {
                    plan.frontier.push(Candidate { err, id: k });
                }
            }
        }
        for job in plan.jobs {
            if !job.steps.is_empty() {
                self.dispatch_job(job.steps, job.given, true);
            }
        }
    }

    /// How many speculative jobs can start now and how many refinements each may hold; `None`
    /// when every worker that may speculate is busy.
    fn speculation_capacity(&self) -> Option<(usize, usize)> {
        // Workers at the frame thread's priority get one job fewer than there are of them, so
        // that the frame's own thread keeps a core (decoding ahead would pre-empt the next
        // frame's refinement: measured on 2 cores); workers that yield to it get one each
        // while frames are paced (PACED_BUDGETS).
        let workers = self.spawner.parallelism().max(1);
        let max_jobs = if self.spawner.yields_to_caller() && self.paced() {
            workers
        } else {
            workers.saturating_sub(1).max(1)
        };
        let free = max_jobs.saturating_sub(self.ahead.jobs);
        if free == 0 {
            return None;
        }
        let per_job = (self.pacing.frame_interval_s / self.pacing.decode_s.max(1e-6)) as usize;
        let max_steps = per_job.clamp(*SPECULATIVE_STEPS.start(), *SPECULATIVE_STEPS.end());
        Some((free, max_steps))
    }

    /// What was decoded ahead for a view that has moved on (a diamond this view does not
    /// refine) stays in the decoded cache like anything coarsened, but is no longer counted as
    /// ahead: counted, it would take room that what this view needs could use (a fast flight
    /// leaves such diamonds behind every frame). For a still view only what came back since
    /// the last frame is looked at.
    fn prune_ahead(&mut self, view: &View) {
        let mut look_at: Vec<DiamondId> = self.ahead.arrived.drain().collect();
        if self.ahead.view == Some(view.camera) {
            let decoded = &self.residency.decoded;
            self.ahead.kept.retain(|id| decoded.contains(id));
        } else {
            look_at.extend(self.ahead.kept.drain());
            self.ahead.view = Some(view.camera);
        }
        for id in look_at {
            if self.residency.decoded.contains(&id) && self.violation(id, view).is_some() {
                self.ahead.kept.insert(id);
            }
        }
    }

    /// Puts `id` (not decoded) in a job of `plan`: the job of its parents taken in this pass,
    /// else the least loaded, with the parents' nodes the job needs. `false` when it cannot be
    /// taken: parents in two jobs or not at hand, the job full, or its record not ready.
    fn take_ahead(&mut self, plan: &mut Plan, id: DiamondId) -> bool {
        // The job of the parents taken in this pass, if any; the others must be at hand.
        let mut job = None;
        let mut ok = true;
        for p in self.domain.parents(id).into_iter().flatten() {
            if let Some(&j) = plan.job_of.get(&p) {
                ok &= job.is_none_or(|k| k == j);
                job = Some(j);
            } else {
                ok &= self.cut_state.cut.is_refined(p) || self.residency.decoded.contains(&p);
            }
        }
        let j = job.unwrap_or_else(|| plan.least_loaded());
        if !ok || plan.jobs[j].steps.len() >= plan.max_steps {
            return false;
        }
        let source = match self.need(id) {
            Need::Ready(Source::Cached(_)) | Need::Missing | Need::Impossible => return false,
            Need::Ready(source) => source,
        };
        for p in self.domain.parents(id).into_iter().flatten() {
            if plan.job_of.contains_key(&p) || plan.jobs[j].given.iter().any(|(g, _)| *g == p) {
                continue;
            }
            let node = self
                .cut_state
                .nodes
                .get(&p)
                .or_else(|| self.residency.decoded.get(&p))
                .cloned()
                .expect("checked above");
            plan.jobs[j].given.push((p, node));
        }
        plan.jobs[j].steps.push((id, source));
        plan.job_of.insert(id, j);
        plan.taken += 1;
        true
    }
}

/// One speculative job being planned: the refinements in order and the parents' nodes given.
struct PlannedJob {
    steps: Vec<(DiamondId, Source)>,
    given: Vec<(DiamondId, Arc<Node>)>,
}

/// A pass of [`Refiner::speculate`]: the frontier walked, the jobs filled and the counts that
/// end it.
struct Plan {
    jobs: Vec<PlannedJob>,
    max_steps: usize,
    max_taken: usize,
    /// Which job refines a diamond taken in this pass; decoded ones (cut, cache) are looked up
    /// when a job needs them.
    job_of: IdMap<usize>,
    seen: IdSet,
    /// Children pushed, each once (one that is also among the leftovers may come twice: the
    /// second is passed over as seen; filling this with every leftover cost more, over a
    /// network, where thousands lack their records).
    queued: IdSet,
    frontier: BinaryHeap<Candidate>,
    taken: usize,
    looked: usize,
    /// Diamonds to decode that could not be taken (record missing, parents not at hand, job
    /// full), counted once `until` has passed.
    missed_late: Option<usize>,
}

impl Plan {
    fn new(free: usize, max_steps: usize, max_taken: usize, leftovers: Vec<Candidate>) -> Plan {
        Plan {
            jobs: (0..free)
                .map(|_| PlannedJob {
                    steps: Vec::new(),
                    given: Vec::new(),
                })
                .collect(),
            max_steps,
            max_taken,
            job_of: IdMap::default(),
            seen: IdSet::default(),
            queued: IdSet::default(),
            frontier: BinaryHeap::from(leftovers),
            taken: 0,
            looked: 0,
            missed_late: None,
        }
    }

    /// Whether the pass ends before the next look: enough taken, too many missed, or — past
    /// `until` — a diamond taken per free worker, or LEAST_LOOKS missed per free worker since
    /// (until a diamond per worker is taken, the clock is read every LEAST_LOOKS looks).
    fn should_stop(&mut self, until: Option<Instant>) -> bool {
        if self.taken >= self.max_taken || self.looked - self.taken >= SPECULATION_MISSES {
            return true;
        }
        let free = self.jobs.len();
        if self.missed_late.is_none()
            && (self.taken >= free || self.looked.is_multiple_of(LEAST_LOOKS))
            && until.is_some_and(|u| Instant::now() >= u)
        {
            self.missed_late = Some(0);
        }
        self.missed_late
            .is_some_and(|missed| self.taken >= free || missed >= LEAST_LOOKS * free)
    }

    /// Counts a diamond that could not be taken, once `until` has passed.
    fn missed_one(&mut self) {
        if let Some(m) = &mut self.missed_late {
            *m += 1;
        }
    }

    fn least_loaded(&self) -> usize {
        (0..self.jobs.len())
            .min_by_key(|&j| self.jobs[j].steps.len())
            .expect("at least one job")
    }
}
