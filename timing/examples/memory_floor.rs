//! What a cold step's memory floor would be with N lines: the cost of only reading N cache
//! lines of one copy of the cycle's state, in `timing step --cache cold`'s set-up (64 MiB of
//! copies written first, then each copy visited in turn, on a thread set up as the cycle
//! thread), with no computation between the reads. `timing step` measures the floor of the
//! lines the step itself asks for (its `memory floor` series); this shows how the floor
//! scales, to judge what a layout with fewer lines would buy.
//!
//! The reads are independent (no read's address depends on another's), so the processor may
//! have all of them in flight at once: the best a step that touches N lines could do, however
//! its code and prefetches were arranged.
//!
//! ```sh
//! cargo run --release -p timing --example memory_floor              # 1 to 512 lines, spread and packed
//! cargo run --release -p timing --example memory_floor -- 8 90 128  # only these line counts
//! ```
//!
//! "spread": the lines evenly apart over the whole state (as an axis's fields are, among the
//! other axes'); "packed": N lines one after the other from the state's start (as a layout that
//! put every line a step needs together would have them).

use coordinator::config::{MAX_AXES, MAX_GROUPS};
use coordinator::cycle::Cycle;
use coordinator::runtime::realtime_thread::{RealtimeSettings, enter_realtime, leave_realtime};
use drivers::time::monotonic_now;
use timing::step::{COLD_BYTES, read_lines};

const LINE: usize = 64;
/// Rounds over the whole set of copies per line count: each gives one sample per copy.
const ROUNDS: usize = 12;

fn main() {
    let counts: Vec<usize> = match std::env::args()
        .skip(1)
        .map(|a| a.parse::<usize>().map_err(|_| a))
        .collect::<Result<Vec<_>, _>>()
    {
        Ok(v) if v.is_empty() => vec![1, 8, 16, 32, 64, 90, 128, 256, 512],
        Ok(v) => v,
        Err(a) => {
            eprintln!("error: '{a}' is not a line count (a whole number, 1 or more)");
            std::process::exit(2);
        }
    };
    let state = size_of::<Cycle<'static, MAX_AXES, MAX_GROUPS>>();
    let lines_in_state = state / LINE;
    if let Some(&n) = counts.iter().find(|&&n| n == 0 || n > lines_in_state) {
        eprintln!("error: {n} lines: the state has 1 to {lines_in_state} lines of {LINE} bytes");
        std::process::exit(2);
    }
    let copies = COLD_BYTES.div_ceil(state);
    let report = enter_realtime(&RealtimeSettings {
        priority: Some(80),
        cpu: None,
        lock_memory: true,
    });
    println!(
        "cold-memory floor: {copies} copies of the cycle's state ({state} bytes each, {} MiB), \
         {ROUNDS} rounds per line count; measuring thread: {}",
        (copies * state) >> 20,
        match report.fifo_priority {
            Some(p) => format!("SCHED_FIFO {p}"),
            None => "normal scheduler (SCHED_FIFO refused)".into(),
        }
    );
    let mut buf = vec![0u8; copies * state];
    println!(
        "{:>6}  {:>13} {:>13}  {:>13} {:>13}",
        "lines", "spread p50", "spread p90", "packed p50", "packed p90"
    );
    for &n in &counts {
        let spread: Vec<usize> = (0..n).map(|i| i * lines_in_state / n * LINE).collect();
        let packed: Vec<usize> = (0..n).map(|i| i * LINE).collect();
        let s = floor(&mut buf, state, &spread);
        let p = floor(&mut buf, state, &packed);
        println!(
            "{n:>6}  {:>10} ns {:>10} ns  {:>10} ns {:>10} ns",
            s.0, s.1, p.0, p.1
        );
    }
    leave_realtime();
}

/// Median and 90th percentile, ns, of reading the lines at `offsets` of one copy, each copy in
/// turn after all were written.
fn floor(buf: &mut [u8], state: usize, offsets: &[usize]) -> (u64, u64) {
    let mut samples = Vec::with_capacity(ROUNDS * buf.len() / state);
    for round in 0..ROUNDS {
        // Written again, as `timing step` copies the state before each batch: the first copies
        // are out of the caches by the time the last is written.
        buf.fill(round as u8);
        for copy in buf.chunks_exact(state) {
            let t0 = monotonic_now();
            read_lines(copy, offsets);
            let t1 = monotonic_now();
            samples.push(t1.saturating_duration_since(t0).as_nanos() as u64);
        }
    }
    samples.sort_unstable();
    (samples[samples.len() / 2], samples[samples.len() * 9 / 10])
}
