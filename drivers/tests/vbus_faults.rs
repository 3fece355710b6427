//! Fault injection on the virtual bus: every fault kind, counters, rules changed while running.
#![cfg(feature = "std")]

use core::time::Duration;
use drivers::can::{
    Bus, BusCounters, BusError, BusState, FaultRule, Frame, IdMatch, TimeWindow, VirtualBus,
    VirtualBusConfig, VirtualPort,
};
use drivers::time::Instant;

fn bus() -> VirtualBus {
    VirtualBus::new(VirtualBusConfig::default()).unwrap()
}

fn f8(id: u16, b: u8) -> Frame {
    Frame::std8(id, [b; 8])
}

fn drain(p: &mut VirtualPort) -> Vec<Frame> {
    let mut v = Vec::new();
    while let Some(f) = p.try_recv().unwrap() {
        v.push(f);
    }
    v
}

fn us(t: u64) -> Instant {
    Instant::from_micros(t)
}

#[test]
fn drop_by_exact_id_and_mask() {
    let bus = bus();
    let mut a = bus.attach("a");
    let mut b = bus.attach("b");
    let mut mon = bus.attach_monitor("mon");
    let exact = bus.add_fault(FaultRule::drop(IdMatch::Exact(0x181)));
    let mask = bus.add_fault(FaultRule::drop(IdMatch::Mask {
        id: 0x600,
        mask: 0x780,
    }));
    a.send_batch(&[f8(0x181, 1), f8(0x182, 2), f8(0x605, 3), f8(0x585, 4)])
        .unwrap();
    bus.run_until_idle();
    let ids: Vec<u32> = drain(&mut b).iter().map(|f| f.raw_id()).collect();
    assert_eq!(ids, vec![0x182, 0x585]);
    // The dropped frames were on the wire: the monitor saw all four, the sender sent all four.
    assert_eq!(drain(&mut mon).len(), 4);
    assert_eq!(a.counters().sent, 4);
    assert_eq!(
        b.counters(),
        BusCounters {
            sent: 0,
            received: 2,
            dropped: 2
        }
    );
    assert_eq!(bus.fault_hits(exact), Some(1));
    assert_eq!(bus.fault_hits(mask), Some(1));
}

#[test]
fn probability_with_a_seed_gives_a_repeatable_count() {
    let run = |seed| {
        let bus = VirtualBus::new(VirtualBusConfig {
            rx_capacity: 4096,
            ..VirtualBusConfig::default()
        })
        .unwrap();
        let mut a = bus.attach("a");
        let mut b = bus.attach("b");
        bus.add_fault(FaultRule::drop(IdMatch::Any).with_probability(0.25, seed));
        for i in 0..2000u32 {
            a.send(&f8(0x200, i as u8)).unwrap();
            bus.run_until_idle();
        }
        let got = drain(&mut b);
        assert_eq!(got.len() as u64, b.counters().received);
        assert_eq!(b.counters().received + b.counters().dropped, 2000);
        got.iter().map(|f| f.data()[0]).collect::<Vec<u8>>()
    };
    let first = run(7);
    assert_eq!(first, run(7), "same seed, same frames lost");
    assert!((1300..1700).contains(&first.len()), "{}", first.len());
    assert_ne!(first, run(8));
}

#[test]
fn time_window_limits_a_rule() {
    let bus = bus();
    let mut a = bus.attach("a");
    let mut b = bus.attach("b");
    // Frames complete at 135, 270, 405, 540 us: the window takes the 2nd and 3rd.
    bus.add_fault(FaultRule::drop(IdMatch::Any).during(TimeWindow::new(us(200), us(405 + 1))));
    a.send_batch(&[f8(1, 1), f8(1, 2), f8(1, 3), f8(1, 4)])
        .unwrap();
    bus.run_until_idle();
    let data: Vec<u8> = drain(&mut b).iter().map(|f| f.data()[0]).collect();
    assert_eq!(data, vec![1, 4]);
}

#[test]
fn corrupt_xors_the_data_for_receivers_only() {
    let bus = bus();
    let mut a = bus.attach("a");
    let mut b = bus.attach("b");
    let mut mon = bus.attach_monitor("mon");
    bus.add_fault(FaultRule::corrupt(
        IdMatch::Exact(0x201),
        [0xFF, 0, 0, 0, 0, 0, 0, 0x01],
    ));
    a.send(&Frame::std8(0x201, [0x0F, 1, 2, 3, 4, 5, 6, 7]))
        .unwrap();
    bus.run_until_idle();
    let got = drain(&mut b);
    assert_eq!(got[0].data(), &[0xF0, 1, 2, 3, 4, 5, 6, 6]);
    assert_eq!(drain(&mut mon)[0].data(), &[0x0F, 1, 2, 3, 4, 5, 6, 7]);
}

#[test]
fn delay_postpones_delivery_not_the_wire() {
    let bus = bus();
    let mut a = bus.attach("a");
    let mut b = bus.attach("b");
    bus.add_fault(FaultRule::delay(
        IdMatch::Exact(0x100),
        Duration::from_micros(500),
    ));
    a.send_batch(&[f8(0x100, 1), f8(0x101, 2)]).unwrap();
    bus.run_until_idle();
    let got: Vec<(u32, u64)> = drain(&mut b)
        .iter()
        .map(|f| (f.raw_id(), f.timestamp().as_micros()))
        .collect();
    // 0x101 follows on the wire at once and overtakes the delayed 0x100.
    assert_eq!(got, vec![(0x101, 270), (0x100, 635)]);
    assert!(bus.is_idle());
}

