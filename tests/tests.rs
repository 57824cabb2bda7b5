//! The `cbdam` binary end to end, as one test binary (one link instead of one per file): a
//! module per subcommand or feature, the helpers they share in `util.rs`. Run one module with
//! `cargo test -p cbdam --test tests -- cli::view::`.

mod util;

mod cli;
