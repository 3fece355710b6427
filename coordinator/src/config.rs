//! The coordinator's TOML configuration: buses, cycle, axes, groups and record tables, and the
//! check that refuses a configuration that is inconsistent or does not fit its bus budget.
//!
//! [`Config::parse`] reads the text (unknown keys are errors that name the key);
//! [`Config::check`] validates everything, collects *all* errors (each naming its key, e.g.
//! `axes[2].node: 0 is not a CANopen node-ID (1..=127)`), and computes the worst-case load of
//! every bus with [`crate::budget`]. The per-axis PDO traffic is derived from the device kind and
//! profile ([`axis_pdos`]), so a user cannot under-declare it. Every key, its unit and default
//! is documented in `docs/configuration.md`; [`EXAMPLE`] is the embedded default machine.
//!
//! Floats appear only here, at the edge: limits and records are given in user units and are
//! converted to whole increments once, and refused when the result does not fit the drive's
//! integer range.

use std::collections::HashMap;
use std::fmt;
use std::time::Duration;

use drivers::can::bit_timing::{MAX_BITRATE, MIN_BITRATE};
use serde::Deserialize;

use crate::budget::{BusLoad, BusTraffic, Pdo, Permille, Supervision};

/// The commented example `coordinator config-example` prints: four axes, one of each device
/// kind, on the virtual bus and Modbus TCP, a group and a few records.
pub const EXAMPLE: &str = include_str!("../examples/machine.toml");

/// Allowed cycle periods in microseconds (the same range as `coordinator run --cycle-us`).
pub const CYCLE_US: core::ops::RangeInclusive<u32> = 250..=100_000;
/// The default bus-load limit in percent.
pub const DEFAULT_LOAD_LIMIT_PERCENT: u32 = 80;
/// The default heartbeat / guard time in milliseconds.
pub const DEFAULT_SUPERVISION_MS: u32 = 100;

/// A whole configuration file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// The SYNC period in microseconds, for every bus that does not set its own.
    pub cycle_us: u32,
    /// Refuse a bus whose worst cycle exceeds this share of the cycle (percent, 1..=100).
    #[serde(default = "default_load_limit")]
    pub load_limit_percent: u32,
    /// The CAN buses.
    #[serde(default)]
    pub buses: Vec<BusConfig>,
    /// The axes (drives).
    #[serde(default)]
    pub axes: Vec<AxisConfig>,
    /// Axis groups (moved together, time-synchronised).
    #[serde(default)]
    pub groups: Vec<GroupConfig>,
    /// Record tables: positioning records per axis.
    #[serde(default)]
    pub records: Vec<RecordConfig>,
}

fn default_load_limit() -> u32 {
    DEFAULT_LOAD_LIMIT_PERCENT
}

fn default_bitrate() -> u32 {
    1_000_000
}

fn default_one() -> u16 {
    1
}

/// How a bus reaches the wire.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BusKind {
    /// The project's virtual bus (`vbus:NAME`), named by the bus's name.
    Virtual,
    /// A SocketCAN interface of the same name as the bus.
    Socketcan,
}

/// Who produces the SYNC on a bus.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SyncMode {
    /// The coordinator sends SYNC on its own deadline.
    #[default]
    Producer,
    /// Another node produces SYNC; the coordinator's cycle follows it.
    Consumer,
}

/// One CAN bus.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BusConfig {
    /// Name, unique; also the virtual bus name or the SocketCAN interface.
    pub name: String,
    /// Virtual or SocketCAN.
    pub kind: BusKind,
    /// Bitrate in bit/s.
    #[serde(default = "default_bitrate")]
    pub bitrate: u32,
    /// This bus's SYNC period in microseconds; defaults to the top-level `cycle_us`.
    pub cycle_us: Option<u32>,
    /// SYNC producer or consumer.
    #[serde(default)]
    pub sync: SyncMode,
    /// Whether SYNC carries the counter byte (0x1019 > 0).
    #[serde(default)]
    pub sync_counter: bool,
    /// 8-byte EMCY frames allowed for per cycle, all nodes together.
    #[serde(default = "default_one")]
    pub emcy_per_cycle: u16,
    /// SDO slots reserved per cycle (an 8-byte request and an 8-byte response each).
    #[serde(default = "default_one")]
    pub sdo_slots: u16,
}

/// The supported drives.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DeviceKind {
    /// Festo MTR-DCI (CANopen; FHPP or CiA 402; node guarding only).
    MtrDci,
    /// Festo EMCA (CANopen; FHPP, or CiA 402 with its other firmware profile; guarding only).
    Emca,
    /// Festo CMMO-ST (Modbus TCP; FHPP).
    CmmoSt,
    /// Schneider TLC5xx (CANopen; CiA 402).
    Tlc5xx,
}

impl DeviceKind {
    /// The name used in the configuration.
    pub fn name(self) -> &'static str {
        match self {
            Self::MtrDci => "mtr-dci",
            Self::Emca => "emca",
            Self::CmmoSt => "cmmo-st",
            Self::Tlc5xx => "tlc5xx",
        }
    }

    /// The profiles the device offers; the first is the default.
    pub fn profiles(self) -> &'static [Profile] {
        match self {
            Self::MtrDci | Self::Emca => &[Profile::Fhpp, Profile::Cia402],
            Self::CmmoSt => &[Profile::Fhpp],
            Self::Tlc5xx => &[Profile::Cia402],
        }
    }

    /// Whether the device is reached over Modbus TCP rather than CANopen.
    pub fn is_modbus(self) -> bool {
        self == Self::CmmoSt
    }

    /// Whether the device can produce a heartbeat. The MTR-DCI and EMCA manuals describe node
    /// guarding only (seed-000 and seed-002 digests), so they are guarded.
    pub fn has_heartbeat(self) -> bool {
        matches!(self, Self::Tlc5xx)
    }

    /// The highest record number of the device's (or, for the TLC5xx, the host's) table.
    pub fn max_record(self) -> u32 {
        match self {
            // Records 1..=31; record 0 is homing (seed-000 section 4).
            Self::MtrDci => 31,
            // 64 records with record 0 homing (seed-001 / seed-002).
            Self::Emca | Self::CmmoSt => 63,
            // No drive-side table: the coordinator holds it.
            Self::Tlc5xx => 255,
        }
    }
}

