//! A complete CANopen device (CiA 301 slave): NMT, SDO server, 4 + 4 PDOs, SYNC consumer, EMCY
//! producer, heartbeat producer and node/life guarding over one [`ObjectDictionary`].
//!
//! The device simulators are this plus an application (the drive profile and the axis model):
//! the application reads what RPDOs and SDO writes put into the dictionary, writes its actual
//! values back, and raises EMCYs. Writes a manual refuses with its own code go through
//! [`DeviceHooks::check_write`].
//!
//! The communication objects (1000h..1A03h) are inserted by [`insert_communication_objects`]
//! from a [`CommProfile`], so each device states only how it differs from CiA 301 defaults.

use super::emcy::{EmcyCobId, EmcyProducer};
use super::endpoint::Endpoint;
use super::guarding::{GuardingSlave, LifeGuardingEvent};
use super::heartbeat::HeartbeatProducer;
use super::nmt::{BootUpStyle, NmtSlave, NmtSlaveEvent, NmtState, ResetKind, Service};
use super::od::{AccessType, DataType, EntryDef, ObjectAccess, ObjectDictionary, OdError, Value};
use super::pdo::mapping::MAX_ENTRIES;
use super::pdo::{
    CommParams, Mapping, PdoError, Positions, Rpdo, RpdoEvent, Tpdo, TransmissionType,
};
use super::sdo::{SdoServer, SdoServerConfig, ServerEvent};
use super::sync::{SyncCobId, SyncConsumer, SyncEvent};
use super::{AbortCode, Address, FunctionCode, NodeId};
use crate::can::Frame;
use crate::time::Instant;

/// Depth of the pre-defined error field (1003h) the device keeps.
pub const EMCY_HISTORY: usize = 8;

/// The default of one PDO of a device: what the manual's object list says at power-up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PdoDefault {
    /// Whether the PDO is valid (COB-ID bit 31 clear) at power-up.
    pub valid: bool,
    /// Transmission type (sub02).
    pub transmission: u8,
    /// Event timer in ms (sub05).
    pub event_ms: u16,
    /// Mapping entries `index << 16 | sub << 8 | bits`.
    pub mapping: &'static [u32],
    /// A static PDO: mapping and transmission type are read-only.
    pub fixed: bool,
}

impl PdoDefault {
    /// A PDO that does not exist on the device (no objects are inserted for it).
    pub const ABSENT: PdoDefault = PdoDefault {
        valid: false,
        transmission: 0,
        event_ms: 0,
        mapping: &[],
        fixed: false,
    };
}

/// How a device's communication objects look at power-up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommProfile {
    /// 1000h device type.
    pub device_type: u32,
    /// 1018h sub01..04: vendor-ID, product code, revision, serial number.
    pub identity: [u32; 4],
    /// Whether the device has a heartbeat producer (1017h). The MTR-DCI has none.
    pub heartbeat: bool,
    /// 1017h default, ms.
    pub heartbeat_ms: u16,
    /// Whether the device supports node guarding (100Ch, 100Dh).
    pub guarding: bool,
    /// The boot-up message form.
    pub boot_up: BootUpStyle,
    /// RPDO 1..4 ([`PdoDefault::ABSENT`] where the device has fewer).
    pub rpdo: [PdoDefault; 4],
    /// TPDO 1..4.
    pub tpdo: [PdoDefault; 4],
    /// Whether TPDO parameters have sub06 (SYNC start value; CiA 301 v4.1 and later).
    pub tpdo_sync_start: bool,
}

impl CommProfile {
    /// A plain CiA 301 device with no PDOs, heartbeat and guarding available, both off.
    pub const fn basic(device_type: u32) -> CommProfile {
        CommProfile {
            device_type,
            identity: [0, 0, 0, 0],
            heartbeat: true,
            heartbeat_ms: 0,
            guarding: true,
            boot_up: BootUpStyle::Ds301,
            rpdo: [PdoDefault::ABSENT; 4],
            tpdo: [PdoDefault::ABSENT; 4],
            tpdo_sync_start: true,
        }
    }
}

const fn u32_entry(
    addr: Address,
    name: &'static str,
    access: AccessType,
    v: u32,
) -> EntryDef<'static> {
    EntryDef::new(addr, name, DataType::Unsigned32, access).default_value(Value::Unsigned(v as u64))
}
const fn u16_entry(
    addr: Address,
    name: &'static str,
    access: AccessType,
    v: u16,
) -> EntryDef<'static> {
    EntryDef::new(addr, name, DataType::Unsigned16, access).default_value(Value::Unsigned(v as u64))
}
const fn u8_entry(
    addr: Address,
    name: &'static str,
    access: AccessType,
    v: u8,
) -> EntryDef<'static> {
    EntryDef::new(addr, name, DataType::Unsigned8, access).default_value(Value::Unsigned(v as u64))
}

