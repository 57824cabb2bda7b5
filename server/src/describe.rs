//! What a repository holds, as JSON: shared by `cbdam inspect --json` and the server's
//! `/v1/repos/{name}/meta`, so the two never drift apart.

use cbdam_codec::lifting::Alpha;
use cbdam_codec::repository::{GeoRef, Repository, RepositoryHead, Section};
use serde_json::{Value, json};

/// Per-level statistics of the stored records.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LevelStats {
    /// Stored records on this level.
    pub records: usize,
    /// Their total size, bytes.
    pub bytes: u64,
    /// Smallest object-space error, units (meaningless when `records` is 0).
    pub object_error_min: u32,
    /// Largest object-space error, units.
    pub object_error_max: u32,
}

/// Figures derived from a repository's index, for reports.
#[derive(Clone, Debug, PartialEq)]
pub struct Summary {
    /// One entry per level, 0 ..= finest.
    pub levels: Vec<LevelStats>,
    /// Records whose residuals are all zero (length 0).
    pub empty_records: usize,
    /// Smallest and largest object-space error over all records and the leaf error, units.
    pub object_error_range: (u32, u32),
    /// File bytes that are neither root field, index nor records: header and checksum table.
    pub container_overhead: u64,
    /// File size in bits per input sample.
    pub bits_per_sample: f64,
}

/// Computes the [`Summary`] of `repo` (one pass over the index).
pub fn summarize(repo: &Repository) -> Summary {
    summarize_head(repo.head())
}

/// [`summarize`] from a repository's head alone (all it reads): a remote repository's too.
pub fn summarize_head(head: &RepositoryHead) -> Summary {
    let p = head.params();
    let finest = p.layout().finest_level();
    let mut levels = vec![
        LevelStats {
            object_error_min: u32::MAX,
            ..LevelStats::default()
        };
        usize::from(finest) + 1
    ];
    let (mut lo, mut hi) = (head.leaf_error(), head.leaf_error());
    let mut empty_records = 0;
    for e in head.entries() {
        let l = &mut levels[usize::from(e.id.level)];
        l.records += 1;
        l.bytes += u64::from(e.length);
        l.object_error_min = l.object_error_min.min(e.object_error);
        l.object_error_max = l.object_error_max.max(e.object_error);
        lo = lo.min(e.object_error);
        hi = hi.max(e.object_error);
        // Smooth terrain has many all-zero records at coarse tolerances.
        empty_records += usize::from(e.length == 0);
    }
    // Distinct lattice points: the data rectangle on a plane, 6·S² + 2 on a planet.
    let samples = p.domain.lattice_points();
    Summary {
        levels,
        empty_records,
        object_error_range: (lo, hi),
        container_overhead: head.file_len()
            - head.section_len(Section::Roots)
            - head.section_len(Section::Index)
            - head.section_len(Section::Records),
        bits_per_sample: head.file_len() as f64 * 8.0 / samples as f64,
    }
}

/// The number of bytes before the records area: header, root field, index and checksum
/// table. A client that fetches `bytes=0-(head_len − 1)` of the file has everything but the
/// records, and can open it with the codec.
pub fn head_len(repo: &Repository) -> u64 {
    repo.head().section_offset(Section::Records)
}

/// `"1"` or `"0.5"`: the lifting weight as the CLI spells it.
pub fn alpha_name(a: Alpha) -> &'static str {
    if a == Alpha::One { "1" } else { "0.5" }
}

/// The repository described as a JSON object: header fields, georeferencing, extent, section
/// sizes and offsets, root ids, and per-level record statistics. This is the output of
/// `cbdam inspect --json`; the server's meta endpoint adds links to it.
pub fn describe(repo: &Repository) -> Value {
    describe_head(repo.head())
}

