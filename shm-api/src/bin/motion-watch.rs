//! `motion-watch`: prints the coordinator's axes at a rate, or one CSV line per cycle.

use shm_api::cli::{self, exit, watch::WatchArgs};

fn main() {
    let args: WatchArgs = cli::parse_or_exit(std::env::args_os());
    let code = match cli::connect(&args.prefix) {
        Ok(mut m) => cli::watch::run(
            &mut m,
            &args,
            &mut std::io::stdout().lock(),
            &mut std::io::stderr(),
        ),
        Err(e) => {
            eprintln!("motion-watch: {e}");
            exit::ERROR
        }
    };
    std::process::exit(code);
}
