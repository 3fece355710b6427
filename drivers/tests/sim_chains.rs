//! Record chains and comparators of the EMCA and CMMO-ST simulators, driven as a master drives
//! them: FHPP bytes through `exchange`, parameters through `write_pnu`/`read_pnu` (EMCA digest
//! §3.3 and §4.1, CMMO-ST digest §4.2 and §5.4).
//!
//! The expected cycles are not hard-coded: every drive cycle the test records what the drive
//! itself reports (actual position in bytes 5..8, PNU 300.1/300.2, 310.1/310.2, 301.1, 312.1) and
//! an independent oracle finds the first cycle at which each step-enabling condition holds,
//! window held for its damping time. The chain must switch exactly there, PNU 312 must match the
//! oracle every cycle, and RC1/RCC must follow the manual's rules.

use core::time::Duration;

use drivers::fhpp::Variant;
use drivers::sim::axis::{Direction, Load};
use drivers::sim::fhpp_drive::{DriveConfig, FhppDrive};
use drivers::time::Instant;

const MC: u8 = 0x04;
const RC1: u8 = 0x01;
const RCC: u8 = 0x02;

/// Step-enabling conditions (RCB2 bits 0..6).
const COND_MC: u8 = 1;
const COND_POS: u8 = 20;
const COND_VEL: u8 = 21;
const COND_FORCE: u8 = 22;
const COND_TIME: u8 = 23;

/// RCB1 control modes.
const COM_POSITION: i64 = 0x00;
const COM_FORCE: i64 = 0x02;

/// What the drive reported after one of its cycles.
#[derive(Debug, Clone, Copy)]
struct Row {
    t: Instant,
    status: [u8; 8],
    /// Actual position from the cyclic image (bytes 5..8).
    position: i64,
    /// PNU 300.2.
    setpoint: i64,
    /// PNU 310.1.
    velocity: i64,
    /// PNU 310.2.
    setpoint_velocity: i64,
    /// PNU 301.1 [‰ of PNU 555].
    force: i64,
    /// PNU 312.1.
    cmp: u8,
    /// The axis' profile generator has finished (part of the drive's own MC condition).
    generator_done: bool,
}

impl Row {
    fn record(&self) -> u8 {
        self.status[2]
    }
    fn rsb(&self) -> u8 {
        self.status[3]
    }
    fn mc(&self) -> bool {
        self.status[1] & MC != 0
    }
}

/// A master exchanging one image per drive cycle and logging every status.
struct Bench {
    d: FhppDrive,
    v: Variant,
    t: Instant,
    cycle: Duration,
    out: [u8; 8],
    rows: Vec<Row>,
}

impl Bench {
    fn new(v: Variant) -> Bench {
        let cfg = DriveConfig::new(v);
        let cycle = cfg.cycle;
        let mut d = FhppDrive::new(cfg).unwrap();
        d.exchange(&[0; 8], Instant::ZERO);
        Bench {
            d,
            v,
            t: Instant::ZERO,
            cycle,
            out: [0; 8],
            rows: Vec::new(),
        }
    }

    fn pos_of(&self, s: &[u8; 8]) -> i64 {
        let b = [s[4], s[5], s[6], s[7]];
        i64::from(match self.v {
            Variant::CmmoSt => i32::from_be_bytes(b),
            _ => i32::from_le_bytes(b),
        })
    }

    fn pnu(&mut self, pnu: u16) -> i64 {
        self.d.read_pnu(pnu, 1).unwrap()
    }

    fn pnu2(&mut self, pnu: u16, sub: u8) -> i64 {
        self.d.read_pnu(pnu, sub).unwrap()
    }

    fn write(&mut self, pnu: u16, sub: u8, value: i64) {
        self.d
            .write_pnu(pnu, sub, value)
            .unwrap_or_else(|e| panic!("write PNU {pnu}.{sub} = {value}: {e}"));
    }

    /// One bus cycle: `out` arrives, the drive runs its next cycle, the status is logged.
    fn send(&mut self, out: [u8; 8]) -> Row {
        self.out = out;
        self.d.exchange(&out, self.t);
        self.t += self.cycle;
        let status = self.d.exchange(&out, self.t);
        let row = Row {
            t: self.t,
            status,
            position: self.pos_of(&status),
            setpoint: self.pnu2(300, 2),
            velocity: self.pnu(310),
            setpoint_velocity: self.pnu2(310, 2),
            force: self.pnu(301),
            cmp: self.pnu(312) as u8,
            generator_done: self.d.axis().status().generator_done,
        };
        self.rows.push(row);
        row
    }

