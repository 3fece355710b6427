//! `timing loop`: a client's command round trip through the machine, stage by stage.
//!
//! One CiA 402 drive (a TLC5xx, node 3) on one CAN bus, the coordinator started as a user
//! starts it (`coordinator run --config FILE --demo --no-chains`, which enables and homes the
//! axis), and a client of the shared-memory contract ([`shm_api::client::Client`]) sending a
//! small absolute move (1 mm and back, 100 % of the limits) once the axis stands still. Each
//! move makes the coordinator change RPDO1 (controlword bit 4 "new set-point" and 607Ah) and
//! the drive answer with a new statusword in TPDO1 (set-point acknowledge, target reached),
//! which the coordinator publishes as the axis's `status_bits`.
//!
//! Stages, all on `CLOCK_MONOTONIC`:
//! - t0: the client sends the command (taken just before [`Client::command_reply`]);
//! - t1: the first RPDO1 to the drive whose data differ from the one before t0;
//! - t2: latched at the drive: the first SYNC after t1 (the simulated drives apply a
//!   synchronous RPDO at the next SYNC; the 1007h window is 0, so none is deferred);
//! - t3: the first TPDO1 after t2 whose statusword differs from the one before t1;
//! - t4: the client holds a state whose `status_bits` differ from before (checked equal to
//!   t3's statusword), read by polling ([`Client::next`], 200 µs sleeps) or busy
//!   ([`Client::next_busy`], `--busy`).
//!
//! Two machines ([`Drives`]): the drive as a `drive-sim` process on `vbus:NAME`, whose frames a
//! monitor endpoint here receives with their `CLOCK_MONOTONIC` completion times; and the drive
//! simulated inside the coordinator (bus kind `simulated`), whose frames come from the
//! coordinator's own capture (`--capture DIR`, candump log): its timestamps are the bus's
//! `CLOCK_MONOTONIC` moved to the Unix epoch by an offset taken when the capture started, so
//! they go back by this process's own `CLOCK_REALTIME - CLOCK_MONOTONIC` (the two offsets
//! differ by the clocks' slew between the readings, well under a µs, plus the log's 1 µs
//! resolution).

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::Duration;

use drivers::can::Bus;
use drivers::cli_number::Allowed;
use drivers::time::monotonic_now;
use shm_api::client::{Client, reply_result};
use shm_api::contract::{AxisState, CommandRequest, axis_flags, axis_mode, axis_state, fault};

use crate::child::{Kept, TAIL_LINES};
use crate::progress::Progress;
use crate::report::summary::Run;
use crate::stats::Series;

/// The drive's node-ID.
pub const NODE: u8 = 3;
/// The SYNC COB-ID.
pub const SYNC: u16 = 0x080;
/// The bus's bitrate, bit/s.
pub const BITRATE: u32 = 1_000_000;
/// The stages' series, in order: four stages, then the two sums the issue asks for.
pub const SERIES: [&str; 6] = [
    "command to RPDO",
    "RPDO to latched",
    "latched to TPDO",
    "TPDO to state seen",
    "command to latched",
    "round trip",
];
/// The goal's text.
pub const GOAL: &str = "Command to latched at the drive: p99 at most 2 cycles plus 100 µs";

/// Where the drive runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Drives {
    /// A `drive-sim` process on `vbus:NAME`.
    Vbus,
    /// Simulated inside the coordinator (bus kind `simulated`).
    InProcess,
}

impl Drives {
    /// Its name in the run's name and the command line.
    pub fn name(self) -> &'static str {
        match self {
            Drives::Vbus => "vbus",
            Drives::InProcess => "in-process",
        }
    }
}

/// What `timing loop` measures with; checked by [`LoopOptions::check`].
#[derive(Debug, Clone, PartialEq)]
pub struct LoopOptions {
    /// The machines, in turn.
    pub drives: Vec<Drives>,
    /// Samples per machine (the run ends at this count or at `duration_s`, first reached).
    pub samples: Option<u64>,
    /// Measuring time per machine, s (boot and homing come on top).
    pub duration_s: f64,
    /// The SYNC period, µs.
    pub cycle_us: u32,
    /// Read the state busy instead of polling every 200 µs.
    pub busy: bool,
}

