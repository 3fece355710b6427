//! Latency measurement runs of the motion coordinator: the `timing` binary and its runs, with
//! raw data for plots under `timing/results/`.
//!
//! - [`shm_latency`]: publish-to-client latency over shared memory, the contract's publisher
//!   and client beside a bare iceoryx2 pair of the same payload.
//!
//! ```
//! assert!(timing::RESULTS_DIR.ends_with("results"));
//! ```

pub mod shm_latency;

/// Where runs write their raw data, relative to the workspace.
pub const RESULTS_DIR: &str = "timing/results";
