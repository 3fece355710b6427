//! Client and server exchanging real frames in-process, and the TLC5xx manual's byte sequences.

extern crate std;
use std::vec::Vec;

use super::codec::{ClientFrame, ServerFrame};
use super::*;
use crate::can::Frame;
use crate::canopen::od::ObjectAccess;
use crate::canopen::{AbortCode, Address, NodeId};
use crate::time::Instant;
use core::time::Duration;

const DEVICE_TYPE: Address = Address::new(0x1000, 0);
const MODE: Address = Address::new(0x6060, 0);
const ACCEL: Address = Address::new(0x6083, 0);
const RPDO2: Address = Address::new(0x1401, 1);
const DOMAIN_RO: Address = Address::new(0x2000, 1);
const DOMAIN_RW: Address = Address::new(0x2000, 2);
const MISSING: Address = Address::new(0x3000, 0);

/// A few objects: U32 and U8 variables, a 1 KiB read-only DOMAIN, a 4 KiB writable DOMAIN.
struct TestOd {
    accel: u32,
    rpdo2: u32,
    mode: u8,
    domain_ro: [u8; 1024],
    domain_rw: Vec<u8>,
}

impl TestOd {
    fn new() -> Self {
        TestOd {
            accel: 0,
            rpdo2: 0x8000_0301,
            mode: 0,
            domain_ro: core::array::from_fn(|i| (i * 7 + i / 256) as u8),
            domain_rw: Vec::new(),
        }
    }
    fn value(&self, addr: Address) -> Result<Vec<u8>, AbortCode> {
        Ok(match addr {
            DEVICE_TYPE => 0x0002_0192u32.to_le_bytes().to_vec(),
            ACCEL => self.accel.to_le_bytes().to_vec(),
            RPDO2 => self.rpdo2.to_le_bytes().to_vec(),
            MODE => std::vec![self.mode],
            DOMAIN_RO => self.domain_ro.to_vec(),
            DOMAIN_RW => self.domain_rw.clone(),
            _ => return Err(AbortCode::NoObject),
        })
    }
}

impl ObjectAccess for TestOd {
    fn size(&self, addr: Address) -> Result<usize, AbortCode> {
        self.value(addr).map(|v| v.len())
    }
    fn read(&mut self, addr: Address, offset: usize, buf: &mut [u8]) -> Result<usize, AbortCode> {
        let v = self.value(addr)?;
        let rest = v.get(offset..).unwrap_or(&[]);
        let n = rest.len().min(buf.len());
        buf[..n].copy_from_slice(&rest[..n]);
        Ok(n)
    }
    fn write(&mut self, addr: Address, data: &[u8]) -> Result<(), AbortCode> {
        let u32_of = |d: &[u8]| -> Result<u32, AbortCode> {
            let a: [u8; 4] = d.try_into().map_err(|_| AbortCode::TypeMismatch)?;
            Ok(u32::from_le_bytes(a))
        };
        match addr {
            DEVICE_TYPE | DOMAIN_RO => Err(AbortCode::ReadOnly),
            ACCEL => {
                self.accel = u32_of(data)?;
                Ok(())
            }
            RPDO2 => {
                self.rpdo2 = u32_of(data)?;
                Ok(())
            }
            MODE => match data {
                [m] => {
                    self.mode = *m;
                    Ok(())
                }
                _ => Err(AbortCode::TypeMismatch),
            },
            DOMAIN_RW if data.len() > 4096 => Err(AbortCode::TooLong),
            DOMAIN_RW => {
                self.domain_rw = data.to_vec();
                Ok(())
            }
            _ => Err(AbortCode::NoObject),
        }
    }
}

fn node() -> NodeId {
    NodeId::new(1).unwrap()
}

/// A client and a server joined by a lossless (or deliberately lossy) in-process link.
struct Link {
    client: SdoClient<4, 4096>,
    server: SdoServer<4096>,
    od: TestOd,
    now: Instant,
    /// Every frame exchanged, in order: (client to server?, frame).
    log: Vec<(bool, Frame)>,
    /// Indices (in client-sent order) of client frames to drop.
    drop_c2s: Vec<usize>,
    /// Indices (in server-sent order) of server frames to drop.
    drop_s2c: Vec<usize>,
    c2s: usize,
    s2c: usize,
}

impl Link {
    fn new() -> Self {
        Link::with(SdoClientConfig::default(), SdoServerConfig::default())
    }
    fn with(cc: SdoClientConfig, sc: SdoServerConfig) -> Self {
        Link {
            client: SdoClient::new(node(), cc),
            server: SdoServer::new(node(), sc),
            od: TestOd::new(),
            now: Instant::from_millis(1),
            log: Vec::new(),
            drop_c2s: Vec::new(),
            drop_s2c: Vec::new(),
            c2s: 0,
            s2c: 0,
        }
    }
    /// Moves frames both ways until neither side has anything to send.
    fn run(&mut self) {
        loop {
            let mut moved = false;
            while let Some(f) = self.client.poll_transmit(self.now) {
                moved = true;
                self.log.push((true, f));
                if !self.drop_c2s.contains(&self.c2s) {
                    self.server.handle_frame(&f, self.now, &mut self.od);
                }
                self.c2s += 1;
            }
            while let Some(f) = self.server.poll_transmit(self.now) {
                moved = true;
                self.log.push((false, f));
                if !self.drop_s2c.contains(&self.s2c) {
                    self.client.handle_frame(&f, self.now);
                }
                self.s2c += 1;
            }
            if !moved {
                break;
            }
            self.now += Duration::from_micros(100);
        }
    }
    /// Runs until stuck, then lets time pass to the earliest deadline, until `ms` passed.
    fn run_with_time(&mut self, ms: u64) {
        let end = self.now + Duration::from_millis(ms);
        loop {
            self.run();
            let next = [self.client.poll_timeout(), self.server.poll_timeout()]
                .into_iter()
                .flatten()
                .min();
            match next {
                Some(t) if t <= end => {
                    self.now = self.now.max(t);
                    self.client.handle_timeout(self.now);
                    self.server.handle_timeout(self.now);
                }
                _ => break,
            }
        }
    }
    fn server_sent(&self) -> impl Iterator<Item = [u8; 8]> + '_ {
        self.log.iter().filter(|(c, _)| !c).map(|(_, f)| f.data8())
    }
    fn client_sent(&self) -> impl Iterator<Item = [u8; 8]> + '_ {
        self.log.iter().filter(|(c, _)| *c).map(|(_, f)| f.data8())
    }
}

