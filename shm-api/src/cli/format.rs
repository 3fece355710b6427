//! Formatting in user units and names for the codes of the contract, and the CSV of
//! `motion-watch`. Numbers are formatted from the fixed-point integers exactly (no floats,
//! [`crate::units`]).

use std::fmt::Write as _;

pub use crate::units::{micro, user};

use crate::contract::{
    AxisState, GroupState, MachineState, axis_activity, axis_flags, axis_mode, axis_state,
    chain_state, fault, group_activity, motion_state,
};

use super::name_str;
use super::resolve::group_members;

/// Formats nanoseconds as seconds with 9 decimals (for CSV time columns).
pub fn seconds(ns: u64) -> String {
    format!("{}.{:09}", ns / 1_000_000_000, ns % 1_000_000_000)
}

/// The name of an [`axis_state`] code.
pub fn state_name(state: u8) -> &'static str {
    match state {
        axis_state::OFFLINE => "offline",
        axis_state::DISABLED => "disabled",
        axis_state::ENABLING => "enabling",
        axis_state::READY => "ready",
        axis_state::HOMING => "homing",
        axis_state::MOVING => "moving",
        axis_state::STOPPING => "stopping",
        axis_state::FAULT => "FAULT",
        _ => "?",
    }
}

/// The name of an [`axis_mode`] code.
pub fn mode_name(mode: u8) -> &'static str {
    match mode {
        axis_mode::OFF => "off",
        axis_mode::ON => "on",
        axis_mode::HOMING => "homing",
        axis_mode::JOG => "jog",
        axis_mode::QUICK_STOPPED => "quick-stopped",
        axis_mode::ACKNOWLEDGING => "acknowledging",
        _ => "?",
    }
}

/// The name of an [`axis_activity`] code (the coordinator's admission table's words).
pub fn activity_name(activity: u8) -> &'static str {
    match activity {
        axis_activity::OFFLINE => "offline",
        axis_activity::DISABLED => "disabled",
        axis_activity::STANDSTILL => "standstill",
        axis_activity::HOMING => "homing",
        axis_activity::MOVING => "moving",
        axis_activity::JOGGING => "jogging",
        axis_activity::IN_GROUP_MOVE => "in group move",
        axis_activity::STOPPING => "stopping",
        axis_activity::QUICK_STOPPED => "quick-stopped",
        axis_activity::FAULTED => "faulted",
        _ => "?",
    }
}

/// The name of a [`group_activity`] code.
pub fn group_activity_name(activity: u8) -> &'static str {
    match activity {
        group_activity::DISABLED => "disabled",
        group_activity::STANDBY => "standby",
        group_activity::MOVING => "moving",
        group_activity::CHAIN => "chain runs",
        group_activity::HELD => "held",
        group_activity::STOPPING => "stopping",
        group_activity::FAULTED => "faulted",
        _ => "?",
    }
}

/// The name of a [`chain_state`] code.
pub fn chain_name(state: u8) -> &'static str {
    match state {
        chain_state::IDLE => "idle",
        chain_state::DELAY => "delay",
        chain_state::MOVING => "moving",
        chain_state::WAITING => "waiting",
        chain_state::COMPLETE => "complete",
        chain_state::ABORTED => "aborted",
        _ => "?",
    }
}

/// The name of a [`motion_state`] code.
pub fn motion_name(state: u8) -> &'static str {
    match state {
        motion_state::NONE => "-",
        motion_state::MOVING => "moving",
        motion_state::HOLDING => "holding",
        motion_state::QUICK_STOPPING => "quick-stopping",
        motion_state::STOPPED => "stopped",
        motion_state::DONE => "done",
        _ => "?",
    }
}

/// Whether the axis has a fault to show.
pub fn is_faulted(axis: &AxisState) -> bool {
    axis.fault != fault::NONE || axis.state == axis_state::FAULT
}

/// The axis's fault in words with its numbers, or "" when there is none.
pub fn fault_text(axis: &AxisState) -> String {
    match axis.fault {
        fault::NONE if axis.state == axis_state::FAULT => "fault".into(),
        fault::NONE => String::new(),
        fault::HEARTBEAT_LOST => "heartbeat lost".into(),
        fault::GUARDING_LOST => "node guarding lost".into(),
        fault::EMCY => format!("EMCY 0x{:04X}", axis.fault_code),
        fault::FOLLOWING_ERROR => format!(
            "following error {} inc (limit {})",
            axis.fault_value, axis.fault_limit
        ),
        fault::DRIVE_FAULT => format!("drive fault {}", axis.fault_code),
        fault::MODBUS_TIMEOUT => "Modbus timeout".into(),
        fault::LATE_TPDO => format!("TPDOs missing for {} cycles", axis.fault_value),
        fault::BOOT_FAILED => "boot failed".into(),
        fault::DRIVE_RESET => "drive reset itself".into(),
        fault::ETHERCAT_LOST => "EtherCAT subdevice not answering".into(),
        fault::ETHERCAT_STATE => format!(
            "EtherCAT subdevice fell back to {}",
            match axis.fault_value {
                1 => "Init",
                2 => "Pre-Operational",
                4 => "Safe-Operational",
                _ => "another state",
            }
        ),
        other => format!("fault kind {other} code {}", axis.fault_code),
    }
}

