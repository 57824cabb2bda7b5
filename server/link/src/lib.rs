//! Link emulation for tests and benchmarks: a loopback TCP proxy ([`Proxy`]) that makes a
//! connection to an upstream server behave as if it crossed a slower, longer link ([`Link`]):
//!
//! - a **rate cap** per direction, shared by all connections (a token bucket per direction,
//!   [`Link::burst`] bytes deep);
//! - a **one-way delay** per direction: every byte is released `delay` after it passed the rate
//!   cap (so an idle link's round trip is `2·delay`), optionally with **jitter** (uniform
//!   `±jitter` on each piece's delay, never reordering the bytes of a connection);
//! - optional **connection resets**: each new connection is, with probability
//!   [`Link::reset_prob`], reset (TCP RST to both ends) after a number of bytes drawn uniformly
//!   in `0..RESET_WINDOW` of its traffic, both directions counted, or at its end if it carries
//!   fewer — so the configured fraction of connections is reset exactly. Draws come from a
//!   seeded xorshift generator in accept order: a run with the same seed and the same sequence of
//!   connections resets the same ones.
//!
//! It needs no privileges and no `tc`: everything happens in user space, on the tokio runtime
//! the proxy is started on. Named profiles: [`Link::ADSL`], [`Link::DSL10`], [`Link::FIBRE`],
//! [`Link::MOBILE`] (also by name through [`FromStr`]).

#![deny(missing_docs)]

mod proxy;

use std::fmt;
use std::str::FromStr;
use std::time::Duration;

pub use proxy::{Counters, Proxy};

/// A connection chosen for a reset is reset within its first this many bytes (both directions
/// counted); the byte is drawn uniformly in `0..RESET_WINDOW`.
pub const RESET_WINDOW: u64 = 64 * 1024;

/// What a link does to the traffic crossing it. Rates are bits per second of payload (TCP and IP
/// headers are not emulated); delays are one way.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Link {
    /// Downstream cap (upstream server → client), bits/s, shared by all connections.
    pub down_bps: u64,
    /// Upstream cap (client → upstream server), bits/s, shared by all connections.
    pub up_bps: u64,
    /// One-way delay, each direction.
    pub delay: Duration,
    /// Each piece's delay is `delay ± u·jitter` for `u` uniform in [-1, 1] (never below zero,
    /// never before the previous piece of the same connection and direction).
    pub jitter: Duration,
    /// Probability that a new connection is reset (0 to 1).
    pub reset_prob: f64,
    /// Seed of the generator of resets and jitter.
    pub seed: u64,
}

impl Link {
    /// The paper's ADSL line: 1.2 Mbit/s down, 256 kbit/s up (a common ADSL upstream; the paper
    /// gives only the downstream), 30 ms each way (60 ms round trip).
    pub const ADSL: Link = Link::custom(1_200_000, 256_000, Duration::from_millis(30));
    /// A 10 Mbit/s DSL line: 10 Mbit/s down, 1 Mbit/s up, 25 ms each way (50 ms round trip).
    pub const DSL10: Link = Link::custom(10_000_000, 1_000_000, Duration::from_millis(25));
    /// Fibre: 100 Mbit/s down, 100 Mbit/s up, 10 ms each way (20 ms round trip).
    pub const FIBRE: Link = Link::custom(100_000_000, 100_000_000, Duration::from_millis(10));
    /// A mobile link: 5 Mbit/s down, 1 Mbit/s up, 60 ms each way (120 ms round trip), ±10 ms of
    /// jitter, and 1 % of connections reset.
    pub const MOBILE: Link = Link {
        jitter: Duration::from_millis(10),
        reset_prob: 0.01,
        ..Link::custom(5_000_000, 1_000_000, Duration::from_millis(60))
    };

