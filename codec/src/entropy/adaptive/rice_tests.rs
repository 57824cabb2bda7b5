//! Tests of the Rice coder: round trips over random and extreme bands, hostile bytes, and a
//! plain reference decoder (one row at a time, one field at a time) that the interleaved fast
//! decoder must agree with on any bytes.

use super::super::super::{BandKind, CoderKind, DecodeLimits, DecodeScratch};
use super::super::tests::{
    MAX, Rng, Shapes, assert_same_outcome, band_strategy, decode_with, encode_with, laplace_band,
};
use super::*;
use crate::entropy::adaptive::tokens::get_len;
use crate::entropy::bitio::{BitReader, BitWriter};
use proptest::prelude::*;

fn encode(bands: &Shapes) -> Vec<u8> {
    encode_with(CoderKind::FastRice, bands)
}

fn decode_limited(
    bytes: &[u8],
    shapes: &Shapes,
    limits: DecodeLimits,
) -> Result<Vec<Vec<i32>>, CodecError> {
    // Start from garbage: the decoder must overwrite everything.
    decode_with(CoderKind::FastRice, bytes, shapes, 7, limits, None)
}

fn decode(bytes: &[u8], shapes: &Shapes) -> Result<Vec<Vec<i32>>, CodecError> {
    decode_limited(bytes, shapes, DecodeLimits::default())
}

fn assert_round_trip(bands: &Shapes) -> Vec<u8> {
    let bytes = encode(bands);
    let got = decode(&bytes, bands).expect("valid record must decode");
    for ((_, _, _, want), got) in bands.iter().zip(&got) {
        assert_eq!(want, got);
    }
    bytes
}

/// One Rice code read a field at a time: the unary zeros bit by bit, the one, the low bits.
/// A quotient past the escape (no encoder writes one) sets `bad`.
fn reference_code(r: &mut BitReader<'_>, k: u32, bad: &mut bool) -> u64 {
    let mut q = 0;
    while q <= ESCAPE && !r.get_bit() {
        q += 1;
    }
    if q > ESCAPE {
        *bad = true;
    }
    if q >= ESCAPE {
        u64::from(r.get_bits(ESCAPE_BITS))
    } else {
        (u64::from(q) << k) | u64::from(r.get_bits(k))
    }
}

/// The format as plainly as it can be written: each row read in raster order from its own
/// stream, with its context summed from the magnitudes already decoded; damage found is
/// reported after each pair of rows, an overrun first, then a bad quotient, then a magnitude.
fn reference_decode(bytes: &[u8], shapes: &Shapes) -> Result<Vec<Vec<i32>>, CodecError> {
    let mut bufs: Vec<Vec<i32>> = shapes.iter().map(|(_, w, h, _)| vec![0; w * h]).collect();
    if bytes.is_empty() {
        return Ok(bufs);
    }
    let (a_len, header) = get_len(bytes, "fast-rice")?;
    let rest = &bytes[header..];
    if a_len > rest.len() {
        return Err(CodecError::truncated("stream A"));
    }
    let mut readers = [
        BitReader::new(&rest[..a_len]),
        BitReader::new(&rest[a_len..]),
    ];
    let mut s = Scratch::default();
    for ((_, w, h, _), values) in shapes.iter().zip(bufs.iter_mut()) {
        let (w, h) = (*w, *h);
        if w == 0 || h == 0 {
            continue;
        }
        s.reset(w, h);
        let top = s.dims.len() - 1;
        if readers[0].get_bit() {
            s.set_dense();
        } else if !code_node(
            &mut RawFlags(&mut readers[0]),
            &mut no_models(),
            &mut s,
            top,
            0,
            0,
            false,
        ) {
            continue;
        }
        if readers[0].is_overrun() {
            return Err(CodecError::truncated("header"));
        }
        let ks = get_k_table(&mut readers[0])?;
        // Magnitudes with a zero column either side and a zero row above, at `(x + 1, y + 1)`.
        let mut magnitudes = vec![0u64; (w + 2) * (h + 1)];
        let at = |xp: usize, yp: usize| yp * (w + 2) + xp;
        let (mut bad, mut too_large) = (false, false);
        for y in 0..h {
            s.rice_slots(y, w);
            let r = &mut readers[y % 2];
            for &x in &s.slots {
                let x = x as usize;
                let m = |xp: usize, yp: usize| magnitudes[at(xp, yp)].min(u64::from(MAG_SAT));
                let sum = 2 * (m(x, y + 1) + m(x + 1, y)) + m(x, y) + m(x + 2, y);
                let u = reference_code(r, ks[rice_class(sum as u32)], &mut bad);
                let a = u.div_ceil(2);
                too_large |= a > u64::from(DecodeLimits::default().max_abs);
                values[y * w + x] = if u % 2 == 1 { -(a as i32) } else { a as i32 };
                magnitudes[at(x + 1, y + 1)] = a;
            }
            if y % 2 == 1 || y + 1 == h {
                if readers.iter().any(BitReader::is_overrun) {
                    return Err(CodecError::truncated("record ends early"));
                }
                if bad || too_large {
                    return Err(CodecError::corrupt("quotient or magnitude"));
                }
            }
        }
    }
    check_padding(&mut readers[0], "A")?;
    check_padding(&mut readers[1], "B")?;
    Ok(bufs)
}

