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
//! timestamps, so other tools show real dates. On `vbus:` it writes frames in timestamp order:
//! each is held for the bus's reorder window (`drivers::can::reorder`, 60 ms at 1 Mbit/s) so
//! that frames of other senders stamped earlier can precede it. Once it listens it prints
//! `listening on IFACE` to stderr. With `--count N` it stops after N frames; with `--timeout
//! SECS` it stops after that long, and fails (exit 1) if `--count` was not reached; Ctrl-C
//! (SIGINT) or SIGTERM stop it too. However it stops, it writes every frame it holds first.
//! Errors go to stderr with exit status 1; a SocketCAN interface on a kernel without CAN names
//! the problem and suggests `vbus:NAME`.

use clap::{Parser, Subcommand};
use drivers::can::candump::{self, CandumpWriter};
use drivers::can::pcap::PcapWriter;
use drivers::can::reorder::{self, ReorderBuffer};
use drivers::can::shm_bus::{self, ShmBus};
use drivers::can::socketcan::SocketCanBus;
use drivers::can::{Bus, BusError, Frame};
use drivers::cli_number::Allowed;
use drivers::time::{Instant, monotonic_now};
use std::fs::File;
use std::io::{BufReader, BufWriter, Write};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
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
        /// Stop after this many frames (at least 1).
        #[arg(long, value_parser = clap::value_parser!(u64).range(1..=1_000_000_000))]
        count: Option<u64>,
        /// Stop after this many seconds (fails if --count was not reached); 0.001 to 31536000.
        #[arg(long, value_parser = SECONDS.parser())]
        timeout: Option<f64>,
    },
    /// Send frames given in cansend notation (605#4000100000000000, 123#R, 12345678#00).
    Send {
        /// `vbus:NAME` or a SocketCAN interface.
        iface: String,
        /// One or more frames, sent in order.
        #[arg(required = true)]
        frames: Vec<String>,
        /// Milliseconds to stay on the bus after the last frame (see LINGER); 0 to 60000.
        #[arg(long, default_value_t = LINGER_MS, value_parser = clap::value_parser!(u64).range(0..=60_000))]
        linger: u64,
    },
    /// Replay a candump log, keeping its relative timing.
    Replay {
        /// The candump log.
        file: PathBuf,
        /// `vbus:NAME` or a SocketCAN interface.
        iface: String,
        /// Time scale: 2 replays twice as fast; 0.001 to 1000.
        #[arg(long, default_value_t = 1.0, value_parser = SPEED.parser())]
        speed: f64,
        /// Milliseconds to stay on the bus after the last frame (see LINGER); 0 to 60000.
        #[arg(long, default_value_t = LINGER_MS, value_parser = clap::value_parser!(u64).range(0..=60_000))]
        linger: u64,
    },
}

/// `--timeout`: seconds a dump can wait (a year at most; a millisecond at least, as less would
/// end before the first frame could arrive).
const SECONDS: Allowed = Allowed::new("seconds", 0.001, 31_536_000.0);

/// `--speed`: a time scale whose replay can be timed (1000 times faster or slower at most).
const SPEED: Allowed = Allowed::new("a time scale", 0.001, 1000.0).note("2 replays twice as fast");

fn open_bus(iface: &str, bitrate: u32) -> Result<Box<dyn Bus>, String> {
    if iface.trim().is_empty()
        || iface
            .strip_prefix("vbus:")
            .is_some_and(|n| n.trim().is_empty())
    {
        return Err(format!(
            "bus `{iface}`: the name is empty; give vbus:NAME or a SocketCAN interface such as can0"
        ));
    }
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

/// Set by SIGINT and SIGTERM: `dump` stops, writes what it still holds, and exits normally.
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

/// Where `dump` writes each frame: stdout, and optionally a candump log and a pcap file.
struct DumpOutput<'a> {
    iface: &'a str,
    offset: u64,
    stdout: std::io::Stdout,
    log: Option<CandumpWriter<BufWriter<File>>>,
    pcap: Option<PcapWriter<BufWriter<File>>>,
}

