//! The TLC5xx simulator against a CANopen master on the in-process virtual bus, in virtual time,
//! with the manual's byte sequences (digest seed-003 §8).
#![cfg(feature = "std")]

use std::collections::VecDeque;
use std::time::Duration;

use drivers::can::station::{self, Station, Steppable};
use drivers::can::{Bus, Frame, VirtualBus, VirtualBusConfig, VirtualPort};
use drivers::canopen::endpoint::Endpoint;
use drivers::canopen::master::{Master, MasterEvent, Supervision};
use drivers::canopen::nmt::{BootUpStyle, NmtCommand, NmtState, NmtTarget};
use drivers::canopen::sdo::{AbortedBy, DownloadMode, SdoError};
use drivers::canopen::{AbortCode, Address, NodeId};
use drivers::cia402::modes::OperationMode;
use drivers::cia402::state::State;
use drivers::sim::axis::{Environment, Load, SwitchZone};
use drivers::sim::tlc5xx::{TRIGGER, Tlc5xx, TlcConfig, TlcFault};
use drivers::time::Instant;

const MS: Duration = Duration::from_millis(1);

/// The master side: a CANopen [`Master`] plus raw frames the test scripts byte for byte.
struct Host {
    master: Master<4, 4, 256>,
    raw: VecDeque<Frame>,
}

impl Endpoint for Host {
    fn handle_frame(&mut self, frame: &Frame, now: Instant) {
        self.master.handle_frame(frame, now)
    }
    fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        self.raw
            .pop_front()
            .or_else(|| self.master.poll_transmit(now))
    }
    fn poll_timeout(&self) -> Option<Instant> {
        self.master.poll_timeout()
    }
    fn handle_timeout(&mut self, now: Instant) {
        self.master.handle_timeout(now)
    }
}

struct Rig {
    bus: VirtualBus,
    host: Station<VirtualPort, Host>,
    drive: Station<VirtualPort, Box<Tlc5xx>>,
    monitor: VirtualPort,
    log: Vec<Frame>,
}

fn node(n: u8) -> NodeId {
    NodeId::new(n).unwrap()
}

fn f(s: &str) -> Frame {
    s.parse().unwrap()
}

impl Rig {
    fn new(cfg: TlcConfig) -> Rig {
        let bus = VirtualBus::new(VirtualBusConfig::default()).unwrap();
        let monitor = bus.attach_monitor("monitor");
        let mut master = Master::new(Default::default(), true);
        master
            .add_node(cfg.node, Supervision::None, bus.now())
            .unwrap();
        let host = Station::new(
            bus.attach("host"),
            Host {
                master,
                raw: VecDeque::new(),
            },
        );
        let drive = Station::new(
            bus.attach("tlc"),
            Box::new(Tlc5xx::new(cfg, bus.now()).unwrap()),
        );
        Rig {
            bus,
            host,
            drive,
            monitor,
            log: Vec::new(),
        }
    }

    fn node1() -> Rig {
        Rig::new(TlcConfig::new(node(1)))
    }

    fn tlc(&mut self) -> &mut Tlc5xx {
        &mut self.drive.endpoint
    }

    fn settle(&mut self) {
        station::settle(&mut [&mut self.host as &mut dyn Steppable, &mut self.drive]);
        while let Ok(Some(fr)) = self.monitor.try_recv() {
            self.log.push(fr);
        }
    }

    fn run_until(&mut self, limit: Duration, mut done: impl FnMut(&mut Rig) -> bool) -> bool {
        let until = self.bus.now() + limit;
        loop {
            self.settle();
            if done(self) {
                return true;
            }
            if self.bus.now() >= until {
                return false;
            }
            let bus = self.bus.clone();
            let next = station::next_event(&bus, &[&mut self.host, &mut self.drive], until);
            bus.advance_to(next);
        }
    }

    fn run_for(&mut self, d: Duration) {
        self.run_until(d, |_| false);
    }

    /// Sends raw frames (in order) and lets the bus run `d`.
    fn send(&mut self, frames: &[&str], d: Duration) {
        self.host.endpoint.raw.extend(frames.iter().map(|s| f(s)));
        self.run_for(d);
    }

    /// The frames with COB-ID `id` logged from index `from` on.
    fn frames(&self, id: u16, from: usize) -> Vec<Frame> {
        self.log[from..]
            .iter()
            .filter(|fr| fr.cob_id() == Some(id) && !fr.is_remote())
            .copied()
            .collect()
    }

    /// A raw SDO request and the device's reply (the next 580h+n frame).
    fn sdo(&mut self, req: &str) -> Frame {
        let id = f(req).cob_id().unwrap() - 0x600 + 0x580;
        let from = self.log.len();
        self.send(&[req], 3 * MS);
        let r = self.frames(id, from);
        assert_eq!(r.len(), 1, "one reply to {req}: {r:?}");
        r[0]
    }

    /// An SDO write through the master's client; the outcome.
    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoError> {
        let n = self.drive.endpoint.node();
        self.host
            .endpoint
            .master
            .sdo(n)
            .unwrap()
            .download(Address::new(index, sub), data, DownloadMode::Auto)
            .unwrap();
        let mut out = None;
        let done = self.run_until(100 * MS, |r| {
            if let Some(e) = r.host.endpoint.master.poll_sdo_event(n) {
                out = Some(e.outcome.map(|_| ()));
                true
            } else {
                false
            }
        });
        assert!(done, "SDO write {index:04X}:{sub} did not complete");
        out.unwrap()
    }

    fn ok(&mut self, index: u16, sub: u8, data: &[u8]) {
        self.write(index, sub, data)
            .unwrap_or_else(|e| panic!("{index:04X}:{sub:02X}: {e}"));
    }

    fn nmt(&mut self, cmd: NmtCommand) {
        self.host.endpoint.master.nmt(cmd, NmtTarget::All).unwrap();
        self.run_for(2 * MS);
    }