#[test]
fn classes_follow_their_definition() {
    // The definition the format was written with: the token coder's table below 64, then one
    // class per octave, to the last class.
    let reference = |s: u32| -> usize {
        let bounds = [0u32, 1, 2, 4, 6, 9, 13, 19, 27, 39, 63];
        if s < 64 {
            bounds.iter().position(|&b| s <= b).unwrap()
        } else {
            (s.ilog2() as usize + 5).min(RICE_CLASSES - 1)
        }
    };
    for s in (0..5000).chain([6 * MAG_SAT, u32::from(u16::MAX) << 3]) {
        assert_eq!(rice_class(s), reference(s), "sum {s}");
    }
    assert_eq!(rice_class(6 * MAG_SAT), RICE_CLASSES - 1);
}

#[test]
fn k_by_sum_is_the_table_at_the_class_of_the_sum() {
    let ks: [u32; RICE_CLASSES] = std::array::from_fn(|c| (c as u32 * 7) % (MAX_K + 1));
    let by_sum = KBySum::new(&ks);
    for s in (0..1 << 19).step_by(7).chain([63, 64, 65, 6 * MAG_SAT]) {
        assert_eq!(by_sum.k(s), ks[rice_class(s)], "sum {s}");
    }
}

#[test]
fn zigzag_interleaves_signs() {
    let got: Vec<u32> = [0, -1, 1, -2, 2, MAX, -MAX].map(zigzag).to_vec();
    let max = MAX as u32;
    assert_eq!(got, [0, 1, 2, 3, 4, 2 * max, 2 * max - 1]);
}

#[test]
fn extremes_round_trip() {
    // The quantizer's whole index range, in every position of a 2×2 neighbourhood.
    let v: Vec<i32> = (0..65 * 65)
        .map(|i| [MAX, -MAX, 0, 1, -1, MAX - 1, -MAX + 1][i % 7])
        .collect();
    assert_round_trip(&[(BandKind::Roots, 65, 65, v)]);
    assert_round_trip(&[(BandKind::Cells, 1, 1, vec![-MAX])]);
    assert_round_trip(&[(BandKind::Cells, 3, 1, vec![MAX, 0, -MAX])]);
    // A single spike anywhere in a zero band, at both extremes and at one.
    for i in 0..33 * 33 {
        let mut v = vec![0; 33 * 33];
        v[i] = [MAX, -MAX, 1][i % 3];
        assert_round_trip(&[(BandKind::Cells, 33, 33, v)]);
    }
    // All zeros: the empty record, and a zero band beside data costs a bit or two.
    assert!(assert_round_trip(&[(BandKind::Cells, 64, 64, vec![0; 4096])]).is_empty());
    let mut rng = Rng(7);
    let data = laplace_band(&mut rng, 64, 64, 1.0);
    let alone = assert_round_trip(&[(BandKind::Cells, 64, 64, data.clone())]).len();
    let with_zero = assert_round_trip(&[
        (BandKind::Cells, 64, 64, data),
        (BandKind::Vertices, 63, 63, vec![0; 63 * 63]),
    ])
    .len();
    assert!(with_zero <= alone + 1, "{alone} → {with_zero}");
}

#[test]
fn sparse_bands_use_the_quadtree_and_busy_ones_go_dense() {
    // Three isolated ±1s in a 64×64 band: far below one bit per sample.
    let mut v = vec![0; 4096];
    v[100] = 1;
    v[2000] = -1;
    v[4095] = 1;
    let bytes = assert_round_trip(&[(BandKind::Cells, 64, 64, v)]);
    assert!(bytes.len() <= 20, "{} bytes", bytes.len());
    // A busy band: the dense bit set, no quadtree.
    let mut rng = Rng(5);
    let busy = laplace_band(&mut rng, 64, 64, 20.0);
    let bytes = assert_round_trip(&[(BandKind::Cells, 64, 64, busy)]);
    let (a_len, header) = get_len(&bytes, "fast-rice").unwrap();
    assert!(a_len > 0);
    assert_eq!(bytes[header] >> 7, 1, "dense bit");
}

