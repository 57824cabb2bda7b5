//! Tests of the planet lattice's painting: every point of every tile of every face (edges and
//! cube corners too) against a point-by-point resampling written independently of the tiles,
//! parts of tiles against the whole, an input's sample footprint against its samples, its
//! resampling error against one reckoned point by point, and a height the plan cannot hold.

use std::path::PathBuf;
use std::sync::Arc;

use super::Resampler;
use crate::band_cache::Samples;
use crate::planet_input::{Frame, PlanetInput, PlanetInputs, PointSource, SampleSource};
use crate::planet_plan::{input_stride, lattice_spacing_deg};
use crate::planet_resampling::{column_sin_cos, sample_footprint, sample_position};
use cbdam_codec::geodesy::cube_map::lat_lon_to_face_st;
use cbdam_codec::geodesy::lattice_lat_lon;
use cbdam_codec::hierarchy::PlanetGrid;
use cbdam_codec::hierarchy::resolution::{COARSE_ONLY, HOLE};
use cbdam_codec::quant::QuantPlan;

/// A geographic input of `w × h` samples `deg` apart from `(lat0, lon0)` (its first sample),
/// around the globe when `period`; heights a function of the sample, one in 23 a void.
fn input(name: &str, (lat0, lon0): (f64, f64), deg: f64, (w, h): (usize, usize)) -> PlanetInput {
    let period = (w as f64 * deg >= 360.0).then_some(w);
    let values = (0..w * h)
        .map(|i| match i % 23 {
            7 => -9999.0,
            k => (i % 97) as f64 * 13.0 + k as f64 * 0.37 + deg,
        })
        .collect();
    PlanetInput {
        path: PathBuf::from(name),
        width: w,
        height: h,
        source: SampleSource::Held(Arc::new(Samples::compact(values))),
        nodata: Some(-9999.0),
        frame: Frame::Geographic {
            lon0,
            lat0,
            dlon: deg,
            dlat: deg,
            period,
        },
        spacing_deg: deg,
    }
}

/// Two fine insets, one astride the edge of an equatorial and a polar face, one on the cube
/// corner at 35.26° N 45° E, and an inset coarser than the lattice (points between its samples
/// are coarse only), over a global coarse input: finest first.
fn inputs() -> PlanetInputs {
    PlanetInputs::held(vec![
        input("edge.tif", (52.0, -12.0), 0.3, (50, 40)),
        input("corner.tif", (40.0, 40.0), 0.3, (34, 30)),
        input("coarse.tif", (30.0, -70.0), 1.2, (30, 20)),
        input("globe.tif", (90.0, -180.0), 3.0, (120, 61)),
    ])
}

/// What a point takes, resampled on its own: the first input (in order) that covers it, its
/// position from the domain's canonical point. Height units, validity, winner, class.
fn reference(
    r: &Resampler,
    plan: &QuantPlan,
    face: u8,
    (x, y): (i64, i64),
) -> (i32, bool, u16, u8) {
    let inputs = r.inputs;
    let ll = lattice_lat_lon(r.domain(), face, x, y).expect("a point of the face");
    for i in 0..inputs.inputs.len() {
        let samples = inputs.samples(i).unwrap();
        let source = inputs
            .probe(&*samples, i as u16, r.lattice_deg, &r.strides)
            .source_of(ll, (x, y));
        match source {
            Some(PointSource::Sample(v, wi, j)) => {
                return match plan.to_units(v).ok().flatten() {
                    Some(u) => (u, true, wi, j),
                    None => (0, false, u16::MAX, HOLE),
                };
            }
            Some(PointSource::CoarseOnly(wi)) => return (0, false, wi, COARSE_ONLY),
            None => {}
        }
    }
    (0, false, u16::MAX, HOLE)
}