    /// NMT start, then Shutdown and Enable operation on R_PDO1.
    fn enable(&mut self) {
        self.nmt(NmtCommand::Start);
        self.send(&["201#0600", "201#0F00"], 3 * MS);
        assert_eq!(self.tlc().drive_state(), State::OperationEnabled);
    }

    fn sw(&mut self) -> u16 {
        self.tlc().statusword()
    }
}

/// R_PDO2 (controlword, target position) valid and applied on reception (type 255).
fn pdo2_async(rig: &mut Rig) {
    rig.ok(0x1401, 2, &[255]);
    rig.ok(0x1401, 1, &0x301u32.to_le_bytes());
}

/// Waits for target reached (bit 10, set-point acknowledge clear), then lets the position loop
/// settle onto the last increment (bit 10 comes once inside p_win for p_winTime).
fn wait_reached(rig: &mut Rig, limit_ms: u32) {
    assert!(
        rig.run_until(limit_ms * MS, |r| r.sw() & 0x1400 == 0x0400),
        "target not reached"
    );
    rig.run_for(50 * MS);
}

fn abort(code: AbortCode) -> Result<(), SdoError> {
    Err(SdoError::Aborted {
        code,
        by: AbortedBy::Server,
    })
}

#[test]
fn boot_up_and_sdo_read_8_1_and_aborts_8_2() {
    let mut rig = Rig::node1();
    rig.run_for(MS);
    // Boot-up as §3.5 prints it: EMCY COB-ID, no data.
    assert_eq!(rig.log[0], f("081#"));
    assert_eq!(rig.tlc().nmt_state(), NmtState::PreOperational);
    // §8.1: 1000h:00 = 0x00020192.
    assert_eq!(rig.sdo("601#4000100000000000"), f("581#4300100092010200"));
    // §8.2 byte order; a missing object and the reserved PDO sub-index 04h (p.9-24).
    assert_eq!(rig.sdo("601#4000200000000000"), f("581#8000200000000206"));
    assert_eq!(rig.sdo("601#4001140400000000"), f("581#8001140411000906"));
    // 6081h above 607Fh is refused (p.9-116); 6060h accepts 1, 3, 6, -1 only; 6098h the
    // manual's nine methods only; 6083h its range 60..2e6.
    assert_eq!(
        rig.write(0x6081, 0, &3001u32.to_le_bytes()),
        abort(AbortCode::ValueTooHigh)
    );
    rig.ok(0x6081, 0, &3000u32.to_le_bytes());
    assert_eq!(rig.write(0x6060, 0, &[2]), abort(AbortCode::InvalidValue));
    assert_eq!(rig.write(0x6098, 0, &[33]), abort(AbortCode::InvalidValue));
    assert_eq!(
        rig.write(0x6083, 0, &59u32.to_le_bytes()),
        abort(AbortCode::ValueTooLow)
    );
    // A read-only object, and PDO4's static mapping.
    assert_eq!(rig.write(0x6041, 0, &[0, 0]), abort(AbortCode::ReadOnly));
    assert_eq!(rig.write(0x1603, 0, &[0]), abort(AbortCode::ReadOnly));
    // SIG start objects outside SIG mode / Operation enable: 0800 0022h.
    assert_eq!(rig.write(0x2090, 0, &[0; 4]), abort(AbortCode::DeviceState));
    // Strings are read segmented.
    let n = node(1);
    rig.host
        .endpoint
        .master
        .sdo(n)
        .unwrap()
        .upload(Address::new(0x6404, 0))
        .unwrap();
    let mut got = None;
    rig.run_until(50 * MS, |r| {
        if let Some(e) = r.host.endpoint.master.poll_sdo_event(n) {
            got = Some(format!("{:?}", e.outcome));
            true
        } else {
            false
        }
    });
    assert!(got.unwrap().contains("83, 73, 71"), "\"SIG\" expected");
}

#[test]
fn boot_up_style_is_configurable() {
    for (style, first) in [
        (BootUpStyle::LegacyEmcyEmpty, "0FF#"),
        (BootUpStyle::LegacyEmcyOneByte, "0FF#00"),
        (BootUpStyle::Ds301, "77F#00"),
    ] {
        let mut cfg = TlcConfig::new(node(127));
        cfg.boot_up = style;
        let mut rig = Rig::new(cfg);
        rig.run_for(MS);
        assert_eq!(rig.log[0], f(first), "{style:?}");
        assert_eq!(
            rig.host.endpoint.master.state(node(127)),
            Some(NmtState::PreOperational)
        );
    }
}

#[test]
fn state_switching_8_4() {
    let mut rig = Rig::node1();
    rig.run_for(MS);
    let from = rig.log.len();
    rig.send(&["000#0100"], 3 * MS);
    rig.send(&["201#0000"], 3 * MS);
    rig.send(&["201#0600"], 3 * MS);
    rig.send(&["201#0700"], 3 * MS);
    rig.send(&["201#0F00"], 3 * MS);
    let tpdo1: Vec<Frame> = rig.frames(0x181, from);
    assert_eq!(
        tpdo1,
        vec![f("181#4000"), f("181#2104"), f("181#2304"), f("181#2704")]
    );
    // Back down: Disable operation, Shutdown, Disable voltage (Tr.5, 6, 7).
    let from = rig.log.len();
    rig.send(&["201#0700", "201#0600", "201#0000"], 3 * MS);
    assert_eq!(
        rig.frames(0x181, from),
        vec![f("181#2304"), f("181#2104"), f("181#4000")]
    );
    // driveStat shows the state code (3 = Switch on disabled).
    assert_eq!(
        rig.tlc().od().get_u16(Address::new(0x2041, 0)).unwrap() & 0xF,
        3
    );
}

