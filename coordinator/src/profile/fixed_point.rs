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
        PathRate(saturating_mul_i128(self.0, t.0 as i128) >> Time::BITS)
    }

    /// The path covered at this velocity over `t`, in whole sub-units (saturated product,
    /// rounded towards −∞).
    pub const fn over(self, t: Time) -> PathPos {
        PathPos(saturating_mul_i128(self.0, t.0 as i128) >> (Time::BITS + PathRate::BITS))
    }

    /// An axis's share of this rate in increments per second^`power` (`power` = n, the cycle's
    /// power), for an axis moving `delta` increments over the whole path with a cycle of
    /// `cycle`: `delta · rate / 2^96 · (1 s / cycle)^power`, truncated towards zero (a
    /// reported velocity never exceeds the continuous one).
    pub fn per_second(self, delta: i64, cycle: CycleLen, power: u32) -> i64 {
        let neg = (delta < 0) != (self.0 < 0);
        // Q16 increments per cycle^power: the rate's 16 lowest fractional bits go first.
        let mut r = saturating_mul_u128(delta.unsigned_abs() as u128, self.0.unsigned_abs() >> 16)
            >> PathPos::BITS;
        for _ in 0..power {
            r = cycle.per_second(r);
        }
        let r = (r >> 16).min(i64::MAX as u128) as i64;
        if neg { -r } else { r }
    }
}

/// Nanoseconds in a second.
const NS_PER_S: u64 = 1_000_000_000;

/// A cycle's length, and how many cycles make a second where that is a whole number (250 µs,
/// 1 ms, 2 ms and every usual cycle): a rate per cycle then becomes a rate per second by a
/// multiplication, where other cycles take a division, which costs the cycle step tens of
/// nanoseconds per axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CycleLen {
    ns: u32,
    /// `1 s / ns` when it divides exactly, else 0.
    per_second: u64,
}

impl CycleLen {
    /// A cycle of `ns` nanoseconds (1 or more).
    pub const fn new(ns: u32) -> CycleLen {
        let per_second = if ns != 0 && NS_PER_S.is_multiple_of(ns as u64) {
            NS_PER_S / ns as u64
        } else {
            0
        };
        CycleLen { ns, per_second }
    }

    /// The length, ns.
    pub const fn ns(self) -> u32 {
        self.ns
    }

    /// `⌊r · 1 s / cycle⌋`, the product saturated first: `r` per cycle as per second.
    fn per_second(self, r: u128) -> u128 {
        // Below 2^98 neither product saturates (1 s < 2^30 ns), and where the cycle divides
        // the second the two are the same number.
        if self.per_second != 0 && r >> 98 == 0 {
            r * self.per_second as u128
        } else {
            div_u128(r.saturating_mul(u128::from(NS_PER_S)), u64::from(self.ns))
        }
    }
}

/// `a · b`, saturated at the `i128` range. Where the operands are small enough that the
/// product cannot overflow (as in every profile sample), a plain multiplication: the
/// overflow check of `saturating_mul` is a 256-bit product.
#[inline]
pub const fn saturating_mul_i128(a: i128, b: i128) -> i128 {
    // |a| < 2^(128 - la) and |b| < 2^(128 - lb): the product is below 2^127 when la + lb > 128.
    if a.unsigned_abs().leading_zeros() + b.unsigned_abs().leading_zeros() > 128 {
        a.wrapping_mul(b)
    } else {
        a.saturating_mul(b)
    }
}

/// `a · b`, saturated at `u128::MAX`, as [`saturating_mul_i128`].
#[inline]
pub const fn saturating_mul_u128(a: u128, b: u128) -> u128 {
    // The product is below 2^128 when la + lb >= 128.
    if a.leading_zeros() + b.leading_zeros() >= 128 {
        a.wrapping_mul(b)
    } else {
        a.saturating_mul(b)
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
        let ms = CycleLen::new(1_000_000);
        assert_eq!(v.per_second(1000, ms, 1), 1000);
        assert_eq!(v.per_second(-1000, ms, 1), -1000);
        assert_eq!((-v).per_second(1000, ms, 1), -1000);
    }

    #[test]
    fn per_second_by_multiplication_is_the_division() {
        // Cycles that divide the second take the multiplication, the others the division;
        // each against the plain formula, products in and beyond the multiplication's range.
        for ns in [250_000u32, 1_000_000, 2_000_000, 3_000_000, 333_333, 1, 7] {
            let c = CycleLen::new(ns);
            assert_eq!(c.per_second != 0, 1_000_000_000u32.is_multiple_of(ns));
            for r in [
                0u128,
                1,
                12_345 << 16,
                1 << 97,
                (1 << 98) - 1,
                1 << 98,
                u128::MAX,
            ] {
                let plain = r.saturating_mul(1_000_000_000) / u128::from(ns);
                assert_eq!(c.per_second(r), plain, "{r} per cycle of {ns} ns");
            }
        }
    }

    proptest::proptest! {
        #[test]
        fn products_are_saturating_mul(a: i128, b: i128, sa in 0u32..127, sb in 0u32..127) {
            // Shifted down to cover every magnitude, not only the huge ones.
            let (a, b) = (a >> sa, b >> sb);
            proptest::prop_assert_eq!(saturating_mul_i128(a, b), a.saturating_mul(b));
            let (ua, ub) = (a.unsigned_abs(), b.unsigned_abs());
            proptest::prop_assert_eq!(saturating_mul_u128(ua, ub), ua.saturating_mul(ub));
        }
    }

    #[test]
    fn products_saturate_only_where_they_overflow() {
        let edge = [
            0i128,
            1,
            -1,
            3,
            i64::MAX as i128,
            i64::MIN as i128,
            1 << 63,
            (1 << 64) - 1,
            1 << 64,
            1 << 100,
            -(1 << 100),
            i128::MAX,
            i128::MIN,
            i128::MIN + 1,
        ];
        for a in edge {
            for b in edge {
                assert_eq!(saturating_mul_i128(a, b), a.saturating_mul(b), "{a} · {b}");
                let (ua, ub) = (a.unsigned_abs(), b.unsigned_abs());
                assert_eq!(
                    saturating_mul_u128(ua, ub),
                    ua.saturating_mul(ub),
                    "{ua} · {ub}"
                );
            }
        }
    }
}
