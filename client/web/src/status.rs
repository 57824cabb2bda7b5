//! The page's state on `window.cbdam`, for the page's overlay and for tests:
//!
//! | field | meaning |
//! |---|---|
//! | `phase` | `"starting"`, `"connecting"`, `"running"` or `"failed"` |
//! | `webgpu` | whether the browser offers a WebGPU adapter |
//! | `webgl2` | without WebGPU: whether it offers WebGL2 (named in the error) |
//! | `backend` | `"webgpu"` or `"webgl"` (WebGL2, built with the `webgl` feature, the default) once an adapter is found |
//! | `vertexFetch` | the renderer's path: `"storage"` (storage buffers, WebGPU) or `"texture"` (WebGL2) |
//! | `adapter` | the adapter's name |
//! | `draped` | whether a colour repository is draped over the terrain (`?colour=URL`) |
//! | `error` | why the page failed (`phase == "failed"`), or `""` |
//! | `frames` | frames drawn |
//! | `refined`, `drawnHalves`, `triangles` | the cut: refined diamonds, half-patches, triangles |
//! | `cut` | the refined diamonds' ids (`"L/x/y"`), sorted, once converged |
//! | `converged` | the last frame's cut is the one this view converges to |
//! | `maxErrorPx` | the largest screen-space error left, pixels |
//! | `recordsRequested`, `bytes`, `fetchErrors` | the data source's counters: records requested, bytes received, failed requests and rejected records |
//! | `firstFrameMs`, `convergedMs` | `performance.now()` at the first frame drawn and at the first converged frame (ms since the page's navigation began) |
//! | `camera` | `[eye x, y, z, target x, y, z]`, metres |
//! | `fps`, `frameMs` | frame rate and frame interval, median of the last 60 frames |
//! | `pixelError` | the pixel-error target in use (keys `+`/`-`, the page's slider) |
//! | `mode`, `frozen`, `levels`, `wireframe` | `"orbit"` or `"fly"`; the cut frozen (F); colour by level (L); wireframe (Tab) |
//! | `cpuCache` | `[record bytes, record budget, decoded bytes, decoded budget]` |
//! | `gpuCache` | `[resident slots, slots]` of the GPU height pool |
//! | `inFlight` | requests in flight |
//! | `decoded`, `decodeMs` | diamonds decoded since the page started (in workers or on the page) and their decode time where they ran, ms |
//! | `refineMs` | `[total, largest]` time of the page's refinement step per frame since the page started, ms |
//! | `workers` | decoding in Web Workers: `{count, ready, decoded, busyMs, onPage, problem}`: workers running and set up, diamonds they decoded and their time on it (ms), diamonds decoded on the page instead, and why (`""` if none) |
//! | `flight` | a camera flight played by the page (`?flight=URL`, `flight.rs`): `{frame, frames, fps, done, stopped}`, and once it ended `refineMs` and `frameMs` (`[median, p99, largest]` per frame of the flight: the refinement step; the interval between animation frames), `overBudget` (frames whose step took longer than its budget), `refineMsPerFrame`, `maxErrorPx`, `seconds`; or `{error}` when it could not be fetched or parsed |
//! | `notice` | a key that could not be honoured (e.g. no wireframe on this adapter) |
//!
//! The page's own "ok" is not proof that anything was drawn (a canvas can stay blank while
//! wgpu reports success): tests check the pixels of a screenshot too.

use js_sys::{Array, Object, Reflect};
use wasm_bindgen::JsValue;

/// Writes fields of `window.cbdam`.
#[derive(Clone, Debug)]
pub struct Status {
    object: Object,
}

impl Status {
    /// Creates `window.cbdam` (replacing any earlier one), phase `"starting"`.
    pub fn install() -> Self {
        let object = Object::new();
        if let Some(window) = web_sys::window() {
            let _ = Reflect::set(&window, &"cbdam".into(), &object);
        }
        let me = Self { object };
        me.set("phase", "starting");
        me.set("error", "");
        me.set("frames", 0.0);
        me.set("converged", false);
        me
    }

    /// Sets one field.
    pub fn set(&self, key: &str, value: impl Into<JsValue>) {
        let _ = Reflect::set(&self.object, &key.into(), &value.into());
    }

    /// Sets a field to an array of numbers.
    pub fn set_numbers(&self, key: &str, values: &[f64]) {
        let array: Array = values.iter().map(|&v| JsValue::from_f64(v)).collect();
        self.set(key, array);
    }

    /// Sets a field to an object of the given fields.
    pub fn set_object(&self, key: &str, fields: &[(&str, JsValue)]) {
        let object = Object::new();
        for (k, v) in fields {
            let _ = Reflect::set(&object, &(*k).into(), v);
        }
        self.set(key, object);
    }

    /// Sets a field to an array of strings.
    pub fn set_strings(&self, key: &str, values: &[String]) {
        let array: Array = values.iter().map(|v| JsValue::from_str(v)).collect();
        self.set(key, array);
    }

    /// Marks the page failed with `message` (also on the console).
    pub fn fail(&self, message: &str) {
        self.set("phase", "failed");
        self.set("error", message);
        web_sys::console::error_1(&format!("cbdam: {message}").into());
    }
}
