//! Network management (CiA 301 §7.2.8): the NMT states, the module-control frame `000h [cs,
//! node]`, the boot-up message in every form the reference devices use, the device side
//! ([`NmtSlave`]) and the master side ([`NmtMaster`]).
//!
//! ```
//! use drivers::canopen::nmt::{NmtCommand, NmtRequest, NmtTarget};
//! let start_all = NmtRequest { command: NmtCommand::Start, target: NmtTarget::All };
//! assert_eq!(start_all.to_bytes(), [0x01, 0x00]);
//! assert_eq!(NmtRequest::from_frame(&start_all.to_frame()), Ok(start_all));
//! ```

use super::NodeId;
use super::cob::ids;
use crate::can::Frame;
use heapless::{Deque, Vec};

/// Builds a standard data frame from protocol code whose identifier (below 0x800) and length
/// (at most 8) are valid by construction, so no caller has to handle an impossible error.
pub(crate) fn frame(id: u16, data: &[u8]) -> Frame {
    let data = data.get(..data.len().min(8)).unwrap_or(&[]);
    match Frame::new_std(id & 0x7FF, data) {
        Ok(f) => f,
        // Unreachable: the id is masked to 11 bits and the data cut to 8 bytes above.
        Err(_) => Frame::std8(id, [0; 8]),
    }
}

/// Why an NMT-related frame or byte could not be decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum NmtError {
    /// The frame is not on COB-ID 000h (the raw identifier is given; extended frames included).
    #[error("NMT module control uses COB-ID 000h, not {0:#x}")]
    WrongCobId(u32),
    /// A remote frame where a data frame was expected.
    #[error("NMT module control must be a data frame, not a remote frame")]
    Remote,
    /// NMT module control carries exactly 2 bytes.
    #[error("NMT module control has DLC 2, not {0}")]
    WrongLength(u8),
    /// A command specifier CiA 301 does not define.
    #[error("unknown NMT command specifier {0:#04x}")]
    UnknownCommand(u8),
    /// A node byte above 127.
    #[error("NMT node byte {0} is not 0 (all) or 1..=127")]
    BadNodeId(u8),
    /// A state byte that is not 00h, 04h, 05h or 7Fh.
    #[error("unknown NMT state byte {0:#04x}")]
    UnknownState(u8),
}

/// The NMT state of a node (CiA 301 §7.3.2.2), as its heartbeat and guarding replies encode it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtState {
    /// Initialising; on the wire only as the boot-up byte 00h.
    Initialising,
    /// Stopped, 04h: only NMT and error control work.
    Stopped,
    /// Operational, 05h: everything works, PDOs included.
    Operational,
    /// Pre-operational, 7Fh: SDO, SYNC, EMCY, but no PDOs.
    PreOperational,
}

/// The communication services whose availability depends on the NMT state (CiA 301 Table 58).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Service {
    /// NMT module control.
    Nmt,
    /// Node guarding, life guarding and heartbeat.
    ErrorControl,
    /// SDO transfers.
    Sdo,
    /// Process data.
    Pdo,
    /// SYNC production and consumption.
    Sync,
    /// TIME stamp.
    Time,
    /// Emergency messages.
    Emcy,
}

impl NmtState {
    /// The state's name as CiA 301 writes it, for people.
    pub const fn name(self) -> &'static str {
        match self {
            NmtState::Initialising => "initialising",
            NmtState::Stopped => "stopped",
            NmtState::Operational => "operational",
            NmtState::PreOperational => "pre-operational",
        }
    }

    /// The state byte of heartbeat and guarding messages (without the guarding toggle bit).
    pub const fn to_byte(self) -> u8 {
        match self {
            NmtState::Initialising => 0x00,
            NmtState::Stopped => 0x04,
            NmtState::Operational => 0x05,
            NmtState::PreOperational => 0x7F,
        }
    }

    /// Decodes a state byte; the caller strips the guarding toggle bit first.
    pub const fn from_byte(b: u8) -> Result<NmtState, NmtError> {
        match b {
            0x00 => Ok(NmtState::Initialising),
            0x04 => Ok(NmtState::Stopped),
            0x05 => Ok(NmtState::Operational),
            0x7F => Ok(NmtState::PreOperational),
            other => Err(NmtError::UnknownState(other)),
        }
    }

    /// Whether a device in this state may use `service` (CiA 301 Table 58; the TLC5xx manual's
    /// Fig 3.29 omits SYNC in pre-operational, CiA 301 allows it and we follow CiA 301).
    pub const fn allows(self, service: Service) -> bool {
        match self {
            // Nothing but the boot-up message leaves a node that is still initialising.
            NmtState::Initialising => false,
            NmtState::Stopped => matches!(service, Service::Nmt | Service::ErrorControl),
            NmtState::PreOperational => !matches!(service, Service::Pdo),
            NmtState::Operational => true,
        }
    }
}