/// §8.5's configuration, byte for byte (replies echo the sub-index, erratum A11).
fn configure_8_5(rig: &mut Rig) {
    for (req, rsp) in [
        ("601#2301140101030000", "581#6001140100000000"),
        ("601#2301180181020000", "581#6001180100000000"),
        ("601#23836000D0070000", "581#6083600000000000"),
        ("601#23816000F4010000", "581#6081600000000000"),
        ("601#23846000E8030000", "581#6084600000000000"),
    ] {
        assert_eq!(rig.sdo(req), f(rsp), "{req}");
    }
}

#[test]
fn pp_move_with_sync_8_5() {
    let mut rig = Rig::node1();
    rig.run_for(MS);
    configure_8_5(&mut rig);
    let from = rig.log.len();
    rig.send(&["000#0100"], 3 * MS);
    rig.send(&["201#0600"], 3 * MS);
    rig.send(&["201#0F00"], 3 * MS);
    assert_eq!(rig.sdo("601#2F60600001000000"), f("581#6060600000000000"));
    // R_PDO2 (type 0) waits for the SYNC: nothing moves before it.
    rig.send(&["301#1F00DC050000"], 5 * MS);
    assert_eq!(rig.tlc().axis().status().position, 0);
    assert_eq!(rig.sw() & 0x1000, 0);
    rig.send(&["080#"], 2 * MS);
    assert_eq!(rig.sw() & 0x106F, 0x1027, "set-point acknowledged");
    rig.send(&["201#0F00"], 2 * MS);
    assert!(
        rig.run_until(2000 * MS, |r| r.sw() & 0x0400 != 0),
        "target reached"
    );
    rig.run_for(50 * MS);
    let tpdo1 = rig.frames(0x181, from);
    // 40 00, 21 xx, 27 xx, 27 10, 27 00, 27 04 (bit 10 before the move: 8.4 shows it set,
    // 8.5 clear; the simulator follows 8.4, so only the low byte and bit 12 are compared).
    let low: Vec<(u8, u8)> = tpdo1
        .iter()
        .map(|fr| (fr.data()[0], fr.data()[1] & 0x10))
        .collect();
    assert_eq!(
        low,
        vec![
            (0x40, 0),
            (0x21, 0),
            (0x27, 0),
            (0x27, 0x10),
            (0x27, 0),
            (0x27, 0)
        ]
    );
    assert_eq!(tpdo1.last().unwrap(), &f("181#2704")); // erratum A12: 0427h
    assert_eq!(rig.tlc().actual_usr(), 1500);
    // T_PDO2 (type 0) is sent at a SYNC when changed: statusword and 6064h = 1500.
    let from = rig.log.len();
    rig.send(&["080#"], 2 * MS);
    assert_eq!(rig.frames(0x281, from), vec![f("281#2704DC050000")]);
    // A relative move of 1500 again (bit 6 = 0): ends at 3000.
    rig.send(&["301#1F00DC050000", "080#"], 2 * MS);
    rig.send(&["201#0F00"], MS);
    wait_reached(&mut rig, 2000);
    assert_eq!(rig.tlc().actual_usr(), 3000);
    // Absolute (bit 6 = 1) to 500.
    rig.send(&["301#5F00F4010000", "080#"], 2 * MS);
    rig.send(&["201#0F00"], MS);
    wait_reached(&mut rig, 2000);
    assert_eq!(rig.tlc().actual_usr(), 500);
}

#[test]
fn pp_queue_change_set_immediately_and_halt() {
    let mut rig = Rig::node1();
    rig.run_for(MS);
    rig.ok(0x6081, 0, &600u32.to_le_bytes());
    pdo2_async(&mut rig);
    rig.enable();
    // Absolute 20000, then (bit 5 = 0) a queued absolute 0: bit 12 stays up while queued.
    rig.send(&["301#5F00204E0000", "301#4F00204E0000"], 5 * MS);
    rig.send(&["301#5F0000000000"], 2 * MS);
    assert_eq!(rig.sw() & 0x1000, 0x1000, "buffer full");
    rig.send(&["301#4F0000000000"], 2 * MS);
    assert_eq!(rig.sw() & 0x1000, 0x1000, "still full");
    // The axis reaches 20000 (stops there), then returns to 0.
    assert!(rig.run_until(3000 * MS, |r| r.tlc().axis().status().position >= 19_990));
    wait_reached(&mut rig, 3000);
    assert_eq!(rig.tlc().actual_usr(), 0);
    // Change set immediately: a new target during motion takes over without stopping.
    rig.send(&["301#5F00204E0000", "301#4F00204E0000"], 20 * MS);
    rig.send(&["301#7F0010270000", "301#4F0010270000"], MS);
    wait_reached(&mut rig, 3000);
    assert_eq!(rig.tlc().actual_usr(), 10_000);
    // Halt (bit 8) stops on the ramp and keeps the move; releasing it finishes the move.
    rig.send(&["301#5F00204E0000", "301#4F00204E0000"], 10 * MS);
    rig.send(&["301#4F01204E0000"], 300 * MS);
    let held = rig.tlc().actual_usr();
    assert!(held > 10_000 && held < 20_000, "{held}");
    assert!(rig.tlc().axis().status().standstill);
    assert_eq!(
        rig.sw() & 0x0400,
        0x0400,
        "halted at standstill shows bit 10"
    );
    rig.send(&["301#4F00204E0000"], MS);
    assert!(rig.run_until(3000 * MS, |r| r.sw() & 0x1400 == 0x0400
        && r.tlc().actual_usr() == 20_000));
}

