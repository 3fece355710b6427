//! The Festo MTR-DCI motor unit on CANopen (seed 000 §7), and the FHPP-over-CANopen adapter it
//! shares with the EMCA ([`super::emca`]).
//!
//! A [`FestoNode`] is a CiA 301 [`Device`] whose dictionary holds the manual's communication
//! objects and static PDO mapping, in front of an [`FhppDrive`] (the device behaviour):
//!
//! - RPDO1 (3000h..3004h, the 8 FHPP control bytes) feeds [`FhppDrive::exchange`]; TPDO1
//!   (3020h..3024h) carries the status image. RPDO2/TPDO2 (3010h..3013h / 3030h..3033h) are the
//!   parameter channel ([`FhppDrive::parameter`]). Transmission type 255 (event-driven) at
//!   power-up, as both manuals give; a master may switch 1400h/1800h sub 02 to synchronous.
//! - SDO 2000h + PNU reaches the drive's parameter table ([`DeviceHooks::app_read`]), with the
//!   device's sub-index rules and the abort codes of [`PnuError::abort_code`].
//! - EMCYs come from [`FhppDrive::poll_emcy`] with the manual's 1001h bits; 1003h keeps them.
//! - Life guarding loss (no guard poll within 100Ch × 100Dh) becomes the drive's fault (MTR-DCI
//!   fault reaction 605Eh = 2, EMCA diagnostic 1Ch) and EMCY 8130h.
//! - The drive's internal cycle (1 ms MTR-DCI, 5 ms EMCA) is reported by
//!   [`Endpoint::poll_timeout`], so the node runs correctly in virtual time.
//!
//! The MTR-DCI alternatively speaks its CiA 402 profile ([`Profile::Cia402`], §7.8–7.10): the
//! objects 6040h.., the Festo state machine of [`crate::cia402::MTR_DCI`], profile position
//! with the set-point handshake and homing, carried out on the same drive and axis. As the
//! manual says, internally the device *is* one drive with two faces: here the CiA 402 face
//! translates into the FHPP commands of the drive core (direct positioning for a set-point,
//! record select when 2032h names a record, HOM for homing).
//!
//! ```
//! use drivers::canopen::NodeId;
//! use drivers::sim::mtr_dci::{MtrDci, Profile};
//! use drivers::time::Instant;
//! let d = MtrDci::new(NodeId::new(3).unwrap(), Profile::Fhpp, Instant::ZERO).unwrap();
//! // Node guarding only: no heartbeat object.
//! assert!(d.device().od().entry(drivers::canopen::Address::new(0x1017, 0)).is_err());
//! ```

use crate::can::Frame;
// PDO1 and the parameter channel on PDO2 as the catalog has them (seed-000 §7.4).
use crate::canopen::device::{
    CommProfile, Device, DeviceEvent, DeviceHooks, PdoDefault, identity_strings,
    insert_communication_objects,
};
use crate::canopen::endpoint::Endpoint;
use crate::canopen::nmt::{BootUpStyle, NmtState, ResetKind};
use crate::canopen::od::{
    AccessType, DataType, EntryDef, ObjectDictionary, OdError, Resolved, Value,
};
use crate::canopen::{AbortCode, Address, NodeId};
use crate::catalog::{
    self, FHPP_RPDO1, FHPP_TPDO1, FPC_RPDO2 as FHPP_RPDO2, FPC_TPDO2 as FHPP_TPDO2,
    MTR_DCI_402_RPDO1 as CIA_RPDO1, MTR_DCI_402_RPDO2 as CIA_RPDO2, MTR_DCI_402_TPDO1 as CIA_TPDO1,
};
use crate::cia402::controlword::Controlword;
use crate::cia402::modes::{ModeSelector, Move, OperationMode, PpAction, PpDevice, PpObjects};
use crate::cia402::state::{DeviceStateMachine, State};
use crate::cia402::statusword::Statusword;
use crate::cia402::{MTR_DCI as MTR_DCI_402, homing::HomingMethod};
use crate::fhpp::Variant;
use crate::fhpp::pnu::DataType as PnuType;
use crate::sim::fhpp_drive::{
    DirectProfile, DriveConfig, DriveError, FhppDrive, Injection, PnuError,
};
use crate::time::{Instant, earliest};

/// Entries of a Festo node's dictionary.
pub const OD_ENTRIES: usize = 192;
/// Value bytes of a Festo node's dictionary.
pub const OD_BYTES: usize = 2048;
/// The longest SDO download a Festo node takes (the parameters are at most 4 bytes).
pub const SDO_BYTES: usize = 64;

/// The dictionary of a Festo node.
pub type FestoOd = ObjectDictionary<'static, OD_ENTRIES, OD_BYTES>;
/// The CANopen device of a Festo node.
pub type FestoDevice = Device<'static, OD_ENTRIES, OD_BYTES, SDO_BYTES, FestoApp>;

/// Which device profile the node speaks (the MTR-DCI's "CAN profile" setting, 2FF5h).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Profile {
    /// FHPP: 8 control/status bytes on PDO1, the parameter channel on PDO2.
    Fhpp,
    /// CiA 402 (MTR-DCI only): controlword/statusword, profile position, homing.
    Cia402,
}

/// Why a simulated node could not be built.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SimError {
    /// The drive core refused its configuration.
    #[error(transparent)]
    Drive(#[from] DriveError),
    /// The dictionary does not fit its capacity.
    #[error(transparent)]
    Od(#[from] OdError),
    /// The profile is not one this device offers (the EMCA's CiA 402 profile is not modelled).
    #[error("{0:?} does not offer this device profile")]
    Profile(Variant),
}

// ---- the FHPP objects (both devices, §7.4 / EMCA §5.1) ---------------------------------------

const fn obj(
    index: u16,
    name: &'static str,
    dt: DataType,
    access: AccessType,
) -> EntryDef<'static> {
    EntryDef::new(Address::new(index, 0), name, dt, access).mappable()
}

/// FHPP output bytes 1..8 as RPDO1 maps them: CCON, CPOS, CDIR/record, value 1, value 2.
pub const FHPP_OUT: [Address; 5] = [
    Address::new(0x3000, 0),
    Address::new(0x3001, 0),
    Address::new(0x3002, 0),
    Address::new(0x3003, 0),
    Address::new(0x3004, 0),
];
/// FHPP input bytes 1..8 as TPDO1 maps them: SCON, SPOS, SDIR/record, RSB/value 1, value 2.
pub const FHPP_IN: [Address; 5] = [
    Address::new(0x3020, 0),
    Address::new(0x3021, 0),
    Address::new(0x3022, 0),
    Address::new(0x3023, 0),
    Address::new(0x3024, 0),
];
/// Parameter channel request as RPDO2 maps it (bytes 1, 2, 3..4, 5..8).
pub const FPC_OUT: [Address; 4] = [
    Address::new(0x3010, 0),
    Address::new(0x3011, 0),
    Address::new(0x3012, 0),
    Address::new(0x3013, 0),
];
/// Parameter channel reply as TPDO2 maps it.
pub const FPC_IN: [Address; 4] = [
    Address::new(0x3030, 0),
    Address::new(0x3031, 0),
    Address::new(0x3032, 0),
    Address::new(0x3033, 0),
];

