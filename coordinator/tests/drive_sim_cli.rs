//! `drive-sim` as its own process, started as a user would start it: the drives of a
//! coordinator configuration (`--config`, `--only`), drives given one by one (`--device`), and
//! the refusals. CANopen drives are asked over the shared-memory bus from this process, the
//! CMMO-ST over Modbus TCP on 127.0.0.1; the answers are the manuals' bytes.
//!
//! Every process is killed when its test ends, however it ends, and its output is printed when
//! the test failed. Bus names, ports and files are unique per test (pid and a counter).

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant as WallInstant};

use coordinator::axis::{
    AxisState, Demand, DeviceKind as AxisKind, DriveAxis, Feedback, Image, Profile as AxisProfile,
    pdo_mapping,
};
use drivers::can::shm_bus::ShmBus;
use drivers::can::station::Station;
use drivers::can::{Bus, Frame};
use drivers::canopen::FunctionCode;
use drivers::canopen::master::{Master, Supervision};
use drivers::canopen::sdo::{DownloadMode, SdoError};
use drivers::canopen::{AbortCode, Address, NodeId};
use drivers::sim::emca::Emca;
use drivers::sim::mtr_dci::{MtrDci, Profile};
use drivers::time::monotonic_now;

/// Ports for the CMMO-ST servers drive-sim binds, chosen as the integration tests choose them.
#[path = "../../tests/src/port.rs"]
mod port;
/// A failing test's drive-sim stopped as the integration tests stop theirs.
#[path = "../../tests/src/stop.rs"]
mod stop;

const BIN: &str = env!("CARGO_BIN_EXE_drive-sim");

/// A process must have exited or answered within this; only a hang reaches it.
const PATIENCE: Duration = Duration::from_secs(20);

