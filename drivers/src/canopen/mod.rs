//! A sans-I/O CANopen (CiA 301) stack: every state machine is fed frames and time and returns
//! frames to send and events to act on. The same code serves the coordinator (master side), the
//! device simulators (device side) and the tests.

mod abort;
mod cob;
pub mod device;
#[cfg(feature = "std")]
pub mod eds;
#[cfg(feature = "std")]
pub mod eds_write;
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

/// Node-ID → position in a list of per-node entries (each node at most once), so that a
/// frame finds its node's entry in one load rather than a scan of the list (the cycle feeds
/// every heartbeat and guarding reply of up to 127 nodes).
#[derive(Debug, Clone)]
pub(crate) struct NodeIndex([u8; 128]);

impl NodeIndex {
    /// No node listed.
    pub(crate) const fn new() -> Self {
        NodeIndex([0; 128])
    }
    /// The position of node `id` (the low 7 bits of a COB-ID), if listed.
    pub(crate) fn get(&self, id: u16) -> Option<usize> {
        let p = *self.0.get(usize::from(id))?;
        (p != 0).then(|| usize::from(p) - 1)
    }
    /// Lists the nodes in order (after a removal moved the entries behind it).
    pub(crate) fn rebuild(&mut self, nodes: impl Iterator<Item = NodeId>) {
        self.0 = [0; 128];
        for (i, n) in nodes.enumerate() {
            // 127 node-IDs: a position fits a byte.
            self.0[usize::from(n.get())] = i as u8 + 1;
        }
    }
}
