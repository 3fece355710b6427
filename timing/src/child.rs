//! A process the runs start (the coordinator, drive-sim, the bare publisher), with its output
//! kept in memory for their error messages, and its stop: SIGINT (the coordinator's safe stop,
//! the others' clean end), a grace period, then SIGKILL.
//!
//! `timing publish` and `timing loop` both use it: one way to start, watch and stop a child.

use std::io::Read as _;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How often [`Kept::stop`] and [`Kept::wait_output`] look again.
const POLL: Duration = Duration::from_millis(20);

/// A started child process: its stdout and stderr, read by two threads into one text as they
/// come; stopped with [`Kept::stop`] or, at the latest, when dropped.
pub struct Kept {
    label: String,
    child: Child,
    text: Arc<Mutex<String>>,
    readers: Vec<JoinHandle<()>>,
    /// The exit code once it ended (`None` inside: killed by a signal).
    ended: Option<Option<i32>>,
}

impl Kept {
    /// Starts `cmd` (stdin closed, stdout and stderr kept); `label` names it in messages
    /// ("the coordinator").
    pub fn spawn(label: &str, mut cmd: Command) -> Result<Kept, String> {
        use std::os::unix::process::CommandExt as _;
        // SIGINT is how [`Kept::stop`] asks a child to end. A process started from a
        // non-interactive shell's background job (`timing ... &` in a script) has SIGINT
        // ignored, and an ignored signal stays ignored across exec: a shell child can then not
        // even trap it. The child gets the default disposition, whatever this process has.
        // SAFETY: the closure runs in the forked child before exec and calls only
        // signal(2), which is async-signal-safe; it touches no memory of the parent.
        unsafe {
            cmd.pre_exec(|| {
                libc::signal(libc::SIGINT, libc::SIG_DFL);
                Ok(())
            });
        }
        let mut child = cmd
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| format!("starting {label} ({}): {e}", cmd.get_program().display()))?;
        let text = Arc::new(Mutex::new(String::new()));
        let streams: [Box<dyn std::io::Read + Send>; 2] = [
            Box::new(child.stdout.take().expect("stdout is piped")),
            Box::new(child.stderr.take().expect("stderr is piped")),
        ];
        let readers = streams
            .into_iter()
            .map(|mut r| {
                let text = text.clone();
                std::thread::spawn(move || {
                    let mut buf = [0u8; 4096];
                    while let Ok(n) = r.read(&mut buf) {
                        if n == 0 {
                            break;
                        }
                        // A poisoned lock only means a reader panicked; the text stands.
                        let mut t = text.lock().unwrap_or_else(|e| e.into_inner());
                        t.push_str(&String::from_utf8_lossy(&buf[..n]));
                    }
                })
            })
            .collect();
        Ok(Kept {
            label: label.into(),
            child,
            text,
            readers,
            ended: None,
        })
    }

    /// The name given at the start.
    pub fn label(&self) -> &str {
        &self.label
    }

    /// Everything it printed so far, stdout and stderr interleaved as read.
    pub fn output(&self) -> String {
        self.text.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Its last `n` lines so far, with a heading naming it (for an error message).
    pub fn tail(&self, n: usize) -> String {
        let text = self.output();
        let lines: Vec<&str> = text.lines().collect();
        let tail = &lines[lines.len().saturating_sub(n)..];
        let of = if tail.len() < lines.len() {
            format!(" (last {} of {} lines)", tail.len(), lines.len())
        } else {
            String::new()
        };
        format!("--- output of {}{of} ---\n{}", self.label, tail.join("\n"))
    }

    /// `error`, followed by its last [`TAIL_LINES`] lines.
    pub fn failed(&self, error: &str) -> String {
        format!("{error}\n{}", self.tail(TAIL_LINES))
    }

    /// Whether it is still running.
    pub fn alive(&mut self) -> bool {
        self.ended.is_none() && matches!(self.child.try_wait(), Ok(None))
    }

    /// Waits until it printed `text`; fails (with its output) when it ended or `within`
    /// passed.
    pub fn wait_output(&mut self, text: &str, within: Duration) -> Result<(), String> {
        let until = Instant::now() + within;
        loop {
            if self.output().contains(text) {
                return Ok(());
            }
            if !self.alive() {
                // Ended: its readers finish, then the whole text is there to look at.
                self.stop(Duration::ZERO);
                if self.output().contains(text) {
                    return Ok(());
                }
            }
            if self.ended.is_some() || Instant::now() > until {
                return Err(self.failed(&format!("{} never printed \"{text}\"", self.label)));
            }
            std::thread::sleep(POLL);
        }
    }

    /// Stops it: SIGINT, up to `grace` for it to end, then SIGKILL; returns its exit code
    /// (`None`: ended by a signal, killed). Once stopped, later calls return the same code.
    pub fn stop(&mut self, grace: Duration) -> Option<i32> {
        if let Some(code) = self.ended {
            return code;
        }
        if let Ok(None) = self.child.try_wait() {
            // SAFETY: kill(2) on our own child, not yet reaped (try_wait saw it running); no
            // memory is involved.
            unsafe {
                libc::kill(self.child.id() as libc::pid_t, libc::SIGINT);
            }
        }
        let until = Instant::now() + grace;
        let code = loop {
            match self.child.try_wait() {
                Ok(Some(s)) => break s.code(),
                Ok(None) if Instant::now() < until => std::thread::sleep(POLL),
                _ => {
                    let _ = self.child.kill();
                    break self.child.wait().ok().and_then(|s| s.code());
                }
            }
        };
        // Its pipes are closed now: the readers reach their end and the text is whole.
        for r in self.readers.drain(..) {
            let _ = r.join();
        }
        self.ended = Some(code);
        code
    }
}

