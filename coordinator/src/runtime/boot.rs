//! Booting the CANopen drives over SDO, sans-I/O: a [`BootSequencer`] is fed received frames
//! and time and hands back the frames to send, so the same code boots the drives in virtual
//! time (tests, the embedded machine) and in real time (the services task).
//!
//! Per node ([`BootPlan`]), in order:
//!
//! 1. NMT reset communication, so the node drops whatever PDO settings it had;
//! 2. wait for its boot-up message (per-node timeout);
//! 3. identity: read 1000h (device type) and 1018h:01 (vendor), compared if the plan knows them;
//! 4. PDO configuration: the writes of `drivers::canopen::pdo::ConfigPlan` for every PDO (or,
//!    for a static mapping such as Festo's FHPP PDO1, only the transmission type);
//! 5. read-back verification of everything written (`ConfigPlan::verify`; for a static mapping
//!    the mapping is read and compared with the expected one);
//! 6. supervision: heartbeat producer time 1017h, or guard time 100Ch + life time factor 100Dh,
//!    each written and read back;
//! 7. NMT start (the node is done when the start command has been handed out).
//!
//! Nodes boot concurrently, one SDO request at a time per node; a node that fails is reported
//! with the step, the object and the abort code, and the others go on. Every wait is bounded:
//! the boot-up by [`BootTimeouts::boot_up`], every SDO exchange by [`BootTimeouts::sdo`].
//!
//! After the first report the sequencer keeps looking after each node, as a CiA 302 master
//! does (the lifecycle):
//!
//! - a node that sent no boot-up is *waiting*: reported once ([`FailureDetail::NoBootUp`]),
//!   then asked again with reset communication every [`BootTimeouts::probe`]; its boot-up
//!   (answer or power-on) boots it;
//! - a node that goes silent mid-boot (SDO timeout) waits the same way;
//! - a running node that sends a boot-up reset itself: it is reported
//!   ([`FailureDetail::UnexpectedBootUp`]) and configured again from the identity step;
//! - a node that sends a boot-up mid-boot is configured again from the identity step once the
//!   SDO request it holds has completed; one that keeps doing so is reported
//!   ([`FailureDetail::BootInterrupted`]) and asked again from the reset. Only the completion of
//!   the current step's request is ever taken for it; an answer naming another object voids
//!   the exchange ([`FailureDetail::StrayAnswer`]) and the node is asked again;
//! - a running node the cycle lost (heartbeat, guarding, late TPDOs: [`BootSequencer::lost`])
//!   is reported ([`FailureDetail::Lost`]) and waits;
//! - a node refused (wrong device, an SDO abort, a read-back mismatch) stays refused until it
//!   sends a boot-up (it was replaced or power-cycled), which boots it again.
//!
//! Every successful (re)configuration ends with another `Ok` report.

use std::collections::VecDeque;
use std::fmt;
use std::time::Duration;

use drivers::can::Frame;
use drivers::canopen::endpoint::Endpoint;
use drivers::canopen::nmt::{NmtCommand, NmtRequest, NmtTarget, decode_boot_up};
use drivers::canopen::pdo::{
    ConfigPlan, PdoDirection, PdoSettings, PlanError, VerifyError, comm::SUB_TRANSMISSION_TYPE,
};
use drivers::canopen::sdo::{
    AbortedBy, Completion, DownloadMode, RequestError, RequestId, SdoClient, SdoClientConfig,
    SdoError,
};
use drivers::canopen::{AbortCode, Address, NodeId};
use drivers::time::{Instant, earliest};

use crate::axis::DeviceKind;

/// The most entries a PDO mapping has (8 bytes of 8 bits each at most).
pub const MAX_MAPPING: usize = 8;

/// The identities the boot compares (1000h, 1018h:01), from the catalog.
pub use drivers::catalog::{
    CIA402_DEVICE_TYPE, FESTO_FHPP_DEVICE_TYPE, FESTO_VENDOR_ID, TLC5XX_VENDOR_ID,
};

/// One PDO to set up on a node, as owned data (the mapping is copied in).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PdoPlan {
    /// RPDO or TPDO (as the node sees it).
    pub direction: PdoDirection,
    /// PDO number, 1-based.
    pub number: u16,
    /// The whole COB-ID entry; `None` = the predefined connection set's identifier.
    pub cob_id: Option<u32>,
    /// Mapping entries `index << 16 | sub << 8 | bits`.
    pub mapping: heapless::Vec<u32, MAX_MAPPING>,
    /// Transmission type (1 = every SYNC).
    pub transmission_type: u8,
    /// Inhibit time, 100 µs (TPDO only).
    pub inhibit_100us: u16,
    /// Event timer, ms.
    pub event_timer_ms: u16,
    /// The device's mapping cannot be written (Festo FHPP PDO1): only the transmission type is
    /// written, the mapping is read back and compared with `mapping`.
    pub static_mapping: bool,
}

impl PdoPlan {
    /// A SYNC-driven (type 1) PDO with the predefined COB-ID; `None` if the mapping has more
    /// than [`MAX_MAPPING`] entries.
    pub fn sync(direction: PdoDirection, number: u16, mapping: &[u32]) -> Option<PdoPlan> {
        Some(PdoPlan {
            direction,
            number,
            cob_id: None,
            mapping: heapless::Vec::from_slice(mapping).ok()?,
            transmission_type: 1,
            inhibit_100us: 0,
            event_timer_ms: 0,
            static_mapping: false,
        })
    }

    /// The settings `ConfigPlan` takes, borrowing the mapping.
    pub fn settings(&self) -> PdoSettings<'_> {
        PdoSettings {
            direction: self.direction,
            number: self.number,
            cob_id: self.cob_id,
            mapping: &self.mapping,
            transmission_type: self.transmission_type,
            inhibit_100us: self.inhibit_100us,
            event_timer_ms: self.event_timer_ms,
            sync_start: 0,
        }
    }
}

/// How a node is supervised once running; the boot writes the node's side of it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SupervisionPlan {
    /// Nothing is written.
    None,
    /// The node produces heartbeats (1017h).
    Heartbeat {
        /// Producer time, ms.
        producer_ms: u16,
    },
    /// The master guards the node (100Ch, 100Dh); for devices without heartbeat.
    Guarding {
        /// Guard time, ms.
        guard_ms: u16,
        /// Life time factor.
        life_factor: u8,
    },
}

/// The bounds on every wait of a boot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct BootTimeouts {
    /// From sending reset communication to the boot-up message.
    pub boot_up: Duration,
    /// One SDO exchange (the client's silence timeout).
    pub sdo: Duration,
    /// How often a waiting node is asked again (reset communication) after its first wait.
    pub probe: Duration,
}

impl Default for BootTimeouts {
    /// 5 s for the boot-up (real drives take a few seconds after power-on), 500 ms per SDO, a
    /// probe of a waiting node every second.
    fn default() -> Self {
        BootTimeouts {
            boot_up: Duration::from_secs(5),
            sdo: Duration::from_millis(500),
            probe: Duration::from_secs(1),
        }
    }
}