fn data(n: usize, seed: u8) -> Vec<u8> {
    (0..n)
        .map(|i| {
            (i as u8)
                .wrapping_mul(31)
                .wrapping_add(seed ^ (i >> 8) as u8)
        })
        .collect()
}

fn take_upload(c: &mut SdoClient<4, 4096>) -> (RequestId, Vec<u8>) {
    let e = c.poll_event().expect("an event");
    match e.outcome {
        Ok(Completion::Uploaded(d)) => (e.id, d.to_vec()),
        other => panic!("expected an upload, got {other:?}"),
    }
}

fn sframe(b: [u8; 8]) -> Frame {
    Frame::std8(0x601, b)
}
fn cframe(b: [u8; 8]) -> Frame {
    Frame::std8(0x581, b)
}

/// Feeds one frame to a server and returns its single reply.
fn ask(server: &mut SdoServer<4096>, od: &mut TestOd, req: [u8; 8]) -> Option<[u8; 8]> {
    server.handle_frame(&sframe(req), Instant::ZERO, od);
    let r = server.poll_transmit(Instant::ZERO).map(|f| f.data8());
    assert_eq!(server.poll_transmit(Instant::ZERO), None);
    r
}

#[test]
fn segmented_upload_of_1k_domain() {
    let mut l = Link::new();
    let id = l.client.upload(DOMAIN_RO).unwrap();
    l.run();
    let (got, d) = take_upload(&mut l.client);
    assert_eq!(got, id);
    assert_eq!(d, l.od.domain_ro.to_vec());
    // Initiate response announces 1024 bytes, then ceil(1024 / 7) = 147 segments.
    let srv: Vec<_> = l.server_sent().collect();
    assert_eq!(srv[0], [0x41, 0x00, 0x20, 0x01, 0x00, 0x04, 0x00, 0x00]);
    let segments = srv.iter().filter(|b| b[0] >> 5 == 0).count();
    assert_eq!(segments, 147);
    // The last segment carries 1024 - 146 * 7 = 2 bytes: n = 5, c = 1; toggle of segment 147 is 0.
    assert_eq!(srv.last().unwrap()[0], (5 << 1) | 1);
    assert_eq!(
        l.server.poll_event(),
        Some(ServerEvent::Uploaded {
            addr: DOMAIN_RO,
            len: 1024
        })
    );
    assert!(l.client.is_idle() && l.server.is_idle());
}

#[test]
fn block_download_of_4k_with_crc() {
    let mut l = Link::new();
    let value = data(4096, 3);
    let id = l
        .client
        .download(DOMAIN_RW, &value, DownloadMode::Block)
        .unwrap();
    l.run();
    let e = l.client.poll_event().unwrap();
    assert_eq!(
        (e.id, e.addr, e.outcome),
        (id, DOMAIN_RW, Ok(Completion::Downloaded))
    );
    assert_eq!(l.od.domain_rw, value);
    // 586 segments in sub-blocks of 127: 5 acknowledges.
    let acks: Vec<_> = l.server_sent().filter(|b| b[0] == 0xA2).collect();
    assert_eq!(acks.len(), 5);
    assert_eq!(acks.iter().map(|a| a[1] as usize).sum::<usize>(), 586);
    // Initiate, 586 segments, end: no segment was sent twice.
    assert_eq!(l.client_sent().count(), 588);
    let first = l.client_sent().next().unwrap();
    assert_eq!(first, [0xC6, 0x00, 0x20, 0x02, 0x00, 0x10, 0x00, 0x00]);
    // End: n = 586 * 7 - 4096 = 6, CRC of the value.
    let end = l.client_sent().find(|b| b[0] & 0xE3 == 0xC1).unwrap();
    assert_eq!(end[0], 0xC1 | (6 << 2));
    assert_eq!(u16::from_le_bytes([end[1], end[2]]), crc16(&value));
    assert_eq!(l.server_sent().last().unwrap()[0], 0xA1);
    assert_eq!(
        l.server.poll_event(),
        Some(ServerEvent::Downloaded {
            addr: DOMAIN_RW,
            len: 4096
        })
    );
}

#[test]
fn block_upload_of_1k_domain() {
    let mut l = Link::new();
    let id = l.client.upload_block(DOMAIN_RO).unwrap();
    l.run();
    let (got, d) = take_upload(&mut l.client);
    assert_eq!(got, id);
    assert_eq!(d, l.od.domain_ro.to_vec());
    let srv: Vec<_> = l.server_sent().collect();
    assert_eq!(srv[0], [0xC6, 0x00, 0x20, 0x01, 0x00, 0x04, 0x00, 0x00]);
    // 147 segments: one sub-block of 127, one of 20.
    let acks: Vec<_> = l.client_sent().filter(|b| b[0] == 0xA2).collect();
    assert_eq!(acks.len(), 2);
    assert_eq!((acks[0][1], acks[1][1]), (127, 20));
    let end = srv.last().unwrap();
    assert_eq!(end[0], 0xC1 | (5 << 2));
    assert_eq!(u16::from_le_bytes([end[1], end[2]]), crc16(&l.od.domain_ro));
    assert_eq!(l.client_sent().last().unwrap()[0], 0xA1);
    assert_eq!(
        l.server.poll_event(),
        Some(ServerEvent::Uploaded {
            addr: DOMAIN_RO,
            len: 1024
        })
    );
}

