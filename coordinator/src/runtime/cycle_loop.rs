//! One cycle iteration for both clocks, behind one I/O seam.
//!
//! [`CycleLoop::iterate`] is everything the coordinator does once per cycle: wait for the
//! cycle and take what arrived, bring drives in and out of the cycle, take the Modbus images and
//! client commands, let the script (the built-in client) act, step, send the frames (PDOs first,
//! then a bounded number of SDO/NMT frames), hand out the Modbus outputs, publish the state and
//! the events. Where those come from and go to is a [`CycleIo`]: [`crate::runtime::run`]'s
//! virtual clock (the simulated drives advanced in lockstep, the boot inline) or
//! [`crate::runtime::real_clock`]'s real clock (absolute deadlines, the bus ports, the services'
//! queues, the Modbus exchange threads). Nothing here allocates after [`CycleLoop::new`].

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use drivers::time::Instant;
use hdrhistogram::Histogram;

use crate::axis::Image;
use crate::command::{Answer, Request};
use crate::cycle::{BusFrame, ImageInput};
use crate::event::Event;
use crate::runtime::nodes::{self, NodeReport, NodeStatus};
use crate::runtime::plan::MachinePlan;
use crate::runtime::record::format::Header;
use crate::runtime::record::recorder::{RecordStats, Recorder, Tap};
use crate::runtime::run::{RunError, Snapshot};
use crate::runtime::script::{Phase, Script};
use crate::runtime::shm::StateSide;
use crate::runtime::stepper::Stepper;

/// When a cycle starts, as the clock saw it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Wake {
    /// The cycle's time (its SYNC).
    pub now: Instant,
    /// How late the wake-up was, ns (0 in virtual time).
    pub late_ns: u64,
    /// Cycles the clock skipped before this one because the coordinator was not there (an
    /// overrun: the host stalled it).
    pub skipped: u64,
}

impl Wake {
    /// The lateness in whole µs, as the published state carries it (saturating).
    pub fn late_us(&self) -> u32 {
        (self.late_ns / 1000).min(u64::from(u32::MAX)) as u32
    }
}

/// A drive report as the cycle takes it: the axis and what the report means.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NodeChange {
    /// The axis.
    pub axis: crate::command::AxisId,
    /// What the report means for it.
    pub status: NodeStatus,
}

impl From<&NodeReport> for NodeChange {
    fn from(r: &NodeReport) -> NodeChange {
        NodeChange {
            axis: r.axis,
            status: r.status(),
        }
    }
}

/// What one cycle iteration talks to. Every method is called on the cycle thread and must not
/// allocate, lock or block (except [`CycleIo::wait`], which is where the cycle sleeps).
pub trait CycleIo {
    /// Waits for the next cycle (real time: its deadline or its received SYNC; virtual time:
    /// runs the simulated drives up to it) and hands every frame received since the last cycle
    /// to `rx`, bus by bus in arrival order.
    fn wait(&mut self, rx: &mut dyn FnMut(BusFrame)) -> Wake;
    /// The next drive report (booted, waiting, lost, refused), if any: its axis and what it
    /// means for the cycle.
    fn node_report(&mut self) -> Option<NodeChange>;
    /// Image slot `slot`'s input for cycle `k` (a Modbus drive's or an EtherCAT subdevice's);
    /// `last_output` is what the cycle wrote to it last.
    fn image_input(&mut self, k: u64, slot: usize, last_output: &Image, now: Instant)
    -> ImageInput;
    /// Image slot `slot`'s output of cycle `k`.
    fn image_output(&mut self, k: u64, slot: usize, output: &Image);
    /// Every slot's output of cycle `k` was given: an EtherCAT bus sends them now, in one
    /// frame.
    fn images_sent(&mut self, _k: u64) {}
    /// The next client request, if any.
    fn request(&mut self) -> Option<Request>;
    /// The answer to a request.
    fn answer(&mut self, answer: Answer);
    /// Sends one frame; `false` if the bus refused it.
    fn send(&mut self, frame: &BusFrame) -> bool;
    /// The next SDO/NMT frame of the drives' boot, if any.
    fn service_frame(&mut self, now: Instant) -> Option<BusFrame>;
    /// Whether a stop signal came (the loop's `flag`, set by [`crate::runtime::signals`]).
    fn stop_asked(&mut self, flag: &AtomicBool) -> bool {
        flag.load(Ordering::Relaxed)
    }
    /// One event of the cycle.
    fn event(&mut self, e: Event);
    /// A status snapshot is due.
    fn status(&mut self, snapshot: Snapshot);
}

