//! `cbdam view`: opens the terrain and hands it to the desktop viewer's window loop
//! ([`cbdam_desktop::view`]).

use anyhow::{Context, Result, bail};
use cbdam_client::refine::Refiner;
use cbdam_desktop::{ViewOptions, view};

pub use cbdam_desktop::KEY_HELP;

use crate::ViewArgs;
use crate::session::{refine_config, terrain_source};

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
