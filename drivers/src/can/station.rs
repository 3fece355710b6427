//! Driving sans-I/O endpoints on buses: a [`Station`] ties one endpoint to one bus port, and
//! [`run_until`] runs several stations on one in-process [`VirtualBus`] in virtual time,
//! jumping from event to event (a frame completing, a timer of some endpoint) so an hour of bus
//! traffic runs in seconds and every run is the same.
//!
//! ```
//! use drivers::can::station::{self, Station, Steppable};
//! use drivers::can::{FaultRule, IdMatch, VirtualBus, VirtualBusConfig};
//! use drivers::canopen::master::{Master, Supervision};
//! use drivers::canopen::sdo::Completion;
//! use drivers::canopen::{example::example_device, Address, NodeId};
//! use std::time::Duration;
//!
//! let bus = VirtualBus::new(VirtualBusConfig::default()).unwrap(); // 1 Mbit/s, virtual time
//! let n = NodeId::new(5).unwrap();
//! let mut master = Station::new(bus.attach("master"), Master::<4, 4, 1024>::default());
//! let mut device = Station::new(bus.attach("drive"), example_device(n, bus.now()));
//! master.endpoint.add_node(n, Supervision::Heartbeat { consumer_ms: 250 }, bus.now()).unwrap();
//! master.endpoint.sdo(n).unwrap().upload(Address::new(0x1018, 1)).unwrap();
//! // Drop every heartbeat: the SDO exchange is unaffected.
//! bus.add_fault(FaultRule::drop(IdMatch::Exact(0x705)));
//! let until = bus.now() + Duration::from_millis(10);
//! station::run_until(&bus, &mut [&mut master as &mut dyn Steppable, &mut device], until);
//! let e = master.endpoint.poll_sdo_event(n).unwrap();
//! assert_eq!(e.outcome, Ok(Completion::Uploaded(&0x59u32.to_le_bytes()[..])));
//! ```

use super::{Bus, BusError, Frame, HeldBus, VirtualBus};
use crate::canopen::endpoint::Endpoint;
use crate::time::Instant;

/// One endpoint on one bus port.
#[derive(Debug)]
pub struct Station<B, E> {
    /// The bus port.
    pub bus: B,
    /// The endpoint.
    pub endpoint: E,
    /// A frame the bus refused for now (full TX queue), sent before anything newer.
    pending: Option<Frame>,
    /// Errors other than a full queue, counted (the loop goes on).
    errors: u64,
    /// Within one [`run_until`]: the endpoint's next deadline as it was at the end of its last
    /// step there (`None`: not known). Outside a run the endpoint may change through the public
    /// field, so every run starts by forgetting it.
    known: Option<Option<Instant>>,
}

impl<B: Bus, E: Endpoint> Station<B, E> {
    /// Ties `endpoint` to `bus`.
    pub fn new(bus: B, endpoint: E) -> Self {
        Station {
            bus,
            endpoint,
            pending: None,
            errors: 0,
            known: None,
        }
    }

    /// One exchange at the bus's current time: deliver every received frame, run due timers,
    /// send what the endpoint has. Returns how many frames moved either way.
    pub fn step(&mut self) -> usize {
        let now = self.bus.now();
        self.step_at(now)
    }

    /// [`Station::step`] at `now`, the bus's current time as the caller already knows it (a
    /// virtual-time loop: asking the bus again costs its lock).
    pub fn step_at(&mut self, now: Instant) -> usize {
        self.known = None;
        self.exchange(now, None)
    }

    /// The port's `try_recv`, through `held` when the port is a virtual port of that bus.
    fn recv(&mut self, held: &mut Option<&mut HeldBus<'_>>) -> Result<Option<Frame>, BusError> {
        if let Some(h) = held {
            match self.bus.virtual_port() {
                Some(p) => return h.try_recv(p),
                // Another kind of bus might reach the held one through its own handles.
                None => h.release(),
            }
        }
        self.bus.try_recv()
    }

