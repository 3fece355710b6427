//! The FHPP drive simulator driven through the manuals' own sequences (digest 000 §2.5, digest
//! 002 §2.4, digest 001 §3.4), checking the exact status bytes and the motion behind them.

use core::time::Duration;

use drivers::fhpp::fpc::{Codec, Param, Request, Response, Value};
use drivers::fhpp::{ByteOrder, Variant};
use drivers::sim::axis::{Direction, Load};
use drivers::sim::fhpp_drive::{DriveConfig, Emcy, FhppDrive, Injection};
use drivers::time::Instant;

/// A master exchanging one image per drive cycle.
struct Bench {
    d: FhppDrive,
    t: Instant,
    cycle: Duration,
    out: [u8; 8],
    last: [u8; 8],
    trace: Vec<[u8; 8]>,
}

impl Bench {
    fn new(cfg: DriveConfig) -> Bench {
        let cycle = cfg.cycle;
        let mut d = FhppDrive::new(cfg).unwrap();
        let t = Instant::ZERO;
        let last = d.exchange(&[0; 8], t);
        Bench {
            d,
            t,
            cycle,
            out: [0; 8],
            last,
            trace: vec![last],
        }
    }
    fn of(v: Variant) -> Bench {
        Bench::new(DriveConfig::new(v))
    }
    /// One bus cycle: send `out`, return the status after the drive's next cycle.
    fn send(&mut self, out: [u8; 8]) -> [u8; 8] {
        self.out = out;
        self.d.exchange(&out, self.t);
        self.t += self.cycle;
        self.last = self.d.exchange(&out, self.t);
        self.trace.push(self.last);
        self.last
    }
    /// Repeats the current output until `pred` holds; panics after `max_ms`.
    fn until(&mut self, max_ms: u64, what: &str, pred: impl Fn(&[u8; 8]) -> bool) -> [u8; 8] {
        let end = self.t + Duration::from_millis(max_ms);
        while self.t < end {
            let s = self.send(self.out);
            if pred(&s) {
                return s;
            }
        }
        panic!(
            "{what}: not reached within {max_ms} ms, last {:02x?}",
            self.last
        );
    }
    fn idle(&mut self, ms: u64) -> [u8; 8] {
        let end = self.t + Duration::from_millis(ms);
        while self.t < end {
            self.send(self.out);
        }
        self.last
    }
    fn pos(s: &[u8; 8]) -> i32 {
        i32::from_le_bytes([s[4], s[5], s[6], s[7]])
    }
}

fn rec(ccon: u8, cpos: u8, record: u8) -> [u8; 8] {
    [ccon, cpos, record, 0, 0, 0, 0, 0]
}

fn direct(ccon: u8, cpos: u8, cdir: u8, v1: u8, v2: i32) -> [u8; 8] {
    let b = v2.to_le_bytes();
    [ccon, cpos, cdir, v1, b[0], b[1], b[2], b[3]]
}

const MC: u8 = 0x04;
const ACK: u8 = 0x02;
const REF: u8 = 0x80;

/// MTR-DCI enabled in record select and homed with its default method 27.
fn mtr_homed() -> Bench {
    let mut b = Bench::of(Variant::MtrDci);
    b.send(rec(0x03, 0x01, 0));
    let s = b.send(rec(0x03, 0x01, 0));
    assert_eq!(&s[..2], &[0x13, 0x05]);
    b.send(rec(0x03, 0x05, 0));
    b.until(100, "homing ACK", |s| s[1] & ACK != 0);
    b.send(rec(0x03, 0x01, 0));
    b.until(20_000, "homing done", |s| s[1] == 0x85);
    b
}

#[test]
fn mtr_power_on_enable_and_fct_control_bytes() {
    let mut b = Bench::of(Variant::MtrDci);
    // Power-on (after T1): drive blocked, 24VL, MC = 1.
    assert_eq!(&b.send([0; 8])[..2], &[0x10, 0x04]);
    // ENABLE + STOP + HOLD: S2 -> S3 -> S4, one transition per drive cycle.
    let s = b.send(rec(0x03, 0x01, 0));
    assert_eq!(&s[..2], &[0x11, 0x05]);
    let s = b.send(rec(0x03, 0x01, 0));
    assert_eq!(&s[..2], &[0x13, 0x05]);
    // Not referenced: REF = 0. Byte 3 = record 0, bytes 5..8 the actual position (LE).
    assert_eq!(Bench::pos(&s), 100_000);
    // Disable, then FCT takes control (Tab. 5/7): SCON 0x30, SPOS 0x04.
    b.send(rec(0x00, 0x00, 0));
    b.idle(50);
    assert!(b.d.set_fct_control(true));
    assert_eq!(&b.send(rec(0x00, 0x00, 0))[..2], &[0x30, 0x04]);
    // With FCT in control ENABLE is ignored.
    assert_eq!(&b.send(rec(0x03, 0x01, 0))[..2], &[0x30, 0x05]);
    // CCON.LOCK = 1 keeps FCT from taking control.
    b.d.set_fct_control(false);
    b.send(rec(0x20, 0x00, 0));
    assert!(!b.d.set_fct_control(true));
}

