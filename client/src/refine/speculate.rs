//! Decoding ahead of the cut (speculation): at the end of a frame, jobs sized to last until the
//! next one decode what the view still needs, so that later frames refine without waiting.

use super::*;

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
        // Workers at the frame thread's priority get one job fewer than there are of them, so
        // that the frame's own thread keeps a core (decoding ahead would pre-empt the next
        // frame's refinement: measured on 2 cores); workers that yield to it get one each
        // while frames are paced (PACED_BUDGETS).
        let workers = self.spawner.parallelism().max(1);
        let paced = self.paced();
        let max_jobs = if self.spawner.yields_to_caller() && paced {
            workers
        } else {
            workers.saturating_sub(1).max(1)
        };
        let free = max_jobs.saturating_sub(self.ahead.jobs);
        if free == 0 {
            return;
        }
        let per_job = (self.pacing.frame_interval_s / self.pacing.decode_s.max(1e-6)) as usize;
        let max_steps = per_job.clamp(*SPECULATIVE_STEPS.start(), *SPECULATIVE_STEPS.end());
        // What was decoded ahead for a view that has moved on (a diamond this view does not
        // refine) stays in the decoded cache like anything coarsened, but is no longer counted
        // as ahead: counted, it would take room that what this view needs could use (a fast
        // flight leaves such diamonds behind every frame). For a still view only what came
        // back since the last frame is looked at.
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
        let room = AHEAD_LIMIT.saturating_sub(self.ahead.kept.len() + self.ahead.speculative.len());
        let max_taken = (max_steps * free).min(room);
        struct Planned {
            steps: Vec<(DiamondId, Source)>,
            given: Vec<(DiamondId, Arc<Node>)>,
        }
        let mut jobs: Vec<Planned> = (0..free)
            .map(|_| Planned {
                steps: Vec::new(),
                given: Vec::new(),
            })
            .collect();
        // Which job refines a diamond taken in this pass; decoded ones (cut, cache) are
        // looked up when a job needs them.
        let mut job_of: IdMap<usize> = IdMap::default();
        let mut seen = IdSet::default();
        // Children pushed, each once (one that is also among the leftovers may come twice: the
        // second is passed over as seen; filling this with every leftover cost more, over a
        // network, where thousands lack their records).
        let mut queued = IdSet::default();
        let mut frontier = BinaryHeap::from(leftovers);
        let mut taken = 0;
        let mut looked = 0;
        // Diamonds to decode that could not be taken (record missing, parents not at hand, job
        // full), counted once `until` has passed.
        let mut missed_late: Option<usize> = None;
        while let Some(Candidate { id, .. }) = frontier.pop() {
            if taken >= max_taken || looked - taken >= SPECULATION_MISSES {
                break;
            }
            // Past `until`, the plan stops once it has taken a diamond per free worker, or has
            // missed LEAST_LOOKS a free worker since (until a diamond per worker is taken, the
            // clock is read every LEAST_LOOKS looks).
            if missed_late.is_none()
                && (taken >= free || looked % LEAST_LOOKS == 0)
                && until.is_some_and(|u| Instant::now() >= u)
            {
                missed_late = Some(0);
            }
            if let Some(missed) = missed_late
                && (taken >= free || missed >= LEAST_LOOKS * free)
            {
                break;
            }
            looked += 1;
            if !seen.insert(id) || self.cut_state.cut.is_refined(id) || self.decoding.contains(&id)
            {
                continue;
            }
            let decoded = self.residency.decoded.contains(&id);
            if !decoded {
                // The job of the parents taken in this pass, if any; the others must be at
                // hand.
                let mut job = None;
                let mut ok = true;
                for p in self.domain.parents(id).into_iter().flatten() {
                    if let Some(&j) = job_of.get(&p) {
                        ok &= job.is_none_or(|k| k == j);
                        job = Some(j);
                    } else {
                        ok &=
                            self.cut_state.cut.is_refined(p) || self.residency.decoded.contains(&p);
                    }
                }
                let j = job.unwrap_or_else(|| {
                    (0..free)
                        .min_by_key(|&j| jobs[j].steps.len())
                        .expect("at least one job")
                });
                let late_miss = |m: &mut Option<usize>| {
                    if let Some(m) = m {
                        *m += 1;
                    }
                };
                if !ok || jobs[j].steps.len() >= max_steps {
                    late_miss(&mut missed_late);
                    continue;
                }
                let source = match self.need(id) {
                    Need::Ready(Source::Cached(_)) | Need::Missing | Need::Impossible => {
                        late_miss(&mut missed_late);
                        continue;
                    }
                    Need::Ready(source) => source,
                };
                for p in self.domain.parents(id).into_iter().flatten() {
                    if job_of.contains_key(&p) || jobs[j].given.iter().any(|(g, _)| *g == p) {
                        continue;
                    }
                    let node = self
                        .cut_state
                        .nodes
                        .get(&p)
                        .or_else(|| self.residency.decoded.get(&p))
                        .cloned()
                        .expect("checked above");
                    jobs[j].given.push((p, node));
                }
                jobs[j].steps.push((id, source));
                job_of.insert(id, j);
                taken += 1;
            }
            for k in self.domain.children(id).into_iter().flatten() {
                // A child of two parents is looked at once.
                if !queued.insert(k) {
                    continue;
                }
                if let Some(err) = self.violation(k, view) {
                    frontier.push(Candidate { err, id: k });
                }
            }
        }
        for job in jobs {
            if !job.steps.is_empty() {
                self.dispatch_job(job.steps, job.given, true);
            }
        }
    }
}