/// The MTR-DCI's name and versions, visible strings, read only (§7.3: 1008h, 1009h, 100Ah;
/// the versions written "V.xx.yy"). The name is the manual's example type code; the version
/// numbers are the simulator's (the manual gives only their form).
const MTR_DCI_STRINGS: [EntryDef<'static>; 3] =
    identity_strings(b"MTR-DCI-42S-VCSC-EG14-H2CO", b"V.01.00", b"V.01.00");

pub(crate) const FHPP_OBJECTS: [EntryDef<'static>; 18] = {
    use AccessType::{Ro, Wo};
    use DataType::{Integer32 as I32, Unsigned8 as U8, Unsigned16 as U16, Unsigned32 as U32};
    [
        obj(0x3000, "CCON", U8, Wo),
        obj(0x3001, "CPOS", U8, Wo),
        obj(0x3002, "CDIR / record number", U8, Wo),
        obj(0x3003, "setpoint value 1", U8, Wo),
        obj(0x3004, "setpoint value 2", I32, Wo),
        obj(0x3010, "FPC byte 1", U8, Wo),
        obj(0x3011, "FPC sub-index", U8, Wo),
        obj(0x3012, "FPC PKE", U16, Wo),
        obj(0x3013, "FPC PWE", U32, Wo),
        obj(0x3020, "SCON", U8, Ro),
        obj(0x3021, "SPOS", U8, Ro),
        obj(0x3022, "SDIR / record number", U8, Ro),
        obj(0x3023, "RSB / actual value 1", U8, Ro),
        obj(0x3024, "actual value 2", I32, Ro),
        obj(0x3030, "FPC reply byte 1", U8, Ro),
        obj(0x3031, "FPC reply sub-index", U8, Ro),
        obj(0x3032, "FPC reply PKE", U16, Ro),
        obj(0x3033, "FPC reply PWE", U32, Ro),
    ]
};

/// A PDO valid at power-up, event-driven (type 255), static mapping. The mapping objects are
/// made read-only by [`FestoApp::check_write`] rather than `fixed`, because the manual lets the
/// transmission type change (§7.4) while the mapping cannot.
const fn event_pdo(mapping: &'static [u32]) -> PdoDefault {
    PdoDefault {
        valid: true,
        transmission: 255,
        event_ms: 0,
        mapping,
        fixed: false,
    }
}

/// 1018h:01..04 of a Festo drive: the catalog's vendor-ID and product code (0 where the manual
/// gives none), revision 1.0 and serial 0 (the simulator's choice).
pub const fn festo_identity(device: &catalog::Device) -> [u32; 4] {
    let vendor = match device.vendor_id {
        Some(v) => v,
        None => 0,
    };
    let product = match device.product_code {
        Some(p) => p,
        None => 0,
    };
    [vendor, product, 0x0001_0000, 0]
}

/// The MTR-DCI's communication objects in the FHPP profile (§7.3, §7.4): device type 12Dh,
/// vendor 1Dh, node guarding only (no 1017h), PDO1 + PDO2 type 255, TPDO sub 04h absent (SDO
/// abort) and no sub 06h.
pub const MTR_DCI_FHPP: CommProfile = CommProfile {
    device_type: catalog::FESTO_FHPP_DEVICE_TYPE,
    identity: festo_identity(&catalog::MTR_DCI),
    heartbeat: catalog::MTR_DCI.has_heartbeat(),
    heartbeat_ms: 0,
    guarding: catalog::MTR_DCI.guard_time_max_ms.is_some(),
    boot_up: BootUpStyle::Ds301,
    rpdo: [
        event_pdo(FHPP_RPDO1),
        event_pdo(FHPP_RPDO2),
        PdoDefault::ABSENT,
        PdoDefault::ABSENT,
    ],
    tpdo: [
        event_pdo(FHPP_TPDO1),
        event_pdo(FHPP_TPDO2),
        PdoDefault::ABSENT,
        PdoDefault::ABSENT,
    ],
    tpdo_sync_start: false,
};

/// The MTR-DCI's communication objects in the CiA 402 profile (§7.4): device type 00020192h
/// (erratum E1), RPDO1/2 and TPDO1 (TPDO2 is not supported).
pub const MTR_DCI_CIA402: CommProfile = CommProfile {
    device_type: catalog::CIA402_DEVICE_TYPE,
    rpdo: [
        event_pdo(CIA_RPDO1),
        event_pdo(CIA_RPDO2),
        PdoDefault::ABSENT,
        PdoDefault::ABSENT,
    ],
    tpdo: [
        event_pdo(CIA_TPDO1),
        PdoDefault::ABSENT,
        PdoDefault::ABSENT,
        PdoDefault::ABSENT,
    ],
    ..MTR_DCI_FHPP
};

// ---- the CiA 402 objects (§7.8) ---------------------------------------------------------------

/// 6040h controlword.
pub const CONTROLWORD: Address = Address::new(0x6040, 0);
/// 6041h statusword.
pub const STATUSWORD: Address = Address::new(0x6041, 0);
/// 6060h modes of operation.
pub const MODE: Address = Address::new(0x6060, 0);
/// 6061h modes of operation display.
pub const MODE_DISPLAY: Address = Address::new(0x6061, 0);
/// 6064h position actual value.
pub const POSITION_ACTUAL: Address = Address::new(0x6064, 0);
/// 607Ah target position.
pub const TARGET_POSITION: Address = Address::new(0x607A, 0);
/// 6071h target torque (‰ of the rated current).
pub const TARGET_TORQUE: Address = Address::new(0x6071, 0);
/// 6081h profile velocity.
pub const PROFILE_VELOCITY: Address = Address::new(0x6081, 0);
/// 6083h profile acceleration.
pub const PROFILE_ACCELERATION: Address = Address::new(0x6083, 0);
/// 6098h homing method.
pub const HOMING_METHOD: Address = Address::new(0x6098, 0);
/// 2032h/01 record number (0 = "direct record": the PDO set-point applies).
pub const RECORD_NUMBER: Address = Address::new(0x2032, 1);

const fn sub(
    index: u16,
    s: u8,
    name: &'static str,
    dt: DataType,
    access: AccessType,
) -> EntryDef<'static> {
    EntryDef::new(Address::new(index, s), name, dt, access)
}

