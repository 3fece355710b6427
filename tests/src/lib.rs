//! Helpers shared by the integration tests in `tests/tests/`: a CANopen test device, and a rig
//! that runs a master and devices on the in-process virtual bus in virtual time.

pub mod candump;
pub mod port;
pub mod stop;

use std::time::Duration;

use drivers::can::station::{self, Station, Steppable};
use drivers::can::{ClockMode, Frame, VirtualBus, VirtualBusConfig, VirtualPort};
use drivers::canopen::NodeId;
use drivers::canopen::master::{Master, Supervision};
use drivers::canopen::sdo::SdoClientConfig;
use drivers::time::Instant;

pub use drivers::canopen::example::*;
/// The test device (the example device of the drivers crate).
pub type TestDevice = ExampleDevice;
/// The test master: 8 nodes, 8 queued SDO requests of up to 4 KiB each.
pub type TestMaster = Master<8, 8, 4096>;

/// `n` as a node-ID.
pub fn node(n: u8) -> NodeId {
    NodeId::new(n).expect("valid node-ID")
}

/// A master and devices on one virtual-time bus, plus a monitor port that records every frame.
pub struct Rig {
    /// The bus.
    pub bus: VirtualBus,
    /// The master's station.
    pub master: Station<VirtualPort, Box<TestMaster>>,
    /// The devices' stations.
    pub devices: Vec<Station<VirtualPort, Box<TestDevice>>>,
    /// Every frame seen on the bus, in order, with its completion time.
    pub log: Vec<Frame>,
    monitor: VirtualPort,
}

impl Rig {
    /// A 1 Mbit/s bus with a master and one test device per node-ID in `nodes`.
    pub fn new(nodes: &[u8]) -> Rig {
        Self::with_bitrate(nodes, 1_000_000)
    }

    /// The same at another bitrate.
    pub fn with_bitrate(nodes: &[u8], bitrate: u32) -> Rig {
        let cfg = VirtualBusConfig {
            bitrate,
            clock: ClockMode::Virtual,
            ..VirtualBusConfig::default()
        };
        let bus = VirtualBus::new(cfg).expect("valid bus configuration");
        let monitor = bus.attach_monitor("monitor");
        let mut m = Box::new(TestMaster::new(SdoClientConfig::default(), true));
        for &n in nodes {
            m.add_node(node(n), Supervision::None, bus.now())
                .expect("room for the node");
        }
        let master = Station::new(bus.attach("master"), m);
        let devices = nodes
            .iter()
            .map(|&n| {
                Station::new(
                    bus.attach(&format!("node{n}")),
                    Box::new(example_device(node(n), bus.now())),
                )
            })
            .collect();
        Rig {
            bus,
            master,
            devices,
            log: Vec::new(),
            monitor,
        }
    }

    /// The current bus time.
    pub fn now(&self) -> Instant {
        self.bus.now()
    }

    /// The device with node-ID `n`.
    pub fn device(&mut self, n: u8) -> &mut TestDevice {
        let st = self
            .devices
            .iter_mut()
            .find(|s| s.endpoint.node().get() == n)
            .expect("device on the rig");
        &mut st.endpoint
    }

    fn stations(&mut self) -> Vec<&mut dyn Steppable> {
        let mut v: Vec<&mut dyn Steppable> = vec![&mut self.master];
        v.extend(self.devices.iter_mut().map(|d| d as &mut dyn Steppable));
        v
    }

    fn settle(&mut self) {
        station::settle(&mut self.stations());
        while let Ok(Some(f)) = drivers::can::Bus::try_recv(&mut self.monitor) {
            self.log.push(f);
        }
    }

    /// Runs event by event until `done` returns true (checked after each settled instant) or
    /// `limit` of bus time passes. Returns whether `done` became true.
    pub fn run_until(&mut self, limit: Duration, mut done: impl FnMut(&mut Rig) -> bool) -> bool {
        let until = self.now() + limit;
        loop {
            self.settle();
            if done(self) {
                return true;
            }
            if self.now() >= until {
                return false;
            }
            let bus = self.bus.clone();
            let next = station::next_event(&bus, &self.stations(), until);
            bus.advance_to(next);
        }
    }

