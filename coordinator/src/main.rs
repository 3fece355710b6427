//! `coordinator`: the command line of the motion coordinator.

use std::process::ExitCode;
use std::time::Duration;

use clap::{Parser, Subcommand};
use coordinator::runtime::run::{RunOptions, run};
use coordinator::runtime::script::ScriptOptions;

/// The real-time motion coordinator.
#[derive(Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a machine: the embedded default (four simulated drives of four kinds on the virtual
    /// CAN bus and Modbus TCP, homed, then a demonstration record chain), or `--config FILE`.
    Run {
        /// The machine's TOML configuration (default: the embedded example, see
        /// `config-example`).
        #[arg(long)]
        config: Option<std::path::PathBuf>,
        /// End after this many seconds of machine time (then stop and disable the drives;
        /// 0.001 to 31536000); without it the run lasts until Ctrl-C.
        #[arg(long, value_parser = run_seconds)]
        duration: Option<f64>,
        /// Run as fast as the machine allows (virtual time, deterministic) instead of in real
        /// time.
        #[arg(long)]
        virtual_time: bool,
        /// Run the demonstration on a configured machine too: enable and home every axis, then
        /// run each group's record chain over and over until an operator's stop. The embedded
        /// default machine runs it unless `--no-demo`; with `--config` the drives are booted
        /// and wait for commands.
        #[arg(long, conflicts_with = "no_demo")]
        demo: bool,
        /// No demonstration on the embedded default machine either.
        #[arg(long)]
        no_demo: bool,
        /// In the demonstration, only enable and home; do not run the record chains.
        #[arg(long)]
        no_chains: bool,
        /// No live status lines, only events and the summary.
        #[arg(long)]
        quiet: bool,
        /// Publish the machine over shared memory under this prefix (services
        /// PREFIX/state, PREFIX/command, PREFIX/events, PREFIX/event-log, PREFIX/description).
        #[arg(long, default_value = shm_api::DEFAULT_PREFIX, value_parser = shm_api::names::check_prefix)]
        shm_prefix: String,
        /// Do not publish over shared memory.
        #[arg(long)]
        no_shm: bool,
        /// Write a candump log (DIR/BUS.log) and a pcap (DIR/BUS.pcap) of every bus, in
        /// timestamp order.
        #[arg(long, value_name = "DIR")]
        capture: Option<std::path::PathBuf>,
        /// Record everything that enters the cycle (frames with their times, drive reports,
        /// Modbus images, client commands, the clock) and what it puts out, compressed, for
        /// `coordinator replay FILE`.
        #[arg(long, value_name = "FILE")]
        record: Option<std::path::PathBuf>,
    },
    /// Run a fault campaign in virtual time: a simulated machine kept moving while scripted and
    /// seeded random faults hit it, every cycle checked against the invariants; exit status 1
    /// at the first violation, reported with the seed that reproduces it (docs/reliability.md).
    Scenario {
        /// The scenario (TOML: machine, duration_s, seed, [random], [[fault]]).
        file: std::path::PathBuf,
        /// Another seed than the file's (any integer 0 to 18446744073709551615).
        #[arg(long, value_parser = seed_number)]
        seed: Option<u64>,
        /// Another duration than the file's: seconds of machine time after start-up, 0.001 to
        /// 31536000.
        #[arg(long, value_parser = run_seconds)]
        duration: Option<f64>,
        /// Record the campaign for `coordinator replay FILE`.
        #[arg(long, value_name = "FILE")]
        record: Option<std::path::PathBuf>,
        /// No progress lines.
        #[arg(long)]
        quiet: bool,
        /// Write everything the run prints (events, drive reports) to FILE.
        #[arg(long, value_name = "FILE")]
        log: Option<std::path::PathBuf>,
    },
    /// Run a recording's cycle again on its recorded inputs and check that every frame sent and
    /// every state published is bit-identical; exit status 1 at the first difference, which is
    /// reported with its cycle and the expected and found values.
    Replay {
        /// The recording (`coordinator run --record FILE`).
        file: std::path::PathBuf,
    },
    /// Print a commented example configuration (the embedded default machine).
    ConfigExample {
        /// The same machine with its drives in other processes: the buses on `vbus:can0` and
        /// `vbus:can1` and the CMMO-ST dialled at 127.0.0.1:1502, as `drive-sim --config` serves
        /// them.
        #[arg(long)]
        vbus: bool,
    },
    /// Validate a configuration file and print each bus's worst-case load per cycle; exit
    /// status 1 if anything is refused.
    Check {
        /// The TOML configuration file.
        file: std::path::PathBuf,
    },
}

/// `--duration`: finite seconds of machine time, a millisecond to a year, checked before any
/// conversion (`Duration::from_secs_f64` panics on NaN, negatives and overflow).
fn run_seconds(text: &str) -> Result<f64, String> {
    coordinator::drivers::cli_number::Allowed::new("seconds of machine time", 0.001, 31_536_000.0)
        .parse(text)
}

