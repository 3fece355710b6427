//! One measured series: an HDR histogram of every sample (ns) and the samples over time, and the
//! figures of the table (min, p50, p90, p99, p99.9, p99.99, max, samples).
//!
//! ```
//! use timing::stats::Series;
//! let mut s = Series::new("ours");
//! for i in 1..=100u64 {
//!     s.record(i * 1_000_000, i * 1000);
//! }
//! let f = s.figures();
//! assert_eq!(f.samples, 100);
//! assert_eq!(f.min, 1000);
//! assert!(f.p50 >= 49_900 && f.p50 <= 50_100);
//! assert_eq!(s.timeline().iter().map(|b| b.count).sum::<u64>(), 100);
//! ```

use hdrhistogram::Histogram;
use serde::{Deserialize, Serialize};

/// The largest value a series records, ns (one minute): anything later is recorded as this.
pub const HIGHEST_NS: u64 = 60_000_000_000;

/// Buckets a timeline keeps at most; past that, neighbours merge and the bucket width doubles,
/// so a run of any length stays a few thousand rows.
pub const MAX_BUCKETS: usize = 1024;

/// The table's figures of one series, ns (samples: a count).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Figures {
    /// Smallest sample, ns.
    pub min: u64,
    /// Median, ns.
    pub p50: u64,
    /// 90th percentile, ns.
    pub p90: u64,
    /// 99th percentile, ns.
    pub p99: u64,
    /// 99.9th percentile, ns.
    pub p99_9: u64,
    /// 99.99th percentile, ns.
    pub p99_99: u64,
    /// Largest sample, ns.
    pub max: u64,
    /// Number of samples.
    pub samples: u64,
}

/// The figures' names as the table and `summary.json` spell them, in table order (without
/// `samples`).
pub const FIGURE_NAMES: [&str; 7] = ["min", "p50", "p90", "p99", "p99_9", "p99_99", "max"];

impl Figures {
    /// The figures of a histogram (all zero when it is empty).
    pub fn of(h: &Histogram<u64>) -> Figures {
        if h.is_empty() {
            return Figures::default();
        }
        Figures {
            min: h.min(),
            p50: h.value_at_quantile(0.5),
            p90: h.value_at_quantile(0.9),
            p99: h.value_at_quantile(0.99),
            p99_9: h.value_at_quantile(0.999),
            p99_99: h.value_at_quantile(0.9999),
            max: h.max(),
            samples: h.len(),
        }
    }

    /// A figure by its name in [`FIGURE_NAMES`] (or `samples`).
    pub fn get(&self, name: &str) -> Option<u64> {
        Some(match name {
            "min" => self.min,
            "p50" => self.p50,
            "p90" => self.p90,
            "p99" => self.p99,
            "p99_9" => self.p99_9,
            "p99_99" => self.p99_99,
            "max" => self.max,
            "samples" => self.samples,
            _ => return None,
        })
    }
}

/// An empty histogram of the range every series uses: 1 ns to [`HIGHEST_NS`], 3 significant
/// digits.
pub fn new_histogram() -> Histogram<u64> {
    // Constant, valid bounds: creation cannot fail.
    Histogram::new_with_bounds(1, HIGHEST_NS, 3).unwrap_or_else(|_| Histogram::new(3).unwrap())
}

/// The samples of one stretch of time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Bucket {
    /// Start of the bucket since the run's start, ns.
    pub start_ns: u64,
    /// Samples in it.
    pub count: u64,
    /// Smallest sample, ns.
    pub min: u64,
    /// Largest sample, ns.
    pub max: u64,
    /// Sum of the samples, ns (for the mean).
    pub sum: u64,
}

impl Bucket {
    fn empty(start_ns: u64) -> Bucket {
        Bucket {
            start_ns,
            count: 0,
            min: u64::MAX,
            max: 0,
            sum: 0,
        }
    }

    /// Mean of the bucket's samples, ns (0 when empty).
    pub fn mean(&self) -> u64 {
        self.sum.checked_div(self.count).unwrap_or(0)
    }

    fn merge(&mut self, o: &Bucket) {
        self.count += o.count;
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
        self.sum = self.sum.saturating_add(o.sum);
    }
}

/// The samples over time, in buckets of a width that doubles as the run grows (min, max, mean,
/// count per bucket): the latency-over-time plot draws from it.
#[derive(Debug, Clone)]
struct Timeline {
    width_ns: u64,
    buckets: Vec<Bucket>,
}

