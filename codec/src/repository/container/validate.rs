//! The steps of [`super::RepositoryHead::parse`], in file order: header, parameters and plan,
//! georeferencing, derived values, section placement, section checksums, index and record
//! checksum table. Each checks what it reads before the next allocates anything sized by it.

use super::{
    FLAG_COLOUR, FLAG_CUBE_SPHERE, FLAG_NODATA_MASK, FORMAT_VERSION, NODATA_DONT_CARE, Section,
    VERTICAL_METRES, range_of,
};
use crate::CodecError;
use crate::colour::ycocg;
use crate::entropy::CoderKind;
use crate::geometry::{DataRect, Domain, Layout};
use crate::hierarchy::{CodecParams, RepoKind, root_quantizer_of};
use crate::lifting::{Alpha, MAX_ABS_HEIGHT};
use crate::quant::{LevelQuantizers, QuantPlan, Quantizer, RmsBound};
use crate::repository::GeoRef;
use crate::repository::header::{
    FLAG_LEVEL_QUANTIZERS, FLAG_PLANET_PROVENANCE, FLAG_RMS_ERROR, HeaderFields, SectionEntry,
    crc32, read_header, read_prefix, u32_at,
};
use crate::repository::index::{IndexCoding, IndexEntry, decode_index};

/// The header step of [`RepositoryHead::parse`]: a version this reader knows, then the header's
/// bytes (magic, length, CRC, reserved bytes; [`read_header`]).
pub(super) fn parse_header(b: &[u8]) -> Result<HeaderFields, CodecError> {
    let (version, _) = read_prefix(b)?;
    if version > FORMAT_VERSION {
        return Err(CodecError::unsupported(format!(
            "repository format version {version} is newer than this reader (version \
             {FORMAT_VERSION}); upgrade cbdam"
        )));
    }
    if version == 0 {
        return Err(CodecError::corrupt(
            "repository format version 0 does not exist",
        ));
    }
    read_header(b)
}

/// The decoder's parameters and the quantization plan from the header's fields: the flags,
/// the layout and the coding ([`parse_layout`]), then the quantizers and the plan
/// ([`parse_plan`]).
pub(super) fn parse_params(h: &HeaderFields) -> Result<(CodecParams, QuantPlan), CodecError> {
    let (domain, alpha, coder, lattice) = parse_layout(h)?;
    let (plan, root_quantizer, kind) = parse_plan(h, lattice)?;
    if let Some(levels) = &plan.levels
        && levels.len() != usize::from(domain.layout().finest_level())
    {
        return Err(CodecError::corrupt(format!(
            "{} per-level quantizers for a hierarchy of {} levels of records",
            levels.len(),
            domain.layout().finest_level()
        )));
    }
    let params = CodecParams {
        domain,
        alpha,
        coder,
        quantizer: plan.quantizer,
        levels: plan.levels,
        root_quantizer,
        nodata_mask: h.flags & FLAG_NODATA_MASK != 0,
        kind,
    };
    Ok((params, plan))
}