impl LoopOptions {
    /// Refuses values that cannot be measured with, naming the option.
    pub fn check(&self) -> Result<(), String> {
        Allowed::new("seconds", 0.5, 86_400.0).check_flag("--duration", self.duration_s)?;
        if !(250..=100_000).contains(&self.cycle_us) {
            return Err(format!(
                "--cycle-us {}: the SYNC period must be 250 to 100000 µs",
                self.cycle_us
            ));
        }
        if let Some(n) = self.samples
            && !(1..=1_000_000).contains(&n)
        {
            return Err(format!("--samples {n}: must be 1 to 1000000"));
        }
        if self.drives.is_empty() {
            return Err("--drives: name vbus, in-process or both".into());
        }
        Ok(())
    }
}

/// One frame as the matching sees it: completion time (`CLOCK_MONOTONIC` ns), COB-ID, data.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Seen {
    /// Completion time, ns.
    pub t: u64,
    /// 11-bit COB-ID.
    pub cob: u16,
    /// The data bytes.
    pub data: Vec<u8>,
}

/// What the client measured for one sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sent {
    /// The command sent, ns.
    pub t0: u64,
    /// The reaction seen in the state, ns.
    pub t4: u64,
    /// The statusword the state showed then.
    pub status: u16,
}

/// The five instants of one sample, ns, in order.
pub type Stages = [u64; 5];

fn statusword(d: &[u8]) -> Option<u16> {
    (d.len() >= 2).then(|| u16::from_le_bytes([d[0], d[1]]))
}

/// Matches one sample against the bus's frames (sorted by time): t1, t2, t3 as the module
/// describes them, with t0 and t4 from `sent`. Fails in words when a stage is missing or out
/// of order, or the TPDO's statusword is not the one the client saw.
pub fn match_sample(frames: &[Seen], node: u8, sent: &Sent) -> Result<Stages, String> {
    let rpdo = 0x200 + u16::from(node);
    let tpdo = 0x180 + u16::from(node);
    let before = frames
        .iter()
        .rev()
        .find(|f| f.cob == rpdo && f.t < sent.t0)
        .ok_or("no RPDO1 before the command")?;
    let t1 = frames
        .iter()
        .find(|f| f.cob == rpdo && f.t >= sent.t0 && f.data != before.data)
        .ok_or("no RPDO1 after the command carries it")?
        .t;
    let t2 = frames
        .iter()
        .find(|f| f.cob == SYNC && f.t > t1)
        .ok_or("no SYNC after the command's RPDO1")?
        .t;
    let old = frames
        .iter()
        .rev()
        .find(|f| f.cob == tpdo && f.t < t1)
        .and_then(|f| statusword(&f.data))
        .ok_or("no TPDO1 before the command's RPDO1")?;
    let (t3, new) = frames
        .iter()
        .filter(|f| f.cob == tpdo && f.t > t2)
        .find_map(|f| statusword(&f.data).filter(|&s| s != old).map(|s| (f.t, s)))
        .ok_or("no TPDO1 after the latching SYNC shows a new statusword")?;
    if new != sent.status {
        return Err(format!(
            "the TPDO1's new statusword {new:04X}h is not the state's {:04X}h",
            sent.status
        ));
    }
    let t = [sent.t0, t1, t2, t3, sent.t4];
    if t.windows(2).any(|w| w[0] > w[1]) {
        return Err("the stages are out of order (the state came before the TPDO1)".into());
    }
    Ok(t)
}

/// The machine's configuration: one TLC5xx on one bus of `kind`.
pub fn config(bus: &str, kind: Drives, cycle_us: u32) -> String {
    let kind = match kind {
        Drives::Vbus => "vbus",
        Drives::InProcess => "simulated",
    };
    format!(
        "cycle_us = {cycle_us}\n\n[[buses]]\nname = \"{bus}\"\nkind = \"{kind}\"\nbitrate = {BITRATE}\n\n\
         [[axes]]\nname = \"z\"\ndevice = \"tlc5xx\"\nbus = \"{bus}\"\nnode = {NODE}\nunit = \"mm\"\n\
         increments_per_unit = 1000.0\n\
         limits = {{ position_min = 0.0, position_max = 100.0, velocity = 50.0, acceleration = 500.0 }}\n"
    )
}

