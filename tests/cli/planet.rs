//! `cbdam build --planet` and `cbdam verify` on planets: geographic and UTM GeoTIFFs resampled
//! onto the cube-sphere, the finest input winning, the L∞ bound exact at every level against the
//! resampled lattice and the resampling error measured against the inputs' samples; inputs that
//! cannot be placed are refused by name, leaving nothing behind.

use std::path::{Path, PathBuf};

use cbdam_builder::write::{Raster, write_geotiff};
use cbdam_codec::geodesy::{LatLon, Utm};
use cbdam_codec::repository::GeoRef;

use crate::util::{cbdam, check_refused, s, stderr, stdout};

/// A smooth relief over the globe, single-valued at the poles: linear in the direction of the
/// point, ±1000 m towards 0° E on the equator, ±300 m towards the poles.
fn relief(ll: LatLon) -> f64 {
    let (lat, lon) = (ll.lat.to_radians(), ll.lon.to_radians());
    1000.0 * lat.cos() * lon.cos() + 300.0 * lat.sin() + 500.0
}

/// A hill of 300 m, 2° wide, at 45° N 15° E.
fn hill(ll: LatLon) -> f64 {
    let d2 = (ll.lat - 45.0).powi(2) + (ll.lon - 15.0).powi(2);
    300.0 * (-d2 / 2.0).exp()
}

fn write(path: &Path, (w, h): (usize, usize), georef: GeoRef, at: impl Fn(usize, usize) -> f64) {
    let values = (0..w * h).map(|i| at(i % w, i / w)).collect();
    let r = Raster {
        width: w,
        height: h,
        values,
        georef: Some(georef),
    };
    write_geotiff(std::fs::File::create(path).unwrap(), &r, None, false).unwrap();
}

fn geographic(origin: (f64, f64), pixel: f64) -> GeoRef {
    GeoRef {
        epsg: Some(4326),
        origin_x: origin.0,
        origin_y: origin.1,
        pixel_x: pixel,
        pixel_y: pixel,
        pixel_is_area: false,
        wkt: None,
    }
}

/// The global grid: 2° pixel-is-point samples, longitudes 0 … 358 (it wraps), latitudes 90 … −90.
fn write_global(path: &Path) {
    write(path, (180, 91), geographic((0.0, 90.0), 2.0), |c, r| {
        relief(LatLon {
            lat: 90.0 - 2.0 * r as f64,
            lon: 2.0 * c as f64,
        })
    });
}

/// Reads `name: N of M samples compared; resampling error … max X m` from verify's output.
fn compared_and_max(out: &str, name: &str) -> (u64, u64, f64) {
    let line = out
        .lines()
        .find(|l| l.contains(name) && l.contains("resampling error"))
        .unwrap_or_else(|| panic!("no line for {name} in\n{out}"));
    let num = |after: &str| -> f64 {
        let rest = &line[line.find(after).unwrap() + after.len()..];
        let t: String = rest
            .trim_start()
            .chars()
            .take_while(|c| c.is_ascii_digit() || *c == '.')
            .collect();
        t.parse().unwrap()
    };
    let compared = num(": ") as u64;
    let of = num(" of ") as u64;
    (compared, of, num("max "))
}

