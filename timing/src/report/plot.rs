//! PNG plots of a run, drawn with plotters' bitmap backend: the histogram (samples per
//! latency, both axes logarithmic), the percentile distribution (latency against 1/(1-q), the
//! way HdrHistogram plots it) and the latency over time (each bucket's maximum as a point, its
//! mean as a line). Text is drawn with a font compiled into the binary (Hack), so no system font
//! library is needed.

use std::path::{Path, PathBuf};
use std::sync::Once;

use plotters::prelude::*;

use crate::stats::Series;

const SIZE: (u32, u32) = (1000, 600);

/// The caption's font size: 22 px, smaller for a long title so that it fits the width (the
/// font is monospaced, about 0.6 em a character).
fn caption_size(title: &str) -> u32 {
    let chars = title.chars().count().max(1) as u32;
    let fits = (SIZE.0 - 40) * 10 / (6 * chars);
    fits.clamp(11, 22)
}

fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The font is a valid TrueType file shipped by the crate; registration cannot fail
        // short of a corrupt build, and then the plots come out without text.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            epaint_default_fonts::HACK_REGULAR,
        );
    });
}

fn color(i: usize) -> RGBColor {
    // Distinct and readable on white: blue, orange, green, red, purple, brown, pink, grey.
    const C: [(u8, u8, u8); 8] = [
        (31, 119, 180),
        (255, 127, 14),
        (44, 160, 44),
        (214, 39, 40),
        (148, 103, 189),
        (140, 86, 75),
        (227, 119, 194),
        (127, 127, 127),
    ];
    let (r, g, b) = C[i % C.len()];
    RGBColor(r, g, b)
}

/// µs for an axis label: `0.5`, `12`, `1500`.
fn us_label(v: &f64) -> String {
    if *v < 1.0 {
        format!("{v:.2}")
    } else if *v < 10.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.0}")
    }
}

/// The latency range of the series, µs, widened a little: (low, high), both above 0.
fn latency_range(series: &[Series]) -> (f64, f64) {
    let lo = series
        .iter()
        .filter(|s| !s.histogram().is_empty())
        .map(|s| s.histogram().min())
        .min()
        .unwrap_or(1000);
    let hi = series
        .iter()
        .map(|s| s.histogram().max())
        .max()
        .unwrap_or(1000);
    let lo = (lo.max(1) as f64 / 1000.0) / 1.5;
    let hi = (hi.max(1) as f64 / 1000.0 * 1.5).max(lo * 10.0);
    (lo, hi)
}

type PlotResult = Result<(), String>;

fn histogram(path: &Path, title: &str, series: &[Series]) -> PlotResult {
    let root = BitMapBackend::new(path, SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let (lo, hi) = latency_range(series);
    // Buckets of 1/8 of a doubling: fine enough to show modes, coarse enough to show counts.
    let step = 2f64.powf(0.125);
    let mut lines = Vec::new();
    let mut top = 1u64;
    for s in series {
        let h = s.histogram();
        let mut pts = Vec::new();
        let mut edge = (h.min().max(1) as f64 / step).max(1.0);
        while edge < h.max() as f64 * step {
            let next = edge * step;
            let n = h.count_between(
                edge as u64,
                (next as u64).saturating_sub(1).max(edge as u64),
            );
            if n > 0 {
                pts.push((((edge * next).sqrt()) / 1000.0, n as f64));
                top = top.max(n);
            }
            edge = next;
        }
        lines.push((s.name.clone(), pts));
    }
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", caption_size(title)))
        .margin(15)
        .x_label_area_size(50)
        .y_label_area_size(80)
        .build_cartesian_2d((lo..hi).log_scale(), (0.8..top as f64 * 2.0).log_scale())
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc("latency (µs, log scale)")
        .y_desc("samples per bucket (log scale)")
        .x_label_formatter(&us_label)
        .y_label_formatter(&|v| format!("{v:.0}"))
        .label_style(("sans-serif", 15))
        .draw()
        .map_err(|e| e.to_string())?;
    for (i, (name, pts)) in lines.into_iter().enumerate() {
        let c = color(i);
        chart
            .draw_series(LineSeries::new(pts, c.stroke_width(2)))
            .map_err(|e| e.to_string())?
            .label(name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(3)));
    }
    legend(&mut chart)?;
    root.present().map_err(|e| e.to_string())
}

fn legend<'a, DB: DrawingBackend + 'a, X: Ranged, Y: Ranged>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<X, Y>>,
) -> PlotResult {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font(("sans-serif", 15))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|e| e.to_string())
}

