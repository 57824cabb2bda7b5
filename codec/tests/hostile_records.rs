//! Hostile bytes at the hierarchy level: real records of an encoded SRTM hierarchy, truncated,
//! bit-flipped or replaced by random bytes, go through `Decoder::refine` (and damaged root
//! fields through `Decoder::new`). Whatever comes back, nothing may panic — the test profile
//! keeps overflow checks on, so arithmetic overflow in the synthesis panics here too — and
//! whatever damaged data decodes must stay within the heights the format can represent, all the
//! way down the hierarchy.

use crate::util::Rng;
use std::collections::HashMap;
use std::path::Path;

use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::{
    Decoder, EncodeOptions, Encoded, Encoder, RefineScratch, walk, walk_with_validity,
};
use cbdam_codec::lifting::{Alpha, MAX_ABS_HEIGHT};
use cbdam_codec::quant::{HeightGrid, QuantPlan};

/// A 256 × 256 window of SRTM at ε = 1 m: real residual statistics, a few levels of diamonds.
/// With `nodata`, a disc and a sprinkling of samples are nodata, so the root field and records
/// carry nodata masks that the damage reaches too.
fn hierarchy(alpha: Alpha, coder: CoderKind, nodata: bool) -> Encoded {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/srtm3_demcompare.tif");
    let dem = read_dem(&path, &ReadOptions::default()).unwrap();
    let part = dem.crop(500, 300, 256, 256).unwrap();
    let plan = QuantPlan::for_dem(&part, 1.0, None).unwrap();
    let mut grid = HeightGrid::from_dem(&part, &plan).unwrap();
    if nodata {
        for (k, v) in grid.valid.iter_mut().enumerate() {
            let (x, y) = ((k % 256) as i64 - 90, (k / 256) as i64 - 150);
            if x * x + y * y < 60 * 60 || k % 97 == 0 {
                *v = false;
            }
        }
    }
    let opts = EncodeOptions {
        alpha,
        coder,
        ..EncodeOptions::default()
    };
    Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap()
}

/// Every stored diamond's reconstructed grid, from an undamaged decode.
fn grids(enc: &Encoded) -> HashMap<DiamondId, Vec<i32>> {
    let mut out = HashMap::new();
    walk(enc, |id, p| {
        out.insert(id, p.to_vec());
    })
    .unwrap();
    out
}

/// Decodes the whole hierarchy with `record` replaced by `bytes` and checks every grid the
/// walk reaches. Children of a damaged diamond are refined from damaged grids, so this also
/// drives the synthesis with extreme (but in-range) inputs. An error part-way is fine.
fn walk_damaged(enc: &Encoded, record: usize, bytes: &[u8]) -> usize {
    let mut damaged = enc.clone();
    damaged.records[record].bytes = bytes.to_vec().into();
    walk_checked(&damaged)
}

/// Walks `enc` and asserts every visited height is representable; returns the grids seen.
fn walk_checked(enc: &Encoded) -> usize {
    let mut seen = 0;
    let _ = walk_with_validity(enc, |id, p, _| {
        seen += 1;
        if let Some(v) = p.iter().find(|v| v.unsigned_abs() > MAX_ABS_HEIGHT as u32) {
            panic!("{id}: decoded height {v} is out of range");
        }
    });
    seen
}

fn configs() -> Vec<(Alpha, CoderKind, bool)> {
    let mut v = Vec::new();
    for coder in CoderKind::ALL {
        for alpha in [Alpha::One, Alpha::Half] {
            v.push((alpha, coder, false));
        }
        v.push((Alpha::One, coder, true));
    }
    v
}

#[test]
fn truncated_records_never_panic() {
    for (alpha, coder, nodata) in configs() {
        let enc = hierarchy(alpha, coder, nodata);
        assert_eq!(enc.params.nodata_mask, nodata);
        let grids = grids(&enc);
        let decoder = Decoder::new(enc.params, &enc.roots).unwrap();
        let mut scratch = RefineScratch::default();
        let (mut total, mut accepted) = (0usize, 0usize);
        for r in &enc.records {
            let p = &grids[&r.id];
            // The intact record decodes: otherwise the truncations below prove nothing.
            decoder.refine(r.id, p, &r.bytes, &mut scratch).unwrap();
            for len in 0..r.bytes.len() {
                total += 1;
                if decoder
                    .refine(r.id, p, &r.bytes[..len], &mut scratch)
                    .is_ok()
                {
                    accepted += 1;
                }
            }
        }
        // Accepting a cut record is not a safety problem (the values are still bounded), only
        // undetected damage; report how often it happens.
        eprintln!(
            "{alpha:?} {}: {} records, {total} truncations, {accepted} accepted",
            coder.name(),
            enc.records.len()
        );
        assert!(
            total > 1000,
            "too few truncations to mean anything: {total}"
        );
    }
}

