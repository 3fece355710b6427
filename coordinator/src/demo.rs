//! The virtual-bus demonstration that `coordinator run` performs until the cycle of the
//! coordinator proper exists: a CANopen master boots, configures and drives simulated devices
//! over the deterministic virtual bus, in real time or as fast as the machine allows.
//!
//! What it shows, step by step: NMT boot-up detection; SDO reads of the identity; PDO remapping
//! over SDO with read-back verification (TPDO2: statusword + position, RPDO2: controlword +
//! target, both SYNC-driven); heartbeat supervision; NMT start; a SYNC-driven cycle in which the
//! master sends every node a new target right after SYNC and reads the actual positions the
//! devices send back; the bus load.

use std::fmt::Write as _;
use std::time::Duration;

use drivers::can::bit_timing::frame_duration;
use drivers::can::station::{self, Station, Steppable};
use drivers::can::{Bus, ClockMode, Frame, VirtualBus, VirtualBusConfig, VirtualPort};
use drivers::canopen::device::DeviceEvent;
use drivers::canopen::endpoint::Endpoint;
use drivers::canopen::example::{
    CONTROLWORD, ExampleDevice, POSITION, STATUSWORD, TARGET, example_device,
};
use drivers::canopen::heartbeat::HeartbeatEvent;
use drivers::canopen::master::{Master, MasterEvent, Supervision};
use drivers::canopen::nmt::{NmtCommand, NmtState, NmtTarget};
use drivers::canopen::pdo::{CobId, ConfigPlan, Mapping, PdoDirection, PdoSettings};
use drivers::canopen::sdo::DownloadMode;
use drivers::canopen::{Address, FunctionCode, NodeId};
use drivers::time::{Instant, monotonic_now};

/// How the demo runs.
#[derive(Debug, Clone)]
pub struct DemoConfig {
    /// Simulated drives (node-IDs 1..=nodes).
    pub nodes: u8,
    /// Cycle (SYNC) period.
    pub cycle: Duration,
    /// How long the cyclic phase runs (bus time).
    pub duration: Duration,
    /// Run as fast as the machine allows instead of in real time.
    pub virtual_time: bool,
    /// Bus bitrate.
    pub bitrate: u32,
    /// Print a status line this often (bus time); `None` for no live output.
    pub status_every: Option<Duration>,
}

impl Default for DemoConfig {
    fn default() -> Self {
        DemoConfig {
            nodes: 4,
            cycle: Duration::from_millis(2),
            duration: Duration::from_secs(5),
            virtual_time: false,
            bitrate: 1_000_000,
            status_every: Some(Duration::from_millis(500)),
        }
    }
}

/// What a demo run measured.
#[derive(Debug, Clone, Default)]
pub struct DemoSummary {
    /// Cycles run.
    pub cycles: u64,
    /// Frames on the bus.
    pub frames: u64,
    /// Bus time occupied by frames (worst-case stuffed lengths) over the cyclic phase.
    pub bus_load_percent: f64,
    /// TPDO2 frames the master received.
    pub tpdos_received: u64,
    /// TPDO2 frames that did not match the mapping.
    pub bad_tpdos: u64,
    /// Largest |target - actual| seen at the end of the run, increments.
    pub final_max_error: i64,
    /// Supervision events (heartbeat loss, EMCY...).
    pub supervision_events: u64,
    /// Wall time of the whole run.
    pub wall: Duration,
    /// Bus time of the whole run.
    pub bus_time: Duration,
}

/// A simulated drive: the example device plus a trivial application (the position follows the
/// target at a bounded speed, the statusword reports operation enabled).
struct DemoDrive {
    dev: Box<ExampleDevice>,
}

impl DemoDrive {
    fn app(&mut self) {
        while let Some(e) = self.dev.poll_event() {
            if let DeviceEvent::Sync { .. } = e {
                let od = self.dev.od_mut();
                let target = od.get_i32(TARGET).unwrap_or(0);
                let pos = od.get_i32(POSITION).unwrap_or(0);
                // Up to 2000 increments per cycle toward the target.
                let step = (target - pos).clamp(-2000, 2000);
                let _ = od.set_i32(POSITION, pos + step);
                let cw = od.get_u16(CONTROLWORD).unwrap_or(0);
                let sw = if cw & 0x000F == 0x000F {
                    0x0427
                } else {
                    0x0440
                };
                let _ = od.set_u16(STATUSWORD, sw);
            }
        }
    }
}

