//! The files a sharded planet build's steps share ([`crate::planet_shard`]): the outline (the
//! planet's stored diamonds and each tile's stride), the apex (the levels above the cut, with
//! the grids and refinements the blocks start from) and each input's resampling error. Each is
//! little-endian, opens with its magic and the layout version, ends with a CRC-32 of the rest,
//! and is written under a temporary name and renamed; a file that does not read back whole is
//! named as damaged, never half-read.

use std::collections::{BTreeSet, HashMap};
use std::fs;
use std::path::{Path, PathBuf};

use cbdam_codec::geodesy::LatLon;
use cbdam_codec::hierarchy::planet::{ApexGrids, ApexRefinements, PlanetApex, PlanetOutline};
use cbdam_codec::hierarchy::{Record, Refined};

use crate::error::{Context, Result, bail};
use crate::journal::{Reader, put_id, write_atomically};
use crate::planet::InputResampling;

/// Version of these files' layout.
const VERSION: u32 = 1;
const OUTLINE_MAGIC: &[u8; 4] = b"CBPO";
const APEX_MAGIC: &[u8; 4] = b"CBPA";
const RESAMPLING_MAGIC: &[u8; 4] = b"CBPR";

/// What the plan measured of the whole planet: the outline, each tile's stride, the cut, and
/// the counts a build reports.
pub(crate) struct OutlineFile {
    pub outline: PlanetOutline,
    /// Per face, per tile: `log2` of its stride.
    pub strides: Vec<Vec<u32>>,
    pub cut: u8,
    /// Distinct lattice points with data.
    pub valid: u64,
    /// Points the tiles hold.
    pub held_points: u64,
}

fn seal(mut out: Vec<u8>) -> Vec<u8> {
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

fn header(magic: &[u8; 4]) -> Vec<u8> {
    let mut out = magic.to_vec();
    out.extend_from_slice(&VERSION.to_le_bytes());
    out
}

/// The checked body of `path` after its magic and version, or `None` when the file is absent.
fn open_body(path: &Path, magic: &[u8; 4]) -> Result<Option<Vec<u8>>> {
    let bytes = match fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e).with_context(|| format!("reading {}", path.display())),
    };
    let whole = bytes.len() >= 12 && {
        let (body, crc) = bytes.split_at(bytes.len() - 4);
        crc32fast::hash(body).to_le_bytes() == crc
            && &body[..4] == magic
            && body[4..8] == VERSION.to_le_bytes()
    };
    if !whole {
        return Err(damaged(path));
    }
    Ok(Some(bytes[8..bytes.len() - 4].to_vec()))
}

fn damaged(path: &Path) -> crate::BuildError {
    crate::BuildError::Invalid(format!(
        "{} is damaged or of another cbdam version: remove it and run its step again",
        path.display()
    ))
}

fn put_u64(out: &mut Vec<u8>, v: u64) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_i32s(out: &mut Vec<u8>, values: &[i32]) {
    put_u64(out, values.len() as u64);
    values
        .iter()
        .for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
}

fn read_i32s(r: &mut Reader) -> Option<Vec<i32>> {
    let n = r.count(4)?;
    (0..n).map(|_| Some(r.u32()? as i32)).collect()
}

/// Writes the outline file `name` in `work`.
pub(crate) fn write_outline(work: &Path, name: &str, o: &OutlineFile) -> Result<()> {
    let mut out = header(OUTLINE_MAGIC);
    let d = o.outline.domain();
    let (has_nodata, has_data) = o.outline.has_nodata_and_data();
    put_u64(&mut out, d.n() as u64);
    out.extend_from_slice(&d.layout().k().to_le_bytes());
    out.extend_from_slice(&o.outline.tile_log2().to_le_bytes());
    out.extend_from_slice(&[
        u8::from(o.outline.is_variable()),
        u8::from(has_nodata),
        u8::from(has_data),
        o.cut,
    ]);
    put_u64(&mut out, o.valid);
    put_u64(&mut out, o.held_points);
    put_u64(&mut out, o.strides.len() as u64);
    for face in &o.strides {
        put_u64(&mut out, face.len() as u64);
        out.extend(face.iter().map(|&s| s as u8));
    }
    put_u64(&mut out, o.outline.leaves().len() as u64);
    for level in o.outline.leaves() {
        put_u64(&mut out, level.len() as u64);
        level.iter().for_each(|&id| put_id(&mut out, id));
    }
    write_atomically(work, name, &seal(out))
        .with_context(|| format!("writing the planet's outline in {}", work.display()))
}

