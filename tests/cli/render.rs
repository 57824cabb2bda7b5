//! `cbdam render` end to end on lavapipe (or a real GPU): a PNG of the requested size, written
//! atomically, and clean failures for bad arguments.

use std::path::Path;

use crate::util::*;

fn png_size(path: &Path) -> (u32, u32) {
    let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
    let reader = png::Decoder::new(file).read_info().unwrap();
    let info = reader.info();
    (info.width, info.height)
}

/// Size and number of distinct RGBA colours of a PNG.
fn png_colours(path: &Path) -> ((u32, u32), usize) {
    let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
    let mut reader = png::Decoder::new(file).read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgba);
    buf.truncate(info.buffer_size());
    let colours: std::collections::HashSet<&[u8]> = buf.chunks(4).collect();
    ((info.width, info.height), colours.len())
}

#[test]
fn render_writes_a_png_and_rejects_bad_arguments() {
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro_at("2");

    let out = dir.path().join("f.png");
    let o = cbdam(&["render", &s(&repo), "--size", "96x64", "-o", &s(&out)]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        text.contains("M triangles") && text.contains("frame"),
        "{text}"
    );
    assert_eq!(png_size(&out), (96, 64));

    let wire = dir.path().join("w.png");
    let o = cbdam(&[
        "render",
        &s(&repo),
        "--size",
        "64x48",
        "-o",
        &s(&wire),
        "--wireframe",
        "--levels",
        "--camera",
        "15000,-42000,5000,15000,-18000,300",
        "--pixel-error",
        "4",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(png_size(&wire), (64, 48));

    // Bad values, nothing written: usage errors (exit 2 from clap's parser, which names the
    // flag) and values refused once parsed (exit 1 with a message).
    let bad = dir.path().join("bad.png");
    for (args, code, message) in [
        (["--size", "0x5"], 2, "WIDTHxHEIGHT"),
        (["--pixel-error", "0"], 2, "positive"),
        (["--exaggeration", "-1"], 2, "positive"),
        (["--camera", "1,2,3,4,5"], 1, "six finite numbers"),
        (["--camera", "1,2,3,1,2,3"], 1, "coincide"),
    ] {
        let (repo, bad) = (s(&repo), s(&bad));
        let o = cbdam(&["render", &repo, "-o", &bad, args[0], args[1]]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(code), "{args:?}: {err}");
        assert!(
            err.contains(args[0]) && err.contains(message),
            "{args:?}: {err}"
        );
        assert!(!Path::new(&bad).exists());
    }
    // A directory as output.
    let o = cbdam(&["render", &s(&repo), "--size", "32x32", "-o", &s(dir.path())]);
    assert_eq!(o.status.code(), Some(1));
}

/// `cbdam render --path`: one PNG per flight frame with the time-budgeted refiner, bounded by
/// --max-frames, and a timing summary.
#[test]
fn render_path_writes_every_frame() {
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro_at("2");
    let flight = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/flights/descent.json");
    let frames = dir.path().join("frames");
    let o = cbdam(&[
        "render",
        &s(&repo),
        "--path",
        &s(&flight),
        "--out-dir",
        &s(&frames),
        "--size",
        "160x90",
        "--fps",
        "10",
        "--budget-ms",
        "2",
        "--max-frames",
        "4",
    ]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        text.contains("4 frames")
            && text.contains("refine ms per frame: median")
            && text.contains("render ms per frame: median")
            && text.contains("p99")
            && text.contains("triangles"),
        "{text}"
    );
    // Progress on stderr (not a terminal here): a line at each quarter of the frames.
    let err = String::from_utf8_lossy(&o.stderr);
    let progress: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("rendering: "))
        .collect();
    assert_eq!(
        progress,
        (1..=4)
            .map(|i| format!("rendering: {i} of 4 frames"))
            .collect::<Vec<_>>(),
        "{err}"
    );
    let mut names: Vec<String> = std::fs::read_dir(&frames)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        (0..4)
            .map(|i| format!("frame_{i:05}.png"))
            .collect::<Vec<_>>()
    );
    for name in &names {
        let (size, colours) = png_colours(&frames.join(name));
        assert_eq!(size, (160, 90), "{name}");
        // Shaded terrain, not a cleared background.
        assert!(colours > 50, "{name}: {colours} colours");
    }

    // --path wants --out-dir, and excludes -o and --camera: usage errors.
    for extra in [
        vec![],
        vec!["--out-dir", "x", "-o", "y.png"],
        vec!["--out-dir", "x", "--camera", "1,2,3,4,5,6"],
    ] {
        let mut args = vec!["render", "REPO", "--path", "f.json"];
        args.extend(extra.iter());
        let repo = s(&repo);
        args[1] = &repo;
        let o = cbdam(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}");
    }
    // A flight that is not one: exit 1.
    let bad = dir.path().join("bad.json");
    std::fs::write(&bad, "{}").unwrap();
    let o = cbdam(&[
        "render",
        &s(&repo),
        "--path",
        &s(&bad),
        "--out-dir",
        &s(&frames),
    ]);
    assert_eq!(o.status.code(), Some(1));
}

