//! `cbdam bench entropy`: the bits a coder spends on each level's residual bands against the
//! entropy references (`cbdam_codec::entropy::references`), and JPEG-LS's MED predictor on the
//! same quantized lattice, to say where a rate gap comes from (docs/RESULTS.md, "Entropy
//! references").

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_codec::entropy::references::{
    CellPredictor, SymbolStats, cell_indices, coder_contexts, corner_activity, med_residuals,
};
use cbdam_codec::entropy::{
    BandKind, BandMut, DecodeLimits, DecodeScratch, ParentGrid, decode_bands_on_grid_with,
};
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::mask::decode_mask;
use cbdam_codec::hierarchy::{EncodeOptions, Encoded, Encoder, walk};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::lifting::{PREDICTION_LIMIT, predict_cells};
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::serialize;
use clap::Args;

use crate::build::CoderArg;

/// Per level and band kind, the bits the coder spent on a repository's residual bands against
/// their zero-order and context-conditioned entropy, and the entropy of JPEG-LS's MED residuals
/// on the same lattice, as Markdown (docs/RESULTS.md, "Entropy references").
#[derive(Args, Debug)]
pub struct BenchEntropyArgs {
    /// DEM files (GeoTIFF, .hgt, ASCII grid, PNG).
    #[arg(required = true)]
    inputs: Vec<PathBuf>,
    /// Maximum errors to measure, metres, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = vec![0.5, 1.0])]
    max_error: Vec<f64>,
    /// The entropy coder whose bits are measured.
    #[arg(long, value_enum, default_value_t = CoderArg::AdaptiveTokens)]
    coder: CoderArg,
    /// Also re-code each diamond's cells with in-band secondary predictions (slow).
    #[arg(long)]
    in_band: bool,
}

/// The tallies by (level, band kind).
type Tallies = BTreeMap<(u8, &'static str), BandTally>;

/// One level's band kind: the coder's bits and the symbol counts.
#[derive(Default)]
struct BandTally {
    records: usize,
    coded_bits: u64,
    stats: SymbolStats,
}

pub fn run(args: &BenchEntropyArgs) -> Result<()> {
    for path in &args.inputs {
        let dem = read_dem(path, &ReadOptions::default())
            .with_context(|| format!("reading {}", path.display()))?;
        let name = path.file_stem().unwrap_or_default().to_string_lossy();
        for &eps in &args.max_error {
            if !(eps.is_finite() && eps >= 0.0) {
                bail!("--max-error {eps}: a tolerance is a finite number of metres, 0 or more");
            }
            let plan = QuantPlan::for_dem(&dem, eps, None)?;
            let grid = HeightGrid::from_dem(&dem, &plan)?;
            let opts = EncodeOptions {
                coder: args.coder.kind(),
                ..EncodeOptions::default()
            };
            let encoded = Encoder::new(&grid, plan.quantizer, &opts).encode()?;
            let file_bytes = serialize(&encoded, &plan, dem.georef.as_ref(), dem.nodata)?.len();
            let (bands, mask_bits) = tally_bands(&encoded)?;
            println!(
                "\n### {name}, ε = {eps} m ({}, unit {} m, quantizer step {} units)\n",
                args.coder.kind().name(),
                plan.unit,
                plan.quantizer.step()
            );
            let samples = (grid.width * grid.height) as f64;
            print_levels(&bands);
            let record_bits: u64 = bands.values().map(|t| t.coded_bits).sum();
            let fixed_bits = file_bytes as f64 * 8.0 - record_bits as f64 - mask_bits as f64;
            print_totals(&bands, samples, file_bytes, fixed_bits, mask_bits);
            print_med(&grid, plan.quantizer.k(), samples);
            print_predictors(&encoded, samples)?;
            if args.in_band {
                super::entropy_secondary::print_secondary(&encoded, samples)?;
            }
        }
    }
    Ok(())
}

/// Decodes every record's bands (on its diamond's grid, as a decoder does) and counts them by
/// (level, band kind), with the coder's bits; also the bits of the records' nodata masks.
fn tally_bands(encoded: &Encoded) -> Result<(Tallies, u64)> {
    let n = encoded.params.layout().n();
    let mut tallies: Tallies = BTreeMap::new();
    let mut mask_bits = 0u64;
    let (mut cells, mut vertices) = (vec![0i32; (n - 1) * (n - 1)], vec![0i32; (n - 2) * (n - 2)]);
    let records: std::collections::HashMap<DiamondId, &[u8]> = encoded
        .records
        .iter()
        .map(|r| (r.id, &r.bytes[..]))
        .collect();
    let mut scratch = DecodeScratch::default();
    let mut failure = None;
    walk(encoded, |id, p| {
        let Some(record) = records.get(&id) else {
            return;
        };
        let tallied = tally_record(
            encoded,
            id,
            p,
            record,
            &mut tallies,
            &mut scratch,
            [&mut cells, &mut vertices],
        );
        match tallied {
            Ok(used_mask) => mask_bits += 8 * used_mask as u64,
            Err(e) => {
                failure.get_or_insert(e);
            }
        }
    })?;
    if let Some(e) = failure {
        return Err(e);
    }
    Ok((tallies, mask_bits))
}

/// [`tally_bands`] for one record of diamond `id`, whose grid is `p`: the mask's bytes.
fn tally_record(
    encoded: &Encoded,
    id: DiamondId,
    p: &[i32],
    record: &[u8],
    tallies: &mut Tallies,
    scratch: &mut DecodeScratch,
    [cells, vertices]: [&mut Vec<i32>; 2],
) -> Result<usize> {
    let params = &encoded.params;
    let n = params.layout().n();
    let half = params.alpha == Alpha::Half;
    let (used_mask, bytes) = strip_mask(encoded, record)?;
    let mut bands = [
        BandMut {
            kind: BandKind::Cells,
            width: n - 1,
            height: n - 1,
            values: cells,
        },
        BandMut {
            kind: BandKind::Vertices,
            width: n - 2,
            height: n - 2,
            values: vertices,
        },
    ];
    let used = &mut bands[..1 + usize::from(half)];
    let grid = ParentGrid {
        values: p,
        n,
        step: params.quantizer.step(),
    };
    let limits = DecodeLimits::default();
    decode_bands_on_grid_with(params.coder, bytes, used, Some(grid), limits, scratch)?;
    // The record's bits go to its first band's row: the coder does not say how they split.
    let mut first = true;
    for band in used.iter() {
        let kind = match band.kind {
            BandKind::Cells => "cells",
            BandKind::Vertices => "vertices",
            BandKind::Roots => "roots",
        };
        let tally = tallies.entry((id.level, kind)).or_default();
        if first {
            tally.records += 1;
            tally.coded_bits += 8 * bytes.len() as u64;
            first = false;
        }
        coder_contexts(band.values, band.width, band.height, |ctx, v| {
            tally.stats.add(ctx, v)
        });
    }
    Ok(used_mask)
}

/// A record's bytes without its nodata mask, and the mask's length.
pub(super) fn strip_mask<'a>(encoded: &Encoded, bytes: &'a [u8]) -> Result<(usize, &'a [u8])> {
    let n = encoded.params.layout().n();
    if encoded.params.nodata_mask && !bytes.is_empty() {
        let (_, used) = decode_mask(2 * n - 1, 2 * n - 1, bytes)?;
        return Ok((used, &bytes[used..]));
    }
    Ok((0, bytes))
}

