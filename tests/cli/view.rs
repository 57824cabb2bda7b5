//! `cbdam view` end to end: the real viewer in a real X11 window (the session's DISPLAY, or an
//! Xvfb this test starts) on lavapipe or a GPU, for a few frames, then its screenshot is checked
//! for terrain and the HUD.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::util::*;
use cbdam_render::hud;

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
    let (display, xvfb) = start_xvfb()?;
    Ok((display, Some(xvfb)))
}

/// A fresh Xvfb, whatever `$DISPLAY` says. Xvfb picks a free display number itself and reports
/// it once it accepts connections (`-displayfd`), so tests starting servers at the same time
/// cannot race for one number.
fn start_xvfb() -> Result<(String, Xvfb), String> {
    let mut child = Command::new("Xvfb")
        .args([
            "-displayfd",
            "1",
            "-screen",
            "0",
            "1024x768x24",
            "-nolisten",
            "tcp",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| format!("DISPLAY is unset and Xvfb cannot be started ({e})"))?;
    let stdout = child.stdout.take().expect("piped");
    let xvfb = Xvfb(child);
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut line = String::new();
        let _ = std::io::BufRead::read_line(&mut std::io::BufReader::new(stdout), &mut line);
        let _ = tx.send(line);
    });
    let line = rx
        .recv_timeout(Duration::from_secs(20))
        .map_err(|_| "Xvfb did not come up in 20 s".to_string())?;
    match line.trim().parse::<u32>() {
        Ok(n) => Ok((format!(":{n}"), xvfb)),
        Err(_) => Err(format!("Xvfb exited without a display ({line:?})")),
    }
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
        "hide / show the HUD",
        "Esc",
    ] {
        assert!(help.contains(needle), "--help lacks {needle:?}:\n{help}");
    }
}

