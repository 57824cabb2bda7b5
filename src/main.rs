//! `cbdam`: build, serve and view C-BDAM terrain repositories.

fn main() {
    eprintln!("cbdam: no subcommands yet");
    std::process::exit(2);
}
