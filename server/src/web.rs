//! The browser viewer, served beside the API by `cbdam serve --web DIR`: `/` is a page listing
//! the repositories, each opening the viewer on it; the viewer's files (the bundle
//! `scripts/web-build.sh` writes) are under `/viewer/HASH/`, where `HASH` is a hash of their
//! contents, so they are cached as immutable and a rebuilt viewer gets new URLs. The page at `/`
//! revalidates. Text and wasm files are sent gzip-compressed to clients that accept it.

use std::collections::HashMap;
use std::io::Write;
use std::path::Path;

use bytes::Bytes;

/// Files the viewer cannot start without (also checked by `cbdam web-export`).
pub const REQUIRED: [&str; 3] = ["index.html", "cbdam_web.js", "cbdam_web_bg.wasm"];
/// Largest viewer file accepted (the wasm module is about 1 MB).
const MAX_FILE: u64 = 64 << 20;

/// One file of the viewer, as sent.
#[derive(Debug)]
pub(crate) struct Asset {
    pub(crate) content_type: &'static str,
    pub(crate) raw: Bytes,
    /// The gzip encoding, when it is smaller.
    pub(crate) gzip: Option<Bytes>,
}

/// The viewer's files, read once at start.
#[derive(Debug)]
pub struct WebAssets {
    hash: String,
    files: HashMap<String, Asset>,
}

/// Why the viewer's files could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum WebError {
    /// The directory or a file in it could not be read.
    #[error("reading the viewer in {dir}: {error}")]
    Io {
        /// The directory given.
        dir: String,
        /// What failed.
        error: std::io::Error,
    },
    /// A file the viewer needs is missing.
    #[error(
        "{dir} is not the viewer's bundle: {file} is missing (build it with scripts/web-build.sh, \
         which writes target/web-bundle)"
    )]
    Missing {
        /// The directory given.
        dir: String,
        /// The file missing.
        file: &'static str,
    },
    /// A file is larger than any viewer file should be.
    #[error("{file} in the viewer's bundle is {size} bytes, more than {MAX_FILE}")]
    TooLarge {
        /// The file.
        file: String,
        /// Its size.
        size: u64,
    },
}

/// The content type of a viewer file (or of the example pages' libraries), by extension.
pub(crate) fn content_type(name: &str) -> &'static str {
    match name.rsplit_once('.').map(|(_, e)| e) {
        Some("html") => "text/html; charset=utf-8",
        Some("js" | "mjs" | "cjs") => "text/javascript; charset=utf-8",
        Some("wasm") => "application/wasm",
        Some("css") => "text/css; charset=utf-8",
        Some("json") => "application/json",
        Some("png") => "image/png",
        Some("jpg" | "jpeg") => "image/jpeg",
        Some("gif") => "image/gif",
        Some("xml") => "application/xml",
        Some("svg") => "image/svg+xml",
        _ => "application/octet-stream",
    }
}

/// FNV-1a, 64 bits: a content hash for cache-busting paths, not for security.
fn fnv1a(hash: &mut u64, bytes: &[u8]) {
    for &b in bytes {
        *hash ^= u64::from(b);
        *hash = hash.wrapping_mul(0x0100_0000_01b3);
    }
}

impl WebAssets {
    /// Reads every file of `dir` (not its subdirectories), which must hold the viewer.
    pub fn load(dir: &Path) -> Result<Self, WebError> {
        let shown = dir.display().to_string();
        let io = |error| WebError::Io {
            dir: shown.clone(),
            error,
        };
        let mut entries: Vec<_> = std::fs::read_dir(dir)
            .map_err(io)?
            .collect::<Result<_, _>>()
            .map_err(io)?;
        entries.sort_by_key(|e| e.file_name());
        let mut files = HashMap::new();
        let mut hash = 0xcbf2_9ce4_8422_2325u64;
        for e in entries {
            let meta = e.metadata().map_err(io)?;
            let name = e.file_name().to_string_lossy().into_owned();
            if !meta.is_file() || name.starts_with('.') {
                continue;
            }
            if meta.len() > MAX_FILE {
                return Err(WebError::TooLarge {
                    file: name,
                    size: meta.len(),
                });
            }
            let raw = std::fs::read(e.path()).map_err(io)?;
            fnv1a(&mut hash, name.as_bytes());
            fnv1a(&mut hash, &raw);
            let content_type = content_type(&name);
            let compressible = !content_type.starts_with("image/png");
            let gzip = compressible
                .then(|| gzip(&raw))
                .filter(|g| g.len() < raw.len())
                .map(Bytes::from);
            files.insert(
                name,
                Asset {
                    content_type,
                    raw: Bytes::from(raw),
                    gzip,
                },
            );
        }
        if let Some(file) = REQUIRED.into_iter().find(|f| !files.contains_key(*f)) {
            return Err(WebError::Missing { dir: shown, file });
        }
        Ok(Self {
            hash: format!("{hash:016x}"),
            files,
        })
    }

