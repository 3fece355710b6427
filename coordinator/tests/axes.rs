//! The master-side axis state machines against the real drive simulators, in virtual time: an
//! FHPP axis driving `sim::fhpp_drive::FhppDrive` (MTR-DCI, CMMO-ST) image by image, and a
//! CiA 402 axis driving the TLC5xx simulator through its PDOs.

use core::time::Duration;

use coordinator::axis::{
    AxisState, Demand, DeviceKind, DriveAxis, Feedback, Image, PointMove, Profile,
};
use coordinator::profile::{AxisLimits, Trapezoid};
use drivers::fhpp::Variant;
use drivers::fhpp::pnu::record_subindex;
use drivers::sim::fhpp_drive::{DriveConfig, FhppDrive, Injection};
use drivers::time::Instant;

// ---- FHPP ------------------------------------------------------------------------------------

/// One coordinator cycle per step: the drive's last image in, the axis' output back, the drive
/// advanced to the next cycle in between.
struct FhppRig {
    drive: FhppDrive,
    axis: DriveAxis,
    t: Instant,
    cycle: Duration,
    out: Image,
    fb: Feedback,
    /// CPOS.START rising edges sent.
    starts: u64,
}

impl FhppRig {
    /// A rig for `variant`, the coordinator cycle twice the drive's internal cycle.
    fn new(variant: Variant) -> FhppRig {
        let cfg = DriveConfig::new(variant);
        let cycle = cfg.cycle * 2;
        let mut drive = FhppDrive::new(cfg).unwrap();
        drive.start_at(Instant::ZERO);
        if variant != Variant::MtrDci {
            // Direct start condition "interrupt": a START while moving retargets (the boot
            // writes PNU 583 = 1 on these drives).
            drive.set_pnu(583, 1, 1).unwrap();
        }
        let kind = match variant {
            Variant::MtrDci => DeviceKind::MtrDci,
            Variant::Emca => DeviceKind::Emca,
            Variant::CmmoSt => DeviceKind::CmmoSt,
        };
        let axis = DriveAxis::new(kind, Profile::Fhpp, cycle.as_nanos() as u32).unwrap();
        FhppRig {
            drive,
            axis,
            t: Instant::ZERO,
            cycle,
            out: Image::default(),
            fb: Feedback::default(),
            starts: 0,
        }
    }

    fn step(&mut self, d: Demand) -> Feedback {
        self.t += self.cycle;
        self.drive.step_to(self.t);
        let input = self.drive.input();
        let was = self.out.data[1] & 0x02;
        self.fb = *self.axis.exchange(Some(&input), &d, &mut self.out).unwrap();
        if was == 0 && self.out.data[1] & 0x02 != 0 {
            self.starts += 1;
        }
        self.drive.exchange(&self.out.data, self.t);
        self.fb
    }

    /// Repeats `d` until `pred` holds; panics after `max_ms`.
    fn until(&mut self, d: Demand, max_ms: u64, pred: impl Fn(&Feedback) -> bool) -> Feedback {
        let end = self.t + Duration::from_millis(max_ms);
        while self.t < end {
            let fb = self.step(d);
            if pred(&fb) {
                return fb;
            }
        }
        panic!("{d:?}: not reached within {max_ms} ms, last {:?}", self.fb);
    }

    fn done(&mut self, d: Demand, max_ms: u64) -> Feedback {
        self.until(d, max_ms, |f| f.done)
    }

    /// Repeats `d` for `ms`.
    fn run(&mut self, d: Demand, ms: u64) -> Feedback {
        let end = self.t + Duration::from_millis(ms);
        while self.t < end {
            self.step(d);
        }
        self.fb
    }

    fn actual(&self) -> i64 {
        self.drive.axis().status().position
    }
}

