//! `coordinator run`: a machine plan driven by the cycle, in virtual time (one thread, the
//! simulated drives in lockstep with the cycle, deterministic, as fast as the machine allows)
//! or in real time (the cycle on its own thread woken by absolute deadlines, the simulated
//! drives on another, the CMMO-ST over Modbus TCP on loopback with its exchange on a third,
//! boot and reports on the services' executor).
//!
//! Both paths run the same cycle iteration ([`CycleCore::iterate`]): frames received → cycle
//! step → frames sent (SYNC, RPDOs, guarding polls, then leftover SDO/NMT within the reserved
//! slots).

use std::fmt::Write as _;
use std::io::{IsTerminal, Write};
use std::sync::atomic::Ordering;
use std::time::Duration;

use drivers::can::bit_timing::frame_duration;
use drivers::can::{Bus, ClockMode, Frame, VirtualBus, VirtualBusConfig, VirtualPort};
use drivers::time::{Instant, monotonic_now};
use hdrhistogram::Histogram;

use crate::axis::{AxisState, Image};
use crate::command::{AxisId, GroupId};
use crate::config::{BusKind, Config};
use crate::cycle::{
    AxisStatus, Cycle, CycleInput, CycleOutput, GroupStatus, ModbusInput, Transport,
};
use crate::event::Event;
use crate::fault::FaultReason;
use crate::runtime::boot::{BootReport, BootSequencer};
use crate::runtime::plan::{MAX_AXES, MAX_GROUPS, MachinePlan};
use crate::runtime::script::{Phase, Script, ScriptOptions};
use crate::runtime::shm::{ServiceSide, StateSide, StaticInfo};
use crate::runtime::sim::{InMemoryCmmo, SimBus};

/// The cycle type of a configured machine.
pub type MachineCycle<'t> = Cycle<'t, MAX_AXES, MAX_GROUPS>;

/// Frames one cycle may send: SYNC, one RPDO and one guarding poll per axis, plus SDO slots.
pub(crate) const TX_CAPACITY: usize = 2 * MAX_AXES + 16;
/// Frames one cycle may receive before the rest waits for the next.
pub(crate) const RX_CAPACITY: usize = 4096;
/// SDO/NMT frames sent per cycle after the PDOs (the budget's reserved slots).
pub(crate) const SDO_PER_CYCLE: usize = 2;

/// Virtual time: cycles without a Modbus answer before the exchange counts as timed out.
pub const MODBUS_TIMEOUT_CYCLES: u32 = 5;

/// How to run.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// How long (machine time); `None` until Ctrl-C.
    pub duration: Option<Duration>,
    /// Virtual time (as fast as possible, deterministic) instead of real time.
    pub virtual_time: bool,
    /// Print the live status this often (machine time); `None` for none.
    pub status_every: Option<Duration>,
    /// The script.
    pub script: ScriptOptions,
    /// Publish the machine over shared memory under this prefix (`shm-api`); `None`: not at
    /// all.
    pub shm: Option<String>,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            duration: Some(Duration::from_secs(10)),
            virtual_time: false,
            status_every: Some(Duration::from_millis(500)),
            script: ScriptOptions {
                chains: true,
                home: true,
            },
            shm: None,
        }
    }
}