    /// Repeats the current output until `pred` holds; panics after `max_ms`.
    fn until(&mut self, max_ms: u64, what: &str, pred: impl Fn(&Row) -> bool) -> Row {
        let end = self.t + Duration::from_millis(max_ms);
        while self.t < end {
            let r = self.send(self.out);
            if pred(&r) {
                return r;
            }
        }
        let sw: Vec<(usize, u8)> = switches(&self.rows, 0);
        panic!(
            "{what}: not reached within {max_ms} ms; records {sw:?}, last {:?}",
            self.rows.last()
        );
    }

    /// Repeats the current output for `ms`.
    fn idle_for(&mut self, ms: u64) {
        let end = self.t + Duration::from_millis(ms);
        while self.t < end {
            self.send(self.out);
        }
    }

    /// PNU 402 for `cond`: the EMCA needs B7 to chain, on the CMMO-ST B7 is reserved (0).
    fn rcb2(&self, cond: u8) -> i64 {
        match (self.v, cond) {
            (_, 0) | (Variant::CmmoSt, _) => i64::from(cond),
            _ => i64::from(0x80 | cond),
        }
    }

    /// A record with its motion, step condition and next record.
    fn record(&mut self, n: u8, com: i64, target: i64, speed: i64, cond: u8, next: u8) {
        let rcb2 = self.rcb2(cond);
        self.write(401, n, com);
        self.write(402, n, rcb2);
        self.write(404, n, target);
        self.write(406, n, speed);
        self.write(407, n, 200_000);
        self.write(408, n, 200_000);
        self.write(416, n, i64::from(next));
    }

    /// A comparator window of record `n` (`base` 430 position, 433 velocity, 436 force, 439
    /// time) or of direct mode (`base` 585.., `n` = 1).
    fn window(&mut self, base: u16, n: u8, min: i64, max: i64, damping_ms: Option<i64>) {
        self.write(base, n, min);
        self.write(base + 1, n, max);
        if let Some(d) = damping_ms {
            self.write(base + 2, n, d);
        }
    }

    /// Raw axis increments = reported position + this.
    fn raw_offset(&self) -> i64 {
        self.d.axis().raw_position() - self.d.axis().status().position
    }
}

/// Enabled in record select and homed on the current position (method -35): the actual
/// position reads 0.
fn homed(v: Variant) -> Bench {
    let mut b = Bench::new(v);
    b.write(1011, 1, -35);
    b.send(rec(0x01, 0));
    let r = b.send(rec(0x01, 0));
    assert_eq!(&r.status[..2], &[0x13, 0x05], "{v:?} enabled");
    b.send(rec(0x05, 0));
    b.send(rec(0x01, 0));
    let r = b.until(1_000, "homed", Row::mc);
    assert_eq!(r.status[1], 0x85, "{v:?} homed: REF + MC + HALT");
    assert_eq!(r.position, 0);
    b
}

/// Record select, LOCK + STOP + ENABLE (CCON 0x23).
fn rec(cpos: u8, record: u8) -> [u8; 8] {
    [0x23, cpos, record, 0, 0, 0, 0, 0]
}

/// Direct mode (CCON OPM = 01): CDIR, value 1, value 2 in the variant's byte order.
fn direct(v: Variant, cpos: u8, cdir: u8, v1: u8, v2: i32) -> [u8; 8] {
    let b = match v {
        Variant::CmmoSt => v2.to_be_bytes(),
        _ => v2.to_le_bytes(),
    };
    [0x63, cpos, cdir, v1, b[0], b[1], b[2], b[3]]
}

/// One comparator as the oracle evaluates it.
#[derive(Debug, Clone, Copy)]
struct Win {
    min: i64,
    max: i64,
    damping: Duration,
}

impl Win {
    /// Reads a window back from the drive, as a master would.
    fn read(b: &mut Bench, base: u16, n: u8, damped: bool) -> Win {
        let damping = if damped { b.pnu2(base + 2, n) } else { 0 };
        Win {
            min: b.pnu2(base, n),
            max: b.pnu2(base + 1, n),
            damping: Duration::from_millis(damping as u64),
        }
    }
    fn inside(&self, v: i64) -> bool {
        // min > max: never inside (CMMO-ST Tab. 6.19).
        self.min <= v && v <= self.max
    }
}

