//! The Modbus exchange thread against the simulated CMMO-ST server on 127.0.0.1: enabling the
//! drive through it, a stalled server, a slow server, a restarted server.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread;
use std::time::Duration;

use coordinator::drivers::fhpp::control::{Ccon, Cpos, OutputImage};
use coordinator::drivers::fhpp::state::{BringUp, bring_up};
use coordinator::drivers::fhpp::status::Scon;
use coordinator::drivers::fhpp::{Opm, Variant};
use coordinator::drivers::sim::cmmo_st::{
    ConnectionLost, FhppDevice, Identification, Server, ServerConfig, drive,
};
use coordinator::drivers::sim::fhpp_drive::FhppDrive;
use coordinator::drivers::time::{Instant, monotonic_now};
use coordinator::runtime::modbus::{self, Link, ModbusCycleSide, ModbusInput, ModbusSettings};
use coordinator::runtime::ticker::Ticker;

/// The simulated CMMO-ST, with two faults the test switches: a stall (the exchange does not
/// return, so the server answers nothing) and a delay before each answer.
struct Faulty {
    drive: FhppDrive,
    stall: Arc<AtomicBool>,
    delay_us: Arc<AtomicU64>,
}

impl FhppDevice for Faulty {
    fn exchange(&mut self, output: &[u8; 8], now: Instant) -> [u8; 8] {
        while self.stall.load(Ordering::Relaxed) {
            thread::sleep(Duration::from_millis(1));
        }
        let delay = self.delay_us.load(Ordering::Relaxed);
        if delay > 0 {
            thread::sleep(Duration::from_micros(delay));
        }
        self.drive.exchange(output, now)
    }
    fn parameter(&mut self, request: &[u8; 8], now: Instant) -> [u8; 8] {
        self.drive.parameter(request, now)
    }
    fn step_to(&mut self, now: Instant) {
        self.drive.step_to(now)
    }
    fn fault_number(&self) -> u16 {
        FhppDevice::fault_number(&self.drive)
    }
    fn identification(&self) -> Identification<'_> {
        FhppDevice::identification(&self.drive)
    }
    fn master_control(&self) -> bool {
        FhppDevice::master_control(&self.drive)
    }
    fn connection_lost(&mut self, lost: ConnectionLost, now: Instant) {
        FhppDevice::connection_lost(&mut self.drive, lost, now)
    }
    fn connection_established(&mut self, now: Instant) {
        FhppDevice::connection_established(&mut self.drive, now)
    }
}

struct Rig {
    server: Server,
    stall: Arc<AtomicBool>,
    delay_us: Arc<AtomicU64>,
}

impl Drop for Rig {
    /// A failed assertion must not leave the server thread stuck in a stall (its drop joins
    /// it).
    fn drop(&mut self) {
        self.stall.store(false, Ordering::Relaxed);
        self.delay_us.store(0, Ordering::Relaxed);
    }
}

fn start_server(addr: SocketAddr) -> Rig {
    let stall = Arc::new(AtomicBool::new(false));
    let delay_us = Arc::new(AtomicU64::new(0));
    let device = Faulty {
        drive: drive::new_drive().unwrap(),
        stall: Arc::clone(&stall),
        delay_us: Arc::clone(&delay_us),
    };
    let config = ServerConfig {
        addr,
        ..ServerConfig::loopback(0)
    };
    let server = Server::spawn(config, Arc::new(Mutex::new(device))).unwrap();
    Rig {
        server,
        stall,
        delay_us,
    }
}

fn loopback() -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], 0))
}

/// The cycle thread's part, on a real ticker: take the input, then put this cycle's output.
struct Cycle {
    side: ModbusCycleSide,
    ticker: Ticker,
    cycle: u64,
}

impl Cycle {
    fn new(side: ModbusCycleSide, period: Duration) -> Cycle {
        Cycle {
            side,
            ticker: Ticker::new(monotonic_now(), period),
            cycle: 0,
        }
    }

    /// Runs up to `max` cycles sending `image`, until `done` holds for an input; returns it.
    fn until(
        &mut self,
        max: u32,
        mut image: impl FnMut(&ModbusInput) -> [u8; 8],
        mut done: impl FnMut(&ModbusInput) -> bool,
    ) -> Option<ModbusInput> {
        for _ in 0..max {
            self.cycle = self.ticker.wait().cycle;
            let input = self.side.take_input(self.cycle);
            let out = image(&input);
            self.side.put_output(self.cycle, &out);
            if done(&input) {
                return Some(input);
            }
        }
        None
    }
}

fn idle(_: &ModbusInput) -> [u8; 8] {
    [0; 8]
}

fn settings(period: Duration) -> ModbusSettings {
    ModbusSettings {
        period,
        timeout: Duration::from_millis(50),
        backoff_min: Duration::from_millis(10),
        backoff_max: Duration::from_millis(80),
        ..ModbusSettings::default()
    }
}

