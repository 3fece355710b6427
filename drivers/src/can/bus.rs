//! The `Bus` trait every backend implements, with bus states, counters and errors.

use super::Frame;
use crate::time::Instant;

/// The fault-confinement state of a CAN controller (ISO 11898-1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BusState {
    /// Normal operation: error counters below 128.
    #[default]
    ErrorActive,
    /// An error counter reached 128: the node still communicates but signals errors passively.
    ErrorPassive,
    /// The transmit error counter passed 255: the node takes no part in bus traffic.
    BusOff,
}

/// Traffic counters of one bus endpoint.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BusCounters {
    /// Frames this endpoint put on the bus.
    pub sent: u64,
    /// Frames this endpoint received.
    pub received: u64,
    /// Frames lost at this endpoint (queue full, injected drop, bus-off).
    pub dropped: u64,
}

/// Why a bus operation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum BusError {
    /// The transmit queue is full; try again after the bus has drained it.
    #[error("the transmit queue is full")]
    WouldBlock,
    /// The controller is bus-off and sends nothing until it recovers.
    #[error("the CAN controller is bus-off")]
    BusOff,
    /// The endpoint is disconnected from the bus (node disconnect, bus closed).
    #[error("the endpoint is disconnected from the bus")]
    Disconnected,
    /// This backend does not offer the operation.
    #[error("the bus backend does not support {0}")]
    Unsupported(&'static str),
    /// An operating-system error from the backend, with its errno.
    #[error("bus I/O error (os error {0})")]
    Os(i32),
}

/// A CAN bus endpoint: what a master or a device sees of the bus.
///
/// `send` and `try_recv` never block. Received frames carry the time at which they completed on
/// the bus, in the bus's own clock ([`Bus::now`]).
pub trait Bus {
    /// Queues a frame for transmission without blocking.
    fn send(&mut self, frame: &Frame) -> Result<(), BusError>;

    /// Takes the next received frame, if one has arrived, without blocking.
    fn try_recv(&mut self) -> Result<Option<Frame>, BusError>;

    /// Waits for a frame until `deadline` (in the bus's clock). Returns `Ok(None)` at the
    /// deadline. Backends that cannot wait return [`BusError::Unsupported`].
    fn recv_until(&mut self, deadline: Instant) -> Result<Option<Frame>, BusError> {
        let _ = deadline;
        Err(BusError::Unsupported("blocking receive"))
    }

    /// The current time in the bus's clock (virtual or monotonic).
    fn now(&self) -> Instant;

    /// The controller's fault-confinement state.
    fn state(&self) -> BusState;

    /// Traffic counters of this endpoint.
    fn counters(&self) -> BusCounters;

    /// The in-process virtual bus port this endpoint is, if it is one: a virtual-time loop
    /// holding that port's bus ([`super::virtual_bus::HeldBus`]) then moves its frames without
    /// a lock per frame. `None` by default.
    #[cfg(feature = "std")]
    fn virtual_port(&mut self) -> Option<&mut super::VirtualPort> {
        None
    }
}

impl<B: Bus + ?Sized> Bus for &mut B {
    fn send(&mut self, frame: &Frame) -> Result<(), BusError> {
        (**self).send(frame)
    }
    fn try_recv(&mut self) -> Result<Option<Frame>, BusError> {
        (**self).try_recv()
    }
    fn recv_until(&mut self, deadline: Instant) -> Result<Option<Frame>, BusError> {
        (**self).recv_until(deadline)
    }
    fn now(&self) -> Instant {
        (**self).now()
    }
    fn state(&self) -> BusState {
        (**self).state()
    }
    fn counters(&self) -> BusCounters {
        (**self).counters()
    }
    #[cfg(feature = "std")]
    fn virtual_port(&mut self) -> Option<&mut super::VirtualPort> {
        (**self).virtual_port()
    }
}

#[cfg(feature = "std")]
impl<B: Bus + ?Sized> Bus for Box<B> {
    fn send(&mut self, frame: &Frame) -> Result<(), BusError> {
        (**self).send(frame)
    }
    fn try_recv(&mut self) -> Result<Option<Frame>, BusError> {
        (**self).try_recv()
    }
    fn recv_until(&mut self, deadline: Instant) -> Result<Option<Frame>, BusError> {
        (**self).recv_until(deadline)
    }
    fn now(&self) -> Instant {
        (**self).now()
    }
    fn state(&self) -> BusState {
        (**self).state()
    }
    fn counters(&self) -> BusCounters {
        (**self).counters()
    }
    #[cfg(feature = "std")]
    fn virtual_port(&mut self) -> Option<&mut super::VirtualPort> {
        (**self).virtual_port()
    }
}
