//! The record table as the drive executes it: one record read from the PNU store
//! ([`Record::load`]) and the chain that steps from record to record on the step-enabling
//! conditions ([`Chain`]).
//!
//! MTR-DCI (digest 000 §4): records 1..31 with RCB1 (relative bit only), target, velocity and
//! acceleration; no chaining (the step condition is never read). EMCA / CMMO-ST (digest 002 §3,
//! 001 §4): records 1..64 with the full field set; chaining per RCB2 (PNU 402: condition in bits
//! 0..6, EMCA bit 7 "activate"), next record PNU 416, start delay 426, MC between records 425,
//! final speed 423, and the four comparators 430..440 ([`super::comparator`]).
//!
//! Chain rules (CMMO-ST digest §4.2 model rules, EMCA §3.3):
//! - the running record's condition is evaluated every drive cycle; the first time one is met,
//!   RSB.RC1 = 1, and the drive switches to PNU 416 of the record on the fly;
//! - a record without a chaining condition ends the chain at its MC with RSB.RCC = 1;
//! - a record whose comparator/time condition was never met when it reaches MC aborts the chain:
//!   MC = 1, RCC = 0;
//! - loops are allowed; a jump to an invalid record (PNU 416 = 0 included) is an error the
//!   drive reports.

use crate::fhpp::pnu::{ComparatorStatus, ParamStore, Rcb1, Rcb2, StepCondition, record_subindex};
use crate::fhpp::state::StartCondition;
use crate::fhpp::{ControlMode, Variant, fpc::Param};
use crate::time::Instant;

use super::comparator::{ComparatorParams, ComparatorSet, RECORD_BASE, Sample};

/// One record, decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Record {
    /// The record number (1..=31 or 1..=64).
    pub number: u8,
    /// RCB1 (PNU 401).
    pub rcb1: Rcb1,
    /// RCB2 (PNU 402); always "inactive" on the MTR-DCI.
    pub rcb2: Rcb2,
    /// Target position (PNU 404) \[inc / SINC\].
    pub target: i64,
    /// Speed (PNU 406) \[inc/s / SINC/s\]: position max speed, force speed limit.
    pub velocity: i64,
    /// Acceleration (PNU 407).
    pub acceleration: i64,
    /// Deceleration (PNU 408; the MTR-DCI ramps symmetrically with PNU 407).
    pub deceleration: i64,
    /// Next record (PNU 416; 0 = none).
    pub next: u8,
    /// Torque limitation (PNU 418) \[‰ of PNU 555\].
    pub torque_limit: i64,
    /// RCB3 (PNU 421): what a START does while this record runs.
    pub start_condition: StartCondition,
    /// Final speed (PNU 423); the speed setpoint of a speed record.
    pub final_speed: i64,
    /// Following-error window (PNU 424; 0 = not monitored by the record).
    pub max_deviation: i64,
    /// MC visible when this record finishes inside a chain (PNU 425).
    pub mc_in_chain: bool,
    /// Start delay (PNU 426) \[ms\].
    pub delay_ms: u64,
    /// Stroke limit of a speed/force record from its start position (PNU 427).
    pub stroke_limit: i64,
    /// The comparators (PNU 430..440).
    pub comparators: ComparatorParams,
    /// Speed setpoint of a speed record (PNU 441).
    pub speed_setpoint: i64,
    /// Force setpoint of a force record (PNU 442) \[‰\].
    pub force_setpoint: i64,
}

/// Why a record cannot run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, thiserror::Error)]
pub enum RecordError {
    /// The number is outside 1..=31 (MTR-DCI) or 1..=64.
    #[error("record {record} out of range 1..={max}")]
    OutOfRange {
        /// The record number.
        record: u8,
        /// The device's last record.
        max: u8,
    },
    /// COM = 11, an unsupported mode, or an undefined step-enabling condition.
    #[error("record {record} is invalid (RCB1 {rcb1:#04x}, RCB2 {rcb2:#04x})")]
    Invalid {
        /// The record number.
        record: u8,
        /// PNU 401.
        rcb1: u8,
        /// PNU 402.
        rcb2: u8,
    },
    /// Speed 0 (a position or force record never finishes).
    #[error("record {record} is not executable: speed 0")]
    NotExecutable {
        /// The record number.
        record: u8,
    },
}

