//! The wire contract: every payload that crosses shared memory, `#[repr(C)]`, fixed size, with
//! explicit padding, so that C, C++ and Python (ctypes) clients can read it as it lies in
//! memory. Units are in each field's doc. Changing any field changes [`LAYOUT_HASH`] (a test
//! recomputes it), and the hash is part of every type name, so a client built against another
//! layout is refused by iceoryx2 when it opens the service.

use iceoryx2::prelude::ZeroCopySend;

/// The contract's version; bumped on any incompatible change.
pub const LAYOUT_VERSION: u32 = 1;
/// A hash of the layout of every payload (sizes and field offsets), checked by a test that
/// recomputes it: see `layout::compute_hash`.
pub const LAYOUT_HASH: u32 = 0xad80_69d3;
/// Axes a [`MachineState`] holds.
pub const MAX_AXES: usize = 128;
/// Groups a [`MachineState`] holds.
pub const MAX_GROUPS: usize = 16;
/// Axes of one group move.
pub const MAX_GROUP_AXES: usize = 8;
/// Bytes of a name (NUL-padded UTF-8).
pub const NAME_LEN: usize = 16;
/// Bytes of a unit name.
pub const UNIT_LEN: usize = 8;
/// User-unit fixed point: positions and velocities are in millionths of the axis's unit
/// (`position = 1_500_000` is 1.5 mm on a mm axis).
pub const MICRO: i64 = 1_000_000;

/// What an axis is (the drive state as the coordinator sees it).
pub mod axis_state {
    /// No image yet, or the drive stopped answering.
    pub const OFFLINE: u8 = 0;
    /// Power stage off.
    pub const DISABLED: u8 = 1;
    /// Being brought to operation enabled.
    pub const ENABLING: u8 = 2;
    /// Operation enabled, standing.
    pub const READY: u8 = 3;
    /// Homing.
    pub const HOMING: u8 = 4;
    /// Moving.
    pub const MOVING: u8 = 5;
    /// Halt or quick stop active.
    pub const STOPPING: u8 = 6;
    /// The drive reports a fault.
    pub const FAULT: u8 = 7;
}

/// What an axis was commanded to do.
pub mod axis_mode {
    /// Power off.
    pub const OFF: u8 = 0;
    /// Enabled (standing or following a move).
    pub const ON: u8 = 1;
    /// Homing.
    pub const HOMING: u8 = 2;
    /// Jogging.
    pub const JOG: u8 = 3;
    /// Quick-stopped (a fault reaction or a command) until acknowledged or re-enabled.
    pub const QUICK_STOPPED: u8 = 4;
    /// Acknowledging a fault.
    pub const ACKNOWLEDGING: u8 = 5;
}

/// What an axis is doing as the coordinator's admission table sees it ([`AxisState::activity`];
/// docs/motion.md has the table of which command each allows).
pub mod axis_activity {
    /// The drive is not booted or not in the cycle.
    pub const OFFLINE: u8 = 0;
    /// Power stage off.
    pub const DISABLED: u8 = 1;
    /// Enabled, not moving.
    pub const STANDSTILL: u8 = 2;
    /// Homing runs.
    pub const HOMING: u8 = 3;
    /// A single-axis move (PLCopen Discrete motion).
    pub const MOVING: u8 = 4;
    /// A jog (PLCopen Continuous motion).
    pub const JOGGING: u8 = 5;
    /// Its group's move or chain drives it (PLCopen Synchronized motion).
    pub const IN_GROUP_MOVE: u8 = 6;
    /// A stop's ramp runs.
    pub const STOPPING: u8 = 7;
    /// Stopped by a quick stop until enabled again.
    pub const QUICK_STOPPED: u8 = 8;
    /// Faulted until acknowledged (PLCopen ErrorStop).
    pub const FAULTED: u8 = 9;
}

