//! The compact variable-length header of format version 3 and later: read field by field
//! through a cursor, and written.

use crate::CodecError;

use super::{
    FLAG_LEVEL_QUANTIZERS, FLAG_PLANET_PROVENANCE, FLAG_RMS_ERROR, HEADER_FETCH_LEN, HeaderFields,
    MAGIC, MAX_HEADER_LEN, PREFIX_LEN, PlanetProvenance, SectionEntry, VerticalDatum, crc32,
    u32_at,
};

/// A cursor over a compact header's field bytes (between the prefix and the CRC).
struct Fields<'a> {
    b: &'a [u8],
    pos: usize,
}

impl Fields<'_> {
    fn byte(&mut self) -> Result<u8, CodecError> {
        let v = *self
            .b
            .get(self.pos)
            .ok_or_else(|| CodecError::corrupt("header fields end early"))?;
        self.pos += 1;
        Ok(v)
    }

    /// A canonical LEB128 varint: no value has two spellings, so a file has one header.
    fn varint(&mut self) -> Result<u64, CodecError> {
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let b = self.byte()?;
            if shift == 63 && b > 1 {
                break;
            }
            v |= u64::from(b & 0x7f) << shift;
            if b & 0x80 == 0 {
                if b == 0 && shift > 0 {
                    return Err(CodecError::corrupt("header number has a redundant byte"));
                }
                return Ok(v);
            }
        }
        Err(CodecError::corrupt("header number longer than 64 bits"))
    }

    fn u32(&mut self, what: &str) -> Result<u32, CodecError> {
        let v = self.varint()?;
        u32::try_from(v).map_err(|_| CodecError::corrupt(format!("header {what} {v} too large")))
    }

    fn f64(&mut self) -> Result<f64, CodecError> {
        Ok(f64::from_bits(self.varint()?.swap_bytes()))
    }

    fn bytes(&mut self, n: usize) -> Result<&[u8], CodecError> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|&e| e <= self.b.len())
            .ok_or_else(|| CodecError::corrupt("header fields end early"))?;
        let v = &self.b[self.pos..end];
        self.pos = end;
        Ok(v)
    }

    fn u32_le(&mut self) -> Result<u32, CodecError> {
        Ok(u32_at(self.bytes(4)?, 0))
    }
}

/// Reads a compact header. Version-3 files written before the CRS definition (WKT) joined the
/// georeferencing fields (commit 08ba422, 2 December 2026, without a new version number) have
/// no WKT length after the geotransform: a georeferenced header that does not read with it is
/// read again without it, and only if that reads to the header's last byte is it taken.
pub(super) fn read_compact(b: &[u8], version: u16, crc: u32) -> Result<HeaderFields, CodecError> {
    match read_compact_layout(b, version, crc, Wkt::Present) {
        Err(e) if version == 3 => read_compact_layout(b, version, crc, Wkt::Absent).map_err(|_| e),
        read => read,
    }
}

/// Whether a compact header's georeferencing carries the CRS definition's length (every
/// compact header but the earliest version-3 ones, [`read_compact`]).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Wkt {
    Present,
    Absent,
}

fn read_compact_layout(
    b: &[u8],
    version: u16,
    crc: u32,
    wkt_layout: Wkt,
) -> Result<HeaderFields, CodecError> {
    let mut f = Fields {
        b: &b[PREFIX_LEN..b.len() - 4],
        pos: 0,
    };
    let flags = f.u32("flags")?;
    let n = f.u32("diamond size")?;
    let [
        level_pairs,
        alpha,
        coder,
        lattice,
        geo_flags,
        nodata_policy,
        vertical_unit,
    ]: [u8; 7] = f.bytes(7)?.try_into().expect("7 bytes");
    let roots_x = f.u32("root count")?;
    let roots_y = f.u32("root count")?;
    let data_width = f.u32("data width")?;
    let data_height = f.u32("data height")?;
    let quantizer_k = f.u32("quantizer")?;
    let leaf_error = f.u32("leaf error")?;
    let unit = f.f64()?;
    let offset = f.f64()?;
    let epsilon = f.f64()?;
    let representation_error = f.f64()?;
    let (epsg, geo, wkt) = parse_georef(&mut f, geo_flags, wkt_layout)?;
    let nodata = f.f64()?;
    let provenance = parse_provenance(&mut f, flags)?;
    let rms = parse_rms(&mut f, flags)?;
    let level_ks = parse_level_ks(&mut f, flags)?;
    let record_count = f.varint()?;
    let sections = parse_sections(&mut f, b.len() as u64)?;
    if f.pos != f.b.len() {
        return Err(CodecError::corrupt(format!(
            "{} unexpected bytes at the end of the header fields",
            f.b.len() - f.pos
        )));
    }
    Ok(HeaderFields {
        version,
        header_len: b.len(),
        flags,
        n,
        level_pairs,
        alpha,
        coder,
        lattice,
        geo_flags,
        nodata_policy,
        vertical_unit,
        roots_x,
        roots_y,
        data_width,
        data_height,
        quantizer_k,
        root_k: None,
        leaf_error,
        epsg,
        unit,
        offset,
        epsilon,
        representation_error,
        geo,
        nodata,
        wkt,
        provenance,
        rms,
        level_ks,
        sections,
        record_count,
        crc,
    })
}