const MAP_NAMES: [&str; 8] = [
    "mapped object 1",
    "mapped object 2",
    "mapped object 3",
    "mapped object 4",
    "mapped object 5",
    "mapped object 6",
    "mapped object 7",
    "mapped object 8",
];
const ERR_NAMES: [&str; EMCY_HISTORY] = [
    "standard error field 1",
    "standard error field 2",
    "standard error field 3",
    "standard error field 4",
    "standard error field 5",
    "standard error field 6",
    "standard error field 7",
    "standard error field 8",
];

/// The CiA 301 identity strings, visible strings and read only: 1008h manufacturer device
/// name, 1009h hardware version, 100Ah software version, each as long as its text.
pub const fn identity_strings(
    name: &'static [u8],
    hardware: &'static [u8],
    software: &'static [u8],
) -> [EntryDef<'static>; 3] {
    const fn text(index: u16, what: &'static str, v: &'static [u8]) -> EntryDef<'static> {
        EntryDef::new(
            Address::new(index, 0),
            what,
            DataType::VisibleString,
            AccessType::Ro,
        )
        .capacity(v.len())
        .default_value(Value::Bytes(v))
    }
    [
        text(0x1008, "manufacturer device name", name),
        text(0x1009, "manufacturer hardware version", hardware),
        text(0x100A, "manufacturer software version", software),
    ]
}

/// Inserts the CiA 301 communication objects of `profile` for `node` into `od`.
pub fn insert_communication_objects<const N: usize, const B: usize>(
    od: &mut ObjectDictionary<'static, N, B>,
    node: NodeId,
    profile: &CommProfile,
) -> Result<(), OdError> {
    use AccessType::{Ro, Rw};
    let a = Address::new;
    od.insert(u32_entry(
        a(0x1000, 0),
        "device type",
        Ro,
        profile.device_type,
    ))?;
    od.insert(u8_entry(a(0x1001, 0), "error register", Ro, 0).mappable())?;
    od.insert(u8_entry(a(0x1003, 0), "number of errors", Rw, 0))?;
    for (i, name) in ERR_NAMES.iter().enumerate() {
        od.insert(u32_entry(a(0x1003, i as u8 + 1), name, Ro, 0))?;
    }
    od.insert(u32_entry(a(0x1005, 0), "COB-ID SYNC", Rw, 0x80))?;
    od.insert(u32_entry(a(0x1006, 0), "communication cycle period", Rw, 0))?;
    od.insert(u32_entry(a(0x1007, 0), "synchronous window length", Rw, 0))?;
    if profile.guarding {
        od.insert(u16_entry(a(0x100C, 0), "guard time", Rw, 0))?;
        od.insert(u8_entry(a(0x100D, 0), "life time factor", Rw, 0))?;
    }
    od.insert(u32_entry(
        a(0x1014, 0),
        "COB-ID EMCY",
        Rw,
        0x80 + node.get() as u32,
    ))?;
    od.insert(u16_entry(a(0x1015, 0), "inhibit time EMCY", Rw, 0))?;
    if profile.heartbeat {
        od.insert(u16_entry(
            a(0x1017, 0),
            "producer heartbeat time",
            Rw,
            profile.heartbeat_ms,
        ))?;
    }
    od.insert(u8_entry(a(0x1018, 0), "identity object", Ro, 4))?;
    let id_names = [
        "vendor-ID",
        "product code",
        "revision number",
        "serial number",
    ];
    for (i, (v, name)) in profile.identity.iter().zip(id_names).enumerate() {
        od.insert(u32_entry(a(0x1018, i as u8 + 1), name, Ro, *v))?;
    }
    for k in 0..4u16 {
        let (rx, tx) = (&profile.rpdo[k as usize], &profile.tpdo[k as usize]);
        if !rx.mapping.is_empty() {
            let cob = FunctionCode::Rpdo(k as u8 + 1).cob_id(node) as u32;
            insert_pdo(od, 0x1400 + k, 0x1600 + k, cob, rx, false, false)?;
        }
        if !tx.mapping.is_empty() {
            let cob = FunctionCode::Tpdo(k as u8 + 1).cob_id(node) as u32;
            insert_pdo(
                od,
                0x1800 + k,
                0x1A00 + k,
                cob,
                tx,
                true,
                profile.tpdo_sync_start,
            )?;
        }
    }
    Ok(())
}