#[test]
fn mtr_start_before_homing_is_fault_1_and_reset_acknowledges() {
    let mut b = Bench::of(Variant::MtrDci);
    b.d.write_pnu(404, 2, 50_000).unwrap();
    b.d.write_pnu(406, 2, 20_000).unwrap();
    b.send(rec(0x03, 0x01, 1));
    b.send(rec(0x03, 0x01, 1));
    b.send(rec(0x03, 0x03, 1));
    let s = b.until(50, "fault", |s| s[0] & 0x08 != 0);
    // "Please enforce homing run": fault 1, EMCY 6310h, device-fault bit 0x0200, no motion.
    assert_eq!(b.d.fault_number(), Some(1));
    assert_eq!(b.d.emcy().map(|e| e.code), Some(0x6310));
    assert_eq!(
        b.d.poll_emcy(),
        Some(Emcy {
            code: 0x6310,
            register: 0x21,
            number: 1
        })
    );
    assert_eq!(b.d.read_pnu(205, 0), Ok(0x0200));
    assert_eq!(b.d.read_pnu(201, 1), Ok(1));
    assert_eq!(b.d.read_pnu(200, 1), Ok(1));
    assert_eq!(s[1] & ACK, 0);
    assert_eq!(Bench::pos(&s), 100_000);
    // S6: the drive holds FAULT until a RESET edge.
    b.send(rec(0x03, 0x01, 1));
    let s = b.idle(20);
    assert_eq!(s[0] & 0x0B, 0x09, "FAULT with the stage on (simple fault)");
    let s = b.send(rec(0x0B, 0x01, 1));
    // T10 (simple fault, ENABLE = 1): S3, FAULT cleared, MC = 1; the next cycle T3.
    assert_eq!(s[0], 0x11);
    assert_eq!(s[1] & MC, MC);
    let s = b.send(rec(0x03, 0x01, 1));
    assert_eq!(&s[..2], &[0x13, 0x05]);
    assert_eq!(b.d.fault_number(), None);
    assert_eq!(b.d.poll_emcy().map(|e| e.code), Some(0x0000));
    // Incoming and outgoing events in the diagnostic memory, newest first.
    assert_eq!(b.d.read_pnu(200, 1), Ok(2));
    assert_eq!(b.d.read_pnu(200, 2), Ok(1));
    assert_eq!(b.d.read_pnu(204, 4), Ok(2));
}

#[test]
fn mtr_homing_method_27_references_at_the_switch_edge() {
    let mut b = Bench::of(Variant::MtrDci);
    b.send(rec(0x03, 0x01, 0));
    b.send(rec(0x03, 0x01, 0));
    // HOM rising edge with HOLD (Tab. 5/11): ACK = 1, MC = 0 while HOM = 1.
    let s = b.send(rec(0x03, 0x05, 0));
    assert_eq!(s[1] & (ACK | MC | REF), ACK);
    let s = b.until(200, "moving", |s| s[1] & 0x10 != 0);
    assert_eq!(s[1], 0x13, "HOLD + ACK + MOV");
    // Release HOM: ACK falls, homing goes on.
    let s = b.send(rec(0x03, 0x01, 0));
    assert_eq!(s[1] & (ACK | MC), 0);
    let s = b.until(20_000, "homed", |s| s[1] & MC != 0);
    assert_eq!(s[1], 0x85, "REF + MC + HOLD");
    // AZ = REF (offset 0) reads 0 - PZ offset = 0; REF is where the switch released.
    assert_eq!(Bench::pos(&s), 0);
    assert_eq!(b.d.axis().raw_position(), 5_400);
    assert!(b.d.is_referenced());
}

#[test]
fn mtr_record_start_mc_only_after_the_settling_time() {
    let mut b = mtr_homed();
    b.d.write_pnu(404, 2, 50_000).unwrap();
    b.d.write_pnu(406, 2, 40_000).unwrap();
    b.send(rec(0x03, 0x01, 1));
    let s = b.send(rec(0x03, 0x03, 1));
    // START: ACK = 1, MC = 0 (0x83).
    assert_eq!(s[1], 0x83);
    let s = b.until(100, "moving", |s| s[1] & 0x10 != 0);
    assert_eq!(s[1], 0x93);
    assert_eq!(s[2], 1, "byte 3: the current record after START");
    // Drop START: ACK falls.
    let s = b.send(rec(0x03, 0x01, 1));
    assert_eq!(s[1] & ACK, 0);
    // MC comes only after the position held the window (PNU 1022 = 750) with the profile
    // finished for PNU 1023 = 100 ms.
    let mut entered = None;
    loop {
        let s = b.send(b.out);
        let st = b.d.axis().status();
        if (st.position - 50_000).abs() <= 750 && st.generator_done {
            entered.get_or_insert(b.t);
        } else {
            entered = None;
        }
        if s[1] & MC != 0 {
            assert_eq!(s[1], 0x85);
            let e = entered.expect("MC outside the window");
            assert!(
                b.t - e >= Duration::from_millis(100),
                "settled {:?}",
                b.t - e
            );
            assert!(b.t - e <= Duration::from_millis(102));
            assert!((Bench::pos(&s) - 50_000).abs() <= 750);
            break;
        }
        assert!(b.t < Instant::from_millis(60_000));
    }
    // The RSB echoes the record's relative bit (absolute) and position control: 0.
    assert_eq!(b.last[3], 0);
    assert_eq!(b.d.read_pnu(1041, 0), Ok(i64::from(Bench::pos(&b.last))));
}

