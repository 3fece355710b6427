//! The Festo EMCA on EtherCAT (seed-002 §5.2, digest `ethercat-digest.md` §10): a simulated
//! subdevice, an [`Esc`] with the EMCA's firmware behind it. The same FHPP drive model as the
//! CANopen EMCA ([`FhppDrive`]); only the transport differs:
//!
//! - the SII image and the object dictionary from one set of facts,
//!   [`catalog::EMCA_ETHERCAT`] (identity, mailboxes, PDOs, 1C32h);
//! - the ESM with the checks of each step up (mailbox sync managers at Init→PreOp, process data
//!   sizes against 1C12h/1C13h and the synchronisation set-up at PreOp→SafeOp, valid outputs at
//!   SafeOp→Op), the error flag until acknowledged, the SM watchdog in Op (001Bh);
//! - CoE: SDO to the dictionary and to the FHPP parameters at 2000h + PNU, emergencies from the
//!   drive (8100h when the master loses control of a drive it held);
//! - process data: the FHPP control bytes and the parameter channel from SM2 in Op, the status
//!   bytes and the parameter channel's reply to SM3 in SafeOp and Op. FHPP+ (1602h/1603h,
//!   1A02h/1A03h) is mapped and carried but not modelled (its inputs read 0).
//!
//! The drive's internal cycle is the shortest EtherCAT cycle, 1C32h:05 (the EMCA runs its
//! FHPP cycle with the bus's; ASSUMED 1 ms in the catalog), not the 5 ms of the CANopen EMCA.
//!
//! ```
//! use drivers::ethercat::esm::AlState;
//! use drivers::sim::emca_ec::EmcaEc;
//! use drivers::time::Instant;
//! let d = EmcaEc::new(Instant::ZERO).unwrap();
//! assert_eq!(d.state(), AlState::Init);
//! ```

use crate::canopen::od::{
    AccessType, DataType, EntryDef, ObjectAccess, ObjectDictionary, OdError, Value,
};
use crate::canopen::{AbortCode, Address};
use crate::catalog::{self, EcPdo, EthercatFacts};
use crate::ethercat::coe::CoeServer;
use crate::ethercat::esc::{Esc, EscConfig};
use crate::ethercat::esm::{self, AlState, AlStatusCode, Request};
use crate::ethercat::register as reg;
use crate::ethercat::segment::Subdevice;
use crate::ethercat::sii::{SiiError, SiiImage, SiiSpec, SmKind, SmSpec};
use crate::fhpp::Variant;
use crate::fhpp::status::Scon;
use crate::sim::fhpp_drive::{DriveConfig, DriveError, FhppDrive};
use crate::sim::mtr_dci::{FHPP_OBJECTS, pnu_read, pnu_size, pnu_write};
use crate::time::Instant;
use core::time::Duration;

/// Entries of the EMCA's EtherCAT dictionary.
pub const OD_ENTRIES: usize = 200;
/// Bytes of its values.
pub const OD_BYTES: usize = 1024;
/// Mailbox messages (SDO replies, emergencies) waiting for the read mailbox.
pub const MAILBOX_QUEUE: usize = 8;
/// The shortest read mailbox an SDO answer fits: mailbox and CoE headers and 8 SDO bytes.
const MIN_REPLY: usize = 16;

/// The dictionary type.
pub type EcDictionary = ObjectDictionary<'static, OD_ENTRIES, OD_BYTES>;

const FACTS: &EthercatFacts = &catalog::EMCA_ETHERCAT;

