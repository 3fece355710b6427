//! Commands into the cycle and their answers. Clients (the shell, the shared-memory API, the
//! demo script) send a [`Command`]; the cycle answers every one with a [`Reply`]: accepted and
//! latched in a given cycle, or rejected with a typed [`Rejected`] reason.

pub use crate::admission::BufferMode;

pub use crate::ids::{AxisId, GroupId};

/// Which axes a command addresses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Target {
    /// One axis.
    Axis(AxisId),
    /// Every axis of a group.
    Group(GroupId),
    /// Every axis.
    All,
}

/// A command for the cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Command {
    /// Bring the drives to operation enabled.
    Enable(Target),
    /// Switch the power stages off (after stopping).
    Disable(Target),
    /// Acknowledge faults (of the drives and the coordinator's own).
    Acknowledge(Target),
    /// Run homing.
    Home(Target),
    /// Jog one axis (`0` stops it), direction from the sign, ‰ of its velocity limit.
    Jog {
        /// The axis.
        axis: AxisId,
        /// Signed share of the velocity limit, ‰ (-1000..=1000).
        permille: i16,
    },
    /// Move one axis to a position, increments, at a share of its limits.
    MoveAxis {
        /// The axis.
        axis: AxisId,
        /// Target, increments.
        position: i64,
        /// Share of the velocity limit, 1..=100 %.
        velocity_percent: u8,
        /// How it takes over from a move or jog that runs.
        buffer: BufferMode,
    },
    /// Move a group, time-synchronised, to one target per member (increments, group order;
    /// members beyond the group's size are ignored).
    MoveGroup {
        /// The group.
        group: GroupId,
        /// Targets, increments.
        positions: [i64; crate::ids::MAX_GROUP_AXES],
        /// Share of the velocity limits, 1..=100 %.
        velocity_percent: u8,
        /// How it takes over from a group move that runs.
        buffer: BufferMode,
    },
    /// Start a group's record chain at a record.
    StartChain {
        /// The group.
        group: GroupId,
        /// The first record.
        record: u16,
    },
    /// Hold on the path (decelerate, keep the move to resume).
    Hold(Target),
    /// Resume held moves.
    Resume(Target),
    /// Stop: decelerate and drop the move and any chain.
    Stop(Target),
    /// Quick stop.
    QuickStop(Target),
    /// Feed override, 0..=200 %, of every kind of motion: a group's (its moves, its chain's
    /// records and its members' own moves and jogs), an axis's own moves and jogs, or all.
    SetOverride {
        /// The axes and groups.
        target: Target,
        /// Percent.
        percent: u16,
    },
    /// Read a drive parameter over the FHPP parameter channel (FPC on PDO2; axes with
    /// `fpc = true`). The value arrives later as [`crate::event::Event::Parameter`].
    ReadParameter {
        /// The axis.
        axis: AxisId,
        /// The parameter number.
        pnu: u16,
        /// The sub-index.
        sub: u8,
    },
    /// Write a drive parameter over the parameter channel; the outcome arrives as
    /// [`crate::event::Event::Parameter`].
    WriteParameter {
        /// The axis.
        axis: AxisId,
        /// The parameter number.
        pnu: u16,
        /// The sub-index.
        sub: u8,
        /// The value (32 bits; the drive takes the parameter's width).
        value: u32,
    },
    /// Set or clear a bit of the machine's digital input word (simulated inputs and tests).
    SetInput {
        /// Bit 0..=31.
        bit: u8,
        /// Level.
        value: bool,
    },
}

/// Why a command was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, thiserror::Error)]
pub enum Rejected {
    /// No such axis.
    #[error("unknown axis {0}")]
    UnknownAxis(AxisId),
    /// No such group.
    #[error("unknown group {0}")]
    UnknownGroup(GroupId),
    /// No such record in the group's table.
    #[error("unknown record {0}")]
    UnknownRecord(u16),
    /// A value outside its limit.
    #[error("axis {axis}: {value} outside {min}..={max}")]
    OutOfRange {
        /// The axis (or group) concerned.
        axis: u16,
        /// The value asked for.
        value: i64,
        /// Lowest allowed.
        min: i64,
        /// Highest allowed.
        max: i64,
    },
    /// The axis or group is not in a state that allows the command.
    #[error("wrong state: {0}")]
    WrongState(&'static str),
    /// The axis or group is busy with another task.
    #[error("busy")]
    Busy,
    /// A fault must be acknowledged first.
    #[error("fault not acknowledged")]
    Faulted,
    /// The move cannot be planned (limits too small, too long).
    #[error("cannot plan the move")]
    Plan,
}

/// The answer to a command.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Reply {
    /// Accepted; its effect latches on the drives at the SYNC of this cycle.
    Latched {
        /// The cycle number.
        cycle: u64,
    },
    /// Refused.
    Rejected(Rejected),
}

/// A command with the caller's tag, so answers can be matched to requests.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Request {
    /// Caller's tag, echoed in the answer.
    pub tag: u64,
    /// The command.
    pub command: Command,
}

/// An answer with its request's tag.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Answer {
    /// The request's tag.
    pub tag: u64,
    /// The answer.
    pub reply: Reply,
}
