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
//! converted to whole increments once, with the axis's exact [`Scale`] (the decimal written,
//! times the scale, rounded to nearest), and refused when the result does not fit the drive's
//! integer range.

use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::time::Duration;

use drivers::can::bit_timing::{MAX_BITRATE, MIN_BITRATE};
use drivers::catalog::{self, Device};
use serde::Deserialize;

use crate::budget::{BusLoad, BusTraffic, Pdo, Permille, Supervision};
use crate::comparator::Window;
use crate::records::{
    self, AxisTarget, Edge, MAX_GROUP_AXES, Quantity, RecordError, RecordMode, RecordTable,
    StepCondition,
};
use crate::units::{Decimal, Scale, ScaleError};

/// Forces are configured in % and travel in ‰: exactly ten ‰ per %.
pub const PERMILLE_PER_PERCENT: Scale = Scale::integer(10);

/// The commented example `coordinator config-example` prints: four axes, one of each device
/// kind, on the virtual bus and Modbus TCP, a group and a few records.
pub const EXAMPLE: &str = include_str!("../examples/machine.toml");

/// The example machine with its drives in other processes (`coordinator config-example --vbus`):
/// its buses of kind `vbus` and the CMMO-ST dialled on loopback, where `drive-sim --config` serves
/// them. Derived from [`EXAMPLE`], so the two never drift apart.
pub fn example_vbus() -> String {
    EXAMPLE
        .replacen(
            "# The coordinator's configuration: the embedded default machine.",
            "# The coordinator's configuration: the embedded default machine, its drives in other\n\
             # processes. Start them with `drive-sim --config FILE`, then `coordinator run --config FILE`.",
            1,
        )
        // Every bus of the machine (can0, can1).
        .replace("kind = \"simulated\"       #", "kind = \"vbus\"            #")
        .replacen("simulated = true", "modbus = \"127.0.0.1:1502\"", 1)
}

/// Allowed cycle periods in microseconds (the same range as `coordinator run --cycle-us`).
pub const CYCLE_US: core::ops::RangeInclusive<u32> = 250..=100_000;
/// Axes one coordinator drives at most.
pub const MAX_AXES: usize = 128;
/// Groups one coordinator runs at most.
pub const MAX_GROUPS: usize = 16;
/// CAN buses one coordinator drives at most (all in its one cycle).
pub const MAX_BUSES: usize = crate::cycle::MAX_BUSES;
/// EtherCAT buses (segments) one coordinator drives at most, each on its own thread.
pub const MAX_SEGMENTS: usize = 4;
/// Subdevices on one EtherCAT bus at most (the coordinator's ethercrab group holds this many).
pub const MAX_SUBDEVICES: usize = 16;
/// The default bus-load limit in percent.
pub const DEFAULT_LOAD_LIMIT_PERCENT: u32 = 80;
/// The default heartbeat / guard time in milliseconds.
pub const DEFAULT_SUPERVISION_MS: u32 = 100;
/// The longest producer heartbeat the coordinator consumes: it waits twice the producer time,
/// in 16-bit milliseconds (`cycle::Supervision::Heartbeat`).
pub const MAX_HEARTBEAT_MS: u32 = u16::MAX as u32 / 2;

/// A whole configuration file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// The SYNC period in microseconds, for every bus that does not set its own.
    pub cycle_us: u32,
    /// Refuse a bus whose worst cycle exceeds this share of the cycle (percent, 1..=100).
    #[serde(default = "default_load_limit")]
    pub load_limit_percent: u32,
    /// What the coordinator does when it missed cycles itself (the host stalled it).
    #[serde(default)]
    pub overrun_reaction: OverrunReactionConfig,
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

/// How a bus reaches the wire, and where its drives are.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BusKind {
    /// A bus inside the coordinator's process with a simulator for every drive on it: the
    /// embedded default machine, demonstrations, tests. No other process can join it.
    Simulated,
    /// The cross-process virtual bus `vbus:NAME` (shared memory): the drives are other
    /// processes (`drive-sim`, a Python tool); `canbus dump vbus:NAME` sees its traffic.
    Vbus,
    /// A SocketCAN interface of the same name as the bus: real drives.
    Socketcan,
    /// An EtherCAT segment on a Linux network interface (`interface`, default the bus's
    /// name), raw Ethernet through ethercrab: its subdevices are the axes that name the bus,
    /// each at its `position`.
    Ethercat,
    /// The old name of `simulated`; refused so that no configuration silently changes meaning
    /// (the key now says where the drives are).
    Virtual,
}

impl BusKind {
    /// The name used in the configuration.
    pub fn name(self) -> &'static str {
        match self {
            Self::Simulated => "simulated",
            Self::Vbus => "vbus",
            Self::Socketcan => "socketcan",
            Self::Ethercat => "ethercat",
            Self::Virtual => "virtual",
        }
    }
}

impl fmt::Display for BusKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// `overrun_reaction`: what a stall of the coordinator itself does.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum OverrunReactionConfig {
    /// Report it and carry on (the default).
    #[default]
    Report,
    /// Report it and quick-stop every axis.
    QuickStop,
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
    /// Name, unique; also the `vbus:NAME` or the SocketCAN interface.
    pub name: String,
    /// Simulated, vbus or SocketCAN.
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
    /// The network interface of an `ethercat` bus; defaults to the bus's name.
    pub interface: Option<String>,
}

impl BusConfig {
    /// The network interface an `ethercat` bus runs on.
    pub fn interface(&self) -> &str {
        self.interface.as_deref().unwrap_or(&self.name)
    }
}

/// The supported drives; their facts are `drivers::catalog`'s ([`DeviceKind::device`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DeviceKind {
    /// Festo MTR-DCI (CANopen; FHPP or CiA 402; node guarding only).
    MtrDci,
    /// Festo EMCA (CANopen; FHPP; node guarding only).
    Emca,
    /// Festo CMMO-ST (Modbus TCP; FHPP).
    CmmoSt,
    /// Schneider TLC5xx (CANopen; CiA 402).
    Tlc5xx,
    /// Any CiA 402 drive, described by its EDS (`eds`); without one, this project's simulator
    /// of a generic drive.
    Cia402,
}

impl DeviceKind {
    /// Every kind, in the catalog's order.
    pub const ALL: [DeviceKind; 5] = [
        Self::MtrDci,
        Self::Emca,
        Self::CmmoSt,
        Self::Tlc5xx,
        Self::Cia402,
    ];

    /// The axis layer's kind.
    pub const fn axis_kind(self) -> crate::axis::DeviceKind {
        match self {
            Self::MtrDci => crate::axis::DeviceKind::MtrDci,
            Self::Emca => crate::axis::DeviceKind::Emca,
            Self::CmmoSt => crate::axis::DeviceKind::CmmoSt,
            Self::Tlc5xx => crate::axis::DeviceKind::Tlc5xx,
            Self::Cia402 => crate::axis::DeviceKind::Cia402,
        }
    }

    /// The device's facts.
    pub const fn device(self) -> &'static Device {
        self.axis_kind().device()
    }

    /// The name used in the configuration (the catalog's `id`, not its manual name).
    pub fn name(self) -> &'static str {
        let device = self.device();
        device.id
    }

    /// The profiles the device offers; the first is the default.
    pub fn profiles(self) -> impl Iterator<Item = Profile> {
        self.device()
            .profiles
            .iter()
            .map(|p| Profile::from(p.profile))
    }

    /// Whether the device is reached over Modbus TCP rather than CANopen.
    pub fn is_modbus(self) -> bool {
        !self.device().is_canopen()
    }

    /// What the device is on EtherCAT, if it has an EtherCAT interface in the catalog.
    pub fn ethercat(self) -> Option<&'static catalog::EthercatFacts> {
        self.device().ethercat
    }

    /// Whether the device can produce a heartbeat (the MTR-DCI and EMCA are guarded only).
    pub fn has_heartbeat(self) -> bool {
        self.device().has_heartbeat()
    }

    /// The highest number of the device's own record table; 0 if it has none (the TLC5xx).
    pub fn max_record(self) -> u32 {
        self.device().records.map_or(0, |r| r.last.into())
    }
}

impl fmt::Display for DeviceKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// How a CiA 402 axis is commanded cyclically (`mode`): the configuration's names of
/// [`crate::axis::CyclicMode`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModeConfig {
    /// Profile position, set-points streamed through the handshake.
    Pp,
    /// Cyclic synchronous position.
    Csp,
    /// Cyclic synchronous velocity.
    Csv,
    /// Cyclic synchronous torque.
    Cst,
}