/// The cells' indices under other predictors on the decoded grids ([`CellPredictor`]), and the
/// codec's with the corner spread added to the context: per level, summed, bits per sample.
fn print_predictors(encoded: &Encoded, samples: f64) -> Result<()> {
    let params = &encoded.params;
    let (n, step) = (params.layout().n(), params.quantizer.step());
    let m = n - 1;
    let records: std::collections::HashMap<DiamondId, &[u8]> = encoded
        .records
        .iter()
        .map(|r| (r.id, &r.bytes[..]))
        .collect();
    let mut by_predictor: BTreeMap<(usize, u8), SymbolStats> = BTreeMap::new();
    let mut with_activity: BTreeMap<u8, SymbolStats> = BTreeMap::new();
    let (mut residuals, mut codec, mut cells, mut indices) = (
        vec![0i32; m * m],
        vec![0i32; m * m],
        vec![0i32; m * m],
        Vec::new(),
    );
    let mut failure = None;
    let mut scratch = DecodeScratch::default();
    walk(encoded, |id, p| {
        let Some(bytes) = records.get(&id) else {
            return;
        };
        let decoded = strip_mask(encoded, bytes).and_then(|(_, bytes)| {
            let mut band = [BandMut {
                kind: BandKind::Cells,
                width: m,
                height: m,
                values: &mut residuals,
            }];
            let grid = ParentGrid { values: p, n, step };
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
        predict_cells(p, n, &mut codec);
        for ((c, &pred), &v) in cells.iter_mut().zip(&codec).zip(&residuals) {
            *c = pred.clamp(-PREDICTION_LIMIT, PREDICTION_LIMIT) + step * v;
        }
        for (k, &predictor) in CellPredictor::ALL.iter().enumerate() {
            cell_indices(predictor, p, n, &codec, &cells, step, &mut indices);
            let stats = by_predictor.entry((k, id.level)).or_default();
            coder_contexts(&indices, m, m, |ctx, v| stats.add(ctx, v));
        }
        let stats = with_activity.entry(id.level).or_default();
        let mut at = 0;
        coder_contexts(&residuals, m, m, |ctx, v| {
            let (i, j) = (at % m, at / m);
            stats.add(ctx * 8 + corner_activity(p, n, i, j, step), v);
            at += 1;
        });
    })?;
    if let Some(e) = failure {
        return Err(e);
    }
    print_predictor_table(&by_predictor, &with_activity, step, samples);
    Ok(())
}

/// The table of [`print_predictors`]: per predictor, the levels' entropies summed.
fn print_predictor_table(
    by_predictor: &BTreeMap<(usize, u8), SymbolStats>,
    with_activity: &BTreeMap<u8, SymbolStats>,
    step: i32,
    samples: f64,
) {
    let exact = if step == 1 {
        "exact"
    } else {
        "open loop, an estimate"
    };
    println!("\nCells under other predictors on the decoded grids ({exact}), bits per sample:\n");
    println!("| cells predicted by | H0 | H(v \\| coder ctx) |\n|---|---:|---:|");
    for (k, predictor) in CellPredictor::ALL.iter().enumerate() {
        let (mut h0, mut hc) = (0.0, 0.0);
        for ((_, _), st) in by_predictor.range((k, 0)..=(k, u8::MAX)) {
            h0 += st.zero_order_bits();
            hc += st.conditional_bits();
        }
        println!(
            "| {} | {:.4} | {:.4} |",
            predictor.name(),
            h0 / samples,
            hc / samples
        );
    }
    let hc: f64 = with_activity.values().map(|s| s.conditional_bits()).sum();
    println!(
        "| codec, context × corner spread (8 bins) | | {:.4} |",
        hc / samples
    );
}

fn print_levels(bands: &Tallies) {
    println!(
        "| level | band | records | values | coded bits/value | H0 | H(v \\| ctx) | H(abs v \\| ctx) + raw sign | coded ÷ H(v \\| ctx) |"
    );
    println!("|---:|---|---:|---:|---:|---:|---:|---:|---:|");
    for ((level, kind), t) in bands {
        let values = t.stats.count() as f64;
        let conditional = t.stats.conditional_bits();
        println!(
            "| {level} | {kind} | {} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} |",
            t.records,
            t.stats.count(),
            t.coded_bits as f64 / values,
            t.stats.zero_order_bits() / values,
            conditional / values,
            t.stats.conditional_bits_raw_sign() / values,
            t.coded_bits as f64 / conditional.max(1.0),
        );
    }
}

/// The whole file in bits per input sample: what the coder spent, what the references would,
/// and the fixed costs (header, index, root field, checksums, nodata masks).
fn print_totals(bands: &Tallies, samples: f64, file_bytes: usize, fixed_bits: f64, mask_bits: u64) {
    let coded: u64 = bands.values().map(|t| t.coded_bits).sum();
    let (mut h0, mut hc, mut hs) = (0.0, 0.0, 0.0);
    for t in bands.values() {
        h0 += t.stats.zero_order_bits();
        hc += t.stats.conditional_bits();
        hs += t.stats.conditional_bits_raw_sign();
    }
    println!("\nBits per input sample ({samples} samples):\n");
    println!("| | bits/sample |\n|---|---:|");
    println!(
        "| whole file ({file_bytes} B) | {:.4} |",
        file_bytes as f64 * 8.0 / samples
    );
    println!("| records' bands, coded | {:.4} |", coded as f64 / samples);
    println!(
        "| fixed: header, index, roots, checksums | {:.4} |",
        fixed_bits / samples
    );
    println!("| nodata masks | {:.4} |", mask_bits as f64 / samples);
    println!("| bands' H0, per level | {:.4} |", h0 / samples);
    println!(
        "| bands' H(v \\| coder ctx), per level | {:.4} |",
        hc / samples
    );
    println!(
        "| bands' H(abs v \\| coder ctx) + raw sign, per level | {:.4} |",
        hs / samples
    );
}

/// JPEG-LS's MED predictor in closed loop over the same lattice with NEAR = the quantizer's
/// `k`: the entropy of its indices alone, given its 365 gradient contexts, and given the
/// coder's neighbourhood classes taken over the index raster.
fn print_med(grid: &HeightGrid, k: i32, samples: f64) {
    let (w, h) = (grid.width, grid.height);
    let mut by_gradient = SymbolStats::default();
    let mut indices = Vec::with_capacity(w * h);
    med_residuals(&grid.values, Some(&grid.valid), w, h, k, |s| {
        by_gradient.add(s.context, s.index);
        indices.push(s.index);
    });
    let mut by_class = SymbolStats::default();
    coder_contexts(&indices, w, h, |ctx, v| by_class.add(ctx, v));
    println!(
        "| MED residuals (NEAR = {k}): H0 | {:.4} |",
        by_gradient.zero_order_bits() / samples
    );
    println!(
        "| MED residuals: H(v \\| 365 gradient ctx) | {:.4} |",
        by_gradient.conditional_bits() / samples
    );
    println!(
        "| MED residuals: H(v \\| coder's class ctx) | {:.4} |",
        by_class.conditional_bits() / samples
    );
}