const CIA402_OBJECTS: [EntryDef<'static>; 30] = {
    use AccessType::{Const, Ro, Rw, Rwr, Rww};
    use DataType::{
        Integer8 as I8, Integer16 as I16, Integer32 as I32, Unsigned8 as U8, Unsigned16 as U16,
        Unsigned32 as U32,
    };
    [
        sub(0x2032, 0, "record number: entries", U8, Const).default_value(Value::Unsigned(1)),
        sub(0x2032, 1, "record number", U8, Rw)
            .mappable()
            .limits(Value::Unsigned(0), Value::Unsigned(31)),
        obj(0x6040, "controlword", U16, Rww),
        obj(0x6041, "statusword", U16, Rwr).default_value(Value::Unsigned(0x0200)),
        sub(0x605D, 0, "halt option code", I16, Const).default_value(Value::Signed(1)),
        sub(0x605E, 0, "fault reaction option code", I16, Const).default_value(Value::Signed(2)),
        obj(0x6060, "modes of operation", I8, Rww).default_value(Value::Signed(1)),
        obj(0x6061, "modes of operation display", I8, Rwr).default_value(Value::Signed(1)),
        sub(0x6062, 0, "position demand value", I32, Ro),
        sub(0x6063, 0, "position actual value (internal)", I32, Ro),
        obj(0x6064, "position actual value", I32, Rwr),
        sub(0x6067, 0, "position window", U32, Rw).default_value(Value::Unsigned(750)),
        sub(0x6068, 0, "position window time", U16, Rw).default_value(Value::Unsigned(100)),
        sub(0x606B, 0, "velocity demand value", I32, Ro),
        obj(0x606C, "velocity actual value", I32, Rwr),
        obj(0x6071, "target torque", I16, Rww)
            .default_value(Value::Signed(200))
            .limits(Value::Signed(200), Value::Signed(1500)),
        obj(0x6077, "torque actual value", I16, Rwr),
        obj(0x607A, "target position", I32, Rww),
        sub(0x607C, 0, "home offset", I32, Rw),
        obj(0x6081, "profile velocity", U32, Rww).default_value(Value::Unsigned(50_000)),
        obj(0x6083, "profile acceleration", U32, Rww).default_value(Value::Unsigned(400_000)),
        sub(0x6084, 0, "profile deceleration", U32, Rw).default_value(Value::Unsigned(400_000)),
        sub(0x6086, 0, "motion profile type", I16, Const).default_value(Value::Signed(-1)),
        sub(0x6087, 0, "torque slope", U32, Const).default_value(Value::Unsigned(10_000)),
        sub(0x6088, 0, "torque profile type", I16, Const),
        sub(0x6098, 0, "homing method", I8, Rw).default_value(Value::Signed(27)),
        sub(0x6099, 0, "homing speeds: entries", U8, Const).default_value(Value::Unsigned(2)),
        sub(0x6099, 1, "speed during search for switch", U32, Rw)
            .default_value(Value::Unsigned(22_400)),
        sub(0x6099, 2, "speed during search for zero", U32, Rw)
            .default_value(Value::Unsigned(22_400)),
        sub(0x6502, 0, "supported drive modes", U32, Const).default_value(Value::Unsigned(0x29)),
    ]
};

// ---- the application: the drive behind the dictionary ----------------------------------------

/// What the [`Device`] consults for the objects it does not hold itself: the drive's parameter
/// table at 2000h + PNU, the static-mapping rule, and the CiA 402 face if the node speaks it.
#[derive(Debug)]
pub struct FestoApp {
    drive: FhppDrive,
    cia: Option<Cia402Face>,
}

const PNU_FIRST: u16 = 0x2000;
const PNU_LAST: u16 = 0x2000 + 2047;

const fn width(dt: PnuType) -> usize {
    match dt {
        PnuType::U8 | PnuType::I8 | PnuType::Char => 1,
        PnuType::U16 | PnuType::I16 => 2,
        PnuType::U32 | PnuType::I32 => 4,
    }
}

/// Decodes an SDO payload of a parameter of type `dt`: little-endian, exactly the type's width
/// (CiA 301 0607 0012h / 0607 0013h otherwise), sign-extended for signed types.
pub fn decode_pnu_value(dt: PnuType, data: &[u8]) -> Result<i64, AbortCode> {
    let w = width(dt);
    if data.len() > w {
        return Err(AbortCode::TooLong);
    }
    if data.len() < w {
        return Err(AbortCode::TooShort);
    }
    let raw = data
        .iter()
        .rev()
        .fold(0u64, |acc, b| acc << 8 | u64::from(*b));
    Ok(match dt {
        PnuType::I8 => i64::from(raw as u8 as i8),
        PnuType::I16 => i64::from(raw as u16 as i16),
        PnuType::I32 => i64::from(raw as u32 as i32),
        _ => raw as i64,
    })
}

fn pnu_of(addr: Address) -> Option<u16> {
    (PNU_FIRST..=PNU_LAST)
        .contains(&addr.index)
        .then(|| addr.index - PNU_FIRST)
}

impl FestoApp {
    /// The drive core.
    pub fn drive(&self) -> &FhppDrive {
        &self.drive
    }
    /// The drive core, for fault injection and the axis' environment.
    pub fn drive_mut(&mut self) -> &mut FhppDrive {
        &mut self.drive
    }
}

impl DeviceHooks for FestoApp {
    fn check_write(
        &mut self,
        def: &EntryDef<'_>,
        data: &[u8],
        _state: NmtState,
    ) -> Result<(), AbortCode> {
        let a = def.addr;
        match a.index {
            // Static mapping (§5.4.4): "cannot be changed".
            0x1600..=0x1603 | 0x1A00..=0x1A03 => Err(AbortCode::ReadOnly),
            // Inhibit time: "0 fixed".
            0x1400..=0x1403 | 0x1800..=0x1803 if a.sub == 3 => Err(AbortCode::ReadOnly),
            // The guard time's range is the device's (MTR-DCI 0..32767 ms, seed-000 §7.3).
            0x100C => {
                let max = self.drive.variant().device().guard_time_max_ms;
                let v = u16::from_le_bytes([
                    data.first().copied().unwrap_or(0),
                    data.get(1).copied().unwrap_or(0),
                ]);
                match max {
                    Some(max) if v > max => Err(AbortCode::ValueTooHigh),
                    _ => Ok(()),
                }
            }
            0x6060 => {
                let code = data.first().map_or(0, |b| *b as i8);
                let m = OperationMode::from_code(code).map_err(|e| e.abort_code())?;
                if MTR_DCI_402.supports_mode(m) {
                    Ok(())
                } else {
                    Err(AbortCode::InvalidValue)
                }
            }
            0x6098 => {
                let code = data.first().map_or(0, |b| *b as i8);
                match HomingMethod::from_code(code) {
                    Ok(m) if MTR_DCI_402.supports_homing(m) => Ok(()),
                    _ => Err(AbortCode::InvalidValue),
                }
            }
            _ => Ok(()),
        }
    }

    fn app_size(&self, addr: Address) -> Option<Result<usize, AbortCode>> {
        pnu_size(&self.drive, addr)
    }

    fn app_read(
        &mut self,
        addr: Address,
        offset: usize,
        buf: &mut [u8],
    ) -> Option<Result<usize, AbortCode>> {
        pnu_read(&mut self.drive, addr, offset, buf)
    }

    fn app_write(
        &mut self,
        addr: Address,
        data: &[u8],
        _state: NmtState,
    ) -> Option<Result<(), AbortCode>> {
        pnu_write(&mut self.drive, addr, data)
    }
}

