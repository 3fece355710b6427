//! The layout of every payload as the Rust compiler lays it out: sizes, alignments, each
//! field's offset and size, the type names iceoryx2 compares, and every constant of the
//! contract. `tests/layout_languages.rs` compares it with what the Python (`ctypes`) module and
//! the C header produce, so the three definitions cannot drift apart unnoticed.
//!
//! ```
//! let json = shm_api::layout_dump::layout_json();
//! assert!(json.contains("\"name\": \"MachineState\""));
//! ```

use crate::contract::{
    self, AxisDescription, AxisState, BusDescription, BusStats, CommandReply, CommandRequest,
    DriveRecord, EventRecord, GroupDescription, GroupRecord, GroupState, MachineDescription,
    MachineState,
};
use core::fmt::Write;
use core::mem::{align_of, offset_of, size_of};
use iceoryx2::prelude::ZeroCopySend;

/// One field of a payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FieldLayout {
    /// The field's name (the same in Rust, Python and C).
    pub name: &'static str,
    /// Its offset from the start of the struct, bytes.
    pub offset: usize,
    /// Its size, bytes (arrays: the whole array).
    pub size: usize,
}

/// One payload type.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TypeLayout {
    /// The Rust type's name (Python: the same; C: prefixed `Motion`).
    pub name: &'static str,
    /// The iceoryx2 type name, for the types that travel on their own (services' payloads).
    pub type_name: Option<&'static str>,
    /// `size_of`, bytes.
    pub size: usize,
    /// `align_of`, bytes.
    pub align: usize,
    /// Every field, in declaration order.
    pub fields: Vec<FieldLayout>,
}

/// The size of the field a projection closure points at (the closure is never called).
fn field_size<T, F>(_project: fn(&T) -> &F) -> usize {
    size_of::<F>()
}

/// The iceoryx2 type name of `T`.
fn iceoryx_type_name<T: ZeroCopySend>() -> &'static str {
    // SAFETY: reading the name has no precondition; the trait method is `unsafe` because an
    // implementor promises that every type sharing the name shares the layout, which is what
    // the language tests check.
    unsafe { <T as ZeroCopySend>::type_name() }
}

/// The iceoryx2 type name of a payload that travels on its own (a service's payload).
fn service_type_name(name: &str) -> Option<&'static str> {
    match name {
        "MachineState" => Some(iceoryx_type_name::<MachineState>()),
        "CommandRequest" => Some(iceoryx_type_name::<CommandRequest>()),
        "CommandReply" => Some(iceoryx_type_name::<CommandReply>()),
        "EventRecord" => Some(iceoryx_type_name::<EventRecord>()),
        "MachineDescription" => Some(iceoryx_type_name::<MachineDescription>()),
        _ => None,
    }
}

/// Appends a struct's layout; the destructuring pattern fails to compile when a field of the
/// contract is missing from the list, so the dump is always complete.
macro_rules! push_layout {
    ($v:ident; $t:ident, [$($f:ident),* $(,)?]) => {{
        #[allow(dead_code)]
        fn exhaustive(v: &$t) {
            let $t { $($f: _),* } = v;
        }
        $v.push(TypeLayout {
            name: stringify!($t),
            type_name: service_type_name(stringify!($t)),
            size: size_of::<$t>(),
            align: align_of::<$t>(),
            fields: vec![$(FieldLayout {
                name: stringify!($f),
                offset: offset_of!($t, $f),
                size: field_size(|v: &$t| &v.$f),
            }),*],
        });
    }};
}

/// Every payload type of the contract, nested types first.
pub fn layouts() -> Vec<TypeLayout> {
    let mut v = Vec::new();
    crate::layout::for_each_payload!(push_layout!(v));
    v
}

/// Lists constants as `("module.NAME", value)` (top-level ones without a module).
macro_rules! constants {
    ($out:ident; $($m:ident: [$($c:ident),* $(,)?]),* $(,)?) => {
        $($(
            $out.push((concat!(stringify!($m), ".", stringify!($c)), contract::$m::$c as i64));
        )*)*
    };
}