/// Enable, home, a streamed trapezoid, a record, a fault acknowledged, a quick stop.
fn fhpp_scenario(variant: Variant) {
    let mut r = FhppRig::new(variant);
    let fb = r.done(Demand::Standstill, 100);
    assert_eq!(fb.state, AxisState::Ready);
    assert_eq!(fb.position, r.actual());
    assert!(!fb.homed);

    let fb = r.done(Demand::Home, 30_000);
    assert!(fb.homed && fb.motion_complete, "{fb:?}");
    assert!(r.drive.is_referenced());
    assert_eq!(fb.state, AxisState::Ready);

    // A trapezoid streamed as direct-mode targets: the axis follows it and reports motion
    // complete only once the drive stands on the final target.
    let start = r.step(Demand::Standstill).position;
    let target = start + 60_000;
    let limits = AxisLimits::new(50_000, 200_000, 0);
    let ramp = Trapezoid::plan(start, target, limits, r.cycle.as_nanos() as u32).unwrap();
    let n = ramp.duration_cycles();
    let starts = r.starts;
    let mut worst_lag = 0;
    for k in 1..=n {
        let s = ramp.sample(k);
        let fb = r.step(Demand::Follow {
            position: s.position,
            velocity: s.velocity,
        });
        assert!(!fb.motion_complete, "complete at cycle {k} of {n}");
        worst_lag = worst_lag.max((s.position - r.actual()).abs());
    }
    assert!(worst_lag < 1_500, "lag {worst_lag}");
    // A fresh target every second cycle.
    assert!(
        r.starts - starts >= n / 2 - 1,
        "{} STARTs in {n} cycles",
        r.starts - starts
    );
    let last = Demand::Follow {
        position: target,
        velocity: 0,
    };
    let fb = r.until(last, 2_000, |f| f.motion_complete);
    let st = r.drive.axis().status();
    assert_eq!(
        st.setpoint, target,
        "the drive's last target is the path's end"
    );
    assert!(st.generator_done);
    assert!((fb.position - target).abs() <= 750, "{fb:?}");
    assert_eq!(fb.state, AxisState::Ready);

    // Record 1 of the drive's own table.
    let rec_target = target - 30_000;
    let sub = record_subindex(variant, 1).unwrap();
    r.drive.set_pnu(404, sub, rec_target).unwrap();
    r.drive.set_pnu(406, sub, 40_000).unwrap();
    if variant != Variant::MtrDci {
        r.drive.set_pnu(407, sub, 200_000).unwrap();
        r.drive.set_pnu(408, sub, 200_000).unwrap();
    }
    let d = Demand::DriveRecord { number: 1 };
    let fb = r.step(d);
    assert!(!fb.done);
    let fb = r.until(d, 1_000, |f| f.state == AxisState::Moving);
    assert!(!fb.motion_complete);
    let fb = r.done(d, 5_000);
    assert!(fb.motion_complete);
    assert!((fb.position - rec_target).abs() <= 750, "{fb:?}");
    assert_eq!(r.drive.axis().status().setpoint, rec_target);

    // Jog: JOGP held moves the axis on, released it stops.
    let from = r.actual();
    r.done(
        Demand::Jog {
            positive: true,
            velocity: 0,
        },
        200,
    );
    r.run(
        Demand::Jog {
            positive: true,
            velocity: 0,
        },
        300,
    );
    let fb = r.until(Demand::Standstill, 2_000, |f| f.state == AxisState::Ready);
    assert!(
        fb.position > from + 100,
        "jogged from {from} to {}",
        fb.position
    );

    // Halt in the middle of a record, then another record: the halted one is deleted first.
    let sub2 = record_subindex(variant, 2).unwrap();
    r.drive.set_pnu(404, sub2, rec_target + 200_000).unwrap();
    r.drive.set_pnu(406, sub2, 40_000).unwrap();
    if variant != Variant::MtrDci {
        r.drive.set_pnu(407, sub2, 200_000).unwrap();
        r.drive.set_pnu(408, sub2, 200_000).unwrap();
    }
    let d2 = Demand::DriveRecord { number: 2 };
    r.until(d2, 1_000, |f| f.velocity > 20_000);
    let fb = r.done(Demand::Halt, 1_000);
    assert_eq!(fb.state, AxisState::Stopping, "halted, task kept");
    assert!(r.drive.axis().status().velocity.abs() < 1_000);
    let fb = r.done(d, 10_000);
    assert!((fb.position - rec_target).abs() <= 750, "{fb:?}");

    // A fault (over-temperature) while enabled, acknowledged once the cause is gone.
    r.drive.inject(Injection::OverTemperature, true);
    let fb = r.until(Demand::Standstill, 500, |f| f.state == AxisState::Fault);
    assert!(!fb.done);
    r.drive.inject(Injection::OverTemperature, false);
    let fb = r.run(Demand::Standstill, 100);
    assert_eq!(fb.state, AxisState::Fault, "enabling does not acknowledge");
    let fb = r.done(Demand::Acknowledge, 500);
    assert_ne!(fb.state, AxisState::Fault);
    assert!(r.drive.fault_number().is_none());
    let fb = r.done(Demand::Standstill, 500);
    assert_eq!(fb.state, AxisState::Ready);

    // Quick stop in the middle of a streamed move: the drive stops in S3, then re-enables.
    let from = r.step(Demand::Standstill).position;
    let ramp = Trapezoid::plan(from, from + 100_000, limits, r.cycle.as_nanos() as u32).unwrap();
    for k in 1..=ramp.duration_cycles() / 2 {
        let s = ramp.sample(k);
        r.step(Demand::Follow {
            position: s.position,
            velocity: s.velocity,
        });
    }
    assert!(r.drive.axis().status().velocity.abs() > 10_000);
    let fb = r.done(Demand::QuickStop, 1_000);
    assert!(r.drive.axis().status().velocity.abs() < 1_000, "stopped");
    assert!(matches!(
        fb.state,
        AxisState::Stopping | AxisState::Enabling
    ));
    let fb = r.done(Demand::Standstill, 500);
    assert_eq!(fb.state, AxisState::Ready);
    assert!(fb.homed);
}

