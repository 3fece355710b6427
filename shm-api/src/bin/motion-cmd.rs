//! `motion-cmd`: sends one command to the coordinator; exit 0 latched, 2 rejected, 1 error.

use shm_api::cli::{self, cmd::CmdArgs, exit};

fn main() {
    let mut args: CmdArgs = cli::parse_or_exit(std::env::args_os());
    // `params` says how far it got, where someone watches.
    args.progress = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let code = match cli::connect(&args.prefix) {
        Ok(mut m) => cli::cmd::run(
            &mut m,
            &args,
            &mut std::io::stdout().lock(),
            &mut std::io::stderr(),
        ),
        Err(e) => {
            eprintln!("motion-cmd: {e}");
            exit::ERROR
        }
    };
    std::process::exit(code);
}
