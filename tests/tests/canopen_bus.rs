//! A CANopen master and devices exchanging real frames over the virtual bus, in virtual time.

use std::time::Duration;

use drivers::can::{FaultRule, IdMatch, TimeWindow};
use drivers::canopen::device::DeviceEvent;
use drivers::canopen::endpoint::Endpoint;
use drivers::canopen::guarding::GuardingEvent;
use drivers::canopen::heartbeat::HeartbeatEvent;
use drivers::canopen::master::{MasterEvent, Supervision};
use drivers::canopen::nmt::{NmtCommand, NmtState, NmtTarget};
use drivers::canopen::pdo::{ConfigPlan, Mapping, PdoDirection, PdoSettings};
use drivers::canopen::sdo::{AbortedBy, DownloadMode, SdoError};
use drivers::canopen::{AbortCode, Address};
use drivers::time::Instant;
use integration_tests::*;

const MS: Duration = Duration::from_millis(1);

/// Runs until node `n`'s SDO request completes; returns the outcome with uploaded data copied.
fn sdo_result(rig: &mut Rig, n: u8, limit: Duration) -> Result<Vec<u8>, SdoError> {
    let mut out = None;
    let done = rig.run_until(limit, |r| {
        if let Some(e) = r.master.endpoint.poll_sdo_event(node(n)) {
            out = Some(e.to_vec());
            true
        } else {
            false
        }
    });
    assert!(
        done,
        "SDO request to node {n} did not complete within {limit:?}"
    );
    out.expect("outcome recorded")
}

fn boot(rig: &mut Rig) {
    // Boot-up messages go out at power-on; the master learns every node is pre-operational.
    rig.run_for(MS);
    for st in &rig.devices {
        let n = st.endpoint.node();
        assert_eq!(
            rig.master.endpoint.state(n),
            Some(NmtState::PreOperational),
            "node {n}"
        );
    }
}

#[test]
fn segmented_upload_of_a_1k_domain() {
    let mut rig = Rig::new(&[5]);
    boot(&mut rig);
    let start = rig.log.len();
    rig.master
        .endpoint
        .sdo(node(5))
        .unwrap()
        .upload(DOMAIN_1K)
        .unwrap();
    let data = sdo_result(&mut rig, 5, 500 * MS).unwrap();
    assert_eq!(data, PATTERN_1K);
    // Initiate + ceil(1024 / 7) = 147 segments, each a request and a response.
    let requests = rig.frames_with_id(0x605, start).len();
    let responses = rig.frames_with_id(0x585, start).len();
    assert_eq!((requests, responses), (148, 148));
    // The initiate response announces the size: 41 00 20 00 00 04 00 00.
    assert_eq!(
        rig.frames_with_id(0x585, start)[0],
        frame("585#4100200000040000")
    );
}

#[test]
fn block_download_of_4k_with_crc() {
    let mut rig = Rig::new(&[5]);
    boot(&mut rig);
    let data: Vec<u8> = (0..4096u32).map(|i| ((i * 13) ^ (i >> 3)) as u8).collect();
    let start = rig.log.len();
    rig.master
        .endpoint
        .sdo(node(5))
        .unwrap()
        .download(DOMAIN_4K, &data, DownloadMode::Block)
        .unwrap();
    sdo_result(&mut rig, 5, 500 * MS).unwrap();
    assert_eq!(rig.device(5).od().raw(DOMAIN_4K).unwrap(), &data[..]);
    let req = rig.frames_with_id(0x605, start);
    // Initiate: ccs 6, cc (CRC) set, size indicated: C6 01 20 00 00 10 00 00.
    assert_eq!(req[0], frame("605#C601200000100000"));
    // 4096 bytes = 586 segments of 7, in sub-blocks of 127: 5 sub-blocks.
    let segments = req.len() - 2; // minus initiate and end
    assert_eq!(segments, 586);
    let acks = rig
        .frames_with_id(0x585, start)
        .iter()
        .filter(|f| f.data()[0] == 0xA2)
        .count();
    assert_eq!(acks, 5);
    // The end frame carries the CRC of the data, which the server checked.
    let end = req.last().unwrap().data8();
    let crc = drivers::canopen::sdo::crc16(&data);
    assert_eq!(u16::from_le_bytes([end[1], end[2]]), crc);
}