/// Flags, layout, lifting weight, coder, lattice flag, georeferencing flags, nodata policy,
/// vertical unit and the data rectangle (which with the layout makes the domain), checked in
/// that order.
pub(super) fn parse_layout(
    h: &HeaderFields,
) -> Result<(Domain, Alpha, CoderKind, bool), CodecError> {
    let flags = h.flags;
    let known = FLAG_NODATA_MASK
        | FLAG_COLOUR
        | FLAG_CUBE_SPHERE
        | FLAG_PLANET_PROVENANCE
        | FLAG_RMS_ERROR
        | FLAG_LEVEL_QUANTIZERS;
    if flags & !known != 0 {
        return Err(CodecError::unsupported(format!(
            "unknown header flags {flags:#x}"
        )));
    }
    if flags & FLAG_LEVEL_QUANTIZERS != 0 && flags & FLAG_RMS_ERROR == 0 {
        return Err(CodecError::corrupt(
            "per-level quantizers (flag bit 5) without an RMS error bound (bit 4)",
        ));
    }
    if flags & FLAG_PLANET_PROVENANCE != 0 && flags & FLAG_CUBE_SPHERE == 0 {
        return Err(CodecError::corrupt(
            "a planet's provenance (flag bit 3) in a planar repository",
        ));
    }
    let n = usize::try_from(h.n).map_err(|_| CodecError::corrupt("diamond size too large"))?;
    let layout = Layout::new(n, u32::from(h.level_pairs), h.roots_x, h.roots_y)
        .map_err(|e| CodecError::corrupt(format!("header layout: {e}")))?;
    let alpha = Alpha::from_byte(h.alpha)
        .ok_or_else(|| CodecError::corrupt(format!("unknown lifting weight id {}", h.alpha)))?;
    let coder = CoderKind::from_byte(h.coder)?;
    let lattice = match h.lattice {
        0 => false,
        1 => true,
        v => {
            return Err(CodecError::corrupt(format!(
                "lattice flag {v} is not 0 or 1"
            )));
        }
    };
    let geo_flags = h.geo_flags;
    if geo_flags & !3 != 0 || geo_flags == 2 {
        return Err(CodecError::corrupt(format!(
            "invalid georeferencing flags {geo_flags:#x}"
        )));
    }
    if h.nodata_policy != NODATA_DONT_CARE {
        return Err(CodecError::unsupported(format!(
            "unknown nodata policy {}",
            h.nodata_policy
        )));
    }
    if h.vertical_unit != VERTICAL_METRES {
        return Err(CodecError::unsupported(format!(
            "unknown vertical unit {}",
            h.vertical_unit
        )));
    }
    let data = DataRect {
        width: h.data_width,
        height: h.data_height,
    };
    if flags & FLAG_CUBE_SPHERE != 0 {
        return cube_sphere_layout(h, data).map(|domain| (domain, alpha, coder, lattice));
    }
    // A header whose data rectangle does not fit its layout is corrupt, not a bad argument.
    let domain = Domain::planar(layout, data).map_err(|e| match e {
        CodecError::InvalidParameter(m) => CodecError::Corrupt(m),
        e => e,
    })?;
    Ok((domain, alpha, coder, lattice))
}

/// The domain of a header with [`FLAG_CUBE_SPHERE`]: one root per face, every face's points
/// holding data, no georeferencing, elevation only.
pub(super) fn cube_sphere_layout(h: &HeaderFields, data: DataRect) -> Result<Domain, CodecError> {
    if h.flags & FLAG_COLOUR != 0 {
        return Err(CodecError::unsupported(
            "a colour cube-sphere repository (this reader knows elevation planets only)",
        ));
    }
    if (h.roots_x, h.roots_y) != (1, 1) {
        return Err(CodecError::corrupt(format!(
            "a cube-sphere has one root per face, not {}×{}",
            h.roots_x, h.roots_y
        )));
    }
    if h.geo_flags != 0 {
        return Err(CodecError::corrupt(
            "a cube-sphere repository has planar georeferencing",
        ));
    }
    let n = usize::try_from(h.n).map_err(|_| CodecError::corrupt("diamond size too large"))?;
    let domain = Domain::cube_sphere(n, u32::from(h.level_pairs))
        .map_err(|e| CodecError::corrupt(format!("header cube-sphere: {e}")))?;
    if domain.data() != data {
        let side = domain.data().width;
        return Err(CodecError::corrupt(format!(
            "a cube-sphere face of this N and K has {side}×{side} points, the header says {}×{}",
            data.width, data.height
        )));
    }
    Ok(domain)
}

