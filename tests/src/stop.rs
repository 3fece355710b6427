//! Stopping a failing test's processes as a user would, so that what they print on the way
//! out (drive-sim's counters and longest pause, the coordinator's summary) is in the output
//! the test shows.
//!
//! This file is used by `integration-tests` (as `stop`) and by the coordinator's own process
//! tests (by path), so both stop their processes the same way.

use std::process::Child;
use std::time::{Duration, Instant};

/// Sends SIGTERM to each of `children` still running and waits up to `grace` for all of them
/// to end. A child already reaped is left alone: its pid may belong to another process now.
/// Whatever still runs afterwards is the caller's to kill.
pub fn ask_to_stop<'a>(children: impl IntoIterator<Item = &'a mut Child>, grace: Duration) {
    let mut running: Vec<&mut Child> = children
        .into_iter()
        .filter_map(|c| matches!(c.try_wait(), Ok(None)).then_some(c))
        .collect();
    for c in &running {
        // SAFETY: kill(2) on our own child's pid, not yet reaped; no memory is involved.
        unsafe { libc::kill(c.id() as libc::pid_t, libc::SIGTERM) };
    }
    let end = Instant::now() + grace;
    while Instant::now() < end {
        running.retain_mut(|c| matches!(c.try_wait(), Ok(None)));
        if running.is_empty() {
            return;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}