#[test]
fn the_k_table_is_no_worse_than_any_single_k() {
    let mut rng = Rng(13);
    for scale in [0.3, 2.0, 40.0, 3000.0] {
        let v = laplace_band(&mut rng, 64, 64, scale);
        let bands = [(BandKind::Cells, 64, 64, v.clone())];
        let bytes = assert_round_trip(&bands);
        let mut s = Scratch::default();
        s.reset(64, 64);
        s.set_flags(&v, 64, 64);
        s.set_dense();
        let mut coded = Vec::new();
        contexts(&mut s, &v, 64, 64, &mut coded);
        let best_single = (0..=MAX_K)
            .map(|k| coded.iter().map(|&(_, u)| code_bits(u, k)).sum::<u64>())
            .min()
            .unwrap();
        // The table costs at most 5 + 3 · 23 bits, the framing a few bytes.
        assert!(
            (bytes.len() as u64) * 8 <= best_single + 5 + 3 * 23 + 32,
            "scale {scale}: {} bytes against {best_single} bits",
            bytes.len()
        );
    }
}

#[test]
#[should_panic(expected = "exceeds")]
fn encoder_rejects_out_of_range() {
    encode(&[(BandKind::Cells, 1, 1, vec![MAX + 1])]);
}

#[test]
fn limit_is_enforced() {
    let bands = [(BandKind::Cells, 2, 1, vec![3, 1000])];
    let bytes = encode(&bands);
    let err = decode_limited(&bytes, &bands, DecodeLimits { max_abs: 999 });
    assert!(
        matches!(&err, Err(CodecError::Corrupt(m)) if m.contains("1000")),
        "{err:?}"
    );
    assert!(decode_limited(&bytes, &bands, DecodeLimits { max_abs: 1000 }).is_ok());
}

#[test]
fn a_k_above_the_largest_is_corrupt_and_named() {
    // Dense bit, then k₀ = 31 in 5 bits: 1 11111 …
    let shapes = [(BandKind::Cells, 4, 4, vec![])];
    let err = decode(&[1, 0b1111_1100, 0], &shapes);
    assert!(
        matches!(&err, Err(CodecError::Corrupt(m)) if m.contains("Rice parameter 31 of class 0")),
        "{err:?}"
    );
}

#[test]
fn a_quotient_past_the_escape_is_corrupt() {
    // A 1×1 dense band (its row is even: stream A): dense bit, k₀ = 0, 23 "same", then a
    // code of 32 zeros, then ones.
    let mut w = BitWriter::new();
    w.put_bits(1, 1);
    w.put_bits(0, 5);
    w.put_bits(0, 23);
    w.put_bits(0, 32);
    w.put_bits(u32::MAX, 32);
    let a = w.finish();
    let mut bytes = vec![a.len() as u8];
    bytes.extend_from_slice(&a);
    let err = decode(&bytes, &[(BandKind::Cells, 1, 1, vec![])]);
    assert!(
        matches!(&err, Err(CodecError::Corrupt(m)) if m.contains("quotient")),
        "{err:?}"
    );
}

#[test]
fn trailing_bytes_and_truncation_are_errors() {
    let mut rng = Rng(3);
    let bands = [(BandKind::Cells, 64, 64, laplace_band(&mut rng, 64, 64, 2.0))];
    let bytes = encode(&bands);
    let mut longer = bytes.clone();
    longer.extend_from_slice(&[0x5A; 8]);
    assert!(matches!(
        decode(&longer, &bands),
        Err(CodecError::Corrupt(_))
    ));
    let half = &bytes[..bytes.len() / 2];
    assert!(matches!(
        decode(half, &bands),
        Err(CodecError::Truncated(_))
    ));
    // Every truncation but to nothing (the all-zero record) is rejected.
    for n in 1..bytes.len() {
        assert!(decode(&bytes[..n], &bands).is_err(), "cut at {n}");
    }
}

#[test]
fn bit_flips_never_panic_and_most_are_caught() {
    let mut rng = Rng(11);
    let mut v = laplace_band(&mut rng, 40, 33, 3.0);
    v[5] = MAX;
    let bands = [
        (BandKind::Cells, 40, 33, v),
        (BandKind::Vertices, 7, 5, laplace_band(&mut rng, 7, 5, 0.3)),
    ];
    let bytes = encode(&bands);
    let mut detected = 0;
    for bit in 0..bytes.len() * 8 {
        let mut b = bytes.clone();
        b[bit / 8] ^= 1 << (bit % 8);
        if decode(&b, &bands).is_err() {
            detected += 1;
        }
    }
    assert!(
        detected > bytes.len(),
        "{detected} of {} flips detected",
        bytes.len() * 8
    );
}

