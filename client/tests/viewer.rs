//! The viewer core: a key's action changes the same switches, camera and error target whichever
//! shell reported it, and drags and held keys move the camera as the controls say.

use cbdam_client::access::LocalSource;
use cbdam_client::camera::Camera;
use cbdam_client::controls::{Controls, Mode};
use cbdam_client::refine::{RefineConfig, Refiner};
use cbdam_client::viewer::{Action, Effect, Gestures, HeldKeys, Toggles, action_for_key};
use cbdam_client::world::World;

use crate::streaming::repository;

fn viewer() -> (Toggles, Controls, Refiner<LocalSource>, World) {
    let repo = repository();
    let world = World::of_repository(&repo);
    let controls = Controls::new(&world, &Camera::framed(&world, (640, 480)));
    let refiner = Refiner::new(LocalSource::new(repo), RefineConfig::default()).unwrap();
    (Toggles::default(), controls, refiner, world)
}

#[test]
fn actions_change_the_error_target_the_switches_and_the_camera() {
    let (mut toggles, mut controls, mut refiner, _) = viewer();
    let px = refiner.config().pixel_error;
    let finer = action_for_key("NumpadAdd", "+").unwrap();
    assert_eq!(
        toggles.act(finer, &mut controls, &mut refiner, true),
        Effect::CutChanged
    );
    assert!(refiner.config().pixel_error < px);
    let coarser = action_for_key("Minus", "-").unwrap();
    toggles.act(coarser, &mut controls, &mut refiner, true);
    assert_eq!(refiner.config().pixel_error, px);

    assert_eq!(
        toggles.act(Action::Freeze, &mut controls, &mut refiner, true),
        Effect::None
    );
    assert!(toggles.frozen);
    // Unfreezing asks the shell to converge again.
    assert_eq!(
        toggles.act(Action::Freeze, &mut controls, &mut refiner, true),
        Effect::CutChanged
    );
    assert!(toggles.hud);
    toggles.act(Action::Hud, &mut controls, &mut refiner, true);
    assert!(!toggles.hud);
    toggles.act(Action::Levels, &mut controls, &mut refiner, true);
    assert!(toggles.levels);
    assert_eq!(
        toggles.act(Action::Wireframe, &mut controls, &mut refiner, false),
        Effect::NoWireframe
    );
    assert!(!toggles.wireframe);
    toggles.act(Action::Wireframe, &mut controls, &mut refiner, true);
    assert!(toggles.wireframe);
    toggles.act(Action::Mode, &mut controls, &mut refiner, true);
    assert_eq!(controls.mode(), Mode::Fly);
    assert_eq!(
        toggles.act(Action::Quit, &mut controls, &mut refiner, true),
        Effect::Quit
    );
    assert_eq!(
        toggles.act(Action::Screenshot, &mut controls, &mut refiner, true),
        Effect::Screenshot
    );
}

#[test]
fn drags_and_keys_move_the_camera_and_reset_brings_it_back() {
    let (mut toggles, mut controls, mut refiner, _) = viewer();
    let (mut gestures, mut keys) = (Gestures::default(), HeldKeys::default());
    let start = controls.eye();
    assert!(!gestures.apply(&mut controls, &mut keys, 480, 0.016));
    assert_eq!(controls.eye(), start);

    gestures.drag(40.0, 10.0, false);
    gestures.zoom += 2.0;
    assert!(gestures.apply(&mut controls, &mut keys, 480, 0.016));
    assert_ne!(controls.eye(), start);
    assert_eq!(gestures, Gestures::default(), "gestures are used once");

    let reset = toggles.act(Action::Reset, &mut controls, &mut refiner, true);
    assert_eq!(reset, Effect::CutChanged);
    assert_eq!(controls.eye(), start);

    // A stalled frame moves no further than a quarter-second one.
    let step = |dt: f64| {
        let mut c = controls.clone();
        let mut k = HeldKeys::default();
        k.set("KeyW", true);
        Gestures::default().apply(&mut c, &mut k, 480, dt);
        (c.eye() - start).length()
    };
    assert!(step(0.1) > 0.0);
    assert_eq!(step(5.0), step(0.25));
}
