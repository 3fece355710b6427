//! The coordinator's side of the shared-memory contract (`shm-api`): the machine state written
//! in place into a loaned sample after every cycle, client commands translated to the cycle's
//! commands and their answers back, the cycle's events as event records, and the machine's
//! description ([`describe`]), published once at start. The conversions are integer (user
//! units in millionths, `shm_api::contract::MICRO`), done by each axis's exact [`Scale`]
//! (rounded to nearest, ties away from zero).

use shm_api::contract::{
    self as wire, AxisState as WireAxis, CommandReply, CommandRequest, EventRecord,
    GroupState as WireGroup, MachineDescription, MachineState, axis_flags, buffer_mode,
    command_kind, status, target,
};

use hdrhistogram::Histogram;
use iceoryx2::prelude::{Node, ipc};
use shm_api::names::ServiceNames;
use shm_api::publisher::{
    CommandServer, DescriptionPublisher, EventPublisher, PendingCommand, PublisherSettings,
    StateNotifier, StatePublisher, cleanup_dead_nodes_with, create_node,
};
use shm_api::request::name_bytes;

use crate::admission::{AxisActivity, GroupActivity};
use crate::axis::AxisState;
use crate::command::{BufferMode, Command, Rejected, Reply, Target};
use crate::cycle::{AxisMode, Cycle};
use crate::event::Event;
use crate::fault::FaultReason;
use crate::profile::MoveState as PathState;
use crate::records::{ChainState, MAX_GROUP_AXES};
use crate::runtime::plan::{AxisPlan, MachinePlan};
use crate::units::{MICROS_PER_UNIT, Scale};

// The scale's µunits are the contract's.
const _: () = assert!(MICROS_PER_UNIT == wire::MICRO);

/// What does not change during a run: names, units, scale factors, group members, and the
/// machine's description the command thread publishes.
#[derive(Debug, Clone)]
pub struct StaticInfo {
    axes: Vec<AxisInfo>,
    groups: Vec<GroupInfo>,
    cycle_ns: u32,
    virtual_time: bool,
    description: Description,
}

/// The machine's description, shared by the clones of a [`StaticInfo`] (it is 1.3 MB).
#[derive(Clone)]
struct Description(std::sync::Arc<MachineDescription>);

impl std::fmt::Debug for Description {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Description")
            .field("axes", &self.0.axis_count)
            .field("groups", &self.0.group_count)
            .finish_non_exhaustive()
    }
}

#[derive(Debug, Clone, Copy)]
struct AxisInfo {
    name: [u8; wire::NAME_LEN],
    unit: [u8; wire::UNIT_LEN],
    scale: Scale,
    fhpp: bool,
    group: Option<u16>,
}

#[derive(Debug, Clone, Copy)]
struct GroupInfo {
    name: [u8; wire::NAME_LEN],
    axes: [u8; MAX_GROUP_AXES],
    count: u8,
}

impl StaticInfo {
    /// The fixed part of the state of `plan`.
    pub fn new(plan: &MachinePlan, virtual_time: bool) -> StaticInfo {
        let axes = plan
            .axes
            .iter()
            .enumerate()
            .map(|(i, a)| AxisInfo {
                name: name_bytes(&a.name),
                unit: name_bytes(&a.unit),
                scale: a.scale,
                fhpp: a.setup.profile == crate::axis::Profile::Fhpp,
                group: plan
                    .groups
                    .iter()
                    .position(|(_, g, _)| g.axes.contains(&(i as u16)))
                    .map(|g| g as u16),
            })
            .collect();
        let groups = plan
            .groups
            .iter()
            .map(|(name, g, _)| {
                let mut axes = [0u8; MAX_GROUP_AXES];
                for (k, &a) in g.axes.iter().enumerate() {
                    axes[k] = a as u8;
                }
                GroupInfo {
                    name: name_bytes(name),
                    axes,
                    count: g.axes.len() as u8,
                }
            })
            .collect();
        StaticInfo {
            axes,
            groups,
            cycle_ns: plan.cycle.cycle_ns,
            virtual_time,
            description: Description(std::sync::Arc::from(describe(plan))),
        }
    }

    /// The machine's description ([`describe`]).
    pub fn description(&self) -> &MachineDescription {
        &self.description.0
    }

    /// Increments (per second) → µunits (per second) of an axis ([`Scale::inc_to_micro`]);
    /// 0 for an axis that does not exist.
    pub fn to_micro(&self, axis: usize, inc: i64) -> i64 {
        self.axes.get(axis).map_or(0, |a| a.scale.inc_to_micro(inc))
    }

    /// µunits → increments of an axis ([`Scale::micro_to_inc`]); 0 for an axis that does not
    /// exist.
    pub fn to_inc(&self, axis: usize, micro: i64) -> i64 {
        self.axes
            .get(axis)
            .map_or(0, |a| a.scale.micro_to_inc(micro))
    }
}

/// Unsigned increments (per second^n) of a limit as µunits (per second^n), saturated.
fn limit_micro(inc: u64, scale: Scale) -> i64 {
    scale.inc_to_micro(i64::try_from(inc).unwrap_or(i64::MAX))
}

/// A NUL-padded text field holding `text`; a text too long for it ends in `…` rather than
/// stopping mid-word without a sign.
fn text_field<const N: usize>(text: &str) -> [u8; N] {
    if text.len() <= N {
        return name_bytes(text);
    }
    let mut cut = N.saturating_sub('…'.len_utf8());
    while !text.is_char_boundary(cut) {
        cut -= 1;
    }
    name_bytes(&format!("{}…", &text[..cut]))
}

/// A step condition in words and in the units of the axis it watches, as an operator reads
/// it: `position x in [150, 210] mm for 10 ms`, `200 ms after motion complete`, `input 0
/// rising`, `group lift reached record 1`; empty for the end of a chain. `members` are the
/// group's axes, in group order.
pub fn condition_text(
    condition: &crate::records::StepCondition,
    members: &[&AxisPlan],
    group_names: &[&str],
) -> String {
    use crate::records::{Edge, Quantity, StepCondition as C};
    match *condition {
        C::End => String::new(),
        C::Mc => "motion complete".into(),
        C::Immediately => "immediately".into(),
        C::Delay(ms) => format!("{ms} ms after motion complete"),
        C::Comparator {
            axis,
            quantity,
            window,
        } => {
            let a = members.get(usize::from(axis));
            let name = a.map_or("?", |a| a.name.as_str());
            let unit = a.map_or("", |a| a.unit.as_str());
            let units = |v: i64| shm_api::units::user(a.map_or(0, |a| a.scale.inc_to_micro(v)));
            // Forces are ‰ of nominal; the configuration and the operator speak %.
            let percent = |v: i64| shm_api::units::user(v.saturating_mul(wire::MICRO / 10));
            let (what, lo, hi, unit) = match quantity {
                Quantity::Position => (
                    "position",
                    units(window.min),
                    units(window.max),
                    unit.to_owned(),
                ),
                Quantity::Velocity => (
                    "velocity",
                    units(window.min),
                    units(window.max),
                    format!("{unit}/s"),
                ),
                Quantity::Force => (
                    "force",
                    percent(window.min),
                    percent(window.max),
                    "%".into(),
                ),
            };
            let mut text = format!("{what} {name} in [{lo}, {hi}] {unit}");
            let damping = window.damping.as_millis();
            if damping > 0 {
                text.push_str(&format!(" for {damping} ms"));
            }
            text
        }
        C::Time { min, max } => format!("time since entry in [{min}, {max}] ms"),
        C::Input { bit, edge } => format!(
            "input {bit} {}",
            match edge {
                Edge::Rising => "rising",
                Edge::Falling => "falling",
            }
        ),
        C::RecordReached { group, record } => format!(
            "group {} reached record {record}",
            group_names.get(usize::from(group)).copied().unwrap_or("?")
        ),
    }
}