impl fmt::Display for DeviceKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The device profile the coordinator speaks to a drive.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Profile {
    /// Festo Handling and Positioning Profile.
    Fhpp,
    /// CiA 402 drives and motion control.
    Cia402,
}

impl fmt::Display for Profile {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Fhpp => "fhpp",
            Self::Cia402 => "cia402",
        })
    }
}

/// FHPP: 8 control bytes and 8 status bytes on PDO1, every SYNC.
const FHPP_PDO1: &[Pdo] = &[Pdo::every_sync(8)];
/// FHPP with the FPC parameter channel on PDO2 (8 bytes each way).
const FHPP_PDO1_FPC: &[Pdo] = &[Pdo::every_sync(8), Pdo::every_sync(8)];
/// CiA 402: controlword + target position (2 + 4 bytes) / statusword + position actual value.
const CIA402_PDO1: &[Pdo] = &[Pdo::every_sync(6)];

/// The PDOs the coordinator maps for one axis, each way (the RPDOs equal the TPDOs in length
/// and number for every supported mapping). Modbus axes put nothing on a CAN bus.
pub fn axis_pdos(device: DeviceKind, profile: Profile, fpc: bool) -> &'static [Pdo] {
    if device.is_modbus() {
        return &[];
    }
    match (profile, fpc) {
        (Profile::Fhpp, false) => FHPP_PDO1,
        (Profile::Fhpp, true) => FHPP_PDO1_FPC,
        (Profile::Cia402, _) => CIA402_PDO1,
    }
}

/// Motion limits in user units (the axis's `unit`, per second, per second squared...).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Limits {
    /// Lowest position, in units.
    pub position_min: f64,
    /// Highest position, in units.
    pub position_max: f64,
    /// Highest speed, in units/s.
    pub velocity: f64,
    /// Highest acceleration and deceleration, in units/s².
    pub acceleration: f64,
    /// Highest jerk, in units/s³; none means trapezoidal profiles.
    pub jerk: Option<f64>,
    /// Highest force / torque, in percent of the drive's nominal value (1..=300).
    pub force: Option<f64>,
}

/// One axis.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisConfig {
    /// Name, unique.
    pub name: String,
    /// The drive.
    pub device: DeviceKind,
    /// The profile; defaults to the device's first ([`DeviceKind::profiles`]).
    pub profile: Option<Profile>,
    /// The CAN bus (CANopen devices only).
    pub bus: Option<String>,
    /// The CANopen node-ID, 1..=127 (CANopen devices only).
    pub node: Option<i64>,
    /// The Modbus TCP address `host:port` (Modbus devices only).
    pub modbus: Option<String>,
    /// Map the FHPP parameter channel (FPC) on PDO2 (FHPP over CANopen only).
    #[serde(default)]
    pub fpc: bool,
    /// Producer heartbeat time in ms (0 disables); only for devices with a heartbeat.
    pub heartbeat_ms: Option<u32>,
    /// Node-guarding guard time in ms (0 disables).
    pub guard_time_ms: Option<u32>,
    /// The user unit's name, for display ("mm", "deg").
    #[serde(default = "default_unit")]
    pub unit: String,
    /// Drive increments per user unit.
    pub increments_per_unit: f64,
    /// Motion limits.
    pub limits: Limits,
    /// Largest |setpoint - actual| while following a path, in units, before the axis faults;
    /// default: the distance covered in 50 ms at the velocity limit.
    pub following_error: Option<f64>,
}

fn default_unit() -> String {
    "mm".into()
}

impl AxisConfig {
    /// The profile in use (the configured one or the device's default).
    pub fn profile(&self) -> Profile {
        self.profile.unwrap_or(self.device.profiles()[0])
    }

    /// The supervision this axis adds to its bus: guarding for devices without a heartbeat,
    /// otherwise heartbeat unless a guard time is set.
    pub fn supervision(&self) -> Supervision {
        let ms = |v: u32| Duration::from_millis(v.into());
        match (self.heartbeat_ms, self.guard_time_ms) {
            (_, Some(g)) => Supervision::Guarding { guard_time: ms(g) },
            (Some(h), None) => Supervision::Heartbeat { period: ms(h) },
            (None, None) if self.device.has_heartbeat() => Supervision::Heartbeat {
                period: ms(DEFAULT_SUPERVISION_MS),
            },
            (None, None) => Supervision::Guarding {
                guard_time: ms(DEFAULT_SUPERVISION_MS),
            },
        }
    }
}

/// A group of axes moved together.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroupConfig {
    /// Name, unique.
    pub name: String,
    /// Member axes by name; an axis belongs to at most one group.
    pub axes: Vec<String>,
}

/// One positioning record.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordConfig {
    /// The axis by name.
    pub axis: String,
    /// Record number, 1..=the device's table size.
    pub number: u32,
    /// Target position (absolute) or distance (relative), in units.
    pub position: f64,
    /// Whether `position` is relative to the last target.
    #[serde(default)]
    pub relative: bool,
    /// Speed in units/s, > 0 and at most the axis limit.
    pub velocity: f64,
    /// Acceleration in units/s²; defaults to the axis limit.
    pub acceleration: Option<f64>,
    /// The record chained after this one (same axis).
    pub next: Option<u32>,
}