/// Why the subdevice could not be built.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EcSimError {
    /// The drive model refused its configuration.
    #[error(transparent)]
    Drive(#[from] DriveError),
    /// The dictionary does not hold the objects.
    #[error(transparent)]
    Dictionary(#[from] OdError),
    /// The SII image could not be built.
    #[error(transparent)]
    Sii(#[from] SiiError),
}

/// A message waiting for the read mailbox.
type Message = heapless::Vec<u8, 128>;

/// The simulated EMCA EtherCAT subdevice.
pub struct EmcaEc {
    esc: Esc,
    od: EcDictionary,
    coe: CoeServer,
    drive: FhppDrive,
    state: AlState,
    /// The AL status error flag and code, until the master acknowledges.
    error: Option<AlStatusCode>,
    /// SM2 written since SafeOp was entered.
    outputs_valid: bool,
    outbox: heapless::Deque<Message, MAILBOX_QUEUE>,
    /// Emergencies dropped because the mailbox queue was full.
    dropped: u32,
    /// Whether it has power (a switched-off subdevice passes no frame on).
    powered: bool,
    now: Instant,
    /// The revision it reports (SII word 0Ch, 1018h:03): the catalog's, or another to try a
    /// master's identity check.
    revision: u32,
}

impl core::fmt::Debug for EmcaEc {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("EmcaEc")
            .field("state", &self.state)
            .field("error", &self.error)
            .finish_non_exhaustive()
    }
}

/// The bytes of the first `n` PDOs of a list (the power-on assignment's sync manager length).
const fn assigned_len(pdos: &[EcPdo], n: u8) -> u16 {
    let mut sum = 0;
    let mut i = 0;
    while i < pdos.len() && i < n as usize {
        sum += pdos[i].bytes();
        i += 1;
    }
    sum
}

/// The sync managers of the SII: the mailboxes and the power-on assignment's process data.
const SMS: [SmSpec; 4] = [
    SmSpec {
        start: FACTS.mailbox_out.0,
        len: FACTS.mailbox_out.1,
        control: 0x26,
        kind: SmKind::MailboxOut,
    },
    SmSpec {
        start: FACTS.mailbox_in.0,
        len: FACTS.mailbox_in.1,
        control: 0x22,
        kind: SmKind::MailboxIn,
    },
    SmSpec {
        start: FACTS.outputs_start,
        len: assigned_len(FACTS.rx_pdos, FACTS.default_assigned),
        control: 0x64,
        kind: SmKind::Outputs,
    },
    SmSpec {
        start: FACTS.inputs_start,
        len: assigned_len(FACTS.tx_pdos, FACTS.default_assigned),
        control: 0x20,
        kind: SmKind::Inputs,
    },
];

/// The SII spec of the EMCA: identity and layout from the catalog. PDO descriptions are left
/// to CoE (GENERAL: SDO, PDO assignment; no complete access, no SDO information), as both
/// ethercrab and SOEM read them there when CoE is offered.
pub fn sii_spec() -> SiiSpec {
    SiiSpec {
        vendor: catalog::FESTO_VENDOR_ID,
        product: FACTS.product_code,
        revision: FACTS.revision,
        serial: 0,
        name: FACTS.name,
        sms: &SMS,
        fmmus: &[1, 2, 3],
        rxpdos: &[],
        txpdos: &[],
        coe_details: 0x01 | 0x04,
        dc: FACTS.dc,
    }
}

const fn e(
    index: u16,
    sub: u8,
    name: &'static str,
    dt: DataType,
    access: AccessType,
) -> EntryDef<'static> {
    EntryDef::new(Address::new(index, sub), name, dt, access)
}

