//! `timing`: latency measurement runs, each beside its baseline, into one folder per run
//! (`summary.json`, HDR histograms, plots, `table.txt`).
//!
//! - `timing cycle [--period-us 1000] [--priority 80] [--cpu N] [--duration S] [--window-s 1]`
//! - `timing step --axes 8,128 [--profile fhpp|cia402|both] [--grouped|--single]`
//! - `timing sim [--drives 8] [--period-us 1000] [--duration S | --cycles N] [--profile fhpp|cia402|both]`
//! - `timing publish [--duration S] [--window-s 0.5]`: the real coordinator's state to a
//!   client process beside a bare iceoryx2 pair
//! - `timing loop [--drives vbus|in-process|both] [--duration S | --samples N] [--cycle-us 2000]`
//! - `timing all [--duration S] [--loop-cycle-us 2000]`: cycle, step, sim, publish and loop
//!   into one folder
//! - `timing load [--duration S]`: the background load alone, to run anything else on a busy
//!   host on purpose
//! - `timing report DIR`, `timing compare DIR DIR`
//!
//! Every measuring subcommand takes `--out DIR` (default `timing/results/run-DATE`) and
//! `--load` (a documented background load, see `timing::load`).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::{Args, Parser, Subcommand, ValueEnum};
use timing::cycle::CycleOptions;
use timing::publish::PublishOptions;
use timing::round_trip::LoopOptions;
use timing::session::{self, Session};
use timing::sim::SimOptions;
use timing::step::{Cache, Profile, StepOptions};

#[derive(Parser)]
#[command(
    version,
    about = "Latency measurement runs of the motion coordinator, beside their baselines"
)]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

/// Where the folder goes and what runs beside the measurement.
#[derive(Args, Clone)]
struct Common {
    /// The folder to write (default: timing/results/run-DATE).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Run a background load meanwhile: one busy thread per CPU and a memory and system call
    /// churner (docs/performance.md).
    #[arg(long)]
    load: bool,
}

