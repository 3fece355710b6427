/*
 * motion_shm.h: the motion coordinator's shared-memory contract for C and C++ clients.
 *
 * Mirrors shm-api/src/contract.rs field by field: every payload is #[repr(C)] in Rust, so the
 * structs below have the same layout on the same target (host byte order, little-endian on
 * x86-64 and ARM). All padding is explicit (reserved fields, zero). The _Static_asserts at the
 * end pin every size and offset, and shm-api/tests/layout_languages.rs compares this header
 * with the Rust layout, so neither side can change without the other.
 *
 * Services under a prefix (default "motion"):
 *   PREFIX/state      publish-subscribe, MotionMachineState, once per cycle, history 1
 *   PREFIX/command    request-response, MotionCommandRequest -> MotionCommandReply
 *   PREFIX/events     event service, event id = MOTION_EVENT_ID_*
 *   PREFIX/event-log  publish-subscribe, MotionEventRecord
 *   PREFIX/description publish-subscribe, MotionMachineDescription, once at start, history 1
 * Open them with the iceoryx2 C or C++ bindings using the MOTION_*_TYPE_NAME strings as the
 * payload type names (size and alignment from sizeof/alignof): a coordinator built from
 * another layout then refuses the client when it opens the service.
 */
#ifndef MOTION_SHM_H
#define MOTION_SHM_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
#define MOTION_STATIC_ASSERT(cond, msg) static_assert(cond, msg)
#define MOTION_ALIGNOF(t) alignof(t)
extern "C" {
#else
#define MOTION_STATIC_ASSERT(cond, msg) _Static_assert(cond, msg)
#define MOTION_ALIGNOF(t) _Alignof(t)
#endif

/* ---- constants ---------------------------------------------------------------------------- */

/* The contract's version; bumped on any incompatible change. */
#define MOTION_LAYOUT_VERSION 1u
/* The layout hash the coordinator writes into MotionMachineState.layout_hash. */
#define MOTION_LAYOUT_HASH 0xad8069d3u
#define MOTION_MAX_AXES 128
#define MOTION_MAX_GROUPS 16
#define MOTION_MAX_GROUP_AXES 8
/* Bytes of a name (NUL-padded UTF-8, not necessarily NUL-terminated when full). */
#define MOTION_NAME_LEN 16
#define MOTION_UNIT_LEN 8
/* Positions and velocities are in millionths of the axis's unit. */
#define MOTION_MICRO 1000000LL
/* Capacities of MotionMachineDescription. */
#define MOTION_MAX_BUSES 8
#define MOTION_MAX_DRIVE_RECORDS 64
#define MOTION_MAX_GROUP_RECORDS 256
/* Bytes of a step condition in words and of a Modbus address (NUL-padded UTF-8). */
#define MOTION_CONDITION_LEN 80
#define MOTION_ADDRESS_LEN 64

/* iceoryx2 type names of the service payloads (equal to the Rust #[type_name]). */
#define MOTION_MACHINE_STATE_TYPE_NAME "motion::MachineState::v1::ad8069d3"
#define MOTION_COMMAND_REQUEST_TYPE_NAME "motion::CommandRequest::v1::ad8069d3"
#define MOTION_COMMAND_REPLY_TYPE_NAME "motion::CommandReply::v1::ad8069d3"
#define MOTION_EVENT_RECORD_TYPE_NAME "motion::EventRecord::v1::ad8069d3"
#define MOTION_MACHINE_DESCRIPTION_TYPE_NAME "motion::MachineDescription::v1::ad8069d3"
/* The default service prefix. */
#define MOTION_DEFAULT_PREFIX "motion"

/* MotionAxisState.state */
#define MOTION_AXIS_STATE_OFFLINE 0
#define MOTION_AXIS_STATE_DISABLED 1
#define MOTION_AXIS_STATE_ENABLING 2
#define MOTION_AXIS_STATE_READY 3
#define MOTION_AXIS_STATE_HOMING 4
#define MOTION_AXIS_STATE_MOVING 5
#define MOTION_AXIS_STATE_STOPPING 6
#define MOTION_AXIS_STATE_FAULT 7

/* MotionAxisState.mode */
#define MOTION_AXIS_MODE_OFF 0
#define MOTION_AXIS_MODE_ON 1
#define MOTION_AXIS_MODE_HOMING 2
#define MOTION_AXIS_MODE_JOG 3
#define MOTION_AXIS_MODE_QUICK_STOPPED 4
#define MOTION_AXIS_MODE_ACKNOWLEDGING 5

/* MotionAxisState.activity: what the axis is doing (docs/motion.md, the admission table) */
#define MOTION_AXIS_ACTIVITY_OFFLINE 0
#define MOTION_AXIS_ACTIVITY_DISABLED 1
#define MOTION_AXIS_ACTIVITY_STANDSTILL 2
#define MOTION_AXIS_ACTIVITY_HOMING 3
#define MOTION_AXIS_ACTIVITY_MOVING 4
#define MOTION_AXIS_ACTIVITY_JOGGING 5
#define MOTION_AXIS_ACTIVITY_IN_GROUP_MOVE 6
#define MOTION_AXIS_ACTIVITY_STOPPING 7
#define MOTION_AXIS_ACTIVITY_QUICK_STOPPED 8
#define MOTION_AXIS_ACTIVITY_FAULTED 9

/* MotionGroupState.activity */
#define MOTION_GROUP_ACTIVITY_DISABLED 0
#define MOTION_GROUP_ACTIVITY_STANDBY 1
#define MOTION_GROUP_ACTIVITY_MOVING 2
#define MOTION_GROUP_ACTIVITY_CHAIN 3
#define MOTION_GROUP_ACTIVITY_HELD 4
#define MOTION_GROUP_ACTIVITY_STOPPING 5
#define MOTION_GROUP_ACTIVITY_FAULTED 6

/* MotionCommandRequest.buffer: how a move takes over from a running one */
#define MOTION_BUFFER_MODE_ABORTING 0
#define MOTION_BUFFER_MODE_BUFFERED 1

/* MotionAxisState.flags bits */
#define MOTION_AXIS_FLAGS_ONLINE (1u << 0)
#define MOTION_AXIS_FLAGS_ENABLED (1u << 1)
#define MOTION_AXIS_FLAGS_HOMED (1u << 2)
#define MOTION_AXIS_FLAGS_MOTION_COMPLETE (1u << 3)
#define MOTION_AXIS_FLAGS_WARNING (1u << 4)
#define MOTION_AXIS_FLAGS_FOLLOWING (1u << 5)
#define MOTION_AXIS_FLAGS_FHPP (1u << 6)

/* MotionAxisState.fault */
#define MOTION_FAULT_NONE 0
#define MOTION_FAULT_HEARTBEAT_LOST 1
#define MOTION_FAULT_GUARDING_LOST 2
#define MOTION_FAULT_EMCY 3
#define MOTION_FAULT_FOLLOWING_ERROR 4
#define MOTION_FAULT_DRIVE_FAULT 5
#define MOTION_FAULT_MODBUS_TIMEOUT 6
#define MOTION_FAULT_LATE_TPDO 7
#define MOTION_FAULT_BOOT_FAILED 8
#define MOTION_FAULT_DRIVE_RESET 9
#define MOTION_FAULT_ETHERCAT_LOST 10
#define MOTION_FAULT_ETHERCAT_STATE 11

/* MotionGroupState.chain_state */
#define MOTION_CHAIN_STATE_IDLE 0
#define MOTION_CHAIN_STATE_DELAY 1
#define MOTION_CHAIN_STATE_MOVING 2
#define MOTION_CHAIN_STATE_WAITING 3
#define MOTION_CHAIN_STATE_COMPLETE 4
#define MOTION_CHAIN_STATE_ABORTED 5

/* MotionGroupState.motion */
#define MOTION_MOTION_STATE_NONE 0
#define MOTION_MOTION_STATE_MOVING 1
#define MOTION_MOTION_STATE_HOLDING 2
#define MOTION_MOTION_STATE_QUICK_STOPPING 3
#define MOTION_MOTION_STATE_STOPPED 4
#define MOTION_MOTION_STATE_DONE 5

/* MotionCommandRequest.kind */
#define MOTION_COMMAND_KIND_ENABLE 1
#define MOTION_COMMAND_KIND_DISABLE 2
#define MOTION_COMMAND_KIND_ACKNOWLEDGE 3
#define MOTION_COMMAND_KIND_HOME 4
#define MOTION_COMMAND_KIND_JOG 5
#define MOTION_COMMAND_KIND_MOVE_AXIS 6
#define MOTION_COMMAND_KIND_MOVE_GROUP 7
#define MOTION_COMMAND_KIND_START_CHAIN 8
#define MOTION_COMMAND_KIND_HOLD 9
#define MOTION_COMMAND_KIND_RESUME 10
#define MOTION_COMMAND_KIND_STOP 11
#define MOTION_COMMAND_KIND_QUICK_STOP 12
#define MOTION_COMMAND_KIND_SET_OVERRIDE 13
#define MOTION_COMMAND_KIND_READ_PARAMETER 14
#define MOTION_COMMAND_KIND_WRITE_PARAMETER 15
#define MOTION_COMMAND_KIND_SET_INPUT 16

/* MotionCommandRequest.target */
#define MOTION_TARGET_AXIS 0
#define MOTION_TARGET_GROUP 1
#define MOTION_TARGET_ALL 2

/* MotionCommandReply.status */
#define MOTION_STATUS_LATCHED 0
#define MOTION_STATUS_UNKNOWN_AXIS 1
#define MOTION_STATUS_UNKNOWN_GROUP 2
#define MOTION_STATUS_UNKNOWN_RECORD 3
#define MOTION_STATUS_OUT_OF_RANGE 4
#define MOTION_STATUS_WRONG_STATE 5
#define MOTION_STATUS_BUSY 6
#define MOTION_STATUS_FAULTED 7
#define MOTION_STATUS_PLAN 8
#define MOTION_STATUS_BAD_REQUEST 9
#define MOTION_STATUS_OVERLOADED 10

/* Event ids on PREFIX/events and MotionEventRecord.id */
#define MOTION_EVENT_ID_STATE_CHANGED 1
#define MOTION_EVENT_ID_FAULT 2
#define MOTION_EVENT_ID_RECORD_REACHED 3
#define MOTION_EVENT_ID_CHAIN_COMPLETE 4
#define MOTION_EVENT_ID_CHAIN_ABORTED 5
#define MOTION_EVENT_ID_ACKNOWLEDGED 6
#define MOTION_EVENT_ID_PARAMETER 7
#define MOTION_EVENT_ID_SHUTDOWN 8
#define MOTION_EVENT_ID_OVERRUN 10

/* MotionAxisDescription.device */
#define MOTION_DEVICE_UNKNOWN 0
#define MOTION_DEVICE_MTR_DCI 1
#define MOTION_DEVICE_EMCA 2
#define MOTION_DEVICE_CMMO_ST 3
#define MOTION_DEVICE_TLC5XX 4

/* MotionAxisDescription.profile */
#define MOTION_PROFILE_FHPP 0
#define MOTION_PROFILE_CIA402 1

/* MotionAxisDescription.link */
#define MOTION_LINK_CAN 0
#define MOTION_LINK_MODBUS 1
#define MOTION_LINK_ETHERCAT 2

/* MotionBusDescription.kind */
#define MOTION_BUS_KIND_SIMULATED 0
#define MOTION_BUS_KIND_VBUS 1
#define MOTION_BUS_KIND_SOCKETCAN 2

/* MotionGroupDescription.shape */
#define MOTION_SHAPE_TRAPEZOID 0
#define MOTION_SHAPE_S_CURVE 1

/* MotionGroupRecord.mode */
#define MOTION_RECORD_MODE_POSITION 0
#define MOTION_RECORD_MODE_VELOCITY 1
#define MOTION_RECORD_MODE_FORCE 2

/* MotionGroupRecord.target_kinds[] */
#define MOTION_TARGET_KIND_KEEP 0
#define MOTION_TARGET_KIND_ABSOLUTE 1
#define MOTION_TARGET_KIND_RELATIVE 2

/* ---- payloads ----------------------------------------------------------------------------- */

/* One axis in MotionMachineState (128 bytes). Positions in µunits (MOTION_MICRO). */
typedef struct MotionAxisState {
    int64_t position;      /* actual position, µunits */
    int64_t setpoint;      /* setpoint, µunits */
    int64_t velocity;      /* actual velocity, µunits/s (0 where not reported) */
    int64_t position_inc;  /* actual position, drive increments */
    int64_t setpoint_inc;  /* setpoint, drive increments */
    int64_t fault_value;   /* following error or missed cycles, by `fault` */
    int64_t fault_limit;   /* following-error limit, increments */
    int32_t force_permille; /* actual force, per mille of nominal */
    uint16_t status_bits;  /* FHPP SCON | SPOS << 8; CiA 402 statusword */
    uint16_t flags;        /* MOTION_AXIS_FLAGS_* */
    uint8_t state;         /* MOTION_AXIS_STATE_* */
    uint8_t mode;          /* MOTION_AXIS_MODE_* */
    uint8_t fault;         /* MOTION_FAULT_* */
    uint8_t activity;      /* MOTION_AXIS_ACTIVITY_* */
    uint16_t fault_code;   /* EMCY error code or drive fault number */
    int16_t active_record; /* the record the group chain is at, or -1 */
    uint8_t name[MOTION_NAME_LEN];
    uint8_t unit[MOTION_UNIT_LEN];
    uint8_t reserved1[32];
} MotionAxisState;

/* One group in MotionMachineState (48 bytes). */
typedef struct MotionGroupState {
    int16_t active_record;     /* the record running, or -1 */
    int16_t record;            /* the record the chain is at or ended at, or -1 */
    int16_t reached;           /* the last record whose move arrived, or -1 */
    uint16_t override_percent; /* feed override, % */
    uint8_t chain_state;       /* MOTION_CHAIN_STATE_* */
    uint8_t rc1;               /* a step condition was met since the chain started */
    uint8_t rcc;               /* the chain ran to its end */
    uint8_t motion;            /* MOTION_MOTION_STATE_* */
    uint8_t axis_count;        /* member axes */
    uint8_t activity;          /* MOTION_GROUP_ACTIVITY_* */
    uint8_t reserved0[2];
    uint8_t axes[MOTION_MAX_GROUP_AXES]; /* indices into MotionMachineState.axes */
    uint8_t name[MOTION_NAME_LEN];
    uint8_t reserved1[8];
} MotionGroupState;

/* Bus and cycle counters in MotionMachineState. */
typedef struct MotionBusStats {
    uint64_t frames_sent;
    uint64_t frames_received;
    uint64_t tx_refused;
    uint64_t rx_dropped;
    uint64_t skipped_cycles;
    uint32_t step_ns;      /* the last cycle step's compute time, ns */
    uint32_t wake_late_us; /* how late the cycle thread woke, µs */
} MotionBusStats;

/* The whole machine, once per cycle on PREFIX/state. */
typedef struct MotionMachineState {
    uint32_t version;         /* MOTION_LAYOUT_VERSION */
    uint32_t layout_hash;     /* MOTION_LAYOUT_HASH */
    uint64_t cycle;
    uint64_t sync_time_ns;    /* the cycle's SYNC time, CLOCK_MONOTONIC (or virtual) ns */
    uint64_t publish_time_ns; /* when the sample was sent, CLOCK_MONOTONIC ns */
    uint32_t cycle_ns;
    uint16_t axis_count;      /* valid entries in axes */
    uint16_t group_count;     /* valid entries in groups */
    uint32_t inputs;          /* the machine's digital input word */
    uint8_t virtual_time;     /* 1 in virtual time */
    uint8_t reserved0[3];
    MotionBusStats bus;
    MotionAxisState axes[MOTION_MAX_AXES];
    MotionGroupState groups[MOTION_MAX_GROUPS];
} MotionMachineState;

/* A command on PREFIX/command. Zero it, then fill the fields its kind uses. */
typedef struct MotionCommandRequest {
    uint64_t tag;     /* echoed in the reply */
    uint16_t kind;    /* MOTION_COMMAND_KIND_* */
    uint8_t target;   /* MOTION_TARGET_* */
    uint8_t percent;  /* share of the limits 1..100 % (moves) */
    uint16_t axis;
    uint16_t group;
    uint16_t record;  /* chains; the input bit for SET_INPUT */
    uint8_t sub;      /* parameter sub-index */
    uint8_t buffer;   /* moves: 0 aborting, 1 buffered */
    uint16_t pnu;     /* parameter number */
    uint16_t reserved1;
    int64_t value;    /* jog per mille, override %, parameter value, input level */
    int64_t positions[MOTION_MAX_GROUP_AXES]; /* targets, µunits */
} MotionCommandRequest;

/* The answer to a MotionCommandRequest. */
typedef struct MotionCommandReply {
    uint64_t tag;    /* the request's tag */
    uint64_t cycle;  /* the cycle whose SYNC latches the command (LATCHED) */
    int64_t value;   /* the value refused, or the axis/group/record concerned */
    int64_t min;
    int64_t max;
    uint16_t status; /* MOTION_STATUS_* */
    uint8_t reserved0[6];
    uint8_t reason[48]; /* words for WRONG_STATE, NUL-padded */
} MotionCommandReply;

/* One event with its details, on PREFIX/event-log. */
typedef struct MotionEventRecord {
    uint64_t seq;    /* counts every record published */
    uint64_t cycle;
    int64_t value;   /* value read or written, following error, late cycles */
    uint16_t id;     /* MOTION_EVENT_ID_* */
    uint16_t axis;   /* or 0xFFFF */
    uint16_t group;  /* or 0xFFFF */
    uint16_t record; /* or 0xFFFF */
    uint8_t state;   /* MOTION_AXIS_STATE_* or MOTION_FAULT_* */
    uint8_t error;   /* 1 if value is an error number */
    uint8_t sub;
    uint8_t reserved0;
    uint16_t code;   /* parameter number, EMCY code or drive fault number */
    uint16_t reserved1;
} MotionEventRecord;

/* One CAN bus in MotionMachineDescription (24 bytes). */
typedef struct MotionBusDescription {
    uint8_t name[MOTION_NAME_LEN];
    uint32_t bitrate; /* bit/s */
    uint8_t kind;     /* MOTION_BUS_KIND_* */
    uint8_t reserved0[3];
} MotionBusDescription;

/* One record of a drive's own record table, as configured (32 bytes). */
typedef struct MotionDriveRecord {
    int64_t position;     /* µunits (a distance from the last target when relative) */
    int64_t velocity;     /* µunits/s */
    int64_t acceleration; /* µunits/s² */
    uint8_t number;       /* 1..the device's table size */
    uint8_t relative;     /* 1: position is relative */
    uint8_t next;         /* the record chained after this one, or 0 */
    uint8_t reserved0[5];
} MotionDriveRecord;

/* One axis in MotionMachineDescription (2216 bytes): what the state does not carry. */
typedef struct MotionAxisDescription {
    int64_t position_min;    /* µunits */
    int64_t position_max;    /* µunits */
    int64_t velocity;        /* limit, µunits/s */
    int64_t acceleration;    /* limit, µunits/s² */
    int64_t jerk;            /* limit, µunits/s³, or 0 (none) */
    int64_t following_error; /* limit, µunits */
    uint64_t increments_per_unit_num; /* the scale: num/den increments per unit, lowest terms */
    uint64_t increments_per_unit_den;
    uint16_t force_permille; /* force limit, per mille of nominal, or 0 (none) */
    uint8_t device;          /* MOTION_DEVICE_* */
    uint8_t profile;         /* MOTION_PROFILE_* */
    uint8_t fpc;             /* 1: the FHPP parameter channel is mapped */
    uint8_t link;            /* MOTION_LINK_* */
    uint8_t bus;             /* index into buses, 0xFF on Modbus */
    uint8_t node;            /* CANopen node-ID, 0 on Modbus */
    uint8_t simulated;       /* 1: simulated inside the coordinator */
    uint8_t record_count;    /* valid entries of records */
    uint8_t reserved0[6];
    uint8_t name[MOTION_NAME_LEN];
    uint8_t unit[MOTION_UNIT_LEN];
    uint8_t modbus[MOTION_ADDRESS_LEN]; /* host:port the coordinator dials, or empty */
    MotionDriveRecord records[MOTION_MAX_DRIVE_RECORDS];
} MotionAxisDescription;

/* One record of a group's table (256 bytes). */
typedef struct MotionGroupRecord {
    int64_t targets[MOTION_MAX_GROUP_AXES]; /* per member, µunits, as target_kinds says */
    uint32_t delay_ms;         /* start delay */
    int32_t force_permille;    /* force records */
    uint16_t number;           /* 0..255 */
    int16_t step_next;         /* where the step condition leads, or -1: the chain ends */
    int16_t alternative_next;  /* where the alternative leads, or -1 */
    uint8_t mode;              /* MOTION_RECORD_MODE_* */
    uint8_t velocity_percent;
    uint8_t acceleration_percent;
    uint8_t jerk_percent;
    uint8_t mc_in_chain;       /* 1: MC shown when the move arrives inside a chain */
    uint8_t reserved0[5];
    uint8_t target_kinds[MOTION_MAX_GROUP_AXES]; /* MOTION_TARGET_KIND_* per member */
    uint8_t step[MOTION_CONDITION_LEN];          /* the condition in words, or empty */
    uint8_t alternative[MOTION_CONDITION_LEN];   /* the alternative in words, or empty */
} MotionGroupRecord;

/* One group in MotionMachineDescription. */
typedef struct MotionGroupDescription {
    uint8_t name[MOTION_NAME_LEN];
    uint8_t axes[MOTION_MAX_GROUP_AXES]; /* indices into axes */
    uint8_t axis_count;
    uint8_t shape;        /* MOTION_SHAPE_* */
    uint16_t record_count; /* valid entries of records */
    uint8_t reserved0[4];
    MotionGroupRecord records[MOTION_MAX_GROUP_RECORDS];
} MotionGroupDescription;

/* What the machine is, once at start on PREFIX/description (history 1). */
typedef struct MotionMachineDescription {
    uint32_t version;     /* MOTION_LAYOUT_VERSION */
    uint32_t layout_hash; /* MOTION_LAYOUT_HASH */
    uint32_t cycle_ns;
    uint16_t axis_count;  /* valid entries in axes (the state's axes, same order) */
    uint16_t group_count; /* valid entries in groups */
    uint8_t bus_count;    /* valid entries in buses */
    uint8_t reserved0[7];
    MotionBusDescription buses[MOTION_MAX_BUSES];
    MotionAxisDescription axes[MOTION_MAX_AXES];
    MotionGroupDescription groups[MOTION_MAX_GROUPS];
} MotionMachineDescription;

/* ---- layout checks (the same numbers as the Rust compiler's) ------------------------------ */

MOTION_STATIC_ASSERT(sizeof(MotionAxisState) == 128, "MotionAxisState size");
MOTION_STATIC_ASSERT(MOTION_ALIGNOF(MotionAxisState) == 8, "MotionAxisState alignment");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, position) == 0, "MotionAxisState.position offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, setpoint) == 8, "MotionAxisState.setpoint offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, velocity) == 16, "MotionAxisState.velocity offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, position_inc) == 24, "MotionAxisState.position_inc offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, setpoint_inc) == 32, "MotionAxisState.setpoint_inc offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, fault_value) == 40, "MotionAxisState.fault_value offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, fault_limit) == 48, "MotionAxisState.fault_limit offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, force_permille) == 56, "MotionAxisState.force_permille offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, status_bits) == 60, "MotionAxisState.status_bits offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, flags) == 62, "MotionAxisState.flags offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, state) == 64, "MotionAxisState.state offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, mode) == 65, "MotionAxisState.mode offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, fault) == 66, "MotionAxisState.fault offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, activity) == 67, "MotionAxisState.activity offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, fault_code) == 68, "MotionAxisState.fault_code offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, active_record) == 70, "MotionAxisState.active_record offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, name) == 72, "MotionAxisState.name offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, unit) == 88, "MotionAxisState.unit offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisState, reserved1) == 96, "MotionAxisState.reserved1 offset");