#[test]
fn mtr_invalid_record_is_warning_3_and_target_beyond_limit_is_fault_2() {
    let mut b = mtr_homed();
    // Record 5 has speed 0: not executable -> warning 3, WARN only.
    b.send(rec(0x03, 0x01, 5));
    let s = b.send(rec(0x03, 0x03, 5));
    assert_eq!(s[0] & 0x0C, 0x04, "WARN, no FAULT");
    assert_eq!(b.d.read_pnu(205, 0), Ok(0x0100));
    assert!(b.d.poll_emcy().is_none(), "no EMCY for warnings");
    // RESET clears the warning.
    b.send(rec(0x03, 0x01, 5));
    let s = b.send(rec(0x0B, 0x01, 5));
    assert_eq!(s[0] & 0x04, 0);
    // Record 2 beyond the upper software end position (270000): fault 2, EMCY 6320h.
    b.d.write_pnu(404, 3, 300_000).unwrap();
    b.d.write_pnu(406, 3, 10_000).unwrap();
    b.send(rec(0x03, 0x01, 2));
    b.send(rec(0x03, 0x03, 2));
    b.until(20, "fault 2", |s| s[0] & 0x08 != 0);
    assert_eq!(b.d.fault_number(), Some(2));
    assert_eq!(b.d.poll_emcy().map(|e| e.code), Some(0x6320));
}

#[test]
fn mtr_direct_position_bytes_and_motion() {
    let mut b = mtr_homed();
    // OPM direct (0x43): SCON 0x53.
    let s = b.send(direct(0x43, 0x01, 0x00, 50, 30_000));
    assert_eq!(&s[..2], &[0x53, 0x85]);
    let s = b.send(direct(0x43, 0x03, 0x00, 50, 30_000));
    assert_eq!(s[1], 0x83);
    let s = b.until(100, "moving", |s| s[1] == 0x93);
    // Actual value 1: speed in % of PNU 502 (100000 inc/s); 50 % at most.
    assert!(s[3] <= 50);
    b.send(direct(0x43, 0x01, 0x00, 50, 30_000));
    let s = b.until(10_000, "done", |s| s[1] & MC != 0);
    assert_eq!(&s[..3], &[0x53, 0x85, 0x00]);
    assert!((Bench::pos(&s) - 30_000).abs() <= 750);
    // Relative (CDIR.ABS = 1): relative to the last nominal value 30000.
    b.send(direct(0x43, 0x03, 0x01, 100, -10_000));
    b.send(direct(0x43, 0x01, 0x01, 100, -10_000));
    let s = b.until(10_000, "relative done", |s| s[1] & MC != 0);
    assert_eq!(s[2], 0x01, "SDIR.ABS echoes CDIR.ABS");
    assert!((Bench::pos(&s) - 20_000).abs() <= 750);
}

#[test]
fn mtr_direct_force_against_a_stop_and_at_the_stroke_limit() {
    let mut cfg = DriveConfig::new(Variant::MtrDci);
    cfg.axis.environment.load = Load::FixedStop {
        position: 60_000 + 5_400,
        side: Direction::Positive,
    };
    let mut b = Bench::new(cfg);
    b.send(rec(0x03, 0x01, 0));
    b.send(rec(0x03, 0x01, 0));
    b.send(rec(0x03, 0x05, 0));
    b.send(rec(0x03, 0x01, 0));
    b.until(20_000, "homed", |s| s[1] == 0x85);
    // Force prepare: COM = 01 only selects; nothing moves until START.
    b.send(direct(0x43, 0x01, 0x02, 0, 50));
    let s = b.send(direct(0x43, 0x01, 0x02, 0, 50));
    assert_eq!(s[1], 0x85);
    // 50 % of the rated current, speed limit PNU 554 narrowed by byte 4 = 10 %.
    b.send(direct(0x43, 0x03, 0x02, 10, 50));
    let s = b.until(200, "force running", |s| s[2] & 0x10 != 0);
    assert_eq!(s[2], 0x12, "SDIR: VLIM + COM force");
    assert_eq!(s[1] & MC, 0);
    b.send(direct(0x43, 0x01, 0x02, 10, 50));
    let s = b.until(20_000, "force reached", |s| s[1] & MC != 0);
    assert_eq!(s[2], 0x02, "setpoint reached: COM force, no VLIM");
    assert_eq!(b.d.axis().raw_position(), 65_400);
    assert_eq!(b.d.axis().status().current_ma, 1150);

    // Stroke limit: 5000 inc from the start position (PNU 510), moving away from the stop.
    let mut b = mtr_homed();
    b.d.write_pnu(510, 0, 5_000).unwrap();
    b.send(direct(0x43, 0x01, 0x02, 0, 50));
    b.send(direct(0x43, 0x03, 0x02, 10, 50));
    b.send(direct(0x43, 0x01, 0x02, 10, 50));
    let s = b.until(20_000, "stroke limit", |s| s[1] & MC != 0);
    assert_eq!(s[2], 0x20, "XLIM, COM back to position control");
    let p = Bench::pos(&s);
    assert!(
        (5_000..5_600).contains(&p),
        "stopped after the stroke at {p}"
    );
}