#[test]
fn pv_with_sync_8_6_quick_stop_and_resume() {
    let mut rig = Rig::node1();
    rig.run_for(MS);
    for (req, rsp) in [
        ("601#2302140101040000", "581#6002140100000000"),
        ("601#2302180181030000", "581#6002180100000000"),
        ("601#23836000D0070000", "581#6083600000000000"),
        ("601#23846000E8030000", "581#6084600000000000"),
    ] {
        assert_eq!(rig.sdo(req), f(rsp), "{req}");
    }
    rig.send(&["000#0100", "201#0600", "201#0F00"], 3 * MS);
    assert_eq!(rig.sdo("601#2F60600003000000"), f("581#6060600000000000"));
    assert_eq!(rig.tlc().mode(), OperationMode::ProfileVelocity);
    rig.send(&["401#1F0085000000"], 5 * MS);
    assert_eq!(rig.tlc().axis().status().velocity, 0, "waits for the SYNC");
    rig.send(&["080#"], 500 * MS);
    // 133 rpm reached: T_PDO3 at the next SYNC shows 0427h (speed reached) and 606Ch = 85h.
    let from = rig.log.len();
    rig.send(&["080#"], 2 * MS);
    assert_eq!(rig.frames(0x381, from), vec![f("381#270485000000")]);
    // Quick stop (Tr.11): state 7, the axis stops; 000Fh continues the speed (Tr.16).
    rig.send(&["201#0B00"], 300 * MS);
    assert_eq!(rig.tlc().drive_state(), State::QuickStopActive);
    assert_eq!(rig.sw() & 0x6F, 0x07);
    assert_eq!(rig.tlc().axis().status().velocity, 0);
    assert_eq!(rig.sw() & 0x1000, 0x1000, "speed = 0");
    rig.send(&["201#0F00"], 500 * MS);
    assert_eq!(rig.tlc().drive_state(), State::OperationEnabled);
    let v = rig.tlc().od().get_i32(Address::new(0x606C, 0)).unwrap();
    assert_eq!(v, 133);
}

#[test]
fn guarding_heartbeat_and_emcy_8_7() {
    let mut rig = Rig::new(TlcConfig::new(node(4)));
    rig.run_for(MS);
    // Guarding: reply 7Fh in Pre-op, toggle alternating.
    let from = rig.log.len();
    rig.send(&["704#R"], 2 * MS);
    rig.send(&["704#R"], 2 * MS);
    assert_eq!(rig.frames(0x704, from), vec![f("704#7F"), f("704#FF")]);
    rig.nmt(NmtCommand::Start);
    let from = rig.log.len();
    rig.send(&["704#R"], 2 * MS);
    rig.send(&["704#R"], 2 * MS);
    assert_eq!(rig.frames(0x704, from), vec![f("704#05"), f("704#85")]);
    // Reset communication restarts the toggle.
    rig.nmt(NmtCommand::ResetCommunication);
    let from = rig.log.len();
    rig.send(&["704#R"], 2 * MS);
    assert_eq!(rig.frames(0x704, from), vec![f("704#7F")]);
    // Life guarding and heartbeat exclude each other.
    rig.ok(0x100C, 0, &100u16.to_le_bytes());
    rig.ok(0x100D, 0, &[3]);
    assert_eq!(
        rig.write(0x1017, 0, &100u16.to_le_bytes()),
        abort(AbortCode::ParamIncompatible)
    );
    rig.ok(0x100D, 0, &[0]);
    rig.ok(0x1017, 0, &100u16.to_le_bytes());
    rig.nmt(NmtCommand::Start);
    let from = rig.log.len();
    rig.run_for(350 * MS);
    let hb = rig.frames(0x704, from);
    assert_eq!(hb.len(), 3);
    assert!(hb.iter().all(|fr| *fr == f("704#05")));
    // Heartbeat off, life guarding on: the master polls, then stops: EMCY 8130h + Fault.
    rig.ok(0x1017, 0, &[0, 0]);
    rig.send(&["204#0600", "204#0F00"], 3 * MS);
    rig.send(&["704#R"], 2 * MS);
    let from = rig.log.len();
    rig.ok(0x100D, 0, &[3]);
    rig.run_for(400 * MS);
    let emcy = rig.frames(0x084, from);
    assert_eq!(emcy.len(), 1, "{emcy:?}");
    assert_eq!(&emcy[0].data()[..2], &[0x30, 0x81]);
    assert_eq!(rig.tlc().drive_state(), State::Fault);
    assert_eq!(rig.tlc().faults(), &[TlcFault::LifeGuarding]);
}

fn homing_env() -> Environment {
    Environment {
        travel: Some((-60_000, 60_000)),
        limit_negative: Some(SwitchZone::below(-50_000)),
        limit_positive: Some(SwitchZone::above(50_000)),
        reference: Some(SwitchZone::cam(10_000, 12_000)),
        load: Load::None,
        index_phase: 123,
    }
}

#[test]
fn homing_every_method_ends_referenced_at_the_right_place() {
    // (method, start, raw position of the reference point = edge (or index) + p_disHome)
    let cases: [(i8, i64, i64); 9] = [
        (17, 0, -50_000 + 200),
        (18, 0, 50_000 - 200),
        (1, 0, -49_029 + 200),
        (2, 0, 49_275 - 200),
        (23, 0, 10_000 - 200),
        (27, 20_000, 12_000 + 200),
        (7, 0, 123 - 200),
        (11, 20_000, 16_507 + 200),
        (35, 5_000, 5_000),
    ];
    for (method, start, az) in cases {
        let mut cfg = TlcConfig::new(node(1));
        cfg.environment = homing_env();
        cfg.start_position = start;
        let mut rig = Rig::new(cfg);
        rig.run_for(MS);
        rig.ok(0x6099, 1, &600i32.to_le_bytes());
        rig.ok(0x6099, 2, &60i32.to_le_bytes());
        rig.ok(0x6083, 0, &60_000u32.to_le_bytes());
        rig.ok(0x6098, 0, &[method as u8]);
        rig.ok(0x20F6, 0, &777i32.to_le_bytes());
        rig.enable();
        rig.ok(0x6060, 0, &[6]);
        assert_eq!(rig.tlc().mode(), OperationMode::Homing);
        rig.send(&["201#1F00"], 2 * MS);
        if method != 35 {
            assert_eq!(rig.sw() & 0x3400, 0, "method {method}: homing in progress");
        }
        let done = rig.run_until(20_000 * MS, |r| r.sw() & 0x3000 != 0);
        assert!(done, "method {method} did not end");
        rig.run_for(50 * MS);
        assert_eq!(
            rig.sw() & 0x3400,
            0x1400,
            "method {method}: attained, no error"
        );
        assert!(rig.tlc().referenced());
        assert_eq!(rig.tlc().axis().raw_position(), az, "method {method}");
        let home = if method == 35 { 777 } else { 0 };
        assert_eq!(rig.tlc().actual_usr(), home, "method {method}");
        assert!(rig.tlc().faults().is_empty(), "method {method}");
    }
}