#[test]
fn fhpp_mtr_dci_enable_home_follow_record_fault_quick_stop() {
    fhpp_scenario(Variant::MtrDci);
}

#[test]
fn fhpp_cmmo_st_enable_home_follow_record_fault_quick_stop() {
    fhpp_scenario(Variant::CmmoSt);
}

#[test]
fn fhpp_emca_enable_home_follow_record_fault_quick_stop() {
    fhpp_scenario(Variant::Emca);
}

// ---- CiA 402: the TLC5xx through its PDOs ------------------------------------------------------

use coordinator::axis::pdo_mapping;
use drivers::can::Frame;
use drivers::canopen::endpoint::Endpoint;
use drivers::canopen::{FunctionCode, NodeId};
use drivers::cia402::state::State as DriveState;
use drivers::sim::axis::{Environment, Load, SwitchZone};
use drivers::sim::mtr_dci::{MtrDci, Profile as MtrProfile};
use drivers::sim::tlc5xx::{Tlc5xx, TlcConfig};

/// A CANopen drive driven directly as an endpoint: per cycle a SYNC, the synchronous TPDO1
/// it answers with, the axis, and the RPDO1 (type 1: applied at the next SYNC).
struct CoRig<E: Endpoint> {
    dev: E,
    node: NodeId,
    axis: DriveAxis,
    t: Instant,
    cycle: Duration,
    out: Image,
    fb: Feedback,
    /// Cycles whose TPDO1 was missing.
    missing: u32,
    /// Controlword bit 4 rising edges sent (new set-points, homing starts).
    set_points: u64,
    /// RPDO2 frames sent (a move's profile, for a drive that takes one set-point per move).
    profiles: u64,
}

impl<E: Endpoint> CoRig<E> {
    fn new(dev: E, node: u8, kind: DeviceKind, cycle: Duration) -> CoRig<E> {
        let axis = DriveAxis::new(kind, Profile::Cia402, cycle.as_nanos() as u32).unwrap();
        CoRig {
            dev,
            node: NodeId::new(node).unwrap(),
            axis,
            t: Instant::ZERO,
            cycle,
            out: Image::default(),
            fb: Feedback::default(),
            missing: 0,
            set_points: 0,
            profiles: 0,
        }
    }

    fn drain(&mut self) -> Vec<Frame> {
        let mut v = Vec::new();
        while let Some(f) = self.dev.poll_transmit(self.t) {
            v.push(f);
        }
        v
    }

