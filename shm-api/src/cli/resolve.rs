//! Axis and group names to indices, using the names the coordinator publishes in
//! [`MachineState`], and user-unit numbers to µunits (exact decimal parsing, no floats, so
//! `12.5` is exactly `12_500_000`).

use crate::contract::{AxisState, GroupState, MAX_AXES, MAX_GROUPS, MICRO, MachineState};

use super::name_str;

/// A name or number the user typed that does not fit the machine.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ResolveError {
    /// No axis of that name or index.
    #[error("{option} {name}: no such axis; the axes are {known}")]
    UnknownAxis {
        /// The option it was typed for (`--axis`, `--axes`).
        option: &'static str,
        /// What was typed.
        name: String,
        /// The axes there are.
        known: String,
    },
    /// No group of that name or index.
    #[error("{option} {name}: no such group; the groups are {known}")]
    UnknownGroup {
        /// The option it was typed for (`--group`).
        option: &'static str,
        /// What was typed.
        name: String,
        /// The groups there are.
        known: String,
    },
    /// Not a decimal number, or too many decimals, or too large.
    #[error("'{0}' is not a number in user units (at most 6 decimals)")]
    BadNumber(String),
    /// A listing (`records`, `params`) has no request of its own.
    #[error("`{0}` lists the machine's description and sends no command of its own")]
    NoRequest(&'static str),
    /// A group move needs one position per member axis.
    #[error("group '{group}' has {axes} axes but {given} positions were given")]
    PositionCount {
        /// The group.
        group: String,
        /// Its member axes.
        axes: usize,
        /// Positions given.
        given: usize,
    },
}

/// The valid axes of a state (the count is clamped: it comes from another process).
pub fn axes(state: &MachineState) -> &[AxisState] {
    let n = usize::from(state.axis_count).min(MAX_AXES);
    state.axes.get(..n).unwrap_or(&[])
}

/// The valid groups of a state.
pub fn groups(state: &MachineState) -> &[GroupState] {
    let n = usize::from(state.group_count).min(MAX_GROUPS);
    state.groups.get(..n).unwrap_or(&[])
}

/// The members of a group as axis indices (clamped to the valid ones).
pub fn group_members(group: &GroupState) -> &[u8] {
    let n = usize::from(group.axis_count).min(group.axes.len());
    group.axes.get(..n).unwrap_or(&[])
}

fn lookup<'a>(names: impl Iterator<Item = &'a str> + Clone, text: &str) -> Option<u16> {
    // A name wins over an index, so an axis called "1" is still found by name.
    if let Some(i) = names.clone().position(|n| n == text) {
        return u16::try_from(i).ok();
    }
    let i: usize = text.parse().ok()?;
    (i < names.count())
        .then_some(i)
        .and_then(|i| u16::try_from(i).ok())
}

/// The names for an error's "the axes are ...": comma-separated, or `none`.
pub(crate) fn known<'a>(names: impl Iterator<Item = &'a str>) -> String {
    let v: Vec<&str> = names.collect();
    if v.is_empty() {
        "none".into()
    } else {
        v.join(", ")
    }
}

/// The index of the axis called `text` (or numbered `text`).
pub fn axis_index(state: &MachineState, text: &str) -> Result<u16, ResolveError> {
    let names = axes(state).iter().map(|a| name_str(&a.name));
    lookup(names.clone(), text).ok_or_else(|| ResolveError::UnknownAxis {
        option: "--axis",
        name: text.into(),
        known: known(names),
    })
}

/// The index of the group called `text` (or numbered `text`).
pub fn group_index(state: &MachineState, text: &str) -> Result<u16, ResolveError> {
    let names = groups(state).iter().map(|g| name_str(&g.name));
    lookup(names.clone(), text).ok_or_else(|| ResolveError::UnknownGroup {
        option: "--group",
        name: text.into(),
        known: known(names),
    })
}

/// The indices of the axes named in `names`; every axis when `names` is empty.
pub fn axis_list(state: &MachineState, names: &[String]) -> Result<Vec<u16>, ResolveError> {
    if names.is_empty() {
        let n = axes(state).len();
        return Ok((0..n).filter_map(|i| u16::try_from(i).ok()).collect());
    }
    names
        .iter()
        .map(|n| {
            axis_index(state, n.trim()).map_err(|e| match e {
                ResolveError::UnknownAxis { name, known, .. } => ResolveError::UnknownAxis {
                    option: "--axes",
                    name,
                    known,
                },
                e => e,
            })
        })
        .collect()
}

/// Parses a decimal in user units ("12.5", "-0.001", "3") to µunits, exactly.
pub fn parse_micro(text: &str) -> Result<i64, ResolveError> {
    let bad = || ResolveError::BadNumber(text.into());
    let t = text.trim();
    let (neg, digits) = match t.strip_prefix('-') {
        Some(rest) => (true, rest),
        None => (false, t.strip_prefix('+').unwrap_or(t)),
    };
    let (whole, frac) = digits.split_once('.').unwrap_or((digits, ""));
    let all_digits = |s: &str| s.bytes().all(|b| b.is_ascii_digit());
    if (whole.is_empty() && frac.is_empty()) || !all_digits(whole) || !all_digits(frac) {
        return Err(bad());
    }
    if frac.len() > 6 {
        return Err(bad());
    }
    let w: i64 = if whole.is_empty() {
        0
    } else {
        whole.parse().map_err(|_| bad())?
    };
    let mut f: i64 = if frac.is_empty() {
        0
    } else {
        frac.parse().map_err(|_| bad())?
    };
    for _ in frac.len()..6 {
        f *= 10;
    }
    let magnitude = w
        .checked_mul(MICRO)
        .and_then(|v| v.checked_add(f))
        .ok_or_else(bad)?;
    Ok(if neg { -magnitude } else { magnitude })
}

/// Parses a comma-separated list of user-unit positions.
pub fn parse_micro_list(text: &str) -> Result<Vec<i64>, ResolveError> {
    text.split(',').map(parse_micro).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_decimals_exactly() {
        assert_eq!(parse_micro("12.5"), Ok(12_500_000));
        assert_eq!(parse_micro("-0.000001"), Ok(-1));
        assert_eq!(parse_micro("+3"), Ok(3_000_000));
        assert_eq!(parse_micro(".5"), Ok(500_000));
        assert_eq!(parse_micro("7."), Ok(7_000_000));
        assert!(parse_micro("1.2345678").is_err());
        assert!(parse_micro("abc").is_err());
        assert!(parse_micro("-").is_err());
        assert!(parse_micro(".").is_err());
        assert!(parse_micro("1e3").is_err());
        assert!(parse_micro("99999999999999999").is_err());
        assert_eq!(
            parse_micro_list("100,-50.25"),
            Ok(vec![100_000_000, -50_250_000])
        );
    }
}
