//! The scheduling policy, portable to every transport: which wanted records go into the next
//! request, how many bytes may be in flight (a window sized by the link's measured rate), the
//! backoff of failed records, and when a request is no longer worth finishing.

use super::{Endpoint, FetchOptions};
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::repository::{RepositoryHead, batch};
use std::collections::{HashMap, HashSet, VecDeque};
use web_time::Instant;

pub(super) struct Pending {
    pub(super) priority: f32,
}

/// The scheduler's bookkeeping; `H` is the transport's handle for aborting a request. Each
/// entry of `batches` lists the records its request has still to deliver (a streamed response
/// delivers them one by one).
pub(super) struct State<H> {
    pub(super) wanted: HashMap<DiamondId, Pending>,
    pub(super) in_flight: HashSet<DiamondId>,
    /// Per record: failures so far and the time before which it is not retried.
    pub(super) backoff: HashMap<DiamondId, (u32, Instant)>,
    pub(super) batches: Vec<(u64, Vec<DiamondId>, H)>,
    /// Records sent to the frame loop but not yet polled: a `want` racing with their delivery
    /// must not fetch them again.
    pub(super) delivered: HashSet<DiamondId>,
    pub(super) next_batch: u64,
    pub(super) shutdown: bool,
    /// The link's measured rate and the bytes in flight against it.
    pub(super) window: Window,
}

/// A byte window over the requests in flight, sized by the link's measured delivery rate.
#[derive(Default)]
pub(super) struct Window {
    /// Record bytes of the requests in flight.
    pub(super) in_flight: u64,
    /// Per request in flight: its record bytes, when it started, and `delivered` then.
    pub(super) started: HashMap<u64, (u64, Instant, u64)>,
    /// Bytes delivered by finished requests so far.
    pub(super) delivered: u64,
    /// Smoothed delivery rate, bytes per second; 0 until measured.
    pub(super) rate: f64,
}

impl Window {
    /// The byte limit of records in flight.
    pub(super) fn limit(&self, options: &FetchOptions) -> u64 {
        if self.rate > 0.0 {
            ((self.rate * options.queue_seconds) as u64).max(16 << 10)
        } else {
            options.initial_window
        }
    }

    pub(super) fn start(&mut self, batch: u64, bytes: u64, now: Instant) {
        self.in_flight += bytes;
        self.started.insert(batch, (bytes, now, self.delivered));
    }

    /// A request ended: `received` bytes if it succeeded (a rate sample: everything delivered
    /// while it was in flight over its duration), `None` if it failed or was cancelled.
    pub(super) fn end(&mut self, batch: u64, received: Option<u64>, now: Instant) {
        let Some((bytes, t0, delivered_then)) = self.started.remove(&batch) else {
            return;
        };
        self.in_flight -= bytes;
        let Some(received) = received else { return };
        self.delivered += received;
        let secs = now.saturating_duration_since(t0).as_secs_f64();
        if secs > 0.0 && received > 0 {
            let sample = (self.delivered - delivered_then) as f64 / secs;
            self.rate = if self.rate > 0.0 {
                self.rate + 0.25 * (sample - self.rate)
            } else {
                sample
            };
        }
    }
}

impl<H> Default for State<H> {
    fn default() -> Self {
        Self {
            wanted: HashMap::new(),
            in_flight: HashSet::new(),
            backoff: HashMap::new(),
            batches: Vec::new(),
            delivered: HashSet::new(),
            next_batch: 0,
            shutdown: false,
            window: Window::default(),
        }
    }
}

impl<H> State<H> {
    /// Whether another request may start: a free slot, and room in the byte window (always
    /// for the first two).
    pub(super) fn may_start(&self, options: &FetchOptions, endpoint: &Endpoint) -> bool {
        self.batches.len() < endpoint.max_in_flight(options)
            && (self.batches.len() < 2 || self.window.in_flight < self.window.limit(options))
    }

    /// Most record bytes in the next request.
    pub(super) fn batch_bytes(&self, options: &FetchOptions) -> u64 {
        (self.window.limit(options) / 2).max(1)
    }

    /// The wanted records neither in flight nor backing off, most urgent first, and the earliest
    /// backoff expiry among the others.
    pub(super) fn ready(&self, now: Instant) -> (VecDeque<DiamondId>, Option<Instant>) {
        let mut next_retry: Option<Instant> = None;
        let mut ready: Vec<(DiamondId, f32)> = Vec::new();
        for (&id, p) in &self.wanted {
            if self.in_flight.contains(&id) {
                continue;
            }
            if let Some(&(_, until)) = self.backoff.get(&id)
                && until > now
            {
                next_retry = Some(next_retry.map_or(until, |t| t.min(until)));
                continue;
            }
            ready.push((id, p.priority));
        }
        ready.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        (ready.into_iter().map(|(id, _)| id).collect(), next_retry)
    }