    /// An expedited SDO download, answered with 60h.
    fn sdo(&mut self, index: u16, sub: u8, data: &[u8]) {
        let cmd = match data.len() {
            1 => 0x2F,
            2 => 0x2B,
            _ => 0x23,
        };
        let i = index.to_le_bytes();
        let mut b = [cmd, i[0], i[1], sub, 0, 0, 0, 0];
        b[4..4 + data.len()].copy_from_slice(data);
        self.drain();
        self.t += Duration::from_micros(500);
        let rx = FunctionCode::SdoRx.cob_id(self.node);
        self.dev.handle_frame(&Frame::std8(rx, b), self.t);
        let reply = self
            .drain()
            .into_iter()
            .find(|f| f.cob_id() == Some(rx - 0x80))
            .expect("SDO reply");
        assert_eq!(
            reply.data()[0],
            0x60,
            "{index:04X}:{sub} refused: {reply:?}"
        );
    }

    /// The PDO part of the coordinator's boot, from [`pdo_mapping`]: remappable PDOs are
    /// disabled, mapped and enabled again; every PDO gets its transmission type.
    fn configure_pdos(&mut self, kind: DeviceKind) {
        let map = pdo_mapping(kind, Profile::Cia402);
        let rpdo = map.rpdo.unwrap();
        let tpdo = map.tpdo.unwrap();
        assert_eq!(rpdo.len(), self.axis.tx_len());
        assert_eq!(tpdo.len(), self.axis.rx_len());
        for (spec, comm, mapping) in [(rpdo, 0x1400u16, 0x1600u16), (tpdo, 0x1800, 0x1A00)] {
            let cob = u32::from(spec.function.cob_id(self.node));
            let comm = comm + u16::from(spec.number) - 1;
            let mapping = mapping + u16::from(spec.number) - 1;
            if spec.remappable {
                self.sdo(comm, 1, &(cob | 0x8000_0000).to_le_bytes());
                self.sdo(mapping, 0, &[0]);
                for (k, e) in spec.mapping.iter().enumerate() {
                    self.sdo(mapping, k as u8 + 1, &e.to_le_bytes());
                }
                self.sdo(mapping, 0, &[spec.mapping.len() as u8]);
            }
            self.sdo(comm, 2, &[spec.transmission]);
            if spec.remappable {
                self.sdo(comm, 1, &cob.to_le_bytes());
            }
        }
    }

    fn start(&mut self) {
        self.t += Duration::from_micros(500);
        self.dev
            .handle_frame(&Frame::new_std(0x000, &[0x01, 0x00]).unwrap(), self.t);
        self.drain();
    }

    fn step(&mut self, d: Demand) -> Feedback {
        self.t += self.cycle;
        self.dev.handle_timeout(self.t);
        self.drain();
        self.dev
            .handle_frame(&Frame::new_std(0x080, &[]).unwrap(), self.t);
        let tx = FunctionCode::Tpdo(1).cob_id(self.node);
        let tpdo = self.drain().into_iter().find(|f| f.cob_id() == Some(tx));
        if tpdo.is_none() {
            self.missing += 1;
        }
        let input = tpdo.map(|f| f.data().to_vec());
        let was = self.out.data[0] & 0x10;
        self.fb = *self
            .axis
            .exchange(input.as_deref(), &d, &mut self.out)
            .unwrap();
        if was == 0 && self.out.data[0] & 0x10 != 0 {
            self.set_points += 1;
        }
        let at = self.t + Duration::from_micros(300);
        if let Some(p) = self.axis.profile_pdo() {
            // Event-driven RPDO2: applied as it arrives, before the next SYNC applies RPDO1.
            let rx2 = FunctionCode::Rpdo(2).cob_id(self.node);
            self.dev.handle_frame(&Frame::std8(rx2, p), at);
            self.profiles += 1;
        }
        let rx = FunctionCode::Rpdo(1).cob_id(self.node);
        let rpdo = Frame::new_std(rx, self.out.bytes()).unwrap();
        self.dev.handle_frame(&rpdo, at);
        self.fb
    }

    fn until(&mut self, d: Demand, max_ms: u64, pred: impl Fn(&Feedback) -> bool) -> Feedback {
        let end = self.t + Duration::from_millis(max_ms);
        while self.t < end {
            let fb = self.step(d);
            if pred(&fb) {
                return fb;
            }
        }
        panic!("{d:?}: not reached within {max_ms} ms, last {:?}", self.fb);
    }