/// The four windows of a record or of direct mode, read back from the drive.
#[derive(Debug, Clone, Copy)]
struct Windows([Win; 4]);

impl Windows {
    fn read(b: &mut Bench, base: u16, n: u8) -> Windows {
        Windows([
            Win::read(b, base, n, true),
            Win::read(b, base + 3, n, true),
            Win::read(b, base + 6, n, true),
            Win::read(b, base + 9, n, false),
        ])
    }
}

/// The value comparator `k` (0 position, 1 velocity, 2 force, 3 time) looks at in `row`, the
/// task having started at `t0`.
fn value(k: usize, row: &Row, t0: Instant) -> i64 {
    match k {
        0 => row.position,
        1 => row.velocity,
        2 => row.force,
        _ => (row.t - t0).as_millis() as i64,
    }
}

/// Oracle: for the cycles `rows[from..to]` of a task started at `rows[start]`, whether `inside`
/// has held without a break, on the drive's own samples (the first taken the cycle after the
/// start), for at least `hold`.
fn held(
    rows: &[Row],
    start: usize,
    to: usize,
    hold: Duration,
    inside: impl Fn(&Row) -> bool,
) -> Vec<bool> {
    let mut out = Vec::new();
    let mut entered: Option<Instant> = None;
    for row in &rows[start + 1..to] {
        if inside(row) {
            let e = *entered.get_or_insert(row.t);
            out.push(row.t - e >= hold);
        } else {
            entered = None;
            out.push(false);
        }
    }
    out
}

/// Oracle for PNU 312 over `rows[start+1..to]`.
fn expected_312(rows: &[Row], start: usize, to: usize, w: &Windows) -> Vec<u8> {
    let t0 = rows[start].t;
    let mut bytes = vec![0u8; to - start - 1];
    for (k, win) in w.0.iter().enumerate() {
        let bits = held(rows, start, to, win.damping, |r| {
            win.inside(value(k, r, t0))
        });
        for (byte, on) in bytes.iter_mut().zip(bits) {
            *byte |= u8::from(on) << k;
        }
    }
    bytes
}

/// The row indices at which the record number in byte 3 changes, with the new record.
fn switches(rows: &[Row], from: usize) -> Vec<(usize, u8)> {
    let mut out = vec![(from, rows[from].record())];
    for i in from + 1..rows.len() {
        if rows[i].record() != rows[i - 1].record() {
            out.push((i, rows[i].record()));
        }
    }
    out
}

/// Prints the rows around `c` for a failing assertion.
fn dump(rows: &[Row], c: usize) {
    for r in &rows[c.saturating_sub(6)..(c + 3).min(rows.len())] {
        eprintln!("{r:?}");
    }
}

/// What one record of the test chain waits for.
#[derive(Debug, Clone, Copy)]
enum Step {
    /// The record's own MC: position window PNU 1022 held for PNU 1023 with the generator done.
    Mc { target: i64 },
    /// Comparator 0..3 of the record.
    Cmp(usize),
    /// End of the chain.
    End,
}