#[test]
fn enables_the_drive_through_the_exchange() {
    let rig = start_server(loopback());
    let period = Duration::from_millis(5);
    let (side, thread) = modbus::spawn(rig.server.local_addr(), settings(period)).unwrap();
    let mut cycle = Cycle::new(side, period);
    let mut last = Ccon::default();
    let mut answered = 0;
    let order = Variant::CmmoSt.default_byte_order();
    // Set by the output closure, read by the stop condition of the same cycle.
    let reached = std::cell::Cell::new(false);
    let ready = cycle.until(
        1000,
        |input| {
            if input.fresh {
                // Answers come in the order the outputs were put.
                assert!(input.answered >= answered, "{input:?}");
                answered = input.answered;
                match bring_up(Scon::from_byte(input.data[0]), last, Opm::RecordSelect) {
                    BringUp::Ready(c) => {
                        last = c;
                        reached.set(true);
                    }
                    BringUp::Send(c) => last = c,
                    BringUp::Blocked(b) => panic!("{b:?}: {input:?}"),
                }
            }
            OutputImage::record(last, Cpos::idle(), 1).to_bytes(order)
        },
        |_| reached.get(),
    );
    let input = ready.expect("the drive never reached operation enabled");
    let scon = Scon::from_byte(input.data[0]);
    assert!(scon.enabled && scon.open && scon.vload, "{scon:?}");
    assert_eq!(input.link, Link::Up);
    // The device latched what the exchange sent: ENABLE, STOP and LOCK in CCON.
    assert_eq!(rig.server.stats().exceptions, 0);
    thread.stop();
}

#[test]
fn a_stalled_server_times_out_and_the_cycle_side_never_blocks() {
    let rig = start_server(loopback());
    let period = Duration::from_millis(5);
    let (side, thread) = modbus::spawn(rig.server.local_addr(), settings(period)).unwrap();
    let mut cycle = Cycle::new(side, period);
    assert!(
        cycle.until(400, idle, |i| i.link == Link::Up).is_some(),
        "never connected"
    );

    rig.stall.store(true, Ordering::Relaxed);
    // Hammer the cycle side until the timeout shows (at least 300 ms, at most 5 s): with a
    // blocking call this loop would manage one call per answer timeout (50 ms), not thousands.
    let start = monotonic_now();
    let mut calls = 0u64;
    let mut timed_out = None;
    loop {
        let elapsed = monotonic_now() - start;
        if elapsed > Duration::from_secs(5)
            || (timed_out.is_some() && elapsed > Duration::from_millis(300))
        {
            break;
        }
        let input = cycle.side.take_input(calls);
        cycle.side.put_output(calls, &[0; 8]);
        calls += 1;
        if let Link::TimedOut(ms) = input.link {
            timed_out = Some(ms);
            assert!(!input.fresh);
        }
        if calls.is_multiple_of(1024) {
            thread::yield_now();
        }
    }
    let ms = timed_out.expect("a stalled server must give TimedOut");
    assert!(ms >= 50, "timed out after {ms} ms, the timeout is 50 ms");
    assert!(calls > 1_000, "only {calls} calls");

    // The server comes back: the exchange reconnects and answers flow again.
    rig.stall.store(false, Ordering::Relaxed);
    let back = cycle.until(400, idle, |i| i.fresh && i.link == Link::Up);
    assert!(back.is_some(), "no answer after the stall ended");
    thread.stop();
}

#[test]
fn a_slow_answer_is_reported_late() {
    let rig = start_server(loopback());
    let period = Duration::from_millis(10);
    let (side, thread) = modbus::spawn(rig.server.local_addr(), settings(period)).unwrap();
    let mut cycle = Cycle::new(side, period);
    assert!(cycle.until(400, idle, |i| i.link == Link::Up).is_some());

    // Answers take 2.5 periods (below the 50 ms timeout).
    rig.delay_us.store(25_000, Ordering::Relaxed);
    let mut late_fresh = 0;
    let mut max_late = 0;
    cycle.until(40, idle, |i| {
        assert!(!matches!(i.link, Link::TimedOut(_)), "{i:?}");
        max_late = max_late.max(i.late_cycles);
        if i.fresh && i.late_cycles > 0 {
            late_fresh += 1;
        }
        false
    });
    assert!(late_fresh >= 3, "{late_fresh} late answers, max {max_late}");
    assert!(max_late >= 2, "max late {max_late}");

    // Fast again: answers are taken on time.
    rig.delay_us.store(0, Ordering::Relaxed);
    let on_time = cycle.until(100, idle, |i| i.fresh && i.late_cycles == 0);
    assert!(on_time.is_some(), "answers stayed late");
    thread.stop();
}

#[test]
fn reconnects_after_the_server_restarts() {
    let rig = start_server(loopback());
    let addr = rig.server.local_addr();
    let period = Duration::from_millis(5);
    let (side, thread) = modbus::spawn(addr, settings(period)).unwrap();
    let mut cycle = Cycle::new(side, period);
    assert!(cycle.until(400, idle, |i| i.link == Link::Up).is_some());
    assert_eq!(rig.server.stats().connections, 1);
    // Stops the server and closes the connection.
    drop(rig);

    let down = cycle.until(400, idle, |i| matches!(i.link, Link::Down(_)));
    assert!(down.is_some(), "the closed connection was not noticed");

    // The same address again: a new device, a new connection.
    let rig = start_server(addr);
    let up = cycle.until(400, idle, |i| i.fresh && i.link == Link::Up);
    assert!(up.is_some(), "no reconnection");
    assert!(rig.server.stats().connections >= 1);
    assert!(rig.server.stats().responses >= 1);
    thread.stop();
}
