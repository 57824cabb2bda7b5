//! `cbdam build --colour` end to end: build over an elevation repository (`--like`), verify in
//! RGB, inspect the kind; bad images and mismatched sizes fail cleanly without leaving files.

use std::path::Path;

use crate::util::*;
use cbdam_codec::colour::reconstruct_rgb;
use cbdam_codec::hierarchy::RepoKind;
use cbdam_codec::repository::Repository;

fn write_asc(path: &Path, w: usize, h: usize) {
    let mut t = format!("ncols {w}\nnrows {h}\nxllcorner 0\nyllcorner 0\ncellsize 1\n");
    for y in 0..h {
        let row: Vec<String> = (0..w)
            .map(|x| format!("{}", 100 + ((x * 7 + y * 3) % 23) + x / 2))
            .collect();
        t += &row.join(" ");
        t.push('\n');
    }
    std::fs::write(path, t).unwrap();
}

/// Colour regions with noise: a hillside-like ramp plus distinct blocks.
fn pixels(w: usize, h: usize) -> Vec<[u8; 3]> {
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let n = ((i * 2654435761) >> 7) % 7;
            match (x * 2 / w, y * 2 / h) {
                (0, 0) => [200, 40 + n as u8, 30],
                (1, 0) => [30, 160, 50 + n as u8],
                (0, _) => [(x * 255 / w) as u8, (y * 255 / h) as u8, 90 + n as u8],
                _ => [40, 70, 210 - n as u8],
            }
        })
        .collect()
}

fn write_png(
    path: &Path,
    w: usize,
    h: usize,
    color: png::ColorType,
    depth: png::BitDepth,
    data: &[u8],
) {
    let f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut e = png::Encoder::new(f, w as u32, h as u32);
    e.set_color(color);
    e.set_depth(depth);
    e.write_header().unwrap().write_image_data(data).unwrap();
}

fn write_rgb(path: &Path, w: usize, h: usize) -> Vec<[u8; 3]> {
    let px = pixels(w, h);
    let data: Vec<u8> = px.iter().flatten().copied().collect();
    write_png(path, w, h, png::ColorType::Rgb, png::BitDepth::Eight, &data);
    px
}

#[test]
fn colour_build_verify_inspect_over_an_elevation() {
    let dir = tempfile::tempdir().unwrap();
    let dem = dir.path().join("dem.asc");
    write_asc(&dem, 33, 25);
    let elev = s(&dir.path().join("dem.cbdam"));
    run_ok(&[
        "build",
        &s(&dem),
        "-o",
        &elev,
        "--max-error",
        "1",
        "--diamond-size",
        "9",
        "--quiet",
    ]);
    // Twice the elevation's resolution: (33 − 1)·2 + 1 × (25 − 1)·2 + 1.
    let img = dir.path().join("ortho.png");
    let px = write_rgb(&img, 65, 49);
    for max_error in ["0", "4", "10"] {
        let out = s(&dir.path().join(format!("ortho{max_error}.cbdam")));
        run_ok(&[
            "build",
            &s(&img),
            "--colour",
            "--like",
            &elev,
            "-o",
            &out,
            "--max-error",
            max_error,
        ]);
        let repo = Repository::open(Path::new(&out)).unwrap();
        assert_eq!(repo.head().kind(), RepoKind::Colour);
        // --like took the elevation's diamond size, not the default 65.
        assert_eq!(repo.head().params().layout().n(), 9);
        let rgb = reconstruct_rgb(&repo.to_encoded().unwrap()).unwrap();
        let worst = rgb
            .iter()
            .zip(&px)
            .flat_map(|(a, b)| {
                (0..3).map(move |c| (i32::from(a[c]) - i32::from(b[c])).unsigned_abs())
            })
            .max()
            .unwrap();
        let bound: u32 = max_error.parse().unwrap();
        assert!(worst <= bound, "{max_error}: {worst}");
        let said = run_ok(&["verify", &out, "--against", &s(&img)]);
        assert!(said.contains("OK"), "{said}");
        let said = run_ok(&["inspect", &out]);
        assert!(said.contains("kind            colour"), "{said}");
        let said = run_ok(&["inspect", &out, "--json"]);
        assert!(said.contains("\"kind\": \"colour\""), "{said}");
    }
    // verify catches an image that is not the one built from.
    let other = dir.path().join("other.png");
    let mut moved = pixels(65, 49);
    moved[100] = [moved[100][0] ^ 0x80, 0, 0];
    let data: Vec<u8> = moved.iter().flatten().copied().collect();
    write_png(
        &other,
        65,
        49,
        png::ColorType::Rgb,
        png::BitDepth::Eight,
        &data,
    );
    run_refused(
        &[
            "verify",
            &s(&dir.path().join("ortho4.cbdam")),
            "--against",
            &s(&other),
        ],
        &[],
    );
    // The elevation inspect says elevation.
    let said = run_ok(&["inspect", &elev]);
    assert!(said.contains("kind            elevation"), "{said}");
}

#[test]
fn bad_colour_inputs_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let dem = dir.path().join("dem.asc");
    write_asc(&dem, 33, 25);
    let elev = s(&dir.path().join("dem.cbdam"));
    run_ok(&[
        "build",
        &s(&dem),
        "-o",
        &elev,
        "--max-error",
        "1",
        "--diamond-size",
        "9",
        "--quiet",
    ]);
    let grey = dir.path().join("grey.png");
    write_png(
        &grey,
        8,
        8,
        png::ColorType::Grayscale,
        png::BitDepth::Eight,
        &[7u8; 64],
    );
    let deep = dir.path().join("deep.png");
    write_png(
        &deep,
        8,
        8,
        png::ColorType::Rgb,
        png::BitDepth::Sixteen,
        &[7u8; 8 * 8 * 6],
    );
    let wrong = dir.path().join("wrong.png");
    write_rgb(&wrong, 64, 49);
    let good = dir.path().join("good.png");
    write_rgb(&good, 33, 25);
    let out = dir.path().join("out.cbdam");
    let cases: [(&Path, &[&str], &str); 6] = [
        (&grey, &[], "greyscale"),
        (&deep, &[], "16-bit"),
        (&wrong, &["--like", &elev], "(W − 1)·2^m + 1"),
        (&good, &["--like", &s(&grey)], "grey.png"),
        (&good, &[], "whole number"),
        (
            &good,
            &["--like", &s(&dir.path().join("missing.cbdam"))],
            "missing.cbdam",
        ),
    ];
    for (i, (input, extra, want)) in cases.into_iter().enumerate() {
        let max_error = if i == 4 { "2.5" } else { "4" };
        let mut args = vec!["build", "--colour", "-o"];
        let o_s = s(&out);
        let in_s = s(input);
        args.extend([o_s.as_str(), in_s.as_str(), "--max-error", max_error]);
        args.extend_from_slice(extra);
        run_refused(&args, &[want]);
        assert!(!out.exists(), "case {i} left a file");
    }
    // --like on an elevation build is refused rather than ignored.
    run_refused(
        &[
            "build",
            &s(&dem),
            "-o",
            &s(&out),
            "--max-error",
            "1",
            "--like",
            &elev,
        ],
        &["--colour"],
    );
}