impl DumpOutput<'_> {
    fn write(&mut self, frame: &Frame) -> Result<(), String> {
        let wall = Instant::from_nanos(frame.timestamp().as_nanos().saturating_add(self.offset));
        let _ = writeln!(
            self.stdout.lock(),
            "{}",
            candump::format_live(self.iface, frame)
        );
        if let Some(w) = self.log.as_mut() {
            w.write(wall, self.iface, frame)
                .map_err(|e| format!("writing log: {e}"))?;
        }
        if let Some(w) = self.pcap.as_mut() {
            w.write(wall, frame)
                .map_err(|e| format!("writing pcap: {e}"))?;
        }
        Ok(())
    }

    /// Called after each batch of released frames: a dump killed from outside still leaves
    /// complete files (minus what the reorder buffer held).
    fn flush(&mut self) -> Result<(), String> {
        let _ = self.stdout.lock().flush();
        if let Some(w) = self.log.as_mut() {
            w.flush().map_err(|e| format!("writing log: {e}"))?;
        }
        if let Some(w) = self.pcap.as_mut() {
            w.flush().map_err(|e| format!("writing pcap: {e}"))?;
        }
        Ok(())
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
    let log = log
        .as_ref()
        .map(create)
        .transpose()?
        .map(CandumpWriter::new);
    let pcap = match pcap.as_ref().map(create).transpose()? {
        Some(w) => Some(PcapWriter::new(w).map_err(|e| format!("writing pcap: {e}"))?),
        None => None,
    };
    // In range (the parser checked it): the conversion cannot overflow.
    let end = match timeout {
        Some(s) => monotonic_now() + Duration::from_secs_f64(s),
        None => Instant::MAX,
    };
    let mut out = DumpOutput {
        iface,
        offset: wall_offset(),
        stdout: std::io::stdout(),
        log,
        pcap,
    };
    // vbus senders stamp frames with modelled completion times and deliver them on arrival,
    // so frames of different senders arrive out of order: hold them for the bus's window.
    // SocketCAN stamps frames as they are read, already in order: release at once.
    let mut reorder = if iface.starts_with("vbus:") {
        ReorderBuffer::for_shm_bus(bitrate)
    } else {
        ReorderBuffer::new(Duration::ZERO, reorder::DEFAULT_CAPACITY)
    };
    install_signal_handlers();
    eprintln!("listening on {iface}");
    let received = receive(bus.as_mut(), iface, &mut reorder, &mut out, count, end);
    // Whatever stopped the dump (count, timeout, Ctrl-C, an error), write what is held.
    let flushed = std::iter::from_fn(|| reorder.pop_oldest())
        .try_for_each(|f| out.write(&f))
        .and_then(|()| out.flush());
    if reorder.released_early() > 0 {
        eprintln!(
            "canbus: warning: {} frames were written before their reorder window had passed \
             (more than {} held); the output may be out of order there",
            reorder.released_early(),
            reorder.capacity()
        );
    }
    if reorder.late() > 0 {
        eprintln!(
            "canbus: warning: {} frames arrived more than {} ms after their timestamp and are \
             out of order",
            reorder.late(),
            reorder.window().as_millis()
        );
    }
    received.and(flushed)
}

/// Receives into the reorder buffer and writes what it releases, until `count` frames, `end`,
/// or a signal.
fn receive(
    bus: &mut dyn Bus,
    iface: &str,
    reorder: &mut ReorderBuffer,
    out: &mut DumpOutput<'_>,
    count: Option<u64>,
    end: Instant,
) -> Result<(), String> {
    let mut seen = 0u64;
    while count.is_none_or(|n| seen < n) && !STOP.load(Ordering::Relaxed) {
        let now = monotonic_now();
        if now >= end {
            if let Some(n) = count {
                return Err(format!("timed out after {seen} of {n} frames"));
            }
            break;
        }
        // Wake for the next release and, at the latest, to look at the stop flag.
        let wake = end
            .min(now + Duration::from_millis(20))
            .min(reorder.next_release().unwrap_or(Instant::MAX));
        if let Some(frame) = bus
            .recv_until(wake)
            .map_err(|e| format!("receiving on {iface}: {e}"))?
        {
            seen += 1;
            if let Some(early) = reorder.push(frame) {
                out.write(&early)?;
            }
        }
        let mut released = false;
        while let Some(f) = reorder.pop_ready(monotonic_now()) {
            out.write(&f)?;
            released = true;
        }
        if released {
            out.flush()?;
        }
    }
    if STOP.load(Ordering::Relaxed) {
        // Frames that arrived before the signal are part of the capture: take them too (at
        // most a receive buffer's worth, so a busy bus cannot keep the dump alive).
        for _ in 0..shm_bus::SUBSCRIBER_BUFFER {
            if count.is_some_and(|n| seen >= n) {
                break;
            }
            let Some(frame) = bus
                .try_recv()
                .map_err(|e| format!("receiving on {iface}: {e}"))?
            else {
                break;
            };
            seen += 1;
            if let Some(early) = reorder.push(frame) {
                out.write(&early)?;
            }
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
