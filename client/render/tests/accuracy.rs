//! Accuracy: the surface an adaptive cut draws stays within the pixel-error target of the
//! full-resolution surface.
//!
//! For every terrain pixel of an adaptive frame, the depth buffer gives the world point `P` the
//! GPU drew there. The full-resolution surface (the decoded finest level, triangulated exactly
//! as the finest diamonds are drawn) is evaluated at `P`'s lattice position on the CPU, and the
//! vertical distance is converted to pixels with the same metric the refinement uses:
//! `Δz · pixels_per_metre(|P − eye|)`.
//!
//! Why the bound holds, and the slack it needs:
//! - The drawn half of diamond `K` was left unrefined because `object_error(K)·unit·ppm(distance
//!   to K's box) ≤ target` (or `K` is outside the frustum, or at the finest level). `P` lies in
//!   `K`'s box, so `ppm(|P − eye|)` is at most the box's.
//! - The object error bounds `|surface − input|`; the finest level is itself within the
//!   repository's bound `k` of the input, so against the finest level the bound is
//!   `target + k·unit·ppm`.
//! - Depth is read back as `f32`: we add the on-screen size of the world-space change that ±4
//!   ulp-scale steps (4·10⁻⁷) of depth make at that pixel.
//! - Between lattice points the two piecewise-linear surfaces differ by at most the differences
//!   at the lattice points around, except where a coarse edge crosses a fine cell (the coarse
//!   surface has a crease there, the fine one not); 0.05 px covers that.

use crate::util::*;
use cbdam_client::camera::Camera;
use cbdam_client::patch::decode_cut;
use cbdam_client::world::World;
use cbdam_codec::geometry::{Cut, Diagonal, DiamondId, Layout};
use cbdam_codec::hierarchy::reconstruct_finest;
use cbdam_codec::repository::Repository;
use cbdam_render::RenderOptions;

/// The decoded finest level as a surface.
struct Finest {
    layout: Layout,
    w: usize,
    h: usize,
    heights: Vec<i32>,
}

impl Finest {
    fn new(repo: &Repository) -> Self {
        let p = repo.head().params();
        Self {
            layout: *p.layout(),
            w: p.domain.data().width as usize,
            h: p.domain.data().height as usize,
            heights: reconstruct_finest(&repo.to_encoded().unwrap()).unwrap(),
        }
    }

    fn at(&self, x: usize, y: usize) -> f64 {
        f64::from(self.heights[y * self.w + x])
    }

    /// Height units at lattice position `(x, y)`, cells split like the finest diamond's.
    fn height(&self, x: f64, y: f64) -> Option<f64> {
        if !(0.0..=(self.w - 1) as f64).contains(&x) || !(0.0..=(self.h - 1) as f64).contains(&y) {
            return None;
        }
        let cx = (x.floor() as usize).min(self.w - 2);
        let cy = (y.floor() as usize).min(self.h - 2);
        let (fx, fy) = (x - cx as f64, y - cy as f64);
        let r = self.layout.radius(self.layout.finest_level()) as usize;
        let id = DiamondId::new(
            self.layout.finest_level(),
            ((2 * (cx / (2 * r)) + 1) * r) as u32,
            ((2 * (cy / (2 * r)) + 1) * r) as u32,
        );
        let (h00, h10, h01, h11) = (
            self.at(cx, cy),
            self.at(cx + 1, cy),
            self.at(cx, cy + 1),
            self.at(cx + 1, cy + 1),
        );
        Some(match self.layout.diagonal(id) {
            Diagonal::Main if fx >= fy => h00 + fx * (h10 - h00) + fy * (h11 - h10),
            Diagonal::Main => h00 + fy * (h01 - h00) + fx * (h11 - h01),
            Diagonal::Anti if fx + fy <= 1.0 => h00 + fx * (h10 - h00) + fy * (h01 - h00),
            Diagonal::Anti => h11 + (1.0 - fx) * (h01 - h11) + (1.0 - fy) * (h10 - h11),
        })
    }
}

