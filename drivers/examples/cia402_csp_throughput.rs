//! How many drive-seconds one core simulates per wall second with the generic CiA 402 drive in
//! cyclic synchronous position: `DRIVES` drives on the in-process virtual bus in virtual time, a
//! master sending each drive its RPDO1 (controlword + 607Ah, a cosine path from rest) and then a SYNC every
//! 1 ms, every drive answering with TPDO1 (statusword + 6064h) at every SYNC; and the worst
//! following error seen (command of the previous SYNC − position after this one).
//!
//! `cargo run --release -p drivers --example cia402_csp_throughput [SECONDS] [TICK_US] [DRIVES]`
//! (defaults 20 s, the simulator's 250 µs tick, 4 drives).

#[cfg(feature = "std")]
fn main() {
    use std::collections::VecDeque;
    use std::time::Duration;

    use drivers::can::station::{self, Station, Steppable};
    use drivers::can::{Frame, VirtualBus, VirtualBusConfig};
    use drivers::canopen::NodeId;
    use drivers::canopen::endpoint::Endpoint;
    use drivers::sim::cia402_drive::{Cia402Config, Cia402Drive};
    use drivers::time::Instant;

    const AMPLITUDE: f64 = 100_000.0;
    const PERIOD_S: f64 = 2.0;

    /// A master: a configuration script, then per cycle every drive's RPDO1 and a SYNC.
    struct Host {
        script: VecDeque<Frame>,
        drives: u8,
        start: Instant,
        next_cycle: Instant,
        cycle: Duration,
        queue: VecDeque<Frame>,
        /// Per drive, the command of the last two SYNCs.
        sent: Vec<[i64; 2]>,
        worst: i64,
        received: u64,
    }
    /// The path starts 10 ms after the first cycle, once the drives are enabled at rest (a
    /// master preloads 607Ah with the actual position, §8.2: here both are 0).
    fn path(t: f64) -> i64 {
        let t = (t - 0.010).max(0.0);
        (AMPLITUDE * (1.0 - (2.0 * std::f64::consts::PI * t / PERIOD_S).cos())).round() as i64
    }
    impl Endpoint for Host {
        fn handle_frame(&mut self, frame: &Frame, _: Instant) {
            self.received += 1;
            let Some(id) = frame.cob_id() else { return };
            if (0x181..0x181 + self.drives as u16).contains(&id) && frame.data().len() == 6 {
                let k = (id - 0x181) as usize;
                let pos = i32::from_le_bytes(frame.data()[2..6].try_into().unwrap_or([0; 4]));
                // The TPDO after SYNC k carries p_act(k); the command of SYNC k−1 is sent[k][0].
                let e = self.sent[k][0] - pos as i64;
                if frame.data()[1] & 0x10 != 0 {
                    self.worst = self.worst.max(e.abs());
                }
            }
        }
        fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
            if let Some(f) = self.script.pop_front() {
                return Some(f);
            }
            if now >= self.next_cycle && self.queue.is_empty() {
                let t = (self.next_cycle - self.start).as_secs_f64();
                let cmd = path(t);
                // Shutdown for the first cycles, then Enable operation (0006h, 000Fh).
                let cw: u16 = if t < 0.003 { 0x0006 } else { 0x000F };
                for n in 0..self.drives {
                    let mut d = [0u8; 6];
                    d[..2].copy_from_slice(&cw.to_le_bytes());
                    d[2..].copy_from_slice(&(cmd as i32).to_le_bytes());
                    if let Ok(f) = Frame::new_std(0x201 + n as u16, &d) {
                        self.queue.push_back(f);
                    }
                    let s = &mut self.sent[n as usize];
                    *s = [s[1], cmd];
                }
                if let Ok(f) = Frame::new_std(0x080, &[]) {
                    self.queue.push_back(f);
                }
                self.next_cycle += self.cycle;
            }
            self.queue.pop_front()
        }
        fn poll_timeout(&self) -> Option<Instant> {
            Some(self.next_cycle)
        }
        fn handle_timeout(&mut self, _: Instant) {}
    }

    let arg = |i: usize| std::env::args().nth(i).and_then(|a| a.parse::<f64>().ok());
    let secs = arg(1).unwrap_or(20.0);
    let mut cfg_tick = Cia402Config::new(NodeId::new(1).expect("node")).tick;
    if let Some(us) = arg(2) {
        cfg_tick = Duration::from_micros(us as u64);
    }
    let drives = arg(3).map_or(4, |d| d as u8).clamp(1, 32);
    let bus = VirtualBus::new(VirtualBusConfig::default()).expect("bus");
    let sdo = |n: u8, cmd: u8, index: u16, sub: u8, v: u32| {
        let mut d = [cmd, index as u8, (index >> 8) as u8, sub, 0, 0, 0, 0];
        d[4..].copy_from_slice(&v.to_le_bytes());
        Frame::new_std(0x600 + n as u16, &d).expect("frame")
    };
    let mut script = VecDeque::new();
    for n in 1..=drives {
        let (w32, w8) = (0x23, 0x2F);
        for (comm, map, cob, entries) in [
            (
                0x1400u16,
                0x1600u16,
                0x200 + n as u32,
                [0x6040_0010u32, 0x607A_0020],
            ),
            (0x1800, 0x1A00, 0x180 + n as u32, [0x6041_0010, 0x6064_0020]),
        ] {
            script.push_back(sdo(n, w32, comm, 1, cob | 0x8000_0000));
            script.push_back(sdo(n, w8, map, 0, 0));
            for (i, e) in entries.iter().enumerate() {
                script.push_back(sdo(n, w32, map, i as u8 + 1, *e));
            }
            script.push_back(sdo(n, w8, map, 0, 2));
            script.push_back(sdo(n, w8, comm, 2, 1));
            script.push_back(sdo(n, w32, comm, 1, cob));
        }
        script.push_back(sdo(n, w8, 0x6060, 0, 8));
        script.push_back(sdo(n, w8, 0x60C2, 1, 1));
    }
    script.push_back(Frame::new_std(0x000, &[1, 0]).expect("frame"));
    let t0 = bus.now();
    let start = t0 + Duration::from_millis(50);
    let mut host = Station::new(
        bus.attach("host"),
        Host {
            script,
            drives,
            start,
            next_cycle: start,
            cycle: Duration::from_millis(1),
            queue: VecDeque::new(),
            sent: vec![[0, 0]; drives as usize],
            worst: 0,
            received: 0,
        },
    );
    let mut stations: Vec<_> = (1..=drives)
        .map(|n| {
            let mut cfg = Cia402Config::new(NodeId::new(n).expect("node"));
            cfg.tick = cfg_tick;
            Station::new(
                bus.attach(&format!("drive{n}")),
                Box::new(Cia402Drive::new(cfg, t0).expect("drive")),
            )
        })
        .collect();
    let wall = std::time::Instant::now();
    let until = t0 + Duration::from_secs_f64(secs);
    {
        let mut all: Vec<&mut dyn Steppable> = vec![&mut host];
        all.extend(stations.iter_mut().map(|d| d as &mut dyn Steppable));
        station::run_until(&bus, &mut all, until);
    }
    let wall = wall.elapsed().as_secs_f64();
    let following = stations
        .iter()
        .filter(|d| d.endpoint.statusword() & 0x1000 != 0)
        .count();
    println!(
        "{drives} generic CiA 402 drives in CSP, tick {} µs, SYNC every 1 ms, {secs:.0} s of \
         virtual time in {wall:.3} s of wall time: {:.0} drive-seconds per wall second ({} \
         frames received by the master; {following} of {drives} following at the end; worst \
         following error {} inc on a {AMPLITUDE}·(1 − cos) inc path of {PERIOD_S} s)",
        cfg_tick.as_micros(),
        drives as f64 * secs / wall,
        host.endpoint.received,
        host.endpoint.worst
    );
}

#[cfg(not(feature = "std"))]
fn main() {}
