use super::super::{
    Band, BandKind, BandMut, CoderKind, DecodeLimits, DecodeScratch, decode_bands,
    decode_bands_with, encode_bands,
};
use super::range_coder::Decoder;
use super::{Models, NCLASS, Scratch, class_of, code_band, model_set};
use crate::CodecError;
use proptest::prelude::*;

pub(super) const MAX: i32 = ((1u32 << 30) - 1) as i32;

/// Bands as tests write them: kind, width, height, values.
pub(super) type Shapes = [(BandKind, usize, usize, Vec<i32>)];

/// Encodes with `coder`, checking that a record is appended without touching what precedes it.
pub(super) fn encode_with(coder: CoderKind, bands: &Shapes) -> Vec<u8> {
    let bands: Vec<Band<'_>> = bands
        .iter()
        .map(|(kind, w, h, v)| Band {
            kind: *kind,
            width: *w,
            height: *h,
            values: v,
        })
        .collect();
    let mut out = vec![0xAB]; // records are appended: a prefix must survive untouched
    encode_bands(coder, &bands, &mut out);
    assert_eq!(out[0], 0xAB);
    out.remove(0);
    out
}

fn encode(bands: &Shapes) -> Vec<u8> {
    encode_with(CoderKind::Adaptive, bands)
}

fn decode(bytes: &[u8], shapes: &Shapes) -> Result<Vec<Vec<i32>>, CodecError> {
    // Start from garbage: the decoder must overwrite everything.
    decode_into(bytes, shapes, 7, None)
}

/// Decodes with `coder` into buffers pre-filled with `fill`, with fresh scratch or with
/// `scratch` reused.
pub(super) fn decode_with(
    coder: CoderKind,
    bytes: &[u8],
    shapes: &Shapes,
    fill: i32,
    limits: DecodeLimits,
    scratch: Option<&mut DecodeScratch>,
) -> Result<Vec<Vec<i32>>, CodecError> {
    decode_into_buffers(shapes, fill, |bands| match scratch {
        None => decode_bands(coder, bytes, bands, limits),
        Some(s) => decode_bands_with(coder, bytes, bands, limits, s),
    })
}