#[test]
fn view_draws_terrain_and_the_hud_in_a_window() {
    let (display, _xvfb) = match display() {
        Ok(d) => d,
        Err(why) => return skip_unless_ci("view_draws_terrain_and_the_hud_in_a_window", &why),
    };
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro_at("2");

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

    let (pw, ph, rgba) = read_rgba_png(&shot);
    assert_eq!((pw, ph), (w, h), "the screenshot has the window's size");
    let px = |x: u32, y: u32| {
        let i = 4 * (y * w + x) as usize;
        [rgba[i], rgba[i + 1], rgba[i + 2], rgba[i + 3]]
    };
    assert!(rgba.chunks(4).all(|p| p[3] == 255), "the frame is opaque");

    // Terrain: the overview puts the data in the middle of the view; there the clear colour
    // must not show.
    let bg = cbdam_render::RenderOptions::default()
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

/// Runs `xdotool ARGS` on `display`; its stdout.
fn xdotool(display: &str, args: &[&str]) -> String {
    let o = Command::new("xdotool")
        .args(args)
        .env("DISPLAY", display)
        .output()
        .expect("run xdotool");
    assert!(
        o.status.success(),
        "xdotool {args:?} failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Waits for the viewer to write `path` (it saves a screenshot after the next frame it draws).
fn wait_for(path: &Path, viewer: &mut Child) -> (u32, u32, Vec<u8>) {
    let start = Instant::now();
    // Written by `write_png` with a rename, so a file that exists is complete.
    while !path.exists() {
        if let Ok(Some(status)) = viewer.try_wait() {
            panic!(
                "the viewer exited ({status}) before writing {}",
                path.display()
            );
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no {} after 60 s",
            path.display()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    read_rgba_png(path)
}

/// The window's pixels as RGBA, read back from the X server with `xwd` (format: X11's XWDFile.h;
/// only the 32-bit TrueColor ZPixmap that Xvfb's 24-bit screen gives is accepted).
fn capture_window(display: &str, window: &str, w: u32, h: u32) -> Vec<u8> {
    let o = Command::new("xwd")
        .args(["-silent", "-id", window])
        .env("DISPLAY", display)
        .output()
        .expect("run xwd");
    assert!(
        o.status.success(),
        "xwd: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let d = o.stdout;
    let field = |i: usize| u32::from_be_bytes(d[4 * i..4 * i + 4].try_into().unwrap());
    let (header, format, width, height) = (field(0), field(2), field(4), field(5));
    let (byte_order, bits_per_pixel, bytes_per_line) = (field(7), field(11), field(12));
    let (red, green, blue, ncolors) = (field(14), field(15), field(16), field(19));
    assert_eq!((format, width, height, bits_per_pixel), (2, w, h, 32));
    assert_eq!(
        (red, green, blue),
        (0xff0000, 0xff00, 0xff),
        "not an RGB TrueColor visual"
    );
    let pixels = &d[(header + 12 * ncolors) as usize..];
    let mut rgba = Vec::with_capacity((4 * w * h) as usize);
    for y in 0..h as usize {
        for x in 0..w as usize {
            let b: [u8; 4] = pixels[y * bytes_per_line as usize + 4 * x..][..4]
                .try_into()
                .unwrap();
            let v = if byte_order == 0 {
                u32::from_le_bytes(b)
            } else {
                u32::from_be_bytes(b)
            };
            rgba.extend_from_slice(&[(v >> 16) as u8, (v >> 8) as u8, v as u8, 255]);
        }
    }
    rgba
}

/// Pixels of the lower half (below the HUD) that differ between two screenshots.
fn lower_half_changes(a: &[u8], b: &[u8], w: u32, h: u32) -> usize {
    let from = (4 * w * (h / 2)) as usize;
    a[from..]
        .chunks(4)
        .zip(b[from..].chunks(4))
        .filter(|(p, q)| p != q)
        .count()
}

/// Mean brightness (0–255) of the square of side `2r` at the centre of the frame.
fn centre_brightness(rgba: &[u8], w: u32, h: u32, r: u32) -> f64 {
    let mut sum = 0u64;
    for y in h / 2 - r..h / 2 + r {
        for x in w / 2 - r..w / 2 + r {
            let i = 4 * (y * w + x) as usize;
            sum += u64::from(rgba[i]) + u64::from(rgba[i + 1]) + u64::from(rgba[i + 2]);
        }
    }
    sum as f64 / (3.0 * f64::from(4 * r * r))
}

/// The viewer driven by real X11 input events (XTEST, through `xdotool`): P saves a screenshot,
/// which matches what the window shows; H hides and shows the HUD; Tab switches to wireframe, a
/// left drag rotates the orbit camera, Esc quits. Always on a private Xvfb, never on the
/// session's display, so no key lands in someone's desktop.
#[test]
fn keys_and_mouse_drive_the_viewer() {
    let skip = |why: &str| skip_unless_ci("keys_and_mouse_drive_the_viewer", why);
    for tool in ["xdotool", "xwd"] {
        if Command::new(tool).arg("-version").output().is_err() {
            return skip(&format!(
                "{tool} is not installed (scripts/test.sh installs it)"
            ));
        }
    }
    let (display, _xvfb) = match start_xvfb() {
        Ok(d) => d,
        Err(why) => return skip(&why),
    };
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro_at("2");
    let (w, h) = (320u32, 240u32);
    let mut viewer = Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args([
            "view",
            &s(&repo),
            "--size",
            &format!("{w}x{h}"),
            "--no-vsync",
        ])
        .current_dir(dir.path())
        .env("DISPLAY", &display)
        // The decode workers at the test's priority, not idle: on a busy machine idle workers
        // can be starved for several frames, and a still view that stops changing for want of
        // decoded records is not a converged one.
        .env("CBDAM_DECODE_PRIORITY", "0")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run cbdam view");
    let window = xdotool(&display, &["search", "--sync", "--name", "cbdam view"]);
    let window = window
        .lines()
        .next()
        .expect("the viewer's window")
        .to_string();
    // Without a window manager, keys go to the focused window: give it the focus.
    xdotool(&display, &["windowfocus", "--sync", &window]);
    let shot = |i: u32| dir.path().join(format!("cbdam-view-{i:04}.png"));
    let press = |keys: &[&str]| {
        let mut args = vec!["key", "--delay", "50"];
        args.extend_from_slice(keys);
        xdotool(&display, &args);
    };

    // P, until three screenshots in a row of the still camera agree below the HUD: the cut has
    // converged (the HUD's fps line changes every frame, so it is left out).
    press(&["p"]);
    let mut n = 1;
    let (_, _, mut still) = wait_for(&shot(n), &mut viewer);
    let mut agreeing = 0;
    while agreeing < 2 {
        press(&["p"]);
        n += 1;
        let (_, _, next) = wait_for(&shot(n), &mut viewer);
        let changed = lower_half_changes(&still, &next, w, h);
        still = next;
        agreeing = if changed == 0 { agreeing + 1 } else { 0 };
        assert!(
            n < 30,
            "the still view never settled ({changed} pixels still change)"
        );
    }

    // What the window shows is what the screenshot saved: the present pass copies the sRGB
    // frame to the swapchain without a second gamma or a channel swap. Below the HUD (which
    // changes every frame) they agree exactly.
    let shown = capture_window(&display, &window, w, h);
    assert_eq!(
        lower_half_changes(&still, &shown, w, h),
        0,
        "the window differs from the screenshot"
    );

    // H hides the HUD: no text-coloured pixel is left in the frame, and the view is the
    // same below it; H again shows it.
    let text_pixels = |rgba: &[u8]| rgba.chunks(4).filter(|p| *p == hud::TEXT_RGBA).count();
    assert!(text_pixels(&still) > 200, "the HUD shows at first");
    press(&["h", "p"]);
    n += 1;
    let (_, _, bare) = wait_for(&shot(n), &mut viewer);
    assert!(
        text_pixels(&bare) < 10,
        "H left {} text pixels",
        text_pixels(&bare)
    );
    assert_eq!(
        lower_half_changes(&still, &bare, w, h),
        0,
        "H changed the view"
    );
    press(&["h", "p"]);
    n += 1;
    let (_, _, shown) = wait_for(&shot(n), &mut viewer);
    assert!(
        text_pixels(&shown) > 200,
        "H twice did not bring the HUD back"
    );

    // Tab: wireframe. The shaded surface is replaced by lines over the background, so the
    // centre's colours change and most of it gets darker (the wireframe is drawn dark).
    press(&["Tab", "p"]);
    n += 1;
    let (_, _, wire) = wait_for(&shot(n), &mut viewer);
    let changed = lower_half_changes(&still, &wire, w, h);
    assert!(
        changed > (w * h / 8) as usize,
        "Tab changed only {changed} pixels"
    );
    let (shaded_light, wire_light) = (
        centre_brightness(&still, w, h, 20),
        centre_brightness(&wire, w, h, 20),
    );
    assert!(
        wire_light < shaded_light * 0.8,
        "wireframe centre brightness {wire_light:.1} vs shaded {shaded_light:.1}"
    );

    // Tab again: back to the shaded frame, identical to before (the camera has not moved).
    press(&["Tab", "p"]);
    n += 1;
    let (_, _, back) = wait_for(&shot(n), &mut viewer);
    assert_eq!(
        lower_half_changes(&still, &back, w, h),
        0,
        "Tab twice is not a no-op"
    );

    // A left drag across the window rotates the orbit camera: the view changes.
    let (cx, cy) = ((w / 2).to_string(), (h * 3 / 4).to_string());
    xdotool(
        &display,
        &[
            "mousemove",
            "--window",
            &window,
            &cx,
            &cy,
            "mousedown",
            "1",
            "mousemove_relative",
            "--",
            "80",
            "0",
            "mouseup",
            "1",
        ],
    );
    press(&["p"]);
    n += 1;
    let (_, _, turned) = wait_for(&shot(n), &mut viewer);
    let changed = lower_half_changes(&still, &turned, w, h);
    assert!(
        changed > (w * h / 8) as usize,
        "the drag changed only {changed} pixels"
    );

    // Esc: the viewer quits cleanly and reports what it drew.
    press(&["Escape"]);
    let start = Instant::now();
    let status = loop {
        if let Some(status) = viewer.try_wait().unwrap() {
            break status;
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "Esc did not quit the viewer"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let out = viewer.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        status.success(),
        "cbdam view: {status}\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains(&format!("saved cbdam-view-{n:04}.png")),
        "{stdout}"
    );
}

/// `view --colour`: the draped colour reaches the window (a red west half and a blue east half
/// of Jacksboro show both colours, on their sides of the view).
#[test]
fn view_drapes_a_colour_repository() {
    let (display, _xvfb) = match display() {
        Ok(d) => d,
        Err(why) => return skip_unless_ci("view_drapes_a_colour_repository", &why),
    };
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro_at("2");
    // Jacksboro is 403 × 344 samples: a colour image of the same size covers its domain.
    let (iw, ih) = (403usize, 344usize);
    let img = dir.path().join("halves.png");
    let data: Vec<u8> = (0..iw * ih)
        .flat_map(|i| {
            if i % iw < iw / 2 {
                [200, 30, 30]
            } else {
                [30, 60, 200]
            }
        })
        .collect();
    {
        let f = std::io::BufWriter::new(std::fs::File::create(&img).unwrap());
        let mut e = png::Encoder::new(f, iw as u32, ih as u32);
        e.set_color(png::ColorType::Rgb);
        e.set_depth(png::BitDepth::Eight);
        e.write_header().unwrap().write_image_data(&data).unwrap();
    }
    let colour = dir.path().join("halves.cbdam");
    let o = cbdam(&[
        "build",
        &s(&img),
        "--colour",
        "--like",
        &s(&repo),
        "-o",
        &s(&colour),
        "--max-error",
        "2",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let shot = dir.path().join("shot.png");
    let (w, h) = (320u32, 240u32);
    let o = Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args([
            "view",
            &s(&repo),
            "--colour",
            &s(&colour),
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
    assert!(o.status.success(), "cbdam view failed:\n{}", stderr(&o));
    let (pw, _, rgba) = read_rgba_png(&shot);
    let (mut red, mut blue) = ((0usize, 0u64), (0usize, 0u64));
    for (i, p) in rgba.chunks(4).enumerate() {
        let [r, g, b] = [p[0], p[1], p[2]].map(u32::from);
        let x = (i % pw as usize) as u64;
        if r > 2 * g && r > 2 * b {
            red = (red.0 + 1, red.1 + x);
        } else if b > 2 * r && 2 * b > 3 * g {
            blue = (blue.0 + 1, blue.1 + x);
        }
    }
    // The terrain covers about a sixth of the view; each half a twelfth, ≈ 6 000 pixels.
    assert!(
        red.0 > 1500 && blue.0 > 1500,
        "red {}, blue {}",
        red.0,
        blue.0
    );
    let mean = |(n, sum): (usize, u64)| sum as f64 / n as f64;
    assert!(mean(red) < mean(blue), "red is not west of blue");
}
