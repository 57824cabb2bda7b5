//! What the server serves: named, validated repositories and the server's settings.

use std::collections::HashMap;
use std::fmt::Write;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, OnceLock};

use axum::http::HeaderValue;
use bytes::Bytes;
use cbdam_codec::repository::{Repository, Section};
use cbdam_tiles::Tiler;

use crate::answer_memory::AnswerMemory;
use crate::config::Config;
use crate::describe::{describe, head_len};
use crate::error::{ApiError, ServerError};
use crate::metrics::Metrics;

/// A served repository's tiler, built on first use: `Err` keeps why it could not be.
pub(crate) type TilerCell = OnceLock<Result<Arc<Tiler>, String>>;

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

/// Where a served repository's bytes are read from once it is open.
#[derive(Debug)]
pub(crate) enum Source {
    /// The repository's own bytes ([`AppState::new`]: repositories given in memory).
    Memory,
    /// The file opened at startup ([`AppState::open`]), read with positioned reads from its
    /// descriptor, never through a memory map: a file truncated underneath a map kills the
    /// process with SIGBUS on the next read of a vanished page, a short read is only an error.
    /// Its identity at startup is checked after every read ([`crate::records`]).
    File {
        file: std::fs::File,
        path: PathBuf,
        identity: FileIdentity,
        /// The records area, read when the file was opened ([`Config::held_records_bytes`]).
        held: Option<Box<[u8]>>,
    },
}

/// What tells a file changed in place: length and modification time (and on Unix the inode,
/// which a descriptor keeps). Not the change time: the rename that replaces a file (how
/// `cbdam build` writes) moves the change time of the file it unlinks, which is served on.
/// A write that keeps the length and puts the modification time back is not seen here; bytes
/// read from the file are checked against their CRCs for that ([`crate::records`]).
#[derive(Debug, PartialEq, Eq)]
pub(crate) struct FileIdentity {
    len: u64,
    modified: Option<std::time::SystemTime>,
    inode: Option<(u64, u64)>,
}

impl FileIdentity {
    fn of(m: &std::fs::Metadata) -> Self {
        #[cfg(unix)]
        let inode = {
            use std::os::unix::fs::MetadataExt;
            Some((m.dev(), m.ino()))
        };
        #[cfg(not(unix))]
        let inode = None;
        Self {
            len: m.len(),
            modified: m.modified().ok(),
            inode,
        }
    }
}

/// One repository as served: the validated repository plus what the server precomputes.
#[derive(Debug)]
pub struct ServedRepo {
    /// The name in URLs.
    pub name: String,
    /// The repository. For one opened from a file ([`AppState::open`]) only its head (header,
    /// index, checksums) is used once serving: records and file ranges are read from the file
    /// descriptor the server holds, never from this repository's map.
    pub repo: Repository,
    /// Where records and file ranges are read from.
    pub(crate) source: Source,
    /// The meta document (JSON), built once.
    pub(crate) meta: Bytes,
    /// Strong validator of [`ServedRepo::meta`].
    pub(crate) meta_etag: HeaderValue,
    /// Strong validator of the whole file.
    pub(crate) file_etag: HeaderValue,
    /// Whether the file's change on disk has been logged (once).
    changed_logged: AtomicBool,
    /// Per record: whether its corruption has been logged (log once per record, not per
    /// request: a client retrying a damaged record must not flood the log).
    pub(crate) corrupt_logged: Vec<AtomicBool>,
    /// Per record: whether its bytes have passed their CRC, so that a batch can refuse a
    /// damaged record before sending anything without reading every record twice. Bytes held
    /// in memory are checked once; bytes read from the file each time they are read
    /// ([`crate::records`]).
    pub(crate) verified: Vec<AtomicBool>,
    /// The web-map tiler ([`crate::tiles`]), its records read on the first tile request.
    pub(crate) tiles: TilerCell,
    /// Every record's ETag, concatenated: a response takes its slice of this shared buffer
    /// (a reference count, no allocation, no formatting per request).
    etags: Bytes,
    /// `etags[etag_at[i]..etag_at[i + 1]]` is record `i`'s ETag.
    etag_at: Vec<u32>,
}

