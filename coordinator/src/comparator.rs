//! Comparators: a window `[min, max]` held for a damping time, never active where `min > max`.
//! The semantics are the drives' (`drivers::sim::comparator`, EMCA/CMMO-ST): one truth, used by
//! the simulated drives and by the coordinator's host-side chains.
//!
//! Besides the re-export, the condition checks a chain needs that are not about records: which
//! actual value a comparator watches ([`actual`]), a digital input edge ([`edge`]) and the time
//! comparator ([`in_time_window`]). All are `const`-cheap, allocation-free and panic-free on any
//! input, because the cycle calls them every cycle with whatever the drives reported.

use core::time::Duration;

pub use drivers::sim::comparator::{Comparator, Window};

/// Which actual value a comparator condition watches.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Quantity {
    /// Actual position, increments.
    Position,
    /// Actual velocity, inc/s.
    Velocity,
    /// Actual force, ‰.
    Force,
}

/// Which edge of a digital input.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Edge {
    /// 0 → 1.
    Rising,
    /// 1 → 0.
    Falling,
}

/// The actual value of `quantity` on the axis at `axis` (group order), from this cycle's
/// values; `None` if the slice has no such axis (a missing value is never inside a window).
pub fn actual(
    quantity: Quantity,
    axis: usize,
    positions: &[i64],
    velocities: &[i64],
    forces: &[i32],
) -> Option<i64> {
    match quantity {
        Quantity::Position => positions.get(axis).copied(),
        Quantity::Velocity => velocities.get(axis).copied(),
        Quantity::Force => forces.get(axis).map(|&f| i64::from(f)),
    }
}

/// Whether input `bit` of the machine's input word went through `edge` between `previous` and
/// `current`. Bits above 31 never change.
pub fn edge(previous: u32, current: u32, bit: u8, edge: Edge) -> bool {
    let Some(mask) = 1u32.checked_shl(u32::from(bit)) else {
        return false;
    };
    let (was, is) = (previous & mask != 0, current & mask != 0);
    match edge {
        Edge::Rising => !was && is,
        Edge::Falling => was && !is,
    }
}

/// The time comparator: `elapsed` (since the record started) in `[min_ms, max_ms]`, whole
/// milliseconds as the drives count them. No damping; never where `min_ms > max_ms`.
pub fn in_time_window(elapsed: Duration, min_ms: u32, max_ms: u32) -> bool {
    let ms = elapsed.as_millis();
    min_ms <= max_ms && u128::from(min_ms) <= ms && ms <= u128::from(max_ms)
}

#[cfg(test)]
mod tests {
    use super::*;
    use drivers::time::Instant;

    #[test]
    fn edges_are_seen_once_and_only_on_their_bit() {
        assert!(edge(0b000, 0b100, 2, Edge::Rising));
        assert!(!edge(0b100, 0b100, 2, Edge::Rising));
        assert!(!edge(0b000, 0b100, 2, Edge::Falling));
        assert!(edge(0b100, 0b000, 2, Edge::Falling));
        assert!(!edge(0b000, 0b010, 2, Edge::Rising));
        assert!(edge(0, 1 << 31, 31, Edge::Rising));
        assert!(!edge(0, u32::MAX, 32, Edge::Rising));
        assert!(!edge(u32::MAX, 0, 255, Edge::Falling));
    }

    #[test]
    fn time_window_is_inclusive_and_empty_when_reversed() {
        let ms = Duration::from_millis;
        assert!(!in_time_window(ms(9), 10, 20));
        assert!(in_time_window(ms(10), 10, 20));
        assert!(in_time_window(Duration::from_micros(20_999), 10, 20));
        assert!(!in_time_window(ms(21), 10, 20));
        for t in 0..40 {
            assert!(!in_time_window(ms(t), 20, 10));
        }
    }

    #[test]
    fn actual_values_by_quantity_and_missing_axes() {
        let (p, v, f) = ([1, 2], [10, 20], [-5, 7]);
        assert_eq!(actual(Quantity::Position, 1, &p, &v, &f), Some(2));
        assert_eq!(actual(Quantity::Velocity, 0, &p, &v, &f), Some(10));
        assert_eq!(actual(Quantity::Force, 0, &p, &v, &f), Some(-5));
        assert_eq!(actual(Quantity::Force, 2, &p, &v, &f), None);
        assert_eq!(actual(Quantity::Position, 7, &[], &[], &[]), None);
    }

    #[test]
    fn damping_restarts_when_the_window_is_left_and_reversed_windows_never_fire() {
        let mut c = Comparator::new(Window::new(100, 200, Duration::from_millis(4)));
        let t = Instant::from_millis;
        assert!(!c.update(150, t(0)));
        assert!(!c.update(150, t(3)));
        assert!(!c.update(250, t(4)));
        assert!(!c.update(150, t(5)));
        assert!(!c.update(150, t(8)));
        assert!(c.update(150, t(9)));
        let mut never = Comparator::new(Window::NEVER);
        for v in [-1, 0, 1, i64::MIN, i64::MAX] {
            assert!(!never.update(v, t(100)));
        }
        assert!(!Window::new(5, 4, Duration::ZERO).enabled());
    }
}
