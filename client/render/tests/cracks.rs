//! No cracks: cuts that mix levels as much as the DAG allows, drawn over a background colour the
//! terrain shader cannot produce, show no background inside the terrain's footprint — from
//! above and at grazing angles.
//!
//! The footprint is computed independently of the renderer: a pixel's ray that enters the slab
//! `min ≤ z ≤ max` of the drawn heights inside the data rectangle and leaves it through the bottom
//! still inside the rectangle must cross the surface there (the surface is continuous over the
//! rectangle, between those heights, and seen from above), unless the surface has a hole. Back
//! faces are culled, so a ray through a hole reaches the background instead of the underside.

use crate::util::*;
use cbdam_client::camera::Camera;
use cbdam_client::patch::decode_cut;
use cbdam_client::world::World;
use cbdam_codec::geometry::Cut;
use cbdam_render::{Frame, RenderOptions};
use glam::DVec3;

const MAGENTA: [u8; 4] = [255, 0, 255, 255];

/// Pixels whose ray must hit the terrain: enters z = hi and reaches z = lo both inside the
/// data rectangle shrunk by `margin` lattice units (pixel centres exactly on the edge may go
/// either way).
fn footprint(world: &World, cam: &Camera, lo: f64, hi: f64) -> Vec<bool> {
    let margin = 0.5;
    let (xmax, ymax) = (
        f64::from(world.domain.data().width - 1) - margin,
        f64::from(world.domain.data().height - 1) - margin,
    );
    let inside = |p: DVec3| {
        let (x, y) = world.lattice_of(p);
        x >= margin && y >= margin && x <= xmax && y <= ymax
    };
    let mut out = Vec::with_capacity((cam.width * cam.height) as usize);
    for y in 0..cam.height {
        for x in 0..cam.width {
            let (o, d) = pixel_ray(cam, x, y);
            // The eye is above the data in every view here; rays going up miss.
            let hit = d.z < 0.0 && o.z > hi && {
                let at = |z: f64| o + d * ((z - o.z) / d.z);
                inside(at(hi)) && inside(at(lo))
            };
            out.push(hit);
        }
    }
    out
}

fn check(name: &str, frame: &Frame, must: &[bool]) {
    let total = must.iter().filter(|&&m| m).count();
    let holes: Vec<(u32, u32)> = (0..frame.height)
        .flat_map(|y| (0..frame.width).map(move |x| (x, y)))
        .filter(|&(x, y)| must[(y * frame.width + x) as usize] && frame.pixel(x, y) == MAGENTA)
        .collect();
    if !holes.is_empty() {
        let path = save(&format!("crack-{name}.png"), &frame.to_png().unwrap());
        panic!(
            "{name}: {} of {total} footprint pixels show the background, first at {:?} \
             (image: {})",
            holes.len(),
            &holes[..holes.len().min(8)],
            path.display()
        );
    }
    // The test must be able to fail: the footprint covers a good part of the image.
    let share = total as f64 / must.len() as f64;
    assert!(
        share > 0.15,
        "{name}: footprint only {share:.2} of the image"
    );
}

fn views(world: &World) -> Vec<(&'static str, Camera)> {
    let size = (192, 144);
    let (lo, hi) = world.bounds();
    let centre = (lo + hi) * 0.5;
    let span = (hi - lo).x.max((hi - lo).y);
    let top = camera(
        world,
        DVec3::new(centre.x, centre.y, hi.z + span * 0.9),
        DVec3::new(centre.x, centre.y, lo.z),
        size,
    );
    let mut v = vec![("top", top)];
    // Grazing: eye a little above the highest point, looking down 12° to 20° so that the top
    // of the view still meets the ground inside the data.
    for (name, az, pitch) in [
        ("graze-south", 0.0f64, 14.0f64),
        ("graze-east", 90.0, 12.0),
        ("graze-nw", 225.0, 20.0),
    ] {
        let a = az.to_radians();
        let back = DVec3::new(a.sin(), -a.cos(), 0.0);
        let eye = DVec3::new(centre.x, centre.y, hi.z + (hi.z - lo.z) * 0.15) + back * span * 0.3;
        let dir = -back * pitch.to_radians().cos() - DVec3::Z * pitch.to_radians().sin();
        v.push((name, camera(world, eye, eye + dir * span, size)));
    }
    v
}

