//! `--colour` on `cbdam render` and `cbdam replay`, end to end: a colour repository built over
//! Jacksboro (`build --colour --like`) turns the rendered terrain red in the west and blue in the
//! east; over `cbdam serve` the PNG is byte-identical; a colour that does not fit is refused
//! with the reason and no PNG.

use std::path::{Path, PathBuf};

use crate::util::*;

/// Jacksboro's grid, 403 × 344 samples.
pub(crate) const W: usize = 403;
pub(crate) const H: usize = 344;
const RED: [u8; 3] = [200, 30, 30];
const BLUE: [u8; 3] = [30, 60, 200];

pub(crate) fn write_png(path: &Path, w: usize, h: usize, rgb: impl Fn(usize, usize) -> [u8; 3]) {
    let data: Vec<u8> = (0..w * h).flat_map(|i| rgb(i % w, i / w)).collect();
    let f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut e = png::Encoder::new(f, w as u32, h as u32);
    e.set_color(png::ColorType::Rgb);
    e.set_depth(png::BitDepth::Eight);
    e.write_header().unwrap().write_image_data(&data).unwrap();
}

pub(crate) fn build_colour(dir: &Path, img: &Path, like: Option<&Path>, name: &str) -> PathBuf {
    let out = dir.join(name);
    let mut args = vec![
        "build".to_string(),
        s(img),
        "--colour".into(),
        "-o".into(),
        s(&out),
        "--max-error".into(),
        "2".into(),
        "--quiet".into(),
    ];
    if let Some(l) = like {
        args.extend(["--like".into(), s(l)]);
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = cbdam(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    out
}

/// Pixels that are clearly red and clearly blue, and their mean x.
fn red_and_blue(path: &Path) -> ((usize, f64), (usize, f64)) {
    let (w, _, px) = read_rgba_png(path);
    let (mut red, mut blue) = ((0, 0.0), (0, 0.0));
    for (i, p) in px.chunks(4).enumerate() {
        let [r, g, b] = [p[0], p[1], p[2]].map(f64::from);
        let x = (i % w as usize) as f64;
        if r > 2.0 * g && r > 2.0 * b {
            red = (red.0 + 1, red.1 + x);
        } else if b > 2.0 * r && b > 1.5 * g {
            blue = (blue.0 + 1, blue.1 + x);
        }
    }
    let mean = |(n, sum): (usize, f64)| (n, sum / n.max(1) as f64);
    (mean(red), mean(blue))
}

fn render(repo: &str, colour: Option<&str>, out: &Path) -> std::process::Output {
    let o = s(out);
    let mut args = vec!["render", repo, "--size", "200x120", "-o", &o];
    if let Some(c) = colour {
        args.extend(["--colour", c]);
    }
    cbdam(&args)
}

#[test]
fn render_drapes_the_colour_locally_and_over_http_and_refuses_misfits() {
    let dir = tempfile::tempdir().unwrap();
    let elev = jacksboro_at("2");
    let img = dir.path().join("ortho.png");
    write_png(&img, W, H, |x, _| if x < W / 2 { RED } else { BLUE });
    let colour = build_colour(dir.path(), &img, Some(&elev), "ortho.cbdam");

    let plain = dir.path().join("plain.png");
    let o = render(&s(&elev), None, &plain);
    assert!(o.status.success(), "{}", stderr(&o));
    let draped = dir.path().join("draped.png");
    let o = render(&s(&elev), Some(&s(&colour)), &draped);
    assert!(o.status.success(), "{}", stderr(&o));

    // 200 × 120 pixels, of which the terrain covers about 4 000 in the overview from the south,
    // the west (red) on the left.
    let ((red, red_x), (blue, blue_x)) = red_and_blue(&draped);
    assert!(red > 1000 && blue > 1000, "red {red}, blue {blue}");
    assert!(
        red_x < 90.0 && blue_x > 110.0,
        "red at {red_x}, blue at {blue_x}"
    );
    // The height ramp (greens, tans, greys) and the sky are neither.
    let ((red, _), (blue, _)) = red_and_blue(&plain);
    assert!(red == 0 && blue == 0, "plain: red {red}, blue {blue}");

    // Over HTTP: both repositories from one `cbdam serve`, the same bytes.
    let (mut server, addr) = spawn_serve(&[&format!("j={}", s(&elev)), &s(&colour)]);
    let remote = dir.path().join("remote.png");
    let o = render(
        &format!("http://{addr}/v1/repos/j"),
        Some(&format!("http://{addr}/v1/repos/ortho")),
        &remote,
    );
    let mixed = dir.path().join("mixed.png");
    let o2 = render(
        &s(&elev),
        Some(&format!("http://{addr}/v1/repos/ortho")),
        &mixed,
    );
    let _ = server.kill();
    let _ = server.wait();
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(o2.status.success(), "{}", stderr(&o2));
    let local = std::fs::read(&draped).unwrap();
    assert!(std::fs::read(&remote).unwrap() == local, "remote differs");
    assert!(std::fs::read(&mixed).unwrap() == local, "mixed differs");

    // Misfits: an elevation given as the colour, and a colour of another domain.
    let other_img = dir.path().join("other.png");
    write_png(&other_img, 300, 200, |_, _| RED);
    let other = build_colour(dir.path(), &other_img, None, "other.cbdam");
    for (c, want) in [
        (&elev, "is an elevation repository, not a colour one"),
        (&other, "does not cover the elevation's domain"),
        (&dir.path().join("missing.cbdam"), "missing.cbdam"),
    ] {
        let out = dir.path().join("misfit.png");
        let o = render(&s(&elev), Some(&s(c)), &out);
        assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
        assert!(stderr(&o).contains(want), "{}", stderr(&o));
        assert!(!out.exists());
    }
    // The colour given as the terrain is refused too.
    let out = dir.path().join("swapped.png");
    let o = render(&s(&colour), Some(&s(&colour)), &out);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("the terrain repository is a colour repository"),
        "{}",
        stderr(&o)
    );
}

/// `replay --colour` refines the same cut and fetches the colour records with the elevation's.
#[test]
fn replay_fetches_colour_with_the_elevation() {
    let dir = tempfile::tempdir().unwrap();
    let elev = jacksboro_at("2");
    let img = dir.path().join("ortho.png");
    write_png(&img, W, H, |x, y| [(x % 256) as u8, (y % 256) as u8, 90]);
    let colour = build_colour(dir.path(), &img, Some(&elev), "ortho.cbdam");
    let flight = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/flights/descent.json");
    let run = |colour: Option<&Path>, csv: &Path| {
        let mut args = vec![
            "replay".to_string(),
            s(&elev),
            "--path".into(),
            s(&flight),
            "--out".into(),
            s(csv),
            "--size".into(),
            "320x180".into(),
            "--budget-ms".into(),
            "0".into(),
        ];
        if let Some(c) = colour {
            args.extend(["--colour".into(), s(c)]);
        }
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = cbdam(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        let text = std::fs::read_to_string(csv).unwrap();
        let header: Vec<String> = text
            .lines()
            .next()
            .unwrap()
            .split(',')
            .map(String::from)
            .collect();
        let col = |name: &str| header.iter().position(|h| h == name).unwrap();
        let rows: Vec<Vec<String>> = text
            .lines()
            .skip(1)
            .map(|l| l.split(',').map(String::from).collect())
            .collect();
        let last = rows.last().unwrap();
        let cut: Vec<String> = rows
            .iter()
            .map(|r| r[col("diamonds_in_cut")].clone())
            .collect();
        (cut, last[col("bytes_fetched")].parse::<u64>().unwrap())
    };
    let (cut_plain, bytes_plain) = run(None, &dir.path().join("plain.csv"));
    let (cut_draped, bytes_draped) = run(Some(&colour), &dir.path().join("draped.csv"));
    assert_eq!(cut_plain, cut_draped, "the colour changed the refinement");
    assert!(
        bytes_draped > bytes_plain,
        "{bytes_draped} vs {bytes_plain}"
    );
}
