//! `cbdam tiles`: a repository's web-map tiles as static files, byte for byte what `cbdam
//! serve` answers; an export run again keeps what is there; bad arguments refused by name.

use std::io::{Read, Write};
use std::path::Path;

use crate::util::*;

/// The body of an HTTP/1.1 GET of `path` on `addr` (`connection: close`), asking for gzip.
fn get_body(addr: &str, path: &str) -> Vec<u8> {
    let mut t = std::net::TcpStream::connect(addr).unwrap();
    write!(
        t,
        "GET {path} HTTP/1.1\r\nhost: x\r\naccept-encoding: gzip\r\naccept: \
         application/vnd.quantized-mesh;extensions=octvertexnormals-metadata\r\n\
         connection: close\r\n\r\n"
    )
    .unwrap();
    let mut resp = Vec::new();
    t.read_to_end(&mut resp).unwrap();
    let end = resp.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
    let head = String::from_utf8_lossy(&resp[..end]).to_string();
    assert!(head.starts_with("HTTP/1.1 200"), "{path}: {head}");
    assert!(!head.contains("chunked"), "{path}: a sized body expected");
    resp[end + 4..].to_vec()
}

fn gunzip(b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    flate2::read::GzDecoder::new(b)
        .read_to_end(&mut out)
        .unwrap();
    out
}

fn export(repo: &Path, out: &Path, format: &str, extra: &[&str]) -> String {
    let (repo, out) = (s(repo), s(out));
    let mut args = vec!["tiles", &repo, "--format", format, "-o", &out];
    args.extend_from_slice(extra);
    let o = cbdam(&args);
    assert!(o.status.success(), "{args:?}: {}", stderr(&o));
    stdout(&o)
}

/// Every file under `dir` with extension `ext`.
fn files(dir: &Path, ext: &str) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(files(&p, ext));
        } else if p.extension().is_some_and(|e| e == ext) {
            out.push(p);
        }
    }
    out
}

#[test]
fn exported_tiles_are_what_serve_answers() {
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro_at("2");
    let (png_dir, qm_dir) = (dir.path().join("png"), dir.path().join("qm"));
    let said = export(&repo, &png_dir, "terrarium", &["--max-zoom", "8"]);
    assert!(said.contains("tiles written (0 already there)"), "{said}");
    let tj: serde_json::Value =
        serde_json::from_slice(&std::fs::read(png_dir.join("tiles.json")).unwrap()).unwrap();
    assert_eq!(tj["tiles"][0], "{z}/{x}/{y}.png");
    assert_eq!(tj["encoding"], "terrarium");
    let pngs = files(&png_dir, "png");
    // One tile a level until the data spans a tile boundary.
    assert!(pngs.len() >= 9, "{} tiles", pngs.len());
    export(&repo, &qm_dir, "quantized-mesh", &["--max-zoom", "9"]);
    let terrains = files(&qm_dir, "terrain");
    assert!(terrains.len() >= 10, "{} tiles", terrains.len());
    // Run again: nothing to do.
    let again = export(&repo, &png_dir, "terrarium", &["--max-zoom", "8"]);
    assert!(again.contains(": 0 tiles written"), "{again}");
    let (mut server, addr) = spawn_serve(&[&format!("j={}", s(&repo))]);
    for p in pngs.iter().chain(&terrains) {
        let rel = p.strip_prefix(if p.starts_with(&png_dir) {
            &png_dir
        } else {
            &qm_dir
        });
        let rel = rel.unwrap().to_str().unwrap().to_string();
        let kind = if rel.ends_with(".png") {
            "terrarium"
        } else {
            "quantized-mesh"
        };
        let served = get_body(&addr, &format!("/v1/repos/j/{kind}/{rel}"));
        let file = std::fs::read(p).unwrap();
        if kind == "terrarium" {
            assert_eq!(served, file, "{rel}");
        } else if rel.starts_with("9/") {
            // The export stops at level 9: its tiles there list no children, the served ones
            // do. Everything before the metadata is the same.
            let (served, file) = (gunzip(&served), gunzip(&file));
            let (a, b) = (metadata_at(&served), metadata_at(&file));
            assert_eq!(served[..a], file[..b], "{rel}");
            assert!(a > 88 && served[a..] != file[b..], "{rel}");
        } else {
            assert_eq!(gunzip(&served), gunzip(&file), "{rel}");
        }
    }
    server.kill().unwrap();
    server.wait().unwrap();
}

