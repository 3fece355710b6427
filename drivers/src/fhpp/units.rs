//! FHPP units and scalings, in integers (no floats on any conversion path).
//!
//! - MTR-DCI (digest 000 §2.4, §A.4): everything on the bus is in encoder increments (inc,
//!   inc/s, inc/s²), relative to the project zero point. Conversion factor
//!   UF \[inc/µm\] = encoder increments per motor revolution × gear / feed \[µm per output
//!   revolution\]; rotary: inc per output revolution = encoder × gear.
//! - EMCA, CMMO-ST (digest 001 §2.5, 002 §6): interface increments SINC, 1 SINC =
//!   10^PNU600 × unit(PNU 601); speed SINC/s, acceleration SINC/s², jerk parameters in units of
//!   10 SINC/s³ with 0 = no limit.
//! - Direct-mode byte 4: a percentage (0..100, larger values limited to 100) of a base: max
//!   speed PNU 502 (MTR-DCI), base speed PNU 540 or base acceleration PNU 560 (EMCA, CMMO-ST).
//! - Force: MTR-DCI direct mode in % of rated current (CiA 402 6071h in ‰); EMCA/CMMO-ST in ‰
//!   of the basic value PNU 555 \[mA\] (their manuals also write "%"; the digests' decision is ‰).

use super::Variant;

/// A ratio of two positive integers, e.g. a gear or an increments-per-millimetre factor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Ratio {
    /// Numerator.
    pub num: u64,
    /// Denominator (never 0 for ratios built here).
    pub den: u64,
}

impl Ratio {
    /// `num / den`, or `None` if `den` is 0.
    pub const fn new(num: u64, den: u64) -> Option<Ratio> {
        if den == 0 {
            None
        } else {
            Some(Ratio { num, den })
        }
    }
    /// `x × num / den`, rounded to nearest (half away from zero), or `None` on overflow of i64.
    pub const fn scale(self, x: i64) -> Option<i64> {
        div_round(x as i128 * self.num as i128, self.den as i128)
    }
    /// `x × den / num` (the inverse), rounded to nearest, or `None` if `num` is 0 or on
    /// overflow.
    pub const fn unscale(self, x: i64) -> Option<i64> {
        if self.num == 0 {
            return None;
        }
        div_round(x as i128 * self.den as i128, self.num as i128)
    }
}

/// `n / d` rounded to nearest, half away from zero; `None` if `d` is 0 or the result does not
/// fit an i64.
const fn div_round(n: i128, d: i128) -> Option<i64> {
    if d == 0 {
        return None;
    }
    let (n, d) = if d < 0 { (-n, -d) } else { (n, d) };
    let q = if n >= 0 {
        (n + d / 2) / d
    } else {
        (n - d / 2) / d
    };
    if q > i64::MAX as i128 || q < i64::MIN as i128 {
        None
    } else {
        Some(q as i64)
    }
}

/// The MTR-DCI motor sizes and their figures (digest 000 §1.1, §2.4, §9, Tab. 5/4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MtrSize {
    /// MTR-DCI-32 (300-line encoder, 24 V).
    S32,
    /// MTR-DCI-42 (500-line encoder, 24 V).
    S42,
    /// MTR-DCI-52 (500-line encoder, 24 V).
    S52,
    /// MTR-DCI-62 (500-line encoder, 48 V).
    S62,
}