    /// The port's `send`, through `held` as [`Station::recv`].
    fn send(&mut self, f: &Frame, held: &mut Option<&mut HeldBus<'_>>) -> Result<(), BusError> {
        if let Some(h) = held {
            match self.bus.virtual_port() {
                Some(p) => return h.send(p, f),
                None => h.release(),
            }
        }
        self.bus.send(f)
    }

    /// [`Station::step_at`] remembering the endpoint's deadline for the rest of a
    /// [`run_until`] (an endpoint's `poll_timeout` is asked several times per event otherwise),
    /// its frames through `held` when given.
    fn exchange(&mut self, now: Instant, mut held: Option<&mut HeldBus<'_>>) -> usize {
        let mut moved = 0;
        let mut handled = false;
        loop {
            match self.recv(&mut held) {
                Ok(Some(f)) => {
                    // The controller's acceptance filter: other nodes' frames never reach it.
                    if self.endpoint.accepts(&f) {
                        self.endpoint.handle_frame(&f, f.timestamp());
                        handled = true;
                    }
                    moved += 1;
                }
                Ok(None) => break,
                Err(_) => {
                    self.errors += 1;
                    break;
                }
            }
        }
        // Without a frame handed over, the deadline is still the one known from the end of the
        // previous step in this run (nothing else touched the endpoint meanwhile).
        let due = match self.known {
            Some(d) if !handled => d,
            _ => self.endpoint.poll_timeout(),
        };
        if due.is_some_and(|t| t <= now) {
            self.endpoint.handle_timeout(now);
        }
        while let Some(f) = self
            .pending
            .take()
            .or_else(|| self.endpoint.poll_transmit(now))
        {
            match self.send(&f, &mut held) {
                Ok(()) => moved += 1,
                Err(BusError::WouldBlock) => {
                    self.pending = Some(f);
                    break;
                }
                Err(_) => self.errors += 1,
            }
        }
        if self.known.is_some() {
            self.known = Some(self.endpoint.poll_timeout());
        }
        moved
    }

    /// Send or receive errors other than a full queue, since creation.
    pub fn errors(&self) -> u64 {
        self.errors
    }

    /// When this station next has something to do on its own (a timer). A frame held back by
    /// a full TX queue is not a deadline: the bus frees a slot when a frame completes, which is
    /// the bus's own next event.
    pub fn next_deadline(&self) -> Option<Instant> {
        self.endpoint.poll_timeout()
    }
}

/// Something [`run_until`] and [`settle`] can step: a [`Station`] with its types erased.
pub trait Steppable {
    /// See [`Station::step`].
    fn step(&mut self) -> usize;
    /// See [`Station::step_at`]; by default [`Steppable::step`], which asks the bus the time.
    fn step_at(&mut self, now: Instant) -> usize {
        let _ = now;
        self.step()
    }
    /// See [`Station::next_deadline`].
    fn next_deadline(&self) -> Option<Instant>;
    /// [`run_until`] begins: from here until it returns, only it steps the station, so what
    /// the station learns of its endpoint in one step stays true until the next. By default
    /// nothing is remembered.
    fn begin_run(&mut self) {}
    /// [`Steppable::step_at`] within a [`run_until`] (after [`Steppable::begin_run`]).
    fn step_in_run(&mut self, now: Instant) -> usize {
        self.step_at(now)
    }
    /// [`Steppable::next_deadline`] within a [`run_until`], after the station's first step
    /// there.
    fn deadline_in_run(&self) -> Option<Instant> {
        self.next_deadline()
    }
    /// [`Steppable::step_in_run`] with the run's bus held: a [`Station`] on a virtual port of
    /// that bus moves its frames under the lock already held. By default the lock is let go
    /// and [`Steppable::step_in_run`] runs as without it.
    fn step_held(&mut self, now: Instant, held: &mut HeldBus<'_>) -> usize {
        held.release();
        self.step_in_run(now)
    }
}

