//! EDS export (CiA 306): a device's object dictionary written out as the INI text a
//! configuration tool or python-canopen reads. Std only: tools, never the cycle.
//!
//! What it writes, per object: VAR for an index with only sub-index 0, ARRAY when every
//! sub-index above 0 has one data type, RECORD otherwise; `ParameterName`, `DataType`,
//! `AccessType`, `DefaultValue` (the dictionary's value as it is now, so a freshly built
//! device's EDS is what an SDO read of it returns), `LowLimit`/`HighLimit` where the entry has
//! them, `PDOMapping`. COB-IDs that follow the predefined connection set are written relative
//! to the node (`$NODEID+0x180`), so the file describes the device at any node-ID.
//! [`super::eds::Eds::parse`] reads every file this writes back into the same entries (a test
//! of each simulated device checks it).

use std::fmt::Write as _;
use std::string::String;
use std::vec::Vec;

use super::od::{AccessType, DataType, EntryDef, ObjectDictionary, TypeClass, Value, decode_value};
use super::{Address, NodeId};

/// What the `[DeviceInfo]` and `[FileInfo]` sections say about the device.
#[derive(Debug, Clone)]
pub struct DeviceInfo<'a> {
    /// The file's name (`FileName`), e.g. `tlc5xx.eds`.
    pub file_name: &'a str,
    /// A line of description (`Description`).
    pub description: &'a str,
    /// `VendorName`.
    pub vendor_name: &'a str,
    /// `ProductName`.
    pub product_name: &'a str,
    /// The bitrates the device supports, kbit/s (of 10, 20, 50, 125, 250, 500, 800, 1000).
    pub baud_rates_kbit: &'a [u16],
    /// Whether the device supports LSS (`LSS_Supported`).
    pub lss: bool,
    /// Who made the file (`CreatedBy`).
    pub created_by: &'a str,
}

/// The standard objects with sub-indices (CiA 301 and CiA 402): their names (the entries name
/// only their sub-indices) and whether the standard makes them an ARRAY (else a RECORD). Tools
/// act on the difference: python-canopen sizes an ARRAY by reading its sub-index 0 from the
/// device, a RECORD by its description.
fn standard_object(index: u16) -> Option<(&'static str, bool)> {
    Some(match index {
        0x1003 => ("Pre-defined error field", true),
        0x1010 => ("Store parameters", true),
        0x1011 => ("Restore default parameters", true),
        0x1016 => ("Consumer heartbeat time", true),
        0x1018 => ("Identity object", false),
        0x1029 => ("Error behaviour", true),
        0x1200..=0x127F => ("SDO server parameter", false),
        0x1280..=0x12FF => ("SDO client parameter", false),
        0x1400..=0x15FF => ("RPDO communication parameter", false),
        0x1600..=0x17FF => ("RPDO mapping parameter", false),
        0x1800..=0x19FF => ("TPDO communication parameter", false),
        0x1A00..=0x1BFF => ("TPDO mapping parameter", false),
        0x607B => ("Position range limit", true),
        0x607D => ("Software position limit", true),
        0x608F => ("Position encoder resolution", true),
        0x6091 => ("Gear ratio", true),
        0x6092 => ("Feed constant", true),
        0x6093 => ("Position factor", true),
        0x6094 => ("Velocity encoder factor", true),
        0x6097 => ("Acceleration factor", true),
        0x6099 => ("Homing speeds", true),
        0x60C1 => ("Interpolation data record", true),
        0x60C2 => ("Interpolation time period", false),
        0x60FE => ("Digital outputs", true),
        _ => return None,
    })
}

/// The predefined connection set's base identifier of a COB-ID entry, if `addr` is one.
fn cob_id_base(addr: Address) -> Option<u32> {
    match (addr.index, addr.sub) {
        (0x1014, 0) => Some(0x080),
        (0x1200, 1) => Some(0x600),
        (0x1200, 2) => Some(0x580),
        (0x1400..=0x1403, 1) => Some(0x200 + 0x100 * u32::from(addr.index - 0x1400)),
        (0x1800..=0x1803, 1) => Some(0x180 + 0x100 * u32::from(addr.index - 0x1800)),
        _ => None,
    }
}