/// The quantizers, the height unit and offset, the tolerance (by kind: colour repositories
/// have their own rules) and the representation error, checked in that order. Returns the
/// plan, the root quantizer and the kind.
pub(super) fn parse_plan(
    h: &HeaderFields,
    lattice: bool,
) -> Result<(QuantPlan, Quantizer, RepoKind), CodecError> {
    let flags = h.flags;
    let quantizer = Quantizer::new(h.quantizer_k)
        .map_err(|e| CodecError::corrupt(format!("header quantizer: {e}")))?;
    let levels = parse_level_quantizers(h)?;
    let root_q = root_quantizer_of(quantizer, levels);
    if let Some(root_k) = h.root_k
        && root_k != root_q.k() as u32
    {
        return Err(CodecError::unsupported(format!(
            "root quantizer k = {root_k}; this reader derives {} from k = {}",
            root_q.k(),
            quantizer.k()
        )));
    }
    let (unit, offset, epsilon, representation_error) =
        (h.unit, h.offset, h.epsilon, h.representation_error);
    if !(unit.is_finite() && unit > 0.0) {
        return Err(CodecError::corrupt(format!(
            "height unit {unit} is not positive"
        )));
    }
    if !offset.is_finite() {
        return Err(CodecError::corrupt("height offset is not finite"));
    }
    let kind = if flags & FLAG_COLOUR != 0 {
        RepoKind::Colour
    } else {
        RepoKind::Elevation
    };
    // A colour tolerance of 0 levels is lossless and meaningful; an elevation one is not.
    let eps_ok = match kind {
        RepoKind::Elevation => epsilon > 0.0,
        RepoKind::Colour => epsilon >= 0.0,
    };
    if !(epsilon.is_finite() && eps_ok) {
        return Err(CodecError::corrupt(format!(
            "tolerance {epsilon} is not positive"
        )));
    }
    if kind == RepoKind::Colour {
        check_colour_plan(h, lattice, quantizer)?;
    }
    if !(representation_error.is_finite() && representation_error >= 0.0) {
        return Err(CodecError::corrupt(
            "representation error is negative or not finite",
        ));
    }
    let plan = QuantPlan {
        unit,
        offset,
        quantizer,
        lattice,
        representation_error,
        epsilon,
        rms: h
            .rms
            .map(|(target, measured)| RmsBound { target, measured }),
        levels,
    };
    if plan.rms.is_some() && kind == RepoKind::Colour {
        return Err(CodecError::corrupt(
            "an RMS error bound in a colour repository",
        ));
    }
    Ok((plan, root_q, kind))
}

/// The per-level quantizers of flag bit 5: each a valid `k`, the largest the header's `k`
/// (which the root quantizer and the L∞ bound derive from).
fn parse_level_quantizers(h: &HeaderFields) -> Result<Option<LevelQuantizers>, CodecError> {
    let Some(ks) = &h.level_ks else {
        return Ok(None);
    };
    let levels = LevelQuantizers::new(ks)
        .map_err(|e| CodecError::corrupt(format!("header per-level quantizers: {e}")))?;
    if levels.max_k() != h.quantizer_k {
        return Err(CodecError::corrupt(format!(
            "the largest per-level quantizer k = {} is not the header's k = {}",
            levels.max_k(),
            h.quantizer_k
        )));
    }
    Ok(Some(levels))
}

/// A colour repository's plan: no nodata mask, unit 1, offset 0, lattice input, and a
/// quantizer whose RGB error is within the stated tolerance.
pub(super) fn check_colour_plan(
    h: &HeaderFields,
    lattice: bool,
    quantizer: Quantizer,
) -> Result<(), CodecError> {
    if h.flags & FLAG_NODATA_MASK != 0 {
        return Err(CodecError::unsupported(
            "a colour repository with a nodata mask",
        ));
    }
    if h.unit != 1.0 || h.offset != 0.0 || !lattice || h.representation_error != 0.0 {
        return Err(CodecError::corrupt(
            "a colour repository must have unit 1, offset 0 and lattice input",
        ));
    }
    let bound = ycocg::rgb_bound(quantizer.k() as u32);
    if bound.iter().any(|&b| f64::from(b) > h.epsilon) {
        return Err(CodecError::corrupt(format!(
            "colour quantizer k = {} allows RGB errors of {bound:?}, over the stated tolerance \
             {}",
            quantizer.k(),
            h.epsilon
        )));
    }
    Ok(())
}

