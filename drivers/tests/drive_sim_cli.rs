//! `drive-sim` as its own process: a TLC5xx on a `vbus:` bus answering SDO reads from this
//! process, and a CMMO-ST answering a Modbus TCP client, both with the manuals' bytes.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

use drivers::can::shm_bus::ShmBus;
use drivers::can::station::Station;
use drivers::canopen::master::{Master, Supervision};
use drivers::canopen::sdo::{DownloadMode, SdoError};
use drivers::canopen::{AbortCode, Address, NodeId};
use drivers::time::monotonic_now;

const BIN: &str = env!("CARGO_BIN_EXE_drive-sim");

fn unique(prefix: &str) -> String {
    static N: AtomicU32 = AtomicU32::new(0);
    format!(
        "{prefix}{}x{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )
}

/// Kills the child when the test ends, however it ends.
struct Reap(Child);
impl Drop for Reap {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn spawn(args: &[&str]) -> Reap {
    Reap(
        Command::new(BIN)
            .args(args)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("drive-sim starts"),
    )
}

type M = Master<2, 4, 256>;

/// Runs the master in real time until `node` answers one SDO request, or 5 s pass.
fn sdo(st: &mut Station<ShmBus, M>, node: NodeId) -> Result<Vec<u8>, SdoError> {
    let end = monotonic_now() + Duration::from_secs(5);
    while monotonic_now() < end {
        st.step();
        if let Some(e) = st.endpoint.poll_sdo_event(node) {
            return e.to_vec();
        }
        std::thread::sleep(Duration::from_micros(200));
    }
    panic!("no SDO answer from node {node} within 5 s");
}

/// Starts `drive-sim --device DEVICE` as node 5 and reads 1000h from it over the shared-memory
/// bus; returns the master station for more requests.
fn read_device_type(device: &str, extra: &[&str]) -> (Reap, Station<ShmBus, M>, Vec<u8>) {
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
    let child = spawn(&args);
    let node = NodeId::new(5).unwrap();
    let bus = ShmBus::open(&bus_name, 1_000_000).unwrap();
    let mut st = Station::new(bus, M::default());
    st.endpoint
        .add_node(node, Supervision::None, monotonic_now())
        .unwrap();
    // The simulator may still be starting: the first request can time out (500 ms), so retry.
    for _ in 0..8 {
        st.endpoint
            .sdo(node)
            .unwrap()
            .upload(Address::new(0x1000, 0))
            .unwrap();
        match sdo(&mut st, node) {
            Ok(v) => return (child, st, v),
            Err(SdoError::Timeout { .. }) => continue,
            Err(e) => panic!("{device}: {e}"),
        }
    }
    panic!("{device}: no answer");
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
    use drivers::sim::emca::Emca;
    use drivers::sim::mtr_dci::{MtrDci, Profile};
    let n = NodeId::new(5).unwrap();
    let t = monotonic_now();
    let expected = |v: u32| v.to_le_bytes().to_vec();
    let mtr = MtrDci::new(n, Profile::Fhpp, t)
        .unwrap()
        .device()
        .od()
        .get_u32(Address::new(0x1000, 0))
        .unwrap();
    let mtr402 = MtrDci::new(n, Profile::Cia402, t)
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
    assert_eq!(read_device_type("mtr-dci", &[]).2, expected(mtr));
    assert_eq!(
        read_device_type("mtr-dci", &["--profile", "cia402"]).2,
        expected(mtr402)
    );
    let (_child, mut st, v) = read_device_type("emca", &[]);
    assert_eq!(v, expected(emca));
    // A PNU by SDO at 2000h + PNU, out of range: the device's own abort code, then it goes on.
    st.endpoint
        .sdo(n)
        .unwrap()
        .upload(Address::new(0x1018, 1))
        .unwrap();
    assert!(sdo(&mut st, n).is_ok());
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
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

#[test]
fn cmmo_st_process_answers_a_modbus_client() {
    let port = free_port();
    let addr = format!("127.0.0.1:{port}");
    let _child = spawn(&["--device", "cmmo-st", "--modbus", &addr, "--duration", "30"]);
    let mut c = None;
    for _ in 0..100 {
        if let Ok(s) = TcpStream::connect(&addr) {
            c = Some(s);
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let mut c = c.expect("drive-sim listens");
    c.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    // FC 17h: write 4 registers (CCON = 0, all zero), read 4: the power-on status
    // SCON 10h, SPOS 04h (big-endian words, FHPP byte k = data byte k).
    let req = [
        0x00, 0x01, 0x00, 0x00, 0x00, 0x13, 0x00, 0x17, 0x00, 0x00, 0x00, 0x04, 0x00, 0x00, 0x00,
        0x04, 0x08, 0, 0, 0, 0, 0, 0, 0, 0,
    ];
    let resp = transact(&mut c, &req);
    assert_eq!(
        &resp[..9],
        &[0x00, 0x01, 0x00, 0x00, 0x00, 0x0B, 0x00, 0x17, 0x08]
    );
    assert_eq!(&resp[9..11], &[0x10, 0x04], "SCON, SPOS at power-on");
    // An unknown function code gets exception 01h and the server keeps serving.
    let resp = transact(&mut c, &[0x00, 0x02, 0x00, 0x00, 0x00, 0x02, 0x00, 0x42]);
    assert_eq!(resp, [0x00, 0x02, 0x00, 0x00, 0x00, 0x03, 0x00, 0xC2, 0x01]);
    let resp = transact(&mut c, &req);
    assert_eq!(resp[7], 0x17);
}
