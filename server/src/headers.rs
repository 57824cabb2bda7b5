//! Request-header checks and cbdam's own response headers, shared by the routes, the tile
//! routes and the CORS layer (which exposes the response headers to scripts).

use axum::http::{HeaderMap, HeaderValue, header};

/// The level of the repository a tile's heights come from (response header).
pub(crate) const LEVEL_HEADER: &str = "cbdam-level";
/// Pixels of a raster tile whose height the encoding had to clamp (response header).
pub(crate) const CLAMPED_HEADER: &str = "cbdam-clamped-pixels";
/// A mesh tile's triangulation error: the largest |mesh − the repository level sampled| at its
/// grid points and that level's samples, metres (response header).
pub(crate) const DEVIATION_HEADER: &str = "cbdam-deviation-m";
/// A mesh tile's triangles over the level's threshold (the grid's finest; response header).
pub(crate) const OVER_THRESHOLD_HEADER: &str = "cbdam-triangles-over-threshold";
/// Vertices of a mesh tile clamped to the header's height range (response header).
pub(crate) const CLAMPED_VERTICES_HEADER: &str = "cbdam-clamped-vertices";

/// Whether `If-None-Match` matches `etag` (weak comparison, as RFC 9110 asks for this header).
pub(crate) fn not_modified(headers: &HeaderMap, etag: &HeaderValue) -> bool {
    let ours = etag.as_bytes();
    headers
        .get_all(header::IF_NONE_MATCH)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .map(str::trim)
        .any(|t| t == "*" || t.strip_prefix("W/").unwrap_or(t).as_bytes() == ours)
}

/// Whether `Accept-Encoding` accepts gzip (`gzip;q=0` refuses it).
pub(crate) fn accepts_gzip(headers: &HeaderMap) -> bool {
    headers
        .get_all(header::ACCEPT_ENCODING)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .any(|e| {
            let mut parts = e.split(';');
            let coding = parts.next().unwrap_or("").trim();
            let refused = parts.any(|p| p.trim().replace(' ', "") == "q=0");
            (coding.eq_ignore_ascii_case("gzip") || coding == "*") && !refused
        })
}
