//! `cbdam bench entropy`'s table of in-band secondary predictions (docs/RESULTS.md, "In-band
//! prediction"): each diamond's cell indices, decoded, coded again by `adaptive-grid` on the
//! same grid after `v − p(L, T, TL, TR)` with each of [`InBand::ALL`] — real coded bytes, not
//! an entropy — and the bytes of choosing the smallest per record (plus 4 bits to say which).

use std::collections::HashMap;

use anyhow::Result;
use cbdam_codec::entropy::references::{SymbolStats, coder_contexts};
use cbdam_codec::entropy::secondary::{GridHints, InBand, forward};
use cbdam_codec::entropy::{
    Band, BandKind, BandMut, CoderKind, DecodeLimits, DecodeScratch, ParentGrid,
    decode_bands_on_grid_with, encode_bands_on_grid,
};
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::{Encoded, walk};

use super::entropy::strip_mask;

/// Per predictor: re-coded bytes and the entropy of the coded values given the coder's classes.
struct Tally {
    bytes: [u64; InBand::ALL.len()],
    stats: Vec<SymbolStats>,
    best_bytes: u64,
    records: u64,
}

/// Prints the table (cells bands only; only for repositories without vertex bands).
pub(super) fn print_secondary(encoded: &Encoded, samples: f64) -> Result<()> {
    let params = &encoded.params;
    let (n, step) = (params.layout().n(), params.quantizer.step());
    let m = n - 1;
    let records: HashMap<DiamondId, &[u8]> = encoded
        .records
        .iter()
        .map(|r| (r.id, &r.bytes[..]))
        .collect();
    let mut tally = Tally {
        bytes: [0; InBand::ALL.len()],
        stats: vec![SymbolStats::default(); InBand::ALL.len()],
        best_bytes: 0,
        records: 0,
    };
    let (mut residuals, mut wide, mut coded, mut out) =
        (vec![0i32; m * m], Vec::new(), Vec::new(), Vec::new());
    let mut scratch = DecodeScratch::default();
    let mut hints = GridHints::default();
    let mut failure = None;
    walk(encoded, |id, p| {
        let Some(bytes) = records.get(&id) else {
            return;
        };
        let grid = ParentGrid { values: p, n, step };
        let decoded = strip_mask(encoded, bytes).and_then(|(_, bytes)| {
            let mut band = [BandMut {
                kind: BandKind::Cells,
                width: m,
                height: m,
                values: &mut residuals,
            }];
            let limits = DecodeLimits::default();
            Ok(decode_bands_on_grid_with(
                params.coder,
                bytes,
                &mut band,
                Some(grid),
                limits,
                &mut scratch,
            )?)
        });
        if let Err(e) = decoded {
            failure.get_or_insert(e);
            return;
        }
        hints.fill(&grid);
        let mut best = u64::MAX;
        for (k, &predictor) in InBand::ALL.iter().enumerate() {
            forward(predictor, &residuals, m, m, Some(&hints), &mut wide);
            coded.clear();
            coded.extend(wide.iter().map(|&v| v as i32));
            let band = Band {
                kind: BandKind::Cells,
                width: m,
                height: m,
                values: &coded,
            };
            out.clear();
            encode_bands_on_grid(CoderKind::AdaptiveGrid, &[band], Some(grid), &mut out);
            tally.bytes[k] += out.len() as u64;
            best = best.min(out.len() as u64);
            let stats = &mut tally.stats[k];
            coder_contexts(&coded, m, m, |ctx, v| stats.add(ctx, v));
        }
        tally.best_bytes += best;
        tally.records += 1;
    })?;
    if let Some(e) = failure {
        return Err(e);
    }
    print_table(&tally, samples);
    Ok(())
}

fn print_table(t: &Tally, samples: f64) {
    println!(
        "\nCells' indices predicted in-band, re-coded by adaptive-grid on the same grids ({} records), bits per sample:\n",
        t.records
    );
    println!("| in-band prediction | coded | H(v \\| coder ctx) |\n|---|---:|---:|");
    for (k, predictor) in InBand::ALL.iter().enumerate() {
        println!(
            "| {} | {:.4} | {:.4} |",
            predictor.name(),
            t.bytes[k] as f64 * 8.0 / samples,
            t.stats[k].conditional_bits() / samples
        );
    }
    println!(
        "| smallest per record (+4 bits each) | {:.4} | |",
        (t.best_bytes as f64 * 8.0 + 4.0 * t.records as f64) / samples
    );
}
