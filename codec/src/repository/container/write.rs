//! Writing a repository: the file image of an encoded hierarchy (header, root field, index,
//! checksum table, records), in memory or streamed atomically to a path.

use std::fs::File;
use std::io::Write;
use std::path::Path;

use super::validate::parse_derived;
use super::{
    FLAG_COLOUR, FLAG_CUBE_SPHERE, FLAG_NODATA_MASK, FORMAT_VERSION, NODATA_DONT_CARE,
    VERTICAL_METRES,
};
use crate::CodecError;
use crate::atomic::write_atomically;
use crate::geometry::DomainKind;
use crate::hierarchy::{Encoded, RepoKind};
use crate::quant::QuantPlan;
use crate::repository::GeoRef;
use crate::repository::header::{
    FLAG_LEVEL_QUANTIZERS, FLAG_PLANET_PROVENANCE, FLAG_RMS_ERROR, HeaderFields, PlanetProvenance,
    SectionEntry, crc32, write_compact,
};
use crate::repository::index::{encode_index, range_shift_for};

/// Serialises `encoded` as a repository file image. `nodata` is the input's effective nodata
/// value (recorded so that `verify` can re-read the input the same way).
pub fn serialize(
    encoded: &Encoded,
    plan: &QuantPlan,
    georef: Option<&GeoRef>,
    nodata: Option<f64>,
) -> Result<Vec<u8>, CodecError> {
    serialize_with(encoded, plan, georef, nodata, None)
}

/// [`serialize`] with a planet's provenance in the header (flag bit 3; cube-sphere only).
pub(super) fn serialize_with(
    encoded: &Encoded,
    plan: &QuantPlan,
    georef: Option<&GeoRef>,
    nodata: Option<f64>,
    provenance: Option<&PlanetProvenance>,
) -> Result<Vec<u8>, CodecError> {
    let mut out = Vec::new();
    let total = serialize_to(&mut out, encoded, plan, georef, nodata, provenance)?;
    debug_assert_eq!(out.len() as u64, total);
    Ok(out)
}

/// Writes the file image of [`serialize_with`] to `out`, section by section (a large
/// repository's records are not copied into one buffer first); returns its length.
pub(super) fn serialize_to(
    out: &mut dyn Write,
    encoded: &Encoded,
    plan: &QuantPlan,
    georef: Option<&GeoRef>,
    nodata: Option<f64>,
    provenance: Option<&PlanetProvenance>,
) -> Result<u64, CodecError> {
    let p = &encoded.params;
    if p.quantizer != plan.quantizer || p.levels != plan.levels {
        return Err(CodecError::invalid(
            "the quantization plan does not match the encoded hierarchy's quantizer",
        ));
    }
    let entries = encoded.index_entries();
    let index = encode_index(&p.domain, &entries, range_shift_for(p.quantizer));
    // Empty records (all residuals zero) get no checksum: their length of 0 is already covered
    // by the index's CRC, and smooth terrain has many (all 69 of lidar1m_mn's at 5 m).
    let checksums: Vec<u8> = encoded
        .records
        .iter()
        .filter(|r| !r.bytes.is_empty())
        .flat_map(|r| crc32(&r.bytes).to_le_bytes())
        .collect();
    let n = u16::try_from(p.layout().n()).map_err(|_| CodecError::limit("diamond size"))?;
    let k = u8::try_from(p.layout().k()).map_err(|_| CodecError::limit("level pairs"))?;
    let flags = header_flags(encoded, plan, georef.is_some(), provenance.is_some())?;
    let fields = HeaderFields {
        version: FORMAT_VERSION,
        header_len: 0,
        flags,
        n: u32::from(n),
        level_pairs: k,
        alpha: p.alpha.to_byte(),
        coder: p.coder.to_byte(),
        lattice: u8::from(plan.lattice),
        geo_flags: georef.map_or(0, |g| 1 | (u8::from(g.pixel_is_area) << 1)),
        nodata_policy: NODATA_DONT_CARE,
        vertical_unit: VERTICAL_METRES,
        roots_x: p.layout().roots_x(),
        roots_y: p.layout().roots_y(),
        data_width: p.domain.data().width,
        data_height: p.domain.data().height,
        quantizer_k: p.quantizer.k() as u32,
        root_k: None,
        leaf_error: encoded.leaf_error,
        epsg: georef.and_then(|g| g.epsg).unwrap_or(0),
        unit: plan.unit,
        offset: plan.offset,
        epsilon: plan.epsilon,
        representation_error: plan.representation_error,
        geo: georef.map_or([0.0; 4], |g| [g.origin_x, g.origin_y, g.pixel_x, g.pixel_y]),
        nodata: nodata.unwrap_or(f64::NAN),
        wkt: georef.and_then(|g| g.wkt.clone()),
        provenance: provenance.copied(),
        rms: plan.rms.map(|r| (r.target, r.measured)),
        level_ks: plan.levels.map(|l| l.ks().to_vec()),
        sections: section_entries(encoded, &index, &checksums),
        record_count: encoded.records.len() as u64,
        crc: 0,
    };
    // What a reader would refuse is not written: the same check, blamed on the caller.
    parse_derived(&fields, &p.domain).map_err(|e| match e {
        CodecError::Corrupt(m) => CodecError::InvalidParameter(m),
        e => e,
    })?;
    let h = write_compact(&fields)?;
    let offset = h.len() as u64 + fields.sections.iter().map(|s| s.length).sum::<u64>();

    out.write_all(&h)?;
    out.write_all(&encoded.roots)?;
    out.write_all(&index)?;
    out.write_all(&checksums)?;
    for r in &encoded.records {
        out.write_all(&r.bytes)?;
    }
    Ok(offset)
}

