//! The coordinator's side: the cycle of the scenario's machine, the commissioning a boot would
//! do (SDO writes, NMT start), and the operator's script (enable, home, a group move, a record
//! chain), with the hash of every cycle's output.

use core::time::Duration;

use coordinator::axis::{AxisState, CyclicMode, DeviceKind, Image, Profile, pdo_mapping};
use coordinator::command::{BufferMode, Command, Reply, Target};
use coordinator::cycle::{
    AxisSetup, BusFrame, Cycle, CycleInput, CycleOutput, CycleSetup, GroupSetup, Supervision,
    Transport,
};
use coordinator::fault::{FaultReason, OverrunReaction, Reaction};
use coordinator::profile::{AxisLimits, Shape};
use coordinator::records::{
    AxisTarget, ChainState, MAX_GROUP_AXES, Quantity, Record, Step, StepCondition,
};
use drivers::can::Frame;
use drivers::canopen::nmt::{NmtCommand, NmtRequest, NmtTarget};
use drivers::canopen::sdo::{Completion, DownloadMode, SdoClient, SdoClientConfig};
use drivers::canopen::{Address, NodeId};
use drivers::time::Instant;
use heapless::Vec;

pub use coordinator::records::RecordTable;

use crate::hash::{self, Fnv1a};
use crate::{AXES, BUS, CYCLE_NS, GROUPS, MAX_CYCLES, X_NODE, Y_NODE};

/// Frames one cycle sends at most: SYNC, two RPDOs, two guarding polls, an SDO request per
/// drive, the NMT start, with room to spare.
pub const TX_CAPACITY: usize = 16;
/// Frames one cycle takes in at most; more would be a fault of the scenario.
pub const RX_CAPACITY: usize = 32;
/// The group's targets of the synchronised move, increments (x 150 mm, y 120 mm).
pub const MOVE_TARGETS: [i64; 2] = [60_000, 120_000];
/// Where the chain ends, increments (x 10 mm, y 0 mm).
pub const CHAIN_END: [i64; 2] = [4_000, 0];
/// The chain's first record.
pub const CHAIN_START: u16 = 10;

/// The SDO writes a boot leaves on a drive, as the coordinator's boot plan makes them for
/// these drives: PDO1 synchronous each way (`coordinator::axis::pdo_mapping`), node guarding
/// every 100 ms with life factor 3, and on the EMCA "direct start condition" PNU 583 = 1 (a
/// START while moving retargets; the streamed setpoints need it).
const GUARD_MS: u16 = 100;
const LIFE_FACTOR: u8 = 3;
/// Downloads per drive at most.
const DOWNLOADS: usize = 5;

/// The machine's cycle: 2 ms, SYNC producer, one bus.
pub const CYCLE_SETUP: CycleSetup = CycleSetup {
    cycle_ns: CYCLE_NS,
    sync_producer: true,
    buses: 1,
    overrun: OverrunReaction::Report,
};

/// The two axes: x an MTR-DCI (400 inc/mm, 0..400 mm, 150 mm/s, 1000 mm/s², 20000 mm/s³), y an
/// EMCA (1000 inc/mm, 0..250 mm, 80 mm/s, 400 mm/s²), as in the embedded example machine, both
/// in FHPP on bus 0 with node guarding.
pub fn axis_setups() -> [AxisSetup; AXES] {
    let guarding = Supervision::Guarding {
        guard_ms: GUARD_MS,
        life_factor: LIFE_FACTOR,
    };
    let x_limits = AxisLimits::new(60_000, 400_000, 8_000_000);
    // No jerk limit on y: the group is trapezoidal, the value only has to be non-zero.
    let y_limits = AxisLimits::new(80_000, 400_000, u64::MAX >> 8);
    let setup = |kind, node, limits: AxisLimits, max: i64| AxisSetup {
        kind,
        profile: Profile::Fhpp,
        transport: Transport::Can { bus: BUS, node },
        supervision: guarding,
        limits,
        position_min: 0,
        position_max: max,
        // The plan's default: the distance at full speed in 100 ms plus 6 cycles.
        following_error: (limits.velocity * 112 / 1000) as i64,
        late_cycles: 3,
        fpc: false,
        mode: CyclicMode::Pp,
    };
    [
        setup(DeviceKind::MtrDci, X_NODE, x_limits, 160_000),
        setup(DeviceKind::Emca, Y_NODE, y_limits, 250_000),
    ]
}

