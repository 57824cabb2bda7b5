//! The server's settings (`cbdam serve`'s flags), read by the state, the connection loop and
//! the router.

use std::sync::Arc;
use std::time::Duration;

use crate::examples::WebLibs;
use crate::web::WebAssets;

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
    pub web: Option<Arc<WebAssets>>,
    /// The JavaScript libraries the example pages load (`--web-libs`: a `node_modules` with
    /// `cesium` and `maplibre-gl`), served under `/web-libs/`; without them the pages say what
    /// to install.
    pub web_libs: Option<Arc<WebLibs>>,
    /// The `attribution` of every repository's `layer.json` and TileJSON (`--attribution`);
    /// `None`: what the repository records of itself.
    pub attribution: Option<String>,
    /// Time a connection has to deliver a request's headers (`--header-timeout`): from its
    /// accept for the first request (protocol detection included), from the end of the last
    /// answer for the next ones on an HTTP/1.1 keep-alive connection, which this also closes
    /// when it stays idle that long.
    pub header_read_timeout: Duration,
    /// A connection that moves no byte either way for this long is closed
    /// (`--idle-timeout`): an idle HTTP/2 connection, or a client that stopped reading its
    /// answer. Longer than [`Config::timeout`], so a request being answered is not cut.
    pub idle_timeout: Duration,
    /// Most connections held open at once (`--max-connections`; lowered to what the process's
    /// file-descriptor limit allows). A connection beyond it closes the least recently active
    /// one of the client address holding the most connections (see [`crate::run`]).
    pub max_connections: usize,
    /// Most samples a repository's decoded levels (4 bytes a sample) may hold for the tiles to
    /// decode them whole in the background after the first tile request; past it, tiles keep
    /// decoding windows (a repository without records, which has no windows, is refused).
    pub max_tile_samples: u64,
    /// Most bytes of decoded windows a repository's web-map tiles keep (`--tile-cache`): cold
    /// mesh tiles of one group read one window, decoded once however many ask at a time.
    pub tile_cache: u64,
    /// Repositories opened from files whose records areas take at most this many bytes in
    /// all (in the order given) are read into memory when opened (`--hold-records`): records
    /// are then served without a read of the file, the file's identity still checked for each
    /// request. Larger ones are read record by record ([`crate::records`]).
    pub held_records_bytes: u64,
    /// Most bytes of streamed answers (batches, file ranges) made and not yet written, over
    /// all connections (`--answer-memory`): a body waits for room beyond it, and a connection
    /// that has held answer bytes without reading for a second is closed to make room
    /// ([`crate::answer_memory`]).
    pub answer_memory: u64,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            max_batch: 4096,
            max_body: 1 << 20,
            cors_origin: "*".to_string(),
            timeout: Duration::from_secs(30),
            web: None,
            web_libs: None,
            attribution: None,
            header_read_timeout: Duration::from_secs(10),
            idle_timeout: Duration::from_secs(60),
            max_connections: 10_000,
            max_tile_samples: 1 << 28,
            tile_cache: cbdam_tiles::windows::WINDOW_CACHE_BYTES as u64,
            held_records_bytes: 256 << 20,
            answer_memory: 32 << 20,
        }
    }
}
