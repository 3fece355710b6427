//! A sans-I/O CANopen (CiA 301) stack: every state machine is fed frames and time and returns
//! frames to send and events to act on. The same code serves the coordinator (master side), the
//! device simulators (device side) and the tests.

mod abort;
mod cob;
pub mod device;
#[cfg(feature = "std")]
pub mod eds;
pub mod emcy;
pub mod endpoint;
pub mod example;
pub mod guarding;
pub mod heartbeat;
pub mod master;
pub mod nmt;
pub mod od;
pub mod pdo;
pub mod sdo;
pub mod sync;

pub use abort::AbortCode;
pub use cob::{Address, FunctionCode, NodeId, ids};