/// The georeferencing fields: finite where the flags say they are present, all zero where
/// they say there are none ([`parse_layout`] checked the flags themselves).
pub(super) fn parse_georef(h: &HeaderFields) -> Result<Option<GeoRef>, CodecError> {
    let (geo_flags, epsg, geo) = (h.geo_flags, h.epsg, h.geo);
    if geo_flags & 1 == 1 {
        if geo.iter().any(|v| !v.is_finite()) {
            return Err(CodecError::corrupt("georeferencing values are not finite"));
        }
        Ok(Some(GeoRef {
            epsg: (epsg != 0).then_some(epsg),
            origin_x: geo[0],
            origin_y: geo[1],
            pixel_x: geo[2],
            pixel_y: geo[3],
            pixel_is_area: geo_flags & 2 == 2,
            wkt: h.wkt.clone(),
        }))
    } else {
        if epsg != 0 || geo.iter().any(|&v| v.to_bits() != 0) {
            return Err(CodecError::corrupt(
                "georeferencing fields are set but the header says there is none",
            ));
        }
        Ok(None)
    }
}

/// Largest magnitude of any height (metres) or georeferenced coordinate (CRS units) a
/// repository may describe. Far beyond any planet (the Earth's circumference is 4·10⁷ m, and a
/// degree 1.1·10⁵ m), yet small enough that what consumers compute from it — distances and
/// their squares, projection matrices, coordinates relative to an eye in `f32`, degrees turned
/// into metres — stays finite.
pub const MAX_MAGNITUDE: f64 = 1e15;

/// The derived-values step: each field is finite on its own ([`parse_plan`], [`parse_georef`]),
/// but what readers compute from them must be too. Every height a record can reconstruct
/// (`offset + unit·h` for `|h| ≤` [`MAX_ABS_HEIGHT`]), every georeferenced coordinate of the
/// lattice (`origin + pixel·i` for `i` from −1 to the lattice's extent) and a planet's
/// resampling errors must be finite and within [`MAX_MAGNITUDE`]; the representation error must
/// lie within its range (below half a unit and the tolerance for lattice input, 0 otherwise).
/// The errors name the field and its value. Writers run the same check, so nothing writes what
/// a reader refuses.
pub(super) fn parse_derived(h: &HeaderFields, domain: &Domain) -> Result<(), CodecError> {
    let within = |v: f64| v.is_finite() && v.abs() <= MAX_MAGNITUDE;
    let reach = h.unit * f64::from(MAX_ABS_HEIGHT);
    let (low, high) = (h.offset - reach, h.offset + reach);
    if !(within(low) && within(high) && low <= high) {
        return Err(CodecError::corrupt(format!(
            "header height unit {:?} m with offset {:?} m: the heights it spans ({low:?} … \
             {high:?} m, offset ± unit · {MAX_ABS_HEIGHT}) are not finite and within \
             ±{MAX_MAGNITUDE:e} m",
            h.unit, h.offset
        )));
    }
    let repr = h.representation_error;
    let repr_ok = repr == 0.0 || (h.lattice == 1 && repr < h.unit / 2.0 && repr < h.epsilon);
    if !repr_ok {
        return Err(CodecError::corrupt(format!(
            "header representation error {repr:?} m is out of range for unit {:?} m and \
             tolerance {:?} m (lattice input: below half a unit and the tolerance; otherwise 0)",
            h.unit, h.epsilon
        )));
    }
    if h.geo_flags & 1 == 1 {
        let (ex, ey) = domain.layout().face_extent();
        let [ox, oy, px, py] = h.geo;
        for (axis, origin, pixel, extent) in [("x", ox, px, ex), ("y", oy, py, ey)] {
            // Pixel-is-point extents reach half a pixel before the origin; a whole one covers it.
            let (first, last) = (origin - pixel, origin + pixel * extent as f64);
            if !(within(origin) && within(first) && within(last)) {
                return Err(CodecError::corrupt(format!(
                    "header georeferencing origin {axis} {origin:?} with pixel size {axis} \
                     {pixel:?}: the lattice's coordinates ({first:?} … {last:?}, over {extent} \
                     points) are not finite and within ±{MAX_MAGNITUDE:e}"
                )));
            }
        }
    }
    if let Some(p) = h.provenance {
        for (what, v) in [
            ("maximum", p.resampling_max),
            ("root mean square", p.resampling_rms),
        ] {
            if !within(v) {
                return Err(CodecError::corrupt(format!(
                    "header planet resampling error ({what}) {v:?} m is not finite and within \
                     ±{MAX_MAGNITUDE:e} m"
                )));
            }
        }
    }
    Ok(())
}

