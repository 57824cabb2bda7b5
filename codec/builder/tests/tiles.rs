//! Tile inputs: a DEM cut into georeferenced tiles that share their edge rows (as SRTM and
//! GLO-30 tiles do) builds byte-identical to the same DEM as one file, whether the tiles come as
//! a directory, a glob, an `@list` or a GDAL VRT; disagreeing tiles, unsupported VRTs and empty
//! inputs are refused by name.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_builder::tiles::expand_inputs;
use cbdam_builder::verify::{MosaicComparison, compare_tiles_whole, compare_tiles_with};
use cbdam_builder::write::{Raster, write_geotiff};
use cbdam_builder::{BuildOptions, NoProgress, build};
use cbdam_codec::hierarchy::BlockPlan;
use cbdam_codec::repository::GeoRef;
use cbdam_codec::repository::Repository;

use crate::util::data;

/// Tile side in samples between shared edges: a tile is `T + 1` samples square.
const T: usize = 128;
/// Tiles per side: the mosaic is `3T + 1` samples square.
const GRID: usize = 3;
const SIDE: usize = GRID * T + 1;
const NODATA: f64 = -32768.0;

/// The north-west `SIDE × SIDE` samples of the bundled SRTM DEM and their georeferencing.
fn source() -> (Vec<f64>, GeoRef) {
    let dem = read_dem(&data("srtm3_demcompare.tif"), &ReadOptions::default()).unwrap();
    let mut v = Vec::with_capacity(SIDE * SIDE);
    for r in 0..SIDE {
        v.extend_from_slice(&dem.values[r * dem.width..r * dem.width + SIDE]);
    }
    (v, dem.georef.unwrap())
}

fn write(path: &Path, w: usize, h: usize, values: Vec<f64>, georef: Option<GeoRef>, nd: bool) {
    let r = Raster {
        width: w,
        height: h,
        values,
        georef,
    };
    let file = std::fs::File::create(path).unwrap();
    write_geotiff(file, &r, nd.then_some(NODATA), false).unwrap();
}

/// Where tile (row `tr`, column `tc`) starts, in the whole DEM's georeferencing.
fn tile_georef(g: &GeoRef, tr: usize, tc: usize) -> GeoRef {
    GeoRef {
        origin_x: g.origin_x + (tc * T) as f64 * g.pixel_x,
        origin_y: g.origin_y - (tr * T) as f64 * g.pixel_y,
        ..g.clone()
    }
}

/// Cuts `values` into the `GRID × GRID` tiles (each `T + 1` square, sharing edge rows and
/// columns with its neighbours) for which `keep(tr, tc)` holds, written as `rRcC.tif` into `dir`
/// (so that name order is row-major, the north-west tile first); with `georef` false the tiles
/// carry no georeferencing. Returns the tiles' paths in that order.
fn cut(
    dir: &Path,
    values: &[f64],
    g: &GeoRef,
    keep: impl Fn(usize, usize) -> bool,
    georef: bool,
    nd: bool,
) -> Vec<PathBuf> {
    std::fs::create_dir_all(dir).unwrap();
    let mut paths = Vec::new();
    for tr in 0..GRID {
        for tc in 0..GRID {
            if !keep(tr, tc) {
                continue;
            }
            let mut v = Vec::with_capacity((T + 1) * (T + 1));
            for r in tr * T..=tr * T + T {
                v.extend_from_slice(&values[r * SIDE + tc * T..=r * SIDE + tc * T + T]);
            }
            let path = dir.join(format!("r{tr}c{tc}.tif"));
            write(
                &path,
                T + 1,
                T + 1,
                v,
                georef.then(|| tile_georef(g, tr, tc)),
                nd,
            );
            paths.push(path);
        }
    }
    paths
}