#[test]
fn delay_is_visible_to_recv_until() {
    let bus = bus();
    let mut a = bus.attach("a");
    let mut b = bus.attach("b");
    bus.add_fault(FaultRule::delay(IdMatch::Any, Duration::from_millis(1)));
    a.send(&f8(0x100, 1)).unwrap();
    assert_eq!(b.recv_until(us(1000)).unwrap(), None);
    let f = b.recv_until(us(5000)).unwrap().unwrap();
    assert_eq!(f.timestamp(), us(1135));
    assert_eq!(b.now(), us(1135));
}

#[test]
fn duplicate_retransmits_back_to_back() {
    let bus = bus();
    let mut a = bus.attach("a");
    let mut b = bus.attach("b");
    let mut mon = bus.attach_monitor("mon");
    bus.add_fault(FaultRule::duplicate(IdMatch::Exact(0x300)));
    a.send_batch(&[f8(0x300, 1), f8(0x301, 2)]).unwrap();
    bus.run_until_idle();
    let got: Vec<(u32, u64)> = drain(&mut b)
        .iter()
        .map(|f| (f.raw_id(), f.timestamp().as_micros()))
        .collect();
    assert_eq!(got, vec![(0x300, 135), (0x300, 270), (0x301, 405)]);
    assert_eq!(drain(&mut mon).len(), 3);
    // Sent once by the node; twice on the wire.
    assert_eq!(a.counters().sent, 2);
    assert_eq!(bus.stats().frames, 3);
}

#[test]
fn disconnect_silences_a_node_both_ways() {
    let bus = bus();
    let mut a = bus.attach("a");
    let mut b = bus.attach("b");
    let mut c = bus.attach("c");
    b.send(&f8(0x10, 1)).unwrap();
    bus.set_disconnected(b.id(), true);
    assert_eq!(b.send(&f8(0x11, 1)), Err(BusError::Disconnected));
    assert_eq!(b.try_recv(), Err(BusError::Disconnected));
    a.send(&f8(0x20, 1)).unwrap();
    bus.run_until_idle();
    // b's queued frame vanished (cut off on the wire); b received nothing.
    let ids: Vec<u32> = drain(&mut c).iter().map(|f| f.raw_id()).collect();
    assert_eq!(ids, vec![0x20]);
    assert_eq!(b.counters().received, 0);
    assert_eq!(b.counters().dropped, 1);
    bus.set_disconnected(b.id(), false);
    a.send(&f8(0x21, 1)).unwrap();
    b.send(&f8(0x12, 1)).unwrap();
    bus.run_until_idle();
    assert_eq!(b.try_recv().unwrap().map(|f| f.raw_id()), Some(0x21));
    assert_eq!(drain(&mut a).last().map(|f| f.raw_id()), Some(0x12));
}

#[test]
fn bus_off_for_a_window_then_recovery() {
    let bus = bus();
    let mut a = bus.attach("a");
    let mut b = bus.attach("b");
    // b has a frame queued behind a's when it goes bus-off at 100 us, until 1 ms.
    a.send(&f8(0x100, 1)).unwrap();
    b.send(&f8(0x200, 2)).unwrap();
    bus.set_bus_off(b.id(), TimeWindow::new(us(100), us(1000)));
    bus.advance_to(us(100));
    assert_eq!(b.state(), BusState::BusOff);
    assert_eq!(b.send(&f8(0x201, 2)), Err(BusError::BusOff));
    a.send(&f8(0x101, 1)).unwrap();
    bus.advance_to(us(999));
    assert_eq!(b.state(), BusState::BusOff);
    // Nothing reached b, and its queued frame was lost.
    assert_eq!(b.try_recv().unwrap(), None);
    assert_eq!(
        b.counters(),
        BusCounters {
            sent: 0,
            received: 0,
            dropped: 3
        }
    );
    let ids: Vec<u32> = drain(&mut a).iter().map(|f| f.raw_id()).collect();
    assert!(ids.is_empty(), "{ids:x?}");
    bus.advance_to(us(1000));
    assert_eq!(b.state(), BusState::ErrorActive);
    b.send(&f8(0x202, 2)).unwrap();
    a.send(&f8(0x102, 1)).unwrap();
    bus.run_until_idle();
    assert_eq!(b.try_recv().unwrap().map(|f| f.raw_id()), Some(0x102));
    assert_eq!(a.try_recv().unwrap().map(|f| f.raw_id()), Some(0x202));
}

#[test]
fn rules_added_and_removed_while_running() {
    let bus = bus();
    let mut a = bus.attach("a");
    let mut b = bus.attach("b");
    a.send(&f8(1, 1)).unwrap();
    bus.run_until_idle();
    let id = bus.add_fault(FaultRule::drop(IdMatch::Any));
    a.send(&f8(1, 2)).unwrap();
    bus.run_until_idle();
    assert!(bus.remove_fault(id));
    assert!(!bus.remove_fault(id));
    a.send(&f8(1, 3)).unwrap();
    bus.run_until_idle();
    let data: Vec<u8> = drain(&mut b).iter().map(|f| f.data()[0]).collect();
    assert_eq!(data, vec![1, 3]);
    assert_eq!(
        b.counters(),
        BusCounters {
            sent: 0,
            received: 2,
            dropped: 1
        }
    );
    assert_eq!(a.counters().sent, 3);
}
