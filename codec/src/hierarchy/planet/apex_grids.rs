//! The grids of a planet apex's diamonds, which the blocks read to measure the apex diamonds'
//! object errors on their own tiles: past [`IN_MEMORY_BYTES`], written to an unlinked
//! temporary file as the apex encodes them, and read back one at a time by the blocks that
//! need them, so that the memory of a planet build does not grow with its apex (over the land,
//! the apex grows with the land). A small apex stays in memory (no temporary to fill a disk).
//!
//! The file is written through `write` (a full disk is an error naming the temporary, never a
//! fault of a mapping) and read with positioned reads.

use std::collections::HashMap;
use std::fmt;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::sync::{Arc, Mutex};

use crate::CodecError;
use crate::geometry::DiamondId;
use crate::temp::TempStorage;

/// What the temporary file holds, for its errors.
const WHAT: &str = "the planet apex's grids";

/// Bytes of grids kept in memory before they go to a temporary file.
pub const IN_MEMORY_BYTES: usize = 16 << 20;

/// Where the grids' bytes are: in memory, or (past [`IN_MEMORY_BYTES`]) in a temporary file
/// and how many bytes it holds.
enum Store {
    Memory(Vec<u8>),
    File(BufWriter<File>, u64),
}

/// Apex grids being written ([`GridSpill::put`]), from any thread.
pub(super) struct GridSpill {
    store: Mutex<Store>,
    values: usize,
}

impl GridSpill {
    /// A spill of grids of `values` heights each.
    pub(super) fn new(values: usize) -> Self {
        Self {
            store: Mutex::new(Store::Memory(Vec::new())),
            values,
        }
    }

    /// Appends `grid`: where it went.
    pub(super) fn put(&self, grid: &[i32]) -> Result<u64, CodecError> {
        debug_assert_eq!(grid.len(), self.values);
        let bytes: Vec<u8> = grid.iter().flat_map(|v| v.to_le_bytes()).collect();
        let mut store = self.store.lock().expect("the apex grids");
        if let Store::Memory(held) = &mut *store {
            if held.len() + bytes.len() <= IN_MEMORY_BYTES {
                held.extend_from_slice(&bytes);
                return Ok((held.len() - bytes.len()) as u64);
            }
            let file = TempStorage::File(None)
                .unlinked_file(WHAT)?
                .expect("a file storage makes a file");
            let mut file = BufWriter::with_capacity(1 << 20, file);
            file.write_all(held).map_err(writing)?;
            let len = held.len() as u64;
            *store = Store::File(file, len);
        }
        let Store::File(file, len) = &mut *store else {
            unreachable!("spilled above")
        };
        let at = *len;
        file.write_all(&bytes).map_err(writing)?;
        *len += bytes.len() as u64;
        Ok(at)
    }

    /// The grids written, by diamond (`index`: where [`GridSpill::put`] put each).
    pub(super) fn finish(self, index: HashMap<DiamondId, u64>) -> Result<ApexGrids, CodecError> {
        let bytes = match self.store.into_inner().expect("the apex grids") {
            Store::Memory(held) => Bytes::Memory(Arc::new(held)),
            Store::File(writer, _) => Bytes::File(Arc::new(
                writer.into_inner().map_err(|e| writing(e.into_error()))?,
            )),
        };
        Ok(ApexGrids {
            bytes,
            index,
            values: self.values,
        })
    }
}

/// The grids' bytes, in memory or in a temporary file.
#[derive(Clone)]
enum Bytes {
    Memory(Arc<Vec<u8>>),
    File(Arc<File>),
}

/// The error of writing the temporary file.
fn writing(e: std::io::Error) -> CodecError {
    CodecError::Io(std::io::Error::new(
        e.kind(),
        format!("writing a temporary file for {WHAT}: {e}"),
    ))
}

/// Every stored apex diamond's grid, in a temporary file ([`GridSpill`]).
#[derive(Clone)]
pub struct ApexGrids {
    bytes: Bytes,
    index: HashMap<DiamondId, u64>,
    values: usize,
}

/// Reads `bytes.len()` bytes of `file` at `at`: a positioned read on Unix (the blocks read in
/// parallel, with no shared cursor); elsewhere (where no planet is built today, e.g. the browser
/// build of this crate) a seek and a read, one reader at a time.
fn read_at(file: &File, bytes: &mut [u8], at: u64) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileExt;
        file.read_exact_at(bytes, at)
    }
    #[cfg(not(unix))]
    {
        use std::io::{Read, Seek, SeekFrom};
        static CURSOR: Mutex<()> = Mutex::new(());
        let _one_reader = CURSOR.lock().unwrap_or_else(|e| e.into_inner());
        let mut file = file;
        file.seek(SeekFrom::Start(at))?;
        file.read_exact(bytes)
    }
}