impl MtrSize {
    /// Increments per motor revolution (4-fold evaluation of the encoder lines).
    pub const fn increments_per_rev(self) -> u32 {
        match self {
            MtrSize::S32 => 1200,
            _ => 2000,
        }
    }
    /// Rated (= default max, PNU 502) speed \[inc/s\].
    pub const fn rated_speed(self) -> u32 {
        match self {
            MtrSize::S32 => 66_000,
            MtrSize::S42 | MtrSize::S52 => 100_000,
            MtrSize::S62 => 113_400,
        }
    }
    /// Max acceleration (PNU 503 default, upper limit of PNU 407/532/541) \[inc/s²\].
    pub const fn max_acceleration(self) -> u32 {
        match self {
            MtrSize::S32 | MtrSize::S42 => 480_000,
            MtrSize::S52 | MtrSize::S62 => 240_000,
        }
    }
    /// Default record (PNU 407) and direct-mode (PNU 541) acceleration \[inc/s²\].
    pub const fn default_acceleration(self) -> u32 {
        match self {
            MtrSize::S32 | MtrSize::S42 => 480_000,
            MtrSize::S52 => 240_000,
            MtrSize::S62 => 160_000,
        }
    }
    /// Default jog phase-2 speed, PNU 531: 10 % of the max speed \[inc/s\].
    pub const fn default_jog_speed(self) -> u32 {
        self.rated_speed() / 10
    }
    /// Default homing speed, PNU 1012 \[inc/s\].
    pub const fn default_homing_speed(self) -> u32 {
        match self {
            MtrSize::S32 => 27_000,
            MtrSize::S42 => 22_400,
            MtrSize::S52 | MtrSize::S62 => 16_800,
        }
    }
    /// Highest homing speed, PNU 1012 \[inc/s\].
    pub const fn max_homing_speed(self) -> u32 {
        match self {
            MtrSize::S32 => 33_000,
            MtrSize::S42 | MtrSize::S52 => 50_000,
            MtrSize::S62 => 56_700,
        }
    }
    /// Rated motor current, PNU 1035 \[mA\].
    pub const fn rated_current_ma(self) -> u32 {
        match self {
            MtrSize::S32 => 730,
            MtrSize::S42 => 2000,
            MtrSize::S52 => 5000,
            MtrSize::S62 => 6190,
        }
    }
}

/// The MTR-DCI planetary gears (PNU 1002, motor/shaft).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MtrGear {
    /// 6.75:1 = 27/4.
    G7,
    /// 13.73:1 = 3969/289.
    G14,
    /// 22.21:1 = 1710/77 (size 62 only).
    G22,
}

impl MtrGear {
    /// The exact ratio.
    pub const fn ratio(self) -> Ratio {
        match self {
            MtrGear::G7 => Ratio { num: 27, den: 4 },
            MtrGear::G14 => Ratio {
                num: 3969,
                den: 289,
            },
            MtrGear::G22 => Ratio { num: 1710, den: 77 },
        }
    }
}

/// The mechanics between increments and the load: encoder, gear, feed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Mechanics {
    /// Increments per motor revolution.
    pub increments_per_rev: u32,
    /// Gear, motor revolutions per output revolution.
    pub gear: Ratio,
    /// Feed per output revolution \[µm\] (PNU 1003; DMES-18/25/40/63: 1500/2500/4000/6000).
    pub feed_um: u32,
}

impl Mechanics {
    /// An MTR-DCI with gear and feed.
    pub const fn mtr_dci(size: MtrSize, gear: MtrGear, feed_um: u32) -> Mechanics {
        Mechanics {
            increments_per_rev: size.increments_per_rev(),
            gear: gear.ratio(),
            feed_um,
        }
    }
    /// Increments per metre as an exact ratio (UF × 10⁶; num/den as the position factor PNU
    /// 1004 would hold per µm times 10⁶).
    pub const fn increments_per_metre(&self) -> Ratio {
        Ratio {
            num: self.increments_per_rev as u64 * self.gear.num * 1_000_000,
            den: self.gear.den * self.feed_um as u64,
        }
    }
    /// Increments per output revolution (rotary axes: UF_rev = encoder × gear).
    pub const fn increments_per_output_rev(&self) -> Ratio {
        Ratio {
            num: self.increments_per_rev as u64 * self.gear.num,
            den: self.gear.den,
        }
    }
    /// A length \[µm\] in increments, rounded to nearest.
    pub const fn um_to_inc(&self, um: i64) -> Option<i64> {
        div_round(
            um as i128 * self.increments_per_rev as i128 * self.gear.num as i128,
            self.gear.den as i128 * self.feed_um as i128,
        )
    }
    /// Increments as a length \[µm\], rounded to nearest.
    pub const fn inc_to_um(&self, inc: i64) -> Option<i64> {
        div_round(
            inc as i128 * self.gear.den as i128 * self.feed_um as i128,
            self.increments_per_rev as i128 * self.gear.num as i128,
        )
    }
}