impl Endpoint for DemoDrive {
    fn handle_frame(&mut self, frame: &Frame, now: Instant) {
        self.dev.handle_frame(frame, now);
        self.app();
    }
    fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        self.dev.poll_transmit(now)
    }
    fn poll_timeout(&self) -> Option<Instant> {
        self.dev.poll_timeout()
    }
    fn handle_timeout(&mut self, now: Instant) {
        self.dev.handle_timeout(now);
        self.app();
    }
}

type DemoMaster = Master<16, 16, 256>;

/// The master side of the demo: the CANopen master plus the process image. After each SYNC it
/// queues every node's RPDO2 (controlword + new target), so the transmit order is SYNC, then
/// all RPDOs; it decodes each TPDO2 (statusword + actual position) that arrives.
struct DemoController {
    master: Box<DemoMaster>,
    nodes: Vec<NodeId>,
    tpdo: Mapping,
    rpdo: Mapping,
    /// Per node: target sent, actual received, statusword received.
    targets: Vec<i64>,
    actual: Vec<i64>,
    status: Vec<u16>,
    cycle: u64,
    cyclic: bool,
    pending: std::collections::VecDeque<Frame>,
    tpdos: u64,
    bad_tpdos: u64,
}

impl DemoController {
    fn queue_rpdos(&mut self) {
        for (i, &n) in self.nodes.iter().enumerate() {
            // Each axis follows a triangle wave with its own phase.
            let t = (self.cycle as i64 + 250 * i as i64) % 4000;
            self.targets[i] = if t < 2000 { t * 100 } else { (4000 - t) * 100 };
            let mut data = [0u8; 8];
            let len = self
                .rpdo
                .pack(&[0x000F, self.targets[i] as u32 as u64], &mut data);
            if let Some(f) =
                CobId::standard(FunctionCode::Rpdo(2).cob_id(n)).data_frame(&data[..len])
            {
                self.pending.push_back(f);
            }
        }
        self.cycle += 1;
    }
}

impl Endpoint for DemoController {
    fn handle_frame(&mut self, frame: &Frame, now: Instant) {
        if let Some(id) = frame.cob_id()
            && let Some((FunctionCode::Tpdo(2), n)) = FunctionCode::split(id)
            && let Some(i) = self.nodes.iter().position(|x| x.get() == n)
        {
            match self.tpdo.unpack_values(frame.data()) {
                Ok(v) => {
                    self.status[i] = v.as_slice()[0] as u16;
                    self.actual[i] = v.as_slice()[1] as u32 as i32 as i64;
                    self.tpdos += 1;
                }
                Err(_) => self.bad_tpdos += 1,
            }
            return;
        }
        self.master.handle_frame(frame, now);
    }
    fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        if let Some(f) = self.master.poll_transmit(now) {
            if self.cyclic && f.cob_id() == Some(0x080) {
                self.queue_rpdos();
            }
            return Some(f);
        }
        self.pending.pop_front()
    }
    fn poll_timeout(&self) -> Option<Instant> {
        self.master.poll_timeout()
    }
    fn handle_timeout(&mut self, now: Instant) {
        self.master.handle_timeout(now)
    }
}

/// Why the demo stopped early.
#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    /// A boot step failed on a node.
    #[error("node {node}: {step} failed: {why}")]
    Boot {
        /// The node.
        node: u8,
        /// The step.
        step: &'static str,
        /// The reason.
        why: String,
    },
    /// The bus configuration is invalid.
    #[error("bus: {0}")]
    Bus(String),
}

struct Machine {
    bus: VirtualBus,
    master: Station<VirtualPort, DemoController>,
    drives: Vec<Station<VirtualPort, DemoDrive>>,
    monitor: VirtualPort,
    frames: u64,
    busy: Duration,
    real_time: bool,
}

