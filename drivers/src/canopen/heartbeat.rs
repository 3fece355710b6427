//! Heartbeat (CiA 301 §7.2.8.3.2.2): the producer (1017h, ms) sends `700h+n [state]`, the
//! consumer (1016h entries `node << 16 | ms`) reports a node lost when its heartbeat does not
//! come within the consumer time.
//!
//! Heartbeat and node guarding exclude each other on one node; see
//! [`crate::canopen::guarding::ErrorControlMode`] for how the choice is made and reported.

use super::cob::ids;
use super::nmt::{NmtError, NmtState, frame};
use super::{NodeId, NodeIndex};
use crate::can::Frame;
use crate::time::Instant;
use core::time::Duration;
use heapless::{Deque, Vec};

/// Why a heartbeat frame or consumer entry was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum HeartbeatError {
    /// Not on 701h..77Fh.
    #[error("heartbeats use COB-IDs 701h..77Fh, not {0:#x}")]
    WrongCobId(u32),
    /// A remote frame: a node-guarding poll, not a heartbeat.
    #[error("a remote frame on 700h+n is a guarding poll, not a heartbeat")]
    Remote,
    /// A heartbeat carries exactly one byte.
    #[error("a heartbeat has DLC 1, not {0}")]
    WrongLength(u8),
    /// The state byte is not 00h, 04h, 05h or 7Fh.
    #[error(transparent)]
    State(#[from] NmtError),
    /// A 1016h entry whose node byte is above 127.
    #[error("heartbeat consumer entry {0:#010x} names node {1}, not 1..=127")]
    BadEntry(u32, u8),
    /// All `N` consumer slots are taken.
    #[error("the heartbeat consumer monitors at most {0} nodes")]
    TooManyNodes(usize),
    /// The event queue is full; the event was dropped (the node's status is still current).
    #[error("the heartbeat event queue is full ({0} events)")]
    EventQueueFull(usize),
}

/// The heartbeat frame of `node` in `state` (boot-up is [`NmtState::Initialising`]).
pub fn encode_heartbeat(node: NodeId, state: NmtState) -> Frame {
    frame(
        ids::NMT_ERROR_CONTROL + node.get() as u16,
        &[state.to_byte()],
    )
}

/// Decodes a heartbeat (or DS301 boot-up) frame into the sender and its state.
pub fn decode_heartbeat(f: &Frame) -> Result<(NodeId, NmtState), HeartbeatError> {
    let cob = f.cob_id().ok_or(HeartbeatError::WrongCobId(f.raw_id()))?;
    let node = NodeId::new((cob & 0x7F) as u8);
    let node = match node {
        Some(n) if cob & !0x7F == ids::NMT_ERROR_CONTROL => n,
        _ => return Err(HeartbeatError::WrongCobId(cob as u32)),
    };
    if f.is_remote() {
        return Err(HeartbeatError::Remote);
    }
    let &[byte] = f.data() else {
        return Err(HeartbeatError::WrongLength(f.dlc()));
    };
    Ok((node, NmtState::from_byte(byte)?))
}

/// The heartbeat producer of a device.
///
/// It stays silent until [`HeartbeatProducer::start`], which the device calls once its boot-up
/// message is out, so the boot-up always comes first.
#[derive(Debug, Clone)]
pub struct HeartbeatProducer {
    node: NodeId,
    period: Duration,
    next: Option<Instant>,
}

impl HeartbeatProducer {
    /// A producer with 1017h = `period_ms` (0 = off).
    pub fn new(node: NodeId, period_ms: u16) -> Self {
        HeartbeatProducer {
            node,
            period: Duration::from_millis(period_ms as u64),
            next: None,
        }
    }

    /// Whether 1017h is non-zero.
    pub fn enabled(&self) -> bool {
        !self.period.is_zero()
    }

    /// The boot-up message went out at `now`: the first heartbeat is due one period later.
    pub fn start(&mut self, now: Instant) {
        self.next = Some(now + self.period);
    }

    /// Stops producing (reset: the next boot-up restarts it).
    pub fn stop(&mut self) {
        self.next = None;
    }

    /// A write to 1017h: takes effect at once, the next heartbeat one new period from `now`.
    pub fn set_period(&mut self, period_ms: u16, now: Instant) {
        self.period = Duration::from_millis(period_ms as u64);
        if self.next.is_some() {
            self.next = Some(now + self.period);
        }
    }

