//! The prefetch policy over loopback HTTP against `cbdam serve`'s router with latency: with
//! [`Prefetch::WhenIdle`] a frame whose cut still lacks records asks for nothing else (the
//! source holds no prefetch request then), and prefetches do go out while the cut lacks nothing,
//! at most [`RefineConfig::prefetch_limit`] records a frame; [`Prefetch::Always`] prefetches
//! alongside what the cut wants; a prefetch that the frame's budget cuts short cancels none of
//! the last frame's prefetches still on their way.

use std::time::{Duration, Instant};

use axum::extract::Request;
use axum::middleware::Next;
use cbdam_client::access::RemoteSource;
use cbdam_client::camera::Camera;
use cbdam_client::fetch::FetchOptions;
use cbdam_client::refine::{FrameStats, Prefetch, RefineConfig, Refiner};
use cbdam_client::world::World;
use cbdam_codec::hierarchy::{EncodeOptions, Encoder};
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::{Repository, serialize};
use cbdam_server::{AppState, Config};
use glam::DVec3;

fn image() -> Vec<u8> {
    let (w, h) = (160usize, 120usize);
    let metres: Vec<f64> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            let noise = ((i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 54) as f64 / 300.0;
            120.0 + 70.0 * (x / 19.0).sin() * (y / 27.0).cos() + noise
        })
        .collect();
    let plan = QuantPlan::new(0.25, None, 0.0, 260.0).unwrap();
    let grid = HeightGrid::from_metres(w, h, &metres, None, &plan).unwrap();
    let opts = EncodeOptions {
        n: 9,
        ..EncodeOptions::default()
    };
    let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
    serialize(&enc, &plan, None, None).unwrap()
}

/// `cbdam serve`'s router on loopback, every request answered after `latency`.
fn serve(rt: &tokio::runtime::Runtime, bytes: &[u8], latency: Duration) -> String {
    serve_delaying(rt, bytes, latency, |_| true)
}

/// `cbdam serve`'s router on loopback, the requests whose path `delayed` picks answered after
/// `latency`.
fn serve_delaying(
    rt: &tokio::runtime::Runtime,
    bytes: &[u8],
    latency: Duration,
    delayed: fn(&str) -> bool,
) -> String {
    let state = AppState::new(
        vec![("t".into(), Repository::from_bytes(bytes.to_vec()).unwrap())],
        Config::default(),
    )
    .unwrap();
    let app = cbdam_server::app(state).layer(axum::middleware::from_fn(
        move |req: Request, next: Next| async move {
            if delayed(req.uri().path()) {
                tokio::time::sleep(latency).await;
            }
            next.run(req).await
        },
    ));
    let _guard = rt.enter();
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    listener.set_nonblocking(true).unwrap();
    let addr = listener.local_addr().unwrap();
    let listener = tokio::net::TcpListener::from_std(listener).unwrap();
    rt.spawn(async move { axum::serve(listener, app).await.unwrap() });
    format!("http://{addr}/v1/repos/t")
}

/// A close view panning across the terrain: `u` from 0 to 1 moves it along x.
fn panning(world: &World, u: f64) -> Camera {
    let (lo, hi) = world.bounds();
    let target = DVec3::new(
        lo.x + (0.3 + 0.4 * u) * (hi.x - lo.x),
        lo.y + 0.4 * (hi.y - lo.y),
        world.min_height,
    );
    let eye = target + DVec3::new(-20.0, -35.0, 60.0 + world.max_height - world.min_height);
    Camera::looking_at(world, eye, target, 50f64.to_radians(), (1280, 720))
}

