//! Colour repositories draped over the terrain: the decoded patches carry the colour image's
//! colours at their grid points (same, finer and coarser colour hierarchies), the renderer
//! lights those colours instead of the height ramp, the refinement (and so what is fetched) is
//! the elevation's alone, and a remote pair served by `cbdam serve` gives the very same patches.

use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::util::*;
use cbdam_client::access::{
    ColouredSource, DataSource, FlakyConfig, FlakySource, LocalSource, RemoteSource,
};
use cbdam_client::camera::Camera;
use cbdam_client::fetch::FetchOptions;
use cbdam_client::patch::{HalfPatch, unpack_rgb};
use cbdam_client::refine::{HeadBytes, RefineConfig, Refiner, WorkerDecoder};
use cbdam_client::spawn::{Portable, Spawner};
use cbdam_client::world::World;
use cbdam_codec::colour::{RgbImage, encode_colour, ycocg};
use cbdam_codec::geometry::Layout;
use cbdam_codec::hierarchy::{EncodeOptions, Encoder};
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::{Repository, serialize};
use cbdam_render::{CacheConfig, Colouring, Frame, RenderOptions, Renderer};
use glam::DVec3;

const N: usize = 17;
/// Elevation samples; the colour images are `(W − 1)·2^m + 1` wide for a whole `m`.
const W: usize = 129;
const H: usize = 97;

/// An elevation repository of `metres(x, y)` on the `W × H` grid.
fn elevation(metres: impl Fn(f64, f64) -> f64) -> Arc<Repository> {
    let m: Vec<f64> = (0..W * H)
        .map(|i| metres((i % W) as f64, (i / W) as f64))
        .collect();
    let (lo, hi) = m
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    let plan = QuantPlan::new(0.25, None, lo - 1.0, hi + 1.0).unwrap();
    let grid = HeightGrid::from_metres(W, H, &m, None, &plan).unwrap();
    let opts = EncodeOptions {
        n: N,
        ..EncodeOptions::default()
    };
    let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
    Arc::new(Repository::from_bytes(serialize(&enc, &plan, None, None).unwrap()).unwrap())
}

/// A colour repository of `rgb(x, y)` (in elevation sample coordinates) sampled `2^shift`
/// times as densely as the elevation, laid over `like` as `cbdam build --colour --like` lays
/// it (the level pairs chosen so that the two hierarchies share their roots).
fn colour(
    like: &Repository,
    shift: i32,
    max_error: u32,
    rgb: impl Fn(f64, f64) -> [u8; 3],
) -> Arc<Repository> {
    let scale = 2f64.powi(shift);
    let size = |s: usize| ((s - 1) as f64 * scale) as usize + 1;
    let (w, h) = (size(W), size(H));
    let pixels = (0..w * h)
        .map(|i| rgb((i % w) as f64 / scale, (i / w) as f64 / scale))
        .collect();
    let img = RgbImage {
        width: w,
        height: h,
        pixels,
        georef: None,
    };
    let base = Layout::covering(N, w, h, 0).unwrap();
    let k = like.head().params().layout().k() as i32 + shift;
    let opts = EncodeOptions {
        n: N,
        extra_level_pairs: (k - base.k() as i32) as u32,
        ..EncodeOptions::default()
    };
    let (enc, plan) = encode_colour(&img, max_error, &opts, &|_, _| {}).unwrap();
    Arc::new(Repository::from_bytes(serialize(&enc, &plan, None, None).unwrap()).unwrap())
}

/// Four flat colours, one per quadrant of the elevation grid.
const QUADRANTS: [[u8; 3]; 4] = [[210, 40, 30], [30, 170, 60], [40, 70, 220], [230, 200, 40]];

fn quadrant(x: f64, y: f64) -> usize {
    usize::from(x >= (W / 2) as f64) + 2 * usize::from(y >= (H / 2) as f64)
}

fn quadrants(x: f64, y: f64) -> [u8; 3] {
    QUADRANTS[quadrant(x, y)]
}

