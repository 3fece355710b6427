//! SYNC (CiA 301 §7.2.5): the producer on an absolute schedule and the consumer with the
//! counter check and the synchronous window.
//!
//! Objects: 1005h COB-ID SYNC (bit 30 = this node produces, bits 10..0 the identifier),
//! 1006h communication cycle period (µs, 0 = no SYNC), 1007h synchronous window length (µs,
//! 0 = off), 1019h synchronous counter overflow value (0 = no counter byte, 2..=240).

use crate::can::Frame;
use crate::canopen::nmt::frame;
use crate::time::Instant;
use core::time::Duration;

/// Why a SYNC frame or a SYNC object value was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SyncError {
    /// A SYNC carries no data or one counter byte.
    #[error("a SYNC has DLC 0 or 1 (counter), not {0}")]
    WrongLength(u8),
    /// A remote frame on the SYNC COB-ID.
    #[error("a SYNC must be a data frame, not a remote frame")]
    Remote,
    /// A counter byte outside 1..=240.
    #[error("SYNC counter {0} is outside 1..=240")]
    BadCounter(u8),
    /// 1019h accepts 0 or 2..=240.
    #[error("synchronous counter overflow value {0} is not 0 or 2..=240")]
    BadOverflow(u8),
    /// 1005h with bit 29 set (29-bit identifier), which this stack does not produce.
    #[error("COB-ID SYNC {0:#010x} selects a 29-bit identifier, which is not supported")]
    ExtendedId(u32),
}

/// The value of 1005h, COB-ID SYNC.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct SyncCobId {
    /// Bit 30: this node generates SYNC.
    pub producer: bool,
    /// Bits 10..0: the 11-bit identifier (080h by default).
    pub id: u16,
}

impl SyncCobId {
    /// The default consumer entry, 080h.
    pub const DEFAULT: SyncCobId = SyncCobId {
        producer: false,
        id: 0x080,
    };

    /// Decodes 1005h. Bit 31 is ignored: older devices (the TLC5xx among them, default
    /// 8000_0080h) use it to say "consumer".
    pub const fn from_u32(raw: u32) -> Result<SyncCobId, SyncError> {
        if raw & (1 << 29) != 0 {
            return Err(SyncError::ExtendedId(raw));
        }
        Ok(SyncCobId {
            producer: raw & (1 << 30) != 0,
            id: (raw & 0x7FF) as u16,
        })
    }

    /// Encodes 1005h.
    pub const fn to_u32(self) -> u32 {
        ((self.producer as u32) << 30) | (self.id & 0x7FF) as u32
    }
}

/// Checks a 1019h value: 0 (no counter) or 2..=240.
pub const fn check_overflow(overflow: u8) -> Result<u8, SyncError> {
    match overflow {
        0 | 2..=240 => Ok(overflow),
        other => Err(SyncError::BadOverflow(other)),
    }
}

/// Decodes a SYNC frame already known to be on the SYNC COB-ID: `None` without a counter,
/// `Some(counter)` with one.
pub fn decode_sync(f: &Frame) -> Result<Option<u8>, SyncError> {
    if f.is_remote() {
        return Err(SyncError::Remote);
    }
    match *f.data() {
        [] => Ok(None),
        [c @ 1..=240] => Ok(Some(c)),
        [c] => Err(SyncError::BadCounter(c)),
        _ => Err(SyncError::WrongLength(f.dlc())),
    }
}

/// The SYNC frame with an optional counter.
pub fn encode_sync(id: u16, counter: Option<u8>) -> Frame {
    match counter {
        Some(c) => frame(id, &[c]),
        None => frame(id, &[]),
    }
}

/// The SYNC producer: the k-th SYNC after [`SyncProducer::start`] is due at `start + k *
/// period`, so errors in when the caller polls never accumulate into drift.
#[derive(Debug, Clone)]
pub struct SyncProducer {
    cob: SyncCobId,
    period: Duration,
    overflow: u8,
    start: Option<Instant>,
    /// Index of the next SYNC on the schedule.
    k: u64,
    counter: u8,
    skipped: u64,
}