#[test]
fn reused_scratch_decodes_like_a_fresh_one() {
    let mut rng = Rng(17);
    let mut scratch = DecodeScratch::default();
    for (w, h) in [(64, 64), (5, 70), (33, 33), (1, 1), (64, 64)] {
        let bands = [
            (BandKind::Cells, w, h, laplace_band(&mut rng, w, h, 2.0)),
            (BandKind::Vertices, h, w, laplace_band(&mut rng, h, w, 0.2)),
        ];
        let bytes = encode(&bands);
        let reused = decode_with(
            CoderKind::FastRice,
            &bytes,
            &bands,
            -5,
            DecodeLimits::default(),
            Some(&mut scratch),
        );
        assert_eq!(reused.unwrap(), decode(&bytes, &bands).unwrap());
    }
}

#[test]
fn fast_decoder_matches_the_reference_on_damaged_records() {
    let mut rng = Rng(9);
    for k in 0..300 {
        let (w, h) = (
            1 + (rng.next() % 70) as usize,
            1 + (rng.next() % 70) as usize,
        );
        let bands = [
            (
                BandKind::Cells,
                w,
                h,
                laplace_band(&mut rng, w, h, [0.3, 2.0, 40.0][k % 3]),
            ),
            (BandKind::Vertices, h, w, laplace_band(&mut rng, h, w, 1.0)),
        ];
        let mut bytes = encode(&bands);
        if !bytes.is_empty() {
            let i = (rng.next() as usize) % bytes.len();
            bytes[i] ^= 1 << (rng.next() % 8);
        }
        assert_same_outcome(decode(&bytes, &bands), reference_decode(&bytes, &bands));
    }
}

/// A band whose 4×4 leaf blocks are each coded (Laplace values, with a large one now and then)
/// or zero with even odds: gaps between coded blocks, runs of them, a last block column narrower
/// than a block.
fn block_sparse_band(rng: &mut Rng, w: usize, h: usize) -> Vec<i32> {
    let (gw, gh) = (w.div_ceil(B), h.div_ceil(B));
    let coded: Vec<bool> = (0..gw * gh).map(|_| rng.next().is_multiple_of(2)).collect();
    let mut values = laplace_band(rng, w, h, 3.0);
    for (i, v) in values.iter_mut().enumerate() {
        let (x, y) = (i % w, i / w);
        if !coded[(y / B) * gw + x / B] {
            *v = 0;
        } else if rng.next().is_multiple_of(64) {
            *v = 70_000 * if rng.next().is_multiple_of(2) { 1 } else { -1 };
        }
    }
    values
}

#[test]
fn blocks_with_gaps_and_a_narrow_last_column_decode_like_the_reference() {
    // The decoder walks each row pair a block at a time, the odd row one block behind; the odd
    // row's last column in a block takes its top-right neighbour from the even row's next block.
    let mut rng = Rng(47);
    for k in 0..400 {
        let (w, h) = (4 * (1 + k % 9) + k % 4, 1 + (k / 4) % 23);
        let bands = [
            (BandKind::Cells, w, h, block_sparse_band(&mut rng, w, h)),
            (BandKind::Vertices, h, w, block_sparse_band(&mut rng, h, w)),
        ];
        let mut bytes = assert_round_trip(&bands);
        assert_same_outcome(decode(&bytes, &bands), reference_decode(&bytes, &bands));
        if !bytes.is_empty() {
            let i = (rng.next() as usize) % bytes.len();
            bytes[i] ^= 1 << (rng.next() % 8);
            assert_same_outcome(decode(&bytes, &bands), reference_decode(&bytes, &bands));
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, ..ProptestConfig::default() })]

    #[test]
    fn round_trips(bands in prop::collection::vec(band_strategy(), 0..4)) {
        assert_round_trip(&bands);
    }

    #[test]
    fn random_bytes_decode_like_the_reference(
        bytes in prop::collection::vec(prop_oneof![3 => Just(0u8), 1 => any::<u8>()], 0..300),
        w in 0usize..80,
        h in 0usize..80,
    ) {
        let shapes = [(BandKind::Cells, w, h, vec![]), (BandKind::Vertices, h, w, vec![])];
        assert_same_outcome(decode(&bytes, &shapes), reference_decode(&bytes, &shapes));
    }

    #[test]
    fn valid_records_decode_like_the_reference(bands in prop::collection::vec(band_strategy(), 1..3)) {
        let bytes = encode(&bands);
        assert_same_outcome(decode(&bytes, &bands), reference_decode(&bytes, &bands));
    }

    #[test]
    fn truncations_are_errors(bands in prop::collection::vec(band_strategy(), 1..3), cut in 0.0f64..1.0) {
        let bytes = encode(&bands);
        let n = (bytes.len() as f64 * cut) as usize;
        prop_assert!(n == 0 || n == bytes.len() || decode(&bytes[..n], &bands).is_err());
    }
}
