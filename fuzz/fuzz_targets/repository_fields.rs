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
//!
//! The checks live in `cbdam_codec::repository::hostile::crafted_fields`, which the stable test
//! `codec/tests/hostile_inputs.rs` (run by CI) also puts through the seeds and their mutants.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = cbdam_codec::repository::hostile::crafted_fields(data);
});