impl Machine {
    fn stations(&mut self) -> Vec<&mut dyn Steppable> {
        let mut v: Vec<&mut dyn Steppable> = vec![&mut self.master];
        v.extend(self.drives.iter_mut().map(|d| d as &mut dyn Steppable));
        v
    }

    fn settle(&mut self, bitrate: u32) {
        station::settle(&mut self.stations());
        while let Ok(Some(f)) = self.monitor.try_recv() {
            self.frames += 1;
            self.busy += frame_duration(&f, bitrate);
        }
    }

    /// Advances to the next event (sleeping until it in real time), no later than `until`.
    fn advance(&mut self, until: Instant) {
        let bus = self.bus.clone();
        let next = station::next_event(&bus, &self.stations(), until);
        if self.real_time {
            let now = monotonic_now();
            if next > now {
                std::thread::sleep(next - now);
            }
        }
        bus.advance_to(next);
    }

    /// Runs until `done` or `limit` of bus time.
    fn run_until(
        &mut self,
        bitrate: u32,
        limit: Duration,
        mut done: impl FnMut(&mut Machine) -> bool,
    ) -> bool {
        let until = self.bus.now() + limit;
        loop {
            self.settle(bitrate);
            if done(self) {
                return true;
            }
            if self.bus.now() >= until {
                return false;
            }
            self.advance(until);
        }
    }
}

fn sdo_wait(m: &mut Machine, bitrate: u32, node: NodeId) -> Result<Vec<u8>, String> {
    let mut out = None;
    m.run_until(bitrate, Duration::from_secs(2), |m| {
        if let Some(e) = m.master.endpoint.master.poll_sdo_event(node) {
            out = Some(e.to_vec());
            true
        } else {
            false
        }
    });
    match out {
        Some(Ok(v)) => Ok(v),
        Some(Err(e)) => Err(e.to_string()),
        None => Err("no answer within 2 s".into()),
    }
}

fn as_u32(d: &[u8]) -> u32 {
    let mut b = [0u8; 4];
    let n = d.len().min(4);
    b[..n].copy_from_slice(&d[..n]);
    u32::from_le_bytes(b)
}

fn configure_pdo(
    m: &mut Machine,
    bitrate: u32,
    node: NodeId,
    settings: &PdoSettings<'_>,
) -> Result<(), DemoError> {
    let fail = |step, why: String| DemoError::Boot {
        node: node.get(),
        step,
        why,
    };
    let plan = ConfigPlan::new(node, settings).map_err(|e| fail("PDO plan", e.to_string()))?;
    for s in plan.writes() {
        let b = s.value.to_le_bytes();
        m.master
            .endpoint
            .master
            .sdo(node)
            .map_err(|e| fail("PDO mapping", e.to_string()))?
            .download(s.addr, &b[..s.size as usize], DownloadMode::Expedited)
            .map_err(|e| fail("PDO mapping", e.to_string()))?;
        sdo_wait(m, bitrate, node).map_err(|e| fail("PDO mapping", format!("{} {e}", s.addr)))?;
    }
    for s in plan.reads() {
        m.master
            .endpoint
            .master
            .sdo(node)
            .map_err(|e| fail("PDO read-back", e.to_string()))?
            .upload(s.addr)
            .map_err(|e| fail("PDO read-back", e.to_string()))?;
        let v = sdo_wait(m, bitrate, node).map_err(|e| fail("PDO read-back", e))?;
        plan.verify(s.addr, as_u32(&v))
            .map_err(|e| fail("PDO read-back", e.to_string()))?;
    }
    Ok(())
}