/// What to do to boot one node.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BootPlan {
    /// The node.
    pub node: NodeId,
    /// The drive on it.
    pub kind: DeviceKind,
    /// Expected 1000h, if known (compared exactly).
    pub device_type: Option<u32>,
    /// Expected 1018h:01, if known.
    pub vendor_id: Option<u32>,
    /// The PDOs to set up, in order.
    pub pdos: Vec<PdoPlan>,
    /// The node's side of supervision.
    pub supervision: SupervisionPlan,
    /// Drive parameters to write and read back after the supervision: (object, value, size in
    /// bytes 1..=4).
    pub parameters: Vec<(Address, u32, u8)>,
    /// Bounds on the waits.
    pub timeouts: BootTimeouts,
}

/// Why [`plan_for`] cannot make a plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum BootPlanError {
    /// The device is not on CANopen (the CMMO-ST speaks Modbus TCP).
    #[error("{0} is not a CANopen device")]
    NotCanopen(DeviceKind),
    /// The device has no heartbeat producer (MTR-DCI, EMCA): guard it instead.
    #[error("{0} has no heartbeat (1017h); use node guarding")]
    NoHeartbeat(DeviceKind),
    /// A mapping has more than [`MAX_MAPPING`] entries.
    #[error("a PDO mapping of {0} entries (at most {MAX_MAPPING})")]
    MappingTooLong(usize),
}

/// The plan for a drive of `kind` on `node`: RPDO1 = `rpdo`, TPDO1 = `tpdo` (an empty slice
/// leaves that PDO alone), both SYNC-driven (type 1) on their predefined COB-IDs, and the
/// supervision given. The expected identity, whether PDO1 is static and whether the device has
/// a heartbeat come from the catalog; the profile is the device's whose PDO1 starts with the
/// same object as `rpdo` (6040h: CiA 402), or its default.
pub fn plan_for(
    node: NodeId,
    kind: DeviceKind,
    rpdo: &[u32],
    tpdo: &[u32],
    supervision: SupervisionPlan,
) -> Result<BootPlan, BootPlanError> {
    let device = kind.device();
    if !device.is_canopen() {
        return Err(BootPlanError::NotCanopen(kind));
    }
    if !device.has_heartbeat() && matches!(supervision, SupervisionPlan::Heartbeat { .. }) {
        return Err(BootPlanError::NoHeartbeat(kind));
    }
    let object = |m: &[u32]| m.first().map(|e| e >> 16);
    let facts = device
        .profiles
        .iter()
        .find(|f| f.pdo1.is_some_and(|p| object(p.rpdo) == object(rpdo)))
        .unwrap_or(&device.profiles[0]);
    let mut pdos = Vec::new();
    for (direction, mapping) in [(PdoDirection::Rpdo, rpdo), (PdoDirection::Tpdo, tpdo)] {
        if mapping.is_empty() {
            continue;
        }
        let mut p = PdoPlan::sync(direction, 1, mapping)
            .ok_or(BootPlanError::MappingTooLong(mapping.len()))?;
        p.static_mapping = facts.pdo1_static;
        pdos.push(p);
    }
    Ok(BootPlan {
        node,
        kind,
        device_type: facts.device_type,
        vendor_id: device.vendor_id,
        pdos,
        supervision,
        parameters: Vec::new(),
        timeouts: BootTimeouts::default(),
    })
}

/// The steps of a boot, as reported.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BootStep {
    /// Reset communication and waiting for the boot-up message.
    BootUp,
    /// Reading 1000h and 1018h:01.
    Identity,
    /// Writing the PDO parameters.
    PdoConfig,
    /// Reading them back.
    PdoReadBack,
    /// Writing and reading back 1017h or 100Ch/100Dh.
    Supervision,
    /// Writing and reading back the drive parameters the axis needs (homing method, profile
    /// velocity and acceleration).
    Parameters,
    /// NMT start.
    Start,
}

impl fmt::Display for BootStep {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            BootStep::BootUp => "boot-up",
            BootStep::Identity => "identity",
            BootStep::PdoConfig => "PDO configuration",
            BootStep::PdoReadBack => "PDO read-back",
            BootStep::Supervision => "supervision",
            BootStep::Parameters => "drive parameters",
            BootStep::Start => "NMT start",
        })
    }
}

/// What went wrong, with the numbers that explain it. No heap data, so a report can cross the
/// queue to the cycle thread and be dropped there without freeing memory.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FailureDetail {
    /// No boot-up message within this many ms of reset communication.
    NoBootUp {
        /// The timeout, ms.
        waited_ms: u64,
    },
    /// The node sent a boot-up in the middle of its boot (it reset itself).
    UnexpectedBootUp,
    /// The node (or the client, for a protocol error) aborted the transfer; the code is in
    /// [`BootFailure::abort`].
    Aborted {
        /// Who aborted.
        by: AbortedBy,
    },
    /// The node did not answer the SDO request in time.
    SdoTimeout {
        /// The timeout, ms.
        timeout_ms: u64,
    },
    /// A value read is not the one expected.
    Mismatch {
        /// Read from the node.
        read: u32,
        /// Expected.
        expected: u32,
    },
    /// The PDO settings cannot work; refused before anything was sent.
    Plan(PlanError),
    /// The SDO client refused the request (an internal limit).
    Request(RequestError),
    /// The node appears twice in the plans; only the first is booted.
    DuplicateNode,
    /// The cycle lost the running node (heartbeat, guarding, TPDOs); it is waited for.
    Lost,
    /// The node kept sending boot-ups in the middle of its boot (it reset again and again, or
    /// answered several resets): it is asked again from the reset.
    BootInterrupted,
    /// An answer named another object than the one asked for (a late answer to a request the
    /// coordinator had given up on): the exchange is void, the node is asked again.
    StrayAnswer,
    /// The node is another device than the one configured (1000h and 1018h:01 as read, and as
    /// expected).
    WrongDevice {
        /// 1000h read.
        device_type: u32,
        /// 1018h:01 read.
        vendor_id: u32,
        /// 1000h expected.
        expected_type: u32,
        /// 1018h:01 expected.
        expected_vendor: u32,
    },
}

impl FailureDetail {
    /// Whether the node is waited for (absent or lost) rather than refused.
    pub fn is_waiting(&self) -> bool {
        // A boot-up in the middle of a boot (the node reset again, or answered two resets) is
        // no refusal: the node is asked again, as an absent one is, rather than left refused
        // until it happens to reset once more.
        matches!(
            self,
            FailureDetail::NoBootUp { .. }
                | FailureDetail::SdoTimeout { .. }
                | FailureDetail::Lost
                | FailureDetail::BootInterrupted
                | FailureDetail::StrayAnswer
        )
    }
}

