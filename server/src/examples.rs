//! The web-map example pages (docs/WEB-MAPS.md): `/examples/cesium.html?repo=NAME`, CesiumJS on
//! the repository's quantized-mesh tiles (no Cesium ion), and `/examples/maplibre.html?repo=NAME`,
//! MapLibre GL JS on its terrarium tiles (hillshade and terrain), linked from `/` for every
//! repository made into tiles. They load their libraries from this server, under `/web-libs/`,
//! read from `cbdam serve --web-libs DIR` (a `node_modules` holding `cesium` and `maplibre-gl`),
//! so nothing is fetched from another host; without `--web-libs` a page says what to install.

use std::path::{Path, PathBuf};

use axum::body::Body;
use axum::extract::rejection::PathRejection;
use axum::extract::{Path as UrlPath, Request, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::Response;

use crate::error::{ApiError, bad_path};
use crate::state::AppState;
use crate::web::escape;

/// The pages, by file name, and the library each needs.
const PAGES: [(&str, &str, &str); 2] = [
    (
        "cesium.html",
        "CesiumJS",
        include_str!("examples/cesium.html"),
    ),
    (
        "maplibre.html",
        "MapLibre GL JS",
        include_str!("examples/maplibre.html"),
    ),
];
/// What `--web-libs` must hold (under the `node_modules` given), and the only trees served.
const LIBRARIES: [(&str, &str); 2] = [
    ("cesium/Build/Cesium/", "Cesium.js"),
    ("maplibre-gl/dist/", "maplibre-gl.mjs"),
];
/// Largest library file served (Cesium.js is about 4 MB, maplibre-gl's largest about 2 MB).
const MAX_FILE: u64 = 64 << 20;
/// How to get the libraries, in the messages.
const INSTALL: &str = "npm install cesium maplibre-gl, then cbdam serve --web-libs node_modules …";

/// The example pages' JavaScript libraries: a `node_modules` directory, files read on request.
#[derive(Debug)]
pub struct WebLibs {
    node_modules: PathBuf,
}

/// Why `--web-libs` cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum WebLibsError {
    /// The directory is not there.
    #[error("--web-libs {dir}: not a directory ({INSTALL})")]
    NotADirectory {
        /// The directory given.
        dir: String,
    },
    /// A library is missing.
    #[error("--web-libs {dir}: no {file} in it (the example pages need it: {INSTALL})")]
    Missing {
        /// The directory given.
        dir: String,
        /// The file looked for, relative to the `node_modules`.
        file: String,
    },
}

impl WebLibs {
    /// The libraries in `dir`: a `node_modules` holding `cesium` and `maplibre-gl`, or a
    /// directory holding such a `node_modules`.
    pub fn open(dir: &Path) -> Result<WebLibs, WebLibsError> {
        let shown = dir.display().to_string();
        if !dir.is_dir() {
            return Err(WebLibsError::NotADirectory { dir: shown });
        }
        let nested = dir.join("node_modules");
        let node_modules = if nested.is_dir() {
            nested
        } else {
            dir.to_path_buf()
        };
        for (tree, file) in LIBRARIES {
            if !node_modules.join(tree).join(file).is_file() {
                return Err(WebLibsError::Missing {
                    dir: shown,
                    file: format!("{tree}{file}"),
                });
            }
        }
        Ok(WebLibs { node_modules })
    }

    /// The file at `path` under `/web-libs/`: plain names only (no `.`, `..` or hidden
    /// components), inside one of the libraries' served trees.
    fn file(&self, path: &str) -> Result<PathBuf, ApiError> {
        let plain = |c: &str| !c.is_empty() && !c.starts_with('.') && !c.contains('\\');
        if !path.split('/').all(plain) {
            return Err(ApiError::BadRequest(format!(
                "malformed library path {path:?} (plain names separated by /)"
            )));
        }
        if !LIBRARIES.iter().any(|(tree, _)| path.starts_with(tree)) {
            return Err(ApiError::NotFound(format!(
                "/web-libs/ serves {} only, not {path:?}",
                LIBRARIES.map(|(tree, _)| tree).join(" and ")
            )));
        }
        Ok(self.node_modules.join(path))
    }
}

