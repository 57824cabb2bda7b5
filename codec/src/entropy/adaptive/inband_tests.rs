use super::super::super::{
    BandKind, CoderKind, DecodeLimits, DecodeScratch, ParentGrid, decode_bands_on_grid_with,
};
use super::super::grid::tests::{encode_on, fuzz_grid, grid_of, residuals_following, rough_grid};
use super::super::tests::{MAX, Rng, Shapes, band_strategy, decode_into_buffers};
use super::*;
use proptest::prelude::*;

fn decode_on(
    bytes: &[u8],
    shapes: &Shapes,
    grid: Option<ParentGrid<'_>>,
    limits: DecodeLimits,
) -> Result<Vec<Vec<i32>>, CodecError> {
    // Start from garbage: the decoder must overwrite everything.
    decode_into_buffers(shapes, 7, |bands| {
        decode_bands_on_grid_with(
            CoderKind::AdaptiveInBand,
            bytes,
            bands,
            grid,
            limits,
            &mut DecodeScratch::default(),
        )
    })
}

/// Cells of grid `g` whose heights are each cell's flatter diagonal's mean, give or take a
/// step: the indices the codec's own prediction leaves are the hints, plus noise.
fn cells_on_the_flatter_diagonal(rng: &mut Rng, g: &[i32], n: usize, step: i32) -> Vec<i32> {
    let m = n - 1;
    let at = |i: usize, j: usize| i64::from(g[j * n + i]);
    let mut own = vec![0i32; m * m];
    crate::lifting::predict_cells(g, n, &mut own);
    (0..m * m)
        .map(|k| {
            let (i, j) = (k % m, k / m);
            let (tl, tr, bl, br) = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
            let (main, anti) = ((tl + br).div_euclid(2), (tr + bl).div_euclid(2));
            let flatter = if (tl - br).abs() <= (tr - bl).abs() {
                main
            } else {
                anti
            };
            let noise = (rng.next() % 3) as i64 - 1;
            ((flatter - i64::from(own[k])) / i64::from(step) + noise) as i32
        })
        .collect()
}

#[test]
fn round_trips_on_its_grid_with_and_without_a_vertex_band() {
    let mut rng = Rng(7);
    for (n, step) in [(65, 1), (65, 5), (9, 3), (2, 1)] {
        let g = rough_grid(&mut rng, n);
        let vertices: Vec<i32> = (0..(n - 2) * (n - 2)).map(|k| (k % 7) as i32 - 3).collect();
        for cells in [
            residuals_following(&mut rng, &g, n, step),
            cells_on_the_flatter_diagonal(&mut rng, &g, n, step),
        ] {
            let one: &Shapes = &[(BandKind::Cells, n - 1, n - 1, cells.clone())];
            let two: &Shapes = &[
                (BandKind::Cells, n - 1, n - 1, cells),
                (BandKind::Vertices, n - 2, n - 2, vertices.clone()),
            ];
            for bands in [one, two] {
                let grid = grid_of(&g, n, step);
                let bytes = encode_on(CoderKind::AdaptiveInBand, bands, grid);
                let got = decode_on(&bytes, bands, grid, DecodeLimits::default());
                let got = got.expect("own record");
                for ((_, _, _, want), got) in bands.iter().zip(&got) {
                    assert_eq!(want, got, "n {n} step {step}");
                }
            }
        }
    }
}

#[test]
fn every_predictor_is_undone_by_its_inverse() {
    let mut rng = Rng(5);
    let (n, step) = (33, 3);
    let g = rough_grid(&mut rng, n);
    let mut hints = GridHints::default();
    hints.fill(&ParentGrid {
        values: &g,
        n,
        step,
    });
    let m = n - 1;
    let values: Vec<i32> = (0..m * m)
        .map(|k| match k % 5 {
            0 => MAX,
            1 => -MAX,
            _ => (rng.next() % 41) as i32 - 20,
        })
        .collect();
    let mut coded = Vec::new();
    for predictor in InBand::ALL {
        for h in [Some(&hints), None] {
            forward(predictor, &values, m, m, h, &mut coded);
            let mut back: Vec<i32> = coded.iter().map(|&v| v as i32).collect();
            inverse(predictor, &mut back, m, m, h);
            assert_eq!(back, values, "{}", predictor.name());
        }
    }
}

