//! `cbdam bench serve`: load test of the HTTP server over loopback, in one process.
//!
//! The server runs on its own tokio runtime and the load generator on another, so the thread
//! split between them is explicit (`--server-threads`, `--client-threads`) rather than left to
//! one work-stealing scheduler. Each client holds one keep-alive HTTP/1.1 connection and sends
//! requests back to back; latency is measured per request from send to the last body byte.
//!
//! The generator shares the machine with the server, so every microsecond it spends is one the
//! server does not get. It is therefore a minimal HTTP/1.1 client written here: requests are
//! encoded before the clock starts, each connection is one task (a hyper client connection
//! is two, handing every request across a channel), and a response is parsed with `httparse`,
//! its status and `Content-Length` checked and its body read to the last byte.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail, ensure};
use cbdam_codec::repository::Repository;
use cbdam_codec::repository::index::IndexEntry;
use cbdam_server::{AppState, Config, RepoSpec};
use clap::Args;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// Load test of the HTTP server: concurrent clients fetching random stored diamonds, one per
/// request and in batches, over loopback; records/s, MB/s and latency as a Markdown table.
#[derive(Args, Debug)]
pub struct BenchServeArgs {
    /// Repository to serve. Default: built from data/srtm3_demcompare.tif at ε = 1 m into a
    /// temporary directory.
    repo: Option<PathBuf>,
    /// Concurrent clients, each on its own keep-alive HTTP/1.1 connection.
    #[arg(long, default_value_t = 64)]
    clients: usize,
    /// Seconds per measured run.
    #[arg(long, default_value_t = 5.0, value_parser = crate::flags::positive_finite)]
    seconds: f64,
    /// Most requests per run (the other bound besides --seconds).
    #[arg(long, default_value_t = 5_000_000)]
    max_requests: u64,
    /// Ids per batch request (0: skip the batched runs).
    #[arg(long, default_value_t = 64)]
    batch: usize,
    /// Runs per mode; the median run (by records/s) is reported.
    #[arg(long, default_value_t = 3)]
    runs: usize,
    /// Server worker threads.
    #[arg(long, default_value_t = 1)]
    server_threads: usize,
    /// Load-generator worker threads (its own runtime, so the two do not share a scheduler).
    #[arg(long, default_value_t = 1)]
    client_threads: usize,
}

const NAME: &str = "bench";

/// What one request asks for, prepared before the clock starts.
struct Job {
    /// The whole HTTP/1.1 request: a GET, or a POST with a JSON body.
    request: Vec<u8>,
    /// Records and body bytes the answer must have (checked, so a broken server cannot post
    /// good figures).
    records: u64,
    bytes: usize,
}

#[derive(Default)]
struct ClientStats {
    requests: u64,
    records: u64,
    bytes: u64,
    latencies_us: Vec<u32>,
}

struct RunResult {
    /// CPU time of the server's and the load generator's threads during the run, seconds.
    server_cpu: f64,
    client_cpu: f64,
    requests: u64,
    records: u64,
    bytes: u64,
    elapsed: Duration,
    p50_us: u32,
    p99_us: u32,
}

impl RunResult {
    fn records_per_s(&self) -> f64 {
        self.records as f64 / self.elapsed.as_secs_f64()
    }
}

/// CPU seconds (user + system) used so far by this process's threads named `name`, from
/// /proc (Linux; 0 elsewhere). On a machine shared with other work the wall-clock rates depend
/// on how much CPU the benchmark got; CPU time per request does not.
fn thread_cpu(name: &str) -> f64 {
    let Ok(dir) = std::fs::read_dir("/proc/self/task") else {
        return 0.0;
    };
    let mut ticks = 0u64;
    for t in dir.flatten() {
        let Ok(stat) = std::fs::read_to_string(t.path().join("stat")) else {
            continue;
        };
        // "tid (comm) state ..." — comm may contain spaces, so split at the last ')'.
        let (Some(open), Some(close)) = (stat.find('('), stat.rfind(')')) else {
            continue;
        };
        if &stat[open + 1..close] != name {
            continue;
        }
        let f: Vec<&str> = stat[close + 1..].split_whitespace().collect();
        // Fields 14 and 15 of stat (utime, stime) are at 11 and 12 after the comm.
        if let (Some(u), Some(s)) = (f.get(11), f.get(12)) {
            ticks += u.parse::<u64>().unwrap_or(0) + s.parse::<u64>().unwrap_or(0);
        }
    }
    // USER_HZ is 100 on every Linux configuration in practice.
    ticks as f64 / 100.0
}

