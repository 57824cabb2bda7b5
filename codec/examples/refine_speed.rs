//! Per-diamond decode speed of one configuration, without criterion: encodes one DEM once (timed,
//! on one thread), then refines every record `reps` times and prints M output samples/s and a
//! checksum of the output.
//! Small enough to run under `valgrind --tool=callgrind` (pass `reps` = 1), and quick to
//! alternate against another build on a loaded machine.
//!
//! `cargo run --release -p cbdam-codec --example refine_speed -- FILE EPS ALPHA CODER REPS`
//! e.g. `… -- data/srtm3_demcompare.tif 0.5 1 adaptive 20` (ALPHA: `1` or `0.5`; CODER:
//! `adaptive` or `gamma`).

use std::collections::HashMap;
use std::hint::black_box;
use std::path::Path;
use std::time::Instant;

use cbdam_codec::entropy::CoderKind;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::{Decoder, EncodeOptions, RefineScratch, Refined, encode};
use cbdam_codec::input::{ReadOptions, read_dem};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [file, eps, alpha, coder, reps] = &args[..] else {
        panic!("usage: refine_speed FILE EPS ALPHA(1|0.5) CODER(adaptive|gamma) REPS");
    };
    let eps: f64 = eps.parse().expect("EPS");
    let alpha = match alpha.as_str() {
        "1" => Alpha::One,
        "0.5" => Alpha::Half,
        a => panic!("ALPHA {a}"),
    };
    let coder = match coder.as_str() {
        "adaptive" => CoderKind::Adaptive,
        "gamma" => CoderKind::EliasGamma,
        c => panic!("CODER {c}"),
    };
    let reps: usize = reps.parse().expect("REPS");
    let dem = read_dem(Path::new(file), &ReadOptions::default()).expect("DEM");
    let plan = QuantPlan::for_dem(&dem, eps, None).expect("plan");
    let grid = HeightGrid::from_dem(&dem, &plan).expect("grid");
    let opts = EncodeOptions {
        alpha,
        coder,
        ..EncodeOptions::default()
    };
    // Timed on one thread, like the `encode/…` rows of the refine bench.
    let one_thread = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let t = Instant::now();
    let enc = one_thread
        .install(|| encode(&grid, plan.quantizer, &opts))
        .expect("encode");
    let encode_s = t.elapsed().as_secs_f64();
    let decoder = Decoder::new(enc.params, &enc.roots).expect("roots");
    let layout = enc.params.layout;
    let mut refined: HashMap<DiamondId, Refined> = HashMap::new();
    let mut grids = Vec::with_capacity(enc.records.len());
    let mut scratch = RefineScratch::default();
    for r in &enc.records {
        let parents = layout
            .parents(r.id)
            .map(|p| p.and_then(|p| refined.get(&p)));
        let p = decoder.grid_of(r.id, parents);
        refined.insert(r.id, decoder.refine(&p, &r.bytes, &mut scratch).unwrap());
        grids.push(p);
    }
    // Checksum of every refinement, so two builds can be compared for identical output.
    let mut sum = 0u64;
    for r in &enc.records {
        let x = &refined[&r.id];
        let n = x.n();
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                sum = sum.wrapping_mul(31).wrapping_add(x.cell(i, j) as u64);
            }
        }
        for j in 0..n {
            for i in 0..n {
                sum = sum.wrapping_mul(31).wrapping_add(x.vertex(i, j) as u64);
            }
        }
    }
    let n = layout.n();
    let per_record = (n - 1) * (n - 1)
        + if alpha == Alpha::Half {
            (n - 2) * (n - 2)
        } else {
            0
        };
    let samples = (per_record * enc.records.len() * reps) as f64;
    let t = Instant::now();
    for _ in 0..reps {
        for (r, p) in enc.records.iter().zip(&grids) {
            black_box(decoder.refine(p, &r.bytes, &mut scratch).unwrap());
        }
    }
    let s = t.elapsed().as_secs_f64();
    let bytes: usize = enc.records.iter().map(|r| r.bytes.len()).sum();
    println!(
        "{} records, {:.3} bits/output sample, checksum {sum:016x}, encode {:.2} M input \
         samples/s, {:.2} M samples/s",
        enc.records.len(),
        bytes as f64 * 8.0 / (per_record * enc.records.len()) as f64,
        (grid.width * grid.height) as f64 / encode_s / 1e6,
        samples / s / 1e6
    );
}
