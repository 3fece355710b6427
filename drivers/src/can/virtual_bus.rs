//! The deterministic in-process virtual CAN bus.
//!
//! A [`VirtualBus`] is one shared bus; [`VirtualBus::attach`] gives a [`VirtualPort`], an
//! endpoint implementing [`Bus`]. The bus is a discrete-event model of the wire:
//!
//! - A frame occupies the bus for its worst-case stuffed length
//!   ([`bit_timing::frame_duration`]: 135 bits for 8 data bytes, 135 us at 1 Mbit/s).
//! - When the bus is idle, the head of every port's transmit queue that was submitted at or
//!   before that moment takes part in arbitration; the lowest [`Frame::arbitration_key`] wins
//!   (equal keys: the port attached first). A frame submitted to an idle bus starts at once;
//!   frames submitted at the very same instant arbitrate together, whatever the call order.
//! - A frame is delivered to every other port (and to its sender with `loopback`) with the
//!   timestamp of the moment it completes; monitor ports see every frame as it was on the wire.
//! - Same submissions at the same times give the same deliveries, order and timestamps, bit for
//!   bit. Nothing depends on wall-clock time in [`ClockMode::Virtual`].
//!
//! Time is either virtual ([`ClockMode::Virtual`]: it moves only through
//! [`VirtualBus::advance_to`], [`VirtualBus::run_until_idle`] or a port's
//! [`Bus::recv_until`]) or real ([`ClockMode::Real`]: [`crate::time::monotonic_now`]; frames
//! become visible once their completion time has passed).
//!
//! Faults are injected with [`FaultRule`]s (drop, delay, corrupt, duplicate; by identifier,
//! probability and time window) and per port (disconnect, bus-off for a window). See
//! [`super::fault`].
//!
//! # Concurrency and allocation
//!
//! The bus state sits behind one `Mutex`, shared by all port handles, which may live on
//! different threads. That models the hardware, the medium every node shares; it is not the
//! coordinator's real-time path (which owns its own bus endpoint). The batch calls
//! ([`VirtualPort::send_batch`], [`VirtualPort::recv_batch`]) take the lock once for many
//! frames. All queues are allocated when a port is attached; carrying frames allocates nothing.
//! In virtual time two questions asked many times per event are answered without the lock,
//! from atomics the locked code keeps up to date: [`VirtualBus::now`], and a port's
//! `try_recv` when nothing waits for it.
//!
//! ```
//! use drivers::can::{Bus, Frame, VirtualBus, VirtualBusConfig};
//! use drivers::time::Instant;
//! let bus = VirtualBus::new(VirtualBusConfig::default()).unwrap();
//! let mut master = bus.attach("master");
//! let mut drive = bus.attach("drive");
//! master.send(&Frame::std8(0x201, [0; 8])).unwrap();
//! bus.run_until_idle();
//! let rx = drive.try_recv().unwrap().unwrap();
//! assert_eq!(rx.timestamp(), Instant::from_micros(135)); // 1 Mbit/s, 135 bits
//! ```

use super::fault::{FaultId, FaultOutcome, FaultRule, FaultSet, TimeWindow};
use super::{Bus, BusCounters, BusError, BusState, Frame, bit_timing};
use crate::time::{Instant, monotonic_now};
use core::cmp::Reverse;
use core::time::Duration;
use std::collections::{BinaryHeap, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};

/// How the bus tells time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ClockMode {
    /// Time moves only when the driver advances it: deterministic, as fast as the machine runs.
    #[default]
    Virtual,
    /// Time is `CLOCK_MONOTONIC`; frames appear when their completion time has passed.
    Real,
}

/// Settings of a virtual bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VirtualBusConfig {
    /// Bit rate in bit/s, 20 kbit/s to 1 Mbit/s.
    pub bitrate: u32,
    /// Virtual or real time.
    pub clock: ClockMode,
    /// Whether a port also receives the frames it sent (as SocketCAN's own-message echo).
    pub loopback: bool,
    /// Transmit queue capacity per port, the frame on the wire included.
    pub tx_capacity: usize,
    /// Receive queue capacity per port; frames arriving at a full queue are dropped and counted.
    pub rx_capacity: usize,
    /// How many delayed frames (fault injection) may be in flight at once; more are dropped.
    pub delay_capacity: usize,
}

impl Default for VirtualBusConfig {
    /// 1 Mbit/s, virtual time, no loopback, 64-frame TX queues, 1024-frame RX queues.
    fn default() -> Self {
        VirtualBusConfig {
            bitrate: 1_000_000,
            clock: ClockMode::Virtual,
            loopback: false,
            tx_capacity: 64,
            rx_capacity: 1024,
            delay_capacity: 256,
        }
    }
}

/// Why a virtual bus could not be created.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum VirtualBusError {
    /// The bitrate lies outside 20 kbit/s ..= 1 Mbit/s.
    #[error(
        "bitrate {0} bit/s is outside {min}..={max} bit/s",
        min = bit_timing::MIN_BITRATE,
        max = bit_timing::MAX_BITRATE
    )]
    Bitrate(u32),
    /// A queue capacity of zero.
    #[error("the {queue} queue capacity must be at least 1, not {value}")]
    Capacity {
        /// Which queue (`tx`, `rx`).
        queue: &'static str,
        /// The capacity given.
        value: usize,
    },
}

/// Index of a port on its bus (in attach order), for the per-port fault and counter calls.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct PortId(pub usize);

/// A frame waiting in a transmit queue, with the time it was handed to the controller.
#[derive(Debug, Clone, Copy)]
struct Pending {
    frame: Frame,
    submitted: Instant,
}

/// The frame currently on the wire. Its source stays at the head of the port's queue (as in a
/// controller's mailbox) until it completes.
#[derive(Debug, Clone, Copy)]
struct OnWire {
    port: usize,
    key: u64,
    start: Instant,
    end: Instant,
}

