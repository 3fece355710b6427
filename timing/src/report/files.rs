//! A run's folder: `summary.json`, and per series `FILE.hdr` (the histogram, HdrHistogram's
//! V2 compressed encoding, readable by every HdrHistogram implementation), `FILE.hgrm` (its
//! percentile distribution as text, in µs: HdrHistogram's plotter reads it) and
//! `FILE.timeline.csv` (the samples over time). Written by a run, read back by `timing report`
//! and `timing compare`.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use hdrhistogram::Histogram;
use hdrhistogram::serialization::{Deserializer, Serializer, V2DeflateSerializer};

use super::summary::Summary;
use crate::stats::{Bucket, Series};

/// The summary's file name in a run's folder.
pub const SUMMARY: &str = "summary.json";

/// A file that could not be written or read, named with the reason.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {reason}")]
pub struct FileError {
    /// The file.
    pub path: String,
    /// What went wrong, as the system or the parser says it.
    pub reason: String,
}

fn err(path: &Path, reason: impl std::fmt::Display) -> FileError {
    FileError {
        path: path.display().to_string(),
        reason: reason.to_string(),
    }
}

fn write(path: &Path, bytes: &[u8]) -> Result<(), FileError> {
    std::fs::write(path, bytes).map_err(|e| err(path, e))
}

fn read(path: &Path) -> Result<Vec<u8>, FileError> {
    std::fs::read(path).map_err(|e| err(path, e))
}

/// The percentile distribution as HdrHistogram prints it (`outputPercentileDistribution`),
/// values in µs.
pub fn hgrm(h: &Histogram<u64>) -> String {
    // TotalCount is the running total, as HdrHistogram prints it.
    let mut out = String::from("       Value     Percentile TotalCount 1/(1-Percentile)\n\n");
    let mut total = 0u64;
    for v in h.iter_quantiles(5) {
        total += v.count_since_last_iteration();
        let q = v.quantile_iterated_to();
        let inv = if q < 1.0 {
            format!("{:14.2}", 1.0 / (1.0 - q))
        } else {
            format!("{:>14}", "inf")
        };
        let _ = writeln!(
            out,
            "{:12.3} {:14.12} {:10} {inv}",
            h.highest_equivalent(v.value_iterated_to()) as f64 / 1000.0,
            q,
            total,
        );
    }
    let _ = writeln!(
        out,
        "#[Mean    = {:12.3}, StdDeviation   = {:12.3}]",
        h.mean() / 1000.0,
        h.stdev() / 1000.0
    );
    let _ = writeln!(
        out,
        "#[Max     = {:12.3}, Total count    = {:12}]",
        h.max() as f64 / 1000.0,
        h.len()
    );
    let _ = writeln!(
        out,
        "#[Buckets = {:12}, SubBuckets     = {:12}]",
        h.buckets(),
        sub_buckets(h.sigfig())
    );
    out
}

/// HdrHistogram's sub-bucket count for `sigfig` significant digits: the power of two at or
/// above 2 × 10^sigfig (2048 for 3 digits).
fn sub_buckets(sigfig: u8) -> u64 {
    (2 * 10u64.pow(u32::from(sigfig))).next_power_of_two()
}

/// Writes `FILE.hgrm`, the percentile text of a histogram.
pub fn write_hgrm(dir: &Path, file: &str, h: &Histogram<u64>) -> Result<(), FileError> {
    write(&dir.join(format!("{file}.hgrm")), hgrm(h).as_bytes())
}

