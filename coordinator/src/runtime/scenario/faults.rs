//! The faults a scenario injects into a machine running in virtual time, each started and ended
//! at a cycle: rules on the simulated buses (loss, delay, corruption, duplication, SYNC loss
//! and lateness), a node's controller off the bus (bus-off, a dead drive), frames a drive sends
//! or is sent (a reboot by NMT reset, an EMCY storm), a Modbus drive that stops answering or
//! answers late, and a client flooding the command path.

use std::time::Duration;

use drivers::can::{FaultId, FaultRule, Frame, IdMatch, PortId, TimeWindow, VirtualPort};
use drivers::time::Instant;
use serde::Deserialize;

use crate::cycle::Transport;
use crate::runtime::virtual_clock::VirtualRun;

/// A kind of fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Deserialize, PartialOrd, Ord)]
#[serde(rename_all = "kebab-case")]
pub enum FaultKind {
    /// A share of a bus's frames is lost.
    FrameLoss,
    /// A bus's frames arrive late.
    FrameDelay,
    /// A share of a bus's process data (TPDO1 or RPDO1) arrives with changed data bytes.
    FrameCorruption,
    /// A share of a bus's frames arrive twice.
    FrameDuplication,
    /// A drive reboots (an NMT reset reaches it), mid-move.
    DriveReboot,
    /// A drive falls off the bus, and comes back rebooting.
    DriveDeath,
    /// A drive's controller goes bus-off, then recovers.
    BusOff,
    /// The coordinator's own controller on a bus goes bus-off, then recovers.
    CoordinatorBusOff,
    /// A drive's EMCY messages, several per cycle.
    EmcyStorm,
    /// SYNCs lost on a bus.
    SyncLoss,
    /// SYNCs late on a bus.
    SyncLate,
    /// A Modbus drive stops answering.
    ModbusDrop,
    /// A Modbus drive answers only every fourth cycle.
    ModbusSlow,
    /// A client sends more commands in one cycle than the coordinator takes.
    ClientFlood,
}

impl FaultKind {
    /// Every kind.
    pub const ALL: [FaultKind; 14] = [
        FaultKind::FrameLoss,
        FaultKind::FrameDelay,
        FaultKind::FrameCorruption,
        FaultKind::FrameDuplication,
        FaultKind::DriveReboot,
        FaultKind::DriveDeath,
        FaultKind::BusOff,
        FaultKind::CoordinatorBusOff,
        FaultKind::EmcyStorm,
        FaultKind::SyncLoss,
        FaultKind::SyncLate,
        FaultKind::ModbusDrop,
        FaultKind::ModbusSlow,
        FaultKind::ClientFlood,
    ];

    /// The kind's name as a scenario file writes it.
    pub fn name(self) -> &'static str {
        match self {
            FaultKind::FrameLoss => "frame-loss",
            FaultKind::FrameDelay => "frame-delay",
            FaultKind::FrameCorruption => "frame-corruption",
            FaultKind::FrameDuplication => "frame-duplication",
            FaultKind::DriveReboot => "drive-reboot",
            FaultKind::DriveDeath => "drive-death",
            FaultKind::BusOff => "bus-off",
            FaultKind::CoordinatorBusOff => "coordinator-bus-off",
            FaultKind::EmcyStorm => "emcy-storm",
            FaultKind::SyncLoss => "sync-loss",
            FaultKind::SyncLate => "sync-late",
            FaultKind::ModbusDrop => "modbus-drop",
            FaultKind::ModbusSlow => "modbus-slow",
            FaultKind::ClientFlood => "client-flood",
        }
    }

    /// What the fault needs: a CANopen axis, a bus, a Modbus axis, or nothing.
    pub fn target(self) -> Needs {
        match self {
            FaultKind::DriveReboot
            | FaultKind::DriveDeath
            | FaultKind::BusOff
            | FaultKind::EmcyStorm => Needs::CanAxis,
            FaultKind::FrameLoss
            | FaultKind::FrameDelay
            | FaultKind::FrameCorruption
            | FaultKind::FrameDuplication
            | FaultKind::CoordinatorBusOff
            | FaultKind::SyncLoss
            | FaultKind::SyncLate => Needs::Bus,
            FaultKind::ModbusDrop | FaultKind::ModbusSlow => Needs::ModbusAxis,
            FaultKind::ClientFlood => Needs::Nothing,
        }
    }
}

