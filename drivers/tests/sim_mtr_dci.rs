//! The MTR-DCI simulator on the virtual CAN bus in virtual time, driven by the CANopen master
//! through the manual's own sequences (seed 000 §2.5, §6, §7) with the exact bytes on the bus.

#[path = "sim_mtr_dci_rig.rs"]
mod rig;

use std::time::Duration;

use drivers::canopen::emcy::EmcyEvent;
use drivers::canopen::guarding::GuardingEvent;
use drivers::canopen::master::{MasterEvent, Supervision};
use drivers::canopen::nmt::{NmtCommand, NmtState};
use drivers::canopen::sdo::{AbortedBy, SdoError};
use drivers::canopen::{AbortCode, Address};
use drivers::cia402::state::State;
use drivers::fhpp::ByteOrder;
use drivers::fhpp::Variant;
use drivers::fhpp::fpc::{Channel, Codec, Param, Request, Response, Value};
use drivers::sim::axis::{Direction, Load};
use drivers::sim::fhpp_drive::DriveConfig;
use drivers::sim::mtr_dci::{MtrDci, Profile};
use rig::*;

fn mtr(profile: Profile) -> Rig<MtrDci> {
    Rig::new(3, |n, now| MtrDci::new(n, profile, now).unwrap())
}

/// Boot-up, NMT start, ENABLE + STOP + HOLD, homing (method 27) over PDO1.
fn homed() -> Rig<MtrDci> {
    let mut r = mtr(Profile::Fhpp);
    r.run_for(MS);
    // Boot-up 703h [00]; the master sees the node pre-operational.
    assert_eq!(r.frames(0x703, 0)[0].data(), &[0x00]);
    assert_eq!(
        r.ctl.endpoint.master.state(r.node),
        Some(NmtState::PreOperational)
    );
    // Pre-operational: PDOs are ignored, nothing answers.
    let from = r.log.len();
    r.rpdo(1, rec(0x03, 0x01, 0));
    r.run_for(10 * MS);
    assert!(r.frames(0x183, from).is_empty());
    r.nmt(NmtCommand::Start);
    assert_eq!(r.dev.endpoint.device().state(), NmtState::Operational);
    // Operational: TPDO1 goes out at once (event-driven) with the power-on image: drive blocked,
    // 24VL, MC (digest §2.5), actual position 100000 inc.
    let s = r.last(0x183).expect("TPDO1 after start");
    assert_eq!(&s[..2], &[0x10, 0x04]);
    assert_eq!(pos(&s), 100_000);
    // ENABLE + STOP + HOLD: S4, SCON 13h, SPOS 05h (not referenced).
    let s = r.pdo1_until(rec(0x03, 0x01, 0), 20, "enabled", |s| s[0] == 0x13);
    assert_eq!(s[1], 0x05);
    // HOM rising edge with HOLD (Tab. 5/11): ACK = 1, MC = 0.
    let s = r.pdo1_until(rec(0x03, 0x05, 0), 20, "homing ACK", |s| s[1] & ACK != 0);
    assert_eq!(s[1] & (ACK | MC | REF), ACK);
    // Homing done: SPOS 85h (REF + MC + HOLD), position 0 at the reference.
    let s = r.pdo1_until(rec(0x03, 0x01, 0), 30_000, "homed", |s| s[1] == 0x85);
    assert_eq!(&s[..2], &[0x13, 0x85]);
    assert_eq!(pos(&s), 0);
    assert!(r.dev.endpoint.drive().is_referenced());
    r
}

#[test]
fn boot_start_enable_and_homing_with_exact_bytes() {
    let r = homed();
    // The RPDO/TPDO COB-IDs of node 3 are 203h/183h; nothing else carried the image.
    assert!(r.frames(0x203, 0).len() >= 3);
    assert!(r.frames(0x183, 0).len() > 10);
}

