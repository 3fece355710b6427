//! `timing cycle`: how late the cycle thread wakes after its absolute deadline, set up exactly
//! as the coordinator sets up its cycle thread (memory locked first, then
//! [`enter_realtime`] with SCHED_FIFO, the CPU and a 1 ns timer slack, then a
//! [`Ticker`] from one period after now), beside cyclictest at the same priority and period.
//!
//! The two take turns in windows of the same run (ours, cyclictest, ours, ...), so both see the
//! same machine; cyclictest is given what our thread obtained (a refused SCHED_FIFO runs both
//! on the normal scheduler). Where cyclictest is not installed or fails, the run says so and
//! reports ours alone.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc;
use std::time::Duration;

use coordinator::runtime::realtime_thread::{
    RealtimeReport, RealtimeSettings, enter_realtime, leave_realtime,
};
use coordinator::runtime::ticker::Ticker;
use drivers::cli_number::Allowed;
use drivers::time::monotonic_now;

use crate::cyclictest::{self, WindowSettings};
use crate::machine::Granted;
use crate::progress::Progress;
use crate::report::summary::Run;
use crate::stats::Series;

/// What `timing cycle` measures with; checked by [`CycleOptions::check`].
#[derive(Debug, Clone, PartialEq)]
pub struct CycleOptions {
    /// Period, µs (50..=100 000).
    pub period_us: u64,
    /// SCHED_FIFO priority (1..=99).
    pub priority: i32,
    /// CPU to pin the thread (and cyclictest) to.
    pub cpu: Option<usize>,
    /// Length of the run, s: both sides together.
    pub duration_s: f64,
    /// Length of one window, s.
    pub window_s: f64,
}

impl Default for CycleOptions {
    fn default() -> Self {
        CycleOptions {
            period_us: 1000,
            priority: 80,
            cpu: None,
            duration_s: 10.0,
            window_s: 1.0,
        }
    }
}

impl CycleOptions {
    /// Refuses values that cannot be measured with, naming the limit.
    pub fn check(&self) -> Result<(), String> {
        if !(50..=100_000).contains(&self.period_us) {
            return Err(format!(
                "--period-us {}: the period must be 50 to 100000 µs",
                self.period_us
            ));
        }
        if !(1..=99).contains(&self.priority) {
            return Err(format!(
                "--priority {}: SCHED_FIFO priorities are 1 to 99",
                self.priority
            ));
        }
        // SAFETY: sysconf takes a constant and touches no memory of ours.
        let online = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) };
        let cpus = usize::try_from(online).unwrap_or(1).max(1);
        if let Some(c) = self.cpu
            && c >= cpus
        {
            return Err(format!(
                "--cpu {c}: this machine has CPUs 0 to {}",
                cpus - 1
            ));
        }
        Allowed::new("seconds", 0.01, 86_400.0).check_flag("--duration", self.duration_s)?;
        Allowed::new("seconds", 0.01, 3600.0).check_flag("--window-s", self.window_s)?;
        if self.loops_per_window() > cyclictest::MAX_LOOPS {
            return Err(format!(
                "--window-s {} at --period-us {} is {} periods: at most {} fit in a window (cyclictest keeps that many samples)",
                self.window_s,
                self.period_us,
                self.loops_per_window(),
                cyclictest::MAX_LOOPS
            ));
        }
        Ok(())
    }

    /// Wake-ups per window (at least 1).
    pub fn loops_per_window(&self) -> u64 {
        ((self.window_s * 1e6 / self.period_us as f64).round() as u64).max(1)
    }

    /// Windows per side: half the run each when there is a baseline, all of it otherwise.
    fn windows(&self, with_baseline: bool) -> u64 {
        let sides = if with_baseline { 2.0 } else { 1.0 };
        ((self.duration_s / (self.window_s * sides)).round() as u64).max(1)
    }
}

/// One window of ours: the wake-ups, (ns since the run's start, lateness ns), and the deadlines
/// skipped.
struct Window {
    samples: Vec<(u64, u64)>,
    skipped: u64,
}

/// Our measuring thread: set up as the coordinator's cycle thread, then one window per
/// request (`loops` wake-ups), each answered with its samples.
struct Ours {
    report: RealtimeReport,
    requests: mpsc::Sender<u64>,
    windows: mpsc::Receiver<Window>,
    done: Arc<AtomicU64>,
    thread: std::thread::JoinHandle<()>,
}