fn unique(prefix: &str) -> String {
    static N: AtomicU32 = AtomicU32::new(0);
    format!(
        "{prefix}{}x{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )
}

/// A running `drive-sim`: its stdout and stderr are collected as they come; dropping it kills
/// the process and, if the test is failing, prints what the process said.
struct Proc {
    args: Vec<String>,
    child: Child,
    out: Arc<Mutex<String>>,
    readers: Vec<JoinHandle<()>>,
}

impl Proc {
    fn spawn(args: &[&str]) -> Proc {
        let mut child = Command::new(BIN)
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("drive-sim starts");
        let out = Arc::new(Mutex::new(String::new()));
        let mut readers = Vec::new();
        let streams: [Box<dyn Read + Send>; 2] = [
            Box::new(child.stdout.take().unwrap()),
            Box::new(child.stderr.take().unwrap()),
        ];
        for s in streams {
            let out = out.clone();
            readers.push(std::thread::spawn(move || {
                for line in BufReader::new(s).lines() {
                    let Ok(line) = line else { break };
                    let mut o = out.lock().unwrap();
                    o.push_str(&line);
                    o.push('\n');
                }
            }));
        }
        Proc {
            args: args.iter().map(|s| s.to_string()).collect(),
            child,
            out,
            readers,
        }
    }

    fn output(&self) -> String {
        self.out.lock().unwrap().clone()
    }

    /// Waits until the output holds `text`.
    fn wait_for(&self, text: &str) {
        let end = WallInstant::now() + PATIENCE;
        while WallInstant::now() < end {
            if self.output().contains(text) {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        panic!("drive-sim never printed {text:?}");
    }

    /// Waits for the process to end; its output is complete afterwards.
    fn wait_exit(&mut self) -> ExitStatus {
        let end = WallInstant::now() + PATIENCE;
        while WallInstant::now() < end {
            if let Some(status) = self.child.try_wait().unwrap() {
                for r in self.readers.drain(..) {
                    let _ = r.join();
                }
                return status;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        panic!("drive-sim did not end");
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if std::thread::panicking() {
            stop::ask_to_stop([&mut self.child], Duration::from_secs(3));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
        for r in self.readers.drain(..) {
            let _ = r.join();
        }
        if std::thread::panicking() {
            eprintln!(
                "--- drive-sim {} said:\n{}---",
                self.args.join(" "),
                self.output()
            );
        }
    }
}

/// Runs `drive-sim ARGS`, which must refuse them: exit status 1 and a message holding every
/// one of `expected`. Returns the process for more checks on its output.
fn refused(args: &[&str], expected: &[&str]) -> Proc {
    let mut p = Proc::spawn(args);
    let status = p.wait_exit();
    assert_eq!(status.code(), Some(1), "drive-sim {args:?} is refused");
    let out = p.output();
    for e in expected {
        assert!(out.contains(e), "drive-sim {args:?}: {e:?} in the message");
    }
    p
}

/// A file removed when the test ends.
struct TempFile(PathBuf);

impl TempFile {
    fn new(text: &str) -> TempFile {
        let path = std::env::temp_dir().join(format!("{}.toml", unique("drive-sim-test-")));
        std::fs::write(&path, text).unwrap();
        TempFile(path)
    }
    fn path(&self) -> &str {
        self.0.to_str().unwrap()
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

type M = Master<4, 4, 256>;

/// A master on `vbus:bus` for `nodes`, in this process.
fn master(bus: &str, nodes: &[u8]) -> Station<ShmBus, M> {
    let mut st = Station::new(ShmBus::open(bus, 1_000_000).unwrap(), M::default());
    for &n in nodes {
        st.endpoint
            .add_node(NodeId::new(n).unwrap(), Supervision::None, monotonic_now())
            .unwrap();
    }
    st
}

/// Runs the master in real time until `node` answers one SDO request (or the client's own
/// timeout ends it).
fn sdo(st: &mut Station<ShmBus, M>, node: NodeId) -> Result<Vec<u8>, SdoError> {
    let end = monotonic_now() + PATIENCE;
    while monotonic_now() < end {
        st.step();
        if let Some(e) = st.endpoint.poll_sdo_event(node) {
            return e.to_vec();
        }
        std::thread::sleep(Duration::from_micros(200));
    }
    panic!("the SDO client never ended its request to node {node}");
}

/// One upload of 1000h (device type) from `node`.
fn device_type_once(st: &mut Station<ShmBus, M>, node: u8) -> Result<Vec<u8>, SdoError> {
    let node = NodeId::new(node).unwrap();
    st.endpoint
        .sdo(node)
        .unwrap()
        .upload(Address::new(0x1000, 0))
        .unwrap();
    sdo(st, node)
}

/// 1000h from `node`, which must answer. The simulator may still be starting, so a timeout
/// (500 ms each) is retried.
fn device_type(st: &mut Station<ShmBus, M>, node: u8) -> Vec<u8> {
    for _ in 0..20 {
        match device_type_once(st, node) {
            Ok(v) => return v,
            Err(SdoError::Timeout { .. }) => continue,
            Err(e) => panic!("node {node}: {e}"),
        }
    }
    panic!("node {node} does not answer");
}

/// 1000h of each simulator, from the simulators themselves (TLC5xx: §8.1, 0002 0192h).
fn expected_device_types() -> (Vec<u8>, Vec<u8>, Vec<u8>) {
    let n = NodeId::new(5).unwrap();
    let t = monotonic_now();
    let tlc = 0x0002_0192u32.to_le_bytes().to_vec();
    let mtr = MtrDci::new(n, Profile::Fhpp, t)
        .unwrap()
        .device()
        .od()
        .get_u32(Address::new(0x1000, 0))
        .unwrap();
    let emca = Emca::new(n, t)
        .unwrap()
        .device()
        .od()
        .get_u32(Address::new(0x1000, 0))
        .unwrap();
    (tlc, mtr.to_le_bytes().to_vec(), emca.to_le_bytes().to_vec())
}

fn transact(c: &mut TcpStream, req: &[u8]) -> Vec<u8> {
    c.write_all(req).unwrap();
    let mut head = [0u8; 6];
    c.read_exact(&mut head).unwrap();
    let len = u16::from_be_bytes([head[4], head[5]]) as usize;
    let mut rest = vec![0u8; len];
    c.read_exact(&mut rest).unwrap();
    [&head[..], &rest[..]].concat()
}

/// Connects to a CMMO-ST that is starting.
fn connect(addr: &str) -> TcpStream {
    let end = WallInstant::now() + PATIENCE;
    while WallInstant::now() < end {
        if let Ok(c) = TcpStream::connect(addr) {
            c.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
            return c;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    panic!("nothing listens on {addr}");
}

/// FC 17h: write 4 registers (CCON = 0, all zero), read 4.
const FC17_ZERO: [u8; 25] = [
    0x00, 0x01, 0x00, 0x00, 0x00, 0x13, 0x00, 0x17, 0x00, 0x00, 0x00, 0x04, 0x00, 0x00, 0x00, 0x04,
    0x08, 0, 0, 0, 0, 0, 0, 0, 0,
];

/// The power-on status of a CMMO-ST over FC 17h: SCON 10h, SPOS 04h (big-endian words, FHPP
/// byte k = data byte k).
fn assert_cmmo_powered_on(c: &mut TcpStream) {
    let resp = transact(c, &FC17_ZERO);
    assert_eq!(
        &resp[..9],
        &[0x00, 0x01, 0x00, 0x00, 0x00, 0x0B, 0x00, 0x17, 0x08]
    );
    assert_eq!(&resp[9..11], &[0x10, 0x04], "SCON, SPOS at power-on");
}

/// A machine on two `vbus` buses and Modbus TCP, plus axes drive-sim must leave alone.
struct Machine {
    bus_a: String,
    bus_b: String,
    port: u16,
    file: TempFile,
}

const LIMITS: &str = "increments_per_unit = 100.0\nlimits = { position_min = 0.0, \
                      position_max = 100.0, velocity = 10.0, acceleration = 100.0 }\n";

fn axis(name: &str, device: &str, place: &str) -> String {
    format!("[[axes]]\nname = \"{name}\"\ndevice = \"{device}\"\n{place}\n{LIMITS}\n")
}

/// Bus A: TLC5xx t (node 1), MTR-DCI m (node 2); bus B: EMCA e (node 3); a SocketCAN bus with
/// TLC5xx r (node 4); CMMO-ST g on 127.0.0.1:PORT; CMMO-ST h simulated in the coordinator.
fn machine() -> Machine {
    let bus_a = unique("dsa");
    let bus_b = unique("dsb");
    // A SocketCAN interface name; drive-sim never opens it.
    let real = unique("rc");
    let port = port::server_port();
    let mut text = format!(
        "cycle_us = 2000\n\n\
         [[buses]]\nname = \"{bus_a}\"\nkind = \"vbus\"\n\n\
         [[buses]]\nname = \"{bus_b}\"\nkind = \"vbus\"\n\n\
         [[buses]]\nname = \"{real}\"\nkind = \"socketcan\"\n\n"
    );
    text += &axis("t", "tlc5xx", &format!("bus = \"{bus_a}\"\nnode = 1"));
    text += &axis("m", "mtr-dci", &format!("bus = \"{bus_a}\"\nnode = 2"));
    text += &axis("e", "emca", &format!("bus = \"{bus_b}\"\nnode = 3"));
    text += &axis("r", "tlc5xx", &format!("bus = \"{real}\"\nnode = 4"));
    text += &axis("g", "cmmo-st", &format!("modbus = \"127.0.0.1:{port}\""));
    text += &axis("h", "cmmo-st", "simulated = true");
    Machine {
        bus_a,
        bus_b,
        port,
        file: TempFile::new(&text),
    }
}

#[test]
fn config_starts_every_drive_the_coordinator_dials() {
    let m = machine();
    let p = Proc::spawn(&[
        "--config",
        m.file.path(),
        "--duration",
        "60",
        "--status-every",
        "0.2",
    ]);
    let (tlc, mtr, emca) = expected_device_types();
    let mut a = master(&m.bus_a, &[1, 2]);
    assert_eq!(device_type(&mut a, 1), tlc, "t: TLC5xx on bus A");
    assert_eq!(device_type(&mut a, 2), mtr, "m: MTR-DCI on bus A");
    let mut b = master(&m.bus_b, &[3]);
    assert_eq!(device_type(&mut b, 3), emca, "e: EMCA on bus B");
    let addr = format!("127.0.0.1:{}", m.port);
    let mut c = connect(&addr);
    assert_cmmo_powered_on(&mut c);

    // A status line per drive, naming its axis, with states by name.
    p.wait_for(&format!("g: CMMO-ST on {addr} | client connected"));
    p.wait_for(&format!("t: TLC5xx node 1 on vbus:{} | NMT ", m.bus_a));
    p.wait_for(&format!("m: MTR-DCI node 2 on vbus:{} | NMT ", m.bus_a));
    p.wait_for(&format!("e: EMCA node 3 on vbus:{} | NMT ", m.bus_b));
    let out = p.output();
    assert!(out.contains("NMT pre-operational"), "NMT state by name");
    assert!(out.contains("S2 Drive blocked"), "FHPP state by name");
    assert!(out.contains("Switch on disabled"), "CiA 402 state by name");
    for debug in [
        "Some(",
        "None",
        "Tlc5xx",
        "MtrDci",
        "CmmoSt",
        "PreOperational",
    ] {
        assert!(!out.contains(debug), "no Rust Debug output ({debug})");
    }
    // The axes it leaves alone, each with its reason; nothing answers for them here.
    assert!(
        out.lines()
            .any(|l| l.contains("r: TLC5xx skipped") && l.contains("socketcan")),
        "the axis on the real bus is skipped"
    );
    assert!(
        out.lines()
            .any(|l| l.contains("h: CMMO-ST skipped") && l.contains("simulated = true")),
        "the simulated CMMO-ST is skipped"
    );
    drop(c);

    // SIGTERM ends the run cleanly.
    let mut p = p;
    // SAFETY: kill(2) on our own child's pid; no memory is involved.
    assert_eq!(
        unsafe { libc::kill(p.child.id() as libc::pid_t, libc::SIGTERM) },
        0
    );
    let status = p.wait_exit();
    assert!(status.success(), "SIGTERM ends with status 0: {status}");
    assert!(p.output().contains("drive-sim: stopped after"));
}

#[test]
fn only_starts_the_named_axes_and_each_can_restart_alone() {
    let m = machine();
    let (tlc, mtr, emca) = expected_device_types();
    let addr = format!("127.0.0.1:{}", m.port);
    let start = |only: &[&str]| {
        let mut args = vec!["--config", m.file.path(), "--duration", "60"];
        for o in only {
            args.extend_from_slice(&["--only", o]);
        }
        Proc::spawn(&args)
    };
    let mut a = master(&m.bus_a, &[1, 2]);
    let mut b = master(&m.bus_b, &[3]);

    let only_e = start(&["e"]);
    assert_eq!(device_type(&mut b, 3), emca);
    // The EMCA's process is up, so silence from the others means they were not started.
    assert!(matches!(
        device_type_once(&mut a, 1),
        Err(SdoError::Timeout { .. })
    ));
    assert!(matches!(
        device_type_once(&mut a, 2),
        Err(SdoError::Timeout { .. })
    ));
    assert!(TcpStream::connect(&addr).is_err(), "no CMMO-ST on {addr}");

    // A second process with two more; the MTR-DCI still has none.
    let t_and_g = start(&["t", "g"]);
    assert_eq!(device_type(&mut a, 1), tlc);
    assert_cmmo_powered_on(&mut connect(&addr));
    assert!(matches!(
        device_type_once(&mut a, 2),
        Err(SdoError::Timeout { .. })
    ));

    // The EMCA stopped and started again on its own, the others running on.
    drop(only_e);
    assert!(matches!(
        device_type_once(&mut b, 3),
        Err(SdoError::Timeout { .. })
    ));
    let _again = start(&["e"]);
    assert_eq!(device_type(&mut b, 3), emca);
    let _m = start(&["m"]);
    assert_eq!(device_type(&mut a, 2), mtr);
    assert_eq!(device_type(&mut a, 1), tlc);
    drop(t_and_g);
}

#[test]
fn config_refusals_exit_1_naming_the_key_or_option() {
    let m = machine();
    let file = m.file.path();
    refused(
        &["--config", file, "--only", "e", "--only", "nosuch"],
        &["--only nosuch", "t, m, e, r, g, h"],
    );
    // Only axes the coordinator simulates, or on a real bus: nothing to start.
    refused(
        &["--config", file, "--only", "r", "--only", "h"],
        &["nothing to start"],
    );

    // Every refusal of `Config::check`, each naming its key.
    let text = std::fs::read_to_string(file)
        .unwrap()
        .replace("node = 1", "node = 0")
        .replace("name = \"m\"", "name = \"t\"");
    let bad = TempFile::new(&text);
    refused(
        &["--config", bad.path()],
        &["axes[0].node", "axes[1].name", "refused: 2 error(s)"],
    );
    // A parse error names the line and the key.
    let typo = TempFile::new(&text.replacen("cycle_us", "cycle_uss", 1));
    refused(&["--config", typo.path()], &["line 1", "cycle_uss"]);
    refused(
        &["--config", "/nonexistent/drive-sim.toml"],
        &["/nonexistent/drive-sim.toml"],
    );
}

#[test]
fn option_refusals_exit_1_naming_the_option() {
    let bus = format!("vbus:{}", unique("dsr"));
    let tlc = ["--device", "tlc5xx", "--bus", bus.as_str(), "--node", "5"];
    refused(
        &[&tlc[..], &["--node", "5"]].concat(),
        &["--node 5 is given twice"],
    );
    for bad in ["inf", "NaN", "-1", "0", "1e30"] {
        refused(
            &[&tlc[..], &["--duration", bad]].concat(),
            &[&format!("--duration {bad}")],
        );
    }
    for bad in ["inf", "NaN", "-1", "1e-9", "1e30"] {
        refused(
            &[&tlc[..], &["--status-every", bad]].concat(),
            &[&format!("--status-every {bad}")],
        );
    }
    refused(
        &[
            "--device",
            "emca",
            "--bus",
            &bus,
            "--node",
            "5",
            "--profile",
            "cia402",
        ],
        &["--profile cia402"],
    );
}

/// Starts `drive-sim --device DEVICE` as node 5 and reads 1000h from it over the shared-memory
/// bus; returns the master station for more requests.
fn read_device_type(device: &str, extra: &[&str]) -> (Proc, Station<ShmBus, M>, Vec<u8>) {
    let (child, st, v, _) = start_device(device, extra);
    (child, st, v)
}

/// [`read_device_type`], with the bus name too (without `vbus:`).
fn start_device(device: &str, extra: &[&str]) -> (Proc, Station<ShmBus, M>, Vec<u8>, String) {
    let bus_name = unique("dsim");
    let bus_arg = format!("vbus:{bus_name}");
    let mut args = vec![
        "--device",
        device,
        "--bus",
        bus_arg.as_str(),
        "--node",
        "5",
        "--duration",
        "30",
    ];
    args.extend_from_slice(extra);
    let child = Proc::spawn(&args);
    let mut st = master(&bus_name, &[5]);
    let v = device_type(&mut st, 5);
    (child, st, v, bus_name)
}

#[test]
fn tlc5xx_process_answers_sdo_from_another_process() {
    let (_child, mut st, device_type) = read_device_type("tlc5xx", &[]);
    let node = NodeId::new(5).unwrap();
    // §8.1: 1000h = 0002 0192h.
    assert_eq!(device_type, 0x0002_0192u32.to_le_bytes());
    // Its own abort code for an invalid write, and it keeps serving afterwards.
    st.endpoint
        .sdo(node)
        .unwrap()
        .download(Address::new(0x1801, 4), &[0], DownloadMode::Expedited)
        .unwrap();
    assert!(
        matches!(sdo(&mut st, node), Err(SdoError::Aborted { code, .. }) if code != AbortCode::Timeout)
    );
    st.endpoint
        .sdo(node)
        .unwrap()
        .upload(Address::new(0x6041, 0))
        .unwrap();
    assert_eq!(
        sdo(&mut st, node).unwrap(),
        0x0040u16.to_le_bytes(),
        "switch on disabled"
    );
}

#[test]
fn festo_processes_answer_sdo_with_their_own_dictionaries() {
    let n = NodeId::new(5).unwrap();
    let (_, mtr, emca) = expected_device_types();
    let mtr402 = MtrDci::new(n, Profile::Cia402, monotonic_now())
        .unwrap()
        .device()
        .od()
        .get_u32(Address::new(0x1000, 0))
        .unwrap();
    assert_eq!(read_device_type("mtr-dci", &[]).2, mtr);
    assert_eq!(
        read_device_type("mtr-dci", &["--profile", "cia402"]).2,
        mtr402.to_le_bytes()
    );
    let (_child, mut st, v) = read_device_type("emca", &[]);
    assert_eq!(v, emca);
    // The identity object answers too: the process keeps serving after the first request.
    st.endpoint
        .sdo(n)
        .unwrap()
        .upload(Address::new(0x1018, 1))
        .unwrap();
    assert!(sdo(&mut st, n).is_ok());
}

#[test]
fn cmmo_st_process_answers_a_modbus_client() {
    let addr = format!("127.0.0.1:{}", port::server_port());
    let _child = Proc::spawn(&["--device", "cmmo-st", "--modbus", &addr, "--duration", "30"]);
    let mut c = connect(&addr);
    assert_cmmo_powered_on(&mut c);
    // An unknown function code gets exception 01h and the server keeps serving.
    let resp = transact(&mut c, &[0x00, 0x02, 0x00, 0x00, 0x00, 0x02, 0x00, 0x42]);
    assert_eq!(resp, [0x00, 0x02, 0x00, 0x00, 0x00, 0x03, 0x00, 0xC2, 0x01]);
    let resp = transact(&mut c, &FC17_ZERO);
    assert_eq!(resp[7], 0x17);
}

/// An expedited SDO download to `node`, which must succeed.
fn write(st: &mut Station<ShmBus, M>, node: NodeId, index: u16, sub: u8, data: &[u8]) {
    st.endpoint
        .sdo(node)
        .unwrap()
        .download(Address::new(index, sub), data, DownloadMode::Expedited)
        .unwrap();
    if let Err(e) = sdo(st, node) {
        panic!("writing {index:04X}h:{sub} = {data:02X?}: {e}");
    }
}

/// An SDO upload of up to 4 bytes from `node`, as a little-endian number.
fn read(st: &mut Station<ShmBus, M>, node: NodeId, index: u16, sub: u8) -> i64 {
    st.endpoint
        .sdo(node)
        .unwrap()
        .upload(Address::new(index, sub))
        .unwrap();
    let v = sdo(st, node).unwrap_or_else(|e| panic!("reading {index:04X}h:{sub}: {e}"));
    let mut b = [0u8; 8];
    b[..v.len()].copy_from_slice(&v);
    match v.len() {
        2 => i64::from(u16::from_le_bytes([b[0], b[1]])),
        4 => i64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        _ => i64::from_le_bytes(b),
    }
}

/// What the master saw of a homing run: the last statusword, and each (position 6064h,
/// inputs 60FDh) polled while it ran; an input counts as on when it was on both before and
/// after the position was read (the three reads are separate SDO transfers).
struct HomingRun {
    statusword: i64,
    seen: Vec<(i64, i64)>,
    /// 603Fh at the end (0: no error).
    error_code: i64,
}

/// Enables the TLC5xx of `drive-sim ... --node 5 EXTRA` and starts homing `method` (search
/// 600 rpm, creep 6 rpm off the switch, 60000 rpm/s), all over SDO; polls it until the
/// statusword shows the end (bit 12 homing attained, or bit 13 error) or `until` holds.
fn home(extra: &[&str], method: i8, mut until: impl FnMut(&HomingRun) -> bool) -> HomingRun {
    let (_child, mut st, _) = read_device_type("tlc5xx", extra);
    let n = NodeId::new(5).unwrap();
    write(&mut st, n, 0x6099, 1, &600i32.to_le_bytes());
    write(&mut st, n, 0x6099, 2, &6i32.to_le_bytes());
    write(&mut st, n, 0x6083, 0, &60_000u32.to_le_bytes());
    write(&mut st, n, 0x6098, 0, &[method as u8]);
    for cw in [0x06u16, 0x07, 0x0F] {
        write(&mut st, n, 0x6040, 0, &cw.to_le_bytes());
    }
    let sw = read(&mut st, n, 0x6041, 0);
    assert_eq!(sw & 0x6F, 0x27, "operation enabled: statusword {sw:04X}h");
    write(&mut st, n, 0x6060, 0, &[6]);
    assert_eq!(read(&mut st, n, 0x6061, 0), 6, "homing mode displayed");
    // Bit 4 rising starts the method of 6098h.
    write(&mut st, n, 0x6040, 0, &0x1Fu16.to_le_bytes());
    let mut run = HomingRun {
        statusword: 0,
        seen: Vec::new(),
        error_code: 0,
    };
    let end = WallInstant::now() + PATIENCE;
    loop {
        run.statusword = read(&mut st, n, 0x6041, 0);
        let before = read(&mut st, n, 0x60FD, 0);
        let p = read(&mut st, n, 0x6064, 0);
        let after = read(&mut st, n, 0x60FD, 0);
        run.seen.push((p, before & after));
        // Bit 12 comes with bit 10 once the drive stands at the reference point.
        if run.statusword & 0x3400 == 0x1400 || run.statusword & 0x2000 != 0 || until(&run) {
            if run.statusword & 0x2000 != 0 {
                // The homing error comes first; a fault it leads to follows within ticks.
                std::thread::sleep(Duration::from_millis(200));
                run.statusword = read(&mut st, n, 0x6041, 0);
            }
            run.error_code = read(&mut st, n, 0x603F, 0);
            return run;
        }
        assert!(
            WallInstant::now() < end,
            "homing method {method} neither ended nor reached the test's condition; statusword \
             {:04X}h, last position {p}",
            run.statusword
        );
    }
}

/// 60FDh digital inputs (TLC5xx manual §6.12): bit 0 LIMN, 1 LIMP, 2 REF.
const LIMN: i64 = 1;
const LIMP: i64 = 2;
const REF: i64 = 4;

#[test]
fn tlc5xx_switches_let_homing_methods_finish_in_a_drive_sim_process() {
    let limits = ["--limit-negative", "-50000", "--limit-positive", "50000"];
    // (method, reference cam, the input it homes on, where that switch releases: the edge).
    // 23 searches upwards onto the cam and creeps back off its lower edge; 27 searches
    // downwards onto a cam below 0 and creeps back off its upper edge.
    let cases: [(i8, &str, i64, i64); 4] = [
        (17, "10000..12000", LIMN, -50_000),
        (18, "10000..12000", LIMP, 50_000),
        (23, "10000..12000", REF, 10_000),
        (27, "-12000..-10000", REF, -10_000),
    ];
    for (method, cam, input, edge) in cases {
        let args = [&limits[..], &["--reference", cam]].concat();
        let run = home(&args, method, |_| false);
        assert_eq!(
            run.statusword & 0x3400,
            0x1400,
            "method {method}: homing attained and standing, no error (statusword {:04X}h)",
            run.statusword
        );
        // It went onto its switch: the input was seen on, at positions past the edge (the
        // drive counts from its power-on 0 until the reference is set).
        let on: Vec<i64> = run
            .seen
            .iter()
            .filter(|(_, i)| i & input != 0)
            .map(|(p, _)| *p)
            .collect();
        assert!(
            !on.is_empty(),
            "method {method}: input {input} never seen on"
        );
        // Below 0 the switch lies below its edge (LIMN, the low cam), above 0 above it.
        let beyond = |p: &i64| if edge < 0 { *p <= edge } else { *p >= edge };
        assert!(
            on.iter().all(beyond),
            "method {method}: positions with the switch on {:?} .. {:?}, edge {edge}",
            on.iter().min(),
            on.iter().max()
        );
        // Done: the reference point is 200 increments (p_disHome 20F4h) off the edge, the
        // switch is off there, and 6064h counts from it (home position 0).
        let (p, inputs) = *run.seen.last().unwrap();
        assert_eq!(p, 0, "method {method}: 6064h at the reference point");
        assert_eq!(
            inputs & (LIMN | LIMP | REF),
            0,
            "method {method}: off every switch"
        );
        assert_eq!(run.error_code, 0, "method {method}: 603Fh");
    }
}

#[test]
fn tlc5xx_homing_without_its_switch_does_not_finish() {
    // No switches at all: method 17 searches for LIMN and goes on searching (the simulator
    // gives up only after 2^30 increments, hours at this speed); it never reports an end.
    let run = home(&[], 17, |r| {
        r.seen.len() > 3 && r.seen.last().unwrap().0 < -200_000
    });
    assert_eq!(
        run.statusword & 0x3000,
        0,
        "still running: neither attained nor an error (statusword {:04X}h)",
        run.statusword
    );
    let positions: Vec<i64> = run.seen.iter().map(|(p, _)| *p).collect();
    assert!(
        positions.windows(2).all(|w| w[1] <= w[0]),
        "it keeps searching downwards"
    );
    assert!(run.seen.iter().all(|(_, i)| i & (LIMN | LIMP | REF) == 0));

    // The limit switches but no reference: method 23 searches upwards, runs onto LIMP before
    // any REF, and stops there with the homing error (bit 13) and the limit switch fault
    // (Fault, 603Fh = FF01h).
    let run = home(
        &["--limit-negative", "-50000", "--limit-positive", "50000"],
        23,
        |_| false,
    );
    assert_eq!(
        run.statusword & 0x3000,
        0x2000,
        "homing error (statusword {:04X}h)",
        run.statusword
    );
    assert!(run.seen.iter().any(|(_, i)| i & LIMP != 0), "LIMP reached");
    assert_eq!(run.statusword & 0x4F, 0x08, "Fault");
    assert_eq!(run.error_code, 0xFF01, "603Fh: positive limit switch");
}

#[test]
fn tlc5xx_switch_refusals_name_the_option_and_what_is_allowed() {
    let bus = format!("vbus:{}", unique("dsw"));
    let tlc = ["--device", "tlc5xx", "--bus", bus.as_str(), "--node", "5"];
    for (args, expected) in [
        (
            &["--limit-negative", "inf"][..],
            "--limit-negative inf: give whole motor increments, -2147483648 to 2147483647",
        ),
        (
            &["--limit-negative", "NaN"],
            "--limit-negative NaN: give whole motor increments",
        ),
        (
            &["--limit-positive", "1.5"],
            "--limit-positive 1.5: give whole motor increments",
        ),
        (
            &["--limit-positive", "3e9"],
            "--limit-positive 3e9: give whole motor increments",
        ),
        (
            &["--limit-negative", "10"],
            "--limit-negative 10: give 0 or less",
        ),
        (
            &["--limit-positive", "0"],
            "--limit-positive 0: give 1 or more",
        ),
        (
            &["--reference", "10000"],
            "--reference 10000: give FROM..TO",
        ),
        (
            &["--reference", "10000..1e99"],
            "--reference 10000..1e99: FROM and TO: give whole motor increments",
        ),
        (
            &["--reference", "12000..10000"],
            "--reference 12000..10000: FROM must be below TO",
        ),
        (
            &["--limit-positive", "50000", "--reference", "40000..60000"],
            "--reference 40000..60000: the cam must lie between the limit switches (none .. 50000)",
        ),
    ] {
        refused(&[&tlc[..], args].concat(), &[expected]);
    }
    refused(
        &[
            "--device",
            "emca",
            "--bus",
            &bus,
            "--node",
            "5",
            "--limit-negative",
            "-100",
        ],
        &["--limit-negative -100: the EMCA simulator has no switches"],
    );
    let m = machine();
    refused(
        &["--config", m.file.path(), "--reference", "1..2"],
        &["--reference 1..2: the switches are options of --device tlc5xx"],
    );
}

/// The coordinator's own CiA 402 axis (`coordinator::axis::DriveAxis`, the code `coordinator
/// run` drives a TLC5xx with) homes the TLC5xx of `drive-sim ... --node 5 EXTRA` with
/// `method`, as `coordinator/tests/axes.rs` does with the in-process simulator: PDO1 mapped
/// over SDO as the coordinator's boot maps it (`pdo_mapping`), 6098h written, NMT start, then
/// per cycle a SYNC, the drive's TPDO1 into the axis and the axis's RPDO1 out. Each cycle
/// waits for its TPDO (lockstep), so a busy host slows the test but cannot fail it. Enables
/// (Standstill until ready), then demands Home until the axis reports it done or failed, or
/// the drive faulted.
fn home_with_the_coordinators_axis(extra: &[&str], method: i8) -> Feedback {
    let (_child, mut st, _, bus_name) = start_device("tlc5xx", extra);
    let n = NodeId::new(5).unwrap();
    let map = pdo_mapping(AxisKind::Tlc5xx, AxisProfile::Cia402);
    for (spec, comm, mapping) in [
        (map.rpdo.unwrap(), 0x1400u16, 0x1600u16),
        (map.tpdo.unwrap(), 0x1800, 0x1A00),
    ] {
        let cob = u32::from(spec.function.cob_id(n));
        let comm = comm + u16::from(spec.number) - 1;
        let mapping = mapping + u16::from(spec.number) - 1;
        if spec.remappable {
            write(&mut st, n, comm, 1, &(cob | 0x8000_0000).to_le_bytes());
            write(&mut st, n, mapping, 0, &[0]);
            for (k, e) in spec.mapping.iter().enumerate() {
                write(&mut st, n, mapping, k as u8 + 1, &e.to_le_bytes());
            }
            write(&mut st, n, mapping, 0, &[spec.mapping.len() as u8]);
        }
        write(&mut st, n, comm, 2, &[spec.transmission]);
        if spec.remappable {
            write(&mut st, n, comm, 1, &cob.to_le_bytes());
        }
    }
    write(&mut st, n, 0x6081, 0, &1200u32.to_le_bytes());
    write(&mut st, n, 0x6083, 0, &60_000u32.to_le_bytes());
    write(&mut st, n, 0x6084, 0, &60_000u32.to_le_bytes());
    write(&mut st, n, 0x6098, 0, &[method as u8]);
    write(&mut st, n, 0x6099, 1, &600i32.to_le_bytes());
    write(&mut st, n, 0x6099, 2, &60i32.to_le_bytes());

    let mut bus = ShmBus::open(&bus_name, 1_000_000).unwrap();
    let send = |bus: &mut ShmBus, f: Frame| {
        let end = WallInstant::now() + PATIENCE;
        while let Err(e) = bus.send(&f) {
            assert!(WallInstant::now() < end, "sending {f}: {e}");
            std::thread::sleep(Duration::from_millis(1));
        }
    };
    send(&mut bus, Frame::new_std(0x000, &[0x01, 5]).unwrap());
    let tpdo1 = FunctionCode::Tpdo(1).cob_id(n);
    let rpdo1 = FunctionCode::Rpdo(1).cob_id(n);
    let mut axis = DriveAxis::new(AxisKind::Tlc5xx, AxisProfile::Cia402, 10_000_000).unwrap();
    let mut out = Image::default();
    let mut homing = false;
    let end = WallInstant::now() + PATIENCE;
    loop {
        send(&mut bus, Frame::new_std(0x080, &[]).unwrap());
        // This cycle's TPDO1 (the drive answers the SYNC); older frames are skipped.
        let input = loop {
            let f = bus
                .recv_until(monotonic_now() + Duration::from_millis(500))
                .unwrap();
            match f {
                Some(f) if f.cob_id() == Some(tpdo1) => break Some(f.data().to_vec()),
                Some(_) => continue,
                None => break None,
            }
        };
        let demand = if homing {
            Demand::Home
        } else {
            Demand::Standstill
        };
        let fb = *axis.exchange(input.as_deref(), &demand, &mut out).unwrap();
        send(&mut bus, Frame::new_std(rpdo1, out.bytes()).unwrap());
        if !homing && fb.done && fb.state == AxisState::Ready {
            homing = true;
        } else if homing && (fb.done || fb.failed || fb.state == AxisState::Fault) {
            return fb;
        }
        assert!(
            WallInstant::now() < end,
            "method {method}: the axis did not end homing ({fb:?})"
        );
        // About the coordinator's 10 ms cycle; the wait for the TPDO paces it too.
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[test]
fn the_coordinators_cia402_axis_homes_a_drive_sim_tlc5xx_on_its_switches() {
    let switches = [
        "--limit-negative",
        "-50000",
        "--limit-positive",
        "50000",
        "--reference",
        "10000..12000",
    ];
    for method in [17, 18, 23] {
        let fb = home_with_the_coordinators_axis(&switches, method);
        assert!(
            fb.homed && fb.motion_complete && !fb.failed,
            "method {method}: {fb:?}"
        );
        // The reference point reads 0 (the home position of 6098h's methods).
        assert_eq!(fb.position, 0, "method {method}");
    }
    // Without its switch homing cannot complete: 23 with no REF runs onto LIMP, where the
    // drive reports the homing error (bit 13), then faults (limit switch). The axis ends at
    // whichever it sees first: the demand failed, or the fault; never homed.
    let fb = home_with_the_coordinators_axis(&switches[..4], 23);
    assert!(
        (fb.failed || fb.state == AxisState::Fault) && fb.status & 0x2000 != 0 && !fb.homed,
        "{fb:?}"
    );
}

/// `drive-sim --write-eds cia402`: the generic drive's built-in EDS.
fn generic_eds() -> String {
    let out = Command::new(BIN)
        .args(["--write-eds", "cia402"])
        .output()
        .unwrap();
    assert!(out.status.success(), "drive-sim --write-eds cia402");
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn cia402_process_runs_from_an_eds_and_refuses_one_without_what_it_needs() {
    // The built-in drive: 1000h and 6502h.
    let (_child, mut st, device_type) = read_device_type("cia402", &[]);
    assert_eq!(device_type, 0x0002_0192u32.to_le_bytes());
    let node = NodeId::new(5).unwrap();
    let read = |st: &mut Station<ShmBus, M>, index: u16, sub: u8| {
        st.endpoint
            .sdo(node)
            .unwrap()
            .upload(Address::new(index, sub))
            .unwrap();
        sdo(st, node).unwrap()
    };
    assert_eq!(read(&mut st, 0x6502, 0), 0x03A5u32.to_le_bytes());
    // From an EDS: its identity and its modes (PP refused where 6502h lacks it).
    let text = generic_eds()
        .replace("DefaultValue=0x3A5", "DefaultValue=0x380")
        .replace("ProductNumber=0x402", "ProductNumber=0x4711");
    let edited = text.replacen(
        "ParameterName=product code\nObjectType=0x7\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x402",
        "ParameterName=product code\nObjectType=0x7\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x4711",
        1,
    );
    assert_ne!(edited, text, "the EDS names 1018h:02 as expected");
    let file = TempFile::new(&edited);
    let (_child, mut st, _) = read_device_type("cia402", &["--eds", file.path()]);
    assert_eq!(read(&mut st, 0x1018, 2), 0x4711u32.to_le_bytes());
    st.endpoint
        .sdo(node)
        .unwrap()
        .download(Address::new(0x6060, 0), &[1], DownloadMode::Expedited)
        .unwrap();
    assert!(matches!(
        sdo(&mut st, node),
        Err(SdoError::Aborted {
            code: AbortCode::InvalidValue,
            ..
        })
    ));
    // Without 607Ah: refused, naming it.
    let start = text.find("[607A]").unwrap();
    let end = start + text[start..].find("\n\n").unwrap() + 2;
    let cut = TempFile::new(&format!("{}{}", &text[..start], &text[end..]));
    let bus = format!("vbus:{}", unique("dse"));
    refused(
        &[
            "--device",
            "cia402",
            "--bus",
            &bus,
            "--node",
            "5",
            "--eds",
            cut.path(),
        ],
        &["607Ah", "target position"],
    );
    // --eds describes a generic drive only.
    refused(
        &[
            "--device",
            "tlc5xx",
            "--bus",
            &bus,
            "--node",
            "5",
            "--eds",
            cut.path(),
        ],
        &["--eds FILE", "--device cia402"],
    );
}