#[test]
fn record_start_with_start_ack_mc_and_the_settling_time() {
    let mut r = homed();
    // Record 1 (IND 2): target 50000 inc, 40000 inc/s, written by SDO at 2000h + PNU.
    r.pnu_write(404, 2, &50_000i32.to_le_bytes()).unwrap();
    r.pnu_write(406, 2, &40_000u32.to_le_bytes()).unwrap();
    assert_eq!(
        r.sdo_read(Address::new(0x2000 + 404, 2)).unwrap(),
        50_000i32.to_le_bytes()
    );
    // Selecting the record changes nothing visible (byte 3 shows the last record run).
    r.rpdo(1, rec(0x03, 0x01, 1));
    r.run_for(5 * MS);
    assert_eq!(r.last(0x183).unwrap()[..2], [0x13, 0x85]);
    // START: ACK = 1, MC = 0 (83h); then MOV (93h) and byte 3 = the current record.
    let s = r.pdo1_until(rec(0x03, 0x03, 1), 20, "ACK", |s| s[1] & ACK != 0);
    assert_eq!(s[1], 0x83);
    let s = r.pdo1_until(rec(0x03, 0x03, 1), 200, "moving", |s| s[1] == 0x93);
    assert_eq!(s[2], 1);
    // START released: ACK falls; MC comes once the position held the window (PNU 1022 = 750
    // inc) for the damping time (PNU 1023 = 100 ms).
    let from = r.log.len();
    let s = r.pdo1_until(rec(0x03, 0x01, 1), 20_000, "MC", |s| s[1] & MC != 0);
    assert_eq!(&s[..3], &[0x13, 0x85, 0x01]);
    assert!((pos(&s) - 50_000).abs() <= 750, "{}", pos(&s));
    let tpdos = r.frames(0x183, from);
    let mc_at = tpdos
        .iter()
        .find(|f| f.data()[1] & MC != 0)
        .unwrap()
        .timestamp();
    // The last TPDO outside the window before MC: the window was entered after it.
    let entered = tpdos
        .iter()
        .filter(|f| f.timestamp() < mc_at)
        .rev()
        .find(|f| (pos(&f.data8()) - 50_000).abs() > 750)
        .map(|f| f.timestamp())
        .unwrap();
    // The window is entered while the generator still brakes; the damping time counts from
    // the end of the profile, so MC is at least 100 ms and well under 200 ms later.
    let settled = mc_at - entered;
    assert!(
        settled >= Duration::from_millis(100) && settled <= Duration::from_millis(200),
        "MC {settled:?} after entering the window"
    );
}

#[test]
fn direct_move_bytes_and_motion() {
    let mut r = homed();
    // OPM direct (43h): SCON 53h. START (Tab. 5/13): SPOS 83h, then 93h while moving.
    let s = r.pdo1_until(direct(0x43, 0x01, 0, 50, 30_000), 20, "direct", |s| {
        s[0] == 0x53
    });
    assert_eq!(s[1], 0x85);
    let s = r.pdo1_until(direct(0x43, 0x03, 0, 50, 30_000), 20, "ACK", |s| {
        s[1] & ACK != 0
    });
    assert_eq!(s[1], 0x83);
    let s = r.pdo1_until(direct(0x43, 0x03, 0, 50, 30_000), 200, "moving", |s| {
        s[1] == 0x93
    });
    // Actual value 1: the speed in % of PNU 502, at most the 50 % asked for.
    assert!(s[3] <= 50);
    let s = r.pdo1_until(direct(0x43, 0x01, 0, 50, 30_000), 20_000, "done", |s| {
        s[1] & MC != 0
    });
    assert_eq!(&s[..3], &[0x53, 0x85, 0x00]);
    assert!((pos(&s) - 30_000).abs() <= 750);
    assert!((r.dev.endpoint.drive().axis().status().position - 30_000).abs() <= 750);
}