#[test]
fn a_planet_from_a_global_grid_a_finer_inset_and_a_utm_tile_verifies() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let global = d.join("global.tif");
    write_global(&global);
    // The inset: 0.25° over 40…50° N, 10…20° E, the relief plus a hill the global grid lacks.
    let inset = d.join("inset.tif");
    write(&inset, (41, 41), geographic((10.0, 50.0), 0.25), |c, r| {
        let ll = LatLon {
            lat: 50.0 - 0.25 * r as f64,
            lon: 10.0 + 0.25 * c as f64,
        };
        relief(ll) + hill(ll)
    });
    // A UTM tile (zone 33 N, 2 km pixels, 120 km square, near 30° N 15° E: finer than the
    // lattice, so area-averaged) whose samples are
    // the relief at each pixel's latitude and longitude (the inverse of UTM, itself checked
    // against GeographicLib): misplacing it (wrong zone, axes, hemisphere) shows as error.
    let utm = Utm::from_epsg(32633).unwrap();
    let utm_tif = d.join("utm33.tif");
    let (e0, n0) = (440_000.0, 3_380_000.0);
    let utm_georef = GeoRef {
        epsg: Some(32633),
        origin_x: e0,
        origin_y: n0,
        pixel_x: 2000.0,
        pixel_y: 2000.0,
        pixel_is_area: false,
        wkt: None,
    };
    write(&utm_tif, (61, 61), utm_georef, |c, r| {
        relief(utm.inverse(e0 + 2000.0 * c as f64, n0 - 2000.0 * r as f64))
    });
    let out = d.join("planet.cbdam");
    let o = cbdam(&[
        "build",
        &s(&global),
        &s(&inset),
        &s(&utm_tif),
        "--planet",
        "--diamond-size",
        "17",
        "--planet-level",
        "5",
        "-o",
        &s(&out),
        "--max-error",
        "2",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    // 90°/(16·2^5) = 0.176° lattice: finer than the inset (bilinear), coarser than the UTM
    // tile's 2 km (area-averaged).
    assert!(text.contains("K = 5"), "{text}");
    assert!(text.contains("cube-sphere"), "{text}");
    // The 2° global grid is 11 lattice steps wide: sampled on every 8th point (1.41°), the
    // hierarchy ends at level 10 − 6 = 4 where it is the finest data (variable resolution);
    // the inset (0.25°) and the UTM tile are sampled at every point.
    assert!(
        text.lines()
            .any(|l| l.contains("global.tif is coarser than the lattice")
                && l.contains("every 8-step")
                && l.contains("level 4 of 10")),
        "{text}"
    );
    assert!(!text.contains("inset.tif is coarser"), "{text}");

    let o = cbdam(&[
        "verify",
        &s(&out),
        "--against",
        &s(&global),
        &s(&inset),
        &s(&utm_tif),
    ]);
    let text = stdout(&o);
    assert!(o.status.success(), "{text}\n{}", stderr(&o));
    assert!(text.contains("OK"), "{text}");
    // Every level within the bound against the resampled lattice, all 11 levels listed.
    assert!(text.contains("max error") && text.lines().any(|l| l.trim_start().starts_with("10 ")));

    // The finest input wins where it lies: its samples are compared (all but its edges, where
    // a lattice cell reaches past it) and the global grid's samples under it are not.
    let (inset_compared, inset_samples, inset_max) = compared_and_max(&text, "inset.tif");
    assert_eq!(inset_samples, 41 * 41);
    assert!(inset_compared > 1000, "{text}");
    let (global_compared, global_samples, global_max) = compared_and_max(&text, "global.tif");
    assert_eq!(global_samples, 180 * 91);
    assert!(global_compared < global_samples, "{text}");
    let (utm_compared, _, utm_max) = compared_and_max(&text, "utm33.tif");
    assert!(utm_compared > 2000, "{text}");
    // The relief is smooth: linear interpolation over a 2° input and its 1.41° lattice stride
    // is off by (h²/8)·|f''| ≤ (0.035²/8)·1000 m ≈ 0.15 m per step, twice, plus half a unit,
    // and averaging 2 km pixels over a 20 km cell by (w²/24)·|f''| ≈ 0.01 m; geocentric
    // instead of geodetic latitudes would add up to 0.19° × 17 m/° ≈ 3 m, a mirrored or
    // shifted input hundreds of metres.
    assert!(
        global_max < 1.0,
        "global resampling error {global_max} m\n{text}"
    );
    assert!(utm_max < 1.0, "UTM resampling error {utm_max} m\n{text}");
    // The inset's hill is sharper: |f''| ≤ 300 m/deg², so bilinear over 0.25° samples then
    // over lattice cells of at most 0.2° is off by at most 2·(0.25² + 0.2²)/8 · 300 ≈ 7.7 m.
    assert!(
        inset_max < 7.7,
        "inset resampling error {inset_max} m\n{text}"
    );

    // inspect shows the domain, the datum and the resampling error the build measured, the
    // largest of the three inputs' (the same figure verify measured again above).
    let o = cbdam(&["inspect", &s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let shown = stdout(&o);
    assert!(shown.contains("cube-sphere"), "{shown}");
    assert!(shown.contains("vertical datum  orthometric"), "{shown}");
    let worst = global_max.max(inset_max).max(utm_max);
    assert!(
        shown.contains(&format!("max {worst:.3} m")),
        "expected max {worst:.3} m in\n{shown}"
    );
}

#[test]
fn inputs_a_planet_cannot_place_are_refused_by_name() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let global = d.join("global.tif");
    write_global(&global);
    // Lambert-93 (EPSG:2154) is projected but not UTM.
    let lambert = d.join("lambert.tif");
    let mut g = geographic((700_000.0, 6_600_000.0), 1000.0);
    g.epsg = Some(2154);
    write(&lambert, (8, 8), g, |_, _| 10.0);
    let out = d.join("p.cbdam");
    let o = cbdam(&[
        "build",
        &s(&global),
        &s(&lambert),
        "--planet",
        "-o",
        &s(&out),
        "--max-error",
        "1",
    ]);
    check_refused(&o, "build --planet", &["lambert.tif", "EPSG:2154", "UTM"]);
    assert!(!out.exists());

    // A lattice finer than the level pairs a planet has is refused by name (the memory limit
    // does not bound the lattice: it is encoded block by block).
    let o = cbdam(&[
        "build",
        &s(&global),
        "--planet",
        "--planet-level",
        "17",
        "-o",
        &s(&out),
        "--max-error",
        "1",
    ]);
    check_refused(&o, "build --planet", &["--planet-level 17", "at most 16"]);
    assert!(!out.exists());
}

/// Two 0.5° tiles sharing their edge column (as SRTM tiles do), 50° … 40° N, 0° … 10° E and
/// 10° … 20° E, and a GDAL VRT placing them; `shift` moves the second tile's `DstRect` that many
/// columns (a VRT that disagrees with the tile's own georeferencing).
fn write_tiles_and_vrt(d: &Path, shift: usize) -> std::path::PathBuf {
    for (name, lon0) in [("a.tif", 0.0), ("b.tif", 10.0)] {
        write(
            &d.join(name),
            (21, 21),
            geographic((lon0, 50.0), 0.5),
            |c, r| {
                let ll = LatLon {
                    lat: 50.0 - 0.5 * r as f64,
                    lon: lon0 + 0.5 * c as f64,
                };
                relief(ll) + hill(ll)
            },
        );
    }
    let source = |name: &str, x: usize| {
        format!(
            r#"    <SimpleSource>
      <SourceFilename relativeToVRT="1">{name}</SourceFilename>
      <SourceBand>1</SourceBand>
      <SrcRect xOff="0" yOff="0" xSize="21" ySize="21" />
      <DstRect xOff="{x}" yOff="0" xSize="21" ySize="21" />
    </SimpleSource>
"#
        )
    };
    // PixelIsArea, as GDAL writes it: the origin is the first sample's north-west corner.
    let vrt = format!(
        r#"<VRTDataset rasterXSize="{}" rasterYSize="21">
  <SRS>EPSG:4326</SRS>
  <GeoTransform> -0.25, 0.5, 0, 50.25, 0, -0.5</GeoTransform>
  <VRTRasterBand dataType="Float32" band="1">
{}{}  </VRTRasterBand>
</VRTDataset>
"#,
        41 + shift,
        source("a.tif", 0),
        source("b.tif", 20 + shift)
    );
    let path = d.join("tiles.vrt");
    std::fs::write(&path, vrt).unwrap();
    path
}

/// A VRT of tiles builds the planet its tiles build, byte for byte; a VRT that places a tile
/// elsewhere than the tile's own georeferencing says is refused naming both; hundreds of inputs
/// build as well as a few.
#[test]
fn a_vrt_of_tiles_builds_the_planet_of_its_tiles() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let global = d.join("global.tif");
    write_global(&global);
    let vrt = write_tiles_and_vrt(d, 0);
    let build = |inputs: &[&Path], out: &Path| {
        let mut args = vec!["build".to_string()];
        args.extend(inputs.iter().map(|p| s(p)));
        args.extend(
            ["--planet", "--planet-level", "3", "--max-error", "2", "-o"].map(String::from),
        );
        args.push(s(out));
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        cbdam(&args)
    };
    let (from_tiles, from_vrt) = (d.join("tiles.cbdam"), d.join("vrt.cbdam"));
    let o = build(&[&global, &d.join("a.tif"), &d.join("b.tif")], &from_tiles);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = build(&[&global, &vrt], &from_vrt);
    assert!(o.status.success(), "{}", stderr(&o));
    let (a, b) = (
        std::fs::read(&from_tiles).unwrap(),
        std::fs::read(&from_vrt).unwrap(),
    );
    assert!(
        a == b,
        "the VRT's planet differs from its tiles' ({} vs {} bytes)",
        b.len(),
        a.len()
    );
    // The inset was used: its samples were compared in the resampling error.
    assert!(
        stdout(&o).contains("resampling error of") && stdout(&o).contains("b.tif"),
        "{}",
        stdout(&o)
    );

    let vrt = write_tiles_and_vrt(d, 2);
    let out = d.join("shifted.cbdam");
    let o = build(&[&global, &vrt], &out);
    check_refused(&o, "build --planet", &["tiles.vrt", "b.tif"]);
    assert!(!out.exists());

    // More inputs than a byte can tell apart (the limit until winners took 16 bits): 300
    // copies of the first tile, the first of which wins wherever it lies, build the planet of
    // one copy, byte for byte.
    let list = d.join("many.txt");
    let line = format!("{}\n", s(&d.join("a.tif")));
    std::fs::write(&list, line.repeat(300)).unwrap();
    let (one, many) = (d.join("one.cbdam"), d.join("many.cbdam"));
    let o = build(&[&global, &d.join("a.tif")], &one);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = build(&[&global, Path::new(&format!("@{}", s(&list)))], &many);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        std::fs::read(&one).unwrap() == std::fs::read(&many).unwrap(),
        "300 copies of a tile build another planet than one copy"
    );
}