/// A gdalbuildvrt-style VRT over `tiles` (file names relative to the VRT), `extra` spliced into
/// each source.
fn vrt(path: &Path, g: &GeoRef, tiles: &[(String, usize, usize)], extra: &str, nd: bool) {
    let mut x = String::new();
    writeln!(
        x,
        r#"<VRTDataset rasterXSize="{SIDE}" rasterYSize="{SIDE}">"#
    )
    .unwrap();
    writeln!(
        x,
        r#"  <SRS dataAxisToSRSAxisMapping="2,1">GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],AXIS["Latitude",NORTH],AXIS["Longitude",EAST],AUTHORITY["EPSG","4326"]]</SRS>"#
    )
    .unwrap();
    // The whole DEM is PixelIsArea: its origin is the north-west corner, as GDAL's is.
    assert!(g.pixel_is_area);
    writeln!(
        x,
        "  <GeoTransform> {:e}, {:e}, 0, {:e}, 0, {:e}</GeoTransform>",
        g.origin_x, g.pixel_x, g.origin_y, -g.pixel_y
    )
    .unwrap();
    writeln!(x, r#"  <VRTRasterBand dataType="Float32" band="1">"#).unwrap();
    if nd {
        writeln!(x, "    <NoDataValue>{NODATA}</NoDataValue>").unwrap();
    }
    writeln!(x, "    <ColorInterp>Gray</ColorInterp>").unwrap();
    let n = T + 1;
    for (name, tr, tc) in tiles {
        let kind = if nd { "ComplexSource" } else { "SimpleSource" };
        writeln!(x, "    <{kind}>").unwrap();
        writeln!(
            x,
            r#"      <SourceFilename relativeToVRT="1">{name}</SourceFilename>"#
        )
        .unwrap();
        writeln!(x, "      <SourceBand>1</SourceBand>").unwrap();
        writeln!(
            x,
            r#"      <SourceProperties RasterXSize="{n}" RasterYSize="{n}" DataType="Float32" BlockXSize="{n}" BlockYSize="1" />"#
        )
        .unwrap();
        writeln!(
            x,
            r#"      <SrcRect xOff="0" yOff="0" xSize="{n}" ySize="{n}" />"#
        )
        .unwrap();
        writeln!(
            x,
            r#"      <DstRect xOff="{}" yOff="{}" xSize="{n}" ySize="{n}" />"#,
            tc * T,
            tr * T
        )
        .unwrap();
        if nd {
            writeln!(x, "      <NODATA>{NODATA}</NODATA>").unwrap();
        }
        x += extra;
        writeln!(x, "    </{kind}>").unwrap();
    }
    x += "  </VRTRasterBand>\n</VRTDataset>\n";
    std::fs::write(path, x).unwrap();
}

/// The VRT entries of the `rRcC.tif` tiles in `paths`.
fn entries(paths: &[PathBuf]) -> Vec<(String, usize, usize)> {
    paths
        .iter()
        .map(|p| {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            let b = name.as_bytes();
            (name.clone(), (b[1] - b'0') as usize, (b[3] - b'0') as usize)
        })
        .collect()
}

/// Builds `inputs` into `out` and returns the repository's bytes.
fn build_bytes(inputs: Vec<PathBuf>, out: &Path) -> Vec<u8> {
    build(
        &BuildOptions::new(inputs, out.to_path_buf(), 2.0),
        &NoProgress,
    )
    .unwrap_or_else(|e| panic!("building {}: {e}", out.display()));
    std::fs::read(out).unwrap()
}

fn build_error(inputs: Vec<PathBuf>, out: &Path) -> String {
    match build(
        &BuildOptions::new(inputs, out.to_path_buf(), 2.0),
        &NoProgress,
    ) {
        Ok(_) => panic!("{} built", out.display()),
        Err(e) => {
            assert!(!out.exists(), "a failed build left {}", out.display());
            e.to_string()
        }
    }
}

/// Every form of tile input builds the same bytes as the DEM they were cut from, as one file.
#[test]
fn tiles_with_shared_edges_build_like_one_file() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let (values, g) = source();
    let whole = d.join("whole.tif");
    write(&whole, SIDE, SIDE, values.clone(), Some(g.clone()), false);
    let want = build_bytes(vec![whole], &d.join("whole.cbdam"));

    let tiles = cut(&d.join("tiles"), &values, &g, |_, _| true, true, false);
    assert_eq!(tiles.len(), GRID * GRID);
    let dir = build_bytes(vec![d.join("tiles")], &d.join("dir.cbdam"));
    assert!(dir == want, "directory of tiles: different bytes");
    let glob = build_bytes(vec![d.join("tiles/r?c[0-2].tif")], &d.join("glob.cbdam"));
    assert!(glob == want, "glob of tiles: different bytes");
    // A list with a comment, a blank line and paths relative to the list, one of them through a
    // subdirectory's parent.
    let mut list = String::from("# the tiles\n\n");
    for p in &tiles {
        writeln!(
            list,
            "tiles/../tiles/{}",
            p.file_name().unwrap().to_string_lossy()
        )
        .unwrap();
    }
    std::fs::write(d.join("tiles.txt"), list).unwrap();
    let listed = build_bytes(
        vec![PathBuf::from(format!("@{}", d.join("tiles.txt").display()))],
        &d.join("list.cbdam"),
    );
    assert!(listed == want, "@list of tiles: different bytes");
    vrt(&d.join("tiles/all.vrt"), &g, &entries(&tiles), "", false);
    let v = build_bytes(vec![d.join("tiles/all.vrt")], &d.join("vrt.cbdam"));
    assert!(v == want, "VRT of tiles: different bytes");

    // Tiles without georeferencing of their own take the VRT's.
    let bare = cut(&d.join("bare"), &values, &g, |_, _| true, false, false);
    vrt(&d.join("bare/all.vrt"), &g, &entries(&bare), "", false);
    let v = build_bytes(vec![d.join("bare/all.vrt")], &d.join("bare.cbdam"));
    assert!(
        v == want,
        "VRT of tiles without georeferencing: different bytes"
    );
}

