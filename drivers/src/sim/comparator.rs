//! The drive-side comparators of the EMCA and the CMMO-ST (EMCA digest §4.1, CMMO-ST digest §5.4):
//! position, velocity, force and time, each a window `[min, max]` that must hold for a damping
//! time before the message goes active. A comparator whose `min > max` is never active (CMMO-ST
//! Tab. 6.19). The status is PNU 312 ([`ComparatorStatus`]); record chaining uses the same
//! messages as step-enabling conditions 20..23.
//!
//! Parameter layout, the same for a record (PNU 430..440, sub-index = record) and for direct
//! mode (PNU 585..595, sub-index 1): base + 0/1/2 position min/max/damping, + 3/4/5 velocity,
//! + 6/7/8 force, + 9/10 time min/max (no damping).

use core::time::Duration;

use crate::fhpp::pnu::ComparatorStatus;
use crate::time::Instant;

/// First PNU of the per-record comparator block (sub-index = record number).
pub const RECORD_BASE: u16 = 430;
/// First PNU of the direct-mode comparator block (sub-index 1).
pub const DIRECT_BASE: u16 = 585;

/// One comparator window.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Window {
    /// Lowest value inside (inclusive).
    pub min: i64,
    /// Highest value inside (inclusive).
    pub max: i64,
    /// How long the value must stay inside before the message is active.
    pub damping: Duration,
}

impl Window {
    /// A window over `[min, max]` held for `damping` (`min > max` makes it never active).
    pub const fn new(min: i64, max: i64, damping: Duration) -> Window {
        Window { min, max, damping }
    }

    /// A window that is never active (`min > max`), for "no comparator here".
    pub const NEVER: Window = Window::new(1, 0, Duration::ZERO);

    /// Whether the comparator can ever be active: never where `min > max`.
    pub const fn enabled(&self) -> bool {
        self.min <= self.max
    }
    /// Whether `v` lies in the window (always false for a disabled window).
    pub const fn contains(&self, v: i64) -> bool {
        self.enabled() && self.min <= v && v <= self.max
    }
}

/// A window with its damping timer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Comparator {
    /// The window.
    pub window: Window,
    inside_since: Option<Instant>,
    active: bool,
}

impl Comparator {
    /// A comparator over `window`, not active.
    pub const fn new(window: Window) -> Comparator {
        Comparator {
            window,
            inside_since: None,
            active: false,
        }
    }

    /// Feeds the value at `now`; returns whether the message is active (inside for at least the
    /// damping time without a break).
    pub fn update(&mut self, value: i64, now: Instant) -> bool {
        if self.window.contains(value) {
            let since = *self.inside_since.get_or_insert(now);
            self.active = now.saturating_duration_since(since) >= self.window.damping;
        } else {
            self.inside_since = None;
            self.active = false;
        }
        self.active
    }

    /// Whether the message is active.
    pub const fn is_active(&self) -> bool {
        self.active
    }

    /// Forgets the time spent inside (a new task starts).
    pub fn reset(&mut self) {
        self.inside_since = None;
        self.active = false;
    }
}

/// The four windows of a record or of direct mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct ComparatorParams {
    /// Position \[SINC\], absolute even for relative records.
    pub position: Window,
    /// Velocity \[SINC/s\], signed.
    pub velocity: Window,
    /// Force \[‰ of PNU 555\].
    pub force: Window,
    /// Time since the task started \[ms\] (no damping).
    pub time: Window,
}

impl ComparatorParams {
    /// Reads the 11 values from `get(pnu)` starting at `base` ([`RECORD_BASE`] or
    /// [`DIRECT_BASE`]); a missing value reads as 0. Damping times are in ms.
    pub fn from_pnus(base: u16, mut get: impl FnMut(u16) -> Option<i64>) -> ComparatorParams {
        let mut v = |off: u16| get(base + off).unwrap_or(0);
        let ms = |x: i64| Duration::from_millis(x.max(0) as u64);
        ComparatorParams {
            position: Window {
                min: v(0),
                max: v(1),
                damping: ms(v(2)),
            },
            velocity: Window {
                min: v(3),
                max: v(4),
                damping: ms(v(5)),
            },
            force: Window {
                min: v(6),
                max: v(7),
                damping: ms(v(8)),
            },
            time: Window {
                min: v(9),
                max: v(10),
                damping: Duration::ZERO,
            },
        }
    }
}