impl SyncProducer {
    /// A producer from 1005h, 1006h (µs) and 1019h. It sends nothing unless 1005h has the
    /// producer bit and the period is not 0, and not before [`SyncProducer::start`].
    pub fn new(cob: SyncCobId, period_us: u32, overflow: u8) -> Result<SyncProducer, SyncError> {
        Ok(SyncProducer {
            cob,
            period: Duration::from_micros(period_us as u64),
            overflow: check_overflow(overflow)?,
            start: None,
            k: 0,
            counter: 0,
            skipped: 0,
        })
    }

    fn active(&self) -> bool {
        self.cob.producer && !self.period.is_zero()
    }

    /// Starts (or restarts) the schedule: the first SYNC is due at `now`, the counter
    /// restarts at 1 (CiA 301: the counter is reset when production starts).
    pub fn start(&mut self, now: Instant) {
        self.start = Some(now);
        self.k = 0;
        self.counter = 0;
    }

    /// Stops producing (Stopped state, or 1005h/1006h being rewritten).
    pub fn stop(&mut self) {
        self.start = None;
    }

    fn due(&self, k: u64) -> Option<Instant> {
        let start = self.start?;
        let ns = (self.period.as_nanos() as u64).saturating_mul(k);
        Some(start + Duration::from_nanos(ns))
    }

    /// When the next SYNC is due.
    pub fn poll_timeout(&self) -> Option<Instant> {
        if self.active() {
            self.due(self.k)
        } else {
            None
        }
    }

    /// The SYNC due at `now`, if any. When polled more than a period late, the SYNCs whose
    /// slots have passed are skipped (counted in [`SyncProducer::skipped`]) instead of being
    /// sent in a burst, and the schedule stays on its grid.
    pub fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        let due = self.poll_timeout()?;
        if now < due {
            return None;
        }
        let period = self.period.as_nanos() as u64;
        let behind = (now - due).as_nanos() as u64 / period.max(1);
        self.skipped += behind;
        self.k += behind + 1;
        let counter = if self.overflow == 0 {
            None
        } else {
            self.counter = if self.counter >= self.overflow {
                1
            } else {
                self.counter + 1
            };
            Some(self.counter)
        };
        Some(encode_sync(self.cob.id, counter))
    }

    /// How many scheduled SYNCs were skipped because the producer was polled too late.
    pub fn skipped(&self) -> u64 {
        self.skipped
    }
}

/// What the SYNC consumer saw.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SyncEvent {
    /// A SYNC arrived.
    Sync {
        /// Its counter, if it carried one.
        counter: Option<u8>,
        /// SYNCs missed before it: from the counter jump when there is a counter, otherwise
        /// from the time since the previous SYNC when the period (1006h) is known.
        missed: u32,
    },
    /// No SYNC for one and a half periods since `last` (reported once per silence).
    Overdue {
        /// When the last SYNC arrived.
        last: Instant,
    },
}

/// The SYNC consumer.
#[derive(Debug, Clone)]
pub struct SyncConsumer {
    id: u16,
    period: Duration,
    window: Duration,
    overflow: u8,
    last: Option<Instant>,
    last_counter: Option<u8>,
    overdue_reported: bool,
}

impl SyncConsumer {
    /// A consumer of COB-ID `cob.id` with 1006h period and 1007h window (µs, 0 = unknown/off)
    /// and 1019h overflow value.
    pub fn new(
        cob: SyncCobId,
        period_us: u32,
        window_us: u32,
        overflow: u8,
    ) -> Result<SyncConsumer, SyncError> {
        Ok(SyncConsumer {
            id: cob.id,
            period: Duration::from_micros(period_us as u64),
            window: Duration::from_micros(window_us as u64),
            overflow: check_overflow(overflow)?,
            last: None,
            last_counter: None,
            overdue_reported: false,
        })
    }