/// The machine's description of `plan` ([`MachineDescription`]): per axis its drive, profile,
/// parameter channel, bus and node (or Modbus address), limits in µunits and its drive's record
/// table as configured; per group its members and record table, with the step conditions in
/// words ([`condition_text`]). Built once at start-up, on the heap (it is 1.3 MB).
pub fn describe(plan: &MachinePlan) -> Box<MachineDescription> {
    use crate::axis::{DeviceKind, Profile};
    use crate::records::{AxisTarget, RecordMode, StepCondition};
    // SAFETY: `MachineDescription` is integers and arrays of integers only (`repr(C)`, no
    // references, no enums), so all-zero bytes are a valid value; zeroed on the heap, it never
    // lies on the stack.
    let mut d = unsafe { Box::<MachineDescription>::new_zeroed().assume_init() };
    d.version = wire::LAYOUT_VERSION;
    d.layout_hash = wire::LAYOUT_HASH;
    d.cycle_ns = plan.cycle.cycle_ns;
    d.bus_count = plan.buses.len().min(wire::MAX_BUSES) as u8;
    for (w, b) in d.buses.iter_mut().zip(&plan.buses) {
        w.name = name_bytes(&b.name);
        w.bitrate = b.bitrate;
        w.kind = match b.kind {
            crate::config::BusKind::Vbus => wire::bus_kind::VBUS,
            // (EtherCAT buses are not among the CAN buses described here.)
            crate::config::BusKind::Socketcan | crate::config::BusKind::Ethercat => {
                wire::bus_kind::SOCKETCAN
            }
            crate::config::BusKind::Simulated | crate::config::BusKind::Virtual => {
                wire::bus_kind::SIMULATED
            }
        };
    }
    d.axis_count = plan.axes.len().min(wire::MAX_AXES) as u16;
    for (w, a) in d.axes.iter_mut().zip(&plan.axes) {
        let setup = &a.setup;
        let micro = |inc: i64| a.scale.inc_to_micro(inc);
        let micro_u = |inc: u64| limit_micro(inc, a.scale);
        w.position_min = micro(setup.position_min);
        w.position_max = micro(setup.position_max);
        w.velocity = micro_u(setup.limits.velocity);
        w.acceleration = micro_u(setup.limits.acceleration);
        w.jerk = a.jerk_limit.map_or(0, micro_u);
        w.following_error = micro(setup.following_error);
        (w.increments_per_unit_num, w.increments_per_unit_den) = a.scale.fraction();
        w.force_permille = a.force_limit_permille.unwrap_or(0);
        w.device = match setup.kind {
            DeviceKind::MtrDci => wire::device::MTR_DCI,
            DeviceKind::Emca => wire::device::EMCA,
            DeviceKind::CmmoSt => wire::device::CMMO_ST,
            DeviceKind::Tlc5xx => wire::device::TLC5XX,
            DeviceKind::Cia402 => wire::device::CIA402,
        };
        w.profile = match setup.profile {
            Profile::Fhpp => wire::profile::FHPP,
            Profile::Cia402 => wire::profile::CIA402,
        };
        w.fpc = u8::from(setup.fpc);
        (w.link, w.bus, w.node) = match setup.transport {
            crate::cycle::Transport::Can { bus, node } => (wire::link::CAN, bus, node),
            crate::cycle::Transport::Modbus { .. } => (wire::link::MODBUS, 0xFF, 0),
            crate::cycle::Transport::Ethercat { .. } => (
                wire::link::ETHERCAT,
                0xFF,
                a.ethercat.map_or(0, |(_, p)| p.min(255) as u8),
            ),
        };
        w.simulated = u8::from(a.simulated);
        w.name = name_bytes(&a.name);
        w.unit = name_bytes(&a.unit);
        // The Modbus address, or an EtherCAT axis's interface.
        let ec_interface = a
            .ethercat
            .and_then(|(s, _)| plan.segments.get(s))
            .map(|s| s.interface.as_str());
        w.modbus = text_field(a.modbus.as_deref().or(ec_interface).unwrap_or(""));
        w.record_count = a.records.len().min(wire::MAX_DRIVE_RECORDS) as u8;
        for (r, rp) in w.records.iter_mut().zip(&a.records) {
            r.number = rp.number;
            r.position = micro(rp.position);
            r.relative = u8::from(rp.relative);
            r.velocity = micro_u(rp.velocity);
            r.acceleration = micro_u(rp.acceleration);
            r.next = rp.next.unwrap_or(0);
        }
    }
    let group_names: Vec<&str> = plan.groups.iter().map(|(n, _, _)| n.as_str()).collect();
    d.group_count = plan.groups.len().min(wire::MAX_GROUPS) as u16;
    for (w, (name, setup, table)) in d.groups.iter_mut().zip(&plan.groups) {
        let members: Vec<&AxisPlan> = setup
            .axes
            .iter()
            .filter_map(|&i| plan.axes.get(usize::from(i)))
            .collect();
        w.name = name_bytes(name);
        w.axis_count = setup.axes.len().min(MAX_GROUP_AXES) as u8;
        for (k, &m) in setup.axes.iter().enumerate().take(MAX_GROUP_AXES) {
            w.axes[k] = m.min(255) as u8;
        }
        w.shape = match setup.shape {
            crate::profile::Shape::SCurve => wire::shape::S_CURVE,
            crate::profile::Shape::Trapezoid => wire::shape::TRAPEZOID,
        };
        let mut count = 0u16;
        for ((number, r), out) in table.iter().zip(w.records.iter_mut()) {
            count += 1;
            out.number = number;
            for (k, t) in r.targets.iter().enumerate() {
                let micro = |v: i64| members.get(k).map_or(0, |a| a.scale.inc_to_micro(v));
                (out.target_kinds[k], out.targets[k]) = match *t {
                    AxisTarget::Keep => (wire::target_kind::KEEP, 0),
                    AxisTarget::Absolute(v) => (wire::target_kind::ABSOLUTE, micro(v)),
                    AxisTarget::Relative(v) => (wire::target_kind::RELATIVE, micro(v)),
                };
            }
            out.mode = match r.mode {
                RecordMode::Position => wire::record_mode::POSITION,
                RecordMode::Velocity => wire::record_mode::VELOCITY,
                RecordMode::Force => wire::record_mode::FORCE,
            };
            out.velocity_percent = r.velocity_percent;
            out.acceleration_percent = r.acceleration_percent;
            out.jerk_percent = r.jerk_percent;
            out.force_permille = r.force_permille;
            out.delay_ms = r.delay_ms;
            out.mc_in_chain = u8::from(r.mc_in_chain);
            out.step_next = if r.step.condition == StepCondition::End {
                -1
            } else {
                record(Some(r.step.next))
            };
            out.step = text_field(&condition_text(&r.step.condition, &members, &group_names));
            out.alternative_next = record(r.alternative.map(|a| a.next));
            out.alternative = text_field(
                &r.alternative
                    .map(|a| condition_text(&a.condition, &members, &group_names))
                    .unwrap_or_default(),
            );
        }
        w.record_count = count;
    }
    d
}