    /// When the next heartbeat is due.
    pub fn poll_timeout(&self) -> Option<Instant> {
        if self.enabled() { self.next } else { None }
    }

    /// The heartbeat due at `now`, carrying `state`. The schedule is absolute; a caller more
    /// than a period late gets one heartbeat, not a burst.
    pub fn poll_transmit(&mut self, now: Instant, state: NmtState) -> Option<Frame> {
        let due = self.poll_timeout()?;
        if now < due {
            return None;
        }
        let mut next = due + self.period;
        if next <= now {
            next = now + self.period;
        }
        self.next = Some(next);
        Some(encode_heartbeat(self.node, state))
    }
}

/// What the heartbeat consumer reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum HeartbeatEvent {
    /// The node booted (boot-up heartbeat 00h). During monitoring this is a reset: the node
    /// lost its configuration.
    BootUp {
        /// The node.
        node: NodeId,
    },
    /// No heartbeat within the consumer time.
    Lost {
        /// The node.
        node: NodeId,
    },
    /// A heartbeat arrived again after [`HeartbeatEvent::Lost`].
    Resumed {
        /// The node.
        node: NodeId,
    },
    /// The reported state changed (`old` is `None` for the first heartbeat).
    StateChanged {
        /// The node.
        node: NodeId,
        /// The state reported before.
        old: Option<NmtState>,
        /// The state reported now.
        new: NmtState,
    },
}

#[derive(Debug, Clone, Copy)]
struct Monitored {
    node: NodeId,
    time: Duration,
    last: Option<Instant>,
    state: Option<NmtState>,
    lost: bool,
}

impl Monitored {
    fn deadline(&self) -> Option<Instant> {
        if self.lost {
            None
        } else {
            Some(self.last? + self.time)
        }
    }
}

/// The heartbeat consumer for up to `N` nodes, with an event queue of `Q`.
///
/// Monitoring of a node starts with its first heartbeat or boot-up; from then on
/// [`HeartbeatEvent::Lost`] is reported as soon as `now` reaches the last heartbeat plus the
/// consumer time, whether `now` comes through [`HeartbeatConsumer::handle_timeout`] or with a
/// late frame.
#[derive(Debug, Clone)]
pub struct HeartbeatConsumer<const N: usize, const Q: usize = 16> {
    nodes: Vec<Monitored, N>,
    events: Deque<HeartbeatEvent, Q>,
    /// At or before every node's deadline (`None`: no deadline), so that a timeout check before
    /// it costs one comparison instead of a walk over every node (it runs once per cycle and
    /// once per heartbeat received).
    earliest: Option<Instant>,
    /// Where each node's entry is in `nodes`.
    index: NodeIndex,
}

impl<const N: usize, const Q: usize> Default for HeartbeatConsumer<N, Q> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize, const Q: usize> HeartbeatConsumer<N, Q> {
    /// A consumer monitoring nothing.
    pub fn new() -> Self {
        HeartbeatConsumer {
            nodes: Vec::new(),
            events: Deque::new(),
            earliest: None,
            index: NodeIndex::new(),
        }
    }

    /// Applies a 1016h sub-entry, `node << 16 | ms` (bits 31..24 reserved). Node 0 or time 0
    /// leaves the entry unused; an entry for a node already monitored replaces its time (and,
    /// with time 0, ends its monitoring).
    pub fn configure(&mut self, entry: u32) -> Result<(), HeartbeatError> {
        let node_byte = (entry >> 16) as u8;
        let ms = entry as u16;
        if node_byte == 0 {
            return Ok(());
        }
        let node = NodeId::new(node_byte).ok_or(HeartbeatError::BadEntry(entry, node_byte))?;
        if ms == 0 {
            self.remove(node);
            return Ok(());
        }
        self.monitor(node, Duration::from_millis(ms as u64))
    }

    /// Monitors `node` with consumer time `time` (which must exceed the producer's 1017h).
    pub fn monitor(&mut self, node: NodeId, time: Duration) -> Result<(), HeartbeatError> {
        if let Some(m) = self.nodes.iter_mut().find(|m| m.node == node) {
            m.time = time;
            let d = m.deadline();
            self.lower(d);
            return Ok(());
        }
        self.nodes
            .push(Monitored {
                node,
                time,
                last: None,
                state: None,
                lost: false,
            })
            .map_err(|_| HeartbeatError::TooManyNodes(N))?;
        self.index.rebuild(self.nodes.iter().map(|m| m.node));
        Ok(())
    }

