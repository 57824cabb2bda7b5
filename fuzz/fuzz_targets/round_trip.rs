//! Arbitrary integer matrices through encode → decode must come back unchanged, for every
//! coder, and for the grid-aware coder also on a grid made of the input's first values.
//!
//! Input layout: `[width byte, height byte, values..]`; each value is one byte (a small
//! signed value, the common case) or, when that byte has its top two bits set, four more
//! bytes giving an arbitrary value clamped to the coder's magnitude limit. Missing values
//! are zero.
#![no_main]

use cbdam_codec::entropy::{
    Band, BandKind, BandMut, CoderKind, DecodeLimits, DecodeScratch, ParentGrid, decode_bands,
    decode_bands_on_grid_with, encode_bands, encode_bands_on_grid,
};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let [w, h, rest @ ..] = data else { return };
    let mut rest: &[u8] = rest;
    let (w, h) = (usize::from(*w % 131), usize::from(*h % 131));
    let max = DecodeLimits::default().max_abs as i32;
    let mut values = vec![0i32; w * h];
    for v in values.iter_mut() {
        let &[b, ref tail @ ..] = rest else { break };
        rest = tail;
        *v = if b >= 0xC0 {
            let Some((word, tail)) = rest.split_first_chunk::<4>() else {
                break;
            };
            rest = tail;
            i32::from_le_bytes(*word).clamp(-max, max)
        } else {
            // 0x00..0xC0 → −96..=95: small residuals, the common case.
            i32::from(b) - 96
        };
    }
    for coder in CoderKind::ALL {
        let band = Band {
            kind: BandKind::Cells,
            width: w,
            height: h,
            values: &values,
        };
        let mut bytes = Vec::new();
        encode_bands(coder, &[band], &mut bytes);
        let mut out = vec![i32::MIN; w * h];
        let mut bands = [BandMut {
            kind: BandKind::Cells,
            width: w,
            height: h,
            values: &mut out,
        }];
        decode_bands(coder, &bytes, &mut bands, DecodeLimits::default())
            .unwrap_or_else(|e| panic!("{}: own record rejected: {e}", coder.name()));
        assert_eq!(out, values, "{}", coder.name());
    }
    if w == h {
        // The cells of an (w + 1)² grid whose heights are the values read again from the
        // start (wrapping), times a factor from the height byte: flat to steep.
        let n = w + 1;
        let grid: Vec<i32> = (0..n * n)
            .map(|k| values.get(k % values.len().max(1)).copied().unwrap_or(0))
            .map(|v| v.saturating_mul(i32::from(data[1] % 16)))
            .collect();
        let grid = Some(ParentGrid {
            values: &grid,
            n,
            step: i32::from(data[0] % 8),
        });
        for coder in [CoderKind::AdaptiveGrid, CoderKind::AdaptiveInBand] {
            let band = Band {
                kind: BandKind::Cells,
                width: w,
                height: h,
                values: &values,
            };
            let mut bytes = Vec::new();
            encode_bands_on_grid(coder, &[band], grid, &mut bytes);
            let mut out = vec![i32::MIN; w * h];
            let mut bands = [BandMut {
                kind: BandKind::Cells,
                width: w,
                height: h,
                values: &mut out,
            }];
            let limits = DecodeLimits::default();
            let mut scratch = DecodeScratch::default();
            decode_bands_on_grid_with(coder, &bytes, &mut bands, grid, limits, &mut scratch)
                .unwrap_or_else(|e| {
                    panic!("{} on its grid: own record rejected: {e}", coder.name())
                });
            assert_eq!(out, values, "{} on its grid", coder.name());
        }
    }
});