/// `--seed`: a whole number that fits 64 bits.
fn seed_number(text: &str) -> Result<u64, String> {
    text.trim()
        .parse::<u64>()
        .map_err(|_| "give a whole number, 0 to 18446744073709551615".into())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::ConfigExample { vbus } => {
            if vbus {
                print!("{}", coordinator::config::example_vbus());
            } else {
                print!("{}", coordinator::config::EXAMPLE);
            }
            ExitCode::SUCCESS
        }
        Command::Check { file } => check(&file),
        Command::Scenario {
            file,
            seed,
            duration,
            record,
            quiet,
            log,
        } => scenario(&file, seed, duration, record, quiet, log),
        Command::Replay { file } => {
            let mut stdout = std::io::stdout();
            match coordinator::runtime::record::replay::replay(&file, &mut stdout) {
                Ok(s) => {
                    println!("{s}");
                    if s.outcome == coordinator::runtime::record::replay::Outcome::Identical {
                        ExitCode::SUCCESS
                    } else {
                        ExitCode::FAILURE
                    }
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    ExitCode::from(2)
                }
            }
        }
        Command::Run {
            config,
            duration,
            virtual_time,
            demo,
            no_demo,
            no_chains,
            quiet,
            shm_prefix,
            no_shm,
            capture,
            record,
        } => {
            if duration.is_none() && virtual_time {
                eprintln!("error: --virtual-time needs --duration (it would run flat out forever)");
                return ExitCode::FAILURE;
            }
            let text = match &config {
                Some(f) => match std::fs::read_to_string(f) {
                    Ok(t) => t,
                    Err(e) => {
                        eprintln!("error: {}: {e}", f.display());
                        return ExitCode::FAILURE;
                    }
                },
                None => coordinator::config::EXAMPLE.to_string(),
            };
            let mut cfg = match coordinator::config::Config::parse(&text) {
                Ok(c) => c,
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::FAILURE;
                }
            };
            let dir = config
                .as_deref()
                .and_then(std::path::Path::parent)
                .unwrap_or(std::path::Path::new("."));
            let eds_errors = cfg.load_eds(dir);
            if !eds_errors.is_empty() {
                for e in eds_errors {
                    eprintln!("error: {e}");
                }
                return ExitCode::FAILURE;
            }
            let opts = RunOptions {
                duration: duration.map(Duration::from_secs_f64),
                virtual_time,
                status_every: (!quiet).then_some(Duration::from_millis(500)),
                script: ScriptOptions {
                    demo: (demo || config.is_none()) && !no_demo,
                    chains: !no_chains,
                    home: true,
                },
                shm: (!no_shm).then_some(shm_prefix),
                capture,
                record: record.map(|path| coordinator::runtime::run::RecordTo {
                    path,
                    config: text.clone(),
                }),
            };
            let mut stdout = std::io::stdout();
            match run(&cfg, &opts, &mut stdout) {
                Ok(s) => {
                    println!("{s}");
                    if s.boot_failures.is_empty() && s.faults.is_empty() {
                        ExitCode::SUCCESS
                    } else {
                        ExitCode::from(2)
                    }
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    ExitCode::FAILURE
                }
            }
        }
    }
}

/// `coordinator scenario FILE`: the campaign and its report; 1 on a violation.
fn scenario(
    file: &std::path::Path,
    seed: Option<u64>,
    duration: Option<f64>,
    record: Option<std::path::PathBuf>,
    quiet: bool,
    log: Option<std::path::PathBuf>,
) -> ExitCode {
    use coordinator::runtime::scenario::{ScenarioOptions, file::ScenarioFile, run_scenario};
    let text = match std::fs::read_to_string(file) {
        Ok(t) => t,
        Err(e) => {
            eprintln!("error: {}: {e}", file.display());
            return ExitCode::from(2);
        }
    };
    let s = match ScenarioFile::parse(&text) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {}: {e}", file.display());
            return ExitCode::from(2);
        }
    };
    let base = file.parent().unwrap_or(std::path::Path::new("."));
    let opts = ScenarioOptions {
        seed,
        duration_s: duration,
        record,
        quiet,
        log,
    };
    match run_scenario(&s, base, &opts, &mut std::io::stdout()) {
        Ok(r) => {
            print!("{r}");
            if r.violation.is_none() {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            }
        }
        Err(e) => {
            eprintln!("error: {}: {e}", file.display());
            ExitCode::from(2)
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
    let mut config = match coordinator::config::Config::parse(&text) {
        Ok(c) => c,
        Err(e) => {
            println!("error: {}: {e}", file.display());
            return ExitCode::FAILURE;
        }
    };
    let eds_errors = config.load_eds(file.parent().unwrap_or(std::path::Path::new(".")));
    let mut report = config.check();
    report.errors.extend(eds_errors);
    report.errors.extend(config.resolve_addresses());
    print!("{report}");
    if report.is_ok() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}
