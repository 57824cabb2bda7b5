//! The link emulator's integration tests, as one test binary: real sockets on 127.0.0.1 only.

mod profiles;
mod proxy;
