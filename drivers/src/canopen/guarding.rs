//! Node guarding and life guarding (CiA 301 §7.2.8.3.2.1).
//!
//! The master polls each node with a remote frame on `700h+n` every guard time (100Ch, ms); the
//! node answers one byte, bit 7 a toggle (0 in the first reply, then alternating, back to 0 at
//! reset communication) and bits 6..0 its state. The master flags toggle errors, states it did
//! not command, missed replies, and the node as lost when no valid reply came within the life
//! time (guard time x 100Dh). The node, in turn, flags life guarding when no poll came within
//! the life time (the device raises EMCY 8130h).
//!
//! # Heartbeat or guarding, never both
//!
//! CiA 301 lets one node run only one error-control protocol, and the TLC5xx manual repeats it.
//! [`ErrorControlMode::select`] is the single place both sides decide from the objects (1017h
//! heartbeat producer time, 100Ch, 100Dh): the device applies the CiA 301 rule (a non-zero
//! 1017h means heartbeat) and the master's configuration check refuses the conflict. At run time
//! [`GuardingMaster`] reports a heartbeat-like frame that no poll asked for as
//! [`GuardingEvent::Unsolicited`], the sign that the node produces heartbeats while guarded.
//!
//! ```
//! use drivers::canopen::guarding::GuardReply;
//! use drivers::canopen::nmt::NmtState;
//! // seed-003 §8.7: node 4 answers `05`, then `85`.
//! assert_eq!(GuardReply::from_byte(0x85), Ok(GuardReply { toggle: true, state: NmtState::Operational }));
//! ```

use super::cob::ids;
use super::heartbeat::min_deadline;
use super::nmt::{NmtCommand, NmtState, NmtTarget, frame};
use super::{NodeId, NodeIndex};
use crate::can::Frame;
use crate::time::Instant;
use core::time::Duration;
use heapless::{Deque, Vec};

/// Why a guarding frame or configuration was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum GuardingError {
    /// A guarding reply carries exactly one byte.
    #[error("a guarding reply has DLC 1, not {0}")]
    WrongLength(u8),
    /// The state bits are not 04h, 05h or 7Fh.
    #[error("guarding reply {0:#04x} carries no valid state")]
    BadState(u8),
    /// Not on 701h..77Fh.
    #[error("node guarding uses COB-IDs 701h..77Fh, not {0:#x}")]
    WrongCobId(u32),
    /// Guard time 0 means guarding is off; there is nothing to poll.
    #[error("guard time 0 disables node guarding")]
    GuardTimeZero,
    /// All `N` slots are taken.
    #[error("the guarding master polls at most {0} nodes")]
    TooManyNodes(usize),
    /// The event queue is full; the event was dropped.
    #[error("the guarding event queue is full ({0} events)")]
    EventQueueFull(usize),
}

/// The one-byte reply to a guarding poll.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct GuardReply {
    /// Bit 7.
    pub toggle: bool,
    /// Bits 6..0: Stopped, Operational or Pre-operational.
    pub state: NmtState,
}

impl GuardReply {
    /// The reply byte.
    pub const fn to_byte(self) -> u8 {
        ((self.toggle as u8) << 7) | self.state.to_byte()
    }

    /// Decodes the reply byte. Initialising (00h) is no answer a guarded node gives.
    pub const fn from_byte(b: u8) -> Result<GuardReply, GuardingError> {
        match NmtState::from_byte(b & 0x7F) {
            Ok(NmtState::Initialising) | Err(_) => Err(GuardingError::BadState(b)),
            Ok(state) => Ok(GuardReply {
                toggle: b & 0x80 != 0,
                state,
            }),
        }
    }

    /// Decodes a reply frame into the sender and the reply.
    pub fn from_frame(f: &Frame) -> Result<(NodeId, GuardReply), GuardingError> {
        let node = f
            .cob_id()
            .filter(|c| c & !0x7F == ids::NMT_ERROR_CONTROL && !f.is_remote())
            .and_then(|c| NodeId::new((c & 0x7F) as u8))
            .ok_or(GuardingError::WrongCobId(f.raw_id()))?;
        let &[b] = f.data() else {
            return Err(GuardingError::WrongLength(f.dlc()));
        };
        Ok((node, GuardReply::from_byte(b)?))
    }

    /// The reply frame of `node`.
    pub fn to_frame(self, node: NodeId) -> Frame {
        frame(
            ids::NMT_ERROR_CONTROL + node.get() as u16,
            &[self.to_byte()],
        )
    }
}

/// The guarding poll of `node`: a remote frame on 700h+n requesting one byte.
pub fn guard_poll(node: NodeId) -> Frame {
    let id = ids::NMT_ERROR_CONTROL + node.get() as u16;
    match Frame::new_std_remote(id, 1) {
        Ok(f) => f,
        // Unreachable: 700h + 127 fits in 11 bits and DLC 1 is valid.
        Err(_) => frame(id, &[]),
    }
}

