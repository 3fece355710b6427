//! An axis's scale: drive increments per user unit, held exactly, and every conversion between
//! user units, µunits (the shared-memory contract's unit, 10^-6 of the user unit) and
//! increments.
//!
//! `core` only and integer arithmetic, so a conversion gives the same increments on every
//! machine. The configuration writes `increments_per_unit` as a TOML float; [`Scale::from_f64`]
//! takes the decimal the user wrote (the shortest decimal that reads back as the same float:
//! `12.8`, not the binary 12.800000000000000710…) and refuses what has more than
//! [`MAX_DECIMALS`] decimal places or exceeds [`MAX_INCREMENTS_PER_UNIT`]. From then on the
//! scale is the exact fraction `num / den`.
//!
//! Every conversion to increments or µunits rounds **to nearest, ties away from zero**, once,
//! at the end (an exact product, then one rounding). A velocity, acceleration or jerk converts
//! with the same factor as a position: per second on both sides.
//!
//! ```
//! use coordinator::units::Scale;
//! let s = Scale::from_f64(12.8).unwrap();
//! assert_eq!(s.to_inc(2.5), Ok(32));
//! assert_eq!(s.inc_to_micro(1), 78_125); // 1 / 12.8 units, exactly
//! assert_eq!(s.micro_to_inc(1_000_000), 13); // 12.8 rounds to 13
//! assert_eq!(s.to_string(), "12.8");
//! ```

use core::cmp::Ordering;
use core::fmt;

/// µunits per user unit: the shared-memory contract's positions are in millionths of the unit.
pub const MICROS_PER_UNIT: i64 = 1_000_000;

/// The most decimal places `increments_per_unit` may have (its denominator divides 10^12).
pub const MAX_DECIMALS: u32 = 12;

/// The largest `increments_per_unit`: far above any drive (a nanometre encoder on a metre is
/// 10^9), low enough that every product below stays inside `i128`.
pub const MAX_INCREMENTS_PER_UNIT: u64 = 1_000_000_000;

/// A decimal number, exactly: `mantissa · 10^exponent`, with no trailing zeros in the
/// mantissa (so equal numbers are equal values).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Decimal {
    mantissa: i128,
    exponent: i32,
}

/// 10^k, if it fits an `i128` (k ≤ 38).
const fn pow10(k: u32) -> Option<i128> {
    10i128.checked_pow(k)
}

/// `n / d` rounded to nearest, ties away from zero (`d > 0`).
const fn div_round(n: i128, d: i128) -> i128 {
    let q = n / d;
    let r = (n % d).unsigned_abs();
    // r ≥ d - r is r ≥ d / 2 without overflowing 2r.
    if r >= d.unsigned_abs() - r {
        q + n.signum()
    } else {
        q
    }
}

const fn gcd(mut a: u64, mut b: u64) -> u64 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}

/// A fixed buffer for the float's text (no allocation in `core`).
struct Text {
    bytes: [u8; 48],
    len: usize,
}

impl fmt::Write for Text {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        let end = self.len + s.len();
        let slot = self.bytes.get_mut(self.len..end).ok_or(fmt::Error)?;
        slot.copy_from_slice(s.as_bytes());
        self.len = end;
        Ok(())
    }
}

impl Decimal {
    /// Zero.
    pub const ZERO: Decimal = Decimal {
        mantissa: 0,
        exponent: 0,
    };

    /// `mantissa · 10^exponent`.
    pub const fn new(mantissa: i128, exponent: i32) -> Decimal {
        let (mut m, mut e) = (mantissa, exponent);
        if m == 0 {
            return Decimal::ZERO;
        }
        while m % 10 == 0 && e < i32::MAX {
            m /= 10;
            e += 1;
        }
        Decimal {
            mantissa: m,
            exponent: e,
        }
    }