/// PNU 601, the position unit of one SINC (EMCA, CMMO-ST).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PositionUnit {
    /// 0x00: user-defined.
    User,
    /// 0x01: metre.
    Metre,
    /// 0x41: degree.
    Degree,
    /// 0xF0: inch.
    Inch,
    /// 0xF6: revolution.
    Revolution,
    /// Another code.
    Other(u8),
}

impl PositionUnit {
    /// From the PNU 601 code.
    pub const fn from_code(code: u8) -> PositionUnit {
        match code {
            0x00 => PositionUnit::User,
            0x01 => PositionUnit::Metre,
            0x41 => PositionUnit::Degree,
            0xF0 => PositionUnit::Inch,
            0xF6 => PositionUnit::Revolution,
            c => PositionUnit::Other(c),
        }
    }
}

/// 1 SINC = 10^`exponent` × `unit` (PNU 600 as int8, PNU 601).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Sinc {
    /// PNU 600 (int8; the CMMO-ST manual also calls it uint8, digest 001 §2.5 decides int8).
    pub exponent: i8,
    /// PNU 601.
    pub unit: PositionUnit,
}

impl Sinc {
    /// SINC values as nano-units of `unit` (nanometres for metres), rounded to nearest; `None`
    /// on overflow or an exponent beyond ±18.
    pub const fn to_nano(&self, sinc: i64) -> Option<i64> {
        let e = self.exponent as i32 + 9;
        if e >= 0 {
            match pow10(e) {
                Some(p) => div_round(sinc as i128 * p, 1),
                None => None,
            }
        } else {
            match pow10(-e) {
                Some(p) => div_round(sinc as i128, p),
                None => None,
            }
        }
    }
    /// Nano-units as SINC, rounded to nearest.
    pub const fn from_nano(&self, nano: i64) -> Option<i64> {
        let e = self.exponent as i32 + 9;
        if e >= 0 {
            match pow10(e) {
                Some(p) => div_round(nano as i128, p),
                None => None,
            }
        } else {
            match pow10(-e) {
                Some(p) => div_round(nano as i128 * p, 1),
                None => None,
            }
        }
    }
}

const fn pow10(e: i32) -> Option<i128> {
    if e < 0 || e > 18 {
        return None;
    }
    let mut p: i128 = 1;
    let mut i = 0;
    while i < e {
        p *= 10;
        i += 1;
    }
    Some(p)
}

/// Direct-mode byte 4 as a value: `percent` of `base` (max speed, base speed or base
/// acceleration). Values above 100 are limited to 100 % (CMMO-ST: "0..255, limited internally
/// to 100 %"; MTR-DCI's range is 0..100). Rounded down, so a command never exceeds its base.
pub const fn percent_of(base: u32, percent: u8) -> u32 {
    let p = if percent > 100 { 100 } else { percent };
    (base as u64 * p as u64 / 100) as u32
}

/// A value as the nearest whole percentage of `base`, saturating at 255 (status byte 4, actual
/// speed %); 0 if `base` is 0.
pub const fn percent_from(value: u32, base: u32) -> u8 {
    if base == 0 {
        return 0;
    }
    let p = (value as u64 * 100 + base as u64 / 2) / base as u64;
    if p > 255 { 255 } else { p as u8 }
}

/// The force setpoint of direct mode bytes 5..8 as a current \[mA\]: MTR-DCI: % of the rated
/// current `base_ma` (PNU 1035); EMCA/CMMO-ST: ‰ of the basic value `base_ma` (PNU 555).
pub const fn force_to_milliamps(variant: Variant, value: i32, base_ma: u32) -> i64 {
    let per = force_resolution(variant) as i64;
    let n = value as i64 * base_ma as i64;
    // Truncation toward zero keeps the magnitude at or below the command.
    n / per
}

