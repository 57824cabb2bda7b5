//! The GPU patch cache under pressure: with a pool too small for the cut, or an upload budget
//! too small for a frame, the frame draws fewer patches and says so — but every pixel it does
//! draw is the right terrain: never a wrong or stale patch.
//!
//! "Right" is checked against a renderer with an ample pool drawing the same cut: a drawn pixel
//! may lie *behind* the reference surface (a missing patch uncovers terrain further away) but
//! never in front of it, and where it is the same surface (same depth) it has the same colour.
//! A slot holding another patch's heights, or heights left from an earlier frame, puts
//! surface in front of the reference or changes colours.

use crate::util::*;
use cbdam_client::camera::Camera;
use cbdam_client::patch::HalfPatch;
use cbdam_client::world::World;
use cbdam_render::{CacheConfig, Frame, RenderOptions, Renderer};

fn options() -> RenderOptions {
    RenderOptions {
        read_depth: true,
        background: [1.0, 0.0, 1.0, 1.0],
        ..RenderOptions::default()
    }
}

/// Checks `frame` against `reference` pixel by pixel; returns how many terrain pixels it drew.
fn check_against(name: &str, frame: &Frame, reference: &Frame) -> usize {
    let (d, r) = (
        frame.depth.as_ref().unwrap(),
        reference.depth.as_ref().unwrap(),
    );
    let mut drawn = 0;
    for y in 0..frame.height {
        for x in 0..frame.width {
            let i = (y * frame.width + x) as usize;
            if d[i] >= 1.0 {
                continue;
            }
            drawn += 1;
            assert!(
                d[i] >= r[i] - 1e-6,
                "{name}: pixel ({x},{y}) at depth {} in front of the reference {}",
                d[i],
                r[i]
            );
            if (d[i] - r[i]).abs() <= 1e-7 {
                let (a, b) = (frame.pixel(x, y), reference.pixel(x, y));
                assert!(
                    a.iter().zip(b.iter()).all(|(p, q)| p.abs_diff(*q) <= 2),
                    "{name}: pixel ({x},{y}) {a:?} vs reference {b:?}"
                );
            }
        }
    }
    drawn
}

fn views(world: &World) -> Vec<Camera> {
    let (lo, hi) = world.bounds();
    let span = (hi - lo).x.max((hi - lo).y);
    let size = (160, 120);
    vec![
        Camera::overview(world, size),
        orbit(world, 60.0, 25.0, span * 0.5, size),
        orbit(world, 150.0, 15.0, span * 0.4, size),
        orbit(world, 300.0, 35.0, span * 0.35, size),
    ]
}

fn cut_patches(cam: &Camera) -> Vec<HalfPatch> {
    let (_, patches) = refined_cut(jacksboro(), cam, 0.5);
    patches.iter().map(|p| (**p).clone()).collect()
}

#[test]
fn a_pool_too_small_draws_fewer_patches_never_wrong_ones() {
    let repo = jacksboro();
    let world = World::of_repository(repo);
    let mut ample = renderer(repo);
    let n = repo.head().params().layout().n() as u64;
    let slot_bytes = n * n * 4;
    let views = views(&world);
    let first = cut_patches(&views[0]);
    // A third of the first view's patches fit.
    let slots = (first.len() as u64 / 3).max(4);
    let mut small = Renderer::new(
        gpu(),
        world,
        CacheConfig {
            pool_bytes: Some(slots * slot_bytes),
            ..CacheConfig::default()
        },
    )
    .unwrap();
    assert_eq!(u64::from(small.cache().capacity()), slots);
    // Several views in turn, twice: slots are evicted and reused with other patches.
    let mut degraded = 0;
    for round in 0..2 {
        for (v, cam) in views.iter().enumerate() {
            let patches = cut_patches(cam);
            let reference = ample.render(cam, &patches, &options()).unwrap();
            let frame = small.render(cam, &patches, &options()).unwrap();
            let name = format!("round {round} view {v}");
            let s = frame.stats;
            assert_eq!(
                s.drawn + s.culled + s.missing,
                patches.len(),
                "{name}: {s:?}"
            );
            assert!(s.drawn as u64 <= slots, "{name}: {s:?}");
            let drawn = check_against(&name, &frame, &reference);
            let full = check_against(&format!("{name} (reference)"), &reference, &reference);
            if s.missing > 0 {
                degraded += 1;
                assert!(
                    s.cache.no_slot > 0,
                    "{name}: missing but not reported {s:?}"
                );
                assert!(
                    drawn < full,
                    "{name}: {drawn} of {full} pixels despite {s:?}"
                );
            }
            eprintln!("{name}: {s:?}, {drawn} of {full} pixels");
        }
    }
    assert!(degraded >= 4, "the pool was not too small ({degraded})");
    let stats = small.cache_stats();
    assert!(stats.evictions > 0 && stats.hits > 0, "{stats:?}");
}

#[test]
fn an_upload_budget_converges_to_the_full_picture() {
    let repo = jacksboro();
    let world = World::of_repository(repo);
    let cam = &views(&world)[1];
    let patches = cut_patches(cam);
    let reference = renderer(repo).render(cam, &patches, &options()).unwrap();
    let n = repo.head().params().layout().n() as u64;
    let per_frame = 40;
    let mut r = Renderer::new(
        gpu(),
        world,
        CacheConfig {
            upload_budget: per_frame * n * n * 4,
            ..CacheConfig::default()
        },
    )
    .unwrap();
    let mut frames = 0;
    loop {
        let frame = r.render(cam, &patches, &options()).unwrap();
        frames += 1;
        let s = frame.stats;
        assert!(s.cache.uploads <= per_frame, "{s:?}");
        check_against(&format!("frame {frames}"), &frame, &reference);
        if s.missing == 0 {
            // Everything resident: the very same picture.
            assert_eq!(frame.rgba, reference.rgba, "converged frame differs");
            break;
        }
        assert!(s.cache.deferred > 0, "{s:?}");
        assert!(frames < 100, "never converged");
    }
    assert!(frames > 2, "the budget did not bind ({frames} frames)");
}
