//! A run's report: the table ([`table`]), `summary.json` ([`summary`]), the histogram files
//! ([`files`]) and the PNG plots ([`plot`]); [`Report`] writes a folder and reads it back for
//! `timing report DIR` and `timing compare A B`.

pub mod files;
pub mod plot;
pub mod summary;
pub mod table;

use std::path::{Path, PathBuf};

use crate::stats::Series;
use summary::{Run, Summary};

/// A summary and the series of each of its runs (`series[i]` belongs to `summary.runs[i]`, in
/// the order of its `series`).
#[derive(Debug, Clone)]
pub struct Report {
    /// The figures and the machine.
    pub summary: Summary,
    /// Each run's series.
    pub series: Vec<Vec<Series>>,
}

impl Report {
    /// Adds a run with its series.
    pub fn push(&mut self, run: Run, series: Vec<Series>) {
        self.summary.runs.push(run);
        self.series.push(series);
    }

    /// Writes the folder: `summary.json`, each series' files and each run's plots. Returns the
    /// plots written.
    pub fn write(&self, dir: &Path) -> Result<Vec<PathBuf>, String> {
        files::create_dir(dir).map_err(|e| e.to_string())?;
        for (run, series) in self.summary.runs.iter().zip(&self.series) {
            for (meta, s) in run.series.iter().zip(series) {
                files::write_series(dir, &meta.file, s).map_err(|e| e.to_string())?;
            }
        }
        files::write_summary(dir, &self.summary).map_err(|e| e.to_string())?;
        self.plot(dir)
    }

    /// Draws every run's plots into `dir`.
    pub fn plot(&self, dir: &Path) -> Result<Vec<PathBuf>, String> {
        let mut out = Vec::new();
        for (run, series) in self.summary.runs.iter().zip(&self.series) {
            out.extend(plot::draw(
                dir,
                &run.name,
                &format!("{}: {}", run.name, run.title),
                series,
            )?);
        }
        Ok(out)
    }

    /// Reads a folder written by [`Report::write`].
    pub fn read(dir: &Path) -> Result<Report, String> {
        let summary = files::read_summary(dir).map_err(|e| e.to_string())?;
        let mut series = Vec::with_capacity(summary.runs.len());
        for run in &summary.runs {
            let mut v = Vec::with_capacity(run.series.len());
            for s in &run.series {
                v.push(files::read_series(dir, &s.file, &s.name).map_err(|e| e.to_string())?);
            }
            series.push(v);
        }
        Ok(Report { summary, series })
    }
}
