//! Property tests of the Elias-gamma quadtree coder through the public entropy interface.

use cbdam_codec::CodecError;
use cbdam_codec::entropy::{
    Band, BandKind, BandMut, CoderKind, DecodeLimits, decode_bands, encode_bands,
};
use proptest::prelude::*;

const GAMMA: CoderKind = CoderKind::EliasGamma;

#[derive(Clone, Debug)]
struct Mat {
    w: usize,
    h: usize,
    v: Vec<i32>,
}

fn encode(mats: &[Mat]) -> Vec<u8> {
    let bands: Vec<Band<'_>> = mats
        .iter()
        .map(|m| Band {
            kind: BandKind::Cells,
            width: m.w,
            height: m.h,
            values: &m.v,
        })
        .collect();
    let mut out = Vec::new();
    encode_bands(GAMMA, &bands, &mut out);
    out
}

fn decode(bytes: &[u8], shapes: &[(usize, usize)]) -> Result<Vec<Mat>, CodecError> {
    // Pre-fill with garbage: the decoder must overwrite every sample.
    let mut mats: Vec<Mat> = shapes
        .iter()
        .map(|&(w, h)| Mat {
            w,
            h,
            v: vec![i32::MIN; w * h],
        })
        .collect();
    let mut bands: Vec<BandMut<'_>> = mats
        .iter_mut()
        .map(|m| BandMut {
            kind: BandKind::Roots,
            width: m.w,
            height: m.h,
            values: &mut m.v,
        })
        .collect();
    decode_bands(GAMMA, bytes, &mut bands, DecodeLimits::default())?;
    Ok(mats)
}

fn shapes(mats: &[Mat]) -> Vec<(usize, usize)> {
    mats.iter().map(|m| (m.w, m.h)).collect()
}

const MAX: i32 = (1 << 30) - 1;

/// A value from one of several regimes: Laplacian-ish small, medium, extreme.
fn value() -> impl Strategy<Value = i32> {
    prop_oneof![
        6 => -3i32..=3,
        2 => -40i32..=40,
        1 => -70_000i32..=70_000,
        1 => prop_oneof![Just(MAX), Just(-MAX), Just(MAX - 1), Just(-MAX + 1), -MAX..=MAX],
    ]
}

/// A `w × h` matrix (sides 0..=max_side) with a random density of non-zeros.
fn mat(max_side: usize) -> impl Strategy<Value = Mat> {
    (0..=max_side, 0..=max_side, 0u32..=100).prop_flat_map(|(w, h, density)| {
        proptest::collection::vec((0u32..100, value()), w * h).prop_map(move |cells| Mat {
            w,
            h,
            v: cells
                .into_iter()
                .map(|(p, v)| if p < density { v } else { 0 })
                .collect(),
        })
    })
}

