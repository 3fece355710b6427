//! Synthetic machines for tests, benchmarks and timing runs: `n` simulated axes of the four
//! kinds in turn (MTR-DCI, EMCA, TLC5xx on one virtual CAN bus, CMMO-ST on Modbus), grouped by
//! up to `group_size`, with a cycle long enough for the bus budget.

use std::fmt::Write as _;

/// CANopen nodes on one bus (node-IDs 1..=127).
pub const MAX_CAN_AXES: usize = 127;

/// The configuration text of a machine of `n` axes in groups of up to `group_size` (CANopen and
/// Modbus axes in separate groups: Modbus has no SYNC). The cycle is the shortest whole number
/// of milliseconds (at least 2) that `coordinator check` accepts.
pub fn config(n: usize, group_size: usize) -> String {
    for cycle_ms in 2..=100 {
        let text = config_with_cycle(n, group_size, cycle_ms);
        if crate::config::Config::parse(&text).is_ok_and(|c| c.check().is_ok()) {
            return text;
        }
    }
    config_with_cycle(n, group_size, 100)
}

/// As [`config`] with a given cycle, ms (which `check` may refuse).
pub fn config_with_cycle(n: usize, group_size: usize, cycle_ms: usize) -> String {
    let group_size = group_size.clamp(1, 8);
    // Axes 4k+3 are CMMO-STs (Modbus) unless the bus is full, so every kind appears.
    let mut kinds = Vec::with_capacity(n);
    let mut can = 0usize;
    for i in 0..n {
        let k = match i % 4 {
            0 => "mtr-dci",
            1 => "emca",
            2 => "tlc5xx",
            _ => "cmmo-st",
        };
        let k = if k != "cmmo-st" && can >= MAX_CAN_AXES {
            "cmmo-st"
        } else {
            k
        };
        if k != "cmmo-st" {
            can += 1;
        }
        kinds.push(k);
    }
    let mut s = String::new();
    let _ = writeln!(s, "cycle_us = {}", cycle_ms * 1000);
    let _ = writeln!(
        s,
        "\n[[buses]]\nname = \"can0\"\nkind = \"simulated\"\nbitrate = 1000000\nsdo_slots = 2"
    );
    let mut node = 0u32;
    for (i, k) in kinds.iter().enumerate() {
        let _ = writeln!(s, "\n[[axes]]\nname = \"a{i}\"\ndevice = \"{k}\"");
        if *k == "cmmo-st" {
            let _ = writeln!(s, "modbus = \"127.0.0.1:{}\"", 1502 + i);
        } else {
            node += 1;
            let _ = writeln!(s, "bus = \"can0\"\nnode = {node}");
        }
        let (ipu, max, v, a) = match *k {
            "mtr-dci" => (400.0, 400.0, 100.0, 800.0),
            "emca" => (1000.0, 250.0, 80.0, 400.0),
            "tlc5xx" => (3200.0, 120.0, 30.0, 150.0),
            _ => (100.0, 180.0, 90.0, 900.0),
        };
        let _ = writeln!(
            s,
            "increments_per_unit = {ipu:.1}\nlimits = {{ position_min = 0.0, position_max = {max:.1}, velocity = {v:.1}, acceleration = {a:.1} }}"
        );
    }
    let on_can: Vec<usize> = (0..n).filter(|&i| kinds[i] != "cmmo-st").collect();
    let on_modbus: Vec<usize> = (0..n).filter(|&i| kinds[i] == "cmmo-st").collect();
    let mut g = 0;
    for members in [on_can, on_modbus] {
        for chunk in members.chunks(group_size) {
            let names: Vec<String> = chunk.iter().map(|i| format!("\"a{i}\"")).collect();
            let _ = writeln!(
                s,
                "\n[[groups]]\nname = \"g{g}\"\naxes = [{}]",
                names.join(", ")
            );
            g += 1;
        }
    }
    s
}
