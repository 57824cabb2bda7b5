//! `cbdam bench …`: the measurement commands, one module each; this names them and runs the one
//! asked for.

mod build;
mod codec;
mod entropy;
mod entropy_secondary;
mod network;
mod render;
mod report;
mod serve;

use anyhow::Result;
use clap::Subcommand;

/// Measure the codec and other parts of the pipeline.
#[derive(Subcommand)]
pub enum BenchCommand {
    Codec(codec::BenchCodecArgs),
    Entropy(entropy::BenchEntropyArgs),
    Serve(serve::BenchServeArgs),
    Build(build::BenchBuildArgs),
    Render(render::BenchRenderArgs),
    Report(report::BenchReportArgs),
    Network(network::BenchNetworkArgs),
}

/// Runs the benchmark `command` names.
pub fn run(command: &BenchCommand) -> Result<()> {
    match command {
        BenchCommand::Codec(args) => codec::run(args),
        BenchCommand::Entropy(args) => entropy::run(args),
        BenchCommand::Serve(args) => serve::run(args),
        BenchCommand::Build(args) => build::run(args),
        BenchCommand::Render(args) => render::run(args),
        BenchCommand::Report(args) => report::run(args),
        BenchCommand::Network(args) => network::run(args),
    }
}
