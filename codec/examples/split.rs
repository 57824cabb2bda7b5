use cbdam_codec::hierarchy::{EncodeOptions, encode};
use cbdam_codec::input::{ReadOptions, read_dem};
use cbdam_codec::quant::{HeightGrid, QuantPlan};
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let dem = read_dem(std::path::Path::new(&args[1]), &ReadOptions::default()).unwrap();
    let eps: f64 = args[2].parse().unwrap();
    let plan = QuantPlan::for_dem(&dem, eps, None).unwrap();
    let grid = HeightGrid::from_dem(&dem, &plan).unwrap();
    let e = encode(&grid, plan.quantizer, &EncodeOptions::default()).unwrap();
    println!("plan {plan:?} layout {:?}", e.params.layout);
    println!("roots {} bytes", e.roots.len());
    let mut per = std::collections::BTreeMap::new();
    for r in &e.records { let x = per.entry(r.id.level).or_insert((0,0,0)); x.0 += 1; x.1 += r.bytes.len(); if r.bytes.is_empty() { x.2 += 1; } }
    for (l, (c, b, z)) in per { println!("level {l}: {c} records, {b} bytes, {z} empty"); }
}
