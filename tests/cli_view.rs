//! `cbdam view` end to end: the real viewer in a real X11 window (the session's DISPLAY, or an
//! Xvfb this test starts) on lavapipe or a GPU, for a few frames, then its screenshot is checked
//! for terrain and the HUD.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use cbdam_client::draw::hud;

fn cbdam(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args(args)
        .output()
        .expect("run cbdam")
}

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

/// An Xvfb started by this test, stopped when dropped.
struct Xvfb(Child);

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The display to open windows on: `$DISPLAY`, or a fresh Xvfb on a free display number.
/// `None` (with the reason) when there is neither.
fn display() -> Result<(String, Option<Xvfb>), String> {
    if let Some(d) = std::env::var_os("DISPLAY").filter(|d| !d.is_empty()) {
        return Ok((d.to_string_lossy().into_owned(), None));
    }
    let free = (150..250).find(|n| {
        !Path::new(&format!("/tmp/.X11-unix/X{n}")).exists()
            && !Path::new(&format!("/tmp/.X{n}-lock")).exists()
    });
    let n = free.ok_or("no free X display number")?;
    let child = Command::new("Xvfb")
        .args([
            &format!(":{n}"),
            "-screen",
            "0",
            "1024x768x24",
            "-nolisten",
            "tcp",
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| format!("DISPLAY is unset and Xvfb cannot be started ({e})"))?;
    let mut xvfb = Xvfb(child);
    let socket = PathBuf::from(format!("/tmp/.X11-unix/X{n}"));
    let start = Instant::now();
    while !socket.exists() {
        if let Ok(Some(status)) = xvfb.0.try_wait() {
            return Err(format!("Xvfb :{n} exited at once ({status})"));
        }
        if start.elapsed() > Duration::from_secs(10) {
            return Err(format!("Xvfb :{n} did not come up in 10 s"));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    Ok((format!(":{n}"), Some(xvfb)))
}

fn read_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
    let mut reader = png::Decoder::new(file).read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgba);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

#[test]
fn help_lists_the_keys() {
    let o = cbdam(&["view", "--help"]);
    assert!(o.status.success());
    let help = String::from_utf8_lossy(&o.stdout);
    for needle in [
        "freeze",
        "wireframe",
        "--max-frames",
        "--screenshot",
        "--no-vsync",
        "Esc",
    ] {
        assert!(help.contains(needle), "--help lacks {needle:?}:\n{help}");
    }
}

#[test]
fn view_draws_terrain_and_the_hud_in_a_window() {
    let (display, _xvfb) = match display() {
        Ok(d) => d,
        Err(why) => {
            println!("SKIPPED view_draws_terrain_and_the_hud_in_a_window: {why}");
            return;
        }
    };
    let dir = tempfile::tempdir().unwrap();
    let repo = dir.path().join("j.cbdam");
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/jacksboro_mpl.tif");
    let o = cbdam(&[
        "build",
        &s(&data),
        "-o",
        &s(&repo),
        "--max-error",
        "2",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let shot = dir.path().join("shot.png");
    let (w, h) = (320u32, 240u32);
    let o = Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args([
            "view",
            &s(&repo),
            "--size",
            &format!("{w}x{h}"),
            "--max-frames",
            "8",
            "--no-vsync",
            "--screenshot",
            &s(&shot),
        ])
        .env("DISPLAY", &display)
        .output()
        .expect("run cbdam view");
    let (stdout, stderr) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(o.status.success(), "cbdam view failed:\n{stdout}\n{stderr}");
    assert!(stdout.contains("8 frames"), "{stdout}");

    let (pw, ph, rgba) = read_png(&shot);
    assert_eq!((pw, ph), (w, h), "the screenshot has the window's size");
    let px = |x: u32, y: u32| {
        let i = 4 * (y * w + x) as usize;
        [rgba[i], rgba[i + 1], rgba[i + 2], rgba[i + 3]]
    };
    assert!(rgba.chunks(4).all(|p| p[3] == 255), "the frame is opaque");

    // Terrain: the overview puts the data in the middle of the view; there the clear colour
    // must not show.
    let bg = cbdam_client::draw::RenderOptions::default()
        .background
        .map(|c| (c * 255.0).round() as u8);
    let centre: Vec<_> = (h / 2 - 10..h / 2 + 10)
        .flat_map(|y| (w / 2 - 10..w / 2 + 10).map(move |x| (x, y)))
        .collect();
    let sky = centre
        .iter()
        .filter(|&&(x, y)| px(x, y)[..3] == bg[..3])
        .count();
    assert_eq!(sky, 0, "background colour {bg:?} in the middle of the view");
    // Some background does show around the terrain (the frame is not one flat colour).
    assert!((0..w).any(|x| px(x, h - 1)[..3] == bg[..3]));

    // HUD: the box is where the layout puts it; in it, opaque text pixels of the text colour,
    // and in its glyph-free top padding, everything darkened by the translucent black box.
    let layout = hud::layout(&["x".to_string()], (w, h), hud::scale_for((w, h)));
    let b = layout[0];
    let (bx, by) = (b.pos[0] as u32, b.pos[1] as u32);
    let text_in = |x0: u32, y0: u32, x1: u32, y1: u32| {
        (y0..y1)
            .flat_map(|y| (x0..x1).map(move |x| (x, y)))
            .filter(|&(x, y)| px(x, y) == hud::TEXT_RGBA)
            .count()
    };
    let hud_text = text_in(bx, by, w, h / 2);
    assert!(hud_text > 200, "only {hud_text} HUD text pixels");
    // The same colour is (nearly) absent from the lower half, where there is no HUD.
    let elsewhere = text_in(0, h / 2, w, h);
    assert!(
        elsewhere < 10,
        "{elsewhere} text-coloured pixels outside the HUD"
    );
    let keep = 1.0 - f64::from(hud::BOX_RGBA[3]) / 255.0;
    for y in by..by + 3 {
        for x in bx..bx + 100 {
            let p = px(x, y);
            assert!(
                p[..3].iter().all(|&c| f64::from(c) <= 255.0 * keep + 2.0),
                "pixel ({x},{y}) = {p:?} is not under the HUD box"
            );
        }
    }
}
