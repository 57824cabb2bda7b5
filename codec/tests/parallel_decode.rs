//! The whole-hierarchy walk decodes each level's diamonds in parallel and visits them in order:
//! on any number of threads it must show `visit` exactly what one thread does, and report the
//! same first error for a damaged record; and what it shows must be what the renderer's
//! per-diamond decoder (`Decoder::grid_of`, `Decoder::refine`) makes of the same records.

use std::collections::HashMap;
use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};
use std::path::Path;

use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::{
    Decoder, EncodeOptions, Encoded, Encoder, RefineScratch, Refined, walk_all_batches,
    walk_all_with_validity,
};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan};

fn encode(name: &str, eps: f64, alpha: Alpha) -> Encoded {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data")
        .join(name);
    let dem = read_dem(&path, &ReadOptions::default()).unwrap();
    let plan = QuantPlan::for_dem(&dem, eps, None).unwrap();
    let grid = HeightGrid::from_dem(&dem, &plan).unwrap();
    let opts = EncodeOptions {
        alpha,
        ..EncodeOptions::default()
    };
    Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap()
}

/// Every visit in order, as (id, hash of grid and validity), or the error and how many visits
/// came before it, on `threads`.
fn walk_on(encoded: &Encoded, threads: usize) -> Result<Vec<(DiamondId, u64)>, String> {
    walk_batched_on(encoded, threads, false)
}

/// [`walk_on`], through `walk_all_batches` when `batched` (the batches one after another).
fn walk_batched_on(
    encoded: &Encoded,
    threads: usize,
    batched: bool,
) -> Result<Vec<(DiamondId, u64)>, String> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let mut seen = Vec::new();
        let mut visit = |id, grid: &[i32], valid: Option<&[bool]>| {
            let mut h = DefaultHasher::new();
            grid.hash(&mut h);
            valid.hash(&mut h);
            seen.push((id, h.finish()));
        };
        let walked = if batched {
            walk_all_batches(encoded, |batch| {
                assert!(!batch.is_empty(), "an empty batch");
                for v in batch {
                    visit(v.id, v.grid, v.valid);
                }
            })
        } else {
            walk_all_with_validity(encoded, visit)
        };
        walked
            .map(|()| seen.clone())
            // Where the walk stopped counts as much as why.
            .map_err(|e| format!("{e} after {} visits", seen.len()))
    })
}

#[test]
fn every_thread_count_visits_the_same_grids_in_the_same_order() {
    for (name, eps, alpha) in [
        ("srtm3_demcompare.tif", 1.0, Alpha::One),
        ("srtm3_demcompare.tif", 2.0, Alpha::Half),
        // A nodata mask: validities travel with the grids.
        ("rhine_nodata.tif", 0.5, Alpha::One),
    ] {
        let encoded = encode(name, eps, alpha);
        let serial = walk_on(&encoded, 1).unwrap();
        // Many levels, many diamonds: more than one parallel chunk on the finest levels.
        assert!(serial.len() > 200, "{name}: {} visits", serial.len());
        for threads in [2, 3, 8] {
            assert_eq!(
                walk_on(&encoded, threads).unwrap(),
                serial,
                "{name} ε={eps} {alpha:?} on {threads} threads"
            );
        }
        // The batches of the batched walk, one after another, are the serial walk.
        for threads in [1, 2, 5] {
            assert_eq!(
                walk_batched_on(&encoded, threads, true).unwrap(),
                serial,
                "{name} ε={eps} {alpha:?} in batches on {threads} threads"
            );
        }
    }
}

#[test]
fn a_damaged_record_gives_the_same_first_error_on_every_thread_count() {
    let mut encoded = encode("srtm3_demcompare.tif", 1.0, Alpha::One);
    // Damage two records of one level: the error a serial walk meets first must win.
    let finest_stored = encoded.records.iter().map(|r| r.id.level).max().unwrap();
    let on_level: Vec<usize> = (0..encoded.records.len())
        .filter(|&i| {
            encoded.records[i].id.level == finest_stored && !encoded.records[i].bytes.is_empty()
        })
        .collect();
    assert!(on_level.len() > 40, "{} records", on_level.len());
    for &i in [on_level[5], on_level[on_level.len() - 3]].iter() {
        let bytes = encoded.records[i].bytes.to_mut();
        bytes.truncate(bytes.len() / 2);
    }
    let serial = walk_on(&encoded, 1).unwrap_err();
    for threads in [2, 4] {
        assert_eq!(
            walk_on(&encoded, threads).unwrap_err(),
            serial,
            "{threads} threads"
        );
    }
    for threads in [1, 3] {
        assert_eq!(
            walk_batched_on(&encoded, threads, true).unwrap_err(),
            serial,
            "in batches on {threads} threads"
        );
    }
}

/// The walk refines each stored diamond in place of its grid (with α = 1 the refinement's
/// vertices are the grid, so no copy is made); every grid it visits, at every level and on
/// every thread count, must be the one the renderer's per-diamond decoder gathers from
/// refinements it made itself with the copying `Decoder::refine`.
#[test]
fn the_walk_shows_what_the_per_diamond_decoder_makes() {
    for (name, eps, alpha) in [
        ("srtm3_demcompare.tif", 1.0, Alpha::One),
        ("srtm3_demcompare.tif", 2.0, Alpha::Half),
        ("rhine_nodata.tif", 0.5, Alpha::One),
    ] {
        let encoded = encode(name, eps, alpha);
        let decoder = Decoder::new(encoded.params, &encoded.roots).unwrap();
        let records: HashMap<DiamondId, &[u8]> = encoded
            .records
            .iter()
            .map(|r| (r.id, &r.bytes[..]))
            .collect();
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut reference: HashMap<DiamondId, Refined> = HashMap::new();
            let mut scratch = RefineScratch::default();
            let mut visits = 0;
            pool.install(|| {
                walk_all_with_validity(&encoded, |id, grid, _| {
                    let parents = encoded
                        .params
                        .domain
                        .parents(id)
                        .map(|p| p.and_then(|p| reference.get(&p)));
                    let expected = decoder.grid_of(id, parents);
                    assert!(grid == &expected[..], "{name} {alpha:?}: grid of {id}");
                    if let Some(bytes) = records.get(&id) {
                        let refined = decoder.refine(id, &expected, bytes, &mut scratch).unwrap();
                        reference.insert(id, refined);
                    }
                    visits += 1;
                })
                .unwrap()
            });
            assert!(visits > 200, "{name}: {visits} visits");
        }
    }
}