/// Counters the runtime adds to the state.
#[derive(Debug, Clone, Copy, Default)]
pub struct Counters {
    /// Frames sent.
    pub frames_sent: u64,
    /// Frames received.
    pub frames_received: u64,
    /// Frames the bus refused.
    pub tx_refused: u64,
    /// Frames dropped on receiving.
    pub rx_dropped: u64,
    /// Cycles skipped.
    pub skipped_cycles: u64,
    /// The last step's compute time, ns.
    pub step_ns: u32,
    /// The last wake-up's lateness, µs.
    pub wake_late_us: u32,
}

fn axis_state(s: AxisState) -> u8 {
    use wire::axis_state as w;
    match s {
        AxisState::Offline => w::OFFLINE,
        AxisState::Disabled => w::DISABLED,
        AxisState::Enabling => w::ENABLING,
        AxisState::Ready => w::READY,
        AxisState::Homing => w::HOMING,
        AxisState::Moving => w::MOVING,
        AxisState::Stopping => w::STOPPING,
        AxisState::Fault => w::FAULT,
    }
}

fn axis_activity(a: AxisActivity) -> u8 {
    use wire::axis_activity as w;
    match a {
        AxisActivity::Offline => w::OFFLINE,
        AxisActivity::Disabled => w::DISABLED,
        AxisActivity::Standstill => w::STANDSTILL,
        AxisActivity::Homing => w::HOMING,
        AxisActivity::Discrete => w::MOVING,
        AxisActivity::Continuous => w::JOGGING,
        AxisActivity::Synchronized => w::IN_GROUP_MOVE,
        AxisActivity::Stopping => w::STOPPING,
        AxisActivity::QuickStopped => w::QUICK_STOPPED,
        AxisActivity::ErrorStop => w::FAULTED,
    }
}

fn group_activity(a: GroupActivity) -> u8 {
    use wire::group_activity as w;
    match a {
        GroupActivity::Disabled => w::DISABLED,
        GroupActivity::Standby => w::STANDBY,
        GroupActivity::Moving => w::MOVING,
        GroupActivity::Chain => w::CHAIN,
        GroupActivity::Held => w::HELD,
        GroupActivity::Stopping => w::STOPPING,
        GroupActivity::ErrorStop => w::FAULTED,
    }
}

fn axis_mode(m: AxisMode) -> u8 {
    use wire::axis_mode as w;
    match m {
        AxisMode::Off => w::OFF,
        AxisMode::On => w::ON,
        AxisMode::Homing => w::HOMING,
        AxisMode::Jog { .. } => w::JOG,
        AxisMode::QuickStopped => w::QUICK_STOPPED,
        AxisMode::Acknowledging { .. } => w::ACKNOWLEDGING,
    }
}

/// A fault as (kind, code, value, limit).
fn fault(f: FaultReason) -> (u8, u16, i64, i64) {
    use wire::fault as w;
    match f {
        FaultReason::None => (w::NONE, 0, 0, 0),
        FaultReason::HeartbeatLost => (w::HEARTBEAT_LOST, 0, 0, 0),
        FaultReason::GuardingLost => (w::GUARDING_LOST, 0, 0, 0),
        FaultReason::Emcy(c) => (w::EMCY, c, 0, 0),
        FaultReason::FollowingError { error, limit } => (w::FOLLOWING_ERROR, 0, error, limit),
        FaultReason::DriveFault(c) => (w::DRIVE_FAULT, c, 0, 0),
        FaultReason::ModbusTimeout => (w::MODBUS_TIMEOUT, 0, 0, 0),
        FaultReason::LateTpdo(n) => (w::LATE_TPDO, 0, i64::from(n), 0),
        FaultReason::BootFailed => (w::BOOT_FAILED, 0, 0, 0),
        FaultReason::DriveReset => (w::DRIVE_RESET, 0, 0, 0),
        FaultReason::EthercatLost => (w::ETHERCAT_LOST, 0, 0, 0),
        FaultReason::EthercatState(s) => (w::ETHERCAT_STATE, 0, i64::from(s), 0),
    }
}

fn chain_state(s: ChainState) -> u8 {
    use wire::chain_state as w;
    match s {
        ChainState::Idle => w::IDLE,
        ChainState::Delay => w::DELAY,
        ChainState::Moving => w::MOVING,
        ChainState::Waiting => w::WAITING,
        ChainState::Complete => w::COMPLETE,
        ChainState::Aborted => w::ABORTED,
    }
}

fn motion_state(s: Option<PathState>) -> u8 {
    use wire::motion_state as w;
    match s {
        None => w::NONE,
        Some(PathState::Moving) => w::MOVING,
        Some(PathState::Holding) => w::HOLDING,
        Some(PathState::QuickStopping) => w::QUICK_STOPPING,
        Some(PathState::Stopped) => w::STOPPED,
        Some(PathState::Done) => w::DONE,
    }
}

fn record(r: Option<u16>) -> i16 {
    r.map_or(-1, |r| r as i16)
}

/// Writes the state of `c` into `s`: every header field and the valid axis and group entries
/// (the sample is expected zeroed, as `StatePublisher::loan` gives it). Allocation-free.
pub fn fill_state<const A: usize, const G: usize>(
    s: &mut MachineState,
    info: &StaticInfo,
    c: &Cycle<'_, A, G>,
    sync_time_ns: u64,
    publish_time_ns: u64,
    counters: &Counters,
) {
    let axis_count = c.axis_count().min(wire::MAX_AXES);
    let group_count = c.group_count().min(wire::MAX_GROUPS);
    s.version = wire::LAYOUT_VERSION;
    s.layout_hash = wire::LAYOUT_HASH;
    // The step that produced this state is the one before `c.cycle()`.
    s.cycle = c.cycle().saturating_sub(1);
    s.sync_time_ns = sync_time_ns;
    s.publish_time_ns = publish_time_ns;
    s.cycle_ns = info.cycle_ns;
    s.axis_count = axis_count as u16;
    s.group_count = group_count as u16;
    s.inputs = c.inputs();
    s.virtual_time = u8::from(info.virtual_time);
    s.reserved0 = [0; 3];
    s.bus = wire::BusStats {
        frames_sent: counters.frames_sent,
        frames_received: counters.frames_received,
        tx_refused: counters.tx_refused,
        rx_dropped: counters.rx_dropped,
        skipped_cycles: counters.skipped_cycles,
        step_ns: counters.step_ns,
        wake_late_us: counters.wake_late_us,
    };
    // Each group's running record, once (not once per member axis).
    let mut active = [None::<u16>; wire::MAX_GROUPS];
    for (g, a) in active.iter_mut().enumerate().take(group_count) {
        *a = c.group_status(g as u16).and_then(|st| st.chain.active);
    }
    // Only the valid entries are written: a loaned sample comes zeroed, and clients read the
    // first `axis_count` / `group_count` entries.
    for (i, w) in s.axes.iter_mut().enumerate().take(axis_count) {
        let (Some(st), Some(ai)) = (c.axis_status(i as u16), info.axes.get(i)) else {
            *w = empty_axis();
            continue;
        };
        let fb = st.feedback;
        let (kind, code, value, limit) = fault(st.fault);
        let mut flags = 0u16;
        let mut set = |on: bool, bit: u16| {
            if on {
                flags |= bit;
            }
        };
        set(st.online, axis_flags::ONLINE);
        set(st.enabled, axis_flags::ENABLED);
        set(fb.homed, axis_flags::HOMED);
        set(fb.motion_complete, axis_flags::MOTION_COMPLETE);
        set(fb.warning, axis_flags::WARNING);
        set(st.moving, axis_flags::FOLLOWING);
        set(ai.fhpp, axis_flags::FHPP);
        let active = ai
            .group
            .and_then(|g| active.get(usize::from(g)).copied().flatten());
        *w = WireAxis {
            position: info.to_micro(i, fb.position),
            setpoint: info.to_micro(i, st.setpoint),
            velocity: info.to_micro(i, fb.velocity),
            position_inc: fb.position,
            setpoint_inc: st.setpoint,
            fault_value: value,
            fault_limit: limit,
            force_permille: fb.force,
            status_bits: fb.status,
            flags,
            state: axis_state(fb.state),
            mode: axis_mode(st.mode),
            fault: kind,
            activity: axis_activity(st.activity),
            fault_code: if code != 0 { code } else { fb.fault_code },
            active_record: record(active),
            name: ai.name,
            unit: ai.unit,
            reserved1: [0; 32],
        };
    }
    for (g, w) in s.groups.iter_mut().enumerate().take(group_count) {
        let (Some(st), Some(gi)) = (c.group_status(g as u16), info.groups.get(g)) else {
            *w = empty_group();
            continue;
        };
        *w = WireGroup {
            active_record: record(st.chain.active),
            record: record(st.chain.record),
            reached: record(st.chain.reached),
            override_percent: st.override_percent,
            chain_state: chain_state(st.chain.state),
            rc1: u8::from(st.chain.rc1),
            rcc: u8::from(st.chain.rcc),
            motion: motion_state(st.motion),
            axis_count: gi.count,
            activity: group_activity(st.activity),
            reserved0: [0; 2],
            axes: gi.axes,
            name: gi.name,
            reserved1: [0; 8],
        };
    }
}