#[test]
fn mtr_halt_resume_and_clear() {
    let mut b = mtr_homed();
    b.d.write_pnu(404, 2, 200_000).unwrap();
    b.d.write_pnu(406, 2, 40_000).unwrap();
    b.send(rec(0x03, 0x03, 1));
    b.send(rec(0x03, 0x01, 1));
    b.idle(500);
    // HOLD = 0: brake, SPOS.HOLD = 0, MC stays 0, task kept.
    b.send(rec(0x03, 0x00, 1));
    let s = b.until(2_000, "stopped", |s| s[1] & 0x10 == 0);
    assert_eq!(s[1] & (0x01 | MC), 0);
    let held = Bench::pos(&s);
    b.idle(100);
    assert!((Bench::pos(&b.last) - held).abs() < 100);
    // HOLD = 1 + START: resume the same record to its target.
    b.send(rec(0x03, 0x01, 1));
    b.send(rec(0x03, 0x03, 1));
    b.send(rec(0x03, 0x01, 1));
    let s = b.until(20_000, "resumed to the target", |s| s[1] & MC != 0);
    assert!((Bench::pos(&s) - 200_000).abs() <= 750);
    // Again, but CLEAR deletes the remaining path: Ready, MC = 1 once stopped.
    b.d.write_pnu(404, 2, 20_000).unwrap();
    b.send(rec(0x03, 0x03, 1));
    b.send(rec(0x03, 0x01, 1));
    b.idle(300);
    b.send(rec(0x03, 0x00, 1));
    b.until(2_000, "stopped", |s| s[1] & 0x10 == 0);
    let s = b.send(rec(0x03, 0x40, 1));
    let s = if s[1] & MC == 0 {
        b.until(100, "MC after clear", |s| s[1] & MC != 0)
    } else {
        s
    };
    assert!(Bench::pos(&s) > 100_000, "stopped short of the target");
}

#[test]
fn mtr_jog_positive_phases_and_stop() {
    let mut b = mtr_homed();
    let s = b.send(rec(0x03, 0x09, 0));
    assert_eq!(s[1], 0x83, "REF + ACK + HOLD; MC = 0");
    // Phase 1 (PNU 534 = 2000 ms) at 10 % of PNU 531, then phase 2 at PNU 531 = 10000 inc/s.
    b.idle(1_000);
    assert_eq!(b.d.axis().status().velocity, 1_000);
    let s = b.idle(1_500);
    assert_eq!(b.d.axis().status().velocity, 10_000);
    assert_eq!(s[1], 0x93, "REF + MOV + ACK + HOLD");
    let s = b.send(rec(0x03, 0x01, 0));
    assert_eq!(s[1] & ACK, 0);
    let s = b.until(1_000, "stopped", |s| s[1] & MC != 0);
    assert_eq!(s[1], 0x85);
}

#[test]
fn mtr_teach_stores_the_actual_position() {
    let mut b = mtr_homed();
    b.d.write_pnu(404, 2, 12_345).unwrap();
    b.d.write_pnu(406, 2, 20_000).unwrap();
    b.send(rec(0x03, 0x03, 1));
    b.send(rec(0x03, 0x01, 1));
    b.until(10_000, "at 12345", |s| s[1] & MC != 0);
    let actual = i64::from(Bench::pos(&b.last));
    // Teach record 7's target (PNU 520 = 1, record in byte 3).
    let s = b.send(rec(0x03, 0x21, 7));
    assert_eq!(s[1] & 0x08, 0, "TEACH = 0: ready");
    let s = b.send(rec(0x03, 0x01, 7));
    assert_eq!(s[1] & 0x08, 0x08, "TEACH = 1: value transferred");
    assert_eq!(b.d.read_pnu(404, 8), Ok(actual));
}

#[test]
fn mtr_following_error_is_fault_31_with_dev_and_emcy_8600() {
    let mut b = mtr_homed();
    b.d.write_pnu(404, 2, 100_000).unwrap();
    b.d.write_pnu(406, 2, 50_000).unwrap();
    b.send(rec(0x03, 0x03, 1));
    b.send(rec(0x03, 0x01, 1));
    b.idle(200);
    b.d.inject(Injection::Block, true);
    let s = b.until(2_000, "drag error", |s| s[0] & 0x08 != 0);
    assert_eq!(s[1] & 0x20, 0x20, "SPOS.DEV");
    assert_eq!(b.d.fault_number(), Some(31));
    assert_eq!(b.d.poll_emcy().map(|e| e.code), Some(0x8600));
    assert_eq!(b.d.read_pnu(205, 0), Ok(0x0001));
    // The ENABLE falling edge acknowledges on the MTR-DCI (T9 with ENABLE = 0).
    b.d.inject(Injection::Block, false);
    b.idle(100);
    let s = b.send(rec(0x00, 0x01, 1));
    assert_eq!(s[0] & 0x0F, 0x00);
    assert_eq!(b.d.fault_number(), None);
}

#[test]
fn mtr_load_voltage_fault_needs_the_cause_gone() {
    let mut b = mtr_homed();
    b.d.inject(Injection::SupplyDrop, true);
    let s = b.until(1_000, "fault 70", |s| s[0] & 0x08 != 0);
    assert_eq!(s[0] & 0x10, 0, "24VL = 0");
    assert_eq!(b.d.fault_number(), Some(70));
    assert_eq!(b.d.poll_emcy().map(|e| e.code), Some(0x5112));
    // RESET while the cause is present: T11, FAULT stays.
    b.send(rec(0x03, 0x01, 0));
    let s = b.send(rec(0x0B, 0x01, 0));
    assert_eq!(s[0] & 0x08, 0x08);
    b.d.inject(Injection::SupplyDrop, false);
    b.send(rec(0x03, 0x01, 0));
    // Serious fault: T9 to S2 whatever ENABLE is (MTR-DCI).
    let s = b.send(rec(0x0B, 0x01, 0));
    assert_eq!(s[0], 0x10);
}

