//! Cross-origin access (`--cors-origin`): parsing the setting and the layer that applies it.
//! Shared by the state (which validates the setting at startup) and the router.

use axum::http::{HeaderName, HeaderValue, Method, header};
use tower_http::cors::{AllowOrigin, CorsLayer};

/// Parses `--cors-origin`: `*` or a comma-separated list of origins.
pub(crate) fn parse_cors_origin(s: &str) -> Result<AllowOrigin, String> {
    if s.trim() == "*" {
        return Ok(AllowOrigin::any());
    }
    let list = s
        .split(',')
        .map(|o| {
            let o = o.trim();
            if o.is_empty() || o.contains('*') {
                return Err(format!("invalid CORS origin {o:?}"));
            }
            HeaderValue::from_str(o).map_err(|_| format!("invalid CORS origin {o:?}"))
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(AllowOrigin::list(list))
}

/// The CORS layer for `origin` (validated by [`parse_cors_origin`] when the state was built).
pub(crate) fn cors_layer(origin: &str) -> CorsLayer {
    // `AppState::new` validated the origin.
    let origin = parse_cors_origin(origin).unwrap_or_else(|_| AllowOrigin::any());
    CorsLayer::new()
        .allow_origin(origin)
        .allow_methods([Method::GET, Method::HEAD, Method::POST])
        .allow_headers([
            header::CONTENT_TYPE,
            header::ACCEPT,
            header::RANGE,
            header::IF_NONE_MATCH,
            header::IF_RANGE,
        ])
        // Browsers hide response headers from scripts unless listed here; a client needs
        // these to cache records and read ranges.
        .expose_headers([
            header::ETAG,
            header::CONTENT_RANGE,
            header::ACCEPT_RANGES,
            header::CONTENT_LENGTH,
            HeaderName::from_static(crate::headers::LEVEL_HEADER),
            HeaderName::from_static(crate::headers::CLAMPED_HEADER),
            HeaderName::from_static(crate::headers::DEVIATION_HEADER),
            HeaderName::from_static(crate::headers::OVER_THRESHOLD_HEADER),
            HeaderName::from_static(crate::headers::CLAMPED_VERTICES_HEADER),
        ])
        .max_age(std::time::Duration::from_secs(86_400))
}
