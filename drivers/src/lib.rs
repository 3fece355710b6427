//! Buses and devices for the motion coordinator.
//!
//! - [`catalog`]: the facts of the four supported drives (identity, profiles, PDO1,
//!   supervision, record table) in one place, each citing its manual digest.
//! - [`cli_number`] (`std`): a number a user typed (seconds, a rate, a scale), checked finite
//!   and in range and refused naming its unit and range, for every binary of the workspace.
//! - [`can`]: one CAN frame type, the [`can::Bus`] trait, the bit-timing model, and (with the
//!   `std` feature) the backends: SocketCAN, the deterministic virtual bus in one process and
//!   across processes over shared memory, fault injection, candump and pcap capture.
//! - [`canopen`]: a sans-I/O CiA 301 stack (object dictionary, NMT, SDO, PDO, SYNC, EMCY,
//!   heartbeat, node guarding): state machines fed frames and time that return frames to send.
//! - [`fhpp`]: the Festo Handling and Positioning Profile: control/status bytes, the FHPP state
//!   machine, the FPC parameter channel, PNU tables, units (MTR-DCI, EMCA, CMMO-ST).
//! - [`cia402`]: CiA 402 controlword/statusword, the device state machine, modes, homing methods.
//! - [`ethercat`]: a sans-I/O EtherCAT subdevice: frames and datagrams, the ESC's registers,
//!   sync managers and FMMUs, the SII image, the ESM, CoE (SDO server, emergencies), a segment.
//! - [`sim`]: the simulated physical axis and the device simulators built on it.
//! - [`time`]: the timestamps every sans-I/O state machine is fed.
//!
//! Without default features the crate is `no_std` and allocation-free: the codecs and state
//! machines build for `thumbv7em-none-eabihf`.
//!
//! ```
//! use drivers::can::Frame;
//! let sync = Frame::new_std(0x080, &[]).unwrap();
//! assert_eq!(sync.cob_id(), Some(0x080));
//! assert_eq!(drivers::can::bit_timing::worst_case_bits(false, 8), 135);
//! ```
#![cfg_attr(not(feature = "std"), no_std)]

pub mod can;
pub mod canopen;
pub mod catalog;
pub mod cia402;
#[cfg(feature = "std")]
pub mod cli_number;
pub mod ethercat;
pub mod fhpp;
pub mod hash_index;
pub mod modbus;
pub mod sim;
pub mod time;