/// The size of a parameter object 2000h + PNU, or `None` if `addr` is not one: the SDO face of
/// the drive's parameter table, on CANopen and on EtherCAT (CoE) alike.
pub(crate) fn pnu_size(drive: &FhppDrive, addr: Address) -> Option<Result<usize, AbortCode>> {
    let pnu = pnu_of(addr)?;
    Some(
        drive
            .pnu_def(pnu, addr.sub)
            .map(|d| width(d.dtype))
            .map_err(|e| e.abort_code()),
    )
}

/// Reads a parameter object 2000h + PNU from `offset` into `buf`; `None` if not one.
pub(crate) fn pnu_read(
    drive: &mut FhppDrive,
    addr: Address,
    offset: usize,
    buf: &mut [u8],
) -> Option<Result<usize, AbortCode>> {
    let pnu = pnu_of(addr)?;
    let r = (|| {
        let dt = drive.pnu_def(pnu, addr.sub)?.dtype;
        let v = drive.read_pnu(pnu, addr.sub)?;
        Ok::<_, PnuError>((dt, v))
    })();
    Some(match r {
        Ok((dt, v)) => {
            let bytes = (v as u32).to_le_bytes();
            let value = bytes.get(..width(dt)).unwrap_or(&[]);
            let rest = value.get(offset..).unwrap_or(&[]);
            let n = rest.len().min(buf.len());
            buf[..n].copy_from_slice(&rest[..n]);
            Ok(n)
        }
        Err(e) => Err(e.abort_code()),
    })
}

/// Writes a parameter object 2000h + PNU; `None` if `addr` is not one.
pub(crate) fn pnu_write(
    drive: &mut FhppDrive,
    addr: Address,
    data: &[u8],
) -> Option<Result<(), AbortCode>> {
    let pnu = pnu_of(addr)?;
    let dt = match drive.pnu_def(pnu, addr.sub) {
        Ok(d) => d.dtype,
        Err(e) => return Some(Err(e.abort_code())),
    };
    Some(decode_pnu_value(dt, data).and_then(|v| {
        drive
            .write_pnu(pnu, addr.sub, v)
            .map_err(|e| e.abort_code())
    }))
}

// ---- the node ---------------------------------------------------------------------------------

/// EMCY codes raised and not yet reset, to clear them all on the drive's acknowledge.
const ACTIVE_EMCY: usize = 8;

/// The CiA 402 values [`FestoNode::mirror`] wrote (statusword, mode display, position, record
/// number) and the dictionary's generation right after.
#[derive(Debug, Clone, Copy)]
struct CiaMirror {
    inputs: (u16, i8, i32, u8),
    generation: u32,
}

/// The CiA 402 face's objects, found once in the node's dictionary: the face reads or writes
/// them on every frame.
#[derive(Debug, Clone, Copy)]
struct CiaObjects {
    controlword: Resolved,
    statusword: Resolved,
    mode: Resolved,
    mode_display: Resolved,
    position_actual: Resolved,
    position_internal: Resolved,
    target_position: Resolved,
    target_torque: Resolved,
    profile_velocity: Resolved,
    profile_acceleration: Resolved,
    profile_deceleration: Resolved,
    homing_method: Resolved,
    record_number: Resolved,
}

impl CiaObjects {
    fn resolve(od: &FestoOd) -> CiaObjects {
        CiaObjects {
            controlword: od.resolve(CONTROLWORD),
            statusword: od.resolve(STATUSWORD),
            mode: od.resolve(MODE),
            mode_display: od.resolve(MODE_DISPLAY),
            position_actual: od.resolve(POSITION_ACTUAL),
            position_internal: od.resolve(Address::new(0x6063, 0)),
            target_position: od.resolve(TARGET_POSITION),
            target_torque: od.resolve(TARGET_TORQUE),
            profile_velocity: od.resolve(PROFILE_VELOCITY),
            profile_acceleration: od.resolve(PROFILE_ACCELERATION),
            profile_deceleration: od.resolve(Address::new(0x6084, 0)),
            homing_method: od.resolve(HOMING_METHOD),
            record_number: od.resolve(RECORD_NUMBER),
        }
    }
}

/// A Festo FHPP drive on CANopen: the [`Device`] and the drive core, as one [`Endpoint`].
#[derive(Debug)]
pub struct FestoNode {
    dev: FestoDevice,
    input_mirror: Option<[u8; 8]>,
    reply_mirror: Option<[u8; 8]>,
    /// CiA 402 face: what [`FestoNode::mirror`] last wrote and the dictionary's generation
    /// after it. While neither changed, writing again would change nothing.
    cia_mirror: Option<CiaMirror>,
    emcy_active: heapless::Vec<u16, ACTIVE_EMCY>,
    obj: CiaObjects,
    /// The instant of the last [`FestoNode::advance`], while nothing has changed the node
    /// since: another advance to the same instant would find nothing to do.
    advanced_at: Option<Instant>,
}

impl core::fmt::Debug for FestoDevice {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("FestoDevice")
            .field("node", &self.node())
            .field("state", &self.state())
            .finish()
    }
}