#[test]
fn abort_on_a_missing_object() {
    let mut rig = Rig::new(&[5]);
    boot(&mut rig);
    let start = rig.log.len();
    rig.master
        .endpoint
        .sdo(node(5))
        .unwrap()
        .upload(Address::new(0x5FFF, 0))
        .unwrap();
    let err = sdo_result(&mut rig, 5, 100 * MS).unwrap_err();
    assert_eq!(
        err,
        SdoError::Aborted {
            code: AbortCode::NoObject,
            by: AbortedBy::Server
        }
    );
    assert_eq!(
        rig.frames_with_id(0x585, start),
        vec![frame("585#80FF5F0000000206")]
    );
}

#[test]
fn abort_on_timeout() {
    // Node 9 is not on the bus: the client gives up after its timeout and says so on the bus.
    let mut rig = Rig::new(&[5]);
    boot(&mut rig);
    rig.master
        .endpoint
        .add_node(node(9), Supervision::None, rig.now())
        .unwrap();
    let start = rig.log.len();
    let t0 = rig.now();
    rig.master
        .endpoint
        .sdo(node(9))
        .unwrap()
        .upload(Address::new(0x1000, 0))
        .unwrap();
    let err = sdo_result(&mut rig, 9, 2000 * MS).unwrap_err();
    assert_eq!(err, SdoError::Timeout { timeout_ms: 500 });
    let elapsed = rig.now() - t0;
    assert!(
        elapsed >= 500 * MS && elapsed < 502 * MS,
        "timed out after {elapsed:?}"
    );
    rig.run_for(MS);
    assert_eq!(
        rig.frames_with_id(0x609, start),
        vec![frame("609#4000100000000000"), frame("609#8000100000000405")]
    );
}

#[test]
fn pdo_remapping_with_read_back() {
    let mut rig = Rig::new(&[3]);
    boot(&mut rig);
    // TPDO2: statusword, position, and two bits of the input byte (not byte-aligned).
    let mapping = [0x6041_0010, 0x6064_0020, 0x60FD_0001, 0x60FD_0001];
    let settings = PdoSettings {
        direction: PdoDirection::Tpdo,
        number: 2,
        cob_id: None,
        mapping: &mapping[..2],
        transmission_type: 1,
        inhibit_100us: 0,
        event_timer_ms: 0,
        sync_start: 0,
    };
    let plan = ConfigPlan::new(node(3), &settings).unwrap();
    for step in plan.writes() {
        let bytes = step.value.to_le_bytes();
        rig.master
            .endpoint
            .sdo(node(3))
            .unwrap()
            .download(
                step.addr,
                &bytes[..step.size as usize],
                DownloadMode::Expedited,
            )
            .unwrap();
        sdo_result(&mut rig, 3, 100 * MS).unwrap();
    }
    for step in plan.reads() {
        rig.master
            .endpoint
            .sdo(node(3))
            .unwrap()
            .upload(step.addr)
            .unwrap();
        let data = sdo_result(&mut rig, 3, 100 * MS).unwrap();
        let mut v = [0u8; 4];
        v[..data.len()].copy_from_slice(&data);
        plan.verify(step.addr, u32::from_le_bytes(v)).unwrap();
    }
    // A wrong read-back is caught.
    assert!(plan.verify(Address::new(0x1A01, 1), 0x6041_0008).is_err());

    // The device now sends that mapping at every SYNC once operational.
    rig.device(3).od_mut().set_i32(POSITION, -123_456).unwrap();
    rig.device(3).od_mut().set_u16(STATUSWORD, 0x0637).unwrap();
    rig.master
        .endpoint
        .nmt(NmtCommand::Start, NmtTarget::All)
        .unwrap();
    rig.run_for(MS);
    rig.master.endpoint.start_sync(1000, 0, rig.now()).unwrap();
    let start = rig.log.len();
    rig.run_for(3 * MS + Duration::from_micros(500));
    let tpdo2 = rig.frames_with_id(0x283, start);
    assert_eq!(tpdo2.len(), 4, "one TPDO2 per SYNC");
    let m = Mapping::from_raw(&mapping[..2]).unwrap();
    let values = m.unpack_values(tpdo2[0].data()).unwrap();
    assert_eq!(values.as_slice()[0], 0x0637);
    assert_eq!(values.as_slice()[1] as u32 as i32, -123_456);
    // Every TPDO2 follows its SYNC directly.
    for f in &tpdo2 {
        let i = rig
            .log
            .iter()
            .position(|g| g.timestamp() == f.timestamp())
            .unwrap();
        assert!(
            rig.log[..i]
                .iter()
                .rev()
                .take(3)
                .any(|g| g.cob_id() == Some(0x080))
        );
    }
}