/// Writes a series' files (`FILE.hdr`, `FILE.hgrm`, `FILE.timeline.csv`) into `dir`.
pub fn write_series(dir: &Path, file: &str, s: &Series) -> Result<(), FileError> {
    let path = dir.join(format!("{file}.hdr"));
    let mut bytes = Vec::new();
    V2DeflateSerializer::new()
        .serialize(s.histogram(), &mut bytes)
        .map_err(|e| err(&path, format!("cannot encode the histogram: {e}")))?;
    write(&path, &bytes)?;
    write_hgrm(dir, file, s.histogram())?;
    let mut csv = String::from("start_s,count,min_ns,mean_ns,max_ns,sum_ns\n");
    for b in s.timeline() {
        let _ = writeln!(
            csv,
            "{:.6},{},{},{},{},{}",
            b.start_ns as f64 / 1e9,
            b.count,
            b.min,
            b.mean(),
            b.max,
            b.sum
        );
    }
    write(&dir.join(format!("{file}.timeline.csv")), csv.as_bytes())
}

/// Reads a series back from `dir` (its histogram and timeline).
pub fn read_series(dir: &Path, file: &str, name: &str) -> Result<Series, FileError> {
    let path = dir.join(format!("{file}.hdr"));
    let bytes = read(&path)?;
    let hist: Histogram<u64> = Deserializer::new()
        .deserialize(&mut bytes.as_slice())
        .map_err(|e| err(&path, format!("not an HdrHistogram V2 file ({e})")))?;
    let path = dir.join(format!("{file}.timeline.csv"));
    let text = String::from_utf8(read(&path)?).map_err(|e| err(&path, e))?;
    let mut buckets = Vec::new();
    for (i, line) in text.lines().enumerate().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let bad = || {
            err(
                &path,
                format!("line {}: expected 6 numbers, found \"{line}\"", i + 1),
            )
        };
        if f.len() != 6 {
            return Err(bad());
        }
        let start_s: f64 = f[0].parse().map_err(|_| bad())?;
        if !start_s.is_finite() || start_s < 0.0 {
            return Err(bad());
        }
        let n = |k: usize| f[k].parse::<u64>().map_err(|_| bad());
        buckets.push(Bucket {
            start_ns: (start_s * 1e9).round() as u64,
            count: n(1)?,
            min: n(2)?,
            max: n(4)?,
            sum: n(5)?,
        });
    }
    Ok(Series::from_parts(name, hist, buckets))
}

/// Writes `summary.json`.
pub fn write_summary(dir: &Path, s: &Summary) -> Result<(), FileError> {
    let path = dir.join(SUMMARY);
    let text = serde_json::to_string_pretty(s).map_err(|e| err(&path, e))?;
    write(&path, format!("{text}\n").as_bytes())
}

/// Reads `summary.json` from a run's folder.
pub fn read_summary(dir: &Path) -> Result<Summary, FileError> {
    let path = dir.join(SUMMARY);
    let bytes = read(&path)?;
    serde_json::from_slice(&bytes).map_err(|e| err(&path, format!("not a timing summary: {e}")))
}

/// Creates the folder (and its parents).
pub fn create_dir(dir: &Path) -> Result<PathBuf, FileError> {
    std::fs::create_dir_all(dir).map_err(|e| err(dir, e))?;
    Ok(dir.to_path_buf())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_series_reads_back_as_written() {
        let dir = std::env::temp_dir().join(format!("timing-files-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut s = Series::new("ours");
        for k in 0..5000u64 {
            s.record(k * 1_000_000, 3000 + (k * 7919) % 20_000);
        }
        write_series(&dir, "cycle-ours", &s).unwrap();
        let r = read_series(&dir, "cycle-ours", "ours").unwrap();
        assert_eq!(r.figures(), s.figures());
        assert_eq!(r.timeline(), s.timeline());
        let text = std::fs::read_to_string(dir.join("cycle-ours.hgrm")).unwrap();
        assert!(text.contains("Total count    =         5000"), "{text}");
        assert!(text.contains("SubBuckets     =         2048"), "{text}");
        let last_total: u64 = text
            .lines()
            .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
            .skip(1)
            .last()
            .and_then(|l| l.split_whitespace().nth(2))
            .and_then(|v| v.parse().ok())
            .unwrap();
        assert_eq!(last_total, 5000);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