/// Every constant of the contract, as `("LAYOUT_VERSION", 1)` for the top-level ones and
/// `("axis_state.OFFLINE", 0)` for those in a module.
pub fn constants() -> Vec<(&'static str, i64)> {
    let mut out: Vec<(&'static str, i64)> = vec![
        ("LAYOUT_VERSION", i64::from(contract::LAYOUT_VERSION)),
        ("LAYOUT_HASH", i64::from(contract::LAYOUT_HASH)),
        ("MAX_AXES", contract::MAX_AXES as i64),
        ("MAX_GROUPS", contract::MAX_GROUPS as i64),
        ("MAX_GROUP_AXES", contract::MAX_GROUP_AXES as i64),
        ("NAME_LEN", contract::NAME_LEN as i64),
        ("UNIT_LEN", contract::UNIT_LEN as i64),
        ("MICRO", contract::MICRO),
        ("MAX_BUSES", contract::MAX_BUSES as i64),
        ("MAX_DRIVE_RECORDS", contract::MAX_DRIVE_RECORDS as i64),
        ("MAX_GROUP_RECORDS", contract::MAX_GROUP_RECORDS as i64),
        ("CONDITION_LEN", contract::CONDITION_LEN as i64),
        ("ADDRESS_LEN", contract::ADDRESS_LEN as i64),
    ];
    constants!(out;
        axis_state: [OFFLINE, DISABLED, ENABLING, READY, HOMING, MOVING, STOPPING, FAULT],
        axis_mode: [OFF, ON, HOMING, JOG, QUICK_STOPPED, ACKNOWLEDGING],
        axis_activity: [
            OFFLINE, DISABLED, STANDSTILL, HOMING, MOVING, JOGGING, IN_GROUP_MOVE, STOPPING,
            QUICK_STOPPED, FAULTED,
        ],
        group_activity: [DISABLED, STANDBY, MOVING, CHAIN, HELD, STOPPING, FAULTED],
        buffer_mode: [ABORTING, BUFFERED],
        axis_flags: [ONLINE, ENABLED, HOMED, MOTION_COMPLETE, WARNING, FOLLOWING, FHPP],
        fault: [
            NONE, HEARTBEAT_LOST, GUARDING_LOST, EMCY, FOLLOWING_ERROR, DRIVE_FAULT,
            MODBUS_TIMEOUT, LATE_TPDO, BOOT_FAILED, DRIVE_RESET, ETHERCAT_LOST, ETHERCAT_STATE,
        ],
        chain_state: [IDLE, DELAY, MOVING, WAITING, COMPLETE, ABORTED],
        motion_state: [NONE, MOVING, HOLDING, QUICK_STOPPING, STOPPED, DONE],
        command_kind: [
            ENABLE, DISABLE, ACKNOWLEDGE, HOME, JOG, MOVE_AXIS, MOVE_GROUP, START_CHAIN, HOLD,
            RESUME, STOP, QUICK_STOP, SET_OVERRIDE, READ_PARAMETER, WRITE_PARAMETER, SET_INPUT,
        ],
        target: [AXIS, GROUP, ALL],
        status: [
            LATCHED, UNKNOWN_AXIS, UNKNOWN_GROUP, UNKNOWN_RECORD, OUT_OF_RANGE, WRONG_STATE,
            BUSY, FAULTED, PLAN, BAD_REQUEST, OVERLOADED,
        ],
        event_id: [
            STATE_CHANGED, FAULT, RECORD_REACHED, CHAIN_COMPLETE, CHAIN_ABORTED, ACKNOWLEDGED,
            PARAMETER, SHUTDOWN, OVERRUN,
        ],
        device: [UNKNOWN, MTR_DCI, EMCA, CMMO_ST, TLC5XX],
        profile: [FHPP, CIA402],
        link: [CAN, MODBUS, ETHERCAT],
        bus_kind: [SIMULATED, VBUS, SOCKETCAN],
        shape: [TRAPEZOID, S_CURVE],
        record_mode: [POSITION, VELOCITY, FORCE],
        target_kind: [KEEP, ABSOLUTE, RELATIVE],
    );
    out
}

