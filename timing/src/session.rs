//! One invocation of a measuring subcommand: the machine read at the start, the optional
//! background load, the runs in order, and at the end the folder (`summary.json`, histograms,
//! plots, `table.txt`) and the table for the terminal.

use std::path::{Path, PathBuf};

use crate::load::{self, Load};
use crate::machine::Machine;
use crate::report::Report;
use crate::report::summary::{FORMAT, Run, Summary};
use crate::report::table;
use crate::stats::Series;

/// The table's file name in a run's folder.
pub const TABLE: &str = "table.txt";

/// A measuring session.
#[derive(Debug)]
pub struct Session {
    report: Report,
    load: Option<Load>,
}

impl Session {
    /// Starts: reads the machine, starts the load where asked.
    pub fn start(command: String, with_load: bool) -> Session {
        let started_unix_s = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs());
        let machine = Machine::read();
        // Said now as well as in the table, so that the run can be stopped and started again.
        if let Some(b) = crate::busy::describe(&machine.busy_before) {
            eprintln!("note: {b}");
        }
        let load = with_load.then(Load::start);
        Session {
            report: Report {
                summary: Summary {
                    format: FORMAT,
                    command,
                    started_unix_s,
                    machine,
                    load: with_load.then(|| load::DESCRIPTION.to_string()),
                    runs: Vec::new(),
                },
                series: Vec::new(),
            },
            load,
        }
    }

    /// Adds a run's result.
    pub fn add(&mut self, (run, series): (Run, Vec<Series>)) {
        self.report.push(run, series);
    }

    /// Stops the load, writes the folder and returns the table (with where the files went).
    pub fn finish(mut self, dir: &Path) -> Result<String, String> {
        drop(self.load.take());
        self.report.summary.machine.finish();
        let plots = self.report.write(dir)?;
        let text = table::summary(&self.report.summary);
        let path = dir.join(TABLE);
        std::fs::write(&path, &text).map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(format!(
            "{text}\nwritten to {}: summary.json, {TABLE}, {} series (.hdr, .hgrm, .timeline.csv), {} plots\n",
            dir.display(),
            self.report.series.iter().map(Vec::len).sum::<usize>(),
            plots.len()
        ))
    }
}

/// Redraws a folder's plots, percentile texts and table (`timing report DIR`); returns the
/// table.
pub fn redraw(dir: &Path) -> Result<String, String> {
    let report = Report::read(dir)?;
    // The percentile text is derived from the histogram too: rewritten with the plots.
    for (run, series) in report.summary.runs.iter().zip(&report.series) {
        for (meta, s) in run.series.iter().zip(series) {
            crate::report::files::write_hgrm(dir, &meta.file, s.histogram())
                .map_err(|e| e.to_string())?;
        }
    }
    let plots = report.plot(dir)?;
    let text = table::summary(&report.summary);
    let path = dir.join(TABLE);
    std::fs::write(&path, &text).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(format!(
        "{text}\nredrawn in {}: {TABLE}, the .hgrm files and {} plots\n",
        dir.display(),
        plots.len()
    ))
}

/// `timing/results/run-YYYY-MM-DD-HHMMSS` (UTC), under the current directory.
pub fn default_dir() -> PathBuf {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    PathBuf::from(crate::RESULTS_DIR).join(format!("run-{}", utc_stamp(secs)))
}

/// `YYYY-MM-DD-HHMMSS` of a Unix time, UTC (civil-from-days, proleptic Gregorian).
pub fn utc_stamp(secs: u64) -> String {
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}-{:02}{:02}{:02}",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stamps_are_utc_dates() {
        assert_eq!(utc_stamp(0), "1970-01-01-000000");
        assert_eq!(utc_stamp(951_782_400 + 3661), "2000-02-29-010101");
        assert_eq!(utc_stamp(1_700_000_000), "2023-11-14-221320");
    }
}