/// The device kinds an identity (1000h, 1018h:01) belongs to, in words, from the catalog: "a
/// Festo MTR-DCI or EMCA (FHPP)".
pub fn identify(device_type: u32, vendor_id: u32) -> String {
    let mut known = drivers::catalog::identify(device_type, vendor_id).peekable();
    let Some((first, facts)) = known.next() else {
        // The low word of 1000h is the device profile number (CiA 301).
        return if device_type & 0xFFFF == CIA402_DEVICE_TYPE & 0xFFFF {
            "a CiA 402 drive of another vendor or kind".into()
        } else {
            "an unknown device".into()
        };
    };
    let mut names = String::from(first.name);
    while let Some((d, _)) = known.next() {
        names += if known.peek().is_some() { ", " } else { " or " };
        names += d.name;
    }
    format!("a {} {names} ({})", first.vendor, facts.profile.label())
}

impl fmt::Display for FailureDetail {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FailureDetail::NoBootUp { waited_ms } => write!(f, "no boot-up within {waited_ms} ms"),
            FailureDetail::UnexpectedBootUp => f.write_str("the node sent a boot-up (it reset)"),
            FailureDetail::Aborted { by } => write!(
                f,
                "SDO aborted by the {}",
                match by {
                    AbortedBy::Client => "coordinator",
                    AbortedBy::Server => "drive",
                }
            ),
            FailureDetail::SdoTimeout { timeout_ms } => {
                write!(f, "no SDO answer within {timeout_ms} ms")
            }
            FailureDetail::Mismatch { read, expected } => {
                write!(f, "read {read:08X}h, expected {expected:08X}h")
            }
            FailureDetail::Plan(e) => write!(f, "invalid PDO settings: {e}"),
            FailureDetail::Request(e) => write!(f, "{e}"),
            FailureDetail::DuplicateNode => f.write_str("the node is planned twice"),
            FailureDetail::Lost => f.write_str("lost by the cycle; waiting for it to come back"),
            FailureDetail::BootInterrupted => {
                f.write_str("the node kept resetting during the boot; asking it again")
            }
            FailureDetail::StrayAnswer => f.write_str(
                "an answer for another object came (a late answer to an earlier request); asking the node again",
            ),
            FailureDetail::WrongDevice {
                device_type,
                vendor_id,
                expected_type,
                expected_vendor,
            } => write!(
                f,
                "wrong device: found device type {device_type:08X}h, vendor {vendor_id:08X}h ({}), expected device type {expected_type:08X}h, vendor {expected_vendor:08X}h ({})",
                identify(*device_type, *vendor_id),
                identify(*expected_type, *expected_vendor)
            ),
        }
    }
}

/// Why a node did not boot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BootFailure {
    /// The node.
    pub node: NodeId,
    /// The step that failed.
    pub step: BootStep,
    /// The object concerned, if the step was an SDO transfer.
    pub object: Option<Address>,
    /// The SDO abort code, if the transfer was aborted.
    pub abort: Option<AbortCode>,
    /// The rest of the story.
    pub detail: FailureDetail,
}

impl fmt::Display for BootFailure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "node {}: {} failed", self.node, self.step)?;
        if let Some(a) = self.object {
            write!(f, " at {a}")?;
        }
        match (self.abort, self.detail) {
            (Some(code), FailureDetail::Aborted { .. }) => write!(f, ": SDO abort {code}"),
            (Some(code), d) => write!(f, ": {d} (abort {code})"),
            (None, d) => write!(f, ": {d}"),
        }
    }
}

impl std::error::Error for BootFailure {}

impl BootFailure {
    /// Whether the node is asked again (absent, lost, or the exchange itself failed) rather than
    /// refused. An SDO transfer aborted for a protocol error (toggle bit, command specifier,
    /// block size or sequence, CRC, out of memory: 0503 0000h, 0504 0000h..0504 0005h) says
    /// nothing about the drive's configuration: one damaged frame must not leave a drive
    /// refused until it happens to reboot.
    pub fn is_waiting(&self) -> bool {
        let protocol = self
            .abort
            .is_some_and(|c| c.code() == 0x0503_0000 || (c.code() & 0xFFFF_0000) == 0x0504_0000);
        self.detail.is_waiting() || protocol
    }
}

/// The outcome of one node's boot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BootReport {
    /// The node.
    pub node: NodeId,
    /// Booted and started, or why not.
    pub result: Result<(), BootFailure>,
    /// 1000h as read (if the identity step got that far).
    pub device_type: Option<u32>,
    /// 1018h:01 as read.
    pub vendor_id: Option<u32>,
}

impl fmt::Display for BootReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.result {
            Ok(()) => {
                write!(f, "node {}: operational", self.node)?;
                if let (Some(t), Some(v)) = (self.device_type, self.vendor_id) {
                    write!(f, " (device type {t:08X}h, vendor {v:08X}h)")?;
                }
                Ok(())
            }
            Err(e) => write!(f, "{e}"),
        }
    }
}

/// What a read value is checked against.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Expect {
    /// Only recorded (identity unknown).
    Record,
    /// Exactly this value.
    Equal(u32),
    /// `ConfigPlan::verify` of the node's plan with this index.
    Plan(usize),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Op {
    Reset,
    Read {
        step: BootStep,
        addr: Address,
        expect: Expect,
    },
    Write {
        step: BootStep,
        addr: Address,
        value: u32,
        size: u8,
    },
    Start,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum NodeState {
    /// The NMT frame of the current op waits in the output queue.
    NmtQueued,
    /// Reset communication sent; the boot-up is due by the deadline.
    WaitBootUp { deadline: Instant },
    /// An SDO request of the current op is with the client.
    Sdo,
    /// Booted and started (report pushed); a boot-up or [`BootSequencer::lost`] restarts it.
    Running,
    /// Refused (report pushed); only a boot-up of the node tries again.
    Refused,
}

/// SDO client of the sequencer: 2 queued requests (one in use), 16-byte uploads (expedited
/// values only are read).
type Client = SdoClient<2, 16>;

struct NodeBoot {
    plan: BootPlan,
    ops: Vec<Op>,
    config: Vec<ConfigPlan>,
    at: usize,
    state: NodeState,
    sdo: Client,
    device_type: Option<u32>,
    vendor_id: Option<u32>,
    /// The id of the current op's SDO request; completions of any other request (one given
    /// up on) are dropped, so that no answer is ever taken for another op's.
    request: Option<RequestId>,
    /// A boot-up came while an SDO request was with the node: configure it again from the
    /// identity step once that request has completed (or timed out), so the SDO client never
    /// holds a request of an abandoned attempt.
    restart: bool,
    /// Boot-ups during this attempt's SDO exchanges.
    restarts: u8,
    /// The node has had its first report (booted, waiting or refused).
    reported: bool,
    /// Waiting has been reported since the last successful boot: probe quietly.
    waiting: bool,
    /// An identity value differed from the expected one (reported after both are read).
    wrong_identity: bool,
}

/// Boot-ups tolerated during one attempt's SDO exchanges. The node's power-on boot-up can reach
/// the bus after the reset communication command (it was queued first, and NMT wins
/// arbitration), so one extra boot-up is normal; a node that keeps rebooting is reported
/// ([`FailureDetail::BootInterrupted`]) and asked again from the reset.
const MAX_RESTARTS: u8 = 3;

impl NodeBoot {
    fn op(&self) -> Option<Op> {
        self.ops.get(self.at).copied()
    }
}

/// Boots a set of nodes concurrently; see the module documentation for the steps.
pub struct BootSequencer {
    nodes: Vec<NodeBoot>,
    /// NMT frames to send, with the index of the node and the op they belong to.
    nmt: VecDeque<(usize, Op, Frame)>,
    next_sdo: usize,
    reports: Vec<BootReport>,
}

impl fmt::Debug for BootSequencer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("BootSequencer")
            .field("nodes", &self.nodes.len())
            .field("reports", &self.reports)
            .finish()
    }
}

