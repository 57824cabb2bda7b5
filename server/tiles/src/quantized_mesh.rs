//! Quantized-mesh-1.0 tiles (CesiumJS's terrain format) of the geographic TMS scheme.
//!
//! Each tile's vertices are points of a grid of `GRID + 1` × `GRID + 1`, evenly spaced in
//! longitude and latitude, each at the repository's height there ([`Surface::height`], from
//! the level whose spacing suits the tile); which of them, and the triangles, come from an
//! adaptive cut within the level's error ([`mesh_cut`]). Vertex positions come from global
//! integer indices and heights are quantized over the repository's whole height range (the
//! same header range in every tile), so the vertices two neighbouring tiles share along an
//! edge are bit-identical: same u/v position on the ground, same quantized height.
//!
//! The byte layout follows the quantized-mesh-1.0 specification: an 88-byte header (centre,
//! height range, bounding sphere, horizon occlusion point), zig-zag delta-coded u/v/height,
//! high-water-mark coded triangle indices, the four edge lists, then the extensions asked for
//! (oct-encoded vertex normals, id 1; metadata, id 4). All little-endian.

use cbdam_codec::geodesy::Geodetic;
use cbdam_codec::geodesy::wgs84::{A, B};

use crate::coverage::Availability;
use crate::mesh_cut;
use crate::mesh_cut::shared::Position;
use crate::place::{Placement, coarsen_for};
use crate::schemes::TileId;
use crate::surface::Surface;

/// Cells along each side of a tile (CesiumJS's own heightmap tiles are 65 × 65 samples).
pub const GRID: u32 = 64;
/// Largest quantized u, v or height.
pub const QMAX: u32 = 32_767;
/// Extension id of oct-encoded vertex normals.
pub const EXT_NORMALS: u8 = 1;
/// Extension id of metadata (JSON).
pub const EXT_METADATA: u8 = 4;

/// Metres of one degree of latitude (mean), for level choice.
pub const METRES_PER_DEGREE: f64 = 111_132.954;

/// What a tile needs besides the surface.
pub struct TileRequest<'a> {
    /// The tile.
    pub tile: TileId,
    /// Oct-encoded vertex normals wanted.
    pub normals: bool,
    /// The metadata extension's JSON, when wanted.
    pub metadata: Option<&'a serde_json::Value>,
}

/// A built tile and what was measured on it.
#[derive(Clone, Debug)]
pub struct MeshTile {
    /// The quantized-mesh bytes, gzip-compressed ([`crate::gzip`]): what clients get (they
    /// all accept gzip but the rare one, for which [`MeshTile::bytes`] unpacks them). Kept
    /// compressed alone, so a kept tile costs its gzip's bytes, half its bytes or less.
    pub gzipped: Vec<u8>,
    /// The repository level the vertex heights come from (the finest one used).
    pub level: u8,
    /// Metres between consecutive quantized heights.
    pub height_step: f64,
    /// Largest |mesh − the repository level sampled| over every grid point and every sample of
    /// that level inside the tile's triangles whose vertices hold data, metres (heights before
    /// quantization; [`mesh_cut`]); at `maxzoom` that level is the finest.
    pub deviation: f64,
    /// Triangles whose error is over [`triangulation_threshold`] (the grid's finest, which
    /// cannot be split further).
    pub over_threshold: usize,
    /// Vertices whose height fell outside the header's range and were clamped to it.
    pub clamped: u64,
}

impl MeshTile {
    /// The quantized-mesh bytes, not compressed.
    pub fn bytes(&self) -> Vec<u8> {
        use std::io::Read;
        let mut out = Vec::new();
        flate2::read::GzDecoder::new(&self.gzipped[..])
            .read_to_end(&mut out)
            .expect("a gzip made in memory unpacks");
        out
    }
}

/// The first geographic level whose vertices are no farther apart than the data's finest
/// spacing.
pub fn max_zoom(place: &Placement) -> u8 {
    let ratio = 180.0 * METRES_PER_DEGREE / (f64::from(GRID) * place.spacing_m());
    (ratio.log2().ceil().max(0.0) as u8).min(crate::schemes::MAX_ZOOM)
}