impl Ours {
    fn start(o: &CycleOptions, run_start: drivers::time::Instant) -> Result<Ours, String> {
        // As `coordinator run`: memory is locked on the main thread before the cycle thread
        // exists (mlockall populates the whole process), then the thread takes its priority.
        let memory = enter_realtime(&RealtimeSettings {
            priority: None,
            cpu: None,
            lock_memory: true,
        });
        let (req_tx, req_rx) = mpsc::channel::<u64>();
        let (win_tx, win_rx) = mpsc::channel::<Window>();
        let (rep_tx, rep_rx) = mpsc::channel::<RealtimeReport>();
        let done = Arc::new(AtomicU64::new(0));
        let counter = done.clone();
        let settings = RealtimeSettings {
            priority: Some(o.priority),
            cpu: o.cpu,
            lock_memory: false,
        };
        let period = Duration::from_micros(o.period_us);
        let thread = std::thread::Builder::new()
            .name("cycle".into())
            .spawn(move || {
                let mut report = enter_realtime(&settings);
                report.memory_locked = memory.memory_locked;
                report.warnings.splice(0..0, memory.warnings);
                let _ = rep_tx.send(report);
                // Between windows the thread waits here, off the measurement.
                while let Ok(loops) = req_rx.recv() {
                    let mut w = Window {
                        samples: Vec::with_capacity(loops as usize),
                        skipped: 0,
                    };
                    let mut ticker = Ticker::new(monotonic_now() + period, period);
                    for _ in 0..loops {
                        let tick = ticker.wait();
                        w.skipped += tick.skipped;
                        w.samples.push((
                            tick.woke.saturating_duration_since(run_start).as_nanos() as u64,
                            tick.late.as_nanos() as u64,
                        ));
                        // An atomic store, no system call: the waiting thread draws the bar.
                        counter.fetch_add(1, Ordering::Relaxed);
                    }
                    if win_tx.send(w).is_err() {
                        break;
                    }
                }
                leave_realtime();
            })
            .map_err(|e| format!("cannot start the measuring thread: {e}"))?;
        let report = rep_rx
            .recv()
            .map_err(|_| "the measuring thread ended before it was set up".to_string())?;
        Ok(Ours {
            report,
            requests: req_tx,
            windows: win_rx,
            done,
            thread,
        })
    }
}

