#![no_main]
//! Capture readers: a candump log line and a pcap file of any bytes parse or give a typed
//! error; a parsed candump line prints back to a line that parses to the same record.

use drivers::can::{candump, pcap};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = pcap::read_pcap(data);
    let _ = pcap::decode_socketcan(data);
    if let Ok(text) = core::str::from_utf8(data) {
        for (i, line) in text.lines().enumerate() {
            if let Ok(rec) = candump::parse_line(line, i + 1) {
                let again = candump::format_line(rec.timestamp, &rec.interface, &rec.frame);
                let back = candump::parse_line(&again, 1).expect("own line parses");
                assert_eq!(back.frame, rec.frame);
            }
        }
    }
});
