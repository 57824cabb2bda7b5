//! Hostile bytes into `decode_bands`, for every coder (and the grid-aware coder also on a grid
//! made of the payload, through `decode_bands_on_grid_with`): it must never panic, and whatever
//! the gamma coder accepts must be within limits and re-encode to exactly the input (it accepts
//! only canonical streams).
//!
//! Input layout: `[limits byte, band count byte, one shape byte per band.., payload..]`.
#![no_main]

use cbdam_codec::entropy::{
    Band, BandKind, BandMut, CoderKind, DecodeLimits, DecodeScratch, ParentGrid, decode_bands,
    decode_bands_on_grid_with, encode_bands,
};
use libfuzzer_sys::fuzz_target;

/// Band sides a shape nibble selects: the real ones (63, 64, 65) plus edge cases.
const SIDES: [usize; 16] = [0, 1, 2, 3, 4, 5, 7, 8, 16, 31, 32, 63, 64, 65, 127, 130];
const KINDS: [BandKind; 3] = [BandKind::Cells, BandKind::Vertices, BandKind::Roots];

fuzz_target!(|data: &[u8]| {
    let [lim, count, rest @ ..] = data else {
        return;
    };
    // A set top bit selects a tiny magnitude limit, to exercise the limit checks.
    let limits = if lim & 0x80 != 0 {
        DecodeLimits {
            max_abs: u32::from(lim & 0x7F),
        }
    } else {
        DecodeLimits::default()
    };
    let n = usize::from(count % 5);
    if rest.len() < n {
        return;
    }
    let (shape_bytes, payload) = rest.split_at(n);
    let shapes: Vec<(BandKind, usize, usize)> = shape_bytes
        .iter()
        .enumerate()
        .map(|(i, &s)| {
            (
                KINDS[i % 3],
                SIDES[usize::from(s & 15)],
                SIDES[usize::from(s >> 4)],
            )
        })
        .collect();

    // The grid of the first band's cells (whatever its kind; a grid that does not fit a cell
    // band is refused), its heights the payload's bytes scaled by the limits byte.
    let n = shapes.first().map_or(0, |&(_, w, _)| w + 1);
    let grid: Vec<i32> = (0..n * n)
        .map(|k| i32::from(payload.get(k % payload.len().max(1)).copied().unwrap_or(0)))
        .map(|v| v.wrapping_mul(1 << (lim & 31)))
        .collect();
    let grid = ParentGrid {
        values: &grid,
        n,
        step: i32::from(*count >> 3),
    };
    for coder in [CoderKind::AdaptiveGrid, CoderKind::AdaptiveInBand] {
        let mut bufs: Vec<Vec<i32>> = shapes.iter().map(|&(_, w, h)| vec![0; w * h]).collect();
        let mut bands: Vec<BandMut<'_>> = bufs
            .iter_mut()
            .zip(&shapes)
            .map(|(v, &(kind, width, height))| BandMut {
                kind,
                width,
                height,
                values: v,
            })
            .collect();
        let mut scratch = DecodeScratch::default();
        if decode_bands_on_grid_with(coder, payload, &mut bands, Some(grid), limits, &mut scratch)
            .is_ok()
        {
            for v in bufs.iter().flatten() {
                assert!(
                    v.unsigned_abs() <= limits.max_abs,
                    "{} on a grid decoded {v} over the limit",
                    coder.name()
                );
            }
        }
    }

    for coder in CoderKind::ALL {
        let mut bufs: Vec<Vec<i32>> = shapes.iter().map(|&(_, w, h)| vec![0; w * h]).collect();
        let mut bands: Vec<BandMut<'_>> = bufs
            .iter_mut()
            .zip(&shapes)
            .map(|(v, &(kind, width, height))| BandMut {
                kind,
                width,
                height,
                values: v,
            })
            .collect();
        if decode_bands(coder, payload, &mut bands, limits).is_err() {
            continue;
        }
        for v in bufs.iter().flatten() {
            assert!(
                v.unsigned_abs() <= limits.max_abs,
                "{} decoded {v} over the limit",
                coder.name()
            );
        }
        if coder == CoderKind::EliasGamma {
            let bands: Vec<Band<'_>> = bufs
                .iter()
                .zip(&shapes)
                .map(|(v, &(kind, width, height))| Band {
                    kind,
                    width,
                    height,
                    values: v,
                })
                .collect();
            let mut again = Vec::new();
            encode_bands(coder, &bands, &mut again);
            assert_eq!(again, payload, "accepted a non-canonical stream");
        }
    }
});