    fn done(&mut self, d: Demand, max_ms: u64) -> Feedback {
        self.until(d, max_ms, |f| f.done)
    }

    /// Streams `ramp` (all its cycles) as `Follow`; returns the worst |path − actual| with
    /// `actual` read from the drive.
    fn stream(&mut self, ramp: &Trapezoid, cycles: u64, actual: impl Fn(&E) -> i64) -> i64 {
        let mut worst = 0;
        let n = ramp.duration_cycles();
        for k in 1..=cycles {
            let s = ramp.sample(k);
            let fb = self.step(Demand::Follow {
                position: s.position,
                velocity: s.velocity,
            });
            assert!(!fb.motion_complete, "complete at cycle {k} of {n}");
            worst = worst.max((s.position - actual(&self.dev)).abs());
        }
        worst
    }
}

/// The TLC5xx with a reference cam at 10 000..12 000 and limit switches, booted: PDO1 from
/// [`pdo_mapping`], profile velocity and ramps, homing method 23, NMT start.
fn tlc_rig() -> CoRig<Tlc5xx> {
    let mut cfg = TlcConfig::new(NodeId::new(1).unwrap());
    cfg.environment = Environment {
        travel: Some((-60_000, 400_000)),
        limit_negative: Some(SwitchZone::below(-50_000)),
        limit_positive: Some(SwitchZone::above(350_000)),
        reference: Some(SwitchZone::cam(10_000, 12_000)),
        load: Load::None,
        index_phase: 0,
    };
    let tlc = Tlc5xx::new(cfg, Instant::ZERO).unwrap();
    let mut r = CoRig::new(tlc, 1, DeviceKind::Tlc5xx, Duration::from_millis(2));
    r.configure_pdos(DeviceKind::Tlc5xx);
    r.sdo(0x6081, 0, &1200u32.to_le_bytes());
    r.sdo(0x6083, 0, &60_000u32.to_le_bytes());
    r.sdo(0x6084, 0, &60_000u32.to_le_bytes());
    r.sdo(0x6098, 0, &[23]);
    r.sdo(0x6099, 1, &600i32.to_le_bytes());
    r.sdo(0x6099, 2, &60i32.to_le_bytes());
    r.start();
    r
}

