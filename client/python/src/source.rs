//! Where a reader's records come from: a memory-mapped local file, or a remote repository
//! (`cbdam serve`, or a `.cbdam` file on any server with Range support) fetched in batches by
//! the client's fetcher; and the windowed decode of one level from either, written into an
//! output slice in place.

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use cbdam_client::fetch::{FetchOptions, RemoteFetcher};
use cbdam_codec::CodecError;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::{
    CodecParams, FaceWindows, LevelWindow, decode_face_windows, decode_window,
};
use cbdam_codec::repository::{LevelGrid, Repository, RepositoryHead};
use rayon::prelude::*;

use crate::cache::{CacheInfo, RecordCache};
use crate::errors::{PyCbdamError, Result};

/// Samples a worker fills with NaN at a time before a read decodes into its array (256 KiB of
/// `f32`): large enough that the pool's overhead vanishes, small enough to share the pages out.
const FILL_CHUNK: usize = 1 << 16;

/// The bytes of one stored diamond's record, as the decoders ask for them.
type RecordFn<'r> = dyn Fn(DiamondId) -> std::result::Result<&'r [u8], CodecError> + Sync + 'r;

/// A repository, local or remote.
pub enum Source {
    /// A memory-mapped file: records are read (and CRC-checked) where they are decoded.
    Local(Arc<Repository>),
    /// Over HTTP: the head fetched at open, the records a read needs and the cache lacks
    /// fetched before it decodes (one read's fetch at a time: the fetcher has one wanted set).
    Remote {
        /// The fetcher, which holds the head.
        fetcher: Mutex<RemoteFetcher>,
        /// Its head, shared.
        head: Arc<RepositoryHead>,
        /// How long a read waits without a record arriving before it gives up.
        stall: Duration,
        /// The records kept between reads.
        cache: Box<Mutex<RecordCache>>,
    },
}

/// Whether `grid` is the finest level over the whole data rectangle: a read that needs every
/// record, decoded whole ([`LevelGrid::decode_into`]) rather than window by window.
fn reads_whole_finest_level(grid: &LevelGrid, params: &CodecParams) -> bool {
    let whole = LevelGrid::new(params, None, None, "");
    params.domain.cube().is_none() && whole.is_ok_and(|whole| whole == *grid)
}

/// The error of a lock an earlier read panicked holding.
fn poisoned<T>(_: T) -> PyCbdamError {
    PyCbdamError::Other("an earlier read panicked".into())
}

/// One output sample type: `float32` or `float64`, NaN where there is no data.
pub trait Sample: Copy + Send + Sync {
    /// The height `v` (metres).
    fn from_metres(v: f64) -> Self;
}

impl Sample for f32 {
    fn from_metres(v: f64) -> Self {
        v as f32
    }
}

impl Sample for f64 {
    fn from_metres(v: f64) -> Self {
        v
    }
}

impl Source {
    /// Maps and validates the repository at `path`.
    pub fn open_local(path: &Path) -> Result<Source> {
        let repo = Repository::open(path)
            .map_err(|e| PyCbdamError::codec(&format!("opening {}", path.display()), &e))?;
        Ok(Source::Local(Arc::new(repo)))
    }

    /// Connects to `url` and fetches the head; later reads give up after `stall` without a
    /// record (and so does connecting, per request).
    /// `cache_bytes`: the records kept between reads, at most (0: none).
    pub fn open_remote(url: &str, stall: Duration, cache_bytes: usize) -> Result<Source> {
        let options = FetchOptions {
            timeout: stall,
            ..FetchOptions::default()
        };
        let fetcher = RemoteFetcher::connect(url, options).map_err(|e| PyCbdamError::remote(&e))?;
        let head = fetcher.head().clone();
        Ok(Source::Remote {
            fetcher: Mutex::new(fetcher),
            head,
            stall,
            cache: Box::new(Mutex::new(RecordCache::new(cache_bytes))),
        })
    }

    /// What the remote cache holds (`None` for a local file).
    pub fn cache_info(&self) -> Option<CacheInfo> {
        match self {
            Source::Local(_) => None,
            Source::Remote { cache, .. } => cache.lock().ok().map(|c| c.info()),
        }
    }

    /// The validated head.
    pub fn head(&self) -> &RepositoryHead {
        match self {
            Source::Local(repo) => repo.head(),
            Source::Remote { head, .. } => head,
        }
    }

