//! `cbdam serve`: the HTTP server of diamond records (the library is `cbdam-server`).

use std::io::IsTerminal;
use std::net::SocketAddr;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use cbdam_server::{AppState, Config, RepoSpec};
use clap::Args;
use tokio::net::TcpListener;
use tokio::sync::oneshot;
use tracing_subscriber::EnvFilter;

/// Serve repositories over HTTP/1.1 and HTTP/2 (cleartext): per-diamond records, batches,
/// the header as JSON, the raw file with range requests, and Prometheus metrics.
///
/// Endpoints and the batch framing: docs/HTTP-API.md. Logs go to stderr,
/// filtered by RUST_LOG (default info, one line per request). Stops on SIGINT/SIGTERM after
/// the requests in flight finish.
#[derive(Args, Debug)]
pub struct ServeArgs {
    /// Repositories: PATH (served under its file stem) or NAME=PATH. Names may use
    /// A-Z a-z 0-9 . _ - and must be unique.
    #[arg(required = true, value_name = "REPO")]
    repos: Vec<String>,
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1:8080")]
    addr: SocketAddr,
    /// Most diamond ids in one batch request (more: 413).
    #[arg(long, default_value_t = 4096)]
    max_batch: usize,
    /// Largest request body, bytes (more: 413).
    #[arg(long, default_value_t = 1 << 20)]
    max_body: usize,
    /// Access-Control-Allow-Origin: `*` or a comma-separated list of origins.
    #[arg(long, default_value = "*")]
    cors_origin: String,
    /// Time allowed for one request, seconds (then 408).
    #[arg(long, default_value_t = 30.0, value_parser = crate::flags::positive_finite)]
    timeout: f64,
    /// Time a connection has to send a request's headers, seconds: from its accept for the
    /// first request, from the last answer for the next (an idle keep-alive connection is
    /// closed then).
    #[arg(long, default_value_t = 10.0, value_parser = crate::flags::positive_finite)]
    header_timeout: f64,
    /// A connection that moves no byte either way for this long is closed, seconds (an idle
    /// HTTP/2 connection, a client that does not read its answer).
    #[arg(long, default_value_t = 60.0, value_parser = crate::flags::positive_finite)]
    idle_timeout: f64,
    /// Most connections open at once (fewer if the file-descriptor limit is lower): one more
    /// closes the least recently active connection of the client address holding the most.
    #[arg(long, default_value_t = 10_000)]
    max_connections: usize,
    /// Most samples a repository's decoded levels (4 bytes a sample) may hold for web-map tiles
    /// (docs/WEB-MAPS.md) to decode them whole, in the background after the first tile; past
    /// it, every tile decodes only the records within its reach (a repository without records
    /// past it answers 404 for tiles, naming the limit).
    #[arg(long, default_value_t = 1 << 28)]
    max_tile_samples: u64,
    /// Most bytes of decoded windows each repository's web-map tiles keep (e.g. 256M; 0: none
    /// kept): the cold mesh tiles of a 4 × 4 group read one window, decoded once however many
    /// ask for it at a time (docs/WEB-MAPS.md).
    #[arg(long, default_value = "256M", value_name = "SIZE")]
    tile_cache: crate::flags::ByteSize,
    /// The browser viewer's files (the bundle `scripts/web-build.sh` writes, e.g.
    /// target/web-bundle): `/` then links every repository to the viewer, served under
    /// `/viewer/HASH/`. Without it `/` only lists the repositories.
    #[arg(long, value_name = "DIR")]
    web: Option<std::path::PathBuf>,
    /// The JavaScript libraries of the web-map example pages (`/examples/cesium.html?repo=NAME`
    /// and `/examples/maplibre.html?repo=NAME`, linked from `/`): a `node_modules` holding
    /// `cesium` and `maplibre-gl` (`npm install cesium maplibre-gl`), served under `/web-libs/`
    /// so the pages fetch nothing from other hosts. Without it the pages say what to install.
    #[arg(long, value_name = "DIR")]
    web_libs: Option<std::path::PathBuf>,
    /// The `attribution` of every repository's web-map `layer.json` and TileJSON (the credit
    /// viewers show, e.g. the data's source). Default: what the repository records of itself.
    #[arg(long, value_name = "TEXT")]
    attribution: Option<String>,
    /// Worker threads (default: one per core).
    #[arg(long)]
    threads: Option<usize>,
    /// Repositories whose records areas take at most this much in all (e.g. 256M, 1G; in the
    /// order given) are read into memory at start and served from it; larger ones are read
    /// from their files record by record (`--hold-records 1`: every one).
    #[arg(long, default_value = "256M", value_name = "SIZE")]
    hold_records: crate::flags::ByteSize,
    /// Most bytes of streamed answers (batches, file ranges) made and not yet written, over
    /// all connections (e.g. 32M): beyond it answers wait for room, and a connection that has
    /// held answer bytes without reading for a second is closed to make room.
    #[arg(long, default_value = "32M", value_name = "SIZE")]
    answer_memory: crate::flags::ByteSize,
}