fn le_u32(data: &[u8]) -> u32 {
    let mut b = [0u8; 4];
    for (d, s) in b.iter_mut().zip(data) {
        *d = *s;
    }
    u32::from_le_bytes(b)
}

/// The ops of one node and the PDO plans they refer to, or the failure that stops it at once.
fn build_ops(plan: &BootPlan) -> Result<(Vec<Op>, Vec<ConfigPlan>), BootFailure> {
    let fail = |step, detail| BootFailure {
        node: plan.node,
        step,
        object: None,
        abort: None,
        detail,
    };
    let record_or = |v: Option<u32>| v.map_or(Expect::Record, Expect::Equal);
    let mut ops = vec![
        Op::Reset,
        Op::Read {
            step: BootStep::Identity,
            addr: Address::new(0x1000, 0),
            expect: record_or(plan.device_type),
        },
        Op::Read {
            step: BootStep::Identity,
            addr: Address::new(0x1018, 1),
            expect: record_or(plan.vendor_id),
        },
    ];
    let mut config = Vec::new();
    let mut reads = Vec::new();
    for p in &plan.pdos {
        if p.static_mapping {
            // Only the transmission type may change; the mapping is checked, not written.
            let comm = p.direction.comm_index(p.number);
            let map = p.direction.mapping_index(p.number);
            let tt = Address::new(comm, SUB_TRANSMISSION_TYPE);
            ops.push(Op::Write {
                step: BootStep::PdoConfig,
                addr: tt,
                value: u32::from(p.transmission_type),
                size: 1,
            });
            for (i, &e) in p.mapping.iter().enumerate() {
                reads.push(Op::Read {
                    step: BootStep::PdoReadBack,
                    addr: Address::new(map, i as u8 + 1),
                    expect: Expect::Equal(e),
                });
            }
            reads.push(Op::Read {
                step: BootStep::PdoReadBack,
                addr: Address::new(map, 0),
                expect: Expect::Equal(p.mapping.len() as u32),
            });
            reads.push(Op::Read {
                step: BootStep::PdoReadBack,
                addr: tt,
                expect: Expect::Equal(u32::from(p.transmission_type)),
            });
        } else {
            let cp = ConfigPlan::new(plan.node, &p.settings())
                .map_err(|e| fail(BootStep::PdoConfig, FailureDetail::Plan(e)))?;
            let k = config.len();
            ops.extend(cp.writes().iter().map(|s| Op::Write {
                step: BootStep::PdoConfig,
                addr: s.addr,
                value: s.value,
                size: s.size,
            }));
            reads.extend(cp.reads().iter().map(|s| Op::Read {
                step: BootStep::PdoReadBack,
                addr: s.addr,
                expect: Expect::Plan(k),
            }));
            config.push(cp);
        }
    }
    ops.extend(reads);
    let mut supervise = |addr: Address, value: u32, size: u8| {
        ops.push(Op::Write {
            step: BootStep::Supervision,
            addr,
            value,
            size,
        });
        ops.push(Op::Read {
            step: BootStep::Supervision,
            addr,
            expect: Expect::Equal(value),
        });
    };
    match plan.supervision {
        SupervisionPlan::None => {}
        SupervisionPlan::Heartbeat { producer_ms } => {
            supervise(Address::new(0x1017, 0), u32::from(producer_ms), 2)
        }
        SupervisionPlan::Guarding {
            guard_ms,
            life_factor,
        } => {
            supervise(Address::new(0x100C, 0), u32::from(guard_ms), 2);
            supervise(Address::new(0x100D, 0), u32::from(life_factor), 1);
        }
    }
    for &(addr, value, size) in &plan.parameters {
        ops.push(Op::Write {
            step: BootStep::Parameters,
            addr,
            value,
            size,
        });
        // Read back what a device of this size returns (sign bits beyond `size` dropped).
        let mask = if size >= 4 {
            u32::MAX
        } else {
            (1u32 << (8 * u32::from(size))) - 1
        };
        ops.push(Op::Read {
            step: BootStep::Parameters,
            addr,
            expect: Expect::Equal(value & mask),
        });
    }
    ops.push(Op::Start);
    Ok((ops, config))
}

impl BootSequencer {
    /// Starts booting `plans`: every node's reset communication is queued. A plan that cannot
    /// work (invalid PDO settings, a node planned twice) is reported failed at once, without
    /// bus traffic. Every timeout runs from when its frame is handed out by
    /// [`BootSequencer::poll_transmit`], not from `_now` (the frames may wait in a queue).
    pub fn new(plans: Vec<BootPlan>, _now: Instant) -> BootSequencer {
        let mut s = BootSequencer {
            nodes: Vec::with_capacity(plans.len()),
            nmt: VecDeque::new(),
            next_sdo: 0,
            reports: Vec::new(),
        };
        for plan in plans {
            let duplicate = s.nodes.iter().any(|n| n.plan.node == plan.node);
            let built = if duplicate {
                Err(BootFailure {
                    node: plan.node,
                    step: BootStep::BootUp,
                    object: None,
                    abort: None,
                    detail: FailureDetail::DuplicateNode,
                })
            } else {
                build_ops(&plan)
            };
            let sdo = Client::new(
                plan.node,
                SdoClientConfig {
                    timeout: plan.timeouts.sdo,
                    ..SdoClientConfig::default()
                },
            );
            match built {
                Ok((ops, config)) => {
                    s.nodes.push(NodeBoot {
                        plan,
                        ops,
                        config,
                        at: 0,
                        state: NodeState::NmtQueued,
                        sdo,
                        device_type: None,
                        vendor_id: None,
                        request: None,
                        restart: false,
                        restarts: 0,
                        reported: false,
                        waiting: false,
                        wrong_identity: false,
                    });
                    let i = s.nodes.len() - 1;
                    s.run(i);
                }
                Err(e) => s.reports.push(BootReport {
                    node: plan.node,
                    result: Err(e),
                    device_type: None,
                    vendor_id: None,
                }),
            }
        }
        s
    }

    /// The reports so far, in the order the nodes finished.
    pub fn reports(&self) -> &[BootReport] {
        &self.reports
    }

    /// Every node has its first report: booted, waiting or refused.
    pub fn is_finished(&self) -> bool {
        self.nodes.iter().all(|n| n.reported)
    }

    /// Whether `node` is booted and running.
    pub fn is_running(&self, node: NodeId) -> bool {
        self.nodes
            .iter()
            .any(|n| n.plan.node == node && n.state == NodeState::Running)
    }