/// Builds the dictionary: communication objects, PDO mapping and assignment, 1C32h/1C33h,
/// the FHPP objects, FHPP+.
fn dictionary(revision: u32) -> Result<EcDictionary, OdError> {
    use AccessType::{Const, Ro, Rw};
    use DataType::{Unsigned8 as U8, Unsigned16 as U16, Unsigned32 as U32};
    let mut od = EcDictionary::new();
    let u = |v: u32| Value::Unsigned(u64::from(v));
    od.insert(
        e(0x1000, 0, "device type", U32, Const).default_value(u(catalog::FESTO_FHPP_DEVICE_TYPE)),
    )?;
    od.insert(e(0x1001, 0, "error register", U8, Ro))?;
    od.insert_all(&crate::canopen::device::identity_strings(
        FACTS.name.as_bytes(),
        b"V.01.00",
        b"V.01.00",
    ))?;
    od.insert(e(0x1018, 0, "identity: entries", U8, Const).default_value(u(4)))?;
    for (sub, name, v) in [
        (1, "vendor-ID", catalog::FESTO_VENDOR_ID),
        (2, "product code", FACTS.product_code),
        (3, "revision number", revision),
        (4, "serial number", 0),
    ] {
        od.insert(e(0x1018, sub, name, U32, Const).default_value(u(v)))?;
    }
    // 1C00h: SM types mailbox out, in, outputs, inputs.
    od.insert(e(0x1C00, 0, "SM types: entries", U8, Const).default_value(u(4)))?;
    for sub in 1..=4u8 {
        od.insert(e(0x1C00, sub, "SM type", U8, Const).default_value(u(u32::from(sub))))?;
    }
    // Mapping objects: fixed (the manual marks 1600h ro; the mapping is the device's).
    for pdo in FACTS.rx_pdos.iter().chain(FACTS.tx_pdos) {
        od.insert(
            e(pdo.index, 0, "PDO mapping: entries", U8, Const)
                .default_value(u(pdo.entries.len() as u32)),
        )?;
        for (k, entry) in pdo.entries.iter().enumerate() {
            od.insert(
                e(pdo.index, k as u8 + 1, "mapped object", U32, Const).default_value(u(*entry)),
            )?;
        }
    }
    // Assignment: writable in PreOp.
    for (index, pdos) in [(0x1C12u16, FACTS.rx_pdos), (0x1C13, FACTS.tx_pdos)] {
        od.insert(
            e(index, 0, "PDO assignment: entries", U8, Rw)
                .default_value(u(u32::from(FACTS.default_assigned)))
                .limits(Value::Unsigned(0), Value::Unsigned(pdos.len() as u64)),
        )?;
        for (k, pdo) in pdos.iter().enumerate() {
            od.insert(
                e(index, k as u8 + 1, "assigned PDO", U16, Rw)
                    .default_value(u(u32::from(pdo.index))),
            )?;
        }
    }
    // 1C32h (outputs) / 1C33h (inputs): sub 0 = 0Ah as the manual prints it.
    for index in [0x1C32u16, 0x1C33] {
        let cycle = FACTS.min_cycle_ns;
        od.insert(e(index, 0, "sync parameters: entries", U8, Const).default_value(u(0x0A)))?;
        od.insert(e(index, 0x01, "synchronization type", U16, Rw))?;
        od.insert(e(index, 0x02, "cycle time", U32, Ro).default_value(u(cycle)))?;
        od.insert(
            e(index, 0x04, "synchronization types supported", U16, Const)
                .default_value(u(u32::from(FACTS.sync_types))),
        )?;
        od.insert(e(index, 0x05, "minimum cycle time", U32, Const).default_value(u(cycle)))?;
        od.insert(
            e(index, 0x06, "calc and copy time", U32, Const).default_value(u(FACTS.calc_copy_ns)),
        )?;
        od.insert(e(index, 0x08, "get cycle time", U16, Rw))?;
        od.insert(e(index, 0x09, "delay time", U32, Const))?;
        od.insert(e(index, 0x0B, "SM event missed counter", U16, Ro))?;
        od.insert(e(index, 0x0C, "cycle time too small counter", U16, Ro))?;
        od.insert(e(index, 0x20, "sync error", DataType::Boolean, Ro))?;
    }
    // 20F1h: store / restore ("load", "save" written as their ASCII codes).
    od.insert(e(0x20F1, 0, "store parameters: entries", U8, Const).default_value(u(2)))?;
    od.insert(e(0x20F1, 1, "load", U32, Rw))?;
    od.insert(e(0x20F1, 2, "save", U32, Rw))?;
    od.insert_all(&FHPP_OBJECTS)?;
    for pdos in [FACTS.rx_pdos, FACTS.tx_pdos] {
        for pdo in pdos.iter().skip(2) {
            let access = if pdo.index < 0x1A00 {
                AccessType::Wo
            } else {
                Ro
            };
            for entry in pdo.entries {
                let index = (entry >> 16) as u16;
                od.insert(e(index, 0, "FHPP+ byte", U8, access).mappable())?;
            }
        }
    }
    Ok(od)
}

impl EmcaEc {
    /// A powered-on EMCA-EC in Init with the default axis, alone on its line.
    pub fn new(now: Instant) -> Result<EmcaEc, EcSimError> {
        EmcaEc::with_config(EmcaEc::drive_config(), false, now)
    }

    /// The EMCA's default drive as it runs on EtherCAT: its internal cycle is the shortest
    /// EtherCAT cycle, 1C32h:05, not the CANopen EMCA's 5 ms.
    pub fn drive_config() -> DriveConfig {
        let mut cfg = DriveConfig::new(Variant::Emca);
        cfg.cycle = Duration::from_nanos(u64::from(FACTS.min_cycle_ns));
        cfg
    }