/// The gantry group: x and y, trapezoidal, quick stop of both on a fault.
pub fn group_setup() -> GroupSetup {
    let mut axes = Vec::new();
    let _ = axes.push(0);
    let _ = axes.push(1);
    GroupSetup {
        axes,
        shape: Shape::Trapezoid,
        reaction: Reaction::QuickStopGroup,
    }
}

fn targets(x: AxisTarget, y: AxisTarget) -> [AxisTarget; MAX_GROUP_AXES] {
    let mut t = [AxisTarget::Keep; MAX_GROUP_AXES];
    t[0] = x;
    t[1] = y;
    t
}

/// The gantry's record chain: 10 moves to (200, 100) mm and steps on the fly once x has stayed
/// in [150, 210] mm for 10 ms (a comparator); 11 moves by (+40, -40) mm after a 50 ms delay
/// and steps at MC; 12 goes to (10, 0) mm and ends the chain.
pub fn record_table() -> RecordTable {
    let mut t = RecordTable::with_axes(2);
    fill_record_table(&mut t);
    t
}

/// Puts [`record_table`]'s records into `t` where it lies (a microcontroller fills a `const`
/// initialised static so, rather than moving the 60 KB table through the stack).
pub fn fill_record_table(t: &mut RecordTable) {
    let r10 = Record {
        targets: targets(AxisTarget::Absolute(80_000), AxisTarget::Absolute(100_000)),
        velocity_percent: 80,
        acceleration_percent: 50,
        step: Step {
            condition: StepCondition::Comparator {
                axis: 0,
                quantity: Quantity::Position,
                window: coordinator::comparator::Window::new(
                    60_000,
                    84_000,
                    Duration::from_millis(10),
                ),
            },
            next: 11,
        },
        ..Record::default()
    };
    let r11 = Record {
        targets: targets(AxisTarget::Relative(16_000), AxisTarget::Relative(-40_000)),
        delay_ms: 50,
        step: Step {
            condition: StepCondition::Mc,
            next: 12,
        },
        mc_in_chain: false,
        ..Record::default()
    };
    let r12 = Record {
        targets: targets(
            AxisTarget::Absolute(CHAIN_END[0]),
            AxisTarget::Absolute(CHAIN_END[1]),
        ),
        ..Record::default()
    };
    for (n, r) in [(10, r10), (11, r11), (12, r12)] {
        t.insert(n, r).expect("the scenario's records are valid");
    }
    t.validate().expect("the scenario's chain links are valid");
}

/// Where the script is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// SDO writes to the drives (the boot's configuration).
    Commissioning,
    /// NMT start sent; the axes join the cycle next.
    Starting,
    /// Enable commanded, waiting for both axes ready.
    Enabling,
    /// Homing commanded, waiting for both referenced and standing.
    Homing,
    /// The group's synchronised move runs.
    Moving,
    /// The record chain runs.
    Chain,
    /// The scenario reached its end.
    Done,
    /// The scenario failed.
    Failed(Failure),
}

impl Phase {
    /// The phase in words.
    pub fn name(self) -> &'static str {
        match self {
            Phase::Commissioning => "commissioning",
            Phase::Starting => "starting",
            Phase::Enabling => "enabling",
            Phase::Homing => "homing",
            Phase::Moving => "moving",
            Phase::Chain => "chain",
            Phase::Done => "done",
            Phase::Failed(_) => "failed",
        }
    }
}

