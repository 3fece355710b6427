//! Synthetic machines for tests, benchmarks and timing runs: `n` simulated axes of the four
//! kinds in turn (MTR-DCI, EMCA, TLC5xx on one virtual CAN bus, CMMO-ST on Modbus), grouped by
//! up to `group_size`, with a cycle long enough for the bus budget; or, through [`Spec`], only
//! the FHPP or only the CiA 402 drives, grouped or each axis on its own. [`capture_moving`]
//! runs one in virtual time until every axis moves and captures a step for replay.

use std::fmt::Write as _;
use std::time::Duration;

use crate::command::{BufferMode, Command, GroupId, Reply};
use crate::ids::MAX_GROUP_AXES;
use crate::runtime::plan::MachinePlan;
use crate::runtime::run::RunOptions;
use crate::runtime::script::{Phase, ScriptOptions};
use crate::runtime::stepper::Captured;
use crate::runtime::virtual_clock::VirtualRun;

/// CANopen nodes on one bus (node-IDs 1..=127).
pub const MAX_CAN_AXES: usize = 127;

/// Which drives a synthetic machine has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kinds {
    /// The four kinds in turn: MTR-DCI and EMCA (FHPP on CAN), TLC5xx (CiA 402), CMMO-ST (FHPP
    /// on Modbus); CAN axes past one bus's 127 nodes become CMMO-STs.
    Mixed,
    /// FHPP only: the mixed machine with an EMCA in the TLC5xx's place (MTR-DCI, EMCA, EMCA,
    /// CMMO-ST in turn), so that 128 axes still make 16 groups.
    Fhpp,
    /// CiA 402 only: TLC5xx and MTR-DCI (in its CiA 402 profile) in turn, a new CAN bus every
    /// 127 nodes.
    Cia402,
}

/// A synthetic machine.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Spec {
    /// Axes (1..=128).
    pub axes: usize,
    /// Which drives.
    pub kinds: Kinds,
    /// Groups of up to this many axes (1..=8; CAN and Modbus axes apart); none: no groups,
    /// each axis moves on its own.
    pub group_size: Option<usize>,
}

/// The configuration text of a machine of `n` axes in groups of up to `group_size` (CANopen and
/// Modbus axes in separate groups: Modbus has no SYNC). The cycle is the shortest whole number
/// of milliseconds (at least 2) that `coordinator check` accepts.
pub fn config(n: usize, group_size: usize) -> String {
    config_of(&Spec {
        axes: n,
        kinds: Kinds::Mixed,
        group_size: Some(group_size),
    })
}

/// The configuration text of `spec`'s machine, with the shortest whole-millisecond cycle (at
/// least 2) that `coordinator check` accepts.
pub fn config_of(spec: &Spec) -> String {
    for cycle_ms in 2..=100 {
        let text = spec_with_cycle(spec, cycle_ms);
        if crate::config::Config::parse(&text).is_ok_and(|c| c.check().is_ok()) {
            return text;
        }
    }
    spec_with_cycle(spec, 100)
}

/// The configuration text of `spec`'s machine with a given cycle, µs, its CANopen drives
/// spread over the fewest buses (at most [`crate::config::MAX_BUSES`]) whose budget fits that
/// cycle, as a real machine would have them; where two SDO slots per bus do not fit, one; where
/// the default 80 % load limit does not fit, 100 % (every frame's worst case inside the cycle).
/// When none fits, the refusal of the most buses (`coordinator check`'s report, with the
/// numbers).
pub fn config_of_with_cycle_us(spec: &Spec, cycle_us: u32) -> Result<String, String> {
    let can = axes_of(spec, MAX_CAN_AXES)
        .iter()
        .filter(|a| a.bus.is_some())
        .count()
        .max(1);
    let mut last = String::new();
    for limit in [None, Some(100)] {
        for buses in 1..=crate::config::MAX_BUSES {
            let per_bus = can.div_ceil(buses).clamp(1, MAX_CAN_AXES);
            for sdo_slots in [2, 1] {
                let mut text = spec_with_cycle_us(spec, cycle_us, per_bus, sdo_slots);
                if let Some(l) = limit {
                    text = format!("load_limit_percent = {l}\n{text}");
                }
                match crate::config::Config::parse(&text) {
                    Ok(c) => {
                        let report = c.check();
                        if report.is_ok() {
                            return Ok(text);
                        }
                        last = report.to_string();
                    }
                    Err(e) => last = e.to_string(),
                }
            }
        }
    }
    Err(last)
}

/// As [`config`] with a given cycle, ms (which `check` may refuse).
pub fn config_with_cycle(n: usize, group_size: usize, cycle_ms: usize) -> String {
    spec_with_cycle(
        &Spec {
            axes: n,
            kinds: Kinds::Mixed,
            group_size: Some(group_size),
        },
        cycle_ms,
    )
}

