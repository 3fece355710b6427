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
use std::time::Duration;

use drivers::can::bit_timing::frame_duration;
use drivers::can::{Bus, ClockMode, Frame, VirtualBus, VirtualBusConfig, VirtualPort};
use drivers::time::{Instant, monotonic_now};
use hdrhistogram::Histogram;

use crate::axis::{AxisState, Image};
use crate::command::{Answer, Request};
use crate::command::{AxisId, GroupId};
use crate::config::{BusKind, Config};
use crate::cycle::{
    AxisStatus, BusFrame, Cycle, CycleInput, CycleOutput, GroupStatus, ModbusInput, Transport,
};
use crate::event::Event;
use crate::fault::FaultReason;
use crate::profile::MoveState;
use crate::records::{ChainState, ChainStatus};
use crate::runtime::boot::FailureDetail;
use crate::runtime::capture::InlineCapture;
use crate::runtime::cycle_loop::{CycleIo, CycleLoop, Wake};
use crate::runtime::nodes::{NodeReport, NodeStatus, Nodes};
use crate::runtime::plan::{MAX_AXES, MAX_BUSES, MAX_GROUPS, MachinePlan};
use crate::runtime::script::{Phase, Script, ScriptOptions};
use crate::runtime::shm::{ServiceSide, StateSide, StaticInfo};
use crate::runtime::sim::{InMemoryCmmo, SimBus, SimDrive};

/// The cycle type of a configured machine.
pub type MachineCycle<'t> = Cycle<'t, MAX_AXES, MAX_GROUPS>;

/// Frames one cycle may send: a SYNC per bus; RPDO1, RPDO2 (the FPC) and a guarding poll per
/// axis; SDO slots.
pub const TX_CAPACITY: usize = 3 * MAX_AXES + MAX_BUSES + 16;
/// Frames one cycle may receive before the rest waits for the next.
pub const RX_CAPACITY: usize = 4096;

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
    /// Write a candump log and a pcap of every bus into this directory.
    pub capture: Option<std::path::PathBuf>,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            duration: Some(Duration::from_secs(10)),
            virtual_time: false,
            status_every: Some(Duration::from_millis(500)),
            script: ScriptOptions {
                demo: true,
                chains: true,
                home: true,
            },
            shm: None,
            capture: None,
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
    /// Frames on the buses (all nodes), where the coordinator could see them.
    pub frames_on_bus: u64,
    /// SYNC frames on the buses (whoever sent them).
    pub syncs_on_bus: u64,
    /// Per bus: what crossed it.
    pub buses: Vec<BusFigures>,
    /// Cycle step compute time, ns: median, p99, max.
    pub step_ns: (u64, u64, u64),
    /// Real time: wake-up lateness, ns: median, p99, max.
    pub wake_late_ns: (u64, u64, u64),
    /// Real time: cycles skipped because a deadline had long passed.
    pub skipped_cycles: u64,
    /// Real time: overruns (stalls of the coordinator itself) and the longest, ns.
    pub overruns: (u64, u64),
    /// Drives refused (wrong device, configuration refused), with the reason.
    pub boot_failures: Vec<String>,
    /// Drives that were not there when first looked for (waited for, and booted if they
    /// appeared later).
    pub waiting: Vec<String>,
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
    /// Per axis: name, unit and increments per unit (to say faults in the axis's unit).
    pub units: Vec<(String, String, crate::units::Scale)>,
    /// What the capture wrote, a line per bus.
    pub captures: Vec<String>,
}

