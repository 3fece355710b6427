"""The motion coordinator's shared-memory contract for Python clients (ctypes).

Mirrors ``shm-api/src/contract.rs`` field by field: the ``#[repr(C)]`` payloads as
``ctypes.Structure``s (ctypes lays them out like a C compiler, and so like ``repr(C)``), the
constants as ``IntEnum``/``IntFlag`` classes, and helpers to read names and to build commands.
``shm-api/tests/layout_languages.rs`` compares :func:`layout_json` with the Rust layout, so a
change on one side without the other fails the test suite.

The five service payloads carry a ``type_name()`` equal to the Rust ``#[type_name]``: the
iceoryx2 Python bindings use it when opening a service, so a client built from another layout
is refused by iceoryx2 exactly as a Rust client would be.

Services, under a prefix (default ``motion``), see :func:`service_names`:

* ``PREFIX/state``: publish-subscribe, :class:`MachineState`, once per cycle, history 1.
* ``PREFIX/command``: request-response, :class:`CommandRequest` -> :class:`CommandReply`.
* ``PREFIX/events``: event service; the event id is an :class:`EventId`.
* ``PREFIX/event-log``: publish-subscribe, :class:`EventRecord`.
* ``PREFIX/description``: publish-subscribe, :class:`MachineDescription`, published once at
  start, history 1 (a client that starts later still receives it).

All integers are in host byte order (little-endian on x86-64 and ARM).
"""

import ctypes
import enum
import json

# --- constants --------------------------------------------------------------------------------

#: The contract's version; bumped on any incompatible change.
LAYOUT_VERSION = 1
#: The layout hash the coordinator writes into ``MachineState.layout_hash``.
LAYOUT_HASH = 0xAD8069D3
#: Axes a MachineState holds.
MAX_AXES = 128
#: Groups a MachineState holds.
MAX_GROUPS = 16
#: Axes of one group move.
MAX_GROUP_AXES = 8
#: Bytes of a name (NUL-padded UTF-8).
NAME_LEN = 16
#: Bytes of a unit name.
UNIT_LEN = 8
#: Positions and velocities are in millionths of the axis's unit.
MICRO = 1_000_000
#: CAN buses a MachineDescription holds.
MAX_BUSES = 8
#: Records of one axis's drive table in an AxisDescription.
MAX_DRIVE_RECORDS = 64
#: Records of one group's table in a GroupDescription.
MAX_GROUP_RECORDS = 256
#: Bytes of a step condition in words (NUL-padded UTF-8).
CONDITION_LEN = 80
#: Bytes of a Modbus TCP address (NUL-padded).
ADDRESS_LEN = 64

#: The default prefix of every service name.
DEFAULT_PREFIX = "motion"

#: The iceoryx2 type names; they must equal the Rust ``#[type_name]`` (the test checks it).
MACHINE_STATE_TYPE_NAME = "motion::MachineState::v1::ad8069d3"
COMMAND_REQUEST_TYPE_NAME = "motion::CommandRequest::v1::ad8069d3"
COMMAND_REPLY_TYPE_NAME = "motion::CommandReply::v1::ad8069d3"
EVENT_RECORD_TYPE_NAME = "motion::EventRecord::v1::ad8069d3"
MACHINE_DESCRIPTION_TYPE_NAME = "motion::MachineDescription::v1::ad8069d3"


class AxisStateKind(enum.IntEnum):
    """What an axis is (``AxisState.state``; Rust ``contract::axis_state``)."""

    OFFLINE = 0
    DISABLED = 1
    ENABLING = 2
    READY = 3
    HOMING = 4
    MOVING = 5
    STOPPING = 6
    FAULT = 7


class AxisMode(enum.IntEnum):
    """What an axis was commanded to do (``AxisState.mode``; Rust ``axis_mode``)."""

    OFF = 0
    ON = 1
    HOMING = 2
    JOG = 3
    QUICK_STOPPED = 4
    ACKNOWLEDGING = 5


