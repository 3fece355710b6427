//! Time as the sans-I/O state machines see it.
//!
//! Every protocol state machine is fed an [`Instant`] with each frame and each poll, so the same
//! code runs on a virtual clock (tests, simulation as fast as the machine allows) and on the
//! monotonic clock (real buses). An `Instant` is a count of nanoseconds since an arbitrary epoch
//! shared by everything on one bus; durations are [`core::time::Duration`].

use core::ops::{Add, AddAssign, Sub};
use core::time::Duration;

/// A point in time: nanoseconds since the epoch of the clock that produced it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Instant(u64);

impl Instant {
    /// The epoch itself.
    pub const ZERO: Instant = Instant(0);
    /// The latest representable instant (about 584 years after the epoch).
    pub const MAX: Instant = Instant(u64::MAX);

    /// An instant `nanos` nanoseconds after the epoch.
    pub const fn from_nanos(nanos: u64) -> Self {
        Instant(nanos)
    }
    /// An instant `micros` microseconds after the epoch.
    pub const fn from_micros(micros: u64) -> Self {
        Instant(micros.saturating_mul(1_000))
    }
    /// An instant `millis` milliseconds after the epoch.
    pub const fn from_millis(millis: u64) -> Self {
        Instant(millis.saturating_mul(1_000_000))
    }
    /// Nanoseconds since the epoch.
    pub const fn as_nanos(self) -> u64 {
        self.0
    }
    /// Whole microseconds since the epoch.
    pub const fn as_micros(self) -> u64 {
        self.0 / 1_000
    }
    /// The time elapsed from `earlier` to `self`, or zero if `earlier` is later.
    pub const fn saturating_duration_since(self, earlier: Instant) -> Duration {
        Duration::from_nanos(self.0.saturating_sub(earlier.0))
    }
    /// `self + d`, saturating at [`Instant::MAX`].
    pub const fn saturating_add(self, d: Duration) -> Instant {
        let n = d.as_nanos();
        let n = if n > u64::MAX as u128 {
            u64::MAX
        } else {
            n as u64
        };
        Instant(self.0.saturating_add(n))
    }
}

impl Add<Duration> for Instant {
    type Output = Instant;
    fn add(self, d: Duration) -> Instant {
        self.saturating_add(d)
    }
}

impl AddAssign<Duration> for Instant {
    fn add_assign(&mut self, d: Duration) {
        *self = self.saturating_add(d);
    }
}

impl Sub<Instant> for Instant {
    type Output = Duration;
    fn sub(self, earlier: Instant) -> Duration {
        self.saturating_duration_since(earlier)
    }
}

impl core::fmt::Display for Instant {
    /// Seconds with microseconds, as candump writes them: `12.000345`.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let us = self.0 / 1_000;
        write!(f, "{}.{:06}", us / 1_000_000, us % 1_000_000)
    }
}

/// The earliest of some optional deadlines (`None` when there is none): how a composition of
/// state machines answers `poll_timeout`.
pub fn earliest(deadlines: impl IntoIterator<Item = Option<Instant>>) -> Option<Instant> {
    deadlines.into_iter().flatten().min()
}

/// A source of time. The virtual bus has a virtual clock; real buses use the monotonic clock.
pub trait Clock {
    /// The current time on this clock.
    fn now(&self) -> Instant;
}

/// `CLOCK_MONOTONIC`, as nanoseconds since the machine booted: the same epoch in every process,
/// so timestamps can cross process boundaries (the shared-memory virtual bus relies on that).
#[cfg(feature = "std")]
#[derive(Debug, Clone, Copy, Default)]
pub struct MonotonicClock;

#[cfg(feature = "std")]
impl Clock for MonotonicClock {
    fn now(&self) -> Instant {
        monotonic_now()
    }
}

/// The current `CLOCK_MONOTONIC` time.
#[cfg(feature = "std")]
pub fn monotonic_now() -> Instant {
    // std::time::Instant is CLOCK_MONOTONIC on Linux but hides the value; a base taken once per
    // process would give every process its own epoch, so read the clock directly.
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec into the valid, exclusively borrowed `ts`.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    debug_assert_eq!(rc, 0);
    Instant::from_nanos(ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arithmetic_saturates() {
        let t = Instant::from_millis(5);
        assert_eq!(t + Duration::from_micros(250), Instant::from_micros(5_250));
        assert_eq!(Instant::from_millis(1) - t, Duration::ZERO);
        assert_eq!(Instant::MAX + Duration::from_secs(1), Instant::MAX);
    }

    #[test]
    fn displays_like_candump() {
        assert_eq!(Instant::from_micros(12_000_345).to_string(), "12.000345");
    }

    #[cfg(feature = "std")]
    #[test]
    fn monotonic_clock_advances() {
        let a = monotonic_now();
        std::thread::sleep(Duration::from_millis(2));
        assert!(monotonic_now() - a >= Duration::from_millis(2));
    }
}
