//! The cycle's clock on Linux: [`Ticker`] wakes a thread at absolute deadlines of
//! `CLOCK_MONOTONIC`, and [`sleep_until`] sleeps to one.

use std::time::Duration;

use drivers::time::{Instant, monotonic_now};

/// One wake-up of a [`Ticker`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Tick {
    /// Index of this deadline since the start: `deadline = start + cycle * period`. Skipped
    /// deadlines are counted, so the number keeps mapping to time.
    pub cycle: u64,
    /// The deadline slept to.
    pub deadline: Instant,
    /// When the thread ran again (never before `deadline`).
    pub woke: Instant,
    /// `woke - deadline`: the wake-up latency (or how late the caller came back).
    pub late: Duration,
    /// Deadlines given up on before this one because the caller came back more than a period
    /// late (0 normally).
    pub skipped: u64,
}

/// Periodic wake-up on absolute deadlines of `CLOCK_MONOTONIC`
/// (`clock_nanosleep(TIMER_ABSTIME)`): the period does not drift with the time spent working,
/// and a late wake-up does not shift later ones.
///
/// A caller that comes back more than one period after a deadline skips the deadlines it
/// missed (counted in [`Tick::skipped`]) instead of running a burst of catch-up cycles: a
/// motion cycle that runs twice back to back would send two setpoints in one bus period.
#[derive(Debug, Clone)]
pub struct Ticker {
    start: Instant,
    period: Duration,
    cycle: u64,
}

impl Ticker {
    /// A ticker whose first deadline is `start` (usually `monotonic_now()` plus a margin),
    /// then every `period` (a zero period is taken as 1 ns).
    pub fn new(start: Instant, period: Duration) -> Ticker {
        Ticker {
            start,
            period: period.max(Duration::from_nanos(1)),
            cycle: 0,
        }
    }

    /// The period.
    pub fn period(&self) -> Duration {
        self.period
    }

    /// The next deadline [`wait`](Self::wait) sleeps to (before any skipping).
    pub fn next_deadline(&self) -> Instant {
        self.deadline_of(self.cycle)
    }

    fn deadline_of(&self, cycle: u64) -> Instant {
        let ns = u128::from(cycle) * self.period.as_nanos();
        self.start + Duration::from_nanos(u64::try_from(ns).unwrap_or(u64::MAX))
    }

    /// Skips the deadlines more than one period before `now`; returns how many. Afterwards the
    /// next deadline is later than `now - period`.
    fn skip_missed(&mut self, now: Instant) -> u64 {
        let behind = now.saturating_duration_since(self.next_deadline());
        if behind <= self.period {
            return 0;
        }
        let k = u64::try_from(behind.as_nanos() / self.period.as_nanos()).unwrap_or(u64::MAX);
        self.cycle = self.cycle.saturating_add(k);
        k
    }

    /// Sleeps until the next deadline (at once if it has passed) and returns what happened.
    pub fn wait(&mut self) -> Tick {
        self.wait_with(sleep_until)
    }

    /// [`wait`](Self::wait), sleeping with `sleep` (tests stall inside it).
    fn wait_with(&mut self, sleep: impl FnOnce(Instant)) -> Tick {
        let mut skipped = self.skip_missed(monotonic_now());
        let mut deadline = self.next_deadline();
        sleep(deadline);
        let woke = monotonic_now();
        // Stopped while asleep (the host stalled the thread, SIGSTOP): the deadlines that passed
        // meanwhile are missed too, now and not only at the next wait, and this cycle is the
        // latest deadline's. Otherwise the first cycle after the stall ran as if on time, with
        // a `now` from before it (its guarding polls stamped then, their replies judged against
        // that time), and the overrun was noticed a cycle later.
        let missed = self.skip_missed(woke);
        if missed > 0 {
            skipped += missed;
            deadline = self.next_deadline();
        }
        let tick = Tick {
            cycle: self.cycle,
            deadline,
            woke,
            late: woke.saturating_duration_since(deadline),
            skipped,
        };
        self.cycle = self.cycle.saturating_add(1);
        tick
    }
}

