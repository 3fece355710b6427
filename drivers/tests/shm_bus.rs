//! The cross-process virtual bus, exercised from one process with several endpoints.
#![cfg(feature = "shm")]

use core::time::Duration;
use drivers::can::bit_timing::frame_duration;
use drivers::can::shm_bus::{ShmBus, TX_BACKLOG_FRAMES};
use drivers::can::{Bus, BusError, Frame};
use drivers::time::monotonic_now;
use std::sync::atomic::{AtomicU32, Ordering};

/// A bus name no other test (or parallel test run) uses.
fn unique_bus(tag: &str) -> String {
    static N: AtomicU32 = AtomicU32::new(0);
    format!(
        "test-{tag}-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )
}

fn recv(bus: &mut ShmBus) -> Option<Frame> {
    bus.recv_until(monotonic_now() + Duration::from_secs(2))
        .unwrap()
}

#[test]
fn frames_reach_others_in_order_with_sender_timestamps() {
    let name = unique_bus("order");
    let mut a = ShmBus::open(&name, 20_000).unwrap();
    let mut b = ShmBus::open(&name, 20_000).unwrap();
    let mut c = ShmBus::open(&name, 20_000).unwrap();
    assert_ne!(a.sender_id(), b.sender_id());
    let frames: Vec<Frame> = ["080#", "601#4000100000000000", "1F334455#11", "701#R1"]
        .iter()
        .map(|s| s.parse().unwrap())
        .collect();
    let before = monotonic_now();
    let mut returned = Vec::new();
    for f in &frames {
        a.send(f).unwrap();
        returned.push(monotonic_now());
    }
    for rx in [&mut b, &mut c] {
        let got: Vec<Frame> = (0..frames.len()).map(|_| recv(rx).unwrap()).collect();
        assert_eq!(got, frames);
        // Each frame completes one frame time after max(send time, previous completion).
        assert!(got[0].timestamp() >= before + frame_duration(&frames[0], 20_000));
        for k in 1..got.len() {
            let (prev, this) = (got[k - 1].timestamp(), got[k].timestamp());
            let d = frame_duration(&got[k], 20_000);
            assert!(this - prev >= d);
            if returned[k] <= prev {
                // Sent while the previous frame was still on the wire: exactly back to back.
                assert_eq!(this - prev, d);
            }
        }
        assert_eq!(rx.counters().received, frames.len() as u64);
    }
    // The sender does not hear itself.
    assert_eq!(a.try_recv().unwrap(), None);
    assert_eq!(a.counters().sent, frames.len() as u64);

    // Replies go the other way.
    b.send(&"581#4300100092010200".parse().unwrap()).unwrap();
    assert_eq!(recv(&mut a).unwrap().cob_id(), Some(0x581));
    assert_eq!(recv(&mut c).unwrap().cob_id(), Some(0x581));
    assert_eq!(b.try_recv().unwrap(), None);
}

#[test]
fn a_full_transmit_backlog_would_block() {
    let name = unique_bus("backlog");
    // At the lowest bitrate the modelled backlog fills long before real time catches up.
    let mut a = ShmBus::open(&name, 20_000).unwrap();
    let f: Frame = "1FFFFFFF#0011223344556677".parse().unwrap();
    let mut sent = 0;
    let err = loop {
        match a.send(&f) {
            Ok(()) => sent += 1,
            Err(e) => break e,
        }
        assert!(sent <= TX_BACKLOG_FRAMES + 2, "never blocked");
    };
    assert_eq!(err, BusError::WouldBlock);
    assert!(sent >= TX_BACKLOG_FRAMES, "blocked after {sent}");
}

#[test]
fn a_dropped_endpoint_does_not_disturb_the_others() {
    let name = unique_bus("drop");
    let mut a = ShmBus::open(&name, 1_000_000).unwrap();
    let mut b = ShmBus::open(&name, 1_000_000).unwrap();
    {
        // A slow endpoint that never reads: safe overflow means it never blocks senders.
        let _slow = ShmBus::open(&name, 1_000_000).unwrap();
        for i in 0..2_000u16 {
            let f = Frame::new_std(0x100 + (i % 0x100), &i.to_le_bytes()).unwrap();
            while a.send(&f) == Err(BusError::WouldBlock) {
                std::thread::sleep(Duration::from_micros(200));
            }
            assert_eq!(recv(&mut b).unwrap(), f);
        }
    }
    a.send(&"080#".parse().unwrap()).unwrap();
    assert_eq!(recv(&mut b).unwrap().cob_id(), Some(0x080));
    // A newcomer joins the same bus after the others came and went.
    let mut late = ShmBus::open(&name, 1_000_000).unwrap();
    late.send(&"701#05".parse().unwrap()).unwrap();
    assert_eq!(recv(&mut a).unwrap().cob_id(), Some(0x701));
}

/// Processes that join a new bus at the same moment all get it: the one that loses the race to
/// create the service finds it half made and asks again instead of failing (seen when two
/// drive-sim processes started together on a loaded host).
#[test]
fn endpoints_joining_a_new_bus_at_once_all_get_it() {
    use std::sync::{Arc, Barrier};
    for round in 0..20 {
        let name = unique_bus(&format!("race{round}"));
        let n = 6;
        let start = Arc::new(Barrier::new(n));
        let joins: Vec<_> = (0..n)
            .map(|_| {
                let (name, start) = (name.clone(), Arc::clone(&start));
                std::thread::spawn(move || {
                    start.wait();
                    ShmBus::open(&name, 1_000_000)
                        .map(|_| ())
                        .map_err(|e| e.to_string())
                })
            })
            .collect();
        for j in joins {
            if let Err(e) = j.join().unwrap() {
                panic!("round {round}: {e}");
            }
        }
    }
}