/// A current \[mA\] as the direct-mode force setpoint of `variant`, rounded to nearest; `None`
/// if `base_ma` is 0 or the result does not fit an i32.
pub const fn milliamps_to_force(variant: Variant, ma: i64, base_ma: u32) -> Option<i32> {
    match div_round(
        ma as i128 * force_resolution(variant) as i128,
        base_ma as i128,
    ) {
        Some(v) if v >= i32::MIN as i64 && v <= i32::MAX as i64 => Some(v as i32),
        _ => None,
    }
}

/// Steps of the force setpoint per base value: 100 (percent, MTR-DCI) or 1000 (per mille).
pub const fn force_resolution(variant: Variant) -> u32 {
    match variant {
        Variant::MtrDci => 100,
        Variant::Emca | Variant::CmmoSt => 1000,
    }
}

/// A jerk parameter (PNU 409/417/543/547, LSB = 10 SINC/s³) as SINC/s³; `None` = 0 = no limit.
pub const fn jerk_from_parameter(p: u32) -> Option<u64> {
    if p == 0 { None } else { Some(p as u64 * 10) }
}

/// A jerk \[SINC/s³\] as the parameter value: rounded to nearest, at least 1 (0 would mean no
/// limit), saturating at `u32::MAX`.
pub const fn jerk_to_parameter(sinc_per_s3: u64) -> u32 {
    let p = (sinc_per_s3 + 5) / 10;
    if p == 0 {
        1
    } else if p > u32::MAX as u64 {
        u32::MAX
    } else {
        p as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mtr_dci_increments_per_mm_tab_a2() {
        // Size / gear / DMES feed → inc/mm (×1000 to keep the two decimals the table prints).
        let cases = [
            (MtrSize::S32, MtrGear::G7, 1500, 5_400_000),
            (MtrSize::S42, MtrGear::G7, 2500, 5_400_000),
            (MtrSize::S52, MtrGear::G7, 4000, 3_375_000),
            (MtrSize::S62, MtrGear::G7, 6000, 2_250_000),
            (MtrSize::S42, MtrGear::G14, 2500, 10_986_851),
            (MtrSize::S62, MtrGear::G14, 6000, 4_577_855),
            (MtrSize::S62, MtrGear::G22, 6000, 7_402_597),
        ];
        for (size, gear, feed, milli_inc_per_mm) in cases {
            let m = Mechanics::mtr_dci(size, gear, feed);
            // inc per metre = inc/mm × 1000.
            assert_eq!(
                m.increments_per_metre().scale(1),
                Some(milli_inc_per_mm),
                "{size:?} {gear:?}"
            );
            assert_eq!(m.um_to_inc(1_000_000), Some(milli_inc_per_mm));
        }
        let m = Mechanics::mtr_dci(MtrSize::S42, MtrGear::G7, 2500);
        assert_eq!(m.um_to_inc(1000), Some(5400));
        assert_eq!(m.inc_to_um(5400), Some(1000));
        assert_eq!(m.um_to_inc(-50_000), Some(-270_000)); // the 50 mm upper limit
        assert_eq!(
            m.increments_per_output_rev(),
            Ratio {
                num: 54_000,
                den: 4
            }
        );
    }

    #[test]
    fn mtr_dci_max_linear_speed_at_g7() {
        // §B.2.8: 12 / 18.5 / 29.6 / 50.4 mm/s (µm/s here).
        let cases = [
            (MtrSize::S32, 1500, 12_222),
            (MtrSize::S42, 2500, 18_519),
            (MtrSize::S52, 4000, 29_630),
            (MtrSize::S62, 6000, 50_400),
        ];
        for (size, feed, um_per_s) in cases {
            let m = Mechanics::mtr_dci(size, MtrGear::G7, feed);
            assert_eq!(
                m.inc_to_um(size.rated_speed() as i64),
                Some(um_per_s),
                "{size:?}"
            );
        }
        // Rated speed in motor revolutions per second: 55 / 50 / 50 / 56.7.
        assert_eq!(
            MtrSize::S42.rated_speed() / MtrSize::S42.increments_per_rev(),
            50
        );
        assert_eq!(MtrSize::S62.default_jog_speed(), 11_340);
    }

    #[test]
    fn sinc_scaling() {
        // −7 with metre: 1 SINC = 0.1 µm = 100 nm; 10 000 SINC = 1 mm.
        let s = Sinc {
            exponent: -7,
            unit: PositionUnit::from_code(0x01),
        };
        assert_eq!(s.unit, PositionUnit::Metre);
        assert_eq!(s.to_nano(10_000), Some(1_000_000));
        assert_eq!(s.from_nano(1_000_000), Some(10_000));
        assert_eq!(s.from_nano(-149), Some(-1));
        let coarse = Sinc {
            exponent: -3,
            unit: PositionUnit::Metre,
        };
        assert_eq!(coarse.to_nano(2), Some(2_000_000));
        let fine = Sinc {
            exponent: -12,
            unit: PositionUnit::Metre,
        };
        assert_eq!(fine.to_nano(1500), Some(2));
        assert_eq!(fine.from_nano(2), Some(2000));
        assert_eq!(
            Sinc {
                exponent: 100,
                unit: PositionUnit::User
            }
            .to_nano(1),
            None
        );
        assert_eq!(
            Sinc {
                exponent: 9,
                unit: PositionUnit::Metre
            }
            .to_nano(i64::MAX),
            None
        );
    }

    #[test]
    fn percentages_clamp_and_round() {
        assert_eq!(percent_of(100_000, 50), 50_000);
        assert_eq!(percent_of(100_000, 100), 100_000);
        assert_eq!(percent_of(100_000, 255), 100_000);
        assert_eq!(percent_of(100_000, 0), 0);
        assert_eq!(percent_of(u32::MAX, 100), u32::MAX);
        assert_eq!(percent_from(49_500, 100_000), 50);
        assert_eq!(percent_from(200_000, 1000), 255);
        assert_eq!(percent_from(5, 0), 0);
    }

    #[test]
    fn force_units_per_variant() {
        // MTR-DCI: 80 % of 2000 mA; EMCA/CMMO-ST: 800 ‰ of 2000 mA.
        assert_eq!(force_to_milliamps(Variant::MtrDci, 80, 2000), 1600);
        assert_eq!(force_to_milliamps(Variant::CmmoSt, 800, 2000), 1600);
        assert_eq!(force_to_milliamps(Variant::Emca, -1000, 3000), -3000);
        assert_eq!(milliamps_to_force(Variant::MtrDci, 1600, 2000), Some(80));
        assert_eq!(milliamps_to_force(Variant::Emca, -1600, 2000), Some(-800));
        assert_eq!(milliamps_to_force(Variant::Emca, 1, 0), None);
    }

    #[test]
    fn jerk_parameter() {
        assert_eq!(jerk_from_parameter(0), None);
        assert_eq!(jerk_from_parameter(12), Some(120));
        assert_eq!(jerk_to_parameter(120), 12);
        assert_eq!(jerk_to_parameter(1), 1);
        assert_eq!(jerk_to_parameter(u64::MAX / 2), u32::MAX);
    }

    #[test]
    fn ratio_rounding_and_overflow() {
        let r = Ratio::new(1, 3).unwrap();
        assert_eq!(r.scale(2), Some(1));
        assert_eq!(r.scale(-2), Some(-1));
        assert_eq!(r.scale(1), Some(0));
        assert_eq!(r.unscale(1), Some(3));
        assert_eq!(Ratio::new(1, 0), None);
        assert_eq!(Ratio::new(u64::MAX, 1).unwrap().scale(i64::MAX), None);
        assert_eq!(Ratio { num: 0, den: 1 }.unscale(5), None);
    }
}