#[test]
fn bad_tile_arguments_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let repo = shared_planet();
    let out = dir.path().join("t");
    let o = cbdam(&[
        "tiles",
        &s(&repo),
        "--format",
        "terrarium",
        "-o",
        &s(&out),
        "--tile",
        "300",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("tile size 300"), "{}", stderr(&o));
    let o = cbdam(&["tiles", &s(&repo), "--format", "webp", "-o", &s(&out)]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    // A planet is tiled whole: two root tiles at level 0; this one's 33-point faces (313 km
    // between samples) have nothing finer to give, so --max-zoom stops at its maxzoom, 0.
    let said = export(&repo, &out, "quantized-mesh", &["--max-zoom", "3"]);
    assert!(said.contains("levels 0…0"), "{said}");
    assert_eq!(files(&out, "terrain").len(), 2);
}

/// A file `…/{z}/{x}/{y}.terrain`'s tile.
fn tile_of(path: &Path) -> (u32, u32, u32) {
    let part = |p: Option<&std::ffi::OsStr>| -> u32 {
        let text = p.unwrap().to_str().unwrap();
        text.trim_end_matches(".terrain").parse().unwrap()
    };
    let y = part(path.file_name());
    let x = part(path.parent().unwrap().file_name());
    let z = part(path.parent().unwrap().parent().unwrap().file_name());
    (z, x, y)
}

/// Whether geographic tile `z/x/y` meets box `b` (west, south, east, north) with an area.
fn meets((z, x, y): (u32, u32, u32), b: [f64; 4]) -> bool {
    let size = 180.0 / f64::from(1u32 << z);
    let (w, s) = (-180.0 + f64::from(x) * size, -90.0 + f64::from(y) * size);
    w < b[2] && b[0] < w + size && s < b[3] && b[1] < s + size
}

#[test]
fn a_bbox_exports_only_the_tiles_meeting_it() {
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro(dir.path());
    let (all_dir, part_dir) = (dir.path().join("all"), dir.path().join("part"));
    export(&repo, &all_dir, "quantized-mesh", &["--max-zoom", "10"]);
    let layer = |d: &Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(d.join("layer.json")).unwrap()).unwrap()
    };
    let b: Vec<f64> = serde_json::from_value(layer(&all_dir)["bounds"].clone()).unwrap();
    // The data's western third, and a box reaching past its south edge.
    let bbox = [b[0], b[1] - 1.0, b[0] + (b[2] - b[0]) / 3.0, b[3]];
    let arg = format!("{},{},{},{}", bbox[0], bbox[1], bbox[2], bbox[3]);
    export(
        &repo,
        &part_dir,
        "quantized-mesh",
        &["--max-zoom", "10", "--bbox", &arg],
    );
    let stated: Vec<f64> = serde_json::from_value(layer(&part_dir)["bounds"].clone()).unwrap();
    assert_eq!(
        stated,
        [b[0], b[1], bbox[2], b[3]],
        "the part of the data in the box"
    );
    let mut all: Vec<_> = files(&all_dir, "terrain")
        .iter()
        .map(|p| tile_of(p))
        .collect();
    let mut part: Vec<_> = files(&part_dir, "terrain")
        .iter()
        .map(|p| tile_of(p))
        .collect();
    all.sort_unstable();
    part.sort_unstable();
    let want: Vec<_> = all
        .iter()
        .copied()
        .filter(|&t| t.0 == 0 || meets(t, bbox))
        .collect();
    assert_eq!(part, want, "the tiles meeting the box, and both roots");
    assert!(
        part.len() < all.len() && part.len() > 12,
        "{} of {}",
        part.len(),
        all.len()
    );
    // Raster tiles too: their document states the part of the data in the box.
    let png = dir.path().join("png");
    export(
        &repo,
        &png,
        "terrarium",
        &["--max-zoom", "9", "--bbox", &arg],
    );
    let tj: serde_json::Value =
        serde_json::from_slice(&std::fs::read(png.join("tiles.json")).unwrap()).unwrap();
    let stated: Vec<f64> = serde_json::from_value(tj["bounds"].clone()).unwrap();
    assert_eq!(stated, [b[0], b[1], bbox[2], b[3]]);
    assert!(!files(&png, "png").is_empty());
}

#[test]
fn bad_boxes_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro(dir.path());
    let out = dir.path().join("t");
    for (bbox, said) in [
        ("1,2,3", "3 values"),
        ("a,0,1,1", "west `a` is not a number"),
        ("-98,33,-99,34", "west -98° is not west of east -99°"),
        ("-98,34,-97,33", "south 34° is not south of north 33°"),
        ("-98,33,-97,95", "north 95° is outside ±90°"),
        ("0,0,1,1", "does not meet the data"),
    ] {
        let args = [
            "tiles",
            &s(&repo),
            "--format",
            "terrarium",
            "-o",
            &s(&out),
            "--bbox",
            bbox,
        ];
        let o = cbdam(&args);
        assert!(!o.status.success(), "{bbox} accepted");
        assert!(stderr(&o).contains(said), "{bbox}: {}", stderr(&o));
        assert!(!stderr(&o).contains("panicked"), "{bbox}: {}", stderr(&o));
    }
}