fn empty_axis() -> WireAxis {
    WireAxis {
        position: 0,
        setpoint: 0,
        velocity: 0,
        position_inc: 0,
        setpoint_inc: 0,
        fault_value: 0,
        fault_limit: 0,
        force_permille: 0,
        status_bits: 0,
        flags: 0,
        state: 0,
        mode: 0,
        fault: 0,
        activity: 0,
        fault_code: 0,
        active_record: -1,
        name: [0; wire::NAME_LEN],
        unit: [0; wire::UNIT_LEN],
        reserved1: [0; 32],
    }
}

fn empty_group() -> WireGroup {
    WireGroup {
        active_record: -1,
        record: -1,
        reached: -1,
        override_percent: 0,
        chain_state: 0,
        rc1: 0,
        rcc: 0,
        motion: 0,
        axis_count: 0,
        activity: 0,
        reserved0: [0; 2],
        axes: [0; MAX_GROUP_AXES],
        name: [0; wire::NAME_LEN],
        reserved1: [0; 8],
    }
}

/// A reply with only a status.
fn reply(tag: u64, status: u16) -> CommandReply {
    CommandReply {
        tag,
        cycle: 0,
        value: 0,
        min: 0,
        max: 0,
        status,
        reserved0: [0; 6],
        reason: [0; 48],
    }
}

/// Translates a client's request into the cycle's command (positions from µunits to
/// increments); a request that cannot be decoded gets its reply at once.
pub fn to_command(info: &StaticInfo, r: &CommandRequest) -> Result<Command, CommandReply> {
    let bad = || reply(r.tag, status::BAD_REQUEST);
    let tgt = match r.target {
        target::AXIS => Target::Axis(r.axis),
        target::GROUP => Target::Group(r.group),
        target::ALL => Target::All,
        _ => return Err(bad()),
    };
    let buffer = match r.buffer {
        buffer_mode::ABORTING => BufferMode::Aborting,
        buffer_mode::BUFFERED => BufferMode::Buffered,
        _ => return Err(bad()),
    };
    let group_positions = || {
        let mut p = [0i64; MAX_GROUP_AXES];
        if let Some(g) = info.groups.get(usize::from(r.group)) {
            for (k, slot) in p.iter_mut().enumerate().take(usize::from(g.count)) {
                *slot = info.to_inc(usize::from(g.axes[k]), r.positions[k]);
            }
        }
        p
    };
    Ok(match r.kind {
        command_kind::ENABLE => Command::Enable(tgt),
        command_kind::DISABLE => Command::Disable(tgt),
        command_kind::ACKNOWLEDGE => Command::Acknowledge(tgt),
        command_kind::HOME => Command::Home(tgt),
        command_kind::HOLD => Command::Hold(tgt),
        command_kind::RESUME => Command::Resume(tgt),
        command_kind::STOP => Command::Stop(tgt),
        command_kind::QUICK_STOP => Command::QuickStop(tgt),
        command_kind::JOG => Command::Jog {
            axis: r.axis,
            permille: r.value.clamp(i64::from(i16::MIN), i64::from(i16::MAX)) as i16,
        },
        command_kind::MOVE_AXIS => Command::MoveAxis {
            axis: r.axis,
            position: info.to_inc(usize::from(r.axis), r.positions[0]),
            velocity_percent: r.percent,
            buffer,
        },
        command_kind::MOVE_GROUP => Command::MoveGroup {
            group: r.group,
            positions: group_positions(),
            velocity_percent: r.percent,
            buffer,
        },
        command_kind::START_CHAIN => Command::StartChain {
            group: r.group,
            record: r.record,
        },
        command_kind::SET_OVERRIDE => Command::SetOverride {
            target: tgt,
            percent: r.value.clamp(0, i64::from(u16::MAX)) as u16,
        },
        command_kind::READ_PARAMETER => Command::ReadParameter {
            axis: r.axis,
            pnu: r.pnu,
            sub: r.sub,
        },
        command_kind::WRITE_PARAMETER => Command::WriteParameter {
            axis: r.axis,
            pnu: r.pnu,
            sub: r.sub,
            value: r.value as u32,
        },
        command_kind::SET_INPUT => Command::SetInput {
            bit: r.record.min(255) as u8,
            value: r.value != 0,
        },
        _ => return Err(bad()),
    })
}

/// The cycle's answer as the contract's reply.
pub fn to_reply(tag: u64, r: Reply) -> CommandReply {
    let mut out = reply(tag, status::LATCHED);
    match r {
        Reply::Latched { cycle } => out.cycle = cycle,
        Reply::Rejected(why) => {
            let (st, value, min, max) = match why {
                Rejected::UnknownAxis(a) => (status::UNKNOWN_AXIS, i64::from(a), 0, 0),
                Rejected::UnknownGroup(g) => (status::UNKNOWN_GROUP, i64::from(g), 0, 0),
                Rejected::UnknownRecord(r) => (status::UNKNOWN_RECORD, i64::from(r), 0, 0),
                Rejected::OutOfRange {
                    value, min, max, ..
                } => (status::OUT_OF_RANGE, value, min, max),
                Rejected::WrongState(why) => {
                    out.reason = name_bytes(why);
                    (status::WRONG_STATE, 0, 0, 0)
                }
                Rejected::Busy => (status::BUSY, 0, 0, 0),
                Rejected::Faulted => (status::FAULTED, 0, 0, 0),
                Rejected::Plan => (status::PLAN, 0, 0, 0),
            };
            out.status = st;
            out.value = value;
            out.min = min;
            out.max = max;
        }
    }
    out
}