#[test]
fn mapping_rules_are_enforced_by_the_device() {
    let mut rig = Rig::new(&[3]);
    boot(&mut rig);
    let sdo = |rig: &mut Rig, a: (u16, u8), v: u32, n: usize| {
        let b = v.to_le_bytes();
        rig.master
            .endpoint
            .sdo(node(3))
            .unwrap()
            .download(Address::new(a.0, a.1), &b[..n], DownloadMode::Expedited)
            .unwrap();
        sdo_result(rig, 3, 100 * MS)
    };
    let aborted = |code| {
        Err(SdoError::Aborted {
            code,
            by: AbortedBy::Server,
        })
    };
    // An entry cannot change while the mapping is enabled.
    assert_eq!(
        sdo(&mut rig, (0x1A01, 1), 0x6041_0010, 4),
        aborted(AbortCode::UnsupportedAccess)
    );
    // A missing object, an unmappable one, and too many bits are refused at sub00.
    sdo(&mut rig, (0x1A01, 0), 0, 1).unwrap();
    sdo(&mut rig, (0x1A01, 1), 0x5555_0010, 4).unwrap();
    assert_eq!(
        sdo(&mut rig, (0x1A01, 0), 1, 1),
        aborted(AbortCode::NoObject)
    );
    sdo(&mut rig, (0x1A01, 1), 0x6083_0020, 4).unwrap();
    assert_eq!(
        sdo(&mut rig, (0x1A01, 0), 1, 1),
        aborted(AbortCode::NotMappable)
    );
    for sub in 1..=3 {
        sdo(&mut rig, (0x1A01, sub), 0x6064_0020, 4).unwrap();
    }
    assert_eq!(
        sdo(&mut rig, (0x1A01, 0), 3, 1),
        aborted(AbortCode::PdoLength)
    );
    // A valid PDO keeps its identifier; reserved transmission types are refused.
    assert_eq!(
        sdo(&mut rig, (0x1800, 1), 0x0000_0190, 4),
        aborted(AbortCode::InvalidValue)
    );
    assert_eq!(
        sdo(&mut rig, (0x1800, 2), 245, 1),
        aborted(AbortCode::InvalidValue)
    );
    // Sub-index 04h of a PDO parameter is reserved.
    assert_eq!(
        sdo(&mut rig, (0x1400, 4), 0, 1),
        aborted(AbortCode::NoSubIndex)
    );
}

