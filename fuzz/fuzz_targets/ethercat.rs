#![no_main]
//! The simulated EtherCAT segment fed any bytes as frames: a buffer that is not EtherCAT
//! datagrams is refused with a typed error, and one that is goes through two EMCA-EC
//! subdevices (whatever registers, sync managers, FMMUs, mailbox messages and AL control
//! values it writes) and comes back the same length, without a panic.

use drivers::ethercat::segment;
use drivers::sim::emca_ec::EmcaEc;
use drivers::time::Instant;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut subs: Vec<EmcaEc> = (0..2)
        .map(|i| EmcaEc::with_config(EmcaEc::drive_config(), i == 0, Instant::ZERO).unwrap())
        .collect();
    // Frames as [len_lo, len_hi, bytes...]..., each after an Ethernet header to every station
    // from a master, EtherType 88A4h: the fuzzer writes the EtherCAT header and datagrams.
    let mut rest = data;
    let mut t = 0u64;
    while rest.len() >= 2 {
        let n = usize::from(u16::from_le_bytes([rest[0], rest[1]])).min(rest.len() - 2).min(1500);
        let mut frame = vec![0xFF; 6];
        frame.extend_from_slice(&[0x10; 6]);
        frame.extend_from_slice(&[0x88, 0xA4]);
        frame.extend_from_slice(&rest[2..2 + n]);
        rest = &rest[2 + n..];
        t += 250_000;
        let before = frame.len();
        let _ = segment::pass(&mut frame, &mut subs, Instant::from_nanos(t));
        assert_eq!(frame.len(), before);
    }
});
