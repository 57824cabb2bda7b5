use super::super::super::{
    Band, BandKind, CoderKind, DecodeLimits, DecodeScratch, ParentGrid, decode_bands_on_grid_with,
    encode_bands_on_grid,
};
use super::super::tests::{MAX, Rng, Shapes, band_strategy, decode_into_buffers};
use super::*;
use proptest::prelude::*;

pub(crate) fn encode_on(coder: CoderKind, bands: &Shapes, grid: Option<ParentGrid<'_>>) -> Vec<u8> {
    let bands: Vec<Band<'_>> = bands
        .iter()
        .map(|(kind, w, h, v)| Band {
            kind: *kind,
            width: *w,
            height: *h,
            values: v,
        })
        .collect();
    let mut out = Vec::new();
    encode_bands_on_grid(coder, &bands, grid, &mut out);
    out
}

fn decode_on(
    bytes: &[u8],
    shapes: &Shapes,
    grid: Option<ParentGrid<'_>>,
) -> Result<Vec<Vec<i32>>, CodecError> {
    // Start from garbage: the decoder must overwrite everything.
    decode_into_buffers(shapes, 7, |bands| {
        decode_bands_on_grid_with(
            CoderKind::AdaptiveGrid,
            bytes,
            bands,
            grid,
            DecodeLimits::default(),
            &mut DecodeScratch::default(),
        )
    })
}

pub(crate) fn grid_of(values: &[i32], n: usize, step: i32) -> Option<ParentGrid<'_>> {
    Some(ParentGrid { values, n, step })
}

/// An `n × n` terrain-like grid: flat on the left, ever steeper and rougher to the right.
pub(crate) fn rough_grid(rng: &mut Rng, n: usize) -> Vec<i32> {
    (0..n * n)
        .map(|k| {
            let x = (k % n) as i64;
            let noise = (rng.next() % 1000) as i64 - 500;
            (x * x * 3 + noise * x * x / (n * n) as i64) as i32
        })
        .collect()
}

