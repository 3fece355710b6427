//! The CMMO-ST Modbus TCP server over real loopback TCP, driven with raw bytes so the tests
//! prove the wire format (digest `seed-001-cmmo-st.md` §1.2, manual §4.3).
//!
//! The device behind the server is [`TestDrive`], a test double (not the FHPP simulator): it
//! reports the power-on status bytes SCON 0x10 / SPOS 0x04, echoes the record number, reports a
//! fixed actual position, echoes the parameter channel with the top bit set, and records what
//! the server tells it. Every wait is bounded; only 127.0.0.1 is used.
#![cfg(feature = "std")]

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivers::sim::cmmo_st::{
    Config, ConnectionLost, FhppDevice, Identification, Profile, Server, ServerConfig,
    node_guard_timeout,
};
use drivers::time::Instant;

/// Test double for the FHPP drive.
#[derive(Debug, Default)]
struct TestDrive {
    outputs: Vec<[u8; 8]>,
    fault: u16,
    foreign_control: bool,
    lost: Vec<ConnectionLost>,
    established: u32,
    last_step: Instant,
}

impl FhppDevice for TestDrive {
    fn exchange(&mut self, output: &[u8; 8], _now: Instant) -> [u8; 8] {
        self.outputs.push(*output);
        // SCON 0x10 (VLOAD), SPOS 0x04 (MC), record echo, RSB 0, position 0x01234567.
        [0x10, 0x04, output[2], 0x00, 0x01, 0x23, 0x45, 0x67]
    }
    fn parameter(&mut self, request: &[u8; 8], _now: Instant) -> [u8; 8] {
        let mut r = *request;
        r[0] |= 0x80;
        r
    }
    fn step_to(&mut self, now: Instant) {
        assert!(now >= self.last_step, "time never runs backwards");
        self.last_step = now;
    }
    fn fault_number(&self) -> u16 {
        self.fault
    }
    fn identification(&self) -> Identification<'_> {
        Identification {
            user_application_name: "line 3",
            ..Identification::default()
        }
    }
    fn master_control(&self) -> bool {
        !self.foreign_control
    }
    fn connection_lost(&mut self, lost: ConnectionLost, _now: Instant) {
        self.lost.push(lost);
        // Like the drive: 47h is a fault by default, and FC 0x07 then reports it.
        if lost == ConnectionLost::WithMasterControl {
            self.fault = u16::from(lost.number());
        }
    }
    fn connection_established(&mut self, _now: Instant) {
        self.established += 1;
    }
}

const BOUND: Duration = Duration::from_secs(3);

fn start(modbus: Config) -> (Server, Arc<Mutex<TestDrive>>) {
    let dev = Arc::new(Mutex::new(TestDrive::default()));
    let mut cfg = ServerConfig::loopback(0);
    cfg.modbus = modbus;
    cfg.tick = Duration::from_millis(1);
    let server = Server::spawn(cfg, Arc::clone(&dev)).unwrap();
    assert!(server.local_addr().ip().is_loopback());
    assert_ne!(
        server.local_addr().port(),
        0,
        "the OS-chosen port is reported"
    );
    (server, dev)
}

fn connect(addr: SocketAddr) -> TcpStream {
    let s = TcpStream::connect_timeout(&addr, BOUND).unwrap();
    s.set_read_timeout(Some(BOUND)).unwrap();
    s.set_nodelay(true).unwrap();
    s
}

/// Reads one whole response ADU (header, then as many bytes as its length field says).
fn read_adu(s: &mut TcpStream) -> Vec<u8> {
    let mut head = [0u8; 7];
    s.read_exact(&mut head).unwrap();
    let len = u16::from_be_bytes([head[4], head[5]]) as usize;
    let mut rest = vec![0u8; len - 1];
    s.read_exact(&mut rest).unwrap();
    let mut v = head.to_vec();
    v.extend(rest);
    v
}

fn transact(s: &mut TcpStream, req: &[u8]) -> Vec<u8> {
    s.write_all(req).unwrap();
    read_adu(s)
}

/// Whether the server closed this connection: EOF (or a reset) within the bound.
fn closed_by_server(s: &mut TcpStream) -> bool {
    let mut b = [0u8; 16];
    match s.read(&mut b) {
        Ok(0) => true,
        Ok(_) => false,
        Err(e) => matches!(
            e.kind(),
            ErrorKind::ConnectionReset | ErrorKind::ConnectionAborted
        ),
    }
}