/// What is wrong with one setting.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Problem {
    /// The text is not valid TOML for this schema (unknown key, wrong type, missing key).
    #[error("{0}")]
    Parse(String),
    /// A node-ID outside 1..=127.
    #[error("{0} is not a CANopen node-ID (1..=127)")]
    NodeId(i64),
    /// Two axes with the same node-ID on one bus.
    #[error("node {node} on bus {bus} is already used by {other}")]
    DuplicateNode {
        /// The node-ID.
        node: i64,
        /// The bus.
        bus: String,
        /// The key of the first user.
        other: String,
    },
    /// A name used twice.
    #[error("the name {0:?} is already used by {1}")]
    DuplicateName(String, String),
    /// A bus name no bus has.
    #[error("no bus named {0:?}")]
    UnknownBus(String),
    /// An axis name no axis has.
    #[error("no axis named {0:?}")]
    UnknownAxis(String),
    /// A required key of this kind of axis is missing.
    #[error("missing: a {device} axis needs it")]
    Missing {
        /// The device.
        device: DeviceKind,
    },
    /// A key this kind of axis must not have.
    #[error("a {device} axis {reason}")]
    NotAllowed {
        /// The device.
        device: DeviceKind,
        /// Why.
        reason: &'static str,
    },
    /// A profile the device does not offer.
    #[error("{device} does not offer the {profile} profile")]
    Profile {
        /// The device.
        device: DeviceKind,
        /// The profile.
        profile: Profile,
    },
    /// A Modbus address that is not `host:port`.
    #[error("{0:?} is not host:port with a port in 1..=65535")]
    ModbusAddress(String),
    /// A number outside its range.
    #[error("{value} is outside {min}..={max}")]
    Range {
        /// The value.
        value: f64,
        /// Lowest allowed.
        min: f64,
        /// Highest allowed.
        max: f64,
    },
    /// A number that must be positive (and finite) is not.
    #[error("{0} must be a positive number")]
    NotPositive(f64),
    /// A number that must be finite is infinite or NaN.
    #[error("{0} is not a finite number")]
    NotFinite(f64),
    /// The lower bound is not below the upper one.
    #[error("{min} is not below position_max {max}")]
    EmptyRange {
        /// The lower bound.
        min: f64,
        /// The upper bound.
        max: f64,
    },
    /// A value that, scaled to increments, leaves the drive's 32-bit range.
    #[error("{value} units are {increments} increments, outside the drive's 32-bit range")]
    Increments {
        /// The value in units.
        value: f64,
        /// The scaled value.
        increments: f64,
    },
    /// A value below one increment (per second...) after scaling: the drive would see 0.
    #[error("{value} units are {increments} increments, less than one")]
    BelowOneIncrement {
        /// The value in units.
        value: f64,
        /// The scaled value.
        increments: f64,
    },
    /// A value above the axis's limit.
    #[error("{value} exceeds the axis limit {limit}")]
    OverLimit {
        /// The value.
        value: f64,
        /// The limit.
        limit: f64,
    },
    /// Heartbeat and guarding both set.
    #[error("heartbeat_ms and guard_time_ms are exclusive (CiA 301)")]
    BothSupervisions,
    /// An axis listed in two groups.
    #[error("axis {axis:?} is already in group {group:?}")]
    TwoGroups {
        /// The axis.
        axis: String,
        /// The first group.
        group: String,
    },
    /// A group without axes.
    #[error("a group needs at least one axis")]
    EmptyGroup,
    /// A group whose buses' SYNCs do not line up.
    #[error("buses {a:?} and {b:?} do not share one SYNC: {reason}")]
    Unaligned {
        /// One bus.
        a: String,
        /// The other.
        b: String,
        /// Why.
        reason: &'static str,
    },
    /// A group mixing Modbus and CANopen axes: Modbus has no SYNC to latch on.
    #[error("axis {0:?} is on Modbus, which has no SYNC; it cannot move with CANopen axes")]
    ModbusInGroup(String),
    /// Two records with one number on one axis.
    #[error("record {number} of axis {axis:?} is already defined by {other}")]
    DuplicateRecord {
        /// The axis.
        axis: String,
        /// The record number.
        number: u32,
        /// The key of the first definition.
        other: String,
    },
    /// A `next` naming a record the axis does not have.
    #[error("axis {axis:?} has no record {number}")]
    UnknownRecord {
        /// The axis.
        axis: String,
        /// The record number.
        number: u32,
    },
    /// The bus budget refuses the bus (the message carries the numbers).
    #[error("{0}")]
    Budget(String),
}

/// One refused setting: the key and what is wrong with it.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{key}: {problem}")]
pub struct ConfigError {
    /// The key, as a path (`axes[2].node`).
    pub key: String,
    /// What is wrong.
    pub problem: Problem,
}

/// The outcome of [`Config::check`]: every bus's worst cycle and every refusal.
#[derive(Debug)]
pub struct Report<'a> {
    /// The worst cycle of every bus whose settings could be computed, in configuration order.
    pub loads: Vec<BusLoad<'a>>,
    /// All refusals, in configuration order, budget refusals last.
    pub errors: Vec<ConfigError>,
}

impl Report<'_> {
    /// Whether the configuration is accepted.
    pub fn is_ok(&self) -> bool {
        self.errors.is_empty()
    }
}

/// What `coordinator check` prints: the budget of every bus, then `OK` or every refusal.
impl fmt::Display for Report<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for load in &self.loads {
            writeln!(f, "{load}")?;
        }
        if self.errors.is_empty() {
            return writeln!(f, "OK");
        }
        for e in &self.errors {
            writeln!(f, "error: {e}")?;
        }
        writeln!(f, "refused: {} error(s)", self.errors.len())
    }
}

/// Collects errors; `push` keeps the code below one line per check.
struct Errors(Vec<ConfigError>);

impl Errors {
    fn push(&mut self, key: impl Into<String>, problem: Problem) {
        self.0.push(ConfigError {
            key: key.into(),
            problem,
        });
    }

    /// A positive, finite number.
    fn positive(&mut self, key: &str, v: f64) -> bool {
        let ok = v.is_finite() && v > 0.0;
        if !ok {
            self.push(key, Problem::NotPositive(v));
        }
        ok
    }
}