    /// Stops monitoring `node`.
    pub fn remove(&mut self, node: NodeId) {
        self.nodes.retain(|m| m.node != node);
        self.index.rebuild(self.nodes.iter().map(|m| m.node));
    }

    /// The node's last reported state.
    pub fn state(&self, node: NodeId) -> Option<NmtState> {
        self.nodes.iter().find(|m| m.node == node)?.state
    }

    /// Whether the node is currently lost.
    pub fn is_lost(&self, node: NodeId) -> bool {
        self.nodes.iter().any(|m| m.node == node && m.lost)
    }

    /// Feeds a frame received at `now`. Frames of unmonitored nodes, other COB-IDs and guarding
    /// polls are ignored; a malformed heartbeat of a monitored node is a typed error.
    pub fn handle_frame(&mut self, f: &Frame, now: Instant) -> Result<(), HeartbeatError> {
        let Some(cob) = f.cob_id() else {
            return Ok(());
        };
        if cob & !0x7F != ids::NMT_ERROR_CONTROL || f.is_remote() {
            return Ok(());
        }
        let Some(idx) = self.index.get(cob & 0x7F) else {
            return Ok(());
        };
        let (node, state) = decode_heartbeat(f)?;
        // A heartbeat that arrives after the deadline still means the node was lost meanwhile.
        // A full event queue is reported after the heartbeat has been taken.
        let timeouts = self.handle_timeout(now);
        self.take(idx, node, state, now)?;
        timeouts
    }

    fn take(
        &mut self,
        idx: usize,
        node: NodeId,
        state: NmtState,
        now: Instant,
    ) -> Result<(), HeartbeatError> {
        let Some(m) = self.nodes.get_mut(idx) else {
            return Ok(());
        };
        let was_lost = core::mem::replace(&mut m.lost, false);
        m.last = Some(now);
        let old = m.state;
        // After its boot-up a node is Pre-operational.
        let new = if state == NmtState::Initialising {
            NmtState::PreOperational
        } else {
            state
        };
        m.state = Some(new);
        let d = m.deadline();
        self.lower(d);
        if was_lost {
            self.push(HeartbeatEvent::Resumed { node })?;
        }
        if state == NmtState::Initialising {
            self.push(HeartbeatEvent::BootUp { node })?;
        }
        if old != Some(new) {
            self.push(HeartbeatEvent::StateChanged { node, old, new })?;
        }
        Ok(())
    }

    /// The earliest moment a monitored node can be lost.
    pub fn poll_timeout(&self) -> Option<Instant> {
        self.nodes.iter().filter_map(Monitored::deadline).min()
    }

    /// Reports every node whose heartbeat is overdue at `now`.
    pub fn handle_timeout(&mut self, now: Instant) -> Result<(), HeartbeatError> {
        if self.earliest.is_none_or(|e| now < e) {
            return Ok(());
        }
        let mut result = Ok(());
        let mut earliest = None;
        for m in self.nodes.iter_mut() {
            if m.deadline().is_some_and(|d| now >= d) {
                m.lost = true;
                let e = HeartbeatEvent::Lost { node: m.node };
                if self.events.push_back(e).is_err() {
                    result = Err(HeartbeatError::EventQueueFull(Q));
                }
            }
            earliest = min_deadline(earliest, m.deadline());
        }
        self.earliest = earliest;
        result
    }

    /// Keeps [`HeartbeatConsumer::earliest`] at or before a deadline that was set or moved.
    fn lower(&mut self, d: Option<Instant>) {
        self.earliest = min_deadline(self.earliest, d);
    }

