//! Web-map tiles of a served repository (`docs/WEB-MAPS.md`): terrarium and terrain-RGB PNG
//! or lossless WebP with their TileJSON for MapLibre, quantized-mesh-1.0 with its `layer.json` for CesiumJS.
//!
//! The tile maths live in `cbdam-tiles`; this module reads a repository's records once, on the
//! first tile request (through the server's checked reads), keeps its `Tiler` for the server's
//! life, and answers each tile on a blocking thread. The first tiles decode the records within
//! their reach while the whole surface is decoded in the background (when it fits
//! `max_tile_samples`); tiles then read it. The bytes are the same either way.

use std::sync::Arc;

use axum::body::Body;
use axum::extract::rejection::PathRejection;
use axum::extract::{Path, Request, State};
use axum::http::{HeaderMap, HeaderName, HeaderValue, StatusCode, header};
use axum::response::Response;
use cbdam_codec::hierarchy::{Encoded, Record};
use cbdam_tiles::surface::Surface;
use cbdam_tiles::{Encoding, ImageFormat, Tiler, TilesError};

use crate::error::{ApiError, bad_path};
use crate::headers::{
    CLAMPED_HEADER, CLAMPED_VERTICES_HEADER, DEVIATION_HEADER, LEVEL_HEADER, OVER_THRESHOLD_HEADER,
    accepts_gzip, not_modified,
};
use crate::records::{RecordBuffer, RecordError};
use crate::state::{AppState, ServedRepo};

/// Caches revalidate tiles (a file rebuilt under the same name changes them): a 304 is cheap
/// for the network, though the server makes the tile again to compare its ETag.
const REVALIDATE: &str = "no-cache";

fn api_error(e: TilesError) -> ApiError {
    match e {
        TilesError::BadTile(m) => ApiError::BadRequest(m),
        TilesError::OutsideData(m) | TilesError::Unsupported(m) => ApiError::NotFound(m),
        TilesError::Internal(m) => ApiError::Internal(m),
    }
}

fn hv(s: &'static str) -> HeaderValue {
    HeaderValue::from_static(s)
}

fn number(v: impl std::fmt::Display) -> HeaderValue {
    HeaderValue::from_str(&v.to_string()).expect("a number is ASCII")
}

/// The repository's whole hierarchy, every record read and checked as the server reads them.
fn encoded(st: &AppState, r: &ServedRepo) -> Result<Encoded, String> {
    let head = r.repo.head();
    let entries = head.entries();
    let mut records = Vec::with_capacity(entries.len());
    let all: Vec<usize> = (0..entries.len()).collect();
    let mut buf = RecordBuffer::default();
    let read = r.read_records(&all, &mut buf, |i, bytes| {
        let e = &entries[i];
        records.push(Record {
            id: e.id,
            bytes: bytes.to_vec().into(),
            object_error: e.object_error,
            min: e.min,
            max: e.max,
        });
    });
    match read {
        Ok(()) => {}
        Err(RecordError::Read(e)) => return Err(e.to_string()),
        Err(RecordError::Damaged(i, e)) => {
            st.metrics().add_corrupt();
            return Err(format!(
                "the record of diamond {} is damaged: {e}",
                e_id(head, i)
            ));
        }
    }
    Ok(Encoded {
        params: *head.params(),
        roots: head.root_bytes().to_vec(),
        records,
        leaf_error: head.leaf_error(),
    })
}

fn e_id(head: &cbdam_codec::repository::RepositoryHead, i: usize) -> String {
    head.entries()[i].id.to_string()
}

