//! One repository's surface placed on the Earth, answering web-map tile requests and their
//! TileJSON / `layer.json` documents. Built once, then shared: it holds the repository's
//! records and which quantized-mesh tiles exist ([`Availability`]); each tile decodes only
//! the records within reach of its pixels or vertices (a plane's window, a planet's face
//! windows). An exporter that makes every tile decodes every even level once instead
//! ([`Tiler::surface`]), to the same samples.

use std::sync::{Arc, OnceLock};

use cbdam_codec::geometry::DomainKind;
use cbdam_codec::hierarchy::Encoded;
use cbdam_codec::quant::QuantPlan;
use cbdam_codec::repository::{RepositoryHead, VerticalDatum};
use serde_json::{Value, json};

use crate::TilesError;
use crate::bounded::Bounded;
use crate::coverage::Availability;
use crate::geoid;
use crate::mesh_cut::shared::{FaceBox, Position, Shared, face_boxes};
use crate::place::Placement;
use crate::quantized_mesh::{self, BlockWork, MeshTile, TileHeights, TileRequest};
use crate::raster::{self, Encoding, PixelPlan, RasterTile};
use crate::raster_image::ImageFormat;
use crate::schemes::{MERCATOR_MAX_LAT, Scheme, TileId, cesium_level_error};
use crate::surface::{RecordIndex, Surface};
use crate::windows::{SharedWindows, WINDOW_CACHE_BYTES};

/// Raster tile sizes served, pixels (`?tile=`): 512 by default.
pub const TILE_SIZES: [u32; 2] = [256, 512];

/// A repository ready to be cut into tiles.
#[derive(Debug)]
pub struct Tiler {
    encoded: Encoded,
    index: RecordIndex,
    plan: QuantPlan,
    /// Every even level, decoded on first use.
    surface: OnceLock<Result<Surface, String>>,
    place: Placement,
    bounds: [f64; 4],
    /// The repository's guaranteed L∞ bound, metres.
    max_error: f64,
    datum: VerticalDatum,
    /// A planet's largest resampling distance from its inputs, metres (its provenance).
    resampling_max: Option<f64>,
    mesh_max_zoom: u8,
    /// The header height range of every quantized-mesh tile, metres.
    mesh_range: (f64, f64),
    /// The quantized-mesh tiles that exist, level by level.
    available: Availability,
    /// Work neighbouring mesh tiles share (`None`: each tile works alone, for comparisons).
    shared: Option<Shared>,
    /// Mesh tiles made, by tile and extensions, within [`MESH_CACHE_BYTES`].
    meshes: Bounded<(TileId, bool, bool), MeshTile>,
    /// Windows decoded for groups of cold mesh tiles, shared between them.
    windows: SharedWindows,
    /// Whether a tile may wait for the whole surface instead of decoding a window (where the
    /// whole is small).
    whole_ok: bool,
    /// The deepest level an export writes ([`Tiler::limit_zoom`]), below the formats' own.
    zoom_cap: Option<u8>,
}

/// Mesh tiles share a window by groups of `2^GROUP_SHIFT` × `2^GROUP_SHIFT` tiles of a level.
pub const GROUP_SHIFT: u32 = 2;
/// A surface of at most this many samples is decoded whole rather than by windows (when the
/// whole is allowed: [`Tiler::with_memory`]); decoding it costs about as much as a few windows.
pub const SMALL_WHOLE_SAMPLES: u64 = 1 << 22;

/// Bytes of made mesh tiles a tiler keeps (a tile asked for again is not made again).
pub const MESH_CACHE_BYTES: usize = 16 << 20;

/// The heights a tile samples: the whole surface, a window decoded for it, or none (no pixel
/// or vertex on the data).
enum Held<'a> {
    Whole(&'a Surface),
    // Boxed: a surface holds the codec's parameters (with their per-level quantizers, some
    // hundreds of bytes), the other variants a pointer.
    Window(Box<Surface>),
    Shared(Arc<Surface>),
    Nothing,
}

impl Held<'_> {
    fn get(&self) -> Option<&Surface> {
        match self {
            Held::Whole(s) => Some(s),
            Held::Window(s) => Some(s),
            Held::Shared(s) => Some(s),
            Held::Nothing => None,
        }
    }
}