/// Reads the outline file `name` of `work` (an error naming it when absent or damaged).
pub(crate) fn read_outline(work: &Path, name: &str) -> Result<OutlineFile> {
    let path = work.join(name);
    let Some(body) = open_body(&path, OUTLINE_MAGIC)? else {
        bail!(
            "{} is missing: the plan did not finish; run `cbdam shard plan` again",
            path.display()
        );
    };
    let parse = |r: &mut Reader| -> Option<_> {
        let n = usize::try_from(r.u64()?).ok()?;
        let (k, tile_log2) = (r.u32()?, r.u32()?);
        let flags: [u8; 4] = r.take(4)?.try_into().ok()?;
        let (valid, held_points) = (r.u64()?, r.u64()?);
        let faces = r.count(8)?;
        let strides = (0..faces)
            .map(|_| {
                let n = r.count(1)?;
                Some(r.take(n)?.iter().map(|&s| u32::from(s)).collect())
            })
            .collect::<Option<Vec<Vec<u32>>>>()?;
        let levels = r.count(8)?;
        let leaves = (0..levels)
            .map(|_| {
                let n = r.count(10)?;
                (0..n).map(|_| r.id()).collect::<Option<BTreeSet<_>>>()
            })
            .collect::<Option<Vec<_>>>()?;
        let shape = (n, k, tile_log2, flags[0] != 0);
        Some((shape, leaves, flags, strides, valid, held_points))
    };
    let mut r = Reader(&body);
    let (shape, leaves, flags, strides, valid, held_points) = parse(&mut r)
        .filter(|_| r.0.is_empty())
        .ok_or_else(|| damaged(&path))?;
    let outline = PlanetOutline::from_parts(shape, leaves, flags[1] != 0, flags[2] != 0)
        .map_err(|_| damaged(&path))?;
    Ok(OutlineFile {
        outline,
        strides,
        cut: flags[3],
        valid,
        held_points,
    })
}

fn put_record(out: &mut Vec<u8>, r: &Record) {
    put_id(out, r.id);
    out.extend_from_slice(&r.min.to_le_bytes());
    out.extend_from_slice(&r.max.to_le_bytes());
    out.extend_from_slice(&r.object_error.to_le_bytes());
    put_u64(out, r.bytes.len() as u64);
    out.extend_from_slice(&r.bytes);
}

fn read_record(r: &mut Reader) -> Option<Record> {
    let id = r.id()?;
    let (min, max, object_error) = (r.u32()? as i32, r.u32()? as i32, r.u32()?);
    let len = r.count(1)?;
    Some(Record {
        id,
        bytes: r.take(len)?.to_vec().into(),
        object_error,
        min,
        max,
    })
}

fn put_refined(out: &mut Vec<u8>, f: &Refined) {
    let n = f.n();
    put_u64(out, n as u64);
    // Row-major, as `Refined::from_parts` takes them: vertex (i, j) is column i of row j.
    for j in 0..n {
        for i in 0..n {
            out.extend_from_slice(&f.vertex(i, j).to_le_bytes());
        }
    }
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            out.extend_from_slice(&f.cell(i, j).to_le_bytes());
        }
    }
    match f.validity() {
        None => out.push(0),
        Some(v) => {
            out.push(1);
            put_u64(out, v.len() as u64);
            out.extend(v.iter().map(|&b| u8::from(b)));
        }
    }
}

fn read_refined(r: &mut Reader) -> Option<Refined> {
    let n = r.count(4).filter(|&n| n >= 2)?;
    let mut ints =
        |count: usize| -> Option<Vec<i32>> { (0..count).map(|_| Some(r.u32()? as i32)).collect() };
    let vertices = ints(n.checked_mul(n)?)?;
    let cells = ints((n - 1) * (n - 1))?;
    let valid = match r.u8()? {
        0 => None,
        _ => {
            let len = r.count(1).filter(|&l| l == (2 * n - 1) * (2 * n - 1))?;
            Some(r.take(len)?.iter().map(|&b| b != 0).collect())
        }
    };
    Some(Refined::from_parts(n, &vertices, &cells).with_validity(valid))
}

/// Writes the apex file `name` in `work`.
pub(crate) fn write_apex(work: &Path, name: &str, apex: &PlanetApex) -> Result<()> {
    let mut out = header(APEX_MAGIC);
    put_i32s(&mut out, &apex.root_field);
    put_u64(&mut out, apex.roots.len() as u64);
    out.extend_from_slice(&apex.roots);
    put_u64(&mut out, apex.records.len() as u64);
    apex.records.iter().for_each(|r| put_record(&mut out, r));
    // In id order: the file's bytes do not depend on a hash map's order.
    let mut ids: Vec<_> = apex.grids.ids().collect();
    ids.sort();
    put_u64(&mut out, ids.len() as u64);
    for id in ids {
        put_id(&mut out, id);
        let grid = apex.grids.get(id)?.expect("an apex diamond's grid");
        put_i32s(&mut out, &grid);
    }
    let mut last: Vec<_> = apex.last.ids().collect();
    last.sort();
    put_u64(&mut out, last.len() as u64);
    for id in last {
        put_id(&mut out, id);
        let refined = apex.last.get(id)?.expect("an apex refinement");
        put_refined(&mut out, &refined);
    }
    write_atomically(work, name, &seal(out))
        .with_context(|| format!("writing the apex in {}", work.display()))
}

