//! The work directory's `summary`: what the encoder's setup measured of the whole grid once in
//! the plan (stored diamonds, roots, bounds), so that no later step scans the grid again.

use std::fs;
use std::path::Path;

use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::GridSummary;

use super::VERSION;
use crate::error::{Context, Result};
use crate::journal::{Reader, write_atomically};

pub(super) const SUMMARY: &str = "summary";
/// Magic bytes of the `summary` file.
pub(super) const SUMMARY_MAGIC: &[u8; 4] = b"CBDS";
/// Writes `work/summary`: magic, version, max |height|, all valid, nodata mask, the stored
/// diamonds per level, the recorded ones (variable resolution), the root field and the coded
/// roots, and a CRC-32; little-endian.
pub(crate) fn write_summary(work: &Path, s: &GridSummary) -> Result<()> {
    let mut out = Vec::new();
    out.extend_from_slice(SUMMARY_MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&s.max_abs.to_le_bytes());
    out.push(u8::from(s.all_valid));
    out.push(u8::from(s.nodata_mask));
    let put_levels = |out: &mut Vec<u8>, levels: &[Vec<DiamondId>]| {
        out.extend_from_slice(&(levels.len() as u64).to_le_bytes());
        for level in levels {
            out.extend_from_slice(&(level.len() as u64).to_le_bytes());
            for id in level {
                out.push(id.level);
                out.push(id.face);
                out.extend_from_slice(&id.x.to_le_bytes());
                out.extend_from_slice(&id.y.to_le_bytes());
            }
        }
    };
    put_levels(&mut out, &s.stored);
    out.push(u8::from(s.recorded.is_some()));
    if let Some(r) = &s.recorded {
        put_levels(&mut out, r);
    }
    out.extend_from_slice(&(s.root_field.len() as u64).to_le_bytes());
    s.root_field
        .iter()
        .for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
    out.extend_from_slice(&(s.roots.len() as u64).to_le_bytes());
    out.extend_from_slice(&s.roots);
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    write_atomically(work, SUMMARY, &out)
        .with_context(|| format!("writing the grid summary in {}", work.display()))?;
    Ok(())
}

/// The summary's stored sets: per level, its diamonds.
pub(super) fn read_levels(r: &mut Reader) -> Option<Vec<Vec<DiamondId>>> {
    let levels = r.count(8)?;
    (0..levels)
        .map(|_| {
            let n = r.count(10)?;
            (0..n).map(|_| r.id()).collect()
        })
        .collect()
}

/// The summary [`write_summary`] wrote.
pub(crate) fn read_summary(work: &Path) -> Result<GridSummary> {
    let path = work.join(SUMMARY);
    let bytes = fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
    let damaged = || {
        crate::BuildError::Invalid(format!(
            "{} is damaged or of another cbdam version; plan again in a new work directory",
            path.display()
        ))
    };
    let (body, crc) = bytes
        .split_at_checked(bytes.len().checked_sub(4).ok_or_else(damaged)?)
        .ok_or_else(damaged)?;
    if crc32fast::hash(body).to_le_bytes() != crc {
        return Err(damaged());
    }
    let mut r = Reader(body);
    let parse = |r: &mut Reader| -> Option<GridSummary> {
        if r.take(4)? != SUMMARY_MAGIC || r.u32()? != VERSION {
            return None;
        }
        let max_abs = r.u64()? as i64;
        let (all_valid, nodata_mask) = (r.u8()? != 0, r.u8()? != 0);
        let stored = read_levels(r)?;
        let recorded = match r.u8()? {
            0 => None,
            _ => Some(read_levels(r)?),
        };
        let n = r.count(4)?;
        let root_field = (0..n)
            .map(|_| Some(r.u32()? as i32))
            .collect::<Option<_>>()?;
        let n = r.count(1)?;
        let roots = r.take(n)?.to_vec();
        r.0.is_empty().then_some(GridSummary {
            max_abs,
            all_valid,
            nodata_mask,
            stored,
            recorded,
            root_field,
            roots,
        })
    };
    parse(&mut r).ok_or_else(damaged)
}