impl FestoNode {
    /// Builds and powers on a node: `comm` the communication objects, `device` the objects
    /// its manual adds to them, `drive` the device core, `cia402` whether it speaks the CiA 402
    /// face instead of FHPP.
    pub fn build(
        node: NodeId,
        comm: &CommProfile,
        device: &[EntryDef<'static>],
        drive: DriveConfig,
        cia402: bool,
        now: Instant,
    ) -> Result<FestoNode, SimError> {
        let mut od = FestoOd::new();
        insert_communication_objects(&mut od, node, comm)?;
        od.insert_all(device)?;
        if cia402 {
            od.insert_all(&CIA402_OBJECTS)?;
        } else {
            od.insert_all(&FHPP_OBJECTS)?;
        }
        let mut drive = FhppDrive::new(drive)?;
        drive.start_at(now);
        let cia = cia402.then(|| Cia402Face::new(drive.axis().status().position as i32));
        let app = FestoApp { drive, cia };
        let mut dev = FestoDevice::new(node, od, comm.boot_up, app);
        dev.power_on(now);
        let obj = CiaObjects::resolve(dev.od());
        let mut n = FestoNode {
            dev,
            input_mirror: None,
            reply_mirror: None,
            cia_mirror: None,
            emcy_active: heapless::Vec::new(),
            obj,
            advanced_at: None,
        };
        n.advance(now);
        Ok(n)
    }

    /// The CANopen device (dictionary, NMT state).
    pub fn device(&self) -> &FestoDevice {
        &self.dev
    }
    /// The CANopen device, mutable.
    pub fn device_mut(&mut self) -> &mut FestoDevice {
        self.advanced_at = None;
        &mut self.dev
    }
    /// The drive core.
    pub fn drive(&self) -> &FhppDrive {
        &self.dev.hooks().drive
    }
    /// The drive core, for fault injection and the axis' environment.
    pub fn drive_mut(&mut self) -> &mut FhppDrive {
        self.advanced_at = None;
        &mut self.dev.hooks_mut().drive
    }
    /// The CiA 402 state, if the node speaks CiA 402.
    pub fn cia402_state(&self) -> Option<State> {
        self.dev.hooks().cia.as_ref().map(|c| c.sm.state())
    }

    /// Runs the drive up to `now` and brings the dictionary and the EMCYs up to date.
    fn advance(&mut self, now: Instant) {
        let app = self.dev.hooks_mut();
        let before = app.drive.next_cycle();
        app.drive.step_to(now);
        if app.drive.next_cycle() != before
            && let Some(cia) = app.cia.as_mut()
        {
            cia.after_cycle(&mut app.drive, now);
        }
        self.mirror();
        self.forward_emcy();
        self.advanced_at = Some(now);
    }

    /// Copies the drive's current images into the objects the TPDOs map.
    fn mirror(&mut self) {
        let app = self.dev.hooks();
        if let Some(cia) = app.cia.as_ref() {
            let sw = cia.statusword(&app.drive);
            let mode = cia.modes.active().code();
            let pos = app.drive.axis().status().position as i32;
            let record = cia.record;
            let inputs = (sw.0, mode, pos, record);
            // While the dictionary is as the last mirror left it, a value equal to the one
            // written then would change nothing: only the others are written.
            let last = self
                .cia_mirror
                .filter(|m| m.generation == self.dev.od().generation())
                .map(|m| m.inputs);
            let o = &self.obj;
            let od = self.dev.od_mut();
            if last.is_none_or(|l| l.0 != sw.0) {
                let _ = od.set_u16(o.statusword, sw.0);
            }
            if last.is_none_or(|l| l.1 != mode) {
                let _ = od.set_i8(o.mode_display, mode);
            }
            if last.is_none_or(|l| l.2 != pos) {
                // TPDO1 is re-sent only when the position moved by more than 1 inc (§7.4).
                let sent = od.get_i32(o.position_actual).unwrap_or(pos);
                if (i64::from(pos) - i64::from(sent)).abs() > 1 {
                    let _ = od.set_i32(o.position_actual, pos);
                }
                let _ = od.set_i32(o.position_internal, pos);
            }
            if last.is_none_or(|l| l.3 != record) {
                let _ = od.set_u8(o.record_number, record);
            }
            self.cia_mirror = Some(CiaMirror {
                inputs,
                generation: od.generation(),
            });
            return;
        }
        let input = app.drive.input();
        let reply = app.drive.fpc_reply();
        if self.input_mirror != Some(input) {
            self.input_mirror = Some(input);
            store_image(self.dev.od_mut(), &FHPP_IN, &input);
        }
        if self.reply_mirror != Some(reply) {
            self.reply_mirror = Some(reply);
            store_image(self.dev.od_mut(), &FPC_IN, &reply);
        }
    }

    fn forward_emcy(&mut self) {
        while let Some(e) = self.dev.hooks_mut().drive.poll_emcy() {
            if e.code == 0 {
                // The drive's acknowledge: every error it reported is gone; the last clear
                // sends the error-reset EMCY.
                while let Some(code) = self.emcy_active.pop() {
                    self.dev.clear_emcy(code);
                }
            } else if self.emcy_active.contains(&e.code) {
                // Reported again (EMCA: a refused acknowledge).
                self.dev.repeat_emcy(e.code, [0; 5]);
            } else {
                self.dev
                    .raise_emcy_with_register(e.code, e.register, [0; 5]);
                let _ = self.emcy_active.push(e.code);
            }
        }
    }

    fn drain_device_events(&mut self, now: Instant) {
        while let Some(e) = self.dev.poll_event() {
            match e {
                DeviceEvent::RpdoApplied { pdo: 1 } => self.rpdo1(now, true),
                DeviceEvent::RpdoApplied { pdo: 2 } => self.rpdo2(now),
                DeviceEvent::SdoWritten { addr }
                    if addr.index >= 0x6000 && self.dev.hooks().cia.is_some() =>
                {
                    // An SDO write of a CiA 402 object acts like its RPDO.
                    self.rpdo1(now, false)
                }
                DeviceEvent::Reset(kind) => self.after_reset(kind, now),
                DeviceEvent::LifeGuardingLost => {
                    self.dev
                        .hooks_mut()
                        .drive
                        .inject(Injection::LifeGuarding, true);
                    self.set_can_diagnosis(true);
                }
                DeviceEvent::LifeGuardingResumed => {
                    self.dev
                        .hooks_mut()
                        .drive
                        .inject(Injection::LifeGuarding, false);
                    self.set_can_diagnosis(false);
                }
                _ => {}
            }
        }
    }

    /// After an NMT reset the dictionary holds its defaults again: the images are re-mirrored.
    /// Reset node also restarts the application (E8): the drive powers on again, unreferenced.
    ///
    /// Never inlined: the new drive is built on the stack (tens of kilobytes), and inlined into
    /// `drain_device_events` that frame was reserved, page by page, on every frame the node
    /// handled.
    #[cold]
    #[inline(never)]
    fn after_reset(&mut self, kind: ResetKind, now: Instant) {
        if kind == ResetKind::Node {
            let app = self.dev.hooks_mut();
            let cfg = *app.drive.config();
            if let Ok(d) = FhppDrive::new(cfg) {
                app.drive = d;
                // The new drive's clock starts at the reset.
                app.drive.start_at(now);
            }
            let pos = app.drive.axis().status().position as i32;
            if app.cia.is_some() {
                app.cia = Some(Cia402Face::new(pos));
            }
            self.emcy_active.clear();
        }
        self.input_mirror = None;
        self.reply_mirror = None;
        self.cia_mirror = None;
        self.mirror();
    }

    /// PNU 206/1 (2FF2h/01): high nibble the NMT state, low nibble 2 = guarding error.
    fn set_can_diagnosis(&mut self, guarding_error: bool) {
        let nmt = match self.dev.state() {
            NmtState::Stopped => 0x10,
            NmtState::Operational => 0x40,
            _ => 0x20,
        };
        let v = nmt | if guarding_error { 2 } else { 0 };
        let _ = self.dev.hooks_mut().drive.set_pnu(206, 1, v);
    }

    /// RPDO1 applied (`from_pdo`) or a CiA 402 object written by SDO.
    fn rpdo1(&mut self, now: Instant, from_pdo: bool) {
        let cia = self.dev.hooks().cia.is_some();
        let o = &self.obj;
        if cia
            && from_pdo
            && self.dev.od().get_i8(o.mode) == Ok(OperationMode::ProfileTorque.code())
        {
            // In PT mode bytes 5..8 of RPDO1 are 6071h target torque (§7.4).
            let raw = self.dev.od().get_i32(o.target_position).unwrap_or(0);
            let t = raw.clamp(i32::from(i16::MIN), i32::from(i16::MAX)) as i16;
            let _ = self.dev.od_mut().set_i16(o.target_torque, t);
        }
        let od = self.dev.od();
        if cia {
            let cw = Controlword(od.get_u16(o.controlword).unwrap_or(0));
            let mode = od.get_i8(o.mode).unwrap_or(1);
            let record = od.get_u8(o.record_number).unwrap_or(0);
            let homing = od.get_i8(o.homing_method).unwrap_or(27);
            let torque = od.get_i16(o.target_torque).unwrap_or(0);
            let objects = PpObjects {
                target: od.get_i32(o.target_position).unwrap_or(0),
                velocity: od.get_u32(o.profile_velocity).unwrap_or(0),
                acceleration: od.get_u32(o.profile_acceleration).unwrap_or(0),
                deceleration: od.get_u32(o.profile_deceleration).unwrap_or(0),
            };
            let app = self.dev.hooks_mut();
            if let Some(cia) = app.cia.as_mut() {
                let input = CiaInput {
                    cw,
                    mode,
                    record,
                    homing,
                    objects,
                    torque,
                };
                cia.handle(&input, &mut app.drive, now);
            }
        } else {
            let out = load_image(od, &FHPP_OUT);
            self.dev.hooks_mut().drive.exchange(&out, now);
        }
        self.mirror();
    }

    fn rpdo2(&mut self, now: Instant) {
        if self.dev.hooks().cia.is_some() {
            // 6081h/6083h are latched at the next set-point edge.
            return;
        }
        let req = load_image(self.dev.od(), &FPC_OUT);
        self.dev.hooks_mut().drive.parameter(&req, now);
        self.mirror();
    }
}

/// The byte widths of an 8-byte image split over mapped objects (1, 1, 1, 1, 4 or 1, 1, 2, 4).
fn widths(addrs: &[Address]) -> &'static [usize] {
    if addrs.len() == 5 {
        &[1, 1, 1, 1, 4]
    } else {
        &[1, 1, 2, 4]
    }
}