impl ApexGrids {
    /// The grids `grids` (each of `values` heights), written to a temporary file.
    pub fn from_grids(
        values: usize,
        grids: impl IntoIterator<Item = (DiamondId, Vec<i32>)>,
    ) -> Result<Self, CodecError> {
        let spill = GridSpill::new(values);
        let mut index = HashMap::new();
        for (id, grid) in grids {
            if grid.len() != values {
                return Err(CodecError::invalid(format!(
                    "apex diamond {id}: a grid of {} heights, not {values}",
                    grid.len()
                )));
            }
            index.insert(id, spill.put(&grid)?);
        }
        spill.finish(index)
    }

    /// The diamonds whose grids are held, in no particular order.
    pub fn ids(&self) -> impl Iterator<Item = DiamondId> + '_ {
        self.index.keys().copied()
    }

    /// How many grids are held.
    pub fn len(&self) -> usize {
        self.index.len()
    }

    /// Whether none is.
    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }

    /// Diamond `id`'s grid, read back; `None` if it is not an apex diamond.
    pub fn get(&self, id: DiamondId) -> Result<Option<Vec<i32>>, CodecError> {
        let Some(&at) = self.index.get(&id) else {
            return Ok(None);
        };
        let mut bytes = vec![0u8; self.values * 4];
        match &self.bytes {
            Bytes::Memory(held) => {
                bytes.copy_from_slice(&held[at as usize..at as usize + self.values * 4]);
            }
            Bytes::File(file) => read_at(file, &mut bytes, at).map_err(|e| {
                CodecError::Io(std::io::Error::new(
                    e.kind(),
                    format!("reading a temporary file for {WHAT}: {e}"),
                ))
            })?,
        }
        Ok(Some(
            bytes
                .chunks_exact(4)
                .map(|b| i32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect(),
        ))
    }
}

impl fmt::Debug for ApexGrids {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "ApexGrids({} grids of {} heights)",
            self.len(),
            self.values
        )
    }
}

impl PartialEq for ApexGrids {
    /// The same diamonds with the same grids (every grid read back).
    fn eq(&self, other: &Self) -> bool {
        self.values == other.values
            && self.len() == other.len()
            && self
                .ids()
                .all(|id| matches!((self.get(id), other.get(id)), (Ok(a), Ok(b)) if a == b))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Grids written from several threads read back as written, each by its diamond: held in
    /// memory, and spilled to a file past [`IN_MEMORY_BYTES`] (200 grids of a 64th of it).
    #[test]
    fn grids_read_back_as_written() {
        const V: usize = IN_MEMORY_BYTES / 4 / 64;
        let grid = |i: u32| {
            (0..V as i32)
                .map(|v| v * 1000 - i as i32 * 7)
                .collect::<Vec<i32>>()
        };
        let spill = GridSpill::new(V);
        let index: HashMap<DiamondId, u64> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..4u32)
                .map(|t| {
                    let spill = &spill;
                    s.spawn(move || {
                        (0..50u32)
                            .map(|i| {
                                let i = t * 50 + i;
                                (DiamondId::new(3, i, i + 1), spill.put(&grid(i)).unwrap())
                            })
                            .collect::<Vec<_>>()
                    })
                })
                .collect();
            handles
                .into_iter()
                .flat_map(|h| h.join().unwrap())
                .collect()
        });
        let grids = spill.finish(index).unwrap();
        assert!(matches!(grids.bytes, Bytes::File(_)), "not spilled");
        assert_eq!(grids.len(), 200);
        for i in 0..200u32 {
            assert_eq!(
                grids.get(DiamondId::new(3, i, i + 1)).unwrap(),
                Some(grid(i))
            );
        }
        assert_eq!(grids.get(DiamondId::new(3, 0, 0)).unwrap(), None);
        let few = (0..20u32).map(|i| (DiamondId::new(3, i, i + 1), grid(i)));
        let held = ApexGrids::from_grids(V, few).unwrap();
        assert!(matches!(held.bytes, Bytes::Memory(_)), "spilled");
        for i in 0..20u32 {
            assert_eq!(
                held.get(DiamondId::new(3, i, i + 1)).unwrap(),
                Some(grid(i))
            );
        }
        let all = (0..200u32).map(|i| (DiamondId::new(3, i, i + 1), grid(i)));
        assert_eq!(ApexGrids::from_grids(V, all).unwrap(), grids);
        let e = ApexGrids::from_grids(V, [(DiamondId::new(3, 0, 0), vec![0; 8])]).unwrap_err();
        assert!(
            e.to_string().contains(&format!("8 heights, not {V}")),
            "{e}"
        );
    }
}