fn now_ns() -> u64 {
    monotonic_now().as_nanos()
}

/// A name nobody else uses: `tag`, the process id, the time.
fn unique(tag: &str) -> String {
    format!("{tag}{}x{}", std::process::id(), now_ns() % 1_000_000_000)
}

/// The processes of one machine ([`Kept`]: their output kept, stopped with SIGINT then
/// SIGKILL) and its folder (configuration, capture); stopped and removed when dropped.
struct Scene {
    dir: PathBuf,
    procs: Vec<Kept>,
}

impl Scene {
    fn new() -> Result<Scene, String> {
        let dir = std::env::temp_dir().join(unique("timing-loop-"));
        std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        Ok(Scene {
            dir,
            procs: Vec::new(),
        })
    }

    fn spawn(&mut self, label: &str, exe: &Path, args: &[&str]) -> Result<usize, String> {
        let mut cmd = Command::new(exe);
        cmd.args(args);
        self.procs.push(Kept::spawn(label, cmd)?);
        Ok(self.procs.len() - 1)
    }

    fn alive(&mut self, p: usize) -> bool {
        self.procs[p].alive()
    }

    /// Waits until `p` printed `text`; fails when it ended or 60 s passed.
    fn wait_output(&mut self, p: usize, text: &str) -> Result<(), String> {
        let r = self.procs[p].wait_output(text, Duration::from_secs(60));
        // The others' output too: one may explain why this one never got there.
        r.map_err(|_| {
            self.failed(&format!(
                "{} never printed \"{text}\"",
                self.procs[p].label()
            ))
        })
    }

    /// `what`, followed by the last lines of every process's output.
    fn failed(&self, what: &str) -> String {
        let mut s = what.to_string();
        for k in &self.procs {
            s.push('\n');
            s.push_str(&k.tail(TAIL_LINES));
        }
        s
    }

    /// SIGINT, then up to 10 s for each to end, then SIGKILL; the last started first.
    fn stop(&mut self) {
        for k in self.procs.iter_mut().rev() {
            k.stop(Duration::from_secs(10));
        }
    }
}

