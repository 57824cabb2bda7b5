//! The grids of the apex diamonds a planet's block-wise verifier hands on to a reconstruction
//! of the finest level ([`ApexFinest`]): the visited diamonds of the finest level's parity above
//! the cut, spilled ([`super::spill`]) so that the verifier's memory does not grow with its apex.

use super::apex_grids::IN_MEMORY_BYTES;
use super::spill::{Spill, Spilled};
use crate::CodecError;
use crate::geometry::DiamondId;
use crate::hierarchy::decode::Visit;

/// What is handed each diamond a reconstruction writes: its id, grid and validity (`None`: all
/// valid).
pub type FinestVisit<'f> = dyn FnMut(DiamondId, &[i32], Option<&[bool]>) + 'f;

/// Where a grid of [`ApexFinest`] lies in its spill: the diamond, the offset, the grid's values
/// and whether a validity follows them.
type FinestEntry = (DiamondId, u64, usize, bool);

/// The grids (with their validity) of the apex diamonds a planet's verifier hands on to a
/// reconstruction of the finest level, spilled as the apex walk visits them, in id order, and
/// read back a block's at a time ([`ApexFinest::visit`]).
pub(super) struct ApexFinest {
    spill: Option<Spill>,
    bytes: Option<Spilled>,
    /// Per level, in id order.
    index: Vec<Vec<FinestEntry>>,
}

impl ApexFinest {
    /// Nothing written yet, for grids of side `n`.
    pub(super) fn new(n: usize) -> Self {
        let in_memory = IN_MEMORY_BYTES.max(n * n * 5);
        Self {
            spill: Some(Spill::new(
                "the planet apex's grids being verified",
                in_memory,
            )),
            bytes: None,
            index: Vec::new(),
        }
    }

    /// Appends the grids of `batch` (each after those of the diamonds before it in id order).
    pub(super) fn put_all(&mut self, batch: &[Visit<'_>]) -> Result<(), CodecError> {
        let spill = self.spill.as_ref().expect("grids are put before finish");
        let mut bytes = Vec::new();
        for v in batch {
            bytes.clear();
            bytes.extend(v.grid.iter().flat_map(|h| h.to_le_bytes()));
            if let Some(valid) = v.valid {
                bytes.extend(valid.iter().map(|&b| u8::from(b)));
            }
            let at = spill.put(&bytes)?;
            let level = usize::from(v.id.level);
            if self.index.len() <= level {
                self.index.resize_with(level + 1, Vec::new);
            }
            self.index[level].push((v.id, at, v.grid.len(), v.valid.is_some()));
        }
        Ok(())
    }

    /// Every grid written, to be read back.
    pub(super) fn finish(mut self) -> Result<Self, CodecError> {
        self.bytes = self.spill.take().map(Spill::finish).transpose()?;
        Ok(self)
    }

    /// Hands `visit`, level by level in id order, the diamonds of `face` with centres in columns
    /// `xs` (widened by each level's `radius`) that `keep` takes, with their grids and validity.
    pub(super) fn visit(
        &self,
        (face, xs): (u8, (i64, i64)),
        radius: &dyn Fn(u8) -> i64,
        keep: &dyn Fn(&DiamondId) -> bool,
        visit: &mut FinestVisit<'_>,
    ) -> Result<(), CodecError> {
        let Some(bytes) = &self.bytes else {
            return Ok(());
        };
        let (mut buf, mut grid, mut valid) = (Vec::new(), Vec::new(), Vec::new());
        for (level, entries) in self.index.iter().enumerate() {
            let r = radius(level as u8);
            let at = |e: &FinestEntry| (e.0.face, i64::from(e.0.x));
            let a = entries.partition_point(|e| at(e) < (face, xs.0 - r));
            let b = entries.partition_point(|e| at(e) <= (face, xs.1 + r));
            for &(id, offset, len, has_validity) in entries[a..b].iter().filter(|e| keep(&e.0)) {
                buf.resize(len * 4 + if has_validity { len } else { 0 }, 0);
                bytes.read(offset, &mut buf)?;
                let (values, validity) = buf.split_at(len * 4);
                grid.clear();
                grid.extend(
                    values
                        .chunks_exact(4)
                        .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]])),
                );
                valid.clear();
                valid.extend(validity.iter().map(|&b| b != 0));
                visit(id, &grid, has_validity.then_some(&valid[..]));
            }
        }
        Ok(())
    }
}