impl Record {
    /// Reads record `number` from `store`.
    pub fn load<const N: usize>(
        store: &ParamStore<N>,
        variant: Variant,
        number: u8,
    ) -> Result<Record, RecordError> {
        let max = variant.max_record();
        let Some(sub) = record_subindex(variant, number).filter(|_| number >= 1) else {
            return Err(RecordError::OutOfRange {
                record: number,
                max,
            });
        };
        let get = |pnu: u16| store.get(Param::new(pnu, sub)).ok();
        let g = |pnu: u16| get(pnu).unwrap_or(0);
        let rcb1_raw = g(401) as u8;
        let rcb2_raw = if variant.has_record_chaining() {
            g(402) as u8
        } else {
            0
        };
        let rcb1 = Rcb1::from_byte(rcb1_raw, variant);
        let rcb2 = Rcb2::from_byte(rcb2_raw);
        let invalid_condition = matches!(rcb2.condition, StepCondition::Invalid(_));
        if !variant.supports(rcb1.com) || invalid_condition {
            return Err(RecordError::Invalid {
                record: number,
                rcb1: rcb1_raw,
                rcb2: rcb2_raw,
            });
        }
        let full = variant.has_record_chaining();
        let opt = |pnu: u16, default: i64| if full { g(pnu) } else { default };
        let acceleration = g(407);
        let r = Record {
            number,
            rcb1,
            rcb2,
            target: g(404),
            velocity: g(406),
            acceleration,
            deceleration: opt(408, acceleration),
            next: opt(416, 0) as u8,
            torque_limit: opt(418, 1000),
            start_condition: StartCondition::from_bits(opt(421, 0) as u8),
            final_speed: opt(423, 0),
            max_deviation: opt(424, 0),
            mc_in_chain: opt(425, 0) != 0,
            delay_ms: opt(426, 0).max(0) as u64,
            stroke_limit: opt(427, 0),
            comparators: if full {
                ComparatorParams::from_pnus(RECORD_BASE, get)
            } else {
                ComparatorParams::default()
            },
            speed_setpoint: opt(441, 0),
            force_setpoint: opt(442, 0),
        };
        let needs_speed = matches!(rcb1.com, ControlMode::Position | ControlMode::Force);
        if needs_speed && r.velocity <= 0 {
            return Err(RecordError::NotExecutable { record: number });
        }
        Ok(r)
    }

    /// Whether this record hands over to PNU 416 by itself on `variant`.
    pub const fn chains(&self, variant: Variant) -> bool {
        self.rcb2.chains(variant)
    }
}

/// What the chain does after a drive cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Verdict {
    /// The record keeps running.
    Running,
    /// The step-enabling condition was met: continue with this record (on the fly). It is PNU
    /// 416 as stored, so it can be 0 or out of range: the drive reports that as its fault.
    Next(u8),
    /// The record reached MC and the chain ends; `complete` is RSB.RCC.
    End {
        /// RCC: the chain ran to its end (false: a condition was never met).
        complete: bool,
    },
}

/// The running record (and the chain it belongs to).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Chain {
    record: Record,
    started: Instant,
    comparators: ComparatorSet,
    rc1: bool,
    rcc: bool,
}

impl Chain {
    /// The first record of a chain, started by START at `now`.
    pub fn start(record: Record, now: Instant) -> Chain {
        Chain {
            record,
            started: now,
            comparators: ComparatorSet::new(record.comparators),
            rc1: false,
            rcc: false,
        }
    }

    /// The next record of the chain, entered at `now`: the time base and the comparators
    /// restart; RC1 stays.
    pub fn advance(&mut self, record: Record, now: Instant) {
        self.record = record;
        self.started = now;
        self.comparators = ComparatorSet::new(record.comparators);
    }

    /// The running record.
    pub const fn record(&self) -> &Record {
        &self.record
    }

    /// When the running record started.
    pub const fn started(&self) -> Instant {
        self.started
    }

    /// RSB.RC1: the first step-enabling condition was reached.
    pub const fn rc1(&self) -> bool {
        self.rc1
    }

    /// RSB.RCC: the chain ran to its end (meaningful with MC = 1).
    pub const fn rcc(&self) -> bool {
        self.rcc
    }

    /// The comparator status of the running record (PNU 312).
    pub const fn comparators(&self) -> &ComparatorSet {
        &self.comparators
    }

    /// Updates the comparators only (PNU 312), without stepping: the cycles in which the
    /// record does not run (halted, after the chain ended), so the status keeps following the
    /// values as it does in direct mode. `sample.elapsed_ms` is filled in here.
    pub fn observe(&mut self, sample: Sample, now: Instant) -> ComparatorStatus {
        let elapsed = now.saturating_duration_since(self.started).as_millis() as i64;
        let s = Sample {
            elapsed_ms: elapsed,
            ..sample
        };
        self.comparators.update(&s, now)
    }