/// What a run did.
#[derive(Clone, Debug, Default)]
pub struct Summary {
    /// Cycles run.
    pub cycles: u64,
    /// Machine time from the first cycle to the last.
    pub machine_time: Duration,
    /// Wall time of the run.
    pub wall: Duration,
    /// Frames the coordinator sent.
    pub frames_sent: u64,
    /// Frames on the bus (all nodes).
    pub frames_on_bus: u64,
    /// SYNC frames on the bus (whoever sent them).
    pub syncs_on_bus: u64,
    /// Bus load over the run, percent (worst-case stuffed frame lengths).
    pub bus_load_percent: f64,
    /// Cycle step compute time, ns: median, p99, max.
    pub step_ns: (u64, u64, u64),
    /// Real time: wake-up lateness, ns: median, p99, max.
    pub wake_late_ns: (u64, u64, u64),
    /// Real time: cycles skipped because a deadline had long passed.
    pub skipped_cycles: u64,
    /// Nodes that failed to boot, with the reason.
    pub boot_failures: Vec<String>,
    /// Faults raised (axis name, reason).
    pub faults: Vec<(String, FaultReason)>,
    /// Chain laps completed.
    pub laps: u64,
    /// Records reached.
    pub records_reached: u64,
    /// Commands the script sent that were refused.
    pub refused: u64,
    /// Frames the bus refused to queue, and received frames dropped for want of room.
    pub frames_lost: (u64, u64),
    /// Modbus answers that came late.
    pub late_modbus: u64,
    /// FNV-1a hash of every frame on the bus with its time (virtual time: reproducible).
    pub frame_hash: u64,
    /// Per axis: name, unit, final position in units, state.
    pub axes: Vec<(String, String, f64, AxisState)>,
    /// The script's last phase.
    pub phase: Option<Phase>,
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "summary: {} cycles, {:.3} s machine time in {:.3} s wall",
            self.cycles,
            self.machine_time.as_secs_f64(),
            self.wall.as_secs_f64()
        )?;
        writeln!(
            f,
            "  bus: {} frames ({} sent by the coordinator), load {:.1} %",
            self.frames_on_bus, self.frames_sent, self.bus_load_percent
        )?;
        if self.frames_lost != (0, 0) {
            writeln!(
                f,
                "  LOST FRAMES: {} refused by the bus on sending, {} dropped on receiving",
                self.frames_lost.0, self.frames_lost.1
            )?;
        }
        writeln!(
            f,
            "  cycle step: median {} ns, p99 {} ns, max {} ns",
            self.step_ns.0, self.step_ns.1, self.step_ns.2
        )?;
        if self.wake_late_ns.2 > 0 || self.skipped_cycles > 0 {
            writeln!(
                f,
                "  wake-up lateness: median {} us, p99 {} us, max {} us; {} cycles skipped",
                self.wake_late_ns.0 / 1000,
                self.wake_late_ns.1 / 1000,
                self.wake_late_ns.2 / 1000,
                self.skipped_cycles
            )?;
        }
        writeln!(
            f,
            "  chains: {} laps, {} records reached; {} refused commands; {} late Modbus answers",
            self.laps, self.records_reached, self.refused, self.late_modbus
        )?;
        for b in &self.boot_failures {
            writeln!(f, "  boot failed: {b}")?;
        }
        for (a, r) in &self.faults {
            writeln!(f, "  fault: {a}: {}", describe(*r))?;
        }
        for (name, unit, pos, state) in &self.axes {
            writeln!(f, "  axis {name}: {pos:.3} {unit}, {state:?}")?;
        }
        write!(f, "  frame hash {:016x}", self.frame_hash)
    }
}

/// A fault reason in words.
pub fn describe(r: FaultReason) -> String {
    match r {
        FaultReason::None => "none".into(),
        FaultReason::HeartbeatLost => "heartbeat lost".into(),
        FaultReason::GuardingLost => "node guarding lost".into(),
        FaultReason::Emcy(c) => format!("EMCY {c:04X}h"),
        FaultReason::FollowingError { error, limit } => {
            format!("following error {error} inc > {limit} inc")
        }
        FaultReason::DriveFault(c) => format!("drive fault {c:04X}h"),
        FaultReason::ModbusTimeout => "Modbus TCP timeout".into(),
        FaultReason::LateTpdo(n) => format!("no TPDO for {n} cycles"),
        FaultReason::BootFailed => "boot failed".into(),
    }
}

/// Why a run could not start.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The configuration cannot be run.
    #[error("{0}")]
    Config(String),
    /// A bus or device could not be opened.
    #[error("{0}")]
    Io(String),
}

/// FNV-1a over frames: id, data, time.
#[derive(Clone, Copy, Debug)]
pub struct FrameHash(u64);

impl Default for FrameHash {
    fn default() -> Self {
        FrameHash(0xcbf2_9ce4_8422_2325)
    }
}

impl FrameHash {
    fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 ^= u64::from(x);
            self.0 = self.0.wrapping_mul(0x100_0000_01b3);
        }
    }
    /// Adds one frame.
    pub fn add(&mut self, f: &Frame) {
        self.bytes(&f.raw_id().to_le_bytes());
        self.bytes(&[f.dlc(), u8::from(f.is_remote())]);
        self.bytes(f.data());
        self.bytes(&f.timestamp().as_nanos().to_le_bytes());
    }
    /// The hash.
    pub fn value(&self) -> u64 {
        self.0
    }
}

