//! EtherCAT across processes: `drive-sim --device emca --ethercat IFACE --count 3` as its own
//! process on one end of a veth pair, in a network namespace this test makes (`unshare -rn`),
//! never on a real interface; the master on the other end is ethercrab 0.7 over a raw socket,
//! in this test's process.
//!
//! The test runs itself again inside the namespace (the environment variable below tells the
//! second run it is there): the shell makes the veth pair, starts drive-sim on `ecs`, then
//! execs this test binary filtered to the test, which drives `ecm`. Where namespaces or raw
//! sockets are refused, the test says it skipped and why; `MOTION_REQUIRE_ALL=1` (`.ci/run`)
//! makes that a failure.

use std::future::Future;
use std::pin::pin;
use std::process::Command;
use std::task::{Context, Poll, Waker};
use std::time::{Duration, Instant};

use drivers::ethercat::frame::MAX_FRAME_LEN;
use drivers::ethercat::raw::RawSocket;
use ethercrab::error::Error;
use ethercrab::std::ethercat_now;
use ethercrab::{MainDevice, MainDeviceConfig, PduRx, PduStorage, PduTx, Timeouts};
use integration_tests::{skip_or_fail, workspace_bin};

/// Set in the second run, inside the namespace.
const INSIDE: &str = "MOTION_TEST_INSIDE_NETNS";
/// The master's and the simulator's ends of the veth pair.
const MASTER_IF: &str = "ecm";
const SIM_IF: &str = "ecs";