/// The tiler of repository `r`, decoding it on first use (on a blocking thread).
async fn tiler(st: &AppState, r: &Arc<ServedRepo>) -> Result<Arc<Tiler>, ApiError> {
    r.check_unchanged()?;
    if let Some(t) = r.tiles.get() {
        return t.clone().map_err(ApiError::Internal);
    }
    Tiler::check(r.repo.head()).map_err(api_error)?;
    let samples = Surface::samples(&r.repo.head().params().domain);
    let cap = st.config().max_tile_samples;
    // Only a repository without records is decoded whole (tiles decode windows otherwise).
    if samples > cap && r.repo.head().entries().is_empty() {
        return Err(ApiError::NotFound(format!(
            "repository {:?} is too large to serve as web-map tiles: its decoded levels hold \
             {samples} samples, more than this server's limit of {cap}",
            r.name
        )));
    }
    let (st2, r2) = (st.clone(), Arc::clone(r));
    let whole_fits = samples <= cap;
    let built = tokio::task::spawn_blocking(move || {
        r2.tiles
            .get_or_init(|| {
                let encoded = encoded(&st2, &r2)?;
                let cache = usize::try_from(st2.config().tile_cache).unwrap_or(usize::MAX);
                let t = Tiler::new(r2.repo.head(), encoded).map_err(|e| e.to_string())?;
                let t = Arc::new(t.with_memory(cache, whole_fits));
                tracing::info!(repo = %r2.name, "records read for web-map tiles");
                if whole_fits {
                    // Tiles decode windows until the whole surface is there, then read it.
                    let (t2, name) = (Arc::clone(&t), r2.name.clone());
                    tokio::task::spawn_blocking(move || match t2.surface() {
                        Ok(_) => tracing::info!(repo = %name, "surface decoded for web-map tiles"),
                        Err(e) => tracing::warn!(repo = %name, "decoding for tiles: {e}"),
                    });
                }
                Ok(t)
            })
            .clone()
    })
    .await
    .map_err(|e| ApiError::Internal(format!("decoding for tiles: {e}")))?;
    built.map_err(|m| ApiError::Internal(format!("repository {:?}: {m}", r.name)))
}

fn lookup<'a>(st: &'a AppState, name: &str) -> Result<&'a Arc<ServedRepo>, ApiError> {
    st.repo(name)
        .ok_or_else(|| ApiError::NotFound(format!("no repository named {name:?}")))
}

/// `?tile=256|512` of the raster endpoints, and `?format=png|webp` of their TileJSON (other
/// parameters are ignored: clients add their own cache busters).
fn tile_query(req: &Request) -> Result<(Option<u32>, ImageFormat), ApiError> {
    let Some(q) = req.uri().query() else {
        return Ok((None, ImageFormat::Png));
    };
    let (mut tile, mut format) = (None, ImageFormat::Png);
    for pair in q.split('&') {
        if let Some(v) = pair.strip_prefix("tile=") {
            tile = Some(v.parse::<u32>().map_err(|_| {
                ApiError::BadRequest(format!("malformed tile size {v:?} (want 256 or 512)"))
            })?);
        } else if let Some(v) = pair.strip_prefix("format=") {
            format = ImageFormat::parse(v).map_err(api_error)?;
        }
    }
    Ok((tile, format))
}

/// Parses `z`, `x` and `y` (`y` with one of the file extensions `exts`), or 400; returns
/// which extension it had.
fn tile_address<'e>(
    z: &str,
    x: &str,
    y: &str,
    exts: &[&'e str],
) -> Result<((u32, u32, u32), &'e str), ApiError> {
    let bad = || {
        ApiError::BadRequest(format!(
            "malformed tile address {z}/{x}/{y} (want z/x/y{}, non-negative integers)",
            exts.join(" or z/x/y")
        ))
    };
    let (y, ext) = (exts.iter())
        .find_map(|e| y.strip_suffix(e).map(|y| (y, *e)))
        .ok_or_else(bad)?;
    let parse = |s: &str| s.parse::<u32>().map_err(|_| bad());
    Ok(((parse(z)?, parse(x)?, parse(y)?), ext))
}

/// A 200 (or a 304 when `If-None-Match` names it) of `body` under an ETag from its bytes.
fn tile_response(r: &ServedRepo, req: &HeaderMap, mut h: HeaderMap, body: Vec<u8>) -> Response {
    let tag = format!(
        "\"{:08x}-t{:08x}\"",
        r.repo.head().header_crc(),
        crc32fast::hash(&body)
    );
    let etag = HeaderValue::from_str(&tag).expect("ASCII");
    h.insert(header::ETAG, etag.clone());
    h.insert(header::CACHE_CONTROL, hv(REVALIDATE));
    let mut resp = Response::new(Body::empty());
    if not_modified(req, &etag) {
        *resp.status_mut() = StatusCode::NOT_MODIFIED;
    } else {
        *resp.body_mut() = Body::from(body);
    }
    *resp.headers_mut() = h;
    resp
}