#[test]
fn homing_without_its_switch_reports_an_error() {
    let mut cfg = TlcConfig::new(node(1));
    cfg.environment = homing_env();
    cfg.environment.reference = None;
    let mut rig = Rig::new(cfg);
    rig.run_for(MS);
    rig.ok(0x6099, 1, &600i32.to_le_bytes());
    rig.ok(0x6083, 0, &60_000u32.to_le_bytes());
    rig.ok(0x6098, 0, &[23]);
    rig.enable();
    rig.ok(0x6060, 0, &[6]);
    rig.send(&["201#1F00"], 2 * MS);
    assert!(rig.run_until(20_000 * MS, |r| r.sw() & 0x3000 != 0));
    assert_eq!(rig.sw() & 0x3000, 0x2000, "homing error");
    assert!(!rig.tlc().referenced());
}

#[test]
fn following_error_fault_and_its_reset() {
    let mut rig = Rig::node1();
    rig.run_for(MS);
    rig.ok(0x6081, 0, &600u32.to_le_bytes());
    pdo2_async(&mut rig);
    rig.enable();
    rig.tlc().inject_block(true);
    let from = rig.log.len();
    rig.send(&["301#5F00A0860100", "301#4F00A0860100"], 800 * MS);
    // Class 3 (Flt_pDiff default): power stage off, Fault (DSP402 coding x0xx1000).
    assert_eq!(rig.tlc().drive_state(), State::Fault);
    assert_eq!(rig.sw() & 0x4F, 0x08);
    assert!(!rig.tlc().axis().is_enabled());
    let emcy = rig.frames(0x081, from);
    assert_eq!(emcy.len(), 1);
    assert_eq!(&emcy[0].data()[..2], &[0x11, 0x86]);
    assert_eq!(emcy[0].data()[2] & 1, 1, "generic error bit");
    assert_eq!(
        emcy[0].data()[3],
        3,
        "error class in the manufacturer field"
    );
    let od = |r: &mut Rig, i, s| r.tlc().od().get_u32(Address::new(i, s)).unwrap();
    assert_eq!(od(&mut rig, 0x603F, 0), 0x8611);
    assert_eq!(od(&mut rig, 0x1003, 1), 0x8611);
    assert_eq!(od(&mut rig, 0x2400, 1), 0x8611);
    assert_eq!(od(&mut rig, 0x1001, 0) & 1, 1);
    assert_eq!(
        od(&mut rig, 0x2041, 0) & 0x2F,
        0x29,
        "driveStat: Fault, internal"
    );
    // SIG start objects answer with the device error number.
    assert_eq!(
        rig.write(0x2090, 0, &[0; 4]),
        abort(AbortCode::Other(0x0800_8611))
    );
    // Fault reset edge: Switch on disabled, EMCY 0000h, error cleared; re-enable works.
    rig.tlc().inject_block(false);
    let from = rig.log.len();
    rig.send(&["201#0000", "201#8000"], 3 * MS);
    assert_eq!(rig.tlc().drive_state(), State::SwitchOnDisabled);
    assert_eq!(rig.frames(0x081, from), vec![f("081#0000000000000000")]);
    assert_eq!(od(&mut rig, 0x603F, 0), 0);
    assert_eq!(od(&mut rig, 0x1001, 0), 0);
    assert_eq!(od(&mut rig, 0x2400, 1), 0x8611, "the history keeps it");
    rig.send(&["201#0600", "201#0F00"], 3 * MS);
    assert_eq!(rig.tlc().drive_state(), State::OperationEnabled);
}

#[test]
fn supply_fault_cannot_be_reset_while_the_cause_persists() {
    let mut rig = Rig::node1();
    rig.run_for(MS);
    rig.enable();
    rig.tlc().set_supply_ok(false);
    let from = rig.log.len();
    rig.run_for(5 * MS);
    assert_eq!(rig.tlc().drive_state(), State::Fault);
    assert_eq!(&rig.frames(0x081, from)[0].data()[..2], &[0x20, 0x32]);
    rig.send(&["201#0000", "201#8000"], 3 * MS);
    assert_eq!(rig.tlc().drive_state(), State::Fault, "cause still present");
    rig.tlc().set_supply_ok(true);
    rig.send(&["201#0000", "201#8000"], 3 * MS);
    assert_eq!(rig.tlc().drive_state(), State::SwitchOnDisabled);
    // Over-temperature on request: class 2, quick stop then Fault.
    rig.send(&["201#0600", "201#0F00"], 3 * MS);
    rig.tlc().set_over_temperature(true);
    rig.run_for(5 * MS);
    assert_eq!(rig.tlc().drive_state(), State::Fault);
    assert_eq!(rig.tlc().faults(), &[TlcFault::OverTemperature]);
    rig.tlc().set_over_temperature(false);
    // driveCtrl bit 3 resets it too (one-shot: reads back 0).
    rig.ok(0x2040, 0, &[8, 0]);
    assert_eq!(rig.tlc().drive_state(), State::SwitchOnDisabled);
    assert_eq!(rig.tlc().od().get_u16(Address::new(0x2040, 0)), Ok(0));
    rig.ok(0x2040, 0, &[2, 0]);
    assert_eq!(rig.tlc().drive_state(), State::OperationEnabled);
}