/// The four sections' lengths and CRCs: roots, index, checksums, records (offsets are laid out
/// by the header writer).
pub(super) fn section_entries(
    encoded: &Encoded,
    index: &[u8],
    checksums: &[u8],
) -> [SectionEntry; 4] {
    let section = |bytes: &[u8]| SectionEntry {
        offset: 0,
        length: bytes.len() as u64,
        crc: crc32(bytes),
    };
    let mut records = crc32fast::Hasher::new();
    for r in &encoded.records {
        records.update(&r.bytes);
    }
    [
        section(&encoded.roots),
        section(index),
        section(checksums),
        SectionEntry {
            offset: 0,
            length: encoded.records.iter().map(|r| r.bytes.len() as u64).sum(),
            crc: records.finalize(),
        },
    ]
}

/// The header's flags for `encoded` under `plan`; errors for what a cube-sphere cannot hold
/// (planar georeferencing, colour) and for a provenance on a plane.
pub(super) fn header_flags(
    encoded: &Encoded,
    plan: &QuantPlan,
    georeferenced: bool,
    provenance: bool,
) -> Result<u32, CodecError> {
    let p = &encoded.params;
    let cube_sphere = p.domain.kind() == DomainKind::CubeSphere;
    if cube_sphere && (georeferenced || p.kind == RepoKind::Colour) {
        return Err(CodecError::invalid(
            "a cube-sphere repository holds elevation placed by its own mapping: no planar \
             georeferencing, no colour",
        ));
    }
    if provenance && !cube_sphere {
        return Err(CodecError::invalid(
            "a planet's provenance belongs in a cube-sphere repository",
        ));
    }
    let flag = |on: bool, bit: u32| if on { bit } else { 0 };
    Ok(flag(p.nodata_mask, FLAG_NODATA_MASK)
        | flag(p.kind == RepoKind::Colour, FLAG_COLOUR)
        | flag(cube_sphere, FLAG_CUBE_SPHERE)
        | flag(provenance, FLAG_PLANET_PROVENANCE)
        | flag(plan.rms.is_some(), FLAG_RMS_ERROR)
        | flag(plan.levels.is_some(), FLAG_LEVEL_QUANTIZERS))
}

/// Writes a repository to `path` atomically, streamed through a buffer.
pub(super) fn write_streamed(
    path: &Path,
    encoded: &Encoded,
    plan: &QuantPlan,
    georef: Option<&GeoRef>,
    nodata: Option<f64>,
    provenance: Option<&PlanetProvenance>,
) -> Result<(), CodecError> {
    write_atomically(path, |f: &mut File| -> Result<(), CodecError> {
        let mut out = std::io::BufWriter::with_capacity(1 << 20, f);
        serialize_to(&mut out, encoded, plan, georef, nodata, provenance)?;
        out.flush()?;
        Ok(())
    })
}

/// Writes `encoded` to `path` atomically ([`crate::atomic::write_atomically`]): a reader never
/// sees a half-written repository and a failed write leaves nothing behind. Refuses a `path`
/// that is a directory.
pub fn write_repository(
    path: &Path,
    encoded: &Encoded,
    plan: &QuantPlan,
    georef: Option<&GeoRef>,
    nodata: Option<f64>,
) -> Result<(), CodecError> {
    write_streamed(path, encoded, plan, georef, nodata, None)
}

/// Writes a planet repository with its provenance ([`PlanetProvenance`]) atomically, as
/// [`write_repository`] does.
pub fn write_planet_repository(
    path: &Path,
    encoded: &Encoded,
    plan: &QuantPlan,
    nodata: Option<f64>,
    provenance: &PlanetProvenance,
) -> Result<(), CodecError> {
    write_streamed(path, encoded, plan, None, nodata, Some(provenance))
}
