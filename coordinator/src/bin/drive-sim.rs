//! `drive-sim`: simulated drives as their own process, as real devices would be.
//!
//! ```text
//! drive-sim --config machine.toml [--only AXIS]...     # the drives a configuration dials
//! drive-sim --device tlc5xx  --bus vbus:NAME --node 1 [--node 2 ...]
//!           [--limit-negative POS] [--limit-positive POS] [--reference FROM..TO]
//! drive-sim --device mtr-dci --bus vbus:NAME --node 3 [--profile fhpp|cia402]
//! drive-sim --device emca    --bus vbus:NAME --node 4
//! drive-sim --device emca    --ethercat IFACE [--count N]
//! drive-sim --device cmmo-st --modbus 127.0.0.1:PORT
//! drive-sim --device cia402  --bus vbus:NAME --node 5 [--eds FILE]
//! drive-sim --write-eds tlc5xx|mtr-dci|emca|cia402
//! ```
//!
//! With `--config`, every drive the coordinator would dial starts: each CANopen axis on a bus of
//! kind `vbus` (on `vbus:BUS` at the bus's bitrate) and each CMMO-ST without `simulated = true`
//! (a Modbus TCP server on its `modbus` address). Axes the coordinator simulates itself, and axes
//! on real (SocketCAN) buses, are skipped with a line saying why. `--only` narrows the set, so a
//! drive can be stopped and started again on its own.
//!
//! CANopen drives run on the shared-memory virtual bus in real time (one bus endpoint per
//! drive). With `--ethercat IFACE` the EMCA is an EtherCAT subdevice (EMCA-EC) on a network
//! interface, `--count N` of them chained in this process as one segment; raw sockets need
//! CAP_NET_RAW, so this runs as root or in a network namespace (`unshare -rn`) on a veth pair.
//! Standard input switches a subdevice's power: `off N`, `on N` (N from 1). A status line per
//! drive goes to stderr every `--status-every` seconds; Ctrl-C, SIGTERM or `--duration` ends
//! the run.

use std::collections::HashSet;
use std::net::{SocketAddr, ToSocketAddrs};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use clap::{ArgGroup, Parser, ValueEnum};
use coordinator::config::{BusKind, Config, DeviceKind, Profile, SyncMode};
use coordinator::drivers;
use drivers::can::Bus;
use drivers::can::shm_bus::ShmBus;
use drivers::can::station::Station;
use drivers::canopen::NodeId;
use drivers::canopen::eds_write::{DeviceInfo, write_eds};
use drivers::canopen::endpoint::Endpoint;
use drivers::cli_number::Allowed;
use drivers::ethercat::frame::MAX_FRAME_LEN;
use drivers::ethercat::raw::RawSocket;
use drivers::ethercat::segment;
use drivers::fhpp::state::State as FhppState;
use drivers::sim::axis::{SwitchZone, Switches as Inputs};
use drivers::sim::cia402_drive::{Cia402Config, Cia402Drive};
use drivers::sim::cmmo_st::{self, Server, ServerConfig};
use drivers::sim::emca::Emca;
use drivers::sim::emca_ec::EmcaEc;
use drivers::sim::fhpp_drive::FhppDrive;
use drivers::sim::mtr_dci::{FestoNode, MtrDci, Profile as MtrProfile};
use drivers::sim::tlc5xx::{Tlc5xx, TlcConfig};
use drivers::time::{Instant, monotonic_now};

/// `--duration`: the same range as `coordinator run --duration`, from a millisecond (less
/// would end before a drive could answer anything) to a year.
const DURATION: Allowed =
    Allowed::new("seconds", 0.001, 31_536_000.0).note("leave --duration out to run until Ctrl-C");
/// `--status-every`: 0 (never), or from a hundredth of a second to one line a day.
const STATUS_EVERY: Allowed = Allowed::new("seconds", 0.01, 86_400.0).note("or 0: never");
/// The shared-memory bus has no wake-up event: poll it at least this often.
const CAN_POLL: Duration = Duration::from_micros(200);
/// Without CAN drives the loop only prints status lines and watches for the end.
const IDLE_POLL: Duration = Duration::from_millis(20);

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum DeviceArg {
    /// Festo MTR-DCI (CANopen, FHPP or CiA 402).
    MtrDci,
    /// Festo EMCA (CANopen, FHPP + FPC).
    Emca,
    /// TLC5xx (CANopen DS301 / DSP402).
    Tlc5xx,
    /// Festo CMMO-ST (Modbus TCP, FHPP).
    CmmoSt,
    /// A generic CiA 402 drive (PP, PV, HM, CSP, CSV, CST): the built-in EDS, or `--eds FILE`.
    Cia402,
}