/// Why the scenario failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Failure {
    /// An SDO write of the commissioning failed.
    Commissioning,
    /// The cycle refused a command of the script.
    Rejected,
    /// An axis faulted.
    Fault,
    /// The chain was aborted.
    ChainAborted,
    /// The scenario did not end within [`MAX_CYCLES`].
    Timeout,
    /// More frames arrived in a cycle than [`RX_CAPACITY`], or a queue between the tasks
    /// overflowed.
    Overflow,
    /// The drives' side had not answered the previous cycle when the next one began (the
    /// microcontroller ran out of time).
    Overrun,
}

impl Failure {
    /// The failure in words.
    pub fn text(self) -> &'static str {
        match self {
            Failure::Commissioning => "an SDO write of the commissioning failed",
            Failure::Rejected => "the cycle refused a command of the script",
            Failure::Fault => "an axis faulted",
            Failure::ChainAborted => "the record chain was aborted",
            Failure::Timeout => "the scenario did not end in time",
            Failure::Overflow => "a frame buffer or queue overflowed",
            Failure::Overrun => "the drives had not answered before the next cycle",
        }
    }
}

/// The cycle, its buffers, the commissioning and the script.
#[derive(Debug)]
pub struct Controller<'t> {
    cycle: Cycle<'t, AXES, GROUPS>,
    sdo: [SdoClient<DOWNLOADS, 16>; AXES],
    pending: [u8; AXES],
    rx: Vec<BusFrame, RX_CAPACITY>,
    tx: [BusFrame; TX_CAPACITY],
    sent: usize,
    phase: Phase,
    /// A command of the current phase has been given.
    commanded: bool,
    /// Events taken from the cycle.
    events: u64,
    /// The cycle the scenario reached its end in.
    end_cycle: u64,
    /// The most a command of the script cost, in the clock's units.
    command_cost: u32,
}

fn node(n: u8) -> NodeId {
    NodeId::new(n).expect("node-IDs of the scenario are valid")
}

impl<'t> Controller<'t> {
    /// The machine of [`axis_setups`] and [`group_setup`] with `table` as the group's records,
    /// all axes offline, the commissioning queued.
    pub fn new(table: &'t RecordTable) -> Controller<'t> {
        let axes = axis_setups();
        let cycle = Cycle::new(CYCLE_SETUP, &axes, &[(group_setup(), table)])
            .expect("the scenario's machine is valid");
        let mut c = Controller {
            cycle,
            sdo: [
                SdoClient::new(node(X_NODE), SdoClientConfig::default()),
                SdoClient::new(node(Y_NODE), SdoClientConfig::default()),
            ],
            pending: [0; AXES],
            rx: Vec::new(),
            tx: [BusFrame::new(BUS, Frame::std8(0, [0; 8])); TX_CAPACITY],
            sent: 0,
            phase: Phase::Commissioning,
            commanded: false,
            events: 0,
            end_cycle: 0,
            command_cost: 0,
        };
        for (i, a) in axes.iter().enumerate() {
            let map = pdo_mapping(a.kind, a.profile);
            let mut writes: Vec<(Address, u32, usize), DOWNLOADS> = Vec::new();
            for pdo in [map.rpdo, map.tpdo].into_iter().flatten() {
                let base = match pdo.function {
                    drivers::canopen::FunctionCode::Rpdo(_) => 0x1400,
                    _ => 0x1800,
                };
                let _ = writes.push((
                    Address::new(base + u16::from(pdo.number) - 1, 2),
                    u32::from(pdo.transmission),
                    1,
                ));
            }
            let _ = writes.push((Address::new(0x100C, 0), u32::from(GUARD_MS), 2));
            let _ = writes.push((Address::new(0x100D, 0), u32::from(LIFE_FACTOR), 1));
            if a.kind == DeviceKind::Emca {
                let _ = writes.push((Address::new(0x2000 + 583, 1), 1, 1));
            }
            for (addr, value, len) in writes {
                let data = value.to_le_bytes();
                if c.sdo[i]
                    .download(addr, &data[..len], DownloadMode::Expedited)
                    .is_ok()
                {
                    c.pending[i] += 1;
                }
            }
        }
        c
    }

    /// The cycle (its published state).
    pub fn cycle(&self) -> &Cycle<'t, AXES, GROUPS> {
        &self.cycle
    }

