//! Booting the real device simulators (MTR-DCI, EMCA, TLC5xx) over SDO with the boot
//! sequencer, on the virtual bus in virtual time; and the services on their executor thread
//! against a stand-in cycle thread in real time.

use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, mpsc};
use std::time::Duration;

use coordinator::axis::DeviceKind;
use coordinator::command::{Command, Reply, Target};
use coordinator::cycle::BusFrame;
use coordinator::drivers;
use coordinator::event::Event;
use coordinator::runtime::boot::{
    BootPlan, BootReport, BootSequencer, BootStep, FailureDetail, SupervisionPlan, plan_for,
};
use coordinator::runtime::nodes::{NodeReport, Nodes};
use coordinator::runtime::services::{ServiceEvent, channels, spawn_services};
use drivers::can::station::{self, Station, Steppable};
use drivers::can::{Bus, ClockMode, Frame, VirtualBus, VirtualBusConfig, VirtualPort};
use drivers::canopen::nmt::NmtState;
use drivers::canopen::{AbortCode, Address, NodeId};
use drivers::sim::emca::Emca;
use drivers::sim::mtr_dci::{MtrDci, Profile};
use drivers::sim::tlc5xx::{Tlc5xx, TlcConfig};

const FHPP_RPDO1: [u32; 5] = [
    0x3000_0008,
    0x3001_0008,
    0x3002_0008,
    0x3003_0008,
    0x3004_0020,
];
const FHPP_TPDO1: [u32; 5] = [
    0x3020_0008,
    0x3021_0008,
    0x3022_0008,
    0x3023_0008,
    0x3024_0020,
];
const TLC_RPDO1: [u32; 3] = [0x6040_0010, 0x607A_0020, 0x6060_0008];
const TLC_TPDO1: [u32; 3] = [0x6041_0010, 0x6064_0020, 0x6061_0008];

const GUARD: SupervisionPlan = SupervisionPlan::Guarding {
    guard_ms: 100,
    life_factor: 3,
};
const HEARTBEAT: SupervisionPlan = SupervisionPlan::Heartbeat { producer_ms: 100 };

fn node(n: u8) -> NodeId {
    NodeId::new(n).unwrap()
}

/// MTR-DCI on node 1, EMCA on 2, TLC5xx on 3, with the mappings the simulators accept.
fn plans() -> Vec<BootPlan> {
    vec![
        plan_for(node(1), DeviceKind::MtrDci, &FHPP_RPDO1, &FHPP_TPDO1, GUARD).unwrap(),
        plan_for(node(2), DeviceKind::Emca, &FHPP_RPDO1, &FHPP_TPDO1, GUARD).unwrap(),
        plan_for(
            node(3),
            DeviceKind::Tlc5xx,
            &TLC_RPDO1,
            &TLC_TPDO1,
            HEARTBEAT,
        )
        .unwrap(),
    ]
}

struct Rig {
    bus: VirtualBus,
    seq: Station<VirtualPort, BootSequencer>,
    mtr: Station<VirtualPort, MtrDci>,
    emca: Station<VirtualPort, Emca>,
    tlc: Station<VirtualPort, Tlc5xx>,
    monitor: VirtualPort,
    frames: Vec<Frame>,
}

impl Rig {
    fn new(plans: Vec<BootPlan>) -> Rig {
        let bus = VirtualBus::new(VirtualBusConfig::default()).unwrap();
        let t0 = bus.now();
        Rig {
            seq: Station::new(bus.attach("master"), BootSequencer::new(plans, t0)),
            mtr: Station::new(
                bus.attach("mtr-dci"),
                MtrDci::new(node(1), Profile::Fhpp, t0).unwrap(),
            ),
            emca: Station::new(bus.attach("emca"), Emca::new(node(2), t0).unwrap()),
            tlc: Station::new(
                bus.attach("tlc5xx"),
                Tlc5xx::new(TlcConfig::new(node(3)), t0).unwrap(),
            ),
            monitor: bus.attach_monitor("monitor"),
            bus,
            frames: Vec::new(),
        }
    }