/// The per-bus traffic lists the budget borrows.
#[derive(Default)]
struct BusPlan {
    pdos: Vec<Pdo>,
    nodes: Vec<Supervision>,
}

impl Config {
    /// Parses a configuration; unknown keys, wrong types and missing keys are errors whose
    /// message names the key and the line.
    pub fn parse(text: &str) -> Result<Self, ConfigError> {
        toml::from_str(text).map_err(|e| ConfigError {
            key: e
                .span()
                .map(|s| {
                    let line = 1 + text.get(..s.start).map_or(0, |t| t.matches('\n').count());
                    format!("line {line}")
                })
                .unwrap_or_else(|| "file".into()),
            problem: Problem::Parse(e.message().trim().to_string()),
        })
    }

    /// The SYNC period of bus `i` in microseconds.
    fn bus_cycle_us(&self, bus: &BusConfig) -> u32 {
        bus.cycle_us.unwrap_or(self.cycle_us)
    }

    /// Validates everything and computes every bus's worst cycle; see [`Report`].
    pub fn check(&self) -> Report<'_> {
        let mut err = Errors(Vec::new());
        let cycle_ok = self.check_cycle("cycle_us", self.cycle_us, &mut err);
        if !(1..=100).contains(&self.load_limit_percent) {
            err.push(
                "load_limit_percent",
                Problem::Range {
                    value: self.load_limit_percent.into(),
                    min: 1.0,
                    max: 100.0,
                },
            );
        }

        // Buses.
        let mut bus_index: HashMap<&str, usize> = HashMap::new();
        let mut bus_ok = Vec::with_capacity(self.buses.len());
        for (i, b) in self.buses.iter().enumerate() {
            let key = format!("buses[{i}]");
            if let Some(&j) = bus_index.get(b.name.as_str()) {
                err.push(
                    format!("{key}.name"),
                    Problem::DuplicateName(b.name.clone(), format!("buses[{j}]")),
                );
            } else {
                bus_index.insert(&b.name, i);
            }
            let mut ok = true;
            if !(MIN_BITRATE..=MAX_BITRATE).contains(&b.bitrate) {
                err.push(
                    format!("{key}.bitrate"),
                    Problem::Range {
                        value: b.bitrate.into(),
                        min: MIN_BITRATE.into(),
                        max: MAX_BITRATE.into(),
                    },
                );
                ok = false;
            }
            ok &= match b.cycle_us {
                Some(c) => self.check_cycle(&format!("{key}.cycle_us"), c, &mut err),
                None => cycle_ok,
            };
            bus_ok.push(ok);
        }

        // Axes.
        let mut axis_index: HashMap<&str, usize> = HashMap::new();
        let mut nodes: HashMap<(&str, i64), usize> = HashMap::new();
        let mut plans: Vec<BusPlan> = self.buses.iter().map(|_| BusPlan::default()).collect();
        for (i, a) in self.axes.iter().enumerate() {
            let key = format!("axes[{i}]");
            if let Some(&j) = axis_index.get(a.name.as_str()) {
                err.push(
                    format!("{key}.name"),
                    Problem::DuplicateName(a.name.clone(), format!("axes[{j}]")),
                );
            } else {
                axis_index.insert(&a.name, i);
            }
            let profile = a.profile();
            if !a.device.profiles().contains(&profile) {
                err.push(
                    format!("{key}.profile"),
                    Problem::Profile {
                        device: a.device,
                        profile,
                    },
                );
            }
            let device = a.device;
            if device.is_modbus() {
                let not = |reason| Problem::NotAllowed { device, reason };
                if a.bus.is_some() {
                    err.push(
                        format!("{key}.bus"),
                        not("is on Modbus TCP, not on a CAN bus"),
                    );
                }
                if a.node.is_some() {
                    err.push(
                        format!("{key}.node"),
                        not("has a Modbus address, not a node-ID"),
                    );
                }
                if a.fpc {
                    err.push(format!("{key}.fpc"), not("has no CANopen PDO2 for the FPC"));
                }
                if a.heartbeat_ms.is_some() || a.guard_time_ms.is_some() {
                    let k = if a.heartbeat_ms.is_some() {
                        "heartbeat_ms"
                    } else {
                        "guard_time_ms"
                    };
                    err.push(
                        format!("{key}.{k}"),
                        not("is supervised by its Modbus timeout"),
                    );
                }
                match &a.modbus {
                    None => err.push(format!("{key}.modbus"), Problem::Missing { device }),
                    Some(addr) if !valid_host_port(addr) => err.push(
                        format!("{key}.modbus"),
                        Problem::ModbusAddress(addr.clone()),
                    ),
                    Some(_) => {}
                }
            } else {
                let not = |reason| Problem::NotAllowed { device, reason };
                if a.modbus.is_some() {
                    err.push(
                        format!("{key}.modbus"),
                        not("is on CANopen, not on Modbus TCP"),
                    );
                }
                if a.fpc && profile != Profile::Fhpp {
                    err.push(
                        format!("{key}.fpc"),
                        not("has the FPC only with the fhpp profile"),
                    );
                }
                match (a.heartbeat_ms, a.guard_time_ms) {
                    (Some(_), Some(_)) => {
                        err.push(format!("{key}.heartbeat_ms"), Problem::BothSupervisions)
                    }
                    (Some(_), None) if !device.has_heartbeat() => err.push(
                        format!("{key}.heartbeat_ms"),
                        not("has no heartbeat, only node guarding (use guard_time_ms)"),
                    ),
                    _ => {}
                }
                let node = match a.node {
                    None => {
                        err.push(format!("{key}.node"), Problem::Missing { device });
                        None
                    }
                    Some(n) if !(1..=127).contains(&n) => {
                        err.push(format!("{key}.node"), Problem::NodeId(n));
                        None
                    }
                    Some(n) => Some(n),
                };
                let bus = match &a.bus {
                    None => {
                        err.push(format!("{key}.bus"), Problem::Missing { device });
                        None
                    }
                    Some(b) => match bus_index.get(b.as_str()) {
                        None => {
                            err.push(format!("{key}.bus"), Problem::UnknownBus(b.clone()));
                            None
                        }
                        Some(&bi) => Some(bi),
                    },
                };
                if let Some(bi) = bus {
                    plans[bi]
                        .pdos
                        .extend_from_slice(axis_pdos(device, profile, a.fpc));
                    plans[bi].nodes.push(a.supervision());
                    if let Some(n) = node {
                        let bus_name = self.buses[bi].name.as_str();
                        if let Some(&j) = nodes.get(&(bus_name, n)) {
                            err.push(
                                format!("{key}.node"),
                                Problem::DuplicateNode {
                                    node: n,
                                    bus: bus_name.to_string(),
                                    other: format!("axes[{j}]"),
                                },
                            );
                        } else {
                            nodes.insert((bus_name, n), i);
                        }
                    }
                }
            }
            check_scaling(&key, a, &mut err);
        }