#[test]
fn late_rpdo_outside_the_1007h_window_is_applied_one_sync_later() {
    let mut rig = Rig::node1();
    rig.run_for(MS);
    configure_8_5(&mut rig);
    rig.ok(0x1006, 0, &10_000u32.to_le_bytes());
    rig.ok(0x1007, 0, &2_000u32.to_le_bytes());
    rig.enable();
    // In the window (1 ms after SYNC): applied at the next SYNC.
    rig.send(&["080#"], MS);
    rig.send(&["301#1F00E8030000"], 9 * MS);
    assert_eq!(rig.sw() & 0x1000, 0);
    rig.send(&["080#"], MS);
    assert_eq!(rig.sw() & 0x1000, 0x1000, "applied at the next SYNC");
    rig.send(&["201#0F00"], 500 * MS);
    assert_eq!(rig.tlc().actual_usr(), 1000);
    // Late (5 ms after SYNC, window 2 ms): not at the next SYNC, at the one after.
    rig.send(&["080#"], 5 * MS);
    rig.send(&["301#1F00E8030000"], 5 * MS);
    rig.send(&["080#"], 10 * MS);
    assert_eq!(rig.sw() & 0x1000, 0, "not at the next SYNC");
    rig.send(&["080#"], MS);
    assert_eq!(rig.sw() & 0x1000, 0x1000, "at the SYNC after next");
    rig.send(&["201#0F00"], 500 * MS);
    assert_eq!(rig.tlc().actual_usr(), 2000);
}

#[test]
fn pdo_settings_are_lost_on_nmt_reset() {
    let mut rig = Rig::node1();
    rig.run_for(MS);
    let a = Address::new;
    rig.ok(0x1401, 1, &0x301u32.to_le_bytes());
    rig.ok(0x1A01, 0, &[0]);
    rig.ok(0x1A01, 1, &0x6041_0010u32.to_le_bytes());
    rig.ok(0x1A01, 0, &[1]);
    rig.ok(0x6083, 0, &5000u32.to_le_bytes());
    // COB-IDs change only in Pre-operational.
    rig.nmt(NmtCommand::Start);
    assert_eq!(
        rig.write(0x1402, 1, &0x401u32.to_le_bytes()),
        abort(AbortCode::DeviceState)
    );
    rig.nmt(NmtCommand::ResetCommunication);
    rig.run_for(5 * MS);
    let od = |r: &mut Rig, i, s| r.tlc().od().get_u32(a(i, s)).unwrap();
    assert_eq!(od(&mut rig, 0x1401, 1), 0x8000_0301);
    assert_eq!(od(&mut rig, 0x1A01, 0), 2);
    assert_eq!(
        od(&mut rig, 0x6083, 0),
        5000,
        "application data kept by 82h"
    );
    rig.nmt(NmtCommand::ResetNode);
    rig.run_for(5 * MS);
    assert_eq!(
        od(&mut rig, 0x6083, 0),
        600,
        "81h reloads the application data"
    );
    assert_eq!(rig.tlc().nmt_state(), NmtState::PreOperational);
}

#[test]
fn fast_ptp_on_pdo4() {
    let mut rig = Rig::node1();
    rig.run_for(MS);
    rig.ok(0x1403, 1, &0x501u32.to_le_bytes());
    rig.ok(0x1803, 1, &0x481u32.to_le_bytes());
    // PDO4 is static.
    assert_eq!(rig.write(0x1803, 2, &[1]), abort(AbortCode::ReadOnly));
    rig.enable();
    rig.ok(0x6060, 0, &[0xFF]);
    assert_eq!(rig.tlc().mode(), OperationMode::TlcSigMode);
    // p_absPTP = 4000, v_tar16 = 600 rpm, ramp = 6000 rpm/s: starts an absolute move.
    rig.send(&["501#A00F000058027017"], 3 * MS);
    assert!(rig.tlc().axis().status().velocity > 0);
    assert_eq!(
        rig.tlc().od().get_u16(Address::new(0x2091, 0)).unwrap() & 0x4000,
        0,
        "x_end = 0 while running"
    );
    assert!(rig.run_until(
        2000 * MS,
        |r| r.tlc().od().get_u16(Address::new(0x2091, 0)).unwrap() & 0x4000 != 0
    ));
    rig.run_for(50 * MS);
    assert_eq!(rig.tlc().actual_usr(), 4000);
    // T_PDO4 reports position, speed and StatePTP (x_end | setpoint reached), then every 1 s.
    let from = rig.log.len();
    rig.run_for(2100 * MS);
    let t4 = rig.frames(0x481, from);
    assert_eq!(t4.len(), 2, "{t4:?}");
    assert_eq!(t4[0], f("481#A00F000000000060"));
}

#[test]
fn position_list_drives_trigger() {
    let mut rig = Rig::node1();
    rig.run_for(MS);
    for (k, (pos, sig)) in [(1000i32, 1u16), (2000, 0), (3000, 1)].iter().enumerate() {
        rig.ok(0x2201, k as u8 + 1, &pos.to_le_bytes());
        rig.ok(0x2202, k as u8 + 1, &sig.to_le_bytes());
    }
    rig.ok(0x20B9, 0, &2u16.to_le_bytes());
    rig.ok(0x6081, 0, &60u32.to_le_bytes()); // 60 rpm = 16384 inc/s: 16 inc per tick
    rig.ok(0x20B4, 0, &1u16.to_le_bytes());
    rig.enable();
    rig.ok(0x607A, 0, &4000i32.to_le_bytes());
    rig.send(&["201#5F00", "201#4F00"], MS);
    let mut edges = Vec::new();
    let mut last = false;
    rig.run_until(2000 * MS, |r| {
        let out = r.tlc().od().get_u32(Address::new(0x60FE, 1)).unwrap();
        let on = out & TRIGGER != 0;
        if on != last {
            edges.push((on, r.tlc().axis().status().position));
            last = on;
        }
        r.tlc().statusword() & 0x0400 != 0 && r.tlc().actual_usr() == 4000
    });
    assert_eq!(edges.len(), 3, "{edges:?}");
    for ((on, at), (want_on, want_at)) in
        edges
            .iter()
            .zip([(true, 1000), (false, 2000), (true, 3000)])
    {
        assert_eq!(*on, want_on);
        assert!((want_at..want_at + 20).contains(at), "{edges:?}");
    }
    let od = rig.tlc().od();
    assert_eq!(od.get_i16(Address::new(0x20BA, 0)), Ok(2));
    assert_eq!(od.get_u16(Address::new(0x20B5, 0)), Ok(1 << 14));
}