/// Every point of every tile, at every stride, is what the point resampled on its own takes:
/// the tiles' one pass over their candidates, with each position computed once, changes
/// nothing.
#[test]
fn every_painted_point_is_its_own_resampling() {
    let inputs = inputs();
    let plan = QuantPlan::new(1.0, None, -10.0, 2000.0).unwrap();
    let r = Resampler::new(&inputs, 17, 4, &plan).unwrap();
    let per_face = r.tiles_per_face();
    let mut coarse_only = 0;
    let mut kinds = [0usize; 5];
    for face in 0..6u8 {
        for tile in 0..per_face {
            for stride in [0, 2] {
                let (t, won) = r.tile(face, tile, stride).unwrap();
                let (x0, y0, x1, y1) = t.rect;
                let step = 1usize << stride;
                for y in (y0..=y1).step_by(step) {
                    for x in (x0..=x1).step_by(step) {
                        let k = t.index(x, y).unwrap();
                        let class = t.class.as_ref().map_or(0, |c| c[k]);
                        let got = (t.grid.values[k], t.grid.valid[k], won[k], class);
                        let want = reference(&r, &plan, face, (x, y));
                        assert_eq!(got, want, "face {face} point ({x}, {y}) stride {stride}");
                        kinds[usize::from(want.2.min(4))] += 1;
                        coarse_only += usize::from(want.3 == COARSE_ONLY && want.2 == 2);
                    }
                }
            }
        }
    }
    // Each input wins points, some are holes (the voids), and the coarse inset wins some
    // points between its samples (coarse only), which the globe covers too.
    assert!(kinds.iter().all(|&n| n > 0), "{kinds:?}");
    assert!(coarse_only > 0);
}

/// A part of a tile holds the whole tile's points in the part and holes elsewhere.
#[test]
fn a_part_of_a_tile_is_the_tile_there_and_holes_elsewhere() {
    let inputs = inputs();
    let plan = QuantPlan::new(1.0, None, -10.0, 2000.0).unwrap();
    let r = Resampler::new(&inputs, 17, 4, &plan).unwrap();
    let rects = PlanetGrid::tile_rects(r.domain(), r.tile_log2());
    let mut inside = 0;
    for face in [0u8, 2, 4] {
        for (tile, &(x0, y0, x1, y1)) in rects.iter().enumerate() {
            let part = (x0 + 3, y0 - 5, x1 - 7, y0 + 4);
            let (whole, won) = r.tile(face, tile, 0).unwrap();
            let (t, won_part) = r.tile_part(face, tile, 0, part).unwrap();
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let k = t.index(x, y).unwrap();
                    let class =
                        |t: &cbdam_codec::hierarchy::PlanetTile| t.class.as_ref().map(|c| c[k]);
                    if part.0 <= x && x <= part.2 && part.1 <= y && y <= part.3 {
                        inside += 1;
                        assert_eq!(t.grid.values[k], whole.grid.values[k]);
                        assert_eq!(t.grid.valid[k], whole.grid.valid[k]);
                        assert_eq!((won_part[k], class(&t)), (won[k], class(&whole)));
                    } else {
                        assert!(!t.grid.valid[k] && won_part[k] == u16::MAX);
                        assert_eq!(class(&t), class(&whole).map(|_| HOLE));
                    }
                }
            }
        }
    }
    assert!(inside > 0);
}

/// Every sample of `inset` lies on a face of its footprint, with the corners of its lattice
/// cell (on the stride, as `lattice_at` reads them) inside that face's rectangle; the faces
/// its samples lie on.
fn check_footprint(inset: &PlanetInput, stride: u32, side: i64) -> std::collections::BTreeSet<u8> {
    let step = 1i64 << stride;
    let cells = side / step;
    let parts = sample_footprint(inset, stride, side).unwrap();
    let mut faces = std::collections::BTreeSet::new();
    for row in 0..inset.height {
        for c in 0..inset.width {
            let (f, s, t) = lat_lon_to_face_st(inset.lat_lon_of(c, row));
            faces.insert(f);
            let name = inset.path.display();
            let &(_, (x0, y0, x1, y1)) = parts
                .iter()
                .find(|(face, _)| *face == f)
                .unwrap_or_else(|| panic!("{name} sample ({c}, {row}): face {f} not in {parts:?}"));
            let cx = ((s * side as f64 / step as f64).floor() as i64).min(cells - 1) * step;
            let cy = ((t * side as f64 / step as f64).floor() as i64).min(cells - 1) * step;
            assert!(
                x0 <= cx && cx + step <= x1 && y0 <= cy && cy + step <= y1,
                "{name} sample ({c}, {row}) on face {f}: cell at ({cx}, {cy}) outside {:?}",
                (x0, y0, x1, y1)
            );
        }
    }
    faces
}

