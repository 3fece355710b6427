//! `timing step`: the cycle step's compute time, measured as `coordinator/benches/cycle.rs`
//! measures it: a synthetic machine ([`synthetic::Spec`]) runs in virtual time until every axis
//! moves, one step's state and inputs are captured ([`synthetic::capture_moving`]), and the
//! step is timed again and again on copies of that state (the copy is made outside the timed
//! span), so every sample does one whole cycle's work.
//!
//! Each sample is one step between two `CLOCK_MONOTONIC` readings (about 20 ns of the reading
//! itself is in every sample; criterion times batches instead). The measuring thread is set up
//! as the coordinator's cycle thread ([`enter_realtime`] at the given priority), since that is
//! where the step runs: on the normal scheduler, every other process on a shared machine
//! preempts it and the tail measures them. A refused priority is reported and the run goes on.
//!
//! Beside each cold series, its memory floor: the same cold copies, of which only the lines
//! the step asks for at its start ([`coordinator::cycle::Cycle::for_each_hot_line`]) are read
//! ([`read_lines`]), nothing computed. A cold step cannot be cheaper than bringing in its lines;
//! the ratio of the two says how much of the cold figure is the machine's memory.

use coordinator::axis::Image;
use coordinator::config::{Config, MAX_AXES, MAX_GROUPS};
use coordinator::cycle::{BusFrame, CycleInput, CycleOutput};
use coordinator::runtime::plan::plan;
use coordinator::runtime::realtime_thread::{RealtimeSettings, enter_realtime, leave_realtime};
use coordinator::runtime::stepper::TX_CAPACITY;
use coordinator::runtime::synthetic::{self, Kinds, Spec};
use drivers::can::Frame;
use drivers::cli_number::Allowed;
use drivers::time::monotonic_now;

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use crate::machine::Granted;
use crate::progress::Progress;
use crate::report::summary::Run;
use crate::stats::Series;

/// Which drives the machine has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Profile {
    /// FHPP drives only (MTR-DCI, EMCA, CMMO-ST).
    Fhpp,
    /// CiA 402 drives only (TLC5xx, MTR-DCI in CiA 402).
    Cia402,
    /// The four kinds in turn, as the criterion bench has them.
    Both,
}

impl Profile {
    fn kinds(self) -> Kinds {
        match self {
            Profile::Fhpp => Kinds::Fhpp,
            Profile::Cia402 => Kinds::Cia402,
            Profile::Both => Kinds::Mixed,
        }
    }

    /// Its name in series names and settings.
    pub fn name(self) -> &'static str {
        match self {
            Profile::Fhpp => "FHPP",
            Profile::Cia402 => "CiA 402",
            Profile::Both => "FHPP and CiA 402",
        }
    }
}

/// Where the step finds its state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cache {
    /// Out of the caches: copies of the state worth [`COLD_BYTES`] are made first, then each
    /// is stepped in turn, so each step reads its state from memory. As criterion's batches
    /// do, and as the cycle thread after sleeping a period while other threads ran.
    Cold,
    /// In the caches: each step right after its copy was made.
    Hot,
}

impl Cache {
    /// Its name in series names.
    pub fn name(self) -> &'static str {
        match self {
            Cache::Cold => "cold",
            Cache::Hot => "hot",
        }
    }
}

/// The copies of a cold batch add up to at least this many bytes: above the last-level cache
/// of the machines this runs on (32 MiB on this one's EPYC).
pub const COLD_BYTES: usize = 64 << 20;

/// What `timing step` measures; checked by [`StepOptions::check`].
#[derive(Debug, Clone, PartialEq)]
pub struct StepOptions {
    /// Machine sizes, axes (each 1..=128).
    pub axes: Vec<usize>,
    /// The drives.
    pub profiles: Vec<Profile>,
    /// Groups of 8 moving together (true) or every axis moving alone (false); both when both
    /// are listed.
    pub grouped: Vec<bool>,
    /// Cold caches, hot caches, or both (one series each).
    pub caches: Vec<Cache>,
    /// Measuring time per series, s.
    pub seconds_per_series: f64,
    /// SCHED_FIFO priority of the measuring thread (1..=99); none: the normal scheduler.
    pub priority: Option<i32>,
}