/// A 10 s scenario: configuration, SYNC every 10 ms from the master, a move every second.
fn scenario() -> Vec<(Instant, Frame)> {
    let mut rig = Rig::node1();
    rig.run_for(MS);
    configure_8_5(&mut rig);
    rig.ok(0x1801, 2, &[1]); // T_PDO2 every SYNC
    rig.enable();
    let now = rig.bus.now();
    rig.host.endpoint.master.start_sync(10_000, 0, now).unwrap();
    for k in 0..10 {
        let target: i32 = if k % 2 == 0 { 30_000 } else { -30_000 };
        let t = target.to_le_bytes();
        let s = format!("301#1F00{:02X}{:02X}{:02X}{:02X}", t[0], t[1], t[2], t[3]);
        rig.send(&[&s], 20 * MS);
        rig.send(&["301#0F0000000000"], 980 * MS);
    }
    while let Some(e) = rig.host.endpoint.master.poll_event() {
        assert!(!matches!(e, MasterEvent::Emcy(_)), "{e:?}");
    }
    rig.log.iter().map(|fr| (fr.timestamp(), *fr)).collect()
}

#[test]
fn ten_seconds_are_deterministic() {
    let a = scenario();
    let b = scenario();
    assert!(a.len() > 1500, "{} frames", a.len());
    assert_eq!(a, b);
    // Every SYNC after the start has its T_PDO2.
    let syncs = a.iter().filter(|(_, f)| f.cob_id() == Some(0x80)).count();
    let tpdo2 = a.iter().filter(|(_, f)| f.cob_id() == Some(0x281)).count();
    assert!(
        syncs >= 990 && tpdo2 == syncs,
        "{syncs} SYNC, {tpdo2} T_PDO2"
    );
}

#[test]
fn limit_switch_stops_and_faults_and_software_limits_refuse_targets() {
    let mut cfg = TlcConfig::new(node(1));
    cfg.environment.limit_positive = Some(SwitchZone::above(20_000));
    let mut rig = Rig::new(cfg);
    rig.run_for(MS);
    rig.ok(0x6085, 0, &60_000u32.to_le_bytes());
    rig.ok(0x6083, 0, &6_000u32.to_le_bytes());
    rig.ok(0x6084, 0, &6_000u32.to_le_bytes());
    rig.enable();
    rig.ok(0x6060, 0, &[3]);
    let from = rig.log.len();
    rig.ok(0x60FF, 0, &600i32.to_le_bytes());
    assert!(rig.run_until(2000 * MS, |r| r.tlc().drive_state() == State::Fault));
    let emcy = rig.frames(0x081, from);
    assert_eq!(&emcy[0].data()[..2], &[0x01, 0xFF]);
    assert_eq!(rig.tlc().faults(), &[TlcFault::LimitPositive]);
    let od = |r: &mut Rig, i| r.tlc().od().get_u32(Address::new(i, 0)).unwrap();
    assert_eq!(rig.sw() & 0x0800, 0x0800, "internal limit active");
    assert_eq!(
        od(&mut rig, 0x2041) & 0x4F,
        0x49,
        "driveStat: Fault, external"
    );
    assert_eq!(od(&mut rig, 0x60FD) & 0x2, 0x2, "LIMP input");
    assert!(rig.tlc().axis().status().position >= 20_000);
    // Reset on the switch, re-enable and drive off it: no new fault.
    rig.send(&["201#0000", "201#8000", "201#0600", "201#0F00"], 3 * MS);
    assert_eq!(rig.tlc().drive_state(), State::OperationEnabled);
    rig.ok(0x60FF, 0, &(-600i32).to_le_bytes());
    assert!(rig.run_until(2000 * MS, |r| r.tlc().axis().status().position < 15_000));
    assert!(rig.tlc().faults().is_empty());
    assert_eq!(rig.sw() & 0x0800, 0);
    rig.ok(0x60FF, 0, &0i32.to_le_bytes());
    rig.run_for(200 * MS);
    // Software limits (SW_Enabl bit 5, SW_LimP = 607Dh:02): no motion, EMCY FF22h then 0000h.
    rig.ok(0x6060, 0, &[1]);
    assert_eq!(rig.tlc().mode(), OperationMode::ProfilePosition);
    rig.ok(0x2054, 0, &0x20u16.to_le_bytes());
    rig.ok(0x607D, 2, &10_000i32.to_le_bytes());
    assert_eq!(rig.tlc().od().get_i32(Address::new(0x2052, 0)), Ok(10_000));
    let pos = rig.tlc().actual_usr();
    rig.ok(0x607A, 0, &12_000i32.to_le_bytes());
    let from = rig.log.len();
    rig.send(&["201#5F00", "201#4F00"], 100 * MS);
    assert_eq!(
        rig.frames(0x081, from),
        vec![f("081#22FF810000000000"), f("081#0000000000000000")]
    );
    assert_eq!(rig.tlc().actual_usr(), pos);
    assert_eq!(rig.tlc().od().get_u16(Address::new(0x603F, 0)), Ok(0xFF22));
}