    /// Where the script is.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// Whether the scenario has ended, reached or failed.
    pub fn finished(&self) -> bool {
        matches!(self.phase, Phase::Done | Phase::Failed(_))
    }

    /// The cycle the scenario reached its end in (0 before).
    pub fn end_cycle(&self) -> u64 {
        self.end_cycle
    }

    /// The most one command of the script cost so far ([`Cycle::command`], timed with the
    /// clock [`Controller::step`] is given): the group move's planning happens there.
    pub fn command_cost(&self) -> u32 {
        self.command_cost
    }

    /// Events the cycle reported so far.
    pub fn events(&self) -> u64 {
        self.events
    }

    /// Marks the scenario failed (a fault the tasks around the controller detected).
    pub fn fail(&mut self, why: Failure) {
        if !self.finished() {
            self.phase = Phase::Failed(why);
        }
    }

    /// Takes a frame the drives sent for the next step.
    pub fn receive(&mut self, f: BusFrame) {
        if self.rx.push(f).is_err() {
            self.fail(Failure::Overflow);
        }
    }

    /// The frames the last step sent: the cycle's, then SDO and NMT.
    pub fn sent(&self) -> &[BusFrame] {
        &self.tx[..self.sent]
    }

    /// The SYNC time of the next step.
    pub fn now(&self) -> Instant {
        Instant::from_nanos(self.cycle.cycle() * u64::from(CYCLE_NS))
    }

    /// One cycle: the commissioning's answers, the script, [`Cycle::step`] (with `clock` read
    /// just before and just after it; the difference is returned as the step's cost), the
    /// commissioning's requests; returns the cycle's number, its output hash and the cost.
    pub fn step(&mut self, clock: &mut impl FnMut() -> u32) -> (u64, u64, u32) {
        let now = self.now();
        let number = self.cycle.cycle();
        self.commissioning_answers();
        self.script(now, clock);
        let t0 = clock();
        let mut modbus: [Image; 0] = [];
        let mut out = CycleOutput {
            frames: &mut self.tx,
            len: 0,
            overflow: 0,
            images: &mut modbus,
        };
        self.cycle.step(
            &CycleInput {
                now,
                frames: &self.rx,
                images: &[],
            },
            &mut out,
        );
        let t1 = clock();
        let (mut len, overflow) = (out.len, out.overflow);
        if overflow > 0 {
            self.fail(Failure::Overflow);
        }
        self.rx.clear();
        // SDO and NMT after the cycle's own frames, as the runtime sends the services' frames.
        for sdo in &mut self.sdo {
            if let Some(f) = sdo.poll_transmit(now) {
                if let Some(slot) = self.tx.get_mut(len) {
                    *slot = BusFrame::new(BUS, f);
                    len += 1;
                } else {
                    self.phase = Phase::Failed(Failure::Overflow);
                }
            }
        }
        if self.phase == Phase::Commissioning && self.pending == [0; AXES] {
            let start = NmtRequest {
                command: NmtCommand::Start,
                target: NmtTarget::All,
            };
            if let Some(slot) = self.tx.get_mut(len) {
                *slot = BusFrame::new(BUS, start.to_frame());
                len += 1;
            }
            self.phase = Phase::Starting;
        }
        self.sent = len;
        while self.cycle.poll_event().is_some() {
            self.events += 1;
        }
        self.check();
        (number, self.hash(number), t1.wrapping_sub(t0))
    }

    fn commissioning_answers(&mut self) {
        for (i, sdo) in self.sdo.iter_mut().enumerate() {
            for f in &self.rx {
                if sdo.accepts(&f.frame) {
                    sdo.handle_frame(&f.frame, f.frame.timestamp());
                }
            }
            while let Some(e) = sdo.poll_event() {
                match e.outcome {
                    Ok(Completion::Downloaded) => {
                        self.pending[i] = self.pending[i].saturating_sub(1)
                    }
                    _ => self.phase = Phase::Failed(Failure::Commissioning),
                }
            }
        }
    }

