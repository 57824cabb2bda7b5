//! A quantizer per level (header flag bit 5, what `--rms-error` may write): every level's
//! samples are within that level's own bound, and every decoder — the whole-file walk, the
//! file read back, a windowed decode and the client's diamond-by-diamond refinement — decodes
//! the same samples, which on the levels quantized losslessly are the input exactly.

use std::collections::HashMap;

use cbdam_codec::geometry::{DiamondId, Domain};
use cbdam_codec::hierarchy::{
    Decoder, EncodeOptions, Encoded, Encoder, LevelWindow, RefineScratch, Refined, decode_window,
    verify, walk_all_with_validity,
};
use cbdam_codec::quant::{HeightGrid, LevelQuantizers, QuantPlan, Quantizer, RmsBound};
use cbdam_codec::repository::{Repository, serialize};

use crate::util::CountedReads;

fn terrain(w: usize, h: usize) -> HeightGrid {
    let values = (0..w * h)
        .map(|k| {
            let (x, y) = ((k % w) as f64, (k / w) as f64);
            (300.0 * (x / 9.0).sin() * (y / 7.0).cos() + 3.0 * y) as i32 + (k * 7919 % 29) as i32
        })
        .collect();
    let mut g = HeightGrid::all_valid(w, h, values);
    // A scatter of samples without data, so the records carry nodata masks too.
    for (i, v) in g.valid.iter_mut().enumerate() {
        *v = i % 37 != 5;
    }
    g
}

/// Per level: records of level 0 lossless, then coarse and fine steps mixed.
fn per_level(finest: u8) -> LevelQuantizers {
    let pattern = [0, 6, 1, 9, 3, 12, 2, 5];
    let ks: Vec<u32> = (0..usize::from(finest)).map(|l| pattern[l % 8]).collect();
    LevelQuantizers::new(&ks).unwrap()
}

fn encode(grid: &HeightGrid, opts: &EncodeOptions) -> (Encoded, LevelQuantizers) {
    let d = Domain::covering(opts.n, grid.width, grid.height, 0).unwrap();
    let levels = per_level(d.layout().finest_level());
    let top = Quantizer::new(levels.max_k()).unwrap();
    let enc = Encoder::new(grid, top, opts)
        .per_level(Some(levels))
        .encode()
        .unwrap();
    (enc, levels)
}

/// Every grid the whole-file walk visits, by diamond (the last visit of each).
fn walked(enc: &Encoded) -> HashMap<DiamondId, Vec<i32>> {
    let mut grids = HashMap::new();
    walk_all_with_validity(enc, |id, g, _| {
        grids.insert(id, g.to_vec());
    })
    .unwrap();
    grids
}

#[test]
fn each_level_is_within_its_own_bound_and_the_lossless_one_is_exact() {
    let grid = terrain(131, 97);
    let opts = EncodeOptions {
        n: 9,
        ..EncodeOptions::default()
    };
    let (enc, levels) = encode(&grid, &opts);
    assert_eq!(enc.params.levels, Some(levels));
    // Half of level 0's k: the roots are lossless too.
    assert_eq!(enc.params.root_quantizer.k(), 0);
    let report = verify(&enc, &grid).unwrap();
    assert!(report.within_bound(), "{report:?}");
    assert_eq!(report.bound, levels.max_k());
    for l in &report.levels {
        let bound = levels.level_bound(0, l.level);
        assert_eq!(l.bound, bound, "level {}", l.level);
        assert!(l.max_error <= bound, "level {}: {l:?}", l.level);
    }
    // Level 1's samples are the roots and level 0's records, both lossless: the input exactly.
    assert_eq!(report.levels[1].max_error, 0, "{report:?}");
    // The coarse steps are used: a level below the coarsest step's level is off by more than
    // the finest steps above it allow.
    assert!(report.levels[4].max_error > 1, "{report:?}");
}

#[test]
fn the_file_a_window_and_the_clients_refinement_decode_what_the_walk_decodes() {
    let grid = terrain(131, 97);
    let opts = EncodeOptions {
        n: 9,
        ..EncodeOptions::default()
    };
    let (enc, levels) = encode(&grid, &opts);
    let want = walked(&enc);
    // The file: flag bit 5 and the list round-trip, and its walk is the same.
    let mut plan = QuantPlan::new(1.0, Some(1.0), -1000.0, 1000.0).unwrap();
    (plan.quantizer, plan.levels) = (enc.params.quantizer, Some(levels));
    plan.rms = Some(RmsBound {
        target: 10.0,
        measured: 5.0,
    });
    let repo = Repository::from_bytes(serialize(&enc, &plan, None, None).unwrap()).unwrap();
    assert_eq!(repo.head().params().levels, Some(levels));
    assert_eq!(repo.head().plan().levels, Some(levels));
    let read = repo.to_encoded().unwrap();
    assert!(walked(&read) == want, "the file decodes otherwise");
    // The client: one diamond at a time, coarse to fine, through the decoder's refine.
    let decoder = Decoder::new(enc.params, &enc.roots).unwrap();
    let mut refined: HashMap<DiamondId, Refined> = HashMap::new();
    let mut scratch = RefineScratch::default();
    for r in &enc.records {
        let parents = enc
            .params
            .domain
            .parents(r.id)
            .map(|p| p.and_then(|p| refined.get(&p)));
        let g = decoder.grid_of(r.id, parents);
        assert!(want[&r.id] == g, "grid of {}", r.id);
        refined.insert(
            r.id,
            decoder.refine(r.id, &g, &r.bytes, &mut scratch).unwrap(),
        );
    }
    // The finest grids gathered from the client's refinements are the walk's.
    let finest = enc.params.layout().finest_level();
    for (id, g) in want.iter().filter(|(id, _)| id.level == finest) {
        let parents = enc
            .params
            .domain
            .parents(*id)
            .map(|p| p.and_then(|p| refined.get(&p)));
        assert!(decoder.grid_of(*id, parents) == *g, "finest grid of {id}");
    }
    // A window at every level.
    let reads = CountedReads::new(&enc);
    for level in 0..=finest {
        let rect = (20, 10, 90, 60);
        let window = LevelWindow { level, rect };
        let mut seen = 0;
        decode_window(
            enc.params,
            &enc.roots,
            &reads.stored,
            |id| reads.read(id),
            window,
            |id, g, _| {
                if id.level == level {
                    assert!(want[&id] == g, "window at level {level}: grid of {id}");
                    seen += 1;
                }
            },
        )
        .unwrap();
        assert!(seen > 0, "level {level}");
    }
}
