//! A server in a child process (this test binary again, running [`server_child`]), so that its
//! file-descriptor limit and its memory are its own to lower and to measure, and the clients
//! that flood it: idle connections, batch requests whose answers nobody reads. Everything
//! listens and connects on 127.0.0.1 only.

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use cbdam_server::{AppState, Config};
use tokio::io::AsyncWriteExt;
use tokio::net::TcpStream;

/// The environment variable that makes [`server_child`] a server: its settings, `key=value`
/// pairs separated by commas.
pub const CHILD: &str = "CBDAM_SERVER_TEST_CHILD";

/// A repository of white noise: large records (a few hundred bytes to kilobytes), so that a
/// batch answer is megabytes.
pub fn noise_repo() -> cbdam_codec::repository::Repository {
    use cbdam_codec::hierarchy::{EncodeOptions, Encoder};
    use cbdam_codec::quant::{HeightGrid, QuantPlan};
    let (w, h) = (129usize, 129usize);
    let mut s = 7u64;
    let metres: Vec<f64> = (0..w * h)
        .map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 40) as f64 / (1u64 << 24) as f64 * 1000.0
        })
        .collect();
    let plan = QuantPlan::new(0.5, None, 0.0, 1000.0).unwrap();
    let grid = HeightGrid::from_metres(w, h, &metres, None, &plan).unwrap();
    let opts = EncodeOptions {
        n: 33,
        ..EncodeOptions::default()
    };
    let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
    let bytes = cbdam_codec::repository::serialize(&enc, &plan, None, None).unwrap();
    cbdam_codec::repository::Repository::from_bytes(bytes).unwrap()
}

/// Not a test: the server the flood tests start in a child process. Serves [`noise_repo`] as `t`
/// on 127.0.0.1, prints `LISTENING addr` and runs until its standard input closes. Settings
/// (from [`CHILD`]): `nofile=N` (the soft file-descriptor limit), `max_connections=N`,
/// `answer_memory=BYTES`.
#[test]
#[ignore = "not a test: the server that the flood tests run in a child process"]
pub fn server_child() {
    let Ok(spec) = std::env::var(CHILD) else {
        return;
    };
    let mut config = Config::default();
    for kv in spec.split(',').filter(|s| !s.is_empty()) {
        match kv.split_once('=') {
            Some(("nofile", v)) => {
                set_fd_limit(v.parse().unwrap());
            }
            Some(("max_connections", v)) => config.max_connections = v.parse().unwrap(),
            Some(("answer_memory", v)) => config.answer_memory = v.parse().unwrap(),
            _ => panic!("unknown child setting {kv:?}"),
        }
    }
    let state = AppState::new(vec![("t".into(), noise_repo())], config).unwrap();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        println!("LISTENING {}", listener.local_addr().unwrap());
        let stdin_closed = tokio::task::spawn_blocking(|| {
            let mut s = String::new();
            let _ = std::io::stdin().read_line(&mut s);
        });
        cbdam_server::run(listener, state, async {
            let _ = stdin_closed.await;
        })
        .await
        .unwrap();
    });
}

/// Sets this process's soft limit on open files (at most the hard limit); returns it.
// `rlim_t` is u64 on Linux, not on every Unix.
#[allow(clippy::unnecessary_cast)]
pub fn set_fd_limit(n: u64) -> u64 {
    let mut r = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: plain system calls on a struct we own.
    unsafe {
        assert_eq!(libc::getrlimit(libc::RLIMIT_NOFILE, &mut r), 0);
        r.rlim_cur = n.min(r.rlim_max as u64) as libc::rlim_t;
        assert_eq!(libc::setrlimit(libc::RLIMIT_NOFILE, &r), 0);
    }
    r.rlim_cur as u64
}

/// A server in a child process; killed when dropped.
pub struct Child {
    proc: std::process::Child,
    pub addr: SocketAddr,
}

