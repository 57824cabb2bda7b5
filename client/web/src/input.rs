//! Mouse input on the canvas, collected by event listeners and applied once a frame: left-drag
//! rotates the orbit camera, right- (or shift-) drag pans, the wheel zooms.

use std::cell::RefCell;
use std::rc::Rc;

use cbdam_client::controls::Controls;
use wasm_bindgen::JsCast;
use wasm_bindgen::closure::Closure;
use web_sys::{HtmlCanvasElement, MouseEvent, WheelEvent};

/// What the mouse did since the last frame.
#[derive(Debug, Default)]
struct Pending {
    rotate: (f64, f64),
    pan: (f64, f64),
    /// Wheel steps, positive towards the terrain.
    zoom: f64,
    /// The button held and the last position, while dragging.
    drag: Option<(i16, f64, f64, bool)>,
}

/// The canvas's accumulated mouse input.
#[derive(Clone, Debug, Default)]
pub struct Input {
    pending: Rc<RefCell<Pending>>,
}

/// Browsers report wheel deltas in pixels (about 100 per notch) or lines (about 3 per notch).
const PIXELS_PER_STEP: f64 = 100.0;
const LINES_PER_STEP: f64 = 3.0;

impl Input {
    /// Listens to the mouse on `canvas` (for the page's lifetime).
    pub fn listen(canvas: &HtmlCanvasElement) -> Self {
        let me = Self::default();
        let on = |event: &str, f: Box<dyn FnMut(MouseEvent)>| {
            let closure = Closure::wrap(f);
            let _ =
                canvas.add_event_listener_with_callback(event, closure.as_ref().unchecked_ref());
            closure.forget();
        };
        let p = me.pending.clone();
        on(
            "mousedown",
            Box::new(move |e: MouseEvent| {
                let pan = e.button() == 2 || e.shift_key();
                p.borrow_mut().drag = Some((
                    e.button(),
                    f64::from(e.client_x()),
                    f64::from(e.client_y()),
                    pan,
                ));
                e.prevent_default();
            }),
        );
        let p = me.pending.clone();
        on(
            "mousemove",
            Box::new(move |e: MouseEvent| {
                let mut p = p.borrow_mut();
                let Some((button, x0, y0, pan)) = p.drag else {
                    return;
                };
                let (x, y) = (f64::from(e.client_x()), f64::from(e.client_y()));
                let d = (x - x0, y - y0);
                if pan {
                    p.pan.0 += d.0;
                    p.pan.1 += d.1;
                } else {
                    p.rotate.0 += d.0;
                    p.rotate.1 += d.1;
                }
                p.drag = Some((button, x, y, pan));
            }),
        );
        for end in ["mouseup", "mouseleave"] {
            let p = me.pending.clone();
            on(end, Box::new(move |_| p.borrow_mut().drag = None));
        }
        on("contextmenu", Box::new(|e: MouseEvent| e.prevent_default()));
        let p = me.pending.clone();
        let wheel = Closure::<dyn FnMut(WheelEvent)>::new(move |e: WheelEvent| {
            let per_step = if e.delta_mode() == WheelEvent::DOM_DELTA_LINE {
                LINES_PER_STEP
            } else {
                PIXELS_PER_STEP
            };
            // Scrolling down (positive delta) moves away from the terrain.
            p.borrow_mut().zoom -= e.delta_y() / per_step;
            e.prevent_default();
        });
        let _ = canvas.add_event_listener_with_callback("wheel", wheel.as_ref().unchecked_ref());
        wheel.forget();
        me
    }

    /// Applies what the mouse did since the last call to `controls`; whether anything did.
    pub fn apply(&self, controls: &mut Controls, height: u32) -> bool {
        let mut p = self.pending.borrow_mut();
        let moved = p.rotate != (0.0, 0.0) || p.pan != (0.0, 0.0) || p.zoom != 0.0;
        if p.rotate != (0.0, 0.0) {
            controls.rotate(p.rotate.0, p.rotate.1);
        }
        if p.pan != (0.0, 0.0) {
            controls.pan(p.pan.0, p.pan.1, height);
        }
        if p.zoom != 0.0 {
            controls.zoom(p.zoom);
        }
        p.rotate = (0.0, 0.0);
        p.pan = (0.0, 0.0);
        p.zoom = 0.0;
        moved
    }
}