impl From<ModeConfig> for crate::axis::CyclicMode {
    fn from(m: ModeConfig) -> Self {
        use crate::axis::CyclicMode as C;
        match m {
            ModeConfig::Pp => C::Pp,
            ModeConfig::Csp => C::Csp,
            ModeConfig::Csv => C::Csv,
            ModeConfig::Cst => C::Cst,
        }
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

impl From<catalog::Profile> for Profile {
    fn from(p: catalog::Profile) -> Self {
        match p {
            catalog::Profile::Fhpp => Self::Fhpp,
            catalog::Profile::Cia402 => Self::Cia402,
        }
    }
}

impl From<Profile> for catalog::Profile {
    fn from(p: Profile) -> Self {
        match p {
            Profile::Fhpp => Self::Fhpp,
            Profile::Cia402 => Self::Cia402,
        }
    }
}

impl fmt::Display for Profile {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(catalog::Profile::from(*self).id())
    }
}

/// The PDOs the coordinator maps for one axis, each way: the catalog's PDO1, and PDO2 for the
/// FPC (the catalog's PDO pairs are equally long both ways). Modbus axes put nothing on a CAN
/// bus.
pub fn axis_pdos(device: DeviceKind, profile: Profile, fpc: bool) -> Vec<Pdo> {
    let Some(facts) = device.device().profile(profile.into()) else {
        return Vec::new();
    };
    let pdo2 = facts.fpc_pdo2.filter(|_| fpc);
    [facts.pdo1, pdo2]
        .into_iter()
        .flatten()
        .map(|p| Pdo::every_sync(p.rpdo_bytes() as u8))
        .collect()
}

/// The CAN-only keys of an `ethercat` bus are refused where they differ from their defaults
/// (the file cannot tell a default from a key written with the default's value).
fn check_ethercat_bus(key: &str, b: &BusConfig, err: &mut Errors) {
    let can_only: [(&str, bool); 5] = [
        ("bitrate", b.bitrate != default_bitrate()),
        ("sync", b.sync != SyncMode::Producer),
        ("sync_counter", b.sync_counter),
        ("emcy_per_cycle", b.emcy_per_cycle != 1),
        ("sdo_slots", b.sdo_slots != 1),
    ];
    for (k, given) in can_only {
        if given {
            err.push(
                format!("{key}.{k}"),
                Problem::Ethercat(format!(
                    "`{k}` is a CAN bus's; an ethercat bus runs at 100 Mbit/s, its frame driven by the coordinator's cycle"
                )),
            );
        }
    }
    if b.interface().is_empty() || b.interface().len() > 15 {
        err.push(
            format!("{key}.interface"),
            Problem::Ethercat(format!(
                "\"{}\" is not a network interface name (1 to 15 bytes)",
                b.interface()
            )),
        );
    }
}

/// An axis on an `ethercat` bus: a device the catalog knows on EtherCAT, the FHPP profile, a
/// position, no CANopen keys, and a cycle the drive allows (1C32h:05). Returns the position.
fn check_ethercat_axis(
    key: &str,
    a: &AxisConfig,
    cycle_us: u32,
    cycle_key: &str,
    err: &mut Errors,
) -> Option<i64> {
    let device = a.device;
    let Some(facts) = device.ethercat() else {
        let offered: Vec<&str> = DeviceKind::ALL
            .iter()
            .filter(|d| d.ethercat().is_some())
            .map(|d| d.name())
            .collect();
        err.push(
            format!("{key}.bus"),
            Problem::Ethercat(format!(
                "the {} has no EtherCAT interface in the device catalog; on an ethercat bus: {}",
                device.device().name,
                offered.join(", ")
            )),
        );
        return None;
    };
    let not = |reason| Problem::NotAllowed { device, reason };
    if a.node.is_some() {
        err.push(
            format!("{key}.node"),
            not("on an ethercat bus has a position, not a node-ID"),
        );
    }
    if a.modbus.is_some() || a.simulated {
        let k = if a.simulated { "simulated" } else { "modbus" };
        err.push(
            format!("{key}.{k}"),
            not("on an ethercat bus is reached on EtherCAT"),
        );
    }
    if a.fpc {
        err.push(
            format!("{key}.fpc"),
            not("on EtherCAT exchanges FHPP's 8-byte standard data (1600h/1A00h), without the FPC"),
        );
    }
    if let Some(k) = a.supervision_key() {
        err.push(
            format!("{key}.{k}"),
            not("on EtherCAT is supervised by the working counter and its AL status, every cycle"),
        );
    }
    let min_us = facts.min_cycle_ns.div_ceil(1000);
    if cycle_us < min_us {
        err.push(
            cycle_key,
            Problem::Ethercat(format!(
                "the cycle of {cycle_us} us is shorter than the {}'s shortest on EtherCAT, {min_us} us (1C32h:05), for axis \"{}\"",
                device.device().name,
                a.name
            )),
        );
    }
    match a.position {
        None => {
            err.push(format!("{key}.position"), Problem::Missing { device });
            None
        }
        Some(p) if !(1..=MAX_SUBDEVICES as i64).contains(&p) => {
            err.push(
                format!("{key}.position"),
                Problem::Range {
                    value: p as f64,
                    min: 1.0,
                    max: MAX_SUBDEVICES as f64,
                },
            );
            None
        }
        Some(p) => Some(p),
    }
}

/// `mode` and `eds` of a CANopen axis: a mode its device takes (and its EDS allows), an EDS
/// only on a `cia402` axis.
fn check_mode(key: &str, a: &AxisConfig, cycle_us: u32, err: &mut Errors) {
    use crate::axis::CyclicMode;
    let mode = a.mode();
    let refuse = |err: &mut Errors, why: String| {
        err.push(
            format!("{key}.mode"),
            Problem::Mode {
                mode,
                id: mode.id(),
                why,
            },
        )
    };
    if a.profile() != Profile::Cia402 {
        if a.mode.is_some() {
            refuse(
                err,
                "modes of operation are CiA 402's; remove `mode` (the FHPP profile has none)"
                    .into(),
            );
        }
    } else if a.device != DeviceKind::Cia402 && mode != CyclicMode::Pp {
        refuse(
            err,
            format!(
                "the {} streams profile position only (\"pp\"); cyclic synchronous modes need a `cia402` drive that offers them",
                a.device.device().name
            ),
        );
    } else if mode != CyclicMode::Pp
        && drivers::cia402::modes::interpolation_time_period(core::time::Duration::from_micros(
            cycle_us.into(),
        ))
        .is_none()
    {
        refuse(
            err,
            format!(
                "the cycle of {cycle_us} µs cannot be given to the drive in 60C2h (interpolation time period: 1..=255 × 10^-6..=0 s exactly, such as 1000 or 1500 µs)"
            ),
        );
    } else if let Some(eds) = &a.eds_read {
        let lacks = eds.lacks(mode);
        if !lacks.is_empty() {
            refuse(
                err,
                format!(
                    "the drive's EDS {}: {}",
                    eds.path.display(),
                    lacks.join("; ")
                ),
            );
        }
    }
    if let Some(m) = a.homing_method {
        let profile = match a.device {
            DeviceKind::Tlc5xx => Some(drivers::cia402::TLC5XX),
            DeviceKind::Cia402 => Some(drivers::cia402::GENERIC),
            _ => None,
        };
        let why = match profile {
            None => Some(String::from(
                "the coordinator sets the homing method (6098h) of the TLC5xx and of cia402 drives only",
            )),
            Some(p) => {
                let method = i8::try_from(m)
                    .ok()
                    .and_then(|c| drivers::cia402::homing::HomingMethod::from_code(c).ok());
                match method {
                    Some(h) if p.supports_homing(h) => None,
                    _ => Some(format!(
                        "{m} is not a homing method of the {}: {}",
                        a.device.device().name,
                        p.homing_methods
                            .iter()
                            .map(|h| h.code().to_string())
                            .collect::<Vec<_>>()
                            .join(", ")
                    )),
                }
            }
        };
        if let Some(why) = why {
            err.push(format!("{key}.homing_method"), Problem::HomingMethod(why));
        }
    }
    if a.eds.is_some() && a.device != DeviceKind::Cia402 {
        err.push(
            format!("{key}.eds"),
            Problem::NotAllowed {
                device: a.device,
                reason: "is described by the device catalog; `eds` is for device = \"cia402\"",
            },
        );
    }
}

/// The PDOs of one axis commanded in `mode` on a CAN bus: (RPDOs, TPDOs), from the mapping the
/// boot writes ([`crate::axis::pdo_mapping_in`]), so the budget counts a CST axis's 5-byte RPDO
/// as 5 bytes; PDO2 for the FPC as in [`axis_pdos`].
pub fn axis_pdos_in(
    device: DeviceKind,
    profile: Profile,
    mode: crate::axis::CyclicMode,
    fpc: bool,
) -> (Vec<Pdo>, Vec<Pdo>) {
    let map = crate::axis::pdo_mapping_in(device.axis_kind(), profile.into(), mode);
    let (Some(r), Some(t)) = (map.rpdo, map.tpdo) else {
        return (Vec::new(), Vec::new());
    };
    let mut rpdos = vec![Pdo::every_sync(r.len() as u8)];
    let mut tpdos = vec![Pdo::every_sync(t.len() as u8)];
    let both = axis_pdos(device, profile, fpc);
    // PDO2 (the FPC), equally long both ways.
    rpdos.extend(both.iter().skip(1).copied());
    tpdos.extend(both.iter().skip(1).copied());
    // A move's profile on RPDO2 (at most one a cycle: counted as if every cycle had one).
    if let Some(m) = crate::axis::profile_rpdo2_mapping(device.axis_kind(), profile.into(), mode) {
        rpdos.push(Pdo::every_sync(drivers::catalog::mapped_bytes(m) as u8));
    }
    (rpdos, tpdos)
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
    /// The subdevice's position on an `ethercat` bus: 1 is the first after the master, in
    /// wiring order (EtherCAT axes only).
    pub position: Option<i64>,
    /// The Modbus TCP address `host:port` (Modbus devices only), dialled by the coordinator.
    pub modbus: Option<String>,
    /// A Modbus device simulated inside the coordinator instead of dialled (no `modbus`
    /// address then). CANopen axes are simulated by their bus's kind.
    #[serde(default)]
    pub simulated: bool,
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
    /// Drive increments per user unit: a decimal with at most 12 decimal places, held exactly
    /// ([`AxisConfig::scale`]).
    pub increments_per_unit: f64,
    /// Motion limits.
    pub limits: Limits,
    /// Largest |setpoint - actual| while following a path, in units, before the axis faults;
    /// default: the distance covered at the velocity limit in 100 ms plus 6 cycles.
    pub following_error: Option<f64>,
    /// How a CiA 402 axis is commanded cyclically; default: `csp` for a `cia402` drive, `pp`
    /// for the TLC5xx and the MTR-DCI (their only one).
    pub mode: Option<ModeConfig>,
    /// The EDS of a `cia402` drive, relative to the configuration file's folder; without one,
    /// the drive is taken to be this project's generic drive (`drive-sim --device cia402`).
    pub eds: Option<String>,
    /// The CiA 402 homing method (6098h) the boot writes; default 35 (the current position is
    /// home). TLC5xx and `cia402` axes only, and a method the drive offers.
    pub homing_method: Option<i64>,
    /// The EDS read by [`Config::load_eds`].
    #[serde(skip)]
    pub eds_read: Option<crate::drive_eds::DriveEds>,
}

fn default_unit() -> String {
    "mm".into()
}

impl AxisConfig {
    /// The exact scale of `increments_per_unit` (refused as [`Config::check`] refuses it).
    pub fn scale(&self) -> Result<Scale, ScaleError> {
        Scale::from_f64(self.increments_per_unit)
    }

    /// The cyclic mode in use (the configured one or the device's default).
    pub fn mode(&self) -> crate::axis::CyclicMode {
        use crate::axis::CyclicMode;
        match (self.mode, self.device) {
            (Some(m), _) => m.into(),
            (None, DeviceKind::Cia402) => CyclicMode::Csp,
            (None, _) => CyclicMode::Pp,
        }
    }

    /// The profile in use (the configured one or the device's default).
    pub fn profile(&self) -> Profile {
        self.profile
            .unwrap_or(self.device.device().default_profile().into())
    }

    /// The CANopen supervision key the file gives (`heartbeat_ms` first), if any: what an axis
    /// supervised otherwise (Modbus, EtherCAT) refuses by name.
    fn supervision_key(&self) -> Option<&'static str> {
        match (self.heartbeat_ms, self.guard_time_ms) {
            (Some(_), _) => Some("heartbeat_ms"),
            (None, Some(_)) => Some("guard_time_ms"),
            (None, None) => None,
        }
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
    /// The group's record table (`[[groups.records]]`), run by the coordinator's chains.
    #[serde(default)]
    pub records: Vec<GroupRecordConfig>,
}

fn default_percent() -> u32 {
    100
}

fn default_true() -> bool {
    true
}

/// One record of a group's table (`[[groups.records]]`): a group move and how the chain goes
/// on from it. See `docs/configuration.md`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroupRecordConfig {
    /// Record number, 0..=255, unique in the group.
    pub number: u32,
    /// Per member axis by name: target (or distance with `relative`) in the axis's units; for
    /// `mode = "velocity"` only the sign counts (the direction). Axes not named keep still.
    #[serde(default)]
    pub targets: BTreeMap<String, f64>,
    /// The targets are distances from where the record starts.
    #[serde(default)]
    pub relative: bool,
    /// Share of each axis's velocity limit, 1..=100 %.
    #[serde(default = "default_percent")]
    pub velocity: u32,
    /// Share of each axis's acceleration limit, 1..=100 %.
    #[serde(default = "default_percent")]
    pub acceleration: u32,
    /// Share of each axis's jerk limit, 1..=100 %.
    #[serde(default = "default_percent")]
    pub jerk: u32,
    /// What the record commands.
    #[serde(default)]
    pub mode: GroupRecordMode,
    /// Force for `mode = "force"`, % of nominal (-300..=300, not 0).
    pub force: Option<f64>,
    /// Delay before the record's move starts, ms.
    #[serde(default)]
    pub delay_ms: u32,
    /// The step condition and the next record; none ends the chain here.
    pub step: Option<StepConfig>,
    /// An alternative condition and record (branching; the step wins a tie).
    pub alternative: Option<StepConfig>,
    /// Show MC when this record finishes inside a chain (FHPP PNU 425).
    #[serde(default = "default_true")]
    pub mc_in_chain: bool,
}

/// `mode` of a group record.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GroupRecordMode {
    /// A time-synchronised move to the targets.
    #[default]
    Position,
    /// Run at `velocity` % of the limits in the direction of each target's sign.
    Velocity,
    /// Push with `force`, toward the targets.
    Force,
}

/// `condition` of a step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ConditionKind {
    /// The group's move arrived (MC).
    Mc,
    /// At once (on the fly).
    Immediately,
    /// `ms` after MC.
    Delay,
    /// Position comparator on `axis`: `[min, max]` units held `damping_ms`.
    Position,
    /// Velocity comparator on `axis`: units/s.
    Velocity,
    /// Force comparator on `axis`: % of nominal.
    Force,
    /// Time since the record started in `[min, max]` ms.
    Time,
    /// An edge of digital input `input` (`edge`, default rising).
    Input,
    /// Group `group` reached its record `record`.
    Record,
}

impl ConditionKind {
    /// The name in the configuration.
    pub fn name(self) -> &'static str {
        match self {
            Self::Mc => "mc",
            Self::Immediately => "immediately",
            Self::Delay => "delay",
            Self::Position => "position",
            Self::Velocity => "velocity",
            Self::Force => "force",
            Self::Time => "time",
            Self::Input => "input",
            Self::Record => "record",
        }
    }

    /// The optional keys this condition takes (`next` and `condition` are always there).
    fn keys(self) -> &'static [&'static str] {
        match self {
            Self::Mc | Self::Immediately => &[],
            Self::Delay => &["ms"],
            Self::Position | Self::Velocity | Self::Force => &["axis", "min", "max", "damping_ms"],
            Self::Time => &["min", "max"],
            Self::Input => &["input", "edge"],
            Self::Record => &["group", "record"],
        }
    }
}

/// An input edge in the configuration.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum EdgeConfig {
    /// 0 → 1.
    #[default]
    Rising,
    /// 1 → 0.
    Falling,
}

/// A step condition with its next record (`step = { ... }`, `alternative = { ... }`). Which
/// keys a condition takes: [`ConditionKind`]; others are refused.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepConfig {
    /// The condition.
    pub condition: ConditionKind,
    /// The record to step to, in the same group.
    pub next: u32,
    /// `delay`: ms after MC.
    pub ms: Option<u32>,
    /// Comparators: the member axis.
    pub axis: Option<String>,
    /// Comparators and `time`: the window's lower bound (axis units, units/s, %, or ms).
    pub min: Option<f64>,
    /// Comparators and `time`: the window's upper bound.
    pub max: Option<f64>,
    /// Comparators: how long the value must stay inside, ms (default 0).
    pub damping_ms: Option<u32>,
    /// `input`: the bit of the machine's input word, 0..=31.
    pub input: Option<u32>,
    /// `input`: which edge (default rising).
    pub edge: Option<EdgeConfig>,
    /// `record`: the other group.
    pub group: Option<String>,
    /// `record`: its record number.
    pub record: Option<u32>,
}

