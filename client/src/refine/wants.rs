//! Wants and prefetch: which records the cut lacks and which the moving view will soon need,
//! requested from the source with their urgency; records that arrived moved into RAM.

use super::node::Info;
use super::{
    Candidate, FetchOrder, FrameStats, PREFETCH_CLOCK_STRIDE, PREFETCH_PRIORITY, Refiner, View,
    WANT_HORIZON_S, most_urgent,
};
use crate::access::DataSource;
use crate::access::Priority;
use crate::camera::Camera;
use crate::spawn::Spawner;
use cbdam_codec::geometry::{DiamondId, IdMap};
use glam::DVec3;
use std::collections::BinaryHeap;
use web_time::Instant;

impl<S: DataSource, X: Spawner> Refiner<S, X> {
    /// Frame step: wants the records of what the refinement loop left unrefined (`leftovers`),
    /// most urgent first, each with its plan (the parents it forces). Past the most urgent
    /// `want_limit` (at least what the refinement rate gets through in [`WANT_HORIZON_S`]),
    /// only what is already on its way stays wanted: dropping it would cancel requests the link
    /// has carried part of.
    pub(super) fn want_leftovers(&mut self, leftovers: &[Candidate], wanted: &mut IdMap<f64>) {
        let mut order: Vec<&Candidate> = leftovers
            .iter()
            .filter(|c| !self.cut_state.cut.is_refined(c.id))
            .collect();
        let limit = self
            .config
            .want_limit
            .map(|min| min.max((self.pacing.refinement_rate * WANT_HORIZON_S) as usize));
        if let Some(limit) = limit
            && order.len() > limit
        {
            order.select_nth_unstable_by(limit, |a, b| b.cmp(a));
            let rest = order.split_off(limit);
            order.extend(
                rest.into_iter()
                    .filter(|c| self.requests.requested.contains_key(&c.id)),
            );
        }
        for c in order {
            self.want_plan(c.id, c.err, wanted);
        }
    }

    /// Frame step: the prefetches (`ahead`) join the cut's wants, each unless the cut wants it
    /// already, and become the next frame's `last_ahead`; with class tracking on, each want is
    /// recorded as the cut's or a prefetch.
    pub(super) fn add_prefetches(
        &mut self,
        ahead: IdMap<f64>,
        wanted: &mut IdMap<f64>,
        stats: &mut FrameStats,
    ) {
        let track = self.requests.track_classes;
        if track {
            for id in wanted.keys() {
                self.requests.last_class.insert(*id, false);
            }
        }
        for (&id, &prio) in &ahead {
            if let std::collections::hash_map::Entry::Vacant(e) = wanted.entry(id) {
                e.insert(prio);
                stats.prefetch_wants += 1;
                if track {
                    self.requests.last_class.insert(id, true);
                }
            }
        }
        self.last_ahead = ahead;
    }

    /// Wants the records that refining `id` (parents first) still lacks.
    pub(super) fn want_plan(&mut self, id: DiamondId, priority: f64, wanted: &mut IdMap<f64>) {
        let plan = self.plan(id);
        self.want_planned(&plan, priority, wanted);
    }

    /// [`Refiner::want_plan`] for a plan at hand.
    pub(super) fn want_planned(
        &mut self,
        plan: &[DiamondId],
        priority: f64,
        wanted: &mut IdMap<f64>,
    ) {
        // Usually everything is at hand (always with a local source): then nothing is wanted
        // whatever the metric says, and the metric's lookups can be skipped.
        if plan.iter().all(|&d| self.have_or_available(d)) {
            return;
        }
        let priority = match self.config.fetch_order {
            FetchOrder::ScreenError => priority,
            FetchOrder::ScreenErrorPerByte => {
                priority * 1024.0 / self.missing_bytes(plan).max(1) as f64
            }
        };
        for &d in plan {
            if self.requests.broken.contains(&d) || self.info(d).is_none() {
                return;
            }
            if !self.have_or_available(d) {
                let w = wanted.entry(d).or_insert(priority);
                *w = w.max(priority);
            }
        }
    }