    /// The shortest decimal that reads back as `v` (what a user wrote as `12.8` is 12.8, not
    /// the nearest binary float); `None` for NaN and the infinities.
    pub fn from_f64(v: f64) -> Option<Decimal> {
        use fmt::Write as _;
        if !v.is_finite() {
            return None;
        }
        // `{:e}` prints the shortest round-trip digits: "-1.28e1", "4e2", "5e-1".
        let mut t = Text {
            bytes: [0; 48],
            len: 0,
        };
        write!(t, "{v:e}").ok()?;
        let text = t.bytes.get(..t.len)?;
        let (digits, exp) = match text.iter().position(|&b| b == b'e') {
            Some(i) => (&text[..i], &text[i + 1..]),
            None => (text, &b"0"[..]),
        };
        let (negative, digits) = match digits.split_first() {
            Some((b'-', rest)) => (true, rest),
            _ => (false, digits),
        };
        let (mut mantissa, mut fraction, mut after_point) = (0i128, 0i32, false);
        for &b in digits {
            match b {
                b'.' => after_point = true,
                b'0'..=b'9' => {
                    mantissa = mantissa
                        .checked_mul(10)?
                        .checked_add(i128::from(b - b'0'))?;
                    fraction += i32::from(after_point);
                }
                _ => return None,
            }
        }
        let exponent: i32 = core::str::from_utf8(exp).ok()?.parse().ok()?;
        let mantissa = if negative { -mantissa } else { mantissa };
        Some(Decimal::new(mantissa, exponent.checked_sub(fraction)?))
    }

    /// Decimal places: 0 for an integer, 2 for 0.25.
    pub const fn decimals(self) -> u32 {
        if self.exponent < 0 {
            self.exponent.unsigned_abs()
        } else {
            0
        }
    }

    /// Whether the number is below zero.
    pub const fn is_negative(self) -> bool {
        self.mantissa < 0
    }

    /// The exact product; `None` if it leaves the representable range.
    pub fn checked_mul(self, other: Decimal) -> Option<Decimal> {
        Some(Decimal::new(
            self.mantissa.checked_mul(other.mantissa)?,
            self.exponent.checked_add(other.exponent)?,
        ))
    }

    /// Rounded to the nearest integer, ties away from zero; `None` beyond `i128`.
    pub fn round(self) -> Option<i128> {
        let k = self.exponent.unsigned_abs();
        if self.mantissa == 0 {
            Some(0)
        } else if self.exponent >= 0 {
            self.mantissa.checked_mul(pow10(k)?)
        } else {
            // Beyond 10^38 the quotient is below a half: |mantissa| < 2^127 < 10^39 / 2.
            Some(pow10(k).map_or(0, |d| div_round(self.mantissa, d)))
        }
    }

    /// Compares the exact value with the integer `n`.
    pub fn cmp_int(self, n: i128) -> Ordering {
        let k = self.exponent.unsigned_abs();
        // When the scaled side overflows, it is the larger in magnitude: its sign decides.
        if self.exponent >= 0 {
            match pow10(k).and_then(|p| self.mantissa.checked_mul(p)) {
                Some(x) => x.cmp(&n),
                None => self.mantissa.cmp(&0),
            }
        } else {
            match pow10(k).and_then(|p| n.checked_mul(p)) {
                Some(y) => self.mantissa.cmp(&y),
                None if n == 0 => self.mantissa.cmp(&0),
                None => 0.cmp(&n),
            }
        }
    }
}

/// Exactly, in plain notation (`0.09`, `2500000000`); scientific beyond 20 zeros.
impl fmt::Display for Decimal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (m, e) = (self.mantissa, self.exponent);
        if !(-40..=20).contains(&e) {
            return write!(f, "{m}e{e}");
        }
        if e >= 0 {
            write!(f, "{m}")?;
            return (0..e).try_for_each(|_| f.write_str("0"));
        }
        let sign = if m < 0 { "-" } else { "" };
        let digits = m.unsigned_abs();
        let p = 10u128.pow(e.unsigned_abs().min(38));
        // e ≥ -40 and |m| < 10^39: the integer part is digits / 10^k for k ≤ 38, else 0.
        let (whole, frac, width) = if e >= -38 {
            (digits / p, digits % p, e.unsigned_abs() as usize)
        } else {
            (0, digits, e.unsigned_abs() as usize)
        };
        write!(f, "{sign}{whole}.{frac:0width$}")
    }
}

/// Why an `increments_per_unit` cannot be an exact scale.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum ScaleError {
    /// Zero, negative, NaN or infinite.
    #[error("{0} must be a positive number")]
    NotPositive(f64),
    /// More decimal places than the exact scale holds.
    #[error(
        "{value} has {decimals} decimal places; an exact scale takes at most 12 (as in 400.0, 12.8 or 0.5)"
    )]
    TooManyDecimals {
        /// The value.
        value: f64,
        /// Its decimal places.
        decimals: u32,
    },
    /// Above [`MAX_INCREMENTS_PER_UNIT`].
    #[error("{0} is above 1000000000 increments per unit")]
    TooLarge(f64),
}