/// "yes"/"no" for the homed flag.
pub fn homed(axis: &AxisState) -> &'static str {
    if axis.flags & axis_flags::HOMED != 0 {
        "yes"
    } else {
        "no"
    }
}

/// One axis on one line: `x ready/on pos 12.500 mm set 12.500 vel 0.000 mm/s`, and the fault.
pub fn axis_line(axis: &AxisState) -> String {
    let unit = name_str(&axis.unit);
    let mut s = format!(
        "{} {}/{} pos {} {unit} set {} vel {} {unit}/s",
        name_str(&axis.name),
        state_name(axis.state),
        mode_name(axis.mode),
        micro(axis.position, 3),
        micro(axis.setpoint, 3),
        micro(axis.velocity, 3),
    );
    if is_faulted(axis) {
        let _ = write!(s, " fault: {}", fault_text(axis));
    }
    s
}

/// A group's member names, comma-separated.
pub fn members(state: &MachineState, group: &GroupState) -> String {
    let names: Vec<&str> = group_members(group)
        .iter()
        .map(|&i| {
            state
                .axes
                .get(usize::from(i))
                .map_or("?", |a| name_str(&a.name))
        })
        .collect();
    names.join(",")
}

/// Quotes a CSV field when it holds a comma, quote or line break.
pub fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.into()
    }
}

/// The CSV header: `cycle,time_s`, then per axis `NAME_position,NAME_setpoint,NAME_velocity,
/// NAME_state` (positions in user units, velocity in units/s, the state by its name as
/// [`state_name`] spells it; `time_s` counts from the first line).
pub fn csv_header(state: &MachineState, axes: &[u16]) -> String {
    let mut s = String::from("cycle,time_s");
    for &i in axes {
        let name = state
            .axes
            .get(usize::from(i))
            .map_or("?", |a| name_str(&a.name));
        for col in ["position", "setpoint", "velocity", "state"] {
            let _ = write!(s, ",{}", csv_field(&format!("{name}_{col}")));
        }
    }
    s
}

/// One CSV line of `state` for `axes` (columns as in [`csv_header`]; 6 decimals, exact).
/// `time_s` is the SYNC time since `start_ns`, the SYNC time of the first line (so the first
/// line reads 0).
pub fn csv_line(state: &MachineState, axes: &[u16], start_ns: u64) -> String {
    let mut s = format!(
        "{},{}",
        state.cycle,
        seconds(state.sync_time_ns.saturating_sub(start_ns))
    );
    for &i in axes {
        match state.axes.get(usize::from(i)) {
            Some(a) => {
                let _ = write!(
                    s,
                    ",{},{},{},{}",
                    micro(a.position, 6),
                    micro(a.setpoint, 6),
                    micro(a.velocity, 6),
                    state_name(a.state)
                );
            }
            None => s.push_str(",,,,"),
        }
    }
    s
}

/// Nanoseconds as microseconds with one decimal (`4359` → `4.4`), exactly (no floats).
pub fn ns_as_us(ns: u64) -> String {
    micro(
        i64::try_from(ns)
            .unwrap_or(i64::MAX / 1000)
            .saturating_mul(1000),
        1,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seconds_have_nine_decimals() {
        assert_eq!(seconds(1_000_000_001), "1.000000001");
        assert_eq!(seconds(5), "0.000000005");
    }

    #[test]
    fn step_times_and_user_numbers_read_in_their_units() {
        assert_eq!(ns_as_us(4359), "4.4");
        assert_eq!(ns_as_us(12_345), "12.3");
        assert_eq!(ns_as_us(0), "0.0");
        assert_eq!(user(400_000_000), "400");
        assert_eq!(user(-1_250_000), "-1.25");
        assert_eq!(user(1), "0.000001");
        assert_eq!(user(0), "0");
    }

    #[test]
    fn csv_fields_are_quoted_when_needed() {
        assert_eq!(csv_field("x_position"), "x_position");
        assert_eq!(csv_field("a,b"), "\"a,b\"");
        assert_eq!(csv_field("a\"b"), "\"a\"\"b\"");
    }
}