/// A rejected reply for a request the coordinator could not take (its queue full).
pub fn overloaded(tag: u64) -> CommandReply {
    reply(tag, status::OVERLOADED)
}

/// The cycle's event as the contract's record (`seq` set by the caller).
pub fn to_record(e: &Event) -> EventRecord {
    use wire::event_id as id;
    let mut r = EventRecord {
        seq: 0,
        cycle: 0,
        value: 0,
        id: 0,
        axis: u16::MAX,
        group: u16::MAX,
        record: u16::MAX,
        state: 0,
        error: 0,
        sub: 0,
        reserved0: 0,
        code: 0,
        reserved1: 0,
    };
    match *e {
        Event::Overrun {
            cycle,
            skipped,
            late_us,
        } => {
            (r.cycle, r.id, r.value, r.code) = (
                cycle,
                id::OVERRUN as u16,
                i64::try_from(late_us).unwrap_or(i64::MAX),
                skipped.min(u64::from(u16::MAX)) as u16,
            );
        }
        Event::AxisState { cycle, axis, state } => {
            (r.cycle, r.id, r.axis, r.state) =
                (cycle, id::STATE_CHANGED as u16, axis, axis_state(state));
        }
        Event::Fault {
            cycle,
            axis,
            reason,
        } => {
            let (kind, code, value, _) = fault(reason);
            (r.cycle, r.id, r.axis, r.state, r.code, r.value) =
                (cycle, id::FAULT as u16, axis, kind, code, value);
        }
        Event::Acknowledged { cycle, axis } => {
            (r.cycle, r.id, r.axis) = (cycle, id::ACKNOWLEDGED as u16, axis);
        }
        Event::RecordReached {
            cycle,
            group,
            record,
        } => (r.cycle, r.id, r.group, r.record) = (cycle, id::RECORD_REACHED as u16, group, record),
        Event::ChainComplete {
            cycle,
            group,
            record,
        } => (r.cycle, r.id, r.group, r.record) = (cycle, id::CHAIN_COMPLETE as u16, group, record),
        Event::ChainAborted {
            cycle,
            group,
            record,
        } => (r.cycle, r.id, r.group, r.record) = (cycle, id::CHAIN_ABORTED as u16, group, record),
        Event::LateModbus {
            cycle,
            axis,
            cycles,
        } => {
            (r.cycle, r.id, r.axis, r.value) =
                (cycle, id::STATE_CHANGED as u16, axis, i64::from(cycles));
        }
        Event::Parameter {
            cycle,
            axis,
            pnu,
            sub,
            result,
        } => {
            (r.cycle, r.id, r.axis, r.code, r.sub) = (cycle, id::PARAMETER as u16, axis, pnu, sub);
            match result {
                Ok(v) => r.value = i64::from(v),
                Err(n) => {
                    r.value = i64::from(n);
                    r.error = 1;
                }
            }
        }
    }
    r
}

/// The cycle thread's side: the state publisher and the state notifier. Created before the
/// first SYNC; publishing loans a sample, writes it in place, sends it and then notifies
/// `STATE_PUBLISHED` on `PREFIX/events` for event-driven clients — no copy, no allocation, no
/// lock; a failed notify is counted, never retried or waited for.
pub struct StateSide {
    // The node must outlive its ports.
    _node: Node<ipc::Service>,
    state: StatePublisher,
    notifier: StateNotifier,
    info: StaticInfo,
    /// Counters published with the state; the runtime updates them.
    pub counters: Counters,
    /// Samples that could not be loaned or sent (counted, never waited for).
    pub failed: u64,
    /// How long each notify took, and how many failed.
    pub notify: NotifyFigures,
}

impl std::fmt::Debug for StateSide {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StateSide")
            .field("failed", &self.failed)
            .finish_non_exhaustive()
    }
}

impl StateSide {
    /// Creates `PREFIX/state` for `plan` and joins (or creates) `PREFIX/events`.
    pub fn create(prefix: &str, info: StaticInfo) -> Result<StateSide, String> {
        let node = create_node().map_err(|e| e.to_string())?;
        let names = ServiceNames::new(prefix);
        let settings = PublisherSettings::default();
        let state = StatePublisher::create(&node, &names, &settings)
            .map_err(|e| busy(prefix, &names.state, &e))?;
        let notifier = StateNotifier::create(&node, &names, &settings)
            .map_err(|e| busy(prefix, &names.events, &e))?;
        Ok(StateSide {
            _node: node,
            state,
            notifier,
            info,
            counters: Counters::default(),
            failed: 0,
            notify: NotifyFigures::new(),
        })
    }

    /// Publishes the state of `c` after its step, then wakes the event-driven clients.
    pub fn publish<const A: usize, const G: usize>(
        &mut self,
        c: &Cycle<'_, A, G>,
        sync_time_ns: u64,
    ) {
        match self.state.loan() {
            Ok(mut s) => {
                fill_state(&mut s, &self.info, c, sync_time_ns, 0, &self.counters);
                // Stamped as it goes out, after the sample is written: the time a client
                // measures from is the publication's, as a bare publisher's is.
                s.publish_time_ns = drivers::time::monotonic_now().as_nanos();
                if s.send().is_err() {
                    self.failed += 1;
                    return;
                }
            }
            Err(_) => {
                self.failed += 1;
                return;
            }
        }
        let t0 = drivers::time::monotonic_now().as_nanos();
        let ok = self.notifier.notify().is_ok();
        let t1 = drivers::time::monotonic_now().as_nanos();
        self.notify.record(t1.saturating_sub(t0), ok);
    }
}

/// How long the cycle thread's notify took: an HDR histogram (1 ns to 10 s, 3 significant
/// digits, as the cycle loop's wake-up lateness) allocated up front, so recording on the cycle
/// thread never allocates; read after the run.
#[derive(Debug, Clone)]
pub struct NotifyFigures {
    /// Notify durations, ns (0 recorded as 1: the histogram's lowest value).
    took: Histogram<u64>,
    /// Notifies made.
    pub calls: u64,
    /// Notifies iceoryx2 refused (counted; the cycle goes on).
    pub failed: u64,
}

impl Default for NotifyFigures {
    fn default() -> Self {
        NotifyFigures::new()
    }
}

impl NotifyFigures {
    /// Empty; allocates its histogram now, so recording never does.
    pub fn new() -> NotifyFigures {
        NotifyFigures {
            // Constant bounds, valid: 1 <= lowest, highest >= 2 * lowest, 3 digits <= 5.
            took: Histogram::new_with_bounds(1, 10_000_000_000, 3)
                .expect("valid constant histogram bounds"),
            calls: 0,
            failed: 0,
        }
    }

    /// Counts one notify of `ns`, `ok` or refused.
    pub fn record(&mut self, ns: u64, ok: bool) {
        // Beyond 10 s the value is dropped from the histogram (never resized: no allocation);
        // it is still counted.
        let _ = self.took.record(ns.max(1));
        self.calls += 1;
        self.failed += u64::from(!ok);
    }

    /// The `q` quantile (0..=1), ns: the highest value the histogram holds as equal to it
    /// (within 0.1 %); 0 before any notify.
    pub fn quantile_ns(&self, q: f64) -> u64 {
        self.took.value_at_quantile(q.clamp(0.0, 1.0))
    }