    /// Runs until the sequencer is finished (bounded to 30 s of bus time), then 250 ms more so
    /// the NMT start reaches the nodes and a heartbeat follows.
    fn run(&mut self) -> Vec<BootReport> {
        let limit = self.bus.now() + Duration::from_secs(30);
        let mut end = None;
        loop {
            station::settle(&mut [
                &mut self.seq as &mut dyn Steppable,
                &mut self.mtr,
                &mut self.emca,
                &mut self.tlc,
            ]);
            while let Ok(Some(f)) = self.monitor.try_recv() {
                self.frames.push(f);
            }
            let now = self.bus.now();
            if end.is_none() && self.seq.endpoint.is_finished() {
                end = Some(now + Duration::from_millis(250));
            }
            let until = end.unwrap_or(limit);
            if now >= until {
                break;
            }
            let st: [&mut dyn Steppable; 4] =
                [&mut self.seq, &mut self.mtr, &mut self.emca, &mut self.tlc];
            let next = station::next_event(&self.bus, &st, until);
            self.bus.advance_to(next);
        }
        assert!(self.seq.endpoint.is_finished(), "boot did not finish");
        self.seq.endpoint.reports().to_vec()
    }

    fn fingerprint(&self) -> u64 {
        let mut h = DefaultHasher::new();
        for f in &self.frames {
            (
                f.raw_id(),
                f.is_remote(),
                f.data(),
                f.timestamp().as_nanos(),
            )
                .hash(&mut h);
        }
        h.finish()
    }
}

fn report(reports: &[BootReport], n: u8) -> BootReport {
    *reports
        .iter()
        .find(|r| r.node == node(n))
        .unwrap_or_else(|| panic!("no report for node {n}"))
}

#[test]
fn three_drives_boot_to_operational_with_pdos_and_supervision() {
    let mut rig = Rig::new(plans());
    let reports = rig.run();
    assert_eq!(reports.len(), 3);
    for r in &reports {
        assert!(r.result.is_ok(), "{r}");
    }
    assert_eq!(report(&reports, 1).device_type, Some(0x12D));
    assert_eq!(report(&reports, 3).vendor_id, Some(0x0100_002E));

    // Festo: static PDO1 mapping kept, SYNC-driven now, node guarding set.
    for od in [
        rig.mtr.endpoint.device().od(),
        rig.emca.endpoint.device().od(),
    ] {
        assert_eq!(od.get_u8(Address::new(0x1400, 2)), Ok(1));
        assert_eq!(od.get_u8(Address::new(0x1800, 2)), Ok(1));
        assert_eq!(od.get_u32(Address::new(0x1A00, 5)), Ok(0x3024_0020));
        assert_eq!(od.get_u16(Address::new(0x100C, 0)), Ok(100));
        assert_eq!(od.get_u8(Address::new(0x100D, 0)), Ok(3));
    }
    assert_eq!(rig.mtr.endpoint.device().state(), NmtState::Operational);
    assert_eq!(rig.emca.endpoint.device().state(), NmtState::Operational);

    // TLC5xx: remapped PDO1 both ways, type 1, valid, heartbeat 100 ms.
    let od = rig.tlc.endpoint.od();
    assert_eq!(od.get_u8(Address::new(0x1600, 0)), Ok(3));
    for (i, e) in TLC_RPDO1.iter().enumerate() {
        assert_eq!(od.get_u32(Address::new(0x1600, i as u8 + 1)), Ok(*e));
    }
    for (i, e) in TLC_TPDO1.iter().enumerate() {
        assert_eq!(od.get_u32(Address::new(0x1A00, i as u8 + 1)), Ok(*e));
    }
    assert_eq!(od.get_u8(Address::new(0x1400, 2)), Ok(1));
    assert_eq!(od.get_u8(Address::new(0x1800, 2)), Ok(1));
    assert_eq!(od.get_u32(Address::new(0x1400, 1)), Ok(0x203));
    assert_eq!(od.get_u32(Address::new(0x1800, 1)), Ok(0x183));
    assert_eq!(od.get_u16(Address::new(0x1017, 0)), Ok(100));
    assert_eq!(rig.tlc.endpoint.nmt_state(), NmtState::Operational);
    // The TLC produces heartbeats now, state operational (05h).
    assert!(
        rig.frames
            .iter()
            .any(|f| f.cob_id() == Some(0x703) && f.data() == [5])
    );
}