#[test]
fn bit6_polarity_and_fault_coding_are_settings() {
    use drivers::cia402::controlword::AbsRel;
    use drivers::cia402::state::FaultCoding;
    let mut cfg = TlcConfig::new(node(1));
    cfg.abs_rel = AbsRel::ZeroIsAbsolute;
    cfg.fault_coding = FaultCoding::AsPrinted;
    let mut rig = Rig::new(cfg);
    rig.run_for(MS);
    rig.ok(0x6081, 0, &600u32.to_le_bytes());
    pdo2_async(&mut rig);
    rig.enable();
    // DSP402 polarity: bit 6 = 0 is absolute, so 001Fh twice to 5000 ends at 5000.
    for _ in 0..2 {
        rig.send(&["301#1F0088130000", "301#0F0088130000"], 5 * MS);
        wait_reached(&mut rig, 3000);
    }
    assert_eq!(rig.tlc().actual_usr(), 5000);
    // Bit 6 = 1 is relative here: +1000.
    rig.send(&["301#5F00E8030000", "301#4F00E8030000"], 5 * MS);
    wait_reached(&mut rig, 3000);
    assert_eq!(rig.tlc().actual_usr(), 6000);
    // Fault "as printed" (erratum A2): 000Fh in the state bits.
    rig.tlc().raise_fault(TlcFault::OverTemperature);
    rig.run_for(50 * MS);
    assert_eq!(rig.tlc().drive_state(), State::Fault);
    assert_eq!(rig.sw() & 0x6F, 0x0F);
}

#[test]
fn arbitrary_frames_never_panic() {
    // A deterministic pseudo-random stream of frames aimed at node 1's COB-IDs, including SDO
    // writes of random bytes to every object the simulator acts on.
    let mut cfg = TlcConfig::new(node(1));
    cfg.environment = homing_env();
    let mut tlc = Box::new(Tlc5xx::new(cfg, Instant::ZERO).unwrap());
    let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut next = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let targets: [u16; 16] = [
        0x6040, 0x6060, 0x607A, 0x60FF, 0x6081, 0x6098, 0x2040, 0x2090, 0x2092, 0x20B4, 0x20B8,
        0x6093, 0x6094, 0x1401, 0x1007, 0x2201,
    ];
    let ids: [u16; 10] = [
        0x000, 0x080, 0x201, 0x301, 0x401, 0x501, 0x601, 0x701, 0x181, 0x7E5,
    ];
    let mut now = Instant::ZERO;
    tlc.handle_frame(&f("000#0100"), now);
    for i in 0..20_000u32 {
        let r = next();
        let id = ids[(r % ids.len() as u64) as usize];
        let mut data = (next()).to_le_bytes();
        let len = (r >> 8) as usize % 9;
        if id == 0x601 && i % 2 == 0 {
            let t = targets[(r >> 16) as usize % targets.len()];
            data[0] = [0x23, 0x2B, 0x2F, 0x27, 0x40][(r >> 24) as usize % 5];
            data[1..3].copy_from_slice(&t.to_le_bytes());
            data[3] = (r >> 32) as u8 % 4;
        }
        let fr = if id == 0x701 && r & 1 == 0 {
            Frame::new_std_remote(id, 1).unwrap()
        } else {
            Frame::new_std(id, &data[..len]).unwrap()
        };
        now += Duration::from_micros(r % 3000);
        if tlc.poll_timeout().is_some_and(|t| t <= now) {
            tlc.handle_timeout(now);
        }
        tlc.handle_frame(&fr, now);
        while tlc.poll_transmit(now).is_some() {}
        if i % 1000 == 0 {
            tlc.set_supply_ok(i % 3000 != 0);
        }
    }
}

#[test]
fn p_max_diff_written_by_sdo_takes_effect_at_once() {
    // The drive keeps 2010h out of its per-tick lookups: a write must still act on the next tick.
    let mut rig = Rig::node1();
    rig.run_for(MS);
    rig.ok(0x2010, 0, &131_072u32.to_le_bytes());
    rig.ok(0x6081, 0, &600u32.to_le_bytes());
    pdo2_async(&mut rig);
    rig.enable();
    rig.tlc().inject_block(true);
    // 600 rpm against a blocked axis for 0.7 s: the following error grows past the default
    // 16384 inc, and the 131072 written above holds.
    rig.send(&["301#5F00A0860100", "301#4F00A0860100"], 700 * MS);
    assert!(rig.tlc().faults().is_empty(), "{:?}", rig.tlc().faults());
    assert_eq!(rig.tlc().drive_state(), State::OperationEnabled);
    let peak = rig.tlc().od().get_u32(Address::new(0x2013, 0)).unwrap();
    assert!(peak > 16_384, "p_DifPeak {peak}");
    // Back to the default: the next tick faults.
    rig.ok(0x2010, 0, &16_384u32.to_le_bytes());
    rig.run_for(5 * MS);
    assert_eq!(rig.tlc().faults(), &[TlcFault::FollowingError]);
    assert_eq!(rig.tlc().drive_state(), State::Fault);
}

#[test]
fn following_error_of_class_1_only_warns() {
    let mut rig = Rig::node1();
    rig.run_for(MS);
    rig.ok(0x204F, 0, &1u16.to_le_bytes()); // Flt_pDiff = 1
    rig.ok(0x6081, 0, &600u32.to_le_bytes());
    pdo2_async(&mut rig);
    rig.enable();
    rig.tlc().inject_block(true);
    rig.send(&["301#5F00A0860100", "301#4F00A0860100"], 800 * MS);
    assert_eq!(rig.tlc().drive_state(), State::OperationEnabled);
    assert_eq!(rig.tlc().faults(), &[TlcFault::FollowingError]);
    // Warning (bit 7) and following error (bit 13); the move was dropped.
    assert_eq!(rig.sw() & 0x20A7, 0x20A7);
    assert!(rig.tlc().axis().status().standstill);
    // A fault-reset edge clears the warning without leaving Operation enable.
    rig.tlc().inject_block(false);
    rig.send(&["201#8F00", "201#0F00"], 3 * MS);
    assert!(rig.tlc().faults().is_empty());
    assert_eq!(rig.tlc().drive_state(), State::OperationEnabled);
    assert_eq!(rig.sw() & 0x20A7, 0x0027);
}
