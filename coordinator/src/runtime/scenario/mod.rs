//! Fault campaigns in virtual time (`coordinator scenario FILE`): a simulated machine kept
//! moving by a client ([`operator`]) while scripted and seeded random faults ([`faults`]) hit
//! its buses, drives, Modbus links and command path; every cycle the invariants
//! ([`invariants`]) are checked, and the first violation is reported with the seed that
//! reproduces it. After the campaign the faults end and the machine must come back (enabled,
//! homed, fault-free) under the operator's acknowledge.
//!
//! - [`file`](mod@file): the scenario file, checked.
//! - [`faults`]: the fault kinds and their injection.
//! - [`invariants`]: what must hold every cycle.
//! - [`operator`]: the client and the books of its commands.

pub mod faults;
pub mod file;
pub mod invariants;
pub mod operator;

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;

use drivers::time::Instant;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::config::Config;
use crate::cycle::Transport;
use crate::runtime::plan::plan;
use crate::runtime::run::RecordTo;
use crate::runtime::script::Phase;
use crate::runtime::synthetic::{self, Kinds, Spec};
use crate::runtime::virtual_clock::VirtualRun;
use faults::{Active, FaultKind, Injector, Needs, Target};
use file::ScenarioFile;
use invariants::{Invariants, Violation};
use operator::{Books, Operator};

/// Machine time a machine may take to boot, enable and home before the campaign starts.
const START_LIMIT: Duration = Duration::from_secs(300);
/// Machine time the machine may take to come back after the last fault.
pub const RECOVERY_LIMIT: Duration = Duration::from_secs(60);

/// What the command line adds to a scenario.
#[derive(Debug, Clone, Default)]
pub struct ScenarioOptions {
    /// Another seed than the file's.
    pub seed: Option<u64>,
    /// Another duration than the file's, seconds.
    pub duration_s: Option<f64>,
    /// Record the run for `coordinator replay`.
    pub record: Option<PathBuf>,
    /// No progress lines.
    pub quiet: bool,
    /// Write everything the run prints (events, drive reports) to this file.
    pub log: Option<PathBuf>,
}

/// The first violation.
#[derive(Debug, Clone)]
pub struct Found {
    /// The cycle.
    pub cycle: u64,
    /// Machine time since the machine was up.
    pub after: Duration,
    /// What.
    pub violation: Violation,
    /// The last lines the run printed (events, reports).
    pub context: String,
}

/// What a campaign did.
#[derive(Debug, Clone)]
pub struct Report {
    /// The machine in words.
    pub machine: String,
    /// The seed used.
    pub seed: u64,
    /// Machine time of the campaign (from the machine being up).
    pub machine_time: Duration,
    /// Cycles of the campaign.
    pub cycles: u64,
    /// Wall time of the whole run.
    pub wall: Duration,
    /// Faults injected, by kind.
    pub injected: BTreeMap<FaultKind, u64>,
    /// The commands' books.
    pub books: Books,
    /// Machine time from the last fault's end to every axis back.
    pub recovered_after: Option<Duration>,
    /// The first violation, if any.
    pub violation: Option<Found>,
    /// The recording's line, if recorded.
    pub recording: Option<String>,
}

impl Report {
    /// Faults injected in all.
    pub fn faults(&self) -> u64 {
        self.injected.values().sum()
    }
}

fn invariant_name(i: u8) -> &'static str {
    match i {
        1 => "no axis moves unless enabled and commanded",
        2 => "a fault stops the affected group",
        3 => "setpoints stay within the limits",
        4 => "every command is answered exactly once",
        _ => "the machine returns to a known state after the faults",
    }
}

impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "scenario: {}, seed {}", self.machine, self.seed)?;
        writeln!(
            f,
            "  {:.3} s of machine time after start-up ({} cycles) in {:.1} s of wall time",
            self.machine_time.as_secs_f64(),
            self.cycles,
            self.wall.as_secs_f64()
        )?;
        let kinds: Vec<String> = self
            .injected
            .iter()
            .map(|(k, n)| format!("{} {n}", k.name()))
            .collect();
        writeln!(
            f,
            "  faults injected: {}{}",
            self.faults(),
            if kinds.is_empty() {
                String::new()
            } else {
                format!(" ({})", kinds.join(", "))
            }
        )?;
        let b = &self.books;
        writeln!(
            f,
            "  commands: {} submitted, {} accepted, {} refused by the admission table, {} refused at the door (inbox full), {} lost, {} answered twice; {} of them recovery commands",
            b.submitted, b.accepted, b.refused, b.refused_at_door, b.lost, b.doubled, b.recovery
        )?;
        match &self.violation {
            None => {
                writeln!(f, "  invariant violations: 0")?;
                if let Some(t) = self.recovered_after {
                    writeln!(
                        f,
                        "  recovered: every axis online, enabled, homed and fault-free {:.3} s after the last fault ended",
                        t.as_secs_f64()
                    )?;
                }
            }
            Some(v) => {
                writeln!(
                    f,
                    "  VIOLATION of invariant {} ({}) at cycle {}, {:.3} s after start-up: {}",
                    v.violation.invariant,
                    invariant_name(v.violation.invariant),
                    v.cycle,
                    v.after.as_secs_f64(),
                    v.violation.what
                )?;
                writeln!(
                    f,
                    "  reproduce it: the same scenario file with --seed {} (add --record FILE to replay its cycles with `coordinator replay FILE`)",
                    self.seed
                )?;
                if !v.context.is_empty() {
                    writeln!(f, "  the run's last lines:")?;
                    for l in v.context.lines() {
                        writeln!(f, "    {l}")?;
                    }
                }
            }
        }
        if let Some(r) = &self.recording {
            writeln!(f, "  {r}")?;
        }
        Ok(())
    }
}

/// The machine's configuration text and its description in words.
fn machine_text(s: &ScenarioFile, base: &Path) -> Result<(String, String), String> {
    match s.machine.as_str() {
        "embedded" => Ok((
            crate::config::EXAMPLE.to_string(),
            "the embedded default machine".into(),
        )),
        "synthetic" => {
            let m = s
                .synthetic
                .ok_or("machine = \"synthetic\" needs a [synthetic] table")?;
            let spec = Spec {
                axes: m.axes,
                kinds: Kinds::Mixed,
                group_size: Some(m.group_size),
            };
            let text = synthetic::config_of_with_cycle_us(&spec, m.cycle_us).map_err(|e| {
                format!(
                    "synthetic.cycle_us = {}: the bus budget refuses {} axes at that cycle:\n{e}",
                    m.cycle_us, m.axes
                )
            })?;
            Ok((
                text,
                format!(
                    "synthetic machine of {} axes in groups of {}, cycle {} µs",
                    m.axes, m.group_size, m.cycle_us
                ),
            ))
        }
        path => {
            let p = base.join(path);
            let text = std::fs::read_to_string(&p)
                .map_err(|e| format!("machine = \"{path}\": cannot read {}: {e}", p.display()))?;
            Ok((text, format!("the machine of {}", p.display())))
        }
    }
}

/// The run's printed lines: the last ones kept for a violation's report, all of them written
/// to the log file if there is one.
struct Printed {
    text: Vec<u8>,
    log: Option<std::io::BufWriter<std::fs::File>>,
}

impl Printed {
    fn step(&mut self, run: &mut VirtualRun<'_>) {
        let from = self.text.len();
        run.step(&mut self.text);
        if let Some(l) = &mut self.log {
            let _ = l.write_all(&self.text[from..]);
        }
        keep_tail(&mut self.text);
    }
}