#[test]
fn mtr_fpc_read_and_write_once_per_task() {
    let mut b = mtr_homed();
    let codec = Codec::new(drivers::fhpp::fpc::Channel::Classic, ByteOrder::Little);
    let mut t = b.t;
    let mut ask = |b: &mut Bench, req: Request| {
        let bytes = codec.encode_request(req);
        b.d.parameter(&bytes, t);
        t += Duration::from_millis(1);
        b.d.parameter(&bytes, t)
    };
    // Write PNU 1022 (dword) = 1000: the reply echoes it; the task repeats without effect.
    let w = Request::Write(Param::new(1022, 0), Value::Dword(1_000));
    let r = ask(&mut b, w);
    assert_eq!(
        codec.decode_response(&r),
        Ok(Response::Value(Param::new(1022, 0), Value::Dword(1_000)))
    );
    assert_eq!(b.d.read_pnu(1022, 0), Ok(1_000));
    b.d.set_pnu(1022, 0, 750).unwrap();
    let again = ask(&mut b, w);
    assert_eq!(again, r, "reply held");
    assert_eq!(
        b.d.read_pnu(1022, 0),
        Ok(750),
        "a repeated task is not executed again"
    );
    // No task in between -> no reply; then a read.
    let r = ask(&mut b, Request::NoTask);
    assert_eq!(codec.decode_response(&r), Ok(Response::NoReply));
    let r = ask(&mut b, Request::Read(Param::new(1041, 0)));
    assert_eq!(
        codec.decode_response(&r),
        Ok(Response::Value(Param::new(1041, 0), Value::Dword(0)))
    );
    // Classic wire bytes of the read reply: ResID 2 (dword) | PNU 1041 = 0x2411, LE.
    assert_eq!(&r[..4], &[0x00, 0x00, 0x11, 0x24]);
    // A read-only PNU refuses a write with classic error 1.
    let r = ask(&mut b, Request::Write(Param::new(1041, 0), Value::Dword(5)));
    assert_eq!(
        codec.decode_response(&r),
        Ok(Response::Error(Param::new(1041, 0), 1))
    );
    // The same store over SDO: range and access errors with their abort codes.
    let e = b.d.write_pnu(1023, 0, 0).unwrap_err();
    assert_eq!(e.abort_code().code(), 0x0609_0030);
    assert_eq!(e.fpc_number(Variant::MtrDci), 22);
    assert_eq!(
        b.d.write_pnu(1041, 0, 1).unwrap_err().abort_code().code(),
        0x0601_0002
    );
}

/// EMCA enabled in record select and homed on the current position (-35, its default).
fn emca_homed() -> Bench {
    let mut b = Bench::of(Variant::Emca);
    // Power-up (§2.4): SCON 0001.0000, SPOS 0000.0100.
    assert_eq!(&b.last[..2], &[0x10, 0x04]);
    b.send(rec(0x23, 0x01, 0));
    let s = b.send(rec(0x23, 0x01, 0));
    assert_eq!(&s[..2], &[0x13, 0x05]);
    let s = b.send(rec(0x23, 0x05, 0));
    assert_eq!(s[1] & (ACK | MC), ACK);
    b.send(rec(0x23, 0x01, 0));
    let s = b.until(1_000, "homed", |s| s[1] & MC != 0);
    assert_eq!(s[1], 0x85);
    b
}

fn emca_record(b: &mut Bench, n: u8, target: i64, speed: i64, rcb2: i64, next: i64) {
    let d = &mut b.d;
    d.write_pnu(404, n, target).unwrap();
    d.write_pnu(406, n, speed).unwrap();
    d.write_pnu(407, n, 200_000).unwrap();
    d.write_pnu(408, n, 200_000).unwrap();
    d.write_pnu(402, n, rcb2).unwrap();
    d.write_pnu(416, n, next).unwrap();
}

#[test]
fn emca_start_before_homing_is_28h_and_acknowledged_with_the_stage_on() {
    let mut b = Bench::of(Variant::Emca);
    emca_record(&mut b, 1, 10_000, 10_000, 0, 0);
    b.send(rec(0x23, 0x01, 1));
    b.send(rec(0x23, 0x01, 1));
    b.send(rec(0x23, 0x03, 1));
    let s = b.until(50, "fault", |s| s[0] & 0x08 != 0);
    assert_eq!(b.d.fault_number(), Some(0x28));
    assert_eq!(b.d.read_pnu(205, 1), Ok(0x28));
    assert_eq!(b.d.read_pnu(230, 1), Ok(2));
    assert_eq!(b.d.read_pnu(220, 2), Ok(1 << (0x28 - 32)));
    assert_eq!(b.d.read_pnu(201, 1), Ok(0x28));
    assert_eq!(s[0] & 0x01, 0x01, "reaction keeps the output stage on");
    // T10: RESET with ENABLE = 1.
    b.send(rec(0x23, 0x01, 1));
    let s = b.send(rec(0x2B, 0x01, 1));
    assert_eq!(s[0] & 0x0B, 0x01);
    assert_eq!(b.d.read_pnu(205, 1), Ok(0xFFFF));
    let mut codes = Vec::new();
    while let Some(e) = b.d.poll_emcy() {
        codes.push(e.code);
    }
    assert_eq!(codes, vec![0x1000, 0x0000]);
}

