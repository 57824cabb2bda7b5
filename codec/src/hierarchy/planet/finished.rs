//! What a block-wise planet encode keeps of its finished records until every block is in
//! ([`FinishedRecords`]), in a few bytes a diamond.
//!
//! The records come block by block, in no id order, and the repository wants them in id order
//! with each one's object error saturated over its descendants, which only the last block
//! completes. A planet of land tiles has millions of records, so what is kept for each diamond
//! counts: whole [`Record`]s (56 bytes) in a vector grown by doubling, the places of their bytes
//! beside them (16) and every own error in a hash map (17 bytes a slot, up to twice as many
//! slots as diamonds) grew with the records, and no memory plan counted them (the Earth's
//! figures: docs/RESULTS.md, "What a planet keeps for each diamond…"). Here the own
//! errors sit in one array per level, aligned with the level's stored diamonds (4 bytes and a
//! bit a diamond, allocated once), and each record keeps its id, height range and the place of
//! its bytes (32 bytes, reserved once for the recorded diamonds' count); the bytes themselves
//! wait in a temporary file ([`RecordSpill`]), or in one buffer for a small planet.

use std::sync::Arc;

use rayon::prelude::*;

use crate::CodecError;
use crate::geometry::{DiamondId, Domain};
use crate::hierarchy::Record;
use crate::hierarchy::field::TempStorage;
use crate::hierarchy::record_bytes::{RecordBytes, RecordSpill};

/// Bytes `FinishedRecords` keeps for each stored diamond (its own error and whether a block
/// measured it) and each recorded one (its `Kept`), for a memory plan.
pub const BYTES_PER_STORED: u64 = 5;
/// See [`BYTES_PER_STORED`].
pub const BYTES_PER_RECORD: u64 = std::mem::size_of::<Kept>() as u64;

/// A finished record without its bytes.
#[derive(Clone, Copy)]
struct Kept {
    id: DiamondId,
    min: i32,
    max: i32,
    len: u32,
    /// Where its bytes start in the spill file or the buffer.
    start: u64,
}

/// Where the records' bytes wait.
enum Bytes {
    Spilled(RecordSpill),
    Held(Vec<u8>),
}

/// The finished records of a block-wise planet encode and the own errors of its stored
/// diamonds (see the module documentation).
pub(super) struct FinishedRecords<'s> {
    stored: &'s [Vec<DiamondId>],
    /// Per level, the largest own error measured so far of each stored diamond.
    own_error: Vec<Vec<u32>>,
    /// Per level, one bit per stored diamond: whether some block (or the apex) measured it.
    measured: Vec<Vec<u64>>,
    records: Vec<Kept>,
    bytes: Bytes,
}

impl<'s> FinishedRecords<'s> {
    /// Room for the records of `recorded` diamonds of a planet storing `stored`; `spill`: their
    /// bytes wait in a temporary file.
    pub(super) fn new(
        stored: &'s [Vec<DiamondId>],
        recorded: usize,
        spill: bool,
    ) -> Result<Self, CodecError> {
        let spilled = match spill {
            true => RecordSpill::new(&TempStorage::File(None))?,
            false => None,
        };
        let mut records = Vec::new();
        records.try_reserve_exact(recorded).map_err(|_| {
            CodecError::limit(format!("memory for the places of {recorded} records"))
        })?;
        Ok(Self {
            stored,
            own_error: stored.iter().map(|s| vec![0; s.len()]).collect(),
            measured: stored
                .iter()
                .map(|s| vec![0; s.len().div_ceil(64)])
                .collect(),
            records,
            bytes: spilled.map_or_else(|| Bytes::Held(Vec::new()), Bytes::Spilled),
        })
    }

    /// Keeps `records` (object errors are set by [`Self::finish`]).
    pub(super) fn keep(&mut self, records: &[Record]) -> Result<(), CodecError> {
        for r in records {
            let start = match &mut self.bytes {
                Bytes::Spilled(spill) => spill.append(&r.bytes)?,
                Bytes::Held(held) => {
                    held.extend_from_slice(&r.bytes);
                    held.len() - r.bytes.len()
                }
            };
            let len = u32::try_from(r.bytes.len())
                .map_err(|_| CodecError::limit(format!("the record of {} is over 4 GiB", r.id)))?;
            self.records.push(Kept {
                id: r.id,
                min: r.min,
                max: r.max,
                len,
                start: start as u64,
            });
        }
        Ok(())
    }