/// Runs the chain started at `rows[start]` (records `plan[i].0`) to its end and checks, per
/// record: the switch at exactly the oracle's first cycle, PNU 312 every cycle, RC1 and RCC.
/// Returns the switch rows.
fn check_chain(b: &mut Bench, start: usize, plan: &[(u8, Step)]) -> Vec<usize> {
    let rows = b.rows.clone();
    let sw = switches(&rows, start);
    let seq: Vec<u8> = sw.iter().map(|s| s.1).collect();
    let want: Vec<u8> = plan.iter().map(|p| p.0).collect();
    assert_eq!(seq, want, "{:?}: record sequence", b.v);
    let mc_window = b.pnu(1022);
    let mc_settle = Duration::from_millis(b.pnu(1023) as u64);
    let end = rows.len();
    for (i, &(n, step)) in plan.iter().enumerate() {
        let s = sw[i].0;
        let to = sw.get(i + 1).map_or(end, |x| x.0 + 1);
        let w = Windows::read(b, 430, n);
        let exp = expected_312(&rows, s, to, &w);
        // PNU 312 follows the running record's comparators every cycle (the switching cycle
        // already shows the next record's).
        let last = if i + 1 < plan.len() { to - 1 } else { to };
        for c in s + 1..last {
            assert_eq!(
                rows[c].cmp,
                exp[c - s - 1],
                "{:?} record {n}: PNU 312 at cycle {} ({:?})",
                b.v,
                c - s,
                rows[c]
            );
        }
        let fired = match step {
            Step::End => None,
            Step::Cmp(k) => {
                let bits: Vec<bool> = exp.iter().map(|e| e & (1 << k) != 0).collect();
                Some(bits.iter().position(|x| *x).map(|p| s + 1 + p))
            }
            Step::Mc { target } => {
                // The switching cycle's flag already belongs to the next record's motion (the
                // command resets it); what the drive sampled was the flag of the cycle before.
                let mut rows = rows.clone();
                if let Some(&(c, _)) = sw.get(i + 1) {
                    rows[c].generator_done = rows[c - 1].generator_done;
                }
                let bits = held(&rows, s, to, mc_settle, |r| {
                    r.generator_done
                        && r.setpoint == target
                        && r.setpoint_velocity == 0
                        && r.position.abs_diff(target) <= mc_window as u64
                });
                Some(bits.iter().position(|x| *x).map(|p| s + 1 + p))
            }
        };
        if let Some(f) = fired {
            let Some(&(switched, _)) = sw.get(i + 1) else {
                panic!("{:?} record {n}: no switch ({:?})", b.v, rows.last());
            };
            let f = f.unwrap_or_else(|| {
                dump(&rows, switched);
                panic!("{:?} record {n}: the condition never held", b.v)
            });
            if switched != f {
                dump(&rows, f);
            }
            assert_eq!(
                sw[i + 1].0,
                f,
                "{:?} record {n} ({step:?}): switched at cycle {}, the condition held from cycle {}",
                b.v,
                sw[i + 1].0 - s,
                f - s
            );
        }
        // RC1 from the first step on; RCC never before the end; MC stays 0 inside the chain
        // (PNU 425 = 0).
        for (c, r) in rows.iter().enumerate().take(to.min(end)).skip(s) {
            let stepped = c >= sw.get(1).map_or(usize::MAX, |x| x.0);
            assert_eq!(r.rsb() & RC1 != 0, stepped, "{:?} RC1 at {r:?}", b.v);
            if c + 1 < end {
                assert_eq!(r.rsb() & RCC, 0, "{:?} RCC before the end", b.v);
                assert!(!r.mc(), "{:?} MC inside the chain at {r:?}", b.v);
            }
        }
    }
    sw.iter().map(|s| s.0).collect()
}

/// START record 1 and run until MC; returns the index of the START cycle.
fn run(b: &mut Bench, max_ms: u64) -> usize {
    b.send(rec(0x01, 1));
    let start = b.rows.len();
    b.send(rec(0x03, 1));
    b.send(rec(0x01, 1));
    b.until(max_ms, "chain end (MC)", Row::mc);
    start
}