/// Which error-control protocol a node runs, decided once from its objects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ErrorControlMode {
    /// Neither (1017h = 0 and 100Ch = 0).
    Off,
    /// Heartbeat with the 1017h period.
    Heartbeat {
        /// 1017h, ms.
        producer_ms: u16,
    },
    /// Node guarding with 100Ch and 100Dh (life guarding off when the factor is 0).
    Guarding {
        /// 100Ch, ms.
        guard_ms: u16,
        /// 100Dh.
        life_time_factor: u8,
    },
}

/// Both heartbeat (1017h) and guarding (100Ch) are configured on one node.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, thiserror::Error)]
#[error(
    "heartbeat (1017h = {producer_ms} ms) and node guarding (100Ch = {guard_ms} ms) are both \
     configured; a node runs one of them"
)]
pub struct ErrorControlConflict {
    /// 1017h, ms.
    pub producer_ms: u16,
    /// 100Ch, ms.
    pub guard_ms: u16,
    /// 100Dh.
    pub life_time_factor: u8,
}

impl ErrorControlConflict {
    /// What a device does anyway (CiA 301: a non-zero heartbeat producer time means heartbeat).
    pub const fn resolved(self) -> ErrorControlMode {
        ErrorControlMode::Heartbeat {
            producer_ms: self.producer_ms,
        }
    }
}

impl ErrorControlMode {
    /// Chooses from 1017h, 100Ch and 100Dh; both protocols at once is an error carrying the
    /// values (a master refuses the configuration; a device uses [`ErrorControlConflict::resolved`]).
    pub const fn select(
        producer_ms: u16,
        guard_ms: u16,
        life_time_factor: u8,
    ) -> Result<ErrorControlMode, ErrorControlConflict> {
        match (producer_ms, guard_ms) {
            (0, 0) => Ok(ErrorControlMode::Off),
            (0, g) => Ok(ErrorControlMode::Guarding {
                guard_ms: g,
                life_time_factor,
            }),
            (p, 0) => Ok(ErrorControlMode::Heartbeat { producer_ms: p }),
            (p, g) => Err(ErrorControlConflict {
                producer_ms: p,
                guard_ms: g,
                life_time_factor,
            }),
        }
    }
}

/// What the guarding master reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum GuardingEvent {
    /// The toggle bit did not alternate.
    ToggleError {
        /// The node.
        node: NodeId,
        /// The toggle expected.
        expected: bool,
        /// The toggle received.
        got: bool,
    },
    /// The node reports a state the master did not command.
    UnexpectedState {
        /// The node.
        node: NodeId,
        /// The state reported.
        state: NmtState,
    },
    /// No reply to a poll within the guard time.
    NoReply {
        /// The node.
        node: NodeId,
    },
    /// No valid reply within the life time (guard time x life time factor).
    Lost {
        /// The node.
        node: NodeId,
    },
    /// A valid reply after [`GuardingEvent::Lost`].
    Resumed {
        /// The node.
        node: NodeId,
    },
    /// The node booted (boot-up `700h+n [00]`): its toggle restarts at 0.
    BootUp {
        /// The node.
        node: NodeId,
    },
    /// A frame on 700h+n that no poll asked for: the node produces heartbeats while guarded.
    Unsolicited {
        /// The node.
        node: NodeId,
        /// The data byte.
        byte: u8,
    },
}

#[derive(Debug, Clone, Copy)]
struct Guarded {
    node: NodeId,
    guard: Duration,
    factor: u8,
    next_poll: Instant,
    /// When the outstanding poll was sent.
    awaiting: Option<Instant>,
    toggle: bool,
    expected: Option<NmtState>,
    state: Option<NmtState>,
    last_valid: Instant,
    lost: bool,
}

impl Guarded {
    fn life_deadline(&self) -> Option<Instant> {
        if self.factor == 0 || self.lost {
            return None;
        }
        Some(self.last_valid + self.guard * self.factor as u32)
    }
    fn reply_deadline(&self) -> Option<Instant> {
        Some(self.awaiting? + self.guard)
    }
}

/// The master side of node guarding for up to `N` nodes, with an event queue of `Q`.
#[derive(Debug, Clone)]
pub struct GuardingMaster<const N: usize, const Q: usize = 16> {
    nodes: Vec<Guarded, N>,
    events: Deque<GuardingEvent, Q>,
    dropped: u32,
    /// At or before every node's reply and life deadline (`None`: no deadline), so that a
    /// timeout check before it costs one comparison instead of a walk over every node (it runs
    /// once per cycle, per reply received and per poll sent).
    earliest: Option<Instant>,
    /// Where each node's entry is in `nodes`.
    index: NodeIndex,
    /// At or before every due poll's time (nodes with no poll outstanding; `None`: none), for
    /// the same reason in [`GuardingMaster::poll_transmit`].
    next_poll: Option<Instant>,
    /// `(t, i)`: at `t`, no node before index `i` could be polled, and none has been freed
    /// since. A run of polls at one instant (a station asks until nothing is left) then scans
    /// each node once, not once per poll.
    resume: Option<(Instant, usize)>,
}

impl<const N: usize, const Q: usize> Default for GuardingMaster<N, Q> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize, const Q: usize> GuardingMaster<N, Q> {
    /// A master guarding nothing.
    pub fn new() -> Self {
        GuardingMaster {
            nodes: Vec::new(),
            events: Deque::new(),
            dropped: 0,
            earliest: None,
            index: NodeIndex::new(),
            next_poll: None,
            resume: None,
        }
    }