/// One bus's traffic over a run.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BusFigures {
    /// How the user names the bus.
    pub label: String,
    /// Frames seen on it (every sender).
    pub frames: u64,
    /// Its load, percent of the time (worst-case stuffed frame lengths).
    pub load_percent: f64,
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
            "  frames: {} sent by the coordinator, {} on the buses it watched",
            self.frames_sent, self.frames_on_bus
        )?;
        for b in &self.buses {
            writeln!(
                f,
                "  bus {}: {} frames, load {:.1} %",
                b.label, b.frames, b.load_percent
            )?;
        }
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
        if self.overruns.0 > 0 {
            writeln!(
                f,
                "  overruns of the coordinator itself: {}, the longest {:.1} ms (not counted against the drives)",
                self.overruns.0,
                self.overruns.1 as f64 / 1e6
            )?;
        }
        writeln!(
            f,
            "  chains: {} laps, {} records reached; {} refused commands; {} late Modbus answers",
            self.laps, self.records_reached, self.refused, self.late_modbus
        )?;
        for c in &self.captures {
            writeln!(f, "  capture: {c}")?;
        }
        for b in &self.waiting {
            writeln!(f, "  waited for: {b}")?;
        }
        for b in &self.boot_failures {
            writeln!(f, "  refused: {b}")?;
        }
        for (a, r) in &self.faults {
            let text = match self.units.iter().find(|u| u.0 == *a) {
                Some((_, unit, scale)) => describe_in(*r, unit, *scale),
                None => describe(*r),
            };
            writeln!(f, "  fault: {a}: {text}")?;
        }
        for (name, unit, pos, state) in &self.axes {
            writeln!(f, "  axis {name}: {pos:.3} {unit}, {}", state)?;
        }
        write!(f, "  frame hash {:016x}", self.frame_hash)
    }
}

/// A fault reason in words (a following error in increments).
pub fn describe(r: FaultReason) -> String {
    r.to_string()
}

/// A fault reason in words, a following error in the axis's own unit (with the increments the
/// drive counts).
pub fn describe_in(r: FaultReason, unit: &str, scale: crate::units::Scale) -> String {
    match r {
        FaultReason::FollowingError { error, limit } => format!(
            "following error {:.3} {unit} > limit {:.3} {unit} ({error} inc > {limit} inc)",
            scale.to_units(error),
            scale.to_units(limit)
        ),
        _ => r.to_string(),
    }
}

/// A group's move in words: "no move", "move running", "move holding", "move arrived", ...
pub fn group_move_text(m: Option<MoveState>) -> &'static str {
    match m {
        None => "no move",
        Some(MoveState::Moving) => "move running",
        Some(MoveState::Holding) => "move holding",
        Some(MoveState::QuickStopping) => "move quick-stopping",
        Some(MoveState::Stopped) => "move stopped on its path",
        Some(MoveState::Done) => "move arrived",
    }
}

