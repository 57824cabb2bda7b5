//! Hostile repository files into `Repository::from_bytes`: never a panic; whatever opens must
//! survive reading every record, building a decoder and decoding the whole hierarchy.
//!
//! Seed the corpus with real repositories (`cbdam build … -o corpus/repository/x.cbdam`) so
//! the fuzzer starts past the header checksum.
#![no_main]

use cbdam_codec::hierarchy::walk;
use cbdam_codec::repository::Repository;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(repo) = Repository::from_bytes(data.to_vec()) else {
        return;
    };
    let _ = repo.check_all();
    for i in 0..repo.entries().len() {
        let _ = repo.record_at(i);
    }
    let _ = repo.decoder();
    if let Ok(enc) = repo.to_encoded() {
        let _ = walk(&enc, |_, _| {});
    }
});
