//! TEMPORARY STAND-IN — delete this file at merge.
//!
//! The smallest copy of the parts of the client library (`shm_api::client`, the command
//! builders, `name_str`) that the shipped clients use, written to the agreed API so that the
//! clients compile and test before the library lands. Nothing outside `cli` uses it; `cli`
//! re-exports from here in one place (`cli/mod.rs`, marked "merge point"). At merge: delete
//! this file and its `mod` line, point the re-exports at the library and implement
//! `cli::Machine` for `client::Client`.

use core::fmt;

use crate::contract::{CommandRequest, MAX_GROUP_AXES, command_kind, target};

/// Which axes a command addresses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Target {
    /// One axis.
    Axis(u16),
    /// Every axis of a group.
    Group(u16),
    /// Every axis.
    All,
}

/// A command was accepted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Latched {
    /// The cycle whose SYNC latches it.
    pub cycle: u64,
}

/// Why a command was not accepted.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Rejected {
    /// No such axis.
    UnknownAxis(u16),
    /// No such group.
    UnknownGroup(u16),
    /// No such record.
    UnknownRecord(u16),
    /// A value outside its limits.
    OutOfRange {
        /// The value.
        value: i64,
        /// Lowest allowed.
        min: i64,
        /// Highest allowed.
        max: i64,
    },
    /// Wrong state, with the reason.
    WrongState(String),
    /// Busy.
    Busy,
    /// Faulted.
    Faulted,
    /// Not plannable.
    Plan,
    /// Not decodable.
    BadRequest,
    /// Queue full.
    Overloaded,
    /// No reply in time.
    Timeout,
    /// The coordinator went away.
    Disconnected,
}

impl fmt::Display for Rejected {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Rejected::UnknownAxis(a) => write!(f, "there is no axis {a}"),
            Rejected::UnknownGroup(g) => write!(f, "there is no group {g}"),
            Rejected::UnknownRecord(r) => write!(f, "there is no record {r}"),
            Rejected::OutOfRange { value, min, max } => {
                write!(f, "{value} is outside {min}..={max}")
            }
            Rejected::WrongState(r) => write!(f, "wrong state: {r}"),
            Rejected::Busy => write!(f, "busy with another task"),
            Rejected::Faulted => write!(f, "a fault must be acknowledged first"),
            Rejected::Plan => write!(f, "the move cannot be planned"),
            Rejected::BadRequest => write!(f, "the request could not be decoded"),
            Rejected::Overloaded => write!(f, "the coordinator's command queue is full"),
            Rejected::Timeout => write!(f, "no reply in time"),
            Rejected::Disconnected => write!(f, "the coordinator went away"),
        }
    }
}

/// Why the client cannot talk to a coordinator.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ClientError {
    /// Nothing publishes under the prefix.
    NoCoordinator(String),
    /// Built from another contract version.
    LayoutMismatch {
        /// Ours.
        expected: String,
        /// Theirs.
        found: String,
    },
    /// Nothing within the timeout.
    Timeout,
    /// The coordinator went away.
    Disconnected,
    /// iceoryx2 failed.
    Shm(String),
}

impl fmt::Display for ClientError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ClientError::NoCoordinator(p) => write!(f, "no coordinator runs with prefix '{p}'"),
            ClientError::LayoutMismatch { expected, found } => write!(
                f,
                "client and coordinator were built from different contract versions ({expected} vs {found})"
            ),
            ClientError::Timeout => write!(f, "timed out"),
            ClientError::Disconnected => write!(f, "the coordinator went away"),
            ClientError::Shm(e) => write!(f, "shared memory: {e}"),
        }
    }
}

/// The text of a NUL-padded name (up to the first NUL; invalid UTF-8 gives "?").
pub fn name_str(bytes: &[u8]) -> &str {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    core::str::from_utf8(bytes.get(..end).unwrap_or(&[])).unwrap_or("?")
}

fn blank(kind: u16) -> CommandRequest {
    CommandRequest {
        tag: 0,
        kind,
        target: target::ALL,
        percent: 0,
        axis: 0,
        group: 0,
        record: 0,
        sub: 0,
        reserved0: 0,
        pnu: 0,
        reserved1: 0,
        value: 0,
        positions: [0; MAX_GROUP_AXES],
    }
}