/// An NMT module-control command (CiA 301 §7.2.8.3.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtCommand {
    /// 01h: enter Operational.
    Start,
    /// 02h: enter Stopped.
    Stop,
    /// 80h: enter Pre-operational.
    EnterPreOperational,
    /// 81h: reset the application and communication parameters, then boot up.
    ResetNode,
    /// 82h: reset the communication parameters, then boot up.
    ResetCommunication,
}

impl NmtCommand {
    /// The command specifier byte.
    pub const fn cs(self) -> u8 {
        match self {
            NmtCommand::Start => 0x01,
            NmtCommand::Stop => 0x02,
            NmtCommand::EnterPreOperational => 0x80,
            NmtCommand::ResetNode => 0x81,
            NmtCommand::ResetCommunication => 0x82,
        }
    }

    /// The command for a command specifier byte.
    pub const fn from_cs(cs: u8) -> Result<NmtCommand, NmtError> {
        match cs {
            0x01 => Ok(NmtCommand::Start),
            0x02 => Ok(NmtCommand::Stop),
            0x80 => Ok(NmtCommand::EnterPreOperational),
            0x81 => Ok(NmtCommand::ResetNode),
            0x82 => Ok(NmtCommand::ResetCommunication),
            other => Err(NmtError::UnknownCommand(other)),
        }
    }

    /// The state a node settles in after obeying the command (resets end in Pre-operational,
    /// after the boot-up message).
    pub const fn resulting_state(self) -> NmtState {
        match self {
            NmtCommand::Start => NmtState::Operational,
            NmtCommand::Stop => NmtState::Stopped,
            NmtCommand::EnterPreOperational
            | NmtCommand::ResetNode
            | NmtCommand::ResetCommunication => NmtState::PreOperational,
        }
    }

    /// Whether the command resets the node (and with it the guarding toggle bit).
    pub const fn is_reset(self) -> bool {
        matches!(self, NmtCommand::ResetNode | NmtCommand::ResetCommunication)
    }
}

/// Which nodes an NMT command addresses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtTarget {
    /// Node byte 0: every node.
    All,
    /// One node.
    Node(NodeId),
}

impl NmtTarget {
    /// The node byte of the frame.
    pub const fn to_byte(self) -> u8 {
        match self {
            NmtTarget::All => 0,
            NmtTarget::Node(n) => n.get(),
        }
    }
    /// Whether `node` is addressed.
    pub fn includes(self, node: NodeId) -> bool {
        match self {
            NmtTarget::All => true,
            NmtTarget::Node(n) => n == node,
        }
    }
}

/// One NMT module-control frame: `000h [cs, node]`, DLC 2.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct NmtRequest {
    /// What to do.
    pub command: NmtCommand,
    /// To whom.
    pub target: NmtTarget,
}

impl NmtRequest {
    /// The two data bytes.
    pub const fn to_bytes(self) -> [u8; 2] {
        [self.command.cs(), self.target.to_byte()]
    }

    /// Decodes the data bytes; exactly 2 are required.
    pub fn from_bytes(data: &[u8]) -> Result<NmtRequest, NmtError> {
        let &[cs, node] = data else {
            return Err(NmtError::WrongLength(data.len() as u8));
        };
        let command = NmtCommand::from_cs(cs)?;
        let target = match node {
            0 => NmtTarget::All,
            n => NmtTarget::Node(NodeId::new(n).ok_or(NmtError::BadNodeId(n))?),
        };
        Ok(NmtRequest { command, target })
    }

    /// The frame on COB-ID 000h.
    pub fn to_frame(self) -> Frame {
        frame(ids::NMT, &self.to_bytes())
    }