/// Keeps the last lines of what the run printed.
fn keep_tail(text: &mut Vec<u8>) {
    const KEEP: usize = 8 * 1024;
    if text.len() > 4 * KEEP {
        let cut = text.len() - KEEP;
        let cut = text[cut..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(cut, |i| cut + i + 1);
        text.drain(..cut);
    }
}

fn tail(text: &[u8], lines: usize) -> String {
    let s = String::from_utf8_lossy(text);
    let v: Vec<&str> = s.lines().collect();
    v[v.len().saturating_sub(lines)..].join("\n")
}

/// The targets each kind can hit on this machine.
struct Targets {
    can_axes: Vec<usize>,
    buses: Vec<usize>,
    modbus_axes: Vec<usize>,
}

impl Targets {
    fn of(run: &VirtualRun<'_>) -> Targets {
        let plan = run.io.plan();
        let mut can_axes = Vec::new();
        let mut modbus_axes = Vec::new();
        for (i, a) in plan.axes.iter().enumerate() {
            match a.setup.transport {
                Transport::Can { .. } => can_axes.push(i),
                Transport::Modbus { .. } => modbus_axes.push(i),
                // Scenarios run simulated machines, which have no EtherCAT.
                Transport::Ethercat { .. } => {}
            }
        }
        Targets {
            can_axes,
            buses: (0..plan.buses.len()).collect(),
            modbus_axes,
        }
    }

    fn fits(&self, k: FaultKind) -> bool {
        match k.target() {
            Needs::CanAxis => !self.can_axes.is_empty(),
            Needs::Bus => !self.buses.is_empty(),
            Needs::ModbusAxis => !self.modbus_axes.is_empty(),
            Needs::Nothing => true,
        }
    }

    fn pick(&self, k: FaultKind, rng: &mut ChaCha8Rng) -> Target {
        let one = |v: &[usize], rng: &mut ChaCha8Rng| v[rng.gen_range(0..v.len())];
        match k.target() {
            Needs::CanAxis => Target::Axis(one(&self.can_axes, rng)),
            Needs::Bus => Target::Bus(one(&self.buses, rng)),
            Needs::ModbusAxis => Target::Axis(one(&self.modbus_axes, rng)),
            Needs::Nothing => Target::Commands,
        }
    }
}

/// A fault planned for a time.
struct Planned {
    at: Instant,
    kind: FaultKind,
    target: Target,
    length: Duration,
}

/// Runs a campaign; `base` is the scenario file's folder (a machine's path is relative to it).
pub fn run_scenario(
    s: &ScenarioFile,
    base: &Path,
    opts: &ScenarioOptions,
    out: &mut dyn Write,
) -> Result<Report, String> {
    let wall0 = std::time::Instant::now();
    let seed = opts.seed.unwrap_or(s.seed);
    let duration_s = opts.duration_s.unwrap_or(s.duration_s);
    file::seconds("--duration", duration_s, 0.001, file::MAX_DURATION_S)?;
    let duration = Duration::from_secs_f64(duration_s);
    let (text, machine) = machine_text(s, base)?;
    let cfg = Config::parse(&text).map_err(|e| format!("the scenario's machine: {e}"))?;
    let plan = plan(&cfg).map_err(|e| format!("the scenario's machine: {e}"))?;
    // (A synthetic machine's drives are all simulated by construction.)
    if let Some(a) = plan
        .axes
        .iter()
        .find(|a| !a.simulated && s.machine != "synthetic")
    {
        return Err(format!(
            "the scenario's machine: axis {} is not simulated; a scenario runs in virtual time, every drive simulated",
            a.name
        ));
    }
    let mut ropts = synthetic::demo_options(false);
    ropts.record = opts.record.as_ref().map(|p| RecordTo {
        path: p.clone(),
        config: text.clone(),
    });
    let mut run = VirtualRun::new(&plan, &ropts).map_err(|e| e.to_string())?;
    let log = match &opts.log {
        Some(p) => Some(std::io::BufWriter::new(
            std::fs::File::create(p).map_err(|e| format!("--log {}: {e}", p.display()))?,
        )),
        None => None,
    };
    let mut printed = Printed {
        text: Vec::new(),
        log,
    };
    // Up: booted, enabled, homed (the script's start-up).
    while run.lp.script.phase() != Phase::Running {
        printed.step(&mut run);
        if run.elapsed() > START_LIMIT || run.lp.script.phase() == Phase::Done {
            return Err(format!(
                "the machine did not come up (boot, enable, home) within {} s of machine time:\n{}",
                START_LIMIT.as_secs(),
                tail(&printed.text, 30)
            ));
        }
    }
    let targets = Targets::of(&run);
    let t0 = run.now();
    let k0 = run.cycles();
    let end = t0 + duration;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut injector = Injector::new(&run, seed);
    let mut operator = Operator::new(
        &plan,
        ChaCha8Rng::seed_from_u64(seed ^ 0x005E_ED0F_C11E),
        t0,
    );
    let mut invariants = Invariants::new(&plan);
    // The scripted faults, checked against the machine.
    let mut planned = Vec::new();
    for (i, f) in s.faults.iter().enumerate() {
        if !targets.fits(f.kind) {
            return Err(format!(
                "fault[{i}].kind = \"{}\": this machine has nothing it can hit",
                f.kind.name()
            ));
        }
        let target = match (f.kind.target(), &f.axis, &f.bus) {
            (Needs::CanAxis | Needs::ModbusAxis, Some(name), _) => {
                let a = plan
                    .axis(name)
                    .ok_or_else(|| format!("fault[{i}].axis = \"{name}\": no such axis"))?;
                let ok = match f.kind.target() {
                    Needs::CanAxis => targets.can_axes.contains(&a),
                    _ => targets.modbus_axes.contains(&a),
                };
                if !ok {
                    return Err(format!(
                        "fault[{i}].axis = \"{name}\": a {} needs an axis on {}",
                        f.kind.name(),
                        if f.kind.target() == Needs::CanAxis {
                            "a CAN bus"
                        } else {
                            "Modbus"
                        }
                    ));
                }
                Target::Axis(a)
            }
            (Needs::Bus, _, Some(name)) => Target::Bus(
                plan.buses
                    .iter()
                    .position(|b| &b.name == name)
                    .ok_or_else(|| format!("fault[{i}].bus = \"{name}\": no such bus"))?,
            ),
            (_, _, _) => targets.pick(f.kind, &mut rng),
        };
        planned.push(Planned {
            at: t0 + Duration::from_secs_f64(f.at_s),
            kind: f.kind,
            target,
            length: Duration::from_secs_f64(f.length_s),
        });
    }
    planned.sort_by_key(|p| p.at);
    let mut planned = std::collections::VecDeque::from(planned);
    let kinds: Vec<FaultKind> = match &s.random {
        Some(r) if !r.kinds.is_empty() => {
            if let Some(k) = r.kinds.iter().find(|k| !targets.fits(**k)) {
                return Err(format!(
                    "random.kinds: \"{}\": this machine has nothing it can hit",
                    k.name()
                ));
            }
            r.kinds.clone()
        }
        Some(_) => FaultKind::ALL
            .into_iter()
            .filter(|k| targets.fits(*k))
            .collect(),
        None => Vec::new(),
    };
    let draw_gap = |rng: &mut ChaCha8Rng, every: f64| {
        let u: f64 = rng.gen_range(f64::MIN_POSITIVE..1.0);
        Duration::from_secs_f64((-u.ln() * every).min(file::MAX_DURATION_S))
    };
    let mut next_random = s
        .random
        .as_ref()
        .map(|r| t0 + draw_gap(&mut rng, r.every_s));
    let mut active: Vec<Active> = Vec::new();
    let mut quiet_since = Some(t0);
    let mut injected: BTreeMap<FaultKind, u64> = BTreeMap::new();
    let mut violation: Option<Found> = None;
    let mut next_progress = 1u32;
    let mut recovered_after = None;
    let mut last_fault_end = t0;
    loop {
        let now = run.now();
        let campaign = now < end;
        if campaign {
            // Faults due now: scripted, then one random.
            let mut due = Vec::new();
            while planned.front().is_some_and(|p| p.at <= now) {
                if let Some(p) = planned.pop_front() {
                    due.push((p.kind, p.target, p.length));
                }
            }
            if let (Some(t), Some(r)) = (next_random, &s.random)
                && t <= now
                && !kinds.is_empty()
            {
                let kind = kinds[rng.gen_range(0..kinds.len())];
                let target = targets.pick(kind, &mut rng);
                let [a, b] = r.length_s;
                let length = Duration::from_secs_f64(rng.gen_range(a..=b));
                due.push((kind, target, length));
                next_random = Some(now + draw_gap(&mut rng, r.every_s));
            }
            for (kind, target, length) in due {
                if let Some(f) = injector.start(&mut run, kind, target, now, length) {
                    *injected.entry(kind).or_default() += 1;
                    if kind == FaultKind::ClientFlood {
                        for i in 0..faults::FLOOD {
                            operator.submit(
                                &mut run,
                                crate::command::Command::SetInput {
                                    bit: 31,
                                    value: i % 2 == 0,
                                },
                            );
                        }
                    }
                    active.push(f);
                    quiet_since = None;
                }
            }
        }
        // Faults that end now (all of them once the campaign is over).
        let mut i = 0;
        while i < active.len() {
            if !campaign || active[i].until <= now {
                let f = active.swap_remove(i);
                injector.end(&mut run, &f);
                last_fault_end = now;
            } else {
                i += 1;
            }
        }
        let k = run.cycles();
        for f in &active {
            injector.tick(&mut run, f, k);
        }
        if active.is_empty() && quiet_since.is_none() {
            quiet_since = Some(now);
        }
        operator.act(&mut run, now, quiet_since);
        printed.step(&mut run);
        let found = operator
            .collect(&mut run)
            .or_else(|| invariants.check(&*run.stepper.cycle, k));
        if let Some(v) = found {
            violation = Some(Found {
                cycle: k,
                after: now.saturating_duration_since(t0),
                violation: v,
                context: tail(&printed.text, 12),
            });
            break;
        }
        if campaign {
            let done = now.saturating_duration_since(t0).as_secs_f64() / duration.as_secs_f64();
            if !opts.quiet && done * 10.0 >= f64::from(next_progress) && next_progress <= 10 {
                let _ = writeln!(
                    out,
                    "scenario: {:>3} % ({:.0} of {:.0} s of machine time), {} faults injected, {} commands, 0 violations",
                    next_progress * 10,
                    now.saturating_duration_since(t0).as_secs_f64(),
                    duration.as_secs_f64(),
                    injected.values().sum::<u64>(),
                    operator.books.submitted
                );
                next_progress += 1;
            }
            continue;
        }
        // After the campaign: back to a known state within the limit.
        let c = &run.stepper.cycle;
        let back = (0..c.axis_count()).all(|a| {
            c.axis_status(a as u16).is_some_and(|s| {
                s.online
                    && s.enabled
                    && s.feedback.homed
                    && s.fault == crate::fault::FaultReason::None
            })
        });
        if back {
            recovered_after = Some(now.saturating_duration_since(last_fault_end));
            break;
        }
        if now.saturating_duration_since(last_fault_end) > RECOVERY_LIMIT {
            let c = &run.stepper.cycle;
            let stuck: Vec<String> = (0..c.axis_count())
                .filter_map(|a| {
                    let s = c.axis_status(a as u16)?;
                    let ok = s.online && s.enabled && s.feedback.homed;
                    (!ok || s.fault != crate::fault::FaultReason::None).then(|| {
                        format!(
                            "{} {} (fault: {})",
                            plan.axes[a].name,
                            s.activity.name(),
                            s.fault
                        )
                    })
                })
                .collect();
            violation = Some(Found {
                cycle: k,
                after: now.saturating_duration_since(t0),
                violation: Violation {
                    invariant: 5,
                    what: format!(
                        "not back within {} s after the last fault ended: {}",
                        RECOVERY_LIMIT.as_secs(),
                        stuck.join("; ")
                    ),
                },
                context: tail(&printed.text, 12),
            });
            break;
        }
    }
    let machine_time = run.now().saturating_duration_since(t0);
    let cycles = run.cycles() - k0;
    // The orderly end (stop, disable), bounded.
    run.shut_down();
    let stop = run.now() + RECOVERY_LIMIT;
    while run.lp.script.phase() != Phase::Done && run.now() < stop {
        printed.step(&mut run);
    }
    let summary = run.finish(wall0.elapsed());
    Ok(Report {
        machine,
        seed,
        machine_time,
        cycles,
        wall: wall0.elapsed(),
        injected,
        books: operator.books,
        recovered_after,
        violation,
        recording: summary.recording,
    })
}