/// What a group is doing ([`GroupState::activity`]).
pub mod group_activity {
    /// A member is offline, off or quick-stopped.
    pub const DISABLED: u8 = 0;
    /// Every member enabled; no move, no chain.
    pub const STANDBY: u8 = 1;
    /// A move runs.
    pub const MOVING: u8 = 2;
    /// Its record chain runs.
    pub const CHAIN: u8 = 3;
    /// Held by the operator until resumed.
    pub const HELD: u8 = 4;
    /// A stop's ramp runs.
    pub const STOPPING: u8 = 5;
    /// A member is faulted.
    pub const FAULTED: u8 = 6;
}

/// Bits of [`AxisState::flags`].
pub mod axis_flags {
    /// The drive is booted and in the cycle.
    pub const ONLINE: u16 = 1 << 0;
    /// Enabled by command.
    pub const ENABLED: u16 = 1 << 1;
    /// Referenced (homed).
    pub const HOMED: u16 = 1 << 2;
    /// Motion complete / target reached.
    pub const MOTION_COMPLETE: u16 = 1 << 3;
    /// The drive signals a warning.
    pub const WARNING: u16 = 1 << 4;
    /// A move (group or single-axis) is streaming setpoints to the axis.
    pub const FOLLOWING: u16 = 1 << 5;
    /// The drive is FHPP (clear: CiA 402).
    pub const FHPP: u16 = 1 << 6;
}

/// Why an axis is faulted ([`AxisState::fault`]); [`AxisState::fault_code`] and
/// [`AxisState::fault_value`] carry the numbers.
pub mod fault {
    /// No fault.
    pub const NONE: u8 = 0;
    /// No heartbeat within the consumer time.
    pub const HEARTBEAT_LOST: u8 = 1;
    /// Node guarding lost (no answer, toggle error).
    pub const GUARDING_LOST: u8 = 2;
    /// An EMCY; `fault_code` is its error code.
    pub const EMCY: u8 = 3;
    /// Following error; `fault_value` is the error, `fault_limit` the limit, increments.
    pub const FOLLOWING_ERROR: u8 = 4;
    /// The drive reports a fault; `fault_code` is its number.
    pub const DRIVE_FAULT: u8 = 5;
    /// The Modbus TCP exchange timed out.
    pub const MODBUS_TIMEOUT: u8 = 6;
    /// TPDOs missing; `fault_value` is the number of cycles.
    pub const LATE_TPDO: u8 = 7;
    /// The drive's boot failed.
    pub const BOOT_FAILED: u8 = 8;
    /// The drive sent a boot-up while in the cycle (it reset itself).
    pub const DRIVE_RESET: u8 = 9;
    /// The EtherCAT subdevice does not answer (working counter).
    pub const ETHERCAT_LOST: u8 = 10;
    /// The EtherCAT subdevice left Op; `fault_value` is its AL state (1 Init, 2 PreOp,
    /// 4 SafeOp).
    pub const ETHERCAT_STATE: u8 = 11;
}

/// A group's chain state ([`GroupState::chain_state`]).
pub mod chain_state {
    /// Never started.
    pub const IDLE: u8 = 0;
    /// A record's start delay runs.
    pub const DELAY: u8 = 1;
    /// A record's move runs.
    pub const MOVING: u8 = 2;
    /// The move arrived; waiting for a condition.
    pub const WAITING: u8 = 3;
    /// Ended at a record without a step (RCC).
    pub const COMPLETE: u8 = 4;
    /// Aborted.
    pub const ABORTED: u8 = 5;
}

/// A group's move ([`GroupState::motion`]).
pub mod motion_state {
    /// No move.
    pub const NONE: u8 = 0;
    /// Following the move.
    pub const MOVING: u8 = 1;
    /// Decelerating after a hold.
    pub const HOLDING: u8 = 2;
    /// Decelerating after a quick stop.
    pub const QUICK_STOPPING: u8 = 3;
    /// Stopped on the path; can resume.
    pub const STOPPED: u8 = 4;
    /// Arrived.
    pub const DONE: u8 = 5;
}