/// A linear colour ramp, well inside 0–255 so that nothing clamps.
fn ramp(x: f64, y: f64) -> [f64; 3] {
    let (u, v) = (x / (W - 1) as f64, y / (H - 1) as f64);
    [
        30.0 + 190.0 * u,
        40.0 + 170.0 * v,
        200.0 - 120.0 * u * 0.5 - 60.0 * v,
    ]
}

fn ramp_u8(x: f64, y: f64) -> [u8; 3] {
    ramp(x, y).map(|c| c.round() as u8)
}

fn keys<S: DataSource, X: Spawner>(r: &Refiner<S, X>) -> Vec<cbdam_client::patch::PatchKey> {
    r.drawn().map(|p| p.key()).collect()
}

fn owned<S: DataSource, X: Spawner>(r: &Refiner<S, X>) -> Vec<HalfPatch> {
    r.drawn().map(|p| (**p).clone()).collect()
}

fn config() -> RefineConfig {
    RefineConfig {
        budget: None,
        ..RefineConfig::default()
    }
}

fn paired(e: &Arc<Repository>, c: &Arc<Repository>) -> ColouredSource<LocalSource, LocalSource> {
    ColouredSource::new(LocalSource::new(e.clone()), LocalSource::new(c.clone())).unwrap()
}

fn settle<S: DataSource>(source: S, cam: &Camera) -> Refiner<S> {
    let mut r = Refiner::new(source, config()).unwrap();
    assert!(r.settle(cam, 16).converged);
    r
}

/// A view from above, slightly tilted (a camera cannot look exactly down its up axis), that
/// refines to the finest level over much of the data.
fn above(world: &World, size: (u32, u32)) -> Camera {
    let (lo, hi) = world.bounds();
    let c = (lo + hi) * 0.5;
    let span = (hi - lo).x.max((hi - lo).y);
    camera(
        world,
        c + DVec3::new(0.0, -0.05 * span, 1.3 * span),
        c,
        size,
    )
}

/// Lattice position of grid point `(i, j)` of a patch.
fn lattice(layout: &Layout, p: &HalfPatch, i: usize, j: usize) -> (i64, i64) {
    let g = layout.grid(p.id);
    (
        g.origin.0 + i as i64 * g.u.0 + j as i64 * g.v.0,
        g.origin.1 + i as i64 * g.u.1 + j as i64 * g.v.1,
    )
}

/// For every drawn point of every patch inside the data, the largest difference between its
/// colour and `expected` at its elevation-sample position; panics on a patch without colour.
fn worst_colour_error(
    refiner: &Refiner<impl DataSource>,
    expected: impl Fn(f64, f64) -> [f64; 3],
) -> (f64, usize) {
    let layout = *refiner.layout();
    let n = layout.n();
    let (mut worst, mut points) = (0f64, 0usize);
    for p in refiner.drawn() {
        let colour = p.colour.as_ref().expect("a draped patch has colour");
        for j in 0..n {
            for i in 0..n {
                if layout
                    .half_of_point(p.id, i, j)
                    .is_some_and(|h| h != p.half)
                {
                    continue;
                }
                let (x, y) = lattice(&layout, p, i, j);
                if x < 0 || y < 0 || x >= W as i64 || y >= H as i64 {
                    continue;
                }
                let got = unpack_rgb(colour[j * n + i]);
                let want = expected(x as f64, y as f64);
                for c in 0..3 {
                    worst = worst.max((f64::from(got[c]) - want[c]).abs());
                }
                points += 1;
            }
        }
    }
    (worst, points)
}