#[test]
fn bit_flipped_records_never_panic_and_stay_in_range() {
    let mut rng = Rng(7);
    for (alpha, coder, nodata) in configs() {
        let enc = hierarchy(alpha, coder, nodata);
        assert_eq!(enc.params.nodata_mask, nodata);
        let grids = grids(&enc);
        let decoder = Decoder::new(enc.params, &enc.roots).unwrap();
        let mut scratch = RefineScratch::default();
        let (mut accepted, mut walked) = (0usize, 0usize);
        const FLIPS: usize = 2500;
        for _ in 0..FLIPS {
            let ri = rng.below(enc.records.len());
            let r = &enc.records[ri];
            let mut bytes = r.bytes.to_vec();
            let bit = rng.below(bytes.len() * 8);
            bytes[bit / 8] ^= 1 << (bit % 8);
            if decoder
                .refine(r.id, &grids[&r.id], &bytes, &mut scratch)
                .is_ok()
            {
                accepted += 1;
                // Whole walks are slower: check the range downstream for some of them.
                if walked < 150 {
                    walked += 1;
                    assert!(
                        walk_damaged(&enc, ri, &bytes) > 0,
                        "the walk reached no grid"
                    );
                }
            }
        }
        eprintln!(
            "{alpha:?} {}: {FLIPS} flips, {accepted} accepted, {walked} walked",
            coder.name()
        );
        // The range checks above run only on what was accepted: with nothing accepted (a
        // decoder refusing everything, or a broken damage loop) they would check nothing.
        assert!(
            walked > 0,
            "{alpha:?} {}: no flipped record accepted, so no range was checked",
            coder.name()
        );
    }
}

#[test]
fn random_records_never_panic_and_stay_in_range() {
    let mut rng = Rng(11);
    for (alpha, coder, nodata) in configs() {
        let enc = hierarchy(alpha, coder, nodata);
        assert_eq!(enc.params.nodata_mask, nodata);
        let grids = grids(&enc);
        let decoder = Decoder::new(enc.params, &enc.roots).unwrap();
        let mut scratch = RefineScratch::default();
        let longest = enc.records.iter().map(|r| r.bytes.len()).max().unwrap();
        let (mut accepted, mut walked) = (0usize, 0usize);
        const TRIES: usize = 1500;
        for t in 0..TRIES {
            let ri = rng.below(enc.records.len());
            let len = rng.below(2 * longest + 2);
            let mut bytes: Vec<u8> = (0..len).map(|_| rng.next() as u8).collect();
            // A real record with a run of up to 16 random bytes inside it (its last byte kept):
            // the coders accept these far more often than whole random streams, which they
            // almost always refuse, so the range checks below see random data decoded.
            if t % 3 == 2 {
                bytes = enc.records[ri].bytes.to_vec();
                if bytes.len() > 1 {
                    let at = rng.below(bytes.len() - 1);
                    let run = 1 + rng.below(16.min(bytes.len() - 1 - at));
                    for b in &mut bytes[at..at + run] {
                        *b = rng.next() as u8;
                    }
                }
            }
            // Sparse bytes too: mostly-zero streams look like plausible "nothing to correct"
            // prefixes and reach deeper into the coders than uniform noise.
            if t % 3 == 1 {
                for b in &mut bytes {
                    if rng.below(8) != 0 {
                        *b = 0;
                    }
                }
            }
            if decoder
                .refine(
                    enc.records[ri].id,
                    &grids[&enc.records[ri].id],
                    &bytes,
                    &mut scratch,
                )
                .is_ok()
            {
                accepted += 1;
                if walked < 100 {
                    walked += 1;
                    assert!(
                        walk_damaged(&enc, ri, &bytes) > 0,
                        "the walk reached no grid"
                    );
                }
            }
        }
        eprintln!(
            "{alpha:?} {}: {TRIES} random records, {accepted} accepted, {walked} walked",
            coder.name()
        );
        // The range checks run only on what was accepted: with nothing accepted they would
        // check nothing.
        assert!(
            walked > 0,
            "{alpha:?} {}: no random record accepted, so no range was checked",
            coder.name()
        );
    }
}

#[test]
fn damaged_root_fields_never_panic_and_stay_in_range() {
    let mut rng = Rng(13);
    for (alpha, coder, nodata) in configs() {
        let enc = hierarchy(alpha, coder, nodata);
        assert_eq!(enc.params.nodata_mask, nodata);
        Decoder::new(enc.params, &enc.roots).unwrap();
        let mut damaged = enc.clone();
        let mut accepted = 0usize;
        let mut tries: Vec<Vec<u8>> = (0..enc.roots.len())
            .map(|len| enc.roots[..len].to_vec())
            .collect();
        for _ in 0..500 {
            let mut bytes = enc.roots.clone();
            let bit = rng.below(bytes.len() * 8);
            bytes[bit / 8] ^= 1 << (bit % 8);
            tries.push(bytes);
        }
        for _ in 0..500 {
            let len = rng.below(2 * enc.roots.len() + 2);
            tries.push((0..len).map(|_| rng.next() as u8).collect());
        }
        let mut seen = 0;
        for bytes in tries {
            if Decoder::new(enc.params, &bytes).is_ok() {
                accepted += 1;
                damaged.roots = bytes;
                seen += walk_checked(&damaged);
            }
        }
        eprintln!(
            "{alpha:?} {}: root field of {} bytes, {accepted} damaged versions accepted, \
             {seen} grids checked",
            coder.name(),
            enc.roots.len()
        );
        assert!(
            seen > 0,
            "{alpha:?} {}: no damaged root field accepted, so no range was checked",
            coder.name()
        );
    }
}
