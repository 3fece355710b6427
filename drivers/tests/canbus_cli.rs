//! The `canbus` binary across processes on one `vbus:` bus, and its SocketCAN error.
#![cfg(all(feature = "std", feature = "socketcan", feature = "shm"))]

use drivers::can::candump::read_log;
use drivers::can::shm_bus::ShmBus;
use drivers::can::{Bus, Frame};
use drivers::time::monotonic_now;
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Output, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

const CANBUS: &str = env!("CARGO_BIN_EXE_canbus");

fn unique(tag: &str) -> String {
    static N: AtomicU32 = AtomicU32::new(0);
    format!(
        "cli-{tag}-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )
}

fn temp(name: &str) -> PathBuf {
    std::env::temp_dir().join(name)
}

/// Starts `canbus dump` and returns once it listens (it says so on stderr).
fn spawn_dump(args: &[&str]) -> Child {
    let mut child = Command::new(CANBUS)
        .arg("dump")
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stderr.as_mut().unwrap())
        .read_line(&mut line)
        .unwrap();
    assert!(line.starts_with("listening on"), "dump said: {line}");
    child
}

fn run(args: &[&str]) -> Output {
    Command::new(CANBUS).args(args).output().unwrap()
}

fn wait(mut child: Child) -> Output {
    // wait_with_output also drains the rest of stderr.
    child.stdin.take();
    child.wait_with_output().unwrap()
}

