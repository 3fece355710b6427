//! python-can and python-canopen on the virtual bus, against drive-sim processes, as a test
//! engineer would use them: `python/motion-vbus` (the `vbus` python-can interface) under
//! `python/motion-vbus/examples/tlc5xx_canopen.py`: NMT, SDO (expedited and segmented, both
//! ways), PDO remapping read back, a CiA 402 profile-position move over PDOs and SYNC, and every
//! readable object of each simulated device read by SDO against the EDS `drive-sim --write-eds`
//! gives. Meanwhile `canbus dump` (Rust) logs the bus: every frame Python received is in its log, in
//! the same order, with the same time.
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
    fn new() -> Procs {
        let dir = std::env::temp_dir().join(format!("python-can-{}", std::process::id()));
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

#[test]
fn python_canopen_drives_a_simulated_tlc5xx_on_the_virtual_bus() {
    if let Some(why) = missing_python() {
        integration_tests::skip_or_fail(
            "python_canopen_drives_a_simulated_tlc5xx_on_the_virtual_bus",
            &why,
        );
        return;
    }
    let drive_sim = workspace_bin("coordinator", "drive-sim");
    let canbus = workspace_bin("drivers", "canbus");
    let mut p = Procs::new();
    let bus = format!("pycan{}x{}", std::process::id(), rand_suffix());
    let vbus = format!("vbus:{bus}");

    // Each device's EDS, from drive-sim itself.
    let mut eds = Vec::new();
    for kind in ["tlc5xx", "mtr-dci", "emca"] {
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
    for (kind, node) in [("tlc5xx", "5"), ("mtr-dci", "6"), ("emca", "7")] {
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
    let mut by_frame: std::collections::HashMap<&str, Vec<i64>> = Default::default();
    for (ts, f) in &rust {
        by_frame.entry(f.as_str()).or_default().push(*ts);
    }
    let (ts0, f0) = &python[0];
    let offset = ts0
        - by_frame.get(f0.as_str()).map_or_else(
            || panic!("{f0}, Python's first frame, is not in canbus dump's log"),
            |t| t[0],
        );
    for (ts, frame) in &python {
        let times = by_frame
            .get(frame.as_str())
            .map_or(&[][..], |v| v.as_slice());
        assert!(
            times.iter().any(|rts| (ts - rts - offset).abs() <= 1),
            "{frame} at {ts} µs, received by Python, is not in canbus dump's log at that time \
             (offset {offset} µs)"
        );
    }
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
