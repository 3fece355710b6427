//! From a checked configuration to what the cycle and the boot need: axis and group setups in
//! increments, record tables, boot plans. Floating point (user units) ends here, converted by
//! each axis's exact [`Scale`]; the cycle sees integers only.

use std::time::Duration;

use drivers::canopen::NodeId;

use crate::axis::{self, DeviceKind, Profile};
use crate::budget::Supervision as BusSupervision;
use crate::config::{self, AxisConfig, BusKind, Config, SyncMode};
use crate::cycle::{AxisSetup, CycleSetup, GroupSetup, Supervision, Transport};
use crate::fault::Reaction;
use crate::profile::{AxisLimits, Shape};
use crate::records::RecordTable;
use crate::runtime::boot::{self, BootPlan, PdoPlan, SupervisionPlan};
use crate::units::Scale;
use drivers::canopen::pdo::PdoDirection;

pub use crate::config::{MAX_AXES, MAX_BUSES, MAX_GROUPS};

/// One axis, with what the runtime needs beside the cycle's setup.
#[derive(Clone, Debug)]
pub struct AxisPlan {
    /// The name.
    pub name: String,
    /// The user unit.
    pub unit: String,
    /// Increments per unit, exactly.
    pub scale: Scale,
    /// The cycle's setup.
    pub setup: AxisSetup,
    /// The boot plan (CANopen axes).
    pub boot: Option<BootPlan>,
    /// The Modbus address to dial (Modbus axes that are not simulated).
    pub modbus: Option<String>,
    /// An EtherCAT axis: its segment (an index of [`MachinePlan::segments`]) and its position
    /// there, 1 first.
    pub ethercat: Option<(usize, u16)>,
    /// The drive is simulated inside the coordinator (an axis on a `simulated` bus, or a
    /// Modbus axis with `simulated = true`).
    pub simulated: bool,
    /// The drive's own record table as configured (`[[records]]`), in number order: the
    /// machine's description publishes it.
    pub records: Vec<DriveRecordPlan>,
    /// The jerk limit as configured, increments/s³ (`setup.limits` holds a stand-in without
    /// one, which trapezoids ignore).
    pub jerk_limit: Option<u64>,
    /// The force limit as configured, ‰ of nominal.
    pub force_limit_permille: Option<u16>,
}

/// One record of a drive's own record table, as configured, in increments.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DriveRecordPlan {
    /// The record number, 1..=the device's table size.
    pub number: u8,
    /// Target, increments (a distance from the last target when `relative`).
    pub position: i64,
    /// Whether `position` is relative.
    pub relative: bool,
    /// Velocity, increments/s.
    pub velocity: u64,
    /// Acceleration, increments/s² (the axis's limit where the record gives none).
    pub acceleration: u64,
    /// The record chained after this one.
    pub next: Option<u8>,
}

/// One CAN bus of the machine, in configuration order (the cycle's bus index).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BusPlan {
    /// The name (the `vbus:NAME` or the SocketCAN interface).
    pub name: String,
    /// Where its drives are.
    pub kind: BusKind,
    /// Bit/s.
    pub bitrate: u32,
    /// SDO/NMT frames the coordinator may send on it per cycle (its budget's SDO slots).
    pub sdo_slots: u16,
}

impl BusPlan {
    /// How the user names the bus: `vbus:NAME`, `NAME` (SocketCAN) or `NAME (simulated)`.
    pub fn label(&self) -> String {
        match self.kind {
            BusKind::Vbus => format!("vbus:{}", self.name),
            BusKind::Socketcan => self.name.clone(),
            BusKind::Simulated | BusKind::Virtual => format!("{} (simulated)", self.name),
            BusKind::Ethercat => format!("{} (EtherCAT)", self.name),
        }
    }
}