/// The same frame from a real `cbdam serve` over HTTP and from the local file: the client cannot
/// tell its sources apart, so the converged cut and the PNG are byte-identical.
#[cfg(unix)]
#[test]
fn render_over_http_equals_render_of_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro_at("2");
    let (mut server, addr) = spawn_serve(&[&s(&repo)]);
    let local = dir.path().join("local.png");
    let remote = dir.path().join("remote.png");
    let o = cbdam(&["render", &s(&repo), "--size", "200x120", "-o", &s(&local)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let url = format!("http://{addr}/");
    let o = cbdam(&["render", &url, "--size", "200x120", "-o", &s(&remote)]);
    let _ = server.kill();
    let _ = server.wait();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        std::fs::read(&local).unwrap(),
        std::fs::read(&remote).unwrap()
    );
}

/// `--cut-out` lists the refined diamonds the printed count reports, sorted and distinct, as
/// `L-x-y` ids; the same from the file and over HTTP.
#[test]
fn render_cut_out_lists_the_refined_diamonds() {
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro_at("2");
    let (mut server, addr) = spawn_serve(&[&s(&repo)]);
    let mut cuts = Vec::new();
    for (name, source) in [("local", s(&repo)), ("remote", format!("http://{addr}/"))] {
        let cut = dir.path().join(format!("{name}.txt"));
        let png = dir.path().join(format!("{name}.png"));
        let o = cbdam(&[
            "render",
            &source,
            "--size",
            "320x240",
            "-o",
            &s(&png),
            "--cut-out",
            &s(&cut),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let stdout = String::from_utf8_lossy(&o.stdout);
        let refined: usize = stdout
            .split(" diamonds refined")
            .next()
            .and_then(|head| head.rsplit(' ').next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("no refined count in {stdout}"));
        let text = std::fs::read_to_string(&cut).unwrap();
        let ids: Vec<&str> = text.lines().collect();
        assert!(refined > 0);
        assert_eq!(ids.len(), refined, "{text}");
        assert!(
            ids.windows(2).all(|w| w[0] < w[1]),
            "not sorted and distinct: {text}"
        );
        for id in &ids {
            let parts: Vec<&str> = id.split('-').collect();
            assert!(
                parts.len() == 3 && parts.iter().all(|p| p.parse::<u32>().is_ok()),
                "not an L-x-y id: {id}"
            );
        }
        cuts.push(text);
    }
    let _ = server.kill();
    let _ = server.wait();
    assert_eq!(cuts[0], cuts[1]);
}

/// Without a usable `XDG_RUNTIME_DIR` (a server, a container, CI), a render says nothing about
/// it — Mesa's drivers would print "error: XDG_RUNTIME_DIR is invalid or not set" twice: `cbdam`
/// gives itself a private runtime directory, and removes it at exit (`TMPDIR`, where it is made,
/// is empty again). Unset, and set to a directory that does not exist.
#[test]
fn render_without_a_runtime_dir_prints_no_error_and_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro_at("2");
    let tmp = dir.path().join("tmp");
    std::fs::create_dir(&tmp).unwrap();
    let not_ours = dir.path().join("missing");
    for runtime in [None, Some(&not_ours)] {
        let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_cbdam"));
        command
            .args(["render", &s(&repo), "--size", "64x48", "-o"])
            .arg(dir.path().join("f.png"))
            .env("TMPDIR", &tmp);
        match runtime {
            None => command.env_remove("XDG_RUNTIME_DIR"),
            Some(d) => command.env("XDG_RUNTIME_DIR", d),
        };
        let o = command.output().expect("run cbdam render");
        assert!(o.status.success(), "{}", stderr(&o));
        assert!(
            !stderr(&o).contains("XDG_RUNTIME_DIR"),
            "XDG_RUNTIME_DIR {runtime:?}:\n{}",
            stderr(&o)
        );
        assert_eq!(listing(&tmp), Vec::<std::path::PathBuf>::new());
    }
}

/// `cbdam demo` end to end (build, serve, replay and render over HTTP), bounded to two frames.
#[test]
fn demo_builds_serves_replays_and_renders() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let o = cbdam(&[
        "demo",
        "--out-dir",
        &s(&out),
        "--size",
        "160x90",
        "--max-frames",
        "2",
        "--view-frames",
        "3",
    ]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("demo finished"), "{stdout}");
    // With a display (scripts/test.sh starts Xvfb) the viewer opens on the served URL for three
    // frames and closes; without one the demo says why it shows none.
    if std::env::var_os("DISPLAY").is_some_and(|d| !d.is_empty()) {
        assert!(stderr.contains("demo: viewer closed"), "{stderr}");
    } else {
        assert!(stderr.contains("no display"), "{stderr}");
    }
    let csv = std::fs::read_to_string(out.join("replay.csv")).unwrap();
    assert!(csv.lines().count() > 100, "a row per frame of the flight");
    assert_eq!(png_size(&out.join("overview.png")), (160, 90));
    for i in 0..2 {
        let (size, colours) = png_colours(&out.join(format!("frames/frame_{i:05}.png")));
        assert_eq!(size, (160, 90));
        assert!(colours > 50, "frame {i} shows terrain");
    }
    assert!(!out.join("frames/frame_00002.png").exists());
    check_flight_video(&out, &stdout);
}

