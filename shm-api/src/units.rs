//! Numbers in µunits (millionths of an axis's unit, [`crate::contract::MICRO`]) as text, exactly
//! (no floats): the clients print positions with them, and the coordinator writes the step
//! conditions of its description with them.
//!
//! ```
//! assert_eq!(shm_api::units::user(-1_250_000), "-1.25");
//! assert_eq!(shm_api::units::micro(12_500_000, 3), "12.500");
//! ```

use crate::contract::MICRO;

/// Formats µunits as user units with `decimals` (0..=6) decimals, rounding half away from zero.
pub fn micro(value: i64, decimals: u32) -> String {
    let decimals = decimals.min(6);
    let step = 10_i128.pow(6 - decimals);
    let abs = i128::from(value).abs();
    let rounded = (abs + step / 2) / step;
    let scale = i128::from(MICRO) / step;
    let sign = if value < 0 && rounded != 0 { "-" } else { "" };
    let whole = rounded / scale;
    if decimals == 0 {
        format!("{sign}{whole}")
    } else {
        let frac = rounded % scale;
        format!("{sign}{whole}.{frac:0width$}", width = decimals as usize)
    }
}

/// A number in µunits as user units, with as many decimals as it needs (`400_000_000` →
/// `400`, `-1_250_000` → `-1.25`).
pub fn user(value: i64) -> String {
    let s = micro(value, 6);
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".into() } else { s.into() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn micro_rounds_exactly() {
        assert_eq!(micro(12_500_000, 3), "12.500");
        assert_eq!(micro(-1_234_567, 3), "-1.235");
        assert_eq!(micro(-400, 3), "0.000");
        assert_eq!(micro(999_999, 2), "1.00");
        assert_eq!(micro(-1, 6), "-0.000001");
        assert_eq!(micro(2_500_000, 0), "3");
        assert_eq!(micro(i64::MIN, 6), "-9223372036854.775808");
    }

    #[test]
    fn user_numbers_have_the_decimals_they_need() {
        assert_eq!(user(400_000_000), "400");
        assert_eq!(user(-1_250_000), "-1.25");
        assert_eq!(user(1), "0.000001");
        assert_eq!(user(0), "0");
        assert_eq!(user(-1), "-0.000001");
    }
}