fn store_image(od: &mut FestoOd, addrs: &[Address], image: &[u8; 8]) {
    let mut at = 0;
    for (a, w) in addrs.iter().zip(widths(addrs)) {
        if let Some(b) = image.get(at..at + w) {
            let _ = od.set_raw(*a, b);
        }
        at += w;
    }
}

fn load_image(od: &FestoOd, addrs: &[Address]) -> [u8; 8] {
    let mut out = [0u8; 8];
    let mut at = 0;
    for (a, w) in addrs.iter().zip(widths(addrs)) {
        if let (Ok(raw), Some(dst)) = (od.raw(*a), out.get_mut(at..at + w)) {
            let n = raw.len().min(*w);
            dst[..n].copy_from_slice(&raw[..n]);
        }
        at += w;
    }
    out
}

impl Endpoint for FestoNode {
    /// The device's identifiers only: another node's frame does not make the drive catch up,
    /// as a real drive's controller never hands it to the drive.
    fn accepts(&self, frame: &Frame) -> bool {
        self.dev.accepts(frame)
    }

    fn handle_frame(&mut self, frame: &Frame, now: Instant) {
        // The drive first catches up, so a SYNC samples the image of this instant.
        self.advance(now);
        self.dev.handle_frame(frame, now);
        self.drain_device_events(now);
        self.forward_emcy();
        self.advanced_at = None;
    }

    fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        // A station asks until nothing is left to send, all at one instant: the drive and
        // the dictionary are brought up to date once for them.
        if self.advanced_at != Some(now) {
            self.advance(now);
        }
        self.dev.poll_transmit(now)
    }

    fn poll_timeout(&self) -> Option<Instant> {
        earliest([self.dev.poll_timeout(), Some(self.drive().next_cycle())])
    }

    fn handle_timeout(&mut self, now: Instant) {
        self.advance(now);
        self.dev.handle_timeout(now);
        self.drain_device_events(now);
        self.forward_emcy();
        self.advanced_at = None;
    }
}

// ---- the CiA 402 face -------------------------------------------------------------------------

/// The RPDO1/SDO inputs of the CiA 402 face, in the manual's evaluation order (§7.4): mode,
/// record number, set-point, then the controlword.
#[derive(Debug, Clone, Copy)]
struct CiaInput {
    cw: Controlword,
    mode: i8,
    record: u8,
    homing: i8,
    objects: PpObjects,
    /// 6071h target torque, ‰ of the rated current.
    torque: i16,
}

/// What the face asked the drive core to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Job {
    /// A profile-position move (direct mode, or record select when `record` ≠ 0).
    Move {
        target: i32,
        percent: u8,
        record: u8,
    },
    /// Homing (HOM edge).
    Homing,
    /// Profile torque: FHPP direct force in % of the rated current; `stroke` = controlword
    /// bit 5 (stroke limitation on, E10).
    Force { percent: i32, stroke: bool },
}

/// Where a job stands in the FHPP START/ACK handshake.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// Waiting for the drive to be in S4 with ACK = 0.
    Pending,
    /// START/HOM raised; waiting for ACK.
    Started,
    /// START/HOM dropped; waiting for MC.
    Running,
    /// MC came. The job's image stays (a force is held, the direct mode stays selected).
    Done,
}

const SCON_ENABLED: u8 = 0x01;
const SCON_OPEN: u8 = 0x02;
const SCON_WARN: u8 = 0x04;
const SCON_FAULT: u8 = 0x08;
const SCON_24VL: u8 = 0x10;
const SPOS_ACK: u8 = 0x02;
const SPOS_MC: u8 = 0x04;
const SPOS_TEACH: u8 = 0x08;
const SPOS_MOV: u8 = 0x10;
const SPOS_DEV: u8 = 0x20;
const SPOS_REF: u8 = 0x80;
const SDIR_XLIM: u8 = 0x20;

/// The MTR-DCI's CiA 402 face over the FHPP drive core.
#[derive(Debug, Clone)]
struct Cia402Face {
    sm: DeviceStateMachine,
    modes: ModeSelector,
    pp: PpDevice,
    record: u8,
    job: Option<(Job, Phase)>,
    homing_failed: bool,
    reset_edge: bool,
    fault_seen: bool,
}

impl Cia402Face {
    fn new(position: i32) -> Cia402Face {
        let mut sm = DeviceStateMachine::new(MTR_DCI_402);
        sm.set_self_test_done(true);
        Cia402Face {
            sm,
            modes: ModeSelector::new(OperationMode::ProfilePosition),
            pp: PpDevice::new(&MTR_DCI_402, position),
            record: 0,
            job: None,
            homing_failed: false,
            reset_edge: false,
            fault_seen: false,
        }
    }

    /// Whether a job is under way (not yet at MC).
    fn busy(&self) -> bool {
        matches!(self.job, Some((_, p)) if p != Phase::Done)
    }