    /// A powered-on EMCA-EC with a drive configuration of its own; `port1_connected` when
    /// another subdevice follows it in the segment.
    pub fn with_config(
        cfg: DriveConfig,
        port1_connected: bool,
        now: Instant,
    ) -> Result<EmcaEc, EcSimError> {
        EmcaEc::with_revision(cfg, port1_connected, now, FACTS.revision)
    }

    /// As [`EmcaEc::with_config`], reporting `revision` instead of the catalog's (another
    /// firmware than the master expects).
    pub fn with_revision(
        cfg: DriveConfig,
        port1_connected: bool,
        now: Instant,
        revision: u32,
    ) -> Result<EmcaEc, EcSimError> {
        let sii = SiiImage::build(&SiiSpec {
            revision,
            ..sii_spec()
        })?;
        let esc = Esc::new(
            EscConfig {
                dc: FACTS.dc,
                port1_connected,
            },
            sii,
        );
        let mut drive = FhppDrive::new(cfg)?;
        drive.start_at(now);
        Ok(EmcaEc {
            esc,
            od: dictionary(revision)?,
            coe: CoeServer::new(),
            drive,
            state: AlState::Init,
            error: None,
            outputs_valid: false,
            outbox: heapless::Deque::new(),
            dropped: 0,
            powered: true,
            now,
            revision,
        })
    }

    /// The ESM state.
    pub fn state(&self) -> AlState {
        self.state
    }

    /// The AL status code while the error flag is set.
    pub fn error(&self) -> Option<AlStatusCode> {
        self.error
    }

    /// The configured station address the master gave it (register 0010h).
    pub fn station_address(&self) -> u16 {
        self.esc.station_address()
    }

    /// The drive model.
    pub fn drive(&self) -> &FhppDrive {
        &self.drive
    }

    /// The drive model, for fault injection.
    pub fn drive_mut(&mut self) -> &mut FhppDrive {
        &mut self.drive
    }

    /// The dictionary.
    pub fn od(&self) -> &EcDictionary {
        &self.od
    }

    /// Emergencies dropped because the mailbox was not read.
    pub fn dropped_emergencies(&self) -> u32 {
        self.dropped
    }

    /// Whether it has power.
    pub fn powered(&self) -> bool {
        self.powered
    }

    /// Switches the subdevice off: it forgets everything, and frames no longer pass it.
    pub fn power_off(&mut self) {
        self.powered = false;
    }

    /// Switches it on again at `now`: a fresh drive in Init, as after a power cycle.
    pub fn power_on(&mut self, now: Instant) -> Result<(), EcSimError> {
        let cfg = *self.drive.config();
        let port1 = self.esc.memory()[usize::from(reg::DL_STATUS)] & 0x20 != 0;
        *self = EmcaEc::with_revision(cfg, port1, now, self.revision)?;
        Ok(())
    }

    fn set_state(&mut self, to: AlState) {
        let from = self.state;
        if from == AlState::Op && to != AlState::Op {
            self.leave_op();
        }
        if to == AlState::Init {
            self.coe.reset();
            self.outbox.clear();
        }
        if to == AlState::SafeOp && from != AlState::Op {
            self.outputs_valid = false;
            let _ = self.esc.take_written(2);
        }
        if to == AlState::Op {
            self.esc.clear_watchdog();
            self.drive.fieldbus_restored(self.now);
        }
        self.state = to;
        self.publish_status();
    }

    /// Op left: the master no longer sends setpoints. A drive it held enabled reacts as to a
    /// lost connection (50h, EMCY 8100h).
    fn leave_op(&mut self) {
        let scon = Scon::from_byte(self.drive.input()[0]);
        if scon.enabled {
            self.drive.fieldbus_lost(true, self.now);
        }
    }

    fn publish_status(&mut self) {
        let code = self.error.map_or(0, |c| c.0);
        self.esc
            .set_al_status(self.state, self.error.is_some(), code);
    }