impl Tiler {
    /// Whether `head`'s repository can be tiled at all (CRS, kind), without decoding it.
    pub fn check(head: &RepositoryHead) -> Result<(), TilesError> {
        Placement::of(head).map(|_| ())
    }

    /// Places `encoded` (the hierarchy of `head`'s repository); decodes nothing yet.
    pub fn new(head: &RepositoryHead, encoded: Encoded) -> Result<Tiler, TilesError> {
        let place = Placement::of(head)?;
        let bounds = place.bounds();
        let datum = head
            .provenance()
            .map_or(VerticalDatum::Unknown, |p| p.vertical_datum);
        let plan = *head.plan();
        let mesh_max_zoom = quantized_mesh::max_zoom(&place);
        let index = RecordIndex::of(&encoded);
        let available = Availability::of(
            &encoded.params.domain,
            &place,
            index.ids(),
            mesh_max_zoom,
            |z| quantized_mesh::coarsen_at(&place, z),
        );
        let surface = OnceLock::new();
        let units = encoded.records.iter().map(|r| (r.min, r.max));
        let records = units.reduce(|a, b| (a.0.min(b.0), a.1.max(b.1)));
        let records = match records {
            Some((lo, hi)) => Some((plan.metres(lo), plan.metres(hi))),
            // No record: only the roots' predictions, whatever their size; decode them.
            None => {
                let decoded = Surface::decode(&encoded, &plan)
                    .map_err(|e| TilesError::Internal(format!("decoding the repository: {e}")));
                let range = decoded.as_ref().ok().and_then(Surface::range);
                let _ = surface.set(decoded.map_err(|e| e.to_string()));
                range
            }
        };
        Ok(Tiler {
            mesh_max_zoom,
            mesh_range: quantized_mesh::height_range(match datum {
                // EGM96 is added to the heights: the range takes its extremes.
                VerticalDatum::Orthometric => {
                    let (n_lo, n_hi) = geoid::range();
                    Some(records.map_or((n_lo, n_hi), |(lo, hi)| (lo + n_lo, hi + n_hi)))
                }
                _ => records,
            }),
            available,
            index,
            encoded,
            plan,
            surface,
            place,
            bounds,
            max_error: head.plan().max_error(),
            datum,
            resampling_max: head.provenance().map(|p| p.resampling_max),
            shared: Some(Shared::default()),
            meshes: Bounded::new(MESH_CACHE_BYTES),
            windows: SharedWindows::new(WINDOW_CACHE_BYTES),
            whole_ok: false,
            zoom_cap: None,
        })
    }

    /// The same tiler keeping at most `window_bytes` of decoded windows, and, with
    /// `whole_surface`, letting tiles wait for the whole surface where it is small (at most
    /// [`SMALL_WHOLE_SAMPLES`]). The tiles are
    /// the same bytes either way.
    pub fn with_memory(mut self, window_bytes: usize, whole_surface: bool) -> Tiler {
        self.windows = SharedWindows::new(window_bytes);
        self.whole_ok = whole_surface;
        self
    }

    /// The windows decoded for cold mesh tiles (how many, and the bytes held).
    pub fn windows(&self) -> &SharedWindows {
        &self.windows
    }

    /// The same tiler making each mesh tile alone: no work shared between neighbours, no tile
    /// kept. Its tiles are the same bytes, made several times slower (for comparisons).
    pub fn without_sharing(mut self) -> Tiler {
        self.shared = None;
        self.meshes = Bounded::new(0);
        self
    }

    /// Narrows the tiles to those meeting `bbox` (west, south, east, north, degrees): the
    /// bounds become the part of the data's inside it, `available` (and the children each
    /// tile's metadata lists) only the tiles meeting it. Refuses a box that misses the data.
    pub fn restrict_to(&mut self, bbox: [f64; 4]) -> Result<(), TilesError> {
        let b = self.bounds;
        let cut = [
            b[0].max(bbox[0]),
            b[1].max(bbox[1]),
            b[2].min(bbox[2]),
            b[3].min(bbox[3]),
        ];
        if cut[0] >= cut[2] || cut[1] >= cut[3] {
            return Err(TilesError::OutsideData(format!(
                "the box {bbox:?} (west, south, east, north) does not meet the data, which \
                 lies within {b:?}"
            )));
        }
        self.bounds = cut;
        self.available = self.available.within(cut);
        // Tiles already made list children of the old `available`.
        self.meshes.clear();
        Ok(())
    }