    fn handle(&mut self, i: &CiaInput, drive: &mut FhppDrive, now: Instant) {
        let _ = self.modes.request(i.mode, &MTR_DCI_402);
        let busy = self.busy();
        if self.modes.update(!busy).is_some() {
            // A new mode starts from a clean drive image.
            self.job = None;
            self.pp.reset(drive.axis().status().position as i32);
        }
        self.record = i.record;
        let before = self.sm.state();
        let prev = self.sm.controlword();
        self.sm.handle_controlword(i.cw);
        if i.cw.fault_reset() && !prev.fault_reset() {
            // Held until the drive's next cycle has sampled it (FHPP CCON.RESET edge).
            self.reset_edge = true;
        }
        let enabled = self.sm.state() == State::OperationEnabled;
        if before == State::OperationEnabled && !enabled {
            // Leaving Operation enabled drops every move.
            self.job = None;
            self.pp.reset(drive.axis().status().position as i32);
        }
        if prev.has(Controlword::HALT)
            && !i.cw.has(Controlword::HALT)
            && let Some((Job::Move { .. }, phase @ (Phase::Started | Phase::Running))) =
                self.job.as_mut()
        {
            // The halted move goes on (CiA 402): FHPP resumes it with a new START edge while
            // HALT is released (TA4).
            *phase = Phase::Pending;
        }
        let rising = i.cw.has(Controlword::NEW_SET_POINT) && !prev.has(Controlword::NEW_SET_POINT);
        if enabled {
            match self.modes.active() {
                OperationMode::ProfilePosition => {
                    let mut o = i.objects;
                    if i.record != 0 {
                        o.target = 0;
                    }
                    // 6083h from the PDO is the move's ramp, accelerating and braking, only
                    // with bit 15 (Tab. C/3); without it the stored ramp applies (0 here).
                    if !i.cw.has(Controlword::MTR_SYMMETRICAL_RAMP) {
                        o.acceleration = 0;
                    }
                    if let Some(PpAction::Start(m)) = self.pp.handle_controlword(i.cw, &o) {
                        self.start_move(m, drive);
                    }
                }
                OperationMode::Homing if rising && !busy => {
                    let _ = drive.write_pnu(1011, 0, i64::from(i.homing));
                    self.homing_failed = false;
                    self.job = Some((Job::Homing, Phase::Pending));
                }
                OperationMode::ProfileTorque if rising => {
                    let job = Job::Force {
                        percent: i32::from(i.torque) / 10,
                        stroke: i.cw.has(Controlword::CHANGE_SET_IMMEDIATELY),
                    };
                    self.job = Some((job, Phase::Pending));
                }
                _ => {}
            }
        }
        self.command(drive, now);
    }

    fn start_move(&mut self, m: Move, drive: &mut FhppDrive) {
        let vmax = stored_pnu(drive, 502).max(1);
        let percent = (u64::from(m.velocity) * 100 / vmax as u64).clamp(1, 100) as u8;
        // The FHPP image carries the speed in whole per cent; the move runs at 6081h itself.
        drive.set_direct_profile(DirectProfile {
            velocity: (m.velocity > 0).then_some(m.velocity),
            acceleration: (m.acceleration > 0).then_some(m.acceleration),
        });
        self.job = Some((
            Job::Move {
                target: m.target,
                percent,
                record: self.record,
            },
            Phase::Pending,
        ));
    }

    /// The FHPP control image for the current state and job, sent to the drive.
    fn command(&mut self, drive: &mut FhppDrive, now: Instant) {
        let state = self.sm.state();
        let input = drive.input();
        let cw = self.sm.controlword();
        let mut ccon = match state {
            State::OperationEnabled => 0x03,
            // Quick stop: STOP = 0, the drive brakes on its emergency ramp and stays enabled.
            State::QuickStopActive => 0x01,
            _ => 0x00,
        };
        // The HMI lock (controlword bit 14) maps to CCON.LOCK.
        if cw.has(Controlword::MTR_HMI_LOCKED) {
            ccon |= 0x20;
        }
        if self.reset_edge {
            ccon |= 0x08;
        }
        let mut cpos = if self.pp.halted() { 0x00 } else { 0x01 };
        if state == State::OperationEnabled {
            // Jog (levels) and teach (the drive takes the falling edge), Tab. C/3.
            let bits = [
                (Controlword::MTR_JOG_POSITIVE, 0x08),
                (Controlword::MTR_JOG_NEGATIVE, 0x10),
                (Controlword::MTR_TEACH, 0x20),
            ];
            for (b, c) in bits {
                if cw.has(b) {
                    cpos |= c;
                }
            }
        }
        let mut bytes = [0u8; 8];
        let ready = input[0] & (SCON_ENABLED | SCON_OPEN | SCON_FAULT) == SCON_ENABLED | SCON_OPEN;
        if let Some((job, phase)) = self.job.as_mut() {
            let edge = match job {
                Job::Homing => 0x04,
                Job::Move { .. } | Job::Force { .. } => 0x02,
            };
            match *job {
                Job::Move {
                    target,
                    percent,
                    record: 0,
                } => {
                    ccon |= 0x40;
                    let t = target.to_le_bytes();
                    bytes = [0, 0, 0, percent, t[0], t[1], t[2], t[3]];
                }
                Job::Move { record, .. } => bytes[2] = record,
                Job::Force { percent, stroke } => {
                    ccon |= 0x40;
                    let f = percent.to_le_bytes();
                    let cdir = 0x02 | if stroke { 0 } else { 0x20 };
                    bytes = [0, 0, cdir, 0, f[0], f[1], f[2], f[3]];
                }
                Job::Homing => {}
            }
            match phase {
                Phase::Pending if ready && input[1] & SPOS_ACK == 0 => {
                    *phase = Phase::Started;
                    cpos |= edge;
                }
                Phase::Started => cpos |= edge,
                _ => {}
            }
        }
        bytes[0] = ccon;
        bytes[1] = cpos;
        drive.exchange(&bytes, now);
    }

    /// After an internal cycle of the drive: the handshake and the fault state follow.
    fn after_cycle(&mut self, drive: &mut FhppDrive, now: Instant) {
        // The cycle just run sampled the RESET edge.
        self.reset_edge = false;
        let input = drive.input();
        let fault = input[0] & SCON_FAULT != 0;
        if fault && !self.fault_seen {
            self.sm.set_fault(true);
            self.sm.set_fault_reaction_done();
            // The cause is the drive's to judge: a refused acknowledge faults again.
            self.sm.set_fault(false);
            if matches!(self.job, Some((Job::Homing, _))) {
                self.homing_failed = true;
            }
            self.job = None;
            self.pp.reset(drive.axis().status().position as i32);
        }
        self.fault_seen = fault;
        self.pp.set_standstill(input[1] & SPOS_MOV == 0);
        let mut next = None;
        if let Some((job, phase)) = self.job.as_mut() {
            match phase {
                Phase::Started if input[1] & SPOS_ACK != 0 => *phase = Phase::Running,
                Phase::Running if input[1] & (SPOS_ACK | SPOS_MC) == SPOS_MC => {
                    *phase = Phase::Done;
                    if matches!(job, Job::Move { .. }) {
                        next = self.pp.move_finished();
                    }
                }
                _ => {}
            }
        }
        if let Some(m) = next {
            self.start_move(m, drive);
        }
        self.command(drive, now);
    }