/// Shapes that stress the split rules: thin strips, odd sides, powers of two, one more/less.
fn tricky_mat() -> impl Strategy<Value = Mat> {
    let side = prop_oneof![
        Just(0usize),
        Just(1),
        Just(2),
        Just(3),
        Just(63),
        Just(64),
        Just(65),
        Just(127),
        Just(128),
        Just(130),
        1usize..=130
    ];
    (side.clone(), side, 0u32..=100).prop_flat_map(|(w, h, density)| {
        proptest::collection::vec((0u32..100, value()), w * h).prop_map(move |cells| Mat {
            w,
            h,
            v: cells
                .into_iter()
                .map(|(p, v)| if p < density { v } else { 0 })
                .collect(),
        })
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn round_trip_one_band(m in tricky_mat()) {
        let bytes = encode(std::slice::from_ref(&m));
        let got = decode(&bytes, &[(m.w, m.h)]).expect("decodes");
        prop_assert_eq!(&got[0].v, &m.v);
    }

    #[test]
    fn round_trip_several_bands(mats in proptest::collection::vec(mat(40), 0..6)) {
        let bytes = encode(&mats);
        let got = decode(&bytes, &shapes(&mats)).expect("decodes");
        for (g, m) in got.iter().zip(&mats) {
            prop_assert_eq!(&g.v, &m.v);
        }
    }

    /// Every proper prefix of a record is reported as truncated: the decoder follows the same
    /// path as on the full record until it reads a missing bit, and it always reads one.
    #[test]
    fn every_truncation_is_an_error(mats in proptest::collection::vec(mat(20), 1..4)) {
        let bytes = encode(&mats);
        let sh = shapes(&mats);
        for len in 0..bytes.len() {
            let r = decode(&bytes[..len], &sh);
            prop_assert!(matches!(r, Err(CodecError::Truncated(_))), "len {} gave {:?}", len, r.err());
        }
    }

    /// A flipped bit never panics, and whenever it still decodes, the result differs from the
    /// original and re-encodes to exactly the flipped bytes (the decoder accepts only canonical
    /// streams, so an accepted stream is some band set's encoding).
    #[test]
    fn every_bit_flip_is_handled(mats in proptest::collection::vec(mat(16), 1..3)) {
        let bytes = encode(&mats);
        let sh = shapes(&mats);
        for bit in 0..bytes.len() * 8 {
            let mut b = bytes.clone();
            b[bit / 8] ^= 0x80 >> (bit % 8);
            if let Ok(got) = decode(&b, &sh) {
                prop_assert!(got.iter().zip(&mats).any(|(g, m)| g.v != m.v));
                for g in &got {
                    prop_assert!(g.v.iter().all(|v| v.unsigned_abs() <= MAX as u32));
                }
                prop_assert_eq!(encode(&got), b);
            }
        }
    }

    /// Arbitrary bytes never panic; whatever decodes is canonical and within limits.
    #[test]
    fn random_bytes_never_panic(
        bytes in proptest::collection::vec(any::<u8>(), 0..64),
        sh in proptest::collection::vec((0usize..20, 0usize..20), 0..4),
    ) {
        if let Ok(got) = decode(&bytes, &sh) {
            for g in &got {
                prop_assert!(g.v.iter().all(|v| v.unsigned_abs() <= MAX as u32));
            }
            prop_assert_eq!(encode(&got), bytes);
        }
    }

    /// Random bytes biased towards 1 bits, which drive the quadtree deep into large bands.
    #[test]
    fn dense_random_bytes_never_panic(
        bytes in proptest::collection::vec(prop_oneof![Just(0xFFu8), any::<u8>()], 0..600),
        w in 1usize..1100,
        h in 1usize..600,
    ) {
        if let Ok(got) = decode(&bytes, &[(w, h)]) {
            prop_assert_eq!(encode(&got), bytes);
        }
    }
}

#[test]
fn large_root_band_round_trips() {
    // A root field the size the brief mentions, with a smooth-plus-noise residual pattern.
    let (w, h) = (1025usize, 513usize);
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let v: Vec<i32> = (0..w * h)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            match state % 16 {
                0..=9 => 0,
                10..=13 => (state >> 8) as i32 % 3,
                _ => (state >> 8) as i32 % 5000,
            }
        })
        .collect();
    let m = Mat { w, h, v };
    let bytes = encode(std::slice::from_ref(&m));
    assert_eq!(decode(&bytes, &[(w, h)]).unwrap()[0].v, m.v);
}

#[test]
fn both_signs_of_the_extreme_values_round_trip_in_every_position() {
    for (w, h) in [(1, 1), (2, 2), (3, 5), (64, 64), (63, 63)] {
        for pos in [0, w * h / 2, w * h - 1] {
            for val in [MAX, -MAX, 1, -1, 31, -31, 32, -32] {
                let mut v = vec![0; w * h];
                v[pos] = val;
                let m = Mat { w, h, v };
                let bytes = encode(std::slice::from_ref(&m));
                assert_eq!(
                    decode(&bytes, &[(w, h)]).unwrap()[0].v,
                    m.v,
                    "{w}×{h} {pos} {val}"
                );
            }
        }
    }
}

#[test]
#[should_panic(expected = "magnitude limit")]
fn encoder_rejects_values_beyond_the_limit() {
    let m = Mat {
        w: 1,
        h: 1,
        v: vec![MAX + 1],
    };
    encode(&[m]);
}

#[test]
#[should_panic(expected = "magnitude limit")]
fn encoder_rejects_i32_min() {
    let m = Mat {
        w: 2,
        h: 1,
        v: vec![0, i32::MIN],
    };
    encode(&[m]);
}
