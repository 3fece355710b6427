//! The shared-memory contract of the motion coordinator over iceoryx2: the `#[repr(C)]`
//! payloads ([`contract`]), the service names under a configurable prefix (default `motion`),
//! the coordinator's publishing side and the client library, and the clients that ship
//! (`motion-watch`, `motion-top`, `motion-cmd`; the `clients` feature, on by default: the
//! coordinator depends on this crate without it, so it links no terminal UI crates). `docs/clients.md` describes the contract field
//! by field and how to write a client in Rust, Python and C.
//!
//! # Access rights
//!
//! iceoryx2 0.10 fixes the permissions of its files in code; no config setting or API chooses
//! a group. Its service segments in `/dev/shm` (`*.data`, `*.dynamic`) are created `0600`,
//! the static service files in `/tmp/iceoryx2/services` `0400` in `0750` directories, the
//! node files owner-only, the event sockets owner-only; only the global management segment
//! (`iox2_*_node.*.global_mgmt`, 16 bytes) is `0666`. So only processes of the coordinator's
//! user can open the services: run the coordinator and its clients under one service account.
//! The crate feature `iceoryx2/dev_permissions` would make everything world-accessible
//! (`0666`/`0777`); a umask cannot narrow or widen anything because iceoryx2 sets the final
//! mode with `fchmod` after creation. The test `service_segments_are_owner_only` pins this.
//!
//! ```
//! assert_eq!(shm_api::DEFAULT_PREFIX, "motion");
//! assert_eq!(core::mem::size_of::<shm_api::contract::AxisState>(), 128);
//! assert_eq!(core::mem::size_of::<shm_api::contract::GroupState>(), 48);
//! ```

#[cfg(feature = "clients")]
pub mod cli;
pub mod client;
pub mod contract;
pub mod layout;
pub mod layout_dump;
pub mod names;
pub mod publisher;
pub mod request;
pub mod units;

pub use client::{Client, ClientError, Latched, Rejected};
pub use names::ServiceNames;
pub use publisher::{
    CommandServer, DescriptionPublisher, EventPublisher, PendingCommand, PublisherSettings,
    ShmError, StateNotifier, StatePublisher, StateSample, cleanup_dead_nodes,
    cleanup_dead_nodes_with, create_node, create_node_with,
};
pub use request::{Target, name_str};

/// The default prefix of every service name of the contract.
pub const DEFAULT_PREFIX: &str = "motion";

/// An iceoryx2 error in words: its Display is `Type::Variant` (`InsufficientPermissions` reads
/// "insufficient permissions").
pub fn words(e: impl core::fmt::Display) -> String {
    let text = e.to_string();
    let variant = text.rsplit("::").next().unwrap_or(&text);
    let mut out = String::new();
    for (i, c) in variant.chars().enumerate() {
        if c.is_ascii_uppercase() && i > 0 {
            out.push(' ');
        }
        out.push(c.to_ascii_lowercase());
    }
    out
}
