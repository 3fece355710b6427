//! `drive-sim`: simulated drives as their own process, as real devices would be.
//!
//! ```text
//! drive-sim --device tlc5xx  --bus vbus:NAME --node 1 [--node 2 ...]
//! drive-sim --device mtr-dci --bus vbus:NAME --node 3 [--profile fhpp|cia402]
//! drive-sim --device emca    --bus vbus:NAME --node 4
//! drive-sim --device cmmo-st --modbus 127.0.0.1:PORT
//! ```
//!
//! CANopen drives run on the shared-memory virtual bus in real time (one bus endpoint per
//! drive); several `--node`s run several drives of the kind in this one process. The CMMO-ST
//! serves Modbus TCP. Ctrl-C (or `--duration`) ends the run; a status line per drive is printed
//! every `--status-every` seconds on stderr.

use std::net::SocketAddr;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use clap::{Parser, ValueEnum};
use drivers::can::Bus;
use drivers::can::shm_bus::ShmBus;
use drivers::can::station::Station;
use drivers::canopen::NodeId;
use drivers::canopen::endpoint::Endpoint;
use drivers::sim::cmmo_st::{self, ServerConfig};
use drivers::sim::emca::Emca;
use drivers::sim::mtr_dci::{FestoNode, MtrDci, Profile as MtrProfile};
use drivers::sim::tlc5xx::{Tlc5xx, TlcConfig};
use drivers::time::{Instant, monotonic_now};

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Device {
    /// Festo MTR-DCI (CANopen, FHPP or CiA 402).
    MtrDci,
    /// Festo EMCA (CANopen, FHPP + FPC).
    Emca,
    /// TLC5xx (CANopen DS301 / DSP402).
    Tlc5xx,
    /// Festo CMMO-ST (Modbus TCP, FHPP).
    CmmoSt,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum ProfileArg {
    /// Festo Handling and Positioning Profile.
    Fhpp,
    /// CiA 402 (MTR-DCI only).
    Cia402,
}

/// Simulated drives as their own process.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Cli {
    /// The device to simulate.
    #[arg(long, value_enum)]
    device: Device,
    /// The CAN bus: `vbus:NAME` (the shared-memory virtual bus).
    #[arg(long, required_if_eq_any([("device", "mtr-dci"), ("device", "emca"), ("device", "tlc5xx")]))]
    bus: Option<String>,
    /// Node-ID(s), 1..=127; one drive per `--node`.
    #[arg(long = "node", num_args = 1.., value_parser = clap::value_parser!(u8).range(1..=127))]
    nodes: Vec<u8>,
    /// Bus bitrate, bit/s.
    #[arg(long, default_value_t = 1_000_000)]
    bitrate: u32,
    /// The MTR-DCI's profile.
    #[arg(long, value_enum, default_value_t = ProfileArg::Fhpp)]
    profile: ProfileArg,
    /// Modbus TCP address to serve (CMMO-ST), e.g. 127.0.0.1:1502.
    #[arg(long, required_if_eq("device", "cmmo-st"))]
    modbus: Option<SocketAddr>,
    /// End after this many seconds (default: run until Ctrl-C).
    #[arg(long)]
    duration: Option<f64>,
    /// Print a status line this often, in seconds (0 = never).
    #[arg(long, default_value_t = 1.0)]
    status_every: f64,
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

fn install_signal_handlers() {
    let handler: extern "C" fn(libc::c_int) = on_signal;
    // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
    unsafe {
        libc::signal(libc::SIGINT, handler as libc::sighandler_t);
        libc::signal(libc::SIGTERM, handler as libc::sighandler_t);
    }
}

fn sleep_until(t: Instant) {
    let now = monotonic_now();
    if t > now {
        std::thread::sleep(t - now);
    }
}

/// A simulated CANopen drive with a one-line status.
trait SimDrive: Endpoint {
    fn status_line(&self) -> String;
}

impl SimDrive for Tlc5xx {
    fn status_line(&self) -> String {
        format!(
            "node {:3} TLC5xx  NMT {:?} {:?} sw {:04X}h pos {} usr",
            self.node().get(),
            self.nmt_state(),
            self.drive_state(),
            self.statusword(),
            self.actual_usr()
        )
    }
}

/// The FHPP status line shared by the two Festo CANopen drives.
fn festo_line(kind: &str, node: &FestoNode) -> String {
    let d = node.drive();
    let i = d.input();
    let state = match node.cia402_state() {
        Some(s) => format!("CiA 402 {s:?}"),
        None => format!("SCON {:02X}h SPOS {:02X}h", i[0], i[1]),
    };
    let fault = d
        .fault_number()
        .map_or_else(|| "-".into(), |n| n.to_string());
    format!(
        "node {:3} {kind:7} NMT {:?} {state} pos {} inc fault {fault}",
        node.device().node().get(),
        node.device().state(),
        d.axis().status().position
    )
}

impl SimDrive for MtrDci {
    fn status_line(&self) -> String {
        festo_line("MTR-DCI", self)
    }
}

impl SimDrive for Emca {
    fn status_line(&self) -> String {
        festo_line("EMCA", self)
    }
}

fn build_can_drive(
    device: Device,
    node: NodeId,
    profile: ProfileArg,
    now: Instant,
) -> Result<Box<dyn SimDrive>, String> {
    if profile == ProfileArg::Cia402 && device != Device::MtrDci {
        return Err(format!(
            "--profile cia402 is the MTR-DCI's alternative profile, not the {device:?}'s"
        ));
    }
    match device {
        Device::Tlc5xx => Tlc5xx::new(TlcConfig::new(node), now)
            .map(|d| Box::new(d) as Box<dyn SimDrive>)
            .map_err(|e| e.to_string()),
        Device::MtrDci => {
            let p = if profile == ProfileArg::Cia402 {
                MtrProfile::Cia402
            } else {
                MtrProfile::Fhpp
            };
            MtrDci::new(node, p, now)
                .map(|d| Box::new(d) as Box<dyn SimDrive>)
                .map_err(|e| e.to_string())
        }
        Device::Emca => Emca::new(node, now)
            .map(|d| Box::new(d) as Box<dyn SimDrive>)
            .map_err(|e| e.to_string()),
        Device::CmmoSt => Err("the CMMO-ST speaks Modbus TCP: use --modbus ADDR".into()),
    }
}

fn run_can(cli: &Cli, name: &str) -> Result<(), String> {
    if cli.nodes.is_empty() {
        return Err("give at least one --node".into());
    }
    let now = monotonic_now();
    let mut stations = Vec::new();
    for &n in &cli.nodes {
        let node = NodeId::new(n).ok_or(format!("invalid node-ID {n}"))?;
        let bus = ShmBus::open(name, cli.bitrate).map_err(|e| e.to_string())?;
        let drive = build_can_drive(cli.device, node, cli.profile, now)?;
        stations.push(Station::new(bus, drive));
    }
    eprintln!(
        "drive-sim: {} {:?} drive(s) on vbus:{name} at {} kbit/s, node(s) {:?}; Ctrl-C to stop",
        stations.len(),
        cli.device,
        cli.bitrate / 1000,
        cli.nodes
    );
    let end = cli
        .duration
        .map(|d| now + Duration::from_secs_f64(d.max(0.0)));
    let every = (cli.status_every > 0.0).then(|| Duration::from_secs_f64(cli.status_every));
    let mut next_status = every.map(|e| now + e);
    // The shared-memory bus has no wake-up event: poll it at least this often.
    let poll = Duration::from_micros(200);
    while !STOP.load(Ordering::Relaxed) {
        for s in stations.iter_mut() {
            s.step();
        }
        let now = monotonic_now();
        if end.is_some_and(|e| now >= e) {
            break;
        }
        if let (Some(t), Some(e)) = (next_status, every)
            && now >= t
        {
            for s in &stations {
                eprintln!("{}", s.endpoint.status_line());
            }
            next_status = Some(t + e);
        }
        let mut wake = now + poll;
        for s in &stations {
            if let Some(t) = s.next_deadline() {
                wake = wake.min(t);
            }
        }
        sleep_until(wake);
    }
    let errors: u64 = stations.iter().map(|s| s.errors()).sum();
    let sent: u64 = stations.iter().map(|s| s.bus.counters().sent).sum();
    let received: u64 = stations.iter().map(|s| s.bus.counters().received).sum();
    eprintln!("drive-sim: stopped; {sent} frames sent, {received} received, {errors} bus errors");
    Ok(())
}

fn run_modbus(cli: &Cli, addr: SocketAddr) -> Result<(), String> {
    let drive = cmmo_st::drive::new_drive().map_err(|e| e.to_string())?;
    let device = Arc::new(Mutex::new(drive));
    let config = ServerConfig {
        addr,
        ..ServerConfig::loopback(0)
    };
    let server = cmmo_st::Server::spawn(config, device.clone()).map_err(|e| e.to_string())?;
    eprintln!(
        "drive-sim: CMMO-ST serving Modbus TCP on {}; Ctrl-C to stop",
        server.local_addr()
    );
    let start = monotonic_now();
    let end = cli
        .duration
        .map(|d| start + Duration::from_secs_f64(d.max(0.0)));
    let every = (cli.status_every > 0.0).then(|| Duration::from_secs_f64(cli.status_every));
    let mut next_status = every.map(|e| start + e);
    while !STOP.load(Ordering::Relaxed) {
        let now = monotonic_now();
        if end.is_some_and(|e| now >= e) {
            break;
        }
        if let (Some(t), Some(e)) = (next_status, every)
            && now >= t
        {
            let line = device
                .lock()
                .map(|d| cmmo_st::drive::status_line(&d))
                .unwrap_or_default();
            eprintln!(
                "CMMO-ST {line} | client {}",
                if server.is_connected() {
                    "connected"
                } else {
                    "none"
                }
            );
            next_status = Some(t + e);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let stats = server.shutdown();
    eprintln!("drive-sim: stopped; {stats:?}");
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    install_signal_handlers();
    let result = match (cli.device, &cli.bus, cli.modbus) {
        (Device::CmmoSt, _, Some(addr)) => run_modbus(&cli, addr),
        (Device::CmmoSt, _, None) => Err("the CMMO-ST needs --modbus ADDR".into()),
        (_, Some(bus), _) => match bus.strip_prefix("vbus:") {
            Some(name) if !name.is_empty() => run_can(&cli, name),
            _ => Err(format!(
                "--bus {bus}: drive-sim runs on the shared-memory virtual bus, name it vbus:NAME \
                 (SocketCAN is not offered: a simulated drive on a real bus would answer for a real device)"
            )),
        },
        (_, None, _) => Err("give --bus vbus:NAME".into()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("drive-sim: error: {e}");
            ExitCode::FAILURE
        }
    }
}
