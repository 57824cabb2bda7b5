//! `cbdam serve`: the HTTP server of diamond records (the library is `cbdam-server`).

use std::io::IsTerminal;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use cbdam_server::{AppState, Config, RepoSpec};
use tokio::net::TcpListener;
use tokio::sync::oneshot;
use tracing_subscriber::EnvFilter;

use crate::ServeArgs;

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
    if !(args.timeout.is_finite() && args.timeout > 0.0) {
        bail!("--timeout must be a positive number of seconds");
    }
    for (flag, v) in [
        ("--header-timeout", args.header_timeout),
        ("--idle-timeout", args.idle_timeout),
    ] {
        if !(v.is_finite() && v > 0.0) {
            bail!("{flag} must be a positive number of seconds");
        }
    }
    if args.max_batch == 0 {
        bail!("--max-batch must be at least 1");
    }
    let specs = args
        .repos
        .iter()
        .map(|s| s.parse::<RepoSpec>())
        .collect::<Result<Vec<_>, _>>()?;
    let timeout = Duration::from_secs_f64(args.timeout);
    let web = match &args.web {
        Some(dir) => Some(std::sync::Arc::new(cbdam_server::WebAssets::load(dir)?)),
        None => None,
    };
    let config = Config {
        max_batch: args.max_batch,
        max_body: args.max_body,
        cors_origin: args.cors_origin.clone(),
        timeout,
        web,
        header_read_timeout: Duration::from_secs_f64(args.header_timeout),
        idle_timeout: Duration::from_secs_f64(args.idle_timeout),
        max_connections: args.max_connections,
    };
    init_logging();
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
        for (name, spec) in state.names().iter().zip(&specs) {
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
    })
}