    /// The cycle lost `node` (heartbeat, guarding or TPDOs): if it was running, it is reported
    /// ([`FailureDetail::Lost`]) and waited for (asked with reset communication every probe).
    pub fn lost(&mut self, node: NodeId) {
        let Some(i) = self.nodes.iter().position(|n| n.plan.node == node) else {
            return;
        };
        if self.nodes[i].state != NodeState::Running {
            return;
        }
        // Out of Running first: `finish` leaves a running (or refused) node alone, which made
        // this a no-op (the lost drive was neither reported nor probed).
        self.nodes[i].state = NodeState::Sdo;
        self.finish(
            i,
            Err(BootFailure {
                node,
                step: BootStep::BootUp,
                object: None,
                abort: None,
                detail: FailureDetail::Lost,
            }),
        );
    }

    /// Node `i` ends its current attempt with `result`: running, waiting (asked again from the
    /// reset) or refused. Its SDO client is still polled for frames, since a timed-out client
    /// owes the node an abort frame.
    fn finish(&mut self, i: usize, result: Result<(), BootFailure>) {
        let Some(n) = self.nodes.get_mut(i) else {
            return;
        };
        if matches!(n.state, NodeState::Running | NodeState::Refused) {
            return;
        }
        let waiting = result.as_ref().err().is_some_and(BootFailure::is_waiting);
        // A waiting node is reported once, not at every probe.
        let quiet = waiting && n.waiting;
        n.reported = true;
        n.restart = false;
        n.wrong_identity = false;
        match &result {
            Ok(()) => {
                n.state = NodeState::Running;
                n.waiting = false;
                n.restarts = 0;
            }
            Err(_) if waiting => {
                n.waiting = true;
                n.restarts = 0;
                n.at = 0;
            }
            Err(_) => n.state = NodeState::Refused,
        }
        if !quiet {
            self.reports.push(BootReport {
                node: n.plan.node,
                result,
                device_type: n.device_type,
                vendor_id: n.vendor_id,
            });
        }
        if waiting {
            self.run(i);
        }
    }

    /// A node that sent a boot-up (it reset, was replaced or came back): configure it again from
    /// the identity step.
    fn reboot(&mut self, i: usize) {
        let Some(n) = self.nodes.get_mut(i) else {
            return;
        };
        if n.state == NodeState::Running {
            // Reported so that its axis leaves the cycle until it is configured again.
            let failure = BootFailure {
                node: n.plan.node,
                step: BootStep::BootUp,
                object: None,
                abort: None,
                detail: FailureDetail::UnexpectedBootUp,
            };
            self.reports.push(BootReport {
                node: n.plan.node,
                result: Err(failure),
                device_type: n.device_type,
                vendor_id: n.vendor_id,
            });
        }
        n.state = NodeState::Sdo;
        n.restart = false;
        n.restarts = 0;
        n.wrong_identity = false;
        n.at = 1;
        self.run(i);
    }

    fn fail_at(&mut self, i: usize, op: Option<Op>, abort: Option<AbortCode>, d: FailureDetail) {
        let Some(n) = self.nodes.get(i) else {
            return;
        };
        let (step, object) = match op {
            Some(Op::Read { step, addr, .. } | Op::Write { step, addr, .. }) => (step, Some(addr)),
            Some(Op::Start) => (BootStep::Start, None),
            Some(Op::Reset) | None => (BootStep::BootUp, None),
        };
        let failure = BootFailure {
            node: n.plan.node,
            step,
            object,
            abort,
            detail: d,
        };
        self.finish(i, Err(failure));
    }

    /// Issues node `i`'s current op.
    fn run(&mut self, i: usize) {
        let Some(n) = self.nodes.get_mut(i) else {
            return;
        };
        let node = n.plan.node;
        let nmt = |command| {
            NmtRequest {
                command,
                target: NmtTarget::Node(node),
            }
            .to_frame()
        };
        let issued = match n.op() {
            None => {
                // Start is the last op; running past it means done.
                self.finish(i, Ok(()));
                return;
            }
            Some(Op::Reset) => {
                let f = nmt(NmtCommand::ResetCommunication);
                n.state = NodeState::NmtQueued;
                self.nmt.push_back((i, Op::Reset, f));
                Ok(())
            }
            Some(Op::Start) => {
                let f = nmt(NmtCommand::Start);
                n.state = NodeState::NmtQueued;
                self.nmt.push_back((i, Op::Start, f));
                Ok(())
            }
            Some(Op::Read { addr, .. }) => {
                n.state = NodeState::Sdo;
                n.sdo.upload(addr).map(|id| n.request = Some(id))
            }
            Some(Op::Write {
                addr, value, size, ..
            }) => {
                n.state = NodeState::Sdo;
                let b = value.to_le_bytes();
                let len = usize::from(size).clamp(1, 4);
                n.sdo
                    .download(addr, &b[..len], DownloadMode::Expedited)
                    .map(|id| n.request = Some(id))
            }
        };
        if let Err(e) = issued {
            let op = n.op();
            self.fail_at(i, op, None, FailureDetail::Request(e));
        }
    }

    /// Takes node `i`'s SDO completions and moves it on.
    fn drain_sdo(&mut self, i: usize) {
        loop {
            let Some(n) = self.nodes.get_mut(i) else {
                return;
            };
            let (id, outcome) = match n.sdo.poll_event() {
                None => return,
                Some(e) => (
                    e.id,
                    e.outcome.map(|c| match c {
                        Completion::Uploaded(d) => Some(le_u32(d)),
                        Completion::Downloaded => None,
                    }),
                ),
            };
            if n.state != NodeState::Sdo || n.request != Some(id) {
                // The completion of a request no op waits for: nothing to do.
                continue;
            }
            n.request = None;
            let op = n.op();
            if n.restart {
                n.restart = false;
                if n.restarts > MAX_RESTARTS {
                    self.fail_at(i, op, None, FailureDetail::BootInterrupted);
                } else {
                    n.at = 1;
                    self.run(i);
                }
                continue;
            }
            match outcome {
                // The client gave up on an answer naming another object: a late answer to a
                // request of an earlier attempt, no word of the node on this one.
                Err(SdoError::Aborted {
                    code: AbortCode::ParamIncompatible,
                    by: AbortedBy::Client,
                }) => self.fail_at(i, op, None, FailureDetail::StrayAnswer),
                Err(SdoError::Aborted { code, by }) => {
                    self.fail_at(i, op, Some(code), FailureDetail::Aborted { by });
                }
                Err(SdoError::Timeout { timeout_ms }) => {
                    self.fail_at(i, op, None, FailureDetail::SdoTimeout { timeout_ms });
                }
                Ok(value) => {
                    if let (Some(Op::Read { addr, expect, .. }), Some(v)) = (op, value) {
                        if addr == Address::new(0x1000, 0) {
                            n.device_type = Some(v);
                        } else if addr == Address::new(0x1018, 1) {
                            n.vendor_id = Some(v);
                        }
                        let checked = match expect {
                            Expect::Record => Ok(()),
                            Expect::Equal(e) if e == v => Ok(()),
                            Expect::Equal(e) => Err((e, v)),
                            Expect::Plan(k) => match n.config.get(k).map(|p| p.verify(addr, v)) {
                                Some(Err(VerifyError::Mismatch { expected, read, .. })) => {
                                    Err((expected, read))
                                }
                                // The op list only reads what the plan reads back.
                                _ => Ok(()),
                            },
                        };
                        let identity = matches!(
                            op,
                            Some(Op::Read {
                                step: BootStep::Identity,
                                ..
                            })
                        );
                        match checked {
                            // Both identity values are read before a wrong device is named.
                            Err(_) if identity => n.wrong_identity = true,
                            Err((expected, read)) => {
                                self.fail_at(
                                    i,
                                    op,
                                    None,
                                    FailureDetail::Mismatch { read, expected },
                                );
                                continue;
                            }
                            Ok(()) => {}
                        }
                        if identity && addr == Address::new(0x1018, 1) && n.wrong_identity {
                            let detail = FailureDetail::WrongDevice {
                                device_type: n.device_type.unwrap_or(0),
                                vendor_id: n.vendor_id.unwrap_or(0),
                                expected_type: n.plan.device_type.unwrap_or(0),
                                expected_vendor: n.plan.vendor_id.unwrap_or(0),
                            };
                            self.fail_at(i, op, None, detail);
                            continue;
                        }
                    }
                    n.at += 1;
                    self.run(i);
                }
            }
        }
    }