/// The bundled global DEM with a bundled 3″ tile as an inset: every level of the planet within
/// the bound against the resampled lattice, and the decoded surface within bound + resampling
/// error of every compared sample of both inputs (`verify` refuses otherwise).
#[test]
fn etopo5_with_an_srtm_inset_verifies_on_every_level() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("earth.cbdam");
    let (etopo, srtm) = (
        crate::util::data("etopo5_global.tif"),
        crate::util::data("srtm3_demcompare.tif"),
    );
    let o = cbdam(&[
        "build",
        &etopo,
        &srtm,
        "--planet",
        "--diamond-size",
        "17",
        "--planet-level",
        "5",
        "-o",
        &s(&out),
        "--max-error",
        "5",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = cbdam(&["verify", &s(&out), "--against", &etopo, &srtm]);
    let text = stdout(&o);
    assert!(o.status.success(), "{text}\n{}", stderr(&o));
    assert!(text.contains("OK"), "{text}");
    // A 0.18° lattice: ETOPO5's 5′ area-averaged, the 0.83° tile of 3″ data area-averaged
    // into a few cells, whose inner cells are compared against its samples.
    let (srtm_compared, srtm_samples, _) = compared_and_max(&text, "srtm3_demcompare.tif");
    assert_eq!(srtm_samples, 1_000_000);
    assert!(srtm_compared > 0, "{text}");
    let (etopo_compared, etopo_samples, _) = compared_and_max(&text, "etopo5_global.tif");
    assert_eq!(etopo_samples, 4320 * 2161);
    assert!(etopo_compared > etopo_samples / 2, "{text}");
    // The bundled planet flight (geodetic keyframes, orbit to the SRTM tile's summit) replays
    // on it and ends where its last keyframe says, over the tile.
    let csv = tmp.path().join("replay.csv");
    let flight = crate::util::data("flights/planet/descent.json");
    let o = cbdam(&[
        "replay",
        &s(&out),
        "--path",
        &flight,
        "--size",
        "640x360",
        "--out",
        &s(&csv),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let rows = std::fs::read_to_string(&csv).unwrap();
    assert!(rows.lines().count() > 15 * 30, "{rows}");
    // extract writes planar rasters: a planet is refused by name, nothing written.
    let tif = tmp.path().join("x.tif");
    let o = cbdam(&["extract", &s(&out), "-o", &s(&tif)]);
    check_refused(&o, "build --planet", &["is a planet"]);
    assert!(!tif.exists());
}

/// A 0.005° inset (18″) in the 2° global grid builds at its own lattice, K = 11 (0.0027°, a
/// face of 32 768 steps: 6.4·10⁹ lattice points, 155 GB at the build's 24 B a point if held
/// whole): the faces are held in tiles, every point only around the inset and every 512th
/// elsewhere. The build says so, verify finds every level within the bound and the inset's
/// samples within bound + resampling error, and a memory limit below what the tiles need
/// still caps the lattice, naming it.
#[test]
fn a_fine_inset_builds_at_its_own_lattice_holding_only_the_points_around_it() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let global = d.join("global.tif");
    write_global(&global);
    let inset = d.join("inset.tif");
    write(&inset, (41, 41), geographic((14.9, 45.1), 0.005), |c, r| {
        let ll = LatLon {
            lat: 45.1 - 0.005 * r as f64,
            lon: 14.9 + 0.005 * c as f64,
        };
        relief(ll) + hill(ll)
    });
    let out = d.join("planet.cbdam");
    let build = |limit: &str| {
        cbdam(&[
            "build",
            &s(&global),
            &s(&inset),
            "--planet",
            "--diamond-size",
            "17",
            "--memory-limit",
            limit,
            "-o",
            &s(&out),
            "--max-error",
            "1",
        ])
    };
    let o = build("256M");
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    // 90°/(16·2^11) = 0.0027° ≤ 0.005° < 0.0055° (K = 10).
    assert!(
        text.contains("K = 11") && text.contains("6442450946 lattice points"),
        "{text}"
    );
    assert!(!text.contains("capped"), "{text}");
    // What the tiles held: the inset's few dense tiles of 1025² points (one to four, and
    // their neighbours within the inset's margin), 9 points in each other tile.
    let held: u64 = text
        .lines()
        .find_map(|l| l.trim_start().strip_prefix("the build held "))
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no held points in\n{text}"));
    assert!((50_000..10_000_000).contains(&held), "{held}\n{text}");
    // The 2° grid is every 512th lattice point: it ends the hierarchy at level 22 − 18.
    assert!(
        text.lines()
            .any(|l| l.contains("global.tif is coarser") && l.contains("level 4 of 22")),
        "{text}"
    );

    let o = cbdam(&["verify", &s(&out), "--against", &s(&global), &s(&inset)]);
    let text = stdout(&o);
    assert!(o.status.success(), "{text}\n{}", stderr(&o));
    assert!(text.contains("OK"), "{text}");
    assert!(
        text.lines().any(|l| l.trim_start().starts_with("22 ")),
        "{text}"
    );
    let (compared, samples, inset_max) = compared_and_max(&text, "inset.tif");
    assert_eq!(samples, 41 * 41);
    assert!(compared > 1000, "{text}");
    // Bilinear over 0.005° samples and again over cells of at most 0.004° on the hill (|f''| ≤
    // 300 m/deg²) is off by 2·(0.005² + 0.004²)/8 · 300 m ≈ 3 mm; the lattice's integer
    // heights add up to half a unit (at most 1 m here).
    assert!(
        inset_max < 0.6,
        "inset resampling error {inset_max} m\n{text}"
    );
    let (global_compared, _, global_max) = compared_and_max(&text, "global.tif");
    assert!(global_compared > 10_000, "{text}");
    assert!(global_max < 1.0, "{text}");

    // The inset cut into 8 × 8 tiles of 6 × 6 samples sharing their edge rows and columns
    // (as SRTM's do): each lattice tile asks only the small inputs whose rectangles reach its
    // points, and the planet is the same (its records and roots; the header's resampling
    // figures count samples per input, so they differ).
    let mut cut = vec![s(&global)];
    for tr in 0..8 {
        for tc in 0..8 {
            let tile = d.join(format!("t{tr}{tc}.tif"));
            let (lat0, lon0) = (45.1 - 0.025 * tr as f64, 14.9 + 0.025 * tc as f64);
            write(&tile, (6, 6), geographic((lon0, lat0), 0.005), |c, r| {
                let ll = LatLon {
                    lat: 45.1 - 0.005 * (5 * tr + r) as f64,
                    lon: 14.9 + 0.005 * (5 * tc + c) as f64,
                };
                relief(ll) + hill(ll)
            });
            cut.push(s(&tile));
        }
    }
    let tiled = d.join("tiled.cbdam");
    let mut args: Vec<&str> = vec!["build"];
    args.extend(cut.iter().map(String::as_str));
    args.extend(["--planet", "--diamond-size", "17", "--max-error", "1", "-o"]);
    let tiled_s = s(&tiled);
    args.push(&tiled_s);
    let o = cbdam(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("K = 11"), "{}", stdout(&o));
    let open = |p: &Path| {
        cbdam_codec::repository::Repository::open(p)
            .unwrap()
            .to_encoded()
            .unwrap()
    };
    let (whole, pieces) = (open(&out), open(&tiled));
    assert!(
        whole.records == pieces.records && whole.roots == pieces.roots,
        "the inset cut into 64 tiles builds another planet ({} and {} records)",
        whole.records.len(),
        pieces.records.len()
    );

    // Far below what the lattice's tiles hold, the lattice keeps the finest input's level (it
    // is encoded block by block) and the repository its bytes.
    let bytes = std::fs::read(&out).unwrap();
    let o = build("16M");
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    assert!(
        text.contains("K = 11") && !text.contains("--planet-level"),
        "{text}"
    );
    assert!(
        std::fs::read(&out).unwrap() == bytes,
        "16M built other bytes"
    );
}

/// A 0.005° inset centred on a cube corner (45° E, 35.446° N geodetic: three faces meet there)
/// builds at its own lattice (K = 11) with the tiles of all three faces around the corner
/// asking it: its samples are compared wherever the lattice points around them took its heights
/// (all but its outer ring, where a lattice cell reaches past it), with the resampling error of
/// a smooth relief, and every level verifies. A face whose tiles did not ask the inset would
/// leave the global grid's heights under its part of the inset: those samples would go
/// uncompared, or compared against the wrong heights.
#[test]
fn an_inset_on_a_cube_corner_is_resampled_on_all_three_faces() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let global = d.join("global.tif");
    write_global(&global);
    let inset = d.join("corner.tif");
    let (lat0, lon0) = (35.446 + 0.1, 45.0 - 0.1);
    write(&inset, (41, 41), geographic((lon0, lat0), 0.005), |c, r| {
        relief(LatLon {
            lat: lat0 - 0.005 * r as f64,
            lon: lon0 + 0.005 * c as f64,
        })
    });
    let out = d.join("planet.cbdam");
    let o = cbdam(&[
        "build",
        &s(&global),
        &s(&inset),
        "--planet",
        "--diamond-size",
        "17",
        "-o",
        &s(&out),
        "--max-error",
        "1",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("K = 11"), "{}", stdout(&o));
    let o = cbdam(&["verify", &s(&out), "--against", &s(&global), &s(&inset)]);
    let text = stdout(&o);
    assert!(o.status.success(), "{text}\n{}", stderr(&o));
    let (compared, samples, max) = compared_and_max(&text, "corner.tif");
    assert_eq!(samples, 41 * 41);
    // The 39 × 39 inner samples at least (the outer ring's cells may reach past the inset).
    assert!(
        compared >= 39 * 39,
        "{compared} of {samples} compared\n{text}"
    );
    // Bilinear twice over cells of at most 0.005° on a relief with |f''| ≤ 1300 m/rad² ≈
    // 0.4 m/deg²: micrometres; half a unit (0.0625 m) of rounding dominates.
    assert!(max < 0.1, "resampling error {max} m\n{text}");
}

/// An inset without georeferencing placed on the planet with `--bounds`/`--crs` (its outer
/// edges, GDAL's convention) builds the same planet, byte for byte, as the same inset carrying
/// that georeferencing; `verify` takes the same flags. Given when every input has its own, or
/// when two inputs have none, the flags are refused naming why, and nothing is written.
#[test]
fn bounds_and_crs_place_an_ungeoreferenced_planet_input() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let global = d.join("global.tif");
    write_global(&global);
    // 40 × 40 cells of 0.0125° (exact in binary) over 14.75…15.25° E, 44.75…45.25° N.
    let height = |c: usize, r: usize| {
        let ll = LatLon {
            lat: 45.25 - 0.0125 * (r as f64 + 0.5),
            lon: 14.75 + 0.0125 * (c as f64 + 0.5),
        };
        relief(ll) + hill(ll)
    };
    let placed = d.join("placed.tif");
    let mut georef = geographic((14.75, 45.25), 0.0125);
    georef.pixel_is_area = true;
    write(&placed, (40, 40), georef, height);
    let bare = d.join("bare.tif");
    let r = Raster {
        width: 40,
        height: 40,
        values: (0..1600).map(|i| height(i % 40, i / 40)).collect(),
        georef: None,
    };
    write_geotiff(std::fs::File::create(&bare).unwrap(), &r, None, false).unwrap();
    let build = |inputs: &[&Path], extra: &[&str], out: &Path| {
        let mut args = vec!["build".to_string()];
        args.extend(inputs.iter().map(|p| s(p)));
        args.extend(["--planet", "--diamond-size", "17", "--max-error", "1"].map(String::from));
        args.extend(extra.iter().map(|a| a.to_string()));
        args.extend(["-o".to_string(), s(out)]);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        cbdam(&args)
    };
    let flags = ["--bounds", "14.75,44.75,15.25,45.25", "--crs", "EPSG:4326"];
    let (a, b) = (d.join("a.cbdam"), d.join("b.cbdam"));
    let o = build(&[&global, &placed], &[], &a);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("K = 9"), "{}", stdout(&o));
    let o = build(&[&global, &bare], &flags, &b);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(),
        "the inset placed by --bounds builds another planet than the georeferenced one"
    );
    let mut args = vec!["verify", &s(&b), "--against", &s(&global), &s(&bare)]
        .into_iter()
        .map(String::from)
        .collect::<Vec<_>>();
    args.extend(flags.map(String::from));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = cbdam(&args);
    let text = stdout(&o);
    assert!(o.status.success(), "{text}\n{}", stderr(&o));
    let (compared, _, _) = compared_and_max(&text, "bare.tif");
    assert!(compared > 1000, "{text}");
    // Without the flags the bare input cannot be placed.
    let o = cbdam(&["verify", &s(&b), "--against", &s(&global), &s(&bare)]);
    check_refused(
        &o,
        "build --planet",
        &["bare.tif carries no georeferencing"],
    );

    let out = d.join("refused.cbdam");
    let o = build(&[&global, &placed], &flags, &out);
    check_refused(&o, "build --planet", &["every input here has its own"]);
    let bare2 = d.join("bare2.tif");
    std::fs::copy(&bare, &bare2).unwrap();
    let o = build(&[&global, &bare, &bare2], &flags, &out);
    check_refused(&o, "build --planet", &["bare.tif", "bare2.tif"]);
    assert!(!out.exists());
}