/// A frame whose delivery a fault rule postponed. Ordered by time, then by creation order.
#[derive(Debug, Clone, Copy)]
struct Delayed {
    at: Instant,
    seq: u64,
    from: usize,
    frame: Frame,
}
impl PartialEq for Delayed {
    fn eq(&self, o: &Self) -> bool {
        (self.at, self.seq) == (o.at, o.seq)
    }
}
impl Eq for Delayed {}
impl PartialOrd for Delayed {
    fn partial_cmp(&self, o: &Self) -> Option<core::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Delayed {
    fn cmp(&self, o: &Self) -> core::cmp::Ordering {
        (self.at, self.seq).cmp(&(o.at, o.seq))
    }
}

#[derive(Debug)]
struct PortSlot {
    attached: bool,
    monitor: bool,
    tx: VecDeque<Pending>,
    rx: VecDeque<Frame>,
    counters: BusCounters,
    disconnected: bool,
    bus_off: Option<TimeWindow>,
    /// The head was already delivered once and is being sent again (duplicate fault).
    retransmit: bool,
    /// Shared with the port's handle: `false` only while `rx` is empty and the port connected,
    /// so a virtual-time `try_recv` that would find nothing need not take the lock.
    maybe_rx: Arc<AtomicBool>,
}

impl PortSlot {
    fn bus_off_at(&self, t: Instant) -> bool {
        self.bus_off.is_some_and(|w| w.contains(t))
    }
}

/// Whole-bus statistics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BusStats {
    /// Frames that completed on the wire (retransmissions included).
    pub frames: u64,
    /// Total time the wire was busy.
    pub busy: Duration,
}

#[derive(Debug)]
struct Core {
    cfg: VirtualBusConfig,
    /// Time up to which the model has been run.
    now: Instant,
    /// When the wire last became idle.
    idle_since: Instant,
    on_wire: Option<OnWire>,
    ports: Vec<PortSlot>,
    delayed: BinaryHeap<Reverse<Delayed>>,
    seq: u64,
    faults: FaultSet,
    stats: BusStats,
    /// Frames in all transmit queues: with none, an idle wire has nothing to arbitrate.
    queued: usize,
    /// The ports a frame is delivered to (attached, not monitors, connected), in attach order:
    /// also the only ports that can have frames queued. Kept by attach, drop and disconnect,
    /// so a frame's arbitration and delivery visit these instead of every port.
    receivers: Vec<usize>,
    /// The attached monitor ports.
    monitors: Vec<usize>,
    /// Some port was ever put into bus-off: arbitration then checks for lost frames.
    any_bus_off: bool,
    /// `now`, readable without the lock (virtual time).
    now_shared: Arc<AtomicU64>,
}

impl Core {
    fn clock_now(&self) -> Instant {
        match self.cfg.clock {
            ClockMode::Virtual => self.now,
            ClockMode::Real => monotonic_now(),
        }
    }

