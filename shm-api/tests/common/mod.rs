//! Shared helpers of the shm-api integration tests: unique prefixes, the stand-in coordinator
//! as a child process, and a lock that runs the heavy tests one at a time (2 cores).

#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError, channel};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

static SERIAL: Mutex<()> = Mutex::new(());

/// Runs the calling test alone among the tests of this binary.
pub fn serial() -> MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

/// A prefix no other test or run shares.
pub fn prefix(name: &str) -> String {
    format!("test-{}-{}", name, std::process::id())
}

/// The stand-in coordinator, stopped (cleanly) or killed when dropped.
pub struct Standin {
    child: Child,
    stdin: Option<ChildStdin>,
    lines: Receiver<String>,
    running: bool,
}

impl Standin {
    /// Starts `motion-standin --prefix PREFIX --stop-on-stdin-eof ARGS` and waits for `ready`.
    pub fn spawn(prefix: &str, args: &[&str]) -> Standin {
        let mut child = Command::new(env!("CARGO_BIN_EXE_motion-standin"))
            .args(["--prefix", prefix, "--stop-on-stdin-eof"])
            .args(args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("spawning motion-standin");
        let stdout = child.stdout.take().expect("stdout piped");
        let (tx, lines) = channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        let stdin = child.stdin.take();
        let mut s = Standin {
            child,
            stdin,
            lines,
            running: true,
        };
        s.wait_line("ready", Duration::from_secs(10))
            .expect("motion-standin did not get ready");
        s
    }

    /// The next line starting with `start`, skipping others, within `timeout`.
    pub fn wait_line(&mut self, start: &str, timeout: Duration) -> Option<String> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(l) if l.starts_with(start) => return Some(l),
                Ok(_) => {}
                Err(RecvTimeoutError::Timeout | RecvTimeoutError::Disconnected) => return None,
            }
        }
    }

    /// Stops it cleanly (closes its stdin) and returns its `done …` line.
    pub fn stop(mut self) -> String {
        self.stdin = None;
        let done = self
            .wait_line("done", Duration::from_secs(10))
            .expect("motion-standin did not finish");
        let status = self.child.wait().expect("waiting for motion-standin");
        assert!(status.success(), "motion-standin failed: {status}");
        self.running = false;
        done
    }

    /// Kills it with SIGKILL (it leaves its resources behind).
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        self.running = false;
    }
}

impl Drop for Standin {
    fn drop(&mut self) {
        if self.running {
            self.stdin = None;
            let deadline = Instant::now() + Duration::from_secs(5);
            while Instant::now() < deadline {
                if let Ok(Some(_)) = self.child.try_wait() {
                    self.running = false;
                    break;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            if self.running {
                self.kill();
            }
        }
        // Whatever a killed stand-in left.
        let _ = shm_api::cleanup_dead_nodes();
    }
}

/// A `key=value` number of a `done …` line.
pub fn field(line: &str, key: &str) -> u64 {
    line.split_whitespace()
        .find_map(|kv| kv.strip_prefix(key)?.strip_prefix('='))
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no {key}= in `{line}`"))
}