/// `cbdam build --planet` encodes the lattice block by block, resampling each tile as a block
/// asks for it, under any memory limit: its repository is byte for byte the one the whole
/// lattice — resampled at once, encoded whole, its resampling error measured over it — writes,
/// with insets astride a cube edge (with a void) and on a cube corner over a global grid.
/// The inputs of a small planet with a void and fine insets on a cube edge and corner: a 2°
/// global grid with a void (nodata) over 60° … 70° N, 100° … 120° E; a 0.005° inset astride the
/// edge between the faces centred on 0° E and 90° E with a void of 5 × 5 samples; and one on a
/// cube corner. Built at N = 17 it is K = 11, 7.4 M points held.
pub(crate) fn edge_and_corner_planet(d: &Path) -> [PathBuf; 3] {
    // The global grid with a void (nodata) over 60° … 70° N, 100° … 120° E.
    let global = d.join("global.tif");
    let r = Raster {
        width: 180,
        height: 91,
        values: (0..180 * 91)
            .map(|i| {
                let (lat, lon) = (90.0 - 2.0 * (i / 180) as f64, 2.0 * (i % 180) as f64);
                if (60.0..=70.0).contains(&lat) && (100.0..=120.0).contains(&lon) {
                    -9999.0
                } else {
                    relief(LatLon { lat, lon })
                }
            })
            .collect(),
        georef: Some(geographic((0.0, 90.0), 2.0)),
    };
    write_geotiff(
        std::fs::File::create(&global).unwrap(),
        &r,
        Some(-9999.0),
        false,
    )
    .unwrap();
    // Astride the edge between the faces centred on 0° E and 90° E (45° E on the equator),
    // with a void of 5 × 5 samples.
    let edge = d.join("edge.tif");
    let r = Raster {
        width: 21,
        height: 21,
        values: (0..21 * 21)
            .map(|i| {
                let (c, r) = (i % 21, i / 21);
                if (8..13).contains(&c) && (3..8).contains(&r) {
                    -9999.0
                } else {
                    relief(LatLon {
                        lat: 0.05 - 0.005 * r as f64,
                        lon: 44.95 + 0.005 * c as f64,
                    })
                }
            })
            .collect(),
        georef: Some(geographic((44.95, 0.05), 0.005)),
    };
    write_geotiff(
        std::fs::File::create(&edge).unwrap(),
        &r,
        Some(-9999.0),
        false,
    )
    .unwrap();
    let corner = d.join("corner.tif");
    let (lat0, lon0) = (35.446 + 0.05, 45.0 - 0.05);
    write(
        &corner,
        (21, 21),
        geographic((lon0, lat0), 0.005),
        |c, r| {
            relief(LatLon {
                lat: lat0 - 0.005 * r as f64,
                lon: lon0 + 0.005 * c as f64,
            }) + 10.0 * ((c * 7 + r * 3) % 5) as f64
        },
    );
    [global, edge, corner]
}

