//! The whole-file readers decode once: `verify_with_finest` and `verify_with_reached` give, from
//! one walk, exactly what `verify` and a second walk (`reconstruct_finest_with_validity`,
//! `reconstruct_reached`) gave; and `LevelGrid::decode` (what `cbdam extract` and the Python
//! package's whole read write) holds exactly what a serial walk puts on the level's grid — on a
//! real DEM with nodata (α = 1 and ½) and a variable-resolution hierarchy.

use std::path::Path;

use crate::util::Rng;
use crate::variable_resolution::{encode_var, terrain, variable_input};
use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::hierarchy::{
    EncodeOptions, Encoded, Encoder, reconstruct_finest_with_validity, reconstruct_reached, verify,
    verify_with_finest, verify_with_reached, walk_all_with_validity,
};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan, Quantizer};
use cbdam_codec::repository::LevelGrid;

/// The Rhine DEM (48 % nodata) encoded at `eps` with `alpha`, and its grid.
fn rhine(eps: f64, alpha: Alpha) -> (Encoded, HeightGrid) {
    let opts = EncodeOptions {
        alpha,
        ..EncodeOptions::default()
    };
    bundled("rhine_nodata.tif", eps, &opts)
}

/// The bundled DEM `file` encoded at `eps` with `opts`, and its grid.
fn bundled(file: &str, eps: f64, opts: &EncodeOptions) -> (Encoded, HeightGrid) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data")
        .join(file);
    let dem = read_dem(&path, &ReadOptions::default()).unwrap();
    let plan = QuantPlan::for_dem(&dem, eps, None).unwrap();
    let grid = HeightGrid::from_dem(&dem, &plan).unwrap();
    let enc = Encoder::new(&grid, plan.quantizer, opts).encode().unwrap();
    (enc, grid)
}

/// The variable-resolution hierarchy of `variable_resolution.rs` and its grid.
fn variable() -> (Encoded, HeightGrid) {
    let h = terrain(&mut Rng(7));
    let (grid, res) = variable_input(&h);
    let enc = encode_var(&grid, &res, Quantizer::new(3).unwrap());
    (enc, grid)
}

/// The cases: nodata at α = 1 and ½, variable resolution.
fn cases() -> Vec<(&'static str, Encoded, HeightGrid)> {
    let (a, ga) = rhine(1.0, Alpha::One);
    let (b, gb) = rhine(2.0, Alpha::Half);
    let (c, gc) = variable();
    vec![
        ("rhine α=1", a, ga),
        ("rhine α=½", b, gb),
        ("variable", c, gc),
    ]
}

#[test]
fn verify_with_the_finest_level_is_verify_and_a_second_decode() {
    for (name, enc, grid) in cases() {
        let (report, finest, valid) = verify_with_finest(&enc, &grid).unwrap();
        assert_eq!(report, verify(&enc, &grid).unwrap(), "{name}: report");
        let (want, want_valid) = reconstruct_finest_with_validity(&enc).unwrap();
        assert!(finest == want, "{name}: finest heights differ");
        assert!(valid == want_valid, "{name}: finest mask differs");
        assert!(valid.iter().any(|v| !v), "{name}: the case has nodata");
    }
}

#[test]
fn verify_with_the_points_reached_is_verify_and_a_second_decode() {
    for (name, enc, grid) in cases() {
        let (report, heights, state) = verify_with_reached(&enc, &grid).unwrap();
        assert_eq!(report, verify(&enc, &grid).unwrap(), "{name}: report");
        let (want, want_state) = reconstruct_reached(&enc).unwrap();
        assert!(heights == want, "{name}: heights differ");
        assert!(state == want_state, "{name}: states differ");
    }
}