/// One axis: its device, its profile where not the device's default, and its bus (none:
/// Modbus).
struct Axis {
    device: &'static str,
    cia402: bool,
    bus: Option<usize>,
}

/// The axes, at most `per_bus` CANopen nodes on a bus (1..=127): the CiA 402 machine takes a
/// new bus for the next; the others too, up to one bus's 127 nodes in all, CMMO-STs beyond.
fn axes_of(spec: &Spec, per_bus: usize) -> Vec<Axis> {
    let per_bus = per_bus.clamp(1, MAX_CAN_AXES);
    let mut out = Vec::with_capacity(spec.axes);
    let mut can = 0usize;
    for i in 0..spec.axes {
        let (device, cia402) = match (spec.kinds, i % 4) {
            (Kinds::Cia402, k) if k % 2 == 0 => ("tlc5xx", false),
            (Kinds::Cia402, _) => ("mtr-dci", true),
            (_, 0) => ("mtr-dci", false),
            (_, 1) => ("emca", false),
            (Kinds::Mixed, 2) => ("tlc5xx", false),
            (_, 2) => ("emca", false),
            _ => ("cmmo-st", false),
        };
        // Axes 4k+3 are CMMO-STs (Modbus) unless the bus is full, so every kind appears.
        let (device, bus) = if device == "cmmo-st" {
            (device, None)
        } else if spec.kinds == Kinds::Cia402 {
            can += 1;
            (device, Some((can - 1) / per_bus))
        } else if can >= MAX_CAN_AXES {
            ("cmmo-st", None)
        } else {
            can += 1;
            (device, Some((can - 1) / per_bus))
        };
        out.push(Axis {
            device,
            cia402: cia402 && device != "cmmo-st",
            bus,
        });
    }
    out
}

fn spec_with_cycle(spec: &Spec, cycle_ms: usize) -> String {
    let cycle_us = (cycle_ms * 1000).try_into().unwrap_or(u32::MAX);
    spec_with_cycle_us(spec, cycle_us, MAX_CAN_AXES, 2)
}