    /// The master wrote AL control.
    fn al_control(&mut self, value: u16) {
        let ack = value & reg::AL_ERROR != 0;
        let requested = (value & reg::AL_STATE_MASK) as u8;
        if ack {
            self.error = None;
        }
        match esm::request(self.state, requested) {
            Request::Stay => {}
            Request::Refuse(code) => self.error = Some(code),
            Request::Go(to) => {
                if self.error.is_some() && to > self.state {
                    // Up only once the error is acknowledged.
                } else {
                    match self.check(to) {
                        Ok(()) => self.set_state(to),
                        Err(code) => self.error = Some(code),
                    }
                }
            }
        }
        self.publish_status();
    }

    /// The checks of a step up (digest §4.2); steps down need none.
    fn check(&self, to: AlState) -> Result<(), AlStatusCode> {
        match (self.state, to) {
            (AlState::Init, AlState::PreOp) => self.check_mailboxes(),
            (AlState::PreOp, AlState::SafeOp) => self.check_process_data(),
            (AlState::SafeOp, AlState::Op) => {
                if !self.outputs_valid {
                    return Err(AlStatusCode::NO_VALID_OUTPUTS);
                }
                self.check_sync()
            }
            _ => Ok(()),
        }
    }

    fn check_mailboxes(&self) -> Result<(), AlStatusCode> {
        let want = [(0u8, FACTS.mailbox_out, true), (1, FACTS.mailbox_in, false)];
        for (n, (start, len), writes) in want {
            let sm = self.esc.sync_manager(n);
            if !sm.enabled
                || sm.start != start
                || sm.len != len
                || !sm.mailbox()
                || sm.master_writes() != writes
            {
                return Err(AlStatusCode::INVALID_MAILBOX_CONFIG);
            }
        }
        Ok(())
    }

