//! The motion coordinator: one deterministic, SYNC-driven cycle that reads the drives' actual
//! values, advances every axis, evaluates comparators and record chains, computes synchronised
//! multi-axis setpoints in fixed point and writes them back.
//!
//! This crate will hold (see `docs/architecture.md`): `units` (fixed-point conversions),
//! `profile` (trapezoidal and jerk-limited profiles), `axis` (FHPP and CiA 402 master-side state
//! machines), `comparator`, `records`, `budget` (bus admission), `cycle` (the pure step),
//! `config` and `runtime` (the real-time thread, the executor, shared-memory publishing).
//! So far: [`budget`] (the bus-load admission check) and [`profile`] (trapezoidal and
//! jerk-limited profiles, time-synchronised group moves), both `no_std`. Until the cycle
//! exists, `demo` (with the `std` feature) is what `coordinator run` does: a CANopen master driving simulated
//! devices over the virtual bus.
//!
//! ```
//! assert_eq!(coordinator::drivers::can::bit_timing::worst_case_bits(false, 8), 135);
//! ```

#![cfg_attr(not(feature = "std"), no_std)]

pub mod axis;
pub mod budget;
pub mod command;
pub mod comparator;
#[cfg(feature = "std")]
pub mod config;
#[cfg(feature = "std")]
pub mod demo;
pub mod event;
pub mod fault;
pub mod profile;
pub mod records;
#[cfg(feature = "std")]
pub mod runtime;

pub use drivers;
