//! cyclictest (rt-tests), the baseline of `timing cycle`: finding it, running one window of
//! it with the settings our thread obtained, and reading its per-sample output.
//!
//! Each window runs `cyclictest -q [-m] -p PRIO -i PERIOD -l LOOPS [-a CPU] -v -N
//! --default-system`: `-v -N` prints every wake-up's lateness in ns, in order (cyclictest's own
//! histogram, `-h`, counts whole microseconds and drops `-N`'s nanoseconds into its overflow),
//! and `--default-system` leaves power management as it is (cyclictest otherwise holds
//! `/dev/cpu_dma_latency` at 0 while it runs, which the coordinator does not do, so it would
//! measure a differently tuned machine in its windows).

use std::path::{Path, PathBuf};
use std::process::Command;

/// cyclictest's verbose mode keeps this many samples per thread before it wraps; a window holds
/// fewer.
pub const MAX_LOOPS: u64 = 16_000;

/// The `cyclictest` on PATH, if any.
pub fn find() -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|d| d.join("cyclictest"))
        .find(|p| p.is_file())
}

/// What one window asks cyclictest for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WindowSettings {
    /// SCHED_FIFO priority; none: the normal scheduler (`-p 0`).
    pub priority: Option<i32>,
    /// Period, µs.
    pub period_us: u64,
    /// Wake-ups.
    pub loops: u64,
    /// CPU to pin to.
    pub cpu: Option<usize>,
    /// `-m`: lock memory.
    pub lock_memory: bool,
}

impl WindowSettings {
    /// The arguments, after `cyclictest`.
    pub fn args(&self) -> Vec<String> {
        let mut a = vec!["-q".to_string()];
        if self.lock_memory {
            a.push("-m".into());
        }
        a.extend([
            "-p".into(),
            self.priority.unwrap_or(0).to_string(),
            "-i".into(),
            self.period_us.to_string(),
            "-l".into(),
            self.loops.to_string(),
        ]);
        if let Some(c) = self.cpu {
            a.extend(["-a".into(), c.to_string()]);
        }
        a.extend(["-v".into(), "-N".into(), "--default-system".into()]);
        a
    }

    /// The command line as a user would type it.
    pub fn command_line(&self) -> String {
        format!("cyclictest {}", self.args().join(" "))
    }
}

/// Runs one window; returns every wake-up's lateness, ns, in order. An error says what
/// cyclictest said (its last line on standard error) or how its output fell short.
pub fn run_window(exe: &Path, w: &WindowSettings) -> Result<Vec<u64>, String> {
    let out = Command::new(exe)
        .args(w.args())
        .output()
        .map_err(|e| format!("cannot start {}: {e}", exe.display()))?;
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    if !out.status.success() {
        let last = stderr
            .lines()
            .chain(stdout.lines())
            .rfind(|l| !l.trim().is_empty())
            .unwrap_or("no message");
        return Err(format!(
            "`{}` failed ({}): {last}",
            w.command_line(),
            out.status
        ));
    }
    let v = parse_verbose(&stdout);
    if v.len() as u64 != w.loops {
        return Err(format!(
            "`{}` printed {} samples, {} expected",
            w.command_line(),
            v.len(),
            w.loops
        ));
    }
    Ok(v)
}

/// The samples of cyclictest's `-v` output (`thread: cycle: value` lines, value in ns with
/// `-N`) of thread 0, in cycle order; other lines are ignored.
pub fn parse_verbose(text: &str) -> Vec<u64> {
    let mut v: Vec<(u64, u64)> = text
        .lines()
        .filter_map(|l| {
            let mut f = l.split(':').map(str::trim);
            let (t, c, x) = (f.next()?, f.next()?, f.next()?);
            if f.next().is_some() || t != "0" {
                return None;
            }
            Some((c.parse().ok()?, x.parse().ok()?))
        })
        .collect();
    v.sort_by_key(|&(c, _)| c);
    v.dedup_by_key(|&mut (c, _)| c);
    v.into_iter().map(|(_, x)| x).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_verbose_output_is_read() {
        let text = "Max CPUs = 2\n# /dev/cpu_dma_latency set to 0us\nThread 0 Interval: 1500\n       0:       1:   14819\n       0:       0:   16202\n       0:       2:   18983\nT: 0 ( 7613) P:80 I:1000 C:   1000 Min:  12014 Act:   12891 Avg:   23722 Max: 1106609\n";
        assert_eq!(parse_verbose(text), vec![16202, 14819, 18983]);
    }

    #[test]
    fn the_command_line_has_the_settings() {
        let w = WindowSettings {
            priority: Some(80),
            period_us: 1000,
            loops: 500,
            cpu: Some(1),
            lock_memory: true,
        };
        assert_eq!(
            w.command_line(),
            "cyclictest -q -m -p 80 -i 1000 -l 500 -a 1 -v -N --default-system"
        );
        let n = WindowSettings {
            priority: None,
            cpu: None,
            lock_memory: false,
            ..w
        };
        assert_eq!(
            n.command_line(),
            "cyclictest -q -p 0 -i 1000 -l 500 -v -N --default-system"
        );
    }
}
