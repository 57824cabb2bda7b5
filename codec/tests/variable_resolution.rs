//! Variable-resolution hierarchies (paper §5, "graph construction"): a coarse input over the whole
//! area with a hole, a 4× finer one over part of it. Every sample is reconstructed within the
//! bound at the level where its input ends, the hierarchy is not refined where only coarse data
//! exists, and the nodata mask keeps holes apart from coarse-only points.

use crate::util::Rng;
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::geometry::{DiamondId, Layout};
use cbdam_codec::hierarchy::resolution::{COARSE_ONLY, HOLE};
use cbdam_codec::hierarchy::{
    BlockPlan, EncodeOptions, Encoded, Encoder, NoJournal, Reached, Resolution, TempStorage,
    block_walk, reconstruct_reached, verify, walk_all_with_validity,
};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, Quantizer};

const SIDE: usize = 513;
/// The coarse input's stride (`2^COARSE_LOG2` lattice points).
const COARSE_LOG2: u8 = 2;
/// The fine input's extent, inclusive lattice coordinates.
const FINE: (usize, usize, usize, usize) = (64, 96, 160, 192);
/// Coarse samples with both coordinates at or above this are nodata.
const HOLE_FROM: usize = 448;
/// The coarse survey is offset from the fine one: where they overlap, a wrong winner shows.
const COARSE_OFFSET: i32 = 500;

fn opts() -> EncodeOptions {
    EncodeOptions {
        n: 17,
        alpha: Alpha::One,
        coder: CoderKind::Adaptive,
        extra_level_pairs: 0,
    }
}

/// Rough terrain, so that residuals are not all zero.
pub(crate) fn terrain(rng: &mut Rng) -> Vec<i32> {
    (0..SIDE * SIDE)
        .map(|k| {
            let (x, y) = ((k % SIDE) as f64, (k / SIDE) as f64);
            (2000.0 * (x / 23.0).sin() * (y / 31.0).cos()) as i32 + rng.below(40) as i32
        })
        .collect()
}

fn in_fine(x: usize, y: usize) -> bool {
    (FINE.0..=FINE.2).contains(&x) && (FINE.1..=FINE.3).contains(&y)
}

/// The grid and classes as the builder would make them from the two inputs (constructed here
/// independently of the CLI's mosaic code).
pub(crate) fn variable_input(h: &[i32]) -> (HeightGrid, Resolution) {
    let s = 1usize << COARSE_LOG2;
    let coarse_valid = |x: usize, y: usize| !(x >= HOLE_FROM && y >= HOLE_FROM);
    let mut values = vec![0i32; SIDE * SIDE];
    let mut valid = vec![false; SIDE * SIDE];
    let mut class = vec![HOLE; SIDE * SIDE];
    for y in 0..SIDE {
        for x in 0..SIDE {
            let k = y * SIDE + x;
            if in_fine(x, y) {
                values[k] = h[k];
                valid[k] = true;
                class[k] = 0;
            } else if x.is_multiple_of(s) && y.is_multiple_of(s) && coarse_valid(x, y) {
                values[k] = h[k] + COARSE_OFFSET;
                valid[k] = true;
                class[k] = COARSE_LOG2;
            } else {
                // Drawn when some closed coarse cell holding the point has four valid corners.
                let starts = |v: usize| {
                    let c = v / s * s;
                    if v.is_multiple_of(s) && c >= s {
                        vec![c, c - s]
                    } else {
                        vec![c]
                    }
                };
                let cell_ok = |cx: usize, cy: usize| {
                    cx + s < SIDE
                        && cy + s < SIDE
                        && [(cx, cy), (cx + s, cy), (cx, cy + s), (cx + s, cy + s)]
                            .iter()
                            .all(|&(a, b)| coarse_valid(a, b))
                };
                let drawn = starts(x)
                    .into_iter()
                    .any(|cx| starts(y).into_iter().any(|cy| cell_ok(cx, cy)));
                if drawn {
                    class[k] = COARSE_ONLY;
                }
            }
        }
    }
    let mut grid = HeightGrid::all_valid(SIDE, SIDE, values);
    grid.valid = valid.into();
    (
        grid,
        Resolution {
            class: class.into(),
        },
    )
}

pub(crate) fn encode_var(grid: &HeightGrid, res: &Resolution, q: Quantizer) -> Encoded {
    Encoder::new(grid, q, &opts())
        .resolution(Some(res))
        .encode()
        .unwrap()
}