    /// Raises `id`'s own error to at least `error` and marks it measured; an id that is not
    /// stored is not kept (nothing reads it).
    pub(super) fn measure(&mut self, id: DiamondId, error: u32) {
        let level = usize::from(id.level);
        let Some(Ok(i)) = self.stored.get(level).map(|s| s.binary_search(&id)) else {
            return;
        };
        let own = &mut self.own_error[level][i];
        let bits = &mut self.measured[level][i / 64];
        *own = if *bits >> (i % 64) & 1 == 1 {
            (*own).max(error)
        } else {
            error
        };
        *bits |= 1 << (i % 64);
    }

    /// Every record with its bytes and its object error saturated over its stored descendants
    /// ([`crate::hierarchy::encode::saturate_errors`]), in id order, and the finest level's
    /// largest own error. Errors for a stored diamond no block measured, and a diamond recorded
    /// twice.
    pub(super) fn finish(mut self, domain: &Domain) -> Result<(Vec<Record>, u32), CodecError> {
        self.check_measured()?;
        let finest = domain.finest_level();
        let leaf_error = self.own_error[usize::from(finest)]
            .iter()
            .copied()
            .max()
            .unwrap_or(0);
        self.saturate(domain);
        self.records.par_sort_unstable_by_key(|k| k.id);
        if let Some(w) = self.records.windows(2).find(|w| w[0].id == w[1].id) {
            return Err(CodecError::invalid(format!(
                "diamond {} was recorded by two blocks",
                w[0].id
            )));
        }
        let bytes = match self.bytes {
            Bytes::Spilled(spill) => spill.into_map()?.map(Place::Mapped),
            Bytes::Held(held) => Some(Place::Held(held)),
        };
        let (stored, own_error) = (self.stored, &self.own_error);
        let records = self
            .records
            .par_iter()
            .map(|k| {
                let object_error = error_of(stored, own_error, k.id).ok_or_else(|| {
                    CodecError::invalid(format!("diamond {} has a record but is not stored", k.id))
                })?;
                Ok(Record {
                    id: k.id,
                    bytes: bytes
                        .as_ref()
                        .map_or_else(RecordBytes::default, |b| b.bytes(k)),
                    object_error,
                    min: k.min,
                    max: k.max,
                })
            })
            .collect::<Result<Vec<_>, CodecError>>()?;
        Ok((records, leaf_error))
    }

    /// Errors naming the first stored diamond that no block measured.
    fn check_measured(&self) -> Result<(), CodecError> {
        for (ids, bits) in self.stored.iter().zip(&self.measured) {
            if let Some(i) = (0..ids.len()).find(|&i| bits[i / 64] >> (i % 64) & 1 == 0) {
                return Err(CodecError::invalid(format!(
                    "diamond {} is in no block: the planet's tiles do not cover its centre",
                    ids[i]
                )));
            }
        }
        Ok(())
    }

    /// Turns each own error into the largest over the diamond and its stored descendants, fine
    /// to coarse (a level reads the one below it, already saturated).
    fn saturate(&mut self, domain: &Domain) {
        for level in (0..self.own_error.len().saturating_sub(1)).rev() {
            let (coarse, fine) = self.own_error.split_at_mut(level + 1);
            let (fine, fine_ids) = (&fine[0], &self.stored[level + 1]);
            coarse[level]
                .par_iter_mut()
                .zip(&self.stored[level])
                .for_each(|(e, &id)| {
                    for c in domain.children(id).into_iter().flatten() {
                        if let Ok(i) = fine_ids.binary_search(&c) {
                            *e = (*e).max(fine[i]);
                        }
                    }
                });
        }
    }
}

/// The (saturated) error of stored diamond `id`.
fn error_of(stored: &[Vec<DiamondId>], own_error: &[Vec<u32>], id: DiamondId) -> Option<u32> {
    let level = usize::from(id.level);
    let i = stored.get(level)?.binary_search(&id).ok()?;
    Some(own_error[level][i])
}

/// Where the kept records' bytes are once every block is in.
enum Place {
    Mapped(Arc<memmap2::Mmap>),
    Held(Vec<u8>),
}