/// A chain's state in words, with its record: "chain idle", "record 3 moving", "record 3
/// waiting for its step condition", "chain complete at record 13", "chain stopped at record
/// 10" (an abort: by a stop, a fault, or the run's end).
pub fn chain_text(c: &ChainStatus) -> String {
    let at = |r: Option<u16>| r.map_or_else(|| "?".to_owned(), |r| r.to_string());
    match c.state {
        ChainState::Idle => "chain idle".into(),
        ChainState::Delay => format!("record {} in its start delay", at(c.active)),
        ChainState::Moving => format!("record {} moving", at(c.active)),
        ChainState::Waiting => format!("record {} waiting for its step condition", at(c.active)),
        ChainState::Complete => format!("chain complete at record {}", at(c.record)),
        ChainState::Aborted => format!("chain stopped at record {}", at(c.record)),
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

/// One status line per axis (and one per group), in words and the axes' units: the drive's
/// state, what the axis does (the admission table's activity), position and setpoint; the
/// group's activity, its chain, its move and override.
pub fn status_lines(plan: &MachinePlan, snap: &Snapshot) -> String {
    let mut s = format!("t={:8.3}s cycle {:8}\n", snap.t.as_secs_f64(), snap.cycle);
    for (a, st) in plan.axes.iter().zip(&snap.axes) {
        let fb = st.feedback;
        let _ = writeln!(
            s,
            "  {:<8} {:<9} {:<15} pos {:>10.3} {:<3} set {:>10.3} {}{}{}",
            a.name,
            fb.state.name(),
            st.activity.name(),
            a.scale.to_units(fb.position),
            a.unit,
            a.scale.to_units(st.setpoint),
            a.unit,
            if fb.homed { " homed" } else { "" },
            if st.fault != FaultReason::None {
                format!("  FAULT: {}", describe_in(st.fault, &a.unit, a.scale))
            } else {
                String::new()
            }
        );
    }
    for ((name, _, _), gs) in plan.groups.iter().zip(&snap.groups) {
        let mut flags = String::new();
        if gs.chain.rc1 {
            flags.push_str(", RC1");
        }
        if gs.chain.rcc {
            flags.push_str(", RCC");
        }
        let _ = writeln!(
            s,
            "  group {:<8} {:<18} {}{flags}; {}; override {} %",
            name,
            format!("{}:", gs.activity.name()),
            chain_text(&gs.chain),
            group_move_text(gs.motion),
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
    pub frames: Vec<BusFrame>,
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
    rx: Vec<BusFrame>,
    tx: Vec<BusFrame>,
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
        let cycle = Box::new(
            MachineCycle::new(plan.cycle, &axes, &groups)
                .map_err(|e| RunError::Config(e.to_string()))?,
        );
        let slots = plan
            .axes
            .iter()
            .filter(|a| matches!(a.setup.transport, Transport::Modbus { .. }))
            .count();
        // Modbus axes come online with their first answer (`CycleLoop`).
        Ok(CycleCore {
            cycle,
            rx: Vec::with_capacity(RX_CAPACITY),
            tx: vec![BusFrame::new(0, Frame::std8(0, [0; 8])); TX_CAPACITY],
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

    /// Takes a received frame for the next step, in timestamp order (frames with equal times in
    /// arrival order). A `vbus:` bus delivers frames in the order their senders' processes got
    /// to sending them, and the CANopen services judge every node's deadlines at each frame's
    /// time: after a stall, one node's late-stamped heartbeat handled before another node's
    /// earlier one declared that node lost although its heartbeat was in the same batch.
    pub fn receive(&mut self, f: BusFrame) {
        if self.rx.len() < RX_CAPACITY {
            let t = f.frame.timestamp();
            // Frames come nearly in order: the place is almost always at the end.
            let at = self.rx.partition_point(|x| x.frame.timestamp() <= t);
            self.rx.insert(at, f);
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
    pub fn iterate(&mut self, now: Instant) -> &[BusFrame] {
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

/// Runs `cfg`'s machine: its buses opened as configured (simulated, `vbus:NAME`, SocketCAN),
/// its Modbus drives dialled (or simulated where the file says so), in real time; or, with
/// every drive simulated, in virtual time.
pub fn run(cfg: &Config, opts: &RunOptions, out: &mut dyn Write) -> Result<Summary, RunError> {
    let plan = crate::runtime::plan::plan(cfg).map_err(RunError::Config)?;
    if opts.virtual_time {
        if let Some(b) = plan.buses.iter().find(|b| b.kind != BusKind::Simulated) {
            return Err(RunError::Config(format!(
                "--virtual-time: bus {:?} is of kind \"{}\"; virtual time runs only machines whose drives are all simulated inside the coordinator (kind = \"simulated\"): drives in other processes or on a real bus keep their own clock",
                b.name, b.kind
            )));
        }
        if let Some(a) = plan.axes.iter().find(|a| !a.simulated) {
            return Err(RunError::Config(format!(
                "--virtual-time: axis {:?} dials its drive at {}; virtual time runs only simulated drives (set simulated = true on the axis, or run in real time)",
                a.name,
                a.modbus.as_deref().unwrap_or("?")
            )));
        }
        run_virtual(&plan, opts, out)
    } else {
        crate::runtime::realtime::run_real(&plan, opts, out)
    }
}

/// The virtual clock's side of the cycle iteration: the simulated drives of every bus
/// advanced in lockstep with the cycle (discrete-event), the drives' boot run inline, the
/// CMMO-STs' Modbus ADUs handed to their sessions in memory, client commands answered between
/// cycles. Deterministic: the same plan and the same commands give the same frames, bit for
/// bit.
pub struct VirtualIo<'p> {
    plan: &'p MachinePlan,
    /// The buses, one per configured bus (for fault injection in tests).
    pub buses: Vec<VirtualBus>,
    ports: Vec<VirtualPort>,
    monitors: Vec<VirtualPort>,
    /// The simulated CANopen drives, one set per bus.
    pub sims: Vec<SimBus>,
    /// The simulated CMMO-STs, by Modbus slot.
    pub cmmo: Vec<(usize, InMemoryCmmo)>,
    modbus_missed: Vec<u32>,
    nodes: Nodes,
    t0: Instant,
    k: u64,
    commands: Option<ServiceSide>,
    pending: Vec<(u64, shm_api::PendingCommand)>,
    next_tag: u64,
    /// What the run has to say (events, reports, status), printed after each step.
    text: Vec<u8>,
    /// What happened so far.
    pub summary: Summary,
    hash: FrameHash,
    busy: Vec<Duration>,
    frames: Vec<u64>,
    status_lines_printed: usize,
    tty: bool,
    /// Every event of the cycle, as well, while set (tests).
    watch: Option<Vec<Event>>,
    /// `--capture DIR`: the buses' frames as they pass the monitors.
    capture: Option<InlineCapture>,
    capture_dir: Option<std::path::PathBuf>,
    /// SYNC-consumer mode: the SYNC being taken, frames after it, frames for the next cycle.
    held: Option<Frame>,
    later: Vec<Frame>,
    pending_rx: Vec<Frame>,
    /// SYNC-consumer mode: SYNCs received.
    pub synced: u64,
    /// SYNC-consumer mode: periods that passed without a SYNC.
    pub missed_syncs: u64,
    /// The orderly end has begun (set before each step from the loop).
    ending: bool,
}

impl std::fmt::Debug for VirtualIo<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VirtualIo")
            .field("cycle", &self.k)
            .finish_non_exhaustive()
    }
}

impl VirtualIo<'_> {
    /// The simulated drive of an axis, on whichever bus it is.
    pub fn drive_mut(&mut self, axis: &str) -> Option<&mut SimDrive> {
        self.sims.iter_mut().find_map(|s| s.drive_mut(axis))
    }

    /// The bus of a simulated drive's axis.
    pub fn bus_of(&self, axis: &str) -> Option<&VirtualBus> {
        let i = self.plan.axis(axis)?;
        match self.plan.axes[i].setup.transport {
            Transport::Can { bus, .. } => self.buses.get(usize::from(bus)),
            Transport::Modbus { .. } => None,
        }
    }

    fn drain_monitors(&mut self) {
        for (b, m) in self.monitors.iter_mut().enumerate() {
            let bitrate = self.plan.buses[b].bitrate;
            while let Ok(Some(f)) = m.try_recv() {
                if let Some(c) = &mut self.capture {
                    c.write(b, &f);
                }
                self.hash.add(&f);
                self.frames[b] += 1;
                self.summary.syncs_on_bus += u64::from(f.cob_id() == Some(0x080));
                self.busy[b] += frame_duration(&f, bitrate);
            }
        }
    }

    fn take(&mut self, bus: usize, f: Frame, rx: &mut dyn FnMut(BusFrame)) {
        let bf = BusFrame::new(bus as u8, f);
        self.nodes.handle_frame(&bf, f.timestamp());
        rx(bf);
    }

    /// SYNC-consumer mode (one bus): runs the bus until the external producer's next SYNC has
    /// arrived, takes every frame up to it, and returns its time (the cycle's `now`). Frames
    /// after it wait for the next cycle, as they would on a real bus.
    fn until_sync(&mut self, rx: &mut dyn FnMut(BusFrame)) -> Instant {
        for f in std::mem::take(&mut self.pending_rx) {
            self.take(0, f, rx);
        }
        let due = self.t0 + self.plan.period * (self.k as u32 + 1);
        // SYNC has the highest priority after NMT, but may wait for a frame on the wire.
        let mut until = due + Duration::from_micros(500);
        loop {
            self.sims[0].run_until(&self.buses[0], until);
            self.drain_monitors();
            while let Ok(Some(f)) = self.ports[0].try_recv() {
                if self.held.is_some() {
                    self.later.push(f);
                    continue;
                }
                if f.cob_id() == Some(0x080) {
                    self.nodes.handle_frame(&BusFrame::new(0, f), f.timestamp());
                    self.held = Some(f);
                    self.synced += 1;
                } else {
                    self.take(0, f, rx);
                }
            }
            if let Some(sync) = self.held.take() {
                // What arrived after the SYNC belongs to the next cycle.
                self.pending_rx = std::mem::take(&mut self.later);
                return sync.timestamp();
            }
            // No SYNC: the producer is gone. Keep waiting, a period at a time (the cycle
            // does not run without SYNC; the drives' own supervision notices).
            self.missed_syncs += 1;
            until += self.plan.period;
        }
    }
}

impl CycleIo for VirtualIo<'_> {
    fn wait(&mut self, rx: &mut dyn FnMut(BusFrame)) -> Wake {
        let now = if self.plan.cycle.sync_producer {
            let now = self.t0 + self.plan.period * (self.k as u32);
            for (sims, bus) in self.sims.iter_mut().zip(&self.buses) {
                sims.run_until(bus, now);
            }
            self.drain_monitors();
            for b in 0..self.ports.len() {
                while let Ok(Some(f)) = self.ports[b].try_recv() {
                    self.take(b, f, rx);
                }
            }
            now
        } else {
            self.until_sync(rx)
        };
        self.nodes.handle_timeout(now);
        self.k += 1;
        Wake {
            now,
            late_ns: 0,
            skipped: 0,
        }
    }

    fn node_report(&mut self) -> Option<NodeReport> {
        let r = self.nodes.poll_report()?;
        report_node(self.plan, &r, &mut self.text, &mut self.summary);
        Some(r)
    }

    fn modbus_input(&mut self, _k: u64, slot: usize, last: &Image, now: Instant) -> ModbusInput {
        let Some(i) = self.cmmo.iter().position(|(s, _)| *s == slot) else {
            return ModbusInput::default();
        };
        let answer = self.cmmo[i].1.exchange(&last.data, now);
        let missed = &mut self.modbus_missed[i];
        *missed = if answer.is_some() {
            0
        } else {
            missed.saturating_add(1)
        };
        ModbusInput {
            image: answer
                .and_then(|a| Image::from_slice(&a))
                .unwrap_or_default(),
            fresh: answer.is_some(),
            late_cycles: 0,
            lost: *missed >= MODBUS_TIMEOUT_CYCLES,
        }
    }

    fn modbus_output(&mut self, _k: u64, _slot: usize, _output: &Image) {
        // The next cycle's exchange carries it (see `modbus_input`).
    }

    fn request(&mut self) -> Option<Request> {
        let side = self.commands.as_mut()?;
        loop {
            let (p, c) = side.receive()?;
            // A request that does not translate was answered by `receive`.
            let Ok(command) = c else { continue };
            let tag = self.next_tag;
            self.next_tag += 1;
            self.pending.push((tag, p));
            return Some(Request { tag, command });
        }
    }

    fn answer(&mut self, answer: Answer) {
        if let Some(i) = self.pending.iter().position(|(t, _)| *t == answer.tag) {
            let (_, p) = self.pending.swap_remove(i);
            let tag = p.request().tag;
            let _ = p.reply(&crate::runtime::shm::to_reply(tag, answer.reply));
        }
    }

    fn send(&mut self, f: &BusFrame) -> bool {
        self.ports
            .get_mut(usize::from(f.bus))
            .is_some_and(|p| p.send(&f.frame).is_ok())
    }

    fn service_frame(&mut self, now: Instant) -> Option<BusFrame> {
        self.nodes.poll_transmit(now)
    }

    fn event(&mut self, e: Event) {
        // The loop asks for the end before the step (the duration, or Ctrl-C seen in this
        // iteration): what the step aborts then is the end's own stop.
        let ending = self.ending
            || crate::runtime::rt::stop_flag().load(std::sync::atomic::Ordering::Relaxed);
        note_event(self.plan, &e, ending, &mut self.summary, &mut self.text);
        self.nodes.event(&e);
        if let Some(svc) = &mut self.commands {
            svc.event(&e);
        }
        if let Some(w) = &mut self.watch {
            w.push(e);
        }
    }

    fn status(&mut self, snapshot: Snapshot) {
        let text = status_lines(self.plan, &snapshot);
        self.status_lines_printed =
            print_status(&mut self.text, &text, self.tty, self.status_lines_printed);
    }
}

/// `coordinator run --virtual-time`: the cycle iteration on the virtual clock, one thread, as
/// fast as the machine allows.
pub struct VirtualRun<'p> {
    /// The cycle and its buffers.
    pub core: CycleCore<'p>,
    /// The iteration's state (the script, the schedule).
    pub lp: CycleLoop<'p>,
    /// The simulated machine around it.
    pub io: VirtualIo<'p>,
}

impl std::fmt::Debug for VirtualRun<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VirtualRun")
            .field("cycle", &self.lp.cycles())
            .finish_non_exhaustive()
    }
}

impl<'p> VirtualRun<'p> {
    /// Builds the buses, the simulated drives and the cycle; nothing has run yet. Every drive
    /// of `plan` must be simulated (see [`run`]).
    pub fn new(plan: &'p MachinePlan, opts: &RunOptions) -> Result<VirtualRun<'p>, RunError> {
        let mut buses = Vec::new();
        for b in &plan.buses {
            buses.push(
                VirtualBus::new(VirtualBusConfig {
                    bitrate: b.bitrate,
                    clock: ClockMode::Virtual,
                    rx_capacity: RX_CAPACITY,
                    tx_capacity: TX_CAPACITY,
                    ..VirtualBusConfig::default()
                })
                .map_err(|e| RunError::Io(format!("bus {}: {e}", b.name)))?,
            );
        }
        let t0 = buses.first().map_or(Instant::ZERO, |b| b.now());
        let ports = buses.iter().map(|b| b.attach("coordinator")).collect();
        let monitors = buses.iter().map(|b| b.attach_monitor("monitor")).collect();
        let mut sims = Vec::new();
        for (i, b) in buses.iter().enumerate() {
            sims.push(SimBus::build(b, plan, i, t0).map_err(RunError::Io)?);
        }
        let mut cmmo = Vec::new();
        for a in &plan.axes {
            if let Transport::Modbus { slot } = a.setup.transport {
                cmmo.push((
                    usize::from(slot),
                    InMemoryCmmo::new(t0).map_err(RunError::Io)?,
                ));
            }
        }
        let core = CycleCore::new(plan)?;
        let (state, commands) = match &opts.shm {
            Some(prefix) => {
                let _ = shm_api::publisher::cleanup_dead_nodes();
                let info = StaticInfo::new(plan, true);
                (
                    Some(StateSide::create(prefix, info.clone()).map_err(RunError::Io)?),
                    Some(ServiceSide::create(prefix, info).map_err(RunError::Io)?),
                )
            }
            None => (None, None),
        };
        let lp = CycleLoop::new(
            plan,
            Script::new(opts.script, t0),
            state,
            t0,
            None,
            opts.status_every,
        )?;
        let n = plan.buses.len();
        let capture = match &opts.capture {
            Some(dir) => {
                let names: Vec<String> = plan.buses.iter().map(|b| b.name.clone()).collect();
                Some(InlineCapture::create(dir, &names).map_err(RunError::Io)?)
            }
            None => None,
        };
        Ok(VirtualRun {
            core,
            lp,
            io: VirtualIo {
                plan,
                buses,
                ports,
                monitors,
                sims,
                modbus_missed: vec![0; cmmo.len()],
                cmmo,
                nodes: Nodes::new(plan, t0),
                t0,
                k: 0,
                commands,
                pending: Vec::new(),
                next_tag: 1,
                text: Vec::new(),
                summary: Summary::default(),
                hash: FrameHash::default(),
                busy: vec![Duration::ZERO; n],
                frames: vec![0; n],
                status_lines_printed: 0,
                tty: out_is_tty(),
                watch: None,
                capture,
                capture_dir: opts.capture.clone(),
                held: None,
                later: Vec::with_capacity(RX_CAPACITY),
                pending_rx: Vec::with_capacity(RX_CAPACITY),
                synced: 0,
                missed_syncs: 0,
                ending: false,
            },
        })
    }

    /// The time of the next cycle's SYNC (producer mode: the coordinator's schedule; consumer
    /// mode: when the external producer is due to send it).
    pub fn now(&self) -> Instant {
        let k = self.io.k + u64::from(!self.io.plan.cycle.sync_producer);
        self.io.t0 + self.io.plan.period * (k as u32)
    }

    /// Machine time since the start.
    pub fn elapsed(&self) -> Duration {
        self.now() - self.io.t0
    }

    /// Cycles run.
    pub fn cycles(&self) -> u64 {
        self.lp.cycles()
    }

    /// Whether every drive has had its first report.
    pub fn booted(&self) -> bool {
        self.lp.booted()
    }

    /// Asks the script for the orderly end (stop, disable).
    pub fn shut_down(&mut self) {
        self.lp.shut_down();
    }

    /// Runs one cycle: the drives up to this SYNC, receive, boot, Modbus, commands, script,
    /// step, send. Events, reports and status are printed to `out`.
    pub fn step(&mut self, out: &mut dyn Write) {
        self.io.ending = self.lp.ending();
        self.lp.iterate(&mut self.core, &mut self.io);
        if !self.io.text.is_empty() {
            let _ = out.write_all(&self.io.text);
            let _ = out.flush();
            self.io.text.clear();
        }
    }

    /// As [`VirtualRun::step`], and appends the cycle's events of this step to `events`.
    pub fn step_with_events(&mut self, out: &mut dyn Write, events: &mut Vec<Event>) {
        self.io.watch = Some(std::mem::take(events));
        self.step(out);
        *events = self.io.watch.take().unwrap_or_default();
    }

    /// Ends the run: lets the buses settle and fills the summary.
    pub fn finish(mut self, wall: Duration) -> Summary {
        let last = self.now();
        let plan = self.io.plan;
        for (sims, bus) in self.io.sims.iter_mut().zip(&self.io.buses) {
            sims.run_until(bus, last + plan.period);
        }
        self.io.drain_monitors();
        let mut summary = std::mem::take(&mut self.io.summary);
        summary.cycles = self.lp.cycles();
        summary.machine_time = last - self.io.t0;
        summary.wall = wall;
        summary.frames_sent = self.core.frames_sent;
        summary.buses = plan
            .buses
            .iter()
            .enumerate()
            .map(|(b, p)| BusFigures {
                label: p.label(),
                frames: self.io.frames[b],
                load_percent: 100.0 * self.io.busy[b].as_secs_f64()
                    / summary.machine_time.as_secs_f64().max(1e-9),
            })
            .collect();
        summary.frames_on_bus = self.io.frames.iter().sum();
        summary.step_ns = self.core.step_figures();
        summary.frames_lost = (self.core.tx_refused, self.core.rx_dropped);
        summary.frame_hash = self.io.hash.value();
        finish_summary(plan, &self.core.cycle, &self.lp.script, &mut summary);
        if let (Some(c), Some(dir)) = (self.io.capture.take(), &self.io.capture_dir) {
            summary.captures = capture_lines(dir, c.finish());
        }
        summary
    }
}

/// The summary's lines for what a capture wrote.
pub fn capture_lines(
    dir: &std::path::Path,
    stats: Vec<crate::runtime::capture::CaptureStats>,
) -> Vec<String> {
    stats
        .into_iter()
        .map(|s| {
            let files = format!(
                "{} and {}",
                dir.join(format!("{}.log", s.name)).display(),
                dir.join(format!("{}.pcap", s.name)).display()
            );
            match s.error {
                Some(e) => format!(
                    "bus {}: {} frames in {files}; FAILED: {e}",
                    s.name, s.frames
                ),
                None if s.dropped > 0 => format!(
                    "bus {}: {} frames in {files}; {} frames lost by the monitor",
                    s.name, s.frames, s.dropped
                ),
                None => format!("bus {}: {} frames in {files}", s.name, s.frames),
            }
        })
        .collect()
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
            "machine: {} axes, {} groups, {} bus(es), cycle {} us, virtual time",
            plan.axes.len(),
            plan.groups.len(),
            plan.buses.len(),
            plan.period.as_micros()
        ),
    );
    loop {
        let over = opts.duration.is_some_and(|d| run.elapsed() >= d);
        if over && !run.lp.ending() {
            run.shut_down();
        }
        run.step(out);
        if run.lp.script.phase() == Phase::Done {
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
    summary.units = plan
        .axes
        .iter()
        .map(|a| (a.name.clone(), a.unit.clone(), a.scale))
        .collect();
    summary.axes = plan
        .axes
        .iter()
        .enumerate()
        .filter_map(|(i, a)| {
            let s = c.axis_status(i as AxisId)?;
            Some((
                a.name.clone(),
                a.unit.clone(),
                a.scale.to_units(s.feedback.position),
                s.feedback.state,
            ))
        })
        .collect();
}

/// Prints a drive report and records it in the summary: booted, waiting (once), lost, reset,
/// refused.
pub fn report_node(plan: &MachinePlan, r: &NodeReport, out: &mut dyn Write, summary: &mut Summary) {
    let Some(a) = plan.axes.get(usize::from(r.axis)) else {
        return;
    };
    let bus = plan
        .buses
        .get(usize::from(r.bus))
        .map_or_else(|| "?".into(), |b| b.label());
    let node = r.report.node;
    let what = format!("node {node} ({} \"{}\") on {bus}", a.setup.kind, a.name);
    match (r.status(), &r.report.result) {
        (NodeStatus::Running, _) => {
            let identity = match (r.report.device_type, r.report.vendor_id) {
                (Some(t), Some(v)) => format!(": device type {t:08X}h, vendor {v:08X}h"),
                _ => String::new(),
            };
            say(out, &format!("drive ready: {what}{identity}"))
        }
        (NodeStatus::Waiting, Err(e)) if e.detail == FailureDetail::Lost => say(
            out,
            &format!("drive lost: {what}; waiting for it to come back"),
        ),
        (NodeStatus::Waiting, _) => {
            say(out, &format!("waiting for {what}"));
            summary.waiting.push(format!("axis {}: {what}", a.name));
        }
        (NodeStatus::Reset, _) => say(
            out,
            &format!("drive reset: {what} sent a boot-up (it reset itself); configuring it again"),
        ),
        (NodeStatus::Refused, _) => {
            say(out, &format!("drive REFUSED: {what}: {}", r.report));
            summary
                .boot_failures
                .push(format!("axis {}: {}", a.name, r.report));
        }
    }
}

/// Records one event in the summary; prints faults, acknowledges, chain aborts, parameter
/// results and overruns. `ending`: the run's orderly end (duration, Ctrl-C) has begun, so a
/// chain aborted now was stopped by the end's own stop and is said as such, not as a problem.
pub fn note_event(
    plan: &MachinePlan,
    e: &Event,
    ending: bool,
    summary: &mut Summary,
    out: &mut dyn Write,
) {
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
            let text = match plan.axes.get(usize::from(a)) {
                Some(p) => describe_in(reason, &p.unit, p.scale),
                None => describe(reason),
            };
            say(
                out,
                &format!("cycle {cycle}: FAULT axis {}: {text}", axis(a)),
            );
            summary.faults.push((axis(a), reason));
        }
        Event::Acknowledged { cycle, axis: a } => {
            say(
                out,
                &format!("cycle {cycle}: axis {}: fault acknowledged", axis(a)),
            );
        }
        Event::RecordReached { .. } => summary.records_reached += 1,
        Event::ChainComplete { .. } => summary.records_reached += 1,
        Event::ChainAborted {
            cycle,
            group: g,
            record,
        } => {
            if ending {
                say(
                    out,
                    &format!(
                        "cycle {cycle}: group {}: chain stopped at record {record} for the end of the run",
                        group(g)
                    ),
                );
            } else {
                say(
                    out,
                    &format!(
                        "cycle {cycle}: group {}: chain aborted at record {record}",
                        group(g)
                    ),
                );
            }
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
                &format!("cycle {cycle}: axis {}: PNU {pnu}:{sub} = {v}", axis(a)),
            ),
            Err(u16::MAX) => say(
                out,
                &format!(
                    "cycle {cycle}: axis {}: PNU {pnu}:{sub}: the drive did not reply in time",
                    axis(a)
                ),
            ),
            Err(n) => say(
                out,
                &format!(
                    "cycle {cycle}: axis {}: PNU {pnu}:{sub} refused: error {n}",
                    axis(a)
                ),
            ),
        },
        Event::AxisState { .. } => {}
        Event::Overrun {
            cycle,
            skipped,
            late_us,
        } => say(
            out,
            &format!(
                "cycle {cycle}: OVERRUN: the coordinator was away {:.1} ms ({skipped} cycle(s) skipped); the drives are not blamed",
                late_us as f64 / 1000.0
            ),
        ),
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