/// 1 position, MC -> 2 position, position comparator -> 3 position (reversing), velocity
/// comparator (negative window) -> 4 position, time comparator -> 5 force into a spring,
/// force comparator (negative window) -> 6 position, end.
fn full_chain(v: Variant) {
    let mut b = homed(v);
    b.record(1, COM_POSITION, 50_000, 40_000, COND_MC, 2);
    b.record(2, COM_POSITION, 80_000, 40_000, COND_POS, 3);
    b.window(430, 2, 60_000, 70_000, Some(100));
    b.record(3, COM_POSITION, 0, 40_000, COND_VEL, 4);
    b.window(433, 3, -45_000, -35_000, Some(30));
    b.record(4, COM_POSITION, 72_000, 10_000, COND_TIME, 5);
    b.window(439, 4, 300, 400, None);
    // Force record: push in the positive direction with 700 ‰ at 5000 SINC/s at most.
    b.record(5, COM_FORCE, 0, 5_000, COND_FORCE, 6);
    b.write(442, 5, 700);
    b.window(436, 5, 500, 800, Some(30));
    b.record(6, COM_POSITION, 40_000, 40_000, 0, 0);
    // Windows that are not step conditions still show in PNU 312.
    b.window(430, 1, 20_000, 30_000, Some(20));
    b.window(433, 2, 39_000, 41_000, Some(10));
    b.window(439, 3, 50, 60, None);
    b.window(430, 6, 35_000, 45_000, Some(40));
    b.window(439, 6, 500, 2_000, None);
    // A spring beyond 75000: 1 mA more per increment of compression.
    let contact = 75_000 + b.raw_offset();
    b.d.environment_mut().load = Load::Spring {
        contact,
        side: Direction::Positive,
        stiffness_ma_per_inc: 1,
    };
    let start = run(&mut b, 20_000);
    let sw = check_chain(
        &mut b,
        start,
        &[
            (1, Step::Mc { target: 50_000 }),
            (2, Step::Cmp(0)),
            (3, Step::Cmp(1)),
            (4, Step::Cmp(3)),
            (5, Step::Cmp(2)),
            (6, Step::End),
        ],
    );
    let rows = &b.rows;
    // The conditions fired where the physics says: inside the position window on the way to
    // 80000, reversing at about -40000 SINC/s, pressed into the spring.
    assert!((60_000..=70_000).contains(&rows[sw[2]].position));
    assert!(rows[sw[2]].velocity > 0);
    assert!((-45_000..=-35_000).contains(&rows[sw[3]].velocity));
    assert!(rows[sw[5]].position > 75_000, "force step in the spring");
    // The time comparator: exactly the first cycle with 300 ms since record 4 started.
    let t4 = rows[sw[3]].t;
    let ran = rows[sw[4]].t - t4;
    assert!(ran >= Duration::from_millis(300) && ran < Duration::from_millis(300) + b.cycle);
    // Each comparator condition had been inside its window before it fired, for its damping
    // time: a cycle earlier it was not yet active.
    for (k, i) in [(0usize, 1usize), (1, 2), (2, 4)] {
        let n = b.rows[sw[i]].record();
        let w = Windows::read(&mut b, 430, n).0[k];
        let rows = &b.rows;
        let t0 = rows[sw[i]].t;
        let fire = sw[i + 1];
        let entered = (sw[i] + 1..=fire)
            .rev()
            .take_while(|&c| w.inside(value(k, &rows[c], t0)))
            .last()
            .unwrap();
        assert!(rows[fire].t - rows[entered].t >= w.damping);
        assert!(rows[fire - 1].t - rows[entered].t < w.damping);
    }
    // End: MC, record 6 at its target, RSB = RC1 + RCC (COM echo position).
    let last = *b.rows.last().unwrap();
    assert_eq!(last.status[1], 0x85);
    assert_eq!(last.record(), 6);
    assert_eq!(last.rsb(), RC1 | RCC);
    assert!(last.position.abs_diff(40_000) <= 500);
    // After the end PNU 312 keeps following record 6's comparators (the time window closes
    // 2 s after its start), as it does in direct mode.
    b.idle_for(1_500);
    let s6 = sw[5];
    let w = Windows::read(&mut b, 430, 6);
    let rows = &b.rows;
    let exp = expected_312(rows, s6, rows.len(), &w);
    for (c, e) in (s6 + 1..rows.len()).zip(&exp) {
        assert_eq!(
            rows[c].cmp, *e,
            "{v:?} PNU 312 after the end: {:?}",
            rows[c]
        );
    }
    assert_eq!(
        exp.last().map(|e| e & 0x09),
        Some(0x01),
        "{v:?} time window closed"
    );
}

#[test]
fn emca_chain_steps_on_mc_position_velocity_time_and_force() {
    full_chain(Variant::Emca);
}

#[test]
fn cmmo_st_chain_steps_on_mc_position_velocity_time_and_force() {
    full_chain(Variant::CmmoSt);
}

