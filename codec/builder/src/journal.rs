//! The build's journal: the finished blocks of a block encode
//! ([`cbdam_codec::hierarchy::BlockPlan`]), kept on disk beside the output so that a build that
//! was killed (SIGKILL, power loss) and run again with the same inputs and arguments continues
//! from its last finished block and writes the same bytes.
//!
//! `OUT.journal/` holds `key` — every input (path, size, CRC-32 of its bytes: not its modification
//! time, which a restored file may carry over from other bytes) and every argument
//! that decides the output, one `name=value` line each — and one `block-NNNNNN` file per finished
//! block, each written to a temporary name and renamed, with a CRC-32 of its contents, so a file
//! is whole or absent after a kill, and a file a power loss cut short is noticed and redone. A journal whose key differs from this build's is removed,
//! and the build says which line changed. The journal goes once the repository is written.

use std::fs;
use std::io::{Read, Seek, SeekFrom, Write};

use rayon::prelude::*;
use std::path::{Path, PathBuf};

use cbdam_codec::CodecError;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::{BlockJournal, BlockOutput, Record};

use crate::error::{Context, Result};

/// Magic bytes of a block file.
const MAGIC: &[u8; 4] = b"CBDJ";
/// Version of the block file layout.
const VERSION: u32 = 1;

/// What opening a journal found.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Resumed {
    /// No journal: a fresh build.
    Fresh,
    /// An earlier run of the same build had finished some blocks.
    Continuing {
        /// Blocks finished whose files are whole: they are kept.
        blocks: usize,
        /// Block files that are not whole (cut short by a power loss, damaged): removed, their
        /// blocks are encoded again.
        damaged: usize,
    },
    /// An earlier run's journal was for other inputs or arguments; it was removed.
    StartedOver {
        /// The first line that differs, `name: old → new`.
        changed: String,
    },
}

/// The journal of one build.
#[derive(Debug)]
pub struct Journal {
    dir: PathBuf,
}

impl Journal {
    /// The journal directory of a build writing `output`.
    pub fn dir_of(output: &Path) -> PathBuf {
        let mut name = output.file_name().unwrap_or_default().to_os_string();
        name.push(".journal");
        output.with_file_name(name)
    }

    /// Opens the journal of a build writing `output` whose bytes depend on `key`, continuing an
    /// earlier run's with the same key and removing one with another.
    pub fn open(output: &Path, key: &str) -> Result<(Journal, Resumed)> {
        let dir = Self::dir_of(output);
        let context = || format!("opening the build journal {}", dir.display());
        let mut resumed = Resumed::Fresh;
        if dir.exists() {
            let old = fs::read_to_string(dir.join("key")).unwrap_or_default();
            if old == key {
                // Every block file is checked now, so that the count of kept blocks is the count
                // the encode will load; one that is not whole is removed and encoded again.
                let names = fs::read_dir(&dir)
                    .with_context(context)?
                    .filter_map(|e| e.ok())
                    .map(|e| e.path())
                    .filter(|p| {
                        p.file_name()
                            .is_some_and(|n| n.to_string_lossy().starts_with("block-"))
                    })
                    .collect::<Vec<_>>();
                let whole = names
                    .par_iter()
                    .map(|p| -> Result<bool> {
                        let whole = fs::read(p)
                            .ok()
                            .is_some_and(|bytes| parse_block(&bytes).is_some());
                        if !whole {
                            fs::remove_file(p)
                                .with_context(|| format!("removing {}", p.display()))?;
                        }
                        Ok(whole)
                    })
                    .collect::<Result<Vec<_>>>()?;
                let blocks = whole.iter().filter(|&&w| w).count();
                let resumed = Resumed::Continuing {
                    blocks,
                    damaged: names.len() - blocks,
                };
                return Ok((Journal { dir }, resumed));
            }
            resumed = Resumed::StartedOver {
                changed: first_difference(&old, key),
            };
            fs::remove_dir_all(&dir).with_context(context)?;
        }
        fs::create_dir_all(&dir).with_context(context)?;
        write_atomically(&dir, "key", key.as_bytes()).with_context(context)?;
        Ok((Journal { dir }, resumed))
    }