fn access_text(a: AccessType) -> &'static str {
    match a {
        AccessType::Ro => "ro",
        AccessType::Wo => "wo",
        AccessType::Rw => "rw",
        AccessType::Rwr => "rwr",
        AccessType::Rww => "rww",
        AccessType::Const => "const",
    }
}

/// A value as an EDS writes it: unsigned in hex, signed and real in decimal, a visible string
/// as its text, an octet string as hex digits.
fn value_text(dt: DataType, v: &Value<'_>) -> String {
    match *v {
        Value::Unsigned(u) => format!("0x{u:X}"),
        Value::Signed(s) => s.to_string(),
        Value::Real32(f) => f.to_string(),
        Value::Real64(f) => f.to_string(),
        Value::Bytes(b) => match dt {
            DataType::OctetString => b.iter().map(|x| format!("{x:02X}")).collect(),
            // Strings end at their first NUL (the dictionary pads to the capacity).
            _ => {
                let end = b.iter().position(|&x| x == 0).unwrap_or(b.len());
                String::from_utf8_lossy(&b[..end]).into_owned()
            }
        },
    }
}

fn entry_section(out: &mut String, section: &str, e: &EntryDef<'_>, default: &str) {
    let _ = writeln!(out, "[{section}]");
    let _ = writeln!(out, "ParameterName={}", e.name);
    let _ = writeln!(out, "ObjectType=0x7");
    let _ = writeln!(out, "DataType=0x{:04X}", e.data_type as u16);
    let _ = writeln!(out, "AccessType={}", access_text(e.access));
    let _ = writeln!(out, "DefaultValue={default}");
    if !matches!(e.data_type.class(), TypeClass::Bytes) {
        if let Some(low) = &e.low {
            let _ = writeln!(out, "LowLimit={}", value_text(e.data_type, low));
        }
        if let Some(high) = &e.high {
            let _ = writeln!(out, "HighLimit={}", value_text(e.data_type, high));
        }
    }
    let _ = writeln!(out, "PDOMapping={}", u8::from(e.pdo_mappable));
    out.push('\n');
}

