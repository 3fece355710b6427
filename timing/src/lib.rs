//! Latency measurement runs of the motion coordinator: the `timing` binary and its runs, each
//! beside a baseline, with histograms, a `summary.json` and plots in one folder per run.
//!
//! - [`cycle`]: the cycle thread's wake-up lateness, set up as the coordinator sets it up,
//!   interleaved with cyclictest ([`cyclictest`]);
//! - [`step`]: the cycle step's compute time on synthetic machines;
//! - [`sim`]: the virtual-time simulation's speed, drive-seconds per wall second, with every
//!   drive sending its TPDOs on every SYNC;
//! - [`publish`]: the real coordinator's state to a client process, busy-poll and
//!   event-driven, beside a bare iceoryx2 pair of the same payload, and what the cycle thread's
//!   notify costs;
//! - [`round_trip`]: `timing loop`, a client's command through RPDO, SYNC and TPDO back to the
//!   state the client sees, stage by stage, with drive-sim processes and in-process drives;
//! - the framework: [`stats`] (a histogram and timeline per series, the table's figures),
//!   [`report`] (table, `summary.json`, histogram files, plots, reading a folder back),
//!   [`machine`] (CPU, kernel, preemption, load, real-time settings granted), [`busy`] (other
//!   processes busy on the CPUs when a run starts), [`progress`]
//!   (a bar on a terminal, lines otherwise), [`load`] (`--load`), [`session`] (one invocation,
//!   its folder), [`binaries`] (the coordinator's binaries beside `timing`), [`child`] (a
//!   started process: its output kept, its stop).
//!
//! ```
//! use timing::report::summary::Run;
//! use timing::stats::Series;
//! let mut ours = Series::new("ours");
//! let mut base = Series::new("baseline");
//! for k in 0..1000u64 {
//!     ours.record(k * 1_000_000, 5_000 + k % 100);
//!     base.record(k * 1_000_000, 4_000 + k % 100);
//! }
//! let mut run = Run::new("demo", "a demonstration, ns");
//! run.add(&ours, Some(1000));
//! run.add(&base, Some(1000));
//! run.add_ratios("ours", "baseline", &["p50"]);
//! let r = run.ratio("ours", "baseline", "p50").unwrap();
//! assert!(r > 1.2 && r < 1.3);
//! assert!(timing::report::table::run(&run).contains("p99.9"));
//! ```

pub mod binaries;
pub mod busy;
pub mod child;
pub mod cycle;
pub mod cyclictest;
pub mod load;
pub mod machine;
pub mod progress;
pub mod publish;
pub mod report;
pub mod round_trip;
pub mod session;
pub mod sim;
pub mod stats;
pub mod step;

/// Where runs write their folders by default, relative to the current directory (the
/// workspace).
pub const RESULTS_DIR: &str = "timing/results";