/// Largest `(error − allowed)` in pixels over the frame, and the largest error, for `cut`.
fn worst_excess(
    repo: &Repository,
    finest: &Finest,
    cam: &Camera,
    cut: &Cut,
    target: f64,
) -> (f64, f64, usize) {
    let world = World::of_repository(repo);
    let mut renderer = renderer(repo);
    let patches = decode_cut(repo, cut).unwrap();
    let frame = renderer
        .render(
            cam,
            &patches,
            &RenderOptions {
                read_depth: true,
                ..RenderOptions::default()
            },
        )
        .unwrap();
    let depth = frame.depth.as_ref().unwrap();
    let k_metres = f64::from(repo.head().params().quantizer.k()) * world.unit;
    let (mut excess, mut worst, mut counted) = (f64::NEG_INFINITY, 0f64, 0);
    for y in 0..cam.height {
        for x in 0..cam.width {
            let d = f64::from(depth[(y * cam.width + x) as usize]);
            if d >= 1.0 {
                continue;
            }
            let p = unproject(cam, x, y, d);
            let (fx, fy) = world.lattice_of(p);
            let Some(h) = finest.height(fx, fy) else {
                continue;
            };
            let ppm = cam.pixels_per_metre((p - cam.eye).length());
            let err = (p.z - world.height(0) - h * world.unit).abs() * ppm;
            let wobble =
                (unproject(cam, x, y, d + 4e-7) - unproject(cam, x, y, d - 4e-7)).length() * ppm;
            let allowed = target + k_metres * ppm + wobble + 0.05;
            excess = excess.max(err - allowed);
            worst = worst.max(err);
            counted += 1;
        }
    }
    (excess, worst, counted)
}

#[test]
fn adaptive_cuts_stay_within_the_pixel_error() {
    within_the_pixel_error(jacksboro());
}

/// The same with the α = ½ lifting weight, whose object errors come from its own filter.
#[test]
fn adaptive_cuts_of_an_alpha_half_repository_stay_within_the_pixel_error() {
    let repo = jacksboro_half();
    assert_eq!(
        repo.head().params().alpha,
        cbdam_codec::lifting::Alpha::Half
    );
    within_the_pixel_error(repo);
}

fn within_the_pixel_error(repo: &std::sync::Arc<cbdam_codec::repository::Repository>) {
    let world = World::of_repository(repo);
    let finest = Finest::new(repo);
    let size = (240, 160);
    let (lo, hi) = world.bounds();
    let span = (hi - lo).x.max((hi - lo).y);
    let full = full_resolution_cut(repo).refined().count();
    for (name, cam) in [
        ("overview", Camera::overview(&world, size)),
        ("oblique", orbit(&world, 30.0, 20.0, span * 0.6, size)),
        ("low", orbit(&world, 200.0, 9.0, span * 0.45, size)),
    ] {
        for target in [0.5, 1.0, 4.0] {
            let (cut, _) = refined_cut(repo, &cam, target);
            let (excess, worst, counted) = worst_excess(repo, &finest, &cam, &cut, target);
            eprintln!(
                "{name} target {target}: {} of {full} refined, worst {worst:.3} px, excess \
                 {excess:.3} px over {counted} pixels",
                cut.refined().count()
            );
            assert!(
                counted > (size.0 * size.1 / 8) as usize,
                "{name}: {counted}"
            );
            assert!(
                excess <= 0.0,
                "{name} target {target}: error exceeds the bound by {excess} px"
            );
            // Adaptive: coarser than the full resolution.
            assert!(cut.refined().count() < full, "{name} refined everything");
        }
    }
}

/// The measurement has teeth: the coarsest cut, drawn where the target asks for refinement,
/// exceeds the bound.
#[test]
fn the_coarsest_cut_fails_the_bound() {
    let repo = jacksboro();
    let world = World::of_repository(repo);
    let finest = Finest::new(repo);
    let cam = Camera::overview(&world, (240, 160));
    let (excess, worst, _) = worst_excess(repo, &finest, &cam, &Cut::new(), 1.0);
    assert!(
        excess > 0.5,
        "coarsest cut: worst {worst} px, excess {excess}"
    );
}