    fn command(&mut self, c: Command, clock: &mut impl FnMut() -> u32) {
        let t0 = clock();
        let reply = self.cycle.command(&c);
        self.command_cost = self.command_cost.max(clock().wrapping_sub(t0));
        if let Reply::Rejected(_) = reply {
            self.fail(Failure::Rejected);
        }
        self.commanded = true;
    }

    fn next(&mut self, p: Phase) {
        self.phase = p;
        self.commanded = false;
    }

    /// The operator: each phase's command once, then the next phase when its condition holds.
    fn script(&mut self, now: Instant, clock: &mut impl FnMut() -> u32) {
        let axes = [0u16, 1].map(|a| self.cycle.axis_status(a));
        let [Some(x), Some(y)] = axes else {
            return;
        };
        let both = |f: &dyn Fn(&coordinator::cycle::AxisStatus) -> bool| f(&x) && f(&y);
        let standing = |s: &coordinator::cycle::AxisStatus| {
            s.feedback.state == AxisState::Ready && !s.moving && s.feedback.motion_complete
        };
        match self.phase {
            Phase::Starting => {
                for a in 0..AXES as u16 {
                    self.cycle.set_online(a, true, now);
                }
                self.next(Phase::Enabling);
            }
            Phase::Enabling => {
                if !self.commanded && both(&|s| s.feedback.state != AxisState::Offline) {
                    self.command(Command::Enable(Target::All), clock);
                } else if self.commanded && both(&|s| s.feedback.state == AxisState::Ready) {
                    self.next(Phase::Homing);
                    self.command(Command::Home(Target::All), clock);
                }
            }
            Phase::Homing => {
                if both(&|s| s.feedback.homed && standing(s)) {
                    self.next(Phase::Moving);
                    let mut positions = [0; MAX_GROUP_AXES];
                    positions[..2].copy_from_slice(&MOVE_TARGETS);
                    self.command(
                        Command::MoveGroup {
                            group: 0,
                            positions,
                            velocity_percent: 100,
                            buffer: BufferMode::Aborting,
                        },
                        clock,
                    );
                }
            }
            Phase::Moving => {
                let moving = self
                    .cycle
                    .group_status(0)
                    .is_some_and(|g| g.motion.is_some());
                if !moving && both(&standing) {
                    self.next(Phase::Chain);
                    self.command(
                        Command::StartChain {
                            group: 0,
                            record: CHAIN_START,
                        },
                        clock,
                    );
                }
            }
            Phase::Chain => {
                let chain = self.cycle.group_status(0).map(|g| g.chain.state);
                if chain == Some(ChainState::Complete) && both(&standing) {
                    self.end_cycle = self.cycle.cycle();
                    self.next(Phase::Done);
                }
            }
            Phase::Commissioning | Phase::Done | Phase::Failed(_) => {}
        }
    }

    /// Faults end the scenario, and so does running out of time.
    fn check(&mut self) {
        for a in 0..AXES as u16 {
            if let Some(s) = self.cycle.axis_status(a)
                && (s.fault != FaultReason::None || s.feedback.state == AxisState::Fault)
            {
                self.fail(Failure::Fault);
            }
        }
        if self
            .cycle
            .group_status(0)
            .is_some_and(|g| g.chain.state == ChainState::Aborted)
        {
            self.fail(Failure::ChainAborted);
        }
        if self.cycle.cycle() >= MAX_CYCLES {
            self.fail(Failure::Timeout);
        }
    }

    /// The hash of cycle `number`'s output: the cycle number, every frame sent, every axis's
    /// and the group's published state after the step ([`crate::hash`] gives the byte order).
    fn hash(&self, number: u64) -> u64 {
        let mut h = Fnv1a::new();
        h.u64(number);
        for f in self.sent() {
            hash::frame(&mut h, f);
        }
        for a in 0..AXES as u16 {
            if let Some(s) = self.cycle.axis_status(a) {
                hash::axis(&mut h, &s);
            }
        }
        if let Some(g) = self.cycle.group_status(0) {
            hash::group(&mut h, &g);
        }
        h.finish()
    }
}