/// The georeferencing fields: written only with `geo_flags` bit 0; their absence reads as the
/// zeros the fixed layout stores, so the container checks both layouts the same way.
fn parse_georef(
    f: &mut Fields<'_>,
    geo_flags: u8,
    wkt: Wkt,
) -> Result<(u32, [f64; 4], Option<String>), CodecError> {
    if geo_flags & 1 == 0 {
        return Ok((0, [0.0; 4], None));
    }
    let epsg = f.u32("EPSG code")?;
    let geo = [f.f64()?, f.f64()?, f.f64()?, f.f64()?];
    if wkt == Wkt::Absent {
        return Ok((epsg, geo, None));
    }
    let len = f.varint()?;
    if len == 0 {
        return Ok((epsg, geo, None));
    }
    let len = usize::try_from(len)
        .ok()
        .filter(|&l| l <= crate::repository::MAX_WKT_LEN)
        .ok_or_else(|| CodecError::corrupt(format!("CRS definition of {len} bytes")))?;
    let text = std::str::from_utf8(f.bytes(len)?)
        .map_err(|_| CodecError::corrupt("CRS definition is not UTF-8"))?;
    Ok((epsg, geo, Some(text.to_owned())))
}

/// A planet's provenance (vertical datum, resampling error), with its flag only.
fn parse_provenance(
    f: &mut Fields<'_>,
    flags: u32,
) -> Result<Option<PlanetProvenance>, CodecError> {
    if flags & FLAG_PLANET_PROVENANCE == 0 {
        return Ok(None);
    }
    let datum = f.byte()?;
    let vertical_datum = VerticalDatum::from_byte(datum)
        .ok_or_else(|| CodecError::unsupported(format!("unknown vertical datum {datum}")))?;
    let (resampling_max, resampling_rms) = (f.f64()?, f.f64()?);
    if !(resampling_max >= 0.0 && resampling_rms >= 0.0 && resampling_rms <= resampling_max) {
        return Err(CodecError::corrupt(format!(
            "resampling error max {resampling_max} m, rms {resampling_rms} m"
        )));
    }
    Ok(Some(PlanetProvenance {
        vertical_datum,
        resampling_max,
        resampling_rms,
    }))
}

/// The RMS bound (target, measured), with its flag only.
fn parse_rms(f: &mut Fields<'_>, flags: u32) -> Result<Option<(f64, f64)>, CodecError> {
    if flags & FLAG_RMS_ERROR == 0 {
        return Ok(None);
    }
    let (target, measured) = (f.f64()?, f.f64()?);
    if !(target.is_finite() && target > 0.0 && measured >= 0.0 && measured <= target) {
        return Err(CodecError::corrupt(format!(
            "RMS error bound {target} m with {measured} m measured"
        )));
    }
    Ok(Some((target, measured)))
}

/// Each level's quantizer `k` (a count, then one varint per level), with its flag only. The
/// count is checked against the layout and the values against the header's `k` by the
/// container; here only that they are numbers, at most [`crate::quant::MAX_LEVELS`] of them.
fn parse_level_ks(f: &mut Fields<'_>, flags: u32) -> Result<Option<Vec<u32>>, CodecError> {
    if flags & FLAG_LEVEL_QUANTIZERS == 0 {
        return Ok(None);
    }
    let count = f.varint()?;
    if count == 0 || count > crate::quant::MAX_LEVELS as u64 {
        return Err(CodecError::corrupt(format!(
            "{count} per-level quantizers in the header"
        )));
    }
    let ks = (0..count)
        .map(|_| f.u32("per-level quantizer"))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Some(ks))
}

/// The four sections' lengths (laid out one after the other from the header's end,
/// `header_len`) and then their CRCs.
fn parse_sections(f: &mut Fields<'_>, header_len: u64) -> Result<[SectionEntry; 4], CodecError> {
    let mut sections = [SectionEntry::default(); 4];
    let mut at = header_len;
    for s in &mut sections {
        let length = f.varint()?;
        *s = SectionEntry {
            offset: at,
            length,
            crc: 0,
        };
        at = at
            .checked_add(length)
            .ok_or_else(|| CodecError::corrupt("section lengths overflow"))?;
    }
    for s in &mut sections {
        s.crc = f.u32_le()?;
    }
    Ok(sections)
}