/// The drawn patches carry the colour image at their points: within the codec's RGB bound where
/// the colour hierarchy has the level (as dense as the elevation, or twice as dense), and close
/// to the linear ramp where a coarser colour is interpolated below its finest level.
#[test]
fn patches_carry_the_colour_image_at_their_points() {
    let e = elevation(|x, y| 300.0 + 40.0 * (x / 13.0).sin() * (y / 17.0).cos());
    let world = World::of_repository(&e);
    let cam = above(&world, (640, 480));
    let plain = settle(LocalSource::new(e.clone()), &cam);
    let max_error = 4;
    let bound = *ycocg::rgb_bound(ycocg::channel_k(max_error))
        .iter()
        .max()
        .unwrap();
    let exact = |x: f64, y: f64| ramp_u8(x, y).map(f64::from);
    for shift in [0, 1, -1] {
        let c = colour(&e, shift, max_error, ramp_u8);
        let r = settle(paired(&e, &c), &cam);
        // The colour does not steer refinement: the same cut as without it.
        assert_eq!(keys(&plain), keys(&r), "shift {shift}");
        let (worst, points) = if shift >= 0 {
            worst_colour_error(&r, exact)
        } else {
            // Below the colour's finest level the codec predicts from the colour parents (an
            // interpolating filter): exact on a linear ramp up to the image's rounding (½) and
            // the filters' integer rounding (a level or two).
            worst_colour_error(&r, ramp)
        };
        let allowed = if shift >= 0 {
            f64::from(bound)
        } else {
            f64::from(bound) + 3.0
        };
        eprintln!("shift {shift}: worst {worst} over {points} points (allowed {allowed})");
        assert!(points > 10_000, "shift {shift}: only {points} points");
        assert!(worst <= allowed, "shift {shift}: {worst} > {allowed}");
        // The colour records fetched are exactly those of the refined diamonds that the colour
        // hierarchy stores.
        let refined: Vec<_> = r.cut().refined().collect();
        let wanted = refined
            .iter()
            .filter(|&&id| r.source().colour_id(id).is_some())
            .count() as u64;
        assert_eq!(r.source().colour().stats().records_taken, wanted);
        if shift >= 0 {
            assert_eq!(wanted, refined.len() as u64);
        } else {
            assert!(wanted < refined.len() as u64);
        }
    }
    // And a test that can fail: the patches of another image are far off.
    let other = colour(&e, 0, max_error, |x, y| ramp_u8(W as f64 - 1.0 - x, y));
    let (worst, _) = worst_colour_error(&settle(paired(&e, &other), &cam), exact);
    assert!(worst > 100.0, "{worst}");
}

/// The pixel's world point (from the depth buffer) in elevation sample coordinates.
fn sample_of(world: &World, cam: &Camera, frame: &Frame, x: u32, y: u32) -> Option<(f64, f64)> {
    let d = frame.depth.as_ref().unwrap()[(y * frame.width + x) as usize];
    (d < 1.0).then(|| {
        let p = unproject(cam, x, y, f64::from(d));
        world.lattice_of(p)
    })
}

