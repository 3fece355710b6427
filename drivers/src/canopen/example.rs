//! An example CiA 301 / CiA 402-style device: a dictionary with the communication objects of a
//! TLC5xx-like drive (only PDO1 valid at power-up), a few drive objects and two DOMAINs. The
//! integration tests and the virtual-bus demo use it; real device models live in `sim`.

use super::device::{CommProfile, Device, NoHooks, PdoDefault, insert_communication_objects};
use super::od::{AccessType, DataType, EntryDef, ObjectDictionary, Value};
use super::{Address, NodeId};
use crate::time::Instant;

/// The dictionary of the example device: 160 entries, 16 KiB of values.
pub type ExampleOd = ObjectDictionary<'static, 160, 16384>;
/// The example device: SDO downloads up to 4 KiB.
pub type ExampleDevice = Device<'static, 160, 16384, 4096, NoHooks>;

/// A 1 KiB read-only DOMAIN.
pub const DOMAIN_1K: Address = Address::new(0x2000, 0);
/// A 4 KiB writable DOMAIN.
pub const DOMAIN_4K: Address = Address::new(0x2001, 0);
/// Controlword (RPDO-mappable).
pub const CONTROLWORD: Address = Address::new(0x6040, 0);
/// Statusword (TPDO-mappable).
pub const STATUSWORD: Address = Address::new(0x6041, 0);
/// Position actual value (TPDO-mappable).
pub const POSITION: Address = Address::new(0x6064, 0);
/// Target position (RPDO-mappable).
pub const TARGET: Address = Address::new(0x607A, 0);
/// A digital input byte, mapped bit-wise in tests.
pub const INPUTS: Address = Address::new(0x60FD, 0);

/// The 1 KiB pattern stored in [`DOMAIN_1K`].
pub static PATTERN_1K: [u8; 1024] = {
    let mut a = [0u8; 1024];
    let mut i = 0;
    while i < 1024 {
        a[i] = (i * 7 + 3) as u8;
        i += 1;
    }
    a
};

/// The communication profile of the example device: TLC5xx-like PDO defaults (only PDO1 valid).
pub const PROFILE: CommProfile = CommProfile {
    rpdo: [
        PdoDefault {
            valid: true,
            transmission: 255,
            event_ms: 0,
            mapping: &[0x6040_0010],
            fixed: false,
        },
        PdoDefault {
            valid: false,
            transmission: 0,
            event_ms: 0,
            mapping: &[0x6040_0010, 0x607A_0020],
            fixed: false,
        },
        PdoDefault::ABSENT,
        PdoDefault::ABSENT,
    ],
    tpdo: [
        PdoDefault {
            valid: true,
            transmission: 255,
            event_ms: 0,
            mapping: &[0x6041_0010],
            fixed: false,
        },
        PdoDefault {
            valid: false,
            transmission: 0,
            event_ms: 0,
            mapping: &[0x6041_0010, 0x6064_0020],
            fixed: false,
        },
        PdoDefault::ABSENT,
        PdoDefault::ABSENT,
    ],
    identity: [0x0000_0059, 0x0005_0001, 0x0001_0000, 0x1234_5678],
    ..CommProfile::basic(0x0002_0192)
};

/// The example device's dictionary for `node`.
pub fn example_od(node: NodeId) -> ExampleOd {
    let mut od = ExampleOd::new();
    insert_communication_objects(&mut od, node, &PROFILE).expect("communication objects fit");
    let defs = [
        EntryDef::new(DOMAIN_1K, "1 KiB domain", DataType::Domain, AccessType::Ro)
            .capacity(1024)
            .default_value(Value::Bytes(&PATTERN_1K)),
        EntryDef::new(DOMAIN_4K, "4 KiB domain", DataType::Domain, AccessType::Rw).capacity(4096),
        EntryDef::new(
            CONTROLWORD,
            "controlword",
            DataType::Unsigned16,
            AccessType::Rww,
        )
        .mappable(),
        EntryDef::new(
            STATUSWORD,
            "statusword",
            DataType::Unsigned16,
            AccessType::Rwr,
        )
        .mappable()
        .default_value(Value::Unsigned(0x0040)),
        EntryDef::new(
            POSITION,
            "position actual value",
            DataType::Integer32,
            AccessType::Rwr,
        )
        .mappable(),
        EntryDef::new(
            TARGET,
            "target position",
            DataType::Integer32,
            AccessType::Rww,
        )
        .mappable(),
        EntryDef::new(
            INPUTS,
            "digital inputs",
            DataType::Unsigned8,
            AccessType::Rwr,
        )
        .mappable(),
        EntryDef::new(
            Address::new(0x6083, 0),
            "profile acceleration",
            DataType::Unsigned32,
            AccessType::Rw,
        ),
        EntryDef::new(
            Address::new(0x6060, 0),
            "modes of operation",
            DataType::Integer8,
            AccessType::Rw,
        ),
    ];
    od.insert_all(&defs).expect("application objects fit");
    od
}

/// A powered-on example device.
pub fn example_device(node: NodeId, now: Instant) -> ExampleDevice {
    let mut d = ExampleDevice::new(node, example_od(node), PROFILE.boot_up, NoHooks);
    d.power_on(now);
    d
}
