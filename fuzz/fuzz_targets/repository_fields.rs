//! Hostile header *fields* with matching checksums: the crafted-but-checksummed header space.
//! `repository_crc` mutates bytes and reseals the checksums, so most of its inputs fail at
//! the header's structure (a varint, a length); this target edits the fields themselves — a
//! unit of 1e308, an origin past any planet, a NaN tolerance, a flag combination — through
//! `craft_header`, which rewrites the header and recomputes every CRC. Whatever then opens must
//! hold only values a reader can use: every height a record can reconstruct and every
//! georeferenced coordinate of the lattice finite and within `MAX_MAGNITUDE`, and the hierarchy
//! must decode without a panic.
//!
//! Input: one byte `e`, then `e % 5` edits of ten bytes each (field selector, value kind, eight
//! value bytes), then a repository file of format version 3. An input that starts with the
//! repository magic is a repository without edits, so the `repository_crc` seeds serve as they
//! are: `cargo +nightly fuzz run repository_fields corpus/repository_fields seeds/repository_crc`.
#![no_main]

use cbdam_codec::colour::reconstruct_rgb;
use cbdam_codec::hierarchy::{RepoKind, walk_all_with_validity};
use cbdam_codec::lifting::MAX_ABS_HEIGHT;
use cbdam_codec::repository::{CRAFTABLE_FIELDS, MAGIC, MAX_MAGNITUDE, Repository, craft_header};
use libfuzzer_sys::fuzz_target;

/// Floats that break arithmetic that trusts its inputs.
const INTERESTING: &[f64] = &[
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

const EDIT: usize = 10;

fuzz_target!(|data: &[u8]| {
    let (edits, file) = if data.starts_with(&MAGIC) {
        (&[][..], data)
    } else {
        let Some((&e, rest)) = data.split_first() else {
            return;
        };
        let n = usize::from(e % 5) * EDIT;
        if rest.len() < n {
            return;
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
        return;
    };
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
    let _ = repo.check_all();
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
});