#[test]
fn fpc_read_and_write_over_pdo2() {
    let mut r = homed();
    let codec = Codec::new(Channel::Classic, ByteOrder::Little);
    let ask = |r: &mut Rig<MtrDci>, req: Request| {
        let from = r.log.len();
        r.rpdo(2, codec.encode_request(req));
        r.run_for(5 * MS);
        let replies = r.frames(0x283, from);
        codec.decode_response(&replies.last().expect("TPDO2 reply").data8())
    };
    // Write PNU 1022 (MC window, dword) = 1000: the reply echoes it.
    let w = Request::Write(Param::new(1022, 0), Value::Dword(1_000));
    assert_eq!(
        ask(&mut r, w),
        Ok(Response::Value(Param::new(1022, 0), Value::Dword(1_000)))
    );
    assert_eq!(r.dev.endpoint.drive_mut().read_pnu(1022, 0), Ok(1_000));
    // No task in between, then a read of record 1's target (array, IND 2).
    assert_eq!(ask(&mut r, Request::NoTask), Ok(Response::NoReply));
    r.dev.endpoint.drive_mut().set_pnu(404, 2, 12_345).unwrap();
    assert_eq!(
        ask(&mut r, Request::Read(Param::new(404, 2))),
        Ok(Response::Value(Param::new(404, 2), Value::Dword(12_345)))
    );
    // The classic wire bytes on TPDO2: byte 1 reserved, IND, PKE (ResID 5 | PNU 404) LE, PWE.
    let raw = r.last(0x283).unwrap();
    assert_eq!(raw, [0x00, 0x02, 0x94, 0x51, 0x39, 0x30, 0x00, 0x00]);
}

#[test]
fn sdo_pnu_access_and_refused_out_of_range_write() {
    let mut r = mtr(Profile::Fhpp);
    r.run_for(MS);
    // SDO works in pre-operational. PNU 1022 (2000h + 1022 = 23FEh) reads its default 750.
    assert_eq!(
        r.sdo_read(Address::new(0x23FE, 0)).unwrap(),
        750u32.to_le_bytes()
    );
    r.pnu_write(1022, 0, &900u32.to_le_bytes()).unwrap();
    assert_eq!(r.dev.endpoint.drive_mut().read_pnu(1022, 0), Ok(900));
    // Record 5's speed above the maximum (100000 inc/s): 0609 0030h, value unchanged.
    let e = r.pnu_write(406, 6, &100_001u32.to_le_bytes()).unwrap_err();
    assert_eq!(
        e,
        SdoError::Aborted {
            code: AbortCode::InvalidValue,
            by: AbortedBy::Server
        }
    );
    // A PNU that does not exist: 0602 0000h; a sub-index beyond the records: 0609 0011h.
    let e = r.sdo_read(Address::new(0x2000 + 2000, 0)).unwrap_err();
    assert!(matches!(
        e,
        SdoError::Aborted {
            code: AbortCode::NoObject,
            ..
        }
    ));
    let e = r.sdo_read(Address::new(0x2000 + 404, 40)).unwrap_err();
    assert!(matches!(
        e,
        SdoError::Aborted {
            code: AbortCode::NoSubIndex,
            ..
        }
    ));
    // The static mapping cannot change; 1800h sub 04h does not exist.
    let e = r.sdo_write(Address::new(0x1600, 0), &[0]).unwrap_err();
    assert!(matches!(
        e,
        SdoError::Aborted {
            code: AbortCode::ReadOnly,
            ..
        }
    ));
    let e = r.sdo_read(Address::new(0x1800, 4)).unwrap_err();
    assert!(matches!(
        e,
        SdoError::Aborted {
            code: AbortCode::NoSubIndex,
            ..
        }
    ));
    // No heartbeat object on the MTR-DCI.
    let e = r.sdo_read(Address::new(0x1017, 0)).unwrap_err();
    assert!(matches!(
        e,
        SdoError::Aborted {
            code: AbortCode::NoObject,
            ..
        }
    ));
    // The guard time 100Ch takes 0..32767 ms (the catalog's, seed-000 §7.3).
    let guard = Address::new(0x100C, 0);
    let max = drivers::catalog::MTR_DCI.guard_time_max_ms.unwrap();
    r.sdo_write(guard, &max.to_le_bytes()).unwrap();
    let e = r.sdo_write(guard, &(max + 1).to_le_bytes()).unwrap_err();
    assert!(matches!(
        e,
        SdoError::Aborted {
            code: AbortCode::ValueTooHigh,
            ..
        }
    ));
    assert_eq!(r.sdo_read(guard).unwrap(), max.to_le_bytes());
}