/// The height range every tile's header states, from the smallest and largest height the
/// repository's records hold (`None`: no record): widened by an eighth of its span (at least
/// 8 m) each way for the heights of unstored leaves between them, 0 m included (vertices
/// without data), rounded outwards to whole metres (the header's f32 holds them exactly). A
/// height that still falls outside is clamped and counted ([`MeshTile::clamped`]).
pub fn height_range(records: Option<(f64, f64)>) -> (f64, f64) {
    let (lo, hi) = records.unwrap_or((0.0, 0.0));
    let pad = (0.125 * (hi - lo)).max(8.0);
    let (lo, hi) = ((lo - pad).min(0.0), (hi + pad).max(0.0));
    (lo.floor(), hi.ceil())
}

/// The level index ([`Surface::levels`]) the vertices of a level-`z` tile sample: the coarsest
/// whose spacing is no larger than theirs.
pub fn coarsen_at(place: &Placement, z: u8) -> usize {
    let cell_deg = 180.0 / f64::from(1u32 << z) / f64::from(GRID);
    coarsen_for(place.spacing_m(), cell_deg * METRES_PER_DEGREE)
}

/// Latitude and longitude of grid position `(i, j)` of tile `t`, from the global grid index
/// so that neighbours compute the same bits.
pub fn vertex_lat_lon(t: TileId, i: u32, j: u32) -> (f64, f64) {
    let g = i64::from(GRID);
    mesh_cut::grid_lat_lon(
        t.z,
        i64::from(t.x) * g + i64::from(i),
        i64::from(t.y) * g + i64::from(j),
    )
}

/// The height at a lattice position: the surface's, 0 m (the ellipsoid) where there is no
/// data (outside a plane's data, beyond half a sample); and whether there is data.
fn height_at(surface: Option<&Surface>, at: Option<(u8, f64, f64)>, coarsen: usize) -> (f64, bool) {
    surface
        .zip(at)
        .and_then(|(s, (face, x, y))| s.height(face, x, y, coarsen))
        .map_or((0.0, false), |(h, _)| (h, true))
}

/// What [`build`] samples.
pub struct TileHeights<'a> {
    /// The surface, holding the tile's level and coarser ones around its block (`None`: no
    /// block point on the data).
    pub surface: Option<&'a Surface>,
    /// The lattice positions of the tile's block ([`mesh_cut::block_positions`]: the tile and
    /// its eight neighbours, whose data decide its edges).
    pub positions: &'a [Option<(u8, f64, f64)>],
    /// The level index ([`Surface::levels`]) the vertices sample ([`coarsen_at`]).
    pub coarsen: usize,
    /// The header's height range, metres ([`height_range`]).
    pub range: (f64, f64),
    /// Whether to add EGM96's undulation to the heights of vertices with data (an orthometric
    /// repository's tiles for CesiumJS, which draws heights above the ellipsoid).
    pub to_ellipsoid: bool,
}

/// What the block's cut works from besides [`TileHeights`]: made once a tile
/// ([`drawn_heights`], [`mesh_cut::shared::face_boxes`]) or assembled from the tiles around it
/// ([`mesh_cut::shared::Shared`]); the same values either way.
pub struct BlockWork<'a> {
    /// The block points' heights as drawn and whether they hold data ([`drawn_height`]).
    pub heights: &'a [(f64, bool)],
    /// Per face, the box of the block points on it.
    pub boxes: &'a [mesh_cut::shared::FaceBox],
    /// Where placed samples are shared (a whole surface only).
    pub shared: Option<&'a mesh_cut::shared::Shared>,
}

/// The largest triangle error (metres, against the repository level sampled, heights before
/// quantization) the cut of a level-`z` tile allows: CesiumJS's level error less half the
/// height step, so that drawn heights stay within the level error.
pub fn triangulation_threshold(z: u8, height_step: f64) -> f64 {
    crate::schemes::cesium_level_error(z) - 0.5 * height_step
}

