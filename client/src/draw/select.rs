//! Interim cut selection for `cbdam render` and the renderer's tests, until the streaming
//! client's time-critical refinement loop (issue 5) replaces it. Kept apart on purpose: swap
//! [`screen_error_cut`] for that loop's cut and nothing else changes.

use std::collections::{HashMap, HashSet};

use cbdam_codec::geometry::{Cut, DiamondId};
use cbdam_codec::repository::Repository;
use cbdam_codec::repository::index::IndexEntry;
use glam::DVec3;

use crate::camera::Camera;
use crate::world::World;

/// Screen-space error in pixels of drawing diamond `e` unrefined: its object-space error in
/// metres, scaled by the pixels per metre at the nearest point of its bounding box.
pub fn screen_error(world: &World, camera: &Camera, e: &IndexEntry) -> f64 {
    let (lo, hi) = world.diamond_box(e.id, e.min, e.max);
    f64::from(e.object_error)
        * world.unit
        * camera.pixels_per_metre(distance_to_box(camera.eye, lo, hi))
}

/// The cut that refines, coarse to fine, every stored diamond whose box meets the view frustum
/// and whose [`screen_error`] exceeds `pixel_error` (with its parents, which the cut rule
/// needs). Decodes nothing: a synchronous stand-in for the streaming refinement loop.
pub fn screen_error_cut(
    repo: &Repository,
    world: &World,
    camera: &Camera,
    pixel_error: f64,
) -> Cut {
    let layout = repo.params().layout;
    let entries: HashMap<DiamondId, &IndexEntry> =
        repo.entries().iter().map(|e| (e.id, e)).collect();
    let frustum = camera.frustum();
    let mut cut = Cut::new();
    let mut stack: Vec<DiamondId> = layout.roots().collect();
    // A diamond is reached from both its parents, and may already be refined because a child
    // forced it: judge each one once, on its own error, whatever the cut holds.
    let mut seen = HashSet::new();
    while let Some(id) = stack.pop() {
        if !seen.insert(id) {
            continue;
        }
        let Some(e) = entries.get(&id) else { continue };
        let (lo, hi) = world.diamond_box(id, e.min, e.max);
        if !frustum.intersects_box(lo, hi) || screen_error(world, camera, e) <= pixel_error {
            continue;
        }
        cut.refine(&layout, id);
        stack.extend(layout.children(id).into_iter().flatten());
    }
    cut
}

/// The full-resolution cut: every stored diamond refined, so the finest level is drawn wherever
/// there is data. The reference that adaptive cuts are compared with.
pub fn full_resolution_cut(repo: &Repository) -> Cut {
    let layout = repo.params().layout;
    let mut cut = Cut::new();
    for e in repo.entries() {
        cut.refine(&layout, e.id);
    }
    cut
}

/// Distance from `eye` to the box `lo..hi` (0 inside).
pub fn distance_to_box(eye: DVec3, lo: DVec3, hi: DVec3) -> f64 {
    (eye.clamp(lo, hi) - eye).length()
}
