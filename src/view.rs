//! `cbdam view`: opens the terrain and hands it to the renderer's window loop
//! ([`cbdam_desktop::view`]).

use std::path::PathBuf;

use anyhow::{Context, Result};
use cbdam_client::refine::Refiner;
use cbdam_desktop::{ViewOptions, view};
use clap::Args;

use cbdam_desktop::KEY_HELP;

use crate::flags;
use crate::session::{refine_config, terrain_source};

/// Open a window onto a repository (file or URL): orbit and fly cameras, the pixel-error
/// target and debug views on keys, and a HUD with frame rate, triangle rate, cut size, cache
/// use and network traffic.
///
/// Every frame runs one step of the refinement loop within --budget-ms (remote records arrive
/// in the background, so the window never waits for the network) and draws the cut with the
/// renderer of `cbdam render`, starting from the same overview. With --max-frames it stops
/// after that many frames, printing the frame-time median and p99 and the triangle rate;
/// --screenshot saves the last frame on exit (scripts, tests). Needs a display: an X11
/// server, or Xvfb.
#[derive(Args, Debug)]
#[command(after_help = KEY_HELP)]
#[command(mut_arg("pixel_error", |a| a.help(
    "Screen-space error target, pixels (+/- halve and double it)"
)))]
pub struct ViewArgs {
    /// Repository file, or its URL (as for `cbdam render`).
    pub(crate) repo: PathBuf,
    /// Initial window size WIDTHxHEIGHT, pixels.
    #[arg(long, value_parser = flags::Size2::pixels, default_value = "1280x720")]
    pub(crate) size: (u32, u32),
    #[command(flatten)]
    pub(crate) pixel_error: flags::PixelError,
    /// Refinement time budget per frame, ms.
    #[arg(long, default_value_t = 2.0, value_parser = flags::positive_finite, allow_hyphen_values = true)]
    pub(crate) budget_ms: f64,
    /// Present as fast as possible (immediate or mailbox) instead of waiting for vsync.
    #[arg(long)]
    pub(crate) no_vsync: bool,
    /// Quit after this many frames.
    #[arg(long)]
    pub(crate) max_frames: Option<u64>,
    /// Save the last frame (with the HUD) to this PNG when the viewer stops.
    #[arg(long)]
    pub(crate) screenshot: Option<PathBuf>,
    #[command(flatten)]
    pub(crate) look: flags::Look,
    #[command(flatten)]
    pub(crate) pool_mib: flags::PoolMib,
    #[command(flatten)]
    pub(crate) colour: flags::Colour,
}

pub fn run(args: &ViewArgs) -> Result<()> {
    let config = refine_config(
        args.pixel_error.value,
        args.budget_ms,
        args.look.exaggeration,
    );
    let repo = args.repo.to_string_lossy();
    let (source, remote) = terrain_source(&repo, args.colour.value.as_deref())?;
    let refiner = Refiner::new(source, config).context("starting the refiner")?;
    view(
        refiner,
        &ViewOptions {
            name: repo.into_owned(),
            remote,
            size: args.size,
            no_vsync: args.no_vsync,
            max_frames: args.max_frames,
            screenshot: args.screenshot.clone(),
            wireframe: args.look.wireframe,
            levels: args.look.levels,
            pool_mib: args.pool_mib.value,
        },
    )
}
