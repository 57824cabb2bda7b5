//! Per-diamond decode and whole-hierarchy encode speed on real DEMs (the targets: decode
//! ≥ 50 M output samples/s per coder, encode ≥ 10 M input samples/s, one core).
//!
//! - `refine/…`: [`Decoder::refine`] over every record of the hierarchy — entropy decoding plus
//!   synthesis. Throughput is in *output* samples: `(N−1)²` cells per record, plus `(N−2)²`
//!   inner vertices for α = ½.
//! - `grid_of/…`: [`Decoder::grid_of`] (the gather from the parents' refinements, or the root
//!   field) for every stored diamond. Throughput is in diamonds.
//! - `encode/…`: the whole [`encode`] on a one-thread rayon pool. Throughput is in *input*
//!   samples.
//!
//! `cargo bench -p cbdam-codec --bench refine -- --warm-up-time 1 --measurement-time 4`

use std::collections::HashMap;
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::{
    Decoder, EncodeOptions, Encoded, Encoder, RefineScratch, Refined, verify,
};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};

/// One benchmarked configuration.
struct Case {
    file: &'static str,
    eps: f64,
    alpha: Alpha,
    coder: CoderKind,
}

impl Case {
    fn label(&self) -> String {
        let stem = self.file.trim_end_matches(".tif");
        let alpha = match self.alpha {
            Alpha::One => "a1",
            Alpha::Half => "a0.5",
        };
        format!("{stem}/eps{}/{alpha}/{}", self.eps, self.coder.name())
    }
}

fn cases() -> Vec<Case> {
    let mut v = Vec::new();
    for coder in CoderKind::ALL {
        for (file, eps, alpha) in [
            ("srtm3_demcompare.tif", 1.0, Alpha::One),
            ("srtm3_demcompare.tif", 1.0, Alpha::Half),
            ("srtm3_demcompare.tif", 0.5, Alpha::One),
            ("srtm3_demcompare.tif", 5.0, Alpha::One),
            ("lidar1m_mn.tif", 1.0, Alpha::One),
        ] {
            v.push(Case {
                file,
                eps,
                alpha,
                coder,
            });
        }
    }
    v
}

/// Every stored diamond's grid and parents' refinements, decoded once up front so each
/// benchmark times only its own step.
struct Decoded {
    decoder: Decoder,
    /// Per record (same order as `Encoded::records`): its reconstructed `N × N` grid.
    grids: Vec<Vec<i32>>,
    /// Refinement of every stored diamond.
    refined: HashMap<DiamondId, Refined>,
}

fn decode_all(enc: &Encoded) -> Decoded {
    let decoder = Decoder::new(enc.params, &enc.roots).unwrap();
    let layout = enc.params.layout();
    let mut refined: HashMap<DiamondId, Refined> = HashMap::new();
    let mut grids = Vec::with_capacity(enc.records.len());
    let mut scratch = RefineScratch::default();
    // Records are sorted coarse to fine, so both parents are refined before their children.
    for r in &enc.records {
        let parents = layout
            .parents(r.id)
            .map(|p| p.and_then(|p| refined.get(&p)));
        let p = decoder.grid_of(r.id, parents);
        let out = decoder.refine(r.id, &p, &r.bytes, &mut scratch).unwrap();
        refined.insert(r.id, out);
        grids.push(p);
    }
    Decoded {
        decoder,
        grids,
        refined,
    }
}

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data")
        .join(name)
}

fn bench(c: &mut Criterion) {
    let one_thread = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let mut dems = HashMap::new();
    for case in cases() {
        let dem = dems
            .entry(case.file)
            .or_insert_with(|| read_dem(&data(case.file), &ReadOptions::default()).unwrap());
        let plan = QuantPlan::for_dem(dem, case.eps, None).unwrap();
        let grid = HeightGrid::from_dem(dem, &plan).unwrap();
        let opts = EncodeOptions {
            alpha: case.alpha,
            coder: case.coder,
            ..EncodeOptions::default()
        };
        let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
        // A fast wrong decoder is worth nothing: the benchmarked hierarchy must be correct.
        assert!(
            verify(&enc, &grid).unwrap().within_bound(),
            "{}",
            case.label()
        );
        let dec = decode_all(&enc);
        let n = enc.params.layout().n() as u64;
        let per_record = (n - 1) * (n - 1)
            + if case.alpha == Alpha::Half {
                (n - 2) * (n - 2)
            } else {
                0
            };
        let records = enc.records.len() as u64;
        let label = case.label();
        eprintln!(
            "{label}: {} records, {:.3} bits/input sample",
            records,
            enc.payload_bytes() as f64 * 8.0 / (grid.width * grid.height) as f64
        );

        let mut g = c.benchmark_group("refine");
        g.throughput(Throughput::Elements(records * per_record));
        g.bench_function(&label, |b| {
            let mut scratch = RefineScratch::default();
            b.iter(|| {
                for (r, p) in enc.records.iter().zip(&dec.grids) {
                    black_box(dec.decoder.refine(r.id, p, &r.bytes, &mut scratch).unwrap());
                }
            })
        });
        g.finish();

        let layout = enc.params.layout();
        let parents: Vec<(DiamondId, [Option<&Refined>; 2])> = enc
            .records
            .iter()
            .map(|r| {
                let ps = layout
                    .parents(r.id)
                    .map(|p| p.and_then(|p| dec.refined.get(&p)));
                (r.id, ps)
            })
            .collect();
        let mut g = c.benchmark_group("grid_of");
        g.throughput(Throughput::Elements(records));
        g.bench_function(&label, |b| {
            b.iter(|| {
                for &(id, ps) in &parents {
                    black_box(dec.decoder.grid_of(id, ps));
                }
            })
        });
        g.finish();

        let mut g = c.benchmark_group("encode");
        g.throughput(Throughput::Elements((grid.width * grid.height) as u64));
        g.bench_function(&label, |b| {
            b.iter(|| {
                one_thread
                    .install(|| black_box(Encoder::new(&grid, plan.quantizer, &opts).encode()))
            })
        });
        g.finish();
    }
}

criterion_group! {
    name = benches;
    // Quick by default, so `cargo test --all-targets` (one pass in test mode) and a plain
    // `cargo bench` stay short; pass `--measurement-time` for steadier numbers.
    config = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
    targets = bench
}
criterion_main!(benches);
