//! The master side of CiA 301 for a set of nodes: NMT, one queued SDO client per node, the
//! heartbeat consumer or node guarding per node, the EMCY consumer, and the SYNC producer.
//!
//! It is one [`Endpoint`]: frames in, frames out, events for the application. Its transmit
//! order is SYNC first, then NMT, then guarding polls, then SDO, so a SYNC never waits behind
//! service traffic. PDOs are not its business: the coordinator's cycle packs and unpacks them
//! with [`crate::canopen::pdo::Mapping`] directly.

use core::time::Duration;

use super::NodeId;
use super::emcy::{EmcyConsumer, EmcyEvent};
use super::endpoint::Endpoint;
use super::guarding::{GuardingEvent, GuardingMaster};
use super::heartbeat::{HeartbeatConsumer, HeartbeatEvent};
use super::nmt::{NmtCommand, NmtMaster, NmtMasterError, NmtMasterEvent, NmtState, NmtTarget};
use super::sdo::{SdoClient, SdoClientConfig, SdoEvent};
use super::sync::{SyncCobId, SyncError, SyncProducer};
use crate::can::Frame;
use crate::time::{Instant, earliest};

/// How the master supervises a node.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Supervision {
    /// No supervision.
    None,
    /// Heartbeat consumer with this consumer time (greater than the node's 1017h).
    Heartbeat {
        /// Consumer time, ms.
        consumer_ms: u16,
    },
    /// Node guarding with guard time (100Ch) and life-time factor (100Dh).
    Guarding {
        /// Guard time, ms.
        guard_ms: u16,
        /// Life-time factor.
        factor: u8,
    },
}

/// Why the master refused a request.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum MasterError {
    /// All node slots are taken.
    #[error("the master handles at most {0} nodes")]
    TooManyNodes(usize),
    /// The node was not added.
    #[error("node {0} is not known to the master")]
    UnknownNode(u8),
    /// NMT refused (queue full...).
    #[error(transparent)]
    Nmt(#[from] NmtMasterError),
    /// The SYNC parameters are invalid.
    #[error(transparent)]
    Sync(#[from] SyncError),
    /// Supervision parameters are invalid (for example a zero guard time).
    #[error("invalid supervision parameters for node {0}")]
    Supervision(u8),
}

/// What the master learned (SDO completions are read per node with
/// [`Master::poll_sdo_event`], since they borrow the uploaded data).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MasterEvent {
    /// NMT: a boot-up, or a node's state changed.
    Nmt(NmtMasterEvent),
    /// Heartbeat consumer: loss, resumption, state change, boot-up.
    Heartbeat(HeartbeatEvent),
    /// Node guarding: toggle error, unexpected state, no reply, loss.
    Guarding(GuardingEvent),
    /// An EMCY arrived.
    Emcy(EmcyEvent),
}

const EVENTS: usize = 64;

/// The CANopen master for up to `N` nodes, each with an SDO client of `Q` queued requests and a
/// `BUF`-byte data buffer.
pub struct Master<const N: usize, const Q: usize, const BUF: usize> {
    nmt: NmtMaster<N>,
    sdo: heapless::Vec<SdoClient<Q, BUF>, N>,
    heartbeat: HeartbeatConsumer<N, 32>,
    guarding: GuardingMaster<N, 32>,
    emcy: EmcyConsumer,
    sync: Option<SyncProducer>,
    events: heapless::Deque<MasterEvent, EVENTS>,
    lost_events: u32,
    next_sdo: usize,
    sdo_config: SdoClientConfig,
}

impl<const N: usize, const Q: usize, const BUF: usize> Default for Master<N, Q, BUF> {
    fn default() -> Self {
        Self::new(SdoClientConfig::default(), true)
    }
}

impl<const N: usize, const Q: usize, const BUF: usize> Master<N, Q, BUF> {
    /// A master with no nodes. `accept_legacy_boot_up` also takes the EMCY-COB-ID boot-up
    /// forms some devices send (80h + node, 0 or 1 byte).
    pub fn new(sdo_config: SdoClientConfig, accept_legacy_boot_up: bool) -> Self {
        Master {
            nmt: NmtMaster::new(accept_legacy_boot_up),
            sdo: heapless::Vec::new(),
            heartbeat: HeartbeatConsumer::new(),
            guarding: GuardingMaster::new(),
            emcy: EmcyConsumer::new(accept_legacy_boot_up),
            sync: None,
            events: heapless::Deque::new(),
            lost_events: 0,
            next_sdo: 0,
            sdo_config,
        }
    }

    /// Adds a node with its supervision, starting at `now`.
    pub fn add_node(
        &mut self,
        node: NodeId,
        supervision: Supervision,
        now: Instant,
    ) -> Result<(), MasterError> {
        if self.sdo.iter().all(|c| c.server_node() != node) {
            self.sdo
                .push(SdoClient::new(node, self.sdo_config))
                .map_err(|_| MasterError::TooManyNodes(N))?;
            self.nmt.add_node(node)?;
        }
        self.set_supervision(node, supervision, now)
    }