    /// The named profiles, as accepted by [`FromStr`].
    pub const PROFILES: [(&'static str, Link); 4] = [
        ("adsl", Link::ADSL),
        ("dsl10", Link::DSL10),
        ("fibre", Link::FIBRE),
        ("mobile", Link::MOBILE),
    ];

    /// A link of the given caps (bits/s) and one-way delay, without jitter or resets, seed 1.
    pub const fn custom(down_bps: u64, up_bps: u64, delay: Duration) -> Link {
        Link {
            down_bps,
            up_bps,
            delay,
            jitter: Duration::ZERO,
            reset_prob: 0.0,
            seed: 1,
        }
    }

    /// Checks the parameters: rates at least 1 000 bit/s, delay and jitter at most 60 s, the
    /// reset probability within [0, 1]. The message names the parameter.
    pub fn validate(&self) -> Result<(), String> {
        for (name, bps) in [
            ("downstream rate", self.down_bps),
            ("upstream rate", self.up_bps),
        ] {
            if bps < 1000 {
                return Err(format!(
                    "the {name} is {bps} bit/s; it must be at least 1000 bit/s"
                ));
            }
        }
        for (name, d) in [("delay", self.delay), ("jitter", self.jitter)] {
            if d > Duration::from_secs(60) {
                return Err(format!("the {name} is {d:?}; it must be at most 60 s"));
            }
        }
        if !(0.0..=1.0).contains(&self.reset_prob) {
            return Err(format!(
                "the reset probability is {}; it must be from 0 to 1",
                self.reset_prob
            ));
        }
        Ok(())
    }

    /// Depth of a direction's token bucket, bytes: 10 ms of its rate, at least one 1 500-byte
    /// packet and at most 16 KiB. Data also crosses the cap in pieces of at most this size.
    pub fn burst(bps: u64) -> usize {
        ((bps / 8 / 100) as usize).clamp(1500, 16 * 1024)
    }
}

impl fmt::Display for Link {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} down, {} up, {} ms each way ({} ms round trip)",
            Rate(self.down_bps),
            Rate(self.up_bps),
            self.delay.as_secs_f64() * 1e3,
            self.delay.as_secs_f64() * 2e3
        )?;
        if !self.jitter.is_zero() {
            write!(f, ", ±{} ms jitter", self.jitter.as_secs_f64() * 1e3)?;
        }
        if self.reset_prob > 0.0 {
            write!(
                f,
                ", {}% of connections reset (seed {})",
                self.reset_prob * 100.0,
                self.seed
            )?;
        }
        Ok(())
    }
}

/// A rate in bits/s, printed with a k, M or G prefix.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rate(pub u64);

impl fmt::Display for Rate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let v = self.0 as f64;
        match self.0 {
            r if r >= 1_000_000_000 => write!(f, "{} Gbit/s", v / 1e9),
            r if r >= 1_000_000 => write!(f, "{} Mbit/s", v / 1e6),
            r if r >= 1_000 => write!(f, "{} kbit/s", v / 1e3),
            _ => write!(f, "{} bit/s", self.0),
        }
    }
}

impl FromStr for Link {
    type Err = String;

    /// One of the named profiles: `adsl`, `dsl10`, `fibre` (or `fiber`), `mobile`.
    fn from_str(name: &str) -> Result<Link, String> {
        let n = name.trim().to_ascii_lowercase();
        let n = if n == "fiber" { "fibre".to_string() } else { n };
        Link::PROFILES
            .iter()
            .find(|(p, _)| *p == n)
            .map(|(_, l)| *l)
            .ok_or_else(|| {
                format!(
                    "{name:?} is not a link profile: adsl, dsl10, fibre or mobile (or custom \
                     parameters: rates, delay)"
                )
            })
    }
}

/// A small seeded generator (xorshift64*), enough for jitter and reset draws.
#[derive(Clone, Debug)]
pub(crate) struct XorShift(u64);

impl XorShift {
    /// A generator from any seed (0 included), mixed by splitmix64 so near seeds diverge.
    pub(crate) fn new(seed: u64) -> XorShift {
        let mut z = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        XorShift(if z == 0 { 0x2545_F491_4F6C_DD1D } else { z })
    }

    pub(crate) fn next_u64(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in [0, 1).
    pub(crate) fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}