    /// The next moment something happens on its own: a completion or a delayed delivery.
    fn next_event(&self) -> Option<Instant> {
        let a = self.on_wire.map(|w| w.end);
        let b = self.delayed.peek().map(|d| d.0.at);
        match (a, b) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Runs the model through every event at or before `until`.
    fn run_to(&mut self, until: Instant) {
        loop {
            if self.on_wire.is_none() && self.queued > 0 {
                self.start_next(until);
            }
            let wire = self.on_wire.map(|w| w.end).filter(|&t| t <= until);
            let late = self.delayed.peek().map(|d| d.0.at).filter(|&t| t <= until);
            match (wire, late) {
                // Ties go to the wire: a completion may start the next frame at the same time.
                (Some(w), Some(l)) if l < w => self.deliver_delayed(),
                (Some(_), _) => self.complete(),
                (None, Some(_)) => self.deliver_delayed(),
                (None, None) => break,
            }
        }
        if until > self.now {
            self.now = until;
            self.now_shared.store(until.as_nanos(), Ordering::Release);
        }
    }

    /// Arbitration on an idle wire: puts the winning head on the wire if it starts by `until`.
    fn start_next(&mut self, until: Instant) {
        if !self.any_bus_off {
            return self.start_next_no_bus_off(until);
        }
        loop {
            let earliest = self
                .ports
                .iter()
                .filter_map(|p| p.tx.front().map(|h| h.submitted))
                .min();
            let Some(earliest) = earliest else { return };
            let t0 = earliest.max(self.idle_since);
            if t0 > until {
                return;
            }
            // A controller that went bus-off after a frame was queued has lost that frame.
            let mut discarded = false;
            for p in &mut self.ports {
                if let Some(w) = p.bus_off {
                    while let Some(h) = p.tx.front() {
                        if h.submitted <= t0 && w.overlaps(h.submitted, t0) {
                            take_front(&mut p.tx);
                            self.queued -= 1;
                            p.counters.dropped += 1;
                            p.retransmit = false;
                            discarded = true;
                        } else {
                            break;
                        }
                    }
                }
            }
            if discarded {
                continue;
            }
            let mut best: Option<(u64, usize)> = None;
            for (i, p) in self.ports.iter().enumerate() {
                if let Some(h) = p.tx.front()
                    && h.submitted <= t0
                {
                    let key = h.frame.arbitration_key();
                    if best.is_none_or(|(k, _)| key < k) {
                        best = Some((key, i));
                    }
                }
            }
            let Some((key, port)) = best else { return };
            self.put_on_wire(port, key, t0);
            return;
        }
    }

    /// [`Core::start_next`] when no port was ever bus-off (no queued frame can have been lost):
    /// one pass over the ports that can have frames queued, in attach order. The arbitration
    /// starts at `t0 = max(earliest submission, idle_since)` among the heads submitted by
    /// `t0`: those submitted by `idle_since` if any (then `t0 = idle_since`), else those
    /// submitted at the earliest instant after it (then `t0` is that instant).
    fn start_next_no_bus_off(&mut self, until: Instant) {
        let idle = self.idle_since;
        // (key, port) of the best head submitted by `idle`, and (submitted, key, port) of the
        // best among the earliest submitted after it; ties to the port attached first.
        let mut by_idle: Option<(u64, usize)> = None;
        let mut after: Option<(Instant, u64, usize)> = None;
        for &i in &self.receivers {
            let Some(h) = self.ports[i].tx.front() else {
                continue;
            };
            let key = h.frame.arbitration_key();
            if h.submitted <= idle {
                if by_idle.is_none_or(|(k, _)| key < k) {
                    by_idle = Some((key, i));
                }
            } else if after.is_none_or(|(t, k, _)| h.submitted < t || (h.submitted == t && key < k))
            {
                after = Some((h.submitted, key, i));
            }
        }
        let (t0, key, port) = match (by_idle, after) {
            (Some((k, i)), _) => (idle, k, i),
            (None, Some(a)) => a,
            (None, None) => return,
        };
        if t0 > until {
            return;
        }
        self.put_on_wire(port, key, t0);
    }

    /// `port`'s head frame, which won the arbitration with `key`, on the wire from `t0`.
    fn put_on_wire(&mut self, port: usize, key: u64, t0: Instant) {
        let Some(head) = self.ports.get(port).and_then(|p| p.tx.front()) else {
            return;
        };
        let end = t0 + bit_timing::frame_duration(&head.frame, self.cfg.bitrate);
        self.on_wire = Some(OnWire {
            port,
            key,
            start: t0,
            end,
        });
    }

    fn complete(&mut self) {
        let Some(w) = self.on_wire.take() else { return };
        self.idle_since = w.end;
        self.stats.frames += 1;
        self.stats.busy += w.end - w.start;
        let Some(src) = self.ports.get_mut(w.port) else {
            return;
        };
        let Some(head) = src.tx.front().copied() else {
            return;
        };
        let retransmission = src.retransmit;
        let frame = head.frame.with_timestamp(w.end);
        let outcome = if retransmission || self.faults.is_empty() {
            FaultOutcome::default()
        } else {
            self.faults.evaluate(&frame, w.end)
        };
        let src = &mut self.ports[w.port];
        if !retransmission {
            src.counters.sent += 1;
        }
        if outcome.duplicate {
            // Keep the head: it goes out again, through arbitration like any retransmission.
            src.retransmit = true;
        } else {
            take_front(&mut src.tx);
            self.queued -= 1;
            src.retransmit = false;
        }
        let loopback = self.cfg.loopback;
        // Monitors capture the wire, before any receiver-side fault.
        let cap = self.cfg.rx_capacity;
        for &i in &self.monitors {
            push_rx(&mut self.ports[i], frame, cap);
        }
        if outcome.drop {
            for &i in &self.receivers {
                if i != w.port || loopback {
                    self.ports[i].counters.dropped += 1;
                }
            }
            return;
        }
        let frame = outcome.corrupted(frame);
        if outcome.delay.is_zero() {
            self.deliver(frame, w.port, w.end);
        } else {
            let at = w.end + outcome.delay;
            if self.delayed.len() < self.cfg.delay_capacity {
                self.seq += 1;
                self.delayed.push(Reverse(Delayed {
                    at,
                    seq: self.seq,
                    from: w.port,
                    frame: frame.with_timestamp(at),
                }));
            } else {
                for &i in &self.receivers {
                    if i != w.port || loopback {
                        self.ports[i].counters.dropped += 1;
                    }
                }
            }
        }
    }

    fn deliver_delayed(&mut self) {
        if let Some(Reverse(d)) = self.delayed.pop() {
            self.deliver(d.frame, d.from, d.at);
        }
    }

    /// Hands `frame` to every receiving port except monitors (which saw it on the wire).
    fn deliver(&mut self, frame: Frame, from: usize, at: Instant) {
        let loopback = self.cfg.loopback;
        let cap = self.cfg.rx_capacity;
        for &i in &self.receivers {
            if i == from && !loopback {
                continue;
            }
            let p = &mut self.ports[i];
            if p.bus_off_at(at) {
                p.counters.dropped += 1;
            } else {
                push_rx(p, frame, cap);
            }
        }
    }

    /// See [`VirtualBus::advance_to_next_event`].
    fn advance_to_next_event(&mut self, now: Instant, bound: Instant) -> Instant {
        let t = match self.cfg.clock {
            ClockMode::Virtual => {
                let next = self.next_event().map_or(bound, |t| t.min(bound));
                if next <= now {
                    now + Duration::from_nanos(1)
                } else {
                    next
                }
            }
            ClockMode::Real => monotonic_now(),
        };
        self.run_to(t);
        t
    }

    fn slot(&self, port: usize) -> Result<&PortSlot, BusError> {
        match self.ports.get(port) {
            Some(p) if p.attached => Ok(p),
            _ => Err(BusError::Disconnected),
        }
    }
}

/// The front of a queue; a queue left empty starts again at the front of its buffer. The
/// receive queues hold thousands of frames and mostly one or two at a time: without the reset
/// each frame would land in the next slot of the ring, a cache line not touched since the last
/// lap, and a simulated machine's every frame would cost a few misses to memory.
fn take_front<T>(q: &mut VecDeque<T>) -> Option<T> {
    let f = q.pop_front();
    if q.is_empty() {
        // `clear` on an empty queue only moves its start back to the buffer's first slot.
        q.clear();
    }
    f
}

/// Queues a received frame, or counts it dropped when the queue is at its configured limit
/// (`VecDeque::with_capacity` may round up, so the limit is checked, not the capacity).
fn push_rx(p: &mut PortSlot, frame: Frame, cap: usize) {
    if p.rx.len() < cap {
        p.rx.push_back(frame);
        p.maybe_rx.store(true, Ordering::Release);
        p.counters.received += 1;
    } else {
        p.counters.dropped += 1;
    }
}

struct Shared {
    core: Mutex<Core>,
    /// The virtual clock's `now`, kept by `Core::run_to`.
    now: Arc<AtomicU64>,
    /// Real-time mode: wakes receivers waiting in `recv_until` when something was sent.
    wake: Condvar,
}

/// A handle to one shared virtual CAN bus. Clones refer to the same bus.
#[derive(Clone)]
pub struct VirtualBus {
    shared: Arc<Shared>,
    cfg: VirtualBusConfig,
}

impl core::fmt::Debug for VirtualBus {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("VirtualBus")
            .field("cfg", &self.cfg)
            .finish()
    }
}

