//! The machine a run measured: CPU, kernel, preemption model, load average, how the binary was
//! built, and which real-time settings the run was granted. Written into `summary.json` beside
//! the figures, since a latency figure means little without them.

use serde::{Deserialize, Serialize};

use coordinator::runtime::realtime_thread::RealtimeReport;

use crate::busy::{self, BusyProcess};

/// What the machine is.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Machine {
    /// The CPU model (`/proc/cpuinfo`), or `unknown`.
    pub cpu: String,
    /// CPUs this process may use.
    pub cpus: usize,
    /// Kernel release (`uname -r`).
    pub kernel: String,
    /// Kernel version string (`uname -v`).
    pub kernel_version: String,
    /// Preemption model: `PREEMPT_RT`, `PREEMPT_DYNAMIC (full)`, `PREEMPT`, `voluntary or none`.
    pub preemption: String,
    /// Load average over 1, 5, 15 minutes when the run started.
    pub load_before: [f64; 3],
    /// Load average when the run ended.
    pub load_after: [f64; 3],
    /// Other processes that used at least [`crate::busy::THRESHOLD_PERCENT`] of a CPU just
    /// before the run (empty in folders written before this was kept).
    #[serde(default)]
    pub busy_before: Vec<BusyProcess>,
    /// How the measuring binary was built: `debug`, `release`, or `release, trained on typical
    /// runs (scripts/pgo-build)` (empty in folders written before this was kept): the
    /// simulation's figures differ by a quarter between the last two.
    #[serde(default)]
    pub build: String,
}

impl Machine {
    /// Reads the machine as it is now (the load average after the run is set by
    /// [`Machine::finish`]).
    pub fn read() -> Machine {
        let (kernel, kernel_version) = uname();
        let load = load_average();
        Machine {
            cpu: cpu_model(),
            cpus: std::thread::available_parallelism().map_or(1, |n| n.get()),
            preemption: preemption(&kernel_version),
            kernel,
            kernel_version,
            load_before: load,
            load_after: load,
            busy_before: busy::busy_processes(
                busy::WINDOW,
                busy::THRESHOLD_PERCENT,
                busy::MAX_NAMED,
            ),
            build: build_kind().to_owned(),
        }
    }

    /// Notes the load average at the end of the run.
    pub fn finish(&mut self) {
        self.load_after = load_average();
    }

    /// Two lines for a reader: CPU and kernel; load (and a third naming the processes that
    /// were busy before the run, if any were).
    pub fn describe(&self) -> String {
        let busy = busy::describe(&self.busy_before)
            .map(|b| format!("\n{b}"))
            .unwrap_or_default();
        let build = if self.build.is_empty() {
            String::new()
        } else {
            format!("; build: {}", self.build)
        };
        format!(
            "machine: {} ({} CPUs), kernel {} ({}), preemption {}{build}\nload average: {:.2} {:.2} {:.2} at the start, {:.2} {:.2} {:.2} at the end{busy}",
            self.cpu,
            self.cpus,
            self.kernel,
            self.kernel_version,
            self.preemption,
            self.load_before[0],
            self.load_before[1],
            self.load_before[2],
            self.load_after[0],
            self.load_after[1],
            self.load_after[2],
        )
    }
}

/// How this binary was built. `scripts/pgo-build` sets `MOTION_PGO` for its optimised build.
fn build_kind() -> &'static str {
    match (cfg!(debug_assertions), option_env!("MOTION_PGO").is_some()) {
        (true, _) => "debug",
        (false, false) => "release",
        (false, true) => "release, trained on typical runs (scripts/pgo-build)",
    }
}

/// The real-time settings a measuring thread asked for and what it obtained
/// (from [`coordinator::runtime::realtime_thread::enter_realtime`]'s report).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Granted {
    /// SCHED_FIFO priority asked for (none: the normal scheduler).
    pub priority_requested: Option<i32>,
    /// SCHED_FIFO priority in force (none: refused or not asked).
    pub priority: Option<i32>,
    /// Memory locked with `mlockall`.
    pub memory_locked: bool,
    /// CPU pinned to.
    pub cpu: Option<usize>,
    /// Timer slack in force, ns.
    pub timer_slack_ns: Option<u64>,
    /// What was refused, with the remedy, one sentence each.
    pub warnings: Vec<String>,
}

