//! The TLC5xx object dictionary (digest §5): the CiA 301 communication objects with the
//! manual's PDO defaults, the DSP402 objects and the manufacturer objects the simulator runs,
//! with the manual's types, access rights, ranges and defaults.

use crate::canopen::device::{
    CommProfile, PdoDefault, identity_strings, insert_communication_objects,
};
use crate::canopen::nmt::BootUpStyle;
use crate::canopen::od::{AccessType, DataType, EntryDef, ObjectDictionary, OdError, Value};
use crate::canopen::{Address, NodeId};
use crate::cia402::objects as obj;

/// Entries of the dictionary (two 64-entry position lists take 520 of them).
pub const OD_ENTRIES: usize = 1024;
/// Bytes of values.
pub const OD_BYTES: usize = 8192;
/// The TLC5xx dictionary.
pub type TlcOd = ObjectDictionary<'static, OD_ENTRIES, OD_BYTES>;

/// 1000h: DSP402 (0192h), bit 17 "actuator" (digest §1.2), from the catalog.
pub const DEVICE_TYPE: u32 = crate::catalog::CIA402_DEVICE_TYPE;
/// 1018h:01 vendor-ID (SIG Positec, digest §5.1), from the catalog.
pub const VENDOR_ID: u32 = crate::catalog::TLC5XX_VENDOR_ID;
/// 1018h:02 product code (digest §5.1: 0), from the catalog.
const PRODUCT_CODE: u32 = match crate::catalog::TLC5XX.product_code {
    Some(p) => p,
    None => 0,
};
/// Entries per position list (sub 01h..40h).
pub const LIST_LEN: u8 = 64;

const fn m3(e: [crate::canopen::pdo::mapping::MappingEntry; 3]) -> [u32; 3] {
    [e[0].to_u32(), e[1].to_u32(), e[2].to_u32()]
}
const fn m2(e: [crate::canopen::pdo::mapping::MappingEntry; 2]) -> [u32; 2] {
    [e[0].to_u32(), e[1].to_u32()]
}
/// PDO1 at power-up: controlword / statusword (digest §2.4), from the catalog.
static RPDO1: &[u32] = crate::catalog::TLC_PDO1_POWER_UP.rpdo;
static RPDO2: [u32; 2] = m2(obj::TLC_RPDO2_MAPPING);
static RPDO3: [u32; 2] = m2(obj::TLC_RPDO3_MAPPING);
static RPDO4: [u32; 3] = m3(obj::TLC_RPDO4_MAPPING);
static TPDO1: &[u32] = crate::catalog::TLC_PDO1_POWER_UP.tpdo;
static TPDO2: [u32; 2] = m2(obj::TLC_TPDO2_MAPPING);
static TPDO3: [u32; 2] = m2(obj::TLC_TPDO3_MAPPING);
static TPDO4: [u32; 3] = m3(obj::TLC_TPDO4_MAPPING);

const fn pdo(valid: bool, transmission: u8, event_ms: u16, mapping: &'static [u32]) -> PdoDefault {
    PdoDefault {
        valid,
        transmission,
        event_ms,
        mapping,
        fixed: false,
    }
}

/// The communication profile (digest §2.4, §5.1): only PDO1 valid at power-up, PDO4 static
/// (type 254, T_PDO4 event timer 1000 ms), R/T_PDO2 and 3 type 0 (erratum A10), DS301 v4.0 PDO
/// parameters (sub00 = 5, no SYNC start value).
pub const fn comm_profile(boot_up: BootUpStyle) -> CommProfile {
    const fn fixed(mut p: PdoDefault) -> PdoDefault {
        p.fixed = true;
        p
    }
    CommProfile {
        device_type: DEVICE_TYPE,
        identity: [VENDOR_ID, PRODUCT_CODE, 0, 0],
        heartbeat: crate::catalog::TLC5XX.has_heartbeat(),
        heartbeat_ms: 0,
        guarding: crate::catalog::TLC5XX.guard_time_max_ms.is_some(),
        boot_up,
        rpdo: [
            pdo(true, 255, 0, RPDO1),
            pdo(false, 0, 0, &RPDO2),
            pdo(false, 0, 0, &RPDO3),
            fixed(pdo(false, 254, 0, &RPDO4)),
        ],
        tpdo: [
            pdo(true, 255, 0, TPDO1),
            pdo(false, 0, 0, &TPDO2),
            pdo(false, 0, 0, &TPDO3),
            fixed(pdo(false, 254, 1000, &TPDO4)),
        ],
        tpdo_sync_start: false,
    }
}

use AccessType::{Ro, Rw, Wo};
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