/// The placement step: the sections follow the header and one another without gaps, end
/// within `file_len` and the records area ends the file; the `given` bytes hold everything
/// before the records area.
pub(super) fn parse_placement(
    sections: &[SectionEntry; 4],
    header_len: usize,
    given: usize,
    file_len: u64,
) -> Result<(), CodecError> {
    let mut expected = header_len as u64;
    for (i, s) in Section::ALL.iter().enumerate() {
        let info = sections[i];
        // Sections follow one another without gaps: anything else is not a repository.
        if info.offset != expected {
            return Err(CodecError::corrupt(format!(
                "{} starts at byte {}, expected {expected}",
                s.name(),
                info.offset
            )));
        }
        let end = info
            .offset
            .checked_add(info.length)
            .ok_or_else(|| CodecError::corrupt(format!("{} length overflows", s.name())))?;
        if end > file_len {
            return Err(CodecError::truncated(format!(
                "{} ends at byte {end} but the file is {file_len} bytes",
                s.name()
            )));
        }
        expected = end;
    }
    if expected != file_len {
        return Err(CodecError::corrupt(format!(
            "{} trailing bytes after the records area",
            file_len - expected
        )));
    }
    if (given as u64) < sections[3].offset {
        return Err(CodecError::truncated(format!(
            "{given} bytes given, the repository head is {}",
            sections[3].offset
        )));
    }
    Ok(())
}

/// The checksum step: the CRCs of the root field, the index and the record checksum table
/// (placed by [`parse_placement`]).
pub(super) fn parse_section_checksums(
    b: &[u8],
    sections: &[SectionEntry; 4],
) -> Result<(), CodecError> {
    for (i, s) in Section::ALL.iter().enumerate().take(3) {
        if crc32(&b[range_of(&sections[i])]) != sections[i].crc {
            return Err(CodecError::corrupt(format!(
                "{} checksum mismatch",
                s.name()
            )));
        }
    }
    Ok(())
}

/// The index step: the record index, decoded in the coding of the file's version, holds as
/// many records as the header says.
pub(super) fn parse_index(
    b: &[u8],
    h: &HeaderFields,
    domain: &Domain,
) -> Result<Vec<IndexEntry>, CodecError> {
    let sections = &h.sections;
    let record_count = h.record_count;
    let entries = decode_index(
        domain,
        &b[range_of(&sections[1])],
        sections[3].length,
        IndexCoding::for_format_version(h.version)?,
    )?;
    if entries.len() as u64 != record_count {
        return Err(CodecError::corrupt(format!(
            "index holds {} records, header says {record_count}",
            entries.len()
        )));
    }
    Ok(entries)
}

/// The record checksum table: one CRC-32 per non-empty record of `entries`, nothing more;
/// returns one per entry (0 for empty records).
pub(super) fn parse_record_checksums(
    b: &[u8],
    sections: &[SectionEntry; 4],
    entries: &[IndexEntry],
) -> Result<Vec<u32>, CodecError> {
    let non_empty = entries.iter().filter(|e| e.length > 0).count() as u64;
    if non_empty * 4 != sections[2].length {
        return Err(CodecError::corrupt(format!(
            "record checksum table is {} bytes for {non_empty} non-empty records",
            sections[2].length
        )));
    }
    let table = &b[range_of(&sections[2])];
    let mut slot = 0;
    Ok(entries
        .iter()
        .map(|e| {
            if e.length == 0 {
                return 0;
            }
            slot += 4;
            u32_at(table, slot - 4)
        })
        .collect())
}