/// Writes `h` as a compact header (version `h.version`, 3 or later). `h.header_len`, `h.crc`,
/// `h.root_k` and the section offsets are ignored: the bytes determine them. Georeferencing
/// fields are written only with `geo_flags` bit 0.
pub(crate) fn write_compact(h: &HeaderFields) -> Result<Vec<u8>, CodecError> {
    let mut out = Vec::with_capacity(HEADER_FETCH_LEN);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&h.version.to_le_bytes());
    out.extend_from_slice(&[0, 0]); // header length, filled in below
    let varint = |out: &mut Vec<u8>, v: u64| crate::repository::index::put_varint(out, v);
    varint(&mut out, u64::from(h.flags));
    varint(&mut out, u64::from(h.n));
    out.extend_from_slice(&[
        h.level_pairs,
        h.alpha,
        h.coder,
        h.lattice,
        h.geo_flags,
        h.nodata_policy,
        h.vertical_unit,
    ]);
    for v in [
        h.roots_x,
        h.roots_y,
        h.data_width,
        h.data_height,
        h.quantizer_k,
        h.leaf_error,
    ] {
        varint(&mut out, u64::from(v));
    }
    for v in [h.unit, h.offset, h.epsilon, h.representation_error] {
        put_float(&mut out, v);
    }
    if h.geo_flags & 1 == 1 {
        put_georef(&mut out, h)?;
    }
    put_float(&mut out, h.nodata);
    put_provenance_and_rms(&mut out, h);
    varint(&mut out, h.record_count);
    for s in &h.sections {
        varint(&mut out, s.length);
    }
    for s in &h.sections {
        out.extend_from_slice(&s.crc.to_le_bytes());
    }
    let len = out.len() + 4;
    if len > MAX_HEADER_LEN {
        return Err(CodecError::limit(format!(
            "header of {len} bytes is over {MAX_HEADER_LEN}"
        )));
    }
    out[10..12].copy_from_slice(&(len as u16).to_le_bytes());
    let crc = crc32(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    Ok(out)
}

/// A float as the compact header stores it: the varint of its byte-swapped bits.
fn put_float(out: &mut Vec<u8>, v: f64) {
    crate::repository::index::put_varint(out, v.to_bits().swap_bytes());
}

/// The georeferencing fields of a compact header: EPSG code, the geotransform and the CRS
/// definition (refused beyond [`crate::repository::MAX_WKT_LEN`]).
fn put_georef(out: &mut Vec<u8>, h: &HeaderFields) -> Result<(), CodecError> {
    crate::repository::index::put_varint(out, u64::from(h.epsg));
    for v in h.geo {
        put_float(out, v);
    }
    let wkt = h.wkt.as_deref().unwrap_or("");
    if wkt.len() > crate::repository::MAX_WKT_LEN {
        return Err(CodecError::limit(format!(
            "a CRS definition of {} bytes (at most {} are kept)",
            wkt.len(),
            crate::repository::MAX_WKT_LEN
        )));
    }
    crate::repository::index::put_varint(out, wkt.len() as u64);
    out.extend_from_slice(wkt.as_bytes());
    Ok(())
}

/// A planet's provenance, the RMS bound and the per-level quantizers, each written when its
/// flag is set.
fn put_provenance_and_rms(out: &mut Vec<u8>, h: &HeaderFields) {
    // The flag decides, as it does for the reader; a flag without values writes zeros.
    if h.flags & FLAG_PLANET_PROVENANCE != 0 {
        let p = h.provenance.unwrap_or(PlanetProvenance {
            vertical_datum: VerticalDatum::Unknown,
            resampling_max: 0.0,
            resampling_rms: 0.0,
        });
        out.push(p.vertical_datum.to_byte());
        put_float(out, p.resampling_max);
        put_float(out, p.resampling_rms);
    }
    if h.flags & FLAG_RMS_ERROR != 0 {
        let (target, measured) = h.rms.unwrap_or((0.0, 0.0));
        put_float(out, target);
        put_float(out, measured);
    }
    if h.flags & FLAG_LEVEL_QUANTIZERS != 0 {
        let ks = h.level_ks.as_deref().unwrap_or(&[]);
        crate::repository::index::put_varint(out, ks.len() as u64);
        for &k in ks {
            crate::repository::index::put_varint(out, u64::from(k));
        }
    }
}
