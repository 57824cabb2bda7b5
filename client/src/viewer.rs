//! The viewer core shared by the desktop window (`cbdam view`) and the browser page: what each
//! key does ([`Action`], [`action_for_key`]), the movement keys held ([`HeldKeys`]), the drags
//! and wheel steps of a frame ([`Gestures`]) and the viewer's switches ([`Toggles`]). The shells
//! only translate their events (winit's, the DOM's) into these calls, so a key or a drag means
//! the same in both.
//!
//! Keys are named as the W3C `KeyboardEvent` names them: `code` is the key's place on the
//! keyboard whatever the layout (`"KeyW"`, `"Digit1"`, `"NumpadAdd"`; winit's `KeyCode` variants
//! carry the same names) and `key` is what it types (`"+"`, `"Escape"`, `"Tab"`).

use crate::access::DataSource;
use crate::controls::{self, Controls, Mode, Movement};
use crate::refine::Refiner;
use crate::spawn::Spawner;

/// A key press that does something once (not a held movement key).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Action {
    /// Halve the pixel-error target (`+`).
    Finer,
    /// Double the pixel-error target (`-`).
    Coarser,
    /// Freeze / unfreeze the cut (F).
    Freeze,
    /// Colour by diamond level on / off (L).
    Levels,
    /// Wireframe on / off (Tab or 1).
    Wireframe,
    /// Heads-up display on / off (H).
    Hud,
    /// Orbit ↔ fly (C).
    Mode,
    /// Back to the first view (R).
    Reset,
    /// Save the window to a PNG (P).
    Screenshot,
    /// Close the viewer (Escape).
    Quit,
}

/// The one-off action of a key, if any: `code` is the key's place, `key` what it types.
pub fn action_for_key(code: &str, key: &str) -> Option<Action> {
    Some(match (key, code) {
        ("+" | "=", _) | (_, "NumpadAdd") => Action::Finer,
        ("-" | "_", _) | (_, "NumpadSubtract") => Action::Coarser,
        ("Escape", _) | (_, "Escape") => Action::Quit,
        (_, "Tab" | "Digit1") => Action::Wireframe,
        (_, "KeyF") => Action::Freeze,
        (_, "KeyL") => Action::Levels,
        (_, "KeyH") => Action::Hud,
        (_, "KeyC") => Action::Mode,
        (_, "KeyR") => Action::Reset,
        (_, "KeyP") => Action::Screenshot,
        _ => return None,
    })
}

/// The movement keys, by `code`: forward, back, right, left, up, down.
const MOVEMENT_KEYS: [&str; 6] = ["KeyW", "KeyS", "KeyD", "KeyA", "KeyQ", "KeyE"];

/// The movement keys held, and those tapped since the last frame.
#[derive(Clone, Debug, Default)]
pub struct HeldKeys {
    held: [bool; 6],
    /// Pressed since the last frame, even if already released: a tap between two slow frames
    /// still moves.
    tapped: [bool; 6],
    /// Shift is held (faster movement).
    pub shift: bool,
}

impl HeldKeys {
    /// Records a movement key (or Shift) going down or up; false when `code` is neither.
    pub fn set(&mut self, code: &str, down: bool) -> bool {
        if matches!(code, "ShiftLeft" | "ShiftRight") {
            self.shift = down;
            return true;
        }
        let Some(i) = MOVEMENT_KEYS.iter().position(|k| *k == code) else {
            return false;
        };
        self.held[i] = down;
        self.tapped[i] |= down;
        true
    }

    /// Forgets every key (the window lost focus and will not report their release).
    pub fn release_all(&mut self) {
        *self = Self::default();
    }

    /// This frame's movement; forgets the taps.
    pub fn take_movement(&mut self) -> Movement {
        let down = |i: usize| f64::from(u8::from(self.held[i] || self.tapped[i]));
        let movement = Movement {
            forward: down(0) - down(1),
            right: down(2) - down(3),
            up: down(4) - down(5),
            fast: self.shift,
        };
        self.tapped = [false; 6];
        movement
    }
}

/// The longest frame interval that moves the camera: a stalled frame (a window drag, a
/// debugger) must not fling it across the map.
pub const MAX_STEP_SECONDS: f64 = 0.25;

/// Drags and wheel steps gathered since the last frame, in pixels and wheel steps.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Gestures {
    /// Rotation drag (orbit) or look-around (fly).
    pub rotate: (f64, f64),
    /// Pan drag (orbit; flying, it looks around like `rotate`).
    pub pan: (f64, f64),
    /// Wheel or pinch steps, positive towards the terrain.
    pub zoom: f64,
}

impl Gestures {
    /// Adds a drag of (dx, dy) pixels, panning or rotating.
    pub fn drag(&mut self, dx: f64, dy: f64, pan: bool) {
        let sum = if pan { &mut self.pan } else { &mut self.rotate };
        sum.0 += dx;
        sum.1 += dy;
    }