#[test]
fn a_missing_node_is_reported_waiting_while_the_others_finish() {
    let mut p = plans();
    let mut ghost = plan_for(
        node(9),
        DeviceKind::Tlc5xx,
        &TLC_RPDO1,
        &TLC_TPDO1,
        HEARTBEAT,
    )
    .unwrap();
    ghost.timeouts.boot_up = Duration::from_millis(800);
    p.insert(1, ghost);
    let mut rig = Rig::new(p);
    let reports = rig.run();
    assert_eq!(reports.len(), 4);
    for n in [1, 2, 3] {
        assert!(report(&reports, n).result.is_ok());
    }
    let f = report(&reports, 9).result.unwrap_err();
    assert_eq!(f.step, BootStep::BootUp);
    assert_eq!(f.detail, FailureDetail::NoBootUp { waited_ms: 800 });
    assert!(f.detail.is_waiting());
    assert_eq!(
        f.to_string(),
        "node 9: boot-up failed: no boot-up within 800 ms"
    );
    // Still asked for, every probe period, with reset communication (reported only once).
    let resets = rig
        .frames
        .iter()
        .filter(|f| f.cob_id() == Some(0x000) && f.data() == [0x82, 9])
        .count();
    assert!(resets >= 2, "{resets} resets of node 9");
    assert_eq!(rig.tlc.endpoint.nmt_state(), NmtState::Operational);
}

#[test]
fn a_drive_the_cycle_lost_is_reported_asked_again_and_configured_again() {
    let mut rig = Rig::new(plans());
    assert_eq!(rig.run().len(), 3);
    let before = rig.frames.len();
    // The cycle lost the EMCA (its supervision); the drive itself is still there.
    rig.seq.endpoint.lost(node(2));
    let reports = rig.run();
    let after = &reports[3..];
    assert_eq!(after.len(), 2, "lost, then booted again: {after:?}");
    let lost = after[0].result.unwrap_err();
    assert_eq!((lost.node, lost.detail), (node(2), FailureDetail::Lost));
    assert!(lost.detail.is_waiting());
    assert_eq!(after[1].node, node(2));
    assert!(after[1].result.is_ok(), "{:?}", after[1]);
    // Asked with reset communication, as a missing node is.
    assert!(
        rig.frames[before..]
            .iter()
            .any(|f| f.cob_id() == Some(0x000) && f.data() == [0x82, 2]),
        "reset communication to node 2"
    );
    // Losing a node that is not running changes nothing.
    rig.seq.endpoint.lost(node(9));
    assert_eq!(rig.seq.endpoint.reports().len(), 5);
}

#[test]
fn aborted_writes_report_step_object_and_code() {
    // The TLC5xx refuses to map 1000h (not mappable) when the count is written; the MTR-DCI
    // refuses any write to its static mapping.
    let mut p = plans();
    p[2] = plan_for(
        node(3),
        DeviceKind::Tlc5xx,
        &[0x6040_0010, 0x1000_0020],
        &TLC_TPDO1,
        HEARTBEAT,
    )
    .unwrap();
    for pdo in &mut p[0].pdos {
        pdo.static_mapping = false;
    }
    let mut rig = Rig::new(p);
    let reports = rig.run();

    let tlc = report(&reports, 3).result.unwrap_err();
    assert_eq!(tlc.step, BootStep::PdoConfig);
    assert_eq!(tlc.object, Some(Address::new(0x1600, 0)));
    assert_eq!(tlc.abort, Some(AbortCode::NotMappable));
    assert!(
        tlc.to_string()
            .starts_with("node 3: PDO configuration failed at 1600h:00h: SDO abort 0604 0041h")
    );

    let mtr = report(&reports, 1).result.unwrap_err();
    assert_eq!(mtr.step, BootStep::PdoConfig);
    assert_eq!(mtr.object, Some(Address::new(0x1600, 0)));
    assert_eq!(mtr.abort, Some(AbortCode::ReadOnly));

    // The EMCA is not held up by its neighbours.
    assert!(report(&reports, 2).result.is_ok());
    assert_eq!(rig.emca.endpoint.device().state(), NmtState::Operational);
    assert_eq!(rig.tlc.endpoint.nmt_state(), NmtState::PreOperational);
}