fn wait_until(mut f: impl FnMut() -> bool) {
    let t0 = std::time::Instant::now();
    while !f() {
        assert!(t0.elapsed() < BOUND, "condition not reached in time");
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// The digest's example frame: FC 0x17, record mode, CCON 0x23 CPOS 0x01 (§1.2).
const DIGEST_0X17: [u8; 25] = [
    0x00, 0x01, 0x00, 0x00, 0x00, 0x13, 0x00, 0x17, 0x00, 0x00, 0x00, 0x04, 0x00, 0x00, 0x00, 0x04,
    0x08, 0x23, 0x01, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
];

#[test]
fn fc17_digest_example_exchanges_the_image_byte_for_byte() {
    let (server, dev) = start(Config::default());
    let mut c = connect(server.local_addr());
    let resp = transact(&mut c, &DIGEST_0X17);
    assert_eq!(
        resp,
        [
            0x00, 0x01, 0x00, 0x00, 0x00, 0x0B, 0x00, 0x17, 0x08, 0x10, 0x04, 0x00, 0x00, 0x01,
            0x23, 0x45, 0x67
        ]
    );
    // Register 0 is (SCON << 8) | SPOS: big-endian words, FHPP byte k = data byte k.
    assert_eq!(u16::from_be_bytes([resp[9], resp[10]]), 0x1004);
    assert_eq!(
        dev.lock().unwrap().outputs.last(),
        Some(&[0x23, 0x01, 0, 0, 0, 0, 0, 0])
    );
}

#[test]
fn fc10_then_fc03_reads_status_not_the_control_image() {
    let (server, dev) = start(Config::default());
    let mut c = connect(server.local_addr());
    let resp = transact(
        &mut c,
        &[
            0x00, 0x07, 0x00, 0x00, 0x00, 0x0F, 0x05, 0x10, 0x00, 0x00, 0x00, 0x04, 0x08, 0x03,
            0x02, 0x2A, 0x00, 0x00, 0x00, 0x00, 0x00,
        ],
    );
    // Unit id 0x05 is ignored and echoed.
    assert_eq!(
        resp,
        [
            0x00, 0x07, 0x00, 0x00, 0x00, 0x06, 0x05, 0x10, 0x00, 0x00, 0x00, 0x04
        ]
    );
    let resp = transact(
        &mut c,
        &[
            0x00, 0x08, 0x00, 0x00, 0x00, 0x06, 0x00, 0x03, 0x00, 0x00, 0x00, 0x04,
        ],
    );
    assert_eq!(
        resp,
        [
            0x00, 0x08, 0x00, 0x00, 0x00, 0x0B, 0x00, 0x03, 0x08, 0x10, 0x04, 0x2A, 0x00, 0x01,
            0x23, 0x45, 0x67
        ]
    );
    // The read presented the latched control image again, and only that.
    let d = dev.lock().unwrap();
    assert_eq!(d.outputs.len(), 2);
    assert!(
        d.outputs
            .iter()
            .all(|o| o == &[0x03, 0x02, 0x2A, 0, 0, 0, 0, 0])
    );
}

#[test]
fn fc17_with_fpc_profile_carries_16_bytes() {
    let (server, _dev) = start(Config {
        profile: Profile::FhppFpc,
        ..Config::default()
    });
    let mut c = connect(server.local_addr());
    let mut req = vec![
        0x00, 0x02, 0x00, 0x00, 0x00, 0x1B, 0x00, 0x17, 0x00, 0x00, 0x00, 0x08, 0x00, 0x00, 0x00,
        0x08, 0x10,
    ];
    req.extend_from_slice(&[0x23, 0x01, 0x04, 0, 0, 0, 0, 0]);
    req.extend_from_slice(&[0x16, 0x00, 0x91, 0x01, 0, 0, 0, 0]);
    let resp = transact(&mut c, &req);
    let mut want = vec![0x00, 0x02, 0x00, 0x00, 0x00, 0x13, 0x00, 0x17, 0x10];
    want.extend_from_slice(&[0x10, 0x04, 0x04, 0x00, 0x01, 0x23, 0x45, 0x67]);
    want.extend_from_slice(&[0x96, 0x00, 0x91, 0x01, 0, 0, 0, 0]);
    assert_eq!(resp, want);
}

#[test]
fn fc07_reports_the_fault_number() {
    let (server, dev) = start(Config::default());
    let mut c = connect(server.local_addr());
    let req = [0x12, 0x34, 0x00, 0x00, 0x00, 0x02, 0x00, 0x07];
    assert_eq!(
        transact(&mut c, &req),
        [0x12, 0x34, 0x00, 0x00, 0x00, 0x03, 0x00, 0x07, 0x00]
    );
    dev.lock().unwrap().fault = 0x2F; // following error
    assert_eq!(
        transact(&mut c, &req),
        [0x12, 0x34, 0x00, 0x00, 0x00, 0x03, 0x00, 0x07, 0x2F]
    );
}

#[test]
fn fc2b_reads_basic_and_regular_identification() {
    let (server, _dev) = start(Config::default());
    let mut c = connect(server.local_addr());
    let resp = transact(
        &mut c,
        &[
            0x00, 0x03, 0x00, 0x00, 0x00, 0x05, 0x00, 0x2B, 0x0E, 0x01, 0x00,
        ],
    );
    let mut pdu = vec![0x2B, 0x0E, 0x01, 0x01, 0x00, 0x00, 0x03];
    pdu.extend_from_slice(b"\x00\x11Festo AG & Co. KG");
    pdu.extend_from_slice(b"\x01\x10CMMO-ST-C5-1-LKP");
    pdu.extend_from_slice(b"\x02\x071.4.0.0");
    let mut want = vec![0x00, 0x03, 0x00, 0x00, 0x00, (pdu.len() + 1) as u8, 0x00];
    want.extend_from_slice(&pdu);
    assert_eq!(resp, want);

    let resp = transact(
        &mut c,
        &[
            0x00, 0x04, 0x00, 0x00, 0x00, 0x05, 0x00, 0x2B, 0x0E, 0x02, 0x00,
        ],
    );
    let mut pdu = vec![0x2B, 0x0E, 0x02, 0x02, 0x00, 0x00, 0x06];
    pdu.extend_from_slice(b"\x00\x11Festo AG & Co. KG");
    pdu.extend_from_slice(b"\x01\x10CMMO-ST-C5-1-LKP");
    pdu.extend_from_slice(b"\x02\x071.4.0.0");
    pdu.extend_from_slice(b"\x03\x14http://www.festo.com");
    pdu.extend_from_slice(b"\x04\x10CMMO-ST-C5-1-LKP");
    pdu.extend_from_slice(b"\x06\x06line 3");
    assert_eq!(&resp[7..], &pdu[..]);
}

#[test]
fn bad_requests_get_the_devices_exception_codes() {
    let (server, _dev) = start(Config::default());
    let mut c = connect(server.local_addr());
    let cases: [(&[u8], [u8; 2]); 6] = [
        // FC 0x03 start 0x0001: illegal data address.
        (
            &[0x00, 0x00, 0x00, 0x06, 0x00, 0x03, 0x00, 0x01, 0x00, 0x04],
            [0x83, 0x02],
        ),
        // FC 0x03 quantity 8 with the 8-byte profile: illegal data value.
        (
            &[0x00, 0x00, 0x00, 0x06, 0x00, 0x03, 0x00, 0x00, 0x00, 0x08],
            [0x83, 0x03],
        ),
        // FC 0x10 byte count 6 for 4 registers: illegal data value.
        (
            &[
                0x00, 0x00, 0x00, 0x0D, 0x00, 0x10, 0x00, 0x00, 0x00, 0x04, 0x06, 0, 0, 0, 0, 0, 0,
            ],
            [0x90, 0x03],
        ),
        // FC 0x17 read start 4: illegal data address.
        (
            &[
                0x00, 0x00, 0x00, 0x13, 0x00, 0x17, 0x00, 0x04, 0x00, 0x04, 0x00, 0x00, 0x00, 0x04,
                0x08, 0, 0, 0, 0, 0, 0, 0, 0,
            ],
            [0x97, 0x02],
        ),
        // FC 0x01 read coils: illegal function.
        (
            &[0x00, 0x00, 0x00, 0x06, 0x00, 0x01, 0x00, 0x00, 0x00, 0x01],
            [0x81, 0x01],
        ),
        // FC 0x2B with read device ID code 0x03 (extended): illegal data value.
        (
            &[0x00, 0x00, 0x00, 0x05, 0x00, 0x2B, 0x0E, 0x03, 0x00],
            [0xAB, 0x03],
        ),
    ];
    for (i, (tail, exc)) in cases.iter().enumerate() {
        let mut req = vec![0x00, i as u8];
        req.extend_from_slice(tail);
        let resp = transact(&mut c, &req);
        assert_eq!(
            resp,
            [0x00, i as u8, 0x00, 0x00, 0x00, 0x03, 0x00, exc[0], exc[1]],
            "case {i}"
        );
    }
    // The connection stays usable after exceptions.
    assert_eq!(transact(&mut c, &DIGEST_0X17)[7], 0x17);
    assert_eq!(server.stats().exceptions, 6);
}

#[test]
fn frames_split_and_joined_by_tcp_are_answered_in_order() {
    let (server, _dev) = start(Config::default());
    let mut c = connect(server.local_addr());
    c.write_all(&DIGEST_0X17[..10]).unwrap();
    std::thread::sleep(Duration::from_millis(5));
    // The rest of the first frame and a whole second one in one write.
    let mut tail = DIGEST_0X17[10..].to_vec();
    tail.extend_from_slice(&[0x00, 0x09, 0x00, 0x00, 0x00, 0x02, 0x00, 0x07]);
    c.write_all(&tail).unwrap();
    assert_eq!(read_adu(&mut c)[..2], [0x00, 0x01]);
    assert_eq!(
        read_adu(&mut c),
        [0x00, 0x09, 0x00, 0x00, 0x00, 0x03, 0x00, 0x07, 0x00]
    );
}

#[test]
fn an_impossible_mbap_length_closes_the_connection() {
    let (server, _dev) = start(Config::default());
    let mut c = connect(server.local_addr());
    c.write_all(&[0x00, 0x01, 0x00, 0x00, 0x01, 0x00, 0x00, 0x03])
        .unwrap();
    assert!(closed_by_server(&mut c));
    wait_until(|| !server.is_connected());
}

#[test]
fn a_second_client_is_closed_and_the_first_keeps_working() {
    let (server, dev) = start(Config::default());
    let mut first = connect(server.local_addr());
    assert_eq!(transact(&mut first, &DIGEST_0X17)[7], 0x17);
    let mut second = connect(server.local_addr());
    assert!(
        closed_by_server(&mut second),
        "the second connection is closed"
    );
    wait_until(|| server.stats().refused == 1);
    assert_eq!(transact(&mut first, &DIGEST_0X17)[7], 0x17);
    assert_eq!(dev.lock().unwrap().established, 1);
}

#[test]
fn a_client_that_disconnects_lets_the_next_one_in() {
    let (server, dev) = start(Config::default());
    let mut first = connect(server.local_addr());
    assert_eq!(transact(&mut first, &DIGEST_0X17)[7], 0x17);
    drop(first);
    wait_until(|| !server.is_connected());
    let mut next = connect(server.local_addr());
    assert_eq!(transact(&mut next, &DIGEST_0X17)[7], 0x17);
    assert_eq!(server.stats().connections, 2);
    assert_eq!(server.stats().refused, 0);
    assert_eq!(dev.lock().unwrap().established, 2);
    // With the timeout off nothing is raised.
    assert!(dev.lock().unwrap().lost.is_empty());
}

#[test]
fn node_guard_timeout_raises_47h_and_closes_the_connection() {
    // 250 ms, so a loaded machine's late sleeps below cannot starve the guard.
    let (server, dev) = start(Config {
        timeout: node_guard_timeout(250).unwrap(),
        ..Config::default()
    });
    let mut c = connect(server.local_addr());
    // A client that keeps talking (every 20 ms, 10 times) is not cut off.
    for _ in 0..10 {
        assert_eq!(transact(&mut c, &DIGEST_0X17)[7], 0x17);
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(dev.lock().unwrap().lost.is_empty());
    // Then it goes silent: the device raises 47h and drops the connection.
    let t0 = std::time::Instant::now();
    assert!(closed_by_server(&mut c));
    assert!(
        t0.elapsed() >= Duration::from_millis(150),
        "not before the timeout"
    );
    assert_eq!(
        dev.lock().unwrap().lost,
        vec![ConnectionLost::WithMasterControl]
    );
    assert_eq!(server.stats().timeouts, 1);
    // A new client can connect and read the fault through FC 0x07.
    wait_until(|| !server.is_connected());
    let mut c = connect(server.local_addr());
    let resp = transact(&mut c, &[0x00, 0x01, 0x00, 0x00, 0x00, 0x02, 0x00, 0x07]);
    assert_eq!(resp[8], 0x47);
}

#[test]
fn node_guard_without_master_control_raises_48h() {
    let (server, dev) = start(Config {
        timeout: node_guard_timeout(100).unwrap(),
        ..Config::default()
    });
    dev.lock().unwrap().foreign_control = true;
    // Connects and never says anything: the connection itself armed the guard.
    let mut c = connect(server.local_addr());
    assert!(closed_by_server(&mut c));
    assert_eq!(
        dev.lock().unwrap().lost,
        vec![ConnectionLost::WithoutMasterControl]
    );
    assert_eq!(ConnectionLost::WithoutMasterControl.number(), 0x48);
}

#[test]
fn shutdown_stops_the_server_and_frees_the_port() {
    let (server, _dev) = start(Config::default());
    let addr = server.local_addr();
    let mut c = connect(addr);
    assert_eq!(transact(&mut c, &DIGEST_0X17)[7], 0x17);
    let stats = server.shutdown();
    assert_eq!(stats.responses, 1);
    assert!(closed_by_server(&mut c));
    assert!(TcpStream::connect_timeout(&addr, Duration::from_millis(200)).is_err());
}
