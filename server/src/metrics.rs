//! Request counters in the Prometheus text format, hand-written with atomics: a handful of
//! fixed label sets needs no metrics framework, and relaxed atomic adds cost a few nanoseconds
//! on the hot path.

use std::fmt::Write;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::time::Duration;

use axum::http::{Method, StatusCode};

/// The endpoints metrics are kept for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Endpoint {
    /// `GET /v1/repos`.
    Repos,
    /// `GET /v1/repos/{name}/meta`.
    Meta,
    /// `GET /v1/repos/{name}/diamonds/{id}`.
    Diamond,
    /// `POST /v1/repos/{name}/diamonds`.
    Batch,
    /// `GET /v1/repos/{name}/file`.
    File,
    /// `GET /metrics`.
    Metrics,
    /// Web-map tiles and their documents: `/v1/repos/{name}/terrarium|terrain-rgb|
    /// quantized-mesh/…` (docs/WEB-MAPS.md).
    Tiles,
    /// Anything else (404s, CORS preflights, …).
    Other,
}

impl Endpoint {
    const ALL: [Endpoint; 8] = [
        Endpoint::Repos,
        Endpoint::Meta,
        Endpoint::Diamond,
        Endpoint::Batch,
        Endpoint::File,
        Endpoint::Metrics,
        Endpoint::Tiles,
        Endpoint::Other,
    ];

    /// The label value.
    pub fn name(self) -> &'static str {
        match self {
            Endpoint::Repos => "repos",
            Endpoint::Meta => "meta",
            Endpoint::Diamond => "diamond",
            Endpoint::Batch => "batch",
            Endpoint::File => "file",
            Endpoint::Metrics => "metrics",
            Endpoint::Tiles => "tiles",
            Endpoint::Other => "other",
        }
    }

    /// Classifies a request by method and path. Done on the raw path rather than axum's
    /// matched route so that requests the router rejects (unknown paths, wrong methods) are
    /// counted too.
    pub fn classify(method: &Method, path: &str) -> Endpoint {
        if path == "/metrics" {
            return Endpoint::Metrics;
        }
        let Some(rest) = path.strip_prefix("/v1/repos") else {
            return Endpoint::Other;
        };
        if rest.is_empty() || rest == "/" {
            return Endpoint::Repos;
        }
        let mut parts = rest.trim_start_matches('/').split('/');
        let (_name, what, id, extra) = (parts.next(), parts.next(), parts.next(), parts.next());
        match (what, id, extra) {
            (Some("meta"), None, None) => Endpoint::Meta,
            (Some("file"), None, None) => Endpoint::File,
            (Some("diamonds"), None, None) if method == Method::POST => Endpoint::Batch,
            (Some("diamonds"), Some(_), None) => Endpoint::Diamond,
            (Some("terrarium" | "terrain-rgb" | "quantized-mesh"), Some(_), _) => Endpoint::Tiles,
            _ => Endpoint::Other,
        }
    }
}

/// Status codes with their own counter; others are counted under `other`.
const STATUSES: [u16; 13] = [
    200, 204, 206, 304, 400, 404, 405, 408, 413, 416, 500, 503, 0,
];

fn status_slot(s: StatusCode) -> usize {
    STATUSES[..STATUSES.len() - 1]
        .iter()
        .position(|&c| c == s.as_u16())
        .unwrap_or(STATUSES.len() - 1)
}

/// Latency histogram bucket upper bounds, seconds (Prometheus `le` labels).
const BUCKETS: [f64; 14] = [
    0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 5.0,
];

const NE: usize = Endpoint::ALL.len();