/// An inset's footprint holds the corners of the lattice cell of every one of its samples, on
/// the face they lie on, also where its samples lie on two faces (across an edge) or three (a
/// cube corner); a global input has none (its tiles are read whole).
#[test]
fn a_footprint_holds_every_sample_cell() {
    let inputs = inputs();
    let plan = QuantPlan::new(1.0, None, -10.0, 2000.0).unwrap();
    let r = Resampler::new(&inputs, 17, 4, &plan).unwrap();
    assert!(sample_footprint(&inputs.inputs[3], r.strides[3], r.side).is_none());
    // Insets inside a face (an equatorial one, a polar one), astride the edge of an
    // equatorial and a polar face, astride two equatorial faces, on the cube corner at
    // 35.26° N 45° E, and a coarse one astride 45° W, on lattices finer than them (at their
    // strides there).
    let insets = [
        (input("equator.tif", (20.0, 10.0), 0.3, (40, 30)), 1),
        (input("pole.tif", (80.0, 100.0), 0.3, (40, 25)), 1),
        (input("edge.tif", (52.0, -12.0), 0.3, (50, 40)), 2),
        (input("meridian.tif", (10.0, 40.0), 0.3, (40, 30)), 2),
        (input("corner.tif", (40.0, 40.0), 0.3, (34, 30)), 3),
        (input("coarse.tif", (30.0, -70.0), 1.2, (30, 20)), 2),
        // A row just under the polar face's edge where it is highest (45.19° N at 0° E): its
        // three middle samples lie on the equatorial face, none of them one of the samples
        // the footprint looks at (every eighth, and the last).
        (input("sliver.tif", (45.1923, -0.4), 0.1, (9, 1)), 2),
    ];
    for (inset, faces) in &insets {
        for k in [4, 6, 8] {
            let side = 16i64 << k;
            let stride = input_stride(inset.spacing_deg, lattice_spacing_deg(17, k), k);
            let on = check_footprint(inset, stride, side);
            assert_eq!(on.len(), *faces, "{}", inset.path.display());
        }
    }
}

/// A lattice of 2048 steps a face in tiles of 1024 (N = 17, K = 7) and one 0.02° inset of 64
/// columns and `rows` rows over face 0's middle, where its four tiles meet; heights quantized
/// to 1 m over −10…2000 m.
fn middle_inset(rows: usize) -> (usize, u32, PlanetInputs, QuantPlan) {
    let (n, k) = (17, 7);
    let domain = cbdam_codec::geometry::Domain::cube_sphere(n, k).unwrap();
    let middle = lattice_lat_lon(&domain, 0, 1024, 1024).unwrap();
    let inputs = PlanetInputs::held(vec![input(
        "middle.tif",
        (middle.lat + 0.61, middle.lon - 0.63),
        0.02,
        (64, rows),
    )]);
    (
        n,
        k,
        inputs,
        QuantPlan::new(1.0, None, -10.0, 2000.0).unwrap(),
    )
}