#[derive(Args, Clone)]
struct CycleArgs {
    /// The cycle's period, µs.
    #[arg(long, default_value_t = 1000)]
    period_us: u64,
    /// SCHED_FIFO priority, as the coordinator's cycle thread (1..99).
    #[arg(long, default_value_t = 80)]
    priority: i32,
    /// Pin the thread (and cyclictest) to this CPU.
    #[arg(long)]
    cpu: Option<usize>,
    /// Windows of each side take turns for this long, s.
    #[arg(long, default_value_t = 1.0)]
    window_s: f64,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum ProfileArg {
    Fhpp,
    Cia402,
    Both,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum CacheArg {
    Cold,
    Hot,
    Both,
}

fn caches(c: CacheArg) -> Vec<Cache> {
    match c {
        CacheArg::Cold => vec![Cache::Cold],
        CacheArg::Hot => vec![Cache::Hot],
        CacheArg::Both => vec![Cache::Cold, Cache::Hot],
    }
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum DrivesArg {
    Vbus,
    InProcess,
    Both,
}

#[derive(Args, Clone)]
struct StepArgs {
    /// Machine sizes, axes (comma-separated, each 1..128).
    #[arg(long, value_delimiter = ',', default_values_t = [8usize, 128])]
    axes: Vec<usize>,
    /// The drives' profile: FHPP drives, CiA 402 drives, or the four kinds in turn.
    #[arg(long, value_enum, default_value = "both")]
    profile: ProfileArg,
    /// Axes move in groups of up to 8 (the default).
    #[arg(long)]
    grouped: bool,
    /// Every axis moves on its own.
    #[arg(long)]
    single: bool,
    /// Where the step finds its state: cold (copies made ahead, out of the caches, as the
    /// criterion bench and the cycle thread after its sleep), hot (copied just before), both.
    /// A cold series is followed by its memory floor (only the step's lines read, cold).
    #[arg(long, value_enum, default_value = "both")]
    cache: CacheArg,
    /// SCHED_FIFO priority of the measuring thread, as the cycle thread's (1..99; 0: the
    /// normal scheduler).
    #[arg(long, default_value_t = 80)]
    priority: i32,
}

#[derive(Subcommand)]
enum Cmd {
    /// Wake-up lateness of the cycle thread beside cyclictest, in alternating windows.
    Cycle {
        #[command(flatten)]
        cycle: CycleArgs,
        /// Length of the run, s (both sides together).
        #[arg(long, default_value_t = 10.0)]
        duration: f64,
        #[command(flatten)]
        common: Common,
    },
    /// The cycle step's compute time on synthetic machines.
    Step {
        #[command(flatten)]
        step: StepArgs,
        /// Measuring time per series, s.
        #[arg(long, default_value_t = 3.0)]
        duration: f64,
        #[command(flatten)]
        common: Common,
    },
    /// Virtual-time simulation speed: drive-seconds per wall second, every drive sending its
    /// TPDOs on every SYNC.
    Sim {
        /// Machine sizes, drives (comma-separated, each 1..128).
        #[arg(long, value_delimiter = ',', default_values_t = [8usize])]
        drives: Vec<usize>,
        /// The SYNC period, µs (250..100000).
        #[arg(long, default_value_t = 1000)]
        period_us: u32,
        /// Wall time per machine, s (boot and homing, unmeasured, come on top).
        #[arg(long, default_value_t = 5.0)]
        duration: f64,
        /// Measure exactly this many cycles per machine instead of --duration's wall time: the
        /// same work in every run, so that instruction counts (valgrind) compare exactly.
        #[arg(long)]
        cycles: Option<u64>,
        /// The drives' profile: FHPP drives, CiA 402 drives, or the four kinds in turn.
        #[arg(long, value_enum, default_value = "cia402")]
        profile: ProfileArg,
        #[command(flatten)]
        common: Common,
    },
    /// The real coordinator's state to a client process, busy-poll and event-driven, beside a
    /// bare iceoryx2 pair of the same payload at the same period (the default machine's: the
    /// coordinator has no period option), in alternating windows; and the notify's cost.
    Publish {
        /// Measuring time, s (the coordinator's boot comes on top).
        #[arg(long, default_value_t = 10.0)]
        duration: f64,
        /// One window of one client kind, s.
        #[arg(long, default_value_t = 0.5)]
        window_s: f64,
        #[command(flatten)]
        common: Common,
    },
    /// A client's command round trip: RPDO, latched at the SYNC, TPDO, state seen.
    Loop {
        /// Where the drive runs: a drive-sim process on a vbus, simulated inside the
        /// coordinator, or both in turn.
        #[arg(long, value_enum, default_value = "both")]
        drives: DrivesArg,
        /// Stop after this many samples per machine (or at --duration, first reached).
        #[arg(long)]
        samples: Option<u64>,
        /// Measuring time per machine, s (boot and homing come on top).
        #[arg(long, default_value_t = 10.0)]
        duration: f64,
        /// The machine's SYNC period, µs (250..100000).
        #[arg(long, default_value_t = 2000)]
        cycle_us: u32,
        /// Read the state busy (one CPU spinning) instead of polling every 200 µs.
        #[arg(long)]
        busy: bool,
        #[command(flatten)]
        common: Common,
    },
    /// Cycle, step, sim, publish and loop into one folder.
    All {
        /// Length of the cycle run, s; the step gets an eighth of it per series (two machines,
        /// cold and hot), sim a tenth (8 CiA 402 drives at 1 ms), publish half of it, loop
        /// a tenth per machine (at least 2 s).
        #[arg(long, default_value_t = 10.0)]
        duration: f64,
        #[command(flatten)]
        cycle: CycleArgs,
        /// Machine sizes of the step run, axes (comma-separated).
        #[arg(long, value_delimiter = ',', default_values_t = [8usize, 128])]
        axes: Vec<usize>,
        /// The loop run's SYNC period, µs (250..100000).
        #[arg(long, default_value_t = 2000)]
        loop_cycle_us: u32,
        #[command(flatten)]
        common: Common,
    },
    /// The documented background load alone, until Ctrl-C or --duration: to run anything
    /// else (the test suite, a machine) on a busy host on purpose.
    Load {
        /// Stop after this long, s (default: until Ctrl-C or SIGTERM).
        #[arg(long)]
        duration: Option<f64>,
    },
    /// Redraws the plots and the table of a run's folder.
    Report {
        /// The folder.
        dir: PathBuf,
    },
    /// Two runs side by side, with the ratio of each figure (B / A).
    Compare {
        /// The first folder (A).
        a: PathBuf,
        /// The second folder (B).
        b: PathBuf,
    },
    /// (internal) The bare iceoryx2 publisher of `publish`.
    #[command(hide = true)]
    BarePublisher {
        /// Service prefix.
        #[arg(long)]
        prefix: String,
        /// Period, ns.
        #[arg(long)]
        period_ns: u64,
        /// Periods to publish at most.
        #[arg(long)]
        count: u64,
    },
}

fn command_line() -> String {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    args.insert(0, "timing".into());
    args.join(" ")
}

fn cycle_options(c: &CycleArgs, duration: f64) -> CycleOptions {
    CycleOptions {
        period_us: c.period_us,
        priority: c.priority,
        cpu: c.cpu,
        duration_s: duration,
        window_s: c.window_s,
    }
}

fn loop_options(d: DrivesArg, samples: Option<u64>, duration: f64) -> LoopOptions {
    use timing::round_trip::Drives;
    LoopOptions {
        drives: match d {
            DrivesArg::Vbus => vec![Drives::Vbus],
            DrivesArg::InProcess => vec![Drives::InProcess],
            DrivesArg::Both => vec![Drives::Vbus, Drives::InProcess],
        },
        samples,
        duration_s: duration,
        cycle_us: 2000,
        busy: false,
    }
}

fn own_exe() -> Result<PathBuf, String> {
    std::env::current_exe().map_err(|e| format!("cannot find this program's path: {e}"))
}

fn finish(s: Session, out: Option<PathBuf>) -> Result<(), String> {
    let dir = out.unwrap_or_else(session::default_dir);
    print!("{}", s.finish(&dir)?);
    Ok(())
}

/// `timing load`: the background load in the foreground, with a line a minute so a log shows
/// that it ran.
fn run_load(duration: Option<f64>) -> Result<(), String> {
    let limit = match duration {
        Some(d) => Some(Duration::from_secs_f64(
            drivers::cli_number::Allowed::new("seconds", 0.1, 7.0 * 86_400.0)
                .check_flag("--duration", d)?,
        )),
        None => None,
    };
    let stop = coordinator::runtime::signals::stop_flag();
    let start = std::time::Instant::now();
    let load = timing::load::Load::start();
    println!("timing load: {}", timing::load::DESCRIPTION);
    println!("timing load: running; Ctrl-C to stop");
    let mut next_line = Duration::from_secs(60);
    while !stop.load(std::sync::atomic::Ordering::Relaxed)
        && limit.is_none_or(|l| start.elapsed() < l)
    {
        std::thread::sleep(Duration::from_millis(100));
        if start.elapsed() >= next_line {
            println!(
                "timing load: {:.0} min, {} churn rounds",
                next_line.as_secs_f64() / 60.0,
                load.churn_rounds.load(std::sync::atomic::Ordering::Relaxed)
            );
            next_line += Duration::from_secs(60);
        }
    }
    let rounds = load.churn_rounds.load(std::sync::atomic::Ordering::Relaxed);
    drop(load);
    println!(
        "timing load: stopped after {:.1} s ({rounds} churn rounds)",
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

fn main() -> ExitCode {
    let result = match Cli::parse().command {
        Cmd::Cycle {
            cycle,
            duration,
            common,
        } => (|| {
            let o = cycle_options(&cycle, duration);
            o.check()?;
            let mut s = Session::start(command_line(), common.load);
            s.add(timing::cycle::run(&o)?);
            finish(s, common.out)
        })(),
        Cmd::Step {
            step,
            duration,
            common,
        } => (|| {
            let o = StepOptions {
                axes: step.axes,
                profiles: match step.profile {
                    ProfileArg::Fhpp => vec![Profile::Fhpp],
                    ProfileArg::Cia402 => vec![Profile::Cia402],
                    ProfileArg::Both => vec![Profile::Both],
                },
                grouped: match (step.grouped, step.single) {
                    (true, true) => vec![true, false],
                    (false, true) => vec![false],
                    _ => vec![true],
                },
                caches: caches(step.cache),
                seconds_per_series: duration,
                priority: (step.priority != 0).then_some(step.priority),
            };
            o.check()?;
            let mut s = Session::start(command_line(), common.load);
            s.add(timing::step::run(&o)?);
            finish(s, common.out)
        })(),
        Cmd::Sim {
            drives,
            period_us,
            duration,
            cycles,
            profile,
            common,
        } => (|| {
            let o = SimOptions {
                drives,
                period_us,
                seconds_per_machine: duration,
                cycles,
                profiles: match profile {
                    ProfileArg::Fhpp => vec![Profile::Fhpp],
                    ProfileArg::Cia402 => vec![Profile::Cia402],
                    ProfileArg::Both => vec![Profile::Both],
                },
            };
            o.check()?;
            let mut s = Session::start(command_line(), common.load);
            s.add(timing::sim::run(&o)?);
            finish(s, common.out)
        })(),
        Cmd::All {
            duration,
            cycle,
            axes,
            loop_cycle_us,
            common,
        } => (|| {
            // Checked here under `all`'s own names: the runs below get shares of them.
            drivers::cli_number::Allowed::new("seconds", 0.8, 86_400.0)
                .check_flag("--duration", duration)
                .map_err(|e| format!("{e} (publish gets half of it, at least 0.4 s)"))?;
            if !(250..=100_000).contains(&loop_cycle_us) {
                return Err(format!(
                    "--loop-cycle-us {loop_cycle_us}: the loop run's SYNC period must be 250 to 100000 µs"
                ));
            }
            let o = cycle_options(&cycle, duration);
            o.check()?;
            let step = StepOptions {
                axes,
                profiles: vec![Profile::Both],
                grouped: vec![true],
                caches: vec![Cache::Cold, Cache::Hot],
                seconds_per_series: duration / 8.0,
                priority: Some(cycle.priority),
            };
            step.check()?;
            let sim = SimOptions {
                drives: vec![8],
                period_us: 1000,
                seconds_per_machine: duration / 10.0,
                cycles: None,
                profiles: vec![Profile::Cia402],
            };
            sim.check()?;
            let round_trip = LoopOptions {
                cycle_us: loop_cycle_us,
                ..loop_options(DrivesArg::Both, None, (duration / 10.0).max(2.0))
            };
            round_trip.check()?;
            let publish = PublishOptions {
                duration_s: duration / 2.0,
                window_s: (duration / 40.0).clamp(0.05, 0.5),
            };
            publish.check()?;
            let exe = own_exe()?;
            let mut s = Session::start(command_line(), common.load);
            s.add(timing::cycle::run(&o)?);
            s.add(timing::step::run(&step)?);
            s.add(timing::sim::run(&sim)?);
            s.add(timing::publish::run(&exe, &publish)?);
            timing::round_trip::run(&round_trip)?
                .into_iter()
                .for_each(|r| s.add(r));
            finish(s, common.out)
        })(),
        Cmd::Loop {
            drives,
            samples,
            duration,
            cycle_us,
            busy,
            common,
        } => (|| {
            let o = LoopOptions {
                cycle_us,
                busy,
                ..loop_options(drives, samples, duration)
            };
            o.check()?;
            let mut s = Session::start(command_line(), common.load);
            timing::round_trip::run(&o)?
                .into_iter()
                .for_each(|r| s.add(r));
            finish(s, common.out)
        })(),
        Cmd::Load { duration } => run_load(duration),
        Cmd::Report { dir } => session::redraw(&dir).map(|t| print!("{t}")),
        Cmd::Compare { a, b } => (|| {
            let sa = timing::report::files::read_summary(&a).map_err(|e| e.to_string())?;
            let sb = timing::report::files::read_summary(&b).map_err(|e| e.to_string())?;
            print!(
                "{}",
                timing::report::table::compare(
                    &sa,
                    &sb,
                    &a.display().to_string(),
                    &b.display().to_string()
                )
            );
            Ok(())
        })(),
        Cmd::Publish {
            duration,
            window_s,
            common,
        } => (|| {
            let o = PublishOptions {
                duration_s: duration,
                window_s,
            };
            o.check()?;
            let exe = own_exe()?;
            timing::binaries::beside(&exe, "coordinator")?;
            let mut s = Session::start(command_line(), common.load);
            s.add(timing::publish::run(&exe, &o)?);
            finish(s, common.out)
        })(),
        Cmd::BarePublisher {
            prefix,
            period_ns,
            count,
        } => {
            if !(10_000..=1_000_000_000).contains(&period_ns) {
                Err(format!(
                    "--period-ns {period_ns}: must be 10000 to 1000000000 ns"
                ))
            } else {
                timing::publish::bare_publisher(&prefix, Duration::from_nanos(period_ns), count)
            }
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
