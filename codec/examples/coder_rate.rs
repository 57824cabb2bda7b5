//! Bytes and decode speed of every coder on the cell records of existing repositories: each
//! record is decoded with the coder that wrote it, re-encoded with every coder, and the
//! re-encoded records decoded again, timed in CPU time (best of five passes, one thread). α = 1
//! repositories without a nodata mask; the root field is left out. A tool for tuning a coder
//! on real residuals without rebuilding repositories.
//!
//! `cargo run --release -p cbdam-codec --example coder_rate -- REPO.cbdam...`

use cbdam_codec::entropy::{
    Band, BandKind, BandMut, CoderKind, DecodeLimits, DecodeScratch, decode_bands,
    decode_bands_with, encode_bands,
};
use cbdam_codec::repository::Repository;
use std::path::Path;
use std::time::Instant;

/// Every cell record of `repo`, decoded.
fn cell_bands(repo: &Repository, side: usize) -> Vec<Vec<i32>> {
    let coder = repo.head().params().coder;
    let mut bands = Vec::new();
    while let Ok(bytes) = repo.record_at(bands.len()) {
        let mut values = vec![0i32; side * side];
        let mut band = [BandMut {
            kind: BandKind::Cells,
            width: side,
            height: side,
            values: &mut values,
        }];
        decode_bands(coder, bytes, &mut band, DecodeLimits::default())
            .expect("an α = 1 record without a mask");
        bands.push(values);
    }
    bands
}

/// This thread's CPU time in seconds (Linux: `/proc/thread-self/schedstat`), so that other
/// processes' load does not count; wall-clock time where that is not available.
fn cpu_seconds(wall: Instant) -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .map_or(wall.elapsed().as_secs_f64(), |ns| ns as f64 * 1e-9)
}

/// Decodes `records` with `coder`, best of five passes: CPU seconds.
fn decode_seconds(coder: CoderKind, records: &[Vec<u8>], side: usize) -> f64 {
    let mut scratch = DecodeScratch::default();
    let mut values = vec![0i32; side * side];
    let mut best = f64::INFINITY;
    let wall = Instant::now();
    for _ in 0..5 {
        let start = cpu_seconds(wall);
        for bytes in records {
            let mut band = [BandMut {
                kind: BandKind::Cells,
                width: side,
                height: side,
                values: &mut values,
            }];
            decode_bands_with(
                coder,
                bytes,
                &mut band,
                DecodeLimits::default(),
                &mut scratch,
            )
            .expect("own record");
        }
        best = best.min(cpu_seconds(wall) - start);
    }
    best
}

fn main() {
    for path in std::env::args().skip(1) {
        let repo = Repository::open(Path::new(&path)).expect("a repository");
        let side = repo.head().params().domain.n() - 1;
        let bands = cell_bands(&repo, side);
        let samples = (bands.len() * side * side) as f64;
        println!("{path}: {} records", bands.len());
        let mut base = None;
        // The default first: the others' bytes are given as a fraction of its.
        let coders = [
            CoderKind::AdaptiveTokens,
            CoderKind::FastRice,
            CoderKind::Adaptive,
            CoderKind::EliasGamma,
        ];
        for coder in coders {
            let records: Vec<Vec<u8>> = bands
                .iter()
                .map(|values| {
                    let band = Band {
                        kind: BandKind::Cells,
                        width: side,
                        height: side,
                        values,
                    };
                    let mut out = Vec::new();
                    encode_bands(coder, &[band], &mut out);
                    out
                })
                .collect();
            let bytes: usize = records.iter().map(Vec::len).sum();
            let base = *base.get_or_insert(bytes as f64);
            let seconds = decode_seconds(coder, &records, side);
            println!(
                "  {:16} {bytes:>10} B ({:.4} of the first, {:.3} bits/sample)  decode {:.2} ns/sample ({:.1} M samples/s)",
                coder.name(),
                bytes as f64 / base,
                bytes as f64 * 8.0 / samples,
                seconds / samples * 1e9,
                samples / seconds / 1e6
            );
        }
    }
}
