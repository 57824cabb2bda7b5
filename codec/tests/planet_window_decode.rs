//! Windowed decodes of a planet ([`decode_face_windows`]): per canonical lattice point of the
//! windows, the last grid value and validity visited at the level are the whole walk's, for
//! every level and for windows inside a face, along a cube edge, at a cube corner (three faces)
//! and over several faces at once; only the records [`FaceWindows::records_needed`] names are
//! read; and a level raster filled from the windowed decode equals one filled from the whole
//! walk.

use std::collections::HashMap;

use cbdam_codec::entropy::CoderKind;
use cbdam_codec::geometry::{DiamondId, Domain, FacePoint};
use cbdam_codec::hierarchy::{
    EncodeOptions, Encoded, FaceWindows, LevelRaster, PlanetGrid, decode_face_windows,
    encode_planet, walk_all_with_validity,
};
use cbdam_codec::quant::Quantizer;

use crate::util::CountedReads;

type Points = HashMap<FacePoint, (i32, bool)>;

/// A planet with relief that differs on every face and nodata on a scatter of points (some on
/// edges and corners).
fn planet(n: usize, k: u32) -> PlanetGrid {
    PlanetGrid::from_fn(n, k, |p| {
        let h = (p.x * 7919 + p.y * 104_729 + i64::from(p.face) * 1_299_709) % 1009;
        if h % 23 == 0 {
            return None;
        }
        Some(1000 * i32::from(p.face) + (20 * p.x - 13 * p.y) as i32 + h as i32)
    })
    .unwrap()
}

/// Whether `p` (canonical) lies in one of `windows`' rectangles through any face holding it.
fn in_windows(domain: &Domain, windows: &FaceWindows, p: FacePoint) -> bool {
    let (reps, len) = domain.cube().unwrap().representations(p);
    reps[..len].iter().any(|q| {
        windows.rects.iter().any(|&(f, (x0, y0, x1, y1))| {
            q.face == f && (x0..=x1).contains(&q.x) && (y0..=y1).contains(&q.y)
        })
    })
}

/// The last value and validity each canonical point in `windows` gets from `visit`'s grids.
fn keep_last(
    enc: &Encoded,
    windows: &FaceWindows,
    points: &mut Points,
    (id, grid, valid): (DiamondId, &[i32], Option<&[bool]>),
) {
    if id.level != windows.level {
        return;
    }
    let domain = enc.params.domain;
    let (n, g) = (domain.layout().n(), domain.layout().grid(id));
    for j in 0..n {
        for i in 0..n {
            let (x, y) = g.point(i as i64, j as i64);
            let Some(p) = domain.canonical_point(id.face, x, y) else {
                continue;
            };
            if in_windows(&domain, windows, p) {
                points.insert(p, (grid[j * n + i], valid.is_none_or(|v| v[j * n + i])));
            }
        }
    }
}

fn encode(n: usize, k: u32) -> Encoded {
    let opts = EncodeOptions {
        n,
        coder: CoderKind::AdaptiveTokens,
        ..EncodeOptions::default()
    };
    encode_planet(&planet(n, k), Quantizer::new(2).unwrap(), &opts).unwrap()
}

#[test]
fn every_face_window_and_level_decodes_as_the_whole_walk() {
    let enc = encode(5, 3);
    let s = enc.params.domain.cube().unwrap().side();
    let finest = enc.params.layout().finest_level();
    let reads = CountedReads::new(&enc);
    let windows = [
        vec![(0, (5, 7, 12, 9))],        // inside a face
        vec![(1, (s - 3, 10, s, 20))],   // along the edge of faces 1 and 2
        vec![(4, (s - 2, s - 2, s, s))], // a cube corner (faces 0, 1, 4)
        vec![(5, (0, 0, 0, 0))],         // a corner point alone
        vec![(2, (0, 0, s, s)), (3, (1, 1, 3, s)), (4, (0, 0, 4, 4))], // several faces
    ];
    let mut partial_reads = 0;
    for level in 0..=finest {
        for rects in &windows {
            let windows = FaceWindows {
                level,
                rects: rects.clone(),
            };
            let mut want = Points::new();
            walk_all_with_validity(&enc, |id, g, v| {
                keep_last(&enc, &windows, &mut want, (id, g, v))
            })
            .unwrap();
            let mut got = Points::new();
            decode_face_windows(
                enc.params,
                &enc.roots,
                &reads.stored,
                |id| reads.read(id),
                &windows,
                |id, g, v| keep_last(&enc, &windows, &mut got, (id, g, v)),
            )
            .unwrap();
            assert!(
                !want.is_empty(),
                "level {level}, {rects:?}: the whole walk shows nothing"
            );
            assert!(
                got == want,
                "level {level}, windows {rects:?}: {} points, want {}",
                got.len(),
                want.len()
            );
            let needed = windows.records_needed(&enc.params, &reads.stored).unwrap();
            let partial = reads.check_read_exactly(needed);
            partial_reads += usize::from(partial);
        }
    }
    // The small windows at the finest levels need only part of the planet.
    assert!(
        partial_reads > 5,
        "only {partial_reads} reads needed fewer than every record"
    );
}

#[test]
fn a_raster_from_face_windows_equals_the_raster_from_the_whole_walk() {
    let enc = encode(5, 2);
    let domain = enc.params.domain;
    let s = domain.cube().unwrap().side();
    let reads = CountedReads::new(&enc);
    let rects = vec![
        (0, (s - 4, 0, s, 5)),
        (4, (s - 5, s - 5, s, s)),
        (1, (0, 0, 3, 3)),
    ];
    for level in [domain.finest_level(), domain.finest_level() - 2] {
        let mut whole = LevelRaster::new(&domain, level, &rects).unwrap();
        walk_all_with_validity(&enc, |id, g, v| whole.put_diamond(&domain, id, g, v)).unwrap();
        let mut windowed = LevelRaster::new(&domain, level, &rects).unwrap();
        let windows = FaceWindows {
            level,
            rects: rects.clone(),
        };
        decode_face_windows(
            enc.params,
            &enc.roots,
            &reads.stored,
            |id| reads.read(id),
            &windows,
            |id, g, v| windowed.put_diamond(&domain, id, g, v),
        )
        .unwrap();
        assert_eq!(windowed, whole, "level {level}");
        // Shared edge points hold the same sample through every face's block.
        let (b0, b4) = (whole.block(0).unwrap(), whole.block(4).unwrap());
        assert!(b0.units.iter().chain(&b4.units).any(|&u| u > i32::MIN + 1));
    }
}

#[test]
fn face_windows_refuse_planes_bad_faces_and_levels() {
    let enc = encode(5, 1);
    let s = enc.params.domain.cube().unwrap().side();
    let stored: Vec<DiamondId> = enc.records.iter().map(|r| r.id).collect();
    let finest = enc.params.layout().finest_level();
    let bad = [
        (finest + 1, vec![(0, (0, 0, 1, 1))], "finest level"),
        (finest, vec![(6, (0, 0, 1, 1))], "not on a face"),
        (finest, vec![(0, (0, 0, s + 1, 1))], "not on a face"),
        (finest, vec![(0, (3, 0, 2, 1))], "not on a face"),
    ];
    for (level, rects, why) in bad {
        let w = FaceWindows { level, rects };
        let e = w
            .records_needed(&enc.params, &stored)
            .unwrap_err()
            .to_string();
        assert!(e.contains(why), "{e}");
    }
}