impl ServedRepo {
    fn new(name: String, repo: Repository, source: Source) -> Self {
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
            source,
            meta,
            meta_etag: HeaderValue::from_str(&meta_etag).expect("ASCII"),
            file_etag: HeaderValue::from_str(&file_etag).expect("ASCII"),
            changed_logged: AtomicBool::new(false),
            corrupt_logged: flags(),
            verified: flags(),
            tiles: TilerCell::new(),
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

    /// Checks that the file served is still the one opened ([`FileIdentity`]). A file rebuilt
    /// in place (overwritten or truncated rather than replaced by a rename) is refused with a
    /// 500 naming the problem until the server is restarted.
    pub(crate) fn check_unchanged(&self) -> Result<(), ApiError> {
        let Source::File {
            file,
            path,
            identity,
            ..
        } = &self.source
        else {
            return Ok(());
        };
        let changed = match file.metadata() {
            Ok(m) => FileIdentity::of(&m) != *identity,
            Err(e) => {
                tracing::error!(repo = %self.name, "cannot stat {}: {e}", path.display());
                true
            }
        };
        if changed {
            Err(self.changed_error())
        } else {
            Ok(())
        }
    }

    fn changed_error(&self) -> ApiError {
        if !self
            .changed_logged
            .swap(true, std::sync::atomic::Ordering::Relaxed)
        {
            let Source::File { path, .. } = &self.source else {
                unreachable!("only files change")
            };
            tracing::error!(
                repo = %self.name,
                "{} was modified or truncated on disk while served: answering 500 for it \
                 until restarted (rebuild into a new file and rename it over the old one)",
                path.display()
            );
        }
        ApiError::Internal(format!(
            "the file of repository {:?} changed on disk while being served (modified or \
             truncated in place); the server must be restarted to serve it",
            self.name
        ))
    }

    /// Appends `range` of the file to `out`, refusing a file that changed underneath (a read
    /// short of the length opened).
    pub(crate) fn read_into(&self, range: Range<u64>, out: &mut Vec<u8>) -> Result<(), ApiError> {
        match &self.source {
            Source::Memory => {
                // Ranges come from the validated index or from `parse_range` against the length.
                out.extend_from_slice(
                    &self.repo.as_bytes()[range.start as usize..range.end as usize],
                );
                Ok(())
            }
            Source::File { file, path, .. } => {
                let at = out.len();
                out.resize(at + (range.end - range.start) as usize, 0);
                match read_exact_at(file, &mut out[at..], range.start) {
                    Ok(()) => Ok(()),
                    Err(e) => {
                        out.truncate(at);
                        if e.kind() == std::io::ErrorKind::UnexpectedEof {
                            Err(self.changed_error())
                        } else {
                            tracing::error!(repo = %self.name, "reading {}: {e}", path.display());
                            Err(ApiError::Internal(format!(
                                "reading the file of repository {:?} failed",
                                self.name
                            )))
                        }
                    }
                }
            }
        }
    }
}

#[cfg(unix)]
fn read_exact_at(file: &std::fs::File, buf: &mut [u8], at: u64) -> std::io::Result<()> {
    std::os::unix::fs::FileExt::read_exact_at(file, buf, at)
}

#[cfg(windows)]
fn read_exact_at(file: &std::fs::File, mut buf: &mut [u8], mut at: u64) -> std::io::Result<()> {
    use std::os::windows::fs::FileExt;
    while !buf.is_empty() {
        match file.seek_read(buf, at)? {
            0 => return Err(std::io::ErrorKind::UnexpectedEof.into()),
            n => {
                buf = &mut buf[n..];
                at += n as u64;
            }
        }
    }
    Ok(())
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
    /// The budget of answer bytes held ([`Config::answer_memory`]).
    pub(crate) answer_memory: Arc<AnswerMemory>,
}

impl AppState {
    /// Serves already opened repositories under the given names (checked with
    /// [`validate_name`], unique).
    pub fn new(repos: Vec<(String, Repository)>, config: Config) -> Result<Self, ServerError> {
        Self::with_sources(
            repos
                .into_iter()
                .map(|(name, repo)| (name, repo, Source::Memory))
                .collect(),
            config,
        )
    }