/// One axis in [`MachineState`] (128 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
pub struct AxisState {
    /// Actual position, µunits (see [`MICRO`]).
    pub position: i64,
    /// Setpoint, µunits.
    pub setpoint: i64,
    /// Actual velocity, µunits/s (0 where the drive does not report it).
    pub velocity: i64,
    /// Actual position, drive increments.
    pub position_inc: i64,
    /// Setpoint, drive increments.
    pub setpoint_inc: i64,
    /// Following-error value or missed cycles, by [`AxisState::fault`].
    pub fault_value: i64,
    /// The following-error limit, increments (for [`fault::FOLLOWING_ERROR`]).
    pub fault_limit: i64,
    /// Actual force, ‰ of nominal (0 where not reported).
    pub force_permille: i32,
    /// Raw status bits: FHPP SCON | SPOS << 8; CiA 402 statusword.
    pub status_bits: u16,
    /// [`axis_flags`].
    pub flags: u16,
    /// [`axis_state`].
    pub state: u8,
    /// [`axis_mode`].
    pub mode: u8,
    /// [`fault`] kind.
    pub fault: u8,
    /// [`axis_activity`].
    pub activity: u8,
    /// EMCY error code or drive fault number.
    pub fault_code: u16,
    /// The record the axis's group chain is at, or -1.
    pub active_record: i16,
    /// The axis name.
    pub name: [u8; NAME_LEN],
    /// The user unit.
    pub unit: [u8; UNIT_LEN],
    /// Padding, 0 (room for fields of later versions).
    pub reserved1: [u8; 32],
}

/// One group in [`MachineState`] (48 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
pub struct GroupState {
    /// The record running (in a delay, moving or waiting), or -1.
    pub active_record: i16,
    /// The record the chain is at or ended at, or -1 (FHPP status byte 3).
    pub record: i16,
    /// The last record whose move arrived since the chain started, or -1.
    pub reached: i16,
    /// Feed override requested, %.
    pub override_percent: u16,
    /// [`chain_state`].
    pub chain_state: u8,
    /// RC1: a step condition was met since the chain started.
    pub rc1: u8,
    /// RCC: the chain ran to its end.
    pub rcc: u8,
    /// [`motion_state`].
    pub motion: u8,
    /// Number of member axes.
    pub axis_count: u8,
    /// [`group_activity`].
    pub activity: u8,
    /// Padding, 0.
    pub reserved0: [u8; 2],
    /// Member axes (indices into [`MachineState::axes`]); the first `axis_count` count.
    pub axes: [u8; MAX_GROUP_AXES],
    /// The group name.
    pub name: [u8; NAME_LEN],
    /// Padding, 0.
    pub reserved1: [u8; 8],
}

/// Bus and cycle counters in [`MachineState`].
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
pub struct BusStats {
    /// Frames the coordinator sent since the start.
    pub frames_sent: u64,
    /// Frames the coordinator received since the start.
    pub frames_received: u64,
    /// Frames the bus refused to queue.
    pub tx_refused: u64,
    /// Received frames dropped for want of room.
    pub rx_dropped: u64,
    /// Cycles skipped (real time: deadlines long passed; consumer mode: periods without SYNC).
    pub skipped_cycles: u64,
    /// The last cycle step's compute time, ns.
    pub step_ns: u32,
    /// How late the cycle thread woke after its deadline in the last cycle, µs.
    pub wake_late_us: u32,
}