    /// The PDOs assigned in 1C12h (`rx`, outputs) or 1C13h (inputs), in their order: the
    /// layout of SM2 or SM3.
    fn assigned(&self, rx: bool) -> heapless::Vec<&'static EcPdo, 4> {
        let (index, pdos) = if rx {
            (0x1C12, FACTS.rx_pdos)
        } else {
            (0x1C13, FACTS.tx_pdos)
        };
        let n = self.od.get_u8(Address::new(index, 0)).unwrap_or(0);
        (1..=n)
            .filter_map(|sub| self.od.get_u16(Address::new(index, sub)).ok())
            .filter_map(|i| pdos.iter().find(|p| p.index == i))
            .collect()
    }

    /// The bytes of the PDOs assigned in 1C12h (`rx`) or 1C13h.
    fn assigned_bytes(&self, rx: bool) -> u16 {
        self.assigned(rx).iter().map(|p| p.bytes()).sum()
    }

    fn check_process_data(&self) -> Result<(), AlStatusCode> {
        for (n, rx, start, code) in [
            (
                2u8,
                true,
                FACTS.outputs_start,
                AlStatusCode::INVALID_OUTPUT_CONFIG,
            ),
            (
                3,
                false,
                FACTS.inputs_start,
                AlStatusCode::INVALID_INPUT_CONFIG,
            ),
        ] {
            let bytes = self.assigned_bytes(rx);
            let sm = self.esc.sync_manager(n);
            if bytes == 0 {
                continue;
            }
            if !sm.enabled
                || sm.start != start
                || sm.len != bytes
                || sm.mailbox()
                || sm.master_writes() != rx
            {
                return Err(code);
            }
        }
        self.check_sync()
    }

    /// 1C32h:01 = 2 (DC SYNC0) needs SYNC0 running with a cycle no shorter than 1C32h:05.
    fn check_sync(&self) -> Result<(), AlStatusCode> {
        let mode = self.od.get_u16(Address::new(0x1C32, 1)).unwrap_or(0);
        match mode {
            0 | 1 => Ok(()),
            2 => match self.esc.sync0() {
                None => Err(AlStatusCode::INVALID_DC_SYNC_CONFIG),
                Some((_, cycle)) if cycle < FACTS.min_cycle_ns => {
                    Err(AlStatusCode::INVALID_SYNC0_CYCLE)
                }
                Some(_) => Ok(()),
            },
            _ => Err(AlStatusCode::SYNC_MODE_NOT_SUPPORTED),
        }
    }

    /// Mailbox: takes a request, answers it, and moves queued messages into the read mailbox.
    fn mailbox(&mut self) {
        if self.state == AlState::Init {
            return;
        }
        if let Some(msg) = self.esc.mailbox_in() {
            let mut request = [0u8; 128];
            let n = msg.len().min(request.len());
            request[..n].copy_from_slice(&msg[..n]);
            self.esc.mailbox_in_done();
            let room = self.esc.sync_manager(1).area().len().min(128);
            if room < MIN_REPLY {
                // No read mailbox to answer into (a master that cleared SM1 in PreOp).
                return;
            }
            let mut reply = [0u8; 128];
            let mut objects = Objects {
                od: &mut self.od,
                drive: &mut self.drive,
                state: self.state,
            };
            if let Some(len) = self
                .coe
                .handle(&request[..n], &mut objects, &mut reply[..room])
            {
                let mut m = Message::new();
                let _ = m.extend_from_slice(&reply[..len]);
                // The answer goes first (a master waits for it in SM1 and takes whatever is
                // there for it) and always finds room: emergencies give way.
                if self.outbox.is_full() {
                    let _ = self.outbox.pop_back();
                    self.dropped += 1;
                }
                let _ = self.outbox.push_front(m);
            }
        }
        while let Some(e) = self.drive.poll_emcy() {
            let mut out = [0u8; 32];
            let num = e.number.to_le_bytes();
            let len = self
                .coe
                .emergency(e.code, e.register, [num[0], num[1], 0, 0, 0], &mut out);
            let mut m = Message::new();
            let _ = m.extend_from_slice(&out[..len]);
            if self.outbox.push_back(m).is_err() {
                self.dropped += 1;
            }
        }
        if !self.esc.mailbox_out_full()
            && let Some(m) = self.outbox.front()
            && self.esc.mailbox_out(m)
        {
            let _ = self.outbox.pop_front();
        }
    }

    /// Process data: outputs in Op, inputs in SafeOp and Op, laid out by the assignment.
    fn process_data(&mut self) {
        if !matches!(self.state, AlState::SafeOp | AlState::Op) {
            return;
        }
        if self.esc.take_written(2) {
            self.outputs_valid = true;
            if self.state == AlState::Op {
                let area = self.esc.sm_area(2);
                let mut at = 0usize;
                let mut control = None;
                let mut request = None;
                for pdo in self.assigned(true) {
                    let len = usize::from(pdo.bytes());
                    let Some(bytes) = area.get(at..at + len) else {
                        break;
                    };
                    let mut b = [0u8; 8];
                    b[..len.min(8)].copy_from_slice(&bytes[..len.min(8)]);
                    match pdo.index {
                        0x1600 => control = Some(b),
                        0x1601 => request = Some(b),
                        _ => {}
                    }
                    at += len;
                }
                if let Some(c) = control {
                    self.drive.exchange(&c, self.now);
                }
                if let Some(r) = request {
                    self.drive.parameter(&r, self.now);
                }
            }
        }
        let mut inputs = [0u8; 32];
        let mut at = 0usize;
        for pdo in self.assigned(false) {
            let len = usize::from(pdo.bytes());
            let bytes = match pdo.index {
                0x1A00 => self.drive.input(),
                0x1A01 => self.drive.fpc_reply(),
                _ => [0; 8],
            };
            if at + len > inputs.len() {
                break;
            }
            inputs[at..at + len.min(8)].copy_from_slice(&bytes[..len.min(8)]);
            at += len;
        }
        self.esc.set_sm_area(3, &inputs[..at]);
    }
}

impl Subdevice for EmcaEc {
    fn esc(&mut self) -> &mut Esc {
        &mut self.esc
    }

    fn powered(&self) -> bool {
        self.powered
    }

    fn poll(&mut self, now: Instant) {
        if !self.powered {
            return;
        }
        self.now = now;
        self.drive.step_to(now);
        if let Some(v) = self.esc.take_al_control() {
            self.al_control(v);
        }
        if self.state == AlState::Op && self.esc.watchdog_expired_at(now) {
            self.error = Some(AlStatusCode::SM_WATCHDOG);
            self.set_state(AlState::SafeOp);
        }
        self.mailbox();
        self.process_data();
    }
}