class AxisActivity(enum.IntEnum):
    """What an axis is doing as the admission table sees it (``AxisState.activity``; Rust
    ``axis_activity``)."""

    OFFLINE = 0
    DISABLED = 1
    STANDSTILL = 2
    HOMING = 3
    MOVING = 4
    JOGGING = 5
    IN_GROUP_MOVE = 6
    STOPPING = 7
    QUICK_STOPPED = 8
    FAULTED = 9


class GroupActivity(enum.IntEnum):
    """What a group is doing (``GroupState.activity``; Rust ``group_activity``)."""

    DISABLED = 0
    STANDBY = 1
    MOVING = 2
    CHAIN = 3
    HELD = 4
    STOPPING = 5
    FAULTED = 6


class BufferMode(enum.IntEnum):
    """How a move takes over from a running one (``CommandRequest.buffer``; Rust
    ``buffer_mode``)."""

    ABORTING = 0
    BUFFERED = 1


class AxisFlags(enum.IntFlag):
    """Bits of ``AxisState.flags`` (Rust ``axis_flags``)."""

    ONLINE = 1 << 0
    ENABLED = 1 << 1
    HOMED = 1 << 2
    MOTION_COMPLETE = 1 << 3
    WARNING = 1 << 4
    FOLLOWING = 1 << 5
    FHPP = 1 << 6


class Fault(enum.IntEnum):
    """Why an axis is faulted (``AxisState.fault``; Rust ``fault``)."""

    NONE = 0
    HEARTBEAT_LOST = 1
    GUARDING_LOST = 2
    EMCY = 3
    FOLLOWING_ERROR = 4
    DRIVE_FAULT = 5
    MODBUS_TIMEOUT = 6
    LATE_TPDO = 7
    BOOT_FAILED = 8
    DRIVE_RESET = 9
    ETHERCAT_LOST = 10
    ETHERCAT_STATE = 11


class ChainState(enum.IntEnum):
    """A group's chain state (``GroupState.chain_state``; Rust ``chain_state``)."""

    IDLE = 0
    DELAY = 1
    MOVING = 2
    WAITING = 3
    COMPLETE = 4
    ABORTED = 5


class MotionState(enum.IntEnum):
    """A group's move (``GroupState.motion``; Rust ``motion_state``)."""

    NONE = 0
    MOVING = 1
    HOLDING = 2
    QUICK_STOPPING = 3
    STOPPED = 4
    DONE = 5


class CommandKind(enum.IntEnum):
    """``CommandRequest.kind`` (Rust ``command_kind``)."""

    ENABLE = 1
    DISABLE = 2
    ACKNOWLEDGE = 3
    HOME = 4
    JOG = 5
    MOVE_AXIS = 6
    MOVE_GROUP = 7
    START_CHAIN = 8
    HOLD = 9
    RESUME = 10
    STOP = 11
    QUICK_STOP = 12
    SET_OVERRIDE = 13
    READ_PARAMETER = 14
    WRITE_PARAMETER = 15
    SET_INPUT = 16


class Target(enum.IntEnum):
    """Which axes a command addresses (``CommandRequest.target``; Rust ``target``)."""

    AXIS = 0
    GROUP = 1
    ALL = 2


class Status(enum.IntEnum):
    """``CommandReply.status`` (Rust ``status``)."""

    LATCHED = 0
    UNKNOWN_AXIS = 1
    UNKNOWN_GROUP = 2
    UNKNOWN_RECORD = 3
    OUT_OF_RANGE = 4
    WRONG_STATE = 5
    BUSY = 6
    FAULTED = 7
    PLAN = 8
    BAD_REQUEST = 9
    OVERLOADED = 10