impl Child {
    pub fn start(settings: &str) -> Self {
        let mut proc = Command::new(std::env::current_exe().unwrap())
            .args([
                "child::server_child",
                "--exact",
                "--ignored",
                "--nocapture",
                "--test-threads=1",
            ])
            .env(CHILD, settings)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        let mut lines = BufReader::new(proc.stdout.take().unwrap()).lines();
        let addr = loop {
            let line = lines
                .next()
                .expect("the child server says where it listens")
                .unwrap();
            // libtest writes the test's name on the same line first.
            if let Some((_, a)) = line.split_once("LISTENING ") {
                break a.trim().parse().unwrap();
            }
        };
        // Keep its output flowing.
        std::thread::spawn(move || lines.for_each(drop));
        Self { proc, addr }
    }

    pub fn url(&self, path: &str) -> String {
        format!("http://{}{path}", self.addr)
    }

    /// Resident memory, bytes.
    pub fn rss(&self) -> u64 {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.proc.id())).unwrap();
        let kib: u64 = status
            .lines()
            .find_map(|l| l.strip_prefix("VmRSS:"))
            .unwrap()
            .trim()
            .trim_end_matches("kB")
            .trim()
            .parse()
            .unwrap();
        kib * 1024
    }

    /// Open file descriptors.
    pub fn fds(&self) -> usize {
        std::fs::read_dir(format!("/proc/{}/fd", self.proc.id()))
            .unwrap()
            .count()
    }

    pub fn alive(&mut self) -> bool {
        self.proc.try_wait().unwrap().is_none()
    }
}

impl Drop for Child {
    fn drop(&mut self) {
        let _ = self.proc.kill();
        let _ = self.proc.wait();
    }
}

/// Opens up to `n` connections to `addr` that send nothing (each connect given 2 s).
pub async fn idle_connections(addr: SocketAddr, n: usize) -> Vec<TcpStream> {
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        match tokio::time::timeout(Duration::from_secs(2), TcpStream::connect(addr)).await {
            Ok(Ok(s)) => out.push(s),
            _ => break,
        }
    }
    out
}

/// A batch request of `n` times the largest record of [`noise_repo`], and the length of its
/// answer's body.
pub fn big_batch(n: usize) -> (Vec<u8>, usize) {
    let repo = noise_repo();
    let big = repo
        .head()
        .entries()
        .iter()
        .max_by_key(|e| e.length)
        .unwrap();
    let ids = vec![format!("\"{}\"", big.id); n].join(",");
    let body = format!(r#"{{"ids":[{ids}]}}"#);
    let req = format!(
        "POST /v1/repos/t/diamonds HTTP/1.1\r\nhost: x\r\ncontent-type: application/json\r\n\
         content-length: {}\r\n\r\n{body}",
        body.len()
    );
    (req.into_bytes(), 8 + n * (5 + big.length as usize))
}

/// Opens a connection with a small receive buffer (so the kernel holds little of an answer),
/// sends `req` and reads nothing.
pub async fn unread_request(addr: SocketAddr, req: &[u8]) -> TcpStream {
    let sock = tokio::net::TcpSocket::new_v4().unwrap();
    sock.set_recv_buffer_size(4096).unwrap();
    let mut s = sock.connect(addr).await.unwrap();
    s.write_all(req).await.unwrap();
    s
}

/// The most the server's resident memory reaches within `limit`, sampled every 100 ms, until it
/// has not grown for 1 s.
pub async fn settled_rss(server: &Child, limit: Duration) -> u64 {
    let start = Instant::now();
    let (mut most, mut since) = (server.rss(), Instant::now());
    while start.elapsed() < limit && since.elapsed() < Duration::from_secs(1) {
        tokio::time::sleep(Duration::from_millis(100)).await;
        let now = server.rss();
        if now > most {
            (most, since) = (now, Instant::now());
        }
    }
    most
}
