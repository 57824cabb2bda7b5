//! Helpers shared by the integration tests.

use std::collections::{HashMap, HashSet};
use std::sync::Mutex;

use cbdam_codec::CodecError;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::Encoded;

/// SplitMix64: deterministic, so a failure reproduces from its seed alone, and fine from any
/// seed (zero included).
pub struct Rng(pub u64);

impl Rng {
    /// The next 64 random bits.
    pub fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`.
    pub fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in `0..n` (n > 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

/// The records of one encoding as a windowed decode reads them (`decode_window`,
/// `decode_face_windows`): by id, each read noted, so that a test checks the decode read
/// exactly the records its window named.
pub struct CountedReads<'a> {
    /// Every stored diamond, as a repository's index lists them.
    pub stored: Vec<DiamondId>,
    bytes: HashMap<DiamondId, &'a [u8]>,
    asked: Mutex<HashSet<DiamondId>>,
}

impl<'a> CountedReads<'a> {
    pub fn new(enc: &'a Encoded) -> Self {
        CountedReads {
            stored: enc.records.iter().map(|r| r.id).collect(),
            bytes: enc.records.iter().map(|r| (r.id, &r.bytes[..])).collect(),
            asked: Mutex::new(HashSet::new()),
        }
    }

    /// The bytes of record `id`, noted as read.
    pub fn read(&self, id: DiamondId) -> Result<&'a [u8], CodecError> {
        self.asked.lock().unwrap().insert(id);
        Ok(self.bytes[&id])
    }

    /// Fails unless the records read since the last check are exactly `needed` (what the window
    /// named); forgets them, and returns whether `needed` is fewer than every stored record.
    pub fn check_read_exactly(&self, needed: Vec<DiamondId>) -> bool {
        let needed: HashSet<DiamondId> = needed.into_iter().collect();
        let asked = std::mem::take(&mut *self.asked.lock().unwrap());
        assert!(asked.is_subset(&needed), "read a record it did not name");
        assert_eq!(asked.len(), needed.len(), "named a record it did not read");
        needed.len() < self.stored.len()
    }
}
