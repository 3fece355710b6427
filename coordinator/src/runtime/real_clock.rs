//! Real time: the cycle iteration ([`crate::runtime::cycle_loop`]) on its own thread, woken at
//! absolute deadlines (`clock_nanosleep`) or by the received SYNC, with SCHED_FIFO and locked
//! memory where granted; every bus opened as configured:
//!
//! - `simulated`: an in-process bus on the real clock, its drives' simulators stepped on a
//!   `drives` thread;
//! - `vbus`: the cross-process bus `vbus:NAME` (shared memory), whose drives are other
//!   processes (`drive-sim`, tools);
//! - `socketcan`: the Linux CAN interface of that name.
//!
//! Each Modbus drive is dialled at its configured address by an exchange thread of its own
//! (connect timeout, reconnect with back-off); a `simulated = true` one is first started as a
//! Modbus TCP server on loopback. The drives' boot and lifecycle, command intake and reports
//! run on the services' executor; the main thread prints what the others report.

use std::io::Write;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc;
use std::time::Duration;

use drivers::can::bit_timing::frame_duration;
use drivers::can::shm_bus::ShmBus;
use drivers::can::socketcan::SocketCanBus;
use drivers::can::{Bus, ClockMode, VirtualBus, VirtualBusConfig, VirtualPort};
use drivers::time::{Instant, monotonic_now};
use heapless::spsc::{Producer, Queue};

use crate::axis::Image;
use crate::command::{Answer, Request};
use crate::config::BusKind;
use crate::cycle::{BusFrame, ImageInput, Transport};
use crate::event::Event;
use crate::runtime::capture::{self, CaptureBus, CaptureSource};
use crate::runtime::cycle_loop::{CycleIo, CycleLoop, NodeChange, Wake};
use crate::runtime::ethercat::{self as ec, SegmentCycleSide, SegmentSettings};
use crate::runtime::modbus::{self as mb, Link, ModbusCycleSide, ModbusSettings};
use crate::runtime::nodes::Nodes;
use crate::runtime::plan::MachinePlan;
use crate::runtime::realtime_thread::{self, RealtimeSettings};
use crate::runtime::run::{
    BusFigures, FrameHash, RunError, RunOptions, Snapshot, Summary, capture_lines, finish_summary,
    machine_line, note_event, out_is_tty, print_status, report_node, say, status_lines,
};
use crate::runtime::script::Script;
use crate::runtime::services::{self, CycleEnds, ServiceEvent};
use crate::runtime::shm::{StateSide, StaticInfo};
use crate::runtime::signals;
use crate::runtime::sim::{SimBus, spawn_cmmo_server};
use crate::runtime::stepper::{RX_CAPACITY, Stepper, TX_CAPACITY};
use crate::runtime::ticker::{self, Ticker};

/// Snapshots in flight from the cycle thread to the printer.
const SNAPSHOTS: usize = 4;

/// A bus port the cycle thread owns.
type Port = Box<dyn Bus>;

/// The real clock's side of the cycle iteration.
struct RealIo {
    ports: Vec<Port>,
    producer: bool,
    ticker: Ticker,
    period: Duration,
    last_sync: Instant,
    end: Option<Instant>,
    ends: CycleEnds,
    exchanges: Vec<(usize, ModbusCycleSide)>,
    /// Every EtherCAT bus's exchange.
    segments: Vec<SegmentCycleSide>,
    /// Per EtherCAT axis: its image slot, its bus (an index of `segments`) and position index
    /// (0 first), and its axis.
    ec_slots: Vec<(usize, usize, usize, crate::command::AxisId)>,
    snapshots: Producer<'static, Snapshot>,
    /// The last wake-up's time.
    now: Instant,
    /// The orderly end (the duration, Ctrl-C) has begun.
    ending: bool,
    /// The cycle of the first event after the orderly end began (`u64::MAX` before): the
    /// printer says what was aborted from then on as the end's own stop.
    end_cycle: Arc<AtomicU64>,
    /// The next cycle's deadline, ns of CLOCK_MONOTONIC: the command thread looks for
    /// requests just before it (`shm::next_look`). One relaxed store a cycle.
    next_deadline: Arc<AtomicU64>,
}