#[test]
fn block_download_recovers_a_lost_segment() {
    let mut l = Link::new();
    let value = data(2000, 9);
    // Client frame 0 is the initiate; frame 11 is segment 11 of the first sub-block.
    l.drop_c2s.push(11);
    l.client
        .download(DOMAIN_RW, &value, DownloadMode::Block)
        .unwrap();
    l.run();
    assert_eq!(
        l.client.poll_event().unwrap().outcome,
        Ok(Completion::Downloaded)
    );
    assert_eq!(l.od.domain_rw, value);
    let acks: Vec<_> = l.server_sent().filter(|b| b[0] == 0xA2).collect();
    // The first acknowledge confirms segments 1..=10 only; the client resends from 11.
    assert_eq!(acks[0][1], 10);
    let resent = l.client_sent().filter(|b| b[0] == 1).nth(1).unwrap();
    assert_eq!(&resent[1..], &value[70..77]);
}

#[test]
fn block_download_recovers_a_lost_last_segment_of_sub_block() {
    let mut l = Link::new();
    let value = data(1500, 1);
    l.drop_c2s.push(127); // segment 127: the server never sees the end of the sub-block
    l.client
        .download(DOMAIN_RW, &value, DownloadMode::Block)
        .unwrap();
    l.run_with_time(1000);
    assert_eq!(
        l.client.poll_event().unwrap().outcome,
        Ok(Completion::Downloaded)
    );
    assert_eq!(l.od.domain_rw, value);
    assert_eq!(l.server_sent().find(|b| b[0] == 0xA2).unwrap()[1], 126);
}

#[test]
fn block_upload_recovers_a_lost_segment() {
    let mut l = Link::new();
    l.drop_s2c.push(30); // server frame 0 is the initiate response, 30 is segment 30
    l.client.upload_block(DOMAIN_RO).unwrap();
    l.run();
    let (_, d) = take_upload(&mut l.client);
    assert_eq!(d, l.od.domain_ro.to_vec());
    let acks: Vec<_> = l.client_sent().filter(|b| b[0] == 0xA2).collect();
    assert_eq!(acks[0][1], 29);
}

#[test]
fn block_upload_recovers_a_lost_last_segment_of_sub_block() {
    let mut l = Link::new();
    l.drop_s2c.push(127); // segment 127: the client never sees the end of the sub-block
    l.client.upload_block(DOMAIN_RO).unwrap();
    l.run_with_time(1000);
    let (_, d) = take_upload(&mut l.client);
    assert_eq!(d, l.od.domain_ro.to_vec());
    assert_eq!(l.client_sent().find(|b| b[0] == 0xA2).unwrap()[1], 126);
}

#[test]
fn block_upload_server_follows_a_shrinking_block_size() {
    let mut s: SdoServer<4096> = SdoServer::new(node(), SdoServerConfig::default());
    let mut od = TestOd::new();
    let t = Instant::ZERO;
    assert_eq!(
        ask(&mut s, &mut od, [0xA4, 0x00, 0x20, 0x01, 10, 0, 0, 0]).unwrap()[0],
        0xC6
    );
    s.handle_frame(&sframe([0xA3, 0, 0, 0, 0, 0, 0, 0]), t, &mut od);
    let first: Vec<_> = core::iter::from_fn(|| s.poll_transmit(t)).collect();
    assert_eq!(first.len(), 10);
    // Only 2 segments arrived; the next sub-block may hold 3.
    s.handle_frame(&sframe([0xA2, 2, 3, 0, 0, 0, 0, 0]), t, &mut od);
    let next: Vec<_> = core::iter::from_fn(|| s.poll_transmit(t)).collect();
    assert_eq!(next.len(), 3);
    for (i, f) in next.iter().enumerate() {
        assert_eq!(f.data()[0], i as u8 + 1);
        assert_eq!(&f.data()[1..], &od.domain_ro[14 + 7 * i..21 + 7 * i]);
    }
    assert_eq!(s.poll_timeout(), Some(t + Duration::from_millis(500)));
}

#[test]
fn crc_mismatch_aborts() {
    let mut s: SdoServer<4096> = SdoServer::new(node(), SdoServerConfig::default());
    let mut od = TestOd::new();
    assert_eq!(
        ask(&mut s, &mut od, [0xC6, 0x00, 0x20, 0x02, 3, 0, 0, 0]).unwrap()[0],
        0xA4
    );
    assert_eq!(
        ask(&mut s, &mut od, [0x81, 1, 2, 3, 0, 0, 0, 0]),
        Some([0xA2, 1, 127, 0, 0, 0, 0, 0])
    );
    let good = crc16(&[1, 2, 3]);
    let bad = (good ^ 1).to_le_bytes();
    let r = ask(
        &mut s,
        &mut od,
        [0xC1 | (4 << 2), bad[0], bad[1], 0, 0, 0, 0, 0],
    )
    .unwrap();
    assert_eq!(r, [0x80, 0x00, 0x20, 0x02, 0x04, 0x00, 0x04, 0x05]);
    assert!(od.domain_rw.is_empty());
}

#[test]
fn abort_on_missing_object() {
    let mut l = Link::new();
    let id = l.client.upload(MISSING).unwrap();
    l.run();
    assert_eq!(
        l.server_sent().next().unwrap(),
        [0x80, 0x00, 0x30, 0x00, 0x00, 0x00, 0x02, 0x06]
    );
    let e = l.client.poll_event().unwrap();
    assert_eq!(e.id, id);
    assert_eq!(
        e.outcome,
        Err(SdoError::Aborted {
            code: AbortCode::NoObject,
            by: AbortedBy::Server
        })
    );
    // Downloads of a missing object are refused at the initiate, for every mode.
    for mode in [
        DownloadMode::Expedited,
        DownloadMode::Segmented,
        DownloadMode::Block,
    ] {
        l.client.download(MISSING, &[1, 2], mode).unwrap();
        l.run();
        let e = l.client.poll_event().unwrap();
        assert_eq!(
            e.outcome,
            Err(SdoError::Aborted {
                code: AbortCode::NoObject,
                by: AbortedBy::Server
            }),
            "{mode:?}"
        );
    }
}