    /// Decodes a frame, checking COB-ID, frame type and DLC.
    pub fn from_frame(f: &Frame) -> Result<NmtRequest, NmtError> {
        if f.cob_id() != Some(ids::NMT) {
            return Err(NmtError::WrongCobId(f.raw_id()));
        }
        if f.is_remote() {
            return Err(NmtError::Remote);
        }
        Self::from_bytes(f.data())
    }
}

/// The boot-up message a device sends when it enters Pre-operational after initialising.
///
/// The TLC5xx manual documents three forms (reference seed-003 §2.2, erratum A4), so a device
/// simulator picks one and the master accepts them all.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum BootUpStyle {
    /// CiA 301 v4: `700h+n [00]`, the heartbeat frame with the Initialising state.
    #[default]
    Ds301,
    /// Legacy, on the EMCY COB-ID without data: `80h+n []`.
    LegacyEmcyEmpty,
    /// Legacy, on the EMCY COB-ID with one byte: `80h+n [00]`.
    LegacyEmcyOneByte,
}

impl BootUpStyle {
    /// The boot-up frame of `node` in this style.
    pub fn frame(self, node: NodeId) -> Frame {
        match self {
            BootUpStyle::Ds301 => frame(ids::NMT_ERROR_CONTROL + node.get() as u16, &[0]),
            BootUpStyle::LegacyEmcyEmpty => frame(ids::EMCY + node.get() as u16, &[]),
            BootUpStyle::LegacyEmcyOneByte => frame(ids::EMCY + node.get() as u16, &[0]),
        }
    }
}

/// The node whose boot-up message `f` is, if it is one: `700h+n [00]` always, and with
/// `accept_legacy` also `80h+n` with DLC 0 or 1 (a real EMCY always has 8 bytes, so the short
/// frame cannot be mistaken for one).
pub fn decode_boot_up(f: &Frame, accept_legacy: bool) -> Option<NodeId> {
    let cob = f.cob_id()?;
    if f.is_remote() {
        return None;
    }
    let node = NodeId::new((cob & 0x7F) as u8)?;
    match cob & !0x7F {
        ids::NMT_ERROR_CONTROL if f.data() == [0] => Some(node),
        ids::EMCY if accept_legacy && f.dlc() <= 1 => Some(node),
        _ => None,
    }
}

/// Which parameters a reset makes the device reload.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ResetKind {
    /// 81h: the application (manufacturer and profile areas) and the communication area.
    Node,
    /// 82h: the communication area (1000h..1FFFh) only.
    Communication,
}

/// What an NMT command did to a device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtSlaveEvent {
    /// The state changed (start, stop, enter pre-operational).
    StateChanged {
        /// Before.
        old: NmtState,
        /// After.
        new: NmtState,
    },
    /// A reset was commanded: the device reloads the parameters named by the kind, then calls
    /// [`NmtSlave::boot`], which sends the boot-up message and enters Pre-operational.
    Reset(ResetKind),
}

/// The device side of NMT: obeys module-control frames addressed to it or to all nodes.
#[derive(Debug, Clone)]
pub struct NmtSlave {
    node: NodeId,
    style: BootUpStyle,
    state: NmtState,
    boot_up_pending: bool,
}

impl NmtSlave {
    /// A device at power-on: Initialising until [`NmtSlave::boot`] is called.
    pub fn new(node: NodeId, style: BootUpStyle) -> NmtSlave {
        NmtSlave {
            node,
            style,
            state: NmtState::Initialising,
            boot_up_pending: false,
        }
    }

    /// The node-ID.
    pub fn node(&self) -> NodeId {
        self.node
    }

    /// The current state.
    pub fn state(&self) -> NmtState {
        self.state
    }

    /// Whether the current state allows `service` (PDO only in Operational, no SDO in Stopped).
    pub fn allows(&self, service: Service) -> bool {
        self.state.allows(service)
    }

    /// Ends initialisation (power-on or after a reset): enters Pre-operational and queues the
    /// boot-up message. Heartbeat production starts after it (see `heartbeat`).
    pub fn boot(&mut self) {
        self.state = NmtState::PreOperational;
        self.boot_up_pending = true;
    }

    /// Whether `f` is on the module-control COB-ID (for any node).
    pub fn accepts(f: &Frame) -> bool {
        f.cob_id() == Some(ids::NMT)
    }