#[test]
fn the_prediction_pays_where_the_grid_says_so() {
    // Cells that follow the flatter diagonal, not the codec's prediction: a band choosing a
    // grid predictor must code them in well under adaptive-grid's bytes.
    let mut rng = Rng(13);
    let (n, step) = (65, 1);
    let g = rough_grid(&mut rng, n);
    let cells = cells_on_the_flatter_diagonal(&mut rng, &g, n, step);
    let bands: &Shapes = &[(BandKind::Cells, n - 1, n - 1, cells)];
    let inband = encode_on(CoderKind::AdaptiveInBand, bands, grid_of(&g, n, step));
    let grid = encode_on(CoderKind::AdaptiveGrid, bands, grid_of(&g, n, step));
    assert!(
        inband.len() * 4 <= grid.len() * 3,
        "in-band {} bytes, adaptive-grid {}",
        inband.len(),
        grid.len()
    );
}

#[test]
fn cells_that_ignore_their_grid_cost_what_the_token_coder_spends() {
    // Residuals of one scale everywhere on a grid that is flat on the left and steep on the
    // right: the corners' contexts mislead, so the band must keep the token coder's contexts
    // and pay only its two choice bits (the record's last byte may round up).
    let mut rng = Rng(17);
    let g = rough_grid(&mut rng, 65);
    let cells = super::super::tests::laplace_band(&mut rng, 64, 64, 2.0);
    let bands: &Shapes = &[(BandKind::Cells, 64, 64, cells)];
    let inband = encode_on(CoderKind::AdaptiveInBand, bands, grid_of(&g, 65, 1));
    let tokens = encode_on(CoderKind::AdaptiveTokens, bands, None);
    let grid = encode_on(CoderKind::AdaptiveGrid, bands, grid_of(&g, 65, 1));
    assert!(
        grid.len() > tokens.len() + 1,
        "the grid's contexts must mislead here"
    );
    assert!(
        inband.len() <= tokens.len() + 1,
        "in-band {} bytes, token coder {}",
        inband.len(),
        tokens.len()
    );
}

#[test]
fn indices_over_the_callers_limit_are_refused_after_the_prediction() {
    // The coded values may exceed the caller's limit by a prediction's size, so the limit
    // is checked on the indices themselves.
    let values: Vec<i32> = (0..64).map(|k| if k == 9 { 1000 } else { k % 3 }).collect();
    let bands: &Shapes = &[(BandKind::Roots, 8, 8, values.clone())];
    let bytes = encode_on(CoderKind::AdaptiveInBand, bands, None);
    let strict = DecodeLimits { max_abs: 999 };
    let e = decode_on(&bytes, bands, None, strict).expect_err("1000 > 999");
    assert!(e.to_string().contains("exceeds the limit 999"), "{e}");
    let got = decode_on(&bytes, bands, None, DecodeLimits { max_abs: 1000 });
    assert_eq!(got.expect("within the limit")[0], values);
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
        let values: Vec<i32> = values.into_iter().chain(std::iter::repeat(0)).take(w * w).collect();
        let n = w + 1;
        let g = fuzz_grid(n, seed, wide);
        let bands: &Shapes = &[(kind, w, w, values.clone())];
        let bytes = encode_on(CoderKind::AdaptiveInBand, bands, grid_of(&g, n, step));
        let got = decode_on(&bytes, bands, grid_of(&g, n, step), DecodeLimits::default());
        prop_assert_eq!(&got.expect("own record")[0], &values);
    }

    #[test]
    fn hostile_bytes_on_a_grid_never_panic(
        bytes in prop::collection::vec(any::<u8>(), 0..400),
        m in 0usize..70,
        seed in any::<u64>(),
        wide in any::<bool>(),
        max_abs in prop_oneof![Just(MAX as u32), 0u32..1000],
    ) {
        let g = fuzz_grid(m + 1, seed, wide);
        let shapes: &Shapes = &[(BandKind::Cells, m, m, vec![]), (BandKind::Vertices, m, m, vec![])];
        let limits = DecodeLimits { max_abs };
        if let Ok(got) = decode_on(&bytes, shapes, grid_of(&g, m + 1, 1), limits) {
            prop_assert!(got.iter().flatten().all(|v| v.unsigned_abs() <= max_abs));
        }
    }

    #[test]
    fn truncated_records_on_a_grid_never_panic(seed in any::<u64>(), cut in 0.0f64..1.0) {
        let mut rng = Rng(seed);
        let g = rough_grid(&mut rng, 65);
        let cells = cells_on_the_flatter_diagonal(&mut rng, &g, 65, 1);
        let bands: &Shapes = &[(BandKind::Cells, 64, 64, cells)];
        let bytes = encode_on(CoderKind::AdaptiveInBand, bands, grid_of(&g, 65, 1));
        let n = (bytes.len() as f64 * cut) as usize;
        let _ = decode_on(&bytes[..n], bands, grid_of(&g, 65, 1), DecodeLimits::default());
    }
}
