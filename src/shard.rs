//! `cbdam shard plan|apex|run|merge`: a build split into steps that run as separate processes
//! (on other machines, under Dask, a Kubernetes Indexed Job or a Slurm array) and are merged
//! into the repository `cbdam build` writes with the same arguments, byte for byte. A thin layer
//! over [`cbdam_builder::shard`], which documents the work directory; docs/SHARDING.md shows the
//! steps on each engine.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Result, bail};
use clap::{Args, Subcommand};

use crate::build::BuildArgs;
use cbdam_builder::planet_shard;

/// A build split into steps that run as separate processes, on other machines (Dask, a
/// Kubernetes Indexed Job, a Slurm array), merged into the repository `cbdam build` writes
/// with the same arguments, byte for byte: plan, apex, run each shard, merge
/// (docs/SHARDING.md).
#[derive(Subcommand, Debug)]
pub enum ShardCommand {
    /// Read and quantize the inputs once (as `cbdam build` would, same arguments), choose the
    /// blocks and shards, and write them to the work directory (which every step must reach,
    /// e.g. a shared file system); with --planet, outline the planet (one block per lattice
    /// tile; the other steps read the inputs again, which must stay where they are, unchanged).
    /// Prints one JSON line: {"shards", "blocks", "reused", "output", "planet"}. With the inputs and arguments of the plan already there it does nothing; a
    /// work directory of another build is refused.
    Plan(Box<ShardPlanArgs>),
    /// Refine the coarse levels over the whole domain (reads the prepared grid, writes the apex).
    Apex(ShardStepArgs),
    /// Encode one shard's blocks (reads the prepared grid under them and the apex, writes the
    /// shard's block files). Blocks already written are kept: a retried task is harmless.
    Run(ShardRunArgs),
    /// Put the apex and every shard together into the repository (written atomically); a
    /// missing shard is named.
    Merge(ShardStepArgs),
}

/// Arguments of `cbdam shard plan`.
#[derive(Args, Debug)]
pub struct ShardPlanArgs {
    #[command(flatten)]
    build: BuildArgs,
    /// The work directory, on a path every step can reach.
    #[arg(long)]
    work: PathBuf,
    /// How many shards (runs of consecutive blocks); default one per block, at most one per block.
    #[arg(long)]
    shards: Option<usize>,
    /// Also encode the apex (what `cbdam shard apex` does) from the grid the plan holds, saving
    /// that step a read of the prepared grid.
    #[arg(long)]
    apex: bool,
}

/// Arguments of `cbdam shard apex` and `cbdam shard merge`.
#[derive(Args, Debug)]
pub struct ShardStepArgs {
    /// The work directory `cbdam shard plan` wrote.
    #[arg(long)]
    work: PathBuf,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
}

/// Arguments of `cbdam shard run`.
#[derive(Args, Debug)]
pub struct ShardRunArgs {
    #[command(flatten)]
    step: ShardStepArgs,
    /// The shard, 0 to the plan's count − 1.
    #[arg(long)]
    shard: usize,
}

pub fn run(command: &ShardCommand) -> Result<()> {
    let start = Instant::now();
    match command {
        ShardCommand::Plan(args) => plan(args)?,
        ShardCommand::Apex(args) => {
            let encoded = if planet_shard::is_planet(&args.work) {
                planet_shard::apex(&args.work, args.threads)?
            } else {
                cbdam_builder::shard::apex(&args.work, args.threads)?
            };
            println!(
                "apex: {}, {:.2} s",
                if encoded {
                    "encoded"
                } else {
                    "already encoded"
                },
                start.elapsed().as_secs_f64()
            );
        }
        ShardCommand::Run(args) => {
            let (work, threads) = (&args.step.work, args.step.threads);
            let s = if planet_shard::is_planet(work) {
                planet_shard::run(work, args.shard, threads)?
            } else {
                cbdam_builder::shard::run(work, args.shard, threads)?
            };
            println!(
                "shard {}: blocks {}…{}, {} encoded, {} kept from an earlier run, {:.2} s",
                args.shard,
                s.blocks.start,
                s.blocks.end.saturating_sub(1),
                s.encoded,
                s.blocks.len() - s.encoded,
                start.elapsed().as_secs_f64()
            );
        }
        ShardCommand::Merge(args) if planet_shard::is_planet(&args.work) => {
            let s = planet_shard::merge(&args.work, args.threads)?;
            let bytes = std::fs::metadata(&s.output)?.len();
            println!(
                "{}: planet, K = {}, {} lattice points with data, {} bytes, {} records, max \
                 error {}, {:.2} s",
                s.output.display(),
                s.level_pairs,
                s.valid,
                bytes,
                s.records,
                s.quant.bound_text(),
                start.elapsed().as_secs_f64()
            );
        }
        ShardCommand::Merge(args) => {
            let s = cbdam_builder::shard::merge(&args.work, args.threads)?;
            let bytes = std::fs::metadata(&s.output)?.len();
            println!(
                "{}: {}×{} samples, {} bytes, {} records, max error {}, {:.2} s",
                s.output.display(),
                s.width,
                s.height,
                bytes,
                s.records,
                s.quant.bound_text(),
                start.elapsed().as_secs_f64()
            );
        }
    }
    Ok(())
}

/// `cbdam shard plan`: a plane's or, with `--planet`, a planet's.
fn plan(args: &ShardPlanArgs) -> Result<()> {
    let opts = crate::build::options(&args.build)?;
    if opts.rms_error.is_some() {
        bail!("--rms-error measures the whole decoded surface: build without shards");
    }
    let (shards, blocks, reused, output) = if opts.planet.is_some() {
        let s = planet_shard::plan(&opts, &args.work, args.shards, args.apex)?;
        (s.plan.shards, s.plan.block_count, s.reused, s.plan.output)
    } else {
        let s = cbdam_builder::shard::plan(
            &opts,
            &args.work,
            args.shards,
            args.apex,
            &cbdam_builder::NoProgress,
        )?;
        (s.plan.shards, s.plan.block_count, s.reused, s.plan.output)
    };
    println!(
        "{}",
        serde_json::json!({
            "shards": shards,
            "blocks": blocks,
            "reused": reused,
            "output": output,
            "planet": opts.planet.is_some(),
        })
    );
    Ok(())
}