/// One EtherCAT bus: its interface and its subdevices in wiring order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SegmentPlan {
    /// The bus's name.
    pub name: String,
    /// The network interface.
    pub interface: String,
    /// Per subdevice, position 1 first: its axis (an index of [`MachinePlan::axes`]).
    pub axes: Vec<usize>,
    /// Per subdevice, position 1 first: the objects the boot writes over CoE after the PDO
    /// assignment (address, value, size in bytes), the same as on CANopen.
    pub parameters: Vec<Vec<(drivers::canopen::Address, u32, u8)>>,
}

/// A machine, ready to run.
#[derive(Debug)]
pub struct MachinePlan {
    /// Cycle settings.
    pub cycle: CycleSetup,
    /// The cycle period.
    pub period: Duration,
    /// The CAN buses; an axis's `Transport::Can { bus, .. }` indexes this.
    pub buses: Vec<BusPlan>,
    /// The EtherCAT buses, in configuration order.
    pub segments: Vec<SegmentPlan>,
    /// The axes, in configuration order.
    pub axes: Vec<AxisPlan>,
    /// The groups: name, setup, record table.
    pub groups: Vec<(String, GroupSetup, Box<RecordTable>)>,
}

impl MachinePlan {
    /// The axis index of a name.
    pub fn axis(&self, name: &str) -> Option<usize> {
        self.axes.iter().position(|a| a.name == name)
    }
    /// The group index of a name.
    pub fn group(&self, name: &str) -> Option<usize> {
        self.groups.iter().position(|g| g.0 == name)
    }
    /// Whether every drive is simulated inside the coordinator (what virtual time needs).
    pub fn all_simulated(&self) -> bool {
        self.axes.iter().all(|a| a.simulated)
            && self.buses.iter().all(|b| b.kind == BusKind::Simulated)
            && self.segments.is_empty()
    }
    /// The buses whose drives are simulated inside the coordinator, by index.
    pub fn simulated_buses(&self) -> impl Iterator<Item = (usize, &BusPlan)> {
        self.buses
            .iter()
            .enumerate()
            .filter(|(_, b)| b.kind == BusKind::Simulated)
    }
    /// How many process-image slots the cycle has: one per axis on Modbus or EtherCAT.
    pub fn image_slots(&self) -> usize {
        self.axes
            .iter()
            .filter(|a| a.setup.transport.image_slot().is_some())
            .count()
    }
    /// The axis on node `node` of bus `bus`.
    pub fn axis_on(&self, bus: usize, node: u8) -> Option<usize> {
        self.axes.iter().position(|a| {
            a.setup.transport
                == Transport::Can {
                    bus: bus as u8,
                    node,
                }
        })
    }
}

/// A positive value (checked) in increments (per second^n), saturated at `i64::MAX`.
fn inc(v: f64, scale: Scale) -> u64 {
    scale.to_inc(v).map_or(i64::MAX as u64, |i| i.max(0) as u64)
}

fn limits(a: &AxisConfig, s: Scale) -> AxisLimits {
    let l = &a.limits;
    // Without a jerk limit the group is trapezoidal and the jerk is unused; keep it non-zero.
    let jerk = l.jerk.map_or(u64::MAX >> 8, |j| inc(j, s).max(1));
    AxisLimits::new(
        inc(l.velocity, s).max(1),
        inc(l.acceleration, s).max(1),
        jerk,
    )
}

/// Increments per motor revolution of the TLC5xx (AC motor with Sincoder, manual §6.3): its
/// profile velocity is in rpm and its accelerations in rpm/s.
pub const TLC_INCREMENTS_PER_REV: u64 = 16384;