/// Buffers of `shapes`' sizes pre-filled with `fill`, handed to `decode` as bands.
pub(super) fn decode_into_buffers(
    shapes: &Shapes,
    fill: i32,
    decode: impl FnOnce(&mut [BandMut<'_>]) -> Result<(), CodecError>,
) -> Result<Vec<Vec<i32>>, CodecError> {
    let mut bufs: Vec<Vec<i32>> = shapes
        .iter()
        .map(|(_, w, h, _)| vec![fill; w * h])
        .collect();
    let mut bands: Vec<BandMut<'_>> = shapes
        .iter()
        .zip(bufs.iter_mut())
        .map(|((kind, w, h, _), buf)| BandMut {
            kind: *kind,
            width: *w,
            height: *h,
            values: buf,
        })
        .collect();
    decode(&mut bands)?;
    Ok(bufs)
}

fn decode_into(
    bytes: &[u8],
    shapes: &Shapes,
    fill: i32,
    scratch: Option<&mut DecodeScratch>,
) -> Result<Vec<Vec<i32>>, CodecError> {
    let limits = DecodeLimits::default();
    decode_with(CoderKind::Adaptive, bytes, shapes, fill, limits, scratch)
}

fn assert_round_trip(bands: &[(BandKind, usize, usize, Vec<i32>)]) -> Vec<u8> {
    let bytes = encode(bands);
    let got = decode(&bytes, bands).expect("valid record must decode");
    for ((_, _, _, want), got) in bands.iter().zip(&got) {
        assert_eq!(want, got);
    }
    bytes
}

/// Deterministic generator (SplitMix64) so rate tests do not depend on proptest's seeds.
pub(super) struct Rng(pub(super) u64);
impl Rng {
    pub(super) fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn unit(&mut self) -> f64 {
        ((self.next() >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    /// A Laplacian sample with the given scale, rounded to the nearest integer.
    fn laplace(&mut self, scale: f64) -> i32 {
        let mag = -scale * self.unit().ln();
        let v = mag.round() as i32;
        if self.next() & 1 == 0 { v } else { -v }
    }
}

pub(super) fn laplace_band(rng: &mut Rng, w: usize, h: usize, scale: f64) -> Vec<i32> {
    (0..w * h).map(|_| rng.laplace(scale)).collect()
}

/// Bits the paper's quadtree + Elias-gamma coder spends on a band: one bit per block visited,
/// split at the ceiling halves in Z order (empty children skipped), and at non-zero 1×1 leaves
/// gamma(|v|) = 2⌊log2|v|⌋ + 1 bits plus a sign bit.
pub(super) fn gamma_bits(
    v: &[i32],
    stride: usize,
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
) -> u64 {
    let nonzero = (y0..y0 + h).any(|y| {
        v[y * stride + x0..y * stride + x0 + w]
            .iter()
            .any(|&a| a != 0)
    });
    if !nonzero {
        return 1;
    }
    if w == 1 && h == 1 {
        let a = v[y0 * stride + x0].unsigned_abs();
        return 1 + 2 * u64::from(a.ilog2()) + 1 + 1;
    }
    let (w1, h1) = (w.div_ceil(2), h.div_ceil(2));
    let mut bits = 1;
    for (x, y, cw, ch) in [
        (x0, y0, w1, h1),
        (x0 + w1, y0, w - w1, h1),
        (x0, y0 + h1, w1, h - h1),
        (x0 + w1, y0 + h1, w - w1, h - h1),
    ] {
        if cw > 0 && ch > 0 {
            bits += gamma_bits(v, stride, x, y, cw, ch);
        }
    }
    bits
}

#[test]
fn gamma_bits_counts_by_hand() {
    // 2×2 with one value 5 at the top left: root flag, child flag, gamma(5) = 5 bits, sign,
    // and three zero-child flags.
    assert_eq!(gamma_bits(&[5, 0, 0, 0], 2, 0, 0, 2, 2), 1 + 1 + 5 + 1 + 3);
    assert_eq!(gamma_bits(&[0; 9], 3, 0, 0, 3, 3), 1);
}

#[test]
fn beats_elias_gamma_on_laplacian_residuals() {
    let mut rng = Rng(42);
    for scale in [0.3, 1.0, 4.0] {
        let v = laplace_band(&mut rng, 64, 64, scale);
        let bytes = assert_round_trip(&[(BandKind::Cells, 64, 64, v.clone())]);
        let gamma = gamma_bits(&v, 64, 0, 0, 64, 64).div_ceil(8);
        assert!(
            (bytes.len() as u64) < gamma,
            "scale {scale}: adaptive {} bytes, gamma {gamma} bytes",
            bytes.len()
        );
    }
    let zero = vec![0; 64 * 64];
    let bytes = assert_round_trip(&[(BandKind::Cells, 64, 64, zero.clone())]);
    assert!((bytes.len() as u64) < gamma_bits(&zero, 64, 0, 0, 64, 64).div_ceil(8));
}

#[test]
fn all_zero_band_costs_under_a_byte_next_to_data() {
    let mut rng = Rng(7);
    let v = laplace_band(&mut rng, 64, 64, 1.0);
    let alone = assert_round_trip(&[(BandKind::Cells, 64, 64, v.clone())]).len();
    let with_zero = assert_round_trip(&[
        (BandKind::Cells, 64, 64, v),
        (BandKind::Vertices, 63, 63, vec![0; 63 * 63]),
    ])
    .len();
    assert!(with_zero <= alone + 1, "{alone} → {with_zero}");
    assert!(assert_round_trip(&[(BandKind::Cells, 64, 64, vec![0; 4096])]).is_empty());
}

#[test]
fn sparse_band_is_small() {
    // Three isolated ±1s in a 64×64 band: far below the 4096 bits of one bit per sample.
    let mut v = vec![0; 4096];
    v[100] = 1;
    v[2000] = -1;
    v[4095] = 1;
    let bytes = assert_round_trip(&[(BandKind::Cells, 64, 64, v)]);
    assert!(bytes.len() <= 16, "{} bytes", bytes.len());
}

#[test]
fn extremes_round_trip() {
    let v: Vec<i32> = (0..65 * 65)
        .map(|i| [MAX, -MAX, 0, 1, -1, MAX - 1][i % 6])
        .collect();
    assert_round_trip(&[(BandKind::Roots, 65, 65, v)]);
    assert_round_trip(&[(BandKind::Cells, 1, 1, vec![-MAX])]);
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
    let mut buf = vec![0; 2];
    let mut out = [BandMut {
        kind: BandKind::Cells,
        width: 2,
        height: 1,
        values: &mut buf,
    }];
    let err = decode_bands(
        CoderKind::Adaptive,
        &bytes,
        &mut out,
        DecodeLimits { max_abs: 999 },
    );
    assert!(matches!(err, Err(CodecError::Corrupt(_))), "{err:?}");
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
    // Every truncation must be rejected or at least not panic; almost all must be rejected.
    let rejected = (0..bytes.len())
        .filter(|&n| decode(&bytes[..n], &bands).is_err())
        .count();
    assert!(rejected + 8 >= bytes.len(), "{rejected} of {}", bytes.len());
}

#[test]
fn bit_flips_never_panic() {
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
        // Decoding to different values is allowed (there is no redundancy to notice every
        // flip); panicking is not.
        if decode(&b, &bands).is_err() {
            detected += 1;
        }
    }
    // Arithmetic coding has no redundancy to catch every flip, but the length and range checks
    // must catch a good share of them.
    assert!(
        detected > bytes.len(),
        "{detected} of {} flips detected",
        bytes.len() * 8
    );
}

#[test]
fn context_class_table_matches_its_definition() {
    // The definition the format was written with: a table below 64, one class per octave above.
    let reference = |s: u32| -> usize {
        let bounds = [0u32, 1, 2, 4, 6, 9, 13, 19, 27, 39, 63];
        if s < 64 {
            bounds.iter().position(|&b| s <= b).unwrap()
        } else {
            (s.ilog2() as usize + 5).min(NCLASS - 1)
        }
    };
    let large = [1 << 16, 6 * 65535, u32::MAX / 2, u32::MAX];
    for s in (0..4096).chain(large) {
        assert_eq!(class_of(s), reference(s), "s = {s}");
    }
}

#[test]
fn reused_scratch_decodes_like_a_fresh_one() {
    // Records of different shapes and band counts, and damaged ones that fail half-way and leave
    // the scratch dirty, all through one scratch: every result must equal a fresh decode's.
    let mut rng = Rng(5);
    let shapes: [&[(usize, usize)]; 5] = [
        &[(64, 64), (63, 63)],
        &[(5, 3)],
        &[(130, 7)],
        &[(64, 64)],
        &[(1, 1), (33, 40)],
    ];
    let mut records = Vec::new();
    for (k, dims) in shapes.iter().cycle().take(12).enumerate() {
        let bands: Vec<_> = dims
            .iter()
            .enumerate()
            .map(|(i, &(w, h))| {
                let kind = if i == 0 {
                    BandKind::Cells
                } else {
                    BandKind::Vertices
                };
                let scale = [0.2, 1.0, 6.0][k % 3];
                (kind, w, h, laplace_band(&mut rng, w, h, scale))
            })
            .collect();
        let mut bytes = encode(&bands);
        if k % 4 == 3 && !bytes.is_empty() {
            let n = bytes.len();
            bytes[n / 2] ^= 0x5A;
        }
        records.push((bands, bytes));
    }
    let mut scratch = DecodeScratch::default();
    for (bands, bytes) in &records {
        let fresh = decode(bytes, bands);
        let reused = decode_into(bytes, bands, -9, Some(&mut scratch));
        match (fresh, reused) {
            (Ok(want), Ok(got)) => assert_eq!(want, got),
            (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string()),
            (a, b) => panic!("fresh {a:?}, reused {b:?}"),
        }
    }
}

/// The decoder as it was before the coefficient pass was specialised: the generic traversal the
/// encoder runs, driven by the range decoder. The fast decoder must agree with it on any bytes.
fn reference_decode(
    bytes: &[u8],
    shapes: &[(BandKind, usize, usize, Vec<i32>)],
) -> Result<Vec<Vec<i32>>, CodecError> {
    let mut bufs: Vec<Vec<i32>> = shapes.iter().map(|(_, w, h, _)| vec![0; w * h]).collect();
    if bytes.is_empty() {
        return Ok(bufs);
    }
    let mut dec = Decoder::new(bytes)?;
    let mut models = [Models::INIT, Models::INIT];
    let mut s = Scratch::default();
    for ((kind, w, h, _), buf) in shapes.iter().zip(bufs.iter_mut()) {
        if *w == 0 || *h == 0 {
            continue;
        }
        s.reset(*w, *h);
        let m = &mut models[model_set(*kind)];
        code_band(
            &mut dec,
            m,
            &mut s,
            buf,
            *w,
            *h,
            DecodeLimits::default().max_abs,
        )?;
    }
    dec.finish()?;
    Ok(bufs)
}

/// Same values, or errors of the same kind (messages may name different magnitudes).
pub(super) fn assert_same_outcome(
    fast: Result<Vec<Vec<i32>>, CodecError>,
    reference: Result<Vec<Vec<i32>>, CodecError>,
) {
    match (fast, reference) {
        (Ok(a), Ok(b)) => assert_eq!(a, b),
        (Err(a), Err(b)) => assert_eq!(
            std::mem::discriminant(&a),
            std::mem::discriminant(&b),
            "{a} / {b}"
        ),
        (a, b) => panic!("fast {a:?}, reference {b:?}"),
    }
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

pub(super) fn band_strategy() -> impl Strategy<Value = (BandKind, usize, usize, Vec<i32>)> {
    let kind = prop_oneof![
        Just(BandKind::Cells),
        Just(BandKind::Vertices),
        Just(BandKind::Roots)
    ];
    let value = prop_oneof![
        6 => Just(0),
        3 => -3..=3i32,
        2 => -100..=100i32,
        1 => -MAX..=MAX,
        1 => prop_oneof![Just(MAX), Just(-MAX)],
    ];
    (kind, 0usize..=130, 0usize..=130, prop::bool::ANY).prop_flat_map(
        move |(kind, w, h, sparse)| {
            let v = if sparse {
                // Mostly zero with a few non-zeros somewhere.
                prop::collection::vec(prop_oneof![30 => Just(0), 1 => value.clone()], w * h).boxed()
            } else {
                prop::collection::vec(value.clone(), w * h).boxed()
            };
            v.prop_map(move |v| (kind, w, h, v))
        },
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 96, ..ProptestConfig::default() })]

    #[test]
    fn round_trips(bands in prop::collection::vec(band_strategy(), 0..4)) {
        assert_round_trip(&bands);
    }

    #[test]
    fn random_bytes_never_panic(
        bytes in prop::collection::vec(any::<u8>(), 0..200),
        w in 0usize..80,
        h in 0usize..80,
    ) {
        let shapes = [(BandKind::Cells, w, h, vec![]), (BandKind::Vertices, h, w, vec![])];
        let _ = decode(&bytes, &shapes);
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