#[test]
fn cia402_tlc5xx_enable_home_follow_halt_fault_reset() {
    let mut r = tlc_rig();
    let fb = r.done(Demand::Standstill, 100);
    assert_eq!(fb.state, AxisState::Ready);
    assert_eq!(r.dev.drive_state(), DriveState::OperationEnabled);

    // Homing method 23 on the reference cam: mode 6, bit 4, bits 12 + 10.
    let fb = r.done(Demand::Home, 20_000);
    assert!(fb.homed && fb.motion_complete && !fb.failed, "{fb:?}");
    assert!(r.dev.referenced());
    assert_eq!(fb.position, 0);
    assert_eq!(r.dev.actual_usr(), 0);

    // A trapezoid streamed as PP set-points: complete only on the final one.
    let target = 50_000;
    let limits = AxisLimits::new(100_000, 400_000, 0);
    let ramp = Trapezoid::plan(0, target, limits, r.cycle.as_nanos() as u32).unwrap();
    let n = ramp.duration_cycles();
    let before = r.set_points;
    let worst_lag = r.stream(&ramp, n, |d| i64::from(d.actual_usr()));
    // RPDO1 and TPDO1 are synchronous: the acknowledge of a set-point sent after SYNC k is in
    // the TPDO1 of SYNC k + 2, so a handshake takes four cycles.
    let sent = r.set_points - before;
    assert!(sent >= n / 4 - 1, "{sent} set-points in {n} cycles");
    assert!(worst_lag < 1_000, "lag {worst_lag}");
    assert_eq!(
        r.dev.mode(),
        drivers::cia402::modes::OperationMode::ProfilePosition
    );
    let last = Demand::Follow {
        position: target,
        velocity: 0,
    };
    let fb = r.until(last, 2_000, |f| f.motion_complete);
    assert!((fb.position - target).abs() <= 10, "{fb:?}");
    assert!((i64::from(r.dev.actual_usr()) - target).abs() <= 10);
    assert_eq!(fb.state, AxisState::Ready);

    // Halt in the middle of a long streamed move: bit 8, the axis stands with bit 10.
    let ramp = Trapezoid::plan(target, 300_000, limits, r.cycle.as_nanos() as u32).unwrap();
    r.stream(&ramp, ramp.duration_cycles() / 2, |d| {
        i64::from(d.actual_usr())
    });
    assert!(r.dev.axis().status().velocity.abs() > 50_000);
    let fb = r.done(Demand::Halt, 1_000);
    assert_eq!(fb.state, AxisState::Ready);
    assert!(r.dev.axis().status().standstill);
    let held = fb.position;
    r.step(Demand::Halt);
    assert_eq!(r.step(Demand::Halt).position, held, "stands while halted");

    // A fault (over-temperature), reset by the bit 7 edge once the cause is gone.
    r.dev.set_over_temperature(true);
    let fb = r.until(Demand::Standstill, 500, |f| f.state == AxisState::Fault);
    assert!(!fb.done);
    r.dev.set_over_temperature(false);
    for _ in 0..50 {
        assert_eq!(r.step(Demand::Standstill).state, AxisState::Fault);
    }
    let fb = r.done(Demand::Acknowledge, 500);
    assert_eq!(fb.state, AxisState::Disabled);
    assert!(r.dev.faults().is_empty());
    let fb = r.done(Demand::Standstill, 500);
    assert_eq!(fb.state, AxisState::Ready);
    assert_eq!(r.dev.drive_state(), DriveState::OperationEnabled);
    assert_eq!(r.missing, 0, "a TPDO1 every SYNC");
}

#[test]
fn cia402_mtr_dci_static_pdo1_enable_home_follow() {
    let dev = MtrDci::new(NodeId::new(3).unwrap(), MtrProfile::Cia402, Instant::ZERO).unwrap();
    let mut r = CoRig::new(dev, 3, DeviceKind::MtrDci, Duration::from_millis(2));
    r.configure_pdos(DeviceKind::MtrDci);
    r.sdo(0x6081, 0, &40_000u32.to_le_bytes());
    r.sdo(0x6083, 0, &400_000u32.to_le_bytes());
    r.start();
    let fb = r.done(Demand::Standstill, 100);
    assert_eq!(fb.state, AxisState::Ready);
    assert_eq!(r.dev.cia402_state(), Some(DriveState::OperationEnabled));
    // Homing (method 27 by default): the MTR-DCI also shows bit 15 "homing performed".
    let fb = r.done(Demand::Home, 30_000);
    assert!(fb.homed && !fb.failed, "{fb:?}");
    assert_eq!(fb.status & 0x8000, 0x8000);
    // The MTR-DCI queues set-points (no change set immediately): the axis sends the move's end
    // once, with its profile on RPDO2, and the drive's generator follows the path closely.
    assert!(r.axis.one_set_point_per_move());
    let from = fb.position;
    let target = from + 20_000;
    let limits = AxisLimits::new(30_000, 200_000, 0);
    let ramp = Trapezoid::plan(from, target, limits, r.cycle.as_nanos() as u32).unwrap();
    r.axis.set_move(Some(PointMove {
        end: target,
        velocity: 30_000,
        acceleration: 200_000,
        halt: false,
    }));
    let (edges, profiles) = (r.set_points, r.profiles);
    let worst = r.stream(&ramp, ramp.duration_cycles(), |d| {
        d.drive().axis().status().position
    });
    // Two cycles of transport at 30 000 inc/s, and the drive's loop.
    assert!(worst <= 2_000, "{worst} inc behind the path");
    let fb = r.until(
        Demand::Follow {
            position: target,
            velocity: 0,
        },
        200,
        |f| f.motion_complete,
    );
    assert!((fb.position - target).abs() <= 2, "{fb:?}");
    assert_eq!((r.set_points - edges, r.profiles - profiles), (1, 1));
    assert_eq!(r.missing, 0);
}
