//! Input on the page, collected by event listeners and applied once a frame, as in `cbdam view`:
//!
//! - Pointer events (mouse, pen and touch alike): one pointer dragging rotates the orbit camera
//!   (looks around in fly mode); the right or middle button, or Shift, pans. Two touching
//!   pointers pinch to zoom, twist to turn the view and move together to pan.
//! - The wheel zooms (orbit) or moves forward (fly).
//! - Keys on the window: W/A/S/D/Q/E (Shift faster) move; `+`/`-` halve/double the pixel-error
//!   target, F freezes the cut, L colours by level, Tab or 1 toggles the wireframe, C switches
//!   orbit/fly, R resets the view.
//!
//! What a key, a drag or a wheel step does is the viewer core's (`cbdam_client::viewer`), as in
//! `cbdam view`: this file only turns DOM events into its calls.

use std::cell::RefCell;
use std::rc::Rc;

use cbdam_client::controls::{Controls, TURN_PER_PIXEL, ZOOM_STEP};
use cbdam_client::viewer::{Action, Gestures, HeldKeys, action_for_key};
use wasm_bindgen::JsCast;
use wasm_bindgen::closure::Closure;
use web_sys::{HtmlCanvasElement, KeyboardEvent, PointerEvent, WheelEvent};

/// A pointer held down on the canvas.
#[derive(Clone, Copy, Debug)]
struct Pointer {
    id: i32,
    x: f64,
    y: f64,
    /// A single-pointer drag pans instead of rotating.
    pan: bool,
}

/// What happened since the last frame.
#[derive(Debug, Default)]
struct Pending {
    gestures: Gestures,
    pointers: Vec<Pointer>,
    keys: HeldKeys,
    actions: Vec<Action>,
}

/// The page's accumulated input.
#[derive(Clone, Debug, Default)]
pub struct Input {
    pending: Rc<RefCell<Pending>>,
}

/// Browsers report wheel deltas in pixels (about 100 per notch) or lines (about 3 per notch).
const PIXELS_PER_STEP: f64 = 100.0;
const LINES_PER_STEP: f64 = 3.0;

/// Adds a listener for the page's lifetime.
fn listen<E: wasm_bindgen::convert::FromWasmAbi + 'static>(
    target: &web_sys::EventTarget,
    event: &str,
    f: impl FnMut(E) + 'static,
) {
    let closure = Closure::<dyn FnMut(E)>::new(f);
    let _ = target.add_event_listener_with_callback(event, closure.as_ref().unchecked_ref());
    closure.forget();
}

/// The pinch, twist and pan of two pointers moving from `before` to `after`: zoom steps
/// (positive when they spread), turn (radians, clockwise on screen) and the midpoint's move.
fn two_finger(before: [(f64, f64); 2], after: [(f64, f64); 2]) -> (f64, f64, (f64, f64)) {
    let span = |p: [(f64, f64); 2]| (p[1].0 - p[0].0).hypot(p[1].1 - p[0].1);
    let angle = |p: [(f64, f64); 2]| (p[1].1 - p[0].1).atan2(p[1].0 - p[0].0);
    let mid = |p: [(f64, f64); 2]| ((p[0].0 + p[1].0) / 2.0, (p[0].1 + p[1].1) / 2.0);
    let (s0, s1) = (span(before), span(after));
    let zoom = if s0 > 1.0 && s1 > 1.0 {
        (s1 / s0).ln() / (1.0 / ZOOM_STEP).ln()
    } else {
        0.0
    };
    let mut turn = angle(after) - angle(before);
    if turn > std::f64::consts::PI {
        turn -= std::f64::consts::TAU;
    } else if turn < -std::f64::consts::PI {
        turn += std::f64::consts::TAU;
    }
    let (m0, m1) = (mid(before), mid(after));
    (zoom, turn, (m1.0 - m0.0, m1.1 - m0.1))
}

impl Pending {
    /// Pointer `id` moved to (x, y): one pointer drags, two pinch, twist and pan.
    fn pointer_moved(&mut self, id: i32, x: f64, y: f64) {
        let Some(i) = self.pointers.iter().position(|q| q.id == id) else {
            return;
        };
        match self.pointers.len() {
            1 => {
                let q = self.pointers[0];
                self.gestures.drag(x - q.x, y - q.y, q.pan);
            }
            2 => {
                let before = [
                    (self.pointers[0].x, self.pointers[0].y),
                    (self.pointers[1].x, self.pointers[1].y),
                ];
                let mut after = before;
                after[i] = (x, y);
                let (zoom, turn, moved) = two_finger(before, after);
                self.gestures.zoom += zoom;
                // The terrain follows the fingers: a clockwise twist turns the view
                // anticlockwise.
                self.gestures.drag(-turn / TURN_PER_PIXEL, 0.0, false);
                self.gestures.drag(moved.0, moved.1, true);
            }
            // Three or more: ignored.
            _ => {}
        }
        self.pointers[i].x = x;
        self.pointers[i].y = y;
    }

