//! python-can and python-canopen on the virtual bus, against drive-sim processes, as a test
//! engineer would use them: `python/motion-vbus` (the `vbus` python-can interface) under
//! `python/motion-vbus/examples/tlc5xx_canopen.py`: NMT, SDO (expedited and segmented, both
//! ways), PDO remapping read back, a CiA 402 profile-position move over PDOs and SYNC, and every
//! readable object of each simulated device read by SDO against the EDS `drive-sim --write-eds`
//! gives. Meanwhile `canbus dump` (Rust) logs the bus: every frame Python received is in its
//! log, in the same order, with the same time.
//!
//! A second test records a bus beside a running coordinator with python-can's own `can.Logger`
//! (`python/motion-vbus/examples/record_log.py`) and plays the log back with `canbus replay`.
//!
//! Needs python3 with python-can, python-canopen, the iceoryx2 bindings and motion-vbus
//! installed (`.ci/run` installs them); skipped with a notice otherwise, mandatory with
//! MOTION_REQUIRE_ALL=1.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use integration_tests::workspace_bin;

fn repo() -> PathBuf {
    integration_tests::repo_root()
}

/// What is missing for the test, in words; `None` when everything is there.
fn missing_python() -> Option<String> {
    let probe = "import importlib.util, sys\n\
        missing = [m for m in ('can', 'canopen', 'iceoryx2') if importlib.util.find_spec(m) is None]\n\
        if not missing:\n\
        \x20   import can.interfaces\n\
        \x20   if 'vbus' not in can.interfaces.VALID_INTERFACES: missing.append('motion-vbus')\n\
        print(' '.join(missing))\n";
    match Command::new("python3").args(["-c", probe]).output() {
        Err(e) => Some(format!("python3 cannot be started ({e})")),
        Ok(out) if !out.status.success() => Some(format!(
            "python3 fails: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        )),
        Ok(out) => {
            let names = String::from_utf8_lossy(&out.stdout).trim().to_owned();
            (!names.is_empty()).then(|| {
                let pip: Vec<&str> = names
                    .split(' ')
                    .map(|m| match m {
                        "can" => "python-can",
                        "canopen" => "canopen",
                        "iceoryx2" => "iceoryx2",
                        _ => "./python/motion-vbus",
                    })
                    .collect();
                format!(
                    "the Python packages {} are not installed (pip install {}; .ci/run installs them)",
                    pip.join(", "),
                    pip.join(" ")
                )
            })
        }
    }
}

/// The processes of the test and their output files; kills them when dropped and, when the
/// test fails, prints what each wrote.
struct Procs {
    dir: PathBuf,
    procs: Vec<(String, Child, PathBuf)>,
}

impl Procs {
    fn new(test: &str) -> Procs {
        let dir = std::env::temp_dir().join(format!(
            "python-can-{test}-{}x{}",
            std::process::id(),
            rand_suffix()
        ));
        std::fs::create_dir_all(&dir).unwrap();
        Procs {
            dir,
            procs: Vec::new(),
        }
    }

    fn spawn(&mut self, label: &str, cmd: &mut Command) -> usize {
        let log = self.dir.join(format!("{}.out", label.replace(' ', "-")));
        let out = File::create(&log).unwrap();
        let err = out.try_clone().unwrap();
        let child = cmd
            .stdin(Stdio::null())
            .stdout(out)
            .stderr(err)
            .spawn()
            .unwrap_or_else(|e| panic!("starting {label}: {e}"));
        self.procs.push((label.to_owned(), child, log));
        self.procs.len() - 1
    }

    fn output(&self, i: usize) -> String {
        std::fs::read_to_string(&self.procs[i].2).unwrap_or_default()
    }

    /// Waits for process `i` to end; its exit code.
    fn wait(&mut self, i: usize, limit: Duration) -> Option<i32> {
        let end = Instant::now() + limit;
        loop {
            if let Some(s) = self.procs[i].1.try_wait().unwrap() {
                return s.code();
            }
            assert!(
                Instant::now() < end,
                "{} did not end within {limit:?}",
                self.procs[i].0
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    fn wait_output(&self, i: usize, text: &str) {
        let end = Instant::now() + Duration::from_secs(60);
        while !self.output(i).contains(text) {
            assert!(Instant::now() < end, "{}: no {text:?}", self.procs[i].0);
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Procs {
    fn drop(&mut self) {
        for (_, c, _) in &mut self.procs {
            let _ = c.kill();
            let _ = c.wait();
        }
        if std::thread::panicking() {
            for (label, _, log) in &self.procs {
                eprintln!(
                    "--- {label}:\n{}\n---",
                    std::fs::read_to_string(log).unwrap_or_default()
                );
            }
            eprintln!("(the files are kept in {})", self.dir.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

/// A candump log line `(seconds) iface ID#DATA`: the time in µs and the frame text.
fn candump_line(line: &str) -> Option<(i64, String)> {
    let (ts, rest) = line.strip_prefix('(')?.split_once(") ")?;
    let (secs, micros) = ts.split_once('.')?;
    let us = secs.parse::<i64>().ok()? * 1_000_000 + micros.parse::<i64>().ok()?;
    let frame = rest.split_whitespace().nth(1)?.to_owned();
    Some((us, frame))
}

/// One test of this file at a time: each runs a machine of real-time processes, and two at once
/// on a small shared host starve each other's drives.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Every frame of a python-can log (`python`) is in canbus dump's log of the same bus (`rust`),
/// at the same time up to one offset: both write the sender's completion time, shifted to the
/// wall clock by an offset each process took when it opened the bus. That offset is taken from
/// Python's first frame and its nearest occurrence in the Rust log (SYNCs and the like repeat;
/// the processes' offsets differ by far less than a cycle). Each time may differ from it by
/// 2 µs: the two offsets differ by a fraction of a microsecond, Rust truncates to the
/// microsecond and python-can rounds its float seconds. python-can also never writes a time
/// below the one before (`CanutilsLogWriter` gives such a frame the previous time), and frames
/// of different processes may arrive out of timestamp order: a frame with the same time as the
/// line before may lie up to the bus's reorder window (60 ms at 1 Mbit/s) earlier.
fn assert_python_frames_in_rust_log(python: &[(i64, String)], rust: &[(i64, String)]) {
    const CLAMPED_US: i64 = 60_000;
    let mut by_frame: std::collections::HashMap<&str, Vec<i64>> = Default::default();
    for (ts, f) in rust {
        by_frame.entry(f.as_str()).or_default().push(*ts);
    }
    let times = |f: &str| by_frame.get(f).map_or(&[][..], |v| v.as_slice());
    let (ts0, f0) = python.first().expect("frames in Python's log");
    let offset = times(f0)
        .iter()
        .map(|rts| ts0 - rts)
        .min_by_key(|o| o.abs())
        .unwrap_or_else(|| panic!("{f0}, Python's first frame, is not in canbus dump's log"));
    let mut previous = None;
    for (ts, frame) in python {
        let late = if previous == Some(*ts) { CLAMPED_US } else { 2 };
        assert!(
            times(frame)
                .iter()
                .any(|rts| (-2..=late).contains(&(ts - rts - offset))),
            "{frame} at {ts} µs, in Python's log, is not in canbus dump's log at that time \
             (offset {offset} µs)"
        );
        previous = Some(*ts);
    }
}

#[test]
fn python_canopen_drives_a_simulated_tlc5xx_on_the_virtual_bus() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(why) = missing_python() {
        integration_tests::skip_or_fail(
            "python_canopen_drives_a_simulated_tlc5xx_on_the_virtual_bus",
            &why,
        );
        return;
    }
    let drive_sim = workspace_bin("coordinator", "drive-sim");
    let canbus = workspace_bin("drivers", "canbus");
    let mut p = Procs::new("canopen");
    let bus = format!("pycan{}x{}", std::process::id(), rand_suffix());
    let vbus = format!("vbus:{bus}");

    // Each device's EDS, from drive-sim itself.
    let mut eds = Vec::new();
    for kind in ["tlc5xx", "mtr-dci", "emca", "cia402"] {
        let out = Command::new(&drive_sim)
            .args(["--write-eds", kind])
            .output()
            .unwrap();
        assert!(out.status.success(), "drive-sim --write-eds {kind}");
        let path = p.dir.join(format!("{kind}.eds"));
        std::fs::write(&path, &out.stdout).unwrap();
        eds.push(path);
    }
    let mut sims = Vec::new();
    for (kind, node) in [
        ("tlc5xx", "5"),
        ("mtr-dci", "6"),
        ("emca", "7"),
        ("cia402", "8"),
    ] {
        sims.push(p.spawn(
            &format!("drive-sim {kind}"),
            Command::new(&drive_sim).args([
                "--device",
                kind,
                "--bus",
                &vbus,
                "--node",
                node,
                "--status-every",
                "0",
            ]),
        ));
    }
    for &s in &sims {
        p.wait_output(s, "drive(s) running");
    }
    let rust_log = p.dir.join("rust.log");
    let dump = p.spawn(
        "canbus dump",
        Command::new(&canbus)
            .args(["dump", &vbus, "--log"])
            .arg(&rust_log),
    );
    p.wait_output(dump, "listening on");

    let py_log = p.dir.join("python.log");
    let script = repo().join("python/motion-vbus/examples/tlc5xx_canopen.py");
    // The package from this checkout first, whatever version pip installed (the entry point
    // that names the interface comes from the installed one).
    let py = p.spawn(
        "python",
        Command::new("python3")
            .arg(&script)
            .args(["--bus", &bus, "--node", "5", "--eds"])
            .arg(&eds[0])
            .args(["--check-eds", "6"])
            .arg(&eds[1])
            .args(["--check-eds", "7"])
            .arg(&eds[2])
            .args(["--check-eds", "8"])
            .arg(&eds[3])
            .arg("--log")
            .arg(&py_log)
            .env("PYTHONPATH", repo().join("python/motion-vbus")),
    );
    let code = p.wait(py, Duration::from_secs(300));
    let out = p.output(py);
    assert_eq!(code, Some(0), "the Python script failed:\n{out}");
    for line in [
        "python-canopen imported its EDS; all",
        "TLC5xx node 5: python-canopen imported its EDS",
        "MTR-DCI node 6: python-canopen imported its EDS",
        "EMCA node 7: python-canopen imported its EDS",
        "node 8: python-canopen imported its EDS",
        "NMT reset communication: boot-up seen",
        "SDO upload, segmented: 1008h device name 'TLC53x'",
        "SDO download, segmented",
        "PDO remapping",
        "target reached",
        "PASSED",
    ] {
        assert!(out.contains(line), "{line:?} in:\n{out}");
    }

    // The dump goes on a moment longer: every frame Python received is in its log.
    std::thread::sleep(Duration::from_millis(300));
    let _ = p.procs[dump].1.kill();
    let _ = p.procs[dump].1.wait();
    let read = |f: &Path| -> Vec<(i64, String)> {
        std::fs::read_to_string(f)
            .unwrap_or_default()
            .lines()
            .filter_map(candump_line)
            .collect()
    };
    let python = read(&py_log);
    let rust = read(&rust_log);
    assert!(
        python.len() > 1000,
        "{} frames in Python's log",
        python.len()
    );
    // Python's frames are the drives' (an endpoint does not receive its own); Rust's have
    // Python's too. Both carry the sender's completion time, shifted to the wall clock by an
    // offset each process took when it opened the bus: one constant difference throughout.
    // (`canbus dump` writes in timestamp order, Python in arrival order; frames of different
    // drive processes may arrive out of timestamp order, so the times are matched, not the
    // positions.)
    assert_python_frames_in_rust_log(&python, &rust);
    // Each drive's frames reach Python in the order they were sent.
    for id in ["585#", "586#", "587#", "185#"] {
        let times: Vec<i64> = python
            .iter()
            .filter(|(_, f)| f.starts_with(id))
            .map(|(t, _)| *t)
            .collect();
        assert!(
            times.windows(2).all(|w| w[0] <= w[1]),
            "{id} frames out of order"
        );
    }
}

/// A few digits that differ between runs of the same process id.
fn rand_suffix() -> u32 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos() % 100_000)
}

/// A candump log as (identifier, data) text per frame, in file order: `181#00112233`.
fn frames_of(f: &Path) -> Vec<String> {
    std::fs::read_to_string(f)
        .unwrap_or_else(|e| panic!("{}: {e}", f.display()))
        .lines()
        .filter_map(candump_line)
        .map(|(_, frame)| frame)
        .collect()
}

#[test]
fn python_can_logger_records_a_running_coordinator_and_canbus_replays_it() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let test = "python_can_logger_records_a_running_coordinator_and_canbus_replays_it";
    if let Some(why) = missing_python() {
        integration_tests::skip_or_fail(test, &why);
        return;
    }
    let coordinator = workspace_bin("coordinator", "coordinator");
    let drive_sim = workspace_bin("coordinator", "drive-sim");
    let canbus = workspace_bin("drivers", "canbus");
    let mut p = Procs::new("logger");
    let tag = format!("{}x{}", std::process::id(), rand_suffix());
    let (bus, other) = (format!("pylog{tag}"), format!("pyreplay{tag}"));
    let (vbus, vother) = (format!("vbus:{bus}"), format!("vbus:{other}"));

    // Two TLC5xx axes on one vbus bus at a 10 ms cycle (as tests/tests/real_drives.rs: a busy
    // shared host must not turn into late TPDOs).
    let limits = "limits = { position_min = 0.0, position_max = 100.0, velocity = 50.0, \
                  acceleration = 200.0 }";
    let config = p.dir.join("machine.toml");
    std::fs::write(
        &config,
        format!(
            "cycle_us = 10000\n\n\
             [[buses]]\nname = \"{bus}\"\nkind = \"vbus\"\n\n\
             [[axes]]\nname = \"a\"\ndevice = \"tlc5xx\"\nbus = \"{bus}\"\nnode = 1\n\
             increments_per_unit = 1000.0\n{limits}\n\n\
             [[axes]]\nname = \"b\"\ndevice = \"tlc5xx\"\nbus = \"{bus}\"\nnode = 2\n\
             increments_per_unit = 1000.0\n{limits}\n"
        ),
    )
    .unwrap();

    // The recorders join the bus before the machine runs (a newcomer stalls the endpoints
    // already there while it sets up its shared memory): canbus dump, and Python's can.Logger.
    let rust_log = p.dir.join("rust.log");
    let dump = p.spawn(
        "canbus dump",
        Command::new(&canbus)
            .args(["dump", &vbus, "--log"])
            .arg(&rust_log),
    );
    p.wait_output(dump, "listening on");
    let py_log = p.dir.join("python.log");
    let stop = p.dir.join("stop");
    let py = p.spawn(
        "python can.Logger",
        Command::new("python3")
            .arg(repo().join("python/motion-vbus/examples/record_log.py"))
            .args(["--bus", &bus, "--seconds", "240", "--log"])
            .arg(&py_log)
            .arg("--stop-file")
            .arg(&stop)
            .env("PYTHONPATH", repo().join("python/motion-vbus")),
    );
    p.wait_output(py, &format!("recording {vbus}"));

    let sim = p.spawn(
        "drive-sim",
        Command::new(&drive_sim)
            .arg("--config")
            .arg(&config)
            .args(["--status-every", "5"]),
    );
    p.wait_output(sim, "drive(s) running");
    let coord = p.spawn(
        "coordinator",
        Command::new(&coordinator)
            .arg("run")
            .arg("--config")
            .arg(&config)
            .args(["--quiet", "--shm-prefix", &format!("t-pylog-{tag}-")]),
    );
    p.wait_output(coord, "drive ready: node 1 (TLC5xx \"a\")");
    p.wait_output(coord, "drive ready: node 2 (TLC5xx \"b\")");
    // Both drives operational: a while of SYNC and PDO cycles, then the recording ends.
    std::thread::sleep(Duration::from_secs(3));
    std::fs::write(&stop, "").unwrap();
    let code = p.wait(py, Duration::from_secs(60));
    assert_eq!(code, Some(0), "the recording script failed");
    // The dump goes on a moment longer, so that it holds every frame Python got.
    std::thread::sleep(Duration::from_millis(300));
    let _ = p.procs[dump].1.kill();
    let _ = p.procs[dump].1.wait();

    let recorded = frames_of(&py_log);
    let count = |id: &str| recorded.iter().filter(|f| f.starts_with(id)).count();
    // SYNC, the coordinator's RPDO1 to each drive and each drive's TPDO1: the cycle ran while
    // Python recorded (3 s at 10 ms are about 300 cycles; a starved host still makes 50).
    for id in ["080#", "201#", "202#", "181#", "182#"] {
        assert!(count(id) >= 50, "{} {id} frames in Python's log", count(id));
    }
    let out = p.output(py);
    assert!(
        out.contains(&format!("{} frames recorded", recorded.len())),
        "the script counted what the log holds ({} lines):\n{out}",
        recorded.len()
    );

    // Every frame of Python's log is in canbus dump's log of the same bus, at the same time.
    let py_timed: Vec<(i64, String)> = std::fs::read_to_string(&py_log)
        .unwrap()
        .lines()
        .filter_map(candump_line)
        .collect();
    let rust_timed: Vec<(i64, String)> = std::fs::read_to_string(&rust_log)
        .unwrap()
        .lines()
        .filter_map(candump_line)
        .collect();
    assert_python_frames_in_rust_log(&py_timed, &rust_timed);

    // The log read back: canbus replay sends it on another bus, where canbus dump logs the
    // same frames in the same order.
    let replayed_log = p.dir.join("replayed.log");
    let dump2 = p.spawn(
        "canbus dump (replay)",
        Command::new(&canbus)
            .args(["dump", &vother, "--log"])
            .arg(&replayed_log)
            .args(["--count", &recorded.len().to_string(), "--timeout", "120"]),
    );
    p.wait_output(dump2, "listening on");
    let replay = p.spawn(
        "canbus replay",
        Command::new(&canbus)
            .arg("replay")
            .arg(&py_log)
            .args([&vother, "--speed", "4"]),
    );
    assert_eq!(
        p.wait(replay, Duration::from_secs(120)),
        Some(0),
        "canbus replay read python-can's log and sent it"
    );
    assert_eq!(
        p.wait(dump2, Duration::from_secs(120)),
        Some(0),
        "canbus dump got every replayed frame"
    );
    let replayed = frames_of(&replayed_log);
    assert_eq!(replayed.len(), recorded.len(), "frames replayed");
    for (i, (r, o)) in replayed.iter().zip(&recorded).enumerate() {
        assert_eq!(r, o, "frame {i} of the replay");
    }
}