/// What a fault kind hits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Needs {
    /// A drive on a CAN bus.
    CanAxis,
    /// A CAN bus.
    Bus,
    /// A drive on Modbus.
    ModbusAxis,
    /// The command path.
    Nothing,
}

/// What a fault hits, resolved.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Target {
    /// An axis (by index).
    Axis(usize),
    /// A bus (by index).
    Bus(usize),
    /// The command path.
    Commands,
}

/// A fault that runs.
#[derive(Debug)]
pub struct Active {
    /// What.
    pub kind: FaultKind,
    /// Where.
    pub target: Target,
    /// When it ends.
    pub until: Instant,
    rule: Option<(usize, FaultId)>,
}

/// Commands a flood sends in one cycle: more than the coordinator's inbox takes.
pub const FLOOD: usize = 300;

/// Starts and ends faults on a [`VirtualRun`]'s simulated machine. Frames a fault sends (an NMT
/// reset, EMCYs) go out of a port of its own on each bus, as another node's would.
pub struct Injector {
    ports: Vec<VirtualPort>,
    seed: u64,
    count: u64,
}

impl std::fmt::Debug for Injector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Injector")
            .field("faults", &self.count)
            .finish_non_exhaustive()
    }
}

fn can_of(run: &VirtualRun<'_>, axis: usize) -> Option<(usize, u8)> {
    match run.io.plan().axes.get(axis)?.setup.transport {
        Transport::Can { bus, node } => Some((usize::from(bus), node)),
        Transport::Modbus { .. } | Transport::Ethercat { .. } => None,
    }
}

fn drive_port(run: &mut VirtualRun<'_>, axis: usize) -> Option<PortId> {
    let name = run.io.plan().axes.get(axis)?.name.clone();
    run.io.drive_mut(&name).map(|d| d.port())
}

fn nmt_reset(node: u8) -> Frame {
    Frame::new_std(0x000, &[0x81, node]).unwrap_or_else(|_| Frame::std8(0, [0; 8]))
}

impl Injector {
    /// An injector for `run`'s buses; `seed` seeds the probabilistic bus rules.
    pub fn new(run: &VirtualRun<'_>, seed: u64) -> Injector {
        Injector {
            ports: run
                .io
                .buses
                .iter()
                .map(|b| b.attach("fault-injector"))
                .collect(),
            seed,
            count: 0,
        }
    }

