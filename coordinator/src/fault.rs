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
    /// The EtherCAT subdevice no longer answers (its share of the working counter is missing:
    /// switched off, or the line is broken before it).
    EthercatLost,
    /// The EtherCAT subdevice left Op; its AL state (1 Init, 2 PreOp, 4 SafeOp).
    EthercatState(u8),
}

impl core::fmt::Display for FaultReason {
    /// The reason in words, as an operator reads it ("heartbeat lost", "no TPDO for 3
    /// cycles"); a following error in increments, the drive's unit (the runtime adds the
    /// axis's own unit where it knows it).
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            FaultReason::None => f.write_str("none"),
            FaultReason::HeartbeatLost => f.write_str("heartbeat lost"),
            FaultReason::GuardingLost => f.write_str("node guarding lost"),
            FaultReason::Emcy(c) => write!(f, "EMCY {c:04X}h"),
            FaultReason::FollowingError { error, limit } => {
                write!(f, "following error {error} inc > {limit} inc")
            }
            FaultReason::DriveFault(c) => write!(f, "drive fault {c:04X}h"),
            FaultReason::ModbusTimeout => f.write_str("Modbus TCP timeout"),
            FaultReason::LateTpdo(n) => write!(f, "no TPDO for {n} cycles"),
            FaultReason::BootFailed => f.write_str("boot failed"),
            FaultReason::DriveReset => {
                f.write_str("the drive reset itself (boot-up while running)")
            }
            FaultReason::EthercatLost => f.write_str("EtherCAT subdevice not answering"),
            FaultReason::EthercatState(s) => write!(
                f,
                "EtherCAT subdevice fell back to {}",
                match s & 0x0F {
                    1 => "Init",
                    2 => "Pre-Operational",
                    3 => "Bootstrap",
                    4 => "Safe-Operational",
                    _ => "an unknown state",
                }
            ),
        }
    }
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