/// A missing tile leaves a hole and tiles hold nodata (one on an edge its neighbour shares,
/// which is not a disagreement): the same bytes as the DEM with the same holes as nodata.
#[test]
fn tiles_with_a_gap_and_nodata_build_like_one_file_with_holes() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let (mut values, g) = source();
    // Nodata inside tile (0, 0), and on the edge row that tiles (0, 2) and (1, 2) share — in
    // tile (0, 2) only, so tile (1, 2) provides those samples.
    let mut tiled = values.clone();
    for r in 10..20 {
        for c in 10..30 {
            tiled[r * SIDE + c] = NODATA;
        }
    }
    let missing = |tr: usize, tc: usize| (tr, tc) == (1, 1);
    let tiles = cut(
        &d.join("tiles"),
        &tiled,
        &g,
        |r, c| !missing(r, c),
        true,
        true,
    );
    let edge = T;
    let mut t02 = read_dem(&tiles[2], &ReadOptions::default()).unwrap();
    assert_eq!(tiles[2].file_name().unwrap(), "r0c2.tif");
    for c in 5..40 {
        t02.values[edge * (T + 1) + c] = NODATA;
    }
    write(&tiles[2], T + 1, T + 1, t02.values, t02.georef, true);

    // The one-file DEM: nodata where no tile has a valid sample.
    for r in 0..SIDE {
        for c in 0..SIDE {
            let inside = |tr: usize, tc: usize| {
                (tr * T..=tr * T + T).contains(&r) && (tc * T..=tc * T + T).contains(&c)
            };
            let covered = (0..GRID)
                .flat_map(|tr| (0..GRID).map(move |tc| (tr, tc)))
                .any(|(tr, tc)| !missing(tr, tc) && inside(tr, tc));
            if !covered || tiled[r * SIDE + c] == NODATA {
                values[r * SIDE + c] = NODATA;
            }
        }
    }
    let holes = values.iter().filter(|&&v| v == NODATA).count();
    // The centre tile's interior, and the nodata block.
    assert_eq!(holes, (T - 1) * (T - 1) + 10 * 20, "{holes}");
    let whole = d.join("whole.tif");
    write(&whole, SIDE, SIDE, values, Some(g.clone()), true);
    let want = build_bytes(vec![whole], &d.join("whole.cbdam"));

    let dir = build_bytes(vec![d.join("tiles")], &d.join("dir.cbdam"));
    assert!(
        dir == want,
        "directory of tiles with a gap: different bytes"
    );
    vrt(&d.join("all.vrt"), &g, &entries(&tiles), "", true);
    // The VRT is beside the directory: its sources name `tiles/…`.
    let mut e = entries(&tiles);
    for t in &mut e {
        t.0 = format!("tiles/{}", t.0);
    }
    vrt(&d.join("all.vrt"), &g, &e, "", true);
    let v = build_bytes(vec![d.join("all.vrt")], &d.join("vrt.cbdam"));
    assert!(v == want, "VRT of tiles with a gap: different bytes");
}

