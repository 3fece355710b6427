//! Other processes busy on the CPUs when a run starts.
//!
//! On a machine with few CPUs one forgotten busy process (a profiler left running, a build)
//! slows every figure and makes two runs disagree, and the load average shows it only slowly
//! and without a name. So a run samples every process's CPU time twice, [`WINDOW`] apart, and
//! names those that used at least [`THRESHOLD_PERCENT`] of a CPU in between: `summary.json`
//! keeps them and the table says so.

use serde::{Deserialize, Serialize};

/// The sampling window.
pub const WINDOW: std::time::Duration = std::time::Duration::from_millis(250);

/// A process at least this busy, % of one CPU over the window, is named.
pub const THRESHOLD_PERCENT: f64 = 20.0;

/// Processes named at most.
pub const MAX_NAMED: usize = 5;

/// A process that was busy.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BusyProcess {
    /// Process ID.
    pub pid: u32,
    /// Its name (`/proc/PID/stat`'s command, at most 15 bytes).
    pub name: String,
    /// CPU time it used over the window, % of one CPU.
    pub cpu_percent: f64,
}

/// One process's CPU time so far: pid, name, user + system time in clock ticks.
type Sample = (u32, String, u64);

/// Reads `/proc/PID/stat`'s pid, name and user + system time. The name is between the first
/// `(` and the last `)`: it may itself hold spaces and parentheses.
pub fn parse_stat(line: &str) -> Option<Sample> {
    let open = line.find('(')?;
    let close = line.rfind(')')?;
    let pid = line.get(..open)?.trim().parse().ok()?;
    let name = line.get(open + 1..close)?.to_string();
    // After the name: state (field 3) ... utime (14), stime (15).
    let mut rest = line.get(close + 1..)?.split_whitespace();
    let utime: u64 = rest.nth(11)?.parse().ok()?;
    let stime: u64 = rest.next()?.parse().ok()?;
    Some((pid, name, utime + stime))
}

/// The processes of `after` that used at least `threshold` % of a CPU since `before`, over
/// `seconds` with `ticks_per_second` clock ticks, busiest first, at most `max`; `own` (this
/// process) left out.
pub fn busy_between(
    before: &[Sample],
    after: &[Sample],
    seconds: f64,
    ticks_per_second: f64,
    threshold: f64,
    own: u32,
    max: usize,
) -> Vec<BusyProcess> {
    if !(seconds > 0.0 && ticks_per_second > 0.0) {
        return Vec::new();
    }
    let mut busy: Vec<BusyProcess> = after
        .iter()
        .filter(|(pid, _, _)| *pid != own)
        .filter_map(|(pid, name, t)| {
            let (_, _, t0) = before.iter().find(|(p, n, _)| p == pid && n == name)?;
            let percent = t.saturating_sub(*t0) as f64 / ticks_per_second / seconds * 100.0;
            (percent >= threshold).then(|| BusyProcess {
                pid: *pid,
                name: name.clone(),
                cpu_percent: percent,
            })
        })
        .collect();
    busy.sort_by(|a, b| b.cpu_percent.total_cmp(&a.cpu_percent));
    busy.truncate(max);
    busy
}

/// Every process's CPU time now (empty where `/proc` cannot be read).
fn sample() -> Vec<Sample> {
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    dir.filter_map(Result::ok)
        .filter(|e| {
            e.file_name()
                .to_string_lossy()
                .bytes()
                .all(|b| b.is_ascii_digit())
        })
        .filter_map(|e| std::fs::read_to_string(e.path().join("stat")).ok())
        .filter_map(|s| parse_stat(&s))
        .collect()
}

/// The other processes that used at least `threshold` % of a CPU over the next `window`,
/// busiest first, at most `max`.
pub fn busy_processes(window: std::time::Duration, threshold: f64, max: usize) -> Vec<BusyProcess> {
    // SAFETY: sysconf reads a constant of the system; no memory is passed.
    let ticks = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    let ticks = if ticks > 0 { ticks as f64 } else { 100.0 };
    let before = sample();
    let t0 = std::time::Instant::now();
    std::thread::sleep(window);
    let after = sample();
    let seconds = t0.elapsed().as_secs_f64();
    busy_between(
        &before,
        &after,
        seconds,
        ticks,
        threshold,
        std::process::id(),
        max,
    )
}

/// One line for a reader, or `None` when nothing was busy.
pub fn describe(busy: &[BusyProcess]) -> Option<String> {
    if busy.is_empty() {
        return None;
    }
    let named: Vec<String> = busy
        .iter()
        .map(|b| format!("{} (pid {}) {:.0} %", b.name, b.pid, b.cpu_percent))
        .collect();
    Some(format!(
        "busy before the run (% of one CPU): {}. The figures are slower and noisier beside them: \
         stop them, or compare only with runs made beside them",
        named.join(", ")
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stat_lines_with_odd_names_are_read() {
        let line = "4242 (my (odd) prog) R 1 2 3 4 5 6 7 8 9 10 150 25 0 0 20 0 1 0";
        assert_eq!(
            parse_stat(line),
            Some((4242, "my (odd) prog".to_string(), 175))
        );
        assert_eq!(parse_stat("garbage"), None);
        assert_eq!(parse_stat("12 (x) R 1 2"), None);
    }

    #[test]
    fn only_the_busy_others_are_named_busiest_first() {
        let before = vec![
            (1, "idle".to_string(), 100),
            (2, "valgrind".to_string(), 1000),
            (3, "cargo".to_string(), 50),
            (9, "timing".to_string(), 0),
        ];
        let after = vec![
            (1, "idle".to_string(), 101),
            (2, "valgrind".to_string(), 1025),
            (3, "cargo".to_string(), 60),
            (9, "timing".to_string(), 25),
            // Started within the window: no first sample, not judged.
            (4, "new".to_string(), 20),
        ];
        let b = busy_between(&before, &after, 0.25, 100.0, 20.0, 9, MAX_NAMED);
        let names: Vec<&str> = b.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(names, ["valgrind", "cargo"]);
        assert!((b[0].cpu_percent - 100.0).abs() < 1e-9);
        assert!((b[1].cpu_percent - 40.0).abs() < 1e-9);
        let text = describe(&b).unwrap_or_default();
        assert!(text.contains("valgrind (pid 2) 100 %"), "{text}");
        assert_eq!(describe(&[]), None);
        // A pid reused by another program within the window is not compared with the old one.
        let reused = vec![(2, "other".to_string(), 5000)];
        assert!(busy_between(&before, &reused, 0.25, 100.0, 20.0, 9, MAX_NAMED).is_empty());
        assert!(busy_between(&before, &after, 0.0, 100.0, 20.0, 9, MAX_NAMED).is_empty());
        assert_eq!(
            busy_between(&before, &after, 0.25, 100.0, 20.0, 9, 1).len(),
            1
        );
    }

    #[test]
    fn a_spinning_process_is_found() {
        let mut child = std::process::Command::new("sh")
            .args(["-c", "while :; do :; done"])
            .spawn()
            .expect("sh starts");
        let pid = child.id();
        // Started before the first sample; a low threshold, since a busy test machine may give
        // it only a share of a CPU.
        std::thread::sleep(std::time::Duration::from_millis(50));
        let busy = busy_processes(std::time::Duration::from_millis(300), 1.0, usize::MAX);
        let _ = child.kill();
        let _ = child.wait();
        assert!(
            busy.iter().any(|b| b.pid == pid),
            "the spinning shell (pid {pid}) is not among {busy:?}"
        );
    }
}