/// The per-run state of the cycle iteration: the schedule, the script, the published state,
/// the drives reported so far, the clock's figures.
pub struct CycleLoop<'p> {
    plan: &'p MachinePlan,
    /// The built-in client (the demonstration script).
    pub script: Script,
    state: Option<StateSide>,
    /// Per axis: whether its drive has had its first report.
    reported: Vec<bool>,
    unreported: usize,
    /// Image slot (Modbus, EtherCAT), its axis, and whether it has answered yet.
    image_slots: Vec<(usize, crate::command::AxisId, bool)>,
    start: Instant,
    end: Option<Instant>,
    next_status: Option<Instant>,
    status_every: Option<Duration>,
    k: u64,
    ending: bool,
    /// Cycles the clock skipped (overruns).
    pub skipped: u64,
    /// Overruns (wake-ups that skipped cycles), and the longest, ns.
    pub overruns: (u64, u64),
    /// Ctrl-C (installed before the first cycle: installing allocates).
    stop: &'static std::sync::atomic::AtomicBool,
    late: Histogram<u64>,
    /// When set, the next iteration keeps a copy of the cycle and its inputs right before the
    /// step (benchmarks replay it) and clears the flag.
    pub capture: bool,
    /// The copy [`CycleLoop::capture`] asked for.
    pub captured: Option<crate::runtime::stepper::Captured<'p>>,
    /// Per bus: SDO/NMT frames it may carry per cycle (its budget's slots), and what is left of
    /// them in this cycle.
    sdo_slots: Vec<(u16, u16)>,
    /// A service frame for a bus whose slots were used up: it goes first next cycle.
    held: Option<BusFrame>,
    /// Called with `true` right before the cycle thread's own work of a cycle (the script's
    /// commands and the step) and with `false` right after: tests count allocations there.
    pub probe: Option<fn(bool)>,
    /// `--record`: what enters each cycle and what it puts out, to the writer.
    recorder: Option<Recorder>,
    /// Whether the orderly end had begun when the last iteration ended (a later change came
    /// from outside the loop: recorded).
    ending_seen: bool,
    /// Per axis: the largest |setpoint − actual position| seen while it followed a move,
    /// increments: the quantity the cycle's following-error fault watches (this cycle's
    /// set-point against the last position reported, so it holds the transport delay too).
    pub following_max: Vec<i64>,
}

impl std::fmt::Debug for CycleLoop<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CycleLoop")
            .field("cycle", &self.k)
            .finish_non_exhaustive()
    }
}