/// Runs `timing cycle`; returns the run's summary part and its series (`ours`, and
/// `cyclictest` where it ran).
pub fn run(o: &CycleOptions) -> Result<(Run, Vec<Series>), String> {
    o.check()?;
    let exe = cyclictest::find();
    let loops = o.loops_per_window();
    let windows = o.windows(exe.is_some());
    let period_ns = o.period_us * 1000;
    let run_start = monotonic_now();
    let ours = Ours::start(o, run_start)?;
    let granted = Granted::from_report(Some(o.priority), &ours.report);
    let mut run = Run::new(
        "cycle",
        &format!(
            "wake-up lateness after the absolute deadline, period {} µs",
            o.period_us
        ),
    );
    run.notes.extend(granted.warnings.iter().cloned());
    // Said before the measurement too, so nobody waits for a figure taken without them.
    for w in &granted.warnings {
        eprintln!("note: {w}");
    }
    let baseline = WindowSettings {
        priority: granted.priority,
        period_us: o.period_us,
        loops,
        cpu: granted.cpu,
        lock_memory: granted.memory_locked,
    };
    let mut ct_state = match &exe {
        Some(p) => format!("ran ({})", p.display()),
        None => "absent".to_string(),
    };
    if exe.is_none() {
        let line = "cyclictest is not installed (rt-tests: `apt-get install rt-tests`): ours is reported alone";
        eprintln!("note: {line}");
        run.notes.push(line.into());
    }
    let mut mine = Series::new("ours");
    let mut theirs = Series::new("cyclictest");
    let mut skipped = 0u64;
    let mut ct_windows = 0u64;
    let mut ct_failed = false;
    let sides = if exe.is_some() { 2 } else { 1 };
    let total = windows * sides * loops;
    let mut progress = Progress::new("cycle", total);
    let mut base = 0u64;
    for _ in 0..windows {
        // Ours.
        let before = ours.done.load(Ordering::Relaxed);
        ours.requests
            .send(loops)
            .map_err(|_| "the measuring thread ended".to_string())?;
        let w = loop {
            match ours.windows.recv_timeout(Duration::from_millis(100)) {
                Ok(w) => break w,
                Err(mpsc::RecvTimeoutError::Timeout) => {
                    progress.set(base + ours.done.load(Ordering::Relaxed) - before)
                }
                Err(mpsc::RecvTimeoutError::Disconnected) => {
                    return Err("the measuring thread ended".into());
                }
            }
        };
        skipped += w.skipped;
        for (t, late) in w.samples {
            mine.record(t, late);
        }
        base += loops;
        progress.set(base);
        // cyclictest's window.
        if let Some(exe) = exe.as_ref().filter(|_| !ct_failed) {
            let t0 = monotonic_now();
            let start_ns = t0.saturating_duration_since(run_start).as_nanos() as u64;
            let exe = exe.clone();
            let settings = baseline.clone();
            let child = std::thread::spawn(move || cyclictest::run_window(&exe, &settings));
            while !child.is_finished() {
                std::thread::sleep(Duration::from_millis(100));
                let est =
                    monotonic_now().saturating_duration_since(t0).as_nanos() as u64 / period_ns;
                progress.set(base + est.min(loops));
            }
            match child.join() {
                Ok(Ok(v)) => {
                    for (i, late) in v.into_iter().enumerate() {
                        theirs.record(start_ns + i as u64 * period_ns, late);
                    }
                    ct_windows += 1;
                }
                Ok(Err(e)) => {
                    ct_failed = true;
                    ct_state = "failed".into();
                    progress.note(&format!("cyclictest: {e}; ours is reported alone"));
                    run.notes.push(format!("cyclictest failed: {e}"));
                }
                Err(_) => {
                    ct_failed = true;
                    ct_state = "failed".into();
                }
            }
            base += loops;
            progress.set(base);
        }
    }
    progress.finish();
    drop(ours.requests);
    let _ = ours.thread.join();
    if skipped > 0 {
        run.notes.push(if skipped == 1 {
            "1 deadline was skipped: our thread came back more than a period late".to_string()
        } else {
            format!(
                "{skipped} deadlines were skipped: our thread came back more than a period late"
            )
        });
    }
    run.set("period_us", o.period_us);
    run.set("priority_requested", o.priority);
    run.set(
        "cpu_requested",
        o.cpu.map_or(serde_json::Value::Null, |c| c.into()),
    );
    run.set("duration_s", o.duration_s);
    run.set("window_s", o.window_s);
    run.set("loops_per_window", loops);
    run.set("windows_ours", windows);
    run.set("windows_cyclictest", ct_windows);
    run.set("skipped_deadlines", skipped);
    if exe.is_some() {
        run.set("cyclictest_command", baseline.command_line());
    }
    run.baselines.insert(
        "cyclictest".into(),
        if ct_state.starts_with("ran") {
            "ran".into()
        } else {
            ct_state
        },
    );
    run.realtime = Some(granted);
    run.add(&mine, Some(windows * loops));
    let mut series = vec![mine];
    if ct_windows > 0 {
        run.add(&theirs, Some(ct_windows * loops));
        run.add_ratios("ours", "cyclictest", &["p50", "p99"]);
        run.goal_ratio(
            "wake-up lateness p99 at most 1.2 times cyclictest's, same run",
            "ours",
            "cyclictest",
            "p99",
            1.2,
        );
        series.push(theirs);
    }
    Ok((run, series))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn options_out_of_range_are_refused_in_words() {
        let ok = CycleOptions::default();
        assert!(ok.check().is_ok());
        for (bad, word) in [
            (
                CycleOptions {
                    period_us: 10,
                    ..ok.clone()
                },
                "--period-us",
            ),
            (
                CycleOptions {
                    priority: 0,
                    ..ok.clone()
                },
                "--priority",
            ),
            (
                CycleOptions {
                    duration_s: f64::NAN,
                    ..ok.clone()
                },
                "--duration",
            ),
            (
                CycleOptions {
                    window_s: -1.0,
                    ..ok.clone()
                },
                "--window-s",
            ),
            (
                CycleOptions {
                    window_s: 100.0,
                    ..ok.clone()
                },
                "at most",
            ),
            (
                CycleOptions {
                    cpu: Some(1 << 20),
                    ..ok.clone()
                },
                "--cpu",
            ),
        ] {
            let e = bad.check().unwrap_err();
            assert!(e.contains(word), "{e}");
        }
        assert_eq!(ok.loops_per_window(), 1000);
        assert_eq!(ok.windows(true), 5);
        assert_eq!(ok.windows(false), 10);
    }
}