#[test]
fn timeout_sends_abort_and_reports() {
    let mut c: SdoClient<2, 64> = SdoClient::new(node(), SdoClientConfig::default());
    let t0 = Instant::from_millis(10);
    let id = c.upload(Address::new(0x6064, 0)).unwrap();
    assert!(c.poll_transmit(t0).is_some());
    assert_eq!(c.poll_timeout(), Some(t0 + Duration::from_millis(500)));
    c.handle_timeout(t0 + Duration::from_millis(499));
    assert!(c.poll_transmit(t0).is_none());
    assert!(c.poll_event().is_none());
    c.handle_timeout(t0 + Duration::from_millis(500));
    let abort = c.poll_transmit(t0 + Duration::from_millis(500)).unwrap();
    assert_eq!(abort.cob_id(), Some(0x601));
    assert_eq!(
        abort.data(),
        &[0x80, 0x64, 0x60, 0x00, 0x00, 0x00, 0x04, 0x05]
    );
    let e = c.poll_event().unwrap();
    assert_eq!(
        (e.id, e.outcome),
        (id, Err(SdoError::Timeout { timeout_ms: 500 }))
    );
    assert_eq!(c.poll_timeout(), None);
    // A per-request timeout overrides the default.
    c.upload_with(
        Address::new(0x6064, 0),
        UploadMode::Normal,
        Some(Duration::from_millis(20)),
    )
    .unwrap();
    c.poll_transmit(t0).unwrap();
    assert_eq!(c.poll_timeout(), Some(t0 + Duration::from_millis(20)));
}

#[test]
fn server_times_out_a_silent_client() {
    let mut s: SdoServer<4096> = SdoServer::new(node(), SdoServerConfig::default());
    let mut od = TestOd::new();
    s.handle_frame(
        &sframe([0x21, 0x00, 0x20, 0x02, 20, 0, 0, 0]),
        Instant::ZERO,
        &mut od,
    );
    assert_eq!(s.poll_transmit(Instant::ZERO).unwrap().data()[0], 0x60);
    let t = s.poll_timeout().unwrap();
    assert_eq!(t, Instant::ZERO + Duration::from_millis(500));
    s.handle_timeout(t);
    assert_eq!(
        s.poll_transmit(t).unwrap().data(),
        &[0x80, 0x00, 0x20, 0x02, 0x00, 0x00, 0x04, 0x05]
    );
    assert!(s.is_idle());
    assert_eq!(
        s.poll_event(),
        Some(ServerEvent::Aborted {
            addr: DOMAIN_RW,
            code: AbortCode::Timeout,
            by: AbortedBy::Server
        })
    );
}

#[test]
fn server_aborts_a_block_download_whose_client_went_silent_mid_sub_block() {
    // Found by the `device` fuzz target: one segment of a sub-block, then silence for longer
    // than the SDO timeout. The server must abort (0504 0000h), not acknowledge the sub-block
    // and wait again, or every later request would be read as a block segment.
    let mut s: SdoServer<4096> = SdoServer::new(node(), SdoServerConfig::default());
    let mut od = TestOd::new();
    s.handle_frame(
        &sframe([0xC0, 0x00, 0x20, 0x02, 0, 0, 0, 0]),
        Instant::ZERO,
        &mut od,
    );
    assert_eq!(s.poll_transmit(Instant::ZERO).unwrap().data()[0], 0xA4);
    s.handle_frame(&sframe([0x01, 1, 2, 3, 4, 5, 6, 7]), Instant::ZERO, &mut od);
    let late = Instant::ZERO + Duration::from_secs(1);
    s.handle_timeout(late);
    assert_eq!(
        s.poll_transmit(late).unwrap().data(),
        &[0x80, 0x00, 0x20, 0x02, 0x00, 0x00, 0x04, 0x05]
    );
    assert!(s.is_idle());
    // Before the full timeout, the same silence is a stalled sub-block: acknowledged.
    let mut s: SdoServer<4096> = SdoServer::new(node(), SdoServerConfig::default());
    s.handle_frame(
        &sframe([0xC0, 0x00, 0x20, 0x02, 0, 0, 0, 0]),
        Instant::ZERO,
        &mut od,
    );
    s.poll_transmit(Instant::ZERO).unwrap();
    s.handle_frame(&sframe([0x01, 1, 2, 3, 4, 5, 6, 7]), Instant::ZERO, &mut od);
    let t = s.poll_timeout().unwrap();
    s.handle_timeout(t);
    assert_eq!(s.poll_transmit(t).unwrap().data()[..2], [0xA2, 1]);
    assert!(!s.is_idle());
}

