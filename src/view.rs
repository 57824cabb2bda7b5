//! `cbdam view`: opens the terrain and hands it to the renderer's window loop
//! ([`cbdam_render::view`]).

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use cbdam_client::refine::Refiner;
use cbdam_render::view::{ViewOptions, view};
use clap::Args;

use cbdam_render::view::KEY_HELP;

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
pub struct ViewArgs {
    /// Repository file, or its URL (as for `cbdam render`).
    pub(crate) repo: PathBuf,
    /// Initial window size WIDTHxHEIGHT, pixels.
    #[arg(long, value_parser = flags::Size2::pixels, default_value = "1280x720")]
    pub(crate) size: (u32, u32),
    /// Screen-space error target, pixels (+/- halve and double it).
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
    pub(crate) pixel_error: f64,
    /// Refinement time budget per frame, ms.
    #[arg(long, default_value_t = 2.0, allow_hyphen_values = true)]
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
    /// Start with the wireframe on.
    #[arg(long)]
    pub(crate) wireframe: bool,
    /// Start colouring by diamond level.
    #[arg(long)]
    pub(crate) levels: bool,
    /// Vertical exaggeration.
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
    pub(crate) exaggeration: f64,
    /// GPU height pool, MiB (default: 256 or what the adapter allows).
    #[arg(long)]
    pub(crate) pool_mib: Option<u64>,
    /// Drape this colour repository (`cbdam build IMG --colour --like REPO`), file or URL, over
    /// the terrain: hillshaded colour instead of the height ramp.
    #[arg(long, value_name = "COLOUR_REPO_OR_URL")]
    pub(crate) colour: Option<String>,
}

pub fn run(args: &ViewArgs) -> Result<()> {
    // Unlike `render` (0 = refine to convergence), a window refines within a budget every frame.
    if !(args.budget_ms.is_finite() && args.budget_ms > 0.0) {
        bail!("--budget-ms must be positive: the viewer refines within a budget every frame");
    }
    let config = refine_config(args.pixel_error, args.budget_ms, args.exaggeration)?;
    let repo = args.repo.to_string_lossy();
    let (source, remote) = terrain_source(&repo, args.colour.as_deref())?;
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
            wireframe: args.wireframe,
            levels: args.levels,
            pool_mib: args.pool_mib,
        },
    )
}