impl RealIo {
    /// Waits for the next cycle: the absolute deadline (producer) or the received SYNC.
    fn next_wake(&mut self, rx: &mut dyn FnMut(BusFrame)) -> Wake {
        if self.producer {
            let tick = self.ticker.wait();
            for (b, port) in self.ports.iter_mut().enumerate() {
                while let Ok(Some(f)) = port.try_recv() {
                    let bf = BusFrame::new(b as u8, f);
                    let _ = self.ends.offer_received(&bf);
                    rx(bf);
                }
            }
            return Wake {
                now: tick.deadline,
                late_ns: tick.late.as_nanos() as u64,
                skipped: tick.skipped,
            };
        }
        // SYNC consumer (the only bus): the received SYNC starts the cycle; what arrives before
        // it belongs to this cycle. Two periods without SYNC count as missed.
        let mut deadline = self.last_sync + self.period * 2;
        let mut skipped = 0;
        let stop = signals::stop_flag();
        loop {
            let Some(port) = self.ports.first_mut() else {
                ticker::sleep_until(deadline);
                return Wake {
                    now: monotonic_now(),
                    late_ns: 0,
                    skipped: 1,
                };
            };
            match port.recv_until(deadline) {
                Ok(Some(f)) if f.cob_id() == Some(0x080) => {
                    let t = f.timestamp();
                    self.last_sync = t;
                    return Wake {
                        now: t,
                        late_ns: monotonic_now().saturating_duration_since(t).as_nanos() as u64,
                        skipped,
                    };
                }
                Ok(Some(f)) => {
                    let bf = BusFrame::new(0, f);
                    let _ = self.ends.offer_received(&bf);
                    rx(bf);
                }
                Ok(None) | Err(_) => {
                    skipped += 1;
                    deadline += self.period;
                    // No SYNC: a stop (Ctrl-C, the duration) still runs the cycle so that the
                    // drives are disabled.
                    let over = self.end.is_some_and(|e| monotonic_now() >= e);
                    if over || stop.load(Ordering::Relaxed) {
                        return Wake {
                            now: monotonic_now(),
                            late_ns: 0,
                            skipped,
                        };
                    }
                }
            }
        }
    }
}

impl CycleIo for RealIo {
    fn wait(&mut self, rx: &mut dyn FnMut(BusFrame)) -> Wake {
        let wake = self.next_wake(rx);
        self.now = wake.now;
        let next = if self.producer {
            self.ticker.next_deadline()
        } else {
            wake.now + self.period
        };
        self.next_deadline.store(next.as_nanos(), Ordering::Relaxed);
        wake
    }

    fn node_report(&mut self) -> Option<NodeChange> {
        if let Some(r) = self.ends.boot_report() {
            return Some(NodeChange::from(&r));
        }
        for (seg, side) in self.segments.iter_mut().enumerate() {
            if let Some((i, op)) = side.report()
                && let Some(&(_, _, _, axis)) =
                    self.ec_slots.iter().find(|e| e.1 == seg && e.2 == i)
            {
                return Some(NodeChange {
                    axis,
                    status: if op {
                        crate::runtime::nodes::NodeStatus::Running
                    } else {
                        crate::runtime::nodes::NodeStatus::Refused
                    },
                });
            }
        }
        None
    }

