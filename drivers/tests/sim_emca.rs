//! The EMCA simulator on the virtual CAN bus in virtual time: FHPP on PDO1, EFPC on PDO2, SDO
//! 2000h + PNU, EMCY on fault and acknowledge, node guarding, a record chain run over the bus
//! (seed 002 §1, §2.4, §3.3, §5.1).

#[path = "sim_mtr_dci_rig.rs"]
mod rig;

use std::time::Duration;

use drivers::canopen::master::Supervision;
use drivers::canopen::nmt::{NmtCommand, NmtState};
use drivers::canopen::sdo::SdoError;
use drivers::canopen::{AbortCode, Address};
use drivers::fhpp::ByteOrder;
use drivers::fhpp::fpc::{Channel, Codec, Param, Request, Response, Value};
use drivers::sim::emca::Emca;
use drivers::sim::fhpp_drive::Injection;
use rig::*;

fn emca() -> Rig<Emca> {
    Rig::new(4, |n, now| Emca::new(n, now).unwrap())
}

/// Boot-up, start, enable with LOCK (23h), homing on the current position (method -35).
fn homed() -> Rig<Emca> {
    let mut r = emca();
    r.run_for(MS);
    assert_eq!(r.frames(0x704, 0)[0].data(), &[0x00]);
    assert_eq!(
        r.ctl.endpoint.master.state(r.node),
        Some(NmtState::PreOperational)
    );
    r.nmt(NmtCommand::Start);
    // Power-up image (§2.4): SCON 0001.0000, SPOS 0000.0100.
    assert_eq!(r.last(0x184).unwrap()[..2], [0x10, 0x04]);
    // One state per 5 ms drive cycle: S2 -> S3 -> S4.
    let s = r.pdo1_until(rec(0x23, 0x01, 0), 40, "enabled", |s| s[0] == 0x13);
    assert_eq!(s[1], 0x05);
    let s = r.pdo1_until(rec(0x23, 0x05, 0), 40, "homing ACK", |s| s[1] & ACK != 0);
    assert_eq!(s[1] & MC, 0);
    let s = r.pdo1_until(rec(0x23, 0x01, 0), 1_000, "homed", |s| s[1] & MC != 0);
    assert_eq!(s[1], 0x85);
    r
}

fn sdo_i32(r: &mut Rig<Emca>, pnu: u16, sub: u8, v: i32) {
    r.pnu_write(pnu, sub, &v.to_le_bytes())
        .unwrap_or_else(|e| panic!("PNU {pnu}/{sub}: {e}"));
}

fn record(r: &mut Rig<Emca>, n: u8, target: i32, speed: i32, rcb2: u8, next: u8) {
    sdo_i32(r, 404, n, target);
    sdo_i32(r, 406, n, speed);
    sdo_i32(r, 407, n, 200_000);
    sdo_i32(r, 408, n, 200_000);
    r.pnu_write(402, n, &[rcb2]).unwrap();
    r.pnu_write(416, n, &[next]).unwrap();
}

#[test]
fn record_chain_runs_over_the_bus() {
    let mut r = homed();
    // 1: to 20000, step on MC -> 2: to 80000, step when the position comparator [40000, 50000]
    // holds -> 3: back to 0, step after 100..200 ms -> 4: to 30000, end. All by SDO.
    record(&mut r, 1, 20_000, 40_000, 0x80 | 1, 2);
    record(&mut r, 2, 80_000, 40_000, 0x80 | 20, 3);
    record(&mut r, 3, 0, 40_000, 0x80 | 23, 4);
    record(&mut r, 4, 30_000, 40_000, 0, 0);
    sdo_i32(&mut r, 430, 2, 40_000);
    sdo_i32(&mut r, 431, 2, 50_000);
    r.pnu_write(439, 3, &100u32.to_le_bytes()).unwrap();
    r.pnu_write(440, 3, &200u32.to_le_bytes()).unwrap();
    let from = r.log.len();
    r.pdo1_until(rec(0x23, 0x03, 1), 40, "ACK", |s| s[1] & ACK != 0);
    let s = r.pdo1_until(rec(0x23, 0x01, 1), 60_000, "chain end", |s| {
        s[2] == 4 && s[1] & MC != 0
    });
    // End: MC, record 4, RSB = RC1 + RCC, at its target.
    assert_eq!(s[1], 0x85);
    assert_eq!(s[3], 0x03);
    assert!((pos(&s) - 30_000).abs() <= 500, "{}", pos(&s));
    // The record numbers TPDO1 reported, in order, and where the steps happened.
    let mut seen: Vec<(u8, i32)> = Vec::new();
    for f in r.frames(0x184, from) {
        let d = f.data8();
        if seen.last().map(|x| x.0) != Some(d[2]) {
            seen.push((d[2], pos(&d)));
        }
    }
    let order: Vec<u8> = seen.iter().map(|x| x.0).collect();
    assert_eq!(order, vec![1, 2, 3, 4]);
    assert!((seen[1].1 - 20_000).abs() <= 500, "1 -> 2 at MC: {seen:?}");
    assert!(
        (40_000..=50_000).contains(&seen[2].1),
        "2 -> 3 inside the comparator: {seen:?}"
    );
}