impl Timeline {
    fn new() -> Timeline {
        // 1 ms to start: a 2 s run keeps every 1 ms cycle apart.
        Timeline {
            width_ns: 1_000_000,
            buckets: Vec::new(),
        }
    }

    fn record(&mut self, t_ns: u64, v: u64) {
        let mut i = (t_ns / self.width_ns) as usize;
        while i >= MAX_BUCKETS {
            self.halve();
            i = (t_ns / self.width_ns) as usize;
        }
        while self.buckets.len() <= i {
            let start = self.buckets.len() as u64 * self.width_ns;
            self.buckets.push(Bucket::empty(start));
        }
        let b = &mut self.buckets[i];
        b.count += 1;
        b.min = b.min.min(v);
        b.max = b.max.max(v);
        b.sum = b.sum.saturating_add(v);
    }

    fn halve(&mut self) {
        self.width_ns = self.width_ns.saturating_mul(2);
        let old = std::mem::take(&mut self.buckets);
        for pair in old.chunks(2) {
            let mut b = Bucket::empty(pair[0].start_ns);
            for x in pair {
                b.merge(x);
            }
            self.buckets.push(b);
        }
    }
}

/// One measured series: its name, an HDR histogram of every sample and the timeline.
#[derive(Debug, Clone)]
pub struct Series {
    /// What was measured (`ours`, `cyclictest`, `8 axes, grouped`...).
    pub name: String,
    hist: Histogram<u64>,
    timeline: Timeline,
}

impl Series {
    /// An empty series.
    pub fn new(name: impl Into<String>) -> Series {
        Series {
            name: name.into(),
            hist: new_histogram(),
            timeline: Timeline::new(),
        }
    }

    /// A series read back from its files: the histogram and the timeline's buckets.
    pub fn from_parts(
        name: impl Into<String>,
        hist: Histogram<u64>,
        buckets: Vec<Bucket>,
    ) -> Series {
        let width_ns = match buckets.as_slice() {
            [a, b, ..] => b.start_ns.saturating_sub(a.start_ns).max(1),
            _ => 1_000_000,
        };
        Series {
            name: name.into(),
            hist,
            timeline: Timeline { width_ns, buckets },
        }
    }

    /// Records one sample `v` ns taken `t_ns` after the run's start. Values are clamped to
    /// 1..=[`HIGHEST_NS`] (a zero lateness is recorded as 1 ns).
    pub fn record(&mut self, t_ns: u64, v: u64) {
        let v = v.clamp(1, HIGHEST_NS);
        // In range by the clamp: record cannot fail.
        let _ = self.hist.record(v);
        self.timeline.record(t_ns, v);
    }

    /// The table's figures.
    pub fn figures(&self) -> Figures {
        Figures::of(&self.hist)
    }

    /// The histogram of every sample, ns.
    pub fn histogram(&self) -> &Histogram<u64> {
        &self.hist
    }

    /// The timeline's buckets that hold samples, in time order.
    pub fn timeline(&self) -> Vec<Bucket> {
        self.timeline
            .buckets
            .iter()
            .filter(|b| b.count > 0)
            .copied()
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_timeline_stays_bounded_and_keeps_every_sample() {
        let mut s = Series::new("x");
        // 100 s of 1 ms samples: far more than MAX_BUCKETS buckets of 1 ms.
        for k in 0..100_000u64 {
            s.record(k * 1_000_000, 1000 + k % 7);
        }
        let t = s.timeline();
        assert!(t.len() <= MAX_BUCKETS, "{}", t.len());
        assert_eq!(t.iter().map(|b| b.count).sum::<u64>(), 100_000);
        assert_eq!(s.figures().samples, 100_000);
        assert!(t.iter().all(|b| b.min >= 1000 && b.max <= 1006));
        assert!(t.windows(2).all(|w| w[0].start_ns < w[1].start_ns));
    }

    #[test]
    fn figures_are_in_order_and_clamped() {
        let mut s = Series::new("x");
        s.record(0, 0);
        s.record(0, u64::MAX);
        let f = s.figures();
        assert_eq!(f.min, 1);
        assert!(f.max >= HIGHEST_NS);
        assert!(f.min <= f.p50 && f.p50 <= f.p90 && f.p90 <= f.p99 && f.p99 <= f.max);
        assert_eq!(Figures::of(&new_histogram()), Figures::default());
        assert_eq!(f.get("samples"), Some(2));
        assert_eq!(f.get("p100"), None);
    }
}