    /// Obeys a module-control frame. Frames on other COB-IDs and commands for other nodes give
    /// `Ok(None)`; a malformed NMT frame gives the typed error and changes nothing. While
    /// initialising the device does not listen yet.
    pub fn handle_frame(&mut self, f: &Frame) -> Result<Option<NmtSlaveEvent>, NmtError> {
        if !Self::accepts(f) {
            return Ok(None);
        }
        let req = NmtRequest::from_frame(f)?;
        if !req.target.includes(self.node) || self.state == NmtState::Initialising {
            return Ok(None);
        }
        let old = self.state;
        let event = match req.command {
            NmtCommand::ResetNode | NmtCommand::ResetCommunication => {
                self.state = NmtState::Initialising;
                // A boot-up not yet sent belongs to the life that just ended.
                self.boot_up_pending = false;
                let kind = if req.command == NmtCommand::ResetNode {
                    ResetKind::Node
                } else {
                    ResetKind::Communication
                };
                Some(NmtSlaveEvent::Reset(kind))
            }
            cmd => {
                let new = cmd.resulting_state();
                self.state = new;
                (old != new).then_some(NmtSlaveEvent::StateChanged { old, new })
            }
        };
        Ok(event)
    }

    /// The boot-up message, once, after [`NmtSlave::boot`].
    pub fn poll_transmit(&mut self) -> Option<Frame> {
        if core::mem::take(&mut self.boot_up_pending) {
            Some(self.style.frame(self.node))
        } else {
            None
        }
    }
}

/// Why the NMT master refused a request or could not take a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum NmtMasterError {
    /// All `N` node slots are taken.
    #[error("the NMT master tracks at most {0} nodes")]
    TooManyNodes(usize),
    /// The node is not registered.
    #[error("node {0} is not registered with the NMT master")]
    UnknownNode(u8),
    /// The transmit queue is full; the command was not queued.
    #[error("the NMT transmit queue is full ({0} frames)")]
    TxQueueFull(usize),
    /// The event queue is full; the state was updated but the event was dropped.
    #[error("the NMT event queue is full ({0} events)")]
    EventQueueFull(usize),
    /// An error-control frame carried a byte that is no state.
    #[error(transparent)]
    Frame(#[from] NmtError),
}

/// What the NMT master learned about a node.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtMasterEvent {
    /// The node sent a boot-up message (power-on or reset): it is now Pre-operational and has
    /// lost every parameter that is not stored.
    BootUp(NodeId),
    /// The node's reported state changed (`old` is `None` the first time it is heard of).
    StateChanged {
        /// The node.
        node: NodeId,
        /// The state known before, if any.
        old: Option<NmtState>,
        /// The state now reported.
        new: NmtState,
    },
}

#[derive(Debug, Clone, Copy)]
struct Tracked {
    node: NodeId,
    state: Option<NmtState>,
    commanded: Option<NmtState>,
}

/// The master side of NMT for up to `N` nodes, with queues of `Q` frames and `Q` events.
///
/// Sends module-control commands and tracks each node's state from boot-up messages (every
/// form of [`BootUpStyle`]), heartbeats and node-guarding replies (the toggle bit is masked).
#[derive(Debug)]
pub struct NmtMaster<const N: usize, const Q: usize = 16> {
    nodes: Vec<Tracked, N>,
    accept_legacy_boot_up: bool,
    tx: Deque<Frame, Q>,
    events: Deque<NmtMasterEvent, Q>,
}

impl<const N: usize, const Q: usize> Default for NmtMaster<N, Q> {
    fn default() -> Self {
        Self::new(true)
    }
}

impl<const N: usize, const Q: usize> NmtMaster<N, Q> {
    /// A master tracking no node yet. With `accept_legacy_boot_up`, `80h+n` frames of DLC 0 or
    /// 1 count as boot-up messages (TLC5xx); without, they are left to the EMCY consumer.
    pub fn new(accept_legacy_boot_up: bool) -> Self {
        NmtMaster {
            nodes: Vec::new(),
            accept_legacy_boot_up,
            tx: Deque::new(),
            events: Deque::new(),
        }
    }