MOTION_STATIC_ASSERT(sizeof(MotionGroupState) == 48, "MotionGroupState size");
MOTION_STATIC_ASSERT(MOTION_ALIGNOF(MotionGroupState) == 2, "MotionGroupState alignment");
MOTION_STATIC_ASSERT(offsetof(MotionGroupState, active_record) == 0, "MotionGroupState.active_record offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupState, record) == 2, "MotionGroupState.record offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupState, reached) == 4, "MotionGroupState.reached offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupState, override_percent) == 6, "MotionGroupState.override_percent offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupState, chain_state) == 8, "MotionGroupState.chain_state offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupState, rc1) == 9, "MotionGroupState.rc1 offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupState, rcc) == 10, "MotionGroupState.rcc offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupState, motion) == 11, "MotionGroupState.motion offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupState, axis_count) == 12, "MotionGroupState.axis_count offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupState, activity) == 13, "MotionGroupState.activity offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupState, reserved0) == 14, "MotionGroupState.reserved0 offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupState, axes) == 16, "MotionGroupState.axes offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupState, name) == 24, "MotionGroupState.name offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupState, reserved1) == 40, "MotionGroupState.reserved1 offset");

MOTION_STATIC_ASSERT(sizeof(MotionBusStats) == 48, "MotionBusStats size");
MOTION_STATIC_ASSERT(MOTION_ALIGNOF(MotionBusStats) == 8, "MotionBusStats alignment");
MOTION_STATIC_ASSERT(offsetof(MotionBusStats, frames_sent) == 0, "MotionBusStats.frames_sent offset");
MOTION_STATIC_ASSERT(offsetof(MotionBusStats, frames_received) == 8, "MotionBusStats.frames_received offset");
MOTION_STATIC_ASSERT(offsetof(MotionBusStats, tx_refused) == 16, "MotionBusStats.tx_refused offset");
MOTION_STATIC_ASSERT(offsetof(MotionBusStats, rx_dropped) == 24, "MotionBusStats.rx_dropped offset");
MOTION_STATIC_ASSERT(offsetof(MotionBusStats, skipped_cycles) == 32, "MotionBusStats.skipped_cycles offset");
MOTION_STATIC_ASSERT(offsetof(MotionBusStats, step_ns) == 40, "MotionBusStats.step_ns offset");
MOTION_STATIC_ASSERT(offsetof(MotionBusStats, wake_late_us) == 44, "MotionBusStats.wake_late_us offset");