/// The dictionary as CoE sees it: the object rules of the EMCA on EtherCAT over the stored
/// values, the FHPP parameters at 2000h + PNU, and the cyclic status objects read live.
struct Objects<'a> {
    od: &'a mut EcDictionary,
    drive: &'a mut FhppDrive,
    state: AlState,
}

impl Objects<'_> {
    /// The live value of a cyclic input object (3020h..3033h: status bytes and the parameter
    /// channel's reply), little-endian, and its length.
    fn live(&self, addr: Address) -> Option<([u8; 4], usize)> {
        if addr.sub != 0 {
            return None;
        }
        let input = self.drive.input();
        let reply = self.drive.fpc_reply();
        let (bytes, at, len): (&[u8; 8], usize, usize) = match addr.index {
            0x3020..=0x3023 => (&input, usize::from(addr.index - 0x3020), 1),
            0x3024 => (&input, 4, 4),
            0x3030 | 0x3031 => (&reply, usize::from(addr.index - 0x3030), 1),
            0x3032 => (&reply, 2, 2),
            0x3033 => (&reply, 4, 4),
            _ => return None,
        };
        let mut v = [0u8; 4];
        v[..len].copy_from_slice(&bytes[at..at + len]);
        Some((v, len))
    }
}

impl ObjectAccess for Objects<'_> {
    fn size(&self, addr: Address) -> Result<usize, AbortCode> {
        if let Some(r) = pnu_size(self.drive, addr) {
            return r;
        }
        self.od.size(addr)
    }

    fn read(&mut self, addr: Address, offset: usize, buf: &mut [u8]) -> Result<usize, AbortCode> {
        if let Some(r) = pnu_read(self.drive, addr, offset, buf) {
            return r;
        }
        if let Some((v, len)) = self.live(addr) {
            self.od.entry(addr)?;
            let rest = v.get(offset..len).unwrap_or(&[]);
            let n = rest.len().min(buf.len());
            buf[..n].copy_from_slice(&rest[..n]);
            return Ok(n);
        }
        self.od.read(addr, offset, buf)
    }

    fn write(&mut self, addr: Address, data: &[u8]) -> Result<(), AbortCode> {
        if let Some(r) = pnu_write(self.drive, addr, data) {
            return r;
        }
        match addr.index {
            0x1C12 | 0x1C13 => {
                if self.state != AlState::PreOp {
                    return Err(AbortCode::DeviceState);
                }
                let pdos = if addr.index == 0x1C12 {
                    FACTS.rx_pdos
                } else {
                    FACTS.tx_pdos
                };
                let count = self.od.get_u8(Address::new(addr.index, 0)).unwrap_or(0);
                if addr.sub == 0 {
                    let n = data.first().copied().unwrap_or(0);
                    let valid = (1..=n).all(|sub| {
                        self.od
                            .get_u16(Address::new(addr.index, sub))
                            .is_ok_and(|i| pdos.iter().any(|p| p.index == i))
                    });
                    if data.len() == 1 && n as usize <= pdos.len() && !valid {
                        return Err(AbortCode::InvalidValue);
                    }
                } else {
                    if count != 0 {
                        // ETG.1000.6: the entries change only while sub-index 0 is 0.
                        return Err(AbortCode::Other(0x0601_0003));
                    }
                    let v = match data {
                        [a, b] => u16::from_le_bytes([*a, *b]),
                        _ if data.len() > 2 => return Err(AbortCode::TooLong),
                        _ => return Err(AbortCode::TooShort),
                    };
                    if !pdos.iter().any(|p| p.index == v) {
                        return Err(AbortCode::InvalidValue);
                    }
                }
                self.od.write(addr, data)
            }
            0x1C32 | 0x1C33 if addr.sub == 1 => {
                if self.state != AlState::PreOp {
                    return Err(AbortCode::DeviceState);
                }
                let v = match data {
                    [a, b] => u16::from_le_bytes([*a, *b]),
                    _ if data.len() > 2 => return Err(AbortCode::TooLong),
                    _ => return Err(AbortCode::TooShort),
                };
                // Free run, SM-synchronous, DC SYNC0 (1C32h:04 = 0007h).
                if v > 2 {
                    return Err(AbortCode::InvalidValue);
                }
                self.od.write(addr, data)
            }
            _ => self.od.write(addr, data),
        }
    }
}
