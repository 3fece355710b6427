//! Frames per second of wall time the virtual bus carries in virtual time.
//!
//! Four ports exchange 8-byte frames at 1 Mbit/s; every frame reaches the three other ports.
//! Two ways of driving it: the batch calls (one lock per batch) and one call per frame.
//!
//! `cargo run --release -p drivers --no-default-features --features std --example vbus_throughput`

#[cfg(feature = "std")]
mod run {
    use drivers::can::{Bus, Frame, VirtualBus, VirtualBusConfig, VirtualPort};
    use std::time::Instant as WallInstant;

    const PORTS: usize = 4;
    const BATCH: usize = 64;
    const FRAMES: u64 = 4_000_000;

    fn setup() -> (VirtualBus, Vec<VirtualPort>) {
        let bus = VirtualBus::new(VirtualBusConfig {
            tx_capacity: BATCH,
            rx_capacity: 4 * BATCH,
            ..VirtualBusConfig::default()
        })
        .expect("valid config");
        let ports = (0..PORTS)
            .map(|i| bus.attach(&format!("node{i}")))
            .collect();
        (bus, ports)
    }

    fn batched() -> (u64, f64) {
        let (bus, mut ports) = setup();
        let batches: Vec<Vec<Frame>> = (0..PORTS)
            .map(|p| {
                (0..BATCH)
                    .map(|i| Frame::std8((0x100 + p * 0x80 + i) as u16, [i as u8; 8]))
                    .collect()
            })
            .collect();
        let mut out = vec![Frame::std8(0, [0; 8]); 4 * BATCH];
        let mut received = 0u64;
        let start = WallInstant::now();
        while bus.stats().frames < FRAMES {
            for (p, b) in ports.iter_mut().zip(&batches) {
                p.send_batch(b).expect("queue drained every round");
            }
            bus.run_until_idle();
            for p in ports.iter_mut() {
                received += p.recv_batch(&mut out).expect("attached") as u64;
            }
        }
        let secs = start.elapsed().as_secs_f64();
        assert_eq!(received, bus.stats().frames * (PORTS as u64 - 1));
        (bus.stats().frames, secs)
    }

    fn per_frame() -> (u64, f64) {
        let (bus, mut ports) = setup();
        let mut n = 0u64;
        let start = WallInstant::now();
        while n < FRAMES {
            for (p, port) in ports.iter_mut().enumerate() {
                port.send(&Frame::std8(0x100 + p as u16, [n as u8; 8]))
                    .expect("queue drained every round");
            }
            bus.run_until_idle();
            for port in ports.iter_mut() {
                while let Ok(Some(_)) = port.try_recv() {}
            }
            n += PORTS as u64;
        }
        (bus.stats().frames, start.elapsed().as_secs_f64())
    }

    pub fn main() {
        for (name, (frames, secs)) in [("batch", batched()), ("per-frame", per_frame())] {
            println!(
                "{name:>9}: {frames} frames in {secs:.3} s wall = {:.2} M frames/s \
                 ({PORTS} ports, 8-byte frames, each delivered to {} ports)",
                frames as f64 / secs / 1e6,
                PORTS - 1
            );
        }
    }
}

fn main() {
    #[cfg(feature = "std")]
    run::main();
    #[cfg(not(feature = "std"))]
    println!("the virtual bus needs the `std` feature");
}
