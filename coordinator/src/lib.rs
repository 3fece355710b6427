//! The motion coordinator: one deterministic, SYNC-driven cycle that reads the drives' actual
//! values, advances every axis, evaluates comparators and record chains, computes synchronised
//! multi-axis setpoints in fixed point and writes them back.
//!
//! The `no_std` core: [`units`] (an axis's exact scale and the conversions between user units,
//! µunits and increments), [`axis`] (FHPP and CiA 402 master-side state machines), [`profile`]
//! (trapezoidal and jerk-limited profiles, time-synchronised group moves, fixed point), [`ids`]
//! (the indices every module shares), [`admission`] (which command each activity allows),
//! [`comparator`] and [`records`] (host-side record chains across axes), [`budget`] (the
//! bus-load admission check), [`command`], [`event`] and [`fault`] (what goes in and out of
//! the cycle) and [`cycle`] (the pure step that ties them together). With the `std` feature:
//! `config` (TOML) and `runtime` (the real-time thread, the services, the simulated machine and
//! `coordinator run`). `docs/architecture.md` and `docs/motion.md` explain the whole.
//!
//! ```
//! assert_eq!(coordinator::drivers::can::bit_timing::worst_case_bits(false, 8), 135);
//! ```

#![cfg_attr(not(feature = "std"), no_std)]

pub mod admission;
pub mod axis;
pub mod budget;
pub mod command;
pub mod comparator;
#[cfg(feature = "std")]
pub mod config;
pub mod cycle;
#[cfg(feature = "std")]
pub mod drive_eds;
pub mod event;
pub mod fault;
pub mod ids;
pub mod profile;
pub mod records;
#[cfg(feature = "std")]
pub mod runtime;
pub mod units;

pub use drivers;
