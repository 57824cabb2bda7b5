use super::super::super::{BandKind, CoderKind, DecodeLimits, DecodeScratch};
use super::super::tests::{
    MAX, Rng, Shapes, assert_same_outcome, band_strategy, decode_with, encode_with, gamma_bits,
    laplace_band,
};
use super::*;
use proptest::prelude::*;

fn encode(bands: &Shapes) -> Vec<u8> {
    encode_with(CoderKind::AdaptiveTokens, bands)
}

fn decode_into(
    bytes: &[u8],
    shapes: &Shapes,
    fill: i32,
    limits: DecodeLimits,
    scratch: Option<&mut DecodeScratch>,
) -> Result<Vec<Vec<i32>>, CodecError> {
    decode_with(
        CoderKind::AdaptiveTokens,
        bytes,
        shapes,
        fill,
        limits,
        scratch,
    )
}

fn decode(bytes: &[u8], shapes: &Shapes) -> Result<Vec<Vec<i32>>, CodecError> {
    // Start from garbage: the decoder must overwrite everything.
    decode_into(bytes, shapes, 7, DecodeLimits::default(), None)
}

fn assert_round_trip(bands: &Shapes) -> Vec<u8> {
    let bytes = encode(bands);
    let got = decode(&bytes, bands).expect("valid record must decode");
    for ((_, _, _, want), got) in bands.iter().zip(&got) {
        assert_eq!(want, got);
    }
    bytes
}

/// The format as plainly as it can be written: [`pair_order`] driving one coefficient at a
/// time, each tree decision loading its model, the raw bits read one field at a time. The
/// fast decoder (interleaved rows, preloaded models, branch-free raw reads) must agree with it
/// on any bytes.
fn reference_decode(bytes: &[u8], shapes: &Shapes) -> Result<Vec<Vec<i32>>, CodecError> {
    let mut bufs: Vec<Vec<i32>> = shapes.iter().map(|(_, w, h, _)| vec![0; w * h]).collect();
    if bytes.is_empty() {
        return Ok(bufs);
    }
    let (raw_len, header) = get_len(bytes, "adaptive tokens")?;
    let rest = &bytes[header..];
    if raw_len > rest.len() {
        return Err(CodecError::truncated("raw stream"));
    }
    let (raw_bytes, coded) = rest.split_at(raw_len);
    let mut raw = BitReader::new(raw_bytes);
    let mut d = Decoder::new(coded);
    let mut models = [TokenModels::<NCLASS>::INIT, TokenModels::INIT];
    let mut s = Scratch::default();
    for ((kind, w, h, _), values) in shapes.iter().zip(bufs.iter_mut()) {
        let (w, h) = (*w, *h);
        if w == 0 || h == 0 {
            continue;
        }
        s.reset(w, h);
        let m = &mut models[model_set(*kind)];
        let top = s.dims.len() - 1;
        if !code_node(&mut d, &mut m.node, &mut s, top, 0, 0, false) {
            continue;
        }
        if d.overran() {
            return Err(CodecError::truncated("record ends early"));
        }
        let stride = w + 4;
        let mut failure = None;
        for y0 in (0..h).step_by(2) {
            s.fill_slots(y0, w);
            let (slots, mag) = (&s.slots, &mut s.mag);
            pair_order(slots.len(), y0 + 1 < h, |i, r| {
                let (x, y) = (slots[i] as usize, y0 + r);
                let j = (y + 2) * stride + 2 + x;
                let sum = 2 * (u32::from(mag[j - 1]) + u32::from(mag[j - stride]))
                    + u32::from(mag[j - stride - 1])
                    + u32::from(mag[j - stride + 1]);
                let class = class_of(sum);
                let border = (y < 2 || y + 2 >= h || x < 2 || x + 2 >= w) as usize;
                let k = shift_of(sum);
                let (mut a, mut negative) = (0u64, false);
                if d.decode(&mut m.zero[class][border]) {
                    let tree = &mut m.tree[class];
                    let mut n = 1;
                    for _ in 0..TREE_LEVELS {
                        n = 2 * n + d.decode(&mut tree[n]) as usize;
                    }
                    let token = (n - TOKENS) as u64;
                    let mut q = token;
                    if token == u64::from(ESCAPE) {
                        match raw.get_gamma(MAX_GAMMA_ZEROS) {
                            Some(g) => q = u64::from(g) + u64::from(ESCAPE) - 1,
                            None => q = u64::MAX >> 20,
                        }
                    }
                    let low = if k > 0 { raw.get_bits(k) } else { 0 };
                    a = ((q << k) | u64::from(low)) + 1;
                    negative = raw.get_bit();
                }
                if a > u64::from(DecodeLimits::default().max_abs) {
                    failure.get_or_insert(a);
                    return;
                }
                values[y * w + x] = if negative { -(a as i32) } else { a as i32 };
                mag[j] = a.min(u64::from(MAG_SAT)) as u16;
            });
            if failure.is_some() {
                return Err(CodecError::corrupt("magnitude"));
            }
            if d.overran() || raw.is_overrun() {
                return Err(CodecError::truncated("record ends early"));
            }
        }
    }
    d.finish()?;
    match raw.remaining_padding() {
        Some((_, 0)) => Ok(bufs),
        Some(_) => Err(CodecError::corrupt("padding")),
        None if raw.is_overrun() => Err(CodecError::truncated("raw stream")),
        None => Err(CodecError::corrupt("unused raw bytes")),
    }
}

