//! `motion-top`: a terminal UI of the coordinator's axes and groups.

use clap::Parser;
use shm_api::cli::{self, exit};

/// Arguments of `motion-top`.
#[derive(Parser)]
#[command(name = "motion-top", about = "A live view of the motion coordinator")]
struct TopArgs {
    /// The coordinator's service prefix.
    #[arg(long, default_value = shm_api::DEFAULT_PREFIX, value_parser = shm_api::names::check_prefix)]
    prefix: String,
}

fn main() {
    let args: TopArgs = cli::parse_or_exit(std::env::args_os());
    if let Err(e) = cli::top::run(&args.prefix, cli::connect) {
        eprintln!("motion-top: terminal: {e}");
        std::process::exit(exit::ERROR);
    }
}