/// The whole machine, published once per cycle on `PREFIX/state`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("motion::MachineState::v1::ad8069d3")]
pub struct MachineState {
    /// [`LAYOUT_VERSION`].
    pub version: u32,
    /// [`LAYOUT_HASH`].
    pub layout_hash: u32,
    /// The cycle number (the step that produced this state).
    pub cycle: u64,
    /// The cycle's SYNC time, ns of CLOCK_MONOTONIC (or of virtual time).
    pub sync_time_ns: u64,
    /// When the sample was sent (stamped after it was written, just before the send), ns of
    /// CLOCK_MONOTONIC (for latency measurements).
    pub publish_time_ns: u64,
    /// Cycle period, ns.
    pub cycle_ns: u32,
    /// Number of valid entries in `axes`.
    pub axis_count: u16,
    /// Number of valid entries in `groups`.
    pub group_count: u16,
    /// The machine's digital input word.
    pub inputs: u32,
    /// 1 in virtual time.
    pub virtual_time: u8,
    /// Padding, 0.
    pub reserved0: [u8; 3],
    /// Bus and cycle counters.
    pub bus: BusStats,
    /// The axes; the first `axis_count` are valid.
    pub axes: [AxisState; MAX_AXES],
    /// The groups; the first `group_count` are valid.
    pub groups: [GroupState; MAX_GROUPS],
}

/// Command kinds ([`CommandRequest::kind`]).
pub mod command_kind {
    /// Enable `target`.
    pub const ENABLE: u16 = 1;
    /// Disable `target`.
    pub const DISABLE: u16 = 2;
    /// Acknowledge faults of `target`.
    pub const ACKNOWLEDGE: u16 = 3;
    /// Home `target`.
    pub const HOME: u16 = 4;
    /// Jog `axis` at `value` ‰ of its velocity limit (signed; 0 stops).
    pub const JOG: u16 = 5;
    /// Move `axis` to `positions[0]` µunits at `percent` % of its velocity limit.
    pub const MOVE_AXIS: u16 = 6;
    /// Move `group` to `positions` (µunits, group order) at `percent` %.
    pub const MOVE_GROUP: u16 = 7;
    /// Start `group`'s chain at `record`.
    pub const START_CHAIN: u16 = 8;
    /// Hold `target`.
    pub const HOLD: u16 = 9;
    /// Resume `target`.
    pub const RESUME: u16 = 10;
    /// Stop `target`.
    pub const STOP: u16 = 11;
    /// Quick stop `target`.
    pub const QUICK_STOP: u16 = 12;
    /// Set `group`'s override to `percent` %.
    pub const SET_OVERRIDE: u16 = 13;
    /// Read parameter `pnu`:`sub` of `axis` (the value arrives as an event).
    pub const READ_PARAMETER: u16 = 14;
    /// Write `value` to parameter `pnu`:`sub` of `axis`.
    pub const WRITE_PARAMETER: u16 = 15;
    /// Set input bit `record` to `value != 0`.
    pub const SET_INPUT: u16 = 16;
}

/// How a move given while another runs takes over ([`CommandRequest::buffer`]), PLCopen's
/// BufferMode.
pub mod buffer_mode {
    /// The running move ramps down along its path; the new one starts from where it stopped.
    pub const ABORTING: u8 = 0;
    /// The new move starts when the running one has arrived.
    pub const BUFFERED: u8 = 1;
}

/// Which axes a command addresses ([`CommandRequest::target`]).
pub mod target {
    /// One axis: `axis`.
    pub const AXIS: u8 = 0;
    /// Every axis of `group`.
    pub const GROUP: u8 = 1;
    /// Every axis.
    pub const ALL: u8 = 2;
}

