//! Hostile record bytes into `Decoder::refine` for a fixed small hierarchy: never a panic
//! (fuzz builds keep overflow checks on), and whatever decodes gives representable heights to
//! the diamond's children.
//!
//! Input layout: `[selector byte, record..]`; the selector picks the coder, α, whether the
//! hierarchy has nodata (so records start with a nodata mask) and which stored diamond (so which
//! parent grid) the record refines.
#![no_main]

use std::sync::OnceLock;

use cbdam_codec::entropy::CoderKind;
use cbdam_codec::hierarchy::{Decoder, EncodeOptions, Encoded, RefineScratch, Encoder, walk, walk_with_validity};
use cbdam_codec::lifting::{Alpha, MAX_ABS_HEIGHT};
use cbdam_codec::quant::{HeightGrid, Quantizer};
use libfuzzer_sys::fuzz_target;

/// One small hierarchy per (coder, α): its decoder and every stored diamond's grid.
struct Fixture {
    enc: Encoded,
    decoder: Decoder,
    grids: Vec<Vec<i32>>,
}

fn fixtures() -> &'static [Fixture] {
    static F: OnceLock<Vec<Fixture>> = OnceLock::new();
    F.get_or_init(|| {
        // 40 × 30 integer terrain with a cliff, N = 9: a handful of levels, records of both
        // smooth and steep residuals.
        let (w, h) = (40usize, 30usize);
        let values = (0..w * h)
            .map(|k| {
                let (x, y) = ((k % w) as i32, (k / w) as i32);
                5 * x - 3 * y + (x * y) % 11 + if x > y { 400 } else { 0 }
            })
            .collect();
        let plain = HeightGrid::all_valid(w, h, values);
        let mut holed = plain.clone();
        for (k, v) in holed.valid.iter_mut().enumerate() {
            *v = !(k % 7 == 0 || (10..20).contains(&(k % w)));
        }
        let mut out = Vec::new();
        for grid in [&plain, &holed] {
            for coder in CoderKind::ALL {
                for alpha in [Alpha::One, Alpha::Half] {
                    let opts = EncodeOptions {
                        n: 9,
                        alpha,
                        coder,
                        ..EncodeOptions::default()
                    };
                    let enc = Encoder::new(&grid, Quantizer::new(2).unwrap(), &opts).encode().unwrap();
                    let decoder = Decoder::new(enc.params, &enc.roots).unwrap();
                    let mut by_id = std::collections::HashMap::new();
                    walk(&enc, |id, p| {
                        by_id.insert(id, p.to_vec());
                    })
                    .unwrap();
                    let grids = enc.records.iter().map(|r| by_id[&r.id].clone()).collect();
                    out.push(Fixture {
                        enc,
                        decoder,
                        grids,
                    });
                }
            }
        }
        out
    })
}

fuzz_target!(|data: &[u8]| {
    let [sel, record @ ..] = data else { return };
    let fs = fixtures();
    // Every fixture (grid × coder × α) and, with what is left of the byte, the diamond.
    let f = &fs[usize::from(*sel) % fs.len()];
    let ri = usize::from(*sel) / fs.len() % f.enc.records.len();
    let mut scratch = RefineScratch::default();
    if f.decoder
        .refine(f.enc.records[ri].id, &f.grids[ri], record, &mut scratch)
        .is_err()
    {
        return;
    }
    // It decoded: the whole hierarchy with this record in place must stay representable.
    let mut damaged = f.enc.clone();
    damaged.records[ri].bytes = record.to_vec().into();
    let _ = walk_with_validity(&damaged, |id, p, _| {
        if let Some(v) = p.iter().find(|v| v.unsigned_abs() > MAX_ABS_HEIGHT as u32) {
            panic!("{id}: decoded height {v} out of range");
        }
    });
});