        self.check_groups(&axis_index, &bus_index, &mut err);
        self.check_records(&axis_index, &mut err);

        // Budgets: every bus whose own settings are valid.
        let limit = Permille::from_percent(self.load_limit_percent.clamp(1, 100));
        let mut loads = Vec::new();
        for (i, b) in self.buses.iter().enumerate() {
            if !bus_ok[i] {
                continue;
            }
            let plan = &plans[i];
            let traffic = BusTraffic {
                name: &b.name,
                bitrate: b.bitrate,
                cycle: Duration::from_micros(self.bus_cycle_us(b).into()),
                sync_counter: b.sync_counter,
                rpdos: &plan.pdos,
                tpdos: &plan.pdos,
                nodes: &plan.nodes,
                emcy_per_cycle: b.emcy_per_cycle,
                sdo_slots: b.sdo_slots,
            };
            match BusLoad::compute(&traffic) {
                Ok(load) => {
                    if let Err(e) = load.check(limit) {
                        err.push(format!("buses[{i}]"), Problem::Budget(e.to_string()));
                    }
                    // Re-borrow the name from the configuration: the traffic lists are local.
                    loads.push(BusLoad {
                        name: &b.name,
                        bitrate: load.bitrate,
                        cycle: load.cycle,
                        sync: load.sync,
                        rpdo: load.rpdo,
                        tpdo: load.tpdo,
                        supervision: load.supervision,
                        emcy: load.emcy,
                        sdo: load.sdo,
                    });
                }
                Err(e) => err.push(format!("buses[{i}]"), Problem::Budget(e.to_string())),
            }
        }
        Report {
            loads,
            errors: err.0,
        }
    }

    fn check_cycle(&self, key: &str, cycle_us: u32, err: &mut Errors) -> bool {
        let ok = CYCLE_US.contains(&cycle_us);
        if !ok {
            err.push(
                key,
                Problem::Range {
                    value: cycle_us.into(),
                    min: (*CYCLE_US.start()).into(),
                    max: (*CYCLE_US.end()).into(),
                },
            );
        }
        ok
    }

    fn check_groups(
        &self,
        axis_index: &HashMap<&str, usize>,
        bus_index: &HashMap<&str, usize>,
        err: &mut Errors,
    ) {
        let mut names: HashMap<&str, usize> = HashMap::new();
        let mut member_of: HashMap<&str, &str> = HashMap::new();
        for (g, group) in self.groups.iter().enumerate() {
            let key = format!("groups[{g}]");
            if let Some(&j) = names.get(group.name.as_str()) {
                err.push(
                    format!("{key}.name"),
                    Problem::DuplicateName(group.name.clone(), format!("groups[{j}]")),
                );
            } else {
                names.insert(&group.name, g);
            }
            if group.axes.is_empty() {
                err.push(format!("{key}.axes"), Problem::EmptyGroup);
            }
            // The first CANopen member's bus, against which the others must line up.
            let mut first_bus: Option<&BusConfig> = None;
            let mut modbus: Option<&str> = None;
            let mut canopen = false;
            for (k, name) in group.axes.iter().enumerate() {
                let akey = format!("{key}.axes[{k}]");
                let Some(&ai) = axis_index.get(name.as_str()) else {
                    err.push(akey, Problem::UnknownAxis(name.clone()));
                    continue;
                };
                if let Some(other) = member_of.insert(name, &group.name) {
                    err.push(
                        akey.clone(),
                        Problem::TwoGroups {
                            axis: name.clone(),
                            group: other.to_string(),
                        },
                    );
                }
                let axis = &self.axes[ai];
                if axis.device.is_modbus() {
                    modbus.get_or_insert(name);
                    continue;
                }
                canopen = true;
                let Some(bus) = axis
                    .bus
                    .as_deref()
                    .and_then(|b| bus_index.get(b))
                    .map(|&bi| &self.buses[bi])
                else {
                    continue;
                };
                match first_bus {
                    None => first_bus = Some(bus),
                    Some(first) if first.name != bus.name => {
                        let reason = if self.bus_cycle_us(first) != self.bus_cycle_us(bus) {
                            Some("their cycle periods differ")
                        } else if first.sync == SyncMode::Consumer || bus.sync == SyncMode::Consumer
                        {
                            Some(
                                "a SYNC consumer bus follows a producer the coordinator does not time",
                            )
                        } else {
                            None
                        };
                        if let Some(reason) = reason {
                            err.push(
                                akey,
                                Problem::Unaligned {
                                    a: first.name.clone(),
                                    b: bus.name.clone(),
                                    reason,
                                },
                            );
                        }
                    }
                    Some(_) => {}
                }
            }
            if let (true, Some(m)) = (canopen, modbus) {
                err.push(format!("{key}.axes"), Problem::ModbusInGroup(m.to_string()));
            }
        }
    }

    fn check_records(&self, axis_index: &HashMap<&str, usize>, err: &mut Errors) {
        let mut defined: HashMap<(&str, u32), usize> = HashMap::new();
        for (r, rec) in self.records.iter().enumerate() {
            defined.entry((rec.axis.as_str(), rec.number)).or_insert(r);
        }
        for (r, rec) in self.records.iter().enumerate() {
            let key = format!("records[{r}]");
            let Some(&ai) = axis_index.get(rec.axis.as_str()) else {
                err.push(
                    format!("{key}.axis"),
                    Problem::UnknownAxis(rec.axis.clone()),
                );
                continue;
            };
            let axis = &self.axes[ai];
            let max = axis.device.max_record();
            if !(1..=max).contains(&rec.number) {
                err.push(
                    format!("{key}.number"),
                    Problem::Range {
                        value: rec.number.into(),
                        min: 1.0,
                        max: max.into(),
                    },
                );
            }
            if let Some(&first) = defined.get(&(rec.axis.as_str(), rec.number))
                && first != r
            {
                err.push(
                    format!("{key}.number"),
                    Problem::DuplicateRecord {
                        axis: rec.axis.clone(),
                        number: rec.number,
                        other: format!("records[{first}]"),
                    },
                );
            }
            if let Some(next) = rec.next
                && !defined.contains_key(&(rec.axis.as_str(), next))
            {
                err.push(
                    format!("{key}.next"),
                    Problem::UnknownRecord {
                        axis: rec.axis.clone(),
                        number: next,
                    },
                );
            }
            let l = &axis.limits;
            if !rec.position.is_finite() {
                err.push(format!("{key}.position"), Problem::NotFinite(rec.position));
            } else if !rec.relative
                && l.position_min < l.position_max
                && !(l.position_min..=l.position_max).contains(&rec.position)
            {
                err.push(
                    format!("{key}.position"),
                    Problem::Range {
                        value: rec.position,
                        min: l.position_min,
                        max: l.position_max,
                    },
                );
            }
            for (name, value, limit) in [
                ("velocity", Some(rec.velocity), l.velocity),
                ("acceleration", rec.acceleration, l.acceleration),
            ] {
                let Some(value) = value else { continue };
                let k = format!("{key}.{name}");
                if err.positive(&k, value) && value > limit {
                    err.push(k, Problem::OverLimit { value, limit });
                }
            }
        }
    }
}