    /// Bytes of the records of `plan` that are not at hand.
    pub(super) fn missing_bytes(&mut self, plan: &[DiamondId]) -> u64 {
        let mut missing = Vec::with_capacity(plan.len());
        for &d in plan {
            if !self.have_or_available(d)
                && let Some(sid) = self.source_id(d)
            {
                missing.push(sid);
            }
        }
        let entries = self.source.head().entries();
        missing
            .iter()
            .filter_map(|sid| entries.binary_search_by(|e| e.id.cmp(sid)).ok())
            .map(|i| u64::from(entries[i].length))
            .sum()
    }

    /// Frame step: posts new requests, re-prioritises, and cancels what is no longer wanted.
    pub(super) fn post_requests(&mut self, wanted: IdMap<f64>) {
        let stale: Vec<DiamondId> = self
            .requests
            .requested
            .keys()
            .filter(|id| !wanted.contains_key(id))
            .copied()
            .collect();
        for id in stale {
            self.requests.requested.remove(&id);
            if let Some(sid) = self.source_id(id) {
                // A remote source may have completed it since the frame began: keep what was
                // paid for rather than dropping it.
                if self.source.is_available(sid) {
                    self.take(id, sid);
                } else {
                    self.source.cancel(sid);
                }
            }
        }
        for (id, prio) in wanted {
            let prio = prio as Priority;
            if self.requests.requested.get(&id) != Some(&prio)
                && let Some(sid) = self.source_id(id)
            {
                self.source.request(sid, prio);
                self.requests.requested.insert(id, prio);
            }
        }
    }

    /// Frame step: moves the records that arrived into RAM; failures are logged now rather than
    /// when next wanted.
    pub(super) fn take_arrived(&mut self) {
        let arrived: Vec<DiamondId> = self
            .requests
            .requested
            .keys()
            .copied()
            .filter(|id| {
                self.source_id(*id)
                    .is_some_and(|s| self.source.is_available(s))
            })
            .collect();
        for id in arrived {
            self.requests.requested.remove(&id);
            let sid = self.source_id(id).expect("requested ids are stored");
            self.take(id, sid);
        }
    }