/// [`describe`] from a repository's head alone (all it reads): a remote repository's too.
pub fn describe_head(head: &RepositoryHead) -> Value {
    let p = head.params();
    let plan = head.plan();
    let s = summarize_head(head);
    let metres = |u: u32| f64::from(u) * plan.unit;
    let geo = head.georef().map(georef_json);
    let bbox = head.georef().map(|g| data_bbox(g, p.domain.data().size()));
    let (ex, ey) = p.layout().face_extent();
    let levels = levels_json(&s.levels, metres);
    let section = |sec: Section| json!({ "offset": head.section_offset(sec), "length": head.section_len(sec) });
    let roots: Vec<String> = p.domain.roots().map(|id| id.to_string()).collect();
    // A planet's provenance, null for planes.
    let planet = head.provenance().map(|v| {
        json!({
            "vertical_datum": v.vertical_datum.code(),
            "resampling_max_m": v.resampling_max,
            "resampling_rms_m": v.resampling_rms,
        })
    });
    let mut v = json!({
        "format_version": head.format_version(),
        "kind": p.kind.name(),
        "domain": p.domain.kind().name(),
        "faces": p.domain.faces(),
        "file_bytes": head.file_len(),
        "header_crc": format!("{:08x}", head.header_crc()),
        "diamond_size": p.layout().n(),
        "level_pairs": p.layout().k(),
        "finest_level": p.layout().finest_level(),
        "roots_x": p.layout().roots_x(),
        "roots_y": p.layout().roots_y(),
        "roots": roots,
        "alpha": alpha_name(p.alpha),
        "coder": p.coder.name(),
        "k": p.quantizer.k(),
        "root_k": p.root_quantizer.k(),
        "data_width": p.domain.data().width,
        "data_height": p.domain.data().height,
        "samples": p.domain.lattice_points(),
        "extent": {
            "lattice_width": ex + 1,
            "lattice_height": ey + 1,
            "bbox": bbox,
        },
        "unit_m": plan.unit,
        "offset_m": plan.offset,
        "max_error_requested_m": plan.epsilon,
        "max_error_guaranteed_m": plan.max_error(),
        "representation_error_m": plan.representation_error,
        "lattice": plan.lattice,
        "nodata": head.nodata(),
        "georef": geo,
        "records": head.entries().len(),
        "empty_records": s.empty_records,
        "roots_bytes": head.section_len(Section::Roots),
        "index_bytes": head.section_len(Section::Index),
        "records_bytes": head.section_len(Section::Records),
        "container_overhead_bytes": s.container_overhead,
        "head_len": head.section_offset(Section::Records),
        "sections": {
            "header": { "offset": 0, "length": head.header_len() },
            "roots": section(Section::Roots),
            "index": section(Section::Index),
            "checksums": section(Section::Checksums),
            "records": section(Section::Records),
        },
        "bits_per_sample": s.bits_per_sample,
        "object_error_range_m": [metres(s.object_error_range.0), metres(s.object_error_range.1)],
        "leaf_error_m": metres(head.leaf_error()),
        "levels": levels,
    });
    v["planet"] = planet.unwrap_or(Value::Null);
    v["float_rounding_m"] = json!(plan.rounding_error());
    v
}

/// The georeferencing as JSON: EPSG code, origin, pixel size, pixel-is, WKT.
fn georef_json(g: &GeoRef) -> Value {
    json!({
        "epsg": g.epsg, "origin_x": g.origin_x, "origin_y": g.origin_y,
        "pixel_x": g.pixel_x, "pixel_y": g.pixel_y,
        "pixel_is": if g.pixel_is_area { "area" } else { "point" },
        "wkt": g.wkt,
    })
}

/// The area the data samples cover, in CRS units: cell edges for pixel-is-area data, sample
/// centres widened by half a pixel for pixel-is-point data (GDAL's convention), so both read
/// as "the extent of the raster". `[x0, y0, x1, y1]`.
fn data_bbox(g: &GeoRef, (width, height): (usize, usize)) -> [f64; 4] {
    let half = if g.pixel_is_area { 0.0 } else { 0.5 };
    let x0 = g.origin_x - half * g.pixel_x;
    let y0 = g.origin_y + half * g.pixel_y;
    let x1 = x0 + width as f64 * g.pixel_x;
    let y1 = y0 - height as f64 * g.pixel_y;
    [x0.min(x1), y0.min(y1), x0.max(x1), y0.max(y1)]
}

/// Per level: records, bytes and the object-error range in metres (null without records).
fn levels_json(levels: &[LevelStats], metres: impl Fn(u32) -> f64) -> Vec<Value> {
    levels
        .iter()
        .enumerate()
        .map(|(i, l)| {
            let some = l.records > 0;
            json!({
                "level": i, "records": l.records, "bytes": l.bytes,
                "object_error_min_m": some.then(|| metres(l.object_error_min)),
                "object_error_max_m": some.then(|| metres(l.object_error_max)),
            })
        })
        .collect()
}