/// Lines of a child's output an error message shows ([`Kept::failed`]).
pub const TAIL_LINES: usize = 30;

/// How long [`Kept`]'s drop waits after SIGINT before killing (the coordinator's safe stop
/// takes up to 6 s).
const DROP_GRACE: Duration = Duration::from_secs(10);

impl Drop for Kept {
    /// A run that failed part-way leaves no process behind.
    fn drop(&mut self) {
        self.stop(DROP_GRACE);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sh(script: &str) -> Command {
        let mut c = Command::new("sh");
        c.args(["-c", script]);
        c
    }

    #[test]
    fn output_is_kept_and_the_tail_is_named() {
        let mut k = Kept::spawn(
            "the lister",
            sh("for i in 1 2 3 4 5; do echo line $i; done; echo oops >&2"),
        )
        .unwrap();
        // Let it end by itself: a SIGINT while it still prints would end it by the signal.
        while k.alive() {
            std::thread::sleep(POLL);
        }
        assert_eq!(k.stop(Duration::from_secs(5)), Some(0));
        let out = k.output();
        assert!(out.contains("line 5") && out.contains("oops"), "{out}");
        let msg = k.failed("it went wrong");
        assert!(
            msg.starts_with("it went wrong\n--- output of the lister ---\n"),
            "{msg}"
        );
        let t = k.tail(2);
        assert!(
            t.starts_with("--- output of the lister (last 2 of 6 lines) ---\n"),
            "{t}"
        );
        assert_eq!(t.lines().count(), 3, "{t}");
    }

    #[test]
    fn sigint_stops_it_and_a_deaf_one_is_killed() {
        // A shell that ends cleanly on SIGINT (also when this test runs in a background job,
        // where SIGINT arrives ignored: `Kept::spawn` restores it for the child).
        let mut k = Kept::spawn(
            "the listener",
            sh("trap 'echo bye; exit 0' INT; echo ready; while :; do sleep 0.05; done"),
        )
        .unwrap();
        k.wait_output("ready", Duration::from_secs(10)).unwrap();
        assert!(k.alive());
        assert_eq!(k.stop(Duration::from_secs(10)), Some(0));
        assert!(!k.alive());
        assert!(k.output().contains("bye"));
        // One that ignores SIGINT is killed after the grace period: no exit code.
        let mut d = Kept::spawn(
            "the deaf one",
            sh("trap '' INT; echo ready; while :; do sleep 0.05; done"),
        )
        .unwrap();
        d.wait_output("ready", Duration::from_secs(10)).unwrap();
        assert_eq!(d.stop(Duration::from_millis(200)), None);
        assert_eq!(d.stop(Duration::from_millis(200)), None);
    }

    #[test]
    fn waiting_for_text_fails_with_the_output_when_it_ends() {
        let mut k = Kept::spawn("the quitter", sh("echo started; exit 3")).unwrap();
        let e = k.wait_output("never", Duration::from_secs(10)).unwrap_err();
        assert!(e.starts_with("the quitter never printed \"never\""), "{e}");
        assert!(e.contains("started"), "{e}");
        assert_eq!(k.stop(Duration::from_secs(1)), Some(3));
    }
}
