//! The client core's integration tests, one binary (as ripgrep's `tests/tests.rs`): each module
//! is one area.

/// Decode jobs sent as bytes (to workers that share no memory): the same refinement as in
/// place, and bad bytes are errors.
mod decode_jobs;
/// The refinement loop over an HTTP source: `cbdam serve` and a static range server on loopback.
mod http;
/// The pipelined decoder: decoding ahead of the cut draws what the reference decoder draws.
mod pipeline;
/// The prefetch policy over loopback HTTP: when-idle prefetching waits for the cut, and a
/// prefetch cut short by the budget keeps what is on its way.
mod prefetch;
/// Request priorities and cancellation against `cbdam serve` on loopback.
mod priorities;
/// The refinement loop's cut, convergence, failures and memory budget over local and flaky
/// sources.
mod streaming;
/// The viewer core shared by the desktop window and the page: keys, drags and switches.
mod viewer;
