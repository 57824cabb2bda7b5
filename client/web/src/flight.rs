//! Camera flights played in the page (`index.html?flight=URL[&fps=N]`, or [`play_flight`]):
//! the JSON flights of `cbdam render --path` and `cbdam replay` (`cbdam_client::flight`), one
//! frame of flight time per animation frame, so that the page flies through the same cameras
//! as `cbdam render --path` does natively, whatever its frame rate. The page measures each
//! frame of the flight: the time of its refinement step and the interval since the frame
//! before, and reports their median, 99th percentile and largest in the status's `flight`
//! field once the flight ends (for the figures beside the native client's). A drag, the
//! wheel or a movement key ends a flight early; the camera then stays where the flight was.

use std::cell::RefCell;

use cbdam_client::camera::Camera;
use cbdam_client::flight::Flight;
use cbdam_client::stats::percentile;
use cbdam_client::world::World;
use wasm_bindgen::JsValue;
use wasm_bindgen::prelude::wasm_bindgen;

thread_local! {
    /// A flight asked for by the page, started at the next animation frame.
    static REQUEST: RefCell<Option<Playback>> = const { RefCell::new(None) };
}

/// Plays a camera flight from its start: `json` is a flight as `cbdam render --path` reads it
/// (client/src/flight.rs), `fps` the frames per second of flight time (one animation frame
/// each, as `cbdam render --path --fps`). Starts at the next animation frame, replacing a
/// flight in progress; the status's `flight` field follows it. A flight that does not parse,
/// or an `fps` that is not positive, is an error naming the problem.
#[wasm_bindgen]
pub fn play_flight(json: &str, fps: f64) -> Result<(), JsValue> {
    if !(fps.is_finite() && fps > 0.0) {
        return Err(format!("the flight's fps must be positive, not {fps}").into());
    }
    let flight = Flight::parse(json).map_err(|e| e.to_string())?;
    REQUEST.with(|r| *r.borrow_mut() = Some(Playback::new(flight, fps)));
    Ok(())
}

/// The flight the page asked for since the last call, if any.
pub fn requested() -> Option<Playback> {
    REQUEST.with(|r| r.borrow_mut().take())
}

/// A flight being played, and what its frames measured.
pub struct Playback {
    flight: Flight,
    fps: f64,
    /// The next frame to fly, and how many the flight has (`⌈duration · fps⌉ + 1`, as
    /// `cbdam render --path`).
    frame: u64,
    frames: u64,
    /// Per frame flown: the refinement step's time, ms; the interval since the previous
    /// animation frame, ms (from the second frame).
    refine_ms: Vec<f64>,
    interval_ms: Vec<f64>,
    /// Frames whose refinement step took longer than its budget; the largest screen error
    /// left, px.
    over_budget: u64,
    max_error_px: f64,
    /// `performance.now()` at the first frame flown.
    started_ms: Option<f64>,
}

impl Playback {
    fn new(flight: Flight, fps: f64) -> Self {
        let frames = (flight.duration() * fps).ceil() as u64 + 1;
        Self {
            flight,
            fps,
            frame: 0,
            frames,
            refine_ms: Vec::new(),
            interval_ms: Vec::new(),
            over_budget: 0,
            max_error_px: 0.0,
            started_ms: None,
        }
    }

    /// The camera of the next frame of the flight.
    pub fn camera(&self, world: &World, size: (u32, u32)) -> Camera {
        let t = (self.frame as f64 / self.fps).min(self.flight.duration());
        self.flight.camera(world, t, size)
    }

    /// Records the frame just flown: its refinement step's time and whether that overran the
    /// step's budget, the screen error left, and the interval since the animation frame
    /// before.
    pub fn flown(
        &mut self,
        refine_ms: f64,
        over_budget: bool,
        error_px: f64,
        interval_ms: f64,
        now_ms: f64,
    ) {
        if self.started_ms.is_none() {
            self.started_ms = Some(now_ms);
        } else {
            self.interval_ms.push(interval_ms);
        }
        self.refine_ms.push(refine_ms);
        self.over_budget += u64::from(over_budget);
        self.max_error_px = self.max_error_px.max(error_px);
        self.frame += 1;
    }

    /// Whether every frame has been flown.
    pub fn finished(&self) -> bool {
        self.frame >= self.frames
    }

    /// The status's `flight` field: `{frame, frames, fps, done, stopped}` and, once the flight
    /// ended (`done`: every frame flown; `stopped`: ended early by input), `refineMs` and
    /// `frameMs` as `[median, p99, largest]`, `overBudget` (frames whose refinement step took
    /// longer than its budget), `refineMsPerFrame` (each frame's step, for plots),
    /// `maxErrorPx` and `seconds` (the flight's wall time).
    pub fn status(&self, now_ms: f64, stopped: bool) -> Vec<(&'static str, JsValue)> {
        let done = self.finished();
        let mut fields = vec![
            ("frame", JsValue::from_f64(self.frame as f64)),
            ("frames", JsValue::from_f64(self.frames as f64)),
            ("fps", JsValue::from_f64(self.fps)),
            ("done", JsValue::from_bool(done)),
            ("stopped", JsValue::from_bool(stopped)),
        ];
        if done || stopped {
            let spread = |values: &[f64]| -> JsValue {
                let mut sorted = values.to_vec();
                sorted.sort_by(f64::total_cmp);
                let last = sorted.last().copied().unwrap_or(0.0);
                [percentile(&sorted, 0.5), percentile(&sorted, 0.99), last]
                    .iter()
                    .map(|&v| JsValue::from_f64(v))
                    .collect::<js_sys::Array>()
                    .into()
            };
            fields.push(("refineMs", spread(&self.refine_ms)));
            fields.push(("frameMs", spread(&self.interval_ms)));
            fields.push(("overBudget", JsValue::from_f64(self.over_budget as f64)));
            let per_frame: js_sys::Array = self
                .refine_ms
                .iter()
                .map(|&v| JsValue::from_f64(v))
                .collect();
            fields.push(("refineMsPerFrame", per_frame.into()));
            fields.push(("maxErrorPx", JsValue::from_f64(self.max_error_px)));
            let seconds = self.started_ms.map_or(0.0, |t| (now_ms - t) / 1e3);
            fields.push(("seconds", JsValue::from_f64(seconds)));
        }
        fields
    }
}