/// A command, on `PREFIX/command` (request-response).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("motion::CommandRequest::v1::ad8069d3")]
pub struct CommandRequest {
    /// The client's tag, echoed in the reply.
    pub tag: u64,
    /// [`command_kind`].
    pub kind: u16,
    /// [`target`].
    pub target: u8,
    /// Share of the limits, 1..=100 % (moves), or the override (0..=200 %).
    pub percent: u8,
    /// The axis (target [`target::AXIS`], jog, moves, parameters).
    pub axis: u16,
    /// The group (target [`target::GROUP`], group moves, chains, override).
    pub group: u16,
    /// The record (chains), or the input bit.
    pub record: u16,
    /// The parameter's sub-index.
    pub sub: u8,
    /// How a move takes over from one that runs ([`buffer_mode`]; 0, aborting, by default).
    pub buffer: u8,
    /// The parameter number.
    pub pnu: u16,
    /// Padding, 0.
    pub reserved1: u16,
    /// Jog ‰, override %, parameter value, input level.
    pub value: i64,
    /// Targets, µunits (group order for group moves; `[0]` for an axis move).
    pub positions: [i64; MAX_GROUP_AXES],
}

/// Reply status ([`CommandReply::status`]).
pub mod status {
    /// Accepted: latches at the SYNC of `cycle`.
    pub const LATCHED: u16 = 0;
    /// No such axis (`value` = the axis).
    pub const UNKNOWN_AXIS: u16 = 1;
    /// No such group.
    pub const UNKNOWN_GROUP: u16 = 2;
    /// No such record.
    pub const UNKNOWN_RECORD: u16 = 3;
    /// A value outside its limit: `value`, `min`, `max`.
    pub const OUT_OF_RANGE: u16 = 4;
    /// The axis or group is in the wrong state (`reason`).
    pub const WRONG_STATE: u16 = 5;
    /// Busy with another task.
    pub const BUSY: u16 = 6;
    /// A fault must be acknowledged first.
    pub const FAULTED: u16 = 7;
    /// The move cannot be planned.
    pub const PLAN: u16 = 8;
    /// The request could not be decoded (unknown kind or target).
    pub const BAD_REQUEST: u16 = 9;
    /// The coordinator could not take the request (its queue is full).
    pub const OVERLOADED: u16 = 10;
}

/// The answer to a [`CommandRequest`].
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("motion::CommandReply::v1::ad8069d3")]
pub struct CommandReply {
    /// The request's tag.
    pub tag: u64,
    /// The cycle whose SYNC latches the command ([`status::LATCHED`]).
    pub cycle: u64,
    /// The value refused ([`status::OUT_OF_RANGE`]) or the axis/group/record concerned.
    pub value: i64,
    /// The lowest allowed value.
    pub min: i64,
    /// The highest allowed value.
    pub max: i64,
    /// [`status`].
    pub status: u16,
    /// Padding, 0.
    pub reserved0: [u8; 6],
    /// The reason in words for [`status::WRONG_STATE`] (NUL-padded).
    pub reason: [u8; 48],
}

/// Event ids on `PREFIX/events` (iceoryx2 event service; the details are in the next state).
pub mod event_id {
    /// An axis changed state or mode.
    pub const STATE_CHANGED: usize = 1;
    /// An axis faulted.
    pub const FAULT: usize = 2;
    /// A chain reached a record.
    pub const RECORD_REACHED: usize = 3;
    /// A chain completed (RCC).
    pub const CHAIN_COMPLETE: usize = 4;
    /// A chain was aborted.
    pub const CHAIN_ABORTED: usize = 5;
    /// A fault was acknowledged.
    pub const ACKNOWLEDGED: usize = 6;
    /// A parameter task ended.
    pub const PARAMETER: usize = 7;
    /// The coordinator is shutting down.
    pub const SHUTDOWN: usize = 8;
    /// A new state was published (signalled by the coordinator's cycle thread right after it
    /// sends the state; event-driven clients wait on it). Not logged on `event-log`.
    pub const STATE_PUBLISHED: usize = 9;
    /// The coordinator itself missed cycles (the host stalled it): `value` how long it was away
    /// in µs, `code` the cycles skipped (at most 65535). The drives are not blamed for them.
    pub const OVERRUN: usize = 10;
}