impl DeviceArg {
    /// The catalog kind; `None` for the generic CiA 402 drive, which the EDS describes.
    fn kind(self) -> Option<DeviceKind> {
        Some(match self {
            DeviceArg::MtrDci => DeviceKind::MtrDci,
            DeviceArg::Emca => DeviceKind::Emca,
            DeviceArg::Tlc5xx => DeviceKind::Tlc5xx,
            DeviceArg::CmmoSt => DeviceKind::CmmoSt,
            DeviceArg::Cia402 => return None,
        })
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum ProfileArg {
    /// Festo Handling and Positioning Profile.
    Fhpp,
    /// CiA 402 (MTR-DCI only).
    Cia402,
}

/// Simulated drives as their own process: the drives of a coordinator configuration
/// (`--config`), or drives of one kind (`--device`).
#[derive(Debug, Parser)]
#[command(version, group(ArgGroup::new("what").required(true).args(["config", "device", "write_eds"])))]
struct Cli {
    /// A coordinator configuration: start every drive it dials (the axes on `vbus` buses and
    /// the CMMO-STs without `simulated = true`).
    #[arg(long, value_name = "FILE", conflicts_with_all = ["device", "bus", "nodes", "modbus", "profile", "bitrate"])]
    config: Option<PathBuf>,
    /// With --config: start only this axis (repeat for more).
    #[arg(long = "only", value_name = "AXIS", requires = "config")]
    only: Vec<String>,
    /// The device to simulate.
    #[arg(long, value_enum)]
    device: Option<DeviceArg>,
    /// Print the CiA 306 EDS of this device (its simulator's object dictionary, as a freshly
    /// powered drive has it; COB-IDs relative to $NODEID) and exit. With `--profile` for the
    /// MTR-DCI's CiA 402 face; `cia402` is the generic drive's built-in EDS.
    #[arg(long, value_enum, value_name = "DEVICE", conflicts_with_all = ["config", "device", "bus", "nodes", "modbus", "bitrate", "duration", "eds", "limit_negative", "limit_positive", "reference"])]
    write_eds: Option<DeviceArg>,
    /// With `--device cia402`: the drive's CiA 306 EDS (or DCF); its objects and defaults, its
    /// identity (1018h) and its modes (6502h) make the simulated drive. Default: the built-in
    /// one (`--write-eds cia402`).
    #[arg(long, value_name = "FILE", requires = "device")]
    eds: Option<PathBuf>,
    /// The CAN bus: `vbus:NAME` (the shared-memory virtual bus).
    #[arg(long)]
    bus: Option<String>,
    /// EMCA only: be an EtherCAT subdevice (EMCA-EC) on this network interface instead of a
    /// CANopen node: a veth end in a network namespace (raw sockets need CAP_NET_RAW).
    #[arg(long, value_name = "IFACE", conflicts_with = "config")]
    ethercat: Option<String>,
    /// With --ethercat: how many EMCA subdevices this process chains as one segment, 1..=16.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u8).range(1..=16))]
    count: Option<u8>,
    /// With --ethercat: the revision the subdevices report (SII, 1018h:03) instead of the
    /// catalog's, in hex (`0x00020000`) or decimal: another firmware, to see a master's
    /// identity check refuse it.
    #[arg(long, value_name = "REVISION", value_parser = parse_revision)]
    revision: Option<u32>,
    /// Node-ID(s), 1..=127; one drive per `--node`.
    #[arg(long = "node", num_args = 1.., value_parser = clap::value_parser!(u8).range(1..=127))]
    nodes: Vec<u8>,
    /// Bus bitrate, bit/s.
    #[arg(long, default_value_t = 1_000_000)]
    bitrate: u32,
    /// The profile, where the device offers two (the MTR-DCI: fhpp or cia402); default: the
    /// device's first.
    #[arg(long, value_enum)]
    profile: Option<ProfileArg>,
    /// Modbus TCP address to serve (CMMO-ST), e.g. 127.0.0.1:1502.
    #[arg(long)]
    modbus: Option<SocketAddr>,
    /// End after this many seconds (default: run until Ctrl-C).
    // Text, checked by `timing`: the message then quotes what the user wrote, and a negative
    // number gets that message rather than clap's "unexpected argument".
    #[arg(long, value_name = "SECONDS", allow_hyphen_values = true)]
    duration: Option<String>,
    /// Print a status line per drive this often, in seconds (0 = never).
    #[arg(
        long,
        value_name = "SECONDS",
        default_value = "1",
        allow_hyphen_values = true
    )]
    status_every: String,
    /// TLC5xx only: the negative limit switch (LIMN), active below POS. Switch positions are
    /// motor increments, 16384 per revolution, counted from where the drive powers on (0):
    /// the TLC5xx's user unit at its factory scaling (6093h = 1/16384), so what 6064h shows
    /// before homing moves its zero, and what a configuration's increments_per_unit counts.
    /// Give 0 or less (the drive must not power on on the switch).
    #[arg(long, value_name = "POS", allow_hyphen_values = true)]
    limit_negative: Option<String>,
    /// TLC5xx only: the positive limit switch (LIMP), active from POS upwards (motor
    /// increments, as --limit-negative); 1 or more.
    #[arg(long, value_name = "POS", allow_hyphen_values = true)]
    limit_positive: Option<String>,
    /// TLC5xx only: the reference switch (REF), a cam active from FROM up to TO (motor
    /// increments, as --limit-negative), between the limit switches. With the switches,
    /// homing methods 1, 2, 7, 11, 17, 18, 23 and 27 find their signal.
    #[arg(long, value_name = "FROM..TO", allow_hyphen_values = true)]
    reference: Option<String>,
}

/// A switch position: a whole number of motor increments, within the 32 bits of the TLC5xx's
/// position objects.
const SWITCH_POSITION: Allowed =
    Allowed::new("whole motor increments", i32::MIN as f64, i32::MAX as f64)
        .note("16384 per revolution, from the power-on position 0");

/// The TLC5xx's limit and reference switches (`--limit-negative`, `--limit-positive`,
/// `--reference`), raw positions of its simulated axis.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct Switches {
    limit_negative: Option<i64>,
    limit_positive: Option<i64>,
    reference: Option<(i64, i64)>,
}

impl Switches {
    fn any(&self) -> bool {
        *self != Switches::default()
    }

    /// The options as given, for refusals: `--limit-negative -5000`.
    fn given(cli: &Cli) -> Vec<String> {
        [
            ("--limit-negative", &cli.limit_negative),
            ("--limit-positive", &cli.limit_positive),
            ("--reference", &cli.reference),
        ]
        .into_iter()
        .filter_map(|(flag, v)| v.as_ref().map(|v| format!("{flag} {v}")))
        .collect()
    }

    /// Checks the options: every number whole and in range, the drive's power-on position 0
    /// off both limit switches, the reference cam between them.
    fn from_cli(cli: &Cli) -> Result<Switches, String> {
        let position = |flag: &str, text: &str| -> Result<i64, String> {
            let v = SWITCH_POSITION.parse_flag(flag, text)?;
            if v.fract() != 0.0 {
                return Err(format!("{flag} {text}: {}", SWITCH_POSITION.refusal()));
            }
            Ok(v as i64)
        };
        let limit_negative = match &cli.limit_negative {
            None => None,
            Some(t) => {
                let v = position("--limit-negative", t)?;
                if v > 0 {
                    return Err(format!(
                        "--limit-negative {t}: give 0 or less: the switch is active below the \
                         position, and the drive powers on at 0, which must not be on it"
                    ));
                }
                Some(v)
            }
        };
        let limit_positive = match &cli.limit_positive {
            None => None,
            Some(t) => {
                let v = position("--limit-positive", t)?;
                if v <= 0 {
                    return Err(format!(
                        "--limit-positive {t}: give 1 or more: the switch is active from the \
                         position upwards, and the drive powers on at 0, which must not be on it"
                    ));
                }
                Some(v)
            }
        };
        let reference = match &cli.reference {
            None => None,
            Some(t) => {
                let Some((a, b)) = t.split_once("..") else {
                    return Err(format!(
                        "--reference {t}: give FROM..TO, the positions between which the switch \
                         is active (e.g. 10000..12000)"
                    ));
                };
                // The refusal quotes the whole FROM..TO the user wrote.
                let whole = |_| {
                    format!(
                        "--reference {t}: FROM and TO: {}",
                        SWITCH_POSITION.refusal()
                    )
                };
                let from = position("--reference", a).map_err(whole)?;
                let to = position("--reference", b).map_err(whole)?;
                if from >= to {
                    return Err(format!(
                        "--reference {t}: FROM must be below TO (the switch is active from FROM \
                         up to TO)"
                    ));
                }
                let low = limit_negative.unwrap_or(i64::MIN);
                let high = limit_positive.unwrap_or(i64::MAX);
                if from < low || to > high {
                    return Err(format!(
                        "--reference {t}: the cam must lie between the limit switches ({} .. {}), \
                         or homing could never reach it",
                        limit_negative.map_or("none".into(), |v| v.to_string()),
                        limit_positive.map_or("none".into(), |v| v.to_string()),
                    ));
                }
                Some((from, to))
            }
        };
        Ok(Switches {
            limit_negative,
            limit_positive,
            reference,
        })
    }
}