/// SplitMix64, one per client.
struct Rng(u64);
impl Rng {
    fn below(&mut self, n: usize) -> usize {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) % n as u64) as usize
    }
}

fn default_repo(dir: &Path) -> Result<PathBuf> {
    let input = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/srtm3_demcompare.tif");
    let output = dir.join("srtm3_demcompare.cbdam");
    eprintln!("building {} at ε = 1 m …", output.display());
    cbdam_builder::build(
        &cbdam_builder::BuildOptions::new(vec![input], output.clone(), 1.0),
        &cbdam_builder::NoProgress,
    )?;
    Ok(output)
}

/// One GET of each stored record.
fn single_jobs(entries: &[IndexEntry]) -> Vec<Job> {
    entries
        .iter()
        .map(|e| Job {
            request: get_request(&format!("/v1/repos/{NAME}/diamonds/{}", e.id)),
            records: 1,
            bytes: e.length as usize,
        })
        .collect()
}

/// 256 batch POSTs of `batch` records each, drawn at random (a fixed seed); none for 0.
fn batch_jobs(entries: &[IndexEntry], batch: usize) -> Vec<Job> {
    if batch == 0 {
        return Vec::new();
    }
    let mut rng = Rng(0x5EED);
    (0..256)
        .map(|_| {
            let picks: Vec<usize> = (0..batch).map(|_| rng.below(entries.len())).collect();
            let ids: Vec<String> = picks.iter().map(|&i| entries[i].id.to_string()).collect();
            let bytes = 8 + picks
                .iter()
                .map(|&i| 5 + entries[i].length as usize)
                .sum::<usize>();
            Job {
                request: post_request(
                    &format!("/v1/repos/{NAME}/diamonds"),
                    &serde_json::json!({ "ids": ids }).to_string(),
                ),
                records: batch as u64,
                bytes,
            }
        })
        .collect()
}

/// The table row of one mode: its median run by records/s, after every run's rate.
fn print_median_run(mode: &str, per: usize, runs: &mut [RunResult]) {
    runs.sort_by(|a, b| a.records_per_s().total_cmp(&b.records_per_s()));
    let all: Vec<String> = runs
        .iter()
        .map(|r| format!("{:.0}", r.records_per_s()))
        .collect();
    let m = &runs[runs.len() / 2];
    println!(
        "| {mode} (median of {}: {} records/s) | {per} | {} | {} | {:.0} | {:.1} | {:.3} | {:.3} \
         | {:.1} | {:.1} | {:.2} |",
        runs.len(),
        all.join(" / "),
        m.requests,
        m.records,
        m.records_per_s(),
        m.bytes as f64 / 1e6 / m.elapsed.as_secs_f64(),
        f64::from(m.p50_us) / 1000.0,
        f64::from(m.p99_us) / 1000.0,
        m.server_cpu * 1e6 / m.requests as f64,
        m.client_cpu * 1e6 / m.requests as f64,
        (m.server_cpu + m.client_cpu) / m.elapsed.as_secs_f64(),
    );
}

/// Every mode's runs against the server at `addr` (single GETs, then batch POSTs unless
/// --batch 0), a table row each.
fn measure_modes(
    args: &BenchServeArgs,
    client_rt: &tokio::runtime::Runtime,
    addr: SocketAddr,
    singles: Vec<Job>,
    batches: Vec<Job>,
) -> Result<()> {
    let singles = Arc::new(singles);
    let batches = Arc::new(batches);
    let modes: Vec<(&str, usize, &Arc<Vec<Job>>)> = if args.batch == 0 {
        vec![("single GET", 1, &singles)]
    } else {
        vec![
            ("single GET", 1, &singles),
            ("batch POST", args.batch, &batches),
        ]
    };
    for (mode, per, jobs) in modes {
        let mut runs = Vec::new();
        for run in 0..args.runs {
            let r = client_rt.block_on(load_run(addr, jobs, args, run as u64))?;
            runs.push(r);
        }
        print_median_run(mode, per, &mut runs);
    }
    Ok(())
}

/// A tokio runtime of `threads` workers (at least one) named `name`.
fn runtime(threads: usize, name: &str) -> Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_multi_thread()
        .worker_threads(threads.max(1))
        .thread_name(name)
        .enable_all()
        .build()?)
}

/// The 1, 5 and 15 minute load averages (empty where /proc/loadavg is not).
fn load_average() -> String {
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    load.split_whitespace()
        .take(3)
        .collect::<Vec<_>>()
        .join(" ")
}