/// Why a value in user units has no increments.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum UnitsError {
    /// NaN or infinite.
    #[error("{0} is not a finite number")]
    NotFinite(f64),
    /// Scaled, it leaves the 64-bit increments.
    #[error("{units} units are {increments} increments, beyond 64 bits")]
    OutOfRange {
        /// The value, units.
        units: f64,
        /// The exact increments.
        increments: Decimal,
    },
}

/// Drive increments per user unit, exactly: `num / den` in lowest terms, `den` a divisor of
/// 10^12.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Scale {
    /// Increments per unit as a decimal (the products with decimal user values stay exact).
    per_unit: Decimal,
    /// Increments per unit = num / den.
    num: u64,
    den: u64,
    /// µunits per increment = micro_num / micro_den (= den · 10^6 / num, in lowest terms).
    micro_num: u64,
    micro_den: u64,
}

impl Scale {
    /// A whole number of increments per unit (`1..=`[`MAX_INCREMENTS_PER_UNIT`]); panics
    /// outside that range (in a `const`, at compile time).
    pub const fn integer(n: u64) -> Scale {
        assert!(n >= 1 && n <= MAX_INCREMENTS_PER_UNIT);
        Scale::from_fraction(Decimal::new(n as i128, 0), n, 1)
    }

    /// `per_unit = num / den`, both non-zero, `den · 10^6` and `num` within `u64`.
    const fn from_fraction(per_unit: Decimal, num: u64, den: u64) -> Scale {
        let g = gcd(num, den);
        let (num, den) = (num / g, den / g);
        let micro = den * MICROS_PER_UNIT as u64;
        let h = gcd(micro, num);
        Scale {
            per_unit,
            num,
            den,
            micro_num: micro / h,
            micro_den: num / h,
        }
    }

    /// The exact scale of a configured `increments_per_unit`: positive, at most
    /// [`MAX_DECIMALS`] decimal places, at most [`MAX_INCREMENTS_PER_UNIT`].
    pub fn from_f64(increments_per_unit: f64) -> Result<Scale, ScaleError> {
        let v = increments_per_unit;
        let d = Decimal::from_f64(v)
            .filter(|d| d.mantissa > 0)
            .ok_or(ScaleError::NotPositive(v))?;
        if d.decimals() > MAX_DECIMALS {
            return Err(ScaleError::TooManyDecimals {
                value: v,
                decimals: d.decimals(),
            });
        }
        if d.cmp_int(MAX_INCREMENTS_PER_UNIT.into()) == Ordering::Greater {
            return Err(ScaleError::TooLarge(v));
        }
        // With decimals, num is the mantissa (at most 17 digits); without, at most 10^9.
        let den = 10u64.pow(d.decimals());
        let num = match d.round_scaled(d.decimals()) {
            Some(n) if n > 0 && n <= i128::from(u64::MAX) => n as u64,
            _ => return Err(ScaleError::TooLarge(v)),
        };
        Ok(Scale::from_fraction(d, num, den))
    }

    /// Increments per unit, exactly.
    pub const fn per_unit(&self) -> Decimal {
        self.per_unit
    }

    /// Increments per unit as `(num, den)` in lowest terms.
    pub const fn fraction(&self) -> (u64, u64) {
        (self.num, self.den)
    }

    /// The exact increments of `units` user units (a position, or a velocity, acceleration or
    /// jerk per second): the decimal the value was written as times the scale. `None` for NaN
    /// and the infinities.
    pub fn increments(&self, units: f64) -> Option<Decimal> {
        // Mantissas below 10^17 each: the product stays below 10^34.
        Decimal::from_f64(units)?.checked_mul(self.per_unit)
    }

    /// `units` user units in increments (a position, or a velocity, acceleration or jerk per
    /// second), rounded to nearest, ties away from zero.
    pub fn to_inc(&self, units: f64) -> Result<i64, UnitsError> {
        let exact = self.increments(units).ok_or(UnitsError::NotFinite(units))?;
        exact
            .round()
            .and_then(|i| i64::try_from(i).ok())
            .ok_or(UnitsError::OutOfRange {
                units,
                increments: exact,
            })
    }

    /// Increments in user units, for text only (a float: display, never arithmetic).
    pub fn to_units(&self, inc: i64) -> f64 {
        inc as f64 * self.den as f64 / self.num as f64
    }