    /// Whether `f` is on the SYNC COB-ID this consumer listens to.
    pub fn accepts(&self, f: &Frame) -> bool {
        f.cob_id() == Some(self.id)
    }

    /// Feeds a frame. Frames on other COB-IDs give `Ok(None)`; a malformed SYNC a typed error.
    pub fn handle_frame(
        &mut self,
        f: &Frame,
        now: Instant,
    ) -> Result<Option<SyncEvent>, SyncError> {
        if !self.accepts(f) {
            return Ok(None);
        }
        let counter = decode_sync(f)?;
        if let Some(c) = counter
            && self.overflow >= 2
            && c > self.overflow
        {
            // The producer counts to a larger overflow value than 1019h says: misconfigured.
            return Err(SyncError::BadCounter(c));
        }
        let missed = match (counter, self.last_counter) {
            (Some(c), Some(prev)) if self.overflow >= 2 => {
                let expected = if prev >= self.overflow { 1 } else { prev + 1 };
                // Distance forward from the expected value on the ring 1..=overflow.
                let ring = self.overflow as u32;
                (c as u32 + ring - expected as u32) % ring
            }
            _ => match self.last {
                Some(last) if !self.period.is_zero() => {
                    let gap = (now - last).as_nanos() as u64;
                    let period = self.period.as_nanos() as u64;
                    // Round to the nearest whole number of periods, then subtract this one.
                    let periods = (gap + period / 2) / period;
                    periods.saturating_sub(1).min(u32::MAX as u64) as u32
                }
                _ => 0,
            },
        };
        self.last = Some(now);
        self.last_counter = counter;
        self.overdue_reported = false;
        Ok(Some(SyncEvent::Sync { counter, missed }))
    }

    /// When the SYNC becomes overdue (1.5 periods after the last one), if the period is known.
    pub fn poll_timeout(&self) -> Option<Instant> {
        if self.period.is_zero() || self.overdue_reported {
            return None;
        }
        Some(self.last? + self.period + self.period / 2)
    }

    /// Reports an overdue SYNC once per silence.
    pub fn handle_timeout(&mut self, now: Instant) -> Option<SyncEvent> {
        let deadline = self.poll_timeout()?;
        let last = self.last?;
        if now >= deadline {
            self.overdue_reported = true;
            Some(SyncEvent::Overdue { last })
        } else {
            None
        }
    }

    /// When the last SYNC arrived.
    pub fn last_sync(&self) -> Option<Instant> {
        self.last
    }

