//! Pacing: how long a frame may refine (its deadline, what recent frames overran) and whether
//! the frames come far enough apart for the workers to decode ahead between them.

use super::{
    AHEAD_SHARE, FrameStats, OVERRUN_CAP, OVERRUN_DECAY, OVERRUN_PRIOR, OVERRUN_SPREAD,
    PACED_BUDGETS, Refiner, SMOOTHING,
};
use crate::access::DataSource;
use crate::spawn::Spawner;
use std::time::Duration;
use web_time::Instant;

/// The frames' timing, for deadlines and for sizing work to the time between frames.
#[derive(Debug)]
pub(super) struct Pacing {
    /// How far recent frames ran past their refinement deadline (the bookkeeping after the
    /// loop, the last results applied): the next deadline comes that much earlier, so that the
    /// whole frame, not only its refinement loop, fits the budget. A decaying maximum, so one
    /// slow tail is remembered for a while (the budget is a bound on every frame, not on the
    /// average).
    pub(super) overrun: Duration,
    /// When the last frame started, and the smoothed interval between frames, seconds.
    pub(super) last_frame_start: Option<Instant>,
    pub(super) frame_interval_s: f64,
    /// Smoothed refinements per second.
    pub(super) refinement_rate: f64,
    /// Smoothed worker time of one decode, seconds.
    pub(super) decode_s: f64,
}

impl Pacing {
    /// Before any frame: a prior overrun of a share of `budget`, 30 frames a second.
    pub(super) fn new(budget: Option<Duration>) -> Self {
        Pacing {
            overrun: budget.map_or(Duration::ZERO, |b| b / OVERRUN_PRIOR),
            last_frame_start: None,
            frame_interval_s: 1.0 / 30.0,
            refinement_rate: 0.0,
            decode_s: 1e-3,
        }
    }
}

impl<S: DataSource, X: Spawner> Refiner<S, X> {
    /// Frame step: counts the frame, smooths the interval between frames, and says whether the
    /// frame collects garbage (every `gc_interval` frames, and while a collection that stopped
    /// at its budget goes on).
    pub(super) fn start_frame(&mut self, start: Instant) -> bool {
        if let Some(last) = self.pacing.last_frame_start {
            let dt = start.duration_since(last).as_secs_f64();
            self.pacing.frame_interval_s += SMOOTHING * (dt - self.pacing.frame_interval_s);
        }
        self.pacing.last_frame_start = Some(start);
        self.frame += 1;
        self.config.gc_interval > 0
            && (self.collecting
                || self
                    .frame
                    .is_multiple_of(u64::from(self.config.gc_interval)))
    }

    /// When the refinement loop of a frame started at `start` must stop: the budget less what
    /// recent frames ran past their deadline ([`Refiner::remember_overrun`]), so that the whole
    /// frame fits the budget. `None` without a budget.
    pub(super) fn refinement_deadline(&self, start: Instant) -> Option<Instant> {
        // At most half the budget is held back for the tail, so refinement always gets the
        // other half; between paced frames that decode ahead, at least AHEAD_SHARE of it.
        let ahead_floor = match self.config.budget {
            Some(b) if self.decodes_ahead() && self.paced() => b / AHEAD_SHARE,
            _ => Duration::ZERO,
        };
        self.config.budget.map(|b| {
            let held_back = self.pacing.overrun.mul_f64(OVERRUN_SPREAD).max(ahead_floor);
            start + b - held_back.min(b / OVERRUN_CAP)
        })
    }

    /// Frame step: the smoothed refinements per second, which sizes the wants of the next
    /// frames.
    pub(super) fn smooth_refinement_rate(&mut self, stats: &FrameStats) {
        let rate = stats.refinements as f64 / self.pacing.frame_interval_s.max(1e-3);
        self.pacing.refinement_rate += SMOOTHING * (rate - self.pacing.refinement_rate);
    }

    /// Frame step: when the budget ran out, how far past its deadline the frame ran (see
    /// `overrun`).
    pub(super) fn remember_overrun(&mut self, deadline: Option<Instant>, stats: &FrameStats) {
        if let (Some(d), Some(b), true) = (deadline, self.config.budget, stats.budget_exhausted) {
            // Remembered at most as the most the deadline can hold back: a longer one is a
            // stall (the thread off its core for a scheduler tick, 4 ms on this machine), which
            // no deadline avoids, and remembered whole it held the next 80 frames' deadlines at
            // the cap.
            let over = Instant::now()
                .saturating_duration_since(d)
                .min(b / OVERRUN_CAP);
            self.pacing.overrun = over.max(self.pacing.overrun.mul_f64(OVERRUN_DECAY));
        }
    }

    /// Whether frames end by decoding ahead of the cut (see [`Refiner::speculate`]).
    pub(super) fn decodes_ahead(&self) -> bool {
        self.config.decode_ahead && self.spawner.runs_in_background()
    }

    /// Whether frames come at least [`PACED_BUDGETS`] budgets apart: a viewer's frames, whose
    /// workers have the time between them.
    pub(super) fn paced(&self) -> bool {
        self.config
            .budget
            .is_some_and(|b| self.pacing.frame_interval_s > PACED_BUDGETS * b.as_secs_f64())
    }
}