/// One event with its details, on `PREFIX/event-log` (publish-subscribe, published from the
/// services thread, never from the cycle thread). Every record is also signalled on
/// `PREFIX/events` with its [`EventRecord::id`] as the event id, so a client can sleep on the
/// event service and read the details here.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("motion::EventRecord::v1::ad8069d3")]
pub struct EventRecord {
    /// A sequence number, counting every record published.
    pub seq: u64,
    /// The cycle it happened in.
    pub cycle: u64,
    /// Details: the value read or written, the following error, the late cycles.
    pub value: i64,
    /// [`event_id`].
    pub id: u16,
    /// The axis, or 0xFFFF.
    pub axis: u16,
    /// The group, or 0xFFFF.
    pub group: u16,
    /// The record, or 0xFFFF.
    pub record: u16,
    /// The axis state ([`axis_state`]) or fault kind ([`fault`]).
    pub state: u8,
    /// 1 if `value` is an error number (a refused parameter task).
    pub error: u8,
    /// The parameter's sub-index.
    pub sub: u8,
    /// Padding, 0.
    pub reserved0: u8,
    /// The parameter number, EMCY code or drive fault number.
    pub code: u16,
    /// Padding, 0.
    pub reserved1: u16,
}

// ---- the machine's description ----------------------------------------------------------------

/// CAN buses a [`MachineDescription`] holds.
pub const MAX_BUSES: usize = 8;
/// Records of one axis's drive table in an [`AxisDescription`] (the EMCA's and the CMMO-ST's
/// 64; the MTR-DCI has 31).
pub const MAX_DRIVE_RECORDS: usize = 64;
/// Records of one group's table in a [`GroupDescription`] (numbers 0..=255).
pub const MAX_GROUP_RECORDS: usize = 256;
/// Bytes of a step condition in words ([`GroupRecord::step`]), NUL-padded UTF-8.
pub const CONDITION_LEN: usize = 80;
/// Bytes of a Modbus TCP address ([`AxisDescription::modbus`]), NUL-padded.
pub const ADDRESS_LEN: usize = 64;

/// The drive of an axis ([`AxisDescription::device`]).
pub mod device {
    /// Not known to this contract version.
    pub const UNKNOWN: u8 = 0;
    /// Festo MTR-DCI (CANopen; FHPP or CiA 402).
    pub const MTR_DCI: u8 = 1;
    /// Festo EMCA (CANopen; FHPP).
    pub const EMCA: u8 = 2;
    /// Festo CMMO-ST (Modbus TCP; FHPP).
    pub const CMMO_ST: u8 = 3;
    /// Schneider TLC5xx (CANopen; CiA 402).
    pub const TLC5XX: u8 = 4;
    /// Any CiA 402 drive, described by its EDS (CANopen; CiA 402).
    pub const CIA402: u8 = 5;
}

/// The device profile an axis is driven with ([`AxisDescription::profile`]).
pub mod profile {
    /// Festo Handling and Positioning Profile.
    pub const FHPP: u8 = 0;
    /// CiA 402 (drives and motion control).
    pub const CIA402: u8 = 1;
}

/// How the coordinator reaches a drive ([`AxisDescription::link`]).
pub mod link {
    /// CANopen on [`super::AxisDescription::bus`], node [`super::AxisDescription::node`].
    pub const CAN: u8 = 0;
    /// Modbus TCP at [`super::AxisDescription::modbus`].
    pub const MODBUS: u8 = 1;
    /// EtherCAT: subdevice [`super::AxisDescription::node`] (its position in the segment,
    /// 1 first) on the interface named in [`super::AxisDescription::modbus`].
    pub const ETHERCAT: u8 = 2;
}

/// Where a bus's drives are ([`BusDescription::kind`]).
pub mod bus_kind {
    /// Simulated inside the coordinator's process.
    pub const SIMULATED: u8 = 0;
    /// Other processes on the cross-process virtual bus `vbus:NAME`.
    pub const VBUS: u8 = 1;
    /// Real drives on the SocketCAN interface `NAME`.
    pub const SOCKETCAN: u8 = 2;
}