class EventId(enum.IntEnum):
    """Event ids on ``PREFIX/events`` and ``EventRecord.id`` (Rust ``event_id``)."""

    STATE_CHANGED = 1
    FAULT = 2
    RECORD_REACHED = 3
    CHAIN_COMPLETE = 4
    CHAIN_ABORTED = 5
    ACKNOWLEDGED = 6
    PARAMETER = 7
    SHUTDOWN = 8
    OVERRUN = 10


class Device(enum.IntEnum):
    """The drive of an axis (``AxisDescription.device``; Rust ``device``)."""

    UNKNOWN = 0
    MTR_DCI = 1
    EMCA = 2
    CMMO_ST = 3
    TLC5XX = 4


class Profile(enum.IntEnum):
    """The device profile (``AxisDescription.profile``; Rust ``profile``)."""

    FHPP = 0
    CIA402 = 1


class Link(enum.IntEnum):
    """How the coordinator reaches a drive (``AxisDescription.link``; Rust ``link``)."""

    CAN = 0
    MODBUS = 1
    ETHERCAT = 2


class BusKind(enum.IntEnum):
    """Where a bus's drives are (``BusDescription.kind``; Rust ``bus_kind``)."""

    SIMULATED = 0
    VBUS = 1
    SOCKETCAN = 2


class Shape(enum.IntEnum):
    """A group's profile shape (``GroupDescription.shape``; Rust ``shape``)."""

    TRAPEZOID = 0
    S_CURVE = 1


class RecordMode(enum.IntEnum):
    """What a group record does (``GroupRecord.mode``; Rust ``record_mode``)."""

    POSITION = 0
    VELOCITY = 1
    FORCE = 2


class TargetKind(enum.IntEnum):
    """Where a member goes in a group record (``GroupRecord.target_kinds``; Rust
    ``target_kind``)."""

    KEEP = 0
    ABSOLUTE = 1
    RELATIVE = 2


#: The Rust module each constant class mirrors (the layout test compares them by these names).
CONSTANT_GROUPS = {
    "axis_state": AxisStateKind,
    "axis_mode": AxisMode,
    "axis_activity": AxisActivity,
    "group_activity": GroupActivity,
    "buffer_mode": BufferMode,
    "axis_flags": AxisFlags,
    "fault": Fault,
    "chain_state": ChainState,
    "motion_state": MotionState,
    "command_kind": CommandKind,
    "target": Target,
    "status": Status,
    "event_id": EventId,
    "device": Device,
    "profile": Profile,
    "link": Link,
    "bus_kind": BusKind,
    "shape": Shape,
    "record_mode": RecordMode,
    "target_kind": TargetKind,
}

# --- helpers ----------------------------------------------------------------------------------


def name_str(raw) -> str:
    """The text of a NUL-padded name field (``bytes`` or a ``c_uint8`` array).

    Invalid UTF-8 is replaced rather than raised: a peer's bytes must not crash a client.
    """
    data = bytes(raw)
    end = data.find(b"\0")
    if end >= 0:
        data = data[:end]
    return data.decode("utf-8", errors="replace")


def name_bytes(text: str, length: int) -> bytes:
    """``text`` as a NUL-padded field of ``length`` bytes; raises ``ValueError`` if too long."""
    data = text.encode("utf-8")
    if len(data) > length:
        raise ValueError(f"name {text!r} is {len(data)} bytes, the field holds {length}")
    return data + b"\0" * (length - len(data))


def format_micro(value: int) -> str:
    """A µunit value as a decimal in units: ``1500000`` -> ``"1.500000"``."""
    sign = "-" if value < 0 else ""
    whole, frac = divmod(abs(value), MICRO)
    return f"{sign}{whole}.{frac:06d}"


def service_names(prefix: str = DEFAULT_PREFIX) -> dict:
    """The service names under ``prefix``, as the Rust ``shm_api::names::ServiceNames``."""
    return {
        "state": f"{prefix}/state",
        "command": f"{prefix}/command",
        "events": f"{prefix}/events",
        "event_log": f"{prefix}/event-log",
        "description": f"{prefix}/description",
    }


