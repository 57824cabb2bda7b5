//! Golden hashes of the encoder's exact output and the decoder's exact reconstruction.
//!
//! The L∞ tests accept any output within the bound; these pin the bytes. They guard the format
//! against silent drift across platforms (float-free integer paths must give identical bytes
//! everywhere) and across refactors of the lifting, gather, quantizer and coders. The expected
//! values cannot come from an independent source: they were captured from the codec itself and
//! must only change together with a deliberate, documented format change.
//!
//! The token coder's values (`adaptive-tokens`, coder id 2) were captured when it was added;
//! their reconstruction hashes equal the other coders', which nothing was copied from.
//!
//! To re-capture after such a change, print the current values instead of asserting:
//! `CBDAM_PRINT_GOLDEN=1 cargo test -p cbdam-codec --test tests -- golden:: --nocapture`.
//! Each test then prints all its values and fails: a run that checked nothing is never green.

use std::path::Path;

use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::hierarchy::{EncodeOptions, Encoded, Encoder, reconstruct_finest, verify};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan, Quantizer};
use cbdam_codec::samples::Dem;

/// 64-bit FNV-1a: tiny, dependency-free and fully specified, so the hash itself can never be
/// the thing that changed.
#[derive(Clone, Copy)]
struct Fnv1a(u64);

impl Fnv1a {
    fn new() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
}

fn fnv(bytes: &[u8]) -> u64 {
    let mut h = Fnv1a::new();
    h.write(bytes);
    h.0
}

#[test]
fn fnv1a_matches_the_reference_vectors() {
    // From the FNV reference test suite (Noll, "FNV hash" test vectors, FNV-1a 64-bit).
    assert_eq!(fnv(b""), 0xcbf2_9ce4_8422_2325);
    assert_eq!(fnv(b"a"), 0xaf63_dc4c_8601_ec8c);
    assert_eq!(fnv(b"foobar"), 0x8594_4171_f739_67e8);
}

/// Hash of everything a repository stores for the hierarchy: the root field's bytes, then per
/// record (in id order) its id, length, metadata and bytes, then the leaf error. Ids and lengths
/// are framed so that bytes moving between records cannot cancel out.
fn hash_encoded(enc: &Encoded) -> u64 {
    let mut h = Fnv1a::new();
    h.write(&(enc.roots.len() as u32).to_le_bytes());
    h.write(&enc.roots);
    for r in &enc.records {
        h.write(&[r.id.level]);
        h.write(&r.id.x.to_le_bytes());
        h.write(&r.id.y.to_le_bytes());
        h.write(&(r.bytes.len() as u32).to_le_bytes());
        h.write(&r.object_error.to_le_bytes());
        h.write(&r.min.to_le_bytes());
        h.write(&r.max.to_le_bytes());
        h.write(&r.bytes);
    }
    h.write(&enc.leaf_error.to_le_bytes());
    h.0
}

/// Hash of the finest reconstruction as little-endian `i32`s, row-major.
fn hash_finest(enc: &Encoded) -> u64 {
    let mut h = Fnv1a::new();
    for v in reconstruct_finest(enc).unwrap() {
        h.write(&v.to_le_bytes());
    }
    h.0
}

/// Checks (or, with `CBDAM_PRINT_GOLDEN=1`, prints) one fixture's hashes; returns them.
fn golden(
    name: &str,
    grid: &HeightGrid,
    quantizer: Quantizer,
    opts: EncodeOptions,
    want: (u64, u64),
) -> (u64, u64) {
    let enc = Encoder::new(grid, quantizer, &opts).encode().unwrap();
    // A golden value is only worth pinning if the output it pins is correct.
    let report = verify(&enc, grid).unwrap();
    assert!(report.within_bound(), "{name}: {report:?}");
    let got = (hash_encoded(&enc), hash_finest(&enc));
    if printing() {
        println!(
            "{name}: (0x{:016x}, 0x{:016x}), // {} records, {} bytes",
            got.0,
            got.1,
            enc.records.len(),
            enc.payload_bytes()
        );
        return got;
    }
    assert_eq!(
        got, want,
        "{name}: the encoded bytes or the reconstruction changed (got (0x{:016x}, 0x{:016x})). \
         If the format change is deliberate, re-capture with CBDAM_PRINT_GOLDEN=1.",
        got.0, got.1
    );
    got
}