    /// The longest, ns (as [`NotifyFigures::quantile_ns`], within 0.1 %); 0 before any notify.
    pub fn max_ns(&self) -> u64 {
        self.took.max()
    }
}

impl std::fmt::Display for NotifyFigures {
    /// `state notify: N calls, F failed, median X µs, p99 Y µs, max Z µs` (the line `timing
    /// publish` reads from the coordinator's output).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let us = |ns: u64| ns as f64 / 1000.0;
        write!(
            f,
            "state notify: {} calls, {} failed, median {:.2} µs, p99 {:.2} µs, max {:.2} µs \
             (the cycle thread's wake-up of event-driven clients, after each state)",
            self.calls,
            self.failed,
            us(self.quantile_ns(0.5)),
            us(self.quantile_ns(0.99)),
            us(self.max_ns())
        )
    }
}

/// The error of a service that could not be created, with the likely cause named: another
/// coordinator already publishes under the prefix (iceoryx2 allows one publisher / server).
fn busy(prefix: &str, service: &str, e: &shm_api::ShmError) -> String {
    let text = e.to_string();
    if text.contains("ExceedsMax") {
        format!(
            "{service}: another coordinator already publishes under the prefix `{prefix}` \
             ({text}); choose another with --shm-prefix, or --no-shm"
        )
    } else {
        format!("{service}: {text}")
    }
}

/// The services' side: the command server, the event publisher and the description.
pub struct ServiceSide {
    _node: Node<ipc::Service>,
    commands: CommandServer,
    events: EventPublisher,
    description: DescriptionPublisher,
    info: StaticInfo,
    seq: u64,
    polls: u64,
}

impl std::fmt::Debug for ServiceSide {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ServiceSide")
            .field("events", &self.seq)
            .finish_non_exhaustive()
    }
}

impl ServiceSide {
    /// Creates `PREFIX/command`, `PREFIX/events`, `PREFIX/event-log` and
    /// `PREFIX/description`, and publishes the machine's description.
    pub fn create(prefix: &str, info: StaticInfo) -> Result<ServiceSide, String> {
        let node = create_node().map_err(|e| e.to_string())?;
        let names = ServiceNames::new(prefix);
        let settings = PublisherSettings::default();
        let commands = CommandServer::create(&node, &names, &settings)
            .map_err(|e| busy(prefix, &names.command, &e))?;
        let events = EventPublisher::create(&node, &names, &settings)
            .map_err(|e| format!("{}: {e}", names.events))?;
        let mut description = DescriptionPublisher::create(&node, &names, &settings)
            .map_err(|e| busy(prefix, &names.description, &e))?;
        description
            .publish(info.description())
            .map_err(|e| format!("{}: {e}", names.description))?;
        Ok(ServiceSide {
            _node: node,
            commands,
            events,
            description,
            info,
            seq: 0,
            polls: 0,
        })
    }

    /// Takes the next client request, translated; a request that cannot be decoded is answered
    /// here and `None` returned for it.
    pub fn receive(&mut self) -> Option<(PendingCommand, Result<Command, ()>)> {
        self.polls += 1;
        if self.polls.is_multiple_of(1000) {
            // A crashed client holds its port slots until someone cleans up.
            let _ = cleanup_dead_nodes_with(&self._node);
        }
        // A client that subscribed since gets the description now (a failure only delays it
        // to the next poll).
        let _ = self.description.update_connections();
        let p = self.commands.receive()?;
        let r = *p.request();
        match to_command(&self.info, &r) {
            Ok(c) => Some((p, Ok(c))),
            Err(reply) => {
                let _ = p.reply(&reply);
                None
            }
        }
    }

    /// Publishes one of the cycle's events.
    pub fn event(&mut self, e: &Event) {
        let mut r = to_record(e);
        self.seq += 1;
        r.seq = self.seq;
        let _ = self.events.publish(r);
    }

    /// Virtual time: answers every pending request at once through `apply`.
    pub fn serve(&mut self, mut apply: impl FnMut(&Command) -> Reply) {
        while let Some((p, c)) = self.receive() {
            let tag = p.request().tag;
            if let Ok(c) = c {
                let _ = p.reply(&to_reply(tag, apply(&c)));
            }
        }
    }
}

/// Real time: serves client commands on its own thread, the one short path into the cycle:
/// each request is translated and put straight into the cycle's request queue
/// ([`crate::runtime::services::CommandPort`]); the cycle looks it up in the admission table,
/// applies it and answers with the latching cycle; the answer goes back to the client matched
/// by tag. A request the queue cannot take is answered OVERLOADED at once. The thread also
/// publishes the events it is sent, and ends when `events` closes.
///
/// Idle, the thread looks every [`COMMAND_POLL`], and every [`COMMAND_WINDOW_POLL`] in the
/// [`COMMAND_WINDOW`] before the cycle's next deadline (`next_deadline`, ns of CLOCK_MONOTONIC,
/// stored by the cycle thread; 0 while unknown): a request that arrives up to about 10 µs
/// before a deadline is in the queue when that cycle starts, so a command waits at most about
/// one cycle for its cycle, not a cycle plus the poll period ([`next_look`]). The thread runs
/// at SCHED_FIFO `priority` (below the cycle's) where that is granted, with a timer slack of
/// 1 ns, so those looks are on time; they cost about 15 wake-ups a cycle.
pub fn spawn_command_thread(
    prefix: String,
    info: StaticInfo,
    mut port: crate::runtime::services::CommandPort,
    events: std::sync::mpsc::Receiver<Event>,
    next_deadline: std::sync::Arc<std::sync::atomic::AtomicU64>,
    priority: Option<i32>,
) -> std::io::Result<std::thread::JoinHandle<Result<(), String>>> {
    std::thread::Builder::new()
        .name("shm-commands".into())
        .spawn(move || {
            let mut side = ServiceSide::create(&prefix, info)?;
            // After the set-up (milliseconds of CPU in a debug build, which at SCHED_FIFO would
            // keep the drives' threads off a CPU). A refusal leaves it on the normal scheduler.
            let _ = crate::runtime::realtime_thread::enter_realtime(
                &crate::runtime::realtime_thread::RealtimeSettings {
                    priority,
                    lock_memory: false,
                    cpu: None,
                },
            );
            // Requests with the cycle, by the port's tag.
            let mut pending: Vec<(u64, PendingCommand)> = Vec::new();
            loop {
                let mut idle = true;
                while let Some((p, c)) = side.receive() {
                    idle = false;
                    let Ok(c) = c else { continue };
                    match port.submit(c) {
                        Ok(tag) => pending.push((tag, p)),
                        Err(_) => {
                            let tag = p.request().tag;
                            let _ = p.reply(&overloaded(tag));
                        }
                    }
                }
                while let Some(a) = port.answer() {
                    idle = false;
                    if let Some(i) = pending.iter().position(|(t, _)| *t == a.tag) {
                        let (_, p) = pending.swap_remove(i);
                        let tag = p.request().tag;
                        let _ = p.reply(&to_reply(tag, a.reply));
                    }
                }
                loop {
                    match events.try_recv() {
                        Ok(e) => {
                            side.event(&e);
                            idle = false;
                        }
                        Err(std::sync::mpsc::TryRecvError::Empty) => break,
                        Err(std::sync::mpsc::TryRecvError::Disconnected) => {
                            // The run is over: what the cycle will not answer any more is
                            // answered OVERLOADED rather than left to the client's timeout.
                            for (_, p) in pending.drain(..) {
                                let tag = p.request().tag;
                                let _ = p.reply(&overloaded(tag));
                            }
                            return Ok(());
                        }
                    }
                }
                if idle {
                    idle_wait(next_deadline.load(std::sync::atomic::Ordering::Relaxed));
                }
            }
        })
}

