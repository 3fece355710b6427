//! The figures as text: one table per run (samples, min, p50, p90, p99, p99.9, p99.99, max),
//! its ratios and goals, and the side-by-side table of `timing compare`.

use std::fmt::Write as _;

use super::summary::{Run, Summary};

/// A duration in ns for a reader: `850 ns`, `3.21 µs`, `45.6 µs`, `123 µs`, `1.23 ms`, `2.50 s`.
pub fn duration(ns: u64) -> String {
    let v = ns as f64;
    if ns < 1_000 {
        format!("{ns} ns")
    } else if ns < 10_000 {
        format!("{:.2} µs", v / 1e3)
    } else if ns < 100_000 {
        format!("{:.1} µs", v / 1e3)
    } else if ns < 1_000_000 {
        format!("{:.0} µs", v / 1e3)
    } else if ns < 1_000_000_000 {
        format!("{:.2} ms", v / 1e6)
    } else {
        format!("{:.2} s", v / 1e9)
    }
}

/// A ratio: `1.07x`, or `-` where it could not be computed.
pub fn ratio(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.2}x"))
}

/// A figure's name as the table heads it (`p99_9` is `p99.9`).
fn figure_head(f: &str) -> String {
    f.replace('_', ".")
}

const HEADS: [&str; 8] = [
    "samples", "min", "p50", "p90", "p99", "p99.9", "p99.99", "max",
];

/// One run as text: the title, the real-time settings obtained, notes, the table, the ratios
/// and the goals.
pub fn run(r: &Run) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "== {}: {} ==", r.name, r.title);
    if let Some(g) = &r.realtime {
        let _ = writeln!(s, "real-time: {}", g.describe());
    }
    for (tool, state) in &r.baselines {
        let _ = writeln!(s, "baseline {tool}: {state}");
    }
    for n in &r.notes {
        let _ = writeln!(s, "note: {n}");
    }
    let width = r
        .series
        .iter()
        .map(|x| x.name.chars().count())
        .max()
        .unwrap_or(6)
        .max(6);
    let _ = write!(s, "{:<width$}", "series");
    for h in HEADS {
        let _ = write!(s, " {h:>10}");
    }
    s.push('\n');
    for x in &r.series {
        let f = &x.figures;
        let _ = write!(s, "{:<width$} {:>10}", x.name, f.samples);
        for v in [f.min, f.p50, f.p90, f.p99, f.p99_9, f.p99_99, f.max] {
            let _ = write!(s, " {:>10}", duration(v));
        }
        s.push('\n');
    }
    // One line per pair of series: "ratio A / B: p50 1.05x, p99 1.10x".
    let mut pairs: Vec<(&str, &str)> = Vec::new();
    for q in &r.ratios {
        let pair = (q.numerator.series.as_str(), q.denominator.series.as_str());
        if !pairs.contains(&pair) {
            pairs.push(pair);
        }
    }
    for (a, b) in pairs {
        let parts: Vec<String> = r
            .ratios
            .iter()
            .filter(|q| q.numerator.series == a && q.denominator.series == b)
            .map(|q| format!("{} {}", figure_head(&q.numerator.figure), ratio(q.value)))
            .collect();
        let _ = writeln!(s, "ratio {a} / {b}: {}", parts.join(", "));
    }
    for g in &r.goals {
        let (m, l) = if g.unit == "x" {
            (format!("{:.2}x", g.measured), format!("{:.2}x", g.limit))
        } else {
            (
                format!("{:.2} {}", g.measured, g.unit),
                format!("{:.2} {}", g.limit, g.unit),
            )
        };
        let _ = writeln!(
            s,
            "goal: {}: {m} (limit {l}) {}",
            g.text,
            if g.met { "met" } else { "NOT met" }
        );
    }
    s
}

/// Every run of a summary, after the machine.
pub fn summary(sum: &Summary) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{}", sum.machine.describe());
    let _ = writeln!(
        s,
        "background load: {}",
        sum.load.as_deref().unwrap_or("none")
    );
    for r in &sum.runs {
        s.push('\n');
        s.push_str(&run(r));
    }
    s
}

/// Two summaries side by side: for each series both have (same run, same name), each figure
/// of A, of B and B / A.
pub fn compare(a: &Summary, b: &Summary, a_name: &str, b_name: &str) -> String {
    let mut s = String::new();
    for (tag, name, sum) in [("A", a_name, a), ("B", b_name, b)] {
        let _ = writeln!(
            s,
            "{tag}: {name}\n   {}\n   background load: {}",
            sum.machine.describe().replace('\n', "\n   "),
            sum.load.as_deref().unwrap_or("none")
        );
    }
    let mut matched = 0;
    for ra in &a.runs {
        let Some(rb) = b.runs.iter().find(|r| r.name == ra.name) else {
            let _ = writeln!(s, "\n{}: only in A", ra.name);
            continue;
        };
        let _ = writeln!(s, "\n== {}: {} ==", ra.name, ra.title);
        let _ = writeln!(
            s,
            "{:<28} {:>8} {:>12} {:>12} {:>8}",
            "series", "figure", "A", "B", "B / A"
        );
        for sa in &ra.series {
            let Some(sb) = rb.series.iter().find(|x| x.name == sa.name) else {
                let _ = writeln!(s, "{:<28} only in A", sa.name);
                continue;
            };
            matched += 1;
            for (i, f) in [
                "samples", "min", "p50", "p90", "p99", "p99_9", "p99_99", "max",
            ]
            .iter()
            .enumerate()
            {
                let (x, y) = (
                    sa.figures.get(f).unwrap_or(0),
                    sb.figures.get(f).unwrap_or(0),
                );
                let (xs, ys) = if *f == "samples" {
                    (x.to_string(), y.to_string())
                } else {
                    (duration(x), duration(y))
                };
                let q = (x > 0).then(|| y as f64 / x as f64);
                let _ = writeln!(
                    s,
                    "{:<28} {:>8} {:>12} {:>12} {:>8}",
                    if i == 0 { sa.name.as_str() } else { "" },
                    HEADS[i],
                    xs,
                    ys,
                    ratio(q)
                );
            }
        }
        for sb in &rb.series {
            if !ra.series.iter().any(|x| x.name == sb.name) {
                let _ = writeln!(s, "{:<28} only in B", sb.name);
            }
        }
    }
    for rb in &b.runs {
        if !a.runs.iter().any(|r| r.name == rb.name) {
            let _ = writeln!(s, "\n{}: only in B", rb.name);
        }
    }
    if matched == 0 {
        let _ = writeln!(s, "\nno series in common");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_read_well() {
        assert_eq!(duration(850), "850 ns");
        assert_eq!(duration(3_210), "3.21 µs");
        assert_eq!(duration(45_600), "45.6 µs");
        assert_eq!(duration(123_400), "123 µs");
        assert_eq!(duration(1_230_000), "1.23 ms");
        assert_eq!(duration(2_500_000_000), "2.50 s");
        assert_eq!(ratio(None), "-");
        assert_eq!(ratio(Some(1.066)), "1.07x");
    }
}