impl Place {
    fn bytes(&self, k: &Kept) -> RecordBytes {
        let (start, len) = (k.start as usize, k.len as usize);
        match self {
            Place::Mapped(map) => RecordBytes::spilled(map, start, len),
            Place::Held(held) => held[start..start + len].to_vec().into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use super::*;
    use crate::hierarchy::encode::saturate_errors;

    /// A domain, its stored diamonds per level, records, and own errors as blocks measure them.
    type Planet = (
        Domain,
        Vec<Vec<DiamondId>>,
        Vec<Record>,
        Vec<(DiamondId, u32)>,
    );

    /// A small cube-sphere's every diamond stored, each but the finest recorded, with bytes,
    /// heights and own errors from a hash of the id.
    fn planet() -> Planet {
        let domain = Domain::cube_sphere(5, 2).unwrap();
        let stored: Vec<Vec<DiamondId>> = (0..=domain.finest_level())
            .map(|l| {
                let mut ids: Vec<DiamondId> = domain.level(l).collect();
                ids.sort();
                ids
            })
            .collect();
        let hash = |id: DiamondId| {
            (u64::from(id.level) << 48 | u64::from(id.face) << 40 | u64::from(id.x) << 20)
                .wrapping_add(u64::from(id.y))
                .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                >> 40
        };
        let records = stored[..stored.len() - 1]
            .iter()
            .flatten()
            .map(|&id| Record {
                id,
                bytes: (0..hash(id) % 7)
                    .map(|b| (b * 31 + hash(id)) as u8)
                    .collect::<Vec<_>>()
                    .into(),
                object_error: 0,
                min: -(hash(id) as i32 % 100),
                max: hash(id) as i32 % 100,
            })
            .collect();
        // Each diamond measured once, some twice (by two blocks): the larger counts.
        let own = stored
            .iter()
            .flatten()
            .flat_map(|&id| {
                let e = (hash(id) % 1000) as u32;
                let again = (hash(id) % 3 == 0).then_some((id, e / 2));
                std::iter::once((id, e)).chain(again)
            })
            .collect();
        (domain, stored, records, own)
    }

    /// The records in blocks of 5, last block first, the own errors in reverse.
    fn finished<'s>(
        stored: &'s [Vec<DiamondId>],
        records: &[Record],
        own: &[(DiamondId, u32)],
        spill: bool,
    ) -> FinishedRecords<'s> {
        let mut f = FinishedRecords::new(stored, records.len(), spill).unwrap();
        for block in records.chunks(5).rev() {
            f.keep(block).unwrap();
        }
        for &(id, e) in own.iter().rev() {
            f.measure(id, e);
        }
        f
    }

    #[test]
    fn records_come_back_in_id_order_saturated_as_the_whole_encoder_does() {
        let (domain, stored, records, own) = planet();
        let mut own_error: HashMap<DiamondId, u32> = HashMap::new();
        for &(id, e) in &own {
            let max = own_error.entry(id).or_insert(e);
            *max = (*max).max(e);
        }
        let want = saturate_errors(&domain, &stored, records.clone(), &own_error);
        assert!(want.0.iter().any(|r| r.object_error > 0) && want.1 > 0);
        for spill in [false, true] {
            let got = finished(&stored, &records, &own, spill)
                .finish(&domain)
                .unwrap();
            assert_eq!(got, want, "spill {spill}");
        }
    }

    #[test]
    fn a_stored_diamond_no_block_measured_is_named() {
        let (domain, stored, records, mut own) = planet();
        let missing = stored[2][3];
        own.retain(|&(id, _)| id != missing);
        let e = finished(&stored, &records, &own, false)
            .finish(&domain)
            .err()
            .unwrap();
        assert!(
            e.to_string()
                .contains(&format!("diamond {missing} is in no block")),
            "{e}"
        );
    }

    #[test]
    fn a_diamond_recorded_twice_is_named() {
        let (domain, stored, mut records, own) = planet();
        records.push(records[4].clone());
        let e = finished(&stored, &records, &own, true)
            .finish(&domain)
            .err()
            .unwrap();
        let twice = records[4].id;
        assert!(
            e.to_string()
                .contains(&format!("diamond {twice} was recorded by two")),
            "{e}"
        );
    }

    /// The sizes the module documentation and the memory plan ([`BYTES_PER_RECORD`]) state.
    #[test]
    fn a_kept_record_is_32_bytes_where_a_record_is_56() {
        assert_eq!(BYTES_PER_RECORD, 32);
        assert_eq!(std::mem::size_of::<Record>(), 56);
    }
}