    /// Increments (or increments per second^n) in µunits (per second^n), rounded to nearest,
    /// ties away from zero, saturating at the `i64` range.
    pub fn inc_to_micro(&self, inc: i64) -> i64 {
        ratio(inc, self.micro_num, self.micro_den)
    }

    /// µunits (or µunits per second^n) in increments (per second^n), rounded to nearest, ties
    /// away from zero, saturating at the `i64` range.
    pub fn micro_to_inc(&self, micro: i64) -> i64 {
        ratio(micro, self.micro_den, self.micro_num)
    }
}

impl Decimal {
    /// `self · 10^k` rounded (the integer numerator of a value with `k` decimals).
    fn round_scaled(self, k: u32) -> Option<i128> {
        Decimal::new(self.mantissa, self.exponent.checked_add(k as i32)?).round()
    }
}

/// `x · num / den`, rounded to nearest (ties away from zero) and saturated to `i64`. Both
/// factors are below 2^64, so the product fits `i128`.
fn ratio(x: i64, num: u64, den: u64) -> i64 {
    let p = i128::from(x) * i128::from(num);
    let q = if den == 1 {
        p
    } else if let (Ok(p), Ok(d)) = (i64::try_from(p), i64::try_from(den)) {
        // The common case, once per axis and value in every published state: a 64-bit
        // division is one instruction where the 128-bit one is a call.
        let (q, r) = (p / d, (p % d).unsigned_abs());
        (q + if r >= d.unsigned_abs() - r {
            p.signum()
        } else {
            0
        })
        .into()
    } else {
        div_round(p, i128::from(den))
    };
    q.clamp(i64::MIN.into(), i64::MAX.into()) as i64
}

