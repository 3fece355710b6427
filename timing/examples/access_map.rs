//! Which cache lines of the cycle's state one step really reads and writes, beside the lines
//! its prefetch asks for (`Cycle::for_each_hot_line`, the memory floor of `timing step`): the
//! map that a smaller per-axis state has to start from.
//!
//! The step runs once under valgrind's `lackey`, which logs every memory access; the same
//! example then reads that log and counts, between two marker reads around the step, the
//! accesses that fall inside the state. The traced run hands the state's address and the
//! markers' to the report through a named pipe (lackey's log and the program's own output
//! cannot share one stream without their lines mixing):
//!
//! ```sh
//! cargo build --release -p timing --example access_map
//! mkfifo /tmp/access-layout
//! valgrind --tool=lackey --trace-mem=yes --log-fd=2 \
//!     target/release/examples/access_map 8 /tmp/access-layout 2>&1 >/dev/null \
//!     | target/release/examples/access_map --report /tmp/access-layout
//! ```
//!
//! The first argument is the machine's size (the grouped FHPP and CiA 402 machine of
//! `timing step`, 1 to 128 axes). Under lackey the capture before the step takes a few
//! minutes.

use coordinator::axis::Image;
use coordinator::config::{Config, MAX_AXES, MAX_GROUPS};
use coordinator::cycle::{BusFrame, Cycle, CycleInput, CycleOutput};
use coordinator::runtime::plan::plan;
use coordinator::runtime::stepper::TX_CAPACITY;
use coordinator::runtime::synthetic::{self, Kinds, Spec};
use drivers::can::Frame;
use std::collections::{BTreeMap, BTreeSet};
use std::io::BufRead;

/// Read just before and just after the step: the trace between them is the step's.
static MARK: [u64; 16] = [0; 16];

const LINE: usize = 64;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: access_map AXES LAYOUT_PIPE (traced) | access_map --report LAYOUT_PIPE";
    let (Some(first), Some(layout)) = (args.first(), args.get(1)) else {
        eprintln!("error: {usage}");
        std::process::exit(2);
    };
    if first == "--report" {
        if let Err(e) = report(layout) {
            eprintln!("error: {e}");
            std::process::exit(2);
        }
        return;
    }
    let axes = match first.parse::<usize>() {
        Ok(n) if (1..=128).contains(&n) => n,
        _ => {
            eprintln!("error: AXES '{first}': a machine has 1 to 128 axes; {usage}");
            std::process::exit(2);
        }
    };
    if let Err(e) = trace(axes, layout) {
        eprintln!("error: {e}");
        std::process::exit(2);
    }
}

/// Captures the moving machine and steps one copy of it between the two marker reads.
fn trace(axes: usize, layout: &str) -> Result<(), String> {
    let spec = Spec {
        axes,
        kinds: Kinds::Mixed,
        group_size: Some(8),
    };
    let cfg = Config::parse(&synthetic::config_of(&spec)).map_err(|e| e.to_string())?;
    let plan = plan(&cfg).map_err(|e| e.to_string())?;
    let cap = synthetic::capture_moving(&plan, true).map_err(|e| e.to_string())?;
    let mut frames = vec![BusFrame::new(0, Frame::std8(0, [0; 8])); TX_CAPACITY];
    let mut images = vec![Image::default(); cap.images.len()];
    let input = CycleInput {
        now: cap.now,
        frames: &cap.frames,
        images: &cap.images,
    };
    let mut cycle: Box<Cycle<'_, MAX_AXES, MAX_GROUPS>> = Box::new((*cap.cycle).clone());
    let mut hot = Vec::new();
    cycle.for_each_hot_line(&mut |off| hot.push(off.to_string()));
    let text = format!(
        "STATE {:x} {}\nMARKS {:x} {:x}\nHOT {}\n",
        &*cycle as *const Cycle<'_, MAX_AXES, MAX_GROUPS> as usize,
        size_of_val(&*cycle),
        &MARK[0] as *const u64 as usize,
        &MARK[8] as *const u64 as usize,
        hot.join(",")
    );
    std::fs::write(layout, text).map_err(|e| format!("{layout}: {e}"))?;
    // The report reads the layout before lackey's lines of the step reach it.
    std::thread::sleep(std::time::Duration::from_secs(1));
    let mut out = CycleOutput {
        frames: &mut frames,
        len: 0,
        overflow: 0,
        images: &mut images,
    };
    std::hint::black_box(std::hint::black_box(&MARK)[0]);
    cycle.step(&input, &mut out);
    std::hint::black_box(std::hint::black_box(&MARK)[8]);
    std::hint::black_box(out.len);
    Ok(())
}