    /// Decodes `grid` (one even level over a window) into `out` (`grid.width × grid.height`,
    /// row-major, row 0 north): heights in metres, NaN where the repository has no data.
    /// `name` names the repository in messages. Runs on rayon's pool; call it without the GIL.
    pub fn read_into<T: Sample>(&self, grid: &LevelGrid, out: &mut [T], name: &str) -> Result<()> {
        debug_assert_eq!(out.len(), grid.width * grid.height);
        // The first touch of a new array's pages (hundreds of MB for a large read): on every
        // core, as the decode that follows.
        out.par_chunks_mut(FILL_CHUNK)
            .for_each(|chunk| chunk.fill(T::from_metres(f64::NAN)));
        let head = self.head();
        let (params, plan) = (*head.params(), *head.plan());
        if let Source::Local(repo) = self
            && reads_whole_finest_level(grid, &params)
        {
            // Every record is read: one walk over the file, in parallel over records and over
            // the raster's rows, as `cbdam extract` decodes.
            let encoded = repo
                .to_encoded()
                .map_err(|e| PyCbdamError::codec(&format!("reading {name}"), &e))?;
            let to_sample = |h: i32| T::from_metres(plan.metres(h));
            return grid
                .decode_into(&encoded, to_sample, out)
                .map_err(|e| PyCbdamError::codec(&format!("decoding {name}"), &e));
        }
        let window = LevelWindow {
            level: grid.level,
            rect: (grid.x0, grid.y0, grid.x1, grid.y1),
        };
        let n = params.layout().n();
        let visit = |id: DiamondId, values: &[i32], valid: Option<&[bool]>| {
            let g = params.layout().grid(id);
            for j in 0..n {
                for i in 0..n {
                    let (x, y) = g.point(i as i64, j as i64);
                    let Some(at) = grid.index_of(x, y) else {
                        continue;
                    };
                    if valid.is_none_or(|v| v[j * n + i]) {
                        out[at] = T::from_metres(plan.metres(values[j * n + i]));
                    }
                }
            }
        };
        let stored: Vec<DiamondId> = head.entries().iter().map(|e| e.id).collect();
        let needed = || Ok(window.records_needed(&params, &stored));
        self.decode_with(needed, name, |record| {
            decode_window(params, head.root_bytes(), &stored, record, window, visit)
        })
    }

    /// Decodes `windows` of a planet, handing `visit` each diamond of the level that reaches
    /// them (see `decode_face_windows`). Runs on rayon's pool; call it without the GIL.
    pub fn decode_faces(
        &self,
        windows: &FaceWindows,
        name: &str,
        visit: impl FnMut(DiamondId, &[i32], Option<&[bool]>),
    ) -> Result<()> {
        let head = self.head();
        let params = *head.params();
        let stored: Vec<DiamondId> = head.entries().iter().map(|e| e.id).collect();
        let needed = || windows.records_needed(&params, &stored);
        self.decode_with(needed, name, |record| {
            decode_face_windows(params, head.root_bytes(), &stored, record, windows, visit)
        })
    }

    /// Runs `decode` with the records it reads: a local file's, or (remote) the records
    /// `needed` names, fetched first. `name` names the repository in messages.
    fn decode_with(
        &self,
        needed: impl FnOnce() -> std::result::Result<Vec<DiamondId>, CodecError>,
        name: &str,
        decode: impl for<'r> FnOnce(&'r RecordFn<'r>) -> std::result::Result<(), CodecError>,
    ) -> Result<()> {
        let decoding = |e: CodecError| PyCbdamError::codec(&format!("decoding {name}"), &e);
        match self {
            Source::Local(repo) => {
                let record = |id: DiamondId| repo.record(id);
                decode(&record).map_err(decoding)
            }
            Source::Remote {
                fetcher,
                stall,
                cache,
                ..
            } => {
                let needed = needed().map_err(decoding)?;
                let (mut records, missing) = cache.lock().map_err(poisoned)?.take(&needed);
                if !missing.is_empty() {
                    let fetched = fetcher
                        .lock()
                        .map_err(poisoned)?
                        .fetch_all(&missing, *stall)
                        .map_err(|m| PyCbdamError::Network(format!("reading {name}: {m}")))?;
                    cache.lock().map_err(poisoned)?.keep(&fetched);
                    records.extend(fetched);
                }
                let record = |id: DiamondId| {
                    records.get(&id).map(|b| &b[..]).ok_or_else(|| {
                        CodecError::invalid(format!("{id} was not fetched for this window"))
                    })
                };
                decode(&record).map_err(decoding)
            }
        }
    }
}