/// All counters. Shared by every request; every field is a relaxed atomic.
#[derive(Debug)]
pub struct Metrics {
    requests: [[AtomicU64; STATUSES.len()]; NE],
    bytes: [AtomicU64; NE],
    /// Cumulative bucket counts would need one add per bucket; storing per-bucket counts and
    /// summing at render time keeps the hot path to one add.
    latency_buckets: [[AtomicU64; BUCKETS.len() + 1]; NE],
    latency_sum_us: [AtomicU64; NE],
    records: AtomicU64,
    corrupt_records: AtomicU64,
    aborted_batches: AtomicU64,
    unsent_batch_bytes: AtomicU64,
}

impl Default for Metrics {
    fn default() -> Self {
        Self {
            requests: std::array::from_fn(|_| std::array::from_fn(|_| AtomicU64::new(0))),
            bytes: std::array::from_fn(|_| AtomicU64::new(0)),
            latency_buckets: std::array::from_fn(|_| std::array::from_fn(|_| AtomicU64::new(0))),
            latency_sum_us: std::array::from_fn(|_| AtomicU64::new(0)),
            records: AtomicU64::new(0),
            corrupt_records: AtomicU64::new(0),
            aborted_batches: AtomicU64::new(0),
            unsent_batch_bytes: AtomicU64::new(0),
        }
    }
}

impl Metrics {
    /// Records one answered request. `body_bytes` is the response body's size (0 when unknown).
    pub fn observe(&self, e: Endpoint, status: StatusCode, body_bytes: u64, latency: Duration) {
        let i = e as usize;
        self.requests[i][status_slot(status)].fetch_add(1, Relaxed);
        self.bytes[i].fetch_add(body_bytes, Relaxed);
        let secs = latency.as_secs_f64();
        let b = BUCKETS
            .iter()
            .position(|&le| secs <= le)
            .unwrap_or(BUCKETS.len());
        self.latency_buckets[i][b].fetch_add(1, Relaxed);
        self.latency_sum_us[i].fetch_add(latency.as_micros() as u64, Relaxed);
    }

    /// Counts records sent (single or in batches).
    pub fn add_records(&self, n: u64) {
        self.records.fetch_add(n, Relaxed);
    }

    /// Counts a request that met a corrupt record.
    pub fn add_corrupt(&self) {
        self.corrupt_records.fetch_add(1, Relaxed);
    }

    /// Counts a batch response dropped unfinished (the client closed the connection or reset
    /// the stream) with `unsent` bytes of its body never written.
    pub fn add_aborted_batch(&self, unsent: u64) {
        self.aborted_batches.fetch_add(1, Relaxed);
        self.unsent_batch_bytes.fetch_add(unsent, Relaxed);
    }

    /// Batch responses dropped unfinished so far, and the bytes of them never written.
    pub fn aborted_batches(&self) -> (u64, u64) {
        (
            self.aborted_batches.load(Relaxed),
            self.unsent_batch_bytes.load(Relaxed),
        )
    }

    /// Requests answered so far with `status` on `e` (for tests and the benchmark).
    pub fn requests(&self, e: Endpoint, status: StatusCode) -> u64 {
        self.requests[e as usize][status_slot(status)].load(Relaxed)
    }

    /// The Prometheus text exposition (format 0.0.4).
    pub fn render(&self) -> String {
        let mut o = String::with_capacity(8192);
        self.render_requests(&mut o);
        self.render_errors(&mut o);
        self.render_bytes(&mut o);
        self.render_latency(&mut o);
        self.render_totals(&mut o);
        o
    }

    // `write!` into a String cannot fail: the results below are ignored.

    /// `cbdam_http_requests_total`, by endpoint and status (the statuses seen only).
    fn render_requests(&self, o: &mut String) {
        let _ = writeln!(
            o,
            "# HELP cbdam_http_requests_total HTTP requests answered, by endpoint and status.\n\
             # TYPE cbdam_http_requests_total counter"
        );
        for e in Endpoint::ALL {
            for (s, &code) in STATUSES.iter().enumerate() {
                let n = self.requests[e as usize][s].load(Relaxed);
                if n > 0 {
                    let code = if code == 0 {
                        "other".to_string()
                    } else {
                        code.to_string()
                    };
                    let _ = writeln!(
                        o,
                        "cbdam_http_requests_total{{endpoint=\"{}\",status=\"{code}\"}} {n}",
                        e.name()
                    );
                }
            }
        }
    }