def enum_name(cls, value: int) -> str:
    """The name of ``value`` in the constant class ``cls``, or ``UNKNOWN(n)``."""
    try:
        return cls(value).name
    except ValueError:
        return f"UNKNOWN({value})"


# --- payloads ---------------------------------------------------------------------------------

U8 = ctypes.c_uint8
U16 = ctypes.c_uint16
U32 = ctypes.c_uint32
U64 = ctypes.c_uint64
I16 = ctypes.c_int16
I32 = ctypes.c_int32
I64 = ctypes.c_int64


class AxisState(ctypes.Structure):
    """One axis in :class:`MachineState` (128 bytes). Positions in µunits, see ``MICRO``."""

    _fields_ = [
        ("position", I64),
        ("setpoint", I64),
        ("velocity", I64),
        ("position_inc", I64),
        ("setpoint_inc", I64),
        ("fault_value", I64),
        ("fault_limit", I64),
        ("force_permille", I32),
        ("status_bits", U16),
        ("flags", U16),
        ("state", U8),
        ("mode", U8),
        ("fault", U8),
        ("activity", U8),
        ("fault_code", U16),
        ("active_record", I16),
        ("name", U8 * NAME_LEN),
        ("unit", U8 * UNIT_LEN),
        ("reserved1", U8 * 32),
    ]

    def name_str(self) -> str:
        """The axis name."""
        return name_str(self.name)

    def unit_str(self) -> str:
        """The user unit."""
        return name_str(self.unit)

    def state_name(self) -> str:
        """``state`` as its constant's name (``"READY"``)."""
        return enum_name(AxisStateKind, self.state)

    def mode_name(self) -> str:
        """``mode`` as its constant's name."""
        return enum_name(AxisMode, self.mode)

    def fault_name(self) -> str:
        """``fault`` as its constant's name."""
        return enum_name(Fault, self.fault)

    def flag_names(self) -> str:
        """The set ``flags`` as ``"ONLINE|ENABLED"`` (``"-"`` when none)."""
        names = [f.name for f in AxisFlags if self.flags & f.value]
        return "|".join(names) if names else "-"


class GroupState(ctypes.Structure):
    """One group in :class:`MachineState` (48 bytes)."""

    _fields_ = [
        ("active_record", I16),
        ("record", I16),
        ("reached", I16),
        ("override_percent", U16),
        ("chain_state", U8),
        ("rc1", U8),
        ("rcc", U8),
        ("motion", U8),
        ("axis_count", U8),
        ("activity", U8),
        ("reserved0", U8 * 2),
        ("axes", U8 * MAX_GROUP_AXES),
        ("name", U8 * NAME_LEN),
        ("reserved1", U8 * 8),
    ]

    def name_str(self) -> str:
        """The group name."""
        return name_str(self.name)

    def member_axes(self) -> list:
        """The member axes' indices (the first ``axis_count`` of ``axes``)."""
        return list(self.axes[: min(self.axis_count, MAX_GROUP_AXES)])


class BusStats(ctypes.Structure):
    """Bus and cycle counters in :class:`MachineState`."""

    _fields_ = [
        ("frames_sent", U64),
        ("frames_received", U64),
        ("tx_refused", U64),
        ("rx_dropped", U64),
        ("skipped_cycles", U64),
        ("step_ns", U32),
        ("wake_late_us", U32),
    ]