#[test]
fn a_static_mapping_that_differs_fails_read_back() {
    let mut p = plans();
    // Expect a CiA 402 TPDO1 on an EMCA whose static FHPP mapping cannot be it: the read-back
    // shows the difference.
    let mut wrong = plan_for(node(2), DeviceKind::Emca, &FHPP_RPDO1, &TLC_TPDO1, GUARD).unwrap();
    wrong.device_type = None;
    p[1] = wrong;
    let mut rig = Rig::new(p);
    let reports = rig.run();
    let f = report(&reports, 2).result.unwrap_err();
    assert_eq!(f.step, BootStep::PdoReadBack);
    assert_eq!(f.object, Some(Address::new(0x1A00, 1)));
    assert_eq!(
        f.to_string(),
        "node 2: PDO read-back failed at 1A00h:01h: read 30200008h, expected 60410010h"
    );
    assert!(report(&reports, 1).result.is_ok());
    assert!(report(&reports, 3).result.is_ok());
}

#[test]
fn identity_mismatch_is_reported_with_both_values() {
    let mut p = plans();
    p[2].vendor_id = Some(0x1D);
    let mut rig = Rig::new(p);
    let reports = rig.run();
    let f = report(&reports, 3).result.unwrap_err();
    assert_eq!(f.step, BootStep::Identity);
    assert_eq!(
        f.detail,
        FailureDetail::WrongDevice {
            device_type: 0x0002_0192,
            vendor_id: 0x0100_002E,
            expected_type: 0x0002_0192,
            expected_vendor: 0x1D,
        }
    );
    // Both devices by name: the one found and the one configured.
    let text = f.to_string();
    assert!(
        text.contains("(a Schneider TLC5xx (CiA 402))")
            && text.contains("(a Festo MTR-DCI (CiA 402))"),
        "{text}"
    );
    // Refused, not started: it stays pre-operational.
    assert_eq!(rig.tlc.endpoint.nmt_state(), NmtState::PreOperational);
}

#[test]
fn the_frames_of_a_boot_are_deterministic() {
    let mut a = Rig::new(plans());
    let ra = a.run();
    let mut b = Rig::new(plans());
    let rb = b.run();
    assert_eq!(ra, rb);
    assert!(a.frames.len() > 100, "{} frames", a.frames.len());
    assert_eq!(a.frames.len(), b.frames.len());
    assert_eq!(a.fingerprint(), b.fingerprint());
}

// ---- the services against a stand-in cycle, in real time ------------------------------------