    /// Runs for `d` of bus time.
    pub fn run_for(&mut self, d: Duration) {
        self.run_until(d, |_| false);
    }

    /// Frames of the log with COB-ID `id`, from index `from` on.
    pub fn frames_with_id(&self, id: u16, from: usize) -> Vec<Frame> {
        self.log[from..]
            .iter()
            .filter(|f| f.cob_id() == Some(id))
            .copied()
            .collect()
    }
}

/// A frame from `cansend` text, for expectations.
pub fn frame(s: &str) -> Frame {
    s.parse().expect("valid frame text")
}

/// A binary of the workspace (`cargo build -p PACKAGE --bin NAME`, next to the test binary),
/// built once per test process: a no-op when it is fresh, and never a stale binary left by an
/// earlier build when only this test crate was rebuilt.
pub fn workspace_bin(package: &str, name: &str) -> std::path::PathBuf {
    use std::collections::HashSet;
    use std::sync::Mutex;
    static BUILT: Mutex<Option<HashSet<String>>> = Mutex::new(None);
    let exe = std::env::current_exe().expect("the test binary's path");
    // target/<profile>/deps/this-test → target/<profile>/<name>
    let dir = exe
        .parent()
        .and_then(|d| d.parent())
        .expect("the test binary sits in target/<profile>/deps")
        .to_path_buf();
    let mut built = BUILT.lock().unwrap_or_else(|e| e.into_inner());
    if built
        .get_or_insert_with(HashSet::new)
        .insert(name.to_string())
    {
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let release = dir.file_name().is_some_and(|d| d == "release");
        let mut cmd = std::process::Command::new(cargo);
        cmd.args(["build", "-q", "-p", package, "--bin", name]);
        if release {
            cmd.arg("--release");
        }
        let ok = cmd.status().expect("cargo runs");
        assert!(ok.success(), "building {name}");
    }
    dir.join(name)
}

/// A test that needs something outside Rust (QEMU, a Python package) and found it missing:
/// fails when `MOTION_REQUIRE_ALL=1` (as `.ci/run` sets it, having installed everything),
/// otherwise prints `SKIPPED test: why` straight to stderr (the harness captures
/// `eprintln!` of a passing test) and the caller returns.
pub fn skip_or_fail(test: &str, why: &str) {
    assert!(
        std::env::var("MOTION_REQUIRE_ALL").as_deref() != Ok("1"),
        "{test}: {why}, and MOTION_REQUIRE_ALL=1"
    );
    use std::io::Write as _;
    let _ = writeln!(std::io::stderr(), "SKIPPED {test}: {why}");
}

/// The repository's root (the folder above this crate's).
pub fn repo_root() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ is in the workspace")
        .to_path_buf()
}

/// How a process run by [`run_to_end`] ended.
pub struct Ended {
    /// Its exit status; `None` when it ran past the limit and was killed.
    pub status: Option<std::process::ExitStatus>,
    /// Everything it wrote to standard output.
    pub stdout: String,
    /// Everything it wrote to standard error.
    pub stderr: String,
}

impl Ended {
    /// Its exit code; `None` when it was killed (by the limit or a signal).
    pub fn code(&self) -> Option<i32> {
        self.status.and_then(|s| s.code())
    }
}

/// Runs `cmd` with no input and both outputs collected, killing it if it runs longer than
/// `limit`: a hung process fails its test with the output it wrote instead of hanging the suite.
pub fn run_to_end(cmd: &mut std::process::Command, limit: Duration) -> Ended {
    use std::process::Stdio;
    let mut child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("starting {:?}: {e}", cmd.get_program()));
    // Both pipes are drained while it runs, so a talkative process never blocks on a full pipe.
    let drain = |mut r: Box<dyn std::io::Read + Send>| {
        std::thread::spawn(move || {
            let mut s = String::new();
            let _ = r.read_to_string(&mut s);
            s
        })
    };
    let out = drain(Box::new(child.stdout.take().expect("piped")));
    let err = drain(Box::new(child.stderr.take().expect("piped")));
    let start = std::time::Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().expect("waiting for the child") {
            break Some(s);
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    Ended {
        status,
        stdout: out.join().unwrap_or_default(),
        stderr: err.join().unwrap_or_default(),
    }
}