    fn with_sources(
        repos: Vec<(String, Repository, Source)>,
        config: Config,
    ) -> Result<Self, ServerError> {
        if repos.is_empty() {
            return Err(ServerError::NoRepositories);
        }
        // Checked here so that a bad origin is a startup error, not a silent fallback later.
        let _valid = crate::cors::parse_cors_origin(&config.cors_origin)
            .map_err(ServerError::InvalidCorsOrigin)?;
        let mut map = HashMap::new();
        let mut names = Vec::new();
        for (name, repo, source) in repos {
            validate_name(&name)?;
            if map.contains_key(&name) {
                return Err(ServerError::DuplicateName(name));
            }
            names.push(name.clone());
            map.insert(name.clone(), Arc::new(ServedRepo::new(name, repo, source)));
        }
        let listing: Vec<_> = names
            .iter()
            .map(|n| serde_json::json!({ "name": n, "meta": format!("/v1/repos/{n}/meta") }))
            .collect();
        let listing = Bytes::from(serde_json::json!({ "repos": listing }).to_string());
        let about: Vec<(String, String, bool)> = names
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
                    cbdam_tiles::Tiler::check(r.head()).is_ok(),
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
                answer_memory: Arc::new(AnswerMemory::new(config.answer_memory)),
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
        let mut budget = config.held_records_bytes;
        let repos = specs
            .iter()
            .map(|s| {
                let (repo, source) = open_one(&s.path, &mut budget)?;
                Ok((s.name.clone(), repo, source))
            })
            .collect::<Result<Vec<_>, ServerError>>()?;
        Self::with_sources(repos, config)
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

/// Opens the file, validates the repository at its path, and checks that both are the same
/// bytes (the head, whose checksums cover everything else, read back through the descriptor),
/// so that a file replaced between the two opens is not served half old, half new. A records
/// area of at most `budget` bytes is read into memory, and taken from the budget.
fn open_one(path: &Path, budget: &mut u64) -> Result<(Repository, Source), ServerError> {
    let open_err = |error: std::io::Error| ServerError::Open {
        path: path.to_path_buf(),
        error: error.into(),
    };
    let file = std::fs::File::open(path).map_err(open_err)?;
    let meta = file.metadata().map_err(open_err)?;
    let repo = Repository::open(path).map_err(|error| ServerError::Open {
        path: path.to_path_buf(),
        error,
    })?;
    let head = repo.head().section_offset(Section::Records) as usize;
    let mut back = vec![0; head];
    let same = meta.len() == repo.head().file_len()
        && read_exact_at(&file, &mut back, 0).is_ok()
        && back[..] == repo.as_bytes()[..head];
    let changed = || {
        open_err(std::io::Error::other(
            "the file changed while it was being opened",
        ))
    };
    if !same {
        return Err(changed());
    }
    let identity = FileIdentity::of(&meta);
    let records_len = repo.head().section_len(Section::Records);
    let held = if records_len <= *budget {
        *budget -= records_len;
        let mut records = vec![0; records_len as usize].into_boxed_slice();
        read_exact_at(&file, &mut records, head as u64).map_err(open_err)?;
        // Read before an unchanged identity: the bytes opened (their CRCs are checked as
        // each record is first served).
        if FileIdentity::of(&file.metadata().map_err(open_err)?) != identity {
            return Err(changed());
        }
        Some(records)
    } else {
        None
    };
    // Nothing reads the map any more: its pages need not stay resident.
    repo.release_pages();
    let source = Source::File {
        file,
        path: path.to_path_buf(),
        identity,
        held,
    };
    Ok((repo, source))
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