#[test]
fn efpc_over_pdo2_and_sdo_refusals() {
    let mut r = homed();
    let codec = Codec::new(Channel::Enhanced, ByteOrder::Little);
    let ask = |r: &mut Rig<Emca>, req: Request| {
        let from = r.log.len();
        r.rpdo(2, codec.encode_request(req));
        r.run_for(12 * MS);
        let replies = r.frames(0x284, from);
        codec.decode_response(&replies.last().expect("TPDO2 reply").data8())
    };
    // Write record 7's target (PNU 404 sub 7) = -5, then read it back.
    let w = Request::Write(Param::new(404, 7), Value::Dword(-5i32 as u32));
    assert_eq!(
        ask(&mut r, w),
        Ok(Response::Value(
            Param::new(404, 7),
            Value::Dword(-5i32 as u32)
        ))
    );
    assert_eq!(
        r.last(0x284).unwrap()[0],
        0x15,
        "FPCS: PNU mode, transferred"
    );
    assert_eq!(ask(&mut r, Request::NoTask), Ok(Response::NoReply));
    assert_eq!(
        ask(&mut r, Request::Read(Param::new(404, 7))),
        Ok(Response::Value(
            Param::new(404, 7),
            Value::Dword(-5i32 as u32)
        ))
    );
    // The same value by SDO at 2194h sub 7.
    assert_eq!(
        r.sdo_read(Address::new(0x2000 + 404, 7)).unwrap(),
        (-5i32).to_le_bytes()
    );
    // Out of range (PNU 520: 1..7): 0609 0030h. rw2 with the output stage on: 0800 0022h.
    let e = r.pnu_write(520, 1, &[9]).unwrap_err();
    assert!(matches!(
        e,
        SdoError::Aborted {
            code: AbortCode::InvalidValue,
            ..
        }
    ));
    let e = r.pnu_write(1022, 1, &100u32.to_le_bytes()).unwrap_err();
    assert!(matches!(
        e,
        SdoError::Aborted {
            code: AbortCode::DeviceState,
            ..
        }
    ));
    // A value of the wrong width: 0607 0012h.
    let e = r.pnu_write(520, 1, &[1, 0]).unwrap_err();
    assert!(matches!(
        e,
        SdoError::Aborted {
            code: AbortCode::TooLong,
            ..
        }
    ));
}

#[test]
fn load_voltage_fault_emcy_and_its_acknowledge() {
    let mut r = homed();
    let from = r.log.len();
    r.dev
        .endpoint
        .drive_mut()
        .inject(Injection::SupplyDrop, true);
    let s = r.pdo1_until(rec(0x23, 0x01, 0), 40, "fault", |s| s[0] & 0x08 != 0);
    assert_eq!(s[0] & 0x10, 0, "SCON.24VL = 0");
    r.run_for(2 * MS);
    // DC-link undervoltage 1Bh: EMCY 3220h, voltage bit.
    let emcy = r.frames(0x084, from);
    assert_eq!(emcy[0].data(), &[0x20, 0x32, 0x05, 0, 0, 0, 0, 0]);
    assert_eq!(r.sdo_read(Address::new(0x1001, 0)).unwrap(), [0x05]);
    // RESET while the cause is present: refused (T11), and the EMCA says so with its EMCY again.
    let from = r.log.len();
    r.rpdo(1, rec(0x20, 0x01, 0));
    r.run_for(10 * MS);
    r.rpdo(1, rec(0x28, 0x01, 0));
    r.run_for(10 * MS);
    assert_eq!(r.last(0x184).unwrap()[0] & 0x08, 0x08);
    let emcy = r.frames(0x084, from);
    assert_eq!(emcy.len(), 1);
    assert_eq!(emcy[0].data(), &[0x20, 0x32, 0x05, 0, 0, 0, 0, 0]);
    assert_eq!(r.sdo_read(Address::new(0x1003, 0)).unwrap(), [2]);
    // The cause goes; a serious fault is acknowledged with ENABLE = 0 and a RESET edge (T9
    // `xxx0.Pxx0`, §2.11); the EMCA sends the error-reset EMCY.
    r.dev
        .endpoint
        .drive_mut()
        .inject(Injection::SupplyDrop, false);
    r.rpdo(1, rec(0x20, 0x01, 0));
    r.run_for(20 * MS);
    let from = r.log.len();
    let s = r.pdo1_until(rec(0x28, 0x01, 0), 40, "acknowledged", |s| s[0] & 0x08 == 0);
    assert_eq!(s[0], 0x10, "S2: drive blocked, 24VL back");
    r.run_for(2 * MS);
    let emcy = r.frames(0x084, from);
    assert_eq!(emcy.len(), 1);
    assert_eq!(emcy[0].data(), &[0; 8]);
}