impl StepConfig {
    /// The optional keys that are set, by name.
    fn set_keys(&self) -> [(&'static str, bool); 9] {
        [
            ("ms", self.ms.is_some()),
            ("axis", self.axis.is_some()),
            ("min", self.min.is_some()),
            ("max", self.max.is_some()),
            ("damping_ms", self.damping_ms.is_some()),
            ("input", self.input.is_some()),
            ("edge", self.edge.is_some()),
            ("group", self.group.is_some()),
            ("record", self.record.is_some()),
        ]
    }
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

/// The rule an axis or group name breaks, if any: clients carry it in the shared-memory
/// contract's 16-byte field and address it on command lines (`--axis x`, `--to 1,2`).
pub fn name_rule(name: &str) -> Option<&'static str> {
    if name.is_empty() {
        Some("is empty: give the axis or group a name")
    } else if name.len() > shm_api::contract::NAME_LEN {
        Some("is longer than 16 bytes (the shared-memory contract's name field)")
    } else if name.bytes().all(|b| b.is_ascii_digit()) {
        Some("is a number, which clients would take for an index")
    } else if !name
        .chars()
        .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'))
    {
        Some("may hold only letters, digits, '_', '-' and '.' (no spaces or commas)")
    } else {
        None
    }
}

/// The rule a unit breaks: longer than the contract's unit field.
const UNIT_RULE: &str = "is longer than 8 bytes (the shared-memory contract's unit field)";

/// What is wrong with one setting.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Problem {
    /// The text is not valid TOML for this schema (unknown key, wrong type, missing key).
    #[error("{0}")]
    Parse(String),
    /// A `mode` the drive cannot be commanded in.
    #[error("\"{id}\" ({mode}) is not for this axis: {why}")]
    Mode {
        /// The mode.
        mode: crate::axis::CyclicMode,
        /// Its configuration name.
        id: &'static str,
        /// Why, in words.
        why: String,
    },
    /// An EDS that could not be read or used.
    #[error("{0}")]
    Eds(String),
    /// A homing method the drive or the coordinator does not offer.
    #[error("{0}")]
    HomingMethod(String),
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
    /// A name clients could not carry or address.
    #[error("the name {name:?} {rule}")]
    BadName {
        /// The name.
        name: String,
        /// The rule it breaks.
        rule: &'static str,
    },
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
    #[error("{device} does not offer the {profile} profile, only {}", offered.join(" or "))]
    Profile {
        /// The device.
        device: DeviceKind,
        /// The profile.
        profile: Profile,
        /// The profiles it offers.
        offered: Vec<String>,
    },
    /// A Modbus address that is not `host:port`.
    #[error("{0:?} is not host:port with a port in 1..=65535")]
    ModbusAddress(String),
    /// A step back to its own record on a condition that can hold at once.
    #[error(
        "{number} is the record itself, on condition \"{condition}\", which can hold as soon as it starts: it would restart every cycle (a relative one crawls on for ever); step back to it on \"mc\" or a delay, or to another record"
    )]
    SelfStep {
        /// The record.
        number: u32,
        /// The condition's name.
        condition: &'static str,
    },
    /// A Modbus host name that does not resolve: the run could never dial it.
    #[error("\"{addr}\": cannot resolve the host ({reason})")]
    ModbusResolve {
        /// The address as written.
        addr: String,
        /// What the resolver said.
        reason: String,
    },
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
        /// The scaled value, exactly.
        increments: Decimal,
    },
    /// A value below one increment (per second...) after scaling: the drive would see 0.
    #[error("{value} units are {increments} increments, less than one")]
    BelowOneIncrement {
        /// The value in units.
        value: f64,
        /// The scaled value, exactly.
        increments: Decimal,
    },
    /// An `increments_per_unit` that is not an exact scale.
    #[error("{0}")]
    Scale(ScaleError),
    /// A value above the axis's limit.
    #[error("{value} exceeds the axis limit {limit}")]
    OverLimit {
        /// The value.
        value: f64,
        /// The limit.
        limit: f64,
    },
    /// A guard time shorter than the cycle: the coordinator polls once per cycle at most, so the
    /// drive's life time (3 × the guard time) would run out between polls.
    #[error(
        "{guard_ms} ms is shorter than the cycle ({cycle_us} us): the coordinator polls once per cycle, and the drive's life time (3 x guard time) would expire; use at least the cycle or 0"
    )]
    GuardBelowCycle {
        /// The guard time, ms.
        guard_ms: u32,
        /// The cycle, µs.
        cycle_us: u32,
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
    /// The bus kind `virtual`, renamed.
    #[error(
        "\"virtual\" is no longer a bus kind: say \"simulated\" for drives simulated inside the coordinator (what \"virtual\" ran), or \"vbus\" for the cross-process bus vbus:NAME that drive-sim, canbus and other tools join"
    )]
    RenamedKind,
    /// More of something than one coordinator holds.
    #[error("{count} {what}: at most {max} per coordinator")]
    TooMany {
        /// What ("axes", "groups", "buses").
        what: &'static str,
        /// How many the file has.
        count: usize,
        /// The most allowed.
        max: usize,
    },
    /// Two buses with different SYNC periods.
    #[error(
        "{value} us differs from bus {other:?}'s {cycle} us: one coordinator runs one cycle for all its buses"
    )]
    OneCycle {
        /// This bus's period, µs.
        value: u32,
        /// The first bus.
        other: String,
        /// Its period, µs.
        cycle: u32,
    },
    /// A SYNC-consumer bus beside other buses.
    #[error(
        "a SYNC consumer bus must be the coordinator's only CAN bus (the cycle follows its SYNC), and bus {0:?} is configured too"
    )]
    ConsumerNotAlone(String),
    /// A group mixing Modbus and CANopen axes: Modbus has no SYNC to latch on.
    #[error(
        "axis \"{0}\" is on Modbus, which has no SYNC; it cannot move with CANopen or EtherCAT axes"
    )]
    ModbusInGroup(String),
    /// An EtherCAT setting that cannot work (the message says why and what is allowed).
    #[error("{0}")]
    Ethercat(String),
    /// A position on an EtherCAT bus used twice.
    #[error("position {position} on bus {bus} is already used by {other}")]
    DuplicatePosition {
        /// The position.
        position: i64,
        /// The bus.
        bus: String,
        /// The key of the first user.
        other: String,
    },
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
    /// A group name no group has.
    #[error("no group named {0:?}")]
    UnknownGroup(String),
    /// An axis that is not a member of the record's group.
    #[error("axis {axis:?} is not in group {group:?}")]
    NotInGroup {
        /// The axis.
        axis: String,
        /// The group.
        group: String,
    },
    /// Two records with one number in one group's table.
    #[error("record {number} of group {group:?} is already defined by {other}")]
    DuplicateGroupRecord {
        /// The group.
        group: String,
        /// The record number.
        number: u32,
        /// The key of the first definition.
        other: String,
    },
    /// A record number the group's table does not hold.
    #[error("group {group:?} has no record {number}")]
    UnknownGroupRecord {
        /// The group.
        group: String,
        /// The record number.
        number: u32,
    },
    /// A key this step condition or record mode requires is missing.
    #[error("missing: {0} needs it")]
    Needs(&'static str),
    /// A key this step condition or record mode does not take.
    #[error("{0} does not take this key")]
    Unused(&'static str),
    /// A comparator or time window that could never be met.
    #[error("min {min} is above max {max}: the condition could never be met")]
    EmptyWindow {
        /// The lower bound.
        min: f64,
        /// The upper bound.
        max: f64,
    },
    /// An alternative on a record without a step.
    #[error("an alternative needs a step (a record without one ends the chain)")]
    AlternativeWithoutStep,
    /// A group with more axes than the cycle moves together (and a record holds).
    #[error("a group has at most {max} axes, this one has {axes}")]
    GroupTooLarge {
        /// The group's axes.
        axes: usize,
        /// The most a record holds.
        max: usize,
    },
    /// The record table refused a record (a check this file missed).
    #[error("{0}")]
    Record(RecordError),
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
    /// Every EtherCAT bus's frame time, in configuration order.
    pub segments: Vec<SegmentLoad>,
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
        for s in &self.segments {
            writeln!(f, "{s}")?;
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

/// One EtherCAT bus's cycle: its frames at 100 Mbit/s and their round trip through the
/// subdevices ([`drivers::ethercat::wire_time`]), against the cycle.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SegmentLoad {
    /// The bus's name.
    pub name: String,
    /// Its network interface.
    pub interface: String,
    /// What one cycle exchanges.
    pub traffic: drivers::ethercat::wire_time::CycleTraffic,
    /// The cycle.
    pub cycle: Duration,
}

impl SegmentLoad {
    /// The round trip of the cycle's frames, ns.
    pub fn round_trip_ns(&self) -> u64 {
        drivers::ethercat::wire_time::round_trip_ns(&self.traffic)
    }

    /// The round trip's share of the cycle.
    pub fn share(&self) -> Permille {
        let v = u128::from(self.round_trip_ns())
            .saturating_mul(1000)
            .div_ceil(self.cycle.as_nanos().max(1));
        Permille(u32::try_from(v).unwrap_or(u32::MAX))
    }

    /// Refuses a segment whose frames' round trip takes more than `limit` of the cycle: the
    /// inputs would not be back before the next cycle needs them.
    pub fn check(&self, limit: Permille) -> Result<(), String> {
        let share = self.share();
        if share > limit {
            return Err(format!(
                "the EtherCAT frames of {} subdevice(s) take {:.1} us to go round ({} bytes in {} \
                 frame(s) at 100 Mbit/s, and {} us through the subdevices), {share} of the {} us \
                 cycle, above the limit of {limit}: lengthen cycle_us or split the segment",
                self.traffic.subdevices,
                self.round_trip_ns() as f64 / 1000.0,
                self.traffic.frame_bytes(),
                self.traffic.frames(),
                self.traffic.subdevices as u64 * drivers::ethercat::wire_time::SUBDEVICE_DELAY_NS
                    / 1000,
                self.cycle.as_micros()
            ));
        }
        Ok(())
    }
}

impl fmt::Display for SegmentLoad {
    /// `bus line (EtherCAT on ecm): 3 subdevice(s), 1 frame(s) of 138 bytes, 13.0 us on the
    /// wire, 16.0 us round trip: 1.6 % of the 1000 us cycle`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let t = &self.traffic;
        write!(
            f,
            "bus {} (EtherCAT on {}): {} subdevice(s), {} frame(s) of {} bytes, {:.1} us on the \
             wire, {:.1} us round trip: {} of the {} us cycle",
            self.name,
            self.interface,
            t.subdevices,
            t.frames(),
            t.frame_bytes(),
            t.wire_ns() as f64 / 1000.0,
            self.round_trip_ns() as f64 / 1000.0,
            self.share(),
            self.cycle.as_micros()
        )
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
    rpdos: Vec<Pdo>,
    tpdos: Vec<Pdo>,
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

    /// Reads the EDS of every `cia402` axis that names one (`eds`, relative to `dir`, the
    /// configuration file's folder) into [`AxisConfig::eds_read`], for [`Config::check`] and the
    /// boot. Kept out of `check`, which does no I/O. An EDS that cannot be read or parsed is an
    /// error naming `axes[i].eds`.
    pub fn load_eds(&mut self, dir: &std::path::Path) -> Vec<ConfigError> {
        let mut errors = Vec::new();
        for (i, a) in self.axes.iter_mut().enumerate() {
            let Some(file) = &a.eds else { continue };
            if a.device != DeviceKind::Cia402 {
                continue;
            }
            match crate::drive_eds::DriveEds::read(&dir.join(file)) {
                Ok(e) => a.eds_read = Some(e),
                Err(e) => errors.push(ConfigError {
                    key: format!("axes[{i}].eds"),
                    problem: Problem::Eds(e),
                }),
            }
        }
        errors
    }

    /// Resolves the host of every Modbus drive the coordinator would dial, as `run` will
    /// (a numeric address resolves without asking anyone): a name that cannot be resolved is
    /// refused before the machine starts. Kept out of [`Config::check`], which does no I/O;
    /// `coordinator check` calls both.
    pub fn resolve_addresses(&self) -> Vec<ConfigError> {
        self.axes
            .iter()
            .enumerate()
            .filter(|(_, a)| a.device == DeviceKind::CmmoSt && !a.simulated)
            .filter_map(|(i, a)| {
                let addr = a.modbus.as_ref().filter(|t| valid_host_port(t))?;
                resolve_modbus(addr).err().map(|reason| ConfigError {
                    key: format!("axes[{i}].modbus"),
                    problem: Problem::ModbusResolve {
                        addr: addr.clone(),
                        reason,
                    },
                })
            })
            .collect()
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
            if b.kind == BusKind::Ethercat {
                check_ethercat_bus(&key, b, &mut err);
            } else if b.interface.is_some() {
                err.push(
                    format!("{key}.interface"),
                    Problem::Ethercat(format!(
                        "`interface` is an ethercat bus's; a {} bus is named by `name`",
                        b.kind
                    )),
                );
            }
            if b.kind != BusKind::Ethercat && !(MIN_BITRATE..=MAX_BITRATE).contains(&b.bitrate) {
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
            if b.kind == BusKind::Virtual {
                err.push(format!("{key}.kind"), Problem::RenamedKind);
            }
            // One cycle drives every bus: one period, and a SYNC consumer only alone.
            if let Some(first) = self.buses.first().filter(|_| i > 0) {
                let (mine, theirs) = (self.bus_cycle_us(b), self.bus_cycle_us(first));
                if mine != theirs {
                    err.push(
                        format!("{key}.cycle_us"),
                        Problem::OneCycle {
                            value: mine,
                            other: first.name.clone(),
                            cycle: theirs,
                        },
                    );
                }
            }
            if b.sync == SyncMode::Consumer
                && b.kind != BusKind::Ethercat
                && let Some(other) = self.buses.iter().find(|o| o.name != b.name)
            {
                err.push(
                    format!("{key}.sync"),
                    Problem::ConsumerNotAlone(other.name.clone()),
                );
            }
            bus_ok.push(ok);
        }
        let ethercat_buses = self
            .buses
            .iter()
            .filter(|b| b.kind == BusKind::Ethercat)
            .count();
        for (what, count, max) in [
            ("buses", self.buses.len() - ethercat_buses, MAX_BUSES),
            ("EtherCAT buses", ethercat_buses, MAX_SEGMENTS),
            ("axes", self.axes.len(), MAX_AXES),
            ("groups", self.groups.len(), MAX_GROUPS),
        ] {
            if count > max {
                err.push(what, Problem::TooMany { what, count, max });
            }
        }

        // Axes.
        let mut axis_index: HashMap<&str, usize> = HashMap::new();
        let mut nodes: HashMap<(&str, i64), usize> = HashMap::new();
        let mut positions: HashMap<(&str, i64), usize> = HashMap::new();
        let mut plans: Vec<BusPlan> = self.buses.iter().map(|_| BusPlan::default()).collect();
        for (i, a) in self.axes.iter().enumerate() {
            let key = format!("axes[{i}]");
            if let Some(rule) = name_rule(&a.name) {
                err.push(
                    format!("{key}.name"),
                    Problem::BadName {
                        name: a.name.clone(),
                        rule,
                    },
                );
            }
            if a.unit.len() > shm_api::contract::UNIT_LEN {
                err.push(
                    format!("{key}.unit"),
                    Problem::BadName {
                        name: a.unit.clone(),
                        rule: UNIT_RULE,
                    },
                );
            }
            if let Some(&j) = axis_index.get(a.name.as_str()) {
                err.push(
                    format!("{key}.name"),
                    Problem::DuplicateName(a.name.clone(), format!("axes[{j}]")),
                );
            } else {
                axis_index.insert(&a.name, i);
            }
            let profile = a.profile();
            if !a.device.device().offers(profile.into()) {
                err.push(
                    format!("{key}.profile"),
                    Problem::Profile {
                        device: a.device,
                        profile,
                        offered: a.device.profiles().map(|p| p.to_string()).collect(),
                    },
                );
            }
            let device = a.device;
            let ethercat_bus = a
                .bus
                .as_deref()
                .and_then(|b| bus_index.get(b))
                .copied()
                .filter(|&bi| self.buses[bi].kind == BusKind::Ethercat);
            if a.position.is_some() && ethercat_bus.is_none() {
                err.push(
                    format!("{key}.position"),
                    Problem::NotAllowed {
                        device,
                        reason: "has a position only on an ethercat bus (`bus` names one)",
                    },
                );
            }
            if let Some(bi) = ethercat_bus {
                let cycle_us = self.bus_cycle_us(&self.buses[bi]);
                let cycle_key = if self.buses[bi].cycle_us.is_some() {
                    format!("buses[{bi}].cycle_us")
                } else {
                    "cycle_us".to_owned()
                };
                if let Some(p) = check_ethercat_axis(&key, a, cycle_us, &cycle_key, &mut err) {
                    let bus_name = self.buses[bi].name.as_str();
                    if let Some(&j) = positions.get(&(bus_name, p)) {
                        err.push(
                            format!("{key}.position"),
                            Problem::DuplicatePosition {
                                position: p,
                                bus: bus_name.to_string(),
                                other: format!("axes[{j}]"),
                            },
                        );
                    } else {
                        positions.insert((bus_name, p), i);
                    }
                }
            } else if device.is_modbus() {
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
                if a.homing_method.is_some() {
                    err.push(
                        format!("{key}.homing_method"),
                        not("is homed by FHPP, which has no CiA 402 homing method (6098h)"),
                    );
                }
                if let Some(k) = a.supervision_key() {
                    err.push(
                        format!("{key}.{k}"),
                        not("is supervised by its Modbus timeout"),
                    );
                }
                match (&a.modbus, a.simulated) {
                    (None, false) => err.push(format!("{key}.modbus"), Problem::Missing { device }),
                    (Some(_), true) => err.push(
                        format!("{key}.modbus"),
                        not("simulated inside the coordinator has no address: remove modbus, or remove simulated to dial the drive"),
                    ),
                    (Some(addr), false) if !valid_host_port(addr) => err.push(
                        format!("{key}.modbus"),
                        Problem::ModbusAddress(addr.clone()),
                    ),
                    _ => {}
                }
            } else {
                let not = |reason| Problem::NotAllowed { device, reason };
                if a.modbus.is_some() {
                    err.push(
                        format!("{key}.modbus"),
                        not("is on CANopen, not on Modbus TCP"),
                    );
                }
                if a.simulated {
                    err.push(
                        format!("{key}.simulated"),
                        not("is simulated by its bus's kind (kind = \"simulated\")"),
                    );
                }
                let facts = device.device().profile(profile.into());
                if a.fpc && facts.is_some_and(|f| f.fpc_pdo2.is_none()) {
                    let offered = device
                        .device()
                        .profiles
                        .iter()
                        .any(|p| p.fpc_pdo2.is_some());
                    err.push(
                        format!("{key}.fpc"),
                        not(if offered {
                            "has the FPC only with the fhpp profile"
                        } else {
                            "has no FPC parameter channel on PDO2"
                        }),
                    );
                }
                let node_ids =
                    i64::from(*catalog::NODE_IDS.start())..=(*catalog::NODE_IDS.end()).into();
                let node = match a.node {
                    None => {
                        err.push(format!("{key}.node"), Problem::Missing { device });
                        None
                    }
                    Some(n) if !node_ids.contains(&n) => {
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
                let cycle_us = bus.map_or(self.cycle_us, |bi| self.bus_cycle_us(&self.buses[bi]));
                check_supervision(&key, a, cycle_us, &mut err);
                check_mode(&key, a, cycle_us, &mut err);
                if let Some(bi) = bus
                    && a.eds.is_some()
                    && device == DeviceKind::Cia402
                    && self.buses[bi].kind == BusKind::Simulated
                {
                    err.push(
                        format!("{key}.eds"),
                        Problem::Eds(
                            "a drive on a simulated bus is this project's built-in generic drive, not the EDS's: put the axis on a vbus bus and start `drive-sim --config`, which simulates the drive from its EDS".into(),
                        ),
                    );
                }
                if let Some(bi) = bus {
                    let (r, t) = axis_pdos_in(device, profile, a.mode(), a.fpc);
                    plans[bi].rpdos.extend(r);
                    plans[bi].tpdos.extend(t);
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

        self.check_groups(&axis_index, &mut err);
        self.check_records(&axis_index, &mut err);
        self.build_group_tables(&mut err);

        // Budgets: every bus whose own settings are valid.
        let limit = Permille::from_percent(self.load_limit_percent.clamp(1, 100));
        let mut loads = Vec::new();
        for (i, b) in self.buses.iter().enumerate() {
            if !bus_ok[i] || b.kind == BusKind::Ethercat {
                continue;
            }
            let plan = &plans[i];
            let traffic = BusTraffic {
                name: &b.name,
                bitrate: b.bitrate,
                cycle: Duration::from_micros(self.bus_cycle_us(b).into()),
                sync_counter: b.sync_counter,
                rpdos: &plan.rpdos,
                tpdos: &plan.tpdos,
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
        let mut segments = Vec::new();
        for (i, b) in self.buses.iter().enumerate() {
            if b.kind != BusKind::Ethercat || !bus_ok[i] {
                continue;
            }
            let on_bus: Vec<i64> = positions
                .iter()
                .filter(|((bus, _), _)| *bus == b.name)
                .map(|((_, p), _)| *p)
                .collect();
            let n = on_bus.len();
            if n == 0 {
                err.push(
                    format!("buses[{i}]"),
                    Problem::Ethercat(format!(
                        "no axis is on ethercat bus \"{}\": give an axis `bus = \"{}\"` and its `position`",
                        b.name, b.name
                    )),
                );
                continue;
            }
            // ethercrab takes every subdevice it finds into the cycle, so the segment is the
            // configured axes, at positions 1..=n.
            if let Some(gap) = (1..=n as i64).find(|p| !on_bus.contains(p)) {
                err.push(
                    format!("buses[{i}]"),
                    Problem::Ethercat(format!(
                        "the axes on ethercat bus \"{}\" must sit at positions 1 to {n} (every subdevice of the segment is an axis), and no axis has position {gap}",
                        b.name
                    )),
                );
                continue;
            }
            let image_bytes: usize = self
                .axes
                .iter()
                .filter(|a| a.bus.as_deref() == Some(b.name.as_str()))
                .filter_map(|a| a.device.ethercat())
                .map(|e| {
                    let (rx, tx) = e.cyclic_pdos();
                    usize::from(rx.bytes() + tx.bytes())
                })
                .sum();
            let load = SegmentLoad {
                name: b.name.clone(),
                interface: b.interface().to_owned(),
                // Every cycle's frame also reads the reference clock (FRMW): the buses run SYNC0.
                traffic: drivers::ethercat::wire_time::CycleTraffic {
                    image_bytes,
                    subdevices: n,
                    dc: true,
                },
                cycle: Duration::from_micros(self.bus_cycle_us(b).into()),
            };
            if let Err(e) = load.check(limit) {
                err.push(format!("buses[{i}]"), Problem::Budget(e));
            }
            segments.push(load);
        }
        Report {
            loads,
            segments,
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

    fn check_groups(&self, axis_index: &HashMap<&str, usize>, err: &mut Errors) {
        let mut names: HashMap<&str, usize> = HashMap::new();
        let mut member_of: HashMap<&str, &str> = HashMap::new();
        for (g, group) in self.groups.iter().enumerate() {
            let key = format!("groups[{g}]");
            if let Some(rule) = name_rule(&group.name) {
                err.push(
                    format!("{key}.name"),
                    Problem::BadName {
                        name: group.name.clone(),
                        rule,
                    },
                );
            }
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
            if group.axes.len() > MAX_GROUP_AXES {
                err.push(
                    format!("{key}.axes"),
                    Problem::GroupTooLarge {
                        axes: group.axes.len(),
                        max: MAX_GROUP_AXES,
                    },
                );
            }
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
                // Members on different buses are fine: every bus gets its SYNC in the same
                // cycle (one period for all buses is checked with the buses).
                if self.axes[ai].device.is_modbus() {
                    modbus.get_or_insert(name);
                } else {
                    canopen = true;
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
            let device = axis.device;
            let Some(table) = device.device().records else {
                err.push(
                    format!("{key}.axis"),
                    Problem::NotAllowed {
                        device,
                        reason: "has no record table of its own: put its moves in a group's [[groups.records]]",
                    },
                );
                continue;
            };
            let max = u32::from(table.last);
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
            if rec.next.is_some() && !table.chaining {
                err.push(
                    format!("{key}.next"),
                    Problem::NotAllowed {
                        device,
                        reason: "does not chain its records: chain them in a group's [[groups.records]]",
                    },
                );
            } else if let Some(next) = rec.next
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

/// The record numbers each group defines (valid numbers only), with the index of the first
/// definition; the same for every check, so a link to a refused record is not also reported.
type Defined = Vec<HashMap<u32, usize>>;

impl Config {
    /// The groups' record tables, in group order (one per group, empty where a group has no
    /// records), with targets and comparator windows converted from user units to increments
    /// (`increments_per_unit`), forces from % to ‰. Refuses with the first error of
    /// [`Config::check`] if the configuration is not accepted, so a table never comes from a
    /// configuration `check` refuses.
    pub fn group_tables(&self) -> Result<Vec<(String, Box<RecordTable>)>, ConfigError> {
        if let Some(e) = self.check().errors.into_iter().next() {
            return Err(e);
        }
        let mut err = Errors(Vec::new());
        let tables = self.build_group_tables(&mut err);
        match err.0.into_iter().next() {
            Some(e) => Err(e),
            None => Ok(tables),
        }
    }

    /// Validates and converts every `[[groups.records]]`; errors go to `err` with their keys.
    fn build_group_tables(&self, err: &mut Errors) -> Vec<(String, Box<RecordTable>)> {
        let defined: Defined = self
            .groups
            .iter()
            .map(|g| {
                let mut m = HashMap::new();
                for (r, rec) in g.records.iter().enumerate() {
                    if (rec.number as usize) < records::RECORDS {
                        m.entry(rec.number).or_insert(r);
                    }
                }
                m
            })
            .collect();
        let mut tables = Vec::with_capacity(self.groups.len());
        for (g, group) in self.groups.iter().enumerate() {
            let gkey = format!("groups[{g}]");
            let axes = group.axes.len().min(MAX_GROUP_AXES) as u8;
            let mut table = Box::new(RecordTable::with_axes(axes));
            // `check_groups` refuses the group.
            if group.axes.len() > MAX_GROUP_AXES {
                tables.push((group.name.clone(), table));
                continue;
            }
            let before = err.0.len();
            for (r, rc) in group.records.iter().enumerate() {
                let key = format!("{gkey}.records[{r}]");
                let n0 = err.0.len();
                let record = self.group_record(g, r, &key, rc, &defined, err);
                if let Some(record) = record
                    && err.0.len() == n0
                    && let Err(e) = table.insert(rc.number as u16, record)
                {
                    err.push(key, Problem::Record(e));
                }
            }
            if err.0.len() == before
                && let Err(e) = table.validate()
            {
                err.push(format!("{gkey}.records"), Problem::Record(e));
            }
            tables.push((group.name.clone(), table));
        }
        tables
    }

    /// Axis `name` as a member of group `g`: its index in the group and its configuration.
    fn member(
        &self,
        g: usize,
        name: &str,
        key: &str,
        err: &mut Errors,
    ) -> Option<(usize, &AxisConfig)> {
        let group = &self.groups[g];
        let axis = self.axes.iter().find(|a| a.name == name);
        match (group.axes.iter().position(|a| a == name), axis) {
            (Some(i), Some(a)) => Some((i, a)),
            (_, None) => {
                err.push(key, Problem::UnknownAxis(name.to_string()));
                None
            }
            (None, Some(_)) => {
                err.push(
                    key,
                    Problem::NotInGroup {
                        axis: name.to_string(),
                        group: group.name.clone(),
                    },
                );
                None
            }
        }
    }

    fn group_record(
        &self,
        g: usize,
        r: usize,
        key: &str,
        rc: &GroupRecordConfig,
        defined: &Defined,
        err: &mut Errors,
    ) -> Option<records::Record> {
        let group = &self.groups[g];
        let mut ok = true;
        let mut rec = records::Record::default();
        if rc.number as usize >= records::RECORDS {
            err.push(
                format!("{key}.number"),
                Problem::Range {
                    value: rc.number.into(),
                    min: 0.0,
                    max: (records::RECORDS - 1) as f64,
                },
            );
            ok = false;
        } else if let Some(&first) = defined[g].get(&rc.number)
            && first != r
        {
            err.push(
                format!("{key}.number"),
                Problem::DuplicateGroupRecord {
                    group: group.name.clone(),
                    number: rc.number,
                    other: format!("groups[{g}].records[{first}]"),
                },
            );
            ok = false;
        }
        for (name, value, slot) in [
            ("velocity", rc.velocity, &mut rec.velocity_percent),
            (
                "acceleration",
                rc.acceleration,
                &mut rec.acceleration_percent,
            ),
            ("jerk", rc.jerk, &mut rec.jerk_percent),
        ] {
            if (1..=100).contains(&value) {
                *slot = value as u8;
            } else {
                err.push(
                    format!("{key}.{name}"),
                    Problem::Range {
                        value: value.into(),
                        min: 1.0,
                        max: 100.0,
                    },
                );
                ok = false;
            }
        }
        rec.mode = match rc.mode {
            GroupRecordMode::Position => RecordMode::Position,
            GroupRecordMode::Velocity => RecordMode::Velocity,
            GroupRecordMode::Force => RecordMode::Force,
        };
        match (rc.mode, rc.force) {
            (GroupRecordMode::Force, None) => {
                err.push(format!("{key}.force"), Problem::Needs("a force record"));
                ok = false;
            }
            (GroupRecordMode::Force, Some(f)) => {
                if f.is_finite() && f != 0.0 && (-300.0..=300.0).contains(&f) {
                    // Within ±300 %: at most ±3000 ‰.
                    rec.force_permille = PERMILLE_PER_PERCENT.to_inc(f).unwrap_or(0) as i32;
                } else {
                    err.push(
                        format!("{key}.force"),
                        Problem::Range {
                            value: f,
                            min: -300.0,
                            max: 300.0,
                        },
                    );
                    ok = false;
                }
            }
            (mode, Some(_)) => {
                let what = if mode == GroupRecordMode::Velocity {
                    "a velocity record"
                } else {
                    "a position record"
                };
                err.push(format!("{key}.force"), Problem::Unused(what));
                ok = false;
            }
            (_, None) => {}
        }
        rec.delay_ms = rc.delay_ms;
        rec.mc_in_chain = rc.mc_in_chain;
        for (name, &v) in &rc.targets {
            let k = format!("{key}.targets.{name}");
            let Some((i, axis)) = self.member(g, name, &k, err) else {
                ok = false;
                continue;
            };
            match target(rc, axis, v) {
                Ok(AxisTarget::Relative(_))
                    if rc.mode == GroupRecordMode::Velocity
                        && crate::axis::takes_one_set_point_per_move(
                            axis.device.axis_kind(),
                            axis.profile().into(),
                            axis.mode(),
                        ) =>
                {
                    err.push(
                        k,
                        Problem::NotAllowed {
                            device: axis.device,
                            reason: "in the CiA 402 profile takes one set-point per move (no \
                                     \"change set immediately\"): it cannot run a velocity \
                                     record; give it 0 here, a position record, or the fhpp profile",
                        },
                    );
                    ok = false;
                }
                Ok(t) => rec.targets[i] = t,
                Err(p) => {
                    err.push(k, p);
                    ok = false;
                }
            }
        }
        if rc.step.is_none() && rc.alternative.is_some() {
            err.push(
                format!("{key}.alternative"),
                Problem::AlternativeWithoutStep,
            );
            ok = false;
        }
        // A step back to the record itself on a condition that can hold as soon as the record
        // starts restarts it every cycle: a relative record then crawls on for ever, an
        // absolute one never gets anywhere. Only a condition that waits for the move (MC, a
        // delay after it) or for something outside it may lead back.
        for (which, s) in [("step", &rc.step), ("alternative", &rc.alternative)] {
            if let Some(s) = s
                && s.next == rc.number
                && (s.condition == ConditionKind::Immediately
                    || (rc.relative
                        && matches!(
                            s.condition,
                            ConditionKind::Position
                                | ConditionKind::Velocity
                                | ConditionKind::Force
                                | ConditionKind::Time
                        )))
            {
                err.push(
                    format!("{key}.{which}.next"),
                    Problem::SelfStep {
                        number: rc.number,
                        condition: s.condition.name(),
                    },
                );
                ok = false;
            }
        }
        if let Some(s) = &rc.step {
            match self.step(g, &format!("{key}.step"), s, defined, err) {
                Some(step) => rec.step = step,
                None => ok = false,
            }
        }
        if let Some(s) = &rc.alternative {
            match self.step(g, &format!("{key}.alternative"), s, defined, err) {
                Some(step) => rec.alternative = Some(step),
                None => ok = false,
            }
        }
        ok.then_some(rec)
    }

    fn step(
        &self,
        g: usize,
        key: &str,
        s: &StepConfig,
        defined: &Defined,
        err: &mut Errors,
    ) -> Option<records::Step> {
        let group = &self.groups[g];
        let kind = s.condition;
        let what = step_name(kind);
        let mut ok = true;
        for (k, set) in s.set_keys() {
            if set && !kind.keys().contains(&k) {
                err.push(format!("{key}.{k}"), Problem::Unused(what));
                ok = false;
            }
        }
        if !defined[g].contains_key(&s.next) {
            err.push(
                format!("{key}.next"),
                Problem::UnknownGroupRecord {
                    group: group.name.clone(),
                    number: s.next,
                },
            );
            ok = false;
        }
        let mut need = |name: &str, present: bool| {
            if !present {
                err.push(format!("{key}.{name}"), Problem::Needs(what));
            }
            present
        };
        let condition = match kind {
            ConditionKind::Mc => Some(StepCondition::Mc),
            ConditionKind::Immediately => Some(StepCondition::Immediately),
            ConditionKind::Delay => {
                need("ms", s.ms.is_some()).then(|| StepCondition::Delay(s.ms.unwrap_or_default()))
            }
            ConditionKind::Position | ConditionKind::Velocity | ConditionKind::Force => {
                let has = need("axis", s.axis.is_some())
                    & need("min", s.min.is_some())
                    & need("max", s.max.is_some());
                if has {
                    self.comparator(g, key, s, err)
                } else {
                    None
                }
            }
            ConditionKind::Time => {
                let has = need("min", s.min.is_some()) & need("max", s.max.is_some());
                if has { time_window(key, s, err) } else { None }
            }
            ConditionKind::Input => {
                if need("input", s.input.is_some()) {
                    match s.input.filter(|b| *b <= 31) {
                        Some(bit) => Some(StepCondition::Input {
                            bit: bit as u8,
                            edge: match s.edge.unwrap_or_default() {
                                EdgeConfig::Rising => Edge::Rising,
                                EdgeConfig::Falling => Edge::Falling,
                            },
                        }),
                        None => {
                            err.push(
                                format!("{key}.input"),
                                Problem::Range {
                                    value: s.input.unwrap_or_default().into(),
                                    min: 0.0,
                                    max: 31.0,
                                },
                            );
                            None
                        }
                    }
                } else {
                    None
                }
            }
            ConditionKind::Record => {
                let has = need("group", s.group.is_some()) & need("record", s.record.is_some());
                if has {
                    self.record_reached(key, s, defined, err)
                } else {
                    None
                }
            }
        };
        let condition = condition?;
        ok.then_some(records::Step {
            condition,
            next: s.next as u16,
        })
    }

    /// A comparator step (axis, min and max present).
    fn comparator(
        &self,
        g: usize,
        key: &str,
        s: &StepConfig,
        err: &mut Errors,
    ) -> Option<StepCondition> {
        let name = s.axis.as_deref().unwrap_or_default();
        let (i, axis) = self.member(g, name, &format!("{key}.axis"), err)?;
        let (min, max) = (s.min.unwrap_or_default(), s.max.unwrap_or_default());
        let mut ok = true;
        for (k, v) in [("min", min), ("max", max)] {
            if !v.is_finite() {
                err.push(format!("{key}.{k}"), Problem::NotFinite(v));
                ok = false;
            }
        }
        if ok && min > max {
            err.push(format!("{key}.min"), Problem::EmptyWindow { min, max });
            ok = false;
        }
        if !ok {
            return None;
        }
        // `check` refused the axis's scale if it is not one.
        let axis_scale = axis.scale().ok()?;
        let (quantity, scale, bound) = match s.condition {
            ConditionKind::Velocity => (Quantity::Velocity, axis_scale, i128::from(u32::MAX)),
            ConditionKind::Force => (Quantity::Force, PERMILLE_PER_PERCENT, 3000),
            _ => (Quantity::Position, axis_scale, i128::from(i32::MAX)),
        };
        let mut scaled = [0i64; 2];
        for (slot, (k, v)) in scaled.iter_mut().zip([("min", min), ("max", max)]) {
            // Finite (checked above): the exact product and its rounding exist.
            let exact = scale.increments(v).unwrap_or(Decimal::ZERO);
            let inc = exact.round().unwrap_or(i128::MAX);
            if inc.abs() > bound {
                let problem = if s.condition == ConditionKind::Force {
                    Problem::Range {
                        value: v,
                        min: -300.0,
                        max: 300.0,
                    }
                } else {
                    Problem::Increments {
                        value: v,
                        increments: exact,
                    }
                };
                err.push(format!("{key}.{k}"), problem);
                ok = false;
            }
            *slot = inc.clamp(-bound, bound) as i64;
        }
        let damping = Duration::from_millis(s.damping_ms.unwrap_or(0).into());
        ok.then_some(StepCondition::Comparator {
            axis: i as u8,
            quantity,
            window: Window::new(scaled[0], scaled[1], damping),
        })
    }

    /// A `record` step (group and record present).
    fn record_reached(
        &self,
        key: &str,
        s: &StepConfig,
        defined: &Defined,
        err: &mut Errors,
    ) -> Option<StepCondition> {
        let name = s.group.as_deref().unwrap_or_default();
        let record = s.record.unwrap_or_default();
        let Some(og) = self.groups.iter().position(|x| x.name == name) else {
            err.push(
                format!("{key}.group"),
                Problem::UnknownGroup(name.to_string()),
            );
            return None;
        };
        if !defined[og].contains_key(&record) {
            err.push(
                format!("{key}.record"),
                Problem::UnknownGroupRecord {
                    group: name.to_string(),
                    number: record,
                },
            );
            return None;
        }
        let group = u8::try_from(og).ok();
        if group.is_none() {
            err.push(
                format!("{key}.group"),
                Problem::Range {
                    value: og as f64,
                    min: 0.0,
                    max: 255.0,
                },
            );
        }
        Some(StepCondition::RecordReached {
            group: group?,
            record: record as u16,
        })
    }
}

/// "a position step", for the messages.
fn step_name(kind: ConditionKind) -> &'static str {
    match kind {
        ConditionKind::Mc => "an mc step",
        ConditionKind::Immediately => "an immediately step",
        ConditionKind::Delay => "a delay step",
        ConditionKind::Position => "a position step",
        ConditionKind::Velocity => "a velocity step",
        ConditionKind::Force => "a force step",
        ConditionKind::Time => "a time step",
        ConditionKind::Input => "an input step",
        ConditionKind::Record => "a record step",
    }
}

/// A `time` step (min and max present): whole ms, `0..=u32::MAX`, min <= max.
fn time_window(key: &str, s: &StepConfig, err: &mut Errors) -> Option<StepCondition> {
    let (min, max) = (s.min.unwrap_or_default(), s.max.unwrap_or_default());
    let mut ok = true;
    for (k, v) in [("min", min), ("max", max)] {
        if !(v.is_finite() && (0.0..=u32::MAX as f64).contains(&v)) {
            err.push(
                format!("{key}.{k}"),
                Problem::Range {
                    value: v,
                    min: 0.0,
                    max: u32::MAX as f64,
                },
            );
            ok = false;
        }
    }
    if ok && min > max {
        err.push(format!("{key}.min"), Problem::EmptyWindow { min, max });
        ok = false;
    }
    ok.then(|| StepCondition::Time {
        min: min.round() as u32,
        max: max.round() as u32,
    })
}

/// One axis's target of a group record, in increments.
fn target(rc: &GroupRecordConfig, axis: &AxisConfig, v: f64) -> Result<AxisTarget, Problem> {
    if !v.is_finite() {
        return Err(Problem::NotFinite(v));
    }
    if rc.mode == GroupRecordMode::Velocity {
        // Only the direction counts.
        return Ok(match v.partial_cmp(&0.0) {
            Some(core::cmp::Ordering::Greater) => AxisTarget::Relative(1),
            Some(core::cmp::Ordering::Less) => AxisTarget::Relative(-1),
            _ => AxisTarget::Keep,
        });
    }
    let l = &axis.limits;
    if l.position_min < l.position_max {
        let (min, max) = if rc.relative {
            let span = l.position_max - l.position_min;
            (-span, span)
        } else {
            (l.position_min, l.position_max)
        };
        if !(min..=max).contains(&v) {
            return Err(Problem::Range { value: v, min, max });
        }
    }
    // A scale that is not one is refused once, on the axis's key; the table is not used then.
    let Ok(scale) = axis.scale() else {
        return Ok(AxisTarget::Keep);
    };
    let exact = scale.increments(v).ok_or(Problem::NotFinite(v))?;
    let inc = exact
        .round()
        .and_then(|i| i32::try_from(i).ok())
        .ok_or(Problem::Increments {
            value: v,
            increments: exact,
        })?;
    Ok(if rc.relative {
        AxisTarget::Relative(inc.into())
    } else {
        AxisTarget::Absolute(inc.into())
    })
}

/// Checks the scaling and the limits of one axis, in units and in increments.
fn check_scaling(key: &str, a: &AxisConfig, err: &mut Errors) {
    let scale = a
        .scale()
        .map_err(|e| err.push(format!("{key}.increments_per_unit"), Problem::Scale(e)))
        .ok();
    if let Some(fe) = a.following_error {
        err.positive(&format!("{key}.following_error"), fe);
    }
    let l = &a.limits;
    let lk = format!("{key}.limits");
    // The exact increments of a finite value (compared exactly with the drive's range).
    let scaled = |v: f64| scale.and_then(|s| s.increments(v));
    for (name, v) in [
        ("position_min", l.position_min),
        ("position_max", l.position_max),
    ] {
        if !v.is_finite() {
            err.push(format!("{lk}.{name}"), Problem::NotFinite(v));
        } else if let Some(inc) = scaled(v)
            && (inc.cmp_int(i32::MIN.into()).is_lt() || inc.cmp_int(i32::MAX.into()).is_gt())
        {
            err.push(
                format!("{lk}.{name}"),
                Problem::Increments {
                    value: v,
                    increments: inc,
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
        if !err.positive(&k, v) {
            continue;
        }
        let Some(inc) = scaled(v) else { continue };
        if inc.cmp_int(1).is_lt() {
            err.push(
                k,
                Problem::BelowOneIncrement {
                    value: v,
                    increments: inc,
                },
            );
        } else if inc.cmp_int(u32::MAX.into()).is_gt() {
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

/// A CANopen axis's heartbeat or guard time against its device (the catalog) and the cycle.
fn check_supervision(key: &str, a: &AxisConfig, cycle_us: u32, err: &mut Errors) {
    let device = a.device.device();
    let range = |v: u32, max: u32| Problem::Range {
        value: v.into(),
        min: 0.0,
        max: max.into(),
    };
    match (a.heartbeat_ms, a.guard_time_ms) {
        (Some(_), Some(_)) => err.push(format!("{key}.heartbeat_ms"), Problem::BothSupervisions),
        (Some(h), None) => match device.heartbeat_max_ms {
            None => err.push(
                format!("{key}.heartbeat_ms"),
                Problem::NotAllowed {
                    device: a.device,
                    reason: "has no heartbeat, only node guarding (use guard_time_ms)",
                },
            ),
            Some(max) => {
                let max = u32::from(max).min(MAX_HEARTBEAT_MS);
                if h > max {
                    err.push(format!("{key}.heartbeat_ms"), range(h, max));
                }
            }
        },
        (None, Some(g)) => {
            let max = device.guard_time_max_ms.map_or(0, u32::from);
            if g > max {
                err.push(format!("{key}.guard_time_ms"), range(g, max));
            } else if g > 0 && u64::from(g) * 1000 < u64::from(cycle_us) {
                err.push(
                    format!("{key}.guard_time_ms"),
                    Problem::GuardBelowCycle {
                        guard_ms: g,
                        cycle_us,
                    },
                );
            }
        }
        (None, None) => {}
    }
}

/// `host:port` with a non-empty host and a port in 1..=65535.
/// Whether `addr` (already `host:port`) resolves to at least one address.
/// The first address `addr` (`host:port`) resolves to, or what the resolver said: what
/// `coordinator check` refuses and the run dials, found one way.
pub fn resolve_modbus(addr: &str) -> Result<std::net::SocketAddr, String> {
    use std::net::ToSocketAddrs;
    match addr.to_socket_addrs() {
        Ok(mut all) => all.next().ok_or_else(|| "the name has no address".into()),
        Err(e) => Err(e.to_string()),
    }
}

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
    fn the_vbus_example_is_the_same_machine_with_its_drives_elsewhere() {
        let c = Config::parse(&example_vbus()).unwrap();
        assert!(c.check().is_ok(), "{}", c.check());
        let e = Config::parse(EXAMPLE).unwrap();
        assert_eq!(c.buses.len(), e.buses.len());
        assert!(c.buses.iter().all(|b| b.kind == BusKind::Vbus));
        assert!(e.buses.iter().all(|b| b.kind == BusKind::Simulated));
        let g = c.axes.iter().find(|a| a.name == "gripper").unwrap();
        assert_eq!(
            (g.simulated, g.modbus.as_deref()),
            (false, Some("127.0.0.1:1502"))
        );
        assert_eq!(c.axes.len(), e.axes.len());
        assert_eq!(c.groups.len(), e.groups.len());
    }

    /// Every configuration shipped in `coordinator/examples` passes `check`, with the budget its
    /// header comment states.
    #[test]
    fn every_shipped_example_passes_check_with_its_stated_budget() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples");
        // The CSP examples' headers: 1720 µs of 2000 and 775 µs of 1000.
        let stated = [("csp-4-axes.toml", 1720), ("csp-1-axis-1ms.toml", 775)];
        let (mut seen, mut budgets) = (0, 0);
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_none_or(|e| e != "toml") {
                continue;
            }
            let text = std::fs::read_to_string(&path).unwrap();
            let c = Config::parse(&text).unwrap();
            let r = c.check();
            assert!(r.is_ok(), "{}: {r}", path.display());
            seen += 1;
            let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
            if let Some((_, load)) = stated.iter().find(|(f, _)| *f == name) {
                assert_eq!(r.loads[0].micros(), *load, "{name}: {r}");
                budgets += 1;
            }
        }
        assert!(seen >= 3, "{seen} examples in {}", dir.display());
        assert_eq!(budgets, stated.len(), "every stated budget was checked");
    }

    #[test]
    fn example_is_accepted_with_its_budget() {
        let c = Config::parse(EXAMPLE).unwrap();
        let r = c.check();
        assert!(r.is_ok(), "{r}");
        assert_eq!(r.loads.len(), 2);
        // can0: SYNC 55 + 2 * (135 + 125) PDO bits (the MTR-DCI, and the TLC5xx's PDO1 of 7
        // bytes) + guarding 55 + 65 + heartbeat 65 + EMCY 135 + SDO 270.
        let l = &r.loads[0];
        assert_eq!(l.bits(), 55 + 2 * 260 + 120 + 65 + 135 + 270);
        assert_eq!(
            (l.frames(), l.micros(), l.load()),
            (11, 1165, Permille(583))
        );
        // can1: the EMCA with its parameter channel, PDO1 and PDO2 each way.
        let l = &r.loads[1];
        assert_eq!(l.bits(), 55 + 4 * 135 + 120 + 135 + 270);
        assert_eq!(
            (l.frames(), l.micros(), l.load()),
            (10, 1120, Permille(560))
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
            7
        );
        // The budget counts exactly what the axes map, for every profile a device offers.
        for d in DeviceKind::ALL {
            for p in d.profiles() {
                let map = crate::axis::pdo_mapping(d.axis_kind(), p.into());
                let pdos = axis_pdos(d, p, false);
                let len = pdos.first().map(|p| usize::from(p.len));
                assert_eq!(map.rpdo.map(|r| r.len()), len, "{d} {p}");
                assert_eq!(map.tpdo.map(|t| t.len()), len, "{d} {p}");
                let fpc = crate::axis::fpc_mapping(d.axis_kind(), p.into());
                assert_eq!(
                    axis_pdos(d, p, true).len() - pdos.len(),
                    usize::from(fpc.is_some())
                );
            }
            // The configuration's (serde's) name is the catalog's.
            let de: serde::de::value::StrDeserializer<'_, serde::de::value::Error> =
                serde::de::IntoDeserializer::into_deserializer(d.device().id);
            assert_eq!(DeviceKind::deserialize(de), Ok(d));
        }
        assert!(axis_pdos(DeviceKind::CmmoSt, Profile::Fhpp, false).is_empty());
        // The MTR-DCI in CiA 402 takes one set-point per move: its profile RPDO2 (6081h, 6083h)
        // is counted beside PDO1, as if every cycle sent one; the TLC5xx has none.
        let lens = |d, p| {
            let (r, t) = axis_pdos_in(d, p, crate::axis::CyclicMode::Pp, false);
            (
                r.iter().map(|p| p.len).collect::<std::vec::Vec<_>>(),
                t.len(),
            )
        };
        assert_eq!(lens(DeviceKind::MtrDci, Profile::Cia402), (vec![8, 8], 1));
        assert_eq!(lens(DeviceKind::MtrDci, Profile::Fhpp), (vec![8], 1));
        assert_eq!(lens(DeviceKind::Tlc5xx, Profile::Cia402), (vec![7], 1));
        // The EMCA with its parameter channel beside the other two drives on can0 does not fit
        // 80 % (which is why the example gives it a bus of its own).
        let e = errors(&edited(&[(
            "bus = \"can1\"\nnode = 2",
            "bus = \"can0\"\nnode = 2",
        )]));
        assert_eq!(
            e,
            [
                "buses[0]: bus can0: 17 frames, 1825 us per 2000 us cycle = 91.3 %, \
              over the 80.0 % limit"
            ]
        );
    }

    /// A machine of `n` generic CiA 402 axes on one 1 Mbit/s bus, `extra` keys on each axis.
    fn cia402_machine(n: usize, cycle_us: u32, extra: &str) -> String {
        let mut t = format!(
            "cycle_us = {cycle_us}\n[[buses]]\nname = \"can0\"\nkind = \"simulated\"\nbitrate = 1000000\n"
        );
        for i in 1..=n {
            t += &format!(
                "[[axes]]\nname = \"a{i}\"\ndevice = \"cia402\"\nbus = \"can0\"\nnode = {i}\n\
                 increments_per_unit = 1000\n{extra}\n\
                 limits = {{ position_min = -100, position_max = 100, velocity = 100, acceleration = 1000 }}\n"
            );
        }
        t
    }

    #[test]
    fn cyclic_modes_are_checked_against_the_device_and_its_eds() {
        // The generic drive defaults to CSP and takes every mode; the budget counts its PDOs.
        let c = Config::parse(&cia402_machine(1, 1000, "")).unwrap();
        assert_eq!(c.axes[0].mode(), crate::axis::CyclicMode::Csp);
        assert!(c.check().is_ok(), "{}", c.check());
        for m in ["pp", "csv", "cst"] {
            let c = Config::parse(&cia402_machine(1, 1000, &format!("mode = \"{m}\""))).unwrap();
            assert!(c.check().is_ok(), "{m}: {}", c.check());
        }
        // One axis more than 1 ms at 1 Mbit/s holds is refused with the numbers.
        assert_eq!(
            errors(&cia402_machine(2, 1000, "")),
            [
                "buses[0]: bus can0: 10 frames, 1090 us per 1000 us cycle = 109.0 %, does not fit the cycle"
            ]
        );
        // At 2 ms four fit (coordinator/examples/csp-4-axes.toml), a fifth does not.
        assert_eq!(
            errors(&cia402_machine(5, 2000, "")),
            [
                "buses[0]: bus can0: 19 frames, 2035 us per 2000 us cycle = 101.8 %, does not fit the cycle"
            ]
        );
        // The seed devices stream profile position only; FHPP has no modes; EDS only on cia402.
        assert_eq!(
            errors(&edited(&[("node = 3", "node = 3\nmode = \"csp\"")])),
            [
                "axes[2].mode: \"csp\" (cyclic synchronous position) is not for this axis: the TLC5xx \
              streams profile position only (\"pp\"); cyclic synchronous modes need a `cia402` drive \
              that offers them"
            ]
        );
        let e = errors(&edited(&[("node = 1", "node = 1\nmode = \"pp\"")]));
        assert!(e[0].starts_with("axes[0].mode: \"pp\""), "{e:?}");
        assert!(e[0].contains("remove `mode`"), "{e:?}");
        assert_eq!(
            errors(&edited(&[("node = 3", "node = 3\neds = \"x.eds\"")])),
            [
                "axes[2].eds: a tlc5xx axis is described by the device catalog; `eds` is for device = \"cia402\""
            ]
        );
        // The homing method: the drive's, on the TLC5xx and cia402 drives only.
        assert!(errors(&edited(&[("node = 3", "node = 3\nhoming_method = 17")])).is_empty());
        assert_eq!(
            errors(&edited(&[("node = 3", "node = 3\nhoming_method = 99")])),
            [
                "axes[2].homing_method: 99 is not a homing method of the TLC5xx: 1, 2, 7, 11, 17, 18, 23, 27, 35"
            ]
        );
        let e = errors(&edited(&[(
            "simulated = true",
            "simulated = true\nhoming_method = 17",
        )]));
        assert!(
            e[0].starts_with("axes[3].homing_method: a cmmo-st axis is homed by FHPP"),
            "{e:?}"
        );
        let e = errors(&edited(&[("node = 1", "node = 1\nhoming_method = 17")]));
        assert!(
            e[0].starts_with("axes[0].homing_method: the coordinator sets"),
            "{e:?}"
        );
        // An EDS on a simulated bus would not be the drive that runs.
        let e = errors(&cia402_machine(1, 1000, "eds = \"drive.eds\""));
        assert!(
            e.iter()
                .any(|e| e.starts_with("axes[0].eds: a drive on a simulated bus")),
            "{e:?}"
        );
        // A cycle 60C2h cannot hold exactly.
        let e = errors(&cia402_machine(1, 1257, ""));
        assert!(
            e.iter()
                .any(|e| e.starts_with("axes[0].mode:") && e.contains("60C2h")),
            "{e:?}"
        );
        // An EDS without CSV in 6502h and with 60FFh not mappable: both named.
        let eds = "[6502]\nParameterName=Supported drive modes\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x000000A5\n\
                   [60FF]\nParameterName=Target velocity\nDataType=0x0004\nAccessType=rww\nPDOMapping=0\n";
        let mut c = Config::parse(&cia402_machine(1, 1000, "mode = \"csv\"")).unwrap();
        c.axes[0].eds_read = Some(
            crate::drive_eds::DriveEds::parse(eds, std::path::Path::new("drive.eds")).unwrap(),
        );
        let e: Vec<String> = c.check().errors.iter().map(|e| e.to_string()).collect();
        assert_eq!(e.len(), 1, "{e:?}");
        for part in [
            "axes[0].mode: \"csv\"",
            "EDS drive.eds",
            "6502h (supported drive modes = 000000A5h) has no cyclic synchronous velocity (mode 9)",
            "60FFh sub 0 is not PDO-mappable",
            "6040h sub 0 is not PDO-mappable",
            "no writable 60C2h sub 1",
            "1600h sub 0 (RPDO1 mapping) is not writable",
            "1A00h sub 0 (TPDO1 mapping) is not writable",
        ] {
            assert!(e[0].contains(part), "{part} in {}", e[0]);
        }
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
                    "increments_per_unit = 100.0",
                    "increments_per_unit = 45.51111111111111",
                )],
                "axes[3].increments_per_unit: 45.51111111111111 has 14 decimal places; an exact scale takes at most 12 (as in 400.0, 12.8 or 0.5)",
            ),
            (
                &[("increments_per_unit = 100.0", "increments_per_unit = 2e9")],
                "axes[3].increments_per_unit: 2000000000 is above 1000000000 increments per unit",
            ),
            (
                &[("simulated = true", "simulated = true\nbus = \"can0\"")],
                "axes[3].bus: a cmmo-st axis is on Modbus TCP, not on a CAN bus",
            ),
            (
                &[("simulated = true", "modbus = \"127.0.0.1\"")],
                "axes[3].modbus: \"127.0.0.1\" is not host:port",
            ),
            (
                &[("simulated = true", "# no address")],
                "axes[3].modbus: missing: a cmmo-st axis needs it",
            ),
            (
                &[(
                    "simulated = true",
                    "simulated = true\nmodbus = \"127.0.0.1:1502\"",
                )],
                "axes[3].modbus: a cmmo-st axis simulated inside the coordinator has no address",
            ),
            (
                &[("node = 3", "node = 3\nsimulated = true")],
                "axes[2].simulated: a tlc5xx axis is simulated by its bus's kind",
            ),
            (
                &[("kind = \"simulated\"", "kind = \"virtual\"")],
                "buses[0].kind: \"virtual\" is no longer a bus kind: say \"simulated\"",
            ),
            (
                &[("name = \"can1\"\n", "name = \"can1\"\ncycle_us = 4000\n")],
                "buses[1].cycle_us: 4000 us differs from bus \"can0\"'s 2000 us: one coordinator runs one cycle",
            ),
            (
                // The example has two buses (can0, can1).
                &[("sync = \"producer\"", "sync = \"consumer\"")],
                "buses[0].sync: a SYNC consumer bus must be the coordinator's only CAN bus",
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
                &[("profile = \"fhpp\"", "profile = \"cia402\"\nfpc = true")],
                "axes[0].fpc: a mtr-dci axis has the FPC only with the fhpp profile",
            ),
            (
                &[("node = 3", "node = 3\nfpc = true")],
                "axes[2].fpc: a tlc5xx axis has no FPC parameter channel on PDO2",
            ),
            (
                &[("node = 2 ", "profile = \"cia402\"\nnode = 2 ")],
                "axes[1].profile: emca does not offer the cia402 profile, only fhpp",
            ),
            (
                &[("heartbeat_ms = 100 ", "heartbeat_ms = 40000 ")],
                "axes[2].heartbeat_ms: 40000 is outside 0..=32767",
            ),
            (
                &[("guard_time_ms = 100 ", "guard_time_ms = 40000 ")],
                "axes[0].guard_time_ms: 40000 is outside 0..=32767",
            ),
            (
                &[("guard_time_ms = 100 ", "guard_time_ms = 1 ")],
                "axes[0].guard_time_ms: 1 ms is shorter than the cycle (2000 us)",
            ),
            (
                &[
                    ("name = \"z\"", "name = \"conveyor_section_1\""),
                    ("[\"z\"]", "[\"conveyor_section_1\"]"),
                    ("{ z =", "{ conveyor_section_1 ="),
                ],
                "axes[2].name: the name \"conveyor_section_1\" is longer than 16 bytes (the shared-memory contract's name field)",
            ),
            (
                &[("name = \"lift\"", "name = \"\"")],
                "groups[1].name: the name \"\" is empty: give the axis or group a name",
            ),
            (
                &[("name = \"lift\"", "name = \"2\"")],
                "groups[1].name: the name \"2\" is a number, which clients would take for an index",
            ),
            (
                &[("name = \"hand\"", "name = \"left hand\"")],
                "groups[2].name: the name \"left hand\" may hold only letters, digits, '_', '-' and '.' (no spaces or commas)",
            ),
            (
                &[("name = \"hand\"", "name = \"a,b\"")],
                "groups[2].name: the name \"a,b\" may hold only letters, digits, '_', '-' and '.' (no spaces or commas)",
            ),
            (
                &[("unit = \"deg\"", "unit = \"degrees_C\"")],
                "axes[3].unit: the name \"degrees_C\" is longer than 8 bytes (the shared-memory contract's unit field)",
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
                "records[0].next: axis \"y\" has no record 5",
            ),
            (
                &[("number = 2", "number = 65")],
                "records[1].number: 65 is outside 1..=64",
            ),
            (
                &[
                    ("axis = \"y\"", "axis = \"x\""),
                    ("axis = \"y\"", "axis = \"x\""),
                    ("number = 2", "number = 32"),
                ],
                "records[1].number: 32 is outside 1..=31",
            ),
            (
                &[("axis = \"y\"", "axis = \"x\"")],
                "records[0].next: a mtr-dci axis does not chain its records",
            ),
            (
                &[("axis = \"gripper\"", "axis = \"z\"")],
                "records[2].axis: a tlc5xx axis has no record table of its own",
            ),
            (
                &[("number = 2", "number = 1")],
                "records[1].number: record 1 of axis \"y\" is already defined by records[0]",
            ),
            (
                &[("position = 240.0", "position = 251.0")],
                "records[1].position: 251 is outside 0..=250",
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
                &[("name = \"can1\"\n", "name = \"can0\"\n")],
                "buses[1].name: the name \"can0\" is already used by buses[0]",
            ),
            (
                &[("position = 240.0", "position = inf")],
                "records[1].position: inf is not a finite number",
            ),
            (
                &[("position_min = -180.0", "position_min = nan")],
                "axes[3].limits.position_min: NaN is not a finite number",
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
    fn a_group_spans_buses_that_share_the_one_cycle() {
        // The example's gantry: x on can0, y on can1.
        let c = Config::parse(EXAMPLE).unwrap();
        let r = c.check();
        assert!(r.is_ok(), "{r}");
        assert_eq!(r.loads.len(), 2);
        let gantry = &c.groups[0].axes;
        let bus_of = |name: &str| {
            c.axes
                .iter()
                .find(|a| a.name == name)
                .and_then(|a| a.bus.clone())
        };
        assert_ne!(bus_of(&gantry[0]), bus_of(&gantry[1]));

        let can1 = "name = \"can1\"\n";
        let other_cycle = [(can1, "name = \"can1\"\ncycle_us = 4000\n")];
        assert_eq!(
            errors(&edited(&other_cycle)),
            [
                "buses[1].cycle_us: 4000 us differs from bus \"can0\"'s 2000 us: one coordinator \
              runs one cycle for all its buses"
            ]
        );
        let consumer = [(can1, "name = \"can1\"\nsync = \"consumer\"\n")];
        let e = errors(&edited(&consumer));
        assert_eq!(e.len(), 1, "{e:?}");
        assert!(e[0].starts_with("buses[1].sync: a SYNC consumer"), "{e:?}");
    }

    #[test]
    fn a_cycle_too_short_is_refused_with_the_numbers() {
        let e = errors(&edited(&[("cycle_us = 2000", "cycle_us = 1000")]));
        assert_eq!(
            e,
            [
                "buses[0]: bus can0: 11 frames, 1165 us per 1000 us cycle = 116.5 %, \
              does not fit the cycle",
                "buses[1]: bus can1: 10 frames, 1120 us per 1000 us cycle = 112.0 %, \
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
        assert_eq!(e.key, "line 19");
        assert!(e.to_string().contains("unknown field `sdo_slot`"), "{e}");
        let e = Config::parse(&edited(&[("device = \"emca\"", "device = \"emcb\"")])).unwrap_err();
        assert!(e.to_string().contains("emcb"), "{e}");
        let e = Config::parse("load_limit_percent = 50\n").unwrap_err();
        assert!(e.to_string().contains("cycle_us"), "{e}");
    }

    fn tables(text: &str) -> Vec<(String, Box<RecordTable>)> {
        Config::parse(text).unwrap().group_tables().unwrap()
    }

    #[test]
    fn group_tables_convert_the_example_to_increments() {
        use crate::records::{Record, Step};
        let t = tables(EXAMPLE);
        assert_eq!(t.len(), 3);
        let (name, gantry) = &t[0];
        assert_eq!(name, "gantry");
        assert_eq!(gantry.axes(), 2);
        assert_eq!(
            gantry.iter().map(|(n, _)| n).collect::<Vec<_>>(),
            [10, 11, 12, 13]
        );
        let keep = AxisTarget::Keep;
        let r10 = gantry.get(10).unwrap();
        // x: 400 inc/mm, y: 1000 inc/mm.
        assert_eq!(
            r10.targets[..3],
            [
                AxisTarget::Absolute(80_000),
                AxisTarget::Absolute(100_000),
                keep
            ]
        );
        assert_eq!(
            (
                r10.velocity_percent,
                r10.acceleration_percent,
                r10.jerk_percent
            ),
            (80, 50, 100)
        );
        assert_eq!(
            r10.step,
            Step {
                condition: StepCondition::Comparator {
                    axis: 0,
                    quantity: Quantity::Position,
                    window: Window::new(60_000, 84_000, Duration::from_millis(10)),
                },
                next: 11,
            }
        );
        let r11 = gantry.get(11).unwrap();
        assert_eq!(
            r11.targets[..2],
            [AxisTarget::Relative(40_000), AxisTarget::Relative(-40_000)]
        );
        assert_eq!((r11.delay_ms, r11.mc_in_chain), (50, false));
        assert_eq!(r11.step.condition, StepCondition::Mc);
        assert_eq!(
            r11.alternative,
            Some(Step {
                condition: StepCondition::Input {
                    bit: 0,
                    edge: Edge::Rising
                },
                next: 13
            })
        );
        assert_eq!(
            gantry.get(12).unwrap().step.condition,
            StepCondition::RecordReached {
                group: 1,
                record: 1
            }
        );
        assert_eq!(gantry.get(13).unwrap().step.condition, StepCondition::End);
        let (name, lift) = &t[1];
        assert_eq!(name, "lift");
        assert_eq!(
            *lift.get(0).unwrap(),
            Record {
                targets: [
                    AxisTarget::Absolute(320_000),
                    keep,
                    keep,
                    keep,
                    keep,
                    keep,
                    keep,
                    keep
                ],
                step: Step {
                    condition: StepCondition::Delay(200),
                    next: 1
                },
                ..Record::default()
            }
        );
        // The tables run: a chain starts on them.
        let mut chain = crate::records::Chain::new();
        chain
            .start(gantry, 10, drivers::time::Instant::ZERO)
            .unwrap();
    }

    #[test]
    fn a_velocity_record_cannot_drive_an_axis_that_takes_one_set_point_per_move() {
        let machine = |profile: &str, target: f64| {
            format!(
                "cycle_us = 2000\n\n[[buses]]\nname = \"can0\"\nkind = \"simulated\"\n\n\
                 [[axes]]\nname = \"m\"\ndevice = \"mtr-dci\"\nprofile = \"{profile}\"\n\
                 bus = \"can0\"\nnode = 1\nunit = \"mm\"\nincrements_per_unit = 400.0\n\
                 limits = {{ position_min = 0.0, position_max = 200.0, velocity = 50.0, \
                 acceleration = 200.0 }}\n\n\
                 [[groups]]\nname = \"g\"\naxes = [\"m\"]\n\n\
                 [[groups.records]]\nnumber = 1\nmode = \"velocity\"\nvelocity = 50\n\
                 targets = {{ m = {target:?} }}\n"
            )
        };
        let refused = errors(&machine("cia402", 1.0));
        assert_eq!(refused.len(), 1, "{refused:?}");
        assert!(
            refused[0].starts_with("groups[0].records[0].targets.m: a mtr-dci axis in the CiA 402")
                && refused[0].contains("cannot run a velocity record"),
            "{refused:?}"
        );
        // Standing still in it, or in FHPP, is fine.
        assert_eq!(errors(&machine("cia402", 0.0)), Vec::<String>::new());
        assert_eq!(errors(&machine("fhpp", 1.0)), Vec::<String>::new());
    }

    #[test]
    fn group_record_modes_and_comparator_units() {
        let text = edited(&[
            (
                "step = { condition = \"position\", axis = \"x\", min = 150.0, max = 210.0, damping_ms = 10, next = 11 }",
                "step = { condition = \"velocity\", axis = \"y\", min = -2.5, max = 2.5, next = 11 }\n\
                 alternative = { condition = \"force\", axis = \"x\", min = -10.0, max = 20.5, damping_ms = 3, next = 13 }",
            ),
            (
                "velocity = 50\n",
                "velocity = 50\nmode = \"velocity\"\ntargets = { z = -1.0 }\n",
            ),
            ("targets = { z = 20.0 }\n", ""),
            (
                "condition = \"delay\", ms = 200,",
                "condition = \"time\", min = 10.0, max = 30.0,",
            ),
        ]);
        let t = tables(&text);
        let r10 = t[0].1.get(10).unwrap();
        assert_eq!(
            r10.step.condition,
            StepCondition::Comparator {
                axis: 1,
                quantity: Quantity::Velocity,
                window: Window::new(-2_500, 2_500, Duration::ZERO),
            }
        );
        assert_eq!(
            r10.alternative.unwrap().condition,
            StepCondition::Comparator {
                axis: 0,
                quantity: Quantity::Force,
                window: Window::new(-100, 205, Duration::from_millis(3)),
            }
        );
        let lift = &t[1].1;
        assert_eq!(
            lift.get(0).unwrap().step.condition,
            StepCondition::Time { min: 10, max: 30 }
        );
        let r1 = lift.get(1).unwrap();
        assert_eq!(r1.mode, RecordMode::Velocity);
        assert_eq!(r1.targets[0], AxisTarget::Relative(-1));
        let forced = edited(&[("velocity = 50\n", "mode = \"force\"\nforce = -12.5\n")]);
        let r1 = *tables(&forced)[1].1.get(1).unwrap();
        assert_eq!((r1.mode, r1.force_permille), (RecordMode::Force, -125));
    }

    #[test]
    fn group_tables_refuse_what_check_refuses() {
        let c = Config::parse(&edited(&[("node = 2", "node = 0")])).unwrap();
        let e = c.group_tables().unwrap_err();
        assert_eq!(e.key, "axes[1].node");
    }

    #[test]
    fn each_bad_group_record_names_its_key() {
        let cases: &[(&[(&str, &str)], &str)] = &[
            (
                &[("number = 13\n", "number = 300\n")],
                "groups[0].records[3].number: 300 is outside 0..=255",
            ),
            (
                &[("number = 12\n", "number = 11\n")],
                "groups[0].records[2].number: record 11 of group \"gantry\" is already defined by groups[0].records[1]",
            ),
            (
                &[("next = 11 }", "next = 19 }")],
                "groups[0].records[0].step.next: group \"gantry\" has no record 19",
            ),
            (
                &[("next = 13 }", "next = 14 }")],
                "groups[0].records[1].alternative.next: group \"gantry\" has no record 14",
            ),
            (
                &[("x = 200.0, y = 100.0", "x = 200.0, z = 100.0")],
                "groups[0].records[0].targets.z: axis \"z\" is not in group \"gantry\"",
            ),
            (
                &[("x = 200.0, y = 100.0", "x = 200.0, w = 100.0")],
                "groups[0].records[0].targets.w: no axis named \"w\"",
            ),
            (
                &[("x = 200.0, y = 100.0", "x = 500.0, y = 100.0")],
                "groups[0].records[0].targets.x: 500 is outside 0..=400",
            ),
            (
                &[("x = 100.0, y = -40.0", "x = 100.0, y = -400.0")],
                "groups[0].records[1].targets.y: -400 is outside -250..=250",
            ),
            (
                &[("x = 100.0, y = -40.0", "x = nan, y = -40.0")],
                "groups[0].records[1].targets.x: NaN is not a finite number",
            ),
            (
                &[("velocity = 80 ", "velocity = 0 ")],
                "groups[0].records[0].velocity: 0 is outside 1..=100",
            ),
            (
                &[("acceleration = 50\n", "acceleration = 150\n")],
                "groups[0].records[0].acceleration: 150 is outside 1..=100",
            ),
            (
                &[("min = 150.0, max = 210.0", "min = 210.0, max = 150.0")],
                "groups[0].records[0].step.min: min 210 is above max 150: the condition could never be met",
            ),
            (
                &[("axis = \"x\", min", "axis = \"z\", min")],
                "groups[0].records[0].step.axis: axis \"z\" is not in group \"gantry\"",
            ),
            (
                &[(
                    "condition = \"position\", axis = \"x\", ",
                    "condition = \"position\", ",
                )],
                "groups[0].records[0].step.axis: missing: a position step needs it",
            ),
            (
                &[("min = 150.0, max = 210.0", "min = 195.0, max = 9000000.0")],
                "groups[0].records[0].step.max: 9000000 units are 3600000000 increments, outside the drive's 32-bit range",
            ),
            (
                &[(
                    "condition = \"mc\", next = 12",
                    "condition = \"mc\", ms = 5, next = 12",
                )],
                "groups[0].records[1].step.ms: an mc step does not take this key",
            ),
            (
                &[("input = 0,", "input = 32,")],
                "groups[0].records[1].alternative.input: 32 is outside 0..=31",
            ),
            (
                &[(
                    "group = \"lift\", record = 1",
                    "group = \"lifter\", record = 1",
                )],
                "groups[0].records[2].step.group: no group named \"lifter\"",
            ),
            (
                &[(
                    "group = \"lift\", record = 1",
                    "group = \"lift\", record = 5",
                )],
                "groups[0].records[2].step.record: group \"lift\" has no record 5",
            ),
            (
                &[("group = \"lift\", record = 1", "record = 1")],
                "groups[0].records[2].step.group: missing: a record step needs it",
            ),
            (
                &[("condition = \"delay\", ms = 200,", "condition = \"delay\",")],
                "groups[1].records[0].step.ms: missing: a delay step needs it",
            ),
            (
                &[(
                    "condition = \"delay\", ms = 200,",
                    "condition = \"time\", min = 30.0, max = 10.0,",
                )],
                "groups[1].records[0].step.min: min 30 is above max 10",
            ),
            (
                &[(
                    "condition = \"delay\", ms = 200,",
                    "condition = \"time\", min = -1.0, max = 10.0,",
                )],
                "groups[1].records[0].step.min: -1 is outside 0..=4294967295",
            ),
            (
                &[("velocity = 50\n", "velocity = 50\nmode = \"force\"\n")],
                "groups[1].records[1].force: missing: a force record needs it",
            ),
            (
                &[(
                    "velocity = 50\n",
                    "velocity = 50\nmode = \"force\"\nforce = 400.0\n",
                )],
                "groups[1].records[1].force: 400 is outside -300..=300",
            ),
            (
                &[("velocity = 50\n", "velocity = 50\nforce = 20.0\n")],
                "groups[1].records[1].force: a position record does not take this key",
            ),
            (
                &[(
                    "step = { condition = \"delay\", ms = 200, next = 1 }",
                    "alternative = { condition = \"mc\", next = 1 }",
                )],
                "groups[1].records[0].alternative: an alternative needs a step",
            ),
            (
                &[(
                    "axes = [\"z\"]",
                    "axes = [\"z\", \"gripper\", \"a\", \"b\", \"c\", \"d\", \"e\", \"f\", \"g\"]",
                )],
                "groups[1].axes: a group has at most 8 axes, this one has 9",
            ),
        ];
        for (edits, expected) in cases {
            let e = errors(&edited(edits));
            assert!(
                e.iter().any(|m| m.starts_with(expected)),
                "{edits:?}: expected {expected:?}, got {e:#?}"
            );
        }
        // Typos in a step are parse errors naming the key.
        let e = Config::parse(&edited(&[("damping_ms = 10,", "dampng_ms = 10,")])).unwrap_err();
        assert!(e.to_string().contains("unknown field `dampng_ms`"), "{e}");
        let e = Config::parse(&edited(&[(
            "condition = \"mc\"",
            "condition = \"arrived\"",
        )]))
        .unwrap_err();
        assert!(e.to_string().contains("arrived"), "{e}");
    }

    #[test]
    fn one_bad_record_does_not_drag_its_referrers_into_the_report() {
        // Record 13 refused for its targets: the records stepping to it are not also refused.
        let e = errors(&edited(&[("x = 10.0, y = 0.0", "x = 10.0, y = 900.0")]));
        assert_eq!(
            e,
            ["groups[0].records[3].targets.y: 900 is outside 0..=250"]
        );
    }

    /// The example's chains in virtual time: 2 ms cycles, each axis moving linearly toward its
    /// target at its share of its velocity limit, `motion_done` when every axis is there.
    /// Returns every group's actions with their cycle.
    fn run_example_chains(
        di_rises_at: Option<u64>,
    ) -> Vec<Vec<(u64, crate::records::ChainAction)>> {
        use crate::records::{Chain, ChainAction, ChainInputs};
        use drivers::time::Instant;
        let c = Config::parse(EXAMPLE).unwrap();
        let tables = c.group_tables().unwrap();
        struct G {
            chain: Chain,
            pos: Vec<i64>,
            target: Vec<i64>,
            speed: Vec<i64>,
            rate: Vec<i64>,
            done: bool,
            log: Vec<(u64, ChainAction)>,
        }
        let mut groups: Vec<G> = c
            .groups
            .iter()
            .map(|g| {
                let rate: Vec<i64> = g
                    .axes
                    .iter()
                    .map(|n| {
                        let a = c.axes.iter().find(|a| &a.name == n).unwrap();
                        // One 2 ms cycle at the velocity limit.
                        a.scale().unwrap().to_inc(a.limits.velocity).unwrap() * 2 / 1000
                    })
                    .collect();
                G {
                    chain: Chain::new(),
                    pos: vec![0; g.axes.len()],
                    target: vec![0; g.axes.len()],
                    speed: rate.clone(),
                    rate,
                    done: true,
                    log: Vec::new(),
                }
            })
            .collect();
        groups[0]
            .chain
            .start(&tables[0].1, 10, Instant::ZERO)
            .unwrap();
        groups[1]
            .chain
            .start(&tables[1].1, 0, Instant::ZERO)
            .unwrap();
        let (mut di, mut previous) = (0u32, 0u32);
        for cycle in 0..5000u64 {
            if Some(cycle) == di_rises_at {
                di = 1;
            }
            let reached: Vec<Option<u16>> =
                groups.iter().map(|g| g.chain.status().reached).collect();
            for (gi, g) in groups.iter_mut().enumerate() {
                for ((p, t), v) in g.pos.iter_mut().zip(&g.target).zip(&g.speed) {
                    *p += (*t - *p).clamp(-v, *v);
                }
                g.done = g.done || g.pos == g.target;
                let zeros = vec![0i64; g.pos.len()];
                let inputs = ChainInputs {
                    now: Instant::from_millis(2 * cycle),
                    cycle,
                    motion_done: g.done,
                    positions: &g.pos,
                    velocities: &zeros,
                    forces: &[],
                    inputs: di,
                    previous_inputs: previous,
                    reached: &reached,
                };
                let table = &tables[gi].1;
                for a in g.chain.step(table, &inputs) {
                    g.log.push((cycle, a));
                    if let ChainAction::StartMotion { record } = a {
                        let r = table.get(record).unwrap();
                        for (i, t) in r.targets.iter().take(g.pos.len()).enumerate() {
                            g.target[i] = match *t {
                                AxisTarget::Keep => g.pos[i],
                                AxisTarget::Absolute(x) => x,
                                AxisTarget::Relative(d) => g.pos[i] + d,
                            };
                            g.speed[i] = (g.rate[i] * i64::from(r.velocity_percent) / 100).max(1);
                        }
                        g.done = false;
                    }
                }
            }
            previous = di;
        }
        groups.into_iter().map(|g| g.log).collect()
    }

    #[test]
    fn the_example_chains_run_across_groups() {
        use crate::records::ChainAction::{Complete, Reached, StartMotion};
        let logs = run_example_chains(None);
        let what = |log: &[(u64, crate::records::ChainAction)]| {
            log.iter().map(|(_, a)| *a).collect::<Vec<_>>()
        };
        // Gantry: 10 steps on the fly (x in its window), 11 (no MC shown) at MC to 12, which
        // waits for the lift's record 1, then 13 ends the chain.
        assert_eq!(
            what(&logs[0]),
            [
                StartMotion { record: 10 },
                StartMotion { record: 11 },
                StartMotion { record: 12 },
                Reached { record: 12 },
                StartMotion { record: 13 },
                Reached { record: 13 },
                Complete { record: 13 },
            ]
        );
        assert_eq!(
            what(&logs[1]),
            [
                StartMotion { record: 0 },
                Reached { record: 0 },
                StartMotion { record: 1 },
                Reached { record: 1 },
                Complete { record: 1 },
            ]
        );
        let at = |log: &[(u64, crate::records::ChainAction)], a| {
            log.iter().find(|(_, x)| *x == a).unwrap().0
        };
        // Record 10 hands over before its move could arrive (x needs 80 000 inc at 96 inc per
        // cycle, 834 cycles): x enters the window (60 000) at cycle 625, plus 5 cycles of
        // damping, plus record 11's start delay of 25 cycles.
        assert_eq!(at(&logs[0], StartMotion { record: 11 }), 625 + 5 + 25);
        // The lift's delay: 200 ms = 100 cycles after its MC.
        assert_eq!(
            at(&logs[1], StartMotion { record: 1 }) - at(&logs[1], Reached { record: 0 }),
            100
        );
        // The gantry waited at 12 for the lift and went on in the cycle after it was seen.
        let lift_done = at(&logs[1], Reached { record: 1 });
        assert!(at(&logs[0], Reached { record: 12 }) < lift_done);
        assert_eq!(at(&logs[0], StartMotion { record: 13 }), lift_done + 1);
    }

    #[test]
    fn the_example_chain_branches_on_the_input() {
        use crate::records::ChainAction::{Complete, StartMotion};
        let plain = run_example_chains(None);
        let start_11 = plain[0]
            .iter()
            .find(|(_, a)| *a == StartMotion { record: 11 })
            .unwrap()
            .0;
        // Input 0 rises while record 11 moves: the alternative, record 13, at once.
        let logs = run_example_chains(Some(start_11 + 5));
        let gantry: Vec<_> = logs[0].iter().map(|(_, a)| *a).collect();
        assert_eq!(
            gantry[..3],
            [
                StartMotion { record: 10 },
                StartMotion { record: 11 },
                StartMotion { record: 13 }
            ]
        );
        assert_eq!(logs[0][2].0, start_11 + 5);
        assert!(gantry.contains(&Complete { record: 13 }));
    }
}

#[cfg(test)]
mod ethercat_tests {
    use super::*;

    const LIMITS: &str = "limits = { position_min = 0.0, position_max = 100.0, velocity = 50.0, acceleration = 500.0 }";

    fn segment(cycle_us: u32, axes: &[(&str, &str)]) -> String {
        let mut t = format!(
            "cycle_us = {cycle_us}\n[[buses]]\nname = \"line\"\nkind = \"ethercat\"\ninterface = \"ecm\"\n"
        );
        for (i, (device, extra)) in axes.iter().enumerate() {
            t += &format!(
                "[[axes]]\nname = \"a{i}\"\ndevice = \"{device}\"\nbus = \"line\"\nincrements_per_unit = 100\n{LIMITS}\n{extra}\n"
            );
        }
        t
    }

    fn errors(text: &str) -> Vec<String> {
        let c = Config::parse(text).unwrap_or_else(|e| panic!("{e}"));
        c.check().errors.iter().map(|e| e.to_string()).collect()
    }

    #[test]
    fn a_segment_of_emcas_is_accepted_with_its_frame_time() {
        let text = segment(1000, &[("emca", "position = 1"), ("emca", "position = 2")]);
        let c = Config::parse(&text).unwrap();
        let r = c.check();
        assert!(r.is_ok(), "{r}");
        assert_eq!(r.segments.len(), 1);
        assert_eq!(r.segments[0].traffic.subdevices, 2);
        assert_eq!(r.segments[0].traffic.image_bytes, 32);
        assert!(
            r.to_string()
                .contains("bus line (EtherCAT on ecm): 2 subdevice(s)"),
            "{r}"
        );
    }

    #[test]
    fn the_ethercat_example_is_accepted() {
        let c = Config::parse(include_str!("../examples/ethercat.toml")).unwrap();
        let r = c.check();
        assert!(r.is_ok(), "{r}");
        assert_eq!(r.segments[0].traffic.subdevices, 3);
    }

    #[test]
    fn a_cycle_shorter_than_1c32_05_is_refused_naming_both() {
        let e = errors(&segment(500, &[("emca", "position = 1")]));
        assert!(
            e.iter()
                .any(|e| e.starts_with("cycle_us: the cycle of 500 us")
                    && e.contains("1000 us (1C32h:05)")),
            "{e:?}"
        );
    }

    #[test]
    fn ethercat_axes_are_refused_what_they_cannot_have() {
        let e = errors(&segment(
            1000,
            &[
                ("tlc5xx", "position = 1"),
                (
                    "emca",
                    "position = 3\nnode = 4\nfpc = true\nguard_time_ms = 100",
                ),
            ],
        ));
        let has = |key: &str, text: &str| e.iter().any(|x| x.starts_with(key) && x.contains(text));
        assert!(has("axes[0].bus", "no EtherCAT interface"), "{e:?}");
        assert!(has("axes[1].node", "position, not a node-ID"), "{e:?}");
        assert!(has("axes[1].fpc", "without the FPC"), "{e:?}");
        assert!(has("axes[1].guard_time_ms", "working counter"), "{e:?}");
        // Position 3 with no 1 or 2 (the TLC5xx's was refused): a gap.
        assert!(has("buses[0]", "no axis has position 1"), "{e:?}");
        let e = errors(&segment(
            1000,
            &[("emca", "position = 1"), ("emca", "position = 1")],
        ));
        assert!(e.iter().any(|x| x.starts_with("axes[1].position")), "{e:?}");
        let e = errors(&segment(1000, &[("emca", "position = 17")]));
        assert!(e.iter().any(|x| x.starts_with("axes[0].position")), "{e:?}");
        let e = errors(&segment(1000, &[("emca", "")]));
        assert!(
            e.iter().any(|x| x.starts_with("axes[0].position: missing")),
            "{e:?}"
        );
    }

    #[test]
    fn can_keys_on_an_ethercat_bus_and_interface_on_a_can_bus_are_refused() {
        let text = segment(1000, &[("emca", "position = 1")]).replace(
            "interface = \"ecm\"",
            "interface = \"ecm\"\nbitrate = 500000",
        );
        let e = errors(&text);
        assert!(e.iter().any(|x| x.starts_with("buses[0].bitrate")), "{e:?}");
        let text =
            "cycle_us = 1000\n[[buses]]\nname = \"can0\"\nkind = \"vbus\"\ninterface = \"x\"\n";
        let e = errors(text);
        assert!(
            e.iter().any(|x| x.starts_with("buses[0].interface")),
            "{e:?}"
        );
    }
}