impl Drop for Scene {
    fn drop(&mut self) {
        self.stop();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// The bus monitor of the vbus machine: a thread with its own endpoint (`ShmBus` is not
/// `Send`), collecting every frame with its completion time until stopped.
struct Monitor {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<Result<Vec<Seen>, String>>>,
}

impl Drop for Monitor {
    /// A run that failed early still ends the monitor's thread (and leaves the bus).
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Monitor {
    fn start(bus: &str) -> Result<Monitor, String> {
        let stop = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready_rx) = mpsc::channel();
        let (name, flag) = (bus.to_string(), stop.clone());
        let thread = std::thread::spawn(move || {
            let mut port = match drivers::can::shm_bus::ShmBus::open(&name, BITRATE) {
                Ok(p) => p,
                Err(e) => {
                    let e = format!("cannot join vbus:{name}: {e}");
                    let _ = ready_tx.send(Err(e.clone()));
                    return Err(e);
                }
            };
            let _ = ready_tx.send(Ok(()));
            let mut seen = Vec::new();
            while !flag.load(Ordering::Relaxed) {
                match port.try_recv() {
                    Ok(Some(f)) => {
                        if let Some(cob) = f.cob_id().filter(|_| !f.is_remote()) {
                            seen.push(Seen {
                                t: f.timestamp().as_nanos(),
                                cob,
                                data: f.data().to_vec(),
                            });
                        }
                    }
                    Ok(None) => std::thread::sleep(Duration::from_micros(100)),
                    Err(e) => return Err(format!("the monitor on vbus:{name}: {e}")),
                }
            }
            Ok(seen)
        });
        ready_rx
            .recv()
            .map_err(|_| "the bus monitor ended before it joined".to_string())??;
        Ok(Monitor {
            stop,
            thread: Some(thread),
        })
    }

    fn finish(mut self) -> Result<Vec<Seen>, String> {
        self.stop.store(true, Ordering::Relaxed);
        self.thread
            .take()
            .ok_or("the bus monitor was already stopped")?
            .join()
            .map_err(|_| "the bus monitor panicked".to_string())?
    }
}

/// The frames of a candump log on `CLOCK_MONOTONIC`: each timestamp less `offset_ns`.
pub fn read_capture(path: &Path, offset_ns: u64) -> Result<Vec<Seen>, String> {
    let f = File::open(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let log = drivers::can::candump::read_log(BufReader::new(f))
        .map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(log
        .into_iter()
        .filter(|r| !r.frame.is_remote())
        .filter_map(|r| {
            Some(Seen {
                t: r.timestamp.as_nanos().checked_sub(offset_ns)?,
                cob: r.frame.cob_id()?,
                data: r.frame.data().to_vec(),
            })
        })
        .collect())
}

/// `CLOCK_REALTIME - CLOCK_MONOTONIC` now, ns (the smaller gap of three readings).
fn realtime_offset() -> u64 {
    (0..3)
        .map(|_| {
            let a = now_ns();
            let wall = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos() as u64);
            let b = now_ns();
            (b - a, wall.saturating_sub(a + (b - a) / 2))
        })
        .min()
        .map_or(0, |(_, o)| o)
}

fn ready(a: &AxisState) -> bool {
    let f = axis_flags::ONLINE | axis_flags::ENABLED | axis_flags::HOMED;
    a.flags & f == f && a.mode == axis_mode::ON && a.state == axis_state::READY
}

/// The axis in words, for an error: statusword, state, mode, fault (the contract's numbers).
fn axis_words(a: &AxisState) -> String {
    format!(
        "statusword {:04X}h, state {}, mode {}, fault {}",
        a.status_bits, a.state, a.mode, a.fault
    )
}

/// Faults recovered at most in one machine's run: more means the host cannot keep the drive.
pub const MAX_RECOVERIES: u32 = 10;

/// What the client side met besides its samples.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Mishaps {
    /// Faults, or the drive lost, after the axis was first online (a drive's late TPDOs on a
    /// busy host, mostly): acknowledged, enabled and homed again. The first bring-up is not
    /// counted.
    pub recovered: u32,
    /// Samples whose reaction was a fault, not the move: discarded.
    pub discarded: u32,
    /// The axis was online at least once: before that, an axis that is not online is the
    /// machine still booting, brought up the same way but not a fault.
    online_seen: bool,
}

/// Whether an axis seen with fault `code` (the contract's number) or not online is a mishap
/// to count: a fault always; not online only after it was online once (before, the machine is
/// still booting).
fn is_mishap(code: u8, online_seen: bool) -> bool {
    code != fault::NONE || online_seen
}

/// Brings a faulted axis back (or, before it was ever online, brings it up): waits until its
/// drive is online again (the coordinator boots a drive it lost anew), acknowledges the fault,
/// enables and homes it, retrying each step every half second for up to 30 s; [`settle`] then
/// waits for the result.
fn recover(c: &mut Client, m: &mut Mishaps, last: &AxisState) -> Result<(), String> {
    use shm_api::request::Target;
    if is_mishap(last.fault, m.online_seen) {
        m.recovered += 1;
    }
    if m.recovered > MAX_RECOVERIES {
        return Err(format!(
            "the axis faulted more than {MAX_RECOVERIES} times (last: {}): a drive that misses three TPDOs in a row is faulted; on a busy host try a longer --cycle-us",
            axis_words(last)
        ));
    }
    let reply = Duration::from_secs(5);
    let end = now_ns() + 30_000_000_000;
    let mut next_try = 0;
    let mut said = String::from("no state");
    while now_ns() < end {
        let Ok(s) = c.next(Duration::from_millis(200)) else {
            continue;
        };
        let a = s.axes[0];
        said = axis_words(&a);
        let online = a.flags & axis_flags::ONLINE != 0;
        m.online_seen |= online;
        let enabled = a.flags & axis_flags::ENABLED != 0 && a.state == axis_state::READY;
        if online && a.fault == fault::NONE && enabled && a.flags & axis_flags::HOMED != 0 {
            return Ok(());
        }
        if !online || now_ns() < next_try {
            continue;
        }
        next_try = now_ns() + 500_000_000;
        let req = if a.fault != fault::NONE {
            CommandRequest::acknowledge(Target::Axis(0))
        } else if !enabled {
            CommandRequest::enable(Target::Axis(0))
        } else {
            CommandRequest::home(Target::Axis(0))
        };
        // A refusal (still acknowledging, still homing) is retried at the next try.
        let _ = c.command(&req, reply);
    }
    Err(format!(
        "recovering from a fault: the axis was not ready again within 30 s; last seen: {said}"
    ))
}

/// Waits until the axis stands ready, its statusword unchanged over 5 states; returns it. A
/// fault is recovered from ([`recover`]) and the wait starts again.
fn settle(c: &mut Client, within: Duration, m: &mut Mishaps) -> Result<u16, String> {
    let mut end = now_ns() + within.as_nanos() as u64;
    let mut same = 0;
    let mut last: Option<AxisState> = None;
    while now_ns() < end {
        if let Ok(s) = c.next(Duration::from_millis(200)) {
            let a = s.axes[0];
            m.online_seen |= a.flags & axis_flags::ONLINE != 0;
            if a.fault != fault::NONE || a.flags & axis_flags::ONLINE == 0 {
                recover(c, m, &a)?;
                end = now_ns() + within.as_nanos() as u64;
                same = 0;
                last = None;
                continue;
            }
            let ok = ready(&a) && a.flags & axis_flags::MOTION_COMPLETE != 0;
            same = if ok && last.is_some_and(|l| l.status_bits == a.status_bits) {
                same + 1
            } else {
                0
            };
            last = Some(a);
            if same >= 5 {
                return Ok(a.status_bits);
            }
        }
    }
    Err(format!(
        "the axis was not ready and still within {} s; last seen: {}",
        within.as_secs(),
        last.as_ref().map_or("no state".into(), axis_words)
    ))
}

/// The client's side of one machine: returns the samples it sent and saw.
fn drive_client(
    prefix: &str,
    o: &LoopOptions,
    progress: &mut Progress,
) -> Result<(Vec<Sent>, Mishaps), String> {
    let mut c = Client::connect_timeout(prefix, Duration::from_secs(60))
        .map_err(|e| format!("no coordinator under {prefix}: {e}"))?;
    // The commands go from a thread of their own, with its own client, so the state is read
    // here while the command's reply is awaited there.
    let (go_tx, go_rx) = mpsc::channel::<i64>();
    let (done_tx, done_rx) = mpsc::channel::<Result<u64, String>>();
    let p = prefix.to_string();
    let commander = std::thread::spawn(move || {
        let mut c = match Client::connect_timeout(&p, Duration::from_secs(10)) {
            Ok(c) => c,
            Err(e) => {
                let _ = done_tx.send(Err(format!("the commanding client: {e}")));
                return;
            }
        };
        while let Ok(target) = go_rx.recv() {
            let t0 = now_ns();
            let r = c
                .command_reply(
                    &CommandRequest::move_axis(0, target, 100),
                    Duration::from_secs(5),
                )
                .map_err(|e| e.to_string())
                .and_then(|r| reply_result(&r).map_err(|e| e.to_string()));
            if done_tx.send(r.map(|_| t0)).is_err() {
                break;
            }
        }
    });
    let mut m = Mishaps::default();
    settle(&mut c, Duration::from_secs(60), &mut m)
        .map_err(|e| format!("waiting for the axis enabled and homed: {e}"))?;
    let start = now_ns();
    let limit = start + (o.duration_s * 1e9) as u64;
    let mut sent = Vec::new();
    let cycle = Duration::from_micros(u64::from(o.cycle_us));
    for k in 0u64.. {
        if o.samples.is_some_and(|n| sent.len() as u64 >= n) || now_ns() >= limit {
            break;
        }
        let before = settle(&mut c, Duration::from_secs(10), &mut m)?;
        // A varying phase against the cycle: 0 to 1 cycle, in 37 steps.
        std::thread::sleep(cycle * (k % 37) as u32 / 37);
        c.latest();
        let target = if k % 2 == 0 { 2_000_000 } else { 1_000_000 };
        go_tx
            .send(target)
            .map_err(|_| "the commanding client ended".to_string())?;
        let end = now_ns() + 5_000_000_000;
        let mut seen = None;
        while seen.is_none() && now_ns() < end {
            let got = if o.busy {
                c.next_busy(Duration::from_millis(500))
            } else {
                c.next(Duration::from_millis(500))
            };
            if let Ok(s) = got
                && s.axes[0].status_bits != before
            {
                seen = Some((now_ns(), s.axes[0]));
            }
        }
        let t0 = done_rx
            .recv()
            .map_err(|_| "the commanding client ended".to_string())?;
        match (t0, seen) {
            (Ok(t0), Some((t4, a))) if a.fault == fault::NONE => sent.push(Sent {
                t0,
                t4,
                status: a.status_bits,
            }),
            // A fault came instead of the reaction, or the move was refused for one: the
            // next settle recovers.
            (Err(_), _) | (_, Some(_)) => m.discarded += 1,
            (Ok(_), None) => {
                return Err(format!(
                    "sample {k}: the axis's statusword stayed {before:04X}h for 5 s after the move"
                ));
            }
        }
        progress.set(match o.samples {
            Some(_) => sent.len() as u64,
            None => (now_ns() - start) / 1_000_000,
        });
    }
    drop(go_tx);
    let _ = commander.join();
    Ok((sent, m))
}

/// Starts one machine, measures, stops it; the samples and the bus's frames.
fn measure(kind: Drives, o: &LoopOptions) -> Result<(Vec<Sent>, Mishaps, Vec<Seen>), String> {
    let coordinator = crate::binaries::sibling("coordinator")?;
    let mut sc = Scene::new()?;
    let bus = unique("tloop");
    let prefix = unique("timing-loop-");
    let cfg = sc.dir.join("machine.toml");
    std::fs::write(&cfg, config(&bus, kind, o.cycle_us))
        .map_err(|e| format!("{}: {e}", cfg.display()))?;
    let cfg_s = cfg.to_string_lossy().into_owned();
    let capture = sc.dir.join("capture");
    let capture_s = capture.to_string_lossy().into_owned();
    let mut monitor = None;
    if kind == Drives::Vbus {
        let sim = crate::binaries::sibling("drive-sim")?;
        // The monitor joins first: a newcomer on a vbus stalls the endpoints already on it.
        monitor = Some(Monitor::start(&bus)?);
        let p = sc.spawn("drive-sim", &sim, &["--config", &cfg_s])?;
        sc.wait_output(p, "drive(s) running")?;
    }
    let mut args = vec![
        "run",
        "--config",
        &cfg_s,
        "--quiet",
        "--shm-prefix",
        &prefix,
        "--demo",
        "--no-chains",
    ];
    if kind == Drives::InProcess {
        args.extend(["--capture", &capture_s]);
    }
    let offset = realtime_offset();
    let coord = sc.spawn("coordinator", &coordinator, &args)?;
    let total = o.samples.unwrap_or((o.duration_s * 1000.0) as u64);
    let mut progress = Progress::new(&format!("loop {}", kind.name()), total);
    let sent = drive_client(&prefix, o, &mut progress);
    progress.finish();
    let (sent, mishaps) = sent.map_err(|e| sc.failed(&e))?;
    if !sc.alive(coord) {
        return Err(sc.failed("the coordinator ended during the run"));
    }
    sc.stop();
    let frames = match monitor {
        Some(m) => m.finish()?,
        None => {
            read_capture(&capture.join(format!("{bus}.log")), offset).map_err(|e| sc.failed(&e))?
        }
    };
    let mut frames = frames;
    // A vbus delivers out of timestamp order.
    frames.sort_by_key(|f| f.t);
    Ok((sent, mishaps, frames))
}

/// The run of one machine from its samples and frames: the series, cycles, the goal, and the
/// raw stage durations (`stages_ns`: per sample t1-t0, t2-t1, t3-t2, t4-t3, ns).
pub fn build_run(
    kind: Drives,
    o: &LoopOptions,
    sent: &[Sent],
    frames: &[Seen],
) -> (Run, Vec<Series>) {
    let mut run = Run::new(
        &format!("loop-{}", kind.name()),
        &format!(
            "client command round trip, {}, cycle {} µs",
            match kind {
                Drives::Vbus => "the drive a drive-sim process on a vbus",
                Drives::InProcess => "the drive simulated in the coordinator",
            },
            o.cycle_us
        ),
    );
    let mut series: Vec<Series> = SERIES.iter().map(|n| Series::new(*n)).collect();
    let mut raw = Vec::new();
    let mut unmatched = Vec::new();
    let origin = sent.first().map_or(0, |s| s.t0);
    for (k, s) in sent.iter().enumerate() {
        match match_sample(frames, NODE, s) {
            Ok(t) => {
                let at = t[0] - origin;
                let d = [
                    t[1] - t[0],
                    t[2] - t[1],
                    t[3] - t[2],
                    t[4] - t[3],
                    t[2] - t[0],
                    t[4] - t[0],
                ];
                for (x, v) in series.iter_mut().zip(d) {
                    x.record(at, v);
                }
                raw.push(serde_json::json!([d[0], d[1], d[2], d[3]]));
            }
            Err(e) => unmatched.push(format!("sample {k}: {e}")),
        }
    }
    let cycle_ns = u64::from(o.cycle_us) * 1000;
    run.set("drives", kind.name());
    run.set("cycle_us", o.cycle_us);
    run.set("duration_s", o.duration_s);
    run.set("samples_sent", sent.len() as u64);
    run.set("frames_seen", frames.len() as u64);
    run.set("state_read", if o.busy { "busy" } else { "poll (200 µs)" });
    run.set(
        "command",
        "move_axis to 2 mm and 1 mm in turn, 100 %; reaction: the TPDO1 statusword",
    );
    run.set("stages_ns", raw);
    if !unmatched.is_empty() {
        run.notes.push(format!(
            "{} of {} samples could not be matched to the bus; the first: {}",
            unmatched.len(),
            sent.len(),
            unmatched[0]
        ));
    }
    if kind == Drives::InProcess {
        run.notes.push(
            "bus stages from the coordinator's capture (candump log, 1 µs resolution), its clock related to CLOCK_MONOTONIC by CLOCK_REALTIME".into(),
        );
    }
    let planned = sent.len() as u64;
    let mut cycles = serde_json::Map::new();
    for s in &series {
        run.add(s, Some(planned));
        let f = s.figures();
        let c = |v: u64| (v as f64 / cycle_ns as f64 * 1000.0).round() / 1000.0;
        cycles.insert(
            s.name.clone(),
            serde_json::json!({"p50": c(f.p50), "p99": c(f.p99), "p99_9": c(f.p99_9), "max": c(f.max)}),
        );
    }
    run.set("in_cycles", serde_json::Value::Object(cycles));
    run.goal_us(
        GOAL,
        "command to latched",
        "p99",
        2.0 * f64::from(o.cycle_us) + 100.0,
    );
    (run, series)
}

/// Runs `timing loop`: one run per machine.
pub fn run(o: &LoopOptions) -> Result<Vec<(Run, Vec<Series>)>, String> {
    o.check()?;
    let mut out = Vec::new();
    for &kind in &o.drives {
        let (sent, mishaps, frames) = measure(kind, o)?;
        let mut r = build_run(kind, o, &sent, &frames);
        r.0.set("faults_recovered", mishaps.recovered);
        r.0.set("samples_discarded", mishaps.discarded);
        if mishaps.recovered > 0 || mishaps.discarded > 0 {
            r.0.notes.push(format!(
                "the axis faulted or went offline {} time(s) after it was first ready (on a busy host, mostly a drive's TPDOs late three times in a row) and was acknowledged, enabled and homed again; {} sample(s) met a fault and were left out",
                mishaps.recovered, mishaps.discarded
            ));
        }
        if r.0.series.first().is_none_or(|s| s.figures.samples == 0) {
            return Err(format!(
                "loop {}: no sample matched the bus ({}); {}",
                kind.name(),
                sent.len(),
                r.0.notes.join("; ")
            ));
        }
        out.push(r);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_bring_up_is_not_a_mishap() {
        assert!(!is_mishap(fault::NONE, false), "not online yet: booting");
        assert!(
            is_mishap(fault::NONE, true),
            "offline after it was online: lost"
        );
        assert!(is_mishap(fault::HEARTBEAT_LOST, false) && is_mishap(fault::EMCY, true));
    }

    fn f(t: u64, cob: u16, data: &[u8]) -> Seen {
        Seen {
            t,
            cob,
            data: data.to_vec(),
        }
    }

    /// A bus of 1000 µs cycles: SYNC at k ms, RPDO1 at +100 µs, TPDO1 at +200 µs; the command
    /// changes the RPDO1 from cycle 3 on and the statusword from cycle 4's TPDO1 on.
    fn bus() -> Vec<Seen> {
        let mut v = Vec::new();
        for k in 0..8u64 {
            let t = k * 1_000_000;
            v.push(f(t, SYNC, &[]));
            let r: &[u8] = if k >= 3 { &[0x1F, 0, 1] } else { &[0x0F, 0, 0] };
            v.push(f(t + 100_000, 0x203, r));
            let s: &[u8] = if k >= 4 {
                &[0x37, 0x16, 9]
            } else {
                &[0x37, 0x06, 9]
            };
            v.push(f(t + 200_000, 0x183, s));
        }
        v
    }

    #[test]
    fn stages_are_found_in_order() {
        let sent = Sent {
            t0: 2_500_000,
            t4: 4_600_000,
            status: 0x1637,
        };
        let t = match_sample(&bus(), 3, &sent).unwrap();
        assert_eq!(t, [2_500_000, 3_100_000, 4_000_000, 4_200_000, 4_600_000]);
    }

    #[test]
    fn a_wrong_statusword_or_order_is_refused_in_words() {
        let mut sent = Sent {
            t0: 2_500_000,
            t4: 4_600_000,
            status: 0x0637,
        };
        assert!(
            match_sample(&bus(), 3, &sent)
                .unwrap_err()
                .contains("0637h")
        );
        sent.status = 0x1637;
        sent.t4 = 4_100_000;
        assert!(
            match_sample(&bus(), 3, &sent)
                .unwrap_err()
                .contains("order")
        );
        // Another node's frames are not this drive's.
        assert!(match_sample(&bus(), 4, &sent).is_err());
        // A command after the last change finds no RPDO1 carrying it.
        sent.t0 = 7_500_000;
        assert!(
            match_sample(&bus(), 3, &sent)
                .unwrap_err()
                .contains("RPDO1")
        );
    }

    #[test]
    fn options_are_checked() {
        let ok = LoopOptions {
            drives: vec![Drives::Vbus],
            samples: None,
            duration_s: 5.0,
            cycle_us: 2000,
            busy: false,
        };
        assert!(ok.check().is_ok());
        for (bad, word) in [
            (
                LoopOptions {
                    cycle_us: 10,
                    ..ok.clone()
                },
                "--cycle-us",
            ),
            (
                LoopOptions {
                    duration_s: f64::NAN,
                    ..ok.clone()
                },
                "--duration",
            ),
            (
                LoopOptions {
                    samples: Some(0),
                    ..ok.clone()
                },
                "--samples",
            ),
            (
                LoopOptions {
                    drives: vec![],
                    ..ok.clone()
                },
                "--drives",
            ),
        ] {
            assert!(bad.check().unwrap_err().contains(word));
        }
    }

    #[test]
    fn the_run_sums_the_stages_and_judges_the_goal() {
        let sent = [Sent {
            t0: 2_500_000,
            t4: 4_600_000,
            status: 0x1637,
        }];
        let o = LoopOptions {
            drives: vec![Drives::Vbus],
            samples: Some(1),
            duration_s: 1.0,
            cycle_us: 1000,
            busy: false,
        };
        let (run, series) = build_run(Drives::Vbus, &o, &sent, &bus());
        assert_eq!(series.len(), 6);
        let p99 = |n: &str| run.series.iter().find(|s| s.name == n).unwrap().figures.p99;
        // command to latched 1.5 ms within 2.1 ms.
        assert!((1_499_000..=1_501_000).contains(&p99("command to latched")));
        assert!(run.goals[0].met && run.goals[0].limit == 2100.0);
        assert!(run.notes.is_empty(), "{:?}", run.notes);
    }
}