/// The demo's flight as one video (two frames of 160×90 at 30 fps): an MP4 where `ffmpeg` is on
/// the PATH (its frames counted with `ffprobe` when that is there too), else an animated PNG
/// whose frames are the flight's frames, pixel for pixel (a flight this short and narrow is kept
/// whole).
fn check_flight_video(out: &Path, stdout: &str) {
    use std::process::Command;
    let runs = |tool: &str| {
        Command::new(tool)
            .arg("-version")
            .output()
            .is_ok_and(|o| o.status.success())
    };
    if runs("ffmpeg") {
        let mp4 = out.join("flight.mp4");
        assert!(
            stdout.contains(&format!(
                "{} (H.264 MP4, 2 frames at 30 fps)",
                mp4.display()
            )),
            "{stdout}"
        );
        let bytes = std::fs::read(&mp4).unwrap();
        assert_eq!(
            &bytes[4..8],
            b"ftyp",
            "an MP4 file starts with its ftyp box"
        );
        for tag in [b"moov", b"avc1"] {
            assert!(
                bytes.windows(4).any(|w| w == tag),
                "no {} box in the MP4",
                String::from_utf8_lossy(tag)
            );
        }
        if !runs("ffprobe") {
            println!("ffprobe is not installed: the MP4's frames are not counted");
        } else {
            let o = Command::new("ffprobe")
                .args(["-v", "error", "-count_frames", "-select_streams", "v:0"])
                .args([
                    "-show_entries",
                    "stream=nb_read_frames,width,height,codec_name",
                ])
                .args(["-of", "default=noprint_wrappers=1"])
                .arg(&mp4)
                .output()
                .unwrap();
            let probe = String::from_utf8_lossy(&o.stdout);
            for line in [
                "codec_name=h264",
                "width=160",
                "height=90",
                "nb_read_frames=2",
            ] {
                assert!(probe.lines().any(|l| l == line), "{line} not in\n{probe}");
            }
        }
        return;
    }
    let apng = out.join("flight.png");
    assert!(
        stdout.contains(&format!(
            "{} (animated PNG, 2 frames of 160×90 at 30 fps)",
            apng.display()
        )),
        "{stdout}"
    );
    let file = std::io::BufReader::new(std::fs::File::open(&apng).unwrap());
    let mut reader = png::Decoder::new(file).read_info().unwrap();
    let control = reader.info().animation_control.expect("an animated PNG");
    assert_eq!(control.num_frames, 2);
    for i in 0..2 {
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        buf.truncate(info.buffer_size());
        assert_eq!((info.width, info.height), (160, 90));
        let frame = out.join(format!("frames/frame_{i:05}.png"));
        let file = std::io::BufReader::new(std::fs::File::open(&frame).unwrap());
        let mut still = png::Decoder::new(file).read_info().unwrap();
        let mut want = vec![0; still.output_buffer_size().unwrap()];
        let info = still.next_frame(&mut want).unwrap();
        want.truncate(info.buffer_size());
        assert!(
            buf == want,
            "video frame {i} differs from {}",
            frame.display()
        );
    }
}

