//! Driving sans-I/O endpoints on buses: a [`Station`] ties one endpoint to one bus port, and a
//! [`Simulation`] runs several stations on one in-process [`VirtualBus`] in virtual time,
//! jumping from event to event (a frame completing, a timer of some endpoint) so an hour of bus
//! traffic runs in seconds and every run is the same.

use super::{Bus, BusError, Frame, VirtualBus};
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
}

impl<B: Bus, E: Endpoint> Station<B, E> {
    /// Ties `endpoint` to `bus`.
    pub fn new(bus: B, endpoint: E) -> Self {
        Station {
            bus,
            endpoint,
            pending: None,
            errors: 0,
        }
    }

    /// One exchange at the bus's current time: deliver every received frame, run due timers,
    /// send what the endpoint has. Returns how many frames moved either way.
    pub fn step(&mut self) -> usize {
        let mut moved = 0;
        let now = self.bus.now();
        loop {
            match self.bus.try_recv() {
                Ok(Some(f)) => {
                    self.endpoint.handle_frame(&f, f.timestamp());
                    moved += 1;
                }
                Ok(None) => break,
                Err(_) => {
                    self.errors += 1;
                    break;
                }
            }
        }
        if self.endpoint.poll_timeout().is_some_and(|t| t <= now) {
            self.endpoint.handle_timeout(now);
        }
        loop {
            let Some(f) = self
                .pending
                .take()
                .or_else(|| self.endpoint.poll_transmit(now))
            else {
                break;
            };
            match self.bus.send(&f) {
                Ok(()) => moved += 1,
                Err(BusError::WouldBlock) => {
                    self.pending = Some(f);
                    break;
                }
                Err(_) => self.errors += 1,
            }
        }
        moved
    }

    /// Send or receive errors other than a full queue, since creation.
    pub fn errors(&self) -> u64 {
        self.errors
    }

    /// When this station next has something to do on its own (a timer).
    pub fn next_deadline(&self) -> Option<Instant> {
        if self.pending.is_some() {
            return Some(self.bus.now());
        }
        self.endpoint.poll_timeout()
    }
}

/// Something a [`Simulation`] can step: a [`Station`] with its types erased.
pub trait Steppable {
    /// See [`Station::step`].
    fn step(&mut self) -> usize;
    /// See [`Station::next_deadline`].
    fn next_deadline(&self) -> Option<Instant>;
}

impl<B: Bus, E: Endpoint> Steppable for Station<B, E> {
    fn step(&mut self) -> usize {
        Station::step(self)
    }
    fn next_deadline(&self) -> Option<Instant> {
        Station::next_deadline(self)
    }
}

/// Several stations on one virtual-time [`VirtualBus`], advanced event by event.
pub struct Simulation<'a> {
    bus: VirtualBus,
    stations: Vec<&'a mut dyn Steppable>,
}

impl<'a> Simulation<'a> {
    /// A simulation of `bus` (which should use [`super::ClockMode::Virtual`]).
    pub fn new(bus: VirtualBus) -> Self {
        Simulation {
            bus,
            stations: Vec::new(),
        }
    }

    /// Adds a station (its port must belong to this simulation's bus).
    pub fn add(&mut self, station: &'a mut dyn Steppable) {
        self.stations.push(station);
    }

    /// The bus.
    pub fn bus(&self) -> &VirtualBus {
        &self.bus
    }

    /// Lets every station act at the current time until none has anything left to do.
    pub fn settle(&mut self) {
        // Bounded: a station that keeps producing frames at one instant fills its TX queue.
        for _ in 0..10_000 {
            let mut moved = 0;
            for s in self.stations.iter_mut() {
                moved += s.step();
            }
            if moved == 0 {
                break;
            }
        }
    }

    /// Runs until `until`, jumping from event to event. `check` runs after each step and can
    /// stop the run early by returning `true`; the time of the stop is returned.
    pub fn run_until(
        &mut self,
        until: Instant,
        mut check: impl FnMut(&VirtualBus) -> bool,
    ) -> Instant {
        loop {
            self.settle();
            if check(&self.bus) {
                return self.bus.now();
            }
            let now = self.bus.now();
            if now >= until {
                return now;
            }
            let mut next = until;
            if let Some(t) = self.bus.next_event_time() {
                next = next.min(t);
            }
            for s in &self.stations {
                if let Some(t) = s.next_deadline() {
                    next = next.min(t);
                }
            }
            // Never stand still: a deadline in the past has just been served by settle().
            let next = if next <= now {
                now + core::time::Duration::from_nanos(1)
            } else {
                next
            };
            self.bus.advance_to(next);
        }
    }
}