    /// Tiles down to level `max` only (an export's `--max-zoom`): `maxzoom`, `available` and
    /// the children each mesh tile's metadata lists stop there, so a viewer asks for no tile
    /// past it; the documents then give the level where their bounds hold as `finest_zoom`.
    pub fn limit_zoom(&mut self, max: u8) {
        self.zoom_cap = Some(max);
        if max < self.mesh_max_zoom {
            self.mesh_max_zoom = max;
            self.available = self.available.up_to(max);
            // Tiles already made list children past `max`.
            self.meshes.clear();
        }
    }

    /// Says in `doc`'s `cbdam` fields that its `maxzoom`, `max`, is short of `finest`, where
    /// the stated bounds hold ([`Tiler::limit_zoom`]), if it is.
    fn note_cut(doc: &mut Value, max: u8, finest: u8) {
        if max < finest {
            doc["cbdam"]["finest_zoom"] = json!(finest);
            doc["cbdam"]["finest_zoom_note"] = json!(
                "maxzoom was lowered (--max-zoom): the bounds stated for level-maxzoom tiles \
                 hold at finest_zoom, whose tiles were not written; the tiles down to maxzoom \
                 take coarser repository levels"
            );
        }
    }

    /// The quantized-mesh tiles that exist.
    pub fn available(&self) -> &Availability {
        &self.available
    }