/// Checks the scaling and the limits of one axis, in units and in increments.
fn check_scaling(key: &str, a: &AxisConfig, err: &mut Errors) {
    let scale_ok = err.positive(&format!("{key}.increments_per_unit"), a.increments_per_unit);
    if let Some(fe) = a.following_error {
        err.positive(&format!("{key}.following_error"), fe);
    }
    let l = &a.limits;
    let lk = format!("{key}.limits");
    let scaled = |v: f64| v * a.increments_per_unit;
    for (name, v) in [
        ("position_min", l.position_min),
        ("position_max", l.position_max),
    ] {
        if !v.is_finite() {
            err.push(format!("{lk}.{name}"), Problem::NotFinite(v));
        } else if scale_ok && !(i32::MIN as f64..=i32::MAX as f64).contains(&scaled(v)) {
            err.push(
                format!("{lk}.{name}"),
                Problem::Increments {
                    value: v,
                    increments: scaled(v),
                },
            );
        }
    }
    if l.position_min.is_finite() && l.position_max.is_finite() && l.position_min >= l.position_max
    {
        err.push(
            format!("{lk}.position_min"),
            Problem::EmptyRange {
                min: l.position_min,
                max: l.position_max,
            },
        );
    }
    for (name, v) in [
        ("velocity", Some(l.velocity)),
        ("acceleration", Some(l.acceleration)),
        ("jerk", l.jerk),
    ] {
        let Some(v) = v else { continue };
        let k = format!("{lk}.{name}");
        if !err.positive(&k, v) || !scale_ok {
            continue;
        }
        let inc = scaled(v);
        if inc < 1.0 {
            err.push(
                k,
                Problem::BelowOneIncrement {
                    value: v,
                    increments: inc,
                },
            );
        } else if inc > u32::MAX as f64 {
            err.push(
                k,
                Problem::Increments {
                    value: v,
                    increments: inc,
                },
            );
        }
    }
    if let Some(f) = l.force
        && !(f.is_finite() && f > 0.0 && f <= 300.0)
    {
        err.push(
            format!("{lk}.force"),
            Problem::Range {
                value: f,
                min: 0.0,
                max: 300.0,
            },
        );
    }
}