/// At most `per_bus` CANopen nodes on a bus (1..=127), `sdo_slots` on each bus.
fn spec_with_cycle_us(spec: &Spec, cycle_us: u32, per_bus: usize, sdo_slots: u32) -> String {
    let axes = axes_of(spec, per_bus);
    let buses = axes.iter().filter_map(|a| a.bus).max().map_or(1, |b| b + 1);
    let mut s = String::new();
    let _ = writeln!(s, "cycle_us = {cycle_us}");
    for b in 0..buses {
        let _ = writeln!(
            s,
            "\n[[buses]]\nname = \"can{b}\"\nkind = \"simulated\"\nbitrate = 1000000\nsdo_slots = {sdo_slots}"
        );
    }
    let mut nodes = vec![0u32; buses];
    for (i, a) in axes.iter().enumerate() {
        let k = a.device;
        let _ = writeln!(s, "\n[[axes]]\nname = \"a{i}\"\ndevice = \"{k}\"");
        match a.bus {
            None => {
                let _ = writeln!(s, "modbus = \"127.0.0.1:{}\"", 1502 + i);
            }
            Some(b) => {
                nodes[b] += 1;
                let _ = writeln!(s, "bus = \"can{b}\"\nnode = {}", nodes[b]);
            }
        }
        if a.cia402 {
            let _ = writeln!(s, "profile = \"cia402\"");
        }
        let (ipu, max, v, acc) = match k {
            "mtr-dci" => (400.0, 400.0, 100.0, 800.0),
            "emca" => (1000.0, 250.0, 80.0, 400.0),
            "tlc5xx" => (3200.0, 120.0, 30.0, 150.0),
            _ => (100.0, 180.0, 90.0, 900.0),
        };
        let _ = writeln!(
            s,
            "increments_per_unit = {ipu:.1}\nlimits = {{ position_min = 0.0, position_max = {max:.1}, velocity = {v:.1}, acceleration = {acc:.1} }}"
        );
    }
    let Some(group_size) = spec.group_size else {
        return s;
    };
    let group_size = group_size.clamp(1, 8);
    let on_can: Vec<usize> = (0..axes.len()).filter(|&i| axes[i].bus.is_some()).collect();
    let on_modbus: Vec<usize> = (0..axes.len()).filter(|&i| axes[i].bus.is_none()).collect();
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

/// Virtual time with the demonstration (enable, home, and the record chains if `chains`), no
/// end, no shared memory, no capture: how the benchmarks, `timing` and the tests bring a
/// machine to a state where every axis can move.
pub fn demo_options(chains: bool) -> RunOptions {
    RunOptions {
        duration: None,
        virtual_time: true,
        status_every: None,
        script: ScriptOptions {
            demo: true,
            chains,
            home: true,
        },
        shm: None,
        capture: None,
        record: None,
    }
}

/// Runs `plan` in virtual time with its simulated drives until every axis is enabled and
/// homed, starts a move to three quarters of the range on every group (or, where `grouped` is
/// false, on every axis by itself), lets 20 cycles pass and captures the next step: the state
/// and inputs `benches/cycle.rs` and `timing step` replay. Every axis moves in that step.
pub fn capture_moving(plan: &MachinePlan, grouped: bool) -> Result<Captured<'_>, String> {
    let opts = demo_options(false);
    let mut run = VirtualRun::new(plan, &opts).map_err(|e| e.to_string())?;
    let mut out = Vec::new();
    while run.lp.script.phase() != Phase::Running {
        run.step(&mut out);
        if run.elapsed() > Duration::from_secs(300) {
            return Err(format!(
                "not homed after 300 s of machine time:\n{}",
                String::from_utf8_lossy(&out)
            ));
        }
    }
    let mut replies = Vec::new();
    if grouped {
        for (g, (_, gs, _)) in plan.groups.iter().enumerate() {
            let mut positions = [0i64; MAX_GROUP_AXES];
            for (i, &a) in gs.axes.iter().enumerate() {
                positions[i] = plan.axes[usize::from(a)].setup.position_max * 3 / 4;
            }
            replies.push((
                format!("group {g}"),
                run.stepper.cycle.command(&Command::MoveGroup {
                    group: g as GroupId,
                    positions,
                    velocity_percent: 100,
                    buffer: BufferMode::Aborting,
                }),
            ));
        }
    } else {
        for (i, a) in plan.axes.iter().enumerate() {
            replies.push((
                format!("axis {i}"),
                run.stepper.cycle.command(&Command::MoveAxis {
                    axis: i as crate::ids::AxisId,
                    position: a.setup.position_max * 3 / 4,
                    velocity_percent: 100,
                    buffer: BufferMode::Aborting,
                }),
            ));
        }
    }
    for (who, r) in &replies {
        if let Reply::Rejected(why) = r {
            return Err(format!(
                "{who}: the move was refused: {why}\n{}",
                String::from_utf8_lossy(&out)
            ));
        }
    }
    for _ in 0..20 {
        run.step(&mut out);
    }
    run.lp.capture = true;
    run.step(&mut out);
    let c = run
        .lp
        .captured
        .take()
        .ok_or_else(|| "no step was captured".to_string())?;
    let still = (0..plan.axes.len())
        .filter(|&a| {
            !c.cycle
                .axis_status(a as crate::ids::AxisId)
                .is_some_and(|s| s.moving)
        })
        .count();
    if still > 0 {
        return Err(format!(
            "{still} of {} axes do not move in the captured step",
            plan.axes.len()
        ));
    }
    Ok(c)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Config;

    #[test]
    fn every_spec_is_a_machine_check_accepts() {
        for kinds in [Kinds::Mixed, Kinds::Fhpp, Kinds::Cia402] {
            for group_size in [Some(8), None] {
                for axes in [1, 8, 128] {
                    let spec = Spec {
                        axes,
                        kinds,
                        group_size,
                    };
                    let c = Config::parse(&config_of(&spec)).expect("parses");
                    assert!(c.check().is_ok(), "{spec:?}");
                    assert_eq!(c.axes.len(), axes);
                    assert_eq!(c.groups.is_empty(), group_size.is_none(), "{spec:?}");
                }
            }
        }
        // At a given cycle the drives take as many buses as the budget needs, or are refused.
        let spec = Spec {
            axes: 8,
            kinds: Kinds::Cia402,
            group_size: None,
        };
        let c = Config::parse(&config_of_with_cycle_us(&spec, 1000).expect("fits")).unwrap();
        assert!(c.check().is_ok());
        assert_eq!((c.cycle_us, c.buses.len(), c.axes.len()), (1000, 8, 8));
        let one_bus = Config::parse(&config_of_with_cycle_us(&spec, 20_000).unwrap()).unwrap();
        assert_eq!(one_bus.buses.len(), 1);
        let big = Spec { axes: 32, ..spec };
        assert!(
            config_of_with_cycle_us(&big, 1000)
                .unwrap_err()
                .contains("does not fit")
        );
        // The mixed machine is the one the benchmarks always measured.
        assert_eq!(
            config(8, 8),
            config_of(&Spec {
                axes: 8,
                kinds: Kinds::Mixed,
                group_size: Some(8)
            })
        );
    }
}
