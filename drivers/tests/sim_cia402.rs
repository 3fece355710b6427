//! The generic CiA 402 drive simulator against a CANopen master on the in-process virtual bus,
//! in virtual time: each mode end to end over CAN frames (`plcopen-and-cia402-csp.md` §6–§10).
#![cfg(feature = "std")]

use std::collections::VecDeque;
use std::time::Duration;

use drivers::can::station::{self, Station, Steppable};
use drivers::can::{Bus, Frame, VirtualBus, VirtualBusConfig, VirtualPort};
use drivers::canopen::eds::Eds;
use drivers::canopen::eds_write::{DeviceInfo, write_eds};
use drivers::canopen::endpoint::Endpoint;
use drivers::canopen::master::{Master, Supervision};
use drivers::canopen::nmt::{NmtCommand, NmtTarget};
use drivers::canopen::od::{DataType, TypeClass};
use drivers::canopen::sdo::{AbortedBy, DownloadMode, SdoError};
use drivers::canopen::{AbortCode, Address, NodeId};
use drivers::cia402::modes::OperationMode;
use drivers::cia402::state::State;
use drivers::sim::axis::SwitchZone;
use drivers::sim::cia402_drive::{Cia402Config, Cia402Drive, Cia402Fault, EdsRefusal};
use drivers::time::Instant;

const MS: Duration = Duration::from_millis(1);

/// The master side: a CANopen [`Master`] plus raw frames the test scripts.
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
    drive: Station<VirtualPort, Box<Cia402Drive>>,
    monitor: VirtualPort,
    log: Vec<Frame>,
}

fn node(n: u8) -> NodeId {
    NodeId::new(n).unwrap()
}

fn f(s: &str) -> Frame {
    s.parse().unwrap()
}

/// RPDO1 data: controlword then a little-endian value of `bytes` bytes.
fn rpdo(cw: u16, value: i64, bytes: usize) -> Frame {
    let mut d = cw.to_le_bytes().to_vec();
    d.extend_from_slice(&value.to_le_bytes()[..bytes]);
    Frame::new_std(0x201, &d).unwrap()
}

fn abort(code: AbortCode) -> Result<(), SdoError> {
    Err(SdoError::Aborted {
        code,
        by: AbortedBy::Server,
    })
}

impl Rig {
    fn with(build: impl FnOnce(Instant) -> Cia402Drive) -> Rig {
        let bus = VirtualBus::new(VirtualBusConfig::default()).unwrap();
        let monitor = bus.attach_monitor("monitor");
        let mut master = Master::new(Default::default(), true);
        master
            .add_node(node(1), Supervision::None, bus.now())
            .unwrap();
        let host = Station::new(
            bus.attach("host"),
            Host {
                master,
                raw: VecDeque::new(),
            },
        );
        let drive = Station::new(bus.attach("drive"), Box::new(build(bus.now())));
        let mut rig = Rig {
            bus,
            host,
            drive,
            monitor,
            log: Vec::new(),
        };
        rig.run_for(MS);
        rig
    }

    fn new(cfg: Cia402Config) -> Rig {
        Rig::with(|now| Cia402Drive::new(cfg, now).unwrap())
    }

    fn node1() -> Rig {
        Rig::new(Cia402Config::new(node(1)))
    }