MOTION_STATIC_ASSERT(sizeof(MotionMachineState) == 17248, "MotionMachineState size");
MOTION_STATIC_ASSERT(MOTION_ALIGNOF(MotionMachineState) == 8, "MotionMachineState alignment");
MOTION_STATIC_ASSERT(offsetof(MotionMachineState, version) == 0, "MotionMachineState.version offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineState, layout_hash) == 4, "MotionMachineState.layout_hash offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineState, cycle) == 8, "MotionMachineState.cycle offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineState, sync_time_ns) == 16, "MotionMachineState.sync_time_ns offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineState, publish_time_ns) == 24, "MotionMachineState.publish_time_ns offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineState, cycle_ns) == 32, "MotionMachineState.cycle_ns offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineState, axis_count) == 36, "MotionMachineState.axis_count offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineState, group_count) == 38, "MotionMachineState.group_count offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineState, inputs) == 40, "MotionMachineState.inputs offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineState, virtual_time) == 44, "MotionMachineState.virtual_time offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineState, reserved0) == 45, "MotionMachineState.reserved0 offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineState, bus) == 48, "MotionMachineState.bus offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineState, axes) == 96, "MotionMachineState.axes offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineState, groups) == 16480, "MotionMachineState.groups offset");

