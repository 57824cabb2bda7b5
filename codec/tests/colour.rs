//! Colour repositories: the RGB bound after YCoCg-R holds exactly at several tolerances
//! (lossless at 0), the container round-trips and refuses what does not fit, and the alignment
//! with an elevation repository refuses mismatched domains.

use crate::util::Rng;
use cbdam_codec::colour::{
    Alignment, RgbImage, encode_colour, reconstruct_rgb, verify_colour, ycocg,
};
use cbdam_codec::hierarchy::{EncodeOptions, Encoder, RepoKind};
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::{Repository, serialize};

/// Large flat regions (like fields), a smooth ramp, a sharp-edged pattern and noise: every
/// kind of content a colour bound must survive.
fn image(w: usize, h: usize, seed: u64) -> RgbImage {
    let mut rng = Rng(seed);
    let pixels = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let noise = (rng.next() % 9) as i32 - 4;
            let base: [i32; 3] = match (x * 3 / w, y * 2 / h) {
                (0, 0) => [200, 30, 40],
                (1, 0) => [20, 180, 60],
                (2, 0) => [30, 60, 220],
                (0, _) => [(x * 255 / w) as i32, (y * 255 / h) as i32, 128],
                (1, _) => {
                    if (x / 3 + y / 3) % 2 == 0 {
                        [255, 255, 255]
                    } else {
                        [0, 0, 0]
                    }
                }
                _ => [120, 110, 90],
            };
            base.map(|v| (v + noise).clamp(0, 255) as u8)
        })
        .collect();
    RgbImage {
        width: w,
        height: h,
        pixels,
        georef: None,
    }
}

fn opts() -> EncodeOptions {
    EncodeOptions {
        n: 9,
        ..EncodeOptions::default()
    }
}

#[test]
fn rgb_bound_holds_at_every_tolerance_and_zero_is_lossless() {
    let img = image(61, 45, 7);
    let mut bytes_seen = Vec::new();
    for max_error in [0u32, 4, 8, 16] {
        let (enc, plan) = encode_colour(&img, max_error, &opts(), &|_, _| {}).unwrap();
        let file = serialize(&enc, &plan, None, None).unwrap();
        let repo = Repository::from_bytes(file.clone()).unwrap();
        assert_eq!(repo.head().kind(), RepoKind::Colour);
        repo.check_all().unwrap();
        let back = repo.to_encoded().unwrap();
        let report = verify_colour(&back, &img).unwrap();
        assert!(report.within_bound(), "{max_error}: {report:?}");
        assert!(report.rgb_bound.iter().all(|&b| b <= max_error));
        let rgb = reconstruct_rgb(&back).unwrap();
        let worst = rgb
            .iter()
            .zip(&img.pixels)
            .flat_map(|(a, b)| (0..3).map(move |c| (i32::from(a[c]) - i32::from(b[c])).abs()))
            .max()
            .unwrap();
        assert!(worst as u32 <= max_error, "{max_error}: {worst}");
        if max_error == 0 {
            assert_eq!(rgb, img.pixels, "tolerance 0 must be lossless");
        }
        // A looser tolerance must actually be used: the bound is not vacuous.
        if max_error >= 4 {
            assert!(worst > 0, "{max_error}: lossless at a loose tolerance?");
        }
        bytes_seen.push(file.len());
    }
    assert!(
        bytes_seen.windows(2).all(|w| w[1] < w[0]),
        "size must drop as the tolerance grows: {bytes_seen:?}"
    );
}

