//! Tests of [`super::ApexView`]: tiles read back as [`super::super::thinned`] thins them.

use super::*;
use crate::hierarchy::planet::thinned;
use crate::hierarchy::resolution::HOLE;

/// A tile of `domain`'s tiles of `2^log2` steps at `index`, at `stride`, its heights a function
/// of the lattice point (so that a point read from the wrong place or stride shows), every
/// seventh point a hole, with classes when `classes`.
fn tile(
    rects: &[(i64, i64, i64, i64)],
    index: usize,
    stride: u32,
    classes: bool,
) -> Arc<PlanetTile> {
    let rect = rects[index];
    let (x0, y0, x1, y1) = rect;
    let step = 1usize << stride;
    let mut values = Vec::new();
    let mut valid = Vec::new();
    for y in (y0..=y1).step_by(step) {
        for x in (x0..=x1).step_by(step) {
            values.push((x * 1000 + y) as i32 - 5000);
            valid.push((x + 3 * y) % 7 != 0);
        }
    }
    let class = classes.then(|| {
        valid
            .iter()
            .map(|&v| if v { stride as u8 } else { HOLE })
            .collect()
    });
    let grid = HeightGrid {
        width: ((x1 - x0) >> stride) as usize + 1,
        height: ((y1 - y0) >> stride) as usize + 1,
        values: values.into(),
        valid: valid.into(),
    };
    Arc::new(PlanetTile::new(stride, rect, grid, class).unwrap())
}

/// Every tile put (at strides finer and coarser than the apex's finest, with and without
/// classes) reads back, alone and together with others, as the tile thinned to the stride
/// asked for would be ([`thinned`], the tile source's own thinning): values, validity,
/// classes, stride and rectangle; in memory and through temporary files. A tile not put, or
/// asked for finer than the apex reads, is an error, not another tile.
#[test]
fn tiles_read_back_as_the_tiles_thinned_to_the_stride_asked_for() {
    // 2·2^6 = 128 steps a face, tiles of 32 steps: 4 × 4 tiles a face; cut 6: the apex
    // reads every 8th point at its finest (2^(6 − 3)).
    let domain = Domain::cube_sphere(3, 6).unwrap();
    let log2 = 5;
    let rects = PlanetGrid::tile_rects(&domain, log2);
    let put: Vec<(u8, usize, Arc<PlanetTile>)> = vec![
        (0, 0, tile(&rects, 0, 0, false)),
        (0, 1, tile(&rects, 1, 0, true)),
        (0, 5, tile(&rects, 5, 4, false)),
        (3, 15, tile(&rects, 15, 5, true)),
        (5, 6, tile(&rects, 6, 2, false)),
    ];
    for in_memory in [usize::MAX, 0] {
        let writer = ApexViewWriter::with_in_memory(&domain, log2, 6, in_memory);
        assert_eq!(writer.finest_stride(), 3);
        for (face, index, t) in &put {
            writer.put(*face, *index, t).unwrap();
        }
        let view = writer.finish().unwrap();
        let in_file = view.strides.iter().flatten().any(|(s, _)| s.in_file());
        assert_eq!(in_file, in_memory == 0);
        for min_stride in 3..=7 {
            let all: BTreeSet<(u8, usize)> = put.iter().map(|&(f, i, _)| (f, i)).collect();
            let together = view.tiles(&all, min_stride).unwrap();
            assert_eq!(together.len(), put.len());
            for (face, index, t) in &put {
                let want = thinned(t, min_stride.min(log2)).unwrap();
                let alone = view.tiles(&BTreeSet::from([(*face, *index)]), min_stride);
                for got in [
                    &alone.unwrap()[&(*face, *index)],
                    &together[&(*face, *index)],
                ] {
                    assert_eq!(
                        (got.stride, got.rect, &got.grid, &got.class),
                        (want.stride, want.rect, &want.grid, &want.class),
                        "face {face} tile {index} at stride {min_stride}"
                    );
                }
            }
        }
        let missing = view.tiles(&BTreeSet::from([(0, 2)]), 3).unwrap_err();
        assert!(missing.to_string().contains("face 0 tile 2"), "{missing}");
        assert!(view.tiles(&BTreeSet::from([(0, 0)]), 2).is_err());
    }
}

/// A tile whose rectangle is not its index's is refused; damaged records are refused, not a
/// panic.
#[test]
fn a_misplaced_tile_and_damaged_records_are_refused() {
    let domain = Domain::cube_sphere(3, 6).unwrap();
    let rects = PlanetGrid::tile_rects(&domain, 5);
    let writer = ApexViewWriter::new(&domain, 5, 6);
    assert!(writer.put(0, 1, &tile(&rects, 0, 0, false)).is_err());
    assert!(writer.put(6, 0, &tile(&rects, 0, 0, false)).is_err());
    let mut bytes = Vec::new();
    thinned_bytes(&tile(&rects, 1, 0, true), 3, &mut bytes);
    assert!(tile_of_bytes(&bytes).is_some_and(|t| t.is_ok()));
    for cut in [0, 3, 20, HEADER_BYTES, bytes.len() - 1] {
        assert!(tile_of_bytes(&bytes[..cut]).is_none(), "cut at {cut}");
    }
    assert!(tile_read_back(0, 1, &bytes[..HEADER_BYTES + 2]).is_err());
}