impl StepOptions {
    /// Refuses values that cannot be measured with, naming the limit.
    pub fn check(&self) -> Result<(), String> {
        if self.caches.is_empty() || self.profiles.is_empty() || self.grouped.is_empty() {
            return Err("name at least one cache state, profile and way of moving".into());
        }
        if self.axes.is_empty() {
            return Err("--axes: name at least one machine size".into());
        }
        if let Some(n) = self.axes.iter().find(|&&n| !(1..=128).contains(&n)) {
            return Err(format!("--axes {n}: a machine has 1 to 128 axes"));
        }
        if let Some(p) = self.priority.filter(|p| !(1..=99).contains(p)) {
            return Err(format!("--priority {p}: SCHED_FIFO priorities are 1 to 99"));
        }
        Allowed::new("seconds", 0.01, 86_400.0)
            .check_flag("--duration", self.seconds_per_series)?;
        Ok(())
    }

    fn machines(&self) -> Vec<(usize, Profile, bool)> {
        let mut v = Vec::new();
        for &p in &self.profiles {
            for &g in &self.grouped {
                for &n in &self.axes {
                    v.push((n, p, g));
                }
            }
        }
        v
    }
}

/// A series' name: `8 axes, FHPP and CiA 402, grouped, cold`.
pub fn series_name(axes: usize, p: Profile, grouped: bool, cache: Cache) -> String {
    format!(
        "{axes} axes, {}, {}, {}",
        p.name(),
        if grouped { "grouped" } else { "single" },
        cache.name()
    )
}

/// The memory floor's series beside a machine's cold one: `8 axes, FHPP and CiA 402, grouped,
/// cold, memory floor`.
pub fn floor_name(axes: usize, p: Profile, grouped: bool) -> String {
    format!(
        "{}, memory floor",
        series_name(axes, p, grouped, Cache::Cold)
    )
}

/// Times the captured step (or, with `floor`, only the reading of those lines of the state)
/// `count` times (calibrated to the time asked for) on a thread set up
/// as the cycle thread; `done` counts samples for the progress display.
#[allow(clippy::too_many_arguments)]
fn measure(
    cap: &coordinator::runtime::stepper::Captured<'_>,
    name: &str,
    o: &StepOptions,
    cache: Cache,
    floor: Option<&[usize]>,
    done: &AtomicU64,
    planned: &AtomicU64,
    run_start: drivers::time::Instant,
) -> (Series, u64, Granted) {
    let report = enter_realtime(&RealtimeSettings {
        priority: o.priority,
        cpu: None,
        lock_memory: true,
    });
    let granted = Granted::from_report(o.priority, &report);
    let mut frames = vec![BusFrame::new(0, Frame::std8(0, [0; 8])); TX_CAPACITY];
    let mut modbus = vec![Image::default(); cap.images.len()];
    let input = CycleInput {
        now: cap.now,
        frames: &cap.frames,
        images: &cap.images,
    };
    // Cold: as criterion's iter_batched_ref, a batch of copies is made first, then each is
    // stepped in turn; enough copies that the first is out of the caches when its turn comes.
    // Hot: one copy, stepped at once.
    let size = std::mem::size_of_val(&*cap.cycle).max(1);
    let batch_len = match cache {
        Cache::Cold => COLD_BYTES.div_ceil(size).clamp(16, 4096),
        Cache::Hot => 1,
    };
    let mut batch: Vec<_> = (0..batch_len).map(|_| cap.cycle.clone()).collect();
    let mut time_batch = |record: &mut dyn FnMut(drivers::time::Instant, u64)| {
        for c in batch.iter_mut() {
            *c = cap.cycle.clone();
        }
        for cycle in batch.iter_mut() {
            let mut out = CycleOutput {
                frames: &mut frames,
                len: 0,
                overflow: 0,
                images: &mut modbus,
            };
            let t0 = monotonic_now();
            match floor {
                None => cycle.step(&input, &mut out),
                Some(lines) => read_lines(&**cycle, lines),
            }
            let t1 = monotonic_now();
            std::hint::black_box(out.len);
            record(t0, t1.saturating_duration_since(t0).as_nanos() as u64);
        }
    };
    // Calibrate: how many samples fill the time asked for (copies included).
    let c0 = monotonic_now();
    let rounds = (2000 / batch_len).max(2);
    for _ in 0..rounds {
        time_batch(&mut |_, _| {});
    }
    let per = (monotonic_now().saturating_duration_since(c0).as_nanos() as f64
        / (rounds * batch_len) as f64)
        .max(1.0);
    let batches = ((o.seconds_per_series * 1e9 / per) as u64 / batch_len as u64)
        .clamp((1000 / batch_len as u64).max(2), 50_000_000);
    let count = batches * batch_len as u64;
    planned.store(count, Ordering::Relaxed);
    let mut s = Series::new(name);
    let mut pause = monotonic_now();
    for i in 0..batches {
        let mut last = pause;
        time_batch(&mut |t0, ns| {
            s.record(
                t0.saturating_duration_since(run_start).as_nanos() as u64,
                ns,
            );
            last = t0;
        });
        done.store((i + 1) * batch_len as u64, Ordering::Relaxed);
        // 1 ms off the CPU every 10 ms: a SCHED_FIFO thread busy for longer than the kernel's
        // real-time budget (950 ms of every second) is throttled for the rest, in the middle
        // of a step; the cycle thread sleeps most of each period anyway.
        if last.saturating_duration_since(pause) > Duration::from_millis(10) {
            std::thread::sleep(Duration::from_millis(1));
            pause = monotonic_now();
        }
    }
    leave_realtime();
    (s, count, granted)
}