/// Rendered from above, each quadrant shows its own colour times the pixel's hillshade: the
/// pixel is `s × colour` for one scale `s` (fitted per pixel by least squares), and `s` varies
/// with the relief; without the colour the same pixels show the height ramp.
///
/// The terrain is rough so that the cut reaches the finest level everywhere in view: colour is
/// per vertex, so a coarse patch would blend the quadrants over its whole extent (the
/// elevation alone steers refinement). Tolerance: 6 levels per channel against `s × colour` —
/// the colour codec's bound (2 levels at `max_error` 2), 8-bit rounding of the shaded output
/// (½) and f32 shading; another quadrant's colour, swapped channels or the ramp's green are off
/// by tens of levels.
#[test]
fn rendered_colour_follows_the_image_and_differs_from_the_ramp() {
    let e = elevation(|x, y| {
        let h = ((x as u64 * 7919 + y as u64 * 104_729).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 58)
            as f64;
        250.0 + 0.05 * h + 4.0 * (x / 5.0).sin() * (y / 7.0).cos()
    });
    let c = colour(&e, 0, 2, quadrants);
    let world = World::of_repository(&e);
    let cam = above(&world, (320, 240));
    let draped = settle(paired(&e, &c), &cam);
    let plain = settle(LocalSource::new(e.clone()), &cam);
    let options = RenderOptions {
        read_depth: true,
        ..RenderOptions::default()
    };
    let mut coloured_renderer =
        Renderer::with_colour(gpu(), world, CacheConfig::default(), Colouring::Draped).unwrap();
    let mut plain_renderer = renderer(&e);
    assert_eq!(
        coloured_renderer.slot_bytes(),
        2 * plain_renderer.slot_bytes()
    );
    let patches: Vec<_> = draped.drawn().cloned().collect();
    let frame = coloured_renderer.render(&cam, &patches, &options).unwrap();
    let path = save("colour-quadrants.png", &frame.to_png().unwrap());
    let plain_patches: Vec<_> = plain.drawn().cloned().collect();
    let hypso = plain_renderer
        .render(&cam, &plain_patches, &options)
        .unwrap();
    save("colour-quadrants-plain.png", &hypso.to_png().unwrap());

    let mut checked = [0usize; 4];
    let (mut s_lo, mut s_hi) = (f64::MAX, f64::MIN);
    let mut ramp_fits = 0;
    for y in (4..frame.height).step_by(6) {
        for x in (4..frame.width).step_by(6) {
            let Some((sx, sy)) = sample_of(&world, &cam, &frame, x, y) else {
                continue;
            };
            // Away from the quadrants' borders (interpolation across them) and the data edge.
            let margin = 3.0;
            let near_border = (sx - (W / 2) as f64).abs() < margin
                || (sy - (H / 2) as f64).abs() < margin
                || sx < margin
                || sy < margin
                || sx > (W - 1) as f64 - margin
                || sy > (H - 1) as f64 - margin;
            if near_border {
                continue;
            }
            let q = quadrant(sx, sy);
            let got = frame.pixel(x, y);
            let (shade, off) = fit(QUADRANTS[q], got);
            // Between the ambient term and full sun.
            assert!(
                (0.3..=1.01).contains(&shade),
                "pixel {x},{y}: shade {shade}"
            );
            (s_lo, s_hi) = (s_lo.min(shade), s_hi.max(shade));
            assert!(
                off <= 6.0,
                "pixel {x},{y} (sample {sx:.1},{sy:.1}, quadrant {q}): {got:?} vs {shade:.3} × \
                 {:?} ({})",
                QUADRANTS[q],
                path.display()
            );
            checked[q] += 1;
            // The same check fails on the ramp's colours (the test can fail).
            if fit(QUADRANTS[q], hypso.pixel(x, y)).1 <= 6.0 {
                ramp_fits += 1;
            }
        }
    }
    assert!(checked.iter().all(|&c| c > 50), "{checked:?}");
    // Hillshade, not flat colour.
    assert!(s_hi - s_lo > 0.2, "shade only {s_lo:.3} … {s_hi:.3}");
    let total: usize = checked.iter().sum();
    assert!(
        ramp_fits * 100 < total,
        "{ramp_fits} of {total} ramp pixels fit"
    );

    // The level debug mode ignores the colour: the same image as without it.
    let levels = RenderOptions {
        level_colours: true,
        ..RenderOptions::default()
    };
    let a = coloured_renderer.render(&cam, &patches, &levels).unwrap();
    let b = plain_renderer
        .render(&cam, &plain_patches, &levels)
        .unwrap();
    assert_eq!(a.rgba, b.rgba);
    // The wireframe is drawn over the draped colour: darker, not replaced.
    if plain_renderer.gpu().device.features().contains(wgpu_line()) {
        let wire = RenderOptions {
            wireframe: true,
            ..RenderOptions::default()
        };
        let w = coloured_renderer.render(&cam, &patches, &wire).unwrap();
        let sum = |f: &Frame| f.rgba.iter().map(|&v| u64::from(v)).sum::<u64>();
        assert!(sum(&w) < sum(&frame), "the wireframe darkens the surface");
    }
}

