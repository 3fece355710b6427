//! `motion-watch`: prints the chosen axes' state at a rate, or one CSV line per cycle.

use std::io::Write;
use std::time::{Duration, Instant};

use clap::Parser;
use drivers::cli_number::Allowed;

use super::resolve::axis_list;
use super::{Machine, exit, format};
use crate::contract::MachineState;

/// Arguments of `motion-watch`.
#[derive(Debug, Clone, Parser)]
#[command(
    name = "motion-watch",
    about = "Prints the motion coordinator's axes as they move"
)]
pub struct WatchArgs {
    /// The coordinator's service prefix.
    #[arg(long, default_value = crate::DEFAULT_PREFIX, value_parser = crate::names::check_prefix)]
    pub prefix: String,
    /// The axes to print, by name or index (default: all).
    #[arg(long, value_delimiter = ',')]
    pub axes: Vec<String>,
    /// Lines per second (0.01 to 1000000).
    #[arg(long, conflicts_with = "every_cycle", default_value_t = 10.0, value_parser = RATE.parser())]
    pub rate: f64,
    /// One line per cycle (every state published; gaps are reported on stderr).
    #[arg(long)]
    pub every_cycle: bool,
    /// CSV: a header, then `cycle,time_s` (seconds since the first line) and per axis
    /// position, setpoint, velocity (user units) and state (its name).
    #[arg(long)]
    pub csv: bool,
    /// Exit 0 after this many lines (the header not counted; at least 1).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=1_000_000_000))]
    pub count: Option<u64>,
    /// How long without a new state before giving up, ms (1 to 3600000).
    #[arg(long, default_value_t = 2000, value_parser = clap::value_parser!(u64).range(1..=3_600_000))]
    pub timeout_ms: u64,
}

/// `--rate`: lines per second, checked before anything connects.
const RATE: Allowed = Allowed::new("lines per second", 0.01, 1e6);

impl WatchArgs {
    /// The time between lines at `--rate` (a non-positive or absurd rate is refused).
    pub fn period(&self) -> Option<Duration> {
        RATE.check(self.rate)
            .ok()
            .map(|r| Duration::from_secs_f64(1.0 / r))
    }
}

fn line(state: &MachineState, axes: &[u16], csv: bool, start_ns: u64) -> String {
    if csv {
        return format::csv_line(state, axes, start_ns);
    }
    let mut s = format!("cycle {}", state.cycle);
    for &i in axes {
        if let Some(a) = state.axes.get(usize::from(i)) {
            s.push_str("  ");
            s.push_str(&format::axis_line(a));
        }
    }
    s
}

/// Runs `motion-watch` on a connected machine, writing lines to `out` and diagnostics to
/// `err`; returns the exit code.
pub fn run(
    m: &mut impl Machine,
    args: &WatchArgs,
    out: &mut impl Write,
    err: &mut impl Write,
) -> i32 {
    let timeout = Duration::from_millis(args.timeout_ms);
    let Some(period) = args.period() else {
        // Only a caller that built the arguments itself gets here: clap checks `--rate`.
        let refused = RATE
            .check_flag("--rate", args.rate)
            .err()
            .unwrap_or_else(|| RATE.refusal());
        let _ = writeln!(err, "error: {refused}");
        return exit::ERROR;
    };
    // The first state gives the names to resolve.
    let first = match m.next(timeout) {
        Ok(s) => *s,
        Err(e) => {
            let _ = writeln!(err, "error: {e}");
            return exit::ERROR;
        }
    };
    let axes = match axis_list(&first, &args.axes) {
        Ok(a) => a,
        Err(e) => {
            let _ = writeln!(err, "error: {e}");
            return exit::ERROR;
        }
    };
    if args.csv && writeln!(out, "{}", format::csv_header(&first, &axes)).is_err() {
        return exit::ERROR;
    }
    let mut printed = 0_u64;
    let mut last_cycle = first.cycle;
    let mut last_change = Instant::now();
    let start_ns = first.sync_time_ns;
    let mut text = line(&first, &axes, args.csv, start_ns);
    loop {
        // A closed pipe (`| head`) ends the watch quietly.
        if writeln!(out, "{text}").and_then(|()| out.flush()).is_err() {
            return exit::OK;
        }
        printed += 1;
        if args.count.is_some_and(|c| printed >= c) {
            return exit::OK;
        }
        if args.every_cycle {
            match m.next(timeout) {
                Ok(s) => {
                    if s.cycle > last_cycle.saturating_add(1) {
                        let _ = writeln!(
                            err,
                            "motion-watch: skipped {} cycles after cycle {last_cycle}",
                            s.cycle - last_cycle - 1
                        );
                    }
                    last_cycle = s.cycle;
                    text = line(s, &axes, args.csv, start_ns);
                }
                Err(e) => {
                    let _ = writeln!(err, "error: no new state: {e}");
                    return exit::ERROR;
                }
            }
        } else {
            std::thread::sleep(period);
            let Some(s) = m.latest() else {
                let _ = writeln!(err, "error: no state");
                return exit::ERROR;
            };
            if s.cycle != last_cycle {
                last_cycle = s.cycle;
                last_change = Instant::now();
            } else if last_change.elapsed() > timeout {
                let _ = writeln!(
                    err,
                    "error: the coordinator published nothing for {} ms (last cycle {last_cycle})",
                    args.timeout_ms
                );
                return exit::ERROR;
            }
            text = line(s, &axes, args.csv, start_ns);
        }
    }
}
