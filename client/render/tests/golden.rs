//! Golden images of two fixed views of Jacksboro: a shaded view of the whole tile and a low oblique view in
//! the level-colour debug mode with wireframe.
//!
//! Tolerance: a pixel matches when every channel is within 6 of the golden, and 99 % of pixels
//! must match. lavapipe is deterministic on one machine, but another Mesa / LLVM version may
//! round interpolants differently (a colour step or two) and flip pixels along silhouettes and
//! triangle edges (wireframe lines); a wrong normal, colour ramp, light direction, camera or
//! patch placement changes far more than 1 % of the pixels or far more than 6 levels.
//!
//! Regenerate with `CBDAM_UPDATE_GOLDEN=1 cargo test -p cbdam-render --test tests golden::`, and
//! look at the new PNGs before committing them. A run in that mode writes every image and then
//! fails each test that wrote one: it compared nothing, so it must never read as green.

use std::path::PathBuf;

use crate::util::*;
use cbdam_client::camera::Camera;
use cbdam_client::world::World;
use cbdam_render::{Frame, RenderOptions};

const TOLERANCE: u8 = 6;
const MIN_MATCHING: f64 = 0.99;

fn golden_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join("golden")
        .join(format!("{name}.png"))
}

fn read_png(path: &std::path::Path) -> (u32, u32, Vec<u8>) {
    let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
    let mut reader = png::Decoder::new(file).read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgba, "{}", path.display());
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

pub fn compare(name: &str, frame: &Frame) {
    let path = golden_path(name);
    if std::env::var_os("CBDAM_UPDATE_GOLDEN").is_some() {
        std::fs::write(&path, frame.to_png().unwrap()).unwrap();
        panic!(
            "{name}: wrote {} (CBDAM_UPDATE_GOLDEN is set: the image was rewritten, not \
             compared, so this test fails; look at it, then run again without the variable)",
            path.display()
        );
    }
    let (w, h, golden) = read_png(&path);
    assert_eq!((w, h), (frame.width, frame.height), "{name}: size");
    let matching = golden
        .chunks(4)
        .zip(frame.rgba.chunks(4))
        .filter(|(a, b)| {
            a.iter()
                .zip(b.iter())
                .all(|(x, y)| x.abs_diff(*y) <= TOLERANCE)
        })
        .count();
    let share = matching as f64 / f64::from(w * h);
    if share < MIN_MATCHING {
        let out = save(
            &format!("golden-{name}-actual.png"),
            &frame.to_png().unwrap(),
        );
        panic!(
            "{name}: only {:.2} % of pixels match {} (actual: {})",
            share * 100.0,
            path.display(),
            out.display()
        );
    }
}

fn render(name: &str, cam: &Camera, pixel_error: f64, options: &RenderOptions) -> Frame {
    let repo = jacksboro();
    let (_, patches) = refined_cut(repo, cam, pixel_error);
    let frame = renderer(repo).render(cam, &patches, options).unwrap();
    eprintln!("{name}: {:?}", frame.stats);
    frame
}

#[test]
fn overview_matches_golden() {
    let world = World::of_repository(jacksboro());
    let (lo, hi) = world.bounds();
    let span = (hi - lo).x.max((hi - lo).y);
    // From the south, 40° high, close enough that the data fills the frame.
    let cam = orbit(&world, 0.0, 40.0, span * 0.8, (200, 130));
    compare(
        "jacksboro-overview",
        &render("overview", &cam, 1.0, &RenderOptions::default()),
    );
}

#[test]
fn oblique_levels_wireframe_matches_golden() {
    let world = World::of_repository(jacksboro());
    let (lo, hi) = world.bounds();
    let span = (hi - lo).x.max((hi - lo).y);
    let cam = orbit(&world, 220.0, 18.0, span * 0.55, (200, 130));
    let options = RenderOptions {
        level_colours: true,
        wireframe: true,
        ..RenderOptions::default()
    };
    compare(
        "jacksboro-oblique-levels",
        &render("oblique", &cam, 3.0, &options),
    );
}