fn insert_pdo<const N: usize, const B: usize>(
    od: &mut ObjectDictionary<'static, N, B>,
    comm: u16,
    map: u16,
    cob: u32,
    d: &PdoDefault,
    transmit: bool,
    sync_start: bool,
) -> Result<(), OdError> {
    use AccessType::{Ro, Rw};
    let a = Address::new;
    let fixed = if d.fixed { Ro } else { Rw };
    let cob = if d.valid { cob } else { cob | 0x8000_0000 };
    let highest = if transmit && sync_start { 6 } else { 5 };
    od.insert(u8_entry(
        a(comm, 0),
        "highest sub-index supported",
        Ro,
        highest,
    ))?;
    od.insert(u32_entry(a(comm, 1), "COB-ID used by PDO", Rw, cob))?;
    od.insert(u8_entry(
        a(comm, 2),
        "transmission type",
        fixed,
        d.transmission,
    ))?;
    // Sub 03h is meaningless for an RPDO but CiA 301 lists it; sub 04h is reserved and absent,
    // so any access to it is refused with 0609 0011h.
    od.insert(u16_entry(a(comm, 3), "inhibit time", fixed, 0))?;
    od.insert(u16_entry(a(comm, 5), "event timer", Rw, d.event_ms))?;
    if transmit && sync_start {
        od.insert(u8_entry(a(comm, 6), "SYNC start value", Rw, 0))?;
    }
    let n = d.mapping.len().min(8);
    od.insert(u8_entry(
        a(map, 0),
        "number of mapped objects",
        fixed,
        n as u8,
    ))?;
    for (i, name) in MAP_NAMES.iter().enumerate() {
        let v = d.mapping.get(i).copied().unwrap_or(0);
        od.insert(u32_entry(a(map, i as u8 + 1), name, fixed, v))?;
    }
    Ok(())
}

/// What a device application may add to the dictionary's own checks of an SDO write.
pub trait DeviceHooks {
    /// Called for every SDO write after the dictionary's type, length, access and limit checks
    /// and after the PDO rules, before the value is stored: refuse with the manual's own code.
    fn check_write(
        &mut self,
        def: &EntryDef<'_>,
        data: &[u8],
        state: NmtState,
    ) -> Result<(), AbortCode> {
        let _ = (def, data, state);
        Ok(())
    }

    /// The size of an object the application serves itself (one the dictionary does not hold,
    /// such as the Festo parameters at 2000h + PNU); `None` = no such object here either.
    fn app_size(&self, addr: Address) -> Option<Result<usize, AbortCode>> {
        let _ = addr;
        None
    }
    /// Reads an application-served object (see [`DeviceHooks::app_size`]) from byte `offset`.
    fn app_read(
        &mut self,
        addr: Address,
        offset: usize,
        buf: &mut [u8],
    ) -> Option<Result<usize, AbortCode>> {
        let _ = (addr, offset, buf);
        None
    }
    /// Writes an application-served object (see [`DeviceHooks::app_size`]).
    fn app_write(
        &mut self,
        addr: Address,
        data: &[u8],
        state: NmtState,
    ) -> Option<Result<(), AbortCode>> {
        let _ = (addr, data, state);
        None
    }
}

/// Hooks that accept every write the dictionary accepts.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoHooks;
impl DeviceHooks for NoHooks {}

/// What happened at the device, for its application.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceEvent {
    /// The NMT state changed.
    StateChanged {
        /// Before.
        old: NmtState,
        /// After.
        new: NmtState,
    },
    /// A reset was commanded and carried out (the dictionary's areas reloaded, boot-up sent).
    Reset(ResetKind),
    /// A SYNC arrived (after synchronous TPDOs were sampled and RPDOs applied).
    Sync {
        /// Its counter byte, if any.
        counter: Option<u8>,
    },
    /// RPDO `pdo` (1..=4) was applied: its mapped objects hold the received values.
    RpdoApplied {
        /// The PDO number.
        pdo: u8,
    },
    /// RPDO `pdo` received a frame it could not unpack (the device goes on).
    RpdoError {
        /// The PDO number.
        pdo: u8,
        /// Why.
        error: PdoError,
    },
    /// An SDO download wrote an object.
    SdoWritten {
        /// The object.
        addr: Address,
    },
    /// An SDO transfer ended with an abort.
    SdoAborted {
        /// The object.
        addr: Address,
        /// The code.
        code: AbortCode,
    },
    /// Life guarding: the master stopped polling (raise EMCY 8130h, as CiA 301 suggests).
    LifeGuardingLost,
    /// Life guarding: polls came back.
    LifeGuardingResumed,
    /// The event queue overflowed; this many events were lost.
    Overflow(u32),
}

const EVENTS: usize = 32;
const TX: usize = 48;