impl VirtualBus {
    /// A new bus, idle, at time zero (virtual) or now (real).
    pub fn new(cfg: VirtualBusConfig) -> Result<Self, VirtualBusError> {
        if !(bit_timing::MIN_BITRATE..=bit_timing::MAX_BITRATE).contains(&cfg.bitrate) {
            return Err(VirtualBusError::Bitrate(cfg.bitrate));
        }
        if cfg.tx_capacity == 0 {
            return Err(VirtualBusError::Capacity {
                queue: "tx",
                value: 0,
            });
        }
        if cfg.rx_capacity == 0 {
            return Err(VirtualBusError::Capacity {
                queue: "rx",
                value: 0,
            });
        }
        let start = match cfg.clock {
            ClockMode::Virtual => Instant::ZERO,
            ClockMode::Real => monotonic_now(),
        };
        let now = Arc::new(AtomicU64::new(start.as_nanos()));
        let core = Core {
            cfg,
            queued: 0,
            receivers: Vec::new(),
            monitors: Vec::new(),
            any_bus_off: false,
            now_shared: now.clone(),
            now: start,
            idle_since: start,
            on_wire: None,
            ports: Vec::new(),
            delayed: BinaryHeap::with_capacity(cfg.delay_capacity),
            seq: 0,
            faults: FaultSet::new(),
            stats: BusStats::default(),
        };
        Ok(VirtualBus {
            shared: Arc::new(Shared {
                core: Mutex::new(core),
                now,
                wake: Condvar::new(),
            }),
            cfg,
        })
    }

    /// The settings this bus was created with.
    pub fn config(&self) -> &VirtualBusConfig {
        &self.cfg
    }

    fn lock(&self) -> MutexGuard<'_, Core> {
        // A panic while holding the lock leaves the model consistent enough for tests to go on.
        self.shared.core.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Locks the core and, in real time, runs the model up to the present.
    fn lock_current(&self) -> MutexGuard<'_, Core> {
        let mut c = self.lock();
        if c.cfg.clock == ClockMode::Real {
            let now = monotonic_now();
            c.run_to(now);
        }
        c
    }

    fn attach_slot(&self, name: &str, monitor: bool) -> VirtualPort {
        let mut c = self.lock();
        let id = c.ports.len();
        let maybe_rx = Arc::new(AtomicBool::new(false));
        if monitor {
            c.monitors.push(id);
        } else {
            c.receivers.push(id);
        }
        c.ports.push(PortSlot {
            attached: true,
            monitor,
            tx: VecDeque::with_capacity(if monitor { 0 } else { self.cfg.tx_capacity }),
            rx: VecDeque::with_capacity(self.cfg.rx_capacity),
            counters: BusCounters::default(),
            disconnected: false,
            bus_off: None,
            retransmit: false,
            maybe_rx: maybe_rx.clone(),
        });
        VirtualPort {
            bus: self.clone(),
            id,
            name: name.into(),
            maybe_rx,
        }
    }

    /// Attaches a new endpoint (a node).
    pub fn attach(&self, name: &str) -> VirtualPort {
        self.attach_slot(name, false)
    }

    /// Attaches a listen-only endpoint that receives every frame on the wire, including the ones
    /// fault rules hide from the nodes, for capture tools. Sending from it is unsupported.
    pub fn attach_monitor(&self, name: &str) -> VirtualPort {
        self.attach_slot(name, true)
    }

    /// The bus clock: virtual time, or `CLOCK_MONOTONIC` in real time.
    pub fn now(&self) -> Instant {
        match self.cfg.clock {
            // Asked several times per event by a virtual-time loop: no lock.
            ClockMode::Virtual => Instant::from_nanos(self.shared.now.load(Ordering::Acquire)),
            ClockMode::Real => monotonic_now(),
        }
    }

    /// Virtual time: runs the bus up to `t` (never backwards). Real time: runs the model up to
    /// the present, as time cannot be moved.
    pub fn advance_to(&self, t: Instant) {
        let mut c = self.lock();
        let t = match c.cfg.clock {
            ClockMode::Virtual => t,
            ClockMode::Real => monotonic_now(),
        };
        c.run_to(t);
    }

    /// Virtual time: runs the bus to its own next event (a frame completing, a delayed
    /// delivery) or to `bound`, whichever comes first, and at least 1 ns past `now`, the
    /// caller's reading of the clock. What [`VirtualBus::next_event_time`] and
    /// [`VirtualBus::advance_to`] do in two calls, under one lock (a virtual-time station loop
    /// does it once per event). Real time: as [`VirtualBus::advance_to`].
    pub fn advance_to_next_event(&self, now: Instant, bound: Instant) -> Instant {
        self.lock().advance_to_next_event(now, bound)
    }

    /// Takes the bus for a stretch of single-threaded work (a virtual-time station loop):
    /// the frames its ports exchange through the [`HeldBus`] and the bus's own advances then
    /// take the lock once for the whole stretch instead of once per call. Meant for virtual
    /// time; in real time another thread's port waits while the bus is held.
    pub fn hold(&self) -> HeldBus<'_> {
        HeldBus {
            bus: self,
            guard: None,
        }
    }

    /// Virtual time: runs the bus for `d`. Real time: as [`VirtualBus::advance_to`].
    pub fn advance(&self, d: Duration) {
        let mut c = self.lock();
        let t = match c.cfg.clock {
            ClockMode::Virtual => c.now + d,
            ClockMode::Real => monotonic_now(),
        };
        c.run_to(t);
    }

    /// When the next frame completes or a delayed frame is delivered; `None` if nothing is
    /// under way.
    pub fn next_event_time(&self) -> Option<Instant> {
        self.lock_current().next_event()
    }

    /// Runs until nothing is pending: all queued frames sent, all delayed frames delivered.
    /// Returns the bus time afterwards. In real time this sleeps until then.
    pub fn run_until_idle(&self) -> Instant {
        match self.cfg.clock {
            ClockMode::Virtual => {
                let mut c = self.lock();
                while let Some(t) = c.next_event() {
                    c.run_to(t);
                }
                c.now
            }
            ClockMode::Real => loop {
                let next = self.lock_current().next_event();
                match next {
                    None => return monotonic_now(),
                    Some(t) => std::thread::sleep(t - monotonic_now()),
                }
            },
        }
    }

    /// Whether nothing is on the wire, queued or delayed.
    pub fn is_idle(&self) -> bool {
        let c = self.lock_current();
        c.on_wire.is_none() && c.delayed.is_empty() && c.ports.iter().all(|p| p.tx.is_empty())
    }

    /// Whole-bus statistics.
    pub fn stats(&self) -> BusStats {
        self.lock_current().stats
    }

    /// Adds a fault rule, effective for frames completing from now on.
    pub fn add_fault(&self, rule: FaultRule) -> FaultId {
        self.lock().faults.add(rule)
    }

    /// Removes a fault rule; `false` if it was not present.
    pub fn remove_fault(&self, id: FaultId) -> bool {
        self.lock().faults.remove(id)
    }

    /// Removes every fault rule.
    pub fn clear_faults(&self) {
        self.lock().faults.clear()
    }

    /// How many frames a rule has hit; `None` if it is not present.
    pub fn fault_hits(&self, id: FaultId) -> Option<u64> {
        self.lock().faults.hits(id)
    }

    /// Disconnects a port from the bus (`true`) or reconnects it. While disconnected, its
    /// queued frames are gone, it receives nothing, and its calls fail with
    /// [`BusError::Disconnected`]. A frame of it already on the wire is cut off.
    pub fn set_disconnected(&self, port: PortId, disconnected: bool) {
        let mut c = self.lock_current();
        let now = c.clock_now();
        let cut = c.on_wire.is_some_and(|w| w.port == port.0);
        let Some(p) = c.ports.get_mut(port.0) else {
            return;
        };
        p.disconnected = disconnected;
        let listed = p.attached && !p.monitor && !disconnected;
        // Reconnected: back in the delivery list, in attach order.
        if let Err(at) = c.receivers.binary_search(&port.0)
            && listed
        {
            c.receivers.insert(at, port.0);
        }
        if !listed {
            c.receivers.retain(|&i| i != port.0);
        }
        let Some(p) = c.ports.get_mut(port.0) else {
            return;
        };
        if disconnected {
            p.maybe_rx.store(true, Ordering::Release);
            let dropped = p.tx.len();
            p.counters.dropped += dropped as u64;
            p.tx.clear();
            c.queued -= dropped;
            let Some(p) = c.ports.get_mut(port.0) else {
                return;
            };
            p.rx.clear();
            p.retransmit = false;
            if cut {
                c.on_wire = None;
                c.idle_since = c.idle_since.max(now);
            }
        }
        self.shared.wake.notify_all();
    }

    /// Puts a port into bus-off for `window`: it takes no part in traffic, its queued frames are
    /// lost, sends fail with [`BusError::BusOff`], and it recovers at `window.until`. Replaces an
    /// earlier window of that port.
    pub fn set_bus_off(&self, port: PortId, window: TimeWindow) {
        let mut c = self.lock_current();
        if let Some(p) = c.ports.get_mut(port.0) {
            p.bus_off = Some(window);
            c.any_bus_off = true;
        }
    }

    /// Counters of a port; `None` for an unknown port.
    pub fn counters(&self, port: PortId) -> Option<BusCounters> {
        self.lock_current().ports.get(port.0).map(|p| p.counters)
    }
}

