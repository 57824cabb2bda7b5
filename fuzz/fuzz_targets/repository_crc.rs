//! Hostile repository files whose checksums are made to match, so the fuzzer explores what lies
//! behind them — the index, root field, nodata masks and records of a file that opens — instead
//! of stopping at the header CRC as `repository` mostly does. Checksums guard against damage in
//! transit or storage, not against a hostile writer: a file with consistent CRCs must still give a
//! clean error or a valid hierarchy, never a panic, an overflow or an out-of-range height.
//!
//! The input is a repository file; before parsing, the section CRCs and the header CRC are
//! recomputed over whatever bytes the header points at, and when the head then parses, every
//! record's slot in the checksum table too (`reseal_checksums`, any format version). Seed with small real repositories (see
//! `fuzz/seeds/repository_crc/README.md`; run with `cargo +nightly fuzz run repository_crc corpus/repository_crc seeds/repository_crc`).
//!
//! The checks live in `cbdam_codec::repository::hostile::resealed`, which the stable test
//! `codec/tests/hostile_inputs.rs` (run by CI) also puts through the seeds and their mutants.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = cbdam_codec::repository::hostile::resealed(data);
});