/// `host:port` with a non-empty host and a port in 1..=65535.
fn valid_host_port(s: &str) -> bool {
    match s.rsplit_once(':') {
        Some((host, port)) => {
            !host.is_empty()
                && !host.contains(char::is_whitespace)
                && port.parse::<u16>().is_ok_and(|p| p != 0)
        }
        None => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The example with `from` replaced by `to` (which must occur).
    fn edited(edits: &[(&str, &str)]) -> String {
        let mut text = EXAMPLE.to_string();
        for (from, to) in edits {
            assert!(text.contains(from), "{from:?} not in the example");
            text = text.replacen(from, to, 1);
        }
        text
    }

    fn errors(text: &str) -> Vec<String> {
        let c = Config::parse(text).unwrap();
        c.check().errors.iter().map(|e| e.to_string()).collect()
    }

    #[test]
    fn example_is_accepted_with_its_budget() {
        let c = Config::parse(EXAMPLE).unwrap();
        let r = c.check();
        assert!(r.is_ok(), "{r}");
        assert_eq!(r.loads.len(), 1);
        let l = &r.loads[0];
        // SYNC 55 + 2 * (135 + 135 + 115) PDO bits + guarding 2 * (55 + 65) + heartbeat 65
        // + EMCY 135 + SDO 270.
        assert_eq!(l.bits(), 55 + 2 * 385 + 240 + 65 + 135 + 270);
        assert_eq!(
            (l.frames(), l.micros(), l.load()),
            (15, 1535, Permille(768))
        );
        assert!(r.to_string().ends_with("OK\n"));
        assert_eq!(c.axes[3].profile(), Profile::Fhpp);
        assert_eq!(c.axes[2].profile(), Profile::Cia402);
    }

    #[test]
    fn pdos_follow_device_and_profile() {
        assert_eq!(axis_pdos(DeviceKind::MtrDci, Profile::Fhpp, false).len(), 1);
        assert_eq!(axis_pdos(DeviceKind::Emca, Profile::Fhpp, true).len(), 2);
        assert_eq!(axis_pdos(DeviceKind::Emca, Profile::Fhpp, true)[1].len, 8);
        assert_eq!(
            axis_pdos(DeviceKind::Tlc5xx, Profile::Cia402, false)[0].len,
            6
        );
        assert!(axis_pdos(DeviceKind::CmmoSt, Profile::Fhpp, false).is_empty());
        // FPC on two axes of the example no longer fits 80 %.
        let e = errors(&edited(&[("fpc = false", "fpc = true")]));
        assert_eq!(
            e,
            [
                "buses[0]: bus can0: 17 frames, 1805 us per 2000 us cycle = 90.3 %, \
              over the 80.0 % limit"
            ]
        );
    }

    #[test]
    fn supervision_defaults_per_device() {
        let c = Config::parse(&edited(&[
            ("guard_time_ms = 100 ", "# "),
            ("heartbeat_ms = 100 ", "# "),
        ]))
        .unwrap();
        let ms100 = Duration::from_millis(100);
        assert_eq!(
            c.axes[0].supervision(),
            Supervision::Guarding { guard_time: ms100 }
        );
        assert_eq!(
            c.axes[1].supervision(),
            Supervision::Guarding { guard_time: ms100 }
        );
        assert_eq!(
            c.axes[2].supervision(),
            Supervision::Heartbeat { period: ms100 }
        );
        assert!(c.check().is_ok());
    }

    #[test]
    fn each_bad_setting_names_its_key() {
        let cases: &[(&[(&str, &str)], &str)] = &[
            (
                &[("node = 2", "node = 0")],
                "axes[1].node: 0 is not a CANopen node-ID (1..=127)",
            ),
            (
                &[("node = 2", "node = 128")],
                "axes[1].node: 128 is not a CANopen node-ID (1..=127)",
            ),
            (
                &[("node = 3", "node = 1")],
                "axes[2].node: node 1 on bus can0 is already used by axes[0]",
            ),
            (
                &[("axes = [\"x\", \"y\"]", "axes = [\"x\", \"w\"]")],
                "groups[0].axes[1]: no axis named \"w\"",
            ),
            (
                &[("axes = [\"x\", \"y\"]", "axes = [\"x\", \"gripper\"]")],
                "groups[0].axes: axis \"gripper\" is on Modbus, which has no SYNC",
            ),
            (
                &[(
                    "velocity = 150.0, acceleration",
                    "velocity = 0.0, acceleration",
                )],
                "axes[0].limits.velocity: 0 must be a positive number",
            ),
            (
                &[("jerk = 20000.0", "jerk = -1.0")],
                "axes[0].limits.jerk: -1 must be a positive number",
            ),
            (
                &[("force = 100.0", "force = 500.0")],
                "axes[0].limits.force: 500 is outside 0..=300",
            ),
            (
                &[(
                    "position_min = 0.0, position_max = 400.0",
                    "position_min = 400.0, position_max = 400.0",
                )],
                "axes[0].limits.position_min: 400 is not below position_max 400",
            ),
            (
                &[("position_max = 250.0", "position_max = 2500000.0")],
                "axes[1].limits.position_max: 2500000 units are 2500000000 increments, outside the drive's 32-bit range",
            ),
            (
                &[("increments_per_unit = 400.0", "increments_per_unit = 0.0")],
                "axes[0].increments_per_unit: 0 must be a positive number",
            ),
            (
                &[("increments_per_unit = 100.0", "increments_per_unit = 0.001")],
                "axes[3].limits.velocity: 90 units are 0.09 increments, less than one",
            ),
            (
                &[(
                    "modbus = \"192.168.0.20:502\"",
                    "modbus = \"192.168.0.20:502\"\nbus = \"can0\"",
                )],
                "axes[3].bus: a cmmo-st axis is on Modbus TCP, not on a CAN bus",
            ),
            (
                &[("modbus = \"192.168.0.20:502\"", "modbus = \"192.168.0.20\"")],
                "axes[3].modbus: \"192.168.0.20\" is not host:port",
            ),
            (
                &[("modbus = \"192.168.0.20:502\"", "# no address")],
                "axes[3].modbus: missing: a cmmo-st axis needs it",
            ),
            (
                &[("node = 3", "node = 3\nmodbus = \"h:1\"")],
                "axes[2].modbus: a tlc5xx axis is on CANopen, not on Modbus TCP",
            ),
            (
                &[("bus = \"can0\"\nnode = 3", "bus = \"can9\"\nnode = 3")],
                "axes[2].bus: no bus named \"can9\"",
            ),
            (
                &[("guard_time_ms = 100 ", "heartbeat_ms = 100 ")],
                "axes[0].heartbeat_ms: a mtr-dci axis has no heartbeat, only node guarding",
            ),
            (
                &[(
                    "heartbeat_ms = 100 ",
                    "heartbeat_ms = 100\nguard_time_ms = 50 ",
                )],
                "axes[2].heartbeat_ms: heartbeat_ms and guard_time_ms are exclusive",
            ),
            (
                &[(
                    "device = \"tlc5xx\"",
                    "device = \"tlc5xx\"\nprofile = \"fhpp\"",
                )],
                "axes[2].profile: tlc5xx does not offer the fhpp profile",
            ),
            (
                &[("fpc = false", "fpc = true\nprofile = \"cia402\"")],
                "axes[1].fpc: a emca axis has the FPC only with the fhpp profile",
            ),
            (
                &[("name = \"z\"", "name = \"x\"")],
                "axes[2].name: the name \"x\" is already used by axes[0]",
            ),
            (
                &[("axis = \"gripper\"", "axis = \"hand\"")],
                "records[2].axis: no axis named \"hand\"",
            ),
            (
                &[("next = 2", "next = 5")],
                "records[0].next: axis \"x\" has no record 5",
            ),
            (
                &[("number = 2", "number = 32")],
                "records[1].number: 32 is outside 1..=31",
            ),
            (
                &[("number = 2", "number = 1")],
                "records[1].number: record 1 of axis \"x\" is already defined by records[0]",
            ),
            (
                &[("position = 390.0", "position = 401.0")],
                "records[1].position: 401 is outside 0..=400",
            ),
            (
                &[("velocity = 45.0", "velocity = 95.0")],
                "records[2].velocity: 95 exceeds the axis limit 90",
            ),
            (
                &[(
                    "axes = [\"x\", \"y\"]",
                    "axes = [\"x\", \"y\"]\n\n[[groups]]\nname = \"gantry\"\naxes = [\"y\"]",
                )],
                "groups[1].name: the name \"gantry\" is already used by groups[0]",
            ),
            (
                &[(
                    "axes = [\"x\", \"y\"]",
                    "axes = [\"x\", \"y\"]\n\n[[groups]]\nname = \"g2\"\naxes = [\"y\"]",
                )],
                "groups[1].axes[0]: axis \"y\" is already in group \"gantry\"",
            ),
            (
                &[("axes = [\"x\", \"y\"]", "axes = []")],
                "groups[0].axes: a group needs at least one axis",
            ),
            (
                &[(
                    "# Festo MTR-DCI on CANopen",
                    "[[buses]]\nname = \"can0\"\nkind = \"virtual\"\n# Festo MTR-DCI on CANopen",
                )],
                "buses[1].name: the name \"can0\" is already used by buses[0]",
            ),
            (
                &[("position = 390.0", "position = inf")],
                "records[1].position: inf is not a finite number",
            ),
            (
                &[("position_min = -50.0", "position_min = nan")],
                "axes[1].limits.position_min: NaN is not a finite number",
            ),
            (
                &[("cycle_us = 2000", "cycle_us = 0")],
                "cycle_us: 0 is outside 250..=100000",
            ),
            (
                &[("bitrate = 1000000 ", "bitrate = 10000 ")],
                "buses[0].bitrate: 10000 is outside 20000..=1000000",
            ),
            (
                &[("load_limit_percent = 80", "load_limit_percent = 0")],
                "load_limit_percent: 0 is outside 1..=100",
            ),
        ];
        for (edits, expected) in cases {
            let e = errors(&edited(edits));
            assert!(
                e.iter().any(|m| m.starts_with(expected)),
                "{edits:?}: expected {expected:?}, got {e:#?}"
            );
        }
    }

    #[test]
    fn all_errors_are_reported() {
        let e = errors(&edited(&[
            ("node = 2", "node = 0"),
            ("next = 2", "next = 9"),
            ("velocity = 45.0", "velocity = 95.0"),
        ]));
        assert_eq!(e.len(), 3, "{e:#?}");
    }

    #[test]
    fn a_group_spans_buses_only_if_their_syncs_line_up() {
        let second_bus = "[[buses]]\nname = \"can1\"\nkind = \"socketcan\"\n\n[[buses]]";
        let two = [
            ("[[buses]]", second_bus),
            ("bus = \"can0\"\nnode = 2", "bus = \"can1\"\nnode = 2"),
        ];
        let c = Config::parse(&edited(&two)).unwrap();
        let r = c.check();
        assert!(r.is_ok(), "{r}");
        assert_eq!(r.loads.len(), 2);

        let mut other_cycle = two.to_vec();
        other_cycle[0].1 =
            "[[buses]]\nname = \"can1\"\nkind = \"socketcan\"\ncycle_us = 4000\n\n[[buses]]";
        assert_eq!(
            errors(&edited(&other_cycle)),
            [
                "groups[0].axes[1]: buses \"can0\" and \"can1\" do not share one SYNC: \
              their cycle periods differ"
            ]
        );
        let mut consumer = two.to_vec();
        consumer[0].1 =
            "[[buses]]\nname = \"can1\"\nkind = \"socketcan\"\nsync = \"consumer\"\n\n[[buses]]";
        let e = errors(&edited(&consumer));
        assert_eq!(e.len(), 1);
        assert!(e[0].contains("SYNC consumer"), "{e:?}");
    }

    #[test]
    fn a_cycle_too_short_is_refused_with_the_numbers() {
        let e = errors(&edited(&[("cycle_us = 2000", "cycle_us = 1000")]));
        assert_eq!(
            e,
            [
                "buses[0]: bus can0: 15 frames, 1535 us per 1000 us cycle = 153.5 %, \
              does not fit the cycle"
            ]
        );
        // A higher limit does not help a cycle that cannot fit at all.
        let e = errors(&edited(&[
            ("cycle_us = 2000", "cycle_us = 1000"),
            ("load_limit_percent = 80", "load_limit_percent = 100"),
        ]));
        assert!(e[0].ends_with("does not fit the cycle"), "{e:?}");
    }

    #[test]
    fn unknown_and_missing_keys_are_parse_errors() {
        let e = Config::parse(&edited(&[("sdo_slots", "sdo_slot")])).unwrap_err();
        assert_eq!(e.key, "line 17");
        assert!(e.to_string().contains("unknown field `sdo_slot`"), "{e}");
        let e = Config::parse(&edited(&[("device = \"emca\"", "device = \"emcb\"")])).unwrap_err();
        assert!(e.to_string().contains("emcb"), "{e}");
        let e = Config::parse("load_limit_percent = 50\n").unwrap_err();
        assert!(e.to_string().contains("cycle_us"), "{e}");
    }
}