/// Logs to stderr, filtered by `RUST_LOG` (default `info`: startup, errors, one line per
/// request except successful record requests, which log at debug:
/// `RUST_LOG=info,cbdam_server::access=debug` logs every request, `RUST_LOG=warn` none).
fn init_logging() {
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info"));
    // Fails only when a subscriber is already installed, which is then the one to keep.
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .try_init();
}

pub fn run(args: &ServeArgs) -> Result<()> {
    if args.max_batch == 0 {
        bail!("--max-batch must be at least 1");
    }
    let specs = args
        .repos
        .iter()
        .map(|s| s.parse::<RepoSpec>())
        .collect::<Result<Vec<_>, _>>()?;
    let config = server_config(args)?;
    let timeout = config.timeout;
    init_logging();
    log_raised_fd_limit();
    let state = AppState::open(&specs, config)?;
    let mut rt = tokio::runtime::Builder::new_multi_thread();
    if let Some(n) = args.threads {
        rt.worker_threads(n.max(1));
    }
    let rt = rt
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    rt.block_on(async {
        let listener = TcpListener::bind(args.addr)
            .await
            .with_context(|| format!("binding {}", args.addr))?;
        let addr = listener.local_addr()?;
        // Signal handlers first: a client (or a test) may signal as soon as it reads the address.
        let shutdown = cbdam_server::shutdown_signal();
        log_addresses(&state, &specs, addr);
        serve_until_signalled(listener, state, shutdown, timeout).await
    })
}

/// The server's settings from the flags (the browser viewer's files read from `--web`).
fn server_config(args: &ServeArgs) -> Result<Config> {
    let web = match &args.web {
        Some(dir) => Some(std::sync::Arc::new(cbdam_server::WebAssets::load(dir)?)),
        None => None,
    };
    let web_libs = match &args.web_libs {
        Some(dir) => Some(std::sync::Arc::new(cbdam_server::WebLibs::open(dir)?)),
        None => None,
    };
    Ok(Config {
        max_batch: args.max_batch,
        max_body: args.max_body,
        cors_origin: args.cors_origin.clone(),
        timeout: Duration::from_secs_f64(args.timeout),
        web,
        web_libs,
        attribution: args.attribution.clone(),
        header_read_timeout: Duration::from_secs_f64(args.header_timeout),
        idle_timeout: Duration::from_secs_f64(args.idle_timeout),
        max_connections: args.max_connections,
        max_tile_samples: args.max_tile_samples,
        tile_cache: args.tile_cache.0,
        held_records_bytes: args.hold_records.0,
        answer_memory: args.answer_memory.0,
    })
}

/// Raises the soft limit on open files to the hard one, and says so.
fn log_raised_fd_limit() {
    if let Some((before, after)) = cbdam_server::raise_fd_limit() {
        let after = if after == u64::MAX {
            "unlimited".to_string()
        } else {
            after.to_string()
        };
        tracing::info!(
            "raised the soft limit on open files from {before} to the hard limit, {after} \
             (it bounds --max-connections)"
        );
    }
}

/// Where each repository is served, the listening address, and where the browser viewer is.
fn log_addresses(state: &AppState, specs: &[RepoSpec], addr: SocketAddr) {
    for (name, spec) in state.names().iter().zip(specs) {
        tracing::info!(
            "serving {} as http://{addr}/v1/repos/{name}/meta",
            spec.path.display()
        );
    }
    tracing::info!("listening on http://{addr}");
    match &state.config().web {
        Some(web) => tracing::info!(
            "browser viewer: http://{addr}/ (files under /viewer/{}/)",
            web.hash()
        ),
        None => tracing::info!(
            "repositories listed at http://{addr}/ (the browser viewer with --web DIR)"
        ),
    }
    if state.config().web_libs.is_some() {
        tracing::info!(
            "web-map examples: http://{addr}/examples/cesium.html?repo=NAME, …/maplibre.html?repo=NAME"
        );
    }
}

/// Serves on `listener` until `shutdown` (SIGINT/SIGTERM), then gives the requests in flight
/// their timeout plus a little to finish.
async fn serve_until_signalled(
    listener: TcpListener,
    state: AppState,
    shutdown: impl std::future::Future<Output = ()>,
    timeout: Duration,
) -> Result<()> {
    let (stop, stopped) = oneshot::channel::<()>();
    let mut server = tokio::spawn(cbdam_server::run(listener, state, async {
        let _ = stopped.await;
    }));
    tokio::select! {
        r = &mut server => {
            // The server ended without being asked to: an I/O error on the listener.
            r.context("server task")??;
            return Ok(());
        }
        () = shutdown => {}
    }
    let _ = stop.send(());
    // In-flight requests get their timeout plus a little to finish; then exit regardless
    // (an idle keep-alive client must not hold the process up).
    let grace = timeout + Duration::from_secs(5);
    match tokio::time::timeout(grace, &mut server).await {
        Ok(r) => r.context("server task")??,
        Err(_) => tracing::warn!("connections still open after {grace:?}; exiting anyway"),
    }
    tracing::info!("stopped");
    Ok(())
}
