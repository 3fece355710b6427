//! The profile's fixed-point formats, each written once: [`Time`] (cycles in Q16), [`PathPos`]
//! (the path parameter, 2^64 sub-units for the whole move) and [`PathRate`] (sub-units per
//! cycle^n in Q32: the path's velocity, acceleration and jerk).
//!
//! Plain integers underneath (`i64`, `i128`), with the profile's rounding spelled out per
//! operation: products are saturated before their shift and shifts round towards −∞, as they
//! always did, so every sample is the same bit for bit. `docs/decisions.md` says why these are
//! our own newtypes and not the `fixed` crate's types (a benchmark).

use core::ops::{Add, Div, Neg, Sub};

/// A span or instant of path time, in cycles with 16 fractional bits: [`Time::ONE`] is one
/// cycle, so phase boundaries need not fall on cycles. Also the override's rate: the path time
/// that passes per cycle (`ONE` at 100 %).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Time(i64);

impl Time {
    /// Fractional bits.
    pub const BITS: u32 = 16;
    /// One cycle.
    pub const ONE: Time = Time(1 << Time::BITS);
    /// No time.
    pub const ZERO: Time = Time(0);

    /// The Q16 value `raw / 2^16` cycles.
    pub const fn from_raw(raw: i64) -> Time {
        Time(raw)
    }

    /// `k` whole cycles.
    pub const fn cycles(k: i64) -> Time {
        Time(k << Time::BITS)
    }

    /// The Q16 integer.
    pub const fn raw(self) -> i64 {
        self.0
    }

    /// The first whole cycle at or after this instant (a non-negative time).
    pub const fn ceil_cycles(self) -> u64 {
        (self.0 as u64).div_ceil(Time::ONE.0 as u64)
    }

    /// The sum, saturated at the `i64` range.
    pub const fn saturating_add(self, other: Time) -> Time {
        Time(self.0.saturating_add(other.0))
    }
}

impl Add for Time {
    type Output = Time;
    fn add(self, other: Time) -> Time {
        Time(self.0 + other.0)
    }
}

impl Sub for Time {
    type Output = Time;
    fn sub(self, other: Time) -> Time {
        Time(self.0 - other.0)
    }
}

/// A place on the path: sub-units of the move, [`PathPos::END`] (2^64) being all of it, so axis
/// `i` sits at `start[i] + delta[i] · s / 2^64`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct PathPos(i128);

impl PathPos {
    /// Bits of the whole move: it is 2^64 sub-units.
    pub const BITS: u32 = 64;
    /// The start of a move.
    pub const ZERO: PathPos = PathPos(0);
    /// The end of a move (the whole path).
    pub const END: PathPos = PathPos(1 << PathPos::BITS);

    /// `raw` sub-units.
    pub const fn from_raw(raw: i128) -> PathPos {
        PathPos(raw)
    }

    /// The sub-units.
    pub const fn raw(self) -> i128 {
        self.0
    }

    /// The sum, saturated at the `i128` range.
    pub const fn saturating_add(self, other: PathPos) -> PathPos {
        PathPos(self.0.saturating_add(other.0))
    }

    /// `delta · s / 2^64` in increments, rounded to nearest (ties towards +∞): where an axis
    /// moving `delta` increments over the whole path is at this place. Exact in `i128` for
    /// `|delta| ≤ 2^47` and `0 ≤ s ≤ END`.
    pub const fn of(self, delta: i64) -> i64 {
        ((delta as i128 * self.0 + (PathPos::END.0 >> 1)) >> PathPos::BITS) as i64
    }
}

impl Sub for PathPos {
    type Output = PathPos;
    fn sub(self, other: PathPos) -> PathPos {
        PathPos(self.0 - other.0)
    }
}

/// A rate along the path: sub-units per cycle^n with 32 fractional bits — the path velocity
/// (n = 1), acceleration (n = 2) or jerk (n = 3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct PathRate(i128);

impl PathRate {
    /// Fractional bits.
    pub const BITS: u32 = 32;
    /// Standing still.
    pub const ZERO: PathRate = PathRate(0);

    /// The Q32 value `raw / 2^32` sub-units per cycle^n.
    pub const fn from_raw(raw: i128) -> PathRate {
        PathRate(raw)
    }

    /// `n` whole sub-units per cycle^n.
    pub const fn from_int(n: u128) -> PathRate {
        PathRate((n << PathRate::BITS) as i128)
    }

    /// The Q32 integer.
    pub const fn raw(self) -> i128 {
        self.0
    }

    /// The whole sub-units per cycle^n of a non-negative rate (the fraction dropped).
    pub const fn int(self) -> u128 {
        (self.0 >> PathRate::BITS) as u128
    }

    /// The larger of the two.
    pub fn max(self, other: PathRate) -> PathRate {
        PathRate(self.0.max(other.0))
    }

    /// `self · t`, the same format: one power of the cycle less when `t` is a duration (a jerk
    /// over a time is an acceleration), the same when `t` is the override's rate (time
    /// scaling). The product saturates, then the shift rounds towards −∞.
    pub const fn mul_time(self, t: Time) -> PathRate {
        PathRate(self.0.saturating_mul(t.0 as i128) >> Time::BITS)
    }

    /// The path covered at this velocity over `t`, in whole sub-units (saturated product,
    /// rounded towards −∞).
    pub const fn over(self, t: Time) -> PathPos {
        PathPos(self.0.saturating_mul(t.0 as i128) >> (Time::BITS + PathRate::BITS))
    }