#[test]
fn fault_sends_its_emcy_and_reset_acknowledges() {
    let mut r = mtr(Profile::Fhpp);
    r.run_for(MS);
    r.nmt(NmtCommand::Start);
    r.pnu_write(404, 2, &50_000i32.to_le_bytes()).unwrap();
    r.pnu_write(406, 2, &20_000u32.to_le_bytes()).unwrap();
    r.pdo1_until(rec(0x03, 0x01, 1), 20, "enabled", |s| s[0] == 0x13);
    // START before homing: fault 1 "please enforce homing run", EMCY 6310h, 1001h bit 5.
    let from = r.log.len();
    let s = r.pdo1_until(rec(0x03, 0x03, 1), 50, "fault", |s| s[0] & 0x08 != 0);
    assert_eq!(s[1] & ACK, 0);
    r.run_for(2 * MS);
    let emcy = r.frames(0x083, from);
    assert_eq!(emcy.len(), 1);
    assert_eq!(emcy[0].data(), &[0x10, 0x63, 0x21, 0, 0, 0, 0, 0]);
    assert!(
        r.ctl
            .endpoint
            .events
            .iter()
            .any(|e| matches!(e, MasterEvent::Emcy(EmcyEvent { code: 0x6310, .. })))
    );
    // 1001h and 1003h hold it.
    assert_eq!(r.sdo_read(Address::new(0x1001, 0)).unwrap(), [0x21]);
    assert_eq!(r.sdo_read(Address::new(0x1003, 0)).unwrap(), [1]);
    assert_eq!(
        r.sdo_read(Address::new(0x1003, 1)).unwrap(),
        0x6310u32.to_le_bytes()
    );
    // RESET rising edge: FAULT cleared, error-reset EMCY 0000h.
    let from = r.log.len();
    // START released: the fault stays (FAULT with the stage on, a simple fault).
    r.rpdo(1, rec(0x03, 0x01, 1));
    r.run_for(5 * MS);
    assert_eq!(r.last(0x183).unwrap()[0] & 0x0B, 0x09);
    let s = r.pdo1_until(rec(0x0B, 0x01, 1), 20, "acknowledged", |s| s[0] & 0x08 == 0);
    assert_eq!(s[1] & MC, MC);
    r.run_for(2 * MS);
    let emcy = r.frames(0x083, from);
    assert_eq!(emcy.len(), 1);
    assert_eq!(emcy[0].data(), &[0, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(r.sdo_read(Address::new(0x1001, 0)).unwrap(), [0x00]);
}

#[test]
fn node_guarding_and_life_guarding_timeout() {
    let mut r = mtr(Profile::Fhpp);
    r.run_for(MS);
    // Guard time 100 ms, life time factor 3 (life time 300 ms).
    r.sdo_write(Address::new(0x100C, 0), &100u16.to_le_bytes())
        .unwrap();
    r.sdo_write(Address::new(0x100D, 0), &[3]).unwrap();
    let n = r.node;
    let now = r.now();
    r.ctl
        .endpoint
        .master
        .set_supervision(
            n,
            Supervision::Guarding {
                guard_ms: 100,
                factor: 3,
            },
            now,
        )
        .unwrap();
    r.nmt(NmtCommand::Start);
    r.pdo1_until(rec(0x03, 0x01, 0), 20, "enabled", |s| s[0] == 0x13);
    let from = r.log.len();
    r.run_for(Duration::from_millis(1_000));
    // Replies 703h: 1 byte, toggle alternating, state 05h (operational).
    let replies: Vec<u8> = r
        .frames(0x703, from)
        .iter()
        .filter(|f| !f.is_remote())
        .map(|f| f.data()[0])
        .collect();
    assert!(replies.len() >= 9, "{replies:?}");
    for w in replies.windows(2) {
        assert_eq!(w[0] & 0x7F, 0x05);
        assert_ne!(w[0] & 0x80, w[1] & 0x80, "toggle");
    }
    assert!(
        !r.ctl
            .endpoint
            .events
            .iter()
            .any(|e| matches!(e, MasterEvent::Guarding(GuardingEvent::NoReply { .. })))
    );
    // The master stops polling: after the life time the drive takes its fault reaction
    // (emergency ramp, output stage off), EMCY 8130h with the communication bit.
    r.ctl
        .endpoint
        .master
        .set_supervision(n, Supervision::None, now)
        .unwrap();
    let from = r.log.len();
    let lost = r.run_until(Duration::from_millis(500), |r| {
        !r.frames(0x083, from).is_empty()
    });
    assert!(lost);
    let emcy = r.frames(0x083, from);
    assert_eq!(emcy[0].data(), &[0x30, 0x81, 0x11, 0, 0, 0, 0, 0]);
    r.run_for(20 * MS);
    let s = r.last(0x183).unwrap();
    assert_eq!(s[0] & 0x09, 0x08, "FAULT, drive disabled (serious fault)");
    // 2FF2h/01 = PNU 206/1: operational, guarding error.
    assert_eq!(r.dev.endpoint.drive_mut().read_pnu(206, 1), Ok(0x42));
    assert_eq!(r.dev.endpoint.drive().fault_number(), Some(51));
}

/// The CiA 402 RPDO1 image: controlword, 2032h record number 0, 6060h mode, 607Ah target (or
/// 6071h torque in PT).
fn cia(cw: u16, mode: i8, value: i32) -> [u8; 8] {
    let c = cw.to_le_bytes();
    let t = value.to_le_bytes();
    [c[0], c[1], 0, mode as u8, t[0], t[1], t[2], t[3]]
}

/// The statusword of a CiA 402 TPDO1 image.
fn sw(s: &[u8; 8]) -> u16 {
    u16::from_le_bytes([s[0], s[1]])
}

/// A CiA 402 MTR-DCI started, enabled (transitions 20, 21) and homed (method 27, bits 12 + 15).
fn cia402_homed(mut r: Rig<MtrDci>) -> Rig<MtrDci> {
    r.run_for(MS);
    r.nmt(NmtCommand::Start);
    r.pdo1_until(cia(0x06, 6, 0), 20, "ready", |s| sw(s) & 0x6F == 0x21);
    r.pdo1_until(cia(0x0F, 6, 0), 20, "enabled", |s| sw(s) & 0x6F == 0x27);
    r.pdo1_until(cia(0x1F, 6, 0), 30_000, "homed", |s| {
        sw(s) & 0x9000 == 0x9000
    });
    r
}

#[test]
fn cia402_profile_enables_homes_and_moves() {
    let mut r = mtr(Profile::Cia402);
    r.run_for(MS);
    r.nmt(NmtCommand::Start);
    assert_eq!(
        r.sdo_read(Address::new(0x1000, 0)).unwrap(),
        0x0002_0192u32.to_le_bytes()
    );
    // Shutdown: transition 20 to Ready to switch on; enable operation: 21 straight to
    // Operation enabled (Festo).
    let s = r.pdo1_until(cia(0x06, 1, 0), 20, "ready", |s| sw(s) & 0x6F == 0x21);
    assert_eq!(s[3], 1, "mode display PP");
    let s = r.pdo1_until(cia(0x0F, 6, 0), 20, "enabled", |s| sw(s) & 0x6F == 0x27);
    assert_eq!(r.dev.endpoint.cia402_state(), Some(State::OperationEnabled));
    assert_eq!(s[3] as i8, 6, "mode display homing");
    // Homing (method 27): bit 4; attained = bit 12, homing performed = bit 15.
    let s = r.pdo1_until(cia(0x1F, 6, 0), 30_000, "homed", |s| {
        sw(s) & 0x9000 == 0x9000
    });
    assert_eq!(sw(&s) & 0x2000, 0, "no homing error");
    assert_eq!(pos(&s), 0);
    // Profile position: profile velocity 40000 inc/s by RPDO2, target 20000, new set-point.
    let v = 40_000u32.to_le_bytes();
    let a = 400_000u32.to_le_bytes();
    r.rpdo(2, [v[0], v[1], v[2], v[3], a[0], a[1], a[2], a[3]]);
    r.pdo1_until(cia(0x0F, 1, 20_000), 20, "PP", |s| s[3] == 1);
    let s = r.pdo1_until(cia(0x1F, 1, 20_000), 20, "set-point ack", |s| {
        sw(s) & 0x1000 != 0
    });
    assert_eq!(sw(&s) & 0x0400, 0, "target not reached");
    let s = r.pdo1_until(cia(0x0F, 1, 20_000), 20_000, "target reached", |s| {
        sw(s) & 0x0400 != 0
    });
    assert_eq!(sw(&s) & 0x6F, 0x27);
    assert!((pos(&s) - 20_000).abs() <= 750, "{}", pos(&s));
    // Quick stop then disable voltage.
    let s = r.pdo1_until(cia(0x0B, 1, 20_000), 20, "quick stop", |s| {
        sw(s) & 0x6F == 0x07
    });
    assert_eq!(sw(&s) & 0x0200, 0x0200, "remote");
    r.pdo1_until(cia(0x00, 1, 20_000), 20, "disabled", |s| {
        sw(s) & 0x4F == 0x40
    });
}

#[test]
fn cia402_moves_run_at_6081h_brake_with_6083h_under_bit_15_and_resume_after_a_halt() {
    let mut r = cia402_homed(mtr(Profile::Cia402));
    // 12 345 inc/s (not a whole per cent of the drive's maximum) and a gentle 20 000 inc/s²,
    // taken over with bit 15 "symmetrical ramp via PDO".
    let v = 12_345u32.to_le_bytes();
    let a = 20_000u32.to_le_bytes();
    r.rpdo(2, [v[0], v[1], v[2], v[3], a[0], a[1], a[2], a[3]]);
    let sym = 0x8000;
    r.pdo1_until(cia(sym | 0x0F, 1, 30_000), 20, "PP", |s| s[3] == 1);
    r.pdo1_until(cia(sym | 0x1F, 1, 30_000), 20, "set-point ack", |s| {
        sw(s) & 0x1000 != 0
    });
    // Accelerating at 20 000 inc/s², the speed is reached after about 0.62 s: at 0.3 s the drive
    // is still accelerating (at the stored ramp it would be at full speed within milliseconds).
    r.run_for(300 * MS);
    let speed = r.dev.endpoint.drive().axis().status().velocity;
    assert!(
        (4_000..=8_000).contains(&speed),
        "{speed} inc/s after 0.3 s"
    );
    r.run_for(700 * MS);
    let speed = r.dev.endpoint.drive().axis().status().velocity;
    assert!(
        (12_300..=12_345).contains(&speed),
        "{speed} inc/s, not 6081h"
    );
    // Halt (bit 8): the drive stops and keeps the move; released, it goes on to the target.
    let s = r.pdo1_until(cia(sym | 0x10F, 1, 30_000), 2_000, "halted", |s| {
        sw(s) & 0x0400 != 0
    });
    assert!(pos(&s) < 29_000, "halted at {}", pos(&s));
    // Bit 10 comes within the standstill window; the last increments settle after it.
    r.run_for(100 * MS);
    let halted_at = r.dev.endpoint.drive().axis().status().position;
    r.run_for(200 * MS);
    assert_eq!(r.dev.endpoint.drive().axis().status().position, halted_at);
    let s = r.pdo1_until(cia(sym | 0x0F, 1, 30_000), 10_000, "target reached", |s| {
        sw(s) & 0x0400 != 0
    });
    assert!((pos(&s) - 30_000).abs() <= 2, "{}", pos(&s));
}

#[test]
fn synchronous_tpdo1_after_switching_the_transmission_type() {
    let mut r = mtr(Profile::Fhpp);
    r.run_for(MS);
    // 1800h sub 02 = 1: TPDO1 after every SYNC (the mapping stays static).
    r.sdo_write(Address::new(0x1800, 2), &[1]).unwrap();
    r.nmt(NmtCommand::Start);
    let now = r.now();
    r.ctl.endpoint.master.start_sync(4_000, 0, now).unwrap();
    r.rpdo(1, rec(0x03, 0x01, 0));
    let from = r.log.len();
    r.run_for(40 * MS);
    let syncs: Vec<_> = r
        .frames(0x080, from)
        .iter()
        .map(|f| f.timestamp())
        .collect();
    let tpdos: Vec<_> = r
        .frames(0x183, from)
        .iter()
        .map(|f| f.timestamp())
        .collect();
    assert_eq!(syncs.len(), 10);
    // One TPDO1 per SYNC, each right after its SYNC, even with the image unchanged.
    assert_eq!(tpdos.len(), syncs.len());
    for (s, t) in syncs.iter().zip(&tpdos) {
        assert!(*t > *s && *t - *s < Duration::from_micros(500));
    }
    assert_eq!(r.last(0x183).unwrap()[..2], [0x13, 0x05]);
}

#[test]
fn cia402_profile_torque_against_a_stop() {
    let mut cfg = DriveConfig::new(Variant::MtrDci);
    cfg.axis.environment.load = Load::FixedStop {
        position: 65_400,
        side: Direction::Positive,
    };
    let mut r = cia402_homed(Rig::new(3, |n, now| {
        MtrDci::with_config(n, Profile::Cia402, cfg, now).unwrap()
    }));
    // The force-mode speed limit (PNU 554, 2000h + 554) at 10 % of the rated speed, so the
    // acceleration current stays out of the force window.
    r.pnu_write(554, 0, &10_000u32.to_le_bytes()).unwrap();
    // Mode 4: bytes 5..8 are 6071h = 500 ‰; bit 6 set as the manual asks, bit 5 = 0 (no stroke
    // limitation), bit 4 starts.
    r.pdo1_until(cia(0x4F, 4, 500), 20, "PT", |s| s[3] == 4);
    let s = r.pdo1_until(cia(0x5F, 4, 500), 50, "running", |s| sw(s) & 0x1000 != 0);
    assert_eq!(sw(&s) & 0x0400, 0);
    let s = r.pdo1_until(cia(0x4F, 4, 500), 20_000, "torque reached", |s| {
        sw(s) & 0x0400 != 0
    });
    assert_eq!(sw(&s) & 0x3000, 0x1000, "running, no stroke limit");
    assert_eq!(r.dev.endpoint.drive().axis().raw_position(), 65_400);
    assert_eq!(r.dev.endpoint.drive().axis().status().current_ma, 1150);
}

#[test]
fn reset_node_boots_again_unreferenced() {
    let mut r = homed();
    let from = r.log.len();
    r.nmt(NmtCommand::ResetNode);
    r.run_for(5 * MS);
    assert_eq!(r.frames(0x703, from)[0].data(), &[0x00]);
    assert_eq!(r.dev.endpoint.device().state(), NmtState::PreOperational);
    assert!(!r.dev.endpoint.drive().is_referenced());
    r.nmt(NmtCommand::Start);
    let s = r.last(0x183).unwrap();
    assert_eq!(&s[..2], &[0x10, 0x04], "power-on image again");
}

/// One scenario: boot, start, enable, homing, a direct move, with a SYNC producer running.
fn scenario() -> Vec<(u16, Vec<u8>, u64)> {
    let mut r = mtr(Profile::Fhpp);
    r.run_for(MS);
    let now = r.now();
    r.ctl.endpoint.master.start_sync(2_000, 0, now).unwrap();
    r.nmt(NmtCommand::Start);
    r.pdo1_until(rec(0x03, 0x01, 0), 20, "enabled", |s| s[0] == 0x13);
    r.pdo1_until(rec(0x03, 0x05, 0), 20, "ACK", |s| s[1] & ACK != 0);
    r.pdo1_until(rec(0x03, 0x01, 0), 30_000, "homed", |s| s[1] == 0x85);
    r.pdo1_until(direct(0x43, 0x03, 0, 30, 8_000), 20, "ACK", |s| {
        s[1] & ACK != 0
    });
    r.pdo1_until(direct(0x43, 0x01, 0, 30, 8_000), 20_000, "MC", |s| {
        s[1] & MC != 0
    });
    r.fingerprint()
}

#[test]
fn two_runs_give_identical_frame_logs() {
    let a = scenario();
    let b = scenario();
    assert!(a.len() > 1_000);
    assert_eq!(a, b);
}

#[test]
fn a_tpdo_switched_between_sync_and_event_driven_follows_its_type() {
    // The device polls its TPDOs for changes only while one is event-driven: switching the
    // type by SDO must switch the polling too.
    let mut r = homed();
    r.sdo_write(Address::new(0x1800, 2), &[1]).unwrap();
    // A record move changes the image every few milliseconds; with no SYNC on this bus a
    // synchronous TPDO1 never goes out.
    r.pnu_write(404, 2, &20_000i32.to_le_bytes()).unwrap();
    let from = r.log.len();
    r.rpdo(1, rec(0x03, 0x03, 1));
    r.run_for(50 * MS);
    assert!(r.frames(0x183, from).is_empty());
    // Back to event-driven (255): the changes go out again.
    r.sdo_write(Address::new(0x1800, 2), &[255]).unwrap();
    let from = r.log.len();
    r.rpdo(1, rec(0x03, 0x01, 1));
    r.run_for(50 * MS);
    assert!(!r.frames(0x183, from).is_empty());
}