    fn image_input(&mut self, k: u64, slot: usize, _last: &Image, _now: Instant) -> ImageInput {
        if let Some(&(_, seg, i, _)) = self.ec_slots.iter().find(|e| e.0 == slot) {
            return self.segments[seg].take(k, i);
        }
        let Some((_, side)) = self.exchanges.iter_mut().find(|(s, _)| *s == slot) else {
            return ImageInput::default();
        };
        let m = side.take_input(k);
        ImageInput {
            image: Image::from_slice(&m.data).unwrap_or_default(),
            fresh: m.fresh,
            late_cycles: m.late_cycles,
            lost: matches!(m.link, Link::TimedOut(_) | Link::Down(_)),
            ..ImageInput::default()
        }
    }

    fn image_output(&mut self, k: u64, slot: usize, output: &Image) {
        if let Some(&(_, seg, i, _)) = self.ec_slots.iter().find(|e| e.0 == slot) {
            self.segments[seg].put(i, &output.data);
            return;
        }
        if let Some((_, side)) = self.exchanges.iter_mut().find(|(s, _)| *s == slot) {
            side.put_output(k, &output.data);
        }
    }

    fn images_sent(&mut self, k: u64) {
        for s in &mut self.segments {
            s.send(k);
        }
    }

    fn request(&mut self) -> Option<Request> {
        self.ends.request()
    }

    fn answer(&mut self, answer: Answer) {
        let _ = self.ends.answer(answer);
    }

    fn send(&mut self, f: &BusFrame) -> bool {
        self.ports
            .get_mut(usize::from(f.bus))
            .is_some_and(|p| p.send(&f.frame).is_ok())
    }

    fn service_frame(&mut self, _now: Instant) -> Option<BusFrame> {
        self.ends.tx_frame()
    }

    fn event(&mut self, e: Event) {
        // The loop asked for the end before this cycle's step if the duration is over or a
        // stop signal came: from this event's cycle on, an aborted chain is the end's stop.
        if !self.ending
            && (self.end.is_some_and(|t| self.now >= t)
                || signals::stop_flag().load(Ordering::Relaxed))
        {
            self.ending = true;
            self.end_cycle.store(e.cycle(), Ordering::Release);
        }
        let _ = self.ends.event(e);
    }

    fn status(&mut self, snapshot: Snapshot) {
        let _ = self.snapshots.enqueue(snapshot);
    }
}

/// SCHED_FIFO priority of the cycle thread while it sets up, below the simulated drives' 70.
const SETUP_PRIORITY: i32 = 60;

/// The shared-memory command thread's SCHED_FIFO priority: below the cycle's (80), above the
/// simulated drives' (70), so that its look just before each deadline is on time; its work
/// there is a few microseconds.
const COMMAND_PRIORITY: i32 = 75;

/// What the cycle thread hands back when it ends.
struct CycleResult {
    summary: Summary,
    late: (u64, u64, u64),
    skipped: u64,
    /// The cycle thread's state notify figures, where the machine is published.
    notify: Option<String>,
}

/// A bus as the main thread opens it before the cycle starts.
enum Opened {
    /// In-process, with its simulators.
    Simulated {
        bus: VirtualBus,
        port: VirtualPort,
        monitor: VirtualPort,
    },
    /// Across processes: opened on the cycle thread (its ports stay on the thread that opened
    /// them); the main thread watches it through an endpoint of its own.
    Vbus,
    /// A CAN interface.
    Socketcan(SocketCanBus),
}

/// The Modbus address of `axis`, resolved as `coordinator check` resolves it.
fn modbus_address(name: &str, addr: &str) -> Result<SocketAddr, RunError> {
    crate::config::resolve_modbus(addr).map_err(|why| {
        RunError::Io(format!(
            "axis {name}: modbus = {addr:?}: cannot resolve: {why}"
        ))
    })
}

