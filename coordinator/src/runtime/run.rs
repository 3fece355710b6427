//! `coordinator run`: the choice of clock for a machine plan, the run's summary and the lines
//! the operator reads (status, drive reports, events, faults in the axis's units).
//!
//! Virtual time ([`crate::runtime::virtual_clock`]): one thread, the simulated drives in
//! lockstep with the cycle, deterministic, as fast as the machine allows. Real time
//! ([`crate::runtime::real_clock`]): the cycle on its own thread woken by absolute deadlines,
//! the buses as configured, boot and reports on the services' executor. Both run the same
//! cycle iteration ([`crate::runtime::cycle_loop`]) around the same step
//! ([`crate::runtime::stepper`]).

use std::fmt::Write as _;
use std::io::{IsTerminal, Write};
use std::time::Duration;

use drivers::can::Frame;

use crate::axis::AxisState;
use crate::command::{AxisId, GroupId};
use crate::config::{BusKind, Config};
use crate::cycle::{AxisStatus, Cycle, GroupStatus};
use crate::event::Event;
use crate::fault::FaultReason;
use crate::profile::MoveState;
use crate::records::{ChainState, ChainStatus};
use crate::runtime::boot::FailureDetail;
use crate::runtime::nodes::{NodeReport, NodeStatus};
use crate::runtime::plan::{MAX_AXES, MAX_GROUPS, MachinePlan};
use crate::runtime::script::{Phase, Script, ScriptOptions};

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
    /// `--record FILE`: record every cycle's inputs and outputs for `coordinator replay`.
    pub record: Option<RecordTo>,
}

/// Where a run records itself, and the configuration text the recording carries.
#[derive(Clone, Debug)]
pub struct RecordTo {
    /// The recording file.
    pub path: std::path::PathBuf,
    /// The machine's configuration as the run read it.
    pub config: String,
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
            record: None,
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
    /// Per axis: the largest following error seen while it moved, in its units
    /// (`CycleLoop::following_max`); 0 for an axis that never moved.
    pub following: Vec<f64>,
    /// The script's last phase.
    pub phase: Option<Phase>,
    /// Per axis: name, unit and increments per unit (to say faults in the axis's unit).
    pub units: Vec<(String, String, crate::units::Scale)>,
    /// What the capture wrote, a line per bus.
    pub captures: Vec<String>,
    /// Per EtherCAT bus: its frames' round trip, a line each.
    pub ethercat: Vec<String>,
    /// What the recording wrote (`--record`).
    pub recording: Option<String>,
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
        for line in &self.ethercat {
            writeln!(f, "  {line}")?;
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
        if let Some(r) = &self.recording {
            writeln!(f, "  {r}")?;
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
        for (i, (name, unit, pos, state)) in self.axes.iter().enumerate() {
            match self.following.get(i).filter(|e| **e > 0.0) {
                Some(e) => writeln!(
                    f,
                    "  axis {name}: {pos:.3} {unit}, {state}; largest following error {e:.3} {unit}"
                )?,
                None => writeln!(f, "  axis {name}: {pos:.3} {unit}, {state}")?,
            }
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

/// The run's first line: what the machine is and which clock runs it.
pub fn machine_line(plan: &MachinePlan, clock: &str) -> String {
    let n = |k: usize, one: &str, many: &str| format!("{k} {}", if k == 1 { one } else { many });
    let ethercat = if plan.segments.is_empty() {
        String::new()
    } else {
        format!(
            ", {}",
            n(plan.segments.len(), "EtherCAT bus", "EtherCAT buses")
        )
    };
    format!(
        "machine: {}, {}, {}{ethercat}, cycle {} µs, {clock}",
        n(plan.axes.len(), "axis", "axes"),
        n(plan.groups.len(), "group", "groups"),
        n(plan.buses.len(), "bus", "buses"),
        plan.period.as_micros()
    )
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
        if let Some(s) = plan.segments.first() {
            return Err(RunError::Config(format!(
                "--virtual-time: bus \"{}\" is of kind \"ethercat\" (interface {}); virtual time runs only machines whose drives are all simulated inside the coordinator: EtherCAT subdevices keep their own clock",
                s.name, s.interface
            )));
        }
        if let Some(a) = plan.axes.iter().find(|a| !a.simulated) {
            return Err(RunError::Config(format!(
                "--virtual-time: axis {:?} dials its drive at {}; virtual time runs only simulated drives (set simulated = true on the axis, or run in real time)",
                a.name,
                a.modbus.as_deref().unwrap_or("?")
            )));
        }
        crate::runtime::virtual_clock::run_virtual(&plan, opts, out)
    } else {
        crate::runtime::real_clock::run_real(&plan, opts, out)
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

/// Fills the per-axis part of the summary.
pub fn finish_summary<const A: usize, const G: usize>(
    plan: &MachinePlan,
    c: &Cycle<'_, A, G>,
    script: &Script,
    following_max: &[i64],
    summary: &mut Summary,
) {
    summary.following = plan
        .axes
        .iter()
        .zip(following_max)
        .map(|(a, e)| a.scale.to_units(*e))
        .collect();
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