#[test]
fn pair_order_visits_every_slot_once_after_its_top_right_neighbour() {
    for n in 0..12 {
        for pair in [false, true] {
            let mut seen = Vec::new();
            pair_order(n, pair, |i, r| seen.push((i, r)));
            let rows = if pair { 2 } else { 1 };
            assert_eq!(seen.len(), n * rows, "n {n}");
            for r in 0..rows {
                let order: Vec<usize> = seen.iter().filter(|s| s.1 == r).map(|s| s.0).collect();
                assert_eq!(order, (0..n).collect::<Vec<_>>(), "n {n} row {r}");
            }
            // Row 1's slot i comes after row 0's slots up to i + 1.
            for (t, &(i, r)) in seen.iter().enumerate() {
                if r == 1 {
                    let done = seen[..t].iter().filter(|s| s.1 == 0).count();
                    assert!(done >= (i + 2).min(n), "n {n}: slot {i} after {done}");
                }
            }
        }
    }
}

#[test]
fn shift_grows_by_one_per_octave_from_sixteen() {
    let want = [
        (0, 0),
        (1, 0),
        (15, 0),
        (16, 1),
        (31, 1),
        (32, 2),
        (1 << 18, 15),
    ];
    for (sum, k) in want {
        assert_eq!(shift_of(sum), k, "sum {sum}");
    }
    assert_eq!(shift_of(6 * MAG_SAT), 15);
}

#[test]
fn tree_priors_are_probabilities_and_favour_small_tokens() {
    for rho in [0.2, 0.5, 0.8] {
        for n in 1..TOKENS {
            let p = tree_prior(rho, n);
            assert!((1..4096).contains(&p), "rho {rho} node {n}: {p}");
        }
        // Geometric tokens: the lower half of every node is at least as likely.
        assert!(tree_prior(rho, 1) >= 2048, "rho {rho}");
    }
}

#[test]
fn extremes_round_trip() {
    let v: Vec<i32> = (0..65 * 65)
        .map(|i| [MAX, -MAX, 0, 1, -1, MAX - 1, 7, 8, -9][i % 9])
        .collect();
    assert_round_trip(&[(BandKind::Roots, 65, 65, v)]);
    assert_round_trip(&[(BandKind::Cells, 1, 1, vec![-MAX])]);
    assert!(assert_round_trip(&[(BandKind::Cells, 64, 64, vec![0; 4096])]).is_empty());
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
    let err = decode_into(&bytes, &bands, 0, DecodeLimits { max_abs: 999 }, None);
    assert!(matches!(err, Err(CodecError::Corrupt(_))), "{err:?}");
    let ok = decode_into(&bytes, &bands, 0, DecodeLimits { max_abs: 1000 }, None);
    assert_eq!(ok.unwrap(), vec![vec![3, 1000]]);
}