#[test]
fn toggle_errors_abort_on_both_sides() {
    // Server: the first download segment must have toggle 0.
    let mut s: SdoServer<4096> = SdoServer::new(node(), SdoServerConfig::default());
    let mut od = TestOd::new();
    ask(&mut s, &mut od, [0x21, 0x00, 0x20, 0x02, 9, 0, 0, 0]).unwrap();
    let r = ask(&mut s, &mut od, [0x10, 1, 2, 3, 4, 5, 6, 7]).unwrap();
    assert_eq!(r, [0x80, 0x00, 0x20, 0x02, 0x00, 0x00, 0x03, 0x05]);
    // Client: a server segment with the wrong toggle.
    let mut c: SdoClient<2, 64> = SdoClient::new(node(), SdoClientConfig::default());
    c.upload(DOMAIN_RO).unwrap();
    c.poll_transmit(Instant::ZERO).unwrap();
    c.handle_frame(
        &cframe([0x41, 0x00, 0x20, 0x01, 20, 0, 0, 0]),
        Instant::ZERO,
    );
    assert_eq!(c.poll_transmit(Instant::ZERO).unwrap().data()[0], 0x60);
    c.handle_frame(&cframe([0x10, 1, 2, 3, 4, 5, 6, 7]), Instant::ZERO);
    assert_eq!(
        c.poll_transmit(Instant::ZERO).unwrap().data(),
        &[0x80, 0x00, 0x20, 0x01, 0x00, 0x00, 0x03, 0x05]
    );
    assert_eq!(
        c.poll_event().unwrap().outcome,
        Err(SdoError::Aborted {
            code: AbortCode::ToggleBit,
            by: AbortedBy::Client
        })
    );
}

#[test]
fn unknown_command_specifier() {
    let mut s: SdoServer<4096> = SdoServer::new(node(), SdoServerConfig::default());
    let mut od = TestOd::new();
    let r = ask(&mut s, &mut od, [0xE0, 0x00, 0x10, 0x00, 0, 0, 0, 0]).unwrap();
    assert_eq!(r, [0x80, 0x00, 0x00, 0x00, 0x01, 0x00, 0x04, 0x05]);
    // A command that is valid but not in this state is refused the same way.
    let r = ask(&mut s, &mut od, [0x60, 0, 0, 0, 0, 0, 0, 0]).unwrap();
    assert_eq!(&r[4..], &[0x01, 0x00, 0x04, 0x05]);
    // The server keeps serving.
    assert_eq!(
        ask(&mut s, &mut od, [0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]).unwrap()[0],
        0x43
    );
}

#[test]
fn wrong_dlc_is_ignored_and_reported() {
    let mut s: SdoServer<4096> = SdoServer::new(node(), SdoServerConfig::default());
    let mut od = TestOd::new();
    // TLC §8.5 prints `2F 60 60 00 01` short: a frame of 5 bytes.
    s.handle_frame(
        &Frame::new_std(0x601, &[0x2F, 0x60, 0x60, 0x00, 0x01]).unwrap(),
        Instant::ZERO,
        &mut od,
    );
    assert_eq!(s.poll_transmit(Instant::ZERO), None);
    assert_eq!(s.poll_event(), Some(ServerEvent::Malformed { len: 5 }));
    assert_eq!(od.mode, 0);
    s.handle_frame(
        &Frame::new_std_remote(0x601, 8).unwrap(),
        Instant::ZERO,
        &mut od,
    );
    assert_eq!(s.poll_event(), Some(ServerEvent::Malformed { len: 0 }));
    // Padded to 8 it is served.
    assert_eq!(
        ask(&mut s, &mut od, [0x2F, 0x60, 0x60, 0x00, 0x01, 0, 0, 0]),
        Some([0x60, 0x60, 0x60, 0, 0, 0, 0, 0])
    );
    assert_eq!(od.mode, 1);
    // Frames for other nodes are not ours.
    s.handle_frame(
        &Frame::std8(0x602, [0x40, 0, 0x10, 0, 0, 0, 0, 0]),
        Instant::ZERO,
        &mut od,
    );
    assert_eq!(s.poll_transmit(Instant::ZERO), None);
    // The client ignores a short answer and counts it.
    let mut c: SdoClient<2, 64> = SdoClient::new(node(), SdoClientConfig::default());
    c.upload(DEVICE_TYPE).unwrap();
    c.poll_transmit(Instant::ZERO).unwrap();
    c.handle_frame(
        &Frame::new_std(0x581, &[0x43, 0x00, 0x10]).unwrap(),
        Instant::ZERO,
    );
    assert_eq!(c.ignored_frames(), 1);
    assert!(c.poll_event().is_none());
}

#[test]
fn queue_order_and_queue_full() {
    let mut l = Link::new();
    let a = l.client.upload(DEVICE_TYPE).unwrap();
    let b = l
        .client
        .download(ACCEL, &2000u32.to_le_bytes(), DownloadMode::Auto)
        .unwrap();
    let c = l.client.upload(ACCEL).unwrap();
    let d = l
        .client
        .download(DOMAIN_RW, &data(100, 5), DownloadMode::Segmented)
        .unwrap();
    assert_eq!(
        l.client.upload(MODE),
        Err(RequestError::QueueFull { capacity: 4 })
    );
    assert_eq!(l.client.pending(), 4);
    // One transfer on the wire at a time: the next starts once the previous event is taken.
    l.run();
    assert_eq!(l.client_sent().count(), 1);
    let (id, v) = take_upload(&mut l.client);
    assert_eq!((id, v), (a, 0x0002_0192u32.to_le_bytes().to_vec()));
    l.run();
    let e = l.client.poll_event().unwrap();
    assert_eq!((e.id, e.outcome), (b, Ok(Completion::Downloaded)));
    l.run();
    let (id, v) = take_upload(&mut l.client);
    assert_eq!((id, v), (c, 2000u32.to_le_bytes().to_vec()));
    l.run();
    assert_eq!(l.client.poll_event().unwrap().id, d);
    assert_eq!(l.od.domain_rw, data(100, 5));
    assert!(l.client.is_idle());
    // Data space is shared by queued downloads.
    let mut small: SdoClient<4, 16> = SdoClient::new(node(), SdoClientConfig::default());
    small
        .download(DOMAIN_RW, &[0; 10], DownloadMode::Segmented)
        .unwrap();
    assert_eq!(
        small.download(DOMAIN_RW, &[0; 10], DownloadMode::Segmented),
        Err(RequestError::NoSpace { len: 10, free: 6 })
    );
    assert_eq!(
        small.download(ACCEL, &[0; 5], DownloadMode::Expedited),
        Err(RequestError::NotExpedited { len: 5 })
    );
}