    /// Feeds one received frame (every frame of the bus may be given; others are ignored).
    pub fn handle_frame(&mut self, frame: &Frame, now: Instant) {
        if let Some(node) = decode_boot_up(frame, true) {
            let Some(i) = self.nodes.iter().position(|n| n.plan.node == node) else {
                return;
            };
            match self.nodes.get(i).map(|n| (n.state, n.op())) {
                Some((NodeState::WaitBootUp { .. }, _)) => {
                    if let Some(n) = self.nodes.get_mut(i) {
                        n.at += 1;
                    }
                    self.run(i);
                }
                // Before the reset went out: the power-on boot-up, not ours.
                Some((NodeState::NmtQueued, Some(Op::Reset))) => {}
                // Reset after its configuration, before the start went out: configure again.
                Some((NodeState::NmtQueued, _)) => self.reboot(i),
                Some((NodeState::Running | NodeState::Refused, _)) => self.reboot(i),
                // An SDO request is with the node: it is let complete (or time out) first, so
                // that its answer is never taken for another request's; then the identity.
                Some((NodeState::Sdo, _)) => {
                    if let Some(n) = self.nodes.get_mut(i) {
                        n.restarts = n.restarts.saturating_add(1);
                        n.restart = true;
                    }
                }
                None => {}
            }
            return;
        }
        if let Some(i) = self.nodes.iter().position(|n| n.sdo.accepts(frame)) {
            if let Some(n) = self.nodes.get_mut(i) {
                n.sdo.handle_frame(frame, now);
            }
            self.drain_sdo(i);
        }
    }

    /// The next frame to send at `now`: NMT commands first, then one SDO request per node in
    /// turn.
    pub fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        while let Some((i, op, f)) = self.nmt.pop_front() {
            let Some(n) = self.nodes.get_mut(i) else {
                continue;
            };
            // A frame whose op the node has left (it reset before its start went out, or a
            // second reset was queued) is not sent.
            if n.state != NodeState::NmtQueued || n.op() != Some(op) {
                continue;
            }
            match op {
                Op::Reset => {
                    let wait = if n.waiting {
                        n.plan.timeouts.probe
                    } else {
                        n.plan.timeouts.boot_up
                    };
                    n.state = NodeState::WaitBootUp {
                        deadline: now.saturating_add(wait),
                    };
                }
                Op::Start => {
                    n.at += 1;
                    self.finish(i, Ok(()));
                }
                Op::Read { .. } | Op::Write { .. } => {}
            }
            return Some(f);
        }
        let len = self.nodes.len();
        for k in 0..len {
            let i = (self.next_sdo + k) % len;
            if let Some(f) = self.nodes.get_mut(i).and_then(|n| n.sdo.poll_transmit(now)) {
                self.next_sdo = (i + 1) % len;
                return Some(f);
            }
        }
        None
    }

    /// When [`BootSequencer::handle_timeout`] is next due.
    pub fn poll_timeout(&self) -> Option<Instant> {
        earliest(self.nodes.iter().flat_map(|n| {
            let boot = match n.state {
                NodeState::WaitBootUp { deadline } => Some(deadline),
                _ => None,
            };
            [boot, n.sdo.poll_timeout()]
        }))
    }

    /// Runs the timers due at `now`: boot-up deadlines and SDO timeouts.
    pub fn handle_timeout(&mut self, now: Instant) {
        for i in 0..self.nodes.len() {
            let Some(n) = self.nodes.get_mut(i) else {
                continue;
            };
            if let NodeState::WaitBootUp { deadline } = n.state
                && deadline <= now
            {
                let waited_ms = n.plan.timeouts.boot_up.as_millis() as u64;
                self.fail_at(
                    i,
                    Some(Op::Reset),
                    None,
                    FailureDetail::NoBootUp { waited_ms },
                );
                continue;
            }
            if n.sdo.poll_timeout().is_some_and(|t| t <= now) {
                n.sdo.handle_timeout(now);
                self.drain_sdo(i);
            }
        }
    }
}