#[test]
fn dump_in_one_process_logs_what_another_sends() {
    let bus = format!("vbus:{}", unique("pair"));
    let log = temp(&format!("{}.log", unique("pair")));
    let pcap = temp(&format!("{}.pcap", unique("pair")));
    let dump = spawn_dump(&[
        &bus,
        "--count",
        "4",
        "--timeout",
        "20",
        "--log",
        log.to_str().unwrap(),
        "--pcap",
        pcap.to_str().unwrap(),
    ]);
    let sent = ["605#4000100000000000", "080#", "1F334455#DEADBEEF", "705#R"];
    let mut args = vec!["send", bus.as_str()];
    args.extend(sent);
    let out = run(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    let out = wait(dump);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let recs = read_log(BufReader::new(std::fs::File::open(&log).unwrap())).unwrap();
    let got: Vec<Frame> = recs.iter().map(|r| r.frame).collect();
    let want: Vec<Frame> = sent.iter().map(|s| s.parse().unwrap()).collect();
    assert_eq!(got, want);
    assert!(recs.iter().all(|r| r.interface == bus));
    let captured = drivers::can::pcap::read_pcap(&std::fs::read(&pcap).unwrap()).unwrap();
    assert_eq!(captured.iter().map(|(_, f)| *f).collect::<Vec<_>>(), want);
    let _ = std::fs::remove_file(&log);
    let _ = std::fs::remove_file(&pcap);
}

#[test]
fn a_sigkilled_participant_does_not_stop_the_others() {
    let name = unique("kill");
    let bus = format!("vbus:{name}");
    let log = temp(&format!("{name}.log"));
    // The survivor: dumps everything until the test stops it with SIGINT (Ctrl-C), as a user
    // would. (A fixed --timeout of 4 s once ran out on a loaded host before the last frames
    // below were sent: each process start there can take a second.)
    let survivor = spawn_dump(&[&bus, "--timeout", "120", "--log", log.to_str().unwrap()]);
    // Victim 1: a listener that never finishes. Victim 2: a sender killed mid-replay.
    let mut listener = spawn_dump(&[&bus]);
    let noise = temp(&format!("{name}-noise.log"));
    let lines: String = (0..2_000)
        .map(|i| {
            format!(
                "({}.{:06}) vbus:x 7FF#{:04X}\n",
                i / 1000,
                (i % 1000) * 1000,
                i
            )
        })
        .collect();
    std::fs::write(&noise, lines).unwrap();
    let mut sender = Command::new(CANBUS)
        .args(["replay", noise.to_str().unwrap(), &bus])
        .spawn()
        .unwrap();
    // Mid-replay (it paces 2 s of frames); long enough for a process started on a loaded
    // machine to have joined the bus and sent some.
    std::thread::sleep(Duration::from_millis(1000));
    listener.kill().unwrap(); // SIGKILL
    sender.kill().unwrap();
    listener.wait().unwrap();
    sender.wait().unwrap();

    // Another process still reaches the survivor.
    let out = run(&["send", &bus, "601#4000100000000000", "080#"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // A newcomer in this process (its open cleans up the dead nodes) is heard too, and hears.
    let mut me = ShmBus::open(&name, 1_000_000).unwrap();
    me.send(&"181#0102".parse().unwrap()).unwrap();
    // Receive while the sender lives: its frames sit in its own shared memory.
    let late_sender = Command::new(CANBUS)
        .args(["send", &bus, "182#03"])
        .spawn()
        .unwrap();
    let deadline = monotonic_now() + Duration::from_secs(3);
    let heard = loop {
        match me.recv_until(deadline).unwrap() {
            Some(f) if f.cob_id() == Some(0x182) => break Some(f),
            Some(_) => continue,
            None => break None,
        }
    };
    assert!(heard.is_some(), "the newcomer heard nothing");
    assert!(wait(late_sender).status.success());

    // Longer than the dump's reorder window (it writes a frame once it is that old).
    std::thread::sleep(Duration::from_millis(500));
    let stopped = Command::new("kill")
        .args(["-INT", &survivor.id().to_string()])
        .status()
        .unwrap();
    assert!(stopped.success(), "kill -INT the survivor");
    let out = wait(survivor);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let recs = read_log(BufReader::new(std::fs::File::open(&log).unwrap())).unwrap();
    let got: Vec<String> = recs
        .iter()
        .filter(|r| r.frame.cob_id() != Some(0x7FF))
        .map(|r| r.frame.to_string())
        .collect();
    assert_eq!(got, ["601#4000100000000000", "080#", "181#0102", "182#03"]);
    // The killed replay did get frames out before it died.
    assert!(recs.iter().any(|r| r.frame.cob_id() == Some(0x7FF)));
    let _ = std::fs::remove_file(&log);
    let _ = std::fs::remove_file(&noise);
}

#[test]
fn replay_keeps_relative_timing() {
    let name = unique("replay");
    let log = temp(&format!("{name}.log"));
    std::fs::write(
        &log,
        "(100.000000) can0 080#\n(100.100000) can0 181#01\n(100.300000) can0 182#02\n",
    )
    .unwrap();
    let mut rx = ShmBus::open(&name, 1_000_000).unwrap();
    let spawned = monotonic_now();
    let replay = Command::new(CANBUS)
        .args([
            "replay",
            log.to_str().unwrap(),
            &format!("vbus:{name}"),
            "--speed",
            "2",
        ])
        .spawn()
        .unwrap();
    let mut got = Vec::new();
    while let Some(f) = rx
        .recv_until(monotonic_now() + Duration::from_secs(2))
        .unwrap()
    {
        got.push(f);
        if got.len() == 3 {
            break;
        }
    }
    assert!(wait(replay).status.success());
    let ids: Vec<_> = got.iter().map(|f| f.cob_id().unwrap()).collect();
    assert_eq!(ids, [0x080, 0x181, 0x182]);
    // At speed 2 the log offsets 100 ms and 300 ms become 50 ms and 150 ms after the replay
    // started (which is after `spawned`); never earlier.
    assert!(got[1].timestamp() >= spawned + Duration::from_millis(50));
    assert!(got[2].timestamp() >= spawned + Duration::from_millis(150));
    // And faster than the log's own 300 ms (generous: a 130 ms scheduling delay would fail).
    assert!(got[2].timestamp() - got[0].timestamp() < Duration::from_millis(280));
    let _ = std::fs::remove_file(&log);
}

#[test]
fn socketcan_failure_is_clear_and_suggests_vbus() {
    let out = run(&["send", "vcan0", "123#00", "--linger", "0"]);
    if out.status.success() {
        return; // a machine with vcan0
    }
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("vcan0"), "{err}");
    assert!(err.contains("vbus:NAME"), "{err}");
    if drivers::can::socketcan::probe_kernel_can().is_err() {
        assert!(err.contains("lacks CAN/vcan support"), "{err}");
    }
    // Bad frame text is a clear error too, before any bus is touched.
    let out = run(&["send", "vbus:unused", "12#00"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("`12#00`"));
}