    fn statusword(&self, drive: &FhppDrive) -> Statusword {
        let input = drive.input();
        let (scon, spos, sdir) = (input[0], input[1], input[2]);
        let set = |on: bool, bit: u16| if on { bit } else { 0 };
        let mut dynamic = set(scon & SCON_24VL != 0, Statusword::VOLTAGE_ENABLED)
            | set(scon & SCON_WARN != 0, Statusword::WARNING)
            | set(spos & SPOS_MOV != 0, Statusword::MTR_DRIVE_MOVES)
            | set(spos & SPOS_TEACH != 0, Statusword::MTR_TEACH_ACK)
            | set(spos & SPOS_REF != 0, Statusword::MTR_HOMING_PERFORMED);
        match self.modes.active() {
            OperationMode::Homing => {
                let homing = matches!(self.job, Some((Job::Homing, p)) if p != Phase::Done);
                dynamic |= set(
                    !homing && spos & SPOS_REF != 0,
                    Statusword::HOMING_ATTAINED | Statusword::TARGET_REACHED,
                ) | set(self.homing_failed, Statusword::HOMING_ERROR);
            }
            OperationMode::ProfileTorque => {
                let running = matches!(self.job, Some((Job::Force { .. }, _)));
                dynamic |= set(running, Statusword::BIT12)
                    | set(
                        matches!(self.job, Some((Job::Force { .. }, Phase::Done)))
                            && spos & SPOS_MC != 0,
                        Statusword::TARGET_REACHED,
                    )
                    | set(running && sdir & SDIR_XLIM != 0, Statusword::BIT13);
            }
            _ => {
                dynamic |= self.pp.status_bits().0
                    | set(spos & SPOS_DEV != 0, Statusword::FOLLOWING_ERROR);
            }
        }
        MTR_DCI_402.statusword(self.sm.state(), Statusword(dynamic))
    }
}

/// A parameter as stored, without the side effects of an SDO/FPC read.
fn stored_pnu(drive: &FhppDrive, pnu: u16) -> i64 {
    drive
        .store()
        .get(crate::fhpp::fpc::Param::new(pnu, 0))
        .unwrap_or(0)
}

// ---- the MTR-DCI ------------------------------------------------------------------------------

/// The MTR-DCI motor unit on CANopen, in its FHPP or CiA 402 profile.
#[derive(Debug)]
pub struct MtrDci(FestoNode);

/// A Festo device type is a [`FestoNode`] under its own name: it derefs to the node and is an
/// [`Endpoint`] through it.
macro_rules! festo_device {
    ($t:ident) => {
        impl core::ops::Deref for $t {
            type Target = $crate::sim::mtr_dci::FestoNode;
            fn deref(&self) -> &$crate::sim::mtr_dci::FestoNode {
                &self.0
            }
        }
        impl core::ops::DerefMut for $t {
            fn deref_mut(&mut self) -> &mut $crate::sim::mtr_dci::FestoNode {
                &mut self.0
            }
        }
        impl $crate::canopen::endpoint::Endpoint for $t {
            fn accepts(&self, frame: &$crate::can::Frame) -> bool {
                self.0.accepts(frame)
            }
            fn handle_frame(&mut self, frame: &$crate::can::Frame, now: $crate::time::Instant) {
                self.0.handle_frame(frame, now)
            }
            fn poll_transmit(&mut self, now: $crate::time::Instant) -> Option<$crate::can::Frame> {
                self.0.poll_transmit(now)
            }
            fn poll_timeout(&self) -> Option<$crate::time::Instant> {
                self.0.poll_timeout()
            }
            fn handle_timeout(&mut self, now: $crate::time::Instant) {
                self.0.handle_timeout(now)
            }
        }
    };
}
pub(crate) use festo_device;

impl MtrDci {
    /// A powered-on MTR-DCI (boot-up message queued) with the default axis.
    pub fn new(node: NodeId, profile: Profile, now: Instant) -> Result<MtrDci, SimError> {
        MtrDci::with_config(node, profile, DriveConfig::new(Variant::MtrDci), now)
    }

    /// A powered-on MTR-DCI with a drive configuration of its own (axis, start position...).
    pub fn with_config(
        node: NodeId,
        profile: Profile,
        cfg: DriveConfig,
        now: Instant,
    ) -> Result<MtrDci, SimError> {
        if cfg.variant != Variant::MtrDci {
            return Err(SimError::Profile(cfg.variant));
        }
        let (comm, cia) = match profile {
            Profile::Fhpp => (&MTR_DCI_FHPP, false),
            Profile::Cia402 => (&MTR_DCI_CIA402, true),
        };
        FestoNode::build(node, comm, &MTR_DCI_STRINGS, cfg, cia, now).map(MtrDci)
    }
}

festo_device!(MtrDci);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pnu_values_decode_by_width_and_sign() {
        assert_eq!(
            decode_pnu_value(PnuType::I32, &[0xFF, 0xFF, 0xFF, 0xFF]),
            Ok(-1)
        );
        assert_eq!(decode_pnu_value(PnuType::U16, &[0x34, 0x12]), Ok(0x1234));
        assert_eq!(decode_pnu_value(PnuType::I8, &[0x80]), Ok(-128));
        assert_eq!(
            decode_pnu_value(PnuType::U8, &[1, 2]),
            Err(AbortCode::TooLong)
        );
        assert_eq!(
            decode_pnu_value(PnuType::U32, &[1]),
            Err(AbortCode::TooShort)
        );
    }

    #[test]
    fn dictionary_has_the_static_fhpp_mapping_and_no_heartbeat() {
        let n = NodeId::new(1).unwrap();
        let d = MtrDci::new(n, Profile::Fhpp, Instant::ZERO).unwrap();
        let od = d.device().od();
        assert_eq!(od.get_u32(Address::new(0x1000, 0)), Ok(0x12D));
        assert_eq!(od.get_u32(Address::new(0x1018, 1)), Ok(0x1D));
        assert_eq!(od.get_u32(Address::new(0x1600, 5)), Ok(0x3004_0020));
        assert_eq!(od.get_u32(Address::new(0x1A01, 4)), Ok(0x3033_0020));
        assert_eq!(od.get_u32(Address::new(0x1401, 1)), Ok(0x301));
        assert_eq!(od.get_u8(Address::new(0x1800, 2)), Ok(255));
        assert!(od.entry(Address::new(0x1017, 0)).is_err());
        assert!(od.entry(Address::new(0x1800, 4)).is_err());
        assert!(od.entry(Address::new(0x100C, 0)).is_ok());
    }

    #[test]
    fn image_round_trips_through_the_mapped_objects() {
        let mut od = FestoOd::new();
        od.insert_all(&FHPP_OBJECTS).unwrap();
        let img = [0x13, 0x85, 0x01, 0x00, 0x78, 0x56, 0x34, 0x12];
        store_image(&mut od, &FHPP_IN, &img);
        assert_eq!(load_image(&od, &FHPP_IN), img);
        assert_eq!(od.get_i32(FHPP_IN[4]), Ok(0x1234_5678));
    }
}