/// Chains whose condition never holds: MC = 1 with RCC = 0 at the record's own MC.
fn aborted_chains(v: Variant) {
    // (a) The position window is crossed in about 250 ms, shorter than its damping time: it
    // never fires, record 2 runs to its target. RC1 = 1 from the MC step of record 1.
    let mut b = homed(v);
    b.record(1, COM_POSITION, 20_000, 40_000, COND_MC, 2);
    b.record(2, COM_POSITION, 80_000, 40_000, COND_POS, 3);
    b.window(430, 2, 40_000, 50_000, Some(300));
    b.record(3, COM_POSITION, 0, 40_000, 0, 0);
    let start = run(&mut b, 20_000);
    let sw = check_chain(
        &mut b,
        start,
        &[(1, Step::Mc { target: 20_000 }), (2, Step::End)],
    );
    let rows = &b.rows;
    assert!(
        rows[sw[1]..]
            .iter()
            .any(|r| (40_000..=50_000).contains(&r.position)),
        "the window was crossed"
    );
    let last = *rows.last().unwrap();
    assert_eq!(last.record(), 2);
    assert_eq!(
        last.rsb() & (RC1 | RCC),
        RC1,
        "aborted after the first step"
    );
    assert!(last.position.abs_diff(80_000) <= 500);
    assert_eq!(last.cmp & 1, 0);

    // (b) A position window the motion never enters, (c) a velocity comparator with
    // min > max around every speed the axis runs: neither ever fires, RC1 = RCC = 0.
    for (base, min, max) in [(430u16, 200_000i64, 210_000i64), (433, 45_000, -45_000)] {
        let mut b = homed(v);
        let cond = if base == 430 { COND_POS } else { COND_VEL };
        b.record(1, COM_POSITION, 50_000, 40_000, cond, 2);
        b.record(2, COM_POSITION, 0, 40_000, 0, 0);
        b.window(base, 1, min, max, Some(0));
        let start = run(&mut b, 20_000);
        check_chain(&mut b, start, &[(1, Step::End)]);
        let bit = if base == 430 { 1 } else { 2 };
        assert!(b.rows[start..].iter().all(|r| r.cmp & bit == 0));
        let last = *b.rows.last().unwrap();
        assert_eq!(last.status[1] & MC, MC);
        assert_eq!(last.record(), 1);
        assert_eq!(last.rsb() & (RC1 | RCC), 0, "{v:?} window {min}..{max}");
        assert!(last.position.abs_diff(50_000) <= 500);
    }

    // (d) A force record pressing a spring with 700 ‰ never reaches a [900, 1000] window: it
    // ends at its own MC (force reached) with RCC = 0; the EMCA echoes COM = force in RSB.
    let mut b = homed(v);
    b.record(1, COM_FORCE, 0, 5_000, COND_FORCE, 2);
    b.write(442, 1, 700);
    b.window(436, 1, 900, 1_000, Some(0));
    b.record(2, COM_POSITION, 0, 40_000, 0, 0);
    let contact = 2_000 + b.raw_offset();
    b.d.environment_mut().load = Load::Spring {
        contact,
        side: Direction::Positive,
        stiffness_ma_per_inc: 1,
    };
    let start = run(&mut b, 20_000);
    check_chain(&mut b, start, &[(1, Step::End)]);
    let last = *b.rows.last().unwrap();
    assert!(
        (650..=750).contains(&last.force),
        "{v:?}: pressing, {last:?}"
    );
    assert!(last.position > 2_000);
    let com_force = if v == Variant::Emca { 0x04 } else { 0 };
    // (VLIM may still be set: force MC comes from the current window, possibly while the
    // spring is still being compressed at the speed limit.)
    assert_eq!((last.record(), last.rsb() & 0x0F), (1, com_force), "{v:?}");
}

#[test]
fn emca_chain_aborts_when_a_condition_never_holds() {
    aborted_chains(Variant::Emca);
}

#[test]
fn cmmo_st_chain_aborts_when_a_condition_never_holds() {
    aborted_chains(Variant::CmmoSt);
}

/// Direct mode: the global comparators PNU 585..595 in PNU 312, every cycle of a position task.
fn direct_comparators(v: Variant) {
    let mut b = homed(v);
    b.window(585, 1, 20_000, 30_000, Some(50));
    b.window(588, 1, 30_000, 100_000, Some(20));
    b.window(591, 1, 100, 1_000, Some(10));
    b.window(594, 1, 100, 200, None);
    let w = Windows::read(&mut b, 585, 1);
    b.send(direct(v, 0x01, 0x00, 0, 0));
    b.send(direct(v, 0x01, 0x00, 0, 0));
    let start = b.rows.len();
    // START: absolute position 60000, byte 4 = speed in % of PNU 540.
    b.send(direct(v, 0x03, 0x00, 50, 60_000));
    b.send(direct(v, 0x01, 0x00, 50, 60_000));
    b.until(10_000, "direct MC", Row::mc);
    b.idle_for(100);
    let rows = &b.rows;
    let exp = expected_312(rows, start, rows.len(), &w);
    for (c, e) in (start + 1..rows.len()).zip(&exp) {
        assert_eq!(
            rows[c].cmp,
            *e,
            "{v:?} PNU 312 at cycle {} {:?}",
            c - start,
            rows[c]
        );
    }
    // Every comparator went active at some point, so the comparison above is not vacuous.
    let any = exp.iter().fold(0, |a, e| a | e);
    assert_eq!(any, 0x0F, "{v:?}");
    assert!(rows.last().unwrap().position.abs_diff(60_000) <= 500);
}

