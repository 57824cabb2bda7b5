//! Nodata is not drawn, data is: full-resolution top views of a synthetic DEM with holes and of
//! the Rhine DEM (48 % nodata), read back with depth.
//!
//! - Every drawn pixel's surface point (unprojected from its depth) must lie in a lattice cell
//!   with at least three corners holding data: at full resolution every triangle is half a cell,
//!   and only triangles whose three corners have data may be drawn.
//! - Every sample whose eight neighbours all have data is surrounded by drawn triangles, and with
//!   cells at least two pixels wide the pixel it projects to must show terrain.
//!
//! The same checks on the same patches with their masks removed must fail: the test can tell.

use std::sync::Arc;

use crate::util::*;
use cbdam_client::camera::Camera;
use cbdam_client::patch::{HalfPatch, decode_cut};
use cbdam_client::world::World;
use cbdam_codec::hierarchy::reconstruct_finest;
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::Repository;
use cbdam_render::{Frame, RenderOptions};
use glam::{DVec3, DVec4};

const MAGENTA: [u8; 4] = [255, 0, 255, 255];

/// What the checks found: pixels drawn over nodata, samples with data not drawn, and how many
/// pixels and samples were checked.
#[derive(Debug, Default)]
struct Findings {
    drawn_over_nodata: Vec<(u32, u32)>,
    data_not_drawn: Vec<(usize, usize)>,
    drawn: usize,
    inner_samples: usize,
}

fn render(repo: &Repository, cam: &Camera, patches: &[HalfPatch]) -> Frame {
    let mut renderer = renderer(repo);
    let options = RenderOptions {
        background: [1.0, 0.0, 1.0, 1.0],
        read_depth: true,
        ..RenderOptions::default()
    };
    renderer.render(cam, patches, &options).unwrap()
}

fn project(cam: &Camera, p: DVec3) -> Option<(u32, u32)> {
    let c = cam.projection() * cam.view() * DVec4::new(p.x, p.y, p.z, 1.0);
    let (nx, ny) = (c.x / c.w, c.y / c.w);
    let px = (nx + 1.0) / 2.0 * f64::from(cam.width);
    let py = (1.0 - ny) / 2.0 * f64::from(cam.height);
    (px >= 0.0 && py >= 0.0 && px < f64::from(cam.width) && py < f64::from(cam.height))
        .then_some((px as u32, py as u32))
}

fn examine(repo: &Repository, valid: &[bool], cam: &Camera, patches: &[HalfPatch]) -> Findings {
    let world = World::of_repository(repo);
    let (w, h) = (
        world.domain.data().width as usize,
        world.domain.data().height as usize,
    );
    let ok = |x: i64, y: i64| {
        x >= 0 && y >= 0 && x < w as i64 && y < h as i64 && valid[y as usize * w + x as usize]
    };
    let frame = render(repo, cam, patches);
    let depth = frame.depth.as_ref().unwrap();
    let mut f = Findings::default();
    for y in 0..cam.height {
        for x in 0..cam.width {
            let d = f64::from(depth[(y * cam.width + x) as usize]);
            if d >= 1.0 {
                continue;
            }
            f.drawn += 1;
            let p = unproject(cam, x, y, d);
            let wobble = (unproject(cam, x, y, d + 4e-7) - unproject(cam, x, y, d - 4e-7)).length()
                / world.min_step();
            let tol = 0.02 + wobble;
            let (fx, fy) = world.lattice_of(p);
            // Some cell within the tolerance has three corners with data.
            let cells = |v: f64| (v - tol).floor() as i64..=(v + tol).floor() as i64;
            let fine = cells(fx).any(|cx| {
                cells(fy).any(|cy| {
                    let corners = [(cx, cy), (cx + 1, cy), (cx, cy + 1), (cx + 1, cy + 1)];
                    corners.iter().filter(|&&(a, b)| ok(a, b)).count() >= 3
                })
            });
            if !fine {
                f.drawn_over_nodata.push((x, y));
            }
        }
    }
    let heights = reconstruct_finest(&repo.to_encoded().unwrap()).unwrap();
    for y in 1..h as i64 - 1 {
        for x in 1..w as i64 - 1 {
            if !(-1..=1).all(|dy| (-1..=1).all(|dx| ok(x + dx, y + dy))) {
                continue;
            }
            let at = world.point(x, y, heights[y as usize * w + x as usize]);
            let Some((px, py)) = project(cam, at) else {
                continue;
            };
            f.inner_samples += 1;
            if frame.pixel(px, py) == MAGENTA {
                f.data_not_drawn.push((x as usize, y as usize));
            }
        }
    }
    f
}