/// A CANopen device over its dictionary. `SDO` bounds one SDO download.
pub struct Device<'a, const N: usize, const B: usize, const SDO: usize, H: DeviceHooks = NoHooks> {
    node: NodeId,
    od: ObjectDictionary<'a, N, B>,
    hooks: H,
    nmt: NmtSlave,
    sdo: SdoServer<SDO>,
    heartbeat: HeartbeatProducer,
    guarding: GuardingSlave,
    emcy: EmcyProducer<EMCY_HISTORY>,
    sync: Option<SyncConsumer>,
    tpdo: [Option<Tpdo>; 4],
    rpdo: [Option<Rpdo<2>>; 4],
    tx: heapless::Deque<Frame, TX>,
    events: heapless::Deque<DeviceEvent, EVENTS>,
    lost_events: u32,
    config_errors: u32,
    /// The dictionary generation the TPDOs were last packed from.
    packed: Option<u32>,
    /// Where each TPDO's and RPDO's mapped objects are in the dictionary (tried first).
    tpdo_at: [Positions; 4],
    rpdo_at: [Positions; 4],
    /// Some TPDO is valid and event-driven (254/255): only then does a poll read the
    /// dictionary's data of now or a TPDO have a deadline. Kept by [`Device::load_pdo`], the
    /// only place a TPDO's parameters change.
    event_tpdos: bool,
}

