//! One repository's surface placed on the Earth, answering web-map tile requests and their
//! TileJSON / `layer.json` documents. Built once, then shared: it holds the repository's
//! records; a plane's raster tile decodes only the records within reach of its pixels, while
//! quantized-mesh tiles (whose heights are quantized over the whole repository's range) and
//! planets decode every even level once, on first use.

use std::sync::OnceLock;

use cbdam_codec::geometry::DomainKind;
use cbdam_codec::hierarchy::Encoded;
use cbdam_codec::quant::QuantPlan;
use cbdam_codec::repository::{RepositoryHead, VerticalDatum};
use serde_json::{Value, json};

use crate::TilesError;
use crate::place::Placement;
use crate::quantized_mesh::{self, MeshTile, TileRequest};
use crate::raster::{self, Encoding, PixelPlan, RasterTile};
use crate::schemes::{MERCATOR_MAX_LAT, Scheme, TileId, cesium_level_error};
use crate::surface::{RecordIndex, Surface};

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
    mesh_max_zoom: u8,
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
        Ok(Tiler {
            mesh_max_zoom: quantized_mesh::max_zoom(&place),
            index: RecordIndex::of(&encoded),
            encoded,
            plan: *head.plan(),
            surface: OnceLock::new(),
            place,
            bounds,
            max_error: head.plan().max_error(),
            datum,
        })
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
        raster::max_zoom(&self.place, tile)
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

    /// Raster tile `z/x/y` (Web Mercator, y from the north).
    pub fn raster(
        &self,
        (z, x, y): (u32, u32, u32),
        tile: u32,
        encoding: Encoding,
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
        let planar = self.encoded.params.domain.kind() == DomainKind::Planar;
        match pixels.lattice_rect() {
            // A plane: only the records within reach of the tile's pixels.
            Some(rect) if planar && self.surface.get().is_none() => {
                let surface = Surface::decode_window(
                    &self.encoded,
                    &self.index,
                    &self.plan,
                    rect,
                    pixels.coarsen,
                )
                .map_err(|e| TilesError::Internal(format!("decoding tile {z}/{x}/{y}: {e}")))?;
                raster::render_plan(&surface, &pixels, tile, encoding)
            }
            _ => raster::render_plan(self.surface()?, &pixels, tile, encoding),
        }
    }

    /// Quantized-mesh tile `z/x/y` (geographic TMS, y from the south).
    pub fn mesh(
        &self,
        (z, x, y): (u32, u32, u32),
        normals: bool,
        metadata: bool,
    ) -> Result<MeshTile, TilesError> {
        let t = Scheme::Geographic.tile(z, x, y)?;
        // Both root tiles exist whatever the data covers: CesiumJS requests them and upsamples
        // the levels below from them where nothing finer is available.
        if t.z > self.mesh_max_zoom || (t.z > 0 && !Scheme::Geographic.meets(t, self.bounds)) {
            return Err(TilesError::OutsideData(format!(
                "tile {z}/{x}/{y} is not available (bounds {:?}, levels 0…{})",
                self.bounds, self.mesh_max_zoom
            )));
        }
        let surface = self.surface()?;
        let meta = metadata.then(|| self.mesh_metadata(surface, t));
        Ok(quantized_mesh::build(
            surface,
            &self.place,
            &TileRequest {
                tile: t,
                normals,
                metadata: meta.as_ref(),
            },
        ))
    }

    /// The metadata extension of tile `t`: its children's availability and the error bound.
    fn mesh_metadata(&self, surface: &Surface, t: TileId) -> Value {
        let (lo, hi) = quantized_mesh::height_range(surface);
        let step = (hi - lo) / f64::from(quantized_mesh::QMAX);
        json!({
            "available": quantized_mesh::child_availability(t, self.bounds, self.mesh_max_zoom),
            "cbdam": {
                "vertex_bound_m": self.max_error + 0.5 * step,
                "repository_max_error_m": self.max_error,
                "height_step_m": step,
                "cesium_level_error_m": cesium_level_error(t.z),
            },
        })
    }

    /// `layer.json` of the quantized-mesh tiles (decodes the whole surface: it states the
    /// height step of the whole repository's range).
    pub fn layer_json(&self, name: &str) -> Result<Value, TilesError> {
        let available: Vec<Value> = (0..=self.mesh_max_zoom)
            .map(|z| match Scheme::Geographic.range(z, self.bounds) {
                _ if z == 0 => json!([{"startX": 0, "startY": 0, "endX": 1, "endY": 0}]),
                Some((x0, y0, x1, y1)) => {
                    json!([{"startX": x0, "startY": y0, "endX": x1, "endY": y1}])
                }
                None => json!([]),
            })
            .collect();
        let (lo, hi) = quantized_mesh::height_range(self.surface()?);
        let step = (hi - lo) / f64::from(quantized_mesh::QMAX);
        Ok(json!({
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
            "attribution": "",
            "cbdam": {
                "vertex_bound_m": self.max_error + 0.5 * step,
                "vertex_bound": "every vertex of a level-maxzoom tile is within this of the \
                    repository's finest level (bilinear between its samples); coarser levels \
                    take their vertices from coarser repository levels",
                "repository_max_error_m": self.max_error,
                "height_step_m": step,
                "height_range_m": [lo, hi],
                "grid": quantized_mesh::GRID,
                "height_datum": self.datum.code(),
                "height_datum_note": "heights are the repository's own (orthometric for DEMs \
                    given above sea level); CesiumJS draws them above the WGS84 ellipsoid. No \
                    geoid (EGM96) correction is applied: expect offsets of up to about ±100 m \
                    against ellipsoidal imagery and 3D tiles.",
            },
        }))
    }

    /// TileJSON 3.0 of the raster tiles; `tiles` is the URL template to put in it.
    pub fn tilejson(&self, name: &str, encoding: Encoding, tile: u32, tiles: &str) -> Value {
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
        json!({
            "tilejson": "3.0.0",
            "name": name,
            "description": format!("cbdam repository {name} as {} elevation tiles",
                                   encoding.maplibre_name()),
            "scheme": "xyz",
            "tiles": [tiles],
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
        })
    }
}