/// What the status display needs of the cycle, copied without allocation (so the cycle thread
/// can hand it to the printing thread through a queue).
#[derive(Clone, Debug)]
pub struct Snapshot {
    /// The cycle number.
    pub cycle: u64,
    /// Machine time since the start.
    pub t: Duration,
    /// Per axis.
    pub axes: heapless::Vec<AxisStatus, MAX_AXES>,
    /// Per group.
    pub groups: heapless::Vec<GroupStatus, MAX_GROUPS>,
}

impl Snapshot {
    /// Copies the cycle's published state.
    pub fn take<const A: usize, const G: usize>(c: &Cycle<'_, A, G>, t: Duration) -> Snapshot {
        let mut s = Snapshot {
            cycle: c.cycle(),
            t,
            axes: heapless::Vec::new(),
            groups: heapless::Vec::new(),
        };
        for a in 0..c.axis_count() as AxisId {
            if let Some(st) = c.axis_status(a) {
                let _ = s.axes.push(st);
            }
        }
        for g in 0..c.group_count() as GroupId {
            if let Some(st) = c.group_status(g) {
                let _ = s.groups.push(st);
            }
        }
        s
    }
}

/// One status line per axis (and one per group).
pub fn status_lines(plan: &MachinePlan, snap: &Snapshot) -> String {
    let mut s = format!("t={:8.3}s cycle {:8}\n", snap.t.as_secs_f64(), snap.cycle);
    for (a, st) in plan.axes.iter().zip(&snap.axes) {
        let fb = st.feedback;
        let mode = format!("{:?}", st.mode);
        let _ = writeln!(
            s,
            "  {:<8} {:<8} {:<13} pos {:>10.3} {:<3} set {:>10.3}{}{}",
            a.name,
            format!("{:?}", fb.state),
            mode.split_whitespace().next().unwrap_or(""),
            fb.position as f64 / a.scale,
            a.unit,
            st.setpoint as f64 / a.scale,
            if fb.homed { " homed" } else { "" },
            if st.fault != FaultReason::None {
                format!("  FAULT: {}", describe(st.fault))
            } else {
                String::new()
            }
        );
    }
    for ((name, _, _), gs) in plan.groups.iter().zip(&snap.groups) {
        let _ = writeln!(
            s,
            "  group {:<8} chain {:?} record {} RC1={} RCC={} move {:?} override {} %",
            name,
            gs.chain.state,
            gs.chain.active.map_or("-".into(), |r| r.to_string()),
            u8::from(gs.chain.rc1),
            u8::from(gs.chain.rcc),
            gs.motion,
            gs.override_percent
        );
    }
    s
}

/// A cycle and the inputs of one of its steps, for replay (benchmarks, determinism checks).
#[derive(Clone, Debug)]
pub struct Captured<'t> {
    /// The cycle before the step.
    pub cycle: Box<MachineCycle<'t>>,
    /// The frames received for the step.
    pub frames: Vec<Frame>,
    /// The Modbus images for the step.
    pub modbus: Vec<ModbusInput>,
    /// The step's SYNC time.
    pub now: Instant,
}

/// The per-cycle work shared by both clocks: everything the cycle thread does between
/// receiving and sending. Allocation-free after [`CycleCore::new`].
pub struct CycleCore<'t> {
    /// The cycle.
    pub cycle: Box<MachineCycle<'t>>,
    rx: Vec<Frame>,
    tx: Vec<Frame>,
    modbus_in: Vec<ModbusInput>,
    modbus_out: Vec<Image>,
    step_ns: Histogram<u64>,
    /// Frames sent by the coordinator.
    pub frames_sent: u64,
    /// Received frames dropped because more than [`RX_CAPACITY`] arrived in one cycle.
    pub rx_dropped: u64,
    /// Frames the bus refused to queue (a full transmit queue, bus-off).
    pub tx_refused: u64,
    /// Frames received.
    pub frames_received: u64,
    /// The last step's compute time, ns.
    pub last_step_ns: u64,
}

impl std::fmt::Debug for CycleCore<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CycleCore").finish_non_exhaustive()
    }
}