/// How often the idle command thread looks for requests.
pub const COMMAND_POLL: std::time::Duration = std::time::Duration::from_micros(200);

/// The window before the cycle's deadline in which the idle command thread looks every
/// [`COMMAND_WINDOW_POLL`] instead: a request that arrives there still makes that cycle.
pub const COMMAND_WINDOW: std::time::Duration = std::time::Duration::from_micros(150);

/// How often the idle command thread looks inside [`COMMAND_WINDOW`].
pub const COMMAND_WINDOW_POLL: std::time::Duration = std::time::Duration::from_micros(10);

/// When the idle command thread looks next (all ns of CLOCK_MONOTONIC; `next_deadline` 0 means
/// unknown): inside the window before the deadline every [`COMMAND_WINDOW_POLL`] (the last
/// look at the deadline itself), else one [`COMMAND_POLL`] from `now` but no later than the
/// window's start.
pub fn next_look(now: u64, next_deadline: u64) -> u64 {
    let poll = COMMAND_POLL.as_nanos() as u64;
    if next_deadline == 0 || now >= next_deadline {
        return now + poll;
    }
    let window = next_deadline.saturating_sub(COMMAND_WINDOW.as_nanos() as u64);
    if now >= window {
        (now + COMMAND_WINDOW_POLL.as_nanos() as u64).min(next_deadline)
    } else {
        (now + poll).min(window)
    }
}

