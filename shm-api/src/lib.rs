//! The shared-memory contract of the motion coordinator over iceoryx2.
//!
//! This crate will hold the `#[repr(C)]` payloads (`MachineState`, commands and their answers),
//! the service names under a configurable prefix (`motion/state`, `motion/command`,
//! `motion/events`), the client library (`Client::connect`, `latest`, `next`, `command`) and the
//! clients that ship (`motion-watch`, `motion-top`, `motion-cmd`).
//!
//! ```
//! assert_eq!(shm_api::DEFAULT_PREFIX, "motion");
//! ```

/// The default prefix of every service name of the contract.
pub const DEFAULT_PREFIX: &str = "motion";