    /// The journal in `dir` as it is, created if absent, with no key: for a caller that checks
    /// what the blocks belong to itself (a sharded build's work directory, [`crate::shard`]).
    pub fn in_dir(dir: PathBuf) -> Result<Journal> {
        fs::create_dir_all(&dir)
            .with_context(|| format!("creating the block directory {}", dir.display()))?;
        Ok(Journal { dir })
    }

    /// The path of block `index`'s file.
    pub fn block_path(&self, index: usize) -> PathBuf {
        self.dir.join(format!("block-{index:06}"))
    }

    /// Removes the journal: the repository is written.
    pub fn finish(self) -> Result<()> {
        fs::remove_dir_all(&self.dir)
            .with_context(|| format!("removing the build journal {}", self.dir.display()))
    }
}

impl BlockJournal for Journal {
    fn load(&self, index: usize) -> Result<Option<BlockOutput>, CodecError> {
        match fs::read(self.block_path(index)) {
            // A block file that does not parse (it never should: files are renamed into place
            // whole) is encoded again.
            Ok(bytes) => Ok(parse_block(&bytes)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(e.into()),
        }
    }

    fn save(&self, index: usize, output: &BlockOutput) -> Result<(), CodecError> {
        let name = format!("block-{index:06}");
        // Named, keeping the error's kind (a full disk is told apart: `crate::disk_full`).
        write_atomically(&self.dir, &name, &serialize_block(output)).map_err(|e| {
            let path = self.dir.join(&name);
            std::io::Error::new(e.kind(), format!("writing {}: {e}", path.display()))
        })?;
        Ok(())
    }
}

/// Bytes of an input hashed as one piece: large files are hashed in pieces of this size in
/// parallel and the pieces' CRCs combined.
const HASH_PIECE: u64 = 64 << 20;

/// The length and CRC-32 of the file at `path`'s contents, read in pieces of [`HASH_PIECE`]
/// bytes in parallel (the pieces' CRCs combined in order), each streamed in 1 MiB reads.
pub(crate) fn content_crc(path: &Path) -> Result<(u64, u32)> {
    let context = || format!("reading {} to check the build journal", path.display());
    let len = fs::metadata(path).with_context(context)?.len();
    let pieces = len.div_ceil(HASH_PIECE).max(1);
    let hashers = (0..pieces)
        .into_par_iter()
        .map(|i| -> std::io::Result<crc32fast::Hasher> {
            let mut file = fs::File::open(path)?;
            file.seek(SeekFrom::Start(i * HASH_PIECE))?;
            let mut left = HASH_PIECE.min(len - i * HASH_PIECE);
            let mut hasher = crc32fast::Hasher::new();
            let mut buf = vec![0u8; 1 << 20];
            while left > 0 {
                let want = buf.len().min(left as usize);
                let n = file.read(&mut buf[..want])?;
                if n == 0 {
                    return Err(std::io::Error::new(
                        std::io::ErrorKind::UnexpectedEof,
                        "the file became shorter while it was read",
                    ));
                }
                hasher.update(&buf[..n]);
                left -= n as u64;
            }
            Ok(hasher)
        })
        .collect::<std::io::Result<Vec<_>>>()
        .with_context(context)?;
    let mut whole = crc32fast::Hasher::new();
    for h in &hashers {
        whole.combine(h);
    }
    Ok((len, whole.finalize()))
}

/// `name: old → new` for the first `name=value` line of `new` that `old` lacks; a name on several
/// lines (one `input` a file) is compared occurrence by occurrence.
pub(crate) fn first_difference(old: &str, new: &str) -> String {
    let values = |text: &str, name: &str| -> Vec<String> {
        text.lines()
            .filter_map(|l| l.strip_prefix(name)?.strip_prefix('=').map(str::to_string))
            .collect()
    };
    let mut seen = std::collections::HashMap::<&str, usize>::new();
    for line in new.lines() {
        let name = line.split('=').next().unwrap_or(line);
        let k = seen.entry(name).or_default();
        let occurrence = *k;
        *k += 1;
        let now = values(new, name).swap_remove(occurrence);
        match values(old, name).get(occurrence) {
            Some(before) if *before == now => continue,
            Some(before) => return format!("{name}: {before} → {now}"),
            None => return format!("{name}: (none) → {now}"),
        }
    }
    "the journal's format".to_string()
}

/// Writes `bytes` to `dir/name` under a temporary name and renames it into place, so that a
/// killed process leaves the file whole or absent. Not synced: after a power loss a block file
/// may be cut short or empty, which its checksum catches ([`parse_block`]) and the block is
/// encoded again — syncing every block would cost more than redoing the few the page cache lost.
pub(crate) fn write_atomically(dir: &Path, name: &str, bytes: &[u8]) -> std::io::Result<()> {
    // A temporary of its own keeps two processes writing the same file (a retried shard whose
    // first run is still going) off each other's; it is removed if the write fails.
    let mut tmp = tempfile::Builder::new()
        .prefix(&format!(".{name}."))
        .suffix(".tmp")
        .tempfile_in(dir)?;
    tmp.write_all(bytes)?;
    tmp.persist(dir.join(name)).map_err(|e| e.error)?;
    Ok(())
}

pub(crate) fn put_id(out: &mut Vec<u8>, id: DiamondId) {
    out.push(id.level);
    out.push(id.face);
    out.extend_from_slice(&id.x.to_le_bytes());
    out.extend_from_slice(&id.y.to_le_bytes());
}

/// A block file: magic, version, the records (id, min, max, length, bytes), the own errors
/// (id, error), and a CRC-32 of everything before it; integers little-endian.
pub(crate) fn serialize_block(b: &BlockOutput) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&(b.records.len() as u64).to_le_bytes());
    for r in &b.records {
        put_id(&mut out, r.id);
        out.extend_from_slice(&r.min.to_le_bytes());
        out.extend_from_slice(&r.max.to_le_bytes());
        out.extend_from_slice(&(r.bytes.len() as u64).to_le_bytes());
        out.extend_from_slice(&r.bytes);
    }
    out.extend_from_slice(&(b.own_errors.len() as u64).to_le_bytes());
    for &(id, e) in &b.own_errors {
        put_id(&mut out, id);
        out.extend_from_slice(&e.to_le_bytes());
    }
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

