//! The virtual clock: the simulated drives of every bus advanced in lockstep with the cycle
//! (discrete-event, one thread, as fast as the machine allows), deterministic.

use std::io::Write;
use std::time::Duration;

use drivers::can::{Bus, ClockMode, Frame, VirtualBus, VirtualBusConfig, VirtualPort};
use drivers::time::Instant;

use crate::axis::Image;
use crate::command::{Answer, Request};
use crate::cycle::{BusFrame, ImageInput, Transport};
use crate::event::Event;
use crate::runtime::capture::InlineCapture;
use crate::runtime::cycle_loop::{CycleIo, CycleLoop, NodeChange, Wake};
use crate::runtime::nodes::Nodes;
use crate::runtime::plan::MachinePlan;
use crate::runtime::run::{
    BusFigures, FrameHash, RunError, RunOptions, Snapshot, Summary, capture_lines, finish_summary,
    machine_line, note_event, out_is_tty, print_status, report_node, say, status_lines,
};
use crate::runtime::script::{Phase, Script};
use crate::runtime::shm::{ServiceSide, StateSide, StaticInfo};
use crate::runtime::sim::{InMemoryCmmo, SimBus, SimDrive};
use crate::runtime::stepper::{RX_CAPACITY, Stepper, TX_CAPACITY};

/// Frames taken from a port per lock of its bus (a stack buffer).
const RECV_BATCH: usize = 32;

/// Virtual time: cycles without a Modbus answer before the exchange counts as timed out.
pub const MODBUS_TIMEOUT_CYCLES: u32 = 5;

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
    /// The order the buses' simulators run in each cycle: buses with drives of the same
    /// kinds one after another (see [`bus_run_order`]).
    run_order: Vec<usize>,
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
    status_lines_printed: usize,
    tty: bool,
    /// Every event of the cycle, as well, while set (tests).
    watch: Option<Vec<Event>>,
    /// `--capture DIR`: the buses' frames as they pass the monitors.
    capture: Option<InlineCapture>,
    /// The frames taken from a port per lock of its bus, kept so that no cycle fills a fresh
    /// buffer.
    batch: [Frame; RECV_BATCH],
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
    /// Requests of in-process clients ([`VirtualRun::submit`]), taken as shared memory's are.
    inbox: std::collections::VecDeque<Request>,
    /// Their answers, until [`VirtualRun::take_answers`].
    outbox: Vec<Answer>,
    next_local: u64,
}

/// The order to run the buses' simulators in: buses whose drives are of the same kinds one
/// after another, otherwise in bus order.
///
/// The buses are independent between two cycles, so the order changes no frame. It changes
/// the speed: a cycle of a simulated drive runs tens of kilobytes of code, as much as the
/// processor's instruction cache holds, so a drive of the kind that just ran finds its code
/// still cached where one of another kind would have evicted it (`timing sim`, issue 12).
fn bus_run_order(sims: &[SimBus]) -> Vec<usize> {
    let kinds: Vec<Vec<u8>> = sims.iter().map(SimBus::kinds).collect();
    let mut order: Vec<usize> = (0..sims.len()).collect();
    // Stable: equal kinds keep their bus order.
    order.sort_by(|&a, &b| kinds[a].cmp(&kinds[b]));
    order
}

/// Tags of in-process requests carry this bit (shared memory's count up from 1).
const LOCAL_TAG: u64 = 1 << 63;
/// In-process requests waiting at most, and their answers kept at most.
pub const INBOX_CAPACITY: usize = 256;

impl std::fmt::Debug for VirtualIo<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VirtualIo")
            .field("cycle", &self.k)
            .finish_non_exhaustive()
    }
}

