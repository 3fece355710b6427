//! Latency measurement runs of the motion coordinator.
//!
//! This crate will hold the `timing` binary: cycle wake-up latency runs with baselines
//! (`clock_nanosleep` alone, the full cycle, publish-to-client), histograms, raw data for plots
//! under `timing/results/`, and the plots themselves.
//!
//! ```
//! assert!(timing::RESULTS_DIR.ends_with("results"));
//! ```

/// Where runs write their raw data, relative to the crate.
pub const RESULTS_DIR: &str = "timing/results";