#[test]
fn colour_decoder_matches_reconstruction_and_elevation_decoder_refuses() {
    let img = image(33, 33, 3);
    let (enc, plan) = encode_colour(&img, 4, &opts(), &|_, _| {}).unwrap();
    let repo = Repository::from_bytes(serialize(&enc, &plan, None, None).unwrap()).unwrap();
    let err = repo.head().decoder().unwrap_err().to_string();
    assert!(err.contains("colour"), "{err}");
    // Refine every stored diamond with the colour decoder, level by level, and compare the
    // finest diamonds' RGB with the whole-image reconstruction.
    let dec = repo.head().colour_decoder().unwrap();
    let layout = repo.head().params().layout();
    let full = reconstruct_rgb(&enc).unwrap();
    let mut refined = std::collections::HashMap::new();
    let mut scratch = Default::default();
    let n = layout.n();
    let mut checked = 0;
    let mut finest = std::collections::BTreeSet::new();
    for e in repo.head().entries() {
        let parents = layout
            .parents(e.id)
            .map(|p| p.and_then(|p| refined.get(&p)));
        let grids = dec.grid_of(e.id, parents);
        let r = dec
            .refine(&grids, repo.record(e.id).unwrap(), &mut scratch)
            .unwrap();
        refined.insert(e.id, r);
        if e.id.level + 1 == layout.finest_level() {
            finest.extend(layout.children(e.id).into_iter().flatten());
        }
    }
    for id in finest {
        let parents = layout.parents(id).map(|p| p.and_then(|p| refined.get(&p)));
        let rgb = cbdam_codec::colour::ColourDecoder::rgb(&dec.grid_of(id, parents));
        let g = layout.grid(id);
        for j in 0..n {
            for i in 0..n {
                let (x, y) = g.point(i as i64, j as i64);
                // Points on a side whose parent is absent are not gathered; sides inside the
                // data always have both parents stored.
                if repo.head().params().domain.data().contains(x, y)
                    && parents.iter().all(|p| p.is_some())
                {
                    assert_eq!(rgb[j * n + i], full[y as usize * 33 + x as usize], "{id}");
                    checked += 1;
                }
            }
        }
    }
    assert!(checked > 33 * 33, "{checked}");
}

#[test]
fn hostile_colour_records_error_not_panic() {
    let img = image(21, 17, 11);
    let (enc, plan) = encode_colour(&img, 2, &opts(), &|_, _| {}).unwrap();
    let repo = Repository::from_bytes(serialize(&enc, &plan, None, None).unwrap()).unwrap();
    let dec = repo.head().colour_decoder().unwrap();
    let n = repo.head().params().layout().n();
    let grids = [vec![0i32; n * n], vec![0; n * n], vec![0; n * n]];
    let mut rng = Rng(5);
    let mut scratch = Default::default();
    for len in 0..64usize {
        let bytes: Vec<u8> = (0..len).map(|_| rng.next() as u8).collect();
        let _ = dec.refine(&grids, &bytes, &mut scratch);
    }
    for len in [0usize, 3, 8, 9] {
        let bytes: Vec<u8> = (0..len).map(|_| 0xFF).collect();
        let params = *repo.head().params();
        assert!(cbdam_codec::colour::ColourDecoder::new(params, &bytes).is_err());
    }
}

#[test]
fn alignment_accepts_power_of_two_refinements_and_refuses_mismatches() {
    let elevation = |w: usize, h: usize| {
        let plan = QuantPlan::new(1.0, None, 0.0, 100.0).unwrap();
        let metres: Vec<f64> = (0..w * h).map(|i| (i % 97) as f64).collect();
        let grid = HeightGrid::from_metres(w, h, &metres, None, &plan).unwrap();
        Encoder::new(&grid, plan.quantizer, &opts())
            .encode()
            .unwrap()
            .params
    };
    let colour = |w: usize, h: usize| {
        encode_colour(&image(w, h, 1), 4, &opts(), &|_, _| {})
            .unwrap()
            .0
            .params
    };
    let e = elevation(25, 17);
    // Same size, twice finer, twice coarser: aligned.
    for (w, h, shift) in [(25, 17, 0), (49, 33, 1), (13, 9, -1)] {
        let a = Alignment::new(&e, None, &colour(w, h), None).unwrap();
        assert_eq!(a.shift, shift, "{w}×{h}");
    }
    let a = Alignment::new(&e, None, &colour(49, 33), None).unwrap();
    let id = cbdam_codec::geometry::DiamondId::new(1, 16, 8);
    assert_eq!(a.colour_id(id).map(|c| (c.x, c.y)), Some((32, 16)));
    // Off by one sample, a different aspect, or swapped kinds: refused, naming the domain.
    for (w, h) in [(26, 17), (25, 18), (49, 17), (50, 34)] {
        let err = Alignment::new(&e, None, &colour(w, h), None)
            .unwrap_err()
            .to_string();
        assert!(err.contains("domain"), "{w}×{h}: {err}");
    }
    assert!(Alignment::new(&colour(25, 17), None, &e, None).is_err());
}

#[test]
fn bound_table_is_what_the_docs_state() {
    // docs/FORMAT.md and docs/RESULTS.md ("Colour") state these; keep them honest.
    assert_eq!(ycocg::channel_k(4), 2);
    assert_eq!(ycocg::rgb_bound(2), [4, 3, 4]);
    assert_eq!(ycocg::channel_k(10), 4);
    assert_eq!(ycocg::rgb_bound(4), [8, 6, 8]);
}