    /// Changes how a node is supervised (heartbeat and guarding exclude each other).
    pub fn set_supervision(
        &mut self,
        node: NodeId,
        supervision: Supervision,
        now: Instant,
    ) -> Result<(), MasterError> {
        self.heartbeat.remove(node);
        self.guarding.remove(node);
        match supervision {
            Supervision::None => Ok(()),
            Supervision::Heartbeat { consumer_ms } => self
                .heartbeat
                .monitor(node, Duration::from_millis(consumer_ms as u64))
                .map_err(|_| MasterError::Supervision(node.get())),
            Supervision::Guarding { guard_ms, factor } => self
                .guarding
                .add_node(node, guard_ms, factor, now)
                .map_err(|_| MasterError::Supervision(node.get())),
        }
    }

    /// Starts producing SYNC every `period_us` from `now` (COB-ID 080h, counter overflow
    /// `overflow`, 0 = no counter).
    pub fn start_sync(
        &mut self,
        period_us: u32,
        overflow: u8,
        now: Instant,
    ) -> Result<(), MasterError> {
        let cob = SyncCobId {
            producer: true,
            ..SyncCobId::DEFAULT
        };
        let mut p = SyncProducer::new(cob, period_us, overflow)?;
        p.start(now);
        self.sync = Some(p);
        Ok(())
    }

    /// Stops producing SYNC.
    pub fn stop_sync(&mut self) {
        self.sync = None;
    }

    /// Sends an NMT command (and tells guarding which state to expect).
    pub fn nmt(&mut self, command: NmtCommand, target: NmtTarget) -> Result<(), MasterError> {
        self.nmt.command(command, target)?;
        self.guarding.note_command(command, target);
        Ok(())
    }

    /// The node's NMT state as last seen.
    pub fn state(&self, node: NodeId) -> Option<NmtState> {
        self.nmt.state(node)
    }

    /// The SDO client for `node`.
    pub fn sdo(&mut self, node: NodeId) -> Result<&mut SdoClient<Q, BUF>, MasterError> {
        self.sdo
            .iter_mut()
            .find(|c| c.server_node() == node)
            .ok_or(MasterError::UnknownNode(node.get()))
    }

    /// The next completed SDO request of `node`.
    pub fn poll_sdo_event(&mut self, node: NodeId) -> Option<SdoEvent<'_>> {
        self.sdo
            .iter_mut()
            .find(|c| c.server_node() == node)?
            .poll_event()
    }

    /// The next supervision or NMT event.
    pub fn poll_event(&mut self) -> Option<MasterEvent> {
        self.collect_events();
        self.events.pop_front()
    }

    /// Events lost because the queue was full.
    pub fn lost_events(&self) -> u32 {
        self.lost_events
    }

    fn push(&mut self, e: MasterEvent) {
        if self.events.push_back(e).is_err() {
            self.lost_events = self.lost_events.saturating_add(1);
        }
    }

    fn collect_events(&mut self) {
        while let Some(e) = self.nmt.poll_event() {
            self.push(MasterEvent::Nmt(e));
        }
        while let Some(e) = self.heartbeat.poll_event() {
            self.push(MasterEvent::Heartbeat(e));
        }
        while let Some(e) = self.guarding.poll_event() {
            self.push(MasterEvent::Guarding(e));
        }
    }
}

impl<const N: usize, const Q: usize, const BUF: usize> Endpoint for Master<N, Q, BUF> {
    fn handle_frame(&mut self, frame: &Frame, now: Instant) {
        // Errors here are a node's malformed frames: counted by the sub-machines, never fatal.
        let _ = self.nmt.handle_frame(frame);
        let _ = self.heartbeat.handle_frame(frame, now);
        let _ = self.guarding.handle_frame(frame, now);
        if let Ok(Some(e)) = self.emcy.handle_frame(frame) {
            self.push(MasterEvent::Emcy(e));
        }
        if let Some(c) = self.sdo.iter_mut().find(|c| c.accepts(frame)) {
            c.handle_frame(frame, now);
        }
        self.collect_events();
    }

    fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        if let Some(f) = self.sync.as_mut().and_then(|s| s.poll_transmit(now)) {
            return Some(f);
        }
        if let Some(f) = self.nmt.poll_transmit() {
            return Some(f);
        }
        if let Some(f) = self.guarding.poll_transmit(now) {
            return Some(f);
        }
        // Round-robin over the nodes so one busy SDO client cannot starve the others.
        let n = self.sdo.len();
        for i in 0..n {
            let k = (self.next_sdo + i) % n;
            if let Some(f) = self.sdo[k].poll_transmit(now) {
                self.next_sdo = (k + 1) % n;
                return Some(f);
            }
        }
        None
    }

    fn poll_timeout(&self) -> Option<Instant> {
        earliest(
            [
                self.sync.as_ref().and_then(|s| s.poll_timeout()),
                self.heartbeat.poll_timeout(),
                self.guarding.poll_timeout(),
            ]
            .into_iter()
            .chain(self.sdo.iter().map(|c| c.poll_timeout())),
        )
    }

    fn handle_timeout(&mut self, now: Instant) {
        let _ = self.heartbeat.handle_timeout(now);
        let _ = self.guarding.handle_timeout(now);
        for c in self.sdo.iter_mut() {
            c.handle_timeout(now);
        }
        self.collect_events();
    }
}