/// Whether the hashes are printed instead of checked (`CBDAM_PRINT_GOLDEN=1`).
fn printing() -> bool {
    std::env::var_os("CBDAM_PRINT_GOLDEN").is_some_and(|v| v == "1")
}

/// The end of a golden test: the cross-check below, then, in the printing mode, a failure —
/// the values were printed, not checked, and such a run must never read as green.
fn finish(hashes: &[(Alpha, CoderKind, (u64, u64))]) {
    same_reconstruction_for_every_coder(hashes);
    fail_if_printed(printing());
}

fn fail_if_printed(printed: bool) {
    assert!(
        !printed,
        "CBDAM_PRINT_GOLDEN=1: the hashes were printed above, not checked, so this test fails"
    );
}

#[test]
fn the_printing_mode_never_passes() {
    fail_if_printed(false);
    assert!(std::panic::catch_unwind(|| fail_if_printed(true)).is_err());
}

/// The entropy coder is lossless over the same quantizer indices, so the reconstruction must
/// not depend on it: a cross-check of the golden values that needs no captured value.
fn same_reconstruction_for_every_coder(hashes: &[(Alpha, CoderKind, (u64, u64))]) {
    for (alpha, coder, (_, finest)) in hashes {
        for (a, c, (_, f)) in hashes {
            assert!(
                a != alpha || f == finest,
                "{alpha:?}: {} and {} reconstruct differently",
                coder.name(),
                c.name()
            );
        }
    }
}

fn read(name: &str) -> Dem {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data")
        .join(name);
    read_dem(&path, &ReadOptions::default()).unwrap()
}

/// The `w × h` window at `(x0, y0)` of a DEM, planned at `eps` on its own.
fn crop(dem: &Dem, x0: usize, y0: usize, w: usize, h: usize, eps: f64) -> (HeightGrid, Quantizer) {
    let part = dem.crop(x0, y0, w, h).unwrap();
    let plan = QuantPlan::for_dem(&part, eps, None).unwrap();
    (HeightGrid::from_dem(&part, &plan).unwrap(), plan.quantizer)
}

fn opts(alpha: Alpha, coder: CoderKind) -> EncodeOptions {
    EncodeOptions {
        alpha,
        coder,
        ..EncodeOptions::default()
    }
}

#[test]
fn srtm_crop_at_one_metre() {
    // Integer (1 m lattice) terrain, k = 1, N = 65: both coders' cell bands, and for α = ½ the
    // vertex bands and the analysis filter. A 200 × 150 window so that the data rectangle ends
    // inside diamonds (don't-care residuals at the edges).
    // Re-captured after the root field's quantizer became k/2 (a deliberate format change); must
    // only change with a deliberate format change.
    let (grid, q) = crop(&read("srtm3_demcompare.tif"), 300, 420, 200, 150, 1.0);
    let cases = [
        (
            Alpha::One,
            CoderKind::EliasGamma,
            (0x1526dcfb9a4e4ed0, 0xfed915baa85c9c34),
        ),
        (
            Alpha::One,
            CoderKind::Adaptive,
            (0xf9db822c2c4acfac, 0xfed915baa85c9c34),
        ),
        (
            Alpha::One,
            CoderKind::AdaptiveTokens,
            (0x719371d0ad16f3c1, 0xfed915baa85c9c34),
        ),
        (
            Alpha::Half,
            CoderKind::EliasGamma,
            (0x0b9d7c2e5c8a7b95, 0x7cdbbc091dcb96ac),
        ),
        (
            Alpha::Half,
            CoderKind::Adaptive,
            (0x06ac5be5f8cc277f, 0x7cdbbc091dcb96ac),
        ),
        (
            Alpha::Half,
            CoderKind::AdaptiveTokens,
            (0xd13a107a5c2d51f6, 0x7cdbbc091dcb96ac),
        ),
    ];
    let mut got = Vec::new();
    for (alpha, coder, want) in cases {
        let name = format!("srtm 200x150 ε=1 {alpha:?} {}", coder.name());
        got.push((
            alpha,
            coder,
            golden(&name, &grid, q, opts(alpha, coder), want),
        ));
    }
    finish(&got);
}