    /// Starts guarding `node` with 100Ch = `guard_ms` and 100Dh = `life_time_factor` (0: no
    /// life-time check, only [`GuardingEvent::NoReply`]). The first poll is due at `now`, and
    /// the life time counts from `now`. Adding a guarded node again updates its times.
    pub fn add_node(
        &mut self,
        node: NodeId,
        guard_ms: u16,
        life_time_factor: u8,
        now: Instant,
    ) -> Result<(), GuardingError> {
        if guard_ms == 0 {
            return Err(GuardingError::GuardTimeZero);
        }
        let guard = Duration::from_millis(guard_ms as u64);
        if let Some(g) = self.nodes.iter_mut().find(|g| g.node == node) {
            g.guard = guard;
            g.factor = life_time_factor;
            let (reply, life) = (g.reply_deadline(), g.life_deadline());
            self.earliest = min_deadline(self.earliest, min_deadline(reply, life));
            return Ok(());
        }
        let g = Guarded {
            node,
            guard,
            factor: life_time_factor,
            next_poll: now,
            awaiting: None,
            toggle: false,
            expected: None,
            state: None,
            last_valid: now,
            lost: false,
        };
        self.earliest = min_deadline(self.earliest, g.life_deadline());
        self.next_poll = min_deadline(self.next_poll, Some(g.next_poll));
        self.resume = None;
        self.nodes
            .push(g)
            .map_err(|_| GuardingError::TooManyNodes(N))?;
        self.index.rebuild(self.nodes.iter().map(|g| g.node));
        Ok(())
    }

    /// Stops guarding `node`.
    pub fn remove(&mut self, node: NodeId) {
        self.nodes.retain(|g| g.node != node);
        self.resume = None;
        self.index.rebuild(self.nodes.iter().map(|g| g.node));
    }

    /// Tells the master which NMT command went out, so replies in the commanded state are not
    /// flagged and a reset restarts the expected toggle at 0.
    pub fn note_command(&mut self, command: NmtCommand, target: NmtTarget) {
        for g in self.nodes.iter_mut().filter(|g| target.includes(g.node)) {
            g.expected = Some(command.resulting_state());
            if command.is_reset() {
                g.toggle = false;
            }
        }
    }

    /// The node's state from its last valid reply.
    pub fn state(&self, node: NodeId) -> Option<NmtState> {
        self.nodes.iter().find(|g| g.node == node)?.state
    }

    /// Whether the node is currently lost.
    pub fn is_lost(&self, node: NodeId) -> bool {
        self.nodes.iter().any(|g| g.node == node && g.lost)
    }

    fn push(
        events: &mut Deque<GuardingEvent, Q>,
        dropped: &mut u32,
        e: GuardingEvent,
    ) -> Result<(), GuardingError> {
        events.push_back(e).map_err(|_| {
            *dropped = dropped.saturating_add(1);
            GuardingError::EventQueueFull(Q)
        })
    }

    /// How many events were dropped because the event queue was full.
    pub fn dropped_events(&self) -> u32 {
        self.dropped
    }

    /// The earliest moment a poll is due or a deadline expires.
    pub fn poll_timeout(&self) -> Option<Instant> {
        self.nodes
            .iter()
            .flat_map(|g| {
                // A due poll waits for the outstanding one (`poll_transmit`): not a deadline.
                let poll = g.awaiting.is_none().then_some(g.next_poll);
                [poll, g.reply_deadline(), g.life_deadline()]
            })
            .flatten()
            .min()
    }

    /// Reports missed replies and lost nodes whose deadlines have passed at `now`.
    pub fn handle_timeout(&mut self, now: Instant) -> Result<(), GuardingError> {
        if self.earliest.is_none_or(|e| now < e) {
            return Ok(());
        }
        let mut result = Ok(());
        let mut earliest = None;
        for g in self.nodes.iter_mut() {
            if g.reply_deadline().is_some_and(|d| now >= d) {
                g.awaiting = None;
                self.next_poll = min_deadline(self.next_poll, Some(g.next_poll));
                self.resume = None;
                if let Err(e) = Self::push(
                    &mut self.events,
                    &mut self.dropped,
                    GuardingEvent::NoReply { node: g.node },
                ) {
                    result = Err(e);
                }
            }
            if g.life_deadline().is_some_and(|d| now >= d) {
                g.lost = true;
                if let Err(e) = Self::push(
                    &mut self.events,
                    &mut self.dropped,
                    GuardingEvent::Lost { node: g.node },
                ) {
                    result = Err(e);
                }
            }
            earliest = min_deadline(
                earliest,
                min_deadline(g.reply_deadline(), g.life_deadline()),
            );
        }
        self.earliest = earliest;
        result
    }

