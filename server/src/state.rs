//! What the server serves: named, validated repositories and the server's settings.

use std::collections::HashMap;
use std::fmt::Write;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use axum::http::HeaderValue;
use bytes::Bytes;
use cbdam_codec::repository::{Repository, Section};

use crate::describe::{describe, head_len};
use crate::error::ServerError;
use crate::metrics::Metrics;

/// Server settings.
#[derive(Clone, Debug)]
pub struct Config {
    /// Most ids in one batch request (`--max-batch`).
    pub max_batch: usize,
    /// Largest accepted request body, bytes.
    pub max_body: usize,
    /// Value of `Access-Control-Allow-Origin`: `*` or an origin such as
    /// `https://example.org` (`--cors-origin`).
    pub cors_origin: String,
    /// Time allowed to answer one request (`--timeout`).
    pub timeout: Duration,
    /// The browser viewer's files, served at `/viewer/…` with a page at `/` (`--web`).
    pub web: Option<Arc<crate::web::WebAssets>>,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            max_batch: 4096,
            max_body: 1 << 20,
            cors_origin: "*".to_string(),
            timeout: Duration::from_secs(30),
            web: None,
        }
    }
}

/// A repository argument: `PATH` (named after the file stem) or `NAME=PATH`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RepoSpec {
    /// The name it is served under.
    pub name: String,
    /// The file.
    pub path: PathBuf,
}

impl FromStr for RepoSpec {
    type Err = ServerError;

    /// `NAME=PATH` when the text before the first `=` is a valid name, otherwise a path named
    /// after its file stem. (A file whose name contains `=` is served as `NAME=PATH`.)
    fn from_str(s: &str) -> Result<Self, ServerError> {
        if let Some((name, path)) = s.split_once('=')
            && validate_name(name).is_ok()
            && !path.is_empty()
        {
            return Ok(Self {
                name: name.to_string(),
                path: PathBuf::from(path),
            });
        }
        let path = PathBuf::from(s);
        let stem =
            path.file_stem()
                .and_then(|s| s.to_str())
                .ok_or_else(|| ServerError::InvalidName {
                    name: s.to_string(),
                    why: "the path has no file name to take a name from",
                })?;
        validate_name(stem)?;
        Ok(Self {
            name: stem.to_string(),
            path,
        })
    }
}

/// Checks a repository name: 1 to 64 characters from `[A-Za-z0-9._-]`, not `.` or `..`.
/// Names are only ever looked up in a map, never joined to a path, so this is about clean URLs
/// rather than safety; it also keeps them printable in logs and metrics.
pub fn validate_name(name: &str) -> Result<(), ServerError> {
    let bad = |why| {
        Err(ServerError::InvalidName {
            name: name.to_string(),
            why,
        })
    };
    if name.is_empty() || name.len() > 64 {
        return bad("names are 1 to 64 characters");
    }
    if !name
        .bytes()
        .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_' | b'-'))
    {
        return bad("names may only contain A-Z, a-z, 0-9, '.', '_' and '-' (use NAME=PATH)");
    }
    if name == "." || name == ".." {
        return bad("'.' and '..' are not names");
    }
    Ok(())
}

/// One repository as served: the validated repository plus what the server precomputes.
#[derive(Debug)]
pub struct ServedRepo {
    /// The name in URLs.
    pub name: String,
    /// The repository.
    pub repo: Repository,
    /// The meta document (JSON), built once.
    pub(crate) meta: Bytes,
    /// Strong validator of [`ServedRepo::meta`].
    pub(crate) meta_etag: HeaderValue,
    /// Strong validator of the whole file.
    pub(crate) file_etag: HeaderValue,
    /// Per record: whether its corruption has been logged (log once per record, not per
    /// request: a client retrying a damaged record must not flood the log).
    pub(crate) corrupt_logged: Vec<AtomicBool>,
    /// Per record: whether its bytes have passed their CRC once. A served repository is
    /// immutable, so one check per record suffices; a damaged record never passes and is
    /// checked (and refused) on every request.
    pub(crate) verified: Vec<AtomicBool>,
    /// Every record's ETag, concatenated: a response takes its slice of this shared buffer
    /// (a reference count, no allocation, no formatting per request).
    etags: Bytes,
    /// `etags[etag_at[i]..etag_at[i + 1]]` is record `i`'s ETag.
    etag_at: Vec<u32>,
}

