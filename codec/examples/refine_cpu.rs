//! The `refine` bench's loop (`benches/refine.rs`: [`Decoder::refine`] over every record of a
//! bundled DEM's hierarchy, α = 1) timed in the thread's **CPU time** rather than wall time, so
//! that two builds can be compared on a loaded machine: ROUNDS passes of PASSES loops each, the
//! median pass printed in µs. CPU time from `/proc/thread-self/schedstat` (Linux, ns).
//!
//! `cargo run --release -p cbdam-codec --example refine_cpu -- DEM.tif EPS CODER [ROUNDS] [PASSES]`

use std::collections::HashMap;
use std::hint::black_box;

use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::{Decoder, verify};
use cbdam_codec::hierarchy::{EncodeOptions, Encoder, RefineScratch, Refined};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan};

/// This thread's CPU time so far, ns.
fn thread_cpu_ns() -> u64 {
    let stat = std::fs::read_to_string("/proc/thread-self/schedstat").expect("Linux schedstat");
    stat.split_whitespace()
        .next()
        .and_then(|t| t.parse().ok())
        .expect("schedstat's first field")
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [file, eps, coder, ..] = &args[..] else {
        panic!("usage: refine_cpu DEM.tif EPS CODER [ROUNDS] [PASSES]");
    };
    let number = |i: usize, default: usize| args.get(i).map_or(default, |a| a.parse().unwrap());
    let (rounds, passes) = (number(3, 9), number(4, 20));
    let eps: f64 = eps.parse().expect("EPS in metres");
    let coder = CoderKind::ALL
        .into_iter()
        .find(|c| c.name() == coder)
        .expect("a coder name");
    let dem = read_dem(std::path::Path::new(file), &ReadOptions::default()).unwrap();
    let plan = QuantPlan::for_dem(&dem, eps, None).unwrap();
    let grid = HeightGrid::from_dem(&dem, &plan).unwrap();
    let opts = EncodeOptions {
        alpha: Alpha::One,
        coder,
        ..EncodeOptions::default()
    };
    let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
    assert!(verify(&enc, &grid).unwrap().within_bound());
    // Every record's grid, from its parents' refinements (records are sorted coarse to fine).
    let decoder = Decoder::new(enc.params, &enc.roots).unwrap();
    let layout = enc.params.layout();
    let mut refined: HashMap<DiamondId, Refined> = HashMap::new();
    let mut grids = Vec::with_capacity(enc.records.len());
    let mut scratch = RefineScratch::default();
    for r in &enc.records {
        let parents = layout
            .parents(r.id)
            .map(|p| p.and_then(|p| refined.get(&p)));
        let p = decoder.grid_of(r.id, parents);
        let out = decoder.refine(r.id, &p, &r.bytes, &mut scratch).unwrap();
        refined.insert(r.id, out);
        grids.push(p);
    }
    let mut per_pass = Vec::with_capacity(rounds);
    for _ in 0..rounds {
        let t0 = thread_cpu_ns();
        for _ in 0..passes {
            for (r, p) in enc.records.iter().zip(&grids) {
                black_box(decoder.refine(r.id, p, &r.bytes, &mut scratch).unwrap());
            }
        }
        per_pass.push((thread_cpu_ns() - t0) as f64 / passes as f64 / 1e3);
    }
    let mut sorted = per_pass.clone();
    sorted.sort_by(f64::total_cmp);
    println!(
        "{file} eps {eps} {} {} records: median {:.1} µs CPU a pass; passes {:?}",
        coder.name(),
        enc.records.len(),
        sorted[rounds / 2],
        per_pass.iter().map(|t| t.round()).collect::<Vec<_>>()
    );
}