pub fn run(args: &BenchServeArgs) -> Result<()> {
    ensure!(args.clients > 0, "--clients must be at least 1");
    ensure!(args.runs > 0, "--runs must be at least 1");
    let tmp = tempfile::tempdir()?;
    let path = match &args.repo {
        Some(p) => p.clone(),
        None => default_repo(tmp.path())?,
    };
    let spec = RepoSpec {
        name: NAME.into(),
        path: path.clone(),
    };
    let state = AppState::open(
        &[spec],
        Config {
            max_batch: args.batch.max(1),
            ..Config::default()
        },
    )?;
    let repo: &Repository = &state.repo(NAME).expect("just opened").repo;
    // Only records that pass their checksum: a damaged one would answer 500 and fail the run.
    repo.check_all()
        .with_context(|| format!("checking {}", path.display()))?;
    let entries = repo.head().entries();
    ensure!(!entries.is_empty(), "{} stores no records", path.display());
    let singles = single_jobs(entries);
    let batches = batch_jobs(entries, args.batch);
    let mean_record = repo
        .head()
        .section_len(cbdam_codec::repository::Section::Records) as f64
        / entries.len() as f64;

    let server_rt = runtime(args.server_threads, "server")?;
    let client_rt = runtime(args.client_threads, "client")?;
    let listener = server_rt.block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))?;
    let addr = listener.local_addr()?;
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = server_rt.spawn(cbdam_server::run(listener, state.clone(), async {
        let _ = stopped.await;
    }));

    println!(
        "repository {}: {} records, mean {:.0} B; {} clients, {} s × {} runs per mode, \
         server threads {}, client threads {}; load average before: {}",
        path.display(),
        entries.len(),
        mean_record,
        args.clients,
        args.seconds,
        args.runs,
        args.server_threads,
        args.client_threads,
        load_average()
    );
    println!();
    println!(
        "| mode | ids/request | requests | records | records/s | MB/s | p50 ms | p99 ms | \
         server CPU µs/request | client CPU µs/request | CPU used (cores) |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    measure_modes(args, &client_rt, addr, singles, batches)?;
    let load = load_average();
    println!();
    println!(
        "load average after: {load}; MB/s counts response bodies (records and batch framing)."
    );
    let _ = stop.send(());
    server_rt
        .block_on(async { tokio::time::timeout(Duration::from_secs(10), server).await })
        .context("server did not stop")???;
    Ok(())
}

async fn load_run(
    addr: SocketAddr,
    jobs: &Arc<Vec<Job>>,
    args: &BenchServeArgs,
    run: u64,
) -> Result<RunResult> {
    // Connect everyone before the clock starts.
    let mut streams = Vec::with_capacity(args.clients);
    for _ in 0..args.clients {
        let stream = TcpStream::connect(addr).await?;
        stream.set_nodelay(true)?;
        streams.push(stream);
    }
    let budget = Arc::new(AtomicU64::new(args.max_requests));
    let (server0, client0) = (thread_cpu("server"), thread_cpu("client"));
    let start = Instant::now();
    let deadline = start + Duration::from_secs_f64(args.seconds);
    let tasks: Vec<_> = streams
        .into_iter()
        .enumerate()
        .map(|(c, stream)| {
            let jobs = Arc::clone(jobs);
            let budget = Arc::clone(&budget);
            let seed = (run << 32) ^ c as u64;
            tokio::spawn(client(stream, jobs, budget, deadline, seed))
        })
        .collect();
    let mut total = ClientStats::default();
    for t in tasks {
        let s = t.await??;
        total.requests += s.requests;
        total.records += s.records;
        total.bytes += s.bytes;
        total.latencies_us.extend(s.latencies_us);
    }
    let elapsed = start.elapsed();
    let (server_cpu, client_cpu) = (
        thread_cpu("server") - server0,
        thread_cpu("client") - client0,
    );
    if total.requests == 0 {
        bail!("no request completed");
    }
    total.latencies_us.sort_unstable();
    let q = |p: f64| {
        let v = &total.latencies_us;
        v[((v.len() - 1) as f64 * p).round() as usize]
    };
    Ok(RunResult {
        server_cpu,
        client_cpu,
        requests: total.requests,
        records: total.records,
        bytes: total.bytes,
        elapsed,
        p50_us: q(0.50),
        p99_us: q(0.99),
    })
}

fn get_request(path: &str) -> Vec<u8> {
    format!("GET {path} HTTP/1.1\r\nhost: bench\r\n\r\n").into_bytes()
}