    /// The next poll due at `now`. Deadlines are checked first, so a poll never replaces an
    /// unanswered one without its [`GuardingEvent::NoReply`] (an event that finds the queue
    /// full is counted in [`GuardingMaster::dropped_events`]; the poll goes out regardless).
    pub fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        let _ = self.handle_timeout(now);
        // One poll outstanding per node, so that each reply's toggle belongs to its poll. A
        // master that fell behind (a stall) catches up on its schedule with polls one cycle
        // apart; sent before the first reply was taken, the second reply was dropped as
        // unsolicited and the next one reported a toggle error (the node "lost").
        if self.next_poll.is_none_or(|p| now < p) {
            return None;
        }
        let from = match self.resume {
            Some((t, i)) if t == now => i,
            _ => 0,
        };
        let Some((k, g)) = self
            .nodes
            .iter_mut()
            .enumerate()
            .skip(from)
            .find(|(_, g)| now >= g.next_poll && g.awaiting.is_none())
        else {
            // None due: every waiting node's poll is later than `now`.
            self.next_poll = self
                .nodes
                .iter()
                .filter(|g| g.awaiting.is_none())
                .map(|g| g.next_poll)
                .min();
            return None;
        };
        // Absolute schedule; a caller more than a guard time late does not get a burst.
        g.next_poll += g.guard;
        if g.next_poll <= now {
            g.next_poll = now + g.guard;
        }
        g.awaiting = Some(now);
        let reply = g.reply_deadline();
        let node = g.node;
        self.resume = Some((now, k + 1));
        self.earliest = min_deadline(self.earliest, reply);
        Some(guard_poll(node))
    }

    /// Feeds a frame received at `now`. Frames of unguarded nodes and other COB-IDs are
    /// ignored; a malformed reply is a typed error.
    pub fn handle_frame(&mut self, f: &Frame, now: Instant) -> Result<(), GuardingError> {
        let Some(cob) = f.cob_id() else {
            return Ok(());
        };
        if cob & !0x7F != ids::NMT_ERROR_CONTROL || f.is_remote() {
            return Ok(());
        }
        let Some(idx) = self.index.get(cob & 0x7F) else {
            return Ok(());
        };
        // A reply after the deadline: the NoReply / Lost it missed come first. A full event
        // queue is reported after the reply has been processed.
        let timeouts = self.handle_timeout(now);
        self.take_reply(idx, f, now)?;
        timeouts
    }

    fn take_reply(&mut self, idx: usize, f: &Frame, now: Instant) -> Result<(), GuardingError> {
        let Some(g) = self.nodes.get_mut(idx) else {
            return Ok(());
        };
        let node = g.node;
        if f.data() == [0] {
            // Boot-up: the node reset; its next reply starts with toggle 0 in Pre-operational.
            g.toggle = false;
            g.expected = Some(NmtState::PreOperational);
            g.state = Some(NmtState::PreOperational);
            return Self::push(
                &mut self.events,
                &mut self.dropped,
                GuardingEvent::BootUp { node },
            );
        }
        if g.awaiting.is_none() {
            let byte = f.data().first().copied().unwrap_or(0);
            return Self::push(
                &mut self.events,
                &mut self.dropped,
                GuardingEvent::Unsolicited { node, byte },
            );
        }
        let (_, reply) = GuardReply::from_frame(f)?;
        g.awaiting = None;
        self.next_poll = min_deadline(self.next_poll, Some(g.next_poll));
        self.resume = None;
        if reply.toggle != g.toggle {
            let expected = g.toggle;
            // Resynchronise on the node's toggle, so one glitch is reported once.
            g.toggle = !reply.toggle;
            return Self::push(
                &mut self.events,
                &mut self.dropped,
                GuardingEvent::ToggleError {
                    node,
                    expected,
                    got: reply.toggle,
                },
            );
        }
        g.toggle = !g.toggle;
        g.last_valid = now;
        g.state = Some(reply.state);
        let was_lost = core::mem::replace(&mut g.lost, false);
        self.earliest = min_deadline(self.earliest, g.life_deadline());
        let unexpected = match g.expected {
            Some(e) => e != reply.state,
            None => {
                // The first state heard is taken as the starting point.
                g.expected = Some(reply.state);
                false
            }
        };
        if was_lost {
            Self::push(
                &mut self.events,
                &mut self.dropped,
                GuardingEvent::Resumed { node },
            )?;
        }
        if unexpected {
            let state = reply.state;
            // Report a surprise once, not at every poll.
            g.expected = Some(state);
            Self::push(
                &mut self.events,
                &mut self.dropped,
                GuardingEvent::UnexpectedState { node, state },
            )?;
        }
        Ok(())
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<GuardingEvent> {
        self.events.pop_front()
    }
}

/// Life-guarding events of a device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LifeGuardingEvent {
    /// No poll within the life time: the device raises EMCY 8130h and its error reaction.
    Lost,
    /// Polls arrive again.
    Resumed,
}

/// The device side of node guarding: answers polls and watches the life time.
#[derive(Debug, Clone)]
pub struct GuardingSlave {
    node: NodeId,
    guard: Duration,
    factor: u8,
    toggle: bool,
    last_poll: Option<Instant>,
    lost: bool,
    pending_lost: bool,
    pending_resumed: bool,
}

