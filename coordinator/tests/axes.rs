//! The master-side axis state machines against the real drive simulators, in virtual time: an
//! FHPP axis driving `sim::fhpp_drive::FhppDrive` (MTR-DCI, CMMO-ST) image by image, and a
//! CiA 402 axis driving the TLC5xx simulator through its PDOs.

use core::time::Duration;

use coordinator::axis::{AxisState, Demand, DeviceKind, DriveAxis, Feedback, Image, Profile};
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
        }
    }

    fn step(&mut self, d: Demand) -> Feedback {
        self.t += self.cycle;
        self.drive.step_to(self.t);
        let input = self.drive.input();
        self.fb = self.axis.exchange(Some(&input), &d, &mut self.out).unwrap();
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
    assert!(worst_lag < 6_000, "lag {worst_lag}");
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

    // A fault (over-temperature) while enabled, acknowledged once the cause is gone.
    r.drive.inject(Injection::OverTemperature, true);
    let fb = r.until(Demand::Standstill, 500, |f| f.state == AxisState::Fault);
    assert!(!fb.done);
    r.drive.inject(Injection::OverTemperature, false);
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
