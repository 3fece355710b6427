//! Device simulators and what they share: the physical axis model.
//!
//! - [`axis`]: a deterministic axis in integer increments, stepped in virtual time at a
//!   sub-cycle rate: the drive's own trapezoid generator, velocity, jog, force and streamed
//!   setpoints, a first-order position loop (a realistic following error), the current limit
//!   against fixed stops and springs, limit and reference switches, the index pulse, and
//!   injectable faults.
//! - [`profile`]: the drive-internal setpoint generator in exact integer step units.
//! - [`homing`]: a homing executor for CiA 402 and Festo FHPP method descriptions.
//!
//! No floats anywhere, so a run is identical bit for bit on every machine.
//!
//! ```
//! use drivers::sim::axis::{Axis, Config, Profile};
//! let mut axis = Axis::new(Config::default(), 0);
//! axis.enable().unwrap();
//! let p = Profile { velocity: 50_000, acceleration: 400_000, deceleration: 400_000 };
//! axis.move_to(10_000, p).unwrap();
//! loop {
//!     let s = axis.step();
//!     if s.generator_done && s.following_error == 0 {
//!         break;
//!     }
//! }
//! assert_eq!(axis.status().position, 10_000);
//! ```

pub mod axis;
pub mod cia402_drive;
#[cfg(feature = "std")]
pub mod cmmo_st;
pub mod comparator;
pub mod emca;
pub mod emca_ec;
pub mod fhpp_drive;
pub mod homing;
pub mod mtr_dci;
pub mod profile;
pub mod records;
pub mod tlc5xx;

pub use axis::{Axis, Config, Direction, Environment, Load, Profile, Status, SwitchZone};
pub use homing::{Homing, HomingMethod, HomingParams, HomingState, Reference};