/// Cell residuals whose scale follows the grid's corner spread, as on real terrain: Laplacian
/// with scale `0.05 + spread / 8` steps.
pub(crate) fn residuals_following(rng: &mut Rng, g: &[i32], n: usize, step: i32) -> Vec<i32> {
    let m = n - 1;
    let mut out = Vec::with_capacity(m * m);
    for j in 0..m {
        for i in 0..m {
            let at = |i: usize, j: usize| i64::from(g[j * n + i]);
            let spread = (at(i, j) - at(i + 1, j + 1)).abs() + (at(i + 1, j) - at(i, j + 1)).abs();
            let scale = 0.05 + spread as f64 / f64::from(step) / 8.0;
            let u = ((rng.next() >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
            let v = (-scale * u.ln()).round() as i32;
            out.push(if rng.next() & 1 == 0 { v } else { -v });
        }
    }
    out
}

#[test]
fn round_trips_on_its_grid_with_and_without_a_vertex_band() {
    let mut rng = Rng(7);
    for (n, step) in [(65, 1), (65, 5), (9, 3), (2, 1)] {
        let g = rough_grid(&mut rng, n);
        let cells = residuals_following(&mut rng, &g, n, step);
        let vertices: Vec<i32> = (0..(n - 2).pow(2)).map(|k| (k % 7) as i32 - 3).collect();
        let one: &Shapes = &[(BandKind::Cells, n - 1, n - 1, cells.clone())];
        let two: &Shapes = &[
            (BandKind::Cells, n - 1, n - 1, cells),
            (BandKind::Vertices, n - 2, n - 2, vertices),
        ];
        for bands in [one, two] {
            let bytes = encode_on(CoderKind::AdaptiveGrid, bands, grid_of(&g, n, step));
            let got = decode_on(&bytes, bands, grid_of(&g, n, step)).expect("own record");
            for ((_, _, _, want), got) in bands.iter().zip(&got) {
                assert_eq!(want, got, "n {n} step {step}");
            }
        }
    }
}

#[test]
fn corner_terms_are_a_quarter_of_the_spread_in_steps() {
    // Corners TL, TR / BL, BR of the one cell of a 2 × 2 grid; terms worked out by hand.
    let cases = [
        ([0, 0, 0, 0], 1, 0),
        ([0, 0, 0, 3], 1, 0),
        ([0, 0, 0, 4], 1, 1),
        ([0, 0, 0, 21], 3, 1),         // 21 / 3 = 7 steps
        ([0, 0, 0, 24], 3, 2),         // 8 steps
        ([5, -4, 6, 5], 1, 2),         // |5 − 5| + |−4 − 6| = 10
        ([0, 0, 0, 1 << 20], 1, 4096), // capped
        ([i32::MIN, i32::MAX, i32::MIN, i32::MAX], 1, 4096),
        ([0, 0, 0, 9], 0, 2), // a step below 1 counts as 1
    ];
    for (corners, step, want) in cases {
        let grid = ParentGrid {
            values: &corners,
            n: 2,
            step,
        };
        let mut cells = CellActivity::default();
        cells.fill(&grid);
        assert_eq!(cells.adds, [want], "{corners:?} step {step}");
    }
}

#[test]
fn without_its_grid_it_writes_the_token_coders_bytes() {
    // Bin 0 everywhere is the token coder's context model exactly.
    let mut rng = Rng(11);
    let g = rough_grid(&mut rng, 65);
    let bands: &Shapes = &[
        (
            BandKind::Cells,
            64,
            64,
            residuals_following(&mut rng, &g, 65, 1),
        ),
        (
            BandKind::Roots,
            20,
            30,
            (0..600).map(|k| k % 11 - 5).collect(),
        ),
    ];
    assert_eq!(
        encode_on(CoderKind::AdaptiveGrid, bands, None),
        encode_on(CoderKind::AdaptiveTokens, bands, None)
    );
}

#[test]
fn the_grid_is_in_the_context() {
    let mut rng = Rng(3);
    let g = rough_grid(&mut rng, 65);
    let cells = residuals_following(&mut rng, &g, 65, 1);
    let bands: &Shapes = &[(BandKind::Cells, 64, 64, cells.clone())];
    let on_grid = encode_on(CoderKind::AdaptiveGrid, bands, grid_of(&g, 65, 1));
    let tokens = encode_on(CoderKind::AdaptiveTokens, bands, None);
    // The residuals follow the grid's roughness, as on terrain: knowing it must pay, here by
    // at least 1 % of the token coder's record.
    assert!(
        on_grid.len() * 100 <= tokens.len() * 99,
        "on its grid {} bytes, token coder {}",
        on_grid.len(),
        tokens.len()
    );
    // Another grid (the same columns mirrored) gives other contexts: the record does not
    // decode to the residuals on it.
    let mirrored: Vec<i32> = (0..65 * 65).map(|k| g[k / 65 * 65 + 64 - k % 65]).collect();
    let wrong = decode_on(&on_grid, bands, grid_of(&mirrored, 65, 1));
    assert!(wrong.is_err() || wrong.unwrap()[0] != cells);
}

#[test]
fn a_grid_that_does_not_fit_the_cells_is_an_error() {
    let g = vec![0; 10 * 10];
    let bands: &Shapes = &[(BandKind::Cells, 64, 64, vec![1; 64 * 64])];
    let bytes = encode_on(CoderKind::AdaptiveGrid, bands, None);
    let short = ParentGrid {
        values: &g[..99],
        n: 10,
        step: 1,
    };
    for grid in [grid_of(&g, 10, 1), Some(short)] {
        let e = decode_on(&bytes, bands, grid).expect_err("the grid does not fit");
        assert!(e.to_string().contains("grid"), "{e}");
    }
}

/// A grid for a fuzzed `n`: values anywhere in i32 or small, by `seed`.
pub(crate) fn fuzz_grid(n: usize, seed: u64, wide: bool) -> Vec<i32> {
    let mut rng = Rng(seed);
    (0..n * n)
        .map(|_| {
            let v = rng.next();
            if wide { v as i32 } else { (v % 64) as i32 - 32 }
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn round_trips_on_any_grid(
        (kind, w, _, values) in band_strategy(),
        seed in any::<u64>(),
        wide in any::<bool>(),
        step in 1i32..40,
    ) {
        // A square cell band of side w on an (w + 1)² grid; other kinds ignore the grid.
        let values: Vec<i32> = values.into_iter().chain(std::iter::repeat(0)).take(w * w).collect();
        let n = w + 1;
        let g = fuzz_grid(n, seed, wide);
        let bands: &Shapes = &[(kind, w, w, values.clone())];
        let bytes = encode_on(CoderKind::AdaptiveGrid, bands, grid_of(&g, n, step));
        let got = decode_on(&bytes, bands, grid_of(&g, n, step)).expect("own record");
        prop_assert_eq!(&got[0], &values);
    }

    #[test]
    fn hostile_bytes_on_a_grid_never_panic(
        bytes in prop::collection::vec(any::<u8>(), 0..400),
        m in 0usize..70,
        seed in any::<u64>(),
        wide in any::<bool>(),
    ) {
        let g = fuzz_grid(m + 1, seed, wide);
        let shapes: &Shapes = &[(BandKind::Cells, m, m, vec![]), (BandKind::Vertices, m, m, vec![])];
        if let Ok(got) = decode_on(&bytes, shapes, grid_of(&g, m + 1, 1)) {
            prop_assert!(got.iter().flatten().all(|v| v.unsigned_abs() <= MAX as u32));
        }
    }

    #[test]
    fn truncated_records_on_a_grid_never_panic(seed in any::<u64>(), cut in 0.0f64..1.0) {
        let mut rng = Rng(seed);
        let g = rough_grid(&mut rng, 65);
        let bands: &Shapes = &[(BandKind::Cells, 64, 64, residuals_following(&mut rng, &g, 65, 1))];
        let bytes = encode_on(CoderKind::AdaptiveGrid, bands, grid_of(&g, 65, 1));
        let n = (bytes.len() as f64 * cut) as usize;
        let _ = decode_on(&bytes[..n], bands, grid_of(&g, 65, 1));
    }
}