/// The height of a block point as drawn (0 m without data), raised onto the ellipsoid where
/// asked so that the cut follows it, and whether it holds data: the point at global grid
/// position `(gx, gy)` of level `z`, lattice position `p`.
pub fn drawn_height(at: &TileHeights<'_>, z: u8, (gx, gy): (i64, i64), p: Position) -> (f64, bool) {
    let (h, data) = height_at(at.surface, p, at.coarsen);
    if !(at.to_ellipsoid && data) {
        return (h, data);
    }
    let (lat, lon) = mesh_cut::grid_lat_lon(z, gx, gy);
    (h + crate::geoid::undulation(lat, lon), true)
}

/// The block's heights as drawn ([`drawn_height`] of every block point), computed here.
pub fn drawn_heights(at: &TileHeights<'_>, t: TileId) -> Vec<(f64, bool)> {
    let (gx0, gy0) = mesh_cut::block_origin(t);
    at.positions
        .iter()
        .enumerate()
        .map(|(k, &p)| {
            let (i, j) = ((k % mesh_cut::SPAN) as i64, (k / mesh_cut::SPAN) as i64);
            drawn_height(at, t.z, (gx0 + i, gy0 + j), p)
        })
        .collect()
}

/// The cut's vertices, numbered in order of first use (as high-water-mark coding needs), and
/// its triangles as those numbers.
fn number_vertices(cut: &mesh_cut::Cut) -> (Vec<(u32, u32)>, Vec<u32>) {
    let n = (GRID + 1) as usize;
    let mut new_of = vec![u32::MAX; n * n];
    let mut order: Vec<(u32, u32)> = Vec::new();
    let mut triangles: Vec<u32> = Vec::with_capacity(3 * cut.triangles.len());
    for &(i, j) in cut.triangles.iter().flatten() {
        let g = j as usize * n + i as usize;
        if new_of[g] == u32::MAX {
            new_of[g] = order.len() as u32;
            order.push((i, j));
        }
        triangles.push(new_of[g]);
    }
    (order, triangles)
}

/// Builds tile `req.tile` from `at`.
pub fn build(
    at: &TileHeights<'_>,
    block: &BlockWork<'_>,
    place: &Placement,
    req: &TileRequest<'_>,
) -> MeshTile {
    let t = req.tile;
    let (lo, hi) = at.range;
    let height_step = (hi - lo) / f64::from(QMAX);
    let heights = block.heights;
    let cut = mesh_cut::cut(&mesh_cut::Block {
        tile: t,
        place,
        surface: at.surface,
        positions: at.positions,
        boxes: block.boxes,
        heights,
        coarsen: at.coarsen,
        threshold: triangulation_threshold(t.z, height_step),
        to_ellipsoid: at.to_ellipsoid,
        shared: block.shared,
    });
    let (order, triangles) = number_vertices(&cut);
    let (vertex_heights, level) = vertex_heights(at, heights, &order);
    let clamped = vertex_heights
        .iter()
        .filter(|h| !(lo..=hi).contains(&h.0))
        .count() as u64;
    let quantize =
        |h: f64| (((h - lo) / (hi - lo)).clamp(0.0, 1.0) * f64::from(QMAX)).round() as u16;
    let grid_q = |k: u32| ((k * QMAX + GRID / 2) / GRID) as u16;
    let us: Vec<u16> = order.iter().map(|&(i, _)| grid_q(i)).collect();
    let vs: Vec<u16> = order.iter().map(|&(_, j)| grid_q(j)).collect();
    let hs: Vec<u16> = vertex_heights.iter().map(|h| quantize(h.0)).collect();
    let decoded_h = |q: u16| lo + f64::from(q) / f64::from(QMAX) * (hi - lo);
    let positions: Vec<[f64; 3]> = order
        .iter()
        .zip(&hs)
        .map(|(&(i, j), &q)| {
            let (lat, lon) = vertex_lat_lon(t, i, j);
            Geodetic::new(lat, lon, decoded_h(q)).to_ecef()
        })
        .collect();
    let edges = edge_lists(&order);
    let mut out = Vec::with_capacity(88 + 6 * us.len() + 2 * triangles.len() + 1024);
    write_header(&mut out, &positions, (lo, hi));
    write_vertices(&mut out, [&us, &vs, &hs]);
    write_indices(&mut out, &triangles, &edges, order.len());
    if req.normals {
        write_normals(&mut out, &positions, &triangles);
    }
    if let Some(meta) = req.metadata {
        write_metadata(&mut out, meta);
    }
    MeshTile {
        gzipped: crate::gzip(&out),
        level: if level == u8::MAX { 0 } else { level },
        height_step,
        deviation: cut.error,
        over_threshold: cut.over,
        clamped,
    }
}