/// `--image webp`: `.webp` files, what `cbdam serve` answers for them, listed by a `tiles.json`
/// whose URLs end in `.webp`; refused with quantized-mesh, naming why.
#[test]
fn webp_exports_are_what_serve_answers() {
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro_at("2");
    let out = dir.path().join("webp");
    export(
        &repo,
        &out,
        "terrain-rgb",
        &["--max-zoom", "7", "--image", "webp"],
    );
    let tj: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("tiles.json")).unwrap()).unwrap();
    assert_eq!(tj["tiles"][0], "{z}/{x}/{y}.webp");
    let webps = files(&out, "webp");
    assert!(webps.len() >= 8, "{} tiles", webps.len());
    assert!(files(&out, "png").is_empty());
    let (mut server, addr) = spawn_serve(&[&format!("j={}", s(&repo))]);
    for p in &webps {
        let rel = p.strip_prefix(&out).unwrap().to_str().unwrap().to_string();
        let served = get_body(&addr, &format!("/v1/repos/j/terrain-rgb/{rel}"));
        let file = std::fs::read(p).unwrap();
        assert!(
            file.starts_with(b"RIFF") && file[8..12] == *b"WEBP",
            "{rel}"
        );
        assert_eq!(served, file, "{rel}");
    }
    server.kill().unwrap();
    server.wait().unwrap();
    let qm = dir.path().join("qm");
    let (repo, qm) = (s(&repo), s(&qm));
    let args = ["tiles", &repo, "--format", "quantized-mesh", "-o", &qm];
    let o = cbdam(&[&args[..], &["--image", "webp"]].concat());
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("--image webp is for raster tiles"),
        "{}",
        stderr(&o)
    );
}