#[test]
fn heartbeat_loss_is_detected_within_consumer_time_plus_one_cycle() {
    let mut rig = Rig::new(&[4]);
    boot(&mut rig);
    rig.master
        .endpoint
        .add_node(
            node(4),
            Supervision::Heartbeat { consumer_ms: 150 },
            rig.now(),
        )
        .unwrap();
    rig.master.endpoint.start_sync(1000, 0, rig.now()).unwrap();
    rig.master
        .endpoint
        .sdo(node(4))
        .unwrap()
        .download(
            Address::new(0x1017, 0),
            &100u16.to_le_bytes(),
            DownloadMode::Auto,
        )
        .unwrap();
    sdo_result(&mut rig, 4, 100 * MS).unwrap();
    rig.run_for(450 * MS);
    let beats = rig.frames_with_id(0x704, 0);
    assert!(beats.len() >= 4, "heartbeats every 100 ms");
    while rig.master.endpoint.poll_event().is_some() {}

    // Cut the device off the bus.
    let port = rig.devices[0].bus.id();
    rig.bus.set_disconnected(port, true);
    let last_beat = rig.frames_with_id(0x704, 0).last().unwrap().timestamp();
    let mut lost_at = None;
    rig.run_until(1000 * MS, |r| {
        while let Some(e) = r.master.endpoint.poll_event() {
            if let MasterEvent::Heartbeat(HeartbeatEvent::Lost { node: n }) = e {
                assert_eq!(n, node(4));
                lost_at = Some(r.now());
            }
        }
        lost_at.is_some()
    });
    let lost_at = lost_at.expect("heartbeat loss reported");
    let cycle = MS;
    assert!(
        lost_at >= last_beat + 150 * MS,
        "not before the consumer time"
    );
    assert!(
        lost_at <= last_beat + 150 * MS + cycle,
        "lost at {lost_at}, last beat {last_beat}"
    );
}

#[test]
fn guarding_detects_a_toggle_error() {
    let mut rig = Rig::new(&[4]);
    boot(&mut rig);
    rig.master
        .endpoint
        .add_node(
            node(4),
            Supervision::Guarding {
                guard_ms: 100,
                factor: 3,
            },
            rig.now(),
        )
        .unwrap();
    rig.run_for(250 * MS);
    // After the boot-up (704#00): each RTR poll answered with the toggle alternating.
    let replies: Vec<String> = rig
        .frames_with_id(0x704, 0)
        .iter()
        .skip(1)
        .map(|f| f.to_string())
        .collect();
    assert_eq!(
        replies,
        ["704#R1", "704#7F", "704#R1", "704#FF", "704#R1", "704#7F"]
    );
    assert!(
        rig.log
            .iter()
            .any(|f| f.cob_id() == Some(0x704) && f.is_remote())
    );
    let mut toggle_errors = 0;
    while let Some(e) = rig.master.endpoint.poll_event() {
        if let MasterEvent::Guarding(GuardingEvent::ToggleError { .. }) = e {
            toggle_errors += 1;
        }
    }
    assert_eq!(toggle_errors, 0);
    // Lose one reply: the device toggled, the master did not see it, the next reply is "wrong".
    // The poll shares the COB-ID, so aim the window at the next reply only (one poll period
    // after the last reply completed, not the poll 65 µs before it).
    let last_reply = rig.frames_with_id(0x704, 0).last().unwrap().timestamp();
    let us = Duration::from_micros(10);
    let at = last_reply + 100 * MS;
    rig.bus.add_fault(
        FaultRule::drop(IdMatch::Exact(0x704)).during(TimeWindow::new(
            Instant::from_nanos(at.as_nanos() - us.as_nanos() as u64),
            at + us,
        )),
    );
    let mut seen = None;
    rig.run_until(400 * MS, |r| {
        while let Some(e) = r.master.endpoint.poll_event() {
            if let MasterEvent::Guarding(g @ GuardingEvent::ToggleError { .. }) = e {
                seen = Some(g);
            }
        }
        seen.is_some()
    });
    match seen {
        Some(GuardingEvent::ToggleError {
            node: n,
            expected,
            got,
        }) => {
            assert_eq!(n, node(4));
            assert_ne!(expected, got);
        }
        other => panic!("expected a toggle error, got {other:?}"),
    }
}