fn cuts(repo: &cbdam_codec::repository::Repository) -> Vec<(String, Cut)> {
    let n = repo.head().entries().len();
    let mut out = vec![
        ("coarsest".to_string(), Cut::new()),
        ("full".to_string(), full_resolution_cut(repo)),
    ];
    for (k, count) in [n / 60, n / 20, n / 6].into_iter().enumerate() {
        out.push((format!("random{k}"), random_cut(repo, count, 17 + k as u64)));
    }
    out
}

#[test]
fn mixed_level_cuts_have_no_cracks() {
    no_cracks(jacksboro());
}

/// The same with the α = ½ lifting weight: the vertices patches share are the same decoded
/// values whatever the filter, so its cuts must be as closed.
#[test]
fn mixed_level_cuts_of_an_alpha_half_repository_have_no_cracks() {
    let repo = jacksboro_half();
    assert_eq!(
        repo.head().params().alpha,
        cbdam_codec::lifting::Alpha::Half
    );
    no_cracks(repo);
}

fn no_cracks(repo: &std::sync::Arc<cbdam_codec::repository::Repository>) {
    let world = World::of_repository(repo);
    let domain = repo.head().params().domain;
    let layout = *domain.layout();
    let mut renderer = renderer(repo);
    let options = RenderOptions {
        background: [1.0, 0.0, 1.0, 1.0],
        ..RenderOptions::default()
    };
    let views = views(&world);
    for (cut_name, cut) in cuts(repo) {
        let patches = decode_cut(repo, &cut).unwrap();
        let levels: std::collections::BTreeSet<u8> = patches.iter().map(|p| p.id.level).collect();
        if cut_name.starts_with("random") {
            assert!(levels.len() >= 4, "{cut_name} mixes only levels {levels:?}");
        }
        let (lo, hi) = height_range(&world, &patches);
        for (view_name, cam) in &views {
            let frame = renderer.render(cam, &patches, &options).unwrap();
            assert_eq!(frame.stats.missing, 0);
            let must = footprint(&world, cam, lo, hi);
            check(&format!("{cut_name}-{view_name}"), &frame, &must);
        }
        eprintln!(
            "{cut_name}: {} patches, levels {levels:?}, {} refined",
            patches.len(),
            cut.refined().count()
        );
        let _ = layout;
    }
}

/// The check itself catches a hole: dropping one patch from the middle of a full-resolution
/// top view leaves background pixels in the footprint.
#[test]
fn a_missing_patch_is_detected() {
    let repo = jacksboro();
    let world = World::of_repository(repo);
    let mut renderer = renderer(repo);
    let options = RenderOptions {
        background: [1.0, 0.0, 1.0, 1.0],
        ..RenderOptions::default()
    };
    let cut = full_resolution_cut(repo);
    let mut patches = decode_cut(repo, &cut).unwrap();
    let (lo, hi) = height_range(&world, &patches);
    let (_, cam) = views(&world).into_iter().next().unwrap();
    // Drop the patch nearest the data's centre.
    let centre = (
        f64::from(world.domain.data().width) / 2.0,
        f64::from(world.domain.data().height) / 2.0,
    );
    let k = (0..patches.len())
        .min_by_key(|&k| {
            let id = patches[k].id;
            ((f64::from(id.x) - centre.0).powi(2) + (f64::from(id.y) - centre.1).powi(2)) as i64
        })
        .unwrap();
    patches.remove(k);
    let frame = renderer.render(&cam, &patches, &options).unwrap();
    let must = footprint(&world, &cam, lo, hi);
    let holes = (0..frame.height)
        .flat_map(|y| (0..frame.width).map(move |x| (x, y)))
        .filter(|&(x, y)| must[(y * frame.width + x) as usize] && frame.pixel(x, y) == MAGENTA)
        .count();
    assert!(holes > 0, "a removed patch went unnoticed");
}