#[test]
fn every_sample_within_bound_and_coarse_areas_stay_coarse() {
    let h = terrain(&mut Rng(7));
    let (grid, res) = variable_input(&h);
    let q = Quantizer::new(3).unwrap();
    let enc = encode_var(&grid, &res, q);
    assert!(enc.params.nodata_mask, "the hole needs a mask");

    // Every sample of both inputs is reached, within k, and the mask matches the classes.
    let (values, state) = reconstruct_reached(&enc).unwrap();
    let (mut fine, mut coarse) = (0, 0);
    for k in 0..SIDE * SIDE {
        let (x, y) = (k % SIDE, k / SIDE);
        match res.class[k] {
            HOLE => assert_ne!(state[k], Reached::Valid, "hole drawn at ({x}, {y})"),
            COARSE_ONLY => assert_ne!(state[k], Reached::Invalid, "({x}, {y})"),
            c => {
                assert_eq!(state[k], Reached::Valid, "sample ({x}, {y}) not reached");
                let want = if c == 0 {
                    fine += 1;
                    h[k]
                } else {
                    coarse += 1;
                    h[k] + COARSE_OFFSET
                };
                assert!(
                    (values[k] - want).abs() <= q.k(),
                    "({x}, {y}): {} vs {want}",
                    values[k]
                );
                // The finer input wins where both have data: the coarse value is far off.
                if in_fine(x, y) {
                    assert!((values[k] - (h[k] + COARSE_OFFSET)).abs() > q.k());
                }
            }
        }
    }
    assert_eq!(fine, 97 * 97);
    assert!(coarse > 3000, "{coarse}");
    let report = verify(&enc, &grid).unwrap();
    assert!(report.within_bound(), "{report:?}");

    // No record refines past the coarse level where there are only coarse samples: every record
    // at or below the coarse leaf level lies near the fine input — within the few diamonds of
    // its level that the parent closure adds around the fine leaves' ancestors (each level up
    // widens it by about one radius of that level, a geometric sum below 4 radii).
    let layout: Layout = *enc.params.layout();
    let coarse_level = layout.finest_level() - 2 * COARSE_LOG2;
    let mut deep = 0;
    for r in &enc.records {
        if r.id.level >= coarse_level {
            let (x0, y0, x1, y1) = layout.bounds(r.id);
            let d = 4 * layout.radius(r.id.level);
            let near = x1 + d >= FINE.0 as i64
                && x0 - d <= FINE.2 as i64
                && y1 + d >= FINE.1 as i64
                && y0 - d <= FINE.3 as i64;
            assert!(near, "{} refines a coarse-only area", r.id);
            deep += 1;
        }
    }

    // Far fewer records than the whole area at the fine spacing.
    let full = Encoder::new(&HeightGrid::all_valid(SIDE, SIDE, h.clone()), q, &opts())
        .encode()
        .unwrap();
    let (v, f) = (enc.records.len(), full.records.len());
    assert!(v * 3 < f, "{v} records variable vs {f} at the fine spacing");
    let full_deep = full
        .records
        .iter()
        .filter(|r| r.id.level >= coarse_level)
        .count();
    assert!(
        deep * 5 < full_deep,
        "{deep} vs {full_deep} records below the coarse level"
    );
}

#[test]
fn a_single_resolution_gives_the_same_hierarchy_as_encode() {
    let h = terrain(&mut Rng(11));
    let mut grid = HeightGrid::all_valid(SIDE, SIDE, h);
    // Some nodata, so the masks are exercised too.
    for k in (0..SIDE * SIDE).filter(|k| (k % SIDE) * 3 + k / SIDE < 150) {
        grid.valid[k] = false;
    }
    let res = Resolution {
        class: grid
            .valid
            .iter()
            .map(|&v| if v { 0 } else { HOLE })
            .collect(),
    };
    let q = Quantizer::new(2).unwrap();
    let single = Encoder::new(&grid, q, &opts()).encode().unwrap();
    assert_eq!(encode_var(&grid, &res, q), single);
}

#[test]
fn inconsistent_classes_and_alpha_half_are_refused() {
    let h = terrain(&mut Rng(3));
    let (grid, mut res) = variable_input(&h);
    let q = Quantizer::new(3).unwrap();
    let half = EncodeOptions {
        alpha: Alpha::Half,
        ..opts()
    };
    assert!(
        Encoder::new(&grid, q, &half)
            .resolution(Some(&res))
            .encode()
            .is_err()
    );
    res.class[0] = HOLE; // a valid sample called a hole
    assert!(
        Encoder::new(&grid, q, &opts())
            .resolution(Some(&res))
            .encode()
            .is_err()
    );
    res.class = res.class[..res.class.len() - 1].to_vec().into();
    assert!(
        Encoder::new(&grid, q, &opts())
            .resolution(Some(&res))
            .encode()
            .is_err()
    );
}

/// A multi-input build whose reconstruction field does not fit its memory limit keeps it in a
/// temporary file: the hierarchy must not depend on where the field lives.
#[test]
fn a_file_backed_field_gives_the_same_variable_hierarchy() {
    let h = terrain(&mut Rng(5));
    let (grid, res) = variable_input(&h);
    let q = Quantizer::new(3).unwrap();
    let in_file = Encoder::new(&grid, q, &opts())
        .resolution(Some(&res))
        .storage(&TempStorage::File(None))
        .encode()
        .unwrap();
    assert_eq!(in_file, encode_var(&grid, &res, q));
}