/// Runs the demo; `out` receives the live output.
pub fn run(cfg: &DemoConfig, out: &mut dyn std::io::Write) -> Result<DemoSummary, DemoError> {
    let wall0 = std::time::Instant::now();
    let clock = if cfg.virtual_time {
        ClockMode::Virtual
    } else {
        ClockMode::Real
    };
    let bus = VirtualBus::new(VirtualBusConfig {
        bitrate: cfg.bitrate,
        clock,
        ..VirtualBusConfig::default()
    })
    .map_err(|e| DemoError::Bus(e.to_string()))?;
    let t0 = bus.now();
    let mut master = Box::new(DemoMaster::default());
    let nodes: Vec<NodeId> = (1..=cfg.nodes).filter_map(NodeId::new).collect();
    for &n in &nodes {
        master
            .add_node(n, Supervision::Heartbeat { consumer_ms: 250 }, t0)
            .map_err(|e| DemoError::Bus(e.to_string()))?;
    }
    let mut m = Machine {
        master: Station::new(
            bus.attach("master"),
            DemoController {
                master,
                nodes: nodes.clone(),
                tpdo: Mapping::from_raw(&[0x6041_0010, 0x6064_0020]).expect("valid mapping"),
                rpdo: Mapping::from_raw(&[0x6040_0010, 0x607A_0020]).expect("valid mapping"),
                targets: vec![0; nodes.len()],
                actual: vec![0; nodes.len()],
                status: vec![0; nodes.len()],
                cycle: 0,
                cyclic: false,
                pending: Default::default(),
                tpdos: 0,
                bad_tpdos: 0,
            },
        ),
        drives: nodes
            .iter()
            .map(|&n| {
                Station::new(
                    bus.attach(&format!("drive{n}")),
                    DemoDrive {
                        dev: Box::new(example_device(n, t0)),
                    },
                )
            })
            .collect(),
        monitor: bus.attach_monitor("monitor"),
        bus,
        frames: 0,
        busy: Duration::ZERO,
        real_time: !cfg.virtual_time,
    };
    let br = cfg.bitrate;
    let say = |out: &mut dyn std::io::Write, s: String| {
        let _ = writeln!(out, "{s}");
    };
    say(
        out,
        format!(
            "virtual CAN bus at {} kbit/s ({} time), master + {} simulated CiA 301 drives",
            br / 1000,
            if cfg.virtual_time { "virtual" } else { "real" },
            nodes.len()
        ),
    );

    // 1. Boot-up.
    let booted = m.run_until(br, Duration::from_secs(1), |m| {
        nodes
            .iter()
            .all(|&n| m.master.endpoint.master.state(n) == Some(NmtState::PreOperational))
    });
    if !booted {
        let missing = nodes
            .iter()
            .find(|&&n| m.master.endpoint.master.state(n) != Some(NmtState::PreOperational))
            .copied();
        return Err(DemoError::Boot {
            node: missing.map_or(0, |n| n.get()),
            step: "boot-up",
            why: "no boot-up message within 1 s".into(),
        });
    }
    say(
        out,
        format!("boot-up: {} nodes pre-operational", nodes.len()),
    );

    // 2. Identity, PDO mapping with read-back, heartbeat.
    for &n in &nodes {
        let fail = |step, why: String| DemoError::Boot {
            node: n.get(),
            step,
            why,
        };
        let mut ident = [0u32; 2];
        for (i, a) in [Address::new(0x1000, 0), Address::new(0x1018, 4)]
            .into_iter()
            .enumerate()
        {
            m.master
                .endpoint
                .master
                .sdo(n)
                .map_err(|e| fail("identity", e.to_string()))?
                .upload(a)
                .map_err(|e| fail("identity", e.to_string()))?;
            ident[i] = as_u32(&sdo_wait(&mut m, br, n).map_err(|e| fail("identity", e))?);
        }
        let tpdo = PdoSettings {
            direction: PdoDirection::Tpdo,
            number: 2,
            cob_id: None,
            mapping: &[0x6041_0010, 0x6064_0020],
            transmission_type: 1,
            inhibit_100us: 0,
            event_timer_ms: 0,
            sync_start: 0,
        };
        let rpdo = PdoSettings {
            direction: PdoDirection::Rpdo,
            number: 2,
            mapping: &[0x6040_0010, 0x607A_0020],
            ..tpdo
        };
        configure_pdo(&mut m, br, n, &tpdo)?;
        configure_pdo(&mut m, br, n, &rpdo)?;
        m.master
            .endpoint
            .master
            .sdo(n)
            .map_err(|e| fail("heartbeat", e.to_string()))?
            .download(
                Address::new(0x1017, 0),
                &100u16.to_le_bytes(),
                DownloadMode::Expedited,
            )
            .map_err(|e| fail("heartbeat", e.to_string()))?;
        sdo_wait(&mut m, br, n).map_err(|e| fail("heartbeat", e))?;
        say(
            out,
            format!(
                "node {n}: device type {:08X}h, serial {:08X}h; TPDO2 = statusword + position, RPDO2 = controlword + target (SYNC), read back OK; heartbeat 100 ms",
                ident[0], ident[1]
            ),
        );
    }

    // 3. Operational, SYNC-driven cycle.
    m.master
        .endpoint
        .master
        .nmt(NmtCommand::Start, NmtTarget::All)
        .map_err(|e| DemoError::Bus(e.to_string()))?;
    m.run_until(br, Duration::from_millis(5), |_| false);
    let sync_start = m.bus.now();
    m.master
        .endpoint
        .master
        .start_sync(cfg.cycle.as_micros() as u32, 0, sync_start)
        .map_err(|e| DemoError::Bus(e.to_string()))?;
    say(
        out,
        format!(
            "NMT start; SYNC every {} µs; driving {} axes for {:.1} s of bus time",
            cfg.cycle.as_micros(),
            nodes.len(),
            cfg.duration.as_secs_f64()
        ),
    );

    m.master.endpoint.cyclic = true;
    let mut summary = DemoSummary::default();
    let frames0 = m.frames;
    let busy0 = m.busy;
    let end = sync_start + cfg.duration;
    let mut t = sync_start;
    while t < end {
        let step = cfg.status_every.unwrap_or(cfg.duration).min(end - t);
        m.run_until(br, step, |_| false);
        t = m.bus.now();
        while let Some(e) = m.master.endpoint.master.poll_event() {
            // State changes the master commanded are expected; losses, EMCYs and guarding
            // errors are what supervision is for.
            let routine = matches!(
                e,
                MasterEvent::Nmt(_)
                    | MasterEvent::Heartbeat(
                        HeartbeatEvent::StateChanged { .. } | HeartbeatEvent::BootUp { .. }
                    )
            );
            if !routine {
                summary.supervision_events += 1;
                say(out, format!("event: {e:?}"));
            }
        }
        if cfg.status_every.is_some() {
            let c = &m.master.endpoint;
            let mut line = format!(
                "t={:6.3}s cycle {:6}",
                (t - sync_start).as_secs_f64(),
                c.cycle
            );
            for (i, &n) in nodes.iter().enumerate() {
                let _ = write!(
                    line,
                    " | n{n} {:04X}h tgt {:7} act {:7}",
                    c.status[i], c.targets[i], c.actual[i]
                );
            }
            let load =
                100.0 * (m.busy - busy0).as_secs_f64() / (t - sync_start).as_secs_f64().max(1e-9);
            let _ = write!(line, " | bus {load:4.1}%");
            say(out, line);
        }
    }
    let phase = m.bus.now() - sync_start;
    let c = &m.master.endpoint;
    summary.cycles = c.cycle;
    summary.tpdos_received = c.tpdos;
    summary.frames = m.frames - frames0;
    summary.bus_load_percent =
        100.0 * (m.busy - busy0).as_secs_f64() / phase.as_secs_f64().max(1e-9);
    summary.final_max_error = c
        .targets
        .iter()
        .zip(&c.actual)
        .map(|(t, a)| (t - a).abs())
        .max()
        .unwrap_or(0);
    summary.bad_tpdos = c.bad_tpdos;
    // Stop cleanly: drives back to pre-operational, SYNC off.
    m.master.endpoint.cyclic = false;
    m.master.endpoint.master.stop_sync();
    let _ = m
        .master
        .endpoint
        .master
        .nmt(NmtCommand::EnterPreOperational, NmtTarget::All);
    m.run_until(br, Duration::from_millis(5), |_| false);
    summary.wall = wall0.elapsed();
    summary.bus_time = m.bus.now() - t0;
    Ok(summary)
}