fn json_response(r: &ServedRepo, req: &HeaderMap, v: &serde_json::Value) -> Response {
    let mut h = HeaderMap::new();
    h.insert(header::CONTENT_TYPE, hv("application/json"));
    let body = serde_json::to_vec_pretty(v).expect("JSON of plain values");
    tile_response(r, req, h, body)
}

/// `http://HOST` of the request (its `Host` header or HTTP/2 authority; `https` behind a proxy
/// that says `X-Forwarded-Proto: https`), for absolute tile URLs: MapLibre resolves a TileJSON's
/// tile URLs against the page, not the TileJSON. Empty (root-relative URLs) without a host.
fn origin(req: &Request) -> String {
    let host = req
        .headers()
        .get(header::HOST)
        .and_then(|h| h.to_str().ok())
        .map(str::to_string)
        .or_else(|| req.uri().authority().map(|a| a.to_string()));
    let valid = |h: &String| {
        h.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b".-:[]_".contains(&b))
    };
    let proto = match req.headers().get("x-forwarded-proto").map(|v| v.as_bytes()) {
        Some(b"https") => "https",
        _ => "http",
    };
    match host.filter(valid) {
        Some(h) => format!("{proto}://{h}"),
        None => String::new(),
    }
}

/// `GET /v1/repos/{name}/{terrarium|terrain-rgb}/tiles.json[?format=webp]`.
async fn tilejson(
    st: AppState,
    name: String,
    req: Request,
    encoding: Encoding,
    segment: &str,
) -> Result<Response, ApiError> {
    let r = lookup(&st, &name)?;
    let (tile, image) = tile_query(&req)?;
    let tile = Tiler::tile_size(tile).map_err(api_error)?;
    let t = tiler(&st, r).await?;
    let query = if tile == 512 { "" } else { "?tile=256" };
    let template = format!(
        "{}/v1/repos/{name}/{segment}/{{z}}/{{x}}/{{y}}.{}{query}",
        origin(&req),
        image.extension()
    );
    Ok(json_response(
        r,
        req.headers(),
        &t.tilejson(
            &name,
            (encoding, tile),
            &template,
            st.config().attribution.as_deref(),
        ),
    ))
}

/// `GET /v1/repos/{name}/{terrarium|terrain-rgb}/{z}/{x}/{y}.{png|webp}`.
async fn raster(
    st: AppState,
    (name, z, x, y): (String, String, String, String),
    req: Request,
    encoding: Encoding,
) -> Result<Response, ApiError> {
    let r = lookup(&st, &name)?;
    let (zxy, ext) = tile_address(&z, &x, &y, &[".png", ".webp"])?;
    let image = ImageFormat::parse(&ext[1..]).map_err(api_error)?;
    let tile = Tiler::tile_size(tile_query(&req)?.0).map_err(api_error)?;
    let t = tiler(&st, r).await?;
    let made = tokio::task::spawn_blocking(move || t.raster(zxy, tile, (encoding, image)))
        .await
        .map_err(|e| ApiError::Internal(format!("making a tile: {e}")))?
        .map_err(api_error)?;
    let mut h = HeaderMap::new();
    h.insert(header::CONTENT_TYPE, hv(image.media_type()));
    h.insert(HeaderName::from_static(LEVEL_HEADER), number(made.level));
    h.insert(
        HeaderName::from_static(CLAMPED_HEADER),
        number(made.clamped),
    );
    Ok(tile_response(r, req.headers(), h, made.image))
}

/// The extensions an `Accept` header asks for: `(octvertexnormals, metadata)`.
fn extensions(headers: &HeaderMap) -> (bool, bool) {
    let mut wanted = (false, false);
    let items = headers
        .get_all(header::ACCEPT)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','));
    for item in items {
        let mut parts = item.split(';').map(str::trim);
        if !parts
            .next()
            .is_some_and(|m| m.eq_ignore_ascii_case("application/vnd.quantized-mesh"))
        {
            continue;
        }
        for p in parts {
            if let Some(list) = p.strip_prefix("extensions=") {
                for e in list.trim_matches('"').split('-') {
                    wanted.0 |= e == "octvertexnormals";
                    wanted.1 |= e == "metadata";
                }
            }
        }
    }
    wanted
}