/// Reads bytes off the front of a block file.
/// Reads little-endian fields off the front of a checked file body (the journal's block files,
/// the sharded build's summary): `None` when the bytes run out.
pub(crate) struct Reader<'a>(pub(crate) &'a [u8]);

impl<'a> Reader<'a> {
    pub(crate) fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let (a, b) = self.0.split_at_checked(n)?;
        self.0 = b;
        Some(a)
    }
    pub(crate) fn u8(&mut self) -> Option<u8> {
        Some(self.take(1)?[0])
    }
    pub(crate) fn u32(&mut self) -> Option<u32> {
        Some(u32::from_le_bytes(self.take(4)?.try_into().ok()?))
    }
    pub(crate) fn u64(&mut self) -> Option<u64> {
        Some(u64::from_le_bytes(self.take(8)?.try_into().ok()?))
    }
    /// A count of items of at least `size` bytes each, no more than the bytes left allow.
    pub(crate) fn count(&mut self, size: usize) -> Option<usize> {
        usize::try_from(self.u64()?)
            .ok()
            .filter(|&n| n.checked_mul(size).is_some_and(|b| b <= self.0.len()))
    }
    pub(crate) fn id(&mut self) -> Option<DiamondId> {
        let (level, face) = (self.u8()?, self.u8()?);
        Some(DiamondId::on_face(face, level, self.u32()?, self.u32()?))
    }
}

