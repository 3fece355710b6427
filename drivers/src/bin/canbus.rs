//! `canbus`: dump, send and replay CAN frames on a SocketCAN interface or on the cross-process
//! virtual bus `vbus:NAME`.
//!
//! ```text
//! canbus dump vbus:test --log run.log --pcap run.pcap --count 10 --timeout 5
//! canbus send vbus:test 605#4000100000000000 080#
//! canbus replay run.log vbus:test --speed 2
//! ```
//!
//! `dump` prints each frame as the interactive `candump` does (`  vbus:test  605   [8]  40 00
//! 10 00 00 00 00 00`), and writes candump `-l` logs and pcap files with wall-clock (Unix epoch)
//! timestamps, so other tools show real dates. Once it listens it prints `listening on IFACE` to
//! stderr. With `--count N` it stops after N frames; with `--timeout SECS` it stops after that
//! long, and fails (exit 1) if `--count` was not reached. Errors go to stderr with exit status
//! 1; a SocketCAN interface on a kernel without CAN names the problem and suggests `vbus:NAME`.

use clap::{Parser, Subcommand};
use drivers::can::candump::{self, CandumpWriter};
use drivers::can::pcap::PcapWriter;
use drivers::can::shm_bus::ShmBus;
use drivers::can::socketcan::SocketCanBus;
use drivers::can::{Bus, BusError, Frame};
use drivers::time::{Instant, monotonic_now};
use std::fs::File;
use std::io::{BufReader, BufWriter, Write};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// How long `send` and `replay` stay on the bus after their last frame by default. A `vbus:`
/// frame lives in the sender's shared memory; a receiver that has not mapped it by the time the
/// sender exits loses it, so the sender gives receivers (polling every 100 µs to 200 ms) time.
const LINGER_MS: u64 = 250;

#[derive(Parser)]
#[command(name = "canbus", version, about = "Dump, send and replay CAN frames")]
struct Cli {
    /// Bitrate the virtual bus models, in bit/s (ignored for SocketCAN).
    #[arg(long, global = true, default_value_t = 1_000_000)]
    bitrate: u32,
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Print received frames; optionally write a candump log and a pcap file.
    Dump {
        /// `vbus:NAME` or a SocketCAN interface (can0, vcan0).
        iface: String,
        /// Write a candump `-l` log here.
        #[arg(long)]
        log: Option<PathBuf>,
        /// Write a pcap (LINKTYPE_CAN_SOCKETCAN) capture here.
        #[arg(long)]
        pcap: Option<PathBuf>,
        /// Stop after this many frames.
        #[arg(long)]
        count: Option<u64>,
        /// Stop after this many seconds (fails if --count was not reached).
        #[arg(long)]
        timeout: Option<f64>,
    },
    /// Send frames given in cansend notation (605#4000100000000000, 123#R, 12345678#00).
    Send {
        /// `vbus:NAME` or a SocketCAN interface.
        iface: String,
        /// One or more frames, sent in order.
        #[arg(required = true)]
        frames: Vec<String>,
        /// Milliseconds to stay on the bus after the last frame (see LINGER).
        #[arg(long, default_value_t = LINGER_MS)]
        linger: u64,
    },
    /// Replay a candump log, keeping its relative timing.
    Replay {
        /// The candump log.
        file: PathBuf,
        /// `vbus:NAME` or a SocketCAN interface.
        iface: String,
        /// Time scale: 2 replays twice as fast.
        #[arg(long, default_value_t = 1.0)]
        speed: f64,
        /// Milliseconds to stay on the bus after the last frame (see LINGER).
        #[arg(long, default_value_t = LINGER_MS)]
        linger: u64,
    },
}

fn open_bus(iface: &str, bitrate: u32) -> Result<Box<dyn Bus>, String> {
    if let Some(name) = iface.strip_prefix("vbus:") {
        return ShmBus::open(name, bitrate)
            .map(|b| Box::new(b) as Box<dyn Bus>)
            .map_err(|e| e.to_string());
    }
    SocketCanBus::open(iface)
        .map(|b| Box::new(b) as Box<dyn Bus>)
        .map_err(|e| e.to_string())
}

/// Nanoseconds to add to a monotonic timestamp to get Unix time.
fn wall_offset() -> u64 {
    let wall = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0);
    wall.saturating_sub(monotonic_now().as_nanos())
}

/// Sends, retrying while the transmit queue is full (up to one second).
fn send_blocking(bus: &mut dyn Bus, frame: &Frame) -> Result<(), String> {
    let give_up = monotonic_now() + Duration::from_secs(1);
    loop {
        match bus.send(frame) {
            Ok(()) => return Ok(()),
            Err(BusError::WouldBlock) if monotonic_now() < give_up => {
                std::thread::sleep(Duration::from_micros(200));
            }
            Err(e) => return Err(format!("sending {frame}: {e}")),
        }
    }
}

