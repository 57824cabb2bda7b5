//! What a repository file from a hostile writer must survive, as the fuzz targets
//! `repository_crc` and `repository_fields` check it, here so that the stable test
//! `codec/tests/hostile_inputs.rs` (run by CI, which cannot run libFuzzer) puts the same checks
//! through the same inputs' space: bytes mutated with every checksum recomputed, and header
//! fields crafted to absurd values with every checksum recomputed. Checksums guard against
//! damage, not against a writer that computes them: such a file must still give a clean error
//! or a repository whose derived values are usable and whose hierarchy decodes, never a panic.
//! Each function panics (the fuzzer's finding) when that does not hold.

use super::{CRAFTABLE_FIELDS, MAGIC, MAX_MAGNITUDE, Repository, craft_header, reseal_checksums};
use crate::colour::reconstruct_rgb;
use crate::hierarchy::{RepoKind, walk_all_with_validity};
use crate::lifting::MAX_ABS_HEIGHT;

/// Floats that break arithmetic that trusts its inputs.
pub const INTERESTING: &[f64] = &[
    0.0,
    -0.0,
    1.0,
    -1.0,
    0.5,
    1e-300,
    5e-324,
    1e15,
    1.000_000_1e15,
    1e16,
    1e300,
    1e308,
    -1e308,
    f64::MAX,
    f64::MIN,
    f64::MIN_POSITIVE,
    f64::INFINITY,
    f64::NEG_INFINITY,
    f64::NAN,
    -f64::NAN,
    44_000_000.0,
    2.0e7,
    6.4e6,
];

/// Bytes per field edit in a [`crafted_fields`] input: field selector, value kind, eight value
/// bytes.
pub const EDIT: usize = 10;

/// `data`, a repository file, with its section CRCs, header CRC and every record's checksum
/// recomputed over whatever bytes the header points at, then opened and, if it opens, checked
/// and decoded whole. Whether it opened.
pub fn resealed(data: &[u8]) -> bool {
    let mut b = data.to_vec();
    reseal_checksums(&mut b);
    let Ok(repo) = Repository::from_bytes(b) else {
        return false;
    };
    let _ = repo.check_all();
    decode_whole(&repo);
    true
}

/// One byte `e`, then `e % 5` edits of [`EDIT`] bytes, then a repository file (an input that
/// starts with the repository magic is a file without edits): each edit sets a header field
/// ([`CRAFTABLE_FIELDS`]) to a value — raw bits, one of [`INTERESTING`], a small integer, or an
/// integer as a float — through [`craft_header`], which recomputes every CRC. Whatever then
/// opens must hold only values a reader can use: every height a record can reconstruct and
/// every georeferenced coordinate of the lattice finite and within [`MAX_MAGNITUDE`], and the
/// hierarchy must decode. Whether it opened.
pub fn crafted_fields(data: &[u8]) -> bool {
    let (edits, file) = if data.starts_with(&MAGIC) {
        (&[][..], data)
    } else {
        let Some((&e, rest)) = data.split_first() else {
            return false;
        };
        let n = usize::from(e % 5) * EDIT;
        if rest.len() < n {
            return false;
        }
        rest.split_at(n)
    };
    let mut b = file.to_vec();
    for edit in edits.chunks_exact(EDIT) {
        let field = CRAFTABLE_FIELDS[usize::from(edit[0]) % CRAFTABLE_FIELDS.len()];
        let raw: [u8; 8] = edit[2..].try_into().expect("eight bytes");
        let bits = match edit[1] % 4 {
            0 => u64::from_le_bytes(raw),
            1 => INTERESTING[usize::from(raw[0]) % INTERESTING.len()].to_bits(),
            // Small integers, for the integer fields.
            2 => u64::from(raw[0]),
            // An integer as a float, for coordinates and heights of every size.
            _ => (i64::from_le_bytes(raw) as f64).to_bits(),
        };
        // A value that does not fit its field, or a header that cannot be rewritten: the
        // edit is skipped.
        if let Ok(c) = craft_header(&b, field, bits) {
            b = c;
        }
    }
    let Ok(repo) = Repository::from_bytes(b) else {
        return false;
    };
    assert_usable(&repo);
    let _ = repo.check_all();
    decode_whole(&repo);
    true
}

/// Every value a reader derives from the header is finite and within [`MAX_MAGNITUDE`].
fn assert_usable(repo: &Repository) {
    let within = |v: f64| v.is_finite() && v.abs() <= MAX_MAGNITUDE;
    let plan = repo.head().plan();
    for h in [-MAX_ABS_HEIGHT, 0, MAX_ABS_HEIGHT] {
        assert!(within(plan.metres(h)), "height {h} is {} m", plan.metres(h));
    }
    assert!(plan.max_error().is_finite(), "{plan:?}");
    if let Some(g) = repo.head().georef() {
        let (ex, ey) = repo.head().params().layout().face_extent();
        for (o, p, e) in [(g.origin_x, g.pixel_x, ex), (g.origin_y, g.pixel_y, ey)] {
            for i in [-1.0, 0.0, e as f64] {
                assert!(within(o + p * i), "{g:?}");
            }
        }
    }
}

/// Decodes the whole hierarchy (errors are fine, panics are not).
fn decode_whole(repo: &Repository) {
    let Ok(enc) = repo.to_encoded() else {
        return;
    };
    match repo.head().params().kind {
        RepoKind::Elevation => {
            let _ = walk_all_with_validity(&enc, |_, _, _| {});
        }
        RepoKind::Colour => {
            let _ = reconstruct_rgb(&enc);
        }
    }
}