    /// Moves `controls` by the gestures and the held keys over `dt` seconds (at most
    /// [`MAX_STEP_SECONDS`]) in a window `height` pixels high; forgets the gestures. Returns
    /// whether the camera moved.
    pub fn apply(
        &mut self,
        controls: &mut Controls,
        keys: &mut HeldKeys,
        height: u32,
        dt: f64,
    ) -> bool {
        let movement = keys.take_movement();
        let keys_move = movement.forward != 0.0 || movement.right != 0.0 || movement.up != 0.0;
        if controls.mode() == Mode::Fly {
            // Flying, every drag looks around.
            self.rotate.0 += self.pan.0;
            self.rotate.1 += self.pan.1;
            self.pan = (0.0, 0.0);
        }
        let moved = keys_move || *self != Self::default();
        if self.rotate != (0.0, 0.0) {
            controls.rotate(self.rotate.0, self.rotate.1);
        }
        if self.pan != (0.0, 0.0) {
            controls.pan(self.pan.0, self.pan.1, height);
        }
        if self.zoom != 0.0 {
            controls.zoom(self.zoom);
        }
        if keys_move {
            controls.update(movement, dt.clamp(0.0, MAX_STEP_SECONDS));
        }
        *self = Self::default();
        moved
    }
}

/// The viewer's switches.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Toggles {
    /// The cut is frozen (refinement paused, the camera still moves).
    pub frozen: bool,
    /// Triangles coloured by diamond level.
    pub levels: bool,
    /// Wireframe over the surface.
    pub wireframe: bool,
    /// The heads-up display is drawn.
    pub hud: bool,
}

impl Default for Toggles {
    fn default() -> Self {
        Self {
            frozen: false,
            levels: false,
            wireframe: false,
            hud: true,
        }
    }
}

/// What an action leaves for the shell to do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Effect {
    /// Nothing more.
    None,
    /// The cut to converge to changed (a new error target, a reset view, an unfrozen cut).
    CutChanged,
    /// The adapter cannot draw a wireframe: tell the user.
    NoWireframe,
    /// Save a screenshot.
    Screenshot,
    /// Close the viewer.
    Quit,
}

impl Toggles {
    /// Carries out `action` on the switches, the camera `controls` and the `refiner`'s error
    /// target; `wireframe_supported` says whether the adapter can draw lines.
    pub fn act<S: DataSource, X: Spawner>(
        &mut self,
        action: Action,
        controls: &mut Controls,
        refiner: &mut Refiner<S, X>,
        wireframe_supported: bool,
    ) -> Effect {
        match action {
            Action::Finer | Action::Coarser => {
                let step = if action == Action::Finer {
                    controls::finer
                } else {
                    controls::coarser
                };
                refiner.set_pixel_error(step(refiner.config().pixel_error));
                return Effect::CutChanged;
            }
            Action::Freeze => {
                self.frozen = !self.frozen;
                if !self.frozen {
                    return Effect::CutChanged;
                }
            }
            Action::Levels => self.levels = !self.levels,
            Action::Wireframe if wireframe_supported => self.wireframe = !self.wireframe,
            Action::Wireframe => return Effect::NoWireframe,
            Action::Hud => self.hud = !self.hud,
            Action::Mode => controls.toggle_mode(),
            Action::Reset => {
                controls.reset();
                return Effect::CutChanged;
            }
            Action::Screenshot => return Effect::Screenshot,
            Action::Quit => return Effect::Quit,
        }
        Effect::None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_map_to_the_same_actions_whatever_the_layout() {
        assert_eq!(action_for_key("Equal", "+"), Some(Action::Finer));
        assert_eq!(action_for_key("NumpadAdd", "+"), Some(Action::Finer));
        assert_eq!(action_for_key("Minus", "-"), Some(Action::Coarser));
        assert_eq!(action_for_key("Tab", "Tab"), Some(Action::Wireframe));
        assert_eq!(action_for_key("Digit1", "&"), Some(Action::Wireframe));
        // An AZERTY keyboard's A sits where QWERTY's Q is: the place decides.
        assert_eq!(action_for_key("KeyF", "f"), Some(Action::Freeze));
        assert_eq!(action_for_key("KeyH", "h"), Some(Action::Hud));
        assert_eq!(action_for_key("Escape", "Escape"), Some(Action::Quit));
        assert_eq!(action_for_key("KeyW", "w"), None);
        assert_eq!(action_for_key("KeyZ", "z"), None);
    }

    #[test]
    fn opposite_keys_cancel_and_a_tap_moves_once() {
        let mut keys = HeldKeys::default();
        assert!(keys.set("KeyW", true));
        assert!(keys.set("KeyS", true));
        assert!(!keys.set("KeyZ", true));
        assert_eq!(keys.take_movement().forward, 0.0);
        keys.set("KeyS", false);
        keys.set("KeyW", false);
        keys.set("KeyD", true);
        keys.set("KeyD", false);
        keys.set("ShiftLeft", true);
        let tapped = keys.take_movement();
        assert_eq!((tapped.right, tapped.fast), (1.0, true));
        assert_eq!(keys.take_movement().right, 0.0);
        keys.set("KeyQ", true);
        keys.release_all();
        assert_eq!(keys.take_movement(), Movement::default());
    }
}
