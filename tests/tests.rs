//! The `cbdam` binary end to end, as one test binary (one link instead of one per file): a
//! module per subcommand or feature, the helpers they share in `util.rs`. Run one module with
//! `cargo test -p cbdam --test tests -- cli_view::`.

mod util;

mod cli;
mod cli_colour;
mod cli_multires;
mod cli_planet_closeup;
mod cli_planet_out_of_core;
mod cli_render;
mod cli_render_colour;
mod cli_tiles;
mod cli_view;
mod cli_web_export;