/// The TLC5xx parameters the coordinator's use needs: the homing method (`homing_method`,
/// default 35: the current position is the reference, the embedded machine has no switches)
/// and a profile velocity and
/// acceleration a quarter above the axis's limits, so that the profile-position set-points the
/// coordinator streams are reached before the next one arrives.
fn tlc_parameters(a: &AxisConfig, l: &AxisLimits) -> Vec<(drivers::canopen::Address, u32, u8)> {
    use drivers::canopen::Address;
    let rpm = |inc_per_s: u64| inc_per_s.saturating_mul(60 * 5 / 4) / TLC_INCREMENTS_PER_REV;
    vec![
        (Address::new(0x6098, 0), homing_method(a), 1),
        (
            Address::new(0x6081, 0),
            rpm(l.velocity).clamp(1, 3000) as u32,
            4,
        ),
        (
            Address::new(0x6083, 0),
            rpm(l.acceleration).clamp(60, 2_000_000) as u32,
            4,
        ),
        (
            Address::new(0x6084, 0),
            rpm(l.deceleration).clamp(60, 2_000_000) as u32,
            4,
        ),
    ]
}

/// The generic CiA 402 drive's parameters, in its own units (increments, increments/s,
/// increments/s²: a drive whose factor group is not 1:1 is scaled by `increments_per_unit`):
/// 60C2h the cycle (cyclic synchronous modes), 6065h the following-error window, 607Fh the
/// velocity limit a quarter above the axis's (CSP clamps set-point steps with it), 6081h/6083h/
/// 6084h the profile for PP and homing as for the TLC5xx, 6098h homing method 35 (the current
/// position), 607Dh the axis's position limits (so that the drive itself bounds the travel
/// where the coordinator commands no position: CSV and CST). Only objects the drive's EDS lists
/// as writable are written; without an EDS, all (this project's simulator has them).
fn cia402_parameters(
    a: &AxisConfig,
    l: &AxisLimits,
    s: Scale,
    following_error: i64,
    period: Duration,
) -> Result<Vec<(drivers::canopen::Address, u32, u8)>, String> {
    use drivers::canopen::Address;
    let quarter_above = |v: u64| v.saturating_mul(5) / 4;
    let u32_of = |v: u64| v.min(u64::from(u32::MAX)) as u32;
    let mut p = Vec::new();
    if a.mode() != axis::CyclicMode::Pp {
        let (value, index) = drivers::cia402::modes::interpolation_time_period(period)
            .ok_or_else(|| {
                format!(
                    "axes.{}.mode: the cycle of {} µs cannot be written to 60C2h (value 1..=255 × 10^index s)",
                    a.name,
                    period.as_micros()
                )
            })?;
        p.push((Address::new(0x60C2, 1), u32::from(value), 1));
        p.push((Address::new(0x60C2, 2), u32::from(index as u8), 1));
    }
    p.extend([
        (
            Address::new(0x6065, 0),
            u32_of(following_error.unsigned_abs()),
            4,
        ),
        (
            Address::new(0x607F, 0),
            u32_of(quarter_above(l.velocity)),
            4,
        ),
        (Address::new(0x6081, 0), u32_of(l.velocity), 4),
        (Address::new(0x6083, 0), u32_of(l.acceleration), 4),
        (Address::new(0x6084, 0), u32_of(l.deceleration), 4),
        (Address::new(0x6098, 0), homing_method(a), 1),
    ]);
    // INTEGER32, sent as its four bytes; `check` kept both within ±2^31 increments.
    let i32_bits = |units: f64| s.to_inc(units).unwrap_or(0) as i32 as u32;
    p.extend([
        (Address::new(0x607D, 1), i32_bits(a.limits.position_min), 4),
        (Address::new(0x607D, 2), i32_bits(a.limits.position_max), 4),
    ]);
    if let Some(eds) = &a.eds_read {
        p.retain(|(addr, _, _)| eds.writable(addr.index, addr.sub));
    }
    Ok(p)
}

/// The homing method 6098h the boot writes (INTEGER8, sent as its byte): the configured one
/// (`check` kept it to the drive's), else 35.
fn homing_method(a: &AxisConfig) -> u32 {
    let m = a
        .homing_method
        .and_then(|m| i8::try_from(m).ok())
        .unwrap_or(35);
    u32::from(m as u8)
}