/// The heights of the numbered vertices (from the block's grid heights), and the finest
/// repository level the surface gave any of them (`u8::MAX`: none).
fn vertex_heights(
    at: &TileHeights<'_>,
    heights: &[(f64, bool)],
    order: &[(u32, u32)],
) -> (Vec<(f64, bool)>, u8) {
    let mut level = u8::MAX;
    let vertex_heights = order
        .iter()
        .map(|&(i, j)| {
            let p = at.positions[mesh_cut::block_index(i, j)];
            if let Some((_, l)) = at
                .surface
                .zip(p)
                .and_then(|(s, (f, x, y))| s.height(f, x, y, at.coarsen))
            {
                level = level.min(l);
            }
            heights[mesh_cut::block_index(i, j)]
        })
        .collect();
    (vertex_heights, level)
}

/// The metadata extension: its id, its length, then the JSON's length and the JSON.
fn write_metadata(out: &mut Vec<u8>, meta: &serde_json::Value) {
    let json = serde_json::to_vec(meta).expect("JSON of plain values");
    out.push(EXT_METADATA);
    out.extend_from_slice(&(json.len() as u32 + 4).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(&json);
}

/// The west, south, east and north edge lists: the vertices on each side, in order along it.
fn edge_lists(order: &[(u32, u32)]) -> [Vec<u32>; 4] {
    let side = |on: &dyn Fn((u32, u32)) -> Option<u32>| -> Vec<u32> {
        let mut e: Vec<(u32, u32)> = order
            .iter()
            .enumerate()
            .filter_map(|(k, &p)| on(p).map(|along| (along, k as u32)))
            .collect();
        e.sort_unstable();
        e.into_iter().map(|(_, k)| k).collect()
    };
    [
        side(&|(i, j)| (i == 0).then_some(j)),
        side(&|(i, j)| (j == 0).then_some(i)),
        side(&|(i, j)| (i == GRID).then_some(j)),
        side(&|(i, j)| (j == GRID).then_some(i)),
    ]
}

fn put_f64s(out: &mut Vec<u8>, v: &[f64]) {
    for x in v {
        out.extend_from_slice(&x.to_le_bytes());
    }
}

/// The 88-byte header.
fn write_header(out: &mut Vec<u8>, positions: &[[f64; 3]], (lo, hi): (f64, f64)) {
    let mut min = [f64::INFINITY; 3];
    let mut max = [f64::NEG_INFINITY; 3];
    for p in positions {
        for k in 0..3 {
            min[k] = min[k].min(p[k]);
            max[k] = max[k].max(p[k]);
        }
    }
    let centre: [f64; 3] = std::array::from_fn(|k| 0.5 * (min[k] + max[k]));
    let radius = positions
        .iter()
        .map(|p| distance(*p, centre))
        .fold(0.0, f64::max);
    put_f64s(out, &centre);
    out.extend_from_slice(&(lo as f32).to_le_bytes());
    out.extend_from_slice(&(hi as f32).to_le_bytes());
    put_f64s(out, &centre);
    put_f64s(out, &[radius]);
    put_f64s(out, &horizon_occlusion_point(positions, centre));
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// The horizon occlusion point, ECEF scaled by the ellipsoid's radii (CesiumJS's
/// `EllipsoidalOccluder.computeHorizonCullingPointFromVertices`): a point that is hidden by the
/// ellipsoid only when every vertex is. A tile too large to have one (a hemisphere at z = 0)
/// gets NaN, which CesiumJS's test reads as never hidden.
fn horizon_occlusion_point(positions: &[[f64; 3]], centre: [f64; 3]) -> [f64; 3] {
    let scale = |p: [f64; 3]| [p[0] / A, p[1] / A, p[2] / B];
    let dir = scale(centre);
    let len = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
    if len == 0.0 {
        return [f64::NAN; 3];
    }
    let dir = dir.map(|c| c / len);
    let mut magnitude = 0.0f64;
    for p in positions {
        let s = scale(*p);
        let m2 = s[0] * s[0] + s[1] * s[1] + s[2] * s[2];
        let m = m2.sqrt();
        let d = s.map(|c| c / m);
        let (m2, m) = (m2.max(1.0), m.max(1.0));
        let cos_alpha = d[0] * dir[0] + d[1] * dir[1] + d[2] * dir[2];
        let cross = [
            d[1] * dir[2] - d[2] * dir[1],
            d[2] * dir[0] - d[0] * dir[2],
            d[0] * dir[1] - d[1] * dir[0],
        ];
        let sin_alpha = (cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2]).sqrt();
        let cos_beta = 1.0 / m;
        let sin_beta = (m2 - 1.0).sqrt() * cos_beta;
        let denominator = cos_alpha * cos_beta - sin_alpha * sin_beta;
        if denominator <= 0.0 {
            return [f64::NAN; 3];
        }
        magnitude = magnitude.max(1.0 / denominator);
    }
    dir.map(|c| c * magnitude)
}

/// Zig-zag delta coding of each of u, v, height.
fn write_vertices(out: &mut Vec<u8>, arrays: [&[u16]; 3]) {
    out.extend_from_slice(&(arrays[0].len() as u32).to_le_bytes());
    for a in arrays {
        let mut prev = 0i32;
        for &v in a {
            let d = i32::from(v) - prev;
            prev = i32::from(v);
            let zz = ((d << 1) ^ (d >> 31)) as u16;
            out.extend_from_slice(&zz.to_le_bytes());
        }
    }
}

/// Triangle indices (high-water mark), then the west, south, east and north edge lists; 16-bit
/// indices up to 65 536 vertices, 32-bit (4-byte aligned) beyond.
fn write_indices(out: &mut Vec<u8>, triangles: &[u32], edges: &[Vec<u32>; 4], vertices: usize) {
    let wide = vertices > 65_536;
    let put = |out: &mut Vec<u8>, v: u32| {
        if wide {
            out.extend_from_slice(&v.to_le_bytes());
        } else {
            out.extend_from_slice(&(v as u16).to_le_bytes());
        }
    };
    let align = if wide { 4 } else { 2 };
    while !out.len().is_multiple_of(align) {
        out.push(0);
    }
    out.extend_from_slice(&((triangles.len() / 3) as u32).to_le_bytes());
    let mut highest = 0u32;
    for &k in triangles {
        put(out, highest - k);
        if k == highest {
            highest += 1;
        }
    }
    for e in edges {
        out.extend_from_slice(&(e.len() as u32).to_le_bytes());
        for &k in e {
            put(out, k);
        }
    }
}

/// Extension 1: per vertex, the area-weighted mean of its triangles' normals, oct-encoded.
fn write_normals(out: &mut Vec<u8>, positions: &[[f64; 3]], triangles: &[u32]) {
    let mut sums = vec![[0.0f64; 3]; positions.len()];
    for t in triangles.chunks_exact(3) {
        let [a, b, c] = [t[0], t[1], t[2]].map(|k| positions[k as usize]);
        let (u, v) = (sub(b, a), sub(c, a));
        let n = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        for &k in t {
            for (s, c) in sums[k as usize].iter_mut().zip(n) {
                *s += c;
            }
        }
    }
    out.push(EXT_NORMALS);
    out.extend_from_slice(&(2 * positions.len() as u32).to_le_bytes());
    for (s, p) in sums.iter().zip(positions) {
        // A degenerate neighbourhood (the poles' collapsed rows) takes the radial direction.
        let n = if s.iter().all(|c| *c == 0.0) { *p } else { *s };
        out.extend_from_slice(&oct_encode(n));
    }
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// CesiumJS's `AttributeCompression.octEncode` of a direction, to two bytes.
pub fn oct_encode(v: [f64; 3]) -> [u8; 2] {
    let l1 = v[0].abs() + v[1].abs() + v[2].abs();
    let (mut x, mut y) = (v[0] / l1, v[1] / l1);
    if v[2] < 0.0 {
        let (ox, oy) = (x, y);
        x = (1.0 - oy.abs()) * if ox >= 0.0 { 1.0 } else { -1.0 };
        y = (1.0 - ox.abs()) * if oy >= 0.0 { 1.0 } else { -1.0 };
    }
    let snorm = |c: f64| ((c.clamp(-1.0, 1.0) * 0.5 + 0.5) * 255.0).round() as u8;
    [snorm(x), snorm(y)]
}

/// The child tiles of `t` that `available` lists, as the metadata extension's `available`
/// (one level: ranges in TMS rows, from the south).
pub fn child_availability(t: TileId, available: &Availability) -> serde_json::Value {
    let mut ranges = Vec::new();
    for dy in 0..2 {
        for dx in 0..2 {
            let c = TileId {
                z: t.z + 1,
                x: 2 * t.x + dx,
                y: 2 * t.y + dy,
            };
            if t.z < available.max_zoom() && available.has(c) {
                ranges.push(serde_json::json!({
                    "startX": c.x, "startY": c.y, "endX": c.x, "endY": c.y
                }));
            }
        }
    }
    if ranges.is_empty() {
        return serde_json::json!([]);
    }
    serde_json::json!([ranges])
}

#[cfg(test)]
mod tests {
    use super::{A, B, Geodetic, horizon_occlusion_point, write_indices};

    /// Reads `count` indices of `width` bytes at `at`.
    fn read(bytes: &[u8], at: &mut usize, width: usize, count: usize) -> Vec<u32> {
        let out = (0..count)
            .map(|k| {
                let b = &bytes[*at + k * width..*at + (k + 1) * width];
                b.iter().rev().fold(0u32, |v, &x| (v << 8) | u32::from(x))
            })
            .collect();
        *at += count * width;
        out
    }

    /// CesiumJS reads 32-bit indices when a tile has more than 64 × 1024 vertices (4-byte
    /// aligned), 16-bit up to that: a strip of triangles over `n` vertices, written after a
    /// prefix of 90 bytes, decodes (high-water mark undone) to the same triangles and edges at
    /// 65 536 vertices (16-bit) and 65 537 (32-bit). Tiles of the 65 × 65 grid never reach it.
    #[test]
    fn indices_are_32_bit_above_65_536_vertices() {
        for (n, width) in [(65_536u32, 2usize), (65_537, 4)] {
            let triangles: Vec<u32> = (0..n - 2).flat_map(|i| [i, i + 1, i + 2]).collect();
            let edges = [vec![0, 1], vec![2], vec![], vec![n - 1]];
            let mut out = vec![7u8; 90];
            write_indices(&mut out, &triangles, &edges, n as usize);
            let mut at = 90usize.next_multiple_of(width);
            assert!(out[90..at].iter().all(|&b| b == 0), "padding");
            let count = read(&out, &mut at, 4, 1)[0] as usize;
            assert_eq!(count, triangles.len() / 3);
            let mut highest = 0;
            let decoded: Vec<u32> = read(&out, &mut at, width, 3 * count)
                .into_iter()
                .map(|code| {
                    let k = highest - code;
                    highest += u32::from(code == 0);
                    k
                })
                .collect();
            assert!(decoded == triangles, "{n} vertices: the triangles differ");
            for e in &edges {
                let len = read(&out, &mut at, 4, 1)[0] as usize;
                assert_eq!(&read(&out, &mut at, width, len), e, "{n} vertices");
            }
            assert_eq!(at, out.len(), "{n} vertices: {width}-byte indices");
        }
    }

    /// CesiumJS's own test (`EllipsoidalOccluder.isScaledSpacePointVisible`, in the space where
    /// the ellipsoid is the unit sphere): a point is hidden from the camera when it lies beyond
    /// the camera's horizon plane and inside the cone the sphere fills as seen from the camera.
    fn hidden(point: [f64; 3], camera: [f64; 3]) -> bool {
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let vh2 = dot(camera, camera) - 1.0;
        let vt: [f64; 3] = std::array::from_fn(|k| point[k] - camera[k]);
        let vt_dot_vc = -dot(vt, camera);
        vt_dot_vc > vh2 && vt_dot_vc * vt_dot_vc / dot(vt, vt) > vh2
    }

    /// The horizon occlusion point does what CesiumJS relies on it for: from every camera that
    /// cannot see it, no vertex of the tile can be seen either (else CesiumJS culls a tile that
    /// shows). Tiles from 0.001° to 45° wide, heights from −430 m to 8 850 m, at 500 cameras
    /// each from 10 m to 10 Earth radii up; the test also counts that the point is hidden from
    /// a good share of the cameras, so that it is not passed by a point never hidden.
    #[test]
    fn no_vertex_shows_where_the_horizon_occlusion_point_is_hidden() {
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            seed = seed
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut tiles, mut hidden_views) = (0, 0);
        for size in [0.001f64, 0.01, 0.1, 1.0, 5.0, 22.5, 45.0] {
            for _ in 0..12 {
                let lat0 = -80.0 + next() * (160.0 - size.min(80.0));
                let lon0 = -180.0 + next() * 360.0;
                let positions: Vec<[f64; 3]> = (0..=16 * 16 + 16)
                    .map(|k| {
                        let (i, j) = ((k % 17) as f64 / 16.0, (k / 17) as f64 / 16.0);
                        let h = -430.0 + next() * 9_280.0;
                        Geodetic::new(lat0 + j * size.min(80.0), lon0 + i * size, h).to_ecef()
                    })
                    .collect();
                let mut min = [f64::MAX; 3];
                let mut max = [f64::MIN; 3];
                for p in &positions {
                    for k in 0..3 {
                        min[k] = min[k].min(p[k]);
                        max[k] = max[k].max(p[k]);
                    }
                }
                let centre: [f64; 3] = std::array::from_fn(|k| 0.5 * (min[k] + max[k]));
                let point = horizon_occlusion_point(&positions, centre);
                if point.iter().any(|c| c.is_nan()) {
                    continue; // CesiumJS never culls by a NaN point.
                }
                tiles += 1;
                for _ in 0..500 {
                    let (z, phi) = (2.0 * next() - 1.0, std::f64::consts::TAU * next());
                    let r = (1.0 - z * z).sqrt();
                    let up = 10.0 + (next() * 6.0).exp() * 1.0e4;
                    let lift = |c: f64, radius: f64| c * (radius + up) / radius;
                    let camera = [lift(r * phi.cos(), A), lift(r * phi.sin(), A), lift(z, B)];
                    if !hidden(point, camera) {
                        continue;
                    }
                    hidden_views += 1;
                    for p in &positions {
                        let scaled = [p[0] / A, p[1] / A, p[2] / B];
                        assert!(
                            hidden(scaled, camera),
                            "a {size}° tile at ({lat0:.3}, {lon0:.3}): vertex {p:?} shows from \
                             camera {camera:?} (scaled) while the occlusion point is hidden"
                        );
                    }
                }
            }
        }
        assert!(tiles >= 70, "only {tiles} tiles had an occlusion point");
        assert!(
            hidden_views >= tiles * 100,
            "the point was hidden in only {hidden_views} views"
        );
    }
}