/// Sleeps on `CLOCK_MONOTONIC` until `deadline`, retrying after signals.
pub fn sleep_until(deadline: Instant) {
    let ns = deadline.as_nanos();
    let ts = libc::timespec {
        tv_sec: (ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: `ts` is a valid timespec for the duration of the call; the remaining-time
        // pointer may be null with TIMER_ABSTIME.
        let rc = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        // clock_nanosleep returns the error number itself. EINTR: a signal (e.g. the stop
        // flag's) woke us early; sleep the rest. Anything else (EINVAL) cannot be slept away.
        if rc != libc::EINTR {
            break;
        }
    }
    // The guarantee callers rely on: never return before the deadline, even after an error.
    while monotonic_now() < deadline {
        std::hint::spin_loop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wake_ups_are_in_order_and_never_early() {
        let period = Duration::from_millis(1);
        let mut t = Ticker::new(monotonic_now() + period, period);
        let mut last: Option<Tick> = None;
        for _ in 0..30 {
            let tick = t.wait();
            assert!(tick.woke >= tick.deadline, "{tick:?}");
            assert_eq!(tick.late, tick.woke - tick.deadline);
            if let Some(prev) = last {
                assert!(tick.cycle > prev.cycle);
                assert!(tick.deadline > prev.deadline);
                assert!(tick.woke >= prev.woke);
                // Deadlines stay on the grid, whatever the wake-up latency.
                let steps = u32::try_from(tick.cycle - prev.cycle).unwrap();
                assert_eq!(tick.deadline - prev.deadline, period * steps);
            }
            last = Some(tick);
        }
    }

    #[test]
    fn a_stalled_caller_skips_instead_of_bursting() {
        // A period well above this shared host's scheduling noise (tens of ms under load), so
        // that only the ticker's logic is checked, not the machine's latency.
        let period = Duration::from_millis(50);
        let mut t = Ticker::new(monotonic_now(), period);
        let first = t.wait();
        // Stall for ten periods.
        std::thread::sleep(period * 10);
        let resumed = t.wait();
        assert!(resumed.skipped >= 8, "{resumed:?}");
        assert_eq!(resumed.cycle, first.cycle + 1 + resumed.skipped);
        // The deadline taken is less than one period past: no catch-up burst follows.
        assert!(resumed.late < period, "{resumed:?}");
        let next = t.wait();
        assert_eq!(next.skipped, 0);
        assert_eq!(next.deadline - resumed.deadline, period);
        assert!(next.woke >= next.deadline);
    }

    #[test]
    fn a_stall_during_the_sleep_is_skipped_at_once() {
        let period = Duration::from_millis(50);
        let mut t = Ticker::new(monotonic_now(), period);
        let first = t.wait();
        // Asleep toward the next deadline, the thread is stopped for ten periods.
        let resumed = t.wait_with(|d| {
            sleep_until(d);
            std::thread::sleep(period * 10);
        });
        assert!(resumed.skipped >= 8, "{resumed:?}");
        assert_eq!(resumed.cycle, first.cycle + 1 + resumed.skipped);
        assert!(resumed.late < period, "{resumed:?}");
        let next = t.wait();
        assert_eq!(next.skipped, 0, "{next:?}");
        assert_eq!(next.deadline - resumed.deadline, period);
    }

    #[test]
    fn skipping_is_exact_on_the_grid() {
        let p = Duration::from_millis(1);
        let mut t = Ticker::new(Instant::from_millis(100), p);
        // Up to one period late: nothing skipped (the deadline is taken late).
        assert_eq!(t.skip_missed(Instant::from_millis(101)), 0);
        assert_eq!(t.next_deadline(), Instant::from_millis(100));
        // 3.5 periods late: skip 3, the next deadline is 0.5 periods past.
        assert_eq!(t.skip_missed(Instant::from_micros(103_500)), 3);
        assert_eq!(t.next_deadline(), Instant::from_millis(103));
        // Before the start: nothing.
        assert_eq!(t.skip_missed(Instant::from_millis(1)), 0);
    }
}