/// A group's profile shape ([`GroupDescription::shape`]).
pub mod shape {
    /// Trapezoidal velocity (a member has no jerk limit).
    pub const TRAPEZOID: u8 = 0;
    /// Jerk-limited (every member has a jerk limit).
    pub const S_CURVE: u8 = 1;
}

/// What a group record does ([`GroupRecord::mode`]).
pub mod record_mode {
    /// A time-synchronised group move to the targets.
    pub const POSITION: u8 = 0;
    /// Run at the record's velocity share in the direction of each target's sign.
    pub const VELOCITY: u8 = 1;
    /// Push with [`super::GroupRecord::force_permille`] toward the targets.
    pub const FORCE: u8 = 2;
}

/// Where a member axis goes in a group record ([`GroupRecord::target_kinds`]).
pub mod target_kind {
    /// It keeps still (no target).
    pub const KEEP: u8 = 0;
    /// To the position in [`super::GroupRecord::targets`].
    pub const ABSOLUTE: u8 = 1;
    /// By the distance in [`super::GroupRecord::targets`] from where the record starts.
    pub const RELATIVE: u8 = 2;
}

/// One CAN bus in a [`MachineDescription`] (24 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
pub struct BusDescription {
    /// The bus name (`vbus:NAME` or the SocketCAN interface `NAME`).
    pub name: [u8; NAME_LEN],
    /// Bit/s.
    pub bitrate: u32,
    /// [`bus_kind`].
    pub kind: u8,
    /// Padding, 0.
    pub reserved0: [u8; 3],
}

/// One record of a drive's own record table, as configured (`[[records]]`; 32 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
pub struct DriveRecord {
    /// Target position, µunits (a distance from the last target when `relative`).
    pub position: i64,
    /// Velocity, µunits/s.
    pub velocity: i64,
    /// Acceleration, µunits/s².
    pub acceleration: i64,
    /// The record number, 1..=the device's table size.
    pub number: u8,
    /// 1: `position` is relative.
    pub relative: u8,
    /// The record chained after this one, or 0 (none).
    pub next: u8,
    /// Padding, 0.
    pub reserved0: [u8; 5],
}

/// One axis in a [`MachineDescription`] (2216 bytes): what the state does not carry.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
pub struct AxisDescription {
    /// Lowest position, µunits.
    pub position_min: i64,
    /// Highest position, µunits.
    pub position_max: i64,
    /// Velocity limit, µunits/s.
    pub velocity: i64,
    /// Acceleration limit, µunits/s².
    pub acceleration: i64,
    /// Jerk limit, µunits/s³, or 0 (none: trapezoidal moves).
    pub jerk: i64,
    /// The following-error limit, µunits.
    pub following_error: i64,
    /// The axis's scale, exactly: `increments_per_unit_num / increments_per_unit_den`
    /// increments per user unit, in lowest terms (`increments_per_unit = 12.8` is 64/5).
    pub increments_per_unit_num: u64,
    /// The denominator of the scale (at least 1).
    pub increments_per_unit_den: u64,
    /// The force limit, ‰ of nominal, or 0 (none).
    pub force_permille: u16,
    /// [`device`].
    pub device: u8,
    /// [`profile`].
    pub profile: u8,
    /// 1: the FHPP parameter channel (FPC) is mapped, so READ_PARAMETER and WRITE_PARAMETER
    /// reach the drive.
    pub fpc: u8,
    /// [`link`].
    pub link: u8,
    /// The bus (index into [`MachineDescription::buses`]), or 0xFF on Modbus.
    pub bus: u8,
    /// The CANopen node-ID, or 0 on Modbus.
    pub node: u8,
    /// 1: the drive is simulated inside the coordinator.
    pub simulated: u8,
    /// Valid entries of `records`.
    pub record_count: u8,
    /// Padding, 0.
    pub reserved0: [u8; 6],
    /// The axis name (as in [`AxisState::name`]).
    pub name: [u8; NAME_LEN],
    /// The user unit.
    pub unit: [u8; UNIT_LEN],
    /// The Modbus TCP address the coordinator dials (`host:port`), or empty.
    pub modbus: [u8; ADDRESS_LEN],
    /// The drive's own record table as configured, in number order; the first
    /// `record_count` are valid.
    pub records: [DriveRecord; MAX_DRIVE_RECORDS],
}