impl<'t> CycleCore<'t> {
    /// The cycle of `plan`, with every buffer allocated and the Modbus axes online.
    pub fn new(plan: &'t MachinePlan) -> Result<CycleCore<'t>, RunError> {
        let axes: Vec<_> = plan.axes.iter().map(|a| a.setup).collect();
        let groups: Vec<_> = plan
            .groups
            .iter()
            .map(|(_, g, t)| (g.clone(), &**t))
            .collect();
        let mut cycle = Box::new(
            MachineCycle::new(plan.cycle, &axes, &groups)
                .map_err(|e| RunError::Config(e.to_string()))?,
        );
        let slots = plan
            .axes
            .iter()
            .filter(|a| matches!(a.setup.transport, Transport::Modbus { .. }))
            .count();
        // Modbus axes need no boot: they are online from the start (the time only matters to
        // the guarding of CANopen axes).
        for (i, a) in plan.axes.iter().enumerate() {
            if matches!(a.setup.transport, Transport::Modbus { .. }) {
                cycle.set_online(i as AxisId, true, Instant::ZERO);
            }
        }
        Ok(CycleCore {
            cycle,
            rx: Vec::with_capacity(RX_CAPACITY),
            tx: vec![Frame::std8(0, [0; 8]); TX_CAPACITY],
            modbus_in: vec![ModbusInput::default(); slots],
            modbus_out: vec![Image::default(); slots],
            step_ns: Histogram::new_with_bounds(1, 1_000_000_000, 3)
                .map_err(|e| RunError::Config(e.to_string()))?,
            frames_sent: 0,
            rx_dropped: 0,
            tx_refused: 0,
            frames_received: 0,
            last_step_ns: 0,
        })
    }

    /// A copy of the cycle and of the inputs of its next step.
    pub fn capture(&self, now: Instant) -> Captured<'t> {
        Captured {
            cycle: self.cycle.clone(),
            frames: self.rx.clone(),
            modbus: self.modbus_in.clone(),
            now,
        }
    }

    /// Takes a received frame for the next step.
    pub fn receive(&mut self, f: Frame) {
        if self.rx.len() < RX_CAPACITY {
            self.rx.push(f);
        } else {
            self.rx_dropped += 1;
        }
    }

    /// The counters the shared-memory state carries.
    pub fn counters(&self, skipped: u64, wake_late_us: u32) -> crate::runtime::shm::Counters {
        crate::runtime::shm::Counters {
            frames_sent: self.frames_sent,
            frames_received: self.frames_received,
            tx_refused: self.tx_refused,
            rx_dropped: self.rx_dropped,
            skipped_cycles: skipped,
            step_ns: self.last_step_ns.min(u64::from(u32::MAX)) as u32,
            wake_late_us,
        }
    }

    /// Sets a Modbus slot's input for the next step.
    pub fn modbus_input(&mut self, slot: usize, m: ModbusInput) {
        if let Some(s) = self.modbus_in.get_mut(slot) {
            *s = m;
        }
    }

    /// A Modbus slot's output of the last step.
    pub fn modbus_output(&self, slot: usize) -> Image {
        self.modbus_out.get(slot).copied().unwrap_or_default()
    }

    /// One step at `now`; returns the frames to send, in order.
    pub fn iterate(&mut self, now: Instant) -> &[Frame] {
        let t0 = monotonic_now();
        let mut out = CycleOutput {
            frames: &mut self.tx,
            len: 0,
            overflow: 0,
            modbus: &mut self.modbus_out,
        };
        self.cycle.step(
            &CycleInput {
                now,
                frames: &self.rx,
                modbus: &self.modbus_in,
            },
            &mut out,
        );
        let len = out.len;
        let dt = monotonic_now().saturating_duration_since(t0).as_nanos() as u64;
        let _ = self.step_ns.record(dt.max(1));
        self.last_step_ns = dt;
        self.frames_received += self.rx.len() as u64;
        self.rx.clear();
        for m in &mut self.modbus_in {
            m.fresh = false;
        }
        self.frames_sent += len as u64;
        &self.tx[..len]
    }

    /// Step time: median, p99, max, ns.
    pub fn step_figures(&self) -> (u64, u64, u64) {
        let h = &self.step_ns;
        (h.value_at_quantile(0.5), h.value_at_quantile(0.99), h.max())
    }
}

/// Queues `frames` on `port`; returns how many the bus refused.
pub fn send_all<B: Bus>(port: &mut B, frames: &[Frame]) -> u64 {
    let mut refused = 0;
    for f in frames {
        if port.send(f).is_err() {
            refused += 1;
        }
    }
    refused
}

/// The axis on a CAN node.
pub fn axis_of_node(plan: &MachinePlan, node: u8) -> Option<AxisId> {
    plan.axes
        .iter()
        .position(|a| a.setup.transport == Transport::Can { node })
        .map(|i| i as AxisId)
}