/// What a CANopen drive to start is.
#[derive(Debug, Clone, PartialEq, Eq)]
enum CanDevice {
    /// A device of the catalog.
    Catalog(DeviceKind),
    /// The generic CiA 402 drive: the built-in dictionary, or that of an EDS file.
    Cia402 {
        /// The EDS file, if not the built-in one.
        eds: Option<PathBuf>,
    },
}

impl CanDevice {
    fn name(&self) -> &'static str {
        match self {
            CanDevice::Catalog(kind) => device_name(*kind),
            CanDevice::Cia402 { .. } => "CiA 402 drive",
        }
    }
}

/// A CANopen drive to start.
#[derive(Debug, Clone)]
struct CanSpec {
    /// The axis name (`--config`), for the status lines.
    axis: Option<String>,
    device: CanDevice,
    profile: Profile,
    node: NodeId,
    /// The bus name without `vbus:`.
    bus: String,
    bitrate: u32,
    /// The TLC5xx's switches (none for other devices).
    switches: Switches,
}

/// A CMMO-ST to serve.
#[derive(Debug, Clone)]
struct ModbusSpec {
    axis: Option<String>,
    /// The address as configured (for messages).
    text: String,
    addr: SocketAddr,
}

/// An EtherCAT segment of simulated EMCAs on a network interface.
#[derive(Debug, Clone)]
struct EcSpec {
    iface: String,
    count: u8,
    /// The revision reported, if not the catalog's.
    revision: Option<u32>,
}

/// `--revision`: a 32-bit number, `0x` hex or decimal.
fn parse_revision(text: &str) -> Result<u32, String> {
    let t = text.trim();
    let parsed = match t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(hex, 16),
        None => t.parse::<u32>(),
    };
    parsed.map_err(|_| {
        format!("\"{text}\" is not a revision: give 0x followed by up to 8 hex digits, or a decimal number up to 4294967295")
    })
}

/// Everything one run starts.
#[derive(Debug, Default)]
struct Plan {
    can: Vec<CanSpec>,
    modbus: Vec<ModbusSpec>,
    ethercat: Option<EcSpec>,
}

/// `name: ` for a configured axis, nothing otherwise.
fn prefix(axis: &Option<String>) -> String {
    axis.as_ref().map_or_else(String::new, |a| format!("{a}: "))
}

/// The device's name as its manual writes it.
fn device_name(kind: DeviceKind) -> &'static str {
    kind.device().name
}

fn profile_name(profile: Profile) -> &'static str {
    match profile {
        Profile::Fhpp => "FHPP",
        Profile::Cia402 => "CiA 402",
    }
}

/// Checks `--duration` and `--status-every` before anything uses them: a user's number must
/// never reach `Duration::from_secs_f64` out of range (it panics on NaN, negative, overflow).
fn timing(cli: &Cli) -> Result<(Option<Duration>, Option<Duration>), String> {
    let duration = match &cli.duration {
        None => None,
        Some(text) => Some(Duration::from_secs_f64(
            DURATION.parse_flag("--duration", text)?,
        )),
    };
    let text = &cli.status_every;
    let every = if text.trim().parse::<f64>() == Ok(0.0) {
        None
    } else {
        Some(Duration::from_secs_f64(
            STATUS_EVERY.parse_flag("--status-every", text)?,
        ))
    };
    Ok((duration, every))
}

/// The plan of `--device ...`.
/// The profile `asked` for, or the device's first; refused where the device lacks it.
fn chosen_profile(kind: DeviceKind, asked: Option<ProfileArg>) -> Result<Profile, String> {
    // The device catalog says which profiles a device offers; the first is its default.
    let first = kind.profiles().next().unwrap_or(Profile::Fhpp);
    match asked {
        None => Ok(first),
        Some(p) => {
            let wanted = match p {
                ProfileArg::Fhpp => Profile::Fhpp,
                ProfileArg::Cia402 => Profile::Cia402,
            };
            if !kind.profiles().any(|o| o == wanted) {
                let offered: Vec<&str> = kind.profiles().map(profile_name).collect();
                let arg = match p {
                    ProfileArg::Fhpp => "fhpp",
                    ProfileArg::Cia402 => "cia402",
                };
                return Err(format!(
                    "--profile {arg}: the {} offers {} only",
                    device_name(kind),
                    offered.join(" and ")
                ));
            }
            Ok(wanted)
        }
    }
}

fn plan_from_args(cli: &Cli, device: DeviceArg) -> Result<Plan, String> {
    let (can_device, profile) = match device.kind() {
        Some(kind) => (CanDevice::Catalog(kind), chosen_profile(kind, cli.profile)?),
        None => {
            if cli.profile.is_some_and(|p| p != ProfileArg::Cia402) {
                return Err("--profile: the generic drive speaks CiA 402 only".into());
            }
            let eds = cli.eds.clone();
            (CanDevice::Cia402 { eds }, Profile::Cia402)
        }
    };
    let switches = Switches::from_cli(cli)?;
    if switches.any() && !matches!(can_device, CanDevice::Catalog(DeviceKind::Tlc5xx)) {
        return Err(format!(
            "{}: the {} simulator has no switches to place; they are options of --device tlc5xx",
            Switches::given(cli).join(" "),
            can_device.name()
        ));
    }
    if cli.eds.is_some() && !matches!(can_device, CanDevice::Cia402 { .. }) {
        return Err(
            "--eds FILE describes a generic drive: give it with --device cia402 (the other \
             devices' dictionaries are their simulators')"
                .into(),
        );
    }
    if let Some(iface) = &cli.ethercat {
        if device != DeviceArg::Emca {
            return Err(format!(
                "--ethercat {iface}: the EMCA is the EtherCAT drive simulated here (--device \
                 emca); the {} is not offered on EtherCAT",
                can_device.name()
            ));
        }
        if iface.is_empty() {
            return Err("--ethercat: give the network interface's name (e.g. a veth end)".into());
        }
        if cli.bus.is_some() || !cli.nodes.is_empty() || cli.modbus.is_some() {
            return Err(format!(
                "--ethercat {iface} with --bus, --node or --modbus: the EMCA is either an \
                 EtherCAT subdevice or a CANopen node; start one drive-sim for each"
            ));
        }
        // A physical interface has a device behind it; a veth end, a bridge or loopback not.
        if Path::new("/sys/class/net")
            .join(iface)
            .join("device")
            .exists()
        {
            return Err(format!(
                "--ethercat {iface}: a physical network interface; drive-sim answers only on a \
                 virtual one (a veth end in a network namespace): a simulated drive on a real \
                 EtherCAT line would answer for a real device"
            ));
        }
        return Ok(Plan {
            ethercat: Some(EcSpec {
                iface: iface.clone(),
                count: cli.count.unwrap_or(1),
                revision: cli.revision,
            }),
            ..Plan::default()
        });
    }
    if let Some(n) = cli.count {
        return Err(format!(
            "--count {n}: the number of EMCA subdevices in an EtherCAT segment; give it with \
             --ethercat IFACE"
        ));
    }
    if let Some(r) = cli.revision {
        return Err(format!(
            "--revision {r:#010x}: the revision of EMCA EtherCAT subdevices; give it with \
             --ethercat IFACE"
        ));
    }
    if let CanDevice::Catalog(kind) = can_device
        && kind.is_modbus()
    {
        let addr = cli
            .modbus
            .ok_or("the CMMO-ST speaks Modbus TCP: give --modbus ADDR")?;
        return Ok(Plan {
            modbus: vec![ModbusSpec {
                axis: None,
                text: addr.to_string(),
                addr,
            }],
            ..Plan::default()
        });
    }
    let bus = cli.bus.as_deref().ok_or(if device == DeviceArg::Emca {
        "give --bus vbus:NAME (CANopen) or --ethercat IFACE (EtherCAT)"
    } else {
        "give --bus vbus:NAME"
    })?;
    let name = match bus.strip_prefix("vbus:") {
        Some(n) if !n.is_empty() => n,
        _ => {
            return Err(format!(
                "--bus {bus}: drive-sim runs on the shared-memory virtual bus, name it vbus:NAME \
                 (SocketCAN is not offered: a simulated drive on a real bus would answer for a \
                 real device)"
            ));
        }
    };
    if cli.nodes.is_empty() {
        return Err("give at least one --node".into());
    }
    let mut seen = HashSet::new();
    let mut can = Vec::new();
    for &n in &cli.nodes {
        if !seen.insert(n) {
            return Err(format!(
                "--node {n} is given twice: two drives with one node-ID would both answer its \
                 frames"
            ));
        }
        let node = NodeId::new(n).ok_or(format!("--node {n}: not a node-ID (1..=127)"))?;
        can.push(CanSpec {
            axis: None,
            device: can_device.clone(),
            profile,
            node,
            bus: name.to_owned(),
            bitrate: cli.bitrate,
            switches,
        });
    }
    Ok(Plan {
        can,
        ..Plan::default()
    })
}

