//! A number a user typed on a command line (seconds, a rate, a time scale): decimal text,
//! finite, within an inclusive range, refused in words that name the unit and the range
//! (`give seconds, 0.001 to 31536000`). Every binary of the workspace checks its typed numbers
//! here, as a clap `value_parser` ([`Allowed::parser`]) or from plain code ([`Allowed::parse`],
//! [`Allowed::check`] and their `_flag` forms, which put the option and the value first).
//!
//! Checked before any conversion: `Duration::from_secs_f64` panics on NaN, negatives and
//! overflow, so no typed number may reach it unchecked.
//!
//! ```
//! use drivers::cli_number::Allowed;
//! const SECONDS: Allowed = Allowed::new("seconds", 0.001, 31_536_000.0);
//! assert_eq!(SECONDS.parse(" 2.5 "), Ok(2.5));
//! assert_eq!(SECONDS.parse("NaN"), Err("give seconds, 0.001 to 31536000".to_string()));
//! assert_eq!(
//!     SECONDS.check_flag("--duration", 1e30),
//!     Err("--duration 1e30: give seconds, 0.001 to 31536000".to_string())
//! );
//! ```

/// What a typed number may be: its unit (in words) and its inclusive range, with an optional
/// note for the refusal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Allowed {
    unit: &'static str,
    min: f64,
    max: f64,
    note: Option<&'static str>,
}

impl Allowed {
    /// `unit` as the refusal says it after "give" (`"seconds"`, `"lines per second"`, `"a time
    /// scale"`), `min..=max` finite with `min <= max`.
    pub const fn new(unit: &'static str, min: f64, max: f64) -> Allowed {
        Allowed {
            unit,
            min,
            max,
            note: None,
        }
    }

    /// The same, with `note` in brackets after the refusal (`"2 replays twice as fast"`).
    pub const fn note(self, note: &'static str) -> Allowed {
        Allowed {
            note: Some(note),
            ..self
        }
    }

    /// The smallest allowed value.
    pub const fn min(&self) -> f64 {
        self.min
    }

    /// The largest allowed value.
    pub const fn max(&self) -> f64 {
        self.max
    }

    /// `v` if it is finite and in range, else the refusal.
    pub fn check(&self, v: f64) -> Result<f64, String> {
        if v.is_finite() && (self.min..=self.max).contains(&v) {
            Ok(v)
        } else {
            Err(self.refusal())
        }
    }

    /// The decimal `text` (spaces around it ignored) if it is finite and in range, else the
    /// refusal. The signature of a clap value parser (see [`Allowed::parser`]).
    pub fn parse(&self, text: &str) -> Result<f64, String> {
        match text.trim().parse::<f64>() {
            Ok(v) => self.check(v),
            Err(_) => Err(self.refusal()),
        }
    }

    /// As [`Allowed::check`], the refusal led by the option and the value (`--duration 1e30:
    /// give seconds, ...`), for numbers clap did not check.
    pub fn check_flag(&self, flag: &str, v: f64) -> Result<f64, String> {
        self.check(v)
            .map_err(|e| format!("{flag} {}: {e}", shown(v)))
    }

    /// As [`Allowed::parse`], the refusal led by the option and the text as typed.
    pub fn parse_flag(&self, flag: &str, text: &str) -> Result<f64, String> {
        self.parse(text).map_err(|e| format!("{flag} {text}: {e}"))
    }

    /// [`Allowed::parse`] as a clap value parser: `#[arg(long, value_parser =
    /// SECONDS.parser())]` (clap leads the refusal with the option and the value).
    pub fn parser(self) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
        move |text: &str| self.parse(text)
    }

    /// The range in words: `0.001 to 31536000`.
    pub fn range(&self) -> String {
        format!("{} to {}", shown(self.min), shown(self.max))
    }

    /// What a refused number is told: `give seconds, 0.001 to 31536000` (and the note).
    pub fn refusal(&self) -> String {
        match self.note {
            Some(n) => format!("give {}, {} ({n})", self.unit, self.range()),
            None => format!("give {}, {}", self.unit, self.range()),
        }
    }
}

/// A number as a user would have typed it: plain where that is short (`0.5`, `86400`), in
/// exponent form where plain would run to dozens of digits (`1e30`, `1e-300`).
pub fn shown(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-6..1e12).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SECONDS: Allowed = Allowed::new("seconds", 0.001, 31_536_000.0);

    #[test]
    fn finite_numbers_in_range_pass_at_both_ends() {
        assert_eq!(SECONDS.parse("0.001"), Ok(0.001));
        assert_eq!(SECONDS.parse("31536000"), Ok(31_536_000.0));
        assert_eq!(SECONDS.parse("\t1e3\n"), Ok(1000.0));
        assert_eq!(SECONDS.check(2.0), Ok(2.0));
    }

    #[test]
    fn everything_else_is_refused_naming_unit_and_range() {
        let refusal = "give seconds, 0.001 to 31536000";
        for text in [
            "inf",
            "-inf",
            "NaN",
            "1e30",
            "1e-300",
            "-1",
            "0",
            "0.0009",
            "31536000.5",
            "soon",
            "",
        ] {
            assert_eq!(SECONDS.parse(text), Err(refusal.into()), "{text}");
        }
        assert_eq!(SECONDS.check(f64::NAN), Err(refusal.into()));
        assert_eq!(
            SECONDS.parse_flag("--timeout", "soon"),
            Err(format!("--timeout soon: {refusal}"))
        );
        assert_eq!(
            SECONDS.check_flag("--duration", 1e-300),
            Err(format!("--duration 1e-300: {refusal}"))
        );
        let scale = Allowed::new("a time scale", 0.001, 1000.0).note("2 replays twice as fast");
        assert_eq!(
            scale.parse("0"),
            Err("give a time scale, 0.001 to 1000 (2 replays twice as fast)".into())
        );
    }

    #[test]
    fn the_parser_is_a_clap_value_parser() {
        let cmd = clap::Command::new("t").arg(
            clap::Arg::new("timeout")
                .long("timeout")
                .value_parser(SECONDS.parser()),
        );
        let m = cmd
            .clone()
            .try_get_matches_from(["t", "--timeout", "2"])
            .unwrap();
        assert_eq!(m.get_one::<f64>("timeout"), Some(&2.0));
        let e = cmd
            .try_get_matches_from(["t", "--timeout", "inf"])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--timeout") && e.contains("0.001 to 31536000"),
            "{e}"
        );
    }

    #[test]
    fn numbers_are_shown_as_typed() {
        assert_eq!(shown(0.5), "0.5");
        assert_eq!(shown(86_400.0), "86400");
        assert_eq!(shown(1e30), "1e30");
        assert_eq!(shown(1e-300), "1e-300");
        assert_eq!(shown(f64::INFINITY), "inf");
    }
}
