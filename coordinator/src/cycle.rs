//! The cycle step: one pure function of the inputs of a cycle and the coordinator's state.
//!
//! Once per SYNC the runtime hands [`Cycle::step`] what arrived since the last one (CAN frames:
//! TPDOs, heartbeats, guarding replies, EMCYs; Modbus process images) and the time of this
//! cycle's SYNC. The step then, in this order:
//!
//! 1. decodes the frames into each axis's input image and supervision state;
//! 2. detects faults (heartbeat or guarding loss, EMCY, drive fault, following error, Modbus
//!    timeout, late TPDO) and applies each group's reaction in this same cycle;
//! 3. steps each group's record chain (comparators on this cycle's actual values) and motion
//!    (time-synchronised profiles, override, hold, quick stop);
//! 4. runs every axis's master-side state machine with its demand, producing its output image;
//! 5. writes the frames to send in the fixed order SYNC, every RPDO, then guarding polls.
//!
//! Commands ([`Cycle::command`]) are applied between steps and answered at once: accepted with
//! the cycle whose SYNC latches them, or rejected with a reason. A multi-axis command changes
//! every axis's demand inside one call, so all of them appear in the RPDOs of the same cycle.
//!
//! Same inputs, same outputs, bit for bit: no clock is read, nothing is allocated (capacities
//! are const generics: `A` axes, `G` groups), no lock is taken, nothing is logged, and the work
//! per step is bounded by the axis and group counts.

use drivers::can::Frame;
use drivers::canopen::emcy::EmcyMessage;
use drivers::canopen::guarding::{GuardingEvent, GuardingMaster};
use drivers::canopen::heartbeat::{HeartbeatConsumer, HeartbeatEvent};
use drivers::canopen::{FunctionCode, NodeId};
use drivers::fhpp::fpc;
use drivers::time::Instant;
use heapless::{Deque, Vec};

use crate::admission::{
    self, Admit, AxisActivity, AxisVerb, BufferMode, GroupActivity, GroupVerb, Refusal,
};
use crate::axis::{
    AxisError, AxisState, CyclicMode, Demand, DeviceKind, DriveAxis, Feedback, Image, PointMove,
    Profile, takes_one_set_point_per_move,
};
use crate::command::{AxisId, Command, GroupId, Rejected, Reply, Target};
use crate::event::Event;
use crate::fault::{FaultReason, OverrunReaction, Reaction};
use crate::profile::{AxisLimits, MoveState, PathMove, Shape, Target as PathTarget};
use crate::records::{
    AxisTarget, Chain, ChainAction, ChainInputs, ChainStatus, MAX_GROUP_AXES, RecordMode,
    RecordTable,
};

/// Events the cycle can hold before the services take them; more are counted and dropped.
pub const EVENT_CAPACITY: usize = 256;
/// Cycles a parameter-channel task may wait for its reply.
pub const FPC_TIMEOUT_CYCLES: u32 = 250;
/// CAN buses one cycle drives at most (each with its own SYNC, PDOs and supervision).
pub const MAX_BUSES: usize = 8;

/// A CAN frame and the bus it came from or goes to (an index into the machine's buses).
#[derive(Clone, Copy, Debug)]
pub struct BusFrame {
    /// The bus, 0-based, below [`CycleSetup::buses`].
    pub bus: u8,
    /// The frame.
    pub frame: Frame,
}

impl BusFrame {
    /// `frame` on `bus`.
    pub fn new(bus: u8, frame: Frame) -> BusFrame {
        BusFrame { bus, frame }
    }
}

/// How an axis is reached.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Transport {
    /// CANopen: TPDO1/RPDO1 of this node on one of the cycle's buses.
    Can {
        /// The bus, 0-based.
        bus: u8,
        /// Node-ID 1..=127.
        node: u8,
    },
    /// Modbus TCP: the process image in this slot of [`CycleInput::images`].
    Modbus {
        /// Slot index.
        slot: u8,
    },
    /// EtherCAT: the subdevice's process data (FHPP standard, 8 bytes each way) in this slot of
    /// [`CycleInput::images`].
    Ethercat {
        /// Slot index.
        slot: u8,
    },
}

impl Transport {
    /// The process-image slot of a Modbus or EtherCAT axis.
    pub fn image_slot(self) -> Option<u8> {
        match self {
            Transport::Modbus { slot } | Transport::Ethercat { slot } => Some(slot),
            Transport::Can { .. } => None,
        }
    }
}

/// How a drive is supervised.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Supervision {
    /// Not supervised (besides late process images).
    None,
    /// Heartbeat consumer with this consumer time, ms.
    Heartbeat {
        /// Consumer time, ms (typically 1.5 to 2 producer periods).
        consumer_ms: u16,
    },
    /// Node guarding by the coordinator: a poll every `guard_ms`, lost after `life_factor` polls.
    Guarding {
        /// Guard time 100Ch, ms.
        guard_ms: u16,
        /// Life time factor 100Dh.
        life_factor: u8,
    },
}

/// One axis, as the cycle needs it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AxisSetup {
    /// The drive.
    pub kind: DeviceKind,
    /// Its profile.
    pub profile: Profile,
    /// How it is reached.
    pub transport: Transport,
    /// Supervision.
    pub supervision: Supervision,
    /// Motion limits, increments.
    pub limits: AxisLimits,
    /// Lowest position, increments.
    pub position_min: i64,
    /// Highest position, increments.
    pub position_max: i64,
    /// Largest |setpoint - actual| while following a path, increments (0: not monitored).
    pub following_error: i64,
    /// A fault after this many cycles in a row without an input image (0: not monitored).
    pub late_cycles: u16,
    /// The FHPP parameter channel is mapped on PDO2 (Festo drives over CANopen).
    pub fpc: bool,
    /// How a CiA 402 drive is commanded cyclically (profile position for the others).
    pub mode: CyclicMode,
}

/// One group, as the cycle needs it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GroupSetup {
    /// Member axes, in group order.
    pub axes: Vec<AxisId, MAX_GROUP_AXES>,
    /// Profile shape of the group's moves.
    pub shape: Shape,
    /// What the group does when one of its axes faults.
    pub reaction: Reaction,
}

/// Whole-machine settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CycleSetup {
    /// Cycle period, ns.
    pub cycle_ns: u32,
    /// Send SYNC (producer) or follow one (consumer: no SYNC in the output).
    pub sync_producer: bool,
    /// CAN buses, 0..=[`MAX_BUSES`]; a producer sends SYNC on each, every cycle.
    pub buses: u8,
    /// What an overrun of the coordinator itself does ([`Cycle::overrun`]).
    pub overrun: OverrunReaction,
}

/// Why a machine could not be set up.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SetupError {
    /// More axes or groups than the cycle's capacity.
    #[error("more than {0} axes or groups")]
    Capacity(usize),
    /// An axis's drive/profile pair is not supported.
    #[error("axis {0}: {1}")]
    Axis(AxisId, AxisError),
    /// Two axes share a node-ID on one bus, a node-ID is outside 1..=127, or the bus does not
    /// exist.
    #[error("axis {0}: node-ID in use or invalid, or no such bus")]
    Node(AxisId),
    /// More buses than [`MAX_BUSES`].
    #[error("more than {MAX_BUSES} CAN buses")]
    Buses,
    /// A group names an axis that does not exist or is already in another group.
    #[error("group {0}: bad member")]
    Member(GroupId),
}

/// One process image handed to the cycle: a Modbus drive's answer or an EtherCAT subdevice's
/// inputs, exchanged off the cycle thread.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct ImageInput {
    /// The status bytes.
    pub image: Image,
    /// A new answer arrived since the last cycle.
    pub fresh: bool,
    /// How many cycles late that answer is (0: it answered the last cycle's output).
    pub late_cycles: u32,
    /// Modbus: the exchange timed out or the connection is down. EtherCAT: the subdevice did
    /// not answer (its part of the working counter is missing).
    pub lost: bool,
    /// EtherCAT: the subdevice answers but is not in Op; its AL state (1 Init, 2 PreOp,
    /// 4 SafeOp). 0: in Op, or not EtherCAT.
    pub not_op: u8,
    /// EtherCAT: the error code of an emergency (CoE EMCY) received since the last cycle;
    /// 0: none.
    pub emcy: u16,
}

/// What arrived for one cycle.
#[derive(Clone, Copy, Debug)]
pub struct CycleInput<'a> {
    /// The time of this cycle's SYNC.
    pub now: Instant,
    /// CAN frames received since the previous step, in arrival order per bus.
    pub frames: &'a [BusFrame],
    /// Process images (Modbus drives, EtherCAT subdevices), by slot.
    pub images: &'a [ImageInput],
}

/// Where the step writes what to send.
#[derive(Debug)]
pub struct CycleOutput<'a> {
    /// CAN frames in transmit order (every bus's SYNC first); the step fills `frames[..len]`.
    pub frames: &'a mut [BusFrame],
    /// Frames written.
    pub len: usize,
    /// Frames that did not fit `frames` (a configuration error: the budget check prevents it).
    pub overflow: u32,
    /// Process images to send (Modbus drives, EtherCAT subdevices), by slot.
    pub images: &'a mut [Image],
}

impl CycleOutput<'_> {
    fn push(&mut self, bus: u8, f: Frame) {
        match self.frames.get_mut(self.len) {
            Some(slot) => {
                *slot = BusFrame::new(bus, f);
                self.len += 1;
            }
            None => self.overflow += 1,
        }
    }
    /// The frames written.
    pub fn sent(&self) -> &[BusFrame] {
        &self.frames[..self.len.min(self.frames.len())]
    }
}

/// What the operator (or a fault) asked of one axis, published as the axis's mode.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum AxisMode {
    /// Power off.
    #[default]
    Off,
    /// Enabled and standing (or following the group's / own move).
    On,
    /// Homing running.
    Homing,
    /// Jogging (published only: a jog is a single-axis motion the coordinator plans towards
    /// the software limit, see [`Cycle::axis_status`]).
    Jog {
        /// Direction.
        positive: bool,
        /// Speed, inc/s.
        velocity: i64,
    },
    /// Stopped by a quick stop (command or fault reaction) until acknowledged / re-enabled.
    QuickStopped,
    /// Acknowledging a fault; then enabled again or off.
    Acknowledging {
        /// Enabled after the acknowledge (it was enabled before the fault).
        enable_after: bool,
    },
}

/// One CAN bus's supervision: its own node-IDs (the same ID may be used on two buses).
#[derive(Debug, Clone)]
struct BusRt<const A: usize> {
    heartbeat: HeartbeatConsumer<A, 32>,
    guarding: GuardingMaster<A, 32>,
    /// Node-ID → axis.
    by_node: NodeMap,
}

/// Node-ID → axis of one bus, a byte per node (the axis index + 1; 0: none): two cache lines
/// that the step asks for every cycle, where `Option<AxisId>` took eight. So a cycle has at
/// most [`NodeMap::MAX_AXES`] axes.
#[derive(Debug, Clone)]
struct NodeMap([u8; 128]);

impl NodeMap {
    /// The most axes a byte can name.
    const MAX_AXES: usize = u8::MAX as usize;

    fn get(&self, node: usize) -> Option<AxisId> {
        match self.0.get(node).copied() {
            None | Some(0) => None,
            Some(k) => Some(AxisId::from(k) - 1),
        }
    }

    /// Names axis `axis` at node `node`; `false` for node 0, a node past 127, one already
    /// named, or an axis a byte cannot name.
    fn insert(&mut self, node: u8, axis: usize) -> bool {
        match (self.0.get_mut(usize::from(node)), u8::try_from(axis + 1)) {
            (Some(slot @ 0), Ok(k)) if node != 0 => {
                *slot = k;
                true
            }
            _ => false,
        }
    }
}

impl<const A: usize> BusRt<A> {
    fn new() -> Self {
        BusRt {
            heartbeat: HeartbeatConsumer::new(),
            guarding: GuardingMaster::new(),
            by_node: NodeMap([0; 128]),
        }
    }
}

/// What the step reads of an axis every cycle. The sweep walks these from memory once per
/// cycle (the cycle thread slept a period in between), so what only commands, the parameter
/// channel's answers and the axis's own planning read is in [`AxisCold`].
///
/// Aligned to cache lines (it fills five, 320 bytes), so that no axis straddles one more.
#[derive(Clone, Debug)]
#[repr(align(64))]
struct AxisRt {
    /// `setup.transport`, `setup.late_cycles` and `setup.following_error`, read every cycle.
    transport: Transport,
    late_cycles: u16,
    following_error: i64,
    /// The drive's state machine; its feedback is the axis's (the step keeps no copy).
    drive: DriveAxis,
    mode: AxisMode,
    online: bool,
    input: Option<Image>,
    missed: u16,
    /// The setpoint the coordinator last commanded (the start of the next move).
    setpoint: i64,
    setpoint_velocity: i64,
    following: bool,
    fault: FaultReason,
    /// The drive's own fault already turned into `fault`, so it is raised once.
    drive_fault_seen: bool,
    group: Option<GroupId>,
    /// The axis's parameter channel in [`Cycle::fpcs`] (axes with `fpc`).
    fpc: Option<u16>,
    last_state: AxisState,
    out: Image,
}