/// The EDS text of `od`, a device at `node` (used to write COB-IDs relative to `$NODEID`).
pub fn write_eds<const N: usize, const B: usize>(
    od: &ObjectDictionary<'_, N, B>,
    node: NodeId,
    info: &DeviceInfo<'_>,
) -> String {
    // Entries by index, in index order (the dictionary keeps them sorted).
    let mut objects: Vec<(u16, Vec<&EntryDef<'_>>)> = Vec::new();
    for e in od.entries() {
        match objects.last_mut() {
            Some((i, subs)) if *i == e.addr.index => subs.push(e),
            _ => objects.push((e.addr.index, vec![e])),
        }
    }
    let default_of = |e: &EntryDef<'_>| -> String {
        let Ok(raw) = od.raw(e.addr) else {
            return value_text(e.data_type, &e.default);
        };
        let v = decode_value(e.data_type, raw);
        if let (Some(base), Value::Unsigned(u)) = (cob_id_base(e.addr), v) {
            let id = (u & 0x7FF) as u32;
            if id == base + u32::from(node.get()) {
                let flags = (u as u32) & 0xE000_0000;
                return format!("$NODEID+0x{:X}", flags | base);
            }
        }
        value_text(e.data_type, &v)
    };
    let count = |lo: u16, hi: u16| {
        objects
            .iter()
            .filter(|(i, _)| (lo..=hi).contains(i))
            .count()
    };
    let rx = count(0x1400, 0x15FF);
    let tx = count(0x1800, 0x19FF);

    let mut out = String::new();
    let _ = writeln!(out, "[FileInfo]");
    let _ = writeln!(out, "FileName={}", info.file_name);
    let _ = writeln!(out, "FileVersion=1");
    let _ = writeln!(out, "FileRevision=0");
    let _ = writeln!(out, "EDSVersion=4.0");
    let _ = writeln!(out, "Description={}", info.description);
    let _ = writeln!(out, "CreatedBy={}", info.created_by);
    out.push('\n');
    let ident = |sub: u8| {
        od.raw(Address::new(0x1018, sub))
            .map(super::od::le_u64)
            .unwrap_or(0)
    };
    let _ = writeln!(out, "[DeviceInfo]");
    let _ = writeln!(out, "VendorName={}", info.vendor_name);
    let _ = writeln!(out, "VendorNumber=0x{:X}", ident(1));
    let _ = writeln!(out, "ProductName={}", info.product_name);
    let _ = writeln!(out, "ProductNumber=0x{:X}", ident(2));
    let _ = writeln!(out, "RevisionNumber=0x{:X}", ident(3));
    for kbit in [10u16, 20, 50, 125, 250, 500, 800, 1000] {
        let _ = writeln!(
            out,
            "BaudRate_{kbit}={}",
            u8::from(info.baud_rates_kbit.contains(&kbit))
        );
    }
    let _ = writeln!(out, "SimpleBootUpMaster=0");
    let _ = writeln!(out, "SimpleBootUpSlave=1");
    let _ = writeln!(out, "Granularity=8");
    let _ = writeln!(out, "DynamicChannelsSupported=0");
    let _ = writeln!(out, "GroupMessaging=0");
    let _ = writeln!(out, "NrOfRXPDO={rx}");
    let _ = writeln!(out, "NrOfTXPDO={tx}");
    let _ = writeln!(out, "LSS_Supported={}", u8::from(info.lss));
    out.push('\n');
    let _ = writeln!(out, "[DummyUsage]");
    for t in 1..=7 {
        let _ = writeln!(out, "Dummy000{t}=0");
    }
    out.push('\n');

    // The three object lists CiA 306 asks for.
    let mandatory: Vec<u16> = objects
        .iter()
        .map(|(i, _)| *i)
        .filter(|i| matches!(i, 0x1000 | 0x1001 | 0x1018))
        .collect();
    let optional: Vec<u16> = objects
        .iter()
        .map(|(i, _)| *i)
        .filter(|i| !mandatory.contains(i) && ((0x1000..0x2000).contains(i) || *i >= 0x6000))
        .collect();
    let manufacturer: Vec<u16> = objects
        .iter()
        .map(|(i, _)| *i)
        .filter(|i| (0x2000..0x6000).contains(i))
        .collect();
    for (name, list) in [
        ("MandatoryObjects", &mandatory),
        ("OptionalObjects", &optional),
        ("ManufacturerObjects", &manufacturer),
    ] {
        let _ = writeln!(out, "[{name}]");
        let _ = writeln!(out, "SupportedObjects={}", list.len());
        for (n, i) in list.iter().enumerate() {
            let _ = writeln!(out, "{}=0x{i:04X}", n + 1);
        }
        out.push('\n');
    }

    for (index, subs) in &objects {
        let only_zero = subs.len() == 1 && subs[0].addr.sub == 0;
        if only_zero {
            entry_section(
                &mut out,
                &format!("{index:04X}"),
                subs[0],
                &default_of(subs[0]),
            );
            continue;
        }
        let above: Vec<&&EntryDef<'_>> = subs.iter().filter(|e| e.addr.sub > 0).collect();
        // A manufacturer object is an ARRAY when its sub-indices share one type.
        let (name, array) = match standard_object(*index) {
            Some((name, array)) => (name.to_owned(), array),
            None => (
                object_name(&above),
                above
                    .first()
                    .is_some_and(|f| above.iter().all(|e| e.data_type == f.data_type)),
            ),
        };
        let _ = writeln!(out, "[{index:04X}]");
        let _ = writeln!(out, "ParameterName={name}");
        let _ = writeln!(out, "ObjectType=0x{}", if array { 8 } else { 9 });
        let _ = writeln!(out, "SubNumber=0x{:X}", subs.len());
        out.push('\n');
        for e in subs {
            entry_section(
                &mut out,
                &format!("{index:04X}sub{:X}", e.addr.sub),
                e,
                &default_of(e),
            );
        }
    }
    out
}

