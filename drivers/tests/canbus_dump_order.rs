//! `canbus dump` beside several senders: the candump log is in timestamp order and complete.
//!
//! The dump runs as its own process; the senders are threads of this process, each with its
//! own `vbus:` endpoint, sending bursts whose modelled backlogs overlap, so frames arrive out
//! of timestamp order (a receiver in this process checks that the scenario shows the problem).
#![cfg(all(feature = "std", feature = "socketcan", feature = "shm"))]

use drivers::can::candump::read_log;
use drivers::can::shm_bus::ShmBus;
use drivers::can::{Bus, BusError, Frame};
use drivers::time::monotonic_now;
use std::io::BufReader;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Barrier, mpsc};
use std::time::Duration;

const CANBUS: &str = env!("CARGO_BIN_EXE_canbus");
/// Slow enough that a burst's modelled completion times run tens of milliseconds ahead.
const BITRATE: u32 = 125_000;
const SENDERS: u16 = 4;
/// Per sender: 60 frames of 1.08 ms at 125 kbit/s stay below the 64-frame backlog limit.
const BURST: u16 = 60;

fn unique(tag: &str) -> String {
    static N: AtomicU32 = AtomicU32::new(0);
    format!(
        "order-{tag}-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )
}

/// A child process whose stdout and stderr go to files; printed if the test fails, removed
/// afterwards. Killed if still running when dropped.
struct Proc {
    child: Child,
    stdout: PathBuf,
    stderr: PathBuf,
}

impl Proc {
    fn spawn(cmd: &mut Command, name: &str) -> Proc {
        let stdout = std::env::temp_dir().join(format!("{name}.stdout"));
        let stderr = std::env::temp_dir().join(format!("{name}.stderr"));
        let child = cmd
            .stdout(std::fs::File::create(&stdout).unwrap())
            .stderr(std::fs::File::create(&stderr).unwrap())
            .spawn()
            .unwrap();
        Proc {
            child,
            stdout,
            stderr,
        }
    }

    fn stderr(&self) -> String {
        std::fs::read_to_string(&self.stderr).unwrap_or_default()
    }

    fn interrupt(&self) {
        let pid = i32::try_from(self.child.id()).unwrap();
        // SAFETY: kill(2) on our own child's pid, which it cannot have reused: not yet waited.
        assert_eq!(unsafe { libc::kill(pid, libc::SIGINT) }, 0);
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        if std::thread::panicking() {
            eprintln!(
                "--- canbus stdout ---\n{}--- canbus stderr ---\n{}",
                std::fs::read_to_string(&self.stdout).unwrap_or_default(),
                self.stderr()
            );
        }
        let _ = std::fs::remove_file(&self.stdout);
        let _ = std::fs::remove_file(&self.stderr);
    }
}

/// A file removed when the test ends, passed or failed.
struct TempFile(PathBuf);

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

fn wait_for(what: &str, mut ready: impl FnMut() -> bool) {
    let deadline = monotonic_now() + Duration::from_secs(10);
    while !ready() {
        assert!(monotonic_now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[test]
fn dump_writes_frames_of_several_senders_in_timestamp_order() {
    let name = unique("dump");
    let bus = format!("vbus:{name}");
    let log = TempFile(std::env::temp_dir().join(format!("{name}.log")));
    let log = &log.0;
    let mut dump = Proc::spawn(
        Command::new(CANBUS)
            .args(["--bitrate", &BITRATE.to_string(), "dump", &bus, "--log"])
            .arg(log)
            .stdin(Stdio::null()),
        &name,
    );
    wait_for("the dump to listen", || {
        dump.stderr().starts_with("listening on")
    });
    // Sees what the dump sees, in arrival order.
    let mut witness = ShmBus::open(&name, BITRATE).unwrap();

    let start = Arc::new(Barrier::new(usize::from(SENDERS)));
    let (sent_tx, sent_rx) = mpsc::channel();
    let mut release = Vec::new();
    let mut threads = Vec::new();
    for s in 0..SENDERS {
        let (start, sent_tx, name) = (start.clone(), sent_tx.clone(), name.clone());
        let (release_tx, release_rx) = mpsc::channel::<()>();
        release.push(release_tx);
        threads.push(std::thread::spawn(move || {
            // Opened on this thread: an endpoint is not Send.
            let mut tx = ShmBus::open(&name, BITRATE).unwrap();
            start.wait();
            for k in 0..BURST {
                let f = Frame::new_std(0x100 + s, &k.to_be_bytes()).unwrap();
                while let Err(e) = tx.send(&f) {
                    assert_eq!(e, BusError::WouldBlock);
                    std::thread::sleep(Duration::from_micros(200));
                }
            }
            sent_tx.send(()).unwrap();
            // A frame lives in its sender's shared memory: stay until the dump has stopped.
            let _ = release_rx.recv();
        }));
    }
    for _ in 0..SENDERS {
        sent_rx.recv_timeout(Duration::from_secs(10)).unwrap();
    }
    let total = usize::from(SENDERS * BURST);

    let mut arrived = Vec::new();
    while arrived.len() < total {
        let deadline = monotonic_now() + Duration::from_secs(5);
        match witness.recv_until(deadline).unwrap() {
            Some(f) => arrived.push(f.timestamp()),
            None => panic!("the witness heard {} of {total} frames", arrived.len()),
        }
    }
    assert!(
        arrived.windows(2).any(|w| w[1] < w[0]),
        "the senders' frames arrived in timestamp order: the scenario shows nothing"
    );

    // Stop the dump while it still holds frames (the window at 125 kbit/s is about 140 ms):
    // Ctrl-C must write them too.
    wait_for("the dump's first frames", || {
        std::fs::read_to_string(log).is_ok_and(|s| !s.is_empty())
    });
    dump.interrupt();
    let status = dump.child.wait().unwrap();
    assert!(status.success(), "canbus dump exited with {status}");
    drop(release);
    for t in threads {
        t.join().unwrap();
    }

    let records = read_log(BufReader::new(std::fs::File::open(log).unwrap())).unwrap();
    for (k, w) in records.windows(2).enumerate() {
        assert!(
            w[1].timestamp >= w[0].timestamp,
            "line {}: {} after {}",
            k + 2,
            w[1].timestamp,
            w[0].timestamp
        );
    }
    // Every frame exactly once: (sender, index) pairs.
    let mut got: Vec<(u32, Vec<u8>)> = records
        .iter()
        .map(|r| (r.frame.raw_id(), r.frame.data().to_vec()))
        .collect();
    got.sort();
    let want: Vec<(u32, Vec<u8>)> = (0..SENDERS)
        .flat_map(|s| (0..BURST).map(move |k| (u32::from(0x100 + s), k.to_be_bytes().to_vec())))
        .collect();
    assert_eq!(got, want);
    // Each sender's own frames keep their order.
    for s in 0..SENDERS {
        let seq: Vec<u16> = records
            .iter()
            .filter(|r| r.frame.raw_id() == u32::from(0x100 + s))
            .map(|r| u16::from_be_bytes([r.frame.data()[0], r.frame.data()[1]]))
            .collect();
        assert!(seq.windows(2).all(|w| w[0] < w[1]), "sender {s}: {seq:?}");
    }
    assert!(
        dump.stderr().lines().all(|l| !l.contains("warning")),
        "{}",
        dump.stderr()
    );
}