/// An axis's parameter channel (FHPP FPC on TPDO2/RPDO2) and this cycle's reply bytes: read
/// every cycle, but only for the few axes that have one, so kept apart from [`AxisRt`].
#[derive(Clone, Debug)]
struct FpcRt {
    client: fpc::Client,
    input: Option<Image>,
}

/// What the step reads of an axis only when a command, a parameter reply or the axis's own
/// planning needs it (the hot part is [`AxisRt`], same index).
#[derive(Clone, Debug)]
struct AxisCold {
    setup: AxisSetup,
    /// Feed override of the axis's own moves and jogs, % (its group's override sets it too).
    override_percent: u16,
    /// The parameter channel's task in progress.
    fpc_task: Option<fpc::Param>,
}

/// What a single-axis motion is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum SoloKind {
    /// To a position at a share of the velocity limit.
    Move {
        /// Target, increments.
        position: i64,
        /// Share of the velocity limit, 1..=100 %.
        velocity_percent: u8,
    },
    /// Towards the software limit in the direction of the sign, at ‰ of the velocity limit,
    /// until released (it stops exactly at the limit at the latest).
    Jog {
        /// Signed share of the velocity limit, ‰.
        permille: i16,
    },
}

/// How a single-axis motion ends; a reader can hold it against PLCopen's Discrete motion,
/// MC_Halt and MC_Stop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum SoloEnd {
    /// At its target (resumed after a hold).
    Arrive,
    /// Held on its path by the operator; resumed by a resume.
    Held,
    /// Where its ramp stops, and the next motion (if any) starts there: a released jog, or a
    /// motion another one aborts (MC_Halt; a motion command may take over).
    Halt,
    /// Where its ramp stops: a stop (sticky; refused motion commands until standstill).
    Stop,
}

/// A single-axis motion the coordinator plans and streams.
#[derive(Clone, Debug)]
struct Solo {
    motion: PathMove<1>,
    kind: SoloKind,
    end: SoloEnd,
    /// The motion that takes over when this one has stopped (aborting) or arrived (buffered).
    next: Option<SoloKind>,
    /// The highest override under which the plan keeps the limits.
    max_override: u16,
}

/// The axes' single-axis motions, kept out of [`AxisRt`]: a planned path is most of an axis's
/// bytes and rarely runs, while the step sweeps every axis every cycle (from memory, after the
/// cycle thread slept). So the sweep reads one flag per axis and a motion's bytes only while it
/// runs; a cleared slot keeps its stale bytes and is never read.
#[derive(Clone, Debug)]
struct Solos<const A: usize> {
    /// Axis index → a motion runs (its slot holds it).
    running: [bool; A],
    slots: Vec<Option<Solo>, A>,
}

impl<const A: usize> Solos<A> {
    fn new() -> Self {
        Solos {
            running: [false; A],
            slots: Vec::new(),
        }
    }

    /// A slot for the next axis.
    fn push(&mut self) -> Result<(), ()> {
        self.slots.push(None).map_err(|_| ())
    }

    fn get(&self, i: usize) -> Option<&Solo> {
        if *self.running.get(i)? {
            self.slots.get(i)?.as_ref()
        } else {
            None
        }
    }

    fn get_mut(&mut self, i: usize) -> Option<&mut Solo> {
        if *self.running.get(i)? {
            self.slots.get_mut(i)?.as_mut()
        } else {
            None
        }
    }

    fn is_some(&self, i: usize) -> bool {
        self.running.get(i).copied().unwrap_or(false)
    }

    fn set(&mut self, i: usize, solo: Option<Solo>) {
        if let (Some(r), Some(slot)) = (self.running.get_mut(i), self.slots.get_mut(i)) {
            *r = solo.is_some();
            *slot = solo;
        }
    }

    /// Ends axis `i`'s motion without touching its bytes.
    fn clear(&mut self, i: usize) {
        if let Some(r) = self.running.get_mut(i) {
            *r = false;
        }
    }
}

/// A group move to start later (aborting: once the running one has stopped; buffered: once it
/// has arrived).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct GroupMove {
    targets: [AxisTarget; MAX_GROUP_AXES],
    velocity_percent: u8,
}

/// A group's operator halt: the stored part of its [`GroupActivity`] (the rest is its move, its
/// chain and its members).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum GroupHalt {
    /// Nothing asked.
    None,
    /// Held (MC_GroupInterrupt): the move stops on its path and nothing starts, not even the
    /// chain's next record, until resumed.
    Held,
    /// Stopping (MC_GroupStop): the move ramps down and is dropped; sticky.
    Stopping,
}

#[derive(Clone, Debug)]
#[repr(C)]
struct GroupRt<'t> {
    // In declared order: the move first (its lines aligned), the fields every cycle reads,
    // the chain (its comparators at its end), and the move to start next last, so that what
    // [`GroupRt::cycle_regions`] leaves out is whole lines.
    motion: Option<PathMove<MAX_GROUP_AXES>>,
    setup: GroupSetup,
    table: &'t RecordTable,
    /// The cycle a velocity or force record started in (its members run on `special`).
    special_since: Option<u64>,
    override_percent: u16,
    /// The highest override the running move can take without any member exceeding its
    /// configured limits (time scaling multiplies velocity, acceleration and jerk by the
    /// override's first, second and third power).
    max_override: u16,
    /// A record to start once the running move has stopped (a step on the fly).
    pending: Option<u16>,
    halt: GroupHalt,
    /// A move given while another ran (`next_move`), to start when that one has stopped
    /// (aborting) or arrived (buffered).
    next: Option<BufferMode>,
    chain: Chain,
    /// The move `next` starts; read only then, so the step does not ask for it every cycle.
    next_move: GroupMove,
}

impl GroupRt<'_> {
    /// The parts of the group the step reads, for asking for them ahead of it: all of it but
    /// what its move ([`PathMove::for_each_skipped`]) and its chain
    /// ([`Chain::for_each_skipped`]) leave out, and the move to start next. In `repr(C)`
    /// order the parts left out come in address order, as [`Gaps`] needs them.
    fn cycle_regions(&self, f: &mut impl FnMut(*const u8, usize)) {
        let mut gaps = Gaps::new((self as *const Self).cast(), f);
        PathMove::for_each_skipped(&self.motion, &mut |p, n| gaps.skip(p, n));
        self.chain.for_each_skipped(&mut |p, n| gaps.skip(p, n));
        // From the next move to the end of the group (`repr(C)`: it comes last).
        let next = core::mem::offset_of!(GroupRt<'static>, next_move);
        gaps.skip(
            (&self.next_move as *const GroupMove).cast(),
            core::mem::size_of::<Self>() - next,
        );
        gaps.finish(core::mem::size_of::<Self>());
    }
}

/// Hands `f` the parts of a region outside the ranges skipped in it, as they are skipped:
/// each range a first byte and a length inside the region, in address order, not overlapping.
struct Gaps<'f, F: FnMut(*const u8, usize)> {
    base: *const u8,
    /// Bytes from `base` handed out or skipped so far.
    at: usize,
    f: &'f mut F,
}

impl<'f, F: FnMut(*const u8, usize)> Gaps<'f, F> {
    fn new(base: *const u8, f: &'f mut F) -> Self {
        Gaps { base, at: 0, f }
    }

    fn skip(&mut self, p: *const u8, len: usize) {
        let start = (p as usize).wrapping_sub(self.base as usize);
        debug_assert!(start >= self.at, "skipped ranges out of order");
        if start > self.at {
            (self.f)(self.base.wrapping_add(self.at), start - self.at);
        }
        self.at = self.at.max(start + len);
    }

    /// The region is `len` bytes: hands out what follows the last range skipped.
    fn finish(self, len: usize) {
        if len > self.at {
            (self.f)(self.base.wrapping_add(self.at), len - self.at);
        }
    }
}

/// Published state of one axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct AxisStatus {
    /// The last feedback.
    pub feedback: Feedback,
    /// The setpoint commanded, increments.
    pub setpoint: i64,
    /// The setpoint's velocity, inc/s (0 at standstill).
    pub setpoint_velocity: i64,
    /// The coordinator's fault reason (None when clear).
    pub fault: FaultReason,
    /// The drive is booted and in the cycle.
    pub online: bool,
    /// The axis is enabled (or being enabled) by command.
    pub enabled: bool,
    /// What the axis is doing by command.
    pub mode: AxisMode,
    /// A move (its own or its group's) streams setpoints to the axis.
    pub moving: bool,
    /// What the axis is doing, as the admission table sees it.
    pub activity: AxisActivity,
}

/// Published state of one group.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct GroupStatus {
    /// The chain.
    pub chain: ChainStatus,
    /// The group's move, if one runs.
    pub motion: Option<MoveState>,
    /// Feed override, %.
    pub override_percent: u16,
    /// What the group is doing, as the admission table sees it.
    pub activity: GroupActivity,
}

/// The coordinator's cycle for up to `A` axes (at most 255) and `G` groups.
#[derive(Debug, Clone)]
pub struct Cycle<'t, const A: usize, const G: usize> {
    setup: CycleSetup,
    axes: Vec<AxisRt, A>,
    /// The axes' setups and rarely read state, by axis index.
    cold: Vec<AxisCold, A>,
    /// The axes' single-axis moves and jogs, by axis index.
    solos: Solos<A>,
    /// The parameter channels, in axis order ([`AxisRt::fpc`] indexes them).
    fpcs: Vec<FpcRt, A>,
    /// By axis index: the demand a velocity or force record of the axis's group gives it
    /// directly. Read only while that group's `special_since` is set, and cleared with it.
    specials: Vec<Option<Demand>, A>,
    groups: Vec<GroupRt<'t>, G>,
    buses: Vec<BusRt<A>, MAX_BUSES>,
    events: Deque<Event, EVENT_CAPACITY>,
    dropped_events: u64,
    cycle: u64,
    now: Instant,
    inputs: u32,
    previous_inputs: u32,
    /// Accepted stops and quick stops ([`Cycle::stops`]).
    stops: u32,
}

fn node(n: u8) -> Option<NodeId> {
    NodeId::new(n)
}