fn read_config(file: &Path) -> Result<Config, String> {
    let text = std::fs::read_to_string(file).map_err(|e| format!("{}: {e}", file.display()))?;
    let mut config = Config::parse(&text).map_err(|e| format!("{}: {e}", file.display()))?;
    let dir = file.parent().unwrap_or(Path::new("."));
    let eds_errors = config.load_eds(dir);
    let mut report = config.check();
    report.errors.extend(eds_errors);
    if !report.is_ok() {
        // Every refusal, as `coordinator check` prints them.
        for e in &report.errors {
            eprintln!("error: {e}");
        }
        return Err(format!(
            "{}: refused: {} error(s) (`coordinator check {}` says the same)",
            file.display(),
            report.errors.len(),
            file.display()
        ));
    }
    Ok(config)
}

/// The plan of `--config FILE [--only AXIS]...`: the drives the coordinator dials. Says on
/// stderr which axes are skipped and why.
fn plan_from_config(file: &Path, only: &[String]) -> Result<Plan, String> {
    let config = read_config(file)?;
    for name in only {
        if !config.axes.iter().any(|a| &a.name == name) {
            let names: Vec<&str> = config.axes.iter().map(|a| a.name.as_str()).collect();
            return Err(format!(
                "--only {name}: {} has no axis of that name; its axes: {}",
                file.display(),
                if names.is_empty() {
                    "none".to_owned()
                } else {
                    names.join(", ")
                }
            ));
        }
    }
    let mut plan = Plan::default();
    let mut consumer_buses = Vec::new();
    for (i, a) in config.axes.iter().enumerate() {
        if !only.is_empty() && !only.contains(&a.name) {
            continue;
        }
        let device = device_name(a.device);
        let key = format!("axes[{i}]");
        if a.device.is_modbus() {
            let Some(text) = a.modbus.as_ref().filter(|_| !a.simulated) else {
                eprintln!(
                    "drive-sim: {}: {device} skipped: simulated = true, the coordinator simulates \
                     it itself",
                    a.name
                );
                continue;
            };
            let addr = text
                .to_socket_addrs()
                .map_err(|e| format!("{key}.modbus = \"{text}\" (axis {}): {e}", a.name))?
                .next()
                .ok_or_else(|| {
                    format!(
                        "{key}.modbus = \"{text}\" (axis {}): the name has no address",
                        a.name
                    )
                })?;
            plan.modbus.push(ModbusSpec {
                axis: Some(a.name.clone()),
                text: text.clone(),
                addr,
            });
            continue;
        }
        // `check` accepted the file: a CANopen axis names an existing bus and a valid node.
        let bus_name = a.bus.as_deref().unwrap_or_default();
        let Some(bus) = config.buses.iter().find(|b| b.name == bus_name) else {
            return Err(format!("{key}.bus: no bus \"{bus_name}\""));
        };
        match bus.kind {
            BusKind::Vbus => {}
            BusKind::Simulated | BusKind::Virtual => {
                eprintln!(
                    "drive-sim: {}: {device} skipped: bus {} is kind = \"simulated\", the \
                     coordinator simulates its drives itself",
                    a.name, bus.name
                );
                continue;
            }
            BusKind::Socketcan => {
                eprintln!(
                    "drive-sim: {}: {device} skipped: bus {} is kind = \"socketcan\", a real bus; \
                     drive-sim does not answer there (it would answer for the real drive)",
                    a.name, bus.name
                );
                continue;
            }
            BusKind::Ethercat => {
                eprintln!(
                    "drive-sim: {}: {device} skipped: bus {} is kind = \"ethercat\" on the \
                     coordinator's interface {}; simulate its segment with `drive-sim --device \
                     emca --ethercat PEER --count N` on the other end of the link",
                    a.name,
                    bus.name,
                    bus.interface()
                );
                continue;
            }
        }
        let node = a
            .node
            .and_then(|n| u8::try_from(n).ok())
            .and_then(NodeId::new)
            .ok_or_else(|| format!("{key}.node: not a node-ID"))?;
        if bus.sync == SyncMode::Consumer && !consumer_buses.contains(&bus.name) {
            consumer_buses.push(bus.name.clone());
        }
        let device = match a.device {
            // The drive the coordinator expects: the configuration's EDS, as it reads it.
            DeviceKind::Cia402 => CanDevice::Cia402 {
                eds: a
                    .eds
                    .as_ref()
                    .map(|f| file.parent().unwrap_or(Path::new(".")).join(f)),
            },
            kind => CanDevice::Catalog(kind),
        };
        plan.can.push(CanSpec {
            axis: Some(a.name.clone()),
            device,
            profile: a.profile(),
            node,
            bus: bus.name.clone(),
            bitrate: bus.bitrate,
            switches: Switches::default(),
        });
    }
    for b in consumer_buses {
        eprintln!(
            "drive-sim: bus {b} has sync = \"consumer\": the coordinator follows another node's \
             SYNC there, which drive-sim does not produce"
        );
    }
    if plan.can.is_empty() && plan.modbus.is_empty() {
        return Err(format!(
            "{}: nothing to start: {} (drive-sim starts the axes on buses of kind \"vbus\" and \
             the CMMO-STs with a modbus address)",
            file.display(),
            if only.is_empty() {
                "no axis is one the coordinator dials"
            } else {
                "no axis named by --only is one the coordinator dials"
            }
        ));
    }
    Ok(plan)
}