impl<'a, const N: usize, const B: usize, const SDO: usize, H: DeviceHooks>
    Device<'a, N, B, SDO, H>
{
    /// A device at power-on (Initialising) over `od`, which must hold the communication
    /// objects ([`insert_communication_objects`]). Call [`Device::power_on`] to boot it.
    pub fn new(
        node: NodeId,
        od: ObjectDictionary<'a, N, B>,
        boot_up: BootUpStyle,
        hooks: H,
    ) -> Self {
        let mut d = Device {
            node,
            od,
            hooks,
            nmt: NmtSlave::new(node, boot_up),
            sdo: SdoServer::new(node, SdoServerConfig::default()),
            heartbeat: HeartbeatProducer::new(node, 0),
            guarding: GuardingSlave::new(node, 0, 0),
            emcy: EmcyProducer::new(EmcyCobId::for_node(node), 0),
            sync: None,
            tpdo: [None, None, None, None],
            rpdo: [None, None, None, None],
            tx: heapless::Deque::new(),
            events: heapless::Deque::new(),
            lost_events: 0,
            config_errors: 0,
            packed: None,
            tpdo_at: [[u16::MAX; MAX_ENTRIES]; 4],
            rpdo_at: [[u16::MAX; MAX_ENTRIES]; 4],
            event_tpdos: false,
        };
        d.load_communication(Instant::ZERO);
        d
    }

    /// The node-ID.
    pub fn node(&self) -> NodeId {
        self.node
    }
    /// The NMT state.
    pub fn state(&self) -> NmtState {
        self.nmt.state()
    }
    /// The dictionary.
    pub fn od(&self) -> &ObjectDictionary<'a, N, B> {
        &self.od
    }
    /// The dictionary, for the application's own values (actual position, statusword...).
    pub fn od_mut(&mut self) -> &mut ObjectDictionary<'a, N, B> {
        &mut self.od
    }
    /// The mapping RPDO `pdo` (1..=4) applies, as its engine was built from 1600h.. (what an
    /// [`DeviceEvent::RpdoApplied`] wrote, without reading the mapping objects again).
    pub fn rpdo_mapping(&self, pdo: u8) -> Option<&Mapping> {
        let k = usize::from(pdo.checked_sub(1)?);
        self.rpdo.get(k)?.as_ref().map(|r| r.mapping())
    }
    /// The application hooks, read-only (a device's deadline may depend on its application).
    pub fn hooks(&self) -> &H {
        &self.hooks
    }
    /// The application hooks.
    pub fn hooks_mut(&mut self) -> &mut H {
        &mut self.hooks
    }
    /// How many times a communication object held a value the engines could not use (for
    /// example a mapping naming a missing object); that PDO is then off.
    pub fn config_errors(&self) -> u32 {
        self.config_errors
    }

    /// Ends initialisation: Pre-operational, boot-up message queued.
    pub fn power_on(&mut self, now: Instant) {
        self.load_communication(now);
        self.nmt.boot();
    }

    /// Raises an EMCY with `code` and manufacturer bytes; updates 1001h and 1003h.
    pub fn raise_emcy(&mut self, code: u16, manufacturer: [u8; 5]) {
        if self.emcy.raise(code, manufacturer).is_ok() {
            self.mirror_errors();
        }
    }
    /// Raises an EMCY whose 1001h bits are the manual's (`register`) rather than those of the
    /// code's CiA 301 class.
    pub fn raise_emcy_with_register(&mut self, code: u16, register: u8, manufacturer: [u8; 5]) {
        if self
            .emcy
            .raise_with_register(code, register, manufacturer)
            .is_ok()
        {
            self.mirror_errors();
        }
    }
    /// Sends the EMCY of an active error again (and logs it in 1003h); raises it if inactive.
    pub fn repeat_emcy(&mut self, code: u16, manufacturer: [u8; 5]) {
        if self.emcy.repeat(code, manufacturer).is_ok() {
            self.mirror_errors();
        }
    }
    /// Clears an active EMCY code (the error-reset EMCY goes out when the last one clears).
    pub fn clear_emcy(&mut self, code: u16) {
        if self.emcy.clear(code).is_ok() {
            self.mirror_errors();
        }
    }

    /// The next event for the application.
    pub fn poll_event(&mut self) -> Option<DeviceEvent> {
        if self.lost_events > 0 {
            let n = core::mem::take(&mut self.lost_events);
            return Some(DeviceEvent::Overflow(n));
        }
        self.events.pop_front()
    }

    fn push_event(&mut self, e: DeviceEvent) {
        if self.events.push_back(e).is_err() {
            self.lost_events = self.lost_events.saturating_add(1);
        }
    }

    fn push_tx(&mut self, f: Frame) {
        // Full: the oldest frame is the least useful (a newer PDO or reply supersedes it).
        if self.tx.is_full() {
            self.tx.pop_front();
        }
        let _ = self.tx.push_back(f);
    }

    fn mirror_errors(&mut self) {
        let _ = self
            .od
            .set_u8(Address::new(0x1001, 0), self.emcy.register().0);
        let n = self.emcy.history_len();
        let _ = self.od.set_u8(Address::new(0x1003, 0), n);
        for sub in 1..=EMCY_HISTORY as u8 {
            let v = self.emcy.history_entry(sub).unwrap_or(0);
            let _ = self.od.set_u32(Address::new(0x1003, sub), v);
        }
    }

    /// Reads every communication object into the engines.
    fn load_communication(&mut self, now: Instant) {
        let get16 =
            |od: &ObjectDictionary<'a, N, B>, i| od.get_u16(Address::new(i, 0)).unwrap_or(0);
        let hb = get16(&self.od, 0x1017);
        self.heartbeat = HeartbeatProducer::new(self.node, hb);
        let guard = get16(&self.od, 0x100C);
        let factor = self.od.get_u8(Address::new(0x100D, 0)).unwrap_or(0);
        self.guarding = GuardingSlave::new(self.node, guard, factor);
        self.load_sync();
        self.load_emcy();
        for k in 0..4u16 {
            self.load_pdo(0x1400 + k, now);
            self.load_pdo(0x1800 + k, now);
        }
    }

    fn load_sync(&mut self) {
        let get = |i| self.od.get_u32(Address::new(i, 0)).unwrap_or(0);
        let cob = SyncCobId::from_u32(get(0x1005)).unwrap_or(SyncCobId::DEFAULT);
        self.sync = SyncConsumer::new(cob, get(0x1006), get(0x1007), 0).ok();
        if self.sync.is_none() {
            self.config_errors += 1;
        }
    }

    fn load_emcy(&mut self) {
        let raw = self
            .od
            .get_u32(Address::new(0x1014, 0))
            .unwrap_or(0x80 + self.node.get() as u32);
        match EmcyCobId::from_u32(raw) {
            Ok(c) => self.emcy.set_cob_id(c),
            Err(_) => self.config_errors += 1,
        }
        self.emcy
            .set_inhibit(self.od.get_u16(Address::new(0x1015, 0)).unwrap_or(0));
    }

    /// (Re)builds the engine of the PDO whose communication (14xxh/18xxh) or mapping
    /// (16xxh/1Axxh) index is `index`.
    fn load_pdo(&mut self, index: u16, _now: Instant) {
        // A rebuilt TPDO starts with zeros: pack it again whatever the dictionary did.
        self.packed = None;
        let (comm, map, transmit, k) = match index {
            0x1400..=0x1403 => (index, index + 0x200, false, index - 0x1400),
            0x1600..=0x1603 => (index - 0x200, index, false, index - 0x1600),
            0x1800..=0x1803 => (index, index + 0x200, true, index - 0x1800),
            0x1A00..=0x1A03 => (index - 0x200, index, true, index - 0x1A00),
            _ => return,
        };
        let k = k as usize;
        if self.od.entry(Address::new(comm, 1)).is_err() {
            return; // the device has no such PDO
        }
        let built = CommParams::from_od(&self.od, comm)
            .ok()
            .zip(Mapping::from_od(&self.od, map).ok());
        match (built, transmit) {
            (Some((c, m)), true) => self.tpdo[k] = Some(Tpdo::new(c, m)),
            (Some((c, m)), false) => self.rpdo[k] = Some(Rpdo::new(c, m)),
            (None, _) => {
                self.config_errors += 1;
                if transmit {
                    self.tpdo[k] = None;
                } else {
                    self.rpdo[k] = None;
                }
            }
        }
        self.event_tpdos = self
            .tpdo
            .iter()
            .flatten()
            .any(|t| t.comm().cob_id.valid && t.comm().transmission.is_event_driven());
    }
}