#[test]
fn emca_chain_steps_on_mc_position_comparator_and_time() {
    let mut b = emca_homed();
    let act = |pnu: u16, n: u8| (pnu, n);
    // 1: to 20000, step on MC -> 2: to 80000, step when the position comparator [40000, 50000]
    // holds 0 ms -> 3: back to 0, step when 100..200 ms have passed -> 4: to 30000, end.
    emca_record(&mut b, 1, 20_000, 40_000, 0x80 | 1, 2);
    emca_record(&mut b, 2, 80_000, 40_000, 0x80 | 20, 3);
    emca_record(&mut b, 3, 0, 40_000, 0x80 | 23, 4);
    emca_record(&mut b, 4, 30_000, 40_000, 0, 0);
    let (p, n) = act(430, 2);
    b.d.write_pnu(p, n, 40_000).unwrap();
    b.d.write_pnu(431, 2, 50_000).unwrap();
    b.d.write_pnu(439, 3, 100).unwrap();
    b.d.write_pnu(440, 3, 200).unwrap();
    let start = 100_000; // homed at the start position with -35: it reads as 0
    let _ = start;
    b.send(rec(0x23, 0x03, 1));
    b.send(rec(0x23, 0x01, 1));
    let mut seen = vec![1u8];
    let mut switch_pos = Vec::new();
    let mut t3 = None;
    loop {
        let s = b.send(b.out);
        if *seen.last().unwrap() != s[2] {
            seen.push(s[2]);
            switch_pos.push((s[2], Bench::pos(&s), b.t));
            if s[2] == 3 {
                t3 = Some(b.t);
            }
            if s[2] == 4 {
                // Time comparator: record 3 ran 100..200 ms.
                let ran = b.t - t3.unwrap();
                assert!(
                    ran >= Duration::from_millis(100) && ran <= Duration::from_millis(110),
                    "{ran:?}"
                );
            }
            // RC1 once the first condition is met.
            assert_eq!(s[3] & 0x01, 0x01, "RC1");
        }
        if s[1] & MC != 0 {
            break;
        }
        assert!(b.t < Instant::from_millis(60_000), "chain did not end");
    }
    assert_eq!(seen, vec![1, 2, 3, 4]);
    // 1 -> 2 at MC: at 20000.
    assert!((switch_pos[0].1 - 20_000).abs() <= 500);
    // 2 -> 3 inside the comparator window, before reaching 80000.
    assert!(
        (40_000..=50_000).contains(&switch_pos[1].1),
        "{switch_pos:?}"
    );
    let s = b.last;
    // End: MC, RSB = RC1 + RCC (position control), record 4 at its target.
    assert_eq!(s[1], 0x85);
    assert_eq!(s[2], 4);
    assert_eq!(s[3], 0x03);
    assert!((Bench::pos(&s) - 30_000).abs() <= 500);
}

#[test]
fn emca_comparator_with_min_above_max_never_fires_and_aborts_the_chain() {
    let mut b = emca_homed();
    emca_record(&mut b, 1, 50_000, 40_000, 0x80 | 20, 2);
    emca_record(&mut b, 2, 0, 40_000, 0, 0);
    b.d.write_pnu(430, 1, 30_000).unwrap();
    b.d.write_pnu(431, 1, 20_000).unwrap();
    b.send(rec(0x23, 0x03, 1));
    b.send(rec(0x23, 0x01, 1));
    let s = loop {
        let s = b.send(b.out);
        assert_eq!(
            b.d.read_pnu(312, 1).unwrap() & 1,
            0,
            "position comparator active"
        );
        assert_eq!(s[2], 1);
        if s[1] & MC != 0 {
            break s;
        }
        assert!(b.t < Instant::from_millis(20_000));
    };
    // Aborted: MC = 1 with RCC = 0 and RC1 = 0.
    assert_eq!(s[3] & 0x03, 0);
    assert!((Bench::pos(&s) - 50_000).abs() <= 500);
}

#[test]
fn emca_mc_between_chained_records_only_with_pnu_425() {
    for mc425 in [0, 1] {
        let mut b = emca_homed();
        emca_record(&mut b, 1, 10_000, 40_000, 0x80 | 1, 2);
        emca_record(&mut b, 2, 20_000, 40_000, 0, 0);
        b.d.write_pnu(425, 1, mc425).unwrap();
        b.send(rec(0x23, 0x03, 1));
        b.send(rec(0x23, 0x01, 1));
        let mut mc_during_chain = false;
        loop {
            let s = b.send(b.out);
            if s[1] & MC != 0 {
                if s[2] == 1 || (s[2] == 2 && (Bench::pos(&s) - 20_000).abs() > 500) {
                    mc_during_chain = true;
                } else {
                    break;
                }
            }
            assert!(b.t < Instant::from_millis(20_000));
        }
        assert_eq!(mc_during_chain, mc425 == 1, "PNU 425 = {mc425}");
    }
}

#[test]
fn emca_direct_speed_mode_and_halt_ends_it() {
    let mut b = emca_homed();
    // CDIR COM = 10 (speed): byte 4 = ramp % of PNU 560, bytes 5..8 = speed.
    b.send(direct(0x63, 0x01, 0x04, 50, 0));
    b.send(direct(0x63, 0x03, 0x04, 50, 10_000));
    b.send(direct(0x63, 0x01, 0x04, 50, 10_000));
    let s = b.until(2_000, "speed reached", |s| s[1] & MC != 0);
    assert_eq!(s[0], 0x53);
    assert_eq!(s[2], 0x04, "SDIR COM echo: speed");
    let v = Bench::pos(&s);
    assert!((v - 10_000).abs() <= 1_000, "actual value 2 = |speed| {v}");
    // The speed is kept after MC; a new speed task 0 stops.
    b.idle(100);
    assert!(b.d.axis().status().velocity.abs_diff(10_000) <= 1_000);
    b.send(direct(0x63, 0x03, 0x04, 50, 0));
    b.send(direct(0x63, 0x01, 0x04, 50, 0));
    b.until(2_000, "stopped", |s| s[1] & MC != 0);
    assert!(b.d.axis().status().velocity.abs() <= 1_000);
    // HALT ends a speed task while it accelerates (TA2, no SA3): MC once stopped.
    b.send(direct(0x63, 0x03, 0x04, 1, 20_000));
    b.send(direct(0x63, 0x01, 0x04, 1, 20_000));
    b.idle(200);
    let s = b.send(direct(0x63, 0x00, 0x04, 1, 20_000));
    assert_eq!(s[1] & MC, 0);
    let s = b.until(2_000, "halted", |s| s[1] & MC != 0);
    assert_eq!(s[1] & 0x11, 0);
    assert!(b.d.axis().status().velocity.abs() <= 100);
}