    /// Whether `now` lies inside the synchronous window after the last SYNC. Always true when
    /// the window is off (1007h = 0); false before the first SYNC. A synchronous RPDO that
    /// arrives outside it is deferred (TLC5xx: applied at the SYNC after next).
    pub fn in_window(&self, now: Instant) -> bool {
        if self.window.is_zero() {
            return true;
        }
        match self.last {
            Some(last) => now >= last && now - last <= self.window,
            None => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::str::FromStr;

    fn f(s: &str) -> Frame {
        Frame::from_str(s).unwrap()
    }
    const PRODUCER: SyncCobId = SyncCobId {
        producer: true,
        id: 0x080,
    };

    #[test]
    fn cob_id_object() {
        // TLC5xx default 8000_0080h: consumer on 080h.
        assert_eq!(SyncCobId::from_u32(0x8000_0080), Ok(SyncCobId::DEFAULT));
        assert_eq!(SyncCobId::from_u32(0x4000_0080), Ok(PRODUCER));
        assert_eq!(PRODUCER.to_u32(), 0x4000_0080);
        assert_eq!(
            SyncCobId::from_u32(0x2000_0080),
            Err(SyncError::ExtendedId(0x2000_0080))
        );
    }

    #[test]
    fn decode_rejects_bad_frames() {
        assert_eq!(decode_sync(&f("080#")), Ok(None));
        assert_eq!(decode_sync(&f("080#F0")), Ok(Some(240)));
        assert_eq!(decode_sync(&f("080#0000")), Err(SyncError::WrongLength(2)));
        assert_eq!(decode_sync(&f("080#00")), Err(SyncError::BadCounter(0)));
        assert_eq!(decode_sync(&f("080#F1")), Err(SyncError::BadCounter(241)));
        assert_eq!(decode_sync(&f("080#R")), Err(SyncError::Remote));
        assert_eq!(check_overflow(1), Err(SyncError::BadOverflow(1)));
        assert_eq!(check_overflow(241), Err(SyncError::BadOverflow(241)));
        assert!(SyncProducer::new(PRODUCER, 1000, 1).is_err());
    }

    #[test]
    fn producer_schedule_does_not_drift() {
        let mut p = SyncProducer::new(PRODUCER, 1_000, 0).unwrap();
        assert_eq!(p.poll_timeout(), None);
        let t0 = Instant::from_micros(500);
        p.start(t0);
        let mut sent = 0u64;
        // Poll with a jittery, always-late caller: 1..=300 µs after each due time.
        for k in 0..1000u64 {
            let due = p.poll_timeout().unwrap();
            assert_eq!(due, Instant::from_micros(500 + k * 1_000));
            let late = Duration::from_micros(1 + (k * 37) % 300);
            if k > 0 {
                let just_before = Instant::from_nanos(due.as_nanos() - 1);
                assert_eq!(p.poll_transmit(just_before), None);
            }
            assert_eq!(p.poll_transmit(due + late), Some(f("080#")));
            sent += 1;
            assert_eq!(p.poll_transmit(due + late), None);
        }
        assert_eq!(sent, 1000);
        // The 1000th SYNC is still due at start + 1000 periods, to the nanosecond.
        assert_eq!(
            p.poll_timeout(),
            Some(Instant::from_micros(500 + 1_000_000))
        );
        assert_eq!(p.skipped(), 0);
    }

    #[test]
    fn producer_skips_instead_of_bursting() {
        let mut p = SyncProducer::new(PRODUCER, 1_000, 0).unwrap();
        p.start(Instant::ZERO);
        assert!(p.poll_transmit(Instant::ZERO).is_some());
        // Polled 3.5 periods late: one SYNC, slots 1..=2 skipped, next on the grid at 4 ms.
        assert!(p.poll_transmit(Instant::from_micros(3_500)).is_some());
        assert_eq!(p.poll_transmit(Instant::from_micros(3_500)), None);
        assert_eq!(p.skipped(), 2);
        assert_eq!(p.poll_timeout(), Some(Instant::from_millis(4)));
    }

    #[test]
    fn producer_disabled_without_producer_bit_or_period() {
        let mut p = SyncProducer::new(SyncCobId::DEFAULT, 1_000, 0).unwrap();
        p.start(Instant::ZERO);
        assert_eq!(p.poll_transmit(Instant::from_millis(5)), None);
        let mut p = SyncProducer::new(PRODUCER, 0, 0).unwrap();
        p.start(Instant::ZERO);
        assert_eq!(p.poll_transmit(Instant::from_millis(5)), None);
    }

    #[test]
    fn counter_wraps_at_overflow() {
        let mut p = SyncProducer::new(PRODUCER, 1_000, 3).unwrap();
        p.start(Instant::ZERO);
        let mut got = [0u8; 7];
        for (k, slot) in got.iter_mut().enumerate() {
            let fr = p.poll_transmit(Instant::from_millis(k as u64)).unwrap();
            *slot = decode_sync(&fr).unwrap().unwrap();
        }
        assert_eq!(got, [1, 2, 3, 1, 2, 3, 1]);
        // A consumer with the same overflow sees no gaps across the wrap.
        let mut c = SyncConsumer::new(SyncCobId::DEFAULT, 1_000, 0, 3).unwrap();
        for (k, v) in got.iter().enumerate() {
            let e = c
                .handle_frame(&f(&format!("080#{v:02X}")), Instant::from_millis(k as u64))
                .unwrap();
            assert_eq!(
                e,
                Some(SyncEvent::Sync {
                    counter: Some(*v),
                    missed: 0
                })
            );
        }
        assert_eq!(
            c.handle_frame(&f("080#04"), Instant::from_millis(8)),
            Err(SyncError::BadCounter(4))
        );
        // 1 -> 3 skips counter 2; after 3 comes 1, so 3 -> 3 skips two.
        let e = c
            .handle_frame(&f("080#03"), Instant::from_millis(9))
            .unwrap();
        assert_eq!(
            e,
            Some(SyncEvent::Sync {
                counter: Some(3),
                missed: 1
            })
        );
        let e = c
            .handle_frame(&f("080#03"), Instant::from_millis(12))
            .unwrap();
        assert_eq!(
            e,
            Some(SyncEvent::Sync {
                counter: Some(3),
                missed: 2
            })
        );
        // Restart of a producer at 1 after 240 on the maximal ring is no gap either.
        let mut p = SyncProducer::new(PRODUCER, 1_000, 240).unwrap();
        p.start(Instant::ZERO);
        let mut last = 0;
        for k in 0..241u64 {
            last = decode_sync(&p.poll_transmit(Instant::from_millis(k)).unwrap())
                .unwrap()
                .unwrap();
        }
        assert_eq!(last, 1);
    }

    #[test]
    fn consumer_counts_missed_by_time_and_overdue() {
        let mut c = SyncConsumer::new(SyncCobId::DEFAULT, 1_000, 0, 0).unwrap();
        assert_eq!(c.handle_frame(&f("181#00"), Instant::ZERO), Ok(None));
        c.handle_frame(&f("080#"), Instant::from_micros(10_000))
            .unwrap();
        // Next SYNC after 3 periods (+40 µs jitter): two missed.
        let e = c
            .handle_frame(&f("080#"), Instant::from_micros(13_040))
            .unwrap();
        assert_eq!(
            e,
            Some(SyncEvent::Sync {
                counter: None,
                missed: 2
            })
        );
        assert_eq!(c.poll_timeout(), Some(Instant::from_micros(14_540)));
        assert_eq!(c.handle_timeout(Instant::from_micros(14_539)), None);
        assert_eq!(
            c.handle_timeout(Instant::from_micros(14_540)),
            Some(SyncEvent::Overdue {
                last: Instant::from_micros(13_040)
            })
        );
        // Reported once per silence.
        assert_eq!(c.handle_timeout(Instant::from_micros(20_000)), None);
        assert_eq!(
            c.handle_frame(&f("080#01"), Instant::from_micros(21_000)),
            Ok(Some(SyncEvent::Sync {
                counter: Some(1),
                missed: 7
            }))
        );
        assert_eq!(
            c.handle_frame(&f("080#0102"), Instant::from_micros(22_000)),
            Err(SyncError::WrongLength(2))
        );
    }

    #[test]
    fn synchronous_window() {
        let mut c = SyncConsumer::new(SyncCobId::DEFAULT, 1_000, 300, 0).unwrap();
        assert!(!c.in_window(Instant::from_micros(100)));
        c.handle_frame(&f("080#"), Instant::from_micros(1_000))
            .unwrap();
        assert!(c.in_window(Instant::from_micros(1_000)));
        assert!(c.in_window(Instant::from_micros(1_300)));
        assert!(!c.in_window(Instant::from_micros(1_301)));
        let off = SyncConsumer::new(SyncCobId::DEFAULT, 1_000, 0, 0).unwrap();
        assert!(off.in_window(Instant::from_micros(5)));
    }
}