    /// The heights around the lattice positions `at` for level index `coarsen` and coarser:
    /// the whole surface when it is decoded (or worth waiting for: [`Self::whole_for`]), else a
    /// window of it (a plane's rectangle around the points on the data, clipped to it; a
    /// planet's face boxes).
    fn held(&self, at: &[Position], coarsen: usize) -> Result<Held<'_>, String> {
        if let Some(whole) = self.surface.get() {
            return whole.as_ref().map(Held::Whole).map_err(Clone::clone);
        }
        let domain = self.encoded.params.domain;
        let (w, h) = domain.data().size();
        let (xmax, ymax) = (w as f64 - 0.5, h as f64 - 0.5);
        let planar = domain.kind() == DomainKind::Planar;
        let on_data = |p: &&(u8, f64, f64)| {
            !planar || (-0.5..=xmax).contains(&p.1) && (-0.5..=ymax).contains(&p.2)
        };
        let boxes = face_boxes_of(at.iter().flatten().filter(on_data));
        if boxes.is_empty() {
            return Ok(Held::Nothing);
        }
        if self.whole_for() {
            return self.whole().map(Held::Whole);
        }
        self.decode_boxes(&boxes, coarsen)
            .map(|s| Held::Window(Box::new(s)))
    }

    /// The heights mesh tile `t` (its block's lattice positions `at`) samples: as
    /// [`Self::held`], but a window is its group's ([`GROUP_SHIFT`]), decoded once for all the
    /// group's tiles and kept ([`SharedWindows`]).
    fn mesh_held(&self, t: TileId, at: &[Position], coarsen: usize) -> Result<Held<'_>, String> {
        let Some(shared) = self
            .shared
            .as_ref()
            .filter(|_| self.surface.get().is_none())
        else {
            return self.held(at, coarsen);
        };
        let domain = self.encoded.params.domain;
        let (w, h) = domain.data().size();
        let (xmax, ymax) = (w as f64 - 0.5, h as f64 - 0.5);
        let planar = domain.kind() == DomainKind::Planar;
        let on_data = |p: &(u8, f64, f64)| {
            !planar || (-0.5..=xmax).contains(&p.1) && (-0.5..=ymax).contains(&p.2)
        };
        if !at.iter().flatten().any(on_data) {
            return Ok(Held::Nothing);
        }
        if self.whole_for() {
            return self.whole().map(Held::Whole);
        }
        let s = GROUP_SHIFT;
        let (gx, gy) = (t.x >> s, t.y >> s);
        let last = |g: u32, tiles: i64| (i64::from(g + 1) << s).min(tiles) - 1;
        let xs = (i64::from(gx) << s, last(gx, 2i64 << t.z));
        let ys = (i64::from(gy) << s, last(gy, 1i64 << t.z));
        let key = (t.z, gx, gy, coarsen);
        let window = self.windows.get_or_decode(key, || {
            let boxes = shared.group_boxes(&self.place, t.z, xs, ys);
            let window = self.decode_boxes(&boxes, coarsen)?;
            let bytes = window.bytes();
            Ok((window, bytes))
        })?;
        Ok(Held::Shared(window))
    }

    /// Whether a tile had better wait for the whole surface than decode a window: when
    /// allowed ([`Self::with_memory`]), for a small surface (its decode costs about as much as a
    /// few windows). A large one is not waited for, even where a window is a large part of it:
    /// the whole decode runs on one thread, the windows of different groups on all of them.
    fn whole_for(&self) -> bool {
        self.whole_ok && Surface::samples(&self.encoded.params.domain) <= SMALL_WHOLE_SAMPLES
    }

    /// The whole surface, decoded by the first caller (the others wait for it).
    fn whole(&self) -> Result<&Surface, String> {
        self.surface().map_err(|e| e.to_string())
    }

    /// The levels of index `coarsen` and coarser over `boxes`: a plane's window over their
    /// box (clipped to the data), a planet's face windows.
    fn decode_boxes(&self, boxes: &[FaceBox], coarsen: usize) -> Result<Surface, String> {
        let domain = self.encoded.params.domain;
        let (e, i, p) = (&self.encoded, &self.index, &self.plan);
        if domain.kind() != DomainKind::Planar {
            let corners: Vec<(u8, f64, f64)> = (boxes.iter())
                .flat_map(|&(f, b)| [(f, b.0, b.1), (f, b.2, b.3)])
                .collect();
            return Surface::decode_faces(e, i, p, &corners, coarsen).map_err(|e| e.to_string());
        }
        let (w, h) = domain.data().size();
        let b = (boxes.iter().map(|b| b.1))
            .reduce(|a, b| (a.0.min(b.0), a.1.min(b.1), a.2.max(b.2), a.3.max(b.3)))
            .ok_or("an empty window")?;
        let lo = |v: f64| v.floor().max(0.0) as i64;
        let hi = |v: f64, m: usize| (v.ceil() as i64).min(m as i64 - 1);
        let rect = (lo(b.0), lo(b.1), hi(b.2, w), hi(b.3, h));
        Surface::decode_window(e, i, p, rect, coarsen).map_err(|e| e.to_string())
    }

    /// West, south, east, north of the data, degrees.
    pub fn bounds(&self) -> [f64; 4] {
        self.bounds
    }

    /// The whole surface, every even level (decoded on the first call).
    pub fn surface(&self) -> Result<&Surface, TilesError> {
        self.surface
            .get_or_init(|| {
                Surface::decode(&self.encoded, &self.plan)
                    .map_err(|e| format!("decoding the repository: {e}"))
            })
            .as_ref()
            .map_err(|m| TilesError::Internal(m.clone()))
    }

    /// The raster tiles' deepest zoom for `tile`-pixel tiles.
    pub fn raster_max_zoom(&self, tile: u32) -> u8 {
        let max = raster::max_zoom(&self.place, tile);
        self.zoom_cap.map_or(max, |cap| cap.min(max))
    }

    /// The quantized-mesh tiles' deepest level.
    pub fn mesh_max_zoom(&self) -> u8 {
        self.mesh_max_zoom
    }

    /// Checks a raster tile size.
    pub fn tile_size(tile: Option<u32>) -> Result<u32, TilesError> {
        match tile {
            None => Ok(512),
            Some(t) if TILE_SIZES.contains(&t) => Ok(t),
            Some(t) => Err(TilesError::BadTile(format!(
                "tile size {t}: raster tiles are 256 or 512 pixels"
            ))),
        }
    }

    /// Raster tile `z/x/y` (Web Mercator, y from the north), heights as `encoding` writes
    /// them, in an image file of `format`.
    pub fn raster(
        &self,
        (z, x, y): (u32, u32, u32),
        tile: u32,
        (encoding, format): (Encoding, ImageFormat),
    ) -> Result<RasterTile, TilesError> {
        let t = Scheme::WebMercator.tile(z, x, y)?;
        let max = self.raster_max_zoom(tile);
        if t.z > max || !Scheme::WebMercator.meets(t, self.bounds) {
            return Err(TilesError::OutsideData(format!(
                "tile {z}/{x}/{y} is outside the data (bounds {:?}, zoom 0…{max})",
                self.bounds
            )));
        }
        let pixels = PixelPlan::of(&self.place, t, tile);
        // Only the records within reach of the tile's pixels.
        let held = self
            .held(&pixels.positions, pixels.coarsen)
            .map_err(|e| TilesError::Internal(format!("decoding tile {z}/{x}/{y}: {e}")))?;
        raster::render_plan(held.get(), &pixels, tile, (encoding, format))
    }

    /// Quantized-mesh tile `z/x/y` (geographic TMS, y from the south), with its gzip; a
    /// tile asked for again is the one kept (within [`MESH_CACHE_BYTES`]), not made again.
    pub fn mesh(
        &self,
        (z, x, y): (u32, u32, u32),
        normals: bool,
        metadata: bool,
    ) -> Result<Arc<MeshTile>, TilesError> {
        let t = Scheme::Geographic.tile(z, x, y)?;
        // Both root tiles exist whatever the data covers: CesiumJS requests them and upsamples
        // the levels below from them where nothing finer is available.
        if !self.available.has(t) {
            return Err(TilesError::OutsideData(format!(
                "tile {z}/{x}/{y} is not available: level {z} of this repository has {} tiles \
                 (layer.json lists them; bounds {:?}, levels 0…{})",
                self.available.count(t.z),
                self.bounds,
                self.mesh_max_zoom
            )));
        }
        let key = (t, normals, metadata);
        if let Some(made) = self.meshes.get(&key) {
            return Ok(made);
        }
        let made = self.make_mesh(t, normals, metadata)?;
        let bytes = made.gzipped.len() + size_of::<MeshTile>();
        Ok(self.meshes.insert(key, Arc::new(made), bytes))
    }

    /// Makes mesh tile `t` (its block's work shared with its neighbours' where it can be).
    fn make_mesh(&self, t: TileId, normals: bool, metadata: bool) -> Result<MeshTile, TilesError> {
        let (positions, boxes) = match &self.shared {
            Some(shared) => shared.block_positions(&self.place, t),
            None => {
                let p = crate::mesh_cut::block_positions(&self.place, t);
                let boxes = face_boxes(&p);
                (p, boxes)
            }
        };
        let coarsen = quantized_mesh::coarsen_at(&self.place, t.z);
        let held = self.mesh_held(t, &positions, coarsen).map_err(|e| {
            TilesError::Internal(format!("decoding tile {}/{}/{}: {e}", t.z, t.x, t.y))
        })?;
        let meta = metadata.then(|| self.mesh_metadata(t));
        let at = TileHeights {
            surface: held.get(),
            positions: &positions,
            coarsen,
            range: self.mesh_range,
            to_ellipsoid: self.datum == VerticalDatum::Orthometric,
        };
        let heights = match &self.shared {
            Some(shared) => shared.block_heights(t, &positions, |gx, gy, p| {
                quantized_mesh::drawn_height(&at, t.z, (gx, gy), p)
            }),
            None => quantized_mesh::drawn_heights(&at, t),
        };
        let block = BlockWork {
            heights: &heights,
            boxes: &boxes,
            // Chunks of placed samples only from the whole surface (a window's could reach
            // past it).
            shared: self
                .shared
                .as_ref()
                .filter(|_| matches!(held, Held::Whole(_))),
        };
        let req = TileRequest {
            tile: t,
            normals,
            metadata: meta.as_ref(),
        };
        Ok(quantized_mesh::build(&at, &block, &self.place, &req))
    }

    /// The bound every vertex of a `maxzoom` mesh tile keeps, metres: ε, half the height step,
    /// and EGM96's interpolation where heights are converted.
    fn vertex_bound(&self) -> f64 {
        let (lo, hi) = self.mesh_range;
        let step = (hi - lo) / f64::from(quantized_mesh::QMAX);
        let geoid = match self.datum {
            VerticalDatum::Orthometric => geoid::ERROR_M,
            _ => 0.0,
        };
        self.max_error + 0.5 * step + geoid
    }

    /// The datum of the mesh tiles' heights, and how they were made.
    fn mesh_datum(&self) -> (&'static str, &'static str) {
        match self.datum {
            VerticalDatum::Orthometric => (
                "ellipsoidal",
                "heights above the WGS84 ellipsoid, as CesiumJS draws them: the repository's \
                 orthometric heights plus EGM96's geoid undulation (a 1° grid from NGA's \
                 spherical harmonics, within geoid_error_m of them)",
            ),
            VerticalDatum::Ellipsoidal => (
                "ellipsoidal",
                "heights above the WGS84 ellipsoid, as stored in the repository",
            ),
            VerticalDatum::Unknown => (
                "unknown",
                "heights as stored: the repository does not record its vertical datum, so no \
                 geoid correction is applied; if they are above sea level, CesiumJS draws them \
                 off the ellipsoid by the geoid undulation (up to about ±100 m)",
            ),
        }
    }

    /// The metadata extension of tile `t`: its children's availability and the error bound.
    fn mesh_metadata(&self, t: TileId) -> Value {
        let (lo, hi) = self.mesh_range;
        let step = (hi - lo) / f64::from(quantized_mesh::QMAX);
        json!({
            "available": quantized_mesh::child_availability(t, &self.available),
            "cbdam": {
                "vertex_bound_m": self.vertex_bound(),
                "repository_max_error_m": self.max_error,
                "height_step_m": step,
                "cesium_level_error_m": cesium_level_error(t.z),
                "triangulation_threshold_m":
                    quantized_mesh::triangulation_threshold(t.z, step),
            },
        })
    }

    /// The `attribution` of `layer.json` and the TileJSON: `given` (`--attribution`), else what
    /// the repository records of itself (it holds no credit for the data it was built from).
    pub fn attribution(&self, name: &str, given: Option<&str>) -> String {
        if let Some(text) = given {
            return text.to_string();
        }
        // Millimetres at most: the bound is a float of the quantizer's step.
        let metres = |v: f64| {
            let s = format!("{v:.3}");
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        };
        let bound = metres(self.max_error);
        match self.resampling_max {
            Some(r) => format!(
                "cbdam planet {name} (heights within {bound} m of its lattice, resampled within \
                 {} m of its inputs)",
                metres(r)
            ),
            None => format!("cbdam repository {name} (heights within {bound} m of its input)"),
        }
    }

    /// `layer.json` of the quantized-mesh tiles; `attribution` as [`Tiler::attribution`] takes it.
    pub fn layer_json(&self, name: &str, attribution: Option<&str>) -> Result<Value, TilesError> {
        let available: Vec<Value> = (0..=self.mesh_max_zoom)
            .map(|z| {
                let ranges = self.available.ranges(z).into_iter();
                ranges
                    .map(|(x0, y0, x1, y1)| {
                        json!({"startX": x0, "startY": y0, "endX": x1, "endY": y1})
                    })
                    .collect()
            })
            .collect();
        let (lo, hi) = self.mesh_range;
        let step = (hi - lo) / f64::from(quantized_mesh::QMAX);
        let mut doc = json!({
            "tilejson": "2.1.0",
            "name": name,
            "description": format!("cbdam repository {name} as quantized-mesh-1.0 terrain"),
            "version": "1.0.0",
            "format": "quantized-mesh-1.0",
            "scheme": "tms",
            "projection": "EPSG:4326",
            "tiles": ["{z}/{x}/{y}.terrain?v={version}"],
            "bounds": self.bounds,
            "minzoom": 0,
            "maxzoom": self.mesh_max_zoom,
            "available": available,
            // CesiumJS reads a tile's metadata extension only with `metadataAvailability`
            // (then it takes availability from the tiles, not from `available`): each tile's
            // metadata lists its children, one level down.
            "metadataAvailability": 1,
            "extensions": ["octvertexnormals", "metadata"],
            "attribution": self.attribution(name, attribution),
            "cbdam": {
                "vertex_bound_m": self.vertex_bound(),
                "vertex_bound": "every vertex of a level-maxzoom tile is within this of the \
                    repository's finest level (bilinear between its samples); coarser levels \
                    take their vertices from coarser repository levels",
                "repository_max_error_m": self.max_error,
                "height_step_m": step,
                "height_range_m": [lo, hi],
                "grid": quantized_mesh::GRID,
                "between_vertex_bound_m": (0..=self.mesh_max_zoom)
                    .map(cesium_level_error)
                    .collect::<Vec<f64>>(),
                "triangulation_threshold_m": (0..=self.mesh_max_zoom)
                    .map(|z| quantized_mesh::triangulation_threshold(z, step))
                    .collect::<Vec<f64>>(),
                "between_vertex_bound": "per level z: every triangle of a level-z tile is \
                    within triangulation_threshold_m[z] of the repository level it samples at \
                    every grid point and every sample of that level inside it (checked when \
                    the tile is made; a tile's cbdam-deviation-m header gives its own largest), \
                    so with the height step within between_vertex_bound_m[z], CesiumJS's level \
                    error; the grid's finest triangles cannot be split, and the response header \
                    cbdam-triangles-over-threshold counts those over it",
                "height_datum": self.mesh_datum().0,
                "height_datum_note": self.mesh_datum().1,
                "repository_datum": self.datum.code(),
                "geoid_error_m": if self.datum == VerticalDatum::Orthometric {
                    geoid::ERROR_M
                } else {
                    0.0
                },
            },
        });
        let finest = quantized_mesh::max_zoom(&self.place);
        Self::note_cut(&mut doc, self.mesh_max_zoom, finest);
        Ok(doc)
    }

    /// TileJSON 3.0 of the raster tiles; `tiles` is the URL template to put in it, `attribution`
    /// as [`Tiler::attribution`] takes it.
    pub fn tilejson(
        &self,
        name: &str,
        (encoding, tile): (Encoding, u32),
        tiles: &str,
        attribution: Option<&str>,
    ) -> Value {
        let b = self.bounds;
        let bounds = [
            b[0],
            b[1].max(-MERCATOR_MAX_LAT),
            b[2],
            b[3].min(MERCATOR_MAX_LAT),
        ];
        let max = self.raster_max_zoom(tile);
        let step = encoding.step();
        let (lo, hi) = encoding.range();
        let mut doc = json!({
            "tilejson": "3.0.0",
            "name": name,
            "description": format!("cbdam repository {name} as {} elevation tiles",
                                   encoding.maplibre_name()),
            "scheme": "xyz",
            "tiles": [tiles],
            "attribution": self.attribution(name, attribution),
            "bounds": bounds,
            "center": [0.5 * (bounds[0] + bounds[2]), 0.5 * (bounds[1] + bounds[3]),
                       max.saturating_sub(2)],
            "minzoom": 0,
            "maxzoom": max,
            "tileSize": tile,
            "encoding": encoding.maplibre_name(),
            "cbdam": {
                "pixel_bound_m": self.max_error + 0.5 * step,
                "pixel_bound": "every pixel of a level-maxzoom tile is within this of the \
                    repository's finest level, bilinear between its samples, at the pixel \
                    centre; coarser zooms take coarser repository levels",
                "repository_max_error_m": self.max_error,
                "encoding_step_m": step,
                "encoding_range_m": [lo, hi],
                "clamped": "heights outside encoding_range_m are clamped to it; the \
                    cbdam-clamped-pixels response header counts them",
                "nodata": "transparent pixels whose RGB encodes 0 m",
                "height_datum": self.datum.code(),
            },
        });
        Self::note_cut(&mut doc, max, raster::max_zoom(&self.place, tile));
        doc
    }
}

/// Per face, the box of `points`.
fn face_boxes_of<'p>(points: impl Iterator<Item = &'p (u8, f64, f64)>) -> Vec<FaceBox> {
    let mut boxes: Vec<FaceBox> = Vec::new();
    for &(face, x, y) in points {
        match boxes.iter_mut().find(|b| b.0 == face) {
            Some((_, r)) => *r = (r.0.min(x), r.1.min(y), r.2.max(x), r.3.max(y)),
            None => boxes.push((face, (x, y, x, y))),
        }
    }
    boxes
}