/// `GET /web-libs/{*path}`: a file of the libraries.
async fn library_file(
    State(st): State<AppState>,
    path: Result<UrlPath<String>, PathRejection>,
) -> Result<Response, ApiError> {
    let UrlPath(path) = path.map_err(bad_path)?;
    let Some(libs) = st.config().web_libs.clone() else {
        return Err(ApiError::NotFound(format!(
            "the example pages' libraries are not served ({INSTALL})"
        )));
    };
    let file = libs.file(&path)?;
    let content_type = crate::web::content_type(&path);
    let read = tokio::task::spawn_blocking(move || -> Result<Vec<u8>, ApiError> {
        let missing = || ApiError::NotFound(format!("no library file {path:?}"));
        let meta = std::fs::metadata(&file).map_err(|_| missing())?;
        if !meta.is_file() {
            return Err(missing());
        }
        if meta.len() > MAX_FILE {
            return Err(ApiError::Internal(format!(
                "library file {path:?} is {} bytes, more than {MAX_FILE}",
                meta.len()
            )));
        }
        std::fs::read(&file).map_err(|e| ApiError::Internal(format!("reading {path:?}: {e}")))
    });
    let bytes = read
        .await
        .map_err(|e| ApiError::Internal(format!("reading a library file: {e}")))??;
    let mut r = Response::new(Body::from(bytes));
    let h = r.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
    h.insert(
        header::CACHE_CONTROL,
        HeaderValue::from_static("public, max-age=3600"),
    );
    Ok(r)
}

/// An HTML page answered with `status`, revalidated by caches.
fn html_page(status: StatusCode, body: String) -> Response {
    let mut r = Response::new(Body::from(body));
    *r.status_mut() = status;
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("text/html; charset=utf-8"),
    );
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    r
}

/// A page of text: an example that cannot be shown, and why.
fn message_page(status: StatusCode, title: &str, message: &str) -> Response {
    let body = format!(
        "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title>\
         <style>body{{font:15px system-ui,sans-serif;margin:2em;max-width:60em}}</style></head>\
         <body>\n<h1>{t}</h1>\n<p>{m}</p>\n<p><a href=\"/\">The repositories</a></p>\n</body></html>\n",
        t = escape(title),
        m = escape(message)
    );
    html_page(status, body)
}

/// `repo` of the query string, if given.
fn repo_of(req: &Request) -> Option<String> {
    let query = req.uri().query()?;
    query
        .split('&')
        .find_map(|pair| pair.strip_prefix("repo="))
        .map(str::to_string)
}

/// `GET /examples/{page}?repo=NAME`: the page, or a page saying why it cannot be shown (an
/// unknown page or repository, one not made into tiles: 404; no `repo`: 400; the libraries not
/// served: 404 saying what to install).
async fn example_page(
    State(st): State<AppState>,
    page: Result<UrlPath<String>, PathRejection>,
    req: Request,
) -> Response {
    let Ok(UrlPath(page)) = page else {
        return message_page(
            StatusCode::BAD_REQUEST,
            "Malformed path",
            "malformed page path",
        );
    };
    let Some(&(_, library, template)) = PAGES.iter().find(|(file, _, _)| *file == page) else {
        let there = PAGES.map(|(file, _, _)| file).join(" and ");
        let m = format!("there is no example page {page:?} (there are {there})");
        return message_page(StatusCode::NOT_FOUND, "No such example", &m);
    };
    let Some(name) = repo_of(&req) else {
        let m = format!("say which repository to show: /examples/{page}?repo=NAME");
        return message_page(StatusCode::BAD_REQUEST, "Which repository?", &m);
    };
    let Some(r) = st.repo(&name) else {
        let m = format!("this server has no repository named {name:?}");
        return message_page(StatusCode::NOT_FOUND, "No such repository", &m);
    };
    if let Err(e) = cbdam_tiles::Tiler::check(r.repo.head()) {
        let m = format!("repository {name:?} is not made into web-map tiles: {e}");
        return message_page(StatusCode::NOT_FOUND, "No web-map tiles", &m);
    }
    if st.config().web_libs.is_none() {
        let m = format!(
            "this server does not serve {library}, which the page needs, and the page fetches \
             nothing from other hosts. Install the libraries and start the server with them: \
             {INSTALL}"
        );
        return message_page(
            StatusCode::NOT_FOUND,
            &format!("{library} is not served"),
            &m,
        );
    }
    // Names hold A-Z a-z 0-9 . _ - only (`validate_name`): nothing to escape in HTML or JS.
    html_page(StatusCode::OK, template.replace("{{REPO}}", &escape(&name)))
}

/// The routes of this module.
pub(crate) fn routes(router: axum::Router<AppState>) -> axum::Router<AppState> {
    use axum::routing::get;
    router
        .route("/examples/{page}", get(example_page))
        .route("/web-libs/{*path}", get(library_file))
}