    /// Frame step: what to prefetch, each diamond with its priority: the records that refining
    /// the candidates that violate the target in the view `lookahead_frames` ahead at the
    /// camera's velocity (with a margin) would take, and those of the children of the
    /// candidates that violate it now, at [`PREFETCH_PRIORITY`] of their screen errors; at most
    /// [`RefineConfig::prefetch_limit`] of them, the most urgent (between equals the coarser).
    ///
    /// With a limit (and priorities that are screen errors), only the most urgent contributions
    /// are planned: each candidate's and child's screen error is computed, and the plans (and
    /// what they lack) are looked at from the most urgent down until the limit is reached and
    /// the next contribution is less urgent than everything kept. In the frames of a fast
    /// flight over a network that prefetch, planning every one of ~3 700 contributions wanted
    /// ~1 000 diamonds to keep 32, in 2.1–2.7 ms of a 2 ms budget; from the most urgent down,
    /// ~1 500 are planned, in 1.2–1.7 ms. The same diamonds and priorities as planning every
    /// contribution (checked in debug builds): a diamond's priority is the largest of its
    /// contributions', and every contribution at least as urgent as the kept ones is planned.
    ///
    /// Prefetching stops at `until` (the budget's end less [`PREFETCH_RESERVE`]): cut short
    /// while planning, it keeps the most urgent of what it planned (their priorities are
    /// final: a diamond's first contribution is its most urgent), and cut short sooner,
    /// nothing new; either way the last frame's prefetches still on their way stay wanted
    /// ([`Refiner::keep_last_ahead`]), so that a frame short of time cancels nothing the link
    /// carries. (By screen error per byte, once begun every plan is looked at.)
    pub(super) fn prefetch(
        &mut self,
        camera: &Camera,
        candidates: &[(DiamondId, Option<Info>)],
        errors: &[Option<f64>],
        until: Option<Instant>,
    ) -> IdMap<f64> {
        let past = || until.is_some_and(|u| Instant::now() >= u);
        if past() {
            return self.keep_last_ahead(IdMap::default(), self.config.prefetch_limit);
        }
        let velocity = self.last_camera.map_or(DVec3::ZERO, |c| camera.eye - c.eye);
        let ahead = velocity * self.config.lookahead_frames;
        let mut future = *camera;
        future.eye += ahead;
        future.target += ahead;
        let margin = self.config.prefetch_margin * (camera.target - camera.eye).length();
        let view = View::new(future, margin, &self.world);
        let now = View::new(*camera, 0.0, &self.world);
        if self.config.fetch_order == FetchOrder::ScreenErrorPerByte {
            // The priority then depends on what a plan lacks: every plan is looked at.
            let mut wanted = IdMap::default();
            self.prefetch_all(&view, &now, candidates, errors, &mut wanted);
            return most_urgent(wanted, self.config.prefetch_limit);
        }
        // Without a limit every contribution is planned, still most urgent first: what a
        // deadline cuts off is the least urgent.
        let limit = self.config.prefetch_limit.unwrap_or(usize::MAX);
        let Some(mut contributions) = self.contributions(&view, &now, candidates, errors, &past)
        else {
            return self.keep_last_ahead(IdMap::default(), Some(limit));
        };
        let mut wanted = IdMap::default();
        // The priority of the contribution that brought `wanted` to the limit: every later one
        // as urgent is planned too (it may add diamonds that tie with the kept ones).
        let mut least_kept: Option<f64> = None;
        let mut planned = 0;
        while let Some(c) = contributions.pop() {
            if limit == 0 || least_kept.is_some_and(|p| c.err < p) {
                break;
            }
            planned += 1;
            if planned % PREFETCH_CLOCK_STRIDE == 0 && past() {
                #[cfg(debug_assertions)]
                self.check_cut_short_prefetch(&view, &now, candidates, errors, &wanted);
                let kept = most_urgent(wanted, Some(limit));
                return self.keep_last_ahead(kept, Some(limit));
            }
            self.want_plan(c.id, c.err, &mut wanted);
            if least_kept.is_none() && wanted.len() >= limit {
                least_kept = Some(c.err);
            }
        }
        let kept = most_urgent(wanted, Some(limit));
        #[cfg(debug_assertions)]
        self.check_prefetch(&view, &now, candidates, errors, &kept, limit);
        kept
    }

    /// The prefetch's contributions, as a heap: each candidate violating the target in the
    /// future `view` (its own plan), and the violating children in `now` of each candidate
    /// violating it now, at [`PREFETCH_PRIORITY`]. `None` when `past` says the time is up.
    fn contributions(
        &mut self,
        view: &View,
        now: &View,
        candidates: &[(DiamondId, Option<Info>)],
        errors: &[Option<f64>],
        past: &dyn Fn() -> bool,
    ) -> Option<BinaryHeap<Candidate>> {
        let mut contributions = Vec::new();
        for (n, (&(id, info), &err_now)) in candidates.iter().zip(errors).enumerate() {
            if n % PREFETCH_CLOCK_STRIDE == PREFETCH_CLOCK_STRIDE - 1 && past() {
                return None;
            }
            if let Some(err) = self.violation_of(id, info, view) {
                contributions.push(Candidate {
                    err: err * PREFETCH_PRIORITY,
                    id,
                });
            }
            if self.violates(id, err_now) {
                for k in self.domain.children(id).into_iter().flatten() {
                    if let Some(err) = self.violation(k, now) {
                        contributions.push(Candidate {
                            err: err * PREFETCH_PRIORITY,
                            id: k,
                        });
                    }
                }
            }
        }
        Some(BinaryHeap::from(contributions))
    }