#[test]
fn index_mismatch_in_answer_aborts() {
    let mut c: SdoClient<2, 64> = SdoClient::new(node(), SdoClientConfig::default());
    c.upload(DEVICE_TYPE).unwrap();
    c.poll_transmit(Instant::ZERO).unwrap();
    c.handle_frame(&cframe([0x43, 0x01, 0x10, 0x00, 1, 2, 3, 4]), Instant::ZERO);
    assert_eq!(
        c.poll_transmit(Instant::ZERO).unwrap().data(),
        &[0x80, 0x00, 0x10, 0x00, 0x43, 0x00, 0x04, 0x06]
    );
    let e = c.poll_event().unwrap();
    assert_eq!(
        e.outcome,
        Err(SdoError::Aborted {
            code: AbortCode::ParamIncompatible,
            by: AbortedBy::Client
        })
    );
    // A sub-index mismatch counts too.
    c.download(ACCEL, &[1, 2, 3, 4], DownloadMode::Auto)
        .unwrap();
    c.poll_transmit(Instant::ZERO).unwrap();
    c.handle_frame(&cframe([0x60, 0x83, 0x60, 0x01, 0, 0, 0, 0]), Instant::ZERO);
    assert!(matches!(
        c.poll_event().unwrap().outcome,
        Err(SdoError::Aborted {
            by: AbortedBy::Client,
            ..
        })
    ));
}

#[test]
fn client_accepts_every_legal_upload_variant() {
    let mut c: SdoClient<2, 64> = SdoClient::new(node(), SdoClientConfig::default());
    let t = Instant::ZERO;
    // Expedited without size indication: all four bytes.
    c.upload(DEVICE_TYPE).unwrap();
    c.poll_transmit(t).unwrap();
    c.handle_frame(&cframe([0x42, 0x00, 0x10, 0x00, 9, 8, 7, 6]), t);
    assert_eq!(
        c.poll_event().unwrap().outcome,
        Ok(Completion::Uploaded(&[9, 8, 7, 6]))
    );
    // Expedited with 2 bytes.
    c.upload(DEVICE_TYPE).unwrap();
    c.poll_transmit(t).unwrap();
    c.handle_frame(&cframe([0x4B, 0x00, 0x10, 0x00, 9, 8, 7, 6]), t);
    assert_eq!(
        c.poll_event().unwrap().outcome,
        Ok(Completion::Uploaded(&[9, 8]))
    );
    // Segmented without size.
    c.upload(DOMAIN_RO).unwrap();
    c.poll_transmit(t).unwrap();
    c.handle_frame(&cframe([0x40, 0x00, 0x20, 0x01, 0, 0, 0, 0]), t);
    assert_eq!(c.poll_transmit(t).unwrap().data()[0], 0x60);
    c.handle_frame(&cframe([0x00, 1, 2, 3, 4, 5, 6, 7]), t);
    assert_eq!(c.poll_transmit(t).unwrap().data()[0], 0x70);
    c.handle_frame(&cframe([0x10 | (6 << 1) | 1, 8, 0, 0, 0, 0, 0, 0]), t);
    assert_eq!(c.poll_transmit(t), None);
    assert_eq!(
        c.poll_event().unwrap().outcome,
        Ok(Completion::Uploaded(&[1, 2, 3, 4, 5, 6, 7, 8]))
    );
    // A block upload the server switches to a normal upload (pst).
    let cfg = SdoClientConfig {
        pst: 4,
        ..SdoClientConfig::default()
    };
    let mut l = Link::with(cfg, SdoServerConfig::default());
    l.client.upload_block(DEVICE_TYPE).unwrap();
    l.run();
    assert_eq!(
        take_upload(&mut l.client).1,
        0x0002_0192u32.to_le_bytes().to_vec()
    );
    assert_eq!(l.server_sent().next().unwrap()[0], 0x43);
}

#[test]
fn segmented_download_roundtrip_and_limits() {
    let mut l = Link::new();
    let value = data(4096, 11);
    l.client
        .download(DOMAIN_RW, &value, DownloadMode::Segmented)
        .unwrap();
    l.run();
    assert_eq!(
        l.client.poll_event().unwrap().outcome,
        Ok(Completion::Downloaded)
    );
    assert_eq!(l.od.domain_rw, value);
    assert_eq!(l.client_sent().count(), 1 + 586);
    // The OD's own refusal is forwarded.
    l.client
        .download(DOMAIN_RO, &value[..10], DownloadMode::Segmented)
        .unwrap();
    l.run();
    assert_eq!(
        l.client.poll_event().unwrap().outcome,
        Err(SdoError::Aborted {
            code: AbortCode::ReadOnly,
            by: AbortedBy::Server
        })
    );
    assert_eq!(
        l.server_sent().last().unwrap(),
        [0x80, 0x00, 0x20, 0x01, 0x02, 0x00, 0x01, 0x06]
    );
    // A value larger than the server's buffer is refused at the initiate.
    let mut s: SdoServer<16> = SdoServer::new(node(), SdoServerConfig::default());
    let mut od = TestOd::new();
    s.handle_frame(
        &sframe([0x21, 0x00, 0x20, 0x02, 17, 0, 0, 0]),
        Instant::ZERO,
        &mut od,
    );
    assert_eq!(
        &s.poll_transmit(Instant::ZERO).unwrap().data()[4..],
        &[0x05, 0x00, 0x04, 0x05]
    );
    // Without size indication, the overflow is found while collecting.
    s.handle_frame(
        &sframe([0x20, 0x00, 0x20, 0x02, 0, 0, 0, 0]),
        Instant::ZERO,
        &mut od,
    );
    s.poll_transmit(Instant::ZERO).unwrap();
    s.handle_frame(&sframe([0x00, 1, 2, 3, 4, 5, 6, 7]), Instant::ZERO, &mut od);
    s.poll_transmit(Instant::ZERO).unwrap();
    s.handle_frame(&sframe([0x10, 1, 2, 3, 4, 5, 6, 7]), Instant::ZERO, &mut od);
    s.poll_transmit(Instant::ZERO).unwrap();
    s.handle_frame(&sframe([0x00, 1, 2, 3, 4, 5, 6, 7]), Instant::ZERO, &mut od);
    assert_eq!(
        &s.poll_transmit(Instant::ZERO).unwrap().data()[4..],
        &[0x05, 0x00, 0x04, 0x05]
    );
    // An empty value goes as one segment with n = 7.
    l.client
        .download(DOMAIN_RW, &[], DownloadMode::Auto)
        .unwrap();
    l.run();
    assert_eq!(
        l.client.poll_event().unwrap().outcome,
        Ok(Completion::Downloaded)
    );
    assert!(l.od.domain_rw.is_empty());
}