impl GuardingSlave {
    /// A device with 100Ch = `guard_ms` and 100Dh = `life_time_factor` (life guarding off when
    /// either is 0).
    pub fn new(node: NodeId, guard_ms: u16, life_time_factor: u8) -> Self {
        GuardingSlave {
            node,
            guard: Duration::from_millis(guard_ms as u64),
            factor: life_time_factor,
            toggle: false,
            last_poll: None,
            lost: false,
            pending_lost: false,
            pending_resumed: false,
        }
    }

    /// Writes of 100Ch and 100Dh.
    pub fn set_times(&mut self, guard_ms: u16, life_time_factor: u8) {
        self.guard = Duration::from_millis(guard_ms as u64);
        self.factor = life_time_factor;
    }

    /// Reset communication (and reset node): the toggle restarts at 0 and life guarding waits
    /// for the first poll again.
    pub fn reset_communication(&mut self) {
        self.toggle = false;
        self.last_poll = None;
        self.lost = false;
        self.pending_lost = false;
        self.pending_resumed = false;
    }

    /// The life time, `None` when life guarding is off.
    fn life_time(&self) -> Option<Duration> {
        let life = self.guard * self.factor as u32;
        (!life.is_zero()).then_some(life)
    }

    /// Whether `f` is on this node's error-control COB-ID (a poll, or another device's
    /// answer on the same identifier).
    pub fn accepts(&self, f: &Frame) -> bool {
        f.cob_id() == Some(ids::NMT_ERROR_CONTROL + self.node.get() as u16)
    }

    /// Answers a poll for this node with `toggle | state` (its RTR DLC is not checked: masters
    /// send 0 or 1). While initialising the device does not answer. Other frames give `None`.
    pub fn handle_frame(&mut self, f: &Frame, now: Instant, state: NmtState) -> Option<Frame> {
        if !self.accepts(f) || !f.is_remote() || state == NmtState::Initialising {
            return None;
        }
        // Life guarding starts with the first poll (CiA 301), not during initialisation.
        self.last_poll = Some(now);
        if core::mem::take(&mut self.lost) {
            self.pending_resumed = true;
        }
        let reply = GuardReply {
            toggle: self.toggle,
            state,
        };
        self.toggle = !self.toggle;
        Some(reply.to_frame(self.node))
    }

    /// When the life time of the last poll ends.
    pub fn poll_timeout(&self) -> Option<Instant> {
        if self.lost {
            return None;
        }
        Some(self.last_poll? + self.life_time()?)
    }

    /// Detects a life-guarding timeout at `now`.
    pub fn handle_timeout(&mut self, now: Instant) {
        if self.poll_timeout().is_some_and(|d| now >= d) {
            self.lost = true;
            self.pending_lost = true;
        }
    }