/// CiA 301's rules for writes to PDO objects, checked before the dictionary stores them.
fn check_pdo_write<const N: usize, const B: usize>(
    od: &ObjectDictionary<'_, N, B>,
    addr: Address,
    data: &[u8],
) -> Result<(), AbortCode> {
    let le = |d: &[u8]| d.iter().rev().fold(0u64, |acc, b| acc << 8 | *b as u64);
    match addr.index {
        0x1400..=0x15FF | 0x1800..=0x19FF if addr.sub == 1 => {
            // The identifier may change only while the PDO is invalid (old or new value).
            let new = le(data) as u32;
            let old = od.get_u32(addr).unwrap_or(0);
            let both_valid = old & 0x8000_0000 == 0 && new & 0x8000_0000 == 0;
            if both_valid && (old & 0x1FFF_FFFF) != (new & 0x1FFF_FFFF) {
                return Err(AbortCode::InvalidValue);
            }
        }
        0x1400..=0x15FF | 0x1800..=0x19FF if addr.sub == 2 => {
            let t = le(data) as u8;
            let rpdo = addr.index < 0x1800;
            match TransmissionType::from_u8(t) {
                Err(_) => return Err(AbortCode::InvalidValue),
                Ok(TransmissionType::SyncRtr | TransmissionType::AsyncRtr) if rpdo => {
                    return Err(AbortCode::InvalidValue);
                }
                Ok(_) => {}
            }
        }
        0x1600..=0x17FF | 0x1A00..=0x1BFF => {
            let count = od.get_u8(Address::new(addr.index, 0)).unwrap_or(0);
            if addr.sub != 0 && count != 0 {
                // Entries change only while the mapping is disabled (sub00 = 0).
                return Err(AbortCode::UnsupportedAccess);
            }
            if addr.sub == 0 {
                let n = le(data) as u8;
                if n > 8 {
                    return Err(AbortCode::PdoLength);
                }
                let mut raw = [0u32; 8];
                for (i, r) in raw.iter_mut().enumerate().take(n as usize) {
                    *r = od
                        .get_u32(Address::new(addr.index, i as u8 + 1))
                        .unwrap_or(0);
                }
                let m = Mapping::from_raw(&raw[..n as usize]).map_err(|e| e.abort_code())?;
                m.validate(od, addr.index >= 0x1A00)
                    .map_err(|e| e.abort_code())?;
            }
        }
        _ => {}
    }
    Ok(())
}

impl<'a, const N: usize, const B: usize, const SDO: usize, H: DeviceHooks>
    Device<'a, N, B, SDO, H>
{
    /// After an SDO write: the engines follow their objects.
    fn after_write(&mut self, addr: Address, now: Instant) {
        match addr.index {
            0x1003 if addr.sub == 0 => {
                let _ = self.emcy.write_history_len(0);
                self.mirror_errors();
            }
            0x1005..=0x1007 => self.load_sync(),
            0x100C | 0x100D => {
                let guard = self.od.get_u16(Address::new(0x100C, 0)).unwrap_or(0);
                let factor = self.od.get_u8(Address::new(0x100D, 0)).unwrap_or(0);
                self.guarding.set_times(guard, factor);
            }
            0x1014 | 0x1015 => self.load_emcy(),
            0x1017 => {
                let ms = self.od.get_u16(addr).unwrap_or(0);
                self.heartbeat.set_period(ms, now);
            }
            0x1400..=0x1403 | 0x1600..=0x1603 | 0x1800..=0x1803 | 0x1A00..=0x1A03 => {
                self.load_pdo(addr.index, now);
                if self.nmt.state() == NmtState::Operational
                    && let Some(t) = self.tpdo_for(addr.index)
                {
                    t.reset();
                }
            }
            _ => {}
        }
    }

    fn tpdo_for(&mut self, index: u16) -> Option<&mut Tpdo> {
        let k = match index {
            0x1800..=0x1803 => index - 0x1800,
            0x1A00..=0x1A03 => index - 0x1A00,
            _ => return None,
        };
        self.tpdo[k as usize].as_mut()
    }

    fn reset(&mut self, kind: ResetKind, now: Instant) {
        match kind {
            ResetKind::Node => self.od.reset_to_defaults(),
            ResetKind::Communication => self.od.reset_range(0x1000, 0x1FFF),
        }
        self.emcy = EmcyProducer::new(EmcyCobId::for_node(self.node), 0);
        self.guarding.reset_communication();
        self.heartbeat.stop();
        self.tx.clear();
        self.load_communication(now);
        self.nmt.boot();
        self.push_event(DeviceEvent::Reset(kind));
    }

    /// Packs the data of every TPDO that can send (valid COB-ID) from the dictionary (before a
    /// SYNC samples it, an RTR asks for it or an event fires), unless no value changed since
    /// the last time. An invalid TPDO samples and sends nothing; making it valid rebuilds it
    /// ([`Device::load_pdo`]), which packs again.
    fn refresh_tpdos(&mut self) {
        let generation = self.od.generation();
        if self.packed == Some(generation) {
            return;
        }
        self.packed = Some(generation);
        for (t, at) in self.tpdo.iter_mut().zip(&mut self.tpdo_at) {
            let Some(t) = t else { continue };
            if !t.comm().cob_id.valid {
                continue;
            }
            let mut buf = [0u8; 8];
            if let Ok(n) = t.mapping().pack_from_od_at(&self.od, &mut buf, at) {
                t.set_data(&buf[..n]);
            }
        }
    }

    fn drain_sdo_events(&mut self, now: Instant) {
        while let Some(e) = self.sdo.poll_event() {
            match e {
                ServerEvent::Downloaded { addr, .. } => {
                    self.after_write(addr, now);
                    self.push_event(DeviceEvent::SdoWritten { addr });
                }
                ServerEvent::Aborted { addr, code, .. } => {
                    self.push_event(DeviceEvent::SdoAborted { addr, code })
                }
                ServerEvent::Uploaded { .. } | ServerEvent::Malformed { .. } => {}
            }
        }
    }

    fn drain_rpdo_events(&mut self) {
        for k in 0..4 {
            while let Some(e) = self.rpdo[k].as_mut().and_then(|r| r.poll_event()) {
                let pdo = k as u8 + 1;
                match e {
                    RpdoEvent::Applied(values) => {
                        let stored = self.rpdo[k].as_ref().map(|r| {
                            r.mapping().store_into_od_at(
                                values.as_slice(),
                                &mut self.od,
                                &mut self.rpdo_at[k],
                            )
                        });
                        match stored {
                            Some(Err(error)) => {
                                self.push_event(DeviceEvent::RpdoError { pdo, error })
                            }
                            _ => self.push_event(DeviceEvent::RpdoApplied { pdo }),
                        }
                    }
                    RpdoEvent::Error(error) => {
                        self.push_event(DeviceEvent::RpdoError { pdo, error })
                    }
                }
            }
        }
    }
}