#[test]
fn empty_and_small_block_transfers() {
    let mut l = Link::new();
    l.client
        .download(DOMAIN_RW, &[], DownloadMode::Block)
        .unwrap();
    l.run();
    assert_eq!(
        l.client.poll_event().unwrap().outcome,
        Ok(Completion::Downloaded)
    );
    assert!(l.od.domain_rw.is_empty());
    l.client.upload_block(DOMAIN_RW).unwrap();
    l.run();
    assert_eq!(take_upload(&mut l.client).1, Vec::<u8>::new());
    l.client
        .download(DOMAIN_RW, &[1, 2, 3, 4, 5, 6, 7], DownloadMode::Block)
        .unwrap();
    l.run();
    assert_eq!(
        l.client.poll_event().unwrap().outcome,
        Ok(Completion::Downloaded)
    );
    l.client.upload_block(DOMAIN_RW).unwrap();
    l.run();
    assert_eq!(take_upload(&mut l.client).1, std::vec![1, 2, 3, 4, 5, 6, 7]);
}

#[test]
fn small_block_size_and_no_crc() {
    let cc = SdoClientConfig {
        block_size: 5,
        crc: false,
        ..SdoClientConfig::default()
    };
    let sc = SdoServerConfig {
        block_size: 3,
        ..SdoServerConfig::default()
    };
    let mut l = Link::with(cc, sc);
    let value = data(300, 2);
    l.client
        .download(DOMAIN_RW, &value, DownloadMode::Block)
        .unwrap();
    l.run();
    assert_eq!(
        l.client.poll_event().unwrap().outcome,
        Ok(Completion::Downloaded)
    );
    assert_eq!(l.od.domain_rw, value);
    // 300 bytes = 43 segments in sub-blocks of 3: 15 acks. Without cc the CRC field is 0.
    assert_eq!(l.server_sent().filter(|b| b[0] == 0xA2).count(), 15);
    let end = l.client_sent().find(|b| b[0] & 0xE3 == 0xC1).unwrap();
    assert_eq!((end[1], end[2]), (0, 0));
    l.client.upload_block(DOMAIN_RW).unwrap();
    l.run();
    assert_eq!(take_upload(&mut l.client).1, value);
    // 43 segments in sub-blocks of the client's 5: 9 acknowledges from the client.
    assert_eq!(l.client_sent().filter(|b| b[0] == 0xA2).count(), 9);
}

#[test]
fn tlc5xx_manual_sequences() {
    let mut s: SdoServer<4096> = SdoServer::new(node(), SdoServerConfig::default());
    let mut od = TestOd::new();
    // §8.1: read 1000h.
    assert_eq!(
        ask(&mut s, &mut od, [0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]),
        Some([0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00])
    );
    // §8.5: writes answered 60h with the multiplexer echoed (a compliant server echoes 01).
    for (req, resp) in [
        (
            [0x23, 0x01, 0x14, 0x01, 0x01, 0x03, 0x00, 0x00],
            [0x60, 0x01, 0x14, 0x01, 0, 0, 0, 0],
        ),
        (
            [0x23, 0x83, 0x60, 0x00, 0xD0, 0x07, 0x00, 0x00],
            [0x60, 0x83, 0x60, 0x00, 0, 0, 0, 0],
        ),
        (
            [0x2F, 0x60, 0x60, 0x00, 0x01, 0x00, 0x00, 0x00],
            [0x60, 0x60, 0x60, 0x00, 0, 0, 0, 0],
        ),
    ] {
        assert_eq!(ask(&mut s, &mut od, req), Some(resp));
    }
    assert_eq!((od.rpdo2, od.accel, od.mode), (0x0301, 2000, 1));
    // §8.2: abort byte order, from the dictionary's refusal of a 2-byte write to a U32.
    assert_eq!(
        ask(&mut s, &mut od, [0x2B, 0x83, 0x60, 0x00, 1, 0, 0, 0]),
        Some([0x80, 0x83, 0x60, 0x00, 0x10, 0x00, 0x07, 0x06])
    );
    // The client produces the manual's request bytes and reads the manual's answer.
    let mut c: SdoClient<2, 64> = SdoClient::new(node(), SdoClientConfig::default());
    c.download(ACCEL, &2000u32.to_le_bytes(), DownloadMode::Auto)
        .unwrap();
    let f = c.poll_transmit(Instant::ZERO).unwrap();
    assert_eq!(
        (f.cob_id(), f.data8()),
        (
            Some(0x601),
            [0x23, 0x83, 0x60, 0x00, 0xD0, 0x07, 0x00, 0x00]
        )
    );
    c.handle_frame(&cframe([0x60, 0x83, 0x60, 0x00, 0, 0, 0, 0]), Instant::ZERO);
    assert_eq!(c.poll_event().unwrap().outcome, Ok(Completion::Downloaded));
    c.download(MODE, &[1], DownloadMode::Auto).unwrap();
    assert_eq!(
        c.poll_transmit(Instant::ZERO).unwrap().data8(),
        [0x2F, 0x60, 0x60, 0x00, 0x01, 0, 0, 0]
    );
    c.handle_frame(&cframe([0x60, 0x60, 0x60, 0x00, 0, 0, 0, 0]), Instant::ZERO);
    c.poll_event().unwrap();
    c.upload(DEVICE_TYPE).unwrap();
    assert_eq!(
        c.poll_transmit(Instant::ZERO).unwrap().data8(),
        [0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]
    );
    c.handle_frame(
        &cframe([0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00]),
        Instant::ZERO,
    );
    assert_eq!(
        c.poll_event().unwrap().outcome,
        Ok(Completion::Uploaded(&[0x92, 0x01, 0x02, 0x00]))
    );
    // Client and server on the same COB-IDs.
    assert!(c.accepts(&cframe([0; 8])));
    assert!(!c.accepts(&Frame::std8(0x582, [0; 8])));
    assert_eq!(c.server_node(), node());
}