/// What a serial walk puts on `grid`'s samples (`fill` elsewhere): every visit of the grid's
/// level, point by point, the valid ones only, later visits over earlier ones.
fn serial_reference(enc: &Encoded, grid: &LevelGrid, fill: i64) -> Vec<i64> {
    let mut out = vec![fill; grid.width * grid.height];
    let layout = enc.params.layout();
    let n = layout.n();
    walk_all_with_validity(enc, |id, p, valid| {
        if id.level != grid.level {
            return;
        }
        let g = layout.grid(id);
        for j in 0..n {
            for i in 0..n {
                let (x, y) = g.point(i as i64, j as i64);
                if let Some(k) = grid.index_of(x, y)
                    && valid.is_none_or(|v| v[j * n + i])
                {
                    out[k] = i64::from(p[j * n + i]);
                }
            }
        }
    })
    .unwrap();
    out
}

#[test]
fn a_level_grid_decodes_to_what_a_serial_walk_puts_there() {
    let fill = i64::MIN;
    for (name, enc, _) in cases() {
        let (w, h) = enc.params.domain.data().size();
        let (w, h) = (w as i64, h as i64);
        let finest = enc.params.layout().finest_level();
        let windows = [
            (None, None),
            (None, Some((w / 5, h / 3, w / 2 + 7, h - 2))),
            (Some(finest - 2), None),
            (Some(finest - 4), Some((3, 1, w / 3, h / 2))),
        ];
        for (level, rect) in windows {
            let grid = LevelGrid::new(&enc.params, level, rect, "level").unwrap();
            let want = serial_reference(&enc, &grid, fill);
            for threads in [1, 2, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let got = pool.install(|| grid.decode(&enc, fill, i64::from)).unwrap();
                assert!(
                    got == want,
                    "{name}: level {level:?} window {rect:?} on {threads} threads"
                );
            }
            assert!(want.iter().any(|&v| v != fill), "{name}: samples decoded");
        }
    }
}

/// Without a nodata mask the finest level is written straight from the level above's
/// refinements, half of a child at a time (no grid of the level gathered): the same samples as
/// the serial walk's grids, on a DEM whose sides are not the domain's (diamonds on the domain's
/// edge, mirrored halves), at α = 1 and ½, with both coders and a small N (many diamonds).
#[test]
fn the_finest_level_without_a_mask_is_what_a_serial_walk_puts_there() {
    let fill = i64::MIN;
    let cases = [
        (Alpha::One, CoderKind::FastRice, 17),
        (Alpha::Half, CoderKind::AdaptiveTokens, 33),
        (Alpha::One, CoderKind::AdaptiveTokens, 65),
    ];
    for (alpha, coder, n) in cases {
        let opts = EncodeOptions {
            alpha,
            coder,
            n,
            ..EncodeOptions::default()
        };
        let (enc, _) = bundled("jacksboro_mpl.tif", 0.5, &opts);
        assert!(!enc.params.nodata_mask, "the case has no mask");
        let (w, h) = enc.params.domain.data().size();
        let (w, h) = (w as i64, h as i64);
        for rect in [None, Some((w / 5 + 1, h / 3, w / 2 + 7, h - 2))] {
            let grid = LevelGrid::new(&enc.params, None, rect, "level").unwrap();
            let want = serial_reference(&enc, &grid, fill);
            assert!(want.iter().all(|&v| v != fill), "every sample decoded");
            for threads in [1, 2] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let got = pool.install(|| grid.decode(&enc, fill, i64::from)).unwrap();
                assert!(
                    got == want,
                    "{alpha:?} {coder:?} N = {n}, window {rect:?}, {threads} threads"
                );
            }
        }
    }
}

#[test]
fn a_level_grid_refuses_an_output_of_another_size() {
    let (enc, _) = variable();
    let grid = LevelGrid::new(&enc.params, None, None, "level").unwrap();
    let mut short = vec![0i32; grid.width * grid.height - 1];
    let e = grid.decode_into(&enc, |h| h, &mut short).unwrap_err();
    assert!(e.to_string().contains("samples given for a"), "{e}");
}