impl<'p> VirtualIo<'p> {
    /// The machine.
    pub fn plan(&self) -> &'p MachinePlan {
        self.plan
    }

    /// The coordinator's own port on bus `bus` (fault injection: its controller's bus-off).
    pub fn coordinator_port(&self, bus: usize) -> Option<drivers::can::PortId> {
        self.ports.get(bus).map(|p| p.id())
    }

    /// The simulated drive of an axis, on whichever bus it is.
    pub fn drive_mut(&mut self, axis: &str) -> Option<&mut SimDrive> {
        self.sims.iter_mut().find_map(|s| s.drive_mut(axis))
    }

    /// The bus of a simulated drive's axis.
    pub fn bus_of(&self, axis: &str) -> Option<&VirtualBus> {
        let i = self.plan.axis(axis)?;
        match self.plan.axes[i].setup.transport {
            Transport::Can { bus, .. } => self.buses.get(usize::from(bus)),
            Transport::Modbus { .. } | Transport::Ethercat { .. } => None,
        }
    }

    /// Runs every bus's simulated drives up to `t`, in the run order ([`bus_run_order`]).
    fn run_sims_until(&mut self, t: Instant) {
        for &b in &self.run_order {
            self.sims[b].run_until(&self.buses[b], t);
        }
    }

    fn drain_monitors(&mut self) {
        let batch = &mut self.batch;
        for (b, m) in self.monitors.iter_mut().enumerate() {
            // A batch per lock of the bus instead of a lock per frame; the same frames in the
            // same order.
            while let Ok(n @ 1..) = m.recv_batch(batch) {
                for f in &batch[..n] {
                    if let Some(c) = &mut self.capture {
                        c.write(b, f);
                    }
                    self.hash.add(f);
                    self.summary.syncs_on_bus += u64::from(f.cob_id() == Some(0x080));
                }
                if n < RECV_BATCH {
                    break;
                }
            }
        }
    }

    /// Every frame waiting at the coordinator's port on bus `b`, in order, a batch per lock.
    fn take_all(&mut self, b: usize, rx: &mut dyn FnMut(BusFrame)) {
        while let Ok(n @ 1..) = self.ports[b].recv_batch(&mut self.batch) {
            for i in 0..n {
                let f = self.batch[i];
                self.take(b, f, rx);
            }
            if n < RECV_BATCH {
                break;
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
            self.run_sims_until(now);
            self.drain_monitors();
            for b in 0..self.ports.len() {
                self.take_all(b, rx);
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

    fn node_report(&mut self) -> Option<NodeChange> {
        let r = self.nodes.poll_report()?;
        report_node(self.plan, &r, &mut self.text, &mut self.summary);
        Some(NodeChange::from(&r))
    }

    fn image_input(&mut self, _k: u64, slot: usize, last: &Image, now: Instant) -> ImageInput {
        let Some(i) = self.cmmo.iter().position(|(s, _)| *s == slot) else {
            return ImageInput::default();
        };
        let answer = self.cmmo[i].1.exchange(&last.data, now);
        let missed = &mut self.modbus_missed[i];
        *missed = if answer.is_some() {
            0
        } else {
            missed.saturating_add(1)
        };
        ImageInput {
            image: answer
                .and_then(|a| Image::from_slice(&a))
                .unwrap_or_default(),
            fresh: answer.is_some(),
            late_cycles: 0,
            lost: *missed >= MODBUS_TIMEOUT_CYCLES,
            ..ImageInput::default()
        }
    }

    fn image_output(&mut self, _k: u64, _slot: usize, _output: &Image) {
        // The next cycle's exchange carries it (see `image_input`).
    }

    fn request(&mut self) -> Option<Request> {
        // In-process clients first (`VirtualRun::submit`), then shared memory's.
        if let Some(r) = self.inbox.pop_front() {
            return Some(r);
        }
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
        if answer.tag & LOCAL_TAG != 0 {
            if self.outbox.len() < self.outbox.capacity() {
                self.outbox.push(answer);
            }
            return;
        }
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
            || crate::runtime::signals::stop_flag().load(std::sync::atomic::Ordering::Relaxed);
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
    pub stepper: Stepper<'p>,
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
    /// of `plan` must be simulated (see [`crate::runtime::run::run`]).
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
        let run_order = bus_run_order(&sims);
        let mut cmmo = Vec::new();
        for a in &plan.axes {
            if let Transport::Modbus { slot } = a.setup.transport {
                cmmo.push((
                    usize::from(slot),
                    InMemoryCmmo::new(t0).map_err(RunError::Io)?,
                ));
            }
        }
        let stepper = Stepper::new(plan)?;
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
        let mut lp = CycleLoop::new(
            plan,
            Script::new(opts.script, t0),
            state,
            t0,
            None,
            opts.status_every,
        )?;
        if let Some(r) = &opts.record {
            // Virtual time ends from outside the loop (`run_virtual`): recorded per cycle.
            lp.record(&r.path, &r.config, true, opts.script, None)?;
        }
        let capture = match &opts.capture {
            Some(dir) => {
                let names: Vec<String> = plan.buses.iter().map(|b| b.name.clone()).collect();
                Some(InlineCapture::create(dir, &names).map_err(RunError::Io)?)
            }
            None => None,
        };
        Ok(VirtualRun {
            stepper,
            lp,
            io: VirtualIo {
                plan,
                buses,
                ports,
                monitors,
                sims,
                run_order,
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
                status_lines_printed: 0,
                tty: out_is_tty(),
                watch: None,
                capture,
                batch: [Frame::std8(0, [0; 8]); RECV_BATCH],
                capture_dir: opts.capture.clone(),
                held: None,
                later: Vec::with_capacity(RX_CAPACITY),
                pending_rx: Vec::with_capacity(RX_CAPACITY),
                synced: 0,
                missed_syncs: 0,
                ending: false,
                inbox: std::collections::VecDeque::with_capacity(INBOX_CAPACITY),
                outbox: Vec::with_capacity(INBOX_CAPACITY),
                next_local: 0,
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

    /// Queues a client's command for the next cycle, taken through the same path as a shared-
    /// memory client's (admission, answer, recording); returns its tag, or `None` when
    /// [`INBOX_CAPACITY`] commands already wait.
    pub fn submit(&mut self, command: crate::command::Command) -> Option<u64> {
        if self.io.inbox.len() >= INBOX_CAPACITY {
            return None;
        }
        let tag = LOCAL_TAG | self.io.next_local;
        self.io.next_local += 1;
        self.io.inbox.push_back(Request { tag, command });
        Some(tag)
    }

    /// The answers to [`VirtualRun::submit`]'s commands since the last call.
    pub fn take_answers(&mut self) -> Vec<Answer> {
        // Drained, not taken: the outbox keeps its capacity (pushing never allocates).
        self.io.outbox.drain(..).collect()
    }

    /// Waits for the answer to `tag`: steps until it comes (at most `cycles` cycles).
    pub fn answer_to(
        &mut self,
        tag: u64,
        cycles: u32,
        out: &mut dyn Write,
    ) -> Option<crate::command::Reply> {
        for _ in 0..cycles {
            if let Some(i) = self.io.outbox.iter().position(|a| a.tag == tag) {
                return Some(self.io.outbox.swap_remove(i).reply);
            }
            self.step(out);
        }
        None
    }

    /// Runs one cycle: the drives up to this SYNC, receive, boot, Modbus, commands, script,
    /// step, send. Events, reports and status are printed to `out`.
    pub fn step(&mut self, out: &mut dyn Write) {
        self.io.ending = self.lp.ending();
        self.lp.iterate(&mut self.stepper, &mut self.io);
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
        self.io.run_sims_until(last + plan.period);
        self.io.drain_monitors();
        let mut summary = std::mem::take(&mut self.io.summary);
        summary.cycles = self.lp.cycles();
        summary.machine_time = last - self.io.t0;
        summary.wall = wall;
        summary.frames_sent = self.stepper.frames_sent;
        // The wire's own account of its frames and busy time: the frames the monitor saw.
        summary.buses = plan
            .buses
            .iter()
            .zip(&self.io.buses)
            .map(|(p, bus)| {
                let wire = bus.stats();
                BusFigures {
                    label: p.label(),
                    frames: wire.frames,
                    load_percent: 100.0 * wire.busy.as_secs_f64()
                        / summary.machine_time.as_secs_f64().max(1e-9),
                }
            })
            .collect();
        summary.frames_on_bus = summary.buses.iter().map(|b| b.frames).sum();
        summary.step_ns = self.stepper.step_figures();
        summary.frames_lost = (self.stepper.tx_refused, self.stepper.rx_dropped);
        summary.frame_hash = self.io.hash.value();
        finish_summary(
            plan,
            &self.stepper.cycle,
            &self.lp.script,
            &self.lp.following_max,
            &mut summary,
        );
        summary.recording = self.lp.finish_recording().map(|r| r.line());
        if let (Some(c), Some(dir)) = (self.io.capture.take(), &self.io.capture_dir) {
            summary.captures = capture_lines(dir, c.finish());
        }
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
    say(out, &machine_line(plan, "virtual time"));
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Config;
    use crate::runtime::plan::plan;
    use crate::runtime::synthetic::{self, Kinds, Spec};

    /// Eight CiA 402 drives at 1 ms, each on its own bus, TLC5xx and MTR-DCI in turn.
    fn eight_buses() -> MachinePlan {
        let spec = Spec {
            axes: 8,
            kinds: Kinds::Cia402,
            group_size: None,
        };
        let text = synthetic::config_of_with_cycle_us(&spec, 1000).expect("the machine fits");
        plan(&Config::parse(&text).expect("it parses")).expect("it plans")
    }

    /// The frame hash of 6000 cycles (the boot, the homing and the demo's first moves: the
    /// synthetic machine is homed after about 4500), with the buses' simulators run in `order`,
    /// or in the run's own order. A fixed count, not "until running": another unit test raises
    /// SIGTERM in this process, which ends every virtual run in an orderly way, whose frames
    /// must not depend on the order either.
    fn frame_hash(plan: &MachinePlan, order: Option<Vec<usize>>) -> (u64, Vec<usize>) {
        let mut run = VirtualRun::new(plan, &synthetic::demo_options(false)).expect("it builds");
        if let Some(o) = order {
            run.io.run_order = o;
        }
        let used = run.io.run_order.clone();
        let mut text = Vec::new();
        for _ in 0..6000 {
            run.step(&mut text);
        }
        (run.finish(Duration::ZERO).frame_hash, used)
    }

    #[test]
    fn buses_of_one_kind_run_together_and_the_order_changes_no_frame() {
        let plan = eight_buses();
        assert_eq!(plan.buses.len(), 8, "one drive per bus at 1 ms");
        let (grouped, order) = frame_hash(&plan, None);
        // TLC5xx on the even buses, MTR-DCI on the odd ones: each kind's buses together, in
        // bus order.
        assert_eq!(order, [1, 3, 5, 7, 0, 2, 4, 6]);
        let (in_bus_order, _) = frame_hash(&plan, Some((0..8).collect()));
        let (reversed, _) = frame_hash(&plan, Some((0..8).rev().collect()));
        assert_eq!(grouped, in_bus_order);
        assert_eq!(grouped, reversed);
    }
}