/// A camera straight above lattice point `(cx, cy)` seeing about `span` samples across.
fn top_view(world: &World, cx: f64, cy: f64, span: f64, size: (u32, u32)) -> Camera {
    let (sx, sy) = world.lattice_vector(1, 1);
    let centre = DVec3::new(cx * sx, cy * sy, world.min_height);
    let across = span * sx;
    // 45° field of view: the ground `across` wide at distance `across / (2 tan 22.5°)`.
    let up = across / (2.0 * 22.5f64.to_radians().tan());
    let eye = DVec3::new(centre.x, centre.y, world.max_height + up);
    camera(world, eye, centre, size)
}

fn check(name: &str, repo: &Repository, valid: &[bool], cam: &Camera) {
    let cut = full_resolution_cut(repo);
    let patches = decode_cut(repo, &cut).unwrap();
    assert!(
        patches.iter().any(|p| p.valid.is_some()),
        "{name}: no patch carries a mask"
    );
    let f = examine(repo, valid, cam, &patches);
    eprintln!(
        "{name}: {} drawn pixels, {} inner samples checked",
        f.drawn, f.inner_samples
    );
    assert!(
        f.drawn_over_nodata.is_empty(),
        "{name}: {} pixels drawn over nodata, first {:?}",
        f.drawn_over_nodata.len(),
        &f.drawn_over_nodata[..f.drawn_over_nodata.len().min(8)]
    );
    assert!(
        f.data_not_drawn.is_empty(),
        "{name}: {} samples with data not drawn, first {:?}",
        f.data_not_drawn.len(),
        &f.data_not_drawn[..f.data_not_drawn.len().min(8)]
    );
    assert!(f.drawn > 10_000 && f.inner_samples > 1_000, "{name}: {f:?}");
    // Without the masks the same patches draw invented surface over the holes.
    let unmasked: Vec<HalfPatch> = patches
        .iter()
        .map(|p| HalfPatch {
            valid: None,
            ..p.clone()
        })
        .collect();
    let g = examine(repo, valid, cam, &unmasked);
    assert!(
        g.drawn_over_nodata.len() > 100,
        "{name}: the check misses unmasked nodata ({} pixels)",
        g.drawn_over_nodata.len()
    );
}

#[test]
fn synthetic_holes_are_not_drawn_and_data_is() {
    let (repo, valid) = holed();
    let world = World::of_repository(repo);
    let (w, h) = (
        f64::from(world.domain.data().width),
        f64::from(world.domain.data().height),
    );
    // 129 samples across 400 pixels: cells of about 3 pixels.
    let cam = top_view(
        &world,
        (w - 1.0) / 2.0,
        (h - 1.0) / 2.0,
        w * 0.95,
        (400, 360),
    );
    check("holed", repo, valid, &cam);
}

#[test]
fn rhine_nodata_is_not_drawn_and_data_is() {
    let dem = cbdam_builder::input::read_dem(
        &data("rhine_nodata.tif"),
        &cbdam_builder::input::ReadOptions::default(),
    )
    .unwrap();
    let plan = QuantPlan::for_dem(&dem, 1.0, None).unwrap();
    let valid = HeightGrid::from_dem(&dem, &plan).unwrap().valid;
    let repo = Arc::new(repository("rhine_nodata.tif", 1.0, 65));
    let world = World::of_repository(&repo);
    let w = dem.width;
    // The 120 × 100 window whose nodata share is nearest one half: the most boundary to check.
    let share = |x0: usize, y0: usize| {
        let mut bad = 0;
        for y in y0..y0 + 100 {
            for x in x0..x0 + 120 {
                bad += usize::from(!valid[y * w + x]);
            }
        }
        (bad as f64 / 12_000.0 - 0.5).abs()
    };
    let (x0, y0) = (0..dem.width - 120)
        .step_by(40)
        .flat_map(|x| (0..dem.height - 100).step_by(40).map(move |y| (x, y)))
        .min_by(|a, b| share(a.0, a.1).total_cmp(&share(b.0, b.1)))
        .unwrap();
    let cam = top_view(
        &world,
        x0 as f64 + 60.0,
        y0 as f64 + 50.0,
        100.0,
        (400, 340),
    );
    check("rhine", &repo, &valid, &cam);
}