fn percentiles(path: &Path, title: &str, series: &[Series]) -> PlotResult {
    let root = BitMapBackend::new(path, SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let (lo, hi) = latency_range(series);
    let most = series
        .iter()
        .map(|s| s.histogram().len())
        .max()
        .unwrap_or(1)
        .max(10);
    // 1/(1-q) up to the resolution the samples allow.
    let right = (most as f64).max(10.0);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", caption_size(title)))
        .margin(15)
        .x_label_area_size(50)
        .y_label_area_size(80)
        .build_cartesian_2d((1.0..right).log_scale(), (lo..hi).log_scale())
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc("percentile (log scale of 1/(1-q))")
        .y_desc("latency (µs, log scale)")
        .x_label_formatter(&|v| {
            let q = 100.0 * (1.0 - 1.0 / v);
            if q < 99.0 {
                format!("{q:.0}%")
            } else {
                let digits = (-(1.0 - q / 100.0).log10()).round().max(2.0) as usize - 2;
                format!("{q:.digits$}%")
            }
        })
        .y_label_formatter(&us_label)
        .label_style(("sans-serif", 15))
        .draw()
        .map_err(|e| e.to_string())?;
    for (i, s) in series.iter().enumerate() {
        let h = s.histogram();
        let pts: Vec<(f64, f64)> = h
            .iter_quantiles(5)
            .filter(|v| v.quantile_iterated_to() < 1.0)
            .map(|v| {
                (
                    1.0 / (1.0 - v.quantile_iterated_to()),
                    h.highest_equivalent(v.value_iterated_to()).max(1) as f64 / 1000.0,
                )
            })
            .filter(|&(x, _)| x <= right)
            .collect();
        let c = color(i);
        chart
            .draw_series(LineSeries::new(pts, c.stroke_width(2)))
            .map_err(|e| e.to_string())?
            .label(s.name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(3)));
    }
    legend(&mut chart)?;
    root.present().map_err(|e| e.to_string())
}

fn over_time(path: &Path, title: &str, series: &[Series]) -> PlotResult {
    let root = BitMapBackend::new(path, SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let (lo, hi) = latency_range(series);
    let end = series
        .iter()
        .filter_map(|s| s.timeline().last().map(|b| b.start_ns))
        .max()
        .unwrap_or(0) as f64
        / 1e9;
    let end = end.max(0.01) * 1.02;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", caption_size(title)))
        .margin(15)
        .x_label_area_size(50)
        .y_label_area_size(80)
        .build_cartesian_2d(0.0..end, (lo..hi).log_scale())
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc("time since the start of the run (s)")
        .y_desc("latency (µs, log scale): points max, line mean")
        .y_label_formatter(&us_label)
        .label_style(("sans-serif", 15))
        .draw()
        .map_err(|e| e.to_string())?;
    for (i, s) in series.iter().enumerate() {
        let c = color(i);
        let t = s.timeline();
        let maxima: Vec<(f64, f64)> = t
            .iter()
            .map(|b| (b.start_ns as f64 / 1e9, b.max.max(1) as f64 / 1000.0))
            .collect();
        chart
            .draw_series(maxima.iter().map(|&p| Circle::new(p, 2, c.filled())))
            .map_err(|e| e.to_string())?
            .label(s.name.clone())
            .legend(move |(x, y)| Circle::new((x + 10, y), 4, c.filled()));
        // Mean: a line per stretch of consecutive buckets, so that windows of another series
        // (cyclictest's between ours) are gaps, not lines across them.
        let mut run: Vec<(f64, f64)> = Vec::new();
        let mut last: Option<u64> = None;
        let width = match t.as_slice() {
            [a, b, ..] => t
                .windows(2)
                .map(|w| w[1].start_ns - w[0].start_ns)
                .min()
                .unwrap_or(b.start_ns - a.start_ns),
            _ => 1,
        };
        for b in &t {
            if last.is_some_and(|l| b.start_ns - l > width) && !run.is_empty() {
                chart
                    .draw_series(LineSeries::new(
                        std::mem::take(&mut run),
                        c.mix(0.6).stroke_width(1),
                    ))
                    .map_err(|e| e.to_string())?;
            }
            run.push((b.start_ns as f64 / 1e9, b.mean().max(1) as f64 / 1000.0));
            last = Some(b.start_ns);
        }
        if !run.is_empty() {
            chart
                .draw_series(LineSeries::new(run, c.mix(0.6).stroke_width(1)))
                .map_err(|e| e.to_string())?;
        }
    }
    legend(&mut chart)?;
    root.present().map_err(|e| e.to_string())
}

/// Draws a run's three plots into `dir` (`RUN-histogram.png`, `RUN-percentiles.png`,
/// `RUN-over-time.png`); returns their paths. `title` names what was measured.
pub fn draw(dir: &Path, run: &str, title: &str, series: &[Series]) -> Result<Vec<PathBuf>, String> {
    register_font();
    let mut out = Vec::new();
    if series.iter().all(|s| s.histogram().is_empty()) {
        return Ok(out);
    }
    for (kind, f) in [
        (
            "histogram",
            histogram as fn(&Path, &str, &[Series]) -> PlotResult,
        ),
        ("percentiles", percentiles),
        ("over-time", over_time),
    ] {
        let path = dir.join(format!("{run}-{kind}.png"));
        f(&path, title, series).map_err(|e| format!("{}: {e}", path.display()))?;
        out.push(path);
    }
    Ok(out)
}