/// The three simulators on their own thread, stepped on the real-clock bus.
fn run_sims(bus: &VirtualBus, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<(NmtState, u8)> {
    let t0 = bus.now();
    let mut mtr = Station::new(
        bus.attach("mtr-dci"),
        MtrDci::new(node(1), Profile::Fhpp, t0).unwrap(),
    );
    let mut emca = Station::new(bus.attach("emca"), Emca::new(node(2), t0).unwrap());
    let mut tlc = Station::new(
        bus.attach("tlc5xx"),
        Tlc5xx::new(TlcConfig::new(node(3)), t0).unwrap(),
    );
    std::thread::spawn(move || {
        while !stop.load(Ordering::Acquire) {
            let mut st: [&mut dyn Steppable; 3] = [&mut mtr, &mut emca, &mut tlc];
            station::settle(&mut st);
            std::thread::sleep(Duration::from_micros(200));
        }
        let tt = tlc
            .endpoint
            .od()
            .get_u8(Address::new(0x1800, 2))
            .unwrap_or(0);
        (tlc.endpoint.nmt_state(), tt)
    })
}

#[test]
fn services_boot_through_the_queues_and_answer_every_request() {
    let bus = VirtualBus::new(VirtualBusConfig {
        clock: ClockMode::Real,
        ..VirtualBusConfig::default()
    })
    .unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let sims = run_sims(&bus, stop.clone());
    let (mut cycle, service, mut commands) = channels();
    let booted: Arc<Mutex<Vec<NodeReport>>> = Arc::default();

    // The stand-in cycle: every 500 µs, forward frames both ways, answer requests, take boot
    // reports, and emit one event per request it answers.
    let mut port = bus.attach("cycle");
    let cycle_stop = stop.clone();
    let cycle_booted = booted.clone();
    let cycle_thread = std::thread::spawn(move || {
        let mut n: u64 = 0;
        let mut held: Option<BusFrame> = None;
        let mut dropped = 0u32;
        while !cycle_stop.load(Ordering::Acquire) {
            n += 1;
            while let Ok(Some(f)) = port.try_recv() {
                if cycle.offer_received(&BusFrame::new(0, f)).is_err() {
                    dropped += 1;
                }
            }
            while let Some(f) = held.take().or_else(|| cycle.tx_frame()) {
                if port.send(&f.frame).is_err() {
                    held = Some(f);
                    break;
                }
            }
            while let Some(r) = cycle.request() {
                cycle
                    .answer(coordinator::command::Answer {
                        tag: r.tag,
                        reply: Reply::Latched { cycle: n },
                    })
                    .expect("a request is taken only with room for its answer");
                let _ = cycle.event(Event::Acknowledged { cycle: n, axis: 0 });
            }
            while let Some(r) = cycle.boot_report() {
                cycle_booted.lock().unwrap().push(r);
            }
            std::thread::sleep(Duration::from_micros(500));
        }
        dropped
    });

    let (etx, erx) = mpsc::channel();
    let handle = spawn_services(
        service,
        Nodes::single_bus(plans(), drivers::time::monotonic_now()),
        Box::new(move |e| {
            let _ = etx.send(e);
        }),
    )
    .unwrap();

    // Boot through the queues.
    let deadline = std::time::Instant::now() + Duration::from_secs(20);
    let mut boot_events = Vec::new();
    loop {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        match erx.recv_timeout(left) {
            Ok(ServiceEvent::BootFinished) => break,
            Ok(ServiceEvent::Node(r)) => boot_events.push(r),
            Ok(_) => {}
            Err(e) => panic!("boot did not finish: {e}"),
        }
    }
    assert_eq!(boot_events.len(), 3);
    for r in &boot_events {
        assert!(r.report.result.is_ok(), "{}", r.report);
    }
    // The cycle got the same reports.
    let deadline = std::time::Instant::now() + Duration::from_secs(5);
    while booted.lock().unwrap().len() < 3 && std::time::Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(1));
    }
    assert_eq!(*booted.lock().unwrap(), boot_events);

    // Every request gets its answer through the command port, matched by tag: a burst of 100,
    // submitted as fast as the queue takes them.
    let mut answered = 0;
    let mut submitted = 0;
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while answered < 100 {
        while submitted < 100 && commands.submit(Command::Enable(Target::All)).is_ok() {
            submitted += 1;
        }
        while let Some(a) = commands.answer() {
            assert!(matches!(a.reply, Reply::Latched { .. }));
            answered += 1;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "{answered} of 100 answered"
        );
        std::thread::sleep(Duration::from_micros(200));
    }
    // ... and the cycle's events reach the sink.
    let deadline = std::time::Instant::now() + Duration::from_secs(5);
    let mut acks = 0;
    while acks < 100 {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        if let ServiceEvent::Cycle(Event::Acknowledged { .. }) = erx.recv_timeout(left).unwrap() {
            acks += 1;
        }
    }

    handle.stop();
    stop.store(true, Ordering::Release);
    let dropped = cycle_thread.join().unwrap();
    assert_eq!(dropped, 0);
    let (state, tpdo_type) = sims.join().unwrap();
    assert_eq!(state, NmtState::Operational);
    assert_eq!(tpdo_type, 1);
}
