//! A sans-I/O CANopen (CiA 301) stack: every state machine is fed frames and time and returns
//! frames to send and events to act on. The same code serves the coordinator (master side), the
//! device simulators (device side) and the tests.

mod abort;
mod cob;
pub mod od;
pub mod sdo;

pub use abort::AbortCode;
pub use cob::{Address, FunctionCode, NodeId, ids};
