//! The CAN layer: one [`Frame`] type, the [`Bus`] trait, the bit-timing model and the backends.
//!
//! Backends (with the `std` feature): `socketcan` for real interfaces and vcan, `virtual_bus`
//! (deterministic, in one process, virtual or real time, with fault injection), `shm_bus`
//! (the same bus across processes over iceoryx2, named `vbus:NAME`); capture as candump logs and
//! pcap files, in timestamp order through `reorder`.

pub mod bit_timing;
mod bus;
#[cfg(feature = "std")]
pub mod candump;
mod frame;
#[cfg(feature = "std")]
pub mod pcap;
#[cfg(feature = "std")]
pub mod reorder;
#[cfg(feature = "shm")]
pub mod shm_bus;
#[cfg(feature = "socketcan")]
pub mod socketcan;

pub use bus::{Bus, BusCounters, BusError, BusState};
pub use frame::{Frame, FrameError, ParseFrameError};

#[cfg(feature = "std")]
pub mod fault;
#[cfg(feature = "std")]
pub mod station;
#[cfg(feature = "std")]
pub mod virtual_bus;
#[cfg(feature = "std")]
pub use fault::{FaultAction, FaultId, FaultRule, IdMatch, TimeWindow};
#[cfg(feature = "std")]
pub use virtual_bus::{
    ClockMode, HeldBus, PortId, VirtualBus, VirtualBusConfig, VirtualBusError, VirtualPort,
};
