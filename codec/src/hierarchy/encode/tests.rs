//! The encoder's tests: the per-diamond, field and block strategies agree bit for bit, on
//! synthetic terrain and on real DEMs with nodata and odd sizes.

use super::*;
use crate::geometry::Layout;
use crate::hierarchy::blocks::BlockOutput;
use crate::quant::QuantPlan;
use crate::samples::{Dem, SampleType};
use proptest::prelude::*;

/// The leaf selection by summed-area table that `stored_sets` replaced: the reference.
fn leaves_by_table(layout: &Layout, grid: &HeightGrid) -> Vec<DiamondId> {
    let (w, h) = (grid.width, grid.height);
    let mut sat = vec![0u32; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0u32;
        for x in 0..w {
            row += u32::from(grid.valid[y * w + x]);
            sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
        }
    }
    let count = |x0: i64, y0: i64, x1: i64, y1: i64| -> u32 {
        let (x0, y0) = (x0.max(0) as usize, y0.max(0) as usize);
        let (x1, y1) = (
            (x1 + 1).min(w as i64) as usize,
            (y1 + 1).min(h as i64) as usize,
        );
        if x0 >= x1 || y0 >= y1 {
            return 0;
        }
        sat[y1 * (w + 1) + x1] + sat[y0 * (w + 1) + x0]
            - sat[y0 * (w + 1) + x1]
            - sat[y1 * (w + 1) + x0]
    };
    let finest = layout.finest_level();
    let r = layout.radius(finest);
    let (ex, ey) = layout.face_extent();
    let mut leaves = Vec::new();
    for cy in (r..ey.min(h as i64 - 1 + r + 1)).step_by(2 * r as usize) {
        for cx in (r..ex.min(w as i64 - 1 + r + 1)).step_by(2 * r as usize) {
            if count(cx - r, cy - r, cx + r, cy + r) > 0 {
                leaves.push(DiamondId::new(finest, cx as u32, cy as u32));
            }
        }
    }
    leaves
}

/// Rough terrain with a few nodata holes, deterministic in `seed`.
fn terrain(w: usize, h: usize, holes: &[u16], seed: u64) -> HeightGrid {
    let mut s = seed | 1;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    let values = (0..w * h)
        .map(|k| {
            let (x, y) = ((k % w) as f64, (k / w) as f64);
            let smooth = 300.0 * (x / 9.0).sin() * (y / 13.0).cos() + 4.0 * x;
            smooth as i32 + (next() % 41) as i32 - 20
        })
        .collect();
    let mut g = HeightGrid::all_valid(w, h, values);
    for &hole in holes {
        let c = hole as usize % (w * h);
        // A small square hole, so whole leaves can lose all their data.
        for k in [c, c + 1, c + w, c + w + 1] {
            if k < w * h {
                g.valid[k] = false;
            }
        }
    }
    g
}

fn both_ways(grid: &HeightGrid, q: Quantizer, opts: &EncodeOptions, storage: &TempStorage) {
    let old = encode_impl(grid, None, (q, None), opts, Keeping::PerDiamond, &|_, _| {}).unwrap();
    let new = encode_impl(
        grid,
        None,
        (q, None),
        opts,
        Keeping::Field(storage),
        &|_, _| {},
    )
    .unwrap();
    assert!(
        old == new,
        "field and per-diamond encoders differ on {}×{} {opts:?}",
        grid.width,
        grid.height
    );
}

/// The whole-domain field encoder against the block encoder with `plan`.
fn in_blocks_too(grid: &HeightGrid, q: Quantizer, opts: &EncodeOptions, plan: &BlockPlan) {
    let whole = encode_impl(
        grid,
        None,
        (q, None),
        opts,
        Keeping::Field(&TempStorage::Memory),
        &|_, _| {},
    )
    .unwrap();
    // In memory, and the same grid in mapped files: there the apex reads a copy of its
    // points and each block a window of its field, not the mapping (on Unix; elsewhere the
    // mapping in place), and the records go to a spill file.
    let mapped = grid.copied_to(&TempStorage::File(None)).unwrap();
    assert_eq!(mapped.windows(), cfg!(unix));
    for (input, storage) in [(grid, "memory"), (&mapped, "mapped files")] {
        let blocks = Encoder::new(input, q, opts)
            .in_blocks(plan, &super::super::blocks::NoJournal)
            .encode()
            .unwrap();
        assert!(
            whole == blocks,
            "block encoder of a grid in {storage} differs on {}×{} {opts:?} {plan:?}",
            grid.width,
            grid.height
        );
    }
    sharded_too(grid, &mapped, q, opts, plan, &whole);
}

