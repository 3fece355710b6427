//! How many drive-seconds one core simulates per wall second: 8 simulated TLC5xx drives on the
//! in-process virtual bus in virtual time, with a master sending SYNC every 1 ms, every drive in
//! profile velocity mode and moving, TPDO3 (statusword + actual velocity) at every SYNC.
//!
//! `cargo run --release -p drivers --example sim_throughput [SECONDS]`

use std::collections::VecDeque;
use std::time::Duration;

#[cfg(feature = "std")]
fn main() {
    use drivers::can::station::{self, Station, Steppable};
    use drivers::can::{Frame, VirtualBus, VirtualBusConfig};
    use drivers::canopen::NodeId;
    use drivers::canopen::endpoint::Endpoint;
    use drivers::sim::tlc5xx::{Tlc5xx, TlcConfig};
    use drivers::time::Instant;

    /// A master that sends a script of frames, then SYNC every `period`.
    struct Host {
        script: VecDeque<Frame>,
        next_sync: Option<Instant>,
        period: Duration,
        received: u64,
    }
    impl Endpoint for Host {
        fn handle_frame(&mut self, _: &Frame, _: Instant) {
            self.received += 1;
        }
        fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
            if let Some(t) = self.next_sync
                && now >= t
            {
                self.next_sync = Some(t + self.period);
                return Frame::new_std(0x080, &[]).ok();
            }
            self.script.pop_front()
        }
        fn poll_timeout(&self) -> Option<Instant> {
            self.next_sync
        }
        fn handle_timeout(&mut self, _: Instant) {}
    }

    let secs: f64 = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(20.0);
    const DRIVES: u8 = 8;
    let bus = VirtualBus::new(VirtualBusConfig::default()).expect("bus");
    let f = |s: String| s.parse::<Frame>().expect("frame");
    let mut script = VecDeque::new();
    for n in 1..=DRIVES {
        // Enable TPDO3 (statusword + actual velocity, SYNC type per the device's default) and
        // RPDO3 (controlword + target velocity); acceleration and deceleration.
        script.push_back(f(format!(
            "{:03X}#2302140101{:02X}0000",
            0x600 + n as u16,
            4
        )));
        script.push_back(f(format!(
            "{:03X}#23021801{:02X}{:02X}0000",
            0x600 + n as u16,
            0x80 + n,
            3
        )));
        script.push_back(f(format!("{:03X}#23836000D0070000", 0x600 + n as u16)));
        script.push_back(f(format!("{:03X}#23846000E8030000", 0x600 + n as u16)));
    }
    script.push_back(f("000#0100".into()));
    for n in 1..=DRIVES {
        script.push_back(f(format!("{:03X}#2F60600003000000", 0x600 + n as u16)));
        script.push_back(f(format!("{:03X}#0600", 0x200 + n as u16)));
        script.push_back(f(format!("{:03X}#0F00", 0x200 + n as u16)));
        script.push_back(f(format!(
            "{:03X}#1F00{:02X}000000",
            0x400 + n as u16,
            50 + 10 * n
        )));
    }
    let t0 = bus.now();
    let mut host = Station::new(
        bus.attach("host"),
        Host {
            script,
            next_sync: Some(t0 + Duration::from_millis(50)),
            period: Duration::from_millis(1),
            received: 0,
        },
    );
    let mut drives: Vec<_> = (1..=DRIVES)
        .map(|n| {
            let cfg = TlcConfig::new(NodeId::new(n).expect("node"));
            Station::new(
                bus.attach(&format!("tlc{n}")),
                Box::new(Tlc5xx::new(cfg, t0).expect("TLC5xx")),
            )
        })
        .collect();
    let wall = std::time::Instant::now();
    let until = t0 + Duration::from_secs_f64(secs);
    {
        let mut stations: Vec<&mut dyn Steppable> = vec![&mut host];
        stations.extend(drives.iter_mut().map(|d| d as &mut dyn Steppable));
        station::run_until(&bus, &mut stations, until);
    }
    let wall = wall.elapsed().as_secs_f64();
    let moving = drives
        .iter()
        .filter(|d| d.endpoint.axis().status().velocity != 0)
        .count();
    println!(
        "{DRIVES} TLC5xx drives, SYNC every 1 ms, {secs:.0} s of virtual time in {wall:.3} s of wall time: \
         {:.0} drive-seconds per wall second ({} frames received by the master, {moving} of {DRIVES} axes moving at the end)",
        DRIVES as f64 * secs / wall,
        host.endpoint.received
    );
}

#[cfg(not(feature = "std"))]
fn main() {}
