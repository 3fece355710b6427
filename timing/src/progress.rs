//! How far a run is: an indicatif bar when standard error is a terminal, plain lines at every
//! tenth otherwise (CI logs, tests, pipes), so a log shows the run went on without a wall of
//! redraws.
//!
//! The measuring thread never draws: it counts in an atomic, and the thread that waits for it
//! calls [`Progress::set`]. Drawing is a write to the terminal, a syscall the real-time thread
//! must not make.

use std::io::IsTerminal;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};

/// A progress display for one part of a run, counted in units of the caller's choosing
/// (periods, samples) and shown in percent.
#[derive(Debug)]
pub struct Progress {
    label: String,
    total: u64,
    bar: Option<ProgressBar>,
    /// The last tenth a plain line was printed for.
    tenth: u64,
}

impl Progress {
    /// A display for `label`, `total` units.
    pub fn new(label: &str, total: u64) -> Progress {
        let bar = std::io::stderr().is_terminal().then(|| {
            let b = ProgressBar::new(total);
            // A fixed template: creating the style cannot fail.
            if let Ok(style) = ProgressStyle::with_template(
                "{prefix:>12} [{bar:40}] {percent:>3} % ({elapsed}, {eta} left)",
            ) {
                b.set_style(style.progress_chars("=> "));
            }
            b.set_prefix(label.to_string());
            b.enable_steady_tick(Duration::from_millis(200));
            b
        });
        if bar.is_none() {
            eprintln!("{label}: 0 %");
        }
        Progress {
            label: label.to_string(),
            total: total.max(1),
            bar,
            tenth: 0,
        }
    }

    /// `done` units of the total are done.
    pub fn set(&mut self, done: u64) {
        let done = done.min(self.total);
        match &self.bar {
            Some(b) => b.set_position(done),
            None => {
                let tenth = done * 10 / self.total;
                if tenth > self.tenth {
                    self.tenth = tenth;
                    eprintln!("{}: {} %", self.label, tenth * 10);
                }
            }
        }
    }

    /// A line for the reader that does not break the bar.
    pub fn note(&self, line: &str) {
        match &self.bar {
            Some(b) => b.println(line),
            None => eprintln!("{line}"),
        }
    }

    /// Done: the bar is cleared (the table follows).
    pub fn finish(self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}