/// The same split run as shards would run it: each part from its own encoder (another
/// process), the apex's field passed as values, the parts put together in reverse. The blocks
/// and the merge are set up from the apex's summary of the grid, each block given only the
/// samples of its field's rectangle (the rest nodata) and the merge none: what they read beyond
/// that would change the output. `mapped` is `grid` in mapped files; `whole` its field encode.
fn sharded_too(
    grid: &HeightGrid,
    mapped: &HeightGrid,
    q: Quantizer,
    opts: &EncodeOptions,
    plan: &BlockPlan,
    whole: &Encoded,
) {
    let first = ShardedEncode::new(grid, None, q, opts, *plan).unwrap();
    let apex = first.apex(&TempStorage::Memory).unwrap();
    // The apex of a grid in mapped files, from a copy of its points: the same.
    let from_files = ShardedEncode::new(mapped, None, q, opts, *plan).unwrap();
    let mut got = from_files.apex(&TempStorage::Memory).unwrap();
    let mut want = apex.clone();
    got.output.own_errors.sort_unstable();
    want.output.own_errors.sort_unstable();
    assert!(got == want, "the apex of a mapped grid differs");
    let summary = first.summary();
    let count = first.block_count();
    let finest = first.setup.params.layout().finest_level();
    let windowed = |rect| windowed(grid, rect);
    let mut parts: Vec<BlockOutput> = (0..count)
        .map(|i| {
            let mut part = windowed(first.block_field_rect(i));
            if i % 2 == 1 {
                // Every other shard's grid in mapped files, read through windows.
                part = part.copied_to(&TempStorage::File(None)).unwrap();
            }
            let shard =
                ShardedEncode::with_summary(&part, None, q, opts, *plan, summary.clone()).unwrap();
            let field = shard.apex_field(&apex.field, &TempStorage::Memory).unwrap();
            shard.block(&field, i, &TempStorage::Memory).unwrap()
        })
        .collect();
    parts.push(apex.output);
    parts.reverse();
    // The merge's grid in mapped files: it spills the records it gathers.
    let nothing = windowed(None).copied_to(&TempStorage::File(None)).unwrap();
    let merger =
        ShardedEncode::with_summary(&nothing, None, q, opts, *plan, summary.clone()).unwrap();
    if count > 0 {
        // A missing block is an error, not a repository with holes.
        let short: Vec<BlockOutput> = parts[..parts.len() - 1].to_vec();
        let cut = plan.cut_level.min(finest);
        let any_owned = parts
            .last()
            .is_some_and(|p| p.own_errors.iter().any(|(id, _)| id.level >= cut));
        if any_owned {
            let fresh = ShardedEncode::new(grid, None, q, opts, *plan).unwrap();
            assert!(
                fresh.finish(short).is_err(),
                "a missing block went unnoticed"
            );
        }
    }
    let sharded = merger.finish(parts).unwrap();
    assert!(
        *whole == sharded,
        "sharded encode differs on {}×{} {opts:?} {plan:?}",
        grid.width,
        grid.height
    );
}

/// `grid` with every sample outside `rect` (inclusive; none: all) made nodata, height 0.
fn windowed(grid: &HeightGrid, rect: Option<(i64, i64, i64, i64)>) -> HeightGrid {
    let mut part = grid.clone();
    for y in 0..grid.height {
        for x in 0..grid.width {
            let (x, y) = (x as i64, y as i64);
            let inside = rect
                .is_some_and(|(x0, y0, x1, y1)| (x0..=x1).contains(&x) && (y0..=y1).contains(&y));
            if !inside {
                let k = y as usize * grid.width + x as usize;
                part.values[k] = 0;
                part.valid[k] = false;
            }
        }
    }
    part
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn block_encoder_is_bit_identical_to_the_whole_field_one(
        n_pow in 1u32..5,
        w in 1usize..120,
        h in 1usize..120,
        extra in 0u32..2,
        k in 0u32..4,
        holes in proptest::collection::vec(any::<u16>(), 0..30),
        seed in any::<u64>(),
        cut in 0u8..12,
        side in 1i64..200,
    ) {
        let mut grid = terrain(w, h, &holes, seed);
        if grid.range().is_none() {
            grid.valid[0] = true;
        }
        let opts = EncodeOptions {
            n: (1 << n_pow) + 1,
            extra_level_pairs: extra,
            coder: CoderKind::ALL[(seed % CoderKind::ALL.len() as u64) as usize],
            ..EncodeOptions::default()
        };
        let plan = BlockPlan { cut_level: cut, block_side: side };
        in_blocks_too(&grid, Quantizer::new(k).unwrap(), &opts, &plan);
    }
    #[test]
    fn field_encoder_is_bit_identical_to_the_per_diamond_one(
        n_pow in 1u32..5,
        w in 1usize..90,
        h in 1usize..90,
        extra in 0u32..2,
        k in 0u32..4,
        holes in proptest::collection::vec(any::<u16>(), 0..30),
        seed in any::<u64>(),
        file in any::<bool>(),
    ) {
        let mut grid = terrain(w, h, &holes, seed);
        if grid.range().is_none() {
            grid.valid[0] = true;
        }
        let opts = EncodeOptions {
            n: (1 << n_pow) + 1,
            extra_level_pairs: extra,
            coder: CoderKind::ALL[(seed % CoderKind::ALL.len() as u64) as usize],
            ..EncodeOptions::default()
        };
        let storage = if file { TempStorage::File(None) } else { TempStorage::Memory };
        both_ways(&grid, Quantizer::new(k).unwrap(), &opts, &storage);
    }

    #[test]
    fn leaf_scan_matches_the_summed_area_table(
        n_pow in 1u32..4,
        w in 1usize..70,
        h in 1usize..70,
        extra in 0u32..2,
        holes in proptest::collection::vec(any::<u16>(), 0..400),
    ) {
        let grid = terrain(w, h, &holes, 7);
        let domain = Domain::covering((1 << n_pow) + 1, w, h, extra).unwrap();
        let layout = *domain.layout();
        let sets = stored_sets(&domain, &grid);
        prop_assert_eq!(&sets[layout.finest_level() as usize], &leaves_by_table(&layout, &grid));
    }
}