    /// A key went down: a movement key is held, another may be an action.
    fn key_down(&mut self, e: &KeyboardEvent) {
        self.keys.shift = e.shift_key();
        if self.keys.set(&e.code(), true) {
            return;
        }
        if e.repeat() || e.ctrl_key() || e.meta_key() || e.alt_key() {
            return;
        }
        // The page has no HUD to hide, no screenshot key and nothing to close.
        match action_for_key(&e.code(), &e.key()) {
            None | Some(Action::Hud | Action::Screenshot | Action::Quit) => {}
            Some(action) => {
                self.actions.push(action);
                e.prevent_default();
            }
        }
    }
}

impl Input {
    /// Listens to pointers and the wheel on `canvas` and to keys on the window.
    pub fn listen(canvas: &HtmlCanvasElement) -> Self {
        let me = Self::default();
        me.listen_pointers(canvas);
        me.listen_wheel(canvas);
        if let Some(window) = web_sys::window() {
            me.listen_keys(window.as_ref());
        }
        me
    }

    /// Pointer events on `canvas` (mouse, pen and touch).
    fn listen_pointers(&self, canvas: &HtmlCanvasElement) {
        let target: &web_sys::EventTarget = canvas.as_ref();
        let (p, c) = (self.pending.clone(), canvas.clone());
        listen(target, "pointerdown", move |e: PointerEvent| {
            let _ = c.set_pointer_capture(e.pointer_id());
            let mut p = p.borrow_mut();
            p.pointers.retain(|q| q.id != e.pointer_id());
            p.pointers.push(Pointer {
                id: e.pointer_id(),
                x: f64::from(e.client_x()),
                y: f64::from(e.client_y()),
                pan: e.button() == 1 || e.button() == 2 || e.shift_key(),
            });
            e.prevent_default();
        });
        let p = self.pending.clone();
        listen(target, "pointermove", move |e: PointerEvent| {
            let (x, y) = (f64::from(e.client_x()), f64::from(e.client_y()));
            p.borrow_mut().pointer_moved(e.pointer_id(), x, y);
        });
        for end in ["pointerup", "pointercancel"] {
            let p = self.pending.clone();
            listen(target, end, move |e: PointerEvent| {
                p.borrow_mut().pointers.retain(|q| q.id != e.pointer_id());
            });
        }
        listen(target, "contextmenu", |e: web_sys::MouseEvent| {
            e.prevent_default()
        });
    }

    /// The wheel on `canvas`.
    fn listen_wheel(&self, canvas: &HtmlCanvasElement) {
        let p = self.pending.clone();
        listen(canvas.as_ref(), "wheel", move |e: WheelEvent| {
            let per_step = if e.delta_mode() == WheelEvent::DOM_DELTA_LINE {
                LINES_PER_STEP
            } else {
                PIXELS_PER_STEP
            };
            // Scrolling down (positive delta) moves away from the terrain.
            p.borrow_mut().gestures.zoom -= e.delta_y() / per_step;
            e.prevent_default();
        });
    }

    /// Keys on the page's `window`.
    fn listen_keys(&self, window: &web_sys::EventTarget) {
        let p = self.pending.clone();
        listen(window, "keydown", move |e: KeyboardEvent| {
            p.borrow_mut().key_down(&e)
        });
        let p = self.pending.clone();
        listen(window, "keyup", move |e: KeyboardEvent| {
            let mut p = p.borrow_mut();
            p.keys.shift = e.shift_key();
            p.keys.set(&e.code(), false);
        });
        // Keys released while the page had no focus never report it.
        let p = self.pending.clone();
        listen(window, "blur", move |_: web_sys::FocusEvent| {
            let mut p = p.borrow_mut();
            p.keys.release_all();
            p.pointers.clear();
        });
    }

    /// Applies what happened since the last call to `controls` (held keys for `dt` seconds);
    /// returns whether the camera moved and the key actions to carry out.
    pub fn apply(&self, controls: &mut Controls, height: u32, dt: f64) -> (bool, Vec<Action>) {
        let p = &mut *self.pending.borrow_mut();
        let moved = p.gestures.apply(controls, &mut p.keys, height, dt);
        (moved, std::mem::take(&mut p.actions))
    }
}
