#![no_main]
//! NMT, SYNC, EMCY, heartbeat and guarding decoders and state machines, master and device side,
//! fed arbitrary frames at advancing times: no panic, and the machines keep answering.

use core::time::Duration;
use drivers::canopen::{emcy, guarding, heartbeat, nmt, sync, NodeId};
use drivers::time::Instant;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let node = NodeId::new(4).unwrap();
    let mut slave = nmt::NmtSlave::new(node, nmt::BootUpStyle::Ds301);
    let mut master: nmt::NmtMaster<4> = nmt::NmtMaster::new(true);
    let _ = master.add_node(node);
    let mut hb: heartbeat::HeartbeatConsumer<4, 8> = heartbeat::HeartbeatConsumer::new();
    let _ = hb.monitor(node, Duration::from_millis(100));
    let mut gm: guarding::GuardingMaster<4, 8> = guarding::GuardingMaster::new();
    let mut gs = guarding::GuardingSlave::new(node, 50, 3);
    let mut ec = emcy::EmcyConsumer::new(true);
    let mut now = Instant::ZERO;
    let _ = gm.add_node(node, 50, 3, now);
    for f in drivers_fuzz::frames(data) {
        now += Duration::from_micros(700);
        let _ = nmt::NmtRequest::from_frame(&f);
        let _ = nmt::decode_boot_up(&f, true);
        let _ = sync::decode_sync(&f);
        let _ = emcy::EmcyMessage::from_frame(&f);
        let _ = heartbeat::decode_heartbeat(&f);
        let _ = guarding::GuardReply::from_frame(&f);
        let _ = slave.handle_frame(&f);
        let _ = master.handle_frame(&f);
        while master.poll_event().is_some() {}
        let _ = hb.handle_frame(&f, now);
        let _ = hb.handle_timeout(now);
        while hb.poll_event().is_some() {}
        let _ = gm.handle_frame(&f, now);
        let _ = gm.handle_timeout(now);
        while gm.poll_transmit(now).is_some() {}
        while gm.poll_event().is_some() {}
        let _ = gs.handle_frame(&f, now, slave.state());
        let _ = ec.handle_frame(&f);
        gs.handle_timeout(now);
        while slave.poll_transmit().is_some() {}
    }
});