/// A [`VirtualBus`] held by one caller ([`VirtualBus::hold`]): its ports' frames go through
/// [`HeldBus::try_recv`] and [`HeldBus::send`], which run the same code as the ports' own
/// calls under a lock taken once, at the first call, and kept until [`HeldBus::release`] or
/// the drop. The one-thread virtual clock so takes one lock per bus and station run instead
/// of one per frame and event (each lock is two atomic read-modify-writes); the real-clock,
/// multi-threaded mode keeps the per-call lock of the ports.
pub struct HeldBus<'a> {
    bus: &'a VirtualBus,
    guard: Option<MutexGuard<'a, Core>>,
}

impl core::fmt::Debug for HeldBus<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("HeldBus")
            .field("held", &self.guard.is_some())
            .finish()
    }
}

impl HeldBus<'_> {
    fn core(&mut self) -> &mut Core {
        let bus = self.bus;
        self.guard.get_or_insert_with(|| bus.lock())
    }

    /// Lets go of the lock (taken again by the next call): before anything else uses the bus
    /// through its own handles, which would otherwise wait for it.
    pub fn release(&mut self) {
        self.guard = None;
    }

    /// The bus held.
    pub fn bus(&self) -> &VirtualBus {
        self.bus
    }

    /// Whether `port` is attached to the bus held.
    pub fn owns(&self, port: &VirtualPort) -> bool {
        Arc::ptr_eq(&self.bus.shared, &port.bus.shared)
    }

    /// [`Bus::try_recv`] of `port`, a port of the bus held ([`HeldBus::owns`]; else the port's
    /// own call, with the lock let go first).
    pub fn try_recv(&mut self, port: &mut VirtualPort) -> Result<Option<Frame>, BusError> {
        if !self.owns(port) || port.bus.cfg.clock != ClockMode::Virtual {
            self.release();
            return port.try_recv();
        }
        if !port.maybe_rx.load(Ordering::Acquire) {
            return Ok(None);
        }
        recv_one(self.core(), port.id)
    }

    /// [`Bus::send`] of `port`, a port of the bus held (else the port's own call, with the
    /// lock let go first).
    pub fn send(&mut self, port: &mut VirtualPort, frame: &Frame) -> Result<(), BusError> {
        if !self.owns(port) || port.bus.cfg.clock != ClockMode::Virtual {
            self.release();
            return port.send(frame);
        }
        send_locked(self.core(), port.id, core::slice::from_ref(frame)).map(|_| ())
    }

    /// [`VirtualBus::advance_to_next_event`] under the lock held.
    pub fn advance_to_next_event(&mut self, now: Instant, bound: Instant) -> Instant {
        self.core().advance_to_next_event(now, bound)
    }
}

/// One endpoint of a [`VirtualBus`]. Dropping it detaches it.
pub struct VirtualPort {
    bus: VirtualBus,
    id: usize,
    name: Box<str>,
    /// See `PortSlot::maybe_rx`.
    maybe_rx: Arc<AtomicBool>,
}