MOTION_STATIC_ASSERT(sizeof(MotionCommandRequest) == 96, "MotionCommandRequest size");
MOTION_STATIC_ASSERT(MOTION_ALIGNOF(MotionCommandRequest) == 8, "MotionCommandRequest alignment");
MOTION_STATIC_ASSERT(offsetof(MotionCommandRequest, tag) == 0, "MotionCommandRequest.tag offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandRequest, kind) == 8, "MotionCommandRequest.kind offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandRequest, target) == 10, "MotionCommandRequest.target offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandRequest, percent) == 11, "MotionCommandRequest.percent offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandRequest, axis) == 12, "MotionCommandRequest.axis offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandRequest, group) == 14, "MotionCommandRequest.group offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandRequest, record) == 16, "MotionCommandRequest.record offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandRequest, sub) == 18, "MotionCommandRequest.sub offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandRequest, buffer) == 19, "MotionCommandRequest.buffer offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandRequest, pnu) == 20, "MotionCommandRequest.pnu offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandRequest, reserved1) == 22, "MotionCommandRequest.reserved1 offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandRequest, value) == 24, "MotionCommandRequest.value offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandRequest, positions) == 32, "MotionCommandRequest.positions offset");

MOTION_STATIC_ASSERT(sizeof(MotionCommandReply) == 96, "MotionCommandReply size");
MOTION_STATIC_ASSERT(MOTION_ALIGNOF(MotionCommandReply) == 8, "MotionCommandReply alignment");
MOTION_STATIC_ASSERT(offsetof(MotionCommandReply, tag) == 0, "MotionCommandReply.tag offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandReply, cycle) == 8, "MotionCommandReply.cycle offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandReply, value) == 16, "MotionCommandReply.value offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandReply, min) == 24, "MotionCommandReply.min offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandReply, max) == 32, "MotionCommandReply.max offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandReply, status) == 40, "MotionCommandReply.status offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandReply, reserved0) == 42, "MotionCommandReply.reserved0 offset");
MOTION_STATIC_ASSERT(offsetof(MotionCommandReply, reason) == 48, "MotionCommandReply.reason offset");

