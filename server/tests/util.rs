//! Helpers shared by the server's integration tests: a small real repository and a real server
//! on a loopback port.
#![allow(dead_code)] // `corrupt.rs`, a binary of its own, uses a subset

use std::net::SocketAddr;

use cbdam_codec::hierarchy::{EncodeOptions, Encoder};
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::GeoRef;
use cbdam_codec::repository::{Repository, serialize};
use cbdam_server::{AppState, Config};
use tokio::sync::oneshot;
use tokio::task::JoinHandle;

/// A small georeferenced repository image: rough terrain (non-trivial records) with a flat
/// strip (empty records) and a hole of nodata (diamonds not stored).
pub fn image(seed: u64) -> Vec<u8> {
    let (w, h) = (61usize, 45usize);
    let mut s = seed;
    let metres: Vec<f64> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            if (x - 45.0).hypot(y - 10.0) < 3.0 {
                return -9999.0;
            }
            if y >= 35.0 {
                return 100.0;
            }
            // SplitMix64 step: deterministic noise.
            s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = s;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            let noise = ((z ^ (z >> 31)) % 100) as f64 / 25.0;
            100.0 + 10.0 * (x / 5.0).sin() * (y / 7.0).cos() + noise
        })
        .collect();
    let plan = QuantPlan::new(0.5, None, 80.0, 120.0).unwrap();
    let grid = HeightGrid::from_metres(w, h, &metres, Some(-9999.0), &plan).unwrap();
    let opts = EncodeOptions {
        n: 9,
        ..EncodeOptions::default()
    };
    let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
    let geo = GeoRef {
        epsg: Some(32632),
        origin_x: 400_000.0,
        origin_y: 5_100_000.0,
        pixel_x: 30.0,
        pixel_y: 30.0,
        pixel_is_area: true,
        wkt: None,
    };
    serialize(&enc, &plan, Some(&geo), Some(-9999.0)).unwrap()
}

pub fn repo(seed: u64) -> Repository {
    Repository::from_bytes(image(seed)).unwrap()
}

/// A server running on a tokio task; dropping `shutdown` (or sending on it) stops it.
pub struct Running {
    pub base: String,
    pub addr: SocketAddr,
    pub state: AppState,
    pub shutdown: Option<oneshot::Sender<()>>,
    pub task: JoinHandle<Result<(), cbdam_server::ServerError>>,
}

impl Running {
    pub fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }

    /// Stops the server and waits for `run` to return.
    pub async fn stop(mut self) {
        self.shutdown.take().unwrap().send(()).unwrap();
        tokio::time::timeout(std::time::Duration::from_secs(10), self.task)
            .await
            .expect("run returns after shutdown")
            .unwrap()
            .unwrap();
    }
}

/// Binds 127.0.0.1:0 and serves `state` with [`cbdam_server::run`].
pub async fn start(state: AppState) -> Running {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (tx, rx) = oneshot::channel::<()>();
    let task = tokio::spawn(cbdam_server::run(listener, state.clone(), async {
        let _ = rx.await;
    }));
    Running {
        base: format!("http://{addr}"),
        addr,
        state,
        shutdown: Some(tx),
        task,
    }
}

/// One repository named `t`.
pub async fn start_one(config: Config) -> Running {
    start(AppState::new(vec![("t".into(), repo(1))], config).unwrap()).await
}

pub fn client() -> reqwest::Client {
    reqwest::Client::builder().build().unwrap()
}

pub async fn json(r: reqwest::Response) -> serde_json::Value {
    serde_json::from_slice(&r.bytes().await.unwrap()).unwrap()
}

/// Checks the JSON error shape and returns its message.
pub async fn error_body(r: reqwest::Response, status: u16) -> String {
    assert_eq!(r.status().as_u16(), status);
    assert_eq!(r.headers()["content-type"], "application/json");
    let v = json(r).await;
    assert_eq!(v["status"], status);
    v["error"].as_str().expect("error message").to_string()
}

/// Parses a batch response body: per id, `Some(bytes)` or `None` for "not stored".
pub fn parse_batch(b: &[u8]) -> Vec<Option<Vec<u8>>> {
    assert_eq!(&b[..4], b"CBDR");
    let n = u32::from_le_bytes(b[4..8].try_into().unwrap()) as usize;
    let mut at = 8;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let status = b[at];
        let len = u32::from_le_bytes(b[at + 1..at + 5].try_into().unwrap()) as usize;
        at += 5;
        match status {
            0 => out.push(Some(b[at..at + len].to_vec())),
            1 => {
                assert_eq!(len, 0);
                out.push(None)
            }
            s => panic!("unknown status {s}"),
        }
        at += len;
    }
    assert_eq!(at, b.len(), "trailing bytes");
    out
}