/// The block in a block file, `None` if it is not one whole (wrong magic or version, cut short,
/// checksum mismatch, counts beyond the file).
pub(crate) fn parse_block(bytes: &[u8]) -> Option<BlockOutput> {
    let (body, crc) = bytes.split_at_checked(bytes.len().checked_sub(4)?)?;
    if crc32fast::hash(body).to_le_bytes() != crc {
        return None;
    }
    let mut r = Reader(body);
    if r.take(4)? != MAGIC || r.u32()? != VERSION {
        return None;
    }
    let count = r.u64()?;
    // Every record takes at least 26 bytes: a count beyond the file is corrupt, not a reason
    // to allocate.
    let mut records = Vec::with_capacity(count.min(body.len() as u64 / 26) as usize);
    for _ in 0..count {
        let id = r.id()?;
        let min = r.u32()? as i32;
        let max = r.u32()? as i32;
        let len = usize::try_from(r.u64()?).ok()?;
        let bytes = r.take(len)?.to_vec();
        records.push(Record {
            id,
            bytes: bytes.into(),
            object_error: 0,
            min,
            max,
        });
    }
    let count = r.u64()?;
    let mut own_errors = Vec::with_capacity(count.min(body.len() as u64 / 14) as usize);
    for _ in 0..count {
        own_errors.push((r.id()?, r.u32()?));
    }
    r.0.is_empty().then_some(BlockOutput {
        records,
        own_errors,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> BlockOutput {
        BlockOutput {
            records: vec![
                Record {
                    id: DiamondId::new(3, 8, 24),
                    bytes: vec![1, 2, 3, 250].into(),
                    object_error: 0,
                    min: -7,
                    max: 4000,
                },
                Record {
                    id: DiamondId::on_face(2, 5, 16, 0),
                    bytes: Vec::new().into(),
                    object_error: 0,
                    min: 0,
                    max: 0,
                },
            ],
            own_errors: vec![(DiamondId::new(3, 8, 24), 12), (DiamondId::new(6, 4, 4), 0)],
        }
    }

    #[test]
    fn block_files_round_trip_and_reject_any_damage() {
        let b = sample();
        let bytes = serialize_block(&b);
        assert_eq!(parse_block(&bytes), Some(b));
        // Every truncation and every single-bit flip is refused, never a panic.
        for n in 0..bytes.len() {
            assert_eq!(parse_block(&bytes[..n]), None, "cut at {n}");
        }
        for i in 0..bytes.len() * 8 {
            let mut d = bytes.clone();
            d[i / 8] ^= 1 << (i % 8);
            assert_eq!(parse_block(&d), None, "bit {i}");
        }
    }

    #[test]
    fn a_changed_key_starts_over_naming_the_change() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("x.cbdam");
        let (j, r) = Journal::open(&out, "input=a 10\nmax_error=1\n").unwrap();
        assert_eq!(r, Resumed::Fresh);
        j.save(3, &sample()).unwrap();
        let (j, r) = Journal::open(&out, "input=a 10\nmax_error=1\n").unwrap();
        assert_eq!(
            r,
            Resumed::Continuing {
                blocks: 1,
                damaged: 0
            }
        );
        assert_eq!(j.load(3).unwrap(), Some(sample()));
        assert_eq!(j.load(4).unwrap(), None);
        let (j, r) = Journal::open(&out, "input=a 10\nmax_error=2\n").unwrap();
        assert_eq!(
            r,
            Resumed::StartedOver {
                changed: "max_error: 1 → 2".into()
            }
        );
        assert_eq!(j.load(3).unwrap(), None);
        j.finish().unwrap();
        assert!(!Journal::dir_of(&out).exists());
    }
}