/// A single-band GeoTIFF of `data/` as a [`Dem`] (samples and GDAL's nodata tag; no
/// georeferencing, which the encoder does not read): the readers are the builder's, which
/// this crate's own tests cannot depend on.
fn read_tiff_fixture(path: &std::path::Path) -> Dem {
    use tiff::decoder::{Decoder, DecodingResult};
    let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
    let mut decoder = Decoder::new(file).unwrap();
    let (width, height) = decoder.dimensions().unwrap();
    let nodata = decoder
        .get_tag_ascii_string(tiff::tags::Tag::Unknown(42113))
        .ok()
        .and_then(|t| t.trim_matches(char::from(0)).trim().parse::<f64>().ok());
    let (values, sample_type): (Vec<f64>, _) = match decoder.read_image().unwrap() {
        DecodingResult::I16(v) => (v.into_iter().map(f64::from).collect(), SampleType::I16),
        DecodingResult::U16(v) => (v.into_iter().map(f64::from).collect(), SampleType::U16),
        DecodingResult::I32(v) => (v.into_iter().map(f64::from).collect(), SampleType::I32),
        DecodingResult::F32(v) => (v.into_iter().map(f64::from).collect(), SampleType::F32),
        DecodingResult::F64(v) => (v, SampleType::F64),
        _ => panic!("{}: a sample type the fixtures do not use", path.display()),
    };
    Dem {
        width: width as usize,
        height: height as usize,
        values,
        sample_type,
        nodata,
        georef: None,
    }
}

#[test]
fn field_encoder_is_bit_identical_on_real_dems_with_nodata_and_odd_sizes() {
    let data = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../data");
    // (file, window x0, y0, w, h, ε): nodata, odd sizes, a data rectangle ending mid-diamond.
    let cases = [
        ("rhine_nodata.tif", 0, 0, 0, 0, 1.0),
        ("srtm3_demcompare.tif", 37, 11, 301, 257, 1.0),
        ("lidar1m_mn.tif", 5, 3, 129, 200, 0.5),
        ("jacksboro_mpl.tif", 0, 0, 0, 0, 2.0),
    ];
    for (name, x0, y0, w, h, eps) in cases {
        let mut dem = read_tiff_fixture(&data.join(name));
        if w > 0 {
            dem = dem.crop(x0, y0, w, h).unwrap();
        }
        let plan = QuantPlan::for_dem(&dem, eps, None).unwrap();
        let grid = HeightGrid::from_dem(&dem, &plan).unwrap();
        if name.starts_with("rhine") {
            assert!(grid.valid.iter().any(|v| !v), "the fixture has nodata");
        }
        for n in [17, 65] {
            let opts = EncodeOptions {
                n,
                ..EncodeOptions::default()
            };
            both_ways(&grid, plan.quantizer, &opts, &TempStorage::Memory);
            // Blocks of a few finest diamonds (most of the work in margins) and of many.
            for (cut_level, block_side) in [(2, 64), (5, 300), (8, 97)] {
                let blocks = BlockPlan {
                    cut_level,
                    block_side,
                };
                in_blocks_too(&grid, plan.quantizer, &opts, &blocks);
            }
        }
    }
}
