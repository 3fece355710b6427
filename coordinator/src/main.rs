//! `coordinator`: the command line of the motion coordinator.

use std::process::ExitCode;
use std::time::Duration;

use clap::{Parser, Subcommand};
use coordinator::demo::{DemoConfig, run};

/// The real-time motion coordinator.
#[derive(Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the embedded default machine: simulated drives on the virtual CAN bus.
    Run {
        /// Stop after this many seconds of bus time (the cyclic phase).
        #[arg(long, default_value_t = 5.0)]
        duration: f64,
        /// Run as fast as the machine allows (virtual time) instead of in real time.
        #[arg(long)]
        virtual_time: bool,
        /// Number of simulated drives (node-IDs 1..=N).
        #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u8).range(1..=16))]
        nodes: u8,
        /// Cycle (SYNC) period in microseconds. 4 drives with one 6-byte PDO each way need
        /// about 1 ms of a 1 Mbit/s bus per cycle (worst-case stuffing), hence 2 ms.
        #[arg(long, default_value_t = 2000, value_parser = clap::value_parser!(u32).range(250..=100_000))]
        cycle_us: u32,
        /// Bus bitrate in bit/s (20000..=1000000).
        #[arg(long, default_value_t = 1_000_000)]
        bitrate: u32,
        /// No live status lines, only the summary.
        #[arg(long)]
        quiet: bool,
    },
    /// Print a commented example configuration (the embedded default machine).
    ConfigExample,
    /// Validate a configuration file and print each bus's worst-case load per cycle; exit
    /// status 1 if anything is refused.
    Check {
        /// The TOML configuration file.
        file: std::path::PathBuf,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::ConfigExample => {
            print!("{}", coordinator::config::EXAMPLE);
            ExitCode::SUCCESS
        }
        Command::Check { file } => check(&file),
        Command::Run {
            duration,
            virtual_time,
            nodes,
            cycle_us,
            bitrate,
            quiet,
        } => {
            if !(duration.is_finite() && duration > 0.0 && duration <= 86_400.0) {
                eprintln!("error: --duration must be between 0 and 86400 seconds, not {duration}");
                return ExitCode::FAILURE;
            }
            let cfg = DemoConfig {
                nodes,
                cycle: Duration::from_micros(cycle_us as u64),
                duration: Duration::from_secs_f64(duration),
                virtual_time,
                bitrate,
                status_every: (!quiet).then_some(Duration::from_millis(500)),
            };
            let mut stdout = std::io::stdout();
            match run(&cfg, &mut stdout) {
                Ok(s) => {
                    println!(
                        "summary: {} cycles, {} frames, bus load {:.1} %, {} TPDOs received ({} malformed), \
                         final max |target - actual| {} increments, {} supervision events, \
                         {:.3} s of bus time in {:.3} s of wall time",
                        s.cycles,
                        s.frames,
                        s.bus_load_percent,
                        s.tpdos_received,
                        s.bad_tpdos,
                        s.final_max_error,
                        s.supervision_events,
                        s.bus_time.as_secs_f64(),
                        s.wall.as_secs_f64()
                    );
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    ExitCode::FAILURE
                }
            }
        }
    }
}

/// `coordinator check FILE`: the budget lines, then `OK` or every refusal.
fn check(file: &std::path::Path) -> ExitCode {
    let text = match std::fs::read_to_string(file) {
        Ok(t) => t,
        Err(e) => {
            eprintln!("error: {}: {e}", file.display());
            return ExitCode::FAILURE;
        }
    };
    let config = match coordinator::config::Config::parse(&text) {
        Ok(c) => c,
        Err(e) => {
            println!("error: {}: {e}", file.display());
            return ExitCode::FAILURE;
        }
    };
    let report = config.check();
    print!("{report}");
    if report.is_ok() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}