    /// An axis's share of this rate in increments per second^`power` (`power` = n, the cycle's
    /// power), for an axis moving `delta` increments over the whole path with a cycle of
    /// `cycle_ns`: `delta · rate / 2^96 · (1 s / cycle)^power`, truncated towards zero (a
    /// reported velocity never exceeds the continuous one).
    pub fn per_second(self, delta: i64, cycle_ns: u32, power: u32) -> i64 {
        const NS_PER_S: u128 = 1_000_000_000;
        let neg = (delta < 0) != (self.0 < 0);
        // Q16 increments per cycle^power: the rate's 16 lowest fractional bits go first.
        let mut r = ((delta.unsigned_abs() as u128).saturating_mul(self.0.unsigned_abs() >> 16))
            >> PathPos::BITS;
        for _ in 0..power {
            r = div_u128(r.saturating_mul(NS_PER_S), u64::from(cycle_ns));
        }
        let r = (r >> 16).min(i64::MAX as u128) as i64;
        if neg { -r } else { r }
    }
}

impl Add for PathRate {
    type Output = PathRate;
    fn add(self, other: PathRate) -> PathRate {
        PathRate(self.0 + other.0)
    }
}

impl Sub for PathRate {
    type Output = PathRate;
    fn sub(self, other: PathRate) -> PathRate {
        PathRate(self.0 - other.0)
    }
}

impl Neg for PathRate {
    type Output = PathRate;
    fn neg(self) -> PathRate {
        PathRate(-self.0)
    }
}

/// A fraction of a rate (`a / 2`, `j / 6` in the polynomial), truncated towards zero.
impl Div<i128> for PathRate {
    type Output = PathRate;
    fn div(self, d: i128) -> PathRate {
        PathRate(div_i128(self.0, d))
    }
}

/// `n / d` (truncated towards zero), with one 64-bit division when both fit in `i64`, as they
/// nearly always do: a 128-bit division is a library call many times slower, and the cycle
/// does several per axis. The quotient is the same either way (`i64::MIN / -1` excepted from
/// the fast path); `d` = 0 panics as `/` does.
#[inline]
pub fn div_i128(n: i128, d: i128) -> i128 {
    match (i64::try_from(n), i64::try_from(d)) {
        (Ok(n), Ok(d)) if d != -1 => i128::from(n / d),
        _ => n / d,
    }
}

/// `n / d` for an unsigned dividend, with one 64-bit division when `n` fits in `u64` (see
/// [`div_i128`]).
#[inline]
pub fn div_u128(n: u128, d: u64) -> u128 {
    match u64::try_from(n) {
        Ok(n) => u128::from(n / d),
        Err(_) => n / u128::from(d),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_formats() {
        assert_eq!(Time::ONE.raw(), 65_536);
        assert_eq!(Time::cycles(3), Time::from_raw(3 << 16));
        assert_eq!(Time::from_raw(65_537).ceil_cycles(), 2);
        assert_eq!(Time::cycles(2).ceil_cycles(), 2);
        assert_eq!(PathPos::END.raw(), 1 << 64);
        assert_eq!(PathRate::from_int(5).raw(), 5 << 32);
        assert_eq!(PathRate::from_raw((5 << 32) + 7).int(), 5);
    }

    #[test]
    fn rounding_per_operation() {
        // Half a cycle at 3 sub-units per cycle: 1.5, rounded towards −∞ both ways.
        let half = Time::from_raw(1 << 15);
        assert_eq!(PathRate::from_int(3).over(half), PathPos::from_raw(1));
        assert_eq!((-PathRate::from_int(3)).over(half), PathPos::from_raw(-2));
        assert_eq!(
            PathRate::from_int(3).mul_time(half),
            PathRate::from_raw(3 << 31)
        );
        assert_eq!(
            PathRate::from_raw(i128::MAX)
                .mul_time(Time::cycles(2))
                .raw(),
            i128::MAX >> 16
        );
        // Half the path of 3 increments is 1.5: ties towards +∞.
        let mid = PathPos::from_raw(1 << 63);
        assert_eq!((mid.of(3), mid.of(-3)), (2, -1));
        assert_eq!(PathPos::END.of(-1_000), -1_000);
        assert_eq!(PathRate::from_raw(-7) / 2, PathRate::from_raw(-3));
    }

    #[test]
    fn the_divisions_give_the_quotients_of_128_bit_division() {
        let big = i128::from(i64::MAX) * 3 + 7;
        for n in [
            0,
            1,
            -1,
            7,
            -7,
            i128::from(i64::MIN),
            i128::from(i64::MAX),
            big,
            -big,
        ] {
            for d in [
                1,
                -1,
                2,
                -2,
                6,
                1_000_000_000,
                i128::from(i64::MAX),
                big,
                -big,
            ] {
                assert_eq!(div_i128(n, d), n / d, "{n} / {d}");
            }
        }
        for n in [
            0u128,
            5,
            u128::from(u64::MAX),
            u128::from(u64::MAX) + 1,
            u128::MAX,
        ] {
            for d in [1u64, 3, 1_000_000, u64::MAX] {
                assert_eq!(div_u128(n, d), n / u128::from(d), "{n} / {d}");
            }
        }
    }

    #[test]
    fn per_second_truncates_towards_zero() {
        // The whole path of 1000 inc at 1/1000 of it per cycle of 1 ms: 1000 inc/s.
        let v = PathRate::from_raw((((1u128 << 64) / 1000) as i128 + 1) << 32);
        assert_eq!(v.per_second(1000, 1_000_000, 1), 1000);
        assert_eq!(v.per_second(-1000, 1_000_000, 1), -1000);
        assert_eq!((-v).per_second(1000, 1_000_000, 1), -1000);
    }
}