/// 1008h, 1009h, 100Ah.
const IDENTITY: [EntryDef<'static>; 3] = identity_strings(b"TLC53x  ", b"HW 1.00 ", b"SW 1.00 ");

/// Scalar objects: `R` = RPDO-mappable (rw), `T` = TPDO-mappable (ro).
const OBJECTS: &[EntryDef<'static>] = &[
    // ---- CiA 301 objects insert_communication_objects does not add -----------------------
    e(0x1002, 0, "manufacturer status register", U32, Ro),
    e(0x1016, 0, "consumer heartbeat time", U8, Ro).default_value(u(1)),
    e(0x1016, 1, "consumer heartbeat time 1", U32, Rw),
    // ---- DSP402 -------------------------------------------------------------------------
    e(0x603F, 0, "error code", U16, Ro).mappable(),
    e(0x6040, 0, "controlword", U16, Rw).mappable(),
    e(0x6041, 0, "statusword", U16, Ro).mappable(),
    // Erratum A17: 6060h is printed write-only; the simulator also lets it be read.
    e(0x6060, 0, "modes of operation", I8, Rw)
        .mappable()
        .default_value(s(1)),
    e(0x6061, 0, "modes of operation display", I8, Ro)
        .mappable()
        .default_value(s(1)),
    e(0x6063, 0, "position actual value (inc)", I32, Ro).mappable(),
    e(0x6064, 0, "position actual value", I32, Ro).mappable(),
    e(0x6068, 0, "position window time", U16, Rw).default_value(u(16)),
    e(0x6069, 0, "velocity sensor actual value", I32, Ro).mappable(),
    e(0x606C, 0, "velocity actual value", I32, Ro).mappable(),
    e(0x607A, 0, "target position", I32, Rw).mappable(),
    e(0x607D, 0, "software position limit", U8, Ro).default_value(u(2)),
    e(0x607D, 1, "min position limit", I32, Rw).default_value(s(i32::MIN as i64)),
    e(0x607D, 2, "max position limit", I32, Rw).default_value(s(i32::MAX as i64)),
    e(0x607F, 0, "max profile velocity", U32, Rw)
        .default_value(u(3000))
        .limits(u(1), u(12000)),
    e(0x6081, 0, "profile velocity", U32, Rw)
        .mappable()
        .default_value(u(60)),
    e(0x6083, 0, "profile acceleration", U32, Rw)
        .mappable()
        .default_value(u(600))
        .limits(u(60), u(2_000_000)),
    e(0x6084, 0, "profile deceleration", U32, Rw)
        .mappable()
        .default_value(u(600))
        .limits(u(60), u(2_000_000)),
    e(0x6085, 0, "quick stop deceleration", U32, Rw)
        .default_value(u(600))
        .limits(u(60), u(2_000_000)),
    e(0x6086, 0, "motion profile type", I16, Rw).limits(s(-1), s(0)),
    e(0x6093, 0, "position factor", U8, Ro).default_value(u(2)),
    e(0x6093, 1, "pNormNum", I32, Rw)
        .default_value(s(1))
        .limits(s(1), s(i32::MAX as i64)),
    e(0x6093, 2, "pNormDen", I32, Rw)
        .default_value(s(16384))
        .limits(s(1), s(i32::MAX as i64)),
    e(0x6094, 0, "velocity encoder factor", U8, Ro).default_value(u(2)),
    e(0x6094, 1, "vNormNum", I32, Rw)
        .default_value(s(1))
        .limits(s(1), s(i32::MAX as i64)),
    e(0x6094, 2, "vNormDen", I32, Rw)
        .default_value(s(1))
        .limits(s(1), s(i32::MAX as i64)),
    e(0x6097, 0, "acceleration factor", U8, Ro).default_value(u(2)),
    e(0x6097, 1, "aNormNum", I32, Rw)
        .default_value(s(1))
        .limits(s(1), s(i32::MAX as i64)),
    e(0x6097, 2, "aNormDen", I32, Rw)
        .default_value(s(1))
        .limits(s(1), s(i32::MAX as i64)),
    e(0x6098, 0, "homing method", I8, Rw).default_value(s(18)),
    e(0x6099, 0, "homing speeds", U8, Ro).default_value(u(2)),
    e(0x6099, 1, "speed during search for switch", I32, Rw)
        .default_value(s(60))
        .limits(s(1), s(12000)),
    e(0x6099, 2, "speed during search for zero", I32, Rw)
        .default_value(s(6))
        .limits(s(1), s(12000)),
    e(0x60F4, 0, "following error actual value", I32, Ro).mappable(),
    e(0x60FD, 0, "digital inputs", U32, Ro).mappable(),
    e(0x60FE, 0, "digital outputs", U8, Ro).default_value(u(2)),
    e(0x60FE, 1, "physical outputs", U32, Rw).mappable(),
    e(0x60FE, 2, "bit mask", U32, Rw),
    e(0x60FF, 0, "target velocity", I32, Rw).mappable(),
    e(0x6404, 0, "motor manufacturer", DataType::VisibleString, Ro)
        .capacity(16)
        .default_value(Value::Bytes(b"SIG Positec BL")),
    e(0x6510, 0, "drive data", U8, Ro).default_value(u(2)),
    e(0x6510, 1, "I_maxPA", U16, Ro).default_value(u(1000)),
    e(0x6510, 2, "I_nomPA", U16, Ro).default_value(u(300)),
    // ---- manufacturer --------------------------------------------------------------------
    e(0x2007, 0, "serial_number", U32, Ro),
    e(0x2008, 0, "eeprSave", U16, Wo),
    e(0x2009, 0, "default", U16, Wo).limits(u(0), u(6)),
    e(0x2010, 0, "p_maxDiff", U32, Rw)
        .default_value(u(16384))
        .limits(u(0), u(131072)),
    e(0x2011, 0, "p_win", U16, Rw).default_value(u(10)),
    e(0x2012, 0, "p_winTime", U16, Rw).default_value(u(16)),
    e(0x2013, 0, "p_DifPeak", U32, Rw),
    e(0x2040, 0, "driveCtrl", U16, Rw)
        .mappable()
        .limits(u(0), u(15)),
    e(0x2041, 0, "driveStat", U16, Ro).mappable(),
    e(0x2042, 0, "xMode_act", U16, Ro).mappable(),
    e(0x2046, 0, "SignEnabl", U16, Rw).default_value(u(15)),
    e(0x2047, 0, "SignLevel", U16, Rw),
    e(0x2048, 0, "Sign_SR", U16, Ro).mappable(),
    e(0x2049, 0, "FltSig", U32, Ro),
    e(0x204A, 0, "FltSig_SR", U32, Ro),
    e(0x204B, 0, "action_st", U16, Ro),
    e(0x204C, 0, "SignQstop", U16, Rw),
    e(0x204D, 0, "I_maxSTOP", U16, Rw)
        .default_value(u(1000))
        .limits(u(0), u(29999)),
    e(0x204F, 0, "Flt_pDiff", U16, Rw)
        .default_value(u(3))
        .limits(u(1), u(3)),
    e(0x2052, 0, "SW_LimP", I32, Rw).default_value(s(i32::MAX as i64)),
    e(0x2053, 0, "SW_LimN", I32, Rw).default_value(s(i32::MIN as i64)),
    e(0x2054, 0, "SW_Enabl", U16, Rw),
    e(0x205A, 0, "n_max0", U16, Rw)
        .default_value(u(3000))
        .limits(u(1), u(12000)),
    e(0x205C, 0, "v_target0", U32, Rw).default_value(u(60)),
    e(0x205E, 0, "acc", U32, Rw)
        .default_value(u(600))
        .limits(u(60), u(2_000_000)),
    e(0x205F, 0, "dec", U32, Rw)
        .default_value(u(600))
        .limits(u(60), u(2_000_000)),
    e(0x2062, 0, "IntSigSr", U32, Ro).mappable(),
    e(0x2073, 0, "p_dif", I32, Ro).mappable(),
    e(0x2089, 0, "p_actusr", I32, Ro).mappable(),
    e(0x208A, 0, "v_jerkusr", I32, Ro).mappable(),
    e(0x208C, 0, "p_remaind", I32, Ro),
    e(0x2090, 0, "p_absPTP", I32, Rw).mappable(),
    e(0x2091, 0, "StatePTP", U16, Ro)
        .mappable()
        .default_value(u(1 << 14)),
    e(0x2092, 0, "p_relPTP", I32, Rw).mappable(),
    e(0x2093, 0, "continue", U16, Rw),
    e(0x2094, 0, "v_tarPTP", I32, Rw).mappable(),
    e(0x20B4, 0, "startList", U16, Rw)
        .mappable()
        .limits(u(0), u(2)),
    e(0x20B5, 0, "stateList", U16, Ro).mappable(),
    e(0x20B7, 0, "cntList1", U16, Rw)
        .default_value(u(64))
        .limits(u(0), u(64)),
    e(0x20B8, 0, "bgnList1", U16, Rw).limits(u(0), u(63)),
    e(0x20B9, 0, "endList1", U16, Rw)
        .default_value(u(63))
        .limits(u(0), u(63)),
    e(0x20BA, 0, "actList1", I16, Ro).default_value(s(-1)),
    e(0x20BD, 0, "cntList2", U16, Rw)
        .default_value(u(64))
        .limits(u(0), u(64)),
    e(0x20BE, 0, "bgnList2", U16, Rw).limits(u(0), u(63)),
    e(0x20BF, 0, "endList2", U16, Rw)
        .default_value(u(63))
        .limits(u(0), u(63)),
    e(0x20C0, 0, "actList2", I16, Ro).default_value(s(-1)),
    e(0x20E8, 0, "v_tar16", U16, Rw).mappable(),
    e(0x20E9, 0, "ramp", U16, Rw)
        .mappable()
        .default_value(u(600)),
    e(0x20EB, 0, "v_jerk16", U16, Ro).mappable(),
    e(0x20F1, 0, "stateHome", U16, Ro).mappable(),
    e(0x20F3, 0, "p_outHome", U32, Rw),
    e(0x20F4, 0, "p_disHome", U32, Rw).default_value(u(200)),
    e(0x20F6, 0, "startSetp", I32, Rw).mappable(),
];

/// Inserts an array object: sub00 = `len` (ro), sub01..=len of type `t`.
fn insert_array(
    od: &mut TlcOd,
    index: u16,
    name: &'static str,
    t: DataType,
    len: u8,
    default: Value<'static>,
    limits: Option<(Value<'static>, Value<'static>)>,
) -> Result<(), OdError> {
    od.insert(e(index, 0, "number of entries", U8, Ro).default_value(u(len as u64)))?;
    for sub in 1..=len {
        let mut d = e(index, sub, name, t, Rw).default_value(default);
        if let Some((lo, hi)) = limits {
            d = d.limits(lo, hi);
        }
        od.insert(d)?;
    }
    Ok(())
}

/// The dictionary of a TLC5xx with node-ID `node` and boot-up style `boot_up`.
pub fn tlc_od(node: NodeId, boot_up: BootUpStyle) -> Result<TlcOd, OdError> {
    let mut od = TlcOd::new();
    insert_communication_objects(&mut od, node, &comm_profile(boot_up))?;
    od.insert_all(&IDENTITY)?;
    od.insert_all(OBJECTS)?;
    // 2400h: the last 20 error numbers (newest in sub 01h).
    insert_array(&mut od, 0x2400, "Error-Field", U16, 20, u(0), None)?;
    for base in [0x2200u16, 0x2300] {
        insert_array(
            &mut od,
            base,
            "list type",
            U16,
            LIST_LEN,
            u(1),
            Some((u(1), u(2))),
        )?;
        insert_array(
            &mut od,
            base + 1,
            "list position",
            I32,
            LIST_LEN,
            s(0),
            None,
        )?;
        insert_array(
            &mut od,
            base + 2,
            "list signal",
            U16,
            LIST_LEN,
            u(0),
            Some((u(0), u(1))),
        )?;
        insert_array(
            &mut od,
            base + 3,
            "list velocity",
            I32,
            LIST_LEN,
            s(0),
            None,
        )?;
    }
    Ok(od)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dictionary_builds_with_the_manual_defaults() {
        let n = NodeId::new(1).unwrap();
        let od = tlc_od(n, BootUpStyle::Ds301).unwrap();
        let a = Address::new;
        assert_eq!(od.get_u32(a(0x1000, 0)), Ok(DEVICE_TYPE));
        assert_eq!(od.get_u32(a(0x1018, 1)), Ok(VENDOR_ID));
        assert_eq!(od.get_u32(a(0x1400, 1)), Ok(0x201));
        assert_eq!(od.get_u32(a(0x1401, 1)), Ok(0x8000_0301));
        assert_eq!(od.get_u8(a(0x1401, 2)), Ok(0));
        assert_eq!(od.get_u8(a(0x1403, 2)), Ok(254));
        assert_eq!(od.get_u32(a(0x1603, 1)), Ok(0x2090_0020));
        assert_eq!(od.get_u32(a(0x1A03, 2)), Ok(0x20EB_0010));
        assert_eq!(od.get_u16(a(0x1803, 5)), Ok(1000));
        assert_eq!(od.get_u8(a(0x1800, 0)), Ok(5));
        assert_eq!(od.get_i32(a(0x6093, 2)), Ok(16384));
        assert_eq!(od.get_i8(a(0x6098, 0)), Ok(18));
        assert_eq!(od.get_i32(a(0x607D, 1)), Ok(i32::MIN));
        assert_eq!(od.get_i16(a(0x20BA, 0)), Ok(-1));
        assert_eq!(od.get_u8(a(0x2301, 0)), Ok(64));
        assert_eq!(
            od.entry(a(0x1401, 4)).err(),
            Some(crate::canopen::AbortCode::NoSubIndex)
        );
    }
}