    /// The next life-guarding event.
    pub fn poll_event(&mut self) -> Option<LifeGuardingEvent> {
        if core::mem::take(&mut self.pending_lost) {
            Some(LifeGuardingEvent::Lost)
        } else if core::mem::take(&mut self.pending_resumed) {
            Some(LifeGuardingEvent::Resumed)
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::str::FromStr;

    fn f(s: &str) -> Frame {
        Frame::from_str(s).unwrap()
    }
    fn n(id: u8) -> NodeId {
        NodeId::new(id).unwrap()
    }
    fn ms(v: u64) -> Instant {
        Instant::from_millis(v)
    }
    fn events<const N: usize, const Q: usize>(
        m: &mut GuardingMaster<N, Q>,
    ) -> std::vec::Vec<GuardingEvent> {
        core::iter::from_fn(|| m.poll_event()).collect()
    }

    #[test]
    fn a_shortened_guard_time_is_checked_at_its_new_deadline() {
        // The timeout check skips the walk before its earliest deadline; a deadline moved
        // earlier (a shorter guard time, a new node, a reply) must move that bound too.
        let mut m: GuardingMaster<4> = GuardingMaster::new();
        m.add_node(n(1), 100, 3, ms(0)).unwrap();
        assert_eq!(m.poll_transmit(ms(0)), Some(guard_poll(n(1))));
        m.handle_timeout(ms(50)).unwrap();
        assert_eq!(events(&mut m), []);
        m.add_node(n(1), 10, 3, ms(50)).unwrap();
        m.handle_timeout(ms(10)).unwrap();
        assert_eq!(events(&mut m), [GuardingEvent::NoReply { node: n(1) }]);
        m.add_node(n(2), 10, 2, ms(10)).unwrap();
        assert_eq!(m.poll_timeout(), Some(ms(10)));
        m.handle_timeout(ms(29)).unwrap();
        assert_eq!(events(&mut m), []);
        m.handle_timeout(ms(30)).unwrap();
        assert_eq!(
            events(&mut m),
            [
                GuardingEvent::Lost { node: n(1) },
                GuardingEvent::Lost { node: n(2) }
            ]
        );
        // A poll due long ago after a quiet stretch still goes out.
        assert_eq!(m.poll_transmit(ms(1000)), Some(guard_poll(n(1))));
        assert_eq!(m.poll_transmit(ms(1000)), Some(guard_poll(n(2))));
        assert_eq!(m.poll_transmit(ms(1000)), None);
    }

    #[test]
    fn polls_at_one_instant_go_in_node_order_and_each_instant_starts_over() {
        // A run of polls at one instant resumes its scan where the last poll was found; the
        // next instant, or a change to the nodes, scans from the first node again, so the
        // lowest-index free node due is always the one polled.
        let run = |m: &mut GuardingMaster<8>, t| {
            core::iter::from_fn(|| m.poll_transmit(ms(t))).collect::<std::vec::Vec<_>>()
        };
        let polls = |ids: &[u8]| {
            ids.iter()
                .map(|&i| guard_poll(n(i)))
                .collect::<std::vec::Vec<_>>()
        };
        let reply = |m: &mut GuardingMaster<8>, id, t| {
            let r = GuardReply {
                toggle: false,
                state: NmtState::Operational,
            };
            m.handle_frame(&r.to_frame(n(id)), ms(t)).unwrap();
        };
        let mut m: GuardingMaster<8> = GuardingMaster::new();
        for id in 1..=4 {
            m.add_node(n(id), 100, 3, ms(0)).unwrap();
        }
        assert_eq!(run(&mut m, 0), polls(&[1, 2, 3, 4]));
        // Nodes 2 to 4 answer; node 1 does not.
        for id in 2..=4 {
            reply(&mut m, id, 5);
        }
        assert_eq!(run(&mut m, 5), polls(&[]));
        // At 100 ms node 1's reply is missed (it is free again) and every node is due.
        assert_eq!(run(&mut m, 100), polls(&[1, 2, 3, 4]));
        assert_eq!(events(&mut m)[..1], [GuardingEvent::NoReply { node: n(1) }]);

        // Node 1 becomes due at 100 ms with nothing received in between: the scan at 100 ms
        // must not resume behind it from the poll of node 2 at 50 ms.
        let mut m: GuardingMaster<8> = GuardingMaster::new();
        m.add_node(n(1), 100, 3, ms(0)).unwrap();
        assert_eq!(run(&mut m, 0), polls(&[1]));
        reply(&mut m, 1, 1);
        m.add_node(n(2), 200, 3, ms(50)).unwrap();
        assert_eq!(run(&mut m, 50), polls(&[2]));
        assert_eq!(run(&mut m, 100), polls(&[1]));

        // A node removed between two polls of one instant moves the others down.
        let mut m: GuardingMaster<8> = GuardingMaster::new();
        for id in 1..=3 {
            m.add_node(n(id), 100, 3, ms(0)).unwrap();
        }
        assert_eq!(m.poll_transmit(ms(0)), Some(guard_poll(n(1))));
        m.remove(n(1));
        assert_eq!(run(&mut m, 0), polls(&[2, 3]));
    }

    #[test]
    fn reply_codec() {
        assert_eq!(guard_poll(n(4)), f("704#R1"));
        assert_eq!(
            GuardReply::from_frame(&f("704#05")),
            Ok((
                n(4),
                GuardReply {
                    toggle: false,
                    state: NmtState::Operational
                }
            ))
        );
        let r = GuardReply {
            toggle: true,
            state: NmtState::PreOperational,
        };
        assert_eq!(r.to_byte(), 0xFF);
        assert_eq!(GuardReply::from_byte(0xFF), Ok(r));
        assert_eq!(
            GuardReply::from_byte(0x80),
            Err(GuardingError::BadState(0x80))
        );
        assert_eq!(
            GuardReply::from_byte(0x06),
            Err(GuardingError::BadState(0x06))
        );
        assert_eq!(
            GuardReply::from_frame(&f("704#0505")),
            Err(GuardingError::WrongLength(2))
        );
        assert_eq!(
            GuardReply::from_frame(&f("704#R1")),
            Err(GuardingError::WrongCobId(0x704))
        );
    }

    #[test]
    fn manual_sequence_node_4() {
        // seed-003 §8.7: `704 RTR -> 704: 05`, then `704 RTR -> 704: 85`.
        let mut dev = GuardingSlave::new(n(4), 100, 3);
        let mut m: GuardingMaster<2> = GuardingMaster::new();
        m.add_node(n(4), 100, 3, ms(0)).unwrap();
        m.note_command(NmtCommand::Start, NmtTarget::All);
        let poll = m.poll_transmit(ms(0)).unwrap();
        assert_eq!(poll, f("704#R1"));
        assert_eq!(m.poll_transmit(ms(0)), None);
        let reply = dev
            .handle_frame(&poll, ms(1), NmtState::Operational)
            .unwrap();
        assert_eq!(reply, f("704#05"));
        m.handle_frame(&reply, ms(1)).unwrap();
        assert_eq!(m.poll_timeout(), Some(ms(100)));
        let poll = m.poll_transmit(ms(100)).unwrap();
        let reply = dev
            .handle_frame(&poll, ms(101), NmtState::Operational)
            .unwrap();
        assert_eq!(reply, f("704#85"));
        m.handle_frame(&reply, ms(101)).unwrap();
        assert_eq!(events(&mut m), []);
        assert_eq!(m.state(n(4)), Some(NmtState::Operational));
        // Polls for other nodes and data frames are not answered.
        assert_eq!(
            dev.handle_frame(&f("705#R1"), ms(102), NmtState::Operational),
            None
        );
        assert_eq!(
            dev.handle_frame(&f("704#05"), ms(102), NmtState::Operational),
            None
        );
    }

    #[test]
    fn toggle_error_and_unexpected_state() {
        let mut m: GuardingMaster<2> = GuardingMaster::new();
        m.add_node(n(4), 100, 3, ms(0)).unwrap();
        m.note_command(NmtCommand::Start, NmtTarget::Node(n(4)));
        m.poll_transmit(ms(0)).unwrap();
        m.handle_frame(&f("704#05"), ms(1)).unwrap();
        m.poll_transmit(ms(100)).unwrap();
        // The toggle did not alternate.
        m.handle_frame(&f("704#05"), ms(101)).unwrap();
        assert_eq!(
            events(&mut m),
            [GuardingEvent::ToggleError {
                node: n(4),
                expected: true,
                got: false
            }]
        );
        // Resynchronised: the node's next toggle (1) is accepted, but it is Stopped uncommanded.
        m.poll_transmit(ms(200)).unwrap();
        m.handle_frame(&f("704#84"), ms(201)).unwrap();
        assert_eq!(
            events(&mut m),
            [GuardingEvent::UnexpectedState {
                node: n(4),
                state: NmtState::Stopped
            }]
        );
        // Reported once, not at every poll.
        m.poll_transmit(ms(300)).unwrap();
        m.handle_frame(&f("704#04"), ms(301)).unwrap();
        assert_eq!(events(&mut m), []);
        // A commanded change is not unexpected.
        m.note_command(NmtCommand::EnterPreOperational, NmtTarget::All);
        m.poll_transmit(ms(400)).unwrap();
        m.handle_frame(&f("704#FF"), ms(401)).unwrap();
        assert_eq!(events(&mut m), []);
        // A heartbeat nobody polled for.
        m.handle_frame(&f("704#7F"), ms(450)).unwrap();
        assert_eq!(
            events(&mut m),
            [GuardingEvent::Unsolicited {
                node: n(4),
                byte: 0x7F
            }]
        );
        m.poll_transmit(ms(500)).unwrap();
        assert_eq!(
            m.handle_frame(&f("704#06"), ms(501)),
            Err(GuardingError::BadState(6))
        );
    }

    #[test]
    fn no_reply_then_lost_then_resumed() {
        // Guard 100 ms, factor 3: life time 300 ms.
        let mut m: GuardingMaster<2> = GuardingMaster::new();
        m.add_node(n(4), 100, 3, ms(0)).unwrap();
        m.poll_transmit(ms(0)).unwrap();
        m.handle_frame(&f("704#7F"), ms(2)).unwrap();
        // From here the node is silent; the master polls every millisecond of virtual time.
        let mut log = std::vec::Vec::new();
        for t in 3..=320u64 {
            while let Some(fr) = m.poll_transmit(ms(t)) {
                assert_eq!(fr, f("704#R1"));
            }
            m.handle_timeout(ms(t)).unwrap();
            for e in events(&mut m) {
                log.push((t, e));
            }
        }
        let node = n(4);
        assert_eq!(
            log,
            [
                (200, GuardingEvent::NoReply { node }),
                (300, GuardingEvent::NoReply { node }),
                (302, GuardingEvent::Lost { node }),
            ]
        );
        assert!(m.is_lost(node));
        // The node comes back with the toggle the master expects.
        m.handle_frame(&f("704#FF"), ms(321)).unwrap();
        assert_eq!(events(&mut m), [GuardingEvent::Resumed { node }]);
        assert!(!m.is_lost(node));
    }

    #[test]
    fn a_due_poll_waits_for_the_outstanding_reply() {
        let mut dev = GuardingSlave::new(n(4), 100, 3);
        let mut m: GuardingMaster<1> = GuardingMaster::new();
        m.add_node(n(4), 100, 3, ms(0)).unwrap();
        let op = NmtState::Operational;
        let p = m.poll_transmit(ms(0)).unwrap();
        let r = dev.handle_frame(&p, ms(0), op).unwrap();
        m.handle_frame(&r, ms(1)).unwrap();
        // The master was away until 195 ms: the poll due at 100 goes now, the next is due at
        // 200 and its cycle comes before the reply was taken: it waits.
        let p1 = m.poll_transmit(ms(195)).unwrap();
        assert_eq!(m.poll_transmit(ms(201)), None);
        assert!(
            m.poll_timeout().unwrap() > ms(201),
            "no deadline in the past"
        );
        let r1 = dev.handle_frame(&p1, ms(196), op).unwrap();
        m.handle_frame(&r1, ms(202)).unwrap();
        // Then it goes at once, and its reply's toggle is the one expected.
        let p2 = m.poll_transmit(ms(202)).unwrap();
        let r2 = dev.handle_frame(&p2, ms(203), op).unwrap();
        m.handle_frame(&r2, ms(204)).unwrap();
        assert_eq!(events(&mut m), []);
        assert!(!m.is_lost(n(4)));
    }

    #[test]
    fn reset_restarts_the_toggle_on_both_sides() {
        let mut dev = GuardingSlave::new(n(4), 100, 0);
        let mut m: GuardingMaster<1> = GuardingMaster::new();
        m.add_node(n(4), 100, 0, ms(0)).unwrap();
        let mut t = 0;
        let mut exchange = |m: &mut GuardingMaster<1>, dev: &mut GuardingSlave, state| {
            let poll = m.poll_transmit(ms(t)).unwrap();
            let reply = dev.handle_frame(&poll, ms(t), state).unwrap();
            m.handle_frame(&reply, ms(t)).unwrap();
            t += 100;
            reply.data()[0]
        };
        assert_eq!(exchange(&mut m, &mut dev, NmtState::PreOperational), 0x7F);
        assert_eq!(exchange(&mut m, &mut dev, NmtState::PreOperational), 0xFF);
        // NMT reset communication: the device resets its toggle, the master is told.
        m.note_command(NmtCommand::ResetCommunication, NmtTarget::All);
        dev.reset_communication();
        assert_eq!(exchange(&mut m, &mut dev, NmtState::PreOperational), 0x7F);
        assert_eq!(exchange(&mut m, &mut dev, NmtState::PreOperational), 0xFF);
        assert_eq!(events(&mut m), []);
        // A boot-up seen by the master also restarts its expectation.
        dev.reset_communication();
        m.handle_frame(&f("704#00"), ms(399)).unwrap();
        assert_eq!(events(&mut m), [GuardingEvent::BootUp { node: n(4) }]);
        assert_eq!(exchange(&mut m, &mut dev, NmtState::PreOperational), 0x7F);
        assert_eq!(events(&mut m), []);
    }

    #[test]
    fn life_guarding_timeout_on_the_device() {
        // Guard 50 ms x 4 = 200 ms life time.
        let mut dev = GuardingSlave::new(n(4), 50, 4);
        // Not active before the first poll.
        assert_eq!(dev.poll_timeout(), None);
        dev.handle_timeout(ms(10_000));
        assert_eq!(dev.poll_event(), None);
        // Initialising devices do not answer.
        assert_eq!(
            dev.handle_frame(&f("704#R1"), ms(0), NmtState::Initialising),
            None
        );
        dev.handle_frame(&f("704#R1"), ms(1_000), NmtState::Operational)
            .unwrap();
        dev.handle_frame(&f("704#R"), ms(1_050), NmtState::Operational)
            .unwrap();
        assert_eq!(dev.poll_timeout(), Some(ms(1_250)));
        dev.handle_timeout(ms(1_249));
        assert_eq!(dev.poll_event(), None);
        dev.handle_timeout(ms(1_250));
        assert_eq!(dev.poll_event(), Some(LifeGuardingEvent::Lost));
        assert_eq!(dev.poll_event(), None);
        dev.handle_timeout(ms(2_000));
        assert_eq!(dev.poll_event(), None, "Lost is reported once");
        dev.handle_frame(&f("704#R1"), ms(2_100), NmtState::Operational)
            .unwrap();
        assert_eq!(dev.poll_event(), Some(LifeGuardingEvent::Resumed));
        // Factor 0: no life guarding.
        let mut off = GuardingSlave::new(n(4), 50, 0);
        off.handle_frame(&f("704#R1"), ms(0), NmtState::Operational);
        assert_eq!(off.poll_timeout(), None);
    }

    #[test]
    fn heartbeat_and_guarding_exclude_each_other() {
        assert_eq!(ErrorControlMode::select(0, 0, 0), Ok(ErrorControlMode::Off));
        assert_eq!(
            ErrorControlMode::select(100, 0, 3),
            Ok(ErrorControlMode::Heartbeat { producer_ms: 100 })
        );
        assert_eq!(
            ErrorControlMode::select(0, 100, 3),
            Ok(ErrorControlMode::Guarding {
                guard_ms: 100,
                life_time_factor: 3
            })
        );
        let err = ErrorControlMode::select(100, 50, 3).unwrap_err();
        assert_eq!(
            err,
            ErrorControlConflict {
                producer_ms: 100,
                guard_ms: 50,
                life_time_factor: 3
            }
        );
        assert_eq!(
            err.resolved(),
            ErrorControlMode::Heartbeat { producer_ms: 100 }
        );
    }

    #[test]
    fn bounded_capacity() {
        let mut m: GuardingMaster<1, 1> = GuardingMaster::new();
        m.add_node(n(1), 10, 1, ms(0)).unwrap();
        assert_eq!(
            m.add_node(n(2), 10, 1, ms(0)),
            Err(GuardingError::TooManyNodes(1))
        );
        assert_eq!(
            m.add_node(n(1), 0, 1, ms(0)),
            Err(GuardingError::GuardTimeZero)
        );
        m.poll_transmit(ms(0)).unwrap();
        // NoReply and Lost at the same instant, one slot: the second is an error, not a panic.
        assert_eq!(
            m.handle_timeout(ms(10)),
            Err(GuardingError::EventQueueFull(1))
        );
        assert!(m.is_lost(n(1)));
    }
}