/// Runs `cfg`'s machine with simulated drives.
pub fn run(cfg: &Config, opts: &RunOptions, out: &mut dyn Write) -> Result<Summary, RunError> {
    let plan = crate::runtime::plan::plan(cfg).map_err(RunError::Config)?;
    if let Some((name, BusKind::Socketcan, _)) = &plan.bus {
        // Opening the interface tells the user exactly why it cannot work here.
        drivers::can::socketcan::SocketCanBus::open(name)
            .map_err(|e| RunError::Io(e.to_string()))?;
        return Err(RunError::Io(format!(
            "bus {name}: running real drives over SocketCAN is not wired into `run` yet; use kind = \"virtual\""
        )));
    }
    if opts.virtual_time {
        run_virtual(&plan, opts, out)
    } else {
        crate::runtime::realtime::run_real(&plan, opts, out)
    }
}

/// Virtual time: the drives, the bus and the cycle advance in lockstep on one thread, cycle by
/// cycle. Deterministic: the same plan and the same commands give the same frames, bit for bit.
pub struct VirtualRun<'p> {
    plan: &'p MachinePlan,
    /// The bus (for fault injection in tests).
    pub bus: VirtualBus,
    port: VirtualPort,
    monitor: VirtualPort,
    /// The simulated CANopen drives.
    pub sims: SimBus,
    /// The simulated CMMO-STs, by Modbus slot.
    pub cmmo: Vec<(usize, InMemoryCmmo)>,
    modbus_missed: Vec<u32>,
    boot: BootSequencer,
    reported: usize,
    /// The cycle and its buffers.
    pub core: CycleCore<'p>,
    /// The demo script (a built-in client).
    pub script: Script,
    /// What happened so far.
    pub summary: Summary,
    hash: FrameHash,
    busy: Duration,
    bitrate: u32,
    t0: Instant,
    k: u64,
    ending: bool,
    next_status: Option<Instant>,
    status_every: Option<Duration>,
    status_lines_printed: usize,
    tty: bool,
    /// Every event of the cycle, as well, while set (tests).
    watch: Option<Vec<Event>>,
    /// The shared-memory sides (state publisher; command server and events), if published.
    shm: Option<(StateSide, ServiceSide)>,
    /// SYNC-consumer mode: the SYNC being taken, frames after it, frames for the next cycle.
    held: Option<Frame>,
    later: Vec<Frame>,
    pending_rx: Vec<Frame>,
    /// SYNC-consumer mode: SYNCs received, and periods that passed without one.
    pub synced: u64,
    /// See [`VirtualRun::synced`].
    pub missed_syncs: u64,
    /// When set, the next step keeps a copy of the cycle and its inputs right before the step
    /// in [`VirtualRun::captured`] (benchmarks replay it) and clears the flag.
    pub capture: bool,
    /// The copy [`VirtualRun::capture`] asked for.
    pub captured: Option<Captured<'p>>,
    /// Called with `true` right before the cycle thread's work of a cycle (the script's
    /// commands and the step) and with `false` right after: tests count allocations there.
    pub probe: Option<fn(bool)>,
}

impl std::fmt::Debug for VirtualRun<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VirtualRun")
            .field("cycle", &self.k)
            .finish_non_exhaustive()
    }
}