/// `-o OUT.pmtiles`: one archive, moved into place whole (no `.partial` left), addressing as
/// many tiles as the directory export writes (its tiles, byte for byte, are checked with an
/// independent reader by scripts/web-maps/pmtiles_check.py); quantized-mesh and a directory
/// named `.pmtiles` are refused by name.
#[test]
fn pmtiles_archives_are_written_whole_and_mesh_tiles_refused() {
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro_at("2");
    let (archive, tiles) = (dir.path().join("p.pmtiles"), dir.path().join("t"));
    export(&repo, &tiles, "terrarium", &["--quiet", "--max-zoom", "7"]);
    let exported = files(&tiles, "png").len() as u64;
    export(
        &repo,
        &archive,
        "terrarium",
        &["--quiet", "--max-zoom", "7"],
    );
    let bytes = std::fs::read(&archive).unwrap();
    assert_eq!(&bytes[..8], b"PMTiles\x03");
    let addressed = u64::from_le_bytes(bytes[72..80].try_into().unwrap());
    assert_eq!(
        (addressed, bytes[99]),
        (exported, 2),
        "tiles addressed, tile type PNG"
    );
    assert!(exported >= 5, "only {exported} tiles");
    assert!(!dir.path().join("p.pmtiles.partial").exists());
    let o = cbdam(&[
        "tiles",
        &s(&repo),
        "--format",
        "quantized-mesh",
        "-o",
        &s(&archive),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("not written to PMTiles"),
        "{}",
        stderr(&o)
    );
    let folder = dir.path().join("d.pmtiles");
    std::fs::create_dir(&folder).unwrap();
    let o = cbdam(&[
        "tiles",
        &s(&repo),
        "--format",
        "terrarium",
        "-o",
        &s(&folder),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("is a directory"), "{}", stderr(&o));
}

#[test]
fn attribution_is_the_flags_in_every_document_the_export_writes() {
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro_at("2");
    let credit = ["--quiet", "--max-zoom", "2", "--attribution", "USGS 3DEP"];
    let read = |p: &Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
    };
    export(&repo, &dir.path().join("t"), "terrarium", &credit);
    assert_eq!(
        read(&dir.path().join("t/tiles.json"))["attribution"],
        "USGS 3DEP"
    );
    export(&repo, &dir.path().join("q"), "quantized-mesh", &credit);
    assert_eq!(
        read(&dir.path().join("q/layer.json"))["attribution"],
        "USGS 3DEP"
    );
    // In a PMTiles archive, in its metadata (gzip JSON at the header's offset and length).
    let archive = dir.path().join("p.pmtiles");
    export(&repo, &archive, "terrain-rgb", &credit);
    let bytes = std::fs::read(&archive).unwrap();
    let at = |i: usize| u64::from_le_bytes(bytes[i..i + 8].try_into().unwrap()) as usize;
    let (offset, length) = (at(24), at(32));
    let meta: serde_json::Value =
        serde_json::from_slice(&gunzip(&bytes[offset..offset + length])).unwrap();
    assert_eq!(meta["attribution"], "USGS 3DEP");
    // Without the flag: what the repository records of itself.
    export(&repo, &dir.path().join("d"), "quantized-mesh", &credit[..3]);
    let own = read(&dir.path().join("d/layer.json"))["attribution"].clone();
    assert!(
        own.as_str().unwrap().starts_with("cbdam repository "),
        "{own}"
    );
}

/// Where the metadata extension of a `.terrain` tile's bytes begins (its id byte, then its
/// u32 length, then the u32 length of its JSON, which runs to the end).
fn metadata_at(raw: &[u8]) -> usize {
    (0..raw.len() - 4)
        .rev()
        .find(|&k| {
            let len = u32::from_le_bytes(raw[k..k + 4].try_into().unwrap()) as usize;
            k >= 5 && len == raw.len() - k - 4 && raw[k + 4] == b'{' && raw[k - 5] == 4
        })
        .expect("a metadata extension")
        - 5
}

/// The metadata extension's JSON of a gzip `.terrain` file.
fn mesh_metadata(path: &Path) -> serde_json::Value {
    let raw = gunzip(&std::fs::read(path).unwrap());
    serde_json::from_slice(&raw[metadata_at(&raw) + 9..]).unwrap()
}

/// The tiles `(z, x, y)` a list of levels of tile rectangles holds (`available`), level `z0`
/// first.
fn listed(levels: &serde_json::Value, z0: u32) -> Vec<(u32, u32, u32)> {
    let at = |r: &serde_json::Value, k: &str| r[k].as_u64().unwrap() as u32;
    let mut out = Vec::new();
    for (z, level) in levels.as_array().unwrap().iter().enumerate() {
        for r in level.as_array().unwrap() {
            for x in at(r, "startX")..=at(r, "endX") {
                out.extend((at(r, "startY")..=at(r, "endY")).map(|y| (z0 + z as u32, x, y)));
            }
        }
    }
    out
}

/// `--max-zoom` below the format's own maxzoom: the documents' `maxzoom` is it, `layer.json`'s
/// `available` lists exactly the tiles written and no mesh tile's metadata lists a child that
/// was not written (a viewer asks for no missing tile); the level where the stated bounds hold
/// is given as `finest_zoom`.
#[test]
fn a_lowered_max_zoom_lists_only_the_tiles_written() {
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro(dir.path());
    let (qm, png) = (dir.path().join("qm"), dir.path().join("png"));
    export(&repo, &qm, "quantized-mesh", &["--max-zoom", "6"]);
    export(&repo, &png, "terrarium", &["--max-zoom", "7"]);
    let read = |p: &Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
    };
    let layer = read(&qm.join("layer.json"));
    assert_eq!(layer["maxzoom"], 6);
    assert!(
        layer["cbdam"]["finest_zoom"].as_u64().unwrap() > 6,
        "{layer}"
    );
    let mut stated = listed(&layer["available"], 0);
    let written_files = files(&qm, "terrain");
    let mut written: Vec<_> = written_files.iter().map(|p| tile_of(p)).collect();
    stated.sort_unstable();
    written.sort_unstable();
    assert_eq!(stated, written, "layer.json's available against the files");
    for p in &written_files {
        let (z, _, _) = tile_of(p);
        for child in listed(&mesh_metadata(p)["available"], z + 1) {
            assert!(written.contains(&child), "{p:?} lists {child:?}");
        }
    }
    let tj = read(&png.join("tiles.json"));
    assert_eq!(tj["maxzoom"], 7);
    assert!(tj["cbdam"]["finest_zoom"].as_u64().unwrap() > 7, "{tj}");
}

/// An export run again into a directory holding another export (another format's encoding, or
/// another `--max-zoom`, whose deepest tiles list no children) is refused naming the fields
/// that differ, and changes nothing; the same export run again goes on.
#[test]
fn an_export_into_another_exports_directory_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro(dir.path());
    let out = dir.path().join("t");
    export(&repo, &out, "terrarium", &["--max-zoom", "6"]);
    let before = files(&out, "png").len();
    let doc = std::fs::read(out.join("tiles.json")).unwrap();
    for (format, max, differ) in [
        ("terrain-rgb", "6", "encoding"),
        ("terrarium", "7", "maxzoom"),
    ] {
        let (r, o) = (s(&repo), s(&out));
        let args = ["tiles", &r, "--format", format, "-o", &o, "--max-zoom", max];
        run_refused(
            &args,
            &["holds another export", differ, "remove the directory"],
        );
        assert_eq!(files(&out, "png").len(), before, "{format} {max}");
        assert!(std::fs::read(out.join("tiles.json")).unwrap() == doc);
    }
    let again = export(&repo, &out, "terrarium", &["--max-zoom", "6"]);
    assert!(again.contains(": 0 tiles written"), "{again}");
}