impl Granted {
    /// From what was asked and the report of what was obtained.
    pub fn from_report(priority_requested: Option<i32>, r: &RealtimeReport) -> Granted {
        Granted {
            priority_requested,
            priority: r.fifo_priority,
            memory_locked: r.memory_locked,
            cpu: r.cpu,
            timer_slack_ns: r.timer_slack_ns,
            warnings: r.warnings.clone(),
        }
    }

    /// One line: what the thread runs with.
    pub fn describe(&self) -> String {
        format!(
            "scheduler {}, memory {}, CPU {}, timer slack {}",
            match self.priority {
                Some(p) => format!("SCHED_FIFO {p}"),
                None => "normal (SCHED_OTHER)".into(),
            },
            if self.memory_locked {
                "locked"
            } else {
                "not locked"
            },
            self.cpu.map_or("any".into(), |c| c.to_string()),
            self.timer_slack_ns
                .map_or("unknown".into(), |s| format!("{s} ns")),
        )
    }
}

fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, v)| v.trim().to_string())
        })
        .unwrap_or_else(|| "unknown".into())
}

fn field(b: &[libc::c_char]) -> String {
    let bytes: Vec<u8> = b
        .iter()
        .take_while(|&&c| c != 0)
        .map(|&c| c as u8)
        .collect();
    String::from_utf8_lossy(&bytes).into_owned()
}

/// `uname -r` and `uname -v`.
fn uname() -> (String, String) {
    // SAFETY: utsname is plain bytes; all-zero is valid.
    let mut u: libc::utsname = unsafe { std::mem::zeroed() };
    // SAFETY: uname fills the valid, exclusively borrowed `u`.
    if unsafe { libc::uname(&mut u) } != 0 {
        return ("unknown".into(), "unknown".into());
    }
    (field(&u.release), field(&u.version))
}

/// The preemption model: `/sys/kernel/realtime` says PREEMPT_RT; otherwise the dynamic mode
/// where debugfs shows it, else the words of `uname -v`.
fn preemption(version: &str) -> String {
    if std::fs::read_to_string("/sys/kernel/realtime").is_ok_and(|s| s.trim() == "1") {
        return "PREEMPT_RT".into();
    }
    let words: Vec<&str> = version.split_whitespace().collect();
    if words.contains(&"PREEMPT_RT") {
        return "PREEMPT_RT".into();
    }
    if words.contains(&"PREEMPT_DYNAMIC") {
        // "none voluntary (full)": the mode in force is in parentheses (debugfs, root only).
        let mode = std::fs::read_to_string("/sys/kernel/debug/sched/preempt")
            .ok()
            .and_then(|s| {
                s.split_whitespace()
                    .find(|w| w.starts_with('('))
                    .map(|w| w.trim_matches(['(', ')']).to_string())
            });
        return match mode {
            Some(m) => format!("PREEMPT_DYNAMIC ({m})"),
            None => "PREEMPT_DYNAMIC".into(),
        };
    }
    if words.contains(&"PREEMPT") {
        return "PREEMPT".into();
    }
    "voluntary or none".into()
}

/// The load average over 1, 5 and 15 minutes (zeros where it cannot be read).
pub fn load_average() -> [f64; 3] {
    let mut out = [0.0; 3];
    if let Ok(s) = std::fs::read_to_string("/proc/loadavg") {
        for (o, w) in out.iter_mut().zip(s.split_whitespace()) {
            *o = w.parse().unwrap_or(0.0);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_machine_is_described() {
        let m = Machine::read();
        assert!(m.cpus >= 1);
        assert!(!m.kernel.is_empty());
        let d = m.describe();
        assert!(d.contains("kernel") && d.contains("load average"), "{d}");
        assert!(!d.contains("Some("), "{d}");
    }

    #[test]
    fn preemption_from_uname() {
        // Skipped where the running kernel is PREEMPT_RT: /sys/kernel/realtime wins.
        if std::fs::read_to_string("/sys/kernel/realtime").is_ok_and(|s| s.trim() == "1") {
            return;
        }
        assert!(preemption("#1 SMP PREEMPT_DYNAMIC @0").starts_with("PREEMPT_DYNAMIC"));
        assert_eq!(preemption("#1 SMP PREEMPT_RT Thu"), "PREEMPT_RT");
        assert_eq!(preemption("#1 SMP PREEMPT Thu"), "PREEMPT");
        assert_eq!(preemption("#1 SMP Thu"), "voluntary or none");
    }
}
