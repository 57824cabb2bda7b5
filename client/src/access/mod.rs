//! The data access layer (paper §6): the one interface through which the refinement loop reaches
//! a repository, whether it is a memory-mapped file (`LocalSource`) or a remote server
//! (`RemoteSource`, over HTTP; both native only). The loop cannot tell which one it has.
//!
//! Everything is non-blocking. The loop, once per frame:
//! 1. calls [`DataSource::pump`] so the source can advance its I/O and collect completions;
//! 2. for each diamond it wants, asks [`DataSource::is_available`] and, if so, moves the record
//!    into its own RAM with [`DataSource::take`] (or, from a memory-mapped file, gets a
//!    [`DataSource::mapped`] handle that the worker decoding it reads); otherwise it posts
//!    [`DataSource::request`] with a priority (the diamond's screen-space error in pixels: larger
//!    is more urgent) and moves on;
//! 3. calls [`DataSource::cancel`] for requests the cut no longer needs.
//!
//! Contract for implementers:
//! - `request` is idempotent: re-requesting a pending diamond only updates its priority.
//!   Requests for diamonds that are not stored must be answered with an error, not ignored.
//! - A record handed out by `take` must be validated (the local source checks its CRC; a remote
//!   one checks the bytes against the head's checksums). Failures are reported through `take`
//!   as `Some(Err(..))` exactly once, after which the diamond is forgotten; the loop decides
//!   whether to retry.
//! - `take` of a diamond that is not available returns `None` immediately: it never waits.
//! - Head metadata (codec parameters, quantization plan, georeferencing, index, root field) is
//!   available from construction on: a remote source fetches and parses the head before it is
//!   handed to the loop.

pub mod coloured;
#[cfg(feature = "test-doubles")]
mod flaky;
mod http;
#[cfg(not(target_arch = "wasm32"))]
mod local;
mod mapped;

pub use coloured::{ColouredSource, Drape};
/// A test double (feature `test-doubles`): a repository with latency and failures.
#[cfg(feature = "test-doubles")]
pub use flaky::{FlakyConfig, FlakySource};
pub use mapped::MappedRecord;

/// HTTP over the target's fetcher (tokio and reqwest on the desktop, the page's `fetch` in a
/// browser).
pub use http::{Received, RemoteSource};
/// The desktop's memory-mapped file.
#[cfg(not(target_arch = "wasm32"))]
pub use local::LocalSource;

use cbdam_codec::CodecError;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::Decoder;
use cbdam_codec::repository::RepositoryHead;

/// Priority of a request: screen-space error in pixels. Larger is fetched first; prefetches use
/// a scaled-down error so that they never overtake what the current view needs.
pub type Priority = f32;

/// Why a record could not be had.
#[derive(Debug, thiserror::Error)]
pub enum AccessError {
    /// The bytes failed validation (checksum) or could not be read.
    #[error("record of {id} rejected: {source}")]
    Record {
        /// The diamond.
        id: DiamondId,
        /// What the codec said.
        source: CodecError,
    },
    /// The transport failed (connection, HTTP status, timeout).
    #[error("fetching {id} failed: {message}")]
    Transport {
        /// The diamond.
        id: DiamondId,
        /// What went wrong.
        message: String,
    },
}

/// Counters since the source was created.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AccessStats {
    /// Requests posted (re-prioritising a pending one does not count).
    pub requests_issued: u64,
    /// Requests withdrawn with [`DataSource::cancel`] before they completed.
    pub requests_cancelled: u64,
    /// Requests posted but not yet taken, failed or cancelled.
    pub in_flight: u64,
    /// Records handed out by [`DataSource::take`], or read through [`DataSource::mapped`].
    pub records_taken: u64,
    /// Bytes of records handed out (for a remote source: bytes received, retries included).
    pub bytes_fetched: u64,
    /// Failures reported through [`DataSource::take`].
    pub errors: u64,
}

/// `Send` where there are threads; nothing on wasm32, whose browser sources hold JavaScript
/// objects (which never leave the page's thread).
#[cfg(not(target_arch = "wasm32"))]
pub trait MaybeSend: Send {}
#[cfg(not(target_arch = "wasm32"))]
impl<T: Send + ?Sized> MaybeSend for T {}
/// `Send` where there are threads; nothing on wasm32, whose browser sources hold JavaScript
/// objects (which never leave the page's thread).
#[cfg(target_arch = "wasm32")]
pub trait MaybeSend {}
#[cfg(target_arch = "wasm32")]
impl<T: ?Sized> MaybeSend for T {}