impl core::fmt::Debug for VirtualPort {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("VirtualPort")
            .field("id", &self.id)
            .field("name", &self.name)
            .finish()
    }
}

impl Drop for VirtualPort {
    fn drop(&mut self) {
        let mut c = self.bus.lock();
        let cut = c.on_wire.is_some_and(|w| w.port == self.id);
        let now = c.clock_now();
        if let Some(p) = c.ports.get_mut(self.id) {
            p.attached = false;
            let id = self.id;
            c.receivers.retain(|&i| i != id);
            c.monitors.retain(|&i| i != id);
            let Some(p) = c.ports.get_mut(self.id) else {
                return;
            };
            let dropped = p.tx.len();
            p.tx.clear();
            p.rx.clear();
            c.queued -= dropped;
        }
        if cut {
            c.on_wire = None;
            c.idle_since = c.idle_since.max(now);
        }
    }
}

impl VirtualPort {
    /// This port's index on the bus.
    pub fn id(&self) -> PortId {
        PortId(self.id)
    }
    /// The name given at attach time.
    pub fn name(&self) -> &str {
        &self.name
    }
    /// The bus this port is attached to.
    pub fn bus(&self) -> &VirtualBus {
        &self.bus
    }

    /// Queues frames in order under one lock; returns how many were accepted. Stops at a full
    /// queue (`Ok` with fewer than `frames.len()`); fails only if none could be queued.
    pub fn send_batch(&mut self, frames: &[Frame]) -> Result<usize, BusError> {
        let mut c = self.bus.lock_current();
        let n = send_locked(&mut c, self.id, frames)?;
        drop(c);
        if self.bus.cfg.clock == ClockMode::Real {
            self.bus.shared.wake.notify_all();
        }
        Ok(n)
    }

    /// Moves received frames into `out` under one lock; returns how many.
    pub fn recv_batch(&mut self, out: &mut [Frame]) -> Result<usize, BusError> {
        let mut c = self.bus.lock_current();
        let p = recv_slot(&mut c, self.id)?;
        let mut n = 0;
        for slot in out.iter_mut() {
            match take_front(&mut p.rx) {
                Some(f) => {
                    *slot = f;
                    n += 1;
                }
                None => break,
            }
        }
        if p.rx.is_empty() {
            p.maybe_rx.store(false, Ordering::Release);
        }
        Ok(n)
    }

    /// Frames waiting in the receive queue.
    pub fn pending_rx(&self) -> usize {
        let c = self.bus.lock_current();
        c.ports.get(self.id).map_or(0, |p| p.rx.len())
    }
}

fn recv_slot(c: &mut Core, id: usize) -> Result<&mut PortSlot, BusError> {
    c.slot(id)?;
    let p = c.ports.get_mut(id).ok_or(BusError::Disconnected)?;
    if p.disconnected {
        return Err(BusError::Disconnected);
    }
    Ok(p)
}

/// A port's `try_recv` under the lock.
fn recv_one(c: &mut Core, id: usize) -> Result<Option<Frame>, BusError> {
    let p = recv_slot(c, id)?;
    let f = take_front(&mut p.rx);
    if p.rx.is_empty() {
        p.maybe_rx.store(false, Ordering::Release);
    }
    Ok(f)
}

fn send_locked(c: &mut Core, id: usize, frames: &[Frame]) -> Result<usize, BusError> {
    let now = c.clock_now();
    let cap = c.cfg.tx_capacity;
    let p = c.slot(id)?;
    if p.monitor {
        return Err(BusError::Unsupported("sending from a monitor port"));
    }
    if p.disconnected {
        return Err(BusError::Disconnected);
    }
    if p.bus_off_at(now) {
        return Err(BusError::BusOff);
    }
    let was_empty = p.tx.is_empty();
    let p = &mut c.ports[id];
    let mut n = 0;
    for f in frames {
        if p.tx.len() >= cap {
            break;
        }
        p.tx.push_back(Pending {
            frame: *f,
            submitted: now,
        });
        n += 1;
    }
    c.queued += n;
    if n == 0 && !frames.is_empty() {
        return Err(BusError::WouldBlock);
    }
    // A frame reaching the head at the instant the wire's current frame started joins that
    // arbitration: the order of calls within one instant must not matter.
    if was_empty
        && n > 0
        && let Some(w) = c.on_wire
        && w.start == now
        && w.port != id
        && let Some(h) = c.ports[id].tx.front()
    {
        let key = h.frame.arbitration_key();
        if key < w.key || (key == w.key && id < w.port) {
            c.on_wire = None;
        }
    }
    c.run_to(now);
    Ok(n)
}

impl Bus for VirtualPort {
    fn send(&mut self, frame: &Frame) -> Result<(), BusError> {
        self.send_batch(core::slice::from_ref(frame)).map(|_| ())
    }

    fn try_recv(&mut self) -> Result<Option<Frame>, BusError> {
        // Virtual time: nothing arrives between calls unless the bus is run, which sets the
        // flag; a port with nothing waiting answers without the lock.
        if self.bus.cfg.clock == ClockMode::Virtual && !self.maybe_rx.load(Ordering::Acquire) {
            return Ok(None);
        }
        recv_one(&mut self.bus.lock_current(), self.id)
    }

    fn recv_until(&mut self, deadline: Instant) -> Result<Option<Frame>, BusError> {
        let mut c = self.bus.lock_current();
        match self.bus.cfg.clock {
            ClockMode::Virtual => loop {
                if let Some(f) = take_front(&mut recv_slot(&mut c, self.id)?.rx) {
                    return Ok(Some(f));
                }
                match c.next_event() {
                    Some(t) if t <= deadline => c.run_to(t),
                    _ => {
                        c.run_to(deadline);
                        return Ok(take_front(&mut recv_slot(&mut c, self.id)?.rx));
                    }
                }
            },
            ClockMode::Real => loop {
                if let Some(f) = take_front(&mut recv_slot(&mut c, self.id)?.rx) {
                    return Ok(Some(f));
                }
                let now = monotonic_now();
                if now >= deadline {
                    return Ok(None);
                }
                let wake = c.next_event().map_or(deadline, |t| t.min(deadline));
                // Bounded waits: a send on another port notifies, the next completion is timed.
                let wait = (wake - now).clamp(Duration::from_micros(20), Duration::from_millis(10));
                c = self
                    .bus
                    .shared
                    .wake
                    .wait_timeout(c, wait)
                    .map(|(g, _)| g)
                    .unwrap_or_else(|e| e.into_inner().0);
                let now = monotonic_now();
                c.run_to(now);
            },
        }
    }

