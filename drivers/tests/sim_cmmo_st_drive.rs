//! The CMMO-ST simulator proper (the FHPP drive model behind the Modbus TCP server) over real
//! loopback TCP: enabling through FC 17h with the manual's bytes, and the node-guard timeout
//! raising 47h, reported by FC 07h and acknowledged.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivers::sim::cmmo_st::{Config, Server, ServerConfig, drive};

fn transact(s: &mut TcpStream, req: &[u8]) -> Vec<u8> {
    s.write_all(req).unwrap();
    let mut head = [0u8; 6];
    s.read_exact(&mut head).unwrap();
    let len = u16::from_be_bytes([head[4], head[5]]) as usize;
    let mut rest = vec![0u8; len];
    s.read_exact(&mut rest).unwrap();
    [&head[..], &rest[..]].concat()
}

/// FC 17h: write the 8 FHPP output bytes, read the 8 input bytes.
fn fc17(s: &mut TcpStream, tid: u16, out: [u8; 8]) -> [u8; 8] {
    let t = tid.to_be_bytes();
    let mut req = vec![
        t[0], t[1], 0, 0, 0, 0x13, 0, 0x17, 0, 0, 0, 4, 0, 0, 0, 4, 8,
    ];
    req.extend_from_slice(&out);
    let resp = transact(s, &req);
    assert_eq!(resp[7], 0x17, "not an exception: {resp:02X?}");
    resp[9..17].try_into().unwrap()
}

fn fc07(s: &mut TcpStream) -> u8 {
    let resp = transact(s, &[0, 9, 0, 0, 0, 2, 0, 0x07]);
    assert_eq!(resp[7], 0x07);
    resp[8]
}

fn start(timeout_ms: Option<u64>) -> Server {
    let dev = Arc::new(Mutex::new(drive::new_drive().unwrap()));
    let mut cfg = ServerConfig::loopback(0);
    cfg.modbus = Config {
        timeout: timeout_ms.map(Duration::from_millis),
        ..Config::default()
    };
    cfg.tick = Duration::from_millis(1);
    Server::spawn(cfg, dev).unwrap()
}

fn connect(server: &Server) -> TcpStream {
    let s = TcpStream::connect(server.local_addr()).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(3))).unwrap();
    s
}

/// Repeats the exchange until the input bytes satisfy `f` (the drive works at its own cycle).
fn until(s: &mut TcpStream, out: [u8; 8], f: impl Fn(&[u8; 8]) -> bool) -> [u8; 8] {
    for i in 0..500u16 {
        let inp = fc17(s, 100 + i, out);
        if f(&inp) {
            return inp;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    panic!("condition never met");
}

#[test]
fn enable_through_fc17_with_the_manual_bytes() {
    let server = start(None);
    let mut c = connect(&server);
    // The power-on status values of the digest: SCON 10h, SPOS 04h.
    let inp = fc17(&mut c, 1, [0; 8]);
    assert_eq!(&inp[..2], &[0x10, 0x04]);
    // CCON = ENABLE | STOP (03h), CPOS = HALT (01h): operation enabled, SCON.ENABLED | OPEN.
    let inp = until(&mut c, [0x03, 0x01, 0, 0, 0, 0, 0, 0], |i| {
        i[0] & 0x03 == 0x03
    });
    assert_eq!(inp[0] & 0x08, 0, "no fault");
}

#[test]
fn node_guard_timeout_raises_47h_and_it_can_be_acknowledged() {
    let server = start(Some(100));
    let mut c = connect(&server);
    until(&mut c, [0x03, 0x01, 0, 0, 0, 0, 0, 0], |i| {
        i[0] & 0x03 == 0x03
    });
    assert_eq!(fc07(&mut c), 0);
    // Fall silent: after 100 ms the device raises 47h (Modbus held master control) and the
    // server closes the connection.
    std::thread::sleep(Duration::from_millis(400));
    drop(c);
    let mut c = connect(&server);
    assert_eq!(fc07(&mut c), 0x47);
    let inp = fc17(&mut c, 2, [0x03, 0x01, 0, 0, 0, 0, 0, 0]);
    assert_ne!(inp[0] & 0x08, 0, "SCON.FAULT");
    // Acknowledge: ENABLE off with a RESET edge (CCON.RESET = 08h), then enable again.
    until(&mut c, [0x02, 0x01, 0, 0, 0, 0, 0, 0], |_| true);
    until(&mut c, [0x0A, 0x01, 0, 0, 0, 0, 0, 0], |i| i[0] & 0x08 == 0);
    assert_eq!(fc07(&mut c), 0);
}

/// The coordinator streams targets as STARTs while moving, which only a drive commissioned with
/// PNU 583 = 1 follows; the factory drive keeps 0 (ignore such a START).
#[test]
fn commissioned_drive_takes_a_start_while_moving() {
    let pnu = drive::PNU_DIRECT_START_CONDITION;
    assert_eq!(drive::new_drive().unwrap().read_pnu(pnu, 1), Ok(0));
    assert_eq!(drive::commissioned().unwrap().read_pnu(pnu, 1), Ok(1));
}
