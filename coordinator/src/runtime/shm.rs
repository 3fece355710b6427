//! The coordinator's side of the shared-memory contract (`shm-api`): the machine state written
//! in place into a loaned sample after every cycle, client commands translated to the cycle's
//! commands and their answers back, the cycle's events as event records. The conversions are
//! integer (user units in millionths, `shm_api::contract::MICRO`), done by each axis's exact
//! [`Scale`] (rounded to nearest, ties away from zero).

use shm_api::contract::{
    self as wire, AxisState as WireAxis, CommandReply, CommandRequest, EventRecord,
    GroupState as WireGroup, MachineState, axis_flags, buffer_mode, command_kind, status, target,
};

use iceoryx2::prelude::{Node, ipc};
use shm_api::names::ServiceNames;
use shm_api::publisher::{
    CommandServer, EventPublisher, PendingCommand, PublisherSettings, StatePublisher,
    cleanup_dead_nodes_with, create_node,
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
use crate::runtime::plan::MachinePlan;
use crate::units::{MICROS_PER_UNIT, Scale};

// The scale's µunits are the contract's.
const _: () = assert!(MICROS_PER_UNIT == wire::MICRO);

/// What does not change during a run: names, units, scale factors, group members.
#[derive(Debug, Clone)]
pub struct StaticInfo {
    axes: Vec<AxisInfo>,
    groups: Vec<GroupInfo>,
    cycle_ns: u32,
    virtual_time: bool,
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
        }
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

/// The cycle thread's side: the state publisher. Created before the first SYNC; publishing
/// loans a sample, writes it in place and sends it — no copy, no notification, no allocation.
pub struct StateSide {
    // The node must outlive its ports.
    _node: Node<ipc::Service>,
    state: StatePublisher,
    info: StaticInfo,
    /// Counters published with the state; the runtime updates them.
    pub counters: Counters,
    /// Samples that could not be loaned or sent (counted, never waited for).
    pub failed: u64,
    /// States published, stored after each send: the relay thread reads it (an atomic store:
    /// the cycle thread makes no syscall to signal clients).
    pub published: std::sync::Arc<std::sync::atomic::AtomicU64>,
}

impl std::fmt::Debug for StateSide {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StateSide")
            .field("failed", &self.failed)
            .finish_non_exhaustive()
    }
}

impl StateSide {
    /// Creates `PREFIX/state` for `plan`.
    pub fn create(prefix: &str, info: StaticInfo) -> Result<StateSide, String> {
        let node = create_node().map_err(|e| e.to_string())?;
        let names = ServiceNames::new(prefix);
        let state = StatePublisher::create(&node, &names, &PublisherSettings::default())
            .map_err(|e| busy(prefix, &names.state, &e))?;
        Ok(StateSide {
            _node: node,
            state,
            info,
            counters: Counters::default(),
            failed: 0,
            published: std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0)),
        })
    }

    /// Publishes the state of `c` after its step.
    pub fn publish<const A: usize, const G: usize>(
        &mut self,
        c: &Cycle<'_, A, G>,
        sync_time_ns: u64,
    ) {
        let publish_ns = drivers::time::monotonic_now().as_nanos();
        match self.state.loan() {
            Ok(mut s) => {
                fill_state(
                    &mut s,
                    &self.info,
                    c,
                    sync_time_ns,
                    publish_ns,
                    &self.counters,
                );
                if s.send().is_err() {
                    self.failed += 1;
                } else {
                    self.published
                        .fetch_add(1, std::sync::atomic::Ordering::Release);
                }
            }
            Err(_) => self.failed += 1,
        }
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

/// The services' side: the command server and the event publisher.
pub struct ServiceSide {
    _node: Node<ipc::Service>,
    commands: CommandServer,
    events: EventPublisher,
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
    /// Creates `PREFIX/command`, `PREFIX/events` and `PREFIX/event-log`.
    pub fn create(prefix: &str, info: StaticInfo) -> Result<ServiceSide, String> {
        let node = create_node().map_err(|e| e.to_string())?;
        let names = ServiceNames::new(prefix);
        let settings = PublisherSettings::default();
        let commands = CommandServer::create(&node, &names, &settings)
            .map_err(|e| busy(prefix, &names.command, &e))?;
        let events = EventPublisher::create(&node, &names, &settings)
            .map_err(|e| format!("{}: {e}", names.events))?;
        Ok(ServiceSide {
            _node: node,
            commands,
            events,
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
pub fn spawn_command_thread(
    prefix: String,
    info: StaticInfo,
    mut port: crate::runtime::services::CommandPort,
    events: std::sync::mpsc::Receiver<Event>,
) -> std::io::Result<std::thread::JoinHandle<Result<(), String>>> {
    std::thread::Builder::new()
        .name("shm-commands".into())
        .spawn(move || {
            let mut side = ServiceSide::create(&prefix, info)?;
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
                    std::thread::sleep(std::time::Duration::from_micros(200));
                }
            }
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Config, EXAMPLE};
    use crate::runtime::plan::plan;

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