    fn now(&self) -> Instant {
        self.bus.now()
    }

    fn state(&self) -> BusState {
        let c = self.bus.lock();
        let now = c.clock_now();
        match c.ports.get(self.id) {
            Some(p) if p.bus_off_at(now) => BusState::BusOff,
            _ => BusState::ErrorActive,
        }
    }

    fn counters(&self) -> BusCounters {
        let c = self.bus.lock_current();
        c.ports.get(self.id).map(|p| p.counters).unwrap_or_default()
    }

    fn virtual_port(&mut self) -> Option<&mut VirtualPort> {
        Some(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bus_at(bitrate: u32) -> VirtualBus {
        VirtualBus::new(VirtualBusConfig {
            bitrate,
            ..VirtualBusConfig::default()
        })
        .unwrap()
    }

    fn f8(id: u16) -> Frame {
        Frame::std8(id, [id as u8; 8])
    }

    #[test]
    fn rejects_bad_config_naming_the_value() {
        let e = VirtualBus::new(VirtualBusConfig {
            bitrate: 10_000,
            ..VirtualBusConfig::default()
        })
        .unwrap_err();
        assert_eq!(e, VirtualBusError::Bitrate(10_000));
        assert!(e.to_string().contains("10000"));
        assert!(
            VirtualBus::new(VirtualBusConfig {
                bitrate: 1_000_001,
                ..VirtualBusConfig::default()
            })
            .is_err()
        );
        assert!(bus_at(20_000).config().bitrate == 20_000);
        let e = VirtualBus::new(VirtualBusConfig {
            rx_capacity: 0,
            ..VirtualBusConfig::default()
        })
        .unwrap_err();
        assert_eq!(
            e,
            VirtualBusError::Capacity {
                queue: "rx",
                value: 0
            }
        );
    }

    #[test]
    fn eight_byte_frame_takes_135_bit_times() {
        for (rate, us) in [(1_000_000, 135), (125_000, 1080)] {
            let bus = bus_at(rate);
            let mut a = bus.attach("a");
            let mut b = bus.attach("b");
            bus.advance_to(Instant::from_micros(1000));
            a.send(&f8(0x181)).unwrap();
            // Starts at once on the idle bus: the completion is the next event.
            assert_eq!(bus.next_event_time(), Some(Instant::from_micros(1000 + us)));
            bus.advance_to(Instant::from_micros(1000 + us - 1));
            assert_eq!(b.try_recv().unwrap(), None);
            bus.advance_to(Instant::from_micros(1000 + us));
            let rx = b.try_recv().unwrap().unwrap();
            assert_eq!(rx, f8(0x181));
            assert_eq!(rx.timestamp(), Instant::from_micros(1000 + us));
            // The sender does not hear itself without loopback.
            assert_eq!(a.try_recv().unwrap(), None);
        }
    }

    #[test]
    fn same_instant_arbitrates_whatever_the_call_order() {
        let bus = bus_at(1_000_000);
        let mut p = [bus.attach("a"), bus.attach("b"), bus.attach("c")];
        let mut rx = bus.attach("rx");
        p[0].send(&f8(0x300)).unwrap();
        p[1].send(&f8(0x200)).unwrap();
        p[2].send(&f8(0x100)).unwrap();
        bus.run_until_idle();
        let mut got = Vec::new();
        while let Some(f) = rx.try_recv().unwrap() {
            got.push((f.raw_id(), f.timestamp().as_micros()));
        }
        assert_eq!(got, vec![(0x100, 135), (0x200, 270), (0x300, 405)]);
    }

    #[test]
    fn a_later_low_id_waits_for_the_frame_on_the_wire() {
        let bus = bus_at(1_000_000);
        let mut a = bus.attach("a");
        let mut b = bus.attach("b");
        let mut rx = bus.attach("rx");
        a.send(&f8(0x300)).unwrap();
        bus.advance_to(Instant::from_micros(1));
        b.send(&f8(0x001)).unwrap();
        bus.run_until_idle();
        assert_eq!(rx.try_recv().unwrap().unwrap().raw_id(), 0x300);
        let second = rx.try_recv().unwrap().unwrap();
        assert_eq!(second.raw_id(), 0x001);
        assert_eq!(second.timestamp(), Instant::from_micros(270));
    }

    #[test]
    fn fifo_within_a_port_even_against_priority() {
        let bus = bus_at(1_000_000);
        let mut a = bus.attach("a");
        let mut rx = bus.attach("rx");
        let frames = [f8(0x700), f8(0x100), f8(0x400)];
        assert_eq!(a.send_batch(&frames).unwrap(), 3);
        bus.run_until_idle();
        let mut out = [Frame::std8(0, [0; 8]); 8];
        let n = rx.recv_batch(&mut out).unwrap();
        assert_eq!(&out[..n], &frames);
    }

    #[test]
    fn loopback_and_monitor() {
        let bus = VirtualBus::new(VirtualBusConfig {
            loopback: true,
            ..VirtualBusConfig::default()
        })
        .unwrap();
        let mut a = bus.attach("a");
        let mut mon = bus.attach_monitor("mon");
        a.send(&f8(0x10)).unwrap();
        bus.run_until_idle();
        assert_eq!(a.try_recv().unwrap(), Some(f8(0x10)));
        assert_eq!(mon.try_recv().unwrap(), Some(f8(0x10)));
        assert_eq!(
            mon.send(&f8(1)),
            Err(BusError::Unsupported("sending from a monitor port"))
        );
    }

    #[test]
    fn queue_full_would_block_and_rx_overflow_counts() {
        let bus = VirtualBus::new(VirtualBusConfig {
            tx_capacity: 2,
            rx_capacity: 1,
            ..VirtualBusConfig::default()
        })
        .unwrap();
        let mut a = bus.attach("a");
        let b = bus.attach("b");
        a.send(&f8(1)).unwrap();
        a.send(&f8(2)).unwrap();
        assert_eq!(a.send(&f8(3)), Err(BusError::WouldBlock));
        assert_eq!(a.send_batch(&[f8(3), f8(4)]), Err(BusError::WouldBlock));
        bus.run_until_idle();
        a.send(&f8(3)).unwrap();
        bus.run_until_idle();
        assert_eq!(a.counters().sent, 3);
        assert_eq!(
            b.counters(),
            BusCounters {
                sent: 0,
                received: 1,
                dropped: 2
            }
        );
    }

    #[test]
    fn recv_until_stops_at_the_first_frame_or_the_deadline() {
        let bus = bus_at(1_000_000);
        let mut a = bus.attach("a");
        let mut b = bus.attach("b");
        a.send_batch(&[f8(1), f8(2)]).unwrap();
        let f = b.recv_until(Instant::from_millis(10)).unwrap().unwrap();
        assert_eq!(f.raw_id(), 1);
        // Time stopped at the first frame, not at the deadline.
        assert_eq!(bus.now(), Instant::from_micros(135));
        assert_eq!(b.recv_until(Instant::from_millis(10)).unwrap(), Some(f8(2)));
        assert_eq!(b.recv_until(Instant::from_millis(10)).unwrap(), None);
        assert_eq!(bus.now(), Instant::from_millis(10));
        // A deadline in the past does not move time back.
        assert_eq!(b.recv_until(Instant::from_millis(1)).unwrap(), None);
        assert_eq!(b.now(), Instant::from_millis(10));
    }

    #[test]
    fn dropping_a_port_detaches_it() {
        let bus = bus_at(1_000_000);
        let mut a = bus.attach("a");
        let b = bus.attach("b");
        let id = b.id();
        drop(b);
        a.send(&f8(1)).unwrap();
        bus.run_until_idle();
        assert_eq!(bus.counters(id).unwrap().received, 0);
        assert_eq!(bus.stats().frames, 1);
        assert!(bus.is_idle());
    }

    #[test]
    fn held_bus_moves_frames_as_the_ports_do() {
        let (plain, held_bus) = (bus_at(1_000_000), bus_at(1_000_000));
        let (mut a1, mut b1) = (plain.attach("a"), plain.attach("b"));
        let (mut a2, mut b2) = (held_bus.attach("a"), held_bus.attach("b"));
        let mut got = (Vec::new(), Vec::new());
        {
            let mut held = held_bus.hold();
            for id in [0x300, 0x181, 0x080] {
                a1.send(&f8(id)).unwrap();
                held.send(&mut a2, &f8(id)).unwrap();
            }
            let mut now = Instant::ZERO;
            for _ in 0..4 {
                let t = plain.advance_to_next_event(now, Instant::from_micros(1000));
                assert_eq!(
                    held.advance_to_next_event(now, Instant::from_micros(1000)),
                    t
                );
                now = t;
                while let Some(f) = b1.try_recv().unwrap() {
                    got.0.push((f, f.timestamp()));
                }
                while let Some(f) = held.try_recv(&mut b2).unwrap() {
                    got.1.push((f, f.timestamp()));
                }
            }
        }
        assert_eq!(got.0.len(), 3);
        assert_eq!(got.0, got.1);
        assert_eq!(plain.counters(b1.id()), held_bus.counters(b2.id()));
    }

    #[test]
    fn held_bus_lets_go_for_other_handles() {
        let (one, other) = (bus_at(1_000_000), bus_at(1_000_000));
        let mut tx = one.attach("tx");
        let mut rx = one.attach("rx");
        let mut elsewhere = other.attach("elsewhere");
        let mut held = one.hold();
        held.send(&mut tx, &f8(0x181)).unwrap();
        // A port of another bus: sent by its own call, the held lock let go first.
        assert!(!held.owns(&elsewhere));
        held.send(&mut elsewhere, &f8(0x182)).unwrap();
        held.release();
        // The bus's own handles work again once let go.
        assert!(!one.is_idle());
        held.advance_to_next_event(Instant::ZERO, Instant::from_micros(1000));
        drop(held);
        assert_eq!(rx.try_recv().unwrap().map(|f| f.raw_id()), Some(0x181));
    }

    #[test]
    fn station_run_lets_go_for_a_steppable_of_its_own() {
        use crate::can::station::{self, Steppable};
        // Steps its own port on the run's bus: the held lock must be let go first.
        struct Sender(VirtualPort, bool);
        impl Steppable for Sender {
            fn step(&mut self) -> usize {
                if core::mem::take(&mut self.1) {
                    self.0.send(&f8(0x181)).unwrap();
                    return 1;
                }
                0
            }
            fn next_deadline(&self) -> Option<Instant> {
                None
            }
        }
        let bus = bus_at(1_000_000);
        let mut s = Sender(bus.attach("sender"), true);
        let mut rx = bus.attach("rx");
        station::run_until(&bus, &mut [&mut s], Instant::from_micros(500));
        assert_eq!(rx.try_recv().unwrap().map(|f| f.raw_id()), Some(0x181));
    }

    #[test]
    fn reconnected_port_keeps_its_place_in_arbitration_ties() {
        let bus = bus_at(1_000_000);
        let mut a = bus.attach("a");
        let mut b = bus.attach("b");
        let mut rx = bus.attach("rx");
        bus.set_disconnected(a.id(), true);
        bus.set_disconnected(a.id(), false);
        bus.advance_to(Instant::from_micros(10));
        // Equal keys: the port attached first wins, reconnected or not.
        let (fa, fb) = (Frame::std8(0x181, [1; 8]), Frame::std8(0x181, [2; 8]));
        b.send(&fb).unwrap();
        a.send(&fa).unwrap();
        bus.run_until_idle();
        assert_eq!(rx.try_recv().unwrap(), Some(fa));
        assert_eq!(rx.try_recv().unwrap(), Some(fb));
        // And it receives again.
        b.send(&f8(0x200)).unwrap();
        bus.run_until_idle();
        assert_eq!(a.try_recv().unwrap(), Some(fb));
        assert_eq!(a.try_recv().unwrap(), Some(f8(0x200)));
    }
}