/// Runs `plan` in real time (see the module docs).
pub fn run_real(
    plan: &MachinePlan,
    opts: &RunOptions,
    out: &mut dyn Write,
) -> Result<Summary, RunError> {
    let wall0 = std::time::Instant::now();
    // Memory is locked here, before any thread of the run exists: mlockall populates the whole
    // process (about 100 ms for a debug build), and a thread that maps memory meanwhile waits
    // for the process's memory-map lock. Done on the cycle thread, it held the threads already
    // running (Modbus exchange, capture) for that long.
    let memory = realtime_thread::enter_realtime(&RealtimeSettings {
        priority: None,
        cpu: None,
        lock_memory: true,
    });
    let t0 = monotonic_now();
    say(out, &machine_line(plan, "real time"));

    // The buses, as configured. A SocketCAN interface that cannot be opened stops the run here,
    // naming the interface and the reason.
    let mut opened = Vec::new();
    let mut sims = Vec::new();
    for (i, b) in plan.buses.iter().enumerate() {
        opened.push(match b.kind {
            BusKind::Ethercat => {
                return Err(RunError::Config(format!(
                    "bus {}: an ethercat bus is not a CAN bus",
                    b.name
                )));
            }
            BusKind::Simulated | BusKind::Virtual => {
                let bus = VirtualBus::new(VirtualBusConfig {
                    bitrate: b.bitrate,
                    clock: ClockMode::Real,
                    rx_capacity: RX_CAPACITY,
                    tx_capacity: TX_CAPACITY,
                    ..VirtualBusConfig::default()
                })
                .map_err(|e| RunError::Io(format!("bus {}: {e}", b.name)))?;
                let port = bus.attach("coordinator");
                let monitor = bus.attach_monitor("monitor");
                sims.push((
                    bus.clone(),
                    SimBus::build(&bus, plan, i, t0).map_err(RunError::Io)?,
                ));
                Opened::Simulated { bus, port, monitor }
            }
            BusKind::Vbus => Opened::Vbus,
            BusKind::Socketcan => Opened::Socketcan(
                SocketCanBus::open(&b.name)
                    .map_err(|e| RunError::Io(format!("bus {}: {e}", b.name)))?,
            ),
        });
        say(
            out,
            &format!(
                "bus {}: {} kbit/s, {} drive(s)",
                b.label(),
                b.bitrate / 1000,
                plan.axes
                    .iter()
                    .filter(|a| matches!(a.setup.transport, Transport::Can { bus, .. } if usize::from(bus) == i))
                    .count()
            ),
        );
    }

    // The Modbus drives: each dialled by an exchange thread; a simulated one is served first.
    let mut servers = Vec::new();
    let mut exchanges = Vec::new();
    let mut exchange_threads = Vec::new();
    for a in &plan.axes {
        let Transport::Modbus { slot } = a.setup.transport else {
            continue;
        };
        let addr = if a.simulated {
            let server = spawn_cmmo_server().map_err(RunError::Io)?;
            let addr = server.local_addr();
            say(
                out,
                &format!(
                    "axis {}: simulated {} on Modbus TCP {addr}",
                    a.name, a.setup.kind
                ),
            );
            servers.push(server);
            addr
        } else {
            let text = a.modbus.as_deref().unwrap_or_default();
            let addr = modbus_address(&a.name, text)?;
            say(
                out,
                &format!("axis {}: {} on Modbus TCP {text}", a.name, a.setup.kind),
            );
            addr
        };
        let settings = ModbusSettings {
            period: plan.period,
            ..ModbusSettings::default()
        };
        let (side, thread) = mb::spawn(addr, settings)
            .map_err(|e| RunError::Io(format!("axis {}: Modbus TCP: {e}", a.name)))?;
        exchanges.push((usize::from(slot), side));
        exchange_threads.push(thread);
    }

    // The EtherCAT buses: a thread each, with ethercrab on the bus's interface.
    let (ec_tx, ec_rx) = mpsc::channel::<ec::SegmentReport>();
    let mut segments = Vec::new();
    let mut segment_threads = Vec::new();
    let mut ec_slots = Vec::new();
    if let (Some(dir), false) = (&opts.capture, plan.segments.is_empty()) {
        std::fs::create_dir_all(dir)
            .map_err(|e| RunError::Io(format!("--capture {}: {e}", dir.display())))?;
    }
    for (s, seg) in plan.segments.iter().enumerate() {
        let mut devices = Vec::new();
        for (i, &a) in seg.axes.iter().enumerate() {
            let axis = &plan.axes[a];
            let facts = axis.setup.kind.device().ethercat.ok_or_else(|| {
                RunError::Config(format!("axis {}: not an EtherCAT device", axis.name))
            })?;
            devices.push(facts);
            if let Some(slot) = axis.setup.transport.image_slot() {
                ec_slots.push((usize::from(slot), s, i, a as crate::command::AxisId));
            }
        }
        let settings = SegmentSettings {
            name: seg.name.clone(),
            period: plan.period,
            devices,
            parameters: seg.parameters.clone(),
            capture: opts
                .capture
                .as_ref()
                .map(|d| d.join(format!("{}.pcap", seg.name))),
        };
        let (side, thread) = ec::spawn(&seg.interface, settings, ec_tx.clone()).map_err(|e| {
            RunError::Io(format!(
                "bus {} (ethercat, interface {}): {e}",
                seg.name, seg.interface
            ))
        })?;
        say(
            out,
            &format!(
                "bus {}: EtherCAT on {}, {} subdevice(s)",
                seg.name,
                seg.interface,
                seg.axes.len()
            ),
        );
        segments.push(side);
        segment_threads.push((seg.name.clone(), thread));
    }
    drop(ec_tx);

    // Services: the drives' boot and lifecycle and the events, on their executor; their
    // reports reach this thread over a channel. The command port goes to the shared-memory
    // command thread: clients' commands reach the cycle's queue without a relay.
    let (cycle_ends, service_ends, command_port) = services::channels();
    let (report_tx, report_rx) = mpsc::channel::<ServiceEvent>();
    let (shm_tx, shm_rx) = mpsc::channel::<Event>();
    let shm_tx = opts.shm.as_ref().map(|_| shm_tx);
    let svc = services::spawn_services(
        service_ends,
        Nodes::new(plan, t0),
        Box::new(move |e| {
            if let (Some(tx), ServiceEvent::Cycle(ev)) = (&shm_tx, &e) {
                let _ = tx.send(*ev);
            }
            let _ = report_tx.send(e);
        }),
    )
    .map_err(|e| RunError::Io(e.to_string()))?;

    // Client commands and events over shared memory, on their own thread.
    let info = StaticInfo::new(plan, false);
    let next_deadline = Arc::new(AtomicU64::new(0));
    let shm_thread = match &opts.shm {
        Some(prefix) => {
            let _ = shm_api::publisher::cleanup_dead_nodes();
            Some(
                crate::runtime::shm::spawn_command_thread(
                    prefix.clone(),
                    info.clone(),
                    command_port,
                    shm_rx,
                    next_deadline.clone(),
                    Some(COMMAND_PRIORITY),
                )
                .map_err(|e| RunError::Io(e.to_string()))?,
            )
        }
        None => None,
    };

    // The simulated drives, stepped as time passes.
    let stop_sims = Arc::new(AtomicBool::new(false));
    let sim_stop = stop_sims.clone();
    let sim_thread = (!sims.is_empty())
        .then(|| {
            std::thread::Builder::new()
                .name("drives".into())
                .spawn(move || step_simulated(sims, &sim_stop))
        })
        .transpose()
        .map_err(|e| RunError::Io(e.to_string()))?;

    let snapshots: &'static mut Queue<Snapshot, { SNAPSHOTS + 1 }> =
        Box::leak(Box::new(Queue::new()));
    let (snap_tx, mut snap_rx) = snapshots.split();
    let period = plan.period;
    let mut summary = Summary::default();
    let tty = out_is_tty();
    // The cycle thread's real-time set-up (scheduler, memory lock, warnings), said before the
    // run's first line of status; and the cycle from which aborts are the end's own stop.
    let (rt_tx, rt_rx) = mpsc::channel::<String>();
    let end_cycle = Arc::new(AtomicU64::new(u64::MAX));
    let end_cycle_io = end_cycle.clone();

    // `--capture DIR`: a thread per bus with a monitor endpoint of its own.
    let capture = match &opts.capture {
        Some(dir) => {
            let mut sources = Vec::new();
            for (b, o) in plan.buses.iter().zip(&opened) {
                sources.push(match o {
                    Opened::Simulated { bus, .. } => CaptureBus {
                        name: b.name.clone(),
                        bitrate: b.bitrate,
                        monitor: Box::new(bus.attach_monitor("capture")),
                    }
                    .into(),
                    Opened::Vbus => CaptureSource::shm(&b.name, b.bitrate),
                    Opened::Socketcan(_) => {
                        let name = b.name.clone();
                        CaptureSource {
                            name: b.name.clone(),
                            bitrate: b.bitrate,
                            open: Box::new(move || {
                                SocketCanBus::open(&name)
                                    .map(|s| Box::new(s) as Box<dyn Bus>)
                                    .map_err(|e| e.to_string())
                            }),
                        }
                    }
                });
            }
            Some(capture::start_sources(dir, sources).map_err(RunError::Io)?)
        }
        None => None,
    };

    // What the cycle thread takes: each bus's port, or what it opens itself.
    let mut cycle_buses: Vec<Option<Box<dyn Bus + Send>>> = Vec::new();
    let mut watchers: Vec<Option<Box<dyn Bus>>> = Vec::new();
    for (b, o) in plan.buses.iter().zip(opened) {
        match o {
            Opened::Simulated { bus, port, monitor } => {
                drop(bus);
                cycle_buses.push(Some(Box::new(port)));
                watchers.push(Some(Box::new(monitor)));
            }
            Opened::Vbus => {
                cycle_buses.push(None);
                watchers.push(
                    ShmBus::open(&b.name, b.bitrate)
                        .ok()
                        .map(|m| Box::new(m) as Box<dyn Bus>),
                );
            }
            Opened::Socketcan(s) => {
                cycle_buses.push(Some(Box::new(s)));
                watchers.push(None);
            }
        }
    }

    let result = std::thread::scope(|s| -> Result<CycleResult, RunError> {
        let cycle_thread = std::thread::Builder::new()
            .name("cycle".into())
            .stack_size(64 << 20)
            .spawn_scoped(s, move || -> Result<CycleResult, RunError> {
                // The set-up below the drives' priority (simulated drives run at 70): opening
                // the ports and the state service takes tens of milliseconds of CPU in a debug
                // build, which at 80 kept a CPU from every other thread, and on the normal
                // scheduler a loaded host stretched it to seconds, past the boot-up timeout of
                // the drives whose reset was waiting for the first cycle.
                let _ = realtime_thread::enter_realtime(&RealtimeSettings {
                    priority: Some(SETUP_PRIORITY),
                    lock_memory: false,
                    cpu: None,
                });
                let mut ports: Vec<Port> = Vec::with_capacity(cycle_buses.len());
                for (b, port) in plan.buses.iter().zip(cycle_buses) {
                    ports.push(match port {
                        Some(p) => p,
                        None => Box::new(
                            ShmBus::open(&b.name, b.bitrate)
                                .map_err(|e| RunError::Io(format!("bus {}: {e}", b.label())))?,
                        ),
                    });
                }
                let state = match &opts.shm {
                    Some(prefix) => Some(StateSide::create(prefix, info).map_err(RunError::Io)?),
                    None => None,
                };
                // The cycle's priority from here. Memory is locked already (above); with
                // MCL_FUTURE this thread's stack was locked and populated when it was created.
                let mut report = realtime_thread::enter_realtime(&RealtimeSettings {
                    lock_memory: false,
                    ..RealtimeSettings::default()
                });
                report.memory_locked = memory.memory_locked;
                report
                    .warnings
                    .splice(0..0, memory.warnings.iter().cloned());
                // Said now, before the first cycle (the printer waits for it).
                let _ = rt_tx.send(report.to_string());
                drop(rt_tx);
                let start = monotonic_now() + period;
                let producer = plan.cycle.sync_producer;
                let mut stepper = Stepper::new(plan)?;
                let mut lp = CycleLoop::new(
                    plan,
                    Script::new(opts.script, start),
                    state,
                    start,
                    opts.duration,
                    opts.status_every,
                )?;
                if let Some(r) = &opts.record {
                    lp.record(&r.path, &r.config, false, opts.script, opts.duration)?;
                }
                let mut io = RealIo {
                    ports,
                    producer,
                    ticker: Ticker::new(start, period),
                    period,
                    last_sync: start,
                    end: opts.duration.map(|d| start + d),
                    ends: cycle_ends,
                    exchanges,
                    segments,
                    ec_slots,
                    snapshots: snap_tx,
                    now: start,
                    ending: false,
                    end_cycle: end_cycle_io,
                    next_deadline,
                };
                while lp.iterate(&mut stepper, &mut io).is_some() {}
                // The rest (summary, closing the ports and services) is no cycle work.
                realtime_thread::leave_realtime();
                let recording = lp.finish_recording().map(|r| r.line());
                let k = lp.cycles();
                let mut summary = Summary {
                    cycles: k,
                    machine_time: period * (k as u32),
                    frames_sent: stepper.frames_sent,
                    step_ns: stepper.step_figures(),
                    frames_lost: (stepper.tx_refused, stepper.rx_dropped),
                    ..Summary::default()
                };
                finish_summary(
                    plan,
                    &stepper.cycle,
                    &lp.script,
                    &lp.following_max,
                    &mut summary,
                );
                summary.overruns = lp.overruns;
                summary.recording = recording;
                Ok(CycleResult {
                    summary,
                    late: lp.lateness(),
                    skipped: lp.skipped,
                    notify: lp.state_side().map(|st| st.notify.to_string()),
                })
            })
            .map_err(|e| RunError::Io(e.to_string()))?;

        // This thread prints: the real-time set-up first (it comes before the first cycle; if
        // the cycle thread failed before, the channel is closed and its error follows), then
        // reports, events, status; and it watches the buses.
        if let Ok(report) = rt_rx.recv() {
            say(out, &report);
        }
        let mut lines = 0usize;
        let mut hash = FrameHash::default();
        let mut busy = vec![Duration::ZERO; plan.buses.len()];
        let mut frames = vec![0u64; plan.buses.len()];
        loop {
            let finished = cycle_thread.is_finished();
            while let Ok(e) = report_rx.try_recv() {
                match e {
                    ServiceEvent::Cycle(ev) => {
                        let ending = ev.cycle() >= end_cycle.load(Ordering::Acquire);
                        note_event(plan, &ev, ending, &mut summary, out);
                    }
                    ServiceEvent::Node(r) => report_node(plan, &r, out, &mut summary),
                    ServiceEvent::BootFinished => {}
                    other => say(out, &format!("services: {other}")),
                }
                lines = 0;
            }
            while let Ok(report) = ec_rx.try_recv() {
                match report {
                    ec::SegmentReport::Line(line) => say(out, &line),
                    ec::SegmentReport::Refused { bus, why } => {
                        say(out, &format!("EtherCAT bus {bus} REFUSED: {why}"));
                        let on_bus = plan.segments.iter().filter(|s| s.name == bus);
                        for &a in on_bus.flat_map(|s| &s.axes) {
                            summary.boot_failures.push(format!(
                                "axis {}: EtherCAT bus {bus} refused: {why}",
                                plan.axes[a].name
                            ));
                        }
                    }
                }
                lines = 0;
            }
            while let Some(snap) = snap_rx.dequeue() {
                lines = print_status(out, &status_lines(plan, &snap), tty, lines);
            }
            for (b, w) in watchers.iter_mut().enumerate() {
                let Some(w) = w else { continue };
                while let Ok(Some(f)) = w.try_recv() {
                    hash.add(&f);
                    frames[b] += 1;
                    busy[b] += frame_duration(&f, plan.buses[b].bitrate);
                }
            }
            if finished {
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let mut r = cycle_thread
            .join()
            .map_err(|_| RunError::Io("the cycle thread panicked".into()))??;
        if let Some(line) = &r.notify {
            say(out, line);
        }
        let secs = r.summary.machine_time.as_secs_f64().max(1e-9);
        r.summary.frames_on_bus = frames.iter().sum();
        r.summary.frame_hash = hash.value();
        r.summary.buses = plan
            .buses
            .iter()
            .enumerate()
            .filter(|(b, _)| watchers[*b].is_some())
            .map(|(b, p)| BusFigures {
                label: p.label(),
                frames: frames[b],
                load_percent: 100.0 * busy[b].as_secs_f64() / secs,
            })
            .collect();
        Ok(r)
    })?;
    for t in exchange_threads {
        t.stop();
    }
    let mut ec_captures = Vec::new();
    let mut ec_lines = Vec::new();
    for (name, t) in segment_threads {
        let stats = t.stop();
        ec_lines.push(format!("bus {name} (EtherCAT): {stats}"));
        if let Some(dir) = &opts.capture {
            ec_captures.push(format!(
                "bus {name}: {} EtherCAT frames in {}",
                stats.captured,
                dir.join(format!("{name}.pcap")).display()
            ));
        }
    }
    let mut captures = match (capture, &opts.capture) {
        (Some(c), Some(dir)) => capture_lines(dir, c.stop()),
        _ => Vec::new(),
    };
    captures.extend(ec_captures);
    stop_sims.store(true, Ordering::Relaxed);
    if let Some(t) = sim_thread {
        let _ = t.join();
    }
    svc.stop();
    if let Some(t) = shm_thread {
        // The services are gone, so the event channel is closed and the thread ends.
        let _ = t.join();
    }
    for s in servers {
        s.shutdown();
    }
    let mut s = result.summary;
    s.boot_failures = summary.boot_failures;
    s.waiting = summary.waiting;
    s.faults = summary.faults;
    s.records_reached = summary.records_reached;
    s.late_modbus = summary.late_modbus;
    s.wake_late_ns = result.late;
    s.skipped_cycles = result.skipped;
    s.wall = wall0.elapsed();
    s.captures = captures;
    s.ethercat = ec_lines;
    Ok(s)
}

/// The `drives` thread: steps the simulators of every simulated bus as time passes.
fn step_simulated(mut sims: Vec<(VirtualBus, SimBus)>, stop: &AtomicBool) {
    // The simulated drives stand for hardware that never waits for this machine's other
    // processes: they run just below the cycle thread (the cycle thread's own report warns
    // where real-time scheduling is refused).
    let _ = realtime_thread::enter_realtime(&RealtimeSettings {
        priority: Some(70),
        cpu: None,
        lock_memory: false,
    });
    while !stop.load(Ordering::Relaxed) {
        let now = monotonic_now();
        let mut wake = now + Duration::from_micros(200);
        for (_, s) in &mut sims {
            if let Some(t) = s.settle().filter(|&t| t > now) {
                // Wake at the drives' next deadline, but look at the bus at least every 200 us
                // (frames the coordinator sends do not wake this thread).
                wake = wake.min(t);
            }
        }
        std::thread::sleep(wake.saturating_duration_since(now));
        let now = monotonic_now();
        for (bus, _) in &sims {
            bus.advance_to(now);
        }
    }
}
