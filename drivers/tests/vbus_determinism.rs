//! Determinism: the same submissions at the same virtual times give the same deliveries, order
//! and timestamps, bit for bit, faults included.
#![cfg(feature = "std")]

use core::time::Duration;
use drivers::can::{
    Bus, FaultRule, Frame, IdMatch, TimeWindow, VirtualBus, VirtualBusConfig, VirtualPort,
};
use drivers::time::Instant;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// (receiving port, frame text, timestamp in ns)
type Log = Vec<(usize, String, u64)>;

fn scenario(traffic_seed: u64) -> Log {
    let bus = VirtualBus::new(VirtualBusConfig {
        bitrate: 500_000,
        tx_capacity: 8,
        ..VirtualBusConfig::default()
    })
    .unwrap();
    let mut ports: Vec<VirtualPort> = (0..5).map(|i| bus.attach(&format!("n{i}"))).collect();
    bus.add_fault(FaultRule::drop(IdMatch::Any).with_probability(0.05, 11));
    bus.add_fault(FaultRule::delay(
        IdMatch::Mask {
            id: 0x180,
            mask: 0x780,
        },
        Duration::from_micros(300),
    ));
    bus.add_fault(FaultRule::duplicate(IdMatch::Any).with_probability(0.02, 12));
    bus.add_fault(
        FaultRule::corrupt(IdMatch::Any, [0x55; 8]).during(TimeWindow::new(
            Instant::from_millis(20),
            Instant::from_millis(25),
        )),
    );
    bus.set_bus_off(
        ports[3].id(),
        TimeWindow::new(Instant::from_millis(40), Instant::from_millis(45)),
    );

    let mut rng = ChaCha8Rng::seed_from_u64(traffic_seed);
    let mut log = Log::new();
    let mut t = Instant::ZERO;
    for _ in 0..3000 {
        t += Duration::from_nanos(rng.gen_range(0..200_000));
        bus.advance_to(t);
        // Several ports often submit at the same instant: arbitration must decide, not call order.
        for _ in 0..rng.gen_range(1..4) {
            let p = rng.gen_range(0..ports.len());
            let id = rng.gen_range(0x080..0x700u16);
            let len = rng.gen_range(0..=8usize);
            let data: [u8; 8] = rng.r#gen();
            let f = Frame::new_std(id, &data[..len]).unwrap();
            let _ = ports[p].send(&f);
        }
        for (i, p) in ports.iter_mut().enumerate() {
            while let Ok(Some(f)) = p.try_recv() {
                log.push((i, f.to_string(), f.timestamp().as_nanos()));
            }
        }
    }
    bus.run_until_idle();
    for (i, p) in ports.iter_mut().enumerate() {
        while let Ok(Some(f)) = p.try_recv() {
            log.push((i, f.to_string(), f.timestamp().as_nanos()));
        }
    }
    log
}

#[test]
fn identical_runs_give_identical_delivery_logs() {
    let a = scenario(1);
    let b = scenario(1);
    assert!(a.len() > 5000, "{}", a.len());
    assert_eq!(a, b);
    assert_ne!(a, scenario(2));
}

#[test]
fn per_port_timestamps_never_go_back_except_for_delayed_frames() {
    // Without delay faults every port sees strictly increasing completion times.
    let bus = VirtualBus::new(VirtualBusConfig::default()).unwrap();
    let mut tx: Vec<VirtualPort> = (0..4).map(|i| bus.attach(&format!("t{i}"))).collect();
    let mut rx = bus.attach("rx");
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut last = Instant::ZERO;
    for round in 0..500u64 {
        for p in tx.iter_mut() {
            let _ = p.send(&Frame::std8(rng.gen_range(0..0x7FF), [0; 8]));
        }
        bus.advance_to(Instant::from_micros(round * 300));
        while let Some(f) = rx.try_recv().unwrap() {
            assert!(f.timestamp() > last);
            last = f.timestamp();
        }
    }
}