impl<B: Bus, E: Endpoint> Steppable for Station<B, E> {
    fn step(&mut self) -> usize {
        Station::step(self)
    }
    fn step_at(&mut self, now: Instant) -> usize {
        Station::step_at(self, now)
    }
    fn next_deadline(&self) -> Option<Instant> {
        Station::next_deadline(self)
    }
    fn begin_run(&mut self) {
        // Asked once here; kept up to date by every step of the run.
        self.known = Some(self.endpoint.poll_timeout());
    }
    fn step_in_run(&mut self, now: Instant) -> usize {
        self.exchange(now, None)
    }
    fn step_held(&mut self, now: Instant, held: &mut HeldBus<'_>) -> usize {
        self.exchange(now, Some(held))
    }
    fn deadline_in_run(&self) -> Option<Instant> {
        match self.known {
            Some(d) => d,
            None => self.endpoint.poll_timeout(),
        }
    }
}

/// Lets every station act at the bus's current time until none has anything left to do.
/// Returns how many frames moved. Bounded: a station that keeps producing frames at one instant
/// fills its TX queue and stops.
pub fn settle(stations: &mut [&mut dyn Steppable]) -> usize {
    let mut total = 0;
    for _ in 0..10_000 {
        let moved: usize = stations.iter_mut().map(|s| s.step()).sum();
        if moved == 0 {
            break;
        }
        total += moved;
    }
    total
}

/// The next instant anything happens on a virtual-time bus: a frame completing or a station's
/// timer, but no later than `until`. Always after the bus's current time, so a loop of
/// [`settle`] and `bus.advance_to(next_event(..))` makes progress.
pub fn next_event(bus: &VirtualBus, stations: &[&mut dyn Steppable], until: Instant) -> Instant {
    let now = bus.now();
    let mut next = until;
    if let Some(t) = bus.next_event_time() {
        next = next.min(t);
    }
    for s in stations {
        // A deadline at or before now that settle() left standing waits for the bus (a frame
        // held back by a full TX queue): the bus's next event is what unblocks it.
        if let Some(t) = s.next_deadline().filter(|&t| t > now) {
            next = next.min(t);
        }
    }
    if next <= now {
        now + core::time::Duration::from_nanos(1)
    } else {
        next
    }
}

/// [`settle`] on a virtual-time bus: after the first round, only stations with a timer still
/// due are stepped again. A frame sent at the bus's current time completes, and is delivered,
/// only after it, and an endpoint that had nothing more to send has nothing more at the same
/// instant without a frame or a timer: the other stations' steps would move nothing (they
/// would only take the bus's lock to find that out).
fn settle_virtual(now: Instant, stations: &mut [&mut dyn Steppable], held: &mut HeldBus<'_>) {
    let mut moved: usize = stations.iter_mut().map(|s| s.step_held(now, held)).sum();
    for _ in 1..10_000 {
        if moved == 0 {
            break;
        }
        moved = stations
            .iter_mut()
            .filter(|s| s.deadline_in_run().is_some_and(|t| t <= now))
            .map(|s| s.step_held(now, held))
            .sum();
    }
}

/// Runs `stations` (every one attached to `bus`) on a virtual-time `bus` until `until`, event
/// by event.
pub fn run_until(bus: &VirtualBus, stations: &mut [&mut dyn Steppable], until: Instant) {
    if bus.config().clock != super::ClockMode::Virtual {
        loop {
            settle(stations);
            if bus.now() >= until {
                return;
            }
            bus.advance_to(next_event(bus, stations, until));
        }
    }
    for s in stations.iter_mut() {
        s.begin_run();
    }
    // One thread runs the bus and its stations here: one lock for the whole run (taken at the
    // first frame or advance, let go when the run returns).
    let mut held = bus.hold();
    loop {
        // Virtual time moves only with `advance_to`: one reading per event.
        let now = bus.now();
        settle_virtual(now, stations, &mut held);
        if now >= until {
            return;
        }
        // The stations' next deadline; the bus adds its own under the same lock it runs by.
        let mut bound = until;
        for s in stations.iter() {
            if let Some(t) = s.deadline_in_run().filter(|&t| t > now) {
                bound = bound.min(t);
            }
        }
        held.advance_to_next_event(now, bound);
    }
}