/// A simulated CANopen drive with a one-line status.
trait SimDrive: Endpoint {
    /// NMT and drive state, position, fault: for people.
    fn status(&self) -> String;
    /// The CiA 306 EDS of the drive's object dictionary as it is now.
    fn eds(&self, node: NodeId, info: &DeviceInfo<'_>) -> String;
}

impl SimDrive for Tlc5xx {
    fn status(&self) -> String {
        // The switches that are on, as the manual names its inputs.
        let on = self.axis().status().switches;
        let switches: Vec<&str> = [
            (Inputs::LIMIT_NEGATIVE, "LIMN"),
            (Inputs::LIMIT_POSITIVE, "LIMP"),
            (Inputs::REFERENCE, "REF"),
        ]
        .into_iter()
        .filter(|(s, _)| on.contains(*s))
        .map(|(_, name)| name)
        .collect();
        format!(
            "NMT {} | {} (statusword {:04X}h) | pos {} usr{}",
            self.nmt_state().name(),
            self.drive_state().name(),
            self.statusword(),
            self.actual_usr(),
            if switches.is_empty() {
                String::new()
            } else {
                format!(" | {} on", switches.join(" "))
            }
        )
    }
    fn eds(&self, node: NodeId, info: &DeviceInfo<'_>) -> String {
        write_eds(self.od(), node, info)
    }
}

/// An FHPP drive's state as the manuals write it: "S4 Operation enabled (Ready)".
fn fhpp_state(d: &FhppDrive) -> String {
    let s = d.machine().state;
    match s {
        FhppState::OperationEnabled(sub) => format!("S4 {} ({})", s.name(), sub.name()),
        _ => format!("S{} {}", s.number(), s.name()),
    }
}

/// The drive state, position and fault of a Festo drive. The MTR-DCI manual numbers its faults
/// in decimal, the EMCA and CMMO-ST manuals in hex.
fn festo_status(d: &FhppDrive, kind: DeviceKind) -> String {
    let fault = match d.fault_number() {
        None => "none".to_owned(),
        Some(n) if kind == DeviceKind::MtrDci => n.to_string(),
        Some(n) => format!("{n:02X}h"),
    };
    let i = d.input();
    format!(
        "{} | SCON {:02X}h SPOS {:02X}h | {} | pos {} inc | fault {fault}",
        fhpp_state(d),
        i[0],
        i[1],
        if d.is_referenced() {
            "referenced"
        } else {
            "not referenced"
        },
        d.axis().status().position
    )
}

fn festo_node_status(node: &FestoNode, kind: DeviceKind) -> String {
    let nmt = node.device().state().name();
    match node.cia402_state() {
        // The CiA 402 face: its state, with the FHPP core's position and fault.
        Some(s) => {
            let d = node.drive();
            let fault = d
                .fault_number()
                .map_or_else(|| "none".to_owned(), |n| n.to_string());
            format!(
                "NMT {nmt} | CiA 402 {} | pos {} inc | fault {fault}",
                s.name(),
                d.axis().status().position
            )
        }
        None => format!("NMT {nmt} | {}", festo_status(node.drive(), kind)),
    }
}

impl SimDrive for MtrDci {
    fn status(&self) -> String {
        festo_node_status(self, DeviceKind::MtrDci)
    }
    fn eds(&self, node: NodeId, info: &DeviceInfo<'_>) -> String {
        write_eds(self.device().od(), node, info)
    }
}

impl SimDrive for Emca {
    fn status(&self) -> String {
        festo_node_status(self, DeviceKind::Emca)
    }
    fn eds(&self, node: NodeId, info: &DeviceInfo<'_>) -> String {
        write_eds(self.device().od(), node, info)
    }
}

impl SimDrive for Cia402Drive {
    fn status(&self) -> String {
        let faults: Vec<String> = self
            .faults()
            .iter()
            .map(|f| format!("{:04X}h", f.emcy_code()))
            .collect();
        format!(
            "NMT {} | {} (statusword {:04X}h) | mode {} | pos {} inc | fault {}",
            self.nmt_state().name(),
            self.drive_state().name(),
            self.statusword(),
            self.mode().code(),
            self.actual(),
            if faults.is_empty() {
                "none".to_owned()
            } else {
                faults.join(" ")
            }
        )
    }
    fn eds(&self, node: NodeId, info: &DeviceInfo<'_>) -> String {
        write_eds(self.od(), node, info)
    }
}

/// The generic CiA 402 drive at `node`: the built-in dictionary, or `eds`'s. The parsed file
/// lives as long as the process (the dictionary borrows its names).
/// SYNC periods without a SYNC before a generic drive in drive-sim faults with 8700h.
const DRIVE_SIM_SYNC_LOSS_PERIODS: u32 = 10;

fn build_cia402(
    node: NodeId,
    eds: Option<&Path>,
    now: Instant,
) -> Result<Box<dyn SimDrive>, String> {
    // A drive in a process on a shared host is not firmware: its loop and the coordinator's
    // both pause now and then (the coordinator reports its own overruns). It faults after 10
    // missing SYNC periods rather than the in-process simulator's 3, so that a pause of a few
    // milliseconds is not taken for a lost master.
    let cfg = Cia402Config {
        sync_loss_periods: DRIVE_SIM_SYNC_LOSS_PERIODS,
        ..Cia402Config::new(node)
    };
    let Some(file) = eds else {
        return Cia402Drive::new(cfg, now)
            .map(|d| Box::new(d) as Box<dyn SimDrive>)
            .map_err(|e| e.to_string());
    };
    let text = std::fs::read_to_string(file).map_err(|e| format!("{}: {e}", file.display()))?;
    let parsed = drivers::canopen::eds::Eds::parse(&text, Some(node))
        .map_err(|e| format!("{}: {e}", file.display()))?;
    let parsed: &'static drivers::canopen::eds::Eds = Box::leak(Box::new(parsed));
    Cia402Drive::from_eds(cfg, parsed, now)
        .map(|d| Box::new(d) as Box<dyn SimDrive>)
        .map_err(|e| format!("{}: {e}", file.display()))
}

fn build_can_drive(spec: &CanSpec, now: Instant) -> Result<Box<dyn SimDrive>, String> {
    let err = |e: &dyn std::fmt::Display| e.to_string();
    let kind = match &spec.device {
        CanDevice::Catalog(kind) => *kind,
        CanDevice::Cia402 { eds } => return build_cia402(spec.node, eds.as_deref(), now),
    };
    match (kind, spec.profile) {
        (DeviceKind::Tlc5xx, _) => {
            let mut cfg = TlcConfig::new(spec.node);
            let sw = spec.switches;
            let env = &mut cfg.environment;
            env.limit_negative = sw.limit_negative.map(SwitchZone::below);
            env.limit_positive = sw.limit_positive.map(SwitchZone::above);
            env.reference = sw.reference.map(|(from, to)| SwitchZone::cam(from, to));
            Tlc5xx::new(cfg, now)
                .map(|d| Box::new(d) as Box<dyn SimDrive>)
                .map_err(|e| err(&e))
        }
        (DeviceKind::MtrDci, p) => {
            let p = match p {
                Profile::Fhpp => MtrProfile::Fhpp,
                Profile::Cia402 => MtrProfile::Cia402,
            };
            MtrDci::new(spec.node, p, now)
                .map(|d| Box::new(d) as Box<dyn SimDrive>)
                .map_err(|e| err(&e))
        }
        (DeviceKind::Emca, Profile::Fhpp) => Emca::new(spec.node, now)
            .map(|d| Box::new(d) as Box<dyn SimDrive>)
            .map_err(|e| err(&e)),
        (kind, profile) => Err(format!(
            "the {} simulator has no {} profile",
            device_name(kind),
            profile_name(profile)
        )),
    }
}

/// A running CANopen drive.
struct CanRun {
    spec: CanSpec,
    station: Station<ShmBus, Box<dyn SimDrive>>,
}

/// A running CMMO-ST.
struct ModbusRun {
    spec: ModbusSpec,
    device: Arc<Mutex<FhppDrive>>,
    server: Server,
}

fn start_can(spec: &CanSpec, now: Instant) -> Result<CanRun, String> {
    let what = format!(
        "{}{} node {} on vbus:{}",
        prefix(&spec.axis),
        spec.device.name(),
        spec.node.get(),
        spec.bus
    );
    let bus = ShmBus::open(&spec.bus, spec.bitrate).map_err(|e| format!("{what}: {e}"))?;
    let drive = build_can_drive(spec, now).map_err(|e| format!("{what}: {e}"))?;
    eprintln!(
        "drive-sim: {what}, {}, at {} kbit/s",
        profile_name(spec.profile),
        spec.bitrate / 1000
    );
    Ok(CanRun {
        spec: spec.clone(),
        station: Station::new(bus, drive),
    })
}

fn start_modbus(spec: &ModbusSpec) -> Result<ModbusRun, String> {
    let what = format!("{}CMMO-ST on {}", prefix(&spec.axis), spec.text);
    let drive = cmmo_st::drive::commissioned().map_err(|e| format!("{what}: {e}"))?;
    let device = Arc::new(Mutex::new(drive));
    let config = ServerConfig {
        addr: spec.addr,
        ..ServerConfig::loopback(0)
    };
    let server = Server::spawn(config, device.clone()).map_err(|e| format!("{what}: {e}"))?;
    eprintln!(
        "drive-sim: {}CMMO-ST serving Modbus TCP on {}",
        prefix(&spec.axis),
        server.local_addr()
    );
    Ok(ModbusRun {
        spec: spec.clone(),
        device,
        server,
    })
}

fn can_status(r: &CanRun) -> String {
    format!(
        "{}{} node {} on vbus:{} | {}",
        prefix(&r.spec.axis),
        r.spec.device.name(),
        r.spec.node.get(),
        r.spec.bus,
        r.station.endpoint.status()
    )
}

fn modbus_status(r: &ModbusRun) -> String {
    let state = r
        .device
        .lock()
        .map(|d| festo_status(&d, DeviceKind::CmmoSt))
        .unwrap_or_else(|_| "the simulator stopped".to_owned());
    format!(
        "{}CMMO-ST on {} | client {} | {state}",
        prefix(&r.spec.axis),
        r.server.local_addr(),
        if r.server.is_connected() {
            "connected"
        } else {
            "none"
        }
    )
}

/// What the EtherCAT thread shares with the main loop.
#[derive(Debug, Default)]
struct EcShared {
    /// One status line per subdevice, refreshed every 100 ms.
    lines: Vec<String>,
    /// Frames answered.
    frames: u64,
    /// Frames of EtherType 88A4h that were not datagrams a subdevice can process.
    bad: u64,
    /// The error that ended the thread.
    error: Option<String>,
}

/// A running EtherCAT segment: its thread and what it shares.
struct EcRun {
    spec: EcSpec,
    stop: Arc<AtomicBool>,
    shared: Arc<Mutex<EcShared>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// How often the EtherCAT thread refreshes its status lines.
const EC_SNAPSHOT: Duration = Duration::from_millis(100);
/// The longest wait for a frame before the subdevices' clocks are advanced anyway.
const EC_POLL: Duration = Duration::from_millis(1);

fn ec_status(i: usize, d: &EmcaEc) -> String {
    let al = match d.error() {
        Some(code) => format!(
            "{}, error {:04X}h ({})",
            d.state(),
            code.0,
            code.description()
        ),
        None => d.state().to_string(),
    };
    format!(
        "EMCA-EC {} (station {:04X}h) | {al} | {}",
        i + 1,
        d.station_address(),
        festo_status(d.drive(), DeviceKind::Emca)
    )
}

/// A switch the operator throws on one subdevice.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Switch {
    /// Its whole power (the ESC too): on or off.
    Power(bool),
    /// The drive's load voltage: on (restored) or off (dropped: fault, emergency).
    Supply(bool),
}

/// The operator's switches for a segment, read from standard input: `off N` switches
/// subdevice N (1 first) off, as pulling its supply would (the line ends there); `on N` switches
/// it on again, a fresh drive in Init; `drop N` drops its load voltage (the drive faults and
/// sends an emergency), `restore N` restores it. A line that is none of these is answered on
/// standard error; the end of the input ends the reading, nothing else.
fn power_commands(count: u8) -> std::sync::mpsc::Receiver<(usize, Switch)> {
    let (tx, rx) = std::sync::mpsc::channel();
    let _ = std::thread::Builder::new()
        .name("power".into())
        .spawn(move || {
            for line in std::io::stdin().lines() {
                let Ok(line) = line else { break };
                let words: Vec<&str> = line.split_whitespace().collect();
                let parsed = match words.as_slice() {
                    [w @ ("on" | "off" | "drop" | "restore"), n] => n
                        .parse::<u8>()
                        .ok()
                        .filter(|n| (1..=count).contains(n))
                        .map(|n| {
                            let s = match *w {
                                "on" => Switch::Power(true),
                                "off" => Switch::Power(false),
                                "restore" => Switch::Supply(true),
                                _ => Switch::Supply(false),
                            };
                            (usize::from(n - 1), s)
                        }),
                    [] => continue,
                    _ => None,
                };
                match parsed {
                    Some(cmd) => {
                        if tx.send(cmd).is_err() {
                            break;
                        }
                    }
                    None => eprintln!(
                        "drive-sim: \"{line}\": give `off N`, `on N`, `drop N` or `restore N` with N a subdevice 1 to {count}"
                    ),
                }
            }
        });
    rx
}

/// Opens the interface and starts the segment's thread: every frame through the subdevices and
/// back; without frames, the drives' clocks still advance every millisecond.
fn start_ethercat(spec: &EcSpec, now: Instant) -> Result<EcRun, String> {
    let sock =
        RawSocket::open(&spec.iface).map_err(|e| format!("--ethercat {}: {e}", spec.iface))?;
    let mut subs = Vec::new();
    for i in 0..spec.count {
        let revision = spec
            .revision
            .unwrap_or(drivers::catalog::EMCA_ETHERCAT.revision);
        let d = EmcaEc::with_revision(EmcaEc::drive_config(), i + 1 < spec.count, now, revision)
            .map_err(|e| format!("EMCA-EC {}: {e}", i + 1))?;
        subs.push(d);
    }
    eprintln!(
        "drive-sim: {} EMCA-EC subdevice(s) on EtherCAT interface {}",
        spec.count, spec.iface
    );
    let stop = Arc::new(AtomicBool::new(false));
    let shared = Arc::new(Mutex::new(EcShared::default()));
    let (stop2, shared2) = (stop.clone(), shared.clone());
    let power = power_commands(spec.count);
    let thread = std::thread::Builder::new()
        .name("ethercat".into())
        .spawn(move || {
            let mut buf = [0u8; MAX_FRAME_LEN];
            let mut next_snapshot = monotonic_now();
            let (mut frames, mut bad) = (0u64, 0u64);
            let mut error = None;
            while !stop2.load(Ordering::Relaxed) {
                while let Ok((i, cmd)) = power.try_recv() {
                    let Some(d) = subs.get_mut(i) else { continue };
                    if let Switch::Supply(on) = cmd {
                        d.drive_mut()
                            .inject(drivers::sim::fhpp_drive::Injection::SupplyDrop, !on);
                        eprintln!(
                            "drive-sim: EMCA-EC {}: load voltage {}",
                            i + 1,
                            if on { "restored" } else { "dropped" }
                        );
                        continue;
                    }
                    let on = cmd == Switch::Power(true);
                    if on {
                        if let Err(e) = d.power_on(monotonic_now()) {
                            eprintln!("drive-sim: EMCA-EC {}: cannot switch on: {e}", i + 1);
                            continue;
                        }
                    } else {
                        d.power_off();
                    }
                    eprintln!(
                        "drive-sim: EMCA-EC {} switched {}",
                        i + 1,
                        if on { "on" } else { "off" }
                    );
                }
                match sock.recv(&mut buf, EC_POLL) {
                    Ok(Some(n)) => match segment::pass(&mut buf[..n], &mut subs, monotonic_now()) {
                        Ok(()) => {
                            if let Err(e) = sock.send(&buf[..n]) {
                                error = Some(format!("sending on {}: {e}", sock.interface()));
                                break;
                            }
                            frames += 1;
                        }
                        Err(_) => bad += 1,
                    },
                    Ok(None) => {
                        let now = monotonic_now();
                        for s in subs.iter_mut() {
                            drivers::ethercat::segment::Subdevice::poll(s, now);
                        }
                    }
                    Err(e) => {
                        error = Some(format!("receiving on {}: {e}", sock.interface()));
                        break;
                    }
                }
                let now = monotonic_now();
                if now >= next_snapshot {
                    next_snapshot = now + EC_SNAPSHOT;
                    let lines: Vec<String> = subs
                        .iter()
                        .enumerate()
                        .map(|(i, d)| ec_status(i, d))
                        .collect();
                    if let Ok(mut sh) = shared2.lock() {
                        sh.lines = lines;
                        sh.frames = frames;
                        sh.bad = bad;
                    }
                }
            }
            if let Ok(mut sh) = shared2.lock() {
                sh.frames = frames;
                sh.bad = bad;
                sh.error = error;
            }
        })
        .map_err(|e| format!("starting the EtherCAT thread: {e}"))?;
    Ok(EcRun {
        spec: spec.clone(),
        stop,
        shared,
        thread: Some(thread),
    })
}

impl EcRun {
    /// The error that ended the thread, if it ended.
    fn failed(&self) -> Option<String> {
        self.shared.lock().ok().and_then(|s| s.error.clone())
    }