MOTION_STATIC_ASSERT(sizeof(MotionEventRecord) == 40, "MotionEventRecord size");
MOTION_STATIC_ASSERT(MOTION_ALIGNOF(MotionEventRecord) == 8, "MotionEventRecord alignment");
MOTION_STATIC_ASSERT(offsetof(MotionEventRecord, seq) == 0, "MotionEventRecord.seq offset");
MOTION_STATIC_ASSERT(offsetof(MotionEventRecord, cycle) == 8, "MotionEventRecord.cycle offset");
MOTION_STATIC_ASSERT(offsetof(MotionEventRecord, value) == 16, "MotionEventRecord.value offset");
MOTION_STATIC_ASSERT(offsetof(MotionEventRecord, id) == 24, "MotionEventRecord.id offset");
MOTION_STATIC_ASSERT(offsetof(MotionEventRecord, axis) == 26, "MotionEventRecord.axis offset");
MOTION_STATIC_ASSERT(offsetof(MotionEventRecord, group) == 28, "MotionEventRecord.group offset");
MOTION_STATIC_ASSERT(offsetof(MotionEventRecord, record) == 30, "MotionEventRecord.record offset");
MOTION_STATIC_ASSERT(offsetof(MotionEventRecord, state) == 32, "MotionEventRecord.state offset");
MOTION_STATIC_ASSERT(offsetof(MotionEventRecord, error) == 33, "MotionEventRecord.error offset");
MOTION_STATIC_ASSERT(offsetof(MotionEventRecord, sub) == 34, "MotionEventRecord.sub offset");
MOTION_STATIC_ASSERT(offsetof(MotionEventRecord, reserved0) == 35, "MotionEventRecord.reserved0 offset");
MOTION_STATIC_ASSERT(offsetof(MotionEventRecord, code) == 36, "MotionEventRecord.code offset");
MOTION_STATIC_ASSERT(offsetof(MotionEventRecord, reserved1) == 38, "MotionEventRecord.reserved1 offset");