    /// The content hash in the viewer's URLs.
    pub fn hash(&self) -> &str {
        &self.hash
    }

    /// The file `name`, if the bundle has it.
    pub(crate) fn get(&self, name: &str) -> Option<&Asset> {
        self.files.get(name)
    }

    /// Where the viewer opens repository `name` of this server.
    pub fn viewer_url(&self, name: &str) -> String {
        format!("/viewer/{}/index.html?repo=/v1/repos/{name}", self.hash)
    }
}

fn gzip(raw: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
    e.write_all(raw).expect("writing to memory");
    e.finish().expect("writing to memory")
}

/// Escapes text for HTML.
pub(crate) fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// The page at `/`: the repositories (name, samples, size, whether web-map tiles are made of
/// it), each linking to the viewer when it is served, and the API's entry points.
pub(crate) fn index_page(repos: &[(String, String, bool)], web: Option<&WebAssets>) -> String {
    let mut rows = String::new();
    for (name, about, tiles) in repos {
        let name_html = escape(name);
        let open = match web {
            Some(w) => format!(
                "<a href=\"{}\">{name_html}</a>",
                escape(&w.viewer_url(name))
            ),
            None => name_html.clone(),
        };
        // Web maps (docs/WEB-MAPS.md): what MapLibre and CesiumJS are pointed at, and the
        // example pages showing it in them.
        let maps = if *tiles {
            format!(
                " · <a href=\"/v1/repos/{name_html}/terrarium/tiles.json\">terrarium</a> \
                 · <a href=\"/v1/repos/{name_html}/terrain-rgb/tiles.json\">terrain-RGB</a> \
                 · <a href=\"/v1/repos/{name_html}/quantized-mesh/layer.json\">quantized-mesh</a> \
                 · examples: <a href=\"/examples/cesium.html?repo={name_html}\">CesiumJS</a>, \
                 <a href=\"/examples/maplibre.html?repo={name_html}\">MapLibre</a>"
            )
        } else {
            String::new()
        };
        rows += &format!(
            "<tr><td>{open}</td><td>{}</td><td><a href=\"/v1/repos/{name_html}/meta\">meta</a> \
             · <a href=\"/v1/repos/{name_html}/file\">file</a>{maps}</td></tr>\n",
            escape(about)
        );
    }
    let note = match web {
        Some(_) => "Click a repository to open it in the browser viewer (WebGPU).",
        None => {
            "The browser viewer is not served: build it with <code>scripts/web-build.sh</code> \
             and start <code>cbdam serve --web target/web-bundle …</code>."
        }
    };
    format!(
        "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\
         <title>cbdam serve</title><style>body{{font:15px system-ui,sans-serif;margin:2em;\
         max-width:60em}}td{{padding:.3em 1em .3em 0}}</style></head><body>\n\
         <h1>cbdam serve</h1>\n<p>{note}</p>\n<table>\n\
         <tr><th align=left>repository</th><th align=left>data</th><th align=left>API</th></tr>\n\
         {rows}</table>\n<p>API: <a href=\"/v1/repos\">/v1/repos</a> · \
         <a href=\"/metrics\">/metrics</a> (docs/HTTP-API.md)</p>\n</body></html>\n"
    )
}