fn post_request(path: &str, json: &str) -> Vec<u8> {
    format!(
        "POST {path} HTTP/1.1\r\nhost: bench\r\ncontent-type: application/json\r\n\
         content-length: {}\r\n\r\n{json}",
        json.len()
    )
    .into_bytes()
}

/// What [`parse_head`] found in a response head.
#[derive(Debug, PartialEq)]
struct Head {
    status: u16,
    /// Length of the head, the blank line included: the body starts there.
    len: usize,
    content_length: usize,
}

/// Parses the head of an HTTP/1.1 response at the start of `buf`: `None` while it is
/// incomplete. A response this client cannot frame (no `Content-Length`, or chunked) is an
/// error rather than a guess.
fn parse_head(buf: &[u8]) -> Result<Option<Head>> {
    let mut headers = [httparse::EMPTY_HEADER; 32];
    let mut resp = httparse::Response::new(&mut headers);
    let len = match resp.parse(buf).context("malformed response head")? {
        httparse::Status::Partial => return Ok(None),
        httparse::Status::Complete(n) => n,
    };
    ensure!(resp.version == Some(1), "not an HTTP/1.1 response");
    let mut content_length = None;
    for h in resp.headers.iter() {
        if h.name.eq_ignore_ascii_case("content-length") {
            let v = std::str::from_utf8(h.value)
                .ok()
                .and_then(|v| v.trim().parse().ok());
            ensure!(
                content_length.is_none() && v.is_some(),
                "bad or repeated content-length"
            );
            content_length = v;
        } else if h.name.eq_ignore_ascii_case("transfer-encoding") {
            bail!("unexpected transfer-encoding in a response");
        }
    }
    Ok(Some(Head {
        status: resp.code.context("no status")?,
        len,
        content_length: content_length.context("response without content-length")?,
    }))
}

async fn client(
    mut stream: TcpStream,
    jobs: Arc<Vec<Job>>,
    budget: Arc<AtomicU64>,
    deadline: Instant,
    seed: u64,
) -> Result<ClientStats> {
    let mut rng = Rng(seed);
    let mut s = ClientStats {
        latencies_us: Vec::with_capacity(1 << 16),
        ..ClientStats::default()
    };
    let mut buf: Vec<u8> = Vec::with_capacity(1 << 16);
    while Instant::now() < deadline
        && budget
            .fetch_update(Relaxed, Relaxed, |b| b.checked_sub(1))
            .is_ok()
    {
        let job = &jobs[rng.below(jobs.len())];
        let t0 = Instant::now();
        stream.write_all(&job.request).await?;
        // One request in flight per connection, so everything read belongs to its response.
        buf.clear();
        let head = loop {
            if let Some(h) = parse_head(&buf)? {
                break h;
            }
            ensure!(
                stream.read_buf(&mut buf).await? > 0,
                "connection closed mid-response"
            );
        };
        let end = head.len + head.content_length;
        buf.reserve(end.saturating_sub(buf.len()));
        while buf.len() < end {
            ensure!(
                stream.read_buf(&mut buf).await? > 0,
                "connection closed mid-body"
            );
        }
        let us = t0.elapsed().as_micros().min(u128::from(u32::MAX)) as u32;
        ensure!(buf.len() == end, "bytes after the response body");
        ensure!(
            head.status == 200,
            "request {} answered {}",
            s.requests,
            head.status
        );
        ensure!(
            head.content_length == job.bytes,
            "{} body bytes, expected {}",
            head.content_length,
            job.bytes
        );
        s.latencies_us.push(us);
        s.requests += 1;
        s.records += job.records;
        s.bytes += head.content_length as u64;
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn response_heads() {
        let r = b"HTTP/1.1 200 OK\r\ncontent-length: 5\r\netag: \"x\"\r\n\r\nhello";
        assert_eq!(
            parse_head(r).unwrap(),
            Some(Head {
                status: 200,
                len: r.len() - 5,
                content_length: 5
            })
        );
        assert_eq!(parse_head(&r[..20]).unwrap(), None);
        let nolen = b"HTTP/1.1 404 Not Found\r\nx: y\r\n\r\n";
        assert!(parse_head(nolen).is_err());
        let chunked = b"HTTP/1.1 200 OK\r\ntransfer-encoding: chunked\r\ncontent-length: 1\r\n\r\n";
        assert!(parse_head(chunked).is_err());
        assert!(parse_head(b"HTTP/1.1 200 OK\r\ncontent-length: x\r\n\r\n").is_err());
        assert!(parse_head(b"garbage\r\n\r\n").is_err());
    }
}
