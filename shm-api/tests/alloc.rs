//! Allocations per sample, counted by a global allocator around loan/write/send and
//! next/latest. shm-api itself allocates nothing per sample; iceoryx2 0.10's `loan_uninit`
//! allocates one small fixed-size `Rc` per sample (the sample's shared state, freed at send),
//! which its public API offers no way around. The test pins exactly that: one small allocation
//! per loan and none per read, so any further allocation shows up.

use shm_api::contract::LAYOUT_HASH;
use shm_api::{Client, PublisherSettings, ServiceNames, StatePublisher, create_node};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::time::Duration;

struct Counting;

thread_local! {
    // Counts only on the measuring thread, only while armed.
    static ARMED: Cell<bool> = const { Cell::new(false) };
    static COUNT: Cell<usize> = const { Cell::new(0) };
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

fn note(size: usize) {
    let _ = ARMED.try_with(|armed| {
        if armed.get() {
            let _ = COUNT.try_with(|c| c.set(c.get() + 1));
            let _ = LARGEST.try_with(|l| l.set(l.get().max(size)));
        }
    });
}

// SAFETY: forwards to the system allocator unchanged; only counts calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        // SAFETY: the caller's contract is passed on unchanged.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as above.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note(new_size);
        // SAFETY: as above.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Runs `f`, returning its result, the number of allocations and the largest one.
fn counted<R>(f: impl FnOnce() -> R) -> (R, usize, usize) {
    COUNT.with(|c| c.set(0));
    LARGEST.with(|c| c.set(0));
    ARMED.with(|a| a.set(true));
    let r = f();
    ARMED.with(|a| a.set(false));
    (r, COUNT.with(|c| c.get()), LARGEST.with(|c| c.get()))
}

#[test]
fn publishing_allocates_only_iceoryx2s_loan_state_and_reading_nothing() {
    let p = format!("test-{}-{}", "alloc", std::process::id());
    let node = create_node().expect("node");
    let names = ServiceNames::new(&p);
    let settings = PublisherSettings::default();
    let mut server = shm_api::CommandServer::create(&node, &names, &settings).expect("server");
    let _events = shm_api::EventPublisher::create(&node, &names, &settings).expect("events");
    let mut publisher = StatePublisher::create(&node, &names, &settings).expect("publisher");
    let mut client = Client::connect(&p).expect("client");
    let mut send = |cycle: u64| {
        let mut s = publisher.loan().expect("loan");
        s.cycle = cycle;
        s.axis_count = 3;
        s.axes[2].position = cycle as i64;
        s.send().expect("send");
    };
    // Connections are set up on the first exchanges; measure after them.
    for cycle in 0..10 {
        send(cycle);
        client.latest().expect("state");
    }
    let ((), allocations, largest) = counted(|| {
        for cycle in 10..1010 {
            send(cycle);
        }
    });
    // iceoryx2's per-loan `Rc` only: one small block per sample, nothing sized by the state.
    assert_eq!(
        allocations, 1000,
        "loan/write/send allocated {allocations} times"
    );
    assert!(
        largest <= 128,
        "an allocation of {largest} bytes per sample"
    );

    let (sum, allocations, _) = counted(|| {
        let mut sum = 0;
        for _ in 0..40 {
            let s = client.next(Duration::from_secs(1)).expect("next");
            assert_eq!(s.layout_hash, LAYOUT_HASH);
            sum += s.axes[2].position;
        }
        sum += client.latest().map_or(0, |s| s.axes[2].position);
        sum
    });
    assert_eq!(allocations, 0, "next/latest allocated {allocations} times");
    assert!(sum > 0);
    drop(server.receive());
}

#[test]
fn notifying_a_new_state_allocates_nothing() {
    // The coordinator's cycle thread notifies after every send: it must not allocate.
    let p = format!("test-{}-{}", "alloc-notify", std::process::id());
    let node = create_node().expect("node");
    let names = ServiceNames::new(&p);
    let settings = PublisherSettings::default();
    let _server = shm_api::CommandServer::create(&node, &names, &settings).expect("server");
    let _events = shm_api::EventPublisher::create(&node, &names, &settings).expect("events");
    let _publisher = StatePublisher::create(&node, &names, &settings).expect("publisher");
    let notifier = shm_api::StateNotifier::create(&node, &names, &settings).expect("notifier");
    // A listening client: each notify writes to its socket (not read here; 100 wake-ups fit in
    // the socket's queue).
    let _client = Client::connect(&p).expect("client");
    // The first notify connects to the listener (that allocates, once).
    notifier.notify().expect("notify");
    let (failed, allocations, _) =
        counted(|| (0..100).filter(|_| notifier.notify().is_err()).count());
    assert_eq!(failed, 0);
    assert_eq!(allocations, 0, "100 notifies allocated {allocations} times");
}