/// `GET /v1/repos/{name}/quantized-mesh/layer.json`.
async fn layer_json(
    State(st): State<AppState>,
    path: Result<Path<String>, PathRejection>,
    req: Request,
) -> Result<Response, ApiError> {
    let Path(name) = path.map_err(bad_path)?;
    let r = lookup(&st, &name)?;
    let t = tiler(&st, r).await?;
    let attribution = st.config().attribution.clone();
    let doc = tokio::task::spawn_blocking(move || t.layer_json(&name, attribution.as_deref()))
        .await
        .map_err(|e| ApiError::Internal(format!("decoding for tiles: {e}")))?
        .map_err(api_error)?;
    Ok(json_response(r, req.headers(), &doc))
}

/// `GET /v1/repos/{name}/quantized-mesh/{z}/{x}/{y}.terrain`: gzip-compressed when the client
/// accepts it, extensions as its `Accept` asks.
async fn terrain(
    State(st): State<AppState>,
    path: Result<Path<(String, String, String, String)>, PathRejection>,
    req: Request,
) -> Result<Response, ApiError> {
    let Path((name, z, x, y)) = path.map_err(bad_path)?;
    let r = lookup(&st, &name)?;
    let (zxy, _) = tile_address(&z, &x, &y, &[".terrain"])?;
    let (normals, metadata) = extensions(req.headers());
    let t = tiler(&st, r).await?;
    let gzip = accepts_gzip(req.headers());
    // A kept tile comes with its gzip: nothing is compressed per request.
    let made = tokio::task::spawn_blocking(move || t.mesh(zxy, normals, metadata))
        .await
        .map_err(|e| ApiError::Internal(format!("making a tile: {e}")))?
        .map_err(api_error)?;
    let body = if gzip {
        made.gzipped.clone()
    } else {
        made.bytes()
    };
    let mut h = HeaderMap::new();
    h.insert(header::CONTENT_TYPE, hv("application/vnd.quantized-mesh"));
    h.insert(header::VARY, hv("accept, accept-encoding"));
    if gzip {
        h.insert(header::CONTENT_ENCODING, hv("gzip"));
    }
    h.insert(HeaderName::from_static(LEVEL_HEADER), number(made.level));
    h.insert(
        HeaderName::from_static(DEVIATION_HEADER),
        number(format!("{:.4}", made.deviation)),
    );
    h.insert(
        HeaderName::from_static(CLAMPED_VERTICES_HEADER),
        number(made.clamped),
    );
    h.insert(
        HeaderName::from_static(OVER_THRESHOLD_HEADER),
        number(made.over_threshold),
    );
    Ok(tile_response(r, req.headers(), h, body))
}

type RasterPath = Result<Path<(String, String, String, String)>, PathRejection>;
type NamePath = Result<Path<String>, PathRejection>;

/// The routes of this module.
pub(crate) fn routes(router: axum::Router<AppState>) -> axum::Router<AppState> {
    use axum::routing::get;
    macro_rules! raster_routes {
        ($router:expr, $segment:literal, $encoding:expr) => {
            $router
                .route(
                    concat!("/v1/repos/{name}/", $segment, "/tiles.json"),
                    get(
                        |State(st): State<AppState>, p: NamePath, req: Request| async move {
                            let Path(name) = p.map_err(bad_path)?;
                            tilejson(st, name, req, $encoding, $segment).await
                        },
                    ),
                )
                .route(
                    concat!("/v1/repos/{name}/", $segment, "/{z}/{x}/{y}"),
                    get(
                        |State(st): State<AppState>, p: RasterPath, req: Request| async move {
                            let Path(p) = p.map_err(bad_path)?;
                            raster(st, p, req, $encoding).await
                        },
                    ),
                )
        };
    }
    let router = raster_routes!(router, "terrarium", Encoding::Terrarium);
    let router = raster_routes!(router, "terrain-rgb", Encoding::TerrainRgb);
    router
        .route(
            "/v1/repos/{name}/quantized-mesh/layer.json",
            get(layer_json),
        )
        .route("/v1/repos/{name}/quantized-mesh/{z}/{x}/{y}", get(terrain))
}
