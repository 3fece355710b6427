//! The shared-memory contract of the motion coordinator over iceoryx2: the `#[repr(C)]`
//! payloads ([`contract`]), the service names under a configurable prefix (default `motion`),
//! the coordinator's publishing side and the client library, and the clients that ship
//! (`motion-watch`, `motion-top`, `motion-cmd`). `docs/clients.md` describes the contract field
//! by field and how to write a client in Rust, Python and C.
//!
//! ```
//! assert_eq!(shm_api::DEFAULT_PREFIX, "motion");
//! assert_eq!(core::mem::size_of::<shm_api::contract::AxisState>(), 128);
//! assert_eq!(core::mem::size_of::<shm_api::contract::GroupState>(), 48);
//! ```

pub mod cli;
pub mod client;
pub mod contract;
pub mod layout;
pub mod layout_dump;
pub mod names;
pub mod publisher;
pub mod request;

pub use client::{Client, ClientError, Latched, Rejected};
pub use names::ServiceNames;
pub use publisher::{
    CommandServer, EventPublisher, PendingCommand, PublisherSettings, ShmError, StatePublisher,
    StateSample, cleanup_dead_nodes, cleanup_dead_nodes_with, create_node,
};
pub use request::{Target, name_str};

/// The default prefix of every service name of the contract.
pub const DEFAULT_PREFIX: &str = "motion";