impl<'t, const A: usize, const G: usize> Cycle<'t, A, G> {
    /// A machine of `axes` and `groups` (each group with its record table), all offline.
    pub fn new(
        setup: CycleSetup,
        axes: &[AxisSetup],
        groups: &[(GroupSetup, &'t RecordTable)],
    ) -> Result<Self, SetupError> {
        let mut c = Cycle {
            setup,
            axes: Vec::new(),
            cold: Vec::new(),
            solos: Solos::new(),
            fpcs: Vec::new(),
            specials: Vec::new(),
            groups: Vec::new(),
            buses: Vec::new(),
            events: Deque::new(),
            dropped_events: 0,
            cycle: 0,
            now: Instant::ZERO,
            inputs: 0,
            previous_inputs: 0,
            stops: 0,
        };
        for _ in 0..setup.buses {
            c.buses.push(BusRt::new()).map_err(|_| SetupError::Buses)?;
        }
        if axes.len() > NodeMap::MAX_AXES {
            return Err(SetupError::Capacity(NodeMap::MAX_AXES.min(A)));
        }
        for (i, s) in axes.iter().enumerate() {
            let id = i as AxisId;
            if let Transport::Can { bus, node: n } = s.transport
                && !c
                    .buses
                    .get_mut(usize::from(bus))
                    .is_some_and(|b| b.by_node.insert(n, i))
            {
                return Err(SetupError::Node(id));
            }
            let drive = DriveAxis::in_mode(s.kind, s.profile, s.mode, setup.cycle_ns)
                .map_err(|e| SetupError::Axis(id, e))?;
            let client = crate::axis::fpc_codec(s.kind)
                .filter(|_| s.fpc)
                .map(|c| fpc::Client::new(c, FPC_TIMEOUT_CYCLES));
            let fpc = match client {
                Some(client) => {
                    let k = c.fpcs.len() as u16;
                    c.fpcs
                        .push(FpcRt {
                            client,
                            input: None,
                        })
                        .map_err(|_| SetupError::Capacity(A))?;
                    Some(k)
                }
                None => None,
            };
            c.specials.push(None).map_err(|_| SetupError::Capacity(A))?;
            c.axes
                .push(AxisRt {
                    transport: s.transport,
                    late_cycles: s.late_cycles,
                    following_error: s.following_error,
                    drive,
                    mode: AxisMode::Off,
                    online: false,
                    input: None,
                    missed: 0,
                    setpoint: 0,
                    setpoint_velocity: 0,
                    following: false,
                    fault: FaultReason::None,
                    drive_fault_seen: false,
                    group: None,
                    fpc,
                    last_state: AxisState::Offline,
                    out: Image::default(),
                })
                .map_err(|_| SetupError::Capacity(A))?;
            c.cold
                .push(AxisCold {
                    setup: *s,
                    override_percent: 100,
                    fpc_task: None,
                })
                .map_err(|_| SetupError::Capacity(A))?;
            c.solos.push().map_err(|_| SetupError::Capacity(A))?;
        }
        for (gi, (g, table)) in groups.iter().enumerate() {
            let gid = gi as GroupId;
            for &a in &g.axes {
                let ax = c
                    .axes
                    .get_mut(usize::from(a))
                    .ok_or(SetupError::Member(gid))?;
                if ax.group.is_some() {
                    return Err(SetupError::Member(gid));
                }
                ax.group = Some(gid);
            }
            c.groups
                .push(GroupRt {
                    setup: g.clone(),
                    table,
                    chain: Chain::new(),
                    motion: None,
                    halt: GroupHalt::None,
                    next: None,
                    next_move: GroupMove {
                        targets: [AxisTarget::Keep; MAX_GROUP_AXES],
                        velocity_percent: 0,
                    },
                    override_percent: 100,
                    max_override: 100,
                    pending: None,
                    special_since: None,
                })
                .map_err(|_| SetupError::Capacity(G))?;
        }
        Ok(c)
    }

    /// The number of the next step (the first is 0).
    pub fn cycle(&self) -> u64 {
        self.cycle
    }

    /// The axes.
    pub fn axis_count(&self) -> usize {
        self.axes.len()
    }

    /// The groups.
    pub fn group_count(&self) -> usize {
        self.groups.len()
    }

    /// The published state of an axis.
    pub fn axis_status(&self, axis: AxisId) -> Option<AxisStatus> {
        let a = self.axes.get(usize::from(axis))?;
        let mode = match (a.mode, self.solos.get(usize::from(axis)).map(|s| s.kind)) {
            (AxisMode::On, Some(SoloKind::Jog { permille })) => AxisMode::Jog {
                positive: permille > 0,
                velocity: jog_velocity(&self.cold[usize::from(axis)].setup.limits, permille),
            },
            (m, _) => m,
        };
        Some(AxisStatus {
            feedback: *a.drive.feedback(),
            setpoint: a.setpoint,
            setpoint_velocity: if a.following { a.setpoint_velocity } else { 0 },
            fault: a.fault,
            online: a.online,
            enabled: !matches!(a.mode, AxisMode::Off),
            mode,
            moving: a.following,
            activity: self.axis_activity(usize::from(axis)),
        })
    }

    /// The published state of a group.
    pub fn group_status(&self, group: GroupId) -> Option<GroupStatus> {
        let g = self.groups.get(usize::from(group))?;
        Some(GroupStatus {
            chain: g.chain.status(),
            motion: g.motion.as_ref().map(|m| m.state()),
            override_percent: g.override_percent,
            activity: self.group_activity(usize::from(group)),
        })
    }

    /// The lowest record number of a group's table.
    pub fn first_record(&self, group: GroupId) -> Option<u16> {
        self.groups
            .get(usize::from(group))?
            .table
            .iter()
            .next()
            .map(|(n, _)| n)
    }

    /// The machine's digital input word.
    pub fn inputs(&self) -> u32 {
        self.inputs
    }

    /// Takes the oldest event.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    /// Events dropped because the queue was full.
    pub fn dropped_events(&self) -> u64 {
        self.dropped_events
    }

    fn emit(&mut self, e: Event) {
        if self.events.push_back(e).is_err() {
            self.dropped_events += 1;
        }
    }

    /// Brings a booted axis into the cycle (its supervision starts now), or takes one out
    /// (boot failed: the axis is faulted with [`FaultReason::BootFailed`]). An axis faulted
    /// before (its drive was lost) keeps that fault until it is acknowledged.
    pub fn set_online(&mut self, axis: AxisId, online: bool, now: Instant) {
        if !online {
            self.set_offline(axis, Some(FaultReason::BootFailed));
            return;
        }
        let Some(a) = self.axes.get_mut(usize::from(axis)) else {
            return;
        };
        a.online = true;
        a.missed = 0;
        if let Transport::Can { bus, node: n } = a.transport
            && let Some(id) = node(n)
            && let Some(b) = self.buses.get_mut(usize::from(bus))
        {
            match self.cold[usize::from(axis)].setup.supervision {
                Supervision::Heartbeat { consumer_ms } => {
                    let _ = b
                        .heartbeat
                        .monitor(id, core::time::Duration::from_millis(consumer_ms.into()));
                }
                Supervision::Guarding {
                    guard_ms,
                    life_factor,
                } => {
                    let _ = b.guarding.add_node(id, guard_ms, life_factor, now);
                }
                Supervision::None => {}
            }
        }
    }

    /// The coordinator itself missed `skipped` cycles before this one (the host stalled it for
    /// `late_ns`). The drives could not answer SYNCs that were never sent, so the late-TPDO
    /// count starts again for every axis; heartbeats and guarding replies that came meanwhile
    /// are in the frames of the next step with their times. Reported as an event, and the
    /// configured reaction applied.
    pub fn overrun(&mut self, skipped: u64, late_ns: u64) {
        for a in self.axes.iter_mut() {
            a.missed = 0;
        }
        let cycle = self.cycle;
        self.emit(Event::Overrun {
            cycle,
            skipped,
            late_us: late_ns / 1000,
        });
        if self.setup.overrun == OverrunReaction::QuickStop {
            let _ = self.apply(&Command::QuickStop(Target::All));
        }
    }

    /// Takes an axis out of the cycle while its drive is away, rebooting or refused: no more
    /// RPDOs, guarding polls or supervision for it until [`Cycle::set_online`]. An axis that is
    /// not faulted yet is first faulted with `reason` (its group reacts in this call), if given;
    /// without a reason (a drive that has not appeared yet) it just stays offline.
    pub fn set_offline(&mut self, axis: AxisId, reason: Option<FaultReason>) {
        if let Some(r) = reason {
            self.raise(axis, r);
        }
        let Some(a) = self.axes.get_mut(usize::from(axis)) else {
            return;
        };
        if let Some(r) = reason
            && a.fault == FaultReason::None
        {
            // Not online yet, so `raise` ignored it: the fault still belongs to the axis.
            a.fault = r;
        }
        a.online = false;
        a.missed = 0;
        a.following = false;
        self.solos.clear(usize::from(axis));
        if let Transport::Can { bus, node: n } = a.transport
            && let Some(id) = node(n)
            && let Some(b) = self.buses.get_mut(usize::from(bus))
        {
            b.heartbeat.remove(id);
            b.guarding.remove(id);
        }
    }

    /// Applies a command; its effect goes out with the next step, whose SYNC latches it.
    pub fn command(&mut self, c: &Command) -> Reply {
        match self.apply(c) {
            Ok(()) => Reply::Latched {
                cycle: self.cycle + 1,
            },
            Err(r) => Reply::Rejected(r),
        }
    }

    fn groups_of(&self, t: Target) -> Result<(usize, usize), Rejected> {
        Ok(match t {
            Target::Group(g) if usize::from(g) < self.groups.len() => {
                (usize::from(g), usize::from(g) + 1)
            }
            Target::Group(g) => return Err(Rejected::UnknownGroup(g)),
            Target::Axis(a) => match self.axes.get(usize::from(a)) {
                Some(ax) => match ax.group {
                    Some(g) => (usize::from(g), usize::from(g) + 1),
                    None => (0, 0),
                },
                None => return Err(Rejected::UnknownAxis(a)),
            },
            Target::All => (0, self.groups.len()),
        })
    }

    /// A group's own run state, before its members are looked at.
    fn group_run(&self, gi: usize) -> GroupActivity {
        let g = &self.groups[gi];
        match g.halt {
            GroupHalt::Stopping => GroupActivity::Stopping,
            GroupHalt::Held => GroupActivity::Held,
            GroupHalt::None if g.chain.is_running() => GroupActivity::Chain,
            GroupHalt::None
                if g.motion.is_some() || g.special_since.is_some() || g.next.is_some() =>
            {
                GroupActivity::Moving
            }
            GroupHalt::None => GroupActivity::Standby,
        }
    }

    /// What axis `i` is doing, for the admission table.
    fn axis_activity(&self, i: usize) -> AxisActivity {
        let a = &self.axes[i];
        if !a.online {
            return AxisActivity::Offline;
        }
        if a.fault != FaultReason::None || matches!(a.mode, AxisMode::Acknowledging { .. }) {
            return AxisActivity::ErrorStop;
        }
        match a.mode {
            AxisMode::Off => return AxisActivity::Disabled,
            AxisMode::QuickStopped => return AxisActivity::QuickStopped,
            AxisMode::Homing => return AxisActivity::Homing,
            AxisMode::On | AxisMode::Jog { .. } | AxisMode::Acknowledging { .. } => {}
        }
        if let Some(s) = self.solos.get(i) {
            return match (s.end, s.kind) {
                (SoloEnd::Stop, _) => AxisActivity::Stopping,
                (_, SoloKind::Jog { .. }) if s.next.is_none() && s.end != SoloEnd::Halt => {
                    AxisActivity::Continuous
                }
                _ => AxisActivity::Discrete,
            };
        }
        match a.group.map(|g| self.group_run(usize::from(g))) {
            Some(GroupActivity::Moving | GroupActivity::Chain | GroupActivity::Held) => {
                AxisActivity::Synchronized
            }
            Some(GroupActivity::Stopping) => AxisActivity::Stopping,
            _ => AxisActivity::Standstill,
        }
    }

    /// What group `gi` is doing, for the admission table: a faulted member makes it faulted,
    /// a member off (or quick-stopped, or offline) disabled; else its own run state.
    fn group_activity(&self, gi: usize) -> GroupActivity {
        let members = &self.groups[gi].setup.axes;
        let base = |m: &AxisId| {
            let a = &self.axes[usize::from(*m)];
            if a.fault != FaultReason::None || matches!(a.mode, AxisMode::Acknowledging { .. }) {
                AxisActivity::ErrorStop
            } else if !a.online {
                AxisActivity::Offline
            } else {
                match a.mode {
                    AxisMode::Off => AxisActivity::Disabled,
                    AxisMode::QuickStopped => AxisActivity::QuickStopped,
                    _ => AxisActivity::Standstill,
                }
            }
        };
        if members.iter().any(|m| base(m) == AxisActivity::ErrorStop) {
            return GroupActivity::ErrorStop;
        }
        if members.iter().any(|m| base(m) != AxisActivity::Standstill) {
            return GroupActivity::Disabled;
        }
        self.group_run(gi)
    }

    /// The axes a target addresses, by index.
    fn target_axes(&self, t: Target) -> Result<Vec<AxisId, A>, Rejected> {
        let mut out = Vec::new();
        match t {
            Target::Axis(a) if usize::from(a) < self.axes.len() => {
                let _ = out.push(a);
            }
            Target::Axis(a) => return Err(Rejected::UnknownAxis(a)),
            Target::Group(g) => {
                let g = self
                    .groups
                    .get(usize::from(g))
                    .ok_or(Rejected::UnknownGroup(g))?;
                for &m in &g.setup.axes {
                    let _ = out.push(m);
                }
            }
            Target::All => {
                for a in 0..self.axes.len() {
                    let _ = out.push(a as AxisId);
                }
            }
        }
        Ok(out)
    }

    /// Looks `verb` up for every axis of a target, whole before anything changes: refused if
    /// any axis refuses it (a group or the machine does a command entirely or not at all).
    /// Returns the axes where it runs.
    fn admit_axes(&self, t: Target, verb: AxisVerb) -> Result<Vec<AxisId, A>, Rejected> {
        let mut run = Vec::new();
        for a in self.target_axes(t)? {
            match admission::axis(self.axis_activity(usize::from(a)), verb) {
                Admit::Run => {
                    let _ = run.push(a);
                }
                Admit::NoOp => {}
                Admit::Refuse(r) => return Err(refused(r)),
            }
        }
        Ok(run)
    }

    /// Looks `verb` up for every group a target concerns (an axis: its group, if the group
    /// drives it), whole first. Returns the groups where it runs.
    fn admit_groups(&self, t: Target, verb: GroupVerb) -> Result<Vec<GroupId, G>, Rejected> {
        let (g0, g1) = self.groups_of(t)?;
        let mut run = Vec::new();
        for gi in g0..g1 {
            if let Target::Axis(a) = t
                && self.axis_activity(usize::from(a)) != AxisActivity::Synchronized
            {
                // An axis on its own: its group is not concerned.
                continue;
            }
            match admission::group(self.group_activity(gi), verb) {
                Admit::Run => {
                    let _ = run.push(gi as GroupId);
                }
                Admit::NoOp => {}
                Admit::Refuse(r) => return Err(refused(r)),
            }
        }
        Ok(run)
    }

    fn apply(&mut self, c: &Command) -> Result<(), Rejected> {
        match *c {
            Command::Enable(t) => {
                for a in self.admit_axes(t, AxisVerb::Enable)? {
                    let a = &mut self.axes[usize::from(a)];
                    a.mode = AxisMode::On;
                    a.setpoint = a.drive.feedback().position;
                }
                Ok(())
            }
            Command::Disable(t) => {
                let (g0, g1) = self.groups_of(t)?;
                for gi in g0..g1 {
                    self.abort_chain(gi);
                    let g = &mut self.groups[gi];
                    g.motion = None;
                    g.next = None;
                    g.halt = GroupHalt::None;
                }
                for a in self.admit_axes(t, AxisVerb::Disable)? {
                    self.solos.clear(usize::from(a));
                    let a = &mut self.axes[usize::from(a)];
                    a.mode = AxisMode::Off;
                    a.following = false;
                }
                Ok(())
            }
            Command::Acknowledge(t) => {
                // A drive that is not there cannot be acknowledged: its fault stays until it is
                // back (booted again) and acknowledged then.
                if let Target::Axis(a) = t
                    && self
                        .axes
                        .get(usize::from(a))
                        .is_some_and(|x| !x.online && x.fault != FaultReason::None)
                {
                    return Err(Rejected::WrongState(
                        "drive offline: acknowledge once it is back",
                    ));
                }
                // Only faulted axes: nothing else stops, aborts or changes.
                for a in self.admit_axes(t, AxisVerb::Acknowledge)? {
                    let i = usize::from(a);
                    let a = &mut self.axes[i];
                    if matches!(a.mode, AxisMode::Acknowledging { .. }) {
                        continue;
                    }
                    let enable_after = !matches!(a.mode, AxisMode::Off);
                    a.fault = FaultReason::None;
                    a.drive_fault_seen = false;
                    a.missed = 0;
                    a.following = false;
                    a.mode = AxisMode::Acknowledging { enable_after };
                    self.solos.clear(i);
                }
                Ok(())
            }
            Command::Home(t) => {
                for a in self.admit_axes(t, AxisVerb::Home)? {
                    self.solos.clear(usize::from(a));
                    let a = &mut self.axes[usize::from(a)];
                    a.mode = AxisMode::Homing;
                }
                Ok(())
            }
            Command::Jog { axis, permille } => {
                if !(-1000..=1000).contains(&permille) {
                    return Err(Rejected::OutOfRange {
                        axis,
                        value: permille.into(),
                        min: -1000,
                        max: 1000,
                    });
                }
                if permille == 0 {
                    for a in self.admit_axes(Target::Axis(axis), AxisVerb::JogStop)? {
                        if let Some(s) = self.solos.get_mut(usize::from(a)) {
                            s.motion.hold();
                            s.end = SoloEnd::Halt;
                            s.next = None;
                        }
                    }
                    return Ok(());
                }
                self.admit_axes(Target::Axis(axis), AxisVerb::Jog)?;
                self.start_solo(
                    usize::from(axis),
                    SoloKind::Jog { permille },
                    BufferMode::Aborting,
                )
            }
            Command::MoveAxis {
                axis,
                position,
                velocity_percent,
                buffer,
            } => {
                let a = &self
                    .cold
                    .get(usize::from(axis))
                    .ok_or(Rejected::UnknownAxis(axis))?
                    .setup;
                in_range(axis, position, a.position_min, a.position_max)?;
                percent(axis, velocity_percent)?;
                self.admit_axes(Target::Axis(axis), AxisVerb::Move)?;
                self.start_solo(
                    usize::from(axis),
                    SoloKind::Move {
                        position,
                        velocity_percent,
                    },
                    buffer,
                )
            }
            Command::MoveGroup {
                group,
                positions,
                velocity_percent,
                buffer,
            } => {
                let gi = usize::from(group);
                let g = self.groups.get(gi).ok_or(Rejected::UnknownGroup(group))?;
                percent(group, velocity_percent)?;
                let mut targets = [AxisTarget::Keep; MAX_GROUP_AXES];
                for (i, &m) in g.setup.axes.iter().enumerate() {
                    let a = &self.cold[usize::from(m)].setup;
                    in_range(m, positions[i], a.position_min, a.position_max)?;
                    targets[i] = AxisTarget::Absolute(positions[i]);
                }
                self.admit_group_motion(gi, GroupVerb::Move)?;
                let mv = GroupMove {
                    targets,
                    velocity_percent,
                };
                let running = self.groups[gi]
                    .motion
                    .as_ref()
                    .is_some_and(|m| m.state() != MoveState::Done)
                    || self.groups[gi].next.is_some();
                if !running {
                    self.groups[gi].motion = None;
                    return self.start_group_move(gi, &targets, velocity_percent, 100, 100);
                }
                let g = &mut self.groups[gi];
                if buffer == BufferMode::Aborting
                    && let Some(m) = &mut g.motion
                {
                    m.hold();
                }
                g.next = Some(buffer);
                g.next_move = mv;
                Ok(())
            }
            Command::StartChain { group, record } => {
                let gi = usize::from(group);
                let g = self.groups.get(gi).ok_or(Rejected::UnknownGroup(group))?;
                if g.table.get(record).is_none() {
                    return Err(Rejected::UnknownRecord(record));
                }
                self.admit_group_motion(gi, GroupVerb::StartChain)?;
                let now = self.now;
                let g = &mut self.groups[gi];
                g.motion = None;
                g.chain
                    .start(g.table, record, now)
                    .map_err(|_| Rejected::UnknownRecord(record))
            }
            Command::Hold(t) => {
                let axes = self.admit_axes(t, AxisVerb::Hold)?;
                let groups = self.admit_groups(t, GroupVerb::Hold)?;
                for gi in groups {
                    let g = &mut self.groups[usize::from(gi)];
                    g.halt = GroupHalt::Held;
                    if let Some(m) = &mut g.motion {
                        m.hold();
                    }
                }
                for a in axes {
                    if let Some(s) = self.solos.get_mut(usize::from(a))
                        && s.end == SoloEnd::Arrive
                    {
                        s.motion.hold();
                        s.end = SoloEnd::Held;
                    }
                }
                Ok(())
            }
            Command::Resume(t) => {
                let axes = self.admit_axes(t, AxisVerb::Resume)?;
                let groups = self.admit_groups(t, GroupVerb::Resume)?;
                for gi in groups {
                    // The move resumes once it has stopped on its path (run_groups), or a
                    // record held back starts.
                    self.groups[usize::from(gi)].halt = GroupHalt::None;
                }
                for a in axes {
                    if let Some(s) = self.solos.get_mut(usize::from(a))
                        && s.end == SoloEnd::Held
                    {
                        s.end = SoloEnd::Arrive;
                    }
                }
                Ok(())
            }
            Command::Stop(t) => {
                let groups = self.admit_groups(t, GroupVerb::Stop)?;
                let axes = self.admit_axes(t, AxisVerb::Stop)?;
                self.stops = self.stops.wrapping_add(1);
                for gi in groups {
                    let gi = usize::from(gi);
                    self.abort_chain(gi);
                    let g = &mut self.groups[gi];
                    g.next = None;
                    match &mut g.motion {
                        Some(m) if m.state() != MoveState::Done => {
                            m.hold();
                            g.halt = GroupHalt::Stopping;
                        }
                        _ => {
                            g.motion = None;
                            g.halt = GroupHalt::None;
                        }
                    }
                }
                for a in axes {
                    let i = usize::from(a);
                    let a = &mut self.axes[i];
                    if let Some(s) = self.solos.get_mut(i) {
                        s.motion.hold();
                        s.end = SoloEnd::Stop;
                        s.next = None;
                    }
                    if a.mode == AxisMode::Homing {
                        a.mode = AxisMode::On;
                        a.setpoint = a.drive.feedback().position;
                    }
                }
                Ok(())
            }
            Command::QuickStop(t) => {
                let groups = self.admit_groups(t, GroupVerb::QuickStop)?;
                let axes = self.admit_axes(t, AxisVerb::QuickStop)?;
                self.stops = self.stops.wrapping_add(1);
                for gi in groups {
                    let gi = usize::from(gi);
                    self.abort_chain(gi);
                    let g = &mut self.groups[gi];
                    g.motion = None;
                    g.next = None;
                    g.halt = GroupHalt::None;
                }
                for a in axes {
                    self.solos.clear(usize::from(a));
                    let a = &mut self.axes[usize::from(a)];
                    a.following = false;
                    a.mode = AxisMode::QuickStopped;
                }
                Ok(())
            }
            Command::SetOverride { target, percent } => {
                if percent > crate::profile::MAX_OVERRIDE {
                    return Err(Rejected::OutOfRange {
                        axis: match target {
                            Target::Axis(a) => a,
                            Target::Group(g) => g,
                            Target::All => 0,
                        },
                        value: percent.into(),
                        min: 0,
                        max: crate::profile::MAX_OVERRIDE.into(),
                    });
                }
                let (g0, g1) = match target {
                    Target::Axis(_) => (0, 0),
                    t => self.groups_of(t)?,
                };
                // Such a drive runs the move on its own generator at the speed it was sent:
                // a path running faster or slower would leave it behind or ahead.
                let axes = self.target_axes(target)?;
                let groups_moving = self.groups[g0..g1].iter().filter(|g| g.motion.is_some());
                let members =
                    groups_moving.flat_map(|g| g.setup.axes.iter().map(|&m| usize::from(m)));
                let solos = axes
                    .iter()
                    .map(|&a| usize::from(a))
                    .filter(|&i| self.solos.is_some(i));
                if members
                    .chain(solos)
                    .any(|i| one_set_point_per_move(&self.cold[i].setup))
                {
                    return Err(Rejected::WrongState(
                        "a running move of an axis whose drive takes one set-point per move \
                         (MTR-DCI in CiA 402) keeps its speed: change the override before the \
                         move, or halt it",
                    ));
                }
                for g in &mut self.groups[g0..g1] {
                    g.override_percent = percent;
                    if let Some(m) = &mut g.motion {
                        let _ = m.set_override(percent.min(g.max_override));
                    }
                }
                for a in axes {
                    let i = usize::from(a);
                    self.cold[i].override_percent = percent;
                    if let Some(s) = self.solos.get_mut(i) {
                        let _ = s.motion.set_override(percent.min(s.max_override));
                    }
                }
                Ok(())
            }
            Command::ReadParameter { axis, pnu, sub } => {
                self.parameter(axis, fpc::Request::Read(fpc::Param::new(pnu, sub)))
            }
            Command::WriteParameter {
                axis,
                pnu,
                sub,
                value,
            } => self.parameter(
                axis,
                fpc::Request::Write(fpc::Param::new(pnu, sub), fpc::Value::Dword(value)),
            ),
            Command::SetInput { bit, value } => {
                if bit >= 32 {
                    return Err(Rejected::OutOfRange {
                        axis: 0,
                        value: bit.into(),
                        min: 0,
                        max: 31,
                    });
                }
                if value {
                    self.inputs |= 1 << bit;
                } else {
                    self.inputs &= !(1 << bit);
                }
                Ok(())
            }
        }
    }

    /// Admission of a group motion command: the group table, then each member (a member on its
    /// own move, homing or off refuses it).
    fn admit_group_motion(&self, gi: usize, verb: GroupVerb) -> Result<(), Rejected> {
        if let Admit::Refuse(r) = admission::group(self.group_activity(gi), verb) {
            return Err(refused(r));
        }
        for &m in &self.groups[gi].setup.axes {
            match self.axis_activity(usize::from(m)) {
                AxisActivity::Standstill | AxisActivity::Synchronized => {}
                other => {
                    if let Admit::Refuse(r) = admission::axis(other, AxisVerb::Move) {
                        return Err(refused(r));
                    }
                    return Err(refused(Refusal::Moving));
                }
            }
        }
        Ok(())
    }

    /// Plans a single-axis motion from the axis's setpoint, or hands it to the running one to
    /// take over (aborting: that one ramps down first; buffered: once it has arrived).
    fn start_solo(&mut self, i: usize, kind: SoloKind, buffer: BufferMode) -> Result<(), Rejected> {
        let cycle_ns = self.setup.cycle_ns;
        let a = &self.axes[i];
        let c = &self.cold[i];
        if let Some(s) = self.solos.get_mut(i) {
            // Checked now, so that a refusal comes with the command, not later.
            plan_solo(&c.setup, a.setpoint, kind, c.override_percent, cycle_ns)?;
            if buffer == BufferMode::Aborting {
                s.motion.hold();
                s.end = SoloEnd::Halt;
            }
            s.next = Some(kind);
            return Ok(());
        }
        let solo = plan_solo(&c.setup, a.setpoint, kind, c.override_percent, cycle_ns)?;
        self.solos.set(i, Some(solo));
        Ok(())
    }

    /// Accepted stop and quick-stop commands so far (a client that runs the machine on its own,
    /// such as the demonstration script, ends when an operator stops it).
    pub fn stops(&self) -> u32 {
        self.stops
    }

    /// Starts a parameter-channel task on an axis.
    fn parameter(&mut self, axis: AxisId, req: fpc::Request) -> Result<(), Rejected> {
        let a = self
            .axes
            .get_mut(usize::from(axis))
            .ok_or(Rejected::UnknownAxis(axis))?;
        if !a.online {
            return Err(Rejected::WrongState("drive not booted"));
        }
        let Some(FpcRt { client, .. }) = a.fpc.and_then(|k| self.fpcs.get_mut(usize::from(k)))
        else {
            return Err(Rejected::WrongState(
                "no parameter channel (fpc) on this axis",
            ));
        };
        client.submit(req).map_err(|_| Rejected::Busy)?;
        self.cold[usize::from(axis)].fpc_task = match req {
            fpc::Request::Read(p) | fpc::Request::Write(p, _) => Some(p),
            fpc::Request::NoTask => None,
        };
        Ok(())
    }

    /// Plans a group move from the members' setpoints; every member's demand becomes a path
    /// sample from the next step on, so all of them start at the same SYNC.
    fn start_group_move(
        &mut self,
        gi: usize,
        targets: &[AxisTarget; MAX_GROUP_AXES],
        velocity_percent: u8,
        acceleration_percent: u8,
        jerk_percent: u8,
    ) -> Result<(), Rejected> {
        let g = &self.groups[gi];
        let mut start = [0i64; MAX_GROUP_AXES];
        let mut end = [0i64; MAX_GROUP_AXES];
        let first = g.setup.axes.first().map_or(0, |&m| usize::from(m));
        let mut limits = [scale(
            &self.cold[first].setup.limits,
            velocity_percent,
            acceleration_percent,
            jerk_percent,
        ); MAX_GROUP_AXES];
        for (i, &m) in g.setup.axes.iter().enumerate() {
            let a = &self.axes[usize::from(m)];
            if a.fault != FaultReason::None {
                return Err(Rejected::Faulted);
            }
            if a.mode != AxisMode::On || self.solos.is_some(usize::from(m)) {
                return Err(Rejected::WrongState("axis not enabled and standing"));
            }
            start[i] = a.setpoint;
            end[i] = match targets[i] {
                AxisTarget::Keep => a.setpoint,
                AxisTarget::Absolute(p) => p,
                AxisTarget::Relative(d) => a.setpoint.saturating_add(d),
            };
            let setup = &self.cold[usize::from(m)].setup;
            in_range(m, end[i], setup.position_min, setup.position_max)?;
            limits[i] = scale(
                &setup.limits,
                velocity_percent,
                acceleration_percent,
                jerk_percent,
            );
        }
        for i in g.setup.axes.len()..MAX_GROUP_AXES {
            start[i] = 0;
            end[i] = 0;
        }
        // A member that takes one set-point per move runs a trapezoid (see `solo_shape`).
        let shape = if g
            .setup
            .axes
            .iter()
            .any(|&m| one_set_point_per_move(&self.cold[usize::from(m)].setup))
        {
            Shape::Trapezoid
        } else {
            g.setup.shape
        };
        let mut m = PathMove::plan(
            start,
            PathTarget::Absolute(end),
            &limits,
            shape,
            self.setup.cycle_ns,
        )
        .map_err(|_| Rejected::Plan)?;
        let g = &mut self.groups[gi];
        g.max_override = override_headroom(velocity_percent, acceleration_percent, jerk_percent);
        let _ = m.set_override(g.override_percent.min(g.max_override));
        g.motion = Some(m);
        g.halt = GroupHalt::None;
        Ok(())
    }

    /// One cycle. `input.now` must not go backwards.
    pub fn step(&mut self, input: &CycleInput<'_>, out: &mut CycleOutput<'_>) {
        self.now = input.now;
        let now = input.now;
        self.prefetch();
        for a in self.axes.iter_mut() {
            a.input = None;
        }
        for p in self.fpcs.iter_mut() {
            p.input = None;
        }
        self.receive(input);
        self.supervise(now);
        self.run_groups(now);
        self.run_axes();
        self.transmit(now, out);
        self.previous_inputs = self.inputs;
        self.cycle += 1;
    }

    /// Asks for the cache lines the step reads every cycle, all at once, before it reads the
    /// first: the state comes from memory (the cycle thread slept a period), and lines asked for
    /// together arrive together instead of one miss after another as the sweep reaches them.
    /// (Not asked for: a running single-axis motion's slot and the supervision's per-node
    /// entries, read only for the axes and nodes concerned.)
    #[inline(always)]
    fn prefetch(&self) {
        self.hot_regions(&mut |p, bytes| prefetch_bytes(p, bytes));
    }

    /// The regions of the state that [`Cycle::prefetch`] asks for, as (start, bytes).
    #[inline(always)]
    fn hot_regions(&self, f: &mut impl FnMut(*const u8, usize)) {
        // The scalars, and the line of each container that holds its length or indices.
        region(f, core::slice::from_ref(&self.cycle));
        region(f, core::slice::from_ref(&self.setup));
        region_first(f, &self.events);
        region_first(f, &self.solos.slots);
        region_first(f, &self.buses);
        region_first(f, &self.axes);
        region(f, self.axes.as_slice());
        region_first(f, &self.groups);
        for g in &self.groups {
            g.cycle_regions(f);
        }
        region(f, &self.solos.running[..self.axes.len()]);
        if !self.fpcs.is_empty() {
            region(f, self.fpcs.as_slice());
        }
        for b in &self.buses {
            region(f, &b.by_node.0);
            region_first(f, &b.heartbeat);
            region_first(f, &b.guarding);
        }
    }

    /// The cache lines the step asks for before it starts ([`Cycle::step`] reads each of them
    /// every cycle), each as the offset of its first byte from the start of `self` (the first
    /// can start up to 63 bytes before it), in the order asked, a line shared by two regions
    /// once per region. Lines outside the state (an empty container's placeholder address)
    /// are left out. `timing step` reads these lines alone from a cold copy of the state: the
    /// memory floor under a cold step.
    pub fn for_each_hot_line(&self, f: &mut dyn FnMut(isize)) {
        let base = (self as *const Self).cast::<u8>() as isize;
        let size = core::mem::size_of::<Self>() as isize;
        self.hot_regions(&mut |p, bytes| {
            // The same lines as `prefetch_bytes` asks for.
            for_each_line(p, bytes, |line| {
                let off = line as isize - base;
                if off > -64 && off < size {
                    f(off);
                }
            });
        });
    }

    fn receive(&mut self, input: &CycleInput<'_>) {
        for bf in input.frames {
            let f = &bf.frame;
            let Some(cob) = f.cob_id() else { continue };
            let Some((fc, n)) = FunctionCode::split(cob) else {
                continue;
            };
            let Some(bus) = self.buses.get_mut(usize::from(bf.bus)) else {
                continue;
            };
            let Some(axis) = bus.by_node.get(usize::from(n)) else {
                continue;
            };
            match fc {
                FunctionCode::Tpdo(1) if !f.is_remote() => {
                    if let Some(img) = Image::from_slice(f.data()) {
                        self.axes[usize::from(axis)].input = Some(img);
                    }
                }
                FunctionCode::Tpdo(2) if !f.is_remote() => {
                    if let (Some(img), Some(k)) = (
                        Image::from_slice(f.data()),
                        self.axes[usize::from(axis)].fpc,
                    ) && let Some(p) = self.fpcs.get_mut(usize::from(k))
                    {
                        p.input = Some(img);
                    }
                }
                FunctionCode::NmtErrorControl => {
                    // A boot-up from a drive in the cycle: it reset itself (power, watchdog);
                    // its PDO settings are gone. Fault it now rather than cycles later.
                    if f.data() == [0] && !f.is_remote() && self.axes[usize::from(axis)].online {
                        self.raise(axis, FaultReason::DriveReset);
                        continue;
                    }
                    let _ = bus.heartbeat.handle_frame(f, f.timestamp());
                    let _ = bus.guarding.handle_frame(f, f.timestamp());
                }
                FunctionCode::SyncEmcy => {
                    if let Ok(m) = EmcyMessage::from_frame(f)
                        && m.code != 0
                    {
                        self.raise(axis, FaultReason::Emcy(m.code));
                    }
                }
                _ => {}
            }
        }
        for i in 0..self.axes.len() {
            let transport = self.axes[i].transport;
            if let Some(slot) = transport.image_slot() {
                let Some(m) = input.images.get(usize::from(slot)).copied() else {
                    continue;
                };
                if !self.axes[i].online {
                    continue;
                }
                let ethercat = matches!(transport, Transport::Ethercat { .. });
                if m.lost {
                    self.raise(
                        i as AxisId,
                        if ethercat {
                            FaultReason::EthercatLost
                        } else {
                            FaultReason::ModbusTimeout
                        },
                    );
                } else if m.not_op != 0 {
                    self.raise(i as AxisId, FaultReason::EthercatState(m.not_op));
                }
                if m.emcy != 0 {
                    self.raise(i as AxisId, FaultReason::Emcy(m.emcy));
                }
                if m.fresh {
                    self.axes[i].input = Some(m.image);
                    if m.late_cycles > 0 {
                        let cycle = self.cycle;
                        self.emit(Event::LateModbus {
                            cycle,
                            axis: i as AxisId,
                            cycles: m.late_cycles,
                        });
                    }
                }
            }
        }
    }

    fn supervise(&mut self, now: Instant) {
        for b in 0..self.buses.len() {
            let bus = &mut self.buses[b];
            let _ = bus.heartbeat.handle_timeout(now);
            let _ = bus.guarding.handle_timeout(now);
            while let Some(e) = self.buses[b].heartbeat.poll_event() {
                if let HeartbeatEvent::Lost { node } = e
                    && let Some(a) = self.buses[b].by_node.get(usize::from(node.get()))
                {
                    self.raise(a, FaultReason::HeartbeatLost);
                }
            }
            while let Some(e) = self.buses[b].guarding.poll_event() {
                let n = match e {
                    GuardingEvent::Lost { node } | GuardingEvent::ToggleError { node, .. } => node,
                    _ => continue,
                };
                if let Some(a) = self.buses[b].by_node.get(usize::from(n.get())) {
                    self.raise(a, FaultReason::GuardingLost);
                }
            }
        }
        for i in 0..self.axes.len() {
            let a = &mut self.axes[i];
            if !a.online {
                continue;
            }
            if a.input.is_some() {
                a.missed = 0;
            } else {
                a.missed = a.missed.saturating_add(1);
                let limit = a.late_cycles;
                if limit != 0 && a.missed == limit {
                    self.raise(i as AxisId, FaultReason::LateTpdo(limit));
                }
            }
        }
    }

    /// Marks an axis faulted (once) and applies its group's reaction in this cycle.
    fn raise(&mut self, axis: AxisId, reason: FaultReason) {
        let Some(a) = self.axes.get_mut(usize::from(axis)) else {
            return;
        };
        if a.fault != FaultReason::None || !a.online {
            return;
        }
        a.fault = reason;
        a.following = false;
        if !matches!(a.mode, AxisMode::Off) {
            a.mode = AxisMode::QuickStopped;
        }
        let group = a.group;
        self.solos.clear(usize::from(axis));
        let cycle = self.cycle;
        self.emit(Event::Fault {
            cycle,
            axis,
            reason,
        });
        let Some(g) = group else { return };
        self.abort_chain(usize::from(g));
        let gr = &mut self.groups[usize::from(g)];
        // A move waiting to take over does not start on a faulted group.
        gr.next = None;
        let reaction = gr.setup.reaction;
        match reaction {
            Reaction::AxisOnly => {}
            Reaction::QuickStopGroup => {
                gr.motion = None;
                gr.next = None;
                gr.halt = GroupHalt::None;
                let members = gr.setup.axes.clone();
                for m in members {
                    self.solos.clear(usize::from(m));
                    let a = &mut self.axes[usize::from(m)];
                    a.following = false;
                    if !matches!(a.mode, AxisMode::Off) {
                        a.mode = AxisMode::QuickStopped;
                    }
                }
            }
            Reaction::HaltGroup => {
                gr.next = None;
                if let Some(m) = &mut gr.motion {
                    m.hold();
                    gr.halt = GroupHalt::Stopping;
                }
            }
        }
    }

    fn run_groups(&mut self, now: Instant) {
        let mut reached = [None::<u16>; G];
        for (i, g) in self.groups.iter().enumerate() {
            reached[i] = g.chain.status().reached;
        }
        for gi in 0..self.groups.len() {
            // Actual values of this cycle, group order.
            let mut pos = [0i64; MAX_GROUP_AXES];
            let mut vel = [0i64; MAX_GROUP_AXES];
            let mut force = [0i32; MAX_GROUP_AXES];
            let n = self.groups[gi].setup.axes.len();
            // Every member's motion complete: the drives' feedback stays as it is until the
            // axes' exchange, after the groups, so this holds for the whole group step.
            let mut all_mc = true;
            for (i, &m) in self.groups[gi].setup.axes.iter().enumerate() {
                let a = &self.axes[usize::from(m)];
                let fb = a.drive.feedback();
                pos[i] = fb.position;
                vel[i] = fb.velocity;
                force[i] = fb.force;
                all_mc &= fb.motion_complete;
            }
            let motion_done = match (&self.groups[gi].motion, self.groups[gi].special_since) {
                // A velocity or force record "arrives" when the drives report it (speed or
                // force reached), not before they have seen it.
                (_, Some(since)) => all_mc && self.cycle > since + 2,
                (None, None) => all_mc,
                (Some(m), None) => m.state() == MoveState::Done && all_mc,
            };
            let ngroups = self.groups.len();
            let g = &mut self.groups[gi];
            let actions = g.chain.step(
                g.table,
                &ChainInputs {
                    now,
                    cycle: self.cycle,
                    motion_done,
                    positions: &pos[..n],
                    velocities: &vel[..n],
                    forces: &force[..n],
                    inputs: self.inputs,
                    previous_inputs: self.previous_inputs,
                    reached: &reached[..ngroups],
                },
            );
            for act in actions {
                let cycle = self.cycle;
                let group = gi as GroupId;
                match act {
                    ChainAction::StartMotion { record } => {
                        let moving = self.groups[gi].motion.as_ref().is_some_and(|m| {
                            !matches!(m.state(), MoveState::Done | MoveState::Stopped)
                        });
                        if self.groups[gi].halt != GroupHalt::None {
                            // Held: the record waits for the resume (a hold is kept across
                            // chain steps).
                            self.groups[gi].pending = Some(record);
                        } else if moving {
                            // On the fly: no blending. The running move decelerates along its
                            // path and the record starts from there, so the setpoints stay
                            // continuous.
                            if let Some(m) = &mut self.groups[gi].motion {
                                m.hold();
                            }
                            self.groups[gi].pending = Some(record);
                        } else {
                            self.start_record(gi, record);
                        }
                    }
                    other => {
                        if matches!(other, ChainAction::Complete { .. }) {
                            self.end_special(gi);
                        }
                        if let Some(e) = other.event(cycle, group) {
                            self.emit(e);
                        }
                    }
                }
            }
            // A record waiting for the previous move to stop starts now (unless held).
            if let Some(record) = self.groups[gi].pending
                && self.groups[gi].halt == GroupHalt::None
                && self.groups[gi]
                    .motion
                    .as_ref()
                    .is_none_or(|m| matches!(m.state(), MoveState::Done | MoveState::Stopped))
            {
                self.groups[gi].pending = None;
                self.start_record(gi, record);
            }
            // A move given while another ran: aborting, once that one has stopped on its path;
            // buffered, once it has arrived.
            if let Some(mode) = self.groups[gi].next
                && self.groups[gi].halt == GroupHalt::None
            {
                let g = &self.groups[gi];
                let mv = g.next_move;
                let go = match (mode, g.motion.as_ref().map(|m| m.state())) {
                    (_, None) => true,
                    (BufferMode::Aborting, Some(MoveState::Stopped | MoveState::Done)) => true,
                    (BufferMode::Buffered, Some(MoveState::Done)) => all_mc,
                    _ => false,
                };
                if go {
                    self.groups[gi].next = None;
                    self.groups[gi].motion = None;
                    // Admitted when given; a fault since then cleared it (see `raise`).
                    let _ = self.start_group_move(gi, &mv.targets, mv.velocity_percent, 100, 100);
                }
            }
            // Motion: one sample per member per cycle.
            let g = &mut self.groups[gi];
            if let Some(m) = &mut g.motion {
                let mut samples = [(0i64, 0i64); MAX_GROUP_AXES];
                let n = g.setup.axes.len().min(MAX_GROUP_AXES);
                m.step_positions(&mut samples[..n]);
                let state = m.state();
                for (i, &mm) in g.setup.axes.iter().enumerate() {
                    let a = &mut self.axes[usize::from(mm)];
                    (a.setpoint, a.setpoint_velocity) = samples[i];
                    a.following = true;
                }
                let arrived = state == MoveState::Done && all_mc;
                let stopped = state == MoveState::Stopped;
                if stopped && g.halt == GroupHalt::Stopping {
                    g.motion = None;
                    g.halt = GroupHalt::None;
                } else if arrived && g.pending.is_none() && g.next.is_none() {
                    g.motion = None;
                } else if stopped
                    && g.halt == GroupHalt::None
                    && g.pending.is_none()
                    && g.next.is_none()
                {
                    // Resumed while it was still ramping down: on along the path.
                    let _ = m.resume();
                }
            } else if g.halt == GroupHalt::Stopping {
                g.halt = GroupHalt::None;
            }
        }
    }

    /// Starts a record's motion from the members' setpoints (the previous move is over).
    fn start_record(&mut self, gi: usize, record: u16) {
        let Some(r) = self.groups[gi].table.get(record).copied() else {
            self.abort_chain(gi);
            return;
        };
        self.end_special(gi);
        self.groups[gi].motion = None;
        if r.mode != RecordMode::Position {
            self.start_special(gi, &r);
            return;
        }
        if self
            .start_group_move(
                gi,
                &r.targets,
                r.velocity_percent,
                r.acceleration_percent,
                r.jerk_percent,
            )
            .is_err()
        {
            self.abort_chain(gi);
        }
    }

    /// Starts a velocity or force record: each member with a target runs on its own demand
    /// (direction from the sign of its target) until the chain moves on.
    fn start_special(&mut self, gi: usize, r: &crate::records::Record) {
        let cycle = self.cycle;
        let members = self.groups[gi].setup.axes.clone();
        self.groups[gi].motion = None;
        self.groups[gi].special_since = Some(cycle);
        for (i, &m) in members.iter().enumerate() {
            let a = &mut self.axes[usize::from(m)];
            let sign = match r.targets[i] {
                AxisTarget::Keep => 0,
                AxisTarget::Absolute(p) => (p - a.setpoint).signum(),
                AxisTarget::Relative(d) => d.signum(),
            };
            let v = self.cold[usize::from(m)].setup.limits.velocity as i64
                * i64::from(r.velocity_percent)
                / 100;
            self.specials[usize::from(m)] = match (r.mode, sign) {
                (_, 0) => None,
                (RecordMode::Velocity, s) => Some(Demand::Velocity { velocity: s * v }),
                (RecordMode::Force, s) => Some(Demand::Force {
                    permille: s as i32 * r.force_permille,
                    velocity_limit: v,
                }),
                (RecordMode::Position, _) => None,
            };
            a.following = false;
            self.solos.clear(usize::from(m));
        }
    }

    /// Ends a velocity or force record: the members stand where they are.
    fn end_special(&mut self, gi: usize) {
        if self.groups[gi].special_since.take().is_none() {
            return;
        }
        let members = self.groups[gi].setup.axes.clone();
        for m in members {
            self.specials[usize::from(m)] = None;
            let a = &mut self.axes[usize::from(m)];
            a.setpoint = a.drive.feedback().position;
        }
    }

    /// Aborts a group's chain (if it runs) and reports it.
    fn abort_chain(&mut self, gi: usize) {
        let now = self.now;
        let cycle = self.cycle;
        if gi >= self.groups.len() {
            return;
        }
        self.end_special(gi);
        let g = &mut self.groups[gi];
        g.pending = None;
        if !g.chain.is_running() {
            return;
        }
        if let Some(e) = g
            .chain
            .abort(now)
            .and_then(|a| a.event(cycle, gi as GroupId))
        {
            self.emit(e);
        }
    }

    fn run_axes(&mut self) {
        let cycle = self.cycle;
        for i in 0..self.axes.len() {
            let cycle_ns = self.setup.cycle_ns;
            let a = &mut self.axes[i];
            if let Some(s) = self.solos.get_mut(i) {
                let mut smp = [(0i64, 0i64)];
                s.motion.step_positions(&mut smp);
                (a.setpoint, a.setpoint_velocity) = smp[0];
                a.following = true;
                let state = s.motion.state();
                let arrived = state == MoveState::Done && a.drive.feedback().motion_complete;
                let over = match (state, s.end) {
                    (MoveState::Stopped, SoloEnd::Arrive) => {
                        // Resumed while it was still ramping down: on along the path.
                        let _ = s.motion.resume();
                        false
                    }
                    (MoveState::Stopped, SoloEnd::Held) => false,
                    (MoveState::Stopped | MoveState::Done, SoloEnd::Halt | SoloEnd::Stop) => true,
                    // Held too late to stop short: arrived, but what waits stays held.
                    (MoveState::Done, SoloEnd::Held) => arrived && s.next.is_none(),
                    (MoveState::Done, SoloEnd::Arrive) => arrived,
                    _ => false,
                };
                if over {
                    let next = s.next;
                    let c = &self.cold[i];
                    let solo = next.and_then(|k| {
                        plan_solo(&c.setup, a.setpoint, k, c.override_percent, cycle_ns).ok()
                    });
                    self.solos.set(i, solo);
                }
            }
            if a.drive.one_set_point_per_move() {
                let point = match (self.solos.get(i), a.group) {
                    (Some(s), _) => Some(point_move(&s.motion, 0)),
                    (None, Some(g)) => {
                        let g = &self.groups[usize::from(g)];
                        g.motion.as_ref().and_then(|m| {
                            let k = g.setup.axes.iter().position(|&x| usize::from(x) == i)?;
                            Some(point_move(m, k))
                        })
                    }
                    (None, None) => None,
                };
                a.drive.set_move(point);
            }
            // A velocity or force record of the group drives the axis directly, and stands
            // while its group is held or stopping.
            let (group_halted, special) = match a.group.map(|g| &self.groups[usize::from(g)]) {
                Some(g) if g.special_since.is_some() => {
                    (g.halt != GroupHalt::None, self.specials[i])
                }
                Some(g) => (g.halt != GroupHalt::None, None),
                None => (false, None),
            };
            let a = &mut self.axes[i];
            let demand = match a.mode {
                _ if !a.online => Demand::Disable,
                AxisMode::Off => Demand::Disable,
                AxisMode::QuickStopped => Demand::QuickStop,
                AxisMode::Acknowledging { .. } => Demand::Acknowledge,
                AxisMode::Homing => Demand::Home,
                // Not stored: a jog is a planned single-axis motion (see `axis_status`).
                AxisMode::Jog { .. } => Demand::Standstill,
                AxisMode::On if special.is_some() && group_halted => Demand::Halt,
                AxisMode::On if special.is_some() => special.unwrap_or(Demand::Standstill),
                AxisMode::On if a.following => Demand::Follow {
                    position: a.setpoint,
                    velocity: a.setpoint_velocity,
                },
                AxisMode::On => Demand::Standstill,
            };
            let input = a.input.as_ref().map(|i| i.bytes());
            let mut out = Image::default();
            // An image that cannot be decoded leaves the last feedback standing.
            let _ = a.drive.exchange(input, &demand, &mut out);
            a.out = out;
            let fb = *a.drive.feedback();
            // Mode changes on completion.
            match a.mode {
                AxisMode::Homing if fb.done && fb.homed => {
                    a.mode = AxisMode::On;
                    a.setpoint = fb.position;
                }
                AxisMode::Acknowledging { enable_after } if fb.done => {
                    a.mode = if enable_after {
                        AxisMode::On
                    } else {
                        AxisMode::Off
                    };
                    a.setpoint = fb.position;
                    self.emit(Event::Acknowledged {
                        cycle,
                        axis: i as AxisId,
                    });
                }
                AxisMode::Homing | AxisMode::QuickStopped | AxisMode::Off => {
                    self.axes[i].setpoint = fb.position;
                }
                AxisMode::On if special.is_some() => {
                    self.axes[i].setpoint = fb.position;
                }
                _ => {}
            }
            let a = &mut self.axes[i];
            if !self.solos.is_some(i)
                && a.group
                    .is_none_or(|g| self.groups[usize::from(g)].motion.is_none())
            {
                a.following = false;
            }
            // Faults seen in the drive's own status.
            let a = &self.axes[i];
            if a.online && fb.state == AxisState::Fault && !a.drive_fault_seen {
                let code = fb.fault_code;
                if a.fault == FaultReason::None && !matches!(a.mode, AxisMode::Acknowledging { .. })
                {
                    self.raise(i as AxisId, FaultReason::DriveFault(code));
                }
                self.axes[i].drive_fault_seen = true;
            }
            let a = &self.axes[i];
            if a.following && a.following_error > 0 && a.input.is_some() {
                let e = (a.setpoint - fb.position).abs();
                if e > a.following_error {
                    let limit = a.following_error;
                    self.raise(i as AxisId, FaultReason::FollowingError { error: e, limit });
                }
            }
            if let Some(FpcRt {
                client,
                input: Some(input),
            }) = self.axes[i]
                .fpc
                .and_then(|k| self.fpcs.get_mut(usize::from(k)))
                && let Some(outcome) = client.handle_input(input.bytes())
            {
                let p = self.cold[i].fpc_task.take().unwrap_or_default();
                let result = match outcome {
                    Ok(v) => Ok(v.raw()),
                    Err(fpc::TaskError::Refused { number, .. }) => Err(number),
                    Err(fpc::TaskError::Timeout { .. }) => Err(u16::MAX),
                };
                self.emit(Event::Parameter {
                    cycle,
                    axis: i as AxisId,
                    pnu: p.pnu,
                    sub: p.sub,
                    result,
                });
            }
            let a = &mut self.axes[i];
            if fb.state != a.last_state {
                a.last_state = fb.state;
                self.emit(Event::AxisState {
                    cycle,
                    axis: i as AxisId,
                    state: fb.state,
                });
            }
        }
    }

    fn transmit(&mut self, now: Instant, out: &mut CycleOutput<'_>) {
        // Every bus's SYNC first, back to back: the buses latch this cycle's RPDOs together.
        if self.setup.sync_producer {
            for b in 0..self.buses.len() {
                out.push(b as u8, drivers::canopen::sync::encode_sync(0x080, None));
            }
        }
        for a in &self.axes {
            if !a.online {
                continue;
            }
            match a.transport {
                Transport::Can { bus, node: n } => {
                    if let Some(id) = node(n)
                        && let Ok(f) =
                            Frame::new_std(FunctionCode::Rpdo(1).cob_id(id), a.out.bytes())
                    {
                        out.push(bus, f);
                    }
                }
                Transport::Modbus { slot } | Transport::Ethercat { slot } => {
                    if let Some(m) = out.images.get_mut(usize::from(slot)) {
                        *m = a.out;
                    }
                }
            }
        }
        // The parameter channels after every RPDO1: the motion images come first. RPDO2 is
        // also where a drive that takes one set-point per move gets the move's profile (never
        // both: such a drive has no parameter channel).
        for a in &self.axes {
            let Transport::Can { bus, node: n } = a.transport else {
                continue;
            };
            let rpdo2 = match a.fpc.and_then(|k| self.fpcs.get(usize::from(k))) {
                Some(p) => Some(p.client.output()),
                None => a.drive.profile_pdo(),
            };
            if let (true, Some(bytes), Some(id)) = (a.online, rpdo2, node(n))
                && let Ok(f) = Frame::new_std(FunctionCode::Rpdo(2).cob_id(id), &bytes)
            {
                out.push(bus, f);
            }
        }
        for (b, bus) in self.buses.iter_mut().enumerate() {
            while let Some(f) = bus.guarding.poll_transmit(now) {
                out.push(b as u8, f);
            }
        }
    }
}

/// Hands `f` the first byte of `x`: for a container, the line that holds its length or
/// indices.
#[inline(always)]
fn region_first<T>(f: &mut impl FnMut(*const u8, usize), x: &T) {
    f((x as *const T).cast(), 1);
}

/// Hands `f` the start and size of `items`.
#[inline(always)]
fn region<T>(f: &mut impl FnMut(*const u8, usize), items: &[T]) {
    f(items.as_ptr().cast(), core::mem::size_of_val(items));
}

/// Hands `f` the start of each 64-byte cache line that `bytes` bytes from `p` touch, from the
/// line `p` is in, so that each line comes once.
#[inline(always)]
fn for_each_line(p: *const u8, bytes: usize, mut f: impl FnMut(*const u8)) {
    let skew = (p as usize) & 63;
    let line = p.wrapping_sub(skew);
    let mut off = 0;
    while off < skew + bytes {
        f(line.wrapping_add(off));
        off += 64;
    }
}

/// Asks for the cache lines of `bytes` bytes from `p` (no-op off x86_64).
#[inline(always)]
fn prefetch_bytes(p: *const u8, bytes: usize) {
    #[cfg(target_arch = "x86_64")]
    for_each_line(p, bytes, |line| {
        use core::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        // SAFETY: a prefetch is a hint: it never faults, whatever the address (and these are
        // lines of the state the step is about to read).
        unsafe { _mm_prefetch::<_MM_HINT_T0>(line.cast::<i8>()) };
    });
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (p, bytes);
}

/// A refusal of the admission table as the reply says it.
fn refused(r: Refusal) -> Rejected {
    match r {
        Refusal::Faulted => Rejected::Faulted,
        r => Rejected::WrongState(r.text()),
    }
}

/// A jog's speed, inc/s: ‰ of the velocity limit (at least 1 inc/s).
fn jog_velocity(l: &AxisLimits, permille: i16) -> i64 {
    let v = l
        .velocity
        .saturating_mul(u64::from(permille.unsigned_abs()))
        / 1000;
    v.max(1).min(i64::MAX as u64) as i64
}

/// A single axis's moves are jerk-limited, except on a drive that takes one set-point per move:
/// it runs each on its own trapezoidal generator (the MTR-DCI: 6086h linear only, seed 000
/// §7.8), and the path, which supervision compares it with, is planned the same way.
fn solo_shape(setup: &AxisSetup) -> Shape {
    if one_set_point_per_move(setup) {
        Shape::Trapezoid
    } else {
        Shape::SCurve
    }
}

/// Whether the axis's drive takes one set-point per move (see [`takes_one_set_point_per_move`]).
fn one_set_point_per_move(setup: &AxisSetup) -> bool {
    takes_one_set_point_per_move(setup.kind, setup.profile, setup.mode)
}

/// The move a drive that takes one set-point per move runs for member `k` of `m`.
fn point_move<const N: usize>(m: &PathMove<N>, k: usize) -> PointMove {
    let (velocity, acceleration) = m.axis_limits(k);
    PointMove {
        end: m.target().get(k).copied().unwrap_or_default(),
        velocity: velocity.min(u64::from(u32::MAX)) as u32,
        acceleration: acceleration.min(u64::from(u32::MAX)) as u32,
        halt: matches!(
            m.state(),
            MoveState::Holding | MoveState::QuickStopping | MoveState::Stopped
        ),
    }
}

/// Plans a single-axis motion from `from`: a move at its share of the limits, or a jog to the
/// software limit in its direction at its speed with the full acceleration (so it stops
/// exactly at the limit at the latest, and a release ramps down within the limits).
fn plan_solo(
    setup: &AxisSetup,
    from: i64,
    kind: SoloKind,
    override_percent: u16,
    cycle_ns: u32,
) -> Result<Solo, Rejected> {
    let (target, limits, max_override) = match kind {
        SoloKind::Move {
            position,
            velocity_percent,
        } => (
            position,
            scale(&setup.limits, velocity_percent, 100, 100),
            override_headroom(velocity_percent, 100, 100),
        ),
        SoloKind::Jog { permille } => {
            let mut l = setup.limits;
            l.velocity = jog_velocity(&setup.limits, permille) as u64;
            let share = (u32::from(permille.unsigned_abs()).div_ceil(10)).clamp(1, 100) as u8;
            let to = if permille > 0 {
                setup.position_max
            } else {
                setup.position_min
            };
            (to, l, override_headroom(share, 100, 100))
        }
    };
    let mut motion = PathMove::plan(
        [from],
        PathTarget::Absolute([target]),
        &[limits],
        solo_shape(setup),
        cycle_ns,
    )
    .map_err(|_| Rejected::Plan)?;
    let _ = motion.set_override(override_percent.min(max_override));
    Ok(Solo {
        motion,
        kind,
        end: SoloEnd::Arrive,
        next: None,
        max_override,
    })
}

fn in_range(axis: u16, v: i64, min: i64, max: i64) -> Result<(), Rejected> {
    if (min..=max).contains(&v) {
        Ok(())
    } else {
        Err(Rejected::OutOfRange {
            axis,
            value: v,
            min,
            max,
        })
    }
}

fn percent(axis: u16, p: u8) -> Result<(), Rejected> {
    if (1..=100).contains(&p) {
        Ok(())
    } else {
        Err(Rejected::OutOfRange {
            axis,
            value: p.into(),
            min: 1,
            max: 100,
        })
    }
}

/// The highest override (%, at most 200) under which a move planned at these shares of the
/// limits stays within the limits: `o·v ≤ 100`, `o²·a ≤ 100²`, `o³·j ≤ 100³` (in %).
fn override_headroom(v: u8, a: u8, j: u8) -> u16 {
    let (v, a, j) = (
        u64::from(v.max(1)),
        u64::from(a.max(1)),
        u64::from(j.max(1)),
    );
    let mut o = crate::profile::MAX_OVERRIDE as u64;
    while o > 100 && (o * v > 10_000 || o * o * a > 1_000_000 || o * o * o * j > 100_000_000) {
        o -= 1;
    }
    o as u16
}

/// Limits scaled by a record's percentages (at least 1 where the limit is non-zero).
fn scale(l: &AxisLimits, v: u8, acc: u8, jerk: u8) -> AxisLimits {
    let s = |x: u64, p: u8| (x.saturating_mul(u64::from(p)) / 100).max(u64::from(x > 0));
    AxisLimits {
        velocity: s(l.velocity, v),
        acceleration: s(l.acceleration, acc),
        deceleration: s(l.deceleration, acc),
        jerk: s(l.jerk, jerk),
        quick_stop_deceleration: l.quick_stop_deceleration,
        quick_stop_jerk: l.quick_stop_jerk,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::records::{Record, RecordTable};

    #[test]
    fn gaps_hand_out_the_parts_between_the_skipped_ones() {
        let bytes = [0u8; 256];
        let base = bytes.as_ptr();
        let at = |o: usize| base.wrapping_add(o);
        let parts = |skipped: &[(usize, usize)]| {
            let mut out = std::vec::Vec::new();
            let mut f = |p: *const u8, n| out.push((p as usize - base as usize, n));
            let mut gaps = Gaps::new(base, &mut f);
            for &(o, n) in skipped {
                gaps.skip(at(o), n);
            }
            gaps.finish(256);
            out
        };
        // Touching ranges leave nothing between them; the ends are kept.
        assert_eq!(
            parts(&[(64, 64), (128, 16), (192, 32)]),
            [(0, 64), (144, 48), (224, 32)]
        );
        assert_eq!(parts(&[(0, 16), (200, 56)]), [(16, 184)]);
        assert_eq!(parts(&[]), [(0, 256)]);
        assert_eq!(parts(&[(0, 256)]), []);
        // An empty range skips nothing.
        assert_eq!(parts(&[(32, 0), (64, 0)]), [(0, 32), (32, 32), (64, 192)]);
    }

    fn axis(node: u8) -> AxisSetup {
        AxisSetup {
            kind: DeviceKind::MtrDci,
            profile: Profile::Fhpp,
            transport: Transport::Can { bus: 0, node },
            supervision: Supervision::None,
            limits: AxisLimits::new(100_000, 400_000, 8_000_000),
            position_min: 0,
            position_max: 160_000,
            following_error: 10_000,
            late_cycles: 3,
            fpc: false,
            mode: CyclicMode::Pp,
        }
    }

    const SETUP: CycleSetup = CycleSetup {
        cycle_ns: 2_000_000,
        sync_producer: true,
        buses: 1,
        overrun: OverrunReaction::Report,
    };

    #[test]
    fn override_headroom_keeps_every_limit() {
        assert_eq!(override_headroom(100, 100, 100), 100);
        // Half the velocity: velocity allows 200 %, but acceleration (o² · 100 ≤ 100²) only 100.
        assert_eq!(override_headroom(50, 100, 100), 100);
        // A quarter of the acceleration: o ≤ 200 by it; the jerk at 100 % caps at 100.
        assert_eq!(override_headroom(50, 25, 100), 100);
        assert_eq!(override_headroom(50, 25, 12), 200);
        // o = 141: 141² · 50 = 994 050 ≤ 10^6; 142² · 50 > 10^6.
        assert_eq!(override_headroom(50, 50, 10), 141);
    }

    #[test]
    fn setup_refuses_shared_nodes_and_bad_members() {
        let table = RecordTable::new();
        let g = GroupSetup {
            axes: Vec::from_slice(&[0, 1]).unwrap(),
            shape: Shape::Trapezoid,
            reaction: Reaction::QuickStopGroup,
        };
        assert_eq!(
            Cycle::<4, 2>::new(SETUP, &[axis(1), axis(1)], &[]).err(),
            Some(SetupError::Node(1))
        );
        assert_eq!(
            Cycle::<4, 2>::new(SETUP, &[axis(1)], &[(g.clone(), &table)]).err(),
            Some(SetupError::Member(0))
        );
        assert_eq!(
            Cycle::<1, 2>::new(SETUP, &[axis(1), axis(2)], &[]).err(),
            Some(SetupError::Capacity(1))
        );
        assert!(Cycle::<4, 2>::new(SETUP, &[axis(1), axis(2)], &[(g, &table)]).is_ok());
    }

    #[test]
    fn a_node_map_names_up_to_255_axes() {
        // A cycle of 256 axes is large: built on a thread with room for it.
        std::thread::Builder::new()
            .stack_size(64 << 20)
            .spawn(|| {
                let modbus = |slot: usize| AxisSetup {
                    kind: DeviceKind::CmmoSt,
                    transport: Transport::Modbus { slot: slot as u8 },
                    ..axis(1)
                };
                let mut axes: std::vec::Vec<AxisSetup> = (0..254).map(modbus).collect();
                // The last axis a byte can name is a CANopen node.
                axes.push(axis(7));
                let c = Cycle::<256, 1>::new(SETUP, &axes, &[]).unwrap();
                assert_eq!(c.buses[0].by_node.get(7), Some(254));
                assert_eq!(c.buses[0].by_node.get(6), None);
                axes.push(axis(8));
                assert_eq!(
                    Cycle::<256, 1>::new(SETUP, &axes, &[]).err(),
                    Some(SetupError::Capacity(255))
                );
            })
            .unwrap()
            .join()
            .unwrap();
    }

    #[test]
    fn bad_commands_are_rejected_with_their_reason() {
        let mut table = RecordTable::new();
        table.insert(5, Record::default()).unwrap();
        let g = GroupSetup {
            axes: Vec::from_slice(&[0, 1]).unwrap(),
            shape: Shape::Trapezoid,
            reaction: Reaction::QuickStopGroup,
        };
        let mut c = Cycle::<4, 2>::new(SETUP, &[axis(1), axis(2)], &[(g, &table)]).unwrap();
        let rej = |r| Reply::Rejected(r);
        assert_eq!(
            c.command(&Command::Enable(Target::Axis(7))),
            rej(Rejected::UnknownAxis(7))
        );
        assert_eq!(
            c.command(&Command::Hold(Target::Group(3))),
            rej(Rejected::UnknownGroup(3))
        );
        assert_eq!(
            c.command(&Command::StartChain {
                group: 0,
                record: 6
            }),
            rej(Rejected::UnknownRecord(6))
        );
        // Not booted yet: enabling is the wrong state.
        assert!(matches!(
            c.command(&Command::Enable(Target::All)),
            Reply::Rejected(Rejected::WrongState(_))
        ));
        assert_eq!(
            c.command(&Command::MoveAxis {
                axis: 0,
                position: 200_000,
                velocity_percent: 50,
                buffer: BufferMode::Aborting,
            }),
            rej(Rejected::OutOfRange {
                axis: 0,
                value: 200_000,
                min: 0,
                max: 160_000
            })
        );
        assert_eq!(
            c.command(&Command::SetOverride {
                target: Target::Group(0),
                percent: 250
            }),
            rej(Rejected::OutOfRange {
                axis: 0,
                value: 250,
                min: 0,
                max: 200
            })
        );
        assert!(matches!(
            c.command(&Command::SetInput {
                bit: 32,
                value: true
            }),
            Reply::Rejected(Rejected::OutOfRange { .. })
        ));
        // Accepted commands latch at the next step's SYNC.
        assert_eq!(
            c.command(&Command::SetInput {
                bit: 3,
                value: true
            }),
            Reply::Latched { cycle: 1 }
        );
        assert_eq!(c.inputs(), 1 << 3);
    }

    #[test]
    fn the_output_is_sync_then_the_rpdos_of_online_axes() {
        let mut c = Cycle::<4, 2>::new(SETUP, &[axis(1), axis(2), axis(3)], &[]).unwrap();
        c.set_online(0, true, Instant::ZERO);
        c.set_online(2, true, Instant::ZERO);
        let mut frames = [BusFrame::new(0, Frame::std8(0, [0; 8])); 8];
        let mut modbus: [Image; 0] = [];
        let mut out = CycleOutput {
            frames: &mut frames,
            len: 0,
            overflow: 0,
            images: &mut modbus,
        };
        c.step(
            &CycleInput {
                now: Instant::ZERO,
                frames: &[],
                images: &[],
            },
            &mut out,
        );
        let ids: heapless::Vec<u16, 8> =
            out.sent().iter().filter_map(|f| f.frame.cob_id()).collect();
        assert_eq!(ids.as_slice(), &[0x080, 0x201, 0x203]);
        assert_eq!(c.cycle(), 1);
    }

    #[test]
    fn an_emcy_faults_its_axis_once_and_refuses_motion_until_acknowledged() {
        let table = RecordTable::new();
        let g = GroupSetup {
            axes: Vec::from_slice(&[0, 1]).unwrap(),
            shape: Shape::Trapezoid,
            reaction: Reaction::QuickStopGroup,
        };
        let mut c = Cycle::<4, 2>::new(SETUP, &[axis(1), axis(2)], &[(g, &table)]).unwrap();
        c.set_online(0, true, Instant::ZERO);
        c.set_online(1, true, Instant::ZERO);
        let emcy = Frame::std8(0x082, [0x10, 0x42, 0x01, 0, 0, 0, 0, 0]);
        let mut frames = [BusFrame::new(0, Frame::std8(0, [0; 8])); 8];
        let mut modbus: [Image; 0] = [];
        for _ in 0..2 {
            let mut out = CycleOutput {
                frames: &mut frames,
                len: 0,
                overflow: 0,
                images: &mut modbus,
            };
            c.step(
                &CycleInput {
                    now: Instant::ZERO,
                    frames: &[BusFrame::new(0, emcy)],
                    images: &[],
                },
                &mut out,
            );
        }
        assert_eq!(c.axis_status(1).unwrap().fault, FaultReason::Emcy(0x4210));
        let faults = core::iter::from_fn(|| c.poll_event())
            .filter(|e| matches!(e, Event::Fault { .. }))
            .count();
        assert_eq!(faults, 1, "raised once");
        assert!(matches!(
            c.command(&Command::Home(Target::Axis(1))),
            Reply::Rejected(Rejected::Faulted)
        ));
    }

    fn step_once<const A: usize, const G: usize>(
        c: &mut Cycle<'_, A, G>,
        rx: &[BusFrame],
        now: Instant,
    ) -> heapless::Vec<(u8, u16), 16> {
        let mut frames = [BusFrame::new(0, Frame::std8(0, [0; 8])); 16];
        let mut modbus: [Image; 0] = [];
        let mut out = CycleOutput {
            frames: &mut frames,
            len: 0,
            overflow: 0,
            images: &mut modbus,
        };
        c.step(
            &CycleInput {
                now,
                frames: rx,
                images: &[],
            },
            &mut out,
        );
        out.sent()
            .iter()
            .filter_map(|f| Some((f.bus, f.frame.cob_id()?)))
            .collect()
    }

    #[test]
    fn two_buses_get_their_sync_first_and_their_own_rpdos_with_one_node_id_on_each() {
        let setup = CycleSetup { buses: 2, ..SETUP };
        let on = |bus, node| AxisSetup {
            transport: Transport::Can { bus, node },
            ..axis(node)
        };
        let mut c = Cycle::<4, 2>::new(setup, &[on(0, 1), on(1, 1), on(1, 2)], &[]).unwrap();
        for a in 0..3 {
            c.set_online(a, true, Instant::ZERO);
        }
        let sent = step_once(&mut c, &[], Instant::ZERO);
        assert_eq!(
            sent.as_slice(),
            &[(0, 0x080), (1, 0x080), (0, 0x201), (1, 0x201), (1, 0x202)]
        );
        // A TPDO from node 1 of bus 1 is axis 1's, not axis 0's.
        let tpdo = BusFrame::new(1, Frame::std8(0x181, [0; 8]));
        step_once(&mut c, &[tpdo], Instant::ZERO);
        // A bus the machine does not have is refused at setup.
        assert_eq!(
            Cycle::<4, 2>::new(SETUP, &[on(1, 1)], &[]).err(),
            Some(SetupError::Node(0))
        );
    }

    #[test]
    fn a_boot_up_from_a_drive_in_the_cycle_faults_it_and_offline_axes_send_nothing() {
        let mut c = Cycle::<4, 2>::new(SETUP, &[axis(1), axis(2)], &[]).unwrap();
        c.set_online(0, true, Instant::ZERO);
        c.set_online(1, true, Instant::ZERO);
        let boot_up = BusFrame::new(0, Frame::new_std(0x702, &[0]).unwrap());
        step_once(&mut c, &[boot_up], Instant::ZERO);
        assert_eq!(c.axis_status(1).unwrap().fault, FaultReason::DriveReset);
        assert_eq!(c.axis_status(0).unwrap().fault, FaultReason::None);
        // Waiting for it: out of the cycle, the fault kept until acknowledged.
        c.set_offline(1, None);
        let sent = step_once(&mut c, &[], Instant::ZERO);
        assert_eq!(sent.as_slice(), &[(0, 0x080), (0, 0x201)]);
        assert_eq!(c.axis_status(1).unwrap().fault, FaultReason::DriveReset);
        // A drive that never came is offline without a fault; a refused one is faulted.
        let mut c = Cycle::<4, 2>::new(SETUP, &[axis(1), axis(2)], &[]).unwrap();
        c.set_offline(0, None);
        c.set_offline(1, Some(FaultReason::BootFailed));
        assert_eq!(c.axis_status(0).unwrap().fault, FaultReason::None);
        assert_eq!(c.axis_status(1).unwrap().fault, FaultReason::BootFailed);
    }

    #[test]
    fn an_overrun_of_the_coordinator_is_not_counted_against_the_drives() {
        let mut c = Cycle::<4, 2>::new(SETUP, &[axis(1)], &[]).unwrap();
        c.set_online(0, true, Instant::ZERO);
        // Two cycles without a TPDO: one short of the fault.
        step_once(&mut c, &[], Instant::ZERO);
        step_once(&mut c, &[], Instant::ZERO);
        // The coordinator was away 200 ms: the drive could not answer SYNCs never sent.
        c.overrun(100, 200_000_000);
        step_once(&mut c, &[], Instant::ZERO);
        step_once(&mut c, &[], Instant::ZERO);
        assert_eq!(c.axis_status(0).unwrap().fault, FaultReason::None);
        let events: heapless::Vec<Event, 8> = core::iter::from_fn(|| c.poll_event()).collect();
        assert!(events.contains(&Event::Overrun {
            cycle: 2,
            skipped: 100,
            late_us: 200_000
        }));
        // The count still works: a third cycle without a TPDO faults it.
        step_once(&mut c, &[], Instant::ZERO);
        assert_eq!(c.axis_status(0).unwrap().fault, FaultReason::LateTpdo(3));

        // With the quick-stop reaction every enabled axis stops.
        let setup = CycleSetup {
            overrun: OverrunReaction::QuickStop,
            ..SETUP
        };
        let mut c = Cycle::<4, 2>::new(setup, &[axis(1)], &[]).unwrap();
        c.set_online(0, true, Instant::ZERO);
        assert!(matches!(
            c.command(&Command::Enable(Target::All)),
            Reply::Latched { .. }
        ));
        c.overrun(3, 8_000_000);
        assert_eq!(c.axis_status(0).unwrap().mode, AxisMode::QuickStopped);
    }
}