    /// Stops the thread; returns the counts, or the error that ended it.
    fn finish(mut self) -> Result<(u64, u64), String> {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let sh = self
            .shared
            .lock()
            .map_err(|_| "the EtherCAT thread panicked".to_owned())?;
        match &sh.error {
            Some(e) => Err(format!("EtherCAT on {}: {e}", self.spec.iface)),
            None => Ok((sh.frames, sh.bad)),
        }
    }
}

fn sleep_until(t: Instant) {
    let now = monotonic_now();
    if t > now {
        std::thread::sleep(t - now);
    }
}

/// A pause of the drive loop this long is reported: three 2 ms cycles without a TPDO fault
/// an axis.
const LONG_PAUSE: Duration = Duration::from_millis(5);

/// Starts every drive of `plan` and runs them until the stop flag, or `duration`.
fn run(plan: &Plan, duration: Option<Duration>, every: Option<Duration>) -> Result<(), String> {
    let stop = coordinator::runtime::signals::stop_flag();
    let start = monotonic_now();
    // The bus endpoints on the normal scheduler: opening one takes milliseconds of CPU (debug
    // build), which at SCHED_FIFO would keep drives of other processes off the CPU.
    let mut stations = Vec::new();
    for c in &plan.can {
        stations.push(start_can(c, start)?);
    }
    // Simulated drives stand for hardware, which never waits for this machine's other
    // processes: run just below the coordinator's cycle thread (SCHED_FIFO 80), as the
    // in-process simulators do. Where real-time scheduling is refused, say so: a loaded machine
    // can then starve the drives into late TPDOs.
    let rt = coordinator::runtime::realtime_thread::enter_realtime(
        &coordinator::runtime::realtime_thread::RealtimeSettings {
            priority: Some(70),
            cpu: None,
            lock_memory: false,
        },
    );
    for w in &rt.warnings {
        eprintln!("drive-sim: warning: {w}");
    }
    // The CMMO-ST servers after that, so that their threads inherit the priority: on the
    // normal scheduler a server waits behind every real-time thread of its CPU (once seen
    // runnable for 42 ms, near the coordinator's 50 ms Modbus timeout). A port already taken
    // fails here, after the CAN drives have joined their buses; they leave them again as the
    // process ends.
    let mut servers = Vec::new();
    for m in &plan.modbus {
        match start_modbus(m) {
            Ok(s) => servers.push(s),
            Err(e) => {
                coordinator::runtime::realtime_thread::leave_realtime();
                return Err(e);
            }
        }
    }
    // The EtherCAT segment's thread too: it inherits the priority.
    let ec = match plan
        .ethercat
        .as_ref()
        .map(|s| start_ethercat(s, monotonic_now()))
    {
        None => None,
        Some(Ok(r)) => Some(r),
        Some(Err(e)) => {
            coordinator::runtime::realtime_thread::leave_realtime();
            return Err(e);
        }
    };
    let ec_drives = plan.ethercat.as_ref().map_or(0, |s| usize::from(s.count));
    eprintln!(
        "drive-sim: {} drive(s) running; Ctrl-C to stop",
        stations.len() + servers.len() + ec_drives
    );
    let end = duration.map(|d| start + d);
    let mut next_status = every.map(|e| start + e);
    let poll = if stations.is_empty() {
        IDLE_POLL
    } else {
        CAN_POLL
    };
    // The longest time between two passes of the drive loop: a simulator starved by its host
    // answers late, which the coordinator rightly faults; this says whether that happened.
    // From here: joining the buses above takes a while and is not a pause of running drives.
    let mut last_pass = monotonic_now();
    let mut longest_pause = Duration::ZERO;
    while !stop.load(Ordering::Relaxed) {
        for s in stations.iter_mut() {
            s.station.step();
        }
        let now = monotonic_now();
        let pause = now.saturating_duration_since(last_pass);
        longest_pause = longest_pause.max(pause);
        last_pass = now;
        if pause >= LONG_PAUSE && !stations.is_empty() {
            eprintln!(
                "drive-sim: the drive loop paused {:.1} ms at {:.3} s (the host did not run it): \
                 TPDOs and heartbeats were late",
                pause.as_secs_f64() * 1000.0,
                (now - start).as_secs_f64()
            );
        }
        if end.is_some_and(|e| now >= e) {
            break;
        }
        if ec.as_ref().and_then(EcRun::failed).is_some() {
            break;
        }
        if let (Some(t), Some(e)) = (next_status, every)
            && now >= t
        {
            for s in &stations {
                eprintln!("{}", can_status(s));
            }
            for m in &servers {
                eprintln!("{}", modbus_status(m));
            }
            if let Some(r) = &ec
                && let Ok(sh) = r.shared.lock()
            {
                for l in &sh.lines {
                    eprintln!("{l}");
                }
            }
            // From now, not from `t`: a stalled process prints one line, not a burst.
            next_status = Some(now + e);
        }
        let mut wake = now + poll;
        for s in &stations {
            if let Some(t) = s.station.next_deadline() {
                wake = wake.min(t);
            }
        }
        if let Some(t) = end {
            wake = wake.min(t);
        }
        sleep_until(wake);
    }
    // Closing the bus endpoints is no drive work: not at SCHED_FIFO, where it would keep other
    // processes' drives (same priority, no time slicing) off this CPU for milliseconds.
    coordinator::runtime::realtime_thread::leave_realtime();
    let ran = monotonic_now() - start;
    if !stations.is_empty() {
        let errors: u64 = stations.iter().map(|s| s.station.errors()).sum();
        let sent: u64 = stations.iter().map(|s| s.station.bus.counters().sent).sum();
        let received: u64 = stations
            .iter()
            .map(|s| s.station.bus.counters().received)
            .sum();
        eprintln!("drive-sim: CAN: {sent} frames sent, {received} received, {errors} bus errors");
    }
    if let Some(r) = ec {
        let iface = r.spec.iface.clone();
        let (frames, bad) = r.finish()?;
        eprintln!(
            "drive-sim: EtherCAT on {iface}: {frames} frames answered, {bad} not processed \
             (not datagrams)"
        );
    }
    for m in servers {
        let prefix = prefix(&m.spec.axis);
        let s = m.server.shutdown();
        eprintln!(
            "drive-sim: {prefix}CMMO-ST: {} connection(s) ({} refused), {} answers, {} \
             exceptions, {} dropped frames, {} node-guard timeouts",
            s.connections, s.refused, s.responses, s.exceptions, s.dropped, s.timeouts
        );
    }
    eprintln!(
        "drive-sim: stopped after {:.1} s; the drive loop's longest pause {:.1} ms",
        ran.as_secs_f64(),
        longest_pause.as_secs_f64() * 1000.0
    );
    Ok(())
}

/// `--write-eds DEVICE`: the EDS of a freshly built simulator of that device.
fn eds_of(device: DeviceArg, profile: Option<ProfileArg>) -> Result<String, String> {
    let (can_device, facts, profile) = match device.kind() {
        Some(kind) => {
            let facts = kind.device();
            if kind.is_modbus() {
                return Err(format!(
                    "--write-eds {}: the {} speaks Modbus TCP, not CANopen; it has no EDS",
                    facts.id, facts.name
                ));
            }
            (
                CanDevice::Catalog(kind),
                facts,
                chosen_profile(kind, profile)?,
            )
        }
        None => (
            CanDevice::Cia402 { eds: None },
            &drivers::catalog::CIA402_GENERIC,
            Profile::Cia402,
        ),
    };
    // Built at node 1; the writer gives the COB-IDs relative to $NODEID.
    let node = NodeId::new(1).ok_or("node 1")?;
    let spec = CanSpec {
        axis: None,
        device: can_device,
        profile,
        node,
        bus: String::new(),
        bitrate: 1_000_000,
        switches: Switches::default(),
    };
    let drive = build_can_drive(&spec, Instant::ZERO)?;
    let file_name = format!(
        "{}-{}.eds",
        facts.id,
        profile_name(profile).to_lowercase().replace(' ', "")
    );
    let description = format!(
        "{} {} ({}), as the motion coordinator's simulator models it",
        facts.vendor,
        facts.name,
        profile_name(profile)
    );
    let info = DeviceInfo {
        file_name: &file_name,
        description: &description,
        vendor_name: facts.vendor,
        product_name: facts.name,
        baud_rates_kbit: facts.can_bitrates_kbit,
        lss: false,
        created_by: concat!("drive-sim ", env!("CARGO_PKG_VERSION")),
    };
    Ok(drive.eds(node, &info))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if let Some(device) = cli.write_eds {
        return match eds_of(device, cli.profile) {
            Ok(text) => {
                // A closed pipe (`| head`) is the reader's choice, not an error.
                use std::io::Write as _;
                let _ = std::io::stdout().lock().write_all(text.as_bytes());
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("drive-sim: error: {e}");
                ExitCode::FAILURE
            }
        };
    }
    let result = timing(&cli).and_then(|(duration, every)| {
        let plan = match (&cli.config, cli.device) {
            (Some(_), _) if Switches::from_cli(&cli)?.any() => {
                return Err(format!(
                    "{}: the switches are options of --device tlc5xx; the drives of --config \
                     have none",
                    Switches::given(&cli).join(" ")
                ));
            }
            (Some(_), _) if cli.count.is_some() || cli.revision.is_some() => {
                let option = if cli.count.is_some() {
                    "--count"
                } else {
                    "--revision"
                };
                return Err(format!(
                    "{option}: give it with --device emca --ethercat IFACE; the drives of \
                     --config are CANopen and Modbus ones"
                ));
            }
            (Some(file), _) => plan_from_config(file, &cli.only)?,
            (None, Some(device)) => plan_from_args(&cli, device)?,
            (None, None) => return Err("give --config FILE or --device".into()),
        };
        run(&plan, duration, every)
    });
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("drive-sim: error: {e}");
            ExitCode::FAILURE
        }
    }
}
