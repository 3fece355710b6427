//! Faults of an axis and how its group reacts.

/// Why an axis is faulted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum FaultReason {
    /// No fault.
    #[default]
    None,
    /// The drive's heartbeat did not arrive within the consumer time.
    HeartbeatLost,
    /// Node guarding: no answer, or a toggle error.
    GuardingLost,
    /// The drive sent an EMCY with this error code.
    Emcy(u16),
    /// |setpoint - actual| exceeded the configured limit, increments.
    FollowingError {
        /// The error seen.
        error: i64,
        /// The limit.
        limit: i64,
    },
    /// The drive reports a fault (its own number).
    DriveFault(u16),
    /// The Modbus TCP exchange did not answer in time.
    ModbusTimeout,
    /// The drive's TPDO did not arrive for this many cycles in a row.
    LateTpdo(u16),
    /// The drive could not be booted (or is not the configured device).
    BootFailed,
    /// The drive sent a boot-up while in the cycle: it reset itself (power, watchdog) and lost
    /// its configuration; the coordinator configures it again when it is back.
    DriveReset,
}

/// What the coordinator does when it missed cycles itself (an overrun: the host stalled it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum OverrunReaction {
    /// Report it (an event, the count and the longest in the summary) and carry on: the drives
    /// kept their last setpoints and their own supervision (life guarding, heartbeat) watches
    /// the coordinator.
    #[default]
    Report,
    /// Report it and quick-stop every axis: the path was not followed for the cycles missed.
    QuickStop,
}

/// What a group does when one of its axes faults.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Reaction {
    /// Quick stop every axis of the group in the same cycle (the default).
    #[default]
    QuickStopGroup,
    /// Halt (normal deceleration) every axis of the group.
    HaltGroup,
    /// Only the faulted axis stops (quick stop); the others go on.
    AxisOnly,
}