impl ServedRepo {
    fn new(name: String, repo: Repository) -> Self {
        let mut meta = describe(&repo);
        let m = meta.as_object_mut().expect("describe returns an object");
        let base = format!("/v1/repos/{name}");
        let roots_at = repo.head().section_offset(Section::Roots);
        let roots_end = roots_at + repo.head().section_len(Section::Roots);
        m.insert("name".into(), name.clone().into());
        m.insert("file".into(), format!("{base}/file").into());
        m.insert("diamonds".into(), format!("{base}/diamonds").into());
        // The root values are not served on their own: they are the coded root field, a
        // section inside the head bytes, decoded by the codec together with the header.
        m.insert(
            "root_values".into(),
            serde_json::json!({
                "file": format!("{base}/file"),
                "range": format!("bytes={roots_at}-{}", roots_end - 1),
                "head_range": format!("bytes=0-{}", head_len(&repo) - 1),
                "note": "the coded root field lies inside the head bytes: fetch head_range of \
                         the file and open it with the codec",
            }),
        );
        let meta = Bytes::from(serde_json::to_vec_pretty(&meta).expect("JSON of plain values"));
        let hdr = repo.head().header_crc();
        let meta_etag = format!("\"{hdr:08x}-m{:08x}\"", crc32fast::hash(&meta));
        let file_etag = format!("\"{hdr:08x}-f{:016x}\"", repo.head().file_len());
        let n = repo.head().entries().len();
        let flags = || (0..n).map(|_| AtomicBool::new(false)).collect();
        let mut etags = String::with_capacity(n * 20);
        let mut etag_at = Vec::with_capacity(n + 1);
        etag_at.push(0);
        for i in 0..n {
            // `write!` into a String cannot fail.
            let _ = match repo.head().record_checksum(i) {
                Some(c) => write!(etags, "\"{hdr:08x}-r{c:08x}\""),
                None => write!(etags, "\"{hdr:08x}-e\""),
            };
            etag_at.push(u32::try_from(etags.len()).expect("under 4 GiB of ETags"));
        }
        Self {
            name,
            repo,
            meta,
            meta_etag: HeaderValue::from_str(&meta_etag).expect("ASCII"),
            file_etag: HeaderValue::from_str(&file_etag).expect("ASCII"),
            corrupt_logged: flags(),
            verified: flags(),
            etags: Bytes::from(etags),
            etag_at,
        }
    }

    /// The strong ETag of record `i`: the header CRC (which covers every section's CRC, so it
    /// identifies the file) and the record's own CRC from the checksum table.
    pub(crate) fn record_etag(&self, i: usize) -> HeaderValue {
        let v = self
            .etags
            .slice(self.etag_at[i] as usize..self.etag_at[i + 1] as usize);
        HeaderValue::from_maybe_shared(v).expect("ASCII")
    }
}

/// Everything the handlers share. Cheap to clone.
#[derive(Clone, Debug)]
pub struct AppState {
    pub(crate) inner: Arc<Inner>,
}

#[derive(Debug)]
pub(crate) struct Inner {
    pub(crate) repos: HashMap<String, Arc<ServedRepo>>,
    /// Names in the order given.
    pub(crate) names: Vec<String>,
    /// `GET /v1/repos`, built once.
    pub(crate) listing: Bytes,
    /// `GET /`, built once.
    pub(crate) index: Bytes,
    pub(crate) config: Config,
    pub(crate) metrics: Metrics,
}