#[test]
fn an_escape_beyond_two_to_the_thirty_is_an_error_not_an_overflow() {
    // A 1×1 band holding 2^30 − 1 codes as an escape whose Elias-gamma value is about 2^30 in
    // the raw stream. One more (|v| = 2^30, just over the limit), 2^30 and the largest value a
    // gamma code can hold are what no encoder writes.
    let bands = [(BandKind::Cells, 1, 1, vec![MAX])];
    let bytes = encode(&bands);
    let (raw_len, header) = get_len(&bytes, "adaptive tokens").unwrap();
    assert!(
        raw_len >= 8,
        "escape of 2^30 needs about 61 raw bits: {raw_len} bytes"
    );
    let (raw_bytes, coded) = bytes[header..].split_at(raw_len);
    let mut r = BitReader::new(raw_bytes);
    let g = r.get_gamma(MAX_GAMMA_ZEROS).unwrap();
    // |v| − 1 = q = g + 6 (no low bits: k = 0 without neighbours).
    assert_eq!(u64::from(g) + u64::from(ESCAPE) - 1 + 1, MAX as u64);
    for hostile in [(1 << 30) - 7, 1 << 30, u32::MAX] {
        let mut w = BitWriter::new();
        w.put_gamma(hostile);
        w.put_bit(false);
        let raw = w.finish();
        let mut rec = Vec::new();
        put_len(&mut rec, raw.len());
        rec.extend_from_slice(&raw);
        rec.extend_from_slice(coded);
        let got = decode(&rec, &bands);
        assert!(
            matches!(got, Err(CodecError::Corrupt(_))),
            "{hostile}: {got:?}"
        );
    }
}

#[test]
fn record_framing_errors_are_named() {
    let mut rng = Rng(3);
    let bands = [(BandKind::Cells, 8, 8, laplace_band(&mut rng, 8, 8, 2.0))];
    let bytes = encode(&bands);
    assert!(bytes[0] < 0x80, "a one-byte raw stream length");
    // A raw stream longer than the record.
    let mut long = vec![0xFF, 0x7F];
    long.extend_from_slice(&bytes[1..]);
    assert!(matches!(
        decode(&long, &bands),
        Err(CodecError::Truncated(_))
    ));
    // An over-long length encoding, and one that never ends.
    let mut padded = vec![0x80 | bytes[0], 0x00];
    padded.extend_from_slice(&bytes[1..]);
    assert!(matches!(
        decode(&padded, &bands),
        Err(CodecError::Corrupt(_))
    ));
    assert!(matches!(
        decode(&[0x80; 3], &bands),
        Err(CodecError::Truncated(_))
    ));
    assert!(matches!(
        decode(&[0xFF; 9], &bands),
        Err(CodecError::Corrupt(_))
    ));
}

#[test]
fn trailing_bytes_and_truncation_are_errors() {
    let mut rng = Rng(3);
    let bands = [(BandKind::Cells, 64, 64, laplace_band(&mut rng, 64, 64, 2.0))];
    let bytes = encode(&bands);
    let mut longer = bytes.clone();
    longer.extend_from_slice(&[0x5A; 16]);
    assert!(matches!(
        decode(&longer, &bands),
        Err(CodecError::Corrupt(_))
    ));
    let half = &bytes[..bytes.len() / 2];
    assert!(matches!(
        decode(half, &bands),
        Err(CodecError::Truncated(_))
    ));
    // Every truncation must be rejected or at least not panic; almost all must be rejected
    // (the range coder's flush may drop up to 8 trailing zero bytes, which read back as zeros).
    let rejected = (0..bytes.len())
        .filter(|&n| decode(&bytes[..n], &bands).is_err())
        .count();
    assert!(rejected + 9 >= bytes.len(), "{rejected} of {}", bytes.len());
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
        let fast = decode(&b, &bands);
        if fast.is_err() {
            detected += 1;
        }
        assert_same_outcome(fast, reference_decode(&b, &bands));
    }
    // Neither stream has redundancy to catch every flip, but the framing, length and range
    // checks must catch a good share of them.
    assert!(
        detected > bytes.len(),
        "{detected} of {} flips detected",
        bytes.len() * 8
    );
}