#[test]
fn emcy_is_decoded_with_its_code() {
    let mut rig = Rig::new(&[6]);
    boot(&mut rig);
    rig.device(6).raise_emcy(0x2310, [1, 2, 3, 4, 5]);
    let mut got = None;
    rig.run_until(10 * MS, |r| {
        while let Some(e) = r.master.endpoint.poll_event() {
            if let MasterEvent::Emcy(e) = e {
                got = Some(e);
            }
        }
        got.is_some()
    });
    let e = got.expect("EMCY received");
    assert_eq!(
        (e.node, e.code, e.manufacturer),
        (node(6), 0x2310, [1, 2, 3, 4, 5])
    );
    assert_eq!(e.register & 0x03, 0x03, "generic and current bits of 1001h");
    assert!(
        e.description.to_lowercase().contains("current"),
        "{}",
        e.description
    );
    assert_eq!(
        rig.frames_with_id(0x086, 0)[0],
        frame("086#1023030102030405")
    );
    // 1003h holds it, newest first.
    rig.master
        .endpoint
        .sdo(node(6))
        .unwrap()
        .upload(Address::new(0x1003, 1))
        .unwrap();
    assert_eq!(
        sdo_result(&mut rig, 6, 100 * MS).unwrap(),
        0x0000_2310u32.to_le_bytes()
    );
}

/// The TLC5xx manual's own byte sequences (reference/seed-003-tlc5xx.md §8), node 1.
#[test]
fn manual_sequences_byte_for_byte() {
    let mut rig = Rig::new(&[1]);
    boot(&mut rig);
    let start = rig.log.len();
    // §8.1: read 1000h.
    rig.master
        .endpoint
        .sdo(node(1))
        .unwrap()
        .upload(Address::new(0x1000, 0))
        .unwrap();
    sdo_result(&mut rig, 1, 10 * MS).unwrap();
    // §8.5: enable RPDO2 and TPDO2, write 6083h = 2000.
    let writes: [(u16, u8, u32); 3] = [(0x1401, 1, 0x301), (0x1801, 1, 0x281), (0x6083, 0, 2000)];
    for (i, s, v) in writes {
        rig.master
            .endpoint
            .sdo(node(1))
            .unwrap()
            .download(
                Address::new(i, s),
                &v.to_le_bytes(),
                DownloadMode::Expedited,
            )
            .unwrap();
        sdo_result(&mut rig, 1, 10 * MS).unwrap();
    }
    let got: Vec<String> = rig.log[start..].iter().map(|f| f.to_string()).collect();
    assert_eq!(
        got,
        [
            "601#4000100000000000",
            "581#4300100092010200",
            "601#2301140101030000",
            "581#6001140100000000", // the manual prints sub-index 00; a compliant server echoes 01
            "601#2301180181020000",
            "581#6001180100000000",
            "601#23836000D0070000",
            "581#6083600000000000",
        ]
    );
    // §8.4: NMT start all is 000: 01 00.
    rig.master
        .endpoint
        .nmt(NmtCommand::Start, NmtTarget::All)
        .unwrap();
    let start = rig.log.len();
    rig.run_for(MS);
    assert_eq!(rig.log[start], frame("000#0100"));
    assert_eq!(rig.device(1).state(), NmtState::Operational);
    // RPDO2 (type 0) is applied at the next SYNC, not before.
    rig.master
        .endpoint
        .start_sync(1000, 0, rig.now() + 5 * MS)
        .unwrap();
    let now = rig.now();
    let rpdo = frame("301#1F00DC050000").with_timestamp(now);
    rig.device(1).handle_frame(&rpdo, now);
    assert_eq!(
        rig.device(1).od().get_i32(TARGET),
        Ok(0),
        "latched, not yet applied"
    );
    while rig.device(1).poll_event().is_some() {}
    rig.run_for(6 * MS);
    assert_eq!(rig.device(1).od().get_i32(TARGET), Ok(1500));
    assert_eq!(rig.device(1).od().get_u16(CONTROLWORD), Ok(0x001F));
}