/// What the comparators look at, once per drive cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Sample {
    /// Actual position \[SINC\].
    pub position: i64,
    /// Actual velocity \[SINC/s\], signed.
    pub velocity: i64,
    /// Actual force \[‰ of PNU 555\], signed.
    pub force_permille: i64,
    /// Time since the task (record) started, ms.
    pub elapsed_ms: i64,
}

/// The four comparators of the running task.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct ComparatorSet {
    /// Position comparator.
    pub position: Comparator,
    /// Velocity comparator.
    pub velocity: Comparator,
    /// Force comparator.
    pub force: Comparator,
    /// Time comparator.
    pub time: Comparator,
}

impl ComparatorSet {
    /// A set over `p`, nothing active.
    pub const fn new(p: ComparatorParams) -> ComparatorSet {
        ComparatorSet {
            position: Comparator::new(p.position),
            velocity: Comparator::new(p.velocity),
            force: Comparator::new(p.force),
            time: Comparator::new(p.time),
        }
    }

    /// Evaluates all four at `now`; returns the PNU 312 status.
    pub fn update(&mut self, s: &Sample, now: Instant) -> ComparatorStatus {
        ComparatorStatus {
            position: self.position.update(s.position, now),
            speed: self.velocity.update(s.velocity, now),
            force: self.force.update(s.force_permille, now),
            time: self.time.update(s.elapsed_ms, now),
        }
    }

    /// The current status without evaluating.
    pub const fn status(&self) -> ComparatorStatus {
        ComparatorStatus {
            position: self.position.is_active(),
            speed: self.velocity.is_active(),
            force: self.force.is_active(),
            time: self.time.is_active(),
        }
    }

    /// Resets every damping timer.
    pub fn reset(&mut self) {
        self.position.reset();
        self.velocity.reset();
        self.force.reset();
        self.time.reset();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(n: u64) -> Instant {
        Instant::from_millis(n)
    }

    #[test]
    fn active_only_after_the_damping_time_without_a_break() {
        let mut c = Comparator::new(Window {
            min: 100,
            max: 200,
            damping: Duration::from_millis(10),
        });
        assert!(!c.update(150, ms(0)));
        assert!(!c.update(150, ms(9)));
        assert!(c.update(150, ms(10)));
        // Leaving the window drops the message and restarts the timer.
        assert!(!c.update(201, ms(11)));
        assert!(!c.update(200, ms(12)));
        assert!(!c.update(100, ms(21)));
        assert!(c.update(100, ms(22)));
    }

    #[test]
    fn min_greater_than_max_never_fires() {
        let mut c = Comparator::new(Window {
            min: 10,
            max: 9,
            damping: Duration::ZERO,
        });
        for v in [-1_000_000, 0, 9, 10, 11, 1_000_000] {
            for t in 0..5 {
                assert!(!c.update(v, ms(t)));
            }
        }
        assert!(
            !Window {
                min: 1,
                max: 0,
                damping: Duration::ZERO
            }
            .contains(0)
        );
    }

    #[test]
    fn params_follow_the_shared_pnu_layout() {
        let p =
            ComparatorParams::from_pnus(DIRECT_BASE, |pnu| Some(i64::from(pnu - DIRECT_BASE) + 1));
        assert_eq!((p.position.min, p.position.max), (1, 2));
        assert_eq!(p.position.damping, Duration::from_millis(3));
        assert_eq!((p.velocity.min, p.velocity.max), (4, 5));
        assert_eq!((p.force.min, p.force.max), (7, 8));
        assert_eq!(p.force.damping, Duration::from_millis(9));
        assert_eq!((p.time.min, p.time.max), (10, 11));
        assert_eq!(p.time.damping, Duration::ZERO);
    }

    #[test]
    fn set_reports_pnu_312_bits() {
        let mut set = ComparatorSet::new(ComparatorParams {
            position: Window {
                min: 0,
                max: 10,
                damping: Duration::ZERO,
            },
            velocity: Window {
                min: 5,
                max: 1,
                damping: Duration::ZERO,
            },
            force: Window {
                min: -10,
                max: 10,
                damping: Duration::ZERO,
            },
            time: Window {
                min: 50,
                max: 60,
                damping: Duration::ZERO,
            },
        });
        let s = Sample {
            position: 5,
            velocity: 3,
            force_permille: 0,
            elapsed_ms: 55,
        };
        let st = set.update(&s, ms(0));
        assert_eq!(st.to_byte(), 0b1101);
        assert_eq!(set.status(), st);
    }
}
