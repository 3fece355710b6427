//! pcap captures: exact bytes for LINKTYPE_CAN_SOCKETCAN, read-back, and tshark's CANopen view.
#![cfg(feature = "std")]

#[path = "common/tshark.rs"]
mod tshark;
use drivers::can::Frame;
use drivers::can::pcap::{PcapWriter, TSHARK_CANOPEN_ARGS, read_pcap};
use drivers::time::Instant;
use tshark::tshark_or_skip;

/// An SDO upload of 1000h:00 from node 1 and its reply (seed-003 section 8.1), NMT start, SYNC,
/// plus an extended and a remote frame.
fn sample_frames() -> Vec<(Instant, Frame)> {
    let t = |us: u64| Instant::from_micros(1_700_000_000_000_000 + us);
    vec![
        (t(0), "601#4000100000000000".parse().unwrap()),
        (t(850), "581#4300100092010200".parse().unwrap()),
        (t(2_000), "000#0101".parse().unwrap()),
        (t(3_000), "080#".parse().unwrap()),
        (t(4_000), "1F334455#1122".parse().unwrap()),
        (t(5_000), "701#R1".parse().unwrap()),
    ]
}

fn write_capture() -> Vec<u8> {
    let mut w = PcapWriter::new(Vec::new()).unwrap();
    for (t, f) in sample_frames() {
        w.write(t, &f).unwrap();
    }
    w.into_inner()
}

#[test]
fn file_layout() {
    let b = write_capture();
    assert_eq!(b.len(), 24 + 6 * 32);
    // Global header: magic (microseconds), 2.4, zone 0, sigfigs 0, snaplen 65535, link 227.
    assert_eq!(
        &b[..24],
        &[
            0xD4, 0xC3, 0xB2, 0xA1, 2, 0, 4, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0xFF, 0xFF, 0, 0, 227, 0,
            0, 0
        ]
    );
    // Second record: the SDO reply 850 us after the first.
    let r = &b[24 + 32..24 + 64];
    assert_eq!(&r[0..4], &1_700_000_000u32.to_le_bytes());
    assert_eq!(&r[4..8], &850u32.to_le_bytes());
    assert_eq!(&r[8..16], &[16, 0, 0, 0, 16, 0, 0, 0]);
    assert_eq!(&r[16..24], &[0, 0, 0x05, 0x81, 8, 0, 0, 0]);
    assert_eq!(
        &r[24..32],
        &[0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00]
    );
    // Extended: EFF flag in the big-endian can_id. Remote: RTR flag, length = DLC, no data.
    let ext = &b[24 + 4 * 32 + 16..24 + 4 * 32 + 24];
    assert_eq!(ext, &[0x9F, 0x33, 0x44, 0x55, 2, 0, 0, 0]);
    let rtr = &b[24 + 5 * 32 + 16..24 + 6 * 32];
    assert_eq!(
        rtr,
        &[0x40, 0, 0x07, 0x01, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]
    );
}

#[test]
fn read_back_equals_written() {
    let back = read_pcap(&write_capture()).unwrap();
    let want = sample_frames();
    assert_eq!(back.len(), want.len());
    for ((bt, bf), (wt, wf)) in back.iter().zip(&want) {
        assert_eq!(bt, wt);
        assert_eq!(bf, wf);
        assert_eq!(bf.timestamp(), *wt);
    }
}

#[test]
fn tshark_decodes_canopen() {
    if !tshark_or_skip("tshark_decodes_canopen") {
        return;
    }
    let text = tshark::fields(
        "capture_pcap",
        &write_capture(),
        &TSHARK_CANOPEN_ARGS,
        &[
            "can.id",
            "canopen.function_code",
            "canopen.node_id",
            "canopen.sdo.main_idx",
            "canopen.sdo.sub_idx",
            "canopen.sdo.data.bytes",
            "_ws.col.Info",
        ],
    );
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 6, "{text}");
    let f = |i: usize| lines[i].split(';').collect::<Vec<_>>();
    // The request: COB-ID 0x601, node 1, index 1000h sub 0, shown as an SDO.
    let req = f(0);
    assert_eq!(req[0], "1537");
    assert_eq!(req[2], "0x00000001");
    assert_eq!(req[3], "0x1000");
    assert_eq!(req[4], "0x00");
    assert!(
        req[6].contains("SDO") && req[6].contains("upload request"),
        "{}",
        lines[0]
    );
    // The reply carries the device type 0x00020192, little-endian.
    let resp = f(1);
    assert_eq!(resp[5], "92010200");
    assert!(
        resp[6].contains("SDO") && resp[6].contains("response"),
        "{}",
        lines[1]
    );
    assert!(f(2)[6].contains("NMT"), "{}", lines[2]);
    assert!(f(3)[6].contains("SYNC"), "{}", lines[3]);
}