class MachineState(ctypes.Structure):
    """The whole machine, published once per cycle on ``PREFIX/state``."""

    _fields_ = [
        ("version", U32),
        ("layout_hash", U32),
        ("cycle", U64),
        ("sync_time_ns", U64),
        ("publish_time_ns", U64),
        ("cycle_ns", U32),
        ("axis_count", U16),
        ("group_count", U16),
        ("inputs", U32),
        ("virtual_time", U8),
        ("reserved0", U8 * 3),
        ("bus", BusStats),
        ("axes", AxisState * MAX_AXES),
        ("groups", GroupState * MAX_GROUPS),
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 type name (equal to the Rust one)."""
        return MACHINE_STATE_TYPE_NAME

    def valid_axes(self) -> list:
        """The valid axes (the first ``axis_count``, bounded by ``MAX_AXES``)."""
        return list(self.axes[: min(self.axis_count, MAX_AXES)])

    def valid_groups(self) -> list:
        """The valid groups (the first ``group_count``, bounded by ``MAX_GROUPS``)."""
        return list(self.groups[: min(self.group_count, MAX_GROUPS)])

    def layout_matches(self) -> bool:
        """True when the sample was written by a coordinator of this module's layout."""
        return self.version == LAYOUT_VERSION and self.layout_hash == LAYOUT_HASH


class CommandRequest(ctypes.Structure):
    """A command, on ``PREFIX/command``. Build one with the class methods below."""

    _fields_ = [
        ("tag", U64),
        ("kind", U16),
        ("target", U8),
        ("percent", U8),
        ("axis", U16),
        ("group", U16),
        ("record", U16),
        ("sub", U8),
        ("buffer", U8),
        ("pnu", U16),
        ("reserved1", U16),
        ("value", I64),
        ("positions", I64 * MAX_GROUP_AXES),
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 type name (equal to the Rust one)."""
        return COMMAND_REQUEST_TYPE_NAME

    @classmethod
    def _targeted(cls, kind: CommandKind, axis=None, group=None) -> "CommandRequest":
        # One axis, every axis of a group, or (neither given) every axis.
        if axis is not None and group is not None:
            raise ValueError("give an axis or a group, not both")
        req = cls(kind=int(kind))
        if axis is not None:
            req.target, req.axis = int(Target.AXIS), axis
        elif group is not None:
            req.target, req.group = int(Target.GROUP), group
        else:
            req.target = int(Target.ALL)
        return req

    @classmethod
    def enable(cls, axis=None, group=None) -> "CommandRequest":
        """Enable an axis, a group's axes, or (no argument) every axis."""
        return cls._targeted(CommandKind.ENABLE, axis, group)

    @classmethod
    def disable(cls, axis=None, group=None) -> "CommandRequest":
        """Disable an axis, a group's axes, or every axis."""
        return cls._targeted(CommandKind.DISABLE, axis, group)

    @classmethod
    def acknowledge(cls, axis=None, group=None) -> "CommandRequest":
        """Acknowledge the faults of an axis, a group's axes, or every axis."""
        return cls._targeted(CommandKind.ACKNOWLEDGE, axis, group)

    @classmethod
    def home(cls, axis=None, group=None) -> "CommandRequest":
        """Home an axis, a group's axes, or every axis."""
        return cls._targeted(CommandKind.HOME, axis, group)

    @classmethod
    def hold(cls, axis=None, group=None) -> "CommandRequest":
        """Hold an axis, a group, or everything."""
        return cls._targeted(CommandKind.HOLD, axis, group)

    @classmethod
    def resume(cls, axis=None, group=None) -> "CommandRequest":
        """Resume an axis, a group, or everything."""
        return cls._targeted(CommandKind.RESUME, axis, group)

    @classmethod
    def stop(cls, axis=None, group=None) -> "CommandRequest":
        """Stop an axis, a group, or everything."""
        return cls._targeted(CommandKind.STOP, axis, group)

    @classmethod
    def quick_stop(cls, axis=None, group=None) -> "CommandRequest":
        """Quick-stop an axis, a group, or everything."""
        return cls._targeted(CommandKind.QUICK_STOP, axis, group)

    @classmethod
    def jog(cls, axis: int, permille: int) -> "CommandRequest":
        """Jog ``axis`` at ``permille`` ‰ of its velocity limit (signed; 0 stops)."""
        req = cls._targeted(CommandKind.JOG, axis=axis)
        req.value = permille
        return req

    @classmethod
    def move_axis(cls, axis: int, position_micro: int, percent: int) -> "CommandRequest":
        """Move ``axis`` to ``position_micro`` µunits at ``percent`` % of its limits."""
        req = cls._targeted(CommandKind.MOVE_AXIS, axis=axis)
        req.positions[0] = position_micro
        req.percent = percent
        return req

    @classmethod
    def move_group(cls, group: int, positions_micro, percent: int) -> "CommandRequest":
        """Move ``group`` to ``positions_micro`` (µunits, group order) at ``percent`` %."""
        positions = list(positions_micro)
        if len(positions) > MAX_GROUP_AXES:
            raise ValueError(f"{len(positions)} positions, a group move holds {MAX_GROUP_AXES}")
        req = cls._targeted(CommandKind.MOVE_GROUP, group=group)
        for i, p in enumerate(positions):
            req.positions[i] = p
        req.percent = percent
        return req

    @classmethod
    def start_chain(cls, group: int, record: int) -> "CommandRequest":
        """Start ``group``'s record chain at ``record``."""
        req = cls._targeted(CommandKind.START_CHAIN, group=group)
        req.record = record
        return req

    @classmethod
    def set_override(cls, group: int, percent: int) -> "CommandRequest":
        """Set ``group``'s feed override to ``percent`` % (0..=200)."""
        req = cls._targeted(CommandKind.SET_OVERRIDE, group=group)
        # The contract names both `percent` and `value` for the override; both carry it.
        req.value = percent
        req.percent = min(max(percent, 0), 255)
        return req

    @classmethod
    def read_parameter(cls, axis: int, pnu: int, sub: int) -> "CommandRequest":
        """Read parameter ``pnu``:``sub`` of ``axis`` (the value arrives as an event)."""
        req = cls._targeted(CommandKind.READ_PARAMETER, axis=axis)
        req.pnu, req.sub = pnu, sub
        return req

    @classmethod
    def write_parameter(cls, axis: int, pnu: int, sub: int, value: int) -> "CommandRequest":
        """Write ``value`` to parameter ``pnu``:``sub`` of ``axis``."""
        req = cls.read_parameter(axis, pnu, sub)
        req.kind = int(CommandKind.WRITE_PARAMETER)
        req.value = value
        return req

    @classmethod
    def set_input(cls, bit: int, value: bool) -> "CommandRequest":
        """Set input ``bit`` of the machine's input word to ``value``."""
        req = cls(kind=int(CommandKind.SET_INPUT), target=int(Target.ALL))
        req.record = bit
        req.value = 1 if value else 0
        return req


class CommandReply(ctypes.Structure):
    """The answer to a :class:`CommandRequest`."""

    _fields_ = [
        ("tag", U64),
        ("cycle", U64),
        ("value", I64),
        ("min", I64),
        ("max", I64),
        ("status", U16),
        ("reserved0", U8 * 6),
        ("reason", U8 * 48),
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 type name (equal to the Rust one)."""
        return COMMAND_REPLY_TYPE_NAME

    def latched(self) -> bool:
        """True when the command was accepted."""
        return self.status == Status.LATCHED

    def describe(self) -> str:
        """The reply as a sentence."""
        s = self.status
        if s == Status.LATCHED:
            return f"latched at cycle {self.cycle}"
        if s == Status.UNKNOWN_AXIS:
            return f"refused: there is no axis {self.value}"
        if s == Status.UNKNOWN_GROUP:
            return f"refused: there is no group {self.value}"
        if s == Status.UNKNOWN_RECORD:
            return f"refused: there is no record {self.value}"
        if s == Status.OUT_OF_RANGE:
            return f"refused: {self.value} is outside {self.min}..={self.max}"
        if s == Status.WRONG_STATE:
            return f"refused: wrong state: {name_str(self.reason)}"
        if s == Status.BUSY:
            return "refused: busy with another task"
        if s == Status.FAULTED:
            return "refused: a fault must be acknowledged first"
        if s == Status.PLAN:
            return "refused: the move cannot be planned"
        if s == Status.BAD_REQUEST:
            return "refused: the coordinator could not decode the request"
        if s == Status.OVERLOADED:
            return "refused: the coordinator's command queue is full"
        return f"refused with unknown status {s}"


class EventRecord(ctypes.Structure):
    """One event with its details, on ``PREFIX/event-log``."""

    _fields_ = [
        ("seq", U64),
        ("cycle", U64),
        ("value", I64),
        ("id", U16),
        ("axis", U16),
        ("group", U16),
        ("record", U16),
        ("state", U8),
        ("error", U8),
        ("sub", U8),
        ("reserved0", U8),
        ("code", U16),
        ("reserved1", U16),
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 type name (equal to the Rust one)."""
        return EVENT_RECORD_TYPE_NAME

    def id_name(self) -> str:
        """``id`` as its constant's name."""
        return enum_name(EventId, self.id)


class BusDescription(ctypes.Structure):
    """One CAN bus in :class:`MachineDescription` (24 bytes)."""

    _fields_ = [
        ("name", U8 * NAME_LEN),
        ("bitrate", U32),
        ("kind", U8),
        ("reserved0", U8 * 3),
    ]

    def name_str(self) -> str:
        """The bus name."""
        return name_str(self.name)


class DriveRecord(ctypes.Structure):
    """One record of a drive's own table, as configured (32 bytes); µunits."""

    _fields_ = [
        ("position", I64),
        ("velocity", I64),
        ("acceleration", I64),
        ("number", U8),
        ("relative", U8),
        ("next", U8),
        ("reserved0", U8 * 5),
    ]


class AxisDescription(ctypes.Structure):
    """One axis in :class:`MachineDescription` (2216 bytes): drive, link, limits (µunits) and
    the drive's record table."""

    _fields_ = [
        ("position_min", I64),
        ("position_max", I64),
        ("velocity", I64),
        ("acceleration", I64),
        ("jerk", I64),
        ("following_error", I64),
        ("increments_per_unit_num", U64),
        ("increments_per_unit_den", U64),
        ("force_permille", U16),
        ("device", U8),
        ("profile", U8),
        ("fpc", U8),
        ("link", U8),
        ("bus", U8),
        ("node", U8),
        ("simulated", U8),
        ("record_count", U8),
        ("reserved0", U8 * 6),
        ("name", U8 * NAME_LEN),
        ("unit", U8 * UNIT_LEN),
        ("modbus", U8 * ADDRESS_LEN),
        ("records", DriveRecord * MAX_DRIVE_RECORDS),
    ]

    def name_str(self) -> str:
        """The axis name."""
        return name_str(self.name)

    def device_name(self) -> str:
        """``device`` as its constant's name (``"EMCA"``)."""
        return enum_name(Device, self.device)

    def valid_records(self) -> list:
        """The drive records (the first ``record_count``)."""
        return list(self.records[: min(self.record_count, MAX_DRIVE_RECORDS)])


class GroupRecord(ctypes.Structure):
    """One record of a group's table (256 bytes); targets in µunits."""

    _fields_ = [
        ("targets", I64 * MAX_GROUP_AXES),
        ("delay_ms", U32),
        ("force_permille", I32),
        ("number", U16),
        ("step_next", I16),
        ("alternative_next", I16),
        ("mode", U8),
        ("velocity_percent", U8),
        ("acceleration_percent", U8),
        ("jerk_percent", U8),
        ("mc_in_chain", U8),
        ("reserved0", U8 * 5),
        ("target_kinds", U8 * MAX_GROUP_AXES),
        ("step", U8 * CONDITION_LEN),
        ("alternative", U8 * CONDITION_LEN),
    ]

    def step_str(self) -> str:
        """The step condition in words (empty where the chain ends)."""
        return name_str(self.step)

    def alternative_str(self) -> str:
        """The alternative condition in words, or empty."""
        return name_str(self.alternative)


class GroupDescription(ctypes.Structure):
    """One group in :class:`MachineDescription`."""

    _fields_ = [
        ("name", U8 * NAME_LEN),
        ("axes", U8 * MAX_GROUP_AXES),
        ("axis_count", U8),
        ("shape", U8),
        ("record_count", U16),
        ("reserved0", U8 * 4),
        ("records", GroupRecord * MAX_GROUP_RECORDS),
    ]

    def name_str(self) -> str:
        """The group name."""
        return name_str(self.name)

    def valid_records(self) -> list:
        """The group's records (the first ``record_count``)."""
        return list(self.records[: min(self.record_count, MAX_GROUP_RECORDS)])


class MachineDescription(ctypes.Structure):
    """What the machine is, published once at start on ``PREFIX/description``."""

    _fields_ = [
        ("version", U32),
        ("layout_hash", U32),
        ("cycle_ns", U32),
        ("axis_count", U16),
        ("group_count", U16),
        ("bus_count", U8),
        ("reserved0", U8 * 7),
        ("buses", BusDescription * MAX_BUSES),
        ("axes", AxisDescription * MAX_AXES),
        ("groups", GroupDescription * MAX_GROUPS),
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 type name (equal to the Rust one)."""
        return MACHINE_DESCRIPTION_TYPE_NAME

    def valid_axes(self) -> list:
        """The described axes (the first ``axis_count``, the state's order)."""
        return list(self.axes[: min(self.axis_count, MAX_AXES)])

    def valid_groups(self) -> list:
        """The described groups (the first ``group_count``)."""
        return list(self.groups[: min(self.group_count, MAX_GROUPS)])


#: Every payload, nested types first (the order of the Rust dump).
PAYLOADS = [
    AxisState,
    GroupState,
    BusStats,
    MachineState,
    CommandRequest,
    CommandReply,
    EventRecord,
    BusDescription,
    DriveRecord,
    AxisDescription,
    GroupRecord,
    GroupDescription,
    MachineDescription,
]

#: The top-level constants by their Rust names.
TOP_LEVEL_CONSTANTS = {
    "LAYOUT_VERSION": LAYOUT_VERSION,
    "LAYOUT_HASH": LAYOUT_HASH,
    "MAX_AXES": MAX_AXES,
    "MAX_GROUPS": MAX_GROUPS,
    "MAX_GROUP_AXES": MAX_GROUP_AXES,
    "NAME_LEN": NAME_LEN,
    "UNIT_LEN": UNIT_LEN,
    "MICRO": MICRO,
    "MAX_BUSES": MAX_BUSES,
    "MAX_DRIVE_RECORDS": MAX_DRIVE_RECORDS,
    "MAX_GROUP_RECORDS": MAX_GROUP_RECORDS,
    "CONDITION_LEN": CONDITION_LEN,
    "ADDRESS_LEN": ADDRESS_LEN,
}


def layout_json() -> str:
    """This module's layout in the shape of Rust's ``shm_api::layout_dump::layout_json()``."""
    types = []
    for cls in PAYLOADS:
        fields = []
        for name, _ctype in cls._fields_:
            descr = getattr(cls, name)
            fields.append({"name": name, "offset": descr.offset, "size": descr.size})
        types.append(
            {
                "name": cls.__name__,
                "type_name": cls.type_name() if hasattr(cls, "type_name") else None,
                "size": ctypes.sizeof(cls),
                "align": ctypes.alignment(cls),
                "fields": fields,
            }
        )
    constants = dict(TOP_LEVEL_CONSTANTS)
    for module, cls in CONSTANT_GROUPS.items():
        for name, member in cls.__members__.items():
            constants[f"{module}.{name}"] = int(member)
    return json.dumps({"types": types, "constants": constants}, indent=2)


if __name__ == "__main__":
    print(layout_json())
