//! `timing`: latency measurement runs.
//!
//! `timing shm-latency [--samples N] [--period-us P] [--out DIR]` starts a publisher process
//! (itself, `timing shm-publisher`) and measures publish-to-client latency over shared memory,
//! printing a table and writing the raw latencies (ns, one per line) per phase to DIR.

use std::process::{Command, ExitCode};
use std::time::Duration;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Publish-to-client latency: the contract's client beside a bare iceoryx2 pair.
    ShmLatency {
        /// Samples per phase.
        #[arg(long, default_value_t = 5000)]
        samples: usize,
        /// Publishing period, µs.
        #[arg(long, default_value_t = 1000)]
        period_us: u64,
        /// Where to write the raw latencies.
        #[arg(long, default_value = timing::RESULTS_DIR)]
        out: std::path::PathBuf,
    },
    /// (internal) The publisher process of `shm-latency`.
    ShmPublisher {
        /// Service prefix.
        #[arg(long)]
        prefix: String,
        /// Period, µs.
        #[arg(long)]
        period_us: u64,
        /// Periods to publish.
        #[arg(long)]
        count: u64,
    },
}

fn main() -> ExitCode {
    match Cli::parse().command {
        Cmd::ShmPublisher {
            prefix,
            period_us,
            count,
        } => match timing::shm_latency::publish(&prefix, Duration::from_micros(period_us), count) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("error: {e}");
                ExitCode::FAILURE
            }
        },
        Cmd::ShmLatency {
            samples,
            period_us,
            out,
        } => {
            let prefix = format!("timing-{}", std::process::id());
            // Enough periods for the four phases plus margin.
            let count = (samples as u64 * 5 + 4000).to_string();
            let exe = std::env::current_exe().expect("own path");
            let mut publisher = match Command::new(exe)
                .args(["shm-publisher", "--prefix", &prefix, "--period-us"])
                .arg(period_us.to_string())
                .args(["--count", &count])
                .spawn()
            {
                Ok(p) => p,
                Err(e) => {
                    eprintln!("error: starting the publisher: {e}");
                    return ExitCode::FAILURE;
                }
            };
            eprintln!("measuring {samples} samples per phase at {period_us} µs...");
            let result = timing::shm_latency::measure(&prefix, samples);
            let _ = publisher.kill();
            let _ = publisher.wait();
            match result {
                Ok(f) => {
                    print!("{}", timing::shm_latency::table(&f));
                    let _ = std::fs::create_dir_all(&out);
                    for x in &f {
                        let file = x.name.replace([' ', ',', '(', ')'], "-").replace("--", "-");
                        let body: String = x.raw.iter().map(|v| format!("{v}\n")).collect();
                        let _ = std::fs::write(out.join(format!("shm-latency-{file}.txt")), body);
                    }
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