impl<'p> CycleLoop<'p> {
    /// The iteration of `plan`, its first cycle at `start`; it ends `duration` after it (then
    /// the script stops and disables), or at Ctrl-C.
    pub fn new(
        plan: &'p MachinePlan,
        script: Script,
        state: Option<StateSide>,
        start: Instant,
        duration: Option<Duration>,
        status_every: Option<Duration>,
    ) -> Result<CycleLoop<'p>, RunError> {
        // CANopen axes are booted by their bus's sequencer, EtherCAT axes by their segment's
        // thread; Modbus axes join with their first answer.
        let reported: Vec<bool> = plan
            .axes
            .iter()
            .map(|a| a.boot.is_none() && a.ethercat.is_none())
            .collect();
        Ok(CycleLoop {
            plan,
            script,
            state,
            unreported: reported.iter().filter(|r| !**r).count(),
            reported,
            image_slots: plan
                .axes
                .iter()
                .enumerate()
                .filter_map(|(i, a)| {
                    let slot = a.setup.transport.image_slot()?;
                    Some((usize::from(slot), i as u16, false))
                })
                .collect(),
            start,
            end: duration.map(|d| start + d),
            next_status: status_every.map(|d| start + d),
            status_every,
            k: 0,
            ending: false,
            skipped: 0,
            overruns: (0, 0),
            stop: crate::runtime::signals::stop_flag(),
            late: Histogram::new_with_bounds(1, 10_000_000_000, 3)
                .map_err(|e| RunError::Config(e.to_string()))?,
            capture: false,
            captured: None,
            sdo_slots: plan.buses.iter().map(|b| (b.sdo_slots, 0)).collect(),
            held: None,
            probe: None,
            recorder: None,
            ending_seen: false,
            following_max: vec![0; plan.axes.len()],
        })
    }

    /// Records every cycle from now on into `path` (`--record`); `config` is the machine's
    /// configuration text, `virtual_time` the clock. Call before the first cycle.
    pub fn record(
        &mut self,
        path: &std::path::Path,
        config: &str,
        virtual_time: bool,
        script: crate::runtime::script::ScriptOptions,
        duration: Option<Duration>,
    ) -> Result<(), RunError> {
        let header = Header {
            recorder: format!("coordinator {}", env!("CARGO_PKG_VERSION")),
            config: String::new(),
            virtual_time,
            start_ns: self.start.as_nanos(),
            duration_ns: duration.map(|d| d.as_nanos().min(u128::from(u64::MAX)) as u64),
            script: [script.demo, script.chains, script.home],
            state_size: std::mem::size_of::<shm_api::contract::MachineState>() as u32,
            layout_hash: shm_api::contract::LAYOUT_HASH,
        };
        self.recorder =
            Some(Recorder::create(path, self.plan, config, header).map_err(RunError::Io)?);
        Ok(())
    }

    /// Ends the recording, if one runs: the writer drains and closes the file.
    pub fn finish_recording(&mut self) -> Option<RecordStats> {
        self.recorder.take().map(Recorder::finish)
    }

    /// Cycles run.
    pub fn cycles(&self) -> u64 {
        self.k
    }

    /// When the first cycle was due.
    pub fn start(&self) -> Instant {
        self.start
    }

    /// Every drive has had its first report.
    pub fn booted(&self) -> bool {
        self.unreported == 0
    }

    /// Whether the orderly end has been asked for.
    pub fn ending(&self) -> bool {
        self.ending
    }

    /// Asks for the orderly end (stop, disable) now.
    pub fn shut_down(&mut self) {
        self.ending = true;
        self.script.shut_down();
    }

    /// Wake-up lateness: median, p99, max, ns.
    pub fn lateness(&self) -> (u64, u64, u64) {
        let h = &self.late;
        (h.value_at_quantile(0.5), h.value_at_quantile(0.99), h.max())
    }

    /// The published state, if the machine is published.
    pub fn state_side(&self) -> Option<&StateSide> {
        self.state.as_ref()
    }

    /// One cycle; returns its time, or `None` once the script has finished (the run is over).
    pub fn iterate<I: CycleIo>(
        &mut self,
        stepper: &mut Stepper<'p>,
        io: &mut I,
    ) -> Option<Instant> {
        let next = match self.recorder.take() {
            None => self.cycle(stepper, io),
            Some(mut rec) => {
                // The recording's own work on the cycle thread is probed too.
                let hook = self.probe;
                let probe = |on| {
                    if let Some(p) = hook {
                        p(on);
                    }
                };
                probe(true);
                rec.begin(self.ending && !self.ending_seen);
                probe(false);
                let k = self.k;
                let next = self.cycle(
                    stepper,
                    &mut Tap {
                        io,
                        rec: rec.record(),
                    },
                );
                let late_us = rec.record().wake.late_us();
                probe(true);
                rec.end(k, stepper, stepper.counters(self.skipped, late_us));
                probe(false);
                self.recorder = Some(rec);
                next
            }
        };
        self.ending_seen = self.ending;
        next
    }

    /// The cycle itself (see [`CycleLoop::iterate`]).
    fn cycle<I: CycleIo>(&mut self, stepper: &mut Stepper<'p>, io: &mut I) -> Option<Instant> {
        let wake = io.wait(&mut |f| stepper.receive(f));
        let now = wake.now;
        self.skipped += wake.skipped;
        let _ = self.late.record(wake.late_ns.max(1));
        if wake.skipped > 0 {
            // The coordinator itself was away: not the drives' fault (see `Cycle::overrun`).
            // The clock skipped whole periods; the lateness is past the last one skipped.
            let period = self.plan.period.as_nanos() as u64;
            let away = wake.late_ns + wake.skipped.saturating_mul(period);
            self.overruns.0 += 1;
            self.overruns.1 = self.overruns.1.max(away);
            stepper.cycle.overrun(wake.skipped, away);
        }
        while let Some(r) = io.node_report() {
            nodes::apply(&mut stepper.cycle, r.axis, r.status, now);
            if let Some(seen) = self.reported.get_mut(usize::from(r.axis))
                && !*seen
            {
                *seen = true;
                self.unreported -= 1;
            }
        }
        for (slot, axis, seen) in &mut self.image_slots {
            let last = stepper.image_output(*slot);
            let m = io.image_input(self.k, *slot, &last, now);
            // A Modbus drive needs no boot: it joins the cycle with its first answer, and from
            // then on a lost link faults it.
            if m.fresh && !*seen {
                *seen = true;
                stepper.cycle.set_online(*axis, true, now);
            }
            stepper.image_input(*slot, m);
        }
        if let Some(p) = self.probe {
            p(true);
        }
        // The one command path: a client's request, the script's commands and a signal's
        // safe stop (the script's, after `shut_down`) all reach the cycle through
        // `Cycle::command`, its admission table and its replies, in this order each cycle.
        while let Some(req) = io.request() {
            let reply = stepper.cycle.command(&req.command);
            io.answer(Answer {
                tag: req.tag,
                reply,
            });
        }
        let over = self.end.is_some_and(|e| now >= e);
        if (over || io.stop_asked(self.stop)) && !self.ending {
            self.shut_down();
        }
        let booted = self.booted();
        self.script.poll(&stepper.cycle, booted, now);
        while let Some(c) = self.script.next_command() {
            let reply = stepper.cycle.command(&c);
            self.script.answered(reply);
        }
        if std::mem::take(&mut self.capture) {
            self.captured = Some(stepper.capture(now));
        }
        let frames = stepper.iterate(now);
        if let Some(p) = self.probe {
            p(false);
        }
        let mut refused = 0;
        for f in frames {
            refused += u64::from(!io.send(f));
        }
        // The boot's SDO/NMT frames, within each bus's slots (the budget `check` computed): a
        // frame for a bus whose slots are used up waits for the next cycle.
        for s in &mut self.sdo_slots {
            s.1 = s.0;
        }
        let total: usize = self.sdo_slots.iter().map(|s| usize::from(s.0)).sum();
        for _ in 0..total {
            let Some(f) = self.held.take().or_else(|| io.service_frame(now)) else {
                break;
            };
            match self.sdo_slots.get_mut(usize::from(f.bus)) {
                Some(s) if s.1 > 0 => {
                    s.1 -= 1;
                    refused += u64::from(!io.send(&f));
                }
                Some(_) => {
                    self.held = Some(f);
                    break;
                }
                // A frame for no bus (cannot happen: the boot plans only configured buses).
                None => {}
            }
        }
        stepper.tx_refused += refused;
        for &(slot, _, _) in &self.image_slots {
            io.image_output(self.k, slot, &stepper.image_output(slot));
        }
        io.images_sent(self.k);
        for (i, m) in self.following_max.iter_mut().enumerate() {
            if let Some(st) = stepper.cycle.axis_status(i as crate::ids::AxisId)
                && st.moving
                && st.feedback.state != crate::axis::AxisState::Offline
            {
                *m = (*m).max((st.setpoint - st.feedback.position).abs());
            }
        }
        if let Some(st) = &mut self.state {
            let late_us = wake.late_us();
            st.counters = stepper.counters(self.skipped, late_us);
            st.publish(&stepper.cycle, now.as_nanos());
        }
        while let Some(e) = stepper.cycle.poll_event() {
            io.event(e);
        }
        if let Some(t) = self.next_status
            && now >= t
        {
            io.status(Snapshot::take(&stepper.cycle, now - self.start));
            self.next_status = self.status_every.map(|d| t + d);
        }
        self.k += 1;
        (self.script.phase() != Phase::Done).then_some(now)
    }

    /// The plan.
    pub fn plan(&self) -> &'p MachinePlan {
        self.plan
    }
}