#[test]
fn emca_direct_mode_comparators_585_to_595() {
    direct_comparators(Variant::Emca);
}

#[test]
fn cmmo_st_direct_mode_comparators_585_to_595() {
    direct_comparators(Variant::CmmoSt);
}

/// A step condition that fires with no next record (PNU 416 = 0, outside 1..64) is a jump to an
/// invalid record (CMMO-ST digest §4.2 rule 8): the drive reports the record-number fault and
/// stops; it must not report MC while the axis is still on its way.
fn chain_into_record_0(v: Variant) {
    let mut b = homed(v);
    b.record(1, COM_POSITION, 50_000, 40_000, COND_POS, 0);
    b.window(430, 1, 10_000, 20_000, Some(0));
    b.send(rec(0x01, 1));
    let start = b.rows.len();
    b.send(rec(0x03, 1));
    b.send(rec(0x01, 1));
    let fault = b.until(2_000, "record-number fault", |r| r.status[0] & 0x08 != 0);
    let expected = if v == Variant::Emca { 0x2C } else { 0x3F };
    assert_eq!(b.d.fault_number(), Some(expected), "{v:?}");
    assert!(
        (10_000..=20_000).contains(&fault.position),
        "{v:?}: fault where the comparator fired, at {}",
        fault.position
    );
    for r in &b.rows[start..] {
        assert!(!r.mc(), "{v:?}: MC while moving {r:?}");
    }
    b.idle_for(500);
    let last = *b.rows.last().unwrap();
    assert!(last.position < 30_000, "{v:?}: the move was stopped");
    assert_eq!(last.velocity, 0);
}

#[test]
fn emca_chain_into_record_0_is_fault_2ch() {
    chain_into_record_0(Variant::Emca);
}

#[test]
fn cmmo_st_chain_into_record_0_is_fault_3fh() {
    chain_into_record_0(Variant::CmmoSt);
}

/// The damping time restarts when the value leaves the window: the velocity window is crossed
/// too fast while accelerating (no step) and fires only while braking, held long enough.
fn window_left_before_damping(v: Variant) {
    let mut b = homed(v);
    b.record(1, COM_POSITION, 60_000, 40_000, COND_VEL, 2);
    b.write(407, 1, 400_000);
    b.write(408, 1, 100_000);
    b.window(433, 1, 20_000, 30_000, Some(50));
    b.record(2, COM_POSITION, 0, 40_000, 0, 0);
    let start = run(&mut b, 20_000);
    let sw = check_chain(&mut b, start, &[(1, Step::Cmp(1)), (2, Step::End)]);
    let rows = &b.rows;
    let inside = |c: &usize| (20_000..=30_000).contains(&rows[*c].velocity);
    let first = (start + 1..sw[1]).find(inside).unwrap();
    let left = (first..sw[1]).find(|c| !inside(c)).unwrap();
    assert!(
        rows[left].velocity > 30_000,
        "{v:?}: left the window accelerating"
    );
    assert!(rows[left].t - rows[first].t < Duration::from_millis(50));
    assert!(rows[sw[1]].position > 52_000, "{v:?}: fired while braking");
    let last = *rows.last().unwrap();
    assert_eq!((last.record(), last.rsb()), (2, RC1 | RCC));
    assert!(last.position.abs() <= 500);
}

#[test]
fn emca_window_left_before_the_damping_time_does_not_fire() {
    window_left_before_damping(Variant::Emca);
}

#[test]
fn cmmo_st_window_left_before_the_damping_time_does_not_fire() {
    window_left_before_damping(Variant::CmmoSt);
}
