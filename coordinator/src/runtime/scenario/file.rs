//! The scenario file (`coordinator scenario FILE`): which machine, how long, which seed, and the
//! faults, scripted and random. Every value is checked before use; an error names the key, the
//! value and what is allowed.

use serde::Deserialize;

use super::faults::FaultKind;

/// A scenario as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioFile {
    /// `"embedded"` (the default machine), `"synthetic"` (see [`ScenarioFile::synthetic`]), or
    /// the path of a configuration whose drives are all simulated (relative to the scenario
    /// file).
    pub machine: String,
    /// The synthetic machine's shape.
    #[serde(default)]
    pub synthetic: Option<SyntheticMachine>,
    /// Machine time the campaign runs once the machine is up (booted, enabled, homed), seconds.
    pub duration_s: f64,
    /// The seed of every random choice (faults and the operator's moves).
    #[serde(default)]
    pub seed: u64,
    /// Random faults.
    #[serde(default)]
    pub random: Option<RandomFaults>,
    /// Scripted faults.
    #[serde(default, rename = "fault")]
    pub faults: Vec<ScriptedFault>,
}

/// `[synthetic]`: N simulated axes of the four kinds in turn, grouped.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SyntheticMachine {
    /// Axes, 1 to 64.
    pub axes: usize,
    /// Axes per group, 1 to 8.
    #[serde(default = "default_group")]
    pub group_size: usize,
    /// The cycle, µs (250 to 100000).
    #[serde(default = "default_cycle")]
    pub cycle_us: u32,
}

fn default_group() -> usize {
    3
}
fn default_cycle() -> u32 {
    1000
}

/// `[random]`: faults drawn at random, one after another.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RandomFaults {
    /// Mean machine time between two faults' starts, seconds (exponentially distributed).
    pub every_s: f64,
    /// Each fault lasts a uniform draw from `[min, max]` seconds.
    #[serde(default = "default_length")]
    pub length_s: [f64; 2],
    /// The kinds to draw from; default: every kind the machine can have.
    #[serde(default)]
    pub kinds: Vec<FaultKind>,
}

fn default_length() -> [f64; 2] {
    [0.02, 0.5]
}

/// `[[fault]]`: one fault at a set time.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScriptedFault {
    /// When, seconds after the machine is up.
    pub at_s: f64,
    /// What.
    pub kind: FaultKind,
    /// The axis it hits (drive and Modbus kinds); default: one at random.
    #[serde(default)]
    pub axis: Option<String>,
    /// The bus it hits (frame, SYNC and bus-off kinds); default: one at random.
    #[serde(default)]
    pub bus: Option<String>,
    /// How long, seconds (default 0.2).
    #[serde(default = "default_fault_length")]
    pub length_s: f64,
}

fn default_fault_length() -> f64 {
    0.2
}

/// The longest campaign: a year of machine time.
pub const MAX_DURATION_S: f64 = 31_536_000.0;

/// Checks seconds a scenario gives under `key` (the workspace's one check of a typed number).
pub fn seconds(key: &str, v: f64, min: f64, max: f64) -> Result<(), String> {
    drivers::cli_number::Allowed::new("seconds", min, max)
        .check(v)
        .map(|_| ())
        .map_err(|e| format!("{key} = {v}: {e}"))
}

impl ScenarioFile {
    /// Parses and checks a scenario.
    pub fn parse(text: &str) -> Result<ScenarioFile, String> {
        let s: ScenarioFile = toml::from_str(text).map_err(|e| e.to_string())?;
        seconds("duration_s", s.duration_s, 0.001, MAX_DURATION_S)?;
        match s.machine.as_str() {
            "synthetic" => {
                let Some(m) = s.synthetic else {
                    return Err(
                        "machine = \"synthetic\" needs a [synthetic] table (axes, group_size, cycle_us)"
                            .into(),
                    );
                };
                if !(1..=64).contains(&m.axes) {
                    return Err(format!("synthetic.axes = {}: give 1 to 64", m.axes));
                }
                if !(1..=8).contains(&m.group_size) {
                    return Err(format!(
                        "synthetic.group_size = {}: give 1 to 8",
                        m.group_size
                    ));
                }
                if !(250..=100_000).contains(&m.cycle_us) {
                    return Err(format!(
                        "synthetic.cycle_us = {}: give 250 to 100000",
                        m.cycle_us
                    ));
                }
            }
            _ if s.synthetic.is_some() => {
                return Err(format!(
                    "[synthetic] is for machine = \"synthetic\", not machine = \"{}\"",
                    s.machine
                ));
            }
            "" => return Err(
                "machine = \"\": give \"embedded\", \"synthetic\" or the path of a configuration"
                    .into(),
            ),
            _ => {}
        }
        if let Some(r) = &s.random {
            seconds("random.every_s", r.every_s, 0.001, MAX_DURATION_S)?;
            let [a, b] = r.length_s;
            seconds("random.length_s[0]", a, 0.001, 3600.0)?;
            seconds("random.length_s[1]", b, a, 3600.0)?;
        }
        for (i, f) in s.faults.iter().enumerate() {
            seconds(&format!("fault[{i}].at_s"), f.at_s, 0.0, s.duration_s)?;
            seconds(&format!("fault[{i}].length_s"), f.length_s, 0.001, 3600.0)?;
        }
        Ok(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_scenario_parses_and_bad_values_are_named() {
        let ok = "machine = \"synthetic\"\nduration_s = 10\nseed = 3\n[synthetic]\naxes = 8\n\
                  [random]\nevery_s = 0.5\nkinds = [\"frame-loss\", \"drive-reboot\"]\n\
                  [[fault]]\nat_s = 1\nkind = \"bus-off\"\nbus = \"can0\"\n";
        let s = ScenarioFile::parse(ok).unwrap();
        assert_eq!(s.synthetic.unwrap().group_size, 3);
        assert_eq!(s.faults[0].kind, FaultKind::BusOff);
        for (text, says) in [
            (
                ok.replace("duration_s = 10", "duration_s = inf"),
                "duration_s = inf",
            ),
            (
                ok.replace("duration_s = 10", "duration_s = -1"),
                "duration_s = -1",
            ),
            (ok.replace("axes = 8", "axes = 0"), "synthetic.axes = 0"),
            (
                ok.replace("every_s = 0.5", "every_s = nan"),
                "random.every_s = NaN",
            ),
            (ok.replace("at_s = 1", "at_s = 11"), "fault[0].at_s = 11"),
            (
                ok.replace("\"bus-off\"", "\"meteor\""),
                "unknown variant `meteor`",
            ),
            (
                ok.replace("seed = 3", "seed = 3\nspeed = 2"),
                "unknown field `speed`",
            ),
        ] {
            let e = ScenarioFile::parse(&text).unwrap_err();
            assert!(e.contains(says), "{e}");
        }
    }
}