/// Frames every 10 ms: 1.5 s panning, then up to 1.5 s still; every frame's stats.
fn fly(url: &str, prefetch: Prefetch, world: &World) -> Vec<FrameStats> {
    let source = RemoteSource::connect(url, FetchOptions::default()).unwrap();
    let config = RefineConfig {
        prefetch,
        ..RefineConfig::default()
    };
    let mut r = Refiner::new(source, config).unwrap();
    let start = Instant::now();
    let mut frames = Vec::new();
    loop {
        let t = start.elapsed().as_secs_f64();
        let s = r.frame(&panning(world, (t / 1.5).min(1.0)));
        frames.push(s);
        if t > 3.0 || (t > 1.5 && s.converged && s.cut_wants == 0 && s.access.in_flight == 0) {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(
        frames.last().unwrap().met_target,
        "{prefetch:?}: the cut converges once the camera stops"
    );
    frames
}

#[test]
fn prefetching_when_idle_waits_for_the_cut_to_lack_nothing() {
    let bytes = image();
    let repo = Repository::from_bytes(bytes.clone()).unwrap();
    let world = World::of_repository(&repo);
    let rt = tokio::runtime::Runtime::new().unwrap();
    let url = serve(&rt, &bytes, Duration::from_millis(60));

    let idle = fly(&url, Prefetch::WhenIdle, &world);
    let limit = RefineConfig::default().prefetch_limit.unwrap();
    for s in &idle {
        assert!(s.prefetch_wants <= limit, "frame {}: {s:?}", s.frame);
        if s.cut_wants > 0 {
            assert_eq!(s.prefetch_wants, 0, "frame {}: {s:?}", s.frame);
            // What the source is asked for is what the cut lacks and nothing more: any
            // prefetch of an earlier frame was withdrawn. Exactly that, unless the frame ran
            // out of time: a record that has arrived then waits to be decoded, wanted by the
            // cut but no longer in flight (seen once in CI on a loaded machine).
            let in_flight = s.access.in_flight as usize;
            assert!(in_flight <= s.cut_wants, "frame {}: {s:?}", s.frame);
            if !s.budget_exhausted {
                assert_eq!(in_flight, s.cut_wants, "frame {}: {s:?}", s.frame);
            }
        }
    }
    let lacking = idle.iter().filter(|s| s.cut_wants > 0).count();
    let prefetching = idle.iter().filter(|s| s.prefetch_wants > 0).count();
    assert!(lacking > 0, "the cut had to wait for records");
    assert!(
        prefetching > 0,
        "prefetches went out while the cut was idle"
    );

    // The other policy prefetches while the cut still waits: the rule above is the policy's,
    // not the flight's.
    let always = fly(&url, Prefetch::Always, &world);
    assert!(
        always
            .iter()
            .any(|s| s.cut_wants > 0 && s.prefetch_wants > 0),
        "Always prefetches alongside what the cut wants"
    );
    let off = fly(&url, Prefetch::Off, &world);
    assert!(off.iter().all(|s| s.prefetch_wants == 0));
}

#[test]
fn a_prefetch_the_budget_cuts_short_keeps_what_is_on_its_way() {
    let bytes = image();
    let repo = Repository::from_bytes(bytes.clone()).unwrap();
    let world = World::of_repository(&repo);
    let rt = tokio::runtime::Runtime::new().unwrap();
    // No record arrives while the test runs: what the source holds is what was asked for.
    let url = serve_delaying(&rt, &bytes, Duration::from_secs(60), |path| {
        path.contains("/diamonds")
    });
    // With the default limit, and without one (every contribution planned, most urgent
    // first, so that a deadline cuts off the least urgent).
    for prefetch_limit in [RefineConfig::default().prefetch_limit, None] {
        let source = RemoteSource::connect(&url, FetchOptions::default()).unwrap();
        let config = RefineConfig {
            prefetch: Prefetch::Always,
            prefetch_limit,
            budget: None,
            ..RefineConfig::default()
        };
        let mut r = Refiner::new(source, config).unwrap();
        let camera = panning(&world, 0.5);
        let whole = r.frame(&camera);
        assert!(whole.prefetch_wants > 0, "{prefetch_limit:?}: {whole:?}");
        assert_eq!(
            whole.access.in_flight as usize,
            whole.cut_wants + whole.prefetch_wants,
            "{prefetch_limit:?}: {whole:?}"
        );

        // What the source holds after `s` is what it held after the whole prefetch.
        let holds_the_same = |s: &FrameStats| {
            let label = format!("{prefetch_limit:?}, frame {}: {s:?}", s.frame);
            assert_eq!(s.cut_wants, whole.cut_wants, "{label}");
            assert_eq!(s.prefetch_wants, whole.prefetch_wants, "{label}");
            assert_eq!(s.access.in_flight, whole.access.in_flight, "{label}");
        };

        // A budget that has run out before prefetching begins: nothing new is planned, and the
        // last frame's prefetches stay requested rather than being cancelled.
        r.set_budget(Some(Duration::from_nanos(1)));
        holds_the_same(&r.frame(&camera));

        // Without the budget the next frame plans them again: the same ones.
        r.set_budget(None);
        holds_the_same(&r.frame(&camera));
    }
}