/// The scale `s` fitting `pixel ≈ s × colour` best (least squares) and the largest channel
/// difference left, levels.
fn fit(colour: [u8; 3], pixel: [u8; 4]) -> (f64, f64) {
    let c = colour.map(f64::from);
    let p = [pixel[0], pixel[1], pixel[2]].map(f64::from);
    let s = (p[0] * c[0] + p[1] * c[1] + p[2] * c[2]) / (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
    let off = (0..3).map(|i| (p[i] - s * c[i]).abs()).fold(0.0, f64::max);
    (s, off)
}

fn wgpu_line() -> wgpu::Features {
    wgpu::Features::POLYGON_MODE_LINE
}

/// A colour repository that does not fit the elevation is refused at start-up with the reason.
#[test]
fn mismatched_colour_is_refused() {
    let e = elevation(|x, _| 100.0 + x);
    let c = colour(&e, 0, 2, quadrants);
    let refuse = |e: &Arc<Repository>, c: &Arc<Repository>| {
        ColouredSource::new(LocalSource::new(e.clone()), LocalSource::new(c.clone()))
            .unwrap_err()
            .to_string()
    };
    let msg = refuse(&e, &e);
    assert!(msg.contains("not a colour one"), "{msg}");
    let msg = refuse(&c, &c);
    assert!(msg.contains("is a colour repository"), "{msg}");
    // Another domain: an image that is not (W − 1)·2^m + 1 wide.
    let img = RgbImage {
        width: 100,
        height: 97,
        pixels: vec![[1, 2, 3]; 100 * 97],
        georef: None,
    };
    let opts = EncodeOptions {
        n: N,
        ..EncodeOptions::default()
    };
    let (enc, plan) = encode_colour(&img, 2, &opts, &|_, _| {}).unwrap();
    let other =
        Arc::new(Repository::from_bytes(serialize(&enc, &plan, None, None).unwrap()).unwrap());
    let msg = refuse(&e, &other);
    assert!(
        msg.contains("does not cover the elevation's domain"),
        "{msg}"
    );
}

/// The pair served by a real `cbdam serve` router on loopback converges to the very patches
/// (heights and colours) of the local pair; frames never wait for the network.
#[test]
fn remote_pair_gives_the_local_patches() {
    let e = elevation(|x, y| 300.0 + 40.0 * (x / 13.0).sin() * (y / 17.0).cos());
    let c = colour(&e, 1, 4, ramp_u8);
    let world = World::of_repository(&e);
    let cam = above(&world, (480, 360));
    let local = settle(paired(&e, &c), &cam);

    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap();
    let state = cbdam_server::AppState::new(
        vec![
            (
                "e".into(),
                Repository::from_bytes(e.as_bytes().to_vec()).unwrap(),
            ),
            (
                "c".into(),
                Repository::from_bytes(c.as_bytes().to_vec()).unwrap(),
            ),
        ],
        cbdam_server::Config::default(),
    )
    .unwrap();
    let app = cbdam_server::app(state);
    let listener = rt
        .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
        .unwrap();
    let addr = listener.local_addr().unwrap();
    rt.spawn(async move { axum::serve(listener, app).await.unwrap() });
    let connect = |name: &str| {
        RemoteSource::connect(
            &format!("http://{addr}/v1/repos/{name}"),
            FetchOptions::default(),
        )
        .unwrap()
    };
    let source = ColouredSource::new(connect("e"), connect("c")).unwrap();
    let mut remote = Refiner::new(
        source,
        RefineConfig {
            budget: Some(Duration::from_millis(2)),
            ..RefineConfig::default()
        },
    )
    .unwrap();
    let start = Instant::now();
    loop {
        let s = remote.frame(&cam);
        if s.converged && s.access.in_flight == 0 {
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(60), "{s:?}");
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(remote.errors().is_empty(), "{:?}", remote.errors());
    let (a, b) = (owned(&local), owned(&remote));
    assert!(a.iter().all(|p| p.colour.is_some()));
    assert_eq!(a.len(), b.len());
    assert!(a == b, "remote patches differ from the local ones");
    // Both repositories were fetched from: the colour's records travel too.
    let s = remote.source();
    assert!(s.elevation().stats().records_taken > 0);
    assert!(s.colour().stats().records_taken > 0);
}

/// Over two slow, lossy sources (each record arriving 1–6 frames late, at most 3 per frame,
/// some corrupt on their first attempt, independently for elevation and colour) the pair still
/// converges to the local pair's patches: a patch waits until both of its records are in, and a
/// rejected colour record fails (and retries) the patch like a rejected elevation one.
#[test]
fn flaky_pair_converges_to_the_local_patches() {
    let e = elevation(|x, y| 300.0 + 40.0 * (x / 13.0).sin() * (y / 17.0).cos());
    let c = colour(&e, 0, 4, ramp_u8);
    let world = World::of_repository(&e);
    let cam = above(&world, (480, 360));
    let local = settle(paired(&e, &c), &cam);
    let flaky = |r: &Arc<Repository>, corrupt_one_in| {
        FlakySource::new(
            r.clone(),
            FlakyConfig {
                latency: (1, 6),
                per_frame: 3,
                corrupt_one_in,
                ..FlakyConfig::default()
            },
        )
    };
    let source = ColouredSource::new(flaky(&e, 5), flaky(&c, 3)).unwrap();
    let mut r = Refiner::new(
        source,
        RefineConfig {
            budget: Some(Duration::from_millis(2)),
            max_failures: 10,
            ..RefineConfig::default()
        },
    )
    .unwrap();
    let mut frames = 0;
    while !(r.frame(&cam).converged && r.source().elevation().pending() == 0) {
        frames += 1;
        assert!(frames < 5000, "no convergence");
    }
    assert!(
        !r.source().colour().corrupted().is_empty(),
        "no colour record was corrupted: the test tests nothing"
    );
    assert!(
        r.errors().iter().any(|e| e.contains("its colour record")),
        "{:?}",
        r.errors()
    );
    assert!(
        owned(&r) == owned(&local),
        "flaky patches differ from the local ones"
    );
}

/// A spawner like the page's Web Workers: every decode job crosses to a [`WorkerDecoder`] as
/// bytes (the context message carrying both heads) and its answer comes back as bytes.
#[derive(Clone, Default)]
struct ThroughBytes {
    worker: std::rc::Rc<std::cell::RefCell<Option<WorkerDecoder>>>,
    answered: std::rc::Rc<std::cell::Cell<usize>>,
}

impl Spawner for ThroughBytes {
    fn sends_jobs_as_messages(&self) -> bool {
        true
    }
    fn spawn<F: FnOnce() + Send + 'static>(&self, job: F) {
        job();
    }
    fn spawn_job<J: Portable>(&self, job: J) {
        self.answered.set(self.answered.get() + job.steps());
        let answer = self.worker.borrow().as_ref().unwrap().run(&job.encode());
        job.receive(&answer.unwrap()).unwrap();
    }
    fn parallelism(&self) -> usize {
        2
    }
    fn runs_in_background(&self) -> bool {
        false
    }
}

fn head(repo: &Repository) -> HeadBytes<'_> {
    HeadBytes {
        bytes: repo.as_bytes(),
        file_len: repo.head().file_len(),
    }
}