impl<'p> VirtualRun<'p> {
    /// Builds the bus, the simulated drives and the cycle; nothing has run yet.
    pub fn new(plan: &'p MachinePlan, opts: &RunOptions) -> Result<VirtualRun<'p>, RunError> {
        let bitrate = plan.bus.as_ref().map_or(1_000_000, |b| b.2);
        let bus = VirtualBus::new(VirtualBusConfig {
            bitrate,
            clock: ClockMode::Virtual,
            rx_capacity: RX_CAPACITY,
            tx_capacity: TX_CAPACITY,
            ..VirtualBusConfig::default()
        })
        .map_err(|e| RunError::Io(e.to_string()))?;
        let t0 = bus.now();
        let port = bus.attach("coordinator");
        let monitor = bus.attach_monitor("monitor");
        let sims = SimBus::build(&bus, plan, t0).map_err(RunError::Io)?;
        let mut cmmo = Vec::new();
        for a in &plan.axes {
            if let Transport::Modbus { slot } = a.setup.transport {
                cmmo.push((
                    usize::from(slot),
                    InMemoryCmmo::new(t0).map_err(RunError::Io)?,
                ));
            }
        }
        let plans: Vec<_> = plan.axes.iter().filter_map(|a| a.boot.clone()).collect();
        let boot = BootSequencer::new(plans, t0);
        let core = CycleCore::new(plan)?;
        let shm = match &opts.shm {
            Some(prefix) => {
                let _ = shm_api::publisher::cleanup_dead_nodes();
                let info = StaticInfo::new(plan, true);
                Some((
                    StateSide::create(prefix, info.clone()).map_err(RunError::Io)?,
                    ServiceSide::create(prefix, info).map_err(RunError::Io)?,
                ))
            }
            None => None,
        };
        Ok(VirtualRun {
            plan,
            bus,
            port,
            monitor,
            sims,
            modbus_missed: vec![0; cmmo.len()],
            cmmo,
            boot,
            reported: 0,
            core,
            script: Script::new(opts.script, t0),
            summary: Summary::default(),
            hash: FrameHash::default(),
            busy: Duration::ZERO,
            bitrate,
            t0,
            k: 0,
            ending: false,
            next_status: opts.status_every.map(|d| t0 + d),
            status_every: opts.status_every,
            status_lines_printed: 0,
            tty: out_is_tty(),
            capture: false,
            captured: None,
            watch: None,
            shm,
            held: None,
            later: Vec::with_capacity(RX_CAPACITY),
            pending_rx: Vec::with_capacity(RX_CAPACITY),
            synced: 0,
            missed_syncs: 0,
            probe: None,
        })
    }

    /// The time of the next cycle's SYNC (producer mode: the coordinator's schedule; consumer
    /// mode: when the external producer is due to send it).
    pub fn now(&self) -> Instant {
        let k = if self.plan.cycle.sync_producer {
            self.k
        } else {
            self.k + 1
        };
        self.t0 + self.plan.period * (k as u32)
    }

    /// Machine time since the start.
    pub fn elapsed(&self) -> Duration {
        self.now() - self.t0
    }

    /// Cycles run.
    pub fn cycles(&self) -> u64 {
        self.k
    }

    /// Whether the boot has finished (every CANopen node has a report).
    pub fn booted(&self) -> bool {
        self.boot.is_finished()
    }

    /// Asks the script for the orderly end (stop, disable).
    pub fn shut_down(&mut self) {
        self.ending = true;
        self.script.shut_down();
    }

    fn drain_monitor(&mut self) {
        while let Ok(Some(f)) = self.monitor.try_recv() {
            self.hash.add(&f);
            self.summary.frames_on_bus += 1;
            self.summary.syncs_on_bus += u64::from(f.cob_id() == Some(0x080));
            self.busy += frame_duration(&f, self.bitrate);
        }
    }

    /// Runs one cycle: the drives up to this SYNC, receive, boot, Modbus, script, step, send.
    /// Events are noted in the summary and printed to `out`.
    pub fn step(&mut self, out: &mut dyn Write) {
        let plan = self.plan;
        let now = if plan.cycle.sync_producer {
            let now = self.now();
            self.sims.run_until(&self.bus, now);
            self.drain_monitor();
            while let Ok(Some(f)) = self.port.try_recv() {
                self.boot.handle_frame(&f, f.timestamp());
                self.core.receive(f);
            }
            now
        } else {
            self.until_sync()
        };
        self.boot.handle_timeout(now);
        for r in &self.boot.reports()[self.reported..] {
            report_boot(plan, r, out, &mut self.summary);
            if let Some(a) = axis_of_node(plan, r.node.get()) {
                self.core.cycle.set_online(a, r.result.is_ok(), now);
            }
        }
        self.reported = self.boot.reports().len();
        for (i, (slot, dev)) in self.cmmo.iter_mut().enumerate() {
            let o = self.core.modbus_output(*slot).data;
            let answer = dev.exchange(&o, now);
            let missed = &mut self.modbus_missed[i];
            *missed = if answer.is_some() {
                0
            } else {
                missed.saturating_add(1)
            };
            self.core.modbus_input(
                *slot,
                ModbusInput {
                    image: answer
                        .and_then(|a| Image::from_slice(&a))
                        .unwrap_or_default(),
                    fresh: answer.is_some(),
                    late_cycles: 0,
                    lost: *missed >= MODBUS_TIMEOUT_CYCLES,
                },
            );
        }
        if let Some(p) = self.probe {
            p(true);
        }
        self.script
            .poll(&mut self.core.cycle, self.boot.is_finished(), now);
        if std::mem::take(&mut self.capture) {
            self.captured = Some(self.core.capture(now));
        }
        let frames = self.core.iterate(now);
        if let Some(p) = self.probe {
            p(false);
        }
        let refused = send_all(&mut self.port, frames);
        self.core.tx_refused += refused;
        for _ in 0..SDO_PER_CYCLE {
            match self.boot.poll_transmit(now) {
                Some(f) => {
                    self.core.tx_refused += send_all(&mut self.port, &[f]);
                }
                None => break,
            }
        }
        if let Some((state, _)) = &mut self.shm {
            state.counters = self.core.counters(0, 0);
            state.publish(&self.core.cycle, now.as_nanos());
        }
        while let Some(e) = self.core.cycle.poll_event() {
            note_event(plan, &e, &mut self.summary, out);
            if let Some((_, svc)) = &mut self.shm {
                svc.event(&e);
            }
            if let Some(w) = &mut self.watch {
                w.push(e);
            }
        }
        if let Some(t) = self.next_status
            && now >= t
        {
            let text = status_lines(plan, &Snapshot::take(&self.core.cycle, now - self.t0));
            self.status_lines_printed =
                print_status(out, &text, self.tty, self.status_lines_printed);
            self.next_status = self.status_every.map(|d| t + d);
        }
        self.k += 1;
    }

    /// SYNC-consumer mode: runs the bus until the external producer's next SYNC has arrived,
    /// takes every frame up to it, and returns its time (the cycle's `now`). Frames after it
    /// wait for the next cycle, as they would on a real bus.
    fn until_sync(&mut self) -> Instant {
        for f in std::mem::take(&mut self.pending_rx) {
            self.boot.handle_frame(&f, f.timestamp());
            self.core.receive(f);
        }
        let due = self.now();
        // SYNC has the highest priority after NMT, but may wait for a frame on the wire.
        let mut until = due + Duration::from_micros(500);
        loop {
            self.sims.run_until(&self.bus, until);
            self.drain_monitor();
            while let Ok(Some(f)) = self.port.try_recv() {
                if self.held.is_some() {
                    self.later.push(f);
                    continue;
                }
                self.boot.handle_frame(&f, f.timestamp());
                if f.cob_id() == Some(0x080) {
                    self.held = Some(f);
                    self.synced += 1;
                } else {
                    self.core.receive(f);
                }
            }
            if let Some(sync) = self.held.take() {
                let now = sync.timestamp();
                // What arrived after the SYNC belongs to the next cycle.
                let later = std::mem::take(&mut self.later);
                self.pending_rx = later;
                return now;
            }
            // No SYNC: the producer is gone. Keep waiting, a period at a time (the cycle
            // does not run without SYNC; the drives' own supervision notices).
            self.missed_syncs += 1;
            until += self.plan.period;
        }
    }

    /// As [`VirtualRun::step`], and appends the cycle's events of this step to `events`.
    pub fn step_with_events(&mut self, out: &mut dyn Write, events: &mut Vec<Event>) {
        self.watch = Some(std::mem::take(events));
        self.step(out);
        *events = self.watch.take().unwrap_or_default();
    }

    /// Ends the run: lets the bus settle and fills the summary.
    pub fn finish(mut self, wall: Duration) -> Summary {
        let last = self.now();
        self.sims.run_until(&self.bus, last + self.plan.period);
        self.drain_monitor();
        let mut summary = std::mem::take(&mut self.summary);
        summary.cycles = self.k;
        summary.machine_time = last - self.t0;
        summary.wall = wall;
        summary.frames_sent = self.core.frames_sent;
        summary.bus_load_percent =
            100.0 * self.busy.as_secs_f64() / summary.machine_time.as_secs_f64().max(1e-9);
        summary.step_ns = self.core.step_figures();
        summary.frames_lost = (self.core.tx_refused, self.core.rx_dropped);
        summary.frame_hash = self.hash.value();
        finish_summary(self.plan, &self.core.cycle, &self.script, &mut summary);
        summary
    }
}

/// Virtual time: runs the script to its end (duration or Ctrl-C, then stop and disable).
pub fn run_virtual(
    plan: &MachinePlan,
    opts: &RunOptions,
    out: &mut dyn Write,
) -> Result<Summary, RunError> {
    let wall0 = std::time::Instant::now();
    let mut run = VirtualRun::new(plan, opts)?;
    say(
        out,
        &format!(
            "machine: {} axes, {} groups, cycle {} us, virtual time",
            plan.axes.len(),
            plan.groups.len(),
            plan.period.as_micros()
        ),
    );
    loop {
        let over = opts.duration.is_some_and(|d| run.elapsed() >= d);
        if (over || crate::runtime::rt::stop_flag().load(Ordering::Relaxed)) && !run.ending {
            run.shut_down();
        }
        run.step(out);
        if run.script.phase() == Phase::Done {
            break;
        }
    }
    Ok(run.finish(wall0.elapsed()))
}

/// Fills the per-axis part of the summary.
pub fn finish_summary<const A: usize, const G: usize>(
    plan: &MachinePlan,
    c: &Cycle<'_, A, G>,
    script: &Script,
    summary: &mut Summary,
) {
    summary.laps = script.laps;
    summary.refused = script.refused;
    summary.phase = Some(script.phase());
    summary.axes = plan
        .axes
        .iter()
        .enumerate()
        .filter_map(|(i, a)| {
            let s = c.axis_status(i as AxisId)?;
            Some((
                a.name.clone(),
                a.unit.clone(),
                s.feedback.position as f64 / a.scale,
                s.feedback.state,
            ))
        })
        .collect();
}

/// Prints a boot report and records a failure.
pub fn report_boot(plan: &MachinePlan, r: &BootReport, out: &mut dyn Write, summary: &mut Summary) {
    let name = axis_of_node(plan, r.node.get())
        .and_then(|a| plan.axes.get(usize::from(a)))
        .map_or("?", |a| a.name.as_str());
    match &r.result {
        Ok(()) => say(out, &format!("boot: axis {name}: {r}")),
        Err(_) => {
            say(out, &format!("boot FAILED: axis {name}: {r}"));
            summary.boot_failures.push(format!("axis {name}: {r}"));
        }
    }
}

/// Records one event in the summary; prints faults and chain ends.
pub fn note_event(plan: &MachinePlan, e: &Event, summary: &mut Summary, out: &mut dyn Write) {
    let axis = |a: AxisId| {
        plan.axes
            .get(usize::from(a))
            .map_or("?".into(), |x| x.name.clone())
    };
    let group = |g: GroupId| {
        plan.groups
            .get(usize::from(g))
            .map_or("?".into(), |x| x.0.clone())
    };
    match *e {
        Event::Fault {
            cycle,
            axis: a,
            reason,
        } => {
            say(
                out,
                &format!(
                    "cycle {cycle}: FAULT axis {}: {}",
                    axis(a),
                    describe(reason)
                ),
            );
            summary.faults.push((axis(a), reason));
        }
        Event::Acknowledged { cycle, axis: a } => {
            say(
                out,
                &format!("cycle {cycle}: axis {} acknowledged", axis(a)),
            );
        }
        Event::RecordReached { .. } => summary.records_reached += 1,
        Event::ChainComplete {
            cycle,
            group: g,
            record,
        } => {
            summary.records_reached += 1;
            let _ = (cycle, g, record, group(g));
        }
        Event::ChainAborted {
            cycle,
            group: g,
            record,
        } => {
            say(
                out,
                &format!(
                    "cycle {cycle}: group {} chain aborted at record {record}",
                    group(g)
                ),
            );
        }
        Event::LateModbus { .. } => summary.late_modbus += 1,
        Event::Parameter {
            cycle,
            axis: a,
            pnu,
            sub,
            result,
        } => match result {
            Ok(v) => say(
                out,
                &format!("cycle {cycle}: axis {} PNU {pnu}:{sub} = {v}", axis(a)),
            ),
            Err(n) => say(
                out,
                &format!(
                    "cycle {cycle}: axis {} PNU {pnu}:{sub} refused: error {n}",
                    axis(a)
                ),
            ),
        },
        Event::AxisState { .. } => {}
    }
}

pub(crate) fn say(out: &mut dyn Write, s: &str) {
    let _ = writeln!(out, "{s}");
}

pub(crate) fn out_is_tty() -> bool {
    std::io::stdout().is_terminal()
}

/// Prints a status block; on a terminal it overwrites the previous one.
pub fn print_status(out: &mut dyn Write, text: &str, tty: bool, previous_lines: usize) -> usize {
    if tty && previous_lines > 0 {
        let _ = write!(out, "\x1b[{previous_lines}A\x1b[J");
    }
    let _ = write!(out, "{text}");
    let _ = out.flush();
    text.lines().count()
}
