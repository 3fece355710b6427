//! `summary.json`: what a run measured, its figures, the ratios to its baselines, the goals,
//! and the machine. Every ratio and goal is computed from the figures written beside it, so a
//! reader (or a test) can recompute it from the file alone.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::machine::{Granted, Machine};
use crate::stats::{Figures, Series};

/// The version of this file's layout.
pub const FORMAT: u32 = 1;

/// Everything one invocation of `timing` measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// [`FORMAT`].
    pub format: u32,
    /// The command line, as typed.
    pub command: String,
    /// When the run started, seconds since 1970 (UTC).
    pub started_unix_s: u64,
    /// The machine.
    pub machine: Machine,
    /// The background load (`--load`), described; none without it.
    pub load: Option<String>,
    /// The runs, in the order they ran.
    pub runs: Vec<Run>,
}

/// One run (`cycle`, `step`, `sim`, `publish`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Run {
    /// Its name, as the subcommand.
    pub name: String,
    /// What it measured, one line with the unit.
    pub title: String,
    /// Its settings (period, priority, axes...), by name.
    pub settings: BTreeMap<String, serde_json::Value>,
    /// Real-time settings the measuring thread obtained, where it asked for them.
    pub realtime: Option<Granted>,
    /// Each baseline tool and whether it ran: `ran`, `absent` (not installed) or `failed`.
    pub baselines: BTreeMap<String, String>,
    /// Lines for the reader (a refused setting, a missing baseline).
    pub notes: Vec<String>,
    /// The series measured.
    pub series: Vec<SeriesSummary>,
    /// Ratios between series' figures.
    pub ratios: Vec<Ratio>,
    /// Where each goal stands.
    pub goals: Vec<Goal>,
}

/// One series' figures and where its data lie.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SeriesSummary {
    /// Its name in the run.
    pub name: String,
    /// The stem of its files in the folder (`FILE.hdr`, `FILE.hgrm`, `FILE.timeline.csv`).
    pub file: String,
    /// The figures, ns.
    pub figures: Figures,
    /// Samples the run planned for it, where it knows (each one measured is a sample).
    pub planned_samples: Option<u64>,
}

/// Names one figure of one series.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct FigureRef {
    /// The series' name.
    pub series: String,
    /// The figure (`p50`, `p99`, ... as in [`crate::stats::FIGURE_NAMES`]).
    pub figure: String,
}

/// `numerator / denominator`, both figures of this run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Ratio {
    /// What it compares, for the reader.
    pub name: String,
    /// The figure above the line.
    pub numerator: FigureRef,
    /// The figure below it.
    pub denominator: FigureRef,
    /// The quotient; none when the denominator is 0 or a series is missing.
    pub value: Option<f64>,
}

/// A goal and where it stands: `measured` against `limit` (at most).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Goal {
    /// The goal, in words.
    pub text: String,
    /// The measured value, in `unit`.
    pub measured: f64,
    /// The limit, in `unit`.
    pub limit: f64,
    /// `µs` or `x` (a ratio).
    pub unit: String,
    /// `measured <= limit`.
    pub met: bool,
}

impl Run {
    /// An empty run.
    pub fn new(name: &str, title: &str) -> Run {
        Run {
            name: name.into(),
            title: title.into(),
            settings: BTreeMap::new(),
            realtime: None,
            baselines: BTreeMap::new(),
            notes: Vec::new(),
            series: Vec::new(),
            ratios: Vec::new(),
            goals: Vec::new(),
        }
    }

    /// Records a setting.
    pub fn set(&mut self, key: &str, value: impl Into<serde_json::Value>) {
        self.settings.insert(key.into(), value.into());
    }

    /// The stem of a series' files: run and series name, lower case, with dashes.
    pub fn file_of(&self, series: &str) -> String {
        let mut s = String::new();
        for c in format!("{}-{}", self.name, series).chars() {
            if c.is_ascii_alphanumeric() {
                s.push(c.to_ascii_lowercase());
            } else if !s.ends_with('-') {
                s.push('-');
            }
        }
        s.trim_end_matches('-').to_string()
    }

    /// Adds a series' figures.
    pub fn add(&mut self, s: &Series, planned_samples: Option<u64>) {
        self.series.push(SeriesSummary {
            name: s.name.clone(),
            file: self.file_of(&s.name),
            figures: s.figures(),
            planned_samples,
        });
    }

    /// A figure of a series of this run.
    pub fn figure(&self, r: &FigureRef) -> Option<u64> {
        self.series
            .iter()
            .find(|s| s.name == r.series)
            .and_then(|s| s.figures.get(&r.figure))
    }

    /// Adds the ratio `num.figure / den.figure` for each figure named, computed from the
    /// figures already added.
    pub fn add_ratios(&mut self, num: &str, den: &str, figures: &[&str]) {
        for f in figures {
            let numerator = FigureRef {
                series: num.into(),
                figure: (*f).into(),
            };
            let denominator = FigureRef {
                series: den.into(),
                figure: (*f).into(),
            };
            let value = match (self.figure(&numerator), self.figure(&denominator)) {
                (Some(a), Some(b)) if b > 0 => Some(a as f64 / b as f64),
                _ => None,
            };
            self.ratios.push(Ratio {
                name: format!("{num} / {den}, {f}"),
                numerator,
                denominator,
                value,
            });
        }
    }

    /// A ratio added before, by series and figure.
    pub fn ratio(&self, num: &str, den: &str, figure: &str) -> Option<f64> {
        self.ratios
            .iter()
            .find(|r| {
                r.numerator.series == num
                    && r.denominator.series == den
                    && r.numerator.figure == figure
            })
            .and_then(|r| r.value)
    }

    /// Adds a goal on a figure, in µs: `series.figure <= limit_us`.
    pub fn goal_us(&mut self, text: &str, series: &str, figure: &str, limit_us: f64) {
        let r = FigureRef {
            series: series.into(),
            figure: figure.into(),
        };
        if let Some(v) = self.figure(&r) {
            let measured = v as f64 / 1000.0;
            self.goals.push(Goal {
                text: text.into(),
                measured,
                limit: limit_us,
                unit: "µs".into(),
                met: measured <= limit_us,
            });
        }
    }

    /// Adds a goal on a ratio added before: `num/den (figure) <= limit`.
    pub fn goal_ratio(&mut self, text: &str, num: &str, den: &str, figure: &str, limit: f64) {
        if let Some(measured) = self.ratio(num, den, figure) {
            self.goals.push(Goal {
                text: text.into(),
                measured,
                limit,
                unit: "x".into(),
                met: measured <= limit,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ratios_and_goals_come_from_the_figures() {
        let mut run = Run::new("cycle", "t");
        let mut a = Series::new("ours");
        let mut b = Series::new("cyclictest");
        for i in 0..100 {
            a.record(i, 2000);
            b.record(i, 1000);
        }
        run.add(&a, Some(100));
        run.add(&b, None);
        run.add_ratios("ours", "cyclictest", &["p50", "p99"]);
        assert_eq!(run.ratio("ours", "cyclictest", "p50"), Some(2.0));
        run.goal_ratio("g", "ours", "cyclictest", "p99", 1.2);
        assert!(!run.goals[0].met);
        run.goal_us("h", "ours", "p50", 2.5);
        assert!(run.goals[1].met);
        assert_eq!(run.file_of("8 axes, grouped"), "cycle-8-axes-grouped");
        run.add_ratios("ours", "nobody", &["p50"]);
        assert_eq!(run.ratios.last().unwrap().value, None);
    }
}
