//! Windowed decodes ([`decode_window`]): per lattice point of the window, the last grid value
//! and validity visited at the level are the whole walk's ([`walk_all_with_validity`]), for
//! every level, windows at corners, edges and inside, α = 1 and ½, with nodata; and only the
//! records [`LevelWindow::records_needed`] names are read.

use std::collections::HashMap;

use cbdam_codec::entropy::CoderKind;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::{
    EncodeOptions, Encoded, Encoder, LevelWindow, decode_window, walk_all_with_validity,
};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, Quantizer};

use crate::util::CountedReads;

type Points = HashMap<(i64, i64), (i32, bool)>;

/// The last value and validity each lattice point of `rect` gets from `visit`'s grids of `level`.
fn keep_last(
    enc: &Encoded,
    level: u8,
    rect: (i64, i64, i64, i64),
    points: &mut Points,
    id: DiamondId,
    grid: &[i32],
    valid: Option<&[bool]>,
) {
    if id.level != level {
        return;
    }
    let layout = enc.params.layout();
    let (n, g) = (layout.n(), layout.grid(id));
    for j in 0..n {
        for i in 0..n {
            let (x, y) = g.point(i as i64, j as i64);
            if x < rect.0 || y < rect.1 || x > rect.2 || y > rect.3 {
                continue;
            }
            let ok = valid.is_none_or(|v| v[j * n + i]);
            points.insert((x, y), (grid[j * n + i], ok));
        }
    }
}

fn terrain(w: usize, h: usize) -> HeightGrid {
    let values = (0..w * h)
        .map(|k| {
            let (x, y) = ((k % w) as f64, (k / w) as f64);
            (150.0 * (x / 6.0).sin() * (y / 4.0).cos() + 2.0 * y) as i32 + (k * 7919 % 13) as i32
        })
        .collect();
    let mut g = HeightGrid::all_valid(w, h, values);
    for y in 0..h {
        for x in 0..w {
            // A hole of whole diamonds and a scatter of single samples without data.
            if (10..26).contains(&x) && (6..18).contains(&y) || (x * 31 + y * 17) % 11 == 0 {
                g.valid[y * w + x] = false;
            }
        }
    }
    g
}

#[test]
fn every_window_and_level_decodes_as_the_whole_walk() {
    let (w, h) = (53, 41);
    let grid = terrain(w, h);
    for (n, alpha) in [(9, Alpha::One), (5, Alpha::Half)] {
        let opts = EncodeOptions {
            n,
            alpha,
            coder: CoderKind::AdaptiveTokens,
            extra_level_pairs: 0,
        };
        let enc = Encoder::new(&grid, Quantizer::new(2).unwrap(), &opts)
            .encode()
            .unwrap();
        let finest = enc.params.layout().finest_level();
        let reads = CountedReads::new(&enc);
        let (wl, hl) = (w as i64 - 1, h as i64 - 1);
        let windows = [
            (0, 0, wl, hl),
            (0, 0, 0, 0),
            (wl, hl, wl, hl),
            (3, 5, 20, 9),
            (30, 0, wl, 12),
            (0, 20, 7, hl),
            (17, 17, 17, 30),
        ];
        for level in 0..=finest {
            for rect in windows {
                let mut want = Points::new();
                walk_all_with_validity(&enc, |id, g, v| {
                    keep_last(&enc, level, rect, &mut want, id, g, v)
                })
                .unwrap();
                let window = LevelWindow { level, rect };
                let mut got = Points::new();
                decode_window(
                    enc.params,
                    &enc.roots,
                    &reads.stored,
                    |id| reads.read(id),
                    window,
                    |id, g, v| keep_last(&enc, level, rect, &mut got, id, g, v),
                )
                .unwrap();
                assert!(
                    got == want,
                    "n {n}, level {level}, window {rect:?}: {} points, want {}",
                    got.len(),
                    want.len()
                );
                let partial =
                    reads.check_read_exactly(window.records_needed(&enc.params, &reads.stored));
                if rect == (0, 0, 0, 0) && level == finest {
                    assert!(partial, "a corner read needs every record");
                }
            }
        }
    }
}

#[test]
fn a_level_past_the_finest_and_a_missing_record_are_errors() {
    let grid = terrain(21, 17);
    let opts = EncodeOptions {
        n: 5,
        ..EncodeOptions::default()
    };
    let enc = Encoder::new(&grid, Quantizer::new(1).unwrap(), &opts)
        .encode()
        .unwrap();
    let stored: Vec<DiamondId> = enc.records.iter().map(|r| r.id).collect();
    assert!(!stored.is_empty());
    let finest = enc.params.layout().finest_level();
    let window = LevelWindow {
        level: finest + 1,
        rect: (0, 0, 20, 16),
    };
    let none = |_: DiamondId| -> Result<&'static [u8], cbdam_codec::CodecError> {
        Err(cbdam_codec::CodecError::corrupt("no record"))
    };
    let e = decode_window(enc.params, &enc.roots, &stored, none, window, |_, _, _| {});
    assert!(e.unwrap_err().to_string().contains("finest level"));
    let window = LevelWindow {
        level: finest,
        rect: (0, 0, 20, 16),
    };
    let e = decode_window(enc.params, &enc.roots, &stored, none, window, |_, _, _| {});
    assert!(e.unwrap_err().to_string().contains("no record"));
}