    /// `cbdam_http_errors_total`, by endpoint and class (client 4xx, server 5xx).
    fn render_errors(&self, o: &mut String) {
        let _ = writeln!(
            o,
            "# HELP cbdam_http_errors_total HTTP requests answered with a 4xx or 5xx status.\n\
             # TYPE cbdam_http_errors_total counter"
        );
        for e in Endpoint::ALL {
            let (mut client, mut server) = (0, 0);
            for (s, &code) in STATUSES.iter().enumerate() {
                let n = self.requests[e as usize][s].load(Relaxed);
                match code {
                    400..=499 => client += n,
                    500..=599 => server += n,
                    _ => {}
                }
            }
            for (class, n) in [("client", client), ("server", server)] {
                let _ = writeln!(
                    o,
                    "cbdam_http_errors_total{{endpoint=\"{}\",class=\"{class}\"}} {n}",
                    e.name()
                );
            }
        }
    }

    /// `cbdam_http_response_bytes_total`, by endpoint.
    fn render_bytes(&self, o: &mut String) {
        let _ = writeln!(
            o,
            "# HELP cbdam_http_response_bytes_total Response body bytes sent.\n\
             # TYPE cbdam_http_response_bytes_total counter"
        );
        for e in Endpoint::ALL {
            let _ = writeln!(
                o,
                "cbdam_http_response_bytes_total{{endpoint=\"{}\"}} {}",
                e.name(),
                self.bytes[e as usize].load(Relaxed)
            );
        }
    }

    /// The `cbdam_http_request_duration_seconds` histogram, by endpoint.
    fn render_latency(&self, o: &mut String) {
        let _ = writeln!(
            o,
            "# HELP cbdam_http_request_duration_seconds Time from request to response head.\n\
             # TYPE cbdam_http_request_duration_seconds histogram"
        );
        for e in Endpoint::ALL {
            let i = e as usize;
            let mut cumulative = 0;
            for (b, le) in BUCKETS.iter().enumerate() {
                cumulative += self.latency_buckets[i][b].load(Relaxed);
                let _ = writeln!(
                    o,
                    "cbdam_http_request_duration_seconds_bucket{{endpoint=\"{}\",le=\"{le}\"}} {cumulative}",
                    e.name()
                );
            }
            cumulative += self.latency_buckets[i][BUCKETS.len()].load(Relaxed);
            let n = e.name();
            let sum = self.latency_sum_us[i].load(Relaxed) as f64 / 1e6;
            let name = "cbdam_http_request_duration_seconds";
            let _ = writeln!(
                o,
                "{name}_bucket{{endpoint=\"{n}\",le=\"+Inf\"}} {cumulative}"
            );
            let _ = writeln!(o, "{name}_sum{{endpoint=\"{n}\"}} {sum}");
            let _ = writeln!(o, "{name}_count{{endpoint=\"{n}\"}} {cumulative}");
        }
    }