/// The traced run's layout: the state's address and size, the markers, the prefetched lines.
struct Layout {
    base: usize,
    size: usize,
    marks: (usize, usize),
    hot: Vec<isize>,
}

fn parse_layout(text: &str) -> Result<Layout, String> {
    let mut l = Layout {
        base: 0,
        size: 0,
        marks: (0, 0),
        hot: Vec::new(),
    };
    for line in text.lines() {
        let mut w = line.split_whitespace();
        match w.next() {
            Some("STATE") => {
                l.base = hex(w.next())?;
                l.size = w
                    .next()
                    .and_then(|s| s.parse().ok())
                    .ok_or("bad STATE line")?;
            }
            Some("MARKS") => l.marks = (hex(w.next())?, hex(w.next())?),
            Some("HOT") => {
                l.hot = w
                    .next()
                    .unwrap_or("")
                    .split(',')
                    .filter_map(|s| s.parse().ok())
                    .collect()
            }
            _ => {}
        }
    }
    if l.size == 0 || l.marks.0 == 0 {
        return Err("the layout names no state or markers".into());
    }
    Ok(l)
}

/// Reads lackey's log from stdin and the traced run's layout from `pipe`, prints the map.
fn report(pipe: &str) -> Result<(), String> {
    // The layout comes once the capture is done, minutes into the log.
    let shared = std::sync::Arc::new(std::sync::OnceLock::new());
    let (path, to) = (pipe.to_string(), shared.clone());
    std::thread::spawn(move || {
        let _ = to.set(std::fs::read_to_string(&path).map_err(|e| format!("{path}: {e}")));
    });
    let mut layout: Option<Layout> = None;
    // Accesses inside the state during the step: line index → (loads, stores).
    let mut lines: BTreeMap<usize, (u64, u64)> = BTreeMap::new();
    let mut on = false;
    for line in std::io::stdin().lock().lines() {
        let line = line.map_err(|e| e.to_string())?;
        let mut w = line.split_whitespace();
        // Lackey's data accesses: " L addr,size" (load), " S" (store), " M" (modify).
        let Some(kind @ ("L" | "S" | "M")) = w.next() else {
            continue;
        };
        if layout.is_none() {
            match shared.get() {
                Some(Ok(text)) => layout = Some(parse_layout(text)?),
                Some(Err(e)) => return Err(e.clone()),
                None => continue,
            }
        }
        let Some(Layout {
            base,
            size,
            marks: (start, end),
            ..
        }) = layout
        else {
            continue;
        };
        let Some(addr) = w.next().and_then(|a| a.split(',').next()) else {
            continue;
        };
        let addr = hex(Some(addr))?;
        if addr == start {
            on = true;
        } else if addr == end {
            break;
        } else if on && addr >= base && addr < base + size {
            let e = lines.entry((addr - base + base % LINE) / LINE).or_default();
            if kind == "L" { e.0 += 1 } else { e.1 += 1 }
        }
    }
    let Some(Layout {
        base, size, hot, ..
    }) = layout.filter(|_| !lines.is_empty())
    else {
        return Err(
            "no traced step in the input: run the traced example under lackey as the \
                    example's documentation shows"
                .into(),
        );
    };
    // The prefetch's offsets may start before the state's first byte (its line's start).
    let hot: BTreeSet<usize> = hot
        .iter()
        .map(|&o| ((o + (base % LINE) as isize).max(0) as usize) / LINE)
        .collect();
    let touched: BTreeSet<usize> = lines.keys().copied().collect();
    let (loads, stores) = lines.values().fold((0, 0), |a, v| (a.0 + v.0, a.1 + v.1));
    println!("state: {size} bytes, {} lines", size.div_ceil(LINE));
    println!(
        "the step touched {} lines ({loads} loads, {stores} stores or modifies)",
        touched.len()
    );
    println!("the prefetch asks for {} lines", hot.len());
    println!(
        "  touched and prefetched: {}",
        touched.intersection(&hot).count()
    );
    println!(
        "  touched, not prefetched: {}",
        touched.difference(&hot).count()
    );
    println!(
        "  prefetched, not touched: {}",
        hot.difference(&touched).count()
    );
    println!("line (byte offset of its start in the state): loads, stores");
    for (l, (ld, st)) in &lines {
        let mark = if hot.contains(l) {
            ""
        } else {
            "  (not prefetched)"
        };
        println!(
            "  {:>8}: {ld}, {st}{mark}",
            (l * LINE) as isize - (base % LINE) as isize
        );
    }
    Ok(())
}

fn hex(s: Option<&str>) -> Result<usize, String> {
    let s = s.ok_or("a line ends early")?;
    usize::from_str_radix(s, 16).map_err(|_| format!("'{s}' is not a hexadecimal address"))
}