/// One record of a group's table (256 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
pub struct GroupRecord {
    /// Per member (group order): the target, µunits, as `target_kinds` says.
    pub targets: [i64; MAX_GROUP_AXES],
    /// Start delay, ms.
    pub delay_ms: u32,
    /// Force for [`record_mode::FORCE`], ‰ of nominal.
    pub force_permille: i32,
    /// The record number, 0..=255.
    pub number: u16,
    /// Where the step condition leads, or -1: the chain ends with this record.
    pub step_next: i16,
    /// Where the alternative leads, or -1 (none).
    pub alternative_next: i16,
    /// [`record_mode`].
    pub mode: u8,
    /// Share of each member's velocity limit, %.
    pub velocity_percent: u8,
    /// Share of each member's acceleration limit, %.
    pub acceleration_percent: u8,
    /// Share of each member's jerk limit, %.
    pub jerk_percent: u8,
    /// 1: MC is shown when the record's move arrives inside a chain.
    pub mc_in_chain: u8,
    /// Padding, 0.
    pub reserved0: [u8; 5],
    /// Per member: [`target_kind`].
    pub target_kinds: [u8; MAX_GROUP_AXES],
    /// The step condition in words, in the axes' units (`position x in [150, 210] mm for 10
    /// ms`), NUL-padded; empty where the chain ends.
    pub step: [u8; CONDITION_LEN],
    /// The alternative condition in words, or empty.
    pub alternative: [u8; CONDITION_LEN],
}

/// One group in a [`MachineDescription`].
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
pub struct GroupDescription {
    /// The group name.
    pub name: [u8; NAME_LEN],
    /// Member axes (indices into [`MachineDescription::axes`]); the first `axis_count` count.
    pub axes: [u8; MAX_GROUP_AXES],
    /// Number of member axes.
    pub axis_count: u8,
    /// [`shape`].
    pub shape: u8,
    /// Valid entries of `records`.
    pub record_count: u16,
    /// Padding, 0.
    pub reserved0: [u8; 4],
    /// The group's record table, in number order; the first `record_count` are valid.
    pub records: [GroupRecord; MAX_GROUP_RECORDS],
}

/// What the machine is, published once by the coordinator at start on `PREFIX/description`
/// (publish-subscribe, history 1: a client that starts later still receives it). It carries
/// what [`MachineState`] does not: per axis its drive, link, limits and drive records, per
/// group its record table with the step conditions in words. The axes and groups are those of
/// the state, in the same order.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("motion::MachineDescription::v1::ad8069d3")]
pub struct MachineDescription {
    /// [`LAYOUT_VERSION`].
    pub version: u32,
    /// [`LAYOUT_HASH`].
    pub layout_hash: u32,
    /// Cycle period, ns.
    pub cycle_ns: u32,
    /// Number of valid entries in `axes`.
    pub axis_count: u16,
    /// Number of valid entries in `groups`.
    pub group_count: u16,
    /// Number of valid entries in `buses`.
    pub bus_count: u8,
    /// Padding, 0.
    pub reserved0: [u8; 7],
    /// The CAN buses.
    pub buses: [BusDescription; MAX_BUSES],
    /// The axes; the first `axis_count` are valid.
    pub axes: [AxisDescription; MAX_AXES],
    /// The groups; the first `group_count` are valid.
    pub groups: [GroupDescription; MAX_GROUPS],
}