fn idle_wait(next_deadline: u64) {
    let now = drivers::time::monotonic_now();
    let at = next_look(now.as_nanos(), next_deadline);
    crate::runtime::ticker::sleep_until(drivers::time::Instant::from_nanos(at));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Config, EXAMPLE};

    #[test]
    fn the_idle_command_thread_looks_often_just_before_the_cycle() {
        let us = 1_000u64;
        // Far from the deadline: the plain poll.
        assert_eq!(next_look(1_000 * us, 3_000 * us), 1_200 * us);
        // A poll would pass the window's start (150 µs before): the window's start instead.
        assert_eq!(next_look(2_800 * us, 3_000 * us), 2_850 * us);
        // Inside the window: every 10 µs, the last look at the deadline.
        assert_eq!(next_look(2_850 * us, 3_000 * us), 2_860 * us);
        assert_eq!(next_look(2_995 * us, 3_000 * us), 3_000 * us);
        // The deadline passed (the cycle has not stored the next one yet), or unknown.
        assert_eq!(next_look(3_001 * us, 3_000 * us), 3_201 * us);
        assert_eq!(next_look(5 * us, 0), 205 * us);
    }
    use crate::runtime::plan::plan;

    #[test]
    fn the_description_of_the_default_machine_says_what_the_state_does_not() {
        use shm_api::request::name_str;
        use wire::{bus_kind, device, link, profile, shape, target_kind as tk};
        let p = plan(&Config::parse(EXAMPLE).unwrap()).unwrap();
        let d = describe(&p);
        assert_eq!(
            (d.version, d.layout_hash, d.cycle_ns),
            (wire::LAYOUT_VERSION, wire::LAYOUT_HASH, 2_000_000)
        );
        assert_eq!((d.axis_count, d.group_count, d.bus_count), (4, 3, 2));
        assert_eq!(name_str(&d.buses[1].name), "can1");
        assert_eq!(
            (d.buses[1].kind, d.buses[1].bitrate),
            (bus_kind::SIMULATED, 1_000_000)
        );

        // x: the MTR-DCI with a jerk and a force limit.
        let x = &d.axes[0];
        assert_eq!((name_str(&x.name), name_str(&x.unit)), ("x", "mm"));
        assert_eq!(
            (x.device, x.profile, x.fpc),
            (device::MTR_DCI, profile::FHPP, 0)
        );
        assert_eq!(
            (
                x.position_min,
                x.position_max,
                x.velocity,
                x.acceleration,
                x.jerk
            ),
            (0, 400_000_000, 150_000_000, 1_000_000_000, 20_000_000_000)
        );
        assert_eq!(x.force_permille, 1000);
        // The exact scales: 400 and 1000 increments per mm, 100 per degree.
        assert_eq!(
            (x.increments_per_unit_num, x.increments_per_unit_den),
            (400, 1)
        );
        assert_eq!(
            (
                d.axes[1].increments_per_unit_num,
                d.axes[1].increments_per_unit_den
            ),
            (1000, 1)
        );
        assert_eq!(
            (
                d.axes[3].increments_per_unit_num,
                d.axes[3].increments_per_unit_den
            ),
            (100, 1)
        );
        assert_eq!((x.link, x.bus, x.node, x.simulated), (link::CAN, 0, 1, 1));
        // y: the EMCA with its parameter channel on can1, and its two drive records.
        let y = &d.axes[1];
        assert_eq!((y.device, y.fpc, y.bus, y.node), (device::EMCA, 1, 1, 2));
        assert_eq!((y.jerk, y.force_permille), (0, 0));
        assert_eq!(y.record_count, 2);
        let r = |i: usize| {
            let r = &y.records[i];
            (
                r.number,
                r.position,
                r.relative,
                r.velocity,
                r.acceleration,
                r.next,
            )
        };
        // Record 1 takes the axis's acceleration limit (400 mm/s²), record 2 its own.
        assert_eq!(r(0), (1, 10_000_000, 0, 60_000_000, 400_000_000, 2));
        assert_eq!(r(1), (2, 240_000_000, 0, 80_000_000, 300_000_000, 0));
        // z: the TLC5xx in CiA 402; gripper: the simulated CMMO-ST on Modbus.
        assert_eq!(
            (d.axes[2].device, d.axes[2].profile),
            (device::TLC5XX, profile::CIA402)
        );
        let g = &d.axes[3];
        assert_eq!(
            (g.device, g.link, g.bus, g.node, g.simulated),
            (device::CMMO_ST, link::MODBUS, 0xFF, 0, 1)
        );
        assert_eq!((g.position_min, name_str(&g.unit)), (-180_000_000, "deg"));
        assert_eq!(name_str(&g.modbus), "");

        // The gantry's table: targets in µunits, the conditions in words and units.
        let gantry = &d.groups[0];
        assert_eq!(name_str(&gantry.name), "gantry");
        assert_eq!((gantry.axis_count, &gantry.axes[..2]), (2, &[0u8, 1][..]));
        // y has no jerk limit, so the group's moves are trapezoids.
        assert_eq!(gantry.shape, shape::TRAPEZOID);
        assert_eq!(gantry.record_count, 4);
        let r10 = &gantry.records[0];
        assert_eq!(r10.number, 10);
        assert_eq!(&r10.targets[..2], &[200_000_000, 100_000_000]);
        assert_eq!(
            &r10.target_kinds[..3],
            &[tk::ABSOLUTE, tk::ABSOLUTE, tk::KEEP]
        );
        assert_eq!((r10.velocity_percent, r10.acceleration_percent), (80, 50));
        assert_eq!(
            (name_str(&r10.step), r10.step_next),
            ("position x in [150, 210] mm for 10 ms", 11)
        );
        assert_eq!((name_str(&r10.alternative), r10.alternative_next), ("", -1));
        let r11 = &gantry.records[1];
        assert_eq!(&r11.targets[..2], &[100_000_000, -40_000_000]);
        assert_eq!(&r11.target_kinds[..2], &[tk::RELATIVE, tk::RELATIVE]);
        assert_eq!((r11.delay_ms, r11.mc_in_chain), (50, 0));
        assert_eq!(
            (name_str(&r11.step), r11.step_next),
            ("motion complete", 12)
        );
        assert_eq!(
            (name_str(&r11.alternative), r11.alternative_next),
            ("input 0 rising", 13)
        );
        let r12 = &gantry.records[2];
        assert_eq!(&r12.target_kinds[..2], &[tk::KEEP, tk::ABSOLUTE]);
        assert_eq!(name_str(&r12.step), "group lift reached record 1");
        let r13 = &gantry.records[3];
        assert_eq!(
            (name_str(&r13.step), r13.step_next, r13.mc_in_chain),
            ("", -1, 1)
        );
        assert_eq!(
            name_str(&d.groups[1].records[0].step),
            "200 ms after motion complete"
        );
        assert_eq!(
            name_str(&d.groups[2].records[0].step),
            "position gripper in [80, 100] deg for 50 ms"
        );
        // The clones of the static part share the one description.
        let info = StaticInfo::new(&p, false);
        assert_eq!(*info.clone().description(), *d);
    }

    #[test]
    fn every_condition_reads_in_words_and_in_its_axis_units() {
        use crate::comparator::Window;
        use crate::records::{Edge, Quantity, StepCondition as C};
        let p = plan(&Config::parse(EXAMPLE).unwrap()).unwrap();
        let members = [&p.axes[0], &p.axes[1]];
        let groups = ["gantry", "lift"];
        let text = |c: C| condition_text(&c, &members, &groups);
        let window = |min, max, ms| Window::new(min, max, std::time::Duration::from_millis(ms));
        assert_eq!(text(C::End), "");
        assert_eq!(text(C::Immediately), "immediately");
        assert_eq!(text(C::Delay(200)), "200 ms after motion complete");
        // 400 increments per mm on x, 1000 on y.
        assert_eq!(
            text(C::Comparator {
                axis: 0,
                quantity: Quantity::Velocity,
                window: window(-2000, 2000, 0),
            }),
            "velocity x in [-5, 5] mm/s"
        );
        assert_eq!(
            text(C::Comparator {
                axis: 1,
                quantity: Quantity::Position,
                window: window(12_345, 12_500, 3),
            }),
            "position y in [12.345, 12.5] mm for 3 ms"
        );
        // Forces in ‰ read in % as configured.
        assert_eq!(
            text(C::Comparator {
                axis: 1,
                quantity: Quantity::Force,
                window: window(-105, 250, 20),
            }),
            "force y in [-10.5, 25] % for 20 ms"
        );
        assert_eq!(
            text(C::Time { min: 100, max: 200 }),
            "time since entry in [100, 200] ms"
        );
        assert_eq!(
            text(C::Input {
                bit: 3,
                edge: Edge::Falling
            }),
            "input 3 falling"
        );
        assert_eq!(
            text(C::RecordReached {
                group: 1,
                record: 7
            }),
            "group lift reached record 7"
        );
        // A text longer than its field ends in an ellipsis, on a character boundary.
        let long = "ä".repeat(60);
        let field: [u8; wire::CONDITION_LEN] = text_field(&long);
        let shown = shm_api::request::name_str(&field);
        assert!(
            shown.ends_with('…') && shown.len() <= wire::CONDITION_LEN,
            "{shown}"
        );
        assert_eq!(shown.chars().filter(|&c| c == 'ä').count(), 38);
    }

    #[test]
    fn notify_figures_read_their_quantiles_from_the_histogram() {
        let mut f = NotifyFigures::new();
        assert_eq!((f.quantile_ns(0.5), f.max_ns()), (0, 0));
        for ns in 1..=100u64 {
            f.record(ns * 1000, ns != 7);
        }
        f.record(1_000_000, true);
        assert_eq!((f.calls, f.failed), (101, 1));
        // 3 significant digits: 2048 sub-buckets, so a value in [1024·2^k, 2048·2^k) shares a
        // 2^k ns bucket and reads as that bucket's highest value.
        // Median, the 51st of 101: 51 µs in [32768, 65536), 32 ns buckets: 50976..=51007.
        assert_eq!(f.quantile_ns(0.5), 51_007);
        // p99, the 100th (ceil(99.99)): 100 µs in [65536, 131072), 64 ns: 99968..=100031.
        assert_eq!(f.quantile_ns(0.99), 100_031);
        // The last, 1 ms in [524288, 1048576), 512 ns: 999936..=1000447.
        assert_eq!(f.quantile_ns(1.0), 1_000_447);
        assert_eq!(f.max_ns(), 1_000_447);
        let line = f.to_string();
        assert!(
            line.starts_with(
                "state notify: 101 calls, 1 failed, median 51.01 µs, p99 100.03 µs, max 1000.45 µs"
            ),
            "{line}"
        );
        // A zero-length notify counts as 1 ns, the histogram's lowest value.
        let mut z = NotifyFigures::new();
        z.record(0, true);
        assert_eq!((z.calls, z.quantile_ns(0.5)), (1, 1));
    }

    #[test]
    fn user_units_convert_both_ways_in_integers() {
        let p = plan(&Config::parse(EXAMPLE).unwrap()).unwrap();
        let info = StaticInfo::new(&p, false);
        // x: 400 inc/mm; gripper: 100 inc/deg.
        assert_eq!(info.to_inc(0, 1_000_000), 400);
        assert_eq!(info.to_micro(0, 400), 1_000_000);
        assert_eq!(info.to_inc(0, 12_500_000), 5_000);
        assert_eq!(info.to_micro(3, -18_000), -180_000_000);
        for inc in [-160_001i64, -1, 0, 1, 7, 159_999] {
            assert_eq!(info.to_inc(0, info.to_micro(0, inc)), inc);
        }
    }

    #[test]
    fn requests_translate_and_bad_ones_are_answered_at_once() {
        let p = plan(&Config::parse(EXAMPLE).unwrap()).unwrap();
        let info = StaticInfo::new(&p, false);
        let mut r = CommandRequest::move_group(0, &[100_000_000, 50_000_000], 40);
        r.tag = 7;
        assert_eq!(
            to_command(&info, &r),
            Ok(Command::MoveGroup {
                group: 0,
                positions: [40_000, 50_000, 0, 0, 0, 0, 0, 0],
                velocity_percent: 40,
                buffer: BufferMode::Aborting,
            })
        );
        r.kind = 999;
        let reply = to_command(&info, &r).unwrap_err();
        assert_eq!((reply.tag, reply.status), (7, status::BAD_REQUEST));
        let out = to_reply(
            3,
            Reply::Rejected(Rejected::OutOfRange {
                axis: 0,
                value: 9,
                min: 0,
                max: 5,
            }),
        );
        assert_eq!(
            (out.status, out.value, out.min, out.max),
            (status::OUT_OF_RANGE, 9, 0, 5)
        );
        assert_eq!(to_reply(3, Reply::Latched { cycle: 42 }).cycle, 42);
    }
}