    fn push(&mut self, e: HeartbeatEvent) -> Result<(), HeartbeatError> {
        self.events
            .push_back(e)
            .map_err(|_| HeartbeatError::EventQueueFull(Q))
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<HeartbeatEvent> {
        self.events.pop_front()
    }
}

/// The earlier of two optional deadlines (`None`: none).
#[inline]
pub(crate) fn min_deadline(a: Option<Instant>, b: Option<Instant>) -> Option<Instant> {
    match (a, b) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
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

    #[test]
    fn a_removal_keeps_the_other_nodes_found() {
        let mut c: HeartbeatConsumer<4> = HeartbeatConsumer::new();
        for id in 1..=3 {
            c.monitor(n(id), Duration::from_millis(100)).unwrap();
        }
        c.remove(n(1));
        c.handle_frame(&f("703#05"), ms(0)).unwrap();
        assert_eq!(c.state(n(3)), Some(NmtState::Operational));
        assert_eq!(c.state(n(2)), None);
        c.handle_frame(&f("701#05"), ms(0)).unwrap();
        assert_eq!(c.state(n(1)), None);
    }

    #[test]
    fn a_shortened_consumer_time_is_checked_at_its_new_deadline() {
        // The timeout check skips the walk before its earliest deadline; a consumer time made
        // shorter must move that bound too.
        let mut c: HeartbeatConsumer<4> = HeartbeatConsumer::new();
        c.monitor(n(1), Duration::from_millis(100)).unwrap();
        c.handle_frame(&f("701#05"), ms(0)).unwrap();
        c.handle_timeout(ms(50)).unwrap();
        assert!(!c.is_lost(n(1)));
        c.monitor(n(1), Duration::from_millis(20)).unwrap();
        c.handle_timeout(ms(20)).unwrap();
        assert!(c.is_lost(n(1)));
    }

    #[test]
    fn frame_codec_matches_the_manual() {
        // seed-003 §8.7: `704: 05` is node 4 Operational.
        assert_eq!(
            decode_heartbeat(&f("704#05")),
            Ok((n(4), NmtState::Operational))
        );
        assert_eq!(encode_heartbeat(n(4), NmtState::Operational), f("704#05"));
        assert_eq!(
            decode_heartbeat(&f("704#00")),
            Ok((n(4), NmtState::Initialising))
        );
        assert_eq!(
            decode_heartbeat(&f("77F#7F")),
            Ok((n(127), NmtState::PreOperational))
        );
        assert_eq!(
            decode_heartbeat(&f("704#0505")),
            Err(HeartbeatError::WrongLength(2))
        );
        assert_eq!(
            decode_heartbeat(&f("704#")),
            Err(HeartbeatError::WrongLength(0))
        );
        assert_eq!(decode_heartbeat(&f("704#R1")), Err(HeartbeatError::Remote));
        assert_eq!(
            decode_heartbeat(&f("704#85")),
            Err(HeartbeatError::State(NmtError::UnknownState(0x85)))
        );
        assert_eq!(
            decode_heartbeat(&f("700#05")),
            Err(HeartbeatError::WrongCobId(0x700))
        );
        assert_eq!(
            decode_heartbeat(&f("604#05")),
            Err(HeartbeatError::WrongCobId(0x604))
        );
    }

    #[test]
    fn producer_waits_for_boot_up_then_keeps_period() {
        let mut p = HeartbeatProducer::new(n(4), 100);
        assert_eq!(p.poll_transmit(ms(500), NmtState::PreOperational), None);
        p.start(ms(1_000));
        assert_eq!(p.poll_timeout(), Some(ms(1_100)));
        assert_eq!(p.poll_transmit(ms(1_099), NmtState::PreOperational), None);
        assert_eq!(
            p.poll_transmit(ms(1_103), NmtState::PreOperational),
            Some(f("704#7F"))
        );
        // Absolute schedule: a late poll does not shift the next one.
        assert_eq!(p.poll_timeout(), Some(ms(1_200)));
        assert_eq!(
            p.poll_transmit(ms(1_200), NmtState::Operational),
            Some(f("704#05"))
        );
        // Far behind: one heartbeat, then a period from now.
        assert!(p.poll_transmit(ms(1_750), NmtState::Stopped).is_some());
        assert_eq!(p.poll_transmit(ms(1_750), NmtState::Stopped), None);
        assert_eq!(p.poll_timeout(), Some(ms(1_850)));
        p.set_period(0, ms(1_800));
        assert_eq!(p.poll_timeout(), None);
    }

    #[test]
    fn consumer_entries_from_1016h() {
        let mut c: HeartbeatConsumer<2> = HeartbeatConsumer::new();
        c.configure(0x0004_0096).unwrap(); // node 4, 150 ms
        c.configure(0x0000_0096).unwrap(); // unused
        c.configure(0x0005_0000).unwrap(); // unused
        assert_eq!(
            c.configure(0x0080_0096),
            Err(HeartbeatError::BadEntry(0x0080_0096, 0x80))
        );
        c.configure(0x0005_0064).unwrap();
        assert_eq!(
            c.configure(0x0006_0064),
            Err(HeartbeatError::TooManyNodes(2))
        );
        // Time 0 for a monitored node ends its monitoring, freeing the slot.
        c.configure(0x0005_0000).unwrap();
        c.configure(0x0006_0064).unwrap();
    }

    #[test]
    fn loss_is_detected_within_consumer_time_plus_one_poll() {
        // Producer 100 ms, consumer 150 ms, the master polls every 1 ms.
        let mut c: HeartbeatConsumer<4> = HeartbeatConsumer::new();
        c.configure(0x0004_0096).unwrap();
        let mut p = HeartbeatProducer::new(n(4), 100);
        // Nothing is monitored before the node is first heard.
        assert_eq!(c.poll_timeout(), None);
        p.start(ms(0));
        let mut last_sent = None;
        let mut lost_at = None;
        for t in 0..1_000u64 {
            let now = ms(t) + Duration::from_micros(300); // the poll is never on the grid
            // The producer dies at 420 ms.
            if t < 420
                && let Some(fr) = p.poll_transmit(now, NmtState::Operational)
            {
                c.handle_frame(&fr, now).unwrap();
                last_sent = Some(now);
            }
            c.handle_timeout(now).unwrap();
            while let Some(e) = c.poll_event() {
                if let HeartbeatEvent::Lost { node } = e {
                    assert_eq!(node, n(4));
                    assert!(lost_at.is_none(), "Lost is reported once");
                    lost_at = Some(now);
                }
            }
        }
        let (last, lost) = (last_sent.unwrap(), lost_at.unwrap());
        assert!(lost - last >= Duration::from_millis(150));
        assert!(lost - last <= Duration::from_millis(151));
        assert!(c.is_lost(n(4)));
        assert_eq!(c.poll_timeout(), None);
    }

    #[test]
    fn consumer_reports_boot_up_resume_and_state_changes() {
        let mut c: HeartbeatConsumer<4> = HeartbeatConsumer::new();
        c.configure(0x0004_0096).unwrap();
        c.handle_frame(&f("705#05"), ms(0)).unwrap(); // not monitored
        c.handle_frame(&f("704#R1"), ms(0)).unwrap(); // a guarding poll
        assert_eq!(c.poll_event(), None);
        c.handle_frame(&f("704#00"), ms(10)).unwrap();
        assert_eq!(c.poll_event(), Some(HeartbeatEvent::BootUp { node: n(4) }));
        assert_eq!(
            c.poll_event(),
            Some(HeartbeatEvent::StateChanged {
                node: n(4),
                old: None,
                new: NmtState::PreOperational
            })
        );
        assert_eq!(c.poll_timeout(), Some(ms(160)));
        c.handle_frame(&f("704#7F"), ms(100)).unwrap();
        assert_eq!(c.poll_event(), None);
        c.handle_frame(&f("704#05"), ms(200)).unwrap();
        assert!(matches!(
            c.poll_event(),
            Some(HeartbeatEvent::StateChanged {
                new: NmtState::Operational,
                ..
            })
        ));
        // A late heartbeat: Lost, then Resumed, in that order.
        c.handle_frame(&f("704#05"), ms(400)).unwrap();
        assert_eq!(c.poll_event(), Some(HeartbeatEvent::Lost { node: n(4) }));
        assert_eq!(c.poll_event(), Some(HeartbeatEvent::Resumed { node: n(4) }));
        assert_eq!(c.poll_event(), None);
        // A reboot during monitoring.
        c.handle_frame(&f("704#00"), ms(450)).unwrap();
        assert_eq!(c.poll_event(), Some(HeartbeatEvent::BootUp { node: n(4) }));
        assert_eq!(
            c.poll_event(),
            Some(HeartbeatEvent::StateChanged {
                node: n(4),
                old: Some(NmtState::Operational),
                new: NmtState::PreOperational
            })
        );
        assert_eq!(
            c.handle_frame(&f("704#0505"), ms(460)),
            Err(HeartbeatError::WrongLength(2))
        );
    }
}