    /// Starts tracking `node` (state unknown until it is heard). Adding a node twice is a no-op.
    pub fn add_node(&mut self, node: NodeId) -> Result<(), NmtMasterError> {
        if self.nodes.iter().any(|t| t.node == node) {
            return Ok(());
        }
        self.nodes
            .push(Tracked {
                node,
                state: None,
                commanded: None,
            })
            .map_err(|_| NmtMasterError::TooManyNodes(N))
    }

    /// The node's last reported state, `None` if never heard or not registered.
    pub fn state(&self, node: NodeId) -> Option<NmtState> {
        self.nodes.iter().find(|t| t.node == node)?.state
    }

    /// The state the last command sent to the node should lead to.
    pub fn commanded(&self, node: NodeId) -> Option<NmtState> {
        self.nodes.iter().find(|t| t.node == node)?.commanded
    }

    /// Queues a command. NMT is unconfirmed, so the tracked state only changes when the node
    /// reports it (heartbeat, guarding reply, boot-up).
    pub fn command(
        &mut self,
        command: NmtCommand,
        target: NmtTarget,
    ) -> Result<(), NmtMasterError> {
        if let NmtTarget::Node(n) = target
            && !self.nodes.iter().any(|t| t.node == n)
        {
            return Err(NmtMasterError::UnknownNode(n.get()));
        }
        let req = NmtRequest { command, target };
        self.tx
            .push_back(req.to_frame())
            .map_err(|_| NmtMasterError::TxQueueFull(Q))?;
        for t in self.nodes.iter_mut().filter(|t| target.includes(t.node)) {
            t.commanded = Some(command.resulting_state());
        }
        Ok(())
    }

    /// Feeds a received frame. Boot-ups, heartbeats and guarding replies of registered nodes
    /// update the state; everything else is ignored. Guarding polls (remote frames) are ignored.
    pub fn handle_frame(&mut self, f: &Frame) -> Result<(), NmtMasterError> {
        let Some(cob) = f.cob_id() else {
            return Ok(());
        };
        if f.is_remote() {
            return Ok(());
        }
        let Some(idx) = self
            .nodes
            .iter()
            .position(|t| t.node.get() as u16 == cob & 0x7F)
        else {
            return Ok(());
        };
        if let Some(node) = decode_boot_up(f, self.accept_legacy_boot_up) {
            self.push_event(NmtMasterEvent::BootUp(node))?;
            return self.set_state(idx, NmtState::PreOperational);
        }
        if cob & !0x7F != ids::NMT_ERROR_CONTROL {
            return Ok(());
        }
        let &[byte] = f.data() else {
            return Err(NmtError::WrongLength(f.dlc()).into());
        };
        // Bit 7 is the guarding toggle; heartbeats keep it 0. Initialising is only ever the
        // boot-up byte 00h, handled above.
        let state = match NmtState::from_byte(byte & 0x7F)? {
            NmtState::Initialising => return Err(NmtError::UnknownState(byte).into()),
            s => s,
        };
        self.set_state(idx, state)
    }

    fn set_state(&mut self, idx: usize, new: NmtState) -> Result<(), NmtMasterError> {
        let Some(t) = self.nodes.get_mut(idx) else {
            return Ok(());
        };
        let old = t.state;
        t.state = Some(new);
        let node = t.node;
        if old != Some(new) {
            self.push_event(NmtMasterEvent::StateChanged { node, old, new })?;
        }
        Ok(())
    }

    fn push_event(&mut self, e: NmtMasterEvent) -> Result<(), NmtMasterError> {
        self.events
            .push_back(e)
            .map_err(|_| NmtMasterError::EventQueueFull(Q))
    }