/// An inset over the middle of a face, where its four tiles meet (a lattice of 2048 steps a
/// face in tiles of 1024), measured as a build measures it ([`super::LatticeTiles::resampling`]:
/// the parts of its tiles around its samples): every sample whose four surrounding lattice
/// points all took their heights from it is compared, on either side of the tiles' sides —
/// the count and the largest error against the same reckoned from the points resampled on
/// their own ([`reference`]), no tile looked up.
#[test]
fn every_sample_is_compared_on_both_sides_of_a_tile_side() {
    let (n, k, inputs, plan) = middle_inset(62);
    let r = Resampler::new(&inputs, n, k, &plan).unwrap();
    assert_eq!((r.side, r.tile_log2()), (2048, 10));
    let strides = r.tiles.strides.clone();
    let tiles = super::LatticeTiles::with_strides(r, strides, 1 << 30).unwrap();
    let got = tiles.resampling(0).unwrap();
    let r = &tiles.resampler;
    let (inset, samples) = (&inputs.inputs[0], inputs.samples(0).unwrap());
    let columns = column_sin_cos(inset);
    let (step, side) = (1i64 << r.strides[0], r.side);
    let (mut compared, mut max, mut tiles_met) = (0u64, 0.0f64, std::collections::BTreeSet::new());
    for row in 0..inset.height {
        let lat = inset.lat_lon_of(0, row).lat.to_radians().sin_cos();
        for c in 0..inset.width {
            let Some(v) = inset.sample(&samples, c, row) else {
                continue;
            };
            let (face, s, t) = sample_position(inset, columns.as_deref(), lat, (c, row));
            let (x, y) = (s * side as f64 / step as f64, t * side as f64 / step as f64);
            let (cx, cy) = (x.floor() as i64, y.floor() as i64);
            let corner = |dx: i64, dy: i64| {
                let p = ((cx + dx) * step, (cy + dy) * step);
                let (units, valid, won, _) = reference(r, &plan, face, p);
                (valid && won == 0).then(|| plan.metres(units))
            };
            let (Some(a), Some(b), Some(cc), Some(d)) =
                (corner(0, 0), corner(1, 0), corner(0, 1), corner(1, 1))
            else {
                continue;
            };
            let (fx, fy) = (x - cx as f64, y - cy as f64);
            let l = (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (cc * (1.0 - fx) + d * fx) * fy;
            compared += 1;
            max = max.max((l - v).abs());
            tiles_met.insert(cbdam_codec::hierarchy::planet::tile_of(
                side,
                10,
                cx * step,
                cy * step,
            ));
        }
    }
    // The inset's compared samples lie in all four tiles around the face's middle.
    assert_eq!(tiles_met.len(), 4, "{tiles_met:?}");
    assert!(compared > 3000, "{compared} of {}", got.samples);
    assert_eq!(got.compared, compared);
    assert!(
        (got.max_error - max).abs() < 1e-9,
        "{} against {max}",
        got.max_error
    );
}

/// An inset whose tiles are more than the lattice cache's budget is measured a band of its
/// rows at a time, each band painting only the parts of its tiles around its own samples
/// ([`super::LatticeTiles::resampling`]): the same figures, to the bit, as all its rows against
/// all its tiles at once — with one row a band (a budget of one byte) and with a few bands.
#[test]
fn an_inset_measured_in_bands_gives_the_figures_of_all_its_rows_at_once() {
    let (n, k, inputs, plan) = middle_inset(400);
    let measured = |budget: u64| {
        let r = Resampler::new(&inputs, n, k, &plan).unwrap();
        let strides = r.tiles.strides.clone();
        let tiles = super::LatticeTiles::with_strides(r, strides, budget).unwrap();
        let got = tiles.resampling(0).unwrap();
        let at = got.worst_at.map(|p| (p.lat.to_bits(), p.lon.to_bits()));
        (
            got.samples,
            got.compared,
            got.max_error.to_bits(),
            got.rms_error.to_bits(),
            at,
        )
    };
    let whole = measured(1 << 40);
    assert!(whole.1 > 20_000, "{whole:?}");
    // Its four tiles of 1025² points at 8 B: 33.6 MB, so 12 MiB is three bands of 134 rows
    // (2.7°, 61 lattice steps: more than the footprint's margin of 41).
    for budget in [1, 12 << 20] {
        assert_eq!(measured(budget), whole, "budget {budget}");
    }
}

/// A height the plan cannot hold is an error naming the input and the lattice point, not a
/// hole: an inset whose heights lie far outside the planned range.
#[test]
fn a_height_outside_the_planned_range_is_an_error_naming_the_input() {
    let mut inset = input("huge.tif", (20.0, 10.0), 0.3, (40, 30));
    inset.source = SampleSource::Held(Arc::new(Samples::compact(vec![1.0e15; 40 * 30])));
    let inputs = PlanetInputs::held(vec![inset]);
    let plan = QuantPlan::new(1.0, None, -10.0, 2000.0).unwrap();
    let r = Resampler::new(&inputs, 17, 4, &plan).unwrap();
    let errors: Vec<String> = (0..6u8)
        .filter_map(|face| r.tile(face, 0, 0).err())
        .map(|e| e.to_string())
        .collect();
    assert_eq!(errors.len(), 1, "{errors:?}");
    let e = &errors[0];
    assert!(
        e.contains("huge.tif") && e.contains("lattice point") && e.contains("outside the planned"),
        "{e}"
    );
    // Within the range, the same inset paints without error.
    let mut inset = input("huge.tif", (20.0, 10.0), 0.3, (40, 30));
    inset.source = SampleSource::Held(Arc::new(Samples::compact(vec![1000.0; 40 * 30])));
    let inputs = PlanetInputs::held(vec![inset]);
    let r = Resampler::new(&inputs, 17, 4, &plan).unwrap();
    assert!((0..6u8).all(|face| r.tile(face, 0, 0).is_ok()));
}

/// A fine geographic tile of 201² samples 0.1° apart from `(lat0, lon0)` (its north-west
/// sample), heights a function of the sample but where `odd` gives one (nodata, NaN).
fn fine_tile(
    name: &str,
    (lat0, lon0): (f64, f64),
    odd: fn(usize, usize) -> Option<f64>,
) -> PlanetInput {
    let mut p = input(name, (lat0, lon0), 0.1, (201, 201));
    let values = (0..201 * 201)
        .map(|i| odd(i % 201, i / 201).unwrap_or(((i * 7919) % 1000) as f64 + 0.25))
        .collect();
    p.source = SampleSource::Held(Arc::new(Samples::compact(values)));
    p
}

/// The outline's tiles ([`Resampler::outline_tile`]) hold the classes and validity the tiles
/// painted whole hold, though the squares proved covered by the fine tiles are not painted:
/// four fine tiles sharing their edges (10–50° N, 0–40° E, astride the edge of face 0 and the
/// north polar face), one with voids every 5°, one with a void of a few samples and one with a
/// NaN, over a global coarse input; and squares proved covered hold many of their points.
#[test]
fn the_outline_s_covered_squares_hold_what_painting_them_holds() {
    let inputs = PlanetInputs::held(vec![
        fine_tile("n50e000.tif", (50.0, 0.0), |c, r| {
            ((40..43).contains(&c) && r == 60).then_some(-9999.0)
        }),
        fine_tile("n50e020.tif", (50.0, 20.0), |c, r| {
            (c % 50 == 25 && r % 50 == 25).then_some(-9999.0)
        }),
        fine_tile("n30e000.tif", (30.0, 0.0), |c, r| {
            (c == 77 && r == 12).then_some(f64::NAN)
        }),
        fine_tile("n30e020.tif", (30.0, 20.0), |c, r| {
            (c == 3 && r == 199).then_some(-9999.0)
        }),
        input("globe.tif", (90.0, -180.0), 3.0, (120, 61)),
    ]);
    let plan = QuantPlan::new(0.25, None, -10.0, 2000.0).unwrap();
    let r = Resampler::new(&inputs, 17, 6, &plan).unwrap();
    assert!(r.lattice_deg <= 0.1 && r.strides[0] == 0);
    let mut covered = 0;
    for face in 0..6u8 {
        for tile in 0..r.tiles_per_face() {
            let (whole, _) = r.final_tile(face, tile).unwrap();
            let outline = r.outline_tile(face, tile, None).unwrap();
            assert_eq!((outline.stride, outline.rect), (whole.stride, whole.rect));
            assert_eq!(outline.class, whole.class, "face {face} tile {tile}");
            assert_eq!(
                outline.grid.valid, whole.grid.valid,
                "face {face} tile {tile}"
            );
            let mask = r.covered_points(face, tile).unwrap();
            for (k, painted) in mask.iter().flatten().map(|&c| !c).enumerate() {
                assert!(!painted || outline.grid.values[k] == whole.grid.values[k]);
            }
            covered += mask.iter().flatten().filter(|&&c| c).count();
        }
    }
    // The fine tiles (40° × 40°) hold about 200 000 lattice points at 0.088°.
    assert!(covered > 50_000, "{covered} points proved covered");
    assert_eq!(r.covered(), covered as u64);
    // Kept for the apex view: the points on multiples of 4 hold the heights painted whole.
    let mut kept = 0;
    for face in 0..6u8 {
        for tile in 0..r.tiles_per_face() {
            let (whole, _) = r.final_tile(face, tile).unwrap();
            let outline = r.outline_tile(face, tile, Some(2)).unwrap();
            let (x0, y0, x1, _) = whole.rect;
            let s = whole.stride;
            let w = ((x1 - x0) >> s) as usize + 1;
            for (k, (&a, &b)) in outline
                .grid
                .values
                .iter()
                .zip(&whole.grid.values)
                .enumerate()
            {
                let (x, y) = (x0 + ((k % w) << s) as i64, y0 + ((k / w) << s) as i64);
                if x % 4 == 0 && y % 4 == 0 {
                    assert_eq!(a, b, "face {face} tile {tile} point ({x}, {y})");
                    kept += 1;
                }
            }
        }
    }
    assert!(kept > covered / 32, "{kept} kept points checked");
}