/// A draped pair decoded by workers that share no memory with the refiner (the browser's):
/// the same cut and the very same patches, colours included, as decoding in place, for a
/// colour hierarchy as dense as the elevation, twice as dense and half as dense.
#[test]
fn a_draped_pair_decoded_through_bytes_gives_the_patches_decoded_in_place() {
    let e = elevation(|x, y| 300.0 + 40.0 * (x / 13.0).sin() * (y / 17.0).cos());
    let world = World::of_repository(&e);
    let cam = above(&world, (640, 480));
    for shift in [0, 1, -1] {
        let c = colour(&e, shift, 4, ramp_u8);
        let in_place = settle(paired(&e, &c), &cam);
        let spawner = ThroughBytes::default();
        let mut by_bytes =
            Refiner::with_spawner(paired(&e, &c), config(), spawner.clone()).unwrap();
        let context = by_bytes.worker_context(head(&e), Some(head(&c)));
        *spawner.worker.borrow_mut() = Some(WorkerDecoder::new(&context).unwrap());
        assert!(by_bytes.settle(&cam, 16).converged, "shift {shift}");
        assert!(
            spawner.answered.get() > 20,
            "shift {shift}: {} through bytes",
            spawner.answered.get()
        );
        assert_eq!(keys(&in_place), keys(&by_bytes), "shift {shift}");
        let (a, b) = (owned(&in_place), owned(&by_bytes));
        assert!(
            a.iter().any(|p| p.colour.is_some()),
            "shift {shift}: no colour drawn"
        );
        assert_eq!(a, b, "shift {shift}: patches");
    }
}