/// The configured number, as written (`400`, `12.8`).
impl fmt::Display for Scale {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.per_unit.fmt(f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn s(v: f64) -> Scale {
        Scale::from_f64(v).unwrap()
    }

    #[test]
    fn the_decimal_is_the_one_written() {
        let d = |v: f64| Decimal::from_f64(v).unwrap();
        assert_eq!(d(12.8), Decimal::new(128, -1));
        assert_eq!(d(400.0), Decimal::new(4, 2));
        assert_eq!(d(-0.5), Decimal::new(-5, -1));
        assert_eq!(d(0.0), Decimal::ZERO);
        assert_eq!(d(-0.0), Decimal::ZERO);
        assert_eq!(d(1e-7), Decimal::new(1, -7));
        assert_eq!(d(0.1 + 0.2), Decimal::new(30000000000000004, -17));
        assert_eq!(Decimal::from_f64(f64::NAN), None);
        assert_eq!(Decimal::from_f64(f64::INFINITY), None);
        for (v, text) in [
            (12.8, "12.8"),
            (0.09, "0.09"),
            (-0.09, "-0.09"),
            (2.5e9, "2500000000"),
            (0.0, "0"),
            (1e30, "1e30"),
            (1e-41, "1e-41"),
            (-1.5e-3, "-0.0015"),
            (1.5e-39, "0.0000000000000000000000000000000000000015"),
        ] {
            assert_eq!(d(v).to_string(), text);
        }
    }

    #[test]
    fn rounding_is_to_nearest_ties_away_from_zero() {
        for (m, e, r) in [
            (15, -1, 2),
            (-15, -1, -2),
            (25, -1, 3),
            (-25, -1, -3),
            (149, -2, 1),
            (-149, -2, -1),
            (151, -2, 2),
            (4, 2, 400),
            (1, -39, 0),
            (5, -1, 1),
            (-5, -1, -1),
        ] {
            assert_eq!(Decimal::new(m, e).round(), Some(r), "{m}e{e}");
        }
        assert_eq!(Decimal::new(1, 39).round(), None);
        let s = s(0.5);
        assert_eq!(s.to_inc(3.0), Ok(2));
        assert_eq!(s.to_inc(-3.0), Ok(-2));
        assert_eq!(s.to_inc(1.0), Ok(1));
        // The decimal, not the binary float: 1.005 · 100 is 100.5 (the float product 100.49…).
        assert_eq!(Scale::integer(100).to_inc(1.005), Ok(101));
    }

    #[test]
    fn exact_comparisons() {
        let d = Decimal::new;
        assert_eq!(d(9, -2).cmp_int(1), Ordering::Less);
        assert_eq!(d(1, 0).cmp_int(1), Ordering::Equal);
        assert_eq!(d(10000001, -7).cmp_int(1), Ordering::Greater);
        assert_eq!(d(1, 50).cmp_int(i128::MAX), Ordering::Greater);
        assert_eq!(d(-1, 50).cmp_int(i128::MIN), Ordering::Less);
        assert_eq!(d(1, -50).cmp_int(0), Ordering::Greater);
        assert_eq!(d(1, -50).cmp_int(1), Ordering::Less);
        assert_eq!(d(-1, -50).cmp_int(-1), Ordering::Greater);
        assert_eq!(d(2147483647, 0).cmp_int(i32::MAX.into()), Ordering::Equal);
    }

    #[test]
    fn configured_scales_are_exact_fractions() {
        assert_eq!(s(400.0).fraction(), (400, 1));
        assert_eq!(s(3200.0).fraction(), (3200, 1));
        assert_eq!(s(0.5).fraction(), (1, 2));
        assert_eq!(s(12.8).fraction(), (64, 5));
        assert_eq!(s(0.000000000001).fraction(), (1, 1_000_000_000_000));
        assert_eq!(s(1e9).fraction(), (1_000_000_000, 1));
        // The next float above 12.8 is another decimal, with 15 places: refused.
        assert!(Scale::from_f64(12.8f64.next_up()).is_err());
        assert_eq!(Scale::integer(400), s(400.0));
        assert_eq!(s(12.8).to_string(), "12.8");
        assert_eq!(s(400.0).to_string(), "400");
    }

    #[test]
    fn what_is_not_an_exact_scale_is_refused_with_the_rule() {
        for v in [0.0, -1.0, f64::NAN, f64::INFINITY, -0.0] {
            assert!(matches!(
                Scale::from_f64(v),
                Err(ScaleError::NotPositive(_))
            ));
        }
        let e = Scale::from_f64(16384.0 / 360.0).unwrap_err();
        assert_eq!(
            e,
            ScaleError::TooManyDecimals {
                value: 16384.0 / 360.0,
                decimals: 14
            }
        );
        assert_eq!(
            e.to_string(),
            "45.51111111111111 has 14 decimal places; an exact scale takes at most 12 (as in 400.0, 12.8 or 0.5)"
        );
        assert_eq!(
            Scale::from_f64(1e-13),
            Err(ScaleError::TooManyDecimals {
                value: 1e-13,
                decimals: 13
            })
        );
        assert_eq!(Scale::from_f64(2e9), Err(ScaleError::TooLarge(2e9)));
        assert_eq!(
            Scale::from_f64(2e9).unwrap_err().to_string(),
            "2000000000 is above 1000000000 increments per unit"
        );
        assert!(Scale::from_f64(45.511111111111).is_ok());
    }

    #[test]
    fn conversions_of_the_configured_scales() {
        let x = s(400.0);
        assert_eq!(x.to_inc(150.0), Ok(60_000));
        assert_eq!(x.inc_to_micro(400), 1_000_000);
        assert_eq!(x.micro_to_inc(1_000_000), 400);
        assert_eq!(x.micro_to_inc(12_500_000), 5_000);
        assert_eq!(x.inc_to_micro(1), 2_500);
        let t = s(3200.0);
        // 1 inc = 312.5 µunits: ties away from zero on both sides.
        assert_eq!((t.inc_to_micro(1), t.inc_to_micro(-1)), (313, -313));
        assert_eq!(t.micro_to_inc(313), 1);
        let g = s(100.0);
        assert_eq!(g.inc_to_micro(-18_000), -180_000_000);
        let half = s(0.5);
        assert_eq!(half.inc_to_micro(1), 2_000_000);
        assert_eq!(half.micro_to_inc(999_999), 0);
        assert_eq!(half.micro_to_inc(1_000_000), 1);
        assert_eq!(s(12.8).to_units(128), 10.0);
        assert_eq!(x.to_units(-60_000), -150.0);
    }

    #[test]
    fn range_errors() {
        let x = s(400.0);
        assert!(matches!(x.to_inc(f64::NAN), Err(UnitsError::NotFinite(_))));
        assert!(matches!(
            x.to_inc(f64::NEG_INFINITY),
            Err(UnitsError::NotFinite(_))
        ));
        let e = x.to_inc(1e17).unwrap_err();
        assert_eq!(
            e,
            UnitsError::OutOfRange {
                units: 1e17,
                increments: Decimal::new(4, 19)
            }
        );
        assert_eq!(
            e.to_string(),
            "100000000000000000 units are 40000000000000000000 increments, beyond 64 bits"
        );
        assert_eq!(x.to_inc(1e300).map_err(|_| ()), Err(()));
        assert_eq!(x.to_inc(1e-300), Ok(0));
        assert_eq!(x.inc_to_micro(i64::MAX), i64::MAX);
        assert_eq!(x.inc_to_micro(i64::MIN), i64::MIN);
        assert_eq!(s(1e-12).micro_to_inc(i64::MAX), 9);
        assert_eq!(s(1e9).micro_to_inc(i64::MAX), i64::MAX);
    }

    /// The scales of the examples and a spread of others, by their decimals.
    fn scales() -> impl Strategy<Value = Scale> {
        (1u64..=1_000_000_000, 0u32..=12).prop_filter_map("within the allowed range", |(m, k)| {
            let v = m as f64 / 10f64.powi(k as i32);
            Scale::from_f64(v).ok()
        })
    }

    proptest! {
        #[test]
        fn micro_round_trips_are_exact_when_an_increment_is_a_micro_or_more(
            s in scales(),
            inc in -(1i64 << 30)..(1i64 << 30),
        ) {
            let (num, den) = s.fraction();
            // At most 10^6 increments per unit: one increment is at least one µunit.
            prop_assume!(u128::from(num) <= 1_000_000 * u128::from(den));
            prop_assume!(s.inc_to_micro(inc).unsigned_abs() < i64::MAX as u64);
            prop_assert_eq!(s.micro_to_inc(s.inc_to_micro(inc)), inc);
        }

        #[test]
        fn unit_round_trips_are_exact_in_whole_units(
            s in (1u64..=MAX_INCREMENTS_PER_UNIT).prop_map(Scale::integer),
            units in -1_000_000i64..1_000_000,
        ) {
            // Whole units of a whole number of increments per unit are exact both ways.
            let (num, _) = s.fraction();
            let inc = s.to_inc(units as f64).unwrap();
            prop_assert_eq!(i128::from(inc), i128::from(units) * i128::from(num));
            prop_assert_eq!(s.inc_to_micro(inc), units * MICROS_PER_UNIT);
            prop_assert_eq!(s.to_units(inc), units as f64);
        }

        #[test]
        fn the_64_bit_division_is_the_128_bit_one(
            x in any::<i64>(),
            num in 1u64..=u64::MAX,
            den in prop_oneof![2u64..1000, 2u64..=u64::MAX],
        ) {
            let exact = div_round(i128::from(x) * i128::from(num), i128::from(den));
            let exact = exact.clamp(i64::MIN.into(), i64::MAX.into()) as i64;
            prop_assert_eq!(ratio(x, num, den), exact);
            let small = (x % 1_000_000, num % 1_000_000 + 1);
            let exact = div_round(i128::from(small.0) * i128::from(small.1), i128::from(den));
            prop_assert_eq!(i128::from(ratio(small.0, small.1, den)), exact);
        }

        #[test]
        fn conversions_round_to_nearest(
            s in scales(),
            micro in -(1i64 << 50)..(1i64 << 50),
        ) {
            let (num, den) = s.fraction();
            let inc = s.micro_to_inc(micro);
            // |inc - micro · num / (den · 10^6)| ≤ 1/2, exactly:
            // |2 · inc · den · 10^6 - 2 · micro · num| ≤ den · 10^6.
            let d = i128::from(den) * i128::from(MICROS_PER_UNIT);
            let err = 2 * i128::from(inc) * d - 2 * i128::from(micro) * i128::from(num);
            prop_assert!(err.abs() <= d);
            // A tie goes away from zero.
            if err.abs() == d {
                prop_assert!(i128::from(inc).abs() * d > i128::from(micro).abs() * i128::from(num));
            }
        }

        #[test]
        fn units_to_increments_is_the_exact_decimal_rounded(
            s in scales(),
            cents in -100_000_000i64..100_000_000,
        ) {
            // A value written with two decimals, as a configuration does.
            let units = cents as f64 / 100.0;
            let (num, den) = s.fraction();
            let exact_num = i128::from(cents) * i128::from(num);
            let exact_den = i128::from(den) * 100;
            prop_assert_eq!(
                i128::from(s.to_inc(units).unwrap()),
                div_round(exact_num, exact_den)
            );
        }
    }
}