/// Where records come from. See the module documentation for the contract.
pub trait DataSource: MaybeSend {
    /// The repository's validated head: its header fields (layout, coder, quantizer, data
    /// rectangle, georeferencing), the index of every stored diamond with its record length,
    /// object-space error and height range, and the coded root field.
    fn head(&self) -> &RepositoryHead;

    /// A decoder over the root field.
    fn decoder(&self) -> Result<Decoder, CodecError> {
        self.head().decoder()
    }

    /// The colour repository draped over this elevation, when the source pairs one
    /// ([`ColouredSource`]): its records are then elevation–colour pairs ([`coloured::split`]).
    fn drape(&self) -> Option<&Drape> {
        None
    }

    /// Asks for `id`'s record, or re-prioritises a pending request. Never blocks.
    fn request(&mut self, id: DiamondId, priority: Priority);
    /// Withdraws a request the cut no longer needs (a no-op if there is none). A record that
    /// already arrived is dropped.
    fn cancel(&mut self, id: DiamondId);
    /// Whether [`DataSource::take`] would return `Some` now.
    fn is_available(&self, id: DiamondId) -> bool;
    /// Whether [`DataSource::is_available`] is true for every id, always (a memory-mapped
    /// repository): the refiner then never needs to request anything and skips the passes that
    /// look for what to request. False unless a source promises it.
    fn always_available(&self) -> bool {
        false
    }
    /// Moves `id`'s validated record into the caller's RAM, or reports why it failed; `None`
    /// when it is not available yet. Never blocks.
    fn take(&mut self, id: DiamondId) -> Option<Result<Vec<u8>, AccessError>>;
    /// A handle on `id`'s record in a memory-mapped file, for whoever decodes it to read and
    /// check (a worker thread: nothing is copied on the caller's); its reads count in
    /// [`DataSource::stats`] like takes. `None` when the source maps no file or does not store
    /// `id`: the caller then takes the record. Never blocks.
    fn mapped(&self, id: DiamondId) -> Option<MappedRecord> {
        let _ = id;
        None
    }
    /// [`DataSource::mapped`] for `id`, whose entry is the `index`-th of
    /// [`DataSource::entries`]: a source that maps a file finds the record without searching
    /// its index (it checks that the entry is `id`'s, and searches if not).
    fn mapped_entry(&self, id: DiamondId, index: usize) -> Option<MappedRecord> {
        let _ = index;
        self.mapped(id)
    }
    /// Advances I/O: called once per frame before anything else.
    fn pump(&mut self);
    /// Counters.
    fn stats(&self) -> AccessStats;
}

/// A boxed source is a source: the command line picks local, remote and coloured sources at
/// run time.
impl<S: DataSource + ?Sized> DataSource for Box<S> {
    fn head(&self) -> &RepositoryHead {
        (**self).head()
    }
    fn decoder(&self) -> Result<Decoder, CodecError> {
        (**self).decoder()
    }
    fn drape(&self) -> Option<&Drape> {
        (**self).drape()
    }
    fn request(&mut self, id: DiamondId, priority: Priority) {
        (**self).request(id, priority)
    }
    fn cancel(&mut self, id: DiamondId) {
        (**self).cancel(id)
    }
    fn is_available(&self, id: DiamondId) -> bool {
        (**self).is_available(id)
    }
    fn always_available(&self) -> bool {
        (**self).always_available()
    }
    fn take(&mut self, id: DiamondId) -> Option<Result<Vec<u8>, AccessError>> {
        (**self).take(id)
    }
    fn mapped(&self, id: DiamondId) -> Option<MappedRecord> {
        (**self).mapped(id)
    }
    fn mapped_entry(&self, id: DiamondId, index: usize) -> Option<MappedRecord> {
        (**self).mapped_entry(id, index)
    }
    fn pump(&mut self) {
        (**self).pump()
    }
    fn stats(&self) -> AccessStats {
        (**self).stats()
    }
}
