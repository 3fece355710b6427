//! Service data objects (CiA 301 §7.2.4): confirmed access to one node's object dictionary.
//!
//! - [`codec`]: every SDO frame layout (expedited, segmented, block), decoders for fuzzing.
//! - [`SdoServer`]: the device side, over an [`ObjectAccess`](crate::canopen::od::ObjectAccess).
//! - [`SdoClient`]: the master side for one server node, with a queue of pending requests.
//! - [`crc16`]: the CRC of block transfer.
//!
//! Both state machines are sans-I/O: they are fed frames and time and hand back frames to send
//! and events.

mod client;
pub mod codec;
mod crc;
mod server;
#[cfg(test)]
mod tests;

pub use client::{
    Completion, DownloadMode, RequestError, RequestId, SdoClient, SdoClientConfig, SdoError,
    SdoEvent, UploadMode,
};
pub use codec::{BlockSegment, ClientFrame, DecodeError, InitiateData, Segment, ServerFrame};
pub use crc::{crc16, crc16_update};
pub use server::{SdoServer, SdoServerConfig, ServerEvent};

/// Which side aborted a transfer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AbortedBy {
    /// The server sent the abort frame.
    Server,
    /// The client sent the abort frame.
    Client,
}