/// Reads the apex file `name` of `work` for the planet `outline` outlines: `None` when absent.
pub(crate) fn read_apex(
    work: &Path,
    name: &str,
    outline: &PlanetOutline,
) -> Result<Option<PlanetApex>> {
    let path = work.join(name);
    let Some(body) = open_body(&path, APEX_MAGIC)? else {
        return Ok(None);
    };
    let parse = |r: &mut Reader| -> Option<_> {
        let root_field = read_i32s(r)?;
        let len = r.count(1)?;
        let roots = r.take(len)?.to_vec();
        let n = r.count(26)?;
        let records = (0..n).map(|_| read_record(r)).collect::<Option<Vec<_>>>()?;
        let n = r.count(18)?;
        let grids = (0..n)
            .map(|_| Some((r.id()?, read_i32s(r)?)))
            .collect::<Option<HashMap<_, _>>>()?;
        let n = r.count(19)?;
        let last = (0..n)
            .map(|_| Some((r.id()?, read_refined(r)?)))
            .collect::<Option<HashMap<_, _>>>()?;
        Some((root_field, roots, records, grids, last))
    };
    let mut r = Reader(&body);
    let (root_field, roots, records, grids, last) = parse(&mut r)
        .filter(|_| r.0.is_empty())
        .ok_or_else(|| damaged(&path))?;
    let n = outline.domain().n();
    let spilled = |e| match e {
        cbdam_codec::CodecError::Io(e) => crate::BuildError::from(cbdam_codec::CodecError::Io(e)),
        _ => damaged(&path),
    };
    let grids = ApexGrids::from_grids(n * n, grids).map_err(spilled)?;
    let last = ApexRefinements::from_refined(n, last).map_err(spilled)?;
    Ok(Some(PlanetApex::from_parts(
        outline, root_field, roots, records, grids, last,
    )))
}

/// Writes input resampling error `name` in `dir`.
pub(crate) fn write_resampling(dir: &Path, name: &str, e: &InputResampling) -> Result<()> {
    let mut out = header(RESAMPLING_MAGIC);
    let path = e.path.to_string_lossy();
    put_u64(&mut out, path.len() as u64);
    out.extend_from_slice(path.as_bytes());
    put_u64(&mut out, e.samples);
    put_u64(&mut out, e.compared);
    put_u64(&mut out, e.max_error.to_bits());
    put_u64(&mut out, e.rms_error.to_bits());
    match e.worst_at {
        None => out.push(0),
        Some(at) => {
            out.push(1);
            put_u64(&mut out, at.lat.to_bits());
            put_u64(&mut out, at.lon.to_bits());
        }
    }
    out.extend_from_slice(&e.stride.to_le_bytes());
    write_atomically(dir, name, &seal(out))
        .with_context(|| format!("writing {}", dir.join(name).display()))
}

/// Reads input resampling error `name` of `dir`: `None` when absent.
pub(crate) fn read_resampling(dir: &Path, name: &str) -> Result<Option<InputResampling>> {
    let path = dir.join(name);
    let Some(body) = open_body(&path, RESAMPLING_MAGIC)? else {
        return Ok(None);
    };
    let parse = |r: &mut Reader| -> Option<InputResampling> {
        let len = r.count(1)?;
        let input = PathBuf::from(String::from_utf8(r.take(len)?.to_vec()).ok()?);
        let (samples, compared) = (r.u64()?, r.u64()?);
        let (max_error, rms_error) = (f64::from_bits(r.u64()?), f64::from_bits(r.u64()?));
        let worst_at = match r.u8()? {
            0 => None,
            _ => Some(LatLon {
                lat: f64::from_bits(r.u64()?),
                lon: f64::from_bits(r.u64()?),
            }),
        };
        Some(InputResampling {
            path: input,
            samples,
            compared,
            max_error,
            rms_error,
            worst_at,
            stride: r.u32()?,
        })
    };
    let mut r = Reader(&body);
    let e = parse(&mut r)
        .filter(|_| r.0.is_empty())
        .ok_or_else(|| damaged(&path))?;
    Ok(Some(e))
}