/// Appends `s` as a JSON string (the names are ASCII; quotes and backslashes are escaped
/// anyway so a future name cannot break the document).
fn json_str(out: &mut String, s: &str) {
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if (c as u32) < 0x20 => {
                let _ = write!(out, "\\u{:04x}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
}

/// The layouts ([`layouts`]) and constants ([`constants`]) as a JSON document:
/// `{"types": [{"name", "type_name" (string or null), "size", "align", "fields": [{"name",
/// "offset", "size"}]}], "constants": {"NAME": value}}`. The Python module's
/// `motion_shm.layout_json()` and the C check print the same shape.
pub fn layout_json() -> String {
    let mut out = String::from("{\n  \"types\": [\n");
    let types = layouts();
    for (i, t) in types.iter().enumerate() {
        out.push_str("    {\"name\": ");
        json_str(&mut out, t.name);
        out.push_str(", \"type_name\": ");
        match t.type_name {
            Some(n) => json_str(&mut out, n),
            None => out.push_str("null"),
        }
        let _ = write!(
            out,
            ", \"size\": {}, \"align\": {}, \"fields\": [",
            t.size, t.align
        );
        for (j, f) in t.fields.iter().enumerate() {
            out.push_str(if j == 0 { "\n      " } else { ",\n      " });
            out.push_str("{\"name\": ");
            json_str(&mut out, f.name);
            let _ = write!(out, ", \"offset\": {}, \"size\": {}}}", f.offset, f.size);
        }
        out.push_str("\n    ]}");
        out.push_str(if i + 1 < types.len() { ",\n" } else { "\n" });
    }
    out.push_str("  ],\n  \"constants\": {");
    for (i, (name, value)) in constants().iter().enumerate() {
        out.push_str(if i == 0 { "\n    " } else { ",\n    " });
        json_str(&mut out, name);
        let _ = write!(out, ": {value}");
    }
    out.push_str("\n  }\n}\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn padding_is_explicit_and_fields_do_not_overlap() {
        // The contract promises no implicit padding: fields tile the struct exactly, so C and
        // Python readers never depend on a compiler's padding rules.
        for t in layouts() {
            let mut end = 0;
            for f in &t.fields {
                assert_eq!(
                    f.offset, end,
                    "{}.{} leaves a gap or overlaps",
                    t.name, f.name
                );
                end = f.offset + f.size;
            }
            assert_eq!(end, t.size, "{} has trailing implicit padding", t.name);
        }
    }

    #[test]
    fn dump_holds_the_documented_sizes_and_offsets() {
        let all = layouts();
        let get = |n: &str| all.iter().find(|t| t.name == n).cloned();
        assert_eq!(get("AxisState").map(|t| t.size), Some(128));
        assert_eq!(get("GroupState").map(|t| t.size), Some(48));
        assert_eq!(get("AxisDescription").map(|t| t.size), Some(2216));
        assert_eq!(get("GroupRecord").map(|t| t.size), Some(256));
        let d = get("MachineDescription").expect("MachineDescription listed");
        assert!(
            d.type_name
                .is_some_and(|n| n.contains("MachineDescription"))
        );
        let ms = get("MachineState").expect("MachineState listed");
        let axes = ms.fields.iter().find(|f| f.name == "axes").copied();
        assert_eq!(axes.map(|f| f.size), Some(128 * contract::MAX_AXES));
        assert!(ms.type_name.is_some_and(|n| n.contains("MachineState")));
        let json = layout_json();
        assert!(json.contains("\"axis_state.FAULT\": 7"));
        assert!(json.contains("{\"name\": \"positions\", \"offset\": 32, \"size\": 64}"));
    }
}