/// Tiles that disagree on a shared sample are refused, naming both, the count and the largest
/// difference; VRTs beyond the supported subset are refused naming the element or attribute;
/// empty directories, globs and lists are refused naming them.
#[test]
fn bad_tile_inputs_are_refused_by_name() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let out = d.join("out.cbdam");
    let (values, g) = source();
    let tiles = cut(&d.join("tiles"), &values, &g, |_, _| true, true, false);

    // Tile r1c1 shares its west column with r1c0: raise two of those samples, by 3 and 1.
    let mut t = read_dem(&tiles[4], &ReadOptions::default()).unwrap();
    assert_eq!(tiles[4].file_name().unwrap(), "r1c1.tif");
    t.values[5 * (T + 1)] += 3.0;
    t.values[9 * (T + 1)] -= 1.0;
    let bad = d.join("bad");
    std::fs::create_dir(&bad).unwrap();
    for p in &tiles {
        std::fs::copy(p, bad.join(p.file_name().unwrap())).unwrap();
    }
    write(
        &bad.join("r1c1.tif"),
        T + 1,
        T + 1,
        t.values,
        t.georef,
        false,
    );
    let e = build_error(vec![bad.clone()], &out);
    assert!(
        e.contains(&bad.join("r1c0.tif").display().to_string())
            && e.contains(&bad.join("r1c1.tif").display().to_string())
            && e.contains(&format!(
                "disagree on 2 of their {} shared samples by up to 3",
                T + 1
            )),
        "{e}"
    );

    // A corrupt tile and a tile in another CRS are named (and nothing is written).
    std::fs::write(bad.join("r1c1.tif"), b"II*\0 not a TIFF").unwrap();
    let e = build_error(vec![bad.clone()], &out);
    assert!(
        e.contains(&bad.join("r1c1.tif").display().to_string()),
        "{e}"
    );
    let mut utm = tile_georef(&g, 1, 1);
    utm.epsg = Some(32632);
    let v = read_dem(&tiles[4], &ReadOptions::default()).unwrap().values;
    write(&bad.join("r1c1.tif"), T + 1, T + 1, v, Some(utm), false);
    let e = build_error(vec![bad.clone()], &out);
    assert!(
        e.contains(&bad.join("r1c1.tif").display().to_string()) && e.contains("EPSG:32632"),
        "{e}"
    );

    // VRTs: each unsupported thing named.
    let all = entries(&tiles);
    for (extra, named) in [
        ("      <ScaleRatio>2</ScaleRatio>\n", "<ScaleRatio>"),
        ("      <LUT>0:0,1:1</LUT>\n", "<LUT>"),
    ] {
        let p = d.join("tiles/x.vrt");
        vrt(&p, &g, &all, extra, false);
        let e = build_error(vec![p.clone()], &out);
        assert!(
            e.contains(named) && e.contains(&p.display().to_string()),
            "{e}"
        );
    }
    let base = d.join("tiles/all.vrt");
    vrt(&base, &g, &all, "", false);
    let text = std::fs::read_to_string(&base).unwrap();
    let second_band = text.replace(
        "</VRTRasterBand>",
        "</VRTRasterBand>\n  <VRTRasterBand dataType=\"Float32\" band=\"2\"></VRTRasterBand>",
    );
    for (changed, named) in [
        (
            text.replace("<SimpleSource>", "<KernelizedSimpleSource>")
                .replace("</SimpleSource>", "</KernelizedSimpleSource>"),
            "<KernelizedSimpleSource>",
        ),
        (
            text.replace(
                "band=\"1\">",
                "band=\"1\" subClass=\"VRTDerivedRasterBand\">",
            ),
            "subClass=\"VRTDerivedRasterBand\"",
        ),
        (second_band, "second <VRTRasterBand>"),
        (
            text.replacen(
                &format!(
                    r#"<SrcRect xOff="0" yOff="0" xSize="{0}" ySize="{0}" />"#,
                    T + 1
                ),
                &format!(
                    r#"<SrcRect xOff="0" yOff="0" xSize="{0}" ySize="{0}" />"#,
                    T
                ),
                1,
            ),
            &format!("<SrcRect> {T}×{T} and <DstRect> {0}×{0}", T + 1),
        ),
        (
            text.replace(
                &format!(r#"xSize="{0}" ySize="{0}" />"#, T + 1),
                &format!(r#"xSize="{0}" ySize="{0}" />"#, T),
            ),
            "<SrcRect>/<DstRect> of",
        ),
        (
            text.replacen(
                r#"<DstRect xOff="0" yOff="0""#,
                r#"<DstRect xOff="1" yOff="0""#,
                1,
            ),
            "r0c0.tif with spacing",
        ),
    ] {
        std::fs::write(&base, changed).unwrap();
        let e = build_error(vec![base.clone()], &out);
        assert!(e.contains(named), "wanted {named:?} in: {e}");
    }

    // Empty inputs, missing and malformed list entries.
    let empty = d.join("empty");
    std::fs::create_dir(&empty).unwrap();
    std::fs::write(empty.join("notes.txt"), "not a DEM").unwrap();
    let e = build_error(vec![empty.clone()], &out);
    assert!(
        e.contains(&format!("directory {} holds no DEM", empty.display())),
        "{e}"
    );
    let e = build_error(vec![d.join("tiles/*.hgt")], &out);
    assert!(
        e.contains(&format!(
            "glob {} matches no file",
            d.join("tiles/*.hgt").display()
        )),
        "{e}"
    );
    for (list, named) in [
        ("# nothing\n\n", "names no file".to_string()),
        (
            "tiles/r0c0.tif\ntiles/r9c9.tif\n",
            format!(
                "line 2 of list @{}: {} does not exist",
                d.join("l.txt").display(),
                d.join("tiles/r9c9.tif").display()
            ),
        ),
        (
            "tiles/r0c0.tif\ntiles/r0\u{1}c1.tif\n",
            "line 2 of list".to_string(),
        ),
    ] {
        std::fs::write(d.join("l.txt"), list).unwrap();
        let e = build_error(
            vec![PathBuf::from(format!("@{}", d.join("l.txt").display()))],
            &out,
        );
        assert!(
            e.contains(&named) && e.contains("l.txt"),
            "wanted {named:?} in: {e}"
        );
    }
}

/// More tiles than the former cap of 253 inputs: 19 × 19 tiles of 51² samples sharing their
/// edges, listed in a directory, build the same bytes as the 951² DEM they were cut from.
#[test]
fn hundreds_of_tiles_build_like_one_file() {
    const T: usize = 50;
    const GRID: usize = 19;
    const SIDE: usize = GRID * T + 1;
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let dem = read_dem(&data("srtm3_demcompare.tif"), &ReadOptions::default()).unwrap();
    let g = dem.georef.clone().unwrap();
    let at = |r: usize, c: usize| dem.values[r * dem.width + c];
    let whole: Vec<f64> = (0..SIDE * SIDE).map(|i| at(i / SIDE, i % SIDE)).collect();
    write(
        &d.join("whole.tif"),
        SIDE,
        SIDE,
        whole,
        Some(g.clone()),
        false,
    );
    let want = build_bytes(vec![d.join("whole.tif")], &d.join("whole.cbdam"));
    let tiles = d.join("tiles");
    std::fs::create_dir(&tiles).unwrap();
    for tr in 0..GRID {
        for tc in 0..GRID {
            let v: Vec<f64> = (0..(T + 1) * (T + 1))
                .map(|i| at(tr * T + i / (T + 1), tc * T + i % (T + 1)))
                .collect();
            let tg = GeoRef {
                origin_x: g.origin_x + (tc * T) as f64 * g.pixel_x,
                origin_y: g.origin_y - (tr * T) as f64 * g.pixel_y,
                ..g.clone()
            };
            let name = format!("r{tr:02}c{tc:02}.tif");
            write(&tiles.join(name), T + 1, T + 1, v, Some(tg), false);
        }
    }
    assert_eq!(std::fs::read_dir(&tiles).unwrap().count(), GRID * GRID);
    let got = build_bytes(vec![tiles], &d.join("tiles.cbdam"));
    assert!(got == want, "{} tiles built different bytes", GRID * GRID);
}

/// Every field of two comparisons is the same.
fn same_comparison(a: &MosaicComparison, b: &MosaicComparison, what: &str) {
    assert_eq!(a.levels, b.levels, "{what}: levels");
    assert_eq!(a.reached_valid, b.reached_valid, "{what}: reached");
    assert_eq!(a.mask_mismatches, b.mask_mismatches, "{what}: mask");
    assert_eq!(
        a.first_mismatch_has_data, b.first_mismatch_has_data,
        "{what}: first mismatch"
    );
    assert_eq!(a.unreached, b.unreached, "{what}: unreached");
    assert_eq!(
        (a.mask_mismatch_count, a.unreached_count),
        (b.mask_mismatch_count, b.unreached_count),
        "{what}: counts"
    );
    assert_eq!(a.worst, b.worst, "{what}: worst");
    assert_eq!(a.inputs.len(), b.inputs.len(), "{what}: inputs");
    for (x, y) in a.inputs.iter().zip(&b.inputs) {
        assert_eq!(
            (&x.path, x.winning, x.stride, x.max_error),
            (&y.path, y.winning, y.stride, y.max_error),
            "{what}: input"
        );
    }
}

/// `cbdam verify` of tiles decodes block by block: on tiles with a gap and nodata over a coarse
/// input with a hole of its own, every plan — blocks smaller than a tile, cuts shallow and deep,
/// and the one a small memory limit picks — finds exactly what decoding the whole hierarchy
/// finds (the comparison `cbdam verify` made before, still used for α = ½), when the repository
/// matches its inputs and when the inputs are wrong (a coarse input 10 m off, and one left out,
/// which leaves the gap without data).
#[test]
fn verify_in_blocks_finds_what_the_whole_comparison_finds() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let (values, g) = source();
    let mut tiled = values.clone();
    for r in 10..20 {
        for c in 10..30 {
            tiled[r * SIDE + c] = NODATA;
        }
    }
    cut(
        &d.join("tiles"),
        &tiled,
        &g,
        |r, c| (r, c) != (1, 1),
        true,
        true,
    );
    // Every other sample, with a hole where the gap's tile would be.
    let cs = (SIDE - 1) / 2 + 1;
    // Its first sample centre on the fine one's.
    let half = if g.pixel_is_area { 0.5 } else { 0.0 };
    let coarse_geo = GeoRef {
        pixel_x: 2.0 * g.pixel_x,
        pixel_y: 2.0 * g.pixel_y,
        origin_x: g.origin_x - half * g.pixel_x,
        origin_y: g.origin_y + half * g.pixel_y,
        ..g.clone()
    };
    let coarse = |dir: &str, raise: f64| {
        let mut v = Vec::with_capacity(cs * cs);
        for r in 0..cs {
            for c in 0..cs {
                let hole = (70..80).contains(&r) && (90..110).contains(&c);
                v.push(if hole {
                    NODATA
                } else {
                    values[2 * r * SIDE + 2 * c] + raise
                });
            }
        }
        std::fs::create_dir_all(d.join(dir)).unwrap();
        let p = d.join(dir).join("coarse.tif");
        write(&p, cs, cs, v, Some(coarse_geo.clone()), true);
        p
    };
    let inputs = vec![d.join("tiles"), coarse("c", 0.0)];
    let out = d.join("var.cbdam");
    build_bytes(inputs.clone(), &out);
    let repo = Repository::open(&out).unwrap();
    let layout = *repo.head().params().layout();
    assert!(layout.finest_level() >= 4, "{layout:?}");
    let limit = 1 << 30;
    let raised = vec![d.join("tiles"), coarse("raised", 10.0)];
    let left_out = vec![d.join("tiles")];
    for (inputs, good) in [(inputs, true), (raised, false), (left_out, false)] {
        let tiles = expand_inputs(&inputs).unwrap();
        let whole = compare_tiles_whole(&repo, &tiles, limit).unwrap();
        assert_eq!(whole.check().is_ok(), good, "{inputs:?}");
        let mut plans: Vec<Option<BlockPlan>> = [(1, 48), (2, 64), (3, 128), (4, 100)]
            .into_iter()
            .map(|(cut_level, block_side)| {
                Some(BlockPlan {
                    cut_level,
                    block_side,
                })
            })
            .collect();
        plans.push(None);
        for plan in plans {
            // 48 MiB leaves the decode 24: blocks smaller than the domain.
            let blocks = compare_tiles_with(&repo, &tiles, 48 << 20, plan).unwrap();
            same_comparison(&whole, &blocks, &format!("{inputs:?} {plan:?}"));
            let used = blocks.blocks.expect("decoded in blocks");
            assert!(
                plan.is_none_or(|p| p == used),
                "{plan:?} asked, {used:?} used"
            );
            assert!(used.block_side < layout.root_side(), "{used:?}");
        }
    }
}