/// Encoding block by block ([`BlockPlan`]) gives the same variable-resolution hierarchy as the
/// whole-domain encoder, for blocks smaller than the fine input, straddling it, and larger.
#[test]
fn blocks_encode_the_same_variable_resolution_hierarchy() {
    let h = terrain(&mut Rng(11));
    let (grid, res) = variable_input(&h);
    let q = Quantizer::new(2).unwrap();
    let whole = encode_var(&grid, &res, q);
    // Also from mapped files, whose apex points and block windows are read as copies.
    let file = TempStorage::File(None);
    let mapped = grid.copied_to(&file).unwrap();
    let mapped_classes = Resolution {
        class: res.class.copied_to(&file).unwrap(),
    };
    for (cut_level, block_side) in [(3, 40), (6, 128), (9, 1000)] {
        let plan = BlockPlan {
            cut_level,
            block_side,
        };
        for (input, classes) in [(&grid, &res), (&mapped, &mapped_classes)] {
            let blocks = Encoder::new(input, q, &opts())
                .resolution(Some(classes))
                .in_blocks(&plan, &NoJournal)
                .encode()
                .unwrap();
            assert!(
                blocks == whole,
                "{plan:?} differs (mapped: {})",
                input.is_mapped()
            );
        }
    }
}

/// What a walk visits, point by point: each data point's last value and validity, as
/// [`reconstruct_reached`] keeps them.
struct Points {
    values: Vec<i32>,
    state: Vec<Reached>,
}

impl Points {
    fn new() -> Self {
        Self {
            values: vec![0; SIDE * SIDE],
            state: vec![Reached::No; SIDE * SIDE],
        }
    }

    /// Writes the grid points of `id` that `keep` accepts.
    fn visit(
        &mut self,
        layout: &Layout,
        id: DiamondId,
        p: &[i32],
        valid: Option<&[bool]>,
        keep: impl Fn(i64, i64) -> bool,
    ) {
        let n = layout.n();
        let g = layout.grid(id);
        for j in 0..n {
            for i in 0..n {
                let (x, y) = g.point(i as i64, j as i64);
                if (0..SIDE as i64).contains(&x) && (0..SIDE as i64).contains(&y) && keep(x, y) {
                    let k = y as usize * SIDE + x as usize;
                    self.values[k] = p[j * n + i];
                    self.state[k] = if valid.is_none_or(|v| v[j * n + i]) {
                        Reached::Valid
                    } else {
                        Reached::Invalid
                    };
                }
            }
        }
    }
}

/// Decoding block by block ([`BlockWalk`]) visits exactly the diamonds the whole walk visits
/// (each owned by one block, or in the apex), and within each block's owned rectangle leaves
/// every point as the whole walk does: on a variable-resolution hierarchy with holes, for cuts
/// shallow and deep and blocks smaller than the fine input, straddling it, and larger.
#[test]
fn a_block_walk_reaches_every_point_as_the_whole_walk_does() {
    let h = terrain(&mut Rng(13));
    let (grid, res) = variable_input(&h);
    let enc = encode_var(&grid, &res, Quantizer::new(2).unwrap());
    let layout: Layout = *enc.params.layout();
    let (values, state) = reconstruct_reached(&enc).unwrap();
    let mut whole_ids = Vec::new();
    walk_all_with_validity(&enc, |id, _, _| whole_ids.push(id)).unwrap();
    whole_ids.sort_unstable();
    for (cut_level, block_side) in [(0, 512), (2, 128), (3, 40), (6, 64), (8, 100), (8, 512)] {
        let plan = BlockPlan {
            cut_level,
            block_side,
        };
        let mut points = Points::new();
        let mut ids = Vec::new();
        let walk = block_walk(&enc, plan, |id, p, v| {
            assert!(id.level < cut_level, "{plan:?}: apex visits {id}");
            ids.push(id);
            points.visit(&layout, id, p, v, |_, _| true);
        })
        .unwrap();
        for (b, block) in walk.blocks().iter().enumerate() {
            let (x0, y0, x1, y1) = block.owned;
            walk.walk_block(b, |id, owned, p, v| {
                assert!(id.level >= cut_level, "{plan:?}: block visits {id}");
                if owned {
                    ids.push(id);
                }
                points.visit(&layout, id, p, v, |x, y| {
                    (x0..=x1).contains(&x) && (y0..=y1).contains(&y)
                });
            })
            .unwrap();
        }
        ids.sort_unstable();
        assert!(ids == whole_ids, "{plan:?}: visits differ");
        assert!(points.state == state, "{plan:?}: nodata states differ");
        assert!(points.values == values, "{plan:?}: values differ");
    }
    // Cut at or below the finest level: nothing left to the blocks.
    let finest = layout.finest_level();
    let deep = BlockPlan {
        cut_level: finest,
        block_side: 64,
    };
    assert!(block_walk(&enc, deep, |_, _, _| {}).is_err());
}
