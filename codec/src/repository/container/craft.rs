//! Hostile writers for tests and fuzzers: resealing every checksum of a repository-shaped
//! file, and a header with one field set to any value, checksums made to match.

use super::RepositoryHead;
use crate::CodecError;
use crate::repository::header::{
    FLAG_LEVEL_QUANTIZERS, FLAG_RMS_ERROR, HeaderFields, PlanetProvenance, VerticalDatum, crc32,
    read_header, reseal_header, write_compact,
};

/// Makes every checksum of a repository-shaped file match its bytes, in place: section CRCs,
/// header CRC and, when the head then parses, each non-empty record's slot in the checksum
/// table. For fuzzers and tests of hostile writers (checksums guard against damage, not against
/// a writer who computes them): what lies behind the checksums must still be validated.
/// Bytes whose header structure cannot be read are left as they are.
#[doc(hidden)]
pub fn reseal_checksums(b: &mut [u8]) {
    let Some(table) = reseal_header(b) else {
        return;
    };
    if let Ok(head) = RepositoryHead::parse(b, b.len() as u64) {
        let mut slot = 0;
        for i in 0..head.entries().len() {
            let Some(r) = head.record_range(i) else {
                continue;
            };
            if r.start == r.end {
                continue;
            }
            let at = table.start + 4 * slot;
            slot += 1;
            if at + 4 > table.end || r.end > b.len() as u64 {
                break;
            }
            let crc = crc32(&b[r.start as usize..r.end as usize]);
            b[at..at + 4].copy_from_slice(&crc.to_le_bytes());
        }
        reseal_header(b);
    }
}

/// The header fields [`craft_header`] can set, by name.
#[doc(hidden)]
pub const CRAFTABLE_FIELDS: &[&str] = &[
    "flags",
    "n",
    "level_pairs",
    "alpha",
    "coder",
    "lattice",
    "geo_flags",
    "nodata_policy",
    "vertical_unit",
    "roots_x",
    "roots_y",
    "data_width",
    "data_height",
    "quantizer_k",
    "leaf_error",
    "epsg",
    "unit",
    "offset",
    "epsilon",
    "representation_error",
    "origin_x",
    "origin_y",
    "pixel_x",
    "pixel_y",
    "nodata",
    "record_count",
    "resampling_max",
    "resampling_rms",
    "rms_target",
    "rms_measured",
    "level_k",
    "level_count",
];

/// A hostile writer's header: the repository `b` (format version 3 or later) with one header
/// field, named as in [`CRAFTABLE_FIELDS`], set to `bits` (a float's bits, or an integer, which
/// must fit the field), the header rewritten and every checksum made to match
/// ([`reseal_checksums`]). For tests and fuzzers of the validation behind the checksums.
///
/// # Errors
/// When `b`'s header cannot be read, is a fixed (version 1 or 2) one, the field is unknown or
/// the value does not fit it.
#[doc(hidden)]
pub fn craft_header(b: &[u8], field: &str, bits: u64) -> Result<Vec<u8>, CodecError> {
    let mut sealed = b.to_vec();
    reseal_header(&mut sealed);
    let mut h = read_header(&sealed)?;
    if h.version < 3 {
        return Err(CodecError::unsupported(
            "crafting a fixed (version 1 or 2) header",
        ));
    }
    let too_large = || CodecError::invalid(format!("{bits} does not fit header field {field}"));
    let int = || u32::try_from(bits).map_err(|_| too_large());
    let byte = || u8::try_from(bits).map_err(|_| too_large());
    let float = f64::from_bits(bits);
    let provenance = |h: &mut HeaderFields| {
        *h.provenance.get_or_insert(PlanetProvenance {
            vertical_datum: VerticalDatum::Unknown,
            resampling_max: 0.0,
            resampling_rms: 0.0,
        })
    };
    match field {
        "flags" => h.flags = int()?,
        "n" => h.n = int()?,
        "level_pairs" => h.level_pairs = byte()?,
        "alpha" => h.alpha = byte()?,
        "coder" => h.coder = byte()?,
        "lattice" => h.lattice = byte()?,
        "geo_flags" => h.geo_flags = byte()?,
        "nodata_policy" => h.nodata_policy = byte()?,
        "vertical_unit" => h.vertical_unit = byte()?,
        "roots_x" => h.roots_x = int()?,
        "roots_y" => h.roots_y = int()?,
        "data_width" => h.data_width = int()?,
        "data_height" => h.data_height = int()?,
        "quantizer_k" => h.quantizer_k = int()?,
        "leaf_error" => h.leaf_error = int()?,
        "epsg" => h.epsg = int()?,
        "unit" => h.unit = float,
        "offset" => h.offset = float,
        "epsilon" => h.epsilon = float,
        "representation_error" => h.representation_error = float,
        "origin_x" => h.geo[0] = float,
        "origin_y" => h.geo[1] = float,
        "pixel_x" => h.geo[2] = float,
        "pixel_y" => h.geo[3] = float,
        "nodata" => h.nodata = float,
        "record_count" => h.record_count = bits,
        "resampling_max" => {
            h.provenance = Some(PlanetProvenance {
                resampling_max: float,
                ..provenance(&mut h)
            });
        }
        "resampling_rms" => {
            h.provenance = Some(PlanetProvenance {
                resampling_rms: float,
                ..provenance(&mut h)
            });
        }
        "rms_target" => h.rms = Some((float, h.rms.map_or(0.0, |r| r.1))),
        "rms_measured" => h.rms = Some((h.rms.map_or(float, |r| r.0), float)),
        "level_k" | "level_count" => craft_level_ks(&mut h, field, bits),
        _ => {
            return Err(CodecError::invalid(format!(
                "no header field {field} (one of {})",
                CRAFTABLE_FIELDS.join(", ")
            )));
        }
    }
    let mut out = write_compact(&h)?;
    out.extend_from_slice(&sealed[h.header_len..]);
    reseal_checksums(&mut out);
    Ok(out)
}

/// The per-level quantizers of a crafted header (flag bit 5, set with bit 4 and an RMS bound
/// where absent; the list starts as the header's `k` on each of the `2K` levels):
/// `level_k` sets level `(bits >> 32) % count` to the low 32 bits, `level_count` makes the
/// list `bits % 100` long (past [`crate::quant::MAX_LEVELS`] and away from `2K` on purpose).
fn craft_level_ks(h: &mut HeaderFields, field: &str, bits: u64) {
    h.flags |= FLAG_LEVEL_QUANTIZERS | FLAG_RMS_ERROR;
    h.rms.get_or_insert((1.0, 0.0));
    let (levels, k) = (usize::from(h.level_pairs) * 2, h.quantizer_k);
    let ks = h.level_ks.get_or_insert_with(|| vec![k; levels]);
    if field == "level_count" {
        ks.resize((bits % 100) as usize, k);
    } else if !ks.is_empty() {
        let at = (bits >> 32) as usize % ks.len();
        ks[at] = bits as u32;
    }
}
