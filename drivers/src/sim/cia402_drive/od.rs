//! The generic CiA 402 drive's built-in object dictionary (`plcopen-and-cia402-csp.md` §10
//! "Minimal object dictionary", plus what PP, PV, HM and the cyclic synchronous modes read):
//! the CiA 301 communication objects with the CiA 402-3 default PDOs, and the CiA 402 objects.
//!
//! Units: positions in encoder increments, velocities in inc/s, accelerations in inc/s² (no
//! factor group: 6091h/6092h/6093h are absent, so the user unit is the increment), torques in
//! per mille of the rated torque.

use crate::canopen::device::{
    CommProfile, PdoDefault, identity_strings, insert_communication_objects,
};
use crate::canopen::nmt::BootUpStyle;
use crate::canopen::od::{AccessType, DataType, EntryDef, ObjectDictionary, OdError, Value};
use crate::canopen::{Address, NodeId};
use crate::catalog::{CIA402_PDO1_POWER_UP, CIA402_SIM_PRODUCT_CODE, CIA402_SIM_VENDOR_ID};

/// Entries of the dictionary (the built-in one uses about 200; an EDS may bring more).
pub const OD_ENTRIES: usize = 512;
/// Bytes of values.
pub const OD_BYTES: usize = 4096;
/// The generic drive's dictionary.
pub type GenericOd = ObjectDictionary<'static, OD_ENTRIES, OD_BYTES>;

/// 1000h: CiA 402 (0192h), servo drive (type 02h), from the catalog.
pub const DEVICE_TYPE: u32 = crate::catalog::CIA402_DEVICE_TYPE;
/// 6502h: the modes of [`crate::cia402::GENERIC`]: PP, PV, HM, CSP, CSV, CST (03A5h).
pub const SUPPORTED_MODES: u32 = 0x03A5;

/// The CiA 402-3 default mappings (§10 "Profile-defined default PDO mappings").
static RPDO2: [u32; 2] = [0x6040_0010, 0x6060_0008];
static RPDO3: [u32; 2] = [0x6040_0010, 0x607A_0020];
static RPDO4: [u32; 2] = [0x6040_0010, 0x60FF_0020];
static TPDO2: [u32; 2] = [0x6041_0010, 0x6061_0008];
static TPDO3: [u32; 2] = [0x6041_0010, 0x6064_0020];
static TPDO4: [u32; 2] = [0x6041_0010, 0x606C_0020];

const fn pdo(valid: bool, mapping: &'static [u32]) -> PdoDefault {
    PdoDefault {
        valid,
        // 255: applied on reception / sent on change; a CSx master makes them type 1.
        transmission: 255,
        event_ms: 0,
        mapping,
        fixed: false,
    }
}

/// The communication profile: the predefined connection set, PDO1 valid at power-up (the others
/// invalid until a master configures them, so an unconfigured drive sends one TPDO only), all
/// mappings dynamic, CiA 301 v4.2 PDO parameters (TPDO sub06 SYNC start value), heartbeat and
/// node guarding available.
pub const fn comm_profile() -> CommProfile {
    CommProfile {
        device_type: DEVICE_TYPE,
        identity: [CIA402_SIM_VENDOR_ID, CIA402_SIM_PRODUCT_CODE, 1, 0],
        heartbeat: true,
        heartbeat_ms: 0,
        guarding: true,
        boot_up: BootUpStyle::Ds301,
        rpdo: [
            pdo(true, CIA402_PDO1_POWER_UP.rpdo),
            pdo(false, &RPDO2),
            pdo(false, &RPDO3),
            pdo(false, &RPDO4),
        ],
        tpdo: [
            pdo(true, CIA402_PDO1_POWER_UP.tpdo),
            pdo(false, &TPDO2),
            pdo(false, &TPDO3),
            pdo(false, &TPDO4),
        ],
        tpdo_sync_start: true,
    }
}

use AccessType::{Ro, Rw};
use DataType::{Integer8 as I8, Integer16 as I16, Integer32 as I32};
use DataType::{Unsigned8 as U8, Unsigned16 as U16, Unsigned32 as U32};

const fn e(
    index: u16,
    sub: u8,
    name: &'static str,
    t: DataType,
    a: AccessType,
) -> EntryDef<'static> {
    EntryDef::new(Address::new(index, sub), name, t, a)
}
const fn u(v: u64) -> Value<'static> {
    Value::Unsigned(v)
}
const fn s(v: i64) -> Value<'static> {
    Value::Signed(v)
}

/// Default 607Fh / motor speed limit, inc/s (6000 rpm of a 10 000-increment encoder).
pub const MAX_VELOCITY: u32 = 1_000_000;

