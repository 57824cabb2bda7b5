//! What `cbdam replay`, `render` and `view` share: opening the terrain (file or URL, with a
//! draped colour repository) and the refinement settings of the command line.

use std::path::Path;
use std::time::Duration;

use anyhow::{Context, Result};
use cbdam_client::access::{ColouredSource, DataSource, LocalSource, RemoteSource};
use cbdam_client::fetch::FetchOptions;
use cbdam_client::refine::RefineConfig;

/// Opens a repository file or URL (`http://`, `https://`) as a source; says whether it is
/// remote.
pub fn open_source(spec: &str) -> Result<(Box<dyn DataSource>, bool)> {
    if spec.starts_with("http://") || spec.starts_with("https://") {
        let source = RemoteSource::connect(spec, FetchOptions::default())
            .with_context(|| format!("connecting to {spec}"))?;
        Ok((Box::new(source), true))
    } else {
        let source =
            LocalSource::open(Path::new(spec)).with_context(|| format!("opening {spec}"))?;
        Ok((Box::new(source), false))
    }
}

/// The terrain's source, file or URL, with the colour repository `colour` draped over it when
/// given (refused, with the mismatch named, when it does not cover the same domain); says
/// whether either is remote.
pub fn terrain_source(repo: &str, colour: Option<&str>) -> Result<(Box<dyn DataSource>, bool)> {
    let (elevation, remote) = open_source(repo)?;
    let Some(colour) = colour else {
        return Ok((elevation, remote));
    };
    let (c, colour_remote) = open_source(colour)?;
    let paired = ColouredSource::new(elevation, c)
        .with_context(|| format!("draping the colour repository {colour} over {repo}"))?;
    Ok((Box::new(paired), remote || colour_remote))
}

/// The refinement settings of the command line, as its value parsers checked them: a positive
/// `pixel_error` and `exaggeration`, a budget of 0 (unlimited) or more.
pub fn refine_config(pixel_error: f64, budget_ms: f64, exaggeration: f64) -> RefineConfig {
    RefineConfig {
        pixel_error,
        budget: (budget_ms > 0.0).then(|| Duration::from_secs_f64(budget_ms / 1e3)),
        exaggeration,
        ..RefineConfig::default()
    }
}

/// A refinement budget in words: "2 ms", or "unlimited" for 0.
pub fn budget_label(budget_ms: f64) -> String {
    if budget_ms > 0.0 {
        format!("{budget_ms} ms")
    } else {
        "unlimited".into()
    }
}