#[test]
fn lidar_crop_at_half_a_metre() {
    // Float input: pre-quantization to a binary unit (1/16 m at ε = 0.5, k = 7), so larger
    // residual indices than the integer fixtures.
    // Re-captured after the root field's quantizer became k/2 (a deliberate format change); must
    // only change with a deliberate format change.
    let (grid, q) = crop(&read("lidar1m_mn.tif"), 100, 60, 160, 130, 0.5);
    let mut got = Vec::new();
    for (coder, want) in [
        (
            CoderKind::EliasGamma,
            (0xad0c4350e7186ca2, 0x77f1dbb38922226a),
        ),
        (
            CoderKind::Adaptive,
            (0x1a3de91ded900f0f, 0x77f1dbb38922226a),
        ),
        (
            CoderKind::AdaptiveTokens,
            (0xd84b8f5474152682, 0x77f1dbb38922226a),
        ),
    ] {
        let name = format!("lidar 160x130 ε=0.5 One {}", coder.name());
        let h = golden(&name, &grid, q, opts(Alpha::One, coder), want);
        got.push((Alpha::One, coder, h));
    }
    finish(&got);
}

#[test]
fn synthetic_field_with_holes_and_small_diamonds() {
    // Integer-only input (no libm, so identical on every platform): smooth ramps plus
    // pseudo-random bumps, a nodata hole and a cliff; N = 9 for a deep hierarchy (many levels of
    // gather), k = 3.
    // Re-captured after the root field's quantizer became k/2 (a deliberate format change); must
    // only change with a deliberate format change.
    let (w, h) = (97, 61);
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut values = Vec::with_capacity(w * h);
    let mut valid = Vec::with_capacity(w * h);
    for y in 0..h as i32 {
        for x in 0..w as i32 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let noise = (state % 41) as i32 - 20;
            let cliff = if x + y / 2 > 60 { 700 } else { 0 };
            values.push(3 * x - 2 * y + (x * y) % 37 + noise + cliff - 150);
            let (dx, dy) = (x - 30, y - 40);
            valid.push(dx * dx + 2 * dy * dy > 120);
        }
    }
    let grid = HeightGrid {
        width: w,
        height: h,
        values: values.into(),
        valid: valid.into(),
    };
    let q = Quantizer::new(3).unwrap();
    let cases = [
        (
            Alpha::One,
            CoderKind::EliasGamma,
            (0x2700517cc0f585ef, 0x0f131d93d6dd1e3d),
        ),
        (
            Alpha::One,
            CoderKind::Adaptive,
            (0x7c91c13ac069c30b, 0x0f131d93d6dd1e3d),
        ),
        (
            Alpha::One,
            CoderKind::AdaptiveTokens,
            (0x83103d16cf52d946, 0x0f131d93d6dd1e3d),
        ),
        (
            Alpha::Half,
            CoderKind::EliasGamma,
            (0xa650db655412fb1c, 0xef24132373bd434f),
        ),
        (
            Alpha::Half,
            CoderKind::Adaptive,
            (0xce9ee39fa0ed361c, 0xef24132373bd434f),
        ),
        (
            Alpha::Half,
            CoderKind::AdaptiveTokens,
            (0x0d3261f542e46c7b, 0xef24132373bd434f),
        ),
    ];
    let mut got = Vec::new();
    for (alpha, coder, want) in cases {
        let name = format!("synthetic 97x61 k=3 N=9 {alpha:?} {}", coder.name());
        let o = EncodeOptions {
            n: 9,
            ..opts(alpha, coder)
        };
        got.push((alpha, coder, golden(&name, &grid, q, o, want)));
    }
    finish(&got);
}
