//! The virtual bus on the monotonic clock, across threads. Only orderings are asserted, never
//! wall-clock durations.
#![cfg(feature = "std")]

use core::time::Duration;
use drivers::can::{Bus, ClockMode, Frame, VirtualBus, VirtualBusConfig};
use drivers::time::monotonic_now;

fn real_bus() -> VirtualBus {
    VirtualBus::new(VirtualBusConfig {
        bitrate: 125_000,
        clock: ClockMode::Real,
        ..VirtualBusConfig::default()
    })
    .unwrap()
}

#[test]
fn frames_appear_after_their_completion_time_in_order() {
    let bus = real_bus();
    let mut a = bus.attach("a");
    let mut b = bus.attach("b");
    let before = monotonic_now();
    let sender = std::thread::spawn(move || {
        for i in 0..20u8 {
            a.send(&Frame::std8(0x200 + i as u16, [i; 8])).unwrap();
            if i.is_multiple_of(5) {
                std::thread::sleep(Duration::from_micros(300));
            }
        }
        a
    });
    let mut last = before;
    for i in 0..20u8 {
        let f = b
            .recv_until(monotonic_now() + Duration::from_secs(5))
            .unwrap()
            .expect("frame within the deadline");
        assert_eq!(f.data()[0], i);
        // At least one frame time after the first submission, strictly after the previous one,
        // and never visible before its completion.
        assert!(f.timestamp() >= before + Duration::from_micros(1080));
        assert!(f.timestamp() > last);
        assert!(f.timestamp() <= monotonic_now());
        last = f.timestamp();
    }
    let a = sender.join().unwrap();
    assert_eq!(a.counters().sent, 20);
    assert_eq!(b.counters().received, 20);
}

#[test]
fn recv_until_times_out_with_none() {
    let bus = real_bus();
    let mut b = bus.attach("b");
    let deadline = monotonic_now() + Duration::from_millis(3);
    assert_eq!(b.recv_until(deadline).unwrap(), None);
    assert!(monotonic_now() >= deadline);
    assert!(bus.now() >= deadline);
}

#[test]
fn run_until_idle_waits_for_the_wire() {
    let bus = real_bus();
    let mut a = bus.attach("a");
    let mut b = bus.attach("b");
    a.send_batch(&[Frame::std8(1, [0; 8]), Frame::std8(2, [0; 8])])
        .unwrap();
    let end = bus.run_until_idle();
    assert!(bus.is_idle());
    let first = b.try_recv().unwrap().unwrap();
    let second = b.try_recv().unwrap().unwrap();
    assert!(first.timestamp() < second.timestamp());
    assert!(second.timestamp() <= end);
}