    fn d(&mut self) -> &mut Cia402Drive {
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

    fn send(&mut self, frames: &[Frame], d: Duration) {
        self.host.endpoint.raw.extend(frames.iter().copied());
        self.run_for(d);
    }

    fn frames(&self, id: u16, from: usize) -> Vec<Frame> {
        self.log[from..]
            .iter()
            .filter(|fr| fr.cob_id() == Some(id) && !fr.is_remote())
            .copied()
            .collect()
    }

    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoError> {
        let n = node(1);
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

    fn read(&mut self, index: u16, sub: u8) -> Vec<u8> {
        let n = node(1);
        self.host
            .endpoint
            .master
            .sdo(n)
            .unwrap()
            .upload(Address::new(index, sub))
            .unwrap();
        let mut out = None;
        self.run_until(100 * MS, |r| {
            if let Some(e) = r.host.endpoint.master.poll_sdo_event(n) {
                out = Some(e.to_vec());
                true
            } else {
                false
            }
        });
        out.expect("an SDO answer")
            .unwrap_or_else(|e| panic!("{index:04X}:{sub:02X}: {e}"))
    }

    fn read_u32(&mut self, index: u16, sub: u8) -> u32 {
        let v = self.read(index, sub);
        let mut b = [0u8; 4];
        b[..v.len().min(4)].copy_from_slice(&v[..v.len().min(4)]);
        u32::from_le_bytes(b)
    }

    fn nmt_start(&mut self) {
        self.host
            .endpoint
            .master
            .nmt(NmtCommand::Start, NmtTarget::All)
            .unwrap();
        self.run_for(2 * MS);
    }

    fn sw(&mut self) -> u16 {
        self.d().statusword()
    }

    /// NMT start, then Shutdown and Enable operation on the power-up RPDO1 (controlword only).
    fn enable(&mut self) {
        self.nmt_start();
        self.send(&[f("201#0600"), f("201#0F00")], 3 * MS);
        assert_eq!(self.d().drive_state(), State::OperationEnabled);
    }

    /// Maps RPDO1 to `rx` and TPDO1 to `tx`, both synchronous (type 1), the CiA 301 way:
    /// invalidate, sub00 = 0, entries, sub00 = count, validate; reads every value back.
    fn remap(&mut self, rx: &[u32], tx: &[u32]) {
        for (comm, map, cob, entries) in
            [(0x1400, 0x1600, 0x201u32, rx), (0x1800, 0x1A00, 0x181, tx)]
        {
            self.ok(comm, 1, &(cob | 0x8000_0000).to_le_bytes());
            self.ok(map, 0, &[0]);
            for (i, e) in entries.iter().enumerate() {
                self.ok(map, i as u8 + 1, &e.to_le_bytes());
            }
            self.ok(map, 0, &[entries.len() as u8]);
            self.ok(comm, 2, &[1]);
            self.ok(comm, 1, &cob.to_le_bytes());
            assert_eq!(self.read(map, 0), vec![entries.len() as u8]);
            for (i, e) in entries.iter().enumerate() {
                assert_eq!(self.read_u32(map, i as u8 + 1), *e, "{map:04X}:{}", i + 1);
            }
            assert_eq!(self.read(comm, 2), vec![1]);
            assert_eq!(self.read_u32(comm, 1), cob);
        }
    }

    /// One cycle of a cyclic master: the RPDO, then the SYNC, then 1 ms; the TPDO1 that
    /// followed the SYNC.
    fn cycle(&mut self, rpdo: Frame) -> Option<Frame> {
        let from = self.log.len();
        self.send(&[rpdo, f("080#")], MS);
        self.frames(0x181, from).last().copied()
    }

    /// A drive in `mode` (8, 9, 10) with RPDO1 = controlword + `setpoint`, TPDO1 = statusword
    /// + 6064h, 60C2h = 1 ms, enabled through the cyclic RPDO with a set-point `hold`.
    fn cyclic(&mut self, mode: i8, setpoint: u32, hold: i64) {
        let bytes = (setpoint & 0xFF) as usize / 8;
        self.remap(&[0x6040_0010, setpoint], &[0x6041_0010, 0x6064_0020]);
        self.ok(0x60C2, 1, &[1]);
        self.ok(0x60C2, 2, &[(-3i8) as u8]);
        self.ok(0x6060, 0, &[mode as u8]);
        self.nmt_start();
        for cw in [0x06, 0x0F, 0x0F, 0x0F] {
            self.cycle(rpdo(cw, hold, bytes));
        }
        assert_eq!(self.d().drive_state(), State::OperationEnabled);
        assert_eq!(self.d().mode().code(), mode);
        assert_eq!(self.sw() & 0x1000, 0x1000, "drive follows (bit 12)");
    }
}

fn sw_of(tpdo: &Frame) -> u16 {
    u16::from_le_bytes([tpdo.data()[0], tpdo.data()[1]])
}
fn pos_of(tpdo: &Frame) -> i64 {
    i32::from_le_bytes(tpdo.data()[2..6].try_into().unwrap()) as i64
}

#[test]
fn boot_identity_and_the_default_dictionary() {
    let mut rig = Rig::node1();
    assert_eq!(rig.log[0], f("701#00"));
    assert_eq!(rig.read_u32(0x1000, 0), 0x0002_0192);
    assert_eq!(rig.read_u32(0x1018, 1), 0);
    assert_eq!(rig.read_u32(0x1018, 2), 0x402);
    assert_eq!(rig.read_u32(0x6502, 0), 0x03A5);
    // CiA 402-3 default mappings.
    assert_eq!(rig.read_u32(0x1600, 1), 0x6040_0010);
    assert_eq!(rig.read_u32(0x1601, 2), 0x6060_0008);
    assert_eq!(rig.read_u32(0x1602, 2), 0x607A_0020);
    assert_eq!(rig.read_u32(0x1603, 2), 0x60FF_0020);
    assert_eq!(rig.read_u32(0x1A00, 1), 0x6041_0010);
    assert_eq!(rig.read_u32(0x1A01, 2), 0x6061_0008);
    assert_eq!(rig.read_u32(0x1A02, 2), 0x6064_0020);
    assert_eq!(rig.read_u32(0x1A03, 2), 0x606C_0020);
    assert_eq!(rig.read(0x1008, 0), b"CiA 402 drive".to_vec());
}

#[test]
fn a_mode_outside_6502h_is_refused() {
    let mut rig = Rig::node1();
    for refused in [2u8, 4, 7, 11, 0xFF] {
        assert_eq!(
            rig.write(0x6060, 0, &[refused]),
            abort(AbortCode::InvalidValue),
            "mode {refused}"
        );
    }
    for accepted in [1u8, 3, 6, 8, 9, 10] {
        rig.ok(0x6060, 0, &[accepted]);
        rig.run_for(MS);
        assert_eq!(rig.read(0x6061, 0), vec![accepted], "6061h follows 6060h");
    }
    // Homing methods: only those of the profile.
    assert_eq!(rig.write(0x6098, 0, &[1]), abort(AbortCode::InvalidValue));
    rig.ok(0x6098, 0, &[17]);
    // RPDO2 (controlword + 6060h) has no SDO check: a mode outside 6502h is ignored.
    rig.ok(0x1401, 1, &0x301u32.to_le_bytes());
    rig.nmt_start();
    rig.send(&[f("301#000004")], 2 * MS);
    assert_eq!(rig.d().mode(), OperationMode::CyclicSyncTorque);
    rig.send(&[f("301#000009")], 2 * MS);
    assert_eq!(rig.d().mode(), OperationMode::CyclicSyncVelocity);
}

#[test]
fn pdo1_remapped_for_csp_with_read_back() {
    let mut rig = Rig::node1();
    // CiA 301: the mapping changes only while the PDO is invalid, and its entries only while
    // sub00 = 0.
    assert_eq!(
        rig.write(0x1600, 0, &[0]),
        abort(AbortCode::UnsupportedAccess)
    );
    assert_eq!(
        rig.write(0x1A00, 0, &[0]),
        abort(AbortCode::UnsupportedAccess)
    );
    rig.ok(0x1401, 1, &0x8000_0301u32.to_le_bytes());
    assert_eq!(
        rig.write(0x1601, 1, &0x607A_0020u32.to_le_bytes()),
        abort(AbortCode::UnsupportedAccess)
    );
    rig.ok(0x1601, 0, &[0]);
    // The identifier changes only while the PDO is invalid.
    assert_eq!(
        rig.write(0x1400, 1, &0x202u32.to_le_bytes()),
        abort(AbortCode::InvalidValue)
    );
    rig.remap(&[0x6040_0010, 0x607A_0020], &[0x6041_0010, 0x6064_0020]);
    // More than 64 bits of mapping is refused.
    rig.ok(0x1400, 1, &0x8000_0201u32.to_le_bytes());
    rig.ok(0x1600, 0, &[0]);
    for s in 3..=4 {
        rig.ok(0x1600, s, &0x607A_0020u32.to_le_bytes());
    }
    assert!(rig.write(0x1600, 0, &[4]).is_err());
}

#[test]
fn profile_position_move() {
    let mut rig = Rig::node1();
    rig.ok(0x607A, 0, &20_000i32.to_le_bytes());
    rig.ok(0x6081, 0, &100_000u32.to_le_bytes());
    rig.enable();
    rig.send(&[f("201#1F00")], 2 * MS);
    assert_eq!(rig.sw() & 0x1000, 0x1000, "set-point acknowledged");
    rig.send(&[f("201#0F00")], 2 * MS);
    assert!(
        rig.run_until(2000 * MS, |r| r.sw() & 0x1400 == 0x0400),
        "target reached"
    );
    // The position loop settles onto the last increment.
    rig.run_for(100 * MS);
    assert_eq!(rig.d().actual(), 20_000);
    assert_eq!(rig.read_u32(0x6064, 0), 20_000);
}

#[test]
fn profile_velocity() {
    let mut rig = Rig::node1();
    rig.ok(0x6060, 0, &[3]);
    rig.enable();
    rig.ok(0x60FF, 0, &50_000i32.to_le_bytes());
    assert!(
        rig.run_until(500 * MS, |r| r.sw() & 0x0400 != 0),
        "velocity reached"
    );
    let v = rig.read_u32(0x606C, 0) as i32;
    assert!((49_000..=51_000).contains(&v), "{v}");
    rig.ok(0x60FF, 0, &0i32.to_le_bytes());
    assert!(rig.run_until(500 * MS, |r| r.sw() & 0x1000 != 0), "speed 0");
}

#[test]
fn homing_35_sets_the_home_offset_here() {
    let mut rig = Rig::node1();
    rig.ok(0x6060, 0, &[6]);
    rig.ok(0x6098, 0, &[35]);
    rig.ok(0x607C, 0, &1234i32.to_le_bytes());
    rig.enable();
    rig.send(&[f("201#1F00")], 5 * MS);
    assert_eq!(rig.sw() & 0x3400, 0x1400, "homing attained");
    assert_eq!(rig.d().actual(), 1234);
    assert!(rig.d().referenced());
}

#[test]
fn homing_17_on_the_negative_limit_switch() {
    let mut cfg = Cia402Config::new(node(1));
    cfg.environment.limit_negative = Some(SwitchZone {
        from: -1_000_000,
        to: -20_000,
    });
    let mut rig = Rig::new(cfg);
    rig.ok(0x6060, 0, &[6]);
    rig.ok(0x6098, 0, &[17]);
    rig.enable();
    rig.send(&[f("201#1F00")], 2 * MS);
    assert!(
        rig.run_until(5000 * MS, |r| r.sw() & 0x3400 != 0),
        "homing ended"
    );
    assert_eq!(rig.sw() & 0x3400, 0x1400, "homing attained");
    // Home is the switch's edge, at 607Ch = 0; the axis stopped just past it.
    let raw = rig.d().axis().raw_position();
    assert!((-20_000..=-19_000).contains(&raw), "raw {raw}");
    assert!(rig.d().actual().abs() < 1000, "{}", rig.d().actual());
    assert!(rig.d().faults().is_empty());
}

/// A trapezoid of `distance` at `v` inc/s and `acc` inc/s², sampled at `t` seconds.
fn trapezoid(distance: f64, v: f64, acc: f64, t: f64) -> f64 {
    let ta = v / acc;
    let da = 0.5 * acc * ta * ta;
    let tc = (distance - 2.0 * da) / v;
    if t <= 0.0 {
        0.0
    } else if t < ta {
        0.5 * acc * t * t
    } else if t < ta + tc {
        da + v * (t - ta)
    } else if t < 2.0 * ta + tc {
        let r = 2.0 * ta + tc - t;
        distance - 0.5 * acc * r * r
    } else {
        distance
    }
}

#[test]
fn csp_follows_a_path_within_the_computed_following_error() {
    let cfg = Cia402Config::new(node(1));
    let mut rig = Rig::new(cfg);
    rig.cyclic(8, 0x607A_0020, 0);
    let (distance, v, acc) = (100_000.0, 200_000.0, 2_000_000.0);
    // The bound from the axis model: the reference reaches p_cmd(k−1) at SYNC k (the path
    // stays inside 607Fh and the acceleration limit, so no limit cuts it); the position loop,
    // a first-order lag of time constant τ stepped every tick, lags a ramp of velocity v by
    // v·(τ − tick) and never by more than v·τ; 2 increments of rounding.
    let tau = cfg.position_time_constant.as_secs_f64();
    let tick = cfg.tick.as_secs_f64();
    let bound = (v * tau).ceil() as i64 + 2;
    let mut cmds = vec![0i64];
    let mut worst = 0i64;
    let mut k = 0;
    loop {
        k += 1;
        let cmd = trapezoid(distance, v, acc, k as f64 * 1e-3).round() as i64;
        let t = rig.cycle(rpdo(0x0F, cmd, 4)).expect("a TPDO every SYNC");
        let e = cmds[k - 1] - pos_of(&t);
        worst = worst.max(e.abs());
        assert_eq!(sw_of(&t) & 0x306F, 0x1027, "following, no error, cycle {k}");
        cmds.push(cmd);
        if k > 650 {
            break;
        }
    }
    assert!(worst <= bound, "worst following error {worst} > {bound}");
    // The bound is tight: the lag at cruise is v·(τ − tick).
    assert!(worst as f64 >= v * (tau - tick) - 2.0, "worst {worst}");
    assert_eq!(rig.d().actual(), 100_000);
    assert_eq!(rig.read_u32(0x60F4, 0) as i32, 0);
}

#[test]
fn csv_follows_the_velocity_setpoint() {
    let mut rig = Rig::node1();
    rig.cyclic(9, 0x60FF_0020, 0);
    let mut last = None;
    for _ in 0..50 {
        last = rig.cycle(rpdo(0x0F, 100_000, 4));
    }
    let v = rig.d().axis().status().velocity;
    assert!((99_000..=101_000).contains(&v), "{v}");
    assert_eq!(sw_of(&last.unwrap()) & 0x1000, 0x1000);
    // The velocity offset 60B1h adds.
    rig.ok(0x60B1, 0, &(-50_000i32).to_le_bytes());
    for _ in 0..50 {
        rig.cycle(rpdo(0x0F, 100_000, 4));
    }
    let v = rig.d().axis().status().velocity;
    assert!((49_000..=51_000).contains(&v), "{v}");
}

#[test]
fn cst_accelerates_the_inertia_with_the_clamped_torque() {
    let cfg = Cia402Config::new(node(1));
    let mut rig = Rig::new(cfg);
    rig.ok(0x6072, 0, &500u16.to_le_bytes());
    rig.cyclic(10, 0x6071_0010, 0);
    // 100 ‰ of rated torque: a tenth of the rated acceleration.
    for _ in 0..50 {
        rig.cycle(rpdo(0x0F, 100, 2));
    }
    let expect = cfg.rated_acceleration as f64 * 0.1 * 0.05;
    let v = rig.d().axis().status().velocity as f64;
    assert!((v - expect).abs() < expect * 0.05, "{v} vs {expect}");
    assert_eq!(rig.read(0x6077, 0), 100i16.to_le_bytes().to_vec());
    // 2000 ‰ asked, 6072h = 500 ‰ applied.
    let v0 = rig.d().axis().status().velocity as f64;
    for _ in 0..20 {
        rig.cycle(rpdo(0x0F, 2000, 2));
    }
    let dv = rig.d().axis().status().velocity as f64 - v0;
    let expect = cfg.rated_acceleration as f64 * 0.5 * 0.02;
    assert!((dv - expect).abs() < expect * 0.1, "{dv} vs {expect}");
    assert_eq!(rig.read(0x6077, 0), 500i16.to_le_bytes().to_vec());
}

#[test]
fn csv_and_cst_brake_to_a_stop_at_the_software_limits() {
    for (mode, setpoint, bytes, push, back) in [
        (9, 0x60FF_0020, 4, 200_000, -50_000),
        (10, 0x6071_0010, 2, 300, -300),
    ] {
        let mut rig = Rig::node1();
        rig.ok(0x607D, 1, &(-5_000i32).to_le_bytes());
        rig.ok(0x607D, 2, &20_000i32.to_le_bytes());
        rig.cyclic(mode, setpoint, 0);
        let mut last = None;
        let mut peak = i64::MIN;
        for _ in 0..400 {
            last = rig.cycle(rpdo(0x0F, push, bytes));
            peak = peak.max(rig.d().axis().status().position);
        }
        let st = *rig.d().axis().status();
        // Stopped at the limit, not past it (the position loop may lag by a few increments).
        assert!(
            peak <= 20_010 && st.position >= 19_900,
            "mode {mode}: peak {peak}, at {}",
            st.position
        );
        assert_eq!(st.velocity, 0, "mode {mode}");
        let sw = sw_of(&last.unwrap());
        assert_eq!(sw & 0x0800, 0x0800, "mode {mode}: bit 11 internal limit");
        // Away from the limit the axis moves freely.
        for _ in 0..50 {
            rig.cycle(rpdo(0x0F, back, bytes));
        }
        let p = rig.d().axis().status().position;
        assert!(p < 19_000, "mode {mode}: moved back to {p}");
    }
}

#[test]
fn csp_following_error_faults_with_8611h() {
    let mut rig = Rig::node1();
    rig.ok(0x6065, 0, &1000u32.to_le_bytes());
    rig.ok(0x6066, 0, &5u16.to_le_bytes());
    rig.ok(0x607F, 0, &200_000u32.to_le_bytes());
    rig.cyclic(8, 0x607A_0020, 0);
    // A set-point jump the 607Fh limit cannot follow: the error exceeds the window for 5 ms.
    let from = rig.log.len();
    let mut bit13 = false;
    for _ in 0..20 {
        if let Some(t) = rig.cycle(rpdo(0x0F, 50_000, 4)) {
            bit13 |= sw_of(&t) & 0x2000 != 0;
        }
    }
    assert!(bit13, "bit 13 reported");
    assert_eq!(rig.d().faults(), &[Cia402Fault::FollowingError]);
    let emcy = rig.frames(0x081, from);
    assert_eq!(&emcy[0].data()[..2], &[0x11, 0x86]);
    assert_eq!(rig.read(0x603F, 0), vec![0x11, 0x86]);
    rig.run_for(50 * MS);
    assert_eq!(rig.d().drive_state(), State::Fault);
    // Fault reset (edge on bit 7) clears it.
    rig.cycle(rpdo(0x80, 0, 4));
    assert_eq!(rig.d().drive_state(), State::SwitchOnDisabled);
    assert!(rig.d().faults().is_empty());
}

#[test]
fn missing_syncs_hold_then_fault_with_8700h() {
    let mut rig = Rig::node1();
    rig.cyclic(8, 0x607A_0020, 0);
    for k in 1..=20 {
        rig.cycle(rpdo(0x0F, k * 100, 4));
    }
    for _ in 0..50 {
        rig.cycle(rpdo(0x0F, 2000, 4));
    }
    // No SYNC for 2 periods: the last set-point is held, no fault.
    let from = rig.log.len();
    rig.run_for(2 * MS);
    assert!(rig.d().faults().is_empty());
    assert_eq!(rig.sw() & 0x1000, 0x1000, "still following");
    rig.run_for(20 * MS);
    assert!(
        (1999..=2001).contains(&rig.d().actual()),
        "held at the last set-point"
    );
    assert_eq!(rig.d().faults(), &[Cia402Fault::SyncLost]);
    let emcy = rig.frames(0x081, from);
    assert_eq!(&emcy[0].data()[..2], &[0x00, 0x87]);
    assert_eq!(rig.d().drive_state(), State::Fault);
}

#[test]
fn halt_ramps_to_rest_and_release_follows_again() {
    let mut rig = Rig::node1();
    rig.cyclic(9, 0x60FF_0020, 0);
    for _ in 0..30 {
        rig.cycle(rpdo(0x0F, 100_000, 4));
    }
    // Halt: the 6084h ramp (1 000 000 inc/s²) stops 100 000 inc/s in 100 ms.
    let mut t = None;
    for k in 0..150 {
        t = rig.cycle(rpdo(0x010F, 100_000, 4));
        if k == 50 {
            let v = rig.d().axis().status().velocity;
            assert!((40_000..=60_000).contains(&v), "on the ramp: {v}");
        }
    }
    let sw = sw_of(&t.unwrap());
    assert_eq!(
        sw & 0x146F,
        0x0427,
        "Operation enabled, bit 12 = 0, bit 10 at rest"
    );
    assert_eq!(rig.d().axis().status().velocity, 0);
    for _ in 0..5 {
        t = rig.cycle(rpdo(0x0F, 100_000, 4));
    }
    assert_eq!(sw_of(&t.unwrap()) & 0x1400, 0x1000, "following again");
}

#[test]
fn quick_stop_per_605ah() {
    // 605Ah = 2 (default): the 6085h ramp, then Switch on disabled.
    let mut rig = Rig::node1();
    rig.cyclic(9, 0x60FF_0020, 0);
    for _ in 0..30 {
        rig.cycle(rpdo(0x0F, 100_000, 4));
    }
    rig.cycle(rpdo(0x0B, 100_000, 4));
    assert_eq!(rig.d().drive_state(), State::QuickStopActive);
    assert_eq!(rig.sw() & 0x1000, 0, "set-point ignored");
    for _ in 0..40 {
        rig.cycle(rpdo(0x0B, 100_000, 4));
    }
    assert_eq!(rig.d().drive_state(), State::SwitchOnDisabled);
    // 605Ah = 6: stays in Quick stop active; Enable operation resumes (transition 16).
    let mut rig = Rig::node1();
    rig.ok(0x605A, 0, &6i16.to_le_bytes());
    rig.cyclic(9, 0x60FF_0020, 0);
    for _ in 0..30 {
        rig.cycle(rpdo(0x0F, 100_000, 4));
    }
    for _ in 0..40 {
        rig.cycle(rpdo(0x0B, 100_000, 4));
    }
    assert_eq!(rig.d().drive_state(), State::QuickStopActive);
    assert_eq!(rig.d().axis().status().velocity, 0);
    rig.cycle(rpdo(0x0F, 100_000, 4));
    assert_eq!(rig.d().drive_state(), State::OperationEnabled);
    for _ in 0..5 {
        rig.cycle(rpdo(0x0F, 100_000, 4));
    }
    assert_eq!(rig.sw() & 0x1000, 0x1000);
}

#[test]
fn late_synchronous_rpdos_are_dropped() {
    let mut rig = Rig::node1();
    rig.cyclic(8, 0x607A_0020, 0);
    rig.ok(0x1007, 0, &400u32.to_le_bytes());
    let us = Duration::from_micros;
    // Inside the 400 µs window after its SYNC: taken at the next SYNC.
    rig.send(&[f("080#")], us(100));
    rig.send(&[rpdo(0x0F, 300, 4)], us(900));
    // 600 µs after its SYNC: dropped, the next SYNC keeps 300.
    rig.send(&[f("080#")], us(500));
    rig.send(&[rpdo(0x0F, 900, 4)], us(500));
    for _ in 0..100 {
        rig.send(&[f("080#")], MS);
    }
    assert_eq!(rig.d().late_rpdos_dropped(), 1);
    assert_eq!(rig.d().actual(), 300);
}

// ---- EDS ---------------------------------------------------------------------------------

fn default_eds(n: NodeId) -> String {
    let d = Cia402Drive::new(Cia402Config::new(n), Instant::ZERO).unwrap();
    let info = DeviceInfo {
        file_name: "cia402.eds",
        description: "generic CiA 402 drive",
        vendor_name: "any",
        product_name: "CiA 402 drive",
        baud_rates_kbit: &[125, 250, 500, 1000],
        lss: false,
        created_by: "sim_cia402",
    };
    write_eds(d.od(), n, &info)
}

fn leak(text: &str, n: NodeId) -> &'static Eds {
    Box::leak(Box::new(Eds::parse(text, Some(n)).unwrap()))
}

fn comparable(dt: DataType, raw: &[u8]) -> Vec<u8> {
    if dt == DataType::VisibleString {
        let end = raw.iter().position(|&b| b == 0).unwrap_or(raw.len());
        raw[..end].to_vec()
    } else {
        raw.to_vec()
    }
}

#[test]
fn the_default_eds_reads_back_into_the_same_dictionary() {
    let n = node(5);
    let text = default_eds(n);
    let built = Cia402Drive::new(Cia402Config::new(n), Instant::ZERO).unwrap();
    let loaded = Cia402Drive::from_eds(Cia402Config::new(n), leak(&text, n), Instant::ZERO)
        .unwrap_or_else(|e| panic!("{e}"));
    let (a, b) = (built.od(), loaded.od());
    assert_eq!(a.len(), b.len());
    for e in a.entries() {
        let g = b
            .entry(e.addr)
            .unwrap_or_else(|_| panic!("{} missing", e.addr));
        assert_eq!(
            (g.name, g.data_type, g.access, g.pdo_mappable),
            (e.name, e.data_type, e.access, e.pdo_mappable),
            "{}",
            e.addr
        );
        if !matches!(e.data_type.class(), TypeClass::Bytes) {
            assert_eq!((&g.low, &g.high), (&e.low, &e.high), "{} limits", e.addr);
        }
        assert_eq!(
            comparable(e.data_type, b.raw(e.addr).unwrap()),
            comparable(e.data_type, a.raw(e.addr).unwrap()),
            "{} value",
            e.addr
        );
    }
    // At another node-ID the COB-IDs follow.
    let m = node(9);
    let other = Cia402Drive::from_eds(Cia402Config::new(m), leak(&text, m), Instant::ZERO).unwrap();
    assert_eq!(other.od().get_u32(Address::new(0x1800, 1)), Ok(0x189));
}

#[test]
fn an_eds_narrows_the_modes_and_gives_the_identity() {
    let n = node(1);
    let text = default_eds(n)
        .replace("DefaultValue=0x3A5", "DefaultValue=0x380")
        .replace(
            "ParameterName=product code\nObjectType=0x7\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x402",
            "ParameterName=product code\nObjectType=0x7\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x1234",
        );
    let eds = leak(&text, n);
    let mut rig = Rig::with(|now| Cia402Drive::from_eds(Cia402Config::new(n), eds, now).unwrap());
    assert_eq!(rig.read_u32(0x1018, 2), 0x1234);
    assert_eq!(rig.write(0x6060, 0, &[1]), abort(AbortCode::InvalidValue));
    rig.ok(0x6060, 0, &[8]);
    rig.run_for(MS);
    assert_eq!(rig.d().mode(), OperationMode::CyclicSyncPosition);
}

#[test]
fn an_eds_without_what_the_simulator_needs_is_refused_by_name() {
    let n = node(1);
    let text = default_eds(n);
    // Without 60FFh: profile velocity and CSV need it.
    let start = text.find("[60FF]").unwrap();
    let end = start + text[start..].find("\n\n").unwrap() + 2;
    let cut = format!("{}{}", &text[..start], &text[end..]).replace("60FF\n", "");
    let cut = cut.replace("=0x60FF\n", "=0x60FE\n");
    let eds = Eds::parse(&cut, Some(n));
    let err = match eds {
        Ok(e) => {
            match Cia402Drive::from_eds(Cia402Config::new(n), Box::leak(Box::new(e)), Instant::ZERO)
            {
                Err(e) => e,
                Ok(_) => panic!("accepted an EDS without 60FFh"),
            }
        }
        Err(e) => panic!("the cut EDS does not parse: {e}"),
    };
    assert!(
        matches!(err, EdsRefusal::Missing { index: 0x60FF, .. }),
        "{err}"
    );
    assert!(err.to_string().contains("60FFh"), "{err}");
    // Not a CiA 402 device.
    let text = default_eds(n).replace("DefaultValue=0x20192", "DefaultValue=0x20191");
    let err = Cia402Drive::from_eds(Cia402Config::new(n), leak(&text, n), Instant::ZERO)
        .err()
        .unwrap();
    assert_eq!(err, EdsRefusal::NotCia402(0x20191));
}

// ---- no_std --------------------------------------------------------------------------------

#[test]
fn the_simulator_builds_without_std() {
    let target = "thumbv7em-none-eabihf";
    let installed = std::process::Command::new("rustup")
        .args(["target", "list", "--installed"])
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).contains(target))
        .unwrap_or(false);
    if !installed {
        assert!(
            std::env::var_os("MOTION_REQUIRE_ALL").is_none(),
            "the {target} target is required"
        );
        eprintln!("SKIPPED the no_std build: rustup target add {target}");
        return;
    }
    // Its own target directory: the build must not wait on the lock of the one running us.
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("nostd");
    let out = std::process::Command::new(env!("CARGO"))
        .args([
            "build",
            "-p",
            "drivers",
            "--no-default-features",
            "--target",
            target,
        ])
        .env("CARGO_TARGET_DIR", &dir)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("cargo runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn disable_operation_ramps_per_605ch_and_a_node_reset_restores_the_defaults() {
    let mut rig = Rig::node1();
    rig.cyclic(9, 0x60FF_0020, 0);
    for _ in 0..30 {
        rig.cycle(rpdo(0x0F, 100_000, 4));
    }
    // 605Ch = 1 (default): Switched on at once, the 6084h ramp, then the power stage off.
    rig.cycle(rpdo(0x07, 100_000, 4));
    assert_eq!(rig.d().drive_state(), State::SwitchedOn);
    assert_eq!(rig.sw() & 0x1000, 0, "set-point ignored");
    for _ in 0..20 {
        rig.cycle(rpdo(0x07, 100_000, 4));
    }
    let v = rig.d().axis().status().velocity;
    assert!(
        rig.d().axis().is_enabled() && v > 50_000 && v < 100_000,
        "{v}"
    );
    for _ in 0..150 {
        rig.cycle(rpdo(0x07, 100_000, 4));
    }
    assert!(!rig.d().axis().is_enabled());
    assert_eq!(rig.d().axis().status().velocity, 0);
    // NMT reset node: boot-up, defaults again (PP, 60C2h = 1 ms, PDO1 = 6040h / 6041h).
    let from = rig.log.len();
    rig.send(&[f("000#8101")], 5 * MS);
    assert_eq!(rig.frames(0x701, from), vec![f("701#00")]);
    assert_eq!(rig.d().drive_state(), State::SwitchOnDisabled);
    assert_eq!(rig.d().mode(), OperationMode::ProfilePosition);
    assert_eq!(rig.read(0x6061, 0), vec![1]);
    assert_eq!(rig.read_u32(0x1600, 1), 0x6040_0010);
    assert_eq!(rig.read(0x1600, 0), vec![1]);
}

#[test]
fn a_profile_position_target_is_clipped_into_607dh() {
    let mut rig = Rig::node1();
    rig.ok(0x607D, 2, &5_000i32.to_le_bytes());
    rig.ok(0x607A, 0, &20_000i32.to_le_bytes());
    rig.enable();
    rig.send(&[f("201#1F00"), f("201#0F00")], 2 * MS);
    assert!(
        rig.run_until(2000 * MS, |r| r.sw() & 0x1400 == 0x0400),
        "target reached"
    );
    rig.run_for(100 * MS);
    assert_eq!(rig.d().actual(), 5_000);
}