/// The dictionary as the SDO server sees it: the dictionary's checks, the PDO rules, then the
/// application's hooks.
struct Checked<'d, 'a, const N: usize, const B: usize, H: DeviceHooks> {
    od: &'d mut ObjectDictionary<'a, N, B>,
    hooks: &'d mut H,
    state: NmtState,
}

impl<const N: usize, const B: usize, H: DeviceHooks> ObjectAccess for Checked<'_, '_, N, B, H> {
    fn size(&self, addr: Address) -> Result<usize, AbortCode> {
        // The dictionary's own objects first; what it lacks, the application may serve.
        if self.od.entry(addr).is_err()
            && let Some(r) = self.hooks.app_size(addr)
        {
            return r;
        }
        self.od.size(addr)
    }
    fn read(&mut self, addr: Address, offset: usize, buf: &mut [u8]) -> Result<usize, AbortCode> {
        if self.od.entry(addr).is_err()
            && let Some(r) = self.hooks.app_read(addr, offset, buf)
        {
            return r;
        }
        self.od.read(addr, offset, buf)
    }
    fn write(&mut self, addr: Address, data: &[u8]) -> Result<(), AbortCode> {
        if self.od.entry(addr).is_err()
            && let Some(r) = self.hooks.app_write(addr, data, self.state)
        {
            return r;
        }
        if addr.index == 0x1003 && addr.sub == 0 && data != [0] {
            // Only 0 may be written: it clears the history.
            return Err(AbortCode::InvalidValue);
        }
        // The PDO rules are asked after the dictionary's own checks (length, access, limits),
        // so a malformed write gets the dictionary's code.
        let pdo_check = check_pdo_write(self.od, addr, data);
        let (hooks, state) = (&mut *self.hooks, self.state);
        self.od.write_with(addr, data, |def, d| {
            pdo_check?;
            hooks.check_write(def, d, state)
        })
    }
}

