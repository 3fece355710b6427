//! Real time: the cycle on its own thread, woken at absolute deadlines (`clock_nanosleep`),
//! with SCHED_FIFO and locked memory where granted; the simulated drives on a thread of their
//! own on the real-clock virtual bus; each CMMO-ST as a Modbus TCP server on loopback with the
//! exchange on its own thread; boot, command intake and reports on the services' executor.
//! The main thread prints what the others report.

use std::io::Write;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::Duration;

use drivers::can::bit_timing::frame_duration;
use drivers::can::{Bus, ClockMode, VirtualBus, VirtualBusConfig};
use drivers::time::monotonic_now;
use hdrhistogram::Histogram;
use heapless::spsc::Queue;

use crate::axis::Image;
use crate::command::Answer;
use crate::cycle::{ModbusInput, Transport};
use crate::runtime::modbus::{self as mb, Link, ModbusSettings};
use crate::runtime::plan::MachinePlan;
use crate::runtime::rt::{self, RtSettings, Ticker};
use crate::runtime::run::{
    CycleCore, FrameHash, RX_CAPACITY, RunError, RunOptions, SDO_PER_CYCLE, Snapshot, Summary,
    TX_CAPACITY, axis_of_node, finish_summary, note_event, out_is_tty, print_status, report_boot,
    say, send_all, status_lines,
};
use crate::runtime::script::{Phase, Script};
use crate::runtime::services::{self, ServiceEvent};
use crate::runtime::shm::{StateSide, StaticInfo};
use crate::runtime::sim::{SimBus, spawn_cmmo_server};

/// Snapshots in flight from the cycle thread to the printer.
const SNAPSHOTS: usize = 4;

/// What the cycle thread hands back when it ends.
struct CycleResult {
    summary: Summary,
    late: (u64, u64, u64),
    skipped: u64,
}

