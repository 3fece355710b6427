//! Criterion benches of the virtual bus in virtual time: frames carried per second of wall time.
//!
//! `cargo bench -p drivers --no-default-features --features std --bench virtual_bus`

// criterion_group! expands to an undocumented public function.
#![allow(missing_docs)]

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use drivers::can::{Bus, FaultRule, Frame, IdMatch, VirtualBus, VirtualBusConfig, VirtualPort};
use std::hint::black_box;

const PORTS: usize = 4;
const BATCH: usize = 64;

fn setup() -> (VirtualBus, Vec<VirtualPort>) {
    let bus = VirtualBus::new(VirtualBusConfig {
        tx_capacity: BATCH,
        rx_capacity: 4 * BATCH,
        ..VirtualBusConfig::default()
    })
    .expect("valid config");
    let ports = (0..PORTS).map(|i| bus.attach(&format!("n{i}"))).collect();
    (bus, ports)
}

fn batches() -> Vec<Vec<Frame>> {
    (0..PORTS)
        .map(|p| {
            (0..BATCH)
                .map(|i| Frame::std8((0x100 + p * 0x80 + i) as u16, [i as u8; 8]))
                .collect()
        })
        .collect()
}

/// One round: every port queues a batch, the bus runs dry, every port drains its receive queue.
fn round(bus: &VirtualBus, ports: &mut [VirtualPort], batches: &[Vec<Frame>], out: &mut [Frame]) {
    for (p, b) in ports.iter_mut().zip(batches) {
        let _ = p.send_batch(b);
    }
    bus.run_until_idle();
    for p in ports.iter_mut() {
        black_box(p.recv_batch(out).unwrap_or(0));
    }
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("virtual_bus");
    g.throughput(Throughput::Elements((PORTS * BATCH) as u64));
    let b = batches();
    let mut out = vec![Frame::std8(0, [0; 8]); 4 * BATCH];

    let (bus, mut ports) = setup();
    g.bench_function("batch_4x64", |it| {
        it.iter(|| round(&bus, &mut ports, &b, &mut out))
    });

    let (bus, mut ports) = setup();
    bus.add_fault(
        FaultRule::drop(IdMatch::Mask {
            id: 0x100,
            mask: 0x780,
        })
        .with_probability(0.1, 1),
    );
    bus.add_fault(FaultRule::corrupt(IdMatch::Exact(0x181), [0xFF; 8]));
    g.bench_function("batch_4x64_with_faults", |it| {
        it.iter(|| round(&bus, &mut ports, &b, &mut out))
    });

    let (bus, mut ports) = setup();
    g.throughput(Throughput::Elements(PORTS as u64));
    g.bench_function("per_frame_4", |it| {
        it.iter(|| {
            for (p, port) in ports.iter_mut().enumerate() {
                let _ = port.send(&Frame::std8(0x100 + p as u16, [0; 8]));
            }
            bus.run_until_idle();
            for port in ports.iter_mut() {
                while let Ok(Some(f)) = port.try_recv() {
                    black_box(f);
                }
            }
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