#[test]
fn client_abort_resets_server() {
    let mut l = Link::new();
    l.server.handle_frame(
        &sframe([0x21, 0x00, 0x20, 0x02, 20, 0, 0, 0]),
        l.now,
        &mut l.od,
    );
    l.server.poll_transmit(l.now).unwrap();
    l.server.handle_frame(
        &sframe([0x80, 0x00, 0x20, 0x02, 0x00, 0x00, 0x00, 0x08]),
        l.now,
        &mut l.od,
    );
    assert!(l.server.is_idle());
    assert_eq!(
        l.server.poll_event(),
        Some(ServerEvent::Aborted {
            addr: DOMAIN_RW,
            code: AbortCode::General,
            by: AbortedBy::Client
        })
    );
    assert_eq!(l.server.poll_transmit(l.now), None);
}

/// A small deterministic generator, so the no-panic tests need no dependency.
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> u8 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 33) as u8
    }
}

#[test]
fn random_frames_never_panic() {
    let mut rng = Lcg(7);
    let mut c: SdoClient<2, 64> = SdoClient::new(node(), SdoClientConfig::default());
    let mut s: SdoServer<64> = SdoServer::new(
        node(),
        SdoServerConfig {
            block_size: 4,
            ..SdoServerConfig::default()
        },
    );
    let mut od = TestOd::new();
    let mut now = Instant::ZERO;
    for i in 0..50_000u32 {
        now += Duration::from_millis(1);
        if c.pending() == 0 {
            let _ = match i % 4 {
                0 => c.upload(DOMAIN_RO),
                1 => c.upload_block(DOMAIN_RO),
                2 => c.download(DOMAIN_RW, &[1; 30], DownloadMode::Block),
                _ => c.download(DOMAIN_RW, &[1; 30], DownloadMode::Segmented),
            };
        }
        let mut b = [0u8; 8];
        b.iter_mut().for_each(|x| *x = rng.next());
        // Bias byte 0 towards valid command specifiers and small sequence numbers.
        if i % 3 == 0 {
            b[0] &= 0xE7;
        }
        let len = if i % 17 == 0 {
            (rng.next() % 9) as usize
        } else {
            8
        };
        let f = Frame::new_std(0x581, &b[..len]).unwrap();
        c.handle_frame(&f, now);
        let g = Frame::new_std(0x601, &b[..len]).unwrap();
        s.handle_frame(&g, now, &mut od);
        while c.poll_transmit(now).is_some() {}
        while s.poll_transmit(now).is_some() {}
        c.handle_timeout(now);
        s.handle_timeout(now);
        let _ = c.poll_event();
        while s.poll_event().is_some() {}
    }
    // The decoders themselves, on random input of random length.
    for _ in 0..50_000 {
        let n = (rng.next() % 10) as usize;
        let b: Vec<u8> = (0..n).map(|_| rng.next()).collect();
        let _ = ClientFrame::decode(&b);
        let _ = ServerFrame::decode(&b);
        let _ = BlockSegment::decode(&b);
    }
}

/// Drops each single frame of a block transfer in turn: every run either delivers the exact
/// value or fails with an error on both sides; none delivers wrong data or hangs.
#[test]
fn block_transfers_survive_or_fail_cleanly_with_any_single_loss() {
    let cc = SdoClientConfig {
        block_size: 4,
        ..SdoClientConfig::default()
    };
    let sc = SdoServerConfig {
        block_size: 4,
        ..SdoServerConfig::default()
    };
    let value = data(60, 4); // 9 segments: sub-blocks of 4, 4, 1
    let (mut ok, mut failed) = (0, 0);
    for upload in [false, true] {
        for c2s in [true, false] {
            for i in 0..16 {
                let mut l = Link::with(cc, sc);
                l.od.domain_rw = value.clone();
                if c2s {
                    l.drop_c2s.push(i)
                } else {
                    l.drop_s2c.push(i)
                }
                if upload {
                    l.client.upload_block(DOMAIN_RW).unwrap();
                } else {
                    l.client
                        .download(DOMAIN_RW, &value, DownloadMode::Block)
                        .unwrap();
                }
                l.run_with_time(5_000);
                let e = l.client.poll_event().expect("the request completes");
                match e.outcome {
                    Ok(Completion::Uploaded(d)) => {
                        assert_eq!(d, &value[..], "upload, drop {c2s} {i}");
                        ok += 1;
                    }
                    Ok(Completion::Downloaded) => {
                        assert_eq!(l.od.domain_rw, value, "download, drop {c2s} {i}");
                        ok += 1;
                    }
                    Err(_) => failed += 1,
                }
                assert!(l.client.is_idle() || l.client.pending() == 0);
                assert!(
                    l.server.is_idle(),
                    "server left busy: upload {upload}, drop {c2s} {i}"
                );
            }
        }
    }
    // Most single losses of segments are repaired by retransmission.
    assert!(ok > failed, "ok {ok}, failed {failed}");
}