#[test]
fn bad_input_gets_typed_errors_and_the_bus_goes_on() {
    let mut rig = Rig::new(&[2]);
    boot(&mut rig);
    rig.master
        .endpoint
        .nmt(NmtCommand::Start, NmtTarget::All)
        .unwrap();
    rig.run_for(MS);
    let now = rig.now();
    let dev = rig.device(2);
    while dev.poll_event().is_some() {}
    // An SDO request with a wrong DLC is ignored (no answer), an unknown command specifier is
    // aborted with 0504 0001h, a download segment out of the blue with 0504 0001h or 0503 0000h.
    dev.handle_frame(&frame("602#4000100000"), now);
    assert_eq!(dev.poll_transmit(now), None);
    dev.handle_frame(&frame("602#E000100000000000"), now);
    // (The abort names no object: the frame was not a request for one.)
    assert_eq!(dev.poll_transmit(now), Some(frame("582#8000000001000405")));
    // A segmented download, then a segment with the wrong toggle bit: 0503 0000h.
    dev.handle_frame(&frame("602#2101200008000000"), now);
    assert_eq!(dev.poll_transmit(now), Some(frame("582#6001200000000000")));
    dev.handle_frame(&frame("602#1011121314151617"), now);
    assert_eq!(dev.poll_transmit(now), Some(frame("582#8001200000000305")));
    // An RPDO shorter than its mapping (RPDO1 maps 16 bits) is reported and dropped.
    dev.handle_frame(&frame("202#1F"), now);
    let mut saw = false;
    while let Some(e) = dev.poll_event() {
        if let DeviceEvent::RpdoError { pdo: 1, error } = e {
            saw = true;
            assert!(error.to_string().contains("16"), "{error}");
        }
    }
    assert!(saw, "RPDO error reported");
    // NMT with a wrong DLC changes nothing.
    dev.handle_frame(&frame("000#80"), now);
    assert_eq!(dev.state(), NmtState::Operational);
    // And the device still serves a normal request.
    rig.master
        .endpoint
        .sdo(node(2))
        .unwrap()
        .upload(Address::new(0x1018, 4))
        .unwrap();
    assert_eq!(
        sdo_result(&mut rig, 2, 10 * MS).unwrap(),
        0x1234_5678u32.to_le_bytes()
    );
}

#[test]
fn reset_communication_restores_pdo_defaults_and_boots_again() {
    let mut rig = Rig::new(&[7]);
    boot(&mut rig);
    rig.master
        .endpoint
        .sdo(node(7))
        .unwrap()
        .download(
            Address::new(0x1801, 1),
            &0x287u32.to_le_bytes(),
            DownloadMode::Auto,
        )
        .unwrap();
    sdo_result(&mut rig, 7, 10 * MS).unwrap();
    assert_eq!(
        rig.device(7).od().get_u32(Address::new(0x1801, 1)),
        Ok(0x287)
    );
    rig.master
        .endpoint
        .nmt(NmtCommand::ResetCommunication, NmtTarget::All)
        .unwrap();
    let start = rig.log.len();
    rig.run_for(2 * MS);
    // PDO parameters are not stored on the TLC5xx: a reset brings the defaults back.
    assert_eq!(
        rig.device(7).od().get_u32(Address::new(0x1801, 1)),
        Ok(0x8000_0287)
    );
    assert_eq!(rig.frames_with_id(0x707, start), vec![frame("707#00")]);
    assert_eq!(
        rig.master.endpoint.state(node(7)),
        Some(NmtState::PreOperational)
    );
    let _ = Instant::ZERO;
}