/// A name for a manufacturer object with sub-indices: what its sub-indices' names share
/// (`"homing speed 1"`, `"homing speed 2"` give `"homing speed"`), or the first one's.
fn object_name(subs: &[&&EntryDef<'_>]) -> String {
    let Some(first) = subs.first() else {
        return String::from("object");
    };
    let mut common = first.name;
    for e in subs.iter().skip(1) {
        let n = common
            .char_indices()
            .zip(e.name.chars())
            .take_while(|((_, a), b)| a == b)
            .last()
            .map_or(0, |((i, c), _)| i + c.len_utf8());
        common = &common[..n];
    }
    let common = common.trim_end_matches(|c: char| c.is_ascii_digit() || c == ' ' || c == '_');
    if common.len() >= 3 {
        common.to_owned()
    } else {
        first.name.to_owned()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canopen::eds::Eds;
    use crate::canopen::od::{AccessType::*, DataType::*, EntryDef};

    #[test]
    fn a_dictionary_comes_back_from_its_eds() {
        let mut od: ObjectDictionary<'_, 16, 256> = ObjectDictionary::new();
        let node = NodeId::new(5).unwrap();
        for d in [
            EntryDef::new(Address::new(0x1000, 0), "device type", Unsigned32, Ro)
                .default_value(Value::Unsigned(0x0002_0192)),
            EntryDef::new(Address::new(0x1008, 0), "device name", VisibleString, Const)
                .capacity(8)
                .default_value(Value::Bytes(b"DRIVE")),
            EntryDef::new(Address::new(0x1018, 0), "count", Unsigned8, Ro)
                .default_value(Value::Unsigned(1)),
            EntryDef::new(Address::new(0x1018, 1), "vendor-ID", Unsigned32, Ro)
                .default_value(Value::Unsigned(0x0800_005A)),
            EntryDef::new(Address::new(0x1800, 0), "count", Unsigned8, Ro)
                .default_value(Value::Unsigned(2)),
            EntryDef::new(Address::new(0x1800, 1), "COB-ID", Unsigned32, Rw)
                .default_value(Value::Unsigned(0x4000_0185)),
            EntryDef::new(Address::new(0x1800, 2), "transmission type", Unsigned8, Rw)
                .default_value(Value::Unsigned(1)),
            EntryDef::new(Address::new(0x607A, 0), "target position", Integer32, Rww)
                .mappable()
                .limits(Value::Signed(-1000), Value::Signed(1000))
                .default_value(Value::Signed(-7)),
        ] {
            od.insert(d).unwrap();
        }
        let info = DeviceInfo {
            file_name: "t.eds",
            description: "a test",
            vendor_name: "nobody",
            product_name: "drive",
            baud_rates_kbit: &[1000],
            lss: false,
            created_by: "test",
        };
        let text = write_eds(&od, node, &info);
        assert!(text.contains("DefaultValue=$NODEID+0x40000180"), "{text}");
        assert!(text.contains("ProductName=drive"), "{text}");
        assert!(
            text.contains(
                "[1800]\nParameterName=TPDO communication parameter\nObjectType=0x9\nSubNumber=0x3"
            ),
            "{text}"
        );
        // At another node, the COB-ID follows it.
        let back = Eds::parse(&text, NodeId::new(9)).unwrap();
        assert_eq!(
            back.entry(Address::new(0x1800, 1))
                .map(|e| e.to_def().default),
            Some(Value::Unsigned(0x4000_0189))
        );
        // At the same node, every entry as it was.
        let back = Eds::parse(&text, Some(node)).unwrap();
        for e in od.entries() {
            let b = back.entry(e.addr).unwrap().to_def();
            assert_eq!(
                (b.name, b.data_type, b.access, b.pdo_mappable, b.low, b.high),
                (e.name, e.data_type, e.access, e.pdo_mappable, e.low, e.high),
                "{}",
                e.addr
            );
            assert_eq!(b.default, e.default, "{}", e.addr);
        }
    }

    #[test]
    fn a_manufacturer_record_is_named_by_what_its_entries_share() {
        let a = EntryDef::new(Address::new(0x2099, 1), "homing speed 1", Unsigned32, Rw);
        let b = EntryDef::new(Address::new(0x2099, 2), "homing speed 2", Unsigned32, Rw);
        assert_eq!(object_name(&[&&a, &&b]), "homing speed");
        let c = EntryDef::new(Address::new(0x2099, 2), "other", Unsigned32, Rw);
        assert_eq!(object_name(&[&&a, &&c]), "homing speed 1");
    }
}
