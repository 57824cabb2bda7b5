//! `cbdam upgrade`: a repository of an older format version rewritten in the current one.

use std::path::PathBuf;

use anyhow::{Context, Result};
use cbdam_codec::repository::Repository;
use clap::Args;

/// Rewrite a repository of an older format version in the current one, 3 (from version 1: a
/// range-coded record index and the compact header; from version 2: the compact header; both
/// smaller on smooth terrain); heights, records and errors are unchanged. The output is written
/// atomically and may be the input itself.
#[derive(Args, Debug)]
pub struct UpgradeArgs {
    /// Repository file to read.
    repo: PathBuf,
    /// Where to write the upgraded repository (may be the input).
    #[arg(short, long)]
    output: PathBuf,
}

/// `cbdam upgrade`: the repository as the current writer writes it. The file's content is the
/// encoder's output as read back (`to_encoded`, every record checked), so this is a rewrite of
/// the containers, never a re-encode.
pub fn run(args: &UpgradeArgs) -> Result<()> {
    let repo =
        Repository::open(&args.repo).with_context(|| format!("opening {}", args.repo.display()))?;
    let from = repo.head().format_version();
    let encoded = repo
        .to_encoded()
        .with_context(|| format!("reading the records of {}", args.repo.display()))?;
    let (plan, georef, nodata) = (
        *repo.head().plan(),
        repo.head().georef().cloned(),
        repo.head().nodata(),
    );
    let before = repo.head().file_len();
    // Unmap before writing: the output may replace the input.
    drop(repo);
    cbdam_codec::repository::write_repository(
        &args.output,
        &encoded,
        &plan,
        georef.as_ref(),
        nodata,
    )
    .with_context(|| format!("writing {}", args.output.display()))?;
    let after = std::fs::metadata(&args.output)
        .with_context(|| format!("reading back {}", args.output.display()))?
        .len();
    println!(
        "{}: format version {from} → {}, {before} → {after} bytes",
        args.output.display(),
        cbdam_codec::repository::FORMAT_VERSION
    );
    Ok(())
}