    /// Starts `kind` on `target` at `now` for `length`; `None` if the target does not fit.
    pub fn start(
        &mut self,
        run: &mut VirtualRun<'_>,
        kind: FaultKind,
        target: Target,
        now: Instant,
        length: Duration,
    ) -> Option<Active> {
        self.count += 1;
        let until = now + length;
        let window = TimeWindow::new(now, until);
        let seed = self.seed ^ self.count.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let mut rule = None;
        let bus_rule = |run: &mut VirtualRun<'_>, bus: usize, r: FaultRule| {
            let b = run.io.buses.get(bus)?;
            Some((bus, b.add_fault(r.during(window))))
        };
        match (kind, target) {
            (FaultKind::FrameLoss, Target::Bus(b)) => {
                rule = bus_rule(
                    run,
                    b,
                    FaultRule::drop(IdMatch::Any).with_probability(0.3, seed),
                );
            }
            (FaultKind::FrameDelay, Target::Bus(b)) => {
                let by = Duration::from_micros(200 + seed % 1800);
                rule = bus_rule(
                    run,
                    b,
                    FaultRule::delay(IdMatch::Any, by).with_probability(0.5, seed),
                );
            }
            (FaultKind::FrameCorruption, Target::Bus(b)) => {
                // Process data, TPDO1 or RPDO1: a real bus's CRC catches a damaged frame (the
                // delay and duplication kinds are what follows); what gets through undetected
                // is a node's bad data.
                let xor = (seed | 1).to_le_bytes();
                let pdo = if seed & 2 == 0 { 0x180 } else { 0x200 };
                let ids = IdMatch::Mask {
                    id: pdo,
                    mask: 0x780,
                };
                rule = bus_rule(
                    run,
                    b,
                    FaultRule::corrupt(ids, xor).with_probability(0.05, seed),
                );
            }
            (FaultKind::FrameDuplication, Target::Bus(b)) => {
                rule = bus_rule(
                    run,
                    b,
                    FaultRule::duplicate(IdMatch::Any).with_probability(0.2, seed),
                );
            }
            (FaultKind::SyncLoss, Target::Bus(b)) => {
                rule = bus_rule(run, b, FaultRule::drop(IdMatch::Exact(0x080)));
            }
            (FaultKind::SyncLate, Target::Bus(b)) => {
                let by = Duration::from_micros(100 + seed % 700);
                rule = bus_rule(run, b, FaultRule::delay(IdMatch::Exact(0x080), by));
            }
            (FaultKind::CoordinatorBusOff, Target::Bus(b)) => {
                let port = run.io.coordinator_port(b)?;
                run.io.buses.get(b)?.set_bus_off(port, window);
            }
            (FaultKind::BusOff, Target::Axis(a)) => {
                let (b, _) = can_of(run, a)?;
                let port = drive_port(run, a)?;
                run.io.buses.get(b)?.set_bus_off(port, window);
            }
            (FaultKind::DriveDeath, Target::Axis(a)) => {
                let (b, _) = can_of(run, a)?;
                let port = drive_port(run, a)?;
                run.io.buses.get(b)?.set_disconnected(port, true);
            }
            (FaultKind::DriveReboot, Target::Axis(a)) => {
                let (b, node) = can_of(run, a)?;
                use drivers::can::Bus;
                let _ = self.ports.get_mut(b)?.send(&nmt_reset(node));
            }
            (FaultKind::EmcyStorm, Target::Axis(a)) => {
                can_of(run, a)?;
            }
            (FaultKind::ModbusDrop | FaultKind::ModbusSlow, Target::Axis(a)) => {
                let slot = match run.io.plan().axes.get(a)?.setup.transport {
                    Transport::Modbus { slot } => usize::from(slot),
                    Transport::Can { .. } | Transport::Ethercat { .. } => return None,
                };
                run.io.cmmo.iter().position(|(s, _)| *s == slot)?;
            }
            (FaultKind::ClientFlood, Target::Commands) => {}
            _ => return None,
        }
        Some(Active {
            kind,
            target,
            until,
            rule,
        })
    }

    /// What a running fault does each cycle (storms, slow answers); `k` is the cycle.
    pub fn tick(&mut self, run: &mut VirtualRun<'_>, f: &Active, k: u64) {
        match (f.kind, f.target) {
            (FaultKind::EmcyStorm, Target::Axis(a)) => {
                if let Some((b, node)) = can_of(run, a)
                    && let Some(p) = self.ports.get_mut(b)
                {
                    use drivers::can::Bus;
                    // Generic error (1000h), error register bit 0: three per cycle.
                    let emcy =
                        Frame::std8(0x080 + u16::from(node), [0x00, 0x10, 0x01, 0, 0, 0, 0, 0]);
                    for _ in 0..3 {
                        let _ = p.send(&emcy);
                    }
                }
            }
            (FaultKind::ModbusDrop, Target::Axis(a)) => set_silent(run, a, true),
            (FaultKind::ModbusSlow, Target::Axis(a)) => set_silent(run, a, !k.is_multiple_of(4)),
            _ => {}
        }
        // The injector's own ports receive every frame: keep their queues empty.
        for p in &mut self.ports {
            use drivers::can::Bus;
            while let Ok(Some(_)) = p.try_recv() {}
        }
    }

    /// Ends a fault: removes its rule, brings a dead drive back (it reboots), answers again.
    pub fn end(&mut self, run: &mut VirtualRun<'_>, f: &Active) {
        if let Some((b, id)) = f.rule
            && let Some(bus) = run.io.buses.get(b)
        {
            bus.remove_fault(id);
        }
        match (f.kind, f.target) {
            (FaultKind::DriveDeath, Target::Axis(a)) => {
                if let (Some((b, node)), Some(port)) = (can_of(run, a), drive_port(run, a))
                    && let Some(bus) = run.io.buses.get(b)
                {
                    bus.set_disconnected(port, false);
                    if let Some(p) = self.ports.get_mut(b) {
                        use drivers::can::Bus;
                        let _ = p.send(&nmt_reset(node));
                    }
                }
            }
            (FaultKind::ModbusDrop | FaultKind::ModbusSlow, Target::Axis(a)) => {
                set_silent(run, a, false);
            }
            _ => {}
        }
    }
}

fn set_silent(run: &mut VirtualRun<'_>, axis: usize, silent: bool) {
    let Some(Transport::Modbus { slot }) = run.io.plan().axes.get(axis).map(|a| a.setup.transport)
    else {
        return;
    };
    if let Some((_, c)) = run
        .io
        .cmmo
        .iter_mut()
        .find(|(s, _)| *s == usize::from(slot))
    {
        c.set_silent(silent);
    }
}
