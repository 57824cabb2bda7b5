//! `cbdam`: build, serve and view C-BDAM terrain repositories.
//!
//! Only this file turns errors into exit codes: 0 success, 1 failure (the message names the
//! problem), 2 bad usage (clap's own code).

mod bench;
mod build;
mod demo;
mod extract;
mod flags;
mod inspect;
mod link;
mod render;
mod replay;
mod runtime_dir;
mod serve;
mod session;
mod shard;
mod synth;
mod synth_earth;
mod upgrade;
mod verify;
mod view;
mod web_export;
mod web_pmtiles;
mod web_tiles;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "cbdam",
    version,
    about = "Compressed Batched Dynamic Adaptive Meshes: terrain with a guaranteed maximum error"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

// Each subcommand's help text is the doc comment of its arguments, beside its code.
#[derive(Subcommand)]
enum Command {
    Build(build::BuildArgs),
    Inspect(inspect::InspectArgs),
    Upgrade(upgrade::UpgradeArgs),
    Verify(verify::VerifyArgs),
    Extract(extract::ExtractArgs),
    Serve(serve::ServeArgs),
    WebExport(web_export::WebExportArgs),
    Tiles(web_tiles::TilesArgs),
    Link(link::LinkArgs),
    Replay(replay::ReplayArgs),
    Render(render::RenderArgs),
    View(view::ViewArgs),
    Demo(demo::DemoArgs),
    #[command(subcommand)]
    Shard(shard::ShardCommand),
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    #[command(hide = true)]
    Synth(synth::SynthArgs),
}

/// Lets a closed stdout end the process quietly, as `cbdam inspect … | head` expects, instead of
/// Rust's default of turning the write error into a panic. Only for the subcommands that touch
/// no sockets: a server must see EPIPE on a dropped connection, not die of the signal.
fn default_sigpipe(command: &Command) {
    #[cfg(unix)]
    if matches!(
        command,
        Command::Inspect(_)
            | Command::Upgrade(_)
            | Command::Verify(_)
            | Command::Extract(_)
            | Command::Tiles(_)
            | Command::Build(_)
            | Command::Shard(_)
    ) {
        // SAFETY: restoring a signal's default disposition before any thread is started.
        unsafe {
            libc::signal(libc::SIGPIPE, libc::SIG_DFL);
        }
    }
    #[cfg(not(unix))]
    let _ = command;
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // SAFETY: no other thread exists yet (parsing the arguments starts none).
    let _runtime_dir = unsafe { runtime_dir::ensure(runtime_dir::needed(&cli.command)) };
    default_sigpipe(&cli.command);
    let result = match cli.command {
        Command::Build(args) => build::run(&args),
        Command::Inspect(args) => inspect::run(&args),
        Command::Upgrade(args) => upgrade::run(&args),
        Command::Verify(args) => verify::run(&args),
        Command::Extract(args) => extract::run(&args),
        Command::Serve(args) => serve::run(&args),
        Command::WebExport(args) => web_export::run(&args),
        Command::Tiles(args) => web_tiles::run(&args),
        Command::Link(args) => link::run(&args),
        Command::Replay(args) => replay::run(&args),
        Command::Render(args) => render::run(&args),
        Command::View(args) => view::run(&args),
        Command::Demo(args) => demo::run(&args),
        Command::Shard(command) => shard::run(&command),
        Command::Bench(command) => bench::run(&command),
        Command::Synth(args) => synth::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("cbdam: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