#[test]
fn reused_scratch_decodes_like_a_fresh_one() {
    // Records of different shapes, some damaged so that they fail half-way and leave the
    // scratch dirty, all through one scratch: every result must equal a fresh decode's.
    let mut rng = Rng(5);
    let shapes: [&[(usize, usize)]; 5] = [
        &[(64, 64), (63, 63)],
        &[(5, 3)],
        &[(130, 7)],
        &[(64, 64)],
        &[(1, 1), (33, 40)],
    ];
    let mut scratch = DecodeScratch::default();
    for (k, dims) in shapes.iter().cycle().take(12).enumerate() {
        let bands: Vec<_> = dims
            .iter()
            .enumerate()
            .map(|(i, &(w, h))| {
                let kind = [BandKind::Cells, BandKind::Vertices][i.min(1)];
                let scale = [0.2, 1.0, 60.0][k % 3];
                (kind, w, h, laplace_band(&mut rng, w, h, scale))
            })
            .collect();
        let mut bytes = encode(&bands);
        if k % 4 == 3 && !bytes.is_empty() {
            let n = bytes.len();
            bytes[n / 2] ^= 0x5A;
        }
        let fresh = decode(&bytes, &bands);
        let reused = decode_into(
            &bytes,
            &bands,
            -9,
            DecodeLimits::default(),
            Some(&mut scratch),
        );
        match (fresh, reused) {
            (Ok(want), Ok(got)) => assert_eq!(want, got),
            (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string()),
            (a, b) => panic!("fresh {a:?}, reused {b:?}"),
        }
    }
}

#[test]
fn beats_elias_gamma_and_stays_near_the_bitwise_coder_on_laplacian_residuals() {
    let mut rng = Rng(42);
    for scale in [0.3, 1.0, 4.0, 30.0] {
        let v = laplace_band(&mut rng, 64, 64, scale);
        let bands = [(BandKind::Cells, 64, 64, v.clone())];
        let tokens = assert_round_trip(&bands).len();
        let gamma = gamma_bits(&v, 64, 0, 0, 64, 64).div_ceil(8) as usize;
        let bitwise = encode_with(CoderKind::Adaptive, &bands).len();
        assert!(
            tokens < gamma,
            "scale {scale}: {tokens} bytes, gamma {gamma}"
        );
        // The raw low bits and sign cost a little; more than 4 % would mean a broken context.
        assert!(
            tokens * 100 <= bitwise * 104,
            "scale {scale}: {tokens} bytes, bitwise {bitwise}"
        );
    }
}

#[test]
fn sparse_band_is_small() {
    let mut v = vec![0; 4096];
    v[100] = 1;
    v[2000] = -1;
    v[4095] = 1;
    let bytes = assert_round_trip(&[(BandKind::Cells, 64, 64, v)]);
    assert!(bytes.len() <= 16, "{} bytes", bytes.len());
}

#[test]
fn fast_decoder_matches_the_reference_on_damaged_records() {
    let mut rng = Rng(9);
    for k in 0..200 {
        let (w, h) = (
            1 + (rng.next() % 70) as usize,
            1 + (rng.next() % 70) as usize,
        );
        let bands = [
            (
                BandKind::Cells,
                w,
                h,
                laplace_band(&mut rng, w, h, [0.3, 2.0, 40.0, 3000.0][k % 4]),
            ),
            (BandKind::Vertices, h, w, laplace_band(&mut rng, h, w, 1.0)),
        ];
        let mut bytes = encode(&bands);
        assert_same_outcome(decode(&bytes, &bands), reference_decode(&bytes, &bands));
        if !bytes.is_empty() {
            let i = (rng.next() as usize) % bytes.len();
            bytes[i] ^= 1 << (rng.next() % 8);
        }
        assert_same_outcome(decode(&bytes, &bands), reference_decode(&bytes, &bands));
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 96, ..ProptestConfig::default() })]

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
    fn truncations_never_panic(bands in prop::collection::vec(band_strategy(), 1..3), cut in 0.0f64..1.0) {
        let bytes = encode(&bands);
        let n = (bytes.len() as f64 * cut) as usize;
        let _ = decode(&bytes[..n], &bands);
    }
}
