//! `cbdam link`: a loopback shaping proxy in front of a server (the library is `cbdam-link`).

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use cbdam_link::{Counters, Link, Proxy};
use clap::Args;

use crate::flags;

/// Emulate a slower, longer network link in front of a server: a loopback TCP proxy that
/// forwards connections on --listen to --to with a one-way delay each way, downstream and
/// upstream rate caps shared by all connections, optional jitter and connection resets.
///
/// Profiles (rates in bits/s, delays one way): adsl 1.2M down / 256k up, 30 ms; dsl10 10M /
/// 1M, 25 ms; fibre 100M / 100M, 10 ms; mobile 5M / 1M, 60 ms ±10 ms, 1 % of connections
/// reset; custom: give --down, --up and --delay-ms. Any flag overrides the profile. Prints
/// the counters every --interval seconds with traffic; Ctrl-C (or SIGTERM) stops it.
#[derive(Args, Debug)]
pub struct LinkArgs {
    /// Link profile: adsl, dsl10, fibre, mobile or custom.
    #[arg(long)]
    profile: String,
    /// Address to listen on (port 0: any free port, printed).
    #[arg(long, default_value = "127.0.0.1:9000")]
    listen: SocketAddr,
    /// Upstream server to forward each connection to, e.g. the address of `cbdam serve`.
    #[arg(long)]
    to: SocketAddr,
    /// Downstream rate cap (server → client), bits/s with k, M or G (e.g. 1.2M).
    #[arg(long, value_name = "RATE")]
    down: Option<flags::BitRate>,
    /// Upstream rate cap (client → server), bits/s with k, M or G (e.g. 256k).
    #[arg(long, value_name = "RATE")]
    up: Option<flags::BitRate>,
    /// One-way delay each direction, ms (the round trip is twice this).
    #[arg(long, allow_hyphen_values = true)]
    delay_ms: Option<f64>,
    /// Jitter, ms: each piece's delay varies uniformly by ± this (bytes are never reordered).
    #[arg(long, allow_hyphen_values = true)]
    jitter_ms: Option<f64>,
    /// Probability that a connection is reset (within its first 64 KiB, or at its end).
    #[arg(long, allow_hyphen_values = true)]
    reset_prob: Option<f64>,
    /// Seed of the reset and jitter draws.
    #[arg(long)]
    seed: Option<u64>,
    /// Seconds between counter lines (0: only the totals when stopped).
    #[arg(
        long,
        default_value_t = 1.0,
        value_parser = flags::non_negative_finite,
        allow_hyphen_values = true
    )]
    interval: f64,
}

/// The link of the arguments: the profile with the overrides applied.
fn link_of(args: &LinkArgs) -> Result<Link> {
    let mut link = if args.profile.trim().eq_ignore_ascii_case("custom") {
        let missing: Vec<&str> = [
            ("--down", args.down.is_none()),
            ("--up", args.up.is_none()),
            ("--delay-ms", args.delay_ms.is_none()),
        ]
        .iter()
        .filter(|(_, m)| *m)
        .map(|(f, _)| *f)
        .collect();
        if !missing.is_empty() {
            bail!("--profile custom needs {}", missing.join(", "));
        }
        Link::custom(0, 0, Duration::ZERO)
    } else {
        args.profile.parse::<Link>().map_err(anyhow::Error::msg)?
    };
    let ms = |flag: &str, v: f64| -> Result<Duration> {
        if !(v.is_finite() && (0.0..=60_000.0).contains(&v)) {
            bail!("{flag} must be a number of milliseconds from 0 to 60000, not {v}");
        }
        Ok(Duration::from_secs_f64(v / 1e3))
    };
    if let Some(r) = args.down {
        link.down_bps = r.0;
    }
    if let Some(r) = args.up {
        link.up_bps = r.0;
    }
    if let Some(v) = args.delay_ms {
        link.delay = ms("--delay-ms", v)?;
    }
    if let Some(v) = args.jitter_ms {
        link.jitter = ms("--jitter-ms", v)?;
    }
    if let Some(p) = args.reset_prob {
        if !(0.0..=1.0).contains(&p) {
            bail!("--reset-prob must be a probability from 0 to 1, not {p}");
        }
        link.reset_prob = p;
    }
    if let Some(s) = args.seed {
        link.seed = s;
    }
    link.validate().map_err(anyhow::Error::msg)?;
    Ok(link)
}

fn megabytes(b: u64) -> String {
    format!("{:.2} MB", b as f64 / 1e6)
}

/// One counter line: the totals since the start and what changed since `last`, with the rates
/// over the last --interval, and the connections the upstream server dropped.
fn print_counters(c: &Counters, last: &Counters, elapsed_s: f64, args: &LinkArgs) {
    let bps =
        |now: u64, then: u64| format!("{:.3} Mbit/s", (now - then) as f64 * 8e-6 / args.interval);
    println!(
        "{:8.1} s  connections {} (+{})  resets {} (+{})  down {} ({})  up {} ({})",
        elapsed_s,
        c.connections,
        c.connections - last.connections,
        c.resets,
        c.resets - last.resets,
        bps(c.bytes_down, last.bytes_down),
        megabytes(c.bytes_down),
        bps(c.bytes_up, last.bytes_up),
        megabytes(c.bytes_up),
    );
    if c.upstream_errors > last.upstream_errors {
        println!(
            "          {} connections dropped: {} unreachable",
            c.upstream_errors - last.upstream_errors,
            args.to
        );
    }
}

pub fn run(args: &LinkArgs) -> Result<()> {
    let link = link_of(args)?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    rt.block_on(async {
        let proxy = Proxy::start(args.listen, args.to, link)
            .await
            .with_context(|| format!("listening on {}", args.listen))?;
        println!(
            "link: {} -> {} over {} ({link}; bursts {} B down, {} B up)",
            proxy.local_addr(),
            args.to,
            args.profile.trim().to_ascii_lowercase(),
            Link::burst(link.down_bps),
            Link::burst(link.up_bps),
        );
        // Signal handlers before the address is announced (see `shutdown_signal`).
        let stop = cbdam_server::shutdown_signal();
        println!("listening on {}; Ctrl-C stops", proxy.local_addr());
        let start = Instant::now();
        let mut last = Counters::default();
        let mut tick = (args.interval > 0.0)
            .then(|| tokio::time::interval(Duration::from_secs_f64(args.interval)));
        tokio::pin!(stop);
        loop {
            let ticked = async {
                match tick.as_mut() {
                    Some(t) => {
                        t.tick().await;
                    }
                    None => std::future::pending().await,
                }
            };
            tokio::select! {
                () = &mut stop => break,
                () = ticked => {
                    let c = proxy.counters();
                    if c == last {
                        continue;
                    }
                    print_counters(&c, &last, start.elapsed().as_secs_f64(), args);
                    last = c;
                }
            }
        }
        let c = proxy.shutdown().await;
        println!(
            "stopped after {:.1} s: {} connections, {} reset, {} down, {} up, {} upstream errors",
            start.elapsed().as_secs_f64(),
            c.connections,
            c.resets,
            megabytes(c.bytes_down),
            megabytes(c.bytes_up),
            c.upstream_errors
        );
        Ok(())
    })
}