MOTION_STATIC_ASSERT(sizeof(MotionBusDescription) == 24, "MotionBusDescription size");
MOTION_STATIC_ASSERT(MOTION_ALIGNOF(MotionBusDescription) == 4, "MotionBusDescription alignment");
MOTION_STATIC_ASSERT(offsetof(MotionBusDescription, name) == 0, "MotionBusDescription.name offset");
MOTION_STATIC_ASSERT(offsetof(MotionBusDescription, bitrate) == 16, "MotionBusDescription.bitrate offset");
MOTION_STATIC_ASSERT(offsetof(MotionBusDescription, kind) == 20, "MotionBusDescription.kind offset");
MOTION_STATIC_ASSERT(offsetof(MotionBusDescription, reserved0) == 21, "MotionBusDescription.reserved0 offset");

MOTION_STATIC_ASSERT(sizeof(MotionDriveRecord) == 32, "MotionDriveRecord size");
MOTION_STATIC_ASSERT(MOTION_ALIGNOF(MotionDriveRecord) == 8, "MotionDriveRecord alignment");
MOTION_STATIC_ASSERT(offsetof(MotionDriveRecord, position) == 0, "MotionDriveRecord.position offset");
MOTION_STATIC_ASSERT(offsetof(MotionDriveRecord, velocity) == 8, "MotionDriveRecord.velocity offset");
MOTION_STATIC_ASSERT(offsetof(MotionDriveRecord, acceleration) == 16, "MotionDriveRecord.acceleration offset");
MOTION_STATIC_ASSERT(offsetof(MotionDriveRecord, number) == 24, "MotionDriveRecord.number offset");
MOTION_STATIC_ASSERT(offsetof(MotionDriveRecord, relative) == 25, "MotionDriveRecord.relative offset");
MOTION_STATIC_ASSERT(offsetof(MotionDriveRecord, next) == 26, "MotionDriveRecord.next offset");
MOTION_STATIC_ASSERT(offsetof(MotionDriveRecord, reserved0) == 27, "MotionDriveRecord.reserved0 offset");