    /// Debug builds: a prefetch cut short kept each diamond at the priority planning every
    /// contribution gives it.
    #[cfg(debug_assertions)]
    fn check_cut_short_prefetch(
        &mut self,
        view: &View,
        now: &View,
        candidates: &[(DiamondId, Option<Info>)],
        errors: &[Option<f64>],
        wanted: &IdMap<f64>,
    ) {
        let mut all = IdMap::default();
        self.prefetch_all(view, now, candidates, errors, &mut all);
        for (d, p) in wanted {
            assert_eq!(all.get(d), Some(p), "a prefetch cut short: {d}'s priority");
        }
    }

    /// Debug builds: a whole prefetch kept exactly the `limit` most urgent of planning every
    /// contribution.
    #[cfg(debug_assertions)]
    fn check_prefetch(
        &mut self,
        view: &View,
        now: &View,
        candidates: &[(DiamondId, Option<Info>)],
        errors: &[Option<f64>],
        kept: &IdMap<f64>,
        limit: usize,
    ) {
        let mut all = IdMap::default();
        self.prefetch_all(view, now, candidates, errors, &mut all);
        let all = most_urgent(all, Some(limit));
        let sorted = |m: &IdMap<f64>| {
            let mut v: Vec<(DiamondId, f64)> = m.iter().map(|(&d, &p)| (d, p)).collect();
            v.sort_unstable_by_key(|&(d, _)| d);
            v
        };
        assert_eq!(sorted(kept), sorted(&all), "prefetch from the most urgent");
    }

    /// A prefetch cut short: `kept`, and what the last frame prefetched that is still on its
    /// way (requested, not arrived), each at the larger of its priorities; at most `limit`, the
    /// most urgent.
    pub(super) fn keep_last_ahead(&self, mut kept: IdMap<f64>, limit: Option<usize>) -> IdMap<f64> {
        for (&id, &p) in &self.last_ahead {
            if self.requests.requested.contains_key(&id) {
                let w = kept.entry(id).or_insert(p);
                *w = w.max(p);
            }
        }
        most_urgent(kept, limit)
    }

    /// [`Refiner::prefetch`] planning every contribution, in candidate order.
    pub(super) fn prefetch_all(
        &mut self,
        view: &View,
        now: &View,
        candidates: &[(DiamondId, Option<Info>)],
        errors: &[Option<f64>],
        wanted: &mut IdMap<f64>,
    ) {
        for (&(id, info), &err_now) in candidates.iter().zip(errors) {
            if let Some(err) = self.violation_of(id, info, view) {
                self.want_plan(id, err * PREFETCH_PRIORITY, wanted);
            }
            if self.violates(id, err_now) {
                for k in self.domain.children(id).into_iter().flatten() {
                    let plan = self.plan(k);
                    if plan.iter().all(|&d| self.have_or_available(d)) {
                        continue; // nothing to want: skip the metric
                    }
                    if let Some(err) = self.violation(k, now) {
                        self.want_planned(&plan, err * PREFETCH_PRIORITY, wanted);
                    }
                }
            }
        }
    }

    /// Whether a candidate whose screen error is `err` violates the target (and has not been
    /// given up on).
    pub(super) fn violates(&self, id: DiamondId, err: Option<f64>) -> bool {
        err.is_some_and(|e| e > self.config.pixel_error) && !self.requests.broken.contains(&id)
    }

    /// Remembers from now on, per record requested, whether its last request was a prefetch
    /// only ([`Refiner::last_requested_as_prefetch`]; benchmarks: an entry per record ever
    /// requested).
    pub fn track_prefetch_requests(&mut self) {
        self.requests.track_classes = true;
    }

    /// The source ids of the records whose last request was a prefetch only (see
    /// [`FrameStats::prefetch_wants`]), since [`Refiner::track_prefetch_requests`] (none
    /// without it): with the records fetched and those the cuts used, what prefetching fetched
    /// that no cut used.
    pub fn last_requested_as_prefetch(&self) -> impl Iterator<Item = DiamondId> + '_ {
        self.requests
            .last_class
            .iter()
            .filter(|&(_, &prefetch)| prefetch)
            .filter_map(|(&id, _)| self.source_id(id))
    }
}