#[test]
fn emca_fpc_errors_and_rw2() {
    let mut b = emca_homed();
    let codec = Codec::new(drivers::fhpp::fpc::Channel::Enhanced, ByteOrder::Little);
    let ask = |b: &mut Bench, req: Request| {
        let bytes = codec.encode_request(req);
        b.d.parameter(&bytes, b.t);
        b.send(b.out);
        b.d.parameter(&bytes, b.t)
    };
    // rw2 (PNU 1022) with the output stage on: 0x11.
    let r = ask(
        &mut b,
        Request::Write(Param::new(1022, 1), Value::Dword(100)),
    );
    assert_eq!(
        codec.decode_response(&r),
        Ok(Response::Error(Param::new(1022, 1), 0x11))
    );
    ask(&mut b, Request::NoTask);
    // Out of range (PNU 520: 1..7): 0x02.
    let r = ask(&mut b, Request::Write(Param::new(520, 1), Value::Dword(9)));
    assert_eq!(
        codec.decode_response(&r),
        Ok(Response::Error(Param::new(520, 1), 0x02))
    );
    ask(&mut b, Request::NoTask);
    // A record write and its read-back.
    let r = ask(
        &mut b,
        Request::Write(Param::new(404, 7), Value::Dword(-5i32 as u32)),
    );
    assert_eq!(r[0], 0x15, "FPCS: parameter mode, transferred");
    ask(&mut b, Request::NoTask);
    let r = ask(&mut b, Request::Read(Param::new(404, 7)));
    assert_eq!(
        codec.decode_response(&r),
        Ok(Response::Value(
            Param::new(404, 7),
            Value::Dword(-5i32 as u32)
        ))
    );
    assert_eq!(b.d.read_pnu(404, 7), Ok(-5));
}

#[test]
fn emca_flying_measurement_latches_once_until_read() {
    let mut b = emca_homed();
    b.d.write_pnu(352, 1, 3).unwrap();
    emca_record(&mut b, 1, 100_000, 40_000, 0, 0);
    b.send(rec(0x23, 0x03, 1));
    b.send(rec(0x23, 0x01, 1));
    b.idle(500);
    let t = b.t + Duration::from_micros(1_250);
    b.d.set_sample_input(true, t);
    let latched = b.d.axis().status().position;
    assert!(latched > 0);
    let s = b.idle(20);
    assert_eq!(s[1] & 0x08, 0x08, "SPOS.B3: a sample is waiting");
    // A second edge before the read does not overwrite.
    b.d.set_sample_input(false, b.t);
    b.d.set_sample_input(true, b.t + Duration::from_millis(1));
    assert_eq!(b.d.store().get(Param::new(350, 1)), Ok(latched));
    assert_eq!(b.d.read_pnu(350, 1), Ok(latched));
    // Read: re-armed.
    b.idle(20);
    b.d.set_sample_input(false, b.t);
    b.d.set_sample_input(true, b.t);
    assert_ne!(b.d.read_pnu(350, 1), Ok(latched));
    // The falling edge went to PNU 351.
    assert!(b.d.read_pnu(351, 1).unwrap() > 0);
}

#[test]
fn cmmo_st_bytes_are_big_endian_and_two_edges_are_3ch() {
    let mut b = Bench::of(Variant::CmmoSt);
    assert_eq!(&b.last[..2], &[0x10, 0x04]);
    b.send(rec(0x23, 0x01, 0));
    let s = b.send(rec(0x23, 0x01, 0));
    assert_eq!(&s[..2], &[0x13, 0x05]);
    // Big-endian actual position (Modbus).
    assert_eq!(&s[4..], &100_000i32.to_be_bytes());
    // START and HOM in the same cycle: 3Ch.
    b.send(rec(0x23, 0x07, 1));
    b.until(20, "3Ch", |s| s[0] & 0x08 != 0);
    assert_eq!(b.d.fault_number(), Some(0x3C));
    // Ack, then homing: SPOS 0x87 then 0x85 after HOM drops.
    b.send(rec(0x23, 0x01, 1));
    b.send(rec(0x2B, 0x01, 1));
    b.idle(10);
    b.send(rec(0x23, 0x05, 0));
    let s = b.until(1_000, "homed", |s| s[1] & MC != 0);
    assert_eq!(s[1], 0x87);
    let s = b.send(rec(0x23, 0x01, 0));
    assert_eq!(s[1], 0x85);
}