/// 1008h, 1009h, 100Ah.
const IDENTITY: [EntryDef<'static>; 3] = identity_strings(b"CiA 402 drive", b"sim 1", b"sim 1");

/// The objects beyond what `insert_communication_objects` adds.
const OBJECTS: &[EntryDef<'static>] = &[
    e(0x603F, 0, "error code", U16, Ro).mappable(),
    e(0x6040, 0, "controlword", U16, Rw).mappable(),
    e(0x6041, 0, "statusword", U16, Ro).mappable(),
    e(0x605A, 0, "quick stop option code", I16, Rw)
        .default_value(s(2))
        .limits(s(0), s(8)),
    e(0x605B, 0, "shutdown option code", I16, Rw).limits(s(0), s(1)),
    e(0x605C, 0, "disable operation option code", I16, Rw)
        .default_value(s(1))
        .limits(s(0), s(1)),
    e(0x605D, 0, "halt option code", I16, Rw)
        .default_value(s(1))
        .limits(s(1), s(4)),
    e(0x605E, 0, "fault reaction option code", I16, Rw)
        .default_value(s(2))
        .limits(s(0), s(4)),
    // Power-up mode: profile position (CiA 402 leaves it to the device; 0 "no mode" is not
    // offered, so 6061h always names a mode).
    e(0x6060, 0, "modes of operation", I8, Rw)
        .mappable()
        .default_value(s(1)),
    e(0x6061, 0, "modes of operation display", I8, Ro)
        .mappable()
        .default_value(s(1)),
    e(0x6064, 0, "position actual value", I32, Ro).mappable(),
    e(0x6065, 0, "following error window", U32, Rw).default_value(u(10_000)),
    e(0x6066, 0, "following error time out", U16, Rw).default_value(u(10)),
    e(0x6067, 0, "position window", U32, Rw).default_value(u(10)),
    e(0x6068, 0, "position window time", U16, Rw),
    e(0x606C, 0, "velocity actual value", I32, Ro).mappable(),
    e(0x6071, 0, "target torque", I16, Rw).mappable(),
    e(0x6072, 0, "max torque", U16, Rw)
        .mappable()
        .default_value(u(3000)),
    e(0x6077, 0, "torque actual value", I16, Ro).mappable(),
    e(0x607A, 0, "target position", I32, Rw).mappable(),
    e(0x607C, 0, "home offset", I32, Rw),
    e(0x607D, 0, "software position limit", U8, Ro).default_value(u(2)),
    e(0x607D, 1, "min position limit", I32, Rw).default_value(s(i32::MIN as i64)),
    e(0x607D, 2, "max position limit", I32, Rw).default_value(s(i32::MAX as i64)),
    e(0x607F, 0, "max profile velocity", U32, Rw)
        .mappable()
        .default_value(u(MAX_VELOCITY as u64))
        .limits(u(1), u(MAX_VELOCITY as u64)),
    e(0x6081, 0, "profile velocity", U32, Rw)
        .mappable()
        .default_value(u(100_000)),
    e(0x6083, 0, "profile acceleration", U32, Rw)
        .mappable()
        .default_value(u(1_000_000))
        .limits(u(1), u(u32::MAX as u64)),
    e(0x6084, 0, "profile deceleration", U32, Rw)
        .mappable()
        .default_value(u(1_000_000))
        .limits(u(1), u(u32::MAX as u64)),
    e(0x6085, 0, "quick stop deceleration", U32, Rw)
        .default_value(u(10_000_000))
        .limits(u(1), u(u32::MAX as u64)),
    e(0x6098, 0, "homing method", I8, Rw).default_value(s(35)),
    e(0x6099, 0, "homing speeds", U8, Ro).default_value(u(2)),
    e(0x6099, 1, "speed during search for switch", U32, Rw)
        .default_value(u(50_000))
        .limits(u(1), u(MAX_VELOCITY as u64)),
    e(0x6099, 2, "speed during search for zero", U32, Rw)
        .default_value(u(5_000))
        .limits(u(1), u(MAX_VELOCITY as u64)),
    e(0x609A, 0, "homing acceleration", U32, Rw)
        .default_value(u(1_000_000))
        .limits(u(1), u(u32::MAX as u64)),
    e(0x60B0, 0, "position offset", I32, Rw).mappable(),
    e(0x60B1, 0, "velocity offset", I32, Rw).mappable(),
    e(0x60B2, 0, "torque offset", I16, Rw).mappable(),
    e(0x60C2, 0, "highest sub-index supported", U8, Ro).default_value(u(2)),
    e(0x60C2, 1, "interpolation time period value", U8, Rw).default_value(u(1)),
    e(0x60C2, 2, "interpolation time index", I8, Rw)
        .default_value(s(-3))
        .limits(s(-6), s(-3)),
    e(0x60F4, 0, "following error actual value", I32, Ro).mappable(),
    e(0x60FF, 0, "target velocity", I32, Rw).mappable(),
    e(0x6502, 0, "supported drive modes", U32, Ro).default_value(u(SUPPORTED_MODES as u64)),
];

/// The built-in dictionary of a generic drive with node-ID `node`.
pub fn generic_od(node: NodeId) -> Result<GenericOd, OdError> {
    let mut od = GenericOd::new();
    insert_communication_objects(&mut od, node, &comm_profile())?;
    od.insert_all(&IDENTITY)?;
    od.insert_all(OBJECTS)?;
    Ok(od)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dictionary_builds_with_the_profile_defaults() {
        let od = generic_od(NodeId::new(3).unwrap()).unwrap();
        let a = Address::new;
        assert_eq!(od.get_u32(a(0x1000, 0)), Ok(0x0002_0192));
        assert_eq!(od.get_u32(a(0x1018, 2)), Ok(0x402));
        assert_eq!(od.get_u32(a(0x1400, 1)), Ok(0x203));
        assert_eq!(od.get_u32(a(0x1401, 1)), Ok(0x8000_0303));
        assert_eq!(od.get_u32(a(0x1601, 2)), Ok(0x6060_0008));
        assert_eq!(od.get_u32(a(0x1A03, 2)), Ok(0x606C_0020));
        assert_eq!(od.get_u32(a(0x6502, 0)), Ok(SUPPORTED_MODES));
        assert_eq!(
            crate::cia402::GENERIC.supported_drive_modes(),
            SUPPORTED_MODES
        );
        assert_eq!(od.get_i8(a(0x60C2, 2)), Ok(-3));
        // docs/simulators.md gives the count.
        assert_eq!(od.len(), 186);
    }
}
