//! The server's two error types: [`ApiError`] is what a request can fail with (it renders as a
//! JSON body), [`ServerError`] is what starting the server can fail with.

use std::path::PathBuf;

use axum::extract::rejection::PathRejection;
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use cbdam_codec::CodecError;

/// Why a request failed. Every variant renders as `{"error": "...", "status": N}` with the
/// matching HTTP status, so clients can rely on one error shape.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// No such repository, diamond or route (404).
    #[error("{0}")]
    NotFound(String),
    /// The request is malformed: bad diamond id, bad JSON body (400).
    #[error("{0}")]
    BadRequest(String),
    /// The request body or batch is over the configured limit (413).
    #[error("{0}")]
    TooLarge(String),
    /// The request target is longer than the server reads (414).
    #[error("{0}")]
    UriTooLong(String),
    /// The request's header fields are more or longer than the server reads (431).
    #[error("{0}")]
    HeadersTooLarge(String),
    /// The method is not allowed on this path (405).
    #[error("{0}")]
    MethodNotAllowed(String),
    /// No part of the requested byte range lies inside the file of this many bytes (416).
    #[error("range not satisfiable: the file is {0} bytes")]
    RangeNotSatisfiable(u64),
    /// The request took longer than the configured timeout, seconds (408).
    #[error("request timed out after {0} s")]
    Timeout(f64),
    /// The stored data is damaged or something else went wrong on our side (500). The message
    /// names what, so operators can find it; it reveals nothing beyond the repository's name.
    #[error("{0}")]
    Internal(String),
}

impl ApiError {
    /// The HTTP status this error is answered with.
    pub fn status(&self) -> StatusCode {
        match self {
            ApiError::NotFound(_) => StatusCode::NOT_FOUND,
            ApiError::BadRequest(_) => StatusCode::BAD_REQUEST,
            ApiError::TooLarge(_) => StatusCode::PAYLOAD_TOO_LARGE,
            ApiError::MethodNotAllowed(_) => StatusCode::METHOD_NOT_ALLOWED,
            ApiError::UriTooLong(_) => StatusCode::URI_TOO_LONG,
            ApiError::HeadersTooLarge(_) => StatusCode::REQUEST_HEADER_FIELDS_TOO_LARGE,
            ApiError::RangeNotSatisfiable(_) => StatusCode::RANGE_NOT_SATISFIABLE,
            ApiError::Timeout(_) => StatusCode::REQUEST_TIMEOUT,
            ApiError::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let status = self.status();
        let body = serde_json::json!({ "error": self.to_string(), "status": status.as_u16() });
        let mut r = (status, body.to_string()).into_response();
        r.headers_mut().insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        );
        // Errors are not immutable: a diamond missing today is missing only from this build.
        r.headers_mut()
            .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
        if let ApiError::RangeNotSatisfiable(len) = self {
            // RFC 9110 §15.5.17: a 416 says how long the resource is.
            let v = HeaderValue::from_str(&format!("bytes */{len}")).expect("ASCII");
            r.headers_mut().insert(header::CONTENT_RANGE, v);
        }
        r
    }
}

/// Why the server could not start.
#[derive(Debug, thiserror::Error)]
pub enum ServerError {
    /// A repository argument names no file or the name it gives is not allowed.
    #[error("invalid repository name {name:?}: {why}")]
    InvalidName {
        /// The offending name.
        name: String,
        /// What is wrong with it.
        why: &'static str,
    },
    /// Two repositories would be served under the same name.
    #[error("repository name {0:?} is given twice (name them with NAME=PATH)")]
    DuplicateName(String),
    /// No repository to serve.
    #[error("no repository to serve")]
    NoRepositories,
    /// A repository file could not be opened or failed validation.
    #[error("opening repository {}: {error}", path.display())]
    Open {
        /// The file.
        path: PathBuf,
        /// What the codec found. Part of the message and deliberately not the error's
        /// `source()`, or `{:#}` chains (anyhow) would print it twice.
        error: CodecError,
    },
    /// `--cors-origin` is not `*` or a list of origins.
    #[error("{0}")]
    InvalidCorsOrigin(String),
    /// Binding or serving the socket failed.
    // Not also the `source`: error chains would print the OS error twice.
    #[error("server I/O: {0}")]
    Io(std::io::Error),
}

impl From<std::io::Error> for ServerError {
    fn from(e: std::io::Error) -> Self {
        ServerError::Io(e)
    }
}

/// A path the router could not parse into its parameters, as a 400.
pub(crate) fn bad_path(e: PathRejection) -> ApiError {
    ApiError::BadRequest(format!("malformed path: {}", e.body_text()))
}