fn targeted(kind: u16, t: Target) -> CommandRequest {
    let mut r = blank(kind);
    match t {
        Target::Axis(a) => {
            r.target = target::AXIS;
            r.axis = a;
        }
        Target::Group(g) => {
            r.target = target::GROUP;
            r.group = g;
        }
        Target::All => r.target = target::ALL,
    }
    r
}

#[allow(missing_docs)]
impl CommandRequest {
    pub fn enable(t: Target) -> Self {
        targeted(command_kind::ENABLE, t)
    }
    pub fn disable(t: Target) -> Self {
        targeted(command_kind::DISABLE, t)
    }
    pub fn acknowledge(t: Target) -> Self {
        targeted(command_kind::ACKNOWLEDGE, t)
    }
    pub fn home(t: Target) -> Self {
        targeted(command_kind::HOME, t)
    }
    pub fn hold(t: Target) -> Self {
        targeted(command_kind::HOLD, t)
    }
    pub fn resume(t: Target) -> Self {
        targeted(command_kind::RESUME, t)
    }
    pub fn stop(t: Target) -> Self {
        targeted(command_kind::STOP, t)
    }
    pub fn quick_stop(t: Target) -> Self {
        targeted(command_kind::QUICK_STOP, t)
    }
    pub fn jog(axis: u16, permille: i16) -> Self {
        let mut r = targeted(command_kind::JOG, Target::Axis(axis));
        r.value = i64::from(permille);
        r
    }
    pub fn move_axis(axis: u16, position_micro: i64, percent: u8) -> Self {
        let mut r = targeted(command_kind::MOVE_AXIS, Target::Axis(axis));
        r.positions[0] = position_micro;
        r.percent = percent;
        r
    }
    pub fn move_group(group: u16, positions_micro: &[i64], percent: u8) -> Self {
        let mut r = targeted(command_kind::MOVE_GROUP, Target::Group(group));
        for (d, s) in r.positions.iter_mut().zip(positions_micro) {
            *d = *s;
        }
        r.percent = percent;
        r
    }
    pub fn start_chain(group: u16, record: u16) -> Self {
        let mut r = targeted(command_kind::START_CHAIN, Target::Group(group));
        r.record = record;
        r
    }
    pub fn set_override(group: u16, percent: u16) -> Self {
        let mut r = targeted(command_kind::SET_OVERRIDE, Target::Group(group));
        r.value = i64::from(percent);
        r
    }
    pub fn read_parameter(axis: u16, pnu: u16, sub: u8) -> Self {
        let mut r = targeted(command_kind::READ_PARAMETER, Target::Axis(axis));
        r.pnu = pnu;
        r.sub = sub;
        r
    }
    pub fn write_parameter(axis: u16, pnu: u16, sub: u8, value: i64) -> Self {
        let mut r = Self::read_parameter(axis, pnu, sub);
        r.kind = command_kind::WRITE_PARAMETER;
        r.value = value;
        r
    }
    pub fn set_input(bit: u16, value: bool) -> Self {
        let mut r = blank(command_kind::SET_INPUT);
        r.record = bit;
        r.value = i64::from(value);
        r
    }
}

/// Stand-in for `Client::connect`: there is no client yet, so there is never a coordinator.
pub fn connect(prefix: &str) -> Result<NoClient, ClientError> {
    Err(ClientError::NoCoordinator(prefix.to_string()))
}

/// A client that cannot exist (the stand-in never connects).
pub enum NoClient {}

impl crate::cli::Machine for NoClient {
    fn latest(&mut self) -> Option<&crate::contract::MachineState> {
        match *self {}
    }
    fn next(
        &mut self,
        _: core::time::Duration,
    ) -> Result<&crate::contract::MachineState, ClientError> {
        match *self {}
    }
    fn command(
        &mut self,
        _: &CommandRequest,
        _: core::time::Duration,
    ) -> Result<Latched, Rejected> {
        match *self {}
    }
    fn wait_event(
        &mut self,
        _: core::time::Duration,
    ) -> Result<Option<crate::contract::EventRecord>, ClientError> {
        match *self {}
    }
}