    /// The server-wide counters: records sent, corrupt records met, aborted batches.
    fn render_totals(&self, o: &mut String) {
        let _ = writeln!(
            o,
            "# HELP cbdam_records_sent_total Diamond records sent, single and batched.\n\
             # TYPE cbdam_records_sent_total counter\n\
             cbdam_records_sent_total {}\n\
             # HELP cbdam_corrupt_record_requests_total Requests that met a record failing its checksum.\n\
             # TYPE cbdam_corrupt_record_requests_total counter\n\
             cbdam_corrupt_record_requests_total {}\n\
             # HELP cbdam_batches_aborted_total Batch responses dropped unfinished (the client closed the connection).\n\
             # TYPE cbdam_batches_aborted_total counter\n\
             cbdam_batches_aborted_total {}\n\
             # HELP cbdam_batch_bytes_unsent_total Bytes of aborted batch responses never written.\n\
             # TYPE cbdam_batch_bytes_unsent_total counter\n\
             cbdam_batch_bytes_unsent_total {}",
            self.records.load(Relaxed),
            self.corrupt_records.load(Relaxed),
            self.aborted_batches.load(Relaxed),
            self.unsent_batch_bytes.load(Relaxed)
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classify_paths() {
        let g = Method::GET;
        assert_eq!(Endpoint::classify(&g, "/v1/repos"), Endpoint::Repos);
        assert_eq!(Endpoint::classify(&g, "/v1/repos/a/meta"), Endpoint::Meta);
        assert_eq!(Endpoint::classify(&g, "/v1/repos/a/file"), Endpoint::File);
        assert_eq!(
            Endpoint::classify(&g, "/v1/repos/a/diamonds/1-2-3"),
            Endpoint::Diamond
        );
        assert_eq!(
            Endpoint::classify(&Method::POST, "/v1/repos/a/diamonds"),
            Endpoint::Batch
        );
        assert_eq!(
            Endpoint::classify(&g, "/v1/repos/a/diamonds"),
            Endpoint::Other
        );
        assert_eq!(Endpoint::classify(&g, "/v1/reposx"), Endpoint::Other);
        for tiles in [
            "/v1/repos/a/terrarium/tiles.json",
            "/v1/repos/a/terrain-rgb/3/1/2.png",
            "/v1/repos/a/quantized-mesh/layer.json",
            "/v1/repos/a/quantized-mesh/0/0/0.terrain",
        ] {
            assert_eq!(Endpoint::classify(&g, tiles), Endpoint::Tiles, "{tiles}");
        }
        assert_eq!(
            Endpoint::classify(&g, "/v1/repos/a/terrarium"),
            Endpoint::Other
        );
        assert_eq!(Endpoint::classify(&g, "/metrics"), Endpoint::Metrics);
        assert_eq!(Endpoint::classify(&g, "/"), Endpoint::Other);
    }

    #[test]
    fn histogram_is_cumulative_and_counts_match() {
        let m = Metrics::default();
        m.observe(
            Endpoint::Diamond,
            StatusCode::OK,
            10,
            Duration::from_micros(50),
        );
        m.observe(
            Endpoint::Diamond,
            StatusCode::OK,
            20,
            Duration::from_millis(3),
        );
        m.observe(
            Endpoint::Diamond,
            StatusCode::IM_A_TEAPOT,
            0,
            Duration::from_secs(9),
        );
        let t = m.render();
        for line in [
            "cbdam_http_requests_total{endpoint=\"diamond\",status=\"200\"} 2",
            "cbdam_http_requests_total{endpoint=\"diamond\",status=\"other\"} 1",
            "cbdam_http_errors_total{endpoint=\"diamond\",class=\"client\"} 0",
            "cbdam_http_response_bytes_total{endpoint=\"diamond\"} 30",
            "cbdam_http_request_duration_seconds_bucket{endpoint=\"diamond\",le=\"0.0001\"} 1",
            "cbdam_http_request_duration_seconds_bucket{endpoint=\"diamond\",le=\"0.0025\"} 1",
            "cbdam_http_request_duration_seconds_bucket{endpoint=\"diamond\",le=\"0.005\"} 2",
            "cbdam_http_request_duration_seconds_bucket{endpoint=\"diamond\",le=\"5\"} 2",
            "cbdam_http_request_duration_seconds_bucket{endpoint=\"diamond\",le=\"+Inf\"} 3",
            "cbdam_http_request_duration_seconds_count{endpoint=\"diamond\"} 3",
        ] {
            assert!(t.lines().any(|l| l == line), "missing {line:?} in\n{t}");
        }
        assert_eq!(m.requests(Endpoint::Diamond, StatusCode::OK), 2);
    }
}