MOTION_STATIC_ASSERT(sizeof(MotionAxisDescription) == 2216, "MotionAxisDescription size");
MOTION_STATIC_ASSERT(MOTION_ALIGNOF(MotionAxisDescription) == 8, "MotionAxisDescription alignment");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, position_min) == 0, "MotionAxisDescription.position_min offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, position_max) == 8, "MotionAxisDescription.position_max offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, velocity) == 16, "MotionAxisDescription.velocity offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, acceleration) == 24, "MotionAxisDescription.acceleration offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, jerk) == 32, "MotionAxisDescription.jerk offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, following_error) == 40, "MotionAxisDescription.following_error offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, increments_per_unit_num) == 48, "MotionAxisDescription.increments_per_unit_num offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, increments_per_unit_den) == 56, "MotionAxisDescription.increments_per_unit_den offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, force_permille) == 64, "MotionAxisDescription.force_permille offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, device) == 66, "MotionAxisDescription.device offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, profile) == 67, "MotionAxisDescription.profile offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, fpc) == 68, "MotionAxisDescription.fpc offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, link) == 69, "MotionAxisDescription.link offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, bus) == 70, "MotionAxisDescription.bus offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, node) == 71, "MotionAxisDescription.node offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, simulated) == 72, "MotionAxisDescription.simulated offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, record_count) == 73, "MotionAxisDescription.record_count offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, reserved0) == 74, "MotionAxisDescription.reserved0 offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, name) == 80, "MotionAxisDescription.name offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, unit) == 96, "MotionAxisDescription.unit offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, modbus) == 104, "MotionAxisDescription.modbus offset");
MOTION_STATIC_ASSERT(offsetof(MotionAxisDescription, records) == 168, "MotionAxisDescription.records offset");