    /// Evaluates one drive cycle: the comparators with `sample` (its `elapsed_ms` is filled in
    /// here), then the step-enabling condition. `mc` is the record's own motion-complete
    /// condition (window held for the settling time).
    pub fn evaluate(
        &mut self,
        variant: Variant,
        mc: bool,
        sample: Sample,
        now: Instant,
    ) -> Verdict {
        let st = self.observe(sample, now);
        if !self.record.chains(variant) {
            if mc {
                self.rcc = true;
                return Verdict::End { complete: true };
            }
            return Verdict::Running;
        }
        let met = match self.record.rcb2.condition {
            StepCondition::Mc => mc,
            StepCondition::Position => st.position,
            StepCondition::Velocity => st.speed,
            StepCondition::Force => st.force,
            StepCondition::Time => st.time,
            StepCondition::Inactive | StepCondition::Invalid(_) => false,
        };
        if met {
            self.rc1 = true;
            // Even PNU 416 = 0: a jump outside 1..=64 is the drive's invalid-record fault, not
            // the end of the chain (which would report MC with the axis still moving).
            return Verdict::Next(self.record.next);
        }
        if mc {
            // The record finished without its condition: the chain is aborted.
            self.rcc = false;
            return Verdict::End { complete: false };
        }
        Verdict::Running
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fhpp::pnu::ParamStore;

    type Store = ParamStore<4096>;

    fn set(s: &mut Store, pnu: u16, rec: u8, v: i64) {
        s.set(Param::new(pnu, rec), v).unwrap();
    }

    #[test]
    fn mtr_dci_records_never_chain_and_refuse_speed_zero() {
        let mut s = Store::new(Variant::MtrDci).unwrap();
        // MTR-DCI record n sits at IND n + 1.
        s.set(Param::new(404, 4), 12_345).unwrap();
        s.set(Param::new(406, 4), 20_000).unwrap();
        let r = Record::load(&s, Variant::MtrDci, 3).unwrap();
        assert_eq!(r.target, 12_345);
        assert_eq!(r.deceleration, r.acceleration);
        assert!(!r.chains(Variant::MtrDci));
        assert_eq!(
            Record::load(&s, Variant::MtrDci, 4),
            Err(RecordError::NotExecutable { record: 4 })
        );
        assert_eq!(
            Record::load(&s, Variant::MtrDci, 32),
            Err(RecordError::OutOfRange {
                record: 32,
                max: 31
            })
        );
    }

    #[test]
    fn emca_needs_bit_7_to_chain_cmmo_does_not() {
        for (variant, rcb2, chains) in [
            (Variant::Emca, 0x01, false),
            (Variant::Emca, 0x81, true),
            (Variant::CmmoSt, 0x01, true),
        ] {
            let mut s = Store::new(variant).unwrap();
            set(&mut s, 402, 1, rcb2);
            set(&mut s, 406, 1, 1000);
            let r = Record::load(&s, variant, 1).unwrap();
            assert_eq!(r.chains(variant), chains, "{variant:?} {rcb2:#x}");
        }
    }

    #[test]
    fn invalid_com_or_condition_is_an_invalid_record() {
        let mut s = Store::new(Variant::CmmoSt).unwrap();
        set(&mut s, 406, 1, 1000);
        set(&mut s, 401, 1, 0b110);
        assert!(matches!(
            Record::load(&s, Variant::CmmoSt, 1),
            Err(RecordError::Invalid { record: 1, .. })
        ));
        set(&mut s, 401, 1, 0);
        set(&mut s, 402, 1, 5);
        assert!(matches!(
            Record::load(&s, Variant::CmmoSt, 1),
            Err(RecordError::Invalid { .. })
        ));
    }

    #[test]
    fn chain_steps_on_its_condition_and_aborts_without_it() {
        let mut s = Store::new(Variant::Emca).unwrap();
        set(&mut s, 406, 1, 1000);
        set(&mut s, 402, 1, 0x80 | 23); // time comparator
        set(&mut s, 416, 1, 2);
        set(&mut s, 439, 1, 20);
        set(&mut s, 440, 1, 30);
        let r1 = Record::load(&s, Variant::Emca, 1).unwrap();
        let t0 = Instant::from_millis(100);
        let mut c = Chain::start(r1, t0);
        let smp = Sample::default();
        assert_eq!(
            c.evaluate(Variant::Emca, false, smp, Instant::from_millis(110)),
            Verdict::Running
        );
        assert!(!c.rc1());
        assert_eq!(
            c.evaluate(Variant::Emca, false, smp, Instant::from_millis(120)),
            Verdict::Next(2)
        );
        assert!(c.rc1());
        // A time window never reached before MC aborts: RCC = 0.
        set(&mut s, 439, 1, 500);
        set(&mut s, 440, 1, 400); // min > max: never active
        let r1 = Record::load(&s, Variant::Emca, 1).unwrap();
        let mut c = Chain::start(r1, t0);
        for t in 100..200 {
            assert_eq!(
                c.evaluate(Variant::Emca, false, smp, Instant::from_millis(t)),
                Verdict::Running
            );
        }
        assert_eq!(
            c.evaluate(Variant::Emca, true, smp, Instant::from_millis(200)),
            Verdict::End { complete: false }
        );
        assert!(!c.rcc());
    }

    #[test]
    fn a_met_condition_without_next_record_is_a_jump_to_record_0() {
        let mut s = Store::new(Variant::CmmoSt).unwrap();
        set(&mut s, 406, 1, 1000);
        set(&mut s, 402, 1, 23);
        set(&mut s, 439, 1, 10);
        set(&mut s, 440, 1, 20);
        let r1 = Record::load(&s, Variant::CmmoSt, 1).unwrap();
        let mut c = Chain::start(r1, Instant::ZERO);
        let smp = Sample::default();
        // Not "end of chain": the caller must see the invalid target (and MC must not come
        // while the record is still moving).
        assert_eq!(
            c.evaluate(Variant::CmmoSt, false, smp, Instant::from_millis(10)),
            Verdict::Next(0)
        );
        assert!(c.rc1());
        assert!(!c.rcc());
    }
}