/// Runs `test` inside a fresh network namespace with the veth pair and drive-sim; returns
/// false (after saying why) where that cannot be had.
fn in_namespace(test: &str, sim_args: &str) -> bool {
    if std::env::var_os(INSIDE).is_some() {
        return true;
    }
    let probe = Command::new("unshare")
        .args([
            "-rn", "ip", "link", "add", "probe0", "type", "veth", "peer", "name", "probe1",
        ])
        .output();
    match probe {
        Ok(o) if o.status.success() => {}
        Ok(o) => {
            skip_or_fail(
                test,
                &format!(
                    "a network namespace with a veth pair cannot be made here (`unshare -rn ip link \
                     add`: {})",
                    String::from_utf8_lossy(&o.stderr).trim()
                ),
            );
            return false;
        }
        Err(e) => {
            skip_or_fail(test, &format!("`unshare` or `ip` cannot be run ({e})"));
            return false;
        }
    }
    let exe = std::env::current_exe().unwrap();
    let sim = workspace_bin("coordinator", "drive-sim");
    let log = std::env::temp_dir().join(format!(
        "drive_sim_ethercat_{}_{test}.log",
        std::process::id()
    ));
    // drive-sim in the background, the test in the foreground; then drive-sim is stopped
    // (Ctrl-C's signal) and waited for, so that its log is whole.
    let script = format!(
        "set -e; ip link add {MASTER_IF} type veth peer name {SIM_IF}; ip link set {MASTER_IF} up; \
         ip link set {SIM_IF} up; '{sim}' --device emca --ethercat {SIM_IF} {sim_args} \
         --status-every 0.5 --duration 120 > '{log}' 2>&1 & sim=$!; set +e; \
         '{exe}' --exact {test} --nocapture --test-threads 1; rc=$?; kill -INT $sim; wait $sim; \
         exit $rc",
        sim = sim.display(),
        exe = exe.display(),
        log = log.display()
    );
    let out = Command::new("unshare")
        .args(["-rn", "sh", "-c", &script])
        .env(INSIDE, "1")
        .output()
        .unwrap();
    let sim_log = std::fs::read_to_string(&log).unwrap_or_default();
    let _ = std::fs::remove_file(&log);
    assert!(
        out.status.success(),
        "the run inside the namespace failed\n--- its output ---\n{}{}\n--- drive-sim ---\n{sim_log}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    // The run's figures and drive-sim's account, for `--nocapture`.
    println!("{}", String::from_utf8_lossy(&out.stdout));
    eprintln!("--- drive-sim ---\n{sim_log}");
    false
}

/// An ethercrab master on a raw socket, its frames pumped by hand (one thread, no executor).
struct Master {
    md: &'static MainDevice<'static>,
    tx: PduTx<'static>,
    rx: PduRx<'static>,
    sock: RawSocket,
}

impl Master {
    fn open(iface: &str) -> Master {
        const DATA: usize = PduStorage::element_size(1100);
        let storage: &'static PduStorage<16, DATA> = Box::leak(Box::new(PduStorage::new()));
        let (tx, rx, pdu_loop) = storage.try_split().unwrap();
        let md = Box::leak(Box::new(MainDevice::new(
            pdu_loop,
            Timeouts::default(),
            MainDeviceConfig {
                dc_static_sync_iterations: 0,
                ..MainDeviceConfig::default()
            },
        )));
        let sock = RawSocket::open(iface).unwrap_or_else(|e| panic!("{e}"));
        Master { md, tx, rx, sock }
    }

    fn run<T>(&mut self, fut: impl Future<Output = T>) -> T {
        let mut fut = pin!(fut);
        let mut cx = Context::from_waker(Waker::noop());
        let mut buf = [0u8; MAX_FRAME_LEN];
        loop {
            if let Poll::Ready(r) = fut.as_mut().poll(&mut cx) {
                return r;
            }
            let mut sent = false;
            while let Some(frame) = self.tx.next_sendable_frame() {
                let sock = &self.sock;
                frame
                    .send_blocking(|b| {
                        sock.send(b).map_err(|_| Error::SendFrame)?;
                        Ok(b.len())
                    })
                    .unwrap();
                sent = true;
            }
            let mut wait = if sent {
                Duration::from_millis(2)
            } else {
                Duration::from_micros(200)
            };
            while let Some(n) = self.sock.recv(&mut buf, wait).unwrap() {
                // A reply to a frame ethercrab gave up on (while drive-sim was still starting)
                // is refused; it changes nothing.
                let _ = self.rx.receive_frame(&buf[..n]);
                wait = Duration::ZERO;
            }
        }
    }
}

#[test]
fn a_drive_sim_segment_of_three_emcas_boots_to_op_over_a_veth_pair() {
    let name = "a_drive_sim_segment_of_three_emcas_boots_to_op_over_a_veth_pair";
    if !in_namespace(name, "--count 3") {
        return;
    }
    let mut m = Master::open(MASTER_IF);
    let md = m.md;
    // drive-sim may still be starting: count again until three answer.
    let start = Instant::now();
    let group = loop {
        let found = match m.run(md.init_single_group::<4, 256>(ethercat_now)) {
            Ok(g) if g.len() == 3 => break g,
            Ok(g) => format!("{} subdevice(s)", g.len()),
            Err(e) => format!("start-up failed: {e}"),
        };
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "after 10 s, {found} instead of 3 subdevices in Pre-Operational"
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    for sd in group.iter(md) {
        assert_eq!(sd.name(), drivers::catalog::EMCA_ETHERCAT.name);
    }
    let sd = group.subdevice(md, 2).unwrap();
    let device_type: u32 = m.run(sd.sdo_read(0x1000, 0)).unwrap();
    assert_eq!(device_type, 0x0000_012D);
    let group = m.run(group.into_safe_op(md)).expect("SafeOp");
    // Valid outputs before Op (the subdevice refuses Op without them, 0019h).
    for _ in 0..3 {
        m.run(group.tx_rx(md)).expect("cycle in SafeOp");
    }
    let group = m.run(group.request_into_op(md)).expect("Op requested");
    let mut op = false;
    for _ in 0..500 {
        let r = m.run(group.tx_rx(md)).expect("cycle");
        if r.all_op() {
            op = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    assert!(op, "Op not reached");
    // Enable all three over the process data: SCON ENABLED | OPEN | VLOAD within 100 cycles.
    let mut enabled = false;
    for _ in 0..100 {
        for sd in group.iter(md) {
            sd.outputs_raw_mut()[..2].copy_from_slice(&[0x23, 0x01]);
        }
        let r = m.run(group.tx_rx(md)).expect("cycle");
        assert_eq!(
            r.working_counter, 9,
            "three subdevices, read and write each"
        );
        if group.iter(md).all(|sd| sd.inputs_raw()[0] == 0x13) {
            enabled = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    assert!(enabled, "the three drives did not enable");

    // The frame's round trip over the veth link, cycling at 1 ms and at 250 µs: printed
    // (docs/performance.md), not asserted. Every cycle must come back whole.
    for period_us in [1000u64, 250] {
        let period = Duration::from_micros(period_us);
        let mut rtt = Vec::with_capacity(2000);
        let mut next = Instant::now();
        for _ in 0..2000 {
            let t0 = Instant::now();
            let r = m.run(group.tx_rx(md)).expect("cycle");
            rtt.push(t0.elapsed());
            assert_eq!(r.working_counter, 9);
            assert!(r.all_op(), "a subdevice left Op at {period_us} µs");
            next += period;
            if let Some(d) = next.checked_duration_since(Instant::now()) {
                std::thread::sleep(d);
            }
        }
        rtt.sort();
        let us = |d: Duration| d.as_secs_f64() * 1e6;
        println!(
            "EtherCAT round trip at a {period_us} µs cycle (3 EMCA-EC, drive-sim over veth): \
             p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs over {} cycles",
            us(rtt[rtt.len() / 2]),
            us(rtt[rtt.len() * 99 / 100]),
            us(rtt[rtt.len() - 1]),
            rtt.len()
        );
    }
}

/// drive-sim's EtherCAT options are refused with exit status 1 and a message naming them: the
/// EMCA only, an interface that exists and is not physical, `--count` only with `--ethercat`.
#[test]
fn drive_sim_refuses_ethercat_options_it_cannot_honour() {
    let sim = workspace_bin("coordinator", "drive-sim");
    let refused = |args: &[&str], expected: &[&str]| {
        let out = Command::new(&sim).args(args).output().unwrap();
        let text = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "drive-sim {args:?}: {text}");
        for e in expected {
            assert!(text.contains(e), "drive-sim {args:?}: {e:?} in {text}");
        }
    };
    refused(
        &["--device", "tlc5xx", "--ethercat", "lo"],
        &[
            "--ethercat lo",
            "the EMCA is the EtherCAT drive simulated here",
        ],
    );
    refused(
        &["--device", "emca", "--ethercat", "no-such-if0"],
        &[
            "--ethercat no-such-if0",
            "no network interface 'no-such-if0'",
        ],
    );
    refused(
        &[
            "--device", "emca", "--bus", "vbus:x", "--node", "5", "--count", "2",
        ],
        &["--count 2"],
    );
    refused(
        &["--device", "emca", "--ethercat", "lo", "--bus", "vbus:x"],
        &["--ethercat lo with --bus"],
    );
    refused(
        &["--device", "emca"],
        &["give --bus vbus:NAME", "--ethercat IFACE"],
    );
    // A physical interface (one with a device behind it), where this machine has one: a
    // simulated drive must not answer on a real line.
    let physical = std::fs::read_dir("/sys/class/net")
        .into_iter()
        .flatten()
        .flatten()
        .find(|e| e.path().join("device").exists())
        .map(|e| e.file_name().to_string_lossy().into_owned());
    if let Some(nic) = physical {
        refused(
            &["--device", "emca", "--ethercat", &nic],
            &[&format!("--ethercat {nic}: a physical network interface")],
        );
    }
}