#[test]
fn life_guarding_loss_is_diagnostic_1c_with_emcy_8130() {
    let mut r = homed();
    r.sdo_write(Address::new(0x100C, 0), &50u16.to_le_bytes())
        .unwrap();
    r.sdo_write(Address::new(0x100D, 0), &[2]).unwrap();
    let (n, now) = (r.node, r.now());
    let guarding = Supervision::Guarding {
        guard_ms: 50,
        factor: 2,
    };
    r.ctl
        .endpoint
        .master
        .set_supervision(n, guarding, now)
        .unwrap();
    let from = r.log.len();
    r.run_for(Duration::from_millis(500));
    assert!(r.frames(0x084, from).is_empty(), "polled in time: no EMCY");
    assert!(r.frames(0x704, from).len() >= 16, "RTRs and replies");
    r.ctl
        .endpoint
        .master
        .set_supervision(n, Supervision::None, now)
        .unwrap();
    let from = r.log.len();
    assert!(r.run_until(Duration::from_millis(300), |r| {
        !r.frames(0x084, from).is_empty()
    }));
    assert_eq!(
        r.frames(0x084, from)[0].data(),
        &[0x30, 0x81, 0x11, 0, 0, 0, 0, 0]
    );
    r.run_for(20 * MS);
    assert_eq!(r.dev.endpoint.drive().fault_number(), Some(0x1C));
    assert_eq!(r.last(0x184).unwrap()[0] & 0x08, 0x08);
}

/// Boot, home, one direct move, with a 5 ms SYNC running: the whole frame log.
fn scenario() -> Vec<(u16, Vec<u8>, u64)> {
    let mut r = emca();
    r.run_for(MS);
    let now = r.now();
    r.ctl.endpoint.master.start_sync(5_000, 0, now).unwrap();
    r.nmt(NmtCommand::Start);
    r.pdo1_until(rec(0x23, 0x01, 0), 40, "enabled", |s| s[0] == 0x13);
    r.pdo1_until(rec(0x23, 0x05, 0), 40, "ACK", |s| s[1] & ACK != 0);
    r.pdo1_until(rec(0x23, 0x01, 0), 1_000, "homed", |s| s[1] & MC != 0);
    r.pdo1_until(direct(0x63, 0x03, 0, 50, 15_000), 40, "ACK", |s| {
        s[1] & ACK != 0
    });
    r.pdo1_until(direct(0x63, 0x01, 0, 50, 15_000), 20_000, "MC", |s| {
        s[1] & MC != 0
    });
    r.fingerprint()
}

#[test]
fn two_runs_give_identical_frame_logs() {
    let a = scenario();
    assert!(a.len() > 100);
    assert_eq!(a, scenario());
}

#[test]
fn dictionary_follows_the_emca_mapping() {
    let mut r = emca();
    r.run_for(MS);
    let rd = |r: &mut Rig<Emca>, i: u16, s: u8| r.sdo_read(Address::new(i, s));
    assert_eq!(rd(&mut r, 0x1000, 0).unwrap(), 0x12Du32.to_le_bytes());
    assert_eq!(rd(&mut r, 0x1018, 1).unwrap(), 0x1Du32.to_le_bytes());
    assert_eq!(rd(&mut r, 0x1601, 4).unwrap(), 0x3013_0020u32.to_le_bytes());
    assert_eq!(rd(&mut r, 0x1A00, 5).unwrap(), 0x3024_0020u32.to_le_bytes());
    assert_eq!(rd(&mut r, 0x1401, 1).unwrap(), 0x304u32.to_le_bytes());
    // FHPP+ PDOs 3/4 are not configured; no heartbeat object.
    assert!(rd(&mut r, 0x1802, 1).is_err());
    assert!(rd(&mut r, 0x1017, 0).is_err());
}