/// Reads one byte at each offset in `lines` of `state`, the reads independent of one another,
/// so that they can all be in flight at once: the cost of bringing those lines in and nothing
/// else. Panics on an offset outside `state`.
#[inline(never)]
pub fn read_lines<T: ?Sized>(state: &T, lines: &[usize]) {
    let size = std::mem::size_of_val(state);
    let p = (state as *const T).cast::<std::mem::MaybeUninit<u8>>();
    for &o in lines {
        assert!(o < size, "line offset {o} outside a {size}-byte state");
        // SAFETY: `o` is inside `*state` (checked above); read as `MaybeUninit`, a padding
        // byte is a valid value too. Volatile, so that the read is made although its value is
        // not used.
        let _ = unsafe { std::ptr::read_volatile(p.add(o)) };
    }
}

/// The lines a step asks for before it starts, as offsets into the state, each once; a line
/// that starts before the state is read at its first byte.
fn hot_lines(cycle: &coordinator::cycle::Cycle<'_, MAX_AXES, MAX_GROUPS>) -> Vec<usize> {
    let mut v = Vec::new();
    cycle.for_each_hot_line(&mut |o| v.push(o.max(0) as usize));
    v.sort_unstable();
    v.dedup();
    v
}

/// Runs `timing step`; returns the run's summary part and one series per machine.
pub fn run(o: &StepOptions) -> Result<(Run, Vec<Series>), String> {
    o.check()?;
    let list = o.machines();
    let mut run = Run::new(
        "step",
        "the cycle step's compute time, one whole cycle per sample",
    );
    run.set("seconds_per_series", o.seconds_per_series);
    run.set(
        "machines",
        "coordinator::runtime::synthetic, every axis homed and moving; groups of up to 8",
    );
    run.set("cold_bytes", COLD_BYTES as u64);
    let mut out = Vec::new();
    // A cold series is followed by its memory floor.
    let per_machine = o.caches.len() + usize::from(o.caches.contains(&Cache::Cold));
    let parts = (list.len() * per_machine) as u64;
    let mut progress = Progress::new("step", parts * 100);
    // Each series's samples are placed in time since the run's start, one after the other.
    let run_start = monotonic_now();
    let mut k = 0u64;
    for &(n, p, grouped) in &list {
        let machine = series_name(n, p, grouped, Cache::Cold);
        let machine = machine.trim_end_matches(", cold");
        let spec = Spec {
            axes: n,
            kinds: p.kinds(),
            group_size: grouped.then_some(8),
        };
        let cfg = Config::parse(&synthetic::config_of(&spec))
            .map_err(|e| format!("{machine}: the synthetic machine does not parse: {e}"))?;
        let plan = plan(&cfg).map_err(|e| format!("{machine}: {e}"))?;
        let cap =
            synthetic::capture_moving(&plan, grouped).map_err(|e| format!("{machine}: {e}"))?;
        run.set(
            &format!("cycle_us ({machine})"),
            plan.period.as_micros() as u64,
        );
        // What one copy of the state weighs: a cold step reads its part of this from memory.
        run.set("state_bytes", std::mem::size_of_val(&*cap.cycle) as u64);
        let lines = hot_lines(&cap.cycle);
        run.set(&format!("hot_lines ({machine})"), lines.len() as u64);
        let mut series: Vec<(String, Cache, Option<&[usize]>)> = Vec::new();
        for &cache in &o.caches {
            series.push((series_name(n, p, grouped, cache), cache, None));
            if cache == Cache::Cold {
                series.push((floor_name(n, p, grouped), cache, Some(&lines)));
            }
        }
        for (name, cache, floor) in series {
            let done = AtomicU64::new(0);
            let planned = AtomicU64::new(u64::MAX);
            let measured = std::thread::scope(|scope| {
                // Named, so that a profiler can pick the measuring thread out (`perf report
                // --comm step`).
                let worker = std::thread::Builder::new()
                    .name("step".into())
                    .spawn_scoped(scope, || {
                        measure(&cap, &name, o, cache, floor, &done, &planned, run_start)
                    })
                    .map_err(|e| format!("cannot start the measuring thread: {e}"))?;
                while !worker.is_finished() {
                    std::thread::sleep(Duration::from_millis(100));
                    let total = planned.load(Ordering::Relaxed).max(1);
                    let i = done.load(Ordering::Relaxed);
                    if total != u64::MAX {
                        progress.set(k * 100 + i * 100 / total);
                    }
                }
                worker
                    .join()
                    .map_err(|_| format!("{name}: the measuring thread failed"))
            });
            let (s, count, granted) = measured?;
            if run.realtime.is_none() {
                run.notes.extend(granted.warnings.iter().cloned());
                run.realtime = Some(granted);
            }
            k += 1;
            progress.set(k * 100);
            run.add(&s, Some(count));
            out.push(s);
            if floor.is_some() {
                // How far the cold step is above what only reading its lines costs.
                run.add_ratios(
                    &series_name(n, p, grouped, Cache::Cold),
                    &name,
                    &["p50", "p99"],
                );
            }
        }
    }
    progress.finish();
    run.set("axes", o.axes.clone());
    run.set(
        "profiles",
        o.profiles.iter().map(|p| p.name()).collect::<Vec<_>>(),
    );
    // The goals are the criterion bench's measurement: the mixed machine, grouped, cold.
    let both = o.profiles.contains(&Profile::Both)
        && o.grouped.contains(&true)
        && o.caches.contains(&Cache::Cold);
    if both && o.axes.contains(&8) {
        run.goal_us(
            "cycle step, 8 axes: median at most 1.5 µs",
            &series_name(8, Profile::Both, true, Cache::Cold),
            "p50",
            1.5,
        );
    }
    if both && o.axes.contains(&128) {
        run.goal_us(
            "cycle step, 128 axes: p99 at most 15 µs",
            &series_name(128, Profile::Both, true, Cache::Cold),
            "p99",
            15.0,
        );
    }
    Ok((run, out))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_floor_reads_inside_the_state_only() {
        // A struct with padding: a line may start in it, and reading it is no error.
        #[allow(dead_code)]
        struct Padded(u8, u64, [u16; 40]);
        let s = Padded(1, 2, [3; 40]);
        read_lines(&s, &[0, 64, size_of::<Padded>() - 1]);
        let r = std::panic::catch_unwind(|| read_lines(&s, &[size_of::<Padded>()]));
        assert!(r.is_err(), "an offset past the state must be refused");
    }

    #[test]
    fn sizes_out_of_range_are_refused() {
        let o = StepOptions {
            axes: vec![8, 129],
            profiles: vec![Profile::Both],
            grouped: vec![true],
            caches: vec![Cache::Cold],
            seconds_per_series: 1.0,
            priority: Some(80),
        };
        assert!(o.check().unwrap_err().contains("--axes 129"));
        let p = StepOptions {
            axes: vec![8],
            priority: Some(100),
            ..o.clone()
        };
        assert!(p.check().unwrap_err().contains("--priority 100"));
        let d = StepOptions {
            axes: vec![8],
            seconds_per_series: f64::INFINITY,
            ..o.clone()
        };
        assert!(d.check().unwrap_err().contains("--duration"));
        let o = StepOptions { axes: vec![], ..o };
        assert!(o.check().is_err());
    }
}
