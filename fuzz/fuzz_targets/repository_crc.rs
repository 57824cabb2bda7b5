//! Hostile repository files whose checksums are made to match, so the fuzzer explores what lies
//! behind them — the index, root field, nodata masks and records of a file that opens — instead
//! of stopping at the header CRC as `repository` mostly does. Checksums guard against damage in
//! transit or storage, not against a hostile writer: a file with consistent CRCs must still give a
//! clean error or a valid hierarchy, never a panic, an overflow or an out-of-range height.
//!
//! The input is a repository file; before parsing, the section CRCs and the header CRC are
//! recomputed over whatever bytes the section table points at, and when the head then parses,
//! every record's slot in the checksum table too. Seed with small real repositories (see
//! `fuzz/seeds/repository_crc/README.md`; run with `cargo +nightly fuzz run repository_crc corpus/repository_crc seeds/repository_crc`).
#![no_main]

use cbdam_codec::colour::reconstruct_rgb;
use cbdam_codec::hierarchy::{RepoKind, walk_all_with_validity};
use cbdam_codec::repository::{Repository, RepositoryHead};
use libfuzzer_sys::fuzz_target;

/// Header layout (docs/FORMAT.md): the section table at 128, four entries of
/// `u64 offset, u64 length, u32 crc, u32 reserved`, the header CRC at 252 over bytes 0..252.
const HEADER_LEN: usize = 256;
const SECTIONS: usize = 128;
const CHECKSUMS: usize = 2;

fn section(b: &[u8], s: usize) -> Option<std::ops::Range<usize>> {
    let e = SECTIONS + 24 * s;
    let off = u64::from_le_bytes(b[e..e + 8].try_into().unwrap());
    let len = u64::from_le_bytes(b[e + 8..e + 16].try_into().unwrap());
    let end = off.checked_add(len)?;
    (end <= b.len() as u64).then(|| off as usize..end as usize)
}

fn fix_sections_and_header(b: &mut [u8]) {
    for s in 0..4 {
        if let Some(r) = section(b, s) {
            let crc = crc32fast::hash(&b[r]);
            let e = SECTIONS + 24 * s + 16;
            b[e..e + 4].copy_from_slice(&crc.to_le_bytes());
        }
    }
    let crc = crc32fast::hash(&b[..HEADER_LEN - 4]);
    b[HEADER_LEN - 4..HEADER_LEN].copy_from_slice(&crc.to_le_bytes());
}

fuzz_target!(|data: &[u8]| {
    if data.len() < HEADER_LEN {
        return;
    }
    let mut b = data.to_vec();
    fix_sections_and_header(&mut b);
    // Record CRCs: the slots of non-empty records, in id order, once the head parses.
    if let (Ok(head), Some(table)) = (
        RepositoryHead::parse(&b, b.len() as u64),
        section(&b, CHECKSUMS),
    ) {
        let mut slot = 0;
        for i in 0..head.entries().len() {
            let Some(r) = head.record_range(i) else { continue };
            if r.start == r.end {
                continue;
            }
            let at = table.start + 4 * slot;
            slot += 1;
            if at + 4 > table.end || r.end > b.len() as u64 {
                break;
            }
            let crc = crc32fast::hash(&b[r.start as usize..r.end as usize]);
            b[at..at + 4].copy_from_slice(&crc.to_le_bytes());
        }
        fix_sections_and_header(&mut b);
    }
    let Ok(repo) = Repository::from_bytes(b) else {
        return;
    };
    let _ = repo.check_all();
    let Ok(enc) = repo.to_encoded() else {
        return;
    };
    match repo.params().kind {
        RepoKind::Elevation => {
            let _ = walk_all_with_validity(&enc, |_, _, _| {});
        }
        RepoKind::Colour => {
            let _ = reconstruct_rgb(&enc);
        }
    }
});