fn sleep_until(t: Instant) {
    let now = monotonic_now();
    if t > now {
        std::thread::sleep(t - now);
    }
}

fn dump(
    iface: &str,
    bitrate: u32,
    log: Option<PathBuf>,
    pcap: Option<PathBuf>,
    count: Option<u64>,
    timeout: Option<f64>,
) -> Result<(), String> {
    let mut bus = open_bus(iface, bitrate)?;
    let create = |p: &PathBuf| {
        File::create(p)
            .map(BufWriter::new)
            .map_err(|e| format!("cannot create {}: {e}", p.display()))
    };
    let mut log = log
        .as_ref()
        .map(create)
        .transpose()?
        .map(CandumpWriter::new);
    let mut pcap = match pcap.as_ref().map(create).transpose()? {
        Some(w) => Some(PcapWriter::new(w).map_err(|e| format!("writing pcap: {e}"))?),
        None => None,
    };
    let offset = wall_offset();
    let end = match timeout {
        Some(s) if s.is_finite() && s >= 0.0 => monotonic_now() + Duration::from_secs_f64(s),
        Some(s) => return Err(format!("--timeout {s} is not a number of seconds")),
        None => Instant::MAX,
    };
    eprintln!("listening on {iface}");
    let stdout = std::io::stdout();
    let mut seen = 0u64;
    while count.is_none_or(|n| seen < n) {
        let now = monotonic_now();
        if now >= end {
            if let Some(n) = count {
                return Err(format!("timed out after {seen} of {n} frames"));
            }
            break;
        }
        let Some(frame) = bus
            .recv_until(end.min(now + Duration::from_millis(200)))
            .map_err(|e| format!("receiving on {iface}: {e}"))?
        else {
            continue;
        };
        seen += 1;
        let wall = Instant::from_nanos(frame.timestamp().as_nanos().saturating_add(offset));
        let mut out = stdout.lock();
        let _ = writeln!(out, "{}", candump::format_live(iface, &frame));
        let _ = out.flush();
        // Flush per frame: a dump killed from outside still leaves a complete file.
        if let Some(w) = log.as_mut() {
            w.write(wall, iface, &frame)
                .and_then(|()| w.flush())
                .map_err(|e| format!("writing log: {e}"))?;
        }
        if let Some(w) = pcap.as_mut() {
            w.write(wall, &frame)
                .and_then(|()| w.flush())
                .map_err(|e| format!("writing pcap: {e}"))?;
        }
    }
    Ok(())
}

fn send(iface: &str, bitrate: u32, frames: &[String], linger: u64) -> Result<(), String> {
    let parsed = frames
        .iter()
        .map(|s| s.parse::<Frame>().map_err(|e| format!("`{s}`: {e}")))
        .collect::<Result<Vec<_>, _>>()?;
    let mut bus = open_bus(iface, bitrate)?;
    for f in &parsed {
        send_blocking(bus.as_mut(), f)?;
    }
    std::thread::sleep(Duration::from_millis(linger));
    Ok(())
}

fn replay(
    file: &PathBuf,
    iface: &str,
    bitrate: u32,
    speed: f64,
    linger: u64,
) -> Result<(), String> {
    if !(speed.is_finite() && speed > 0.0) {
        return Err(format!("--speed {speed} must be a positive number"));
    }
    let input = File::open(file).map_err(|e| format!("cannot open {}: {e}", file.display()))?;
    let records =
        candump::read_log(BufReader::new(input)).map_err(|e| format!("{}: {e}", file.display()))?;
    let mut bus = open_bus(iface, bitrate)?;
    let Some(first) = records.first() else {
        return Ok(());
    };
    let t0 = first.timestamp;
    let start = monotonic_now();
    for r in &records {
        let offset = (r.timestamp - t0).div_f64(speed);
        sleep_until(start + offset);
        send_blocking(bus.as_mut(), &r.frame)?;
    }
    std::thread::sleep(Duration::from_millis(linger));
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.cmd {
        Cmd::Dump {
            iface,
            log,
            pcap,
            count,
            timeout,
        } => dump(
            iface,
            cli.bitrate,
            log.clone(),
            pcap.clone(),
            *count,
            *timeout,
        ),
        Cmd::Send {
            iface,
            frames,
            linger,
        } => send(iface, cli.bitrate, frames, *linger),
        Cmd::Replay {
            file,
            iface,
            speed,
            linger,
        } => replay(file, iface, cli.bitrate, *speed, *linger),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("canbus: error: {e}");
            ExitCode::FAILURE
        }
    }
}
