//! Hostile repository files into `Repository::from_bytes` and, as a remote client sees them, into
//! `required_head_len` + `RepositoryHead::parse` on a prefix: never a panic; whatever opens must
//! survive reading every record, building a decoder and decoding the whole hierarchy.
//!
//! Seed the corpus with real repositories (`cbdam build … -o corpus/repository/x.cbdam`) so
//! the fuzzer starts past the header checksum.
#![no_main]

use cbdam_codec::hierarchy::walk;
use cbdam_codec::repository::{Repository, RepositoryHead, required_head_len};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(len) = required_head_len(data) {
        let prefix = &data[..(len.min(data.len() as u64)) as usize];
        if let Ok(head) = RepositoryHead::parse(prefix, data.len() as u64) {
            for i in 0..head.entries().len() {
                if let Some(r) = head.record_range(i) {
                    let _ = head.check_record(i, data.get(r.start as usize..r.end as usize).unwrap_or(&[]));
                }
            }
            let _ = head.decoder();
        }
    }
    let Ok(repo) = Repository::from_bytes(data.to_vec()) else {
        return;
    };
    let _ = repo.check_all();
    for i in 0..repo.head().entries().len() {
        let _ = repo.record_at(i);
    }
    let _ = repo.head().decoder();
    if let Ok(enc) = repo.to_encoded() {
        let _ = walk(&enc, |_, _| {});
    }
});
