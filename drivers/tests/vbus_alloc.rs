//! Carrying frames allocates nothing once the ports are attached: a counting global allocator
//! watches 100 000 frames through every path (single and batch calls, arbitration, delayed and
//! duplicated frames, drops, monitor, receive-until).
#![cfg(feature = "std")]

use core::time::Duration;
use drivers::can::{Bus, FaultRule, Frame, IdMatch, VirtualBus, VirtualBusConfig};
use drivers::time::Instant;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

struct Counting;

static ALLOCS: AtomicU64 = AtomicU64::new(0);
thread_local! {
    // Count only the test thread's allocations: the harness may allocate on its own threads.
    static TRACK: Cell<bool> = const { Cell::new(false) };
}

// SAFETY: forwards every call unchanged to the system allocator; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if TRACK.with(|t| t.get()) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: the caller's contract is passed on unchanged.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: the caller's contract is passed on unchanged.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if TRACK.with(|t| t.get()) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: the caller's contract is passed on unchanged.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn no_allocation_per_frame() {
    let bus = VirtualBus::new(VirtualBusConfig {
        tx_capacity: 16,
        rx_capacity: 256,
        delay_capacity: 64,
        ..VirtualBusConfig::default()
    })
    .unwrap();
    let mut ports = [
        bus.attach("a"),
        bus.attach("b"),
        bus.attach("c"),
        bus.attach("d"),
    ];
    let mut mon = bus.attach_monitor("mon");
    bus.add_fault(FaultRule::delay(
        IdMatch::Exact(0x181),
        Duration::from_micros(50),
    ));
    bus.add_fault(FaultRule::duplicate(IdMatch::Any).with_probability(0.01, 3));
    bus.add_fault(FaultRule::drop(IdMatch::Any).with_probability(0.01, 4));
    let mut out = [Frame::std8(0, [0; 8]); 64];
    let batch: [Frame; 4] = core::array::from_fn(|i| Frame::std8(0x180 + i as u16, [i as u8; 8]));

    TRACK.with(|t| t.set(true));
    let mut carried = 0u64;
    let mut round = 0u64;
    while carried < 100_000 {
        round += 1;
        for (i, p) in ports.iter_mut().enumerate() {
            if round.is_multiple_of(2) {
                let _ = p.send_batch(&batch);
            } else {
                let _ = p.send(&Frame::std8(0x200 + i as u16, [round as u8; 8]));
            }
        }
        if round.is_multiple_of(3) {
            let deadline = bus.now() + Duration::from_micros(400);
            let _ = ports[0].recv_until(deadline);
        }
        bus.run_until_idle();
        for p in ports.iter_mut() {
            while p.recv_batch(&mut out).unwrap_or(0) > 0 {}
            let _ = p.try_recv();
        }
        while mon.recv_batch(&mut out).unwrap_or(0) > 0 {}
        carried = bus.stats().frames;
    }
    TRACK.with(|t| t.set(false));
    assert_eq!(ALLOCS.load(Ordering::Relaxed), 0);
    assert!(bus.now() > Instant::ZERO);
    assert!(ports[1].counters().received > 70_000);
}