impl<const N: usize, const B: usize, const SDO: usize, H: DeviceHooks> Endpoint
    for Device<'_, N, B, SDO, H>
{
    /// The identifiers its services answer to: NMT module control, its error control, its
    /// SDO, the SYNC, its valid PDOs. On any other `handle_frame` changes nothing.
    fn accepts(&self, frame: &Frame) -> bool {
        NmtSlave::accepts(frame)
            || self.guarding.accepts(frame)
            || self.sdo.accepts(frame)
            || self.sync.as_ref().is_some_and(|s| s.accepts(frame))
            || self.rpdo.iter().flatten().any(|r| r.accepts(frame))
            || self.tpdo.iter().flatten().any(|t| t.accepts(frame))
    }

    fn handle_frame(&mut self, frame: &Frame, now: Instant) {
        let state = self.nmt.state();
        if state == NmtState::Initialising {
            return;
        }
        match self.nmt.handle_frame(frame) {
            Ok(Some(NmtSlaveEvent::Reset(kind))) => return self.reset(kind, now),
            Ok(Some(NmtSlaveEvent::StateChanged { old, new })) => {
                if new == NmtState::Operational {
                    for t in self.tpdo.iter_mut().flatten() {
                        t.reset();
                    }
                }
                self.push_event(DeviceEvent::StateChanged { old, new });
                return;
            }
            Ok(None) => {}
            Err(_) => return,
        }
        if let Some(reply) = self.guarding.handle_frame(frame, now, state) {
            self.push_tx(reply);
            return;
        }
        if self.sdo.accepts(frame) {
            if state.allows(Service::Sdo) {
                let mut checked = Checked {
                    od: &mut self.od,
                    hooks: &mut self.hooks,
                    state,
                };
                self.sdo.handle_frame(frame, now, &mut checked);
                self.drain_sdo_events(now);
            }
            return;
        }
        let operational = state == NmtState::Operational;
        if state.allows(Service::Sync)
            && let Some(sync) = self.sync.as_mut()
        {
            match sync.handle_frame(frame, now) {
                Ok(Some(SyncEvent::Sync { counter, .. })) => {
                    if operational {
                        self.refresh_tpdos();
                        for t in self.tpdo.iter_mut().flatten() {
                            t.handle_sync(counter, now);
                        }
                        for r in self.rpdo.iter_mut().flatten() {
                            r.handle_sync(now);
                        }
                        self.drain_rpdo_events();
                    }
                    self.push_event(DeviceEvent::Sync { counter });
                    return;
                }
                Ok(_) => {}
                Err(_) => return,
            }
        }
        if operational {
            // The synchronous window (1007h) is not enforced here: a synchronous RPDO is latched
            // whenever it arrives and applied at the next SYNC. Devices whose manuals say
            // otherwise (the TLC5xx defers a late PDO to the SYNC after next) do it themselves.
            for r in self.rpdo.iter_mut().flatten() {
                if r.handle_frame(frame, now) {
                    break;
                }
            }
            self.drain_rpdo_events();
            // Only a remote frame can ask a TPDO for its current data.
            if frame.is_remote() {
                self.refresh_tpdos();
                for t in self.tpdo.iter_mut().flatten() {
                    if t.handle_frame(frame, now) {
                        break;
                    }
                }
            }
        }
    }

    fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        if let Some(f) = self.nmt.poll_transmit() {
            // The boot-up is out: heartbeats follow it.
            self.heartbeat.start(now);
            return Some(f);
        }
        let state = self.nmt.state();
        if state == NmtState::Initialising {
            return None;
        }
        if let Some(f) = self.tx.pop_front() {
            return Some(f);
        }
        if state.allows(Service::Sdo)
            && let Some(f) = self.sdo.poll_transmit(now)
        {
            return Some(f);
        }
        if state.allows(Service::Emcy)
            && let Some(f) = self.emcy.poll_transmit(now)
        {
            return Some(f);
        }
        if let Some(f) = self.heartbeat.poll_transmit(now, state) {
            return Some(f);
        }
        if state == NmtState::Operational {
            // What SYNCs and RTRs queued was packed then; only an event-driven TPDO sends the
            // dictionary's data of now.
            if self.event_tpdos {
                self.refresh_tpdos();
            }
            for t in self.tpdo.iter_mut().flatten() {
                if let Some(f) = t.poll_transmit(now) {
                    return Some(f);
                }
            }
        }
        None
    }

    fn poll_timeout(&self) -> Option<Instant> {
        // Asked several times per event by a virtual-time bus loop: plain comparisons, no
        // iterator chain.
        let min = |a: Option<Instant>, b: Option<Instant>| match (a, b) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        let mut t = min(self.sdo.poll_timeout(), self.heartbeat.poll_timeout());
        t = min(t, self.guarding.poll_timeout());
        t = min(t, self.emcy.poll_timeout());
        // Only an event-driven TPDO has a deadline of its own.
        if self.event_tpdos && self.nmt.state() == NmtState::Operational {
            for p in self.tpdo.iter().flatten() {
                t = min(t, p.poll_timeout());
            }
        }
        t
    }

    fn handle_timeout(&mut self, now: Instant) {
        self.sdo.handle_timeout(now);
        self.drain_sdo_events(now);
        self.guarding.handle_timeout(now);
        while let Some(e) = self.guarding.poll_event() {
            self.push_event(match e {
                LifeGuardingEvent::Lost => DeviceEvent::LifeGuardingLost,
                LifeGuardingEvent::Resumed => DeviceEvent::LifeGuardingResumed,
            });
        }
    }
}