fn scenario(v: Variant) -> Vec<[u8; 8]> {
    let mut b = Bench::of(v);
    b.send(rec(0x23, 0x01, 0));
    b.send(rec(0x23, 0x01, 0));
    b.send(rec(0x23, 0x05, 0));
    b.send(rec(0x23, 0x01, 0));
    b.idle(if v == Variant::MtrDci { 8_000 } else { 200 });
    let _ = b.d.write_pnu(404, 2, 30_000);
    let _ = b.d.write_pnu(406, 2, 30_000);
    let _ = b.d.write_pnu(404, 1, 30_000);
    let _ = b.d.write_pnu(406, 1, 30_000);
    let _ = b.d.write_pnu(407, 1, 100_000);
    let _ = b.d.write_pnu(408, 1, 100_000);
    b.send(rec(0x23, 0x03, 1));
    b.send(rec(0x23, 0x01, 1));
    b.idle(400);
    b.send(rec(0x23, 0x00, 1));
    b.idle(300);
    b.send(rec(0x23, 0x03, 1));
    b.send(rec(0x23, 0x01, 1));
    b.idle(2_000);
    b.trace
}

#[test]
fn same_calls_same_bytes() {
    for v in [Variant::MtrDci, Variant::Emca, Variant::CmmoSt] {
        let a = scenario(v);
        let b = scenario(v);
        assert_eq!(a, b, "{v:?}");
        // The run did something: positions changed.
        assert!(a.iter().any(|s| s[4..] != a[0][4..]), "{v:?}");
    }
}

#[test]
fn mtr_homing_on_the_negative_stop_minus_17() {
    let mut b = Bench::of(Variant::MtrDci);
    // Method -17 (fixed stop, negative) with AZ 2000 inc (> 0.25 mm) from the stop.
    b.d.write_pnu(1011, 0, -17).unwrap();
    b.d.write_pnu(1010, 0, 2_000).unwrap();
    b.send(rec(0x03, 0x01, 0));
    b.send(rec(0x03, 0x01, 0));
    b.send(rec(0x03, 0x05, 0));
    b.send(rec(0x03, 0x01, 0));
    let s = b.until(20_000, "homed", |s| s[1] & MC != 0);
    assert_eq!(s[1], 0x85);
    assert_eq!(Bench::pos(&s), 0);
    // The mechanical stop is at raw -2000: AZ = stop + 2000.
    assert_eq!(b.d.axis().raw_position(), 0);
    // Changing the method drops the reference and resets the AZ offset (§3.4).
    b.d.write_pnu(1011, 0, 27).unwrap();
    assert!(!b.d.is_referenced());
    assert_eq!(b.d.read_pnu(1010, 0), Ok(0));
    assert_eq!(b.send(b.out)[1] & REF, 0);
}

#[test]
fn mtr_standstill_warning_36_when_pushed_out_of_the_window() {
    let mut b = mtr_homed();
    b.idle(300);
    let raw = b.d.axis().raw_position();
    // A spring on the negative side pushes the axis 1500 inc up (stiffness 1 mA/inc, limit
    // 3450 mA): outside the standstill window (PNU 1042 = 750).
    b.d.environment_mut().load = Load::Spring {
        contact: raw + 3_450 + 1_500,
        side: Direction::Negative,
        stiffness_ma_per_inc: 1,
    };
    let s = b.idle(150);
    assert_eq!(s[1] & 0x40, 0, "not before PNU 1043 = 200 ms");
    let s = b.until(100, "STILL", |s| s[1] & 0x40 != 0);
    assert_eq!(s[0] & 0x0C, 0x04, "warning, no fault");
    assert_eq!(b.d.read_pnu(205, 0), Ok(0x4000));
    assert_eq!(s[1] & MC, MC, "motion stays complete");
    b.d.environment_mut().load = Load::None;
    let s = b.until(100, "back in the window", |s| s[1] & 0x40 == 0);
    assert_eq!(s[0] & 0x04, 0);
}

#[test]
fn mtr_record_32_is_an_illegal_record() {
    let mut b = mtr_homed();
    b.send(rec(0x03, 0x01, 32));
    let s = b.send(rec(0x03, 0x03, 32));
    assert_eq!(s[0] & 0x0C, 0x04);
    assert_eq!(s[1] & ACK, 0, "not started");
    assert_eq!(b.d.active()[0].info.number, 3);
}

#[test]
fn emca_start_condition_wait_appends_after_mc_and_delay_applies() {
    let mut b = emca_homed();
    b.d.write_pnu(583, 1, 2).unwrap();
    b.d.write_pnu(582, 1, 50).unwrap();
    // Direct position: 20000 at 50 % of PNU 540, then (while moving) 0, queued.
    let t0 = b.t;
    b.send(direct(0x63, 0x03, 0x00, 50, 20_000));
    b.send(direct(0x63, 0x01, 0x00, 50, 20_000));
    // The start delay PNU 582 = 50 ms: nothing moves before it expires.
    b.idle(40);
    assert_eq!(b.d.axis().status().velocity, 0);
    b.until(100, "moving", |s| s[1] & 0x10 != 0);
    assert!(b.t - t0 >= Duration::from_millis(50));
    b.idle(100);
    let s = b.send(direct(0x63, 0x03, 0x00, 50, 0));
    assert_eq!(s[1] & ACK, ACK, "the queued task is acknowledged");
    b.send(direct(0x63, 0x01, 0x00, 50, 0));
    // The first task finishes at 20000 first.
    let mut top = 0;
    let s = loop {
        let s = b.send(b.out);
        top = top.max(Bench::pos(&s));
        if s[1] & MC != 0 {
            break s;
        }
        assert!(b.t < Instant::from_millis(30_000));
    };
    assert!(
        (top - 20_000).abs() <= 500,
        "went to 20000 first (max {top})"
    );
    assert!(Bench::pos(&s).abs() <= 500, "then back to 0");
}
