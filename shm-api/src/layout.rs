//! The layout fingerprint of the contract: [`compute_hash`] folds the size, alignment and every
//! field offset of each payload into one FNV-1a hash, in a fixed order. The hash is
//! [`contract::LAYOUT_HASH`] and it is part of every payload's iceoryx2 type name, so a client
//! built from another layout cannot open the services (iceoryx2 compares type names, sizes and
//! alignments when a service is opened).

use crate::contract::{
    self, AxisDescription, AxisState, BusDescription, BusStats, CommandReply, CommandRequest,
    DriveRecord, EventRecord, GroupDescription, GroupRecord, GroupState, MachineDescription,
    MachineState,
};
use core::mem::{align_of, offset_of, size_of};

const FNV_OFFSET: u32 = 0x811c_9dc5;
const FNV_PRIME: u32 = 0x0100_0193;

const fn feed(mut h: u32, v: usize) -> u32 {
    // Every number as 4 little-endian bytes, so the hash is the same on every host.
    let bytes = (v as u32).to_le_bytes();
    let mut i = 0;
    while i < 4 {
        h ^= bytes[i] as u32;
        h = h.wrapping_mul(FNV_PRIME);
        i += 1;
    }
    h
}

/// Every payload of the contract with its fields in declaration order, written once: calls
/// `$m!($($a)*; Type, [field, ...]);` for each, nested types first. The layout hash and the
/// layout dump (`crate::layout_dump`, which also fails to compile when a field is missing
/// here) both walk this list.
macro_rules! for_each_payload {
    ($m:ident ! ($($a:tt)*)) => {
        $m!($($a)*; AxisState, [
            position, setpoint, velocity, position_inc, setpoint_inc, fault_value, fault_limit,
            force_permille, status_bits, flags, state, mode, fault, activity, fault_code,
            active_record, name, unit, reserved1,
        ]);
        $m!($($a)*; GroupState, [
            active_record, record, reached, override_percent, chain_state, rc1, rcc, motion,
            axis_count, activity, reserved0, axes, name, reserved1,
        ]);
        $m!($($a)*; BusStats, [
            frames_sent, frames_received, tx_refused, rx_dropped, skipped_cycles, step_ns,
            wake_late_us,
        ]);
        $m!($($a)*; MachineState, [
            version, layout_hash, cycle, sync_time_ns, publish_time_ns, cycle_ns, axis_count,
            group_count, inputs, virtual_time, reserved0, bus, axes, groups,
        ]);
        $m!($($a)*; CommandRequest, [
            tag, kind, target, percent, axis, group, record, sub, buffer, pnu, reserved1,
            value, positions,
        ]);
        $m!($($a)*; CommandReply, [tag, cycle, value, min, max, status, reserved0, reason]);
        $m!($($a)*; EventRecord, [
            seq, cycle, value, id, axis, group, record, state, error, sub, reserved0, code,
            reserved1,
        ]);
        $m!($($a)*; BusDescription, [name, bitrate, kind, reserved0]);
        $m!($($a)*; DriveRecord, [
            position, velocity, acceleration, number, relative, next, reserved0,
        ]);
        $m!($($a)*; AxisDescription, [
            position_min, position_max, velocity, acceleration, jerk, following_error,
            increments_per_unit_num, increments_per_unit_den,
            force_permille, device, profile, fpc, link, bus, node, simulated, record_count,
            reserved0, name, unit, modbus, records,
        ]);
        $m!($($a)*; GroupRecord, [
            targets, delay_ms, force_permille, number, step_next, alternative_next, mode,
            velocity_percent, acceleration_percent, jerk_percent, mc_in_chain, reserved0,
            target_kinds, step, alternative,
        ]);
        $m!($($a)*; GroupDescription, [
            name, axes, axis_count, shape, record_count, reserved0, records,
        ]);
        $m!($($a)*; MachineDescription, [
            version, layout_hash, cycle_ns, axis_count, group_count, bus_count, reserved0, buses,
            axes, groups,
        ]);
    };
}
pub(crate) use for_each_payload;

/// Feeds size, alignment and the listed field offsets of a type.
macro_rules! layout {
    ($h:ident; $t:ident, [$($f:ident),* $(,)?]) => {{
        $h = feed($h, size_of::<$t>());
        $h = feed($h, align_of::<$t>());
        $( $h = feed($h, offset_of!($t, $f)); )*
    }};
}

/// The layout hash of the contract as compiled (see the module docs).
pub const fn compute_hash() -> u32 {
    let mut h = FNV_OFFSET;
    h = feed(h, contract::LAYOUT_VERSION as usize);
    for_each_payload!(layout!(h));
    h
}

/// The iceoryx2 type names of the five payloads that travel on their own
/// (`MachineState`, `CommandRequest`, `CommandReply`, `EventRecord`, `MachineDescription`).
pub fn type_names() -> [&'static str; 5] {
    use iceoryx2::prelude::ZeroCopySend;
    // SAFETY: `type_name` is unsafe only because an implementer must keep names and layouts
    // consistent; reading it is harmless.
    unsafe {
        [
            <MachineState as ZeroCopySend>::type_name(),
            <CommandRequest as ZeroCopySend>::type_name(),
            <CommandReply as ZeroCopySend>::type_name(),
            <EventRecord as ZeroCopySend>::type_name(),
            <MachineDescription as ZeroCopySend>::type_name(),
        ]
    }
}

/// The type name suffix every payload carries: `v{LAYOUT_VERSION}::{LAYOUT_HASH:08x}`.
pub fn type_name_suffix() -> String {
    format!(
        "v{}::{:08x}",
        contract::LAYOUT_VERSION,
        contract::LAYOUT_HASH
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_constant_is_the_hash_of_the_compiled_layout() {
        assert_eq!(
            compute_hash(),
            contract::LAYOUT_HASH,
            "contract::LAYOUT_HASH must be {:#010x}",
            compute_hash()
        );
    }

    #[test]
    fn every_type_name_carries_version_and_hash() {
        let suffix = type_name_suffix();
        for name in type_names() {
            assert!(name.starts_with("motion::"), "{name}");
            assert!(name.ends_with(&suffix), "{name} lacks {suffix}");
        }
    }

    #[test]
    fn the_hash_sees_a_moved_field() {
        #[repr(C)]
        #[allow(dead_code)]
        struct A {
            a: u16,
            b: u32,
        }
        #[repr(C)]
        #[allow(dead_code)]
        struct B {
            a: u16,
            b: u16,
        }
        let mut ha = FNV_OFFSET;
        layout!(ha; A, [a, b]);
        let mut hb = FNV_OFFSET;
        layout!(hb; B, [a, b]);
        assert_ne!(ha, hb);
    }
}