    /// Replaces the wanted records (those the head stores and that were not just delivered).
    pub(super) fn set_wanted(
        &mut self,
        head: &RepositoryHead,
        wanted: impl IntoIterator<Item = (DiamondId, f32)>,
    ) {
        let delivered = &self.delivered;
        self.wanted = wanted
            .into_iter()
            .filter(|(id, _)| head.position(*id).is_some() && !delivered.contains(id))
            .map(|(id, priority)| (id, Pending { priority }))
            .collect();
    }

    /// Drops the requests [`not_worth_finishing`] for the wanted set, calling `abort` on each
    /// one's handle; their records go back to the queue. Returns the requests dropped and the
    /// records still wanted that they were carrying.
    pub(super) fn cancel_unwanted(
        &mut self,
        head: &RepositoryHead,
        options: &FetchOptions,
        abort: impl Fn(&H),
    ) -> (u64, u64) {
        let now = Instant::now();
        let (mut cancelled, mut requeued) = (0, 0);
        let State {
            wanted,
            batches,
            in_flight,
            window,
            ..
        } = self;
        batches.retain(|(batch, ids, handle)| {
            if !not_worth_finishing(ids, wanted, head, options) {
                return true;
            }
            abort(handle);
            window.end(*batch, None, now);
            for id in ids {
                in_flight.remove(id);
                requeued += u64::from(wanted.contains_key(id));
            }
            cancelled += 1;
            false
        });
        (cancelled, requeued)
    }

    /// Puts `failed` records into backoff: each retry waits twice as long as the last, from
    /// [`FetchOptions::initial_backoff`] up to [`FetchOptions::max_backoff`].
    pub(super) fn back_off(
        &mut self,
        failed: Vec<DiamondId>,
        now: Instant,
        options: &FetchOptions,
    ) {
        for id in failed {
            let attempts = self.backoff.get(&id).map_or(0, |b| b.0) + 1;
            let delay = options
                .initial_backoff
                .saturating_mul(1 << attempts.min(16))
                .min(options.max_backoff);
            self.backoff.insert(id, (attempts, now + delay));
        }
    }
}

/// Takes the next request's records off the front of `ready` (most urgent first): up to
/// [`FetchOptions::max_batch`] for a server; for a static file, the most urgent record and those
/// of the next few that lie near it (one range request covers them), the rest staying queued in
/// order.
pub(super) fn next_batch(
    ready: &mut VecDeque<DiamondId>,
    endpoint: &Endpoint,
    head: &RepositoryHead,
    options: &FetchOptions,
    max_bytes: u64,
) -> Vec<DiamondId> {
    match endpoint {
        Endpoint::Server { .. } => {
            let mut bytes = 0;
            let mut n = 0;
            while n < ready.len().min(options.max_batch) {
                let r = record_range(head, ready[n]);
                if n > 0 && bytes + (r.end - r.start) > max_bytes {
                    break;
                }
                bytes += r.end - r.start;
                n += 1;
            }
            ready.drain(..n).collect()
        }
        Endpoint::File { .. } => {
            let first = ready.pop_front().expect("not empty");
            let r0 = record_range(head, first);
            let (mut lo, mut hi) = (r0.start, r0.end);
            let gap = options.max_range_gap;
            let mut ids = vec![first];
            let mut kept = VecDeque::with_capacity(ready.len());
            for (scanned, id) in ready.drain(..).enumerate() {
                let r = record_range(head, id);
                if scanned < 4 * options.max_batch
                    && ids.len() < options.max_batch
                    && hi.max(r.end) - lo.min(r.start) <= max_bytes
                    && r.start <= hi + gap
                    && r.end + gap >= lo
                {
                    lo = lo.min(r.start);
                    hi = hi.max(r.end);
                    ids.push(id);
                } else {
                    kept.push_back(id);
                }
            }
            *ready = kept;
            ids
        }
    }
}

/// Record bytes of `ids`.
pub(super) fn record_bytes(head: &RepositoryHead, ids: &[DiamondId]) -> u64 {
    ids.iter()
        .map(|&id| {
            let r = record_range(head, id);
            r.end - r.start
        })
        .sum()
}

pub(super) fn record_range(head: &RepositoryHead, id: DiamondId) -> std::ops::Range<u64> {
    let i = head.position(id).expect("only stored records are wanted");
    head.record_range(i).expect("position is in range")
}

/// Whether a request whose still-to-come records are `remaining` should be dropped now that
/// `wanted` is what the view wants: none of them is wanted, or at least
/// [`FetchOptions::cancel_waste`] of their bytes (each with its entry's framing) is not.
pub(super) fn not_worth_finishing<V>(
    remaining: &[DiamondId],
    wanted: &HashMap<DiamondId, V>,
    head: &RepositoryHead,
    options: &FetchOptions,
) -> bool {
    let (mut useful, mut waste) = (0u64, 0u64);
    for &id in remaining {
        let r = record_range(head, id);
        let bytes = r.end - r.start + batch::ENTRY_HEAD_LEN as u64;
        if wanted.contains_key(&id) {
            useful += bytes;
        } else {
            waste += bytes;
        }
    }
    useful == 0 || waste as f64 >= options.cancel_waste * (useful + waste) as f64
}