MOTION_STATIC_ASSERT(sizeof(MotionGroupRecord) == 256, "MotionGroupRecord size");
MOTION_STATIC_ASSERT(MOTION_ALIGNOF(MotionGroupRecord) == 8, "MotionGroupRecord alignment");
MOTION_STATIC_ASSERT(offsetof(MotionGroupRecord, targets) == 0, "MotionGroupRecord.targets offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupRecord, delay_ms) == 64, "MotionGroupRecord.delay_ms offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupRecord, force_permille) == 68, "MotionGroupRecord.force_permille offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupRecord, number) == 72, "MotionGroupRecord.number offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupRecord, step_next) == 74, "MotionGroupRecord.step_next offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupRecord, alternative_next) == 76, "MotionGroupRecord.alternative_next offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupRecord, mode) == 78, "MotionGroupRecord.mode offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupRecord, velocity_percent) == 79, "MotionGroupRecord.velocity_percent offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupRecord, acceleration_percent) == 80, "MotionGroupRecord.acceleration_percent offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupRecord, jerk_percent) == 81, "MotionGroupRecord.jerk_percent offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupRecord, mc_in_chain) == 82, "MotionGroupRecord.mc_in_chain offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupRecord, reserved0) == 83, "MotionGroupRecord.reserved0 offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupRecord, target_kinds) == 88, "MotionGroupRecord.target_kinds offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupRecord, step) == 96, "MotionGroupRecord.step offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupRecord, alternative) == 176, "MotionGroupRecord.alternative offset");

MOTION_STATIC_ASSERT(sizeof(MotionGroupDescription) == 65568, "MotionGroupDescription size");
MOTION_STATIC_ASSERT(MOTION_ALIGNOF(MotionGroupDescription) == 8, "MotionGroupDescription alignment");
MOTION_STATIC_ASSERT(offsetof(MotionGroupDescription, name) == 0, "MotionGroupDescription.name offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupDescription, axes) == 16, "MotionGroupDescription.axes offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupDescription, axis_count) == 24, "MotionGroupDescription.axis_count offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupDescription, shape) == 25, "MotionGroupDescription.shape offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupDescription, record_count) == 26, "MotionGroupDescription.record_count offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupDescription, reserved0) == 28, "MotionGroupDescription.reserved0 offset");
MOTION_STATIC_ASSERT(offsetof(MotionGroupDescription, records) == 32, "MotionGroupDescription.records offset");

MOTION_STATIC_ASSERT(sizeof(MotionMachineDescription) == 1332952, "MotionMachineDescription size");
MOTION_STATIC_ASSERT(MOTION_ALIGNOF(MotionMachineDescription) == 8, "MotionMachineDescription alignment");
MOTION_STATIC_ASSERT(offsetof(MotionMachineDescription, version) == 0, "MotionMachineDescription.version offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineDescription, layout_hash) == 4, "MotionMachineDescription.layout_hash offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineDescription, cycle_ns) == 8, "MotionMachineDescription.cycle_ns offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineDescription, axis_count) == 12, "MotionMachineDescription.axis_count offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineDescription, group_count) == 14, "MotionMachineDescription.group_count offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineDescription, bus_count) == 16, "MotionMachineDescription.bus_count offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineDescription, reserved0) == 17, "MotionMachineDescription.reserved0 offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineDescription, buses) == 24, "MotionMachineDescription.buses offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineDescription, axes) == 216, "MotionMachineDescription.axes offset");
MOTION_STATIC_ASSERT(offsetof(MotionMachineDescription, groups) == 283864, "MotionMachineDescription.groups offset");

#ifdef __cplusplus
}
#endif

#endif /* MOTION_SHM_H */