/// The EMCA's PNU 583 "direct start condition" = 1 (interrupt), over SDO 2000h + PNU: its
/// default 0 ignores a START while moving, and the coordinator's streamed targets are STARTs
/// while moving (EMCA manual, PNU 583). The CMMO-ST has the same parameter but no parameter
/// channel in the 8-byte Modbus profile: it is commissioned so (see `runtime::sim`).
fn emca_start_interrupts() -> (drivers::canopen::Address, u32, u8) {
    (drivers::canopen::Address::new(0x2000 + 583, 1), 1, 1)
}

/// The following-error limit, increments: the configured one, or the distance covered at full
/// speed in 100 ms plus 6 cycles. Streamed setpoints lag by a few cycles (FHPP takes one every
/// second cycle, the TLC5xx's PP handshake one every fourth) plus the drive's own loop.
fn following_error_limit(a: &AxisConfig, lim: &AxisLimits, s: Scale, cycle_us: u32) -> i64 {
    let lag_ms = 100 + 6 * u64::from(cycle_us) / 1000;
    a.following_error
        .map_or(lim.velocity * lag_ms / 1000, |e| inc(e, s))
        .max(1) as i64
}

/// Turns a configuration that passed [`Config::check`] into a machine plan.
pub fn plan(cfg: &Config) -> Result<MachinePlan, String> {
    let report = cfg.check();
    if !report.is_ok() {
        return Err(report.to_string());
    }
    // `check` refused more buses, axes or groups than fit, differing periods and a consumer
    // beside other buses: one period and one SYNC mode hold for every bus.
    let cycle_us = cfg
        .buses
        .first()
        .and_then(|b| b.cycle_us)
        .unwrap_or(cfg.cycle_us);
    let can = |b: &&config::BusConfig| b.kind != BusKind::Ethercat;
    let first = cfg.buses.iter().find(can);
    let period = Duration::from_micros(cycle_us.into());
    let setup = CycleSetup {
        cycle_ns: cycle_us * 1000,
        sync_producer: first.is_none_or(|b| b.sync == SyncMode::Producer),
        buses: cfg.buses.iter().filter(can).count() as u8,
        overrun: match cfg.overrun_reaction {
            config::OverrunReactionConfig::Report => crate::fault::OverrunReaction::Report,
            config::OverrunReactionConfig::QuickStop => crate::fault::OverrunReaction::QuickStop,
        },
    };
    let buses: Vec<BusPlan> = cfg
        .buses
        .iter()
        .filter(can)
        .map(|b| BusPlan {
            name: b.name.clone(),
            kind: b.kind,
            bitrate: b.bitrate,
            sdo_slots: b.sdo_slots.max(1),
        })
        .collect();
    let mut segments: Vec<SegmentPlan> = cfg
        .buses
        .iter()
        .filter(|b| b.kind == BusKind::Ethercat)
        .map(|b| SegmentPlan {
            name: b.name.clone(),
            interface: b.interface().to_owned(),
            axes: Vec::new(),
            parameters: Vec::new(),
        })
        .collect();
    let mut axes = Vec::new();
    let mut slot_next = 0u8;
    for a in &cfg.axes {
        let segment = a
            .bus
            .as_deref()
            .and_then(|b| segments.iter().position(|s| s.name == b));
        let s = a
            .scale()
            .map_err(|e| format!("axes.{}.increments_per_unit: {e}", a.name))?;
        let k = a.device.axis_kind();
        let p: Profile = a.profile().into();
        let lim = limits(a, s);
        let (transport, sup, boot) = if a.device.is_modbus() {
            let slot = slot_next;
            slot_next += 1;
            (Transport::Modbus { slot }, Supervision::None, None)
        } else if segment.is_some() {
            let slot = slot_next;
            slot_next += 1;
            (Transport::Ethercat { slot }, Supervision::None, None)
        } else {
            let n = a.node.unwrap_or(0) as u8;
            let bus = a
                .bus
                .as_deref()
                .and_then(|b| buses.iter().position(|p| p.name == b))
                .ok_or_else(|| format!("axes.{}.bus: no such bus", a.name))?;
            let (sup, sp) = match a.supervision() {
                BusSupervision::Heartbeat { period } if !period.is_zero() => {
                    // `check` refused longer heartbeats than the consumer's 16 bits hold.
                    let ms = period.as_millis().min(config::MAX_HEARTBEAT_MS.into()) as u16;
                    (
                        Supervision::Heartbeat {
                            consumer_ms: ms.saturating_mul(2),
                        },
                        SupervisionPlan::Heartbeat { producer_ms: ms },
                    )
                }
                BusSupervision::Guarding { guard_time } if !guard_time.is_zero() => {
                    let ms = guard_time.as_millis().min(u16::MAX as u128) as u16;
                    (
                        Supervision::Guarding {
                            guard_ms: ms,
                            life_factor: 3,
                        },
                        SupervisionPlan::Guarding {
                            guard_ms: ms,
                            life_factor: 3,
                        },
                    )
                }
                _ => (Supervision::None, SupervisionPlan::None),
            };
            let node = NodeId::new(n)
                .ok_or_else(|| format!("axes.{}.node: {n} is not 1..=127", a.name))?;
            let map = axis::pdo_mapping_in(k, p, a.mode());
            let entries = |s: Option<axis::PdoSpec>| s.map_or(&[][..], |s| s.mapping);
            let mut bp = boot::plan_for(node, k, entries(map.rpdo), entries(map.tpdo), sp)
                .map_err(|e| format!("axes.{}: {e}", a.name))?;
            if k == DeviceKind::Tlc5xx {
                bp.parameters = tlc_parameters(a, &lim);
            }
            if k == DeviceKind::Cia402 {
                let fe = following_error_limit(a, &lim, s, cycle_us);
                bp.parameters = cia402_parameters(a, &lim, s, fe, period)?;
                if let Some(eds) = &a.eds_read {
                    bp.device_type = eds.device_type.or(bp.device_type);
                    bp.vendor_id = eds.vendor_id.or(bp.vendor_id);
                }
            }
            if a.fpc
                && let Some(m) = axis::fpc_mapping(k, p)
            {
                for (dir, spec) in [(PdoDirection::Rpdo, m.rpdo), (PdoDirection::Tpdo, m.tpdo)] {
                    if let Some(spec) = spec
                        && let Some(mut pp) = PdoPlan::sync(dir, 2, spec.mapping)
                    {
                        pp.static_mapping = !spec.remappable;
                        bp.pdos.push(pp);
                    }
                }
            }
            if let Some(mapping) = axis::profile_rpdo2_mapping(k, p, a.mode())
                && let Some(mut pp) = PdoPlan::sync(PdoDirection::Rpdo, 2, mapping)
            {
                // Each move's profile (6081h, 6083h), taken as it arrives: in place before the
                // set-point it belongs to is applied at the next SYNC.
                pp.static_mapping = true;
                pp.transmission_type = 255;
                bp.pdos.push(pp);
            }
            if k == DeviceKind::Emca && p == Profile::Fhpp {
                bp.parameters = vec![emca_start_interrupts()];
            }
            (
                Transport::Can {
                    bus: bus as u8,
                    node: n,
                },
                sup,
                Some(bp),
            )
        };
        let fe = following_error_limit(a, &lim, s, cycle_us);
        let mut records: Vec<DriveRecordPlan> = cfg
            .records
            .iter()
            .filter(|r| r.axis == a.name)
            .map(|r| DriveRecordPlan {
                // `check` kept numbers within the device's table (at most 64).
                number: r.number.min(255) as u8,
                // `check` kept it within the axis's limits, so within ±2^31 increments.
                position: s.to_inc(r.position).unwrap_or(0),
                relative: r.relative,
                velocity: inc(r.velocity, s),
                acceleration: r.acceleration.map_or(lim.acceleration, |v| inc(v, s)),
                next: r.next.map(|n| n.min(255) as u8),
            })
            .collect();
        records.sort_by_key(|r| r.number);
        axes.push(AxisPlan {
            name: a.name.clone(),
            unit: a.unit.clone(),
            scale: s,
            setup: AxisSetup {
                kind: k,
                profile: p,
                transport,
                supervision: sup,
                limits: lim,
                // `check` kept both within ±2^31 increments.
                position_min: s.to_inc(a.limits.position_min).unwrap_or(0),
                position_max: s.to_inc(a.limits.position_max).unwrap_or(0),
                following_error: fe,
                // Modbus and EtherCAT report a lost exchange themselves.
                late_cycles: if transport.image_slot().is_some() {
                    0
                } else {
                    3
                },
                fpc: a.fpc && axis::fpc_mapping(k, p).is_some(),
                mode: a.mode(),
            },
            simulated: if a.device.is_modbus() {
                a.simulated
            } else {
                a.bus
                    .as_deref()
                    .and_then(|b| buses.iter().find(|p| p.name == b))
                    .is_some_and(|b| b.kind == BusKind::Simulated)
            },
            boot,
            modbus: a.modbus.clone(),
            // `check` kept the position within 1..=MAX_SUBDEVICES.
            ethercat: segment.map(|s| (s, a.position.unwrap_or(0) as u16)),
            records,
            jerk_limit: a.limits.jerk.map(|j| inc(j, s).max(1)),
            // `check` kept the force within 0..=300 %.
            force_limit_permille: a
                .limits
                .force
                .map(|f| config::PERMILLE_PER_PERCENT.to_inc(f).unwrap_or(0) as u16),
        });
    }
    for (s, seg) in segments.iter_mut().enumerate() {
        let mut on: Vec<(u16, usize)> = axes
            .iter()
            .enumerate()
            .filter_map(|(i, a): (usize, &AxisPlan)| match a.ethercat {
                Some((sa, p)) if sa == s => Some((p, i)),
                _ => None,
            })
            .collect();
        on.sort();
        seg.axes = on.into_iter().map(|(_, i)| i).collect();
        seg.parameters = seg
            .axes
            .iter()
            .map(|&a| {
                // DC SYNC0 mode (1C32h:01 = 2; the coordinator's EtherCAT buses run SYNC0 at
                // the cycle's period), then the drive's own parameters.
                let mut p = vec![(drivers::canopen::Address::new(0x1C32, 1), 2, 2)];
                if axes[a].setup.kind == DeviceKind::Emca {
                    p.push(emca_start_interrupts());
                }
                p
            })
            .collect();
    }
    let mut tables = cfg.group_tables().map_err(|e| e.to_string())?;
    let mut groups = Vec::new();
    for g in &cfg.groups {
        let mut members = heapless::Vec::new();
        let mut jerk = true;
        for name in &g.axes {
            let i = axes
                .iter()
                .position(|a: &AxisPlan| &a.name == name)
                .ok_or_else(|| format!("groups.{}: unknown axis {name}", g.name))?;
            jerk &= cfg.axes[i].limits.jerk.is_some();
            members
                .push(i as u16)
                .map_err(|_| format!("groups.{}: more than 8 axes", g.name))?;
        }
        let table = match tables.iter().position(|(n, _)| n == &g.name) {
            Some(i) => tables.swap_remove(i).1,
            None => Box::new(RecordTable::new()),
        };
        groups.push((
            g.name.clone(),
            GroupSetup {
                axes: members,
                shape: if jerk {
                    Shape::SCurve
                } else {
                    Shape::Trapezoid
                },
                reaction: Reaction::QuickStopGroup,
            },
            table,
        ));
    }
    Ok(MachinePlan {
        cycle: setup,
        period,
        buses,
        segments,
        axes,
        groups,
    })
}