/// Runs `plan` in real time (see the module docs).
pub fn run_real(
    plan: &MachinePlan,
    opts: &RunOptions,
    out: &mut dyn Write,
) -> Result<Summary, RunError> {
    let wall0 = std::time::Instant::now();
    let bitrate = plan.bus.as_ref().map_or(1_000_000, |b| b.2);
    let bus = VirtualBus::new(VirtualBusConfig {
        bitrate,
        clock: ClockMode::Real,
        rx_capacity: RX_CAPACITY,
        tx_capacity: TX_CAPACITY,
        ..VirtualBusConfig::default()
    })
    .map_err(|e| RunError::Io(e.to_string()))?;
    let t0 = bus.now();
    let mut port = bus.attach("coordinator");
    let mut monitor = bus.attach_monitor("monitor");
    let mut sims = SimBus::build(&bus, plan, t0).map_err(RunError::Io)?;

    // The CMMO-STs: a Modbus TCP server each, and the exchange thread each.
    let mut servers = Vec::new();
    let mut exchanges = Vec::new();
    for a in &plan.axes {
        if let Transport::Modbus { slot } = a.setup.transport {
            let server = spawn_cmmo_server().map_err(RunError::Io)?;
            let settings = ModbusSettings {
                period: plan.period,
                ..ModbusSettings::default()
            };
            let (side, thread) = mb::spawn(server.local_addr(), settings)
                .map_err(|e| RunError::Io(format!("axis {}: Modbus TCP: {e}", a.name)))?;
            say(
                out,
                &format!(
                    "axis {}: simulated CMMO-ST on Modbus TCP {}",
                    a.name,
                    server.local_addr()
                ),
            );
            servers.push(server);
            exchanges.push((usize::from(slot), side, thread));
        }
    }

    // Services: boot, commands, reports. Their reports reach this thread over a channel.
    let (cycle_ends, service_ends) = services::channels();
    let (report_tx, report_rx) = mpsc::channel::<ServiceEvent>();
    let (shm_tx, shm_rx) = mpsc::channel::<crate::event::Event>();
    let shm_tx = opts.shm.as_ref().map(|_| shm_tx);
    let plans: Vec<_> = plan.axes.iter().filter_map(|a| a.boot.clone()).collect();
    let boot_count = plans.len();
    let svc = services::spawn_services(
        service_ends,
        plans,
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
    let shm_thread = match &opts.shm {
        Some(prefix) => {
            let _ = shm_api::publisher::cleanup_dead_nodes();
            Some(
                crate::runtime::shm::spawn_command_thread(
                    prefix.clone(),
                    info.clone(),
                    svc.client(),
                    shm_rx,
                )
                .map_err(|e| RunError::Io(e.to_string()))?,
            )
        }
        None => None,
    };

    // The simulated drives, stepped as time passes.
    let stop_sims = Arc::new(AtomicBool::new(false));
    let sim_stop = stop_sims.clone();
    let sim_bus = bus.clone();
    let sim_thread = std::thread::Builder::new()
        .name("drives".into())
        .spawn(move || {
            // The simulated drives stand for hardware that never waits for this machine's
            // other processes: they run just below the cycle thread (a warning is printed by
            // the cycle thread's own report where real-time scheduling is refused).
            let _ = rt::enter_realtime(&RtSettings {
                priority: Some(70),
                cpu: None,
                lock_memory: false,
            });
            while !sim_stop.load(Ordering::Relaxed) {
                let next = sims.settle();
                let now = monotonic_now();
                // Wake at the drives' next deadline, but look at the bus at least every 200 us
                // (frames the coordinator sends do not wake this thread).
                let wake = next
                    .filter(|&t| t > now)
                    .unwrap_or(now + Duration::from_micros(200))
                    .min(now + Duration::from_micros(200));
                std::thread::sleep(wake.saturating_duration_since(now));
                sim_bus.advance_to(monotonic_now());
            }
        })
        .map_err(|e| RunError::Io(e.to_string()))?;

    let snapshots: &'static mut Queue<Snapshot, { SNAPSHOTS + 1 }> =
        Box::leak(Box::new(Queue::new()));
    let (mut snap_tx, mut snap_rx) = snapshots.split();
    let stop = rt::stop_flag();
    let period = plan.period;
    let mut summary = Summary::default();
    let tty = out_is_tty();

    let result = std::thread::scope(|s| -> Result<CycleResult, RunError> {
        let cycle_thread = std::thread::Builder::new()
            .name("cycle".into())
            .stack_size(64 << 20)
            .spawn_scoped(s, move || -> Result<(CycleResult, String), RunError> {
                let report = rt::enter_realtime(&RtSettings::default());
                let mut ends = cycle_ends;
                let mut shm_state = match &opts.shm {
                    Some(prefix) => Some(StateSide::create(prefix, info).map_err(RunError::Io)?),
                    None => None,
                };
                let relay_stop = Arc::new(AtomicBool::new(false));
                let mut relay = None;
                let mut core = CycleCore::new(plan)?;
                let mut script = Script::new(opts.script, t0);
                let mut late = Histogram::<u64>::new_with_bounds(1, 10_000_000_000, 3)
                    .map_err(|e| RunError::Config(e.to_string()))?;
                let mut skipped = 0u64;
                let mut booted = 0usize;
                let start = monotonic_now() + period;
                let producer = plan.cycle.sync_producer;
                let mut ticker = Ticker::new(start, period);
                if let (Some(st), Some(prefix)) = (&shm_state, &opts.shm)
                    && producer
                {
                    // Event-driven clients: a relay wakes 5 µs after each deadline and
                    // signals the new state; the cycle thread itself never notifies.
                    relay = shm_api::publisher::spawn_state_relay(
                        prefix.clone(),
                        start.as_nanos(),
                        period,
                        Duration::from_micros(5),
                        st.published.clone(),
                        relay_stop.clone(),
                    )
                    .ok();
                }
                let mut last_late_ns = 0u64;
                let mut last_sync = start;
                let end = opts.duration.map(|d| start + d);
                let mut next_status = opts.status_every.map(|d| start + d);
                let mut exchanges = exchanges;
                let mut k = 0u64;
                loop {
                    let now = if producer {
                        let tick = ticker.wait();
                        last_late_ns = tick.late.as_nanos() as u64;
                        let _ = late.record(last_late_ns.max(1));
                        skipped += tick.skipped;
                        while let Ok(Some(f)) = port.try_recv() {
                            let _ = ends.offer_received(&f);
                            core.receive(f);
                        }
                        tick.deadline
                    } else {
                        // SYNC consumer: the received SYNC starts the cycle; what arrives before
                        // it belongs to this cycle. Two periods without SYNC count as missed.
                        let mut deadline = last_sync + period * 2;
                        loop {
                            match port.recv_until(deadline) {
                                Ok(Some(f)) if f.cob_id() == Some(0x080) => {
                                    let t = f.timestamp();
                                    last_late_ns =
                                        monotonic_now().saturating_duration_since(t).as_nanos()
                                            as u64;
                                    let _ = late.record(last_late_ns.max(1));
                                    last_sync = t;
                                    break t;
                                }
                                Ok(Some(f)) => {
                                    let _ = ends.offer_received(&f);
                                    core.receive(f);
                                }
                                Ok(None) | Err(_) => {
                                    skipped += 1;
                                    deadline += period;
                                    // No SYNC: a stop (Ctrl-C, the duration) still runs the
                                    // cycle so that the drives are disabled.
                                    let over = end.is_some_and(|e| monotonic_now() >= e);
                                    if over || stop.load(Ordering::Relaxed) {
                                        break monotonic_now();
                                    }
                                }
                            }
                        }
                    };
                    while let Some(r) = ends.boot_reports.dequeue() {
                        booted += 1;
                        if let Some(a) = axis_of_node(plan, r.node.get()) {
                            core.cycle.set_online(a, r.result.is_ok(), now);
                        }
                    }
                    for (slot, side, _) in &mut exchanges {
                        let m = side.take_input(k);
                        core.modbus_input(
                            *slot,
                            ModbusInput {
                                image: Image::from_slice(&m.data).unwrap_or_default(),
                                fresh: m.fresh,
                                late_cycles: m.late_cycles,
                                lost: matches!(m.link, Link::TimedOut(_) | Link::Down(_)),
                            },
                        );
                    }
                    while let Some(req) = ends.requests.dequeue() {
                        let reply = core.cycle.command(&req.command);
                        let _ = ends.answer(Answer {
                            tag: req.tag,
                            reply,
                        });
                    }
                    if end.is_some_and(|e| now >= e) || stop.load(Ordering::Relaxed) {
                        script.shut_down();
                    }
                    script.poll(&mut core.cycle, booted >= boot_count, now);
                    let frames = core.iterate(now);
                    let refused = send_all(&mut port, frames);
                    core.tx_refused += refused;
                    for _ in 0..SDO_PER_CYCLE {
                        match ends.tx_frames.dequeue() {
                            Some(f) => {
                                core.tx_refused += send_all(&mut port, &[f]);
                            }
                            None => break,
                        }
                    }
                    for (slot, side, _) in &mut exchanges {
                        side.put_output(k, &core.modbus_output(*slot).data);
                    }
                    if let Some(st) = &mut shm_state {
                        let late_us = (last_late_ns / 1000).min(u64::from(u32::MAX)) as u32;
                        st.counters = core.counters(skipped, late_us);
                        st.publish(&core.cycle, now.as_nanos());
                    }
                    while let Some(e) = core.cycle.poll_event() {
                        let _ = ends.event(e);
                    }
                    if let Some(t) = next_status
                        && now >= t
                    {
                        let _ = snap_tx.enqueue(Snapshot::take(&core.cycle, now - start));
                        next_status = opts.status_every.map(|d| t + d);
                    }
                    k += 1;
                    if script.phase() == Phase::Done {
                        break;
                    }
                }
                let mut summary = Summary {
                    cycles: k,
                    machine_time: period * (k as u32),
                    frames_sent: core.frames_sent,
                    step_ns: core.step_figures(),
                    frames_lost: (core.tx_refused, core.rx_dropped),
                    ..Summary::default()
                };
                finish_summary(plan, &core.cycle, &script, &mut summary);
                for (_, _, thread) in exchanges {
                    thread.stop();
                }
                relay_stop.store(true, Ordering::Relaxed);
                if let Some(r) = relay {
                    let _ = r.join();
                }
                Ok((
                    CycleResult {
                        summary,
                        late: (
                            late.value_at_quantile(0.5),
                            late.value_at_quantile(0.99),
                            late.max(),
                        ),
                        skipped,
                    },
                    report.to_string(),
                ))
            })
            .map_err(|e| RunError::Io(e.to_string()))?;

        // This thread prints: reports, events, status.
        let mut lines = 0usize;
        let mut hash = FrameHash::default();
        let mut busy = Duration::ZERO;
        let mut frames = 0u64;
        loop {
            let finished = cycle_thread.is_finished();
            while let Ok(e) = report_rx.try_recv() {
                match e {
                    ServiceEvent::Cycle(ev) => note_event(plan, &ev, &mut summary, out),
                    ServiceEvent::Boot(r) => report_boot(plan, &r, out, &mut summary),
                    other => say(out, &format!("services: {other}")),
                }
                lines = 0;
            }
            while let Some(snap) = snap_rx.dequeue() {
                lines = print_status(out, &status_lines(plan, &snap), tty, lines);
            }
            while let Ok(Some(f)) = monitor.try_recv() {
                hash.add(&f);
                frames += 1;
                busy += frame_duration(&f, bitrate);
            }
            if finished {
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let (mut r, rt_report) = cycle_thread
            .join()
            .map_err(|_| RunError::Io("the cycle thread panicked".into()))??;
        if !rt_report.is_empty() {
            say(out, &rt_report);
        }
        r.summary.frames_on_bus = frames;
        r.summary.frame_hash = hash.value();
        r.summary.bus_load_percent =
            100.0 * busy.as_secs_f64() / r.summary.machine_time.as_secs_f64().max(1e-9);
        Ok(r)
    })?;
    stop_sims.store(true, Ordering::Relaxed);
    let _ = sim_thread.join();
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
    s.faults = summary.faults;
    s.records_reached = summary.records_reached;
    s.late_modbus = summary.late_modbus;
    s.wake_late_ns = result.late;
    s.skipped_cycles = result.skipped;
    s.wall = wall0.elapsed();
    Ok(s)
}
