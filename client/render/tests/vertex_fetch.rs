//! The texture path of the terrain shader (WebGL2's: the patches as instance-stepped vertex
//! attributes, the height pool in an `R32Sint` texture read with `textureLoad`), forced on the
//! test device, draws exactly the storage-buffer path's image and depth: the shader's maths are
//! one source and both paths read the same exact words (integers and `f32` bits), so nothing
//! may differ — not one pixel, not one bit of depth. Heights, nodata marks, draped colours and
//! planet positions are all read through the pool; a small pool makes slots start mid-row of
//! the texture and spread over rows, and evictions rewrite them across several views.

use std::sync::Arc;

use crate::util::*;
use cbdam_client::camera::Camera;
use cbdam_client::patch::{HalfPatch, pack_rgb};
use cbdam_client::world::World;
use cbdam_codec::repository::Repository;
use cbdam_render::{CacheConfig, Colouring, Frame, RenderOptions, Renderer, VertexFetch};

fn renderers(
    repo: &Repository,
    draped: bool,
    pool_bytes: Option<u64>,
) -> [(VertexFetch, Renderer); 2] {
    [VertexFetch::StorageBuffers, VertexFetch::Texture].map(|fetch| {
        let config = CacheConfig {
            pool_bytes,
            vertex_fetch: fetch,
            ..CacheConfig::default()
        };
        let r = Renderer::with_colour(
            gpu(),
            World::of_repository(repo),
            config,
            Colouring::draped_if(draped),
        )
        .unwrap();
        assert_eq!(r.vertex_fetch(), fetch);
        (fetch, r)
    })
}

/// Renders `patches` from `cam` with both renderers; asserts identical colour and depth.
fn same_image(
    name: &str,
    renderers: &mut [(VertexFetch, Renderer); 2],
    cam: &Camera,
    patches: &[Arc<HalfPatch>],
    options: &RenderOptions,
) -> Frame {
    let options = RenderOptions {
        read_depth: true,
        ..*options
    };
    let [(_, storage), (_, texture)] = renderers;
    let a = storage.render(cam, patches, &options).unwrap();
    let b = texture.render(cam, patches, &options).unwrap();
    assert_eq!(a.stats.drawn, b.stats.drawn, "{name}");
    assert!(a.stats.drawn > 0, "{name}: nothing drawn");
    let differing = a
        .rgba
        .chunks(4)
        .zip(b.rgba.chunks(4))
        .filter(|(x, y)| x != y)
        .count();
    if differing > 0 {
        save(&format!("fetch-{name}-storage.png"), &a.to_png().unwrap());
        let out = save(&format!("fetch-{name}-texture.png"), &b.to_png().unwrap());
        panic!(
            "{name}: {differing} of {} pixels differ between the paths (texture path: {})",
            a.rgba.len() / 4,
            out.display()
        );
    }
    let (da, db) = (a.depth.as_ref().unwrap(), b.depth.as_ref().unwrap());
    let depth_differs = da
        .iter()
        .zip(db)
        .filter(|(x, y)| x.to_bits() != y.to_bits())
        .count();
    assert_eq!(
        depth_differs, 0,
        "{name}: depth differs at {depth_differs} pixels"
    );
    a
}

/// Jacksboro from several views, shaded, by level and with the wireframe where the adapter
/// has one, through a pool of 300 slots (the first view's cut needs more than that: slots are
/// evicted and rewritten from view to view).
#[test]
fn texture_path_draws_the_storage_path_image() {
    let repo = jacksboro();
    let world = World::of_repository(repo);
    let (lo, hi) = world.bounds();
    let span = (hi - lo).x.max((hi - lo).y);
    let n = repo.head().params().layout().n() as u64;
    let mut both = renderers(repo, false, Some(300 * n * n * 4));
    let wire = gpu()
        .device
        .features()
        .contains(wgpu::Features::POLYGON_MODE_LINE);
    let views = [
        (0.0, 40.0, 0.8, 1.0),
        (220.0, 18.0, 0.55, 0.5),
        (90.0, 60.0, 0.4, 2.0),
    ];
    for (k, &(azimuth, elevation, distance, pixel_error)) in views.iter().enumerate() {
        let cam = orbit(&world, azimuth, elevation, span * distance, (240, 160));
        let (_, patches) = refined_cut(repo, &cam, pixel_error);
        let frame = same_image(
            &format!("view{k}"),
            &mut both,
            &cam,
            &patches,
            &RenderOptions::default(),
        );
        if k == 0 {
            // The pool is too small for this cut: what is missing is not drawn, by both.
            assert!(
                frame.stats.missing > 0 || patches.len() <= 300,
                "{:?}",
                frame.stats
            );
        }
        let levels = RenderOptions {
            level_colours: true,
            wireframe: wire,
            ..RenderOptions::default()
        };
        same_image(&format!("levels{k}"), &mut both, &cam, &patches, &levels);
    }
}

/// Nodata marks and draped colours are words of the pool too: patches given a pattern of
/// invalid points and of colours (both functions of the grid position) draw the same.
#[test]
fn texture_path_reads_nodata_marks_and_draped_colours() {
    let repo = jacksboro();
    let world = World::of_repository(repo);
    let (lo, hi) = world.bounds();
    let span = (hi - lo).x.max((hi - lo).y);
    let cam = orbit(&world, 30.0, 50.0, span * 0.7, (240, 160));
    let (_, patches) = refined_cut(repo, &cam, 1.0);
    let n = repo.head().params().layout().n();
    let marked: Vec<Arc<HalfPatch>> = patches
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let mut p = (**p).clone();
            p.valid = Some((0..n * n).map(|i| (i * 7 + k) % 23 != 0).collect());
            p.colour = Some(
                (0..n * n)
                    .map(|i| pack_rgb([(i * 5) as u8, (k * 11) as u8, (i / n * 9) as u8]))
                    .collect(),
            );
            Arc::new(p)
        })
        .collect();
    let mut both = renderers(repo, true, None);
    let frame = same_image(
        "draped",
        &mut both,
        &cam,
        &marked,
        &RenderOptions::default(),
    );
    // The marks were read: the holes show more background than the unmarked patches do (on a
    // fresh renderer: the cache keys patches by id, and the marked ones are resident).
    let [(_, mut fresh), _] = renderers(repo, true, None);
    let unmarked = fresh
        .render(&cam, &patches, &RenderOptions::default())
        .unwrap();
    let sky = |f: &Frame| {
        f.rgba
            .chunks(4)
            .filter(|p| *p == [158, 189, 219, 255])
            .count()
    };
    assert!(
        sky(&frame) > sky(&unmarked) + 100,
        "{} background pixels with holes, {} without",
        sky(&frame),
        sky(&unmarked)
    );
}

/// A planet: each slot holds 6 N² position words after the heights (f32 bits).
#[test]
fn texture_path_draws_the_planet() {
    let repo = crate::planet::planet();
    let world = World::of_repository(repo);
    let cam = Camera::framed(&world, (200, 150));
    let (_, patches) = refined_cut(repo, &cam, 1.0);
    let mut both = renderers(repo, false, None);
    same_image(
        "planet",
        &mut both,
        &cam,
        &patches,
        &RenderOptions::default(),
    );
}