    /// The next command frame to send.
    pub fn poll_transmit(&mut self) -> Option<Frame> {
        self.tx.pop_front()
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<NmtMasterEvent> {
        self.events.pop_front()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::str::FromStr;

    fn n(id: u8) -> NodeId {
        NodeId::new(id).unwrap()
    }
    fn f(s: &str) -> Frame {
        Frame::from_str(s).unwrap()
    }

    #[test]
    fn state_bytes_round_trip() {
        for s in [
            NmtState::Initialising,
            NmtState::Stopped,
            NmtState::Operational,
            NmtState::PreOperational,
        ] {
            assert_eq!(NmtState::from_byte(s.to_byte()), Ok(s));
        }
        assert_eq!(NmtState::from_byte(0x06), Err(NmtError::UnknownState(0x06)));
    }

    #[test]
    fn command_frames_match_the_manual() {
        // seed-003 §8.4/§8.7: `000: 01 00` starts all nodes.
        let req = NmtRequest::from_frame(&f("000#0100")).unwrap();
        assert_eq!(req.command, NmtCommand::Start);
        assert_eq!(req.target, NmtTarget::All);
        for (cs, cmd) in [
            (0x01, NmtCommand::Start),
            (0x02, NmtCommand::Stop),
            (0x80, NmtCommand::EnterPreOperational),
            (0x81, NmtCommand::ResetNode),
            (0x82, NmtCommand::ResetCommunication),
        ] {
            let r = NmtRequest {
                command: cmd,
                target: NmtTarget::Node(n(4)),
            };
            assert_eq!(r.to_frame(), Frame::new_std(0, &[cs, 4]).unwrap());
            assert_eq!(NmtRequest::from_frame(&r.to_frame()), Ok(r));
        }
    }

    #[test]
    fn bad_command_frames_give_typed_errors() {
        assert_eq!(
            NmtRequest::from_frame(&f("000#01")),
            Err(NmtError::WrongLength(1))
        );
        assert_eq!(
            NmtRequest::from_frame(&f("000#010000")),
            Err(NmtError::WrongLength(3))
        );
        assert_eq!(
            NmtRequest::from_frame(&f("000#0300")),
            Err(NmtError::UnknownCommand(0x03))
        );
        assert_eq!(
            NmtRequest::from_frame(&f("000#0180")),
            Err(NmtError::BadNodeId(0x80))
        );
        assert_eq!(
            NmtRequest::from_frame(&f("001#0100")),
            Err(NmtError::WrongCobId(1))
        );
        assert_eq!(NmtRequest::from_frame(&f("000#R2")), Err(NmtError::Remote));
    }

    #[test]
    fn services_per_state() {
        use Service::*;
        assert!(NmtState::Operational.allows(Pdo));
        assert!(!NmtState::PreOperational.allows(Pdo));
        assert!(NmtState::PreOperational.allows(Sdo));
        assert!(NmtState::PreOperational.allows(Emcy));
        assert!(!NmtState::Stopped.allows(Sdo));
        assert!(!NmtState::Stopped.allows(Emcy));
        assert!(NmtState::Stopped.allows(ErrorControl));
        assert!(NmtState::Stopped.allows(Nmt));
        assert!(!NmtState::Initialising.allows(Nmt));
    }

    #[test]
    fn slave_obeys_its_commands_and_broadcasts() {
        let mut s = NmtSlave::new(n(4), BootUpStyle::Ds301);
        // Deaf while initialising.
        assert_eq!(s.handle_frame(&f("000#0100")), Ok(None));
        assert_eq!(s.poll_transmit(), None);
        s.boot();
        assert_eq!(s.poll_transmit(), Some(f("704#00")));
        assert_eq!(s.poll_transmit(), None);
        assert_eq!(s.state(), NmtState::PreOperational);
        assert!(!s.allows(Service::Pdo));
        // For another node: ignored.
        assert_eq!(s.handle_frame(&f("000#0105")), Ok(None));
        assert_eq!(s.state(), NmtState::PreOperational);
        assert_eq!(
            s.handle_frame(&f("000#0104")),
            Ok(Some(NmtSlaveEvent::StateChanged {
                old: NmtState::PreOperational,
                new: NmtState::Operational
            }))
        );
        assert!(s.allows(Service::Pdo));
        // Repeating a command changes nothing and reports nothing.
        assert_eq!(s.handle_frame(&f("000#0100")), Ok(None));
        assert_eq!(
            s.handle_frame(&f("000#0200")),
            Ok(Some(NmtSlaveEvent::StateChanged {
                old: NmtState::Operational,
                new: NmtState::Stopped
            }))
        );
        assert!(!s.allows(Service::Sdo));
        // A malformed frame changes nothing.
        assert_eq!(s.handle_frame(&f("000#07")), Err(NmtError::WrongLength(1)));
        assert_eq!(s.state(), NmtState::Stopped);
        // Other COB-IDs are not NMT.
        assert_eq!(s.handle_frame(&f("080#")), Ok(None));
    }

    #[test]
    fn slave_reports_resets_and_boots_again() {
        let mut s = NmtSlave::new(n(127), BootUpStyle::LegacyEmcyEmpty);
        s.boot();
        assert_eq!(s.poll_transmit(), Some(f("0FF#")));
        assert_eq!(
            s.handle_frame(&f("000#817F")),
            Ok(Some(NmtSlaveEvent::Reset(ResetKind::Node)))
        );
        assert_eq!(s.state(), NmtState::Initialising);
        assert_eq!(s.poll_transmit(), None);
        s.boot();
        assert_eq!(s.poll_transmit(), Some(f("0FF#")));
        assert_eq!(
            s.handle_frame(&f("000#8200")),
            Ok(Some(NmtSlaveEvent::Reset(ResetKind::Communication)))
        );
        let mut s = NmtSlave::new(n(127), BootUpStyle::LegacyEmcyOneByte);
        s.boot();
        assert_eq!(s.poll_transmit(), Some(f("0FF#00")));
    }

    #[test]
    fn boot_up_forms() {
        assert_eq!(decode_boot_up(&f("704#00"), false), Some(n(4)));
        assert_eq!(decode_boot_up(&f("0FF#"), true), Some(n(127)));
        assert_eq!(decode_boot_up(&f("0FF#00"), true), Some(n(127)));
        assert_eq!(decode_boot_up(&f("0FF#00"), false), None);
        // A heartbeat, a guarding poll, a real EMCY and SYNC are not boot-ups.
        assert_eq!(decode_boot_up(&f("704#05"), true), None);
        assert_eq!(decode_boot_up(&f("704#R1"), true), None);
        assert_eq!(decode_boot_up(&f("081#1222000000000000"), true), None);
        assert_eq!(decode_boot_up(&f("080#"), true), None);
    }

    #[test]
    fn master_tracks_states_and_a_reboot() {
        let mut m: NmtMaster<4> = NmtMaster::new(true);
        m.add_node(n(4)).unwrap();
        m.add_node(n(127)).unwrap();
        assert_eq!(m.state(n(4)), None);

        m.handle_frame(&f("704#00")).unwrap();
        assert_eq!(m.poll_event(), Some(NmtMasterEvent::BootUp(n(4))));
        assert_eq!(
            m.poll_event(),
            Some(NmtMasterEvent::StateChanged {
                node: n(4),
                old: None,
                new: NmtState::PreOperational
            })
        );
        // Legacy boot-up of the factory node 127.
        m.handle_frame(&f("0FF#")).unwrap();
        assert_eq!(m.poll_event(), Some(NmtMasterEvent::BootUp(n(127))));
        assert!(m.poll_event().is_some());
        assert_eq!(m.state(n(127)), Some(NmtState::PreOperational));

        m.command(NmtCommand::Start, NmtTarget::All).unwrap();
        assert_eq!(m.poll_transmit(), Some(f("000#0100")));
        assert_eq!(m.poll_transmit(), None);
        assert_eq!(m.commanded(n(4)), Some(NmtState::Operational));
        // Unconfirmed: the state changes only when reported.
        assert_eq!(m.state(n(4)), Some(NmtState::PreOperational));
        m.handle_frame(&f("704#05")).unwrap(); // heartbeat
        assert_eq!(
            m.poll_event(),
            Some(NmtMasterEvent::StateChanged {
                node: n(4),
                old: Some(NmtState::PreOperational),
                new: NmtState::Operational
            })
        );
        // A guarding reply with the toggle bit set carries the same state: no event.
        m.handle_frame(&f("704#85")).unwrap();
        assert_eq!(m.poll_event(), None);
        // The guarding poll itself is ignored.
        m.handle_frame(&f("704#R1")).unwrap();
        assert_eq!(m.poll_event(), None);

        // The node reboots mid-run.
        m.handle_frame(&f("704#00")).unwrap();
        assert_eq!(m.poll_event(), Some(NmtMasterEvent::BootUp(n(4))));
        assert_eq!(
            m.poll_event(),
            Some(NmtMasterEvent::StateChanged {
                node: n(4),
                old: Some(NmtState::Operational),
                new: NmtState::PreOperational
            })
        );
        assert_eq!(m.state(n(4)), Some(NmtState::PreOperational));

        // Unregistered nodes are ignored; bad bytes are typed errors.
        m.handle_frame(&f("705#05")).unwrap();
        assert_eq!(m.poll_event(), None);
        assert_eq!(
            m.handle_frame(&f("704#06")),
            Err(NmtMasterError::Frame(NmtError::UnknownState(6)))
        );
        assert_eq!(
            m.handle_frame(&f("704#80")),
            Err(NmtMasterError::Frame(NmtError::UnknownState(0x80)))
        );
        assert_eq!(
            m.handle_frame(&f("704#0505")),
            Err(NmtMasterError::Frame(NmtError::WrongLength(2)))
        );
        assert_eq!(
            m.command(NmtCommand::Stop, NmtTarget::Node(n(9))),
            Err(NmtMasterError::UnknownNode(9))
        );
    }

    #[test]
    fn master_queues_are_bounded() {
        let mut m: NmtMaster<1, 2> = NmtMaster::new(false);
        m.add_node(n(1)).unwrap();
        assert_eq!(m.add_node(n(2)), Err(NmtMasterError::TooManyNodes(1)));
        m.command(NmtCommand::Start, NmtTarget::All).unwrap();
        m.command(NmtCommand::Stop, NmtTarget::All).unwrap();
        assert_eq!(
            m.command(NmtCommand::Stop, NmtTarget::All),
            Err(NmtMasterError::TxQueueFull(2))
        );
        m.handle_frame(&f("701#00")).unwrap(); // two events
        assert_eq!(
            m.handle_frame(&f("701#05")),
            Err(NmtMasterError::EventQueueFull(2))
        );
        // The state is still tracked when the event is dropped.
        assert_eq!(m.state(n(1)), Some(NmtState::Operational));
        // Legacy boot-ups are not accepted by this master.
        m.handle_frame(&f("081#")).unwrap();
    }

    #[test]
    fn decoders_never_panic() {
        use crate::canopen::{emcy, guarding, heartbeat, sync};
        let mut nmt: NmtMaster<2, 4> = NmtMaster::new(true);
        nmt.add_node(n(1)).unwrap();
        let mut slave = NmtSlave::new(n(1), BootUpStyle::Ds301);
        slave.boot();
        let mut emcy_c = emcy::EmcyConsumer::new(true);
        let mut sync_c = sync::SyncConsumer::new(sync::SyncCobId::DEFAULT, 1_000, 100, 16).unwrap();
        let mut hb: heartbeat::HeartbeatConsumer<2, 4> = heartbeat::HeartbeatConsumer::new();
        hb.configure(0x0001_0064).unwrap();
        let mut gm: guarding::GuardingMaster<2, 4> = guarding::GuardingMaster::new();
        gm.add_node(n(1), 10, 2, crate::time::Instant::ZERO)
            .unwrap();
        let mut t = crate::time::Instant::ZERO;
        for id in [0x000u16, 0x080, 0x081, 0x0FF, 0x701, 0x77F] {
            for len in 0..=8usize {
                for b in 0..=255u8 {
                    let data = [b, b.wrapping_mul(7), 0, b, 0xFF, 0, b, 1];
                    let data_frame = Frame::new_std(id, &data[..len]).unwrap();
                    let remote = Frame::new_std_remote(id, len as u8).unwrap();
                    for fr in [data_frame, remote] {
                        t += core::time::Duration::from_micros(1);
                        let _ = NmtRequest::from_frame(&fr);
                        let _ = decode_boot_up(&fr, true);
                        let _ = nmt.handle_frame(&fr);
                        let _ = slave.handle_frame(&fr);
                        let _ = emcy::EmcyMessage::from_frame(&fr);
                        let _ = emcy_c.handle_frame(&fr);
                        let _ = sync::decode_sync(&fr);
                        let _ = sync_c.handle_frame(&fr, t);
                        let _ = heartbeat::decode_heartbeat(&fr);
                        let _ = hb.handle_frame(&fr, t);
                        let _ = guarding::GuardReply::from_frame(&fr);
                        let _ = gm.handle_frame(&fr, t);
                        let _ = gm.poll_transmit(t);
                        while nmt.poll_event().is_some() || hb.poll_event().is_some() {}
                        while gm.poll_event().is_some() {}
                    }
                }
            }
        }
    }
}