#[test]
fn a_planet_built_block_by_block_is_the_planet_encoded_whole() {
    use cbdam_builder::planet::{PlanetInputs, provenance_of, resample, resampling_error};
    use cbdam_codec::hierarchy::{EncodeOptions, encode_planet};
    use cbdam_codec::quant::QuantPlan;
    use cbdam_codec::repository::write_planet_repository;
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let paths = edge_and_corner_planet(d);
    let mut args: Vec<String> = vec!["build".into()];
    args.extend(paths.iter().map(|p| s(p)));
    for a in ["--planet", "--diamond-size", "17", "--max-error", "1"] {
        args.push(a.into());
    }
    // Under 4 MiB the lattice (7.4 M points held) does not fit whole; under 8 GiB it does.
    let mut outputs = Vec::new();
    for (limit, path) in [("4M", "(block by block)"), ("8G", "(whole lattice)")] {
        let out = d.join(format!("planet-{limit}.cbdam"));
        let mut args = args.clone();
        args.extend(["--timings", "--memory-limit", limit, "-o", &s(&out)].map(String::from));
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = cbdam(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        assert!(stdout(&o).contains("K = 11"), "{}", stdout(&o));
        assert!(stderr(&o).contains(path), "{limit}: {}", stderr(&o));
        if limit == "4M" {
            assert_blocks_follow_the_data(&stderr(&o));
        }
        outputs.push(std::fs::read(&out).unwrap());
    }
    assert!(
        outputs[0] == outputs[1],
        "the two paths wrote different bytes"
    );

    let tiles = cbdam_builder::tiles::expand_inputs(&paths).unwrap();
    let inputs = PlanetInputs::read(&tiles, None, None, u64::MAX).unwrap();
    let (lo, hi) = inputs.range().unwrap().unwrap();
    let plan = QuantPlan::new(1.0, None, lo, hi).unwrap();
    let resampled = resample(&inputs, 17, 11, &plan).unwrap();
    assert!(resampled.planet.has_nodata());
    let opts = EncodeOptions {
        n: 17,
        ..EncodeOptions::default()
    };
    let encoded = encode_planet(&resampled.planet, plan.quantizer, &opts).unwrap();
    let provenance = provenance_of(&resampling_error(&inputs, &resampled, &plan).unwrap());
    let whole = d.join("whole.cbdam");
    write_planet_repository(&whole, &encoded, &plan, None, &provenance).unwrap();
    let (a, b) = (std::fs::read(&whole).unwrap(), outputs.remove(0));
    assert!(
        a == b,
        "block by block {} bytes, whole {} bytes",
        b.len(),
        a.len()
    );
}

/// The blocks follow the data, not the cube: the two 0.1° insets make a few fine lattice tiles
/// of the 6·32² at K = 11 (N = 17: tiles of 1 024 steps, 0.0027° each), the 2° grid elsewhere
/// holds 3 × 3 points a tile, so the coarse faces are a block or a few each and all the
/// blocks together are a small fraction of the tiles (one journal file each).
fn assert_blocks_follow_the_data(timings: &str) {
    let line = timings
        .lines()
        .find(|l| l.starts_with("encoded in "))
        .unwrap_or_else(|| panic!("no block count in {timings}"));
    let words: Vec<&str> = line.split_whitespace().collect();
    let (blocks, tiles): (usize, usize) = (words[2].parse().unwrap(), words[7].parse().unwrap());
    assert_eq!(tiles, 6 * 32 * 32, "{line}");
    assert!(blocks >= 6 && blocks * 20 <= tiles, "{line}");
}

/// A planet built block by block keeps a journal of finished blocks: killed (SIGKILL) before
/// any block and after some, it resumes when run again and writes the same bytes as a build
/// that was never interrupted; no output is left under its name meanwhile, and the journal is
/// gone once the repository is written. Run again with another tolerance, it starts over and
/// says why.
#[test]
fn a_killed_planet_build_resumes_and_writes_the_same_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let paths = edge_and_corner_planet(d);
    let args = |out: &Path, eps: &str| -> Vec<String> {
        let mut a: Vec<String> = vec!["build".into()];
        a.extend(paths.iter().map(|p| s(p)));
        a.extend(
            [
                "--planet",
                "--diamond-size",
                "17",
                "--max-error",
                eps,
                "--memory-limit",
                "4M",
                "-o",
                &s(out),
            ]
            .map(String::from),
        );
        a
    };
    let run = |out: &Path, eps: &str| {
        let a = args(out, eps);
        let o = cbdam(&a.iter().map(String::as_str).collect::<Vec<_>>());
        assert!(o.status.success(), "{}", stderr(&o));
        o
    };
    let whole = d.join("whole.cbdam");
    run(&whole, "1");
    let expected = std::fs::read(&whole).unwrap();
    let out = d.join("killed.cbdam");
    let journal = d.join("killed.cbdam.journal");
    let blocks_done = || crate::util::journal_blocks(&journal);
    let kill_after_blocks =
        |n: usize| crate::util::kill_after_blocks(&args(&out, "1"), &journal, n);
    for n in [0, 1, 3] {
        kill_after_blocks(n);
        assert!(!out.exists(), "a killed build left {}", out.display());
    }
    let before = blocks_done();
    let o = run(&out, "1");
    assert!(
        stderr(&o).contains(&format!("resuming: {before} blocks")),
        "{}",
        stderr(&o)
    );
    assert!(
        std::fs::read(&out).unwrap() == expected,
        "the resumed planet differs"
    );
    assert!(!journal.exists(), "the journal outlived the build");
    // Killed again, then run with another tolerance: it starts over, naming the change.
    kill_after_blocks(1);
    let o = run(&out, "2");
    assert!(
        stderr(&o).contains("starting over") && stderr(&o).contains("max_error"),
        "{}",
        stderr(&o)
    );
}