impl Endpoint for BootSequencer {
    fn handle_frame(&mut self, frame: &Frame, now: Instant) {
        BootSequencer::handle_frame(self, frame, now)
    }
    fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        BootSequencer::poll_transmit(self, now)
    }
    fn poll_timeout(&self) -> Option<Instant> {
        BootSequencer::poll_timeout(self)
    }
    fn handle_timeout(&mut self, now: Instant) {
        BootSequencer::handle_timeout(self, now)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(n: u8) -> NodeId {
        NodeId::new(n).unwrap()
    }

    #[test]
    fn plan_for_refuses_what_cannot_work() {
        let hb = SupervisionPlan::Heartbeat { producer_ms: 100 };
        assert_eq!(
            plan_for(node(1), DeviceKind::CmmoSt, &[], &[], SupervisionPlan::None),
            Err(BootPlanError::NotCanopen(DeviceKind::CmmoSt))
        );
        assert_eq!(
            plan_for(node(1), DeviceKind::Emca, &[], &[], hb),
            Err(BootPlanError::NoHeartbeat(DeviceKind::Emca))
        );
        assert_eq!(
            plan_for(node(1), DeviceKind::Tlc5xx, &[0x6040_0010; 9], &[], hb),
            Err(BootPlanError::MappingTooLong(9))
        );
        let p = plan_for(
            node(1),
            DeviceKind::MtrDci,
            &[0x6040_0010],
            &[],
            SupervisionPlan::None,
        )
        .unwrap();
        assert_eq!(p.device_type, Some(CIA402_DEVICE_TYPE));
        assert!(p.pdos.iter().all(|p| p.static_mapping));
        assert_eq!(p.pdos.len(), 1);
    }

    #[test]
    fn ops_follow_the_steps_in_order() {
        let p = plan_for(
            node(5),
            DeviceKind::Tlc5xx,
            &[0x6040_0010, 0x607A_0020],
            &[0x6041_0010],
            SupervisionPlan::Heartbeat { producer_ms: 100 },
        )
        .unwrap();
        let (ops, config) = build_ops(&p).unwrap();
        assert_eq!(config.len(), 2);
        assert_eq!(ops.first(), Some(&Op::Reset));
        assert_eq!(ops.last(), Some(&Op::Start));
        let steps: Vec<BootStep> = ops
            .iter()
            .filter_map(|o| match o {
                Op::Read { step, .. } | Op::Write { step, .. } => Some(*step),
                _ => None,
            })
            .collect();
        let mut sorted = steps.clone();
        sorted.dedup();
        assert_eq!(
            sorted,
            [
                BootStep::Identity,
                BootStep::PdoConfig,
                BootStep::PdoReadBack,
                BootStep::Supervision
            ]
        );
        let writes = config.iter().map(|c| c.writes().len()).sum::<usize>();
        assert_eq!(
            steps.iter().filter(|s| **s == BootStep::PdoConfig).count(),
            writes
        );
    }

    #[test]
    fn failure_reads_like_a_sentence() {
        let f = BootFailure {
            node: node(3),
            step: BootStep::PdoReadBack,
            object: Some(Address::new(0x1A00, 1)),
            abort: None,
            detail: FailureDetail::Mismatch {
                read: 0x6041_0010,
                expected: 0x3020_0008,
            },
        };
        assert_eq!(
            f.to_string(),
            "node 3: PDO read-back failed at 1A00h:01h: read 60410010h, expected 30200008h"
        );
        let g = BootFailure {
            step: BootStep::PdoConfig,
            object: Some(Address::new(0x1600, 0)),
            abort: Some(AbortCode::ReadOnly),
            detail: FailureDetail::Aborted {
                by: AbortedBy::Server,
            },
            ..f
        };
        assert_eq!(
            g.to_string(),
            "node 3: PDO configuration failed at 1600h:00h: SDO abort 0601 0002h (Attempt to write a read only object)"
        );
        let h = BootFailure {
            step: BootStep::BootUp,
            object: None,
            detail: FailureDetail::NoBootUp { waited_ms: 5000 },
            ..f
        };
        assert_eq!(
            h.to_string(),
            "node 3: boot-up failed: no boot-up within 5000 ms"
        );
    }

    #[test]
    fn duplicate_and_invalid_plans_fail_without_traffic() {
        let mut p = plan_for(node(2), DeviceKind::Tlc5xx, &[], &[], SupervisionPlan::None).unwrap();
        let mut bad = p.clone();
        bad.node = node(4);
        bad.pdos.push(PdoPlan {
            transmission_type: 241,
            ..PdoPlan::sync(PdoDirection::Rpdo, 1, &[0x6040_0010]).unwrap()
        });
        p.timeouts.boot_up = Duration::from_millis(10);
        let mut s = BootSequencer::new(vec![p.clone(), p, bad], Instant::ZERO);
        let r = s.reports().to_vec();
        assert_eq!(r.len(), 2);
        assert_eq!(
            r[0].result.unwrap_err().detail,
            FailureDetail::DuplicateNode
        );
        assert!(matches!(
            r[1].result.unwrap_err().detail,
            FailureDetail::Plan(PlanError::Comm(_))
        ));
        // Only node 2's reset goes out; with no answer it fails at boot-up.
        let f = s.poll_transmit(Instant::ZERO).unwrap();
        assert_eq!((f.cob_id(), f.data()), (Some(0), &[0x82, 2][..]));
        assert_eq!(s.poll_transmit(Instant::ZERO), None);
        assert!(!s.is_finished());
        let t = s.poll_timeout().unwrap();
        assert_eq!(t, Instant::from_millis(10));
        s.handle_timeout(t);
        assert!(s.is_finished());
        assert_eq!(
            s.reports()[2].result.unwrap_err().detail,
            FailureDetail::NoBootUp { waited_ms: 10 }
        );
    }

    /// An SDO upload request frame of `node` for `addr`.
    fn is_upload(f: &Frame, node: u8, addr: Address) -> bool {
        let a = addr.to_sdo_bytes();
        f.cob_id() == Some(0x600 + u16::from(node)) && f.data()[0] == 0x40 && f.data()[1..4] == a
    }

    fn expedited_answer(node: u8, addr: Address, v: u32) -> Frame {
        let a = addr.to_sdo_bytes();
        let b = v.to_le_bytes();
        Frame::std8(
            0x580 + u16::from(node),
            [0x43, a[0], a[1], a[2], b[0], b[1], b[2], b[3]],
        )
    }

    #[test]
    fn a_second_boot_up_during_identity_restarts_it_after_the_answer() {
        let p = plan_for(node(2), DeviceKind::Tlc5xx, &[], &[], SupervisionPlan::None).unwrap();
        let t = Instant::from_millis(1);
        let mut s = BootSequencer::new(vec![p], t);
        let reset = s.poll_transmit(t).unwrap();
        assert_eq!(reset.data(), &[0x82, 2]);
        // Legacy boot-up (80h + n, no data), as the TLC5xx sends it.
        let boot = Frame::new_std(0x82, &[]).unwrap();
        s.handle_frame(&boot, t);
        let dt = Address::new(0x1000, 0);
        assert!(is_upload(&s.poll_transmit(t).unwrap(), 2, dt));
        // The reset's boot-up arrives after the power-on one: the identity starts over once
        // the request in flight is answered, with 1000h again rather than 1018h:01.
        s.handle_frame(&boot, t);
        s.handle_frame(&expedited_answer(2, dt, CIA402_DEVICE_TYPE), t);
        assert!(is_upload(&s.poll_transmit(t).unwrap(), 2, dt));
        s.handle_frame(&expedited_answer(2, dt, CIA402_DEVICE_TYPE), t);
        let vendor = Address::new(0x1018, 1);
        assert!(is_upload(&s.poll_transmit(t).unwrap(), 2, vendor));
        s.handle_frame(&expedited_answer(2, vendor, TLC5XX_VENDOR_ID), t);
        let start = s.poll_transmit(t).unwrap();
        assert_eq!(start.data(), &[0x01, 2]);
        assert!(s.is_finished());
        let r = s.reports()[0];
        assert_eq!(r.result, Ok(()));
        assert_eq!(r.device_type, Some(CIA402_DEVICE_TYPE));
        // A boot-up during the configuration: the write in flight is let complete, then the
        // node is configured again from the identity (no report: nothing is lost yet).
        let p = plan_for(
            node(2),
            DeviceKind::Tlc5xx,
            &[0x6040_0010],
            &[],
            SupervisionPlan::None,
        )
        .unwrap();
        let mut s = BootSequencer::new(vec![p], t);
        s.poll_transmit(t);
        s.handle_frame(&boot, t);
        s.poll_transmit(t);
        s.handle_frame(&expedited_answer(2, dt, CIA402_DEVICE_TYPE), t);
        s.poll_transmit(t);
        s.handle_frame(&expedited_answer(2, vendor, TLC5XX_VENDOR_ID), t);
        // The first write (1400h:01 with bit 31) is out.
        let write = s.poll_transmit(t).unwrap();
        assert_eq!(write.data()[0], 0x23);
        s.handle_frame(&boot, t);
        assert!(s.poll_transmit(t).is_none(), "nothing before the answer");
        let ack = Frame::new_std(
            0x582,
            &[
                0x60,
                write.data()[1],
                write.data()[2],
                write.data()[3],
                0,
                0,
                0,
                0,
            ],
        )
        .unwrap();
        s.handle_frame(&ack, t);
        assert!(is_upload(&s.poll_transmit(t).unwrap(), 2, dt));
        assert!(s.reports().is_empty());
    }

    /// Boots node 2 (TLC5xx, no PDOs) up to its identity read of 1000h in flight.
    fn at_identity(t: Instant) -> BootSequencer {
        let p = plan_for(node(2), DeviceKind::Tlc5xx, &[], &[], SupervisionPlan::None).unwrap();
        let mut s = BootSequencer::new(vec![p], t);
        s.poll_transmit(t).unwrap();
        s.handle_frame(&Frame::new_std(0x702, &[0]).unwrap(), t);
        assert!(is_upload(
            &s.poll_transmit(t).unwrap(),
            2,
            Address::new(0x1000, 0)
        ));
        s
    }

    /// An SDO abort frame from node 2 for `a` with `code`.
    fn abort_frame(a: Address, code: u32) -> Frame {
        let c = code.to_le_bytes();
        Frame::new_std(
            0x582,
            &[
                0x80,
                a.index as u8,
                (a.index >> 8) as u8,
                a.sub,
                c[0],
                c[1],
                c[2],
                c[3],
            ],
        )
        .unwrap()
    }

    #[test]
    fn a_damaged_exchange_is_asked_again_and_a_refusal_is_kept() {
        // Seen in a fault campaign: a damaged SDO frame made the drive abort with "command
        // specifier not valid", and the node stayed refused until it rebooted, which a
        // running drive never does. A protocol abort says nothing about the drive: ask again.
        let t = Instant::from_millis(1);
        let dt = Address::new(0x1000, 0);
        let mut s = at_identity(t);
        s.handle_frame(&abort_frame(dt, 0x0504_0001), t);
        let f = s.reports()[0].result.unwrap_err();
        assert_eq!(f.abort.map(|c| c.code()), Some(0x0504_0001));
        assert!(f.is_waiting(), "{f}");
        let mut reset = false;
        while let Some(f) = s.poll_transmit(t) {
            reset |= f.data() == [0x82, 2];
        }
        assert!(reset, "the node is asked again");
        // The toggle bit too; but a value the drive refuses is the drive's answer: refused.
        let mut s = at_identity(t);
        s.handle_frame(&abort_frame(dt, 0x0503_0000), t);
        assert!(s.reports()[0].result.unwrap_err().is_waiting());
        let mut s = at_identity(t);
        s.handle_frame(&abort_frame(dt, 0x0609_0030), t);
        let f = s.reports()[0].result.unwrap_err();
        assert!(!f.is_waiting(), "{f}");
        assert!(s.poll_transmit(t).is_none_or(|f| f.data() != [0x82, 2]));
    }

    #[test]
    fn a_node_that_keeps_resetting_is_asked_again_and_no_answer_is_taken_for_another() {
        // Seen with drives of a loaded host: boot-ups one after another during the identity.
        // The old sequencer gave up on the read in flight, asked 1000h again and took the late
        // answer of the first read for 1018h:01: "wrong device, vendor 00020192h".
        let t = Instant::from_millis(1);
        let dt = Address::new(0x1000, 0);
        let vendor = Address::new(0x1018, 1);
        let boot = Frame::new_std(0x702, &[0]).unwrap();
        let mut s = at_identity(t);
        for _ in 0..=MAX_RESTARTS {
            s.handle_frame(&boot, t);
        }
        s.handle_frame(&expedited_answer(2, dt, CIA402_DEVICE_TYPE), t);
        let f = s.reports()[0].result.unwrap_err();
        assert_eq!(f.detail, FailureDetail::BootInterrupted);
        assert!(f.detail.is_waiting());
        // Asked again from the reset; the new attempt reads 1000h, then 1018h:01.
        assert_eq!(s.poll_transmit(t).unwrap().data(), &[0x82, 2]);
        s.handle_frame(&boot, t);
        assert!(is_upload(&s.poll_transmit(t).unwrap(), 2, dt));
        s.handle_frame(&expedited_answer(2, dt, CIA402_DEVICE_TYPE), t);
        assert!(is_upload(&s.poll_transmit(t).unwrap(), 2, vendor));
        s.handle_frame(&expedited_answer(2, vendor, TLC5XX_VENDOR_ID), t);
        assert_eq!(s.poll_transmit(t).unwrap().data(), &[0x01, 2]);
        assert!(s.is_running(node(2)));

        // A late answer for 1000h while 1018h:01 is asked is not the vendor: the exchange is
        // void and the node is asked again (waiting), not refused as a wrong device.
        let mut s = at_identity(t);
        s.handle_frame(&expedited_answer(2, dt, CIA402_DEVICE_TYPE), t);
        assert!(is_upload(&s.poll_transmit(t).unwrap(), 2, vendor));
        s.handle_frame(&expedited_answer(2, dt, CIA402_DEVICE_TYPE), t);
        let f = s.reports()[0].result.unwrap_err();
        assert_eq!(f.detail, FailureDetail::StrayAnswer, "{f}");
        assert!(f.detail.is_waiting());
        let mut reset = false;
        while let Some(f) = s.poll_transmit(t) {
            reset |= f.data() == [0x82, 2];
        }
        assert!(reset, "the node is asked again");
        s.handle_frame(&boot, t);
        assert!(is_upload(&s.poll_transmit(t).unwrap(), 2, dt));
        s.handle_frame(&expedited_answer(2, dt, CIA402_DEVICE_TYPE), t);
        s.poll_transmit(t).unwrap();
        s.handle_frame(&expedited_answer(2, vendor, TLC5XX_VENDOR_ID), t);
        assert_eq!(s.poll_transmit(t).unwrap().data(), &[0x01, 2]);
        assert!(s.is_running(node(2)));
    }

    #[test]
    fn a_boot_up_before_the_start_went_out_configures_again_without_starting() {
        let t = Instant::from_millis(1);
        let dt = Address::new(0x1000, 0);
        let vendor = Address::new(0x1018, 1);
        let mut s = at_identity(t);
        s.handle_frame(&expedited_answer(2, dt, CIA402_DEVICE_TYPE), t);
        s.poll_transmit(t).unwrap();
        s.handle_frame(&expedited_answer(2, vendor, TLC5XX_VENDOR_ID), t);
        // The start is queued, not yet handed out; the node resets meanwhile.
        s.handle_frame(&Frame::new_std(0x702, &[0]).unwrap(), t);
        let next = s.poll_transmit(t).unwrap();
        assert!(
            is_upload(&next, 2, dt),
            "identity again, not a start: {next:?}"
        );
        assert!(!s.is_running(node(2)));
    }
}