/// `cbdam bench render --flight`: one table row per repository and flight, with frame counts
/// bounded by --max-frames and positive frame times and triangle rates; a bad --fps is refused.
#[test]
fn bench_render_flies_the_flights() {
    let repo = jacksboro_at("2");
    let flights = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/flights");
    let (low, descent) = (flights.join("low_pass.json"), flights.join("descent.json"));
    let o = cbdam(&[
        "bench",
        "render",
        &s(&repo),
        "--size",
        "160x90",
        "--runs",
        "1",
        "--flight",
        &s(&low),
        "--flight",
        &s(&descent),
        "--max-frames",
        "3",
    ]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for flight in ["low_pass.json", "descent.json"] {
        let row = text
            .lines()
            .find(|l| l.starts_with(&format!("| {} | ", file_name(&repo))) && l.contains(flight))
            .unwrap_or_else(|| panic!("no row for {flight}:\n{text}"));
        let cells: Vec<&str> = row.split('|').map(str::trim).collect();
        assert_eq!(cells[3], "3", "frames: {row}");
        for (i, what) in [
            (4, "frame ms median"),
            (6, "triangles/frame"),
            (7, "M tris/s"),
        ] {
            let v: f64 = cells[i].parse().unwrap_or_else(|_| panic!("{what}: {row}"));
            assert!(v > 0.0, "{what} is {v}: {row}");
        }
    }
    let o = cbdam(&[
        "bench",
        "render",
        &s(&repo),
        "--flight",
        &s(&low),
        "--fps",
        "0",
    ]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--fps") && err.contains("positive"), "{err}");
}

/// Without `--camera`, `cbdam render` frames the data so that it fills most of the frame (the
/// old overview left about 80 % of a 640×480 frame to the sky on a landscape DEM): the share of
/// pixels that are not the sky's colour (the top-left corner's, which the framed view leaves
/// clear) is counted.
#[test]
fn the_default_view_fills_most_of_the_frame() {
    let dir = tempfile::tempdir().unwrap();
    let repo = dir.path().join("r.cbdam");
    let o = cbdam(&[
        "build",
        &data("srtm3_demcompare.tif"),
        "--max-error",
        "2",
        "-o",
        &s(&repo),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = dir.path().join("v.png");
    let o = cbdam(&["render", &s(&repo), "--size", "640x480", "-o", &s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let file = std::io::BufReader::new(std::fs::File::open(&out).unwrap());
    let mut reader = png::Decoder::new(file).read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    let sky = &buf[..4];
    let terrain = buf.chunks(4).filter(|p| *p != sky).count();
    let share = terrain as f64 / (640.0 * 480.0);
    assert!(
        share > 0.6,
        "terrain covers only {:.1} % of the frame",
        100.0 * share
    );
}

/// A planet (cube-sphere repository): `render` without a camera shows the whole globe, centred,
/// its disc 90 % of the frame's height; `--geo` places the eye at the geodetic position asked
/// for (echoed back through an independent ECEF → geodetic conversion); `--geo` on a plane and
/// a bad `--geo` are refused with messages naming the problem; `replay` runs on a planet.
#[test]
fn render_draws_a_planet_whole_and_from_a_geodetic_camera() {
    let dir = tempfile::tempdir().unwrap();
    let repo = shared_planet();
    let out = dir.path().join("globe.png");
    let o = cbdam(&["render", &s(&repo), "--size", "160x120", "-o", &s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (w, h, px) = read_rgba_png(&out);
    let bg = &px[0..4];
    let (mut x0, mut x1, mut y0, mut y1) = (u32::MAX, 0, u32::MAX, 0);
    for y in 0..h {
        for x in 0..w {
            let i = ((y * w + x) * 4) as usize;
            if &px[i..i + 4] != bg {
                (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
            }
        }
    }
    let (cx, cy) = (f64::from(x0 + x1 + 1) / 2.0, f64::from(y0 + y1 + 1) / 2.0);
    assert!(
        (cx - 80.0).abs() <= 1.5 && (cy - 60.0).abs() <= 1.5,
        "globe centred at {cx}, {cy}"
    );
    let disc = f64::from(y1 - y0 + 1);
    assert!((disc - 108.0).abs() <= 3.0, "globe {disc} px high of 120");

    let geo = dir.path().join("geo.png");
    let o = cbdam(&[
        "render",
        &s(&repo),
        "--size",
        "96x64",
        "--geo",
        "30,20,25000,45,-20",
        "-o",
        &s(&geo),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("lat 30.000000, lon 20.000000, 25000.0 m above the ellipsoid"),
        "{e}"
    );
    assert_eq!(png_size(&geo), (96, 64));

    let plane = jacksboro_at("2");
    let o = cbdam(&["render", &s(&plane), "--geo", "30,20,100", "-o", &s(&geo)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("--geo needs a planet"),
        "{}",
        stderr(&o)
    );
    let o = cbdam(&["render", &s(&repo), "--geo", "91,0,10", "-o", &s(&geo)]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("latitude 91"), "{}", stderr(&o));

    let csv = dir.path().join("replay.csv");
    let o = cbdam(&[
        "replay",
        &s(&repo),
        "--path",
        &data("flights/descent.json"),
        "--out",
        &s(&csv),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(std::fs::read_to_string(&csv).unwrap().lines().count() > 10);
}
