//! The fuzz targets `repository_crc` and `repository_fields` on the stable toolchain: their
//! checks (`cbdam_codec::repository::hostile`) through the seed repositories of
//! `fuzz/seeds/repository_crc` and deterministic mutants of them — bytes changed with every
//! checksum recomputed, header fields set to absurd values with every checksum recomputed. CI
//! cannot run libFuzzer; this puts the crafted-but-checksummed space through the reader on
//! every run. A finding panics inside the checks.

use std::path::PathBuf;

use cbdam_codec::repository::hostile::{EDIT, INTERESTING, crafted_fields, resealed};
use cbdam_codec::repository::{CRAFTABLE_FIELDS, Repository};

/// The seed repositories, each opened as it is (they must be valid, or the test tests nothing).
fn seeds() -> Vec<(String, Vec<u8>)> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../fuzz/seeds/repository_crc");
    let mut out: Vec<(String, Vec<u8>)> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "cbdam"))
        .map(|p| (p.display().to_string(), std::fs::read(&p).unwrap()))
        .collect();
    out.sort();
    assert!(out.len() >= 5, "{} seeds in {}", out.len(), dir.display());
    for (name, bytes) in &out {
        Repository::from_bytes(bytes.clone()).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
    out
}

/// SplitMix64: deterministic mutants.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

/// How many of a run's inputs opened and how many were refused.
#[derive(Default, Debug)]
struct Tally {
    opened: usize,
    refused: usize,
}

impl Tally {
    fn add(&mut self, opened: bool) {
        if opened {
            self.opened += 1;
        } else {
            self.refused += 1;
        }
    }

    /// Both outcomes happened: the checks behind a successful open were reached, and the
    /// mutants were not all harmless.
    fn assert_both(&self, what: &str) {
        eprintln!("{what}: {self:?}");
        assert!(self.opened > 0 && self.refused > 0, "{what}: {self:?}");
    }
}

#[test]
fn resealed_mutants_of_every_seed_open_cleanly_or_are_refused() {
    let mut rng = Rng(0xC8C);
    let mut tally = Tally::default();
    for (_, seed) in seeds() {
        tally.add(resealed(&seed));
        for _ in 0..400 {
            let mut b = seed.clone();
            // One to four bytes changed, most in the head (the first 256 bytes), then resealed.
            for _ in 0..1 + rng.below(4) {
                let at = if rng.below(4) == 0 {
                    rng.below(b.len())
                } else {
                    rng.below(b.len().min(256))
                };
                b[at] = match rng.below(3) {
                    0 => rng.next() as u8,
                    1 => b[at] ^ (1 << rng.below(8)),
                    _ => [0, 1, 0x7F, 0x80, 0xFF][rng.below(5)],
                };
            }
            // Sometimes cut short or lengthened.
            match rng.below(8) {
                0 => b.truncate(rng.below(b.len())),
                1 => b.extend((0..rng.below(64)).map(|_| rng.next() as u8)),
                _ => {}
            }
            tally.add(resealed(&b));
        }
    }
    tally.assert_both("resealed mutants");
}

#[test]
fn every_craftable_field_at_every_interesting_value_opens_usable_or_is_refused() {
    let mut tally = Tally::default();
    for (_, seed) in seeds() {
        for f in 0..CRAFTABLE_FIELDS.len() {
            for (k, _) in INTERESTING.iter().enumerate() {
                // One edit: field f, kind 1 (an interesting value), value k.
                let mut input = vec![1u8, f as u8, 1, k as u8];
                input.resize(1 + EDIT, 0);
                input.extend_from_slice(&seed);
                tally.add(crafted_fields(&input));
            }
        }
    }
    tally.assert_both("one field at an interesting value");
}

#[test]
fn random_field_edits_of_every_seed_open_usable_or_are_refused() {
    let mut rng = Rng(0xF1E1D);
    let mut tally = Tally::default();
    for (_, seed) in seeds() {
        for _ in 0..300 {
            let edits = 1 + rng.below(4);
            let mut input = vec![edits as u8];
            for _ in 0..edits * EDIT {
                input.push(rng.next() as u8);
            }
            input.extend_from_slice(&seed);
            tally.add(crafted_fields(&input));
        }
    }
    tally.assert_both("random field edits");
}