impl AppState {
    /// Serves already opened repositories under the given names (checked with
    /// [`validate_name`], unique).
    pub fn new(repos: Vec<(String, Repository)>, config: Config) -> Result<Self, ServerError> {
        if repos.is_empty() {
            return Err(ServerError::NoRepositories);
        }
        // Checked here so that a bad origin is a startup error, not a silent fallback later.
        let _valid = crate::cors::parse_cors_origin(&config.cors_origin)
            .map_err(ServerError::InvalidCorsOrigin)?;
        let mut map = HashMap::new();
        let mut names = Vec::new();
        for (name, repo) in repos {
            validate_name(&name)?;
            if map.contains_key(&name) {
                return Err(ServerError::DuplicateName(name));
            }
            names.push(name.clone());
            map.insert(name.clone(), Arc::new(ServedRepo::new(name, repo)));
        }
        let listing: Vec<_> = names
            .iter()
            .map(|n| serde_json::json!({ "name": n, "meta": format!("/v1/repos/{n}/meta") }))
            .collect();
        let listing = Bytes::from(serde_json::json!({ "repos": listing }).to_string());
        let about: Vec<(String, String)> = names
            .iter()
            .map(|n| {
                let r = &map[n].repo;
                let data = r.head().params().domain.data();
                let size = r.as_bytes().len();
                (
                    n.clone(),
                    format!(
                        "{} × {} samples, {:.1} MB",
                        data.width,
                        data.height,
                        size as f64 / 1e6
                    ),
                )
            })
            .collect();
        let index = Bytes::from(crate::web::index_page(&about, config.web.as_deref()));
        Ok(Self {
            inner: Arc::new(Inner {
                repos: map,
                names,
                listing,
                index,
                config,
                metrics: Metrics::default(),
            }),
        })
    }

    /// Opens (memory-maps and validates) every repository of `specs`. Names are checked
    /// before any file is opened, so a typo in a name fails fast.
    pub fn open(specs: &[RepoSpec], config: Config) -> Result<Self, ServerError> {
        let mut seen = std::collections::HashSet::new();
        for s in specs {
            validate_name(&s.name)?;
            if !seen.insert(&s.name) {
                return Err(ServerError::DuplicateName(s.name.clone()));
            }
        }
        let repos = specs
            .iter()
            .map(|s| Ok((s.name.clone(), open_one(&s.path)?)))
            .collect::<Result<Vec<_>, ServerError>>()?;
        Self::new(repos, config)
    }

    /// The request counters.
    pub fn metrics(&self) -> &Metrics {
        &self.inner.metrics
    }

    /// The settings.
    pub fn config(&self) -> &Config {
        &self.inner.config
    }

    /// The names served, in the order given.
    pub fn names(&self) -> &[String] {
        &self.inner.names
    }

    /// The repository served as `name`.
    pub fn repo(&self, name: &str) -> Option<&Arc<ServedRepo>> {
        self.inner.repos.get(name)
    }
}

fn open_one(path: &Path) -> Result<Repository, ServerError> {
    Repository::open(path).map_err(|error| ServerError::Open {
        path: path.to_path_buf(),
        error,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs() {
        let s: RepoSpec = "data/srtm.cbdam".parse().unwrap();
        assert_eq!(
            (s.name.as_str(), s.path.as_path()),
            ("srtm", Path::new("data/srtm.cbdam"))
        );
        let s: RepoSpec = "alps=/x/y.cbdam".parse().unwrap();
        assert_eq!(
            (s.name.as_str(), s.path.as_path()),
            ("alps", Path::new("/x/y.cbdam"))
        );
        // '/' cannot be in a name, so this is a path whose stem is taken.
        let s: RepoSpec = "/a=b/c.cbdam".parse().unwrap();
        assert_eq!(s.name, "c");
        assert!("my repo.cbdam".parse::<RepoSpec>().is_err());
        assert!("/".parse::<RepoSpec>().is_err());
        assert!("x=".parse::<RepoSpec>().is_err());
    }

    #[test]
    fn names() {
        for ok in ["srtm", "a.b_c-D9", "x"] {
            validate_name(ok).unwrap();
        }
        for bad in ["", ".", "..", "a/b", "a b", "ä", "a%2e", &"x".repeat(65)] {
            assert!(validate_name(bad).is_err(), "{bad:?}");
        }
    }
}
